"""Independent quadrotor simulator of a blind audit (2026-12-05, the eighteenth), kept as a
test generator that is not greybox's own: written from ``README.md`` and ``CONTRACT.md``
alone, without reading the package, and checked against ``greybox simulate`` to 1e-11 m /
5e-10 rad in open loop (plus and x layouts, rotor inertia, the accelerometer) and, with its
own effect, to 1e-12. A 2.5 kg plus-layout vehicle logged at 100 Hz and a 35 g x-layout one
at 500 Hz (positions at 100 Hz), each under a cascaded PID with a nominal model 5 % / 10 %
off and a 3 % multisine on the rotor speeds, the commanded speeds logged with white noise;
an effect outside the catalogue, a thrust that falls with the climb rate
(``T_i = K_T w_i^2 (1 + k_climb vz_b)``), which the audit registered with ``--effects-file``
(:data:`CLIMB_LOSS_EFFECT`). The audit's ``sim.py``, ``airframes.py`` and its
``gen_flights.py`` cases as :func:`flight`; the physics and numbers are the audit's.

The audit's description:
Independent quadrotor simulator for the greybox blind audit (audit18).

Conventions from CONTRACT.md s1-s3: NED world, FRD body, ZYX Euler (R = Rz Ry Rx, body->world),
thrust K_T w^2 along body -z at r_i, reaction torque spin_i*b*w_i^2 about body +z,
gyroscopic torque J_r*Omega_r*(omega x e_z), Omega_r = sum(spin_i w_i),
world-frame linear drag -Kd*v.  Inputs zero-order held per row.  Own RK4 with substeps.

Own non-catalogue effect "climb_loss": each rotor's thrust x (1 + k_climb * vz_b), vz_b the
body-frame z velocity (down positive), so climbing (vz_b < 0) loses thrust for k_climb > 0.
"""

import numpy as np

G = 9.81


def rot(phi, th, psi):
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)
    Rz = np.array([[cp, -sp, 0], [sp, cp, 0], [0, 0, 1]])
    Ry = np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    Rx = np.array([[1, 0, 0], [0, cf, -sf], [0, sf, cf]])
    return Rz @ Ry @ Rx


def layout(kind, l):
    if kind == "plus":
        pos = np.array([[l, 0, 0], [0, l, 0], [-l, 0, 0], [0, -l, 0]], float)
        spin = np.array([-1, 1, -1, 1], float)
    elif kind == "x":
        a = l / np.sqrt(2)
        pos = np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]], float)
        spin = np.array([1, 1, -1, -1], float)
    else:
        raise ValueError(kind)
    return pos, spin


class Vehicle:
    def __init__(self, mass, J, arm, kind, K_T, b, Kd, J_r=0.0, k_climb=0.0, g=G, k_yd=0.0):
        self.m = mass
        self.J = np.diag(J) if np.ndim(J) == 1 else np.array(J)
        self.Jinv = np.linalg.inv(self.J)
        self.arm = arm
        self.kind = kind
        self.pos, self.spin = layout(kind, arm)
        self.K_T, self.b = K_T, b
        self.Kd = np.array(Kd, float)
        self.J_r = J_r
        self.k_climb = k_climb
        self.k_yd = k_yd   # own effect 2: yaw drag torque -k_yd*r*|r| about body z
        self.g = g

    def deriv(self, x, w):
        phi, th, psi = x[3:6]
        v = x[6:9]
        om = x[9:12]
        R = rot(phi, th, psi)
        vb = R.T @ v
        T = self.K_T * w ** 2 * (1.0 + self.k_climb * vb[2])
        F_body = np.array([0, 0, -T.sum()])
        acc = np.array([0, 0, self.g]) + (R @ F_body - self.Kd * v) / self.m
        tau = np.zeros(3)
        for i in range(len(w)):
            tau += np.cross(self.pos[i], [0, 0, -T[i]])
        tau[2] += self.b * np.sum(self.spin * w ** 2)
        if self.k_yd:
            tau[2] -= self.k_yd * om[2] * abs(om[2])
        Om_r = np.sum(self.spin * w)
        tau += self.J_r * Om_r * np.cross(om, [0, 0, 1.0])
        omd = self.Jinv @ (tau - np.cross(om, self.J @ om))
        p, q, r = om
        cf, sf, ct, tt = np.cos(phi), np.sin(phi), np.cos(th), np.tan(th)
        eul_d = np.array([p + (q * sf + r * cf) * tt, q * cf - r * sf, (q * sf + r * cf) / ct])
        return np.concatenate([v, eul_d, acc, omd])

    def step(self, x, w, h, nsub):
        dt = h / nsub
        for _ in range(nsub):
            k1 = self.deriv(x, w)
            k2 = self.deriv(x + dt / 2 * k1, w)
            k3 = self.deriv(x + dt / 2 * k2, w)
            k4 = self.deriv(x + dt * k3, w)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    def simulate_open(self, t, W, x0=None, max_sub=0.5e-3):
        x = np.zeros(12) if x0 is None else np.array(x0, float)
        X = [x]
        for k in range(len(t) - 1):
            h = t[k + 1] - t[k]
            n = max(1, int(np.ceil(h / max_sub - 1e-9)))
            x = self.step(x, W[k], h, n)
            X.append(x)
        return np.array(X)

    def mixer(self):
        """rows: total thrust, roll, pitch, yaw torque per w^2"""
        M = np.zeros((4, len(self.spin)))
        M[0] = 1.0
        M[1] = -self.pos[:, 1]
        M[2] = self.pos[:, 0]
        return M


class Controller:
    """Cascaded PID: position (PID) -> desired accel -> thrust + attitude; attitude P -> rate PI -> torques.
    Uses NOMINAL parameters (not the truth)."""

    def __init__(self, nom: Vehicle, wn_pos=1.5, wn_att=8.0, wn_rate=30.0):
        self.n = nom
        self.wp = wn_pos
        self.wa = wn_att
        self.wr = wn_rate
        self.ipos = np.zeros(3)
        self.irate = np.zeros(3)
        M = nom.mixer()
        M = M * nom.K_T
        M[3] = nom.b * nom.spin
        self.Minv = np.linalg.inv(M)

    def __call__(self, x, ref, dt):
        n = self.n
        pos, eul, v, om = x[0:3], x[3:6], x[6:9], x[9:12]
        pr, vr, ar, psir = ref
        e = pr - pos
        self.ipos += e * dt
        self.ipos = np.clip(self.ipos, -2, 2)
        a_des = ar + 2 * 0.9 * self.wp * (vr - v) + self.wp ** 2 * e + 0.3 * self.ipos
        f = a_des - np.array([0, 0, n.g])   # desired (specific force) = R*(0,0,-T/m)
        T = n.m * np.linalg.norm(f)
        zb = -f / np.linalg.norm(f)         # body z axis in world
        # desired attitude from zb and yaw
        xc = np.array([np.cos(psir), np.sin(psir), 0])
        yb = np.cross(zb, xc); yb /= np.linalg.norm(yb)
        xb = np.cross(yb, zb)
        Rd = np.column_stack([xb, yb, zb])
        R = rot(*eul)
        eR = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([eR[2, 1], eR[0, 2], eR[1, 0]])
        om_des = -self.wa * eR
        om_des = np.clip(om_des, -4, 4)
        er = om_des - om
        self.irate += er * dt
        self.irate = np.clip(self.irate, -1, 1)
        alpha = self.wr * er + 0.5 * self.wr * self.irate
        tau = n.J @ alpha + np.cross(om, n.J @ om)
        w2 = self.Minv @ np.concatenate([[T], tau])
        return np.sqrt(np.clip(w2, 0.05 * T / n.K_T / 4, None))


def min_jerk(p0, p1, s):
    s = np.clip(s, 0, 1)
    return p0 + (p1 - p0) * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)


def make_reference(rng, duration, scale, z0, seg=2.5, psi_offset=0.0):
    """Piecewise minimum-jerk waypoints; returns function t -> (p, v, a, psi)."""
    n = int(np.ceil(duration / seg)) + 1
    wps = [np.array([0.0, 0.0, z0])]
    yaws = [psi_offset]
    for i in range(n):
        d = rng.uniform(-1, 1, 3) * scale * np.array([1.0, 1.0, 0.6])
        wps.append(np.array([d[0], d[1], z0 + d[2]]))
        yaws.append(psi_offset + rng.uniform(-0.8, 0.8))

    def ref(t, dt=1e-3):
        def pp(tt):
            k = min(int(tt // seg), n - 1)
            s = (tt - k * seg) / seg
            return min_jerk(wps[k], wps[k + 1], s), float(min_jerk(np.array(yaws[k]), np.array(yaws[k + 1]), s))
        p, psi = pp(t)
        pa, _ = pp(t + dt)
        pb, _ = pp(max(t - dt, 0))
        v = (pa - pb) / (2 * dt) if t > dt else (pa - p) / dt
        a = (pa - 2 * p + pb) / dt ** 2 if t > dt else np.zeros(3)
        return p, v, a, psi
    return ref


def fly(truth: Vehicle, nominal: Vehicle, duration, rate, seed, scale=1.0, z0=-1.5,
        excite=0.03, wnoise=0.0, pos_noise=0.003, att_noise=0.002, gyro_noise=0.01,
        pos_every=1, max_sub=1e-3, ctrl_gains=None, psi_offset=0.0):
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate
    nsub = max(1, int(np.ceil(dt / max_sub - 1e-9)))
    t = np.arange(int(round(duration * rate)) + 1) * dt
    ref = make_reference(rng, duration, scale, z0, psi_offset=psi_offset)
    ctrl = Controller(nominal, **(ctrl_gains or {}))
    # excitation: multisine per rotor, relative
    nf = 8
    freqs = rng.uniform(0.3, 6.0, (4, nf))
    phs = rng.uniform(0, 2 * np.pi, (4, nf))
    x = np.zeros(12)
    x[0:3] = [0, 0, z0]
    x[5] = psi_offset
    wh = np.sqrt(truth.m * truth.g / (4 * truth.K_T))
    X = np.zeros((len(t), 12)); W = np.zeros((len(t), 4))
    for k in range(len(t)):
        X[k] = x
        w = ctrl(x, ref(t[k]), dt)
        ex = excite * np.sqrt(2.0 / nf) * np.sum(np.sin(2 * np.pi * freqs * t[k] + phs), axis=1)
        w = w * (1 + ex)
        w = np.clip(w, 0.2 * wh, 2.2 * wh)
        W[k] = w
        if k < len(t) - 1:
            x = truth.step(x, w, dt, nsub)
    # measurements
    Y = X.copy()
    Y[:, 0:3] += rng.normal(0, pos_noise, (len(t), 3))
    Y[:, 3:6] += rng.normal(0, att_noise, (len(t), 3))
    if psi_offset:
        Y[:, 5] = wrap(Y[:, 5])   # IMU reports yaw in [-pi, pi)
    Y[:, 9:12] += rng.normal(0, gyro_noise, (len(t), 3))
    Wlog = W + rng.normal(0, wnoise, W.shape)
    mask = np.arange(len(t)) % pos_every != 0
    Y[mask, 0:3] = np.nan
    return t, Wlog, Y, X, W


def write_log(path, t, W, Y, digits=9):
    cols = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r"]
    idx = [0, 1, 2, 3, 4, 5, 9, 10, 11]
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for k in range(len(t)):
            row = [f"{t[k]:.6f}"] + [f"{v:.{digits}g}" for v in W[k]]
            for j in idx:
                v = Y[k, j]
                row.append("" if np.isnan(v) else f"{v:.{digits}g}")
            f.write(",".join(row) + "\n")


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


# --- the audit's airframes.py
BIG = dict(name="big25", mass=2.5, inertia=[0.030, 0.032, 0.055], arm=0.30, layout="plus",
           J_r=5e-5, K_T=3.0e-5, b=6.0e-7, Kd=[0.25, 0.25, 0.35])
SMALL = dict(name="cf35", mass=0.035, inertia=[1.5e-5, 1.6e-5, 2.9e-5], arm=0.046, layout="x",
             J_r=0.0, K_T=2.2e-8, b=1.3e-10, Kd=[0.012, 0.012, 0.018])

def toml(af, K_T, b, Kd, path, extra=""):
    s = f"""[airframe]
name = "{af['name']}"
mass = {af['mass']}
inertia = {af['inertia']}
arm_length = {af['arm']}
layout = "{af['layout']}"
rotor_inertia = {af['J_r']}
gravity = 9.81

[parameters]
K_T = {K_T!r}
b = {b!r}
Kd = {list(Kd)!r}
{extra}"""
    open(path, "w").write(s)

def vehicle(af, **over):
    d = dict(af); d.update(over)
    return Vehicle(d["mass"], d["inertia"], d["arm"], d["layout"], d["K_T"], d["b"], d["Kd"], J_r=d["J_r"], k_climb=d.get("k_climb", 0.0), k_yd=d.get("k_yd", 0.0))

SPECS = {
    # name: airframe, k_climb, seed, duration, rate, pos_every, scale, z0, wnoise (the audit's gen_flights.py)
    "big_A": (BIG, 0.0, 11, 30, 100, 1, 1.5, -1.5, 0.5),
    "big_B": (BIG, 0.0, 12, 30, 100, 1, 1.5, -1.5, 0.5),
    "big_C": (BIG, 0.08, 13, 30, 100, 1, 1.5, -1.5, 0.5),
    "big_D": (BIG, 0.08, 14, 30, 100, 1, 1.5, -1.5, 0.5),
    "big_E": (BIG, 0.0, 15, 20, 100, 1, 1.5, -1.5, 0.5),
    "big_A0": (BIG, 0.0, 11, 30, 100, 1, 1.5, -1.5, 0.0),
    "small_A": (SMALL, 0.0, 21, 16, 500, 5, 0.8, -1.0, 2.0),
    "small_C": (SMALL, 0.10, 22, 16, 500, 5, 0.8, -1.0, 2.0),
    "small_D": (SMALL, 0.10, 23, 16, 500, 5, 0.8, -1.0, 2.0),
}


def flight(path, name: str) -> dict:
    """Fly the audit's case ``name`` (:data:`SPECS`) and write its log to ``path`` as the audit
    did; its truth."""
    af, kc, seed, dur, rate, pe, scale, z0, wn = SPECS[name]
    tr = vehicle(af, k_climb=kc)
    nom = vehicle(af, K_T=af["K_T"] * 1.05, b=af["b"] * 0.9)   # the controller's nominal model
    gains = dict(wn_pos=2.0, wn_att=12, wn_rate=50) if af is SMALL else None
    t, W, Y, X, Wt = fly(tr, nom, dur, rate, seed, scale=scale, z0=z0, wnoise=wn,
                         pos_noise=0.003, att_noise=0.002, gyro_noise=0.01, pos_every=pe,
                         max_sub=0.5e-3 if af is SMALL else 1e-3, ctrl_gains=gains)
    write_log(str(path), t, W, Y)
    return dict(af, k_climb=kc)


CLIMB_LOSS_EFFECT = '"""audit18\'s own effect: each rotor\'s thrust x (1 + k_climb * vz_b), vz_b = body-frame z air velocity (FRD, down +)."""\nimport casadi as ca\nfrom greybox.effects import Effect\nfrom greybox.parameters import Parameter\n\n\nclass ClimbLoss(Effect):\n    name = "climb_loss"\n    summary = "rotor thrust scaled by (1 + k_climb * vz_b): thrust lost while climbing"\n    channels = ("z", "phi", "theta")\n\n    def parameters(self, airframe):\n        return [Parameter(name="k_climb", size=1, default=0.0, unit="s/m", lower=-0.5, upper=0.5,\n                          scale=0.05, null=0.0, description="relative thrust change per m/s of body-z velocity",\n                          effect=self.name)]\n\n    def modify(self, ctx):\n        vb = ca.mtimes(ctx.R.T, ctx.v_air)\n        ctx.thrust_scale = ctx.thrust_scale * (1 + ctx.params["k_climb"] * vb[2])\n'
"""The audit's effect file (contract §6): each rotor's thrust times ``1 + k_climb vz_b``."""

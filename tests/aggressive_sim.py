"""Independent simulator of an aggressive 0.8 kg X quadrotor, by a blind audit (the tenth,
2026-12-04) that read only ``CONTRACT.md`` and the README: kept as a test generator that is not
greybox's own. Checked against ``greybox simulate --integrator cvodes`` on 2 s of strongly varying
speeds from a tilted, spinning start (base model, ``quadratic_drag``, ``motor_lag``): 1e-6 m
and 1e-7 rad apart, where leaving out the rotors' inertia alone moves them 0.19 m.

World NED, body FRD, quaternion state (scalar first, body->world), ZYX Euler for logging.
X layout: rotor1 (+a,+a) spin+1, 2 (-a,-a) +1, 3 (+a,-a) -1, 4 (-a,+a) -1, a = l/sqrt2.
Thrust K_T w^2 along body -z; reaction torque spin_i b w_i^2 about body +z;
gyroscopic J_r*Omega_r*(omega x e_z), Omega_r = sum(spin_i w_i); world-axis drag
-Kd v - Kq |v| v; first-order motors (20 ms) behind commands held for each 4 ms step.
``scipy.integrate.solve_ivp`` (DOP853, tolerances 1e-10) between the updates of its own
geometric (Lee) SE(3) controller at 250 Hz on the nominal airframe, a 2 % multisine on the
commands; flights with 55 degree tilts, 2-3 rad/s yaw turns, 2.5 m/s climbs, 7.7 m/s.

    from aggressive_sim import default_truth, fly, write_log
    t, S, W, ref = fly(truth, default_truth(), 30.0, 11, "est")
    write_log("F.csv", t, S, W, 11, acc=ref["acc"], wnoise=0.0)
"""
import numpy as np
from scipy.integrate import solve_ivp

G = 9.81


def default_truth():
    m = 0.8
    wh = 900.0
    K_T = m * G / (4 * wh ** 2)
    return dict(
        m=m, J=np.array([4e-3, 4.5e-3, 8e-3]), l=0.12, K_T=K_T, b=0.012 * K_T,
        Kd=np.array([0.1, 0.1, 0.15]), Kq=np.zeros(3), J_r=2.0e-6, tau_m=0.02,
        w_min=150.0, w_max=wh * np.sqrt(3.0), inflow=None,  # inflow: e.g. 0.02 -> T_i*(1 - vc/(0.02 w_i))
    )


def rotor_geometry(l):
    a = l / np.sqrt(2.0)
    pos = np.array([[a, a, 0.0], [-a, -a, 0.0], [a, -a, 0.0], [-a, a, 0.0]])
    spin = np.array([1.0, 1.0, -1.0, -1.0])
    return pos, spin


def quat_to_R(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def euler_to_quat(phi, th, psi):
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(th / 2), np.sin(th / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    return np.array([cy * cp * cr + sy * sp * sr, cy * cp * sr - sy * sp * cr,
                     cy * sp * cr + sy * cp * sr, sy * cp * cr - cy * sp * sr])


def R_to_euler(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    th = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, th, psi


def Rzyx(phi, th, psi):
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)
    Rz = np.array([[cp, -sp, 0], [sp, cp, 0], [0, 0, 1]])
    Ry = np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    Rx = np.array([[1, 0, 0], [0, cf, -sf], [0, sf, cf]])
    return Rz @ Ry @ Rx


class Quad:
    # state: pos(3) v(3) q(4) omega(3) w(4)  -> 17
    def __init__(self, truth, motor_lag=True):
        self.T = truth
        self.pos_r, self.spin = rotor_geometry(truth["l"])
        self.motor_lag = motor_lag

    def forces(self, s, wcmd):
        T = self.T
        v = s[3:6]
        q = s[6:10] / np.linalg.norm(s[6:10])
        om = s[10:13]
        w = s[13:17] if self.motor_lag else wcmd
        R = quat_to_R(q)
        thr = T["K_T"] * w ** 2
        if T["inflow"] is not None:
            vb = R.T @ v
            vc = -vb[2]  # climb speed along body -z
            thr = thr * (1.0 - vc / (T["inflow"] * w))
        F = R @ np.array([0.0, 0.0, -thr.sum()]) + T["m"] * G * np.array([0, 0, 1.0])
        F = F - T["Kd"] * v - T["Kq"] * np.linalg.norm(v) * v
        tau = np.zeros(3)
        for i in range(4):
            tau += np.cross(self.pos_r[i], np.array([0.0, 0.0, -thr[i]]))
        if T.get("torque_exp") is None:
            tau[2] += T["b"] * np.sum(self.spin * w ** 2)
        else:  # reaction torque b' w^n with b' = b w_h^(2-n): equal to b w^2 at hover
            n = T["torque_exp"]
            wh = np.sqrt(T["m"] * G / (4 * T["K_T"]))
            tau[2] += T["b"] * wh ** (2 - n) * np.sum(self.spin * w ** n)
        Om_r = np.sum(self.spin * w)
        tau += T["J_r"] * Om_r * np.cross(om, np.array([0.0, 0.0, 1.0]))
        return F, tau, R, q, w

    def rhs(self, t, s, wcmd):
        T = self.T
        F, tau, R, q, w = self.forces(s, wcmd)
        om = s[10:13]
        J = T["J"]
        dom = (tau - np.cross(om, J * om)) / J
        qw, qx, qy, qz = q
        p, qq, r = om
        dq = 0.5 * np.array([-qx * p - qy * qq - qz * r,
                             qw * p + qy * r - qz * qq,
                             qw * qq - qx * r + qz * p,
                             qw * r + qx * qq - qy * p])
        # keep the norm: gentle correction
        dq += 1.0 * (1 - np.dot(s[6:10], s[6:10])) * s[6:10]
        dw = (wcmd - s[13:17]) / T["tau_m"] if self.motor_lag else np.zeros(4)
        return np.concatenate([s[3:6], F / T["m"], dq, dom, dw])

    def step(self, s, wcmd, dt, method="DOP853", rtol=1e-10, atol=1e-10):
        sol = solve_ivp(self.rhs, (0.0, dt), s, method=method, rtol=rtol, atol=atol, args=(wcmd,))
        out = sol.y[:, -1].copy()
        out[6:10] /= np.linalg.norm(out[6:10])
        return out


def vee(M):
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


class Controller:
    """Geometric (Lee) SE(3) controller in NED/FRD with a mixer to rotor speeds."""

    def __init__(self, nom, wn_pos=4.0, wn_att=18.0, wn_yaw=6.0, max_tilt=55.0):
        self.max_tilt = max_tilt
        self.N = nom
        self.pos_r, self.spin = rotor_geometry(nom["l"])
        self.Kp = wn_pos ** 2
        self.Kv = 2 * 0.9 * wn_pos
        J = nom["J"]
        self.KR = np.array([J[0] * wn_att ** 2, J[1] * wn_att ** 2, J[2] * wn_yaw ** 2])
        self.Kw = np.array([2 * 0.8 * wn_att * J[0], 2 * 0.8 * wn_att * J[1], 2 * 0.9 * wn_yaw * J[2]])
        K_T, b = nom["K_T"], nom["b"]
        M = np.zeros((4, 4))
        M[0, :] = K_T
        M[1, :] = -self.pos_r[:, 1] * K_T
        M[2, :] = self.pos_r[:, 0] * K_T
        M[3, :] = self.spin * b
        self.Minv = np.linalg.inv(M)

    def __call__(self, s, ref):
        N = self.N
        pos, v = s[0:3], s[3:6]
        R = quat_to_R(s[6:10] / np.linalg.norm(s[6:10]))
        om = s[10:13]
        pr, vr, ar, psir, rr = ref
        e3 = np.array([0, 0, 1.0])
        acc = ar + self.Kp * (pr - pos) + self.Kv * (vr - v)
        ah = np.linalg.norm(acc[:2])
        amax = G * np.tan(np.radians(58.0))
        if ah > amax:
            acc[:2] *= amax / ah
        acc[2] = np.clip(acc[2], -1.2 * G, 0.75 * G)
        Fd = N["m"] * (acc - G * e3) + N["Kd"] * v  # desired non-gravity force, world
        Fd[2] = min(Fd[2], -0.3 * N["m"] * G)
        fh = np.linalg.norm(Fd[:2])
        fhmax = np.tan(np.radians(self.max_tilt)) * (-Fd[2])
        if fh > fhmax:
            Fd[:2] *= fhmax / fh
        nF = np.linalg.norm(Fd)
        b3d = -Fd / nF
        # limit tilt to 62 deg
        T = max(-Fd @ (R @ e3), 0.3 * N["m"] * G)
        b1c = np.array([np.cos(psir), np.sin(psir), 0.0])
        b2d = np.cross(b3d, b1c)
        b2d /= np.linalg.norm(b2d)
        b1d = np.cross(b2d, b3d)
        Rd = np.column_stack([b1d, b2d, b3d])
        eR = 0.5 * vee(Rd.T @ R - R.T @ Rd)
        omd = np.array([0.0, 0.0, rr])  # yaw-rate feed-forward (approx, body)
        ew = om - R.T @ Rd @ omd
        J = N["J"]
        tau = -self.KR * eR - self.Kw * ew + np.cross(om, J * om)
        lo, hi = N["w_min"] ** 2, N["w_max"] ** 2
        base = self.Minv @ np.array([T, tau[0], tau[1], 0.0])
        yaw = self.Minv @ np.array([0.0, 0.0, 0.0, tau[2]])
        base = np.clip(base, lo, hi)
        alpha = 1.0
        for i in range(4):  # yaw has the lowest priority
            if yaw[i] > 0 and base[i] + yaw[i] > hi:
                alpha = min(alpha, (hi - base[i]) / yaw[i])
            if yaw[i] < 0 and base[i] + yaw[i] < lo:
                alpha = min(alpha, (lo - base[i]) / yaw[i])
        w2 = np.clip(base + max(alpha, 0.0) * yaw, lo, hi)
        return np.sqrt(w2)


def smoothstep(t, t0, dur):
    x = np.clip((t - t0) / dur, 0, 1)
    return x ** 3 * (10 - 15 * x + 6 * x * x)


def make_reference(t, seed, kind):
    """Aggressive reference: fast figure-8 with climbs, sharp steps, fast yaw turns."""
    rng = np.random.default_rng(seed)
    n = len(t)
    p = np.zeros((n, 3))
    p[:, 2] = -2.0
    psi = np.zeros(n)
    if kind == "est":
        segs = [("hover", 0, 1.5), ("fig8", 1.5, 13.0), ("steps", 13.0, 21.0), ("fig8b", 21.0, 30.0)]
    else:
        segs = [("hover", 0, 1.0), ("fig8b", 1.0, 9.0), ("steps", 9.0, 15.0), ("fig8", 15.0, 20.0)]
    A = rng.uniform(2.5, 2.8)
    B = rng.uniform(0.9, 1.1)
    om = rng.uniform(1.3, 1.45)
    for name, t0, t1 in segs:
        m = (t >= t0) & (t < t1)
        tt = t[m] - t0
        ramp = smoothstep(t[m], t0, 1.0) * (1 - smoothstep(t[m], t1 - 1.0, 1.0))
        if name == "fig8":
            p[m, 0] = ramp * A * np.sin(om * tt)
            p[m, 1] = ramp * B * np.sin(2 * om * tt)
            p[m, 2] = -2.0 - ramp * 0.9 * np.sin(2.2 * tt)
        elif name == "fig8b":
            p[m, 0] = ramp * B * np.sin(2 * om * tt)
            p[m, 1] = ramp * A * np.sin(om * tt)
            p[m, 2] = -2.0 - ramp * 0.8 * np.sin(2.8 * tt + 0.5)
        elif name == "steps":
            k = int((t1 - t0 - 0.6) / 1.5)
            targets = rng.uniform([-1.8, -1.8, -3.0], [1.8, 1.8, -1.2], size=(k, 3))
            cur = np.array([0.0, 0.0, -2.0])
            pm = np.tile(cur, (m.sum(), 1))
            for j in range(k):
                sj = smoothstep(t[m], t0 + j * 1.5, 0.9)[:, None]
                pm = pm + sj * (targets[j] - (targets[j - 1] if j else cur))
            back = smoothstep(t[m], t1 - 0.6, 0.5)[:, None]
            p[m] = pm * (1 - back) + back * cur
    # yaw: fast turns (2-3 rad/s), several revolutions so psi crosses +-pi
    r = np.zeros(n)
    nturn = 6 if kind == "est" else 4
    starts = np.sort(rng.uniform(1.5, t[-1] - 3.0, nturn))
    for j, ts in enumerate(starts):
        rate = rng.uniform(2.0, 3.0) * (1 if j % 2 == 0 else -1)
        dur = rng.uniform(1.2, 2.5)
        r += rate * (smoothstep(t, ts, 0.7) - smoothstep(t, ts + dur, 0.7))
    dt = t[1] - t[0]
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * dt)])
    v = np.gradient(p, dt, axis=0)
    a = np.gradient(v, dt, axis=0)
    return p, v, a, psi, r


def multisine(t, seed, amp, nrot=4):
    rng = np.random.default_rng(seed + 1000)
    freqs = np.array([0.3, 0.7, 1.3, 2.1, 3.4, 5.3, 7.9, 11.3, 15.7, 21.1])
    out = np.zeros((len(t), nrot))
    for i in range(nrot):
        ph = rng.uniform(0, 2 * np.pi, len(freqs))
        s = np.sum(np.sin(2 * np.pi * freqs[None, :] * t[:, None] + ph[None, :]), axis=1)
        out[:, i] = amp * s / np.sqrt(len(freqs) / 2)
    return out


def fly(truth, nominal, T_end, seed, kind, dt=0.004, excite=0.02):
    quad = Quad(truth, motor_lag=True)
    ctl = Controller(nominal)
    t = np.arange(0.0, T_end + 1e-9, dt)
    pr, vr, ar, psir, rr = make_reference(t, seed, kind)
    ms = multisine(t, seed, excite)
    wh = np.sqrt(truth["m"] * G / (4 * truth["K_T"]))
    s = np.zeros(17)
    s[2] = -2.0
    s[6:10] = [1, 0, 0, 0]
    s[13:17] = wh
    n = len(t)
    S = np.zeros((n, 17))
    W = np.zeros((n, 4))
    ACC = np.zeros((n, 3))
    for k in range(n):
        S[k] = s
        wc = ctl(s, (pr[k], vr[k], ar[k], psir[k], rr[k]))
        wc = np.clip(wc * (1 + ms[k]), truth["w_min"], truth["w_max"])
        W[k] = wc
        F, _, Rk, _, _ = quad.forces(s, wc)
        ACC[k] = Rk.T @ (F - truth["m"] * G * np.array([0, 0, 1.0])) / truth["m"]
        if k < n - 1:
            s = quad.step(s, wc, dt)
    return t, S, W, dict(pr=pr, psir=psir, acc=ACC)


def write_log(path, t, S, W, seed, log_cmd=False, wrap_psi=True, noise=True, wnoise=0.005, acc=None, acc_noise=0.05):
    rng = np.random.default_rng(seed + 77)
    n = len(t)
    eul = np.array([R_to_euler(quat_to_R(S[k, 6:10])) for k in range(n)])
    if not wrap_psi:
        eul[:, 2] = np.unwrap(eul[:, 2])
    w = W.copy() if log_cmd else S[:, 13:17].copy()
    pos = S[:, 0:3].copy()
    om = S[:, 10:13].copy()
    if noise:
        if not log_cmd:
            w *= 1 + wnoise * rng.standard_normal(w.shape)
        pos += 0.001 * rng.standard_normal(pos.shape)
        eul += 0.002 * rng.standard_normal(eul.shape)
        om += 0.01 * rng.standard_normal(om.shape)
        if wrap_psi:
            eul[:, 2] = np.arctan2(np.sin(eul[:, 2]), np.cos(eul[:, 2]))
    cols = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r"]
    data = np.column_stack([t, w, pos, eul, om])
    if acc is not None:
        a = acc + (acc_noise * rng.standard_normal(acc.shape) if noise else 0)
        cols += ["ax", "ay", "az"]
        data = np.column_stack([data, a])
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for row in data:
            f.write(",".join("%.10g" % x for x in row) + "\n")


def write_airframe(path, truth, K_T, b, Kd, extra=""):
    with open(path, "w") as f:
        f.write(f"""[airframe]
name = "audit10_aggressive"
mass = {truth['m']}
inertia = [{truth['J'][0]}, {truth['J'][1]}, {truth['J'][2]}]
arm_length = {truth['l']}
layout = "x"
rotor_inertia = {truth['J_r']}
gravity = {G}

[parameters]
K_T = {K_T:.6e}
b = {b:.6e}
Kd = [{Kd[0]}, {Kd[1]}, {Kd[2]}]
{extra}""")

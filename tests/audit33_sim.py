"""Audit 33 simulator: a 0.85 kg "x" quadrotor on 7-inch props (numpy only).

Independent of greybox. Conventions from /work/shared/CONTRACT.md:
NED world, FRD body, ZYX Euler, layout "x": rotor 1 (+a,+a), 2 (-a,-a), 3 (+a,-a),
4 (-a,+a), a = l/sqrt(2), spin [+1,+1,-1,-1]. Thrust K_T w^2 along -z_body, reaction
torque spin*b*w^2 about +z_body, gyroscopic J_r*Omega_r*(omega x e_z).

Integrator: quaternion RK4 at 1 ms. Controller: 200 Hz geometric cascade whose internal
model is 5-10 % off. Motors: first-order lag. Log rows at 200 Hz.

    python sim.py data       # writes every file into data/
"""
import json
import os
import sys

import numpy as np

G = 9.81
DT = 0.001            # integrator step
ROW = 5               # integrator steps per log row (200 Hz)

TRUTH = dict(
    mass=0.85, J=[0.0065, 0.0070, 0.0125], l=0.16, K_T=4.5e-6, b=6.8e-8,
    Kd=[0.10, 0.11, 0.16], J_r=3.0e-5, tau_mot=0.015, w_max=1300.0, w_min=150.0,
)
A = TRUTH["l"] / np.sqrt(2.0)
RPOS = np.array([[A, A, 0.0], [-A, -A, 0.0], [A, -A, 0.0], [-A, A, 0.0]])
SPIN = np.array([1.0, 1.0, -1.0, -1.0])
E3 = np.array([0.0, 0.0, 1.0])


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def qrot(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler_from_R(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    theta = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, theta, psi


def q_from_euler(phi, theta, psi):
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(theta / 2), np.sin(theta / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


class Plant:
    """Truth dynamics. Options: Kq (quadratic drag, world axes), drift (K_T(t) =
    K_T (1 + drift t)), wind (horizontal world wind), motors (True: first-order lag
    towards the command; False: the input is the rotor speed itself, ZOH)."""

    def __init__(self, Kq=(0, 0, 0), drift=0.0, wind=(0, 0), tau_mot=None, motors=True):
        T = TRUTH
        self.m = T["mass"]
        self.J = np.diag(T["J"])
        self.Jinv = np.linalg.inv(self.J)
        self.K_T, self.b, self.J_r = T["K_T"], T["b"], T["J_r"]
        self.Kd = np.array(T["Kd"])
        self.Kq = np.array(Kq, float)
        self.drift = drift
        self.wind = np.array([wind[0], wind[1], 0.0])
        self.tau = T["tau_mot"] if tau_mot is None else tau_mot
        self.motors = motors

    def forces(self, s, u, t):
        """Non-gravitational world force (N), body torque, rotor speeds used."""
        v, q, om = s[3:6], s[6:10], s[10:13]
        w = s[13:17] if self.motors else u
        R = qrot(q)
        KT = self.K_T * (1.0 + self.drift * t)
        T = KT * w * w
        vair = v - self.wind
        F = R @ np.array([0.0, 0.0, -T.sum()]) - self.Kd * vair \
            - self.Kq * np.linalg.norm(vair) * vair
        tau = np.array([-(RPOS[:, 1] * T).sum(), (RPOS[:, 0] * T).sum(),
                        (SPIN * self.b * w * w).sum()])
        Om = (SPIN * w).sum()
        tau = tau + self.J_r * Om * np.array([om[1], -om[0], 0.0])
        return F, tau, R

    def deriv(self, s, u, t):
        v, q, om = s[3:6], s[6:10], s[10:13]
        F, tau, R = self.forces(s, u, t)
        ds = np.empty_like(s)
        ds[0:3] = v
        ds[3:6] = F / self.m + G * E3
        ds[6:10] = 0.5 * qmul(q, np.array([0.0, om[0], om[1], om[2]]))
        ds[10:13] = self.Jinv @ (tau - np.cross(om, self.J @ om))
        if self.motors:
            ds[13:17] = (u - s[13:17]) / self.tau
        else:
            ds[13:17] = 0.0
        return ds

    def step(self, s, u, t, h=DT):
        k1 = self.deriv(s, u, t)
        k2 = self.deriv(s + 0.5 * h * k1, u, t + 0.5 * h)
        k3 = self.deriv(s + 0.5 * h * k2, u, t + 0.5 * h)
        k4 = self.deriv(s + h * k3, u, t + h)
        s = s + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
        return s


# ---------------------------------------------------------------- reference
def minjerk(tau):
    tau = np.clip(tau, 0.0, 1.0)
    s = 10 * tau ** 3 - 15 * tau ** 4 + 6 * tau ** 5
    ds = 30 * tau ** 2 - 60 * tau ** 3 + 30 * tau ** 4
    dds = 60 * tau - 180 * tau ** 2 + 120 * tau ** 3
    return s, ds, dds


def make_reference(seed, duration):
    """Segments of min-jerk moves (x, y, z, psi) between random waypoints, with fast
    crossings of the box, climbs and yaw turns. Returns a function t -> (p, v, a, psi, r)."""
    rng = np.random.default_rng(seed)
    segs = []                       # (t0, T, start(4), end(4))
    cur = np.array([0.0, 0.0, -1.5, 0.0])
    t = 2.0                         # hover first
    kinds = ["fast", "step", "climb", "yaw", "fast", "diag", "step"]
    i = 0
    while t < duration - 3.0:
        kind = kinds[rng.integers(len(kinds))] if i > 0 else "step"
        i += 1
        tgt = cur.copy()
        if kind == "fast":
            ax = rng.integers(2)
            lim = 4.0 if ax == 0 else 3.0
            tgt[ax] = -np.sign(cur[ax] if abs(cur[ax]) > 0.5 else rng.choice([-1, 1])) * lim * rng.uniform(0.8, 1.0)
            T = rng.uniform(2.0, 2.6)
        elif kind == "diag":
            tgt[0] = rng.uniform(-3.5, 3.5)
            tgt[1] = rng.uniform(-2.5, 2.5)
            tgt[3] = cur[3] + rng.uniform(-0.8, 0.8)
            T = rng.uniform(1.8, 2.6)
        elif kind == "climb":
            tgt[2] = -1.0 - rng.uniform(0.2, 2.0)
            tgt[0] += rng.uniform(-1.0, 1.0)
            T = rng.uniform(1.5, 2.2)
        elif kind == "yaw":
            tgt[3] = np.clip(cur[3] + rng.choice([-1, 1]) * rng.uniform(0.8, 1.5), -2.0, 2.0)
            tgt[1] += rng.uniform(-1.0, 1.0)
            T = rng.uniform(1.5, 2.5)
        else:
            tgt[0] = np.clip(cur[0] + rng.uniform(-2.0, 2.0), -4, 4)
            tgt[1] = np.clip(cur[1] + rng.uniform(-2.0, 2.0), -3, 3)
            tgt[2] = np.clip(cur[2] + rng.uniform(-0.6, 0.6), -3.0, -1.0)
            T = rng.uniform(1.2, 2.0)
        T = min(T, duration - 1.0 - t)
        segs.append((t, T, cur.copy(), tgt.copy()))
        cur = tgt
        t += T + rng.uniform(0.2, 0.9)
    segs = np.array([(s[0], s[1]) for s in segs]), [s[2] for s in segs], [s[3] for s in segs]
    times, starts, ends = segs

    def ref(tt):
        k = np.searchsorted(times[:, 0], tt, side="right") - 1
        if k < 0:
            p0 = starts[0]
            return p0[:3], np.zeros(3), np.zeros(3), p0[3], 0.0
        t0, T = times[k]
        s, ds, dds = minjerk((tt - t0) / T)
        d = ends[k] - starts[k]
        pos = starts[k] + s * d
        if tt > t0 + T:
            ds, dds = 0.0, 0.0
        vel = d * ds / T
        acc = d * dds / T ** 2
        return pos[:3], vel[:3], acc[:3], pos[3], vel[3]
    return ref


def multisine(seed, n=6, fmin=0.3, fmax=9.0):
    rng = np.random.default_rng(seed + 1000)
    f = np.exp(rng.uniform(np.log(fmin), np.log(fmax), size=(4, n)))
    ph = rng.uniform(0, 2 * np.pi, size=(4, n))
    amp = np.array([0.25, 0.012, 0.012, 0.003]) / np.sqrt(n / 2.0)   # N, N m

    def u(t):
        return amp * np.sin(2 * np.pi * f * t + ph).sum(axis=1)
    return u


# ---------------------------------------------------------------- controller
class Controller:
    """Geometric cascade at 200 Hz. Internal model 5-10 % off the truth."""

    def __init__(self):
        T = TRUTH
        self.m = T["mass"] * 0.94
        self.J = np.diag(T["J"]) * np.array([1.08, 0.93, 1.10])
        self.K_T = T["K_T"] * 1.07
        self.b = T["b"] * 0.91
        a = T["l"] * 1.05 / np.sqrt(2)
        rp = np.array([[a, a], [-a, -a], [a, -a], [-a, a]])
        M = np.vstack([np.full(4, self.K_T), -rp[:, 1] * self.K_T, rp[:, 0] * self.K_T,
                       SPIN * self.b])
        self.Minv = np.linalg.inv(M)
        self.ei = np.zeros(3)
        self.kp, self.kv, self.ki = np.array([4.0, 4.0, 6.0]), np.array([3.6, 3.6, 4.5]), np.array([0.6, 0.6, 1.0])
        self.kR, self.kW = np.array([110.0, 110.0, 30.0]), np.array([19.0, 19.0, 9.0])

    def __call__(self, p, v, R, om, ref, exc, dt=ROW * DT):
        pr, vr, ar, psir, rr = ref
        ep, ev = pr - p, vr - v
        self.ei = np.clip(self.ei + ep * dt, -2.0, 2.0)
        acc = ar + self.kp * ep + self.kv * ev + self.ki * self.ei
        f = self.m * (acc - G * E3)                        # required non-grav force, world
        zb = -f / np.linalg.norm(f)
        tilt = np.arccos(np.clip(zb[2], -1, 1))
        if tilt > 0.8:                                     # limit tilt to ~46 deg
            h = zb[:2] / np.linalg.norm(zb[:2]) * np.sin(0.8)
            zb = np.array([h[0], h[1], np.cos(0.8)])
        xc = np.array([np.cos(psir), np.sin(psir), 0.0])
        yb = np.cross(zb, xc)
        yb /= np.linalg.norm(yb)
        xb = np.cross(yb, zb)
        Rd = np.column_stack([xb, yb, zb])
        T = -f @ (R @ E3)
        T = max(T, 0.3 * self.m * G)
        eRm = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([eRm[2, 1], eRm[0, 2], eRm[1, 0]])
        omd = np.array([0.0, 0.0, rr])
        alpha = -self.kR * eR - self.kW * (om - R.T @ Rd @ omd)
        tau = self.J @ alpha + np.cross(om, self.J @ om)
        u = np.concatenate([[T], tau]) + exc
        w2 = self.Minv @ u
        w2 = np.clip(w2, TRUTH["w_min"] ** 2, TRUTH["w_max"] ** 2)
        return np.sqrt(w2)


class Mahony:
    """Complementary (Mahony) roll/pitch filter: gyro integration corrected toward the
    accelerometer's 'up'. kp in rad/s."""

    def __init__(self, q0, kp):
        self.R = qrot(q0)
        self.kp = kp

    def update(self, gyro, acc, dt):
        a = acc / np.linalg.norm(acc)                      # ~ -R^T e3 when unaccelerated
        vhat = -self.R.T @ E3
        e = np.cross(a, vhat)
        w = gyro + self.kp * e
        th = np.linalg.norm(w) * dt
        if th > 0:
            k = w / np.linalg.norm(w)
            K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
            self.R = self.R @ (np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K)
        U, _, Vt = np.linalg.svd(self.R)
        self.R = U @ Vt


# ---------------------------------------------------------------- flights
NOISE = dict(w=0.5, att=0.002, gyro=0.004, acc=0.05, pos=0.0015)


def fly(seed, duration, plant, log_commands=False, tau_pos=0.0, mahony_kp=None):
    rng = np.random.default_rng(seed)
    ref = make_reference(seed, duration)
    exc = multisine(seed)
    ctrl = Controller()
    wh = np.sqrt(TRUTH["mass"] * G / (4 * TRUTH["K_T"]))
    p0, _, _, psi0, _ = ref(0.0)
    s = np.zeros(17)
    s[0:3] = p0
    s[6:10] = q_from_euler(0.0, 0.0, psi0)
    s[13:17] = wh
    nrow = int(round(duration / (ROW * DT))) + 1
    nstep = (nrow - 1) * ROW
    hist_p = np.zeros((nstep + 1, 3))
    hist_p[0] = s[0:3]
    rows = []
    filt = Mahony(s[6:10], mahony_kp) if mahony_kp is not None else None
    # vision: 100 Hz (every 2nd row), 2 % frames lost, two 0.15-s outages
    out_starts = rng.uniform(3.0, duration - 3.0, size=2)
    k = 0
    for r in range(nrow):
        t = r * ROW * DT
        F, tau, R = plant.forces(s, s[13:17], t)
        sf = R.T @ F / plant.m                               # specific force, body
        om = s[10:13]
        gyro = om + rng.normal(0, NOISE["gyro"], 3)
        accm = sf + rng.normal(0, NOISE["acc"], 3)
        phi, th, psi = euler_from_R(R)
        if filt is not None:
            if r > 0:
                filt.update(gyro, accm, ROW * DT)
            fphi, fth, _ = euler_from_R(filt.R)
            Rc = qrot(q_from_euler(fphi, fth, psi))          # controller sees the filter
        else:
            Rc = R
        wcmd = ctrl(s[0:3], s[3:6], Rc, gyro, ref(t), exc(t))
        if r > 0 and filt is not None:
            pass
        row = {"t": t}
        wlog = wcmd if log_commands else s[13:17] + rng.normal(0, NOISE["w"], 4)
        for i in range(4):
            row[f"w{i + 1}"] = wlog[i]
        vis = (r % 2 == 0) and rng.uniform() > 0.02 and not np.any(np.abs(t - out_starts - 0.075) < 0.075)
        if vis:
            kk = int(round((t - tau_pos) / DT))
            pp = hist_p[max(kk, 0)] if kk <= k else s[0:3]
            if kk < 0:
                pp = p0
            pm = pp + rng.normal(0, NOISE["pos"], 3)
            row.update(x=pm[0], y=pm[1], z=pm[2])
        else:
            row.update(x=np.nan, y=np.nan, z=np.nan)
        if filt is not None:
            row.update(phi=fphi + rng.normal(0, 0.5 * NOISE["att"]),
                       theta=fth + rng.normal(0, 0.5 * NOISE["att"]),
                       psi=psi + rng.normal(0, NOISE["att"]))
        else:
            row.update(phi=phi + rng.normal(0, NOISE["att"]), theta=th + rng.normal(0, NOISE["att"]),
                       psi=psi + rng.normal(0, NOISE["att"]))
        row.update(p=gyro[0], q=gyro[1], r=gyro[2], ax=accm[0], ay=accm[1], az=accm[2])
        # hidden truth for the report (not written to the log)
        row["_true_phi"], row["_true_theta"] = phi, th
        row["_speed"] = np.linalg.norm(s[3:6])
        row["_wmax"] = s[13:17].max()
        rows.append(row)
        if r == nrow - 1:
            break
        for j in range(ROW):
            hist_p[k] = s[0:3]
            s = plant.step(s, wcmd, k * DT)
            k += 1
        hist_p[k] = s[0:3]
        if not np.all(np.isfinite(s)) or s[2] > 0.0:
            raise RuntimeError(f"flight seed {seed} diverged at t={t}")
    return rows


COLS = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r",
        "ax", "ay", "az"]


def write_log(path, rows):
    with open(path, "w") as f:
        f.write(",".join(COLS) + "\n")
        for row in rows:
            cells = []
            for c in COLS:
                v = row[c]
                cells.append("" if not np.isfinite(v) else repr(float(v)))
            f.write(",".join(cells) + "\n")


def stats(rows):
    sp = np.array([r["_speed"] for r in rows])
    wm = np.array([r["_wmax"] for r in rows])
    tilt = np.array([np.hypot(r["_true_phi"], r["_true_theta"]) for r in rows])
    d = dict(max_speed=float(sp.max()), max_rotor=float(wm.max()), max_tilt=float(tilt.max()))
    if "_true_phi" in rows[0]:
        ep = np.array([r["phi"] - r["_true_phi"] for r in rows])
        et = np.array([r["theta"] - r["_true_theta"] for r in rows])
        d["att_err_rms"] = [float(np.sqrt(np.mean(ep ** 2))), float(np.sqrt(np.mean(et ** 2)))]
        d["att_err_max"] = [float(np.abs(ep).max()), float(np.abs(et).max())]
    return d


AIRFRAME = """[airframe]
name = "audit33_7inch_x"
mass = 0.85
inertia = [0.0065, 0.0070, 0.0125]
arm_length = 0.16
layout = "x"
rotor_inertia = 3.0e-5
gravity = 9.81

[parameters]
K_T = 5.85e-6      # guess: +30 %
b = 4.76e-8        # guess: -30 %
Kd = [0.05, 0.05, 0.08]
"""

CASES = {
    # name: (plant kwargs, fly kwargs)
    "control": (dict(), dict()),
    "two": (dict(Kq=(0.04, 0.04, 0.04), drift=-0.0015), dict()),
    "three": (dict(wind=(1.8, -1.2), tau_mot=0.035), dict(log_commands=True, tau_pos=0.030)),
    "estimator": (dict(), dict(mahony_kp=0.25)),
}
SEEDS = {"control": (11, 12), "two": (21, 22), "three": (31, 32), "estimator": (41, 42)}


def check(outdir):
    """Open-loop convention check: rotor speeds held (ZOH) per 5-ms row, no motor model."""
    rng = np.random.default_rng(5)
    plant = Plant(motors=False)
    wh = np.sqrt(TRUTH["mass"] * G / (4 * TRUTH["K_T"]))
    n = 801                                             # 4 s at 200 Hz
    t = np.arange(n) * ROW * DT
    base = wh * (1.0 + 0.04 * np.sin(2 * np.pi * 0.7 * t))
    W = np.empty((n, 4))
    for i in range(4):
        f = rng.uniform(0.5, 3.0, 3)
        ph = rng.uniform(0, 2 * np.pi, 3)
        W[:, i] = base + 12.0 * np.sin(2 * np.pi * f[:, None] * t + ph[:, None]).sum(axis=0)
    x0 = np.array([0.3, -0.2, -2.0, 0.1, -0.05, 0.4, 1.0, -0.5, 0.2, 0.3, -0.2, 0.5])
    s = np.zeros(17)
    s[0:3] = x0[0:3]
    s[6:10] = q_from_euler(*x0[3:6])
    s[3:6] = x0[6:9]
    s[10:13] = x0[9:12]
    out = []
    for r in range(n):
        R = qrot(s[6:10])
        phi, th, psi = euler_from_R(R)
        out.append([t[r], *s[0:3], phi, th, psi, *s[10:13]])
        if r == n - 1:
            break
        for j in range(ROW):
            s = plant.step(s, W[r], t[r] + j * DT)
    with open(os.path.join(outdir, "check_inputs.csv"), "w") as f:
        f.write("t,w1,w2,w3,w4\n")
        for r in range(n):
            f.write(",".join(repr(float(v)) for v in [t[r], *W[r]]) + "\n")
    with open(os.path.join(outdir, "check_truth.csv"), "w") as f:
        f.write("t,x,y,z,phi,theta,psi,p,q,r\n")
        for o in out:
            f.write(",".join(repr(float(v)) for v in o) + "\n")
    with open(os.path.join(outdir, "check_x0.txt"), "w") as f:
        f.write(",".join(repr(float(v)) for v in x0))


def main():
    if len(sys.argv) < 2 or sys.argv[1] != "data":
        print(__doc__)
        sys.exit(1)
    out = "data"
    os.makedirs(out, exist_ok=True)
    only = sys.argv[2:] or list(CASES) + ["check"]
    with open(os.path.join(out, "af.toml"), "w") as f:
        f.write(AIRFRAME)
    if "check" in only:
        check(out)
    summary = {}
    for name in CASES:
        if name not in only:
            continue
        pk, fk = CASES[name]
        for tag, seed, dur in (("est", SEEDS[name][0], 40.0), ("val", SEEDS[name][1], 30.0)):
            rows = fly(seed, dur, Plant(**pk), **fk)
            write_log(os.path.join(out, f"{name}_{tag}.csv"), rows)
            summary[f"{name}_{tag}"] = dict(seed=seed, duration=dur, **stats(rows))
            print(name, tag, summary[f"{name}_{tag}"], flush=True)
    truth = dict(TRUTH, cases={k: dict(plant=v[0], fly=v[1]) for k, v in CASES.items()},
                 noise=NOISE, flights=summary)
    p = os.path.join(out, "truth.json")
    if os.path.exists(p) and len(only) < len(CASES) + 1:
        old = json.load(open(p))
        old.get("flights", {}).update(summary)
        truth["flights"] = old.get("flights", summary)
    with open(p, "w") as f:
        json.dump(truth, f, indent=1)


if __name__ == "__main__":
    main()

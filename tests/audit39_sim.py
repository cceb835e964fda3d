#!/usr/bin/env python3
"""Blind audit 39: an independent quadrotor simulator (not greybox's) for flights that do or do
not contain the information greybox needs.

    python sim.py OUTDIR        # writes every flight (CSV), the airframe (TOML) and truth.json

Deterministic: every flight has its own fixed seed; the output is bit for bit reproducible.

TRUTH (SI units, greybox's conventions: NED world, FRD body, ZYX Euler, layout "x")
  mass            1.20 kg
  inertia         Jx 0.0110, Jy 0.0120, Jz 0.0210 kg m^2 (diagonal)
  arm             0.225 m (hub distance from the centre), layout "x":
                  rotor1 (+a,+a) spin +1, rotor2 (-a,-a) +1, rotor3 (+a,-a) -1, rotor4 (-a,+a) -1
  K_T             6.0e-6  N/(rad/s)^2   (hover ~700 rad/s, 8-inch props)
  b               9.0e-8  N m/(rad/s)^2 (b/K_T = 15 mm)
  Kd              [0.14, 0.14, 0.20] N s/m, world-frame linear drag
  J_r             1.5e-5 kg m^2 (rotor gyroscopic)
  gravity         9.81
  motors          first-order lag 25 ms from command to actual speed, 120..1150 rad/s
Hidden effect (flight "noyawasym" only): rotor 1's reaction-torque coefficient is 1.35 b
(a yaw-torque asymmetry; greybox's model has one b for every rotor).

AIRFRAME given to greybox (airframe.toml): mass, inertia, arm, J_r exact; starting guesses
  K_T 6.9e-6 (x1.15), b 6.3e-8 (x0.7), Kd [0.07, 0.07, 0.10] (x0.5: truth is 2x the guess).

Dynamics: rigid body, unit quaternion, fixed-step RK4 at 1 ms (motor states integrated with it).
Controller (500 Hz, geometric SE(3), on noisy state estimates): its internal model is off the
  truth: mass +7 %, inertia -8 %, K_T -5 %, b +10 %; position loop wn 2 rad/s with an integral
  term, attitude wn 18 rad/s (roll/pitch), 7 rad/s (yaw); its own mixer from its own model.
Sensors on 200 Hz rows (t = k * 5 ms):
  rotor speeds w1..w4: ESC telemetry of the ACTUAL speed, noise 1.0 rad/s, quantised to 10 RPM
  position x,y,z: motion capture at 100 Hz (every other row, the others empty), noise 1.5 mm
  attitude phi,theta,psi: 200 Hz, noise 2 mrad, psi wrapped to (-pi, pi]
  gyro p,q,r: 200 Hz, noise 5 mrad/s
  accelerometer ax,ay,az: specific force R^T(dv/dt - g e3), noise 0.05 m/s^2
Flight plans (each estimation flight has a validation flight of the same kind, other seed):
  rich, hover, noyaw, slow (all speeds < 0.3 m/s), vertical, short (6 s of the rich kind),
  noyawasym (noyaw with the hidden yaw-torque asymmetry).
  Control variants *_cleanesc: the slow flights, hover_est and vertical_est again with noise-free, unquantised rotor speeds.
"""
import json
import math
import os
import sys

import numpy as np

# ----------------------------------------------------------------------------- truth
G = 9.81
MASS = 1.20
J = np.diag([0.0110, 0.0120, 0.0210])
ARM = 0.225
A = ARM / math.sqrt(2.0)
POS = np.array([[+A, +A, 0.0], [-A, -A, 0.0], [+A, -A, 0.0], [-A, +A, 0.0]])
SPIN = np.array([+1.0, +1.0, -1.0, -1.0])
K_T = 6.0e-6
B = 9.0e-8
KD = np.array([0.14, 0.14, 0.20])
J_R = 1.5e-5
TAU_MOTOR = 0.025
W_MIN, W_MAX = 120.0, 1150.0

GUESS = {"K_T": K_T * 1.15, "b": B * 0.7, "Kd": list(KD * 0.5)}

# controller's model (off the truth)
C_MASS = MASS * 1.07
C_J = J * 0.92
C_KT = K_T * 0.95
C_B = B * 1.10

DT = 0.001          # integration step
CTRL_EVERY = 2      # 500 Hz controller
ROW_EVERY = 5       # 200 Hz rows
POS_EVERY = 2       # mocap on every other row (100 Hz)

NOISE = dict(pos=0.0015, att=0.002, gyro=0.005, acc=0.05, w=1.0)
W_QUANT = 10.0 * 2.0 * math.pi / 60.0  # 10 RPM


def hat(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def quat_to_R(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler_from_R(R):
    phi = math.atan2(R[2, 1], R[2, 2])
    theta = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    psi = math.atan2(R[1, 0], R[0, 0])
    return phi, theta, psi


def quat_from_euler(phi, theta, psi):
    cr, sr = math.cos(phi / 2), math.sin(phi / 2)
    cp, sp = math.cos(theta / 2), math.sin(theta / 2)
    cy, sy = math.cos(psi / 2), math.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


class Plant:
    def __init__(self, b_scale=None):
        self.bvec = B * np.ones(4) if b_scale is None else B * np.asarray(b_scale)

    def deriv(self, s, wcmd):
        v = s[3:6]
        q = s[6:10]
        om = s[10:13]
        w = s[13:17]
        R = quat_to_R(q)
        w2 = w * w
        T = K_T * w2
        f_body = np.array([0.0, 0.0, -T.sum()])
        acc = (R @ f_body - KD * v) / MASS + np.array([0.0, 0.0, G])
        tau = np.array([np.sum(-POS[:, 1] * T), np.sum(POS[:, 0] * T),
                        np.sum(SPIN * self.bvec * w2)])
        om_r = np.sum(SPIN * w)
        tau = tau + J_R * om_r * np.cross(om, np.array([0.0, 0.0, 1.0]))
        domega = np.linalg.solve(J, tau - np.cross(om, J @ om))
        wx, wy, wz = om
        Om = np.array([[0, -wx, -wy, -wz], [wx, 0, wz, -wy], [wy, -wz, 0, wx], [wz, wy, -wx, 0]])
        dq = 0.5 * Om @ q
        dw = (wcmd - w) / TAU_MOTOR
        return np.concatenate([v, acc, dq, domega, dw]), acc, R


class Controller:
    def __init__(self):
        # mixer of the controller's own model: [T, tx, ty, tz] = M w^2
        M = np.vstack([C_KT * np.ones(4), -POS[:, 1] * C_KT, POS[:, 0] * C_KT, SPIN * C_B])
        self.Minv = np.linalg.inv(M)
        self.zint = 0.0
        self.xyint = np.zeros(2)

    def __call__(self, p, v, R, om, ref, dt):
        pr, vr, ar, psir = ref
        ep = pr - p
        ev = vr - v
        self.xyint += 0.3 * ep[:2] * dt
        self.zint += 1.0 * ep[2] * dt
        a_des = 4.0 * ep + 3.2 * ev + ar + np.array([self.xyint[0], self.xyint[1], self.zint])
        f_des = C_MASS * (a_des - np.array([0.0, 0.0, G]))
        T = max(0.0, -f_des @ R[:, 2])
        b3 = -f_des / np.linalg.norm(f_des)
        b1c = np.array([math.cos(psir), math.sin(psir), 0.0])
        b2 = np.cross(b3, b1c)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        E = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([E[2, 1], E[0, 2], E[1, 0]])
        wn = np.array([18.0, 18.0, 7.0])
        KR = np.diag(C_J) * wn ** 2
        KW = np.diag(C_J) * 2 * 0.8 * wn
        tau = -KR * eR - KW * om + np.cross(om, C_J @ om)
        w2 = self.Minv @ np.array([T, tau[0], tau[1], tau[2]])
        w2 = np.clip(w2, W_MIN ** 2, W_MAX ** 2)
        return np.sqrt(w2)


# ----------------------------------------------------------------------------- flight plans
def sstep(t, t0, T):
    """quintic smooth step 0 -> 1 over [t0, t0+T]"""
    x = np.clip((t - t0) / T, 0.0, 1.0)
    return x ** 3 * (10 - 15 * x + 6 * x * x)


Z0 = -1.5  # 1.5 m above the ground (NED)


def plan(kind, seed, duration):
    """reference position (NED) and heading as functions of t (vectorised)."""
    rng = np.random.default_rng(1000 + seed)

    def steps(t, items):
        out = np.zeros_like(t)
        for t0, T, amp in items:
            out = out + amp * sstep(t, t0, T)
        return out

    if kind in ("rich", "short"):
        # steps, a circle, yaw turns, climbs; order shuffled by seed
        s = rng.uniform(0.8, 1.2)
        off = rng.uniform(0, 0.5)

        def f(t):
            env = sstep(t, 9.0 + off, 1.0) - sstep(t, 17.0 + off, 1.0)
            om = 1.3 * s
            x = steps(t, [(1.0, 1.2, 1.2 * s), (5.0, 1.2, -1.2 * s), (20.0, 1.0, 0.8)]) \
                + env * 0.9 * (np.cos(om * (t - 9.0)) - 1.0)
            y = steps(t, [(2.5, 1.2, -1.0 * s), (6.5, 1.0, 1.0 * s), (22.0, 1.0, -0.8)]) \
                + env * 0.9 * np.sin(om * (t - 9.0))
            z = Z0 + steps(t, [(3.5, 1.5, -0.8), (7.0, 1.5, 0.8), (18.5, 1.2, 0.6), (24.0, 1.5, -0.6)])
            psi = steps(t, [(1.5, 1.2, 1.4 * s), (4.0, 1.2, -2.0), (8.0, 1.0, 0.6), (13.0, 2.0, 2.5),
                            (19.5, 1.5, -2.5), (23.0, 1.0, 1.0 * s)])
            return x, y, z, psi
        return f
    if kind == "hover":
        # position hold: a few centimetre setpoint nudges, heading held
        nud = [(rng.uniform(1, duration - 2), 1.5, rng.normal(0, 0.03, 3)) for _ in range(8)]
        psi0 = rng.uniform(-0.5, 0.5)

        def f(t):
            x = steps(t, [(a, b, c[0]) for a, b, c in nud])
            y = steps(t, [(a, b, c[1]) for a, b, c in nud])
            z = Z0 + steps(t, [(a, b, c[2]) for a, b, c in nud])
            return x, y, z, psi0 + 0 * t
        return f
    if kind in ("noyaw", "noyawasym"):
        s = rng.uniform(0.8, 1.2)
        psi0 = rng.uniform(-0.5, 0.5)

        def f(t):
            env = sstep(t, 9.0, 1.0) - sstep(t, 17.0, 1.0)
            om = 1.3 * s
            x = steps(t, [(1.0, 1.2, 1.2 * s), (5.0, 1.2, -1.2 * s), (20.0, 1.0, 0.8)]) \
                + env * 0.9 * (np.cos(om * (t - 9.0)) - 1.0)
            y = steps(t, [(2.5, 1.2, -1.0 * s), (6.5, 1.0, 1.0 * s), (22.0, 1.0, -0.8)]) \
                + env * 0.9 * np.sin(om * (t - 9.0))
            z = Z0 + steps(t, [(3.5, 1.5, -0.8), (7.0, 1.5, 0.8), (18.5, 1.2, 0.6)])
            return x, y, z, psi0 + 0 * t
        return f
    if kind == "slow":
        # the same kinds of motion, but slowly: every speed below 0.3 m/s; slow yaw turns too
        s = rng.uniform(0.8, 1.2)

        def f(t):
            x = steps(t, [(1.0, 6.0, 0.8 * s), (12.0, 6.0, -0.8 * s)])
            y = steps(t, [(4.0, 6.0, -0.7 * s), (15.0, 5.0, 0.7 * s)])
            z = Z0 + steps(t, [(2.0, 5.0, -0.6), (9.0, 5.0, 0.6)])
            psi = steps(t, [(1.0, 3.0, 1.2 * s), (6.0, 3.0, -1.8), (11.0, 3.0, 1.0), (17.0, 3.0, -0.8)])
            return x, y, z, psi
        return f
    if kind == "vertical":
        psi0 = rng.uniform(-0.5, 0.5)
        s = rng.uniform(0.8, 1.2)

        def f(t):
            z = Z0 + steps(t, [(1.0, 1.5, -1.0 * s), (4.0, 1.2, 0.8), (7.0, 1.5, -0.6), (10.0, 1.0, 0.9 * s),
                               (13.0, 1.5, -1.2), (16.5, 1.2, 1.0), (19.5, 1.0, -0.5), (22.0, 1.5, 0.6)])
            return 0 * t, 0 * t, z, psi0 + 0 * t
        return f
    raise ValueError(kind)


FLIGHTS = [  # name, kind, seed, duration
    ("rich_est", "rich", 11, 30.0), ("rich_val", "rich", 12, 25.0),
    ("hover_est", "hover", 21, 25.0), ("hover_val", "hover", 22, 20.0),
    ("noyaw_est", "noyaw", 31, 25.0), ("noyaw_val", "noyaw", 32, 20.0),
    ("slow_est", "slow", 41, 25.0), ("slow_val", "slow", 42, 20.0),
    ("vertical_est", "vertical", 51, 25.0), ("vertical_val", "vertical", 52, 20.0),
    ("short_est", "short", 61, 6.0), ("short_val", "short", 62, 6.0),
    ("noyawasym_est", "noyawasym", 71, 25.0), ("noyawasym_val", "noyawasym", 72, 20.0),
    # control variants: the same flights (same seeds, same trajectory and other sensors) with the
    # ESC telemetry noise-free and unquantised (the noise is still drawn, multiplied by zero)
    ("slow_est_cleanesc", "slow", 41, 25.0), ("slow_val_cleanesc", "slow", 42, 20.0),
    ("hover_est_cleanesc", "hover", 21, 25.0), ("vertical_est_cleanesc", "vertical", 51, 25.0),
]


def simulate(kind, seed, duration, clean_esc=False):
    rng = np.random.default_rng(seed)
    plant = Plant(b_scale=[1.35, 1.0, 1.0, 1.0] if kind == "noyawasym" else None)
    ctrl = Controller()
    f = plan(kind, seed, duration)
    # reference derivatives by finite differences on a fine grid
    tg = np.arange(0.0, duration + 0.5, DT)
    xr, yr, zr, psr = f(tg)
    P = np.vstack([xr, yr, zr]).T
    V = np.gradient(P, DT, axis=0)
    Acc = np.gradient(V, DT, axis=0)

    wh = math.sqrt(MASS * G / (4 * K_T))
    s = np.zeros(17)
    s[0:3] = P[0]
    s[6:10] = quat_from_euler(0.0, 0.0, psr[0])
    s[13:17] = wh
    n = int(round(duration / DT))
    wcmd = np.full(4, wh)
    rows = []
    tq_noise = np.zeros(3)
    for k in range(n + 1):
        t = k * DT
        if k % CTRL_EVERY == 0:
            R = quat_to_R(s[6:10])
            pn = s[0:3] + rng.normal(0, 0.001, 3)
            vn = s[3:6] + rng.normal(0, 0.01, 3)
            omn = s[10:13] + rng.normal(0, NOISE["gyro"], 3)
            ang = np.array(euler_from_R(R)) + rng.normal(0, 0.0015, 3)
            Rn = quat_to_R(quat_from_euler(*ang))
            wcmd = ctrl(pn, vn, Rn, omn, (P[k], V[k], Acc[k], psr[k]), CTRL_EVERY * DT)
        if k % ROW_EVERY == 0:
            d, acc, R = plant.deriv(s, wcmd)
            phi, theta, psi = euler_from_R(R)
            sf = R.T @ (acc - np.array([0.0, 0.0, G]))
            i = k // ROW_EVERY
            wn_ = rng.normal(0, NOISE["w"], 4)
            if clean_esc:
                wl = s[13:17] + 0.0 * wn_
            else:
                wl = np.round((s[13:17] + wn_) / W_QUANT) * W_QUANT
            row = {"t": i * ROW_EVERY * DT}
            for j in range(4):
                row[f"w{j + 1}"] = wl[j]
            if i % POS_EVERY == 0:
                pm = s[0:3] + rng.normal(0, NOISE["pos"], 3)
                row.update(x=pm[0], y=pm[1], z=pm[2])
            else:
                row.update(x=None, y=None, z=None)
            att = np.array([phi, theta, psi]) + rng.normal(0, NOISE["att"], 3)
            att[2] = math.atan2(math.sin(att[2]), math.cos(att[2]))
            row.update(phi=att[0], theta=att[1], psi=att[2])
            g = s[10:13] + rng.normal(0, NOISE["gyro"], 3)
            row.update(p=g[0], q=g[1], r=g[2])
            a = sf + rng.normal(0, NOISE["acc"], 3)
            row.update(ax=a[0], ay=a[1], az=a[2])
            row["_v"] = s[3:6].copy()
            rows.append(row)
        if k == n:
            break
        # RK4
        k1, _, _ = plant.deriv(s, wcmd)
        k2, _, _ = plant.deriv(s + 0.5 * DT * k1, wcmd)
        k3, _, _ = plant.deriv(s + 0.5 * DT * k2, wcmd)
        k4, _, _ = plant.deriv(s + DT * k3, wcmd)
        s = s + DT / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
    return rows


COLS = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az"]


def write_csv(path, rows):
    with open(path, "w") as fh:
        fh.write(",".join(COLS) + "\n")
        for r in rows:
            cells = []
            for c in COLS:
                v = r[c]
                cells.append("" if v is None else ("%.4f" % v if c == "t" else "%.9g" % v))
            fh.write(",".join(cells) + "\n")


AIRFRAME = """[airframe]
name = "audit39_x12"
mass = {mass}
inertia = [{jx}, {jy}, {jz}]
arm_length = {arm}
layout = "x"
rotor_inertia = {jr}
gravity = {g}

[parameters]
K_T = {kt:.6g}
b = {b:.6g}
Kd = [{kd0:.6g}, {kd1:.6g}, {kd2:.6g}]
"""


def main(out):
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "airframe.toml"), "w") as fh:
        fh.write(AIRFRAME.format(mass=MASS, jx=J[0, 0], jy=J[1, 1], jz=J[2, 2], arm=ARM, jr=J_R, g=G,
                                 kt=GUESS["K_T"], b=GUESS["b"], kd0=GUESS["Kd"][0], kd1=GUESS["Kd"][1],
                                 kd2=GUESS["Kd"][2]))
    stats = {}
    only = sys.argv[2:] or None
    for name, kind, seed, dur in FLIGHTS:
        if only and name not in only:
            continue
        rows = simulate(kind, seed, dur, clean_esc=name.endswith("_cleanesc"))
        write_csv(os.path.join(out, name + ".csv"), rows)
        V = np.array([r["_v"] for r in rows])
        psi = np.unwrap(np.array([r["psi"] for r in rows]))
        rr = np.array([r["r"] for r in rows])
        hs = np.hypot(V[:, 0], V[:, 1])
        stats[name] = dict(kind=kind, seed=seed, duration=dur, max_hspeed=float(hs.max()),
                           rms_hspeed=float(np.sqrt(np.mean(hs ** 2))),
                           max_vspeed=float(np.abs(V[:, 2]).max()), rms_r=float(np.sqrt(np.mean(rr ** 2))),
                           psi_range=float(psi.max() - psi.min()))
        print(name, json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in stats[name].items()}),
              flush=True)
    truth = dict(mass=MASS, inertia=list(np.diag(J)), arm=ARM, layout="x", K_T=K_T, b=B, Kd=list(KD), J_r=J_R,
                 tau_motor=TAU_MOTOR, hidden={"noyawasym": "rotor 1 reaction torque 1.35 b"},
                 guesses=GUESS, noise=NOISE, flights=stats)
    if not only:
        with open(os.path.join(out, "truth.json"), "w") as fh:
            json.dump(truth, fh, indent=1)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "flights")

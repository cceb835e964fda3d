#!/usr/bin/env python3
"""Blind audit 41: an independent quadrotor simulator (numpy only), written from the contract.

Usage:  python sim.py OUTDIR      -> regenerates every log and airframe bit for bit.

Physics (contract section 1): rigid body on a unit quaternion, fixed-step RK4 (substeps of at
most 1 ms inside each log row), thrust K_T*w^2 along body -z per rotor, reaction torque
spin_i*b*w_i^2 about body +z, world-frame linear drag -Kd*v, rotor gyroscopic torque
J_r*Omega_r*(omega x e_z), Omega_r = sum(spin_i*w_i).
Rotor speeds: a first-order motor (time constant TAU_M) updated once per row (the ESC's
update), so the speed is constant over each row: the contract's zero-order hold is exact and
the base model is exactly right.  Logged speeds: the true ones ("clean") or ESC telemetry
(white noise + quantisation, "esc").
Controller: cascaded position PD -> tilt/thrust -> attitude PD with feed-forward, using an
internal model whose K_T, b, inertia and mass are 5-10 % off the truth; own mixer.
Sensors: mocap position at 100 Hz (empty cells otherwise), attitude (white noise), gyro,
accelerometer (body specific force), each at the row rate.

TRUTH (also written to OUTDIR/truth.json):
  cf   : Crazyflie-like, x layout, m=0.030 kg, J=[1.4e-5,1.4e-5,2.2e-5], l=0.046 m,
         K_T=1.8e-8, b=1.1e-10, Kd=[0.010,0.010,0.015], J_r=1.0e-9, tau_m=0.030 s
  q1kg : plus layout, m=1.0 kg, J=[0.0082,0.0082,0.0149], l=0.17 m,
         K_T=1.2e-5, b=2.0e-7, Kd=[0.10,0.10,0.15], J_r=3.0e-5, tau_m=0.040 s
  heavy: x layout, m=3.0 kg, J=[0.060,0.060,0.110], l=0.35 m,
         K_T=5.0e-5, b=1.2e-6, Kd=[0.30,0.30,0.45], J_r=1.5e-4, tau_m=0.060 s

Logs (each with a validation flight, other seed): see LOGS below.
Mixes:  A  = pos(100 Hz) + att + gyro, clean speeds
        B  = att + gyro + accel, no position (x,y,z columns empty), clean speeds
        C  = pos(100 Hz) + att, no gyro, ESC-telemetry speeds (noise + quantisation)
        D  = pos(100 Hz) + att + gyro + accel, ESC-telemetry speeds
Starting points (airframe TOMLs): truth; s1: K_T*1.4, b*0.6; s2: K_T*0.65, b*1.5, Kd*0.5;
        s3: Kd*1.5, b*0.5.
"""
import json
import os
import sys

import numpy as np

G = 9.81

VEHICLES = {
    "cf": dict(mass=0.030, J=[1.4e-5, 1.4e-5, 2.2e-5], l=0.046, layout="x",
               K_T=1.8e-8, b=1.1e-10, Kd=[0.010, 0.010, 0.015], J_r=1.0e-9, tau_m=0.030,
               pos_noise=0.001, att_noise=0.002, gyro_noise=0.01, acc_noise=0.05,
               esc_noise=15.0, esc_q=4.0, att_wn=18.0, pos_wn=2.2),
    "q1kg": dict(mass=1.0, J=[0.0082, 0.0082, 0.0149], l=0.17, layout="plus",
                 K_T=1.2e-5, b=2.0e-7, Kd=[0.10, 0.10, 0.15], J_r=3.0e-5, tau_m=0.040,
                 pos_noise=0.002, att_noise=0.003, gyro_noise=0.008, acc_noise=0.05,
                 esc_noise=4.0, esc_q=1.0, att_wn=12.0, pos_wn=1.8),
    "heavy": dict(mass=3.0, J=[0.060, 0.060, 0.110], l=0.35, layout="x",
                  K_T=5.0e-5, b=1.2e-6, Kd=[0.30, 0.30, 0.45], J_r=1.5e-4, tau_m=0.060,
                  pos_noise=0.003, att_noise=0.003, gyro_noise=0.006, acc_noise=0.05,
                  esc_noise=3.0, esc_q=1.0, att_wn=8.0, pos_wn=1.4),
}

# (name, vehicle, row rate Hz, mix, seed_est, seed_val, duration_est, duration_val)
LOGS = [
    ("cf_A100", "cf", 100, "A", 11, 12, 20.0, 15.0),
    ("cf_A500", "cf", 500, "A", 13, 14, 20.0, 15.0),
    ("cf_B500", "cf", 500, "B", 15, 16, 20.0, 15.0),
    ("q1kg_A100", "q1kg", 100, "A", 21, 22, 20.0, 15.0),
    ("q1kg_A500", "q1kg", 500, "A", 23, 24, 20.0, 15.0),
    ("q1kg_C100", "q1kg", 100, "C", 25, 26, 20.0, 15.0),
    ("heavy_A100", "heavy", 100, "A", 31, 32, 20.0, 15.0),
    ("heavy_A500", "heavy", 500, "A", 33, 34, 20.0, 15.0),
    ("heavy_C500", "heavy", 500, "C", 35, 36, 20.0, 15.0),
    ("heavy_B100", "heavy", 100, "B", 37, 38, 20.0, 15.0),
    ("cf_C1000", "cf", 1000, "C", 17, 18, 20.0, 15.0),
    ("q1kg_B100", "q1kg", 100, "B", 27, 28, 20.0, 15.0),
    ("q1kg_D500", "q1kg", 500, "D", 29, 30, 20.0, 15.0),
    ("heavy_D1000", "heavy", 1000, "D", 39, 40, 20.0, 15.0),
]

STARTS = {
    "truth": dict(kt=1.0, b=1.0, kd=1.0),
    "s1": dict(kt=1.4, b=0.6, kd=1.0),
    "s2": dict(kt=0.65, b=1.5, kd=0.5),
    "s3": dict(kt=1.0, b=0.5, kd=1.5),
}


def rotors(v):
    l = v["l"]
    if v["layout"] == "plus":
        pos = np.array([[l, 0, 0], [0, l, 0], [-l, 0, 0], [0, -l, 0]], float)
        spin = np.array([-1, 1, -1, 1], float)
    else:
        a = l / np.sqrt(2)
        pos = np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]], float)
        spin = np.array([1, 1, -1, -1], float)
    return pos, spin


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1*w2 - x1*x2 - y1*y2 - z1*z2, w1*x2 + x1*w2 + y1*z2 - z1*y2,
                     w1*y2 - x1*z2 + y1*w2 + z1*x2, w1*z2 + x1*y2 - y1*x2 + z1*w2])


def qrot(q):
    w, x, y, z = q
    return np.array([[1 - 2*(y*y + z*z), 2*(x*y - w*z), 2*(x*z + w*y)],
                     [2*(x*y + w*z), 1 - 2*(x*x + z*z), 2*(y*z - w*x)],
                     [2*(x*z - w*y), 2*(y*z + w*x), 1 - 2*(x*x + y*y)]])


def euler(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    theta = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, theta, psi


def deriv(s, w, v, P):
    pos_r, spin = P["rot"]
    vel, q, om = s[3:6], s[6:10], s[10:13]
    R = qrot(q)
    J = np.array(v["J"])
    thr = v["K_T"] * w**2
    F = R @ np.array([0, 0, -thr.sum()]) + np.array([0, 0, v["mass"] * G]) - np.array(v["Kd"]) * vel
    tau = np.zeros(3)
    for i in range(len(w)):
        tau += np.cross(pos_r[i], np.array([0, 0, -thr[i]]))
        tau[2] += spin[i] * v["b"] * w[i]**2
    Om = np.dot(spin, w)
    tau += v["J_r"] * Om * np.cross(om, [0, 0, 1.0])
    domega = (tau - np.cross(om, J * om)) / J
    dq = 0.5 * qmul(q, np.array([0, *om]))
    return np.concatenate([vel, F / v["mass"], dq, domega])


def reference(t, rng, dur):
    """Piecewise setpoints: steps, a circle, yaw turns, climbs; smoothed later."""
    segs = []
    tt = 1.5
    kinds = ["step_x", "circle", "yaw", "climb", "step_y", "yaw_circle", "step_xy"]
    order = list(rng.permutation(kinds))
    while tt < dur - 1.0:
        segs.append((tt, order[len(segs) % len(order)], rng.uniform(0.6, 1.2), rng.choice([-1, 1])))
        tt += rng.uniform(2.5, 3.5)
    return segs


def setpoint(t, segs):
    x = y = 0.0
    z = -1.0
    psi = 0.0
    for (t0, kind, A, sgn) in segs:
        if t < t0:
            break
        if kind == "step_x":
            x += sgn * A
        elif kind == "step_y":
            y += sgn * A
        elif kind == "step_xy":
            x -= sgn * 0.7 * A
            y += 0.7 * A
        elif kind == "climb":
            z -= sgn * 0.5 * A
        elif kind == "yaw":
            psi += sgn * 1.2 * A
        elif kind in ("circle", "yaw_circle"):
            te = t - t0
            if te < 3.0:
                om = 1.6
                x += A * 0.6 * np.sin(om * te)
                y += sgn * A * 0.6 * (1 - np.cos(om * te))
                if kind == "yaw_circle":
                    psi += sgn * 0.5 * np.sin(om * te)
    return np.array([x, y, z]), psi


def simulate(vname, rate, mix, seed, dur):
    v = VEHICLES[vname]
    rng = np.random.default_rng(seed)
    pos_r, spin = rotors(v)
    P = {"rot": (pos_r, spin)}
    # controller's internal model, 5-10 % off
    c = dict(mass=v["mass"] * 1.06, J=np.array(v["J"]) * np.array([0.92, 1.08, 1.07]),
             K_T=v["K_T"] * 0.93, b=v["b"] * 1.09)
    # mixer: [T, tx, ty, tz] = M @ w^2
    M = np.zeros((4, 4))
    for i in range(4):
        M[0, i] = c["K_T"]
        M[1, i] = -(pos_r[i, 1]) * c["K_T"]
        M[2, i] = pos_r[i, 0] * c["K_T"]
        M[3, i] = spin[i] * c["b"]
    Minv = np.linalg.inv(M)
    dt = 1.0 / rate
    nsub = max(1, int(np.ceil(dt / 0.001 - 1e-9)))
    h = dt / nsub
    n = int(round(dur * rate)) + 1
    segs = reference(0, rng, dur)
    w_hover = np.sqrt(v["mass"] * G / (4 * v["K_T"]))
    s = np.zeros(13)
    s[2] = -1.0
    s[6] = 1.0
    w = np.full(4, w_hover)
    a_m = np.exp(-dt / v["tau_m"])
    # setpoint prefilter (critically damped 2nd order)
    ref = np.array([0.0, 0.0, -1.0, 0.0])
    refd = np.zeros(4)
    wf = 2.5
    Kp_pos, Kd_pos = v["pos_wn"]**2, 2 * 0.85 * v["pos_wn"]
    Kp_att, Kd_att = v["att_wn"]**2, 2 * 0.8 * v["att_wn"]
    rows = []
    wmax = 2.2 * w_hover
    for k in range(n):
        t = k * dt
        R = qrot(s[6:10])
        phi, theta, psi = euler(R)
        om = s[10:13].copy()
        # reference
        sp, psp = setpoint(t, segs)
        target = np.array([*sp, psp])
        refdd = wf * wf * (target - ref) - 2 * wf * refd
        refd = refd + dt * refdd
        ref = ref + dt * refd
        # outer loop
        e = ref[:3] - s[0:3]
        ed = refd[:3] - s[3:6]
        acc = Kp_pos * e + Kd_pos * ed + refdd[:3]
        fdes = c["mass"] * (acc - np.array([0, 0, G]))  # desired force (world), thrust = -fdes
        fdes[2] = min(fdes[2], -0.3 * c["mass"] * G)
        bz = -fdes / np.linalg.norm(fdes)        # desired body z axis (down) in world
        xc = np.array([np.cos(ref[3]), np.sin(ref[3]), 0.0])
        by = np.cross(bz, xc); by /= np.linalg.norm(by)
        bx = np.cross(by, bz)
        Rd = np.column_stack([bx, by, bz])
        T = -(fdes @ R[:, 2])                     # collective thrust along the actual body -z
        # attitude error (geometric)
        Em = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([Em[2, 1], Em[0, 2], Em[1, 0]])
        alpha = -Kp_att * eR - Kd_att * om
        tau = c["J"] * alpha + np.cross(om, c["J"] * om)
        wsq = Minv @ np.array([T, *tau])
        wcmd = np.sqrt(np.clip(wsq, (0.15 * w_hover)**2, wmax**2))
        # motor (ESC update once per row): speed constant over this row
        w = a_m * w + (1 - a_m) * wcmd
        # specific force at the row start (accelerometer)
        thr = v["K_T"] * w**2
        fb = np.array([0, 0, -thr.sum()]) / v["mass"] + R.T @ (-np.array(v["Kd"]) * s[3:6]) / v["mass"]
        rows.append((t, w.copy(), s[0:3].copy(), (phi, theta, psi), om, fb))
        for _ in range(nsub):
            k1 = deriv(s, w, v, P)
            k2 = deriv(s + 0.5 * h * k1, w, v, P)
            k3 = deriv(s + 0.5 * h * k2, w, v, P)
            k4 = deriv(s + h * k3, w, v, P)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            s[6:10] /= np.linalg.norm(s[6:10])
        if not np.all(np.isfinite(s)) or abs(s[2]) > 50:
            raise RuntimeError(f"{vname} seed {seed}: diverged at t={t}")
    # sensors
    t = np.array([r[0] for r in rows])
    W = np.array([r[1] for r in rows])
    X = np.array([r[2] for r in rows])
    E = np.array([r[3] for r in rows])
    E[:, 2] = np.unwrap(E[:, 2])
    O = np.array([r[4] for r in rows])
    FB = np.array([r[5] for r in rows])
    nr = len(t)
    nrng = np.random.default_rng(seed + 1000)
    Xm = X + v["pos_noise"] * nrng.standard_normal(X.shape)
    pos_every = int(round(rate / 100))
    mask = np.zeros(nr, bool)
    mask[::pos_every] = True
    Xm[~mask] = np.nan
    Em = E + v["att_noise"] * nrng.standard_normal(E.shape)
    Om = O + v["gyro_noise"] * nrng.standard_normal(O.shape)
    Am = FB + v["acc_noise"] * nrng.standard_normal(FB.shape)
    if mix in ("C", "D"):
        Wl = np.round((W + v["esc_noise"] * nrng.standard_normal(W.shape)) / v["esc_q"]) * v["esc_q"]
    else:
        Wl = W
    cols = {"t": t}
    for i in range(4):
        cols[f"w{i+1}"] = Wl[:, i]
    for j, nm in enumerate("xyz"):
        cols[nm] = Xm[:, j] if mix != "B" else np.full(nr, np.nan)
    for j, nm in enumerate(["phi", "theta", "psi"]):
        cols[nm] = Em[:, j]
    if mix in ("A", "B", "D"):
        for j, nm in enumerate("pqr"):
            cols[nm] = Om[:, j]
    if mix in ("B", "D"):
        for j, nm in enumerate(["ax", "ay", "az"]):
            cols[nm] = Am[:, j]
    info = dict(max_tilt_deg=float(np.degrees(np.max(np.hypot(E[:, 0], E[:, 1])))),
                max_speed=float(np.max(np.linalg.norm(np.diff(X, axis=0), axis=1)) * rate),
                w_range=[float(W.min()), float(W.max())], w_hover=float(w_hover))
    return cols, info


def write_csv(path, cols):
    names = list(cols)
    n = len(cols["t"])
    with open(path, "w") as f:
        f.write(",".join(names) + "\n")
        for k in range(n):
            cells = []
            for nm in names:
                x = cols[nm][k]
                cells.append("" if not np.isfinite(x) else repr(float(x)))
            f.write(",".join(cells) + "\n")


def write_toml(path, vname, start):
    v = VEHICLES[vname]
    st = STARTS[start]
    kd = [x * st["kd"] for x in v["Kd"]]
    with open(path, "w") as f:
        f.write(f"""[airframe]
name = "audit41_{vname}_{start}"
mass = {v['mass']!r}
inertia = [{v['J'][0]!r}, {v['J'][1]!r}, {v['J'][2]!r}]
arm_length = {v['l']!r}
layout = "{v['layout']}"
rotor_inertia = {v['J_r']!r}
gravity = {G!r}

[parameters]
K_T = {v['K_T'] * st['kt']!r}
b = {v['b'] * st['b']!r}
Kd = [{kd[0]!r}, {kd[1]!r}, {kd[2]!r}]
""")


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "out"
    os.makedirs(out, exist_ok=True)
    truth = {"vehicles": VEHICLES, "logs": {}, "starts": STARTS}
    for vname in VEHICLES:
        for st in STARTS:
            write_toml(os.path.join(out, f"{vname}_{st}.toml"), vname, st)
    only = sys.argv[2].split(",") if len(sys.argv) > 2 else None
    for (name, vname, rate, mix, se, sv, de, dv) in LOGS:
        if only and name not in only:
            continue
        for tag, seed, dur in (("", se, de), ("_val", sv, dv)):
            cols, info = simulate(vname, rate, mix, seed, dur)
            write_csv(os.path.join(out, f"{name}{tag}.csv"), cols)
            truth["logs"][name + tag] = dict(vehicle=vname, rate=rate, mix=mix, seed=seed,
                                             duration=dur, **info)
            print(name + tag, info, flush=True)
    with open(os.path.join(out, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)


if __name__ == "__main__":
    main()

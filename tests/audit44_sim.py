"""Audit 44 simulator: saturation and clipping as real hardware does it.

Written from scratch (numpy only) from greybox's CONTRACT.md / README.md; no greybox code used.

    python sim.py OUTDIR        # writes every case's estimation + validation CSV, airframes, truth.json

Dynamics: rigid body, unit quaternion (body->world, NED world, FRD body), RK4 at 0.5 ms.
State: position (NED), world velocity, quaternion, body rates, 4 rotor speeds (first-order motors).
Forces: thrust K_T w^2 along body -z per rotor, world-axis linear drag -Kd v, gravity +g z,
optional hidden quadratic drag -Kq |v| v (world axes).  Torques: r_i x F_i, spin_i b w_i^2 about
body +z, gyroscopic J_r*Omega_r*(omega x e_z) with Omega_r = sum(spin_i w_i) (contract sign).
Layout "x" of the contract: rotor1 (+a,+a), 2 (-a,-a), 3 (+a,-a), 4 (-a,+a), spin [+1,+1,-1,-1].

Controller (500 Hz, zero-order hold, aligned with the log rows): geometric position/attitude
controller (Lee-style) whose model is 5-8 % off the truth (mass -5 %, K_T +7 %, b -7 %,
inertia +8 %); rate-mode overlays for flips / snaps / yaw spins; "punch" overlays (thrust near
max); mixer inverts the controller's own model, then clips w^2 to [w_min^2, w_max^2]
(simple per-motor clip, no airmode / desaturation priority).

Sensors (log rows at 500 Hz):
  rotor speeds: either ESC telemetry of the actual speed (noise 0.3 %, quantised to
     100 eRPM / 7 pole pairs = 1.496 rad/s), or the controller's command (clipped or unclipped);
  attitude phi,theta,psi every row: truth + 2 mrad white noise, wrapped to (-pi, pi];
  gyro p,q,r every row: truth + noise, then CLIPPED to +-gyro_range (MEMS full scale);
  accelerometer ax,ay,az every row: true specific force R^T(dv/dt - g e3) + noise, CLIPPED to
     +-accel_range;
  motion capture x,y,z at 100 Hz (every 5th row), 1 mm noise; empty cells otherwise.

TRUTH (both vehicles, "x" layout):
  racer  (5-inch): m 0.60 kg, J [9.0e-4, 9.5e-4, 1.6e-3], arm 0.11 m, K_T 7.5e-7, b 1.2e-8,
         Kd [0.08, 0.08, 0.12], J_r 2.5e-6, tau_m 20 ms, w in [300, 3000] rad/s
         (thrust/weight 4.59, hover 1401 rad/s); gyro +-2000 deg/s (34.91 rad/s), accel +-4 g
         (39.24 m/s^2) unless the case says otherwise.
  heavy (10-inch): m 1.50 kg, J [0.020, 0.021, 0.036], arm 0.225 m, K_T 6.1e-6, b 1.1e-7,
         Kd [0.20, 0.20, 0.30], J_r 1.5e-5, tau_m 50 ms, w in [150, 1150] rad/s
         (thrust/weight 2.19, hover 776 rad/s); gyro +-250 deg/s (4.363 rad/s), accel +-2 g.
Airframe starting guesses: K_T x1.2, b x0.8, Kd x0.5; rotor_inertia given at its truth.
"""
import json
import math
import os
import sys

import numpy as np

G = 9.81
DT = 0.0005          # integrator step
ROW = 0.002          # log row / controller period (500 Hz)
SUB = int(round(ROW / DT))
MOCAP_EVERY = 5      # 100 Hz

VEH = {
    "racer": dict(m=0.60, J=[9.0e-4, 9.5e-4, 1.6e-3], l=0.11, K_T=7.5e-7, b=1.2e-8,
                  Kd=[0.08, 0.08, 0.12], J_r=2.5e-6, tau=0.020, wmin=300.0, wmax=3000.0,
                  gyro_range=math.radians(2000), accel_range=4 * G, gyro_noise=0.01,
                  att_wn=20.0, pos_wn=3.5, rate_k=40.0, amax=14.0),
    "heavy": dict(m=1.50, J=[0.020, 0.021, 0.036], l=0.225, K_T=6.1e-6, b=1.1e-7,
                  Kd=[0.20, 0.20, 0.30], J_r=1.5e-5, tau=0.050, wmin=150.0, wmax=1150.0,
                  gyro_range=math.radians(250), accel_range=2 * G, gyro_noise=0.005,
                  att_wn=9.0, pos_wn=2.2, rate_k=15.0, amax=6.0),
}

# case: vehicle, manoeuvre, logged inputs, overrides
CASES = {
    # racer
    "r1_control":   dict(veh="racer", man="brisk", inputs="actual"),
    "r2_gyro":      dict(veh="racer", man="flips", inputs="actual"),
    "r3_accel":     dict(veh="racer", man="punch", inputs="actual"),
    "r4a_motor":    dict(veh="racer", man="sat", inputs="actual"),
    "r4b_cmd":      dict(veh="racer", man="sat", inputs="cmd_unclipped"),
    "r4c_cmdctl":   dict(veh="racer", man="brisk", inputs="cmd_clipped"),   # lag control for 4b/5
    "r5_lag":       dict(veh="racer", man="flips+punch", inputs="cmd_clipped"),
    # heavy
    "h1_control":   dict(veh="heavy", man="brisk", inputs="actual"),
    "h2_gyro":      dict(veh="heavy", man="snaps", inputs="actual"),
    "h3_accel":     dict(veh="heavy", man="punch", inputs="actual"),
    "h4a_motor":    dict(veh="heavy", man="sat", inputs="actual"),
    "h4b_cmd":      dict(veh="heavy", man="sat", inputs="cmd_unclipped"),
    "h5_qdrag":     dict(veh="heavy", man="sat", inputs="actual", Kq=[0.04, 0.04, 0.06]),
}
DUR = {"est": 20.0, "val": 15.0}


def layout(l):
    a = l / math.sqrt(2)
    pos = np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]], float)
    spin = np.array([1, 1, -1, -1], float)
    return pos, spin


def qmul(p, q):
    w0, x0, y0, z0 = p
    w1, x1, y1, z1 = q
    return np.array([w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1,
                     w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
                     w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1,
                     w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1])


def qrot(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler(R):
    phi = math.atan2(R[2, 1], R[2, 2])
    theta = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    psi = math.atan2(R[1, 0], R[0, 0])
    return phi, theta, psi


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


class Plant:
    def __init__(self, v, Kq):
        self.v = v
        self.m = v["m"]
        self.J = np.diag(v["J"])
        self.Ji = np.linalg.inv(self.J)
        self.pos, self.spin = layout(v["l"])
        self.Kd = np.array(v["Kd"])
        self.Kq = np.array(Kq)

    def deriv(self, s, wc):
        v = self.v
        vel = s[3:6]
        q = s[6:10]
        om = s[10:13]
        w = s[13:17]
        R = qrot(q)
        T = v["K_T"] * w * w
        f_body = np.array([0.0, 0.0, -T.sum()])
        F = R @ f_body + np.array([0, 0, self.m * G]) - self.Kd * vel - self.Kq * np.linalg.norm(vel) * vel
        acc = F / self.m
        tau = np.array([-(self.pos[:, 1] * T).sum(), (self.pos[:, 0] * T).sum(),
                        (self.spin * v["b"] * w * w).sum()])
        Om = (self.spin * w).sum()
        tau = tau + v["J_r"] * Om * np.cross(om, [0, 0, 1.0])
        domega = self.Ji @ (tau - np.cross(om, self.J @ om))
        dq = 0.5 * qmul(q, np.array([0.0, *om]))
        dw = (wc - w) / v["tau"]
        return np.concatenate([vel, acc, dq, domega, dw]), acc, R

    def step(self, s, wc):
        k1 = self.deriv(s, wc)[0]
        k2 = self.deriv(s + 0.5 * DT * k1, wc)[0]
        k3 = self.deriv(s + 0.5 * DT * k2, wc)[0]
        k4 = self.deriv(s + DT * k3, wc)[0]
        s = s + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
        return s


def schedule(man, dur, rng, veh):
    """Reference: smooth sines; overlays: list of (t0, t1, kind, value)."""
    racer = veh == "racer"
    A = (1.6 if racer else 1.8) if "sat" not in man else (2.5 if racer else 3.0)
    fr = rng.uniform(0.15, 0.45, size=(4, 3))
    ph = rng.uniform(0, 2 * np.pi, size=(4, 3))
    amp = np.array([A, A, 0.5 if racer else 0.4, 0.6])
    ov = []
    if "flips" in man:
        t = 2.0
        while t < dur - 1.5:
            kind = rng.choice(["flip", "yawspin", "snap"])
            if kind == "flip":
                rate = rng.choice([-1, 1]) * rng.uniform(40.0, 46.0)
                ov.append((t, t + 2 * np.pi / abs(rate) * 0.97, "rate", (rate, 0.0, 0.0)))
            elif kind == "yawspin":
                rate = rng.choice([-1, 1]) * rng.uniform(30.0, 38.0)
                ov.append((t, t + 0.6, "rate", (0.0, 0.0, rate)))
            else:
                ax = rng.integers(0, 2)
                rr = [0.0, 0.0, 0.0]
                rr[ax] = rng.choice([-1, 1]) * rng.uniform(38.0, 44.0)
                ov.append((t, t + 0.045, "rate", tuple(rr)))
            t += rng.uniform(1.6, 2.6)
    if "snaps" in man:
        t = 2.0
        while t < dur - 1.5:
            if rng.uniform() < 0.6:
                ax = rng.integers(0, 2)
                rr = [0.0, 0.0, 0.0]
                rr[ax] = rng.choice([-1, 1]) * rng.uniform(5.5, 7.0)
                ov.append((t, t + 0.10, "rate", tuple(rr)))
            else:
                ov.append((t, t + 1.2, "rate", (0.0, 0.0, rng.choice([-1, 1]) * 5.5)))
            t += rng.uniform(1.8, 2.8)
    if "punch" in man:
        t = 3.0 if "flips" not in man else 2.9
        while t < dur - 1.5:
            ov.append((t, t + rng.uniform(0.35, 0.55), "punch", 0.95 if racer else 0.965))
            t += rng.uniform(3.0, 4.0)
    steps = []
    if "sat" in man:
        t = 1.5
        while t < dur - 1.0:
            steps.append((t, rng.uniform(-3, 3, size=3) * np.array([1, 1, 0.6 if racer else 0.5])))
            t += rng.uniform(1.5, 2.5)
    return fr, ph, amp, ov, steps


def reference(t, fr, ph, amp, steps):
    p = np.zeros(3); v = np.zeros(3); a = np.zeros(3)
    for k in range(3):
        w = 2 * np.pi * fr[k]
        p[k] = sum(amp[k] / 3 * np.sin(w[j] * t + ph[k, j]) for j in range(3)) if False else \
            sum(amp[k] / 3 * math.sin(2 * np.pi * fr[k, j] * t + ph[k, j]) for j in range(3))
        v[k] = sum(amp[k] / 3 * 2 * np.pi * fr[k, j] * math.cos(2 * np.pi * fr[k, j] * t + ph[k, j]) for j in range(3))
        a[k] = -sum(amp[k] / 3 * (2 * np.pi * fr[k, j]) ** 2 * math.sin(2 * np.pi * fr[k, j] * t + ph[k, j]) for j in range(3))
    psi = sum(amp[3] / 3 * math.sin(2 * np.pi * fr[3, j] * t + ph[3, j]) for j in range(3))
    off = np.zeros(3)
    for (ts, d) in steps:
        if t >= ts:
            off = d          # position steps (not cumulative): a jump of the reference
    p = p + off
    p[2] -= 2.0              # fly 2 m above the origin (NED z = -2)
    return p, v, a, psi


def fly(case, seed, dur):
    c = CASES[case]
    v = VEH[c["veh"]]
    rng = np.random.default_rng(seed)
    plant = Plant(v, c.get("Kq", [0.0, 0.0, 0.0]))
    pos_r, spin = plant.pos, plant.spin
    # controller's model (off the truth)
    mc, KTc, bc, Jc = 0.95 * v["m"], 1.07 * v["K_T"], 0.93 * v["b"], 1.08 * np.diag(v["J"])
    M = np.vstack([KTc * np.ones(4), -KTc * pos_r[:, 1], KTc * pos_r[:, 0], bc * spin])
    Mi = np.linalg.inv(M)
    wn, pwn = v["att_wn"], v["pos_wn"]
    kR, kW = wn * wn, 2 * 0.75 * wn
    kp, kd = pwn * pwn, 2 * 0.9 * pwn
    fr, ph, amp, ov, steps = schedule(c["man"], dur, rng, c["veh"])
    whov = math.sqrt(v["m"] * G / (4 * v["K_T"]))
    p0, v0, _, psi0 = reference(0.0, fr, ph, amp, steps)
    q0 = np.array([math.cos(psi0 / 2), 0, 0, math.sin(psi0 / 2)])
    s = np.concatenate([p0, v0, q0, np.zeros(3), np.full(4, whov)])
    psi_off = 0.0
    was_rate = False
    n = int(round(dur / ROW)) + 1
    rows = []
    wmin2, wmax2 = v["wmin"] ** 2, v["wmax"] ** 2
    for k in range(n):
        t = k * ROW
        R = qrot(s[6:10])
        om = s[10:13]
        pr, vr, ar, psir = reference(t, fr, ph, amp, steps)
        mode = None
        for (t0, t1, kind, val) in ov:
            if t0 <= t < t1:
                mode = (kind, val)
        if was_rate and (mode is None or mode[0] != "rate"):
            # capture heading after a rate manoeuvre
            psi_off += wrap(euler(R)[2] - (psir + psi_off))
        was_rate = mode is not None and mode[0] == "rate"
        psid = psir + psi_off
        # position loop
        ea = kp * (pr - s[0:3]) + kd * (vr - s[3:6]) + ar
        h = np.linalg.norm(ea[:2])
        if h > v["amax"]:
            ea[:2] *= v["amax"] / h
        ea[2] = np.clip(ea[2], -v["amax"], 0.8 * G)
        F = mc * (ea - np.array([0, 0, G]))          # needed force (NED), thrust = -F along b3
        b3 = R[:, 2]
        if mode is not None and mode[0] == "punch":
            b3d = np.array([0, 0, 1.0])
            Tcmd = mode[1] * 4 * KTc * wmax2   # -> w^2 = frac * wmax^2: that fraction of the true max thrust
        else:
            b3d = -F / np.linalg.norm(F)
            Tcmd = max(-F @ b3, 0.2 * mc * G)
        b1c = np.array([math.cos(psid), math.sin(psid), 0.0])
        b2d = np.cross(b3d, b1c); b2d /= np.linalg.norm(b2d)
        b1d = np.cross(b2d, b3d)
        Rd = np.column_stack([b1d, b2d, b3d])
        E = Rd.T @ R - R.T @ Rd
        eR = 0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]])
        if mode is not None and mode[0] == "rate":
            wd = np.array(mode[1])
            tauc = Jc @ (v["rate_k"] * (wd - om)) + np.cross(om, Jc @ om)
            Tcmd = 1.1 * mc * G
            if c["veh"] == "heavy" and wd[0] == 0.0 and wd[1] == 0.0:
                # heavy yaw spin: angle mode for roll/pitch and altitude (yaw stick only)
                tatt = Jc @ (-kR * eR - kW * om) + np.cross(om, Jc @ om)
                tauc[:2] = tatt[:2]
                Tcmd = max(-F @ b3, 0.2 * mc * G)
        else:
            tauc = Jc @ (-kR * eR - kW * om) + np.cross(om, Jc @ om)
        u = np.array([Tcmd, *tauc])
        w2 = Mi @ u
        w2c = np.clip(w2, wmin2, wmax2)
        wc = np.sqrt(w2c)
        w_unc = np.sqrt(np.maximum(w2, 0.0))
        # measurements at this row (state at t, before stepping)
        d, acc, _ = plant.deriv(s, s[13:17])   # acceleration does not depend on wc
        sf = R.T @ (acc - np.array([0, 0, G]))
        phi, th, psi = euler(R)
        rows.append((t, s.copy(), wc.copy(), w_unc.copy(), sf, (phi, th, psi), 1 if mode else 0))
        for _ in range(SUB):
            s = plant.step(s, wc)
    return rows, v, c


def write_log(path, rows, v, c, seed):
    rng = np.random.default_rng(seed + 1000)
    n = len(rows)
    out = []
    q_erpm = 100.0 / 7 * 2 * np.pi / 60       # 100 eRPM per LSB, 7 pole pairs -> 1.496 rad/s
    sat_rows = {"gyro": 0, "accel": 0, "wmax": 0, "wmin": 0}
    for k, (t, s, wc, wu, sf, att, ovl) in enumerate(rows):
        if c["inputs"] == "actual":
            w = s[13:17] * (1 + 0.003 * rng.standard_normal(4))
            w = np.round(w / q_erpm) * q_erpm
        elif c["inputs"] == "cmd_clipped":
            w = wc
        else:
            w = wu
        om = s[10:13] + v["gyro_noise"] * rng.standard_normal(3)
        gr = v["gyro_range"]
        if np.any(np.abs(om) > gr):
            sat_rows["gyro"] += 1
        om = np.clip(om, -gr, gr)
        acc = sf + 0.08 * rng.standard_normal(3)
        ar = v["accel_range"]
        if np.any(np.abs(acc) > ar):
            sat_rows["accel"] += 1
        acc = np.clip(acc, -ar, ar)
        if np.any(wc >= v["wmax"] - 1e-9):
            sat_rows["wmax"] += 1
        if np.any(wc <= v["wmin"] + 1e-9):
            sat_rows["wmin"] += 1
        a = np.array(att) + 0.002 * rng.standard_normal(3)
        a = [(x + math.pi) % (2 * math.pi) - math.pi for x in a]
        if k % MOCAP_EVERY == 0:
            p = s[0:3] + 0.001 * rng.standard_normal(3)
            ps = [f"{x:.6f}" for x in p]
        else:
            ps = ["", "", ""]
        out.append(",".join([f"{t:.4f}"] + [f"{x:.4f}" for x in w] + ps + [f"{x:.6f}" for x in a]
                            + [f"{x:.5f}" for x in om] + [f"{x:.4f}" for x in acc]))
    with open(path, "w") as f:
        f.write("t,w1,w2,w3,w4,x,y,z,phi,theta,psi,p,q,r,ax,ay,az\n")
        f.write("\n".join(out) + "\n")
    # true extremes
    S = np.array([r[1] for r in rows])
    SF = np.array([r[4] for r in rows])
    ext = dict(max_abs_rate=float(np.abs(S[:, 10:13]).max()),
               max_abs_sf=float(np.abs(SF).max()),
               max_speed=float(np.linalg.norm(S[:, 3:6], axis=1).max()),
               max_tilt_deg=float(np.degrees(np.arccos(np.clip([qrot(x)[2, 2] for x in S[:, 6:10]], -1, 1))).max()),
               rows=n, **{f"rows_{k}_clipped": val for k, val in sat_rows.items()})
    return ext


def write_airframe(path, veh):
    v = VEH[veh]
    with open(path, "w") as f:
        f.write(f"""[airframe]
name = "audit44_{veh}"
mass = {v['m']}
inertia = {v['J']}
arm_length = {v['l']}
layout = "x"
rotor_inertia = {v['J_r']}
gravity = {G}

[parameters]
K_T = {v['K_T'] * 1.2:.6e}
b = {v['b'] * 0.8:.6e}
Kd = [{v['Kd'][0] * 0.5}, {v['Kd'][1] * 0.5}, {v['Kd'][2] * 0.5}]
""")


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "flights"
    only = sys.argv[2:] or list(CASES)
    os.makedirs(out, exist_ok=True)
    for veh in VEH:
        write_airframe(os.path.join(out, f"{veh}.toml"), veh)
    truth = {}
    tpath = os.path.join(out, "truth.json")
    if os.path.exists(tpath):
        truth = json.load(open(tpath))
    for i, case in enumerate(CASES):
        if case not in only:
            continue
        c = CASES[case]
        v = VEH[c["veh"]]
        info = {"vehicle": c["veh"], "manoeuvre": c["man"], "inputs": c["inputs"],
                "K_T": v["K_T"], "b": v["b"], "Kd": v["Kd"], "tau_m": v["tau"],
                "Kq": c.get("Kq"), "gyro_range": v["gyro_range"], "accel_range": v["accel_range"]}
        for part, seed in (("est", 100 + 2 * i), ("val", 101 + 2 * i)):
            rows, v, c = fly(case, seed, DUR[part])
            info[part] = write_log(os.path.join(out, f"{case}_{part}.csv"), rows, v, c, seed)
            print(case, part, info[part], flush=True)
        truth[case] = info
        with open(tpath, "w") as f:
            json.dump(truth, f, indent=1)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Blind audit 40: an independent quadrotor flight simulator (numpy only).

Usage:  python sim.py OUTDIR        (regenerates every flight + airframe bit for bit)

TRUTH (the vehicle)
-------------------
  mass            m    = 2.00 kg                  ("x" quadrotor, 11-inch props, 450 mm frame)
  inertia         J    = diag(0.028, 0.028, 0.050) kg m^2 (about the true centre of gravity)
  arm length      l    = 0.225 m  (a = l/sqrt 2 = 0.1591 m)
  thrust coeff    K_T  = 1.80e-5 N/(rad/s)^2   (hover ~ 522 rad/s = 4985 rpm)
  torque coeff    b    = 2.90e-7 N m/(rad/s)^2 (b/K_T = 16.1 mm)
  linear drag     Kd   = [0.25, 0.25, 0.35] N s/m, world axes, on the vehicle's velocity
  rotor inertia   J_r  = 6.0e-5 kg m^2 (gyroscopic torque, contract sign; given in the TOML)
  motors          first-order lag tau = 30 ms from command to actual speed (the log holds the
                  ACTUAL speeds as ESC telemetry, so the lag is not a hidden effect)
  gravity         9.81, NED world, FRD body, rotor layout "x" per the contract
                  (1 FR +spin, 2 BL +spin, 3 FL -spin, 4 BR -spin)

HIDDEN EFFECTS (graded; case name -> truth)
  control        nothing hidden
  asym_0p1 ... asym_10  rotor 3 (front-left) weaker in thrust AND reaction torque by
                  e = 0.1 %, 0.4 %, 2 %, 10 %.  In greybox's parameterisation
                  (K_T = mean, d_4 = -(d_1+d_2+d_3)): K_T_true = K_T*(1-e/4),
                  K_T_dev[0] = K_T_dev[1] = 1/(1-e/4) - 1, K_T_dev[2] = (1-e)/(1-e/4) - 1
  (asym_0p2 = 0.2 % and cog_0p2 = 0.2 mm are extra in-between sizes)
  python sim.py OUTDIR CASES 3:4,5:6   makes extra flights of CASES with seed pairs (est:val),
  written as CASE_est_s3.csv / CASE_val_s4.csv (used for the std-honesty check)
  cog_0p1 ... cog_10    centre of gravity offset (dx, dy) = d*(0.8, -0.6) from the rotor
                  centre, |d| = 0.1, 0.4, 2, 10 mm (r_cog = [0.8 d, -0.6 d]). Inertia about
                  the true CoG is unchanged (the airframe file gives it).

SIMULATION
  RK4 at 1 ms on (position, world velocity, unit quaternion body->world, body rates,
  actual rotor speeds); quaternion renormalised each step.
  Controller at 500 Hz: reference shaping (2nd-order filter, wn = 2.5 rad/s) -> position
  PID (world NED) -> geometric attitude (SO(3)) P -> body-rate PI(D) -> mixer.  The
  controller's model is off: mass +6 %, K_T +7 %, b -8 %, inertia +5 %, drag ignored.
  Command held (ZOH) between controller ticks; motors follow with a 30 ms lag.

SENSORS (rows at 250 Hz, 30 s per flight)
  rotor speeds  ESC telemetry of the actual speed at each row: + N(0, 3 rad/s), quantised
                to 2 rad/s steps
  position      motion capture at 125 Hz (every 2nd row, empty cells otherwise), N(0, 1 mm)
  attitude      phi/theta/psi at 250 Hz from the same mocap body: N(0, 2 mrad) each
  gyro          p, q, r at 250 Hz: N(0, 0.01 rad/s)

FLIGHTS: every case has an estimation flight (seed 1) and a validation flight (seed 2) of
the same kind (hover, x step, y step with climb, yaw turn, circle, yaw back + descent,
return); the seeds change the amplitudes, directions and the sensor noise. All cases use
the same seeds, so the sizes differ ONLY by the hidden effect.
"""
import math
import os
import sys

import numpy as np

# ----------------------------------------------------------------------------- truth
M = 2.0
JX, JY, JZ = 0.028, 0.028, 0.050
L_ARM = 0.225
A = L_ARM / math.sqrt(2.0)
KT = 1.80e-5
B = 2.90e-7
KD = (0.25, 0.25, 0.35)
JR = 6.0e-5
TAU_M = 0.030
G = 9.81
ROT_POS = [(+A, +A), (-A, -A), (+A, -A), (-A, +A)]
SPIN = [+1, +1, -1, -1]

DT = 0.001          # integrator step
CTRL_EVERY = 2      # controller at 500 Hz
ROW_EVERY = 4       # log rows at 250 Hz
DURATION = 30.0
W_MIN, W_MAX = 150.0, 1000.0

ASYM_SIZES = {"asym_0p1": 0.001, "asym_0p4": 0.004, "asym_2": 0.02, "asym_10": 0.10,
              "asym_0p2": 0.002}   # 0p2: an extra in-between size
COG_SIZES = {"cog_0p1": 0.0001, "cog_0p4": 0.0004, "cog_2": 0.002, "cog_10": 0.010,
             "cog_0p2": 0.0002}    # 0p2: an extra in-between size
COG_DIR = (0.8, -0.6)


def case_truth(case):
    """Per-rotor thrust/torque scale and CoG offset of a case, and greybox-style truth."""
    scale = [1.0, 1.0, 1.0, 1.0]
    cog = (0.0, 0.0)
    truth = {"K_T": KT, "b": B, "Kd": list(KD)}
    if case in ASYM_SIZES:
        e = ASYM_SIZES[case]
        scale[2] = 1.0 - e
        mean = 1.0 - e / 4
        truth["K_T"] = KT * mean
        truth["b"] = B * mean
        truth["K_T_dev"] = [1 / mean - 1, 1 / mean - 1, (1 - e) / mean - 1]
        truth["weak_rotor"] = 3
        truth["e"] = e
    elif case in COG_SIZES:
        d = COG_SIZES[case]
        cog = (COG_DIR[0] * d, COG_DIR[1] * d)
        truth["r_cog"] = list(cog)
    return scale, cog, truth


# ----------------------------------------------------------------------------- helpers
def quat_to_R(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def R_to_euler(R):
    """ZYX Euler angles with R = Rz(psi) Ry(theta) Rx(phi)."""
    theta = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    phi = math.atan2(R[2, 1], R[2, 2])
    psi = math.atan2(R[1, 0], R[0, 0])
    return phi, theta, psi


def derivs(s, w_cmd, scale, cog):
    # s: 0:3 pos, 3:6 vel (world), 6:10 quat, 10:13 omega (body), 13:17 actual rotor speeds
    v = s[3:6]
    q = s[6:10]
    p, qq, r = s[10:13]
    w = s[13:17]
    R = quat_to_R(q)
    T = [KT * scale[i] * w[i] * w[i] for i in range(4)]
    Ttot = sum(T)
    acc = np.array([0.0, 0.0, G]) + R @ np.array([0.0, 0.0, -Ttot]) / M \
        - np.array([KD[0] * v[0], KD[1] * v[1], KD[2] * v[2]]) / M
    tx = ty = tz = 0.0
    om_r = 0.0
    for i in range(4):
        rx = ROT_POS[i][0] - cog[0]
        ry = ROT_POS[i][1] - cog[1]
        tx += -ry * T[i]
        ty += rx * T[i]
        tz += SPIN[i] * B * scale[i] * w[i] * w[i]
        om_r += SPIN[i] * w[i]
    # gyroscopic: J_r * Omega_r * (omega x e_z) = J_r*Omega_r*(q, -p, 0)
    tx += JR * om_r * qq
    ty += -JR * om_r * p
    # -omega x J omega
    tx -= (qq * JZ * r - r * JY * qq)
    ty -= (r * JX * p - p * JZ * r)
    tz -= (p * JY * qq - qq * JX * p)
    dom = np.array([tx / JX, ty / JY, tz / JZ])
    w0, x0, y0, z0 = q
    dq = 0.5 * np.array([
        -x0 * p - y0 * qq - z0 * r,
        w0 * p + y0 * r - z0 * qq,
        w0 * qq - x0 * r + z0 * p,
        w0 * r + x0 * qq - y0 * p])
    dw = (w_cmd - w) / TAU_M
    return np.concatenate([v, acc, dq, dom, dw])


# ----------------------------------------------------------------------------- plan
def make_plan(seed):
    """Set-point function (x, y, z, psi) of time for one flight of the common kind."""
    rng = np.random.default_rng(1000 + seed)
    ax = rng.uniform(0.8, 1.5) * rng.choice([-1, 1])
    ay = rng.uniform(0.8, 1.5) * rng.choice([-1, 1])
    dz = rng.uniform(0.6, 1.0)
    yaw = rng.uniform(1.0, 1.6) * rng.choice([-1, 1])
    rad = rng.uniform(0.8, 1.2)
    per = rng.uniform(4.5, 6.0)
    z0 = -1.5

    def sp(t):
        x = y = 0.0
        z = z0
        psi = 0.0
        if t >= 2.0:
            x = ax
        if t >= 6.0:
            y = ay
            z = z0 - dz
        if t >= 10.0:
            psi = yaw
        if 13.0 <= t < 23.0:
            ph = 2 * math.pi * (t - 13.0) / per
            x = ax + rad * (math.cos(ph) - 1.0)
            y = ay + rad * math.sin(ph)
        if t >= 23.0:
            x, y = ax, ay
            psi = 0.0
            z = z0
        if t >= 26.0:
            x, y = 0.0, 0.0
        return np.array([x, y, z, psi])
    return sp


# ----------------------------------------------------------------------------- controller
class Controller:
    def __init__(self):
        self.m = M * 1.06
        self.kt = KT * 1.07
        self.b = B * 0.92
        self.J = np.array([JX, JY, JZ]) * 1.05
        self.wn = 2.5
        self.ref = None
        self.ref_v = np.zeros(4)
        self.int_p = np.zeros(3)
        self.int_w = np.zeros(3)
        self.kp = np.array([2.5, 2.5, 4.0])
        self.kv = np.array([3.0, 3.0, 4.0])
        self.ki = np.array([0.4, 0.4, 1.0])
        self.kR = np.array([6.0, 6.0, 3.0])
        self.kw = np.array([14.0, 14.0, 8.0])
        self.kwi = np.array([6.0, 6.0, 2.0])
        a = A
        # rows: T, tau_x, tau_y, tau_z  = Mix @ w^2
        mix = np.zeros((4, 4))
        for i in range(4):
            rx, ry = ROT_POS[i]
            mix[0, i] = self.kt
            mix[1, i] = -ry * self.kt
            mix[2, i] = rx * self.kt
            mix[3, i] = SPIN[i] * self.b
        self.mix_inv = np.linalg.inv(mix)
        del a

    def step(self, t, dt, s, sp):
        target = sp(t)
        if self.ref is None:
            self.ref = target.copy()
        # 2nd-order critically damped reference filter
        acc_ref = self.wn ** 2 * (target - self.ref) - 2 * self.wn * self.ref_v
        self.ref_v = self.ref_v + acc_ref * dt
        self.ref = self.ref + self.ref_v * dt
        pos, vel = s[0:3], s[3:6]
        R = quat_to_R(s[6:10])
        om = s[10:13]
        ep = self.ref[:3] - pos
        ev = self.ref_v[:3] - vel
        self.int_p += ep * dt
        a_des = self.kp * ep + self.kv * ev + self.ki * self.int_p + acc_ref[:3]
        F = self.m * (a_des - np.array([0.0, 0.0, G]))     # desired thrust force (world)
        nF = np.linalg.norm(F)
        b3 = -F / nF
        psi_d = self.ref[3]
        c = np.array([math.cos(psi_d), math.sin(psi_d), 0.0])
        b2 = np.cross(b3, c)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        T = -F @ R[:, 2]
        E = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([E[2, 1], E[0, 2], E[1, 0]])
        om_d = -self.kR * eR
        eo = om_d - om
        self.int_w += eo * dt
        tau = self.J * (self.kw * eo + self.kwi * self.int_w) + np.cross(om, self.J * om)
        w2 = self.mix_inv @ np.array([T, tau[0], tau[1], tau[2]])
        w2 = np.clip(w2, W_MIN ** 2, W_MAX ** 2)
        return np.sqrt(w2)


# ----------------------------------------------------------------------------- flight
def fly(case, seed):
    scale, cog, truth = case_truth(case)
    sp = make_plan(seed)
    rng = np.random.default_rng(seed)     # sensor noise: same for every case
    ctrl = Controller()
    w_h = math.sqrt(M * G / (4 * KT))
    s = np.zeros(17)
    s[2] = -1.5
    s[6] = 1.0
    s[13:17] = w_h
    n_steps = int(round(DURATION / DT))
    rows = []
    w_cmd = np.full(4, w_h)
    for k in range(n_steps + 1):
        t = k * DT
        if k % CTRL_EVERY == 0:
            w_cmd = ctrl.step(t, CTRL_EVERY * DT, s, sp)
        if k % ROW_EVERY == 0:
            rows.append((t, s.copy()))
        if k == n_steps:
            break
        k1 = derivs(s, w_cmd, scale, cog)
        k2 = derivs(s + 0.5 * DT * k1, w_cmd, scale, cog)
        k3 = derivs(s + 0.5 * DT * k2, w_cmd, scale, cog)
        k4 = derivs(s + DT * k3, w_cmd, scale, cog)
        s = s + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
    # sensors
    out = []
    for j, (t, st) in enumerate(rows):
        phi, theta, psi = R_to_euler(quat_to_R(st[6:10]))
        w = st[13:17] + rng.normal(0.0, 3.0, 4)
        w = np.round(w / 2.0) * 2.0
        pos = st[0:3] + rng.normal(0.0, 0.001, 3)
        att = np.array([phi, theta, psi]) + rng.normal(0.0, 0.002, 3)
        gyr = st[10:13] + rng.normal(0.0, 0.01, 3)
        out.append((t, w, pos if j % 2 == 0 else None, att, gyr))
    return out, truth


def write_log(path, out):
    with open(path, "w") as f:
        f.write("t,w1,w2,w3,w4,x,y,z,phi,theta,psi,p,q,r\n")
        for t, w, pos, att, gyr in out:
            ps = ",".join("%.6f" % v for v in pos) if pos is not None else ",,"
            f.write("%.3f,%s,%s,%s,%s\n" % (
                t, ",".join("%.1f" % v for v in w), ps,
                ",".join("%.6f" % v for v in att), ",".join("%.5f" % v for v in gyr)))


AIRFRAME = """[airframe]
name = "audit40_2kg_x"
mass = 2.0
inertia = [0.028, 0.028, 0.050]
arm_length = 0.225
layout = "x"
rotor_inertia = 6.0e-5
gravity = 9.81

[parameters]
K_T = 1.5e-5
b = 3.5e-7
Kd = [0.15, 0.15, 0.20]
"""

CASES = ["control"] + list(ASYM_SIZES) + list(COG_SIZES)


def main():
    if len(sys.argv) < 2:
        print(__doc__)
        sys.exit(2)
    outdir = sys.argv[1]
    only = sys.argv[2].split(",") if len(sys.argv) > 2 else CASES
    # optional third argument: extra seed pairs "3:4,5:6" -> files CASE_est_s3.csv, CASE_val_s4.csv
    extra = [tuple(int(v) for v in p.split(":")) for p in sys.argv[3].split(",")] if len(sys.argv) > 3 else []
    os.makedirs(outdir, exist_ok=True)
    with open(os.path.join(outdir, "airframe.toml"), "w") as f:
        f.write(AIRFRAME)
    import json
    truths = {}
    for case in only:
        pairs = [(("est", 1, ""), ("val", 2, ""))] if not extra else \
            [(("est", a, "_s%d" % a), ("val", b, "_s%d" % b)) for a, b in extra]
        for (tag, seed, suf) in [x for pr in pairs for x in pr]:
            out, truth = fly(case, seed)
            write_log(os.path.join(outdir, "%s_%s%s.csv" % (case, tag, suf)), out)
            print(case, tag, "rows", len(out), flush=True)
        truths[case] = truth
    if extra:
        return
    with open(os.path.join(outdir, "truth.json"), "w") as f:
        json.dump(truths, f, indent=1)


if __name__ == "__main__":
    main()

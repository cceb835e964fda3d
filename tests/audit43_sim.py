#!/usr/bin/env python3
"""Blind audit 43: acrobatic flights of a 5-inch FPV racer, written as greybox CSV logs.

Usage: python sim.py OUTDIR     (deterministic; regenerates every file bit for bit)

TRUTH (the simulated vehicle):
  mass            0.600 kg
  inertia         Jx=1.20e-3, Jy=1.25e-3, Jz=2.20e-3 kg m^2 (diagonal)
  layout          "x", arm_length l = 0.110 m (hubs at +-l/sqrt2), spins [+1,+1,-1,-1]
  K_T             9.40e-7 N/(rad/s)^2      (max 2800 rad/s -> 7.37 N/rotor, T/W = 5.0)
  b               1.13e-8 N m/(rad/s)^2    (b/K_T = 12 mm)
  Kd              [0.08, 0.08, 0.12] N s/m (world-frame linear drag)
  J_r             5.0e-6 kg m^2 (rotor gyroscopic; given in the airframe)
  motors          first order, tau = 18 ms, speeds clipped to [300, 2800] rad/s
  gravity         9.81
  hidden effect   case 5 only ("rollflip_lag"): the logged w1..w4 are the controller's
                  COMMANDED speeds (the motors lag them by tau = 18 ms -> catalogue motor_lag)
Airframe file starting guesses: K_T x1.3 (1.222e-6), b x0.7 (7.91e-9), Kd x0.5 (0.04,0.04,0.06).

Simulation: unit quaternion + RK4 at 0.5 ms (states p, v, q, omega, rotor speeds);
controller at 1 kHz: geometric position loop + quaternion attitude PD (works through
any attitude) on a model 5-9 % off (m 0.95x, J 0.92x, K_T 1.07x, b 0.93x, no drag).
Flips: a 0.25 s punch (1.9 mg, level) then a min-jerk 360 deg rotation in 0.45 s about
body x (roll flip) or body y (pitch flip) at 0.35 mg, then the position loop recovers.
Yaw spins: yaw-rate profile up to 12-14 rad/s while flying circles (tilt ~15-30 deg).

Sensors, 500 Hz rows (t every 2 ms):
  w1..w4   actual rotor speed (eRPM telemetry: quantised to 1.5 rad/s + 2 rad/s noise)
  x,y,z    motion capture at 100 Hz (every 5th row), 1 mm noise, NED, empty otherwise
  phi,theta,psi  ZYX Euler from the (2 mrad-noise-perturbed) quaternion, principal ranges
  p,q,r    gyro, 0.01 rad/s noise;  ax,ay,az accelerometer (specific force), 0.15 m/s^2 noise
The flight starts in the air hovering at z = -5 m (5 m up).
"""
import json
import os
import sys

import numpy as np

G = 9.81
M = 0.600
J = np.array([1.20e-3, 1.25e-3, 2.20e-3])
L = 0.110
A = L / np.sqrt(2)
POS = np.array([[A, A, 0], [-A, -A, 0], [A, -A, 0], [-A, A, 0]])
SPIN = np.array([1.0, 1.0, -1.0, -1.0])
K_T = 9.40e-7
B = 1.13e-8
KD = np.array([0.08, 0.08, 0.12])
J_R = 5.0e-6
TAU_M = 0.018
W_MIN, W_MAX = 300.0, 2800.0

DT = 0.0005          # integrator step
CTRL_EVERY = 2       # 1 kHz controller
LOG_EVERY = 4        # 500 Hz rows
POS_EVERY = 5        # positions on every 5th row (100 Hz)

# controller's model (5-9 % off)
M_H, J_H, KT_H, B_H = 0.95 * M, 0.92 * J, 1.07 * K_T, 0.93 * B


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def qrot(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def rot2q(R):
    tr = np.trace(R)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif R[1, 1] > R[2, 2]:
        s = np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    else:
        s = np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    return q / np.linalg.norm(q)


def euler_zyx(R):
    """ZYX Euler angles as an IMU logs them: phi, psi in (-pi, pi], theta in [-pi/2, pi/2]."""
    theta = -np.arcsin(np.clip(R[2, 0], -1.0, 1.0))
    phi = np.arctan2(R[2, 1], R[2, 2])
    psi = np.arctan2(R[1, 0], R[0, 0])
    if phi <= -np.pi:
        phi += 2 * np.pi
    if psi <= -np.pi:
        psi += 2 * np.pi
    return phi, theta, psi


def Rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def Ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def deriv(s, w_cmd, kt=K_T, kd=KD):
    """state s = [p(3), v(3), q(4), omega(3), w(4)]"""
    v = s[3:6]
    q = s[6:10]
    om = s[10:13]
    w = s[13:17]
    R = qrot(q)
    f = kt * w * w
    T = f.sum()
    acc = np.array([0, 0, G]) - (T / M) * R[:, 2] - kd * v / M
    tau = np.array([np.sum(-POS[:, 1] * f), np.sum(POS[:, 0] * f), np.sum(SPIN * B * w * w)])
    Om_r = np.sum(SPIN * w)
    tau = tau + J_R * Om_r * np.cross(om, [0, 0, 1.0])
    domega = (tau - np.cross(om, J * om)) / J
    dq = 0.5 * qmul(q, np.array([0.0, om[0], om[1], om[2]]))
    dw = (w_cmd - w) / TAU_M
    return np.concatenate([v, acc, dq, domega, dw]), acc


# ----------------------------------------------------------------- controller
MIX = np.vstack([np.ones(4), -POS[:, 1], POS[:, 0], SPIN * B_H / KT_H])
MIX_INV = np.linalg.inv(MIX)
F_MIN, F_MAX = KT_H * W_MIN ** 2, KT_H * W_MAX ** 2


def mixer(T, tau):
    d = MIX_INV @ np.concatenate([[0.0], tau])
    lo = F_MIN - d.min()
    hi = F_MAX - d.max()
    c = T / 4
    c = np.clip(c, lo, hi) if lo <= hi else 0.5 * (lo + hi)
    f = np.clip(c + d, F_MIN, F_MAX)
    return np.sqrt(f / KT_H)


def min_jerk(s):
    s = np.clip(s, 0, 1)
    return 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5, (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4)


class Flight:
    def __init__(self, kind, seed, duration):
        self.kind = kind
        self.rng = np.random.default_rng(seed)
        self.duration = duration
        rng = self.rng
        self.home = np.array([0.0, 0.0, -5.0])
        acro = kind in ("rollflip", "pitchflip")
        amp = {"control": 3.5, "yawspin": 1.0}.get(kind, 1.2)
        nk = 3
        self.Ax = rng.uniform(0.3, 1.0, (3, nk)) * amp / nk * np.array([[1], [1], [0.5]])
        self.Wx = rng.uniform(0.8, 2.5, (3, nk))
        self.Px = rng.uniform(0, 2 * np.pi, (3, nk))
        self.flips = []
        if acro:
            t = 2.5 + rng.uniform(0, 0.5)
            while t + 1.2 < duration - 1.5:
                self.flips.append(t)
                t += rng.uniform(3.0, 4.0)
        self.flip_sign = [rng.choice([-1.0, 1.0]) for _ in self.flips]
        self.T_PUNCH, self.T_FLIP = 0.25, 0.45
        # yaw spins
        self.spins = []
        if kind == "yawspin":
            t = 2.0
            while t + 3.0 < duration - 1.0:
                self.spins.append((t, rng.uniform(12.0, 14.0) * rng.choice([-1.0, 1.0])))
                t += rng.uniform(4.0, 5.0)
        # torque dither (excitation): random sum of sines
        self.Ad = rng.uniform(0.004, 0.010, (3, 4)) * np.array([[1], [1], [0.4]])
        self.Wd = rng.uniform(6, 30, (3, 4))
        self.Pd = rng.uniform(0, 2 * np.pi, (3, 4))
        self.psi_amp = 0.6 if kind == "control" else 0.3
        self._fpsi = {}

    def ref(self, t):
        ph = self.Wx * t + self.Px
        x = self.home + (self.Ax * np.sin(ph)).sum(1)
        v = (self.Ax * self.Wx * np.cos(ph)).sum(1)
        a = -(self.Ax * self.Wx ** 2 * np.sin(ph)).sum(1)
        if self.kind == "yawspin":   # circles: 2.5 m radius at ~1.1 rad/s
            wc = 1.1
            x = x + np.array([2.5 * np.cos(wc * t) - 2.5, 2.5 * np.sin(wc * t), 0])
            v = v + np.array([-2.5 * wc * np.sin(wc * t), 2.5 * wc * np.cos(wc * t), 0])
            a = a + np.array([-2.5 * wc ** 2 * np.cos(wc * t), -2.5 * wc ** 2 * np.sin(wc * t), 0])
        psi = self.psi_amp * np.sin(0.5 * t)
        r = self.psi_amp * 0.5 * np.cos(0.5 * t)
        for (t0, rmax) in self.spins:
            # yaw-rate bump over 3 s: ramp up 1 s, hold 1 s, down 1 s (integral analytic)
            for (a0, a1, kind) in ((t0, t0 + 1, "up"), (t0 + 1, t0 + 2, "hold"), (t0 + 2, t0 + 3, "down")):
                if t <= a0:
                    continue
                s = min(t, a1) - a0
                if kind == "up":
                    sm, _ = min_jerk(s)
                    # integral of min_jerk over [0, s]
                    integ = 2.5 * s ** 4 - 3 * s ** 5 + s ** 6
                    psi += rmax * integ
                    if t < a1:
                        r += rmax * sm
                elif kind == "hold":
                    psi += rmax * s
                    if t < a1:
                        r += rmax
                else:
                    integ = s - (2.5 * s ** 4 - 3 * s ** 5 + s ** 6)
                    psi += rmax * integ
                    if t < a1:
                        r += rmax * (1 - min_jerk(s)[0])
        return x, v, a, psi, r

    def control(self, t, s):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = qrot(q)
        xr, vr, ar, psi_d, r_d = self.ref(t)
        dither = (self.Ad * np.sin(self.Wd * t + self.Pd)).sum(1)
        # flip phases
        for i, t0 in enumerate(self.flips):
            sg = self.flip_sign[i]
            if t0 <= t and i not in self._fpsi:
                self._fpsi[i] = euler_zyx(R)[2]
            if t0 <= t < t0 + self.T_PUNCH:
                Rd = Rz(self.flip_psi(i))
                wd = np.zeros(3)
                T = 1.9 * M_H * G
                return self.att(R, om, Rd, wd, T, dither)
            if t0 + self.T_PUNCH <= t < t0 + self.T_PUNCH + self.T_FLIP:
                sp = (t - t0 - self.T_PUNCH) / self.T_FLIP
                ang, dang = min_jerk(sp)
                ang, rate = sg * 2 * np.pi * ang, sg * 2 * np.pi * dang / self.T_FLIP
                if self.kind == "pitchflip":
                    Rd = Rz(self.flip_psi(i)) @ Ry(ang)
                    wd = np.array([0, rate, 0])
                else:
                    Rd = Rz(self.flip_psi(i)) @ Rx(ang)
                    wd = np.array([rate, 0, 0])
                T = 0.35 * M_H * G
                return self.att(R, om, Rd, wd, T, dither)
        # position loop
        kp, kv = np.array([5.0, 5.0, 7.0]), np.array([4.0, 4.0, 5.0])
        ad = kp * (xr - p) + kv * (vr - v) + ar
        ah = np.linalg.norm(ad[:2])
        if ah > 8.0:
            ad[:2] *= 8.0 / ah
        ad[2] = np.clip(ad[2], -8.0, 6.0)
        F = M_H * (ad - np.array([0, 0, G]))
        b3d = -F / np.linalg.norm(F)
        b1c = np.array([np.cos(psi_d), np.sin(psi_d), 0])
        b2d = np.cross(b3d, b1c)
        b2d /= np.linalg.norm(b2d)
        b1d = np.cross(b2d, b3d)
        Rd = np.column_stack([b1d, b2d, b3d])
        T = -F @ R[:, 2]
        T = max(T, 0.1 * M_H * G)
        wd = Rd.T @ np.array([0, 0, r_d])
        return self.att(R, om, Rd, wd, T, dither)

    def flip_psi(self, i):
        return self._fpsi[i]

    def att(self, R, om, Rd, wd, T, dither):
        qe = qmul(rot2q(Rd) * np.array([1, -1, -1, -1]), rot2q(R))
        if qe[0] < 0:
            qe = -qe
        eR = 2 * qe[1:]
        ew = om - R.T @ Rd @ wd
        kr = np.array([220.0, 220.0, 60.0])
        kw = np.array([24.0, 24.0, 14.0])
        tau = J_H * (-kr * eR - kw * ew) + np.cross(om, J_H * om) + dither
        return mixer(T, tau)


def simulate(kind, seed, duration, log_commands=False):
    fl = Flight(kind, seed, duration)
    rng = np.random.default_rng(seed + 1000)
    wh = np.sqrt(M * G / (4 * K_T))
    s = np.zeros(17)
    s[0:3] = fl.home + (fl.Ax * np.sin(fl.Px)).sum(1)
    s[6] = 1.0
    psi0 = 0.0
    s[6:10] = rot2q(Rz(psi0))
    s[13:17] = wh
    n = int(round(duration / DT))
    rows = []
    w_cmd = np.full(4, wh)
    k_row = 0
    for k in range(n + 1):
        t = k * DT
        if k % CTRL_EVERY == 0:
            w_cmd = fl.control(t, s)
        if k % LOG_EVERY == 0:
            d, acc = deriv(s, w_cmd)
            R = qrot(s[6:10])
            # attitude sensor noise: small random rotation
            dn = rng.normal(0, 0.002, 3)
            qn = qmul(s[6:10], np.concatenate([[1.0], 0.5 * dn]))
            qn /= np.linalg.norm(qn)
            phi, th, ps = euler_zyx(qrot(qn))
            wl = (w_cmd if log_commands else s[13:17]).copy()
            wl = np.round(wl / 1.5) * 1.5 + rng.normal(0, 2.0, 4)
            gyro = s[10:13] + rng.normal(0, 0.01, 3)
            sf = R.T @ (acc - np.array([0, 0, G])) + rng.normal(0, 0.15, 3)
            pos = s[0:3] + rng.normal(0, 0.001, 3)
            has_pos = (k_row % POS_EVERY == 0)
            rows.append([t, *wl, *(pos if has_pos else [np.nan] * 3), phi, th, ps, *gyro, *sf])
            k_row += 1
        if k == n:
            break
        # RK4, command held over the step
        k1, _ = deriv(s, w_cmd)
        k2, _ = deriv(s + 0.5 * DT * k1, w_cmd)
        k3, _ = deriv(s + 0.5 * DT * k2, w_cmd)
        k4, _ = deriv(s + DT * k3, w_cmd)
        s = s + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
        s[13:17] = np.clip(s[13:17], W_MIN, W_MAX)
    return np.array(rows), fl


HEADER = "t,w1,w2,w3,w4,x,y,z,phi,theta,psi,p,q,r,ax,ay,az"


def write_csv(path, rows):
    with open(path, "w") as f:
        f.write(HEADER + "\n")
        for r in rows:
            cells = []
            for j, v in enumerate(r):
                if np.isnan(v):
                    cells.append("")
                elif j == 0:
                    cells.append("%.4f" % v)
                else:
                    cells.append("%.7g" % v)
            f.write(",".join(cells) + "\n")


AIRFRAME = """[airframe]
name = "audit43_racer5"
mass = 0.600
inertia = [1.20e-3, 1.25e-3, 2.20e-3]
arm_length = 0.110
layout = "x"
rotor_inertia = 5.0e-6
gravity = 9.81

[parameters]
K_T = 1.222e-6
b = 7.91e-9
Kd = [0.04, 0.04, 0.06]
"""

CASES = [  # name, kind, est seed, val seed, duration est, duration val, log_commands
    ("control", "control", 11, 12, 20.0, 16.0, False),
    ("rollflip", "rollflip", 21, 22, 20.0, 16.0, False),
    ("pitchflip", "pitchflip", 31, 32, 20.0, 16.0, False),
    ("yawspin", "yawspin", 41, 42, 20.0, 16.0, False),
    ("rollflip_lag", "rollflip", 51, 52, 20.0, 16.0, True),
]


def stats(rows):
    phi, th, ps = rows[:, 8], rows[:, 9], rows[:, 10]
    tilt = np.degrees(np.arccos(np.clip(np.cos(phi) * np.cos(th), -1, 1)))
    return dict(max_tilt_deg=float(tilt.max()), max_abs_theta_deg=float(np.degrees(np.abs(th).max())),
                phi_jumps=int((np.abs(np.diff(phi)) > np.pi).sum()),
                psi_jumps=int((np.abs(np.diff(ps)) > np.pi).sum()),
                max_rate=[float(np.abs(rows[:, j]).max()) for j in (11, 12, 13)],
                w_min=float(rows[:, 1:5].min()), w_max=float(rows[:, 1:5].max()))


def phi_unwrapped_variant(path):
    """What a user might try: the same log with phi continued across its +-pi wraps
    (np.unwrap on the logged, rounded column), written beside it as *_phiunwrap.csv."""
    d = np.genfromtxt(path, delimiter=",", skip_header=1)
    d[:, 8] = np.unwrap(d[:, 8])
    write_csv(path.replace(".csv", "_phiunwrap.csv"), d)
    return float(np.abs(d[:, 8]).max())


def main(out):
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "airframe.toml"), "w") as f:
        f.write(AIRFRAME)
    info = {"truth": {"mass": M, "inertia": J.tolist(), "arm_length": L, "K_T": K_T, "b": B,
                      "Kd": KD.tolist(), "J_r": J_R, "tau_m": TAU_M}, "flights": {}}
    for name, kind, se, sv, de, dv, lc in CASES:
        for tag, seed, dur in (("est", se, de), ("val", sv, dv)):
            rows, fl = simulate(kind, seed, dur, log_commands=lc)
            path = os.path.join(out, f"{name}_{tag}.csv")
            write_csv(path, rows)
            st = stats(rows)
            st["flips"] = fl.flips
            st["spins"] = fl.spins
            # the same flight with the flips cut out: segments between flips
            if fl.flips:
                bounds = []
                start = 0.0
                for t0 in fl.flips:
                    bounds.append((start, t0 - 0.1))
                    start = t0 + fl.T_PUNCH + fl.T_FLIP + 0.6
                bounds.append((start, dur))
                segs = []
                for j, (a, b_) in enumerate(bounds):
                    m = (rows[:, 0] >= a - 1e-9) & (rows[:, 0] <= b_ + 1e-9)
                    if b_ - a < 1.5:
                        continue
                    p = os.path.join(out, f"{name}_{tag}_cut{j + 1}.csv")
                    write_csv(p, rows[m])
                    segs.append([a, b_])
                st["cut_segments"] = segs
            info["flights"][f"{name}_{tag}"] = st
            if name == "rollflip":
                phi_unwrapped_variant(path)
            print(name, tag, json.dumps(st))
    with open(os.path.join(out, "truth.json"), "w") as f:
        json.dump(info, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "flights")

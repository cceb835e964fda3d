#!/usr/bin/env python3
"""Blind audit 37: an independent quadrotor simulator and the user-mistake variants.

    python sim.py OUTDIR

Writes, deterministically (seeded), one truth flight (50 s) and one validation flight (30 s)
of the same vehicle, and, for each case, CASE/flight.csv, CASE/val.csv, CASE/airframe.toml:

  control    correct files (contract: NED, FRD, ZYX Euler in rad, w in rad/s, layout "x")
  numbering  w1..w4 columns in Betaflight's motor order (1 rear-right, 2 front-right,
             3 rear-left, 4 front-left) while the airframe says layout "x" (contract order:
             1 front-right, 2 back-left, 3 front-left, 4 back-right = PX4's order)
  spin       airframe as [[rotor]] tables at the "x" positions with every spin flipped
  zup        positions written NWU (x north, y west, z up), e.g. a z-up motion capture
  altitude   (extra) only z written up (height positive), x, y still north/east
  rpm        rotor speeds in RPM
  inertia    airframe inertia 25 % too high on every axis
  mass       airframe mass 8 % too low
  degrees    phi, theta, psi in degrees (rates still rad/s)
  eulerflu   (extra) attitude converted to ENU/FLU Euler angles (phi, -theta, pi/2 - psi),
             positions left NED
  eulerinv   (extra) Euler angles of the inverse rotation (world w.r.t. body)
  eulerflu_fix, eulerinv_fix  (extra) the two above after doing what greybox's refusal says
  eulerflu_fix2, eulerinv_fix2  (extra) ... and then what the second refusal says (psi -+ 180 deg)
  gyroflu    (extra) gyro q, r negated (FLU body rates), everything else right
  pitchsign  (extra) theta negated, everything else right
  gyroflu_fix, pitchsign_fix, pitchsign_fix_pq  (extra) after doing what the refusal says
  pitchsign_fix2  (extra) pitchsign_fix_pq after doing what its refusal says (psi - 90 deg)
  pitchsign_fix3  (extra) ... and then what the next refusal says (swap w1 and w2)

TRUTH (SI, contract conventions):
  mass 0.700 kg, inertia diag(3.0e-3, 3.2e-3, 5.5e-3) kg m^2, arm_length l = 0.125 m
  (layout "x": a = l/sqrt(2)), rotor_inertia J_r = 1.0e-5 kg m^2, g = 9.81
  K_T = 8.0e-7 N/(rad/s)^2 (hover ~1465 rad/s = 14 000 RPM), b = 1.0e-8 N m/(rad/s)^2
  Kd = [0.08, 0.08, 0.12] N s/m (world-frame linear drag). No other effect, no wind.
  Motors: first-order lag tau = 20 ms toward the controller's command, speeds 300..3000 rad/s.

Dynamics: quaternion rigid body integrated by RK4 at 1 ms (state: NED position, world velocity,
quaternion body->world, body rates, 4 motor speeds); forces/torques exactly the contract's base
model (thrust K_T w^2 along -z_b at r_i, reaction spin_i b w^2 about +z_b, gyroscopic
J_r Omega_r (omega x e_z), drag -Kd v).
Controller (500 Hz): own geometric cascade (position PID -> thrust vector -> SO(3) attitude PD
-> torques) with its own model (K_T 10 % high, b 20 % low, inertia 10 % low), own mixer,
plus a multisine excitation on thrust and torques.
Sensors, on 200 Hz rows: rotor speeds = ESC telemetry of the actual speed (+-2 rad/s noise,
quantised to 10 RPM); attitude 2 mrad white noise, psi wrapped to (-pi, pi]; gyro 0.01 rad/s;
accelerometer 0.05 m/s^2 (FRD specific force); positions from motion capture at 100 Hz (1 mm),
empty cells on the other rows.
"""
import os
import sys

import numpy as np

# ---------------------------------------------------------------- truth
M = 0.700
J = np.diag([3.0e-3, 3.2e-3, 5.5e-3])
L_ARM = 0.125
A = L_ARM / np.sqrt(2)
JR = 1.0e-5
G = 9.81
KT = 8.0e-7
B = 1.0e-8
KD = np.array([0.08, 0.08, 0.12])
TAU_M = 0.020
W_MIN, W_MAX = 300.0, 3000.0
# contract layout "x": 1 FR, 2 BL, 3 FL, 4 BR
POS = np.array([[A, A, 0], [-A, -A, 0], [A, -A, 0], [-A, A, 0]], float)
SPIN = np.array([1.0, 1.0, -1.0, -1.0])

DT = 0.001
CTRL_EVERY = 2       # 500 Hz
LOG_EVERY = 5        # 200 Hz rows
POS_EVERY = 10       # 100 Hz mocap

ez = np.array([0.0, 0.0, 1.0])


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


def rot_zyx(phi, theta, psi):
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    Rz = np.array([[cp, -sp, 0], [sp, cp, 0], [0, 0, 1.0]])
    Ry = np.array([[ct, 0, st], [0, 1.0, 0], [-st, 0, ct]])
    Rx = np.array([[1.0, 0, 0], [0, cf, -sf], [0, sf, cf]])
    return Rz @ Ry @ Rx


def euler_zyx(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    theta = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, theta, psi


def deriv(s, wcmd):
    v = s[3:6]
    q = s[6:10]
    om = s[10:13]
    w = s[13:17]
    R = qrot(q)
    f = KT * w ** 2
    T = f.sum()
    acc = G * ez + (-T * (R @ ez) - KD * v) / M
    tau = np.zeros(3)
    for i in range(4):
        tau += np.cross(POS[i], np.array([0, 0, -f[i]]))
    tau[2] += B * np.sum(SPIN * w ** 2)
    Om_r = np.sum(SPIN * w)
    tau += JR * Om_r * np.cross(om, ez)
    domega = np.linalg.solve(J, tau - np.cross(om, J @ om))
    dq = 0.5 * qmul(q, np.concatenate([[0.0], om]))
    dw = (wcmd - w) / TAU_M
    return np.concatenate([v, acc, dq, domega, dw])


def vee(S):
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


class Controller:
    def __init__(self, rng):
        self.KT = KT * 1.10
        self.B = B * 0.80
        self.J = J * 0.90
        self.m = M * 1.03
        self.ki = np.zeros(3)
        # multisine excitation (thrust N, torques N m)
        self.freqs = rng.uniform(0.2, 6.0, size=(4, 8))
        self.phases = rng.uniform(0, 2 * np.pi, size=(4, 8))
        self.amp = np.array([0.9, 0.035, 0.035, 0.012]) / np.sqrt(4.0)
        mix = np.zeros((4, 4))
        mix[0] = self.KT
        mix[1] = -POS[:, 1] * self.KT
        mix[2] = POS[:, 0] * self.KT
        mix[3] = SPIN * self.B
        self.mixinv = np.linalg.inv(mix)

    def __call__(self, t, s, ref, dt):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        pr, vr, psir = ref
        R = qrot(q)
        e = pr - p
        self.ki = np.clip(self.ki + e * dt, -1, 1)
        a_des = np.array([4.0, 4.0, 6.0]) * e + np.array([3.0, 3.0, 4.0]) * (vr - v) \
            + np.array([0.5, 0.5, 1.0]) * self.ki
        f_des = self.m * (a_des - G * ez)          # world force wanted (NED)
        n = np.linalg.norm(f_des)
        b3 = -f_des / n
        # limit tilt to ~50 deg
        if b3[2] < np.cos(np.radians(50)):
            h = b3[:2] / (np.linalg.norm(b3[:2]) + 1e-12)
            b3 = np.array([h[0] * np.sin(np.radians(50)), h[1] * np.sin(np.radians(50)),
                           np.cos(np.radians(50))])
        b1c = np.array([np.cos(psir), np.sin(psir), 0.0])
        b2 = np.cross(b3, b1c)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        T = -f_des @ (R @ ez)
        eR = 0.5 * vee(Rd.T @ R - R.T @ Rd)
        KR = np.array([160.0, 160.0, 45.0])
        KW = np.array([24.0, 24.0, 12.0])
        tau = self.J @ (-KR * eR - KW * om) + np.cross(om, self.J @ om)
        ex = (self.amp[:, None] * np.sin(2 * np.pi * self.freqs * t + self.phases)).sum(axis=1)
        u = np.array([T + ex[0], tau[0] + ex[1], tau[1] + ex[2], tau[2] + ex[3]])
        w2 = self.mixinv @ u
        return np.sqrt(np.clip(w2, W_MIN ** 2, W_MAX ** 2))


def reference(t, kind):
    """Setpoint (position NED, velocity, yaw) of the manoeuvre schedule."""
    z0 = -1.5
    if kind == "truth":
        if t < 3:
            return np.array([0, 0, z0]), np.zeros(3), 0.0
        if t < 6:
            return np.array([1.5, 0, z0]), np.zeros(3), 0.0
        if t < 9:
            return np.array([1.5, -1.5, z0 - 0.5]), np.zeros(3), 0.5
        if t < 21:   # circle r=1.8 m, 2.4 m/s, yaw following
            th = (t - 9) * 1.35
            c = np.array([0.0, -1.5, z0])
            p = c + 1.8 * np.array([np.cos(th) - 1.0, np.sin(th), 0])
            v = 1.8 * 1.35 * np.array([-np.sin(th), np.cos(th), 0])
            return p, v, 0.5 + 0.3 * (t - 9)
        if t < 27:   # yaw turns in place
            return np.array([0, 0, z0]), np.zeros(3), 4.1 - 2.0 * (t - 21) if t < 24 else -1.9 + 1.5 * (t - 24)
        if t < 33:   # climb / descent
            zz = z0 - 2.0 * np.sin(np.pi * (t - 27) / 6) ** 2
            return np.array([0, 0, zz]), np.zeros(3), 2.6
        if t < 43:   # figure eight
            th = (t - 33) * 1.2
            p = np.array([2.0 * np.sin(th), 1.2 * np.sin(2 * th), z0 - 0.3 * np.sin(th)])
            v = np.array([2.4 * np.cos(th), 2.88 * np.cos(2 * th), -0.36 * np.cos(th)])
            return p, v, 2.6 - 0.4 * (t - 33)
        steps = [(np.array([1.0, 1.0, z0]), -1.0), (np.array([-1.0, 0.5, z0 - 1.0]), 0.5),
                 (np.array([0.0, -1.0, z0 + 0.4]), -0.5), (np.array([0, 0, z0]), 0.0)]
        k = min(int((t - 43) / 1.8), 3)
        return steps[k][0], np.zeros(3), steps[k][1]
    else:  # validation flight
        if t < 2:
            return np.array([0, 0, z0]), np.zeros(3), 0.0
        if t < 14:  # ellipse with climbing
            th = (t - 2) * 1.1
            p = np.array([2.2 * np.sin(th), 1.4 * (1 - np.cos(th)), z0 - 0.6 * np.sin(0.5 * th)])
            v = np.array([2.42 * np.cos(th), 1.54 * np.sin(th), -0.33 * np.cos(0.5 * th)])
            return p, v, -0.8 * (t - 2) * 0.5
        if t < 22:
            steps = [(np.array([-1.0, 0.0, z0]), -1.0), (np.array([1.0, -1.0, z0 - 1.5]), 1.5),
                     (np.array([0.5, 1.0, z0 + 0.3]), 3.0), (np.array([0.0, 0.0, z0]), 1.0)]
            return steps[min(int((t - 14) / 2), 3)][0], np.zeros(3), steps[min(int((t - 14) / 2), 3)][1]
        return np.array([0.8 * np.sin(2 * (t - 22)), 0, z0]), np.array([1.6 * np.cos(2 * (t - 22)), 0, 0]), 1.0 - 0.5 * (t - 22)


def fly(duration, kind, seed):
    rng = np.random.default_rng(seed)
    ctrl = Controller(rng)
    whov = np.sqrt(M * G / (4 * KT))
    p0, _, psi0 = reference(0.0, kind)
    s = np.concatenate([p0, np.zeros(3), [np.cos(psi0 / 2), 0, 0, np.sin(psi0 / 2)], np.zeros(3),
                        np.full(4, whov)])
    n = int(round(duration / DT))
    wcmd = np.full(4, whov)
    rows = []
    for k in range(n + 1):
        t = k * DT
        if k % CTRL_EVERY == 0:
            wcmd = ctrl(t, s, reference(t, kind), DT * CTRL_EVERY)
        if k % LOG_EVERY == 0:
            R = qrot(s[6:10])
            d = deriv(s, wcmd)
            fs = R.T @ (d[3:6] - G * ez)
            rows.append((t, s.copy(), fs))
        if k == n:
            break
        k1 = deriv(s, wcmd)
        k2 = deriv(s + 0.5 * DT * k1, wcmd)
        k3 = deriv(s + 0.5 * DT * k2, wcmd)
        k4 = deriv(s + DT * k3, wcmd)
        s = s + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
    # sensors
    out = []
    srng = np.random.default_rng(seed + 1000)
    for i, (t, st, fs) in enumerate(rows):
        R = qrot(st[6:10])
        phi, th, psi = euler_zyx(R)
        w = st[13:17] + srng.normal(0, 2.0, 4)
        rpm = np.round(w * 60 / (2 * np.pi) / 10) * 10
        w = rpm * 2 * np.pi / 60
        att = np.array([phi, th, psi]) + srng.normal(0, 0.002, 3)
        att[2] = (att[2] + np.pi) % (2 * np.pi) - np.pi
        gyro = st[10:13] + srng.normal(0, 0.01, 3)
        acc = fs + srng.normal(0, 0.05, 3)
        pos = st[0:3] + srng.normal(0, 0.001, 3) if (i * LOG_EVERY) % POS_EVERY == 0 else np.full(3, np.nan)
        out.append(np.concatenate([[t], w, pos, att, gyro, acc]))
    return np.array(out)


COLS = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az"]


def write_csv(path, data, cols=COLS):
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for row in data:
            f.write(",".join("" if np.isnan(v) else repr(float(np.round(v, 9))) for v in row) + "\n")


def airframe(name, mass=M, inertia=(3.0e-3, 3.2e-3, 5.5e-3), rotors=None):
    s = "[airframe]\n"
    s += f'name = "{name}"\n'
    s += f"mass = {mass!r}\n"
    s += "inertia = [" + ", ".join(repr(float(round(v, 9))) for v in inertia) + "]\n"
    s += f"arm_length = {L_ARM!r}\n"
    if rotors is None:
        s += 'layout = "x"\n'
    s += f"rotor_inertia = {JR!r}\n"
    s += f"gravity = {G!r}\n\n"
    if rotors is not None:
        for pos, sp in rotors:
            s += "[[rotor]]\n"
            s += "position = [" + ", ".join(repr(float(round(v, 9))) for v in pos) + "]\n"
            s += f"spin = {int(sp)}\n\n"
    s += "[parameters]\nK_T = 1.0e-6\nb = 1.5e-8\nKd = [0.1, 0.1, 0.1]\n"
    return s


def variants(data):
    """Return {case: (data, airframe_text)}; data columns as COLS."""
    out = {}
    I = (3.0e-3, 3.2e-3, 5.5e-3)
    out["control"] = (data, airframe("audit37"))
    d = data.copy()
    # Betaflight order: BF1 = rear-right (contract 4), BF2 = front-right (1),
    # BF3 = rear-left (2), BF4 = front-left (3)
    d[:, 1:5] = data[:, [4, 1, 2, 3]]
    out["numbering"] = (d, airframe("audit37"))
    out["spin"] = (data, airframe("audit37", rotors=[(POS[i], -SPIN[i]) for i in range(4)]))
    d = data.copy()
    d[:, 6] = -data[:, 6]   # NWU: y west
    d[:, 7] = -data[:, 7]   # z up
    out["zup"] = (d, airframe("audit37"))
    d = data.copy()
    d[:, 7] = -data[:, 7]
    out["altitude"] = (d, airframe("audit37"))
    d = data.copy()
    d[:, 1:5] = data[:, 1:5] * 60 / (2 * np.pi)
    out["rpm"] = (d, airframe("audit37"))
    out["inertia"] = (data, airframe("audit37", inertia=tuple(1.25 * v for v in I)))
    out["mass"] = (data, airframe("audit37", mass=round(0.92 * M, 6)))
    d = data.copy()
    d[:, 8:11] = np.degrees(data[:, 8:11])
    out["degrees"] = (d, airframe("audit37"))
    # extra: attitude converted to ENU/FLU (phi, -theta, pi/2 - psi) while positions stay NED
    d = data.copy()
    T = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    F = np.diag([1.0, -1.0, -1.0])
    d2 = data.copy()
    for k in range(len(data)):
        R = rot_zyx(*data[k, 8:11])
        d[k, 8:11] = euler_zyx(T @ R @ F)
        d2[k, 8:11] = euler_zyx(R.T)
    out["eulerflu"] = (d, airframe("audit37"))
    # extra: Euler angles of the inverse rotation (world w.r.t. body: a conjugated quaternion)
    out["eulerinv"] = (d2, airframe("audit37"))
    # follow-ups: what a user gets after following greybox's refusal message on the two above
    d3 = d.copy()
    d3[:, [5, 6]] = d[:, [6, 5]]          # eulerflu: "x and y swapped (ENU ...)": swap x and y
    out["eulerflu_fix"] = (d3, airframe("audit37"))
    d4 = d2.copy()
    d4[:, 10] = np.radians(d2[:, 10])     # eulerinv: "psi in degrees?": psi * pi/180
    out["eulerinv_fix"] = (d4, airframe("audit37"))
    # second follow-ups: "add -180 degrees to psi" / "add 180 degrees to psi"
    d5 = d3.copy()
    d5[:, 10] = d3[:, 10] - np.pi
    out["eulerflu_fix2"] = (d5, airframe("audit37"))
    d6 = d4.copy()
    d6[:, 10] = d4[:, 10] + np.pi
    out["eulerinv_fix2"] = (d6, airframe("audit37"))
    # extra: gyro logged FLU (q, r negated), everything else right (a ROS IMU message)
    d7 = data.copy()
    d7[:, 12:14] = -data[:, 12:14]
    out["gyroflu"] = (d7, airframe("audit37"))
    # extra: pitch logged nose-down positive (theta negated), everything else right
    d8 = data.copy()
    d8[:, 9] = -data[:, 9]
    out["pitchsign"] = (d8, airframe("audit37"))
    # follow-ups of the two above, doing what the refusal says
    d9 = d7.copy()
    d9[:, 1:5] = d7[:, [4, 3, 2, 1]]      # gyroflu: "w1 as rotor 4, w2 as rotor 3, ...": reorder
    out["gyroflu_fix"] = (d9, airframe("audit37"))
    d10 = d8.copy()
    d10[:, [8, 9]] = d8[:, [9, 8]]        # pitchsign: "phi and theta swapped (and p and q?)"
    out["pitchsign_fix"] = (d10, airframe("audit37"))
    d11 = d10.copy()
    d11[:, [11, 12]] = d10[:, [12, 11]]
    out["pitchsign_fix_pq"] = (d11, airframe("audit37"))
    d12 = d11.copy()
    d12[:, 10] = d11[:, 10] - np.pi / 2   # then "add -90 degrees to psi"
    out["pitchsign_fix2"] = (d12, airframe("audit37"))
    d13 = d12.copy()
    d13[:, [1, 2]] = d12[:, [2, 1]]       # then "w1 as rotor 2, w2 as rotor 1": swap w1, w2
    out["pitchsign_fix3"] = (d13, airframe("audit37"))
    return out


def main(outdir):
    os.makedirs(outdir, exist_ok=True)
    truth = fly(50.0, "truth", seed=37)
    val = fly(30.0, "val", seed=3701)
    vt, vv = variants(truth), variants(val)
    for case in vt:
        cd = os.path.join(outdir, case)
        os.makedirs(cd, exist_ok=True)
        write_csv(os.path.join(cd, "flight.csv"), vt[case][0])
        write_csv(os.path.join(cd, "val.csv"), vv[case][0])
        with open(os.path.join(cd, "airframe.toml"), "w") as f:
            f.write(vt[case][1])
    # a few stats for the report
    for nm, d in (("truth", truth), ("val", val)):
        w = d[:, 1:5]
        pos = d[:, 5:8]
        ok = ~np.isnan(pos[:, 0])
        vel = np.diff(pos[ok], axis=0) / 0.01
        print(f"{nm}: rows {len(d)}, w {w.min():.0f}..{w.max():.0f} rad/s, "
              f"tilt max {np.degrees(np.max(np.abs(d[:, 8:10]))):.1f} deg, "
              f"speed max {np.max(np.linalg.norm(vel, axis=1)):.2f} m/s, "
              f"z {pos[ok, 2].min():.2f}..{pos[ok, 2].max():.2f}, rates max {np.max(np.abs(d[:, 11:14])):.2f}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "out")

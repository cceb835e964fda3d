#!/usr/bin/env python3
"""Independent flight simulator for a small indoor 250 g "x" quadrotor (audit 35).

numpy/scipy only; does not import greybox.  `python sim.py OUTDIR` writes every log,
airframe file and truth.json into OUTDIR deterministically (fixed seeds).

Physics (truth): rigid body, unit quaternion (body FRD -> world NED), fixed-step RK4 at
0.5 ms; rotor thrust K_T w^2 along body -z, reaction torque spin*b*w^2 about body +z,
gyroscopic torque J_r*Omega_r*(omega x e_z), linear world drag -Kd v; first-order motors
(tau 15 ms) driven by the controller's commanded speeds.
Controller: 500 Hz cascade (position PD+I -> geometric attitude P -> rate P with feed-
forward), its model 5-10 % off the truth, fed by the estimated attitude (Mahony filter),
the biased gyro and the mocap position.
Sensors: 1 kHz IMU (gyro bias + white noise, accel bias + vibration noise, PT1 filters),
Mahony filter (Kp 0.5, Ki 0.02, heading pulled to mocap yaw); logged rows at ~200 Hz with
timestamp jitter (the IMU's latest 1 kHz sample on each row); mocap 100 Hz (2 mm noise,
3 % dropped frames, one 0.25-s outage) put on the row nearest to each frame; rotor speeds
from ESC eRPM telemetry (7 pole pairs, integer-microsecond electrical period) updated at
100 Hz per motor and held between updates.
"""
import json
import math
import os
import sys

import numpy as np

G = 9.81
DT = 0.0005          # integrator step
CTRL_DIV = 4         # controller at 500 Hz
IMU_DIV = 2          # IMU / Mahony at 1 kHz

# ---------------------------------------------------------------- truth vehicle
TRUTH = dict(
    mass=0.250,
    arm=0.065,                       # hub distance from centre (x layout)
    J=[1.6e-4, 1.7e-4, 2.9e-4],
    K_T=1.39e-7,                     # N/(rad/s)^2 (3-inch props, hover ~2100 rad/s)
    b=1.8e-9,                        # N m/(rad/s)^2 (b/K_T = 12.9 mm)
    Kd=[0.030, 0.032, 0.050],        # N s/m world axes
    J_r=1.0e-6,                      # kg m^2
    tau_m=0.015,                     # s motor lag (logged speeds are the actual ones)
    gyro_bias=[0.020, -0.015, 0.012],
    accel_bias=[0.08, -0.05, 0.10],
)


def rotors(arm):
    a = arm / math.sqrt(2.0)
    pos = np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]], float)
    spin = np.array([1.0, 1.0, -1.0, -1.0])
    return pos, spin


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def q2R(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler_zyx(R):
    phi = math.atan2(R[2, 1], R[2, 2])
    theta = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    psi = math.atan2(R[1, 0], R[0, 0])
    return phi, theta, psi


def eul2q(phi, theta, psi):
    cr, sr = math.cos(phi / 2), math.sin(phi / 2)
    cp, sp = math.cos(theta / 2), math.sin(theta / 2)
    cy, sy = math.cos(psi / 2), math.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


class Vehicle:
    """State: p(3) v(3) q(4) om(3) w(4) [bob pos(3) bob vel(3)]."""

    def __init__(self, tr, effects):
        self.m = tr["mass"]
        self.J = np.array(tr["J"])
        self.KT = tr["K_T"]
        self.b = tr["b"]
        self.Kd = np.array(tr["Kd"])
        self.Jr = tr["J_r"]
        self.tau = tr["tau_m"]
        self.pos, self.spin = rotors(tr["arm"])
        self.eff = effects
        self.Kq = np.array(effects.get("Kq", [0, 0, 0]), float)
        self.payload = effects.get("payload")   # dict(mass, length, k, c, cd)
        self.att_mount = effects.get("imu_mount")  # (roll, pitch) of the IMU, rad

    def n(self):
        return 17 + (6 if self.payload else 0)

    def deriv(self, s, wcmd):
        p, v, q, om, w = s[0:3], s[3:6], s[6:10], s[10:13], s[13:17]
        R = q2R(q)
        T = self.KT * w * w
        fb = np.array([0.0, 0.0, -T.sum()])
        tau = np.array([-(self.pos[:, 1] * T).sum(), (self.pos[:, 0] * T).sum(),
                        (self.spin * self.b * w * w).sum()])
        Om = (self.spin * w).sum()
        tau = tau + self.Jr * Om * np.cross(om, [0.0, 0.0, 1.0])
        F = R @ fb + np.array([0.0, 0.0, self.m * G]) - self.Kd * v
        if self.Kq.any():
            F = F - self.Kq * np.linalg.norm(v) * v
        ds = np.zeros_like(s)
        if self.payload:
            pl = self.payload
            bp, bv = s[17:20], s[20:23]
            d = bp - p
            L = np.linalg.norm(d)
            u = d / L
            stretch = L - pl["length"]
            rate = np.dot(bv - v, u)
            ten = pl["k"] * stretch + pl["c"] * rate
            ten = max(ten, 0.0) if stretch > 0 else 0.0
            F = F + ten * u
            Fb = -ten * u + np.array([0.0, 0.0, pl["mass"] * G]) - pl["cd"] * bv
            ds[17:20] = bv
            ds[20:23] = Fb / pl["mass"]
        ds[0:3] = v
        ds[3:6] = F / self.m
        ds[6:10] = 0.5 * qmul(q, np.array([0.0, om[0], om[1], om[2]]))
        ds[10:13] = (tau - np.cross(om, self.J * om)) / self.J
        ds[13:17] = (wcmd - w) / self.tau
        return ds

    def specific_force(self, s, ds):
        R = q2R(s[6:10])
        return R.T @ (ds[3:6] - np.array([0.0, 0.0, G]))


# ---------------------------------------------------------------- references
def smooth(x, sigma_n):
    k = np.arange(-4 * sigma_n, 4 * sigma_n + 1)
    g = np.exp(-0.5 * (k / sigma_n) ** 2)
    g /= g.sum()
    pad = np.concatenate([np.repeat(x[:1], len(k), 0), x, np.repeat(x[-1:], len(k), 0)])
    out = np.empty_like(pad)
    for j in range(x.shape[1]):
        out[:, j] = np.convolve(pad[:, j], g, mode="same")
    return out[len(k):-len(k)]


def reference(duration, rng, style):
    """Position (NED) and yaw setpoints on a 2-ms grid; smooth; returns t, P, V, A, psi."""
    dt = 0.002
    t = np.arange(0.0, duration + 1.0, dt)
    P = np.zeros((len(t), 3))
    psi = np.zeros(len(t))
    cur = np.array([0.0, 0.0, -1.0])
    cpsi = 0.0
    i = 0
    kinds = ["move", "eight", "move", "yaw", "climb", "move", "hover", "eight", "move", "yaw"]
    if style == "low":
        kinds = ["move", "lowpass", "move", "eight", "lowpass", "yaw", "move", "lowpass"]
    k = 0
    while i < len(t):
        kind = kinds[k % len(kinds)]
        k += 1
        if kind == "hover":
            n = int(1.5 / dt)
            seg = np.repeat(cur[None], n, 0)
            segpsi = np.full(n, cpsi)
        elif kind == "move":
            tgt = np.array([rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), rng.uniform(-1.8, -0.7)])
            dist = np.linalg.norm(tgt - cur)
            T = max(1.2, dist / 1.4)
            n = int(T / dt)
            s = np.linspace(0, 1, n)
            mj = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
            seg = cur + mj[:, None] * (tgt - cur)
            segpsi = np.full(n, cpsi)
            seg = np.vstack([seg, np.repeat(tgt[None], int(0.6 / dt), 0)])
            segpsi = np.concatenate([segpsi, np.full(int(0.6 / dt), cpsi)])
            cur = tgt
        elif kind == "eight":
            per = rng.uniform(4.5, 6.0)
            A = rng.uniform(0.9, 1.3)
            n = int(per * 2 / dt)
            tt = np.arange(n) * dt
            w0 = 2 * np.pi / per
            ramp = np.clip(tt / 1.5, 0, 1) * np.clip((per * 2 - tt) / 1.5, 0, 1)
            seg = np.zeros((n, 3))
            seg[:, 0] = cur[0] + ramp * A * np.sin(w0 * tt)
            seg[:, 1] = cur[1] + ramp * 0.6 * A * np.sin(2 * w0 * tt)
            seg[:, 2] = cur[2] + ramp * 0.25 * np.sin(w0 * tt + 0.5)
            segpsi = np.full(n, cpsi)
        elif kind == "yaw":
            d = rng.choice([-1, 1]) * rng.uniform(1.5, 3.5)
            n = int(3.0 / dt)
            s = np.linspace(0, 1, n)
            mj = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
            segpsi = cpsi + d * mj
            seg = np.repeat(cur[None], n, 0)
            cpsi = cpsi + d
        elif kind == "climb":
            tgt = cur.copy()
            tgt[2] = -1.9 if cur[2] > -1.3 else -0.7
            n = int(1.6 / dt)
            s = np.linspace(0, 1, n)
            mj = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
            seg = cur + mj[:, None] * (tgt - cur)
            segpsi = np.full(n, cpsi)
            cur = tgt
        elif kind == "lowpass":
            # descend to 6 cm above the landing pad (ground z = 0), slide, climb again
            low = np.array([cur[0], cur[1], -0.08])
            n1 = int(2.0 / dt)
            s = np.linspace(0, 1, n1)
            mj = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
            a = cur + mj[:, None] * (low - cur)
            n2 = int(2.5 / dt)
            s2 = np.linspace(0, 1, n2)
            tgt = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), -0.08])
            mj2 = 10 * s2 ** 3 - 15 * s2 ** 4 + 6 * s2 ** 5
            b_ = low + mj2[:, None] * (tgt - low)
            up = np.array([tgt[0], tgt[1], -1.0])
            c = tgt + mj[:, None] * (up - tgt)
            seg = np.vstack([a, b_, c])
            segpsi = np.full(len(seg), cpsi)
            cur = up
        m = min(len(seg), len(t) - i)
        P[i:i + m] = seg[:m]
        psi[i:i + m] = segpsi[:m]
        i += m
    P = smooth(P, int(0.12 / dt))
    psi = smooth(psi[:, None], int(0.12 / dt))[:, 0]
    V = np.gradient(P, dt, axis=0)
    A = np.gradient(V, dt, axis=0)
    return dt, P, V, A, psi


# ---------------------------------------------------------------- flight
def fly(tr, effects, duration, seed, style="normal"):
    rng = np.random.default_rng(seed)
    veh = Vehicle(tr, effects)
    rdt, Pr, Vr, Ar, Psr = reference(duration, rng, style)
    # controller's model: 5-10 % off
    mc, KTc, bc = tr["mass"] * 1.07, tr["K_T"] * 0.93, tr["b"] * 1.09
    Jc = np.array(tr["J"]) * np.array([1.08, 0.94, 1.10])
    pos_c, spin_c = rotors(tr["arm"] * 0.95)
    if veh.payload:
        mc = (tr["mass"] + veh.payload["mass"]) * 1.06
    Mix = np.vstack([np.full(4, KTc), -pos_c[:, 1] * KTc, pos_c[:, 0] * KTc, spin_c * bc])
    Minv = np.linalg.inv(Mix)

    n = veh.n()
    s = np.zeros(n)
    s[0:3] = Pr[0]
    s[6:10] = eul2q(0, 0, Psr[0])
    wh = math.sqrt(veh.m * G / 4 / tr["K_T"]) if not veh.payload else math.sqrt(
        (veh.m + veh.payload["mass"]) * G / 4 / tr["K_T"])
    s[13:17] = wh
    if veh.payload:
        s[17:20] = s[0:3] + np.array([0, 0, veh.payload["length"] + veh.payload["mass"] * G / veh.payload["k"]])
    wcmd = np.full(4, wh)

    gb = np.array(tr["gyro_bias"])
    ab = np.array(tr["accel_bias"])
    # IMU mounting rotation (IMU frame = body rotated by mount angles)
    if veh.att_mount:
        Rm = q2R(eul2q(veh.att_mount[0], veh.att_mount[1], 0.0))  # imu->body
    else:
        Rm = np.eye(3)
    # filters
    gyro_f = gb.copy()
    acc_f = np.array([0, 0, -G]) + ab
    a_g = 1 - math.exp(-2 * math.pi * 150 * 0.001)
    a_a = 1 - math.exp(-2 * math.pi * 40 * 0.001)
    qe = s[6:10].copy()
    if veh.att_mount:
        qe = qmul(qe, eul2q(veh.att_mount[0], veh.att_mount[1], 0.0))
    ei = -0.85 * gb  # bias estimate partly converged while sitting on the pad
    Kp_m, Ki_m, Kyaw = 0.25, 0.02, 0.3
    iint = np.zeros(3)
    psi_mocap = Psr[0]

    nsteps = int(round(duration / DT))
    T_grid = np.arange(nsteps + 1) * DT
    S = np.zeros((nsteps + 1, n))
    D = np.zeros((nsteps + 1, n))
    imu_t, imu_g, imu_a, imu_att = [], [], [], []
    pmeas = s[0:3].copy()
    vest = np.zeros(3)
    # small pilot-like dither on the attitude setpoint
    fr = rng.uniform(0.3, 3.0, 6)
    ph = rng.uniform(0, 2 * np.pi, 6)
    for k in range(nsteps + 1):
        t = k * DT
        d = veh.deriv(s, wcmd)
        S[k] = s
        D[k] = d
        if k == nsteps:
            break
        if k % IMU_DIV == 0:
            om = s[10:13]
            sf = veh.specific_force(s, d)
            g_raw = Rm.T @ om + gb + rng.normal(0, 0.02, 3)
            a_raw = Rm.T @ sf + ab + rng.normal(0, 2.0, 3)
            gyro_f = gyro_f + a_g * (g_raw - gyro_f)
            acc_f = acc_f + a_a * (a_raw - acc_f)
            # Mahony
            Re = q2R(qe)
            an = acc_f / np.linalg.norm(acc_f)
            vv = Re.T @ np.array([0.0, 0.0, -1.0])
            e = np.cross(an, vv)
            if abs(np.linalg.norm(acc_f) - G) > 0.15 * G:
                e = 0.0 * e   # accelerometer not trusted away from 1 g
            _, _, psi_e = euler_zyx(Re)
            dpsi = (psi_mocap - psi_e + np.pi) % (2 * np.pi) - np.pi
            e = e + Kyaw / Kp_m * dpsi * (Re.T @ np.array([0.0, 0.0, 1.0]))
            ei = ei + Ki_m * e * 0.001
            wc = gyro_f + Kp_m * e + ei
            qe = qe + 0.001 * 0.5 * qmul(qe, np.array([0.0, *wc]))
            qe = qe / np.linalg.norm(qe)
            imu_t.append(t)
            imu_g.append(gyro_f.copy())
            imu_a.append(acc_f.copy())
            imu_att.append(euler_zyx(q2R(qe)))
        if k % 20 == 0:  # mocap at 100 Hz for the controller
            pmeas_new = s[0:3] + rng.normal(0, 0.002, 3)
            vest = 0.7 * vest + 0.3 * (s[3:6] + rng.normal(0, 0.03, 3))
            pmeas = pmeas_new
            _, _, psi_mocap = euler_zyx(q2R(s[6:10]))
            psi_mocap += rng.normal(0, 0.003)
        if k % CTRL_DIV == 0:
            j = min(int(round(t / rdt)), len(Pr) - 1)
            ep = Pr[j] - pmeas
            ev = Vr[j] - vest
            iint = np.clip(iint + ep * DT * CTRL_DIV, -0.5, 0.5)
            a_des = 3.0 * ep + 3.2 * ev + 0.4 * iint + Ar[j]
            dith = 0.03 * np.array([math.sin(fr[0] * t + ph[0]) + math.sin(fr[1] * t + ph[1]),
                                    math.sin(fr[2] * t + ph[2]) + math.sin(fr[3] * t + ph[3]), 0.0])
            Fw = mc * (a_des - np.array([0, 0, G]))
            zb = -Fw / np.linalg.norm(Fw)
            ps = Psr[j]
            xc = np.array([math.cos(ps), math.sin(ps), 0.0])
            yb = np.cross(zb, xc)
            yb /= np.linalg.norm(yb)
            xb = np.cross(yb, zb)
            Rd = np.column_stack([xb, yb, zb]) @ q2R(eul2q(dith[0], dith[1], 0))
            Re = q2R(qe)
            Thr = -Fw @ Re[:, 2]
            E = 0.5 * (Rd.T @ Re - Re.T @ Rd)
            eR = np.array([E[2, 1], E[0, 2], E[1, 0]])
            omd = -7.0 * eR
            omm = gyro_f
            taud = Jc * (30.0 * (omd - omm)) + np.cross(omm, Jc * omm)
            w2 = Minv @ np.array([Thr, taud[0], taud[1], taud[2]])
            wcmd = np.sqrt(np.clip(w2, 300.0 ** 2, 4200.0 ** 2))
        # RK4
        k1 = d
        k2 = veh.deriv(s + 0.5 * DT * k1, wcmd)
        k3 = veh.deriv(s + 0.5 * DT * k2, wcmd)
        k4 = veh.deriv(s + DT * k3, wcmd)
        s = s + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
    return dict(T=T_grid, S=S, D=D, imu_t=np.array(imu_t), imu_g=np.array(imu_g),
                imu_a=np.array(imu_a), imu_att=np.array(imu_att), veh=veh, rng=rng)


def hermite(T, S, D, t):
    """Cubic Hermite interpolation of the grid states at times t."""
    i = np.clip(np.searchsorted(T, t, side="right") - 1, 0, len(T) - 2)
    h = T[i + 1] - T[i]
    u = ((t - T[i]) / h)[:, None]
    h = h[:, None]
    h00 = 2 * u ** 3 - 3 * u ** 2 + 1
    h10 = u ** 3 - 2 * u ** 2 + u
    h01 = -2 * u ** 3 + 3 * u ** 2
    h11 = u ** 3 - u ** 2
    return h00 * S[i] + h10 * h * D[i] + h01 * S[i + 1] + h11 * h * D[i + 1]


def write_log(path, fl, seed, rate=200.0, mocap_rate=100.0, outage=(12.0, 12.25)):
    rng = np.random.default_rng(seed + 1000)
    T, S, D = fl["T"], fl["S"], fl["D"]
    dur = T[-1]
    per = 1.0 / rate
    nrow = int((dur - 0.02) / per)
    tr = 0.01 + np.arange(nrow) * per + rng.normal(0, 0.03 * per, nrow)
    assert np.all(np.diff(tr) > 0)
    tr = np.round(tr, 6)
    # IMU: latest 1 kHz sample at or before each row
    it = fl["imu_t"]
    ii = np.searchsorted(it, tr, side="right") - 1
    gyro = fl["imu_g"][ii]
    acc = fl["imu_a"][ii]
    att = fl["imu_att"][ii]
    # rotor telemetry: 100 Hz per motor, staggered; eRPM period quantised to 1 us
    Sw = hermite(T, S[:, 13:17], D[:, 13:17], tr)  # unused except shape
    W = np.zeros((nrow, 4))
    for m in range(4):
        tt = np.arange(0.0025 * m, dur, 0.01)
        wv = hermite(T, S[:, 13 + m:14 + m], D[:, 13 + m:14 + m], tt)[:, 0]
        rpm = wv * 60 / (2 * np.pi)
        erpm = rpm * 7
        period = np.round(60e6 / erpm)
        wq = (60e6 / period) / 7 * 2 * np.pi / 60
        j = np.searchsorted(tt, tr, side="right") - 1
        W[:, m] = wq[np.clip(j, 0, None)]
    # mocap: frames at 100 Hz, offset 3.3 ms, 3 % dropped, one outage; nearest row
    ft = np.arange(0.0033, dur - 0.02, 1.0 / mocap_rate)
    keep = rng.random(len(ft)) > 0.03
    keep &= ~((ft > outage[0]) & (ft < outage[1]))
    ft = ft[keep]
    P = hermite(T, S[:, 0:3], D[:, 0:3], ft) + rng.normal(0, 0.002, (len(ft), 3))
    X = np.full((nrow, 3), np.nan)
    jr = np.clip(np.searchsorted(tr, ft), 1, nrow - 1)
    jr = np.where(np.abs(tr[jr - 1] - ft) < np.abs(tr[jr] - ft), jr - 1, jr)
    X[jr] = P
    phi, theta, psi = att[:, 0], att[:, 1], att[:, 2]
    cols = dict(t=tr, w1=W[:, 0], w2=W[:, 1], w3=W[:, 2], w4=W[:, 3], x=X[:, 0], y=X[:, 1],
                z=X[:, 2], phi=phi, theta=theta, psi=psi, p=gyro[:, 0], q=gyro[:, 1],
                r=gyro[:, 2], ax=acc[:, 0], ay=acc[:, 1], az=acc[:, 2])
    fmt = dict(t="%.6f")
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for r in range(nrow):
            cells = []
            for c, v in cols.items():
                x = v[r]
                if np.isnan(x):
                    cells.append("")
                elif c == "t":
                    cells.append("%.6f" % x)
                elif c.startswith("w"):
                    cells.append("%.3f" % x)
                else:
                    cells.append("%.6g" % x)
            f.write(",".join(cells) + "\n")
    return cols


def airframe_text(name, mass, arm, J, K_T, b, Jr, Kd=(0.1, 0.1, 0.1), extra=""):
    return f"""# {name}: a user's airframe file (mass and arm measured, inertia from CAD,
# K_T and b guessed from a prop datasheet)
[airframe]
name = "{name}"
mass = {mass:.4f}
inertia = [{J[0]:.3e}, {J[1]:.3e}, {J[2]:.3e}]
arm_length = {arm:.4f}
layout = "x"
rotor_inertia = {Jr:.2e}
gravity = 9.81
{extra}
[parameters]
K_T = {K_T:.3e}
b = {b:.3e}
Kd = [{Kd[0]}, {Kd[1]}, {Kd[2]}]
"""


def main(out):
    os.makedirs(out, exist_ok=True)
    tr = TRUTH
    truth = dict(vehicle=dict(tr), cases={})
    m_meas = tr["mass"] * 1.012
    arm_meas = tr["arm"] * 0.99
    J_cad = [tr["J"][0] * 1.15, tr["J"][1] * 1.12, tr["J"][2] * 0.88]
    KT_g, b_g = tr["K_T"] * 1.40, tr["b"] * 0.62
    with open(os.path.join(out, "airframe.toml"), "w") as f:
        f.write(airframe_text("tiny250", m_meas, arm_meas, J_cad, KT_g, b_g, 1.2e-6))
    payload = dict(mass=0.035, length=0.25, k=300.0, c=0.3, cd=0.003)
    with open(os.path.join(out, "airframe_payload.toml"), "w") as f:
        f.write(airframe_text("tiny250_payload", (tr["mass"] + payload["mass"]) * 1.01,
                              arm_meas, J_cad, KT_g, b_g, 1.2e-6))
    cases = [
        ("a_control_est", {}, 40.0, 11, "normal"),
        ("a_control_val", {}, 25.0, 12, "normal"),
        ("b_qdrag_est", {"Kq": [0.012, 0.012, 0.012]}, 40.0, 21, "normal"),
        ("b_qdrag_val", {"Kq": [0.012, 0.012, 0.012]}, 25.0, 22, "normal"),
        ("b2_imumount_est", {"imu_mount": (0.035, -0.025)}, 40.0, 41, "normal"),
        ("b2_imumount_val", {"imu_mount": (0.035, -0.025)}, 25.0, 42, "normal"),
        ("c_payload_est", {"payload": payload}, 40.0, 31, "normal"),
        ("c_payload_val", {"payload": payload}, 25.0, 32, "normal"),
    ]
    only = os.environ.get("SIM_ONLY")
    for name, eff, dur, seed, style in cases:
        if only and not name.startswith(only):
            continue
        fl = fly(tr, eff, dur, seed, style)
        cols = write_log(os.path.join(out, name + ".csv"), fl, seed)
        truth["cases"][name] = dict(effects={k: (list(v) if isinstance(v, tuple) else v)
                                             for k, v in eff.items()}, duration=dur,
                                    seed=seed)
        S = fl["S"]
        truth["cases"][name]["max_speed"] = float(np.max(np.linalg.norm(S[:, 3:6], axis=1)))
        truth["cases"][name]["max_tilt_deg"] = float(np.degrees(np.max(np.arccos(
            np.clip(1 - 2 * (S[:, 7] ** 2 + S[:, 8] ** 2), -1, 1)))))
        truth["cases"][name]["z_range"] = [float(S[:, 2].min()), float(S[:, 2].max())]
        print(name, "done", truth["cases"][name]["max_speed"], truth["cases"][name]["max_tilt_deg"],
              flush=True)
    truth["airframe_given"] = dict(mass=m_meas, arm=arm_meas, J=J_cad, K_T=KT_g, b=b_g, J_r=1.2e-6)
    truth["notes"] = ("logged rotor speeds = actual speeds via eRPM telemetry (100 Hz per motor, "
                      "held, 1-us period quantisation); gyro logged = PT1(150 Hz) of biased "
                      "noisy gyro at 1 kHz; accel = PT1(40 Hz) with bias; attitude = Mahony "
                      "(Kp .5, Ki .02) on those; mocap 100 Hz 2 mm nearest row")
    if not only:
        with open(os.path.join(out, "truth.json"), "w") as f:
            json.dump(truth, f, indent=1, sort_keys=True)
    if not only or only == "bad":
        make_bad(out)


# ---------------------------------------------------------------- bad inputs (case d)
def _read(path):
    with open(path) as f:
        lines = f.read().splitlines()
    head = lines[0].split(",")
    rows = [l.split(",") for l in lines[1:]]
    return head, rows


def _write(path, head, rows):
    with open(path, "w") as f:
        f.write(",".join(head) + "\n")
        for r in rows:
            f.write(",".join(r) + "\n")


def _map(head, rows, col, fn, fmt="%.6g"):
    j = head.index(col)
    for r in rows:
        if r[j] != "":
            r[j] = fmt % fn(float(r[j]))


def make_bad(out):
    src = os.path.join(out, "a_control_est.csv")
    bad = os.path.join(out, "bad")
    os.makedirs(bad, exist_ok=True)
    d2r = 180.0 / math.pi

    def variant(name, fn):
        head, rows = _read(src)
        head, rows = fn(head, rows)
        _write(os.path.join(bad, name + ".csv"), head, rows)

    def degrees_all(h, r):
        for c in ["phi", "theta", "psi", "p", "q", "r"]:
            _map(h, r, c, lambda v: v * d2r)
        return h, r

    def degrees_att(h, r):
        for c in ["phi", "theta", "psi"]:
            _map(h, r, c, lambda v: v * d2r)
        return h, r

    def psi_deg(h, r):
        _map(h, r, "psi", lambda v: v * d2r)
        return h, r

    def gyro_degs(h, r):
        for c in ["p", "q", "r"]:
            _map(h, r, c, lambda v: v * d2r)
        return h, r

    def enu(h, r):
        h = list(h)
        ix, iy = h.index("x"), h.index("y")
        h[ix], h[iy] = "y", "x"
        _map(h, r, "z", lambda v: -v)
        return h, r

    def z_up(h, r):
        _map(h, r, "z", lambda v: -v)
        return h, r

    def betaflight_order(h, r):
        # Betaflight quad-X motor order (1 rear-right, 2 front-right, 3 rear-left,
        # 4 front-left) written as w1..w4
        h = list(h)
        j = [h.index(c) for c in ["w1", "w2", "w3", "w4"]]
        for row in r:
            fr, bl, fl, br = [row[k] for k in j]
            row[j[0]], row[j[1]], row[j[2]], row[j[3]] = br, fr, bl, fl
        return h, r

    def ms(h, r):
        _map(h, r, "t", lambda v: v * 1000.0, "%.3f")
        return h, r

    def dup_rows(h, r):
        out_rows = []
        for k, row in enumerate(r):
            out_rows.append(row)
            if 2000 <= k < 2010:
                out_rows.append(list(row))
        return h, out_rows

    def typo(h, r):
        h = list(h)
        h[h.index("theta")] = "thetha"
        return h, r

    def rpm(h, r):
        for c in ["w1", "w2", "w3", "w4"]:
            _map(h, r, c, lambda v: v * 60 / (2 * math.pi), "%.1f")
        return h, r

    def erpm(h, r):
        for c in ["w1", "w2", "w3", "w4"]:
            _map(h, r, c, lambda v: v * 60 / (2 * math.pi) * 7 / 100, "%.0f")
        return h, r

    def acc_g(h, r):
        for c in ["ax", "ay", "az"]:
            _map(h, r, c, lambda v: v / G)
        return h, r

    def mm(h, r):
        for c in ["x", "y", "z"]:
            _map(h, r, c, lambda v: v * 1000.0)
        return h, r

    def revs(h, r):
        for c in ["w1", "w2", "w3", "w4"]:
            _map(h, r, c, lambda v: v / (2 * math.pi), "%.3f")
        return h, r

    def phi_theta_swapped(h, r):
        h = list(h)
        a, b_ = h.index("phi"), h.index("theta")
        h[a], h[b_] = "theta", "phi"
        a, b_ = h.index("p"), h.index("q")
        h[a], h[b_] = "q", "p"
        return h, r

    for name, fn in [("deg_all", degrees_all), ("deg_att_only", degrees_att),
                     ("psi_deg", psi_deg), ("gyro_degs", gyro_degs), ("enu", enu),
                     ("z_up", z_up), ("betaflight_order", betaflight_order), ("ms", ms),
                     ("dup_rows", dup_rows), ("typo", typo), ("rpm", rpm), ("erpm100", erpm),
                     ("acc_g", acc_g), ("mm", mm), ("revs", revs),
                     ("phi_theta_swapped", phi_theta_swapped)]:
        variant(name, fn)
    tr = TRUTH
    with open(os.path.join(bad, "airframe_cad_nonphysical.toml"), "w") as f:
        f.write(airframe_text("cad", tr["mass"] * 1.012, tr["arm"] * 0.99,
                              [tr["J"][0] * 0.86, tr["J"][1] * 0.88, tr["J"][2] * 1.15],
                              tr["K_T"] * 1.4, tr["b"] * 0.62, 1.2e-6))
    with open(os.path.join(bad, "airframe_grams.toml"), "w") as f:
        f.write(airframe_text("grams", 253.0, tr["arm"] * 0.99,
                              [tr["J"][0] * 1.15, tr["J"][1] * 1.12, tr["J"][2] * 0.88],
                              tr["K_T"] * 1.4, tr["b"] * 0.62, 1.2e-6))
    with open(os.path.join(bad, "airframe_plus.toml"), "w") as f:
        f.write(airframe_text("plus", tr["mass"] * 1.012, tr["arm"] * 0.99,
                              [tr["J"][0] * 1.15, tr["J"][1] * 1.12, tr["J"][2] * 0.88],
                              tr["K_T"] * 1.4, tr["b"] * 0.62, 1.2e-6).replace('"x"', '"plus"'))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "data")

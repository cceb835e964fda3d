#!/usr/bin/env python3
"""Independent outdoor PX4-like quadrotor simulator (audit24).

Vendored as written by blind audit 24 (a helper session that read only the README, the
contract and docs/VALIDATION.md), for tests/test_audit24_sim.py; only this paragraph added.

Own code: scipy solve_ivp between 400 Hz controller ticks, cascaded controller
(position P -> velocity PID -> attitude P -> rate PID), own quad-X mixer (PX4 order,
same as greybox contract "x": 1 FR, 2 BL, 3 FL, 4 BR; spin +1,+1,-1,-1), own
Mahony/attitude_estimator_q-like estimator (gyro integration + accel tilt correction
with GNSS-velocity acceleration compensation + magnetometer heading correction).

Frames: NED world, FRD body, ZYX Euler, R maps body->world. Thrust along body -z.
Logged at 100 Hz: ESC RPM telemetry at 50 Hz held, GNSS x,y at 10 Hz (0.3 m), baro z at
25 Hz (0.10 m), estimator attitude, gyro and accel with bias + noise.

Usage: python sim.py  -> writes everything under /tmp/audit24/data
"""
import json
import os
import sys

import numpy as np
from scipy.integrate import solve_ivp

G = 9.81
DATA = "/tmp/audit24/data"

TRUTH = dict(
    mass=1.5,
    inertia=[0.021, 0.021, 0.037],
    arm=0.25,
    J_r=3.0e-5,
    K_T=1.1e-5,
    b=1.1e-5 * 0.014,  # b/K_T = 0.014 m
    Kd=[0.25, 0.25, 0.35],
    tau_motor=0.04,
)
SPIN = np.array([1.0, 1.0, -1.0, -1.0])


def rotor_pos(arm):
    a = arm / np.sqrt(2)
    return np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]])


# ---------------------------------------------------------------- math helpers
def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def q2R(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler2q(phi, th, psi):
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(th / 2), np.sin(th / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


def R2euler(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    th = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, th, psi


def R2q(R):
    return euler2q(*R2euler(R))


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


# ---------------------------------------------------------------- wind
class Wind:
    def __init__(self, steady, gust_sd, seed, T, tau=3.0):
        self.steady = np.array(steady, float)
        self.t = np.arange(-10.0, T + 1.0, 0.01)
        rng = np.random.default_rng(seed)
        g = np.zeros((len(self.t), 2))
        a = np.exp(-0.01 / tau)
        for k in range(1, len(self.t)):
            g[k] = a * g[k - 1] + np.sqrt(1 - a * a) * gust_sd * rng.standard_normal(2)
        self.g = g

    def __call__(self, t):
        gx = np.interp(t, self.t, self.g[:, 0])
        gy = np.interp(t, self.t, self.g[:, 1])
        return np.array([self.steady[0] + gx, self.steady[1] + gy, 0.0])


# ---------------------------------------------------------------- plant
class Plant:
    def __init__(self, thrust_scale=(1, 1, 1, 1), Kq=0.0, wind=None):
        T = TRUTH
        self.m = T["mass"]
        self.J = np.diag(T["inertia"])
        self.Jinv = np.linalg.inv(self.J)
        self.r = rotor_pos(T["arm"])
        self.KT = T["K_T"] * np.array(thrust_scale, float)
        self.b = T["b"] * np.array(thrust_scale, float)
        self.Kd = np.array(T["Kd"])
        self.Kq = Kq
        self.Jr = T["J_r"]
        self.tau_m = T["tau_motor"]
        self.wind = wind

    def rhs(self, t, s, wcmd):
        v = s[3:6]
        q = s[6:10]
        om = s[10:13]
        w = s[13:17]
        R = q2R(q)
        Ti = self.KT * w * w
        F_body = np.array([0, 0, -Ti.sum()])
        vw = self.wind(t) if self.wind is not None else np.zeros(3)
        va = v - vw
        Fd = -self.Kd * va - self.Kq * np.linalg.norm(va) * va
        acc = np.array([0, 0, G]) + (R @ F_body + Fd) / self.m
        tau = np.zeros(3)
        for i in range(4):
            tau += np.cross(self.r[i], [0, 0, -Ti[i]])
        tau[2] += np.sum(SPIN * self.b * w * w)
        Om_r = np.sum(SPIN * w)
        tau += self.Jr * Om_r * np.cross(om, [0, 0, 1.0])
        domega = self.Jinv @ (tau - np.cross(om, self.J @ om))
        dq = 0.5 * qmul(q, np.r_[0.0, om])
        dw = (wcmd - w) / self.tau_m
        return np.r_[v, acc, dq, domega, dw]

    def specific_force(self, t, s, wcmd):
        d = self.rhs(t, s, wcmd)
        R = q2R(s[6:10])
        return R.T @ (d[3:6] - np.array([0, 0, G]))


# ---------------------------------------------------------------- estimator
class Estimator:
    """attitude_estimator_q-like: quaternion complementary filter with bias."""

    def __init__(self, q0, kp_acc=0.2, kp_mag=0.1, ki=0.05, mag_w=(0.6, 0.0, 0.8)):
        self.q = np.array(q0, float)
        self.bias = np.zeros(3)
        self.kp_acc, self.kp_mag, self.ki = kp_acc, kp_mag, ki
        self.mag_w = np.array(mag_w) / np.linalg.norm(mag_w)
        self.acc_comp = np.zeros(3)  # world accel estimate from GNSS velocity

    def update(self, gyro, acc, mag, dt):
        R = q2R(self.q)
        corr = np.zeros(3)
        # tilt: measured "down" direction in body, from specific force compensated
        f_w_expected = self.acc_comp - np.array([0, 0, G])  # world specific force
        f_b_exp_from_world = R.T @ f_w_expected
        n = np.linalg.norm(acc)
        if 0.5 * G < n < 1.5 * G:
            v_meas = acc / n
            v_est = f_b_exp_from_world / np.linalg.norm(f_b_exp_from_world)
            corr += self.kp_acc * np.cross(v_meas, v_est)
        # heading from magnetometer (horizontal part only)
        m_w = R @ mag
        yaw_err = np.arctan2(m_w[1], m_w[0]) - np.arctan2(self.mag_w[1], self.mag_w[0])
        yaw_err = wrap(yaw_err)
        corr += R.T @ np.array([0, 0, -self.kp_mag * yaw_err])
        self.bias += self.ki * corr * dt
        self.bias = np.clip(self.bias, -0.05, 0.05)
        om = gyro + self.bias + corr
        self.q = self.q + 0.5 * qmul(self.q, np.r_[0.0, om]) * dt
        self.q /= np.linalg.norm(self.q)
        return self.q


# ---------------------------------------------------------------- controller
class Controller:
    def __init__(self):
        T = TRUTH
        self.m = T["mass"]
        self.J = np.array(T["inertia"])
        r = rotor_pos(T["arm"])
        KT, b = T["K_T"], T["b"]
        # rows: total thrust, tau_x, tau_y, tau_z ; columns: rotor thrusts
        A = np.vstack([np.ones(4), -r[:, 1], r[:, 0], SPIN * b / KT])
        self.Ainv = np.linalg.inv(A)
        self.KT = KT
        self.kp_pos = np.array([1.0, 1.0, 1.2])
        self.kp_vel = np.array([1.8, 1.8, 4.0])
        self.ki_vel = np.array([0.4, 0.4, 1.5])
        self.kp_att = np.array([6.0, 6.0, 2.8])
        self.kp_rate = np.array([16.0, 16.0, 6.0])
        self.ki_rate = np.array([6.0, 6.0, 2.0])
        self.kd_rate = np.array([0.25, 0.25, 0.0])
        self.int_v = np.zeros(3)
        self.int_r = np.zeros(3)
        self.prev_gyro = None
        self.dgyro = np.zeros(3)

    def step(self, dt, p_sp, v_ff, psi_sp, pos, vel, q_est, gyro):
        # position P -> velocity setpoint
        v_sp = self.kp_pos * (p_sp - pos) + v_ff
        vh = np.linalg.norm(v_sp[:2])
        if vh > 5.0:
            v_sp[:2] *= 5.0 / vh
        v_sp[2] = np.clip(v_sp[2], -2.0, 1.5)
        # velocity PID -> acceleration setpoint
        ev = v_sp - vel
        self.int_v = np.clip(self.int_v + ev * dt, -3, 3)
        a_sp = self.kp_vel * ev + self.ki_vel * self.int_v
        a_sp[:2] = np.clip(a_sp[:2], -5, 5)
        a_sp[2] = np.clip(a_sp[2], -4, 4)
        F = self.m * (a_sp - np.array([0, 0, G]))  # desired force (world): thrust vector
        # tilt limit 35 deg
        fz = -F[2]
        fh = np.linalg.norm(F[:2])
        maxh = fz * np.tan(np.radians(35))
        if fh > maxh:
            F[:2] *= maxh / fh
        zb = -F / np.linalg.norm(F)
        xc = np.array([np.cos(psi_sp), np.sin(psi_sp), 0])
        yb = np.cross(zb, xc)
        yb /= np.linalg.norm(yb)
        xb = np.cross(yb, zb)
        Rsp = np.column_stack([xb, yb, zb])
        R = q2R(q_est)
        thrust = -F @ (R @ np.array([0, 0, 1.0]))
        # attitude P (quaternion error, body frame)
        q_sp = R2q(Rsp)
        qe = qmul(np.r_[q_est[0], -q_est[1:]], q_sp)
        if qe[0] < 0:
            qe = -qe
        rate_sp = 2 * self.kp_att * qe[1:]
        rate_sp = np.clip(rate_sp, [-3.5, -3.5, -1.5], [3.5, 3.5, 1.5])
        # rate PID
        if self.prev_gyro is None:
            self.prev_gyro = gyro.copy()
        dg = (gyro - self.prev_gyro) / dt
        self.dgyro += (dg - self.dgyro) * min(1.0, dt / 0.01)
        self.prev_gyro = gyro.copy()
        er = rate_sp - gyro
        self.int_r = np.clip(self.int_r + er * dt, -0.5, 0.5)
        alpha = self.kp_rate * er + self.ki_rate * self.int_r - self.kd_rate * self.dgyro * 1.0
        tau = self.J * alpha
        Ti = self.Ainv @ np.r_[thrust, tau]
        Ti = np.clip(Ti, 0.05, None)
        return np.clip(np.sqrt(Ti / self.KT), 80.0, 1050.0)


# ---------------------------------------------------------------- trajectories
def smooth_path(waypoints):
    """waypoints: list of (t, x, y, z, psi). Cosine blend between them."""
    wp = np.array(waypoints, float)

    def f(t):
        if t <= wp[0, 0]:
            return wp[0, 1:4].copy(), np.zeros(3), wp[0, 4]
        if t >= wp[-1, 0]:
            return wp[-1, 1:4].copy(), np.zeros(3), wp[-1, 4]
        k = np.searchsorted(wp[:, 0], t) - 1
        t0, t1 = wp[k, 0], wp[k + 1, 0]
        s = (t - t0) / (t1 - t0)
        bl = 0.5 - 0.5 * np.cos(np.pi * s)
        dbl = 0.5 * np.pi * np.sin(np.pi * s) / (t1 - t0)
        p = wp[k, 1:4] + bl * (wp[k + 1, 1:4] - wp[k, 1:4])
        v = dbl * (wp[k + 1, 1:4] - wp[k, 1:4])
        psi = wp[k, 4] + bl * (wp[k + 1, 4] - wp[k, 4])
        return p, v, psi

    return f


H = -12.0  # altitude (NED z)
TRAJ = {
    # estimation: hover, box 12 m sides at ~4 m/s peak (cosine), yaw turns, climb
    "est": [(0, 0, 0, H, 0), (3, 0, 0, H, 0), (7, 12, 0, H, 0), (8, 12, 0, H, 0),
            (12, 12, 12, H, 0), (13, 12, 12, H, 0), (17, 0, 12, H, 0), (18, 0, 12, H, 0),
            (22, 0, 0, H, 0), (23, 0, 0, H, 0), (26, 0, 0, H, 1.6), (29, 0, 0, H - 5, 0.0),
            (32, 0, 0, H - 5, -1.6), (35, 0, 0, H, 0.0), (37, 0, 0, H, 0.0)],
    # validation: hover, yaw turns, diagonal dashes, climb/descent, box part at other yaw
    "val": [(0, 0, 0, H, 0), (2, 0, 0, H, 0), (5, 0, 0, H, 1.2), (8, 0, 0, H, -1.2),
            (10, 0, 0, H, 0), (14, 10, 10, H, 0.5), (15, 10, 10, H, 0.5), (19, 0, 0, H - 4, 0.5),
            (20, 0, 0, H - 4, 0.5), (24, -10, 5, H, -0.8), (25, -10, 5, H, -0.8),
            (29, 0, 0, H, 0), (33, 0, 0, H, 0)],
}


# ---------------------------------------------------------------- flight
def fly(traj, case="A", seed=0, noise=True, wind_on=True, duration=None,
        log_every=4, pre_roll=5.0, true_speeds_log=False):
    rng = np.random.default_rng(seed)
    thrust_scale = (1, 1, 0.92, 1) if case == "B" else (1, 1, 1, 1)
    Kq = 0.05 if case == "D" else 0.0
    gyro_scale = 1.025 if case == "C" else 1.0
    path = smooth_path(TRAJ[traj])
    T_end = TRAJ[traj][-1][0] if duration is None else duration
    wind = Wind((1.2, -0.8) if wind_on else (0, 0), 0.3 if wind_on else 0.0,
                seed + 1000, T_end, tau=3.0)
    plant = Plant(thrust_scale, Kq, wind)
    ctrl = Controller()
    sn = dict(gyro=0.005, gyro_bias=np.array([0.003, -0.002, 0.0015]),
              acc=0.15, acc_bias=np.array([0.06, -0.04, 0.10]), mag=0.01,
              gnss_h=0.30, baro=0.10, esc=2.0, gnss_vel=0.03)
    if not noise:
        sn = {k: (0 * v) for k, v in sn.items()}
    # initial hover trim (level, nominal), with the wind: start level, settle in pre-roll
    w_h = np.sqrt(TRUTH["mass"] * G / (4 * TRUTH["K_T"]))
    s = np.zeros(17)
    p0, _, psi0 = path(0.0)
    s[0:3] = p0
    s[6:10] = euler2q(0, 0, psi0)
    s[13:17] = w_h
    est = Estimator(s[6:10].copy(), kp_acc=0.15, ki=0.1)
    est.bias = -0.9 * sn["gyro_bias"] if noise else np.zeros(3)  # converged on the ground
    if not noise:
        est = None
    dt = 1.0 / 400
    n_ticks = int(round((T_end + pre_roll) / dt))
    wcmd = np.full(4, w_h)
    rows = []
    esc_hold = s[13:17].copy()
    mag_w = np.array([0.6, 0.0, 0.8]) / 1.0
    mag_w /= np.linalg.norm(mag_w)
    gv_prev = None
    acc_lp = np.zeros(3)
    gnss_vel_hold = np.zeros(3)
    for k in range(n_ticks):
        t = k * dt - pre_roll
        R = q2R(s[6:10])
        om = s[10:13]
        gyro = gyro_scale * om + sn["gyro_bias"] + sn["gyro"] * rng.standard_normal(3)
        sf = plant.specific_force(t, s, wcmd)
        acc = sf + sn["acc_bias"] + sn["acc"] * rng.standard_normal(3)
        mag = R.T @ mag_w + sn["mag"] * rng.standard_normal(3)
        # GNSS velocity at 20 Hz for the estimator's acceleration compensation
        if k % 20 == 0:
            gv = s[3:6] + sn["gnss_vel"] * rng.standard_normal(3)
            if gv_prev is not None:
                a_raw = (gv - gv_prev) / 0.05
                acc_lp = a_raw  # 10 Hz GNSS-velocity difference, held (PX4 ATT_ACC_COMP-like)
            gv_prev = gv
        if est is not None:
            est.acc_comp = acc_lp
            q_est = est.update(gyro, acc, mag, dt)
        else:
            q_est = s[6:10].copy()
        p_sp, v_ff, psi_sp = path(max(t, 0.0))
        wcmd = ctrl.step(dt, p_sp, v_ff, psi_sp, s[0:3], s[3:6], q_est, gyro)
        # log row (100 Hz) at tick start (sensor values of this tick)
        if t >= -1e-9 and k % log_every == 0:
            if k % 8 == 0 or true_speeds_log:
                esc_hold = s[13:17] + sn["esc"] * rng.standard_normal(4)
                if true_speeds_log:
                    esc_hold = s[13:17].copy()
            phi, th, psi = R2euler(q2R(q_est))
            row = dict(t=round(t, 6), w1=esc_hold[0], w2=esc_hold[1], w3=esc_hold[2],
                       w4=esc_hold[3])
            ri = int(round(t / dt))
            # GNSS x,y at 10 Hz, baro z at 25 Hz
            if ri % 40 == 0:
                row["x"] = s[0] + sn["gnss_h"] * rng.standard_normal()
                row["y"] = s[1] + sn["gnss_h"] * rng.standard_normal()
            else:
                row["x"] = row["y"] = np.nan
            if ri % 16 == 0 or not noise:
                row["z"] = s[2] + sn["baro"] * rng.standard_normal()
            else:
                row["z"] = np.nan
            if not noise:
                row["x"], row["y"], row["z"] = s[0], s[1], s[2]
            row.update(phi=phi, theta=th, psi=psi, p=gyro[0], q=gyro[1], r=gyro[2],
                       ax=acc[0], ay=acc[1], az=acc[2])
            tphi, tth, tpsi = R2euler(R)
            row.update(true_x=s[0], true_y=s[1], true_z=s[2], true_phi=tphi,
                       true_theta=tth, true_psi=tpsi, true_vx=s[3], true_vy=s[4],
                       true_vz=s[5], true_p=om[0], true_q=om[1], true_r=om[2])
            rows.append(row)
        sol = solve_ivp(plant.rhs, (t, t + dt), s, args=(wcmd,), method="RK45",
                        rtol=1e-8, atol=1e-10)
        s = sol.y[:, -1].copy()
        s[6:10] /= np.linalg.norm(s[6:10])
    return rows


LOG_COLS = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi",
            "p", "q", "r", "ax", "ay", "az"]


def write_csv(rows, path, cols=LOG_COLS):
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for r in rows:
            vals = []
            for c in cols:
                v = r[c]
                if c == "t":
                    vals.append(f"{v:.4f}")
                elif isinstance(v, float) and np.isnan(v):
                    vals.append("")
                else:
                    vals.append(f"{v:.7g}")
            f.write(",".join(vals) + "\n")


def write_truth_csv(rows, path):
    cols = ["t"] + [c for c in rows[0] if c.startswith("true_")]
    write_csv(rows, path, cols)


def airframe_toml(path, KT, b, Kd, name):
    T = TRUTH
    with open(path, "w") as f:
        f.write(f"""[airframe]
name = "{name}"
mass = {T['mass']}
inertia = [{T['inertia'][0]}, {T['inertia'][1]}, {T['inertia'][2]}]
arm_length = {T['arm']}
layout = "x"
rotor_inertia = {T['J_r']}
gravity = {G}

[parameters]
K_T = {KT:.6e}
b = {b:.6e}
Kd = [{Kd[0]}, {Kd[1]}, {Kd[2]}]
""")


SEEDS = {("A", "est"): 11, ("A", "val"): 12, ("B", "est"): 21, ("B", "val"): 22,
         ("C", "est"): 31, ("C", "val"): 32, ("D", "est"): 41, ("D", "val"): 42}


def main(argv):
    os.makedirs(DATA, exist_ok=True)
    T = TRUTH
    airframe_toml(f"{DATA}/truth.toml", T["K_T"], T["b"], T["Kd"], "audit24_truth")
    airframe_toml(f"{DATA}/user.toml", T["K_T"] * 1.25, T["b"] * 0.70, [0.1, 0.1, 0.1],
                  "audit24_user_guess")
    what = argv[1:] or ["check"] + [f"{c}{f}" for c in "ABCD" for f in ("est", "val")]
    for w in what:
        if w.startswith("check"):
            # conventions check: no noise, no wind, speeds logged at every 400 Hz tick
            tr = "val" if w == "check2" else "est"
            rows = fly(tr, case="A", seed=1, noise=False, wind_on=False,
                       duration=10.0 if tr == "est" else 16.0,
                       log_every=1, true_speeds_log=True)
            write_csv(rows, f"{DATA}/{w}_inputs.csv", ["t", "w1", "w2", "w3", "w4"])
            write_truth_csv(rows, f"{DATA}/{w}_truth.csv")
            print("check written", len(rows))
            continue
        case, fl = w[0], w[1:]
        rows = fly(fl, case=case, seed=SEEDS[(case, fl)])
        write_csv(rows, f"{DATA}/{case}_{fl}.csv")
        write_truth_csv(rows, f"{DATA}/{case}_{fl}.truth.csv")
        print(w, "written", len(rows), flush=True)
    truth = dict(T, spin=SPIN.tolist(), wind_steady=[1.2, -0.8], gust_sd=0.3,
                 cases={"A": "base + wind", "B": "rotor 3 thrust&torque x0.92",
                        "C": "gyro scale 1.025", "D": "quadratic drag 0.05 isotropic"},
                 motor_asymmetry_truth_KT_dev=[1 / 0.98 - 1, 1 / 0.98 - 1, 0.92 / 0.98 - 1],
                 K_T_mean_B=0.98 * T["K_T"], b_mean_B=0.98 * T["b"], seeds={f"{k[0]}_{k[1]}": v for k, v in SEEDS.items()})
    with open(f"{DATA}/truth.json", "w") as f:
        json.dump(truth, f, indent=1)


if __name__ == "__main__":
    main(sys.argv)

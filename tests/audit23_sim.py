#!/usr/bin/env python3
"""Independent quadrotor simulator for the audit of greybox (audit23).

Vendored as written by blind audit 23 (a helper session that read only the README, the
contract and docs/VALIDATION.md), for tests/test_audit23_sim.py; only this paragraph added.

Written from greybox's README/CONTRACT conventions only (NED world, FRD body,
ZYX Euler, R = Rz Ry Rx, plus layout rotor 1 front, 2 right, 3 back, 4 left,
spin [-1,+1,-1,+1], thrust K_T w^2 along body -z, reaction torque spin*b*w^2
about body +z, gyroscopic J_r*Omega_r*(omega x e_z), Omega_r = sum(spin*w)).

Own choices: unit quaternion attitude, scipy solve_ivp (RK45, rtol 1e-10)
between the ticks of a 400 Hz geometric SO(3) controller with a nominal model
5-10 % off, RPM-controlled ESCs (first-order 40 ms, saturation set by the
battery voltage), 100 Hz log rows, 50 Hz motion capture with dropouts.

Cases:
  A  control: base model only (world linear drag Kd, yaw torque, gyroscopic).
     Logged w = measured (ESC telemetry) rotor speed + noise.
  B  the log holds the controller's *commanded* speeds; the rotors follow them
     through dw/dt = (w_cmd - w)/0.04 (catalogue motor_lag, tau_m = 40 ms).
  C  hub rotor drag (catalogue hub_rotor_drag form): per rotor
     F_i = -w_i [k_rdh v_ix, k_rdh v_iy, k_rdv v_iz], v_i = R^T v + omega x r_i,
     r_i = rotor position + (0,0,-h_hub); torque r_i x F_i.
  E  outside the catalogue: wake ingestion by the downstream rotor (K_WAKE).
  F  as E, every flight 1 m higher (z0 = -2.5 m), other noise seeds.
  D  outside the catalogue: rotor acceleration reaction torque
     tau_z += J_r * sum(spin_i * dw_i/dt) (the motors' torque to spin the
     props up/down reacts on the body), J_r the same rotor inertia as the
     gyroscopic term.

Usage:  python sim.py            # writes every log/airframe under ./data
        python sim.py --check    # open-loop runs for the greybox simulate check
"""
import json
import os
import sys

import numpy as np
from scipy.integrate import solve_ivp

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")

# ---------------------------------------------------------------- vehicle
G = 9.81
MASS = 2.2
J = np.diag([0.036, 0.036, 0.064])           # kg m^2, J3 > J1 = J2
ARM = 0.30
# 13-inch prop (D = 0.330 m), static C_T ~ 0.090, C_P ~ 0.040 (UIUC-like data
# for 13x4.5 props): K_T = C_T rho D^4 / (4 pi^2) = 3.32e-5 N/(rad/s)^2.
# Reaction torque set to b/K_T = 0.017 m.
K_T = 3.3e-5
B_YAW = 0.017 * K_T                          # 5.61e-7 N m/(rad/s)^2
J_R = 1.7e-4                                 # prop + bell, kg m^2
KD = np.array([0.30, 0.30, 0.40])            # world linear drag, N s/m
TAU_MOTOR = 0.040
POS = np.array([[ARM, 0, 0], [0, ARM, 0], [-ARM, 0, 0], [0, -ARM, 0]], float)
SPIN = np.array([-1.0, 1.0, -1.0, 1.0])
# case C truth
K_RDH = 3.0e-4      # N s/m/(rad/s): 0.12 N s/m per rotor at hover (404 rad/s)
K_RDV = 5.0e-4
H_HUB = 0.04        # hubs 4 cm above the CoG
# case E truth (outside the catalogue): the rotor downstream of the others in
# horizontal flight ingests their wake: T_i *= 1 - min(0.2, K_WAKE*max(0,u_i)^2),
# u_i = -(r_i/|r_i|) . v_b,xy  (m/s; rotor 3 when flying forward, 4 flying right)
K_WAKE = 0.015
W_HOVER = np.sqrt(MASS * G / (4 * K_T))

CTRL_DT = 0.0025
LOG_DT = 0.01


def rotmat_from_quat(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def quat_from_euler(phi, th, psi):
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(th / 2), np.sin(th / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


def euler_from_R(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    th = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, th, psi


def hat(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


class Physics:
    """state: p(3) v(3) q(4) omega(3) w(4)  (w = actual rotor speeds)."""

    def __init__(self, case, tau_motor=TAU_MOTOR):
        self.case = case
        self.tau = tau_motor
        self.Jinv = np.linalg.inv(J)

    def forces(self, R, v, om, w, wdot):
        """body force (N) and body torque (N m) of everything but gravity."""
        T = K_T * w ** 2
        if self.case in ("E", "F"):     # wake ingestion: downstream rotor loses thrust
            vb = R.T @ v
            u = -(POS[:, :2] / ARM) @ vb[:2]
            T = T * (1.0 - np.minimum(0.2, K_WAKE * np.maximum(0.0, u) ** 2))
        Fb = np.array([0.0, 0.0, -T.sum()])
        tau = np.zeros(3)
        for i in range(4):
            tau += np.cross(POS[i], [0, 0, -T[i]])
        tau[2] += B_YAW * np.dot(SPIN, w ** 2)
        Om = np.dot(SPIN, w)
        tau += J_R * Om * np.array([om[1], -om[0], 0.0])
        # world linear drag, expressed in body
        Fb += R.T @ (-KD * v)
        if self.case == "C":
            vb = R.T @ v
            for i in range(4):
                ri = POS[i] + np.array([0, 0, -H_HUB])
                vi = vb + np.cross(om, ri)
                Fi = -w[i] * np.array([K_RDH * vi[0], K_RDH * vi[1], K_RDV * vi[2]])
                Fb += Fi
                tau += np.cross(ri, Fi)
        if self.case == "D":
            tau[2] += J_R * np.dot(SPIN, wdot)
        return Fb, tau

    def rhs(self, t, s, wcmd, held=False):
        v = s[3:6]
        q = s[6:10]
        om = s[10:13]
        w = s[13:17]
        R = rotmat_from_quat(q / np.linalg.norm(q))
        if held:           # open loop on held speeds, no motor dynamics
            wdot = np.zeros(4)
            w = wcmd
        else:
            wdot = (wcmd - w) / self.tau
        Fb, tau = self.forces(R, v, om, w, wdot)
        pdot = v
        vdot = np.array([0, 0, G]) + R @ Fb / MASS
        qw, qx, qy, qz = q
        Omq = 0.5 * np.array([
            -qx * om[0] - qy * om[1] - qz * om[2],
            qw * om[0] + qy * om[2] - qz * om[1],
            qw * om[1] - qx * om[2] + qz * om[0],
            qw * om[2] + qx * om[1] - qy * om[0]])
        omdot = self.Jinv @ (tau - np.cross(om, J @ om))
        return np.concatenate([pdot, vdot, Omq, omdot, wdot])

    def specific_force(self, s, wcmd, held=False):
        R = rotmat_from_quat(s[6:10])
        w = wcmd if held else s[13:17]
        wdot = np.zeros(4) if held else (wcmd - s[13:17]) / self.tau
        Fb, _ = self.forces(R, s[3:6], s[10:13], w, wdot)
        return Fb / MASS


# ---------------------------------------------------------------- controller
class Controller:
    """Geometric SO(3) controller with position PID, own mixer; nominal model off."""

    def __init__(self):
        self.m = MASS * 1.04
        self.J = J * 1.10
        self.kt = K_T * 1.06
        self.b = B_YAW * 0.93
        self.Kp = np.array([2.5, 2.5, 4.0])
        self.Kv = np.array([3.0, 3.0, 4.0])
        self.Ki = np.array([0.4, 0.4, 0.8])
        self.KR = np.array([50.0, 50.0, 8.0])
        self.Kw = np.array([12.0, 12.0, 5.0])
        self.ei = np.zeros(3)
        A = np.zeros((4, 4))
        A[0] = self.kt
        for i in range(4):
            tq = np.cross(POS[i], [0, 0, -self.kt])
            A[1, i], A[2, i] = tq[0], tq[1]
            A[3, i] = self.b * SPIN[i]
        self.Minv = np.linalg.inv(A)

    def __call__(self, s, ref, wmax):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = rotmat_from_quat(q / np.linalg.norm(q))
        pr, vr, ar, psir = ref
        e = pr - p
        ev = vr - v
        self.ei = np.clip(self.ei + e * CTRL_DT, -2, 2)
        a_des = ar + self.Kp * e + self.Kv * ev + self.Ki * self.ei
        F = self.m * (a_des - np.array([0, 0, G]))
        # tilt limit 35 deg
        hz = -F[2]
        hxy = np.hypot(F[0], F[1])
        lim = np.tan(np.radians(35)) * hz
        if hxy > lim:
            F[:2] *= lim / hxy
        b3 = -F / np.linalg.norm(F)
        b1c = np.array([np.cos(psir), np.sin(psir), 0])
        b2 = np.cross(b3, b1c)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        T = -F @ (R @ np.array([0, 0, 1.0]))
        E = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([E[2, 1], E[0, 2], E[1, 0]])
        tau = self.J @ (-self.KR * eR - self.Kw * om) + np.cross(om, self.J @ om)
        w2 = self.Minv @ np.array([T, *tau])
        if np.any(w2 < 80.0 ** 2) or np.any(w2 > wmax ** 2):   # drop yaw first
            w2 = self.Minv @ np.array([T, tau[0], tau[1], 0.2 * tau[2]])
        return np.sqrt(np.clip(w2, 80.0 ** 2, wmax ** 2))


# ---------------------------------------------------------------- manoeuvres
def smooth(t, t0, dur):
    """quintic 0->1 over [t0, t0+dur]; value, rate, acceleration."""
    x = np.clip((t - t0) / dur, 0, 1)
    s = 10 * x ** 3 - 15 * x ** 4 + 6 * x ** 5
    ds = (30 * x ** 2 - 60 * x ** 3 + 30 * x ** 4) / dur
    dds = (60 * x - 180 * x ** 2 + 120 * x ** 3) / dur ** 2
    if x <= 0 or x >= 1:
        ds = dds = 0.0
    return s, ds, dds


def make_ref(kind, z0=-1.5):
    """Reference functions t -> (p, v, a, psi)."""
    def steps(t, items):
        p = np.array([0, 0, z0], float)
        v = np.zeros(3)
        a = np.zeros(3)
        psi = 0.0
        for (t0, dur, axis, amp) in items:
            s, ds, dds = smooth(t, t0, dur)
            if axis == 3:
                psi += amp * s
            else:
                p[axis] += amp * s
                v[axis] += amp * ds
                a[axis] += amp * dds
        return p, v, a, psi

    if kind == "steps":       # hover + steps in x and y, a yaw turn
        items = [(1.5, 1.6, 0, 2.0), (5.0, 1.6, 1, 1.5), (8.0, 1.8, 3, 1.2),
                 (10.5, 1.6, 0, -2.0), (13.0, 1.6, 1, -1.5)]
        return lambda t: steps(t, items), 16.0
    if kind == "circle":      # two laps of r = 2 m at 2.5 m/s, with a climb
        r, wc = 2.0, 1.25

        def f(t):
            s, ds, dds = smooth(t, 1.0, 2.5)       # ramp the angular rate in
            # phase th(t) = wc * integral of s
            # integrate numerically (cheap): closed form of quintic integral
            x = np.clip((t - 1.0) / 2.5, 0, 1)
            I = 2.5 * (2.5 * x ** 4 - 3 * x ** 5 + x ** 6) + max(0.0, t - 3.5)
            th = wc * I
            thd = wc * s
            thdd = wc * ds
            p = np.array([r * np.sin(th), r * (1 - np.cos(th)), z0])
            v = np.array([r * np.cos(th) * thd, r * np.sin(th) * thd, 0])
            a = np.array([-r * np.sin(th) * thd ** 2 + r * np.cos(th) * thdd,
                          r * np.cos(th) * thd ** 2 + r * np.sin(th) * thdd, 0])
            zs, zds, zdds = smooth(t, 8.0, 3.0)
            p[2] += -1.0 * zs
            v[2] += -1.0 * zds
            a[2] += -1.0 * zdds
            return p, v, a, 0.3 * np.sin(0.4 * t)
        return f, 17.0
    if kind == "climb":       # climb/descend steps with yaw turns
        items = [(1.0, 1.5, 2, -1.5), (3.5, 2.0, 3, 1.5), (5.5, 1.3, 2, 2.2),
                 (7.5, 2.0, 3, -2.5), (9.5, 1.2, 2, -1.8), (11.5, 1.5, 0, 1.0),
                 (12.5, 1.5, 3, 1.0)]
        return lambda t: steps(t, items), 15.0
    if kind == "mixed":       # validation: diagonal dash, climb, yaw, lateral
        items = [(1.0, 1.5, 0, 2.5), (1.0, 1.5, 1, 1.5), (3.5, 1.4, 2, -1.2),
                 (4.0, 1.8, 3, -1.3), (6.5, 1.6, 0, -2.5), (7.0, 1.4, 2, 1.5),
                 (9.0, 1.6, 1, -2.5), (11.0, 1.8, 3, 1.3), (12.0, 1.4, 0, 1.5),
                 (14.0, 1.3, 1, 1.0)]
        return lambda t: steps(t, items), 17.0
    raise ValueError(kind)


FLIGHTS = [  # (name, manoeuvre, start cell voltage, seed offset)
    ("f1_steps", "steps", 4.18, 1),
    ("f2_circle", "circle", 4.02, 2),
    ("f3_climb", "climb", 3.86, 3),
    ("f4_mixed_val", "mixed", 3.95, 4),   # validation flight
]


def wmax_of(vcell):
    # 6S, Kv 400 rpm/V -> ~ 0.82 of no-load speed under load
    return 0.82 * 400 * 6 * vcell * 2 * np.pi / 60


def fly(case, kind, vcell0, seed):
    rng = np.random.default_rng(seed)
    ref, dur = make_ref(kind, z0=-2.5 if case == "F" else -1.5)
    phys = Physics(case)
    ctrl = Controller()
    p0, _, _, psi0 = ref(0.0)
    s = np.zeros(17)
    s[0:3] = p0
    s[6:10] = quat_from_euler(0, 0, psi0)
    s[13:17] = W_HOVER
    # pre-charge the integrator with the nominal model's hover mismatch
    ctrl.ei[2] = (MASS * G - ctrl.m * G * K_T / ctrl.kt) / (ctrl.m * ctrl.Ki[2]) * 0.0
    n_tick = int(round(dur / CTRL_DT))
    rows = []
    vcell = vcell0
    for k in range(n_tick + 1):
        t = k * CTRL_DT
        load = np.sum(K_T * s[13:17] ** 2) / (MASS * G)
        vcell = vcell0 - 0.004 * t - 0.12 * (load - 1.0)   # sag + load droop
        wcmd = ctrl(s, ref(t), wmax_of(vcell))
        if k % 4 == 0:
            rows.append((t, s.copy(), wcmd.copy(), vcell,
                         phys.specific_force(s, wcmd)))
        if k == n_tick:
            break
        sol = solve_ivp(phys.rhs, (t, t + CTRL_DT), s, args=(wcmd,),
                        method="RK45", rtol=1e-10, atol=1e-11)
        s = sol.y[:, -1]
        s[6:10] /= np.linalg.norm(s[6:10])
    return rows, rng


def write_log(path, case, rows, rng, truth_path=None):
    n = len(rows)
    t = np.array([r[0] for r in rows])
    S = np.array([r[1] for r in rows])
    WC = np.array([r[2] for r in rows])
    VC = np.array([r[3] for r in rows])
    SF = np.array([r[4] for r in rows])
    eul = np.array([euler_from_R(rotmat_from_quat(s[6:10])) for s in S])
    om = S[:, 10:13]
    if case == "B":
        w_log = WC.copy()                              # commands, exact
    else:
        w_log = S[:, 13:17] + rng.normal(0, 1.0, (n, 4))   # ESC telemetry
    # motion capture 50 Hz (every 2nd row), 1 mm, two dropouts
    pos = S[:, 0:3] + rng.normal(0, 0.001, (n, 3))
    have = (np.arange(n) % 2 == 0)
    for _ in range(2):
        a = rng.integers(200, n - 200)
        have[a:a + rng.integers(8, 25)] = False
    pos[~have] = np.nan
    att = eul + rng.normal(0, 1, (n, 3)) * np.array([0.0015, 0.0015, 0.003])
    att[:, 2] = (att[:, 2] + np.pi) % (2 * np.pi) - np.pi
    gyro = om + rng.normal(0, 0.004, (n, 3))
    acc = SF + rng.normal(0, 0.03, (n, 3))
    cols = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi",
            "p", "q", "r", "ax", "ay", "az", "vbat"]
    data = np.column_stack([t, w_log, pos, att, gyro, acc, VC])
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for row in data:
            f.write(",".join("" if np.isnan(x) else f"{x:.9g}" for x in row) + "\n")
    if truth_path:
        tr = np.column_stack([t, S[:, 13:17], WC, S[:, 0:3], eul, S[:, 3:6], om, SF])
        tcols = ["t", "wa1", "wa2", "wa3", "wa4", "wc1", "wc2", "wc3", "wc4",
                 "x", "y", "z", "phi", "theta", "psi", "vx", "vy", "vz",
                 "p", "q", "r", "ax", "ay", "az"]
        np.savetxt(truth_path, tr, delimiter=",", header=",".join(tcols),
                   comments="", fmt="%.12g")


def write_airframes():
    common = f"""[airframe]
name = "audit23_plus_2p2kg"
mass = {MASS}
inertia = [{J[0,0]}, {J[1,1]}, {J[2,2]}]
arm_length = {ARM}
layout = "plus"
rotor_inertia = {J_R}
gravity = {G}
"""
    with open(os.path.join(OUT, "true.toml"), "w") as f:
        f.write(common + f"""
[parameters]
K_T = {K_T}
b = {B_YAW}
Kd = [{KD[0]}, {KD[1]}, {KD[2]}]
""")
    with open(os.path.join(OUT, "guess.toml"), "w") as f:
        f.write(common + f"""
[parameters]   # a user's rough guesses: K_T +30 %, b -40 %, drag off
K_T = {K_T*1.3:.4g}
b = {B_YAW*0.6:.4g}
Kd = [0.1, 0.15, 0.8]
""")
    truth = dict(mass=MASS, inertia=np.diag(J).tolist(), arm=ARM, J_r=J_R,
                 K_T=K_T, b=B_YAW, Kd=KD.tolist(), tau_motor=TAU_MOTOR,
                 C=dict(k_rdh=K_RDH, k_rdv=K_RDV, h_hub=H_HUB),
                 D="tau_z += J_r*sum(spin_i*dw_i/dt)", E=dict(k_wake=K_WAKE), w_hover=W_HOVER)
    with open(os.path.join(OUT, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)


def open_loop(case, t, W, s0, tau_motor=TAU_MOTOR):
    """Own integration of held inputs W (rows) for the simulate check.
    case 'B' integrates the motor lag state from the held logged speeds."""
    phys = Physics("C" if case == "C" else "A", tau_motor)
    s = s0.copy()
    out = [s.copy()]
    for k in range(len(t) - 1):
        held = case != "B"
        sol = solve_ivp(phys.rhs, (t[k], t[k + 1]), s, args=(W[k], held),
                        method="DOP853", rtol=1e-11, atol=1e-12)
        s = sol.y[:, -1]
        s[6:10] /= np.linalg.norm(s[6:10])
        out.append(s.copy())
    return np.array(out)


def check():
    """Write inputs-only CSVs and own open-loop outputs for greybox simulate."""
    d = os.path.join(OUT, "check")
    os.makedirs(d, exist_ok=True)
    rng = np.random.default_rng(99)
    t = np.round(np.arange(0, 6.0001, 0.01), 6)
    n = len(t)
    # excitation around hover: multisine per rotor
    W = np.zeros((n, 4))
    for i in range(4):
        fr = rng.uniform(0.3, 3.0, 4)
        ph = rng.uniform(0, 2 * np.pi, 4)
        W[:, i] = W_HOVER * (1.003 + sum(0.02 * np.sin(2 * np.pi * f * t + p)
                                          for f, p in zip(fr, ph)))
    with open(os.path.join(d, "inputs.csv"), "w") as f:
        f.write("t,w1,w2,w3,w4\n")
        for k in range(n):
            f.write(f"{t[k]:.6f}," + ",".join(f"{x:.9f}" for x in W[k]) + "\n")
    x0 = np.array([0.2, -0.1, -1.5, 0.05, -0.03, 0.4, 0.5, -0.3, 0.2, 0.1, -0.2, 0.3])
    s0 = np.zeros(17)
    s0[0:3] = x0[0:3]
    s0[3:6] = x0[6:9]
    s0[6:10] = quat_from_euler(*x0[3:6])
    s0[10:13] = x0[9:12]
    s0[13:17] = W[0]
    for case in ["A", "B", "C"]:
        S = open_loop(case, t, W, s0)
        eul = np.array([euler_from_R(rotmat_from_quat(s[6:10])) for s in S])
        arr = np.column_stack([t, S[:, 0:3], eul, S[:, 10:13]])
        np.savetxt(os.path.join(d, f"own_{case}.csv"), arr, delimiter=",",
                   header="t,x,y,z,phi,theta,psi,p,q,r", comments="", fmt="%.12g")
    with open(os.path.join(d, "x0.txt"), "w") as f:
        f.write(",".join(f"{v}" for v in x0))


def main():
    os.makedirs(OUT, exist_ok=True)
    write_airframes()
    if "--check" in sys.argv:
        check()
        return
    cases = [c for c in "ABCDEF" if c in (sys.argv[1] if len(sys.argv) > 1 else "ABCDEF")]
    for ci, case in enumerate(cases):
        for name, kind, v0, so in FLIGHTS:
            seed = 1000 * (ord(case) - 64) + so
            rows, rng = fly(case, kind, v0, seed)
            path = os.path.join(OUT, f"{case}_{name}.csv")
            write_log(path, case, rows, rng, path.replace(".csv", ".truth.csv"))
            print("wrote", path, len(rows), "rows", flush=True)


if __name__ == "__main__":
    main()

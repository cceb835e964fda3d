#!/usr/bin/env python3
"""Blind audit 38: an independent quadrotor simulator (numpy only) for greybox.

Usage:  python sim.py OUTDIR [--seeds=1-14] [--cases=control,lag]
        (default: control seeds 1-30, lag seeds 1-12, lag3 seeds 1-6)

Writes, per seed s and case c:
    OUTDIR/c_sS_est.csv   22 s estimation flight (200 Hz rows)
    OUTDIR/c_sS_val.csv   15 s validation flight (a different draw, seed 1000+s)
    OUTDIR/airframe.toml  the airframe file (true geometry, *guesses* for K_T, b, Kd)
    OUTDIR/truth.json     the truth below and the injected sensor noise
Everything is deterministic: numpy.random.default_rng(seed) for every draw.

TRUTH (the same vehicle in every flight):
    0.5 kg "x" quadrotor, 5-inch props, arm (centre to hub) l = 0.125 m
    inertia J = diag(2.2e-3, 2.2e-3, 4.0e-3) kg m^2, rotor inertia J_r = 3.0e-6 kg m^2
    K_T = 1.5e-6 N/(rad/s)^2  (hover ~904 rad/s),  b = 2.4e-8 N m/(rad/s)^2
    Kd  = [0.10, 0.10, 0.15] N s/m (world-frame linear drag, -Kd*v)
    g = 9.81, NED world, FRD body, greybox's "x" layout and spins [+1,+1,-1,-1].
Cases:
    control : base model only. The rotor speed that acts on the vehicle is held constant over
              each 5 ms row (zero-order hold, exactly the contract's input convention); it is
              the output of a discrete first-order motor (tau 15 ms) driven by the controller's
              command. The log holds that speed as ESC telemetry: + N(0, 1.0 rad/s) white noise,
              then quantised to 1.5 rad/s steps (~100 eRPM for 7 pole pairs).
    lag     : hidden motor_lag, tau_m = 15 ms: the acting speed is the continuous first-order
              lag (dw/dt = (w_cmd - w)/tau_m, integrated in the RK4) of the held command; the
              log holds the *command* (quantised to 0.1 rad/s, no noise).
    lag3    : the same with a smaller hidden lag, tau_m = 3 ms (0.6 of a row).
Sensors (rows at 200 Hz, t = k*5 ms):
    x,y,z     : motion capture at 100 Hz (every other row, others empty), N(0, 1.0 mm) each
    phi,theta,psi : motion-capture attitude at 200 Hz, N(0, 2.0 mrad) each (white)
    p,q,r     : gyro at 200 Hz, N(0, 4.0 mrad/s) each (white, no bias)
Controller (200 Hz): geometric (Lee) SE(3) controller with velocity PI outer loop; its model is
    off the truth: mass +6 %, inertia +8 %, K_T -7 %, b +10 %. Low-pass band-limited torque dither
    (roll/pitch 4e-3 N m RMS, yaw 1e-3 N m) keeps the rates excited.
Manoeuvres: seeded random sequence of hover, step_x, step_y, climb/descend, circle, yaw turn.
Integrator: RK4 at 1 ms with a unit quaternion (renormalised each step).
"""
import json
import os
import sys

import numpy as np

# ----------------------------------------------------------------------------- truth
M = 0.5
G = 9.81
ARM = 0.125
J = np.diag([2.2e-3, 2.2e-3, 4.0e-3])
JD = np.diag(J).copy()
JR = 3.0e-6
KT = 1.5e-6
B = 2.4e-8
KD = np.array([0.10, 0.10, 0.15])
TAU_M = 0.015
TAU_M3 = 0.003          # the 'lag3' case's smaller hidden motor lag
A = ARM / np.sqrt(2)
POS = np.array([[A, A, 0], [-A, -A, 0], [A, -A, 0], [-A, A, 0]])
SPIN = np.array([1.0, 1.0, -1.0, -1.0])

ROW_DT = 0.005
SUB = 5                     # RK4 steps of 1 ms per row
H = ROW_DT / SUB
SIG_POS = 1.0e-3
SIG_ATT = 2.0e-3
SIG_GYR = 4.0e-3
SIG_W = 1.0
Q_W = 1.5
Q_CMD = 0.1

# controller's model (off the truth)
MC = M * 1.06
JC = J * 1.08
KTC = KT * 0.93
BC = B * 1.10
W_HOVER = np.sqrt(M * G / (4 * KT))


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


def euler(q):
    w, x, y, z = q
    phi = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    theta = np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))
    psi = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.array([phi, theta, psi])


def quat_from_euler(phi, theta, psi):
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(theta / 2), np.sin(theta / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


def deriv(s, w_act, lag_cmd=None, tau_lag=None):
    """s = [p(3), v(3), q(4), om(3), (w_eff(4) if lag)]"""
    v = s[3:6]
    q = s[6:10]
    om = s[10:13]
    if lag_cmd is not None:
        w = s[13:17]
    else:
        w = w_act
    w2 = w * w
    T = KT * w2
    R = qrot(q)
    acc = R[:, 2] * (-T.sum() / M) - KD * v / M
    acc[2] += G
    tau = np.array([-(POS[:, 1] @ T), POS[:, 0] @ T, B * (SPIN @ w2)])
    Om_r = SPIN @ w
    tau += JR * Om_r * np.array([om[1], -om[0], 0.0])      # omega x e_z = (q, -p, 0)
    omdot = (tau - np.cross(om, JD * om)) / JD
    qdot = 0.5 * qmul(q, np.array([0.0, *om]))
    out = np.concatenate([v, acc, qdot, omdot])
    if lag_cmd is not None:
        out = np.concatenate([out, (lag_cmd - w) / tau_lag])
    return out


def rk4(s, w_act, lag_cmd=None, tau_lag=None):
    k1 = deriv(s, w_act, lag_cmd, tau_lag)
    k2 = deriv(s + 0.5 * H * k1, w_act, lag_cmd, tau_lag)
    k3 = deriv(s + 0.5 * H * k2, w_act, lag_cmd, tau_lag)
    k4 = deriv(s + H * k3, w_act, lag_cmd, tau_lag)
    s = s + H / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    s[6:10] /= np.linalg.norm(s[6:10])
    return s


# ----------------------------------------------------------------------------- references
def make_reference(rng, duration):
    """Piecewise manoeuvres -> functions of t giving (p_ref, v_ref, a_ref, psi_ref)."""
    kinds = ["hover", "step_x", "step_y", "climb", "circle", "yaw"]
    segs = []
    t = 0.0
    base = np.array([0.0, 0.0, -1.5])
    psi0 = 0.0
    # first segment: hover, then a shuffled draw that uses every kind at least once
    order = ["hover"] + list(rng.permutation(kinds[1:]))
    while t < duration:
        kind = order.pop(0) if order else kinds[rng.integers(len(kinds))]
        dur = rng.uniform(2.5, 4.0)
        seg = {"kind": kind, "t0": t, "t1": t + dur, "base": base.copy(), "psi0": psi0}
        if kind == "step_x":
            seg["d"] = np.array([rng.choice([-1, 1]) * rng.uniform(0.6, 1.5), 0, 0])
        elif kind == "step_y":
            seg["d"] = np.array([0, rng.choice([-1, 1]) * rng.uniform(0.6, 1.5), 0])
        elif kind == "climb":
            dz = rng.uniform(0.4, 0.9) * rng.choice([-1, 1])
            if base[2] + dz > -0.8 or base[2] + dz < -3.0:
                dz = -dz
            seg["d"] = np.array([0, 0, dz])
        elif kind == "hover":
            seg["d"] = rng.normal(0, 0.1, 3)
        elif kind == "circle":
            seg["rad"] = rng.uniform(0.6, 1.2)
            seg["om"] = rng.choice([-1, 1]) * rng.uniform(1.5, 2.5)
            seg["d"] = np.zeros(3)
        elif kind == "yaw":
            seg["dpsi"] = rng.choice([-1, 1]) * rng.uniform(np.pi / 4, 2 * np.pi / 3)
            seg["d"] = np.zeros(3)
        segs.append(seg)
        base = base + seg["d"]
        psi0 = psi0 + seg.get("dpsi", 0.0)
        t += dur
    return segs


def smoothstep(u):
    """quintic 0->1, zero vel/acc at ends; returns (s, ds/du, d2s/du2)."""
    u = np.clip(u, 0, 1)
    return (10 * u**3 - 15 * u**4 + 6 * u**5, 30 * u**2 - 60 * u**3 + 30 * u**4,
            60 * u - 180 * u**2 + 120 * u**3)


def ref_at(segs, t):
    for seg in segs:
        if seg["t0"] <= t < seg["t1"] or seg is segs[-1]:
            break
    T = min(1.5, seg["t1"] - seg["t0"])
    u = (t - seg["t0"]) / T
    s, ds, dds = smoothstep(u)
    if u > 1:
        ds = dds = 0.0
    p = seg["base"] + s * seg["d"]
    v = seg["d"] * ds / T
    a = seg["d"] * dds / T**2
    psi = seg["psi0"]
    if seg["kind"] == "yaw":
        psi = seg["psi0"] + s * seg["dpsi"]
    if seg["kind"] == "circle":
        tc = t - seg["t0"]
        dur = seg["t1"] - seg["t0"]
        # ramp the angular rate in and out so the reference is smooth
        r, om = seg["rad"], seg["om"]
        env, denv, ddenv = smoothstep(min(tc, dur - tc) / 0.8)
        env = min(env, 1.0)
        # angle: integral of om*env, approximate by om*tc*env (small error, continuous)
        ang = om * tc
        c, sn = np.cos(ang), np.sin(ang)
        p = seg["base"] + env * r * np.array([c - 1, sn, 0]) * 1.0
        v = env * r * om * np.array([-sn, c, 0])
        a = env * r * om**2 * np.array([-c, -sn, 0])
    return p, v, a, psi


# ----------------------------------------------------------------------------- controller
def vee(Mx):
    return np.array([Mx[2, 1], Mx[0, 2], Mx[1, 0]])


class Controller:
    def __init__(self, rng):
        self.i_v = np.zeros(3)
        self.kp = np.array([3.0, 3.0, 5.0])
        self.kv = np.array([3.0, 3.0, 4.0])
        self.ki = np.array([0.8, 0.8, 1.0])
        wn = np.array([22.0, 22.0, 9.0])
        self.KR = np.diag(JC) * wn**2
        self.KW = np.diag(JC) * 2 * 0.8 * wn
        self.Ainv = np.linalg.inv(np.array([
            [KTC] * 4,
            [-KTC * POS[i, 1] for i in range(4)],
            [KTC * POS[i, 0] for i in range(4)],
            [BC * SPIN[i] for i in range(4)]]))

    def __call__(self, pm, vm, eul, om, ref, dither):
        p_ref, v_ref, a_ref, psi_ref = ref
        e_p = p_ref - pm
        e_v = v_ref - vm
        self.i_v = np.clip(self.i_v + e_v * ROW_DT, -1, 1)
        a_des = self.kp * e_p + self.kv * e_v + self.ki * self.i_v + a_ref
        a_des[:2] = np.clip(a_des[:2], -6, 6)
        f = MC * (np.array([0, 0, G]) - a_des)      # -T R e3 = m (a - g e3)  => R e3 = f/|f|
        b3 = f / np.linalg.norm(f)
        bc = np.array([np.cos(psi_ref), np.sin(psi_ref), 0])
        b2 = np.cross(b3, bc)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        R = qrot(quat_from_euler(*eul))
        thrust = np.dot(f, R[:, 2])
        eR = 0.5 * vee(Rd.T @ R - R.T @ Rd)
        tau = -self.KR * eR - self.KW * om + np.cross(om, JC @ om) + dither
        w2 = self.Ainv @ np.concatenate([[thrust], tau])
        w2 = np.clip(w2, (0.15 * W_HOVER) ** 2, (2.2 * W_HOVER) ** 2)
        return np.sqrt(w2)


# ----------------------------------------------------------------------------- flight
def fly(seed, duration, case):
    rng = np.random.default_rng(seed)
    segs = make_reference(rng, duration)
    n = int(round(duration / ROW_DT))
    # band-limited dither: white noise through a 1st-order low-pass (10 Hz)
    wd = rng.normal(0, 1, (n, 3))
    alpha = np.exp(-2 * np.pi * 10 * ROW_DT)
    dith = np.zeros((n, 3))
    for k in range(1, n):
        dith[k] = alpha * dith[k - 1] + np.sqrt(1 - alpha**2) * wd[k]
    dith *= np.array([4e-3, 4e-3, 1e-3])
    # sensor noise draws (one stream, drawn up front so the cases share them)
    n_pos = rng.normal(0, SIG_POS, (n, 3))
    n_att = rng.normal(0, SIG_ATT, (n, 3))
    n_gyr = rng.normal(0, SIG_GYR, (n, 3))
    n_w = rng.normal(0, SIG_W, (n, 4))
    n_vel = rng.normal(0, 0.01, (n, 3))          # controller's velocity estimate error
    p0 = ref_at(segs, 0.0)[0]
    lagged = case in ("lag", "lag3")
    tau_hidden = TAU_M if case == "lag" else TAU_M3
    s = np.zeros(17 if lagged else 13)
    s[0:3] = p0
    s[6:10] = [1, 0, 0, 0]
    w_act = np.full(4, W_HOVER)
    if lagged:
        s[13:17] = W_HOVER
    ctrl = Controller(rng)
    rows = []
    pm = p0 + n_pos[0]
    for k in range(n):
        t = k * ROW_DT
        q = s[6:10]
        eul_true = euler(q)
        om_true = s[10:13].copy()
        eul_m = eul_true + n_att[k]
        om_m = om_true + n_gyr[k]
        pos_m = s[0:3] + n_pos[k]
        has_pos = (k % 2 == 0)
        if has_pos:
            pm = pos_m
        cmd = ctrl(pm, s[3:6] + n_vel[k], eul_m, om_m, ref_at(segs, t), dith[k])
        if lagged:
            logged = np.round(cmd / Q_CMD) * Q_CMD
            lag_cmd = logged.copy()
        else:
            a = 1 - np.exp(-ROW_DT / TAU_M)
            w_act = w_act + a * (cmd - w_act)
            logged = np.round((w_act + n_w[k]) / Q_W) * Q_W
            lag_cmd = None
        row = [t, *logged]
        row += list(pos_m) if has_pos else [np.nan] * 3
        row += list(eul_m) + list(om_m)
        rows.append(row)
        for _ in range(SUB):
            s = rk4(s, w_act, lag_cmd, tau_hidden)
        if not np.all(np.isfinite(s)) or abs(s[2]) > 50:
            raise RuntimeError(f"seed {seed}: diverged at t={t}")
    arr = np.array(rows)
    arr[:, 10] = np.unwrap(arr[:, 10])            # heading continuous (wrap-free)
    return arr, segs


HEADER = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r"]


def write_csv(path, arr):
    with open(path, "w") as f:
        f.write(",".join(HEADER) + "\n")
        for row in arr:
            cells = []
            for j, v in enumerate(row):
                if np.isnan(v):
                    cells.append("")
                elif j == 0:
                    cells.append(f"{v:.3f}")
                else:
                    cells.append(f"{v:.7g}")
            f.write(",".join(cells) + "\n")


AIRFRAME = f"""[airframe]
name = "audit38_5inch"
mass = {M}
inertia = [{J[0,0]}, {J[1,1]}, {J[2,2]}]
arm_length = {ARM}
layout = "x"
rotor_inertia = {JR}
gravity = {G}

[parameters]            # guesses: K_T +30 %, b -30 %, Kd half
K_T = {KT*1.3:.4g}
b = {B*0.7:.4g}
Kd = [0.05, 0.05, 0.075]
"""


def main():
    out = sys.argv[1]
    seeds = None                                  # default: control 1-30, lag 1-12, lag3 1-6
    cases = ["control", "lag", "lag3"]
    for a in sys.argv[2:]:
        if a.startswith("--seeds="):
            lo, hi = a.split("=")[1].split("-")
            seeds = list(range(int(lo), int(hi) + 1))
        if a.startswith("--cases="):
            cases = a.split("=")[1].split(",")
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "airframe.toml"), "w") as f:
        f.write(AIRFRAME)
    truth = {"mass": M, "inertia": np.diag(J).tolist(), "arm": ARM, "J_r": JR, "K_T": KT,
             "b": B, "Kd": KD.tolist(), "tau_m_lag_case": TAU_M, "tau_m_lag3_case": TAU_M3,
             "noise": {"x": SIG_POS, "y": SIG_POS, "z": SIG_POS, "phi": SIG_ATT,
                       "theta": SIG_ATT, "psi": SIG_ATT, "p": SIG_GYR, "q": SIG_GYR,
                       "r": SIG_GYR, "w_white": SIG_W, "w_quant_step": Q_W}}
    with open(os.path.join(out, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    for case in cases:
        case_seeds = seeds or {"control": list(range(1, 31)), "lag": list(range(1, 13)),
                               "lag3": list(range(1, 7))}[case]
        for sd in case_seeds:
            for tag, seed, dur in (("est", sd, 22.0), ("val", 1000 + sd, 15.0)):
                path = os.path.join(out, f"{case}_s{sd}_{tag}.csv")
                arr, segs = fly(seed, dur, case)
                write_csv(path, arr)
                kinds = ",".join(s["kind"] for s in segs)
                print(f"{path}: {len(arr)} rows, {kinds}", flush=True)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Blind audit 36: an independent quadrotor simulator (numpy only), written from scratch.

    python sim.py OUTDIR            # writes every flight + airframe + truth.json, bit for bit

Vehicle (truth, SI units)
-------------------------
  mass           M   = 1.00 kg (vehicle); payload case: + 0.15 kg slung payload
  inertia        J   = diag(0.0110, 0.0115, 0.0210) kg m^2
  layout         "x", arm l = 0.225 m (a = l/sqrt 2), rotors in the CoG plane,
                 rotor 1 (+a,+a), 2 (-a,-a), 3 (+a,-a), 4 (-a,+a), spin [+1,+1,-1,-1]
  8-inch props   R = 0.1016 m
  K_T            6.8e-6  N/(rad/s)^2   (hover ~600 rad/s)
  b              1.0e-7  N m/(rad/s)^2 (b/K_T = 14.7 mm)
  Kd             [0.10, 0.11, 0.16] N s/m, world axes (linear drag)
  J_r            2.5e-5 kg m^2 (gyroscopic torque, contract form; given in the airframe)
  motors         first-order lag 20 ms from the commanded to the actual speed (the log holds
                 the actual speeds, as ESC telemetry would, so the lag is not in the model)
Integration: fixed-step RK4 at 1 ms on a unit quaternion (renormalised each step).
Controller: 400 Hz geometric (SE(3)) position/attitude controller on the true state, its own
model K_T x1.06, b x0.92, J x1.1; multisine excitation on thrust and torques; mixer inverts
the controller's model; speeds clipped to [150, 1150] rad/s.
Sensors (rows at 200 Hz, t = 0.005 k):
  w1..w4   actual speed at the row time + N(0, 0.6 rad/s), quantised to 1.5 rad/s (eRPM steps)
  x,y,z    motion capture at 100 Hz (every other row), N(0, 1.5 mm), empty otherwise
  phi,theta,psi  true ZYX Euler + N(0, 2 mrad), psi wrapped to (-pi, pi]
  p,q,r    gyro, true + N(0, 0.005 rad/s)
  ax,ay,az accelerometer (body FRD specific force) + N(0, 0.05 m/s^2)

Cases (estimation flight 50 s seed s, validation flight 40 s seed s+100)
  control : base model only
  canted  : every rotor's thrust axis canted 7 deg inward (top toward the centre): thrust
            T_i = K_T w^2 along n_i = cos c (-e_z) - sin c r_hat_i, reaction torque
            -spin_i b w^2 n_i. Greybox's airframe cannot give an axis: to the model,
            K_T cos c = 6.7493e-6 and b cos c (README).
  payload : 0.15 kg point mass on a 0.6 m cable (stiff spring 600 N/m, 2 N s/m damping,
            slack allowed) from an attach point 0.05 m below the CoG; airframe mass 1.15
            (weighed with the payload), controller knows 1.15 kg.
  inflow  : per-rotor axial inflow, blade-element/momentum: C_T = s (theta0/3 - lambda/2),
            C_T = 2 lambda_i (lambda_i + lambda_c), s = sigma a /2 = 0.285, theta0 fitted so
            hover C_T matches; lambda_c = v_climb,i / (w_i R), v_climb,i = -(R^T v + omega x r_i)_z
            Thrust T_i = K_T w_i^2 C_T(lambda_c)/C_T(0) (reaction torque unchanged).
            Linearised: T = K_T w^2 (1 - kin v_climb/(w R)), kin printed in truth.json,
            i.e. hub_rotor_drag's k_rdv = K_T kin / R.
            Flights hold sustained climbs/descents at up to 3-3.5 m/s.
  ground  : ground effect per rotor, Sanchez-Cuevas et al. (2017) multirotor form with each
            rotor's own height h_i above z = 0:
            T/T_inf = 1/(1 - (R/4h)^2 - R^2 h/(d^2+4h^2)^1.5 - R^2/2 h/(2d^2+4h^2)^1.5
                          - 2 R^2 h/(bb^2+4h^2)^1.5 K_b)
            d = 0.318 m (adjacent rotors), bb = 0.225 m (rotor to centre), K_b = 1.0,
            h clamped >= 0.06 m.  Greybox's form: 1/(1 - k_ge/h^2) with k_ge = (R/4)^2 =
            6.45e-4 m^2 for the first term alone. Low passes at 0.15-0.35 m.
"""
import json
import math
import os
import sys

import numpy as np

G = 9.81
M = 1.00
J = np.diag([0.0110, 0.0115, 0.0210])
L_ARM = 0.225
A = L_ARM / math.sqrt(2)
RPOS = np.array([[A, A, 0.0], [-A, -A, 0.0], [A, -A, 0.0], [-A, A, 0.0]])
SPIN = np.array([1.0, 1.0, -1.0, -1.0])
RAD = 0.1016
K_T = 6.8e-6
B = 1.0e-7
KD = np.array([0.10, 0.11, 0.16])
J_R = 2.5e-5
TAU_M = 0.020
CANT = math.radians(7.0)
M_L, L_CAB, K_CAB, C_CAB = 0.15, 0.6, 600.0, 2.0
ATTACH = np.array([0.0, 0.0, 0.05])
S_BEM = 0.285
GE_D, GE_BB, GE_KB = 2 * A, L_ARM, 1.0
DT = 0.001
CTRL_EVERY = 2.5  # not used directly: controller at 400 Hz -> every 2.5 ms: use 2 ms/3 ms alternation? keep 400 Hz exact with 0.5 ms? see below

W_MIN, W_MAX = 150.0, 1150.0
W_HOVER = math.sqrt(M * G / (4 * K_T))


def bem_theta0():
    ct0 = M * G / 4 / (1.225 * math.pi * RAD ** 2 * (W_HOVER * RAD) ** 2)
    lam_i = math.sqrt(ct0 / 2)
    return 3 * (ct0 / S_BEM + lam_i / 2)


THETA0 = bem_theta0()


def bem_ct(lam_c):
    s = S_BEM
    bq = 2 * lam_c + s / 2
    cq = -s * (THETA0 / 3 - lam_c / 2)
    lam_i = (-bq + np.sqrt(bq * bq - 8 * cq)) / 4
    return 2 * lam_i * (lam_i + lam_c)


CT0 = float(bem_ct(0.0))


def ge_ratio(h):
    h = np.maximum(h, 0.06)
    R2 = RAD ** 2
    s = ((RAD / (4 * h)) ** 2 + R2 * h / (GE_D ** 2 + 4 * h ** 2) ** 1.5
         + R2 / 2 * h / (2 * GE_D ** 2 + 4 * h ** 2) ** 1.5
         + 2 * R2 * h / (GE_BB ** 2 + 4 * h ** 2) ** 1.5 * GE_KB)
    return 1.0 / (1.0 - s)


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


def euler_from_R(R):
    phi = math.atan2(R[2, 1], R[2, 2])
    theta = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    psi = math.atan2(R[1, 0], R[0, 0])
    return phi, theta, psi


def q_from_euler(phi, theta, psi):
    cr, sr = math.cos(phi / 2), math.sin(phi / 2)
    cp, sp = math.cos(theta / 2), math.sin(theta / 2)
    cy, sy = math.cos(psi / 2), math.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


# rotor axes
AX_NOM = np.tile(np.array([0.0, 0.0, -1.0]), (4, 1))
_rh = RPOS / np.linalg.norm(RPOS, axis=1, keepdims=True)
AX_CANT = math.cos(CANT) * AX_NOM - math.sin(CANT) * _rh


class Plant:
    def __init__(self, case):
        self.case = case
        self.mtot = M + (M_L if case == "payload" else 0.0)
        self.axes = AX_CANT if case == "canted" else AX_NOM

    def rotor_thrusts(self, p, v, R, om, wr):
        fac = np.ones(4)
        if self.case == "ground":
            h = -(p[2] + (R @ RPOS.T)[2])
            fac = ge_ratio(h)
        elif self.case == "inflow":
            vb = R.T @ v
            vi = vb[None, :] + np.cross(om[None, :], RPOS)
            vclimb = -vi[:, 2]
            lam = vclimb / (np.maximum(wr, 50.0) * RAD)
            fac = bem_ct(lam) / CT0
        return K_T * wr ** 2 * fac

    def deriv(self, s, wcmd):
        p, v, q, om, wr = s[0:3], s[3:6], s[6:10], s[10:13], s[13:17]
        R = qrot(q)
        T = self.rotor_thrusts(p, v, R, om, wr)
        Fb = (T[:, None] * self.axes).sum(0)
        tau = np.cross(RPOS, T[:, None] * self.axes).sum(0)
        tau += (-(SPIN * B * wr ** 2)[:, None] * self.axes).sum(0)
        Om_r = float(SPIN @ wr)
        tau += J_R * Om_r * np.cross(om, np.array([0.0, 0.0, 1.0]))
        Fw = R @ Fb - KD * v + M * G * np.array([0.0, 0.0, 1.0])
        ds = np.zeros_like(s)
        if self.case == "payload":
            pL, vL = s[17:20], s[20:23]
            pa = p + R @ ATTACH
            va = v + R @ np.cross(om, ATTACH)
            d = pL - pa
            ln = np.linalg.norm(d)
            u = d / ln
            ten = K_CAB * (ln - L_CAB) + C_CAB * float(u @ (vL - va))
            ten = max(ten, 0.0) if ln > L_CAB else 0.0
            Fc = ten * u  # on the vehicle, toward the payload
            Fw = Fw + Fc
            tau = tau + np.cross(ATTACH, R.T @ Fc)
            ds[17:20] = vL
            ds[20:23] = G * np.array([0.0, 0.0, 1.0]) - ten * u / M_L - 0.01 * vL / M_L
        ds[0:3] = v
        ds[3:6] = Fw / M
        ds[6:10] = 0.5 * qmul(q, np.array([0.0, *om]))
        ds[10:13] = np.linalg.solve(J, tau - np.cross(om, J @ om))
        ds[13:17] = (wcmd - wr) / TAU_M
        return ds

    def specific_force(self, s, wcmd):
        ds = self.deriv(s, wcmd)
        R = qrot(s[6:10])
        return R.T @ (ds[3:6] - G * np.array([0.0, 0.0, 1.0]))


# ---------------- reference trajectory ----------------
def make_reference(case, seed, dur):
    rng = np.random.default_rng(seed + 7)
    segs = []  # list of (t_end, function t->(pos, psi))
    h0 = -1.5

    def hold(P, psi):
        return lambda t: (np.array(P, float), psi)

    t = 0.0
    plan = []
    if case == "ground":
        base = ["hover", "step", "low", "circle", "low", "yaw", "low", "eight", "low", "step"]
    elif case == "inflow":
        base = ["hover", "step", "climb", "circle", "climb", "yaw", "climb", "eight", "climb"]
    else:
        base = ["hover", "step", "circle", "yaw", "climb", "eight", "step", "circle", "climb", "yaw"]
    if seed % 2 == 1:
        base = [base[0]] + list(rng.permutation(base[1:]))
    i = 0
    while t < dur:
        plan.append(base[i % len(base)])
        i += 1
        t += 6.0
    refs = []
    t0 = 0.0
    cur = np.array([0.0, 0.0, h0])
    psi = 0.0
    for kind in plan:
        Tseg = 6.0
        if kind == "hover":
            refs.append((t0, Tseg, "hold", cur.copy(), psi, {}))
        elif kind == "step":
            tgt = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), h0 + rng.uniform(-0.5, 0.5)])
            refs.append((t0, Tseg, "hold", tgt, psi, {}))
            cur = tgt
        elif kind == "yaw":
            psi = psi + rng.choice([-1, 1]) * rng.uniform(1.5, 2.8)
            refs.append((t0, Tseg, "hold", cur.copy(), psi, {}))
        elif kind == "circle":
            r = rng.uniform(1.2, 1.8)
            om = rng.choice([-1, 1]) * rng.uniform(1.6, 2.2)
            refs.append((t0, Tseg, "circle", cur.copy(), psi, {"r": r, "om": om}))
        elif kind == "eight":
            r = rng.uniform(1.2, 1.8)
            om = rng.uniform(1.3, 1.8)
            refs.append((t0, Tseg, "eight", cur.copy(), psi, {"r": r, "om": om}))
        elif kind == "climb":
            if case == "inflow":
                amp = rng.uniform(5.5, 7.0)
            else:
                amp = rng.uniform(1.0, 2.0)
            refs.append((t0, Tseg, "climb", cur.copy(), psi, {"amp": amp}))
        elif kind == "low":
            hlow = rng.uniform(0.15, 0.3)
            tgt = np.array([rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), -hlow])
            refs.append((t0, Tseg, "low", tgt, psi, {"dx": rng.uniform(-1.5, 1.5), "dy": rng.uniform(-1.5, 1.5)}))
            cur = np.array([tgt[0], tgt[1], h0])
        t0 += Tseg

    def ref(t):
        for (ts, Tseg, kind, P, ps, par) in refs:
            if t < ts + Tseg:
                tau = t - ts
                break
        if kind == "hold":
            return P, ps
        if kind == "circle":
            r, om = par["r"], par["om"]
            ang = om * tau
            return P + np.array([r * math.sin(ang), r * (1 - math.cos(ang)), 0.0]), ps + 0.25 * math.sin(0.8 * tau)
        if kind == "eight":
            r, om = par["r"], par["om"]
            ang = om * tau
            return P + np.array([r * math.sin(ang), 0.5 * r * math.sin(2 * ang), 0.3 * math.sin(ang)]), ps
        if kind == "climb":
            amp = par["amp"]
            # up amp metres then back down (z negative up), smooth-ish
            frac = tau / Tseg
            dz = -amp * math.sin(math.pi * frac) ** 1
            return P + np.array([0.0, 0.0, dz]), ps
        if kind == "low":
            frac = min(1.0, tau / Tseg)
            if tau < 1.0:
                return np.array([P[0], P[1], P[2]]), ps
            if tau < 4.5:
                f = (tau - 1.0) / 3.5
                return np.array([P[0] + par["dx"] * f, P[1] + par["dy"] * f, P[2]]), ps
            return np.array([P[0] + par["dx"], P[1] + par["dy"], -1.5]), ps
        return P, ps

    return ref


# ---------------- controller ----------------
class Controller:
    def __init__(self, mtot, seed):
        self.m = mtot
        self.KT = K_T * 1.06
        self.b = B * 0.92
        self.J = J * 1.1
        rng = np.random.default_rng(seed + 11)
        self.freqs = rng.uniform(0.3, 6.0, size=(4, 8))
        self.phases = rng.uniform(0, 2 * np.pi, size=(4, 8))
        self.amps = np.array([1.5, 0.09, 0.09, 0.02])  # N, N m, N m, N m (sum of 8 sines / sqrt)
        a = A
        Mx = np.array([[1, 1, 1, 1],
                       [-RPOS[i, 1] for i in range(4)],
                       [RPOS[i, 0] for i in range(4)],
                       [-SPIN[i] * 0 + SPIN[i] for i in range(4)]], float)
        # [T; tau_x; tau_y; tau_z] = diag(KT, KT, KT, b) @ Mx @ w^2, tau_x = -sum y_i T_i
        self.mix = np.diag([self.KT, self.KT, self.KT, self.b]) @ Mx
        self.mix_inv = np.linalg.inv(self.mix)
        # filtered reference state (2nd-order prefilter)
        self.pf = None
        self.vf = np.zeros(3)
        self.psif = None
        self.kp = np.array([4.0, 4.0, 6.0])
        self.kv = np.array([3.0, 3.0, 4.0])
        self.kR = np.array([4.5, 4.5, 1.2])
        self.kW = np.array([0.45, 0.45, 0.25])
        self.wn = 2.8

    def excitation(self, t):
        e = (self.amps[:, None] * np.sin(2 * np.pi * self.freqs * t + self.phases)).sum(1) / math.sqrt(8) * 1.4
        return e

    def step(self, t, dtc, s, refP, refpsi):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = qrot(q)
        if self.pf is None:
            self.pf = refP.copy()
            self.psif = refpsi
        # prefilter
        af = self.wn ** 2 * (refP - self.pf) - 2 * self.wn * self.vf
        na = np.linalg.norm(af)
        if na > 5.0:
            af = af * (5.0 / na)
        self.vf = self.vf + dtc * af
        self.pf = self.pf + dtc * self.vf
        self.psif = self.psif + dtc * 2.0 * (refpsi - self.psif)
        a_des = self.kp * (self.pf - p) + self.kv * (self.vf - v) + af
        na = np.linalg.norm(a_des)
        if na > 7.0:
            a_des = a_des * (7.0 / na)
        f = self.m * (a_des - G * np.array([0, 0, 1.0])) + KD * 0.8 * v
        b3 = -f / np.linalg.norm(f)
        bc = np.array([math.cos(self.psif), math.sin(self.psif), 0.0])
        b2 = np.cross(b3, bc)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        T = float(-f @ R[:, 2])
        E = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([E[2, 1], E[0, 2], E[1, 0]])
        tau = -self.kR * eR - self.kW * om + np.cross(om, self.J @ om)
        ex = self.excitation(t)
        u = np.array([T + ex[0], tau[0] + ex[1], tau[1] + ex[2], tau[2] + ex[3]])
        w2 = self.mix_inv @ u
        w2 = np.clip(w2, W_MIN ** 2, W_MAX ** 2)
        return np.sqrt(w2)


def simulate(case, seed, dur, outdir, name):
    rng = np.random.default_rng(seed)
    plant = Plant(case)
    ctrl = Controller(plant.mtot, seed)
    ref = make_reference(case, seed, dur)
    n = 17 + (6 if case == "payload" else 0)
    s = np.zeros(n)
    P0, psi0 = ref(0.0)
    s[0:3] = P0
    s[6:10] = q_from_euler(0, 0, psi0)
    s[13:17] = math.sqrt(plant.mtot * G / (4 * K_T))
    if case == "payload":
        s[17:20] = P0 + ATTACH + np.array([0, 0, L_CAB + M_L * G / K_CAB])
    nsteps = int(round(dur / DT))
    rows = []
    wcmd = s[13:17].copy()
    ctrl_period = 5  # controller at 400 Hz: every 2.5 ms -> alternate 2 and 3 steps
    next_ctrl = 0
    k_ctrl = 0
    for k in range(nsteps + 1):
        t = k * DT
        if k == next_ctrl:
            P, ps = ref(t)
            wcmd = ctrl.step(t, 0.0025, s, P, ps)
            k_ctrl += 1
            next_ctrl = int(round(k_ctrl * 2.5))
        if k % 5 == 0:
            rows.append((t, s.copy(), wcmd.copy()))
        if k == nsteps:
            break
        k1 = plant.deriv(s, wcmd)
        k2 = plant.deriv(s + 0.5 * DT * k1, wcmd)
        k3 = plant.deriv(s + 0.5 * DT * k2, wcmd)
        k4 = plant.deriv(s + DT * k3, wcmd)
        s = s + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
    # write log
    lines = ["t,w1,w2,w3,w4,x,y,z,phi,theta,psi,p,q,r,ax,ay,az"]
    truth_track = []
    for i, (t, st, wc) in enumerate(rows):
        R = qrot(st[6:10])
        phi, th, ps = euler_from_R(R)
        wr = st[13:17] + rng.normal(0, 0.6, 4)
        wr = np.round(wr / 1.5) * 1.5
        att = np.array([phi, th, ps]) + rng.normal(0, 0.002, 3)
        att[2] = (att[2] + math.pi) % (2 * math.pi) - math.pi
        gyro = st[10:13] + rng.normal(0, 0.005, 3)
        acc = plant.specific_force(st, wc) + rng.normal(0, 0.05, 3)
        if i % 2 == 0:
            pos = st[0:3] + rng.normal(0, 0.0015, 3)
            ps_txt = ",".join(f"{x:.5f}" for x in pos)
        else:
            ps_txt = ",,"
        lines.append(f"{t:.3f}," + ",".join(f"{x:.2f}" for x in wr) + "," + ps_txt + ","
                     + ",".join(f"{x:.5f}" for x in att) + "," + ",".join(f"{x:.5f}" for x in gyro)
                     + "," + ",".join(f"{x:.4f}" for x in acc))
        truth_track.append(st[:13])
    with open(os.path.join(outdir, name + ".csv"), "w") as f:
        f.write("\n".join(lines) + "\n")
    tr = np.array(truth_track)
    vt = tr[:, 3:6]
    return {"max_speed": float(np.linalg.norm(vt, axis=1).max()),
            "max_climb": float((-vt[:, 2]).max()), "max_descent": float(vt[:, 2].max()),
            "min_height": float((-tr[:, 2]).min()),
            "max_tilt_deg": float(max(math.degrees(math.acos(max(-1, min(1, qrot(x[6:10])[2, 2])))) for x in tr[::20]))}


def airframe(mass, path):
    txt = f"""[airframe]
name = "audit36_8in_x"
mass = {mass}
inertia = [0.0110, 0.0115, 0.0210]
arm_length = {L_ARM}
layout = "x"
rotor_inertia = {J_R}
gravity = {G}

[parameters]
K_T = 9.0e-6
b = 7.0e-8
Kd = [0.2, 0.2, 0.2]
"""
    with open(path, "w") as f:
        f.write(txt)


CASES = ["control", "canted", "payload", "inflow", "ground"]
SEEDS = {"control": 3601, "canted": 3611, "payload": 3621, "inflow": 3631, "ground": 3641}


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "flights"
    only = sys.argv[2].split(",") if len(sys.argv) > 2 else CASES
    os.makedirs(out, exist_ok=True)
    airframe(1.0, os.path.join(out, "airframe.toml"))
    airframe(1.15, os.path.join(out, "airframe_payload.toml"))
    lam = 1e-4
    kin = -(bem_ct(lam) - bem_ct(-lam)) / (2 * lam) / CT0
    truth = {"K_T": K_T, "b": B, "Kd": KD.tolist(), "J_r": J_R, "mass": M, "tau_motor": TAU_M,
             "canted": {"cant_deg": 7.0, "K_T_eff": K_T * math.cos(CANT), "b_eff": B * math.cos(CANT)},
             "payload": {"m_L": M_L, "L": L_CAB, "attach_below_cog": 0.05},
             "inflow": {"theta0": THETA0, "kin": kin, "k_rdv_linearised": K_T * kin / RAD,
                        "thrust_ratio_at_climb_3mps_hover": float(bem_ct(3.0 / (W_HOVER * RAD)) / CT0),
                        "thrust_ratio_at_descent_3mps_hover": float(bem_ct(-3.0 / (W_HOVER * RAD)) / CT0)},
             "ground": {"ratio_h": {str(h): float(ge_ratio(h)) for h in [0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.75, 1.0, 1.5]},
                        "cheeseman_k_ge": (RAD / 4) ** 2},
             "flights": {}}
    for case in only:
        for tag, seed, dur in (("est", SEEDS[case], 50.0), ("val", SEEDS[case] + 100, 40.0)):
            name = f"{case}_{tag}"
            info = simulate(case, seed, dur, out, name)
            truth["flights"][name] = {"seed": seed, "duration": dur, **info}
            print(name, info, flush=True)
    with open(os.path.join(out, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)


if __name__ == "__main__":
    main()

"""Blind audit 42: an independent quadrotor simulator (numpy only) writing greybox flight logs.

    python sim.py OUTDIR        # regenerates every flight and airframe bit for bit

Written from /work/shared/CONTRACT.md alone (NED world, FRD body, ZYX Euler, layout "x":
rotor 1 front-right (+a,+a), 2 back-left (-a,-a), 3 front-left (+a,-a), 4 back-right (-a,+a),
a = l/sqrt(2), spin = [+1,+1,-1,-1]; thrust K_T w^2 along body -z, reaction torque
spin_i*b*w_i^2 about body +z; world-frame linear drag -Kd*v; rotor inertia 0).

Dynamics: RK4 with a unit quaternion (renormalised each step), sub-steps <= 1 ms between
controller ticks.  Controller: cascaded geometric (position PD -> thrust vector -> attitude
PD on SO(3)) running at the log rate on the true state, with its OWN model: mass +6 %,
inertia -8 %/+7 %/+9 %, K_T -7 %, b +10 % (so it is 5-10 % off the truth), and its own mixer
(inverse of its model's allocation matrix, w^2 clipped to [w_min^2, w_max^2]).  A small
multisine (1-7 Hz) is added to the attitude set point (system-ID excitation).
Manoeuvres (25 s): position steps, circles, yaw turns, climbs, order and sizes from the seed.

Rotor speeds: the commanded speed is held over each controller period (zero-order hold).
Case "control" and every case but "motor_lag": the rotors take the commanded speed at
once (what the base model assumes) and that speed is logged.  "motor_lag": the rotors follow
dw/dt = (w_cmd - w)/tau_m, the commands are logged.

Sensors (every log row = one IMU sample, taken at the controller tick BEFORE the new command
acts, i.e. with the previous row's rotor speeds, as an autopilot samples then commands):
  gyro  = omega + gyro_bias + N(0, gyro_sd)
  accel = R^T (dv/dt - g e3) + acc_bias + N(0, acc_sd)      (specific force, FRD)
  attitude (IMU-only logs) = my own Mahony filter (Kp 1.0, Ki 0.02 on the accelerometer's
      gravity direction) run on the noisy gyro and accelerometer, plus a weak heading
      correction toward a magnetometer-like heading (truth + N(0, 0.03 rad)); NOT the truth.
  mocap logs: the same flight with x, y, z (NED) and phi, theta, psi from motion capture at
      100 Hz (every rate/100 th row; 1 mm and 3 mrad white noise), the other rows' cells
      empty; p, q, r, ax, ay, az as in the IMU-only log.
The IMU-only logs have the columns t,w1..w4,x,y,z,phi,theta,psi,p,q,r,ax,ay,az with x, y, z\nempty on every row (greybox refuses a log without the columns: see REPORT.md).

Hidden effects (one per case):
  control     : nothing beyond the base model
  motor_lag   : first-order rotor lag tau_m (commands logged)
  drag2x      : linear drag Kd = 2 x the airframe's [parameters] Kd
  battery_sag : K_T(t) = K_T * (1 - 0.003 t)   (thrust_drift, K_T_drift = -0.003 /s)
  weak_rotor  : rotor 2's thrust AND reaction torque x 0.92
Airframe starting values: K_T x 1.25, b x 0.70 of the truth, Kd = the truth's nominal Kd.
Estimation flight seed = base + case index, validation flight = that + 1000.

TRUTH (see VEHICLES below):
  cf   : m 0.030 kg, J [1.66e-5, 1.66e-5, 2.93e-5], l 0.046 m, K_T 1.8e-8, b 1.1e-10,
         Kd [0.010, 0.010, 0.014], tau_m 0.025 s, 500 Hz, gyro sd 0.004, acc sd 0.06
  q1kg : m 1.0 kg, J [0.0095, 0.0098, 0.0175], l 0.225 m, K_T 1.2e-5, b 1.9e-7,
         Kd [0.25, 0.25, 0.35], tau_m 0.040 s, 250 Hz, gyro sd 0.008, acc sd 0.15
  h3kg : m 3.0 kg, J [0.045, 0.047, 0.082], l 0.35 m, K_T 5.0e-5, b 1.0e-6,
         Kd [0.6, 0.6, 0.9], tau_m 0.070 s, 200 Hz, gyro sd 0.010, acc sd 0.25
"""
import os
import sys
import json
import numpy as np

G = 9.81

VEHICLES = {
    "cf": dict(m=0.030, J=[1.66e-5, 1.66e-5, 2.93e-5], l=0.046, K_T=1.8e-8, b=1.1e-10,
               Kd=[0.010, 0.010, 0.014], tau=0.025, rate=500, wmax=3000.0, wmin=300.0,
               gyro_sd=0.004, acc_sd=0.06, gyro_bias=[0.012, -0.009, 0.004],
               acc_bias=[0.05, -0.06, 0.08], wn_att=22.0, wn_pos=2.2, amp=0.6, R=0.5,
               dither=0.05, seed=4200),
    "q1kg": dict(m=1.0, J=[0.0095, 0.0098, 0.0175], l=0.225, K_T=1.2e-5, b=1.9e-7,
                 Kd=[0.25, 0.25, 0.35], tau=0.040, rate=250, wmax=800.0, wmin=100.0,
                 gyro_sd=0.008, acc_sd=0.15, gyro_bias=[0.010, 0.006, -0.008],
                 acc_bias=[-0.08, 0.06, 0.05], wn_att=16.0, wn_pos=1.8, amp=1.5, R=1.2,
                 dither=0.04, seed=4300),
    "h3kg": dict(m=3.0, J=[0.045, 0.047, 0.082], l=0.35, K_T=5.0e-5, b=1.0e-6,
                 Kd=[0.6, 0.6, 0.9], tau=0.070, rate=200, wmax=650.0, wmin=80.0,
                 gyro_sd=0.010, acc_sd=0.25, gyro_bias=[-0.006, 0.011, 0.007],
                 acc_bias=[0.07, 0.05, -0.06], wn_att=11.0, wn_pos=1.4, amp=2.0, R=1.6,
                 dither=0.035, seed=4400),
}
CASES = ["control", "motor_lag", "drag2x", "battery_sag", "weak_rotor"]
DURATION = 25.0
KT_DRIFT = -0.003
WEAK = (1, 0.92)          # rotor index (0-based: rotor 2), scale
CTRL_ERR = dict(m=1.06, J=[0.92, 1.07, 1.09], K_T=0.93, b=1.10)


def geometry(l):
    a = l / np.sqrt(2.0)
    pos = np.array([[a, a, 0.0], [-a, -a, 0.0], [a, -a, 0.0], [-a, a, 0.0]])
    spin = np.array([1.0, 1.0, -1.0, -1.0])
    return pos, spin


def alloc(K_T, b, pos, spin):
    """[T, tx, ty, tz] = M @ w^2 (rotor i force -f e3 at r_i: torque (-y f, x f, 0))."""
    M = np.zeros((4, 4))
    M[0] = K_T
    M[1] = -pos[:, 1] * K_T
    M[2] = pos[:, 0] * K_T
    M[3] = spin * b
    return M


def q2R(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def euler2q(phi, th, psi):
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(th / 2), np.sin(th / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


def R2euler(R):
    return (np.arctan2(R[2, 1], R[2, 2]), -np.arcsin(np.clip(R[2, 0], -1, 1)),
            np.arctan2(R[1, 0], R[0, 0]))


def hat(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def vee(M):
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


class Truth:
    def __init__(self, V, case):
        self.m = V["m"]
        self.J = np.array(V["J"])
        self.pos, self.spin = geometry(V["l"])
        self.K_T = V["K_T"]
        self.b = V["b"]
        self.Kd = np.array(V["Kd"]) * (2.0 if case == "drag2x" else 1.0)
        self.lag = V["tau"] if case == "motor_lag" else None
        self.scale = np.ones(4)
        if case == "weak_rotor":
            self.scale[WEAK[0]] = WEAK[1]
        self.drift = KT_DRIFT if case == "battery_sag" else 0.0

    def forces(self, t, q, v, w):
        """thrust T (N), body torque (N m), world acceleration."""
        kt = self.K_T * (1.0 + self.drift * t)
        f = kt * self.scale * w * w
        T = f.sum()
        tau = np.array([np.sum(-self.pos[:, 1] * f), np.sum(self.pos[:, 0] * f),
                        np.sum(self.spin * self.b * self.scale * w * w)])
        R = q2R(q)
        acc = np.array([0, 0, G]) + R @ np.array([0, 0, -T]) / self.m - self.Kd * v / self.m
        return T, tau, acc, R

    def deriv(self, t, s, wcmd):
        v, q, om, w = s[3:6], s[6:10], s[10:13], s[13:17]
        if self.lag is None:
            w_act, dw = wcmd, np.zeros(4)
        else:
            w_act, dw = w, (wcmd - w) / self.lag
        T, tau, acc, R = self.forces(t, q, v, w_act)
        domega = (tau - np.cross(om, self.J * om)) / self.J
        dq = 0.5 * qmul(q, np.array([0.0, om[0], om[1], om[2]]))
        return np.concatenate([v, acc, dq, domega, dw])


def reference(rng, V):
    """List of (t0, kind, params) segments of 4 s; returns function t -> (pos_ref, psi_ref)."""
    kinds = list(rng.permutation(["step", "circle", "yaw", "climb"])) + \
        list(rng.choice(["step", "circle", "yaw", "climb"], 2))
    segs = []
    pos = np.array([0.0, 0.0, -1.0])
    psi = 0.0
    amp, R = V["amp"], V["R"]
    for i, k in enumerate(kinds):
        t0 = 0.5 + 4.0 * i
        if k == "step":
            target = pos.copy()
            target[:2] = rng.uniform(-amp, amp, 2)
            segs.append((t0, k, dict(p0=pos.copy(), p1=target.copy(), psi=psi)))
            pos = target
        elif k == "circle":
            period = rng.uniform(3.5, 5.0)
            sgn = rng.choice([-1.0, 1.0])
            segs.append((t0, k, dict(c=pos.copy(), R=R, period=period, sgn=sgn, psi=psi)))
        elif k == "yaw":
            dpsi = rng.choice([-1.0, 1.0]) * rng.uniform(1.2, 2.0)
            segs.append((t0, k, dict(p0=pos.copy(), psi0=psi, psi1=psi + dpsi)))
            psi = psi + dpsi
        else:
            target = pos.copy()
            target[2] = -1.0 - rng.uniform(0.3, 0.8) if pos[2] > -1.4 else -1.0
            segs.append((t0, k, dict(p0=pos.copy(), p1=target.copy(), psi=psi)))
            pos = target

    def ref(t):
        p, ps = np.array([0.0, 0.0, -1.0]), 0.0
        for t0, k, d in segs:
            if t < t0:
                break
            tau = t - t0
            if k in ("step", "climb"):
                p, ps = d["p1"], d["psi"]
            elif k == "circle":
                if tau < 4.0:
                    ang = d["sgn"] * 2 * np.pi * tau / d["period"]
                    p = d["c"] + np.array([d["R"] * np.sin(abs(ang)),
                                           d["sgn"] * d["R"] * (1 - np.cos(ang)), 0.0])
                else:
                    p = d["c"]
                ps = d["psi"]
            else:
                p, ps = d["p0"], d["psi1"]
        return p, ps
    return ref, kinds


def multisine(rng, n=4):
    f = rng.uniform(1.0, 7.0, (3, n))
    ph = rng.uniform(0, 2 * np.pi, (3, n))
    return lambda t: np.sin(2 * np.pi * f * t + ph).sum(axis=1) / np.sqrt(n / 2.0)


def fly(vname, case, seed):
    V = VEHICLES[vname]
    rng = np.random.default_rng(seed)
    tr = Truth(V, case)
    pos, spin = tr.pos, tr.spin
    # controller's model (5-10 % off)
    mc = V["m"] * CTRL_ERR["m"]
    Jc = np.array(V["J"]) * np.array(CTRL_ERR["J"])
    Mc = alloc(V["K_T"] * CTRL_ERR["K_T"], V["b"] * CTRL_ERR["b"], pos, spin)
    Minv = np.linalg.inv(Mc)
    wn, z = V["wn_att"], 0.8
    wns = np.array([wn, wn, 0.4 * wn])                 # yaw loop slower
    kR, kW = Jc * wns ** 2, Jc * 2 * z * wns
    wp = V["wn_pos"]
    kp, kv = wp ** 2, 2 * 0.9 * wp
    ref, kinds = reference(rng, V)
    dith = multisine(rng)
    dt = 1.0 / V["rate"]
    nsub = int(np.ceil(dt / 0.001 - 1e-9))
    h = dt / nsub
    N = int(round(DURATION / dt))
    # state: p v q om w
    w_h = np.sqrt(V["m"] * G / (4 * V["K_T"]))
    s = np.concatenate([[0, 0, -1.0], [0, 0, 0], [1, 0, 0, 0], [0, 0, 0], [w_h] * 4])
    wcmd = np.full(4, w_h) if tr.lag is None else np.full(4, w_h)
    pr_f, vr_f = np.array([0, 0, -1.0]), np.zeros(3)   # filtered reference (2nd order)
    psr_f, psr_v = 0.0, 0.0
    wr = 1.6
    gb, ab = np.array(V["gyro_bias"]), np.array(V["acc_bias"])
    # Mahony filter state
    qe = np.array([1.0, 0, 0, 0])
    bint = np.zeros(3)
    rows = []
    truth_att = []
    for k in range(N):
        t = k * dt
        p, v, q, om, w = s[0:3], s[3:6], s[6:10], s[10:13], s[13:17]
        # ---- sensors at t_k, with the rotor speeds acting just before the new command
        w_act = wcmd if tr.lag is None else w
        T, tau, acc, R = tr.forces(t, q, v, w_act)
        gyro = om + gb + rng.normal(0, V["gyro_sd"], 3)
        accm = R.T @ (acc - np.array([0, 0, G])) + ab + rng.normal(0, V["acc_sd"], 3)
        # ---- Mahony filter (FRD: gravity's specific-force direction in body = R^T(-e3))
        Re = q2R(qe)
        vhat = Re.T @ np.array([0, 0, -1.0])
        an = accm / np.linalg.norm(accm)
        e = np.cross(an, vhat)
        # heading aid (magnetometer-like): yaw error about world z expressed in body
        psi_true = R2euler(R)[2]
        psi_m = psi_true + rng.normal(0, 0.03)
        psi_e = R2euler(Re)[2]
        dpsi = np.arctan2(np.sin(psi_m - psi_e), np.cos(psi_m - psi_e))
        e = e + 0.3 * dpsi * (Re.T @ np.array([0, 0, 1.0]))
        if k > 0:
            bint = bint + 0.02 * e * dt
            wcorr = gyro + 1.0 * e + bint
            qe = qe + 0.5 * qmul(qe, np.array([0.0, *wcorr])) * dt
            qe = qe / np.linalg.norm(qe)
        else:
            qe = q.copy()
        phi_e, th_e, psi_ee = R2euler(q2R(qe))
        # mocap pose
        mp = p + rng.normal(0, 0.001, 3)
        ma = np.array(R2euler(R)) + rng.normal(0, 0.003, 3)
        ma[2] = np.arctan2(np.sin(ma[2]), np.cos(ma[2]))
        # ---- controller (true state), new command for [t_k, t_k+1)
        pref, psiref = ref(t)
        # filtered reference
        ar = wr ** 2 * (pref - pr_f) - 2 * wr * vr_f
        vr_f = vr_f + ar * dt
        pr_f = pr_f + vr_f * dt
        apsi = wr ** 2 * (psiref - psr_f) - 2 * wr * psr_v
        psr_v += apsi * dt
        psr_f += psr_v * dt
        a_des = kp * (pr_f - p) + kv * (vr_f - v) + ar
        a_des = np.clip(a_des, -3.0, 3.0)
        F = mc * (a_des - np.array([0, 0, G]))          # desired force (world), thrust = -F.zb
        zb = -F / np.linalg.norm(F)
        d = dith(t) * V["dither"]
        psi_d = psr_f + 0.3 * d[2]
        xc = np.array([np.cos(psi_d), np.sin(psi_d), 0.0])
        yb = np.cross(zb, xc)
        yb /= np.linalg.norm(yb)
        xb = np.cross(yb, zb)
        Rd = np.column_stack([xb, yb, zb])
        # excitation: small roll/pitch rotation of the set point
        ca, sa = np.cos(d[0]), np.sin(d[0])
        cb, sb = np.cos(d[1]), np.sin(d[1])
        Rd = Rd @ np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]]) @ \
            np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
        Tcmd = F @ (-(R @ np.array([0, 0, 1.0])))
        eR = 0.5 * vee(Rd.T @ R - R.T @ Rd)
        torque = -kR * eR - kW * om + np.cross(om, Jc * om)
        w2 = Minv @ np.concatenate([[Tcmd], torque])
        wnew = np.sqrt(np.clip(w2, V["wmin"] ** 2, V["wmax"] ** 2))
        rows.append([t, *wnew, phi_e, th_e, psi_ee, *gyro, *accm, *mp, *ma])
        truth_att.append(R2euler(R))
        wcmd = wnew
        # ---- integrate to t_k+1 (RK4)
        for j in range(nsub):
            tt = t + j * h
            k1 = tr.deriv(tt, s, wcmd)
            k2 = tr.deriv(tt + h / 2, s + h / 2 * k1, wcmd)
            k3 = tr.deriv(tt + h / 2, s + h / 2 * k2, wcmd)
            k4 = tr.deriv(tt + h, s + h * k3, wcmd)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            s[6:10] /= np.linalg.norm(s[6:10])
        if tr.lag is None:
            s[13:17] = wcmd
    rows = np.array(rows)
    ta = np.array(truth_att)
    err = rows[:, 5:8] - ta
    err[:, 2] = np.arctan2(np.sin(err[:, 2]), np.cos(err[:, 2]))
    info = dict(vehicle=vname, case=case, seed=seed, kinds=[str(x) for x in kinds],
                filter_att_err_rms=np.sqrt((err ** 2).mean(axis=0)).tolist(),
                w_min=float(rows[:, 1:5].min()), w_max=float(rows[:, 1:5].max()),
                tilt_max_deg=float(np.degrees(np.abs(ta[:, :2]).max())),
                z_range=[float(rows[:, 16].min()), float(rows[:, 16].max())],
                clipped_share=float(np.mean((rows[:, 1:5] <= V["wmin"] + 1e-9) | (rows[:, 1:5] >= V["wmax"] - 1e-9))))
    return rows, info


def fmt(x):
    return "" if x is None else "%.10g" % x


def write_logs(rows, V, base):
    n_mocap = int(round(V["rate"] / 100))
    # greybox refuses a log without the x, y, z columns ("a log without position keeps the
    # columns x, y, z, left empty"), so the IMU-only logs carry them, empty on every row.
    head_imu = "t,w1,w2,w3,w4,x,y,z,phi,theta,psi,p,q,r,ax,ay,az"
    with open(base + "_imu.csv", "w") as f:
        f.write(head_imu + "\n")
        for r in rows:
            f.write(",".join(fmt(x) for x in list(r[0:5]) + [None] * 3 + list(r[5:14])) + "\n")
    with open(base + "_mocap.csv", "w") as f:
        f.write("t,w1,w2,w3,w4,x,y,z,phi,theta,psi,p,q,r,ax,ay,az\n")
        for k, r in enumerate(rows):
            if k % n_mocap == 0:
                pose = list(r[14:17]) + list(r[17:20])
            else:
                pose = [None] * 6
            f.write(",".join(fmt(x) for x in list(r[0:5]) + pose + list(r[8:14])) + "\n")


def write_airframe(vname, V, path):
    Kd = V["Kd"]
    with open(path, "w") as f:
        f.write(f"""[airframe]
name = "{vname}"
mass = {V['m']!r}
inertia = [{V['J'][0]!r}, {V['J'][1]!r}, {V['J'][2]!r}]
arm_length = {V['l']!r}
layout = "x"
rotor_inertia = 0.0
gravity = 9.81

[parameters]
K_T = {V['K_T'] * 1.25!r}
b = {V['b'] * 0.70!r}
Kd = [{Kd[0]!r}, {Kd[1]!r}, {Kd[2]!r}]
""")


def main(out, only=None):
    os.makedirs(out, exist_ok=True)
    infos = []
    for vname, V in VEHICLES.items():
        write_airframe(vname, V, os.path.join(out, f"{vname}.toml"))
        for ci, case in enumerate(CASES):
            for kind, off in (("est", 0), ("val", 1000)):
                tag = f"{vname}_{case}_{kind}"
                if only and not any(o in tag for o in only):
                    continue
                rows, info = fly(vname, case, V["seed"] + ci + off)
                write_logs(rows, V, os.path.join(out, tag))
                info["tag"] = tag
                infos.append(info)
                print(tag, json.dumps({k: info[k] for k in
                                       ("filter_att_err_rms", "w_min", "w_max", "tilt_max_deg",
                                        "z_range", "clipped_share", "kinds")}), flush=True)
    if not only:
        with open(os.path.join(out, "flights.json"), "w") as f:
            json.dump(infos, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:] or None)

#!/usr/bin/env python3
"""Independent quadrotor simulator for the greybox blind audit 32 (numpy/scipy only).

Vehicle: a 1.35 kg "dead-cat" X quadrotor (front arms longer and wider than the back arms),
given to greybox as [[rotor]] tables in PX4 order (1 front-right, 2 back-left, 3 front-left,
4 back-right; spins +1,+1,-1,-1).

Dynamics: unit quaternion (scalar first) + world-frame NED velocity + body rates, fixed-step
RK4 at 1 ms.  Rotor i: thrust K_T_i(t) w_i^2 along body -z at r_i, reaction torque
spin_i * b_i(t) * w_i^2 about body +z, gyroscopic J_r*Omega_r*(omega x e_z), world linear drag
-Kd*v.  Ground contact (case 'ground'): four feet, penalty spring-damper normal force and
viscous friction capped by Coulomb.

Controller (250 Hz, ZOH): geometric (Lee-type) position/attitude control with integral action,
internal model mismatched (K_T +5 %, b -10 %, J +8 %), a multisine added to the torque command
for excitation, waypoint steps (filtered) and yaw steps.  The rotor-speed command computed at
row k is applied on [t_k, t_k+1) and logged in row k (exactly the contract's zero-order hold).

Sensors (rows at 250 Hz): attitude 250 Hz (2 mrad noise, heading wrapped), gyro 250 Hz
(5 mrad/s), accelerometer 250 Hz (0.08 m/s^2), motion-capture position every 3rd row
(83.3 Hz, 1 mm).  Rotor speeds logged as commanded, rounded to 0.1 rad/s.

Usage: python sim.py OUTDIR            (writes every case)
       python sim.py OUTDIR --openloop INPUTS.csv OUT.csv x0(12 comma values)   (convention check)
"""
import json
import os
import sys

import numpy as np

G = 9.81
DT_ROW = 0.004
SUB = 4  # 1 ms RK4 substeps

# ---------------------------------------------------------------- vehicle truth
MASS = 1.35
J = np.diag([0.0105, 0.0135, 0.0215])
J_R = 2.5e-5
POS = np.array([[0.12, 0.17, 0.0],     # 1 front-right
                [-0.15, -0.15, 0.0],   # 2 back-left
                [0.12, -0.17, 0.0],    # 3 front-left
                [-0.15, 0.15, 0.0]])   # 4 back-right
SPIN = np.array([1.0, 1.0, -1.0, -1.0])
K_T = 1.10e-5
B = 1.80e-7
KD = np.array([0.12, 0.14, 0.20])
ARM = float(np.mean(np.linalg.norm(POS[:, :2], axis=1)))

# ground contact (case 'ground')
FEET = np.array([[0.10, 0.10, 0.08], [-0.10, 0.10, 0.08], [0.10, -0.10, 0.08], [-0.10, -0.10, 0.08]])
K_GND = 4000.0    # N/m per foot
C_GND = 60.0      # N s/m per foot
MU_V = 40.0       # N s/m viscous friction per foot
MU = 0.8          # Coulomb cap


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


def hat(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def vee(M):
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


class Truth:
    def __init__(self, case):
        self.case = case
        self.ground = case.get("ground", False)
        self.damage_t = case.get("damage_t", None)
        self.damage_rotor = case.get("damage_rotor", 2)
        self.damage = case.get("damage", 0.0)

    def coeffs(self, t):
        kt = np.full(4, K_T)
        b = np.full(4, B)
        if self.damage_t is not None and t >= self.damage_t:
            kt[self.damage_rotor] *= 1 - self.damage
            b[self.damage_rotor] *= 1 - self.damage
        return kt, b

    def deriv(self, t, s, w):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = q2R(q)
        kt, b = self.coeffs(t)
        T = kt * w ** 2
        F_b = np.array([0.0, 0.0, -T.sum()])
        tau = np.zeros(3)
        for i in range(4):
            tau += np.cross(POS[i], np.array([0, 0, -T[i]]))
        tau[2] += np.sum(SPIN * b * w ** 2)
        Om_r = np.sum(SPIN * w)
        tau += J_R * Om_r * np.cross(om, np.array([0.0, 0.0, 1.0]))
        F_w = R @ F_b + MASS * G * np.array([0, 0, 1.0]) - KD * v
        if self.ground:
            for f in FEET:
                pf = p + R @ f
                if pf[2] > 0.0:   # below the ground plane z = 0 (NED)
                    vf = v + R @ np.cross(om, f)
                    fn = max(0.0, K_GND * pf[2] + C_GND * vf[2])
                    ft = -MU_V * vf[:2]
                    nt = np.linalg.norm(ft)
                    if nt > MU * fn and nt > 0:
                        ft *= MU * fn / nt
                    Fc = np.array([ft[0], ft[1], -fn])
                    F_w = F_w + Fc
                    tau += np.cross(f, R.T @ Fc)
        a = F_w / MASS
        omd = np.linalg.solve(J, tau - np.cross(om, J @ om))
        qd = 0.5 * qmul(q, np.array([0.0, *om]))
        return np.concatenate([v, a, qd, omd])

    def step(self, t, s, w, dt):
        k1 = self.deriv(t, s, w)
        k2 = self.deriv(t + dt / 2, s + dt / 2 * k1, w)
        k3 = self.deriv(t + dt / 2, s + dt / 2 * k2, w)
        k4 = self.deriv(t + dt, s + dt * k3, w)
        s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
        return s


class Controller:
    def __init__(self, rng):
        self.m = MASS
        self.J = J * 1.08
        kt, b = K_T * 1.05, B * 0.9
        M = np.zeros((4, 4))
        for i in range(4):
            M[0, i] = kt
            M[1, i] = -POS[i, 1] * kt   # r x (0,0,-T): tau_x = -y_i*T
            M[2, i] = POS[i, 0] * kt    # tau_y = x_i*T
            M[3, i] = SPIN[i] * b
        self.Minv = np.linalg.inv(M)
        self.ie = np.zeros(3)
        self.pref_f = None
        self.psi_f = None
        self.amp = np.array([0.035, 0.035, 0.010])
        self.freqs = [np.array([0.7, 1.9, 3.7, 6.1]), np.array([0.9, 2.3, 4.3, 5.3]), np.array([0.5, 1.3, 2.9])]
        self.phases = [rng.uniform(0, 2 * np.pi, len(f)) for f in self.freqs]

    def __call__(self, t, p_m, v_m, R_m, om_m, pref, psiref, dt, excite=True, airborne=True):
        if self.pref_f is None:
            self.pref_f = p_m.copy()
        # reference smoothing: 1st order, 0.6 s, rate-limited 1.5 m/s
        d = (pref - self.pref_f) * dt / 0.6
        lim = 1.5 * dt
        n = np.linalg.norm(d)
        if n > lim:
            d *= lim / n
        self.pref_f = self.pref_f + d
        if self.psi_f is None:
            self.psi_f = psiref
        self.psi_f += np.clip(psiref - self.psi_f, -0.8 * dt, 0.8 * dt)  # yaw setpoint rate-limited 0.8 rad/s
        psiref = self.psi_f
        e = self.pref_f - p_m
        if airborne:
            self.ie = np.clip(self.ie + e * dt, -2, 2)
        a_des = 3.0 * e - 3.2 * v_m + 0.8 * self.ie
        F = self.m * (a_des - np.array([0, 0, G]))
        # tilt limit 35 deg
        hor = np.linalg.norm(F[:2])
        if hor > np.tan(np.radians(35)) * -F[2]:
            F[:2] *= np.tan(np.radians(35)) * -F[2] / hor
        b3 = -F / np.linalg.norm(F)
        c1 = np.array([np.cos(psiref), np.sin(psiref), 0.0])
        b2 = np.cross(b3, c1)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        thrust = max(0.0, F @ (-R_m[:, 2]))
        eR = 0.5 * vee(Rd.T @ R_m - R_m.T @ Rd)
        wn = np.array([11.0, 11.0, 5.0])
        KR = self.J @ np.diag(wn ** 2)
        Kw = self.J @ np.diag(2 * 0.85 * wn)
        tau = -KR @ eR - Kw @ om_m + np.cross(om_m, self.J @ om_m)
        if excite:
            for k in range(3):
                tau[k] += self.amp[k] * np.sum(np.sin(2 * np.pi * self.freqs[k] * t + self.phases[k])) / 2
        u = np.array([thrust, *tau])
        w2 = self.Minv @ u
        w2 = np.clip(w2, 150.0 ** 2, 1050.0 ** 2)
        return np.sqrt(w2)


def waypoints(rng, dur, start_z=-1.5, dt_wp=3.0):
    times = np.arange(0, dur, dt_wp)
    wps = [np.array([0.0, 0.0, start_z])]
    yaws = [0.0]
    for _ in times[1:]:
        wps.append(np.array([rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), start_z + rng.uniform(-0.5, 0.5)]))
        yaws.append(rng.uniform(-1.2, 1.2))
    return times, wps, yaws


def fly(case, dur, seed, damage_t=None):
    rng = np.random.default_rng(seed)
    c = dict(case)
    if damage_t is not None:
        c["damage_t"] = damage_t
    truth = Truth(c)
    ctl = Controller(rng)
    ground = c.get("ground", False)
    att_bias = np.array(c.get("att_bias", [0.0, 0.0]))
    n = int(round(dur / DT_ROW))
    # initial state
    if ground:
        # resting on the feet: CoG 8 cm above the floor minus the static compression
        z0 = -0.08 + MASS * G / (4 * K_GND)
        s = np.concatenate([[0.0, 0.0, z0], np.zeros(3), euler2q(0, 0, 0.0), np.zeros(3)])
    else:
        s = np.concatenate([[0.0, 0.0, -1.5], np.zeros(3), euler2q(0, 0, 0.0), np.zeros(3)])
    t_wp, wps, yaws = waypoints(rng, dur)
    if ground:
        t_up, t_fly, t_land = 2.0, 4.0, dur - 8.0
    rows = []
    truthrows = []
    phase = "air"
    w_prev = np.zeros(4)
    touchdown_t = None
    for k in range(n):
        t = k * DT_ROW
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = q2R(q)
        phi, th, psi = R2euler(R)
        # the controller's attitude estimate carries the bias (case attitude_bias)
        R_m = q2R(euler2q(phi + att_bias[0], th + att_bias[1], psi))
        j = np.searchsorted(t_wp, t, side="right") - 1
        pref, psiref = wps[j].copy(), yaws[j]
        if ground:
            if t < t_up:
                w = np.zeros(4)
                phase = "ground"
            elif t < t_fly:
                # spin-up, open loop: 0 -> 75 % of hover speed
                wh = np.sqrt(MASS * G / (4 * K_T))
                w = np.full(4, 0.75 * wh * (t - t_up) / (t_fly - t_up))
                phase = "spinup"
            elif t < t_land:
                if t < t_fly + 3.0:
                    pref, psiref = np.array([0.0, 0.0, -1.5]), 0.0
                w = ctl(t, p, v, R_m, om, pref, psiref, DT_ROW, excite=t > t_fly + 3.0)
                phase = "air"
            else:
                # descend onto the floor, then cut
                if touchdown_t is None:
                    w = ctl(t, p, v, R_m, om, np.array([0.0, 0.0, 0.3]), 0.0, DT_ROW, excite=False, airborne=False)
                    if p[2] > -0.09 and abs(v[2]) < 0.05:
                        touchdown_t = t
                    phase = "landing"
                else:
                    fr = max(0.0, 1 - (t - touchdown_t) / 1.0)
                    w = w_prev * fr if fr > 0 else np.zeros(4)
                    if fr > 0:
                        w = w_land * fr
                    phase = "ground"
                if touchdown_t is not None and t == touchdown_t:
                    w_land = w_prev.copy()
                    w = w_land
        else:
            w = ctl(t, p, v, R_m, om, pref, psiref, DT_ROW)
        w = np.round(w, 1)
        # --- sensors at t_k (specific force with this row's input)
        ds = truth.deriv(t, s, w)
        acc = ds[3:6]
        f_b = R.T @ (acc - np.array([0, 0, G]))
        row = {"t": round(t, 6)}
        for i in range(4):
            row[f"w{i+1}"] = w[i]
        if k % 3 == 0:
            pm = p + rng.normal(0, 0.001, 3)
            row.update(x=pm[0], y=pm[1], z=pm[2])
        else:
            row.update(x=np.nan, y=np.nan, z=np.nan)
        am = np.array([phi + att_bias[0], th + att_bias[1], psi]) + rng.normal(0, 0.002, 3)
        am[2] = (am[2] + np.pi) % (2 * np.pi) - np.pi
        row.update(phi=am[0], theta=am[1], psi=am[2])
        gm = om + rng.normal(0, 0.005, 3)
        row.update(p=gm[0], q=gm[1], r=gm[2])
        fm = f_b + rng.normal(0, 0.08, 3)
        row.update(ax=fm[0], ay=fm[1], az=fm[2])
        rows.append(row)
        truthrows.append([t, *p, phi, th, psi, *v, *om, *w])
        w_prev = w
        for _ in range(SUB):
            s = truth.step(t + _ * DT_ROW / SUB, s, w, DT_ROW / SUB)
        if not np.all(np.isfinite(s)):
            raise RuntimeError("diverged")
    return rows, np.array(truthrows)


COLS = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az"]


def write_csv(path, rows):
    with open(path, "w") as f:
        f.write(",".join(COLS) + "\n")
        for r in rows:
            vals = []
            for c in COLS:
                v = r[c]
                if c == "t":
                    vals.append(f"{v:.4f}")
                elif isinstance(v, float) and np.isnan(v):
                    vals.append("")
                elif c.startswith("w"):
                    vals.append(f"{v:.1f}")
                else:
                    vals.append(f"{v:.6f}")
            f.write(",".join(vals) + "\n")


def write_airframe(path):
    lines = ["[airframe]", 'name = "deadcat135"', f"mass = {MASS}",
             f"inertia = [{J[0,0]}, {J[1,1]}, {J[2,2]}]", f"arm_length = {ARM:.4f}",
             f"rotor_inertia = {J_R}", "gravity = 9.81", ""]
    for i in range(4):
        lines += ["[[rotor]]", f"position = [{POS[i,0]}, {POS[i,1]}, 0.0]", f"spin = {int(SPIN[i])}", ""]
    lines += ["[parameters]", "K_T = 1.35e-5", "b = 1.2e-7", "Kd = [0.1, 0.1, 0.1]", ""]
    with open(path, "w") as f:
        f.write("\n".join(lines))


CASES = {
    "control": dict(desc="base model only: rotor thrust, reaction torque, world linear drag, gyroscopic", est_seed=101, val_seed=102),
    "ground": dict(desc="base model + ground contact: 2 s on the floor, motors off; 2 s open-loop spin-up to 75 % hover speed; "
                   "flight; landing and 1 s spin-down, then on the floor. Outside the catalogue (a normal force).",
                   ground=True, est_seed=201, val_seed=202),
    "damage": dict(desc="base model + propeller damaged mid-flight: rotor 3 (front-left) thrust and torque coefficient drop "
                   "15 % at t = 20 s (estimation) / t = 15 s (validation). Time-varying: outside the catalogue.",
                   damage_rotor=2, damage=0.15, est_seed=301, val_seed=302, est_damage_t=20.0, val_damage_t=15.0),
    "attbias": dict(desc="base model + attitude_bias: logged roll/pitch offset by (+0.035, -0.026) rad (attitude "
                    "estimator's level trim); the controller flies on the biased attitude.",
                    att_bias=[0.035, -0.026], est_seed=401, val_seed=402),
}
DUR_EST, DUR_VAL = 40.0, 32.0


def openloop(inputs_csv, out_csv, x0):
    import csv
    data = np.genfromtxt(inputs_csv, delimiter=",", names=True)
    t = data["t"]
    W = np.column_stack([data[f"w{i}"] for i in range(1, 5)])
    x0 = np.array(x0, float)
    s = np.concatenate([x0[0:3], x0[6:9], euler2q(*x0[3:6]), x0[9:12]])
    tr = Truth({})
    out = []
    for k in range(len(t)):
        R = q2R(s[6:10])
        out.append([t[k], *s[0:3], *R2euler(R)])
        if k + 1 < len(t):
            dt = t[k + 1] - t[k]
            nsub = int(np.ceil(dt / 0.001 - 1e-9))
            for j in range(nsub):
                s = tr.step(t[k] + j * dt / nsub, s, W[k], dt / nsub)
    np.savetxt(out_csv, np.array(out), delimiter=",", header="t,x,y,z,phi,theta,psi", comments="")


def main():
    if len(sys.argv) >= 2 and "--openloop" in sys.argv:
        i = sys.argv.index("--openloop")
        openloop(sys.argv[i + 1], sys.argv[i + 2], [float(v) for v in sys.argv[i + 3].split(",")])
        return
    out = sys.argv[1]
    only = sys.argv[2:] or list(CASES)
    os.makedirs(out, exist_ok=True)
    write_airframe(os.path.join(out, "airframe.toml"))
    for name in only:
        c = CASES[name]
        truth = {"case": name, "description": c["desc"], "mass": MASS, "inertia": np.diag(J).tolist(),
                 "rotor_inertia": J_R, "rotors": POS.tolist(), "spin": SPIN.tolist(), "K_T": K_T, "b": B,
                 "Kd": KD.tolist(), "airframe_given": "airframe.toml (exact mass, inertia, rotor positions, J_r; "
                 "K_T, b, Kd starting guesses only)",
                 "sensors": {"rows_hz": 250, "position_hz": 83.33, "position_sd_m": 0.001, "attitude_sd_rad": 0.002,
                             "gyro_sd": 0.005, "accel_sd": 0.08, "w_rounding": 0.1},
                 "controller_model": "K_T*1.05, b*0.9, J*1.08; multisine torque excitation"}
        if name == "ground":
            truth["ground_contact"] = {"ground_plane_z": 0.0, "feet_body": FEET.tolist(), "k_per_foot": K_GND,
                                       "c_per_foot": C_GND, "friction_visc": MU_V, "mu": MU}
        if name == "damage":
            truth["damage"] = {"rotor": 3, "factor_after": 0.85, "est_t": c["est_damage_t"], "val_t": c["val_damage_t"],
                               "equivalent_const_asymmetry_note": "K_T of rotor 3 = 0.85 K_T after the event"}
        if name == "attbias":
            truth["att_bias"] = c["att_bias"]
        for kind, seed, dur, dt_ in (("est", c["est_seed"], DUR_EST, c.get("est_damage_t")),
                                      ("val", c["val_seed"], DUR_VAL, c.get("val_damage_t"))):
            rows, tr = fly(c, dur, seed, damage_t=dt_)
            write_csv(os.path.join(out, f"{name}_{kind}.csv"), rows)
            np.save(os.path.join(out, f"{name}_{kind}_truthstates.npy"), tr)
            truth[f"{kind}_seed"] = seed
            truth[f"{kind}_duration_s"] = dur
            truth[f"{kind}_max_speed"] = float(np.max(np.linalg.norm(tr[:, 7:10], axis=1)))
            truth[f"{kind}_max_tilt_deg"] = float(np.degrees(np.max(np.abs(tr[:, 4:6]))))
            truth[f"{kind}_w_range"] = [float(tr[:, 13:17].min()), float(tr[:, 13:17].max())]
            truth[f"{kind}_z_range"] = [float(tr[:, 3].min()), float(tr[:, 3].max())]
        with open(os.path.join(out, f"{name}_truth.json"), "w") as f:
            json.dump(truth, f, indent=1)
        print(name, "done", {k: v for k, v in truth.items() if k.endswith(("max_speed", "max_tilt_deg", "w_range", "z_range"))})


if __name__ == "__main__":
    main()

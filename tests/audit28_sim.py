#!/usr/bin/env python3
"""Independent quadrotor simulator for the greybox blind audit (audit28).

1.1 kg "x" quadrotor, 9-inch props, camera gimbal (lumped into the rigid body).
Own RK4 integrator with a unit quaternion (body->world), NED world / FRD body.
Controller: geometric PD on SO(3) attitude at 250 Hz, velocity loop (+ position P) at 50 Hz.
Sensors: motion capture at 120 Hz (marker body origin at r_pos from the CoG), IMU attitude,
gyro and accelerometer at 250 Hz, rotor speeds logged at 250 Hz with noise.

Regenerate everything:  python sim.py        (fixed seeds, deterministic)

Vendored as written by blind audit 28 (2026-12-06, a helper session that read only the README,
docs/VALIDATION.md and CONTRACT.md, never greybox's code): checked by it against ``greybox
simulate`` to 4e-11 m, 1.2e-12 rad over 6 s. Changed here only so that ``main`` takes the
output directory (``out``; ``./data`` by default, beside the audit's own script it was its
``data/``); the flights are the audit's, byte for byte (``tests/test_audit28_sim.py``).
"""
import json
import os
import sys
import numpy as np

OUT = os.path.join(os.getcwd(), "data")
G = 9.81
E3 = np.array([0.0, 0.0, 1.0])

TRUTH = dict(
    mass=1.1, J=[0.0125, 0.0125, 0.0215], arm=0.20, K_T=7.8e-6, b=1.3e-7,
    Kd=[0.22, 0.22, 0.30], J_r=2.5e-5,
)
A_ = TRUTH["arm"] / np.sqrt(2.0)
ROT_POS = np.array([[A_, A_, 0.0], [-A_, -A_, 0.0], [A_, -A_, 0.0], [-A_, A_, 0.0]])
SPIN = np.array([1.0, 1.0, -1.0, -1.0])


def quat_to_R(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler_to_quat(phi, th, psi):
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(th / 2), np.sin(th / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


def R_to_euler(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    th = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, th, psi


def skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


class Vehicle:
    """Rigid body + physics options. State: p(3) v(3) q(4) w(3) [pL(3) vL(3)]."""

    def __init__(self, K_T=TRUTH["K_T"], b=TRUTH["b"], Kd=TRUTH["Kd"], J=TRUTH["J"],
                 mass=TRUTH["mass"], J_r=TRUTH["J_r"], Kq=None, cant_deg=0.0,
                 payload=None):
        self.K_T, self.b, self.Kd = K_T, b, np.array(Kd)
        self.J = np.diag(J)
        self.Jinv = np.linalg.inv(self.J)
        self.Jd = np.array(J, float)
        self.m, self.J_r = mass, J_r
        self.Kq = None if Kq is None else np.array(Kq)
        c = np.deg2rad(cant_deg)
        u = ROT_POS / np.linalg.norm(ROT_POS, axis=1, keepdims=True)
        # thrust direction (body): up (-z) tilted inward (toward the centre)
        self.tdir = np.array([-np.cos(c) * E3 - np.sin(c) * ui for ui in u])
        self.payload = payload  # dict(mL, L, r_att, k, c)
        self.TM = np.cross(ROT_POS, self.tdir)
        self.YD = -SPIN[:, None] * self.tdir

    def deriv(self, s, w_rot):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = quat_to_R(q)
        w2 = w_rot * w_rot
        T = self.K_T * w2
        F_b = T @ self.tdir
        tau = T @ self.TM + (self.b * w2) @ self.YD
        Om = SPIN @ w_rot
        tau = tau + self.J_r * Om * np.array([om[1], -om[0], 0.0])
        F_w = R @ F_b + self.m * G * E3 - self.Kd * v
        if self.Kq is not None:
            F_w -= self.Kq * np.linalg.norm(v) * v
        ds = np.zeros_like(s)
        if self.payload is not None:
            P = self.payload
            pL, vL = s[13:16], s[16:19]
            ra = R @ P["r_att"]
            a = p + ra
            va = v + R @ np.cross(om, P["r_att"])
            d = pL - a
            ln = np.linalg.norm(d)
            n = d / ln
            ten = P["k"] * (ln - P["L"]) + P["c"] * np.dot(vL - va, n)
            ten = max(ten, 0.0)
            Fc = ten * n  # force on vehicle at attachment
            F_w += Fc
            tau += np.cross(P["r_att"], R.T @ Fc)
            ds[13:16] = vL
            ds[16:19] = (-Fc + P["mL"] * G * E3 - 0.01 * vL) / P["mL"]
        ds[0:3] = v
        ds[3:6] = F_w / self.m
        wq, xq, yq, zq = q
        Omq = np.array([[0, -om[0], -om[1], -om[2]], [om[0], 0, om[2], -om[1]],
                        [om[1], -om[2], 0, om[0]], [om[2], om[1], -om[0], 0]])
        ds[6:10] = 0.5 * Omq @ q
        Jw = self.Jd * om
        ds[10:13] = (tau - np.array([om[1]*Jw[2]-om[2]*Jw[1], om[2]*Jw[0]-om[0]*Jw[2], om[0]*Jw[1]-om[1]*Jw[0]])) / self.Jd
        return ds

    def step(self, s, w_rot, dt, n):
        h = dt / n
        for _ in range(n):
            k1 = self.deriv(s, w_rot)
            k2 = self.deriv(s + h / 2 * k1, w_rot)
            k3 = self.deriv(s + h / 2 * k2, w_rot)
            k4 = self.deriv(s + h * k3, w_rot)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            s[6:10] /= np.linalg.norm(s[6:10])
        return s

    def accel(self, s, w_rot):
        """specific force in body FRD: R^T (dv/dt - g e3)."""
        ds = self.deriv(s, w_rot)
        R = quat_to_R(s[6:10])
        return R.T @ (ds[3:6] - G * E3)


class Controller:
    """Own design: position P -> velocity PI (50 Hz) -> geometric SO(3) PD (250 Hz) -> mixer."""

    def __init__(self, m_nom, J_nom, KT_nom, b_nom):
        self.m, self.J = m_nom, np.diag(J_nom)
        a = A_
        # rows: total thrust, tau_x, tau_y, tau_z  as functions of w^2
        M = np.zeros((4, 4))
        for i in range(4):
            M[0, i] = KT_nom
            M[1, i] = -ROT_POS[i, 1] * KT_nom  # r x (-T e3): tau_x = -y*T
            M[2, i] = ROT_POS[i, 0] * KT_nom   # tau_y = x*T
            M[3, i] = SPIN[i] * b_nom
        self.Minv = np.linalg.inv(M)
        self.Kp, self.Kv, self.Ki = 1.2, 2.2, 0.4
        self.KR = np.array([2.6, 2.6, 1.2])
        self.Kw = np.array([0.30, 0.30, 0.25])
        self.vint = np.zeros(3)
        self.F_des = np.array([0, 0, -m_nom * G])
        self.psi_d = 0.0

    def outer(self, p, v, pref, vff, psi_ref, dt):
        v_sp = self.Kp * (pref - p) + vff
        nv = np.linalg.norm(v_sp)
        if nv > 4.5:
            v_sp *= 4.5 / nv
        ev = v_sp - v
        self.vint = np.clip(self.vint + ev * dt, -2, 2)
        a_des = self.Kv * ev + self.Ki * self.vint
        a_des[:2] = np.clip(a_des[:2], -6, 6)
        a_des[2] = np.clip(a_des[2], -5, 5)
        self.F_des = self.m * (a_des - G * E3)
        self.psi_d = psi_ref

    def inner(self, R, om):
        F = self.F_des
        b3 = -F / np.linalg.norm(F)
        b1c = np.array([np.cos(self.psi_d), np.sin(self.psi_d), 0.0])
        b2 = np.cross(b3, b1c); b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        E = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([E[2, 1], E[0, 2], E[1, 0]])
        tau = -self.KR * eR - self.Kw * om + np.cross(om, self.J @ om)
        T = -F @ (R @ E3)
        w2 = self.Minv @ np.array([T, *tau])
        return np.sqrt(np.clip(w2, 150.0 ** 2, 1150.0 ** 2))


def reference(kind, t):
    """position reference (NED), velocity feed-forward, yaw."""
    z0 = -1.5
    if kind == "steps":
        seq = [(0, (0, 0, z0), 0), (3, (2, 0, z0), 0), (7, (2, 2, z0 - 0.8), 0.8),
               (11, (0, 2, z0), 1.6), (15, (0, 0, z0 - 1.2), 0.3), (19, (-1.5, 1, z0), -1.0),
               (23, (0, 0, z0), 0.0)]
        pr, ps = seq[0][1], seq[0][2]
        for t0, pp, yy in seq:
            if t >= t0:
                pr, ps = pp, yy
        return np.array(pr, float), np.zeros(3), ps
    if kind == "eight":
        A, T = 2.5, 9.0
        w = 2 * np.pi / T
        ramp = min(1.0, t / 3.0)
        pr = np.array([A * np.sin(w * t) * ramp, A / 2 * np.sin(2 * w * t) * ramp,
                       z0 - 0.4 * np.sin(0.5 * w * t) * ramp])
        vf = np.array([A * w * np.cos(w * t), A * w * np.cos(2 * w * t), -0.2 * w * np.cos(0.5 * w * t)]) * ramp
        psi = 0.6 * np.sin(0.35 * t) * ramp
        return pr, vf, psi
    if kind == "mixed":  # validation: faster eight + steps + yaw turn + climb
        if t < 12:
            A, T = 2.0, 7.0
            w = 2 * np.pi / T
            ramp = min(1.0, t / 2.0)
            pr = np.array([A / 2 * np.sin(2 * w * t) * ramp, A * np.sin(w * t) * ramp, z0])
            vf = np.array([A * w * np.cos(2 * w * t), A * w * np.cos(w * t), 0]) * ramp
            return pr, vf, -0.5 * ramp * np.sin(0.5 * t)
        seq = [(12, (0, 0, z0), 0.0), (14, (1.5, -1, z0 - 1.0), 1.2), (18, (-1, 0.5, z0 - 0.3), -0.6),
               (22, (0, 0, z0), 0.2)]
        pr, ps = seq[0][1], seq[0][2]
        for t0, pp, yy in seq:
            if t >= t0:
                pr, ps = pp, yy
        return np.array(pr, float), np.zeros(3), ps
    raise ValueError(kind)


def fly(kind, duration, seed, veh, r_pos=np.zeros(3), sub=4, rate=250.0,
        mocap_rate=120.0, w_noise=5.0, pos_noise=5e-4, att_noise=2e-3, gyro_noise=0.01,
        acc_noise=0.05, ctrl_nom=None, truth_only=False):
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate
    n = int(round(duration * rate))
    pref0, _, psi0 = reference(kind, 0.0)
    s = np.zeros(13 if veh.payload is None else 19)
    s[0:3] = pref0
    s[6:10] = euler_to_quat(0, 0, psi0)
    if veh.payload is not None:
        P = veh.payload
        s[13:16] = s[0:3] + P["r_att"] + np.array([0, 0, P["L"] + P["mL"] * G / P["k"]])
    cn = ctrl_nom or dict(m_nom=TRUTH["mass"] * (1.0 if veh.payload is None else 1.0) + (0 if veh.payload is None else veh.payload["mL"]),
                          J_nom=[0.013, 0.013, 0.022], KT_nom=TRUTH["K_T"] * 1.05, b_nom=TRUTH["b"] * 0.9)
    ctl = Controller(**cn)
    ctl.psi_d = psi0
    rows = []
    states = []
    wcmd = np.full(4, np.sqrt(cn["m_nom"] * G / (4 * cn["KT_nom"])))
    mocap_k = -1
    for k in range(n):
        t = k * dt
        R = quat_to_R(s[6:10])
        if k % 5 == 0:  # 50 Hz outer loop
            pr, vf, ps = reference(kind, t)
            ctl.outer(s[0:3], s[3:6], pr, vf, ps, 5 * dt)
        wcmd = ctl.inner(R, s[10:13])  # 250 Hz inner loop; speeds held for the row (ZOH)
        phi, th, psi = R_to_euler(R)
        acc = veh.accel(s, wcmd)
        row = dict(t=t)
        for i in range(4):
            row[f"w{i+1}"] = wcmd[i] + w_noise * rng.standard_normal()
        mk = int(np.floor(t * mocap_rate + 1e-9))
        if mk != mocap_k:
            mocap_k = mk
            pm = s[0:3] + R @ r_pos + pos_noise * rng.standard_normal(3)
            row.update(x=pm[0], y=pm[1], z=pm[2])
        else:
            row.update(x=np.nan, y=np.nan, z=np.nan)
        a = np.array([phi, th, psi]) + att_noise * rng.standard_normal(3)
        a[2] = (a[2] + np.pi) % (2 * np.pi) - np.pi
        row.update(phi=a[0], theta=a[1], psi=a[2])
        g = s[10:13] + gyro_noise * rng.standard_normal(3)
        row.update(p=g[0], q=g[1], r=g[2])
        ac = acc + acc_noise * rng.standard_normal(3)
        row.update(ax=ac[0], ay=ac[1], az=ac[2])
        rows.append(row)
        states.append(np.concatenate([[t], s[:13], wcmd]))
        s = veh.step(s, wcmd, dt, sub)
        if not np.all(np.isfinite(s)) or abs(s[2]) > 50:
            raise RuntimeError(f"diverged at t={t}")
    return rows, np.array(states)


COLS = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az"]


def write_csv(path, rows, cols=COLS):
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for r in rows:
            f.write(",".join("" if (isinstance(r[c], float) and np.isnan(r[c])) else repr(float(r[c])) for c in cols) + "\n")


def airframe(path, name, mass=TRUTH["mass"], J=TRUTH["J"], K_T=TRUTH["K_T"], b=TRUTH["b"],
             Kd=TRUTH["Kd"], extra_params="", rotor_tables=None):
    with open(path, "w") as f:
        f.write(f'[airframe]\nname = "{name}"\nmass = {mass}\ninertia = [{J[0]}, {J[1]}, {J[2]}]\n'
                f'arm_length = {TRUTH["arm"]}\n')
        if rotor_tables is None:
            f.write('layout = "x"\n')
        f.write(f'rotor_inertia = {TRUTH["J_r"]}\ngravity = {G}\n\n')
        if rotor_tables:
            f.write(rotor_tables + "\n")
        f.write(f'[parameters]\nK_T = {K_T}\nb = {b}\nKd = [{Kd[0]}, {Kd[1]}, {Kd[2]}]\n{extra_params}')


CASES = {
    # name: (vehicle kwargs, r_pos, substeps)
    "A": (dict(), np.zeros(3), 4),
    "B": (dict(), np.array([0.03, 0.02, -0.05]), 4),
    "C": (dict(payload=dict(mL=0.10, L=0.5, r_att=np.array([0.0, 0.0, 0.04]), k=4000.0, c=8.0)), np.zeros(3), 8),
    "D": (dict(cant_deg=5.0), np.zeros(3), 4),
    "E": (dict(Kq=[0.06, 0.06, 0.09]), np.zeros(3), 4),
}
FLIGHTS = [("est1", "steps", 26.0, 1), ("est2", "eight", 27.0, 2), ("val", "mixed", 26.0, 3)]


def main(which=None, out=None):
    OUT = out or globals()["OUT"]
    os.makedirs(OUT, exist_ok=True)
    truth = {"vehicle": TRUTH, "cases": {}}
    for case, (vk, r_pos, sub) in CASES.items():
        if which and case not in which:
            continue
        veh = Vehicle(**vk)
        for fname, kind, dur, seed in FLIGHTS:
            rows, st = fly(kind, dur, 100 * ord(case) + seed, veh, r_pos=r_pos, sub=sub)
            write_csv(f"{OUT}/{case}_{fname}.csv", rows)
            np.save(f"{OUT}/{case}_{fname}_truth.npy", st)
            print(case, fname, len(rows), "rows", flush=True)
        truth["cases"][case] = dict(vehicle={k: (v if not isinstance(v, dict) else {kk: (vv.tolist() if hasattr(vv, 'tolist') else vv) for kk, vv in v.items()}) for k, v in vk.items()},
                                    r_pos=r_pos.tolist())
    # airframes
    airframe(f"{OUT}/af_true.toml", "audit28_true")
    airframe(f"{OUT}/af_off.toml", "audit28_off", K_T=TRUTH["K_T"] * 1.4, b=TRUTH["b"] * 0.6,
             Kd=[0.11, 0.11, 0.15])
    airframe(f"{OUT}/af_off_inertia.toml", "audit28_off_J", K_T=TRUTH["K_T"] * 1.4, b=TRUTH["b"] * 0.6,
             Kd=[0.11, 0.11, 0.15], J=[0.0125 * 1.35, 0.0125 * 1.35, 0.0215 * 1.35])
    airframe(f"{OUT}/af_payload.toml", "audit28_payload", mass=1.2, K_T=TRUTH["K_T"] * 1.4,
             b=TRUTH["b"] * 0.6, Kd=[0.11, 0.11, 0.15])
    airframe(f"{OUT}/af_mass25.toml", "audit28_mass25", mass=1.1 * 1.25)
    with open(f"{OUT}/truth.json", "w") as f:
        json.dump(truth, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1:] or None)

#!/usr/bin/env python
"""A third independent quadrotor flight simulator (after ``foreign_sim`` and ``peer_sim``).

Written by a blind audit (2026-11-29) from the public contract only, without greybox's
code: NED world, FRD body, ZYX Euler, plus layout rotor 1 front / 2 right / 3 back / 4 left,
spin [-1,+1,-1,+1]; a 0.25 kg vehicle with an asymmetric inertia, integrated by scipy's
``solve_ivp`` (DOP853) between the updates of its own 400 Hz geometric/cascaded controller,
logged at 200 Hz (so each logged command holds for half its row), mocap at 100 Hz. The
cases add a quadratic drag, a position delay, a thrust falling with axial inflow (outside
greybox's catalogue) or 30-ms motors with the commands logged. ``cfg["duration"]`` sets the
flight's length (30 s by default).

usage: gen.py CASE OUTDIR      (CASE in c1_clean c2_quaddrag c3_posdelay c4_inflow c5_motorlag)
       gen.py check
"""
import json
import sys
import os
import numpy as np
from scipy.integrate import solve_ivp

# ---------------------------------------------------------------- vehicle (truth)
M = 0.25
G = 9.81
J = np.array([1.2e-4, 1.3e-4, 2.2e-4])
ARM = 0.11
W_HOVER = 1100.0
K_T = M * G / (4 * W_HOVER ** 2)          # 5.0670e-7 N/(rad/s)^2
B = 0.012 * K_T                           # 6.080e-9 N m/(rad/s)^2
J_R = 3e-7
KD = np.array([0.04, 0.05, 0.08])
POS = np.array([[ARM, 0, 0], [0, ARM, 0], [-ARM, 0, 0], [0, -ARM, 0]], float)
SPIN = np.array([-1.0, 1.0, -1.0, 1.0])
W_MIN, W_MAX = 150.0, 2400.0

CTRL_DT = 1 / 400
LOG_EVERY = 2               # 200 Hz log
MOCAP_EVERY = 2             # 100 Hz mocap (every other log row)
T_END = 30.0

CASES = {
    "c1_clean": {"speed": 0.75},
    "c2_quaddrag": {"quad_c": 0.02, "speed": 1.6, "fscale": 0.7},
    "c3_posdelay": {"pos_delay": 0.04, "speed": 0.75},
    "c4_inflow": {"inflow_k": 0.03, "zamp": 1.0, "speed": 0.75},
    "c5_motorlag": {"tau_m": 0.03, "log_commands": True, "speed": 0.75},
    # control run: c1 logged at the controller's 400 Hz (log rows = exact held inputs), w to 1e-6
    "c1b_log400": {"speed": 0.75, "log_every": 1, "mocap_every": 4, "wdigits": 6},
    "c3b_posdelay_log400": {"pos_delay": 0.04, "speed": 0.75, "log_every": 1, "mocap_every": 4, "wdigits": 6},
    "c5b_motorlag_log400": {"tau_m": 0.03, "log_commands": True, "speed": 0.75, "log_every": 1, "mocap_every": 4, "wdigits": 6},
}


# ---------------------------------------------------------------- rotations
def quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def quat_to_R(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler_to_quat(phi, theta, psi):
    # R = Rz(psi) Ry(theta) Rx(phi)  -> q = qz * qy * qx
    qx = np.array([np.cos(phi / 2), np.sin(phi / 2), 0, 0])
    qy = np.array([np.cos(theta / 2), 0, np.sin(theta / 2), 0])
    qz = np.array([np.cos(psi / 2), 0, 0, np.sin(psi / 2)])
    return quat_mul(qz, quat_mul(qy, qx))


def R_to_euler(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    theta = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return np.array([phi, theta, psi])


def Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def Ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def Rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


# ---------------------------------------------------------------- dynamics
def make_rhs(cfg):
    quad_c = cfg.get("quad_c", 0.0)
    inflow_k = cfg.get("inflow_k", None)
    tau_m = cfg.get("tau_m", None)

    def rhs(t, s, w_cmd):
        pos, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        w = s[13:17] if tau_m is not None else w_cmd
        R = quat_to_R(q)
        T = K_T * w ** 2
        if inflow_k is not None:
            vb = R.T @ v
            v_up = -vb[2]
            T = T * (1 - v_up / (w * inflow_k))
        f_body = np.array([0.0, 0.0, -T.sum()])
        F = R @ f_body + M * G * np.array([0, 0, 1.0]) - KD * v
        if quad_c:
            F = F - quad_c * np.linalg.norm(v) * v
        acc = F / M
        tau = np.zeros(3)
        for i in range(4):
            tau += np.cross(POS[i], np.array([0, 0, -T[i]]))
        tau[2] += np.sum(SPIN * B * w ** 2)
        Om_r = np.sum(SPIN * w)
        tau += J_R * Om_r * np.cross(om, np.array([0, 0, 1.0]))
        dom = (tau - np.cross(om, J * om)) / J
        dq = 0.5 * quat_mul(q, np.array([0, *om]))
        # keep the quaternion on the unit sphere (first-order normalisation)
        dq += 10.0 * (1 - q @ q) * q
        out = np.concatenate([v, acc, dq, dom])
        if tau_m is not None:
            out = np.concatenate([out, (w_cmd - w) / tau_m])
        return out
    return rhs


# ---------------------------------------------------------------- mixer
MIX = np.array([[K_T, K_T, K_T, K_T],
                [0, -ARM * K_T, 0, ARM * K_T],        # roll  l K_T (w4^2 - w2^2)
                [ARM * K_T, 0, -ARM * K_T, 0],        # pitch l K_T (w1^2 - w3^2)
                [-B, B, -B, B]])                      # yaw   b(-w1^2+w2^2-w3^2+w4^2)
MIX_INV = np.linalg.inv(MIX)


def mix(T, tau):
    w2 = MIX_INV @ np.array([T, *tau])
    return np.sqrt(np.clip(w2, W_MIN ** 2, W_MAX ** 2))


# ---------------------------------------------------------------- trajectory
class Traj:
    def __init__(self, seed, speed=1.0, zamp=0.4, fscale=1.0):
        rng = np.random.default_rng(seed)
        self.comp = []
        # x, y: two sines each; z: two sines; yaw: two sines
        for axis, amps, freqs in [(0, [1.6, 0.6], [0.9, 2.1]), (1, [1.4, 0.5], [1.1, 2.5]),
                                  (2, [zamp * 0.55, zamp * 0.22], [1.6, 3.1]),
                                  (3, [0.7, 0.25], [0.5, 1.7])]:
            for a, f in zip(amps, freqs):
                sc = speed if axis < 2 else 1.0
                aa = a * sc * rng.uniform(0.8, 1.2)
                ff = f * rng.uniform(0.85, 1.15) * (fscale if axis < 2 else 1.0)
                ph = rng.uniform(0, 2 * np.pi)
                self.comp.append((axis, aa, ff, ph))
        self.z0 = -1.5

    def _raw(self, t):
        out = np.zeros((3, 4))  # derivative order x (x,y,z,psi)
        for axis, a, f, ph in self.comp:
            s, c = np.sin(f * t + ph), np.cos(f * t + ph)
            out[0, axis] += a * (s - np.sin(ph))
            out[1, axis] += a * f * c
            out[2, axis] += -a * f * f * s
        return out

    def __call__(self, t):
        # smooth envelope: ramp in over 3 s
        T0 = 3.0
        if t < T0:
            u = t / T0
            e = u ** 3 * (10 - 15 * u + 6 * u * u)
            de = 30 * u ** 2 * (1 - u) ** 2 / T0
            dde = 60 * u * (1 - u) * (1 - 2 * u) / T0 ** 2
        else:
            e, de, dde = 1.0, 0.0, 0.0
        r = self._raw(t)
        p = e * r[0]
        v = e * r[1] + de * r[0]
        a = e * r[2] + 2 * de * r[1] + dde * r[0]
        p[2] += self.z0
        return p, v, a


# ---------------------------------------------------------------- controller
class Controller:
    def __init__(self):
        self.kp = np.array([4.0, 4.0, 6.0])
        self.kd = np.array([3.5, 3.5, 4.5])
        self.k_att = np.array([9.0, 9.0, 5.0])
        self.k_rate = np.array([45.0, 45.0, 25.0])
        self.ki_rate = np.array([20.0, 20.0, 10.0])
        self.i_rate = np.zeros(3)

    def __call__(self, ref, pos, v, R, om):
        p_d, v_d, a_d, psi_d = ref
        a_cmd = a_d + self.kp * (p_d - pos) + self.kd * (v_d - v) + KD * v / M * 0.5
        f = M * (G * np.array([0, 0, 1.0]) - a_cmd)   # = T * R e3 desired
        b3 = f / np.linalg.norm(f)
        b1c = np.array([np.cos(psi_d), np.sin(psi_d), 0])
        b2 = np.cross(b3, b1c)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        T = f @ (R @ np.array([0, 0, 1.0]))
        E = 0.5 * (Rd.T @ R - R.T @ Rd)
        e_R = np.array([E[2, 1], E[0, 2], E[1, 0]])
        om_cmd = -self.k_att * e_R
        e_om = om_cmd - om
        self.i_rate = np.clip(self.i_rate + e_om * CTRL_DT, -0.5, 0.5)
        tau = J * (self.k_rate * e_om + self.ki_rate * self.i_rate) + np.cross(om, J * om)
        return mix(max(T, 0.1), tau)


# ---------------------------------------------------------------- flight
def fly(cfg, seed, amp_scale=1.0):
    rng = np.random.default_rng(seed + 1000)
    traj = Traj(seed, speed=cfg.get("speed", 1.0) * amp_scale, zamp=cfg.get("zamp", 0.4) * amp_scale,
                fscale=cfg.get("fscale", 1.0))
    rhs = make_rhs(cfg)
    tau_m = cfg.get("tau_m", None)
    ctrl = Controller()
    p0, v0, _ = traj(0.0)
    s = np.concatenate([p0[:3], v0[:3], euler_to_quat(0, 0, p0[3]), np.zeros(3)])
    if tau_m is not None:
        s = np.concatenate([s, np.full(4, W_HOVER)])
    n_steps = int(round(cfg.get("duration", T_END) / CTRL_DT))
    rows = []
    for k in range(n_steps + 1):
        t = k * CTRL_DT
        pos, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = quat_to_R(q)
        p_d, v_d, a_d = traj(t)
        w_cmd = ctrl((p_d[:3], v_d[:3], a_d[:3], p_d[3]), pos, v, R, om)
        w_act = s[13:17].copy() if tau_m is not None else w_cmd
        if k % cfg.get("log_every", LOG_EVERY) == 0:
            rows.append(dict(t=t, pos=pos.copy(), v=v.copy(), R=R.copy(), om=om.copy(),
                             w_act=w_act.copy(), w_cmd=w_cmd.copy()))
        if k == n_steps:
            break
        sol = solve_ivp(rhs, (t, t + CTRL_DT), s, method="DOP853", rtol=1e-8, atol=1e-10,
                        args=(w_cmd,))
        s = sol.y[:, -1].copy()
        s[6:10] /= np.linalg.norm(s[6:10])
    return rows, rng


def write_log(rows, rng, cfg, path):
    n = len(rows)
    delay_rows = int(round(cfg.get("pos_delay", 0.0) / (CTRL_DT * cfg.get("log_every", LOG_EVERY))))
    wfmt = "%%.%df" % cfg.get("wdigits", 4)
    log_cmd = cfg.get("log_commands", False)
    hdr = "t,w1,w2,w3,w4,x,y,z,phi,theta,psi,p,q,r"
    lines = [hdr]
    truth_pos = np.array([r["pos"] for r in rows])
    for i, r in enumerate(rows):
        w = r["w_cmd"] if log_cmd else r["w_act"]
        eul = R_to_euler(r["R"]) + rng.normal(0, 0.003, 3)
        gyro = r["om"] + rng.normal(0, 0.01, 3)
        if i % cfg.get("mocap_every", MOCAP_EVERY) == 0:
            src = truth_pos[max(i - delay_rows, 0)]
            pxyz = src + rng.normal(0, 0.0015, 3)
            ps = ["%.6f" % c for c in pxyz]
        else:
            ps = ["nan"] * 3
        vals = ["%.4f" % r["t"]] + [wfmt % c for c in w] + ps + \
            ["%.6f" % c for c in eul] + ["%.6f" % c for c in gyro]
        lines.append(",".join(vals))
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def write_airframe(path):
    txt = f"""[airframe]
name = "audit5_plus_250g"
mass = {M}
inertia = [{J[0]}, {J[1]}, {J[2]}]
arm_length = {ARM}
layout = "plus"
rotor_inertia = {J_R}
gravity = {G}

[parameters]
K_T = {K_T * 1.35:.6e}
b = {B * 0.6:.6e}
Kd = [0.1, 0.1, 0.1]
"""
    with open(path, "w") as f:
        f.write(txt)


def stats(rows):
    v = np.array([r["v"] for r in rows])
    eul = np.array([R_to_euler(r["R"]) for r in rows])
    w = np.array([r["w_act"] for r in rows])
    wc = np.array([r["w_cmd"] for r in rows])
    vb = np.array([r["R"].T @ r["v"] for r in rows])
    return dict(max_speed=float(np.linalg.norm(v, axis=1).max()),
                rms_speed=float(np.sqrt((np.linalg.norm(v, axis=1) ** 2).mean())),
                max_vz=float(np.abs(v[:, 2]).max()), max_vzb=float(np.abs(vb[:, 2]).max()),
                max_bank_deg=float(np.degrees(np.abs(eul[:, :2]).max())),
                psi_range=[float(eul[:, 2].min()), float(eul[:, 2].max())],
                w_range=[float(w.min()), float(w.max())],
                frac_cmd_saturated=float(np.mean((wc >= W_MAX - 1e-6) | (wc <= W_MIN + 1e-6))))


# ---------------------------------------------------------------- checks
def check():
    rhs = make_rhs({})
    s = np.concatenate([np.zeros(3), np.zeros(3), [1, 0, 0, 0], np.zeros(3)])
    d = rhs(0, s, np.full(4, W_HOVER))
    print(f"K_T={K_T:.5e}  b={B:.5e}  b/K_T={B / K_T:.4f} m")
    print("hover accel (should be 0):", d[3:6], " thrust", 4 * K_T * W_HOVER ** 2, "weight", M * G)
    # roll torque: w4 > w2 -> positive roll (right side down), then +y acceleration
    w = np.array([W_HOVER, W_HOVER * 0.99, W_HOVER, W_HOVER * 1.01])
    sol = solve_ivp(rhs, (0, 0.2), s, method="DOP853", rtol=1e-8, atol=1e-10, args=(w,))
    sf = sol.y[:, -1]
    eul = R_to_euler(quat_to_R(sf[6:10]))
    print("w4>w2 for 0.2 s: p=%.3f rad/s phi=%.4f rad vy=%.5f m/s (expect all > 0)" % (sf[10], eul[0], sf[4]))
    w = np.array([W_HOVER * 1.01, W_HOVER, W_HOVER * 0.99, W_HOVER])
    sol = solve_ivp(rhs, (0, 0.2), s, method="DOP853", rtol=1e-8, atol=1e-10, args=(w,))
    sf = sol.y[:, -1]
    eul = R_to_euler(quat_to_R(sf[6:10]))
    print("w1>w3 for 0.2 s: q=%.3f rad/s theta=%.4f vx=%.5f (expect q>0, theta>0 nose up, vx<0)" % (sf[11], eul[1], sf[3]))
    w = np.array([W_HOVER * 0.99, W_HOVER * 1.01, W_HOVER * 0.99, W_HOVER * 1.01])
    sol = solve_ivp(rhs, (0, 0.2), s, method="DOP853", rtol=1e-8, atol=1e-10, args=(w,))
    print("w2,w4 > w1,w3 (spin +1 faster): r=%.4f rad/s (expect > 0)" % sol.y[12, -1])
    # euler round trip
    q = euler_to_quat(0.3, -0.2, 1.1)
    print("euler round trip:", R_to_euler(quat_to_R(q)), " R check:",
          np.abs(quat_to_R(q) - Rz(1.1) @ Ry(-0.2) @ Rx(0.3)).max())
    # gyroscopic sign: Om_r>0, q>0 -> roll torque +J_r q Om_r
    s2 = s.copy(); s2[11] = 1.0
    w = np.array([1000, 1200, 1000, 1200.0])
    d = rhs(0, s2, w)
    Om = np.sum(SPIN * w)
    print("gyro: roll accel %.4f, expected J_r*q*Om_r/Jx = %.4f" % (d[10], J_R * 1.0 * Om / J[0]))


if __name__ == "__main__":
    if sys.argv[1] == "check":
        check()
        sys.exit()
    case, out = sys.argv[1], sys.argv[2]
    cfg = CASES[case]
    os.makedirs(out, exist_ok=True)
    write_airframe(os.path.join(out, "airframe.toml"))
    info = {"case": case, "cfg": cfg, "K_T": K_T, "b": B, "Kd": KD.tolist(), "J_r": J_R}
    for name, seed, amp in [("est", 11, 1.0), ("val", 22, 0.9)]:
        rows, rng = fly(cfg, seed, amp)
        write_log(rows, rng, cfg, os.path.join(out, name + ".csv"))
        info[name] = stats(rows)
        print(name, info[name], flush=True)
    with open(os.path.join(out, "truth.json"), "w") as f:
        json.dump(info, f, indent=1)

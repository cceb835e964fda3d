#!/usr/bin/env python3
"""Independent hexacopter simulator for the greybox blind audit (audit26).

Vendored as written by blind audit 26 (a helper session that read only the README, the
contract and docs/VALIDATION.md), for tests/test_audit26_sim.py; only this paragraph added.

Written from README/CONTRACT conventions only: NED world, FRD body, ZYX Euler,
thrust K_T w^2 along body -z at r_i, reaction torque spin_i*b*w^2 about body +z,
gyroscopic torque J_r*Omega_r*(omega x e_z), Omega_r = sum(spin_i w_i),
world-frame linear drag -Kd*v.

Own implementation: quaternion attitude, fixed-step RK4 at 1 ms, a geometric
controller at 200 Hz whose mixer uses mismatched K_T/b, commands held (ZOH) 5 ms,
no motor dynamics.  Log rows at 200 Hz: rotor speeds (+noise), gyro, vbat per cell;
motion capture (position 1 mm, attitude 2 mrad) on every other row (100 Hz).

`python sim.py` regenerates everything under /tmp/audit26/data deterministically.
`python sim.py check` writes the convention-check inputs / reference trajectories.
"""
import os
import sys
import numpy as np

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")
G = 9.81

# ----------------------------------------------------------------- truth
M = 1.8
J = np.diag([0.030, 0.030, 0.055])
JD = np.diag(J).copy()
ARM = 0.30
ANG = np.deg2rad(30.0 + 60.0 * np.arange(6))       # hexa-X: rotor1 front-right, then clockwise seen from above
POS = np.stack([ARM * np.cos(ANG), ARM * np.sin(ANG), np.zeros(6)], axis=1)   # FRD
SPIN = np.array([+1, -1, +1, -1, +1, -1], float)
K_T = 1.45e-5
B = 2.3e-7
KD = np.array([0.30, 0.30, 0.45])
J_R = 4.0e-5
K_VBAT = 0.20          # case B only: w_actual = w_logged*(1 + K_VBAT*(vbat_cell - 4))
WEAK_ROTOR = 3         # case C: rotor 3 (1-based) at 90 % thrust and torque
WEAK = 0.90

DT_CTRL = 0.005        # controller and log rows: 200 Hz
N_SUB = 5              # RK4 sub-steps per row (1 ms)


def rot_from_quat(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler_from_R(R):
    # R = Rz(psi) Ry(theta) Rx(phi)
    phi = np.arctan2(R[2, 1], R[2, 2])
    theta = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return np.array([phi, theta, psi])


def R_from_euler(phi, th, psi):
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)
    Rz = np.array([[cp, -sp, 0], [sp, cp, 0], [0, 0, 1]])
    Ry = np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    Rx = np.array([[1, 0, 0], [0, cf, -sf], [0, sf, cf]])
    return Rz @ Ry @ Rx


def quat_from_R(R):
    tr = np.trace(R)
    if tr > 0:
        s = 2 * np.sqrt(tr + 1)
        return np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    i = np.argmax(np.diag(R))
    if i == 0:
        s = 2 * np.sqrt(1 + R[0, 0] - R[1, 1] - R[2, 2])
        return np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    if i == 1:
        s = 2 * np.sqrt(1 + R[1, 1] - R[0, 0] - R[2, 2])
        return np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    s = 2 * np.sqrt(1 + R[2, 2] - R[0, 0] - R[1, 1])
    return np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])


class Vehicle:
    def __init__(self, kt_scale=None):
        self.kt_scale = np.ones(6) if kt_scale is None else np.asarray(kt_scale, float)

    def deriv(self, s, w):
        """s = [p(3), v(3), quat(4), omega(3)]; w: actual rotor speeds (6)."""
        v = s[3:6]
        q = s[6:10]
        om = s[10:13]
        R = rot_from_quat(q / np.linalg.norm(q))
        T = K_T * self.kt_scale * w ** 2
        f_body = np.array([0.0, 0.0, -T.sum()])
        acc = np.array([0, 0, G]) + (R @ f_body - KD * v) / M
        tau = np.array([-np.dot(POS[:, 1], T), np.dot(POS[:, 0], T), np.sum(SPIN * B * self.kt_scale * w ** 2)])
        Om_r = np.sum(SPIN * w)
        tau = tau + J_R * Om_r * np.array([om[1], -om[0], 0.0])
        Jom = JD * om
        domega = (tau - np.array([om[1] * Jom[2] - om[2] * Jom[1], om[2] * Jom[0] - om[0] * Jom[2],
                                  om[0] * Jom[1] - om[1] * Jom[0]])) / JD
        qw, qx, qy, qz = q
        ox, oy, oz = om
        dq = 0.5 * np.array([-qx * ox - qy * oy - qz * oz,
                             qw * ox + qy * oz - qz * oy,
                             qw * oy - qx * oz + qz * ox,
                             qw * oz + qx * oy - qy * ox])
        return np.concatenate([v, acc, dq, domega])

    def step(self, s, w, dt):
        h = dt / N_SUB
        for _ in range(N_SUB):
            k1 = self.deriv(s, w)
            k2 = self.deriv(s + 0.5 * h * k1, w)
            k3 = self.deriv(s + 0.5 * h * k2, w)
            k4 = self.deriv(s + h * k3, w)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            s[6:10] /= np.linalg.norm(s[6:10])
        return s


# ------------------------------------------------------------ controller
KT_C, B_C, M_C = 1.05 * K_T, 0.9 * B, M * 1.02
A_MIX = np.vstack([KT_C * np.ones(6), -KT_C * POS[:, 1], KT_C * POS[:, 0], B_C * SPIN])
A_PINV = np.linalg.pinv(A_MIX)
W_MIN, W_MAX = 150.0, 1000.0


def vee(S):
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


class Controller:
    def __init__(self):
        self.ipos = np.zeros(3)

    def __call__(self, s, ref):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = rot_from_quat(q)
        pr, vr, ar, psir, rr = ref
        ep, ev = pr - p, vr - v
        self.ipos += ep * DT_CTRL
        self.ipos = np.clip(self.ipos, -2, 2)
        a_des = ar + np.array([2.5, 2.5, 4.0]) * ep + np.array([3.0, 3.0, 4.0]) * ev + np.array([0.4, 0.4, 1.5]) * self.ipos
        f = M_C * (a_des - np.array([0, 0, G]))          # required force, world (NED)
        zb = -f / np.linalg.norm(f)                        # body z (down) desired
        # limit tilt to 35 deg
        c = np.array([np.cos(psir), np.sin(psir), 0.0])
        yb = np.cross(zb, c); yb /= np.linalg.norm(yb)
        xb = np.cross(yb, zb)
        Rd = np.stack([xb, yb, zb], axis=1)
        T = -f @ (R @ np.array([0, 0, 1.0]))
        eR = 0.5 * vee(Rd.T @ R - R.T @ Rd)
        om_d = np.array([0, 0, rr])
        eW = om - R.T @ Rd @ om_d
        kR = np.array([9.0, 9.0, 4.0]) * np.diag(J) / 0.03 * np.array([1, 1, 1])
        kW = np.array([2.2, 2.2, 1.8]) * np.diag(J) / 0.03
        Jc = J * 1.1
        tau = -kR * eR - kW * eW + np.cross(om, Jc @ om)
        u = np.concatenate([[T], tau])
        w2 = A_PINV @ u
        w2 = np.clip(w2, W_MIN ** 2, W_MAX ** 2)
        return np.sqrt(w2)


# ------------------------------------------------------------ references
def make_ref(seed, dur):
    rng = np.random.default_rng(1000 + seed)
    comps = []
    for ax, amp in ((0, 1.1), (1, 1.1), (2, 0.3), (3, 0.8)):
        k = 3
        fr = rng.uniform(0.06, 0.32, k)
        ph = rng.uniform(0, 2 * np.pi, k)
        am = rng.uniform(0.3, 1.0, k); am = am / am.sum() * amp
        comps.append((fr, ph, am))

    def ref(t):
        TR = 2.0
        if t < TR:
            ramp = 0.5 * (1 - np.cos(np.pi * t / TR))
            dramp = 0.5 * np.pi / TR * np.sin(np.pi * t / TR)
            ddramp = 0.5 * (np.pi / TR) ** 2 * np.cos(np.pi * t / TR)
        else:
            ramp, dramp, ddramp = 1.0, 0.0, 0.0
        out = []
        for fr, ph, am in comps:
            w = 2 * np.pi * fr
            sig = np.sum(am * (np.sin(w * t + ph) - np.sin(ph)))
            dsig = np.sum(am * w * np.cos(w * t + ph))
            ddsig = np.sum(-am * w * w * np.sin(w * t + ph))
            out.append((ramp * sig, ramp * dsig + dramp * sig, ramp * ddsig + 2 * dramp * dsig + ddramp * sig))
        p0 = np.array([0.0, 0.0, -1.6])
        pr = p0 + np.array([out[0][0], out[1][0], out[2][0]])
        vr = np.array([out[0][1], out[1][1], out[2][1]])
        ar = np.array([out[0][2], out[1][2], out[2][2]])
        return pr, vr, ar, out[3][0], out[3][1]
    return ref


# -------------------------------------------------------------- flights
def fly(seed, dur, v0, case, rng_noise):
    """Return dict of arrays for one flight. case in 'A','B','C'."""
    veh = Vehicle(kt_scale=None)
    if case == "C":
        sc = np.ones(6); sc[WEAK_ROTOR - 1] = WEAK
        veh = Vehicle(kt_scale=sc)
    ctl = Controller()
    ref = make_ref(seed, dur)
    q0 = quat_from_R(R_from_euler(0, 0, 0))
    s = np.concatenate([[0, 0, -1.6], [0, 0, 0], q0, [0, 0, 0]])
    n = int(round(dur / DT_CTRL))
    w_hover = np.sqrt(M * G / (6 * K_T))
    P_hover = 6 * w_hover ** 3
    vb = v0
    rows = []
    for k in range(n):
        t = k * DT_CTRL
        w_cmd = ctl(s, ref(t))
        # battery: per-cell voltage, slow discharge + sag with power
        if case == "B":
            w_act = w_cmd * (1 + K_VBAT * (vb - 4.0))
        else:
            w_act = w_cmd.copy()
        P = np.sum(w_act ** 3)
        vb = v0 - 0.0025 * t - 0.07 * (P / P_hover)
        R = rot_from_quat(s[6:10])
        eul = euler_from_R(R)
        w_logged_true = w_cmd if case == "B" else w_act     # B: the ESC's speed at the command (calibrated at 4 V)
        rows.append(dict(t=t, s=s.copy(), eul=eul, w_true=w_logged_true.copy(), w_act=w_act.copy(), vbat=vb))
        s = veh.step(s, w_act, DT_CTRL)
    # assemble log with noise
    t = np.array([r["t"] for r in rows])
    W = np.array([r["w_true"] for r in rows])
    Wlog = W + rng_noise.normal(0, 3.0, W.shape)
    S = np.array([r["s"] for r in rows])
    E = np.array([r["eul"] for r in rows])
    vbat = np.array([r["vbat"] for r in rows]) + rng_noise.normal(0, 0.005, n)
    pos = S[:, 0:3] + rng_noise.normal(0, 0.001, (n, 3))
    att = E + rng_noise.normal(0, 0.002, (n, 3))
    att[:, 2] = (att[:, 2] + np.pi) % (2 * np.pi) - np.pi
    gyro = S[:, 10:13] + rng_noise.normal(0, 0.004, (n, 3))
    mocap = (np.arange(n) % 2 == 0)
    pos[~mocap] = np.nan
    att[~mocap] = np.nan
    return dict(t=t, W=Wlog, Wtrue=W, Wact=np.array([r["w_act"] for r in rows]), pos=pos, att=att, gyro=gyro,
                vbat=vbat, S=S, E=E)


def write_log(path, fl, swap=None, vbat_scale=1.0):
    W = fl["W"].copy()
    if swap is not None:
        i, j = swap
        W[:, [i - 1, j - 1]] = W[:, [j - 1, i - 1]]
    cols = ["t"] + [f"w{i}" for i in range(1, 7)] + ["x", "y", "z", "phi", "theta", "psi", "p", "q", "r", "vbat"]
    data = np.column_stack([fl["t"], W, fl["pos"], fl["att"], fl["gyro"], fl["vbat"] * vbat_scale])
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for row in data:
            cells = []
            for c, v in zip(cols, row):
                if np.isnan(v):
                    cells.append("")
                elif c == "t":
                    cells.append(f"{v:.3f}")
                else:
                    cells.append(f"{v:.6g}")
            f.write(",".join(cells) + "\n")


def write_airframe(path, name, spins=None, guess=True):
    spins = SPIN if spins is None else spins
    lines = ["[airframe]", f'name = "{name}"', f"mass = {M}",
             f"inertia = [{J[0,0]}, {J[1,1]}, {J[2,2]}]", f"arm_length = {ARM}",
             f"rotor_inertia = {J_R}", "gravity = 9.81", ""]
    for i in range(6):
        lines += ["[[rotor]]", f"position = [{POS[i,0]:.6f}, {POS[i,1]:.6f}, 0.0]", f"spin = {int(spins[i])}", ""]
    lines += ["[parameters]"]
    if guess:   # a user's rough guesses, 20-40 % off
        lines += [f"K_T = {K_T*1.3:.4e}", f"b = {B*0.7:.4e}", "Kd = [0.21, 0.21, 0.6]"]
    else:
        lines += [f"K_T = {K_T:.4e}", f"b = {B:.4e}", f"Kd = [{KD[0]}, {KD[1]}, {KD[2]}]"]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


FLIGHTS = [  # (name, seed, duration, battery per cell at start)
    ("f1", 1, 20.0, 4.15),
    ("f2", 2, 18.0, 3.98),
    ("f3", 3, 22.0, 3.82),
    ("f4", 4, 16.0, 3.68),
]
VALID = ("val", 9, 20.0, 3.90)


def main():
    os.makedirs(OUT, exist_ok=True)
    write_airframe(os.path.join(OUT, "hexa.toml"), "hexa10")
    write_airframe(os.path.join(OUT, "hexa_truth.toml"), "hexa10_truth", guess=False)
    truth = dict(K_T=K_T, b=B, Kd=KD.tolist(), J_r=J_R, K_vbat=K_VBAT, weak_rotor=WEAK_ROTOR, weak=WEAK,
                 mass=M, inertia=np.diag(J).tolist(), positions=POS.tolist(), spins=SPIN.tolist())
    import json
    with open(os.path.join(OUT, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    for case in ("A", "B", "C"):
        d = os.path.join(OUT, case)
        os.makedirs(d, exist_ok=True)
        for ci, (name, seed, dur, v0) in enumerate(FLIGHTS + [VALID]):
            rng = np.random.default_rng(100 * seed + ord(case))
            fl = fly(seed, dur, v0, case, rng)
            write_log(os.path.join(d, f"{name}.csv"), fl)
            np.savez_compressed(os.path.join(d, f"{name}_truth.npz"), **{k: v for k, v in fl.items()})
            if case == "A":   # case D: the user swapped rotor columns 2 and 3 in every log
                dd = os.path.join(OUT, "D"); os.makedirs(dd, exist_ok=True)
                write_log(os.path.join(dd, f"{name}.csv"), fl, swap=(2, 3))
            if case == "B" and name == "f2":   # bad input: vbat in millivolts
                dd = os.path.join(OUT, "bad"); os.makedirs(dd, exist_ok=True)
                write_log(os.path.join(dd, f"{name}_vbat_mV.csv"), fl, vbat_scale=1000.0)
            print(case, name, "done", "tilt max %.2f rad" % np.abs(fl["E"][:, :2]).max(),
                  "w range %.0f-%.0f" % (fl["Wact"].min(), fl["Wact"].max()),
                  "vbat %.2f-%.2f" % (fl["vbat"].min(), fl["vbat"].max()),
                  "psi range %.2f..%.2f" % (fl["E"][:, 2].min(), fl["E"][:, 2].max()), flush=True)
    check()


def check():
    """Convention check inputs: noise-free true speeds of flight A/f1 (first 4 s) and my trajectory."""
    d = os.path.join(OUT, "check"); os.makedirs(d, exist_ok=True)
    for case in ("A", "B", "C"):
        rng = np.random.default_rng(0)
        fl = fly(1, 4.0, 3.80, case, rng)
        W = fl["Wtrue"]
        cols = ["t"] + [f"w{i}" for i in range(1, 7)] + (["vbat"] if case == "B" else [])
        vb = fl["vbat"]  # noisy but that's an input; my truth uses its own noise-free vbat -> use logged one in both
        # re-simulate open loop from the logged inputs with my own integrator so both sides see the same inputs
        veh = Vehicle()
        if case == "C":
            sc = np.ones(6); sc[WEAK_ROTOR - 1] = WEAK; veh = Vehicle(sc)
        s = fl["S"][0].copy()
        traj = []
        for k in range(len(fl["t"])):
            traj.append(np.concatenate([s[0:3], euler_from_R(rot_from_quat(s[6:10])), s[10:13]]))
            w = W[k] * (1 + K_VBAT * (vb[k] - 4.0)) if case == "B" else W[k]
            s = veh.step(s, w, DT_CTRL)
        traj = np.array(traj)
        with open(os.path.join(d, f"inputs_{case}.csv"), "w") as f:
            f.write(",".join(cols) + "\n")
            for k in range(len(fl["t"])):
                vals = [f"{fl['t'][k]:.3f}"] + [f"{x:.10g}" for x in W[k]] + ([f"{vb[k]:.10g}"] if case == "B" else [])
                f.write(",".join(vals) + "\n")
        np.savetxt(os.path.join(d, f"mine_{case}.csv"), np.column_stack([fl["t"], traj]), delimiter=",",
                   header="t,x,y,z,phi,theta,psi,p,q,r", comments="")
    print("check files written")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "check":
        check()
    else:
        main()

#!/usr/bin/env python3
"""Independent 5-inch racing quadrotor simulator for the greybox blind audit (audit25).

Vendored as written by blind audit 25 (a helper session that read only the README, the
contract and docs/VALIDATION.md), for tests/test_audit25_sim.py; only this paragraph added.

Written from README/CONTRACT conventions only:
  world NED, body FRD, ZYX Euler (R = Rz Ry Rx, body->world), thrust K_T w^2 along body -z,
  reaction torque spin_i*b*w_i^2 about body +z, gyroscopic torque J_r*Omega_r*(omega x e_z),
  Omega_r = sum(spin_i*w_i), linear drag -Kd*v (world axes), layout "x":
  rotor 1 (+a,+a), 2 (-a,-a), 3 (+a,-a), 4 (-a,+a), spin [+1,+1,-1,-1], a = l/sqrt(2).

Closed loop: geometric (Lee-type) SE(3) controller at 1 kHz, first-order motors
(tau 15 ms), RK4 at 0.5 ms. Sensors: DShot-eRPM-like telemetry (quantised 100 eRPM, 7 pole
pairs -> 1.496 rad/s, noise), mocap pose at 200 Hz with dropouts, gyro at 500 Hz with bias.

`python sim.py` regenerates every file under /tmp/audit25/data deterministically.
`python sim.py --openloop U.csv OUT.csv [k_rd]` integrates the model open loop (ZOH inputs,
no motor lag) for the convention check against `greybox simulate`.
"""
import json, os, sys
import numpy as np

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")

# ---------------- truth -----------------
M = 0.6
G = 9.81
J = np.array([1.5e-3, 1.5e-3, 2.8e-3])
L = 0.11
A = L / np.sqrt(2)
POS = np.array([[A, A, 0], [-A, -A, 0], [A, -A, 0], [-A, A, 0]])
SPIN = np.array([1.0, 1.0, -1.0, -1.0])
K_T = 6.0e-7
B = 8.4e-9            # b/K_T = 0.014 m
KD = np.array([0.06, 0.06, 0.09])
J_R = 6.0e-6
TAU_M = 0.015
W_MIN, W_MAX = 250.0, 3140.0
POLE_PAIRS = 7
ERPM_RES = 100.0      # bidirectional DShot reports eRPM/100
W_Q = ERPM_RES / POLE_PAIRS * 2 * np.pi / 60.0   # rad/s per telemetry count (1.496)


def rot(phi, th, psi):
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)
    Rz = np.array([[cp, -sp, 0], [sp, cp, 0], [0, 0, 1]])
    Ry = np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    Rx = np.array([[1, 0, 0], [0, cf, -sf], [0, sf, cf]])
    return Rz @ Ry @ Rx


def dyn(s, w, P):
    """s = [x,y,z,phi,th,psi,vx,vy,vz,p,q,r]; w = effective rotor speeds (4,)."""
    phi, th, psi = s[3:6]
    v = s[6:9]
    om = s[9:12]
    R = rot(phi, th, psi)
    vb = R.T @ v
    w2 = w * w
    fac = 1.0 + P.get("c_in", 0.0) * vb[2]            # case C: thrust x (1 + c v_bz)
    T = P["K_T"] * (1.0 + P.get("dev", np.zeros(4))) * w2 * fac
    Fb = np.array([0.0, 0.0, -T.sum()])
    krd = P.get("k_rd", 0.0)
    if krd:
        Fb += -krd * w.sum() * np.array([vb[0], vb[1], 0.0])
    Fw = R @ Fb - P["Kd"] * v + np.array([0, 0, M * G])
    acc = Fw / M
    tau = np.array([(-POS[:, 1] * T).sum(), (POS[:, 0] * T).sum(), (SPIN * P["b"] * w2).sum()])
    Om_r = (SPIN * w).sum()
    tau += P["J_r"] * Om_r * np.cross(om, [0, 0, 1.0])
    domega = (tau - np.cross(om, J * om)) / J
    p, q, r = om
    cf, sf, tt, ct = np.cos(phi), np.sin(phi), np.tan(th), np.cos(th)
    deul = np.array([p + (q * sf + r * cf) * tt, q * cf - r * sf, (q * sf + r * cf) / ct])
    return np.concatenate([v, deul, acc, domega])


def rk4(f, s, h):
    k1 = f(s); k2 = f(s + h / 2 * k1); k3 = f(s + h / 2 * k2); k4 = f(s + h * k3)
    return s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


# ---------------- reference trajectories -----------------
def ref_traj(seed, T, vmax_h, vmax_z, amax_h):
    rng = np.random.default_rng(seed)
    dt = 1e-3
    t = np.arange(0, T + 1e-9, dt)
    env = np.clip(t / 6.0, 0, 1); env = env * env * (3 - 2 * env)
    end = np.clip((T - t) / 5.0, 0, 1); end = end * end * (3 - 2 * end)
    env = env * end
    comp = []
    for ax in range(3):
        om = rng.uniform(0.3, 0.65, 3) if ax < 2 else rng.uniform(0.5, 1.5, 3)
        ph = rng.uniform(0, 2 * np.pi, 3)
        am = rng.uniform(0.5, 1.0, 3) / om
        sig = (am[:, None] * np.sin(om[:, None] * t + ph[:, None])).sum(0)
        om2 = rng.uniform(3, 7, 2); ph2 = rng.uniform(0, 2 * np.pi, 2)
        fast = (0.02 * np.sin(om2[:, None] * t + ph2[:, None])).sum(0)
        comp.append((sig, fast))
    pos = np.zeros((len(t), 3))
    for ax in range(3):
        sig, fast = comp[ax]
        pos[:, ax] = env * sig
    vel = np.gradient(pos, dt, axis=0)
    acc = np.gradient(vel, dt, axis=0)
    mid = (t > 6) & (t < T - 5)
    sh = max(np.linalg.norm(vel[mid, :2], axis=1).max() / vmax_h,
             np.linalg.norm(acc[:, :2], axis=1).max() / amax_h)
    sz = max(np.abs(vel[:, 2]).max() / vmax_z, np.abs(acc[:, 2]).max() / 5.0)
    pos[:, :2] /= sh
    pos[:, 2] /= sz
    for ax in range(3):
        pos[:, ax] += env * comp[ax][1]
    pos[:, 2] += -7.0                                  # 7 m above the ground (NED z = -7)
    vel = np.gradient(pos, dt, axis=0)
    acc = np.gradient(vel, dt, axis=0)
    # yaw: a few spins of +-rate with smooth bumps
    rate = np.zeros_like(t)
    nsp = 4
    for c in np.sort(rng.uniform(5, T - 5, nsp)):
        width = rng.uniform(1.5, 3.0)
        amp = rng.choice([-1, 1]) * rng.uniform(2.0, 3.0)
        x = (t - c) / width
        rate += amp * np.where(np.abs(x) < 1, np.cos(np.pi * x / 2) ** 2, 0.0)
    psi = np.cumsum(rate) * dt
    return t, pos, vel, acc, psi, rate


# ---------------- controller -----------------
CTRL_KT = K_T * 1.05          # controller's own (slightly wrong) nominal values
CTRL_B = B * 0.9
ALLOC = np.vstack([np.ones(4) * CTRL_KT, -POS[:, 1] * CTRL_KT, POS[:, 0] * CTRL_KT, SPIN * CTRL_B])
ALLOC_INV = np.linalg.inv(ALLOC)
KP, KV = 9.0, 5.4
KR = J * 30.0 ** 2
KW = J * 2 * 0.75 * 30.0


def vee(S):
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


def control(s, pr, vr, ar, psir, rr):
    R = rot(*s[3:6])
    ep, ev = s[0:3] - pr, s[6:9] - vr
    a_des = ar - KP * ep - KV * ev
    F = M * (np.array([0, 0, G]) - a_des)           # = T * R e3
    Tc = np.linalg.norm(F)
    b3 = F / Tc
    b1c = np.array([np.cos(psir), np.sin(psir), 0.0])
    b2 = np.cross(b3, b1c); b2 /= np.linalg.norm(b2)
    b1 = np.cross(b2, b3)
    Rd = np.column_stack([b1, b2, b3])
    eR = 0.5 * vee(Rd.T @ R - R.T @ Rd)
    omd = R.T @ Rd @ np.array([0, 0, rr])
    ew = s[9:12] - omd
    om = s[9:12]
    tau = -KR * eR - KW * ew + np.cross(om, J * om)
    Tc = Tc * (R[:, 2] @ b3)                         # project thrust on the current axis
    w2 = ALLOC_INV @ np.array([Tc, *tau])
    return np.sqrt(np.clip(w2, W_MIN ** 2, W_MAX ** 2))


# ---------------- closed-loop flight -----------------
def fly(seed, T, P, vmax_h=9.5, vmax_z=3.5, amax_h=9.0):
    t, pr, vr, ar, psir, rr = ref_traj(seed, T, vmax_h, vmax_z, amax_h)
    s = np.zeros(12); s[0:3] = pr[0]; s[5] = psir[0]
    w_hover = np.sqrt(M * G / 4 / K_T)
    wm = np.full(4, w_hover)                  # actual motor speeds
    h = 5e-4
    n = len(t)
    S = np.zeros((n, 12)); W = np.zeros((n, 4)); WC = np.zeros((n, 4))
    for k in range(n):
        S[k] = s; W[k] = wm
        wc = control(s, pr[k], vr[k], ar[k], psir[k], rr[k])
        WC[k] = wc
        for _ in range(2):
            z = np.concatenate([s, wm])
            f = lambda zz: np.concatenate([dyn(zz[:12], zz[12:], P), (wc - zz[12:]) / TAU_M])
            z = rk4(f, z, h)
            s, wm = z[:12], z[12:]
    return t, S, W, WC, pr


def sense(seed, t, S, W, w_delay_rows=0, mocap_jitter=0.0):
    """500 Hz rows. Returns dict of columns."""
    rng = np.random.default_rng(seed + 1000)
    idx = np.arange(0, len(t), 2)                 # 1 kHz -> 500 Hz rows
    tr = t[idx]
    Sr = S[idx]
    Wr_true = W[idx]
    if w_delay_rows:
        Wr_true = np.vstack([np.repeat(Wr_true[:1], w_delay_rows, 0), Wr_true[:-w_delay_rows]])
    wl = Wr_true + rng.normal(0, 3.0, Wr_true.shape)
    wl = np.round(wl / W_Q) * W_Q                 # eRPM quantisation
    n = len(tr)
    cols = {"t": np.round(tr, 6)}
    for i in range(4):
        cols[f"w{i+1}"] = wl[:, i]
    # mocap at 200 Hz: the nearest 500 Hz row to each 5 ms instant, true value at that row
    mt = np.arange(0, tr[-1], 0.005)
    mrow = np.unique(np.round(mt / 0.002).astype(int))
    mask = np.zeros(n, bool); mask[mrow] = True
    # dropouts
    for _ in range(5):
        c = rng.uniform(2, tr[-1] - 2); d = rng.uniform(0.05, 0.3)
        mask[(tr > c) & (tr < c + d)] = False
    pos = Sr[:, 0:3] + rng.normal(0, 0.001, (n, 3))
    att = Sr[:, 3:6] + rng.normal(0, 0.002, (n, 3))
    if mocap_jitter:
        # mocap values are those of a time jittered around the row stamp
        jt = tr + rng.uniform(-mocap_jitter, mocap_jitter, n)
        for j in range(3):
            pos[:, j] = np.interp(jt, tr, Sr[:, j]) + rng.normal(0, 0.001, n)
            att[:, j] = np.interp(jt, tr, np.unwrap(Sr[:, 3 + j])) + rng.normal(0, 0.002, n)
    att[:, 2] = (att[:, 2] + np.pi) % (2 * np.pi) - np.pi
    for j, c in enumerate("xyz"):
        cols[c] = np.where(mask, pos[:, j], np.nan)
    for j, c in enumerate(["phi", "theta", "psi"]):
        cols[c] = np.where(mask, att[:, j], np.nan)
    bias = np.array([0.004, -0.003, 0.002])
    gy = Sr[:, 9:12] + bias + rng.normal(0, 0.005, (n, 3))
    for j, c in enumerate("pqr"):
        cols[c] = gy[:, j]
    return cols


def write_csv(path, cols, order=None):
    order = order or list(cols)
    n = len(cols["t"])
    with open(path, "w") as f:
        f.write(",".join(order) + "\n")
        for k in range(n):
            row = []
            for c in order:
                v = cols[c][k]
                row.append("" if (isinstance(v, float) and np.isnan(v)) else ("%.6f" % v if c == "t" else "%.9g" % v))
            f.write(",".join(row) + "\n")


def write_unwrapped(path):
    """Same log with psi unwrapped (continuous heading) -> *_unwrapped.csv."""
    lines = open(path).read().splitlines()
    hdr = lines[0].split(","); ip = hdr.index("psi")
    rows = [l.split(",") for l in lines[1:]]
    idx = [k for k, r in enumerate(rows) if r[ip] != ""]
    v = np.unwrap(np.array([float(rows[k][ip]) for k in idx]))
    for k, x in zip(idx, v):
        rows[k][ip] = "%.9g" % x
    open(path.replace(".csv", "_unwrapped.csv"), "w").write("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")


def base_params():
    return {"K_T": K_T, "b": B, "Kd": KD.copy(), "J_r": J_R}


CASES = {
    # name: (params update, est seed, val seed, extras)
    "A": ({}, 101, 202, {}),
    "B": ({"k_rd": 4.5e-5}, 303, 404, {}),
    "C": ({"c_in": 0.04}, 505, 606, {}),
    "D": ({}, 101, 202, {"w_delay_rows": 5}),      # rotor speeds logged 10 ms late (same flights as A)
}


def airframe_toml(path, name):
    with open(path, "w") as f:
        f.write(f"""[airframe]
name = "{name}"
mass = 0.6
inertia = [1.5e-3, 1.5e-3, 2.8e-3]
arm_length = 0.11
layout = "x"
rotor_inertia = 6.0e-6
gravity = 9.81

[parameters]
K_T = 4.5e-7
b = 1.1e-8
Kd = [0.1, 0.1, 0.1]
""")


def openloop(upath, opath, krd=0.0):
    d = np.genfromtxt(upath, delimiter=",", names=True)
    t = d["t"]; U = np.column_stack([d[f"w{i}"] for i in range(1, 5)])
    P = base_params(); P["k_rd"] = krd
    s = np.zeros(12)
    out = [s.copy()]
    for k in range(len(t) - 1):
        dt = t[k + 1] - t[k]
        nsub = int(np.ceil(dt / 2.5e-4 - 1e-9))
        for _ in range(nsub):
            s = rk4(lambda ss: dyn(ss, U[k], P), s, dt / nsub)
        out.append(s.copy())
    out = np.array(out)
    np.savetxt(opath, np.column_stack([t, out]), delimiter=",",
               header="t,x,y,z,phi,theta,psi,vx,vy,vz,p,q,r", comments="")


def main():
    os.makedirs(OUT, exist_ok=True)
    manifest = {"truth": {"mass": M, "inertia": J.tolist(), "arm": L, "layout": "x", "K_T": K_T, "b": B,
                          "Kd": KD.tolist(), "J_r": J_R, "tau_motor": TAU_M, "gyro_bias": [0.004, -0.003, 0.002],
                          "erpm_resolution_rad_s": W_Q, "w_noise": 3.0, "pos_noise": 0.001, "att_noise": 0.002,
                          "gyro_noise": 0.005},
                "cases": {}}
    airframe_toml(os.path.join(OUT, "racer.toml"), "racer5")
    cache = {}
    for case, (upd, se, sv, extra) in CASES.items():
        P = base_params(); P.update(upd)
        info = {"params": {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in upd.items()},
                "seeds": {}, "extra": extra}
        for tag, seed, T in (("est", se, 50.0), ("val", sv, 35.0)):
            key = (tuple(sorted((k, str(v)) for k, v in upd.items())), seed, T)
            if key not in cache:
                cache[key] = fly(seed, T, P)
            t, S, W, WC, pr = cache[key]
            cols = sense(seed, t, S, W, **extra)
            path = os.path.join(OUT, f"{case}_{tag}.csv")
            write_csv(path, cols, ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r"])
            write_unwrapped(path)
            sp = np.linalg.norm(S[:, 6:9], axis=1)
            tilt = np.degrees(np.arccos(np.cos(S[:, 3]) * np.cos(S[:, 4])))
            info["seeds"][tag] = {"seed": seed, "sense_seed": seed + 1000, "duration": T,
                                  "max_speed": float(sp.max()), "max_tilt_deg": float(tilt.max()),
                                  "max_vz": float(np.abs(S[:, 8]).max()), "max_r": float(np.abs(S[:, 11]).max()),
                                  "w_range": [float(W.min()), float(W.max())],
                                  "track_rms_m": float(np.sqrt(((S[:, 0:3] - pr) ** 2).sum(1).mean()))}
            # truth states for reference
            np.save(os.path.join(OUT, f"{case}_{tag}_truth.npy"), np.column_stack([t, S, W]))
            print(case, tag, info["seeds"][tag], flush=True)
        manifest["cases"][case] = info
    with open(os.path.join(OUT, "truth.json"), "w") as f:
        json.dump(manifest, f, indent=1)
    write_bad_inputs()


def write_bad_inputs():
    """User mistakes derived from A_est_unwrapped.csv."""
    src = os.path.join(OUT, "A_est_unwrapped.csv")
    lines = open(src).read().splitlines(); hdr = lines[0].split(",")
    rows = [l.split(",") for l in lines[1:]]
    def conv(name, cols, f):
        ii = [hdr.index(c) for c in cols]
        out = [lines[0]]
        for r in rows:
            r = list(r)
            for i in ii:
                if r[i] != "":
                    r[i] = "%.9g" % f(float(r[i]))
            out.append(",".join(r))
        open(os.path.join(OUT, name), "w").write("\n".join(out) + "\n")
    conv("bad_erpm.csv", ["w1", "w2", "w3", "w4"], lambda w: w * 60 / (2 * np.pi) * POLE_PAIRS)        # eRPM
    conv("bad_erpm100.csv", ["w1", "w2", "w3", "w4"], lambda w: w * 60 / (2 * np.pi) * POLE_PAIRS / 100)  # raw DShot eRPM/100
    conv("bad_deg.csv", ["phi", "theta", "psi"], np.degrees)
    conv("bad_gyro_deg.csv", ["p", "q", "r"], np.degrees)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--openloop":
        openloop(sys.argv[2], sys.argv[3], float(sys.argv[4]) if len(sys.argv) > 4 else 0.0)
    elif len(sys.argv) > 1 and sys.argv[1] == "--one":
        P = base_params()
        t, S, W, WC, pr = fly(101, 20.0, P)
        sp = np.linalg.norm(S[:, 6:9], axis=1)
        tilt = np.degrees(np.arccos(np.cos(S[:, 3]) * np.cos(S[:, 4])))
        print("speed", sp.max(), "tilt", tilt.max(), "W", W.min(), W.max(), "track", np.abs(S[:, :3] - pr).max())
    else:
        main()

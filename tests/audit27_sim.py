#!/usr/bin/env python3
"""Vendored as written by blind audit 27 (a helper session that read only the README, the
contract and docs/VALIDATION.md), for tests/test_audit27_sim.py; only this paragraph added.

Independent simulator for the audit (numpy only): an agricultural sprayer quadrotor ("x"
layout, 4 kg take-off) flying spray lanes at 2-4 m height, with or without its tank
emptying during the flight.  Also an X8 coaxial octocopter (rotor tables, lower rotors less
efficient).  Quaternion rigid body, fixed-step RK4 at 1 ms, first-order motors (30 ms) whose
*actual* speeds are logged (ESC telemetry), cascaded PD/PI controller at 200 Hz with torque
excitation, sensors: attitude+gyro+accel at 200 Hz, position at 50 Hz.

usage: python sim.py OUTDIR            # writes every case (deterministic, fixed seeds)
       python sim.py OUTDIR --check    # also the open-loop comparison inputs (U.csv)
Conventions follow CONTRACT.md: NED world, FRD body, R = Rz Ry Rx (ZYX), thrust -z body,
reaction torque spin_i*b*w_i^2 about +z body, gyroscopic J_r*Omega_r*(omega x e_z).
"""
import os
import sys
import json
import numpy as np

G = 9.81


# ---------------------------------------------------------------- rotations
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
    th = -np.arcsin(np.clip(R[2, 0], -1, 1))
    phi = np.arctan2(R[2, 1], R[2, 2])
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, th, psi


def quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


# ---------------------------------------------------------------- vehicles
def sprayer(tank_empties):
    a = 0.35 / np.sqrt(2)
    pos = np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]])  # contract "x"
    spin = np.array([1, 1, -1, -1])
    v = dict(name="sprayer", pos=pos, spin=spin, eff=np.ones(4), teff=np.ones(4),
             K_T=6.0e-5, b=1.0e-6, Kd=np.array([0.35, 0.35, 0.50]), J_r=1.5e-4,
             m_dry=3.2, m_liq0=0.8, mdot=0.015 if tank_empties else 0.0,
             J_dry=np.array([0.085, 0.085, 0.150]), J_liq_per_kg=np.array([0.007, 0.007, 0.008]),
             tau_m=0.03, arm=0.35, layout="x")
    return v


def x8(lower_eff):
    a = 0.45 / np.sqrt(2)
    xy = np.array([[a, a], [-a, -a], [a, -a], [-a, a]])
    pos, spin, eff = [], [], []
    # rotors 1-4 upper (spin as the x layout), 5-8 lower at the same arm, opposite spin
    sp4 = [1, 1, -1, -1]
    for k in range(4):
        pos.append([xy[k, 0], xy[k, 1], 0.0]); spin.append(sp4[k]); eff.append(1.0)
    for k in range(4):
        pos.append([xy[k, 0], xy[k, 1], 0.0]); spin.append(-sp4[k]); eff.append(lower_eff)
    v = dict(name="x8", pos=np.array(pos), spin=np.array(spin), eff=np.array(eff),
             teff=np.array(eff), K_T=4.0e-5, b=7.0e-7, Kd=np.array([0.4, 0.4, 0.6]),
             J_r=1.0e-4, m_dry=5.0, m_liq0=0.0, mdot=0.0,
             J_dry=np.array([0.20, 0.20, 0.36]), J_liq_per_kg=np.zeros(3),
             tau_m=0.03, arm=0.45, layout=None)
    return v


def mass_inertia(v, t):
    liq = max(v["m_liq0"] - v["mdot"] * t, 0.0)
    return v["m_dry"] + liq, v["J_dry"] + liq * v["J_liq_per_kg"]


# ---------------------------------------------------------------- dynamics
def deriv(v, t, s, wcmd):
    """s = [p(3), v(3), q(4), omega(3), w(N)]"""
    n = len(v["spin"])
    vel = s[3:6]
    q = s[6:10]
    om = s[10:13]
    w = s[13:13 + n] if v["tau_m"] > 0 else np.asarray(wcmd, float)
    m, J = mass_inertia(v, t)
    R = quat_to_R(q / np.linalg.norm(q))
    T = v["K_T"] * v["eff"] * w ** 2
    F_b = np.array([0.0, 0.0, -T.sum()])
    vair = vel - v.get("wind", np.zeros(3))
    acc = G * np.array([0, 0, 1.0]) + (R @ F_b - v["Kd"] * vair) / m
    tau = np.zeros(3)
    for i in range(n):
        tau += np.cross(v["pos"][i], np.array([0, 0, -T[i]]))
    tau[2] += np.sum(v["spin"] * v["b"] * v["teff"] * w ** 2)
    Om = np.sum(v["spin"] * w)
    tau += v["J_r"] * Om * np.cross(om, [0, 0, 1.0])
    Jm = np.diag(J)
    omd = np.linalg.solve(Jm, tau - np.cross(om, Jm @ om))
    qd = 0.5 * quat_mul(q, np.array([0.0, *om]))
    if v["tau_m"] > 0:
        wd = (wcmd - w) / v["tau_m"]
    else:
        wd = np.zeros(n)
    return np.concatenate([vel, acc, qd, omd, wd]), acc


def rk4(v, t, s, wcmd, h):
    k1, a1 = deriv(v, t, s, wcmd)
    k2, _ = deriv(v, t + h / 2, s + h / 2 * k1, wcmd)
    k3, _ = deriv(v, t + h / 2, s + h / 2 * k2, wcmd)
    k4, _ = deriv(v, t + h, s + h * k3, wcmd)
    s2 = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    s2[6:10] /= np.linalg.norm(s2[6:10])
    return s2


# ---------------------------------------------------------------- reference (spray lanes)
def smoothstep(u):
    u = np.clip(u, 0, 1)
    return u * u * u * (10 - 15 * u + 6 * u * u), (30 * u * u - 60 * u ** 3 + 30 * u ** 4)


def make_reference(rng, duration, speed=(2.8, 3.8)):
    """Waypoints: lanes north/south ~20-26 m, shifted east 3 m, altitude 2-4 m, yaw flips
    by 180 deg at lane ends (sprayers keep the nozzles' side), short hovers."""
    segs = []  # (t0, dur, p0, p1, psi0, psi1)
    t = 0.0
    p = np.array([0.0, 0.0, -3.0])
    psi = 0.0
    segs.append((t, 2.0, p.copy(), p.copy(), psi, psi)); t += 2.0
    north = True
    while t < duration:
        L = rng.uniform(18, 26)
        dz = rng.uniform(-1.0, 1.0)
        p1 = p + np.array([L if north else -L, 0, 0])
        p1[2] = np.clip(p[2] + dz, -4.0, -2.0)
        dur = L / rng.uniform(*speed) * 1.0
        segs.append((t, dur, p.copy(), p1.copy(), psi, psi)); t += dur; p = p1
        # hover + turn + lateral shift
        p1 = p + np.array([0, rng.uniform(2.5, 3.5), 0])
        psi1 = psi + (np.pi if rng.uniform() < 0.7 else np.pi / 2) * rng.choice([-1, 1])
        segs.append((t, 3.0, p.copy(), p1.copy(), psi, psi1)); t += 3.0; p = p1; psi = psi1
        north = not north

    def ref(tt):
        for (t0, d, p0, p1, s0, s1) in segs:
            if t0 <= tt < t0 + d:
                u = (tt - t0) / d
                sgm, dsg = smoothstep(u)
                return p0 + (p1 - p0) * sgm, (p1 - p0) * dsg / d, s0 + (s1 - s0) * sgm
        t0, d, p0, p1, s0, s1 = segs[-1]
        return p1, np.zeros(3), s1
    return ref


# ---------------------------------------------------------------- controller
class Controller:
    def __init__(self, v, rng):
        self.v = v
        n = len(v["spin"])
        # controller's internal model: bench values, slightly off
        self.K_T = v["K_T"] * 1.05
        self.b = v["b"] * 0.93
        self.m = v["m_dry"] + v["m_liq0"]
        self.J = v["J_dry"] + v["m_liq0"] * v["J_liq_per_kg"]
        M = np.zeros((4, n))
        for i in range(n):
            M[0, i] = self.K_T
            M[1, i] = -v["pos"][i][1] * self.K_T
            M[2, i] = v["pos"][i][0] * self.K_T
            M[3, i] = v["spin"][i] * self.b
        self.Minv = np.linalg.pinv(M)
        self.iz = 0.0
        self.ixy = np.zeros(2)
        # torque excitation: multisine per axis
        self.exc_f = rng.uniform(0.3, 4.0, size=(3, 5))
        self.exc_ph = rng.uniform(0, 2 * np.pi, size=(3, 5))
        self.exc_amp = np.array([0.25, 0.25, 0.35])  # rad/s^2 -> times J
        self.wmax = 2.2 * np.sqrt(self.m * G / (n * self.K_T))

    def __call__(self, t, p, vel, eul, om, ref, h):
        pr, vr, psir = ref
        phi, th, psi = eul
        e = pr - p
        ev = vr - vel
        self.ixy += h * e[:2]
        self.iz += h * e[2]
        a = np.zeros(3)
        a[:2] = 1.2 * e[:2] + 1.8 * ev[:2] + 0.15 * self.ixy
        a[2] = 3.0 * e[2] + 3.0 * ev[2] + 0.8 * self.iz
        c, s = np.cos(psi), np.sin(psi)
        axh = c * a[0] + s * a[1]
        ayh = -s * a[0] + c * a[1]
        th_d = np.clip(-axh / G, -0.35, 0.35)
        ph_d = np.clip(ayh / G, -0.35, 0.35)
        T = self.m * (G - a[2]) / (np.cos(phi) * np.cos(th))
        exc = self.exc_amp[:, None] * np.sin(2 * np.pi * self.exc_f * t + self.exc_ph)
        exc = exc.sum(axis=1) / np.sqrt(5)
        wa = np.array([36.0, 36.0, 9.0])
        za = np.array([12.0, 12.0, 6.0])
        err = np.array([ph_d - phi, th_d - th, wrap(psir - psi)])
        # rate targets from Euler error (small angles)
        alpha = wa * err - za * om + exc
        tau = self.J * alpha
        u = np.array([T, *tau])
        w2 = self.Minv @ u
        w2 = np.clip(w2, (0.15 * self.wmax) ** 2, self.wmax ** 2)
        return np.sqrt(w2)


# ---------------------------------------------------------------- flight
def fly(v, seed, duration=40.0, rate=200, pos_rate=50, h=1e-3, noise=None, log_every=1,
        speed=(2.8, 3.8)):
    rng = np.random.default_rng(seed)
    noise = noise or dict(pos=0.005, att=0.002, gyro=0.01, acc=0.05, w=0.5)
    n = len(v["spin"])
    ref = make_reference(rng, duration, speed)
    ctl = Controller(v, rng)
    m0, _ = mass_inertia(v, 0)
    w_h = np.sqrt(m0 * G / (n * v["K_T"] * v["eff"].mean()))
    s = np.zeros(13 + n)
    s[2] = -3.0
    s[6:10] = [1, 0, 0, 0]
    s[13:] = w_h
    sub = int(round(1.0 / rate / h))
    nrow = int(round(duration * rate))
    rows = []
    wcmd = np.full(n, w_h)
    for k in range(nrow):
        t = k / rate
        p, vel = s[0:3], s[3:6]
        R = quat_to_R(s[6:10])
        eul = R_to_euler(R)
        om = s[10:13]
        w_act = s[13:13 + n].copy()
        _, acc = deriv(v, t, s, wcmd)
        spf = R.T @ (acc - G * np.array([0, 0, 1.0]))
        # controller acts on noisy-ish measurement; use truth + small noise
        wcmd = ctl(t, p + rng.normal(0, 0.003, 3), vel, eul, om, ref(t), 1.0 / rate)
        rows.append(dict(t=t, p=p.copy(), eul=eul, om=om.copy(), w=w_act, spf=spf,
                         ref=ref(t), m=mass_inertia(v, t)[0]))
        for j in range(sub):
            s = rk4(v, t + j * h, s, wcmd, h)
    # sensors
    out = []
    rows = rows[::log_every]
    rate = rate // log_every
    for k, r in enumerate(rows):
        d = dict(t=r["t"])
        for i in range(n):
            d[f"w{i+1}"] = r["w"][i] + rng.normal(0, noise["w"])
        if k % (rate // pos_rate) == 0:
            pp = r["p"] + rng.normal(0, noise["pos"], 3)
            d.update(x=pp[0], y=pp[1], z=pp[2])
        else:
            d.update(x=np.nan, y=np.nan, z=np.nan)
        e = np.array(r["eul"]) + rng.normal(0, noise["att"], 3)
        d.update(phi=e[0], theta=e[1], psi=wrap(e[2]))
        g = r["om"] + rng.normal(0, noise["gyro"], 3)
        d.update(p=g[0], q=g[1], r=g[2])
        a = r["spf"] + rng.normal(0, noise["acc"], 3)
        d.update(ax=a[0], ay=a[1], az=a[2])
        d["mass_true"] = r["m"]
        out.append(d)
    return out


def write_csv(path, out, extra=True):
    n = len([k for k in out[0] if k.startswith("w") and k[1:].isdigit()])
    cols = ["t"] + [f"w{i+1}" for i in range(n)] + ["x", "y", "z", "phi", "theta", "psi",
                                                   "p", "q", "r", "ax", "ay", "az"]
    if extra:
        cols += ["mass_true"]
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for d in out:
            f.write(",".join("" if (isinstance(d[c], float) and np.isnan(d[c])) else
                             f"{d[c]:.9g}" for c in cols) + "\n")


def write_airframe(path, v, guess=(0.7, 1.3), mass=None):
    m0, J0 = mass_inertia(v, 0)
    mass = m0 if mass is None else mass
    L = [f'[airframe]', f'name = "{v["name"]}"', f'mass = {mass}',
         f'inertia = [{J0[0]:.6g}, {J0[1]:.6g}, {J0[2]:.6g}]', f'arm_length = {v["arm"]}',
         f'rotor_inertia = {v["J_r"]}', 'gravity = 9.81']
    if v["layout"]:
        L.append(f'layout = "{v["layout"]}"')
    else:
        for i in range(len(v["spin"])):
            pz = v["pos"][i]
            L += ['', '[[rotor]]', f'position = [{pz[0]:.6f}, {pz[1]:.6f}, {pz[2]:.6f}]',
                  f'spin = {int(v["spin"][i])}']
    L += ['', '[parameters]', f'K_T = {v["K_T"]*guess[0]:.6g}', f'b = {v["b"]*guess[1]:.6g}',
          'Kd = [0.2, 0.2, 0.2]', '']
    with open(path, "w") as f:
        f.write("\n".join(L))


def open_loop_check(outdir):
    """Open-loop flight (no motor lag, ZOH inputs) for comparison with `greybox simulate`."""
    v = sprayer(False)
    v["tau_m"] = 0.0
    n = 4
    rate, h, dur = 200, 1e-3, 3.0
    w_h = np.sqrt(4.0 * G / (4 * v["K_T"]))
    t = np.arange(int(dur * rate)) / rate
    W = np.tile(w_h, (len(t), 4))
    W[:, 0] += 8 * np.sin(2 * np.pi * 1.0 * t)          # rotor 1 (front right)
    W[:, 2] += 5 * np.sin(2 * np.pi * 0.7 * t)          # rotor 3 (front left)
    W[:, 1] += 3 * (t > 1.0)                            # rotor 2
    W += 4.0                                            # climb a little
    s = np.zeros(13 + n); s[6] = 1.0; s[13:] = w_h
    out = []
    for k in range(len(t)):
        R = quat_to_R(s[6:10])
        out.append([t[k], *s[0:3], *R_to_euler(R), *s[10:13]])
        for j in range(5):
            s = rk4(v, t[k] + j * h, s, W[k], h)
    with open(os.path.join(outdir, "U.csv"), "w") as f:
        f.write("t,w1,w2,w3,w4\n")
        for k in range(len(t)):
            f.write(",".join(f"{x:.10g}" for x in [t[k], *W[k]]) + "\n")
    with open(os.path.join(outdir, "Y_mine.csv"), "w") as f:
        f.write("t,x,y,z,phi,theta,psi,p,q,r\n")
        for r in out:
            f.write(",".join(f"{x:.10g}" for x in r) + "\n")
    write_airframe(os.path.join(outdir, "sprayer_truth.toml"), v, guess=(1, 1))
    with open(os.path.join(outdir, "sprayer_truth.toml"), "a") as f:
        pass


def main():
    outdir = sys.argv[1]
    os.makedirs(outdir, exist_ok=True)
    if "--check" in sys.argv:
        open_loop_check(outdir)
        return
    cases = sys.argv[2:] or ["control", "tank"]
    truth = {}
    for case in cases:
        if case == "control":
            v = sprayer(False)
        elif case == "tank":
            v = sprayer(True)
        elif case == "wind":
            v = sprayer(False); v["wind"] = np.array([2.0, -1.2, 0.0])
        elif case == "tankwind":
            v = sprayer(True); v["wind"] = np.array([2.0, -1.2, 0.0])
        elif case == "control50hz":
            v = sprayer(False)
        elif case == "tank50hz":
            v = sprayer(True)
        elif case == "x8":
            v = x8(0.8)
        elif case == "x8control":
            v = x8(1.0)
        else:
            raise SystemExit("unknown case " + case)
        kw = {}
        if case.endswith("50hz"):   # long slow flights logged at 50 Hz, positions at 25 Hz
            kw = dict(log_every=4, pos_rate=25, speed=(1.5, 2.2),
                      noise=dict(pos=0.01, att=0.002, gyro=0.01, acc=0.05, w=0.5))
        for tag, seed, dur in (("est", 11, 80.0), ("val", 22, 40.0)):
            if not kw:
                dur = 40.0
            out = fly(v, seed, duration=dur, **kw)
            write_csv(os.path.join(outdir, f"{case}_{tag}.csv"), out)
        write_airframe(os.path.join(outdir, f"{case}.toml"), v)
        truth[case] = dict(K_T=v["K_T"], b=v["b"], Kd=v["Kd"].tolist(), J_r=v["J_r"],
                           mass0=v["m_dry"] + v["m_liq0"], mdot=v["mdot"],
                           eff=v["eff"].tolist(), wind=v.get("wind", np.zeros(3)).tolist(), tau_m_actual_speeds_logged=v["tau_m"])
        print(case, "done", flush=True)
    with open(os.path.join(outdir, "truth_" + "_".join(cases) + ".json"), "w") as f:
        json.dump(truth, f, indent=1)


if __name__ == "__main__":
    main()

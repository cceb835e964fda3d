#!/usr/bin/env python3
"""Independent Crazyflie-scale quadrotor simulator for the blind audit of greybox.

(The twenty-ninth blind audit's, 2026-12-06, kept as it wrote it but for ``main(which, out)``
writing where it is told; ``tests/test_audit29_sim.py`` runs its cases.)

numpy + scipy only; never imports greybox.  Deterministic: `python sim.py` regenerates
every file under data/.  Conventions from CONTRACT.md: NED world, FRD body, ZYX Euler,
layout "x": rotor1 FR (+a,+a), 2 BL (-a,-a), 3 FL (+a,-a), 4 BR (-a,+a), spin [+1,+1,-1,-1],
thrust K_T w^2 along body -z, reaction torque spin_i*b*w_i^2 about body +z.

Dynamics: quaternion attitude, world velocity, body rates, 4 motor-speed states
(first-order lag), fixed-step RK4 at 0.5 ms; Crazyflie-style cascaded controller at 500 Hz
(position PID -> attitude P -> rate PI), mixer built from slightly wrong constants.
"""
import json, os, sys
import numpy as np

G = 9.81
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")

BASE = dict(
    mass=0.032, J=[1.4e-5, 1.4e-5, 2.2e-5], arm=0.046,
    K_T=2.0e-8, b=1.0e-10, Kd=[0.010, 0.010, 0.012], J_r=0.0,
    tau_motor=0.015,          # actual motor lag (logged speeds are the actual ones unless log_cmd)
    log_cmd=False,            # log commanded speeds instead of actual ones
    r_cog=[0.0, 0.0],         # CoG offset from rotor centre (body x,y), m
    K_vbat=0.0,               # w_act = w_cmd*(1+K_vbat*(vbat-4))
    k_rdh=0.0, k_rdv=0.0, h_hub=0.0,   # hub rotor drag
    spin_scale=[1.0, 1.0, 1.0, 1.0],   # per-rotor thrust AND torque scale
    c_climb=0.0,              # (G) thrust scale T*(1 - c_climb*vz_body) ... unused by default
    rotor_accel_torque=False, # (G) yaw torque J_r*sum(spin*dw/dt)
)

A_ = BASE["arm"] / np.sqrt(2)
POS = np.array([[A_, A_, 0], [-A_, -A_, 0], [A_, -A_, 0], [-A_, A_, 0]])
SPIN = np.array([1.0, 1.0, -1.0, -1.0])


def quat_mul(a, b):
    w1, x1, y1, z1 = a; w2, x2, y2, z2 = b
    return np.array([w1*w2 - x1*x2 - y1*y2 - z1*z2, w1*x2 + x1*w2 + y1*z2 - z1*y2,
                     w1*y2 - x1*z2 + y1*w2 + z1*x2, w1*z2 + x1*y2 - y1*x2 + z1*w2])


def quat_to_R(q):
    w, x, y, z = q
    return np.array([[1-2*(y*y+z*z), 2*(x*y-w*z), 2*(x*z+w*y)],
                     [2*(x*y+w*z), 1-2*(x*x+z*z), 2*(y*z-w*x)],
                     [2*(x*z-w*y), 2*(y*z+w*x), 1-2*(x*x+y*y)]])


def euler_to_quat(phi, th, psi):
    cr, sr = np.cos(phi/2), np.sin(phi/2); cp, sp = np.cos(th/2), np.sin(th/2)
    cy, sy = np.cos(psi/2), np.sin(psi/2)
    return np.array([cr*cp*cy + sr*sp*sy, sr*cp*cy - cr*sp*sy, cr*sp*cy + sr*cp*sy, cr*cp*sy - sr*sp*cy])


def R_to_euler(R):
    th = -np.arcsin(np.clip(R[2, 0], -1, 1))
    phi = np.arctan2(R[2, 1], R[2, 2]); psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, th, psi


class Plant:
    def __init__(self, P):
        self.P = P
        self.m = P["mass"]; self.J = np.diag(P["J"]); self.Jinv = np.linalg.inv(self.J)
        self.pos = POS.copy(); self.rc = np.array([P["r_cog"][0], P["r_cog"][1], 0.0])
        self.arms = self.pos - self.rc          # moment arms about the true CoG
        self.hubs = self.arms + np.array([0, 0, -P["h_hub"]])
        self.sc = np.array(P["spin_scale"])
        self.Kd = np.array(P["Kd"])

    def deriv(self, s, wtarget):
        """s = [p(3) v(3) q(4) om(3) w(4)]; wtarget: speeds the motors are driven to."""
        P = self.P
        v = s[3:6]; q = s[6:10]; om = s[10:13]; w = s[13:17]
        R = quat_to_R(q)
        if P.get("direct"):
            w = wtarget; wdot = np.zeros(4)
        else:
            wdot = (wtarget - w) / P["tau_motor"]
        T = P["K_T"] * self.sc * w**2
        vb = R.T @ v
        if P["c_climb"]:
            T = T * (1.0 + P["c_climb"] * vb[2])      # descending (vb_z>0) raises thrust
        F_b = np.zeros(3); F_b[2] = -T.sum()
        tau = np.zeros(3)
        for i in range(4):
            tau += np.cross(self.arms[i], np.array([0, 0, -T[i]]))
        tau[2] += np.sum(SPIN * P["b"] * self.sc * w**2)
        if P["k_rdh"] or P["k_rdv"]:
            for i in range(4):
                vi = vb + np.cross(om, self.hubs[i])
                Fi = -w[i] * np.array([P["k_rdh"]*vi[0], P["k_rdh"]*vi[1], P["k_rdv"]*vi[2]])
                F_b += Fi; tau += np.cross(self.hubs[i], Fi)
        if P["J_r"]:
            Om = np.sum(SPIN * w)
            tau += P["J_r"] * Om * np.cross(om, np.array([0, 0, 1.0]))
            if P["rotor_accel_torque"]:
                tau[2] += P["J_r"] * np.sum(SPIN * wdot)
        F_w = R @ F_b - self.Kd * v + np.array([0, 0, self.m * G])
        a = F_w / self.m
        omq = np.array([0.0, *om])
        qdot = 0.5 * quat_mul(q, omq)
        omdot = self.Jinv @ (tau - np.cross(om, self.J @ om))
        return np.concatenate([v, a, qdot, omdot, wdot]), a, R

    def step(self, s, wt, dt):
        k1 = self.deriv(s, wt)[0]; k2 = self.deriv(s + dt/2*k1, wt)[0]
        k3 = self.deriv(s + dt/2*k2, wt)[0]; k4 = self.deriv(s + dt*k3, wt)[0]
        s = s + dt/6*(k1 + 2*k2 + 2*k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
        return s


class Controller:
    """Crazyflie-like cascade at 500 Hz with a mixer built from wrong-ish constants."""
    def __init__(self, P):
        self.m = 0.031; self.J = np.array([1.5e-5, 1.5e-5, 2.4e-5])
        KT = P["K_T"] * 1.06; b = P["b"] * 0.9; a = P["arm"] / np.sqrt(2) * 1.03
        M = np.vstack([np.ones(4) * KT, -POS[:, 1] / A_ * a * KT, POS[:, 0] / A_ * a * KT, SPIN * b])
        self.Minv = np.linalg.inv(M); self.KT = KT
        self.ipos = np.zeros(3); self.irate = np.zeros(3)

    def __call__(self, t, pos, vel, eul, om, ref, dt):
        pr, vr, ar, psir = ref
        e = pr - pos; ev = vr - vel
        self.ipos = np.clip(self.ipos + e*dt, -0.5, 0.5)
        kp = np.array([6.0, 6.0, 8.0]); kv = np.array([4.0, 4.0, 5.0]); ki = np.array([1.0, 1.0, 3.0])
        acc = ar + kp*e + kv*ev + ki*self.ipos
        f = self.m * (acc - np.array([0, 0, G]))
        T = np.linalg.norm(f)
        c, s_ = np.cos(eul[2]), np.sin(eul[2])
        fh = np.array([c*f[0] + s_*f[1], -s_*f[0] + c*f[1], f[2]])
        phi_d = np.arcsin(np.clip(fh[1]/T, -0.45, 0.45))
        th_d = np.clip(np.arctan2(-fh[0], -fh[2]), -0.45, 0.45)
        epsi = (psir - eul[2] + np.pi) % (2*np.pi) - np.pi
        rate_d = np.array([7.0*(phi_d - eul[0]), 7.0*(th_d - eul[1]), 4.0*epsi])
        er = rate_d - om
        self.irate = np.clip(self.irate + er*dt, -8.0, 8.0)
        kr = np.array([22.0, 22.0, 12.0]); kir = np.array([15.0, 15.0, 5.0])
        tau = self.J * (kr*er + kir*self.irate)
        Tz = T * 1.0
        thr = self.Minv @ np.array([Tz, *tau])
        return np.sqrt(np.clip(thr, 0, None)).clip(0, 2900.0)


def smoothstep(t, t0, T):
    x = np.clip((t - t0)/T, 0, 1)
    return x*x*x*(10 - 15*x + 6*x*x)


def env(t, t0, t1, r=1.0):
    return smoothstep(t, t0, r) * (1 - smoothstep(t, t1 - r, r))


def ref_est(t):
    # figure-eight 2-14 s, steps 14-20 s, circle with yaw 20-30 s; hover start at z=-1
    w8 = 2*np.pi/7.0; e8 = env(t, 1.5, 14.0)
    x = 0.9*np.sin(w8*t)*e8; y = 0.45*np.sin(2*w8*t)*e8
    z = -1.0 - 0.3*smoothstep(t, 14.5, 0.6) + 0.5*smoothstep(t, 16.5, 0.6) - 0.2*smoothstep(t, 18.0, 0.6)
    x += 0.5*smoothstep(t, 15.0, 0.8) - 0.5*smoothstep(t, 17.5, 0.8)
    y += -0.4*smoothstep(t, 16.0, 0.8) + 0.4*smoothstep(t, 18.5, 0.8)
    wc = 1.4; ec = env(t, 20.0, 29.5)
    x += 0.7*(np.cos(wc*(t-20)) - 1)*ec; y += 0.7*np.sin(wc*(t-20))*ec
    psi = 0.7*np.sin(0.35*t) + 0.8*smoothstep(t, 12.0, 1.0) - 0.8*smoothstep(t, 24.0, 1.5)
    return np.array([x, y, z]), psi


def ref_val(t):
    # 20 s: circle the other way, a smaller faster figure eight, steps, yaw turns
    wc = 1.6; ec = env(t, 1.0, 8.0)
    x = 0.6*(1 - np.cos(wc*(t-1)))*ec; y = -0.6*np.sin(wc*(t-1))*ec
    w8 = 2*np.pi/5.0; e8 = env(t, 8.0, 16.0)
    x += 0.7*np.sin(w8*(t-8))*e8; y += 0.35*np.sin(2*w8*(t-8))*e8
    z = -1.0 + 0.3*np.sin(0.9*t)*env(t, 1.0, 19.0) - 0.25*smoothstep(t, 16.5, 0.5)
    y += 0.4*smoothstep(t, 16.5, 0.8) - 0.4*smoothstep(t, 18.5, 0.8)
    psi = -0.6*np.sin(0.5*t) + 1.0*smoothstep(t, 10.0, 1.2)
    return np.array([x, y, z]), psi


def refs(fn, t, h=1e-3):
    p, psi = fn(t); pp, _ = fn(t+h); pm, _ = fn(t-h)
    return p, (pp - pm)/(2*h), (pp - 2*p + pm)/h**2, psi


def vbat_true(t, wcmd, wh):
    load = np.mean((wcmd/wh)**2)
    return 4.12 - 0.014*t - 0.10*(load - 1.0)


def fly(P, reffn, T_end, seed, rate=200, dt=0.001, ctrl_dt=0.002):
    rng = np.random.default_rng(seed)
    pl = Plant(P); ct = Controller(P)
    wh = np.sqrt(P["mass"]*G/(4*P["K_T"]*np.mean(P["spin_scale"])))
    p0, psi0 = reffn(0.0)
    s = np.concatenate([p0, np.zeros(3), euler_to_quat(0, 0, psi0), np.zeros(3), np.full(4, wh)])
    n_sub = int(round(ctrl_dt/dt)); n_log = int(round(1.0/rate/dt))
    nsteps = int(round(T_end/dt))
    wcmd = np.full(4, wh); vb = 4.0; wt = wcmd.copy()
    rows = []
    for k in range(nsteps + 1):
        t = k*dt
        if k % n_sub == 0:
            R = quat_to_R(s[6:10]); eul = R_to_euler(R)
            gy = s[10:13] + rng.normal(0, 0.005, 3)
            wcmd = ct(t, s[0:3], s[3:6], eul, gy, refs(reffn, t), ctrl_dt)
            if P["K_vbat"]:
                vb = vbat_true(t, wcmd, wh)
                wt = wcmd*(1 + P["K_vbat"]*(vb - 4.0))
            else:
                wt = wcmd.copy()
        if k % n_log == 0:
            d, a, R = pl.deriv(s, wt)
            phi, th, psi = R_to_euler(R)
            sf = R.T @ (a - np.array([0, 0, G]))
            rows.append(dict(t=t, pos=s[0:3].copy(), eul=(phi, th, psi), om=s[10:13].copy(),
                             w=s[13:17].copy(), wcmd=wcmd.copy(), sf=sf, vb=vb))
        if k < nsteps:
            s = pl.step(s, wt, dt)
        if not np.all(np.isfinite(s)) or abs(s[2]) > 50:
            raise RuntimeError(f"diverged at t={t}")
    # sensors
    out = []
    for j, r in enumerate(rows):
        w = (r["wcmd"] if P["log_cmd"] else r["w"] + rng.normal(0, 2.0, 4))
        row = {"t": f"{r['t']:.4f}"}
        for i in range(4):
            row[f"w{i+1}"] = f"{w[i]:.3f}"
        vis = (j % 2 == 0) and rng.random() > 0.02
        for c, v in zip("xyz", r["pos"]):
            row[c] = f"{v + rng.normal(0, 0.0007):.5f}" if vis else ""
        for c, v in zip(("phi", "theta", "psi"), r["eul"]):
            vv = v + rng.normal(0, 0.002)
            if c == "psi":
                vv = (vv + np.pi) % (2*np.pi) - np.pi
            row[c] = f"{vv:.5f}" if vis else ""
        for c, v in zip("pqr", r["om"]):
            row[c] = f"{v + rng.normal(0, 0.01):.5f}"
        for c, v in zip(("ax", "ay", "az"), r["sf"]):
            row[c] = f"{v + rng.normal(0, 0.05):.4f}"
        if P["K_vbat"]:
            row["vbat"] = f"{r['vb'] + rng.normal(0, 0.004):.4f}"
        out.append(row)
    return out, rows


def write_csv(path, out):
    cols = list(out[0].keys())
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for r in out:
            f.write(",".join(r[c] for c in cols) + "\n")


def write_toml(path, P, guess=(1.3, 0.6, 0.5), name="cf21"):
    KT = P["K_T"]*guess[0]; b = P["b"]*guess[1]; Kd = [k*guess[2] for k in P["Kd"]]
    with open(path, "w") as f:
        f.write(f"""[airframe]
name = "{name}"
mass = {P['mass']}
inertia = [{P['J'][0]}, {P['J'][1]}, {P['J'][2]}]
arm_length = {P['arm']}
layout = "x"
rotor_inertia = {P['J_r']}
gravity = {G}

[parameters]
K_T = {KT:.6e}
b = {b:.6e}
Kd = [{Kd[0]:.6e}, {Kd[1]:.6e}, {Kd[2]:.6e}]
""")


CASES = {
    "A": {},
    "B": dict(r_cog=[0.0025, -0.0020]),
    "C": dict(tau_motor=0.040, log_cmd=True),
    "D": dict(K_vbat=0.20, tau_motor=0.003, log_cmd=True),
    "E": dict(k_rdh=2.0e-6, k_rdv=1.0e-6, h_hub=0.005),
    "F": dict(spin_scale=[0.95, 0.95, 1.0, 1.0]),
    "G": dict(J_r=3.0e-8, rotor_accel_torque=True),
    # N: NanoBench-like control: commanded speeds at 100 Hz rows, 25 ms motor lag, nothing else
    "N": dict(tau_motor=0.025, log_cmd=True, rate=100),
    # M: N plus the CoG offset of B (a combination, as a real Crazyflie would have)
    "M": dict(tau_motor=0.025, log_cmd=True, rate=100, r_cog=[0.0025, -0.0020]),
}
BASE["rate"] = 200


def truth_for(name, P):
    t = dict(mass=P["mass"], inertia=P["J"], arm=P["arm"], K_T=P["K_T"], b=P["b"], Kd=P["Kd"],
             J_r=P["J_r"], tau_motor_actual=P["tau_motor"], logged_speeds="commanded" if P["log_cmd"] else "actual (+N(0,2 rad/s))",
             airframe_guess_factors=dict(K_T=1.3, b=0.6, Kd=0.5))
    if name in ("B", "M"):
        t["r_cog"] = P["r_cog"]
    if name in ("C", "N", "M"):
        t["tau_m"] = P["tau_motor"]
    if name in ("N", "M"):
        t["log_rate_hz"] = 100
    if name == "D":
        t["K_vbat"] = P["K_vbat"]; t["note"] = "w_act = w_cmd*(1+K_vbat*(vbat-4)), then motor lag 3 ms; vbat logged with N(0,4 mV)"
    if name == "E":
        t.update(k_rdh=P["k_rdh"], k_rdv=P["k_rdv"], h_hub=P["h_hub"])
    if name == "F":
        sc = np.array(P["spin_scale"]); m = sc.mean()
        t["spin_scale"] = P["spin_scale"]
        t["motor_asymmetry_equiv"] = dict(K_T_dev=list(np.round(sc[:3]/m - 1, 6)), K_T_eff=P["K_T"]*m, b_eff=P["b"]*m)
    if name == "G":
        t["note"] = "rotor inertia J_r=3e-8 in airframe (gyroscopic ok) plus yaw torque J_r*sum(spin_i*dw_i/dt) from rotor accelerations (outside catalogue)"
    return t


def openloop_check(out_dir):
    """Open-loop run for comparison with `greybox simulate` (control-case physics, direct speeds)."""
    P = dict(BASE); P["direct"] = True
    pl = Plant(P); wh = np.sqrt(P["mass"]*G/(4*P["K_T"]))
    ts = np.arange(0, 3.0 + 1e-9, 0.005)
    W = np.full((len(ts), 4), wh)
    W[:, 0] += 40*np.sin(2*np.pi*0.7*ts); W[:, 1] += 25*np.sin(2*np.pi*1.1*ts + 1)
    W[:, 2] += 30*np.cos(2*np.pi*0.5*ts); W[:, 3] += 15*np.sin(2*np.pi*1.7*ts)
    W += 10
    with open(os.path.join(out_dir, "ol_inputs.csv"), "w") as f:
        f.write("t,w1,w2,w3,w4\n")
        for t, w in zip(ts, W):
            f.write(f"{t:.4f}," + ",".join(f"{x:.4f}" for x in w) + "\n")
    s = np.concatenate([np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), W[0]])
    res = []
    for k, t in enumerate(ts):
        R = quat_to_R(s[6:10]); res.append([t, *s[0:3], *R_to_euler(R), *s[10:13]])
        if k + 1 < len(ts):
            for _ in range(10):
                s = pl.step(s, W[k], 0.0005)
    np.savetxt(os.path.join(out_dir, "ol_mine.csv"), np.array(res), delimiter=",",
               header="t,x,y,z,phi,theta,psi,p,q,r", comments="")
    write_toml(os.path.join(out_dir, "ol_true.toml"), P, guess=(1, 1, 1))


def make_mistakes():
    """User mistakes derived from data/A_est.csv: units and frames wrong, one change each."""
    import csv, math
    d = os.path.join(OUT, "mistakes"); os.makedirs(d, exist_ok=True)
    rows = list(csv.DictReader(open(os.path.join(OUT, "A_est.csv")))); cols = list(rows[0].keys())
    def w(name, f):
        with open(os.path.join(d, name), "w") as fh:
            fh.write(",".join(cols) + "\n")
            for r in rows:
                r2 = dict(r); f(r2); fh.write(",".join(r2[k] for k in cols) + "\n")
    def scale(r, keys, k):
        for c in keys:
            if r[c] != "":
                r[c] = "%.6f" % (float(r[c])*k)
    def enu(r):
        r["x"], r["y"] = r["y"], r["x"]
        if r["z"] != "":
            r["z"] = "%.5f" % (-float(r["z"]))
    def order(r):
        r["w1"], r["w3"] = r["w3"], r["w1"]; r["w2"], r["w4"] = r["w4"], r["w2"]
    w("mm.csv", lambda r: scale(r, "xyz", 1000)); w("enu.csv", enu)
    w("rpm.csv", lambda r: scale(r, ["w1", "w2", "w3", "w4"], 60/(2*math.pi)))
    w("gyro_degs.csv", lambda r: scale(r, "pqr", 180/math.pi))
    w("psi_deg.csv", lambda r: scale(r, ["psi"], 180/math.pi))
    w("acc_g.csv", lambda r: scale(r, ["ax", "ay", "az"], 1/9.81)); w("rotor_order.csv", order)
    open(os.path.join(d, "grams.toml"), "w").write(open(os.path.join(OUT, "A.toml")).read().replace("mass = 0.032", "mass = 32.0"))


def main(which=None, out=None):
    """Write the cases ``which`` (default all; "mistakes" and "check" as the audit's command
    line) into ``out`` (default ``data/`` beside this file)."""
    global OUT
    if out is not None:
        OUT = out
    args = list(which) if which is not None else sys.argv[1:]
    if args[:1] == ["mistakes"]:
        make_mistakes(); return
    if args[:1] == ["check"]:
        os.makedirs(OUT, exist_ok=True); openloop_check(OUT); return
    os.makedirs(OUT, exist_ok=True)
    truth = {}
    sel = args or list(CASES)
    for ci, name in enumerate(CASES):
        if name not in sel:
            continue
        P = dict(BASE); P.update(CASES[name])
        for kind, fn, T, seed in (("est", ref_est, 30.0, 100 + ci), ("val", ref_val, 20.0, 200 + ci)):
            out_rows, rows = fly(P, fn, T, seed, rate=P.get('rate', 200))
            write_csv(os.path.join(OUT, f"{name}_{kind}.csv"), out_rows)
            w = np.array([r["w"] for r in rows]); pos = np.array([r["pos"] for r in rows])
            v = np.diff(pos, axis=0)*200
            print(name, kind, "w range", w.min().round(0), w.max().round(0), "max speed", np.linalg.norm(v, axis=1).max().round(2),
                  "max tilt", np.degrees(np.max(np.abs([r["eul"][:2] for r in rows]))).round(1), flush=True)
        write_toml(os.path.join(OUT, f"{name}.toml"), P)
        write_toml(os.path.join(OUT, f"{name}_true.toml"), P, guess=(1, 1, 1))
        truth[name] = truth_for(name, P)
    tp = os.path.join(OUT, "truth.json")
    old = json.load(open(tp)) if os.path.exists(tp) else {}
    old.update(truth)
    json.dump(old, open(tp, "w"), indent=1)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Independent quadrotor flight simulator for the audit31 blind audit of greybox.

(The thirty-first blind audit's, 2026-12-06, kept as it wrote it; ``tests/test_audit31_sim.py``
runs its cases through ``run_case(case, outdir)``.)

Written from the CONTRACT (/work/shared/CONTRACT.md) only.  Deterministic (seeded):
    python sim.py CASE OUTDIR
CASE in: control, slew, saturation, linthrust, posdelay, verify, all
writes OUTDIR/<case>_est.csv, OUTDIR/<case>_val.csv, OUTDIR/<case>.toml (airframe, guesses),
OUTDIR/<case>_truth.json.

Vehicle: 2.6 kg "x" quad, 12-inch props (R = 0.1524 m), arm 0.275 m.
Dynamics: quaternion RK4 at 1 ms, NED world / FRD body, rotor order and spins of the contract's
"x" layout, thrust K_T w^2 along body -z, reaction torque spin_i b w^2 about body +z,
gyroscopic torque J_r Omega_r (omega x e_z), Omega_r = sum(spin_i w_i), linear drag -Kd v per
world axis.  Motors: first-order lag on the command (+ optional slew limit / saturation).
Controller: 250 Hz cascade (position PID -> thrust vector -> attitude P -> rate P with
feed-forward), internal model 5-10 % off.  Sensors: motion capture position and attitude at
100 Hz (2 mm, 2 mrad), gyro at 200 Hz (4 mrad/s), rows at 200 Hz.
"""
import json
import math
import os
import sys

import numpy as np

G = 9.81
TRUTH = dict(
    mass=2.6,
    inertia=[0.035, 0.037, 0.063],
    arm=0.275,
    K_T=2.7e-5,           # N/(rad/s)^2 -> hover 486 rad/s
    b=4.0e-7,             # N m/(rad/s)^2  (b/K_T = 0.0148 m)
    Kd=[0.25, 0.25, 0.40],
    J_r=1.5e-4,
    w_max=1000.0,         # motor max speed: hover at 48.6 %
    tau_m=0.025,          # motor lag (actual speeds logged in cases where it is not the subject)
)
A = TRUTH["arm"] / math.sqrt(2.0)
POS = np.array([[A, A, 0.0], [-A, -A, 0.0], [A, -A, 0.0], [-A, A, 0.0]])   # contract "x"
SPIN = np.array([1.0, 1.0, -1.0, -1.0])

CASES = {
    # name: (log what, motor model, extra)
    "control": dict(log="actual", tau_m=0.025),
    "slew": dict(log="command", tau_m=0.040, slew=2500.0, katt=(6.0, 6.0, 3.5), krate=(11.0, 11.0, 7.0)),
    # the first slew flight: the normal gains against a slew-limited 40 ms motor; it diverged (fell)
    "slewcrash": dict(log="command", tau_m=0.040, slew=2500.0),
    "saturation": dict(log="command", tau_m=0.025, w_max_motor=1000.0, w_max_cmd=1400.0,
                       punch=True),
    "linthrust": dict(log="actual", tau_m=0.025, k1=1.4e-3),
    "posdelay": dict(log="actual", tau_m=0.025, pos_delay=0.040),
}


def quat_to_R(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler_from_R(R):
    phi = math.atan2(R[2, 1], R[2, 2])
    theta = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    psi = math.atan2(R[1, 0], R[0, 0])
    return phi, theta, psi


def euler_to_quat(phi, th, psi):
    cr, sr = math.cos(phi / 2), math.sin(phi / 2)
    cp, sp = math.cos(th / 2), math.sin(th / 2)
    cy, sy = math.cos(psi / 2), math.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


class Plant:
    def __init__(self, cfg, truth=TRUTH):
        self.m = truth["mass"]
        self.J = np.array(truth["inertia"])
        self.KT = truth["K_T"]
        self.b = truth["b"]
        self.Kd = np.array(truth["Kd"])
        self.Jr = truth["J_r"]
        self.k1 = cfg.get("k1", 0.0)
        self.tau = cfg.get("tau_m", 0.025)
        self.slew = cfg.get("slew", None)
        self.wmax = cfg.get("w_max_motor", None)
        self.motors = cfg.get("motors", True)

    def thrusts(self, w):
        return self.KT * w * w + self.k1 * w

    def deriv(self, s, wcmd):
        v = s[3:6]
        q = s[6:10]
        om = s[10:13]
        w = s[13:17]
        if not self.motors:
            w = wcmd
        R = quat_to_R(q)
        T = self.thrusts(w)
        F = R @ np.array([0.0, 0.0, -T.sum()]) + np.array([0.0, 0.0, self.m * G]) - self.Kd * v
        dv = F / self.m
        tau = np.zeros(3)
        tau[0] = np.sum(-POS[:, 1] * T)
        tau[1] = np.sum(POS[:, 0] * T)
        tau[2] = np.sum(SPIN * self.b * w * w)
        Om = np.sum(SPIN * w)
        tau += self.Jr * Om * np.array([om[1], -om[0], 0.0])
        tau -= np.cross(om, self.J * om)
        dom = tau / self.J
        qw, qx, qy, qz = q
        p, qq, r = om
        dq = 0.5 * np.array([-qx * p - qy * qq - qz * r,
                             qw * p + qy * r - qz * qq,
                             qw * qq + qz * p - qx * r,
                             qw * r + qx * qq - qy * p])
        if self.motors:
            target = wcmd if self.wmax is None else np.minimum(wcmd, self.wmax)
            dw = (target - w) / self.tau
            if self.slew is not None:
                dw = np.clip(dw, -self.slew, self.slew)
        else:
            dw = np.zeros(4)
        return np.concatenate([v, dv, dq, dom, dw])

    def step(self, s, wcmd, h):
        k1 = self.deriv(s, wcmd)
        k2 = self.deriv(s + 0.5 * h * k1, wcmd)
        k3 = self.deriv(s + 0.5 * h * k2, wcmd)
        k4 = self.deriv(s + h * k3, wcmd)
        s = s + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
        return s


class Controller:
    """250 Hz cascade; internal model deliberately off."""

    def __init__(self, cfg):
        self.m = TRUTH["mass"] * 1.06
        self.KT = TRUTH["K_T"] * 0.945
        self.b = TRUTH["b"] * 1.075
        self.J = np.array(TRUTH["inertia"]) * 0.92
        a = TRUTH["arm"] * 1.03 / math.sqrt(2.0)
        P = np.array([[a, a], [-a, -a], [a, -a], [-a, a]])
        M = np.vstack([np.ones(4) * self.KT, -P[:, 1] * self.KT, P[:, 0] * self.KT,
                       SPIN * self.b])
        self.Minv = np.linalg.inv(M)
        self.wmax_cmd = cfg.get("w_max_cmd", TRUTH["w_max"])
        self.punch = cfg.get("punch", False)
        self.Kp = np.array([1.8, 1.8, 3.0])
        self.Kv = np.array([2.6, 2.6, 4.0])
        self.Ki = np.array([0.25, 0.25, 0.6])
        self.integ = np.array([0.0, 0.0, G * (1 - TRUTH["mass"] * self.KT / (self.m * TRUTH["K_T"]))
                               / 0.6])
        self.Katt = np.array(cfg.get("katt", (9.0, 9.0, 5.0)))
        self.Krate = np.array(cfg.get("krate", (22.0, 22.0, 12.0)))
        self.dt = 0.004

    def __call__(self, s, ref):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        pr, vr, ar, psir = ref
        ep = pr - p
        ev = vr - v
        self.integ += ep * self.dt
        self.integ = np.clip(self.integ, -8, 8)
        acmd = ar + self.Kp * ep + self.Kv * ev + self.Ki * self.integ
        ah = math.hypot(acmd[0], acmd[1])
        amax_h = 7.0
        if ah > amax_h:
            acmd[0:2] *= amax_h / ah
        zlo = -38.0 if self.punch else -12.0
        acmd[2] = min(max(acmd[2], zlo), 6.0)
        f = self.m * (acmd - np.array([0.0, 0.0, G]))       # thrust force wanted (world)
        b3 = -f / np.linalg.norm(f)
        # tilt limit 40 deg (b3 = body z axis, pointing down-ish)
        cmax = math.cos(math.radians(40))
        if b3[2] < cmax:
            hh = math.hypot(b3[0], b3[1])
            sm = math.sin(math.radians(40))
            b3 = np.array([b3[0] / hh * sm, b3[1] / hh * sm, cmax])
        R = quat_to_R(q)
        T = max(-f @ R[:, 2], 0.0)
        b1c = np.array([math.cos(psir), math.sin(psir), 0.0])
        b2 = np.cross(b3, b1c)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        E = Rd.T @ R - R.T @ Rd
        eR = 0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]])
        omd = -self.Katt * eR
        omd = np.clip(omd, -4.0, 4.0)
        tau = self.J * self.Krate * (omd - om) + np.cross(om, self.J * om)
        w2 = self.Minv @ np.array([T, tau[0], tau[1], tau[2]])
        w2 = np.clip(w2, 80.0 ** 2, self.wmax_cmd ** 2)
        return np.sqrt(w2)


def make_reference(rng, duration, punch, kind):
    """Piecewise: position steps, yaw steps, a circle; returns function t -> (p, v, a, psi)."""
    segs = []
    t = 2.0
    z0 = -10.0
    items = ["step", "step", "circle", "step", "yaw", "step", "zstep", "circle", "step", "fig8"]
    if punch:
        items = ["step", "punch", "step", "circle", "punch", "yaw", "step", "punch", "fig8",
                 "step", "punch"]
    i = 0
    while t < duration - 1.0:
        it = items[i % len(items)] if kind == "est" else items[(i + 3) % len(items)]
        i += 1
        if it == "step":
            d = 3.0
            tgt = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), z0 + rng.uniform(-1.5, 1.5)])
            segs.append(("step", t, d, tgt, rng.uniform(-1.2, 1.2)))
        elif it == "zstep":
            d = 3.0
            tgt = np.array([0.0, 0.0, z0 + rng.choice([-2.5, 2.0])])
            segs.append(("step", t, d, tgt, 0.0))
        elif it == "yaw":
            d = 3.0
            segs.append(("step", t, d, np.array([0.0, 0.0, z0]), rng.choice([-2.5, 2.5])))
        elif it == "circle":
            d = 7.0
            segs.append(("circle", t, d, rng.uniform(2.0, 3.0), rng.uniform(1.3, 1.8)))
        elif it == "fig8":
            d = 7.0
            segs.append(("fig8", t, d, rng.uniform(2.0, 3.0), rng.uniform(1.0, 1.4)))
        elif it == "punch":
            d = 4.0
            segs.append(("punch", t, d, 0, 0))
        t += d

    def ref(tt):
        p = np.array([0.0, 0.0, z0]); v = np.zeros(3); a = np.zeros(3); psi = 0.0
        for sg in segs:
            if tt < sg[1]:
                break
            kind_, t0, d = sg[0], sg[1], sg[2]
            if tt >= t0 + d and kind_ != "step":
                continue
            if kind_ == "step":
                p = sg[3].copy(); v = np.zeros(3); a = np.zeros(3); psi = sg[4]
            elif kind_ in ("circle", "fig8"):
                r, om = sg[3], sg[4]
                u = tt - t0
                ramp = min(1.0, u / 1.0) * min(1.0, (d - u) / 1.0)
                if kind_ == "circle":
                    p = np.array([r * math.sin(om * u), r * (1 - math.cos(om * u)), z0 + 0.5 * math.sin(0.9 * u)])
                    v = ramp * np.array([r * om * math.cos(om * u), r * om * math.sin(om * u), 0.45 * math.cos(0.9 * u)])
                    a = ramp * np.array([-r * om * om * math.sin(om * u), r * om * om * math.cos(om * u), -0.405 * math.sin(0.9 * u)])
                else:
                    p = np.array([r * math.sin(om * u), 0.5 * r * math.sin(2 * om * u), z0 + 0.6 * math.sin(1.3 * u)])
                    v = ramp * np.array([r * om * math.cos(om * u), r * om * math.cos(2 * om * u), 0.78 * math.cos(1.3 * u)])
                    a = ramp * np.array([-r * om * om * math.sin(om * u), -2 * r * om * om * math.sin(2 * om * u), -1.014 * math.sin(1.3 * u)])
                psi = 0.4 * math.sin(0.7 * u)
            elif kind_ == "punch":
                u = tt - t0
                # hard climb 0.25 s at 3.4 g beyond gravity, then coast/brake to hold
                if u < 0.25:
                    a = np.array([0.0, 0.0, -33.0]); v = np.array([0.0, 0.0, -33.0 * u])
                    p = np.array([0.0, 0.0, z0 - 16.5 * u * u])
                else:
                    p = np.array([0.0, 0.0, z0 - 1.03 - 2.0]); v = np.zeros(3); a = np.zeros(3)
                psi = 0.0
        return p, v, a, psi
    return ref


def simulate(case, kind, seed, duration):
    cfg = CASES[case]
    rng = np.random.default_rng(seed)
    plant = Plant(cfg)
    ctrl = Controller(cfg)
    ref = make_reference(rng, duration, cfg.get("punch", False), kind)
    w_h = math.sqrt(TRUTH["mass"] * G / (4 * TRUTH["K_T"]))
    if cfg.get("k1"):
        k1 = cfg["k1"]; KT = TRUTH["K_T"]
        w_h = (-k1 + math.sqrt(k1 * k1 + 4 * KT * TRUTH["mass"] * G / 4)) / (2 * KT)
    s = np.zeros(17)
    s[2] = -10.0
    s[6:10] = [1, 0, 0, 0]
    s[13:17] = w_h
    h = 0.001
    n = int(round(duration / h))
    delay_steps = int(round(cfg.get("pos_delay", 0.0) / h))
    pos_hist = []
    rows = []
    wcmd = np.full(4, w_h)
    slew_bind = 0; sat_bind = 0; nsteps = 0
    for k in range(n + 1):
        t = k * h
        if k % 4 == 0:
            wcmd = ctrl(s, ref(t))
        pos_hist.append(s[0:3].copy())
        if k % 5 == 0:
            rows.append((t, s.copy(), wcmd.copy(), pos_hist[max(0, k - delay_steps)].copy()))
        if k == n:
            break
        # diagnostics
        if plant.slew is not None:
            dw = (wcmd - s[13:17]) / plant.tau
            slew_bind += int(np.any(np.abs(dw) > plant.slew)); nsteps += 1
        if plant.wmax is not None:
            sat_bind += int(np.any(wcmd > plant.wmax)); nsteps += 1 if plant.slew is None else 0
        s = plant.step(s, wcmd, h)
    # sensors
    out = []
    for j, (t, st, wc, pd) in enumerate(rows):
        R = quat_to_R(st[6:10])
        phi, th, psi = euler_from_R(R)
        w_log = st[13:17] if cfg["log"] == "actual" else wc
        row = {"t": t}
        for i in range(4):
            row[f"w{i+1}"] = w_log[i]
        if j % 2 == 0:
            pn = pd + rng.normal(0, 0.002, 3)
            an = np.array([phi, th, psi]) + rng.normal(0, 0.002, 3)
            an[2] = (an[2] + math.pi) % (2 * math.pi) - math.pi
            row.update(x=pn[0], y=pn[1], z=pn[2], phi=an[0], theta=an[1], psi=an[2])
        else:
            row.update(x=None, y=None, z=None, phi=None, theta=None, psi=None)
        g = st[10:13] + rng.normal(0, 0.004, 3)
        row.update(p=g[0], q=g[1], r=g[2])
        out.append(row)
    stats = dict(slew_bind_frac=slew_bind / max(nsteps, 1) if plant.slew else None,
                 sat_frac=sat_bind / max(nsteps, 1) if plant.wmax else None,
                 w_actual_max=float(max(r[1][13:17].max() for r in rows)),
                 w_cmd_max=float(max(r[2].max() for r in rows)),
                 w_hover=w_h)
    return out, stats


COLS = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r"]


def write_csv(path, rows):
    with open(path, "w", newline="\n") as f:
        f.write(",".join(COLS) + "\n")
        for r in rows:
            f.write(",".join("" if r[c] is None else ("%.4f" % r[c] if c == "t" else "%.9g" % r[c])
                             for c in COLS) + "\n")


def write_airframe(path, name):
    txt = f"""[airframe]
name = "{name}"
mass = {TRUTH['mass']}
inertia = [{TRUTH['inertia'][0]}, {TRUTH['inertia'][1]}, {TRUTH['inertia'][2]}]
arm_length = {TRUTH['arm']}
layout = "x"
rotor_inertia = {TRUTH['J_r']}
gravity = {G}

[parameters]
K_T = 2.4e-5
b = 3.3e-7
Kd = [0.1, 0.1, 0.1]
"""
    with open(path, "w") as f:
        f.write(txt)


def verify(outdir):
    """Open-loop, motors off (inputs are the rotor speeds, ZOH): write U.csv and our outputs."""
    cfg = dict(motors=False)
    plant = Plant(cfg)
    w_h = math.sqrt(TRUTH["mass"] * G / (4 * TRUTH["K_T"]))
    h = 0.001
    dur = 4.0
    n = int(dur / h)
    s = np.zeros(17); s[6:10] = [1, 0, 0, 0]
    rowsU, rowsY = [], []
    for k in range(n + 1):
        t = k * h
        if k % 5 == 0:
            tt = t
            w = w_h * np.array([1.0 + 0.03 * math.sin(2.1 * tt) + 0.01 * math.sin(7 * tt),
                                1.0 + 0.03 * math.sin(2.1 * tt) - 0.01 * math.sin(7 * tt),
                                1.0 - 0.02 * math.cos(1.7 * tt) + 0.012 * math.sin(5 * tt),
                                1.0 - 0.02 * math.cos(1.7 * tt) - 0.012 * math.sin(5 * tt)]) * 1.01
            R = quat_to_R(s[6:10])
            phi, th, psi = euler_from_R(R)
            rowsU.append([t] + list(w))
            rowsY.append([t, *s[0:3], phi, th, psi, *s[3:6], *s[10:13]])
        if k == n:
            break
        s = plant.step(s, w, h)
    with open(os.path.join(outdir, "verify_U.csv"), "w") as f:
        f.write("t,w1,w2,w3,w4\n")
        for r in rowsU:
            f.write(",".join("%.9g" % x for x in r) + "\n")
    with open(os.path.join(outdir, "verify_ours.csv"), "w") as f:
        f.write("t,x,y,z,phi,theta,psi,vx,vy,vz,p,q,r\n")
        for r in rowsY:
            f.write(",".join("%.12g" % x for x in r) + "\n")
    write_airframe(os.path.join(outdir, "verify.toml"), "audit31_verify")


def run_case(case, outdir):
    os.makedirs(outdir, exist_ok=True)
    if case == "verify":
        verify(outdir)
        return
    base = {"control": 100, "slew": 200, "slewcrash": 200, "saturation": 300, "linthrust": 400, "posdelay": 500}[case]
    est, st_e = simulate(case, "est", base + 1, 50.0)
    val, st_v = simulate(case, "val", base + 2, 30.0)
    write_csv(os.path.join(outdir, f"{case}_est.csv"), est)
    write_csv(os.path.join(outdir, f"{case}_val.csv"), val)
    write_airframe(os.path.join(outdir, f"{case}.toml"), f"audit31_{case}")
    truth = dict(TRUTH)
    truth.update(case=case, config=CASES[case], est_stats=st_e, val_stats=st_v)
    with open(os.path.join(outdir, f"{case}_truth.json"), "w") as f:
        json.dump(truth, f, indent=1, sort_keys=True)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print(__doc__)
        sys.exit(2)
    case, outdir = sys.argv[1], sys.argv[2]
    cases = list(CASES) + ["verify"] if case == "all" else [case]
    for c in cases:
        run_case(c, outdir)

#!/usr/bin/env python3
"""Independent flight simulator of a 5-inch FPV racing quadrotor, by the thirteenth blind audit
(2026-12-04), kept as a test generator that is not greybox's own: written from ``CONTRACT.md``
and the README alone, without reading the package, and checked against ``greybox simulate``
(2e-12 m, 1e-14 rad/s over 1.5 s of excited open-loop flight).

Written from greybox's public contract only (CONTRACT.md / README conventions):
world NED, body FRD, ZYX Euler, thrust along body -z, X layout
rotor1 FR (+a,+a) spin +1, rotor2 BL (-a,-a) spin +1, rotor3 FL (+a,-a) spin -1,
rotor4 BR (-a,+a) spin -1; reaction torque spin_i*b*w_i^2 about body +z;
gyroscopic torque J_r*Omega_r*(omega x e_z), Omega_r = sum spin_i w_i.

Own choices: unit-quaternion attitude state, fixed-step RK4 at 2 kHz, first-order
rotor-speed lag (on w), Betaflight-like acro controller (rate PID at 2 kHz with D on
filtered gyro, I-term), attitude loop on SO(3) at 1 kHz, position loop at 400 Hz,
airmode-like mixer with honest clipping at motor limits.
Sensors: mocap 166.7 Hz (1 mm, dropouts + outages), attitude estimator 500 Hz with
white + coloured error, gyro 500 Hz, bidirectional-DShot eRPM telemetry (period
quantised to 1 us, 7 pole pairs, jitter), optional accelerometer.
"""
import argparse, json, math, sys
import numpy as np

G = 9.81
# ---------------- vehicle truth ----------------
VEH = dict(
    name="fpv5", mass=0.65, J=[1.2e-3, 1.3e-3, 2.2e-3], l=0.10, K_T=5.2e-7, b=8.3e-9,
    Kd=[0.06, 0.06, 0.09], J_r=2.0e-6, tau_m=0.020, w_min=300.0, w_max=3500.0,
    R_prop=0.0635, pole_pairs=7,
)
SPIN = np.array([1.0, 1.0, -1.0, -1.0])


def rotor_pos(l):
    a = l / math.sqrt(2)
    return np.array([[a, a, 0.0], [-a, -a, 0.0], [a, -a, 0.0], [-a, a, 0.0]])


def q2R(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler2q(phi, th, psi):
    cr, sr = math.cos(phi / 2), math.sin(phi / 2)
    cp, sp = math.cos(th / 2), math.sin(th / 2)
    cy, sy = math.cos(psi / 2), math.sin(psi / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


def R2euler(R):
    phi = math.atan2(R[2, 1], R[2, 2])
    th = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    psi = math.atan2(R[1, 0], R[0, 0])
    return phi, th, psi


def eulerR(phi, th, psi):
    cf, sf, ct, st, cp, sp = math.cos(phi), math.sin(phi), math.cos(th), math.sin(th), math.cos(psi), math.sin(psi)
    Rz = np.array([[cp, -sp, 0], [sp, cp, 0], [0, 0, 1]])
    Ry = np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    Rx = np.array([[1, 0, 0], [0, cf, -sf], [0, sf, cf]])
    return Rz @ Ry @ Rx


class Plant:
    """state: p(3) v(3) q(4) om(3) w(4) ang(4)  -> 21"""

    def __init__(self, veh, hidden):
        self.v = veh
        self.h = hidden
        self.m = veh["mass"]
        self.J = np.array(veh["J"])
        self.r = rotor_pos(veh["l"])
        if "cog_offset" in hidden:
            dx, dy = hidden["cog_offset"]
            self.r = self.r - np.array([dx, dy, 0.0])
        self.kt = np.full(4, veh["K_T"])
        self.bb = np.full(4, veh["b"])
        if "weak_rotor" in hidden:
            i, d = hidden["weak_rotor"]
            self.kt[i] *= (1 + d)
            self.bb[i] *= (1 + d)
        self.Kd = np.array(veh["Kd"])

    def forces(self, t, s):
        """returns (dv/dt world, domega/dt body, specific force body)"""
        v = s[3:6]; q = s[6:10]; om = s[10:13]; w = s[13:17]; ang = s[17:21]
        R = q2R(q)
        h = self.h
        kt = self.kt
        if "thrust_drift" in h:
            kt = kt * (1 + h["thrust_drift"] * t)
        T = kt * w * w
        vb = R.T @ v
        if "inflow" in h:  # thrust loss with axial inflow (outside catalogue)
            vrot = np.cross(om, self.r)  # hub velocity due to rotation
            v_ax = -(vb[2] + vrot[:, 2])  # upward (into the rotor) velocity
            T = T * (1 - h["inflow"] * v_ax / (np.maximum(w, 50.0) * self.v["R_prop"]))
        Fb = np.array([0.0, 0.0, -T.sum()])
        tau = np.zeros(3)
        # thrust moments
        for i in range(4):
            tau += np.cross(self.r[i], [0.0, 0.0, -T[i]])
        if "bent_prop" in h:  # once-per-rev thrust ripple + rotating imbalance on rotor 1
            amp_T, F_imb = h["bent_prop"]
            a0 = ang[0]
            dT = amp_T * T[0] * math.sin(a0)
            fi = np.array([F_imb * math.cos(a0), F_imb * math.sin(a0), -dT])
            Fb = Fb + fi
            tau += np.cross(self.r[0], fi)
        tau += np.array([0.0, 0.0, (SPIN * self.bb * w * w).sum()])
        if "rotor_accel" in h and self.wcmd_now is not None:  # motor acceleration reaction torque (outside catalogue)
            dw = (self.wcmd_now - w) / self.v["tau_m"]
            tau += np.array([0.0, 0.0, h["rotor_accel"] * (SPIN * dw).sum()])
        if "propwash" in h and self.pw is not None:  # descending through own wake: random torque/thrust (outside catalogue)
            tau += self.pw[0:3]
            Fb = Fb + np.array([0.0, 0.0, self.pw[3]])
        Om_r = (SPIN * w).sum()
        tau += self.v["J_r"] * Om_r * np.cross(om, [0.0, 0.0, 1.0])
        if "rotor_drag" in h:
            k = h["rotor_drag"]
            Fb = Fb + np.array([-k * w.sum() * vb[0], -k * w.sum() * vb[1], 0.0])
        Fw = R @ Fb - self.Kd * v
        if "quad_drag" in h:
            Fw = Fw - h["quad_drag"] * np.linalg.norm(v) * v
        acc = Fw / self.m + np.array([0.0, 0.0, G])
        domega = (tau - np.cross(om, self.J * om)) / self.J
        spf = R.T @ (Fw / self.m)
        return acc, domega, spf, R

    def deriv(self, t, s, wcmd):
        acc, dom, _, _ = self.forces(t, s)
        q = s[6:10]; om = s[10:13]; w = s[13:17]
        qw, qx, qy, qz = q
        p, qq, r = om
        dq = 0.5 * np.array([-qx * p - qy * qq - qz * r,
                             qw * p + qy * r - qz * qq,
                             qw * qq + qz * p - qx * r,
                             qw * r + qx * qq - qy * p])
        if self.openloop:
            dw = np.zeros(4)
        else:
            dw = (wcmd - w) / self.v["tau_m"]
        return np.concatenate([s[3:6], acc, dq, dom, dw, w])

    openloop = False
    wcmd_now = None
    pw = None


# ---------------- reference ----------------
def smoothstep(x):
    x = np.clip(x, 0, 1)
    return x * x * x * (10 - 15 * x + 6 * x * x)


class Ref:
    def __init__(self, rng, dur):
        self.dur = dur
        self.Om0 = rng.uniform(0.95, 1.1)
        self.ph = rng.uniform(0, 2 * np.pi)
        self.phz = rng.uniform(0, 2 * np.pi)
        self.Ax = rng.uniform(3.6, 4.0)
        self.Ay = rng.uniform(2.0, 2.4)
        self.z0 = -2.1
        self.t_spin = sorted(rng.uniform(4, dur - 3, size=2))
        self.spin_dir = [1, -1]
        self.t_dive = sorted(rng.uniform(5, dur - 3, size=2))
        if self.t_dive[1] - self.t_dive[0] < 2.5:  # keep dives apart (stay above the floor)
            self.t_dive[1] = self.t_dive[0] + 2.5 if self.t_dive[0] + 2.5 < dur - 1.5 else self.t_dive[0] - 2.5
        self.t_climb = rng.uniform(6, dur - 4)

    def pos(self, t):
        e = smoothstep(t / 2.5)
        # slowly varying speed: phase integral
        Om = self.Om0
        phi = Om * t + 0.25 * math.sin(0.21 * t) / 0.21 * 0.8 * Om  # speed modulation
        x = self.Ax * math.sin(phi + self.ph) - self.Ax * math.sin(self.ph) * (1 - e)
        y = self.Ay * math.sin(2 * (phi + self.ph)) - self.Ay * math.sin(2 * self.ph) * (1 - e)
        x = e * x + (1 - e) * 0.0 if False else x
        x *= e; y *= e
        z = self.z0 + 0.7 * math.sin(0.55 * t + self.phz) * e
        for td in self.t_dive:  # dive down 1.0 m and back up
            z += 1.0 * (smoothstep((t - td) / 0.8) - smoothstep((t - td - 1.3) / 1.0))
        z -= 0.8 * (smoothstep((t - self.t_climb) / 0.7) - smoothstep((t - self.t_climb - 1.5) / 1.2))
        psi = 0.5 * math.sin(0.4 * t)
        for ts, d in zip(self.t_spin, self.spin_dir):
            psi += d * 2 * math.pi * smoothstep((t - ts) / 1.6)
        return np.array([x, y, z]), psi

    def pva(self, t, h=2e-3):
        p0, s0 = self.pos(t)
        p1, s1 = self.pos(t + h)
        pm, sm = self.pos(t - h)
        return p0, (p1 - pm) / (2 * h), (p1 - 2 * p0 + pm) / h ** 2, s0, (s1 - sm) / (2 * h)


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


# ---------------- controller ----------------
class Acro:
    def __init__(self, veh):
        self.v = veh
        self.m = veh["mass"]
        self.J = np.array(veh["J"])
        r = rotor_pos(veh["l"])
        kt, b = veh["K_T"], veh["b"]
        # [T, tx, ty, tz] = A @ w^2
        A = np.zeros((4, 4))
        for i in range(4):
            A[0, i] = kt
            A[1, i] = -r[i, 1] * kt  # tau_x = y*(-T) ... r x (0,0,-T): x comp = r_y*(-T)
            A[2, i] = r[i, 0] * kt  # y comp = -(r_x*(-T)) = r_x T
            A[3, i] = SPIN[i] * b
        self.Ainv = np.linalg.inv(A)
        self.I = np.zeros(3)
        self.gf = np.zeros(3)  # filtered gyro
        self.gf_prev = np.zeros(3)
        self.Kp_r = np.array([90.0, 90.0, 45.0])
        self.Ki_r = np.array([150.0, 150.0, 80.0])
        self.Kd_r = np.array([0.35, 0.35, 0.0])
        self.K_att = np.array([11.0, 11.0, 6.0])
        self.Kp = 7.0; self.Kv = 5.0; self.Kip = 1.0
        self.ip = np.zeros(3)
        self.om_des = np.zeros(3)
        self.Tdes = self.m * G
        self.Rdes = np.eye(3)
        self.yawrate_ff = 0.0

    def position(self, dt, pos, vel, ref):
        p_r, v_r, a_r, psi_r, dpsi_r = ref
        e = p_r - pos
        self.ip = np.clip(self.ip + e * dt, -1, 1)
        a = a_r + self.Kp * e + self.Kv * (v_r - vel) + self.Kip * self.ip
        F = self.m * (a - np.array([0, 0, G]))  # force needed (world), thrust is R(0,0,-T)
        # limit tilt to 60 deg
        Fz = min(F[2], -0.2 * self.m * G)
        Fh = F[:2]
        maxh = abs(Fz) * math.tan(math.radians(60))
        nh = np.linalg.norm(Fh)
        if nh > maxh:
            Fh = Fh * maxh / nh
        F = np.array([Fh[0], Fh[1], Fz])
        b3 = -F / np.linalg.norm(F)
        c1 = np.array([math.cos(psi_r), math.sin(psi_r), 0.0])
        b2 = np.cross(b3, c1); b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        self.Rdes = np.column_stack([b1, b2, b3])
        self.Fdes = F
        self.yawrate_ff = dpsi_r

    def attitude(self, R):
        eR = 0.5 * vee(self.Rdes.T @ R - R.T @ self.Rdes)
        om = -self.K_att * eR
        om[2] += self.yawrate_ff * R[2, 2]
        self.om_des = np.clip(om, [-16, -16, -9], [16, 16, 9])
        self.Tdes = float(-(self.Fdes @ R[:, 2]))
        self.Tdes = max(self.Tdes, 0.1 * self.m * G)

    def rate(self, dt, gyro):
        alpha = dt / (dt + 1 / (2 * math.pi * 90.0))
        self.gf = self.gf + alpha * (gyro - self.gf)
        dg = (self.gf - self.gf_prev) / dt
        self.gf_prev = self.gf.copy()
        e = self.om_des - gyro
        self.I = np.clip(self.I + self.Ki_r * e * dt, -30, 30)
        acc = self.Kp_r * e + self.I - self.Kd_r * dg * 0 - self.Kd_r * dg
        tau = self.J * acc + np.cross(gyro, self.J * gyro)
        u = np.array([self.Tdes, tau[0], tau[1], tau[2]])
        w2 = self.Ainv @ u
        lo, hi = self.v["w_min"] ** 2, self.v["w_max"] ** 2
        # airmode-like: keep the differential (attitude) if possible, sacrifice thrust
        if w2.max() > hi:
            w2 = w2 - (w2.max() - hi)
        if w2.min() < lo:
            w2 = w2 + (lo - w2.min())
        w2 = np.clip(w2, lo, hi)  # honest saturation
        return np.sqrt(w2)


def vee(M):
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


# ---------------- flight ----------------
def fly(hidden, seed, dur, accel=False, log_commands=False, gyro_scale=None, sim_rate=2000,
        log_rate=500, mocap_div=3, outdir=None, name=None, ctl_div=1):
    rng = np.random.default_rng(seed)
    veh = VEH
    pl = Plant(veh, hidden)
    ctl = Acro(veh)
    ref = Ref(rng, dur)
    dt = 1.0 / sim_rate
    nsub = sim_rate // log_rate
    p0, v0, a0, psi0, _ = ref.pva(0.0)
    wh = math.sqrt(veh["mass"] * G / (4 * veh["K_T"]))
    s = np.zeros(21)
    s[0:3] = p0; s[3:6] = v0; s[6:10] = euler2q(0, 0, psi0); s[13:17] = wh
    s[17:21] = rng.uniform(0, 2 * np.pi, 4)
    ctl.I[:] = 0
    nsteps = int(round(dur * sim_rate))
    rows = []
    # coloured attitude error (OU), gyro noise, etc.
    ou = np.zeros(3); ou_tau = 2.0; ou_sig = np.array([0.0015, 0.0015, 0.003])
    wcmd = np.full(4, wh)
    gsc = np.ones(3) if gyro_scale is None else np.array(gyro_scale)
    sat_count = 0
    hist = []
    for k in range(nsteps + 1):
        t = k * dt
        hist.append(s[0:3].copy())
        om = s[10:13]
        vib = np.zeros(3); vib_a = np.zeros(3)
        if "bent_prop" in hidden:
            a0_ = s[17]
            g_amp, a_amp = hidden.get("bent_vib", (0.15, 3.0))
            vib = g_amp * np.array([math.sin(a0_), math.cos(a0_), 0.3 * math.sin(a0_)])
            vib_a = a_amp * np.array([math.cos(a0_), math.sin(a0_), 0.5 * math.sin(a0_)])
        gyro = gsc * om + rng.normal(0, 0.01, 3) + vib
        # controller
        if k % 5 == 0:
            ctl.position(5 * dt, s[0:3] + rng.normal(0, 0.001, 3), s[3:6], ref.pva(t))
        R = q2R(s[6:10])
        if k % 2 == 0:
            ctl.attitude(R)
        if k % ctl_div == 0:
            wcmd = ctl.rate(ctl_div * dt, gyro)
        if np.any(wcmd >= veh["w_max"] - 1e-6):
            sat_count += 1
        if k % nsub == 0:
            # log row (sensors sample state at time t)
            acc, dom, spf, _ = pl.forces(t, s)
            phi, th, psi = R2euler(R)
            ou = ou + (-ou / ou_tau) * (nsub * dt) + ou_sig * math.sqrt(2 * nsub * dt / ou_tau) * rng.normal(size=3)
            att = np.array([phi, th, psi]) + ou + rng.normal(0, 0.0007, 3)
            if "att_bias" in hidden:
                att[0] += hidden["att_bias"][0]; att[1] += hidden["att_bias"][1]
            att[2] = wrap(att[2])
            wtrue = s[13:17]
            if log_commands:
                wlog = wcmd.copy()
            else:  # eRPM telemetry: period quantised to 1 us, jitter
                erpm = wtrue * 60 / (2 * math.pi) * veh["pole_pairs"]
                period_us = np.round(60e6 / erpm)
                wq = 60e6 / period_us / veh["pole_pairs"] * 2 * math.pi / 60
                wlog = wq * (1 + rng.normal(0, 0.002, 4))
            row = dict(t=round(t, 6), w1=wlog[0], w2=wlog[1], w3=wlog[2], w4=wlog[3])
            if (k // nsub) % mocap_div == 0:
                kd = int(round(hidden.get("pos_delay", 0.0) / dt))
                pos = hist[max(0, k - kd)] + rng.normal(0, 0.001, 3)
                row.update(x=pos[0], y=pos[1], z=pos[2])
            else:
                row.update(x=np.nan, y=np.nan, z=np.nan)
            row.update(phi=att[0], theta=att[1], psi=att[2], p=gyro[0], q=gyro[1], r=gyro[2])
            if accel:
                a_meas = spf + rng.normal(0, 0.08, 3) + vib_a
                row.update(ax=a_meas[0], ay=a_meas[1], az=a_meas[2])
            row.update(x_true=s[0], y_true=s[1], z_true=s[2], vx_true=s[3], vy_true=s[4], vz_true=s[5],
                       wtrue1=wtrue[0], wtrue2=wtrue[1], wtrue3=wtrue[2], wtrue4=wtrue[3])
            rows.append(row)
        if k == nsteps:
            break
        # RK4 step with wcmd held
        pl.wcmd_now = wcmd
        if "propwash" in hidden:
            if pl.pw is None:
                pw_state = np.zeros(4)
            sig_tau, sig_T, tau_c = hidden["propwash"]
            pw_state = pw_state - pw_state * dt / tau_c + np.sqrt(2 * dt / tau_c) * rng.normal(size=4)
            vz = s[5]; vh = math.hypot(s[3], s[4])
            fpw = min(max(vz / 1.5, 0.0), 1.5) * math.exp(-vh / 5.0)
            pl.pw = fpw * np.array([sig_tau, sig_tau, 0.3 * sig_tau, sig_T]) * pw_state
        f = pl.deriv
        k1 = f(t, s, wcmd)
        k2 = f(t + dt / 2, s + dt / 2 * k1, wcmd)
        k3 = f(t + dt / 2, s + dt / 2 * k2, wcmd)
        k4 = f(t + dt, s + dt * k3, wcmd)
        s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
    # mocap dropouts: random 2 %, plus two outages of 50-80 ms
    n = len(rows)
    mo = [i for i in range(n) if not math.isnan(rows[i]["x"])]
    drop = rng.choice(mo, size=int(0.02 * len(mo)), replace=False)
    for i in drop:
        rows[i]["x"] = rows[i]["y"] = rows[i]["z"] = np.nan
    for _ in range(2):
        i0 = int(rng.uniform(0.1, 0.9) * n); L = int(rng.uniform(0.05, 0.08) * log_rate)
        for i in range(i0, min(n, i0 + L)):
            rows[i]["x"] = rows[i]["y"] = rows[i]["z"] = np.nan
    # never leave the first/last row without position
    info = dict(sat_fraction=sat_count / nsteps)
    return rows, info


def write_csv(rows, path, truth_cols=False):
    keys = [k for k in rows[0].keys() if truth_cols or not (k.endswith("_true") or k.startswith("wtrue"))]
    with open(path, "w") as f:
        f.write(",".join(keys) + "\n")
        for r in rows:
            f.write(",".join("" if (isinstance(r[k], float) and math.isnan(r[k])) else repr(float(r[k])) if k != "t" else f"{r[k]:.6f}" for k in keys) + "\n")


def airframe_toml(path, guess=True):
    v = VEH
    f = 1.0
    with open(path, "w") as fh:
        fh.write(f"""[airframe]
name = "fpv5_racer"
mass = {v['mass']}
inertia = [{v['J'][0]}, {v['J'][1]}, {v['J'][2]}]
arm_length = {v['l']}
layout = "x"
rotor_inertia = {v['J_r']}
gravity = {G}

[parameters]
K_T = {v['K_T']*1.25 if guess else v['K_T']:.4e}
b = {v['b']*0.7 if guess else v['b']:.4e}
Kd = [0.03, 0.03, 0.05]
""")


def openloop(inputs_csv, out_csv, x0=None):
    """simulate my plant open loop from t,w1..w4 (ZOH), no hidden effects, output noise-free"""
    import csv
    data = np.genfromtxt(inputs_csv, delimiter=",", names=True)
    pl = Plant(VEH, {})
    pl.openloop = True
    s = np.zeros(21); s[6] = 1.0
    if x0 is not None:
        s[0:3] = x0[0:3]; s[6:10] = euler2q(*x0[3:6]); s[3:6] = x0[6:9]; s[10:13] = x0[9:12]
    t = data["t"]; W = np.column_stack([data[f"w{i}"] for i in range(1, 5)])
    out = []
    for k in range(len(t)):
        R = q2R(s[6:10]); phi, th, psi = R2euler(R)
        out.append([t[k], *s[0:3], phi, th, psi, *s[10:13], *s[3:6]])
        if k == len(t) - 1:
            break
        s[13:17] = W[k]
        T = t[k + 1] - t[k]
        n = max(1, int(math.ceil(T / 2.5e-4)))
        h = T / n
        for j in range(n):
            tt = t[k] + j * h
            k1 = pl.deriv(tt, s, None); k2 = pl.deriv(tt + h / 2, s + h / 2 * k1, None)
            k3 = pl.deriv(tt + h / 2, s + h / 2 * k2, None); k4 = pl.deriv(tt + h, s + h * k3, None)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4); s[6:10] /= np.linalg.norm(s[6:10])
    np.savetxt(out_csv, np.array(out), delimiter=",", header="t,x,y,z,phi,theta,psi,p,q,r,vx,vy,vz", comments="")


CASES = {
    "control": {},
    "quad_drag": {"quad_drag": 0.015},
    "rotor_drag": {"rotor_drag": 1.2e-5},
    "motor_lag": {},  # commands logged
    "thrust_drift": {"thrust_drift": -0.004},
    "cog_offset": {"cog_offset": (0.006, -0.004)},
    "weak_rotor": {"weak_rotor": (1, -0.07)},
    "inflow": {"inflow": 3.5},
    "bent_prop": {"bent_prop": (0.04, 0.3), "bent_vib": (0.15, 3.0)},
    "gyro_scale": {},
    "rotor_accel": {"rotor_accel": 2.0e-6},
    "pos_delay": {"pos_delay": 0.012},
    "att_bias": {"att_bias": (0.02, -0.015)},
    "weak_rotor3": {"weak_rotor": (2, -0.03)},
    "propwash": {"propwash": (0.015, 0.4, 0.02)},
}

if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("case", choices=list(CASES))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--dur", type=float, default=25)
    ap.add_argument("--accel", action="store_true")
    ap.add_argument("--out", required=True)
    ap.add_argument("--log-rate", type=int, default=500)
    ap.add_argument("--ctl-div", type=int, default=1)
    a = ap.parse_args()
    hidden = dict(CASES[a.case])
    rows, info = fly(hidden, a.seed, a.dur, accel=a.accel or a.case == "bent_prop",
                     log_commands=(a.case == "motor_lag"),
                     gyro_scale=(1.05, 1.05, 0.96) if a.case == "gyro_scale" else None,
                     log_rate=a.log_rate, mocap_div=3 if a.log_rate == 500 else 6, ctl_div=a.ctl_div)
    write_csv(rows, a.out)
    write_csv(rows, a.out.replace(".csv", ".truth.csv"), truth_cols=True)
    V = np.array([[r["vx_true"], r["vy_true"], r["vz_true"]] for r in rows])
    W = np.array([[r["wtrue1"], r["wtrue2"], r["wtrue3"], r["wtrue4"]] for r in rows])
    info.update(case=a.case, seed=a.seed, hidden={k: v for k, v in hidden.items()},
                max_speed=float(np.linalg.norm(V, axis=1).max()), rms_speed=float(np.sqrt((V ** 2).sum(1).mean())),
                max_vz=float(np.abs(V[:, 2]).max()), w_min=float(W.min()), w_max=float(W.max()),
                zmin=float(min(r["z_true"] for r in rows)), zmax=float(max(r["z_true"] for r in rows)),
                xr=[float(min(r["x_true"] for r in rows)), float(max(r["x_true"] for r in rows))],
                yr=[float(min(r["y_true"] for r in rows)), float(max(r["y_true"] for r in rows))])
    json.dump(info, open(a.out.replace(".csv", ".info.json"), "w"), indent=1)
    print(json.dumps(info))

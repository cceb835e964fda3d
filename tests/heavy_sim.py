"""
sim.py -- independent quadrotor flight-log generator (numpy/scipy only; does NOT import greybox).

Written by a fifteenth blind audit (2026-12-05) from CONTRACT.md and the README alone, without
reading the package; kept in greybox's tests as ``heavy_sim`` (a generator that is not greybox's
own). Checked against ``greybox simulate``: 1.5e-6 m and 6e-7 rad over a tumbling open-loop
flight from a moving, tilted start.

Vehicle: 3 kg heavy-lift "+" quadrotor (greybox contract layout "plus": rotor 1 front (+l,0,0),
2 right (0,+l,0), 3 back (-l,0,0), 4 left (0,-l,0); spin [-1,+1,-1,+1]).
Conventions (greybox CONTRACT section 1): world NED, body FRD, thrust K_T w^2 along body -z,
reaction torque spin_i*b*w_i^2 about body +z, rotor angular momentum h = -J_r*Omega_r*e_z,
Omega_r = sum(spin_i w_i), gyroscopic torque -omega x h.  Linear drag -Kd*v (world axes).
Attitude kept as a unit quaternion (body->world, scalar first); ZYX Euler only for logging.

Integrator: scipy.integrate.solve_ivp (LSODA by default, rtol 1e-9) between controller ticks;
the controller runs at 250 Hz and its rotor-speed commands are a zero-order hold between ticks.
Motors: first-order lag dw/dt = (w_cmd - w)/tau_m (tau_m = 60 ms), part of the ODE state.

Controller: Lee-style geometric SO(3) controller (position -> desired thrust vector -> desired
rotation; attitude error e_R = vee(Rd^T R - R^T Rd)/2), using the complementary-filter attitude,
the (noisy) gyro and a mocap-based position/velocity estimate; mixer built from nominal
parameters 5 % off the truth (K_T +5 %, b -5 %, l +5 %, J +5 %, m -5 %).

Estimator / sensors:
  * complementary filter at 250 Hz: Euler angles propagated with the gyro, roll/pitch pulled
    towards the accelerometer tilt with gain `cf_gain` per step; yaw pulled towards a noisy
    magnetometer heading (gain `mag_gain` per step, noise `mag_noise` rad).
  * log at 100 Hz: t, w1..w4 (measured speeds, 0.5 % noise; or the COMMANDS with
    log_commands=True), x,y,z at 50 Hz only (other rows empty) with 3 mm noise, phi,theta,psi
    (the filter), p,q,r gyro (noise), ax,ay,az accelerometer (FRD specific force R^T(a - g e3), noise).

Hidden effects (`effects` dict; all off by default):
  ground_effect: k_ge          per-rotor thrust /(1 - k_ge/h_i^2), h_i rotor's own height above z=0
                                (ratio capped at 1/(1-0.5))
  thrust_drift: frac           K_T(t) = K_T*(1 - frac*t/T_flight)  (battery sag; b unchanged)
  quadratic_drag: [Kq]*3       world-axes -Kq_i*|v|*v_i
  motor_asymmetry: (i, s)      rotor i (0-based) thrust and torque x s
  payload: (m_p, L)            slung point mass on a cable (stiff one-sided spring) from the CoG
  vrs: (loss, centre, width)   vortex-ring-like thrust loss in descent: every rotor's thrust x
                                (1 - loss*exp(-((vd/v_h - centre)/width)^2)) for body-down speed vd>0
  rotor_accel_torque: True     reaction torque -J_r * dOmega_r/dt about body z (not in greybox)

Usage:
  python sim.py flight OUT.csv --seed 1 [--duration 50] [--effects JSON] [--cf-gain 0.02]
                 [--log-commands] [--truth TRUTH.json]
  python sim.py openloop U.csv OUT.csv --x0 x,y,z,phi,theta,psi,vx,vy,vz,p,q,r
                 (no motor lag: the logged speeds act directly, held per row; for the convention check)
  python sim.py airframe A.toml [--guess]   writes the airframe (true or with guesses K_T x1.3, b x0.7, Kd x0.7)
"""
import argparse
import json

import numpy as np
from scipy.integrate import solve_ivp

G = 9.81
TRUE = dict(
    m=3.0, J=np.array([0.045, 0.045, 0.085]), l=0.30,
    K_T=3.0 * G / (4 * 450.0 ** 2),           # hover at 450 rad/s -> 3.633e-5
    b_over_KT=0.017,                          # m
    J_r=1.0e-4,                               # kg m^2 (15" prop + bell)
    Kd=np.array([0.30, 0.30, 0.45]),          # N s/m
    tau_m=0.060,
    R_prop=0.19,
)
TRUE["b"] = TRUE["K_T"] * TRUE["b_over_KT"]
POS = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], float)  # times l
SPIN = np.array([-1, 1, -1, 1], float)


# ---------------------------------------------------------------- math helpers
def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1*w2 - x1*x2 - y1*y2 - z1*z2, w1*x2 + x1*w2 + y1*z2 - z1*y2,
                     w1*y2 - x1*z2 + y1*w2 + z1*x2, w1*z2 + x1*y2 - y1*x2 + z1*w2])


def q2R(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1-2*(y*y+z*z), 2*(x*y-w*z), 2*(x*z+w*y)],
                     [2*(x*y+w*z), 1-2*(x*x+z*z), 2*(y*z-w*x)],
                     [2*(x*z-w*y), 2*(y*z+w*x), 1-2*(x*x+y*y)]])


def eul2q(phi, th, psi):
    cr, sr = np.cos(phi/2), np.sin(phi/2)
    cp, sp = np.cos(th/2), np.sin(th/2)
    cy, sy = np.cos(psi/2), np.sin(psi/2)
    return np.array([cy*cp*cr + sy*sp*sr, cy*cp*sr - sy*sp*cr, sy*cp*sr + cy*sp*cr, sy*cp*cr - cy*sp*sr])


def R2eul(R):
    th = -np.arcsin(np.clip(R[2, 0], -1, 1))
    return np.arctan2(R[2, 1], R[2, 2]), th, np.arctan2(R[1, 0], R[0, 0])


def eul2R(phi, th, psi):
    return q2R(eul2q(phi, th, psi))


def vee(M):
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


def wrap(a):
    return (a + np.pi) % (2*np.pi) - np.pi


# ---------------------------------------------------------------- plant
class Plant:
    def __init__(self, effects=None, T_flight=60.0, motors=True):
        self.e = effects or {}
        self.T = T_flight
        self.motors = motors
        self.l = TRUE["l"]
        self.r = POS * self.l
        self.KT = TRUE["K_T"]
        self.b = TRUE["b"]
        self.J = TRUE["J"]
        self.m = TRUE["m"]
        self.Kd = TRUE["Kd"]
        self.Jr = TRUE["J_r"]
        pl = self.e.get("payload")
        self.npay = 6 if pl else 0
        self.vh = np.sqrt(self.m*G/4 / (2*1.225*np.pi*TRUE["R_prop"]**2))

    # state: p(3) v(3) q(4) w(3) [motor speeds 4] [payload pos 3, vel 3]
    def nx(self):
        return 13 + (4 if self.motors else 0) + self.npay

    def forces(self, t, s, u):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = q2R(q)
        if self.motors:
            w = s[13:17]
        else:
            w = u
        kt = np.full(4, self.KT)
        kb = np.full(4, self.b)
        e = self.e
        if "thrust_drift" in e:
            kt = kt * (1 - e["thrust_drift"] * t / self.T)
        if "motor_asymmetry" in e:
            i, sc = e["motor_asymmetry"]
            kt[i] *= sc
            kb[i] *= sc
        T = kt * w**2
        if "ground_effect" in e:
            rw = (R @ self.r.T).T + p  # rotor positions in world
            h = np.maximum(-rw[:, 2], 0.05)
            ratio = np.minimum(e["ground_effect"] / h**2, 0.5)
            T = T / (1 - ratio)
        vb = R.T @ v
        if "vrs" in e:
            loss, c, wd = e["vrs"]
            vd = max(vb[2], 0.0) / self.vh
            T = T * (1 - loss * np.exp(-((vd - c) / wd)**2) * (vb[2] > 0))
        F_b = np.array([0, 0, -T.sum()])
        M = np.zeros(3)
        for i in range(4):
            M += np.cross(self.r[i], np.array([0, 0, -T[i]]))
        M[2] += np.sum(SPIN * kb * w**2)
        Om_r = np.sum(SPIN * w)
        h_r = np.array([0, 0, -self.Jr * Om_r])
        M += -np.cross(om, h_r)
        F_w = R @ F_b - self.Kd * v
        if "quadratic_drag" in e:
            F_w = F_w - np.asarray(e["quadratic_drag"]) * np.linalg.norm(v) * v
        return R, F_w, M, w

    def rhs(self, t, s, u):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R, F_w, M, w = self.forces(t, s, u)
        ds = np.zeros_like(s)
        ds[0:3] = v
        F_tot = F_w + np.array([0, 0, self.m*G])
        k = 13
        if self.motors:
            dw = (u - w) / TRUE["tau_m"]
            ds[13:17] = dw
            if self.e.get("rotor_accel_torque"):
                M = M + np.array([0, 0, -self.Jr * np.sum(SPIN * dw)])
            k = 17
        if self.npay:
            mp, L = self.e["payload"]
            pp, vp = s[k:k+3], s[k+3:k+6]
            d = pp - p
            dist = np.linalg.norm(d)
            n = d / dist
            stretch = dist - L
            kc, cc = 4000.0, 40.0
            ten = 0.0
            if stretch > 0:
                ten = kc*stretch + cc*np.dot(vp - v, n)
                ten = max(ten, 0.0)
            Fp = -ten*n  # on payload, towards vehicle
            ds[k:k+3] = vp
            ds[k+3:k+6] = Fp/mp + np.array([0, 0, G]) - 0.02*vp/mp
            F_tot = F_tot - Fp
        ds[3:6] = F_tot / self.m
        ds[6:10] = 0.5 * qmul(q, np.r_[0.0, om])
        ds[10:13] = (M - np.cross(om, self.J*om)) / self.J
        return ds

    def specific_force(self, t, s, u):
        ds = self.rhs(t, s, u)
        R = q2R(s[6:10])
        return R.T @ (ds[3:6] - np.array([0, 0, G]))


def step(plant, t0, t1, s, u, method="LSODA"):
    sol = solve_ivp(plant.rhs, (t0, t1), s, method=method, args=(u,), rtol=1e-9, atol=1e-10)
    if not sol.success:
        raise RuntimeError(sol.message)
    s = sol.y[:, -1].copy()
    s[6:10] /= np.linalg.norm(s[6:10])
    return s


# ---------------------------------------------------------------- reference trajectory
def reference(t, T, seed, start_low=False):
    """Heavy-lift manoeuvres: slow figure-eights, climbs/descents, yaw turns, brisk steps.
    Returns position (NED), velocity, acceleration, yaw."""
    rng = np.random.default_rng(1000 + seed)
    # piecewise schedule, deterministic per seed
    segs = []
    tt = 0.0
    kinds = ["fig8", "climb", "step", "yaw", "fig8", "descent", "step", "yaw", "fig8", "step"]
    rng.shuffle(kinds)
    for k in kinds:
        d = {"fig8": 10.0, "climb": 5.0, "descent": 5.0, "step": 4.0, "yaw": 5.0}[k]
        segs.append((tt, tt + d, k, rng.uniform(-1, 1, 4)))
        tt += d
    return segs


class RefGen:
    def __init__(self, T, seed, h0=-2.0, low_passes=False, fast_descent=False):
        self.T, self.seed = T, seed
        self.rng = np.random.default_rng(1000 + seed)
        self.h0 = h0
        # build smooth waypoint curve via sums of sines + smoothed steps
        r = self.rng
        self.fig = [(r.uniform(1.5, 2.5), r.uniform(1.0, 1.5), r.uniform(0.25, 0.33), r.uniform(0, 6.28))
                    for _ in range(1)]
        n = int(T // 6) + 2
        self.step_times = np.sort(r.uniform(3, T - 3, n))
        self.step_x = r.uniform(-2.0, 2.0, n)
        self.step_y = r.uniform(-2.0, 2.0, n)
        self.step_z = r.uniform(-1.5, 1.5, n)
        self.yaw_times = np.sort(r.uniform(3, T - 3, 4))
        self.yaw_amp = r.uniform(-1.5, 1.5, 4)
        self.low_passes = low_passes
        self.fast_descent = fast_descent

    @staticmethod
    def sstep(t, t0, width):
        x = np.clip((t - t0) / width, 0, 1)
        return x*x*x*(10 - 15*x + 6*x*x)

    def pos(self, t):
        A, B, w, ph = self.fig[0]
        env = np.clip(t / 3.0, 0, 1)
        x = env * A * np.sin(w*t + ph)
        y = env * B * np.sin(2*(w*t + ph))
        z = self.h0
        for i, ts in enumerate(self.step_times):
            width = 1.8 if i % 3 == 0 else 3.5   # some brisk repositioning steps
            s = self.sstep(t, ts, width)
            x += s * (self.step_x[i] - (self.step_x[i-1] if i else 0))
            y += s * (self.step_y[i] - (self.step_y[i-1] if i else 0))
            z += s * (self.step_z[i] - (self.step_z[i-1] if i else 0)) * 0.8
        if self.low_passes:
            # go down to 0.25 m (rotor) above the ground around 30 % and 75 % of the flight, and start/end low
            z0 = -0.28
            for tc in (0.0, 0.33*self.T, 0.72*self.T, self.T):
                wgt = np.exp(-((t - tc)/2.2)**2)
                z = wgt*z0 + (1-wgt)*z
        if self.fast_descent:
            # climb 9 m and descend at up to ~4.2 m/s, twice
            for tc in (0.3*self.T, 0.75*self.T):
                up = self.sstep(t, tc - 6.0, 3.0) - self.sstep(t, tc, 4.0)
                z += -9.0 * up
        return np.array([x, y, z])

    def yaw(self, t):
        y = 0.0
        for i, ts in enumerate(self.yaw_times):
            y += self.yaw_amp[i] * self.sstep(t, ts, 3.0)
        return y

    def __call__(self, t, dt=1e-3):
        p0 = self.pos(t)
        pp = self.pos(t + dt)
        pm = self.pos(t - dt)
        return p0, (pp - pm)/(2*dt), (pp - 2*p0 + pm)/dt**2, self.yaw(t)


# ---------------------------------------------------------------- controller
class Geometric:
    def __init__(self):
        f = 1.05
        self.m = TRUE["m"] / f
        self.J = TRUE["J"] * f
        self.KT = TRUE["K_T"] * f
        self.b = TRUE["b"] / f
        self.l = TRUE["l"] * f
        l, KT, b = self.l, self.KT, self.b
        # [T, Mx, My, Mz] = A @ w^2   (plus layout)
        self.A = np.array([[KT, KT, KT, KT],
                           [0, -l*KT, 0, l*KT],
                           [l*KT, 0, -l*KT, 0],
                           [-b, b, -b, b]])
        self.Ainv = np.linalg.inv(self.A)
        self.kx = self.m * np.array([1.6, 1.6, 2.5])
        self.kv = self.m * np.array([2.2, 2.2, 3.0])
        wn = 6.5
        self.kR = self.J * wn**2
        self.kW = self.J * 2 * 0.75 * wn
        self.kRz = self.J[2] * 2.0**2
        self.kWz = self.J[2] * 2 * 0.8 * 2.0
        self.wmax = 800.0

    def __call__(self, pos, vel, R, om, ref):
        pd, vd, ad, psid = ref
        ex, ev = pos - pd, vel - vd
        Fd = -self.kx*ex - self.kv*ev - self.m*G*np.array([0, 0, 1.0]) + self.m*ad   # world force wanted
        # tilt limit ~30 deg
        hor = np.linalg.norm(Fd[:2])
        lim = abs(Fd[2]) * np.tan(np.radians(25))
        if hor > lim:
            Fd[:2] *= lim / hor
        b3 = -Fd / np.linalg.norm(Fd)          # body z (down) desired... thrust along -b3
        b1c = np.array([np.cos(psid), np.sin(psid), 0])
        b2 = np.cross(b3, b1c); b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        T = -Fd @ (R @ np.array([0, 0, 1.0]))  # thrust magnitude along -body z
        eR = 0.5 * vee(Rd.T @ R - R.T @ Rd)
        kR = np.array([self.kR[0], self.kR[1], self.kRz])
        kW = np.array([self.kW[0], self.kW[1], self.kWz])
        M = -kR*eR - kW*om + np.cross(om, self.J*om)
        w2 = self.Ainv @ np.r_[T, M]
        return np.sqrt(np.clip(w2, 80.0**2, self.wmax**2))


# ---------------------------------------------------------------- flight
def fly(out, seed=1, duration=50.0, effects=None, cf_gain=0.001, mag_gain=0.01, mag_noise=0.02,
        log_commands=False, truth_path=None, low_passes=None, fast_descent=None, h0=-2.0, method="LSODA", ctrl_true_att=False, log_true_att=0.0):
    effects = effects or {}
    rng = np.random.default_rng(seed)
    if low_passes is None:
        low_passes = "ground_effect" in effects
    if fast_descent is None:
        fast_descent = "vrs" in effects
    plant = Plant(effects, T_flight=duration)
    ref = RefGen(duration, seed, h0=h0, low_passes=low_passes, fast_descent=fast_descent)
    ctrl = Geometric()
    p0, _, _, psi0 = ref(0.0)
    wh = np.sqrt(TRUE["m"]*G/(4*TRUE["K_T"]))
    s = np.zeros(plant.nx())
    s[0:3] = p0
    s[6:10] = eul2q(0, 0, psi0)
    s[13:17] = wh
    if plant.npay:
        mp, L = effects["payload"]
        s[17:20] = p0 + np.array([0, 0, L + mp*G/4000.0])
        s[13:17] = np.sqrt((TRUE["m"] + mp)*G/(4*TRUE["K_T"]))
    dtc = 1/250.0
    n = int(round(duration / dtc))
    est = np.array([0.0, 0.0, psi0])    # filter's phi, theta, psi
    gyro_noise, acc_noise, pos_noise = 0.004, 0.05, 0.003
    rows = []
    u = s[13:17].copy()
    pos_est = s[0:3] + rng.normal(0, pos_noise, 3)
    vel_est = np.zeros(3)
    for k in range(n):
        t = k*dtc
        # sensors at the tick
        R = q2R(s[6:10])
        om = s[10:13]
        gyro = om + rng.normal(0, gyro_noise, 3)
        f_true = plant.specific_force(t, s, u)
        acc = f_true + rng.normal(0, acc_noise, 3)
        # complementary filter (Euler), 250 Hz
        ph, th, ps = est
        W = np.array([[1, np.sin(ph)*np.tan(th), np.cos(ph)*np.tan(th)],
                      [0, np.cos(ph), -np.sin(ph)],
                      [0, np.sin(ph)/np.cos(th), np.cos(ph)/np.cos(th)]])
        est = est + dtc * (W @ gyro)
        ph_a = np.arctan2(-acc[1], -acc[2])
        th_a = np.arctan2(acc[0], np.hypot(acc[1], acc[2]))
        est[0] += cf_gain * wrap(ph_a - est[0])
        est[1] += cf_gain * (th_a - est[1])
        psi_true = R2eul(R)[2]
        est[2] += mag_gain * wrap(psi_true + rng.normal(0, mag_noise) - est[2])
        est[2] = wrap(est[2])
        # mocap 50 Hz -> position/velocity estimate (alpha-beta)
        if k % 5 == 0:
            meas = s[0:3] + rng.normal(0, pos_noise, 3)
            pred = pos_est + vel_est*dtc
            r_ = meas - pred
            pos_est = pred + 0.5*r_
            vel_est = vel_est + 0.5*r_/(5*dtc)*0.3
        else:
            pos_est = pos_est + vel_est*dtc
        Rest = eul2R(*est) if not ctrl_true_att else R
        u = ctrl(pos_est, vel_est, Rest, gyro, ref(t))
        # log at 100 Hz: a row at every 2.5 ticks -> log rows at t multiple of 0.01 (ticks 0, 2.5...)
        # we log on ticks that fall on 10-ms boundaries (t = 0, 0.02, ...) and in-between ones by
        # integrating to the boundary; simpler: controller 250 Hz, log rows at 100 Hz sampled from
        # the state at those instants (see below)
        t1 = (k+1)*dtc
        # sub-steps to hit every 10-ms log instant inside [t, t1)
        cuts = [t]
        for j in range(int(np.ceil(t*100 - 1e-9)), int(np.ceil(t1*100 - 1e-9))):
            tj = j/100.0
            if tj > t + 1e-12:
                cuts.append(tj)
        cuts.append(t1)
        for a, bnd in zip(cuts[:-1], cuts[1:]):
            if abs(a*100 - round(a*100)) < 1e-6:
                lest = est
                if log_true_att > 0:   # log the true attitude + white noise instead of the filter's
                    lest = np.array(R2eul(q2R(s[6:10]))) + rng.normal(0, log_true_att, 3)
                rows.append(log_row(plant, a, s, u, lest, rng, log_commands, gyro_noise, acc_noise,
                                    pos_noise, round(a*100)))
            s = step(plant, a, bnd, s, u, method)
        # safety
        if not np.all(np.isfinite(s)) or abs(s[2]) > 200:
            raise RuntimeError("diverged at t=%.2f" % t)
    write_log(out, rows)
    tr = dict(seed=seed, duration=duration, effects={k: (list(v) if isinstance(v, (list, tuple, np.ndarray)) else v)
                                                      for k, v in effects.items()},
              cf_gain=cf_gain, K_T=TRUE["K_T"], b=TRUE["b"], Kd=list(TRUE["Kd"]), tau_m=TRUE["tau_m"],
              J_r=TRUE["J_r"], m=TRUE["m"], J=list(TRUE["J"]), l=TRUE["l"], log_commands=log_commands)
    if truth_path:
        with open(truth_path, "w") as f:
            json.dump(tr, f, indent=1)
    return tr


def log_row(plant, t, s, u, est, rng, log_commands, gn, an, pn, j):
    R = q2R(s[6:10])
    om = s[10:13]
    w = u if log_commands else s[13:17] * (1 + rng.normal(0, 0.005, 4))
    f = plant.specific_force(t, s, u) + rng.normal(0, an, 3)
    g = om + rng.normal(0, gn, 3)
    pos = s[0:3] + rng.normal(0, pn, 3) if j % 2 == 0 else [np.nan]*3
    return [t, *w, *pos, *est, *g, *f], [t, *s[0:6], *R2eul(R), *om, *s[13:17], *u]


HEAD = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az"]


def write_log(path, rows):
    tru = [r[1] for r in rows]
    rows = [r[0] for r in rows]
    np.savetxt(path.replace(".csv", ".truestate.txt"), np.array(tru), fmt="%.9g",
               header="t x y z vx vy vz phi theta psi p q r w1 w2 w3 w4 c1 c2 c3 c4")
    with open(path, "w") as f:
        f.write(",".join(HEAD) + "\n")
        for r in rows:
            f.write(",".join("" if (isinstance(v, float) and np.isnan(v)) else repr(float(v)) for v in r) + "\n")


# ---------------------------------------------------------------- open loop (convention check)
def openloop(u_csv, out, x0, method="DOP853"):
    data = np.genfromtxt(u_csv, delimiter=",", names=True)
    t = data["t"]
    U = np.column_stack([data["w%d" % i] for i in range(1, 5)])
    plant = Plant({}, motors=False)
    s = np.zeros(13)
    s[0:3] = x0[0:3]
    s[6:10] = eul2q(*x0[3:6])
    s[3:6] = x0[6:9]
    s[10:13] = x0[9:12]
    rows = []
    for k in range(len(t)):
        R = q2R(s[6:10])
        rows.append([t[k], *U[k], *s[0:3], *R2eul(R), *s[10:13]])
        if k + 1 < len(t):
            sol = solve_ivp(plant.rhs, (t[k], t[k+1]), s, method=method, args=(U[k],), rtol=1e-11, atol=1e-12)
            s = sol.y[:, -1]
            s[6:10] /= np.linalg.norm(s[6:10])
    with open(out, "w") as f:
        f.write("t,w1,w2,w3,w4,x,y,z,phi,theta,psi,p,q,r\n")
        for r in rows:
            f.write(",".join(repr(float(v)) for v in r) + "\n")


def airframe(path, guess=True, mass=None, J=None, name="heavy3kg_plus"):
    J = TRUE["J"] if J is None else J
    m = TRUE["m"] if mass is None else mass
    f = (1.3, 0.7, 0.7) if guess else (1, 1, 1)
    Kd = TRUE["Kd"] * f[2]
    with open(path, "w") as fh:
        fh.write(f"""[airframe]
name = "{name}"
mass = {m}
inertia = [{J[0]}, {J[1]}, {J[2]}]
arm_length = {TRUE['l']}
layout = "plus"
rotor_inertia = {TRUE['J_r']}
gravity = {G}

[parameters]
K_T = {TRUE['K_T']*f[0]:.6e}
b = {TRUE['b']*f[1]:.6e}
Kd = [{Kd[0]:.4f}, {Kd[1]:.4f}, {Kd[2]:.4f}]
""")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd")
    a = sub.add_parser("flight"); a.add_argument("out"); a.add_argument("--seed", type=int, default=1)
    a.add_argument("--duration", type=float, default=50); a.add_argument("--effects", default="{}")
    a.add_argument("--cf-gain", type=float, default=0.001); a.add_argument("--log-commands", action="store_true")
    a.add_argument("--truth"); a.add_argument("--method", default="LSODA")
    o = sub.add_parser("openloop"); o.add_argument("u"); o.add_argument("out"); o.add_argument("--x0", required=True)
    o.add_argument("--method", default="DOP853")
    f = sub.add_parser("airframe"); f.add_argument("out"); f.add_argument("--true", action="store_true")
    args = ap.parse_args()
    if args.cmd == "flight":
        fly(args.out, args.seed, args.duration, json.loads(args.effects), args.cf_gain, log_commands=args.log_commands,
            truth_path=args.truth, method=args.method)
    elif args.cmd == "openloop":
        openloop(args.u, args.out, np.array([float(v) for v in args.x0.split(",")]), args.method)
    elif args.cmd == "airframe":
        airframe(args.out, guess=not args.true)

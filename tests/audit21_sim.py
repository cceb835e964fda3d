"""Independent Crazyflie-scale quadrotor simulator writing NanoBench-like CSV logs.

Written by a twenty-first blind audit on 2026-12-05 (a helper session that read only the
README, the contract and docs/VALIDATION.md, no greybox source), kept as it ran; the cases
of its generators are :data:`CASES`, written by :func:`flights`.

World z-up (ENU-like), body FLU, as in the NanoBench files.  Own RK4 at 1 kHz,
cascaded position -> geometric attitude controller at 500 Hz, Crazyflie X mixer,
PWM -> rotor speed map depending on battery voltage, first-order motor lag,
spring-damper ground contact, optional effects (weak spin pair, rotor drag at hubs,
ground effect).  Logs at 100 Hz with Vicon/IMU noise; PWM columns refreshed every
12 ms (~83 Hz) and held on the 100 Hz grid.
"""
import json
import numpy as np

G = 9.81
A_MAP, C_MAP = 0.04076521, 380.8359      # Foerster 2015 map (at V_REF)
V_REF = 4.0

# Crazyflie X layout, FLU body: M1 front-right, M2 back-right, M3 back-left, M4 front-left
def rotor_positions(arm):
    a = arm / np.sqrt(2.0)
    return np.array([[a, -a, 0.0], [-a, -a, 0.0], [-a, a, 0.0], [a, a, 0.0]])

# reaction torque on the body about body +z (UP): M1, M3 spin CCW seen from above ->
# body reacts CW (negative about up); M2, M4 spin CW -> positive.  (= greybox FRD spin +1,-1,+1,-1)
SPIN_UP = np.array([-1.0, 1.0, -1.0, 1.0])


def quat_mul(q, r):
    w0, x0, y0, z0 = q
    w1, x1, y1, z1 = r
    return np.array([w0*w1 - x0*x1 - y0*y1 - z0*z1,
                     w0*x1 + x0*w1 + y0*z1 - z0*y1,
                     w0*y1 - x0*z1 + y0*w1 + z0*x1,
                     w0*z1 + x0*y1 - y0*x1 + z0*w1])


def quat_to_R(q):
    w, x, y, z = q
    return np.array([[1-2*(y*y+z*z), 2*(x*y-w*z), 2*(x*z+w*y)],
                     [2*(x*y+w*z), 1-2*(x*x+z*z), 2*(y*z-w*x)],
                     [2*(x*z-w*y), 2*(y*z+w*x), 1-2*(x*x+y*y)]])


def quat_to_euler_zyx(q):
    w, x, y, z = q
    roll = np.arctan2(2*(w*x + y*z), 1 - 2*(x*x + y*y))
    pitch = np.arcsin(np.clip(2*(w*y - z*x), -1, 1))
    yaw = np.arctan2(2*(w*z + x*y), 1 - 2*(y*y + z*z))
    return roll, pitch, yaw


def vee(M):
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


class Truth:
    def __init__(self, **kw):
        self.mass = 0.031
        self.arm = 0.046
        self.J = np.array([1.4e-5, 1.4e-5, 2.2e-5])
        self.K_T = 2.2e-8
        self.b = 2.2e-8 * 0.008
        self.Kd_body = np.array([0.010, 0.010, 0.015])  # N s/m, body frame linear drag
        self.tau_m = 0.030
        self.k_vbat = 0.0          # w = w_map(PWM) * (1 + k_vbat*(V - V_REF))
        self.v_start = 4.02
        self.v_end = 3.98
        self.v_load_drop = 0.0     # V drop proportional to mean normalised rotor speed^2
        self.gain = np.ones(4)     # per-rotor thrust AND torque factor
        self.k_hub = 0.0           # hub drag N s/m/(rad/s), horizontal, at hub (rotor plane)
        self.k_ge = 0.0            # ground effect m^2 (Cheeseman-Bennett-like, per rotor)
        self.floor_z = 0.029       # world z of the floor
        self.rest_z = 0.054        # CoG / rotor plane height at rest
        self.__dict__.update(kw)
        self.r = rotor_positions(self.arm)

    def to_json(self):
        d = {}
        for k, v in self.__dict__.items():
            d[k] = v.tolist() if isinstance(v, np.ndarray) else v
        return d


def battery(truth, t, T_total, load):
    return truth.v_start + (truth.v_end - truth.v_start) * t / T_total - truth.v_load_drop * load


def pwm_to_w(pwm, V, truth):
    w = np.where(pwm > 0, A_MAP * pwm + C_MAP, 0.0)
    return w * (1.0 + truth.k_vbat * (V - V_REF))


def deriv(s, pwm, V, truth):
    p, v, q, om, w = s[0:3], s[3:6], s[6:10], s[10:13], s[13:17]
    R = quat_to_R(q)
    wss = pwm_to_w(pwm, V, truth)
    wdot = (wss - w) / truth.tau_m
    wp = np.maximum(w, 0.0)
    T = truth.K_T * truth.gain * wp**2
    # ground effect per rotor
    if truth.k_ge > 0:
        hub_w = p[None, :] + (R @ truth.r.T).T
        h = np.maximum(hub_w[:, 2] - truth.floor_z, 1e-3)
        ratio = np.minimum(truth.k_ge / h**2, 0.5)
        T = T / (1.0 - ratio)
    F_b = np.array([0.0, 0.0, T.sum()])
    tau = np.zeros(3)
    for i in range(4):
        tau += np.cross(truth.r[i], np.array([0.0, 0.0, T[i]]))
    tau[2] += np.sum(SPIN_UP * truth.b * truth.gain * wp**2)
    vb = R.T @ v
    F_b = F_b - truth.Kd_body * vb
    if truth.k_hub > 0:
        for i in range(4):
            vi = vb + np.cross(om, truth.r[i])
            Fi = -truth.k_hub * wp[i] * np.array([vi[0], vi[1], 0.0])
            F_b = F_b + Fi
            tau += np.cross(truth.r[i], Fi)
    F_w = R @ F_b + np.array([0.0, 0.0, -truth.mass * G])
    # ground contact (spring-damper at the CoG, friction, levelling torque)
    pen = (truth.rest_z + 0.001) - p[2]
    tau_c = np.zeros(3)
    if pen > 0:
        fz = 300.0 * pen - 3.0 * v[2]
        fz = max(fz, 0.0)
        F_w = F_w + np.array([-0.6 * v[0], -0.6 * v[1], fz])
        rpy = quat_to_euler_zyx(q)
        tau_c = np.array([-0.05 * rpy[0] - 1.5e-3 * om[0], -0.05 * rpy[1] - 1.5e-3 * om[1], -2e-4 * om[2]])
    pdot = v
    vdot = F_w / truth.mass
    qdot = 0.5 * quat_mul(q, np.array([0.0, *om]))
    J = truth.J
    omdot = (tau + tau_c - np.cross(om, J * om)) / J
    return np.concatenate([pdot, vdot, qdot, omdot, wdot])


class Controller:
    """Cascaded PID position -> geometric attitude controller with integrators, nominal model."""
    def __init__(self, mass, J, K_T, b, arm):
        self.m, self.J, self.K_T, self.kappa = mass, J, K_T, b / K_T
        a = arm / np.sqrt(2.0)
        A = np.array([[1, 1, 1, 1], [-a, -a, a, a], [-a, a, a, -a], SPIN_UP * self.kappa])
        self.Ainv = np.linalg.inv(A)
        self.ip = np.zeros(3)
        self.iatt = np.zeros(3)

    def __call__(self, dt, pm, vm, qm, omm, pr, vr, ar, yaw_r, active):
        if not active:
            self.ip[:] = 0
            self.iatt[:] = 0
            return np.zeros(4), np.zeros(4)
        ep = pr - pm
        ev = vr - vm
        self.ip += ep * dt
        self.ip = np.clip(self.ip, -0.5, 0.5)
        kp = np.array([6.0, 6.0, 8.0]); kv = np.array([4.0, 4.0, 5.0]); ki = np.array([1.0, 1.0, 4.0])
        acc = ar + kp * ep + kv * ev + ki * self.ip
        f = self.m * (acc + np.array([0, 0, G]))
        R = quat_to_R(qm)
        Tcol = max(f @ R[:, 2], 0.05)
        zb = f / np.linalg.norm(f)
        xc = np.array([np.cos(yaw_r), np.sin(yaw_r), 0.0])
        yb = np.cross(zb, xc); yb /= np.linalg.norm(yb)
        xb = np.cross(yb, zb)
        Rd = np.column_stack([xb, yb, zb])
        eR = 0.5 * vee(Rd.T @ R - R.T @ Rd)
        self.iatt += eR * dt
        self.iatt = np.clip(self.iatt, -0.3, 0.3)
        KR = np.array([500.0, 500.0, 120.0]); Kw = np.array([36.0, 36.0, 18.0]); KI = np.array([300.0, 300.0, 150.0])
        tau = self.J * (-KR * eR - Kw * omm - KI * self.iatt)
        Ti = self.Ainv @ np.array([Tcol, *tau])
        Ti = np.maximum(Ti, 0.0)
        wd = np.sqrt(Ti / self.K_T)
        pwm = np.clip((wd - C_MAP) / A_MAP, 1000.0, 65535.0)
        return pwm, np.array([Tcol, *tau])


def smoothstep(x):
    x = np.clip(x, 0, 1)
    return x**3 * (10 - 15 * x + 6 * x * x)


def run(truth, traj, T_total, seed, out_csv, truth_json, meta=None,
        noise_pos=0.001, noise_att=0.002, noise_acc=0.003, noise_gyro=0.003,
        ctrl_err=None, pwm_log_period=0.012, ctrl_every=2):
    """traj(t) -> (p_ref, v_ref, a_ref, yaw_ref, motors_on)"""
    rng = np.random.default_rng(seed)
    dt = 0.001
    nsteps = int(round(T_total / dt))
    ce = dict(mass=0.030, K_T=2.0e-8, b=2.0e-8 * 0.006)
    if ctrl_err: ce.update(ctrl_err)
    ctrl = Controller(ce['mass'], np.array([1.5e-5, 1.5e-5, 2.4e-5]), ce['K_T'], ce['b'], 0.046)
    s = np.zeros(17)
    s[0:3] = [0.0, 0.0, truth.rest_z]
    s[6:10] = [1.0, 0.0, 0.0, 0.0]
    pwm = np.zeros(4)
    pwm_logged = np.zeros(4)
    ctrl_out = np.zeros(4)
    w_hover = np.sqrt(truth.mass * G / (4 * truth.K_T))
    rows = []
    t0_unix = 1772419726.251343966
    next_pwm_log = 0.0
    gyro_bias = rng.normal(0, 0.0, 3)
    for k in range(nsteps + 1):
        t = k * dt
        load = float(np.mean((s[13:17] / w_hover)**2)) if np.any(s[13:17] > 1) else 0.0
        V = battery(truth, t, T_total, load)
        if k % ctrl_every == 0:  # controller at 500 Hz (default) on noisy measurements
            pm = s[0:3] + rng.normal(0, noise_pos, 3)
            vm = s[3:6] + rng.normal(0, 0.01, 3)
            dq = np.array([1.0, *rng.normal(0, noise_att / 2, 3)]); dq /= np.linalg.norm(dq)
            qm = quat_mul(s[6:10], dq)
            omm = s[10:13] + rng.normal(0, noise_gyro, 3)
            pr, vr, ar, yr, on = traj(t)
            if on:
                pwm, ctrl_out = ctrl(ctrl_every * dt, pm, vm, qm, omm, pr, vr, ar, yr, True)
            else:
                pwm, ctrl_out = ctrl(ctrl_every * dt, pm, vm, qm, omm, pr, vr, ar, yr, False)
        if t >= next_pwm_log - 1e-9:
            pwm_logged = pwm.copy()
            next_pwm_log += pwm_log_period
        if k % 10 == 0:  # log at 100 Hz
            p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
            R = quat_to_R(q)
            a_world = deriv(s, pwm, V, truth)[3:6]
            f_spec = R.T @ (a_world + np.array([0, 0, G])) / 9.80665
            dq = np.array([1.0, *rng.normal(0, noise_att / 2, 3)]); dq /= np.linalg.norm(dq)
            qn = quat_mul(q, dq)
            if qn[0] < 0: qn = -qn
            roll, pitch, yaw = quat_to_euler_zyx(qn)
            pn = p + rng.normal(0, noise_pos, 3)
            pr, vr, ar, yr, on = traj(t)
            rows.append([t0_unix + t, *pn, qn[1], qn[2], qn[3], qn[0],
                         np.degrees(roll), np.degrees(pitch), np.degrees(yaw),
                         *(v + rng.normal(0, 0.01, 3)), *(R @ om + rng.normal(0, 0.01, 3)),
                         *(f_spec + rng.normal(0, noise_acc, 3)),
                         *(om + gyro_bias + rng.normal(0, noise_gyro, 3)),
                         *pwm_logged,
                         *(p + rng.normal(0, 0.003, 3)), *(v + rng.normal(0, 0.02, 3)),
                         *(a_world + rng.normal(0, 0.05, 3)),
                         np.degrees(roll), np.degrees(pitch), np.degrees(yaw), qn[1], qn[2], qn[3], qn[0],
                         *pr, np.degrees(yr), *ctrl_out[1:], float(np.mean(pwm)),
                         V + rng.normal(0, 0.005)])
        if k == nsteps:
            break
        # RK4
        k1 = deriv(s, pwm, V, truth)
        k2 = deriv(s + 0.5 * dt * k1, pwm, V, truth)
        k3 = deriv(s + 0.5 * dt * k2, pwm, V, truth)
        k4 = deriv(s + dt * k3, pwm, V, truth)
        s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
    header = ("t,px,py,pz,qx,qy,qz,qw,roll,pitch,yaw,vx,vy,vz,wx_vicon,wy_vicon,wz_vicon,"
              "imu_acc_x,imu_acc_y,imu_acc_z,imu_gyro_x,imu_gyro_y,imu_gyro_z,"
              "motor_motor_m1,motor_motor_m2,motor_motor_m3,motor_motor_m4,"
              "est_stateEstimate_x,est_stateEstimate_y,est_stateEstimate_z,"
              "est_stateEstimate_vx,est_stateEstimate_vy,est_stateEstimate_vz,"
              "est_stateEstimate_ax,est_stateEstimate_ay,est_stateEstimate_az,"
              "att_stateEstimate_roll,att_stateEstimate_pitch,att_stateEstimate_yaw,"
              "att_stateEstimate_qx,att_stateEstimate_qy,att_stateEstimate_qz,att_stateEstimate_qw,"
              "sp_ctrltarget_x,sp_ctrltarget_y,sp_ctrltarget_z,sp_ctrltarget_yaw,"
              "pid_controller_roll,pid_controller_pitch,pid_controller_yaw,pid_controller_cmd_thrust,pwr_pm_vbat")
    arr = np.array(rows)
    with open(out_csv, "w") as f:
        f.write(header + "\n")
        for r in arr:
            f.write("%.9f," % r[0] + ",".join("%.9f" % x for x in r[1:]) + "\n")
    d = truth.to_json()
    d["seed"] = seed
    d["duration"] = T_total
    d["controller_nominal"] = ce
    d["pwm_map_at_VREF"] = [A_MAP, C_MAP]
    d["V_REF"] = V_REF
    d["hover_w"] = float(w_hover)
    d["b_over_KT"] = truth.b / truth.K_T
    # greybox-convention equivalents
    d["greybox_equiv"] = {
        "frame": "greybox FRD: M1..M4 spins +1,-1,+1,-1; floor 2.5 cm below resting rotor plane",
        "Kd_world_approx": truth.Kd_body.tolist(),
        "K_T_dev_if_gain": (truth.gain / truth.gain.mean() - 1).tolist()[:3],
        "K_T_mean_gain": float(truth.K_T * truth.gain.mean()),
        "k_rdh": truth.k_hub, "k_rdv": 0.0, "h_hub": 0.0,
        "k_ge": truth.k_ge, "tau_m": truth.tau_m, "K_vbat": truth.k_vbat,
    }
    if meta: d.update(meta)
    with open(truth_json, "w") as f:
        json.dump(d, f, indent=1)
    return arr


# ---------- trajectories ----------
def make_traj(shape, T_total, speed=1.0, z_fly=1.0, low_hover=None, t_rest=1.5, seed=0):
    """Rest, take-off, shape, landing, rest.  low_hover=(z, duration) inserts a low hover after take-off."""
    t_on = t_rest
    t_up = 2.0
    z0 = 0.054
    t_land = 2.5
    t_off = T_total - t_rest
    t_ld0 = t_off - t_land - 0.3
    lh = low_hover
    t_shape0 = t_on + t_up + 1.0 + (lh[1] + 3.0 if lh else 0.0)
    t_shape1 = t_ld0 - 1.0
    Ts = t_shape1 - t_shape0
    R = 0.6

    def shape_pos(tau):
        # tau: time since shape start; envelope to ramp in/out
        env = smoothstep(tau / 2.0) * smoothstep((Ts - tau) / 2.0)
        if shape == "circle":
            om = speed / R
            p = np.array([R * np.sin(om * tau), R * (1 - np.cos(om * tau)) - 0.0, 0.1 * np.sin(0.7 * tau)])
            p[1] -= 0.0
        elif shape == "figure8":
            om = speed / 0.9
            p = np.array([0.7 * np.sin(om * tau), 0.4 * np.sin(2 * om * tau), 0.15 * np.sin(0.5 * tau)])
        elif shape == "ramp":
            # back and forth along x with increasing speed, plus y
            ph = 0.25 * tau + 0.02 * tau**2
            p = np.array([0.8 * np.sin(ph * speed * 1.4), 0.3 * np.sin(0.6 * ph), 0.2 * np.sin(0.4 * tau)])
        elif shape == "lissajous":
            om = speed / 0.8
            p = np.array([0.7 * np.sin(om * tau), 0.5 * np.sin(1.5 * om * tau + 0.5), 0.15 * np.sin(0.9 * tau)])
        elif shape == "oval":
            om = speed / 0.7
            p = np.array([0.8 * np.sin(om * tau), 0.45 * (1 - np.cos(om * tau)), 0.12 * np.sin(1.1 * tau)])
        return env * p

    def traj(t):
        on = (t >= t_on) and (t < t_off)
        yaw = 0.0
        if t < t_on:
            z = z0
        elif t < t_on + t_up:
            z = z0 + (z_fly - z0) * smoothstep((t - t_on) / t_up) if not lh else z0 + (lh[0] - z0) * smoothstep((t - t_on) / t_up)
        else:
            z = z_fly if not lh else None
        p = np.array([0.0, 0.0, 0.0])
        if lh and t >= t_on + t_up:
            tl = t - (t_on + t_up)
            if tl < lh[1] + 1.0:
                z = lh[0]
            elif tl < lh[1] + 3.0:
                z = lh[0] + (z_fly - lh[0]) * smoothstep((tl - lh[1] - 1.0) / 2.0)
            else:
                z = z_fly
        if t >= t_shape0 and t < t_shape1:
            p = shape_pos(t - t_shape0)
            yaw = 0.3 * np.sin(0.4 * (t - t_shape0)) * smoothstep((t - t_shape0) / 2) * smoothstep((t_shape1 - t) / 2)
        if t >= t_ld0:
            z = z_fly + (z0 - 0.03 - z_fly) * smoothstep((t - t_ld0) / t_land)
        pr = np.array([p[0], p[1], z + p[2]])
        return pr, None, None, yaw, on

    def traj_full(t, h=1e-3):
        pr, _, _, yaw, on = traj(t)
        p1 = traj(t + h)[0]; p0 = traj(t - h)[0]
        vr = (p1 - p0) / (2 * h)
        ar = (p1 - 2 * pr + p0) / h**2
        return pr, vr, ar, yaw, on
    return traj_full, dict(t_on=t_on, t_off=t_off, t_shape0=t_shape0, t_shape1=t_shape1, shape=shape, speed=speed)


# ---------- the audit's cases (gen_case*.py), written into a folder ----------
CASES = {
    # nothing beyond the rigid body: motor lag 30 ms, mild battery sag
    "control": (dict(k_vbat=0.15, v_start=4.02, v_end=3.98),
                ("figure8", 1.0, 32.0, 101, None), ("circle", 0.8, 28.0, 102, None)),
    # the two clockwise rotors (M2, M4) 8 % weaker in thrust and yaw torque per w^2
    "weak_pair": (dict(k_vbat=0.15, v_start=4.02, v_end=3.98, gain=np.array([1.0, 0.92, 1.0, 0.92])),
                  ("lissajous", 0.9, 32.0, 201, None), ("oval", 1.0, 28.0, 202, None)),
    # strong battery sag 4.1 -> 3.45 V: the speed per PWM falls with the voltage
    "battery": (dict(k_vbat=0.15, v_start=4.10, v_end=3.45, v_load_drop=0.05),
                ("figure8", 1.0, 36.0, 301, None), ("circle", 1.0, 30.0, 302, None)),
    # horizontal rotor drag at each hub, k w_i (v_b + om x r_i)_xy
    "hub_drag": (dict(k_vbat=0.15, v_start=4.02, v_end=3.98, k_hub=1.3e-6, Kd_body=np.array([0.003, 0.003, 0.015])),
                 ("oval", 1.3, 32.0, 401, None), ("figure8", 1.2, 28.0, 402, None)),
    # per-rotor ground effect and a low hover
    "ground": (dict(k_vbat=0.15, v_start=4.02, v_end=3.98, k_ge=8.0e-5),
               ("circle", 0.9, 36.0, 501, (0.054 + 0.035, 4.0)), ("ramp", 0.8, 34.0, 502, (0.054 + 0.03, 3.0))),
}
"""``case: (truth keywords, estimation flight, validation flight)``, a flight
``(shape, speed, duration, seed, low_hover)``: the audit's ``gen_case1..5.py``."""


def flights(folder, case):
    """Write the case's estimation and validation flights (NanoBench CSV) and their truth
    JSON into ``folder`` (the audit's files, bit for bit): ``((est, val), truth)``, paths as
    strings and the estimation flight's truth as a dict."""
    from pathlib import Path
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    truth_kw, *specs = CASES[case]
    paths = []
    for (shape, speed, T, seed, low_hover), part in zip(specs, ("est", "val")):
        traj, info = make_traj(shape, T, speed=speed, low_hover=low_hover, seed=seed)
        meta = dict(info)
        meta["low_hover"] = low_hover
        csv, tj = folder / f"{case}_{part}.csv", folder / f"{case}_{part}.truth.json"
        run(Truth(**truth_kw), traj, T, seed, str(csv), str(tj), meta=meta)
        paths.append(str(csv))
    return tuple(paths), json.loads((folder / f"{case}_est.truth.json").read_text())

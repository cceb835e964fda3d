#!/usr/bin/env python
"""Independent H-frame quadrotor simulator of a blind audit (2026-12-04, the twelfth), kept as a
test generator that is not greybox's own: written from ``CONTRACT.md`` and the README alone,
without reading the package, and checked against ``greybox simulate --integrator cvodes`` (4 s
open loop; 3.7e-7 m, 2.2e-8 rad, also with wind plus a CoG offset and with quadratic drag).

numpy + scipy ``solve_ivp`` only. State (own choices): position NED (3), world velocity (3),
unit quaternion body->world (scalar first, 4), body rates FRD (3), actual rotor speeds (4) -> 17
states. An H-frame, 2.2 kg: front hubs at x = +0.16 m, y = +-0.20; rear ones at x = -0.14,
y = +-0.24 (so its rear rotors hover harder); 25-ms motors; a 400-Hz cascade (position P,
velocity PI, attitude P, rate PID with a 30-Hz derivative filter) on a noisy estimate with a 5 %
wrong mixer. The log: 200 Hz; the rotors' actual speeds as ESC telemetry (12 RPM jitter,
10 RPM steps), except on ``motor_lag`` (the commands logged, the motors 40 ms behind); position at
50 Hz with 5 mm noise, dropouts and two outages; attitude, gyro, accelerometer; ``vbat`` per cell
on ``battery``.

Usage:
  python hframe_sim.py openloop --inputs U.csv --out Y.csv [--kd ...]   (verification, no motor dynamics)
  python hframe_sim.py flight --effect NAME --seed N --duration T --out LOG.csv [--truth T.json] [--accel]
     NAME in: none, motor_lag, battery, quad_drag, wind, cog, ground
"""
import argparse, json, sys
import numpy as np
from scipy.integrate import solve_ivp

G = 9.81
# ---------------- vehicle truth ----------------
MASS = 2.2
J = np.diag([0.030, 0.022, 0.048])
JINV = np.linalg.inv(J)
# H frame: front rotors x=+0.16, y=+-0.20; rear x=-0.14, y=+-0.24
# order like greybox "x": 1 front-right, 2 back-left, 3 front-left, 4 back-right
ROTORS = np.array([[0.16, 0.20, 0.0],
                   [-0.14, -0.24, 0.0],
                   [0.16, -0.20, 0.0],
                   [-0.14, 0.24, 0.0]])
SPIN = np.array([+1.0, +1.0, -1.0, -1.0])
K_T = 1.5e-5      # N/(rad/s)^2
B_YAW = 2.4e-7    # N m/(rad/s)^2
J_R = 2.0e-5      # rotor inertia kg m^2
KD = np.array([0.25, 0.25, 0.35])   # world-frame linear drag N s/m
PROP_R = 0.127    # 10 inch prop radius


def default_truth():
    return dict(mass=MASS, K_T=K_T, b=B_YAW, J_r=J_R, Kd=KD.tolist(),
                Kq_body=[0.0, 0.0, 0.0], wind=[0.0, 0.0], r_cog=[0.0, 0.0],
                ground=False, ground_z=0.0, prop_R=PROP_R,
                tau_motor=0.025, log_command=False,
                battery=False, c_vbat=0.0)


def airframe_toml(K_T: float = 1.0e-5, b: float = 3.4e-7, Kd=(0.1, 0.1, 0.1)) -> str:
    """The airframe as a user would write it for greybox (``[[rotor]]`` tables in the order of
    ``ROTORS``); the default parameters are a spec sheet's guesses, 30-70 % off the truth."""
    rotors = "".join(f"\n[[rotor]]\nposition = [{x!r}, {y!r}, {z!r}]\nspin = {int(s)}\n"
                     for (x, y, z), s in zip(ROTORS.tolist(), SPIN))
    return (f'[airframe]\nname = "hframe_audit12"\nmass = {MASS!r}\n'
            f"inertia = [{float(J[0, 0])!r}, {float(J[1, 1])!r}, {float(J[2, 2])!r}]\nrotor_inertia = {J_R!r}\n{rotors}\n"
            f"[parameters]\nK_T = {K_T!r}\nb = {b!r}\nKd = [{', '.join(repr(float(k)) for k in Kd)}]\n")


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
    return np.array([cr * cp * cy + sr * sp * sy,
                     sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy])


def R_to_euler(R):
    # R = Rz(psi) Ry(theta) Rx(phi)
    th = -np.arcsin(np.clip(R[2, 0], -1, 1))
    phi = np.arctan2(R[2, 1], R[2, 2])
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, th, psi


def rotor_thrusts(w, pos, R, tr, t, vbat):
    T = tr['K_T'] * w ** 2
    if tr['battery']:
        # own form: thrust coefficient follows the battery's per-cell voltage (thrust only)
        T = T * (1.0 + tr['c_vbat'] * (vbat - 4.0))
    if tr['ground']:
        # Cheeseman-Bennett per rotor, own code, hub heights in the CoG plane
        arms = ROTORS - np.array([tr['r_cog'][0], tr['r_cog'][1], 0.0])
        zr = pos[2] + (R @ arms.T)[2]
        h = np.maximum(tr['ground_z'] - zr, 1e-3)
        kk = (tr['prop_R'] / 4.0) ** 2 / h ** 2
        T = T / (1.0 - np.minimum(kk, 0.5))
    return T


def forces_torques(t, s, w, tr, vbat):
    pos, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
    q = q / np.linalg.norm(q)
    R = quat_to_R(q)
    T = rotor_thrusts(w, pos, R, tr, t, vbat)
    arms = ROTORS - np.array([tr['r_cog'][0], tr['r_cog'][1], 0.0])
    F_b = np.array([0.0, 0.0, -T.sum()])
    vair = v - np.array([tr['wind'][0], tr['wind'][1], 0.0])
    F_w = R @ F_b + MASS * G * np.array([0, 0, 1.0]) - np.asarray(tr['Kd']) * vair
    kq = np.asarray(tr['Kq_body'])
    if np.any(kq):
        vb = R.T @ vair
        F_w = F_w + R @ (-kq * np.linalg.norm(vb) * vb)
    tau = np.zeros(3)
    for i in range(4):
        tau += np.cross(arms[i], np.array([0.0, 0.0, -T[i]]))
    tau[2] += tr['b'] * np.sum(SPIN * w ** 2)
    Om_r = np.sum(SPIN * w)
    tau += tr['J_r'] * Om_r * np.cross(om, np.array([0, 0, 1.0]))
    return F_w, tau, R, T


def rhs(t, s, wcmd, tr, vbat_fn, motors=True):
    w = s[13:17] if motors else wcmd
    vbat = vbat_fn(t, s) if vbat_fn is not None else 4.0
    F_w, tau, R, _ = forces_torques(t, s, w, tr, vbat)
    q = s[6:10]
    om = s[10:13]
    dq = 0.5 * np.array([
        -q[1] * om[0] - q[2] * om[1] - q[3] * om[2],
        q[0] * om[0] + q[2] * om[2] - q[3] * om[1],
        q[0] * om[1] - q[1] * om[2] + q[3] * om[0],
        q[0] * om[2] + q[1] * om[1] - q[2] * om[0]])
    # keep the quaternion on the unit sphere
    dq += -0.5 * (q @ q - 1.0) * q * 10.0
    dom = JINV @ (tau - np.cross(om, J @ om))
    ds = np.zeros(17)
    ds[0:3] = s[3:6]
    ds[3:6] = F_w / MASS
    ds[6:10] = dq
    ds[10:13] = dom
    if motors:
        ds[13:17] = (wcmd - s[13:17]) / tr['tau_motor']
    return ds


# ---------------- open loop verification ----------------
def openloop(args):
    import pandas as pd
    U = pd.read_csv(args.inputs)
    tr = default_truth()
    if args.kd:
        tr['Kd'] = [float(x) for x in args.kd.split(',')]
    tr['K_T'] = args.kt
    tr['b'] = args.b
    tr['J_r'] = args.jr
    if args.wind:
        tr['wind'] = [float(x) for x in args.wind.split(',')]
    if args.cog:
        tr['r_cog'] = [float(x) for x in args.cog.split(',')]
    if args.kq:
        tr['Kq_body'] = [float(x) for x in args.kq.split(',')]
    t = U['t'].values
    W = U[['w1', 'w2', 'w3', 'w4']].values
    s = np.zeros(17)
    s[6] = 1.0
    if args.x0:
        x0 = [float(v) for v in args.x0.split(',')]
        s[0:3] = x0[0:3]
        s[6:10] = euler_to_quat(*x0[3:6])
        s[3:6] = x0[6:9]
        s[10:13] = x0[9:12]
    out = []
    for k in range(len(t)):
        R = quat_to_R(s[6:10] / np.linalg.norm(s[6:10]))
        phi, th, psi = R_to_euler(R)
        out.append([t[k], *W[k], *s[0:3], phi, th, psi, *s[10:13]])
        if k == len(t) - 1:
            break
        sol = solve_ivp(rhs, (t[k], t[k + 1]), s, args=(W[k], tr, None, False),
                        method='DOP853', rtol=1e-11, atol=1e-12)
        s = sol.y[:, -1]
    cols = ['t', 'w1', 'w2', 'w3', 'w4', 'x', 'y', 'z', 'phi', 'theta', 'psi', 'p', 'q', 'r']
    pd.DataFrame(out, columns=cols).to_csv(args.out, index=False, float_format='%.10g')


# ---------------- closed loop flight ----------------
ALLOC = None


def allocation(KT, b):
    # rows: total thrust, roll torque, pitch torque, yaw torque ; columns w_i^2
    A = np.zeros((4, 4))
    for i in range(4):
        A[0, i] = KT
        A[1, i] = -ROTORS[i, 1] * KT      # tau_x = y*(-T)
        A[2, i] = ROTORS[i, 0] * KT       # tau_y = -x*(-T) = x T
        A[3, i] = SPIN[i] * b
    return A


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def make_reference(rng, duration, effect):
    """Piecewise setpoint schedule: list of (t_start, kind, params). Returns a function
    t -> (p_ref, v_ff, psi_ref)."""
    segs = []
    t = 0.0
    home = np.array([0.0, 0.0, -1.5])
    kinds = ['hover', 'step_x', 'step_y', 'circle', 'fast', 'step_z', 'yaw', 'fig8']
    if effect == 'ground':
        kinds = kinds + ['low', 'low']
    if effect == 'quad_drag':
        kinds = kinds + ['fast', 'fast']
    if effect == 'motor_lag':
        kinds = kinds + ['yaw', 'step_y']
    seq = [kinds[i] for i in rng.permutation(len(kinds))]
    # always start with a short hover
    seq = ['hover'] + seq
    if effect == 'ground' and seq.count('low') < 3:
        seq.insert(2, 'low')
    i = 0
    while t < duration:
        kind = seq[i % len(seq)]
        i += 1
        dur = {'hover': 3.0, 'step_x': 4.0, 'step_y': 4.0, 'circle': 7.0, 'fast': 5.0,
               'step_z': 4.0, 'yaw': 4.0, 'fig8': 8.0, 'low': 6.0}[kind]
        par = dict(amp=rng.uniform(0.8, 1.5) * rng.choice([-1, 1]),
                   rad=rng.uniform(1.2, 2.0), spd=rng.uniform(2.0, 3.5),
                   dist=rng.uniform(4.0, 6.0), ang=rng.uniform(0, 2 * np.pi),
                   yaw=rng.uniform(0.6, 1.4) * rng.choice([-1, 1]),
                   lowh=rng.uniform(0.14, 0.22))
        segs.append((t, dur, kind, par))
        t += dur
    return segs, home


def ref_at(segs, home, t):
    """Raw (unfiltered) setpoint: position, velocity feed-forward, yaw."""
    for (t0, dur, kind, par) in segs:
        if t0 <= t < t0 + dur:
            break
    tau = t - t0
    p = home.copy()
    v = np.zeros(3)
    psi = 0.0
    if kind == 'step_x':
        p[0] += par['amp'] if tau > 0.3 else 0.0
    elif kind == 'step_y':
        p[1] += par['amp'] if tau > 0.3 else 0.0
    elif kind == 'step_z':
        p[2] += 0.6 * np.sign(par['amp']) if tau > 0.3 else 0.0
    elif kind == 'yaw':
        psi = par['yaw'] if tau < 2.0 else -0.5 * par['yaw']
    elif kind == 'circle':
        om = par['spd'] / par['rad']
        ramp = min(1.0, tau / 1.5) * min(1.0, max(0.0, (dur - tau) / 1.5))
        a = om * tau
        p[0] += ramp * par['rad'] * np.sin(a)
        p[1] += ramp * par['rad'] * (1 - np.cos(a))
        v[0] = ramp * par['spd'] * np.cos(a)
        v[1] = ramp * par['spd'] * np.sin(a)
    elif kind == 'fig8':
        om = 0.9
        ramp = min(1.0, tau / 1.5) * min(1.0, max(0.0, (dur - tau) / 1.5))
        p[0] += ramp * 1.8 * np.sin(om * tau)
        p[1] += ramp * 1.0 * np.sin(2 * om * tau)
        p[2] += ramp * 0.3 * np.sin(om * tau)
        v[0] = ramp * 1.8 * om * np.cos(om * tau)
        v[1] = ramp * 2.0 * om * np.cos(2 * om * tau)
        v[2] = ramp * 0.3 * om * np.cos(om * tau)
        psi = 0.4 * np.sin(0.5 * om * tau)
    elif kind == 'fast':
        d = par['dist']
        u = np.array([np.cos(par['ang']), np.sin(par['ang']), 0.0])
        # go out and back, speed-limited by the controller's clip
        if tau < dur / 2:
            p = home + u * d / 2
        else:
            p = home - u * d / 2
    elif kind == 'low':
        p[2] = -par['lowh'] if tau > 0.3 else home[2]
        if 0.5 < tau < 4.5:
            p[2] = -par['lowh']
        else:
            p[2] = -par['lowh'] if tau <= 4.5 else home[2]
        p[0] += 0.3 * np.sin(0.8 * tau)   # slow drift while low
    return p, v, psi


def flight(args):
    rng = np.random.default_rng(args.seed)
    tr = default_truth()
    eff = args.effect
    if eff == 'motor_lag':
        tr['tau_motor'] = 0.040
        tr['log_command'] = True
    elif eff == 'battery':
        tr['battery'] = True
        tr['c_vbat'] = 0.18
    elif eff == 'quad_drag':
        tr['Kq_body'] = [0.045, 0.055, 0.08]
    elif eff == 'wind':
        tr['wind'] = [1.6, -1.1]
    elif eff == 'cog':
        tr['r_cog'] = [0.008, -0.007]
    elif eff == 'ground':
        tr['ground'] = True
    elif eff != 'none':
        raise SystemExit('unknown effect ' + eff)

    dt_c = 1 / 400.0
    n_c = int(round(args.duration / dt_c))
    segs, home = make_reference(rng, args.duration, eff)

    # battery model (per-cell volts): open circuit falls over the flight, load sag
    V0 = args.v0
    def vbat_fn(t, s):
        w = s[13:17]
        load = np.sum(w ** 2) / (4 * 600.0 ** 2)
        return V0 - 0.0075 * t - 0.12 * (load - 1.0)

    # controller nominal (the vehicle's own tuning: 5 % off true K_T, b)
    KTn, bn = tr['K_T'] * 1.05, tr['b'] * 0.95
    A = allocation(KTn, bn)
    Ainv = np.linalg.inv(A)
    wmin, wmax = 150.0, 1000.0

    s = np.zeros(17)
    s[0:3] = home
    s[6] = 1.0
    w_h = np.sqrt(np.linalg.solve(allocation(tr['K_T'], tr['b']), np.array([MASS * G, 0, 0, 0])))
    s[13:17] = w_h
    wcmd = w_h.copy()

    # controller state
    vi = np.zeros(3)
    ri = np.zeros(3)
    d_filt = np.zeros(3)
    prev_rerr = np.zeros(3)
    pf = home.copy(); pfd = np.zeros(3)     # 2nd order setpoint filter
    psif = 0.0
    # estimator noise (a noisy state estimate; slowly wandering + white)
    est_bias = np.zeros(6)

    log = []
    for k in range(n_c + 1):
        t = k * dt_c
        R = quat_to_R(s[6:10] / np.linalg.norm(s[6:10]))
        phi, th, psi = R_to_euler(R)
        # ---- log at 200 Hz (every 2nd control tick), before this tick's command ----
        if k % 2 == 0:
            F_w, tau_b, _, _ = forces_torques(t, s, s[13:17], tr, vbat_fn(t, s))
            acc_w = F_w / MASS
            f_spec = R.T @ (acc_w - G * np.array([0, 0, 1.0]))
            log.append(dict(t=t, w=(wcmd.copy() if tr['log_command'] else s[13:17].copy()),
                            pos=s[0:3].copy(), eul=(phi, th, psi), om=s[10:13].copy(),
                            acc=f_spec, vbat=vbat_fn(t, s)))
        if k == n_c:
            break
        # ---- noisy state estimate ----
        est_bias = 0.995 * est_bias + 0.1 * np.sqrt(1 - 0.995 ** 2) * rng.standard_normal(6) * np.array([0.01, 0.01, 0.01, 0.03, 0.03, 0.03])
        p_e = s[0:3] + est_bias[0:3] + 0.002 * rng.standard_normal(3)
        v_e = s[3:6] + est_bias[3:6] + 0.02 * rng.standard_normal(3)
        phi_e = phi + 0.002 * rng.standard_normal()
        th_e = th + 0.002 * rng.standard_normal()
        psi_e = psi + 0.004 * rng.standard_normal()
        om_e = s[10:13] + 0.01 * rng.standard_normal(3)
        # ---- reference, filtered ----
        pr, vff, psir = ref_at(segs, home, t)
        wn = 2.2
        pfdd = wn * wn * (pr - pf) - 2 * wn * pfd
        pfd = pfd + dt_c * pfdd
        pf = pf + dt_c * pfd
        psif = psif + dt_c * 2.0 * wrap(psir - psif)
        # ---- position P -> velocity PI ----
        v_des = 1.6 * (pf - p_e) + 0.6 * pfd + vff
        hs = np.linalg.norm(v_des[:2])
        if hs > 5.0:
            v_des[:2] *= 5.0 / hs
        v_des[2] = np.clip(v_des[2], -2.0, 1.5)
        ev = v_des - v_e
        vi = np.clip(vi + dt_c * ev, -3, 3)
        a_des = np.array([3.2, 3.2, 4.5]) * ev + np.array([0.8, 0.8, 1.5]) * vi
        f = MASS * (a_des - G * np.array([0, 0, 1.0]))     # desired force (world), thrust = -f along b3
        b3 = -f / np.linalg.norm(f)
        tilt = np.arccos(np.clip(b3[2], -1, 1))
        if tilt > 0.6:
            # limit tilt to ~35 deg
            h = np.linalg.norm(b3[:2])
            b3 = np.array([b3[0] / h * np.sin(0.6), b3[1] / h * np.sin(0.6), np.cos(0.6)])
        # collective: desired force projected on the current thrust axis (-z_b)
        T_cmd = -f @ (R @ np.array([0, 0, 1.0]))
        T_cmd = np.clip(T_cmd, 0.3 * MASS * G, 2.2 * MASS * G)
        # body z axis in the yaw frame: [cos(phi) sin(th), -sin(phi), cos(phi) cos(th)] = b3
        cps, sps = np.cos(psif), np.sin(psif)
        bx = cps * b3[0] + sps * b3[1]
        by = -sps * b3[0] + cps * b3[1]
        phi_d = np.arcsin(np.clip(-by, -1, 1))
        th_d = np.arctan2(bx, b3[2])
        # ---- attitude P -> rate PID ----
        e_att = np.array([phi_d - phi_e, th_d - th_e, wrap(psif - psi_e)])
        rate_des = np.array([7.0, 7.0, 3.5]) * e_att
        rate_des = np.clip(rate_des, -4, 4)
        rerr = rate_des - om_e
        ri = np.clip(ri + dt_c * rerr, -0.5, 0.5)
        dr = (rerr - prev_rerr) / dt_c
        prev_rerr = rerr
        alpha = dt_c / (dt_c + 1 / (2 * np.pi * 30.0))     # D-term low pass 30 Hz
        d_filt = d_filt + alpha * (dr - d_filt)
        kp = np.array([14.0, 14.0, 6.0]); ki = np.array([8.0, 8.0, 3.0]); kdg = np.array([0.25, 0.25, 0.0])
        alpha_des = kp * rerr + ki * ri + kdg * d_filt
        tau_cmd = J @ alpha_des + np.cross(om_e, J @ om_e)
        tau_cmd[2] = np.clip(tau_cmd[2], -0.3, 0.3)
        w2 = Ainv @ np.array([T_cmd, *tau_cmd])
        wcmd = np.sqrt(np.clip(w2, wmin ** 2, wmax ** 2))
        # ---- integrate the plant over one control period ----
        sol = solve_ivp(rhs, (t, t + dt_c), s, args=(wcmd, tr, vbat_fn, True),
                        method='RK45', rtol=1e-8, atol=1e-9)
        s = sol.y[:, -1]
        if s[2] > tr['ground_z'] - 0.03:
            raise SystemExit(f'crashed into ground at t={t:.2f}')
    write_log(args, log, tr, rng)


def write_log(args, log, tr, rng):
    import pandas as pd
    n = len(log)
    t = np.array([r['t'] for r in log])
    W = np.array([r['w'] for r in log])
    P = np.array([r['pos'] for r in log])
    E = np.array([r['eul'] for r in log])
    O = np.array([r['om'] for r in log])
    Acc = np.array([r['acc'] for r in log])
    V = np.array([r['vbat'] for r in log])
    # ESC RPM telemetry: rad/s -> RPM, jitter, quantised to 10 RPM (eRPM/7 pole pairs ~ 70 eRPM), back to rad/s
    rpm = W * 60 / (2 * np.pi) + rng.normal(0, 1, W.shape) * args.rpm_jitter
    if args.rpm_quant > 0:
        rpm = np.round(rpm / args.rpm_quant) * args.rpm_quant
    Wlog = rpm * 2 * np.pi / 60
    # attitude & gyro 200 Hz
    Em = E + rng.normal(0, 1, E.shape) * np.array([0.0025, 0.0025, 0.006])
    Em[:, 2] = wrap(Em[:, 2])
    Om = O + rng.normal(0, 0.012, O.shape)
    Am = Acc + rng.normal(0, 0.08, Acc.shape)
    # mocap/GNSS-like positions 50 Hz (every 4th row), 5 mm noise, dropouts
    Pm = np.full(P.shape, np.nan)
    idx = np.arange(0, n, 4)
    keep = rng.random(len(idx)) > 0.03
    Pm[idx[keep]] = P[idx[keep]] + rng.normal(0, 0.005, (keep.sum(), 3))
    # two outages of 0.2-0.5 s
    for _ in range(2):
        t0 = rng.uniform(2, t[-1] - 2)
        L = rng.uniform(0.2, 0.5)
        Pm[(t >= t0) & (t < t0 + L)] = np.nan
    df = pd.DataFrame(dict(t=np.round(t, 6)))
    for i in range(4):
        df[f'w{i+1}'] = Wlog[:, i]
    for j, c in enumerate('xyz'):
        df[c] = Pm[:, j]
    for j, c in enumerate(['phi', 'theta', 'psi']):
        df[c] = Em[:, j]
    for j, c in enumerate('pqr'):
        df[c] = Om[:, j]
    if args.accel:
        for j, c in enumerate(['ax', 'ay', 'az']):
            df[c] = Am[:, j]
    if tr['battery']:
        df['vbat'] = np.round(V + rng.normal(0, 0.004, n), 3)
    df.to_csv(args.out, index=False, float_format='%.7g', na_rep='')
    if args.truth:
        tr2 = dict(tr)
        tr2.update(effect=args.effect, seed=args.seed, duration=args.duration,
                   inertia=np.diag(J).tolist(), rotors=ROTORS.tolist(), spin=SPIN.tolist(),
                   noise=dict(pos=0.005, att=[0.0025, 0.0025, 0.006], gyro=0.012, acc=0.08,
                              rpm_jitter=args.rpm_jitter, rpm_quant=args.rpm_quant),
                   min_height=float(-(P[:, 2]).min()) if False else float((-P[:, 2]).min()),
                   max_speed=float(np.max(np.linalg.norm(np.diff(P, axis=0) / np.diff(t)[:, None], axis=1))),
                   max_tilt_deg=float(np.degrees(np.max(np.abs(E[:, :2])))))
        if tr['battery']:
            tr2['vbat_range'] = [float(V.min()), float(V.max())]
        json.dump(tr2, open(args.truth, 'w'), indent=1)
    print(f'wrote {args.out}: {n} rows, min height {(-P[:,2]).min():.3f} m, '
          f'max tilt {np.degrees(np.abs(E[:, :2]).max()):.1f} deg, w range {W.min():.0f}-{W.max():.0f}')


if __name__ == '__main__':
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest='cmd', required=True)
    o = sub.add_parser('openloop')
    o.add_argument('--inputs', required=True); o.add_argument('--out', required=True)
    o.add_argument('--kt', type=float, default=K_T); o.add_argument('--b', type=float, default=B_YAW)
    o.add_argument('--jr', type=float, default=J_R); o.add_argument('--kd', default=None)
    o.add_argument('--wind', default=None); o.add_argument('--cog', default=None)
    o.add_argument('--kq', default=None); o.add_argument('--x0', default=None)
    f = sub.add_parser('flight')
    f.add_argument('--effect', default='none'); f.add_argument('--seed', type=int, default=0)
    f.add_argument('--duration', type=float, default=40.0); f.add_argument('--out', required=True)
    f.add_argument('--truth', default=None); f.add_argument('--accel', action='store_true')
    f.add_argument('--rpm-jitter', type=float, default=12.0); f.add_argument('--v0', type=float, default=4.15); f.add_argument('--rpm-quant', type=float, default=10.0)
    a = ap.parse_args()
    openloop(a) if a.cmd == 'openloop' else flight(a)

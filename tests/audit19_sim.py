"""A nineteenth blind audit's simulator and its writers of real log formats, kept as the audit
wrote them (its files were in /tmp/audit19: sim.py, writers.py, usd.py; written by a helper
session that read only the README and the contract): a 30 g Crazyflie-like X quadrotor, RK4 at
1 ms, a cascaded geometric controller, a first-order motor lag on the rotor speed, flights
written as NanoBench CSV (ENU/FLU, degrees, g, PWM held at 80-88 Hz on 100 Hz rows) and as
Crazyflie uSD v2 binary logs (1 kHz, the controller at 500 Hz). :func:`nanobench_flight` and
:func:`usd_flight` regenerate the audit's flights bit for bit from their seeds.

Conventions (the contract's): world NED, body FRD, R = Rz(psi) Ry(theta) Rx(phi); rotor i
thrust K_T w_i^2 along body -z at r_i; reaction torque spin_i b w_i^2 about body +z; linear
drag -Kd v (world). Crazyflie order M1 front-right, M2 back-right, M3 back-left, M4
front-left, spin [+1, -1, +1, -1]; w_cmd = A_PWM PWM + C_PWM (0: stopped).
"""
import struct
import zlib

import numpy as np

A_PWM, C_PWM = 0.04076521, 380.8359
G = 9.81
TRUTH = dict(mass=0.030, J=[1.395e-5, 1.436e-5, 2.173e-5], arm=0.046,
             K_T=1.3e-8, b=7.8e-11, Kd=[0.012, 0.012, 0.018], tau_m=0.0)
a_ = 0.046 / np.sqrt(2)
RPOS = np.array([[a_, a_, 0], [-a_, a_, 0], [-a_, -a_, 0], [a_, -a_, 0]])
SPIN = np.array([1., -1., 1., -1.])
Z_REST = -0.054   # NED z of the body at rest (pz = 0.054 m up)

def quat_to_R(q):
    w, x, y, z = q
    return np.array([[1-2*(y*y+z*z), 2*(x*y-w*z), 2*(x*z+w*y)],
                     [2*(x*y+w*z), 1-2*(x*x+z*z), 2*(y*z-w*x)],
                     [2*(x*z-w*y), 2*(y*z+w*x), 1-2*(x*x+y*y)]])

def R_to_quat(R):
    tr = np.trace(R)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2; w = 0.25*s
        x = (R[2,1]-R[1,2])/s; y = (R[0,2]-R[2,0])/s; z = (R[1,0]-R[0,1])/s
    elif R[0,0] > R[1,1] and R[0,0] > R[2,2]:
        s = np.sqrt(1.0+R[0,0]-R[1,1]-R[2,2])*2; w = (R[2,1]-R[1,2])/s; x = 0.25*s
        y = (R[0,1]+R[1,0])/s; z = (R[0,2]+R[2,0])/s
    elif R[1,1] > R[2,2]:
        s = np.sqrt(1.0+R[1,1]-R[0,0]-R[2,2])*2; w = (R[0,2]-R[2,0])/s
        x = (R[0,1]+R[1,0])/s; y = 0.25*s; z = (R[1,2]+R[2,1])/s
    else:
        s = np.sqrt(1.0+R[2,2]-R[0,0]-R[1,1])*2; w = (R[1,0]-R[0,1])/s
        x = (R[0,2]+R[2,0])/s; y = (R[1,2]+R[2,1])/s; z = 0.25*s
    q = np.array([w, x, y, z]); return q/np.linalg.norm(q)*np.sign(w if w != 0 else 1)

def euler_zyx(R):
    phi = np.arctan2(R[2,1], R[2,2]); theta = -np.arcsin(np.clip(R[2,0], -1, 1)); psi = np.arctan2(R[1,0], R[0,0])
    return phi, theta, psi

def Rzyx(phi, th, psi):
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)
    Rz = np.array([[cp,-sp,0],[sp,cp,0],[0,0,1]]); Ry = np.array([[ct,0,st],[0,1,0],[-st,0,ct]])
    Rx = np.array([[1,0,0],[0,cf,-sf],[0,sf,cf]]); return Rz@Ry@Rx

PWM_MAP = None   # None: Crazyflie (PWM 0..65535, Förster map, 0 = stopped); else dict(a, c, lo, hi, off)

def pwm_to_w(pwm):
    pwm = np.asarray(pwm, float)
    if PWM_MAP is None: return np.where(pwm > 0, A_PWM*pwm + C_PWM, 0.0)
    return np.where(pwm >= PWM_MAP['lo'], PWM_MAP['a']*pwm + PWM_MAP['c'], 0.0)

def w_to_pwm(w):
    if PWM_MAP is None: return np.clip(np.round((w - C_PWM)/A_PWM), 0, 65535)
    return np.clip(np.round((w - PWM_MAP['c'])/PWM_MAP['a']), PWM_MAP['lo'], PWM_MAP['hi'])

def pwm_off():
    return np.zeros(4) if PWM_MAP is None else np.full(4, float(PWM_MAP['off']))

class Quad:
    def __init__(self, P, vbat_gain=0.0):
        self.P = P; self.J = np.diag(P['J']); self.Jinv = np.linalg.inv(self.J)
        self.Kd = np.array(P['Kd']); self.vbat_gain = vbat_gain

    def deriv(self, s, wcmd, vbat=None):
        P = self.P
        pos, v, q, om, w = s[0:3], s[3:6], s[6:10], s[10:13], s[13:17]
        R = quat_to_R(q)
        we = w if P['tau_m'] > 0 else wcmd
        T = P['K_T']*we**2
        F = R @ np.array([0, 0, -T.sum()]) - self.Kd*v + np.array([0, 0, P['mass']*G])
        tau = np.cross(RPOS, np.c_[np.zeros(4), np.zeros(4), -T]).sum(0) + np.array([0, 0, (SPIN*P['b']*we**2).sum()])
        domg = self.Jinv @ (tau - np.cross(om, self.J@om))
        wx, wy, wz = om
        Om = np.array([[0,-wx,-wy,-wz],[wx,0,wz,-wy],[wy,-wz,0,wx],[wz,wy,-wx,0]])
        dq = 0.5*Om@q
        dw = (wcmd - w)/P['tau_m'] if P['tau_m'] > 0 else np.zeros(4)
        return np.concatenate([v, F/P['mass'], dq, domg, dw]), F/P['mass'], R

class Controller:
    """Cascaded PID in NED: position -> accel -> attitude -> rates -> torques -> mixer."""
    def __init__(self, P):
        self.P = P; self.iz = 0.0
        M = np.zeros((4, 4))
        for i in range(4):
            M[0, i] = 1.0; M[1, i] = -RPOS[i, 1]; M[2, i] = RPOS[i, 0]; M[3, i] = SPIN[i]*P['b']/P['K_T']
        self.Minv = np.linalg.inv(M)   # [T, tx, ty, tz] = M @ thrusts
    def __call__(self, s, ref, dt, airborne):
        P = self.P; pos, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        pr, vr, ar, psir = ref
        if airborne: self.iz += (pr[2]-pos[2])*dt
        acc = ar + 6.0*(pr-pos) + 4.5*(vr-v) + np.array([0, 0, 1.0*self.iz])
        acc[:2] = np.clip(acc[:2], -4, 4)
        fdes = P['mass']*(acc - np.array([0, 0, G]))        # desired force (world), thrust = -fdes along body z
        R = quat_to_R(q); zb_des = -fdes/np.linalg.norm(fdes)
        xc = np.array([np.cos(psir), np.sin(psir), 0]); yb = np.cross(zb_des, xc); yb /= np.linalg.norm(yb)
        xb = np.cross(yb, zb_des); Rd = np.c_[xb, yb, zb_des]
        Tcmd = -fdes @ (R @ np.array([0, 0, 1.0]))*(-1)    # projection on current body -z
        Tcmd = max(fdes @ -(R@np.array([0,0,1.0])), 0.0)
        eR = 0.5*np.array([ (Rd.T@R - R.T@Rd)[2,1], (Rd.T@R - R.T@Rd)[0,2], (Rd.T@R - R.T@Rd)[1,0]])
        kR = np.array([90., 90., 25.]); kw = np.array([14., 14., 8.])
        J = np.diag(P['J'])
        tau = J@(-kR*eR - kw*om) + np.cross(om, J@om)
        th = self.Minv @ np.r_[Tcmd, tau]
        th = np.clip(th, 0, None)
        w = np.sqrt(th/P['K_T'])
        return w_to_pwm(w)

def reference(t, t0=2.0, t_land=None, amp=0.8, freq=0.12, yaw_amp=0.5, hz=1.0, yaw0=0.0):
    """Take off at t0 to height hz (NED z=-hz), lissajous, descend from t_land."""
    def p(tt):
        if tt < t0: return np.array([0, 0, Z_REST + 0.02]), (yaw0 if yaw0 else 0.0)
        h = Z_REST + (-hz - Z_REST)*min((tt-t0)/2.0, 1.0)
        s = max(tt - t0 - 2.0, 0.0); e = min(s/2.0, 1.0)
        if t_land is not None and tt > t_land:
            h = -hz + (Z_REST + 0.15 + hz)*min((tt - t_land)/2.5, 1.0)
            if tt > t_land + 2.5: h = Z_REST + 0.15 - 0.4*(tt - t_land - 2.5)
            e = max(0.0, 1 - (tt - t_land)/1.0)*e
        xy = e*amp*np.array([np.sin(2*np.pi*freq*s), np.sin(2*np.pi*2*freq*s)*0.7])
        yw = e*yaw_amp*np.sin(2*np.pi*0.15*s)
        return np.array([xy[0], xy[1], h]), (yaw0 + yw) if yaw0 else yw
    d = 1e-3; p0, y0 = p(t); p1, _ = p(t+d); pm, _ = p(t-d)
    return p0, (p1-pm)/(2*d), np.clip((p1-2*p0+pm)/d**2, -3, 3), y0

def vbat_true(t, pwm):
    """Battery voltage (V): slow discharge plus a load sag with the mean command."""
    return 4.25 - 0.02*t - 0.3*np.mean(pwm)/65535.0

def simulate(P, T, ctrl_times, dt=1e-3, t0=2.0, t_land=None, ref_kw={}, K_vbat=0.0):
    """Returns dict of arrays at every 1-ms step; ctrl_times: controller update instants."""
    quad = Quad(P); ctl = Controller(P)
    n = int(round(T/dt)) + 1
    s = np.zeros(17); s[2] = Z_REST; s[6] = 1.0
    if ref_kw.get('yaw0', 0.0): s[6:10] = R_to_quat(Rzyx(0, 0, ref_kw['yaw0']))
    ctrl_idx = set(int(round(tc/dt)) for tc in ctrl_times)
    pwm = pwm_off(); vbat = vbat_true(0.0, pwm); out = {k: [] for k in ['t','s','pwm','wcmd','spf','ground','vbat']}
    on_ground = True; landed = False; last_ctrl_t = 0.0
    for k in range(n):
        t = k*dt
        if k in ctrl_idx:
            ref = reference(t, t0=t0, t_land=t_land, **ref_kw)
            if landed or t < t0 - 0.5: pwm = pwm_off()
            else: pwm = ctl(s, ref, t - last_ctrl_t, not on_ground)
            last_ctrl_t = t
            vbat = vbat_true(t, pwm)
        wcmd = pwm_to_w(pwm)*(1 + K_vbat*(vbat - 4.0))
        d, spf_acc, R = quad.deriv(s, wcmd)
        # specific force in body FRD: R^T (a - g e3)
        out['t'].append(t); out['s'].append(s.copy()); out['pwm'].append(pwm.copy()); out['wcmd'].append(wcmd.copy())
        out['spf'].append(R.T @ (spf_acc - np.array([0, 0, G]))); out['ground'].append(on_ground); out['vbat'].append(vbat)
        if k == n-1: break
        # RK4
        k1, _, _ = quad.deriv(s, wcmd); k2, _, _ = quad.deriv(s + dt/2*k1, wcmd)
        k3, _, _ = quad.deriv(s + dt/2*k2, wcmd); k4, _, _ = quad.deriv(s + dt*k3, wcmd)
        sn = s + dt/6*(k1 + 2*k2 + 2*k3 + k4); sn[6:10] /= np.linalg.norm(sn[6:10])
        if on_ground:
            if sn[2] < Z_REST - 1e-6 and sn[5] < 0: on_ground = False
            else:
                sn[0:2] = s[0:2]; sn[2] = Z_REST; sn[3:6] = 0; sn[6:10] = s[6:10]; sn[10:13] = 0
        elif sn[2] >= Z_REST and sn[5] > 0 and t > t0 + 3:
            on_ground = True; landed = True; sn[2] = Z_REST; sn[3:6] = 0; sn[10:13] = 0
            phi, th, psi = euler_zyx(quat_to_R(sn[6:10])); sn[6:10] = R_to_quat(Rzyx(0, 0, psi))
        s = sn
    # fix ground spf: on ground the reaction force cancels gravity+thrust
    res = {k: np.array(v) for k, v in out.items()}
    for i in np.where(res['ground'])[0]:
        R = quat_to_R(res['s'][i, 6:10]); res['spf'][i] = R.T @ np.array([0, 0, -G])
    return res


# ------------------------------------------------------------------ uSD format

def read_usd(path):
    data = open(path, 'rb').read()
    assert data[0] == 0xBC, "magic"
    crc_ok = (zlib.crc32(data[:-4]) & 0xffffffff) == struct.unpack('<I', data[-4:])[0]
    version, nev = struct.unpack('<HH', data[1:5])
    idx = 5; evs = {}; out = {}
    for _ in range(nev):
        eid, = struct.unpack('<H', data[idx:idx+2]); idx += 2
        end = data.index(b'\0', idx); name = data[idx:end].decode(); idx = end + 1
        nv, = struct.unpack('<H', data[idx:idx+2]); idx += 2
        fmt = '<'; vars_ = []
        for _ in range(nv):
            end = data.index(b'\0', idx); s = data[idx:end].decode(); idx = end + 1
            vars_.append(s[:-3]); fmt += s[-2]
        evs[eid] = (name, fmt, struct.calcsize(fmt), vars_)
        out[name] = {v: [] for v in ['timestamp'] + vars_}
    while idx < len(data) - 4:
        if version == 1:
            eid, ts = struct.unpack('<HI', data[idx:idx+6]); idx += 6
        else:
            eid, ts = struct.unpack('<HQ', data[idx:idx+10]); idx += 10; ts = ts / 1000.0
        name, fmt, nb, vars_ = evs[eid]
        vals = struct.unpack(fmt, data[idx:idx+nb]); idx += nb
        for v, d in zip(vars_, vals): out[name][v].append(d)
        out[name]['timestamp'].append(ts)
    return {k: {v: np.array(a) for v, a in d.items()} for k, d in out.items()}, version, crc_ok

def write_usd(path, event_name, columns, t_us, version=2, event_id=0, corrupt_crc=False):
    """columns: list of (name, typechar, array). t_us: uint64 microsecond timestamps."""
    b = bytearray([0xBC]) + struct.pack('<HH', version, 1)
    b += struct.pack('<H', event_id) + event_name.encode() + b'\0' + struct.pack('<H', len(columns))
    fmt = '<'
    for name, tc, _ in columns:
        b += f"{name}({tc})".encode() + b'\0'; fmt += tc
    arrs = [a for _, _, a in columns]
    for k in range(len(t_us)):
        if version == 1:
            b += struct.pack('<HI', event_id, int(t_us[k] // 1000))
        else:
            b += struct.pack('<HQ', event_id, int(t_us[k]))
        b += struct.pack(fmt, *[a[k] for a in arrs])
    crc = zlib.crc32(bytes(b)) & 0xffffffff
    if corrupt_crc: crc ^= 0xdeadbeef
    b += struct.pack('<I', crc)
    open(path, 'wb').write(bytes(b))


# ------------------------------------------------------------------ writers

NB_COLS = "t,px,py,pz,qx,qy,qz,qw,roll,pitch,yaw,vx,vy,vz,wx_vicon,wy_vicon,wz_vicon,imu_acc_x,imu_acc_y,imu_acc_z,imu_gyro_x,imu_gyro_y,imu_gyro_z,motor_motor_m1,motor_motor_m2,motor_motor_m3,motor_motor_m4,est_stateEstimate_x,est_stateEstimate_y,est_stateEstimate_z,est_stateEstimate_vx,est_stateEstimate_vy,est_stateEstimate_vz,est_stateEstimate_ax,est_stateEstimate_ay,est_stateEstimate_az,att_stateEstimate_roll,att_stateEstimate_pitch,att_stateEstimate_yaw,att_stateEstimate_qx,att_stateEstimate_qy,att_stateEstimate_qz,att_stateEstimate_qw,sp_ctrltarget_x,sp_ctrltarget_y,sp_ctrltarget_z,sp_ctrltarget_yaw,pid_controller_roll,pid_controller_pitch,pid_controller_yaw,pid_controller_cmd_thrust,pwr_pm_vbat".split(',')
FLIP = np.diag([1., -1., -1.])   # NED<->ENU and FRD<->FLU (rotation of pi about x)
G0 = 9.80665

def fresh_rows(n, rng, dt=0.01):
    f = rng.uniform(80, 88); ev = np.cumsum(rng.uniform(0.9, 1.1, size=int(n*dt*f*1.3)+10)/f)
    idx = np.unique(np.ceil(ev/dt - 1e-9).astype(int)); idx = idx[idx < n]
    return np.r_[0, idx] if idx[0] != 0 else idx

def nanobench_rows(res, rng, stride=10, t_unix0=1772419726.251343966, angle_unit='deg',
                   noise=dict(pos=3e-4, att=1.5e-3, gyro=0.02, acc=0.01), ref_kw={}, t0=2.0, t_land=None, vbat_from_sim=False):
    s = res['s'][::stride]; spf = res['spf'][::stride]; pwm = res['pwm'][::stride]; tt = res['t'][::stride]
    n = len(tt); rows = []
    vbat_fresh = 4.15 - 0.025*tt + rng.normal(0, 0.004, n)
    if vbat_from_sim: vbat_fresh = res['vbat'][::stride] + rng.normal(0, 0.004, n)
    vb = vbat_fresh.copy()
    for k in range(n):
        if k % 10: vb[k] = vb[k-1]
    for k in range(n):
        R = quat_to_R(s[k, 6:10])
        # small attitude noise
        dth = rng.normal(0, noise['att'], 3); R = R @ Rzyx(*dth)
        Renu = FLIP @ R @ FLIP
        qw, qx, qy, qz = R_to_quat(Renu)
        rpy = np.array(euler_zyx(Renu)); rpy_out = np.degrees(rpy) if angle_unit == 'deg' else rpy
        p_enu = FLIP @ s[k, 0:3] + rng.normal(0, noise['pos'], 3)
        v_enu = FLIP @ s[k, 3:6]
        om_flu = FLIP @ s[k, 10:13]
        w_world_enu = Renu @ om_flu
        acc_g = FLIP @ spf[k] / G0 + rng.normal(0, noise['acc'], 3)
        gyro = om_flu + rng.normal(0, noise['gyro'], 3)
        ref = reference(tt[k], t0=t0, t_land=t_land, **ref_kw)
        sp = FLIP @ ref[0]
        rows.append([t_unix0 + tt[k] + rng.normal(0, 2e-7)] + list(p_enu) + [qx, qy, qz, qw] + list(rpy_out)
                    + list(v_enu) + list(w_world_enu) + list(acc_g) + list(gyro) + list(pwm[k])
                    + list(p_enu) + list(v_enu) + [0, 0, 0] + list(np.degrees(rpy)) + [qx, qy, qz, qw]
                    + list(sp) + [-ref[3], 0, 0, 0, float(np.mean(pwm[k])), vb[k]])
    return rows

def write_csv(path, rows, cols=NB_COLS, drop=None):
    keep = [i for i, c in enumerate(cols) if c != drop]
    with open(path, 'w', newline='') as f:
        f.write(','.join(cols[i] for i in keep) + '\n')
        for r in rows:
            f.write(','.join(('%.9f' % r[i]) if isinstance(r[i], (float, np.floating)) else str(r[i]) for i in keep) + '\n')

def write_usd_flight(path, res, rng, noise=dict(gyro=0.3, acc=0.005), version=2, t_us0=26333702):
    """1 kHz fixedFrequency: acc.x/y/z (g, FLU), gyro.x/y/z (deg/s, FLU), motor.m1..m4 (PWM, uint32)."""
    spf = res['spf']; om = res['s'][:, 10:13]; pwm = res['pwm']; n = len(res['t'])
    acc = (spf @ FLIP.T)/G0 + rng.normal(0, noise['acc'], (n, 3))
    gyro = np.degrees(om @ FLIP.T) + rng.normal(0, noise['gyro'], (n, 3))
    t_us = t_us0 + np.round(res['t']*1e6).astype(np.int64) + rng.integers(-5, 6, n)
    cols = [('acc.x', 'f', acc[:, 0]), ('acc.y', 'f', acc[:, 1]), ('acc.z', 'f', acc[:, 2]),
            ('gyro.x', 'f', gyro[:, 0]), ('gyro.y', 'f', gyro[:, 1]), ('gyro.z', 'f', gyro[:, 2])] + \
           [(f'motor.m{i+1}', 'I', pwm[:, i].astype(np.int64)) for i in range(4)]
    write_usd(path, 'fixedFrequency', cols, t_us, version=version, event_id=0xffff)


# ------------------------------------------------------------------ the audit's generators

def nanobench_flight(path, seed: int, tau: float = 0.0, K_vbat: float = 0.0) -> dict:
    """gen_nanobench.py NAME SEED [tau_m] {} [K_vbat]: a 22-s flight (take-off at 2 s, landing
    from 16 s), the controller at the fresh rows; returns the truth."""
    rng = np.random.default_rng(seed)
    P = dict(TRUTH)
    P['tau_m'] = tau
    T = 22.0
    n = int(T / 0.01) + 1
    fr = fresh_rows(n, rng)
    res = simulate(P, T, fr * 0.01, t0=2.0, t_land=16.0, ref_kw={}, K_vbat=K_vbat)
    rows = nanobench_rows(res, rng, t_land=16.0, ref_kw={}, vbat_from_sim=K_vbat != 0)
    write_csv(str(path), rows)
    return dict(P, K_vbat=K_vbat)


def usd_flight(path, seed: int, tau: float) -> dict:
    """gen_usd.py NAME SEED TAU_M: a 20-s uSD v2 log (take-off at 2 s, landing from 14 s), the
    controller at 500 Hz; returns the truth."""
    rng = np.random.default_rng(seed)
    P = dict(TRUTH)
    P['tau_m'] = tau
    T = 20.0
    res = simulate(P, T, np.arange(0, T, 0.002), t0=2.0, t_land=14.0)
    write_usd_flight(str(path), res, rng)
    return P

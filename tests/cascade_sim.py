"""Independent quadrotor simulator of a blind audit (2026-12-05, the sixteenth), kept as a
test generator that is not greybox's own: written from ``README.md`` and ``CONTRACT.md``
alone, without reading the package, and checked against ``greybox simulate`` to 3e-12 m/rad
(rk4) and 7.6e-8 (cvodes) before any diagnosis. A 1.2 kg "x" quadrotor, its 30-ms motors in
the state, scipy DOP853 between the ticks of a 400 Hz cascaded PID with integrators (its own
model 5 % off); 200 Hz rows of ESC speeds (actual speeds at the row instant, 0.3 % noise,
rounded to 1 rad/s), motion capture at 100 Hz. The audit's ``sim.py`` and ``gen.py`` in one
module, pandas replaced by :func:`write_csv`; the physics and numbers are the audit's.

The audit's description:
Independent quadrotor flight simulator for a blind audit of greybox (audit16).

Written from /work/main/README.md + /work/shared/CONTRACT.md only; no greybox code read.

Physics (true state, integrated by scipy solve_ivp DOP853, rtol 1e-9 / atol 1e-10, between
400 Hz controller ticks; the controller command is held over each tick):
  state s = [p(3) NED world, v(3) world, q(4) unit quaternion body->world (w,x,y,z),
             omega(3) body FRD, w_act(4) actual rotor speeds]
  dp/dt = v
  m dv/dt = R F_b + m g e3 - Kd * (v - wind) + F_hub(world)         (NED, z down)
     F_b = sum_i [0, 0, -T_i],  T_i = K_T w_i^2  (or thrust_curve: K_T w^2 (1+k_Tw(w/w_h-1))
             written as a w^2 + c w^3)
  dq/dt = 0.5 q (x) [0, omega]
  J domega/dt = sum_i r_i x [0,0,-T_i] + sum_i spin_i b w_i^2 e_z
                + J_r Omega_r (omega x e_z)  (Omega_r = sum spin_i w_i)  - omega x J omega
                + hub drag torques
  dw_act/dt = (w_target - w_act)/tau_m,  tau_m = 30 ms  (true motor lag)
  Layout "x": r1 (+a,+a,0) spin+1, r2 (-a,-a,0) +1, r3 (+a,-a,0) -1, r4 (-a,+a,0) -1.
  Rotor spin-up reaction torque (J_r dw/dt about z) is NOT modelled (greybox's convention
  has none either).

Controller (400 Hz): cascaded position P -> velocity PI (+ feed-forward) -> thrust vector,
geometric attitude P -> rate PID, with its own model 5 % off (mass +5 %, inertia -5 %,
K_T +5 %, arm -5 %, b -5 %). Flies on the true state + noise (1 mm pos, 2 cm/s vel,
2 mrad attitude, 5 mrad/s gyro). Tilt limited to 25 deg, speed commands to 3 m/s.

Logging (200 Hz rows): rotor speeds = actual speeds at the row instant x (1 + 0.3 % noise),
rounded to 1 rad/s; mocap position at 100 Hz (every other row, 1 mm noise; others empty);
attitude (ZYX Euler from the quaternion) 2 mrad noise every row; gyro 5 mrad/s;
accelerometer R^T(dv/dt - g e3) + 0.08 m/s^2 noise; vbat column for the battery case.
"""

import numpy as np
from scipy.integrate import solve_ivp

G = 9.81


def quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1*w2 - x1*x2 - y1*y2 - z1*z2,
                     w1*x2 + x1*w2 + y1*z2 - z1*y2,
                     w1*y2 - x1*z2 + y1*w2 + z1*x2,
                     w1*z2 + x1*y2 - y1*x2 + z1*w2])


def quat_to_R(q):
    w, x, y, z = q
    return np.array([[1-2*(y*y+z*z), 2*(x*y-w*z), 2*(x*z+w*y)],
                     [2*(x*y+w*z), 1-2*(x*x+z*z), 2*(y*z-w*x)],
                     [2*(x*z-w*y), 2*(y*z+w*x), 1-2*(x*x+y*y)]])


def euler_to_quat(phi, th, psi):
    cr, sr = np.cos(phi/2), np.sin(phi/2)
    cp, sp = np.cos(th/2), np.sin(th/2)
    cy, sy = np.cos(psi/2), np.sin(psi/2)
    return np.array([cr*cp*cy + sr*sp*sy, sr*cp*cy - cr*sp*sy,
                     cr*sp*cy + sr*cp*sy, cr*cp*sy - sr*sp*cy])


def R_to_euler(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    th = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return np.array([phi, th, psi])


def layout_x(l):
    a = l/np.sqrt(2)
    pos = np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]], float)
    spin = np.array([1, 1, -1, -1], float)
    return pos, spin


class Truth:
    def __init__(self, **kw):
        self.m = 1.2
        self.J = np.array([0.0135, 0.0145, 0.0250])
        self.l = 0.225
        self.K_T = 6.97e-6            # hover ~ 650 rad/s
        self.b = 0.015 * self.K_T
        self.Kd = np.array([0.25, 0.25, 0.35])
        self.J_r = 1.5e-5
        self.tau_m = 0.030
        self.k_Tw = 0.0               # thrust_curve
        self.k_rdh = 0.0              # hub_rotor_drag
        self.k_rdv = 0.0
        self.h_hub = 0.0
        self.drop_t = None            # payload drop time
        self.drop_m = None
        for k, v in kw.items():
            setattr(self, k, v)
        self.rpos, self.spin = layout_x(self.l)

    def mass(self, t):
        if self.drop_t is not None and t >= self.drop_t:
            return self.drop_m
        return self.m

    def w_h(self):
        return np.sqrt(self.m*G/(4*self.K_T))

    def thrusts(self, w):
        if self.k_Tw == 0.0:
            return self.K_T*w*w
        wh = self.w_h()
        # K_T w^2 (1 + k (w/wh - 1)) = a w^2 + c w^3
        a = self.K_T*(1 - self.k_Tw)
        c = self.K_T*self.k_Tw/wh
        return a*w*w + c*w*w*w


def rhs_factory(tr, m, wind, w_target, lag=True):
    J = tr.J
    rpos, spin = tr.rpos, tr.spin
    hub_on = tr.k_rdh != 0.0 or tr.k_rdv != 0.0
    rh = rpos + np.array([0, 0, -tr.h_hub])

    def f(t, s):
        v = s[3:6]
        q = s[6:10]
        om = s[10:13]
        w = s[13:17] if lag else w_target
        R = quat_to_R(q / np.sqrt(q @ q))
        T = tr.thrusts(w)
        Fb = np.array([0.0, 0.0, -T.sum()])
        tau = np.array([-(rpos[:, 1]*T).sum(), (rpos[:, 0]*T).sum(),
                        tr.b*(spin*w*w).sum()])
        Om_r = (spin*w).sum()
        tau = tau + tr.J_r*Om_r*np.array([om[1], -om[0], 0.0])
        vair = v - wind
        if hub_on:
            vb = R.T @ vair
            vi = vb[None, :] + np.cross(om[None, :], rh)
            Fi = -w[:, None]*np.column_stack([tr.k_rdh*vi[:, 0], tr.k_rdh*vi[:, 1],
                                              tr.k_rdv*vi[:, 2]])
            Fb = Fb + Fi.sum(0)
            tau = tau + np.cross(rh, Fi).sum(0)
        acc = (R @ Fb - tr.Kd*vair)/m + np.array([0, 0, G])
        dom = (tau - np.cross(om, J*om))/J
        dq = 0.5*quat_mul(q, np.array([0.0, *om]))
        ds = np.empty_like(s)
        ds[0:3] = v
        ds[3:6] = acc
        ds[6:10] = dq
        ds[10:13] = dom
        ds[13:17] = (w_target - w)/tr.tau_m if lag else 0.0
        return ds
    return f


def accel_body(tr, m, wind, s):
    """Specific force in body frame (what an IMU measures) at state s (actual speeds)."""
    f = rhs_factory(tr, m, wind, s[13:17], lag=True)
    ds = f(0.0, s)
    R = quat_to_R(s[6:10])
    return R.T @ (ds[3:6] - np.array([0, 0, G]))


def step(tr, s, t0, t1, w_target, wind, lag=True):
    m = tr.mass(t0)
    f = rhs_factory(tr, m, wind, w_target, lag)
    sol = solve_ivp(f, (t0, t1), s, method="DOP853", rtol=1e-9, atol=1e-10)
    s = sol.y[:, -1].copy()
    s[6:10] /= np.linalg.norm(s[6:10])
    return s


# ---------------------------------------------------------------- controller
class Controller:
    """Cascaded PID, 400 Hz, own model 5 % off."""
    def __init__(self, tr, dt=0.0025):
        self.dt = dt
        self.m = tr.m*1.05
        self.J = tr.J*0.95
        self.K_T = tr.K_T*1.05
        self.l = tr.l*0.95
        self.b = tr.b*0.95
        a = self.l/np.sqrt(2)
        pos = np.array([[a, a], [-a, -a], [a, -a], [-a, a]])
        spin = np.array([1, 1, -1, -1])
        M = np.vstack([self.K_T*np.ones(4), -self.K_T*pos[:, 1], self.K_T*pos[:, 0],
                       self.b*spin])
        self.Minv = np.linalg.inv(M)
        self.kp_pos = np.array([1.2, 1.2, 1.5])
        self.kp_vel = np.array([3.0, 3.0, 4.0])
        self.ki_vel = np.array([1.0, 1.0, 1.5])
        self.k_att = np.array([8.0, 8.0, 4.0])
        self.kp_rate = np.array([18.0, 18.0, 8.0])
        self.ki_rate = np.array([5.0, 5.0, 2.0])
        self.kd_rate = np.array([0.08, 0.08, 0.0])
        self.iv = np.zeros(3)
        self.ir = np.zeros(3)
        self.prev_om = None
        self.dom_f = np.zeros(3)
        self.max_tilt = np.radians(25)

    def __call__(self, pos, vel, R, om, ref):
        p_ref, v_ref, a_ref, psi_ref = ref
        v_des = self.kp_pos*(p_ref - pos) + v_ref
        sp = np.linalg.norm(v_des[:2])
        if sp > 3.0:
            v_des[:2] *= 3.0/sp
        ev = v_des - vel
        self.iv = np.clip(self.iv + ev*self.dt, -2, 2)
        a_des = self.kp_vel*ev + self.ki_vel*self.iv + a_ref
        F = self.m*(a_des - np.array([0, 0, G]))   # desired R Fb (thrust along -b3)
        # tilt limit
        Fz = min(F[2], -0.3*self.m*G)
        h = np.linalg.norm(F[:2])
        hmax = -Fz*np.tan(self.max_tilt)
        if h > hmax:
            F[:2] *= hmax/h
        F[2] = Fz
        b3 = -F/np.linalg.norm(F)
        c1 = np.array([np.cos(psi_ref), np.sin(psi_ref), 0.0])
        b2 = np.cross(b3, c1); b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        T = -F @ R[:, 2]
        E = 0.5*(Rd.T @ R - R.T @ Rd)
        eR = np.array([E[2, 1], E[0, 2], E[1, 0]])
        om_des = -self.k_att*eR
        om_des = np.clip(om_des, -4, 4)
        er = om_des - om
        self.ir = np.clip(self.ir + er*self.dt, -0.5, 0.5)
        if self.prev_om is None:
            self.prev_om = om.copy()
        dom = (om - self.prev_om)/self.dt
        self.prev_om = om.copy()
        self.dom_f += 0.2*(dom - self.dom_f)
        alpha = self.kp_rate*er + self.ki_rate*self.ir - self.kd_rate*self.dom_f
        tau = self.J*alpha + np.cross(om, self.J*om)
        w2 = self.Minv @ np.array([T, *tau])
        w = np.sqrt(np.clip(w2, 120.0**2, 1100.0**2))
        return w


# ---------------------------------------------------------------- references
def make_reference(seed, duration, dt=0.0025, kind=None):
    """Piecewise manoeuvres (figure-eights, steps, climbs/descents, yaw turns), smoothed."""
    rng = np.random.default_rng(seed)
    n = int(round(duration/dt)) + 1
    t = np.arange(n)*dt
    P = np.zeros((n, 3)); P[:, 2] = -2.0
    psi = np.zeros(n)
    segs = ['fig8', 'steps', 'climb', 'yaw', 'fig8b', 'steps', 'climb_yaw']
    rng.shuffle(segs)
    seg_len = duration/len(segs)
    base = np.array([0.0, 0.0, -2.0]); yaw0 = 0.0
    for i, sname in enumerate(segs):
        i0 = int(i*seg_len/dt); i1 = min(n, int((i+1)*seg_len/dt))
        tt = t[i0:i1] - t[i0]
        L = seg_len
        if sname.startswith('fig8'):
            A = rng.uniform(1.1, 1.6); om = 2*np.pi/L
            P[i0:i1, 0] = base[0] + A*np.sin(om*tt)
            P[i0:i1, 1] = base[1] + 0.5*A*np.sin(2*om*tt)*(1 if sname == 'fig8' else -1)
            P[i0:i1, 2] = base[2] + 0.3*np.sin(om*tt)
            psi[i0:i1] = yaw0
        elif sname == 'steps':
            k = 3
            P[i0:i1] = base
            for j in range(k):
                jj = i0 + int(j*(i1-i0)/k)
                d = rng.uniform(-1.5, 1.5, 2)
                P[jj:i1, 0] = base[0] + d[0]; P[jj:i1, 1] = base[1] + d[1]
            P[i0:i1, 2] = base[2]
            psi[i0:i1] = yaw0
        elif sname.startswith('climb'):
            dz = rng.uniform(0.8, 1.5)
            P[i0:i1] = base
            P[i0:i1, 2] = base[2] - dz*np.sin(np.pi*tt/L)**2*np.sign(np.sin(2*np.pi*tt/L) + 1e-9)
            psi[i0:i1] = yaw0 + (rng.uniform(-1.5, 1.5)*np.sin(np.pi*tt/L) if sname == 'climb_yaw' else 0)
        elif sname == 'yaw':
            P[i0:i1] = base
            P[i0:i1, 0] = base[0] + 0.8*np.sin(2*np.pi*tt/L)
            psi[i0:i1] = yaw0 + rng.uniform(1.0, 2.0)*np.sin(2*np.pi*tt/L)
    # smooth (Gaussian sigma 0.4 s) -> finite derivatives
    from scipy.ndimage import gaussian_filter1d
    sig = 0.4/dt
    Ps = gaussian_filter1d(P, sig, axis=0, mode='nearest')
    psis = gaussian_filter1d(psi, sig, mode='nearest')
    V = np.gradient(Ps, dt, axis=0)
    A = np.gradient(V, dt, axis=0)
    # start at rest at hover point
    return t, Ps, V, A, psis


def colored_wind(seed, n, dt, rms=1.0, tau=1.5, vert=0.3):
    """Dryden-like first-order (OU) gusts, zero mean, given RMS per horizontal axis."""
    rng = np.random.default_rng(seed + 999)
    a = np.exp(-dt/tau)
    W = np.zeros((n, 3))
    sc = np.array([rms, rms, rms*vert])
    x = rng.normal(0, 1, 3)*sc
    for k in range(n):
        W[k] = x
        x = a*x + np.sqrt(1 - a*a)*sc*rng.normal(0, 1, 3)
    W -= W.mean(0)
    return W


# ---------------------------------------------------------------- flights (the audit's gen.py)
DT = 0.0025          # controller tick
ROW = 2              # log every 2 ticks = 200 Hz

CASES = {
    'c1': dict(seeds=(11, 12)),
    'c2': dict(seeds=(21, 22)),
    'c3': dict(seeds=(31, 32), glitches=True),
    'thrust_curve': dict(seeds=(41, 42), truth=dict(k_Tw=0.25)),
    'rotor_map': dict(seeds=(51, 52), w_offset=-40.0),
    'attitude_bias': dict(seeds=(61, 62), att_bias=(np.radians(2.0), np.radians(-1.5))),
    'position_delay': dict(seeds=(71, 72), tau_pos=0.025),
    'hub_rotor_drag': dict(seeds=(81, 82), truth=dict(k_rdh=8e-5, k_rdv=6e-5, h_hub=0.03)),
    'battery_voltage': dict(seeds=(91, 92), K_vbat=0.12),
    'turbulence': dict(seeds=(101, 102), gust_rms=1.0),
    'payload_drop': dict(seeds=(111, 112), truth=dict(drop_m=1.05)),
    'payload_drop2': dict(seeds=(113, 114), truth=dict(drop_m=1.05)),
}


def fly(case, seed, duration, v0_bat=4.15):
    cfg = CASES[case]
    tr = Truth(**cfg.get('truth', {}))
    if tr.drop_m is not None:
        tr.drop_t = round(duration/2/DT)*DT
    rng = np.random.default_rng(seed)
    t, Pr, Vr, Ar, psir = make_reference(seed, duration + 1, DT)
    n = int(round(duration/DT))
    wind = colored_wind(seed, n + 1, DT, rms=cfg.get('gust_rms', 0.0)) if cfg.get('gust_rms') else np.zeros((n + 1, 3))
    ctrl = Controller(tr, DT)
    s = np.zeros(17)
    s[0:3] = Pr[0]; s[6:10] = euler_to_quat(0, 0, psir[0])
    s[13:17] = tr.w_h()
    ctrl.iv[2] = 0.0
    rows = []
    K_vbat = cfg.get('K_vbat', 0.0)
    for k in range(n + 1):
        tk = k*DT
        R = quat_to_R(s[6:10])
        if k % ROW == 0:
            m = tr.mass(tk)
            acc = accel_body(tr, m, wind[k], s)
            rows.append((tk, s.copy(), acc, R_to_euler(R)))
        if k == n:
            break
        # sensors for the controller
        pos_m = s[0:3] + rng.normal(0, 0.001, 3)
        vel_m = s[3:6] + rng.normal(0, 0.02, 3)
        eul = R_to_euler(R) + rng.normal(0, 0.002, 3)
        Rm = quat_to_R(euler_to_quat(*eul))
        om_m = s[10:13] + rng.normal(0, 0.005, 3)
        w_cmd = ctrl(pos_m, vel_m, Rm, om_m, (Pr[k], Vr[k], Ar[k], psir[k]))
        s = step(tr, s, tk, tk + DT, w_cmd, wind[k])
    # ---- log
    N = len(rows)
    T = np.array([r[0] for r in rows])
    S = np.array([r[1] for r in rows])
    ACC = np.array([r[2] for r in rows])
    EUL = np.array([r[3] for r in rows])
    w_act = S[:, 13:17]
    df = {'t': np.round(T, 6)}
    truth = dict(case=case, seed=seed, duration=duration, mass=tr.m, inertia=tr.J.tolist(), arm=tr.l,
                 layout='x', J_r=tr.J_r, tau_m_true_state=tr.tau_m,
                 parameters={'K_T': tr.K_T, 'b': tr.b, 'Kd[0]': tr.Kd[0], 'Kd[1]': tr.Kd[1], 'Kd[2]': tr.Kd[2]},
                 hover_w=float(tr.w_h()))
    w_log = w_act.copy()
    if 'w_offset' in cfg:
        w_log = w_act - cfg['w_offset']        # actual = logged + offset
        truth['parameters']['w_offset'] = cfg['w_offset']
    if K_vbat:
        load = (w_act**2).sum(1)/(4*tr.w_h()**2) - 1
        vbat = v0_bat - 0.009*T - 0.12*load
        vbat = np.round(vbat + rng.normal(0, 0.002, N), 3)
        w_log = w_act/(1 + K_vbat*(vbat[:, None] - 4.0))
        truth['parameters']['K_vbat'] = K_vbat
        truth['vbat_range'] = [float(vbat.min()), float(vbat.max())]
    w_log = np.round(w_log*(1 + rng.normal(0, 0.003, w_log.shape)))
    for i in range(4):
        df[f'w{i+1}'] = w_log[:, i]
    pos = S[:, 0:3].copy()
    if 'tau_pos' in cfg:
        sh = int(round(cfg['tau_pos']/(DT*ROW)))
        pos = np.vstack([np.repeat(pos[:1], sh, 0), pos[:-sh]])
        truth['parameters']['tau_pos'] = cfg['tau_pos']
    pos = pos + rng.normal(0, 0.001, pos.shape)
    pos[1::2] = np.nan                        # mocap at 100 Hz
    if cfg.get('glitches'):
        idx = np.where(~np.isnan(pos[:, 0]))[0]
        nout = int(round(0.003*len(idx)))
        sel = rng.choice(idx, nout, replace=False)
        d = rng.normal(0, 1, (nout, 3)); d /= np.linalg.norm(d, axis=1)[:, None]
        pos[sel] += d*rng.uniform(0.05, 0.20, (nout, 1))
        gaps = []
        for g in range(3):
            t0 = (g + 0.5 + rng.uniform(-0.2, 0.2))*duration/3.2 + 1
            L = rng.uniform(0.4, 0.8)
            m_ = (T >= t0) & (T < t0 + L)
            pos[m_] = np.nan
            gaps.append([float(t0), float(L)])
        truth['glitches'] = dict(outlier_rows=[int(i) + 2 for i in sorted(sel)], gaps_t0_len=gaps)
    for i, c in enumerate('xyz'):
        df[c] = pos[:, i]
    eul = EUL + rng.normal(0, 0.002, EUL.shape)
    if 'att_bias' in cfg:
        eul[:, 0] += cfg['att_bias'][0]; eul[:, 1] += cfg['att_bias'][1]
        truth['parameters']['att_bias[0]'] = cfg['att_bias'][0]
        truth['parameters']['att_bias[1]'] = cfg['att_bias'][1]
    eul[:, 2] = np.angle(np.exp(1j*eul[:, 2]))
    for i, c in enumerate(['phi', 'theta', 'psi']):
        df[c] = eul[:, i]
    om = S[:, 10:13] + rng.normal(0, 0.005, (N, 3))
    for i, c in enumerate('pqr'):
        df[c] = om[:, i]
    acc = ACC + rng.normal(0, 0.08, ACC.shape)
    for i, c in enumerate(['ax', 'ay', 'az']):
        df[c] = acc[:, i]
    if K_vbat:
        df['vbat'] = vbat
    if tr.k_Tw:
        truth['parameters']['k_Tw'] = tr.k_Tw
    if tr.k_rdh:
        truth['parameters'].update({'k_rdh': tr.k_rdh, 'k_rdv': tr.k_rdv, 'h_hub': tr.h_hub})
    if tr.drop_m is not None:
        truth['payload_drop'] = dict(t=tr.drop_t, mass_after=tr.drop_m)
    if cfg.get('gust_rms'):
        truth['gusts'] = dict(rms=cfg['gust_rms'], tau=1.5, vertical_ratio=0.3,
                              actual_rms=np.sqrt((wind**2).mean(0)).tolist())
    tilt = np.degrees(np.arccos(np.clip(np.cos(EUL[:, 0])*np.cos(EUL[:, 1]), -1, 1)))
    spd = np.linalg.norm(S[:, 3:6], axis=1)
    truth['stats'] = dict(max_tilt_deg=float(tilt.max()), max_speed=float(spd.max()),
                          w_min=float(w_act.min()), w_max=float(w_act.max()),
                          track_err_rms=float(np.sqrt(((S[:, 0:3] - Pr[::ROW][:N])**2).sum(1).mean())),
                          yaw_range_deg=float(np.degrees(np.ptp(EUL[:, 2]))))
    return df, truth


def airframe_guess(path):
    """The audit's airframe: true mass, inertia, arm and rotor inertia; K_T 30 % high, b and Kd 30 % low."""
    tr = Truth()
    open(path, 'w').write(f"""[airframe]
name = "audit16_guess"
mass = {tr.m}
inertia = [{tr.J[0]}, {tr.J[1]}, {tr.J[2]}]
arm_length = {tr.l}
layout = "x"
rotor_inertia = {tr.J_r}
gravity = 9.81

[parameters]
K_T = {tr.K_T*1.3:.6g}
b = {tr.b*0.7:.6g}
Kd = [{tr.Kd[0]*0.7:.4g}, {tr.Kd[1]*0.7:.4g}, {tr.Kd[2]*0.7:.4g}]
""")


def write_csv(df, path):
    """The columns of ``df`` (name -> array) as greybox's CSV, empty cells for NaN."""
    names = list(df)
    cols = [np.asarray(df[n], dtype=float) for n in names]
    with open(path, "w") as f:
        f.write(",".join(names) + "\n")
        for row in zip(*cols):
            f.write(",".join("" if not np.isfinite(v) else f"{v:.8g}" for v in row) + "\n")


def flight(case, part, path):
    """Write the audit's ``part`` ("est", 40 s, or "val", 30 s) of ``case`` to ``path``; its truth."""
    seed = CASES[case]["seeds"][0 if part == "est" else 1]
    df, truth = fly(case, seed, 40.0 if part == "est" else 30.0, v0_bat=4.15 if part == "est" else 4.08)
    write_csv(df, path)
    return truth

#!/usr/bin/env python3
"""Independent outdoor PX4-style quadrotor simulator of a blind audit (2026-12-04, the fourteenth),
kept as a test generator that is not greybox's own: written from ``CONTRACT.md`` and the README
alone, without reading the package, and checked against ``greybox simulate`` (numpy only; no
greybox import): 5e-13 to 4e-12 m and rad over an excited open-loop flight, also with a CoG
offset, a wind and quadratic drag.

Vehicle: 2.0 kg X quadrotor, arm 0.25 m, 10-inch props.
Conventions (from CONTRACT.md): NED world, FRD body, ZYX Euler, R = Rz Ry Rx body->world.
X layout: rotor 1 front-right (+a,+a), 2 back-left (-a,-a), 3 front-left (+a,-a),
4 back-right (-a,+a); spin [+1,+1,-1,-1]; reaction torque spin_i*b*w_i^2 about body +z;
gyroscopic torque J_r*Omega_r*(omega x e_z), Omega_r = sum(spin_i w_i).

Dynamics: quaternion attitude, fixed-step RK4 at 1 kHz (own code), first-order motors
(tau_m = 35 ms) inside the RK4 state. Controller: PX4-like cascade at 500 Hz
(position P -> velocity PID -> thrust vector/attitude -> attitude P -> rate PID -> mixer).
Log rows: ESC telemetry = ACTUAL rotor speeds sampled at the row instant, 0.3 % white
noise, quantised to 10 RPM (1.047 rad/s). Attitude = "EKF": truth + white + AR(1)
coloured error. Gyro p,q,r: truth + white. Position: RTK GNSS at 10 Hz (other rows empty).
"""
import argparse, json, math, sys
import numpy as np

G = 9.81
TRUE = dict(mass=2.0, J=[0.028, 0.026, 0.048], arm=0.25, J_r=3.0e-5,
            K_T=1.35e-5, b=2.0e-7, Kd=[0.30, 0.30, 0.30], tau_m=0.035)


def rotors(arm):
    a = arm / math.sqrt(2)
    pos = np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]], float)
    spin = np.array([1, 1, -1, -1], float)
    return pos, spin


def qmul(a, b):
    w1, x1, y1, z1 = a; w2, x2, y2, z2 = b
    return np.array([w1*w2-x1*x2-y1*y2-z1*z2, w1*x2+x1*w2+y1*z2-z1*y2,
                     w1*y2-x1*z2+y1*w2+z1*x2, w1*z2+x1*y2-y1*x2+z1*w2])


def q2R(q):
    w, x, y, z = q
    return np.array([[1-2*(y*y+z*z), 2*(x*y-w*z), 2*(x*z+w*y)],
                     [2*(x*y+w*z), 1-2*(x*x+z*z), 2*(y*z-w*x)],
                     [2*(x*z-w*y), 2*(y*z+w*x), 1-2*(x*x+y*y)]])


def euler2q(phi, th, psi):
    cr, sr = math.cos(phi/2), math.sin(phi/2)
    cp, sp = math.cos(th/2), math.sin(th/2)
    cy, sy = math.cos(psi/2), math.sin(psi/2)
    return np.array([cr*cp*cy+sr*sp*sy, sr*cp*cy-cr*sp*sy, cr*sp*cy+sr*cp*sy, cr*cp*sy-sr*sp*cy])


def R2euler(R):
    return (math.atan2(R[2, 1], R[2, 2]), -math.asin(max(-1, min(1, R[2, 0]))),
            math.atan2(R[1, 0], R[0, 0]))


class Physics:
    """Truth physics with optional hidden effects (cfg dict)."""
    def __init__(self, cfg):
        self.m = TRUE['mass']; self.J = np.diag(TRUE['J']); self.Jinv = np.linalg.inv(self.J)
        self.pos, self.spin = rotors(TRUE['arm'])
        self.J_r = TRUE['J_r']; self.K_T = TRUE['K_T']; self.b = TRUE['b']
        self.Kd = np.array(TRUE['Kd']); self.tau_m = TRUE['tau_m']
        self.cfg = cfg
        self.scale = np.array(cfg.get('rotor_scale', [1, 1, 1, 1]), float)
        self.r_cog = np.array(list(cfg.get('cog', [0, 0])) + [0.0])
        self.Kq = cfg.get('Kq', 0.0)
        self.drift = cfg.get('kt_drop', 0.0)     # fractional K_T drop over T_drift seconds
        self.T_drift = cfg.get('T_drift', 1.0)
        self.c_tl = cfg.get('c_tl', 0.0)          # translational lift (outside catalogue)
        self.t0 = 0.0

    def deriv(self, t, s, w_cmd, wind, motor=True):
        p, v, q, om, w = s[0:3], s[3:6], s[6:10], s[10:13], s[13:17]
        weff = w if motor else w_cmd
        R = q2R(q)
        v_air = v - wind
        vb = R.T @ v_air
        kt = self.K_T * (1.0 - self.drift * (t + self.t0) / self.T_drift)
        T = kt * self.scale * weff**2
        if self.c_tl:
            T = T * (1.0 + self.c_tl * (vb[0]**2 + vb[1]**2))
        F = R @ np.array([0, 0, -T.sum()])
        F += np.array([0, 0, self.m * G])
        F += R @ (-self.Kd * vb)                      # linear body drag (isotropic => world)
        if self.Kq:
            F += -self.Kq * np.linalg.norm(v_air) * v_air
        M = np.zeros(3)
        for i in range(4):
            M += np.cross(self.pos[i] - self.r_cog, [0, 0, -T[i]])
        M[2] += np.sum(self.spin * self.b * self.scale * weff**2)
        Om = np.sum(self.spin * weff)
        M += self.J_r * Om * np.array([om[1], -om[0], 0.0])
        M -= np.cross(om, self.J @ om)
        dq = 0.5 * qmul(q, np.array([0, *om]))
        dw = (w_cmd - w) / self.tau_m if motor else np.zeros(4)
        return np.concatenate([v, F / self.m, dq, self.Jinv @ M, dw])

    def step(self, t, s, w_cmd, wind, dt, motor=True):
        k1 = self.deriv(t, s, w_cmd, wind, motor)
        k2 = self.deriv(t+dt/2, s+dt/2*k1, w_cmd, wind, motor)
        k3 = self.deriv(t+dt/2, s+dt/2*k2, w_cmd, wind, motor)
        k4 = self.deriv(t+dt, s+dt*k3, w_cmd, wind, motor)
        s = s + dt/6*(k1+2*k2+2*k3+k4)
        s[6:10] /= np.linalg.norm(s[6:10])
        return s


class Controller:
    """PX4-like cascade. Nominal (controller's own) parameters slightly off truth."""
    def __init__(self, dt):
        self.dt = dt
        self.m = 2.0; self.J = np.diag([0.03, 0.03, 0.05])
        self.K_T = 1.30e-5; self.b = 2.1e-7
        pos, spin = rotors(0.25)
        A = np.vstack([np.ones(4), -pos[:, 1], pos[:, 0], spin * self.b / self.K_T])
        self.Ainv = np.linalg.inv(A)     # [T, Mx, My, Mz] = K_T * A @ w^2
        self.kp_pos = np.array([0.95, 0.95, 1.0])
        self.kp_vel = np.array([1.8, 1.8, 4.0]); self.ki_vel = np.array([0.4, 0.4, 2.0])
        self.kd_vel = np.array([0.2, 0.2, 0.0])
        self.kp_att = np.array([6.5, 6.5, 2.8])
        self.kp_rate = np.array([0.15, 0.15, 0.2]) / 0.03 * 0.5  # in rad/s^2 per rad/s
        self.kp_rate = np.array([16.0, 16.0, 8.0]); self.ki_rate = np.array([6.0, 6.0, 2.0])
        self.kd_rate = np.array([0.25, 0.25, 0.0])
        self.iv = np.zeros(3); self.ir = np.zeros(3)
        self.prev_v = None; self.prev_om = None
        self.dterm_v = np.zeros(3); self.dterm_r = np.zeros(3)

    def update(self, p, v, R, om, ref):
        pr, vr, ar, psir = ref
        dt = self.dt
        vsp = self.kp_pos * (pr - p) + vr
        h = np.hypot(vsp[0], vsp[1])
        if h > 9.0: vsp[:2] *= 9.0 / h
        vsp[2] = np.clip(vsp[2], -3.0, 2.0)
        ev = vsp - v
        if self.prev_v is None: self.prev_v = v.copy()
        dv = -(v - self.prev_v) / dt; self.prev_v = v.copy()
        self.dterm_v += 0.1 * (dv - self.dterm_v)      # low-pass D
        self.iv = np.clip(self.iv + ev * dt, -3, 3)
        asp = self.kp_vel * ev + self.ki_vel * self.iv + self.kd_vel * self.dterm_v + ar
        f = asp - np.array([0, 0, G])                   # specific thrust (NED)
        # tilt limit 35 deg
        fz = min(f[2], -2.0)
        fh = f[:2]; maxh = -fz * math.tan(math.radians(35))
        nh = np.hypot(*fh)
        if nh > maxh: fh = fh * maxh / nh
        f = np.array([fh[0], fh[1], fz])
        b3 = -f / np.linalg.norm(f)
        c = np.array([math.cos(psir), math.sin(psir), 0])
        b2 = np.cross(b3, c); b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        Tcmd = self.m * np.dot(-f, R[:, 2]) * 1.0
        Tcmd = self.m * np.linalg.norm(f) * max(0.0, np.dot(b3, R[:, 2]))
        E = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([E[2, 1], E[0, 2], E[1, 0]])
        omsp = -self.kp_att * eR
        omsp = np.clip(omsp, [-3.5, -3.5, -1.5], [3.5, 3.5, 1.5])
        er = omsp - om
        if self.prev_om is None: self.prev_om = om.copy()
        dom = -(om - self.prev_om) / dt; self.prev_om = om.copy()
        self.dterm_r += 0.3 * (dom - self.dterm_r)
        self.ir = np.clip(self.ir + er * dt, -0.5, 0.5)
        alpha = self.kp_rate * er + self.ki_rate * self.ir + self.kd_rate * self.dterm_r
        M = self.J @ alpha + np.cross(om, self.J @ om)
        w2 = self.Ainv @ np.array([Tcmd, *M]) / self.K_T
        # simple desaturation: scale the yaw torque first
        if w2.min() < 280**2 or w2.max() > 1000**2:
            M2 = M.copy(); M2[2] *= 0.3
            w2 = self.Ainv @ np.array([Tcmd, *M2]) / self.K_T
        w = np.sqrt(np.clip(w2, 280**2, 1000**2))
        return w


def reference(t, prm):
    """Figure-eight + altitude wave + yaw turns. Returns p, v, a, psi."""
    A, B, om, h0, H, omz, ph, yamp, omy, yph = (prm[k] for k in
        ('A', 'B', 'om', 'h0', 'H', 'omz', 'ph', 'yamp', 'omy', 'yph'))
    x = A*math.sin(om*t); vx = A*om*math.cos(om*t); ax = -A*om*om*math.sin(om*t)
    y = B*math.sin(2*om*t); vy = 2*B*om*math.cos(2*om*t); ay = -4*B*om*om*math.sin(2*om*t)
    z = -h0 - H*math.sin(omz*t+ph); vz = -H*omz*math.cos(omz*t+ph); az = H*omz*omz*math.sin(omz*t+ph)
    psi = yamp*math.sin(omy*t + yph)
    # waypoint jumps: piecewise-constant offsets (position P saturates -> sharp climbs/turns)
    steps = prm.get('steps', [])
    off = np.zeros(3); dpsi = 0.0
    for (ts, dx, dy, dz, dps) in steps:
        if t >= ts:
            off = np.array([dx, dy, dz]); dpsi = dps
    return np.array([x, y, z]) + off, np.array([vx, vy, vz]), np.array([ax, ay, az]), psi + dpsi


class AR1:
    def __init__(self, rng, n, sigma, tau, dt):
        self.a = math.exp(-dt/tau) if tau > 0 else 0.0
        self.s = sigma*math.sqrt(1-self.a**2); self.rng = rng
        self.x = rng.normal(0, sigma, n) if sigma > 0 else np.zeros(n)

    def step(self):
        self.x = self.a*self.x + self.s*self.rng.normal(size=self.x.shape)
        return self.x


def fly(cfg, seed, duration, out, truth_out=None):
    rng = np.random.default_rng(seed)
    dt = 0.001; ctrl_every = 2
    row_rate = cfg.get('row_rate', 200); row_every = int(round(1/(row_rate*dt)))
    gnss_rate = cfg.get('gnss_rate', 10); gnss_every = int(round(1/(gnss_rate*dt)))
    gnss_sd = cfg.get('gnss_sd', 0.015); gnss_lat = cfg.get('gnss_latency', 0.0)
    lever = np.array(cfg.get('gnss_lever', [0, 0, 0]), float)
    att_white = cfg.get('att_white', 0.0015); att_col = cfg.get('att_col', 0.002)
    att_tau = cfg.get('att_tau', 2.0); yaw_col = cfg.get('yaw_col', 0.004)
    gyro_sd = cfg.get('gyro_sd', 0.003); w_sd = cfg.get('w_noise', 0.003)
    wq = cfg.get('w_quant', 10*2*math.pi/60)
    acc_sd = cfg.get('accel_sd', None)
    wind_mean = np.array(list(cfg.get('wind', [0, 0])) + [cfg.get('wind_z', 0.0)])
    turb_sd = cfg.get('turb_sd', 0.0); turb_tau = cfg.get('turb_tau', 1.5)
    warm = 5.0
    prm = dict(A=rng.uniform(16, 22), B=rng.uniform(6, 9), om=rng.uniform(0.28, 0.33),
               h0=rng.uniform(12, 18), H=rng.uniform(2.0, 3.5), omz=rng.uniform(0.35, 0.55),
               ph=rng.uniform(0, 6.28), yamp=rng.uniform(1.0, 1.5), omy=rng.uniform(0.2, 0.35),
               yph=rng.uniform(0, 6.28))
    tt = rng.uniform(2, 5); steps = []
    while tt < duration:
        steps.append((tt, rng.uniform(-5, 5), rng.uniform(-5, 5), rng.choice([-1, 1])*rng.uniform(2, 4),
                       rng.uniform(-1.2, 1.2)))
        tt += rng.uniform(5, 8)
    prm['steps'] = steps
    phys = Physics(cfg)
    phys.T_drift = cfg.get('T_drift', 45.0)
    phys.t0 = 0.0
    ctrl = Controller(dt*ctrl_every)
    p0, v0, a0, psi0 = reference(-warm, prm)
    w_h = math.sqrt(TRUE['mass']*G/(4*TRUE['K_T']))
    s = np.concatenate([p0, v0, euler2q(0, 0, psi0), np.zeros(3), np.full(4, w_h)])
    turb = AR1(rng, 3, turb_sd, turb_tau, dt)
    turb_scale = np.array([1, 1, 0.5])
    att_err = AR1(rng, 3, 1.0, att_tau, row_every*dt)
    att_err_scale = np.array([att_col, att_col, yaw_col])
    n = int(round((duration + warm)/dt))
    hist_p = {}          # for latency: true position at step index
    lat_steps = int(round(gnss_lat/dt))
    rows = []
    wcmd = np.full(4, w_h)
    for k in range(n + 1):
        t = -warm + k*dt
        wind = wind_mean + turb.x * turb_scale
        R = q2R(s[6:10])
        if k % ctrl_every == 0:
            ref = reference(t, prm)
            wcmd = ctrl.update(s[0:3], s[3:6], R, s[10:13], ref)
        hist_p[k] = s[0:3] + R @ lever
        if lat_steps:
            hist_p.pop(k - lat_steps - 10, None)
        if t >= -1e-9 and k % row_every == 0:
            ti = round(t, 6)
            phi, th, psi = R2euler(R)
            ae = att_err.step() * att_err_scale
            row = dict(t=ti)
            wm = s[13:17] * (1 + w_sd*rng.normal(size=4))
            if wq: wm = np.round(wm/wq)*wq
            if cfg.get('log_cmd'):
                wm = wcmd.copy()        # PX4 actuator_outputs: the commanded speeds
            for i in range(4): row[f'w{i+1}'] = wm[i]
            row['phi'] = phi + ae[0] + att_white*rng.normal()
            row['theta'] = th + ae[1] + att_white*rng.normal()
            ps = psi + ae[2] + att_white*rng.normal()
            row['psi'] = (ps + math.pi) % (2*math.pi) - math.pi
            om = s[10:13] + gyro_sd*rng.normal(size=3)
            row['p'], row['q'], row['r'] = om
            if k % gnss_every == 0:
                pm = hist_p[max(k - lat_steps, 0)] + gnss_sd*rng.normal(size=3)
                row['x'], row['y'], row['z'] = pm
            else:
                row['x'] = row['y'] = row['z'] = None
            if acc_sd is not None:
                d = phys.deriv(t, s, wcmd, wind)
                sf = R.T @ (d[3:6] - np.array([0, 0, G]))
                sf += acc_sd*rng.normal(size=3)
                row['ax'], row['ay'], row['az'] = sf
            row['_true'] = (phi, th, psi, *s[0:6], *s[13:17], *wind)
            rows.append(row)
        s = phys.step(t, s, wcmd, wind, dt)
        turb.step()
    cols = ['t', 'w1', 'w2', 'w3', 'w4', 'x', 'y', 'z', 'phi', 'theta', 'psi', 'p', 'q', 'r']
    if acc_sd is not None: cols += ['ax', 'ay', 'az']
    with open(out, 'w') as fh:
        fh.write(','.join(cols) + '\n')
        for r in rows:
            fh.write(','.join('' if r[c] is None else (repr(float(r[c])) if c != 't' else f'{r[c]:.6f}')
                              for c in cols) + '\n')
    tr = np.array([r['_true'] for r in rows])
    info = dict(cfg=cfg, seed=seed, duration=duration, ref=prm,
                max_speed=float(np.max(np.linalg.norm(tr[:, 6:9], axis=1))),
                max_tilt_deg=float(np.degrees(np.max(np.arccos(np.cos(tr[:, 0])*np.cos(tr[:, 1]))))),
                w_min=float(tr[:, 9:13].min()), w_max=float(tr[:, 9:13].max()),
                frac_w_at_1000=float(np.mean(tr[:, 9:13] > 995)),
                z_range=[float(tr[:, 5].min()), float(tr[:, 5].max())],
                psi_range=[float(tr[:, 2].min()), float(tr[:, 2].max())],
                wind_mean_realised=tr[:, 13:16].mean(axis=0).tolist(),
                wind_mean_first_half=tr[:len(tr)//2, 13:16].mean(axis=0).tolist(),
                wind_mean_second_half=tr[len(tr)//2:, 13:16].mean(axis=0).tolist())
    if truth_out:
        json.dump(info, open(truth_out, 'w'), indent=1)
    return info


def open_loop(cfg, t, W, x0=None, sub=1e-3):
    """Open-loop integration of the rotor speeds held (ZOH), no motor lag (for the
    convention check against greybox simulate). Returns Euler + position + velocity."""
    phys = Physics(cfg)
    s = np.zeros(17); s[6] = 1.0
    if x0 is not None:
        s[0:3] = x0[0:3]; s[6:10] = euler2q(*x0[3:6]); s[3:6] = x0[6:9]; s[10:13] = x0[9:12]
    wind = np.array(list(cfg.get('wind', [0, 0])) + [0.0])
    out = []
    for k in range(len(t)):
        R = q2R(s[6:10]); out.append([*s[0:3], *R2euler(R), *s[3:6], *s[10:13]])
        if k == len(t)-1: break
        h = t[k+1]-t[k]; nsub = max(1, int(math.ceil(h/sub - 1e-9))); d = h/nsub
        for j in range(nsub):
            s = phys.step(t[k]+j*d, s, W[k], wind, d, motor=False)
    return np.array(out)


CASES = {
    'c1_calm': {},
    'c2_noise': dict(row_rate=100, gnss_rate=5, gnss_sd=0.02, att_white=0.003, att_col=0.003,
                     gyro_sd=0.006, w_noise=0.006, accel_sd=0.08),
    'c3_wind': dict(wind=[3.5, -2.0], turb_sd=0.3),
    'c4_sag': dict(kt_drop=0.10),
    'c5_gnsslat': dict(gnss_latency=0.10),
    'c6_cog': dict(cog=[0.015, -0.010]),
    'c7_weak': dict(rotor_scale=[1, 0.92, 1, 1]),
    'c8_quad': dict(Kq=0.035),
    'c9a_etl': dict(c_tl=0.0015),
    'c9b_lever': dict(gnss_lever=[0.10, 0.0, -0.15]),
    'c10_cmd': dict(log_cmd=True),
    'c5b_gnsslat150': dict(gnss_latency=0.15),
    'c1b_calm': {},
    'c10b_cmd': dict(log_cmd=True),
    'c11_updraft': dict(wind_z=-1.0),
}

if __name__ == '__main__':
    ap = argparse.ArgumentParser()
    ap.add_argument('case'); ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--duration', type=float, default=45.0)
    ap.add_argument('--out', required=True); ap.add_argument('--truth')
    a = ap.parse_args()
    info = fly(CASES[a.case], a.seed, a.duration, a.out, a.truth)
    print(json.dumps({k: info[k] for k in ('max_speed', 'max_tilt_deg', 'w_min', 'w_max',
                                             'frac_w_at_1000', 'z_range', 'psi_range')}))

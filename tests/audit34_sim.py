#!/usr/bin/env python3
"""Audit 34 simulator: a 1.6 kg "plus" quadrotor on 10-inch props, many short flights.

Independent of greybox: numpy only.  Unit-quaternion rigid body, fixed-step RK4 (1 ms)
between the ticks of its own 250 Hz geometric cascade (internal model 5-10 % off),
20-ms first-order motors, a per-flight wind (constant + slow gust) on a world-axis linear
drag, a per-flight battery sag of its own (quadratic in time) that lowers the actual rotor
speed below the logged one.

    python sim.py data      # writes every file into data/
"""
import json
import os
import sys

import numpy as np

G = 9.81
TRUTH = dict(
    mass=1.60, inertia=[0.0185, 0.0185, 0.0330], arm=0.25,
    K_T=1.45e-5, b=2.3e-7, Kd=[0.18, 0.20, 0.30], J_r=8.0e-5,
)
POS = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], float)  # "plus", times arm
SPIN = np.array([-1.0, 1.0, -1.0, 1.0])
TICK = 1.0 / 250.0
SUB = 4                      # RK4 substeps per tick (1 ms)
TAU_M = 0.020
W_MIN, W_MAX = 120.0, 950.0


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1*w2 - x1*x2 - y1*y2 - z1*z2,
                     w1*x2 + x1*w2 + y1*z2 - z1*y2,
                     w1*y2 - x1*z2 + y1*w2 + z1*x2,
                     w1*z2 + x1*y2 - y1*x2 + z1*w2])


def qrot(q):
    w, x, y, z = q
    return np.array([[1 - 2*(y*y + z*z), 2*(x*y - w*z), 2*(x*z + w*y)],
                     [2*(x*y + w*z), 1 - 2*(x*x + z*z), 2*(y*z - w*x)],
                     [2*(x*z - w*y), 2*(y*z + w*x), 1 - 2*(x*x + y*y)]])


def euler_to_q(phi, th, psi):
    cr, sr = np.cos(phi/2), np.sin(phi/2)
    cp, sp = np.cos(th/2), np.sin(th/2)
    cy, sy = np.cos(psi/2), np.sin(psi/2)
    return np.array([cr*cp*cy + sr*sp*sy, sr*cp*cy - cr*sp*sy,
                     cr*sp*cy + sr*cp*sy, cr*cp*sy - sr*sp*cy])


def R_to_euler(R):
    return (np.arctan2(R[2, 1], R[2, 2]), -np.arcsin(np.clip(R[2, 0], -1, 1)),
            np.arctan2(R[1, 0], R[0, 0]))


class Vehicle:
    def __init__(self, tr):
        self.m = tr['mass']
        self.J = np.diag(tr['inertia'])
        self.Jinv = np.linalg.inv(self.J)
        self.l = tr['arm']
        self.KT = tr['K_T']
        self.b = tr['b']
        self.Kd = np.array(tr['Kd'])
        self.Jr = tr['J_r']
        self.r = POS * self.l
        self.Jd = tuple(tr['inertia'])

    def deriv(self, s, wcmd, wind, sag, tau_m):
        v, q, om, wm = s[3:6], s[6:10], s[10:13], s[13:17]
        R = qrot(q)
        wa = wm * np.sqrt(sag)                  # actual rotor speed (battery sag)
        T = self.KT * wa * wa
        Tsum = T.sum()
        drag = -self.Kd * (v - wind)
        Fw = -Tsum * R[:, 2] + drag             # non-gravitational force, world
        acc = Fw / self.m
        acc[2] += G
        l = self.l
        # r_i x (0,0,-T_i) = (-r_y T, r_x T, 0); plus layout
        tx = l * (T[3] - T[1])
        ty = l * (T[0] - T[2])
        tz = self.b * (SPIN @ (wa * wa))
        Om_r = SPIN @ wa
        p_, q_, r_ = om
        Jx, Jy, Jz = self.Jd
        # omega x e_z = (q, -p, 0)
        tx += self.Jr * Om_r * q_
        ty -= self.Jr * Om_r * p_
        dp = (tx - (q_ * Jz * r_ - r_ * Jy * q_)) / Jx
        dq_ = (ty - (r_ * Jx * p_ - p_ * Jz * r_)) / Jy
        dr = (tz - (p_ * Jy * q_ - q_ * Jx * p_)) / Jz
        qw, qx, qy, qz = q
        dquat = 0.5 * np.array([-qx*p_ - qy*q_ - qz*r_, qw*p_ + qy*r_ - qz*q_,
                                qw*q_ - qx*r_ + qz*p_, qw*r_ + qx*q_ - qy*p_])
        dwm = (wcmd - wm) / tau_m if tau_m > 0 else np.zeros(4)
        out = np.empty(17)
        out[0:3] = v; out[3:6] = acc; out[6:10] = dquat; out[10:13] = (dp, dq_, dr); out[13:17] = dwm
        return out, R.T @ Fw / self.m


class Controller:
    """Geometric cascade, its own (wrong) model of the vehicle."""

    def __init__(self, tr, rng):
        self.m = tr['mass'] * 1.05
        self.J = np.diag(np.array(tr['inertia']) * np.array([1.06, 0.94, 1.08]))
        self.KT = tr['K_T'] * 0.93
        self.b = tr['b'] * 1.10
        self.l = tr['arm']
        l, k, b = self.l, self.KT, self.b
        M = np.array([[k, k, k, k], [0, -l*k, 0, l*k], [l*k, 0, -l*k, 0], [-b, b, -b, b]])
        self.Minv = np.linalg.inv(M)
        self.ipos = np.zeros(3)
        ph = rng.uniform(0, 2*np.pi, (3, 5))
        fr = np.array([0.7, 1.3, 2.3, 3.7, 5.9])
        self.ms = lambda t: np.array([np.sum(np.sin(2*np.pi*fr*t + ph[j])) for j in range(3)]) / np.sqrt(2.5)
        self.ms_amp = np.array([0.045, 0.045, 0.012])   # N m RMS-ish torque excitation

    def __call__(self, t, s, ref):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        pr, vr, ar, psir = ref
        R = qrot(q)
        ep, ev = pr - p, vr - v
        self.ipos = np.clip(self.ipos + ep*TICK, -1, 1)
        a_des = ar + np.array([4.0, 4.0, 6.0])*ep + np.array([3.6, 3.6, 4.5])*ev + 0.8*self.ipos
        F = self.m * (a_des - G*np.array([0, 0, 1.0]))
        T = -F @ R[:, 2]
        b3 = -F / np.linalg.norm(F)
        c1 = np.array([np.cos(psir), np.sin(psir), 0.0])
        b2 = np.cross(b3, c1); b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        E = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([E[2, 1], E[0, 2], E[1, 0]])
        KR = np.array([2.8, 2.8, 1.6]); Kw = np.array([0.36, 0.36, 0.30])
        tau = -KR*eR - Kw*om + np.cross(om, self.J @ om) + self.ms_amp*self.ms(t)
        w2 = self.Minv @ np.array([T, *tau])
        return np.sqrt(np.clip(w2, W_MIN**2, W_MAX**2))


def make_ref(kind, dur, rng):
    """Smooth references: returns f(t) -> (p, v, a, psi)."""
    z0 = -2.5
    A = rng.uniform(0.8, 1.2)
    if kind == 'eight':
        om = 2*np.pi/rng.uniform(5.0, 7.0); Ax = 3.0*A; Ay = 1.5*A
        def f(t):
            p = np.array([Ax*np.sin(om*t), Ay*np.sin(2*om*t), z0 + 0.3*np.sin(0.5*om*t)])
            v = np.array([Ax*om*np.cos(om*t), 2*Ay*om*np.cos(2*om*t), 0.15*om*np.cos(0.5*om*t)])
            a = np.array([-Ax*om**2*np.sin(om*t), -4*Ay*om**2*np.sin(2*om*t), -0.075*om**2*np.sin(0.5*om*t)])
            return p, v, a, 0.4*np.sin(0.3*om*t)
    elif kind == 'steps':
        pts = rng.uniform(-1.2, 1.2, (8, 3)) * np.array([1, 1, 0.35])
        tk = np.linspace(0, dur, 9)
        def f(t):
            i = min(int(t / (dur/8)), 7); s = (t - tk[i]) / (dur/8)
            prev = pts[i-1] if i > 0 else np.zeros(3)
            sm = np.clip(s / 0.7, 0, 1); h = sm*sm*(3 - 2*sm)
            dh = (6*sm*(1 - sm)/0.7/(dur/8)) if s < 0.7 else 0.0
            p = prev + (pts[i] - prev)*h + np.array([0, 0, z0])
            return p, (pts[i] - prev)*dh, np.zeros(3), 0.6*((i % 3) - 1)*h
    elif kind == 'dash':
        om = 2*np.pi/rng.uniform(4.0, 5.5); L = 3.5*A; ang = rng.uniform(0, np.pi)
        d = np.array([np.cos(ang), np.sin(ang), 0.0])
        def f(t):
            s = L*np.sin(om*t)
            return (d*s + np.array([0, 0, z0]), d*L*om*np.cos(om*t),
                    -d*L*om**2*np.sin(om*t), ang + 0.2*np.sin(om*t))
    elif kind == 'climb':
        om = 2*np.pi/rng.uniform(3.5, 5.0)
        def f(t):
            p = np.array([0.8*np.sin(0.5*om*t), 0.5*np.cos(0.7*om*t) - 0.5, z0 - 1.0*np.sin(om*t)])
            v = np.array([0.4*om*np.cos(0.5*om*t), -0.35*om*np.sin(0.7*om*t), -om*np.cos(om*t)])
            a = np.array([-0.2*om**2*np.sin(0.5*om*t), -0.245*om**2*np.cos(0.7*om*t), om**2*np.sin(om*t)])
            return p, v, a, 1.2*np.sin(0.4*om*t)
    elif kind == 'yaw':
        om = 2*np.pi/rng.uniform(4.0, 6.0)
        def f(t):
            p = np.array([1.5*np.sin(om*t), 1.5*np.cos(om*t) - 1.5, z0])
            v = np.array([1.5*om*np.cos(om*t), -1.5*om*np.sin(om*t), 0])
            a = np.array([-1.5*om**2*np.sin(om*t), -1.5*om**2*np.cos(om*t), 0])
            return p, v, a, 2.5*np.sin(0.5*om*t)
    elif kind == 'hover':
        def f(t):
            return np.array([0, 0, z0]), np.zeros(3), np.zeros(3), 0.0
    else:
        raise ValueError(kind)
    return f


def fly(tr, kind, dur, seed, wind0=(0.0, 0.0), gust=0.0, sag=(0.0, 0.0),
        tau_m=TAU_M, noise=True, inputs='actual'):
    """Returns dict of arrays at tick rate (one row per controller tick)."""
    rng = np.random.default_rng(seed)
    veh = Vehicle(tr)
    ctl = Controller(tr, rng)
    ref = make_ref(kind, dur, rng)
    gph = rng.uniform(0, 2*np.pi, 2)
    w0 = np.array([*wind0, 0.0])

    def wind(t):
        return w0 + gust*np.array([np.sin(2*np.pi*0.11*t + gph[0]), np.sin(2*np.pi*0.07*t + gph[1]), 0])

    def sagf(t):
        return 1.0 + sag[0]*t + sag[1]*t*t

    p0, v0, a0, psi0 = ref(0.0)
    wh = np.sqrt(tr['mass']*G/(4*tr['K_T']))
    s = np.concatenate([p0, v0, euler_to_q(0, 0, psi0), np.zeros(3), np.full(4, wh)])
    n = int(round(dur / TICK)) + 1
    out = {k: np.zeros(n) for k in ['t', 'x', 'y', 'z', 'phi', 'theta', 'psi', 'vx', 'vy', 'vz',
                                    'p', 'q', 'r', 'ax', 'ay', 'az']}
    W = np.zeros((n, 4)); Wc = np.zeros((n, 4))
    h = TICK / SUB
    for k in range(n):
        t = k*TICK
        wc = ctl(t, s, ref(t))
        if tau_m <= 0:
            s[13:17] = wc
        _, fb = veh.deriv(s, wc, wind(t), sagf(t), tau_m)
        R = qrot(s[6:10]); ph, th, ps = R_to_euler(R)
        out['t'][k] = t
        for j, c in enumerate('xyz'): out[c][k] = s[j]
        out['vx'][k], out['vy'][k], out['vz'][k] = s[3:6]
        out['phi'][k], out['theta'][k], out['psi'][k] = ph, th, ps
        out['p'][k], out['q'][k], out['r'][k] = s[10:13]
        out['ax'][k], out['ay'][k], out['az'][k] = fb
        W[k] = s[13:17]; Wc[k] = wc
        if k == n - 1:
            break
        for _ in range(SUB):
            tt = t + _*h
            k1, _a = veh.deriv(s, wc, wind(tt), sagf(tt), tau_m)
            k2, _a = veh.deriv(s + h/2*k1, wc, wind(tt + h/2), sagf(tt + h/2), tau_m)
            k3, _a = veh.deriv(s + h/2*k2, wc, wind(tt + h/2), sagf(tt + h/2), tau_m)
            k4, _a = veh.deriv(s + h*k3, wc, wind(tt + h), sagf(tt + h), tau_m)
            s = s + h/6*(k1 + 2*k2 + 2*k3 + k4)
            if tau_m <= 0:
                s[13:17] = wc
            s[6:10] /= np.linalg.norm(s[6:10])
    out['W'] = W if inputs == 'actual' else Wc
    return out


def write_log(path, o, rng, noise=True, pos_rate=50, swap=None, drop_p=0.03):
    n = len(o['t'])
    cols = {'t': o['t']}
    W = o['W'].copy()
    if noise:
        W = W + rng.normal(0, 0.5, W.shape)
    if swap:
        i, j = swap
        W[:, [i, j]] = W[:, [j, i]]
    for i in range(4):
        cols[f'w{i+1}'] = W[:, i]
    step = int(round(250 / pos_rate))
    for c, sd in [('x', 0.006), ('y', 0.006), ('z', 0.008)]:
        v = o[c] + (rng.normal(0, sd, n) if noise else 0)
        m = np.full(n, np.nan); m[::step] = v[::step]
        if noise:
            drop = rng.random(n) < drop_p
            m[drop] = np.nan
            m[0] = v[0]
        cols[c] = m
    for c, sd in [('phi', 0.002), ('theta', 0.002), ('psi', 0.003)]:
        v = o[c] + (rng.normal(0, sd, n) if noise else 0)
        if c == 'psi':
            v = (v + np.pi) % (2*np.pi) - np.pi
        cols[c] = v
    for c, sd in [('p', 0.01), ('q', 0.01), ('r', 0.01)]:
        cols[c] = o[c] + (rng.normal(0, sd, n) if noise else 0)
    for c, sd in [('ax', 0.08), ('ay', 0.08), ('az', 0.08)]:
        cols[c] = o[c] + (rng.normal(0, sd, n) if noise else 0)
    keys = list(cols)
    M = np.column_stack([cols[k] for k in keys])
    with open(path, 'w') as f:
        f.write(','.join(keys) + '\n')
        for row in M:
            f.write(','.join('' if np.isnan(v) else f'{v:.9g}' for v in row) + '\n')


def airframe(path, tr, guess=True, name='plus16'):
    KT = tr['K_T']*1.25 if guess else tr['K_T']
    b = tr['b']*0.7 if guess else tr['b']
    Kd = [0.1, 0.1, 0.1] if guess else tr['Kd']
    with open(path, 'w') as f:
        f.write(f"""[airframe]
name = "{name}"
mass = {tr['mass']}
inertia = [{tr['inertia'][0]}, {tr['inertia'][1]}, {tr['inertia'][2]}]
arm_length = {tr['arm']}
layout = "plus"
rotor_inertia = {tr['J_r']}
gravity = 9.81

[parameters]
K_T = {KT:.6g}
b = {b:.6g}
Kd = [{Kd[0]}, {Kd[1]}, {Kd[2]}]
""")


# Flight plans: (name, kind, duration, seed, wind (N,E), gust, sag (a1, a2))
CASE1 = [('c1_f1', 'eight', 14, 11), ('c1_f2', 'steps', 16, 12), ('c1_f3', 'dash', 12, 13),
         ('c1_f4', 'climb', 10, 14), ('c1_f5', 'yaw', 18, 15), ('c1_f6', 'eight', 9, 16),
         ('c1_v1', 'steps', 15, 17), ('c1_v2', 'dash', 12, 18)]
# case 2: per-flight wind and a battery sag that grows as the charge falls flight to flight
CASE2 = [('c2_f1', 'eight', 14, 21, (1.2, 0.4), 0.10, (-0.0010, -1.0e-5)),
         ('c2_f2', 'steps', 16, 22, (-0.6, 1.5), 0.10, (-0.0013, -1.5e-5)),
         ('c2_f3', 'dash', 12, 23, (0.3, -1.8), 0.12, (-0.0016, -2.0e-5)),
         ('c2_f4', 'climb', 10, 24, (2.0, 0.0), 0.12, (-0.0019, -2.5e-5)),
         ('c2_f5', 'yaw', 18, 25, (-1.4, -1.0), 0.10, (-0.0022, -3.0e-5)),
         ('c2_f6', 'eight', 9, 26, (0.8, 1.2), 0.08, (-0.0026, -3.5e-5)),
         ('c2_v1', 'steps', 15, 27, (1.0, -0.7), 0.10, (-0.0015, -2.0e-5))]
OTHER = dict(mass=2.10, inertia=[0.026, 0.026, 0.046], arm=0.27,
             K_T=1.75e-5, b=3.3e-7, Kd=[0.25, 0.25, 0.35], J_r=1.0e-4)


def main(outdir):
    os.makedirs(outdir, exist_ok=True)
    tr = TRUTH
    airframe(os.path.join(outdir, 'airframe.toml'), tr, guess=True)
    airframe(os.path.join(outdir, 'airframe_true.toml'), tr, guess=False)
    truth = {'vehicle': tr, 'flights': {}}
    # convention checks: instant motors, inputs held over each tick, no noise
    for name, kw in [('check1', {}), ('check2', dict(wind0=(1.5, -0.8), sag=(-0.003, 0.0)))]:
        o = fly(tr, 'eight', 6, 99, tau_m=0.0, noise=False, **kw)
        with open(os.path.join(outdir, f'{name}_U.csv'), 'w') as f:
            f.write('t,w1,w2,w3,w4\n')
            for k in range(len(o['t'])):
                f.write(f"{o['t'][k]:.6f}," + ','.join(f'{v:.12g}' for v in o['W'][k]) + '\n')
        np.savez(os.path.join(outdir, f'{name}_truth.npz'), **{k: v for k, v in o.items()})
        k0 = 0
        x0 = [o['x'][k0], o['y'][k0], o['z'][k0], o['phi'][k0], o['theta'][k0], o['psi'][k0],
              o['vx'][k0], o['vy'][k0], o['vz'][k0], o['p'][k0], o['q'][k0], o['r'][k0]]
        truth['flights'][name] = {'x0': x0, **{k: v for k, v in kw.items()}}
    for name, kind, dur, seed in CASE1:
        o = fly(tr, kind, dur, seed)
        write_log(os.path.join(outdir, name + '.csv'), o, np.random.default_rng(seed + 1000))
        truth['flights'][name] = dict(kind=kind, dur=dur, vmax=float(np.max(np.hypot(o['vx'], o['vy']))),
                                      tilt_max_deg=float(np.degrees(np.max(np.hypot(o['phi'], o['theta'])))))
        print(name, kind, dur, 'vmax %.2f' % truth['flights'][name]['vmax'], flush=True)
    for name, kind, dur, seed, wnd, gust, sag in CASE2:
        o = fly(tr, kind, dur, seed, wind0=wnd, gust=gust, sag=sag)
        write_log(os.path.join(outdir, name + '.csv'), o, np.random.default_rng(seed + 1000))
        tt = np.linspace(0, dur, 1001); f = 1 + sag[0]*tt + sag[1]*tt**2
        lin = np.polyfit(tt, f - 1, 1)   # least-squares linear K_T_drift equivalent (through free intercept)
        lin0 = float(np.sum(tt*(f - 1))/np.sum(tt*tt))   # through zero
        truth['flights'][name] = dict(kind=kind, dur=dur, tilt_max_deg=float(np.degrees(np.max(np.hypot(o['phi'], o['theta'])))), wind=list(wnd), gust=gust, sag=list(sag),
                                      K_T_drift_equiv=lin0, sag_end=float(f[-1]),
                                      vmax=float(np.max(np.hypot(o['vx'], o['vy']))))
        print(name, kind, dur, wnd, 'drift~%.3g' % lin0, flush=True)
    # case 3: bad flights a user makes
    o = fly(tr, 'dash', 12, 23, wind0=(0.3, -1.8), gust=0.12, sag=(-0.0016, -2.0e-5))
    write_log(os.path.join(outdir, 'c3_swap.csv'), o, np.random.default_rng(1023), swap=(1, 3))
    o = fly(tr, 'hover', 4, 31, wind0=(0.5, 0.5), gust=0.0, sag=(-0.001, 0))
    write_log(os.path.join(outdir, 'c3_short.csv'), o, np.random.default_rng(1031))
    o = fly(OTHER, 'eight', 12, 32, wind0=(0.7, 0.9), gust=0.1, sag=(-0.0015, -1e-5))
    write_log(os.path.join(outdir, 'c3_other.csv'), o, np.random.default_rng(1032))
    truth['flights']['c3_swap'] = 'c2_f3 flown again, w2 and w4 columns swapped'
    truth['flights']['c3_short'] = '4 s hover, wind (0.5,0.5), sag -0.001/s'
    truth['flights']['c3_other'] = dict(vehicle=OTHER, note='a different 2.1 kg vehicle')
    with open(os.path.join(outdir, 'truth.json'), 'w') as f:
        json.dump(truth, f, indent=1)


if __name__ == '__main__':
    main(sys.argv[1] if len(sys.argv) > 1 else 'data')

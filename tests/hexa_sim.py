"""Independent hexacopter simulator of a blind audit (2026-12-01, the ninth), kept as a test
generator that is not greybox's own: written from ``CONTRACT.md`` and the README alone, without
reading the package, and checked against ``greybox simulate`` (3 s open loop, jittered inputs:
1.2e-13 m, 1.4e-14 rad, 3e-14 m/s^2) before any diagnosis.

NED world, FRD body, quaternion attitude, fixed-step RK4 at 0.5 ms or finer. Six rotors on a
0.25 m circle, alternating spins, 1.8 kg, 30 ms motor lag; a geometric attitude controller with a
cascaded position PID at 400 Hz on noisy feedback and a mismatched internal model, a 2 % multisine
on the commands. The log: 200 Hz with +-0.5 ms jitter, the rotors' actual speeds with
multiplicative white noise (``speed_noise``, an ESC's telemetry), position at 50 Hz with dropouts
and a 0.3 s outage, attitude, gyro, accelerometer. Cases: ``none``, ``cog`` (CoG offset 15, -10
mm), ``asym`` (rotor 3 at 92 % thrust and torque), ``tlift`` (thrust x (1 + 0.06 |v_h,body|^2),
outside the catalogue).

    python tests/hexa_sim.py fly --case none --seed 1 --dur 36 --out F.csv
    python -c "import hexa_sim; hexa_sim.write_airframe('A.toml', 1.4, 0.6, 0.5)"
"""
import numpy as np, sys, argparse

G = 9.81
M = 1.8
J = np.diag([0.03, 0.03, 0.055])
JINV = np.linalg.inv(J)
ARM = 0.25
ANG = np.deg2rad(np.arange(6) * 60.0)          # rotor 1 front, counter-clockwise seen from above? (y right)
RPOS = np.stack([ARM * np.cos(ANG), ARM * np.sin(ANG), np.zeros(6)], 1)
SPIN = np.array([1, -1, 1, -1, 1, -1], float)
KT = 7.0e-6          # hover ~ 648 rad/s
BQ = 1.1e-7          # b/K_T = 0.0157 m
KD = np.array([0.25, 0.25, 0.35])
JR = 2.5e-5
TAU_M = 0.030


def qmul(a, b):
    w1, x1, y1, z1 = a; w2, x2, y2, z2 = b
    return np.array([w1*w2-x1*x2-y1*y2-z1*z2, w1*x2+x1*w2+y1*z2-z1*y2,
                     w1*y2-x1*z2+y1*w2+z1*x2, w1*z2+x1*y2-y1*x2+z1*w2])


def qrot(q):
    w, x, y, z = q
    return np.array([[1-2*(y*y+z*z), 2*(x*y-w*z), 2*(x*z+w*y)],
                     [2*(x*y+w*z), 1-2*(x*x+z*z), 2*(y*z-w*x)],
                     [2*(x*z-w*y), 2*(y*z+w*x), 1-2*(x*x+y*y)]])


def euler2q(phi, th, psi):
    cr, sr = np.cos(phi/2), np.sin(phi/2); cp, sp = np.cos(th/2), np.sin(th/2); cy, sy = np.cos(psi/2), np.sin(psi/2)
    return np.array([cr*cp*cy+sr*sp*sy, sr*cp*cy-cr*sp*sy, cr*sp*cy+sr*cp*sy, cr*cp*sy-sr*sp*cy])


def r2euler(R):
    return np.array([np.arctan2(R[2, 1], R[2, 2]), -np.arcsin(np.clip(R[2, 0], -1, 1)), np.arctan2(R[1, 0], R[0, 0])])


class Truth:
    def __init__(self, case):
        self.case = case
        self.kt = np.full(6, KT); self.bq = np.full(6, BQ)
        self.rcog = np.zeros(3)
        self.tl = 0.0
        if case == 'cog':
            self.rcog = np.array([0.015, -0.010, 0.0])
        if case == 'asym':
            self.kt[2] *= 0.92; self.bq[2] *= 0.92
        if case == 'tlift':
            self.tl = 0.06     # thrust x (1 + tl*|v_h,body|^2)
        self.lag = case != 'openloop'

    def forces(self, x, w):
        v = x[3:6]; q = x[6:10]; om = x[10:13]
        R = qrot(q)
        T = self.kt * w * w
        if self.tl:
            vb = R.T @ v
            T = T * (1 + self.tl * (vb[0]**2 + vb[1]**2))
        Ts = T.sum()
        fb = np.array([0.0, 0.0, -Ts])
        ax_ = RPOS[:, 0] - self.rcog[0]; ay_ = RPOS[:, 1] - self.rcog[1]
        Om = float(SPIN @ w)
        tau = np.array([-(ay_ @ T) + JR * Om * om[1], (ax_ @ T) - JR * Om * om[0],
                        float((SPIN * self.bq) @ (w * w))])
        fw = -Ts * R[:, 2] - KD * v
        return R, fb, fw, tau

    def f(self, x, wcmd):
        w = x[13:19] if self.lag else wcmd
        R, fb, fw, tau = self.forces(x, w)
        om = x[10:13]; q = x[6:10]
        dx = np.empty(19)
        dx[0:3] = x[3:6]
        dx[3:6] = fw / M + np.array([0, 0, G])
        w0, x1, y1, z1 = q; p, q_, r = om
        dx[6] = 0.5*(-x1*p - y1*q_ - z1*r); dx[7] = 0.5*(w0*p + y1*r - z1*q_)
        dx[8] = 0.5*(w0*q_ - x1*r + z1*p); dx[9] = 0.5*(w0*r + x1*q_ - y1*p)
        p, q_, r = om
        Jx, Jy, Jz = 0.03, 0.03, 0.055
        dx[10] = (tau[0] - (q_*r*Jz - r*q_*Jy)) / Jx
        dx[11] = (tau[1] - (r*p*Jx - p*r*Jz)) / Jy
        dx[12] = (tau[2] - (p*q_*Jy - q_*p*Jx)) / Jz
        dx[13:19] = (wcmd - x[13:19]) / TAU_M if self.lag else 0.0
        return dx

    def rk4(self, x, wcmd, h):
        k1 = self.f(x, wcmd); k2 = self.f(x + h/2*k1, wcmd)
        k3 = self.f(x + h/2*k2, wcmd); k4 = self.f(x + h*k3, wcmd)
        x = x + h/6*(k1 + 2*k2 + 2*k3 + k4)
        x[6:10] /= np.linalg.norm(x[6:10])
        return x

    def advance(self, x, wcmd, T, hmax=5e-4):
        n = max(1, int(np.ceil(T / hmax - 1e-9)))
        for _ in range(n):
            x = self.rk4(x, wcmd, T / n)
        return x


# allocation for the controller (nominal rotor table, nominal K_T, b)
def alloc(kt, bq):
    A = np.zeros((4, 6))
    A[0] = kt
    A[1] = -RPOS[:, 1] * kt
    A[2] = RPOS[:, 0] * kt
    A[3] = SPIN * bq
    return np.linalg.pinv(A)


def vee(S):
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


def reference(rng, dur, dt):
    """Piecewise set-points (steps, circles, altitude, yaw) through a 2nd-order prefilter."""
    n = int(round(dur / dt)) + 1
    sp = np.zeros((n, 3)); yaw = np.zeros(n)
    cur = np.array([0.0, 0.0, -1.5]); cyaw = 0.0
    t = 0.0; i = 0; order = []
    kinds = ['hover', 'step_x', 'step_y', 'step_z', 'circle', 'yaw', 'step_xy', 'circle', 'step_z']
    while i < n:
        if t <= 2.0: k = 'hover'
        else:
            if not order: order = list(rng.permutation(kinds))
            k = order.pop()
        L = rng.uniform(3.0, 5.0)
        m = int(L / dt)
        if k == 'step_x': cur = cur + [rng.choice([-1, 1]) * rng.uniform(1.0, 1.8), 0, 0]
        if k == 'step_y': cur = cur + [0, rng.choice([-1, 1]) * rng.uniform(1.0, 1.8), 0]
        if k == 'step_xy': cur = cur + np.r_[rng.uniform(-1.5, 1.5, 2), 0]
        if k == 'step_z': cur[2] = -rng.uniform(0.8, 2.8)
        if k == 'yaw': cyaw = rng.uniform(-1.0, 1.0)
        cur[:2] = np.clip(cur[:2], -3, 3)
        for j in range(m):
            if i >= n: break
            if k == 'circle':
                L2 = 8.0; m2 = int(L2 / dt)
                if j >= m2: break
                ph = 1.0 * j * dt
                sp[i] = cur + 1.2 * np.array([np.cos(ph) - 1, np.sin(ph), 0]) * (1 if rng.random() < 2 else 1)
            else:
                sp[i] = cur
            yaw[i] = cyaw
            i += 1
        t = i * dt
    # prefilter
    for i in range(1, n):
        sp[i] = sp[i-1] + dt / 0.4 * (sp[i] - sp[i-1])
    wn = 1.8
    p = np.zeros((n, 3)); v = np.zeros((n, 3)); a = np.zeros((n, 3))
    p[0] = sp[0]
    for i in range(1, n):
        a[i-1] = wn**2 * (sp[i-1] - p[i-1]) - 2 * wn * v[i-1]
        v[i] = v[i-1] + dt * a[i-1]
        p[i] = p[i-1] + dt * v[i]
    a[-1] = a[-2]
    yf = np.zeros(n)
    for i in range(1, n):
        yf[i] = yf[i-1] + dt * 1.5 * (yaw[i-1] - yf[i-1])
    return p, v, a, yf


def fly(case, seed, dur, out, truth_out=None, speed_noise=0.01):
    rng = np.random.default_rng(seed)
    tr = Truth(case)
    dtc = 1 / 400.
    pr, vr, ar, yr = reference(rng, dur + 0.1, dtc)
    ctrl_kt, ctrl_b = KT * 1.05, BQ * 0.95          # controller's mismatched internal model
    Ainv = alloc(ctrl_kt, ctrl_b)
    # excitation multisine on commands (2 % each rotor)
    fr = rng.uniform(0.3, 9.0, (6, 8)); ph = rng.uniform(0, 2*np.pi, (6, 8))
    wh = np.sqrt(M * G / (6 * KT))
    x = np.zeros(19)
    x[0:3] = pr[0]; x[6:10] = euler2q(0, 0, 0); x[13:19] = wh
    # log times: 200 Hz with +-0.5 ms jitter
    nlog = int(dur / 0.005)
    tlog = np.arange(nlog) * 0.005 + rng.uniform(-5e-4, 5e-4, nlog); tlog[0] = 0.0
    nc = int(dur / dtc) + 1
    tc = np.arange(nc) * dtc
    ev = np.unique(np.r_[tc, tlog])
    ev = ev[ev <= tlog[-1] + 1e-12]
    ilog = {float(t): k for k, t in enumerate(tlog)}
    rows = np.zeros((nlog, 19)); acc = np.zeros((nlog, 3)); wc_log = np.zeros((nlog, 6))
    ipos = np.zeros(3); iatt = np.zeros(3)
    wcmd = np.full(6, wh)
    kc = 0
    for i, t in enumerate(ev):
        if abs(t - kc * dtc) < 1e-12:          # controller tick
            pos_m = x[0:3] + rng.normal(0, 0.002, 3); vel_m = x[3:6] + rng.normal(0, 0.02, 3)
            R = qrot(x[6:10])
            dn = rng.normal(0, 0.003, 3)
            Rn = R @ qrot(np.r_[1.0, dn/2] / np.linalg.norm(np.r_[1.0, dn/2]))
            om_m = x[10:13] + rng.normal(0, 0.01, 3)
            e = pr[kc] - pos_m
            ipos = np.clip(ipos + e * dtc, -2, 2)
            acmd = ar[kc] + np.array([4, 4, 6.]) * e + np.array([3.5, 3.5, 4.5]) * (vr[kc] - vel_m) + np.array([1.0, 1.0, 2.0]) * ipos
            fvec = M * (acmd - np.array([0, 0, G]))          # desired thrust force, world
            b3 = -fvec / np.linalg.norm(fvec)
            # tilt limit
            b1c = np.array([np.cos(yr[kc]), np.sin(yr[kc]), 0])
            b2 = np.cross(b3, b1c); b2 /= np.linalg.norm(b2)
            b1 = np.cross(b2, b3)
            Rd = np.stack([b1, b2, b3], 1)
            Tcmd = float(fvec @ (-Rn[:, 2]))
            eR = 0.5 * vee(Rd.T @ Rn - Rn.T @ Rd)
            iatt = np.clip(iatt + eR * dtc, -0.5, 0.5)
            kR = np.array([6.5, 6.5, 3.5]); kw = np.array([0.75, 0.75, 0.7]); kI = np.array([4.0, 4.0, 1.0])
            tau = -kR * eR - kw * om_m - kI * iatt + np.cross(om_m, J @ om_m)
            w2 = Ainv @ np.r_[Tcmd, tau]
            wcmd = np.sqrt(np.clip(w2, 150.0**2, 1100.0**2))
            wcmd = wcmd * (1 + 0.02 * np.sin(2*np.pi*fr*t + ph).sum(1) / np.sqrt(4))
            kc += 1
        k = ilog.get(float(t))
        if k is not None:
            rows[k] = x
            wc_log[k] = wcmd
            R, fb, fw, tau = tr.forces(x, x[13:19] if tr.lag else wcmd)
            acc[k] = R.T @ (fw / M)               # specific force in body
        if i + 1 < len(ev):
            x = tr.advance(x, wcmd, ev[i+1] - t)
    # measurements
    eul = np.array([r2euler(qrot(q)) for q in rows[:, 6:10]])
    n = nlog
    data = {'t': tlog}
    wl = rows[:, 13:19] * (1 + rng.normal(0, speed_noise, (n, 6)))
    for j in range(6): data[f'w{j+1}'] = wl[:, j]
    pos = rows[:, 0:3] + rng.normal(0, 0.0015, (n, 3))
    vis = (np.arange(n) % 4 == 0)
    vis &= rng.random(n) > 0.04                  # random dropouts
    s = rng.integers(n // 3, 2 * n // 3); vis[s:s + 60] = False   # a 0.3 s outage
    for j, c in enumerate('xyz'):
        col = np.where(vis, pos[:, j], np.nan); data[c] = col
    att = eul + rng.normal(0, [0.002, 0.002, 0.004], (n, 3))
    att[:, 2] = (att[:, 2] + np.pi) % (2*np.pi) - np.pi
    for j, c in enumerate(['phi', 'theta', 'psi']): data[c] = att[:, j]
    gy = rows[:, 10:13] + rng.normal(0, 0.008, (n, 3))
    for j, c in enumerate('pqr'): data[c] = gy[:, j]
    ac = acc + rng.normal(0, 0.05, (n, 3))
    for j, c in enumerate(['ax', 'ay', 'az']): data[c] = ac[:, j]
    cols = list(data)
    with open(out, 'w') as fh:
        fh.write(','.join(cols) + '\n')
        for i in range(n):
            fh.write(','.join('' if np.isnan(data[c][i]) else repr(float(data[c][i])) for c in cols) + '\n')
    if truth_out:
        np.savez(truth_out, t=tlog, state=rows, wcmd=wc_log, eul=eul)
    print(f'{out}: {n} rows, z range {rows[:,2].min():.2f}..{rows[:,2].max():.2f}, '
          f'vmax {np.linalg.norm(rows[:,3:6],axis=1).max():.2f}, tilt max {np.degrees(np.abs(eul[:,:2]).max()):.1f} deg, '
          f'w {rows[:,13:19].min():.0f}..{rows[:,13:19].max():.0f}', file=sys.stderr)


def write_airframe(path, kt_factor=1.0, b_factor=1.0, kd_factor=1.0, name="hexa"):
    """The airframe TOML a user would write: true geometry and inertia, starting guesses the
    true K_T, b and Kd times the factors."""
    s = (f'[airframe]\nname = "{name}"\nmass = {M!r}\ninertia = [0.03, 0.03, 0.055]\narm_length = {ARM!r}\n'
         f'rotor_inertia = {JR!r}\ngravity = {G!r}\n')
    for r, sp in zip(RPOS, SPIN):
        s += f'\n[[rotor]]\nposition = [{float(r[0])!r}, {float(r[1])!r}, 0.0]\nspin = {int(sp)}\n'
    kd = KD * kd_factor
    s += f'\n[parameters]\nK_T = {KT * kt_factor!r}\nb = {BQ * b_factor!r}\nKd = [{float(kd[0])!r}, {float(kd[1])!r}, {float(kd[2])!r}]\n'
    with open(path, 'w') as fh:
        fh.write(s)


def openloop(inp, out):
    """Open-loop integration of held logged inputs (for the check against greybox simulate)."""

    d = np.genfromtxt(inp, delimiter=',', names=True)
    t = d['t']; W = np.stack([d[f'w{j+1}'] for j in range(6)], 1)
    tr = Truth('openloop')
    x = np.zeros(19); x[6] = 1.0
    res = []
    for k in range(len(t)):
        R = qrot(x[6:10]); _, _, fw, _ = tr.forces(x, W[k]); res.append(np.r_[x[0:3], r2euler(R), x[10:13], x[3:6], R.T @ (fw / M)])
        if k + 1 < len(t):
            x = tr.advance(x, W[k], t[k+1] - t[k], hmax=2.5e-4)
    res = np.array(res)
    np.savetxt(out, np.c_[t, res], delimiter=',', header='t,x,y,z,phi,theta,psi,p,q,r,vx,vy,vz,ax,ay,az', comments='')


if __name__ == '__main__':
    ap = argparse.ArgumentParser()
    ap.add_argument('mode'); ap.add_argument('--case', default='none'); ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--dur', type=float, default=36.0); ap.add_argument('--out'); ap.add_argument('--inp')
    ap.add_argument('--speed-noise', type=float, default=0.01)
    a = ap.parse_args()
    if a.mode == 'fly':
        fly(a.case, a.seed, a.dur, a.out, a.out.replace('.csv', '.truth.npz'), speed_noise=a.speed_noise)
    else:
        openloop(a.inp, a.out)

"""Independent quadrotor simulator of a blind audit (2026-12-05, the seventeenth), kept as a
test generator that is not greybox's own: written from ``README.md`` and ``CONTRACT.md``
alone, without reading the package, and checked against ``greybox simulate`` to 1e-12 in open
loop (frames, Euler angles, the X layout's rotor order and spins, yaw and gyroscopic signs, the
accelerometer; 1.6e-9 with rotor drag, motor lag or wind). A 0.55 kg 250-class "x" quadrotor
under a geometric controller with a multisine on its commands, the commands logged at the
controller's 250 Hz and held (zero-order) to first-order motors that start at the hover speed
while the first command is elsewhere (as a log cut in flight has them). The audit's
``sim.py`` with its ``gen.py`` cases as :func:`flight`; the physics and numbers are the audit's.

The audit's description:
Independent quadrotor simulator for the greybox audit (audit17).

Conventions (from the public contract): world NED, body FRD, thrust K_T w^2 along body -z,
reaction torque spin_i*b*w_i^2 about body +z, gyroscopic torque J_r*Omega_r*(omega x e_z),
Omega_r = sum(spin_i w_i). X layout: rotor1 (+a,+a) spin+1, rotor2 (-a,-a) +1,
rotor3 (+a,-a) -1, rotor4 (-a,+a) -1.

Attitude is integrated as a quaternion (independent of greybox's Euler form);
solve_ivp (RK45, tight tolerances) between control/log instants; commands held (ZOH).
Physical extras: first-order motor lag tau_m (on the actual speed), battery scaling
w_target = w_cmd*(1+K_vbat*(vbat-4)), body-frame rotor drag -k_rd*sum(w)*[vbx,vby,0],
world-frame linear drag -Kd*v.
"""

import math
import numpy as np
from scipy.integrate import solve_ivp

G = 9.81
TRUE = dict(mass=0.55, inertia=[0.0028, 0.0030, 0.0052], arm=0.125, J_r=8e-6,
            K_T=1.35e-6, b=2.1e-8, Kd=[0.06, 0.07, 0.10], tau_m=0.020,
            K_vbat=0.0, k_rd=0.0, ge_k=0.0)


def geometry(arm):
    a = arm / math.sqrt(2)
    pos = np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]], float)
    spin = np.array([1, 1, -1, -1], float)
    return pos, spin


def qmul(a, b):
    w1, x1, y1, z1 = a; w2, x2, y2, z2 = b
    return np.array([w1*w2-x1*x2-y1*y2-z1*z2, w1*x2+x1*w2+y1*z2-z1*y2,
                     w1*y2-x1*z2+y1*w2+z1*x2, w1*z2+x1*y2-y1*x2+z1*w2])


def qrot(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1-2*(y*y+z*z), 2*(x*y-w*z), 2*(x*z+w*y)],
                     [2*(x*y+w*z), 1-2*(x*x+z*z), 2*(y*z-w*x)],
                     [2*(x*z-w*y), 2*(y*z+w*x), 1-2*(x*x+y*y)]])


def euler_to_q(phi, th, psi):
    cr, sr = math.cos(phi/2), math.sin(phi/2)
    cp, sp = math.cos(th/2), math.sin(th/2)
    cy, sy = math.cos(psi/2), math.sin(psi/2)
    return np.array([cr*cp*cy+sr*sp*sy, sr*cp*cy-cr*sp*sy, cr*sp*cy+sr*cp*sy, cr*cp*sy-sr*sp*cy])


def R_to_euler(R):
    return math.atan2(R[2, 1], R[2, 2]), -math.asin(max(-1, min(1, R[2, 0]))), math.atan2(R[1, 0], R[0, 0])


class Quad:
    def __init__(self, P):
        self.P = P
        self.pos, self.spin = geometry(P['arm'])
        self.J = np.diag(P['inertia'])
        self.Jinv = np.linalg.inv(self.J)
        self.Kd = np.array(P['Kd'])

    def forces(self, s, wact):
        """body-frame force (without gravity), world drag, body torque."""
        P = self.P
        v = s[3:6]; q = s[6:10]; om = s[10:13]
        R = qrot(q)
        dev = np.array(P.get('kt_dev', [0, 0, 0, 0]), float)   # motor_asymmetry: thrust and torque x (1+d_i)
        T_i = P['K_T'] * wact**2 * (1 + dev)
        if P.get('ge_k', 0) > 0:  # per-rotor ground effect (rotor height above z=0)
            zr = s[2] + (R @ self.pos.T)[2]
            h = np.maximum(-zr, 0.05)
            T_i = T_i / (1 - np.minimum(P['ge_k'] / h**2, 0.5))
        Fb = np.array([0, 0, -T_i.sum()])
        wind = np.array([*P.get('wind', [0.0, 0.0]), 0.0])
        v = v - wind                      # air-relative velocity (wind effect: drags act on v - wind)
        vb = R.T @ v
        if P.get('k_rd', 0):
            Fb = Fb + np.array([-P['k_rd']*wact.sum()*vb[0], -P['k_rd']*wact.sum()*vb[1], 0])
        Fw_drag = -self.Kd * v
        tau = np.zeros(3)
        for i in range(4):
            tau += np.cross(self.pos[i], np.array([0, 0, -T_i[i]]))
        tau[2] += P['b'] * np.sum(self.spin * wact**2 * (1 + dev))
        Om = np.sum(self.spin * wact)
        tau += P['J_r'] * Om * np.cross(om, [0, 0, 1.0])
        return R, Fb, Fw_drag, tau

    def deriv(self, t, s, wtarget, lag):
        # s = [p(3), v(3), q(4), om(3), w(4)]
        wact = s[13:17] if lag else wtarget
        R, Fb, Fw, tau = self.forces(s, wact)
        m = self.P['mass']
        om = s[10:13]
        acc = np.array([0, 0, G]) + (R @ Fb + Fw) / m
        qd = 0.5 * qmul(s[6:10], np.array([0, *om]))
        omd = self.Jinv @ (tau - np.cross(om, self.J @ om))
        wd = (wtarget - s[13:17]) / self.P['tau_m'] if lag else np.zeros(4)
        return np.concatenate([s[3:6], acc, qd, omd, wd])

    def specific_force(self, s, lag, wtarget):
        wact = s[13:17] if lag else wtarget
        R, Fb, Fw, tau = self.forces(s, wact)
        return (Fb + R.T @ Fw) / self.P['mass']


def step(quad, s, wt, dt, lag):
    sol = solve_ivp(quad.deriv, (0, dt), s, args=(wt, lag), method='RK45', rtol=1e-10, atol=1e-11)
    s = sol.y[:, -1].copy()
    s[6:10] /= np.linalg.norm(s[6:10])
    return s


def outputs(s):
    R = qrot(s[6:10])
    phi, th, psi = R_to_euler(R)
    return np.array([*s[0:3], phi, th, psi, *s[10:13]])


def open_loop(P, t, W, x0=None, lag=False):
    """Open-loop simulation from held rotor speeds W (N x 4) at times t."""
    quad = Quad(P)
    s = np.zeros(17); s[6] = 1.0
    if x0 is not None:
        s[0:3] = x0[0:3]; s[6:10] = euler_to_q(*x0[3:6]); s[3:6] = x0[6:9]; s[10:13] = x0[9:12]
    s[13:17] = W[0]
    out = [outputs(s)]
    for k in range(len(t) - 1):
        s = step(quad, s, W[k], t[k+1]-t[k], lag)
        out.append(outputs(s))
    return np.array(out)


# ---------------------------------------------------------------- closed loop
def reference(t, rng, dur, z0=-1.5, amp=1.0):
    """A smooth reference built from random segments (figure-8, steps, yaw)."""
    # sum of sinusoids with random freq/phase + smoothed steps
    fx = rng.uniform(0.15, 0.45, 3); px = rng.uniform(0, 2*np.pi, 3)
    fy = rng.uniform(0.15, 0.45, 3); py = rng.uniform(0, 2*np.pi, 3)
    fz = rng.uniform(0.1, 0.3, 2); pz = rng.uniform(0, 2*np.pi, 2)
    fpsi = rng.uniform(0.05, 0.2); ppsi = rng.uniform(0, 2*np.pi)
    ramp = np.minimum(1.0, t / 2.0)  # soft start
    def S(f, ph, A):
        return sum(A*np.sin(2*np.pi*fi*t + pi_) for fi, pi_ in zip(f, ph))
    x = ramp * S(fx, px, amp)
    y = ramp * S(fy, py, amp)
    z = z0 + ramp * S(fz, pz, 0.35*amp)
    psi = ramp * 0.8 * np.sin(2*np.pi*fpsi*t + ppsi)
    # remove initial offsets (start at rest near origin)
    return x - x[0], y - y[0], z, psi - psi[0]


def closed_loop(P, nominal, dur=15.0, rate=250.0, seed=0, vbat0=4.0, vbat_sag=0.0,
                amp=1.0, z0=-1.5, excite=0.02, start_z=None, ground_pass=False, takeoff=False, consistent_start=False):
    rng = np.random.default_rng(seed)
    quad = Quad(P)
    dt = 1.0 / rate
    n = int(round(dur * rate)) + 1
    t = np.arange(n) * dt
    xr, yr, zr, psir = reference(t, rng, dur, z0=z0, amp=amp)
    if takeoff:  # smooth climb from the ground (z=0) to the flight's reference over 3 s
        u = np.clip(t / 3.0, 0, 1); sm = u*u*(3-2*u)
        zr = zr * sm
        start_z = 0.0
    if ground_pass:  # dip to 0.2 m above ground in the middle
        mid = dur / 2
        bump = np.exp(-((t - mid) / 1.5)**4)
        zr = zr * (1 - bump) + (-0.2) * bump
    # numeric derivatives of reference for feedforward
    vr = np.gradient(np.stack([xr, yr, zr]), dt, axis=1)
    ar = np.gradient(vr, dt, axis=1)
    m_n = nominal['mass']; KT_n = nominal['K_T']; b_n = nominal['b']
    Jn = np.diag(nominal['inertia'])
    pos, spin = geometry(nominal['arm'])
    M = np.vstack([KT_n*np.ones(4), -KT_n*pos[:, 1], KT_n*pos[:, 0], b_n*spin])
    Minv = np.linalg.inv(M)
    s = np.zeros(17); s[6] = 1.0
    s[0:3] = [xr[0], yr[0], zr[0] if start_z is None else start_z]
    s[6:10] = euler_to_q(0, 0, psir[0])
    whov = math.sqrt(P['mass']*G/(4*P['K_T']))
    s[13:17] = whov
    # multisine excitation on commands
    fe = rng.uniform(0.5, 12, (4, 6)); pe = rng.uniform(0, 2*np.pi, (4, 6))
    exc = np.array([np.sum(np.sin(2*np.pi*fe[i][:, None]*t + pe[i][:, None]), 0) for i in range(4)]).T
    exc = exc / exc.std() * excite
    kp, kd, ki = np.array([6.0, 6.0, 8.0]), np.array([4.0, 4.0, 5.0]), np.array([1.5, 1.5, 2.5])
    kR, kW = np.array([0.9, 0.9, 0.35]), np.array([0.10, 0.10, 0.06])
    eint = np.zeros(3)
    vbat = vbat0 - vbat_sag * (t / dur) + 0.0  # ZOH per row
    vbat = np.round(vbat, 3)
    rows = []
    W = np.zeros((n, 4)); S = np.zeros((n, 17)); AF = np.zeros((n, 3)); WACT = np.zeros((n, 4))
    for k in range(n):
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = qrot(q)
        ep = p - np.array([xr[k], yr[k], zr[k]]); ev = v - vr[:, k]
        eint = np.clip(eint + ep*dt, -1, 1)
        a_des = ar[:, k] - kp*ep - kd*ev - ki*eint
        F = m_n * (a_des - np.array([0, 0, G]))
        T = max(0.2*m_n*G, -F @ R[:, 2])
        b3 = -F / np.linalg.norm(F)
        c1 = np.array([math.cos(psir[k]), math.sin(psir[k]), 0])
        b2 = np.cross(b3, c1); b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        eR = 0.5 * (Rd.T @ R - R.T @ Rd); eR = np.array([eR[2, 1], eR[0, 2], eR[1, 0]])
        tau = -kR*eR*np.diag(Jn)/0.003 - kW*om*np.diag(Jn)/0.003 + np.cross(om, Jn @ om)
        w2 = Minv @ np.array([T, *tau])
        wc = np.sqrt(np.clip(w2, 550.0**2, 1600.0**2)) * (1 + exc[k])
        wc = np.clip(wc, 500, 1700)
        W[k] = wc; S[k] = s
        wt = wc * (1 + P['K_vbat'] * (vbat[k] - 4.0))
        if k == 0 and consistent_start:   # motors already at the first command (lag state = logged speed at t0)
            s[13:17] = wt
        AF[k] = quad.specific_force(s, True, wt)
        WACT[k] = s[13:17]
        if k < n - 1:
            s = step(quad, s, wt, dt, True)
    return dict(t=t, W=W, S=S, AF=AF, WACT=WACT, vbat=vbat, ref=np.stack([xr, yr, zr, psir], 1))


def write_log(path, sim, rng, pos_rate=100.0, pos_noise=0.002, att_noise=0.002, gyro_noise=0.005,
              acc_noise=0.05, imu_only=False, with_acc=True, with_vbat=True, with_att=True,
              logged='cmd'):
    t = sim['t']; n = len(t); S = sim['S']
    Y = np.array([outputs(s) for s in S])
    cols = {}
    cols['t'] = t
    Wl = sim['W'] if logged == 'cmd' else sim['WACT']
    for i in range(4):
        cols[f'w{i+1}'] = Wl[:, i]
    dtl = t[1] - t[0]
    every = max(1, int(round(1 / (pos_rate * dtl))))
    for j, c in enumerate('xyz'):
        col = Y[:, j] + rng.normal(0, pos_noise, n)
        mask = np.ones(n, bool); mask[::every] = False
        col[mask] = np.nan
        if imu_only:
            col[:] = np.nan
        cols[c] = col
    for j, c in enumerate(['phi', 'theta', 'psi']):
        a = Y[:, 3+j] + rng.normal(0, att_noise, n)
        if c == 'psi':
            a = (a + np.pi) % (2*np.pi) - np.pi
        if not with_att:
            a[:] = np.nan
        cols[c] = a
    for j, c in enumerate('pqr'):
        cols[c] = Y[:, 6+j] + rng.normal(0, gyro_noise, n)
    if with_acc:
        for j, c in enumerate(['ax', 'ay', 'az']):
            cols[c] = sim['AF'][:, j] + rng.normal(0, acc_noise, n)
    if with_vbat:
        cols['vbat'] = sim['vbat']
    keys = list(cols)
    with open(path, 'w') as f:
        f.write(','.join(keys) + '\n')
        for k in range(n):
            f.write(','.join('' if np.isnan(cols[c][k]) else repr(float(cols[c][k])) for c in keys) + '\n')


def airframe_toml(path, nominal, guess):
    J = nominal['inertia']
    with open(path, 'w') as f:
        f.write(f"""[airframe]
name = "audit17_250x"
mass = {nominal['mass']}
inertia = [{J[0]}, {J[1]}, {J[2]}]
arm_length = {nominal['arm']}
layout = "x"
rotor_inertia = {nominal['J_r']}
gravity = {G}

[parameters]
K_T = {guess['K_T']}
b = {guess['b']}
Kd = [{guess['Kd'][0]}, {guess['Kd'][1]}, {guess['Kd'][2]}]
""")


GUESS = dict(K_T=1.1e-6, b=1.5e-8, Kd=[0.1, 0.1, 0.1])
"""The audit's starting values: K_T 19 % low, b 29 % low, Kd off."""


def flight(path, seed=11, duration=30.0, imu_only=True, **truth):
    """Fly the audit's vehicle (:data:`TRUE`, updated by ``truth``: ``tau_m``, ``kt_dev`` per
    rotor thrust-and-torque deviations, ``k_rd``, ``K_vbat``, ``wind``...) and write its log to
    ``path`` as the audit did (seed ``1000 + seed`` for the sensors); the truth."""
    P = dict(TRUE)
    P.update(truth)
    sim = closed_loop(P, dict(TRUE), dur=duration, seed=seed, amp=0.5)
    write_log(path, sim, np.random.default_rng(1000 + seed), imu_only=imu_only, with_vbat=False)
    return P

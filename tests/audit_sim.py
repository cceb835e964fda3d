"""Independent quadrotor simulator of a blind audit (2026-11-30, the eighth), kept as a
test generator that is not greybox's own: written from ``CONTRACT.md`` and the README alone,
without reading the package, and checked against ``greybox simulate`` to 3e-8 m and 1e-9 rad
(base model, plus and x layouts, accelerometer channels) before any diagnosis.

Written from /work/shared/CONTRACT.md conventions only:
  world NED, body FRD, thrust along body -z, R = Rz(psi) Ry(theta) Rx(phi) body->world,
  rotor i thrust K_T w_i^2 along -z at r_i, reaction torque spin_i*b*w_i^2 about +z,
  gyroscopic torque J_r*Omega_r*(omega x e_z), Omega_r = sum(spin_i w_i),
  linear drag -Kd*v (world axes).
Attitude is integrated as a unit quaternion (not Euler angles) with a fixed-step RK4 at
a fine sub-step; the controller is a geometric SO(3) attitude controller with a
cascaded PID position loop, running at the log rate, holding its rotor command (ZOH)
between log rows.  Hidden effects are switched on by the `hidden` dict.

Hidden effects (``hidden`` keys): ``cog`` [dx, dy] m, ``asym`` per-rotor thrust and torque
factors, ``drift`` K_T per second, ``w3`` a cubic thrust term, ``ge`` "cb" (Cheeseman-Bennett
per rotor) or "exp", ``wind`` [wn, we], ``Kq``, ``hubdrag``, ``tau_m`` (motor lag),
``K_vbat`` (with a ``vbat`` column), and outside greybox's catalogue ``dist_torque`` (A N m,
f Hz: a periodic roll and pitch torque) and ``J_growth`` (roll/pitch inertia growing by that
share per second).
"""
import numpy as np

G = 9.81


# ---------------------------------------------------------------- rotations
def quat_to_R(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def euler_to_quat(phi, theta, psi):
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(theta / 2), np.sin(theta / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    return np.array([cy * cp * cr + sy * sp * sr,
                     cy * cp * sr - sy * sp * cr,
                     cy * sp * cr + sy * cp * sr,
                     sy * cp * cr - cy * sp * sr])


def R_to_euler(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    theta = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, theta, psi


def Rzyx(phi, theta, psi):
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    Rz = np.array([[cp, -sp, 0], [sp, cp, 0], [0, 0, 1]])
    Ry = np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    Rx = np.array([[1, 0, 0], [0, cf, -sf], [0, sf, cf]])
    return Rz @ Ry @ Rx


def cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def vee(M):
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


# ---------------------------------------------------------------- vehicles
def vehicle(name):
    if name == "quad1kg":      # 1 kg, plus layout
        v = dict(name=name, mass=1.0, J=[0.0095, 0.0105, 0.018], arm=0.20, layout="plus",
                 J_r=4.0e-5, K_T=1.6e-5, b=2.4e-7, Kd=[0.22, 0.26, 0.35], rotor_R=0.12)
    elif name == "cf30g":      # 30 g Crazyflie-like, x layout
        v = dict(name=name, mass=0.030, J=[1.4e-5, 1.4e-5, 2.2e-5], arm=0.046, layout="x",
                 J_r=1.0e-9, K_T=2.0e-8, b=1.2e-10, Kd=[0.009, 0.010, 0.014], rotor_R=0.023)
    elif name == "quad3kg":    # 3 kg, x layout
        v = dict(name=name, mass=3.0, J=[0.045, 0.05, 0.085], arm=0.30, layout="x",
                 J_r=1.5e-4, K_T=3.5e-5, b=7.0e-7, Kd=[0.5, 0.55, 0.8], rotor_R=0.165)
    else:
        raise ValueError(name)
    l = v["arm"]
    if v["layout"] == "plus":
        v["r"] = np.array([[l, 0, 0], [0, l, 0], [-l, 0, 0], [0, -l, 0]], float)
        v["spin"] = np.array([-1, 1, -1, 1], float)
    else:
        a = l / np.sqrt(2)
        v["r"] = np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]], float)
        v["spin"] = np.array([1, 1, -1, -1], float)
    v["J"] = np.array(v["J"], float)
    v["Kd"] = np.array(v["Kd"], float)
    return v


def write_airframe(v, path, guess_factor=(1.3, 0.7), kd_guess=None):
    kdg = kd_guess if kd_guess is not None else list(np.round(v["Kd"] * 0.5, 6))
    txt = f"""[airframe]
name = "{v['name']}"
mass = {v['mass']}
inertia = [{v['J'][0]}, {v['J'][1]}, {v['J'][2]}]
arm_length = {v['arm']}
layout = "{v['layout']}"
rotor_inertia = {v['J_r']}
gravity = {G}

[parameters]
K_T = {v['K_T'] * guess_factor[0]:.6e}
b = {v['b'] * guess_factor[1]:.6e}
Kd = [{kdg[0]}, {kdg[1]}, {kdg[2]}]
"""
    open(path, "w").write(txt)


# ---------------------------------------------------------------- dynamics
def forces(v, h, t, pos, vel, R, om, w):
    """Return (force_world incl. gravity, torque_body, rotor thrusts). w = effective speeds."""
    K_T, b, m = v["K_T"], v["b"], v["mass"]
    r = v["r"].copy()
    spin = v["spin"]
    if "cog" in h:                       # CoG offset: rotor arms measured from CoG
        r = r - np.array([h["cog"][0], h["cog"][1], 0.0])
    kt = np.full(4, K_T)
    kb = np.full(4, b)
    if "asym" in h:                      # per-rotor thrust/torque scale
        kt = kt * (1 + np.asarray(h["asym"]))
        kb = kb * (1 + np.asarray(h["asym"]))
    if "drift" in h:                     # battery sag: K_T(t) = K_T (1 + drift t)
        kt = kt * (1 + h["drift"] * t)   # documented form: thrust only (b unchanged)
    T = kt * w ** 2
    if "w3" in h:                        # thrust curve with a cubic term (outside catalogue)
        T = T + h["w3"] * w ** 3
    if "ge" in h:                        # ground effect per rotor, Cheeseman-Bennett
        hz = h.get("ground_z", 0.0)
        rw = (R @ r.T).T + pos           # rotor hub world positions
        hi = np.maximum(hz - rw[:, 2], 1e-3)
        if h["ge"] == "cb":
            k = (v["rotor_R"] / 4) ** 2
            ratio = np.minimum(k / hi ** 2, 0.5)
            T = T / (1 - ratio)
        elif h["ge"] == "exp":           # physically different form: exponential decay with height
            T = T * (1 + h["ge_a"] * np.exp(-hi / h["ge_l"]))
    v_air = vel.copy()
    if "wind" in h:
        v_air = vel - np.array([h["wind"][0], h["wind"][1], 0.0])
    F = R @ np.array([0, 0, -T.sum()]) + np.array([0, 0, m * G]) - v["Kd"] * v_air
    if "Kq" in h:
        F = F - np.asarray(h["Kq"]) * np.linalg.norm(v_air) * v_air
    tau = np.zeros(3)
    for i in range(4):
        tau += cross(r[i], np.array([0, 0, -T[i]]))
    tau[2] += np.sum(spin * kb * w ** 2)
    Om = np.sum(spin * w)
    tau += v["J_r"] * Om * cross(om, np.array([0, 0, 1.0]))
    if "hubdrag" in h:                   # rotor drag at each hub on hub air velocity (different form)
        vb = R.T @ v_air
        Fb = np.zeros(3)
        for i in range(4):
            vi = vb + cross(om, r[i])
            Fi = -h["hubdrag"] * w[i] * np.array([vi[0], vi[1], 0.0])
            Fb += Fi
            tau += cross(r[i], Fi)
        F = F + R @ Fb
    if "dist_torque" in h:               # periodic roll/pitch torque (outside catalogue)
        A, f = h["dist_torque"]
        tau += A * np.array([np.sin(2 * np.pi * f * t), 0.6 * np.cos(2 * np.pi * 0.63 * f * t), 0.0])
    return F, tau, T


def deriv(v, h, t, s, wcmd):
    pos, vel, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
    R = quat_to_R(q / np.linalg.norm(q))
    if "tau_m" in h:
        w = s[13:17]
        dw = (wcmd - w) / h["tau_m"]
    else:
        w = wcmd
        dw = np.zeros(4)
    if "K_vbat" in h:                    # battery: effective speed w_log*(1+K_vbat*(vbat-4 V))
        w = w * (1 + h["K_vbat"] * (vbat(t) - 4.0))
    F, tau, _ = forces(v, h, t, pos, vel, R, om, w)
    J = v["J"]
    acc = F / v["mass"]
    if "J_growth" in h:                  # time-varying roll/pitch inertia (outside catalogue)
        g = h["J_growth"]
        J = J * np.array([1 + g * t, 1 + g * t, 1.0])
        dJ = v["J"] * np.array([g, g, 0.0])
        domega = (tau - cross(om, J * om) - dJ * om) / J
    else:
        domega = (tau - cross(om, J * om)) / J
    Omq = np.array([[0, -om[0], -om[1], -om[2]],
                    [om[0], 0, om[2], -om[1]],
                    [om[1], -om[2], 0, om[0]],
                    [om[2], om[1], -om[0], 0]])
    dq = 0.5 * Omq @ q
    if "tau_m" in h:
        return np.concatenate([vel, acc, dq, domega, dw])
    return np.concatenate([vel, acc, dq, domega])


def vbat(t):
    return 4.15 - 0.012 * t + 0.04 * np.sin(0.45 * t) + 0.02 * np.sin(1.7 * t + 1.0)


def rk4(v, h, t, s, u, dt):
    k1 = deriv(v, h, t, s, u)
    k2 = deriv(v, h, t + dt / 2, s + dt / 2 * k1, u)
    k3 = deriv(v, h, t + dt / 2, s + dt / 2 * k2, u)
    k4 = deriv(v, h, t + dt, s + dt * k3, u)
    s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    s[6:10] /= np.linalg.norm(s[6:10])
    return s


# ---------------------------------------------------------------- reference
def make_reference(kind, duration, seed, scale=1.0):
    """Raw (unfiltered) reference function of time: x,y,z,psi.  kind: 'mix', 'fast', 'ground'."""
    rng = np.random.default_rng(seed)
    segs = []
    t = 0.0
    base_z = -1.2 * scale
    if kind == "ground":
        plan = ["hover", "ground", "fig8", "ground", "steps", "yaw", "ground", "alt"]
    elif kind == "fast":
        plan = ["hover", "fastfig8", "steps", "fastfig8", "yaw", "alt", "fastfig8"]
    else:
        plan = ["hover", "fig8", "steps", "yaw", "alt", "fig8", "steps", "yaw"]
    i = 0
    while t < duration:
        k = plan[i % len(plan)]
        i += 1
        d = {"hover": 2.0, "fig8": 8.0, "fastfig8": 6.0, "steps": 6.0, "yaw": 4.0, "alt": 5.0, "ground": 6.0}[k]
        segs.append((t, t + d, k, rng.uniform(-1, 1, 6)))
        t += d

    def ref(tt):
        x = y = 0.0
        z = base_z
        psi = 0.0
        for (a, b_, k, r) in segs:
            if a <= tt < b_:
                s = tt - a
                if k == "fig8":
                    T = 8.0
                    A = 1.2 * scale * (1 + 0.2 * r[0])
                    x = A * np.sin(2 * np.pi * s / T)
                    y = 0.6 * A * np.sin(4 * np.pi * s / T)
                    z = base_z + 0.3 * scale * np.sin(2 * np.pi * s / T + r[1])
                    psi = 0.3 * np.sin(2 * np.pi * s / T)
                elif k == "fastfig8":
                    T = 3.0
                    A = 2.0 * scale * (1 + 0.1 * r[0])
                    x = A * np.sin(2 * np.pi * s / T)
                    y = 0.5 * A * np.sin(4 * np.pi * s / T)
                    psi = 0.2 * np.sin(2 * np.pi * s / T)
                elif k == "steps":
                    n = int(s // 1.5)
                    x = scale * [0.8, -0.6, 0.5, -0.3][n % 4] * (1 + 0.3 * r[2])
                    y = scale * [0.0, 0.7, -0.5, 0.4][n % 4] * (1 + 0.3 * r[3])
                elif k == "yaw":
                    psi = (0.9 + 0.2 * r[4]) * (1 if s < d_yaw(s) else -1)
                elif k == "alt":
                    z = base_z + scale * (0.6 if s < 2.5 else -0.5)
                elif k == "ground":
                    # low pass: descend to 0.18 m above ground, translate, climb back
                    hlow = (0.16 + 0.04 * (r[5] + 1)) * (0.4 if scale < 1 else 1.0)
                    z = -hlow if 1.0 <= s < 5.0 else base_z
                    x = 0.8 * scale * np.sin(2 * np.pi * (s - 1.0) / 4.0) if 1.0 <= s < 5.0 else 0.0
                    psi = 0.2 * r[4]
                break
        return np.array([x, y, z, psi])
    return ref


def d_yaw(s):
    return 2.0


# ---------------------------------------------------------------- flight
def fly(vname, hidden, duration, rate, seed, kind="mix", vision_rate=100.0,
        pos_noise=0.002, att_noise=0.002, gyro_noise=0.005, accel_noise=None,
        excite=0.03, substeps=None, log_actual=False):
    """Closed-loop flight. Returns dict with columns and truth."""
    v = vehicle(vname)
    h = dict(hidden)
    rng = np.random.default_rng(seed + 1000)
    dt = 1.0 / rate
    if substeps is None:
        substeps = max(1, int(np.ceil(dt / 5e-4 - 1e-9)))
    hdt = dt / substeps
    m, J, K_T, b = v["mass"], v["J"], v["K_T"], v["b"]
    scale = 1.0 if vname != "cf30g" else 0.6
    ref = make_reference(kind, duration, seed, scale=scale)
    # controller gains
    wn_att = {"quad1kg": 18.0, "cf30g": 22.0, "quad3kg": 14.0}[vname]
    wn_pos = 2.2
    kR, kW = J * wn_att ** 2, J * 2 * 0.8 * wn_att
    kp, kv, ki = wn_pos ** 2, 2 * 0.9 * wn_pos, 0.4
    # mixer M: [T, tx, ty, tz] = M @ w^2 (nominal)
    r, spin = v["r"], v["spin"]
    M = np.vstack([K_T * np.ones(4), -K_T * r[:, 1], K_T * r[:, 0], b * spin])
    Minv = np.linalg.inv(M)
    # multisine excitation on w^2, per rotor
    nfreq = 6
    freqs = rng.uniform(0.3, 6.0, (4, nfreq))
    phases = rng.uniform(0, 2 * np.pi, (4, nfreq))
    # reference prefilter state (3rd order critically damped per axis)
    wf = 2.0
    rf = np.zeros((4, 3))
    r0 = ref(0.0)
    rf[:, 0] = r0
    # initial state: hover at reference start
    s = np.zeros(17 if "tau_m" in h else 13)
    s[0:3] = r0[:3]
    s[6:10] = euler_to_quat(0, 0, r0[3])
    w_h = np.sqrt(m * G / (4 * K_T))
    if "tau_m" in h:
        s[13:17] = w_h
    integ = np.zeros(3)
    n = int(round(duration * rate))
    truth_rows = []
    for k in range(n):
        t = k * dt
        # reference filter (Euler at control rate, fine enough)
        raw = ref(t)
        for j in range(4):
            x0, x1, x2 = rf[j]
            e = raw[j] - x0
            x3 = wf ** 3 * e - 3 * wf ** 2 * x1 - 3 * wf * x2
            rf[j] = [x0 + dt * x1, x1 + dt * x2, x2 + dt * x3]
        pref, vref, aref = rf[:3, 0], rf[:3, 1], rf[:3, 2]
        psid = rf[3, 0]
        pos, vel, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = quat_to_R(q)
        # position loop (true states)
        ep = pref - pos
        integ = np.clip(integ + ep * dt, -1, 1)
        a_des = kp * ep + kv * (vref - vel) + ki * integ + aref
        # compensate nominal linear drag (controller knows a guess)
        f = m * (a_des - np.array([0, 0, G])) + 0.5 * v["Kd"] * vel
        Tcmd = max(np.linalg.norm(f), 0.2 * m * G)
        b3 = -f / np.linalg.norm(f)
        c1 = np.array([np.cos(psid), np.sin(psid), 0])
        b2 = cross(b3, c1); b2 /= np.linalg.norm(b2)
        b1 = cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        # tilt limit
        eR = 0.5 * vee(Rd.T @ R - R.T @ Rd)
        tau = -kR * eR - kW * om + cross(om, J * om)
        w2 = Minv @ np.array([Tcmd, *tau])
        ex = np.array([np.sum(np.sin(2 * np.pi * freqs[i] * t + phases[i])) for i in range(4)])
        w2 = w2 * (1 + excite * ex / np.sqrt(nfreq / 2))
        w2 = np.clip(w2, (0.1 * w_h) ** 2, (2.2 * w_h) ** 2)
        wcmd = np.sqrt(w2)
        # log row (state at t, command held over [t, t+dt))
        phi, th, ps = R_to_euler(R)
        weff = s[13:17].copy() if "tau_m" in h else wcmd.copy()
        sd = deriv(v, h, t, s, wcmd)
        acc_w = sd[3:6]
        spec = R.T @ (acc_w - np.array([0, 0, G]))
        truth_rows.append([t, *pos, phi, th, ps, *vel, *om, *wcmd, *weff, *spec])
        # integrate
        for _ in range(substeps):
            s = rk4(v, h, t, s, wcmd, hdt)
            t += hdt
    tr = np.array(truth_rows)
    # unwrap yaw
    tr[:, 6] = np.unwrap(tr[:, 6])
    out = {"truth": tr, "vehicle": v}
    # measurements
    N = len(tr)
    meas = {}
    meas["t"] = tr[:, 0]
    for i in range(4):
        meas[f"w{i+1}"] = tr[:, 13 + i] if not log_actual else tr[:, 17 + i]
    vis_every = max(1, int(round(rate / vision_rate)))
    mask = np.zeros(N, bool); mask[::vis_every] = True
    for j, c in enumerate("xyz"):
        col = tr[:, 1 + j] + rng.normal(0, pos_noise, N)
        col[~mask] = np.nan
        meas[c] = col
    for j, c in enumerate(["phi", "theta", "psi"]):
        meas[c] = tr[:, 4 + j] + rng.normal(0, att_noise, N)
    for j, c in enumerate("pqr"):
        meas[c] = tr[:, 10 + j] + rng.normal(0, gyro_noise, N)
    if accel_noise:
        for j, c in enumerate(["ax", "ay", "az"]):
            meas[c] = tr[:, 21 + j] + rng.normal(0, accel_noise, N)
    if "K_vbat" in h:
        meas["vbat"] = vbat(tr[:, 0]) + rng.normal(0, 0.003, N)
    out["meas"] = meas
    return out


def write_log(meas, path, digits=9):
    cols = list(meas.keys())
    N = len(meas["t"])
    with open(path, "w") as fh:
        fh.write(",".join(cols) + "\n")
        for k in range(N):
            vals = []
            for c in cols:
                x = meas[c][k]
                vals.append("" if np.isnan(x) else f"{x:.{digits}g}")
            fh.write(",".join(vals) + "\n")

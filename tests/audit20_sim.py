"""Independent quadrotor simulator of a twentieth blind audit (2026-12-05), kept as written.

The audit's sim.py, with its gen_flights.py and gen_airframes.py as :func:`flights` and
:func:`airframe` at the end (they regenerate its flights and airframe files bit for bit).
The auditor read only README.md and CONTRACT.md; none of greybox's code.

--- the audit's own docstring ---
Independent quadrotor simulator for the greybox audit (audit20).

Written from the public CONTRACT/README conventions only:
  world NED, body FRD, ZYX Euler, R = Rz Ry Rx (body->world),
  "x" layout: r1=(+a,+a), r2=(-a,-a), r3=(+a,-a), r4=(-a,+a), a=l/sqrt2, spin=[+1,+1,-1,-1],
  thrust K_T w^2 along body -z, reaction torque spin_i b w_i^2 about body +z,
  gyroscopic torque J_r*Omega_r*(omega x e_z), Omega_r = sum spin_i w_i,
  world-frame linear drag -Kd*v.
Vehicle state: p(3) v(3) q(4, unit quaternion w,x,y,z body->world) omega(3) w_act(4).
Integration: fixed-step RK4 at 2 kHz. Controller: PX4-like cascade at 500 Hz.
Hidden effects (flags in `truth`):
  Kq            world-axis quadratic drag  -Kq_i |v| v_i         (catalogue: quadratic_drag)
                (Kq_form="axis": -Kq_i |v_i| v_i instead, a per-axis form)
  log_commands  log the commanded speeds, motors first-order tau_m (catalogue: motor_lag)
  c_inflow      T_i = K_T w_i^2 (1 + c_inflow * vz_body)           (NOT in catalogue)
  cant_deg      each rotor tilted about its arm by cant, tangential thrust s_i*sin(cant)
                (yaw authority cant; NOT in catalogue; b_eff = b + l K_T sin(cant))
  lin_share     T_i = a w_i + c w_i^2, a = s K_T w_h, c = (1-s) K_T  (NOT in catalogue; thrust_curve is
                the catalogue's K_T w^2 (1 + k_Tw (w/w_h - 1)))
"""
import numpy as np

G = 9.81


def default_truth():
    l = 0.125
    KT = 5.0e-7
    return dict(mass=0.50, J=[2.4e-3, 2.6e-3, 4.5e-3], l=l, KT=KT, b=KT * 0.015,
                Kd=[0.12, 0.12, 0.18], Jr=3.0e-6, tau_m=0.020, w_min=300.0, w_max=2600.0,
                Kq=[0.0, 0.0, 0.0], log_commands=False, c_inflow=0.0, cant_deg=0.0)


def geometry(l):
    a = l / np.sqrt(2.0)
    r = np.array([[a, a, 0.0], [-a, -a, 0.0], [a, -a, 0.0], [-a, a, 0.0]])
    spin = np.array([1.0, 1.0, -1.0, -1.0])
    return r, spin


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
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


def R_to_euler(R):
    phi = np.arctan2(R[2, 1], R[2, 2])
    theta = -np.arcsin(np.clip(R[2, 0], -1, 1))
    psi = np.arctan2(R[1, 0], R[0, 0])
    return phi, theta, psi


class Vehicle:
    def __init__(self, truth):
        self.T = truth
        self.m = truth["mass"]
        self.J = np.diag(truth["J"])
        self.Jinv = np.linalg.inv(self.J)
        self.r, self.spin = geometry(truth["l"])
        self.Kd = np.array(truth["Kd"])
        self.Kq = np.array(truth["Kq"])
        d = np.radians(truth["cant_deg"])
        # per-rotor thrust direction in body frame (unit), tilted about the arm axis
        self.tdir = np.zeros((4, 3))
        for i in range(4):
            rh = self.r[i] / np.linalg.norm(self.r[i])
            tang = np.array([-rh[1], rh[0], 0.0])     # e_z x r_hat
            # force = T*(cos d * (-e_z) + sin d * s_i * tang)
            self.tdir[i] = np.cos(d) * np.array([0, 0, -1.0]) + np.sin(d) * self.spin[i] * tang

    def deriv(self, s, wcmd):
        T = self.T
        v = s[3:6]
        q = s[6:10]
        om = s[10:13]
        w = s[13:17]
        R = quat_to_R(q)
        vb = R.T @ v
        thr = T["KT"] * w * w
        if T.get("lin_share", 0.0) != 0.0:
            # T_i = a w_i + c w_i^2 with a = s K_T w_h, c = (1 - s) K_T  (equal to K_T w_h^2 at hover)
            sh = T["lin_share"]
            wh = np.sqrt(self.m * G / (4 * T["KT"]))
            thr = sh * T["KT"] * wh * w + (1 - sh) * T["KT"] * w * w
        if T.get("k_ge", 0.0) != 0.0:
            # per-rotor Cheeseman-Bennett, ground plane world z = 0, rotor height h_i = -(p_z + (R r_i)_z)
            hz = -(s[2] + (R @ self.r.T)[2])
            ratio = np.minimum(T["k_ge"] / np.maximum(hz, 1e-3) ** 2, 0.5)
            thr = thr / (1.0 - ratio)
        if T["c_inflow"] != 0.0:
            thr = thr * (1.0 + T["c_inflow"] * vb[2])
        Fb = (thr[:, None] * self.tdir).sum(0)
        tau = np.zeros(3)
        for i in range(4):
            tau += np.cross(self.r[i], thr[i] * self.tdir[i])
        tau[2] += T["b"] * np.sum(self.spin * w * w)
        Om = np.sum(self.spin * w)
        tau += T["Jr"] * Om * np.array([om[1], -om[0], 0.0])
        if T.get("Kq_form", "norm") == "axis":
            qd = self.Kq * np.abs(v) * v                 # per-axis |v_i| v_i (NOT the catalogue form)
        else:
            qd = self.Kq * np.linalg.norm(v) * v         # catalogue form -Kq_i |v| v_i
        F = R @ Fb + np.array([0, 0, self.m * G]) - self.Kd * v - qd
        ds = np.empty(17)
        ds[0:3] = v
        ds[3:6] = F / self.m
        p, qq, rr = om
        ds[6:10] = 0.5 * np.array([
            -q[1] * p - q[2] * qq - q[3] * rr,
            q[0] * p + q[2] * rr - q[3] * qq,
            q[0] * qq - q[1] * rr + q[3] * p,
            q[0] * rr + q[1] * qq - q[2] * p])
        ds[10:13] = self.Jinv @ (tau - np.cross(om, self.J @ om))
        ds[13:17] = (wcmd - w) / T["tau_m"]
        return ds


class Controller:
    """PX4-like cascade: pos P -> vel PID -> attitude P -> rate PID -> mixer (nominal params)."""

    def __init__(self, nominal, dt):
        self.n = nominal
        self.dt = dt
        self.m = nominal["mass"]
        self.J = np.diag(nominal["J"])
        r, spin = geometry(nominal["l"])
        KT, b = nominal["KT"], nominal["b"]
        # rows: thrust (up, positive), tau_x, tau_y, tau_z  as functions of w^2
        self.M = np.vstack([KT * np.ones(4), -r[:, 1] * KT, r[:, 0] * KT, spin * b])
        self.Minv = np.linalg.inv(self.M)
        self.vint = np.zeros(3)
        self.rint = np.zeros(3)
        self.prev_rerr = np.zeros(3)
        self.prev_v = None
        self.kp_pos = np.array([1.2, 1.2, 1.5])
        self.kp_vel = np.array([3.0, 3.0, 4.0])
        self.ki_vel = np.array([0.6, 0.6, 1.0])
        self.kd_vel = np.array([0.05, 0.05, 0.0])
        self.kp_att = np.array([7.0, 7.0, 3.5])
        self.kp_rate = np.array([16.0, 16.0, 8.0])
        self.ki_rate = np.array([3.0, 3.0, 1.0])
        self.kd_rate = np.array([0.15, 0.15, 0.0])
        self.vmax_xy, self.vmax_z = 6.0, 3.0
        self.wmin, self.wmax = nominal["w_min"], nominal["w_max"]

    def step(self, s, ref):
        pref, vff, psiref = ref
        p, v, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
        R = quat_to_R(q)
        vsp = self.kp_pos * (pref - p) + vff
        h = np.linalg.norm(vsp[:2])
        if h > self.vmax_xy:
            vsp[:2] *= self.vmax_xy / h
        vsp[2] = np.clip(vsp[2], -self.vmax_z, self.vmax_z)
        ev = vsp - v
        self.vint = np.clip(self.vint + ev * self.dt, -2, 2)
        dv = np.zeros(3) if self.prev_v is None else -(v - self.prev_v) / self.dt
        self.prev_v = v.copy()
        asp = self.kp_vel * ev + self.ki_vel * self.vint + self.kd_vel * dv
        asp[:2] = np.clip(asp[:2], -8, 8)
        asp[2] = np.clip(asp[2], -6, 6)
        f = asp - np.array([0, 0, G])                # desired specific force (NED)
        # tilt limit 35 deg
        fh = np.linalg.norm(f[:2])
        fz = -f[2]
        maxh = fz * np.tan(np.radians(35))
        if fh > maxh:
            f[:2] *= maxh / fh
        b3 = -f / np.linalg.norm(f)                  # desired body z (down) axis
        c1 = np.array([np.cos(psiref), np.sin(psiref), 0.0])
        b2 = np.cross(b3, c1)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        thrust = -self.m * f @ R[:, 2]
        E = 0.5 * (Rd.T @ R - R.T @ Rd)
        eR = np.array([E[2, 1], E[0, 2], E[1, 0]])
        omsp = np.clip(-self.kp_att * eR, [-4, -4, -2], [4, 4, 2])
        er = omsp - om
        self.rint = np.clip(self.rint + er * self.dt, -0.5, 0.5)
        der = (er - self.prev_rerr) / self.dt
        self.prev_rerr = er
        alpha = self.kp_rate * er + self.ki_rate * self.rint + self.kd_rate * der
        tau = self.J @ alpha + np.cross(om, self.J @ om)
        w2 = self.Minv @ np.concatenate([[thrust], tau])
        w2 = np.clip(w2, self.wmin ** 2, self.wmax ** 2)
        return np.sqrt(w2)


def simulate(truth, nominal, reference, duration, x0_pos=(0.0, 0.0, -1.5),
             dt=0.0005, ctrl_every=4, log_every=5, seed=0,
             esc_noise=1.5, esc_quant=1.496, pos_noise=0.001, att_noise=0.003,
             gyro_noise=0.005, mocap_every=4):
    """Returns a dict of numpy columns at the log rate (dt*log_every, 400 Hz by default).
    Position only on every `mocap_every`-th log row (100 Hz), NaN otherwise."""
    rng = np.random.default_rng(seed)
    veh = Vehicle(truth)
    ctl = Controller(nominal, dt * ctrl_every)
    m = truth["mass"]
    wh = np.sqrt(m * G / (4 * truth["KT"]))
    s = np.zeros(17)
    s[0:3] = x0_pos
    s[6:10] = euler_to_quat(0, 0, 0)
    s[13:17] = wh
    wcmd = np.full(4, wh)
    nsteps = int(round(duration / dt))
    rows = []
    for k in range(nsteps + 1):
        t = k * dt
        if k % ctrl_every == 0:
            wcmd = ctl.step(s, reference(t))
        if k % log_every == 0:
            rows.append((t, s.copy(), wcmd.copy()))
        if k == nsteps:
            break
        k1 = veh.deriv(s, wcmd)
        k2 = veh.deriv(s + 0.5 * dt * k1, wcmd)
        k3 = veh.deriv(s + 0.5 * dt * k2, wcmd)
        k4 = veh.deriv(s + dt * k3, wcmd)
        s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[6:10] /= np.linalg.norm(s[6:10])
    n = len(rows)
    out = {k: np.empty(n) for k in ["t", "w1", "w2", "w3", "w4", "x", "y", "z",
                                     "phi", "theta", "psi", "p", "q", "r"]}
    truth_states = np.empty((n, 17))
    for j, (t, st, wc) in enumerate(rows):
        truth_states[j] = st
        out["t"][j] = t
        wlog = wc if truth["log_commands"] else st[13:17]
        for i in range(4):
            out[f"w{i+1}"][j] = wlog[i]
        R = quat_to_R(st[6:10])
        out["phi"][j], out["theta"][j], out["psi"][j] = R_to_euler(R)
        out["x"][j], out["y"][j], out["z"][j] = st[0:3]
        out["p"][j], out["q"][j], out["r"][j] = st[10:13]
    # sensors
    for i in range(4):
        key = f"w{i+1}"
        if truth["log_commands"]:
            out[key] = np.round(out[key], 1)            # command log resolution 0.1 rad/s
        else:
            noisy = out[key] + esc_noise * rng.standard_normal(n)
            out[key] = np.round(noisy / esc_quant) * esc_quant   # eRPM/100 telemetry, 7 pole pairs
    for key in ["x", "y", "z"]:
        out[key] = out[key] + pos_noise * rng.standard_normal(n)
        mask = (np.arange(n) % mocap_every) != 0
        out[key][mask] = np.nan
    for key in ["phi", "theta", "psi"]:
        out[key] = out[key] + att_noise * rng.standard_normal(n)
    out["psi"] = (out["psi"] + np.pi) % (2 * np.pi) - np.pi
    for key in ["p", "q", "r"]:
        out[key] = out[key] + gyro_noise * rng.standard_normal(n)
    return out, truth_states


def write_csv(path, cols, every=1):
    keys = ["t", "w1", "w2", "w3", "w4", "x", "y", "z", "phi", "theta", "psi", "p", "q", "r"]
    n = len(cols["t"])
    idx = np.arange(0, n, every)
    with open(path, "w") as f:
        f.write(",".join(keys) + "\n")
        for j in idx:
            vals = []
            for k in keys:
                x = cols[k][j]
                vals.append("" if np.isnan(x) else repr(float(np.round(x, 9))))
            f.write(",".join(vals) + "\n")


def write_airframe(path, truth, KT, b, Kd, name="audit20_250x", extra=None):
    with open(path, "w") as f:
        f.write("[airframe]\n")
        f.write(f'name = "{name}"\n')
        f.write(f"mass = {truth['mass']}\n")
        f.write(f"inertia = [{truth['J'][0]}, {truth['J'][1]}, {truth['J'][2]}]\n")
        f.write(f"arm_length = {truth['l']}\n")
        f.write('layout = "x"\n')
        f.write(f"rotor_inertia = {truth['Jr']}\n")
        f.write(f"gravity = {G}\n\n")
        f.write("[parameters]\n")
        f.write(f"K_T = {KT:.6e}\n")
        f.write(f"b = {b:.6e}\n")
        f.write(f"Kd = [{Kd[0]}, {Kd[1]}, {Kd[2]}]\n")
        if extra:
            for k, v in extra.items():
                f.write(f"{k} = {v}\n")


# ---------------- references ----------------

def smoothstep(t, t0, T):
    x = np.clip((t - t0) / T, 0, 1)
    return x * x * (3 - 2 * x)


def make_reference(kind, seed):
    """Piecewise manoeuvre programme. Returns reference(t) -> (p_ref, v_ff, psi_ref)."""
    rng = np.random.default_rng(seed)
    segs = []      # (t0, t1, func(t)->(p, vff, psi))
    t = 0.0
    p0 = np.array([0.0, 0.0, -1.5])
    psi0 = 0.0
    if kind == "estg":
        plan = ["hover", "step_x", "ground", "yaw", "climb", "eight", "step_y", "descend", "ground",
                "eight_fast", "hover"]
    elif kind == "valg":
        plan = ["hover", "ground", "step_y", "eight", "yaw", "ground", "hover"]
    elif kind == "est":
        plan = ["hover", "step_x", "step_y", "yaw", "climb", "eight", "step_z", "yaw",
                "eight_fast", "descend", "step_xy", "yaw", "climb", "eight", "hover"]
    else:
        plan = ["hover", "step_y", "eight", "yaw", "climb", "step_x", "eight_fast", "descend",
                "yaw", "hover"]
    state = dict(p=p0.copy(), psi=psi0)

    def add(dur, f):
        nonlocal t
        segs.append((t, t + dur, f))
        t += dur

    for m in plan:
        P, PSI = state["p"].copy(), state["psi"]
        if m == "hover":
            add(2.0, lambda tt, P=P, PSI=PSI: (P, np.zeros(3), PSI))
        elif m in ("step_x", "step_y", "step_xy", "step_z"):
            d = np.zeros(3)
            amp = rng.uniform(1.2, 2.0) * rng.choice([-1, 1])
            if m == "step_x":
                d[0] = amp
            elif m == "step_y":
                d[1] = amp
            elif m == "step_xy":
                d[0] = amp
                d[1] = -amp * 0.7
            else:
                d[2] = 0.8 if P[2] < -2.5 else -0.8
            Q = P + d
            add(3.0, lambda tt, Q=Q, PSI=PSI: (Q, np.zeros(3), PSI))
            state["p"] = Q
        elif m == "yaw":
            dpsi = rng.choice([-1, 1]) * rng.uniform(1.2, 2.0)
            t0 = t
            add(3.0, lambda tt, P=P, PSI=PSI, t0=t0, dpsi=dpsi:
                (P, np.zeros(3), PSI + dpsi * smoothstep(tt, t0, 1.5)))
            state["psi"] = PSI + dpsi
        elif m in ("climb", "descend"):
            dz = -2.0 if m == "climb" else 2.0
            Q = P + np.array([0, 0, dz])
            t0 = t
            vz = 2.0 * np.sign(dz)
            dur = abs(dz) / 2.0

            def f(tt, P=P, Q=Q, t0=t0, vz=vz, dur=dur):
                if tt - t0 < dur:
                    return P + np.array([0, 0, vz * (tt - t0)]), np.array([0, 0, vz]), PSI
                return Q, np.zeros(3), PSI
            add(dur + 2.0, f)
            state["p"] = Q
        elif m == "ground":
            # slow approach to 0.10 m above the ground, 1.5 m lateral pass, slow climb back
            low = -0.10
            t0 = t
            d1 = (low - P[2]) / 0.5          # down at 0.5 m/s
            ang = rng.uniform(0, 2 * np.pi)
            lat = 1.5 * np.array([np.cos(ang), np.sin(ang), 0.0])

            def f(tt, P=P, t0=t0, d1=d1, lat=lat, low=low, PSI=PSI):
                s_ = tt - t0
                A = np.array([P[0], P[1], low])
                if s_ < d1:
                    return P + np.array([0, 0, 0.5 * s_]), np.array([0, 0, 0.5]), PSI
                s_ -= d1
                if s_ < 1.5:
                    return A, np.zeros(3), PSI
                s_ -= 1.5
                if s_ < 3.0:
                    return A + lat * smoothstep(s_, 0, 3.0), np.zeros(3), PSI
                s_ -= 3.0
                if s_ < 1.5:
                    return A + lat, np.zeros(3), PSI
                s_ -= 1.5
                B = A + lat
                if s_ < d1:
                    return B - np.array([0, 0, 0.5 * s_]), np.array([0, 0, -0.5]), PSI
                return P + lat, np.zeros(3), PSI
            add(2 * d1 + 7.0, f)
            state["p"] = P + lat
        elif m in ("eight", "eight_fast"):
            A = 2.0 if m == "eight" else 3.0
            Tp = 7.0 if m == "eight" else 5.5
            om = 2 * np.pi / Tp
            t0 = t
            yawrate = rng.uniform(-0.4, 0.4)

            def f(tt, P=P, A=A, om=om, t0=t0, yawrate=yawrate, PSI=PSI):
                s = tt - t0
                ramp = smoothstep(tt, t0, 1.0)
                pos = P + ramp * np.array([A * np.sin(om * s), 0.5 * A * np.sin(2 * om * s),
                                           0.3 * np.sin(om * s)])
                vel = ramp * np.array([A * om * np.cos(om * s), A * om * np.cos(2 * om * s),
                                       0.3 * om * np.cos(om * s)])
                return pos, vel, PSI + yawrate * s
            add(Tp, f)
            state["psi"] = PSI + yawrate * Tp
    total = t

    def reference(tt):
        for (a, b_, f) in segs:
            if a <= tt < b_:
                return f(tt)
        return segs[-1][2](min(tt, total - 1e-9))
    return reference, total


# ---------------- the audit's gen_flights.py and gen_airframes.py ----------------

CASES = {
    "control": dict(),
    "qdrag": dict(Kq=[0.015, 0.015, 0.020]),
    "qdragaxis": dict(Kq=[0.015, 0.015, 0.020], Kq_form="axis"),
    "mlag": dict(log_commands=True, tau_m=0.030),
    "inflow": dict(c_inflow=0.10),
    "cant": dict(cant_deg=4.0),
    "linthrust": dict(lin_share=0.25),
    "ground": dict(k_ge=(0.0635 / 4) ** 2),
    "ground2": dict(k_ge=(0.0635 / 4) ** 2),
}
SEEDS = {"control": 101, "qdrag": 201, "qdragaxis": 201, "mlag": 301, "inflow": 401, "cant": 501, "linthrust": 601,
         "ground": 701, "ground2": 711}


def flights(folder, case, every=4):
    """The audit's estimation and validation flights of ``case`` written to
    ``folder/CASE_{est,val}_RATE.csv`` (``every=4``: its 100 Hz logs, every 4th row of the
    400 Hz simulation); returns their paths and the truth (``effective``: the K_T and b a
    canted rotor gives)."""
    import os
    truth = default_truth()
    truth.update(CASES[case])
    nominal = dict(truth)
    nominal["KT"] = truth["KT"] * 1.05       # the autopilot's own (imperfect) tuning model
    nominal["b"] = truth["b"] * 0.95
    os.makedirs(folder, exist_ok=True)
    kinds = ["estg", "valg"] if case in ("ground", "ground2") else ["est", "val"]
    paths = []
    for j, kind in enumerate(kinds):
        seed = SEEDS[case] + j
        ref, dur = make_reference(kind, seed)
        cols, _ = simulate(truth, nominal, ref, dur, seed=seed + 1000)
        path = os.path.join(str(folder), f"{case}_{['est', 'val'][j]}_{400 // every}.csv")
        write_csv(path, cols, every=every)
        paths.append(path)
    d = np.radians(truth["cant_deg"])
    truth["effective"] = dict(K_T=truth["KT"] * np.cos(d), b=truth["b"] + truth["l"] * truth["KT"] * np.sin(d))
    return paths, truth


def airframe(path, start="high", ground_z=None):
    """The audit's airframe files: mass, inertia, arm and rotor inertia right (measured); K_T,
    b, Kd started off (``"high"``: +40 %, +45 %, +50 %; ``"low"``: -35 %, -40 %, -45 %;
    ``"true"``); ``ground_z`` as its af_highg.toml (1.5)."""
    t = default_truth()
    KT, b, Kd = t["KT"], t["b"], t["Kd"]
    f = {"high": (1.40, 1.45, 1.5), "low": (0.65, 0.60, 0.55), "true": (1.0, 1.0, 1.0)}[start]
    write_airframe(path, t, KT * f[0], b * f[1], [k * f[2] for k in Kd])
    if ground_z is not None:
        text = open(path).read().replace(f"gravity = {G}\n", f"gravity = {G}\nground_z = {ground_z}\n")
        open(path, "w").write(text)
    return path

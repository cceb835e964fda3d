"""Independent quadrotor simulator for auditing greybox (audit30).

Own physics from the contract's conventions (NED world, FRD body, ZYX Euler,
"x" layout, spin [+1,+1,-1,-1]); own cascade controller at 400 Hz; own
quaternion RK4 at 0.5 ms; first-order motors; sensors per case.

    python sim.py CASE OUTDIR      CASE in control, inflow, filtered_attitude,
                                   quadratic_with_lag
"""
import os
import sys
import numpy as np

# ---------------------------------------------------------------- vehicle
G = 9.81
M = 0.45                      # kg
J = np.array([6.0e-4, 6.2e-4, 1.10e-3])   # kg m^2
L_ARM = 0.11                  # m, hub distance from centre
A = L_ARM / np.sqrt(2)
POS = np.array([[+A, +A, 0.0], [-A, -A, 0.0], [+A, -A, 0.0], [-A, +A, 0.0]])
SPIN = np.array([+1.0, +1.0, -1.0, -1.0])
K_T = 3.4e-7                  # N/(rad/s)^2   (hover ~1800 rad/s)
B_YAW = 5.0e-9                # N m/(rad/s)^2 (b/K_T = 0.0147 m)
KD = np.array([0.08, 0.08, 0.12])   # N s/m world-frame linear drag
J_R = 2.0e-7                  # kg m^2 rotor+motor bell inertia
R_PROP = 0.038                # m (3-inch prop)
W_MIN, W_MAX = 300.0, 3600.0
W_HOVER = np.sqrt(M * G / (4 * K_T))

DT_SIM = 0.0005               # RK4 step
DT_CTRL = 0.0025              # 400 Hz controller
DT_LOG = 0.005                # 200 Hz log rows

CASES = {
    "control": dict(tau_m=0.020, inflow_c=None, Kq=None, att="mocap", log_w="actual"),
    "inflow": dict(tau_m=0.020, inflow_c=0.4, Kq=None, att="mocap", log_w="actual"),
    # variant: inflow from the centre of gravity's body-z velocity only (no rotation term)
    "inflow_cog": dict(tau_m=0.020, inflow_c=0.4, Kq=None, att="mocap", log_w="actual", inflow_hub=False),
    "filtered_attitude": dict(tau_m=0.020, inflow_c=None, Kq=None, att="filter", log_w="actual"),
    "quadratic_with_lag": dict(tau_m=0.030, inflow_c=None, Kq=np.array([0.025, 0.025, 0.025]),
                               att="mocap", log_w="command"),
}
CASE_SEED = {"control": 101, "inflow": 202, "inflow_cog": 252, "filtered_attitude": 303, "quadratic_with_lag": 404}


# ---------------------------------------------------------------- maths
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


def q_to_euler(q):
    w, x, y, z = q
    phi = np.arctan2(2*(w*x + y*z), 1 - 2*(x*x + y*y))
    theta = np.arcsin(np.clip(2*(w*y - z*x), -1, 1))
    psi = np.arctan2(2*(w*z + x*y), 1 - 2*(y*y + z*z))
    return np.array([phi, theta, psi])


def euler_to_q(phi, theta, psi):
    cr, sr = np.cos(phi/2), np.sin(phi/2)
    cp, sp = np.cos(theta/2), np.sin(theta/2)
    cy, sy = np.cos(psi/2), np.sin(psi/2)
    return np.array([cr*cp*cy + sr*sp*sy, sr*cp*cy - cr*sp*sy,
                     cr*sp*cy + sr*cp*sy, cr*cp*sy - sr*sp*cy])


# ---------------------------------------------------------------- dynamics
def rotor_thrusts(w, vb, om, cfg):
    T = K_T * w**2
    if cfg["inflow_c"] is not None:
        # axial inflow: hub velocity along body z (down +); climbing (v_hz<0) -> less thrust
        v_hub_z = vb[2] + (np.cross(om, POS))[:, 2] if cfg.get("inflow_hub", True) else vb[2]
        T = T * (1.0 + v_hub_z / (cfg["inflow_c"] * np.maximum(w, 1.0) * R_PROP))
    return T


def deriv(s, w_cmd, cfg):
    """s = [p(3) world, v(3) world, q(4) body->world, om(3) body, w(4)]"""
    v = s[3:6]
    q = s[6:10]
    om = s[10:13]
    w = s[13:17]
    Rm = qrot(q)
    vb = Rm.T @ v
    T = rotor_thrusts(w, vb, om, cfg)
    F = np.array([0.0, 0.0, M * G]) - Rm @ np.array([0.0, 0.0, T.sum()]) - KD * v
    if cfg["Kq"] is not None:
        F = F - cfg["Kq"] * np.linalg.norm(v) * v
    acc = F / M
    tau = np.array([np.sum(-POS[:, 1] * T), np.sum(POS[:, 0] * T),
                    np.sum(SPIN * B_YAW * w**2)])
    Om_r = np.sum(SPIN * w)
    tau = tau + J_R * Om_r * np.array([om[1], -om[0], 0.0])
    dom = (tau - np.cross(om, J * om)) / J
    dq = 0.5 * qmul(q, np.array([0.0, om[0], om[1], om[2]]))
    dw = (w_cmd - w) / cfg["tau_m"]
    return np.concatenate([v, acc, dq, dom, dw]), acc


def rk4(s, w_cmd, cfg, h):
    k1, a1 = deriv(s, w_cmd, cfg)
    k2, _ = deriv(s + 0.5*h*k1, w_cmd, cfg)
    k3, _ = deriv(s + 0.5*h*k2, w_cmd, cfg)
    k4, _ = deriv(s + h*k3, w_cmd, cfg)
    s = s + h/6*(k1 + 2*k2 + 2*k3 + k4)
    s[6:10] /= np.linalg.norm(s[6:10])
    return s


# ---------------------------------------------------------------- references
class MultiSine:
    def __init__(self, rng, duration, scale=1.0, yaw=True):
        self.T = duration
        def comps(amps, freqs):
            return [(a * scale, f, rng.uniform(0, 2*np.pi)) for a, f in zip(amps, freqs)]
        j = lambda: rng.uniform(0.9, 1.1)
        self.ch = {
            "x": comps([1.2, 0.6, 0.10], [0.11*j(), 0.33*j(), 0.85*j()]),
            "y": comps([1.0, 0.55, 0.10], [0.13*j(), 0.29*j(), 0.95*j()]),
            "z": comps([0.35, 0.25, 0.06], [0.17*j(), 0.55*j(), 1.3*j()]),
            "psi": comps([0.8, 0.3, 0.08], [0.07*j(), 0.25*j(), 0.9*j()]) if yaw else [],
        }
        # faster segment (a burst of 1.5-2 Hz) in the middle third
        self.fast = {k: (0.05*scale if k != "psi" else 0.1, rng.uniform(1.5, 2.0), rng.uniform(0, 2*np.pi))
                     for k in ("x", "y", "z", "psi")}
        self.t_fast = (duration*0.45, duration*0.62)
        self.center = {"x": 0.0, "y": 0.0, "z": -1.5, "psi": 0.0}

    def _win(self, t):
        # smooth ramp in/out over 3 s, returns value and derivatives (approx. via numerics)
        r = 3.0
        def s(u):
            u = np.clip(u, 0, 1)
            return u*u*u*(10 - 15*u + 6*u*u)
        return s(t / r) * s((self.T - t) / r)

    def value(self, t, k):
        out = self.center[k]
        wv = self._win(t)
        acc = 0.0
        for a, f, ph in self.ch[k]:
            acc += a * np.sin(2*np.pi*f*t + ph)
        a, f, ph = self.fast[k]
        t0, t1 = self.t_fast
        if t0 < t < t1:
            u = (t - t0) / (t1 - t0)
            acc += a * np.sin(np.pi*u)**2 * np.sin(2*np.pi*f*t + ph)
        return out + wv * acc

    def derivs(self, t, k, h=1e-3):
        f0 = self.value(t, k)
        fp, fm = self.value(t + h, k), self.value(t - h, k)
        return f0, (fp - fm)/(2*h), (fp - 2*f0 + fm)/(h*h)


# ---------------------------------------------------------------- controller
class Controller:
    def __init__(self):
        # mixer model deliberately 5-10 % off the truth
        self.KT_hat = K_T * 1.07
        self.l_hat = A * 0.93
        self.b_hat = B_YAW * 1.09
        self.M_hat = M * 0.95
        self.J_hat = J * 1.06
        self.ipos = np.zeros(3)
        self.irate = np.zeros(3)
        Mx = np.vstack([np.full(4, self.KT_hat), -POS[:, 1]/A*self.l_hat*self.KT_hat,
                        POS[:, 0]/A*self.l_hat*self.KT_hat, SPIN*self.b_hat])
        self.Minv = np.linalg.inv(Mx)

    def step(self, t, pos, vel, eul, om, ref, dt):
        (xr, vxr, axr), (yr, vyr, ayr), (zr, vzr, azr), (psir, dpsir, _) = ref
        e = np.array([xr, yr, zr]) - pos
        ev = np.array([vxr, vyr, vzr]) - vel
        self.ipos = np.clip(self.ipos + e*dt, -1.0, 1.0)
        kp = np.array([4.0, 4.0, 6.0]); kv = np.array([3.5, 3.5, 4.5]); ki = np.array([1.0, 1.0, 2.0])
        a_des = kp*e + kv*ev + ki*self.ipos + np.array([axr, ayr, azr])
        F = self.M_hat * (a_des - np.array([0, 0, G]))      # = -T R e3
        F[2] = min(F[2], -0.3*self.M_hat*G)
        T = np.linalg.norm(F)
        b3 = -F / T
        psi = eul[2]
        c, s = np.cos(psi), np.sin(psi)
        b3r = np.array([c*b3[0] + s*b3[1], -s*b3[0] + c*b3[1], b3[2]])
        phi_d = np.arcsin(np.clip(-b3r[1], -0.7, 0.7))
        th_d = np.clip(np.arctan2(b3r[0], b3r[2]), -0.7, 0.7)
        epsi = np.arctan2(np.sin(psir - psi), np.cos(psir - psi))
        # attitude P -> rate setpoint (Euler-rate feedforward for yaw)
        katt = np.array([9.0, 9.0, 5.0])
        eatt = np.array([phi_d - eul[0], th_d - eul[1], epsi])
        om_d = katt * eatt + np.array([0, 0, dpsir])
        erate = om_d - om
        self.irate = np.clip(self.irate + erate*dt, -0.5, 0.5)
        alpha = np.array([28.0, 28.0, 12.0]) * erate + np.array([40.0, 40.0, 10.0]) * self.irate
        tau = self.J_hat * alpha + np.cross(om, self.J_hat * om)
        w2 = self.Minv @ np.array([T, tau[0], tau[1], tau[2]])
        w = np.sqrt(np.clip(w2, W_MIN**2, W_MAX**2))
        return w


# ---------------------------------------------------------------- flight
def fly(case, seed, duration):
    cfg = CASES[case]
    rng = np.random.default_rng(seed)
    ref = MultiSine(rng, duration, scale=1.35 if case == "quadratic_with_lag" else 1.0)
    ctrl = Controller()
    s = np.zeros(17)
    s[2] = -1.5
    s[6:10] = euler_to_q(0, 0, 0)
    s[13:17] = W_HOVER
    n_ctrl_per_log = int(round(DT_LOG / DT_CTRL))
    n_sim_per_ctrl = int(round(DT_CTRL / DT_SIM))
    n_rows = int(round(duration / DT_LOG))
    gyro_bias = np.array([0.01, 0.01, 0.01]) if cfg["att"] == "filter" else np.zeros(3)
    est = np.zeros(3)          # complementary filter euler estimate
    tau_f = 2.0
    rows = []
    w_cmd = np.full(4, W_HOVER)
    acc = np.zeros(3)
    for k in range(n_rows):
        t = k * DT_LOG
        for j in range(n_ctrl_per_log):
            tc = t + j * DT_CTRL
            pos, vel, q, om = s[0:3], s[3:6], s[6:10], s[10:13]
            eul = q_to_euler(q)
            # onboard IMU at 400 Hz
            gyro = om + gyro_bias + rng.normal(0, 0.003, 3)
            _, acc = deriv(s, w_cmd, cfg)
            Rm = qrot(q)
            f_b = Rm.T @ (acc - np.array([0, 0, G])) + rng.normal(0, 0.05, 3)
            if cfg["att"] == "filter":
                ph, th = est[0], est[1]
                Wm = np.array([[1, np.sin(ph)*np.tan(th), np.cos(ph)*np.tan(th)],
                               [0, np.cos(ph), -np.sin(ph)],
                               [0, np.sin(ph)/np.cos(th), np.cos(ph)/np.cos(th)]])
                est = est + DT_CTRL * (Wm @ gyro)
                phi_a = np.arctan2(-f_b[1], -f_b[2])
                th_a = np.arctan2(f_b[0], np.hypot(f_b[1], f_b[2]))
                psi_m = eul[2]   # magnetometer/heading reference
                g = DT_CTRL / tau_f
                est[0] += g * (phi_a - est[0])
                est[1] += g * (th_a - est[1])
                est[2] += g * np.arctan2(np.sin(psi_m - est[2]), np.cos(psi_m - est[2]))
            if j == 0:
                # log row: state at time t (before this row's control update)
                rows.append(dict(t=t, pos=pos.copy(), eul=eul.copy(), om=om.copy(),
                                 w=s[13:17].copy(), gyro=gyro.copy(), est=est.copy(),
                                 w_cmd=None))
            r = [ref.derivs(tc, ch) for ch in ("x", "y", "z", "psi")]
            w_cmd = ctrl.step(tc, pos, vel, eul, om, r, DT_CTRL)
            if j == 0:
                rows[-1]["w_cmd"] = w_cmd.copy()
            for _ in range(n_sim_per_ctrl):
                s = rk4(s, w_cmd, cfg, DT_SIM)
        if not np.all(np.isfinite(s)):
            raise RuntimeError("simulation diverged")
    return rows, cfg


def write_log(rows, cfg, path, seed):
    rng = np.random.default_rng(seed + 7)
    n = len(rows)
    # mocap at 100 Hz (even rows), 2 % random drops and three 0.3-s gaps
    moc = np.zeros(n, bool)
    moc[::2] = True
    moc &= rng.random(n) > 0.02
    for _ in range(3):
        g0 = rng.integers(200, n - 200)
        moc[g0:g0 + 60] = False
    lines = ["t,w1,w2,w3,w4,x,y,z,phi,theta,psi,p,q,r"]
    for i, rw in enumerate(rows):
        if cfg["log_w"] == "actual":
            w = rw["w"] + rng.normal(0, 3.0, 4)
        else:
            w = rw["w_cmd"]
        if moc[i]:
            pos = rw["pos"] + rng.normal(0, 0.001, 3)
            ps = "%.5f,%.5f,%.5f" % tuple(pos)
        else:
            ps = ",,"
        if cfg["att"] == "mocap":
            if moc[i]:
                e = rw["eul"] + rng.normal(0, 0.002, 3)
                e[2] = np.arctan2(np.sin(e[2]), np.cos(e[2]))
                es = "%.5f,%.5f,%.5f" % tuple(e)
            else:
                es = ",,"
            gy = rw["om"] + rng.normal(0, 0.005, 3)
        else:
            e = rw["est"].copy()
            e[2] = np.arctan2(np.sin(e[2]), np.cos(e[2]))
            es = "%.5f,%.5f,%.5f" % tuple(e)
            gy = rw["gyro"]
        lines.append("%.3f,%.3f,%.3f,%.3f,%.3f,%s,%s,%.5f,%.5f,%.5f" %
                     (rw["t"], w[0], w[1], w[2], w[3], ps, es, gy[0], gy[1], gy[2]))
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def write_truth_states(rows, path):
    with open(path, "w") as f:
        f.write("t,x,y,z,phi,theta,psi,p,q,r,w1,w2,w3,w4,c1,c2,c3,c4\n")
        for rw in rows:
            f.write(",".join("%.9g" % v for v in
                             [rw["t"], *rw["pos"], *rw["eul"], *rw["om"], *rw["w"], *rw["w_cmd"]]) + "\n")


def write_airframe(path, guesses=True):
    if guesses:
        kt, b, kd = K_T * 1.25, B_YAW * 0.7, [0.15, 0.15, 0.15]
    else:
        kt, b, kd = K_T, B_YAW, list(KD)
    with open(path, "w") as f:
        f.write('[airframe]\nname = "audit30_quad"\nmass = %r\ninertia = [%r, %r, %r]\n'
                'arm_length = %r\nlayout = "x"\nrotor_inertia = %r\ngravity = %r\n\n'
                '[parameters]\nK_T = %r\nb = %r\nKd = [%r, %r, %r]\n'
                % tuple(float(v) for v in (M, *J, L_ARM, J_R, G, kt, b, *kd)))


def main(which, out):
    if which not in CASES:
        raise SystemExit("unknown case %r (one of %s)" % (which, ", ".join(CASES)))
    os.makedirs(out, exist_ok=True)
    base = CASE_SEED[which]
    flights = [("est1", base + 1, 45.0), ("est2", base + 2, 45.0), ("val", base + 3, 30.0)]
    if which == "inflow_cog":      # time budget: one estimation flight
        flights = [flights[0], flights[2]]
    for name, seed, dur in flights:
        rows, cfg = fly(which, seed, dur)
        write_log(rows, cfg, os.path.join(out, name + ".csv"), seed)
        write_truth_states(rows, os.path.join(out, name + "_truth.csv"))
    write_airframe(os.path.join(out, "airframe.toml"), guesses=True)
    write_airframe(os.path.join(out, "airframe_true.toml"), guesses=False)


def airframes_only(out):
    write_airframe(os.path.join(out, "airframe.toml"), guesses=True)
    write_airframe(os.path.join(out, "airframe_true.toml"), guesses=False)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print(__doc__)
        sys.exit(2)
    main(sys.argv[1], sys.argv[2])

"""Closed-loop simulation of a composed nonlinear model under the seed paper's LQR or an
automatically tuned cascaded PID, with rotor-speed limits, and step-response metrics.

:func:`design_lqr` linearises the model at hover, discretises it (ZOH, the controller's
sample time) and designs ``dlqry`` on the outputs ``x, y, z, psi`` (the seed's design:
``Q = 1``, ``R = 0.001``; those four outputs are the ones a position controller is asked to
track, the other states are weighted through the dynamics), with the reference gain ``Kr``
of eq. (12). The law is ``u = u_trim - K (x - x_trim) + Kr (r - r_trim)``, saturated to
``[w_min, w_max]``.

:func:`simulate_lqr` runs the controller and the plant (sub-stepped RK4) as one CasADi
step ``mapaccum``-ed over the whole scenario: no Python loop over samples.

:func:`step_metrics` gives rise time (10-90 %), overshoot, settling time (2 % band) and
ITAE of one axis' response to a step.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .control import dlqry, reference_gain
from .errors import GreyboxInputError
from .integrate import n_substeps, rk4_step
from .linearize import hover_trim, linearize
from .model import QuadrotorModel

__all__ = ["LQRDesign", "design_lqr", "simulate_lqr", "ClosedLoop", "step_metrics", "step_reference",
           "TRACKED", "CascadedPID", "PID_GAINS", "simulate_pid", "tune_pid", "LinearClosedLoop",
           "simulate_linear_lqr"]

TRACKED = ("x", "y", "z", "psi")


@dataclass
class LQRDesign:
    K: np.ndarray          # (nu, nx)
    Kr: np.ndarray         # (nu, 4)
    x_trim: np.ndarray
    u_trim: np.ndarray
    dt: float
    poles: np.ndarray      # closed-loop eigenvalues of the linear design


@dataclass
class ClosedLoop:
    t: np.ndarray
    states: np.ndarray     # (N, nx)
    inputs: np.ndarray     # (N, nu) after saturation
    reference: np.ndarray  # (N, 4) x, y, z, psi
    saturated: float       # fraction of samples with some rotor at a limit

    def output(self, name: str, state_names: list[str]) -> np.ndarray:
        return self.states[:, state_names.index(name)]


def design_lqr(model: QuadrotorModel, p: np.ndarray | None = None, dt: float = 0.01,
               q: float = 1.0, r: float = 1e-3, position=(0.0, 0.0, -1.0)) -> LQRDesign:
    """Discrete LQR (``dlqry``, ``Q = q I`` on ``x, y, z, psi``, ``R = r I``) and ``Kr``."""
    p = model.default_parameters() if p is None else np.asarray(p, dtype=float)
    if model.signal_names:
        raise GreyboxInputError(f"design_lqr: the model reads logged signals {model.signal_names}; "
                                "design on a model without them")
    x0, u0 = hover_trim(model, p, position=position)
    lin = linearize(model, p=p, x=x0, u=u0).discretize(dt)
    K, Kr, E = _tracking_lqr(lin.A, lin.B, lin.C, lin.D, lin.output_names, q, r)
    return LQRDesign(K, Kr, x0, u0, dt, E)


def _tracking_lqr(A, B, C, D, output_names, q: float, r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(K, Kr, poles)``: ``dlqry`` with ``Q = q I`` on the outputs :data:`TRACKED`,
    ``R = r I``, and the reference gain of eq. (12) — for any state coordinates."""
    rows = [list(output_names).index(c) for c in TRACKED]
    Ct, Dt = C[rows], D[rows]
    Q, R = q * np.eye(len(rows)), r * np.eye(B.shape[1])
    K, S, E = dlqry(A, B, Ct, Dt, Q, R)
    return K, reference_gain(A, B, Ct, Q, R, K, S), E


def _saturated_fraction(U: np.ndarray, lo: float, hi: float) -> float:
    """Fraction of samples with some rotor at a limit."""
    return float(np.mean(np.any((U <= lo + 1e-9) | (U >= hi - 1e-9), axis=1)))


def step_reference(t: np.ndarray, start=(0.0, 0.0, -1.0, 0.0), steps=None) -> np.ndarray:
    """The seed's scenario: hover at ``start``, then 1 m steps in x (t = 1 s), y (t = 6 s)
    and z (t = 11 s, upwards = -1 m in NED); ``steps``: ``[(time, axis index, size)]``."""
    steps = [(1.0, 0, 1.0), (6.0, 1, 1.0), (11.0, 2, -1.0)] if steps is None else steps
    ref = np.tile(np.asarray(start, dtype=float), (t.size, 1))
    for t0, ax, size in steps:
        ref[t >= t0, ax] += size
    return ref


def simulate_lqr(model: QuadrotorModel, p: np.ndarray, design: LQRDesign, reference: np.ndarray,
                 w_limits: tuple[float, float] | None = None, x0: np.ndarray | None = None) -> ClosedLoop:
    """Closed loop of ``model`` (parameters ``p``, possibly not those of the design) under
    ``design`` tracking ``reference`` (N, 4) sampled every ``design.dt``; rotor speeds
    saturated to ``w_limits`` (default 0 .. 2 x hover)."""
    reference = np.asarray(reference, dtype=float)
    if reference.ndim != 2 or reference.shape[1] != 4:
        raise GreyboxInputError(f"reference must be (N, 4) x, y, z, psi, got {reference.shape}")
    if model.inputs != "rotor_speeds":
        raise GreyboxInputError("simulate_lqr needs a rotor-speed model")
    nx_d = design.K.shape[1]
    if nx_d > model.nx:
        raise GreyboxInputError(f"the design has {nx_d} states, the plant {model.nx}")
    lo, hi = w_limits if w_limits is not None else (0.0, 2.0 * float(np.max(design.u_trim)))
    step = rk4_step(model, n_substeps(design.dt))
    x = ca.SX.sym("x", model.nx)
    rk = ca.SX.sym("r", 4)
    r_trim = np.array([design.x_trim[0], design.x_trim[1], design.x_trim[2], design.x_trim[5]])
    # the design's states are the first nx_d of the plant's (extra plant effect states unseen)
    u = design.u_trim - ca.mtimes(design.K, x[:nx_d] - design.x_trim[:nx_d]) + \
        ca.mtimes(design.Kr, rk - r_trim)
    u_sat = ca.fmin(ca.fmax(u, lo), hi)
    xn = step(x, u_sat, p, 0.0, design.dt)
    F = ca.Function("cl_step", [x, rk], [xn, u_sat]).mapaccum("cl", reference.shape[0], [0], [0])
    if x0 is None:
        x0 = _start_state(model, p, reference, design.x_trim[:12], design.u_trim)
    Xs, Us = F(x0, reference.T)
    X = np.vstack([x0, np.asarray(Xs).T[:-1]])
    if not np.all(np.isfinite(X)):
        raise GreyboxInputError("closed-loop simulation diverged (non-finite states)")
    return _closed_loop(X, np.asarray(Us).T, reference, design.dt, (lo, hi))


def _start_state(model: QuadrotorModel, p: np.ndarray, reference: np.ndarray, x_base: np.ndarray,
                 u0: np.ndarray) -> np.ndarray:
    """Still hover at the reference's first point (effect states from ``u0``)."""
    base = np.array(x_base, dtype=float)
    base[[0, 1, 2, 5]] = reference[0]
    return model.initial_state(base, u0, p)


def _closed_loop(X: np.ndarray, U: np.ndarray, reference: np.ndarray, dt: float,
                 limits: tuple[float, float]) -> ClosedLoop:
    return ClosedLoop(np.arange(reference.shape[0]) * dt, X, U, reference, _saturated_fraction(U, *limits))


@dataclass
class LinearClosedLoop:
    """A linear (black-box) model's closed loop: its outputs, not physical states."""

    t: np.ndarray
    outputs: np.ndarray     # (N, l) in the model's output units
    output_names: list[str]
    inputs: np.ndarray      # (N, m) after saturation
    reference: np.ndarray   # (N, 4)
    saturated: float
    K: np.ndarray
    Kr: np.ndarray
    poles: np.ndarray

    def output(self, name: str) -> np.ndarray:
        return self.outputs[:, self.output_names.index(name)]


def simulate_linear_lqr(ss, reference: np.ndarray, q: float = 1.0, r: float = 1e-3,
                        w_limits: tuple[float, float] | None = None) -> LinearClosedLoop:
    """The seed's LQR designed and flown on a discrete linear model ``ss`` (e.g. from
    :func:`greybox.n4sid.n4sid`: any state coordinates, outputs named ``x, y, z, ...``).

    ``dlqry`` with ``Q = q I`` on the outputs ``x, y, z, psi`` and ``R = r I``, and ``Kr`` of
    eq. (12) — the same design as :func:`design_lqr`, on the black box's own states (the
    output weighting is what makes one design procedure apply to both). Deviations are
    about the model's operating point (``ss.u0``, ``ss.y0``); rotor speeds are saturated to
    ``w_limits`` (default 0 .. 2 x ``ss.u0``) in absolute units. The loop starts at the
    steady state that holds the reference's first point.
    """
    names = list(ss.output_names)
    missing = [c for c in TRACKED if c not in names]
    if missing:
        raise GreyboxInputError(f"simulate_linear_lqr: the model has no output(s) {missing}; "
                                f"its outputs are {names}")
    reference = np.asarray(reference, dtype=float)
    if reference.ndim != 2 or reference.shape[1] != 4:
        raise GreyboxInputError(f"reference must be (N, 4) x, y, z, psi, got {reference.shape}")
    rows = [names.index(c) for c in TRACKED]
    A, B, C, D = ss.A, ss.B, ss.C, ss.D
    K, Kr, E = _tracking_lqr(A, B, C, D, names, q, r)
    u0, y0 = np.asarray(ss.u0, float), np.asarray(ss.y0, float)
    lo, hi = w_limits if w_limits is not None else (0.0, 2.0 * float(np.max(u0)))
    dref = reference - y0[rows]
    Acl = A - B @ K
    x = np.linalg.solve(np.eye(A.shape[0]) - Acl, B @ Kr @ dref[0])
    N = reference.shape[0]
    Y = np.empty((N, C.shape[0]))
    U = np.empty((N, B.shape[1]))
    for k in range(N):   # a few thousand steps of small matrices: cheaper than building a graph
        du = np.clip(u0 - K @ x + Kr @ dref[k], lo, hi) - u0
        U[k] = u0 + du
        Y[k] = C @ x + D @ du + y0
        x = A @ x + B @ du
    if not np.all(np.isfinite(Y)):
        raise GreyboxInputError("linear closed-loop simulation diverged (non-finite outputs)")
    return LinearClosedLoop(np.arange(N) * ss.dt, Y, names, U, reference, _saturated_fraction(U, lo, hi),
                            K, Kr, E)


def step_metrics(t: np.ndarray, y: np.ndarray, t_step: float, y_before: float, y_after: float,
                 t_end: float | None = None) -> dict[str, float]:
    """Rise time (10-90 %), overshoot (% of the step), settling time (last exit from the 2 %
    band) and ITAE ``int (t - t_step) |e| dt`` of a step from ``y_before`` to ``y_after``
    at ``t_step`` (up to ``t_end``)."""
    k = (t >= t_step) & (t <= (t_end if t_end is not None else t[-1]))
    tt, yy = t[k] - t_step, y[k]
    size = y_after - y_before
    if size == 0:
        raise GreyboxInputError("step_metrics: the step has zero size")
    frac = (yy - y_before) / size
    i10 = np.flatnonzero(frac >= 0.1)
    i90 = np.flatnonzero(frac >= 0.9)
    rise = float(tt[i90[0]] - tt[i10[0]]) if i10.size and i90.size else float("nan")
    overshoot = float(max(0.0, (frac.max() - 1.0) * 100.0))
    outside = np.flatnonzero(np.abs(frac - 1.0) > 0.02)
    if outside.size == 0:
        settling = 0.0
    elif outside[-1] == tt.size - 1:
        settling = float("nan")        # never settles within the window
    else:
        settling = float(tt[outside[-1] + 1])
    itae = float(np.trapezoid(tt * np.abs(y_after - yy), tt))
    return {"rise_time": rise, "overshoot_pct": overshoot, "settling_time": settling, "itae": itae}


# ------------------------------------------------------------------------------ cascaded PID
PID_GAINS = ("kp_xy", "ki_xy", "kd_xy", "kp_z", "ki_z", "kd_z", "kp_att", "kd_att")
"""Gains of :class:`CascadedPID`: outer position loop (P, I, D on the error's rate, seed eqs.
13-16 as corrected in the README's "Departures from the seed paper"), inner attitude loop (P, D);
yaw uses the attitude gains."""


@dataclass
class CascadedPID:
    """Seed eqs. (13)-(18): position errors -> desired accelerations (PID, derivative on the
    error's rate, integrators clamped at ``i_limit`` for anti-windup) -> desired roll, pitch
    (heading-compensated, limited to ``tilt_limit``) and thrust -> attitude PD -> torques ->
    rotor speeds through the nominal allocation, saturated to ``w_limits`` attitude first
    (torques scaled into the available range, then the collective shifted)."""

    gains: dict[str, float]
    dt: float = 0.01
    tilt_limit: float = 0.5
    i_limit: float = 1.0
    w_limits: tuple[float, float] | None = None
    cost: float | None = None       # tuning criterion reached, if tuned

    def vector(self) -> np.ndarray:
        return np.array([self.gains[k] for k in PID_GAINS])


def _pid_loop(model: QuadrotorModel, p: np.ndarray, dt: float, n: int, tilt_limit: float, i_limit: float,
              w_limits: tuple[float, float]) -> ca.Function:
    """``F(x0, xi0, ref (4, n), gains) -> (X, U)``: the PID closed loop mapaccum'd over n steps."""
    af = model.airframe
    names = model.param_names
    kt = float(p[names.index("K_T")])
    b = float(p[names.index("b")]) if "b" in names else 1e-7
    G = af.allocation_matrix() * np.array([kt, kt, kt, b])[:, None]
    J = np.diag(af.inertia)
    m, g = af.mass, af.gravity
    x = ca.SX.sym("x", model.nx)
    xi = ca.SX.sym("xi", 3)
    r = ca.SX.sym("r", 4)
    k = ca.SX.sym("k", len(PID_GAINS))
    kp = ca.vertcat(k[0], k[0], k[3])
    ki = ca.vertcat(k[1], k[1], k[4])
    kd = ca.vertcat(k[2], k[2], k[5])
    kp_att, kd_att = k[6], k[7]
    pos, eul, vel, om = x[0:3], x[3:6], x[6:9], x[9:12]
    e = r[:3] - pos
    a_des = kp * e + ki * xi - kd * vel          # derivative on the error's rate (constant steps)
    psi = eul[2]
    th_d = -(a_des[0] * ca.cos(psi) + a_des[1] * ca.sin(psi)) / g
    ph_d = (a_des[1] * ca.cos(psi) - a_des[0] * ca.sin(psi)) / g
    th_d = ca.fmin(ca.fmax(th_d, -tilt_limit), tilt_limit)
    ph_d = ca.fmin(ca.fmax(ph_d, -tilt_limit), tilt_limit)
    thrust = m * (g - a_des[2]) / (ca.cos(eul[0]) * ca.cos(eul[1]))
    e_psi = ca.atan2(ca.sin(r[3] - psi), ca.cos(r[3] - psi))
    tau = ca.vertcat(J[0] * (kp_att * (ph_d - eul[0]) - kd_att * om[0]),
                     J[1] * (kp_att * (th_d - eul[1]) - kd_att * om[1]),
                     J[2] * (0.25 * kp_att * e_psi - 0.5 * kd_att * om[2]))
    # attitude before altitude when rotors saturate: scale the torque part into the
    # available range, then shift the collective as far as the limits allow
    lo, hi = w_limits
    Ginv_np = np.linalg.pinv(G)
    d = ca.DM(Ginv_np[:, 1:]) @ tau
    span = ca.mmax(d) - ca.mmin(d)
    d = d * ca.fmin(1.0, (hi ** 2 - lo ** 2) / ca.fmax(span, 1e-12))
    c = ca.fmin(ca.fmax(thrust * float(np.mean(Ginv_np[:, 0])), lo ** 2 - ca.mmin(d)), hi ** 2 - ca.mmax(d))
    w2 = c + d
    w = ca.sqrt(ca.fmin(ca.fmax(w2, lo ** 2), hi ** 2))
    step = rk4_step(model, n_substeps(dt))
    xn = step(x, w, p, 0.0, dt)
    xin = ca.fmin(ca.fmax(xi + dt * e, -i_limit), i_limit)      # clamped integrators: anti-windup
    f = ca.Function("pid_step", [ca.vertcat(x, xi), r, k], [ca.vertcat(xn, xin), w])
    return f.mapaccum("pid", n, [0], [0])


def simulate_pid(model: QuadrotorModel, p: np.ndarray, pid: CascadedPID, reference: np.ndarray,
                 x0: np.ndarray | None = None) -> ClosedLoop:
    """Closed loop of ``model`` under ``pid`` tracking ``reference`` (N, 4) every ``pid.dt``."""
    reference = np.asarray(reference, dtype=float)
    w_h = model.hover_speed(p)
    lims = pid.w_limits or (0.0, 2.0 * w_h)
    F = _pid_loop(model, p, pid.dt, reference.shape[0], pid.tilt_limit, pid.i_limit, lims)
    return _run_pid(F, model, p, pid.vector(), reference, x0, lims, pid.dt)


def _run_pid(F, model, p, gains, reference, x0, lims, dt) -> ClosedLoop:
    if x0 is None:
        x0 = _start_state(model, p, reference, np.zeros(12), np.full(model.nu, model.hover_speed(p)))
    Xs, Us = F(np.concatenate([x0, np.zeros(3)]), reference.T, gains)
    X = np.vstack([x0, np.asarray(Xs).T[:-1, :model.nx]])
    return _closed_loop(X, np.asarray(Us).T, reference, dt, lims)


def tune_pid(model: QuadrotorModel, p: np.ndarray | None = None, dt: float = 0.01,
             w_limits: tuple[float, float] | None = None, max_evals: int = 300) -> CascadedPID:
    """Gains minimising the ITAE of the seed's x, y and z steps (plus a penalty on rotor
    saturation and on divergence) on ``model``, by Nelder-Mead in log-gains from a
    bandwidth-separated start (inner loop 20 rad/s, outer 2 rad/s, damping 0.8). The loop
    is built once; each evaluation is one mapaccum call."""
    from scipy.optimize import minimize
    p = model.default_parameters() if p is None else np.asarray(p, dtype=float)
    t = np.arange(0, 16, dt)
    ref = step_reference(t)
    w_h = model.hover_speed(p)
    lims = w_limits or (0.0, 2.0 * w_h)
    F = _pid_loop(model, p, dt, t.size, 0.5, 1.0, lims)
    wa, wp, z = 20.0, 2.0, 0.8
    g0 = np.array([wp ** 2, 0.1 * wp ** 2, 2 * z * wp, wp ** 2, 0.1 * wp ** 2, 2 * z * wp, wa ** 2, 2 * z * wa])
    steps = [(1.0, 0), (6.0, 1), (11.0, 2)]

    def cost(lg):
        cl = _run_pid(F, model, p, np.exp(lg), ref, None, lims, dt)
        if not np.all(np.isfinite(cl.states)) or np.abs(cl.states[:, :3]).max() > 100:
            return 1e6
        c = 0.0
        for ts, ax in steps:
            c += step_metrics(t, cl.states[:, ax], ts, ref[0, ax], ref[-1, ax], ts + 5)["itae"]
        return c + 10.0 * cl.saturated

    res = minimize(cost, np.log(g0), method="Nelder-Mead",
                   options={"maxfev": max_evals, "xatol": 1e-3, "fatol": 1e-4})
    best = np.exp(res.x)
    return CascadedPID(dict(zip(PID_GAINS, map(float, best))), dt, w_limits=lims, cost=float(res.fun))

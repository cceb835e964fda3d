"""Closed-loop simulation of a composed nonlinear model under the seed paper's LQR, with
rotor-speed limits, and step-response metrics.

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
           "TRACKED"]

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
    rows = [lin.output_names.index(c) for c in TRACKED]
    C, D = lin.C[rows], lin.D[rows]
    Q, R = q * np.eye(len(rows)), r * np.eye(model.nu)
    K, S, E = dlqry(lin.A, lin.B, C, D, Q, R)
    Kr = reference_gain(lin.A, lin.B, C, Q, R, K, S)
    return LQRDesign(K, Kr, x0, u0, dt, E)


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
        base = design.x_trim[:12].copy()
        base[[0, 1, 2, 5]] = reference[0]
        x0 = model.initial_state(base, design.u_trim, p)
    Xs, Us = F(x0, reference.T)
    X = np.vstack([x0, np.asarray(Xs).T[:-1]])
    U = np.asarray(Us).T
    if not np.all(np.isfinite(X)):
        raise GreyboxInputError("closed-loop simulation diverged (non-finite states)")
    t = np.arange(reference.shape[0]) * design.dt
    sat = float(np.mean(np.any((U <= lo + 1e-9) | (U >= hi - 1e-9), axis=1)))
    return ClosedLoop(t, X, U, reference, sat)


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

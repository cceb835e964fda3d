"""Integration of the model over zero-order-hold inputs.

Two integrators:

* :func:`rk4_step` — fixed-step RK4 as a CasADi ``Function`` ``(x, u, p, t, h) -> x_next``
  with ``n_sub`` sub-steps per sample interval; it is what the fitter maps over data.
* CVODES through ``casadi.integrator`` (adaptive, tight tolerances) as the accurate reference.

:func:`simulate` runs either over a whole input sequence with ``mapaccum`` (no Python loop
over samples) and returns states and outputs at the sample times.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, Sequence

import casadi as ca
import numpy as np

from .errors import GreyboxInputError, SolverError
from .model import QuadrotorModel

__all__ = ["MAX_STEP", "SUBSTEP_SLACK", "Substeps", "substeps", "log_substeps", "rk4_step", "rk4_step_with_output", "n_substeps", "simulate", "Simulation", "threads",
           "parallel_map", "integrate_states_along"]

MAX_STEP = 2.5e-3
"""Largest RK4 step (s). Logs sampled more slowly are integrated with sub-steps; with the
``motor_lag`` lower bound ``tau_m >= 2 ms`` this keeps ``h/tau <= 1.25``, well inside RK4's
stability region."""


def threads() -> int:
    """Threads a mapped CasADi function runs on: ``$GREYBOX_THREADS`` (default 2). Batch
    workers (``greybox batch``) set it to 1: one process per core is the parallelism there."""
    import os
    try:
        return max(1, int(os.environ.get("GREYBOX_THREADS", "2")))
    except ValueError:
        return 2


def parallel_map(f: ca.Function, n: int) -> ca.Function:
    """``f`` mapped over ``n`` columns, on :func:`threads` threads (serially for one)."""
    k = threads()
    return f.map(n, "serial") if k == 1 else f.map(n, "thread", k)


SUBSTEP_SLACK = 0.05
"""A sub-step may exceed ``max_step`` by this fraction: a 100-Hz log's steps, 10 ms give or
take the jitter of its time stamps (Unix times: 1e-7 s), take four sub-steps, not five."""


def n_substeps(h_max: float, max_step: float = MAX_STEP) -> int:
    """Number of RK4 sub-steps so that no step exceeds ``max_step`` (by more than
    :data:`SUBSTEP_SLACK`)."""
    return max(1, math.ceil(h_max / (max_step * (1 + SUBSTEP_SLACK))))


class Substeps(NamedTuple):
    """RK4 sub-steps per sample of a log: ``n`` over its usual (median) step, up to ``n_max``
    over its longest (a dropped row). A sample takes the least multiple of ``n`` that keeps
    its sub-steps within ``max_step``; a sample-step function branches on the step's length
    (:func:`rk4_step`), so one 20-ms gap in a 100-Hz log no longer makes every sample take
    the sub-steps of 20 ms."""
    n: int
    n_max: int
    max_step: float = MAX_STEP

    @property
    def branches(self) -> int:
        """Number of sub-step counts: ``n``, ``2n``, ... up to ``n_max``."""
        return max(1, math.ceil(self.n_max / self.n))

    def branch(self, h: "ca.MX | np.ndarray") -> "ca.MX | np.ndarray":
        """0-based branch of a step of length ``h``: it takes ``(branch + 1) * n`` sub-steps."""
        limit = self.n * self.max_step * (1 + SUBSTEP_SLACK)
        if isinstance(h, ca.MX):
            return ca.fmin(ca.fmax(ca.ceil(h / limit) - 1, 0), self.branches - 1)
        return np.clip(np.ceil(np.asarray(h) / limit) - 1, 0, self.branches - 1).astype(int)


def substeps(h: "np.ndarray | Sequence[np.ndarray]", max_step: float = MAX_STEP) -> Substeps:
    """The :class:`Substeps` of sample steps ``h`` (an array of steps, or several flights'
    arrays)."""
    parts = [np.asarray(a, dtype=float).ravel() for a in (h if isinstance(h, (list, tuple)) else [h])]
    h = np.concatenate(parts) if parts else np.zeros(0)
    if h.size == 0:
        return Substeps(1, 1, max_step)
    n = n_substeps(float(np.median(h)), max_step)
    n_max = max(n, n_substeps(float(h.max()), max_step))
    return Substeps(n, n * math.ceil(n_max / n), max_step)


def log_substeps(logs: "Sequence") -> Substeps:
    """The :class:`Substeps` of flight logs (objects with sample times ``t``): what the fitter,
    the diagnosis' queued builds and the predictions use alike."""
    return substeps([np.diff(lg.t) for lg in logs])


def rk4_step(model: QuadrotorModel, n_sub: "int | Substeps" = 1) -> ca.Function:
    """``F(x, u, p, t, h) -> x_next``: ``n_sub`` RK4 steps of size ``h/n_sub``, input held;
    with :class:`Substeps` of several branches, a step of length ``h`` takes the count of its
    branch (:meth:`Substeps.branch`)."""
    if isinstance(n_sub, Substeps):
        if n_sub.branches == 1:
            return rk4_step(model, n_sub.n)
        return _branched(rk4_step(model, n_sub.n), n_sub, "rk4_branched")
    f = model.rhs
    x = ca.SX.sym("x", model.nx)
    u = ca.SX.sym("u", model.nu)
    p = ca.SX.sym("p", model.n_params)
    t = ca.SX.sym("t")
    h = ca.SX.sym("h")
    dt = h / n_sub
    xk, tk = x, t
    for _ in range(n_sub):
        k1 = f(xk, u, p, tk)
        k2 = f(xk + dt / 2 * k1, u, p, tk + dt / 2)
        k3 = f(xk + dt / 2 * k2, u, p, tk + dt / 2)
        k4 = f(xk + dt * k3, u, p, tk + dt)
        xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        tk = tk + dt
    return ca.Function("rk4", [x, u, p, t, h], [xk], ["x", "u", "p", "t", "h"], ["x_next"])


def _branched(step: ca.Function, plan: Substeps, name: str) -> ca.Function:
    """``step`` (``(x, u, p, t, h) -> x_next``, ``plan.n`` sub-steps) repeated ``k`` times
    over ``h/k`` in branch ``k - 1``, chosen by the step's length; only the chosen branch runs."""
    ins = [ca.MX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(step.n_in())]
    x, u, p, t, h = ins
    cases = []
    for k in range(1, plan.branches + 1):
        xs, ts, hk = x, t, h / k
        for _ in range(k):
            xs = step(xs, u, p, ts, hk)
            ts = ts + hk
        cases.append(ca.Function(f"{name}_x{k}", ins, [xs]))
    switch = ca.Function.conditional(f"{name}_branch", cases[:-1], cases[-1])
    return ca.Function(name, ins, [switch(plan.branch(h), x, u, p, t, h)],
                       ["x", "u", "p", "t", "h"], ["x_next"])


def integrate_states_along(model: QuadrotorModel, t: np.ndarray, inputs: np.ndarray, states: "list[int]",
                           x0: np.ndarray, held: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Some of the model's states, ``states`` (indices), integrated sample by sample over the
    times ``t`` (n,) with each sample's input ``inputs`` (n, nu), as the shooting intervals do;
    the other states held at ``held`` (n - 1, nx: sample j's values over the step from t[j]).
    Returns (n, len(states)), ``x0`` first; not checked for finiteness. One ``mapaccum``, no
    Python loop over samples: how an effect's own states (a motor lag's effective speeds)
    get node guesses that follow the logged inputs, where inputs held over a whole interval
    missed them by the inputs' change."""
    h = np.diff(t)
    step = rk4_step(model, substeps(np.maximum(h, 1e-6)))
    Sym = ca.SX if step.is_a("SXFunction") else ca.MX     # a branched step is an MX graph
    xa = Sym.sym("xa", len(states))
    xo = Sym.sym("xo", model.nx)
    u = Sym.sym("u", model.nu)
    pp = Sym.sym("p", model.n_params)
    ts = Sym.sym("t")
    hs = Sym.sym("h")
    x = Sym(xo)
    for i, c in enumerate(states):
        x[c] = xa[i]
    f = ca.Function("states_along", [xa, xo, u, pp, ts, hs], [step(x, u, pp, ts, hs)[states]])
    n = len(t) - 1
    seq = np.asarray(f.mapaccum("states_along_acc", n)(
        np.asarray(x0, dtype=float), held.T, inputs[:-1].T, np.repeat(np.asarray(p, dtype=float)[:, None], n, axis=1),
        t[None, :-1], h[None, :]))
    return np.vstack([np.asarray(x0, dtype=float)[None, :], seq.T])


def rk4_step_with_output(model: QuadrotorModel, n_sub: "int | Substeps" = 1) -> ca.Function:
    """``F(x, u, p, t, h) -> (x_next, y, x)``: one held-input RK4 interval and the outputs and
    state at its start, the building block of trajectory and prediction maps."""
    step = rk4_step(model, n_sub)
    Sym = ca.SX if step.is_a("SXFunction") else ca.MX
    x = Sym.sym("x", model.nx)
    u = Sym.sym("u", model.nu)
    p = Sym.sym("p", model.n_params)
    t = Sym.sym("t")
    h = Sym.sym("h")
    return ca.Function("rk4_out", [x, u, p, t, h], [step(x, u, p, t, h), model.output(x, u, p, t), x],
                       ["x", "u", "p", "t", "h"], ["x_next", "y", "x_now"])


def _cvodes_step(model: QuadrotorModel, rtol: float, atol: float) -> ca.Function:
    # Normalised time s in [0, 1] so one integrator serves every sample interval length.
    x = ca.SX.sym("x", model.nx)
    u = ca.SX.sym("u", model.nu)
    p = ca.SX.sym("p", model.n_params)
    t0 = ca.SX.sym("t0")
    h = ca.SX.sym("h")
    s = ca.SX.sym("s")
    par = ca.vertcat(u, p, t0, h)
    ode = h * model.rhs(x, u, p, t0 + s * h)
    integ = ca.integrator("cvodes_step", "cvodes", {"x": x, "p": par, "t": s, "ode": ode}, 0.0, 1.0,
                          {"reltol": rtol, "abstol": atol, "max_num_steps": 100000})
    xs, us, ps, ts, hs = (ca.MX.sym(n, k) for n, k in
                          (("x", model.nx), ("u", model.nu), ("p", model.n_params), ("t", 1), ("h", 1)))
    xf = integ(x0=xs, p=ca.vertcat(us, ps, ts, hs))["xf"]
    return ca.Function("cvodes", [xs, us, ps, ts, hs], [xf], ["x", "u", "p", "t", "h"], ["x_next"])


@dataclass
class Simulation:
    """States and outputs at the sample times of a simulation."""

    t: np.ndarray          # (n,)
    states: np.ndarray     # (n, nx)
    outputs: np.ndarray    # (n, ny)
    state_names: list[str]
    output_names: list[str]

    def output(self, name: str) -> np.ndarray:
        return self.outputs[:, self.output_names.index(name)]

    def state(self, name: str) -> np.ndarray:
        return self.states[:, self.state_names.index(name)]


def simulate(model: QuadrotorModel, t: np.ndarray, inputs: np.ndarray, p: np.ndarray | None = None,
             x0: np.ndarray | None = None, method: str = "rk4", max_step: float = 1e-3,
             rtol: float = 1e-10, atol: float = 1e-12) -> Simulation:
    """Simulate ``model`` open loop over sample times ``t`` with inputs held between samples.

    Args:
        t: (n,) strictly increasing sample times.
        inputs: (n, nu) inputs; row k acts on [t_k, t_{k+1}).
        p: flat parameter vector (default: the model's defaults).
        x0: full initial state (``model.nx``) or the 12 base states (default: rest at the
            origin, level; effect states from the first input).
        method: ``"rk4"`` (sub-stepped so no step exceeds ``max_step``) or ``"cvodes"``.

    Returns a :class:`Simulation` (``t``, ``states``, ``outputs`` and their names).

    Example::

        import numpy as np
        from greybox import QuadrotorModel, load_airframe, simulate
        model = QuadrotorModel(load_airframe("greybox/data/airframes/paper.toml"))
        t = np.arange(0.0, 2.0, 0.01)
        w = np.full((t.size, 4), 1.01 * model.hover_speed())    # a little above hover
        sim = simulate(model, t, w)
        sim.output("z")[-1]                                     # climbing: z < 0 (NED)
    """
    t = np.asarray(t, dtype=float).ravel()
    U = np.asarray(inputs, dtype=float)
    if U.ndim != 2 or U.shape != (t.size, model.nu):
        raise GreyboxInputError(f"inputs must be ({t.size}, {model.nu}), got {U.shape}")
    if t.size < 1 or np.any(np.diff(t) <= 0):
        raise GreyboxInputError("sample times must be strictly increasing")
    p = model.default_parameters() if p is None else np.asarray(p, dtype=float)
    if x0 is None or np.size(x0) == 12:
        x0 = model.initial_state(x0, U[0], p)
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (model.nx,):
        raise GreyboxInputError(f"x0 needs {model.nx} values, got {x0.size}")

    if t.size > 2 and method == "rk4" and np.diff(t).max() > 3 * np.median(np.diff(t)):
        # a long step would add a branch to the step function per median step it spans
        # (Substeps): split long steps on a finer grid with the input held, as
        # FlightLog.fill_gaps does, and report the original samples
        step = float(np.median(np.diff(t)))
        n_in = np.maximum(np.ceil(np.diff(t) / step).astype(int), 1)
        keep = np.concatenate([[0], np.cumsum(n_in)])
        t_fine = np.concatenate([t[k] + np.arange(m) * (t[k + 1] - t[k]) / m
                                 for k, m in enumerate(n_in)] + [t[-1:]])
        fine = simulate(model, t_fine, np.repeat(U, np.append(n_in, 1), axis=0), p, x0, method,
                        max_step, rtol, atol)
        return Simulation(t, fine.states[keep], fine.outputs[keep], fine.state_names, fine.output_names)

    n = t.size
    X = np.empty((n, model.nx))
    X[0] = x0
    if n > 1:
        h = np.diff(t)
        if method == "rk4":
            step = rk4_step(model, substeps(h, max_step))
        elif method == "cvodes":
            step = _cvodes_step(model, rtol, atol)
        else:
            raise GreyboxInputError(f"unknown integration method {method!r}: use 'rk4' or 'cvodes'")
        sim = step.mapaccum("sim", n - 1)
        P = np.tile(p[:, None], (1, n - 1))
        try:
            Xn = sim(x0, U[:-1].T, P, t[:-1][None, :], h[None, :])
        except RuntimeError as e:
            raise SolverError(f"integration failed ({method}): {e}") from None
        X[1:] = np.asarray(Xn).T
    Y = np.asarray(model.output.map(n)(X.T, U.T, np.tile(p[:, None], (1, n)), t[None, :])).T
    if not np.all(np.isfinite(X)):
        bad = int(np.argmax(~np.all(np.isfinite(X), axis=1)))
        raise SolverError(f"simulation diverged (non-finite state) at t = {t[bad]:.4f} s")
    return Simulation(t, X, Y, model.state_names, list(model.output_names))

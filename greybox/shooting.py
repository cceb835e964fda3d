"""The multiple-shooting problem of a fit, apart from any solver.

The problem: find the free parameters ``theta`` and the states ``s_j`` at shooting nodes
(every ``interval`` samples) that minimise the weighted measurement residuals at every
measured sample of every channel, subject to continuity: integrating the model (RK4, input
held) from ``s_j`` over interval j must land on ``s_{j+1}``.

This module holds what describes that problem: the CasADi interval functions
(:class:`ShootingProblem`, compiled to C when that pays and cached by
:mod:`greybox.codegen`), the flights
laid out as padded intervals (:class:`ShootingData`), state guesses from the measurements
(:func:`initial_node_states`), channel noise estimates and the parameters' bounds. The
solvers live in :mod:`greybox.fitting`; :mod:`greybox.validation` uses the problem's
functions for predictions.
"""
from __future__ import annotations

import hashlib
import math
import time
import weakref
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import casadi as ca
import numpy as np
from scipy.signal import savgol_filter

from . import codegen
from .data import FlightLog, inside_gaps, median_row_interval, unwrap_heading
from .errors import GreyboxInputError
from .integrate import Substeps, integrate_states_along, parallel_map, rk4_step
from .model import OUTPUTS, QuadrotorModel
from .rotations import body_rates_from_euler_rates, euler_rate_matrices

__all__ = ["attitude_gyro_disagreement",
           "ShootingProblem", "MappedPair", "BufferedFunction", "ShootingData", "layout", "initial_node_states",
           "estimate_noise", "difference_noise", "robust_std", "noise_levels", "NOISE_FLOOR", "sensor_noise", "channel_noise", "filtered_attitude_error",
           "filtered_attitude_levels", "filtered_attitude_channels", "free_indices", "parameter_bounds",
           "DEFAULT_INTERVAL_S", "default_interval"]

DEFAULT_INTERVAL_S = 0.05
"""Default shooting interval in seconds: 50 samples at 1 kHz, chosen by
``experiments/bench_fit.py``; at other rates the nearest whole number of samples."""


def default_interval(logs: "Sequence[FlightLog]") -> int:
    """Samples per shooting interval closest to :data:`DEFAULT_INTERVAL_S`."""
    return max(1, int(round(DEFAULT_INTERVAL_S / median_row_interval(logs))))

PSI = OUTPUTS.index("psi")
BACKGROUND_BUILD_AT = 0.5
"""In ``"auto"`` compile mode, the fraction of a step function's expected build time spent on
CasADi's virtual machine after which it is compiled in the background (the compiler then
shares the cores with the fit for a few seconds, but nothing waits for it)."""

# ------------------------------------------------------------------------------ noise
def robust_std(x: np.ndarray) -> float:
    """Standard deviation of the bulk of ``x`` (finite values) from its median absolute
    deviation: 1.4826 MAD is the std of normal data, and a few wild values do not move it."""
    v = np.asarray(x, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan")
    return 1.4826 * float(np.median(np.abs(v - np.median(v))))


def difference_noise(y: np.ndarray, spacing: int = 1, order: int = 2, min_rows: int = 3) -> float:
    """Noise standard deviation of the measured samples of ``y`` from robust differences of
    ``order`` (2 or 4) between samples ``spacing`` apart: white noise gives its standard
    deviation (``var(y[k+1]-2y[k]+y[k-1]) = 6 s^2``, 70 for the fourth); a low-passed noise
    less, until ``spacing`` spans its correlation; a smooth signal adds least to the fourth.
    Where the robust spread is 0 (a quantised signal's differences, mostly 0), their standard
    deviation; nan with fewer than ``min_rows`` differences."""
    v = y[np.isfinite(y)]
    k = spacing
    n = v.size - order * k
    if n < min_rows:
        return float("nan")
    if order == 2:
        d, scale = v[2 * k:] - 2 * v[k:k + n] + v[:n], math.sqrt(6.0)
    elif order == 4:
        d, scale = v[4 * k:] - 4 * v[3 * k:3 * k + n] + 6 * v[2 * k:2 * k + n] - 4 * v[k:k + n] + v[:n], math.sqrt(70.0)
    else:
        raise ValueError(f"difference_noise: order {order} (2 or 4)")
    s = robust_std(d) / scale
    if s <= 0:
        s = float(np.std(d)) / scale
    return float(s)


def estimate_noise(y: np.ndarray) -> float:
    """Noise standard deviation of a (possibly sparse) channel from robust second
    differences of its measured samples (:func:`difference_noise`; nan with fewer than 5)."""
    return difference_noise(y)


# ------------------------------------------------------------------------------ initial states
def _fill(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    k = np.isfinite(y)
    if k.sum() == 0:
        return np.zeros_like(y)
    if k.sum() == 1:
        return np.full_like(y, y[k][0])
    return np.interp(t, t[k], y[k])


def _smooth(t: np.ndarray, y: np.ndarray, window_s: float, deriv: int = 0) -> np.ndarray:
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    win = int(round(window_s / dt)) | 1
    win = max(5, min(win, (t.size - 1) | 1 if t.size % 2 == 0 else t.size))
    if win > t.size:
        win = t.size if t.size % 2 else t.size - 1
    if win < 5:
        return np.gradient(y, t) if deriv else y.copy()
    return savgol_filter(y, win, 2, deriv=deriv, delta=dt, mode="interp")


def initial_node_states(model: QuadrotorModel, log: FlightLog, idx: np.ndarray,
                        p: np.ndarray | None = None) -> np.ndarray:
    """State guesses at samples ``idx`` from the measurements: positions and angles
    interpolated and smoothed, velocities and (without gyro) body rates from smoothed
    numerical derivatives, effect states from the logged inputs. Returns (len(idx), nx)."""
    t = log.t
    X = np.zeros((t.size, 12))
    for i, name in enumerate(["x", "y", "z"]):
        yi = _fill(t, log.output(name))
        X[:, i] = _smooth(t, yi, 0.1)
        X[:, 6 + i] = _smooth(t, yi, 0.2, deriv=1)
    # the heading unwrapped on its own samples before the rows between them are filled: filled
    # first, a wrap between two samples became a swing through 0 that no unwrap undoes (a blind
    # audit's racer, its attitude at 200 Hz on 500 Hz rows: shooting gaps of 2 pi, its fit
    # uncertified with b 16 orders off)
    psi, _ = unwrap_heading(t, log.output("psi"), log.output("r") if log.measures("r") else None)
    phi, _ = unwrap_heading(t, log.output("phi"), log.output("p") if log.measures("p") else None)   # rolls too
    ang = np.column_stack([_fill(t, phi), _fill(t, log.output("theta")), _fill(t, psi)])
    for i in range(3):
        X[:, 3 + i] = _smooth(t, ang[:, i], 0.03)
    if all(n in log.output_names for n in ("p", "q", "r")) and np.isfinite(log.output("p")).sum() > 5:
        for i, n in enumerate(("p", "q", "r")):
            X[:, 9 + i] = _smooth(t, _fill(t, log.output(n)), 0.03)
    else:
        rates = np.column_stack([_smooth(t, ang[:, i], 0.06, deriv=1) for i in range(3)])
        X[:, 9:12] = body_rates_from_euler_rates(X[:, 3], X[:, 4], rates)
    out = np.zeros((idx.size, model.nx))
    out[:, :12] = X[idx]
    if model.nx > 12:
        for r, k in enumerate(idx):
            out[r] = model.initial_state(out[r, :12], log.inputs[k], p)
        if p is not None and len(t) > 1:
            along = _effect_states_along(model, log, X, p)
            if along is not None:
                out[:, 12:] = along[idx]
    return out


def _effect_states_along(model: QuadrotorModel, log: FlightLog, X: np.ndarray, p: np.ndarray
                         ) -> np.ndarray | None:
    """The effects' own states integrated over the whole log with parameters ``p``, the 12
    base states held at their guesses ``X`` (n, 12): a motor lag's effective speeds are then
    the logged commands filtered by its time constant instead of the commands themselves. With
    a 30 ms lag in aggressive manoeuvres the commands as node guesses opened shooting gaps of
    10^3 noise levels, and a fit started at the true parameters left for a basin with every
    drag on its bound. None when the integration does not stay finite (an effect whose own
    states are unstable without the rest of the model)."""
    held = np.zeros((len(log.t) - 1, model.nx))
    held[:, :12] = X[:-1]
    x0 = model.initial_state(X[0], log.inputs[0], p)[12:]
    with np.errstate(all="ignore"):
        traj = integrate_states_along(model, log.t, log.inputs, list(range(12, model.nx)), x0, held, p)
    return traj if np.all(np.isfinite(traj)) and np.abs(traj).max() < 1e12 else None


_STEP_FUNCTIONS: "OrderedDict[str, dict[str, ca.Function]]" = OrderedDict()
"""Step functions by model structure, free set and sub-steps, the most recently used up to
:data:`STEP_FUNCTIONS_KEPT` instructions. A diagnosis round builds some seventy problems of
a few dozen structures (the screening's, each refit's solves, every prediction's state
estimates, the start-state window's choice), from new model objects of the same effects;
building a step function (two symbolic Jacobians) and hashing it for its compile-cache name
cost more than a small fit spends evaluating it."""
_STEP_SIZES: dict[str, int] = {}      # key -> instructions of its step functions (counted once)
STEP_FUNCTIONS_KEPT = 4_000_000
"""Instructions of the step functions kept (about 75 bytes each: some 300 MB), most of a
diagnosis round's structures (a Crazyflie round: about 5 million)."""
_structure: "weakref.WeakKeyDictionary[QuadrotorModel, str]" = weakref.WeakKeyDictionary()


def _structure_key(model: QuadrotorModel) -> str:
    """What determines a model's step functions: its dynamics and output map, serialised
    (a few ms; the step functions' own serialisation runs to megabytes)."""
    if model not in _structure:
        text = model.rhs.serialize() + model.output.serialize()
        _structure[model] = hashlib.sha1(text.encode()).hexdigest()
    return _structure[model]


class ShootingProblem:
    """CasADi functions for the interval blocks of a given model, free set and interval.

    The per-sample step functions (small) run compiled to C or on CasADi's virtual machine;
    the fold over an interval's samples and the map over intervals stay CasADi constructs
    around them. ``compile_mode``:

    - ``"auto"``: a library from the compile cache if there is one; otherwise the virtual
      machine, until the time spent evaluating it there (by every problem of the same
      structure, in this process and earlier runs: :func:`greybox.codegen.add_vm_seconds`)
      reaches half the compiler's expected time for it; then it is compiled (``-O1``) in the
      background while the virtual machine goes on, and the library is used from when it
      is ready. A job that evaluates a function a few times mostly stays below that, but
      one evaluation of a large function can pass it: a diagnosis' screening therefore runs
      ``"cached"`` (below), and the diagnosis queues the builds of the refits it knows are
      coming (:func:`greybox.codegen.queue_builds`). None ever waits for a build: a refit that ends
      before its library is ready has it ready in the cache for the next fit of that
      structure. A broken file under the cache name is removed (with a warning) and rebuilt.
    - ``"cached"``: a library from the compile cache if there is one, else the virtual
      machine; never starts the compiler: for one-off evaluations (a diagnosis' screening,
      whose model of every candidate at once is new each round and several times a refit's
      model in size: its own build took the compiler 25 s on a real flight, for nothing).
    - ``"always"``: compile at once (``-O1``); ``"quick"``: at once, unoptimised (``-O0``);
    - ``"never"``: the virtual machine only.
    """

    @staticmethod
    def step_functions(model: QuadrotorModel, free_idx: list[int], n_sub: "int | Substeps"
                       ) -> tuple[ca.Function, ca.Function]:
        """Per-sample Gauss-Newton step functions: (blocks, value).

        The blocks function is an MX graph of two SX functions: one RK4 sub-step that carries
        the sensitivity ``S = d x / d (x0, theta)`` along (called ``n_sub`` times), and the
        sample's weighted residuals with their Jacobian added into ``J'J``, ``J'e`` and the
        squared residuals. Unrolled into one SX expression, the sub-steps' Jacobians were
        multiplied out: at a Crazyflie's four sub-steps the same numbers took three times the
        instructions, and a diagnosis with an empty compile cache spent most of its time in
        the C compiler."""
        nx, nu, ny, npar = model.nx, model.nu, model.ny, model.n_params
        nth = len(free_idx)
        nz = nx + nth
        # the blocks' inputs in their order, declared once: SX for the per-sample pieces, MX
        # for the graph that calls them
        shapes = {"x": (nx, 1), "S": (nx, nz), "H": (nz, nz), "g": (nz, 1), "c": (ny, 1), "u": (nu, 1),
                  "t": (1, 1), "h": (1, 1), "ym": (ny, 1), "w": (ny, 1),
                  "th": (nth, 1),            # scaled free parameters
                  "scale": (nth, 1), "pfix": (npar, 1)}
        x, S, H, g, c, u, t, h, ym, w, th, sc, pfix = (ca.SX.sym(k, *v) for k, v in shapes.items())
        inputs = [ca.MX.sym(k, *v) for k, v in shapes.items()]
        X, Sm, Hm, gm, C, U, T, Hs, Ym, Wm, Th, Sc, Pf = inputs
        p = ca.SX(pfix)
        for i, k in enumerate(free_idx):
            p[k] = th[i] * sc[i]

        def sensitivity(f: ca.SX) -> ca.SX:
            # d f / d (x0, theta) = d f / d x  S  +  d f / d theta  [0 I]
            return ca.jacobian(f, x) @ S + ca.horzcat(ca.SX(f.numel(), nx), ca.jacobian(f, th))

        xn = rk4_step(model, 1)(x, u, p, t, h)
        substep = ca.Function("gb_substep", [x, S, u, t, h, th, sc, pfix], [xn, sensitivity(xn)])
        y = model.output(x, u, p, t)
        d = ym - y
        d[PSI] = ca.atan2(ca.sin(d[PSI]), ca.cos(d[PSI]))  # yaw residual wrapped to (-pi, pi]
        e = w * d
        Je = sensitivity(e)
        # J'J is symmetric: each entry once (half the instructions of Je.T @ Je, and of its
        # run time, which is a good part of the whole at one sub-step)
        JJ = ca.SX(nz, nz)
        for i in range(nz):
            for j in range(i, nz):
                JJ[i, j] = JJ[j, i] = ca.dot(Je[:, i], Je[:, j])
        accumulate = ca.Function("gb_sample_accumulate", [x, S, H, g, c, u, t, th, sc, pfix, ym, w],
                                 [H + JJ, g + Je.T @ e, c + e * e])

        plan = n_sub if isinstance(n_sub, Substeps) else Substeps(n_sub, n_sub)

        def substeps_over(k: int) -> list:
            # k * plan.n sub-steps over the sample's step Hs
            dt = Hs / (k * plan.n)
            xk, Sk, tk = X, Sm, T
            for _ in range(k * plan.n):
                xk, Sk = substep(xk, Sk, U, tk, dt, Th, Sc, Pf)
                tk = tk + dt
            return [xk, Sk]

        if plan.branches == 1:
            xk, Sk = substeps_over(1)
        else:
            # a long step (a dropped row) takes more sub-steps; only its branch runs
            cases = [ca.Function(f"gb_substeps_x{k}", inputs, substeps_over(k))
                     for k in range(1, plan.branches + 1)]
            xk, Sk = ca.Function.conditional("gb_substeps", cases[:-1], cases[-1])(plan.branch(Hs), *inputs)
        Hn, gn, Cn = accumulate(X, Sm, Hm, gm, C, U, T, Th, Sc, Pf, Ym, Wm)
        step_blk = ca.Function("gb_step_blocks", inputs, [xk, Sk, Hn, gn, Cn])
        step = rk4_step(model, plan)
        if step.is_a("SXFunction"):
            step_val = ca.Function("gb_step_value", [x, c, u, t, h, ym, w, th, sc, pfix],
                                   [step(x, u, p, t, h), c + e * e])
        else:       # a branched step is an MX graph: the residuals' SX part called beside it
            vin = [x, c, u, t, h, ym, w, th, sc, pfix]
            cost = ca.Function("gb_sample_cost", vin, [c + e * e])
            mins = [ca.MX.sym(f"v{i}", v.sparsity()) for i, v in enumerate(vin)]
            Mx, Mc, Mu, Mt, Mh, Mym, Mw, Mth, Msc, Mpf = mins
            Mp = ca.Function("gb_params", [th, sc, pfix], [p])(Mth, Msc, Mpf)
            step_val = ca.Function("gb_step_value", mins, [step(Mx, Mu, Mp, Mt, Mh), cost(*mins)])
        return step_blk, step_val

    @classmethod
    def shared_step_functions(cls, model: QuadrotorModel, free_idx: list[int], n_sub: "int | Substeps"
                              ) -> dict[str, ca.Function]:
        """The step functions of a structure, ``{"blocks": ..., "value": ...}``
        (:meth:`step_functions`), built once in a process and kept while they are among the
        most recently used (:data:`STEP_FUNCTIONS_KEPT` instructions in all): every problem of
        the structure and the diagnosis' builds queued ahead of its refits share them (the
        same function objects: each is built, and serialised for its cache name, once)."""
        plan = n_sub if isinstance(n_sub, Substeps) else Substeps(n_sub, n_sub)
        key = f"{_structure_key(model)} {tuple(free_idx)} {plan.n} {plan.n_max} {plan.max_step}"
        if key not in _STEP_FUNCTIONS:
            step_blk, step_val = cls.step_functions(model, free_idx, n_sub)
            _STEP_FUNCTIONS[key] = {"blocks": step_blk, "value": step_val}
            _STEP_SIZES[key] = codegen.code_size(step_blk) + codegen.code_size(step_val)
            while len(_STEP_FUNCTIONS) > 1 and sum(_STEP_SIZES.values()) > STEP_FUNCTIONS_KEPT:
                del _STEP_SIZES[_STEP_FUNCTIONS.popitem(last=False)[0]]
        _STEP_FUNCTIONS.move_to_end(key)
        return dict(_STEP_FUNCTIONS[key])

    def __init__(self, model: QuadrotorModel, free_idx: list[int], N: int, n_sub: "int | Substeps",
                 compile_mode: str):
        if compile_mode not in ("auto", "cached", "always", "quick", "never"):
            raise GreyboxInputError(f"compile must be 'auto', 'cached', 'always', 'quick' or 'never', "
                                    f"not {compile_mode!r}")
        self.model, self.free_idx, self.N = model, free_idx, N
        nx, nu, ny, npar = model.nx, model.nu, model.ny, model.n_params
        nth = len(free_idx)
        nz = nx + nth
        self.nx, self.nth, self.nz, self.ny = nx, nth, nz, ny
        self.compile_mode = compile_mode
        self._opt = "-O0" if compile_mode == "quick" else "-O1"
        self._symbolic = self.shared_step_functions(model, free_idx, n_sub)
        self._step: dict[str, ca.Function] = {}
        self._how: dict[str, str] = {}
        self._lib: dict[str, Path] = {}       # kind -> its library path in the compile cache
        self._build: dict[str, codegen.Build] = {}   # kind -> its library being compiled
        self.version = 0            # bumped when a step function is swapped for its compiled twin
        self._interval: dict[str, ca.Function] = {}
        self._maps: dict[int, "MappedPair"] = {}

        xs = ca.MX.sym("s", nx)
        ths = ca.MX.sym("th", nth)
        scs = ca.MX.sym("scale", nth)
        pf = ca.MX.sym("pfix", npar)
        U = ca.MX.sym("U", nu, N)
        T = ca.MX.sym("T", 1, N)
        Hs = ca.MX.sym("h", 1, N)
        Y = ca.MX.sym("Y", ny, N)
        W = ca.MX.sym("W", ny, N)
        self._ins = [xs, ths, scs, pf, U, T, Hs, Y, W]
        self._const = [ca.repmat(ths, 1, N), ca.repmat(scs, 1, N), ca.repmat(pf, 1, N)]
        # the blocks now (the fit needs them first); the line-search function when first used
        self._choose("blocks")

    @property
    def how(self) -> str:
        """How the blocks run: "compiled", "cached" or "virtual machine"."""
        return self._how["blocks"]

    @property
    def compiles_when_it_pays(self) -> bool:
        """Whether the blocks run on the virtual machine for now and compile once that pays."""
        return "blocks" in self._lib

    def _choose(self, kind: str) -> None:
        f = self._symbolic[kind]
        how = "virtual machine"
        if self.compile_mode in ("always", "quick"):
            f, how = codegen.compiled(f, opt=self._opt)
        elif self.compile_mode in ("auto", "cached") and codegen.compiler_available():
            lib = codegen.library_path(f, self._opt)
            if self.compile_mode == "auto":
                self._lib[kind] = lib       # built once the virtual machine has cost enough
            g = codegen.cached(f, opt=self._opt, lib=lib)
            if g is not None:
                f, how = g, "cached"
        self._step[kind], self._how[kind] = f, how

    def account(self, kind: str, seconds: float) -> None:
        """Record ``seconds`` spent evaluating ``kind`` ("blocks" or "value"); in ``"auto"``
        mode, start compiling its step function in the background once the virtual machine
        has cost :data:`BACKGROUND_BUILD_AT` of what the compiler is expected to, and swap
        the library in when it is ready."""
        if self.compile_mode in ("auto", "cached"):
            codegen.poll_builds()           # queued builds of work to come move on too
        if kind not in self._lib or self._how.get(kind) != "virtual machine":
            return
        build = self._build.get(kind) or codegen.running_build(self._lib[kind])
        f = self._symbolic[kind]
        if build is None and self._lib[kind].exists():
            # built meanwhile (queued for this work, or by another process)
            g = codegen.cached(f, opt=self._opt, lib=self._lib[kind])
            if g is not None:
                self._swap(kind, g, "cached")
                return
            codegen.discard_broken(self._lib[kind])     # rebuilt below, in its turn
        if build is None:
            spent = codegen.add_vm_seconds(self._lib[kind], seconds)
            if spent < BACKGROUND_BUILD_AT * codegen.expected_build_seconds(f, self._opt):
                return
            build = codegen.start_build(f, opt=self._opt, lib=self._lib[kind])
            if build is None:               # no compiler, or no cache to write: decided
                del self._lib[kind]
                return
        else:
            codegen.add_vm_seconds(self._lib[kind], seconds)
        self._build[kind] = build
        got = build.result()
        if got is None:
            return                          # still compiling: go on on the virtual machine
        self._swap(kind, *got)

    def _swap(self, kind: str, g: ca.Function, how: str) -> None:
        """Decided: run ``kind`` as ``g`` (compiled or cached), or on the virtual machine for
        good when the compiler failed."""
        self._how[kind] = how
        self._lib.pop(kind, None)
        self._build.pop(kind, None)
        if how != "virtual machine":
            self._step[kind] = g
            self._interval.pop(kind, None)
            self.version += 1

    def interval_function(self, kind: str) -> ca.Function:
        """The function of one interval: the fold of the step over its ``N`` samples."""
        if kind not in self._interval:
            if kind not in self._step:
                self._choose(kind)
            step = self._step[kind]
            nz, ny = self.nz, self.ny
            xs, U, T, Hs, Y, W = (self._ins[i] for i in (0, 4, 5, 6, 7, 8))
            if kind == "blocks":
                acc = step.mapaccum("acc", self.N, [0, 1, 2, 3, 4], [0, 1, 2, 3, 4])
                S0 = ca.horzcat(ca.MX.eye(self.nx), ca.MX.zeros(self.nx, self.nth))
                r = acc(xs, S0, ca.MX.zeros(nz, nz), ca.MX.zeros(nz, 1), ca.MX.zeros(ny, 1),
                        U, T, Hs, Y, W, *self._const)
                outs = [r[0][:, -1], r[1][:, -nz:], r[2][:, -nz:], r[3][:, -1], r[4][:, -1]]
                name = "gb_interval_blocks"
            else:
                acc = step.mapaccum("accv", self.N, [0, 1], [0, 1])
                r = acc(xs, ca.MX.zeros(ny, 1), U, T, Hs, Y, W, *self._const)
                outs = [r[0][:, -1], r[1][:, -1]]
                name = "gb_interval_value"
            self._interval[kind] = ca.Function(name, self._ins, outs)
        return self._interval[kind]

    @property
    def blocks(self) -> ca.Function:
        """Interval function: (end state, its sensitivity, J'J, J'e, squared residuals)."""
        return self.interval_function("blocks")

    @property
    def value(self) -> ca.Function:
        """Interval function: (end state, squared residuals)."""
        return self.interval_function("value")

    def mapped(self, M: int) -> "MappedPair":
        if M not in self._maps:
            self._maps[M] = MappedPair(self, M)
        return self._maps[M]


class BufferedFunction:
    """A CasADi function called on numpy arrays through its :meth:`casadi.Function.buffer`:
    the arguments are read and the results written in place, column-major, with no
    conversion to and from ``DM`` (for the interval blocks of a fit, converting the results
    cost a third as much as computing them). Returns a list of Fortran-ordered arrays of the
    outputs' shapes. Arguments of another shape than the inputs' go through an ordinary
    call, which checks them."""

    def __init__(self, f: ca.Function):
        self.f = f
        self.shape_in = [f.size_in(i) for i in range(f.n_in())]
        self.shape_out = [f.size_out(i) for i in range(f.n_out())]
        self.dense = all(f.sparsity_in(i).is_dense() for i in range(f.n_in())) and \
            all(f.sparsity_out(i).is_dense() for i in range(f.n_out()))

    @staticmethod
    def _column_major(a: np.ndarray, shape: tuple[int, int]) -> np.ndarray | None:
        """``a``'s entries in column-major order for an input of ``shape``, or None if it
        does not fit. A column given for a mapped input of several columns is repeated, as
        CasADi's own call does (the parameters, the same for every interval)."""
        rows, cols = shape
        if a.ndim == 2 and a.shape == shape:
            return np.asfortranarray(a).ravel(order="F")
        if a.ndim <= 1 and a.size == rows * cols and (rows == 1 or cols == 1):
            return np.ascontiguousarray(a).ravel()
        if a.size == rows and cols > 1 and (a.ndim == 1 or a.shape == (rows, 1)):
            return np.tile(a.ravel(), cols)
        return None

    def __call__(self, *args) -> list[np.ndarray]:
        flat_in = [self._column_major(np.asarray(a, dtype=float), s) for a, s in zip(args, self.shape_in)] \
            if self.dense and len(args) == len(self.shape_in) else None
        if flat_in is None or any(a is None for a in flat_in):
            return [np.asarray(r) for r in self.f(*args)]
        # a buffer per call: it holds the function's work memory (for the interval blocks of
        # a long flight, the folds' intermediate results: ~100 MB), which a kept one would
        # hold for good, beside the line search's
        buf, run = self.f.buffer()
        # flat_in holds the arguments (copies or views) alive until the call returns
        flat_out = [np.empty(r * c) for r, c in self.shape_out]
        for i, a in enumerate(flat_in):
            buf.set_arg(i, memoryview(a))
        for i, r in enumerate(flat_out):
            buf.set_res(i, memoryview(r))
        run()
        if buf.ret() != 0:
            return [np.asarray(r) for r in self.f(*args)]     # CasADi's own error
        return [r.reshape(s, order="F") for r, s in zip(flat_out, self.shape_out)]


class MappedPair:
    """The interval functions mapped over M intervals, called like functions
    (``pair.blocks(*args)``); each call's time is reported to the problem, which may swap
    in compiled code (then the maps are rebuilt)."""

    def __init__(self, prob: ShootingProblem, M: int):
        self.prob, self.M = prob, M
        self._fun: dict[str, tuple[int, BufferedFunction]] = {}

    def _function(self, kind: str) -> "BufferedFunction":
        version, f = self._fun.get(kind, (-1, None))
        if version != self.prob.version:
            f = BufferedFunction(parallel_map(self.prob.interval_function(kind), self.M))
            self._fun[kind] = (self.prob.version, f)
        return f

    def _call(self, kind: str, args) -> list:
        f = self._function(kind)
        t0 = time.perf_counter()
        out = f(*args)
        self.prob.account(kind, time.perf_counter() - t0)
        return out

    def blocks(self, *args) -> list:
        return self._call("blocks", args)

    def value(self, *args) -> list:
        return self._call("value", args)


@dataclass
class ShootingData:
    """One or several flights laid out as padded intervals."""

    U: np.ndarray      # (nu, M*N)
    T: np.ndarray
    Hs: np.ndarray
    Y: np.ndarray      # (ny, M*N), NaN -> 0
    W: np.ndarray      # (ny, M*N) weights (1/sigma, 0 where missing)
    mask: np.ndarray   # (ny, M*N) measured
    flights: list[tuple[int, int]]   # per flight: first interval, number of intervals
    node_index: list[np.ndarray]


def layout(model: QuadrotorModel, logs: Sequence[FlightLog], N: int, sigma: np.ndarray) -> ShootingData:
    Us, Ts, Hs, Ys, flights, node_index = [], [], [], [], [], []
    j0 = 0
    for log in logs:
        n = len(log)
        M = math.ceil(n / N)
        pad = M * N - n
        h = np.append(np.diff(log.t), 0.0)
        Y = np.full((n, model.ny), np.nan)
        for c, name in enumerate(OUTPUTS):
            if name in log.output_names:
                Y[:, c] = log.output(name)
        Us.append(np.vstack([log.inputs, np.repeat(log.inputs[-1:], pad, 0)]))
        Ts.append(np.append(log.t, np.full(pad, log.t[-1])))
        Hs.append(np.append(h, np.zeros(pad)))
        Ys.append(np.vstack([Y, np.full((pad, model.ny), np.nan)]))
        flights.append((j0, M))
        node_index.append(np.minimum(np.arange(M + 1) * N, n - 1))
        j0 += M
    Y = np.vstack(Ys).T
    mask = np.isfinite(Y)
    W = np.where(mask, 1.0 / sigma[:, None], 0.0)
    return ShootingData(np.vstack(Us).T, np.concatenate(Ts)[None, :], np.concatenate(Hs)[None, :],
                 np.where(mask, Y, 0.0), W, mask, flights, node_index)


def free_indices(model: QuadrotorModel, free: Iterable[str] | None,
                  fixed: Iterable[str] | None) -> list[int]:
    names = model.param_names

    def expand(items):
        out = []
        for it in items:
            if it in names:
                out.append(it)
                continue
            par = next((p for p in model.parameters if p.name == it), None)
            if par is None:
                raise GreyboxInputError(f"unknown parameter {it!r}; the model's parameters are "
                                        f"{', '.join(p.name for p in model.parameters)}")
            out += par.component_names
        return out

    if free is not None:
        chosen = set(expand(free))
    else:
        chosen = {n for p in model.parameters if p.free for n in p.component_names}
    chosen -= set(expand(fixed or []))
    if not chosen:
        raise GreyboxInputError("no free parameters to fit")
    return [i for i, n in enumerate(names) if n in chosen]


def parameter_bounds(model: QuadrotorModel) -> tuple[np.ndarray, np.ndarray]:
    """Every parameter component's bounds for the solver; a bound the value must stay strictly
    above (``Parameter.lower_exclusive``: ``K_T > 0``) is lifted by a millionth of the
    parameter's scale, so that a fit held there leaves a value every later division can take
    (rotor columns in another order drove K_T to exactly 0: b/K_T and the thrust's balance then
    raised ZeroDivisionError)."""
    lo, hi = [], []
    for p in model.parameters:
        lower = p.lower + 1e-6 * abs(p.scale) if p.lower_exclusive else p.lower
        lo += [lower] * p.size
        hi += [p.upper] * p.size
    return np.array(lo), np.array(hi)


NOISE_FLOOR = np.array([{"x": 1e-4, "y": 1e-4, "z": 1e-4, "phi": 1e-4, "theta": 1e-4, "psi": 1e-4,
                         "p": 1e-3, "q": 1e-3, "r": 1e-3, "ax": 1e-3, "ay": 1e-3, "az": 1e-3}[n] for n in OUTPUTS])
"""Per output channel (``OUTPUTS`` order), the resolution below which no sensor reports: the
floor of a noise estimated from the measurements (0.1 mm, 0.1 mrad, 1 mrad/s, 1 mm/s^2)."""


FILTERED_ATTITUDE_HF = 2.0
"""An attitude channel whose high-frequency noise is at most this multiple of its floor (0.2
mrad) is an estimate propagated from the gyro (an autopilot's filter: a motion-capture or
vision attitude shows more from sample to sample): its error is slow, and its high-frequency
content does not show it (:func:`filtered_attitude_error`)."""
FILTERED_ATTITUDE_RATIO = 3.0
"""... and whose disagreement with the gyro (:func:`filtered_attitude_error`) is beyond this
multiple of that noise is weighed by that disagreement instead."""
KINEMATIC_WINDOWS = (0.5, 1.0, 2.0)
"""s: the spans over which :func:`filtered_attitude_error` compares the attitude's change
with the gyro's integral (the largest error found is kept; spans beyond a quarter of the
flight are left out)."""


def filtered_attitude_error(log: FlightLog) -> dict[str, float]:
    """Per attitude channel (phi, theta, psi), the RMS of the attitude's own slow error that
    its disagreement with the gyro shows: over spans of :data:`KINEMATIC_WINDOWS` the
    measured angle's change less the integral of the gyro's Euler-angle rates,
    ``d/dt (phi, theta, psi) = W(phi, theta) (p, q, r)``, less what a constant gyro bias
    gives through ``W`` (fitted), its variance less the gyro noise's integral over the span,
    halved (two ends), the largest. Model-free, from the log alone: for white attitude noise
    it is that noise, for an estimator's error correlated over seconds it is that error (a
    blind audit's complementary filter: 21.8 and 14.2 mrad by this, 21.7 and 14.6 by its
    truth, 0.12 and 0.07 mrad by the high-frequency content). Empty without a gyro or roll
    and pitch."""
    t = log.t
    names = log.output_names
    if not all(ch in names for ch in ("phi", "theta", "p", "q", "r")) or t.size < 20:
        return {}
    G = np.column_stack([log.output(ch) for ch in ("p", "q", "r")])
    E = np.column_stack([log.output(ch) if ch in names else np.full(t.size, np.nan) for ch in ("phi", "theta", "psi")])
    gk, ek = np.isfinite(G).all(axis=1), np.isfinite(E[:, :2]).all(axis=1)
    if gk.sum() < 20 or ek.sum() < 20:
        return {}
    Gf = np.column_stack([np.interp(t, t[gk], g[gk]) for g in G.T])
    Ef = np.column_stack([np.interp(t, t[ek], e[ek]) for e in E[:, :2].T])
    # the Euler-rate map W (n, 3 angles, 3 body axes) and its running integral, whose product
    # with a constant gyro bias is what the bias adds to each angle's change
    Wm = euler_rate_matrices(Ef[:, 0], Ef[:, 1])
    dots = np.einsum("nab,nb->na", Wm, Gf)
    half_dt = 0.5 * np.diff(t)
    integral = np.concatenate([np.zeros((1, 3)), np.cumsum((dots[1:] + dots[:-1]) * half_dt[:, None], axis=0)])
    Wint = np.concatenate([np.zeros((1, 3, 3)), np.cumsum((Wm[1:] + Wm[:-1]) * half_dt[:, None, None], axis=0)])
    ang = E.copy()
    k = np.isfinite(ang[:, 2])
    if k.any():
        ang[k, 2] = np.unwrap(ang[k, 2])
    gyro_noise = np.array([estimate_noise(g) for g in G.T])
    gyro_noise = np.where(np.isfinite(gyro_noise), gyro_noise, 0.0)
    dt = float(np.median(np.diff(t)))
    best = np.full(3, np.nan)
    gap = np.concatenate([[0], np.cumsum(inside_gaps(t, gk))])    # spans across a gyro gap left out
    for span in KINEMATIC_WINDOWS:
        if span > 0.25 * (t[-1] - t[0]):
            continue
        i = np.arange(t.size)
        j = np.searchsorted(t, t + span)
        ok = j < t.size
        ok[ok] &= gap[j[ok] + 1] == gap[i[ok] + 1]
        i, j = i[ok], j[ok]
        D = (ang[j] - ang[i]) - (integral[j] - integral[i])          # (m, 3)
        A = -(Wint[j] - Wint[i])                                     # (m, 3 angles, 3 bias components)
        rows = np.isfinite(D)
        if rows[:, :2].all(axis=1).sum() < 20:
            continue
        # a constant bias (3) and each angle's mean change (3), least squares over the angles measured
        X = np.zeros((rows.sum(), 6))
        X[:, :3] = A[rows]
        X[np.arange(rows.sum()), 3 + np.nonzero(rows)[1]] = 1.0
        coef, *_ = np.linalg.lstsq(X, D[rows], rcond=None)
        resid = np.full(D.shape, np.nan)
        resid[rows] = D[rows] - X @ coef
        for c in range(3):
            d = resid[:, c][np.isfinite(resid[:, c])]
            if d.size < 20:
                continue
            var = float(np.mean(d ** 2)) - float(np.sum((np.abs(Wm[0, c]) * gyro_noise) ** 2)) * dt * span
            best[c] = np.nanmax([best[c], math.sqrt(max(var, 0.0) / 2.0)])
    return {ch: float(best[c]) for c, ch in enumerate(("phi", "theta", "psi")) if np.isfinite(best[c])}


def filtered_attitude_levels(log: FlightLog) -> dict[str, float]:
    """The attitude channels of ``log`` weighed by their disagreement with the gyro
    (:func:`filtered_attitude_error`), with that level:
    those beyond :data:`FILTERED_ATTITUDE_RATIO` times their high-frequency noise, when the
    channel — or, for roll and pitch, either of the two, which one estimator gives — is an
    estimate propagated from the gyro (noise within :data:`FILTERED_ATTITUDE_HF` of the floor;
    a blind audit's roll at 0.20-0.21 mrad beside a pitch at 0.14 had straddled the line)."""
    hf = {ch: estimate_noise(log.output(ch)) for ch in ("phi", "theta", "psi") if ch in log.output_names}
    floor = {ch: float(NOISE_FLOOR[OUTPUTS.index(ch)]) for ch in hf}
    smooth = {ch for ch, v in hf.items() if np.isfinite(v) and v <= FILTERED_ATTITUDE_HF * floor[ch]}
    if smooth & {"phi", "theta"}:
        smooth |= {"phi", "theta"} & set(hf)
    if not smooth:
        return {}
    kin = filtered_attitude_error(log)
    return {ch: float(kin[ch]) for ch in smooth if ch in kin and np.isfinite(hf[ch])
            and kin[ch] > FILTERED_ATTITUDE_RATIO * max(hf[ch], floor[ch])}


def channel_noise(log: FlightLog, name: str, levels: Mapping[str, float] | None = None) -> float:
    """One log's noise estimate of channel ``name``: its high-frequency content
    (:func:`estimate_noise`), or for an attitude channel filtered from the gyro its
    disagreement with the gyro (:func:`filtered_attitude_levels`; ``levels``: them, computed
    already)."""
    if name in ("phi", "theta", "psi"):
        lv = (filtered_attitude_levels(log) if levels is None else levels).get(name)
        if lv is not None:
            return lv
    return estimate_noise(log.output(name))


def filtered_attitude_channels(logs: Sequence[FlightLog]) -> dict[str, tuple[float, float]]:
    """The attitude channels whose noise :func:`noise_levels` takes from their disagreement with
    the gyro (:func:`filtered_attitude_levels`), with (that, their high-frequency noise),
    medians over the flights that have them."""
    per_log = [filtered_attitude_levels(lg) for lg in logs]
    out: dict[str, tuple[float, float]] = {}
    for name in ("phi", "theta", "psi"):
        pairs = [(lv[name], estimate_noise(lg.output(name))) for lg, lv in zip(logs, per_log) if name in lv]
        if pairs and 2 * len(pairs) > sum(name in lg.output_names for lg in logs):
            out[name] = (float(np.median([a for a, _ in pairs])), float(np.median([b for _, b in pairs])))
    return out


def attitude_gyro_disagreement(logs: Sequence[FlightLog]) -> dict[str, tuple[float, float]]:
    """Roll and pitch weighed by their high-frequency noise (not an estimate propagated from the
    gyro: :func:`filtered_attitude_channels` leaves them) that disagree with the gyro's integral
    (:func:`filtered_attitude_error`) by more than :data:`FILTERED_ATTITUDE_RATIO` times that
    noise: ``{channel: (disagreement, high-frequency noise)}``, medians over the flights, on
    most of them. Either the attitude has a slow error of that size (an onboard estimate with
    noise on it: a blind audit's complementary filter with 1 mrad of noise, 40 and 16 mrad of
    slow error, weighed at 1 mrad, gave a confident wrong verdict) or the gyro's scale or
    timing is off (the NanoBench flights' motion-capture attitude, 6-190 times): the log alone
    cannot tell which, so it is said, not acted on."""
    weighed = filtered_attitude_channels(logs)
    out: dict[str, tuple[float, float]] = {}
    per_log = [filtered_attitude_error(lg) for lg in logs]
    for name in ("phi", "theta"):
        if name in weighed:
            continue
        pairs = [(kin[name], estimate_noise(lg.output(name))) for lg, kin in zip(logs, per_log)
                 if name in kin and name in lg.output_names]
        off = [(k, h) for k, h in pairs if np.isfinite(h) and k > FILTERED_ATTITUDE_RATIO * max(h, 1e-4)]
        if off and 2 * len(off) > len(pairs):
            out[name] = (float(np.median([k for k, _ in off])), float(np.median([h for _, h in off])))
    return out


def noise_levels(logs: Sequence[FlightLog], noise: Mapping[str, float] | None) -> np.ndarray:
    """Per output channel, the noise standard deviation: ``noise``'s where given, else
    estimated from each flight's measurements (:func:`channel_noise`), the median over the
    flights, floored at :data:`NOISE_FLOOR`."""
    sigma = np.ones(len(OUTPUTS))
    given = dict(noise or {})
    levels = [None] * len(logs)
    for c, name in enumerate(OUTPUTS):
        if name in given:
            sigma[c] = float(given[name])
            continue
        vals = []
        for f, lg in enumerate(logs):
            if name not in lg.output_names:
                continue
            if name in ("phi", "theta", "psi") and levels[f] is None:
                levels[f] = filtered_attitude_levels(lg)
            vals.append(channel_noise(lg, name, levels[f]))
        vals = [v for v in vals if np.isfinite(v)]
        sigma[c] = float(np.median(vals)) if vals else 1.0
    return np.maximum(sigma, NOISE_FLOOR)


def sensor_noise(logs: Sequence[FlightLog]) -> np.ndarray:
    """Per output channel, the noise standard deviation estimated from the measurements'
    high-frequency content (:func:`estimate_noise`; an attitude filtered from the gyro by its
    disagreement with the gyro, :func:`channel_noise`), never from model residuals; floored at
    the resolution below which no sensor reports (0.1 mm, 0.1 mrad, 1 mrad/s, 1 mm/s^2)."""
    return noise_levels(logs, None)



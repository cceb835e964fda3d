"""Multiple-shooting least-squares fitting of grey-box parameters.

The problem: find the free parameters ``theta`` and the states ``s_j`` at shooting nodes
(every ``interval`` samples) that minimise the weighted measurement residuals at every
measured sample of every channel, subject to continuity: integrating the model (RK4, input
held) from ``s_j`` over interval j must land on ``s_{j+1}``.

How it is solved (a structure-exploiting constrained Gauss–Newton; README, "How the fit
is solved", says why):

* One CasADi function per interval folds over the interval's samples and returns the
  interval's end state, the Jacobian of that end state with respect to ``z_j = (s_j, theta)``
  and the Gauss–Newton blocks ``H_j = J_j^T J_j``, ``g_j = J_j^T e_j`` of its residuals —
  formed inside the function, so only small blocks ever leave CasADi. It is ``map``-ped over
  all intervals and compiled to C (cached on disk, :mod:`greybox.codegen`).
* The parameters are carried as constant extra states of every node (``theta_j =
  theta_{j+1}``), which keeps the KKT system of each Gauss–Newton step banded; it is solved
  with LAPACK's banded LU (``scipy.linalg.solve_banded``).
* Steps are damped Levenberg–Marquardt style and accepted by a backtracking line search on
  an l1 merit function (cost + weighted continuity gaps).
* Uncertainty: at the solution, the parameter block of the inverse KKT matrix is the
  Gauss–Newton covariance of the constrained problem; it is scaled by the residual variance.
  Channel noise levels are estimated from the data (robust second differences) and
  re-estimated from the residuals after a first solve.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable, Mapping, Sequence

import casadi as ca
import numpy as np
from scipy.linalg import solve_banded
from scipy.signal import savgol_filter

from .codegen import compiled
from .data import FlightLog
from .errors import ConvergenceWarning, GreyboxInputError, SolverError
from .integrate import n_substeps, rk4_step
from .model import OUTPUTS, QuadrotorModel
from .residuals import fitted_trajectory, output_residuals, whiteness_fraction

__all__ = ["fit", "FitResult", "Certificate", "GreyBoxEstimator", "estimate_noise", "sensor_noise", "initial_node_states",
           "DEFAULT_INTERVAL_S", "default_interval", "MANOEUVRE_ADVICE"]

DEFAULT_INTERVAL_S = 0.05
"""Default shooting interval in seconds: 50 samples at 1 kHz, chosen by
``experiments/bench_fit.py``; at other rates the nearest whole number of samples."""


def default_interval(logs: "Sequence[FlightLog]") -> int:
    """Samples per shooting interval closest to :data:`DEFAULT_INTERVAL_S`."""
    dt = float(np.median(np.concatenate([np.diff(l.t) for l in logs])))
    return max(1, int(round(DEFAULT_INTERVAL_S / dt)))

PSI = OUTPUTS.index("psi")

MANOEUVRE_ADVICE = {
    "K_T": "vertical steps (step_z) and climbs at varied thrust",
    "b": "yaw steps (yaw) with large rotor-speed differences",
    "Kd": "fast translations (fast) along each axis, and vertical steps for Kd[2]",
    "J_r": "fast roll/pitch motions with high rotor speeds",
    "Kq": "translations at several different speeds (fast)",
    "k_rd": "horizontal flight at different thrust levels (fast, step_z while moving)",
    "k_ge": "a slow pass close to the ground (ground)",
    "tau_m": "rapid rotor-speed changes (steps, excitation)",
    "r_cog": "hover and attitude steps",
    "K_T_dev": "roll and pitch steps with varied thrust",
    "wind": "horizontal flight in several directions",
    "K_T_drift": "a longer flight, repeating the same manoeuvres early and late",
    "tau_pos": "fast translations (fast)",
    "att_bias": "hover and slow translations",
}


# ------------------------------------------------------------------------------ noise
def estimate_noise(y: np.ndarray) -> float:
    """Noise standard deviation of a (possibly sparse) channel from robust second
    differences of its measured samples: for white noise ``var(y[k+1]-2y[k]+y[k-1]) = 6 s^2``.
    """
    v = y[np.isfinite(y)]
    if v.size < 5:
        return float("nan")
    d2 = v[2:] - 2 * v[1:-1] + v[:-2]
    mad = np.median(np.abs(d2 - np.median(d2)))
    s = 1.4826 * mad / math.sqrt(6.0)
    if s <= 0:
        s = float(np.std(d2)) / math.sqrt(6.0)
    return float(s)


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
    ang = np.column_stack([_fill(t, log.output(n)) for n in ("phi", "theta", "psi")])
    ang[:, 2] = np.unwrap(ang[:, 2])
    for i in range(3):
        X[:, 3 + i] = _smooth(t, ang[:, i], 0.03)
    if all(n in log.output_names for n in ("p", "q", "r")) and np.isfinite(log.output("p")).sum() > 5:
        for i, n in enumerate(("p", "q", "r")):
            X[:, 9 + i] = _smooth(t, _fill(t, log.output(n)), 0.03)
    else:
        rates = np.column_stack([_smooth(t, ang[:, i], 0.06, deriv=1) for i in range(3)])
        ph, th = X[:, 3], X[:, 4]
        # omega = E(phi, theta) * euler_dot, E the inverse of the Euler-rate matrix
        X[:, 9] = rates[:, 0] - np.sin(th) * rates[:, 2]
        X[:, 10] = np.cos(ph) * rates[:, 1] + np.sin(ph) * np.cos(th) * rates[:, 2]
        X[:, 11] = -np.sin(ph) * rates[:, 1] + np.cos(ph) * np.cos(th) * rates[:, 2]
    out = np.zeros((idx.size, model.nx))
    out[:, :12] = X[idx]
    if model.nx > 12:
        for r, k in enumerate(idx):
            out[r] = model.initial_state(out[r, :12], log.inputs[k], p)
    return out


# ------------------------------------------------------------------------------ result
STEP_TOLERANCE = 0.1
"""A fit is at its optimum when one more undamped Gauss-Newton step would move no free
parameter by more than this fraction of its standard deviation, nor any node state by more
than this fraction of its noise scale: further iterations cannot change a conclusion."""
GAP_TOLERANCE = 0.1
"""Largest continuity gap allowed at a certified optimum, as a fraction of the state's noise
scale (output-error fits; with process noise the gaps are residuals)."""
NOISE_RATIO_ADEQUATE = 2.0
"""Residual RMS up to this multiple of the sensor noise (estimated from the measurements'
high-frequency content) counts as "at the noise level" when the residuals are white."""
NOISE_RATIO_COLOURED = math.sqrt(2.0)
"""Coloured residuals are systematic: they count as the model's error once their systematic
part, ``sqrt(rms^2 - noise^2)``, is as large as the noise itself (RMS ratio sqrt(2)). On long
logs a tiny systematic error is already far outside the whiteness band; it is not yet a
failure of the model."""
MAX_RESTARTS = 2
"""Times a fit whose end point is not certified is solved on from there."""
TRUST_REGION = 0.5
"""Largest change of a parameter in one iteration (relative to its scale, the starting value)
in the second strategy, tried from the start when the first ends uncertified."""
WHITENESS_ADEQUATE = 0.2
"""Fraction of autocorrelation lags outside the 99 % band up to which residuals count as white."""


@dataclass
class Certificate:
    """Whether a fit reached the optimum of its own problem (first-order optimality, closed
    shooting gaps), and whether its residuals look like sensor noise.

    The first is what makes test statistics at that fit meaningful (``optimal``); the second
    says whether the model explains the data (``adequate``): an optimal fit of a model that
    misses physics has residuals far above the noise, and coloured.
    """

    optimal: bool
    step_over_std: float                 # largest remaining GN parameter step / its std
    state_step_over_noise: float         # largest remaining GN node-state step / noise scale
    gap_over_noise: float                # largest continuity gap / the state's noise scale
    held: list[str]                      # parameters held on a bound (the step is projected)
    residual_over_noise: dict[str, float]   # per channel: RMS residual / sensor noise of the data
    whiteness: dict[str, float]          # per channel: fraction of lags outside the 99 % band
    sensor_noise: dict[str, float]       # per channel: noise estimated from the measurements
    reasons: list[str] = field(default_factory=list)   # why not optimal, in words

    @property
    def adequate(self) -> bool:
        """No channel's residuals are far above the noise, or coloured and above it."""
        return not self.off_channels()

    def off_channels(self) -> list[str]:
        """Channels whose residuals are far above the noise level, or coloured with a
        systematic part as large as the noise."""
        return [ch for ch, r in self.residual_over_noise.items()
                if r > NOISE_RATIO_ADEQUATE or (r > NOISE_RATIO_COLOURED and
                                                self.whiteness.get(ch, 0.0) > WHITENESS_ADEQUATE)]

    def text(self) -> str:
        """The certificate in words."""
        if self.optimal:
            head = (f"optimum certified: one more Gauss-Newton step would move the parameters by "
                    f"{self.step_over_std:.2g} std at most, the largest gap is {self.gap_over_noise:.2g} of the noise")
        else:
            head = "optimum NOT certified: " + "; ".join(self.reasons)
        if self.held:
            head += f"; held on a bound: {', '.join(self.held)}"
        off = self.off_channels()
        if off:
            tail = ("residuals above the sensor noise in " +
                    ", ".join(f"{ch} ({self.residual_over_noise[ch]:.3g}x noise, "
                              f"{100 * self.whiteness.get(ch, 0.0):.0f} % of lags outside the band)" for ch in off) +
                    ": the model does not explain these channels")
        else:
            tail = "residuals at the sensor noise"
        return f"{head}. {tail}."

    def as_dict(self) -> dict:
        return {"optimal": self.optimal, "adequate": self.adequate, "step_over_std": _finite(self.step_over_std),
                "state_step_over_noise": _finite(self.state_step_over_noise),
                "gap_over_noise": _finite(self.gap_over_noise), "held": list(self.held),
                "residual_over_noise": {k: _finite(v) for k, v in self.residual_over_noise.items()},
                "whiteness": {k: _finite(v) for k, v in self.whiteness.items()},
                "sensor_noise": {k: _finite(v) for k, v in self.sensor_noise.items()},
                "reasons": list(self.reasons), "text": self.text()}


def _finite(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


@dataclass
class FitResult:
    """The outcome of :func:`fit`.

    ``parameters`` holds every model parameter (fitted or fixed) by component name;
    ``std`` and ``correlation`` refer to the free ones (``free_names`` order).

    Example::

        res = fit(model, est)
        res.converged, res.status               # a certified optimum? what is open, in words
        res.parameters["Kd[2]"], res.free_names, res.correlation
        pred = predict(model, res.p, val)       # res.p: the flat parameter vector
    """

    model: QuadrotorModel
    p: np.ndarray                       # full flat parameter vector
    free_names: list[str]
    std: np.ndarray                     # standard deviations of the free parameters
    covariance: np.ndarray
    correlation: np.ndarray
    converged: bool
    status: str
    iterations: int
    cost: float                         # 0.5 * sum of squared weighted residuals
    n_residuals: int
    sigma: dict[str, float]             # channel noise levels used as weights
    residual_rms: dict[str, float]      # RMS residual per channel (units of the channel)
    node_states: list[np.ndarray]       # per flight, (M+1, nx)
    node_index: list[np.ndarray]        # per flight, sample index of each node
    warnings: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    evaluator: str = ""
    interval: int = 50
    channel_cost: dict[str, float] = field(default_factory=dict)   # sum of squared weighted residuals
    channel_count: dict[str, int] = field(default_factory=dict)    # measured samples per channel
    process_noise: dict[str, float] | None = None   # q per state when continuity was soft
    process_cost: float = 0.0           # 0.5 * sum of squared gaps / q^2 (soft continuity)
    certificate: Certificate | None = None   # ``converged`` is ``certificate.optimal``

    @property
    def parameters(self) -> dict[str, dict[str, float | None]]:
        """``{name: {"value": v, "std": s or None (fixed)}}`` for every component."""
        out: dict[str, dict[str, float | None]] = {}
        for name, v in zip(self.model.param_names, self.p):
            s = None
            if name in self.free_names:
                s = float(self.std[self.free_names.index(name)])
            out[name] = {"value": float(v), "std": s}
        return out

    def value(self, name: str) -> float:
        return float(self.p[self.model.param_names.index(name)])

    def summary(self) -> str:
        """A readable table of the fitted parameters."""
        lines = [f"{'parameter':<12} {'value':>13} {'std':>11} {'rel':>7}"]
        for name in self.free_names:
            v, s = self.value(name), float(self.std[self.free_names.index(name)])
            rel = f"{abs(s / v) * 100:6.2f}%" if v != 0 else "     - "
            lines.append(f"{name:<12} {v:13.6g} {s:11.3g} {rel:>7}")
        lines.append(f"status: {self.status}; {self.iterations} iterations; "
                     f"evaluator: {self.evaluator}")
        if self.certificate is not None:
            lines.append(self.certificate.text())
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


# ------------------------------------------------------------------------------ problem
class _ShootingProblem:
    """CasADi functions for the interval blocks of a given model, free set and interval.

    The per-sample step functions (small) are compiled to C and cached; the fold over an
    interval's samples and the map over intervals stay CasADi constructs around them.
    """

    @staticmethod
    def step_functions(model: QuadrotorModel, free_idx: list[int], n_sub: int
                       ) -> tuple[ca.Function, ca.Function, str]:
        """Per-sample Gauss-Newton step functions and the cache key that determines them."""
        nx, nu, ny, npar = model.nx, model.nu, model.ny, model.n_params
        nth = len(free_idx)
        nz = nx + nth
        step = rk4_step(model, n_sub)
        x = ca.SX.sym("x", nx)
        S = ca.SX.sym("S", nx, nz)
        H = ca.SX.sym("H", nz, nz)
        g = ca.SX.sym("g", nz)
        c = ca.SX.sym("c", ny)
        u = ca.SX.sym("u", nu)
        t = ca.SX.sym("t")
        h = ca.SX.sym("h")
        ym = ca.SX.sym("ym", ny)
        w = ca.SX.sym("w", ny)
        th = ca.SX.sym("th", nth)          # scaled free parameters
        sc = ca.SX.sym("scale", nth)
        pfix = ca.SX.sym("pfix", npar)
        p = ca.SX(pfix)
        for i, k in enumerate(free_idx):
            p[k] = th[i] * sc[i]
        y = model.output(x, u, p, t)
        d = ym - y
        d[PSI] = ca.atan2(ca.sin(d[PSI]), ca.cos(d[PSI]))  # yaw residual wrapped to (-pi, pi]
        e = w * d
        xn = step(x, u, p, t, h)
        z = ca.vertcat(x, th)
        E0 = ca.horzcat(ca.SX.zeros(nth, nx), ca.SX.eye(nth))  # d theta / d z
        Jy = ca.jacobian(y, z)
        Jx = ca.jacobian(xn, z)
        Je = -w * (Jy[:, :nx] @ S + Jy[:, nx:] @ E0)   # (ny, nz); w broadcasts over rows
        Sn = Jx[:, :nx] @ S + Jx[:, nx:] @ E0
        step_blk = ca.Function("gb_step_blocks", [x, S, H, g, c, u, t, h, ym, w, th, sc, pfix],
                               [xn, Sn, H + Je.T @ Je, g + Je.T @ e, c + e * e])
        step_val = ca.Function("gb_step_value", [x, c, u, t, h, ym, w, th, sc, pfix], [xn, c + e * e])
        af = model.airframe
        key = repr((af.mass, af.inertia.tolist(), af.rotor_positions.tolist(), af.spins.tolist(),
                    af.gravity, af.ground_z, af.rotor_inertia,
                    af.parameters if model.inputs == "controls" else None,
                    model.effect_names, model.inputs, free_idx, n_sub))
        return step_blk, step_val, key

    def __init__(self, model: QuadrotorModel, free_idx: list[int], N: int, n_sub: int,
                 compile_mode: str):
        self.model, self.free_idx, self.N = model, free_idx, N
        nx, nu, ny, npar = model.nx, model.nu, model.ny, model.n_params
        nth = len(free_idx)
        nz = nx + nth
        self.nx, self.nth, self.nz, self.ny = nx, nth, nz, ny
        step_blk, step_val, key = self.step_functions(model, free_idx, n_sub)
        self.how = "virtual machine"
        if compile_mode != "never":
            # "quick": a faster build, slower code, for functions evaluated once or twice
            opt = "-O0" if compile_mode == "quick" else "-O1"
            step_blk, self.how = compiled(step_blk, key + "blocks", opt)
            # the line-search function compiles when first used (screening never needs it)
            self._value_step = (step_val, key + "value", opt)
        else:
            self._value_step = (step_val, None, None)
        self._N = N

        # fold over the interval's samples; theta, scale and fixed parameters are repeated
        acc_b = step_blk.mapaccum("acc", N, [0, 1, 2, 3, 4], [0, 1, 2, 3, 4])
        xs = ca.MX.sym("s", nx)
        ths = ca.MX.sym("th", nth)
        scs = ca.MX.sym("scale", nth)
        pf = ca.MX.sym("pfix", npar)
        U = ca.MX.sym("U", nu, N)
        T = ca.MX.sym("T", 1, N)
        Hs = ca.MX.sym("h", 1, N)
        Y = ca.MX.sym("Y", ny, N)
        W = ca.MX.sym("W", ny, N)
        const = [ca.repmat(ths, 1, N), ca.repmat(scs, 1, N), ca.repmat(pf, 1, N)]
        S0 = ca.horzcat(ca.MX.eye(nx), ca.MX.zeros(nx, nth))
        r = acc_b(xs, S0, ca.MX.zeros(nz, nz), ca.MX.zeros(nz, 1), ca.MX.zeros(ny, 1), U, T, Hs, Y, W, *const)
        ins = [xs, ths, scs, pf, U, T, Hs, Y, W]
        self.blocks = ca.Function("gb_interval_blocks", ins,
                                  [r[0][:, -1], r[1][:, -nz:], r[2][:, -nz:], r[3][:, -1], r[4][:, -1]])
        self._value_args = (ins, const)
        self._value: ca.Function | None = None
        self._maps: dict[int, "_MappedPair"] = {}

    @property
    def value(self) -> ca.Function:
        if self._value is None:
            step_val, key, opt = self._value_step
            if key is not None:
                step_val, _ = compiled(step_val, key, opt)
            ins, const = self._value_args
            xs, U, T, Hs, Y, W = ins[0], ins[4], ins[5], ins[6], ins[7], ins[8]
            acc_v = step_val.mapaccum("accv", self._N, [0, 1], [0, 1])
            rv = acc_v(xs, ca.MX.zeros(self.ny, 1), U, T, Hs, Y, W, *const)
            self._value = ca.Function("gb_interval_value", ins, [rv[0][:, -1], rv[1][:, -1]])
        return self._value

    def mapped(self, M: int) -> "_MappedPair":
        if M not in self._maps:
            self._maps[M] = _MappedPair(self, M)
        return self._maps[M]


class _MappedPair:
    """The interval functions mapped over M intervals; the value function on first use."""

    def __init__(self, prob: _ShootingProblem, M: int):
        self.prob, self.M = prob, M
        self.blocks = prob.blocks.map(M, "thread", 2)
        self._value = None

    @property
    def value(self) -> ca.Function:
        if self._value is None:
            self._value = self.prob.value.map(self.M, "thread", 2)
        return self._value


@dataclass
class _Data:
    """One or several flights laid out as padded intervals."""

    U: np.ndarray      # (nu, M*N)
    T: np.ndarray
    Hs: np.ndarray
    Y: np.ndarray      # (ny, M*N), NaN -> 0
    W: np.ndarray      # (ny, M*N) weights (1/sigma, 0 where missing)
    mask: np.ndarray   # (ny, M*N) measured
    flights: list[tuple[int, int]]   # per flight: first interval, number of intervals
    node_index: list[np.ndarray]


def _layout(model: QuadrotorModel, logs: Sequence[FlightLog], N: int, sigma: np.ndarray) -> _Data:
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
    return _Data(np.vstack(Us).T, np.concatenate(Ts)[None, :], np.concatenate(Hs)[None, :],
                 np.where(mask, Y, 0.0), W, mask, flights, node_index)


class _KKT:
    """Index pattern of the banded KKT system of all flights' nodes and constraints."""

    def __init__(self, flights: list[tuple[int, int]], nx: int, nth: int):
        nz = nx + nth
        self.nz, self.nx, self.nth = nz, nx, nth
        # variable ordering: per flight z_0, lam_0, z_1, lam_1, ..., z_M, [link lam], next flight
        zoff, loff, link = [], [], []
        pos = 0
        for f, (_, M) in enumerate(flights):
            zf, lf = [], []
            for j in range(M + 1):
                zf.append(pos)
                pos += nz
                if j < M:
                    lf.append(pos)
                    pos += nz
            if f < len(flights) - 1:
                link.append(pos)
                pos += nth
            zoff.append(np.array(zf))
            loff.append(np.array(lf))
        self.n = pos
        self.zoff, self.loff, self.link = zoff, loff, link
        self.znodes = np.concatenate(zoff)           # offsets of all nodes, flight by flight
        self.lams = np.concatenate(loff)              # offsets of interval multipliers
        # interval j (global) connects node zi[j] -> zi[j] + 1 (index into znodes)
        zi, k = [], 0
        for f, (_, M) in enumerate(flights):
            zi += list(range(k, k + M))
            k += M + 1
        self.zi = np.array(zi)
        self.bw = 2 * nz

    def solve(self, H: np.ndarray, g: np.ndarray, G: np.ndarray, c: np.ndarray, mu: float,
              rhs_extra: np.ndarray | None = None, q2: np.ndarray | None = None) -> np.ndarray:
        """Solve the KKT system. H: (n_nodes, nz, nz) (zero for nodes without data),
        g: (n_nodes, nz), G: (n_int, nz, nz) interval constraint Jacobians, c: (n_int, nz)
        gaps. ``q2`` (nz,): process-noise variances of soft continuity rows (0 = hard):
        the penalty ``|gap|^2/(2 q^2)`` puts ``-q^2`` on the multiplier diagonal, which keeps
        the band. Returns the solution vector (or matrix for ``rhs_extra``)."""
        nz, nth, nx = self.nz, self.nth, self.nx
        l = u = self.bw
        ab = np.zeros((l + u + 1, self.n))
        ar = np.arange(nz)

        def put(r0, c0, blk):  # blk: (k, a, b); r0, c0: (k,)
            a, b = blk.shape[1:]
            rows = r0[:, None, None] + np.arange(a)[None, :, None]
            cols = c0[:, None, None] + np.arange(b)[None, None, :]
            ab[u + rows - cols, cols] = blk

        d = np.einsum("kii->ki", H)
        floor = 1e-10 * max(float(d.max()), 1.0)
        Hd = H.copy()
        Hd[:, ar, ar] += mu * d
        # a tiny floor keeps the system regular; on the parameters (repeated at every node,
        # tied by the continuity rows) only once, or it would sum to a prior over all nodes
        Hd[:, ar[:nx], ar[:nx]] += floor
        Hd[0, ar[nx:], ar[nx:]] += floor
        put(self.znodes, self.znodes, Hd)
        nI = G.shape[0]
        zfrom = self.znodes[self.zi]
        zto = self.znodes[self.zi + 1]
        put(self.lams, zfrom, G)
        put(zfrom, self.lams, np.transpose(G, (0, 2, 1)))
        negI = np.broadcast_to(-np.eye(nz), (nI, nz, nz))
        put(self.lams, zto, negI)
        put(zto, self.lams, negI)
        if q2 is not None and np.any(q2 > 0):
            put(self.lams, self.lams, np.broadcast_to(-np.diag(q2), (nI, nz, nz)))
        if self.link:
            L = np.zeros((nth, nz))
            L[:, nx:] = np.eye(nth)
            lk = np.array(self.link)
            last = np.array([zf[-1] for zf in self.zoff[:-1]])
            first = np.array([zf[0] for zf in self.zoff[1:]])
            k = len(lk)
            put(lk, last, np.broadcast_to(L, (k, nth, nz)))
            put(last, lk, np.broadcast_to(L.T, (k, nz, nth)))
            put(lk, first, np.broadcast_to(-L, (k, nth, nz)))
            put(first, lk, np.broadcast_to(-L.T, (k, nz, nth)))
        if rhs_extra is not None:
            rhs = rhs_extra
        else:
            rhs = np.zeros(self.n)
            rhs[(self.znodes[:, None] + ar).ravel()] = -g.ravel()
            rhs[(self.lams[:, None] + ar).ravel()] = -c.ravel()
        try:
            return solve_banded((l, u), ab, rhs, check_finite=False)
        except (np.linalg.LinAlgError, ValueError) as e:
            raise SolverError(f"Gauss-Newton step: singular KKT system ({e})") from None


# ------------------------------------------------------------------------------ fit
def _free_indices(model: QuadrotorModel, free: Iterable[str] | None,
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


def _bounds(model: QuadrotorModel) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = [], []
    for p in model.parameters:
        lo += [p.lower] * p.size
        hi += [p.upper] * p.size
    return np.array(lo), np.array(hi)


def _progress_printer(stream=None) -> Callable[[str], None]:
    stream = stream or sys.stderr

    def say(msg: str) -> None:
        print(msg, file=stream, flush=True)
    return say


def _noise_levels(logs: Sequence[FlightLog], noise: Mapping[str, float] | None) -> np.ndarray:
    sigma = np.ones(len(OUTPUTS))
    given = dict(noise or {})
    for c, name in enumerate(OUTPUTS):
        if name in given:
            sigma[c] = float(given[name])
            continue
        vals = [estimate_noise(l.output(name)) for l in logs if name in l.output_names]
        vals = [v for v in vals if np.isfinite(v)]
        sigma[c] = float(np.median(vals)) if vals else 1.0
    floor = {"x": 1e-4, "y": 1e-4, "z": 1e-4, "phi": 1e-4, "theta": 1e-4, "psi": 1e-4,
             "p": 1e-3, "q": 1e-3, "r": 1e-3}
    return np.maximum(sigma, [floor[n] for n in OUTPUTS])


class _Session:
    """One multiple-shooting problem (model, logs, free set, weights) and its solver."""

    def __init__(self, model: QuadrotorModel, logs: Sequence[FlightLog], free_idx: list[int], p: np.ndarray,
                 sigma: np.ndarray, interval: int, compile: str, say: Callable[[str], None]):
        self.model, self.logs, self.free_idx, self.say = model, list(logs), free_idx, say
        params_by_comp = {n: par for par in model.parameters for n in par.component_names}
        # scale by the starting value where there is one (a 30 g and a 3 kg vehicle differ in
        # K_T by 1000x); a parameter starting at zero gets its nominal scale
        self.scale = np.array([abs(p[i]) if p[i] != 0 else params_by_comp[model.param_names[i]].scale
                               for i in free_idx])
        lo, hi = _bounds(model)
        self.lo_s, self.hi_s = lo[free_idx] / self.scale, hi[free_idx] / self.scale
        self.sigma = sigma.copy()
        self.q: np.ndarray | None = None   # process noise per state (None: hard continuity)
        self.max_step: float | None = None   # trust region on the scaled parameters (None: off)
        self.interval = interval
        h_max = max(float(np.diff(l.t).max()) for l in logs)
        t0 = time.perf_counter()
        self.prob = _ShootingProblem(model, free_idx, interval, n_substeps(h_max), compile)
        self.t_build = time.perf_counter() - t0
        self.data = _layout(model, logs, interval, sigma)
        self.n_int = sum(M for _, M in self.data.flights)
        self.mapped = self.prob.mapped(self.n_int)
        self.kkt = _KKT(self.data.flights, model.nx, len(free_idx))
        self.nx, self.nth, self.nz = model.nx, len(free_idx), self.prob.nz
        self.pfix = p.copy()
        n_nodes = self.n_int + len(self.data.flights)
        self.last_mask = np.zeros(n_nodes, dtype=bool)
        k = 0
        for _, M in self.data.flights:
            self.last_mask[k + M] = True
            k += M + 1
        self.nxt = self.kkt.zi + 1

    def set_sigma(self, sigma: np.ndarray) -> None:
        self.sigma = sigma.copy()
        self.data.W = np.where(self.data.mask, 1.0 / sigma[:, None], 0.0)

    def initial_nodes(self, p: np.ndarray) -> np.ndarray:
        return np.vstack([initial_node_states(self.model, log, idx, p)
                          for log, idx in zip(self.logs, self.data.node_index)])

    def evaluate(self, X, th, blocks=True):
        nx, nz, n_int = self.nx, self.nz, self.n_int
        args = (X[~self.last_mask].T, th, self.scale, self.pfix, self.data.U, self.data.T, self.data.Hs,
                self.data.Y, self.data.W)
        if blocks:
            xe, S, H, g, c = self.mapped.blocks(*args)
            S = np.asarray(S).reshape(nx, n_int, nz).transpose(1, 0, 2)
            H = np.asarray(H).reshape(nz, n_int, nz).transpose(1, 0, 2)
            return np.asarray(xe).T, S, H, np.asarray(g).T, np.asarray(c)
        xe, c = self.mapped.value(*args)
        return np.asarray(xe).T, np.asarray(c)

    def gaps(self, X, xe):
        return xe - X[self.nxt]

    def _q2(self) -> np.ndarray | None:
        if self.q is None:
            return None
        return np.concatenate([self.q ** 2, np.zeros(self.nth)])

    def total_cost(self, X, xe, c) -> float:
        """Measurement cost, plus the process-noise cost of the gaps when continuity is soft."""
        cost = 0.5 * float(c.sum())
        if self.q is not None:
            cost += 0.5 * float(((self.gaps(X, xe) / self.q) ** 2).sum())
        return cost

    def _kkt_parts(self, X, blocks):
        xe, S, Hb, g, _ = blocks
        nx, nz, nth, n_int = self.nx, self.nz, self.nth, self.n_int
        H = np.zeros((X.shape[0], nz, nz))
        gg = np.zeros((X.shape[0], nz))
        H[~self.last_mask] = Hb
        gg[~self.last_mask] = g
        G = np.zeros((n_int, nz, nz))
        G[:, :nx, :] = S
        G[:, nx:, nx:] = np.eye(nth)
        cz = np.zeros((n_int, nz))
        cz[:, :nx] = self.gaps(X, xe)
        return H, gg, G, cz

    def step(self, X, th, blocks, mu):
        """Gauss-Newton step with parameters on a bound held when the step points outward."""
        H, gg, G, cz = self._kkt_parts(X, blocks)
        nx, nz, nth, kkt = self.nx, self.nz, self.nth, self.kkt
        frozen = np.zeros(nth, dtype=bool)
        for _ in range(nth + 1):
            Hf, gf, Gf = H, gg, G
            if frozen.any():
                # hold a parameter by removing it from the step: no curvature, gradient or
                # sensitivity anywhere, a unit diagonal at the first node. (A large penalty
                # instead cost the banded solve its accuracy: the gaps it should close stayed
                # open, and the iteration crawled along the bound for dozens of steps.)
                fz = nx + np.flatnonzero(frozen)
                Hf, gf, Gf = H.copy(), gg.copy(), G.copy()
                Hf[:, fz, :] = 0.0
                Hf[:, :, fz] = 0.0
                Hf[0, fz, fz] = 1.0
                gf[:, fz] = 0.0
                Gf[:, :nx, fz] = 0.0
            sol = kkt.solve(Hf, gf, Gf, cz, mu, q2=self._q2())
            dz = sol[(kkt.znodes[:, None] + np.arange(nz)).ravel()].reshape(-1, nz)
            dth = dz[0, nx:]
            out = (((th <= self.lo_s + 1e-12) & (dth < 0)) | ((th >= self.hi_s - 1e-12) & (dth > 0))) & ~frozen
            if not out.any():
                break
            # hold the worst violator only, then look again: the others may turn inward
            frozen[np.flatnonzero(out)[np.argmax(np.abs(dth[out]))]] = True
        dz[:, nx:] = np.where(frozen, 0.0, dz[:, nx:])
        self.last_held = frozen
        lam = sol[(kkt.lams[:, None] + np.arange(nz)).ravel()].reshape(-1, nz)
        return dz, lam, H, gg, cz

    def predicted_decrease(self, X, th) -> float:
        """Cost decrease one undamped Gauss-Newton step predicts from (X, th): at the optimum of
        a smaller model it is half the score (Lagrange multiplier) statistic of the extra
        parameters."""
        blocks = self.evaluate(X, th)
        dz, lam, H, gg, cz = self.step(X, th, blocks, 0.0)
        d = float(-(gg * dz).sum() - 0.5 * np.einsum("ki,kij,kj->", dz, H, dz))
        if self.q is not None:
            # soft continuity: the linearised gaps after the step are q^2 * lambda
            q2 = self.q ** 2
            d += 0.5 * float((cz[:, :self.nx] ** 2 / q2).sum()) - 0.5 * float((q2 * lam[:, :self.nx] ** 2).sum())
        return d

    def solve(self, X, th, mu, max_iter, tol, rough: bool = False):
        """Damped Gauss-Newton from (X, th). ``rough``: stop once the cost settles to 1e-3
        with the gaps closed (a solve whose residuals only serve to re-estimate the weights)."""
        say, nx, n_int = self.say, self.nx, self.n_int
        rho = np.zeros((n_int, nx))
        blocks = self.evaluate(X, th)
        soft = self.q is not None
        cost = self.total_cost(X, blocks[0], blocks[4])
        last_rel = np.inf
        it, status, converged = 0, "maximum iterations reached", False
        for it in range(1, max_iter + 1):
            dz, lam, H, gg, cz = self.step(X, th, blocks, mu)
            c = cz[:, :nx]
            dX, dth = dz[:, :nx], dz[0, nx:]
            rho = np.maximum(rho, 2.0 * np.abs(lam[:, :nx]) + 1e-8)
            if soft:  # an unconstrained least-squares problem: the cost is the merit
                merit0, slope = cost, 0.0
            else:
                merit0 = cost + float((rho * np.abs(c)).sum())
                slope = float((gg * dz).sum()) - float((rho * np.abs(c)).sum())
            alpha, accepted, trial = 1.0, False, None
            if self.max_step is not None and self.nth:
                big = float(np.max(np.abs(dth)))
                if big > self.max_step:
                    alpha = self.max_step / big
            for ls in range(14):
                # projected step: parameters are clipped onto their bounds
                Xt, tht = X + alpha * dX, np.clip(th + alpha * dth, self.lo_s, self.hi_s)
                if ls == 0:  # the full step is usually taken: its blocks serve the next iteration
                    trial = self.evaluate(Xt, tht)
                    xe_t, c_t = trial[0], trial[4]
                else:
                    trial = None
                    xe_t, c_t = self.evaluate(Xt, tht, blocks=False)
                if soft:
                    merit_t = self.total_cost(Xt, xe_t, c_t)
                else:
                    merit_t = 0.5 * float(c_t.sum()) + float((rho * np.abs(self.gaps(Xt, xe_t))).sum())
                if np.isfinite(merit_t) and merit_t <= merit0 + 1e-4 * alpha * min(slope, 0.0) and \
                        (not soft or merit_t < merit0):
                    accepted = True
                    break
                alpha *= 0.5
            step_size = float(np.max(np.abs(tht - th))) if self.nth else 0.0
            if not accepted:
                if mu > 1e6:
                    if soft and last_rel < 1e-4:
                        # no decrease left to find: the smoother is at its optimum to rounding
                        converged, status = True, "converged"
                        break
                    status = "line search failed: no decrease along the Gauss-Newton direction"
                    break
                mu = max(mu * 10, 1e-3)
                say(f"  iter {it:3d}  step rejected, damping -> {mu:.1e}")
                continue
            X, th = Xt, tht
            mu = mu / 3 if alpha == 1.0 else min(mu * 2, 1e8)
            mu = max(mu, 1e-10)
            blocks = trial if trial is not None else self.evaluate(X, th)
            new_cost = self.total_cost(X, blocks[0], blocks[4])
            gap = float(np.abs(self.gaps(X, blocks[0])).max())
            say(f"  iter {it:3d}  cost {new_cost:12.6g}  max gap {gap:9.2e}  step {step_size:9.2e}  alpha {alpha:.3f}")
            rel = abs(cost - new_cost) / max(new_cost, 1e-300)
            last_rel = rel
            cost = new_cost
            # soft continuity: the smoother's states settle slowly once the parameters have
            # stopped moving, so a looser cost test
            if step_size < tol and ((soft and rel < 1e-4) or
                                    (rel < 1e-6 and gap < 1e-6 * (1 + float(np.abs(X).max())))):
                converged, status = True, "converged"
                break
            if rough and not soft and rel < 1e-3 and gap < 1e-4 * (1 + float(np.abs(X).max())):
                # the weights from these residuals change by < 0.1 %: more iterations would be
                # spent on a problem about to be re-weighted (a large-residual start can creep
                # at a linear rate for dozens of iterations)
                converged, status = True, "settled (weights to be re-estimated)"
                break
        if not np.all(np.isfinite(X)) or not np.all(np.isfinite(th)):
            raise SolverError("fit diverged: non-finite states or parameters")
        return X, th, mu, it, converged, status, blocks

    def covariance(self, X, blocks) -> np.ndarray:
        """Parameter block of the inverse KKT matrix (undamped): the Gauss-Newton covariance
        of the scaled free parameters for unit-variance weighted residuals."""
        H, _, G, _ = self._kkt_parts(X, blocks)
        nx, nth, kkt = self.nx, self.nth, self.kkt
        rhs = np.zeros((kkt.n, nth))
        rhs[kkt.znodes[0] + nx + np.arange(nth), np.arange(nth)] = 1.0
        P = kkt.solve(H, np.zeros((X.shape[0], self.nz)), G, np.zeros((self.n_int, self.nz)), 0.0, rhs_extra=rhs,
                      q2=self._q2())
        P = P[kkt.znodes[0] + nx + np.arange(nth)]
        return 0.5 * (P + P.T)

    def state_noise_scale(self, sensor: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Per state, the size of a change the measurements could just see: the sensor noise
        of its channel (positions, angles, gyro), over one shooting interval for velocities
        (and body rates without a gyro); 1e-3 of its spread for effect states."""
        dt = float(np.median(self.data.Hs[self.data.Hs > 0])) if np.any(self.data.Hs > 0) else 1.0
        T = max(self.interval, 1) * dt
        sig = dict(zip(OUTPUTS, sensor))
        measured = {n for c, n in enumerate(OUTPUTS) if self.data.mask[c].any()}
        out = np.empty(self.nx)
        for j, name in enumerate(self.model.state_names):
            if name in ("x", "y", "z", "phi", "theta", "psi"):
                out[j] = sig[name]
            elif name in ("vx", "vy", "vz"):
                out[j] = sig["xyz"[j - 6]] / T
            elif name in ("p", "q", "r"):
                out[j] = sig[name] if name in measured else sig[("phi", "theta", "psi")[j - 9]] / T
            else:
                out[j] = 1e-3 * (float(np.std(X[:, j])) + 1e-6 * (1.0 + float(np.abs(X[:, j]).max())))
        return out

    def optimality(self, X, th, blocks, P: np.ndarray, s2: float, sensor: np.ndarray
                   ) -> tuple[float, float, float, list[str], list[str]]:
        """First-order optimality at (X, th): the undamped Gauss-Newton step (projected onto
        the bounds) in parameter standard deviations and in state noise scales, and the
        largest continuity gap against the state's noise scale. At an optimum the step is
        zero whatever the size of the residuals. Returns (step/std, state step/noise,
        gap/noise, held parameters, reasons it is not optimal)."""
        reasons: list[str] = []
        names = [self.model.param_names[i] for i in self.free_idx]
        try:
            dz, _, _, _, cz = self.step(X, th, blocks, 0.0)
        except SolverError as e:
            return math.inf, math.inf, math.inf, [], [f"the Gauss-Newton system is singular at the end point ({e})"]
        held = [n for n, h in zip(names, self.last_held) if h]
        scale = self.state_noise_scale(sensor, X)
        var = s2 * np.diag(P)
        ok = var > 0
        if not np.all(ok):
            reasons.append("the information matrix is singular in " +
                           ", ".join(n for n, k in zip(names, ok) if not k))
        dth = dz[0, self.nx:]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(ok, np.abs(dth) / np.sqrt(np.abs(var)), np.inf)
        ratio = np.where(self.last_held, 0.0, ratio)
        step_std = float(ratio.max()) if ratio.size else 0.0
        state_step = float((np.abs(dz[:, :self.nx]) / scale).max())
        gap = 0.0 if self.q is not None else float((np.abs(cz[:, :self.nx]) / scale).max())
        if step_std > STEP_TOLERANCE and np.all(ok):
            worst = names[int(np.argmax(ratio))]
            reasons.append(f"one more Gauss-Newton step would move {worst} by {step_std:.3g} std")
        if state_step > STEP_TOLERANCE:
            j = int(np.argmax((np.abs(dz[:, :self.nx]) / scale).max(axis=0)))
            reasons.append(f"one more Gauss-Newton step would move the state {self.model.state_names[j]} by "
                           f"{state_step:.3g} of its noise scale")
        if gap > GAP_TOLERANCE:
            j = int(np.argmax((np.abs(cz[:, :self.nx]) / scale).max(axis=0)))
            reasons.append(f"shooting gaps are open (largest in {self.model.state_names[j]}: {gap:.3g} of its noise scale)")
        return step_std, state_step, gap, held, reasons


def sensor_noise(logs: Sequence[FlightLog]) -> np.ndarray:
    """Per output channel, the noise standard deviation estimated from the measurements'
    high-frequency content (:func:`estimate_noise`), never from model residuals; floored at
    the resolution below which no sensor reports (0.1 mm, 0.1 mrad, 1 mrad/s)."""
    return _noise_levels(logs, None)


def fit(model: QuadrotorModel, logs: "FlightLog | Sequence[FlightLog]", *, free: Iterable[str] | None = None,
        fixed: Iterable[str] | None = None, p0: np.ndarray | Mapping[str, float] | None = None,
        interval: int | None = None, noise: Mapping[str, float] | None = None,
        max_iter: int = 60, tol: float = 1e-7, reweight: bool = True, compile: str = "auto",
        progress: bool | Callable[[str], None] = False, initial_states: Sequence[np.ndarray] | None = None,
        process_noise: str | Mapping[str, float] | None = None) -> FitResult:
    """Fit the free parameters of ``model`` to one or several flight logs.

    Args:
        model: the grey-box model (its effects decide the parameters).
        logs: one log or a list of logs (several flights share the parameters; each has its
            own states). Fit on the estimation part (``log.split()``); validate with
            :func:`greybox.validation.predict` on the rest.
        free / fixed: parameter (or component) names to estimate / hold. Default: every
            parameter whose ``Parameter.free`` is set (``J_r`` is fixed by default).
        p0: starting values (flat vector or ``{name: value}``); default the airframe's guesses.
        interval: samples per shooting interval (default: the number nearest 50 ms).
        noise: channel noise standard deviations ``{"x": 0.003, ...}``; others are estimated.
        reweight: re-estimate channel noise from the residuals and solve again.
        compile: ``"auto"`` (compile the step functions to C when a compiler exists), ``"quick"``
            (compile without optimisation: faster to build, slower to run) or ``"never"``.
        progress: True to print iterations to stderr, or a callable taking a line of text.
        initial_states: per flight (M+1, nx) node state guesses (default: from the data).
        process_noise: ``None`` (default): the model is exact between measurements, the
            shooting gaps must close (output error). ``"auto"`` or ``{state: std}``: the
            gaps are process noise, penalised by ``|gap_i|^2 / (2 q_i^2)`` (a filter-error
            / smoothing formulation); with ``"auto"`` ``q`` starts as the RMS gap of each
            state at the starting point and is re-estimated (downwards only) after each
            solve. Use it on real data whose inputs are not the whole truth (e.g. PWM logged at 85 Hz for a 500 Hz controller): an output-error
            fit of such data can only shrink the parameters until the model stops moving.

    Example::

        from greybox import QuadrotorModel, fit, load_airframe, load_log
        model = QuadrotorModel(load_airframe("greybox/data/airframes/paper.toml"))
        est, val = load_log("greybox/data/logs/demo_ground_effect.csv").split(0.8)
        res = fit(model, est, p0={"K_T": 3e-5})
        print(res.summary()); res.parameters["K_T"]     # {"value": ..., "std": ...}
    """
    t_start = time.perf_counter()
    say = _progress_printer() if progress is True else (progress or (lambda _m: None))
    logs = [logs] if isinstance(logs, FlightLog) else list(logs)
    if not logs:
        raise GreyboxInputError("no flight logs to fit")
    if interval is None:
        # with process noise every sample is a node: the model is only trusted one step ahead
        interval = 1 if process_noise is not None else default_interval(logs)
    if interval < 1:
        raise GreyboxInputError(f"interval must be >= 1 sample, got {interval}")
    soft = process_noise is not None
    if soft:   # checked before anything is built
        if isinstance(process_noise, str) and process_noise != "auto":
            raise GreyboxInputError(f"process_noise must be None, 'auto' or {{state: std}}, got {process_noise!r}")
        q_given = {} if isinstance(process_noise, str) else dict(process_noise)
        for k in q_given:
            if k not in model.state_names:
                raise GreyboxInputError(f"process_noise: unknown state {k!r}; states are "
                                        f"{', '.join(model.state_names)}")
    logs = [model.prepare_log(log) for log in logs]
    for log in logs:
        log.check_fittable(min_samples=max(2 * interval, 20))
    if isinstance(p0, Mapping):
        p = model.parameter_vector(p0)
    else:
        p = model.default_parameters() if p0 is None else np.array(p0, dtype=float)
    free_idx = _free_indices(model, free, fixed)
    free_names = [model.param_names[i] for i in free_idx]
    sigma = _noise_levels(logs, noise)
    ses = _Session(model, logs, free_idx, p, sigma, interval, compile, say)
    say(f"fit: {len(logs)} flight(s), {sum(len(l) for l in logs)} samples, {len(free_idx)} free "
        f"parameters, interval {interval} samples; interval function: {ses.prob.how} ({ses.t_build:.1f} s)")
    if initial_states is not None:
        X = np.vstack([np.array(s, dtype=float) for s in initial_states])
    else:
        X = ses.initial_nodes(p)
    th = p[free_idx] / ses.scale
    data = ses.data
    n_c = data.mask.sum(axis=1)
    user_sigma = np.array([n in (noise or {}) for n in OUTPUTS])

    def residual_rms(c: np.ndarray) -> np.ndarray:
        return np.sqrt(np.where(n_c > 0, c.sum(axis=1) / np.maximum(n_c, 1), 1.0))

    t0 = time.perf_counter()
    if soft:
        def estimate_q(X_, th_) -> np.ndarray:
            xe = ses.evaluate(X_, th_, blocks=False)[0]
            rms = np.sqrt(np.mean(ses.gaps(X_, xe) ** 2, axis=0))
            floor = 1e-6 * (np.abs(X_).max(axis=0) + 1e-3)
            q = np.maximum(rms, floor)
            if ses.q is not None:
                # only downwards: grown process noise would let the states follow measurement
                # noise, and the gaps grow with it (the degenerate end of joint Q estimation)
                q = np.minimum(q, ses.q)
            for name, v in q_given.items():
                q[model.state_names.index(name)] = float(v)
            return q

        ses.q = estimate_q(X, th)
        say("fit: process noise (RMS gap per state): " +
            ", ".join(f"{n}={v:.2g}" for n, v in zip(model.state_names, ses.q)))
    sensor = sensor_noise(logs)
    n_res = int(data.mask.sum())
    dof = max(n_res - ses.nth - ses.nx * len(logs), 1)

    def check(X_, th_, blocks_):
        P_ = ses.covariance(X_, blocks_)
        s2_ = 2 * ses.total_cost(X_, blocks_[0], blocks_[4]) / dof
        return P_, s2_, ses.optimality(X_, th_, blocks_, P_, s2_, sensor)

    def attempt(X, th):
        if reweight and not soft:
            # Where the starting model misses a channel by far more than the sensor noise (real
            # data: unmodelled physics dwarfs a mocap's 0.1 mm), noise weights would let that one
            # channel dictate the fit; start from weights of the size of the starting residuals.
            rms0 = residual_rms(ses.evaluate(X, th, blocks=False)[1])
            inflate = np.where((n_c > 0) & ~user_sigma & (rms0 > 10.0), rms0 / 10.0, 1.0)
            if np.any(inflate > 1):
                ses.set_sigma(ses.sigma * inflate)
                say("fit: starting weights from the first residuals: " +
                    ", ".join(f"{n}={s:.3g}" for n, s, k in zip(OUTPUTS, ses.sigma, inflate) if k > 1))
        polished = not (reweight and not soft)
        X, th, mu, iters, converged, status, blocks = ses.solve(X, th, 1e-3, max_iter, tol, rough=not polished)
        total_iters = iters
        for _ in range(3 if soft and process_noise == "auto" else 0):
            if not converged:
                break
            q_new = estimate_q(X, th)
            if np.all(np.abs(q_new / ses.q - 1) < 0.2):
                break
            ses.q = q_new
            say("fit: process noise re-estimated: " + ", ".join(f"{n}={v:.2g}" for n, v in zip(model.state_names, ses.q)))
            X, th, mu, iters, converged, status, blocks = ses.solve(X, th, 1e-4, max_iter, tol)
            total_iters += iters
        for _ in range(3 if reweight and not soft else 0):
            if not converged:
                break
            # channel noise re-estimated from the residuals: weights match the data
            rms_w = residual_rms(blocks[4])
            fix = np.where((n_c > 0) & ~user_sigma, rms_w, 1.0)
            if not np.any(np.abs(fix - 1) > 0.05):
                break
            ses.set_sigma(ses.sigma * fix)
            say("fit: noise re-estimated from residuals: " +
                ", ".join(f"{n}={s:.3g}" for n, s, k in zip(OUTPUTS, ses.sigma, n_c) if k))
            X, th, mu, iters, converged, status, blocks = ses.solve(X, th, 1e-4, max_iter, tol)
            total_iters += iters
            polished = True
        if not polished and converged:
            # the weights did not change: finish the settled solve to the full tolerance
            X, th, mu, iters, converged, status, blocks = ses.solve(X, th, mu, max_iter, tol)
            total_iters += iters
        P, s2, opt = check(X, th, blocks)
        for _ in range(MAX_RESTARTS):
            if not opt[4] or status == "maximum iterations reached":   # the user's budget is spent
                break
            # Not there yet: a line search that found no decrease on an l1 merit whose weights
            # only grow, or an iteration cap. Solve on from here with fresh damping and merit
            # weights; the certificate, not the solver's stopping rule, decides.
            say(f"fit: not certified ({'; '.join(opt[4])}): solving on with fresh damping and merit weights")
            X, th, mu, iters, converged, status, blocks = ses.solve(X, th, 1e-3, max_iter, tol)
            total_iters += iters
            P, s2, opt = check(X, th, blocks)
        return X, th, mu, total_iters, converged, status, blocks, P, s2, opt

    start = (X.copy(), th.copy(), ses.sigma.copy(), None if ses.q is None else ses.q.copy())
    X, th, mu, total_iters, converged, status, blocks, P, s2, opt = attempt(X, th)
    if opt[4] and status != "maximum iterations reached":
        # A second strategy from the same start: a trust region on the parameters. Far from
        # the optimum a linearisation can ask for a sign change or a tenfold value in one step
        # (a foreign 1 kg flight with a weak rotor went there and never came back); kept for
        # the retry because it slows a fit that would have got there anyway.
        say(f"fit: not certified ({'; '.join(opt[4])}); again from the start with a trust region "
            f"of {100 * TRUST_REGION:.0f} % per iteration on the parameters")
        first = (X, th, mu, total_iters, converged, status, blocks, P, s2, opt)
        kept_sigma, kept_q = ses.sigma.copy(), ses.q
        X0, th0, sigma0, q0 = start
        ses.set_sigma(sigma0)
        ses.q = q0
        ses.max_step = TRUST_REGION
        second = attempt(X0.copy(), th0.copy())
        ses.max_step = None
        if second[9][4]:      # not certified either: keep the first, and its weights
            ses.set_sigma(kept_sigma)
            ses.q = kept_q
            X, th, mu, total_iters, converged, status, blocks, P, s2, opt = first
            total_iters += second[3]
        else:
            X, th, mu, total_iters, converged, status, blocks, P, s2, opt = second
            total_iters += first[3]
    step_std, state_step, gap, held, reasons = opt
    if not reasons and not converged:
        status = f"converged (certified optimum; the solver stopped on: {status})"
    elif reasons:
        status = f"{'' if status.startswith('converged') else status + '; '}optimum not certified: {'; '.join(reasons)}"
    converged = not reasons
    t_solve = time.perf_counter() - t0
    sigma, scale, nth, nx = ses.sigma, ses.scale, ses.nth, ses.nx
    cch = blocks[4]
    cost = ses.total_cost(X, blocks[0], cch)
    cov = s2 * P * np.outer(scale, scale)
    var = np.diag(cov)
    warnings: list[str] = []
    if np.any(var <= 0) or not np.all(np.isfinite(var)):
        warnings.append("information matrix is singular: some parameters are not identifiable from these data")
    # a non-positive variance is no variance: its std is unknown (NaN), not sqrt(|v|), and it
    # has no correlations (a correlation outside [-1, 1] was once reported from one)
    std = np.where(var > 0, np.sqrt(np.abs(var)), np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(std, std)
    corr = np.clip(np.nan_to_num(corr), -1.0, 1.0)
    p_out = p.copy()
    p_out[free_idx] = th * scale
    warnings += _identifiability_warnings(free_names, p_out[free_idx], std, corr, P)
    if not converged:
        warnings.insert(0, f"solver did not converge: {status}; test statistics at this fit are not valid")
        import warnings as _w
        _w.warn(f"fit did not converge: {status}", ConvergenceWarning, stacklevel=2)

    cc = cch.sum(axis=1)
    resid_rms = {n: float(sigma[c] * math.sqrt(cc[c] / n_c[c])) for c, n in enumerate(OUTPUTS) if n_c[c]}
    node_states, k = [], 0
    for _, M in data.flights:
        node_states.append(X[k:k + M + 1].copy())
        k += M + 1
    # the residual check: RMS against the noise of the data, whiteness of the residual series.
    # With process noise the fitted states follow the data through the gaps, so residuals at
    # the nodes say nothing about the model: it is judged open loop instead, over intervals of
    # the default length (50 ms) started from the fitted states.
    white: dict[str, list[float]] = {}
    sq: dict[str, list[float]] = {}
    check_n = default_interval(logs) if soft else interval
    for f, log in enumerate(logs):
        nodes, idx = node_states[f], data.node_index[f]
        if check_n != interval:
            M = math.ceil(len(log) / check_n)
            idx = np.minimum(np.arange(M + 1) * check_n, len(log) - 1)
            nodes = nodes[idx]          # soft fits have a node at every sample
        probe = FitResult(model, p_out, free_names, np.zeros(0), np.zeros((0, 0)), np.zeros((0, 0)), converged,
                          status, 0, 0.0, 0, {}, {}, [nodes], [idx], interval=check_n)
        E = output_residuals(log, fitted_trajectory(model, probe, log, 0)[1])
        for c, n in enumerate(OUTPUTS):
            if n_c[c]:
                white.setdefault(n, []).append(whiteness_fraction(E[:, c]))
                sq.setdefault(n, []).append(float(np.nansum(E[:, c] ** 2)))
    check_rms = {n: math.sqrt(sum(sq[n]) / n_c[c]) for c, n in enumerate(OUTPUTS) if n_c[c]}
    certificate = Certificate(
        converged, step_std, state_step, gap, held,
        {n: float(check_rms[n] / sensor[c]) for c, n in enumerate(OUTPUTS) if n_c[c]},
        {n: float(np.nanmean(v)) if np.any(np.isfinite(v)) else float("nan") for n, v in white.items()},
        {n: float(sensor[c]) for c, n in enumerate(OUTPUTS) if n_c[c]}, reasons)
    timings = {"build": ses.t_build, "solve": t_solve, "total": time.perf_counter() - t_start}
    say(f"fit: {status} after {total_iters} iterations in {timings['total']:.2f} s")
    return FitResult(model, p_out, free_names, std, cov, corr, converged, status, total_iters, cost,
                     n_res, {n: float(sigma[c]) for c, n in enumerate(OUTPUTS) if n_c[c]}, resid_rms,
                     node_states, data.node_index, warnings, timings, ses.prob.how, interval,
                     {n: float(cc[c]) for c, n in enumerate(OUTPUTS) if n_c[c]},
                     {n: int(n_c[c]) for c, n in enumerate(OUTPUTS) if n_c[c]},
                     dict(zip(model.state_names, map(float, ses.q))) if soft else None,
                     cost - 0.5 * float(cch.sum()), certificate)


def _identifiability_warnings(names: list[str], values: np.ndarray, std: np.ndarray, corr: np.ndarray,
                              P: np.ndarray) -> list[str]:
    out = []

    def advice(n: str) -> str:
        base = n.split("[")[0]
        return MANOEUVRE_ADVICE.get(base, "more varied manoeuvres")

    n = len(names)
    for i in range(n):
        for j in range(i + 1, n):
            if abs(corr[i, j]) > 0.95:
                out.append(f"{names[i]} and {names[j]} are strongly correlated (r = {corr[i, j]:+.3f}): "
                           f"the data hardly tell them apart; fly {advice(names[i])} / {advice(names[j])}")
    for i in range(n):
        if values[i] != 0 and std[i] > 0.5 * abs(values[i]):
            out.append(f"{names[i]} is poorly determined ({std[i]:.3g} on {values[i]:.3g}); "
                       f"fly {advice(names[i])}")
    # near-singular information: the weakest direction of the scaled covariance
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    if w.size and w[-1] > 0 and w[0] > 0 and w[-1] / w[0] > 1e10:
        v = V[:, -1]
        top = [names[k] for k in np.argsort(-np.abs(v))[:3] if abs(v[k]) > 0.3]
        out.append(f"near-singular information (condition {w[-1] / w[0]:.1e}); weakest combination "
                   f"involves {', '.join(top)}")
    return out


class GreyBoxEstimator:
    """scikit-learn style wrapper of :func:`fit`.

    >>> est = GreyBoxEstimator(model).fit(est_log)       # doctest: +SKIP
    >>> est.params_, est.std_, est.predict(val_log)       # doctest: +SKIP
    """

    def __init__(self, model: QuadrotorModel, **fit_options):
        self.model = model
        self.fit_options = fit_options

    def fit(self, logs: FlightLog | Sequence[FlightLog]) -> "GreyBoxEstimator":
        self.result_ = fit(self.model, logs, **self.fit_options)
        self.params_ = self.result_.model.parameter_dict(self.result_.p)
        self.std_ = dict(zip(self.result_.free_names, map(float, self.result_.std)))
        return self

    def predict(self, log: FlightLog, horizon: float = 1.0):
        """k-step-ahead predictions on ``log`` (see :func:`greybox.validation.predict`)."""
        from .validation import predict
        return predict(self.model, self.result_.p, log, horizon=horizon)

    def score(self, log: FlightLog, horizon: float = 1.0) -> float:
        """Validation ``nrmse`` (lower is better) of the fitted model on ``log``."""
        from .validation import nrmse
        return nrmse(self.model, self.result_.p, log, horizon=horizon)["nrmse"]

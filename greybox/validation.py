"""Validation: k-step-ahead prediction, ``nrmse``, ``compare`` and residual plots.

How a prediction window is initialised (documented contract of ``nrmse``): the validation
log is cut into consecutive windows of ``horizon`` seconds (default 1 s). The state at the
start of each window is a *moving-horizon estimate* from the ``init_window`` seconds of
measurements just before it (default 0.5 s): a small Gauss–Newton fit of the state at the
start of that stretch, with the model's parameters held, propagated to the window start.
Only past data enter the initial state; the model then predicts the whole window open loop
from the logged inputs, and the prediction errors over the window are scored. A window whose
stretch before it does not measure a pose channel the log measures throughout its second half
(a vision outage; :func:`startable`) starts instead at the next sample whose stretch does, and
the samples in between are not scored: a state guessed across an outage tests the guess, not
the model.

``nrmse`` of a channel is the RMS of its prediction errors (over every measured sample in
every window) divided by the RMS of the measured signal's variation about its mean over the
same samples; the total ``nrmse`` is the mean over the channels. ``fit`` percent is
MATLAB's ``100 * (1 - nrmse)``.
"""
from __future__ import annotations

import math

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import casadi as ca
import numpy as np

from . import effects as fx
from .data import OUTPUT_LIMITS, FlightLog
from .errors import GreyboxInputError
from .shooting import ShootingProblem, estimate_noise, initial_node_states
from .integrate import Substeps, log_substeps, parallel_map, rk4_step_with_output
from .model import OUTPUTS, QuadrotorModel
from .rotations import euler_rates_from_body_rates

__all__ = ["Prediction", "HorizonErrors", "HorizonAccumulator", "measured_outputs", "DEFAULT_HORIZONS", "POSE_CHANNELS", "startable", "check_validation_length", "predict", "predict_flights", "pool_predictions", "nrmse", "compare_plot", "residual_plot", "estimate_states",
           "DEFAULT_HORIZON", "DEFAULT_INIT_WINDOW", "prediction_options", "predict_after_fit",
           "horizon_errors_after", "horizon_errors", "HORIZON_START_EVERY", "INIT_WINDOWS",
           "choose_horizon_predictor", "HELD_MOMENT_WINDOWS", "estimation_tails", "INIT_WINDOW_DATA",
           "INIT_WINDOW_HORIZON", "choose_init_window", "choose_measured_start",
           "choose_start", "STATE_PRIOR_SCALE", "horizon_windows", "validation_vectors", "mean_value_words"]

DEFAULT_HORIZON = 1.0
DEFAULT_INIT_WINDOW = 0.5
PSI = OUTPUTS.index("psi")


@dataclass
class Prediction:
    """k-step-ahead predictions of a model on a log.

    Example::

        pred = predict(model, res.p, val)       # 1 s ahead on the validation part
        pred.total, pred.nrmse["z"], pred.fit_percent["z"]
        pred.predicted[:, 2]                    # z predicted (NaN outside windows)
    """

    log: FlightLog
    predicted: np.ndarray            # (n, 9) predictions, NaN outside windows
    windows: list[tuple[int, int]]   # [start, stop) sample indices
    channels: list[str]              # channels scored (measured in the log)
    nrmse: dict[str, float]          # per channel
    total: float                     # mean over channels
    horizon: float
    errors: np.ndarray = field(repr=False, default=None)   # (n, 9) measured - predicted (psi wrapped)
    parts: list["Prediction"] | None = field(repr=False, default=None)   # per flight, when pooled
    start_states: np.ndarray | None = field(repr=False, default=None)    # (windows, nx) estimated at each start

    def above_spread_words(self) -> str:
        """Where a channel's nrmse is above 1, what that says and what it does not: the
        prediction error (RMS) beside how much the channel moves in the windows (its RMS about
        its mean, the nrmse's denominator), and where to look instead; "" where none is. A
        certified, adequate exact model on a 100-Hz log of noisy speeds read nrmse 2.10 (y 7.48)
        with nothing said, where it beat the naive predictor 0.25 and 0.5 s ahead (a blind
        audit)."""
        if self.parts:
            return ""
        meas = measured_outputs(self.log, self.errors.shape[1])
        covered = _window_rows(meas.shape[0], self.windows)
        said = []
        for name in self.channels:
            if not math.isfinite(self.nrmse[name]) or self.nrmse[name] <= 1.0:
                continue
            c = OUTPUTS.index(name)
            k = covered & np.isfinite(meas[:, c])
            unit = OUTPUT_LIMITS[name][1]
            said.append(f"{name} {self.nrmse[name]:.3g} (error {float(np.sqrt(np.mean(self.errors[k, c] ** 2))):.3g} "
                        f"{unit} RMS where {name} moves {_spread(meas[k, c], c):.3g} {unit} about its mean)")
        if not said:
            return ""
        return (f"nrmse above 1 on {', '.join(said)}: over {self.horizon:g} s the prediction drifts further than "
                f"the channel moves in these windows, which a channel that barely moves makes easy; it does not "
                "say how far off the model is: its error against horizon beside the naive predictor's does (the "
                "JSON's horizons, horizons.png)")

    def horizon_errors(self, horizons: Sequence[float] | None = None) -> "HorizonErrors":
        """RMS prediction error against horizon, beside the naive predictor's (see
        :class:`HorizonErrors`)."""
        return HorizonErrors.from_prediction(self, horizons)

    @property
    def longest_window(self) -> float:
        """s: the longest window predicted; shorter than :attr:`horizon` when the log after its
        start window is (then every number here is over that shorter stretch); pooled, the
        longest of the flights'."""
        if self.parts:      # the pooled windows index the stacked flights, not self.log
            return max(part.longest_window for part in self.parts)
        t = self.log.t
        return max((float(t[ke - 1] - t[k]) for k, ke in self.windows), default=0.0)

    @property
    def horizon_label(self) -> str:
        """``"1 s-ahead"``, or what was predicted when the log is shorter than the horizon."""
        dt = float(np.median(np.diff(self.log.t))) if self.log.t.size > 1 else 0.0
        if self.longest_window + 1.5 * dt < self.horizon:
            return (f"{self.horizon:g} s-ahead asked, the data after the start window give "
                    f"{len(self.windows)} window(s) of at most {self.longest_window:.3g} s")
        return f"{self.horizon:g} s-ahead"

    @property
    def fit_percent(self) -> dict[str, float]:
        return {c: 100.0 * (1.0 - v) for c, v in self.nrmse.items()}

    def as_dict(self) -> dict:
        """JSON-ready; a diverged prediction's infinite nrmse is ``None`` (null)."""
        num = lambda v: v if math.isfinite(v) else None   # noqa: E731
        return {"nrmse": num(self.total), "channels": {c: num(v) for c, v in self.nrmse.items()},
                "horizon": self.horizon, "windows": len(self.windows),
                "longest_window": self.longest_window}


POSE_CHANNELS = ("x", "y", "z", "phi", "theta", "psi")
"""Channels a window's start state needs measured in the stretch it is estimated from."""


def startable(log: FlightLog, L: int) -> np.ndarray:
    """Per sample ``k``: can a prediction start there, from the ``L`` samples before it? Each
    pose channel the log measures at all must be measured throughout the stretch's second half
    (the samples ``k - L/2`` to ``k - 1``, which carry the velocity): nowhere in it may its
    last measurement be older than a quarter of the stretch, or three of its typical spacings
    for a channel sampled sparsely (two frames lost are no outage). A start state estimated
    over a sensor's outage is a guess: on a 250 g racer at 7 m/s a window started in a 0.4-s
    vision outage was predicted 1.6 m off in y, from positions and a velocity guessed across
    the gap, and it alone took the validation nrmse from 0.028 to 0.069; started just after
    the outage, from one position sample and a velocity guessed across it, a window was as
    far off. False for ``k < L``."""
    t = log.t
    n = t.size
    ok = np.arange(n) >= L
    if n <= L:
        return ok
    stretch = t - t[np.clip(np.arange(n) - L, 0, n - 1)]
    h = max(L // 2, 1)                                          # the stretch's second half: k-h .. k-1
    for name in POSE_CHANNELS:
        if name not in log.output_names:
            continue
        measured = np.isfinite(log.output(name))
        if measured.sum() < 2:
            continue
        tm = t[measured]
        j = np.searchsorted(tm, t, side="right") - 1            # the last measurement at or before each sample
        age = np.where(j >= 0, t - tm[np.maximum(j, 0)], np.inf)
        # the oldest age over the stretch's second half: a sliding maximum
        oldest = np.full(n, np.inf)
        oldest[h:] = np.lib.stride_tricks.sliding_window_view(age, h).max(axis=1)[:n - h]
        allowed = np.maximum(0.25 * stretch, 3.0 * float(np.median(np.diff(tm))))
        ok &= oldest <= allowed + 1e-9
    return ok


def _windows(t: np.ndarray, L: int, horizon: float, can_start: np.ndarray | None = None) -> list[tuple[int, int]]:
    """Consecutive windows of ``horizon`` seconds, each with ``L`` samples before it; a window
    that cannot start (``can_start`` False: a sensor's outage) starts at the next sample that
    can, and the samples between are not scored."""
    out = []
    k = L
    while k < t.size - 2:
        if can_start is not None and not can_start[k]:
            later = np.flatnonzero(can_start[k:])
            if not later.size:
                break
            k += int(later[0])
            continue
        ke = int(np.searchsorted(t, t[k] + horizon - 1e-9, side="right"))
        ke = min(max(ke, k + 2), t.size)
        out.append((k, ke))
        k = ke
    return out


def _sigma(log: FlightLog) -> np.ndarray:
    s = np.ones(len(OUTPUTS))
    for c, name in enumerate(OUTPUTS):
        if name in log.output_names:
            v = estimate_noise(log.output(name))
            s[c] = v if np.isfinite(v) and v > 0 else 1.0
    return np.maximum(s, 1e-4)


STATE_PRIOR_SCALE = np.array([1.0, 1.0, 1.0, 0.5, 0.5, 0.5, 2.0, 2.0, 2.0, 5.0, 5.0, 5.0])
"""Scale of the weak prior the moving-horizon start-state estimate puts on the rigid-body
states about their guesses from the measurements (:func:`estimate_states`): m, rad, m/s,
rad/s, in the state order x, y, z, phi, theta, psi, vx, vy, vz, p, q, r."""


def estimate_states(model: QuadrotorModel, p: np.ndarray, log: FlightLog, starts: Sequence[int],
                    L: int, sigma: np.ndarray | None = None, iterations: int = 10,
                    compile: str = "auto", measured_start: bool = False) -> np.ndarray:
    """Moving-horizon state estimates at samples ``starts``: for each, the state at
    ``start - L`` is fitted (parameters held) to the ``L`` samples before ``start`` and
    integrated to ``start``. ``measured_start``: then the attitude and body rates are taken
    from the measurements at ``start`` instead, as the naive predictor takes them
    (:func:`naive_start`; where a channel is measured), and only the rest (position, velocity,
    the effects' states) from the estimate. Returns (len(starts), nx)."""
    starts = np.asarray(starts, dtype=int)
    if np.any(starts < L):
        raise GreyboxInputError("state estimation needs L samples before every start")
    sigma = _sigma(log) if sigma is None else sigma
    n_sub = log_substeps([log])
    prob = ShootingProblem(model, [], L, n_sub, compile)
    nW = starts.size
    Fb = prob.mapped(nW).blocks
    idx = (starts[:, None] - L + np.arange(L)[None, :]).ravel()
    Y = np.full((idx.size, model.ny), np.nan)
    for c, name in enumerate(OUTPUTS):
        if name in log.output_names:
            Y[:, c] = log.output(name)[idx]
    mask = np.isfinite(Y)
    W = np.where(mask, 1.0 / sigma[None, :], 0.0).T
    Y = np.where(mask, Y, 0.0).T
    U = log.inputs[idx].T
    T = log.t[idx][None, :]
    h = (log.t[idx + 1] - log.t[idx])[None, :]
    args = (np.zeros(0), np.zeros(0), p, U, T, h, Y, W)
    X = initial_node_states(model, log, starts - L, p)
    nx = model.nx
    # A weak prior on the rigid-body states about their guesses from the measurements
    # (STATE_PRIOR_SCALE): where the stretch measures a state it weighs nothing beside the
    # data; where it does not (a vision dropout over the whole stretch), the state stays at
    # its guess. Without it a state the data do not see moves along the faint gradient a
    # model may give it: with a ground effect, z fitted to a stretch without position went
    # 31 m up (where the ground effect vanishes), and its window's prediction with it.
    X0 = X.copy()
    info = np.zeros(nx)
    info[:12] = 1.0 / STATE_PRIOR_SCALE ** 2

    def with_prior(Xc, H, g, c):
        dev = Xc - X0
        return H + np.diag(info), g + info * dev, c + (info * dev * dev).sum(axis=1)

    mu = np.full(nW, 1e-3)
    xe, S, H, g, c = Fb(X.T, *args)
    H, g, cost = with_prior(X, np.asarray(H).reshape(nx, nW, nx).transpose(1, 0, 2), np.asarray(g).T,
                            np.asarray(c).sum(axis=0))
    xe = np.asarray(xe).T
    for _ in range(iterations):
        d = np.einsum("kii->ki", H)
        A = H + (mu[:, None] * d + 1e-9 * (1 + d.max(axis=1, keepdims=True)))[:, :, None] * np.eye(nx)
        dx = -np.linalg.solve(A, g[:, :, None])[:, :, 0]
        Xt = X + dx
        xe_t, S_t, H_t, g_t, c_t = Fb(Xt.T, *args)
        H_t, g_t, cost_t = with_prior(Xt, np.asarray(H_t).reshape(nx, nW, nx).transpose(1, 0, 2), np.asarray(g_t).T,
                                      np.asarray(c_t).sum(axis=0))
        ok = np.isfinite(cost_t) & (cost_t <= cost)
        X[ok] = Xt[ok]
        cost[ok] = cost_t[ok]
        H[ok], g[ok] = H_t[ok], g_t[ok]
        xe[ok] = np.asarray(xe_t).T[ok]
        mu = np.where(ok, np.maximum(mu / 5, 1e-9), mu * 10)
    if measured_start:
        meas = measured_outputs(log, model.ny)
        # what the sensors' effects add to the attitude and rates at the estimate (a gyro's bias,
        # an attitude offset): taken off the measurements the windows start from, as the state
        # is the body's (a blind audit's gyro bias, added back on a start from the raw rates:
        # r predicted 12 % worse with the bias fitted to 0.4 std of the truth)
        Yx = np.asarray(model.output.map(nW)(xe.T, log.inputs[starts].T, np.repeat(p[:, None], nW, axis=1),
                                              log.t[starts][None, :])).T
        sensor = Yx[:, [OUTPUTS.index(n) for n in ("phi", "theta", "psi", "p", "q", "r")]] - xe[:, [3, 4, 5, 9, 10, 11]]
        for i, a in enumerate(starts):
            _, eul, _, om = naive_start(log, meas, int(a), xe[i])
            xe[i, 3:6], xe[i, 9:12] = eul - sensor[i, :3], om - sensor[i, 3:]
    return xe


def _prediction_function(model: QuadrotorModel, n_steps: int, n_sub: "int | Substeps", n_windows: int) -> ca.Function:
    acc = rk4_step_with_output(model, n_sub).mapaccum("pred", n_steps, [0], [0])
    X0 = ca.MX.sym("x0", model.nx)
    U = ca.MX.sym("U", model.nu, n_steps)
    P = ca.MX.sym("p", model.n_params)
    T = ca.MX.sym("T", 1, n_steps)
    Hs = ca.MX.sym("h", 1, n_steps)
    _, Y, _ = acc(X0, U, ca.repmat(P, 1, n_steps), T, Hs)
    return parallel_map(ca.Function("predict", [X0, U, P, T, Hs], [Y]), n_windows)


def _predict_windows(model: QuadrotorModel, p: np.ndarray, log: FlightLog, starts: np.ndarray,
                     n_steps: int, L: int, sigma: np.ndarray | None, compile: str,
                     measured_start: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop predictions of ``n_steps`` samples from each of ``starts`` (a prepared log),
    each started at its moving-horizon estimate over the ``L`` samples before it. Returns the
    predicted outputs (windows, n_steps, ny; a window running past the log's end repeats its
    last sample) and the start states (windows, nx)."""
    t = log.t
    x0 = estimate_states(model, p, log, starts, L, sigma, compile=compile, measured_start=measured_start)
    n_sub = log_substeps([log])
    F = _prediction_function(model, n_steps, n_sub, len(starts))
    idx = np.minimum(starts[:, None] + np.arange(n_steps)[None, :], t.size - 1)   # (nW, n_steps)
    nxt = np.minimum(idx + 1, t.size - 1)
    h = t[nxt] - t[idx]
    U = log.inputs[idx.ravel()].T
    Yp = np.asarray(F(x0.T, U, p, t[idx.ravel()][None, :], h.ravel()[None, :]))   # (ny, nW*n_steps)
    return Yp.reshape(model.ny, len(starts), n_steps).transpose(1, 2, 0), x0


def _too_short(log: FlightLog, init_window: float, dt: float) -> GreyboxInputError:
    """The error for a log too short to start one validation window on."""
    span = float(log.t[-1] - log.t[0]) if log.t.size else 0.0
    return GreyboxInputError(f"{log.source or 'log'}: too short for validation: the rows validated on span "
                             f"{span:.3f} s, need more than {init_window + 2 * dt:.3f} s (a fit validates on "
                             "each flight's last 20 % unless given separate validation flights: --validation LOGV, "
                             "then every LOG is estimation data whole)")


def check_validation_length(log: FlightLog, init_window: float = DEFAULT_INIT_WINDOW) -> None:
    """The error :func:`predict` gives a log too short to start one window on, raised before
    any fit (an audit's 0.6-s flight among others was refused after the whole fit had run)."""
    t = log.t
    if t.size < 3:
        raise GreyboxInputError(f"{log.source or 'log'}: too short for validation: {t.size} samples")
    dt = float(np.median(np.diff(t)))
    if not _windows(t, max(int(round(init_window / dt)), 3), DEFAULT_HORIZON):
        raise _too_short(log, init_window, dt)


def predict(model: QuadrotorModel, p: np.ndarray, log: FlightLog, horizon: float = DEFAULT_HORIZON,
            init_window: float = DEFAULT_INIT_WINDOW, sigma: np.ndarray | None = None,
            compile: str = "auto", held_moment: bool = False, measured_start: bool = False) -> Prediction:
    """k-step-ahead prediction of ``model`` with parameters ``p`` on ``log`` (see module doc).

    ``held_moment``: also estimate, with each window's start state, the roll and pitch moment
    the commands do not show, and hold it over the window (:class:`~greybox.effects.HeldMoment`,
    a disturbance model; ``p`` is unchanged: it has no parameters). It helps where a constant
    moment is missing from the model (a simulated CoG offset); on real Crazyflie flights it made
    roll and pitch worse; greybox's horizon reports use it only where it predicts the estimation
    data better (:func:`choose_horizon_predictor`).

    ``measured_start``: each window starts from the measured attitude and body rates (the
    rest from the estimate; see :func:`estimate_states`).

    Example::

        from greybox import fit, predict
        est, val = log.split(0.8)
        res = fit(model, est)
        pred = predict(model, res.p, val, horizon=1.0)   # pred.nrmse per channel, pred.total
    """
    if held_moment and fx.HeldMoment.name not in model.effects:
        model = model + fx.HeldMoment()
    log = model.prepare_log(log)
    p = np.asarray(p, dtype=float)
    t = log.t
    dt = float(np.median(np.diff(t)))
    L = max(int(round(init_window / dt)), 3)
    anywhere = _windows(t, L, horizon)
    if not anywhere:
        raise _too_short(log, init_window, dt)
    # windows that start from an outage only where nothing else can start (a log shorter than
    # an outage and a start stretch): as before, rather than no validation at all
    wins = _windows(t, L, horizon, startable(log, L)) or anywhere
    starts = np.array([a for a, _ in wins])
    Yp, x0 = _predict_windows(model, p, log, starts, max(b - a for a, b in wins), L, sigma, compile,
                              measured_start)
    pred = np.full((t.size, model.ny), np.nan)
    for w, (a, b) in enumerate(wins):
        pred[a:b] = Yp[w, :b - a]
    meas = measured_outputs(log, model.ny)
    err = meas - pred
    err[:, PSI] = np.arctan2(np.sin(err[:, PSI]), np.cos(err[:, PSI]))
    # a prediction that diverged (NaN, inf) where there is a measurement is an infinite error,
    # not a sample left out: scoring the finite rest would make a blown-up model look good
    covered = _window_rows(t.size, wins)
    err[covered[:, None] & np.isfinite(meas) & ~np.isfinite(pred)] = np.inf
    scores, channels = {}, []
    for c, name in enumerate(OUTPUTS):
        k = covered & np.isfinite(meas[:, c])
        if k.sum() < 3:
            continue
        spread = _spread(meas[k, c], c)
        with np.errstate(over="ignore"):   # a prediction that blew up to 1e200 scores inf
            rms = float(np.sqrt(np.mean(err[k, c] ** 2)))
        scores[name] = rms / spread if spread > 0 else float("inf")
        channels.append(name)
    if not scores:
        raise GreyboxInputError(f"{log.source or 'log'}: no measured channel to validate against")
    total = float(np.mean(list(scores.values())))
    return Prediction(log, pred, wins, channels, scores, total, horizon, err, start_states=x0)


def _window_rows(n: int, windows: Sequence[tuple[int, int]]) -> np.ndarray:
    """(n,) True on the rows inside the ``[start, stop)`` windows."""
    covered = np.zeros(n, dtype=bool)
    for a, b in windows:
        covered[a:b] = True
    return covered


def _spread(values: np.ndarray, channel: int) -> float:
    """The RMS of a channel's measured ``values`` about their mean (psi unwrapped): the
    denominator of its nrmse."""
    ref = np.unwrap(values) if channel == PSI else values
    return float(np.sqrt(np.mean((ref - ref.mean()) ** 2)))


DEFAULT_HORIZONS = (0.05, 0.1, 0.25, 0.5, 1.0)
"""s, after one sample: the horizons at which :class:`HorizonErrors` reports."""
NAIVE_FIT_WINDOW = 0.05
"""s of measurements before a window's start from which the naive predictor takes its
state (5 samples of a 100 Hz motion-capture log: long enough to average the noise of a
velocity, short enough that the vehicle's acceleration does not bend it)."""
NAIVE_LOOKBACK = 0.5
"""s: a channel sampled more sparsely than :data:`NAIVE_FIT_WINDOW` (GNSS positions at
5-10 Hz) gives the naive predictor its last two samples from this far back instead."""


def naive_start(log: FlightLog, meas: np.ndarray, a: int, x0: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The naive predictor's state at sample ``a`` from the measurements ``meas`` (n, ny;
    NaN where not measured) of the last :data:`NAIVE_FIT_WINDOW` (a channel with fewer than
    two samples there: its last two of :data:`NAIVE_LOOKBACK`), each line through them carried
    to sample ``a``: position, velocity, Euler angles and their rates; ``x0`` (the model's
    estimate) where a channel has no sample, and the velocity that carries a lone sample."""
    t = log.t
    lo = int(np.searchsorted(t, t[a] - NAIVE_LOOKBACK - 1e-9, side="left"))
    tt = t[lo:a + 1] - t[a]
    recent = tt >= -NAIVE_FIT_WINDOW - 1e-9

    def samples(c):
        y = meas[lo:a + 1, c]
        k = np.isfinite(y)
        if np.count_nonzero(k & recent) >= 2:
            k &= recent
        else:
            # sparser than the window (10 Hz GNSS): a line through the last two samples; a
            # sample 50 ms old held as the present position had been the naive's whole error
            measured = np.flatnonzero(k)
            if measured.size >= 2:
                k[:measured[-2]] = False
        yk = y[k]
        if c == PSI and yk.size:
            yk = np.unwrap(yk)
        return tt[k], yk

    def line(c, fallback, fallback_rate=0.0):
        tk, yk = samples(c)
        if yk.size == 0:
            return fallback, None
        if yk.size < 2 or np.ptp(tk) <= 0:
            return float(yk[-1] - fallback_rate * tk[-1]), None
        slope, intercept = np.polyfit(tk, yk, 1)
        return float(intercept), float(slope)

    pos, vel = np.empty(3), np.empty(3)
    for j in range(3):
        pos[j], v = line(j, x0[j], x0[6 + j])
        vel[j] = x0[6 + j] if v is None else v
    om = np.array([x0[9 + j] for j in range(3)], dtype=float)
    gyro = np.zeros(3, dtype=bool)
    for j in range(3):
        tk, yk = samples(OUTPUTS.index("p") + j)     # the gyro's channels
        if yk.size:
            om[j], gyro[j] = yk[-1], True
    eul = np.empty(3)
    angles = [samples(3 + j) for j in range(3)]
    if gyro.all():
        last = [yk[-1] if yk.size else x0[3 + j] for j, (_, yk) in enumerate(angles)]
        rate = euler_rates_from_body_rates(last[0], last[1], om)
        for j, (tk, yk) in enumerate(angles):
            eul[j] = float(np.mean(yk - rate[j] * tk)) if yk.size else x0[3 + j]
    else:
        rate = np.empty(3)
        fallback_rate = euler_rates_from_body_rates(x0[3], x0[4], om)
        for j in range(3):
            eul[j], r = line(3 + j, x0[3 + j], fallback_rate[j])
            rate[j] = fallback_rate[j] if r is None else r
    return np.concatenate([pos, vel]), eul, np.asarray(rate, dtype=float), om


@dataclass
class HorizonErrors:
    """Prediction error against horizon, per channel, for the model and for the naive
    predictor that system-identification benchmarks of small quadrotors use beside it:
    constant velocity and constant body rates from the measurements at the window's start
    (positions ``p0 + v0 h``, ``p0`` and ``v0`` a straight line through the position
    samples of the last :data:`NAIVE_FIT_WINDOW`; angles ``e0 + W(e0) omega0 h``, ``omega0``
    the last gyro sample and ``e0`` the angle samples of that window carried to the start at
    that rate (a line through them without a gyro); rates ``omega0``; the accelerometer,
    which is no state, held at its first measured sample of the window). The naive
    predictor never sees the model: a model-based state estimate would make it as wrong as
    the model on real flights (phi errors of 14 rad at 0.25 s were once reported as the
    naive predictor's). Where a channel has no sample in that window, the model's estimated
    start state stands in.

    ``model[ch][i]`` and ``naive[ch][i]`` are RMS errors in the channel's units (m, rad,
    rad/s, m/s^2) at ``horizons[i]`` seconds ahead, over every window of the prediction;
    ``windows`` is how many windows were scored (their starts; not in :meth:`as_dict`)."""

    horizons: list[float]
    model: dict[str, list[float]]
    naive: dict[str, list[float]]
    windows: int = 0
    predictor: dict = field(default_factory=dict)
    """how the model's windows started (:func:`horizon_errors`' ``init_window``,
    ``measured_start``, ``held_moment``); empty when not known (:meth:`from_prediction`)."""

    def as_dict(self) -> dict:
        clean = lambda d: {ch: [v if math.isfinite(v) else None for v in vals] for ch, vals in d.items()}  # noqa: E731
        # the contract's keys only (CONTRACT.md section 5); the predictor is in the reports' words
        return {"horizons": list(self.horizons), "model": clean(self.model), "naive": clean(self.naive)}

    def beats_naive(self, channel: str, horizon: float) -> bool:
        """Whether the model's error is below the naive predictor's at ``horizon``."""
        i = int(np.argmin(np.abs(np.asarray(self.horizons) - horizon)))
        return bool(self.model[channel][i] < self.naive[channel][i])

    def relative_error(self, horizons: Sequence[float] = (0.25, 0.5),
                       channels: Sequence[str] = POSE_CHANNELS) -> float:
        """The model's error relative to the naive predictor's: the geometric mean of their
        ratio over ``channels`` (the positions and angles measured) at ``horizons`` (below 1: the
        model predicts better). A ratio of logs, so that one channel whose prediction diverges
        does not decide alone; ``inf`` when a model error is not finite, ``nan`` when nothing
        can be compared."""
        logs = []
        for h in horizons:
            i = int(np.argmin(np.abs(np.asarray(self.horizons) - h)))
            if abs(self.horizons[i] - h) > 1e-9:
                continue
            for ch in channels:
                if ch not in self.model:
                    continue
                m, n = self.model[ch][i], self.naive[ch][i]
                if not (math.isfinite(n) and n > 0):
                    continue
                if not math.isfinite(m):
                    return math.inf
                logs.append(math.log(max(m, 1e-300) / n))
        return math.exp(float(np.mean(logs))) if logs else math.nan

    @classmethod
    def from_prediction(cls, pred: "Prediction", horizons: Sequence[float] | None = None) -> "HorizonErrors":
        """From the windows of one (pooled) prediction: consecutive, so each horizon is scored
        once per window (a 5-s validation flight gives 5 samples per horizon at the default
        1-s windows; :func:`horizon_errors` starts many overlapping windows instead)."""
        parts = pred.parts or [pred]
        dt = float(np.median(np.diff(parts[0].log.t)))
        hs = sorted({round(dt, 9), *[h for h in (horizons or DEFAULT_HORIZONS) if h <= pred.horizon + 1e-9]})
        acc = HorizonAccumulator(hs, pred.channels, dt)
        for part in parts:
            if part.start_states is None:
                raise GreyboxInputError("horizon errors need a prediction made by greybox.predict")
            meas = measured_outputs(part.log, part.predicted.shape[1])
            for w, (a, b) in enumerate(part.windows):
                acc.add(part.log, meas, a, part.errors[a:b], part.start_states[w])
        return acc.result()


def measured_outputs(log: FlightLog, ny: int) -> np.ndarray:
    """The log's outputs as an (n, ny) array in ``OUTPUTS`` order, NaN where not measured."""
    meas = np.full((len(log.t), ny), np.nan)
    for c, name in enumerate(OUTPUTS[:ny]):
        if name in log.output_names:
            meas[:, c] = log.output(name)
    return meas


class HorizonAccumulator:
    """Squared model and naive errors at each horizon, summed over prediction windows: the
    scoring of :class:`HorizonErrors` for any predictor that gives its errors per window
    (:func:`horizon_errors`, :func:`greybox.controller_law.closed_loop_horizon_errors`)."""

    def __init__(self, hs: Sequence[float], channels: Sequence[str], dt: float):
        self.hs, self.channels, self.dt = list(hs), list(channels), dt
        self.sq_m = {ch: np.zeros(len(hs)) for ch in channels}
        self.sq_n = {ch: np.zeros(len(hs)) for ch in channels}
        self.cnt = {ch: np.zeros(len(hs)) for ch in channels}
        self.windows = 0

    def add(self, log: FlightLog, meas: np.ndarray, a: int, errors: np.ndarray, x0: np.ndarray) -> None:
        """One window starting at sample ``a``: ``errors`` (its samples, ny) measured minus
        predicted, psi wrapped; ``x0`` the model's start state (the naive predictor's
        fallback where a channel has no recent sample)."""
        t, dt = log.t, self.dt
        self.windows += 1
        pv, eul0, eul_rate, om0 = naive_start(log, meas, a, x0)
        for ch in self.channels:
            c = OUTPUTS.index(ch)
            # this channel's measured samples in the window (multi-rate logs); where the
            # prediction is not finite there, the model's error is infinite (as in predict)
            ks = np.flatnonzero(np.isfinite(meas[a:a + len(errors), c]))
            if ks.size == 0:
                continue
            for i, h in enumerate(self.hs):
                # the measured sample nearest h ahead, if near enough
                j = int(ks[np.argmin(np.abs(t[a + ks] - t[a] - h))])
                k = a + j
                tau = t[k] - t[a]
                if abs(tau - h) > 0.2 * h + 0.5 * dt:
                    continue
                y = meas[k, c]
                naive = {"x": pv[0] + pv[3] * tau, "y": pv[1] + pv[4] * tau, "z": pv[2] + pv[5] * tau,
                         "phi": eul0[0] + eul_rate[0] * tau, "theta": eul0[1] + eul_rate[1] * tau,
                         "psi": eul0[2] + eul_rate[2] * tau, "p": om0[0], "q": om0[1], "r": om0[2]}
                # the accelerometer is no state: held at its first sample of the window
                en = y - naive.get(ch, meas[a + ks[0], c])
                if c == PSI:
                    en = math.atan2(math.sin(en), math.cos(en))
                # a Python float: a prediction that blew up squares to inf without a warning
                em = float(errors[j, c]) if np.isfinite(errors[j, c]) else math.inf
                self.sq_m[ch][i] += em * em
                self.sq_n[ch][i] += en * en
                self.cnt[ch][i] += 1

    def add_windows(self, log: FlightLog, meas: np.ndarray, starts: Sequence[int], predicted: np.ndarray,
                    start_states: np.ndarray) -> None:
        """Windows starting at samples ``starts`` with their predicted outputs ``predicted``
        (windows, steps, ny; cut at the log's end) and start states: each window's errors,
        measured minus predicted with psi wrapped, :meth:`add`-ed."""
        for w, a in enumerate(starts):
            b = min(a + predicted.shape[1], log.t.size)
            err = meas[a:b] - predicted[w, :b - a]
            err[:, PSI] = np.arctan2(np.sin(err[:, PSI]), np.cos(err[:, PSI]))
            self.add(log, meas, a, err, start_states[w])

    def result(self) -> HorizonErrors:
        rms = lambda sq, n: [float(math.sqrt(s / c)) if c else float("nan") for s, c in zip(sq, n)]  # noqa: E731
        return HorizonErrors([float(h) for h in self.hs],
                             {ch: rms(self.sq_m[ch], self.cnt[ch]) for ch in self.channels},
                             {ch: rms(self.sq_n[ch], self.cnt[ch]) for ch in self.channels}, self.windows)


HORIZON_START_EVERY = 0.1
"""s between the starts of :func:`horizon_errors`' overlapping windows."""
HORIZON_MAX_STARTS = 200
"""at most this many window starts per flight (spread evenly) in :func:`horizon_errors`."""


def horizon_windows(log: FlightLog, longest: float, init_window: float = DEFAULT_INIT_WINDOW,
                    start_every: float = HORIZON_START_EVERY) -> tuple[int, int, np.ndarray]:
    """The overlapping windows of an error-against-horizon report on ``log``: ``(L, n_steps,
    starts)`` — the samples of the start window before each start, the samples each window is
    predicted (``longest`` horizon and a margin) and the starts (every ``start_every`` s, at
    most :data:`HORIZON_MAX_STARTS`, none from a sensor's outage where others can start)."""
    t = log.t
    dt = float(np.median(np.diff(t)))
    L = max(int(round(init_window / dt)), 3)
    n_steps = int(np.searchsorted(t - t[0], longest * 1.2 + dt, side="right")) + 1
    last = t.size - 2
    if last <= L:
        raise _too_short(log, init_window, dt)
    step = max(1, int(round(start_every / dt)), int(math.ceil((last - L) / HORIZON_MAX_STARTS)))
    starts = np.arange(L, last, step)
    can = startable(log, L)[starts]
    return L, n_steps, (starts[can] if can.any() else starts)


def horizon_errors(model: QuadrotorModel, p: "np.ndarray | Sequence[np.ndarray]",
                   logs: "FlightLog | Sequence[FlightLog]", horizons: Sequence[float] | None = None,
                   start_every: float = HORIZON_START_EVERY, init_window: float = DEFAULT_INIT_WINDOW,
                   sigma: np.ndarray | None = None, compile: str = "auto",
                   held_moment: bool = False, measured_start: bool = False) -> HorizonErrors:
    """Prediction error against horizon beside the naive predictor's (:class:`HorizonErrors`),
    from windows started every ``start_every`` seconds (overlapping; at most
    :data:`HORIZON_MAX_STARTS` per flight), each predicted ``max(horizons)`` ahead open loop
    from its moving-horizon start state (``init_window``, ``held_moment``, ``measured_start`` as
    in :func:`predict`). ``p``: one parameter vector, or one per flight.

    Consecutive 1-s windows (:meth:`Prediction.horizon_errors`) score each horizon once per
    second of log; on a 5-s validation flight that is five samples, too few to tell a model
    from the naive predictor (on a real Crazyflie flight the verdict at 0.5 s flipped on
    x, y and psi between the two).

    Example::

        he = horizon_errors(model, res.p, val)
        he.beats_naive("x", 0.25), he.as_dict()
    """
    logs = [logs] if isinstance(logs, FlightLog) else list(logs)
    ps = [p] * len(logs) if isinstance(p, np.ndarray) and p.ndim == 1 else list(p)
    if held_moment and fx.HeldMoment.name not in model.effects:
        model = model + fx.HeldMoment()
    hs_req = sorted(horizons or DEFAULT_HORIZONS)
    acc = None
    for pk, log in zip(ps, logs):
        log = model.prepare_log(log)
        t = log.t
        dt = float(np.median(np.diff(t)))
        if acc is None:
            hs = sorted({round(dt, 9), *hs_req})
            channels = [name for name in OUTPUTS if name in log.output_names]
            acc = HorizonAccumulator(hs, channels, dt)
        L, n_steps, starts = horizon_windows(log, max(acc.hs), init_window, start_every)
        Yp, x0 = _predict_windows(model, np.asarray(pk, dtype=float), log, starts, n_steps, L, sigma, compile,
                                  measured_start)
        acc.add_windows(log, measured_outputs(log, model.ny), starts, Yp, x0)
    out = acc.result()
    out.predictor = {"init_window": float(init_window), "measured_start": bool(measured_start),
                     "held_moment": bool(held_moment)}
    return out


def pool_predictions(preds: Sequence[Prediction]) -> Prediction:
    """Several flights' predictions as one: arrays stacked flight after flight, and each
    channel's nrmse pooled — the RMS of all errors over the RMS spread of all measurements
    about their common mean (yaw unwrapped per flight). ``log`` is the first flight's;
    ``parts`` the flights' own predictions. One prediction is returned as it is."""
    preds = list(preds)
    if len(preds) == 1:
        return preds[0]
    meas = [p.predicted + p.errors for p in preds]
    scores, channels = {}, []
    for c, name in enumerate(OUTPUTS):
        errs, refs = [], []
        for p, m in zip(preds, meas):
            k = np.isfinite(p.errors[:, c])
            if k.sum() >= 3:
                errs.append(p.errors[k, c])
                refs.append(np.unwrap(m[k, c]) if c == PSI else m[k, c])
        if not errs:
            continue
        e, r = np.concatenate(errs), np.concatenate(refs)
        spread = float(np.sqrt(np.mean((r - r.mean()) ** 2)))
        with np.errstate(over="ignore"):
            scores[name] = float(np.sqrt(np.mean(e ** 2))) / spread if spread > 0 else float("inf")
        channels.append(name)
    offset, windows = 0, []
    for p in preds:
        windows += [(a + offset, b + offset) for a, b in p.windows]
        offset += p.predicted.shape[0]
    return Prediction(preds[0].log, np.vstack([p.predicted for p in preds]), windows, channels, scores,
                      float(np.mean(list(scores.values()))), preds[0].horizon,
                      np.vstack([p.errors for p in preds]), preds)


def prediction_options(res) -> dict:
    """Options of :func:`predict` that match how the fit ``res`` was made (``{}``: the
    defaults): the start-state window the fit chose (``res.init_window``, kept in a saved
    model's provenance). A fit with process noise trusted its model open loop over one
    shooting interval only; such a model may diverge within the default 0.5 s window (a real
    Crazyflie's roll does), and :func:`choose_init_window` picks its window on the estimation
    data, :func:`choose_measured_start` whether the measured attitude and rates replace the
    estimated ones (``"measured_start": True`` then). A model saved before the window was
    recorded, fitted with process noise, gets :data:`NAIVE_FIT_WINDOW`, as it did then."""
    provenance = getattr(res, "provenance", None) or {}
    measured = bool(getattr(res, "measured_start", None) or provenance.get("measured_start"))
    iw = getattr(res, "init_window", None) or provenance.get("init_window")
    if iw:
        return {"init_window": float(iw), **({"measured_start": True} if measured else {})}
    return {"init_window": NAIVE_FIT_WINDOW} if _fitted_with_process_noise(res) else {}


INIT_WINDOWS = (0.05, 0.1, 0.2, 0.5)
"""s: the start-state windows :func:`choose_init_window` tries."""
INIT_WINDOW_HORIZON = 0.5
"""s ahead :func:`choose_init_window` predicts to compare the windows."""
INIT_WINDOW_DATA = 8.0
"""s at the end of each estimation flight on which :func:`choose_init_window` compares them."""


def choose_init_window(model: QuadrotorModel, p: "np.ndarray | Sequence[np.ndarray]",
                       logs: "FlightLog | Sequence[FlightLog]", compile: str = "auto") -> float:
    """The start-state window (s, one of :data:`INIT_WINDOWS`) with which ``model`` with
    parameters ``p`` (one vector, or one per flight) predicts ``logs`` best
    :data:`INIT_WINDOW_HORIZON` ahead over the last :data:`INIT_WINDOW_DATA` seconds of each
    log (the lowest pooled ``nrmse``; windows too long for a log are skipped; the default
    0.5 s when none can be scored).

    Which is best depends on the data and the model together: a model that diverges open loop
    within half a second (a real Crazyflie's roll) wants a short window, whose start state is
    not bent by the divergence; a model that follows the data wants a long one, since a
    velocity estimated from three 60-Hz position samples is noise (a synthetic flight's true
    model predicted its own data with nrmse 1.02 from 50 ms and 0.012 from 0.5 s). Chosen on
    the estimation data, so that validation stays out of it."""
    return _best_window(model, p, estimation_tails(logs), compile)[0]


def estimation_tails(logs: "FlightLog | Sequence[FlightLog]") -> list[FlightLog]:
    """The last :data:`INIT_WINDOW_DATA` seconds of each flight: enough windows to rank the
    predictors' choices (start states, a held moment, the closed loop) on estimation data."""
    logs = [logs] if isinstance(logs, FlightLog) else list(logs)
    return [lg.slice(int(np.searchsorted(lg.t, lg.t[-1] - INIT_WINDOW_DATA)), len(lg)) for lg in logs]


def _best_window(model, p, tails, compile) -> tuple[float, float]:
    best, best_score = DEFAULT_INIT_WINDOW, math.inf
    for w in INIT_WINDOWS:
        try:
            score = predict_flights(model, p, tails, horizon=INIT_WINDOW_HORIZON, init_window=w, compile=compile).total
        except GreyboxInputError:
            continue
        if score < best_score:
            best, best_score = w, score
    return best, best_score


def _measured_start_better(model, p, tails, init_window, compile, score_estimated: float | None = None) -> bool:
    try:
        if score_estimated is None:
            score_estimated = predict_flights(model, p, tails, horizon=INIT_WINDOW_HORIZON, init_window=init_window,
                                              compile=compile).total
        score = predict_flights(model, p, tails, horizon=INIT_WINDOW_HORIZON, init_window=init_window,
                                compile=compile, measured_start=True).total
    except GreyboxInputError:
        return False
    return bool(score < score_estimated)


def choose_start(model: QuadrotorModel, p: "np.ndarray | Sequence[np.ndarray]",
                 logs: "FlightLog | Sequence[FlightLog]", compile: str = "auto") -> tuple[float, bool]:
    """(start-state window, measured start): :func:`choose_init_window`, then
    :func:`choose_measured_start` at that window (one prediction fewer than the two apart)."""
    tails = estimation_tails(logs)
    window, score = _best_window(model, p, tails, compile)
    return window, _measured_start_better(model, p, tails, window, compile,
                                          score if math.isfinite(score) else None)


def choose_measured_start(model: QuadrotorModel, p: "np.ndarray | Sequence[np.ndarray]",
                          logs: "FlightLog | Sequence[FlightLog]", init_window: float,
                          compile: str = "auto") -> bool:
    """Whether ``model`` predicts ``logs`` better :data:`INIT_WINDOW_HORIZON` ahead (the last
    :data:`INIT_WINDOW_DATA` seconds of each, as :func:`choose_init_window` scores) when its
    windows start from the measured attitude and body rates than from the estimated ones.

    A model trusted open loop over one shooting interval drifts over a start window longer
    than that: on a real Crazyflie flight the estimated roll and pitch at the start were
    0.01-0.02 rad off where the attitude is measured to 0.002 rad, and roll was then predicted
    worse than by the naive predictor 0.25 s ahead. Where the model follows the data (or the
    attitude is measured coarsely), the estimate is the better start, and this says so; chosen
    on the estimation data, so that validation stays out of it."""
    return _measured_start_better(model, p, estimation_tails(logs), init_window, compile)


def _fitted_with_process_noise(res) -> bool:
    """Whether the fit ``res`` used process noise (a loaded model knows it from its provenance)."""
    return bool(getattr(res, "process_noise", None) or (getattr(res, "provenance", None) or {}).get("process_noise"))


def horizon_errors_after(res, preds: "Sequence[Prediction]", ps: "Sequence[np.ndarray]",
                         compile: str = "auto", est: "Sequence[FlightLog] | None" = None) -> "HorizonErrors":
    """The error-against-horizon report of the fit ``res`` validated by ``preds`` (one
    prediction per flight, made with the parameter vectors ``ps``): :func:`horizon_errors` on
    those flights with the start-state options the fit calls for (:func:`prediction_options`),
    or, given the fit's estimation flights ``est``, with a held moment where that predicts
    them better (:func:`choose_horizon_predictor`)."""
    options = prediction_options(res)
    if est is not None:
        est = [est] if isinstance(est, FlightLog) else list(est)
        flight_p = getattr(res, "flight_p", None)
        est_ps = [flight_p(i) for i in range(len(est))] if flight_p is not None else [res.p] * len(est)
        options = choose_horizon_predictor(res.model, est_ps, est, options, compile=compile)
    return horizon_errors(res.model, list(ps), [pr.log for pr in preds], compile=compile, **options)


HELD_MOMENT_WINDOWS = (0.05, 0.1, 0.2)
"""s: the start-state windows :func:`choose_horizon_predictor` tries with a held moment."""


def choose_horizon_predictor(model: QuadrotorModel, p: "np.ndarray | Sequence[np.ndarray]",
                             logs: "FlightLog | Sequence[FlightLog]", options: dict | None = None,
                             compile: str = "auto") -> dict:
    """The :func:`horizon_errors` options for a fit's report on its estimation flights
    ``logs``: ``options`` (the fit's :func:`prediction_options`), or a roll and pitch moment
    held from each window's start (:class:`~greybox.effects.HeldMoment`, estimated with the
    start state over one of :data:`HELD_MOMENT_WINDOWS`) where that predicts the last
    :data:`INIT_WINDOW_DATA` seconds of each flight better :data:`INIT_WINDOW_HORIZON` ahead
    (the lowest pooled ``nrmse``; chosen on the estimation data, so validation stays out of it).

    A disturbance model, as a predictor with a noise model has (MATLAB's ``predict``): a
    closed-loop vehicle's controller cancels a moment the log does not show, and a model whose
    moment from the commands is off by a slowly varying amount rolls away open loop. On real
    Crazyflie flights it is taken where the model's attitude predictions are poor (the slow
    B10_lissajous and B6_linear_ramp: 0.5-s nrmse on the estimation data 1.54 -> 1.23 and 14.1
    -> 6.3) and left where they are good (B3_figure8_fast 0.62 against 0.79 with it, B9 0.72
    against 0.82): a moment estimated from a few gyro samples is noise there. Only the horizon
    report uses it; validation (``nrmse``) and the diagnosis judge the model as it is."""
    options = dict(options or {})
    if not model.accepts(fx.HeldMoment()):
        return options
    tails = estimation_tails(logs)
    try:
        best = predict_flights(model, p, tails, horizon=INIT_WINDOW_HORIZON, compile=compile, **options).total
    except GreyboxInputError:
        return options
    chosen = options
    measured = bool(options.get("measured_start", False))
    for w in HELD_MOMENT_WINDOWS:
        held = {"init_window": w, "measured_start": measured, "held_moment": True}
        try:
            score = predict_flights(model, p, tails, horizon=INIT_WINDOW_HORIZON, compile=compile, **held).total
        except (GreyboxInputError, ValueError, np.linalg.LinAlgError, RuntimeError):
            # an option of the report only: where it cannot be scored, the fit's own start stands
            continue
        if score < best:
            best, chosen = score, held
    return chosen


def predict_flights(model: QuadrotorModel, p: "np.ndarray | Sequence[np.ndarray]",
                    logs: "FlightLog | Sequence[FlightLog]", horizon: float = DEFAULT_HORIZON, **kw) -> Prediction:
    """:func:`predict` on each flight, pooled (:func:`pool_predictions`); ``p`` one parameter
    vector, or one per flight (:func:`validation_vectors`)."""
    logs = [logs] if isinstance(logs, FlightLog) else list(logs)
    ps = [p] * len(logs) if isinstance(p, np.ndarray) and p.ndim == 1 else list(p)
    return pool_predictions([predict(model, pk, log, horizon, **kw) for pk, log in zip(ps, logs)])


def validation_vectors(res, est: Sequence[FlightLog], val: Sequence[FlightLog]) -> list[np.ndarray]:
    """The parameter vector each validation flight is predicted with, after a fit ``res`` on
    ``est``: a flight fitted with its own values of per-flight parameters (wind, battery sag:
    ``res.per_flight_``) is validated with them when the validation flight is its tail
    (:meth:`FlightLog.split`: same log, starting at the estimation part's last sample); any
    other flight gets their mean, ``res.p`` (its wind was never seen)."""
    return [res.flight_p(i) if _own_tail(res, est, i, v) else res.p for i, v in enumerate(val)]


def _own_tail(res, est: Sequence[FlightLog], i: int, v: FlightLog) -> bool:
    """Whether validation flight ``v`` (the ``i``-th) is estimation flight ``i``'s tail, fitted
    with its own values of per-flight parameters (:meth:`FlightLog.split`: same log, starting at
    the estimation part's last sample)."""
    e = est[i] if i < len(est) else None
    return bool(e is not None and getattr(res, "per_flight_", None) and len(v) and len(e)
                and v.source == e.source and v.t[0] == e.t[-1])


def mean_value_words(res, est: Sequence[FlightLog], val: Sequence[FlightLog]) -> list[str]:
    """Words for each validation flight that :func:`validation_vectors` predicts with the mean
    of the per-flight parameters (a flight that is not an estimation flight's tail), with the
    values it averages: its validation error then counts how far its own (never fitted) are
    from that mean. A blind audit's separate validation flight was predicted with the mean of
    the flights' winds, 49 % off its own in y, and nothing said so."""
    each = getattr(res, "per_flight_", None) or {}
    if not each:
        return []
    mean = [k for k, v in enumerate(val) if not _own_tail(res, est, k, v)]
    if not mean:
        return []
    values = "; ".join(f"{n} {float(np.mean(d['value'])):.3g} (flights: "
                       + ", ".join(f"{x:.3g}" for x in d["value"]) + ")" for n, d in each.items())
    names = ", ".join(val[k].source or f"validation flight {k + 1}" for k in mean)
    return [f"{names} {'is' if len(mean) == 1 else 'are'} predicted with the mean of the estimation flights' own "
            f"values of {', '.join(each)} ({values}): {'its' if len(mean) == 1 else 'their'} own were never "
            "fitted, so the validation error counts how far they are from that mean too (a wind, a battery's "
            "charge differ from flight to flight)"]


def predict_after_fit(res, est: Sequence[FlightLog], val: Sequence[FlightLog], **kw) -> Prediction:
    """The validation prediction of a fit ``res`` on ``est``: its model on ``val``, each
    flight with its parameter vector (:func:`validation_vectors`) and the start-state options
    the fit calls for (:func:`prediction_options`), pooled."""
    return predict_flights(res.model, validation_vectors(res, est, val), val, **{**prediction_options(res), **kw})


def nrmse(model: QuadrotorModel, p: np.ndarray, log: FlightLog, horizon: float = DEFAULT_HORIZON,
          **kw) -> dict:
    """``{"nrmse": total, "channels": {name: value}}`` of the k-step-ahead prediction.

    Example::

        nrmse(model, res.p, val)                # {"nrmse": 0.05, "channels": {"x": ..., ...}}
    """
    pr = predict(model, p, log, horizon, **kw)
    return {"nrmse": pr.total, "channels": dict(pr.nrmse)}


# ------------------------------------------------------------------------------ plots
def compare_plot(pred: Prediction | Sequence[Prediction], path: str | Path,
                 labels: Sequence[str] | None = None, title: str = "") -> Path:
    """Measured vs predicted per channel (MATLAB's ``compare``), written to ``path`` (PNG).

    Writes :func:`greybox.plotting.compare`'s figure; use that for a ``Figure`` (notebooks,
    your own axes).

    Example::

        compare_plot([pred_base, pred_new], "compare.png", labels=["base", "+ ground effect"])
    """
    from .plotting import compare
    path = Path(path)
    compare(pred, path=path, labels=labels, title=title or None)
    return path


def residual_plot(pred: Prediction, path: str | Path) -> Path:
    """Prediction errors against time, and their histograms, per channel, written to ``path``.

    Writes :func:`greybox.plotting.residuals`'s figure.

    Example::

        residual_plot(predict(model, res.p, val), "residuals.png")
    """
    from .plotting import residuals
    path = Path(path)
    residuals(pred, path=path)
    return path

"""A model of the closed loop: the vehicle model flown by its controller's law, fitted to the log.

On a slow flight the logged commands carry the attitude's next half second *through the
controller*: the command moves as the measured rate does (the rate loop read backwards), and a
torque model driven by the logged commands predicts roll and pitch no better than the naive
predictor (README, "What the logged commands can tell"). What the vehicle was *asked* to do
does carry it: an autopilot's cascade (position P, velocity PI, attitude P, rate PID) turns the
setpoint and the state into the commands, and the vehicle then follows its law. This module
fits that law to the log and predicts with the vehicle model and the law in one loop.

**The law** (:class:`ControllerLaw`): the cascade linearised about hover, in the yaw-aligned
frame, one row per mixer axis of the airframe's allocation (``Airframe.allocation_matrix``:
the sum of ``w_i^2``, the roll, pitch and yaw combinations of ``w_i^2``, i.e. thrust and torque
per ``K_T`` or ``b``)::

    thrust  ~ e_z, v_z
    roll    ~ e_y, v_y, phi,   p        (e, v: position error to the setpoint and velocity,
    pitch   ~ e_x, v_x, theta, q         rotated by -psi into the yaw-aligned frame)
    yaw     ~ psi - psi_ref, r

plus a trim per axis, acting ``delay_`` after the state it reads (chosen by least squares
among 0 .. ``max_delay``, one for all axes). The gains are fitted to the logged commands (the
commands the fit sees: the CLI's are smoothed where they carry white noise, ``--input-noise``)
against the measured states (positions, a straight line through them for the velocity,
attitude, gyro; samples bridging a sensor's outage left out); a log needs the setpoint columns
:data:`SETPOINTS` (``x_ref, y_ref, z_ref`` in m, NED, ``psi_ref`` in rad; the NanoBench
importer writes them from ``sp_ctrltarget_*``). The setpoint's velocity, which a trajectory's
commander sends with it, is the slope of the logged setpoint (a centred line, so it reads
50 ms of the setpoint ahead: the setpoints are the loop's inputs over the whole window anyway).
The law is the structure of a cascade, not its exact gains: derivative filters, saturations
and the law's nonlinearity are not modelled (the rotor speeds are clipped to the range the log
flew), and the integrators are taken to hold the model in its hover (:func:`hover_commands`).
The law also has a level (``level_``, :meth:`ControllerLaw.measured_level`): the measured roll
and pitch at which the thrust is vertical. An attitude estimate's level is off (the IMU's
mounting, the accelerometer's bias; 5-28 mrad on the real Crazyflie flights) and the controller
levels the estimate, so the vehicle hovers where the estimate reads ``level_``.

**Closed-loop prediction** (:func:`closed_loop_horizon_errors`): each window's rigid-body
state is taken from the measurements as the naive predictor takes it (position and velocity
from the last 50 ms, attitude, gyro; the effects' states from the moving-horizon estimate,
:func:`greybox.validation.estimate_states`); the commands already on their way (``delay_``)
are the logged ones; from then on the law computes the commands from the *predicted* state and
the logged setpoints. The model's attitude is the thrust's: the measured one less ``level_``;
the law reads, and the prediction reports, the model's plus ``level_``. It is scored beside
the naive predictor as in :func:`greybox.validation.horizon_errors`. It answers a different
question from the open-loop prediction: not "what does the vehicle do with these commands" but
"what does the vehicle do, flown by its controller, asked for these setpoints" — the prediction
an engineer planning a manoeuvre needs, and the one a controller's gains can be checked
against.

Example::

    law = ControllerLaw().fit(model, est)             # est: logs with x_ref..psi_ref
    law.gains_["roll"], law.delay_, law.r2_
    he = closed_loop_horizon_errors(model, res.p, law, val)
    he.beats_naive("phi", 0.25)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import casadi as ca
import numpy as np

from .data import FlightLog
from .errors import GreyboxError, GreyboxInputError
from .integrate import Substeps, log_substeps, parallel_map, rk4_step
from .model import OUTPUTS, QuadrotorModel
from .rotations import rotation_matrices
from .validation import (DEFAULT_HORIZONS, DEFAULT_INIT_WINDOW, HORIZON_START_EVERY, INIT_WINDOW_DATA,
                         HorizonAccumulator, HorizonErrors, estimate_states, estimation_tails, horizon_errors,
                         horizon_windows, measured_outputs, naive_start)

__all__ = ["ControllerLaw", "closed_loop_horizon_errors", "SETPOINTS", "LAW_AXES", "LAW_FEATURES",
           "TRIM_WINDOW", "has_setpoints", "setpoint_signals", "measured_law_states", "loop_model",
           "ClosedLoopReport", "closed_loop_report", "closed_loop_or_why", "hover_commands",
           "logged_mixer_commands", "reported_horizons", "CHOICE_HORIZONS"]

SETPOINTS = ("x_ref", "y_ref", "z_ref", "psi_ref")
"""The log's extra columns a closed-loop model reads: the position setpoint (m, NED) and the
yaw setpoint (rad)."""
LAW_AXES = ("thrust", "roll", "pitch", "yaw")
LAW_FEATURES = {"thrust": ("e_z", "v_z"), "roll": ("e_y", "v_y", "phi", "p"),
                "pitch": ("e_x", "v_x", "theta", "q"), "yaw": ("e_psi", "r")}
"""Which of the state's errors each mixer axis of the law reads (module doc)."""
_FEATURE_ORDER = [f for axis in LAW_AXES for f in LAW_FEATURES[axis]]
TRIM_WINDOW = 0.25
"""s before a window's start over which the law's residual is averaged into its held trim."""
VELOCITY_WINDOW = 0.05
"""s: the positions' derivative for the fit is a straight line through this much of them on
each side (5 samples of a 100-Hz motion-capture log each way)."""


ACCELERATION_WINDOW = 0.1
"""s: the accelerations for the law's level (:attr:`ControllerLaw.level_`) are a straight line
through this much of the velocities on each side."""
LEVEL_MIN_SAMPLES = 100
"""Airborne samples with positions and attitude :meth:`ControllerLaw.measured_level` needs (a
second at 100 Hz: the level is a mean over the flight's accelerations)."""

OUTAGE_SPACINGS = 3.0
"""A measured state is interpolated for the law's fit only between measurements at most this
many of the channel's median spacings apart."""


def logged_mixer_commands(allocation: np.ndarray, log: FlightLog) -> np.ndarray:
    """The log's rotor commands in the law's coordinates (n, 4): ``allocation @ w^2`` of the
    first ``allocation.shape[1]`` inputs (the rotor speeds)."""
    return log.inputs[:, :allocation.shape[1]] ** 2 @ allocation.T


def has_setpoints(log: FlightLog) -> bool:
    """Whether ``log`` carries the setpoint columns :data:`SETPOINTS` a closed-loop model reads."""
    return all(name in log.extras for name in SETPOINTS)


def _feature_function() -> ca.Function:
    """``features(x12, ref)`` in :data:`_FEATURE_ORDER`: the errors the law reads; ``ref`` is
    the setpoint (:data:`SETPOINTS`) and the setpoint's velocity (:func:`setpoint_signals`)."""
    x = ca.SX.sym("x", 12)
    ref = ca.SX.sym("ref", 7)
    psi = x[5]
    c, s = ca.cos(psi), ca.sin(psi)
    e = x[0:3] - ref[0:3]
    v = x[6:9] - ref[4:7]
    # world -> yaw-aligned frame: rotate by -psi about z
    e_h = ca.vertcat(c * e[0] + s * e[1], -s * e[0] + c * e[1])
    v_h = ca.vertcat(c * v[0] + s * v[1], -s * v[0] + c * v[1])
    d = psi - ref[3]
    vals = {"e_z": e[2], "v_z": v[2], "e_y": e_h[1], "v_y": v_h[1], "phi": x[3], "p": x[9],
            "e_x": e_h[0], "v_x": v_h[0], "theta": x[4], "q": x[10], "e_psi": ca.atan2(ca.sin(d), ca.cos(d)),
            "r": x[11]}
    return ca.Function("law_features", [x, ref], [ca.vertcat(*[vals[f] for f in _FEATURE_ORDER])])


_FEATURES = _feature_function()


def _check_log(log: FlightLog, model: QuadrotorModel) -> None:
    where = log.source or "log"
    missing = [s for s in SETPOINTS if s not in log.extras]
    if missing:
        raise GreyboxInputError(f"{where}: a closed-loop model needs the setpoint column(s) {', '.join(missing)} "
                                f"(m, NED; psi_ref in rad)")
    if model.inputs == "controls":
        raise GreyboxInputError(f"{where}: a closed-loop model needs rotor-speed inputs w1..wN")
    for s in SETPOINTS:
        if not np.isfinite(log.extras[s]).all():
            k = int(np.flatnonzero(~np.isfinite(log.extras[s]))[0])
            raise GreyboxInputError(f"{where}: column {s!r} at t = {log.t[k]:.3f} s: a setpoint may not be missing")
    if model.command_names != list(log.input_names[:model.airframe.n_rotors]):
        raise GreyboxInputError(f"{where}: inputs {','.join(log.input_names)} do not start with the model's "
                                f"rotor speeds {','.join(model.command_names)}")


def setpoint_signals(log: FlightLog) -> np.ndarray:
    """(n, 7): the setpoint :data:`SETPOINTS` and its velocity (the slope of a straight line
    through :data:`VELOCITY_WINDOW` of it on each side), which a trajectory's commander sends
    with it: the velocity loop acts on ``v - v_ref``."""
    ref = np.column_stack([log.extras[s] for s in SETPOINTS])
    dt = float(np.median(np.diff(log.t)))
    m = max(1, int(round(VELOCITY_WINDOW / dt)))
    vel = np.column_stack([_local_slope(log.t, ref[:, j], m) for j in range(3)])
    return np.hstack([ref, vel])


def measured_law_states(log: FlightLog) -> np.ndarray:
    """The 12 rigid-body states from the measurements (n, 12; NaN where they cannot be had):
    positions and angles interpolated between measurements (not across an outage: longer than
    :data:`OUTAGE_SPACINGS` of the channel's spacing), velocities the slope of a straight line
    through :data:`VELOCITY_WINDOW` of positions on each side, rates from the gyro (from the
    angles' derivative without one)."""
    t = log.t
    n = t.size
    S = np.full((n, 12), np.nan)

    def filled(name):
        y = log.output(name).astype(float)
        k = np.isfinite(y)
        if k.sum() < 2:
            return np.full(n, np.nan)
        tk = t[k]
        yk = np.unwrap(y[k]) if name == "psi" else y[k]
        out = np.interp(t, tk, yk)
        # only between measurements at most OUTAGE_SPACINGS of the channel's own spacing apart
        # (np.interp would bridge a vision outage with a straight line, and hold the ends)
        j = np.clip(np.searchsorted(tk, t), 1, tk.size - 1)
        span = tk[j] - tk[j - 1]
        inside = (t >= tk[0]) & (t <= tk[-1])
        out[~inside | (span > OUTAGE_SPACINGS * float(np.median(np.diff(tk))) + 1e-12)] = np.nan
        return out

    for j, name in enumerate(("x", "y", "z", "phi", "theta", "psi")):
        if log.measures(name):
            S[:, j] = filled(name)
    dt = float(np.median(np.diff(t)))
    m = max(1, int(round(VELOCITY_WINDOW / dt)))
    for j in range(3):
        S[:, 6 + j] = _local_slope(t, S[:, j], m)
    for j, name in enumerate(("p", "q", "r")):
        if log.measures(name):
            S[:, 9 + j] = filled(name)
        else:
            S[:, 9 + j] = _local_slope(t, S[:, 3 + j], m)
    return S


def _local_slope(t: np.ndarray, y: np.ndarray, m: int) -> np.ndarray:
    """Least-squares slope of ``y`` over its finite samples among ``k-m .. k+m`` at every ``k``
    (NaN where ``y[k]`` is missing or fewer than ``m + 1`` samples are finite there)."""
    n = t.size
    fin = np.isfinite(y)
    if not fin.any():
        return np.full(n, np.nan)
    lo = np.clip(np.arange(n) - m, 0, n)
    hi = np.clip(np.arange(n) + m + 1, 0, n)

    # windowed sums by cumulative sums (a missing sample weighs nothing): no loop over samples
    def wsum(a):
        c = np.concatenate([[0.0], np.cumsum(a)])
        return c[hi] - c[lo]
    tc = t - t[0]
    w = fin.astype(float)
    y0 = np.where(fin, y, 0.0)
    N, St, Sy, Stt, Sty = wsum(w), wsum(w * tc), wsum(y0), wsum(w * tc * tc), wsum(tc * y0)
    den = N * Stt - St * St
    ok = fin & (N >= m + 1) & (den > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ok, (N * Sty - St * Sy) / np.where(ok, den, 1.0), np.nan)


class _LawData(NamedTuple):
    """One log's rows for the law's regression."""
    features: np.ndarray      # (n, 12) in _FEATURE_ORDER, NaN where a state is not had
    commands: np.ndarray      # (n, 4) mixer coordinates
    airborne: np.ndarray      # (n,) bool
    dt: float                 # the log's median sample time


@dataclass(eq=False)
class ControllerLaw:
    """A cascaded position and attitude controller's law, linear about hover, fitted to the
    commands of logs with setpoints (module doc).

    Parameters:
        delay: the law's delay in s; ``None`` chooses it among 0 .. ``max_delay`` in steps
            of the (first) log's sample time by the least-squares residual. Each log reads it
            in its own samples.
        max_delay: s.
        fit_level: estimate the attitude estimate's level (``level_``); False: take the
            measured attitude for the thrust's.
        axis_delays: each axis' delay chosen by its own least squares (``delays_``); False:
            one for all (the default: on the ten NanoBench flights the thrust axis then takes
            the longest allowed and predicts height better, but B6_linear_ramp's roll takes
            90 ms and its loop swings; README); or the names of the axes (of
            :data:`LAW_AXES`) that get their own, the rest sharing the joint one
            (``("thrust",)``).

    Fitted attributes: ``gains_`` (axis -> gains on :data:`LAW_FEATURES` [axis]), ``trims_``
    (4,), ``delay_`` (s; the joint one), ``delays_`` (4,: each axis', s), ``r2_`` (axis ->
    share of the commands' variance the law explains),
    ``level_`` (2,: the measured roll and pitch, rad, at which the thrust is vertical:
    :meth:`measured_level`), ``allocation_`` (4 x N), ``w_range_`` (the rotor speeds the logs
    flew).

    Example::

        est, val = log.split(0.8)                  # a log with x_ref, y_ref, z_ref, psi_ref
        law = ControllerLaw().fit(model, est)
        law.gains_["roll"], law.delay_, law.r2_    # gains on e_y, v_y, phi, p
    """

    delay: float | None = None
    max_delay: float = 0.15
    fit_level: bool = True
    axis_delays: bool | tuple[str, ...] = False
    gains_: dict[str, np.ndarray] = field(default_factory=dict, init=False)
    trims_: np.ndarray | None = field(default=None, init=False)
    delay_: float = field(default=float("nan"), init=False)
    delays_: np.ndarray = field(default_factory=lambda: np.full(4, np.nan), init=False)
    r2_: dict[str, float] = field(default_factory=dict, init=False)
    level_: np.ndarray = field(default_factory=lambda: np.zeros(2), init=False)
    allocation_: np.ndarray | None = field(default=None, init=False)
    w_range_: tuple[float, float] = field(default=(0.0, math.inf), init=False)

    # ------------------------------------------------------------------ fitting
    def fit(self, model: QuadrotorModel, logs: "FlightLog | Sequence[FlightLog]") -> "ControllerLaw":
        """Fit the law's gains and trims to the logged commands of ``logs`` (each with the
        setpoint columns :data:`SETPOINTS`)."""
        logs = [logs] if isinstance(logs, FlightLog) else list(logs)
        if not logs:
            raise GreyboxInputError("ControllerLaw.fit needs at least one log")
        for name, v in (("delay", self.delay), ("max_delay", self.max_delay)):
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise GreyboxInputError(f"ControllerLaw: {name} must be a time >= 0 s, got {v!r}")
        own = self.own_delay_axes()
        A = model.airframe.allocation_matrix()
        nr = model.airframe.n_rotors
        data = []
        for log in logs:
            _check_log(log, model)
            airborne = np.ones(log.t.size, dtype=bool)
            if "on_ground" in log.extras:
                airborne = log.extras["on_ground"] < 0.5
            data.append(_LawData(self._features_measured(log), logged_mixer_commands(A, log), airborne,
                                 float(np.median(np.diff(log.t)))))
        dt = data[0].dt
        delays = [self.delay] if self.delay is not None else \
            [k * dt for k in range(int(round(self.max_delay / dt)) + 1)]
        fits = [fitd + (delay,) for delay in delays if (fitd := self._regress(data, delay)) is not None]
        if not fits:
            raise GreyboxInputError("ControllerLaw.fit: too few airborne samples with every state measured "
                                    f"{'(is the delay longer than the logs?)' if self.delay else ''}")
        # the first of equal scores: the shortest delay, as a strict '<' over the delays in order
        _, gains, trims, r2, delay = min(fits, key=lambda f: f[0])
        self.gains_, self.trims_, self.r2_, self.delay_ = dict(gains), trims.copy(), dict(r2), float(delay)
        self.delays_ = np.full(4, float(delay))
        for i, axis in enumerate(LAW_AXES):
            if axis in own:
                _, g, tr, r, dl = max(fits, key=lambda f: f[3][axis])
                self.gains_[axis], self.trims_[i], self.r2_[axis], self.delays_[i] = g[axis], tr[i], r[axis], dl
        self.level_ = self.measured_level(logs, model.airframe.gravity) if self.fit_level else np.zeros(2)
        self.allocation_ = A
        w = np.concatenate([log.inputs[:, :nr].ravel() for log in logs])
        self.w_range_ = (float(np.min(w)), float(np.max(w)))
        return self

    def own_delay_axes(self) -> tuple[str, ...]:
        """The axes (of :data:`LAW_AXES`) whose delay :meth:`fit` chooses by their own least
        squares (``axis_delays``)."""
        a = self.axis_delays
        if isinstance(a, (bool, np.bool_)):
            return tuple(LAW_AXES) if a else ()
        names = (a,) if isinstance(a, str) else tuple(a)
        bad = [n for n in names if n not in LAW_AXES]
        if bad:
            raise GreyboxInputError(f"ControllerLaw: axis_delays names {', '.join(map(repr, bad))}: not an axis of "
                                    f"the law ({', '.join(LAW_AXES)})")
        return names

    def delay_samples(self, dt: float) -> int:
        """The law's delay in samples of a log with sample time ``dt``."""
        self._check_fitted()
        return int(round(self.delay_ / dt))

    def axis_delay_samples(self, dt: float) -> np.ndarray:
        """Each axis' delay (:data:`LAW_AXES`) in samples of a log with sample time ``dt``."""
        self._check_fitted()
        return np.rint(self.delays_ / dt).astype(int)

    @staticmethod
    def measured_level(logs: "FlightLog | Sequence[FlightLog]", gravity: float = 9.81) -> np.ndarray:
        """The measured roll and pitch (rad) at which the thrust is vertical: an attitude
        estimate's level is off by its IMU's mounting and its accelerometer's bias (on the ten
        NanoBench flights by 5-28 mrad), and the controller levels the estimate, so the vehicle
        hovers at the measured attitude ``level_``. From the specific force the positions give,
        ``f = a - g e3`` in the measured body frame: a thrust along the true body axis reads
        ``f_x = |f| theta_0``, ``f_y = -|f| phi_0`` there, less a drag on the body velocity
        (its own coefficient per axis, so that a flight with a mean speed does not put its drag
        into the level; a flight at one steady speed cannot tell the two apart); least squares
        over the airborne samples of all ``logs``."""
        logs = [logs] if isinstance(logs, FlightLog) else list(logs)
        rows = []
        for log in logs:
            S = measured_law_states(log)
            m = max(1, int(round(ACCELERATION_WINDOW / float(np.median(np.diff(log.t))))))
            acc = np.column_stack([_local_slope(log.t, S[:, 6 + j], m) for j in range(3)])
            k = np.isfinite(acc).all(1) & np.isfinite(S[:, :9]).all(1)
            if "on_ground" in log.extras:
                k &= log.extras["on_ground"] < 0.5
            if not k.any():
                continue
            R = rotation_matrices(S[k, 3], S[k, 4], S[k, 5])
            f_world = acc[k] - np.array([0.0, 0.0, gravity])
            f_body = np.einsum("nji,nj->ni", R, f_world)
            v_body = np.einsum("nji,nj->ni", R, S[k, 6:9])
            rows.append(np.column_stack([np.linalg.norm(f_world, axis=1), v_body[:, :2], f_body[:, :2]]))
        X = np.vstack(rows) if rows else np.zeros((0, 5))
        if X.shape[0] < LEVEL_MIN_SAMPLES:
            raise GreyboxInputError(f"the attitude estimate's level needs {LEVEL_MIN_SAMPLES} airborne samples with "
                                    f"positions and attitude measured; the log(s) have {X.shape[0]}")
        level = np.zeros(2)
        for j, sign, out in ((0, 1.0, 1), (1, -1.0, 0)):       # f_x -> pitch, f_y -> -roll
            coef, *_ = np.linalg.lstsq(X[:, [0, 1 + j]], X[:, 3 + j], rcond=None)
            level[out] = sign * coef[0]
        return level

    @staticmethod
    def _features_measured(log: FlightLog) -> np.ndarray:
        states = measured_law_states(log)
        ref = setpoint_signals(log)
        ok = np.isfinite(states).all(1) & np.isfinite(ref).all(1)
        out = np.full((log.t.size, len(_FEATURE_ORDER)), np.nan)
        if ok.any():
            out[ok] = np.asarray(_FEATURES.map(int(ok.sum()))(states[ok].T, ref[ok].T)).T
        return out

    @staticmethod
    def _regress(data: Sequence[_LawData], delay: float):
        """Least squares of each axis' command on its features ``delay`` s earlier (each log in
        its own samples); returns (summed unexplained shares, gains, trims, r2) or None."""
        rows_f, rows_c = [], []
        for feats, c, air, dt in data:
            n, d = c.shape[0], int(round(delay / dt))
            if n <= d + 1:
                continue
            f = feats[:n - d]
            k = np.isfinite(f).all(1) & air[d:] & air[:n - d]
            rows_f.append(f[k])
            rows_c.append(c[d:][k])
        if not rows_f:
            return None
        F = np.vstack(rows_f)
        C = np.vstack(rows_c)
        if F.shape[0] < 10 * len(_FEATURE_ORDER):
            return None
        gains, trims, r2, score = {}, np.zeros(4), {}, 0.0
        for i, axis in enumerate(LAW_AXES):
            cols = [_FEATURE_ORDER.index(f) for f in LAW_FEATURES[axis]]
            X = np.column_stack([F[:, cols], np.ones(F.shape[0])])
            coef, *_ = np.linalg.lstsq(X, C[:, i], rcond=None)
            res = C[:, i] - X @ coef
            var = float(np.var(C[:, i]))
            share = float(np.mean(res ** 2)) / var if var > 0 else 0.0
            gains[axis], trims[i], r2[axis] = coef[:-1], coef[-1], 1.0 - share
            score += share
        return score, gains, trims, r2

    # ------------------------------------------------------------------ the law
    @property
    def gain_matrix_(self) -> np.ndarray:
        """(4, 12) gains on the features in the order of :data:`LAW_FEATURES`."""
        gm = np.zeros((4, len(_FEATURE_ORDER)))
        for i, axis in enumerate(LAW_AXES):
            for g, f in zip(self.gains_[axis], LAW_FEATURES[axis]):
                gm[i, _FEATURE_ORDER.index(f)] = g
        return gm

    def mixer_commands(self, states: np.ndarray, setpoints: np.ndarray) -> np.ndarray:
        """The law's commands in mixer coordinates (n, 4) for rigid-body ``states`` (n, 12)
        and setpoints with their velocity (n, 7; :func:`setpoint_signals`), with the fitted
        trims (no delay)."""
        self._check_fitted()
        feats = np.asarray(_FEATURES.map(states.shape[0])(states.T, setpoints.T)).T
        return feats @ self.gain_matrix_.T + self.trims_

    def residual_trims(self, log: FlightLog, starts: Sequence[int],
                       window: float = TRIM_WINDOW) -> np.ndarray:
        """Held trims (len(starts), 4): the fitted trims plus the law's mean residual over
        ``window`` seconds before each start (the integrators' output just then)."""
        self._check_fitted()
        feats = self._features_measured(log)
        c = logged_mixer_commands(self.allocation_, log)
        dt = float(np.median(np.diff(log.t)))
        pred = np.full_like(c, np.nan)
        for i, d in enumerate(self.axis_delay_samples(dt)):
            pred[d:, i] = feats[:c.shape[0] - d] @ self.gain_matrix_[i] + self.trims_[i]
        res = c - pred
        m = max(1, int(round(window / dt)))
        out = np.tile(self.trims_, (len(starts), 1))
        for w, a in enumerate(starts):
            r = res[max(0, a - m):a]
            r = r[np.isfinite(r).all(1)]
            if r.size:
                out[w] += r.mean(0)
        return out

    def _check_fitted(self) -> None:
        if not self.gains_:
            raise GreyboxInputError("the ControllerLaw is not fitted: call .fit(model, logs) first")

    def __repr__(self) -> str:
        if not self.gains_:
            return "ControllerLaw(not fitted)"
        r2 = ", ".join(f"{a} {self.r2_[a]:.2f}" for a in LAW_AXES)
        return (f"ControllerLaw(delay {1e3 * self.delay_:.0f} ms; R^2 {r2}; level {1e3 * self.level_[0]:.1f}, "
                f"{1e3 * self.level_[1]:.1f} mrad)")

    # ------------------------------------------------------------------ closed-loop step
    def closed_loop_step(self, model: QuadrotorModel, n_sub: "int | Substeps",
                         delay_samples: "int | Sequence[int]") -> ca.Function:
        """``F(xb, ref, trim, sig, p, t, h, shift) -> (xb_next, y)``: one sample of the vehicle
        model flown by the law with its axes ``delay_samples`` late (one for all or one per
        axis of :data:`LAW_AXES`); ``xb`` is the model's state and the commands computed in the
        last ``d = max(delay_samples)`` samples (``4 d``, oldest first; axis ``i`` acts on the
        one computed ``delay_samples[i]`` ago), ``ref`` the setpoint and its velocity,
        ``sig`` the model's other inputs (logged signals), ``shift`` (2) what is added to the
        model's measured roll and pitch to make them the estimate's (``level_`` less the model's
        own offset, e.g. an ``attitude_bias``). The law reads the estimate: the model's attitude
        plus ``level_``."""
        self._check_fitted()
        nr = model.airframe.n_rotors
        d_axes = np.broadcast_to(np.asarray(delay_samples, dtype=int), (4,))
        d = int(d_axes.max())
        step = rk4_step(model, n_sub)
        nsig = model.nu - nr
        xb = ca.MX.sym("xb", model.nx + 4 * d)
        ref = ca.MX.sym("ref", 7)
        trim = ca.MX.sym("trim", 4)
        sig = ca.MX.sym("sig", nsig)
        p = ca.MX.sym("p", model.n_params)
        t = ca.MX.sym("t")
        h = ca.MX.sym("h")
        shift = ca.MX.sym("shift", 2)
        x = xb[:model.nx]
        read = x[:12] + ca.DM(np.concatenate([np.zeros(3), self.level_, np.zeros(7)]))
        c_new = ca.mtimes(ca.DM(self.gain_matrix_), _FEATURES(read, ref)) + trim
        # axis i acts on the command computed d_i samples ago: buffer entry d - d_i (oldest first)
        c_now = ca.vertcat(*[c_new[i] if d_axes[i] == 0 else xb[model.nx + 4 * (d - int(d_axes[i])) + i]
                             for i in range(4)])
        w2 = ca.mtimes(ca.DM(np.linalg.pinv(self.allocation_)), c_now)
        lo, hi = self.w_range_
        w = ca.fmin(ca.sqrt(ca.fmax(w2, lo * lo)), hi)
        u = ca.vertcat(w, sig)
        x_next = step(x, u, p, t, h)
        buf_next = ca.vertcat(xb[model.nx + 4:], c_new) if d else ca.MX(0, 1)
        y = model.output(x, u, p, t)
        i = OUTPUTS.index("phi")
        y = ca.vertcat(y[:i], y[i:i + 2] + shift, y[i + 2:])
        return ca.Function("closed_loop_step", [xb, ref, trim, sig, p, t, h, shift],
                           [ca.vertcat(x_next, buf_next), y], ["xb", "ref", "trim", "sig", "p", "t", "h", "shift"],
                           ["xb_next", "y"])

    def level_trims(self) -> np.ndarray:
        """(4,): the law's commands at its level (:attr:`level_`) with every error nil: what
        the integrators cancel so that the vehicle holds a hover the estimate reads as level_."""
        self._check_fitted()
        feats = np.zeros(len(_FEATURE_ORDER))
        feats[_FEATURE_ORDER.index("phi")], feats[_FEATURE_ORDER.index("theta")] = self.level_
        return self.gain_matrix_ @ feats


def loop_model(model: QuadrotorModel, p: np.ndarray) -> tuple[QuadrotorModel, np.ndarray, float, list[str]]:
    """The model the closed loop flies, its parameters, the delay (s) added to the law's, and
    the effects left out.

    Effects that read the log's earlier or later commands (derived signals: a command delay,
    sampled inputs) describe how the *logged* commands reach the rotors; the loop's commands
    are held values it computes itself, so these effects are left out, and a delay among their
    input-timed parameters (in s) is added to the law's (the rotors act on the loop's commands
    that much later)."""
    names = model.param_names
    p = np.asarray(p, dtype=float)
    extra, left_out = 0.0, []
    for e in model.effects:
        if not e.derived_signals(model.command_names):
            continue
        left_out.append(e.name)
        for par, comp, null in model.effect_components(e.name):
            if par.name in e.input_timed and par.unit == "s":
                extra += float(p[names.index(comp)]) - null
    if not left_out:
        return model, p, 0.0, []
    flown = model.without(*left_out)
    return flown, np.array([p[names.index(n)] for n in flown.param_names]), extra, left_out


HOVER_NEWTON_STEPS = 4
"""Newton steps of :func:`hover_commands` (the model's forces are nearly linear in ``w^2``:
two reach a millionth of the weight)."""


def hover_commands(model: QuadrotorModel, p: np.ndarray, allocation: np.ndarray, start: np.ndarray,
                   log: FlightLog, samples: Sequence[int], positions: np.ndarray) -> np.ndarray:
    """The mixer commands (len(samples), 4) that hold ``model`` still and level at each of the
    log's ``samples``: at its time, its logged signals (battery voltage) and ``positions``
    (height: a ground effect), with the effects' states steady at those speeds (a motor lag).
    Newton's method on the vertical and angular accelerations from ``start`` (4,), with a
    finite-difference Jacobian (an effect's steady state is no symbolic function of the
    commands). Which commands are the trim depends on time and signals: a thrust that drifts
    or follows the battery needs more command later in a flight."""
    nr = model.airframe.n_rotors
    pinv = np.linalg.pinv(allocation)
    rhs = model.rhs
    held = [8, 9, 10, 11]                      # vz, p, q, r: their derivatives vanish in a hover
    scale = np.maximum(np.abs(start), 1e-3 * abs(start[0]) + 1e-12)
    out = np.empty((len(samples), 4))

    def accelerations(c, x12, sig, t):
        w = np.sqrt(np.maximum(pinv @ c, 0.0))
        u = np.concatenate([w, sig])
        x = model.initial_state(x12, u, p)
        return np.asarray(rhs(x, u, p, t)).ravel()[held]

    for k, a in enumerate(samples):
        x12 = np.zeros(12)
        x12[0:3] = positions[k]
        sig, t = log.inputs[a, nr:], float(log.t[a])
        c = np.array(start, dtype=float)
        for _ in range(HOVER_NEWTON_STEPS):
            r0 = accelerations(c, x12, sig, t)
            J = np.empty((4, 4))
            for j in range(4):
                dc = np.zeros(4)
                dc[j] = 1e-6 * scale[j]
                J[:, j] = (accelerations(c + dc, x12, sig, t) - r0) / dc[j]
            c = c - np.linalg.lstsq(J, r0, rcond=None)[0]
        out[k] = c
    return out


def closed_loop_horizon_errors(model: QuadrotorModel, p: "np.ndarray | Sequence[np.ndarray]", law: ControllerLaw,
                               logs: "FlightLog | Sequence[FlightLog]", horizons: Sequence[float] | None = None,
                               start_every: float = HORIZON_START_EVERY, init_window: float = DEFAULT_INIT_WINDOW,
                               held_trim: bool = False, trim: str = "model", measured_start: bool = True,
                               compile: str = "auto") -> HorizonErrors:
    """Prediction error against horizon of ``model`` (parameters ``p``, one vector or one per
    log) flown by the fitted ``law`` from the logged setpoints, beside the naive predictor's,
    over windows started every ``start_every`` s (as :func:`greybox.validation.horizon_errors`;
    module doc).

    ``measured_start``: each window's rigid-body state from the measurements as the naive
    predictor takes it (the effects' states from the moving-horizon estimate), else all from the
    estimate. ``trim``: ``"model"`` (the integrators hold the model in its own hover trim) or
    ``"law"`` (the law's fitted trims, which also cancel what the vehicle has and the model may
    lack). ``held_trim``: add the law's mean residual over :data:`TRIM_WINDOW` before each start
    (:meth:`ControllerLaw.residual_trims`: the integrators' state then). The defaults are the
    best of these on the ten NanoBench flights (README).

    Example::

        res = fit(model, est)
        law = ControllerLaw().fit(model, est)
        he = closed_loop_horizon_errors(model, res.p, law, val)
        he.beats_naive("phi", 0.5), he.as_dict()
    """
    law._check_fitted()
    if trim not in ("model", "law"):
        raise GreyboxInputError(f"closed_loop_horizon_errors: trim must be 'model' or 'law', not {trim!r}")
    logs = [logs] if isinstance(logs, FlightLog) else list(logs)
    ps = [p] * len(logs) if isinstance(p, np.ndarray) and p.ndim == 1 else list(p)
    hs_req = sorted(horizons or DEFAULT_HORIZONS)
    nr = model.airframe.n_rotors
    acc = None
    left_out: list[str] = []
    loop_delays = []
    for pk, log in zip(ps, logs):
        _check_log(log, model)
        log = model.prepare_log(log)
        t = log.t
        dt = float(np.median(np.diff(t)))
        if acc is None:
            channels = [name for name in OUTPUTS if name in log.output_names]
            acc = HorizonAccumulator(sorted({round(dt, 9), *hs_req}), channels, dt)
        pk = np.asarray(pk, dtype=float)
        flown, p_loop, extra_s, left_out = loop_model(model, pk)
        extra = int(round(extra_s / dt))
        d_axes = law.axis_delay_samples(dt) + extra
        d = int(d_axes.max())
        loop_delays.append(d)
        L, n_steps, starts = horizon_windows(log, max(acc.hs), init_window, start_every)
        # the effects' states from the moving-horizon estimate of the model as fitted
        x0 = estimate_states(model, pk, log, starts, L, None, compile=compile)
        meas = measured_outputs(log, model.ny)
        if measured_start:
            # the rigid body entirely from the measurements, as the naive predictor takes it: a
            # closed loop forgives a start, not a wrong one
            for w, a in enumerate(starts):
                pv, eul, _, om = naive_start(log, meas, a, x0[w])
                x0[w, 0:3], x0[w, 6:9], x0[w, 3:6], x0[w, 9:12] = pv[:3], pv[3:], eul, om
        x0 = x0[:, [model.state_names.index(n) for n in flown.state_names]]
        naive_x0 = x0.copy()
        flown_log = flown.prepare_log(log)
        # the estimate's level: the model's attitude is the thrust's, the measured one is off by
        # level_ (the model's own measured offset, an attitude_bias, is replaced by it)
        model_level = np.asarray(flown.output(flown.initial_state(np.zeros(12), flown_log.inputs[starts[0]], p_loop),
                                              flown_log.inputs[starts[0]], p_loop, 0.0)).ravel()[3:5]
        shift = law.level_ - model_level
        # measured start: the model's attitude is the measured one less level_; estimated: the
        # model's estimate (its outputs: its attitude plus model_level) less the shift
        x0[:, 3:5] -= law.level_ if measured_start else shift
        A = law.allocation_
        c_logged = logged_mixer_commands(A, log)
        # the commands acting in the first d samples were computed from states before the start:
        # the logged ones, the rotors' delay (extra) after they were logged
        # (entry j stands for the command computed j - d samples from the start; axis i acts on
        # it at sample j - d + d_i, where the logged command is the one acting)
        buf0 = np.zeros((len(starts), 4 * d))
        for j in range(d):
            for i in range(4):
                buf0[:, 4 * j + i] = c_logged[np.clip(starts + j - d + d_axes[i] - extra, 0, t.size - 1), i]
        trims = law.residual_trims(log, starts) if held_trim else np.tile(law.trims_, (len(starts), 1))
        if trim == "model":
            # the integrators hold the model in its hover: the law's trims are the model's, not
            # the vehicle's (which trim out what the model may lack, e.g. a CoG offset)
            # (at the level the law reads, level_)
            trims = (trims - law.trims_ - law.level_trims()
                     + hover_commands(flown, p_loop, A, law.trims_, flown_log, starts, x0[:, :3]))
        step_fn = law.closed_loop_step(flown, log_substeps([log]), d_axes)
        nW = len(starts)
        windows = parallel_map(step_fn.mapaccum("closed_loop", n_steps, [0], [0]), nW)
        idx = np.minimum(starts[:, None] + np.arange(n_steps)[None, :], t.size - 1)
        nxt = np.minimum(idx + 1, t.size - 1)
        h = (t[nxt] - t[idx]).ravel()[None, :]
        ref = setpoint_signals(log)[idx.ravel()].T
        sig = flown_log.inputs[idx.ravel(), nr:].T
        trim_rep = np.repeat(trims, n_steps, axis=0).T
        _, Y = windows(np.hstack([x0, buf0]).T, ref, trim_rep, sig, np.tile(p_loop[:, None], (1, nW * n_steps)),
                       t[idx.ravel()][None, :], h, np.tile(shift[:, None], (1, nW * n_steps)))
        acc.add_windows(log, meas, starts, np.asarray(Y).reshape(flown.ny, nW, n_steps).transpose(1, 2, 0), naive_x0)
    out = acc.result()
    out.predictor = {"init_window": float(init_window), "measured_start": bool(measured_start),
                     "closed_loop": True, "held_trim": bool(held_trim), "law_delay": float(law.delay_),
                     "loop_delay_samples": loop_delays, "left_out": left_out,
                     "level": [float(v) for v in law.level_]}
    return out


CHOICE_HORIZONS = (0.25, 0.5)
"""s ahead at which :func:`closed_loop_report` compares the closed loop with the open loop on
the estimation flights (the horizons the naive predictor is beaten at)."""


@dataclass
class ClosedLoopReport:
    """A fitted model flown by its controller's law on the validation flights: the law
    (:class:`ControllerLaw`, fitted to the estimation flights) and the prediction error against
    horizon (:class:`~greybox.validation.HorizonErrors`, beside the naive predictor).

    ``preferred``: the closed loop predicts the last :data:`~greybox.validation.INIT_WINDOW_DATA`
    seconds of the estimation flights better than the model open loop (its error relative to
    the naive predictor's at :data:`CHOICE_HORIZONS`, ``estimation_errors``: ``{"open_loop":
    r, "closed_loop": r}``), so that it is the model's prediction the reports give
    (:func:`reported_horizons`). Chosen on the estimation data: validation stays out of it."""

    law: ControllerLaw
    horizons: HorizonErrors
    preferred: bool = False
    estimation_errors: dict = field(default_factory=dict)

    def beats(self, horizon: float) -> list[str]:
        """The position and attitude channels where the closed loop beats the naive predictor."""
        return [ch for ch in OUTPUTS[:6] if ch in self.horizons.model and self.horizons.beats_naive(ch, horizon)]

    def as_dict(self) -> dict:
        """The JSON's ``closed_loop``: ``horizons`` (as the contract's ``horizons``), the
        ``law`` (delay in s, each axis' delay, gains per axis and feature, trims and R² per
        axis, the level: the measured roll and pitch in rad at which the thrust is vertical), how
        the windows were flown (``predictor``), whether it is the model's reported prediction
        (``preferred``) and the errors relative to naive on the estimation flights that chose
        it (``estimation_errors``)."""
        law = self.law
        return {"horizons": self.horizons.as_dict(),
                "law": {"delay": float(law.delay_),
                        "delays": {a: float(v) for a, v in zip(LAW_AXES, law.delays_)},
                        "gains": {a: {f: float(g) for f, g in zip(LAW_FEATURES[a], law.gains_[a])} for a in LAW_AXES},
                        "trims": {a: float(v) for a, v in zip(LAW_AXES, law.trims_)},
                        "r2": {a: float(law.r2_[a]) for a in LAW_AXES},
                        "level": [float(v) for v in law.level_]},
                "predictor": dict(self.horizons.predictor),
                "preferred": bool(self.preferred),
                "estimation_errors": {k: (float(v) if math.isfinite(v) else None)
                                      for k, v in self.estimation_errors.items()}}

    def line(self) -> str:
        """One line for a summary: what the closed loop beats the naive predictor on."""
        law = self.law
        beats = "; ".join(f"{h:g} s: {', '.join(self.beats(h)) or 'none'}" for h in (0.25, 0.5)
                          if any(abs(x - h) < 1e-9 for x in self.horizons.horizons))
        why = ""
        if self.preferred:
            o, c = self.estimation_errors["open_loop"], self.estimation_errors["closed_loop"]
            why = (f" (the model's reported prediction: on the estimation flights' last {INIT_WINDOW_DATA:g} s its "
                   f"error is {c:.2f} of the naive predictor's, open loop {o:.2f})")
        return (f"   flown by its controller's law (fitted to the logged commands and setpoints: delay "
                f"{1e3 * law.delay_:.0f} ms, R² roll {law.r2_['roll']:.2f}, pitch {law.r2_['pitch']:.2f}), "
                f"the model beats the naive predictor on {beats}{why}")


def reported_horizons(open_loop: HorizonErrors, closed: "ClosedLoopReport | None") -> HorizonErrors:
    """The model's error against horizon that the reports give (the contract's ``horizons``):
    the closed loop's where it predicts the estimation flights better (``closed.preferred``),
    else the open loop's."""
    return closed.horizons if closed is not None and closed.preferred else open_loop


def _estimation_errors(model: QuadrotorModel, est_ps: Sequence[np.ndarray], est: Sequence[FlightLog],
                       law: ControllerLaw, open_options: dict, compile: str) -> dict:
    """The open loop's (with ``open_options``, as its report predicts) and the closed loop's
    error relative to naive on the last seconds of the estimation flights."""
    tails = estimation_tails(est)
    open_he = horizon_errors(model, list(est_ps), tails, horizons=CHOICE_HORIZONS, compile=compile,
                             **{k: open_options[k] for k in ("init_window", "measured_start", "held_moment")
                                if k in open_options})
    closed_he = closed_loop_horizon_errors(model, list(est_ps), law, tails, horizons=CHOICE_HORIZONS, compile=compile)
    return {"open_loop": open_he.relative_error(CHOICE_HORIZONS), "closed_loop": closed_he.relative_error(CHOICE_HORIZONS)}


def closed_loop_report(model: QuadrotorModel, ps: Sequence[np.ndarray], est: Sequence[FlightLog],
                       val: Sequence[FlightLog], horizons: Sequence[float] | None = None,
                       compile: str = "auto", open_loop: HorizonErrors | None = None,
                       est_ps: Sequence[np.ndarray] | None = None) -> ClosedLoopReport | None:
    """The closed-loop prediction of a fitted model (``ps``: its parameters per validation
    flight) on ``val`` with a law fitted to ``est``, or None when a log has no setpoints or
    the model's inputs are no rotor speeds (nothing to fly it with).

    Given the open loop's report ``open_loop`` (its ``predictor``: how its windows start), the
    two are also compared on the last seconds of the estimation flights (``est_ps``: the
    parameters per estimation flight; ``ps`` when as many, else the first) and the report says
    whether the closed loop is the better predictor there (``preferred``)."""
    logs = list(est) + list(val)
    if not logs or not all(has_setpoints(log) for log in logs) or model.inputs == "controls":
        return None
    law = ControllerLaw().fit(model, list(est))
    report = ClosedLoopReport(law, closed_loop_horizon_errors(model, list(ps), law, list(val), horizons=horizons,
                                                              compile=compile))
    if open_loop is not None:
        if est_ps is None:
            est_ps = list(ps) if len(ps) == len(est) else [ps[0]] * len(est)
        try:
            errors = _estimation_errors(model, est_ps, list(est), law, open_loop.predictor, compile)
        except (GreyboxError, RuntimeError, np.linalg.LinAlgError, ValueError):
            # the comparison is a choice of the report only: where it cannot be made, the open loop stands
            errors = {}
        report.estimation_errors = errors
        o, c = errors.get("open_loop", math.nan), errors.get("closed_loop", math.nan)
        report.preferred = bool(math.isfinite(c) and (c < o or not math.isfinite(o)))
        report.horizons.predictor["preferred"] = report.preferred
    return report


def closed_loop_or_why(model: QuadrotorModel, ps: Sequence[np.ndarray], est: Sequence[FlightLog],
                       val: Sequence[FlightLog], horizons: Sequence[float] | None = None,
                       compile: str = "auto", open_loop: HorizonErrors | None = None,
                       est_ps: Sequence[np.ndarray] | None = None) -> tuple[ClosedLoopReport | None, str]:
    """:func:`closed_loop_report` for the commands that add it to a finished fit or diagnosis:
    the report, or None and why not in words ("" when the logs simply have no setpoints). The
    closed loop is an extra: a law the logs cannot give or a loop that cannot be flown (a
    solver's failure) must not cost the user the fit itself."""
    try:
        return closed_loop_report(model, ps, est, val, horizons=horizons, compile=compile, open_loop=open_loop,
                                  est_ps=est_ps), ""
    except (GreyboxError, RuntimeError, np.linalg.LinAlgError) as err:
        return None, f"the model flown by its controller's law was not predicted: {err}"

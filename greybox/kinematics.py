"""The gyro against the attitude, from the log alone: whether the gyro's rates, integrated,
turn the vehicle as far as the measured attitude says it turned.

A gyro whose scale is off (an uncalibrated MEMS part: 1-3 % is common) feeds the fit rates
that do not match the angles: the model's moments, ``b`` and ``K_T`` are fitted to both at
once and absorb the difference, certified and many std off (a blind audit's 0.9 kg vehicle
with its gyro 3 % high: "nothing missing", ``b`` +1.7 %, 12 std), unless the model holds the
effect ``gyro_scale``. Over spans of :data:`SPAN` seconds, the attitude's change is regressed
on the gyro's integral through the Euler-rate map, per body axis, beside a constant gyro bias
and a delay between the two sensors (a motion-capture attitude arrives late: over a span, a
delay ``tau`` looks like a scale ``cos(omega tau)`` at a motion of frequency ``omega``).

And the heading's spread over flights (:func:`heading_spread`): how much of a force fixed in
the world (a wind) no offset fixed in the body (an accelerometer's bias) can stand for; and
the logged rotor speeds' timing against the gyro (:func:`input_lead`): a body that turns before
the speeds that turn it says the speeds are stamped late.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .data import FlightLog, inside_gaps
from .rotations import euler_rate_matrices

__all__ = ["GyroScale", "gyro_scale", "gyro_bias_reading", "SPAN", "SCALE_NOTABLE", "SCALE_SIGMAS", "HINT_SIGMAS", "heading_spread",
           "HEADING_SPREAD", "InputLead", "input_lead", "LEAD_BAND", "LEAD_UNEXPLAINED_RATIO"]

SPAN = 1.0
"""s: the spans (not overlapping, so that their errors are independent) over which the
attitude's change is compared with the gyro's integral."""
SCALE_NOTABLE = 0.01
"""A gyro scale off by less than this share of 1 is left unsaid (a calibrated MEMS gyro's
residual scale error; below it the fitted moments move by less than their usual spread)."""
SCALE_SIGMAS = 4.0
"""... and so is one within this many of its std of 1."""
HINT_SIGMAS = 2.0
"""An axis off by :data:`SCALE_NOTABLE` and this many of its std hints at a scale error: enough
for the diagnosis to try the effect ``gyro_scale`` (a fit's word needs :data:`SCALE_SIGMAS`)."""
AXES = ("p", "q", "r")
HEADING_SPREAD = 0.1
"""A :func:`heading_spread` from which the flights tell a force fixed in the world from an
offset fixed in the body: a tenth of the force that no offset can hold (a heading's spread of
about 26 degrees std)."""


@dataclass(frozen=True)
class GyroScale:
    """How the gyro reads against the attitude's turning, per body axis: ``scale[a]`` times the
    rate the attitude shows (1: they agree), its std, and the delay of the attitude behind
    the gyro fitted beside it (s)."""

    scale: dict[str, float]
    std: dict[str, float]
    delay: float
    spans: int
    # the constant gyro bias fitted beside (rad/s, gyro = rate + bias) and its std, per axis
    bias: dict[str, float] = field(default_factory=dict)
    bias_std: dict[str, float] = field(default_factory=dict)

    def off(self) -> dict[str, float]:
        """The axes whose scale is off by at least :data:`SCALE_NOTABLE` and
        :data:`SCALE_SIGMAS` of its std."""
        return self._beyond(SCALE_SIGMAS)

    def hints(self) -> dict[str, float]:
        """The axes off by :data:`SCALE_NOTABLE` and :data:`HINT_SIGMAS` of their std."""
        return self._beyond(HINT_SIGMAS)

    def _beyond(self, sigmas: float) -> dict[str, float]:
        return {a: k for a, k in self.scale.items()
                if abs(k - 1) >= SCALE_NOTABLE and abs(k - 1) >= sigmas * self.std[a]}

    def reading(self) -> str:
        """The axes that are off in a few words ("the gyro reads q 1.036 ± 0.008 times the rate
        at which the measured attitude turns"), or ""."""
        off = self.off()
        if not off:
            return ""
        return ("the gyro reads " + ", ".join(f"{a} {k:.3f} ± {self.std[a]:.1g}" for a, k in off.items())
                + " times the rate at which the measured attitude turns")

    def words(self) -> str:
        """:meth:`reading` with how it was read and what to do, or ""."""
        if not self.off():
            return ""
        delay_ms = round(1e3 * self.delay) or 0          # no "-0 ms"
        return (f"{self.reading()} (its change over {self.spans} spans of {SPAN:g} s against the gyro's "
                f"integral, with a gyro bias and a delay of the attitude behind the gyro, {delay_ms} ms, fitted "
                "beside): a gyro scale error (an uncalibrated gyro), or an attitude that under-reads the turns; "
                "the model is fitted to both at once and its moments, b and K_T absorb the difference: add the "
                "effect gyro_scale, calibrate the gyro, or divide its columns by these factors")


def gyro_scale(log: FlightLog) -> GyroScale | None:
    """The gyro's scale against the attitude (module doc), or None without a gyro, roll and
    pitch, or enough spans (12) that turn the vehicle."""
    sensors = _gyro_and_attitude(log)
    if sensors is None:
        return None
    G, E, gk, ek = sensors
    first = _spans(log, G, E, gk, ek, 0.0)
    if first is None or not first.scale:
        return None
    # the gyro delayed by the delay found, and read again: the delay's first-order term alone
    # leaves a step's fast turn in the scale (+4 % on greybox's own flights with a 20 ms delay)
    again = _spans(log, G, E, gk, ek, first.delay)
    return again if again is not None and again.scale else None


def _gyro_and_attitude(log: FlightLog) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The gyro ``G`` (n, 3) and the attitude ``E`` (n, 3; psi NaN when not logged) with the
    rows where each is measured, ``(G, E, gyro rows, roll-and-pitch rows)``; None without a
    gyro, roll and pitch, or 20 rows of each."""
    if not all(log.measures(c) for c in ("phi", "theta") + AXES):
        return None
    t = log.t
    G = np.column_stack([log.output(c) for c in AXES])
    E = np.column_stack([log.output(c) if c in log.output_names else np.full(t.size, np.nan)
                         for c in ("phi", "theta", "psi")])
    gk, ek = np.isfinite(G).all(axis=1), np.isfinite(E[:, :2]).all(axis=1)
    if gk.sum() < 20 or ek.sum() < 20:
        return None
    return G, E, gk, ek


def gyro_bias_reading(log: FlightLog) -> dict[str, tuple[float, float]] | None:
    """The gyro's constant bias against the attitude's turning, per body axis, ``{axis: (bias,
    std)}`` (rad/s; gyro = rate + bias), read as :func:`gyro_scale` reads the scale (beside it,
    over spans of :data:`SPAN` s), also where the flight turns too little to read the scale;
    None without a gyro, roll and pitch, or enough spans. The data's own word on a fitted
    ``gyro_bias``, which the predictions hardly test."""
    sensors = _gyro_and_attitude(log)
    if sensors is None:
        return None
    read = _spans(log, *sensors, 0.0)
    if read is None or not read.bias:
        return None
    return {a: (read.bias[a], read.bias_std[a]) for a in read.bias}


def _spans(log: FlightLog, G: np.ndarray, E: np.ndarray, gk: np.ndarray, ek: np.ndarray, shift: float
           ) -> GyroScale | None:
    """:func:`gyro_scale` with the gyro read ``shift`` seconds late."""
    t = log.t
    Gf = np.column_stack([np.interp(t - shift, t[gk], g[gk]) for g in G.T])
    Ef = np.column_stack([np.interp(t, t[ek], e[ek]) for e in E[:, :2].T])
    W = euler_rate_matrices(Ef[:, 0], Ef[:, 1])                        # (n, angle, axis)
    per_axis = W * Gf[:, None, :]                                      # each axis' share of the angle rates
    half_dt = (0.5 * np.diff(t))[:, None, None]
    S = np.concatenate([np.zeros((1, 3, 3)), np.cumsum((per_axis[1:] + per_axis[:-1]) * half_dt, axis=0)])
    Wint = np.concatenate([np.zeros((1, 3, 3)), np.cumsum((W[1:] + W[:-1]) * half_dt, axis=0)])
    rates = per_axis.sum(axis=2)                                       # Euler angle rates from the gyro
    ang = E.copy()
    k = np.isfinite(ang[:, 2])
    if k.any():
        ang[k, 2] = np.unwrap(ang[k, 2])
    # span ends on rows where the attitude is measured, one span after the other
    rows_measured = np.nonzero(ek)[0]
    ends = rows_measured[np.unique(np.searchsorted(t[rows_measured], np.arange(t[0], t[-1], SPAN)))]
    ends = ends[ends < t.size]
    if ends.size < 13:
        return None
    i, j = ends[:-1], ends[1:]
    # a span across a stretch the gyro did not measure (its clipped samples left out) would
    # read its interpolation as the turn: a blind audit's racer, gyro past +-2000 deg/s, 0.86
    gap = np.concatenate([[0], np.cumsum(inside_gaps(t, gk))])
    whole = gap[j + 1] == gap[i + 1]
    i, j = i[whole], j[whole]
    if i.size < 12:
        return None
    D = (ang[j] - ang[i]) - (S[j] - S[i]).sum(axis=2)                  # (m, angle): what the gyro leaves
    # unknowns: c_a (3, the attitude's change per unit of axis a's integral, less 1), the
    # gyro's bias (3), the attitude's delay (1)
    m = i.size
    X = np.zeros((m, 3, 7))
    X[:, :, 0:3] = S[j] - S[i]
    X[:, :, 3:6] = -(Wint[j] - Wint[i])
    X[:, :, 6] = -(rates[j] - rates[i])
    whole = _regression(X, D)
    if whole is None:
        return None
    coef, cov = whole
    # the halves' spread as well: an attitude error correlated from span to span makes the
    # formal std too small (the real NanoBench flights, which hardly turn: 0.91 +- 0.03)
    halves = [_regression(X[part], D[part]) for part in (slice(0, m // 2), slice(m // 2, m))]
    both = halves[0] is not None and halves[1] is not None

    def read(i: int) -> tuple[float, float, float | None]:
        """Coefficient ``i``: its value, formal std and half the halves' difference (None
        without both halves)."""
        spread = 0.5 * abs(float(halves[0][0][i]) - float(halves[1][0][i])) if both else None
        return float(coef[i]), math.sqrt(max(float(cov[i, i]), 0.0)), spread

    scale, std, bias, bias_std = {}, {}, {}, {}
    for a, name in enumerate(AXES):
        bb, sb, spread = read(3 + a)
        sb = sb if spread is None else max(sb, spread)
        if np.isfinite(bb) and np.isfinite(sb):
            bias[name], bias_std[name] = bb, sb
        c, s, spread = read(a)
        s = math.inf if spread is None else max(s, spread)       # a scale is read only with both halves
        if not (np.isfinite(c) and np.isfinite(s)) or 1 + c <= 0 or s > 0.05:
            continue            # an axis the flight hardly turns about: not read
        scale[name] = 1.0 / (1.0 + c)                                  # gyro = scale x the attitude's rate
        std[name] = s / (1.0 + c) ** 2
    return GyroScale(scale=scale, std=std, delay=shift + float(coef[6]), spans=int(m), bias=bias, bias_std=bias_std)


def _regression(X: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Least squares of the spans' leftover changes ``D`` (spans, angles) on ``X`` (spans,
    angles, unknowns) over the angles measured: coefficients and their covariance."""
    ok = np.isfinite(D)
    A, y = X[ok], D[ok]
    if A.shape[0] < 2 * A.shape[1]:
        return None
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    sigma2 = float(np.sum((y - A @ coef) ** 2)) / (A.shape[0] - A.shape[1])
    try:
        return coef, np.linalg.inv(A.T @ A) * sigma2
    except np.linalg.LinAlgError:
        return None


def heading_spread(logs: Sequence[FlightLog]) -> float:
    """The share of a constant horizontal force fixed in the world that no constant vector
    fixed in the body can stand for over these flights' logged headings: ``1 - |mean
    exp(i psi)|^2`` over every sample with a measured ``psi`` (0: one heading held throughout;
    1: every heading alike). The best body-fixed stand-in for a world force ``f`` is its mean
    projection, ``mean(exp(-i psi)) f``, and what it leaves is this share of ``|f|^2``. 0 where
    no flight measures the heading (nothing tells the two apart)."""
    psi = [log.output("psi") for log in logs if log.measures("psi")]
    psi = np.concatenate(psi) if psi else np.zeros(0)
    psi = psi[np.isfinite(psi)]
    if psi.size == 0:
        return 0.0
    return float(1.0 - abs(np.mean(np.exp(1j * psi))) ** 2)


LEAD_BAND = (1.0, 8.0)
"""Hz: the band in which the roll and pitch acceleration is compared with the speeds' moment
(above a trim's drift, below the rows' noise)."""
LEAD_MAX = 0.1
"""s: the largest shift tried either way."""
LEAD_UNEXPLAINED_RATIO = 2.0
"""A shift of the speeds is said when the speeds as logged leave this many times as much of the
acceleration unexplained (``1 - r^2``) as shifted, or more: the shift explains clearly better."""


@dataclass(frozen=True)
class InputLead:
    """How the body's roll and pitch acceleration (the gyro's derivative) follows the moment of
    the logged rotor speeds (through the rotors' positions): the shift that correlates them
    best (s; > 0 the body answers later than the speeds are stamped, < 0 before), the
    correlation there and with no shift, and the rows' spacing."""

    lag: float
    correlation: float
    at_zero: float
    row: float

    @property
    def shift(self) -> float:
        """s: how late the speeds are stamped (< 0) or early (> 0) against the gyro: :attr:`lag`
        less the half row by which a row's speed, held over the row after it, acts late."""
        return self.lag - 0.5 * self.row

    def late(self) -> bool:
        """Whether the speeds are stamped late: the body answers more than a row before them
        (:attr:`shift`), and that shift explains the acceleration clearly better
        (:data:`LEAD_UNEXPLAINED_RATIO`). Nothing makes a vehicle turn before the rotors that
        turn it."""
        return bool(self.shift < -max(self.row, 0.002) and self.correlation > 0.5
                    and 1 - self.at_zero ** 2 >= LEAD_UNEXPLAINED_RATIO * (1 - self.correlation ** 2))

    def words(self) -> str:
        """What :meth:`late` finds, and what to do, or ""."""
        if not self.late():
            return ""
        ms = -1e3 * self.shift
        return (f"the body's roll and pitch acceleration (the gyro) leads the logged rotor speeds' moment by "
                f"{ms:.0f} ms (correlation {self.correlation:.3f} shifted, {self.at_zero:.3f} as logged): no "
                "vehicle turns before its rotors, so the speeds are stamped late against the gyro (a clock "
                "offset between the streams, a telemetry's delay); the parameters and any effect fitted take up "
                f"the difference (a lag, a moment, a random torque): shift the speeds {ms:.0f} ms earlier "
                f"(t - {ms / 1e3:.2g} s) or the other sensors as late")


def input_lead(log: FlightLog, rotor_positions: np.ndarray) -> InputLead | None:
    """The logged rotor speeds' timing against the gyro (:class:`InputLead`): the roll and pitch
    acceleration (a Savitzky-Golay derivative of p and q over 20 ms) against the moment
    ``w^2`` gives through the rotors' positions, both band-passed to :data:`LEAD_BAND`,
    correlated at shifts of whole rows up to :data:`LEAD_MAX` either way (the peak refined
    between rows). None without p and q, rotor speeds, or 2 s of rows. A blind audit's racer
    with its speeds stamped 10 ms late: a shift of -10.5 ms (correlation 0.993, 0.957 as
    logged); as logged, -0.5 ms; the real NanoBench flights' PWM commands: +38 to +43 ms (the
    commands' delay, which ``command_delay`` holds)."""
    from scipy.signal import butter, correlate, filtfilt, savgol_filter
    P = np.asarray(rotor_positions, dtype=float)
    t = log.t
    if t.size < 50 or not all(log.measures(c) for c in ("p", "q")) or log.inputs.shape[1] < len(P):
        return None
    row = float(np.median(np.diff(t)))
    if not row > 0 or t[-1] - t[0] < 2.0 or LEAD_BAND[0] >= 0.4 / row:
        return None
    G = np.column_stack([log.output(c) for c in ("p", "q")])
    ok = np.isfinite(G).all(axis=1)
    if ok.sum() < 50:
        return None
    G = np.column_stack([np.interp(t, t[ok], g[ok]) for g in G.T])
    acc = savgol_filter(G, max(5, int(round(0.02 / row)) | 1), 2, deriv=1, delta=row, axis=0)
    w2 = log.inputs[:, :len(P)] ** 2
    moment = np.column_stack([w2 @ -P[:, 1], w2 @ P[:, 0]])        # FRD, thrust along -z
    b, a = butter(2, (LEAD_BAND[0], min(LEAD_BAND[1], 0.4 / row)), btype="band", fs=1 / row)
    acc, moment = filtfilt(b, a, acc, axis=0), filtfilt(b, a, moment, axis=0)
    n = int(round(LEAD_MAX / row))
    if t.size < 4 * n + 50:
        return None
    lags = np.arange(-n, n + 1)
    m = t.size - 2 * n
    A = acc[n:n + m] - acc[n:n + m].mean(axis=0)
    # at lag L the moment's rows n - L .. n - L + m face the acceleration's n .. n + m: every lag's
    # dot product at once (A is centred, so the moment's own mean drops out of it), and each
    # window's spread from running sums; one pass, not one per lag (it runs in every fit)
    dots = np.column_stack([correlate(moment[:, c], A[:, c], mode="valid")[::-1] for c in range(2)])
    s1 = np.concatenate([np.zeros((1, 2)), np.cumsum(moment, axis=0)])
    s2 = np.concatenate([np.zeros((1, 2)), np.cumsum(moment ** 2, axis=0)])
    start = n - lags
    spread = (s2[start + m] - s2[start]) - (s1[start + m] - s1[start]) ** 2 / m
    den = np.sqrt((A ** 2).sum(axis=0) * np.maximum(spread, 0.0))
    r = np.mean(np.where(den > 0, dots / np.where(den > 0, den, 1.0), 0.0), axis=1)
    j = int(np.argmax(r))
    frac = 0.0
    if 0 < j < r.size - 1:
        den = r[j - 1] - 2 * r[j] + r[j + 1]
        frac = 0.5 * (r[j - 1] - r[j + 1]) / den if den < 0 else 0.0
    return InputLead(lag=float((lags[j] + frac) * row), correlation=float(r[j]), at_zero=float(r[n]), row=row)

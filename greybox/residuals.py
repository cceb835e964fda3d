"""Residuals of a fitted trajectory and the statistics that say whether they look like noise.

Shared by the fitter (its certificate: are the residuals at the sensor noise and white?)
and the diagnosis (where does the model fail, how coloured is the error).
"""
from __future__ import annotations

import math
from typing import Any, NamedTuple, Sequence

import numpy as np

from .data import FlightLog
from .integrate import log_substeps, parallel_map, rk4_step_with_output
from .model import OUTPUTS, QuadrotorModel
from .rotations import euler_rate_matrices

__all__ = ["fitted_trajectory", "output_residuals", "flight_residuals", "whiteness_fraction", "long_run_factor",
           "residual_widening", "attitude_motion", "AttitudeMotion", "WHITENESS_LAGS", "MOTION_WINDOW",
           "NOT_MOTION_COHERENCE", "MOTION_GAIN_SIGMAS", "ANGLE_OF_RATE"]

WHITENESS_LAGS = 30
"""Autocorrelation lags (in measured samples) examined by :func:`whiteness_fraction`."""
NOT_MOTION_COHERENCE = 0.25
"""An attitude channel's residual above the noise is the sensor's own error, not motion the
model misses, when the integrated gyro residuals account for less than this share of it
(:func:`attitude_motion`), at least half its excess lying within the stretches compared. With
attitude noise correlated over 50 ms and nothing missing, output-error fits leave 0-1 % on
greybox's own flights (1 kg, 500 Hz) and 1-14 % on the peer simulator's 30 g vehicle (the fit
bends its trajectory a little towards the coloured noise, and the gyro then sees that); a
residual that is motion accounts for (r^2 - 1)/r^2 of itself at r times the noise: 75 % and
more beyond 2x."""
MOTION_GAIN_SIGMAS = 3.0
"""How many standard errors the slope of the angle residual on the integrated rate residual
must lie from 0 (and within of 1) for a rate channel's residual to count as motion, or from
1 for it to count as the gyro's own error."""
ANGLE_OF_RATE = {"p": "phi", "q": "theta", "r": "psi"}
"""The Euler angle a body rate mostly moves near level flight: whose :class:`AttitudeMotion`
says whether that rate's residual is motion (:meth:`AttitudeMotion.rate_verdict`)."""
MOTION_WINDOW = 1.0
"""Seconds over which :func:`attitude_motion` compares an attitude residual with the
integrated rate residuals (each window detrended: a gyro bias and slow drift drop out)."""


def fitted_trajectory(model: QuadrotorModel, res: Any, log: FlightLog, flight: int = 0
                      ) -> tuple[np.ndarray, np.ndarray]:
    """States and outputs at every sample of ``log`` (flight number ``flight`` of the fit),
    integrated over each shooting interval from the fitted node states. ``res`` is a
    :class:`~greybox.fitting.FitResult`, or anything with its ``p``, ``node_states``,
    ``node_index`` and ``interval``."""
    log = model.prepare_log(log)
    nodes, idx = res.node_states[flight], res.node_index[flight]
    N = res.interval
    n = len(log)
    M = len(idx) - 1
    f = rk4_step_with_output(model, log_substeps([log]))
    F = parallel_map(f.mapaccum("traj", N, [0], [0]), M)
    k = np.minimum(np.arange(M * N), n - 1)
    hk = np.append(np.diff(log.t), 0.0)[k]
    # a fit with parameters per flight (wind, battery sag) gives each flight its own vector
    p = res.flight_p(flight) if hasattr(res, "flight_p") else res.p
    _, Y, X = F(nodes[:M].T, log.inputs[k].T, p, log.t[k][None, :], hk[None, :])
    Y, X = np.asarray(Y).T, np.asarray(X).T
    out_y = np.full((n, model.ny), np.nan)
    out_x = np.full((n, model.nx), np.nan)
    m = min(n, M * N)
    out_y[:m], out_x[:m] = Y[:m], X[:m]
    return out_x, out_y


def output_residuals(log: FlightLog, Y: np.ndarray) -> np.ndarray:
    """Measured minus modelled outputs, (n, ny), NaN where a channel is not measured; the
    yaw residual is wrapped to (-pi, pi]."""
    E = np.full_like(Y, np.nan)
    for c, name in enumerate(OUTPUTS):
        if name in log.output_names:
            E[:, c] = log.output(name) - Y[:, c]
    psi = OUTPUTS.index("psi")
    E[:, psi] = np.arctan2(np.sin(E[:, psi]), np.cos(E[:, psi]))
    return E


def flight_residuals(model: QuadrotorModel, res: Any, logs: Sequence[FlightLog]) -> list[np.ndarray]:
    """Output residuals (:func:`output_residuals`) of the fit ``res`` on each of its flights ``logs``."""
    return [output_residuals(lg, fitted_trajectory(model, res, lg, i)[1]) for i, lg in enumerate(logs)]


def whiteness_fraction(e: np.ndarray, lags: int = WHITENESS_LAGS) -> float:
    """Fraction of the first ``lags`` autocorrelations of the measured samples of ``e``
    outside the 99 % band of white noise (about 0.01 for white noise; MATLAB's ``resid``
    draws the same band). NaN when fewer than 50 samples are measured."""
    v = e[np.isfinite(e)]
    if v.size < 50:
        return float("nan")
    v = v - v.mean()
    var = float(v @ v)
    if var <= 0:
        return 0.0
    band = 2.576 / math.sqrt(v.size)
    ac = np.array([float(v[j:] @ v[:-j]) / var for j in range(1, lags + 1)])
    return float(np.mean(np.abs(ac) > band))


def long_run_factor(e: np.ndarray, lags: int = 50) -> float:
    """Long-run variance / variance of a residual sequence (Bartlett weights), >= 1."""
    e = e[np.isfinite(e)]
    if e.size < 4 * lags:
        return 1.0
    e = e - e.mean()
    v = float(e @ e) / e.size
    if v <= 0:
        return 1.0
    acc = 0.0
    for k in range(1, lags + 1):
        rho = float(e[k:] @ e[:-k]) / e.size / v
        acc += (1 - k / (lags + 1)) * rho
    return max(1.0, 1.0 + 2.0 * acc)


def residual_widening(E: np.ndarray, channels) -> float:
    """The square root of the median :func:`long_run_factor` of the residual columns of ``E``
    (n, ny; ``OUTPUTS`` order) whose channel is in ``channels``; 1 without any."""
    facs = [long_run_factor(E[:, c]) for c, ch in enumerate(OUTPUTS) if ch in channels]
    return math.sqrt(float(np.median(facs))) if facs else 1.0


class AttitudeMotion(NamedTuple):
    """How much of an attitude channel's residual is motion (:func:`attitude_motion`)."""

    coherence: float      # squared correlation with the integrated rate residual, in [0, 1]
    gain: float           # slope of the angle residual on that integral (1 when the rate residual is motion)
    gain_std: float       # its standard error (the stretches as independent clusters)
    within_rms: float     # RMS of the angle residual within the stretches (centred or detrended), rad
    rate_rms: float       # RMS of the integrated rate residual within the stretches, rad
    samples: int          # attitude samples compared

    def angle_is_sensor_error(self, ratio: float, noise: float) -> bool:
        """Whether the angle residual, ``ratio`` times the channel's ``noise`` in RMS, is the
        attitude sensor's own error: the gyro accounts for less than
        :data:`NOT_MOTION_COHERENCE` of it, and at least half its excess over the noise lies
        within the stretches (a constant offset, which they do not see, does not count)."""
        if not noise > 0:
            return False
        within = (self.within_rms / noise) ** 2 - 1.0
        return self.coherence < NOT_MOTION_COHERENCE and within >= 0.5 * (ratio ** 2 - 1.0)

    def rate_verdict(self) -> str | None:
        """``"motion"`` when the rate residual integrates into the angle residual one for one
        (slope within :data:`MOTION_GAIN_SIGMAS` standard errors of 1 and beyond them from 0),
        ``"sensor"`` when it clearly does not (the slope that far from 1 and below 0.5: the
        gyro's own error), else None (cannot tell)."""
        k = MOTION_GAIN_SIGMAS * self.gain_std
        if self.gain > k and abs(self.gain - 1.0) < k:
            return "motion"
        if abs(self.gain - 1.0) > k and self.gain < 0.5:
            return "sensor"
        return None


def attitude_motion(residuals: Sequence[np.ndarray], logs: Sequence[FlightLog],
                    starts: Sequence[np.ndarray | None] | None = None,
                    window: float = MOTION_WINDOW) -> dict[str, AttitudeMotion]:
    """Whether the attitude residuals of a fit are motion the model misses or the attitude
    sensor's own error, from each flight's residuals (``residuals``: (n, ny), ``OUTPUTS``
    order, measured minus modelled) and its log (times, measured roll and pitch).

    Two sensors see one motion: a torque the model lacks moves the measured body rates and
    the measured angles alike, so within a stretch of continuous model trajectory the angle
    residual follows the integral of the rate residuals through the Euler kinematics,
    ``d/dt e_(phi,theta,psi) = W(phi, theta) e_(p,q,r)``. An attitude sensor's own error
    (coloured by a filter, an estimator's lag) is not in the gyro and does not. The stretches
    start at ``starts`` (per flight, sample indices: a fit with process noise restarts its
    trajectory at every shooting node) or every ``window`` s (an output-error fit is one
    trajectory). In each, the integral starts at zero and both are centred, over 0.5 s or
    more detrended (the integration constant, a gyro bias). Pooled over stretches and
    flights: the squared correlation (near 1 when the angle residual is motion, near 0 when
    it is the sensor's) and the slope of the angle residual on the integral (near 1 when the
    rate residual is motion, near 0 when it is the gyro's noise). A channel without a
    measured rate partner is left out."""
    cols = {n: OUTPUTS.index(n) for n in ("phi", "theta", "psi", "p", "q", "r")}
    acc = {ch: [] for ch in ("phi", "theta", "psi")}      # per stretch: (aa, ii, ai, count)
    for f, (E, log) in enumerate(zip(residuals, logs)):
        t = log.t
        n = len(t)
        att = [log.output(c) if c in log.output_names else np.full(n, np.nan) for c in ("phi", "theta")]
        rates = E[:, [cols["p"], cols["q"], cols["r"]]]
        ok = np.isfinite(rates).all(axis=1) & np.isfinite(att[0]) & np.isfinite(att[1])
        if ok.sum() < max(50, 0.5 * n):
            continue
        # Euler-angle rates of the rate residuals (ZYX), at the measured roll and pitch
        dots = np.einsum("nab,nb->na", euler_rate_matrices(att[0][ok], att[1][ok]), rates[ok])
        dots = np.column_stack([np.interp(t, t[ok], d) for d in dots.T])
        step = np.vstack([np.zeros((1, 3)), 0.5 * (dots[1:] + dots[:-1]) * np.diff(t)[:, None]])
        st = starts[f] if starts is not None and starts[f] is not None else \
            np.searchsorted(t, np.arange(t[0], t[-1], window))
        st = np.unique(np.clip(np.asarray(st, int), 0, n - 1))
        which = np.searchsorted(st, np.arange(n), side="right") - 1
        integral = np.cumsum(step, axis=0)
        integral -= integral[st][np.maximum(which, 0)]      # each stretch's integral starts at zero
        for k, ch in enumerate(acc):
            e = E[:, cols[ch]]
            m = np.isfinite(e) & (which >= 0)
            for w in np.unique(which[m]):
                sel = m & (which == w)
                if sel.sum() < 4:
                    continue
                tw = t[sel] - t[sel].mean()
                basis = np.column_stack([np.ones_like(tw), tw]) if tw[-1] - tw[0] >= 0.5 else np.ones((tw.size, 1))
                a = e[sel] - basis @ np.linalg.lstsq(basis, e[sel], rcond=None)[0]
                i = integral[sel, k] - basis @ np.linalg.lstsq(basis, integral[sel, k], rcond=None)[0]
                acc[ch].append((float(a @ a), float(i @ i), float(a @ i), int(sel.sum())))
    out: dict[str, AttitudeMotion] = {}
    for ch, rows in acc.items():
        if not rows:
            continue
        aa, ii, ai, cnt = (np.array(c, float) for c in zip(*rows))
        saa, sii, sai, count = aa.sum(), ii.sum(), ai.sum(), int(cnt.sum())
        if count < 50 or saa <= 0 or sii <= 0:
            continue
        gain = sai / sii
        # the stretches as independent clusters: the slope's spread from each one's share
        spread = math.sqrt(float(np.sum((ai - gain * ii) ** 2))) / sii
        out[ch] = AttitudeMotion(float(min(sai ** 2 / (saa * sii), 1.0)), float(gain), spread,
                                 math.sqrt(saa / count), math.sqrt(sii / count), count)
    return out

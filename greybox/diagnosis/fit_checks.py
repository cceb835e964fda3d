"""What ``greybox fit`` says of a fit beyond the fit's own warnings: checks that need the
diagnosis's tools (a score test, one Gauss–Newton step of an effect, regressions on the log),
so the fitter, which the diagnosis builds on, cannot make them itself. One function, for the
command line and for a script alike: ``fit(model, log).summary()`` alone does not say them."""
from __future__ import annotations

from typing import Sequence

from ..data import FlightLog, median_row_interval
from ..fitting import FitResult
from .analysis import (below_ground_words, command_imbalance, flights_rotor_geometry, log_moment_words,
                       odd_flight_geometry, rotor_geometry_warnings, spin_words, spins_opposed, steady_torque_words,
                       thrust_at_top_words)
from .screening import free_input_timed, lag_timing_words, moment_scale_words, row_timing_words, smoothed_lag_words

__all__ = ["fit_warnings"]


def fit_warnings(res: FitResult, logs: FlightLog | Sequence[FlightLog], compile: str = "cached") -> list[str]:
    """Words on the fit ``res`` of ``logs`` (its estimation data), most telling first.

    First, whatever the fit: positions below the airframe's ground plane (a crash, or a ground
    plane elsewhere; :func:`~greybox.diagnosis.analysis.below_ground_words`).
    Where the fit failed or leaves residuals beyond the noise: rotor columns in another order
    or a layout read wrong (:func:`~greybox.diagnosis.analysis.rotor_geometry_warnings`), or
    spins given the wrong way round (:func:`~greybox.diagnosis.analysis.spins_opposed`), else
    roll and pitch moments the log gives far off the airframe's
    (:func:`~greybox.diagnosis.analysis.log_moment_words`), and the highest commands giving
    less thrust than they ask (:func:`~greybox.diagnosis.analysis.thrust_at_top_words`: motors
    at the end of their range), and a rotor whose share of the work steps during a flight
    (:attr:`~greybox.diagnosis.analysis.CommandImbalance.share_step`: a propeller damaged in
    flight, which no constant parameter holds). A fit that failed: then a steady
    torque the model lacks (:func:`~greybox.diagnosis.analysis.steady_torque_words`) — the
    reasons before its status. A certified fit: then the rows' timing, where held speeds lag a
    varying signal (:func:`~greybox.diagnosis.screening.row_timing_words`), what a fitted lag's
    std leaves out (the log's timing; smoothed speeds: :func:`_lag_words`), and a moment gain
    off the airframe's that ``K_T``, ``b`` and ``Kd`` carry silently
    (:func:`~greybox.diagnosis.screening.moment_scale_words`; not beside highest commands the
    motors did not follow, which take the moments down too). ``greybox fit`` puts them
    before the fit's own warnings, or in its error when the fit failed.

    Example::

        res = fit(model, est)
        for words in fit_warnings(res, est):
            print("warning:", words)
    """
    logs = [logs] if isinstance(logs, FlightLog) else list(logs)
    model = res.model
    moments = top = changed = ""
    inadequate = not res.converged or (res.certificate is not None and not res.certificate.adequate)
    if inadequate:
        # a blind audit's M2/M4 swapped: "certified", p and q 1.7x the noise, nothing said; an
        # inertia a fifth of the vehicle's: "line search failed", or certified at 53 % of the
        # weight blaming a torque it lacked
        flight, order, turned = flights_rotor_geometry(model, logs)
        geometry = rotor_geometry_warnings(model, order, turned, flight=flight)
        if not geometry:
            # spins given the wrong way round (a blind audit's: "certified", b on its bound at 0;
            # the command line refuses them before fitting, a script's fit hears it here)
            opposed = spins_opposed(model, logs)
            geometry = [spin_words(model, opposed)] if opposed is not None else []
        moments = "" if geometry else log_moment_words(model, logs)
        # commands beyond what the motors turn: a blind audit's, diagnosed as a thrust curve
        top = "" if geometry else thrust_at_top_words(model, logs)
        # a rotor that changed in flight (a damaged propeller): a blind audit's fit said only
        # that K_T differed between the halves, and the diagnosis said it in its verdict
        imbalance = None if geometry else command_imbalance(model, logs)
        changed = imbalance.share_step_words() if imbalance is not None else ""
        if changed:
            changed = (changed[0].upper() + changed[1:] + ": the parameters fitted across it are an average "
                       "of the two")
    else:
        # one flight among several logged in another order: said whatever the fit (pooled with
        # honest flights a blind audit's swapped w2/w4 left a fit "certified" and adequate)
        odd = odd_flight_geometry(model, logs)
        geometry = rotor_geometry_warnings(model, *odd[1:], flight=odd[0]) if odd is not None else []
    ground = below_ground_words(model, logs)
    if not res.converged:
        torque = "" if geometry or changed else steady_torque_words(model, logs, res)
        return [w for w in (ground, *geometry, changed, torque, moments, top) if w]
    # a moment gain's reading (an inertia, an arm, a mass off) is not offered beside commands
    # the motors did not follow: the saturated audit's fit read k_M 0.48 as an inertia 2x off
    timing = row_timing_words(res, logs, compile)
    return ([w for w in (ground, *geometry, changed, moments, top) if w] + timing + _lag_words(res, logs, timing)
            + ([] if moments or top else moment_scale_words(res, logs, compile)))


def _lag_words(res: FitResult, logs: Sequence[FlightLog], timing: list[str]) -> list[str]:
    """What a certified fit's lags and delays (:attr:`~greybox.effects.Effect.input_timed`)
    count and what they do not, as the diagnosis says of its final model: the log's timing
    (how a row's logged value holds within the row) moves them by up to half a row beyond
    their std, where that std is below half a row and no timing was found or modelled
    (:func:`~greybox.diagnosis.screening.lag_timing_words`; a blind audit's 3-ms motors behind
    commands logged at 200 Hz: ``tau_m`` 3.074 ± 0.0019 ms, 40 std off, certified and silent);
    and, fitted to speeds smoothed since they were logged, that the smoother shortens them
    (:func:`~greybox.diagnosis.screening.smoothed_lag_words`)."""
    model = res.model
    lags = free_input_timed(model, res)
    if not lags:
        return []
    out = []
    half = 0.5 * median_row_interval(logs)
    below = any(float(res.std[res.free_names.index(n)]) < half for n in lags)
    if not timing and below and not any(e.describes_sampling for e in model.effects):
        words = lag_timing_words(model, res, logs)[0]
        if words:
            out.append(words)
    smoothed = smoothed_lag_words(logs, res)
    return out + ([smoothed] if smoothed else [])

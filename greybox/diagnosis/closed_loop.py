"""A closed-loop flight's unmodelled torque, taken as a disturbance: the yaw coefficient ``b``
with the controller's bias taken out (:func:`closed_loop_yaw`), and the baseline against which
the candidates are judged when a random torque no catalogue effect holds hides the rest
(:func:`disturbance_baseline`).

A controller answers a torque the model lacks through the very commands the model reads; a
fit without a state for that torque explains the commands that moved nothing by shrinking
``b``. On real Crazyflie flights that put ``b/K_T`` at 0-0.0011 m, below what propellers give;
refitted with :class:`~greybox.effects.DisturbanceTorque` (a random-walk torque) it came out
0.0028-0.0101 m on all ten (README, "A disturbance torque for closed-loop flights").
"""
from __future__ import annotations

import warnings as _warnings
from typing import Callable, NamedTuple, Sequence

import numpy as np

from .. import effects as fx
from ..data import FlightLog
from ..errors import ConvergenceWarning
from ..fitting import FitResult, fit

__all__ = ["closed_loop_yaw", "ClosedLoopYaw", "disturbance_baseline", "can_hold_disturbance", "rates_missing_a_torque",
           "rate_levels", "controller_answer", "TIGHT_PROCESS_NOISE", "RATE_STATES", "ANSWER_SHARE", "BIAS_SHIFT_STD"]


BIAS_SHIFT_STD = 2.0
"""A ``b`` refitted with a disturbance torque that moves by less than this many of its std
from the fit's has not shown a closed-loop bias: the halves of the estimation data disagree
for another reason (a blind audit's hexacopter with noise on its logged speeds and nothing
missing: halves 1.105e-7 and 1.056e-7, the refit +1.7 %, 0.9 std, from a b 0.4 % off the
truth; a real Crazyflie slice: 0.0010 m -> 0.0078 m, many std)."""


class ClosedLoopYaw(NamedTuple):
    """What :func:`closed_loop_yaw` found: the words ("" when there is nothing to say) and the
    certified refit with the disturbance torque whose ``b`` they give (None when there is none)."""

    words: str
    fit: FitResult | None = None


NOTHING = ClosedLoopYaw("")


def closed_loop_yaw(res: FitResult, logs: Sequence[FlightLog], *, baseline: FitResult | None = None,
                    halves_disagree: bool = False, compile: str = "auto",
                    say: Callable[[str], None] = lambda s: None) -> ClosedLoopYaw:
    """Words on ``b`` once the closed-loop bias is taken out, and the refit that gives it.

    Only for a certified fit whose ``b/K_T`` lies outside what propellers give
    (:attr:`~greybox.effects.YawTorque.RATIO_RANGE`), or whose ``b`` differs between the two
    halves of the estimation data (``halves_disagree``; a 1.2 kg vehicle under a random torque:
    ``b`` 30 % low, flagged by the halves, inside the range): its model is refitted with a
    :class:`~greybox.effects.DisturbanceTorque`, with process noise, from its parameters and
    node states; when that refit is not certified, ``baseline``'s model is (on a real flight,
    a final model with a motor lag did not certify in 200 iterations; the base model did in
    a few seconds). The words give the certified refit's ``b/K_T``: inside the range, as the
    value to take; outside, as not identified from these flights even so."""
    if not _applies(res):
        return NOTHING
    lo, hi = fx.YawTorque.RATIO_RANGE
    ratio = res.value("b") / res.value("K_T")
    outside = not lo <= ratio <= hi
    if not (outside or halves_disagree):
        return NOTHING
    say(f"diagnose: {'b/K_T is outside what propellers give' if outside else 'b differs between the halves'}; "
        "refitting with a disturbance torque")
    alt, which = _with_disturbance(res, logs, compile), "the model"
    if not alt.converged and baseline is not None and baseline is not res and _applies(baseline):
        say(f"diagnose: that refit is not certified ({alt.status}); the base model instead")
        first, alt, which = alt, _with_disturbance(baseline, logs, compile), "the base model"
        if alt.converged:
            which += f" (the final model's refit was not certified: {first.status})"
    if not alt.converged:
        return ClosedLoopYaw(f"b/K_T = {ratio:.2g} m: refitted with a disturbance torque (the controller's bias "
                             f"taken out) the fit was not certified ({alt.status}), so greybox cannot tell what b is")
    r, s = alt.value("b") / alt.value("K_T"), alt.std[alt.free_names.index("b")] / alt.value("K_T")
    refit = (f"{which} refitted with a disturbance torque (a random-walk torque the controller cancels through "
             f"the commands the model reads) gives b = {alt.value('b'):.4g}, K_T = {alt.value('K_T'):.4g}, "
             f"b/K_T = {r:.2g} ± {s:.1g} m")
    if not outside:
        shift = alt.value("b") / res.value("b") - 1
        moved = abs(alt.value("b") - res.value("b")) / (s * alt.value("K_T"))
        if moved < BIAS_SHIFT_STD and lo <= r <= hi:
            words = (f"b = {res.value('b'):.4g} differs between the halves of the estimation data, but not as a "
                     f"closed-loop bias makes it: {refit} ({100 * shift:+.1f} %, {moved:.1f} of its std): keep "
                     "this b, and read its std as too small (the halves say how far it can be off)")
        else:
            words = (f"b = {res.value('b'):.4g} differs between the halves of the estimation data, as a closed-loop "
                     f"bias makes it: {refit} ({100 * shift:+.0f} %)" +
                     (": take this b" if lo <= r <= hi else ", outside what propellers give: b is not identified"))
    elif lo <= r <= hi:
        words = (f"b/K_T = {ratio:.2g} m is a closed-loop bias: {refit}, inside what propellers give: take this b "
                 "(model + DisturbanceTorque() with process noise; --effects disturbance_torque --process-noise auto)")
    else:
        words = (f"b/K_T = {ratio:.2g} m is a closed-loop bias: {refit}, still outside what propellers give: b is not "
                 "identified from these flights; fly yaw steps")
    return ClosedLoopYaw(words, alt)


def _applies(res: FitResult) -> bool:
    """A certified fit with ``b`` and ``K_T`` free whose model can take a disturbance torque."""
    return bool(res.converged and {"b", "K_T"} <= set(res.free_names) and can_hold_disturbance(res.model))


def _with_disturbance(res: FitResult, logs: Sequence[FlightLog], compile: str,
                      process_noise: "str | dict[str, float]" = "auto", per_flight=None) -> FitResult:
    """``res``'s model with a :class:`~greybox.effects.DisturbanceTorque`, fitted with
    ``process_noise`` from ``res``'s parameters and node states (the disturbance, the last
    states, at zero), and once more from where it stopped when it is not certified."""
    with_d = res.model + fx.DisturbanceTorque()
    nodes = [np.hstack([X, np.zeros((len(X), with_d.nx - res.model.nx))]) for X in res.node_states]
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", ConvergenceWarning)   # judged by the caller
        alt = fit(with_d, logs, p0=res.p, process_noise=process_noise, initial_states=nodes, compile=compile,
                  max_iter=100, free=res.free_names, interval=res.interval, per_flight=per_flight,
                  sensor_noise=res.sensor_given)
        if not alt.converged:
            alt = fit(with_d, logs, p0=alt.p, compile=compile, max_iter=100, free=res.free_names,
                      **alt.settings())
    return alt


TIGHT_PROCESS_NOISE = 1e-6
"""Process noise of every state but the disturbance's in :func:`disturbance_baseline`, as a
fraction of the state's largest magnitude in the flight: the rigid body (and any effect
state) follows the model between the nodes; only the torque wanders."""

RATE_STATES = ("p", "q", "r")
"""The body-rate channels (and states) where a torque the model lacks shows first."""


def rates_missing_a_torque(res: FitResult, ratio: float) -> list[str]:
    """The body-rate channels (or, with process noise, rate states) that the certified fit
    ``res`` misses by more than ``ratio`` times their noise: residuals, or shooting gaps that
    are mostly systematic. A torque the model lacks shows there first."""
    if res.certificate is None or not res.converged:
        return []
    channels, gaps = res.certificate.far_off(ratio)
    off = [ch for ch in channels if ch in RATE_STATES]
    return off + [s for s in gaps if s in RATE_STATES and s not in off]


def rate_levels(res: FitResult) -> str:
    """The body rates' residual RMS over their noise in words (``"p 1.1, q 1.1, r 1.0"``); the
    shooting gaps over their random part where the rates are not measured."""
    cert = res.certificate
    if cert is None:
        return "unknown"
    levels = [f"{ch} {cert.residual_over_noise[ch]:.1f}" for ch in RATE_STATES if ch in cert.residual_over_noise]
    levels += [f"{ch} (gaps) {cert.systematic_gaps[ch]:.1f}" for ch in RATE_STATES
               if ch not in cert.residual_over_noise and ch in cert.systematic_gaps]
    return ", ".join(levels) or "unknown"


def can_hold_disturbance(model) -> bool:
    """Whether a :class:`~greybox.effects.DisturbanceTorque` can be added to ``model``: it holds
    no disturbance model already (whose states would clash: ``held_moment``'s ``d_p, d_q``)."""
    return model.accepts(fx.DisturbanceTorque())


def disturbance_baseline(res: FitResult, logs: Sequence[FlightLog], compile: str = "auto") -> FitResult:
    """``res``'s model with a :class:`~greybox.effects.DisturbanceTorque`, fitted with process
    noise on the disturbance alone (every other state :data:`TIGHT_PROCESS_NOISE`).

    Why: under a random torque (turbulence) a fit with process noise on every state lets the
    states absorb everything the model lacks; the rate channels stay far above their noise,
    and any candidate fed by the commands explains a sliver of them (the controller answers
    the torque through the commands), so none can stand, and an effect that is there too (a
    ground effect at 8 cm, on an independent simulator) hides in the vertical process noise:
    its refit removed 0.0 % of what the model missed. With the torque as the one random input,
    the rigid body follows the model between the nodes: the ground effect's absence then shows
    in the height (residuals 91 times the noise, 1.75 with it), and K_T and b came out within
    1 % of the truth. Started from ``res``'s parameters and node states (disturbance zero)."""
    # every state of the model as given tight; the disturbance's, left out, starts at the rate
    # gaps per second (fit's estimate for a disturbance state)
    scale = np.max([np.abs(X).max(axis=0) for X in res.node_states], axis=0) + 1e-3
    q = {s: TIGHT_PROCESS_NOISE * float(scale[j]) for j, s in enumerate(res.model.state_names)}
    return _with_disturbance(res, logs, compile, process_noise=q, per_flight=res.per_flight_rule)


ANSWER_SHARE = 0.5
"""Share of an effect's distance from its null values that a disturbance torque in the model
must take away for :func:`controller_answer` to call the effect the controller's answer: the
larger part of its size then came from the torque the model lacked, not from the vehicle."""


def controller_answer(fr: FitResult, effect: str, logs: Sequence[FlightLog], ratio: float,
                      compile: str = "auto", say: Callable[[str], None] = lambda s: None) -> str:
    """Words saying that ``effect`` in the certified refit ``fr`` stands for a closed-loop
    controller's answer to a torque the model lacks, not for the vehicle; "" otherwise.

    Asked of an effect whose torque is a multiple of the commands' own moment
    (:attr:`~greybox.effects.Effect.scales_commanded_moment`) that leaves the body rates more
    than ``ratio`` times their noise (:func:`rates_missing_a_torque`). The controller cancels an
    unmodelled torque through the commands, so the commands' moment carries minus that torque
    and a gain below 1 on it takes up part of any torque the model lacks: an independent
    simulator's periodic disturbance torque gave ``moment_gain`` k_M = 0.67 ± 0.02 (truth 1)
    with the roll rate still 3.5x its noise, and a random torque k_M 0.66-0.74. Refitted with a
    :class:`~greybox.effects.DisturbanceTorque` (:func:`disturbance_baseline`, process noise on
    it alone), an effect of the vehicle keeps its size; when more than :data:`ANSWER_SHARE` of
    its distance from its null values goes, or that refit is not certified (greybox cannot
    tell), the words say so."""
    cls = fx.known_effects().get(effect)
    if not getattr(cls, "scales_commanded_moment", False) or not can_hold_disturbance(fr.model):
        return ""
    rates = rates_missing_a_torque(fr, ratio)
    if not rates:
        return ""
    say(f"  {effect} leaves {', '.join(rates)} far off: refitting it with a disturbance torque")
    alt = disturbance_baseline(fr, logs, compile)
    if not alt.converged:
        return (f"with it {', '.join(rates)} stay far off, and refitted with a disturbance torque (a random torque "
                f"the controller answers through the commands) the fit was not certified ({alt.status}), so "
                "greybox cannot tell it from the controller's answer to a torque the model lacks")
    moves, fell = [], True
    for _, comp, null in fr.model.effect_components(effect):
        v, vd = fr.value(comp), alt.value(comp)
        moves.append(f"{comp} {v:.3g} -> {vd:.3g}")
        if abs(vd - null) > (1 - ANSWER_SHARE) * abs(v - null):
            fell = False
    if not moves or not fell:
        return ""
    return (f"with it {', '.join(rates)} stay far off, and refitted with a disturbance torque (a random torque the "
            f"controller answers through the commands) it falls back towards its null value ({', '.join(moves)}): "
            "it stood for the controller's answer to a torque the model lacks, not for the vehicle")

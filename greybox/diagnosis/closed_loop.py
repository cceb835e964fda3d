"""The yaw coefficient ``b`` of a closed-loop flight, with the controller's bias taken out.

A controller answers a torque the model lacks through the very commands the model reads; a
fit without a state for that torque explains the commands that moved nothing by shrinking
``b``. On real Crazyflie flights that put ``b/K_T`` at 0-0.0011 m, below what propellers give;
refitted with :class:`~greybox.effects.DisturbanceTorque` (a random-walk torque) it came out
0.0028-0.0101 m on all ten (README, "A disturbance torque for closed-loop flights").
"""
from __future__ import annotations

import warnings as _warnings
from typing import Callable, Sequence

from .. import effects as fx
from ..data import FlightLog
from ..errors import ConvergenceWarning
from ..fitting import FitResult, fit

__all__ = ["closed_loop_yaw"]


def closed_loop_yaw(res: FitResult, logs: Sequence[FlightLog], *, compile: str = "auto",
                    say: Callable[[str], None] = lambda s: None) -> str:
    """Words on ``b`` once the closed-loop bias is taken out, or "" when there is nothing to say.

    Only for a certified fit whose ``b/K_T`` lies outside what propellers give
    (:attr:`~greybox.effects.YawTorque.RATIO_RANGE`): its model is refitted with a
    :class:`~greybox.effects.DisturbanceTorque`, with process noise, from its parameters. The
    words give that fit's ``b/K_T`` when it is certified: inside the range, as the value to
    take; outside, as not identified from these flights even so."""
    model = res.model
    names = set(model.param_names)
    if not res.converged or not {"b", "K_T"} <= names or fx.DisturbanceTorque.name in model.effects:
        return ""
    lo, hi = fx.YawTorque.RATIO_RANGE
    ratio = res.value("b") / res.value("K_T")
    if lo <= ratio <= hi or "b" not in res.free_names:
        return ""
    say("diagnose: b/K_T is outside what propellers give; refitting with a disturbance torque")
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", ConvergenceWarning)   # judged below
        alt = fit(model + fx.DisturbanceTorque(), logs, p0=res.p, process_noise="auto", compile=compile,
                  max_iter=200, free=res.free_names, interval=res.interval)
    if not alt.converged:
        return (f"b/K_T = {ratio:.2g} m: refitted with a disturbance torque (the controller's bias taken out) the "
                f"fit was not certified ({alt.status}), so greybox cannot tell what b is")
    r, s = alt.value("b") / alt.value("K_T"), alt.std[alt.free_names.index("b")] / alt.value("K_T")
    head = (f"b/K_T = {ratio:.2g} m is a closed-loop bias: refitted with a disturbance torque (a random-walk "
            f"torque the controller cancels through the commands the model reads) b = {alt.value('b'):.4g}, "
            f"K_T = {alt.value('K_T'):.4g}, b/K_T = {r:.2g} ± {s:.1g} m")
    if lo <= r <= hi:
        return head + ", inside what propellers give: take this b (model + DisturbanceTorque() with process noise)"
    return head + ", still outside what propellers give: b is not identified from these flights; fly yaw steps"

"""What a logged command delivers: the thrust drifting as the battery sags, rotor speed
scaling with the logged battery voltage, and the offset of a command-to-speed map."""
from __future__ import annotations

from ..parameters import Parameter
from .base import Effect

__all__ = ["ThrustDrift", "RotorMap", "BatteryVoltage"]


class ThrustDrift(Effect):
    """Thrust coefficient drifting linearly over the flight (battery sag):
    ``K_T(t) = K_T * (1 + K_T_drift * t)``, t in seconds from the log's start.
    """

    name = "thrust_drift"
    summary = "thrust coefficient drifting linearly in time"
    excited_by = 'the same manoeuvre repeated early and late in the flight'
    fit_advice = 'a longer flight, repeating the same manoeuvres early and late'
    per_flight = True      # how fast thrust sags depends on the battery each flight starts with
    channels = ('z',)
    distinguish = {
        'ground_effect': 'repeat the same climb early and late in the flight, away from the ground',
        'battery_voltage': 'vary the thrust level: the voltage sags with the current drawn, time does not',
    }
    shifts_trim = True

    def parameters(self, airframe):
        return [Parameter("K_T_drift", 1, 0.0, "1/s", -0.05, 0.05, 1e-3, 0.0, True,
                          "relative change of K_T per second", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"K_T_drift": -0.002}

    def modify(self, ctx):
        ctx.thrust_scale *= 1.0 + ctx.params["K_T_drift"] * ctx.t


class RotorMap(Effect):
    """A constant offset ``w_offset`` (rad/s) added to the logged rotor speeds.

    For logs whose speeds come from a command through an affine map ``w = a*cmd + c``
    (e.g. Crazyflie PWM), this fits the map: a wrong slope ``a`` is absorbed exactly by
    ``K_T`` and ``b`` (thrust is ``K_T*w^2``), so the offset is the one coefficient left
    to identify. Applied before the other effects (it changes the command itself).
    """

    name = "rotor_map"
    summary = "offset of the logged rotor speeds (command-to-speed map)"
    excited_by = 'a wide range of thrust levels'
    channels = ('z', 'phi', 'theta', 'p', 'q')

    def parameters(self, airframe):
        return [Parameter("w_offset", 1, 0.0, "rad/s", -2000.0, 2000.0, 100.0, 0.0, True,
                          "offset added to the logged rotor speeds", self.name)]

    def modify(self, ctx):
        ctx.w_command = ctx.w_command + ctx.params["w_offset"]
        ctx.w = ctx.w + ctx.params["w_offset"]


class BatteryVoltage(Effect):
    """Rotor speed (hence thrust and reaction torque) at a given command changing with the
    logged battery voltage ``vbat`` (V): ``w = w_logged * (1 + K_vbat * (vbat - v_ref))``.

    Real motors spin slower at the same command as the battery sags, so a log of commanded
    speeds (PWM mapped to rad/s) over-states thrust late in the flight. ``thrust_drift``
    models the same with time; this uses the measured voltage instead. Reads the signal
    ``vbat`` (an extra input column of the log).
    """

    name = "battery_voltage"
    summary = "rotor speed at a given command scaling with battery voltage"
    excited_by = 'long flights at varied thrust'
    channels = ('z', 'psi', 'r')
    signals = ("vbat",)

    def __init__(self, v_ref: float = 4.0):
        self.v_ref = float(v_ref)

    def parameters(self, airframe):
        return [Parameter("K_vbat", 1, 0.0, "1/V", -2.0, 2.0, 0.05, 0.0, True,
                          f"relative rotor speed change per volt about {self.v_ref:g} V", self.name)]

    def modify(self, ctx):
        scale = 1.0 + ctx.params["K_vbat"] * (ctx.signals["vbat"] - self.v_ref)
        ctx.w_command = ctx.w_command * scale
        ctx.w = ctx.w * scale

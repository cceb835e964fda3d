"""greybox's own effects by name: the catalogue (README, "Effects"), the effects tied to
a logged signal, the order a model applies them in, and the seed paper's base model."""
from __future__ import annotations

from .asymmetry import CogOffset, MotorAsymmetry
from .base import Effect
from .drag import DragMoment, HubRotorDrag, LinearDrag, QuadraticDrag, RotorDrag, Wind
from .ground import GroundEffect
from .power import BatteryVoltage, CommandDelay, RotorMap, SampledInputs, ThrustDrift
from .rotor import Gyroscopic, MomentGain, MotorLag, ThrustCurve, YawTorque
from .sensors import AccelBias, AttitudeBias, GyroBias, GyroScaleError, PositionDelay, PositionOffset

__all__ = ["CATALOGUE", "SIGNAL_EFFECTS", "APPLY_ORDER", "BASE_EFFECTS"]

CATALOGUE: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (YawTorque, LinearDrag, Gyroscopic, QuadraticDrag, RotorDrag, HubRotorDrag, DragMoment, GroundEffect,
                MotorLag, MomentGain, ThrustCurve, CogOffset, MotorAsymmetry, Wind, ThrustDrift, PositionDelay,
                PositionOffset, AttitudeBias)
}
"""The catalogue of effects (README, "Effects"), by name, in the order they are applied."""

SIGNAL_EFFECTS: dict[str, type[Effect]] = {cls.name: cls for cls in (SampledInputs, CommandDelay, RotorMap, BatteryVoltage,
                                                                     AccelBias, GyroBias, GyroScaleError)}
"""Effects beyond the catalogue, tied to what a log records (the timing of rotor speeds
sampled between rows, the delay of logged commands, a command map, the battery voltage, the
accelerometer's bias).
Applied before the catalogue's effects, since those that act on the command change it
for them (the timing first, since it moves the logged command in time; the accelerometer's
bias and the gyro's scale act on the measurement alone, so their place does not matter). ``diagnose`` considers ``sampled_inputs`` when
the inputs are rotor speeds (``w1``), ``battery_voltage`` when the log has a ``vbat`` column,
``command_delay`` when it has ``pwm1`` (rotor speeds mapped from motor commands) and
``accel_bias`` when it measures the specific force (``ax``), ``gyro_bias`` when it
measures the body rates (``p``), ``gyro_scale`` when it measures them and the log hints
at a scale error."""

APPLY_ORDER: tuple[str, ...] = tuple(SIGNAL_EFFECTS) + tuple(CATALOGUE)
"""Order in which a model applies its effects, whatever order they were composed in."""

BASE_EFFECTS: tuple[str, ...] = ("yaw_torque", "linear_drag", "gyroscopic")
"""The seed paper's model: rigid body + thrust + these."""

"""Composable physical effects (README, "Effects").

An effect is a small object that adds its own parameters, and possibly states, forces,
torques or measurement terms, to the quadrotor model — much as a PySINDy library term adds
a candidate function. Effects combine with ``+`` into an :class:`EffectLibrary`, and a
model plus an effect is a new model.

Example::

    from greybox import QuadrotorModel, effects, load_airframe
    airframe = load_airframe("greybox/data/airframes/paper.toml")
    model = QuadrotorModel(airframe) + effects.GroundEffect() + effects.MotorLag()
    model = model.without("yaw_torque")

Every parameter has a *null* value at which its effect vanishes (zero drag, zero wind,
zero delay...). The diagnosis relies on that to test whether an effect is missing.

How an effect takes part in building the model (all symbolic CasADi, see
:class:`ModelContext`):

* ``modify(ctx)``: changes what the rotors produce or what the air does before forces are
  formed — effective rotor speeds (``motor_lag``), per-rotor thrust factors
  (``ground_effect``, ``thrust_drift``, ``motor_asymmetry``), moment arms (``cog_offset``),
  air-relative velocity (``wind``).
* ``add_forces(ctx)``: adds world-frame forces and body-frame torques (drags, reaction and
  gyroscopic torques).
* ``state_derivative(ctx)``: time derivative of the effect's own extra states.
* ``modify_measurement(ctx, y)``: changes what the sensors report (``position_delay``,
  ``attitude_bias``).
"""
from __future__ import annotations

# The package's modules: ``base`` (the effect API), one module per family of effects
# (``rotor``, ``drag``, ``ground``, ``asymmetry``, ``power``, ``sensors``), ``catalogue``
# (greybox's own by name), ``registry`` (every known effect by name, the user's too) and
# ``discovered`` (the generalised forces the diagnosis' discovery finds, as effects).
from .asymmetry import CogOffset, MotorAsymmetry
from .base import Effect, EffectLibrary, ModelContext, is_derived_signal
from .catalogue import APPLY_ORDER, BASE_EFFECTS, CATALOGUE, SIGNAL_EFFECTS
from .discovered import DiscoveredEffect
from .disturbance import DisturbanceTorque, HeldMoment
from .drag import DragMoment, HubRotorDrag, LinearDrag, QuadraticDrag, RotorDrag, Wind
from .ground import GroundEffect
from .power import BatteryVoltage, CommandDelay, RotorMap, SampledInputs, ThrustDrift
from .registry import (DISTURBANCE_MODELS, ENTRY_POINT_GROUP, by_name, confusable, distinguishing_manoeuvre,
                       effect_class, example_values, known_effects, load_effects_file, measurement_only,
                       parse_effect_names, per_flight, register, registered_effects, unregister, user_hook)
from .rotor import Gyroscopic, MomentGain, MotorLag, ThrustCurve, YawTorque
from .sensors import AccelBias, AttitudeBias, GyroBias, GyroScaleError, PositionDelay, PositionOffset

__all__ = [
    "Effect", "EffectLibrary", "ModelContext", "CATALOGUE", "BASE_EFFECTS", "by_name",
    "parse_effect_names", "YawTorque", "LinearDrag", "Gyroscopic", "QuadraticDrag", "RotorDrag",
    "HubRotorDrag", "DragMoment", "GroundEffect", "MotorLag", "CogOffset", "MotorAsymmetry", "Wind", "ThrustDrift",
    "PositionDelay", "PositionOffset", "AttitudeBias", "AccelBias", "GyroBias", "GyroScaleError", "RotorMap", "BatteryVoltage", "SIGNAL_EFFECTS",
    "APPLY_ORDER", "register", "load_effects_file", "known_effects", "registered_effects",
    "effect_class", "confusable", "measurement_only", "per_flight", "distinguishing_manoeuvre", "ENTRY_POINT_GROUP",
    "example_values", "DiscoveredEffect",
    "unregister", "HeldMoment", "DisturbanceTorque", "DISTURBANCE_MODELS", "MomentGain", "ThrustCurve", "CommandDelay", "SampledInputs", "is_derived_signal",
    "user_hook",
]

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

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Iterable, Iterator

import casadi as ca
import numpy as np

from .errors import GreyboxInputError
from .parameters import Parameter

if TYPE_CHECKING:  # pragma: no cover
    from .airframe import Airframe

__all__ = [
    "Effect", "EffectLibrary", "ModelContext", "CATALOGUE", "BASE_EFFECTS", "by_name",
    "parse_effect_names", "YawTorque", "LinearDrag", "Gyroscopic", "QuadraticDrag", "RotorDrag",
    "GroundEffect", "MotorLag", "CogOffset", "MotorAsymmetry", "Wind", "ThrustDrift",
    "PositionDelay", "AttitudeBias", "RotorMap", "BatteryVoltage", "SIGNAL_EFFECTS",
    "APPLY_ORDER",
]


@dataclass
class ModelContext:
    """Symbolic quantities shared by the effects while the model is built.

    Frames: world NED, body FRD, ``R`` maps body vectors to world (README, "Conventions").
    """

    airframe: "Airframe"
    t: ca.SX
    pos: ca.SX                 # world position (3)
    euler: ca.SX               # phi, theta, psi
    v: ca.SX                   # world velocity (3)
    omega: ca.SX               # body rates p, q, r
    R: ca.SX                   # 3x3 body -> world
    w: ca.SX                   # rotor speeds acting on the air (N), rad/s
    params: dict[str, ca.SX]
    extra_states: dict[str, ca.SX]
    w_command: ca.SX = None    # rotor speeds as logged (N)
    thrust_scale: ca.SX = None  # per-rotor multiplier of K_T (N)
    torque_scale: ca.SX = None  # per-rotor multiplier of b (N)
    rotor_pos: ca.SX = None    # N x 3 rotor positions relative to the centre of gravity
    v_air: ca.SX = None        # world velocity relative to the air
    force_world: ca.SX = None  # forces added by effects (world, N)
    torque_body: ca.SX = None  # torques added by effects (body, N m)
    rotor_thrust: ca.SX = None  # per-rotor thrust magnitude along body -z (N), set by the model
    signals: dict[str, ca.SX] = None  # extra logged inputs by name (see Effect.signals)
    acc_world: ca.SX = None    # translational acceleration, set before measurement hooks


class Effect:
    """Base class of a physical effect. Subclasses set ``name`` and override hooks."""

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    signals: ClassVar[tuple[str, ...]] = ()
    """Logged signals the effect reads as extra model inputs (e.g. ``vbat``), after the
    rotor speeds in the input vector; a log supplies them as extra columns."""

    def parameters(self, airframe: "Airframe") -> list[Parameter]:
        return []

    def state_names(self, airframe: "Airframe") -> list[str]:
        return []

    def initial_state(self, airframe: "Airframe", w0: np.ndarray) -> np.ndarray:
        """Initial value of the extra states given the first logged rotor speeds."""
        return np.zeros(len(self.state_names(airframe)))

    def modify(self, ctx: ModelContext) -> None:
        pass

    def add_forces(self, ctx: ModelContext) -> None:
        pass

    def state_derivative(self, ctx: ModelContext) -> ca.SX:
        return ca.SX(0, 1)

    def modify_measurement(self, ctx: ModelContext, y: dict[str, ca.SX]) -> None:
        pass

    def options(self) -> dict:
        """Constructor arguments that make this effect what it is (e.g. ``BatteryVoltage``'s
        ``v_ref``), as saved with a fitted model: by default every instance attribute."""
        return {k: v for k, v in vars(self).items() if not k.startswith("_")}

    def with_options(self, options: dict) -> "Effect":
        """A new effect of this class built from :meth:`options`' output."""
        try:
            return type(self)(**options)
        except TypeError as e:
            raise GreyboxInputError(f"effect {self.name!r}: bad options {options!r} ({e})") from None

    # composition, PySINDy style
    def __add__(self, other: "Effect | EffectLibrary") -> "EffectLibrary":
        return EffectLibrary([self]) + other

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Effect) and other.name == self.name

    def __hash__(self) -> int:
        return hash(self.name)

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class EffectLibrary:
    """An ordered set of effects, built with ``+``; adding an effect twice is an error."""

    def __init__(self, effects: Iterable[Effect] = ()):
        self._effects: list[Effect] = []
        for e in effects:
            self._append(e)

    def _append(self, e: Effect) -> None:
        if not isinstance(e, Effect):
            raise TypeError(f"not an effect: {e!r}")
        if any(x.name == e.name for x in self._effects):
            raise GreyboxInputError(f"effect {e.name!r} is already in the model")
        self._effects.append(e)

    def __add__(self, other: "Effect | EffectLibrary | Iterable[Effect]") -> "EffectLibrary":
        out = EffectLibrary(self._effects)
        for e in ([other] if isinstance(other, Effect) else other):
            out._append(e)
        return out

    def __iter__(self) -> Iterator[Effect]:
        return iter(self._effects)

    def __len__(self) -> int:
        return len(self._effects)

    def __contains__(self, name: object) -> bool:
        if isinstance(name, Effect):
            name = name.name
        return any(e.name == name for e in self._effects)

    @property
    def names(self) -> list[str]:
        return [e.name for e in self._effects]

    def __repr__(self) -> str:
        return " + ".join(repr(e) for e in self._effects) or "EffectLibrary()"


def _sumsq_speed(v: ca.SX) -> ca.SX:
    # sqrt(v.v) has an undefined derivative at v = 0; a tiny floor keeps Jacobians finite.
    return ca.sqrt(ca.dot(v, v) + 1e-12)


# ---------------------------------------------------------------------- base-model effects
class YawTorque(Effect):
    """Rotor reaction (drag) torque ``spin_i * b * w_i**2`` about body +z.

    Without it a model cannot balance yaw and keeps rotating (the seed paper's Fig. 1).
    """

    name = "yaw_torque"
    summary = "rotor reaction torque b*w^2 about body z"

    def parameters(self, airframe):
        return [Parameter("b", 1, 5e-7, "N m/(rad/s)^2", 0.0, np.inf, 1e-6, 0.0, True,
                          "rotor reaction torque coefficient", self.name)]

    def add_forces(self, ctx):
        b = ctx.params["b"]
        spins = ca.DM(ctx.airframe.spins)
        ctx.torque_body[2] += b * ca.dot(spins * ctx.torque_scale, ctx.w ** 2)


class LinearDrag(Effect):
    """Translational drag ``F = -Kd * v_air`` per world axis (the seed paper's eq. 4)."""

    name = "linear_drag"
    summary = "translational drag -Kd*v (world axes)"

    def parameters(self, airframe):
        # upper bound: a drag time constant m/Kd below 0.1 s is no multirotor; it keeps a
        # misspecified model from running away to absurd drag
        return [Parameter("Kd", 3, 0.1, "N s/m", 0.0, 10.0 * airframe.mass, 0.1, 0.0, True,
                          "linear drag coefficients along world x, y, z", self.name)]

    def add_forces(self, ctx):
        ctx.force_world -= ctx.params["Kd"] * ctx.v_air


class Gyroscopic(Effect):
    """Rotor gyroscopic torque ``J_r * Omega_r * (omega x e_z)``, ``Omega_r = sum(spin_i*w_i)``.

    Sign convention (README, "Conventions"): roll ``+J_r*q*Omega_r``, pitch ``-J_r*p*Omega_r``.
    ``J_r`` defaults to the airframe's ``rotor_inertia`` and is held fixed when fitting
    unless freed: it is rarely identifiable from flight data.
    """

    name = "gyroscopic"
    summary = "rotor gyroscopic torque J_r*Omega_r*(omega x e_z)"

    def parameters(self, airframe):
        jr = airframe.rotor_inertia
        return [Parameter("J_r", 1, jr, "kg m^2", 0.0, np.inf, max(jr, 1e-6), 0.0, False,
                          "moment of inertia of one rotor about its axis", self.name)]

    def add_forces(self, ctx):
        omega_r = ca.dot(ca.DM(ctx.airframe.spins), ctx.w)
        p, q = ctx.omega[0], ctx.omega[1]
        jr = ctx.params["J_r"]
        ctx.torque_body += jr * omega_r * ca.vertcat(q, -p, 0)


# ---------------------------------------------------------------------- candidate effects
class QuadraticDrag(Effect):
    """Parasitic (pressure) drag ``F_i = -Kq_i * |v_air| * v_air_i`` along world axes."""

    name = "quadratic_drag"
    summary = "parasitic drag -Kq*|v|*v"

    def parameters(self, airframe):
        return [Parameter("Kq", 3, 0.0, "N s^2/m^2", 0.0, 10.0 * airframe.mass, 0.01, 0.0, True,
                          "quadratic drag coefficients along world x, y, z", self.name)]

    def add_forces(self, ctx):
        ctx.force_world -= ctx.params["Kq"] * _sumsq_speed(ctx.v_air) * ctx.v_air


class RotorDrag(Effect):
    """Rotor induced drag / blade flapping: a horizontal body-frame force
    ``F_b = -k_rd * sum(w_i) * [vb_x, vb_y, 0]`` with ``vb = R^T v_air`` the body-frame air
    velocity. It grows with rotor speed, which separates it from ``linear_drag`` when the
    thrust changes.
    """

    name = "rotor_drag"
    summary = "rotor drag -k_rd*sum(w)*v_body (horizontal, body frame)"

    def parameters(self, airframe):
        return [Parameter("k_rd", 1, 0.0, "N s/m/(rad/s)", 0.0, np.inf, 1e-5, 0.0, True,
                          "rotor drag per unit rotor speed and body velocity", self.name)]

    def add_forces(self, ctx):
        vb = ctx.R.T @ ctx.v_air
        fb = -ctx.params["k_rd"] * ca.sum1(ctx.w) * ca.vertcat(vb[0], vb[1], 0)
        ctx.force_world += ctx.R @ fb


class GroundEffect(Effect):
    """Thrust increase near the ground (Cheeseman–Bennett):
    ``T_IGE / T = 1 / (1 - k_ge / h**2)`` with ``h = ground_z - z`` the height above the
    ground plane and ``k_ge = (R_rotor/4)**2``. The ratio ``k_ge/h**2`` is capped at 0.5
    (factor 2) so the model stays finite on the ground.
    """

    name = "ground_effect"
    summary = "thrust increase close to the ground, 1/(1 - k_ge/h^2)"

    def parameters(self, airframe):
        return [Parameter("k_ge", 1, 0.0, "m^2", 0.0, 1.0, 1e-3, 0.0, True,
                          "ground-effect coefficient (rotor radius / 4)^2", self.name)]

    def modify(self, ctx):
        h = ca.fmax(ctx.airframe.ground_z - ctx.pos[2], 1e-3)
        ratio = ca.fmin(ctx.params["k_ge"] / h ** 2, 0.5)
        ctx.thrust_scale *= 1.0 / (1.0 - ratio)


class MotorLag(Effect):
    """First-order lag between logged and effective rotor speed:
    ``dw_eff/dt = (w_logged - w_eff) / tau_m``. Adds one state per rotor (``w_eff1``...),
    started at the first logged speeds (steady motors).
    """

    name = "motor_lag"
    summary = "first-order motor lag, time constant tau_m"

    def parameters(self, airframe):
        # The lower bound keeps the fixed-step integrators stable (see integrate.MAX_STEP).
        return [Parameter("tau_m", 1, 0.02, "s", 2e-3, 1.0, 0.02, 0.0, True,
                          "motor time constant", self.name)]

    def state_names(self, airframe):
        return [f"w_eff{i + 1}" for i in range(airframe.n_rotors)]

    def initial_state(self, airframe, w0):
        return np.asarray(w0, dtype=float).copy()

    def modify(self, ctx):
        ctx.w = ctx.extra_states[self.name]

    def state_derivative(self, ctx):
        return (ctx.w_command - ctx.extra_states[self.name]) / ctx.params["tau_m"]


class CogOffset(Effect):
    """Centre of gravity displaced by ``r_cog = [dx, dy]`` (body frame) from the centre of
    the rotor plane: every thrust moment arm becomes ``r_i - r_cog``, so hover needs
    unequal rotor speeds and a level hover with equal speeds pitches/rolls.
    """

    name = "cog_offset"
    summary = "centre of gravity offset from the rotor centre"

    def parameters(self, airframe):
        return [Parameter("r_cog", 2, 0.0, "m", -0.5, 0.5, 0.01, 0.0, True,
                          "centre-of-gravity offset along body x, y", self.name)]

    def modify(self, ctx):
        c = ctx.params["r_cog"]
        n = ctx.airframe.n_rotors
        ctx.rotor_pos = ctx.rotor_pos - ca.repmat(ca.horzcat(c[0], c[1], 0), n, 1)


class MotorAsymmetry(Effect):
    """Per-rotor thrust (and reaction torque) factors ``1 + d_i``, a weak or damaged rotor.

    The parameter ``K_T_dev`` holds ``d_1..d_{N-1}``; ``d_N = -sum(d_1..d_{N-1})`` so that
    ``K_T`` stays the rotors' mean coefficient and the deviations are identifiable.
    """

    name = "motor_asymmetry"
    summary = "per-rotor thrust factors 1+d_i (sum d_i = 0)"

    def parameters(self, airframe):
        return [Parameter("K_T_dev", airframe.n_rotors - 1, 0.0, "1", -0.9, 0.9, 0.05, 0.0, True,
                          "relative thrust deviation of rotors 1..N-1", self.name)]

    def modify(self, ctx):
        d = ctx.params["K_T_dev"]
        factors = 1.0 + ca.vertcat(d, -ca.sum1(d))
        ctx.thrust_scale *= factors
        ctx.torque_scale *= factors


class Wind(Effect):
    """Constant horizontal wind ``[w_N, w_E]`` (m/s, world): every drag effect acts on the
    velocity relative to the air, ``v_air = v - wind``. It needs a drag effect to matter.
    """

    name = "wind"
    summary = "constant horizontal wind; drag acts on v - wind"

    def parameters(self, airframe):
        return [Parameter("wind", 2, 0.0, "m/s", -30.0, 30.0, 1.0, 0.0, True,
                          "wind velocity, world north and east", self.name)]

    def modify(self, ctx):
        wnd = ctx.params["wind"]
        ctx.v_air = ctx.v_air - ca.vertcat(wnd[0], wnd[1], 0)


class ThrustDrift(Effect):
    """Thrust coefficient drifting linearly over the flight (battery sag):
    ``K_T(t) = K_T * (1 + K_T_drift * t)``, t in seconds from the log's start.
    """

    name = "thrust_drift"
    summary = "thrust coefficient drifting linearly in time"

    def parameters(self, airframe):
        return [Parameter("K_T_drift", 1, 0.0, "1/s", -0.05, 0.05, 1e-3, 0.0, True,
                          "relative change of K_T per second", self.name)]

    def modify(self, ctx):
        ctx.thrust_scale *= 1.0 + ctx.params["K_T_drift"] * ctx.t


class PositionDelay(Effect):
    """Latency ``tau_pos`` of the position measurement (vision pipeline): the sensor
    reports ``p(t - tau_pos)``, modelled by its second-order Taylor expansion
    ``p - tau_pos*v + tau_pos**2/2 * a`` (exact to ``tau^3 * jerk / 6``: sub-millimetre for
    latencies below 0.1 s in ordinary flight), so no delay states are needed.
    """

    name = "position_delay"
    summary = "latency of the position measurement"

    def parameters(self, airframe):
        return [Parameter("tau_pos", 1, 0.0, "s", 0.0, 0.3, 0.02, 0.0, True,
                          "position measurement latency", self.name)]

    def modify_measurement(self, ctx, y):
        tau = ctx.params["tau_pos"]
        for i, ch in enumerate("xyz"):
            y[ch] = y[ch] - tau * ctx.v[i] + 0.5 * tau ** 2 * ctx.acc_world[i]


class AttitudeBias(Effect):
    """Constant offsets of the measured roll and pitch (IMU mounting misalignment):
    ``phi_meas = phi + att_bias[0]``, ``theta_meas = theta + att_bias[1]``.
    """

    name = "attitude_bias"
    summary = "constant roll/pitch measurement offsets"

    def parameters(self, airframe):
        return [Parameter("att_bias", 2, 0.0, "rad", -0.3, 0.3, 0.01, 0.0, True,
                          "roll and pitch measurement offsets", self.name)]

    def modify_measurement(self, ctx, y):
        y["phi"] = y["phi"] + ctx.params["att_bias"][0]
        y["theta"] = y["theta"] + ctx.params["att_bias"][1]


class RotorMap(Effect):
    """A constant offset ``w_offset`` (rad/s) added to the logged rotor speeds.

    For logs whose speeds come from a command through an affine map ``w = a*cmd + c``
    (e.g. Crazyflie PWM), this fits the map: a wrong slope ``a`` is absorbed exactly by
    ``K_T`` and ``b`` (thrust is ``K_T*w^2``), so the offset is the one coefficient left
    to identify. Applied before the other effects (it changes the command itself).
    """

    name = "rotor_map"
    summary = "offset of the logged rotor speeds (command-to-speed map)"

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


CATALOGUE: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (YawTorque, LinearDrag, Gyroscopic, QuadraticDrag, RotorDrag, GroundEffect,
                MotorLag, CogOffset, MotorAsymmetry, Wind, ThrustDrift, PositionDelay,
                AttitudeBias)
}
"""The catalogue of effects (README, "Effects"), by name, in the order they are applied."""

SIGNAL_EFFECTS: dict[str, type[Effect]] = {cls.name: cls for cls in (RotorMap, BatteryVoltage)}
"""Effects beyond the catalogue, tied to what a log records (a command map, the
battery voltage). Applied before the catalogue's effects, since they change the command.
``diagnose`` considers ``battery_voltage`` when the log has a ``vbat`` column."""

APPLY_ORDER: tuple[str, ...] = tuple(SIGNAL_EFFECTS) + tuple(CATALOGUE)
"""Order in which a model applies its effects, whatever order they were composed in."""

BASE_EFFECTS: tuple[str, ...] = ("yaw_torque", "linear_drag", "gyroscopic")
"""The seed paper's model: rigid body + thrust + these."""


def by_name(name: str) -> Effect:
    """A new effect object from its catalogue name."""
    cls = CATALOGUE.get(name) or SIGNAL_EFFECTS.get(name)
    if cls is None:
        raise GreyboxInputError(f"unknown effect {name!r}; known effects: "
                                f"{', '.join(list(CATALOGUE) + list(SIGNAL_EFFECTS))}")
    return cls()


def parse_effect_names(text: str | None) -> list[str]:
    """Split a comma-separated list of effect names, checking each one."""
    if not text:
        return []
    names = [s.strip() for s in text.split(",") if s.strip()]
    for n in names:
        by_name(n)
    return names


def example_values(name: str, airframe: "Airframe", K_T: float) -> dict[str, float | list[float]]:
    """Physically plausible magnitudes of an effect for this airframe, used by
    :mod:`greybox.synth` when a hidden effect is added without explicit values."""
    m, arm, n = airframe.mass, max(airframe.arm_length, 1e-3), airframe.n_rotors
    w_hover = float(np.sqrt(m * airframe.gravity / (n * K_T)))
    r_rotor = 0.5 * arm
    values: dict[str, dict[str, float | list[float]]] = {
        "quadratic_drag": {"Kq": [0.04 * m ** (2 / 3)] * 3},
        "rotor_drag": {"k_rd": 0.35 * m / (n * w_hover)},
        "ground_effect": {"k_ge": (r_rotor / 4) ** 2 * 4},
        "motor_lag": {"tau_m": 0.03},
        "cog_offset": {"r_cog": [0.06 * arm, -0.04 * arm]},
        "motor_asymmetry": {"K_T_dev": [-0.08] + [0.08 / (n - 1)] * (n - 2)},
        "wind": {"wind": [1.5, -1.0]},
        "thrust_drift": {"K_T_drift": -0.002},
        "position_delay": {"tau_pos": 0.04},
        "attitude_bias": {"att_bias": [0.02, -0.015]},
    }
    return values.get(name, {})


__all__.append("example_values")

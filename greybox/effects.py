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
    "HubRotorDrag", "GroundEffect", "MotorLag", "CogOffset", "MotorAsymmetry", "Wind", "ThrustDrift",
    "PositionDelay", "AttitudeBias", "RotorMap", "BatteryVoltage", "SIGNAL_EFFECTS",
    "APPLY_ORDER", "register", "load_effects_file", "known_effects", "registered_effects",
    "effect_class", "distinguishing_manoeuvre", "ENTRY_POINT_GROUP",
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
    excited_by: ClassVar[str] = ""
    """The manoeuvre in which the effect shows (diagnosis advice)."""
    fit_advice: ClassVar[str] = ""
    """What to fly to pin its parameters down (fit warnings); default :attr:`excited_by`."""
    channels: ClassVar[tuple[str, ...]] = ()
    """Output channels the effect should improve when it is missing (before/after tables)."""
    distinguish: ClassVar[dict[str, str]] = {}
    """``{other effect: manoeuvre}`` that tells this effect apart from a confusable one
    (looked up both ways, see :func:`distinguishing_manoeuvre`)."""
    shifts_trim: ClassVar[bool] = False
    """Whether it changes where, or with which rotor speeds, a level hover balances (the
    closed-form hover trim then does not apply)."""
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

    def plausible_values(self, airframe: "Airframe", K_T: float) -> dict:
        """Physically plausible parameter magnitudes for this airframe (synthetic flights, a
        diagnosis' cold refits, the negligibility test); ``{}``: use the parameters' scales."""
        return {}

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
    excited_by = 'yaw turns'
    fit_advice = 'yaw steps (yaw) with large rotor-speed differences'
    channels = ('psi', 'r')

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
    excited_by = 'translations at moderate speed along each axis'
    fit_advice = 'fast translations (fast) along each axis, and vertical steps for Kd[2]'
    channels = ('x', 'y', 'z')
    distinguish = {
        'rotor_drag': 'fly the same speeds at different thrust levels (climbing and descending translations): rotor drag scales with rotor speed',
    }

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
    excited_by = 'fast roll and pitch motions during yaw turns'
    fit_advice = 'fast roll/pitch motions with high rotor speeds'
    channels = ('phi', 'theta', 'p', 'q')

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
    excited_by = 'translations at several speeds, up to the fastest you can fly'
    fit_advice = 'translations at several different speeds (fast)'
    channels = ('x', 'y', 'z')
    distinguish = {
        'rotor_drag': 'fly several speeds at a constant thrust, and the same speed at another thrust',
        'wind': 'fly the same speed upwind and downwind',
    }

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
    excited_by = 'translations at one speed with different thrust (climbing, descending)'
    fit_advice = 'horizontal flight at different thrust levels (fast, step_z while moving)'
    channels = ('x', 'y')
    distinguish = {
        'wind': 'fly in several directions: wind has a fixed direction',
    }

    def parameters(self, airframe):
        return [Parameter("k_rd", 1, 0.0, "N s/m/(rad/s)", 0.0, np.inf, 1e-5, 0.0, True,
                          "rotor drag per unit rotor speed and body velocity", self.name)]

    def add_forces(self, ctx):
        vb = ctx.R.T @ ctx.v_air
        fb = -ctx.params["k_rd"] * ca.sum1(ctx.w) * ca.vertcat(vb[0], vb[1], 0)
        ctx.force_world += ctx.R @ fb


class HubRotorDrag(Effect):
    """Rotor drag at each hub, on the hub's own air velocity: rotor ``i`` at ``r_i`` (body,
    from the centre of gravity) sees ``v_i = R^T v_air + omega x r_i`` and feels
    ``F_i = -w_i * [k_rdh v_ix, k_rdh v_iy, k_rdv v_iz]`` (body frame), with the torque
    ``r_i x F_i``. Summed over rotors the force is ``rotor_drag``'s (to first order), but
    the ``omega x r_i`` term also damps the body rates — roll and pitch through the vertical
    part (a rolling vehicle's descending rotors push up), yaw through the horizontal part — so
    a model without it pushes ``b`` down to absorb the yaw damping. ``k_rdv`` (a thrust that
    falls with the rotor's axial inflow) is fitted too.
    """

    name = "hub_rotor_drag"
    summary = "rotor drag at each hub on R^T v + omega x r_i (also damps body rates)"
    excited_by = "translations at different thrust levels and fast roll, pitch and yaw rates"
    fit_advice = "fast translations at several thrust levels, and fast yaw turns and roll/pitch steps"
    channels = ("x", "y", "z", "p", "q", "r", "phi", "theta", "psi")
    distinguish = {
        "rotor_drag": "fast yaw turns and roll/pitch steps: the hub form damps the body rates, the "
                      "centre-of-gravity form does not",
        "linear_drag": "fly the same speeds at different thrust levels: rotor drag scales with rotor speed",
    }

    def parameters(self, airframe):
        return [Parameter("k_rdh", 1, 0.0, "N s/m/(rad/s)", 0.0, np.inf, 1e-5, 0.0, True,
                          "in-plane drag per unit rotor speed and hub air velocity", self.name),
                Parameter("k_rdv", 1, 0.0, "N s/m/(rad/s)", 0.0, np.inf, 1e-5, 0.0, True,
                          "axial (thrust-axis) drag per unit rotor speed and hub air velocity", self.name)]

    def plausible_values(self, airframe, K_T):
        m, n = airframe.mass, airframe.n_rotors
        w_hover = float(np.sqrt(m * airframe.gravity / (n * K_T)))
        k = 0.35 * m / (n * w_hover)
        return {"k_rdh": k, "k_rdv": 0.5 * k}

    def add_forces(self, ctx):
        vb = ctx.R.T @ ctx.v_air
        k = ca.vertcat(ctx.params["k_rdh"], ctx.params["k_rdh"], ctx.params["k_rdv"])
        force = ca.SX.zeros(3)
        torque = ca.SX.zeros(3)
        for i in range(ctx.airframe.n_rotors):
            r = ctx.rotor_pos[i, :].T
            f = -ctx.w[i] * k * (vb + ca.cross(ctx.omega, r))
            force += f
            torque += ca.cross(r, f)
        ctx.force_world += ctx.R @ force
        ctx.torque_body += torque


class GroundEffect(Effect):
    """Thrust increase near the ground (Cheeseman–Bennett):
    ``T_IGE / T = 1 / (1 - k_ge / h**2)`` with ``h = ground_z - z`` the height above the
    ground plane and ``k_ge = (R_rotor/4)**2``. The ratio ``k_ge/h**2`` is capped at 0.5
    (factor 2) so the model stays finite on the ground.
    """

    name = "ground_effect"
    summary = "thrust increase close to the ground, 1/(1 - k_ge/h^2)"
    excited_by = 'low passes close to the ground (below about two rotor diameters)'
    fit_advice = 'a slow pass close to the ground (ground)'
    channels = ('z',)
    shifts_trim = True

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
    excited_by = 'fast rotor-speed changes (steps, excitation)'
    fit_advice = 'rapid rotor-speed changes (steps, excitation)'
    channels = ('phi', 'theta', 'p', 'q', 'z')
    distinguish = {
        'position_delay': 'fast rotor-speed steps with attitude recorded: motor lag delays attitude too, a vision delay only position',
    }

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
    excited_by = 'hovers and roll/pitch steps at several thrust levels'
    fit_advice = 'hover and attitude steps'
    channels = ('phi', 'theta', 'p', 'q', 'x', 'y')
    distinguish = {
        'motor_asymmetry': 'hover at several thrust levels and yaw angles',
        'attitude_bias': 'fly roll and pitch steps: a bias shifts readings, an offset needs torque',
    }
    shifts_trim = True

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
    excited_by = 'hovers at several thrust levels and yaw turns'
    fit_advice = 'roll and pitch steps with varied thrust'
    channels = ('phi', 'theta', 'p', 'q', 'psi', 'r', 'x', 'y')
    shifts_trim = True

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
    excited_by = 'flight in several directions (wind keeps one direction)'
    fit_advice = 'horizontal flight in several directions'
    channels = ('x', 'y')
    shifts_trim = True

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
    excited_by = 'the same manoeuvre repeated early and late in the flight'
    fit_advice = 'a longer flight, repeating the same manoeuvres early and late'
    channels = ('z',)
    distinguish = {
        'ground_effect': 'repeat the same climb early and late in the flight, away from the ground',
        'battery_voltage': 'vary the thrust level: the voltage sags with the current drawn, time does not',
    }
    shifts_trim = True

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
    excited_by = 'fast translations (a delay lags the velocity)'
    fit_advice = 'fast translations (fast)'
    channels = ('x', 'y', 'z')

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
    excited_by = 'long hovers at several headings'
    fit_advice = 'hover and slow translations'
    channels = ('phi', 'theta', 'x', 'y')

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


CATALOGUE: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (YawTorque, LinearDrag, Gyroscopic, QuadraticDrag, RotorDrag, HubRotorDrag, GroundEffect,
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


_REGISTERED: dict[str, type[Effect]] = {}     # user effects: register(), files, entry points
_REGISTERED_FROM: dict[str, str] = {}
_FROM_FILE: dict[str, bool] = {}
_ENTRY_POINTS_LOADED = False
ENTRY_POINT_GROUP = "greybox.effects"
"""Installed packages offer effects through this entry-point group (``name = module:Class``)."""


def register(cls: type[Effect], source: str = "register()", from_file: bool = False) -> type[Effect]:
    """Make an :class:`Effect` subclass usable everywhere a catalogue effect is: in
    ``QuadrotorModel(..., [name])``, ``--effects``/``--without``/``--candidates``, as a default
    diagnosis candidate, in an airframe's ``[parameters]`` and ``--set``. Returns ``cls``, so
    it works as a class decorator.

    Example::

        @greybox.effects.register
        class RateDamping(greybox.effects.Effect):
            name = "rate_damping"
            summary = "body-rate damping -k*omega"
            channels = ("p", "q", "r")
            def parameters(self, airframe):
                return [Parameter("k_w", 3, 0.0, "N m s", 0.0, 1.0, 1e-4, 0.0, True,
                                  "rate damping per axis", self.name)]
            def add_forces(self, ctx):
                ctx.torque_body -= ctx.params["k_w"] * ctx.omega
    """
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise GreyboxInputError(f"{source}: {cls!r} is not an Effect subclass")
    name = getattr(cls, "name", "")
    if not isinstance(name, str) or not name.isidentifier() or name != name.lower():
        raise GreyboxInputError(f"{source}: effect class {cls.__name__} needs a unique lowercase name that is "
                                f"an identifier, got {name!r}")
    builtin = CATALOGUE.get(name) or SIGNAL_EFFECTS.get(name)
    if builtin is not None and builtin is not cls:
        raise GreyboxInputError(f"{source}: effect name {name!r} is already taken by greybox's "
                                f"{builtin.__qualname__}")
    known = _REGISTERED.get(name)
    # an effects file loaded again (edited, or another copy) replaces its earlier version;
    # two different classes registered in code under one name are a clash
    if known is not None and not _same_class(known, cls) and not (_FROM_FILE.get(name) and from_file):
        raise GreyboxInputError(f"{source}: effect name {name!r} is already taken by "
                                f"{known.__module__}.{known.__qualname__} ({_REGISTERED_FROM[name]})")
    try:
        obj = cls()
    except Exception as e:   # noqa: BLE001 - any failure to build is the user's to fix
        raise GreyboxInputError(f"{source}: effect {name!r} cannot be created without arguments ({e})") from None
    _check_hooks(obj, source)
    _REGISTERED[name] = cls
    _REGISTERED_FROM[name] = source
    _FROM_FILE[name] = from_file
    return cls


def _check_hooks(effect: Effect, source: str) -> None:
    """Call the hooks that need no model on a generic airframe, so that an effect that
    cannot describe itself fails here with its file and line, not deep in a fit."""
    import traceback
    from .airframe import airframe_from_dict
    af = airframe_from_dict({"airframe": {"name": "check", "mass": 1.0, "inertia": [0.01, 0.01, 0.02],
                                          "arm_length": 0.2, "layout": "x"}}, source="effect check")
    try:
        params = effect.parameters(af)
        states = effect.state_names(af)
        for p in params:
            if not isinstance(p, Parameter):
                raise TypeError(f"parameters() must return Parameter objects, got {type(p).__name__}")
        if not all(isinstance(n, str) for n in states):
            raise TypeError("state_names() must return strings")
    except Exception as e:   # noqa: BLE001 - the user's code: one line saying where
        tb = traceback.extract_tb(e.__traceback__)
        where = f", line {tb[-1].lineno}" if tb else ""
        raise GreyboxInputError(f"{source}{where}: effect {effect.name!r}: {type(e).__name__}: {e}") from None


def _same_class(a: type, b: type) -> bool:
    # the same class loaded twice (a file given twice, a module reloaded) is not a clash
    return a is b or (a.__qualname__ == b.__qualname__ and a.__module__ == b.__module__)


def load_effects_file(path) -> list[str]:
    """Run a Python file and register every :class:`Effect` subclass with a ``name`` defined
    in it (``--effects-file``). Returns their names. Errors name the file (and line)."""
    import importlib.util
    import traceback
    from pathlib import Path
    path = Path(path)
    if not path.is_file():
        raise GreyboxInputError(f"{path}: effects file not found")
    mod_name = f"greybox_user_effects_{abs(hash(str(path.resolve())))}"
    spec = importlib.util.spec_from_file_location(mod_name, path)
    module = importlib.util.module_from_spec(spec)
    import sys
    sys.modules[mod_name] = module      # dataclasses and pickling look classes up by module
    try:
        spec.loader.exec_module(module)
    except GreyboxInputError:
        raise
    except (Exception, SystemExit) as e:   # noqa: BLE001 - the user's file: one line saying where it failed
        frames = [f for f in traceback.extract_tb(e.__traceback__) if Path(f.filename) == path]
        where = f", line {frames[-1].lineno}" if frames else (f", line {e.lineno}" if getattr(e, "lineno", None) else "")
        raise GreyboxInputError(f"{path}{where}: {type(e).__name__}: {e}") from None
    names = []
    for obj in vars(module).values():
        if isinstance(obj, type) and issubclass(obj, Effect) and obj.__module__ == mod_name and obj.name:
            register(obj, source=str(path), from_file=True)
            names.append(obj.name)
    if not names:
        raise GreyboxInputError(f"{path}: defines no Effect subclass with a name")
    return names


def _load_entry_points() -> None:
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return
    _ENTRY_POINTS_LOADED = True
    from importlib.metadata import entry_points
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            register(ep.load(), source=f"entry point {ep.name} ({ep.value})")
        except Exception as e:   # noqa: BLE001 - a broken plugin must not break greybox
            import warnings
            warnings.warn(f"effect plugin {ep.name} ({ep.value}) not loaded: {e}", stacklevel=2)


def known_effects() -> dict[str, type[Effect]]:
    """Every effect by name: the catalogue, the signal effects, then registered ones."""
    _load_entry_points()
    return {**CATALOGUE, **SIGNAL_EFFECTS, **_REGISTERED}


def registered_effects() -> dict[str, str]:
    """``{name: where it came from}`` of the effects registered beyond greybox's own."""
    _load_entry_points()
    return dict(_REGISTERED_FROM)


def effect_class(name: str) -> type[Effect]:
    """The class of a known effect (see :func:`known_effects`)."""
    cls = known_effects().get(name)
    if cls is None:
        raise GreyboxInputError(f"unknown effect {name!r}; known effects: {', '.join(known_effects())} "
                                "(effects of your own: --effects-file FILE.py or greybox.effects.register)")
    return cls


def by_name(name: str) -> Effect:
    """A new effect object from its name (catalogue or registered)."""
    return effect_class(name)()


def distinguishing_manoeuvre(a: str, b: str) -> str:
    """What to fly to tell effects ``a`` and ``b`` apart (from the effects' own
    ``distinguish`` and ``excited_by``)."""
    known = known_effects()
    ca_, cb = known.get(a), known.get(b)
    hint = (ca_.distinguish.get(b) if ca_ else None) or (cb.distinguish.get(a) if cb else None)
    if hint:
        return hint
    if ca_ and cb and ca_.excited_by and cb.excited_by:
        return f"{a} shows in {ca_.excited_by}, {b} in {cb.excited_by}: fly one without the other"
    return "fly manoeuvres that excite one and not the other"


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
    if name in values:
        return values[name]
    cls = known_effects().get(name)
    return cls().plausible_values(airframe, K_T) if cls is not None else {}


__all__.append("example_values")

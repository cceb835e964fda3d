"""The effect API: :class:`ModelContext` (the symbolic quantities an effect reads and
changes while the model is built), :class:`Effect` (the base class and its hooks) and
:class:`EffectLibrary` (effects composed with ``+``). Public and kept compatible (README,
"Effects of your own")."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Iterable, Iterator, Mapping, Sequence

import casadi as ca
import numpy as np

from ..errors import GreyboxInputError
from ..parameters import Parameter

if TYPE_CHECKING:  # pragma: no cover
    from ..airframe import Airframe
    from ..data import FlightLog

__all__ = ["ModelContext", "Effect", "EffectLibrary", "is_derived_signal"]


def is_derived_signal(name: str) -> bool:
    """Whether an input name is a signal an effect derives from the log
    (:meth:`Effect.derived_signals`, e.g. ``w1@10ms``) rather than a logged column."""
    return "@" in name


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
    thrust_torque: ca.SX = None  # the rotor thrusts' moment about the CoG (body, N m), set by the model
    signals: dict[str, ca.SX] = None  # extra logged inputs by name (see Effect.signals)
    acc_world: ca.SX = None    # translational acceleration, set before measurement hooks
    w_row_mean: ca.SX = None   # the speeds an effect made a row's mean (sampled_inputs), and
    w_at_sample: ca.SX = None  # the speeds at the row's sample instant, for instantaneous sensors


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
    trim_evidence: ClassVar[tuple[str, ...]] = ()
    """What in the logged commands of steady flight points at this effect before any fit
    (:class:`~greybox.diagnosis.CommandImbalance`): ``"steady"`` (rotors driven unequally on
    average), ``"speed"`` (a roll/pitch trim that follows the body speed). The diagnosis
    refits an effect the evidence points at even when its score test, taken at a baseline
    that absorbs much into process noise, ranks it low."""
    signals: ClassVar[tuple[str, ...]] = ()
    """Logged signals the effect reads as extra model inputs (e.g. ``vbat``), after the
    rotor speeds in the input vector; a log supplies them as extra columns."""
    signal_limits: ClassVar[dict[str, tuple[float, str, str]]] = {}
    """``{signal: (largest plausible typical magnitude, unit, the likely mistake)}``: a log whose
    signal is typically (its median) beyond it is refused, naming the mistake (``vbat`` in
    millivolts)."""
    rate_of_unmodelled: ClassVar[dict[str, str]] = {}
    """``{its state: another state}`` for a disturbance state that is the rate of change of
    what the model leaves out of that other state (``d_p`` of ``p``). A fit with process noise
    starts its random walk at the other state's shooting gaps per second: the base model's
    gaps in ``p`` are the unmodelled torque over one interval."""
    systematic_gap_words: ClassVar[str] = ""
    """What its own states' shooting gaps say when, in a fit with process noise, they are
    mostly systematic (:meth:`~greybox.fitting.Certificate.off_states`): the law those states
    follow does not hold there. Default (and for the body's states): a force or torque the
    model lacks."""
    scales_commanded_moment: ClassVar[bool] = False
    """Whether its torque is a multiple of the moment the logged commands give. A closed-loop
    controller answers a torque the model lacks through the commands (they carry minus that
    torque), so such an effect can take up part of any unmodelled torque by scaling the
    commands' moment down. When it leaves the body rates far off, the diagnosis judges it again
    with a random-walk disturbance torque in the model (:func:`~greybox.diagnosis.ranking.rank_round`)."""
    scales_reaction_torques: ClassVar[bool] = False
    """Whether its parameters scale the rotors' reaction torques one by one (per-rotor gains
    on thrust and torque). They can then hold a difference between the spin directions,
    which with a propeller's ``b`` is a steady yaw torque the commands cancel; a fit from a
    baseline whose ``b`` went to near zero stays there. The diagnosis refits such an effect
    also with ``b`` first held at the airframe's value (:func:`~greybox.diagnosis.screening.refit`)."""
    input_timed: ClassVar[tuple[str, ...]] = ()
    """Its parameters that are times measured against the logged inputs (a lag, a delay):
    whether a row's logged value holds for the whole row or is a sample of a signal varying
    within it moves them by up to half a row, beyond what their std count (a blind audit's
    200 Hz log of a 400 Hz controller: tau_m 28.7 ms for 30, tau_pos 38.9 for 40)."""
    shape_parameters: ClassVar[tuple[str, ...]] = ()
    """Its parameters that shape the effect but do not make it: with the others at their null
    values it vanishes whatever these are (``hub_rotor_drag``'s hub height: a drag of zero acts
    at any height). Their size alone never makes the effect physically non-negligible."""
    per_flight: ClassVar[bool] = False
    """Whether its parameters belong to one flight rather than to the vehicle (the day's
    wind, the battery's state): a fit of several flights with ``per_flight="auto"`` gives
    each flight its own copy of them and shares the rest."""
    describes_sampling: ClassVar[bool] = False
    """Whether its parameters describe how the log samples a signal rather than the vehicle
    (``sampled_inputs``' share of the next row, which follows how fast the speeds change within
    a row, so each part of a flight has its own): two halves of a flight that disagree on them
    are no sign of something missing (a blind audit's control flight: s_lead 0.56 and 0.70,
    warned as "absorbing something the model lacks")."""
    considered_when_logged: ClassVar[tuple[str, ...]] = ()
    """Log columns (inputs, extra signals or measured outputs) whose presence in every flight
    makes :func:`~greybox.diagnose` try this effect although it reads no logged signal
    (``command_delay``: ``pwm1``, the rotor speeds are mapped from logged motor commands;
    ``accel_bias``: ``ax``, the accelerometer is measured)."""

    @classmethod
    def considered_for(cls, logs: Sequence["FlightLog"]) -> bool:
        """Whether :func:`~greybox.diagnose` tries this effect by default on these estimation
        flights, beyond the columns it needs (:attr:`considered_when_logged`): a sign of it in
        the log alone (``gyro_scale``: the gyro's reading against the attitude). Default: yes."""
        return True

    @classmethod
    def mimicked_by_sensor_offsets(cls, logs: Sequence["FlightLog"]) -> bool:
        """Whether, on these estimation flights, a sensor's constant offset (an effect that is
        :meth:`measurement_only`: ``accel_bias``) can act on the data as this condition of the
        flight (:attr:`per_flight`) does. Where the validation cannot tell the two apart and
        this holds, the diagnosis's tie rule takes the offset, which is there on every flight,
        before a claim about this one; where it does not, the estimation data decide. Default:
        yes (``wind`` says no where the flights turned: a force fixed in the world against an
        offset fixed in the body)."""
        return True

    def parameters(self, airframe: "Airframe") -> list[Parameter]:
        return []

    def derived_signals(self, commands: Sequence[str]) -> list[str]:
        """Signals the effect computes from the log itself instead of reading a logged column
        (``command_delay``: each command ``w1`` at earlier times, ``w1@10ms``), given the
        model's command names. They follow :attr:`signals` in the model's inputs; their
        names contain ``@`` (:func:`is_derived_signal`). Default: none."""
        return []

    def derive_signals(self, t: np.ndarray, commands: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Values of :meth:`derived_signals` on a log with sample times ``t`` and command
        columns ``commands`` (by name)."""
        return {}

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

    @classmethod
    def measurement_only(cls) -> bool:
        """Whether the effect changes only what a sensor reports, not how the vehicle moves: it
        overrides :meth:`modify_measurement` and none of :meth:`modify`, :meth:`add_forces`,
        :meth:`state_derivative` (``accel_bias``, ``attitude_bias``)."""
        motion = ("modify", "add_forces", "state_derivative")
        return (cls.modify_measurement is not Effect.modify_measurement
                and all(getattr(cls, hook) is getattr(Effect, hook) for hook in motion))

    def plausible_limits(self, airframe: "Airframe") -> dict[str, float]:
        """The largest magnitude ``|value - null|`` each parameter can physically have on this
        airframe (``{name: limit}``); a fit beyond it has the parameter standing in for
        something else. Default ``{}``: no limit known."""
        return {}

    def validation_reading(self, logs: Sequence["FlightLog"], values: dict, std: dict) -> str:
        """Words saying that the validation flights ``logs``' own data, read without the model,
        show this effect as fitted (``values``, ``std``: the refit's parameters by name), for an
        effect whose fitted values move the predictions too little for their error to confirm
        it (a sensor's offset); "" when it has no such reading or the data do not show it
        (default). ``gyro_bias``: the validation flights' gyro against their attitude's turning."""
        return ""

    def negligible_size(self, airframe: "Airframe") -> dict[str, float]:
        """The magnitude ``|value - null|`` below which each parameter is physically negligible
        on this airframe (``{name: size}``), where a share of :meth:`plausible_values` is not
        the right yardstick (a gyro's scale: what a calibration leaves). Default ``{}``: the
        diagnosis takes 1 % of the plausible value."""
        return {}

    def plausibility_warnings(self, values: dict[str, float], std: dict[str, float],
                              airframe: "Airframe") -> list[str]:
        """Warnings, in words, when the fitted values of this effect's free parameters are
        physically implausible for the airframe (a fit that reached them explained the data
        with the parameter standing in for something else). ``values``: every parameter by
        component name; ``std``: the free ones' (a fixed parameter is absent: no warning
        about it). Default: the components beyond :meth:`plausible_limits`."""
        limits = self.plausible_limits(airframe)
        beyond = []
        for par in self.parameters(airframe):
            if par.name not in limits:
                continue
            for comp in par.component_names:
                if comp in std and comp in values and abs(values[comp] - par.null) > limits[par.name]:
                    unit = "" if par.unit in ("", "1") else f" {par.unit}"
                    beyond.append(f"{comp} = {values[comp]:.3g}{unit}")
        if not beyond:
            return []
        lim = ", ".join(f"|{n}| <= {v:.3g}" for n, v in limits.items())
        return [f"{', '.join(beyond)}: beyond what {self.name} physically does on this airframe ({lim}); "
                f"the fit has it standing in for something the model lacks"]

    def interpretation_notes(self, values: dict[str, float], std: dict[str, float],
                             airframe: "Airframe") -> list[str]:
        """Notes, in words, on how to read this effect's fitted values on this airframe (what
        they depend on beyond the physics, e.g. a geometry the airframe leaves out). Unlike
        :meth:`plausibility_warnings`, a note never makes a candidate implausible. ``values``
        and ``std`` as there. Default: none."""
        return []

    def lowers_top_thrust(self, values: Mapping[str, float]) -> str:
        """Words naming what, at these fitted ``values``, makes the thrust per ``w^2`` fall
        at the highest rotor speeds (a thrust curve with ``k_Tw < 0``), or "" where nothing
        does (the default). Where the log's highest commands gave less thrust than they ask
        (:func:`~greybox.diagnosis.thrust_at_top`), such an effect may stand for commands
        beyond the motors' range, and the diagnosis says so beside it."""
        return ""

    def reduces_to(self, other: str, values: Mapping[str, float], covariance: np.ndarray,
                   free_names: Sequence[str], airframe: "Airframe") -> str:
        """Words saying that this effect's fitted values are what the effect named ``other``
        gives with fewer parameters (within their noise, or beyond it by a physically small
        part), or "" where they are not or nothing is known (the default). ``values``: every
        parameter by component name; ``covariance``: the fit's, in ``free_names`` order. The
        diagnosis's tie rule takes the simpler effect when the validation cannot tell them
        apart and this says the larger one is it (``motor_asymmetry``'s rotor gains in the
        pattern of a ``cog_offset``)."""
        return ""

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
        if e.name in self:
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

    def get(self, name: str) -> Effect | None:
        """The effect called ``name``, or None when it is not in the library."""
        return next((e for e in self._effects if e.name == name), None)

    @property
    def names(self) -> list[str]:
        return [e.name for e in self._effects]

    def __repr__(self) -> str:
        return " + ".join(repr(e) for e in self._effects) or "EffectLibrary()"


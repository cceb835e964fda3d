"""Effects found by the diagnosis' discovery (README, "Discovering effects outside the
catalogue"): a generalised force in one body-frame channel that is a linear combination of
named physical features, with the coefficients as fittable parameters.

Channels: ``fx``, ``fy``, ``fz`` — a body-frame force per unit mass (m/s²), added to the
world-frame force as ``R @ (mass * f e_c)``; ``mx``, ``my``, ``mz`` — a body-frame angular
acceleration (rad/s²), added as the torque ``J @ (alpha e_c)`` so that it adds exactly
``alpha`` to the rate equations.

Features (:data:`BASE_FEATURES`, evaluated on the model's own context, so after the other
effects have acted — effective rotor speeds after ``motor_lag``, air velocity after
``wind``): ``vx_b``, ``vy_b``, ``vz_b`` (body-frame air velocity ``R^T v_air``), ``p``,
``q``, ``r``, ``wsum`` (sum of the rotor speeds), ``w2sum`` (sum of their squares),
``height`` (above the ground plane), ``t`` (model time, s), ``w2roll``, ``w2pitch``,
``w2yaw`` (the rotor-speed patterns that make the roll, pitch and yaw moments:
``sum(-y_i w_i^2)``, ``sum(x_i w_i^2)`` with the rotor positions from the centre of gravity,
``sum(spin_i w_i^2)``: a thrust factor that acts on every rotor scales the control moments
too), any logged signal by its column name (read as a model input, like
``battery_voltage`` reads ``vbat``), and products ``a*b`` of those (``vx_b*vx_b``).

A discovery written by ``greybox diagnose --write-effect FILE.py`` is a subclass::

    from greybox.effects import DiscoveredEffect

    class DiscoveredMx(DiscoveredEffect):
        name = "discovered_mx"
        channel = "mx"
        features = ("p",)
        coefficients = (-2.1,)      # starting values; fitted like any parameter

whose parameters are named ``<channel>_per_<feature>`` (``mx_per_p``; a product's ``*``
becomes ``_``): usable in ``[parameters]`` and ``--set`` like any effect's.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar, Sequence

import casadi as ca
import numpy as np

from ..errors import GreyboxInputError
from ..parameters import Parameter
from .base import Effect, ModelContext

if TYPE_CHECKING:  # pragma: no cover
    from ..airframe import Airframe

__all__ = ["DiscoveredEffect", "discovered_effect_class", "effect_file_text", "feature_expression",
           "feature_unit", "parameter_name", "split_feature", "BASE_FEATURES", "FORCE_CHANNELS",
           "MOMENT_CHANNELS", "CHANNEL_UNITS"]

FORCE_CHANNELS: tuple[str, ...] = ("fx", "fy", "fz")
"""Body-frame force per unit mass, m/s²."""
MOMENT_CHANNELS: tuple[str, ...] = ("mx", "my", "mz")
"""Body-frame angular acceleration, rad/s²."""
CHANNEL_UNITS = {**{c: "m/s^2" for c in FORCE_CHANNELS}, **{c: "rad/s^2" for c in MOMENT_CHANNELS}}

_FEATURE_UNITS = {"vx_b": "m/s", "vy_b": "m/s", "vz_b": "m/s", "p": "rad/s", "q": "rad/s", "r": "rad/s",
                  "wsum": "rad/s", "w2sum": "rad^2/s^2", "height": "m", "t": "s",
                  "w2roll": "m rad^2/s^2", "w2pitch": "m rad^2/s^2", "w2yaw": "rad^2/s^2"}
BASE_FEATURES: tuple[str, ...] = tuple(_FEATURE_UNITS)
"""The features every model offers; a logged signal adds its own name."""

# output channels a generalised force in each body channel moves (before/after tables)
_OUTPUTS_MOVED = {"fx": ("x", "y", "z"), "fy": ("x", "y", "z"), "fz": ("z", "x", "y"),
                  "mx": ("phi", "p", "y"), "my": ("theta", "q", "x"), "mz": ("psi", "r")}


def split_feature(feature: str) -> list[str]:
    """The factors of a feature name: ``"wsum*vx_b"`` -> ``["wsum", "vx_b"]``."""
    parts = [f.strip() for f in feature.split("*")]
    if not feature or not all(parts):
        raise GreyboxInputError(f"bad feature name {feature!r}: names joined by '*'")
    return parts


def feature_unit(feature: str) -> str:
    """SI unit of a feature (a logged signal's unit is not known: ``[name]``)."""
    return "*".join(_FEATURE_UNITS.get(f, f"[{f}]") for f in split_feature(feature))


def parameter_name(channel: str, feature: str) -> str:
    """Name of the coefficient of ``feature`` in ``channel``: ``mx_per_p``, ``fz_per_wsum_vx_b``."""
    return f"{channel}_per_{'_'.join(split_feature(feature))}"


def _factor(name: str, ctx: ModelContext) -> ca.SX:
    if name in ("vx_b", "vy_b", "vz_b"):
        return (ctx.R.T @ ctx.v_air)[("vx_b", "vy_b", "vz_b").index(name)]
    if name in ("p", "q", "r"):
        return ctx.omega[("p", "q", "r").index(name)]
    if name == "wsum":
        return ca.sum1(ctx.w)
    if name == "w2sum":
        return ca.sumsqr(ctx.w)
    if name in ("w2roll", "w2pitch", "w2yaw"):
        # the rotor-speed patterns that make roll, pitch and yaw moments (per unit K_T, b):
        # a thrust factor acting on every rotor scales the control moments with it
        w2 = ctx.w ** 2
        arm = {"w2roll": -ctx.rotor_pos[:, 1], "w2pitch": ctx.rotor_pos[:, 0],
               "w2yaw": ca.DM(ctx.airframe.spins)}[name]
        return ca.dot(arm, w2)
    if name == "height":
        return ctx.airframe.ground_z - ctx.pos[2]
    if name == "t":
        return ctx.t
    if ctx.signals is not None and name in ctx.signals:
        return ctx.signals[name]
    raise GreyboxInputError(f"unknown feature {name!r}: known are {', '.join(BASE_FEATURES)} and the logged "
                            "signals the effect declares in its 'signals'")


def feature_expression(feature: str, ctx: ModelContext) -> ca.SX:
    """The symbolic value of a feature (a product of factors) in the model context ``ctx``."""
    out = ca.SX(1.0)
    for f in split_feature(feature):
        out = out * _factor(f, ctx)
    return out


def _derived(channel: str, features: Sequence[str]) -> dict:
    """Class attributes that follow from a discovered effect's channel and features."""
    factors = [f for feat in features for f in split_feature(feat)]
    rest = {"vx_b", "vy_b", "vz_b", "p", "q", "r"}
    return {
        "summary": f"discovered {channel} = " + " + ".join(f"c*{f}" for f in features),
        "channels": _OUTPUTS_MOVED.get(channel, ()),
        # a term of velocities and rates only vanishes in a level hover at rest; any other
        # (rotor speeds, height, time, a signal) may act there
        "shifts_trim": any(not (set(split_feature(f)) & rest) for f in features),
        # logged signals among the factors are model inputs (read from the log's columns)
        "signals": tuple(dict.fromkeys(f for f in factors if f not in _FEATURE_UNITS)),
    }


class DiscoveredEffect(Effect):
    """A generalised force in body channel :attr:`channel`, ``sum_k c_k * feature_k``, with
    one fitted coefficient per feature (module docstring). Subclasses set ``name``,
    ``channel``, ``features`` and the starting ``coefficients``; ``scales`` (typical
    magnitudes of the coefficients, for the fitter) default to the coefficients' sizes.

    The constructor takes ``channel``/``features``/``coefficients``/``scales`` to override
    the class's (what :meth:`options` saves): the compile cache is keyed by them, so two
    discoveries with one name never share compiled code.
    """

    channel: ClassVar[str] = ""
    features: ClassVar[tuple[str, ...]] = ()
    coefficients: ClassVar[tuple[float, ...]] = ()
    scales: ClassVar[tuple[float, ...]] = ()
    excited_by = "manoeuvres in which the discovered features vary"

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        # what the rest of greybox reads on the class (``greybox effects``, the logged
        # signals a log must supply) follows from the channel and the features
        if cls.channel:
            for k, v in _derived(cls.channel, cls.features).items():
                setattr(cls, k, v)

    def __init__(self, channel: str | None = None, features: Sequence[str] | None = None,
                 coefficients: Sequence[float] | None = None, scales: Sequence[float] | None = None):
        # instance values shadow the class's only when given (a file's class needs no arguments)
        if channel is not None:
            self.channel = channel
        if features is not None:
            self.features = tuple(features)
        if coefficients is not None:
            self.coefficients = tuple(float(c) for c in coefficients)
        if scales is not None:
            self.scales = tuple(float(s) for s in scales)
        if self.channel not in CHANNEL_UNITS:
            raise GreyboxInputError(f"effect {self.name!r}: channel must be one of {', '.join(CHANNEL_UNITS)}, "
                                    f"got {self.channel!r}")
        if self.coefficients and len(self.coefficients) != len(self.features):
            raise GreyboxInputError(f"effect {self.name!r}: {len(self.features)} features but "
                                    f"{len(self.coefficients)} coefficients")
        if channel is not None or features is not None:
            for k, v in _derived(self.channel, self.features).items():
                setattr(self, k, v)

    def parameters(self, airframe: "Airframe") -> list[Parameter]:
        coefs = self.coefficients or (0.0,) * len(self.features)
        scales = self.scales or tuple(abs(c) if c != 0 else 1.0 for c in coefs)
        unit = CHANNEL_UNITS[self.channel]
        return [Parameter(parameter_name(self.channel, f), 1, float(c), f"({unit})/({feature_unit(f)})",
                          -np.inf, np.inf, float(s) if s > 0 else 1.0, 0.0, True,
                          f"{self.channel} per unit {f}", self.name)
                for f, c, s in zip(self.features, coefs, scales)]

    def add_forces(self, ctx: ModelContext) -> None:
        value = ca.SX(0.0)
        for f in self.features:
            value = value + ctx.params[parameter_name(self.channel, f)] * feature_expression(f, ctx)
        if self.channel in FORCE_CHANNELS:
            axis = ca.DM.zeros(3)
            axis[FORCE_CHANNELS.index(self.channel)] = 1.0
            ctx.force_world += ctx.R @ (ctx.airframe.mass * value * axis)
        else:
            axis = ca.DM.zeros(3)
            axis[MOMENT_CHANNELS.index(self.channel)] = 1.0
            ctx.torque_body += ca.DM(ctx.airframe.inertia) @ (value * axis)

    def options(self) -> dict:
        # what makes the equations (the compile cache's key, a saved model's structure); the
        # starting values and scales do not: compiled code takes every parameter as an input
        return {"channel": self.channel, "features": list(self.features)}

    def __repr__(self) -> str:
        return f"{type(self).__name__}(channel={self.channel!r}, features={self.features!r})"


def discovered_effect_class(channel: str, features: Sequence[str], coefficients: Sequence[float] = (),
                            scales: Sequence[float] = (), name: str | None = None) -> type[DiscoveredEffect]:
    """A new :class:`DiscoveredEffect` subclass named ``discovered_<channel>`` (or ``name``)."""
    name = name or f"discovered_{channel}"
    return type(f"Discovered{channel.capitalize()}", (DiscoveredEffect,),
                {"name": name, "channel": channel, "features": tuple(features),
                 "coefficients": tuple(float(c) for c in coefficients),
                 "scales": tuple(float(s) for s in scales), "__module__": __name__})


def effect_file_text(classes: "type[DiscoveredEffect] | Sequence[type[DiscoveredEffect]]", note: str = "") -> str:
    """Python source of an effects file (``--effects-file``) defining one discovered effect
    class or several (one per channel), as written by ``greybox diagnose --write-effect``;
    ``note`` goes into its docstring."""
    classes = [classes] if isinstance(classes, type) else list(classes)
    doc = ["Effect(s) discovered by greybox diagnose:"]
    for cls in classes:
        terms = " + ".join(f"{parameter_name(cls.channel, f)}*{f}" for f in cls.features)
        doc.append(f"  {cls.name}: {cls.channel} ({CHANNEL_UNITS[cls.channel]}, body frame) = {terms}")
    if note:
        doc += [""] + note.splitlines()
    names = ",".join(cls.name for cls in classes)
    doc += ["", f"Load it with --effects-file and add them with --effects {names}; their coefficients are",
            "fitted like any parameter (the values below only start the fit). Edit the features or the",
            "channel to test another form."]
    body = "\n".join(doc)
    text = f'"""{body}\n"""\nfrom greybox.effects import DiscoveredEffect\n'
    for cls in classes:
        text += (f"\n\nclass {cls.__name__}(DiscoveredEffect):\n"
                 f"    name = {cls.name!r}\n"
                 f"    channel = {cls.channel!r}\n"
                 f"    features = {tuple(cls.features)!r}\n"
                 f"    coefficients = {tuple(float(c) for c in cls.coefficients)!r}\n"
                 f"    scales = {tuple(float(s) for s in cls.scales)!r}\n")
    return text

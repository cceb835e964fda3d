"""Effects known by name: greybox's own, and the user's — registered in code
(:func:`register`), from a file (:func:`load_effects_file`, ``--effects-file``) or by an
installed package's entry point (:data:`ENTRY_POINT_GROUP`) — and what is looked up by
name: the class, a new instance, the advice that tells two effects apart, plausible
magnitudes."""
from __future__ import annotations

from contextlib import contextmanager
from typing import TYPE_CHECKING, Iterator

from ..errors import GreyboxInputError
from ..parameters import Parameter
from .base import Effect
from .catalogue import CATALOGUE, SIGNAL_EFFECTS
from .disturbance import DisturbanceTorque, HeldMoment

if TYPE_CHECKING:  # pragma: no cover
    from ..airframe import Airframe

__all__ = ["register", "unregister", "load_effects_file", "known_effects", "registered_effects", "effect_class",
           "by_name", "confusable", "measurement_only", "per_flight", "distinguishing_manoeuvre", "parse_effect_names",
           "example_values", "ENTRY_POINT_GROUP", "user_hook"]


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
    _check_parameter_names(obj, _check_hooks(obj, source), source)
    _REGISTERED[name] = cls
    _REGISTERED_FROM[name] = source
    _FROM_FILE[name] = from_file
    return cls


def _generic_airframe() -> "Airframe":
    from ..airframe import airframe_from_dict
    return airframe_from_dict({"airframe": {"name": "check", "mass": 1.0, "inertia": [0.01, 0.01, 0.02],
                                            "arm_length": 0.2, "layout": "x"}}, source="effect check")


def _check_hooks(effect: Effect, source: str) -> list[Parameter]:
    """Call the hooks that need no model on a generic airframe, so that an effect that
    cannot describe itself fails here with its file and line, not deep in a fit. Returns its
    parameters there."""
    import traceback
    af = _generic_airframe()
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
    return params


def _check_parameter_names(effect: Effect, params: list[Parameter], source: str) -> None:
    """Refuse an effect whose parameter names another known effect's parameter (or the base
    model's ``K_T``): parameters are named alike in a model's vector, an airframe's
    ``[parameters]``, ``--set`` and every JSON result, so two of one name would be one value
    there, and a model holding both could not be built."""
    owners = {"K_T": "the base model"}
    af = _generic_airframe()
    for other, cls in {**CATALOGUE, **SIGNAL_EFFECTS, **_REGISTERED}.items():
        if other == effect.name:
            continue
        try:
            for p in cls().parameters(af):
                owners.setdefault(p.name, f"effect {other!r}")
        except Exception:   # noqa: BLE001 - an effect that cannot describe itself names nothing
            continue
    taken = [f"{p.name!r} (already {owners[p.name]}'s)" for p in params if p.name in owners]
    if taken:
        raise GreyboxInputError(f"{source}: effect {effect.name!r}: parameter name {', '.join(taken)}; "
                                "give it another name")


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


@contextmanager
def user_hook(effect: Effect, hook: str) -> Iterator[None]:
    """Run a hook of ``effect`` (e.g. ``with user_hook(e, "add_forces"): e.add_forces(ctx)``):
    when the effect came from an effects file, an error raised in it is the file's to fix and
    becomes one :class:`GreyboxInputError` line naming the file, the line, the effect and the
    hook (``--effects-file``: no traceback for a user's mistake). greybox's own effects and
    effects registered in code raise as they are (a programmer reads the traceback)."""
    import traceback
    from pathlib import Path
    try:
        yield
    except GreyboxInputError:
        raise
    except Exception as e:   # noqa: BLE001 - the user's code: one line saying where
        name = getattr(effect, "name", "")
        if not _FROM_FILE.get(name) or not _same_class(_REGISTERED[name], type(effect)):
            raise
        source = _REGISTERED_FROM[name]
        frames = [f for f in traceback.extract_tb(e.__traceback__) if Path(f.filename).resolve() == Path(source).resolve()]
        where = f", line {frames[-1].lineno}" if frames else ""
        raise GreyboxInputError(f"{source}{where}: effect {name!r}, {hook}(): {type(e).__name__}: {e}") from None


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


def unregister(name: str) -> None:
    """Forget a registered effect (one of the user's: greybox's own cannot be removed), e.g.
    after a run that loaded an effects file, so that it is no longer a default candidate."""
    if name in CATALOGUE or name in SIGNAL_EFFECTS:
        raise GreyboxInputError(f"{name!r} is one of greybox's own effects and cannot be unregistered")
    if name not in _REGISTERED:
        raise GreyboxInputError(f"no registered effect {name!r}")
    for table in (_REGISTERED, _REGISTERED_FROM, _FROM_FILE):
        table.pop(name, None)


DISTURBANCE_MODELS: dict[str, type[Effect]] = {HeldMoment.name: HeldMoment, DisturbanceTorque.name: DisturbanceTorque}
"""Disturbance models by name: a model may hold them (a saved one is read back), but they are
no diagnosis candidates, since they explain any torque."""


def effect_class(name: str) -> type[Effect]:
    """The class of a known effect (see :func:`known_effects`) or a disturbance model
    (:data:`DISTURBANCE_MODELS`)."""
    cls = known_effects().get(name) or DISTURBANCE_MODELS.get(name)
    if cls is None:
        raise GreyboxInputError(f"unknown effect {name!r}; known effects: {', '.join(known_effects())}; "
                                f"disturbance models: {', '.join(DISTURBANCE_MODELS)} "
                                "(effects of your own: --effects-file FILE.py or greybox.effects.register)")
    return cls


def by_name(name: str) -> Effect:
    """A new effect object from its name (catalogue or registered)."""
    return effect_class(name)()


def confusable(a: str, b: str) -> bool:
    """Whether effects ``a`` and ``b`` are known to explain the same data (either names the
    other in its ``distinguish``)."""
    known = known_effects()
    ca_, cb = known.get(a), known.get(b)
    return bool((ca_ is not None and b in ca_.distinguish) or (cb is not None and a in cb.distinguish))


def measurement_only(name: str) -> bool:
    """Whether the known effect ``name`` changes only what a sensor reports
    (:meth:`~greybox.effects.Effect.measurement_only`); False for an unknown name."""
    cls = known_effects().get(name)
    return bool(cls is not None and cls.measurement_only())


def per_flight(name: str) -> bool:
    """Whether the known effect ``name`` is a condition of one flight rather than the vehicle's
    (:attr:`~greybox.effects.Effect.per_flight`: the day's wind); False for an unknown name."""
    cls = known_effects().get(name)
    return bool(cls is not None and cls.per_flight)


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
    """Physically plausible magnitudes of an effect for this airframe (the effect class's
    :meth:`~greybox.effects.Effect.plausible_values`), used by :mod:`greybox.synth` when a
    hidden effect is added without explicit values and by the diagnosis; ``{}`` for an
    unknown name."""
    cls = known_effects().get(name)
    return cls().plausible_values(airframe, K_T) if cls is not None else {}

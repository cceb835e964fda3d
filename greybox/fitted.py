"""A fitted model you can hold: structure + parameters + covariance + provenance.

:class:`FittedModel` carries what :func:`greybox.fit` found and does what one does with it:
``predict`` on a log, ``simulate`` inputs, ``linearize`` about hover, ``to_control``,
``save`` to a versioned, human-readable JSON file and :func:`load` it back (the same
predictions, bit for bit). :class:`greybox.fitting.FitResult` is one (with the solver's
record on top); ``Diagnosis.fitted_model`` is the diagnosis' final model.

Example::

    res = greybox.fit(model, log.split()[0])
    res.save("quad.json")
    fm = greybox.load("quad.json")
    fm.predict(log.split()[1]).total          # the fit's validation nrmse
    sys = fm.to_control()                     # python-control StateSpace at hover

File format (``format_version`` 1)::

    {"format": "greybox.fitted_model", "format_version": 1, "greybox_version": "0.1.0",
     "model": {"inputs": "rotor_speeds", "airframe": {... the airframe TOML as a table ...},
               "effects": [{"name": "yaw_torque", "options": {}}, ...]},
     "parameters": {"K_T": 2.4e-05, "Kd[0]": ..., ...},        # every component, exact
     "free": ["K_T", ...], "std": {"K_T": 3.1e-08, ...},       # free ones
     "covariance": [[...]],                                    # free ones, free order
     "provenance": {"logs": [...], "created": "...", ...}}

Numbers are written with Python's shortest exact representation, so a reload is exact.
A file of another ``format_version`` is refused with a clear error.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import tomllib
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from . import effects as fx
from .airframe import airframe_from_dict
from .data import read_text_file
from .errors import GreyboxInputError

__all__ = ["FittedModel", "load", "FORMAT", "FORMAT_VERSION"]

FORMAT = "greybox.fitted_model"
FORMAT_VERSION = 1


def _version() -> str:
    from . import __version__
    return __version__


class FittedModel:
    """A model structure with fitted parameters (and, when fitted, their covariance).

    Attributes:
        model: the :class:`~greybox.model.QuadrotorModel` (airframe, effects, inputs).
        p: every parameter value, flat, in ``model.param_names`` order.
        free_names: the parameters that were estimated.
        covariance: their covariance matrix (``free_names`` order); empty if not fitted.
        std: their standard deviations (NaN where not determined).
        provenance: where it came from (logs, greybox version, time, fit status).

    Example::

        fm = greybox.fit(model, est)              # a FitResult is a FittedModel
        fm.save("quad.json")
        fm = greybox.load("quad.json")
        fm.predict(val).total, fm.value("K_T"), fm.to_control()
    """

    def __init__(self, model, p, free_names: Sequence[str] = (), covariance=None, std=None,
                 provenance: dict | None = None):
        self.model = model
        self.p = np.asarray(p, dtype=float).copy()
        if self.p.shape != (model.n_params,):
            raise GreyboxInputError(f"parameter vector has {self.p.size} values; the model "
                                    f"({', '.join(model.effect_names)}) has {model.n_params}")
        self.free_names = list(free_names)
        n = len(self.free_names)
        self.covariance = np.zeros((n, n)) if covariance is None else np.asarray(covariance, dtype=float)
        self.std = (np.sqrt(np.clip(np.diag(self.covariance), 0, None)) if std is None
                    else np.asarray(std, dtype=float))
        self.provenance = dict(provenance or {})

    # ------------------------------------------------------------------ what it knows
    @property
    def parameters_(self) -> dict[str, float]:
        """``{component name: value}`` of every parameter."""
        return self.model.parameter_dict(self.p)

    @property
    def parameters(self) -> dict[str, dict[str, float | None]]:
        """``{name: {"value": v, "std": s or None (fixed)}}`` for every component (a saved
        and loaded model's as the fit's)."""
        out: dict[str, dict[str, float | None]] = {}
        for name, v in zip(self.model.param_names, self.p):
            s = None
            if name in self.free_names:
                s = float(self.std[self.free_names.index(name)])
            out[name] = {"value": float(v), "std": s}
        return out

    def value(self, name: str) -> float:
        """One parameter component's value."""
        return float(self.p[self.model.param_names.index(name)])

    def __repr__(self) -> str:
        shown = ", ".join(f"{n}={self.value(n):.4g}" for n in (self.free_names or self.model.param_names)[:6])
        more = "" if len(self.free_names or self.model.param_names) <= 6 else ", ..."
        return (f"{type(self).__name__}({self.model.airframe.name}: {', '.join(self.model.effect_names)}; "
                f"{shown}{more})")

    def _repr_html_(self) -> str:
        from .display import fitted_model_html
        return fitted_model_html(self)

    # ------------------------------------------------------------------ what it does
    def predict(self, log, horizon: float = 1.0, **options):
        """k-step-ahead prediction on ``log`` (:func:`greybox.validation.predict`), or on
        several flights pooled (:func:`greybox.validation.predict_flights`): a
        :class:`~greybox.validation.Prediction` with ``.nrmse`` per channel and ``.total``."""
        from .validation import predict_flights, prediction_options
        return predict_flights(self.model, self.p, log, horizon=horizon, **{**prediction_options(self), **options})

    def simulate(self, t, inputs, x0=None, method: str = "rk4"):
        """Open-loop simulation from inputs held between samples
        (:func:`greybox.integrate.simulate`)."""
        from .integrate import simulate
        return simulate(self.model, t, inputs, self.p, x0, method=method)

    def hover_trim(self, position=(0.0, 0.0, None), psi: float = 0.0):
        """``(x_trim, u_trim)`` of a still hover (:func:`greybox.linearize.hover_trim`)."""
        from .linearize import hover_trim
        return hover_trim(self.model, self.p, position=position, psi=psi)

    def linearize(self, position=(0.0, 0.0, None), psi: float = 0.0):
        """Continuous-time :class:`~greybox.linearize.LinearModel` about the hover trim."""
        from .linearize import linearize
        x_t, u_t = self.hover_trim(position, psi)
        return linearize(self.model, self.p, x_t, u_t)

    def to_control(self, position=(0.0, 0.0, None), psi: float = 0.0):
        """The linearisation about hover as a python-control ``StateSpace``."""
        return self.linearize(position, psi).to_control()

    # ------------------------------------------------------------------ persistence
    def to_dict(self) -> dict:
        """The saved form (see the module docstring); JSON-ready."""
        af = tomllib.loads(self.model.airframe.to_toml())
        effects = [{"name": e.name, "options": e.options()} for e in self.model.effects]
        std = {n: (float(s) if math.isfinite(s) else None) for n, s in zip(self.free_names, self.std)}
        cov = [[float(v) if math.isfinite(v) else None for v in row] for row in self.covariance]
        return {"format": FORMAT, "format_version": FORMAT_VERSION, "greybox_version": _version(),
                "model": {"inputs": self.model.inputs, "airframe": af, "effects": effects},
                "parameters": {n: float(v) for n, v in zip(self.model.param_names, self.p)},
                "free": list(self.free_names), "std": std, "covariance": cov,
                "provenance": _jsonable(self.provenance)}

    def save(self, path: str | Path) -> Path:
        """Write the model as JSON (atomically); returns the path."""
        from .data import atomic_write
        atomic_write(path, json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n")
        return Path(path)

    @classmethod
    def from_dict(cls, doc: dict, source: str = "model") -> "FittedModel":
        """The model saved by :meth:`to_dict` (errors name ``source`` and the field)."""
        from .model import QuadrotorModel
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise GreyboxInputError(f"{source}: not a greybox fitted model (no \"format\": \"{FORMAT}\")")
        version = doc.get("format_version")
        if version != FORMAT_VERSION:
            raise GreyboxInputError(f"{source}: format_version {version!r} is not supported by greybox "
                                    f"{_version()} (it reads version {FORMAT_VERSION}); saved by greybox "
                                    f"{doc.get('greybox_version', '?')}")
        try:
            m = doc["model"]
            af = airframe_from_dict(m["airframe"], source=f"{source}: model.airframe")
            effects = []
            for e in m["effects"]:
                effects.append(fx.by_name(e["name"]).with_options(e.get("options") or {}))
            model = QuadrotorModel(af, effects, inputs=m.get("inputs", "rotor_speeds"))
            values = dict(doc["parameters"])
            _fill_added_parameters(model, values, source)
            missing = [n for n in model.param_names if n not in values]
            if missing:
                raise GreyboxInputError(f"{source}: parameters: missing {', '.join(missing)}")
            p = np.array([float(values[n]) for n in model.param_names])
            free = list(doc.get("free", []))
            unknown = [n for n in free if n not in model.param_names]
            if unknown:
                raise GreyboxInputError(f"{source}: free: unknown parameter(s) {', '.join(unknown)}")
            cov = np.array([[np.nan if v is None else float(v) for v in row]
                            for row in doc.get("covariance", [])], dtype=float).reshape(len(free), len(free))
            std_doc = doc.get("std", {})
            std = np.array([np.nan if std_doc.get(n) is None else float(std_doc[n]) for n in free])
        except GreyboxInputError:
            raise
        except (KeyError, TypeError, ValueError) as e:
            raise GreyboxInputError(f"{source}: malformed fitted model ({type(e).__name__}: {e})") from None
        return cls(model, p, free, cov, std, doc.get("provenance", {}))


def _fill_added_parameters(model: Any, values: dict, source: str) -> None:
    """Put into ``values`` (in place) the parameters an effect gained after the model was saved:
    a missing component of an effect's parameter whose default is its null value, where the
    effect does what it did without it (``hub_rotor_drag``'s ``h_hub``, 0: the hubs in the
    rotor plane). It is taken at that value, held fixed, so the model predicts what it did when
    saved; a warning says so. Anything else missing stays an error."""
    filled = []
    for par in model.parameters:
        if par.effect == "base":
            continue
        defaults = np.broadcast_to(np.asarray(par.default, dtype=float), (par.size,))
        for comp, d in zip(par.component_names, defaults):
            if comp not in values and d == par.null:
                values[comp] = float(d)
                filled.append(f"{comp} = {d:g} ({par.effect})")
    if filled:
        warnings.warn(f"{source}: saved without {', '.join(filled)}, a parameter its effect gained later: taken "
                      "at that value, where the effect is what it was when saved, and held fixed", UserWarning,
                      stacklevel=3)


def load(path: str | Path) -> FittedModel:
    """A :class:`FittedModel` saved by :meth:`FittedModel.save`.

    Example::

        fm = greybox.load("quad.json")
        fm.predict(log).total
    """
    path = Path(path)
    text = read_text_file(path, "model")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise GreyboxInputError(f"{path}: not valid JSON: {e}") from None
    return FittedModel.from_dict(doc, source=str(path))


def provenance(logs: Sequence[Any], **extra) -> dict:
    """What a fit records about where its parameters came from."""
    return {"logs": [getattr(l, "source", None) or "log" for l in logs], "greybox_version": _version(),
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"), **extra}


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    return obj


__all__.append("provenance")

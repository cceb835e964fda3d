"""greybox: grey-box system identification of quadrotors, built on CasADi.

Main entry points::

    from greybox import load_airframe, QuadrotorModel, effects, load_log, simulate
    model = QuadrotorModel(load_airframe("quad.toml")) + effects.GroundEffect()

The names below are imported on first use (PEP 562), so that ``import greybox`` and the
command line start fast and an early Ctrl-C is handled by the CLI, not by an import.
"""
from __future__ import annotations

import importlib
import sys
import types

__version__ = "0.1.0"

_EXPORTS = {
    "effects": (".effects", None),
    "Airframe": (".airframe", "Airframe"), "load_airframe": (".airframe", "load_airframe"),
    "FlightLog": (".data", "FlightLog"), "load_log": (".data", "load_log"), "save_log": (".data", "save_log"),
    "GreyboxError": (".errors", "GreyboxError"), "GreyboxInputError": (".errors", "GreyboxInputError"),
    "SolverError": (".errors", "SolverError"), "ConvergenceWarning": (".errors", "ConvergenceWarning"),
    "AirframeWarning": (".errors", "AirframeWarning"), "CacheWarning": (".errors", "CacheWarning"),
    "simulate": (".integrate", "simulate"),
    "QuadrotorModel": (".model", "QuadrotorModel"),
    "FitResult": (".fitting", "FitResult"), "GreyBoxEstimator": (".fitting", "GreyBoxEstimator"),
    "fit": (".fitting", "fit"), "Solver": (".fitting", "Solver"), "GaussNewton": (".fitting", "GaussNewton"),
    "denoise_inputs": (".fitting", "denoise_inputs"),
    "FittedModel": (".fitted", "FittedModel"), "load": (".fitted", "load"),
    "Prediction": (".validation", "Prediction"), "compare_plot": (".validation", "compare_plot"),
    "nrmse": (".validation", "nrmse"), "predict": (".validation", "predict"),
    "residual_plot": (".validation", "residual_plot"),
    "ControllerLaw": (".controller_law", "ControllerLaw"),
    "closed_loop_horizon_errors": (".controller_law", "closed_loop_horizon_errors"),
    "Diagnosis": (".diagnosis", "Diagnosis"), "diagnose": (".diagnosis", "diagnose"),
    "LinearModel": (".linearize", "LinearModel"), "hover_trim": (".linearize", "hover_trim"),
    "linearize": (".linearize", "linearize"),
    "dlqr": (".control", "dlqr"), "dlqry": (".control", "dlqry"), "reference_gain": (".control", "reference_gain"),
    "StateSpaceModel": (".n4sid", "StateSpaceModel"), "n4sid": (".n4sid", "n4sid"),
    "batch": (".batch", "batch"), "BatchResult": (".batch", "BatchResult"),
}

__all__ = list(_EXPORTS) + ["__version__"]

# Functions named like their module (``linearize``, ``n4sid``): importing the submodule makes
# the import system bind it to the package's attribute of that name, which would hide the
# function (``from greybox import LinearModel, linearize`` gave the module). The function wins,
# as it did when this file imported everything eagerly.
_SHADOWED = {name for name, (module, attr) in _EXPORTS.items() if module == "." + name and attr}


class _Package(types.ModuleType):
    def __setattr__(self, name: str, value) -> None:
        if name in _SHADOWED and isinstance(value, types.ModuleType):
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


def __getattr__(name: str):
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'greybox' has no attribute {name!r}") from None
    mod = importlib.import_module(module, __name__)
    value = mod if attr is None else getattr(mod, attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

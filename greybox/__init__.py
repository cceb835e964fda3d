"""greybox: grey-box system identification of quadrotors, built on CasADi.

Main entry points::

    from greybox import load_airframe, QuadrotorModel, effects, load_log, simulate
    model = QuadrotorModel(load_airframe("quad.toml")) + effects.GroundEffect()
"""
__version__ = "0.1.0"

from . import effects  # noqa: E402
from .airframe import Airframe, load_airframe  # noqa: E402
from .data import FlightLog, load_log, save_log  # noqa: E402
from .errors import GreyboxError, GreyboxInputError, SolverError  # noqa: E402
from .integrate import simulate  # noqa: E402
from .model import QuadrotorModel  # noqa: E402
from .fitting import FitResult, GreyBoxEstimator, fit  # noqa: E402
from .validation import Prediction, compare_plot, nrmse, predict, residual_plot  # noqa: E402
from .diagnosis import Diagnosis, diagnose  # noqa: E402
from .linearize import LinearModel, hover_trim, linearize  # noqa: E402
from .control import dlqr, dlqry, reference_gain  # noqa: E402
from .n4sid import StateSpaceModel, n4sid  # noqa: E402

__all__ = ["effects", "Airframe", "load_airframe", "FlightLog", "load_log", "save_log",
           "GreyboxError", "GreyboxInputError", "SolverError", "simulate", "QuadrotorModel",
           "fit", "FitResult", "GreyBoxEstimator", "Prediction", "predict", "nrmse", "compare_plot",
           "residual_plot", "diagnose", "Diagnosis", "linearize", "hover_trim", "LinearModel", "dlqr",
           "dlqry", "reference_gain", "n4sid", "StateSpaceModel", "__version__"]

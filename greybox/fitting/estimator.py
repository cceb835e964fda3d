"""scikit-learn's estimator contract around :func:`greybox.fit`."""
from __future__ import annotations

import inspect
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from ..data import FlightLog
from ..model import QuadrotorModel
from .api import IF_NEEDED, fit
from .gauss_newton import Solver

__all__ = ["GreyBoxEstimator"]


class GreyBoxEstimator:
    """scikit-learn style estimator of a grey-box model's parameters.

    Every option of :func:`greybox.fit` is an explicit keyword parameter, so
    ``get_params``/``set_params``/``sklearn.base.clone`` keep them; ``horizon`` is the
    prediction horizon of :meth:`score`. Fitted attributes end in ``_``: ``result_`` (the
    :class:`~greybox.fitting.FitResult`, a :class:`~greybox.FittedModel`), ``params_``
    (every parameter's value), ``std_`` (the free ones' standard deviations).
    :meth:`score` is **minus** the validation nrmse: higher is better, as scikit-learn's
    model selection expects.

    Example::

        est = GreyBoxEstimator(model, free=["K_T", "b"], max_iter=40).fit(est_log)
        est.params_["K_T"], est.std_["K_T"]
        est.score(val_log)                       # -nrmse of 1-s-ahead predictions
        sklearn.base.clone(est).get_params()["max_iter"]    # 40
    """

    def __init__(self, model: QuadrotorModel | None = None, *, free: Iterable[str] | None = None,
                 fixed: Iterable[str] | None = None, p0: np.ndarray | Mapping[str, float] | None = None,
                 interval: int | None = None, noise: Mapping[str, float] | None = None,
                 max_iter: int = 60, tol: float = 1e-7, reweight: bool = True, compile: str = "auto",
                 process_noise: str | Mapping[str, float] | None = IF_NEEDED, solver: Solver | None = None,
                 progress: bool | Callable[[str], None] = False, horizon: float = 1.0):
        # scikit-learn's rule: store the arguments as given, validate in fit
        self.model = model
        self.free = free
        self.fixed = fixed
        self.p0 = p0
        self.interval = interval
        self.noise = noise
        self.max_iter = max_iter
        self.tol = tol
        self.reweight = reweight
        self.compile = compile
        self.process_noise = process_noise
        self.solver = solver
        self.progress = progress
        self.horizon = horizon

    @classmethod
    def _get_param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        return [n for n, p in sig.parameters.items() if n != "self" and p.kind != p.VAR_KEYWORD]

    def get_params(self, deep: bool = True) -> dict:
        """The constructor's parameters (scikit-learn's contract)."""
        return {n: getattr(self, n) for n in self._get_param_names()}

    def set_params(self, **params) -> "GreyBoxEstimator":
        """Set constructor parameters by name (scikit-learn's contract)."""
        valid = self._get_param_names()
        for k, v in params.items():
            if k not in valid:
                raise ValueError(f"invalid parameter {k!r} for GreyBoxEstimator; valid: {', '.join(valid)}")
            setattr(self, k, v)
        return self

    def __repr__(self) -> str:
        changed = {n: v for n, v in self.get_params().items()
                   if n != "model" and v is not inspect.signature(type(self).__init__).parameters[n].default}
        opts = "".join(f", {k}={v!r}" for k, v in changed.items())
        return f"GreyBoxEstimator({self.model!r}{opts})"

    def fit(self, logs: FlightLog | Sequence[FlightLog], y=None) -> "GreyBoxEstimator":
        """Fit the model's free parameters to one or several logs (``y`` is ignored: the
        outputs are in the logs)."""
        if self.model is None:
            raise ValueError("GreyBoxEstimator needs a model: GreyBoxEstimator(model, ...)")
        self.result_ = fit(self.model, logs, free=self.free, fixed=self.fixed, p0=self.p0,
                           interval=self.interval, noise=self.noise, max_iter=self.max_iter, tol=self.tol,
                           reweight=self.reweight, compile=self.compile, progress=self.progress,
                           process_noise=self.process_noise, solver=self.solver)
        self.params_ = self.result_.model.parameter_dict(self.result_.p)
        self.std_ = dict(zip(self.result_.free_names, map(float, self.result_.std)))
        return self

    def _fitted(self):
        if not hasattr(self, "result_"):
            raise ValueError("this GreyBoxEstimator is not fitted yet: call fit(logs) first")
        return self.result_

    def predict(self, log: FlightLog, horizon: float | None = None):
        """k-step-ahead predictions on ``log`` (a :class:`~greybox.validation.Prediction`)."""
        return self._fitted().predict(log, horizon=self.horizon if horizon is None else horizon)

    def score(self, log: FlightLog, y=None, horizon: float | None = None) -> float:
        """Minus the validation nrmse of :meth:`predict` on ``log``: higher is better."""
        return -float(self.predict(log, horizon).total)

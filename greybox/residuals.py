"""Residuals of a fitted trajectory and the statistics that say whether they look like noise.

Shared by the fitter (its certificate: are the residuals at the sensor noise and white?)
and the diagnosis (where does the model fail, how coloured is the error).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .data import FlightLog
from .integrate import n_substeps, parallel_map, rk4_step_with_output
from .model import OUTPUTS, QuadrotorModel

__all__ = ["fitted_trajectory", "output_residuals", "whiteness_fraction", "long_run_factor",
           "residual_widening", "WHITENESS_LAGS"]

WHITENESS_LAGS = 30
"""Autocorrelation lags (in measured samples) examined by :func:`whiteness_fraction`."""


def fitted_trajectory(model: QuadrotorModel, res: Any, log: FlightLog, flight: int = 0
                      ) -> tuple[np.ndarray, np.ndarray]:
    """States and outputs at every sample of ``log`` (flight number ``flight`` of the fit),
    integrated over each shooting interval from the fitted node states. ``res`` is a
    :class:`~greybox.fitting.FitResult`, or anything with its ``p``, ``node_states``,
    ``node_index`` and ``interval``."""
    log = model.prepare_log(log)
    nodes, idx = res.node_states[flight], res.node_index[flight]
    N = res.interval
    n = len(log)
    M = len(idx) - 1
    f = rk4_step_with_output(model, n_substeps(float(np.diff(log.t).max())))
    F = parallel_map(f.mapaccum("traj", N, [0], [0]), M)
    k = np.minimum(np.arange(M * N), n - 1)
    hk = np.append(np.diff(log.t), 0.0)[k]
    # a fit with parameters per flight (wind, battery sag) gives each flight its own vector
    p = res.flight_p(flight) if hasattr(res, "flight_p") else res.p
    _, Y, X = F(nodes[:M].T, log.inputs[k].T, p, log.t[k][None, :], hk[None, :])
    Y, X = np.asarray(Y).T, np.asarray(X).T
    out_y = np.full((n, model.ny), np.nan)
    out_x = np.full((n, model.nx), np.nan)
    m = min(n, M * N)
    out_y[:m], out_x[:m] = Y[:m], X[:m]
    return out_x, out_y


def output_residuals(log: FlightLog, Y: np.ndarray) -> np.ndarray:
    """Measured minus modelled outputs, (n, ny), NaN where a channel is not measured; the
    yaw residual is wrapped to (-pi, pi]."""
    E = np.full_like(Y, np.nan)
    for c, name in enumerate(OUTPUTS):
        if name in log.output_names:
            E[:, c] = log.output(name) - Y[:, c]
    psi = OUTPUTS.index("psi")
    E[:, psi] = np.arctan2(np.sin(E[:, psi]), np.cos(E[:, psi]))
    return E


def whiteness_fraction(e: np.ndarray, lags: int = WHITENESS_LAGS) -> float:
    """Fraction of the first ``lags`` autocorrelations of the measured samples of ``e``
    outside the 99 % band of white noise (about 0.01 for white noise; MATLAB's ``resid``
    draws the same band). NaN when fewer than 50 samples are measured."""
    v = e[np.isfinite(e)]
    if v.size < 50:
        return float("nan")
    v = v - v.mean()
    var = float(v @ v)
    if var <= 0:
        return 0.0
    band = 2.576 / math.sqrt(v.size)
    ac = np.array([float(v[j:] @ v[:-j]) / var for j in range(1, lags + 1)])
    return float(np.mean(np.abs(ac) > band))


def long_run_factor(e: np.ndarray, lags: int = 50) -> float:
    """Long-run variance / variance of a residual sequence (Bartlett weights), >= 1."""
    e = e[np.isfinite(e)]
    if e.size < 4 * lags:
        return 1.0
    e = e - e.mean()
    v = float(e @ e) / e.size
    if v <= 0:
        return 1.0
    acc = 0.0
    for k in range(1, lags + 1):
        rho = float(e[k:] @ e[:-k]) / e.size / v
        acc += (1 - k / (lags + 1)) * rho
    return max(1.0, 1.0 + 2.0 * acc)


def residual_widening(E: np.ndarray, channels) -> float:
    """The square root of the median :func:`long_run_factor` of the residual columns of ``E``
    (n, ny; ``OUTPUTS`` order) whose channel is in ``channels``; 1 without any."""
    facs = [long_run_factor(E[:, c]) for c, ch in enumerate(OUTPUTS) if ch in channels]
    return math.sqrt(float(np.median(facs))) if facs else 1.0

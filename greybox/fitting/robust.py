"""Parameter covariance that holds when the residuals are coloured (a sandwich estimate).

The Gauss-Newton covariance counts every sample as independent information. A model that is
not exact — and on data greybox did not make, none is — leaves residuals correlated over
many samples, and then that covariance is optimistic: a motor lag recovered 2.8 % low was
13 of its std away from the truth. The estimate moves with each interval's residuals through
a linear map (:meth:`greybox.fitting.FitSession.influence`: the shares of a Gauss-Newton step
that sum to it), so its scatter is the long-run covariance of that sequence of shares, which
a Bartlett-weighted (Newey-West) sum of their autocovariances estimates whatever their
colour. For white residuals it is the Gauss-Newton covariance again, up to its own noise.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["long_run_covariance", "bartlett_bandwidth", "upper_covariance"]

#: largest lag-one autocorrelation the bandwidth rule takes (nearer 1 it divides by ~0)
RHO_MAX = 0.97


def bartlett_bandwidth(u: np.ndarray) -> int:
    """Andrews' (1991) AR(1) plug-in bandwidth of the Bartlett kernel for the sequence ``u``
    (n, k), column by column, the widest kept: ``1.1447 (alpha n)^(1/3)`` with ``alpha =
    4 rho^2 / ((1 - rho)^2 (1 + rho)^2)``, at most a quarter of the sequence."""
    n = u.shape[0]
    if n < 8:
        return 0
    a, b = u[1:], u[:-1]
    den = np.einsum("ij,ij->j", b, b)
    rho = np.where(den > 0, np.einsum("ij,ij->j", a, b) / np.where(den > 0, den, 1.0), 0.0)
    rho = np.clip(rho, -RHO_MAX, RHO_MAX)
    alpha = 4 * rho ** 2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    width = 1.1447 * (float(alpha.max()) * n) ** (1.0 / 3.0) if alpha.size else 0.0
    return int(min(np.ceil(width), n // 4))


def long_run_covariance(u: np.ndarray, segments: Sequence[slice] | None = None,
                        bandwidth: int | None = None) -> np.ndarray:
    """Bartlett-weighted long-run covariance ``sum_l (1 - |l|/(L+1)) sum_t u_t u_{t+l}^T`` of
    the rows of ``u`` (n, k), segment by segment (``segments``: independent pieces such as
    flights, each with its own bandwidth from :func:`bartlett_bandwidth` unless ``bandwidth``
    gives one), summed. Computed
    as the mean outer product of moving sums over L + 1 rows (the same sum, exactly), so its
    cost does not grow with the bandwidth; it is positive semidefinite."""
    k = u.shape[1]
    out = np.zeros((k, k))
    for sl in segments if segments is not None else [slice(0, u.shape[0])]:
        v = u[sl]
        if not v.size:
            continue
        L = bartlett_bandwidth(v) if bandwidth is None else int(bandwidth)
        c = np.vstack([np.zeros((1, k)), np.cumsum(v, axis=0)])
        n = v.shape[0]
        # window sums of L + 1 rows ending at t = 0 .. n + L - 1 (zero rows beyond both ends)
        ends = np.minimum(np.arange(n + L) + 1, n)
        starts = np.maximum(np.arange(n + L) - L, 0)
        s = c[ends] - c[starts]
        out += s.T @ s / (L + 1)
    return 0.5 * (out + out.T)


def upper_covariance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A covariance at least as large as both ``a`` and ``b`` in every direction: ``a`` plus
    the positive part of ``b - a``. The Gauss-Newton covariance is what the measurement
    noise alone leaves; a long-run one that comes out smaller in some direction (its own
    scatter, when the residuals are white) does not make the estimate surer than that.

    Taken in units of ``a``'s own standard deviations, so that it does not depend on the
    parameters' units: in SI units the eigen-decomposition's rounding (1e-16 of the largest
    variance, a drag's) outweighed a 30 g vehicle's ``b`` variance (1e-31) and set ``b``'s std
    100x its scatter, by an amount that changed with the fit's starting point (blind audit)."""
    d = 0.5 * ((b - a) + (b - a).T)
    if not np.all(np.isfinite(d)):
        return a
    diag = np.diag(a)
    unit = np.where(np.isfinite(diag) & (diag > 0), np.sqrt(np.abs(diag)), 1.0)
    w, V = np.linalg.eigh(d / np.outer(unit, unit))
    return a + ((V * np.clip(w, 0.0, None)) @ V.T) * np.outer(unit, unit)

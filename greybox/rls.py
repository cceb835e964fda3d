"""Recursive least squares with forgetting, for online estimates of ``K_T`` and ``b``.

The two coefficients enter the equations of motion linearly (seed paper, Sec. II-B):

* thrust along body z:  ``K_T * sum(w_i^2) = -[R^T (m (a - g e_z) + Kd * v)]_z``
* yaw torque:           ``b * sum(spin_i w_i^2) = J_z dr/dt - (J_x - J_y) p q``

so each is a scalar regression ``y_k = theta * phi_k``. Accelerations and angular
accelerations come from the logged positions and rates through one *causal* second-order
low-pass ``H(s) = wc^2 / (s^2 + 2 zeta wc s + wc^2)`` and its derivatives ``s H`` and
``s^2 H``; the regressors pass through the same ``H`` so both sides keep the same delay.
The estimate at time k uses only samples up to k: it can run online.

Recursive least squares with forgetting factor ``lambda`` minimises
``sum_i lambda^(k-i) (y_i - theta phi_i)^2``; for a scalar parameter its solution is the
ratio of two exponentially weighted sums, which :class:`RecursiveLeastSquares` updates
sample by sample and :func:`online_thrust_yaw` evaluates for a whole log with a
first-order recursive filter. ``lambda = exp(-dt / memory)``: the memory is in seconds,
independent of the sample rate.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import bilinear, lfilter

from .data import FlightLog
from .errors import GreyboxInputError
from .model import QuadrotorModel
from .rotations import body_rates_from_euler_rates, rotation_matrices

__all__ = ["RecursiveLeastSquares", "online_thrust_yaw", "OnlineEstimate"]


class RecursiveLeastSquares:
    """Textbook vector RLS with exponential forgetting.

    Args:
        n: number of parameters.
        forgetting: ``lambda`` in (0, 1].
        theta0: prior estimate; ``delta`` its initial covariance scale (large = weak prior).
    """

    def __init__(self, n: int, forgetting: float = 0.999, theta0: np.ndarray | None = None,
                 delta: float = 1e6):
        if not 0 < forgetting <= 1:
            raise GreyboxInputError(f"forgetting factor must be in (0, 1], got {forgetting}")
        self.lam = forgetting
        self.theta_ = np.zeros(n) if theta0 is None else np.array(theta0, dtype=float)
        self.P_ = np.eye(n) * delta

    def update(self, phi: np.ndarray, y: float) -> np.ndarray:
        """One sample ``y = phi . theta + e``; returns the new estimate."""
        phi = np.atleast_1d(np.asarray(phi, dtype=float))
        Pphi = self.P_ @ phi
        k = Pphi / (self.lam + phi @ Pphi)
        self.theta_ = self.theta_ + k * (y - phi @ self.theta_)
        self.P_ = (self.P_ - np.outer(k, Pphi)) / self.lam
        return self.theta_


@dataclass
class OnlineEstimate:
    """Time series of online estimates."""

    t: np.ndarray
    K_T: np.ndarray
    b: np.ndarray
    memory: float
    settle: float   # s after the start before the estimates are meaningful


def _filters(dt: float, wc: float, zeta: float = 0.8):
    """Discrete (bilinear) H, sH, s^2H with H = wc^2/(s^2 + 2 zeta wc s + wc^2)."""
    den = [1.0, 2 * zeta * wc, wc ** 2]
    fs = 1.0 / dt
    return [bilinear(num, den, fs) for num in ([wc ** 2], [wc ** 2, 0.0], [wc ** 2, 0.0, 0.0])]


def _uniform(log: FlightLog) -> float:
    dt = np.diff(log.t)
    if np.ptp(dt) > 1e-6 * dt.mean() + 1e-9:
        raise GreyboxInputError(f"{log.source or 'log'}: online estimation needs a uniform sample rate; "
                                "use log.resample(dt) first")
    return float(dt.mean())


def _ewls(phi: np.ndarray, y: np.ndarray, lam: float, prior: float, prior_weight: float) -> np.ndarray:
    """theta_k = argmin sum lam^(k-i) (y_i - theta phi_i)^2 + prior term, for all k."""
    num = lfilter([1.0], [1.0, -lam], phi * y)
    den = lfilter([1.0], [1.0, -lam], phi * phi)
    decay = lam ** np.arange(1, phi.size + 1)
    return (num + prior * prior_weight * decay) / (den + prior_weight * decay)


def online_thrust_yaw(model: QuadrotorModel, log: FlightLog, p: np.ndarray | None = None,
                      memory: float = 2.0, cutoff_hz: float = 4.0) -> OnlineEstimate:
    """Online (causal) estimates of ``K_T`` and ``b`` along a flight.

    Args:
        model: gives mass, inertia, spins and the drag ``Kd`` used in the thrust equation.
        p: parameter vector for ``Kd`` and the priors (default: the model's defaults).
        memory: forgetting time constant, s (``lambda = exp(-dt/memory)``).
        cutoff_hz: bandwidth of the causal differentiating filters.
    """
    if model.inputs != "rotor_speeds":
        raise GreyboxInputError("online estimation of K_T and b needs rotor-speed inputs")
    dt = _uniform(log)
    p = model.default_parameters() if p is None else p
    names = model.param_names
    kd = np.array([p[names.index(f"Kd[{i}]")] for i in range(3)]) if "Kd[0]" in names else np.zeros(3)
    af = model.airframe
    (bH, aH), (bD, aD), (bDD, aDD) = _filters(dt, 2 * np.pi * cutoff_hz)
    t = log.t

    def fill(y):
        k = np.isfinite(y)
        if k.sum() < 2:
            raise GreyboxInputError(f"{log.source or 'log'}: too few measurements for online estimation")
        return np.interp(t, t[k], y[k])

    def filt(b, a, y):  # start the filter at rest on the first value (no start-up jump)
        y0 = y[0]
        return lfilter(b, a, y - y0) + (y0 if b is bH else 0.0)

    pos = np.column_stack([fill(log.output(c)) for c in "xyz"])
    ang = np.column_stack([fill(log.output(c)) for c in ("phi", "theta", "psi")])
    ang[:, 2] = np.unwrap(ang[:, 2])
    acc = np.column_stack([filt(bDD, aDD, pos[:, i]) for i in range(3)])
    vel = np.column_stack([filt(bD, aD, pos[:, i]) for i in range(3)])
    phi, th, psi = (filt(bH, aH, ang[:, i]) for i in range(3))
    if all(c in log.output_names for c in "pqr") and np.isfinite(log.output("r")).sum() > 2:
        rates = np.column_stack([fill(log.output(c)) for c in "pqr"])
    else:
        ed = np.column_stack([filt(bD, aD, ang[:, i]) for i in range(3)])
        ph0, th0 = ang[:, 0], ang[:, 1]
        rates = body_rates_from_euler_rates(ph0, th0, ed)
    # body z axis in the world (third column of R): thrust direction is its negative
    ez_b = rotation_matrices(phi, th, psi)[:, :, 2]
    g = af.gravity
    force = af.mass * (acc - np.array([0.0, 0.0, g])) + kd * vel
    y1 = -np.sum(ez_b * force, axis=1)
    w2 = log.inputs ** 2
    phi1 = filt(bH, aH, w2.sum(axis=1))
    J = af.inertia
    rdot = filt(bD, aD, rates[:, 2])
    pf, qf = filt(bH, aH, rates[:, 0]), filt(bH, aH, rates[:, 1])
    y2 = J[2, 2] * rdot - (J[0, 0] - J[1, 1]) * pf * qf
    phi2 = filt(bH, aH, w2 @ af.spins)
    lam = float(np.exp(-dt / memory))
    kt0 = p[names.index("K_T")]
    b0 = p[names.index("b")] if "b" in names else 0.0
    # a weak prior: worth about 10 ms of data at the typical regressor size
    n_prior = max(1, int(0.01 / dt))
    kt = _ewls(phi1, y1, lam, kt0, n_prior * float(np.median(phi1 ** 2)))
    bb = _ewls(phi2, y2, lam, b0, n_prior * float(np.median(phi2 ** 2)) + 1e-300)
    return OnlineEstimate(t, kt, bb, memory, settle=3.0 / (2 * np.pi * cutoff_hz) + memory)

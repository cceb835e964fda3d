"""Attitude conventions in one place: ZYX Euler angles, body FRD to world NED.

``R = Rz(psi) Ry(theta) Rx(phi)`` maps body vectors to world vectors; ``p, q, r`` are body
rates. The symbolic form (CasADi, for the model) and the numeric forms (numpy, for data)
are written here once and checked against each other and against SciPy's ``Rotation`` in
the tests.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

__all__ = ["rotation_matrix", "rotation_matrices", "rotation", "euler_from_rotation",
           "euler_rate_matrix", "euler_rate_matrices", "euler_rates_from_body_rates", "body_rates_from_euler_rates"]


def rotation_matrix(phi, theta, psi):
    """R = Rz(psi) Ry(theta) Rx(phi): body (FRD) vectors to world (NED). Works on SX or floats."""
    cph, sph = ca.cos(phi), ca.sin(phi)
    cth, sth = ca.cos(theta), ca.sin(theta)
    cps, sps = ca.cos(psi), ca.sin(psi)
    return ca.vertcat(
        ca.horzcat(cth * cps, sph * sth * cps - cph * sps, cph * sth * cps + sph * sps),
        ca.horzcat(cth * sps, sph * sth * sps + cph * cps, cph * sth * sps - sph * cps),
        ca.horzcat(-sth, sph * cth, cph * cth),
    )


def rotation_matrices(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """:func:`rotation_matrix` for arrays of angles, in numpy: (n, 3, 3) body -> world."""
    cph, sph, cth, sth = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)
    cps, sps = np.cos(psi), np.sin(psi)
    return np.stack([np.stack([cth * cps, sph * sth * cps - cph * sps, cph * sth * cps + sph * sps], -1),
                     np.stack([cth * sps, sph * sth * sps + cph * cps, cph * sth * sps - sph * cps], -1),
                     np.stack([-sth, sph * cth, cph * cth], -1)], 1)


def rotation(phi: float, theta: float, psi: float) -> np.ndarray:
    """The (3, 3) rotation of one attitude (numpy)."""
    return rotation_matrices(np.atleast_1d(phi), np.atleast_1d(theta), np.atleast_1d(psi))[0]


def euler_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """ZYX Euler angles ``(phi, theta, psi)`` of ``R = Rz(psi) Ry(theta) Rx(phi)``."""
    theta = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    return math.atan2(R[2, 1], R[2, 2]), theta, math.atan2(R[1, 0], R[0, 0])


def euler_rate_matrix(phi, theta):
    """W with d/dt [phi, theta, psi] = W [p, q, r] (ZYX Euler angles, body rates)."""
    cph, sph = ca.cos(phi), ca.sin(phi)
    cth, tth = ca.cos(theta), ca.tan(theta)
    return ca.vertcat(
        ca.horzcat(1, sph * tth, cph * tth),
        ca.horzcat(0, cph, -sph),
        ca.horzcat(0, sph / cth, cph / cth),
    )


def euler_rate_matrices(phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """(n, 3, 3) matrices W of :func:`euler_rate_matrix` in numpy, one per attitude (so
    ``np.einsum("nab,nb->na", W, omega)`` gives the Euler angle rates of body rates ``omega``);
    ``cos(theta)`` kept at least 1e-3 from zero (a measured pitch at the gimbal lock)."""
    phi, theta = np.asarray(phi, dtype=float), np.asarray(theta, dtype=float)
    sp, cp, ct = np.sin(phi), np.cos(phi), np.cos(theta)
    ct = np.where(np.abs(ct) < 1e-3, np.copysign(1e-3, ct), ct)
    tt = np.sin(theta) / ct
    one, zero = np.ones_like(phi), np.zeros_like(phi)
    return np.stack([np.stack([one, sp * tt, cp * tt], axis=-1), np.stack([zero, cp, -sp], axis=-1),
                     np.stack([zero, sp / ct, cp / ct], axis=-1)], axis=-2)


def euler_rates_from_body_rates(phi: float, theta: float, omega: np.ndarray) -> np.ndarray:
    """``W(phi, theta) @ omega`` in numpy: Euler angle rates from body rates (one attitude)."""
    return np.asarray(ca.DM(euler_rate_matrix(phi, theta))) @ np.asarray(omega, dtype=float)


def body_rates_from_euler_rates(phi: np.ndarray, theta: np.ndarray, euler_dot: np.ndarray) -> np.ndarray:
    """(n, 3) body rates ``p, q, r`` from Euler angle rates (n, 3): the inverse of
    :func:`euler_rate_matrix`, in numpy."""
    d = np.asarray(euler_dot, dtype=float)
    return np.column_stack([d[:, 0] - np.sin(theta) * d[:, 2],
                            np.cos(phi) * d[:, 1] + np.sin(phi) * np.cos(theta) * d[:, 2],
                            -np.sin(phi) * d[:, 1] + np.cos(phi) * np.cos(theta) * d[:, 2]])

"""Discrete LQR design with MATLAB's semantics: ``dlqr``, ``dlqry`` and the reference gain.

``dlqr(A, B, Q, R)`` minimises ``sum x'Qx + u'Ru (+ 2x'Nu)`` for ``x[k+1] = A x + B u``.
``dlqry(A, B, C, D, Q, R)`` weights the *outputs* ``y = C x + D u`` instead:
``J = sum y'Qy + u'Ru``, i.e. ``dlqr`` with ``Q_x = C'QC``, ``R_x = R + D'QD``,
``N = C'QD`` (MATLAB's definition; README, "Departures from the seed paper", eq. 11).
Both return ``(K, S, E)``: the gain of ``u = -K x``, the Riccati solution and the
closed-loop eigenvalues.

:func:`reference_gain` is the seed paper's eq. (12), the feed-forward of a constant
reference ``r`` in ``u = -K_f x + K_r r``:
``K_r = (B'SB + R)^-1 B' [I - (A - B K_f)']^-1 C'Q``.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import solve_discrete_are

from .errors import GreyboxInputError

__all__ = ["dlqr", "dlqry", "reference_gain"]


def _mat(M, name: str) -> np.ndarray:
    M = np.atleast_2d(np.asarray(M, dtype=float))
    if not np.all(np.isfinite(M)):
        raise GreyboxInputError(f"{name} has non-finite entries")
    return M


def _discrete_system(sys) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of a discrete-time system: a python-control ``StateSpace`` (``dt`` True or
    positive) or a :class:`~greybox.linearize.LinearModel` (``dt`` set); a continuous one is
    refused, since the sampling period is the designer's choice."""
    dt = getattr(sys, "dt", None)
    if dt is None or dt is False or (dt is not True and not dt > 0):
        raise GreyboxInputError(
            f"dlqr: the system is continuous-time (dt = {dt!r}); this is a discrete LQR: "
            "discretise it first, e.g. sys.sample(0.01) in python-control or "
            "LinearModel.discretize(0.01)")
    return np.asarray(sys.A), np.asarray(sys.B)


def dlqr(A, B, Q=None, R=None, N=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discrete LQR ``(K, S, E)`` for ``x[k+1] = A x + B u``, cost ``x'Qx + u'Ru + 2x'Nu``.

    Also ``dlqr(sys, Q, R[, N])`` as in python-control and MATLAB, where ``sys`` is a
    discrete-time python-control ``StateSpace`` or a discretised
    :class:`~greybox.linearize.LinearModel` (its ``A`` and ``B`` are used); a continuous-time
    system is an error (discretise it first: the period is a design choice).

    Example::

        import numpy as np
        from greybox import dlqr
        A = np.array([[1.0, 0.01], [0.0, 1.0]]); B = np.array([[0.0], [0.01]])
        K, S, E = dlqr(A, B, np.eye(2), np.eye(1))       # u = -K x; E: closed-loop poles
        import control                                   # python-control (optional)
        sys = control.ss(A, B, np.eye(2), np.zeros((2, 1)), 0.01)
        K, S, E = dlqr(sys, np.eye(2), np.eye(1))        # the same gain
    """
    if hasattr(A, "A") and hasattr(A, "B") and not isinstance(A, np.ndarray):
        if N is not None:
            raise GreyboxInputError("dlqr(sys, Q, R, N) takes four arguments, got five")
        Q, R, N = B, Q, R
        A, B = _discrete_system(A)
    if Q is None or R is None:
        raise GreyboxInputError("dlqr: give (A, B, Q, R) or (sys, Q, R)")
    A, B, Q, R = _mat(A, "A"), _mat(B, "B"), _mat(Q, "Q"), _mat(R, "R")
    n, m = B.shape
    if A.shape != (n, n) or Q.shape != (n, n) or R.shape != (m, m):
        raise GreyboxInputError(f"dlqr: sizes do not match: A {A.shape}, B {B.shape}, Q {Q.shape}, R {R.shape}")
    N = np.zeros((n, m)) if N is None else _mat(N, "N")
    try:
        S = solve_discrete_are(A, B, Q, R, s=N)
    except (np.linalg.LinAlgError, ValueError) as e:
        raise GreyboxInputError(f"dlqr: no stabilising solution ({e}); is (A, B) stabilisable?") from None
    K = np.linalg.solve(B.T @ S @ B + R, B.T @ S @ A + N.T)
    E = np.linalg.eigvals(A - B @ K)
    return K, S, E


def dlqry(A, B, C, D, Q, R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discrete LQR weighting outputs (MATLAB ``dlqry``): ``J = sum y'Qy + u'Ru``.

    Example::

        import numpy as np
        from greybox import QuadrotorModel, dlqry, linearize, load_airframe
        d = linearize(QuadrotorModel(load_airframe("greybox/data/airframes/paper.toml"))).discretize(0.01)
        C = d.C[[0, 1, 2, 5]]                       # outputs x, y, z, psi (the seed's design)
        K, S, E = dlqry(d.A, d.B, C, np.zeros((4, 4)), np.eye(4), 1e-3 * np.eye(4))
    """
    C, D, Q, R = _mat(C, "C"), _mat(D, "D"), _mat(Q, "Q"), _mat(R, "R")
    return dlqr(A, B, C.T @ Q @ C, R + D.T @ Q @ D, C.T @ Q @ D)


def reference_gain(A, B, C, Q, R, K, S) -> np.ndarray:
    """Seed eq. (12): ``K_r = (B'SB + R)^-1 B' [I - (A - B K)']^-1 C'Q``.

    Example::

        K, S, E = dlqry(A, B, C, D, Q, R)           # as in dlqry's example
        Kr = reference_gain(A, B, C, Q, R, K, S)    # u = -K dx + Kr r
    """
    A, B, C, Q, R, K, S = (_mat(M, n) for M, n in ((A, "A"), (B, "B"), (C, "C"), (Q, "Q"), (R, "R"),
                                                    (K, "K"), (S, "S")))
    n = A.shape[0]
    M = np.linalg.solve(np.eye(n) - (A - B @ K).T, C.T @ Q)
    return np.linalg.solve(B.T @ S @ B + R, B.T @ M)

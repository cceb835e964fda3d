"""The Gauss-Newton solver of a multiple-shooting fit (the default :class:`Solver`).

How it is solved (a structure-exploiting constrained Gauss–Newton; on the same problem
CasADi's IPOPT, fatrop and SQP solvers were measured 13–77 times slower):

* One CasADi function per interval folds over the interval's samples and returns the
  interval's end state, the Jacobian of that end state with respect to ``z_j = (s_j, theta)``
  and the Gauss–Newton blocks ``H_j = J_j^T J_j``, ``g_j = J_j^T e_j`` of its residuals —
  formed inside the function, so only small blocks ever leave CasADi. It is ``map``-ped over
  all intervals and compiled to C (cached on disk, :mod:`greybox.codegen`).
* The KKT system of each Gauss–Newton step is a band in the node states and continuity
  multipliers, bordered by the parameters (:class:`BorderedKKT`): LAPACK's banded LU
  (``scipy.linalg.solve_banded``) eliminates the band, a small dense solve gives the
  parameters. With soft continuity (process noise) the multipliers are eliminated too and
  the band, then symmetric positive definite, is Cholesky-factored.
* The interval functions are called on numpy buffers (:class:`greybox.shooting.BufferedFunction`),
  and a model structure's step functions are built once per process.
* Steps are damped Levenberg–Marquardt style and accepted by a backtracking line search on
  an l1 merit function (cost + weighted continuity gaps). It stops at the step tolerance or
  once the cost decreases left (extrapolated from the last full steps) are negligible.

Another solver plugs in through :func:`greybox.fitting.fit`'s ``solver=``: any object with
the :class:`Solver` method ``solve(session, X, th, mu, max_iter, tol, rough)``.
"""
from __future__ import annotations

import math
import time
from typing import Callable, Protocol, Sequence

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded, solve_banded

from ..data import FlightLog
from ..errors import SolverError
from ..integrate import log_substeps
from ..model import OUTPUTS, QuadrotorModel
from ..shooting import ShootingProblem, initial_node_states, layout, parameter_bounds
from .certificate import DECREASE_TOLERANCE, GAP_TOLERANCE, STEP_TOLERANCE

__all__ = ["Solver", "GaussNewton", "FitSession", "BorderedKKT", "STOPPED", "budget_spent"]

STOPPED = "stopped by its caller: "
"""How the status of a solve ended by :class:`GaussNewton`'s ``stop`` begins."""


def budget_spent(status: str) -> bool:
    """Whether a solve ended because its caller's budget or rule said so (the iteration cap,
    or :class:`GaussNewton`'s ``stop``), not because it could go no further: the fit then
    neither solves on from there nor tries again from the start."""
    return status == "maximum iterations reached" or status.startswith(STOPPED)


class Solver(Protocol):
    """What :func:`greybox.fitting.fit` needs of a solver (a strategy object, PySINDy style).

    ``solve(session, X, th, mu, max_iter, tol, rough)`` minimises the session's cost from
    node states ``X`` (n_nodes, nx) and scaled free parameters ``th`` (bounds
    ``session.lo_s``/``session.hi_s``) subject to closed shooting gaps (``session.q`` None)
    or with the gaps as process noise, using ``session.evaluate``, ``session.gaps``,
    ``session.total_cost`` and, if it likes, ``session.step`` (the banded Gauss-Newton step).
    It returns ``(X, th, mu, iterations, converged, status, blocks)`` with ``blocks`` =
    ``session.evaluate(X, th)`` at the end point, ``mu`` whatever damping state it wants
    back on the next call, and ``status`` a short reason in words. The fit certifies the end
    point itself, whichever solver reached it.

    A solver of one's own, wrapping the default. Example::

        class Logged:
            def __init__(self):
                self.inner = GaussNewton()
            def solve(self, session, X, th, mu, max_iter, tol, rough=False):
                print("solving", session.nth, "parameters")
                return self.inner.solve(session, X, th, mu, max_iter, tol, rough)

        res = greybox.fit(model, log, solver=Logged())
    """

    def solve(self, session: "FitSession", X: np.ndarray, th: np.ndarray, mu: float, max_iter: int,
              tol: float, rough: bool = False) -> tuple: ...


class BorderedKKT:
    """The KKT system of a Gauss-Newton step, solved as a banded system bordered by the
    parameters.

    Unknowns: per flight the node states' steps ``dx_0 .. dx_M`` and the continuity
    multipliers ``lam_0 .. lam_{M-1}``, ordered ``dx_0, lam_0, dx_1, ..., dx_M`` (a band of
    half-width ``2 nx``), and the parameters' step ``dtheta``, which every interval touches
    (the border). With ``A`` the band, ``B`` its coupling to the parameters and ``C`` their
    own curvature::

        [A   B] [u     ]   [r_u    ]
        [B^T C] [dtheta] = [r_theta]

    is solved by block elimination: ``A [Y y] = [B r_u]`` (LAPACK's banded LU, ``nth + 1``
    right-hand sides), then the ``nth x nth`` Schur complement ``C - B^T Y`` gives
    ``dtheta``, and ``u = y - Y dtheta``. This is the system of the parameters carried as
    constant node states (``theta_j = theta_{j+1}``) with those equalities eliminated; the
    band is ``nx`` wide instead of ``nx + nth`` and LU's work, which grows with its cube,
    falls several times over. The Schur complement at zero damping is the inverse of the
    parameters' covariance (:meth:`parameter_inverse`)."""

    def __init__(self, flights: list[tuple[int, int]], nx: int, nth: int):
        self.nx, self.nth = nx, nth
        xoff, loff, zi = [], [], []
        pos = k = 0
        for _, M in flights:
            for j in range(M + 1):
                xoff.append(pos)
                pos += nx
                if j < M:
                    loff.append(pos)
                    pos += nx
            zi += list(range(k, k + M))
            k += M + 1
        self.n = pos
        self.xoff, self.loff = np.array(xoff, dtype=np.intp), np.array(loff, dtype=np.intp)
        # interval j (global) connects node zi[j] -> zi[j] + 1 (node indices, flight by flight)
        self.zi = np.array(zi, dtype=np.intp)
        self.l = self.u = 2 * nx
        ar = np.arange(nx)
        self.rows_x = (self.xoff[:, None] + ar).ravel()     # band rows of the node states
        self.rows_l = (self.loff[:, None] + ar).ravel()     # band rows of the multipliers
        xfrom, xto = self.xoff[self.zi], self.xoff[self.zi + 1]
        # flat positions in LAPACK's band storage ab[u + i - j, j] of each block's entries,
        # computed once: filling the band is then one np.put per block kind
        self.at_H = self._band_index(self.xoff, self.xoff)
        self.at_S = self._band_index(self.loff, xfrom)
        self.at_St = self._band_index(xfrom, self.loff)
        self.at_q = ((self.u * self.n) + self.rows_l)       # multiplier diagonal
        band = np.zeros((self.l + self.u + 1, self.n))
        minus_I = np.broadcast_to(-np.eye(nx), (len(self.loff), nx, nx))
        np.put(band, self._band_index(self.loff, xto), minus_I)
        np.put(band, self._band_index(xto, self.loff), minus_I)
        self.band = band
        # soft continuity (every gap penalised, none held): the multipliers are eliminated
        # too, leaving the normal equations in the node states alone, symmetric positive
        # definite, upper half-band 2 nx - 1 (node k touches node k + 1): Cholesky
        self.n_nodes = len(self.xoff)
        self.us = 2 * nx - 1
        nn = self.n_nodes * nx
        node = np.arange(self.n_nodes) * nx
        rows = node[:, None, None] + ar[None, :, None]
        cols = node[:, None, None] + ar[None, None, :]
        upper = (rows <= cols).ravel()
        self.soft_upper = upper                                 # entries of a node block kept
        self.soft_at_H = ((self.us + rows - cols) * nn + cols).ravel()[upper]
        rows = node[self.zi][:, None, None] + ar[None, :, None]
        cols = node[self.zi + 1][:, None, None] + ar[None, None, :]
        self.soft_at_off = ((self.us + rows - cols) * nn + cols).ravel()

    def _band_index(self, r0: np.ndarray, c0: np.ndarray) -> np.ndarray:
        nx = self.nx
        rows = r0[:, None, None] + np.arange(nx)[None, :, None]
        cols = c0[:, None, None] + np.arange(nx)[None, None, :]
        return ((self.u + rows - cols) * self.n + cols).ravel()

    def _damped(self, H: np.ndarray, mu: float) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        """The data curvature with the damping: (its diagonal, the floor, the node states'
        blocks (n_nodes, nx, nx), the parameters' block). A tiny floor keeps the system
        regular; on the parameters only once (they are one vector, not one per node)."""
        nx, nth = self.nx, self.nth
        ar = np.arange(nx)
        d = np.einsum("kii->ki", H)
        floor = 1e-10 * max(float(d.max()) if d.size else 1.0, 1.0)
        Hxx = H[:, :nx, :nx].copy()
        Hxx[:, ar, ar] += mu * d[:, :nx] + floor
        C = H[:, nx:, nx:].sum(axis=0)
        C[np.diag_indices(nth)] += mu * d[:, nx:].sum(axis=0) + floor
        return d, floor, Hxx, C

    def _reduce(self, C: np.ndarray, B: np.ndarray, solve_band: Callable[[np.ndarray], np.ndarray],
                r_th: np.ndarray | None) -> tuple:
        """Eliminate the band: ``A [Y y] = B`` (``B``'s last column the band's right-hand side
        when ``r_th`` is given), then the Schur complement ``C - B^T Y``. Returns (Schur
        complement, Y, y, the parameters' reduced right-hand side ``r_th - B^T y``); y and
        the reduced right-hand side None without ``r_th``."""
        nth = self.nth
        Bth = B[:, :nth].copy()
        Y = solve_band(B)
        BtY = Bth.T @ Y
        schur = C - BtY[:, :nth]
        if r_th is None:
            return schur, Y, None, None
        return schur, Y[:, :nth], Y[:, nth], r_th - BtY[:, nth]

    def _eliminate(self, H: np.ndarray, g: np.ndarray | None, S: np.ndarray, c: np.ndarray | None,
                   mu: float, q2: np.ndarray | None) -> tuple:
        """The KKT band (node states and multipliers), LU-factored and eliminated
        (:meth:`_reduce`; without ``g`` the Schur complement only)."""
        nx, nth = self.nx, self.nth
        d, floor, Hxx, C = self._damped(H, mu)
        ab = self.band.copy()
        np.put(ab, self.at_H, Hxx)
        Sx = S[:, :, :nx]
        np.put(ab, self.at_S, Sx)
        np.put(ab, self.at_St, Sx.transpose(0, 2, 1))
        if q2 is not None and np.any(q2 > 0):
            np.put(ab, self.at_q, -np.broadcast_to(q2, (len(self.loff), nx)))
        B = np.zeros((self.n, nth + (g is not None)))
        B[self.rows_x, :nth] = H[:, :nx, nx:].reshape(-1, nth)
        B[self.rows_l, :nth] = S[:, :, nx:].reshape(-1, nth)
        r_th = None
        if g is not None:
            B[self.rows_x, nth] = -g[:, :nx].ravel()
            B[self.rows_l, nth] = -c.ravel()
            r_th = -g[:, nx:].sum(axis=0)

        def lu(rhs):
            try:
                return solve_banded((self.l, self.u), ab, rhs, overwrite_ab=True, overwrite_b=True,
                                    check_finite=False)
            except (np.linalg.LinAlgError, ValueError) as e:
                raise SolverError(f"Gauss-Newton step: singular KKT system ({e})") from None
        return self._reduce(C, B, lu, r_th)

    def _soft_normal(self, H: np.ndarray, g: np.ndarray | None, S: np.ndarray, c: np.ndarray | None,
                     mu: float, q2: np.ndarray) -> tuple:
        """Soft continuity: the normal equations of the cost plus ``|gap|^2 / (2 q^2)`` in the
        node states (a band, Cholesky-factored) and the parameters (its border), eliminated
        like :meth:`_eliminate`. Raises LinAlgError when the band is not positive definite."""
        nx, nth, nn = self.nx, self.nth, self.n_nodes * self.nx
        ar = np.arange(nx)
        zi = self.zi
        Dq = np.broadcast_to(1.0 / q2, (len(zi), nx))              # gap weights
        Sx, St = S[:, :, :nx], S[:, :, nx:]
        SxD = Sx.transpose(0, 2, 1) * Dq[:, None, :]              # Sx^T D
        d, floor, Hxx, C = self._damped(H, mu)
        Hxx[zi] += SxD @ Sx                                        # each node starts <= 1 interval
        Hxx[(zi + 1)[:, None], ar, ar] += Dq                       # and ends <= 1
        ab = np.zeros((self.us + 1, nn))
        np.put(ab, self.soft_at_H, Hxx.reshape(-1)[self.soft_upper])
        np.put(ab, self.soft_at_off, -SxD)
        Hxt = H[:, :nx, nx:].copy()
        Hxt[zi] += SxD @ St
        Hxt[zi + 1] -= Dq[:, :, None] * St
        B = np.empty((nn, nth + (g is not None)))
        B[:, :nth] = Hxt.reshape(nn, nth)
        C = C + np.einsum("kai,ka,kaj->ij", St, Dq, St)
        r_th = None
        if g is not None:
            rx = -g[:, :nx].copy()
            rx[zi] -= np.einsum("kab,kb->ka", SxD, c)
            rx[zi + 1] += Dq * c
            B[:, nth] = rx.ravel()
            r_th = -g[:, nx:].sum(axis=0) - np.einsum("kai,ka,ka->i", St, Dq, c)
        chol = cholesky_banded(ab, overwrite_ab=True, lower=False, check_finite=False)
        return self._reduce(C, B, lambda rhs: cho_solve_banded((chol, False), rhs, overwrite_b=True,
                                                               check_finite=False), r_th)

    def solve(self, H: np.ndarray, g: np.ndarray, S: np.ndarray, c: np.ndarray, mu: float,
              q2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The damped Gauss-Newton step. H: (n_nodes, nz, nz) node curvature (zero for nodes
        without data), g: (n_nodes, nz) gradients, S: (n_int, nx, nz) each interval's end
        state's sensitivity to (its start state, the parameters), c: (n_int, nx) gaps, ``mu``
        Levenberg-Marquardt damping (relative to the diagonal). ``q2``: process-noise
        variances (nx,) or (n_int, nx) of soft continuity rows (None: hard); the penalty
        ``|gap|^2/(2 q^2)`` puts ``-q^2`` on the multiplier diagonal, which keeps the band,
        and with every gap penalised the multipliers are eliminated too (Cholesky).
        Returns (dz (n_nodes, nz): every node's state step beside the parameter step,
        multipliers (n_int, nx))."""
        nx, nth = self.nx, self.nth
        soft = None
        if q2 is not None and np.all(q2 > 0):
            try:
                soft = self._soft_normal(H, g, S, c, mu, q2)
            except np.linalg.LinAlgError:
                pass        # not positive definite to rounding: the KKT system below
        schur, Y, y, r_th = soft if soft is not None else self._eliminate(H, g, S, c, mu, q2)
        try:
            dth = np.linalg.solve(schur, r_th) if nth else np.zeros(0)
        except np.linalg.LinAlgError as e:
            raise SolverError(f"Gauss-Newton step: singular KKT system ({e})") from None
        u = y - Y @ dth
        dz = np.empty((self.n_nodes, nx + nth))
        dz[:, nx:] = dth
        if soft is None:
            dz[:, :nx] = u[self.rows_x].reshape(-1, nx)
            return dz, u[self.rows_l].reshape(-1, nx)
        dz[:, :nx] = dx = u.reshape(-1, nx)
        zi = self.zi
        # the multipliers: the linearised gaps after the step over q^2
        lam = (np.einsum("kab,kb->ka", S[:, :, :nx], dx[zi]) + S[:, :, nx:] @ dth - dx[zi + 1] + c) / q2
        return dz, lam

    def _parameter_columns(self, H: np.ndarray, S: np.ndarray, q2: np.ndarray | None
                           ) -> tuple[bool, np.ndarray, np.ndarray]:
        """The undamped band eliminated against the parameters' columns: (soft, Schur
        complement, the band's solution for those columns). With every gap penalised the
        normal equations in the node states (``soft``), else (or when those are not positive
        definite to rounding) the KKT band with its multipliers."""
        if q2 is not None and np.all(q2 > 0):
            try:
                schur, Y = self._soft_normal(H, None, S, None, 0.0, q2)[:2]
                return True, schur, Y
            except np.linalg.LinAlgError:
                pass
        schur, Y = self._eliminate(H, None, S, None, 0.0, q2)[:2]
        return False, schur, Y

    def influence(self, H: np.ndarray, g: np.ndarray, S: np.ndarray, c: np.ndarray,
                  q2: np.ndarray | None = None) -> np.ndarray:
        """Each interval's share of the undamped step in the parameters, (n_int, nth): the
        step is linear in the right-hand side (the gradients ``g`` and gaps ``c``), and the
        rows of one interval are its residuals' and its gap's. The shares sum to the step's
        parameter part; at an optimum their spread over the intervals is what the estimate's
        scatter is made of (a sandwich covariance, :func:`greybox.fitting.robust.long_run_covariance`)."""
        nx, nth = self.nx, self.nth
        zi = self.zi
        if not nth:
            return np.zeros((len(zi), 0))
        soft, schur, Y = self._parameter_columns(H, S, q2)
        gx, gth = g[zi, :nx], g[zi, nx:]
        if soft:
            Y = Y.reshape(self.n_nodes, nx, nth)
            Dq = np.broadcast_to(1.0 / q2, (len(zi), nx))
            Dc = Dq * c
            Sx, St = S[:, :, :nx], S[:, :, nx:]
            # the band's right-hand side of interval k: -g_x at its node, -Sx^T D c there and
            # +D c at the next node; the parameters': -g_th - St^T D c
            r = (-gth - np.einsum("kai,ka->ki", St, Dc)
                 + np.einsum("kai,ka->ki", Y[zi], gx + np.einsum("kab,ka->kb", Sx, Dc))
                 - np.einsum("kai,ka->ki", Y[zi + 1], Dc))
        else:
            Yx, Yl = Y[self.rows_x].reshape(self.n_nodes, nx, nth), Y[self.rows_l].reshape(-1, nx, nth)
            r = -gth + np.einsum("kai,ka->ki", Yx[zi], gx) + np.einsum("kai,ka->ki", Yl, c)
        try:
            return np.linalg.solve(schur, r.T).T
        except np.linalg.LinAlgError as e:
            raise SolverError(f"Gauss-Newton influence: singular KKT system ({e})") from None

    def parameter_inverse(self, H: np.ndarray, S: np.ndarray, q2: np.ndarray | None = None) -> np.ndarray:
        """The parameter block of the inverse of the undamped KKT matrix (the inverse of the
        Schur complement): the Gauss-Newton covariance of the parameters for unit-variance
        weighted residuals."""
        schur = self._parameter_columns(H, S, q2)[1]
        try:
            return np.linalg.inv(schur)
        except np.linalg.LinAlgError as e:
            raise SolverError(f"Gauss-Newton covariance: singular KKT system ({e})") from None


class FitSession:
    """One multiple-shooting problem (model, logs, free set, weights) as the solvers see it:
    evaluation of residuals, gaps and Gauss-Newton blocks at (node states X, scaled free
    parameters th), the undamped or damped Gauss-Newton step with bounds (an active set),
    the covariance and the first-order optimality test. ``solver`` runs the iterations."""

    def __init__(self, model: QuadrotorModel, logs: Sequence[FlightLog], free_idx: list[int], p: np.ndarray,
                 sigma: np.ndarray, interval: int, compile: str, say: Callable[[str], None],
                 solver: "Solver | None" = None, per_flight: Sequence[int] = ()):
        self.model, self.logs, self.free_idx, self.say = model, list(logs), free_idx, say
        self.solver = solver if solver is not None else GaussNewton()
        params_by_comp = {n: par for par in model.parameters for n in par.component_names}
        # scale by the starting value where there is one (a 30 g and a 3 kg vehicle differ in
        # K_T by 1000x); a parameter starting at zero gets its nominal scale
        scale = np.array([abs(p[i]) if p[i] != 0 else params_by_comp[model.param_names[i]].scale
                          for i in free_idx])
        self.scale_local = scale
        # Parameters fitted per flight (``per_flight``: positions in ``free_idx``): the solver's
        # parameter vector holds one copy per flight; ``theta_index[f, j]`` is where flight f's
        # free parameter j sits in it. The interval functions see only their flight's copy,
        # so the structure (and its compiled code) is that of one flight.
        n_local, n_flights = len(free_idx), len(self.logs)
        spread = sorted(set(per_flight)) if n_flights > 1 else []
        self.theta_index = np.tile(np.arange(n_local), (n_flights, 1))
        names = [model.param_names[i] for i in free_idx]
        self.names = [f"{n}@1" if j in spread else n for j, n in enumerate(names)]
        k = n_local
        for f in range(1, n_flights):
            for j in spread:
                self.theta_index[f, j] = k
                self.names.append(f"{names[j]}@{f + 1}")
                k += 1
        self.per_flight = spread
        self.local_of = np.empty(k, dtype=int)       # global position -> free parameter
        for f in range(n_flights):
            self.local_of[self.theta_index[f]] = np.arange(n_local)
        self.scale = scale[self.local_of]
        lo, hi = parameter_bounds(model)
        self.lo_s, self.hi_s = lo[free_idx][self.local_of] / self.scale, hi[free_idx][self.local_of] / self.scale
        self.sigma = sigma.copy()
        # process noise per state, (nx,), or per interval (n_int, nx) when flights have their
        # own (None: hard continuity)
        self.q: np.ndarray | None = None
        self.max_step: float | None = None   # trust region on the scaled parameters (None: off)
        self.interval = interval
        t0 = time.perf_counter()
        self.prob = ShootingProblem(model, free_idx, interval, log_substeps(logs), compile)
        self.t_build = time.perf_counter() - t0
        self.data = layout(model, logs, interval, sigma)
        self.n_int = sum(M for _, M in self.data.flights)
        self.mapped = self.prob.mapped(self.n_int)
        self.nx, self.nth = model.nx, len(self.local_of)
        self.nz = self.nx + self.nth
        self.kkt = BorderedKKT(self.data.flights, model.nx, self.nth)
        counts = [M for _, M in self.data.flights]
        self.interval_slices = [slice(a, a + M) for a, M in zip(np.cumsum([0] + counts[:-1]), counts)]
        # per interval, the solver's parameters its flight's copy is made of
        self.theta_of_interval = np.repeat(self.theta_index, counts, axis=0)
        self.flight_of_interval = np.repeat(np.arange(len(counts)), counts)
        self.pfix = p.copy()
        n_nodes = self.n_int + len(self.data.flights)
        self.last_mask = np.zeros(n_nodes, dtype=bool)
        k = 0
        for _, M in self.data.flights:
            self.last_mask[k + M] = True
            k += M + 1
        self.nxt = self.kkt.zi + 1

    def set_sigma(self, sigma: np.ndarray) -> None:
        self.sigma = sigma.copy()
        self.data.W = np.where(self.data.mask, 1.0 / sigma[:, None], 0.0)

    def initial_nodes(self, p: np.ndarray) -> np.ndarray:
        return np.vstack([initial_node_states(self.model, log, idx, p)
                          for log, idx in zip(self.logs, self.data.node_index)])

    def theta(self, p: "np.ndarray | Sequence[np.ndarray]") -> np.ndarray:
        """The solver's scaled parameters: every flight's copy at ``p``'s value, or at its own
        flight's (``p`` a list of one parameter vector per flight)."""
        if isinstance(p, np.ndarray) and p.ndim == 1:
            return p[self.free_idx][self.local_of] / self.scale
        th = np.empty(self.nth)
        for f, pf in enumerate(p):
            th[self.theta_index[f]] = np.asarray(pf)[self.free_idx] / self.scale_local
        return th

    def flight_theta(self, th: np.ndarray, f: int) -> np.ndarray:
        """Flight ``f``'s free parameters (unscaled, ``free_idx`` order)."""
        return th[self.theta_index[f]] * self.scale_local

    def evaluate(self, X, th, blocks=True):
        nx, n_int = self.nx, self.n_int
        spread = bool(self.per_flight)
        nz = nx + len(self.free_idx)
        # one flight's copy per interval (a map input given per column), or the one vector
        th_arg = th[self.theta_of_interval].T if spread else th
        args = (X[~self.last_mask].T, th_arg, self.scale_local, self.pfix, self.data.U, self.data.T, self.data.Hs,
                self.data.Y, self.data.W)
        if blocks:
            xe, S, H, g, c = self.mapped.blocks(*args)
            S = np.asarray(S).reshape(nx, n_int, nz).transpose(1, 0, 2)
            H = np.asarray(H).reshape(nz, n_int, nz).transpose(1, 0, 2)
            g = np.asarray(g).T
            if spread:
                S, H, g = self._spread(S, H, g)
            return np.asarray(xe).T, S, H, g, np.asarray(c)
        xe, c = self.mapped.value(*args)
        return np.asarray(xe).T, np.asarray(c)

    def _spread(self, S, H, g):
        """Blocks in one flight's parameters -> blocks in the solver's (all flights' copies)."""
        nx, nz = self.nx, self.nz
        S2 = np.zeros((S.shape[0], nx, nz))
        H2 = np.zeros((H.shape[0], nz, nz))
        g2 = np.zeros((g.shape[0], nz))
        for f, sl in enumerate(self.interval_slices):
            zi = np.concatenate([np.arange(nx), nx + self.theta_index[f]])
            S2[sl, :, zi] = S[sl]      # one advanced index: its axis stays in place
            H2[sl, zi[:, None], zi[None, :]] = H[sl]
            g2[sl, zi] = g[sl]
        return S2, H2, g2

    def gaps(self, X, xe):
        return xe - X[self.nxt]

    def _q2(self) -> np.ndarray | None:
        return None if self.q is None else self.q ** 2

    def total_cost(self, X, xe, c) -> float:
        """Measurement cost, plus the process-noise cost of the gaps when continuity is soft."""
        cost = 0.5 * float(c.sum())
        if self.q is not None:
            cost += 0.5 * float(((self.gaps(X, xe) / self.q) ** 2).sum())
        return cost

    def _kkt_parts(self, X, blocks):
        """Per node curvature and gradient (zero at each flight's last node, which has no
        interval of its own), the intervals' sensitivities and gaps."""
        xe, S, Hb, g, _ = blocks
        nz = self.nz
        H = np.zeros((X.shape[0], nz, nz))
        gg = np.zeros((X.shape[0], nz))
        H[~self.last_mask] = Hb
        gg[~self.last_mask] = g
        return H, gg, S, self.gaps(X, xe)

    def step(self, X, th, blocks, mu, held: np.ndarray | None = None):
        """Gauss-Newton step with parameters on a bound held when the step points outward;
        ``held``: parameters (a mask over ``th``) held where they are in any case."""
        H, gg, S, cz = self._kkt_parts(X, blocks)
        nx, nth, kkt = self.nx, self.nth, self.kkt
        frozen = np.zeros(nth, dtype=bool) if held is None else np.array(held, dtype=bool)
        for _ in range(nth + 1):
            Hf, gf, Sf = H, gg, S
            if frozen.any():
                # hold a parameter by removing it from the step: no curvature, gradient or
                # sensitivity anywhere, a unit diagonal at the first node. (A large penalty
                # instead cost the banded solve its accuracy: the gaps it should close stayed
                # open, and the iteration crawled along the bound for dozens of steps.)
                fz = nx + np.flatnonzero(frozen)
                Hf, gf, Sf = H.copy(), gg.copy(), S.copy()
                Hf[:, fz, :] = 0.0
                Hf[:, :, fz] = 0.0
                Hf[0, fz, fz] = 1.0
                gf[:, fz] = 0.0
                Sf[:, :, fz] = 0.0
            dz, lam = kkt.solve(Hf, gf, Sf, cz, mu, q2=self._q2())
            dth = dz[0, nx:]
            out = (((th <= self.lo_s + 1e-12) & (dth < 0)) | ((th >= self.hi_s - 1e-12) & (dth > 0))) & ~frozen
            if not out.any():
                break
            # hold the worst violator only, then look again: the others may turn inward
            frozen[np.flatnonzero(out)[np.argmax(np.abs(dth[out]))]] = True
        dz[:, nx:] = np.where(frozen, 0.0, dz[:, nx:])
        self.last_held = frozen
        return dz, lam, H, gg, cz

    def predicted_decrease(self, X, th, blocks: tuple | None = None, held: np.ndarray | None = None) -> float:
        """Cost decrease one undamped Gauss-Newton step predicts from (X, th): at the optimum of
        a smaller model it is half the score (Lagrange multiplier) statistic of the extra
        parameters. ``blocks``: :meth:`evaluate` at (X, th) when already known; ``held``: a
        mask of parameters held (the step of the model without them: several candidates'
        statistics from one evaluation)."""
        blocks = self.evaluate(X, th) if blocks is None else blocks
        return self._decrease(*self.step(X, th, blocks, 0.0, held=held))

    def predicted_optimum(self, X, th) -> float:
        """The cost at (X, th) less :meth:`predicted_decrease`: the cost one undamped
        Gauss-Newton step predicts it reaches (one evaluation for both)."""
        blocks = self.evaluate(X, th)
        return self.total_cost(X, blocks[0], blocks[4]) - self._decrease(*self.step(X, th, blocks, 0.0))

    def _decrease(self, dz, lam, H, gg, cz) -> float:
        """The cost decrease the Gauss-Newton step ``dz`` (with multipliers ``lam``) predicts."""
        d = float(-(gg * dz).sum() - 0.5 * np.einsum("ki,kij,kj->", dz, H, dz))
        if self.q is not None:
            # soft continuity: the linearised gaps after the step are q^2 * lambda
            q2 = self.q ** 2
            d += 0.5 * float((cz[:, :self.nx] ** 2 / q2).sum()) - 0.5 * float((q2 * lam[:, :self.nx] ** 2).sum())
        return d

    def _realised_decrease(self, X, th, blocks, dz, fractions=(1.0, 0.5, 0.25, 0.125, 0.0625)) -> float:
        """The largest cost decrease actually reached along the step ``dz`` at ``fractions`` of
        it (one evaluation of the residuals each; the parameters kept inside their bounds)."""
        base = self.total_cost(X, blocks[0], blocks[4])
        best = 0.0
        for a in fractions:
            th1 = np.clip(th + a * dz[0, self.nx:], self.lo_s, self.hi_s)
            X1 = X + a * dz[:, :self.nx]
            xe, c = self.evaluate(X1, th1, blocks=False)
            cost = self.total_cost(X1, xe, c)
            if np.isfinite(cost):
                best = max(best, base - cost)
        return best

    def solve(self, X, th, mu, max_iter, tol, rough: bool = False):
        """Run the session's solver from (X, th): see :class:`Solver`."""
        return self.solver.solve(self, X, th, mu, max_iter, tol, rough)

    def covariance(self, X, blocks) -> np.ndarray:
        """Parameter block of the inverse KKT matrix (undamped): the Gauss-Newton covariance
        of the scaled free parameters for unit-variance weighted residuals."""
        H, _, S, _ = self._kkt_parts(X, blocks)
        P = self.kkt.parameter_inverse(H, S, q2=self._q2())
        return 0.5 * (P + P.T)

    def influence(self, X, blocks) -> np.ndarray:
        """Each interval's share of the undamped Gauss-Newton step in the scaled free
        parameters, (n_int, nth) (:meth:`BorderedKKT.influence`)."""
        H, gg, S, cz = self._kkt_parts(X, blocks)
        return self.kkt.influence(H, gg, S, cz, q2=self._q2())

    @property
    def interval_duration(self) -> float:
        """One shooting interval in seconds (the median sample period times the interval)."""
        hs = self.data.Hs[self.data.Hs > 0]
        return max(self.interval, 1) * (float(np.median(hs)) if hs.size else 1.0)

    @property
    def disturbance_sources(self) -> dict[int, int]:
        """``{disturbance state index: index of the state it drives}`` from the effects'
        :attr:`~greybox.effects.Effect.rate_of_unmodelled`."""
        names = self.model.state_names
        return {names.index(d): names.index(src) for e in self.model.effects
                for d, src in e.rate_of_unmodelled.items()}

    def state_noise_scale(self, sensor: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Per state, the size of a change the measurements could just see: the sensor noise
        of its channel (positions, angles, gyro), over one shooting interval for velocities
        (and body rates without a gyro); 1e-3 of its spread for effect states, but a
        disturbance state's random-walk step (:attr:`~greybox.effects.Effect.rate_of_unmodelled`)."""
        T = self.interval_duration
        sig = dict(zip(OUTPUTS, sensor))
        measured = {n for c, n in enumerate(OUTPUTS) if self.data.mask[c].any()}
        out = np.empty(self.nx)
        for j, name in enumerate(self.model.state_names):
            if name in ("x", "y", "z", "phi", "theta", "psi"):
                out[j] = sig[name]
            elif name in ("vx", "vy", "vz"):
                out[j] = sig["xyz"[j - 6]] / T
            elif name in ("p", "q", "r"):
                out[j] = sig[name] if name in measured else sig[("phi", "theta", "psi")[j - 9]] / T
            else:
                out[j] = 1e-3 * (float(np.std(X[:, j])) + 1e-6 * (1.0 + float(np.abs(X[:, j]).max())))
        # a disturbance state (the rate of what the model misses in another state) is a random
        # walk: its own process noise per interval, at least the change that moves that
        # state by its scale over one interval
        q = None if self.q is None else np.median(np.atleast_2d(self.q), axis=0)
        for j, src in self.disturbance_sources.items():
            out[j] = max(out[src] / T, 0.0 if q is None else float(q[j]))
        return out

    def optimality(self, X, th, blocks, P: np.ndarray, s2: float, sensor: np.ndarray
                   ) -> tuple[float, float, float, list[str], list[str]]:
        """First-order optimality at (X, th): the undamped Gauss-Newton step (projected onto
        the bounds) in parameter standard deviations and in state noise scales, and the
        largest continuity gap against the state's noise scale. At an optimum the step is
        zero whatever the size of the residuals. Returns (step/std, state step/noise,
        gap/noise, held parameters, reasons it is not optimal)."""
        reasons: list[str] = []
        names = self.names
        try:
            dz, lam, H, gg, cz = self.step(X, th, blocks, 0.0)
        except SolverError as e:
            return math.inf, math.inf, math.inf, [], [f"the Gauss-Newton system is singular at the end point ({e})"]
        held = [n for n, h in zip(names, self.last_held) if h]
        scale = self.state_noise_scale(sensor, X)
        var = s2 * np.diag(P)
        ok = var > 0
        if not np.all(ok):
            reasons.append("the information matrix is singular in " +
                           ", ".join(n for n, k in zip(names, ok) if not k))
        dth = dz[0, self.nx:]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(ok, np.abs(dth) / np.sqrt(np.abs(var)), np.inf)
        ratio = np.where(self.last_held, 0.0, ratio)
        step_std = float(ratio.max()) if ratio.size else 0.0
        state_step = float((np.abs(dz[:, :self.nx]) / scale).max())
        gap = 0.0 if self.q is not None else float((np.abs(cz[:, :self.nx]) / scale).max())
        if step_std > STEP_TOLERANCE and np.all(ok):
            worst = names[int(np.argmax(ratio))]
            reasons.append(f"one more Gauss-Newton step would move {worst} by {step_std:.3g} std")
        # An effect's state at a node can be nearly invisible in the outputs (a motor lag's
        # effective speed: a 0.03 rad/s change moves a 1 kg vehicle by microns); a remaining
        # step there that would not lower the cost measurably changes no conclusion. Nor does
        # one whose predicted decrease the cost does not follow along it: under process noise
        # that spans eleven decades of weights (a 2 kg vehicle's vz gaps 3e-6 m/s, a motor
        # lag's states 2e-3 rad/s) the undamped step's prediction is rounding (a blind audit:
        # 0.064 predicted from the first nodes' lag states, +9.8 taken, -0.005 at a tenth).
        invisible = gap <= GAP_TOLERANCE and step_std <= STEP_TOLERANCE and (
            self._decrease(dz, lam, H, gg, cz) < DECREASE_TOLERANCE
            or self._realised_decrease(X, th, blocks, dz) < DECREASE_TOLERANCE)
        if state_step > STEP_TOLERANCE and not invisible:
            j = int(np.argmax((np.abs(dz[:, :self.nx]) / scale).max(axis=0)))
            reasons.append(f"one more Gauss-Newton step would move the state {self.model.state_names[j]} by "
                           f"{state_step:.3g} of its noise scale")
        if gap > GAP_TOLERANCE:
            j = int(np.argmax((np.abs(cz[:, :self.nx]) / scale).max(axis=0)))
            reasons.append(f"shooting gaps are open (largest in {self.model.state_names[j]}: {gap:.3g} of its noise scale)")
        return step_std, state_step, gap, held, reasons




EXTRAPOLATE = 64.0
"""Longest multiple of a full Gauss-Newton step tried when the solve converges linearly
(:data:`SLOW_RATIO`): 2, 4, ... times the step while the merit keeps falling."""
EXTRA_GAIN = 0.1
"""A longer step is kept only when it lowers the merit below the shorter one's by at least this
share of what the full step gained (no step lengthened for a rounding-level gain)."""
SLOW_RATIO = 0.5
"""A full step whose cost decrease is more than this share of the previous full step's
marks linear convergence: the next full step is extended (:data:`EXTRAPOLATE`)."""


class GaussNewton:
    """Damped (Levenberg–Marquardt) Gauss–Newton with a backtracking line search on an l1
    merit function; the default :class:`Solver`.

    Example::

        res = greybox.fit(model, log, solver=GaussNewton())   # the same as no solver=

    ``negligible_decrease``: it stops once full steps whose cost decreases fall geometrically
    would together lower the cost (half the weighted chi-square) by less than this, however
    far the parameters still creep; ``None`` to run to the step tolerance alone.

    ``extrapolate``: the longest multiple of a full step tried once full steps converge
    linearly (each lowering the cost by more than :data:`SLOW_RATIO` of the one before): 2, 4,
    ... times the step along its direction while the merit keeps falling, one evaluation of
    the residuals each; ``1.0`` turns it off.

    ``stop``: called as ``stop(session, th)`` after every accepted step; words returned (not
    "") end the solve there, its status :data:`STOPPED` followed by them, not converged, and
    the fit takes it as a spent budget (:func:`budget_spent`). A diagnosis stops a
    candidate's refit that holds the candidate on a bound beyond what it physically does.
    """

    def __init__(self, negligible_decrease: float | None = 0.1 * DECREASE_TOLERANCE,
                 stop: "Callable[[FitSession, np.ndarray], str] | None" = None,
                 extrapolate: float = EXTRAPOLATE):
        self.negligible_decrease = negligible_decrease
        self.stop = stop
        self.extrapolate = float(extrapolate)

    def solve(self, ses: "FitSession", X, th, mu, max_iter, tol, rough: bool = False):
        """Damped Gauss-Newton from (X, th). ``rough``: stop once the cost settles to 1e-3
        with the gaps closed (a solve whose residuals only serve to re-estimate the weights)."""
        say, nx, n_int = ses.say, ses.nx, ses.n_int
        rho = np.zeros((n_int, nx))
        blocks = ses.evaluate(X, th)
        soft = ses.q is not None
        cost = ses.total_cost(X, blocks[0], blocks[4])
        last_rel, last_decrease = np.inf, np.inf
        last_actual, slow = 0.0, False

        def merit(Xm, xe, c):
            """The line search's merit at nodes ``Xm`` (end states ``xe``, residual costs ``c``):
            the cost with soft continuity, else the cost plus the l1 penalty on the gaps."""
            # a trial step that blows the states up gives an infinite merit, which the line
            # search refuses: numpy's overflow warning there is no news for the user
            with np.errstate(over="ignore", invalid="ignore"):
                if soft:
                    return ses.total_cost(Xm, xe, c)
                return 0.5 * float(c.sum()) + float((rho * np.abs(ses.gaps(Xm, xe))).sum())
        it, status, converged = 0, "maximum iterations reached", False
        for it in range(1, max_iter + 1):
            dz, lam, H, gg, cz = ses.step(X, th, blocks, mu)
            # what this (nearly undamped) step lowers the cost by, on the Gauss-Newton model
            decrease = ses._decrease(dz, lam, H, gg, cz) if mu <= 1e-5 and self.negligible_decrease else np.inf
            c = cz[:, :nx]
            dX, dth = dz[:, :nx], dz[0, nx:]
            rho = np.maximum(rho, 2.0 * np.abs(lam[:, :nx]) + 1e-8)
            if soft:  # an unconstrained least-squares problem: the cost is the merit
                merit0, slope = cost, 0.0
            else:
                merit0 = cost + float((rho * np.abs(c)).sum())
                slope = float((gg * dz).sum()) - float((rho * np.abs(c)).sum())
            alpha, accepted, trial = 1.0, False, None
            if ses.max_step is not None and ses.nth:
                big = float(np.max(np.abs(dth)))
                if big > ses.max_step:
                    alpha = ses.max_step / big
            for ls in range(14):
                # projected step: parameters are clipped onto their bounds
                Xt, tht = X + alpha * dX, np.clip(th + alpha * dth, ses.lo_s, ses.hi_s)
                if ls == 0:  # the full step is usually taken: its blocks serve the next iteration
                    trial = ses.evaluate(Xt, tht)
                    xe_t, c_t = trial[0], trial[4]
                else:
                    trial = None
                    xe_t, c_t = ses.evaluate(Xt, tht, blocks=False)
                merit_t = merit(Xt, xe_t, c_t)
                if np.isfinite(merit_t) and merit_t <= merit0 + 1e-4 * alpha * min(slope, 0.0) and \
                        (not soft or merit_t < merit0):
                    accepted = True
                    break
                alpha *= 0.5
            if accepted and alpha == 1.0 and self.extrapolate > 1.0 and slow:
                # Linear convergence: full steps that each take the same share of what is left
                # along nearly the same direction (a large-residual fit, a stiff state chain: a
                # motor lag's refit crept 0.2 of cost per step for 400 steps). Longer steps along
                # the direction are tried while the merit keeps falling; never past the trust
                # region a retried fit keeps its parameters in.
                longest = self.extrapolate
                if ses.max_step is not None and ses.nth and float(np.max(np.abs(dth))) > 0:
                    longest = min(longest, ses.max_step / float(np.max(np.abs(dth))))
                full_gain = merit0 - merit_t
                longer = 2.0
                while longer <= longest:
                    raw = th + longer * dth
                    Xe, the = X + longer * dX, np.clip(raw, ses.lo_s, ses.hi_s)
                    merit_e = merit(Xe, *ses.evaluate(Xe, the, blocks=False))
                    # each doubling must gain a real share of what the full step gained
                    if not (np.isfinite(merit_e) and merit_e < merit_t - EXTRA_GAIN * full_gain):
                        break
                    Xt, tht, merit_t, trial, alpha = Xe, the, merit_e, None, longer
                    if np.any(the != raw):
                        break          # a bound cut the step: it no longer follows the direction
                    longer *= 2.0
                slow = alpha > 1.0
            step_size = float(np.max(np.abs(tht - th))) if ses.nth else 0.0
            if not accepted:
                if mu > 1e6:
                    if soft and last_rel < 1e-4:
                        # no decrease left to find: the smoother is at its optimum to rounding
                        converged, status = True, "converged"
                        break
                    status = "line search failed: no decrease along the Gauss-Newton direction"
                    break
                mu = max(mu * 10, 1e-3)
                say(f"  iter {it:3d}  step rejected, damping -> {mu:.1e}")
                continue
            X, th = Xt, tht
            mu = mu / 3 if alpha >= 1.0 else min(mu * 2, 1e8)
            mu = max(mu, 1e-10)
            blocks = trial if trial is not None else ses.evaluate(X, th)
            new_cost = ses.total_cost(X, blocks[0], blocks[4])
            gap = float(np.abs(ses.gaps(X, blocks[0])).max())
            say(f"  iter {it:3d}  cost {new_cost:12.6g}  max gap {gap:9.2e}  step {step_size:9.2e}  alpha {alpha:.3f}")
            rel = abs(cost - new_cost) / max(new_cost, 1e-300)
            last_rel = rel
            if alpha == 1.0:
                # a full step repeating much of the last full step's decrease: linear convergence
                slow = slow or (last_actual > 0 and (cost - new_cost) > SLOW_RATIO * last_actual)
                last_actual = cost - new_cost
            elif alpha < 1.0:
                slow, last_actual = False, 0.0
            else:
                last_actual = 0.0        # a longer step's decrease is no full step's to compare with
            cost = new_cost
            # soft continuity: the smoother's states settle slowly once the parameters have
            # stopped moving, so a looser cost test
            x_scale = 1 + float(np.abs(X).max())
            closed = gap < 1e-6 * x_scale
            if step_size < tol and ((soft and rel < 1e-4) or (rel < 1e-6 and closed)):
                converged, status = True, "converged"
                break
            # Whatever the steps still move, the cost has nothing left to give: full steps whose
            # decreases fall geometrically (ratio q) leave at most decrease * q / (1 - q), and below
            # a tenth of the certificate's DECREASE_TOLERANCE that changes no statistic. A
            # large-residual fit (a real flight's final model) converges linearly: its parameters
            # crept by 1e-5 of their scale per step for 230 more iterations (368 against 137,
            # 150 s against 41 s) to the same cost.
            if alpha == 1.0 and (soft or closed) and np.isfinite(decrease) and np.isfinite(last_decrease):
                q = min(max(decrease, 0.0) / max(last_decrease, 1e-300), 0.99)
                if decrease * q / (1 - q) < self.negligible_decrease and decrease < DECREASE_TOLERANCE:
                    converged, status = True, "converged (the cost decrease left is negligible)"
                    break
            last_decrease = decrease if alpha == 1.0 else np.inf
            if rough and not soft and rel < 1e-3 and gap < 1e-4 * x_scale:
                # the weights from these residuals change by < 0.1 %: more iterations would be
                # spent on a problem about to be re-weighted (a large-residual start can creep
                # at a linear rate for dozens of iterations)
                converged, status = True, "settled (weights to be re-estimated)"
                break
            why = self.stop(ses, th) if self.stop is not None else ""
            if why:
                status = STOPPED + why
                break
        if not np.all(np.isfinite(X)) or not np.all(np.isfinite(th)):
            raise SolverError("fit diverged: non-finite states or parameters")
        return X, th, mu, it, converged, status, blocks


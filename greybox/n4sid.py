"""Black-box subspace identification: ``n4sid`` for closed-loop flights, in numpy/scipy.

A quadrotor is unstable in open loop, so its identification data are always closed loop:
the controller feeds output noise back into the inputs. The classical N4SID oblique
projection (Van Overschee & De Moor) assumes future inputs uncorrelated with past noise
and is biased there; on our flights it predicted 1 s ahead far worse than the same data
allow. ``n4sid`` therefore uses, by default, the predictor-based member of the family
(PBSID, Chiuso 2007; the closed-loop counterpart of N4SID/MOESP), ``method="pbsid"``:

1. a VARX model of the one-step predictor over a past window of ``p`` samples by least
   squares (the innovation is uncorrelated with all past inputs and outputs, feedback or
   not);
2. the predictor's Markov parameters arranged as ``Gamma K``, times the past data: its SVD
   gives the order (the singular values are kept for :func:`order_plot`) and the state
   sequence;
3. ``C`` (and ``D`` with ``feedthrough``) and then ``A, B`` (with the Kalman gain) by least
   squares on the state sequence.

``method="oblique"`` keeps the classical algorithm (oblique projection, ``A``, ``C`` by
shift invariance, ``B`` by least squares over 1-s windows with their own initial states)
for comparison. Both work on Gram matrices of the Hankel data (one BLAS product), never
on the tall data matrices: 40,000 samples x (4 in, 6 out) take well under a second.

``order="auto"`` fits every order up to ``max_order`` on the first 75 % of the data and
takes the smallest whose 1-s-ahead fit (:meth:`StateSpaceModel.predict_windows`) on the
last 25 % is within 1 % (absolute fit percentage) of the best.

What is left of the closed-loop bias is limited by exciting the loop (the synthetic flights
add a multisine to the commands), by fitting near hover (the linear model is a hover model
anyway) and by a sampling rate at which the past window spans the dynamics (~100 Hz for a
quadrotor: at 1 kHz decimate first). The held-out 1-s-ahead fit checks the result.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import linalg, signal

from .errors import GreyboxInputError

__all__ = ["n4sid", "StateSpaceModel", "fit_percent", "order_plot"]


@dataclass
class StateSpaceModel:
    """Discrete-time ``x+ = A x + B u``, ``y = C x + D u`` around an operating point
    (``u0``, ``y0`` are subtracted before and added after).

    Example::

        ss = n4sid(u, y, dt=0.01)               # a StateSpaceModel
        ss.order, ss.is_stable(), ss.simulate(u)
        ss.to_control()                         # python-control StateSpace
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float
    x0: np.ndarray
    u0: np.ndarray
    y0: np.ndarray
    input_names: list[str] = field(default_factory=list)
    output_names: list[str] = field(default_factory=list)
    singular_values: np.ndarray | None = None
    order_scores: dict[int, float] = field(default_factory=dict)

    @property
    def order(self) -> int:
        return self.A.shape[0]

    def simulate(self, u: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """Outputs (N, l) for inputs ``u`` (N, m) in absolute units, from ``x0`` (default the
        identified initial state)."""
        du = np.asarray(u, dtype=float) - self.u0
        x = self.x0 if x0 is None else np.asarray(x0, dtype=float)
        X = _state_sequence(self.A, self.B @ du.T, x)
        return (self.C @ X).T + du @ self.D.T + self.y0

    def predict_windows(self, u: np.ndarray, y: np.ndarray, horizon: int, init: int) -> np.ndarray:
        """k-step-ahead fit % per output: in consecutive windows of ``horizon`` samples, the
        state at the window start is estimated by least squares from the ``init`` samples
        before it, then the model runs open loop through the window (as
        :func:`greybox.validation.predict` does for the grey-box model). Returns the fit %
        over all windows together (MATLAB ``compare`` with a prediction horizon)."""
        du = np.asarray(u, dtype=float) - self.u0
        dy = np.asarray(y, dtype=float) - self.y0
        n = self.order
        N = du.shape[0]
        starts = np.arange(init, N - horizon + 1, horizon)
        if starts.size == 0:
            raise GreyboxInputError(f"predict_windows: {N} samples are fewer than init + horizon")
        # observability over the init + horizon samples: y_k = C A^k x + forced response
        L = init + horizon
        Obs = _observability(self.A, self.C, L)                             # (L, l, n)
        yh, yt = [], []
        for s0 in starts:
            a = s0 - init
            uu = du[a:a + L]
            forced = _forced_response(self.A, self.B, self.C, self.D, uu)
            x = linalg.lstsq(Obs[:init].reshape(-1, n), (dy[a:s0] - forced[:init]).reshape(-1),
                             check_finite=False)[0]
            pred = Obs @ x + forced
            yh.append(pred[init:])
            yt.append(dy[s0:s0 + horizon])
        return fit_percent(np.vstack(yt), np.vstack(yh))

    def is_stable(self) -> bool:
        return bool(np.max(np.abs(np.linalg.eigvals(self.A))) < 1.0)

    def to_control(self):
        """A python-control ``StateSpace`` (needs python-control)."""
        import control
        return control.ss(self.A, self.B, self.C, self.D, self.dt, inputs=self.input_names or None,
                          outputs=self.output_names or None)


def _state_sequence(A: np.ndarray, Bu: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """States x_0..x_{N-1} of x+ = A x + Bu[:, k] (columns), x_0 = x0; x0 may be (n, c)."""
    n, N = A.shape[0], Bu.shape[1]
    x = np.array(x0, dtype=float)
    X = np.empty((n, N) + x.shape[1:])
    for k in range(N):
        X[:, k] = x
        x = A @ x + Bu[:, k]
    return X


def _observability(A: np.ndarray, C: np.ndarray, L: int) -> np.ndarray:
    """(L, l, n): the output ``C A^k`` of each initial-state direction, k = 0..L-1."""
    n = A.shape[0]
    return np.einsum("ln,nkc->klc", C, _state_sequence(A, np.zeros((n, L)), np.eye(n)))


def _forced_response(A, B, C, D, u: np.ndarray) -> np.ndarray:
    """(N, l) outputs from a zero initial state under inputs u (N, m)."""
    return (C @ _state_sequence(A, B @ u.T, np.zeros(A.shape[0]))).T + u @ D.T


def _block_hankel(x: np.ndarray, i: int, j: int) -> np.ndarray:
    """Rows: x_k^T of block row k = 0..i-1, columns: time 0..j-1 -> (i*dim, j)."""
    d = x.shape[1]
    H = np.empty((i * d, j))
    for r in range(i):
        H[r * d:(r + 1) * d] = x[r:r + j].T
    return H


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> np.ndarray:
    """MATLAB's ``compare`` fit per output: ``100 (1 - |y - yhat| / |y - mean(y)|)``."""
    e = np.linalg.norm(y - yhat, axis=0)
    d = np.linalg.norm(y - y.mean(axis=0), axis=0)
    return 100.0 * (1.0 - e / np.maximum(d, 1e-300))


def _left_singular(MMt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values (descending) and left singular vectors of ``M`` from ``M M^T``."""
    w, V = linalg.eigh((MMt + MMt.T) / 2, check_finite=False)
    order = np.argsort(w)[::-1]
    return np.sqrt(np.maximum(w[order], 0.0)), V[:, order]


class _Subspace:
    """The oblique projection ``O_i = Yf /_Uf Wp`` of the N4SID algorithm, through its
    left singular vectors and singular values only.

    Everything needed is in the Gram matrix of the stacked Hankel rows ``[Uf; Wp; Yf]``
    (one BLAS product): the regression of ``Yf`` on ``[Uf; Wp]`` is solved on the small
    Gram blocks, and ``O O^T = c_W (Wp Wp^T) c_W^T`` gives the singular vectors without
    ever forming the ``i l x N`` projection (at 40,000 samples that, and a thin least
    squares on the tall Hankel matrix, were 60 % of the time). Same singular values and
    subspace as the tall least squares to 4 digits on our flights (checked).
    """

    def __init__(self, u: np.ndarray, y: np.ndarray, i: int):
        N, m = u.shape
        l = y.shape[1]
        j = N - 2 * i + 1
        Uh = _block_hankel(u, 2 * i, j)
        Yh = _block_hankel(y, 2 * i, j)
        self.m, self.l = m, l
        H = np.vstack([Uh[i * m:], Uh[:i * m], Yh[:i * l], Yh[i * l:]])   # Uf, Wp = [Up; Yp], Yf
        G = H @ H.T / j
        nf, nz = i * m, 2 * i * m + i * l
        coef = linalg.lstsq(G[:nz, :nz], G[nz:, :nz].T, check_finite=False, cond=1e-12)[0].T
        cw = coef[:, nf:]
        s, self.Usv = _left_singular(cw @ G[nf:nz, nf:nz] @ cw.T)
        self.s = s * np.sqrt(j)                                            # singular values of O_i


def _model_of_order(sub: _Subspace, n: int, feedthrough: bool, u: np.ndarray, y: np.ndarray,
                    window: int):
    """A and C from the shift invariance of ``Gamma_i``; B and D by least squares on the
    outputs over windows of ``window`` samples, each window with its own initial state (the
    outputs are linear in them). Restarting every window keeps an open-loop-unstable plant
    (a quadrotor) well posed, where fitting one free-run simulation is not."""
    l, m = sub.l, sub.m
    G = sub.Usv[:, :n] * np.sqrt(sub.s[:n])
    C = G[:l]
    A = linalg.lstsq(G[:-l], G[l:], check_finite=False)[0]
    N = u.shape[0]
    W = max(min(window, N), 2)
    starts = np.arange(0, N - W + 1, W)
    Obs = _observability(A, C, W).reshape(W * l, n)
    nb = n * m + (l * m if feedthrough else 0)
    # normal equations of [x0_1 .. x0_nw, vec(B), vec(D)], block-arrow: eliminate the x0's
    Sbb = np.zeros((nb, nb))
    sb = np.zeros(nb)
    Q_obs = linalg.orth(Obs)                                               # basis of range(Obs)
    M = Obs.reshape(W, l, n)                                               # Markov parameters C A^k
    for s0 in starts:
        uu = u[s0:s0 + W]
        # forced response to B = e_r e_q^T: y_k = sum_{s<k} C A^(k-1-s) e_r u_s[q], one FFT
        # convolution for all (output, input, state) triples instead of m*n simulations
        conv = signal.fftconvolve(M[:, :, None, :], uu[:, None, :, None], axes=0)[:W - 1]
        Phi = np.zeros((W, l, m, n))
        Phi[1:] = conv                                                     # B[r, q] at q n + r
        Phi = Phi.reshape(W, l, m * n)
        if feedthrough:
            Phi_D = np.zeros((W, l, l * m))
            for o in range(l):
                Phi_D[:, o, o * m:(o + 1) * m] = uu
            Phi = np.concatenate([Phi, Phi_D], axis=2)
        Phi = Phi.reshape(W * l, nb)
        yy = y[s0:s0 + W].reshape(-1)
        # the window's own initial state takes whatever lies in range(Obs)
        Phi_r = Phi - Q_obs @ (Q_obs.T @ Phi)
        y_r = yy - Q_obs @ (Q_obs.T @ yy)
        Sbb += Phi_r.T @ Phi_r
        sb += Phi_r.T @ y_r
    sol = linalg.lstsq(Sbb, sb, check_finite=False)[0]
    B = sol[:n * m].reshape(m, n).T
    D = sol[n * m:].reshape(l, m) if feedthrough else np.zeros((l, m))
    return A, B, C, D


class _Predictor:
    """Predictor-based subspace identification (PBSID, Chiuso 2007), consistent on
    closed-loop data.

    1. A VARX model of the one-step *predictor*, ``y_k = sum_s Xi_s z_{k-s} + e_k`` with
       ``z = [u; y]`` over ``p`` past samples, by least squares: the innovation ``e_k`` is
       uncorrelated with all past data even when a controller feeds outputs back into the
       inputs (the oblique projection assumes future inputs uncorrelated with noise,
       which feedback breaks). ``Xi_s = C Ac^(s-1) [B - K D, K]`` with ``Ac = A - K C``.
    2. The block-triangular matrix ``Gamma K`` built from the ``Xi_s``, times the past data,
       estimates ``Gamma X``; its SVD gives the order and the state sequence ``X``.
    3. ``C`` (``D``) by least squares of ``y`` on ``X`` (and ``u``); then ``A, B, K`` by least
       squares of ``x_(k+1)`` on ``[x_k; u_k; e_k]``.

    As in :class:`_Subspace`, everything is done on Gram matrices of the past data (one
    BLAS product), never on the tall data matrices.
    """

    def __init__(self, u: np.ndarray, y: np.ndarray, p: int):
        N, m = u.shape
        l = y.shape[1]
        r = m + l
        j = N - p
        self.m, self.l = m, l
        Zp = _block_hankel(np.hstack([u, y]), p, j)          # column k-p: z_{k-p} .. z_{k-1}
        self.Zp, self.uk, self.yk = Zp, u[p:].T, y[p:].T
        G = Zp @ Zp.T
        Xi = linalg.lstsq(G, Zp @ self.yk.T, check_finite=False, cond=1e-12)[0].T   # block c: Xi_(p-c)
        # Gamma_f K_p: row block f0 (future step), column block c (z_{k-p+c}) = Xi_(f0+p-c), c >= f0
        LK = np.zeros((p * l, p * r))
        for f0 in range(p):
            LK[f0 * l:(f0 + 1) * l, f0 * r:] = Xi[:, :(p - f0) * r]
        self.s, V = _left_singular(LK @ G @ LK.T)                              # singular values of LK Zp
        self.W = V.T @ LK

    def model(self, n: int, feedthrough: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        X = (self.W[:n] @ self.Zp) / np.sqrt(np.maximum(self.s[:n], 1e-300))[:, None]   # S^(1/2) V^T
        m, l = self.m, self.l
        reg = np.vstack([X, self.uk]) if feedthrough else X
        CD = linalg.lstsq(reg.T, self.yk.T, check_finite=False)[0].T
        C = CD[:, :n]
        D = CD[:, n:] if feedthrough else np.zeros((l, m))
        e = self.yk - CD @ reg
        Z = np.vstack([X[:, :-1], self.uk[:, :-1], e[:, :-1]])
        AB = linalg.lstsq(Z.T, X[:, 1:].T, check_finite=False)[0].T
        return AB[:, :n], AB[:, n:n + m], C, D


def _initial_state(A, B, C, D, u, y, n_samples: int = 200) -> np.ndarray:
    """Least-squares initial state from the first samples (short: unstable modes grow)."""
    n = A.shape[0]
    L = min(n_samples, u.shape[0])
    Obs = _observability(A, C, L).reshape(-1, n)
    forced = _forced_response(A, B, C, D, u[:L])
    return linalg.lstsq(Obs, (y[:L] - forced).reshape(-1), check_finite=False)[0]


def n4sid(u: np.ndarray, y: np.ndarray, dt: float, order: int | str = "auto", horizon: int | None = None,
          max_order: int = 16, feedthrough: bool = False, input_names: list[str] | None = None,
          output_names: list[str] | None = None, method: str = "pbsid") -> StateSpaceModel:
    """Identify a discrete-time state-space model from input/output data (see module doc).

    Args:
        u: (N, m) inputs; y: (N, l) outputs, no missing values (resample multi-rate logs first).
        dt: sample time (s) of the returned model.
        order: model order, or ``"auto"`` (smallest order within 1 % fit of the best on the
            last 25 % of the data).
        horizon: PBSID's past window ``p`` / the oblique method's block rows ``i``
            (default: enough to span 0.2 s / 0.15 s, at least ``max_order // l + 2`` and 5,
            at most 30 / 20, fewer if the data are short). At 1 kHz that span is cut by
            the cap: decimate to ~100 Hz first (block means), where a 0.2 s past covers the
            predictor's memory (see ``experiments/bench_n4sid.py``).
        feedthrough: estimate ``D`` (default ``D = 0``: rotor speeds do not move the
            position instantly).
        method: ``"pbsid"`` (default: predictor-based, consistent on closed-loop data; the
            horizon is its past window ``p``) or ``"oblique"`` (the classical N4SID oblique
            projection, biased in closed loop; kept for comparison).

    Example::

        from greybox import n4sid
        ss = n4sid(u, y, dt=0.01)           # u: (N, 4) rotor speeds, y: (N, 6) x..psi, 100 Hz
        ss.order, ss.predict_windows(u, y, horizon=100, init=20)   # 1-s-ahead fit % per output
    """
    if method not in ("pbsid", "oblique"):
        raise GreyboxInputError(f"n4sid: method must be 'pbsid' or 'oblique', got {method!r}")
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    if u.ndim != 2 or y.ndim != 2 or u.shape[0] != y.shape[0]:
        raise GreyboxInputError(f"n4sid needs u (N, m) and y (N, l) with the same N, got {u.shape} and {y.shape}")
    if not (np.isfinite(u).all() and np.isfinite(y).all()):
        raise GreyboxInputError("n4sid: data contain NaN or inf; resample or fill multi-rate logs first")
    N, m = u.shape
    l = y.shape[1]
    if isinstance(order, int):
        max_order = order
    # samples needed: Hankel columns per parameter row (the oblique projection has 2i block
    # rows and wants 20 columns a row, PBSID p block rows and 10)
    def need(i: int) -> int:
        return 20 * i * (m + l) + 2 * i - 1 if method == "oblique" else 10 * i * (m + l) + i

    span = 0.15 if method == "oblique" else 0.2
    i = horizon or min(max(max_order // l + 2, int(round(span / dt)), 5), 20 if method == "oblique" else 30)
    if horizon is None:
        while i > max_order // l + 2 and N < need(i):
            i -= 1
    if i * l <= max_order:
        raise GreyboxInputError(f"n4sid: horizon {i} x {l} outputs must exceed the order {max_order}")
    if N < need(i):
        raise GreyboxInputError(f"n4sid: {N} samples are too few for horizon {i} (need {need(i)})")
    u0, y0 = u.mean(axis=0), y.mean(axis=0)
    # in the data's own units: the SVD's weighting of the outputs follows their variation
    # (positions over attitude), which predicted better than unit-RMS scaling (tried)
    du, dy = u - u0, y - y0

    W = max(int(round(1.0 / dt)), 2)

    def identify(uu: np.ndarray, yy: np.ndarray):
        """The order-independent part, and a function giving the model of each order."""
        if method == "pbsid":
            pred = _Predictor(uu, yy, i)
            return pred.s, lambda n: pred.model(n, feedthrough)
        sub = _Subspace(uu, yy, i)
        return sub.s, lambda n: _model_of_order(sub, n, feedthrough, uu, yy, W)

    scores: dict[int, float] = {}
    if order == "auto":
        k = int(0.75 * N)
        _, of_order = identify(du[:k], dy[:k])
        L = max(int(round(0.5 / dt)), n_init_min(max_order, l))
        for n in range(1, max_order + 1):
            A, B, C, D = of_order(n)
            trial = StateSpaceModel(A, B, C, D, dt, np.zeros(n), u0, y0)
            try:
                fp = trial.predict_windows(u[k - L:], y[k - L:], W, L)
            except GreyboxInputError:
                raise GreyboxInputError("n4sid: order 'auto' needs at least 1.5 s of data after the first "
                                        "75 %; give a fixed order") from None
            scores[n] = float(np.mean(np.clip(fp, -100, 100))) if np.all(np.isfinite(fp)) else -100.0
        best = max(scores.values())
        order = min(n for n, v in scores.items() if v >= best - 1.0)
    elif not isinstance(order, int) or order < 1:
        raise GreyboxInputError(f"n4sid: order must be a positive integer or 'auto', got {order!r}")
    sv, of_order = identify(du, dy)
    A, B, C, D = of_order(order)
    x0 = _initial_state(A, B, C, D, du, dy)
    return StateSpaceModel(A, B, C, D, dt, x0, u0, y0, list(input_names or []), list(output_names or []),
                           sv, scores)


def n_init_min(n: int, l: int) -> int:
    """Samples needed to observe an order-n state from l outputs (with margin)."""
    return 2 * (n // max(l, 1) + 2)


def order_plot(model: StateSpaceModel, path: str | Path) -> Path:
    """Singular values of the oblique projection (log scale) with the chosen order, and the
    validation fit of each order when it was chosen automatically, written to ``path``
    (:func:`greybox.plotting.n4sid_order` gives the ``Figure``)."""
    from .plotting import n4sid_order
    path = Path(path)
    n4sid_order(model, path=path)
    return path

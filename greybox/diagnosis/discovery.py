"""Discovery of effects outside the catalogue (step 5 of :func:`~greybox.diagnosis.diagnose`;
README, "Discovering effects outside the catalogue").

After the ranking, the *residual generalised forces* the fitted model (the baseline, as the
candidates are judged against it) leaves on the estimation flights — the body-frame force
per unit mass (``fx, fy, fz``, m/s²) and angular acceleration (``mx, my, mz``, rad/s²) it
lacks — are estimated and explained by a sparse combination of named physical features
(:mod:`greybox.effects.discovered`).

**The residual forces, without differentiating noise.** A missing force changes the
translational equation ``dv/dt = a_model(x, u) + R f_b`` and the rate equation
``domega/dt = alpha_model(x, u) + m_b``. Each is multiplied by a smooth bump ``phi``
(``(1 - s^2)^4`` over a window of half-width ``H``, centres every ``H/2``) and integrated by
parts (the weak form, as in weak SINDy)::

    integral(phi'' * position) - integral(phi * a_model)     = integral(phi * R f_b)
   -integral(phi' * omega)     - integral(phi * alpha_model) = integral(phi * m_b)

so the measured positions and gyro rates enter undifferentiated, and the model terms are
evaluated at the smoothed measured states (:func:`greybox.shooting.initial_node_states`;
effect states such as effective rotor speeds from the fitted trajectory). Every quantity is
divided by ``integral(phi)``: a window's value is a weighted mean acceleration.

**The regression.** Per group (forces; moments), the windows' residuals are regressed on
nuisance columns — the sensitivities of the model's accelerations to its free parameters
(the fit may shift them once the new term is in) and a constant per channel — and on the
candidate columns: every feature (and product of two) in every channel of the group, for a
force rotated by ``R`` as in the equation above. Forward selection adds the column that
reduces the residual sum of squares most (among those within 2 % of the best, the one with
fewer factors); a term is kept only when

* its coefficient is significant at :data:`~greybox.diagnosis.ALPHA` by a Wald test with a
  heteroscedasticity-and-autocorrelation-consistent variance (Newey-West, Bartlett weights
  over the overlapping windows and beyond: the residual of a wrong model is coloured),
  Bonferroni-corrected over every candidate column; and
* its contribution (RMS over the windows) reaches :data:`MIN_CONTRIBUTION` of the RMS
  generalised acceleration measured in that group: physically non-negligible.

**Refit and confirmation.** The terms selected in one channel become a
:class:`~greybox.effects.DiscoveredEffect` (``discovered_fz``...) added to the model and
refitted by the ordinary fitter, from the model's optimum with its weights (the new
coefficients at the regression's values), like a catalogue candidate: its likelihood ratio (autocorrelation-corrected, Bonferroni over the
same columns) and the validation nrmse decide ``significant`` by the candidates' rules.

Where the model's fit is not certified, the residual forces are not those of an optimum and
discovery says "cannot tell" instead of guessing.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import Callable, Sequence

import casadi as ca
import numpy as np
from scipy import sparse, stats

from ..controller_law import SETPOINTS
from ..data import RECORD_EXTRAS, FlightLog, is_command_column
from ..effects.base import EffectLibrary
from ..effects.discovered import (BASE_FEATURES, FORCE_CHANNELS, MOMENT_CHANNELS, discovered_effect_class,
                                  parameter_name, split_feature)
from ..errors import ConvergenceWarning, GreyboxInputError
from ..fitting import FitResult, fit
from ..model import OUTPUTS, QuadrotorModel, rotation_matrices
from ..residuals import fitted_trajectory
from ..shooting import initial_node_states
from ..validation import Prediction, predict_after_fit
from .analysis import estimation_residuals
from .ranking import (ALPHA, MIN_VALIDATION_GAIN, confirmed_on_validation, parameter_shifts, timing_stand_in,
                      validation_falls)
from .results import CandidateResult, Discovered, DiscoveredTerm
from .screening import lr_test

__all__ = ["discover", "refit_with", "residual_forces", "ResidualForces", "select_terms", "weak_form_weights",
           "hac_covariance", "signal_features", "MIN_CONTRIBUTION", "WINDOW_HALF_WIDTH", "MAX_TERMS",
           "MAX_TERMS_PER_CHANNEL", "MAX_REFITS", "MAX_THRUST_SHIFT", "NOT_SIGNALS"]

WINDOW_HALF_WIDTH = {"force": 0.25, "moment": 0.1}
"""Half-width ``H`` (s) of the weak-form windows. Forces come from twice-integrated-by-parts
positions, whose noise grows as ``H^-2.5``: a wider window; moments from the gyro rates."""
MIN_CONTRIBUTION = 0.02
"""A discovered term must contribute at least this fraction of the RMS generalised
acceleration measured in its group (forces or moments): physically non-negligible."""
MAX_TERMS = 6
"""Terms selected per group (forces, moments) at most."""
MAX_TERMS_PER_CHANNEL = 3
MAX_REFITS = 3
"""Discovered channels refitted (the largest contributions first); the others are reported
from the regression alone, not significant."""
PARSIMONY = 0.02
"""Among candidate columns that reduce the residual within this fraction of the best one,
the one with fewer factors is taken (``p`` before ``wsum*p``)."""
MAX_THRUST_SHIFT = 0.25
"""A discovered force whose refit moves ``K_T`` by more than this fraction has taken over
part of the rotors' thrust: a force at the centre of gravity carries no moment, so the
control moments (``K_T`` times the rotor-speed pattern) shrink or grow with it — a moment
gain in disguise, not a missing force. On a real Crazyflie flight (B6_linear_ramp)
``fz ∝ w2sum*vbat`` took the weight off the rotors and its refit cut the validation nrmse
57.6 -> 1.2 by shrinking the roll moment, which the catalogue's own moment gain (0.02) had
been refused for. The rule applies to a joint refit of several combinations as well."""
NOT_SIGNALS = frozenset({"ax", "ay", "az", "t", *SETPOINTS})
"""Extra log columns never offered as features: the accelerometer measures the very forces
discovery estimates (a feature made of the answer), ``t`` is a feature already; nor are
commands kept beside the inputs (``u1..u4``, ``w1..wN``, the importers' raw ``pwm1..``:
:func:`~greybox.data.is_command_column`): a commanded torque "explains" any torque the
controller had to produce; nor the controller's setpoints (``x_ref .. psi_ref``), which act on
the vehicle only through those commands; nor the importers' bookkeeping
(:data:`~greybox.data.RECORD_EXTRAS`: a blind audit's discovery offered ``t*pwm3`` and
``t_unix``)."""


# ------------------------------------------------------------------------ residual forces
@dataclass
class ResidualForces:
    """Weak-form residual generalised forces of one group (``"force"``: ``fx, fy, fz``;
    ``"moment"``: ``mx, my, mz``) on the estimation flights, ready for the regression.

    Rows are (window, component) pairs, window-major: a force window has the three world
    components, a moment window the three body components. ``window`` and ``flight`` give
    each row's window number and flight (for the autocorrelation-consistent variance)."""

    group: str
    y: np.ndarray                       # (rows,) residual, channel units
    nuisance: np.ndarray                # (rows, m): parameter sensitivities, constants
    candidates: np.ndarray              # (rows, 3 * K): channel-major, then feature
    names: list[tuple[str, str]]        # (channel, feature) of each candidate column
    window: np.ndarray                  # (rows,) window number (over all flights)
    flight: np.ndarray                  # (rows,) flight number
    measured_rms: float                 # RMS of the measured generalised acceleration (about its mean)
    step_windows: int                   # windows per window width (their overlap)


def signal_features(logs: Sequence[FlightLog]) -> list[str]:
    """Logged extra columns offered as features: numeric, measured at every sample of every
    flight, not constant, and not the accelerometer (:data:`NOT_SIGNALS`) nor an output."""
    names = []
    for name in logs[0].extras:
        if (name in NOT_SIGNALS or name in RECORD_EXTRAS or name in OUTPUTS or name in BASE_FEATURES
                or not name.isidentifier() or is_command_column(name)):
            continue
        values = [lg.extras.get(name) for lg in logs]
        if all(v is not None and np.shape(v) == lg.t.shape and np.all(np.isfinite(np.asarray(v, dtype=float)))
               and np.ptp(np.asarray(v, dtype=float)) > 0 for v, lg in zip(values, logs)):
            names.append(name)
    return names


def _feature_names(base: Sequence[str]) -> list[str]:
    out = list(base)
    for i, a in enumerate(base):
        for b in base[i:]:
            out.append(f"{a}*{b}")
    return out


def weak_form_weights(t: np.ndarray, H: float) -> tuple[sparse.csr_matrix, sparse.csr_matrix, sparse.csr_matrix]:
    """Weak-form weights over ``t`` (rows: windows, centres every H/2), divided by
    ``integral(phi)``: ``phi`` over the sample *intervals* (a model term is evaluated once
    per interval, at its midpoint with the input held over it: the model's zero-order hold;
    evaluated at the samples instead, it would lead the data by half a sample, which the
    closed loop turns into a spurious rate damping), and ``phi'``, ``phi''`` over the
    samples (for the measured rates and positions)."""
    centres = np.arange(t[0] + H, t[-1] - H + 1e-9, H / 2)
    dt = np.gradient(t)
    h = np.diff(t)
    tm = t[:-1] + h / 2
    mats: list[list[np.ndarray]] = [[], [], [], [], [], []]   # rows, cols of phi; rows, cols, phi', phi''
    vals: list[np.ndarray] = []
    for i, c in enumerate(centres):
        lo, hi = np.searchsorted(tm, c - H), np.searchsorted(tm, c + H, side="right")
        s = np.clip(1 - ((tm[lo:hi] - c) / H) ** 2, 0.0, None)
        w0 = s ** 4 * h[lo:hi]
        norm = float(w0.sum())
        lo1, hi1 = np.searchsorted(t, c - H), np.searchsorted(t, c + H, side="right")
        tau = (t[lo1:hi1] - c) / H
        s1 = np.clip(1 - tau ** 2, 0.0, None)
        d1 = -8 * tau * s1 ** 3 / H * dt[lo1:hi1]
        d2 = (-8 * s1 ** 3 + 48 * tau ** 2 * s1 ** 2) / H ** 2 * dt[lo1:hi1]
        # the quadrature of phi'' leaves a sum of ~1e-4 of its scale, which turns a position
        # 10 m from the origin into a 0.1 m/s^2 acceleration: correct the weights (within
        # phi's support) so that they annihilate constants and straight lines exactly, as
        # the integrals do; likewise phi' and constants
        g = np.column_stack([s1 ** 4, s1 ** 4 * tau]) * dt[lo1:hi1, None]
        moments = np.column_stack([np.ones_like(tau), tau])
        d2 = d2 - g @ np.linalg.solve(moments.T @ g, moments.T @ d2)
        d1 = d1 - g[:, 0] * d1.sum() / g[:, 0].sum()
        mats[0].append(np.full(hi - lo, i))
        mats[1].append(np.arange(lo, hi))
        vals.append(w0 / norm)
        mats[2].append(np.full(hi1 - lo1, i))
        mats[3].append(np.arange(lo1, hi1))
        mats[4].append(d1 / norm)
        mats[5].append(d2 / norm)
    nw = len(centres)
    cat = np.concatenate
    P0 = sparse.csr_matrix((cat(vals), (cat(mats[0]), cat(mats[1]))), shape=(nw, t.size - 1))
    P1 = sparse.csr_matrix((cat(mats[4]), (cat(mats[2]), cat(mats[3]))), shape=(nw, t.size))
    P2 = sparse.csr_matrix((cat(mats[5]), (cat(mats[2]), cat(mats[3]))), shape=(nw, t.size))
    return P0, P1, P2


def _fill(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    k = np.isfinite(y)
    return np.interp(t, t[k], y[k]) if k.sum() >= 2 else np.full_like(t, np.nan)


def _probe_function(model: QuadrotorModel, res: FitResult, signals: Sequence[str]
                    ) -> tuple[QuadrotorModel, ca.Function, np.ndarray]:
    """The model with a zero-valued probe effect whose coefficient sensitivities are the base
    features (so they are evaluated on the model's own context), and a function of
    ``(x, u, p, t)`` returning the generalised accelerations ``[dv/dt; domega/dt]`` (6), their
    sensitivities to the free parameters (6 x m) and the base features."""
    probe_cls = discovered_effect_class("mx", list(BASE_FEATURES) + list(signals), name="discovery_probe")
    ext = model + probe_cls()
    base = res.model.parameter_dict(res.p)
    p_ext = ext.default_parameters()
    for i, n in enumerate(ext.param_names):
        p_ext[i] = base.get(n, 0.0)
    free = [ext.param_names.index(n) for n in res.free_names]
    probe_params = {c for par in ext.parameters if par.effect == probe_cls.name for c in par.component_names}
    probe = [i for i, n in enumerate(ext.param_names) if n in probe_params]
    x = ca.SX.sym("x", ext.nx)
    u = ca.SX.sym("u", ext.nu)
    p = ca.SX.sym("p", ext.n_params)
    t = ca.SX.sym("t")
    acc = ext.rhs(x, u, p, t)[6:12]
    f = ca.Function("discovery_terms", [x, u, p, t],
                    [acc, ca.jacobian(acc, p[free]) if free else ca.SX(6, 0), ca.jacobian(acc[3], p[probe])])
    return ext, f, p_ext


def residual_forces(model: QuadrotorModel, res: FitResult, logs: Sequence[FlightLog]
                    ) -> tuple[ResidualForces, ResidualForces, list[str]]:
    """The weak-form residual generalised forces (module docstring) of the fitted model
    ``res`` on its estimation flights ``logs``: the force group, the moment group, and the
    feature names of the candidate columns."""
    signals = signal_features(logs)
    ext, f, p_ext = _probe_function(model, res, signals)
    base_names = list(BASE_FEATURES) + signals
    names = _feature_names(base_names)
    K = len(names)
    parts: dict[str, list] = {"force": [], "moment": []}
    n_windows = {"force": 0, "moment": 0}
    for i, log in enumerate(logs):
        lg = ext.prepare_log(log)
        n, t = len(lg), lg.t
        X = initial_node_states(ext, lg, np.arange(n), p_ext)
        if model.nx > 12:
            # effect states (effective rotor speeds...) as the fit has them, not the guesses
            Xf, _ = fitted_trajectory(res.model, res, log, i)
            extra = Xf[:, 12:]
            ok = np.all(np.isfinite(extra), axis=1)
            X[ok, 12:model.nx] = extra[ok]
        # the model's terms at the interval midpoints, with the input held over the interval
        Xm = 0.5 * (X[:-1] + X[1:])
        tm = 0.5 * (t[:-1] + t[1:])
        nm = n - 1
        out = f.map(nm)(Xm.T, lg.inputs[:-1].T, p_ext, tm[None, :])
        acc = np.asarray(out[0]).T                                      # (nm, 6)
        m = len(res.free_names)
        sens = np.asarray(out[1]).reshape(6, nm, m).transpose(1, 0, 2)  # (nm, 6, m)
        base = np.asarray(out[2]).reshape(1, nm, len(base_names))[0]   # (nm, Kb)
        F = np.column_stack([base] + [base[:, a] * base[:, b] for a in range(len(base_names))
                                      for b in range(a, len(base_names))])   # (nm, K)
        R = rotation_matrices(Xm[:, 3], Xm[:, 4], Xm[:, 5])             # (nm, 3, 3) body -> world
        pos = np.column_stack([_fill(t, log.output(c)) for c in ("x", "y", "z")])
        if all(c in log.output_names for c in ("p", "q", "r")) and np.isfinite(log.output("p")).sum() > 5:
            omega = np.column_stack([_fill(t, log.output(c)) for c in ("p", "q", "r")])
        else:
            omega = X[:, 9:12]
        for group in ("force", "moment"):
            P0, P1, P2 = weak_form_weights(t, WINDOW_HALF_WIDTH[group])
            nw = P0.shape[0]
            if nw < 10 or not np.all(np.isfinite(pos if group == "force" else omega)):
                continue
            if group == "force":
                measured = P2 @ pos                                     # weighted mean dv/dt
                y = measured - P0 @ acc[:, :3]
                nuis = (P0 @ sens[:, :3, :].reshape(nm, 3 * m)).reshape(nw, 3, m)
                const = (P0 @ R.reshape(nm, 9)).reshape(nw, 3, 3)        # R e_c: body constants
                # integral(phi R[i, c] f_k): a body force in channel c seen in world component i
                # (the sample weights folded into the sparse window matrix: no (n, 3, 3, K) array)
                cand = np.empty((nw, 3, 3, K))
                for a in range(3):
                    for c in range(3):
                        cand[:, a, c, :] = (P0 @ sparse.diags(R[:, a, c])) @ F
            else:
                measured = -(P1 @ omega)                                 # weighted mean domega/dt
                y = measured - P0 @ acc[:, 3:]
                nuis = (P0 @ sens[:, 3:, :].reshape(nm, 3 * m)).reshape(nw, 3, m)
                const = np.broadcast_to(np.eye(3), (nw, 3, 3))
                PF = P0 @ F                                             # (nw, K)
                cand = np.zeros((nw, 3, 3, K))
                for c in range(3):
                    cand[:, c, c, :] = PF
            parts[group].append(dict(y=y, nuis=np.concatenate([nuis, const], axis=2), cand=cand,
                                     measured=measured, window=n_windows[group] + np.arange(nw), flight=i))
            n_windows[group] += nw
    out = []
    for group in ("force", "moment"):
        ps = parts[group]
        channels = FORCE_CHANNELS if group == "force" else MOMENT_CHANNELS
        if not ps:
            out.append(None)
            continue
        y = np.concatenate([p["y"] for p in ps]).reshape(-1)
        nuis = np.concatenate([p["nuis"] for p in ps]).reshape(y.size, -1)
        cand = np.concatenate([p["cand"] for p in ps])                   # (nw, 3 comps, 3 channels, K)
        cand = cand.reshape(y.size, 3 * K)
        window = np.repeat(np.concatenate([p["window"] for p in ps]), 3)
        flight = np.repeat(np.concatenate([np.full(len(p["window"]), p["flight"]) for p in ps]), 3)
        meas = np.concatenate([p["measured"] for p in ps])
        measured_rms = float(np.sqrt(np.mean((meas - meas.mean(axis=0)) ** 2)))
        out.append(ResidualForces(group, y, nuis, cand, [(c, nm) for c in channels for nm in names], window,
                                  flight, measured_rms, 4))
    return out[0], out[1], names


# ------------------------------------------------------------------------------ regression
def hac_covariance(X: np.ndarray, e: np.ndarray, window: np.ndarray, flight: np.ndarray, lags: int) -> np.ndarray:
    """Newey-West covariance of OLS coefficients: ``(X'X)^-1 S (X'X)^-1`` with ``S`` the
    Bartlett-weighted long-run covariance of the per-window scores ``sum x_r e_r`` (lags
    within a flight only)."""
    scores = np.zeros((int(window.max()) + 1, X.shape[1]))
    np.add.at(scores, window, X * e[:, None])
    wf = np.full(scores.shape[0], -1)
    wf[window] = flight
    used = wf >= 0
    scores, wf = scores[used], wf[used]
    S = scores.T @ scores
    for lag in range(1, lags + 1):
        same = wf[lag:] == wf[:-lag]
        G = scores[lag:][same].T @ scores[:-lag][same]
        S += (1 - lag / (lags + 1)) * (G + G.T)
    XtX_inv = np.linalg.pinv(X.T @ X)
    return XtX_inv @ S @ XtX_inv


def select_terms(rf: ResidualForces, alpha: float = ALPHA, min_contribution: float = MIN_CONTRIBUTION
                 ) -> tuple[list[int], np.ndarray, np.ndarray, list[float], list[float]]:
    """Forward selection on one group (module docstring). Returns the selected candidate
    columns, their coefficients and standard deviations (HAC), each one's Bonferroni
    p-value when it entered, and each one's contribution (RMS over the windows)."""
    y, N, C = rf.y, rf.nuisance, rf.candidates
    n_win = len(np.unique(rf.window))
    col_rms = np.sqrt(np.sum(C ** 2, axis=0) / n_win)      # a unit coefficient's contribution
    usable = col_rms > 0
    Cs = np.where(usable, C / np.where(usable, col_rms, 1.0), 0.0)
    n_factors = np.array([len(split_feature(f)) for _, f in rf.names])
    channel_of = [c for c, _ in rf.names]
    pool = int(usable.sum())
    lags = 3 * rf.step_windows
    floor = min_contribution * rf.measured_rms
    selected: list[int] = []
    p_entered: list[float] = []
    Nn = N / np.maximum(np.sqrt(np.sum(N ** 2, axis=0)), 1e-300)
    beta, cov = np.zeros(0), np.zeros((0, 0))
    for _ in range(MAX_TERMS):
        D = np.column_stack([Nn] + [Cs[:, j] for j in selected])
        Q, r = np.linalg.qr(D)
        Q = Q[:, np.abs(np.diag(r)) > 1e-10 * np.abs(np.diag(r)).max()]
        e = y - Q @ (Q.T @ y)
        Ct = Cs - Q @ (Q.T @ Cs)
        nn = np.sum(Ct ** 2, axis=0)
        red = np.where(usable & (nn > 1e-8 * np.maximum(np.sum(Cs ** 2, axis=0), 1e-300)),
                       (Ct.T @ e) ** 2 / np.maximum(nn, 1e-300), 0.0)
        for j in selected:
            red[j] = 0.0
        full = {c for c in set(channel_of) if sum(channel_of[j] == c for j in selected) >= MAX_TERMS_PER_CHANNEL}
        red[[j for j, c in enumerate(channel_of) if c in full]] = 0.0
        if not np.any(red > 0):
            break
        near = np.flatnonzero(red >= (1 - PARSIMONY) * red.max())
        best = int(min(near, key=lambda j: (n_factors[j], -red[j])))
        # scaled columns (sensitivities to K_T are ~1e6, to a drag ~1): the coefficients of
        # Cs are contributions, those of C follow by dividing by the column RMS
        Dn = np.column_stack([Nn] + [Cs[:, j] for j in selected + [best]])
        b, *_ = np.linalg.lstsq(Dn, y, rcond=None)
        V = hac_covariance(Dn, y - Dn @ b, rf.window, rf.flight, lags)
        z2 = b[-1] ** 2 / max(V[-1, -1], 1e-300)
        p = min(1.0, float(stats.chi2.sf(z2, 1)) * pool)
        if p >= alpha or abs(b[-1]) < floor:
            break
        selected.append(best)
        p_entered.append(p)
        beta, cov = b, V
    if not selected:
        return [], np.zeros(0), np.zeros(0), [], []
    k = len(selected)
    rms = col_rms[selected]
    coef = beta[-k:] / rms
    std = np.sqrt(np.maximum(np.diag(cov)[-k:], 0.0)) / rms
    contributions = [float(abs(c)) for c in beta[-k:]]
    return selected, coef, std, p_entered, contributions


# ------------------------------------------------------------------------------ discover
def discover(model: QuadrotorModel, res: FitResult, pred: Prediction, est: Sequence[FlightLog],
             val: Sequence[FlightLog], compile: str = "auto", say: Callable[[str], None] = lambda _m: None,
             timing: CandidateResult | None = None) -> tuple[list[Discovered], dict]:
    """Discovery on the fitted model ``res`` (validation prediction ``pred``). Returns the
    discovered combinations best first and what was found, in short: ``{"status": "found" |
    "nothing" | "cannot tell", "text": words, "together": the refit with every significant
    combination added, or None}``.

    ``timing``: the log's timing (its certified refit onto ``res``) when it was significant in
    the fit and refused on validation alone; a combination confirmed alone must then stand
    beside it too (:func:`_beside_timing`), as a catalogue verdict must."""
    if not res.converged:
        return [], {"status": "cannot tell", "together": None,
                    "text": "cannot tell: the model's fit is not at a certified optimum, so what it leaves is "
                            "not a residual force of the model"}
    t0 = time.perf_counter()
    force, moment, names = residual_forces(model, res, est)
    found: list[Discovered] = []
    pools = 0
    for rf in (force, moment):
        if rf is None:
            continue
        pools = max(pools, int(np.sum(np.any(rf.candidates != 0, axis=0))))
        cols, coef, std, p_in, contrib = select_terms(rf)
        by_channel: dict[str, list[int]] = {}
        for k, j in enumerate(cols):
            by_channel.setdefault(rf.names[j][0], []).append(k)
        for ch, ks in by_channel.items():
            terms = [DiscoveredTerm(rf.names[cols[k]][1], float(coef[k]), float(std[k])) for k in ks]
            contribution = float(np.sqrt(sum(contrib[k] ** 2 for k in ks)))
            found.append(Discovered(ch, terms, max(p_in[k] for k in ks), contribution, pred.total,
                                    share=contribution / rf.measured_rms if rf.measured_rms > 0 else 0.0))
    say(f"diagnose: discovery regression ({time.perf_counter() - t0:.1f} s): " +
        (", ".join(d.text() for d in found) if found else "nothing significant"))
    if not found:
        return [], {"status": "nothing", "together": None,
                    "text": "nothing: no combination of the features explains a significant, non-negligible "
                            "residual force"}
    # the largest shares of what the vehicle's motion measures in their group first: the size
    # of the missing physics, not how an average over output channels happens to weigh it
    found.sort(key=lambda d: -d.share)
    alone: dict[int, str] = {}      # id -> its best channel: confirmed there, the total worse
    for d in found[:MAX_REFITS]:
        best_ch = _refit_and_judge(d, model, res, pred, est, val, compile, pools, say)
        if best_ch is not None:
            alone[id(d)] = best_ch
    for d in found[MAX_REFITS:]:
        d.reason = f"not refitted: only the {MAX_REFITS} largest are"
    if timing is not None and timing.fit is not None and timing.prediction is not None:
        for d in found[:MAX_REFITS]:
            if d.significant:
                _beside_timing(d, timing, est, val, compile, pools, pred.horizon, say)
    together = _confirm_together([d for d in found if d.significant or id(d) in alone], alone, model, res,
                                 pred, est, val, compile, pools, say)
    found.sort(key=lambda d: (not d.significant, -d.share))
    sig = [d for d in found if d.significant]
    if not sig:
        return found, {"status": "nothing", "together": None,
                       "text": "nothing significant: what the regression found is not confirmed by a refit and "
                               "the validation data"}
    if together is None and len(sig) > 1:
        # (a confirmed joint refit is already of exactly the significant ones)
        together = _refit_together(sig, model, res, pred, est, val, compile, pools, say)
    text = f"{len(sig)} significant: " + "; ".join(d.text() for d in sig)
    if together is not None:
        text += (f"; all {len(sig)} added together: nrmse {pred.total:.3f} -> {together['nrmse_after']:.3f}")
    return found, {"status": "found", "text": text, "together": together}


def refit_with(sig: Sequence[Discovered], res: FitResult, est: Sequence[FlightLog], val: Sequence[FlightLog],
               horizon: float, compile: str = "auto") -> tuple[FitResult, Prediction, float, float]:
    """The fitted model ``res`` (any model: the baseline, or one with a catalogue effect
    added) with the refitted discovered combinations ``sig`` added, refitted from ``res``'s
    optimum; its fit, validation prediction, and the likelihood ratio of what ``sig`` adds to
    ``res`` with its p-value. :func:`discover` must have refitted ``sig`` (their ``effect`` is
    set)."""
    _, fr, pr, lr, p = _fit_with(sig, res.model, res, est, val, compile, 1, horizon)
    return fr, pr, lr, p


def _fit_with(sig: Sequence[Discovered], model: QuadrotorModel, res: FitResult, est: Sequence[FlightLog],
              val: Sequence[FlightLog], compile: str, n_tests: int, horizon: float
              ) -> tuple[QuadrotorModel, FitResult, Prediction, float, float]:
    """The model with the discovered combinations ``sig`` added, refitted by the ordinary
    fitter from the model's optimum (its node states and weights) with the new coefficients
    at their discovered values; its validation prediction and likelihood-ratio test against
    ``res`` (Bonferroni over ``n_tests``)."""
    ext = model + EffectLibrary([d.effect() for d in sig])
    start = res.model.parameter_dict(res.p)
    for d in sig:
        for t in d.fitted or d.terms:
            start[parameter_name(d.channel, t.feature)] = t.coefficient
    p0 = np.array([start.get(n, v) for n, v in zip(ext.param_names, ext.default_parameters())])
    new = [parameter_name(d.channel, t.feature) for d in sig for t in d.terms]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)    # judged by its likelihood ratio
        # a discovered effect adds no states: the model's node states start the refit as they are
        fr = fit(ext, est, free=list(res.free_names) + new, p0=p0, noise=res.sigma, reweight=False,
                 sensor_noise=res.sensor_given,
                 compile=compile, max_iter=200, initial_states=res.node_states, interval=res.interval,
                 process_noise=res.process_noise, per_flight=res.per_flight_rule)
    pr = predict_after_fit(fr, est, val, compile=compile, horizon=horizon)
    lr, p = lr_test(res, fr, estimation_residuals(ext, fr, est), len(new), False, max(n_tests, 1))
    return ext, fr, pr, lr, p


def _refit_together(sig: Sequence[Discovered], model: QuadrotorModel, res: FitResult, pred: Prediction,
                    est: Sequence[FlightLog], val: Sequence[FlightLog], compile: str, n_tests: int,
                    say: Callable[[str], None]) -> dict:
    """Every significant combination added at once and refitted (one channel's term is
    refitted while the others' missing forces still bend the model; together they are not)."""
    t0 = time.perf_counter()
    ext, fr, pr, lr, p = _fit_with(sig, model, res, est, val, compile, n_tests, pred.horizon)
    say(f"  discovered, all together: nrmse {pred.total:.3f} -> {pr.total:.3f}  ({time.perf_counter() - t0:.1f} s)")
    return {"effects": [d.effect.name for d in sig], "nrmse_before": pred.total, "nrmse_after": pr.total,
            "channels_after": dict(pr.nrmse), "lr": lr, "lr_p_value": p, "certified": bool(fr.converged),
            # the refit's relative change of K_T: the thrust-shift rule applies to a group as to one
            "K_T_change": (float(fr.value("K_T") / res.value("K_T") - 1)
                           if "K_T" in res.free_names and "K_T" in fr.free_names else None),
            "terms": {d.channel: [{"feature": t.feature, "coefficient": fr.value(parameter_name(d.channel, t.feature)),
                                   "std": float(fr.std[fr.free_names.index(parameter_name(d.channel, t.feature))])}
                                  for t in d.terms] for d in sig}}


def _refit_and_judge(d: Discovered, model: QuadrotorModel, res: FitResult, pred: Prediction,
                     est: Sequence[FlightLog], val: Sequence[FlightLog], compile: str, n_tests: int,
                     say: Callable[[str], None]) -> str | None:
    """Add ``d`` as an effect, refit with the ordinary fitter, and judge it by the
    candidates' rules: likelihood ratio and validation confirmation. Returns the channel it
    predicts better when only the total holds it back (for :func:`_confirm_together`)."""
    t0 = time.perf_counter()
    d.effect = discovered_effect_class(d.channel, [t.feature for t in d.terms],
                                       [t.coefficient for t in d.terms], [t.scale for t in d.terms])
    ext, fr, pr, d.lr, d.lr_p_value = _fit_with([d], model, res, est, val, compile, n_tests, pred.horizon)
    d.fit, d.prediction = fr, pr
    d.nrmse_after, d.channels_after = pr.total, dict(pr.nrmse)
    d.fitted = []
    for t in d.terms:
        name = parameter_name(d.channel, t.feature)
        d.fitted.append(DiscoveredTerm(t.feature, fr.value(name), float(fr.std[fr.free_names.index(name)])))
    falls, best_ch, gain = validation_falls(pred, pr)
    confirmed_alone = None
    shift = _thrust_shift(d, res, fr)
    if d.lr_p_value >= ALPHA:
        d.reason = f"the refit does not confirm it (likelihood ratio p = {d.lr_p_value:.2g})"
    elif shift is not None:
        d.reason = (f"its refit moves K_T by {100 * shift:+.0f} %: it takes over part of the rotors' thrust "
                    f"without their moments, so the control moments scale by {1 + shift:.2f} with it (a moment "
                    f"gain in disguise, not a missing force)")
    elif not confirmed_on_validation(falls, best_ch, gain):
        d.reason = (f"significant in the refit but not confirmed on validation (best channel {best_ch} "
                    f"{-100 * falls[best_ch]:+.1f} %, total {-100 * gain:+.1f} %)")
        if falls[best_ch] >= MIN_VALIDATION_GAIN:
            confirmed_alone = best_ch
        if fr.converged:
            # what the model's parameters do with it: a blind audit's thrust loss with the climb
            # rate (thrust ~ w (w - k vz)), found to 4 % and set aside on the total (z -16 %,
            # total +1 %): Kd[2] 0.246 +- 0.009 without it, the truth 0.12, nothing said
            d.shifts = {n: (res.value(n), fr.value(n), float(fr.std[fr.free_names.index(n)]))
                        for n in parameter_shifts(res, fr)}
    else:
        d.significant = True
        d.reason = (f"p = {d.p_value:.2g} (regression), {d.lr_p_value:.2g} (refit); validation {best_ch} "
                    f"{-100 * falls[best_ch]:+.0f} %, total {-100 * gain:+.0f} %")
    if not fr.converged:
        # its nrmse and LR are where the refit stopped (a diverged one's nrmse was 1.8e6 on a
        # blind audit's flight, read there as a result)
        d.reason = f"its refit was not certified ({fr.status}); " + d.reason
    say(f"  discovered {d.channel:<3} {', '.join(t.feature for t in d.terms):<24} LR {d.lr:10.1f} "
        f"nrmse {pred.total:.3f} -> {pr.total:.3f}  ({time.perf_counter() - t0:.1f} s)")
    return confirmed_alone


def _beside_timing(d: Discovered, timing: CandidateResult, est: Sequence[FlightLog], val: Sequence[FlightLog],
                   compile: str, n_tests: int, horizon: float, say: Callable[[str], None]) -> None:
    """Refuse the confirmed combination ``d`` when it does not stand with the log's timing in
    the model (``timing``: significant in the fit, refused on validation alone): significant
    against the timing's fit and confirmed on validation against its prediction, else it
    stands in for the timing (:func:`~greybox.diagnosis.ranking.stands_beside_timing` for a
    catalogue verdict). Held samples of a varying signal lag it by half a row: on a blind
    audit's H-frame with nothing missing (ESC telemetry at 200 Hz), the timing fell short on
    validation (roll -4.4 %) and a roll damping ``mx = -0.065 p`` was "found" in its place
    (roll -5 %)."""
    t0 = time.perf_counter()
    try:
        _, fr, pr, lr, p = _fit_with([d], timing.fit.model, timing.fit, est, val, compile, n_tests, horizon)
    except (GreyboxInputError, ValueError):
        return
    if not fr.converged or pr is None:
        return          # cannot tell from an uncertified refit: its own judgement stands
    why = timing_stand_in(timing, lr, p, timing.prediction, pr)
    say(f"  discovered {d.channel} beside the log's timing: {why or 'stands'} ({time.perf_counter() - t0:.1f} s)")
    if why:
        d.significant = False
        d.reason = f"{d.reason}; but {why}"


def _thrust_shift(d: Discovered, res: FitResult, fr: FitResult) -> float | None:
    """The relative change of ``K_T`` from ``res`` to the refit ``fr`` with the discovered
    force ``d`` when it exceeds :data:`MAX_THRUST_SHIFT` (else None; moments never)."""
    if d.channel not in FORCE_CHANNELS or "K_T" not in res.free_names or "K_T" not in fr.free_names:
        return None
    shift = fr.value("K_T") / res.value("K_T") - 1
    return float(shift) if abs(shift) > MAX_THRUST_SHIFT else None


def _confirm_together(group: list[Discovered], alone: dict[int, str], model: QuadrotorModel, res: FitResult,
                      pred: Prediction, est: Sequence[FlightLog], val: Sequence[FlightLog], compile: str,
                      n_tests: int, say: Callable[[str], None]) -> dict | None:
    """Combinations that predict their own channel better on validation but the total worse
    (the other channels' missing forces, no longer absorbed, now show in a coupled open-loop
    prediction) are judged together with the rest: all of ``group`` refitted at once, each is
    confirmed when the joint model predicts the total better and its own channel better
    than the baseline. The joint refit (``_refit_together``'s dict) or None."""
    if not any(id(d) in alone for d in group) or len(group) < 2:
        return None
    together = _refit_together(group, model, res, pred, est, val, compile, n_tests, say)
    shift = together["K_T_change"]
    if shift is not None and abs(shift) > MAX_THRUST_SHIFT and any(d.channel in FORCE_CHANNELS for d in group):
        for d in group:
            if id(d) in alone:
                d.reason += (f"; refitted together with the others it moves K_T by {100 * shift:+.0f} %: a force "
                             f"among them takes over part of the rotors' thrust (a moment gain in disguise)")
        return None
    gain = 1 - together["nrmse_after"] / pred.total
    own = {id(d): 1 - together["channels_after"][ch] / pred.nrmse[ch] for d in group
           if (ch := alone.get(id(d))) is not None}
    if gain < MIN_VALIDATION_GAIN or min(own.values()) < MIN_VALIDATION_GAIN:
        return None
    confirmed = False
    for d in group:
        if id(d) in alone:
            others = ", ".join(o.channel for o in group if o is not d)
            # the joint model must also beat what each of the others does alone: a term that only
            # rides on another's gain adds nothing (an audit's filtered attitude gave fx ~ t*w2pitch,
            # total +4 % alone, "confirmed" beside a weathervane moment that alone predicted better
            # than the two together, 0.129 against 0.140)
            alone_totals = [(o.nrmse_after, o) for o in group if o is not d and o.nrmse_after is not None
                            and np.isfinite(o.nrmse_after)]
            best = min(alone_totals, key=lambda a: a[0])[1] if alone_totals else None
            if best is not None and together["nrmse_after"] >= best.nrmse_after:
                d.reason += (f"; refitted together with {others} the model predicts worse than with {best.channel} "
                             f"alone (total {together['nrmse_after']:.3g} against {best.nrmse_after:.3g}): it "
                             "adds nothing")
                continue
            confirmed = True
            d.significant = True
            d.reason = (f"p = {d.p_value:.2g} (regression), {d.lr_p_value:.2g} (refit); validation "
                        f"{alone[id(d)]} {-100 * own[id(d)]:+.0f} %, total {-100 * gain:+.0f} % together with "
                        f"{others} (alone the total {-100 * (1 - d.nrmse_after / pred.total):+.0f} %)")
    return together if confirmed else None


"""Screening and refits of candidate effects (step 3 of
:func:`~greybox.diagnosis.diagnose`): the model extended by a candidate at the baseline
optimum, the score statistic of one Gauss–Newton step, the warm or cold refit with the
baseline's weights, and the statistics a refit is judged by — the autocorrelation-corrected
likelihood ratio, the share of the excess residual it explains, its physical size, and how
much it moves the validation predictions."""
from __future__ import annotations

import math
import warnings as _warnings
from typing import Sequence

import numpy as np
from scipy import stats

from .. import effects as fx
from ..data import FlightLog, median_row_interval
from ..errors import ConvergenceWarning, GreyboxInputError
from ..fitting import FitResult, FitSession, GaussNewton, fit, per_flight_positions
from ..fitting.input_errors import mixer_noise_shares
from ..fitting.robust import long_run_covariance
from ..integrate import Substeps, integrate_states_along
from ..model import BASE_STATES, OUTPUTS, QuadrotorModel
from ..residuals import long_run_factor
from ..shooting import ShootingProblem, free_indices
from ..validation import DEFAULT_HORIZON, Prediction, predict_after_fit

__all__ = ["NEGLIGIBLE_FRACTION", "SMOOTHED_LAG_WORDS", "smoothed_lag_words", "SETTLED_SHARE", "lag_timing_words", "free_input_timed", "MIN_FORCE_SHARE", "effect_accelerations", "physically_small", "negligible_effect", "extended_model", "screen", "refit", "prediction_change", "lr_test", "profile_log_likelihood",
           "explained_fraction", "screen_jointly", "JOINT_COST_TOLERANCE", "physically_negligible", "small_in_force_only", "physically_implausible", "held_on_bound", "replaced_base_terms", "REPLACED_CLEAR_STD", "null_on_bound", "precompile_refits", "queue_refit_builds",
           "HeldBeyondPlausible", "HELD_ITERATIONS", "within_row_timing", "row_timing_words", "TIMING_ALPHA", "fit_weights",
           "robust_screen", "one_step_estimate", "moment_scale_words", "MOMENT_SCALE_NOTICE"]


NEGLIGIBLE_FRACTION = 0.01
"""An effect whose fitted parameters are all below this fraction of their physically plausible
magnitude for the airframe (:func:`greybox.effects.example_values`) is negligible: never the
verdict, whatever its likelihood ratio."""

MIN_FORCE_SHARE = 0.02
"""An effect whose largest force and moment along the flight (99th percentile of the
accelerations it adds, a misread tilt counted as the horizontal force ``g * tilt`` it
stands for) stay below this fraction of the RMS acceleration the vehicle flies with, in
both groups, is physically negligible: never the verdict, whatever its likelihood ratio.
The same share as a discovered term must reach (:data:`~greybox.diagnosis.MIN_CONTRIBUTION`).
In force terms, a 2.5 m/s "wind" behind a drag coefficient of 0.0035 N s/m pushes a
1 kg vehicle with 9 mN (0.4 % of its 2.5 m/s^2); a per-rotor ground effect reaches 8 %."""


def effect_accelerations(fr: FitResult, effect: str, logs: Sequence[FlightLog]
                         ) -> tuple[float, float, float, float] | None:
    """The size of ``effect`` in the fit ``fr``, in force terms, along the fitted states of
    the flights ``logs``: (99th percentile of the translational acceleration it adds, of the
    angular acceleration it adds, RMS translational acceleration, RMS angular acceleration
    of the model), m/s^2 and rad/s^2, comparing the effect at its fitted values with the
    effect at its null values. A roll/pitch measurement offset counts as the horizontal
    acceleration ``g * offset`` a model must otherwise explain, an accelerometer offset as
    itself. None when the effect cannot be
    switched off this way (its own states, a parameter whose null is outside its bounds) or
    when, without a force, it changes other measurements (a position delay)."""
    model = fr.model
    components = model.effect_components(effect)
    comps = [(model.param_names.index(c), null) for _, c, null in components]
    own = model.effects.get(effect)
    if not comps or (own is not None and own.state_names(model.airframe)):
        return None
    if any(not par.lower <= null <= par.upper for par, _, null in components):
        return None
    da, dw, a_all, w_all = [], [], [], []
    g = model.airframe.gravity
    moved = [OUTPUTS.index(c) for c in ("x", "y", "z", "psi", "p", "q", "r")]
    for f, log in enumerate(logs):
        log = model.prepare_log(log)     # the model's inputs (a log may hold more signals)
        X, idx = fr.node_states[f], fr.node_index[f]
        idx = np.minimum(idx, len(log) - 1)
        p = fr.flight_p(f)
        p0 = p.copy()
        for j, null in comps:
            p0[j] = null
        rhs, out = model.rhs.map(len(idx)), model.output.map(len(idx))
        args = (X.T, log.inputs[idx].T)
        T = log.t[idx][None, :]
        xd1, xd0 = np.asarray(rhs(*args, p, T)), np.asarray(rhs(*args, p0, T))
        y1, y0 = np.asarray(out(*args, p, T)), np.asarray(out(*args, p0, T))
        changed = np.abs(xd1 - xd0) > 1e-12 * (1.0 + np.abs(xd1))
        force = np.any(changed)
        if force and not np.any(changed[:len(BASE_STATES)]):
            # it changes only the derivatives of the model's own states (an input timing
            # feeding a motor lag's speeds): its forces follow through those states, later,
            # and are not measured by comparing one instant (they read 0 here)
            return None
        dy = np.abs(y1 - y0)
        if not force and np.any(dy[moved] > 1e-9 * (1.0 + np.abs(y1[moved]))):
            return None
        # a force moves the measurements through the state; only a pure measurement effect
        # is judged by what it does to them
        tilt = 0.0 if force else (g * np.hypot(dy[OUTPUTS.index("phi")], dy[OUTPUTS.index("theta")])
                                  + np.linalg.norm(dy[[OUTPUTS.index(c) for c in ("ax", "ay", "az")]], axis=0))
        da.append(np.linalg.norm(xd1[6:9] - xd0[6:9], axis=0) + tilt)
        dw.append(np.linalg.norm(xd1[9:12] - xd0[9:12], axis=0))
        a_all.append(np.sum(xd1[6:9] ** 2, axis=0))
        w_all.append(np.sum(xd1[9:12] ** 2, axis=0))
    da, dw = np.concatenate(da), np.concatenate(dw)
    return (float(np.percentile(da, 99)), float(np.percentile(dw, 99)),
            float(np.sqrt(np.mean(np.concatenate(a_all)))), float(np.sqrt(np.mean(np.concatenate(w_all)))))


def physically_small(fr: FitResult, effect: str, logs: Sequence[FlightLog]) -> str:
    """Words saying that ``effect`` is physically negligible in force terms in the fit ``fr``
    (:data:`MIN_FORCE_SHARE`, :func:`effect_accelerations`), or ""."""
    size = effect_accelerations(fr, effect, logs)
    if size is None:
        return ""
    da, dw, a, w = size
    share_a = da / a if a > 0 else 0.0
    share_w = dw / w if w > 0 else 0.0
    if max(share_a, share_w) >= MIN_FORCE_SHARE:
        return ""
    return (f"its largest force adds {da:.2g} m/s^2 ({100 * share_a:.1f} % of the {a:.2g} m/s^2 RMS the vehicle "
            f"flies with) and its largest moment {dw:.2g} rad/s^2 ({100 * share_w:.1f} % of {w:.2g} rad/s^2), below "
            f"{100 * MIN_FORCE_SHARE:.0f} %")


def extended_model(model: QuadrotorModel, res: FitResult, name: str
                   ) -> tuple[QuadrotorModel, np.ndarray, list[str]]:
    """The model plus effect ``name``, its parameter vector (baseline values, new parameters at
    their null value or lower bound) and the free set (baseline's plus the new parameters)."""
    return _extended_by(model, res, [name])


def _extended_by(model: QuadrotorModel, res: FitResult, names: Sequence[str]
                 ) -> tuple[QuadrotorModel, np.ndarray, list[str]]:
    """:func:`extended_model` with the effects ``names`` added at once."""
    ext = model + [fx.by_name(name) for name in names]
    base = res.model.parameter_dict(res.p)
    p = ext.default_parameters()
    param_names = ext.param_names
    new: list[str] = []
    for par in ext.parameters:
        for comp in par.component_names:
            i = param_names.index(comp)
            if comp in base:
                p[i] = base[comp]
            else:
                p[i] = min(max(par.null, par.lower), par.upper)
                new.append(comp)
    return ext, p, list(res.free_names) + new


def _extend_nodes(ext: QuadrotorModel, res: FitResult, logs: Sequence[FlightLog], p: np.ndarray) -> list[np.ndarray]:
    out = []
    for nodes, idx, log in zip(res.node_states, res.node_index, [ext.prepare_log(lg) for lg in logs]):
        full = np.zeros((nodes.shape[0], ext.nx))
        for r, k in enumerate(idx):
            full[r] = ext.initial_state(nodes[r, :12], log.inputs[k], p)
        # keep effect states the smaller model already had (same order: catalogue order)
        old = [s for s in res.model.state_names]
        for j, s in enumerate(ext.state_names):
            if s in old:
                full[:, j] = nodes[:, old.index(s)]
        new = [j for j, s in enumerate(ext.state_names) if s not in old]
        if new and res.process_noise is not None and full.shape[0] > 1:
            # with process noise every node is a residual: start the candidate's own states
            # (e.g. effective motor speeds) on their own dynamics along the baseline's nodes,
            # so that the extension starts at the baseline optimum (zero gaps in them) and
            # the score statistic is taken where it means something
            full[:, new] = _propagate_new_states(ext, new, full, log, idx, p)
        out.append(full)
    return out


def _propagate_new_states(ext: QuadrotorModel, new: list[int], full: np.ndarray, log: FlightLog,
                          idx: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The states ``new`` at the nodes ``idx``, integrated sample by sample with each sample's
    input, as the shooting intervals do, by the extended model; the other states held at
    their node's value ``full`` over its interval. Held at the node's input over a whole
    interval instead, a 2-ms motor lag's speeds missed the logged ones at the next node by
    the input's change over the interval, gaps a tight process noise turned into a screening
    statistic of 1e9."""
    k = np.asarray(idx)
    j = np.arange(k[0], k[-1])
    node_of_sample = np.searchsorted(k, j, side="right") - 1
    seq = integrate_states_along(ext, log.t[k[0]:k[-1] + 1], log.inputs[k[0]:k[-1] + 1], new, full[0, new],
                                 full[node_of_sample], p)
    return seq[k - k[0]]


def _one_off(compile: str) -> str:
    """The compile mode for a job of a few evaluations (a screening) in a diagnosis run with
    ``compile``: a cached library, else the virtual machine, and no build started for it
    (``"auto"`` would start one once the virtual machine had cost half the expected build;
    the model of a round's candidates together, new each round, took the compiler 25 s on a
    real flight and was never evaluated again)."""
    return "cached" if compile == "auto" else compile


def fit_weights(res: FitResult) -> np.ndarray:
    """The noise levels the fit ``res`` weighed its channels with, in :data:`OUTPUTS` order (1
    for a channel it did not have): the ``sigma`` its screens take."""
    return np.array([res.sigma.get(ch, 1.0) for ch in OUTPUTS])


def screen(model: QuadrotorModel, res: FitResult, logs: Sequence[FlightLog], name: str, sigma: np.ndarray,
           compile: str) -> tuple[float, int]:
    """Score statistic and degrees of freedom of candidate ``name`` at the baseline optimum
    (for an effect that cannot vanish, an approximate likelihood ratio: below)."""
    ext, p, ses, X, th, df = _screen_session(model, res, logs, name, sigma, compile)
    logs = ses.logs
    off = _plausible_start(ext, res, name, p)
    if off is None:
        return 2.0 * max(ses.predicted_decrease(X, th), 0.0), df
    # The effect cannot vanish: its null lies beyond a numerical bound (a motor lag of 0 s),
    # and at that floor the extended model is not the baseline (a 2-ms lag at a 100-Hz log
    # costs 7x the baseline's cost there). Its statistic is the decrease from the baseline's
    # cost to the Gauss-Newton optimum predicted from the floor or, better where the floor's
    # linearisation is poor, from a plausible value: an approximate likelihood ratio (B10's
    # 70-ms lag: 1.1e6 where its refit's is 4.2e6, a lower bound; the floor's own step said 2.8e5).
    Xo = np.vstack(_extend_nodes(ext, res, logs, off))
    tho = ses.theta(flight_vectors(ext, off, res, len(logs)))
    reached = min(ses.predicted_optimum(X, th), ses.predicted_optimum(Xo, tho))
    return 2.0 * max(res.cost - reached, 0.0), df


def _screen_session(model: QuadrotorModel, res: FitResult, logs: Sequence[FlightLog], name: str,
                    sigma: np.ndarray, compile: str):
    """The model extended by ``name`` at the baseline ``res``: ``(ext, p, ses, X, th, df)``, its
    parameter vector, a fit session on ``logs`` with the baseline's weights and process noise,
    the baseline's nodes and parameters in it, and the degrees of freedom the candidate adds."""
    ext, p, free = extended_model(model, res, name)
    free_idx = free_indices(ext, free, None)
    logs = [ext.prepare_log(lg) for lg in logs]
    # parameters fitted per flight in the baseline (and the candidate's, if it belongs to a
    # flight) keep one copy per flight: the statistic's degrees of freedom count the copies
    spread = (per_flight_positions(ext, [ext.param_names[i] for i in free_idx], res.per_flight_rule)
              if len(logs) > 1 else [])
    # one evaluation: on CasADi's virtual machine unless a compiled library is cached
    ses = FitSession(ext, logs, free_idx, p, sigma, res.interval, _one_off(compile), lambda _m: None,
                     per_flight=spread)
    if res.process_noise is not None:
        qd = _process_noise(ext, res)    # per state a std, or one per flight
        qf = np.array([[v[f] if isinstance(v, (list, tuple)) else v for v in qd.values()] for f in range(len(logs))])
        ses.q = qf[0] if len(logs) == 1 else qf[ses.flight_of_interval]
    X = np.vstack(_extend_nodes(ext, res, logs, p))
    th = ses.theta(flight_vectors(ext, p, res, len(logs)))
    df = ses.nth - (len(res.free_names) + (len(logs) - 1) * len(res.per_flight_))
    return ext, p, ses, X, th, df


def one_step_estimate(model: QuadrotorModel, res: FitResult, logs: Sequence[FlightLog], name: str,
                      sigma: np.ndarray, compile: str, variance_at: str = "step") -> tuple[float, float, float]:
    """One undamped Gauss–Newton step of a one-parameter candidate ``name`` from the baseline
    ``res`` (its other parameters and the nodes moving with it; a parameter the step would
    take past a bound held): ``(null, step, std)`` in the parameter's units. ``std`` is taken
    where the step ends, near the extended model's optimum, as the fit's own parameter std:
    the larger of the Gauss–Newton one (for the weights ``sigma`` as given, not rescaled by the
    residuals) and the long-run scatter of the intervals' shares of the next step (which grows
    with the residuals; a Wald test's). ``variance_at="baseline"``: of the shares of this step
    instead, about their mean (a score test's, under the null): they also scatter with how much
    each interval tells of the effect, so it is conservative where the effect is there (a
    moment gain of 1.35: ± 0.14 at the baseline, ± 0.0014 where the step ends)."""
    if variance_at not in ("step", "baseline"):
        raise ValueError(f"one_step_estimate: variance_at must be 'step' or 'baseline', not {variance_at!r}")
    ext, _p, ses, X, th, _df = _screen_session(model, res, logs, name, sigma, compile)
    comps = [(c, null) for _, c, null in ext.effect_components(name)]
    free = [ext.param_names[i] for i in ses.free_idx]
    cols = [j for j, c in enumerate(free[k] for k in ses.local_of) if c in dict(comps)]
    if len(comps) != 1 or len(cols) != 1:
        raise ValueError(f"one_step_estimate: {name} must add one parameter shared by the flights")
    j = cols[0]
    blocks = ses.evaluate(X, th)
    dz = ses.step(X, th, blocks, 0.0)[0]
    X1, th1 = X + dz[:, :ses.nx], np.clip(th + dz[0, ses.nx:], ses.lo_s, ses.hi_s)
    Xv = X1 if variance_at == "step" else X
    blocks = ses.evaluate(X1, th1) if variance_at == "step" else blocks
    shares = ses.influence(Xv, blocks)[:, j:j + 1]
    P = float(ses.covariance(Xv, blocks)[j, j])
    centred = np.vstack([shares[sl] - shares[sl].mean(axis=0) for sl in ses.interval_slices])
    V = float(long_run_covariance(centred, ses.interval_slices)[0, 0]) if centred.size else 0.0
    scale = float(ses.scale[j])
    return comps[0][1], float(th1[j] - th[j]) * scale, float(np.sqrt(max(P, V, 0.0))) * abs(scale)


def robust_screen(model: QuadrotorModel, res: FitResult, logs: Sequence[FlightLog], name: str,
                  sigma: np.ndarray, compile: str) -> float:
    """The score statistic of a one-parameter candidate ``name`` whose null is its lower bound,
    with the step's variance taken from the intervals' shares of it where they scatter more
    than the weights say (:func:`one_step_estimate`, its variance under the null, at the
    baseline): ``(step / std)^2`` for a step toward the effect, 0 for one away from it. The
    plain statistic (:func:`screen`) trusts the weights; noise on the logged inputs is a random
    forcing they do not hold, and there it is large by chance as often as not (greybox's own
    flights with 0.5-1 rad/s of noise on held speeds: 11-16 for the central blend of the rows'
    timing, where its robust statistic is at most 5). Under the null it is 0 half the time, so
    read as chi-square with one degree of freedom its level is half the nominal one: a
    conservative test."""
    _null, step, std = one_step_estimate(model, res, logs, name, sigma, compile, variance_at="baseline")
    return (step / std) ** 2 if step > 0 and std > 0 else 0.0


MOMENT_SCALE_NOTICE = 0.05
"""A roll and pitch moment off the airframe's by this share or more (and by 3 std) is said by
:func:`moment_scale_words`: beyond what a careful estimate of an inertia misses. (At 0.1 a blind
audit's airframe with the mass 8 % low, k_M 1.088 ± 0.0005, was fitted with K_T 8 % low and
nothing said.)"""


def moment_scale_words(res: FitResult, logs: Sequence[FlightLog], compile: str = "cached") -> list[str]:
    """Words for a certified fit of a model whose roll and pitch moments are the airframe's
    (no effect that scales them, :attr:`~greybox.effects.Effect.scales_commanded_moment`), when
    one Gauss–Newton step of ``moment_gain`` from it (:func:`one_step_estimate`) says the body
    turns :data:`MOMENT_SCALE_NOTICE` or more otherwise per rotor-speed difference, beyond
    3 std: a mass, an inertia, an arm or a command map off, which the fit's ``K_T``, ``b`` and
    ``Kd`` carry silently (a blind audit's 1.1 kg vehicle given an inertia 35 % too large:
    ``b`` 35 % high at 0.03 %, "certified"; given a mass 25 % too large: ``K_T`` and ``Kd``
    25 % high, "certified"), within what a moment gain physically is
    (:meth:`~greybox.effects.MomentGain.plausible_limits`). ``[]`` otherwise."""
    model = res.model
    name = fx.MomentGain.name
    if not res.converged or any(e.scales_commanded_moment for e in model.effects):
        return []
    try:
        null, step, std = one_step_estimate(model, res, logs, name, fit_weights(res), compile)
    except (GreyboxInputError, ValueError, np.linalg.LinAlgError, RuntimeError):
        return []      # words on the fit only: where the step cannot be had, nothing is said
    k = null + step
    # beyond what a moment gain physically is (a step to its bound, 0.02, on the real Crazyflie
    # flights, whose base model lacks the CoG offset's trim moment) it stands for something
    # else, which the diagnosis looks for: nothing said of the airframe then
    plausible = abs(step) <= fx.MomentGain().plausible_limits(model.airframe)["k_M"]
    if not (np.isfinite(k) and plausible and abs(step) > 3 * std and abs(step) >= MOMENT_SCALE_NOTICE):
        return []
    # a lag between the logged speeds and the thrust (commands logged, no motor lag in the
    # model) lowers the moment's gain at the manoeuvres' frequencies: 1/(1 + (w tau)^2)
    lag = ("; or a lag between the logged speeds and the thrust that the model lacks (motor_lag, "
           "command_delay) lowers the moment's gain at the manoeuvres' frequencies"
           if k < 1 and not any(e.input_timed for e in model.effects) else "")
    # noise on the speeds' roll and pitch combinations takes the gain read from them down by up
    # to its share (errors in variables): a blind audit's slow flight, 57 % noise in the roll
    # combination, read 0.874 as an inertia 14 % off where the airframe was exact
    shares = [c for c in (mixer_noise_shares(model, lg) for lg in logs) if c is not None]
    noisy = max((float(max(c[1], c[2])) for c in shares), default=0.0)
    if k < 1 and noisy >= 1 - k:
        return [f"the roll and pitch turn about {k:.3g} times as much per rotor-speed difference as the airframe's "
                f"inertia, arm and mass give (one Gauss–Newton step of {name} from this fit: k_M ≈ {k:.3g} ± "
                f"{std:.2g}), but white noise makes up {100 * noisy:.0f} % of the speeds' roll or pitch combination "
                "on this flight, and noise on the speeds takes the gain read from them down by up to that share "
                "(errors in variables): this flight cannot tell an airframe off from that; one that turns more, "
                "or speeds logged with less noise, can"]
    return [f"the roll and pitch turn about {k:.3g} times as much per rotor-speed difference as the airframe's "
            f"inertia, arm and mass give (one Gauss–Newton step of {name} from this fit: k_M ≈ {k:.3g} ± "
            f"{std:.2g}), which K_T and Kd (a mass) or b (an inertia about z) may carry: "
            f"{fx.MomentGain.readings(k, model.airframe)}{lag}; or diagnose, which fits {name}"]


def screen_jointly(model: QuadrotorModel, res: FitResult, logs: Sequence[FlightLog], names: Sequence[str],
                   sigma: np.ndarray, compile: str) -> dict[str, tuple[float, int]]:
    """The statistics of :func:`screen` for those of ``names`` that one evaluation of the
    model extended by all of them gives (``{name: (score, df)}``; the others are left to
    :func:`screen`): each candidate's Gauss-Newton step is taken with the other candidates'
    parameters held at their null values, where they do nothing, so it is the step of the
    model extended by that candidate alone. A round screened 15 candidates on a real flight
    in 12 s, one evaluation each on CasADi's virtual machine; together it is one evaluation
    and a banded solve each. Candidates that add states or cannot vanish (a motor lag) are
    left out, and so is everything for several flights; should the extended model's cost at
    the baseline not be the baseline's (an effect that is not nothing at its null value),
    nothing is taken from it."""
    joint = []
    for name in names:
        effect = fx.by_name(name)
        if effect.state_names(model.airframe) or any(not par.lower <= par.null <= par.upper
                                                     for par in effect.parameters(model.airframe)):
            continue
        joint.append(name)
    if len(joint) < 2 or len(logs) != 1 or res.per_flight_:
        return {}
    try:
        sup, p, free = _extended_by(model, res, joint)
    except GreyboxInputError:
        return {}        # effects that cannot be in one model (a clash of names): one at a time
    new = {name: [c for _, c, _ in sup.effect_components(name)] for name in joint}
    free_idx = free_indices(sup, free, None)
    logs = [sup.prepare_log(lg) for lg in logs]
    ses = FitSession(sup, logs, free_idx, p, sigma, res.interval, _one_off(compile), lambda _m: None)
    if res.process_noise is not None:
        qd = _process_noise(sup, res)
        ses.q = np.array([v[0] if isinstance(v, (list, tuple)) else v for v in qd.values()])
    X = np.vstack(_extend_nodes(sup, res, logs, p))
    th = ses.theta(p)
    blocks = ses.evaluate(X, th)
    cost = ses.total_cost(X, blocks[0], blocks[4])
    if not abs(cost - res.cost) <= JOINT_COST_TOLERANCE * max(abs(res.cost), 1e-300):
        return {}
    free_names = [sup.param_names[i] for i in ses.free_idx]
    comp_of = [free_names[j] for j in ses.local_of]
    out = {}
    for name in joint:
        others = {c for m, comps in new.items() if m != name for c in comps}
        held = np.array([c in others for c in comp_of], dtype=bool)
        out[name] = (2.0 * max(ses.predicted_decrease(X, th, blocks=blocks, held=held), 0.0), len(new[name]))
    return out


JOINT_COST_TOLERANCE = 1e-8
"""The model extended by every jointly screened candidate (:func:`screen_jointly`) must have
the baseline's cost at the baseline to this relative tolerance (rounding only)."""


def _plausible_start(ext: QuadrotorModel, res: FitResult, name: str, p: np.ndarray) -> np.ndarray | None:
    """``p`` with effect ``name``'s new parameters whose null lies outside their bounds at the
    effect's plausible values for the airframe (within the bounds); None when it has none."""
    plausible = fx.example_values(name, ext.airframe, res.value("K_T"))
    out, moved = p.copy(), False
    for par in ext.parameters:
        if par.effect != name or par.lower <= par.null <= par.upper or par.name not in plausible:
            continue
        vals = np.broadcast_to(np.asarray(plausible[par.name], dtype=float), (par.size,))
        for comp, v in zip(par.component_names, vals):
            out[ext.param_names.index(comp)] = min(max(v, par.lower), par.upper)
            moved = True
    return out if moved else None


def flight_vectors(ext: QuadrotorModel, p: np.ndarray, res: FitResult, n_flights: int) -> list[np.ndarray]:
    """``p`` (a vector of ``ext``) once per flight, with each flight's own values of the
    baseline's per-flight parameters."""
    out = []
    for f in range(n_flights):
        pf = p.copy()
        for comp, v in res.per_flight_.items():
            pf[ext.param_names.index(comp)] = v["value"][f]
        out.append(pf)
    return out


def _process_noise(ext: QuadrotorModel, res: FitResult) -> dict[str, float] | None:
    """The baseline's process noise for the extended model's states (same weights, so costs
    compare); new effect states (motor speeds) get so tight a process noise that their
    random walk over the whole flight stays below 1e-4 of their scale: a candidate must
    explain the data through its physics. With a loose process noise of its own (it was
    1 %), a state-adding effect such as motor_lag got four free process-noise channels that
    absorbed any torque the model lacks, and a likelihood ratio in the thousands; with 1e-4
    per step, 20,000 steps at 1 kHz still let a motor speed drift by 1.4 % and stand in for
    a weak rotor (LR 1076)."""
    if res.process_noise is None:
        return None
    w_ref = res.model.hover_speed(res.p)
    steps = max(max(len(idx) for idx in res.node_index) - 1, 1)
    return {s: res.process_noise.get(s, 1e-4 * w_ref / np.sqrt(steps)) for s in ext.state_names}


HELD_ITERATIONS = 3
"""A candidate's refit is stopped once it has held one of the candidate's parameters on a
bound beyond what the effect physically does for this many accepted steps in a row
(:class:`HeldBeyondPlausible`)."""


class HeldBeyondPlausible:
    """The stop rule of a candidate's refit (:class:`~greybox.fitting.GaussNewton`'s
    ``stop``): words once the refit has held a parameter of ``effect`` on one of its bounds,
    with the effect's values beyond what it physically does on the airframe
    (:meth:`~greybox.effects.Effect.plausibility_warnings`), for ``iterations`` accepted steps
    in a row. Such a refit can be the verdict only by travelling back; judged where it
    stopped it is refused as implausible all the same, with its likelihood ratio a lower
    bound. On the real flights a thrust curve ran to its bound in every round of every
    flight and its refits, run to their end, took 39 refits and 215 s of ten diagnoses to be
    refused."""

    def __init__(self, effect: str, iterations: int = HELD_ITERATIONS):
        self.effect, self.iterations = effect, iterations
        self.held = 0

    def __call__(self, ses: FitSession, th: np.ndarray) -> str:
        model = ses.model
        e = model.effects.get(self.effect)
        comps = {c for _, c, _ in model.effect_components(self.effect)}
        free = [model.param_names[i] for i in ses.free_idx]
        # every copy (one per flight for a per-flight parameter) of the effect's free components
        mine = np.array([free[j] in comps for j in ses.local_of], dtype=bool)
        on_bound = mine & ((th <= ses.lo_s) | (th >= ses.hi_s))
        words: list[str] = []
        std = {c: 1.0 for c in free if c in comps}     # free components: the ones judged
        p = ses.pfix.copy()
        # each flight's values (per-flight copies), where one of its copies is on a bound
        for f in (range(ses.theta_index.shape[0]) if e is not None else ()):
            if on_bound[ses.theta_index[f]].any():
                p[ses.free_idx] = ses.flight_theta(th, f)
                words = e.plausibility_warnings(model.parameter_dict(p), std, model.airframe)
                if words:
                    break
        self.held = self.held + 1 if words else 0
        if self.held < self.iterations:
            return ""
        return f"{'; '.join(words)} (held on its bound for {self.held} steps)"


SOFT_REFIT_ITER = 15
"""Iteration budget of a candidate's refit with soft continuity (process noise)."""
COLD_REFIT_ITER = 40
"""Iteration budget of a candidate's second refit from the airframe's guesses (the right
model gets there in a handful of iterations; a wrong one crawls, and is judged where it is)."""


def refit(model: QuadrotorModel, res: FitResult, est: Sequence[FlightLog], val: Sequence[FlightLog] | None,
          name: str,
          sigma: dict, compile: str, cold: bool = False, max_iter: int | None = None,
          start: FitResult | None = None, restart: bool = False, horizon: float = DEFAULT_HORIZON
          ) -> tuple[QuadrotorModel, FitResult, Prediction | None]:
    """Fit the model extended by ``name``: warm-started at the baseline optimum with the
    baseline's weights, or ``cold`` — from the airframe's guesses with the candidate's
    parameters at a plausible magnitude and the fit's own noise re-estimation — when the
    baseline is a compensating solution, or continued from ``start`` (an earlier, capped
    refit). With ``restart`` a warm refit is followed by a cold one and the refit with the
    larger likelihood (:func:`profile_log_likelihood`) is kept: a baseline far from the data
    sits in a compensating basin (a vertical drag of 6.4 standing in for a ground effect), and
    the candidate's refit from there stays in it (k_ge at a third of its value after 200
    iterations), where a fit from the guesses gets to the truth in five. No validation when
    ``val`` is None. With soft continuity the cold refit keeps the baseline's weights and
    process noise, and the refit with the lower cost is kept."""
    ext, p, free = extended_model(model, res, name)
    soft = res.process_noise is not None
    reweight = False
    if start is not None:
        p, init = start.p, start.node_states
        sigma = start.sigma          # the weights it reached
    elif cold:
        # from the airframe's guesses, except what the baseline held (a b measured on a bench)
        guess, held = _guesses(ext, name), [i for i, n in enumerate(ext.param_names) if n not in free]
        guess[held] = p[held]
        p, init = guess, None
        reweight = not soft
    else:
        init = _extend_nodes(ext, res, est, p)
    # a cold start of a still-wrong model can crawl along a compensating valley: cap it, the
    # likelihood ratio against the baseline stays valid for any point reached
    # a soft-continuity refit has a node at every sample: its iterations are dear (13 s each
    # for motor_lag on a 20 s, 1 kHz flight), a right candidate gets there in a handful, and
    # a likelihood ratio at any point reached is a valid lower bound
    cap = 50 if cold else (SOFT_REFIT_ITER if soft else 200)
    # what every fit of this refit shares: the baseline's sensor noise, shooting intervals,
    # process noise and per-flight rule, the weights unless re-estimated, the budget
    shared = dict(noise=None if reweight else sigma, reweight=reweight, sensor_noise=res.sensor_given,
                  compile=compile, max_iter=max_iter or cap, interval=res.interval,
                  process_noise=_process_noise(ext, res), per_flight=res.per_flight_rule)
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", ConvergenceWarning)   # a capped refit is judged by its LR
        fr = fit(ext, est, free=free, p0=p, initial_states=init, solver=GaussNewton(stop=HeldBeyondPlausible(name)),
                 **shared)
    if not cold and start is None and (held := _reaction_torque_start(ext, res, name, p)) is not None:
        # the baseline's b near zero: the spin directions' difference in the gains is
        # escaped through it; from a propeller's b, the gains carry it (a blind audit's simulated
        # Crazyflie with one spin direction's rotors 8 % weaker in thrust and torque)
        fr = _lower_cost(fr, _held_then_free(ext, est, free, held, "b", init, shared))
    if (cold or start is not None) and _worse(fr, res, soft):
        # the model holds the baseline (the candidate at its null), so its optimum is no worse:
        # a cold refit that ends above the baseline's cost found another basin, not the
        # candidate's answer (a blind audit's sprayer in a wind: the baseline's vertical drag on
        # its upper bound, 40, stood for the mass the vehicle lost; the wind refitted from the
        # guesses took the drag to 0 and ended at 1.21 times the baseline's cost, "LR 0,
        # p = 1", though its wind was right): the refit from the baseline is tried, the better kept
        warm = refit(model, res, est, None, name, sigma, compile)[1]
        fr = warm if _worse(fr, warm, soft) else fr
    if restart and not cold and start is None:
        again = refit(model, res, est, None, name, sigma, compile, cold=True, max_iter=COLD_REFIT_ITER)[1]
        if _worse(fr, again, soft):
            fr = again
    return ext, fr, predict_after_fit(fr, est, val, compile=compile, horizon=horizon) if val is not None else None


def _reaction_torque_start(ext: QuadrotorModel, res: FitResult, name: str, p: np.ndarray) -> np.ndarray | None:
    """``p`` with ``b`` at the airframe's value, when ``name`` scales the rotors' reaction
    torques (:attr:`~greybox.effects.Effect.scales_reaction_torques`), the baseline's
    ``b/K_T`` is below what propellers give and the airframe's is within it; else None."""
    if not getattr(fx.by_name(name), "scales_reaction_torques", False) or "b" not in res.free_names \
            or "K_T" not in ext.param_names:
        return None
    lo, hi = fx.YawTorque.RATIO_RANGE
    kt = res.value("K_T")
    guess = ext.default_parameters()
    b0, kt0 = guess[ext.param_names.index("b")], guess[ext.param_names.index("K_T")]
    if not (kt > 0 and kt0 > 0) or res.value("b") / kt >= lo or not lo <= b0 / kt0 <= hi:
        return None
    held = np.array(p, dtype=float).copy()
    held[ext.param_names.index("b")] = b0 / kt0 * kt      # the airframe's ratio at the fitted K_T
    return held


def _held_then_free(ext: QuadrotorModel, est: Sequence[FlightLog], free: list[str], p: np.ndarray, held: str,
                    init, shared: dict) -> FitResult:
    """A refit with ``held`` first held at its value in ``p``, then freed, with the warm
    refit's settings ``shared`` (the baseline's weights and process noise)."""
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", ConvergenceWarning)
        first = fit(ext, est, free=[n for n in free if n != held], p0=p, initial_states=init, **shared)
        return fit(ext, est, free=free, p0=first.p, initial_states=first.node_states, **shared)


def _worse(fr: FitResult, other: FitResult, soft: bool) -> bool:
    """Whether the fit ``fr`` ends worse than ``other``: with soft continuity (``soft``: the
    same weights and process noise) on the cost, with output error on the likelihood (a cold
    refit re-estimates its own weights)."""
    if soft:
        return fr.cost > other.cost
    return profile_log_likelihood(fr) < profile_log_likelihood(other)


def _lower_cost(a: FitResult, b: FitResult) -> FitResult:
    """The one of two fits with the same weights that reached the lower cost."""
    return b if b.cost < a.cost else a


def _guesses(ext: QuadrotorModel, name: str | fx.Effect) -> np.ndarray:
    """The airframe's starting values, the candidate's parameters at a plausible magnitude
    (its class's :meth:`~greybox.effects.Effect.plausible_values`; null when it has none)."""
    p = ext.default_parameters()
    kt = p[ext.param_names.index("K_T")]
    effect = name if isinstance(name, fx.Effect) else fx.by_name(name)
    return ext.parameter_vector(effect.plausible_values(ext.airframe, kt), p)


def profile_log_likelihood(fr: FitResult) -> float:
    """The Gaussian log-likelihood of a fit with every channel's noise level at its
    maximum-likelihood value (the RMS residual), up to a constant: ``-sum_c n_c log rms_c``.
    Fits with different weights compare on it; with soft continuity (process noise) the
    weights are part of the model and it is not used."""
    return -sum(fr.channel_count[ch] * np.log(max(fr.residual_rms[ch], 1e-300)) for ch in fr.residual_rms)


def prediction_change(before: Prediction, after: Prediction) -> dict[str, float]:
    """Per channel, how much ``after`` moves the predictions of ``before`` on the same log,
    relative to the error of ``before``: below the confirmation threshold in every channel,
    the validation data cannot confirm (or refute) the change out of sample."""
    out = {}
    for c, ch in enumerate(OUTPUTS):
        if ch not in before.nrmse:
            continue
        d = after.predicted[:, c] - before.predicted[:, c]
        if ch == "psi":
            d = np.arctan2(np.sin(d), np.cos(d))
        e = before.errors[:, c]
        k = np.isfinite(d) & np.isfinite(e)
        with np.errstate(over="ignore", invalid="ignore"):   # a prediction that blew up moves it by inf
            err = float(np.sqrt(np.mean(e[k] ** 2))) if k.any() else 0.0
            out[ch] = float(np.sqrt(np.mean(d[k] ** 2))) / err if err > 0 else 0.0
    return out


def lr_test(base: FitResult, alt: FitResult, alt_resid: np.ndarray, df: int, on_bound: bool,
            n_tests: int) -> tuple[float, float]:
    """Likelihood-ratio statistic of ``alt`` against ``base`` (per channel divided by the
    long-run variance factor of ``alt``'s residuals ``alt_resid``) and its p-value against
    chi-square(``df``), halved when the null value is on a bound, times ``n_tests``
    (Bonferroni).

    With hard continuity the channel noise levels are estimated with the parameters, so the
    ratio is that of the concentrated likelihoods, ``n_c log(rms_base^2 / rms_alt^2)`` per
    channel: it compares fits made with different weights (a refit that re-estimated its
    own), and at equal weights it is never below the weighted cost difference
    ``n_c (1 - rms_alt^2 / rms_base^2)`` it replaces (log x >= 1 - 1/x). Any point a refit
    reaches gives a lower bound of the statistic at the refit's optimum, provided the
    baseline sits at its own optimum (the diagnosis checks its certificate first). With soft
    continuity (process noise) the weights are fixed and the gaps count as residuals."""
    lr = 0.0
    soft = base.process_noise is not None
    for c, ch in enumerate(OUTPUTS):
        if ch not in base.channel_cost:
            continue
        f = long_run_factor(alt_resid[:, c] / base.sigma[ch])
        if soft:
            lr += (base.channel_cost[ch] - alt.channel_cost[ch]) / f
        else:
            lr += base.channel_count[ch] * 2.0 * np.log(base.residual_rms[ch] / max(alt.residual_rms[ch], 1e-300)) / f
    if soft:
        lr += base.process_cost - alt.process_cost   # soft continuity: the gaps are residuals too
    lr = max(float(lr), 0.0)
    p = float(stats.chi2.sf(lr, df)) if df > 0 else 1.0
    if on_bound:
        p *= 0.5   # chi-bar-square: half the mass sits on the bound
    return lr, min(1.0, p * n_tests)


def explained_fraction(base: FitResult, alt: FitResult) -> float | None:
    """Fraction of the baseline's excess residual that ``alt`` removes: per channel the
    residual variance above the sensor noise, ``(rms/noise)^2 - 1``, summed over channels
    (less what the logged inputs' noise puts on a prediction, the baseline certificate's
    :attr:`~greybox.fitting.certificate.Certificate.input_noise`: no model removes it).
    1 means the residuals fall to the noise; near 0, the candidate explains a sliver of what
    the model misses, however significant that sliver is."""
    if base.certificate is None or alt.certificate is None:
        return None
    cert = base.certificate
    r0, r1 = cert.residual_over_noise, alt.certificate.residual_over_noise
    floor = {ch: cert.exact_model_variance(ch) for ch in r0}
    ex0 = sum(max(r0[ch] ** 2 - floor[ch], 0.0) for ch in r0)
    ex1 = sum(max(r1.get(ch, r0[ch]) ** 2 - floor[ch], 0.0) for ch in r0)
    return None if ex0 <= 0 else float(1.0 - ex1 / ex0)


def physically_negligible(fr: FitResult, effect: str) -> str:
    """Words saying that the fitted parameters of ``effect`` are physically negligible (all
    below :data:`NEGLIGIBLE_FRACTION` of their plausible magnitude for the airframe, or the
    effect's own :meth:`~greybox.effects.Effect.negligible_size`), or ""."""
    model = fr.model
    # the vehicle's size sets the plausible magnitudes: the airframe's K_T when the fit's is
    # not positive (a compensating refit can push it onto its bound)
    kt = fr.value("K_T") if "K_T" in model.param_names else 0.0
    if not kt > 0:
        kt = float(model.default_parameters()[model.param_names.index("K_T")]) \
            if "K_T" in model.param_names else 0.0
    if not kt > 0:
        return ""
    plausible = fx.example_values(effect, model.airframe, kt)
    e = model.effects.get(effect)
    shape = set(e.shape_parameters) if e is not None else set()
    own = e.negligible_size(model.airframe) if e is not None else {}
    def quantity(value: float, unit: str) -> str:
        return f"{value:.3g}" + ("" if unit in ("", "1") else f" {unit}")   # "1": a pure number

    parts, units = [], {}
    for par, comp, null in model.effect_components(effect):
        if par.name in shape:
            continue    # a hub height does not make a drag of zero
        # the largest plausible component's size; none known: a tenth of the parameter's scale
        ref = float(np.max(np.abs(np.atleast_1d(np.asarray(plausible.get(par.name, 0.1 * par.scale), dtype=float)))))
        if abs(fr.value(comp) - null) >= own.get(par.name, NEGLIGIBLE_FRACTION * ref):
            return ""
        parts.append(f"{comp} = {quantity(fr.value(comp), par.unit)}")
        units[par.name] = par.unit
    if not parts:
        return ""
    if own:
        return f"{', '.join(parts)} (each below " + ", ".join(quantity(v, units.get(n, "")) for n, v in own.items()) + \
            f" in size: negligible for {effect})"
    return f"{', '.join(parts)} (below {100 * NEGLIGIBLE_FRACTION:.0f} % of a plausible size for this airframe)"


def free_input_timed(model: QuadrotorModel, fr: FitResult) -> list[str]:
    """The lags and delays (:attr:`~greybox.effects.Effect.input_timed`) of ``model``'s effects
    that the fit ``fr`` fits."""
    return [n for e in model.effects for n in e.input_timed if n in fr.free_names]


SMOOTHED_LAG_WORDS = (
    "the logged rotor speeds were smoothed before the fit as white noise the gyro does not follow, and a "
    "controller's commands logged exactly look like that noise behind motors slower than the rows: the smoother "
    "then takes out what the motors filter, and the lag comes out short (a blind audit's 15-ms motors: 14.1 ms, "
    "8 std low; its 3-ms motors: 2.45 ms, under half a row; fitted as logged 15.0 and 2.97 ms). If the speeds "
    "are commands logged as sent, fit or diagnose again with --input-noise keep (in Python: without denoise_inputs)")
"""Said beside a lag or delay fitted to rotor speeds smoothed as noisy (:func:`smoothed_lag_words`)."""


def smoothed_lag_words(logs: Sequence[FlightLog], fr: FitResult | None = None) -> str:
    """:data:`SMOOTHED_LAG_WORDS` when some log's inputs were smoothed since they were logged
    (:attr:`~greybox.data.FlightLog.input_noise_left`, set by
    :func:`~greybox.fitting.denoise_inputs`), else "". With a fit ``fr``, only where it fits a
    lag or delay (:attr:`~greybox.effects.Effect.input_timed`), and the words start with their
    values. The smoother's noise is what the gyro does not follow of the speeds' row-to-row
    changes; behind a motor lag of a few rows the gyro follows little of a command's, so exact
    commands are smoothed too, and a lag fitted to them is shortened by what the smoother took
    (a blind audit's 0.5 kg vehicle, commands logged exactly at 200 Hz: tau_m 14.1 ms for 15
    on every seed, 8 std low on average)."""
    if not any(lg.input_noise_left for lg in logs):
        return ""
    if fr is None:
        return SMOOTHED_LAG_WORDS
    lags = free_input_timed(fr.model, fr)
    return ", ".join(f"{n} = {1e3 * fr.value(n):.3g} ms" for n in lags) + f": {SMOOTHED_LAG_WORDS}" if lags else ""


SETTLED_SHARE = 0.1
"""A lag's std with the log's timing free, as a share of half a row, below which the data
settle the timing for it (:func:`lag_timing_words` then says nothing, when the lag also stays
within 3 combined std of its value with the rows held)."""


def lag_timing_words(model: QuadrotorModel, fr, est: Sequence[FlightLog],
                     timing_refit=None) -> tuple[str, dict[str, float]]:
    """Words for the final fit's lags and delays (:attr:`~greybox.effects.Effect.input_timed`)
    when the log's timing was not found (the held rows stood): their std count the noise, not
    whether a row's logged value holds for the whole row; that moves them by up to half a
    row. ``timing_refit``: the certified refit of ``fr``'s model with the timing free as well;
    its std of a lag count both, and where they are all below :data:`SETTLED_SHARE` of half a
    row and every lag stays within 3 combined std of ``fr``'s, the data settle it and there are
    no words (a blind audit's 100 Hz log of commands held at the controller's rate: tau_m
    24.99 ms for 25, yet the words said 5 ms). A lag the timing moves further is not settled,
    however small its std: the words give both values. Returns the words and the bound they
    give, half a row per lag they name (:attr:`Diagnosis.timing_bound`); ``("", {})`` when the
    final model has none or the data settle them."""
    names = free_input_timed(model, fr)
    if not names:
        return "", {}
    half = 0.5 * median_row_interval(est)

    def ms(f, n):
        return f"{n} = {1e3 * f.value(n):.3g} ± {1e3 * f.std[f.free_names.index(n)]:.2g} ms"

    values = ", ".join(ms(fr, n) for n in names)
    if timing_refit is not None and all(n in timing_refit.free_names for n in names):
        free_std = [float(timing_refit.std[timing_refit.free_names.index(n)]) for n in names]
        # settled: the timing free, the lags' std are a small share of half a row, and they stay
        # within 3 combined std of where the held rows put them (an undetermined std: moved)
        moved = [not abs(timing_refit.value(n) - fr.value(n))
                 <= 3 * math.hypot(v, float(fr.std[fr.free_names.index(n)]))
                 for n, v in zip(names, free_std)]
        if all(np.isfinite(v) and v < SETTLED_SHARE * half for v in free_std) and not any(moved):
            return "", {}
        values += f" (with the log's timing free as well: {', '.join(ms(timing_refit, n) for n in names)})"
    return ((f"{values} count{'s' if len(names) == 1 else ''} the measurement noise only: whether each row's "
            f"rotor speeds hold for the whole row or are samples of a signal that varies within it (the log's "
            f"timing, which these data do not settle) moves a lag or a delay by up to half a row, "
            f"{1e3 * half:.2g} ms here; log the rotor speeds at the rate the controller sets them to remove it"),
            {n: half for n in names})


def within_row_timing(model: QuadrotorModel, effect: str, values: dict[str, float],
                      logs: Sequence[FlightLog]) -> str:
    """Words saying that every lag or delay of ``effect`` (its
    :attr:`~greybox.effects.Effect.input_timed` parameters, at ``values``) is shorter than half
    a row of the logged inputs, or "". How the logged values vary within a row (held, or samples
    of a signal varying between rows: the log's timing) moves a lag by up to half a row (a blind
    audit's 200 Hz log: tau_m 28.7 ms for 30), so a lag under half a row cannot be told from
    it: a six-rotor simulator with no lag between its logged speeds and its thrust, speeds
    logged at 200 Hz with white noise, gave ``motor_lag`` LR 312 and tau_m 1.05 ms with the
    noise's share extrapolated out (:mod:`~greybox.diagnosis.input_noise`)."""
    e = model.effects.get(effect)
    timed = [n for n in (e.input_timed if e is not None else ()) if n in values]
    if not timed or not logs:
        return ""
    half = 0.5 * median_row_interval(logs)
    if not all(abs(values[n]) < half for n in timed):
        return ""
    lower = {par.name: float(np.atleast_1d(par.lower)[0]) for par in model.parameters}

    def one(n: str) -> str:
        v, lo = values[n], lower.get(n.split("[")[0], -np.inf)
        if np.isfinite(lo) and lo > 0 and abs(v - lo) <= 1e-6 * lo:
            return f"{n} = {1e3 * v:.3g} ms (its lower bound)"
        digits = 3
        # as many digits as show it below the half row (2 ms against 2 ms read as a contradiction)
        while digits < 6 and float(f"{1e3 * v:.{digits}g}") >= float(f"{1e3 * half:.2g}"):
            digits += 1
        return f"{n} = {1e3 * v:.{digits}g} ms"
    said = ", ".join(one(n) for n in timed)
    smoothed = smoothed_lag_words(logs)
    return (f"{said} is under half a row of the logged inputs ({1e3 * half:.2g} ms), which how the logged values "
            "vary within a row (the log's timing) moves a lag by: cannot tell it from the log's timing; "
            "log the inputs faster to measure it" + (f"; and {smoothed}" if smoothed else ""))


def negligible_effect(fr: FitResult, effect: str, logs: Sequence[FlightLog]) -> str:
    """Words saying that ``effect`` is physically negligible in the fit ``fr``, in its parameters
    (:func:`physically_negligible`) or in force terms (:func:`physically_small`), or "". Small
    in force terms with parameters that are neither small nor determined (every free one
    within 3 std of its null value), the words say so: what the flights show is that it moves
    little, not how large it is (a blind audit's X8 octocopter, its lower rotors at 0.8 of the
    upper ones, which its mixer's equal commands to each pair leave unseen: rotor gains
    ±0.08 ± 0.06 "physically negligible" whatever the truth)."""
    small_parameters = physically_negligible(fr, effect)
    if small_parameters:
        return small_parameters
    small = physically_small(fr, effect, logs)
    if not small:
        return ""
    undetermined = _undetermined_components(fr, effect)
    if undetermined:
        values = ", ".join(f"{c} = {v:.3g} ± {s:.2g}" for c, v, s in undetermined)
        small += (f"; its parameters are not small but not determined either ({values}, each within 3 std of "
                  "its null value): these flights show that it moves little here, not how large it is")
    return small


def small_in_force_only(fr: FitResult, effect: str, logs: Sequence[FlightLog]) -> bool:
    """Whether :func:`negligible_effect` refuses ``effect`` only for its force: parameters
    neither negligible nor undetermined, its force below :data:`MIN_FORCE_SHARE`."""
    return not physically_negligible(fr, effect) and bool(physically_small(fr, effect, logs)) \
        and not _undetermined_components(fr, effect)


def _undetermined_components(fr: FitResult, effect: str) -> list[tuple[str, float, float]]:
    """``(component, value, std)`` of ``effect``'s size parameters when every one lies within 3
    std of its null value (none otherwise, or without any)."""
    std = dict(zip(fr.free_names, map(float, fr.std)))
    e = fr.model.effects.get(effect)
    shape = set(e.shape_parameters) if e is not None else set()     # a hub height is no size
    comps = [(c, fr.value(c), null) for par, c, null in fr.model.effect_components(effect)
             if c in std and par.name not in shape]
    if comps and all(np.isfinite(std[c]) and abs(v - null) < 3.0 * std[c] for c, v, null in comps):
        return [(c, v, std[c]) for c, v, _ in comps]
    return []


def physically_implausible(fr: FitResult, effect: str) -> str:
    """Words saying that the fitted parameters of ``effect`` are beyond what it physically
    does on the airframe (the effect's :meth:`~greybox.effects.Effect.plausibility_warnings`),
    or ""."""
    e = fr.model.effects.get(effect)
    if e is None:
        return ""
    std = dict(zip(fr.free_names, map(float, fr.std)))
    return "; ".join(e.plausibility_warnings(fr.model.parameter_dict(fr.p), std, fr.model.airframe))


def _nearest_bound(par, value: float) -> tuple[float, str]:
    """The bound of ``par`` nearer ``value``, and which it is ("lower" or "upper")."""
    return (par.lower, "lower") if abs(value - par.lower) <= abs(value - par.upper) else (par.upper, "upper")


def held_on_bound(fr: FitResult, effect: str) -> str:
    """Words naming the parameters of ``effect`` that the refit ``fr`` holds on a bound away
    from their null value (``"k_M = 0.02 (lower bound)"``), or "". An effect whose parameter
    runs to a bound stands in for something the model lacks: on a real Crazyflie flight the
    moment gain ran to 0.02 (a vehicle that ignores its commands) before the CoG offset that
    balances the commanded trim moment was in the model."""
    held = set(fr.certificate.held) if fr.certificate is not None else set()
    parts = []
    for par, comp, null in fr.model.effect_components(effect):
        v = fr.value(comp)
        if comp not in held or np.isclose(v, null, rtol=1e-6, atol=1e-12):
            continue
        _, side = _nearest_bound(par, v)
        # a bound that stands for the null (a motor lag's 2 ms floor) is no stand-in
        if (side == "lower" and null <= par.lower) or (side == "upper" and null >= par.upper):
            continue
        parts.append(f"{comp} = {v:.3g} ({side} bound)")
    return ", ".join(parts)


REPLACED_CLEAR_STD = 3.0
"""A parameter the model already had is *replaced* by a candidate when the baseline's value
stood more than this many of its std clear of the bound (or null) the candidate's refit takes
it to."""


def replaced_base_terms(base: FitResult, fr: FitResult, effect: str) -> str:
    """Words naming the parameters the model had before ``effect`` (free in the baseline
    ``base``) whose place the refit ``fr`` with it takes (``"Kd[0] 0.25 -> 0 (lower bound)"``,
    ``"Kd[2] 0.349 -> 0.021 ± 0.12 (no longer told from 0)"``), or "". Such a candidate does
    not add to the model: it swaps a term of it for another form of the same physics. A term
    is taken over when the refit holds it on a bound the baseline had it clear of (the ninth
    audit's hexacopter, drag on the world-frame velocity: ``rotor_drag`` took the place of
    ``Kd[0]``, ``Kd[1]``, held at 0, k_rd 1.3 std from 0 beside them, for a validation x 7 %
    better and the total unchanged), or when the refit moves it more than half way to its null
    and leaves it within two of its own std of it, from a baseline that had it clear of the
    null (the same hexacopter from other seeds: ``hub_rotor_drag`` with hubs 0.13-0.21 m up,
    its thrust-proportional vertical drag in place of ``Kd[2]`` 0.35 -> 0.02 ± 0.12, for a
    validation q 16 % better and the total 3 %)."""
    held = set(fr.certificate.held) if fr.certificate is not None else set()
    was_held = set(base.certificate.held) if base.certificate is not None else set()
    base_std = dict(zip(base.free_names, base.std))
    new_std = dict(zip(fr.free_names, fr.std))
    parts = []
    for par in fr.model.parameters:
        if par.effect == effect:
            continue
        null = float(par.null)
        for comp in par.component_names:
            if comp in was_held or comp not in base_std:
                continue
            v0, v, s0, s = base.value(comp), fr.value(comp), base_std[comp], float(new_std.get(comp, np.nan))
            if not (np.isfinite(s0) and s0 > 0):
                continue
            if comp in held:
                bound, side = _nearest_bound(par, v)
                if abs(v0 - bound) > REPLACED_CLEAR_STD * s0:
                    parts.append(f"{comp} {v0:.3g} -> {v:.3g} ({side} bound)")
            elif abs(v0 - null) > REPLACED_CLEAR_STD * s0 and abs(v - null) < 0.5 * abs(v0 - null) and \
                    not abs(v - null) >= 2.0 * s:
                # a NaN std (undetermined) counts as not told from the null
                parts.append(f"{comp} {v0:.3g} -> {v:.3g} ± {s:.2g} (no longer told from {null:g})")
    return ", ".join(parts)


def null_on_bound(ext: QuadrotorModel, name: str) -> bool:
    """Whether a parameter of effect ``name`` has its null value on its lower bound (a
    one-sided test: chi-bar-square)."""
    return any(par.effect == name and par.lower >= min(par.null, par.upper) for par in ext.parameters)


def queue_refit_builds(model: QuadrotorModel, res: FitResult, names: Sequence[str], n_sub: "int | Substeps",
                       prediction_plans: "Sequence[int | Substeps]" = ()) -> None:
    """Compile the refit step functions (blocks, line search, start-state estimation) of candidates ``names`` in
    the background, one compiler at a time, in the order they will be refitted: the refits
    go on meanwhile (the first on the virtual machine) and the later ones find their
    libraries ready. A round's models are new structures (the last round's verdict is in
    them), so a fresh compile cache would otherwise make each refit wait for its own.
    ``n_sub``: the fit's sub-steps (:func:`~greybox.integrate.log_substeps` of the estimation
    logs); ``prediction_plans``: those of each log predicted on (each log's own: a log's
    dropped rows give its plan more branches), default ``n_sub``."""
    from ..codegen import queue_builds
    functions = []
    for ext, free_idx in _refit_structures(model, res, names):
        functions.extend(ShootingProblem.shared_step_functions(ext, free_idx, n_sub).values())
        # its predictions' start states
        functions.extend(ShootingProblem.shared_step_functions(ext, [], plan)["blocks"]
                         for plan in dict.fromkeys(prediction_plans or [n_sub]))
    queue_builds(functions)


def _refit_structures(model: QuadrotorModel, res: FitResult, names: Sequence[str]
                      ) -> list[tuple[QuadrotorModel, list[int]]]:
    """Each candidate's extended model and the free parameter indices its refit fits."""
    out = []
    for name in names:
        ext, _, free = extended_model(model, res, name)
        out.append((ext, free_indices(ext, free, None)))
    return out


def precompile_refits(model: QuadrotorModel, res: FitResult, names: Sequence[str], n_sub: "int | Substeps") -> None:
    """Compile the refit step functions of candidates ``names`` at once, unoptimised, two
    compilers in parallel: for the cold refits of every candidate, where each is known to
    need its blocks (ten quick builds beat ten optimised ones, and ten builds one after the
    other: the paper demo took 105 s that way against 75 s)."""
    from ..codegen import precompile
    precompile([ShootingProblem.shared_step_functions(ext, free_idx, n_sub)["blocks"]
                for ext, free_idx in _refit_structures(model, res, names)], opt="-O0")


TIMING_ALPHA = 0.01
"""Significance at which :func:`row_timing_words` says the logged rotor speeds look like samples
of a signal varying between rows (the diagnosis's own level, ``ranking.ALPHA``)."""


NOTHING_BEHIND = 0.5
"""p-value of the blend toward the previous row above which :func:`row_timing_words` takes it
to explain nothing: noise on the speeds, which it would average as the blend toward the next row
does, is then not what makes the next row significant."""


def row_timing_words(res: FitResult, logs: Sequence[FlightLog], compile: str = "cached") -> list[str]:
    """Words for a certified fit of a model without the log's timing (``sampled_inputs``) on
    rotor-speed logs, when the timing's score test at the fit's optimum says the logged speeds
    are samples of a signal varying between rows: held, they lag it by up to half a row, which
    a fitted lag or delay of the inputs (an effect's
    :attr:`~greybox.effects.Effect.input_timed` parameters) takes (a blind audit's 40-ms motors
    behind commands sampled at 100 Hz rows: ``tau_m`` 36.3 ± 0.05 ms, 71 std off, certified and
    silent; 39.5 with the timing), or the certificate's misfit may be (the audit's control
    flights: "the shooting gaps of vz are mostly systematic: a force or torque the model
    lacks"), or else the parameters may carry (its one-flight control fit: ``b`` +0.87 %,
    6.4 std). Noise on the speeds favours a blend toward the next row and one toward the
    previous row alike, so it is said only where the next row explains significantly more than
    the previous one (:meth:`~greybox.effects.SampledInputs.toward_previous_row`) and the blend
    along the speeds' central difference
    (:meth:`~greybox.effects.SampledInputs.toward_central_difference`) is significant, with its
    scale taken from the data (:func:`robust_screen`), or the previous row explains nothing
    (:data:`NOTHING_BEHIND`: no noise to average). ``[]`` otherwise."""
    model = res.model
    timed = [n for e in model.effects for n in e.input_timed if any(c.startswith(n) for c in res.free_names)]
    off = res.certificate is not None and not res.certificate.adequate
    name = fx.SampledInputs.name
    if not res.converged or any(e.describes_sampling for e in model.effects) \
            or any(c not in lg.input_names for c in fx.SampledInputs.considered_when_logged for lg in logs):
        return []
    sigma = fit_weights(res)
    try:
        stat, df = screen(model, res, logs, name, sigma, compile)
    except (GreyboxInputError, ValueError, np.linalg.LinAlgError, RuntimeError):
        return []      # words on the fit only: where the statistic cannot be had, nothing is said
    p = float(stats.chi2.sf(stat, max(df, 1)))
    if not p < TIMING_ALPHA:
        return []
    # White noise on the speeds is averaged by a blend with the next row, and so by one with the
    # previous row (a half-row delay) alike (a blind audit's hexacopter, commands held exactly
    # with 3 rad/s of telemetry noise: 975 toward the next row, 1682 toward the previous, said as
    # "samples of a varying signal"). Along their difference, the central difference of the
    # speeds, the noise's share cancels on average and a timing's stays; and the noise is a
    # random forcing the weights do not hold, so that statistic's scale is taken from the data
    # (robust_screen: greybox's own held flights with 0.5-1 rad/s of noise, 12-16 plain, at most
    # 5 robust; speeds varying between rows: 9-180)
    try:
        central = robust_screen(model, res, [fx.SampledInputs.toward_central_difference(lg) for lg in logs], name,
                                sigma, compile)
        behind, _ = screen(model, res, [fx.SampledInputs.toward_previous_row(lg) for lg in logs], name, sigma,
                           compile)
    except (GreyboxInputError, ValueError, np.linalg.LinAlgError, RuntimeError):
        return []
    # both: the next row beyond the previous, and the central difference (each alone has let
    # noise through: the difference on greybox's own held flights, 357 against 119; the central
    # statistic, 6.98, on a blind audit's held speeds under 5 rad/s of noise, 3.9e4 against 1.8e5)
    # Or the previous row explains nothing at all: then no noise is there to average, which either
    # blend would (a blind audit's ESC telemetry, smoothed: the next row 1193, the previous 0,
    # the central statistic 5.6 on what the smoother left; the diagnosis's refit s_lead 0.525 ±
    # 0.022, Kd[2] 3.4 std high with the rows held and nothing said)
    nothing_behind = stats.chi2.sf(behind, max(df, 1)) > NOTHING_BEHIND
    if not (stats.chi2.sf(stat - behind, max(df, 1)) < TIMING_ALPHA
            and (stats.chi2.sf(central, 1) < TIMING_ALPHA or nothing_behind)):
        return []
    half_row = 0.5 * median_row_interval(logs)
    takes = (f"the fitted {', '.join(timed)} takes the difference beyond its std" if timed else
             "what the certificate finds the model misses may be this timing, not a force or torque" if off else
             "the fitted parameters may carry it beyond their std")
    # noise favours the previous row too: where that is significant, part of the next row's gain
    # may be the noise (held commands under 5 rad/s of noise: 357 against 119), said as such
    noise = (f"; a blend toward the previous row (a half-row delay) fits better too ({behind:.3g}): noise on the "
             "speeds, which either blend averages, may be part of it"
             if stats.chi2.sf(behind, max(df, 1)) < TIMING_ALPHA else "")
    return [f"the logged rotor speeds look like samples of a signal that varies between the log's rows, not "
            f"values held until the next row (score test of {name}: {stat:.3g}, p = {p:.2g}; along the speeds' central "
            f"difference, scaled by the data: {central:.3g}{noise}"
            f"{'; toward the previous row: nothing, so no noise to average' if nothing_behind else ''}): held, they lag it "
            f"by up to half a row ({1e3 * half_row:.3g} ms), and {takes}; add the effect {name} "
            f"(--effects {name}), or diagnose, which judges the log's timing first"]

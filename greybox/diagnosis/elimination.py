"""Backward elimination (step 4 of :func:`~greybox.diagnosis.diagnose`): does each verdict
of the rounds still stand in the final model, with the later verdicts in it?

Forward selection adds the best candidate of each round against the model of that round. A
verdict of an early round can be a partial stand-in for what a later round names (a thrust
that drifts in time standing in for a battery that sags), and once the later effect is in,
it explains nothing more. Each earlier verdict is therefore judged again against the final
model less itself, by the test that admitted it: likelihood ratio (Bonferroni over its round's
candidates) and effect size; its confirmation on the validation data stays its round's. A
cheap Wald screen on the final fit comes first: a verdict whose parameters are still far from
their null values there (:data:`WALD_MARGIN`) and not physically negligible stands without a
refit; every other is refitted out of the model.
"""
from __future__ import annotations

import time
import warnings as _warnings
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy import stats

from ..data import FlightLog
from ..errors import ConvergenceWarning
from ..fitting import FitResult, fit
from ..validation import Prediction, predict_after_fit
from .analysis import estimation_residuals
from .ranking import ALPHA
from .screening import lr_test, negligible_effect, null_on_bound

__all__ = ["WALD_MARGIN", "Removal", "wald_p_value", "fit_without", "judge_removal", "backward_elimination"]

WALD_MARGIN = 1e-3
"""A verdict stands without a refit when its Wald p-value on the final fit (Bonferroni over
its round's candidates) is below this share of :data:`~greybox.diagnosis.ALPHA`: the Wald and
likelihood-ratio statistics agree only near the null, so only a verdict far past the line is
spared its refit (on real flights every verdict's is, at no cost)."""


@dataclass
class Removal:
    """What the final model less one verdict says about it. ``stands``: it passes its round's
    test again; ``reason``: why or why not, in words; ``fit`` and ``prediction``: the
    certified refit without it (None when it stood on the Wald screen or the refit was not
    certified; the prediction only when it is left out)."""

    effect: str
    stands: bool
    reason: str
    lr: float | None = None
    p_value: float | None = None
    fit: FitResult | None = None
    prediction: Prediction | None = None


def _effect_free(res: FitResult, effect: str) -> dict[str, float]:
    """``{component: null value}`` of ``effect``'s free parameter components in ``res``."""
    return {comp: null for _, comp, null in res.model.effect_components(effect) if comp in res.free_names}


def _degrees_of_freedom(res: FitResult, effect: str) -> int:
    """Free parameter components of ``effect`` in ``res``, each flight's copy counted."""
    return sum(len(res.per_flight_[c]["value"]) if c in res.per_flight_ else 1 for c in _effect_free(res, effect))


def wald_p_value(res: FitResult, effect: str, n_tests: int = 1) -> float:
    """The Wald test of ``effect``'s free parameters against their null values on the fit
    ``res`` (its covariance, which counts the residuals' colour), halved where the null is on
    a bound, times ``n_tests`` (Bonferroni); 1.0 when it has no free parameter or a singular
    covariance block."""
    free = _effect_free(res, effect)
    if not free:
        return 1.0
    idx = [res.free_names.index(c) for c in free]
    d = np.array([res.value(c) - null for c, null in free.items()])
    C = res.covariance[np.ix_(idx, idx)]
    try:
        w = float(d @ np.linalg.solve(C, d))
    except np.linalg.LinAlgError:
        return 1.0
    if not np.isfinite(w):
        return 1.0
    p = float(stats.chi2.sf(max(w, 0.0), len(free)))
    if null_on_bound(res.model, effect):
        p *= 0.5
    return min(1.0, p * n_tests)


def fit_without(res: FitResult, effects: str | Sequence[str], est: Sequence[FlightLog], compile: str = "auto",
                max_iter: int = 200) -> FitResult:
    """The fit ``res`` refitted without ``effects`` (one name or several), warm-started at its
    values, in its formulation (weights, interval, process noise of the states that remain,
    node states); certified or not, as :attr:`FitResult.converged` says (no warning)."""
    full = res.model
    reduced = full.without(*([effects] if isinstance(effects, str) else effects))
    keep = [full.state_names.index(s) for s in reduced.state_names]
    kw = res.settings()
    kw["initial_states"] = [np.asarray(x)[:, keep] for x in kw["initial_states"]]
    if kw["process_noise"] is not None:
        kw["process_noise"] = {s: q for s, q in kw["process_noise"].items() if s in reduced.state_names}
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", ConvergenceWarning)   # judged by the caller: certified or not
        return fit(reduced, est, free=[n for n in res.free_names if n in reduced.param_names],
                   p0=np.array([res.value(n) for n in reduced.param_names]), compile=compile, max_iter=max_iter,
                   **kw)


def judge_removal(res: FitResult, pred: Prediction, effect: str, est: Sequence[FlightLog],
                  val: Sequence[FlightLog], n_tests: int, compile: str = "auto") -> Removal:
    """Whether ``effect`` still stands in the certified fit ``res`` (validation prediction
    ``pred``) by the test that admitted it in its round: significant (likelihood ratio against
    the certified refit without it, Bonferroni over ``n_tests``) and not physically
    negligible. First the Wald screen (:data:`WALD_MARGIN`). Its confirmation on the validation
    data is its round's (a verdict is not judged there again: on two real Crazyflie flights
    the drag moment, p = 0 in the final model and cutting the 0.5-s psi or theta error by
    16-41 %, raised the total nrmse by 7-10 % and would have gone)."""
    small = negligible_effect(res, effect, est)
    p_wald = wald_p_value(res, effect, n_tests)
    if not small and p_wald < WALD_MARGIN * ALPHA:
        return Removal(effect, True, f"Wald p = {p_wald:.2g} on the final fit")
    reduced = fit_without(res, effect, est, compile)
    if not reduced.converged:
        return Removal(effect, True, f"the refit without it is not certified ({reduced.status}): cannot tell, kept")
    lr, p = lr_test(reduced, res, estimation_residuals(res.model, res, est), _degrees_of_freedom(res, effect),
                    null_on_bound(res.model, effect), n_tests)
    if p < ALPHA and not small:
        return Removal(effect, True, f"LR {lr:.3g}, p = {p:.2g} against the refit without it", lr, p, reduced)
    why = (f"not significant once the others are in (LR {lr:.3g}, p = {p:.2g})" if p >= ALPHA else
           f"physically negligible once the others are in: {small}")
    return Removal(effect, False, why, lr, p, reduced,
                   predict_after_fit(reduced, est, val, compile=compile, horizon=pred.horizon))


def backward_elimination(res: FitResult, pred: Prediction, verdicts: Sequence[tuple[str, int]],
                         est: Sequence[FlightLog], val: Sequence[FlightLog], compile: str = "auto",
                         say: Callable[[str], None] = lambda _m: None
                         ) -> tuple[FitResult, Prediction, list[Removal]]:
    """The certified final fit ``res`` (prediction ``pred``) less the ``verdicts`` that no
    longer stand (:func:`judge_removal`), one at a time. ``verdicts``: ``(effect, n_tests)``
    in the order the rounds added them, ``n_tests`` its round's candidates. The last verdict
    was judged against all the others by its round; it is judged again too, at no cost when
    the Wald screen spares it: admitted against a fit that had not found the others' best
    values, it can be a collinear partner they no longer need (an audit's H-frame: a drag
    moment 0.3 std from zero beside a hub drag whose height took its place). Returns the
    final fit, its prediction and the removals (each with why)."""
    order = [e for e, _ in verdicts]
    tests = dict(verdicts)
    removed: list[Removal] = []
    if len(order) < 2 or not res.converged:
        return res, pred, removed
    pending = list(order)
    while pending:
        effect = pending.pop(0)
        if effect not in res.model.effect_names:
            continue
        t0 = time.perf_counter()
        r = judge_removal(res, pred, effect, est, val, tests[effect], compile)
        say(f"diagnose: does {effect} still stand with the later verdicts? "
            f"{'yes' if r.stands else 'no'} ({r.reason}; {time.perf_counter() - t0:.1f} s)")
        if r.stands:
            continue
        removed.append(r)
        res, pred = r.fit, r.prediction
        # with one gone, each other verdict is judged again against the new fit (the last too)
        pending = [e for e in order if e in res.model.effect_names]
    return res, pred, removed

"""Consistency of the fitted parameters: fitted on each half of the estimation data, a
constant of the vehicle agrees with itself; a parameter absorbing a missing effect follows
what each half happens to exercise (the baseline's), and a parameter whose standard deviation
understates its scatter disagrees with itself beyond it (the final model's)."""
from __future__ import annotations

import math
import warnings as _warnings
from typing import Callable, Sequence

import numpy as np

from .. import effects as fx
from ..data import FlightLog
from ..errors import ConvergenceWarning, GreyboxError
from ..fitting import FitResult, fit, per_flight_positions
from ..model import QuadrotorModel
from ..residuals import residual_widening

__all__ = ["CONSISTENCY_Z", "CONSISTENCY_MIN_CHANGE", "UNDETERMINED_SHARE", "half_consistency", "half_spread",
           "validation_spread", "undetermined_parameters"]


CONSISTENCY_Z = 3.0
"""A parameter whose estimates on the two halves of the estimation data differ by more than
this many standard deviations (of the difference) is flagged as absorbing something else."""
CONSISTENCY_MIN_CHANGE = 0.02
"""...and by more than this fraction of its size (the larger estimate, or a plausible size of
its effect on the airframe when that is larger): two estimates 0.2 % apart are the same
constant, however small their standard deviations (another simulator's 1.2 kg vehicle with a
gyro bias: b 1.697e-7 ± 7e-11 against 1.700e-7 ± 6e-11 had been flagged)."""

UNDETERMINED_SHARE = 0.5
"""A fitted parameter whose standard deviation exceeds this share of the whole range its bounds
allow is not determined by the data at all: its value says nothing."""


def undetermined_parameters(res: FitResult, effects: Sequence[str]) -> list[str]:
    """Words on the free parameters of ``effects`` in ``res`` that the data do not determine:
    standard deviation above :data:`UNDETERMINED_SHARE` of the range between their (finite)
    bounds, each with the parameter it trades with most (largest correlation). An audit's
    H-frame with a body-axis drag: a hub drag's height -0.039 ± 0.83 m (bounds ± 0.27 m)
    beside a drag moment that explains the same pitching."""
    model = res.model
    std = dict(zip(res.free_names, map(float, res.std)))
    C = np.asarray(res.covariance, dtype=float)
    d = np.sqrt(np.clip(np.diag(C), 0.0, None))
    out = []
    for effect in effects:
        for par, comp, _null in model.effect_components(effect):
            width = par.upper - par.lower
            s = std.get(comp, math.nan)
            if not (np.isfinite(width) and width > 0 and np.isfinite(s)) or s <= UNDETERMINED_SHARE * width:
                continue
            i = res.free_names.index(comp)
            with np.errstate(invalid="ignore", divide="ignore"):
                r = C[i] / (d[i] * d)
            r[i] = 0.0
            r = np.where(np.isfinite(r), r, 0.0)
            words = (f"{comp} = {res.value(comp):.3g} ± {s:.2g} {par.unit} is not determined by these data: its std "
                     f"is {s / width:.1f}x the whole range it may take ({par.lower:.3g} to {par.upper:.3g} {par.unit})")
            if r.size > 1 and np.max(np.abs(r)) > 0.5:
                j = int(np.argmax(np.abs(r)))
                partner = res.free_names[j]
                owner = next(q.effect for q in model.parameters if partner in q.component_names)
                owner = "the base model" if owner == "base" else owner
                words += (f"; it trades with {partner} (r = {r[j]:+.2f}, {owner})"
                          + (", and the two effects share what they explain" if owner != effect else ""))
            out.append(words)
    return out


def half_consistency(model: QuadrotorModel, res: FitResult, est: Sequence[FlightLog], E: np.ndarray,
                     compile: str, say: Callable[[str], None]
                     ) -> dict[str, tuple[float, float, float, float]] | None:
    """Fit each half of the estimation data (warm-started at the baseline, its weights) and
    return the parameters whose two estimates disagree, ``{name: (first, first_std, second,
    second_std)}`` (None when a half cannot be fitted or its fit is not certified: nothing
    was compared): a constant of the vehicle is the same in both halves; a parameter absorbing
    a missing effect follows what each half happens to exercise.

    They disagree when they differ by more than :data:`CONSISTENCY_Z` standard deviations of
    the difference counted two ways, and by more than :data:`CONSISTENCY_MIN_CHANGE` of the
    parameter's size: with the half fits' white-residual (Gauss-Newton) std widened by the
    square root of the median long-run variance factor of the baseline's residual channels
    (``E``), and with each half's own std (its reported one, a sandwich per parameter that
    counts the colour of the residuals it is fitted from; never below the first), which the
    returned std are. Residuals coloured in the channels a parameter rests on widen its
    scatter far beyond the median channel's: a blind audit's racer with an estimator's slow
    attitude error and nothing missing had ``Kd[0]``'s halves 0.0586 and 0.0616 (5 %) at 37
    std of the first count but 1.8 of the second (the fit on all of it: 0.0603 ± 0.0010, truth
    0.060), on three of three such flights; its thrust drifting 0.4 %/s stays flagged (K_T
    halves 5.7 % apart, 7 std of their own). A ``b`` whose halves differ only within their own
    std is no evidence of a closed-loop bias either: the same racer's acceleration reaction
    torque had ``b``'s halves 8.7 % apart (14 std of the first count, 2.4 of the second) and
    the disturbance refit's ``b``, 18 % below a fitted ``b`` 1.4 % from the truth, was offered
    as the one to take."""
    out: dict[str, tuple[float, float, float, float]] = {}
    fits = _half_fits(model, res, est, compile, say)
    if fits is None:
        return None
    a, b = fits
    widen = residual_widening(E, res.sigma)
    sizes = _plausible_sizes(model, res)
    within: list[str] = []
    sampling = {comp for e in res.model.effects if e.describes_sampling
                for _, comp, _ in res.model.effect_components(e.name)}
    for i, n in enumerate(res.free_names):
        if n in res.per_flight_ or n in sampling:
            continue    # a wind or battery sag of other flights, the log's sampling: no reason to agree
        sa, sb = (widen * float((f.white_std if f.white_std is not None else f.std)[i]) for f in (a, b))
        if not (np.isfinite(sa) and np.isfinite(sb)) or sa + sb <= 0:
            continue
        diff = abs(a.value(n) - b.value(n))
        size = max(abs(a.value(n)), abs(b.value(n)), sizes.get(n, 0.0))
        if not (diff / math.hypot(sa, sb) > CONSISTENCY_Z and diff > CONSISTENCY_MIN_CHANGE * size):
            continue
        # each half's own std (an undefined one leaves the widened white one)
        ca, cb = (max(s, float(f.std[i])) if np.isfinite(f.std[i]) else s for s, f in ((sa, a), (sb, b)))
        if diff / math.hypot(ca, cb) > CONSISTENCY_Z:
            out[n] = (a.value(n), ca, b.value(n), cb)
        else:
            within.append(n)
    say("diagnose: halves of the estimation data " +
        (f"disagree on {', '.join(out)}" if out else "agree on every parameter" if not within else
         "agree within their own std") +
        (f" ({', '.join(within)} apart on the white screen, within what the colour of their residuals gives)"
         if within else ""))
    return out


def half_spread(model: QuadrotorModel, res: FitResult, est: Sequence[FlightLog], components: Sequence[str],
                compile: str, say: Callable[[str], None]) -> "dict[str, tuple[float, float, float, float]] | None":
    """Fit each half of the estimation data (warm-started at ``res``, its weights) and return
    those of ``components`` whose two estimates differ by more than :data:`CONSISTENCY_Z` of
    the difference's standard deviation (the half fits' reported ones, sandwich included):
    ``{name: (first, first_std, second, second_std)}``. Unlike :func:`half_consistency` there
    is no size floor: this asks whether ``res``'s std can be believed, not whether the value
    is a constant of the vehicle. A std that counts the noise as white understates a mean the
    fit takes from noise correlated over many samples, when the states follow that noise (the
    peer simulator's attitude bias outdoors, AR(1) attitude noise over 0.1 s: 2e-5 rad where
    the error scatters by 2.4e-4). None when a half cannot be fitted or its fit is not
    certified (nothing was compared: no word on whether the std can be believed)."""
    wanted = [n for n in components if n in res.free_names and n not in res.per_flight_]
    if not wanted:
        return {}
    fits = _half_fits(model, res, est, compile, say)
    if fits is None:
        say("diagnose: the final model's halves not compared (a half's fit failed or is not certified)")
        return None
    out = _disagreeing(*fits, wanted)
    say("diagnose: the final model's halves " +
        (f"disagree beyond their std on {', '.join(out)}" if out else f"agree on {', '.join(wanted)}"))
    return out


def validation_spread(model: QuadrotorModel, res: FitResult, val: Sequence[FlightLog], components: Sequence[str],
                      compile: str, say: Callable[[str], None],
                      tails: bool = False) -> "dict[str, tuple[float, float, float, float]] | None":
    """Fit the validation flights alone (warm-started at ``res``, its weights) and return
    those of ``components`` whose estimate there differs from ``res``'s by more than
    :data:`CONSISTENCY_Z` of the difference's standard deviation: ``{name: (estimation, std,
    validation, std)}``. The same question as :func:`half_spread` asked of independent data:
    the halves of one flight can agree by chance on a mean they both take from slow noise (the
    peer simulator's attitude bias outdoors, seed 5: roll 23 std off, halves within theirs),
    another flight's noise is another draw. ``tails``: the validation logs are the estimation
    flights' own tails (a split), each fitted with its flight's process noise; otherwise they
    are other flights, fitted with the first estimation flight's, and the parameters of a
    flight's conditions (:attr:`~greybox.effects.Effect.per_flight`: a wind, a battery's sag)
    are not compared (another flight has its own). None when the validation flights cannot be
    fitted alone or their fit is not certified (nothing was compared)."""
    wanted = [n for n in components if n in res.free_names and n not in res.per_flight_]
    if not tails:
        conditions = {res.free_names[j] for j in per_flight_positions(model, list(res.free_names), "auto")}
        wanted = [n for n in wanted if n not in conditions]
    if not wanted or not val:
        return {}
    flights = list(range(len(val))) if tails else [0] * len(val)
    try:
        with _warnings.catch_warnings():
            _warnings.simplefilter("ignore", ConvergenceWarning)
            other = fit(model, list(val), p0=res.p, free=res.free_names, compile=compile, max_iter=100,
                        **res.settings(states=False, flights=flights))
    except GreyboxError as e:
        say(f"diagnose: the validation flights not fitted alone ({e})")
        return None
    if not other.converged:
        say("diagnose: the validation flights' own fit is not certified: not compared")
        return None
    out = _disagreeing(res, other, wanted)
    say("diagnose: the final model on the validation flights " +
        (f"disagrees beyond its std on {', '.join(out)}" if out else f"agrees on {', '.join(wanted)}"))
    return out


def _disagreeing(a: FitResult, b: FitResult, names: Sequence[str]) -> dict[str, tuple[float, float, float, float]]:
    """Those of ``names`` whose estimates in the fits ``a`` and ``b`` differ by more than
    :data:`CONSISTENCY_Z` of the difference's std (their reported ones): ``{name: (a, std, b, std)}``."""
    out: dict[str, tuple[float, float, float, float]] = {}
    for n in names:
        sa, sb = float(a.std[a.free_names.index(n)]), float(b.std[b.free_names.index(n)])
        if not (np.isfinite(sa) and np.isfinite(sb)) or sa + sb <= 0:
            continue
        if abs(a.value(n) - b.value(n)) / math.hypot(sa, sb) > CONSISTENCY_Z:
            out[n] = (a.value(n), sa, b.value(n), sb)
    return out


def _half_fits(model: QuadrotorModel, res: FitResult, est: Sequence[FlightLog], compile: str,
               say: Callable[[str], None]) -> "tuple[FitResult, FitResult] | None":
    """``res``'s model fitted on each half of the estimation data (one flight: its halves in
    time; several: the first half of the flights against the second), warm-started at ``res``
    with its weights; None when a half cannot be fitted or a fit is not certified."""
    if len(est) == 1:
        halves = [[h] for h in est[0].split(0.5)]
        flights = [[0], [0]]
    else:   # several flights: the first half of the flights against the second
        k = len(est) // 2
        halves = [list(est[:k]), list(est[k:])]
        flights = [list(range(k)), list(range(k, len(est)))]
    try:
        with _warnings.catch_warnings():
            _warnings.simplefilter("ignore", ConvergenceWarning)
            # each half with its own flights' process noise (a 2-flight baseline's is given per flight)
            fits = [fit(model, half, p0=res.p, free=res.free_names, compile=compile, max_iter=100,
                        **res.settings(states=False, flights=f))
                    for half, f in zip(halves, flights)]
    except GreyboxError as e:   # a half too short or too poor to fit: no verdict on consistency
        say(f"diagnose: halves not compared ({e})")
        return None
    if not all(f.converged for f in fits):
        return None
    return fits[0], fits[1]


def _plausible_sizes(model: QuadrotorModel, res: FitResult) -> dict[str, float]:
    """A plausible magnitude of each parameter component for the airframe (its effect's
    :meth:`~greybox.effects.Effect.plausible_values`, about its null), where one is known."""
    kt = res.value("K_T") if "K_T" in model.param_names else 0.0
    out: dict[str, float] = {}
    if not kt > 0:
        return out
    for par in model.parameters:
        if not par.effect:
            continue
        v = fx.example_values(par.effect, model.airframe, kt).get(par.name)
        if v is None:
            continue
        vals = np.resize(np.abs(np.atleast_1d(np.asarray(v, dtype=float)) - par.null), par.size)
        out.update({c: float(x) for c, x in zip(par.component_names, vals)})
    return out

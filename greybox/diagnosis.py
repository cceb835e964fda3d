"""Find the missing physics: compare, see where the model fails, rank the missing effects.

The workflow (:func:`diagnose`):

1. **Compare.** Fit the model on the estimation part (first 80 %), predict the validation
   part (k-step ahead, :mod:`greybox.validation`): ``nrmse`` per channel and in total. With
   a separate validation flight (``validation=``) the whole log is the estimation data and
   that flight is predicted instead: a validation nrmse can only confirm an effect that the
   validation data exercise, and the last 20 % of one flight may not (drag needs speed).
2. **Where it fails.** Residuals of the fitted trajectory on the estimation part: whiteness
   (autocorrelation against the 99 % band of white noise, as MATLAB's ``resid``),
   cross-correlation with the inputs, and the *regimes* where the error concentrates — the
   rank correlation (Spearman) of each channel's error envelope with speed (world and body
   frame), vertical speed, height above the ground, thrust level, yaw rate, rotor-speed
   spread, acceleration and time — said in words with the correlation.
3. **Which effect is missing.** Every catalogue effect not in the model is a candidate.
   *Screening*: from the baseline optimum, one Gauss–Newton step of the model extended by
   the candidate (its parameters starting at their null values) predicts the cost decrease,
   i.e. the score (Lagrange-multiplier) statistic — one evaluation per candidate, no fit.
   The best few are then *refitted* (warm-started, same weights): the likelihood-ratio
   statistic ``2 (C0 - C1)``, divided per channel by the long-run variance factor of the
   refitted residuals (Bartlett-weighted autocorrelation, so coloured noise does not
   masquerade as information), is compared with chi-square(df) (halved where the null
   value is on a bound), Bonferroni-corrected over the candidates. A candidate is
   *significant* when that test passes at 1 % **and** the validation ``nrmse`` falls by at
   least 2 % (out-of-sample confirmation). The verdict is the best significant candidate,
   or ``None``.
4. **Add it and watch the error fall.** With ``iterate=True`` the verdict is added, the
   model refitted and the remaining candidates screened again, until nothing significant
   is missing. Candidates that were significant alone but explain nothing once the winner
   is in are reported as confusable, with the manoeuvre that would tell them apart.
"""
from __future__ import annotations

import base64
import html
import math
import time
import warnings as _warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import casadi as ca
import numpy as np
from scipy import stats

from . import effects as fx
from .data import FlightLog, atomic_write
from .errors import ConvergenceWarning, GreyboxError, GreyboxInputError
from .fitting import FitResult, FitSession, fit, progress_printer
from .shooting import ShootingProblem, free_indices, initial_node_states
from .integrate import n_substeps, rk4_step
from .model import OUTPUTS, QuadrotorModel, rotation_matrices
from .residuals import fitted_trajectory, long_run_factor, output_residuals, whiteness_fraction
from .validation import Prediction, predict_flights

__all__ = ["diagnose", "Diagnosis", "CandidateResult", "Finding", "residual_analysis", "ALPHA",
           "MIN_VALIDATION_GAIN", "distinguishing_manoeuvre",
           "CommandImbalance", "command_imbalance", "default_candidates"]

ALPHA = 0.01
"""Family-wise significance level of the likelihood-ratio tests (Bonferroni over candidates)."""
MIN_VALIDATION_GAIN = 0.05
"""Relative fall of some channel's validation nrmse that confirms a candidate out of sample
(while the total nrmse may not rise by more than :data:`MAX_VALIDATION_LOSS`)."""
MAX_VALIDATION_LOSS = 0.01
N_REFIT = 4
"""Candidates refitted after screening (the rest keep their screening statistic)."""
NEGLIGIBLE_FRACTION = 0.01
"""An effect whose fitted parameters are all below this fraction of their physically plausible
magnitude for the airframe (:func:`greybox.effects.example_values`) is negligible: never the
verdict, whatever its likelihood ratio."""
UNEXPLAINED_RATIO = 3.0
"""With a null verdict, channels whose residual RMS stays above this multiple of the sensor
noise (and coloured) are reported as what the model misses beyond every candidate."""
CONSISTENCY_Z = 3.0
"""A parameter whose estimates on the two halves of the estimation data differ by more than
this many standard deviations (of the difference) is flagged as absorbing something else."""

# What the diagnosis knows about each effect (the manoeuvre that excites it, the channels it
# moves, the effects it is confusable with) lives on the effect's class: greybox.effects.
distinguishing_manoeuvre = fx.distinguishing_manoeuvre


# ------------------------------------------------------------------------------ results
@dataclass
class Finding:
    """A sentence about where the model fails, with its evidence."""

    channel: str
    variable: str
    r: float
    text: str
    values: np.ndarray | None = field(default=None, repr=False)   # regime variable (subsampled)
    errors: np.ndarray | None = field(default=None, repr=False)   # error envelope at those samples


@dataclass
class CandidateResult:
    """One candidate effect: screening statistic, and for the best few a refit."""

    effect: str
    df: int
    score: float                        # score (LM) statistic from the screening step
    lr: float | None = None             # autocorrelation-corrected likelihood-ratio statistic
    p_value: float | None = None
    significant: bool = False
    nrmse_before: float = float("nan")
    nrmse_after: float | None = None
    channels_after: dict[str, float] | None = None
    fit: FitResult | None = None
    prediction: Prediction | None = None
    reason: str = ""
    unconfirmable: bool = False         # significant in the fit, validation data without power
    explained: float | None = None      # fraction of the baseline's excess residual (above noise) removed

    def as_dict(self) -> dict:
        out = {"effect": self.effect, "significant": bool(self.significant),
               "nrmse_before": _num(self.nrmse_before), "nrmse_after": _num(self.nrmse_after),
               "score": _num(self.score), "lr": _num(self.lr), "p_value": _num(self.p_value),
               "df": self.df, "reason": self.reason, "explained": _num(self.explained)}
        if self.channels_after is not None:
            out["channels_after"] = {k: _num(v) for k, v in self.channels_after.items()}
        if self.fit is not None:
            new = [n for n in self.fit.free_names if _effect_of(self.fit.model, n) == self.effect]
            out["parameters"] = {n: {"value": self.fit.value(n),
                                     "std": float(self.fit.std[self.fit.free_names.index(n)])} for n in new}
        return out


def _num(v):
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _effect_of(model: QuadrotorModel, comp: str) -> str:
    for par in model.parameters:
        if comp in par.component_names:
            return par.effect
    return ""


@dataclass
class Round:
    """One pass of screening and refits."""

    model: QuadrotorModel
    fit: FitResult
    prediction: Prediction
    ranking: list[CandidateResult]
    verdict: str | None


@dataclass
class Diagnosis:
    """Everything :func:`diagnose` found; ``report(dir)`` writes it as HTML with plots.

    Example::

        d = diagnose(model, log, validation=other_flight)
        d.verdict, [c.effect for c in d.ranking]     # 'ground_effect', best first
        print(d.summary()); d.report("report/")      # text; HTML with the plots
        d.final_model, d.final_prediction.total      # the model with what was added
    """

    model: QuadrotorModel
    baseline: FitResult
    baseline_prediction: Prediction
    findings: list[Finding]
    whiteness: dict[str, float]         # fraction of autocorrelation lags outside the 99 % band
    input_correlation: dict[str, tuple[str, float]]
    ranking: list[CandidateResult]
    verdict: str | None
    warnings: list[str]
    rounds: list[Round] = field(default_factory=list)
    final_model: QuadrotorModel | None = None
    final_fit: FitResult | None = None
    final_prediction: Prediction | None = None
    residuals: np.ndarray | None = field(default=None, repr=False)
    regimes: dict[str, np.ndarray] | None = field(default=None, repr=False)
    log: FlightLog | None = field(default=None, repr=False)
    timings: dict[str, float] = field(default_factory=dict)
    validation_source: str = ""        # what the validation nrmse was computed on, in words
    unexplained: dict[str, float] = field(default_factory=dict)   # channel -> residual / sensor noise
    inconsistent: dict[str, tuple[float, float, float, float]] = field(default_factory=dict)
    command_imbalance: "CommandImbalance | None" = None   # rotors driven unequally in steady flight
    # parameter -> (first half, std, second half, std) where the halves disagree

    @property
    def baseline_certified(self) -> bool:
        """Whether the baseline fit is at a certified optimum (else no candidate was tested)."""
        return bool(self.baseline.converged)

    @property
    def fitted_model(self) -> FitResult:
        """The final fitted model (with the effects added; the baseline's when none was): a
        :class:`~greybox.FittedModel` to predict, linearize or ``save``."""
        return self.final_fit if self.final_fit is not None else self.baseline

    def parameter_table(self) -> dict[str, dict[str, float | None]]:
        """The final model's parameters: ``{name: {"value": v, "std": s}}`` (std None when
        held fixed or not determined)."""
        return {n: {"value": _num(v["value"]), "std": None if v["std"] is None else _num(v["std"])}
                for n, v in self.fitted_model.parameters.items()}

    def as_json(self) -> dict:
        """The diagnose JSON (README, "Command line"), plus findings, warnings and the added effects."""
        out = {"baseline": {"nrmse": self.baseline_prediction.total,
                            "channels": dict(self.baseline_prediction.nrmse),
                            "horizons": self.baseline_prediction.horizon_errors().as_dict()},
               "ranking": [c.as_dict() for c in self.ranking],
               "verdict": self.verdict,
               "findings": [f.text for f in self.findings],
               "warnings": list(self.warnings),
               "effects": self.model.effect_names,
               "certificate": self.baseline.certificate.as_dict() if self.baseline.certificate else None,
               "unexplained": {ch: _num(v) for ch, v in self.unexplained.items()},
               "command_imbalance": self.command_imbalance.as_dict() if self.command_imbalance else None,
               "inconsistent_parameters": {n: {"first_half": a, "first_half_std": sa, "second_half": b,
                                               "second_half_std": sb}
                                           for n, (a, sa, b, sb) in self.inconsistent.items()}}
        if self.final_model is not None and self.final_prediction is not None:
            out["added"] = [e for e in self.final_model.effect_names if e not in self.model.effect_names]
            out["final"] = {"effects": self.final_model.effect_names, "nrmse": self.final_prediction.total,
                            "channels": dict(self.final_prediction.nrmse),
                            "horizons": self.final_prediction.horizon_errors().as_dict()}
        out["model"] = {"effects": self.fitted_model.model.effect_names, "parameters": self.parameter_table(),
                        "certified": bool(self.fitted_model.converged)}
        out["time_s"] = self.timings.get("total")
        return out

    def summary(self) -> str:
        """Readable text of steps 1-4."""
        b = self.baseline_prediction
        lines = [f"1. compare: validation nrmse {b.total:.3f} on the {self.validation_source}  (" +
                 ", ".join(f"{c} {v:.3f}" for c, v in b.nrmse.items()) + ")"]
        lines.append("2. where it fails:")
        lines += [f"   - {f.text}" for f in self.findings] or ["   - no regime stands out"]
        if self.command_imbalance is not None and self.command_imbalance.notable:
            lines.append(f"   - {self.command_imbalance.text()}")
        lines.append("3. candidates (best first):")
        for c in self.ranking:
            after = f"{c.nrmse_after:.3f}" if c.nrmse_after is not None else "  -  "
            lr = f"LR {c.lr:10.1f} p={c.p_value:.1e}" if c.lr is not None else f"score {c.score:10.1f}        "
            lines.append(f"   {'*' if c.significant else ' '} {c.effect:<16} {lr}  nrmse {c.nrmse_before:.3f} -> "
                         f"{after}  {c.reason}")
        if not self.baseline_certified:
            lines.append("   (no candidate tested: the baseline fit is not at a certified optimum, and a test "
                         "statistic against it would be meaningless)")
        if self.verdict:
            top = self.ranking[0] if self.ranking else None
            share = (f"; it removes {100 * top.explained:.0f} % of the residual above the sensor noise"
                     if top is not None and top.explained is not None else "")
            lines.append(f"   verdict: {self.verdict}{share}")
            if self.unexplained:
                lines.append(f"   and the model still misses something no candidate explains: {self._far_off()}")
        elif self.unexplained:
            lines.append(f"   verdict: null -- the model is missing something no candidate explains: "
                         f"{self._far_off()} and coloured" + (f"; {self.findings[0].text}" if self.findings else ""))
        elif not self.baseline_certified:
            lines.append("   verdict: null (cannot tell: the baseline fit is not certified)")
        else:
            lines.append("   verdict: null (nothing significant is missing)")
        if self.final_prediction is not None and self.final_model is not None:
            added = [e for e in self.final_model.effect_names if e not in self.model.effect_names]
            f = self.final_prediction
            lines.append(f"4. added {', '.join(added) or 'nothing'}: nrmse {b.total:.3f} -> {f.total:.3f}")
            for ch in b.nrmse:
                change = 100 * (f.nrmse[ch] / b.nrmse[ch] - 1) if b.nrmse[ch] > 0 else 0.0
                lines.append(f"   {ch:<6} {b.nrmse[ch]:8.3f} -> {f.nrmse[ch]:8.3f}  ({change:+.0f} %)")
            for name in self.final_fit.free_names if self.final_fit else []:
                if _effect_of(self.final_model, name) in added:
                    s = self.final_fit.std[self.final_fit.free_names.index(name)]
                    lines.append(f"   {name} = {self.final_fit.value(name):.5g} ± {s:.2g}")
        fm = self.fitted_model
        lines.append("   final model: " + ", ".join(
            f"{n} = {fm.value(n):.4g}" + (f" ± {s:.2g}" if np.isfinite(s) else "")
            for n, s in zip(fm.free_names, fm.std)))
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def _far_off(self) -> str:
        return "residuals in " + ", ".join(f"{ch} ({v:.3g}x the sensor noise)" for ch, v in self.unexplained.items()) + \
            " stay far above the noise"

    def report(self, directory: str | Path) -> Path:
        """Write ``report.html`` (plots embedded) and the plots as PNG files into ``directory``."""
        return _write_report(self, Path(directory))

    def __repr__(self) -> str:
        from .display import diagnosis_text
        return diagnosis_text(self)

    def _repr_html_(self) -> str:
        from .display import diagnosis_html
        return diagnosis_html(self)


# ------------------------------------------------------------------------------ residuals
def _regime_variables(model: QuadrotorModel, X: np.ndarray, log: FlightLog) -> dict[str, np.ndarray]:
    """Flight-condition variables at every sample, from states ``X`` (e.g. smoothed measurements)."""
    af = model.airframe
    ph, th, ps = X[:, 3], X[:, 4], X[:, 5]
    v = X[:, 6:9]
    # body-frame velocity: R^T v
    vb = np.einsum("kji,kj->ki", rotation_matrices(ph, th, ps), v)
    dt = np.gradient(log.t)
    acc = np.gradient(v, axis=0) / dt[:, None]
    n_cmd = len(model.command_names)
    w = log.inputs[:, :n_cmd] if model.inputs == "rotor_speeds" else np.abs(log.inputs[:, :n_cmd])
    return {
        "horizontal speed": np.hypot(v[:, 0], v[:, 1]),
        "body-frame horizontal speed": np.hypot(vb[:, 0], vb[:, 1]),
        "vertical speed": np.abs(v[:, 2]),
        "height above ground": af.ground_z - X[:, 2],
        "thrust level": (w ** 2).sum(axis=1),
        "yaw rate": np.abs(X[:, 11]),
        "rotor speed spread": w.std(axis=1),
        "acceleration": np.linalg.norm(acc, axis=1),
        "time into the flight": log.t - log.t[0],
    }


def _envelope(e: np.ndarray, t: np.ndarray, window: float = 0.2) -> np.ndarray:
    """RMS of the error over a sliding window (NaN-aware), sampled where e is measured."""
    k = np.isfinite(e)
    cs = np.concatenate([[0.0], np.cumsum(np.where(k, e * e, 0.0))])
    cn = np.concatenate([[0.0], np.cumsum(k)])
    lo = np.searchsorted(t, t - window / 2)
    hi = np.searchsorted(t, t + window / 2, side="right")
    n = cn[hi] - cn[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt((cs[hi] - cs[lo]) / n)


IMBALANCE_NOTABLE = 0.03
"""A rotor's steady-flight share of the squared commands this far from the mean (3 %) is
worth telling: more than hover trim tolerances, less than a damaged propeller."""


@dataclass
class CommandImbalance:
    """How unequally the logged rotor speeds share the work in steady flight (level, not
    rotating, not accelerating): evidence a propeller engineer reads before any fit.

    ``share[name]`` is rotor ``name``'s mean ``w^2`` over the mean of all rotors', minus 1;
    ``spin[+1 / -1]`` the same for the two spin directions. A model with equal rotors needs a
    steady torque to explain an imbalance: a weaker rotor (``motor_asymmetry``, thrust and
    torque), a centre of gravity off the middle (``cog_offset``, roll and pitch only), or,
    between spin directions, a yaw-torque difference that drives ``b`` towards zero."""

    share: dict[str, float]
    spin: dict[int, float]
    seconds: float                      # steady flight the averages are taken over

    @property
    def notable(self) -> bool:
        return max(abs(v) for v in self.share.values()) > IMBALANCE_NOTABLE

    def text(self) -> str:
        rotors = ", ".join(f"{n} {100 * v:+.1f} %" for n, v in self.share.items())
        pairs = " vs ".join(f"spin {k:+d} rotors {100 * v:+.1f} %" for k, v in sorted(self.spin.items()))
        return (f"in {self.seconds:.1f} s of steady flight the rotors are driven unequally ({rotors} of the mean "
                f"squared speed; {pairs}): equal rotors would need a steady torque here — a weaker rotor "
                "(motor_asymmetry, thrust and torque), a centre of gravity off the middle (cog_offset), or, between "
                "spin directions, a yaw-torque difference that pulls b towards zero")

    def as_dict(self) -> dict:
        return {"share": dict(self.share), "spin": {str(k): v for k, v in self.spin.items()},
                "seconds": self.seconds, "notable": self.notable}


def command_imbalance(model: QuadrotorModel, log: FlightLog | Sequence[FlightLog], max_rate: float = 0.3,
                      max_tilt: float = 0.15, max_angular_acc: float = 3.0) -> CommandImbalance | None:
    """Per-rotor share of the squared rotor speeds in steady flight (body rates below
    ``max_rate`` rad/s, roll and pitch below ``max_tilt`` rad, angular acceleration below
    ``max_angular_acc`` rad/s²; from the smoothed measurements, no model), over one flight or
    several. None when there is less than a second of it, or the inputs are not rotor speeds."""
    n_rot = model.airframe.n_rotors
    if model.inputs != "rotor_speeds":
        return None
    rows, seconds = [], 0.0
    for lg in ([log] if isinstance(log, FlightLog) else list(log)):
        if len(lg) < 10:
            continue
        X = initial_node_states(model, lg, np.arange(len(lg)))
        rates = X[:, 9:12]
        acc = np.gradient(rates, lg.t, axis=0)
        steady = ((np.abs(rates).max(axis=1) < max_rate) & (np.abs(X[:, 3:5]).max(axis=1) < max_tilt)
                  & (np.abs(acc).max(axis=1) < max_angular_acc))
        seconds += float(np.append(np.diff(lg.t), 0.0)[steady].sum())
        rows.append(lg.inputs[steady, :n_rot] ** 2)
    if seconds < 1.0:
        return None
    mean = np.vstack(rows).mean(axis=0)
    share = {name: float(m / mean.mean() - 1.0) for name, m in zip(model.command_names[:n_rot], mean)}
    spins = model.airframe.spins
    spin = {int(s): float(mean[spins == s].mean() / mean.mean() - 1.0) for s in np.unique(spins)}
    return CommandImbalance(share, spin, seconds)


def residual_analysis(model: QuadrotorModel, res: FitResult, log: FlightLog | Sequence[FlightLog],
                      pred: Prediction | None = None, validation_is_tail: bool = True,
                      min_r: float = 0.4
                      ) -> tuple[list[Finding], dict[str, float], dict[str, tuple[str, float]], np.ndarray,
                                 dict[str, np.ndarray]]:
    """Where the fitted model fails: on ``log`` (the estimation log it was fitted to) and, if
    given, on the k-step-ahead prediction errors of the validation part.

    Returns (findings, whiteness, input correlation, estimation residuals, regime variables):
    ``whiteness[ch]`` is the fraction of the first 30 autocorrelation lags (measured samples)
    outside the 99 % band of white noise; findings are sentences for regimes whose rank
    correlation with the error envelope reaches ``min_r`` (an effect-size threshold). Regime
    variables come from the measurements (smoothed), not from the model under test.
    """
    logs = [log] if isinstance(log, FlightLog) else list(log)
    Es = _flight_residuals(model, res, logs)
    regs = [_regime_variables(model, initial_node_states(model, lg, np.arange(len(lg))), lg) for lg in logs]
    E = np.vstack(Es)
    regimes = {k: np.concatenate([r[k] for r in regs]) for k in regs[0]}
    log = logs[0]
    inputs = np.vstack([lg.inputs for lg in logs])
    whiteness: dict[str, float] = {}
    input_corr: dict[str, tuple[str, float]] = {}
    for c, ch in enumerate(OUTPUTS):
        e = E[:, c]
        k = np.isfinite(e)
        if k.sum() < 50:
            continue
        ek = e[k] - e[k].mean()
        var = float(ek @ ek)
        whiteness[ch] = whiteness_fraction(e)
        best = ("", 0.0)
        for i, name in enumerate(log.input_names):
            u = inputs[k, i] - inputs[k, i].mean()
            r = float(u @ ek) / math.sqrt(max(float(u @ u) * var, 1e-300))
            if abs(r) > abs(best[1]):
                best = (name, r)
        input_corr[ch] = best
    sets = list(zip(Es, logs, regs))
    if pred is not None:
        # per validation flight; the time into the flight counts from its estimation flight's
        # start when the validation part is that flight's end
        for j, part in enumerate(pred.parts or [pred]):
            vlog = part.log
            vreg = _regime_variables(model, initial_node_states(model, vlog, np.arange(len(vlog))), vlog)
            t_start = logs[j].t[0] if validation_is_tail and j < len(logs) else vlog.t[0]
            vreg["time into the flight"] = vlog.t - t_start
            sets.append((part.errors, vlog, vreg))
    best: dict[tuple[str, str], Finding] = {}
    for err, lg, reg in sets:
        for f in _regime_findings(err, lg, reg, min_r):
            key = (f.channel, f.variable)
            if key not in best or abs(f.r) > abs(best[key].r):
                best[key] = f
    per_channel: dict[str, list[Finding]] = {}
    for f in best.values():
        per_channel.setdefault(f.channel, []).append(f)
    findings = [f for fs in per_channel.values() for f in sorted(fs, key=lambda f: -abs(f.r))[:2]]
    findings.sort(key=lambda f: -abs(f.r))
    return findings, whiteness, input_corr, E, regimes


def _regime_findings(E: np.ndarray, log: FlightLog, regimes: dict[str, np.ndarray], min_r: float) -> list[Finding]:
    out = []
    t = log.t
    for c, ch in enumerate(OUTPUTS):
        e = E[:, c]
        k = np.isfinite(e)
        if k.sum() < 50:
            continue
        env = _envelope(e, t)
        sel = np.flatnonzero(k)[:: max(1, k.sum() // 4000)]
        for name, v in regimes.items():
            ok = np.isfinite(env[sel]) & np.isfinite(v[sel])
            if ok.sum() < 30 or np.ptp(v[sel][ok]) == 0:
                continue
            if name == "time into the flight":
                rs = float(stats.spearmanr(e[sel][ok], v[sel][ok])[0])  # a signed drift
                if np.isfinite(rs) and abs(rs) >= min_r:
                    out.append(Finding(ch, name, rs, f"{ch} error drifts steadily over the flight "
                                                     f"(r = {rs:+.2f} with time)", v[sel][ok], e[sel][ok]))
                continue
            r = float(stats.spearmanr(env[sel][ok], v[sel][ok])[0])
            if np.isfinite(r) and abs(r) >= min_r:
                out.append(Finding(ch, name, r, _sentence(ch, name, r, env[sel][ok], v[sel][ok]),
                                   v[sel][ok], env[sel][ok]))
    return out


def _sentence(ch: str, name: str, r: float, env: np.ndarray, v: np.ndarray) -> str:
    if name == "height above ground" and r < 0:
        low = v <= np.quantile(v, 0.1)
        ratio = float(np.sqrt(np.mean(env[low] ** 2) / max(np.mean(env[~low] ** 2), 1e-300)))
        if ratio >= 1.2:
            return (f"{ch} error is largest close to the ground: below {np.quantile(v, 0.1):.2f} m it is "
                    f"{ratio:.1f}x the RMS elsewhere (r = {r:+.2f} with height)")
        # a rank correlation over the whole flight, not a near-ground concentration: say both
        return (f"{ch} error grows as {name} falls (r = {r:+.2f}), but not close to the ground: below "
                f"{np.quantile(v, 0.1):.2f} m it is {ratio:.1f}x the RMS elsewhere")
    if r > 0:
        return f"{ch} error grows with {name} (r = {r:+.2f})"
    return f"{ch} error grows as {name} falls (r = {r:+.2f})"


# ------------------------------------------------------------------------------ candidates
def _extended(model: QuadrotorModel, res: FitResult, name: str) -> tuple[QuadrotorModel, np.ndarray, list[str]]:
    """The model plus effect ``name``, its parameter vector (baseline values, new parameters at
    their null value or lower bound) and the free set (baseline's plus the new parameters)."""
    ext = model + fx.by_name(name)
    base = res.model.parameter_dict(res.p)
    p = ext.default_parameters()
    names = ext.param_names
    new: list[str] = []
    for par in ext.parameters:
        for comp in par.component_names:
            i = names.index(comp)
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
    """The states ``new`` integrated node to node by the extended model, the other states
    held at ``full`` (one ``mapaccum``, no Python loop over samples)."""
    k = np.asarray(idx)
    t = log.t[k]
    h = np.diff(t)
    step = rk4_step(ext, n_substeps(float(max(h.max(), 1e-6))))
    xa = ca.SX.sym("xa", len(new))
    xo = ca.SX.sym("xo", ext.nx)
    u = ca.SX.sym("u", ext.nu)
    pp = ca.SX.sym("p", ext.n_params)
    ts = ca.SX.sym("t")
    hs = ca.SX.sym("h")
    x = ca.SX(xo)
    for i, j in enumerate(new):
        x[j] = xa[i]
    xn = step(x, u, pp, ts, hs)
    f = ca.Function("propagate_new", [xa, xo, u, pp, ts, hs], [xn[new]])
    n = len(k) - 1
    F = f.mapaccum("propagate_acc", n)
    seq = F(full[0, new], full[:-1].T, log.inputs[k[:-1]].T, np.repeat(p[:, None], n, axis=1), t[None, :-1],
            h[None, :])
    return np.vstack([full[0, new], np.asarray(seq).T])


def _screen(model: QuadrotorModel, res: FitResult, logs: Sequence[FlightLog], name: str, sigma: np.ndarray,
            compile: str) -> tuple[float, int]:
    """Score statistic and degrees of freedom of candidate ``name`` at the baseline optimum."""
    ext, p, free = _extended(model, res, name)
    free_idx = free_indices(ext, free, None)
    logs = [ext.prepare_log(lg) for lg in logs]
    ses = FitSession(ext, logs, free_idx, p, sigma, res.interval, "quick" if compile != "never" else compile,
                     lambda _m: None)
    if res.process_noise is not None:
        ses.q = np.array(list(_process_noise(ext, res).values()))
    X = np.vstack(_extend_nodes(ext, res, logs, p))
    th = p[free_idx] / ses.scale
    d = ses.predicted_decrease(X, th)
    return 2.0 * max(d, 0.0), len(free) - len(res.free_names)


def _process_noise(ext: QuadrotorModel, res: FitResult) -> dict[str, float] | None:
    """The baseline's process noise for the extended model's states (same weights, so costs
    compare); new effect states (motor speeds) get a tight 1e-4 of their scale: a candidate
    must explain the data through its physics. With a loose process noise of its own (it
    was 1 %), a state-adding effect such as motor_lag got four free process-noise channels
    that absorbed any torque the model lacks, and a likelihood ratio in the thousands."""
    if res.process_noise is None:
        return None
    w_ref = res.model.hover_speed(res.p)
    return {s: res.process_noise.get(s, 1e-4 * w_ref) for s in ext.state_names}


def _refit(model: QuadrotorModel, res: FitResult, est: Sequence[FlightLog], val: Sequence[FlightLog] | None,
           name: str,
           sigma: dict, compile: str, cold: bool = False, max_iter: int | None = None,
           start: FitResult | None = None) -> tuple[QuadrotorModel, FitResult, Prediction | None]:
    """Fit the model extended by ``name`` with the baseline's weights: warm-started at the
    baseline optimum, or ``cold`` — from the airframe's guesses with the candidate's
    parameters at a plausible magnitude — when the baseline is a compensating solution, or
    continued from ``start`` (an earlier, capped refit). No validation when ``val`` is None."""
    ext, p, free = _extended(model, res, name)
    if start is not None:
        p, init = start.p, start.node_states
    elif cold:
        p = ext.default_parameters()
        kt = p[ext.param_names.index("K_T")]
        p = ext.parameter_vector(fx.example_values(name, ext.airframe, kt), p)
        init = None
    else:
        init = _extend_nodes(ext, res, est, p)
    # a cold start of a still-wrong model can crawl along a compensating valley: cap it, the
    # likelihood ratio against the baseline stays valid for any point reached
    # a soft-continuity refit has a node at every sample: its iterations are dear, and a
    # likelihood ratio at any point reached is a valid lower bound
    cap = 50 if cold else (60 if res.process_noise is not None else 200)
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", ConvergenceWarning)   # a capped refit is judged by its LR
        fr = fit(ext, est, free=free, p0=p, noise=sigma, reweight=False, compile=compile,
                 max_iter=max_iter or cap, initial_states=init, interval=res.interval,
                 process_noise=_process_noise(ext, res))
    return ext, fr, (predict_flights(ext, fr.p, val, compile=compile) if val is not None else None)


def _prediction_change(before: Prediction, after: Prediction) -> dict[str, float]:
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
        err = float(np.sqrt(np.mean(e[k] ** 2))) if k.any() else 0.0
        out[ch] = float(np.sqrt(np.mean(d[k] ** 2))) / err if err > 0 else 0.0
    return out


def _lr_test(base: FitResult, alt: FitResult, alt_resid: np.ndarray, df: int, on_bound: bool,
             n_tests: int) -> tuple[float, float]:
    lr = 0.0
    for c, ch in enumerate(OUTPUTS):
        if ch not in base.channel_cost:
            continue
        f = long_run_factor(alt_resid[:, c] / base.sigma[ch])
        lr += (base.channel_cost[ch] - alt.channel_cost[ch]) / f
    lr += base.process_cost - alt.process_cost   # soft continuity: the gaps are residuals too
    lr = max(lr, 0.0)
    p = float(stats.chi2.sf(lr, df)) if df > 0 else 1.0
    if on_bound:
        p *= 0.5   # chi-bar-square: half the mass sits on the bound
    return lr, min(1.0, p * n_tests)


def _explained_fraction(base: FitResult, alt: FitResult) -> float | None:
    """Fraction of the baseline's excess residual that ``alt`` removes: per channel the
    residual variance above the sensor noise, ``(rms/noise)^2 - 1``, summed over channels.
    1 means the residuals fall to the noise; near 0, the candidate explains a sliver of what
    the model misses, however significant that sliver is."""
    if base.certificate is None or alt.certificate is None:
        return None
    r0, r1 = base.certificate.residual_over_noise, alt.certificate.residual_over_noise
    ex0 = sum(max(r0[ch] ** 2 - 1.0, 0.0) for ch in r0)
    ex1 = sum(max(r1.get(ch, r0[ch]) ** 2 - 1.0, 0.0) for ch in r0)
    return None if ex0 <= 0 else float(1.0 - ex1 / ex0)


def _negligible(fr: FitResult, effect: str) -> str:
    """Words saying that the fitted parameters of ``effect`` are physically negligible (all
    below :data:`NEGLIGIBLE_FRACTION` of their plausible magnitude for the airframe), or ""."""
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
    parts = []
    for par in model.parameters:
        if par.effect != effect:
            continue
        # no plausible size known: a tenth of the parameter's nominal scale
        ref = np.abs(np.atleast_1d(np.asarray(plausible.get(par.name, 0.1 * par.scale), dtype=float)))
        ref = np.resize(np.max(ref), par.size)
        for comp, r in zip(par.component_names, ref):
            v = fr.value(comp) - par.null
            if abs(v) >= NEGLIGIBLE_FRACTION * r:
                return ""
            parts.append(f"{comp} = {fr.value(comp):.3g} {par.unit}".rstrip())
    if not parts:
        return ""
    return f"{', '.join(parts)} (below {100 * NEGLIGIBLE_FRACTION:.0f} % of a plausible size for this airframe)"


def _null_on_bound(ext: QuadrotorModel, name: str) -> bool:
    return any(par.effect == name and par.lower >= min(par.null, par.upper) for par in ext.parameters)


def _precompile(model: QuadrotorModel, res: FitResult, names: Sequence[str], n_sub: int, compile: str,
                what: str) -> None:
    """Compile candidates' step functions at once, two compilers in parallel, before they
    are needed one by one: ``what`` = "screen" (blocks, quick build) or "refit" (blocks and
    line search, optimised; plus the state estimator of the validation part)."""
    if compile == "never":
        return
    from .codegen import precompile
    items, quick = [], []
    for name in names:
        ext, _, free = _extended(model, res, name)
        blk, val, key = ShootingProblem.step_functions(ext, free_indices(ext, free, None), n_sub)
        if what == "screen":
            quick.append((blk, key + "blocks"))
        else:
            items += [(blk, key + "blocks"), (val, key + "value")]
            blk0, _, key0 = ShootingProblem.step_functions(ext, [], n_sub)
            items.append((blk0, key0 + "blocks"))
    if quick:
        precompile(quick, opt="-O0")
    if items:
        precompile(items, opt="-O0" if compile == "quick" else "-O1")


COLD_SCREEN_ITER = 6
"""Iterations each candidate gets from cold before the best few are continued."""
COLD_CONTINUE = (3, 20)
"""How many of the cold-screened candidates are continued, and for how many iterations: the
right model has converged by then; a wrong one is still crawling, and its likelihood ratio
at any point reached is a valid (lower) bound."""


def _rank_round(model: QuadrotorModel, res: FitResult, pred: Prediction, est: Sequence[FlightLog],
                val: Sequence[FlightLog],
                candidates: Sequence[str], compile: str, say: Callable[[str], None], n_refit: int
                ) -> list[CandidateResult]:
    sigma = np.array([res.sigma.get(ch, 1.0) for ch in OUTPUTS])
    n_sub = n_substeps(max(float(np.diff(lg.t).max()) for lg in est))
    t0 = time.perf_counter()
    _precompile(model, res, candidates, n_sub, compile, "screen")
    say(f"  built candidate models ({time.perf_counter() - t0:.1f} s)")
    out: list[CandidateResult] = []
    for name in candidates:
        t0 = time.perf_counter()
        score, df = _screen(model, res, est, name, sigma, compile)
        say(f"  screen {name:<16} score {score:12.1f}  ({time.perf_counter() - t0:.1f} s)")
        out.append(CandidateResult(name, df, score, nrmse_before=pred.total))
    out.sort(key=lambda c: -c.score)
    n_tests = max(len(candidates), 1)

    def score_p(c: CandidateResult) -> float:
        """Bonferroni-corrected p-value of the screening (score) statistic."""
        half = 0.5 if _null_on_bound(model + fx.by_name(c.effect), c.effect) else 1.0
        return min(1.0, float(stats.chi2.sf(c.score, c.df)) * half * n_tests)

    # A baseline with parameters on their bounds is compensating for something: the score,
    # a local statistic at that distorted point, can miss the effect. Then refit them all.
    lo_hi = [(par.lower, par.upper) for par in model.parameters for _ in range(par.size)]
    # a parameter pushed onto a bound is a compensating solution, unless the bound is its
    # null value (no vertical drag is an answer, not a compensation)
    nulls = {c: par.null for par in model.parameters for c in par.component_names}
    at_bound = [n for n in res.free_names
                if any(np.isclose(res.value(n), b, rtol=1e-6, atol=1e-15)
                       for b in lo_hi[model.param_names.index(n)] if np.isfinite(b) and b != nulls[n])]
    if at_bound:
        say(f"  baseline has {', '.join(at_bound)} on a bound: refitting every candidate")
        to_refit = list(out)
    else:
        to_refit = []
        for c in out[:n_refit]:
            p = score_p(c)
            if c.score <= 0:
                c.reason = "no improvement in the allowed direction"
            elif p >= ALPHA:
                # the score statistic is larger than the corrected LR: it cannot become significant
                c.reason = f"score test not significant (p = {p:.2g}), not refitted"
            else:
                to_refit.append(c)
    # refitting every candidate from cold: ten quick builds beat ten optimised ones (on a
    # fresh machine the -O1 builds alone took ~55 s of a 2-minute demo)
    rcompile = "quick" if at_bound and compile == "auto" else compile
    t0 = time.perf_counter()
    _precompile(model, res, [c.effect for c in to_refit], n_sub, rcompile, "refit")
    say(f"  built refit models ({time.perf_counter() - t0:.1f} s)")
    starts: dict[str, FitResult] = {}
    if at_bound:
        # cold refits in two stages: a few iterations for every candidate (the right model
        # converges fast from cold, wrong ones crawl along the compensating valley), then
        # the best few by the cost reached are continued to the usual cap
        t0 = time.perf_counter()
        for cand in to_refit:
            starts[cand.effect] = _refit(model, res, est, None, cand.effect, res.sigma, rcompile, cold=True,
                                         max_iter=COLD_SCREEN_ITER)[1]
        to_refit.sort(key=lambda c: starts[c.effect].cost)
        n_cont = min(n_refit, COLD_CONTINUE[0])
        for cand in to_refit[n_cont:]:
            cand.reason = f"cold screen: cost {starts[cand.effect].cost:.4g} after {COLD_SCREEN_ITER} iterations, " \
                          f"not among the {n_cont} lowest"
        to_refit = to_refit[:n_cont]
        say(f"  cold screen ({time.perf_counter() - t0:.1f} s): continuing "
            f"{', '.join(c.effect for c in to_refit)}")
    for cand in to_refit:
        t0 = time.perf_counter()
        ext, fr, pr = _refit(model, res, est, val, cand.effect, res.sigma, rcompile, cold=bool(at_bound),
                             start=starts.get(cand.effect), max_iter=COLD_CONTINUE[1] if at_bound else None)
        E = _estimation_residuals(ext, fr, est)
        cand.lr, cand.p_value = _lr_test(res, fr, E, cand.df, _null_on_bound(ext, cand.effect), n_tests)
        cand.fit, cand.prediction = fr, pr
        cand.nrmse_after, cand.channels_after = pr.total, dict(pr.nrmse)
        gain = 1 - pr.total / pred.total
        falls = {ch: 1 - pr.nrmse[ch] / pred.nrmse[ch] for ch in pred.nrmse if pred.nrmse[ch] > 0}
        best_ch = max(falls, key=falls.get)
        cand.explained = _explained_fraction(res, fr)
        negligible = _negligible(fr, cand.effect)
        if cand.p_value >= ALPHA:
            cand.reason = f"not significant (p = {cand.p_value:.2g})"
        elif negligible:
            cand.reason = f"significant in the fit (p = {cand.p_value:.2g}) but physically negligible: {negligible}"
        elif falls[best_ch] < MIN_VALIDATION_GAIN or gain < -MAX_VALIDATION_LOSS:
            cand.reason = (f"significant in the fit but not confirmed on validation (best channel {best_ch} "
                           f"{-100 * falls[best_ch]:+.1f} %, total {-100 * gain:+.1f} %)")
            moved = _prediction_change(pred, pr)
            if max(moved.values(), default=0.0) < MIN_VALIDATION_GAIN:
                # the refit moves the validation predictions too little to be judged there:
                # the validation data lack the regime, which is not evidence against the effect
                cand.unconfirmable = True
                cand.reason += (f"; the validation data hardly exercise it (its predictions there move by "
                                f"< {100 * MIN_VALIDATION_GAIN:.0f} % of the error in every channel)")
        else:
            cand.significant = True
            cand.reason = f"p = {cand.p_value:.2g}; validation {best_ch} {-100 * falls[best_ch]:+.0f} %, " \
                          f"total {-100 * gain:+.0f} %"
        say(f"  refit  {cand.effect:<16} LR {cand.lr:12.1f}  p {cand.p_value:.2g}  nrmse {pred.total:.3f} -> "
            f"{pr.total:.3f}  ({time.perf_counter() - t0:.1f} s)")
    for c in out:
        if c.lr is None and not c.reason:
            c.reason = f"screened only: the {n_refit} best by score are refitted"
    # the at-bound fallback decides by refits: put that in the reasons of the screened-out
    for c in out:
        if c.lr is not None and at_bound:
            c.reason += f" (refitted: baseline {', '.join(at_bound)} on a bound)"
    refitted = [c for c in out if c.lr is not None]
    rest = [c for c in out if c.lr is None]
    # significant first; among them the largest validation improvement (the out-of-sample
    # evidence), then the likelihood ratio
    refitted.sort(key=lambda c: (not c.significant, (c.nrmse_after or 0.0) if c.significant else 0.0,
                                 -(c.lr or 0.0)))
    return refitted + rest


def default_candidates(model: QuadrotorModel, logs: Sequence[FlightLog]) -> list[str]:
    """The effects :func:`diagnose` tries by default: the catalogue and the effects
    registered by the user (files, plugins) that are not in the model, and the effects that
    read a logged signal when every flight has that signal."""
    return [n for n, cls in fx.known_effects().items() if n not in model.effects
            and (n in fx.CATALOGUE or n in fx.registered_effects() or cls.signals)
            and all(all(s in lg.extras or s in lg.input_names for lg in logs) for s in cls.signals)]


def diagnose(model: QuadrotorModel, log: FlightLog | Sequence[FlightLog], *, candidates: Sequence[str] | None = None,
             iterate: bool = True, max_rounds: int = 3, split: float = 0.8, p0=None,
             n_refit: int = N_REFIT, compile: str = "auto",
             progress: bool | Callable[[str], None] = False,
             process_noise: str | dict[str, float] | None = None,
             validation: FlightLog | Sequence[FlightLog] | None = None) -> Diagnosis:
    """Compare ``model`` with ``log``, find where it fails and which catalogue effect is
    missing; with ``iterate`` add significant effects until none is left (see module doc).

    Args:
        candidates: effect names to consider (default: every catalogue effect not in the model).
        p0: starting values of the baseline fit.
        process_noise: passed to the baseline :func:`~greybox.fitting.fit` (e.g. ``"auto"`` for
            real logs); candidates are then fitted with the baseline's process noise.
        validation: a separate flight (or several) to validate on; then all of ``log`` is
            estimation data and ``split`` is not used.

    ``log`` may be several flights of one vehicle: they share the parameters, each has its
    own states (the baseline, the screening, every refit); each is split into estimation and
    validation parts unless ``validation`` is given; validation nrmse is pooled over flights
    (:func:`greybox.validation.pool_predictions`).

    Example::

        from greybox import QuadrotorModel, diagnose, load_airframe, load_log
        model = QuadrotorModel(load_airframe("greybox/data/airframes/paper.toml"))
        log = load_log("greybox/data/logs/demo_ground_effect.csv")
        val = load_log("greybox/data/logs/demo_ground_effect_validation.csv")
        d = diagnose(model, log, validation=val)     # about a minute
        print(d.summary())                           # verdict: ground_effect
    """
    t_start = time.perf_counter()
    say = progress_printer() if progress is True else \
        (progress or (lambda _m: None))
    logs = [log] if isinstance(log, FlightLog) else list(log)
    if not logs:
        raise GreyboxInputError("diagnose: no flight logs")
    if candidates is None:
        candidates = default_candidates(model, logs)
    for c in candidates:
        fx.by_name(c)
        if c in model.effects:
            raise GreyboxInputError(f"candidate {c!r} is already in the model")
    if validation is None:
        est, val = map(list, zip(*[lg.split(split) for lg in logs]))
    else:
        val = [validation] if isinstance(validation, FlightLog) else list(validation)
        for v in val + logs[1:]:
            if list(v.input_names) != list(logs[0].input_names):
                raise GreyboxInputError(f"{v.source or 'log'}: inputs {','.join(v.input_names)} differ from the "
                                        f"first estimation log's {','.join(logs[0].input_names)}")
        est = logs
    say(f"diagnose: fitting the model ({', '.join(model.effect_names)}) to {sum(len(e) for e in est)} samples"
        + (f" of {len(est)} flights" if len(est) > 1 else ""))
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", ConvergenceWarning)   # judged below, in words
        res = fit(model, est, p0=p0, compile=compile, max_iter=200, process_noise=process_noise)
        if not res.converged:
            # one more go from where it stopped, with the weights it reached
            say(f"diagnose: the baseline fit is not certified ({res.status}); solving on")
            res = fit(model, est, p0=res.p, compile=compile, max_iter=200, process_noise=process_noise,
                      noise=res.sigma, reweight=False, initial_states=res.node_states,
                      interval=res.interval)
    pred = predict_flights(model, res.p, val, compile=compile)
    say(f"diagnose: validation nrmse {pred.total:.3f} ({_validation_source(validation, split)})")
    findings, white, incorr, E, regimes = residual_analysis(model, res, est, pred,
                                                            validation_is_tail=validation is None)
    rounds: list[Round] = []
    warnings: list[str] = list(res.warnings)
    if res.certificate is not None:
        say(f"diagnose: baseline {res.certificate.text()}")
    if not res.converged:
        # No fallback to another formulation here: its statistics for candidates that add
        # states were not sound (a score in the millions for motor_lag), and "cannot tell"
        # with where the model fails is an answer a person can act on.
        warnings.insert(0, f"the baseline fit did not reach a certified optimum ({res.status}): no candidate is "
                           "tested against it, since any extra parameter would 'explain' the distance still to go; "
                           "the verdict is null because greybox cannot tell. A model that misses a large force or "
                           "torque cannot follow the data open loop over a shooting interval: see where it fails "
                           "(above), try shorter intervals, or process_noise='auto' (--process-noise auto)")
    inconsistent = _half_consistency(model, res, est, E, compile, say) if res.converged else {}
    for n, (a, sa, b, sb) in inconsistent.items():
        warnings.append(f"{n} differs between the two halves of the estimation data ({a:.4g} ± {sa:.2g} vs "
                        f"{b:.4g} ± {sb:.2g}): it is absorbing something the model lacks, not a constant of the vehicle")
    for n in (res.certificate.held if res.certificate else []):
        par = next(par for par in model.parameters if n in par.component_names)
        if not np.isclose(res.value(n), par.null, rtol=1e-6, atol=1e-15):
            warnings.append(f"{n} = {res.value(n):.4g} sits on its bound: it is compensating for something the "
                            "model lacks, and its value is not a property of the vehicle")
    cur_model, cur_res, cur_pred = model, res, pred
    remaining = list(candidates) if res.converged else []
    for r in range(max_rounds if iterate else 1):
        if not remaining:
            break
        say(f"diagnose: round {r + 1}: screening {len(remaining)} candidates")
        ranking = _rank_round(cur_model, cur_res, cur_pred, est, val, remaining, compile, say, n_refit)
        verdict = ranking[0].effect if ranking and ranking[0].significant else None
        rounds.append(Round(cur_model, cur_res, cur_pred, ranking, verdict))
        if verdict is None:
            break
        win = ranking[0]
        if not win.fit.converged:
            # the next round's statistics are taken at the winner's fit: it must be an optimum
            say(f"diagnose: {verdict}'s refit is not certified ({win.fit.status}); solving on")
            with _warnings.catch_warnings():
                _warnings.simplefilter("ignore", ConvergenceWarning)
                more = fit(win.fit.model, est, free=win.fit.free_names, p0=win.fit.p, noise=win.fit.sigma,
                           reweight=False, compile=compile, max_iter=200, initial_states=win.fit.node_states,
                           interval=win.fit.interval, process_noise=win.fit.process_noise)
            if not more.converged:
                warnings.append(f"{verdict}'s refit did not reach a certified optimum ({more.status}): no further "
                                "candidate was tested against it")
                break
            win.fit, win.prediction = more, predict_flights(more.model, more.p, val, compile=compile)
        cur_model, cur_res, cur_pred = win.fit.model, win.fit, win.prediction
        remaining = [c for c in remaining if c != verdict]
    # confusable candidates: significant alone in round 1, explained away by the winner
    first = rounds[0].ranking if rounds else []
    if len(rounds) >= 2 and rounds[0].verdict:
        later = {c.effect: c for c in rounds[1].ranking}
        for c in first[1:]:
            if c.significant and c.effect in later and not later[c.effect].significant:
                hint = distinguishing_manoeuvre(rounds[0].verdict, c.effect)
                warnings.append(f"{c.effect} explains much of what {rounds[0].verdict} explains "
                                f"(significant alone, not once {rounds[0].verdict} is in); to tell them apart: {hint}")
    elif len(first) >= 2 and first[0].significant and first[1].significant and first[1].lr and first[0].lr \
            and first[1].lr > 0.5 * first[0].lr:
        warnings.append(f"{first[0].effect} and {first[1].effect} both explain the data well; to tell them apart: "
                        f"{distinguishing_manoeuvre(first[0].effect, first[1].effect)}")
    verdict = rounds[0].verdict if rounds else None
    for c in (rounds[0].ranking if rounds and verdict is None else []):
        if c.unconfirmable:
            warnings.append(f"{c.effect} is significant in the fit (p = {c.p_value:.2g}) but the validation data do "
                            f"not exercise it, so it could not be confirmed: validate on a flight that does "
                            f"(validation=, --validation LOG2)")
    unexplained: dict[str, float] = {}
    if cur_res.converged and cur_res.certificate is not None:
        # what the final model (the baseline when nothing was added) still misses by far
        cert = cur_res.certificate
        unexplained = {ch: cert.residual_over_noise[ch] for ch in cert.off_channels()
                       if cert.residual_over_noise[ch] > UNEXPLAINED_RATIO}
    diag = Diagnosis(model, res, pred, findings, white, incorr, rounds[0].ranking if rounds else [], verdict,
                     warnings, rounds, cur_model, cur_res, cur_pred, E, regimes, est[0],
                     validation_source=_validation_source(validation, split, len(est)), unexplained=unexplained,
                     inconsistent=inconsistent, command_imbalance=command_imbalance(model, est))
    diag.timings["total"] = time.perf_counter() - t_start
    say(f"diagnose: verdict {verdict or 'null'}; {diag.timings['total']:.1f} s")
    return diag


def _flight_residuals(model: QuadrotorModel, res: FitResult, logs: Sequence[FlightLog]) -> list[np.ndarray]:
    """Output residuals of a fit on each of its estimation flights."""
    return [output_residuals(lg, fitted_trajectory(model, res, lg, i)[1]) for i, lg in enumerate(logs)]


def _estimation_residuals(model: QuadrotorModel, res: FitResult, logs: Sequence[FlightLog]) -> np.ndarray:
    """Output residuals of a fit on its estimation flights, stacked flight after flight."""
    return np.vstack(_flight_residuals(model, res, logs))


def _half_consistency(model: QuadrotorModel, res: FitResult, est: Sequence[FlightLog], E: np.ndarray,
                      compile: str,
                      say: Callable[[str], None]) -> dict[str, tuple[float, float, float, float]]:
    """Fit each half of the estimation data (warm-started at the baseline, its weights) and
    return the parameters whose two estimates differ by more than :data:`CONSISTENCY_Z`
    standard deviations: a constant of the vehicle is the same in both halves; a parameter
    absorbing a missing effect follows what each half happens to exercise.

    The standard deviations assume white residuals; coloured ones (``E``, the baseline's)
    carry less information, so they are widened by the square root of the median long-run
    variance factor of the channels."""
    if len(est) == 1:
        halves = [[h] for h in est[0].split(0.5)]
    else:   # several flights: the first half of the flights against the second
        k = len(est) // 2
        halves = [list(est[:k]), list(est[k:])]
    out: dict[str, tuple[float, float, float, float]] = {}
    try:
        with _warnings.catch_warnings():
            _warnings.simplefilter("ignore", ConvergenceWarning)
            fits = [fit(model, half, p0=res.p, free=res.free_names, noise=res.sigma, reweight=False,
                        compile=compile, max_iter=100, interval=res.interval) for half in halves]
    except GreyboxError as e:   # a half too short or too poor to fit: no verdict on consistency
        say(f"diagnose: halves not compared ({e})")
        return out
    if not all(f.converged for f in fits):
        return out
    a, b = fits
    widen = math.sqrt(float(np.median([long_run_factor(E[:, c]) for c, ch in enumerate(OUTPUTS)
                                       if ch in res.sigma])))
    for i, n in enumerate(res.free_names):
        sa, sb = widen * float(a.std[i]), widen * float(b.std[i])
        if not (np.isfinite(sa) and np.isfinite(sb)) or sa + sb <= 0:
            continue
        z = abs(a.value(n) - b.value(n)) / math.hypot(sa, sb)
        if z > CONSISTENCY_Z:
            out[n] = (a.value(n), sa, b.value(n), sb)
    say("diagnose: halves of the estimation data " +
        (f"disagree on {', '.join(out)}" if out else "agree on every parameter"))
    return out


def _validation_source(validation, split: float, n_flights: int = 1) -> str:
    if validation is None:
        return f"last {100 * (1 - split):.0f} % of the log" + (f"s ({n_flights} flights)" if n_flights > 1 else "")
    vals = [validation] if isinstance(validation, FlightLog) else list(validation)
    names = [Path(v.source).name if v.source else "unnamed" for v in vals]
    return ("validation flight " if len(vals) == 1 else "validation flights ") + ", ".join(names)


# ------------------------------------------------------------------------------ report
def _write_report(d: Diagnosis, out: Path) -> Path:
    from .plotting import report_figures, save
    out.mkdir(parents=True, exist_ok=True)
    images: dict[str, str] = {}
    for name, fig in report_figures(d).items():
        images[name] = base64.b64encode(save(fig, out / f"{name}.png").read_bytes()).decode()
    esc = html.escape
    rows = "".join(
        f"<tr><td>{esc(c.effect)}</td><td>{'yes' if c.significant else 'no'}</td>"
        f"<td>{c.score:.1f}</td><td>{'' if c.lr is None else f'{c.lr:.1f}'}</td>"
        f"<td>{'' if c.p_value is None else f'{c.p_value:.2g}'}</td><td>{c.nrmse_before:.3f}</td>"
        f"<td>{'' if c.nrmse_after is None else f'{c.nrmse_after:.3f}'}</td><td>{esc(c.reason)}</td></tr>"
        for c in d.ranking)
    b = d.baseline_prediction
    chan_rows = ""
    if d.final_prediction is not None:
        f = d.final_prediction
        chan_rows = "".join(f"<tr><td>{ch}</td><td>{b.nrmse[ch]:.3f}</td><td>{f.nrmse.get(ch, float('nan')):.3f}</td>"
                            f"<td>{100 * (f.nrmse.get(ch, 0) / b.nrmse[ch] - 1) if b.nrmse[ch] else 0:+.0f} %</td></tr>"
                            for ch in b.nrmse)
    img = lambda k: f'<img src="data:image/png;base64,{images[k]}"/>' if k in images else ""
    imbalance = (f"<li>{esc(d.command_imbalance.text())}</li>"
                 if d.command_imbalance is not None and d.command_imbalance.notable else "")
    param_rows = "".join(
        f"<tr><td>{esc(n)}</td><td>{v['value']:.6g}</td>"
        f"<td>{'fixed' if v['std'] is None else format(v['std'], '.3g')}</td></tr>"
        for n, v in d.parameter_table().items() if v["value"] is not None)
    text = f"""<!doctype html><html><head><meta charset="utf-8"><title>greybox diagnosis</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 8px}}img{{max-width:100%}}</style></head><body>
<h1>greybox diagnosis</h1>
<p>Model: {esc(', '.join(d.model.effect_names))}. Verdict: <b>{esc(d.verdict or 'null: nothing significant is missing')}</b>.</p>
<h2>1. Compare</h2><p>Validation nrmse {b.total:.3f} on the {esc(d.validation_source)} ({esc(', '.join(f'{c} {v:.3f}' for c, v in b.nrmse.items()))}).</p>
{img('compare_baseline')}
<h2>2. Where it fails</h2><ul>{''.join(f'<li>{esc(f.text)}</li>' for f in d.findings) or '<li>no regime stands out</li>'}{imbalance}</ul>
{img('regimes')}<p>Residual autocorrelation (grey: 99 % band of white noise):</p>{img('whiteness')}
<h2>3. Which effect is missing</h2><table><tr><th>effect</th><th>significant</th><th>score</th><th>LR</th>
<th>p</th><th>nrmse before</th><th>nrmse after</th><th>why</th></tr>{rows}</table>{img('ranking')}
<h2>4. Added, and the error falls</h2>
<table><tr><th>channel</th><th>before</th><th>after</th><th>change</th></tr>{chan_rows}</table>{img('compare_after')}
<h2>Fitted parameters of the final model</h2><table><tr><th>parameter</th><th>value</th><th>std</th></tr>{param_rows}</table>
<h2>Warnings</h2><ul>{''.join(f'<li>{esc(w)}</li>' for w in d.warnings) or '<li>none</li>'}</ul>
</body></html>"""
    path = out / "report.html"
    atomic_write(path, text)
    return path

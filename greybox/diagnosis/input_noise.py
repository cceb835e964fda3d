"""Errors in the inputs: rotor speeds logged with white noise (an ESC's speed telemetry) are not
the speeds the rotors turned at, and a model fed them responds to the noise too. A fit then
prefers a weaker response to the logged speeds: an effect that attenuates it — a thrust curve
falling with the speed, a moment gain below one, a motor lag that filters the noise — fits the
noise, not the vehicle (errors in variables; a blind audit's hexacopter with 1 % noise on its
logged speeds and nothing missing got the verdict ``thrust_curve``, k_Tw = -0.072 ± 0.020, and
the same simulator without the noise ``null``).

The check is SIMEX (simulation-extrapolation; Cook and Stefanski, JASA 1994): refit the
candidate with noise added to the logged speeds so that their noise variance is twice and three
times the log's (the level estimated from their high-frequency content,
:func:`~greybox.fitting.input_errors.input_noise_sd`), :data:`DRAWS` refits averaged per level (more while their
Monte Carlo spread would decide: :data:`MONTE_CARLO_SHARE`), and
extrapolate each parameter in the noise variance back to noise-free speeds through the three
points: with the rational extrapolant ``a + b / (c + lambda)`` (Carroll et al., *Measurement
Error in Nonlinear Models*: it is exact for the attenuation ``lambda / (1 + k lambda)`` a
regression's noisy input gives), the quadratic where its pole comes near zero. The linear
one under-corrects: on a flight of the audit's simulator without the log's timing in the model,
k_Tw -0.155 ± 0.010 with the log's noise and -0.273 with twice its variance extrapolate linearly
to -0.036, 3.6 std off its null, where the same flight without the noise has none. A candidate
none of whose parameters is then significantly away from its null value on the side it was
fitted on (one extrapolated across its null was the noise's in sign and size), at the
diagnosis's own test level (``alpha`` two-sided, Bonferroni over the round's candidates as the likelihood-ratio
test is: 3.0 standard deviations for four candidates), stands for the noise in the inputs: the
diagnosis cannot tell it from them. The standard deviation counts the fit's and the Monte Carlo
spread of the noisy refits carried through the extrapolant. Only for logs whose speeds carry
noise of at least :data:`NOISE_SHARE_NOTABLE` of their variance: below that, noise on the
inputs biases a gain by less than that share (the regression-dilution bound), which no
verdict's size is.
"""
from __future__ import annotations

import warnings as _warnings
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy import stats

from ..data import FlightLog
from ..errors import ConvergenceWarning, GreyboxError
from ..fitting import FitResult, fit
from ..fitting.input_errors import COMBINATION_NOISE_NOTABLE, INPUT_NOISE_SHARE, input_noise_sd, mixer_noise_shares, state_steps
from ..model import QuadrotorModel

__all__ = ["InputNoise", "input_noise", "SimexCheck", "simex", "simex_check", "extrapolate", "away_from_null",
           "rates_moved_by_input_noise", "RATE_STEP_NOTABLE", "NOISE_SHARE_NOTABLE",
           "DRAWS", "MAX_DRAWS", "MONTE_CARLO_SHARE", "LEVELS"]

NOISE_SHARE_NOTABLE = INPUT_NOISE_SHARE
"""Share of a logged rotor speed's variance that is white noise from which the inputs' errors
are checked for (the share from which the fit warns of gains biased low; its floor of process
noise counts whatever the share)."""
DRAWS = 2
"""Noise draws averaged per noise level, and drawn again while the Monte Carlo spread counts
(:data:`MONTE_CARLO_SHARE`)."""
MAX_DRAWS = 8
"""The most noise draws per level."""
MONTE_CARLO_SHARE = 0.25
"""The largest share of the fit's own variance that the draws' Monte Carlo variance, carried
through the extrapolant, may add to an extrapolated parameter's before more are drawn: the
draws, not the data, would decide the check (a blind audit's 30-ms motors behind 83-Hz
commands: tau_m 0.0121 +- 0.0050 from two draws, across what the noise gives, where the fit's
own std is 0.0032; 0.0133 +- 0.0035 from six, standing)."""
LEVELS = (2.0, 3.0)
"""The noise variances, in multiples of the log's, the candidate is refitted at."""


@dataclass
class InputNoise:
    """White noise on the logged rotor speeds: ``sigma`` per rotor (rad/s) and ``share``, the
    largest share of a rotor speed's variance, or of the thrust, roll, pitch or yaw combination
    of them (:func:`~greybox.fitting.input_errors.mixer_noise_shares`, from
    :data:`~greybox.fitting.input_errors.COMBINATION_NOISE_NOTABLE` on), that it makes up."""

    sigma: np.ndarray
    share: float

    @property
    def notable(self) -> bool:
        return self.share >= NOISE_SHARE_NOTABLE


def input_noise(model: QuadrotorModel, logs: Sequence[FlightLog]) -> InputNoise | None:
    """The logged rotor speeds' white-noise level (robust second differences of their fresh
    samples, pooled over the flights by variance), or None when the inputs are not rotor speeds."""
    if model.inputs != "rotor_speeds":
        return None
    n = model.airframe.n_rotors
    var_noise = np.zeros(n)
    var_total = np.zeros(n)
    for log in logs:
        w = log.inputs[:, :n]
        var_noise += np.array([input_noise_sd(log, w[:, i]) ** 2 for i in range(n)]) * len(log)
        var_total += np.nanvar(w, axis=0) * len(log)
    if not np.all(np.isfinite(var_noise)) or np.any(var_total <= 0):
        return None
    share = float(np.max(var_noise / var_total))
    # and of the thrust, roll, pitch and yaw they make together, from which the gains are read:
    # a flight that barely turns has combinations the noise dwarfs while each speed's own
    # variance hides it (a blind audit's slow flight: 0.6 % of each speed's, 57 % of the roll
    # combination's; moment_gain 0.874 +- 0.012 for 1 was its verdict)
    # (counted from the share at which fit and diagnose say so, COMBINATION_NOISE_NOTABLE: at a
    # few per cent a real flight's diagnosis, B6_linear_ramp, lost its drag moment to the check)
    combined = [float(np.max(c)) for c in (mixer_noise_shares(model, lg) for lg in logs) if c is not None]
    share = max([share] + [c for c in combined if c >= COMBINATION_NOISE_NOTABLE])
    return InputNoise(np.sqrt(var_noise / sum(len(lg) for lg in logs)), share)


RATE_STEP_NOTABLE = 1.0
"""The noise on the logged speeds moves a modelled body rate by this many times the gyro's noise
per row or more: a random torque the rates then miss is the inputs' noise as much as anything
(the peer simulator's 30 g vehicle at 500 Hz with 1 % speed noise: p, q 1.4 per row, the rates
3x their noise with every candidate, taken for turbulence; its 1.2 kg vehicle 0.37, the audit's
hexacopter 0.54, their rates at the noise)."""


def rates_moved_by_input_noise(fr: FitResult, logs: Sequence[FlightLog], noise: InputNoise) -> dict[str, float]:
    """Per body rate (``p, q, r``) the RMS change over one row that the logged speeds' white noise
    gives the model ``fr`` (its rate derivatives' sensitivity to every input column derived from a
    rotor speed, each column's noise independent of the others'), over the gyro's noise (the
    certificate's, from the measurements). Empty where the rates are not measured; 0 for a rate
    that does not follow the inputs directly (a motor lag between them)."""
    model = fr.model
    cert = fr.certificate
    if cert is None or model.inputs != "rotor_speeds":
        return {}
    rates = [s for s in ("p", "q", "r") if cert.sensor_noise.get(s, 0.0) > 0]
    if not rates:
        return {}
    # each steady input's noise: the rotor speeds' (w3@next, w3@-10ms carry rotor 3's: state_steps)
    speeds = model.command_names
    sigma = np.array([noise.sigma[speeds.index(s)] if s in speeds else 0.0 for s in model.steady_input_names])
    rows = [model.state_names.index(s) for s in rates]
    steps, weights = [], []
    for log in logs:
        prepared = model.prepare_log(log)
        idx = np.unique(np.linspace(0, len(prepared) - 2, min(400, len(prepared) - 1)).astype(int))
        steps.append(state_steps(model, prepared, fr.p, sigma, idx)[rows])
        weights.append(idx.size)
    step = np.sqrt(np.average(np.square(steps), axis=0, weights=weights))
    return {s: float(step[k] / cert.sensor_noise[s]) for k, s in enumerate(rates)}


@dataclass
class SimexCheck:
    """What :func:`simex_check` found: per parameter of the candidate ``(with the log's noise,
    with twice its variance, with three times, extrapolated to none, std)``, and whether the
    candidate stands with noise-free inputs."""

    effect: str
    noise: InputNoise
    values: dict[str, tuple[float, float, float, float, float]]
    stands: bool
    nulls: dict[str, float]

    def values_text(self) -> str:
        """The parameters at each noise level and extrapolated, those furthest from their null
        (in std, which carry the judgement) first; three at most."""
        ranked = sorted(self.values.items(),
                        key=lambda kv: -abs(kv[1][3] - self.nulls[kv[0]]) / kv[1][4] if kv[1][4] > 0 else 0.0)[:3]
        return ", ".join(f"{n} {a:.3g} with the log's noise, {b:.3g} and {c:.3g} with twice and three times its "
                         f"variance, {z:.3g} ± {s:.2g} without" for n, (a, b, c, z, s) in ranked)

    def text(self) -> str:
        vals = self.values_text()
        rms = ", ".join(f"{s:.3g}" for s in self.noise.sigma)
        if self.stands:
            return f"it stands with the inputs' errors taken out (SIMEX: {vals})"
        return (f"the logged rotor speeds carry white noise ({rms} rad/s, up to {100 * self.noise.share:.0f} % of "
                f"their variance or of a combination's the mixer makes), and noise on a model's inputs weakens its response to them, which "
                f"{self.effect} imitates: extrapolated to noise-free speeds it is at its null or across it (SIMEX: {vals}); "
                "cannot tell it from the errors in the inputs")


def _noisier(logs: Sequence[FlightLog], noise: InputNoise, level: float, rng: np.random.Generator) -> list[FlightLog]:
    """``logs`` with white noise added to the speeds: their noise variance ``level`` times the log's."""
    n = noise.sigma.size
    out = []
    for log in logs:
        inputs = log.inputs.copy()
        inputs[:, :n] += rng.standard_normal((len(log), n)) * noise.sigma * np.sqrt(level - 1.0)
        out.append(replace(log, inputs=inputs))
    return out


def simex(fr: FitResult, logs: Sequence[FlightLog], noise: InputNoise, names: Sequence[str],
          compile: str = "auto", seed: int = 0) -> dict[str, tuple[float, float, float, float, float]] | None:
    """SIMEX for the free parameters ``names`` of the fit ``fr``: refit with the inputs' noise
    variance at each of :data:`LEVELS` times the log's (:data:`DRAWS` draws each, and as many
    again while the draws' Monte Carlo variance is more than :data:`MONTE_CARLO_SHARE` of the
    fit's own for a parameter, up to :data:`MAX_DRAWS`; the fit's own weights and process
    noise) and extrapolate to noise-free inputs (:func:`extrapolate`). Per
    parameter ``(with the log's noise, with twice its variance, with three times, extrapolated,
    std)``: the std counts the fit's and the Monte Carlo spread of the draws carried through the
    extrapolant. None when a refit fails or is not certified."""
    model = fr.model
    rng = np.random.default_rng(seed)
    fit_var = {n: float(fr.std[fr.free_names.index(n)]) ** 2 for n in names}
    refits: dict[float, list[FitResult]] = {level: [] for level in LEVELS}
    while True:
        try:
            with _warnings.catch_warnings():
                _warnings.simplefilter("ignore", ConvergenceWarning)
                for level in LEVELS:
                    refits[level] += [fit(model, _noisier(logs, noise, level, rng), p0=fr.p, free=fr.free_names,
                                          compile=compile, max_iter=100, **fr.settings(states=False))
                                      for _ in range(DRAWS)]
        except GreyboxError:
            return None
        if not all(r.converged for rs in refits.values() for r in rs):
            return None
        values = {n: _extrapolated(fr, n, refits) for n in names}
        drawn = len(refits[LEVELS[0]])
        if drawn + DRAWS > MAX_DRAWS or all(mc <= MONTE_CARLO_SHARE * fit_var[n] for n, (*_, mc) in values.items()):
            return {n: v[:4] + (float(np.sqrt(fit_var[n] + v[4])),) for n, v in values.items()}


def _extrapolated(fr: FitResult, name: str, refits: dict[float, list[FitResult]]
                  ) -> tuple[float, float, float, float, float]:
    """``name`` with the log's noise, the mean of the refits at each of :data:`LEVELS`, the
    extrapolation to none (:func:`extrapolate`) and the Monte Carlo variance of the level means
    carried through it."""
    one = fr.value(name)
    draws = [np.array([r.value(name) for r in refits[level]]) for level in LEVELS]
    two, three = (float(d.mean()) for d in draws)
    zero = extrapolate(one, two, three)
    # the Monte Carlo variance of each level's mean, carried through the extrapolant
    h = [max(1e-6 * abs(x), 1e-300) for x in (two, three)]
    slope = [(extrapolate(one, two + h[0], three) - extrapolate(one, two - h[0], three)) / (2 * h[0]),
             (extrapolate(one, two, three + h[1]) - extrapolate(one, two, three - h[1])) / (2 * h[1])]
    mc = sum(g * g * float(np.var(d, ddof=1)) / len(d) for g, d in zip(slope, draws))
    return one, two, three, zero, float(mc)


def simex_check(cand_fit: FitResult, effect: str, logs: Sequence[FlightLog], noise: InputNoise,
                compile: str = "auto", alpha: float = 0.01, seed: int = 0) -> SimexCheck | None:
    """Refit ``cand_fit`` (the model with ``effect``) with the inputs' noise variance at each of
    :data:`LEVELS` times the log's (module doc; :func:`simex`) and extrapolate ``effect``'s
    parameters to noise-free inputs; ``alpha``: the two-sided level at which one must then differ
    from its null (the diagnosis's, per candidate). None when a refit fails or is not certified
    (then nothing is said)."""
    nulls = {comp: null for _, comp, null in cand_fit.model.effect_components(effect)
             if comp in cand_fit.free_names}
    if not nulls:
        return None
    values = simex(cand_fit, logs, noise, list(nulls), compile, seed)
    if values is None:
        return None
    z = float(stats.norm.isf(alpha / 2))
    stands = any(away_from_null(one, zero, std, nulls[n], z) for n, (one, _, _, zero, std) in values.items())
    return SimexCheck(effect, noise, values, stands, nulls)


def away_from_null(fitted: float, extrapolated: float, std: float, null: float, z: float) -> bool:
    """Whether a parameter ``fitted`` with the log's noise stands ``extrapolated`` (± ``std``)
    to noise-free inputs: more than ``z`` std from its ``null``, on the side it was fitted on.
    Extrapolated across its null, the fitted value was the noise's in sign and size (a blind
    audit's CoG-offset flight: k_Tw -0.167, -0.402, -0.543 at one to three times the noise,
    +0.31 ± 0.03 extrapolated). An undefined std cannot refuse it."""
    if not np.isfinite(std):
        return True
    return (extrapolated - null) * (fitted - null) > 0 and abs(extrapolated - null) > z * std


def extrapolate(one: float, two: float, three: float) -> float:
    """A parameter at noise variance 0 from its values at 1, 2 and 3 times the log's: the
    rational extrapolant ``a + b / (c + lambda)`` through the three points when its pole lies
    well below zero (``c >= 0.5``), else the quadratic ``3 theta_1 - 3 theta_2 + theta_3``."""
    d1, d2 = one - two, two - three
    quadratic = 3 * one - 3 * two + three
    if d1 == 0 or d2 == 0 or d1 * d2 < 0:
        return quadratic
    r = d1 / d2                                  # (c + 3) / (c + 1)
    if r <= 1.0:
        return quadratic
    c = (3.0 - r) / (r - 1.0)
    if c < 0.5:     # a pole near zero: the rational one swings with the draws' noise
        return quadratic
    # a + b / c with b = d1 (c + 1)(c + 2), a = one - b / (c + 1), in the form that stays exact
    # where the points lie nearly on a line (c large: the sum of two large terms lost 6 % of
    # the step on an exact line)
    return float(one + d1 * (c + 2) / c)

"""The certificate of a fit's end point: is it the optimum, and is the model adequate?"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["Certificate", "STEP_TOLERANCE", "GAP_TOLERANCE", "DECREASE_TOLERANCE", "NOISE_RATIO_ADEQUATE",
           "NOISE_RATIO_COLOURED", "WHITENESS_ADEQUATE", "GAP_VISIBLE", "GAP_FORCE_SHARE", "FILTERED_SENSOR_RATIO", "NOISE_RATIO_BELOW"]

STEP_TOLERANCE = 0.1
"""A fit is at its optimum when one more undamped Gauss-Newton step would move no free
parameter by more than this fraction of its standard deviation, nor any node state by more
than this fraction of its noise scale: further iterations cannot change a conclusion."""
GAP_TOLERANCE = 0.1
"""Largest continuity gap allowed at a certified optimum, as a fraction of the state's noise
scale (output-error fits; with process noise the gaps are residuals)."""
DECREASE_TOLERANCE = 0.01
"""A remaining node-state step larger than :data:`STEP_TOLERANCE` of its noise scale is
accepted at an optimum when the parameters and gaps pass and the step would lower the cost
(half the chi-square of the weighted residuals) by less than this: the state is one the
measurements barely see, and no test statistic can move by more than twice this."""
NOISE_RATIO_ADEQUATE = 2.0
"""Residual RMS up to this multiple of the sensor noise (estimated from the measurements'
high-frequency content) counts as "at the noise level" when the residuals are white."""
NOISE_RATIO_COLOURED = math.sqrt(2.0)
"""Coloured residuals are systematic: they count as the model's error once their systematic
part, ``sqrt(rms^2 - noise^2)``, is as large as the noise itself (RMS ratio sqrt(2)). On long
logs a tiny systematic error is already far outside the whiteness band; it is not yet a
failure of the model."""
WHITENESS_ADEQUATE = 0.2
"""Fraction of autocorrelation lags outside the 99 % band up to which residuals count as white."""
FILTERED_SENSOR_RATIO = 10.0
"""Residuals up to this multiple of the noise estimated from the measurements' high-frequency
content may be the sensors' own noise when it is coloured (a filtered estimate: an
autopilot's attitude, a smoothed vision pose), which that estimate does not count. Greybox's
own flights with every sensor's noise correlated over 50 ms and nothing missing leave
output-error residuals 2-6x that estimate; a sensor whose noise hides beyond 10x it would
have to be filtered to a tenth of its bandwidth."""
NOISE_RATIO_BELOW = 0.7
"""Residual RMS below this multiple of the noise estimated from the measurements says that
estimate is too large: for white noise the two agree to a few per cent, and fast motion that
the model follows but the high-frequency estimate takes for noise makes it larger (a blind
audit's 30 g vehicle logged at 100 Hz: gyro residuals 0.53x an estimate twice the truth).
The certificate's words say so; adequacy is judged against the larger figure."""
GAP_VISIBLE = 1.0
"""With process noise, a state's shooting gaps are judged only where their RMS reaches this
multiple of the state's noise scale (what its measurements could just see over an interval):
an exact model's gaps shrink towards zero, and their pattern then means nothing."""
GAP_FORCE_SHARE = 0.02
"""A velocity's gaps summed over several intervals (``systematic_gaps``) are judged only where
the force they stand for reaches this share of the RMS acceleration the fitted states fly
with: the share below which the diagnosis calls an effect's force physically negligible
(:data:`greybox.diagnosis.screening.MIN_FORCE_SHARE`). Over a second or more the positions
see even a force error far below that, which is not a model that misses something."""


@dataclass
class Certificate:
    """Whether a fit reached the optimum of its own problem (first-order optimality, closed
    shooting gaps), and whether its residuals look like sensor noise.

    The first is what makes test statistics at that fit meaningful (``optimal``); the second
    says whether the model explains the data (``adequate``): an optimal fit of a model that
    misses physics has residuals far above the noise, and coloured.
    """

    optimal: bool
    step_over_std: float                 # largest remaining GN parameter step / its std
    state_step_over_noise: float         # largest remaining GN node-state step / noise scale
    gap_over_noise: float                # largest continuity gap / the state's noise scale
    held: list[str]                      # parameters held on a bound (the step is projected)
    residual_over_noise: dict[str, float]   # per channel: RMS residual / sensor noise of the data
    whiteness: dict[str, float]          # per channel: fraction of lags outside the 99 % band
    sensor_noise: dict[str, float]       # per channel: noise estimated from the measurements
    reasons: list[str] = field(default_factory=list)   # why not optimal, in words
    systematic_gaps: dict[str, float] = field(default_factory=dict)
    """With process noise: per state whose gaps are visible (:data:`GAP_VISIBLE`), their RMS
    over their random part (the scale of their interval-to-interval differences,
    :func:`~greybox.fitting.api.process_noise_scale`); about 1 for random forcing, large when
    consecutive gaps share a force or torque the model lacks."""
    sensor_error: dict[str, float] = field(default_factory=dict)
    """Attitude channels off the noise whose residuals are not motion but the attitude
    sensor's own error, with the share of them the integrated gyro residuals account for
    (:func:`~greybox.residuals.attitude_motion`; set by :func:`~greybox.fitting.fit` when it
    keeps output error for that reason). They stay in :meth:`off_channels`: the residuals are
    not at the noise; what they are is said in :meth:`text`."""
    soft: bool = False
    """The fit had process noise: its shooting gaps are part of the cost, not held closed
    (``gap_over_noise`` is 0 by construction; :attr:`systematic_gaps` judges them)."""
    input_noise: dict[str, float] = field(default_factory=dict)
    """Per channel whose prediction the logged inputs feed straight through the output map (the
    accelerometer's, through the thrust): the RMS error the inputs' white noise puts on it
    (:func:`~greybox.fitting.input_errors.output_input_noise`), in the channel's unit. Set
    where some channel's residuals would otherwise be judged off the noise; an exact model's
    residuals there are the sensor's noise and this together (:meth:`noise_ratio`)."""
    state_words: dict[str, str] = field(default_factory=dict)
    """Per effect state, what its mostly systematic gaps say (the effect's
    :attr:`~greybox.effects.Effect.systematic_gap_words`); the others: a force or torque the
    model lacks."""
    flightless: float | None = None
    """Set where the end point passed every check of optimality but its rotors' mean thrust
    cannot be a flying vehicle's (:data:`~greybox.fitting.THRUST_IMPOSSIBLE`): their share of
    the weight. ``optimal`` is then False: the optimum of the problem as posed, and no
    vehicle's (a model that misses a large torque can trade the thrust for it)."""

    @property
    def optimum_of_problem(self) -> bool:
        """Whether the end point is the optimum of its own problem, where test statistics mean
        something: :attr:`optimal`, or optimal but :attr:`flightless`."""
        return self.optimal or self.flightless is not None

    @property
    def adequate(self) -> bool:
        """No channel's residuals are far above the noise, or coloured and above it, and no
        state's shooting gaps (with process noise) are mostly systematic."""
        return not self.off_channels() and not self.off_states()

    def noise_ratio(self, ch: str) -> float:
        """A channel's residual RMS over what an exact model leaves there: the sensor's noise
        and, where the logged inputs feed the prediction straight (:attr:`input_noise`), their
        noise too."""
        return self.residual_over_noise[ch] / math.sqrt(self.exact_model_variance(ch))

    def exact_model_variance(self, ch: str) -> float:
        """What an exact model's residual variance is in a channel, over the sensor's noise
        variance: 1, plus the logged inputs' noise where it feeds the prediction straight."""
        extra = self.input_noise.get(ch, 0.0) / self.sensor_noise[ch] if self.sensor_noise.get(ch, 0.0) > 0 else 0.0
        return 1.0 + extra * extra

    def input_noise_covers(self) -> list[str]:
        """Channels more than :data:`NOISE_RATIO_COLOURED` times the sensor's noise that the
        logged inputs' noise accounts for: with it, within that ratio (:meth:`noise_ratio`)."""
        return [ch for ch, r in self.residual_over_noise.items() if self.input_noise.get(ch, 0.0) > 0
                and r > NOISE_RATIO_COLOURED and self.noise_ratio(ch) <= NOISE_RATIO_COLOURED]

    def _off(self, r: float, ch: str) -> bool:
        return r > NOISE_RATIO_ADEQUATE or (r > NOISE_RATIO_COLOURED and self.whiteness.get(ch, 0.0) > WHITENESS_ADEQUATE)

    def far_off(self, ratio: float) -> tuple[dict[str, float], dict[str, float]]:
        """What the fit misses by more than ``ratio`` times the noise: ``({channel: residual
        RMS / sensor noise}, {state: gap RMS / its random part})`` among :meth:`off_channels`
        and :meth:`off_states`."""
        return ({ch: self.residual_over_noise[ch] for ch in self.off_channels()
                 if self.noise_ratio(ch) > ratio},
                {n: self.systematic_gaps[n] for n in self.off_states() if self.systematic_gaps[n] > ratio})

    def off_states(self) -> list[str]:
        """States whose shooting gaps (with process noise) are more than
        :data:`NOISE_RATIO_ADEQUATE` times their random part: what the states were let do
        between the nodes is a model error acting over many intervals, not noise."""
        return [n for n, r in self.systematic_gaps.items() if r > NOISE_RATIO_ADEQUATE]

    def off_channels(self) -> list[str]:
        """Channels whose residuals are far above the noise level, or coloured with a
        systematic part as large as the noise (:meth:`noise_ratio`: the logged inputs' noise
        counted where it feeds the prediction straight)."""
        return [ch for ch in self.residual_over_noise if self._off(self.noise_ratio(ch), ch)]

    def text(self) -> str:
        """The certificate in words."""
        if self.optimal:
            head = (f"optimum certified: one more Gauss-Newton step would move the parameters by "
                    f"{self.step_over_std:.2g} std at most, " +
                    ("the shooting gaps are process noise (judged below)" if self.soft else
                     f"the largest gap is {self.gap_over_noise:.2g} of the noise"))
        else:
            head = "optimum NOT certified: " + "; ".join(self.reasons)
        if self.held:
            head += f"; held on a bound: {', '.join(self.held)}"
        off_channels = self.off_channels()
        sensor = [ch for ch in off_channels if ch in self.sensor_error]
        off = [ch for ch in off_channels if ch not in self.sensor_error]
        parts = []
        if off:
            parts.append("residuals above the sensor noise in " +
                         ", ".join(f"{ch} ({self.residual_over_noise[ch]:.3g}x noise, "
                                   f"{100 * self.whiteness.get(ch, 0.0):.0f} % of lags outside the band)" for ch in off) +
                         ": the model does not explain these channels")
        if sensor:
            parts.append("residuals above the sensor noise in " +
                         ", ".join(f"{ch} ({self.residual_over_noise[ch]:.3g}x noise)" for ch in sensor) +
                         " that are not motion (the integrated gyro residuals account for " +
                         ", ".join(f"{100 * self.sensor_error[ch]:.0f} %" for ch in sensor) +
                         " of them): the attitude sensor's own error")
        covered = self.input_noise_covers()
        near = {ch: r for ch, r in self.residual_over_noise.items()
                if ch not in off_channels and ch not in covered and r > NOISE_RATIO_COLOURED}
        if parts:
            tail = "; ".join(parts)
        elif near:
            # white residuals up to NOISE_RATIO_ADEQUATE x the noise are adequate; say how far
            # they are, not that they are at the noise (a blind audit read "at the sensor noise"
            # beside az at 1.92x)
            tail = (f"residuals white and within {NOISE_RATIO_ADEQUATE:.0f}x the sensor noise (" +
                    ", ".join(f"{ch} {r:.3g}x" for ch, r in sorted(near.items(), key=lambda kv: -kv[1])) +
                    "; the others at it)")
        else:
            tail = "residuals at the sensor noise"
        if covered:
            # an exact model fed noisy speeds predicts the specific force with the thrust's
            # noise in it (a blind audit's az at 1.5x, coloured where the speeds were smoothed)
            tail += ("; " + ", ".join(
                f"{ch} at {self.residual_over_noise[ch]:.3g}x the sensor noise "
                f"({100 * self.whiteness.get(ch, 0.0):.0f} % of lags outside the band)" for ch in covered) +
                ": within what the logged inputs' noise adds to the prediction there (" +
                ", ".join(f"{ch} {self.input_noise[ch] / self.sensor_noise[ch]:.2g}x the sensor noise; "
                          f"the residuals {self.noise_ratio(ch):.2g}x the two together" for ch in covered) + ")")
        below = [ch for ch, r in self.residual_over_noise.items() if r < NOISE_RATIO_BELOW]
        if below:
            tail += ("; residuals below the noise estimated from the measurements in " +
                     ", ".join(f"{ch} ({self.residual_over_noise[ch]:.2g}x)" for ch in below) +
                     ": that estimate takes fast motion for noise (a log rate low for the vehicle's dynamics), "
                     "so these channels are judged against a noise larger than theirs")
        states = self.off_states()
        groups: dict[str, list[str]] = {}
        for n in states:
            groups.setdefault(self.state_words.get(n, ""), []).append(n)
        for words, names in groups.items():
            tail += ("; the shooting gaps of " + ", ".join(f"{n} ({self.systematic_gaps[n]:.3g}x their random part)"
                                                         for n in names) +
                     " are mostly systematic: " + (words or "a force or torque the model lacks acts there over many intervals"))
        return f"{head}. {tail}."

    def as_dict(self) -> dict:
        return {"optimal": self.optimal, "adequate": self.adequate, "step_over_std": _finite(self.step_over_std),
                "state_step_over_noise": _finite(self.state_step_over_noise),
                "gap_over_noise": _finite(self.gap_over_noise), "held": list(self.held),
                "residual_over_noise": {k: _finite(v) for k, v in self.residual_over_noise.items()},
                "whiteness": {k: _finite(v) for k, v in self.whiteness.items()},
                "sensor_noise": {k: _finite(v) for k, v in self.sensor_noise.items()},
                "systematic_gaps": {k: _finite(v) for k, v in self.systematic_gaps.items()},
                "sensor_error": {k: _finite(v) for k, v in self.sensor_error.items()},
                "input_noise": {k: _finite(v) for k, v in self.input_noise.items()},
                "reasons": list(self.reasons), "flightless": self.flightless, "text": self.text()}


def _finite(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


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
   *significant* when that test passes at 1 % **and** some channel's validation ``nrmse``
   falls by at least 5 % (out-of-sample confirmation). The verdict is the best significant candidate,
   or ``None``. When the logged rotor speeds carry notable white noise, the verdict-to-be is
   first extrapolated to noise-free speeds (SIMEX, :mod:`greybox.diagnosis.input_noise`): one
   that is then at its null was the errors in the inputs, and the next is asked.
4. **Add it and watch the error fall.** With ``iterate=True`` the verdict is added, the
   model refitted and the remaining candidates screened again, until nothing significant
   is missing. Candidates that were significant alone but explain nothing once the winner
   is in are reported as confusable, with the manoeuvre that would tell them apart. Then
   *backward elimination* (:mod:`greybox.diagnosis.elimination`): each earlier verdict is
   judged again against the final model less itself, by the same test; one that no longer
   stands (a stand-in for part of what a later verdict explains) is left out, with a warning.
   When nothing stands in the first round and the body rates stay far off (a random torque,
   turbulence, that no candidate holds, hiding any other effect in the process noise), the
   candidates are judged again from a baseline holding that torque as a disturbance
   (:func:`~greybox.diagnosis.closed_loop.disturbance_baseline`: a random-walk torque, process
   noise on it alone); what stands there is the verdict, and the final model keeps the
   disturbance.
5. **Beyond the catalogue.** The baseline's residual generalised forces (body-frame
   force per unit mass ``fx, fy, fz`` and angular acceleration ``mx, my, mz``) on the
   estimation data, explained by a sparse combination of named features (body air velocity,
   rates, rotor speeds, height, time, logged signals and their products) with an
   autocorrelation-consistent significance test; a combination becomes an effect
   (``discovered_mz``...) refitted by the ordinary fitter and judged on the validation data
   like a candidate (:mod:`greybox.diagnosis.discovery`). Not run when the baseline fit is not
   certified: then it "cannot tell".
"""
from __future__ import annotations

# The package's modules, along the workflow's steps: ``analysis`` (where the model fails:
# residuals, regimes, command imbalance), ``screening`` (a candidate's score statistic and
# refit, and the statistics a refit is judged by), ``ranking`` (one round over the
# candidates), ``closed_loop`` (a torque taken as a disturbance: b's closed-loop bias, the
# baseline under turbulence), ``predictability`` (whether the logged commands' torque shows in
# the attitude at all, data only), ``input_noise`` (noise on the logged speeds: SIMEX),
# ``consistency`` (the baseline on the two halves of the data), ``discovery``
# (residual forces beyond the catalogue, step 5), ``elimination`` (each verdict judged again
# in the final model), ``results`` (Diagnosis, its JSON and
# summary), ``report`` (the HTML report) and ``workflow`` (:func:`diagnose`).
# the constants are public names of greybox.diagnosis as well
from .analysis import (IMBALANCE_NOTABLE, CommandImbalance, Finding, ThrustAtTop, command_imbalance, residual_analysis,
                       thrust_at_top)
from .closed_loop import TIGHT_PROCESS_NOISE
from .consistency import CONSISTENCY_MIN_CHANGE, CONSISTENCY_Z
from .discovery import MAX_THRUST_SHIFT
from .fit_checks import fit_warnings
from .input_noise import InputNoise, SimexCheck, input_noise, simex_check
from .predictability import CommandPredictability, command_predictability
from .ranking import (ALPHA, COLD_CONTINUE, COLD_SCREEN_ITER, MAX_VALIDATION_LOSS, MIN_EXPLAINED, MIN_EXPLAINED_INADEQUATE,
                      MIN_VALIDATION_GAIN, N_REFIT, PARTNER_SCORE_SHARE, default_candidates, order_refitted,
                      validation_ties)
from .results import CandidateResult, Diagnosis, Discovered, DiscoveredTerm, Round
from .screening import NEGLIGIBLE_FRACTION
from .workflow import UNEXPLAINED_RATIO, diagnose, distinguishing_manoeuvre

__all__ = ["diagnose", "fit_warnings", "Diagnosis", "CandidateResult", "Finding", "residual_analysis", "ALPHA",
           "MIN_VALIDATION_GAIN", "MIN_EXPLAINED", "MIN_EXPLAINED_INADEQUATE", "distinguishing_manoeuvre",
           "CommandImbalance", "command_imbalance", "default_candidates", "Discovered", "DiscoveredTerm",
           "order_refitted", "validation_ties", "PARTNER_SCORE_SHARE", "MAX_THRUST_SHIFT",
           "CommandPredictability", "command_predictability", "InputNoise", "input_noise", "SimexCheck",
           "simex_check", "ThrustAtTop", "thrust_at_top"]

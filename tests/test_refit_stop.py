"""A solver's caller can stop it (:class:`GaussNewton`'s ``stop``), and a diagnosis stops a
candidate's refit that holds the candidate on a bound beyond what it physically does
(:class:`~greybox.diagnosis.screening.HeldBeyondPlausible`)."""
from importlib import resources

import numpy as np
import pytest

from greybox import QuadrotorModel, load_airframe
from greybox.errors import ConvergenceWarning
from greybox.diagnosis.screening import HELD_ITERATIONS, HeldBeyondPlausible
from greybox.fitting import STOPPED, FitSession, GaussNewton, fit
from greybox.shooting import default_interval, free_indices, noise_levels
from greybox.synth import synthesize

PAPER = resources.files("greybox") / "data" / "airframes" / "paper.toml"


def test_a_stop_rule_ends_the_fit_where_it_says_with_no_retry():
    """Words from ``stop`` after the first accepted step end the fit there: no solving on
    with fresh damping, no second start with a trust region (each would call it again)."""
    model = QuadrotorModel(load_airframe(PAPER))
    log = synthesize(model, duration=4.0, seed=3).log
    p0 = model.default_parameters().copy()
    p0[:2] *= (1.5, 0.5)
    seen = []

    def stop(ses, th):
        seen.append(th.copy())
        return "enough for this test" if len(seen) == 1 else ""

    with pytest.warns(ConvergenceWarning, match="stopped by its caller"):
        res = fit(model, log, p0=p0, process_noise=None, solver=GaussNewton(stop=stop))
    assert len(seen) == 1
    assert res.status.startswith(STOPPED + "enough for this test") and not res.converged
    # the same fit without the rule runs on to its certified optimum, K_T within 1 %
    full = fit(model, log, p0=p0, process_noise=None)
    assert full.converged and abs(full.value("K_T") / model.default_parameters()[0] - 1) < 0.01


def test_a_refit_held_on_a_bound_beyond_the_plausible_is_stopped():
    """A thrust curve's k_Tw on its lower bound (-0.6, beyond the plausible |k_Tw| <= 0.5)
    for three accepted steps in a row stops the refit, in words; a step off the bound starts
    the count again; beyond the plausible but off the bound, or on a bound within it, never."""
    af = load_airframe(PAPER)
    base = QuadrotorModel(af)
    model = QuadrotorModel(af, [e.name for e in base.effects] + ["thrust_curve"])
    log = synthesize(base, duration=2.0, seed=3).log
    p = model.default_parameters()
    ses = FitSession(model, [log], free_indices(model, None, None), p, noise_levels([log], None),
                     default_interval([log]), "never", lambda _m: None)
    j = [model.param_names[i] for i in ses.free_idx].index("k_Tw")
    th = ses.theta(p)

    def at(v):
        t = th.copy()
        t[j] = v / ses.scale[j]
        return t

    lower = ses.lo_s[j] * ses.scale[j]
    assert np.isclose(lower, -0.6)
    rule = HeldBeyondPlausible("thrust_curve")
    assert [rule(ses, at(lower)) for _ in range(HELD_ITERATIONS - 1)] == [""] * (HELD_ITERATIONS - 1)
    assert rule(ses, at(0.1)) == ""                     # off the bound: counted from 0 again
    said = [rule(ses, at(lower)) for _ in range(HELD_ITERATIONS)]
    assert said[:-1] == [""] * (HELD_ITERATIONS - 1)
    assert "k_Tw = -0.6" in said[-1] and "beyond what thrust_curve physically does" in said[-1], said[-1]
    assert f"held on its bound for {HELD_ITERATIONS} steps" in said[-1]
    rule = HeldBeyondPlausible("thrust_curve")
    assert [rule(ses, at(-0.55)) for _ in range(5)] == [""] * 5      # beyond, but not held on a bound
    # the upper bound (1.0) is beyond the plausible too; a component of another effect on its
    # bound is not this effect's
    assert [rule(ses, at(1.0)) for _ in range(HELD_ITERATIONS)][-1] != ""
    other = HeldBeyondPlausible("yaw_torque")
    assert [other(ses, at(lower)) for _ in range(5)] == [""] * 5

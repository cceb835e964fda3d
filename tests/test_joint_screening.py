"""Several candidates screened from one evaluation (:func:`screen_jointly`) give each the
statistic of its own screen (:func:`screen`): the model extended by all of them, each
candidate's step taken with the others' parameters held at their null values."""
from importlib import resources

import numpy as np
import pytest

import greybox.effects as fx
from greybox import QuadrotorModel, load_airframe
from greybox.diagnosis.screening import screen, screen_jointly
from greybox.parameters import Parameter
from greybox.fitting import fit
from greybox.model import OUTPUTS
from greybox.synth import synthesize

PAPER = resources.files("greybox") / "data" / "airframes" / "paper.toml"
NAMES = ["ground_effect", "wind", "thrust_drift", "attitude_bias", "cog_offset", "motor_lag", "quadratic_drag"]


@pytest.fixture(scope="module")
def baseline():
    """A flight with a ground effect the model lacks (hard continuity), and the model's fit."""
    af = load_airframe(PAPER)
    model = QuadrotorModel(af)
    truth = QuadrotorModel(af, [e.name for e in model.effects] + ["ground_effect"])
    p = truth.parameter_vector({"k_ge": 0.5})
    log = synthesize(truth, p, duration=8.0, seed=7, manoeuvres=["hover", "step_z", "yaw", "step_x"]).log
    est = log.split(0.8)[0]
    res = fit(model, est, process_noise=None)
    assert res.converged
    return model, res, est


def test_joint_statistics_are_each_candidates_own(baseline):
    model, res, est = baseline
    sigma = np.array([res.sigma.get(ch, 1.0) for ch in OUTPUTS])
    together = screen_jointly(model, res, [est], NAMES, sigma, "never")
    assert set(together) == set(NAMES) - {"motor_lag"}       # adds states, cannot vanish: alone
    for name, (score, df) in together.items():
        alone, df_alone = screen(model, res, [est], name, sigma, "never")
        assert df == df_alone
        assert score == pytest.approx(alone, rel=1e-8, abs=1e-6), name
    # several flights (per-flight copies, degrees of freedom per copy): one screen each
    assert screen_jointly(model, res, [est, est], NAMES, sigma, "never") == {}
    # statistics worth comparing: most candidates explain something of what the model lacks
    assert sum(score > 10 for score, _ in together.values()) >= 3, together


def test_an_effect_that_is_not_nothing_at_its_null_stops_the_joint_screen(baseline):
    """An effect of one's own that pushes at its null value too would give every other
    candidate a wrong step: the extended model's cost at the baseline is not the baseline's,
    and nothing is taken from the joint evaluation."""
    model, res, est = baseline

    @fx.register
    class AlwaysPushing(fx.Effect):
        name = "test_always_pushing"
        summary = "a force that is there at its null value"

        def parameters(self, airframe):
            return [Parameter("k_push", 1, 0.0, "N", -1.0, 1.0, 0.01, 0.0, True, "push", self.name)]

        def add_forces(self, ctx):
            ctx.force_world += np.array([0.0, 0.0, 0.05]) + ctx.params["k_push"] * np.array([1.0, 0.0, 0.0])

    try:
        sigma = np.array([res.sigma.get(ch, 1.0) for ch in OUTPUTS])
        assert screen_jointly(model, res, [est], ["wind", "test_always_pushing"], sigma, "never") == {}
        assert set(screen_jointly(model, res, [est], ["wind", "thrust_drift"], sigma, "never")) == \
            {"wind", "thrust_drift"}
    finally:
        fx.unregister("test_always_pushing")


@pytest.mark.slow
def test_a_screening_starts_no_compiler_but_takes_a_cached_library(baseline, monkeypatch, tmp_path):
    """A screening evaluates each model once: with ``compile="auto"`` it must not start the
    C compiler on it (the model of a round's candidates together is new each round and took
    the compiler 25 s on a real flight), even where "auto" would build after any time on the
    virtual machine; a library already in the cache is used."""
    from greybox import codegen, shooting
    from greybox.integrate import log_substeps
    from greybox.shooting import ShootingProblem, free_indices
    if codegen.compiler_available() is None:
        pytest.skip("no C compiler")
    model, res, est = baseline
    monkeypatch.setenv("GREYBOX_CACHE", str(tmp_path))
    monkeypatch.setattr(shooting, "BACKGROUND_BUILD_AT", 0.0)     # "auto" builds after any VM time
    started = []
    monkeypatch.setattr(codegen, "start_build", lambda f, **kw: started.append(f.name()))
    free_idx = free_indices(model, list(res.free_names), None)
    n_sub = log_substeps([est])
    auto = ShootingProblem(model, free_idx, res.interval, n_sub, "auto")
    auto.account("blocks", 1.0)
    assert started == ["gb_step_blocks"]                          # the contrast: "auto" builds
    started.clear()
    cached = ShootingProblem(model, free_idx, res.interval, n_sub, "cached")
    cached.account("blocks", 1.0)
    assert started == [] and cached.how == "virtual machine"
    sigma = np.array([res.sigma.get(ch, 1.0) for ch in OUTPUTS])
    together = screen_jointly(model, res, [est], NAMES, sigma, "auto")
    lag = screen(model, res, [est], "motor_lag", sigma, "auto")
    assert started == []
    assert together == screen_jointly(model, res, [est], NAMES, sigma, "never")
    assert lag[0] == pytest.approx(screen(model, res, [est], "motor_lag", sigma, "never")[0], rel=1e-10)
    # a fit in "cached" mode (public: fit(compile="cached")) builds nothing and gets the same optimum
    again = fit(model, est, process_noise=None, compile="cached")
    assert started == [] and again.converged
    assert np.allclose(again.p, res.p, rtol=1e-6, atol=1e-12)
    # a library in the cache is taken
    codegen.compiled(ShootingProblem.shared_step_functions(model, free_idx, n_sub)["blocks"])
    assert ShootingProblem(model, free_idx, res.interval, n_sub, "cached").how == "cached"

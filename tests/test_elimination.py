"""Backward elimination (greybox.diagnosis.elimination) on another simulator's flights: a
verdict that a later one explains away is left out of the final model, and one that is there
stands, on the Wald screen and on its refit alike."""
import pytest

from greybox import QuadrotorModel, diagnose, load_airframe, load_log
from greybox.diagnosis import ALPHA
from greybox.diagnosis import elimination
from greybox.diagnosis.elimination import Removal, backward_elimination, judge_removal, wald_p_value
from greybox.effects import by_name
from greybox.fitting import fit
from greybox.synth import SensorSpec, synthesize
from greybox.validation import predict_after_fit

from conftest import AIRFRAMES

from peer_sim import PeerBattery, PeerEffects, PeerSensors, PeerVehicle, fly, write_case

N_TESTS = 12     # a round's candidates, as the diagnosis counts them for Bonferroni
FORCED_DURATION = 10.0


@pytest.fixture(scope="module")
def drift_beside_battery(tmp_path_factory):
    """Two 12-s flights of the peer simulator's 30 g vehicle (motors quick, 2 ms) whose
    open-loop ESCs drive the motors from a battery that sags with the current and the charge
    drawn, commands and ``vbat`` logged; fitted with ``thrust_drift`` (a thrust falling in
    time, the battery's stand-in) beside ``battery_voltage``."""
    d = tmp_path_factory.mktemp("elimination")
    veh = PeerVehicle.crazyflie(log_rate=100.0, tau_motor=0.002)
    flights = [fly(veh, duration=12.0, seed=s, effects=PeerEffects(battery=PeerBattery()),
                   sensors=PeerSensors(log_commands=True)) for s in (1, 2)]
    paths = [write_case(f, d, name=f"seed{s}") for s, f in zip((1, 2), flights)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"])) + by_name("thrust_drift") + by_name("battery_voltage")
    est, val = [load_log(paths[0]["log"])], [load_log(paths[1]["log"])]
    res = fit(model, est, process_noise="auto")
    assert res.converged, res.status
    return res, predict_after_fit(res, est, val), est, val, flights[0].truth["greybox_equivalent"]


@pytest.mark.slow
def test_a_thrust_drift_that_stood_in_for_the_battery_is_left_out(drift_beside_battery):
    res, pred, est, val, truth = drift_beside_battery
    # the Wald screen does not spare the drift (2.5 std at most): it is refitted out
    assert wald_p_value(res, "thrust_drift", N_TESTS) > elimination.WALD_MARGIN * ALPHA
    assert wald_p_value(res, "battery_voltage", N_TESTS) < 1e-20
    lines = []
    final, fpred, removed = backward_elimination(res, pred, [("thrust_drift", N_TESTS), ("battery_voltage", N_TESTS)],
                                                 est, val, say=lines.append)
    assert [r.effect for r in removed] == ["thrust_drift"], lines
    gone = removed[0]
    assert gone.p_value >= ALPHA and gone.lr is not None and "not significant" in gone.reason
    assert gone.prediction is not None and gone.fit.converged
    assert final.converged and "thrust_drift" not in final.model.effect_names
    assert "battery_voltage" in final.model.effect_names
    # the battery was judged again without the drift, and stands
    assert any("battery_voltage still stand" in ln and "yes" in ln for ln in lines), lines
    assert final.value("K_T") == pytest.approx(truth["K_T"], rel=0.03)
    assert final.value("K_vbat") > 0.5 * truth["K_vbat"]
    # leaving the drift out costs the validation less than a candidate must gain to be confirmed
    # (2.5 % here: the drift follows part of the sag's curvature, which greybox's linear
    # battery form misses, but the estimation data do not support it)
    assert fpred.total < 1.05 * pred.total


def test_the_battery_that_is_there_stands_on_its_refit_too(drift_beside_battery, monkeypatch):
    """With the Wald screen off, the battery's removal is refitted and judged: significant, it
    stands. The rounds' last verdict is judged again too (its Wald screen not passed): the
    drift taken as the last, not the first, still goes."""
    res, pred, est, val, _ = drift_beside_battery
    monkeypatch.setattr(elimination, "WALD_MARGIN", 0.0)
    r = judge_removal(res, pred, "battery_voltage", est, val, N_TESTS)
    assert r.stands, r.reason
    assert r.fit is not None and r.fit.converged and r.p_value < 1e-10 and r.prediction is None
    # the drift as the rounds' last verdict, the battery first: the drift goes, the battery stands
    final, _, removed = backward_elimination(res, pred, [("battery_voltage", N_TESTS), ("thrust_drift", N_TESTS)],
                                             est, val)
    assert [r.effect for r in removed] == ["thrust_drift"] and "not significant" in removed[0].reason
    assert "battery_voltage" in final.model.effect_names and "thrust_drift" not in final.model.effect_names


@pytest.mark.slow
def test_when_round_ones_verdict_no_longer_stands_the_verdict_moves_on(monkeypatch):
    """The workflow's side of a removal. No foreign flight was found where forward selection
    takes a stand-in first (the peer's battery wins round 1 over the drift even with a 0.15-V
    noisy ``vbat``), so the judgement is forced here: round 1's verdict, refitted out for real,
    is declared not to stand. The final model leaves it out, its ranking entry says why, a
    warning names the later verdict, and the verdict becomes round 2's in the summary and the
    JSON alike, with the final fit certified."""
    paper = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    true = paper + by_name("ground_effect") + by_name("thrust_drift")
    p = true.default_parameters()
    p[true.param_names.index("k_ge")] = 1.806e-3
    p[true.param_names.index("K_T_drift")] = -0.002
    flight = synthesize(true, p, duration=FORCED_DURATION, seed=3, sensors=SensorSpec(rate=100.0, vision_rate=50.0),
                        manoeuvres=["hover", "ground", "step_z", "yaw", "step_x", "ground"])
    real = elimination.judge_removal
    forced = []

    def judged(res, pred, effect, est, val, n_tests, compile="auto"):
        # the first judged is round 1's verdict (checked below): judged in the rounds' order
        r = real(res, pred, effect, est, val, n_tests, compile)
        if forced:
            return r
        assert r.fit is not None and r.fit.converged, r.reason     # the Wald screen is off: refitted
        forced.append(effect)
        return Removal(effect, False, "forced by the test", r.lr, r.p_value, r.fit,
                       predict_after_fit(r.fit, est, val, horizon=pred.horizon))

    monkeypatch.setattr(elimination, "WALD_MARGIN", 0.0)
    monkeypatch.setattr(elimination, "judge_removal", judged)
    d = diagnose(paper, flight.log, candidates=["ground_effect", "thrust_drift", "wind"])
    picks = [rd.verdict for rd in d.rounds if rd.verdict]
    assert len(picks) == 2 and set(picks) == {"ground_effect", "thrust_drift"}, d.summary()
    assert forced == [picks[0]]
    assert d.verdict == picks[1]
    assert picks[0] not in d.final_model.effect_names and picks[1] in d.final_model.effect_names
    assert d.final_fit.converged
    entry = next(c for c in d.ranking if c.effect == picks[0])
    assert not entry.significant and "backward elimination" in entry.reason
    significant = [c.significant for c in d.ranking]      # round 1's ranking: what still stands first
    assert significant == sorted(significant, reverse=True)
    # the verdict's share is its own round's, measured on what round 1's pick left
    assert f"verdict: {picks[1]}; it removes" in d.summary() and "that round 2's model" in d.summary()
    assert any(w.startswith(f"{picks[0]}, the verdict of round 1, no longer stands once {picks[1]} is in the model")
               for w in d.warnings), d.warnings
    js = d.as_json()
    assert js["verdict"] == picks[1] and picks[0] not in js["added"] and picks[1] in js["added"]

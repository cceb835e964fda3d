"""Backward elimination (greybox.diagnosis.elimination) on another simulator's flights: a
verdict that a later one explains away is left out of the final model, and one that is there
stands, on the Wald screen and on its refit alike."""
import pytest

from greybox import QuadrotorModel, load_airframe, load_log
from greybox.diagnosis import ALPHA
from greybox.diagnosis import elimination
from greybox.diagnosis.elimination import backward_elimination, judge_removal, wald_p_value
from greybox.effects import by_name
from greybox.fitting import fit
from greybox.validation import predict_after_fit

from peer_sim import PeerBattery, PeerEffects, PeerSensors, PeerVehicle, fly, write_case

N_TESTS = 12     # a round's candidates, as the diagnosis counts them for Bonferroni


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
    stands; the last verdict of the rounds is judged only after a removal."""
    res, pred, est, val, _ = drift_beside_battery
    monkeypatch.setattr(elimination, "WALD_MARGIN", 0.0)
    r = judge_removal(res, pred, "battery_voltage", est, val, N_TESTS)
    assert r.stands, r.reason
    assert r.fit is not None and r.fit.converged and r.p_value < 1e-10 and r.prediction is None
    # the battery as the rounds' last verdict, the drift first: the drift goes, the battery stands
    final, _, removed = backward_elimination(res, pred, [("battery_voltage", N_TESTS), ("thrust_drift", N_TESTS)],
                                             est, val)
    assert removed == [] and set(final.model.effect_names) >= {"battery_voltage", "thrust_drift"}

"""How the logged commands predict the attitude (greybox.diagnosis.predictability), on flights
greybox did not make: the peer simulator's 30 g vehicle with and without a random torque the
controller cancels, and real Crazyflie flights."""
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from greybox import QuadrotorModel, load_airframe, load_log
from greybox.airframe import airframe_from_dict
from greybox.diagnosis import command_predictability
from greybox.diagnosis.predictability import HARDLY_BETTER, HIDDEN_SHARE

from peer_sim import PeerEffects, PeerVehicle, fly, write_case

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "nanobench"


@pytest.fixture(scope="module")
def peer_flights(tmp_path_factory):
    """The 30 g peer vehicle logged at 100 Hz (the rate of the real flights' logs), 12 s, its
    ESCs' speeds logged: calm, and under a random torque (5e-4 N m RMS, 1-s correlation)."""
    veh = PeerVehicle.crazyflie(log_rate=100.0)
    out = {}
    for name, turbulence in (("calm", 0.0), ("turbulent", 5e-4)):
        f = fly(veh, duration=12.0, seed=1, effects=PeerEffects(turbulence=turbulence), low_hovers=False)
        paths = write_case(f, tmp_path_factory.mktemp(name), name=name)
        out[name] = (QuadrotorModel(load_airframe(paths["airframe"])), load_log(paths["log"]))
    return veh, out


def test_calm_flight_the_commands_torque_predicts_and_its_gain_is_the_vehicles(peer_flights):
    """Without an unseen torque the plant form predicts roll and pitch far better than the
    naive predictor, and its gain, taken with the true K_T, is the vehicle's torque per command
    (the motors' 20 ms lag is among its forms). Nothing is hidden."""
    veh, flights = peer_flights
    model, log = flights["calm"]
    cp = command_predictability(model, log, k_t=veh.K_T)
    for axis in ("roll", "pitch"):
        for h in (0.25, 0.5):
            assert cp.ratio("plant", axis, h) < 0.5, (axis, h, cp.as_dict())
            assert not cp.torque_hidden(axis, h)
        k = cp.horizons.index(0.25)
        assert cp.plant_gain[axis][k] == pytest.approx(1.0, abs=0.15), cp.as_dict()
    assert cp.text(0.25) == ""
    # the yaw's gain is the true b/K_T
    assert cp.plant_gain["yaw"][0] == pytest.approx(veh.b / veh.K_T, rel=0.15)


def test_a_torque_the_controller_cancels_hides_the_commands_torque(peer_flights):
    """Under the random torque the controller answers, the commands' roll and pitch torque no
    longer shows in the attitude a quarter and a half second ahead: the plant form predicts no
    better than naive, with a few per cent of the vehicle's torque per command. The words say so,
    and that the model's losing channels are why."""
    veh, flights = peer_flights
    model, log = flights["turbulent"]
    cp = command_predictability(model, log, k_t=veh.K_T)
    for h in (0.25, 0.5):
        assert cp.hidden_axes(h) == ["roll", "pitch"], cp.as_dict()
        for axis in ("roll", "pitch"):
            assert cp.ratio("plant", axis, h) > HARDLY_BETTER
            assert cp.plant_gain[axis][cp.horizons.index(h)] < HIDDEN_SHARE
    text = cp.text(0.25, losing=["phi", "x"])
    assert "does not show in the roll and pitch" in text and "the model's phi prediction" in text
    assert "phi, x" not in text              # a position channel is not the torque's to explain
    d = cp.as_dict()
    assert d["axes"]["roll"]["torque_hidden"] == [True, True] and d["horizons"] == [0.25, 0.5]


def test_needs_a_gyro_and_rotor_speeds(peer_flights):
    _, flights = peer_flights
    model, log = flights["calm"]
    no_gyro = replace(log, outputs=log.outputs.copy())
    for c in ("p", "q", "r"):
        no_gyro.outputs[:, no_gyro.output_names.index(c)] = np.nan
    assert command_predictability(model, no_gyro) is None
    short = log.split(0.05)[0]          # under a second: nothing held out to speak of
    assert command_predictability(model, short) is None


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/realdata not beside the clone")
def test_real_crazyflie_flights_commands_torque_is_hidden():
    """On real Crazyflie flights, slow and fast, the logged commands' roll and pitch torque
    does not show in the attitude (plant form 0.94-1.02 of the naive error, 0-6 % of the
    published torque per command), while the commands' change predicts it 20-40 % better than
    naive: the controller's answer (README, "Real flights")."""
    from greybox.importers import crazyflie_airframe_toml, import_nanobench
    for name in ("B6_linear_ramp_rep2.csv", "B3_figure8_fast_rep1.csv"):
        imp = import_nanobench(REAL / name)
        model = QuadrotorModel(airframe_from_dict(tomllib.loads(crazyflie_airframe_toml(0.030, imp.hover_rotor_speed))))
        cp = command_predictability(model, imp.log)
        assert cp.hidden_axes(0.25) == ["roll", "pitch"], (name, cp.as_dict())
        for axis in ("roll", "pitch"):
            assert cp.ratio("change", axis, 0.25) < 0.85, (name, axis, cp.as_dict())
            assert cp.plant_gain[axis][0] < 0.1


def test_the_diagnosis_says_why_when_its_model_loses_on_a_hidden_axis(peer_flights):
    """The diagnosis's summary and JSON (wiring): the sentence comes where the final model loses
    to the naive predictor on an angle whose torque is hidden, and not where it beats it."""
    from greybox.diagnosis import Diagnosis
    from greybox.validation import HorizonErrors
    veh, flights = peer_flights
    model, log = flights["turbulent"]
    cp = command_predictability(model, log, k_t=veh.K_T)

    def diagnosis(phi_model):
        he = HorizonErrors([0.25, 0.5], {"x": [0.01, 0.05], "phi": phi_model, "theta": [0.01, 0.02]},
                           {"x": [0.02, 0.06], "phi": [0.04, 0.08], "theta": [0.03, 0.06]})
        return Diagnosis(model, None, None, [], {}, {}, [], None, [], final_horizons=he, command_predictability=cp)

    losing = diagnosis([0.08, 0.2])
    assert "the model's phi prediction" in losing.horizon_why()
    assert any(line.startswith("   why not on attitude: over 0.25 s") for line in losing.horizon_lines())
    winning = diagnosis([0.02, 0.05])
    assert winning.horizon_why() == "" and not any("why not" in line for line in winning.horizon_lines())
    assert Diagnosis(model, None, None, [], {}, {}, [], None, [], final_horizons=losing.final_horizons).horizon_why() == ""

import json

import numpy as np
import pytest

from greybox import QuadrotorModel, simulate
from greybox.cli import main
from greybox.data import load_log
from greybox.synth import DEFAULT_MANOEUVRES, MANOEUVRES, model_with_hidden_effects, reference_trajectory, synthesize


@pytest.fixture(scope="module")
def flight(request):
    from conftest import make_airframe
    m = QuadrotorModel(make_airframe("plus"))
    model, p = model_with_hidden_effects(m, ["ground_effect", "motor_lag"])
    return synthesize(model, p, duration=20.0, seed=7)


def test_flight_follows_reference_and_stays_airborne(flight):
    X = flight.states
    err = np.abs(X[:, :3] - flight.reference[:, :3])
    assert np.median(err) < 0.05 and err.max() < 1.0
    assert np.all(X[:, 2] < -0.05)                 # never touches the ground (NED z < 0)
    assert np.abs(X[:, 3:5]).max() < 0.6


def test_multirate_sampling_and_noise(flight):
    log, s = flight.log, flight.sensors
    assert log.rate("phi") == pytest.approx(s.rate, rel=1e-6)
    n_vis = np.isfinite(log.output("x")).sum()
    expected = flight.log.duration * s.vision_rate
    assert 0.75 * expected < n_vis < 0.97 * expected  # dropouts remove some frames
    k = np.isfinite(log.output("x"))
    resid = log.output("x")[k] - flight.outputs_true[k, 0]
    assert np.std(resid) == pytest.approx(s.pos_noise, rel=0.15)
    assert np.std(log.output("phi") - flight.outputs_true[:, 3]) == pytest.approx(s.att_noise, rel=0.05)


def test_logged_inputs_replay_the_flight(flight):
    sim = simulate(flight.model, flight.log.t, flight.log.inputs, flight.parameters, flight.states[0])
    np.testing.assert_allclose(sim.states, flight.states, atol=1e-9)


def test_hidden_effect_values(flight):
    d = flight.model.parameter_dict(flight.parameters)
    assert d["k_ge"] > 0 and d["tau_m"] == 0.03
    assert flight.truth()["effects"][-2:] == ["ground_effect", "motor_lag"]


def test_seeded_and_reproducible(plus_airframe):
    m = QuadrotorModel(plus_airframe)
    a = synthesize(m, duration=5, seed=3)
    b = synthesize(m, duration=5, seed=3)
    c = synthesize(m, duration=5, seed=4)
    np.testing.assert_array_equal(a.log.outputs, b.log.outputs)
    assert not np.allclose(np.nan_to_num(a.log.outputs), np.nan_to_num(c.log.outputs))


def test_reference_covers_manoeuvres():
    t = np.arange(0, 60, 0.01)
    ref = reference_trajectory(t, list(MANOEUVRES), np.random.default_rng(0))
    assert ref[:, 2].max() == pytest.approx(-0.15, abs=1e-6)    # the low pass near the ground
    assert np.abs(ref[:, 3]).max() == pytest.approx(np.radians(60))
    assert np.abs(np.gradient(ref[:, 0], t)).max() > 2.0 or np.abs(np.gradient(ref[:, 1], t)).max() > 2.0


def test_sprint_is_a_fast_diagonal_and_not_in_the_default_flight():
    t = np.arange(0, 12, 0.005)
    ref = reference_trajectory(t, ["sprint"], np.random.default_rng(1))
    vx, vy = np.gradient(ref[:, 0], t), np.gradient(ref[:, 1], t)
    speed = np.hypot(vx, vy)
    assert 5.0 < speed.max() < 7.0                       # min-jerk: 1.875 * 6 m / 1.8 s = 6.25 m/s
    k = np.argmax(speed)
    assert abs(abs(vx[k]) - abs(vy[k])) < 1e-6 * speed[k]   # diagonal: x and y both move
    assert "sprint" in MANOEUVRES and "sprint" not in DEFAULT_MANOEUVRES


def test_synth_cli(tmp_path, paper_airframe_path):
    rc = main(["synth", "--airframe", str(paper_airframe_path), "--out", str(tmp_path / "f.csv"),
               "--effects", "wind", "--set", "wind=1,0", "--duration", "4", "--seed", "2",
               "--rate", "500", "--vision-rate", "50", "--json", str(tmp_path / "truth.json")])
    assert rc == 0
    log = load_log(tmp_path / "f.csv")
    assert len(log) == 2001 and log.rate("x") < 55
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert truth["parameters"]["wind[0]"] == 1.0 and truth["seed"] == 2 and "wind" in truth["effects"]


def test_synth_cli_errors(tmp_path, paper_airframe_path, capsys):
    rc = main(["synth", "--airframe", str(paper_airframe_path), "--out", str(tmp_path / "f.csv"),
               "--manoeuvres", "loop"])
    assert rc == 2 and "unknown manoeuvre 'loop'" in capsys.readouterr().err
    assert not (tmp_path / "f.csv").exists()

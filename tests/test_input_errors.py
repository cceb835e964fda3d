"""The process noise that white noise on the logged inputs gives the states
(greybox.fitting.input_errors): checked by hand on a flight of the peer simulator (not
greybox's), and as the floor that makes a soft fit's answer independent of its start on the
blind audit's hexacopter (tests/hexa_sim.py)."""
from dataclasses import replace

import numpy as np
import pytest

from greybox import QuadrotorModel, effects, load_airframe, load_log
from greybox.fitting import fit, initial_node_states
from greybox.fitting.input_errors import INPUT_NOISE_SHARE, input_column_noise, input_noise_process_scale

import hexa_sim
from peer_sim import PeerSensors, PeerVehicle, fly, write_case


@pytest.fixture(scope="module")
def noisy_cf(tmp_path_factory):
    """A 30 g vehicle, 4 s at 500 Hz, 1 % noise on its logged speeds."""
    d = tmp_path_factory.mktemp("cf")
    fl = fly(PeerVehicle.crazyflie(), duration=4.0, seed=5, sensors=PeerSensors(speed_noise=0.01))
    paths = write_case(fl, d, K_T_factor=1.0, b_factor=1.0)
    model = QuadrotorModel(load_airframe(paths["airframe"]))
    return model, model.prepare_log(load_log(paths["log"])), fl


def test_the_floor_is_the_random_walk_the_speeds_noise_gives_by_hand(noisy_cf):
    """Near level flight the vertical acceleration moves with each rotor's thrust 2 K_T w_i / m
    per rad/s, the yaw acceleration with its reaction torque 2 b w_i / J_z: over one row each
    rotor's noise sigma_i adds independently, and over an interval of n rows sqrt(n) rows'
    worth. The floor is that, within 3 % (the attitude's cosines, the gyroscopic term)."""
    model, log, _ = noisy_cf
    sigma, share = input_column_noise(model, log)
    assert share >= INPUT_NOISE_SHARE
    assert np.all((sigma > 0.005 * 1800) & (sigma < 0.015 * 1800))       # 1 % of ~1800 rad/s
    p = model.default_parameters()
    interval = 25
    idx = np.arange(0, len(log), interval)
    X = initial_node_states(model, log, idx, p)
    floor = input_noise_process_scale(model, [log], [idx], X, p, interval)[0]
    af = model.airframe
    K_T, b = model.parameter_dict(p)["K_T"], model.parameter_dict(p)["b"]
    rows = idx[:-1]
    dt = float(np.median(np.diff(log.t)))
    w = log.inputs[rows, :4]
    vz_row = np.sqrt(np.mean(np.sum((2 * K_T * w * sigma / af.mass) ** 2, axis=1))) * dt
    r_row = np.sqrt(np.mean(np.sum((2 * b * w * sigma / af.inertia[2, 2]) ** 2, axis=1))) * dt
    names = model.state_names
    assert floor[names.index("vz")] == pytest.approx(vz_row * np.sqrt(interval), rel=0.03)
    assert floor[names.index("r")] == pytest.approx(r_row * np.sqrt(interval), rel=0.03)
    for s in ("x", "y", "z", "phi", "theta", "psi"):      # integrals of the noise, not driven by it
        assert floor[names.index(s)] == 0.0


def test_inputs_without_notable_noise_set_no_floor(noisy_cf):
    """The same flight's true speeds (the simulator's states, no telemetry noise): no input's
    high-frequency content reaches 1 % of its variance, and there is no floor."""
    model, log, fl = noisy_cf
    clean = replace(log, inputs=np.asarray(fl.states[:, 13:17], dtype=float).copy())
    _, share = input_column_noise(model, clean)
    assert share < INPUT_NOISE_SHARE
    idx = np.arange(0, len(clean), 25)
    p = model.default_parameters()
    assert input_noise_process_scale(model, [clean], [idx], initial_node_states(model, clean, idx, p), p, 25) is None


@pytest.mark.slow
def test_a_soft_fit_on_noisy_speeds_ends_where_the_data_put_it_from_either_start(tmp_path):
    """The audit's hexacopter with a 15, -10 mm CoG offset and 1 % speed noise, fitted with
    sampled_inputs and cog_offset from the airframe's guesses (K_T x 1.4, b x 0.6, Kd x 0.5)
    and from a start near the answer with drag 30 % low: without the floor the second start's
    vertical process noise collapsed (3.5e-7 m/s, the noise gives 9e-4) and its drag stayed
    0.165 ± 0.027; with it both starts give the drag within 3 std of 0.25 and of each other."""
    est_path = tmp_path / "cog.csv"
    hexa_sim.fly("cog", 41, 36.0, str(est_path), None, speed_noise=0.01)
    hexa_sim.write_airframe(tmp_path / "airframe.toml", 1.4, 0.6, 0.5)
    base = QuadrotorModel(load_airframe(tmp_path / "airframe.toml"))
    model = base + effects.by_name("sampled_inputs") + effects.by_name("cog_offset")
    est = load_log(est_path)
    near = model.parameter_vector({"K_T": hexa_sim.KT, "b": hexa_sim.BQ, "Kd": list(0.7 * hexa_sim.KD),
                                   "s_lead": 0.37, "r_cog": [0.015, -0.010]})
    fits = [fit(model, est), fit(model, est, p0=near)]
    for res in fits:
        assert res.converged, res.status
        assert res.process_noise is not None
        for i in (0, 1):
            k = res.free_names.index(f"Kd[{i}]")
            assert res.value(f"Kd[{i}]") == pytest.approx(hexa_sim.KD[i], abs=3 * res.std[k]), res.summary()
    for i in (0, 1):
        a, b_ = (r.value(f"Kd[{i}]") for r in fits)
        s = max(r.std[r.free_names.index(f"Kd[{i}]")] for r in fits)
        assert abs(a - b_) < 3 * s


def test_fast_input_content_the_vehicle_follows_is_signal_and_noise_on_the_log_is_not(noisy_cf, tmp_path):
    """The gyro tells them apart. greybox's own 100 Hz flight logs the speeds the rotors turned
    at, jumping with a controller fed by a noisy gyro: the rates follow that content one for one
    (slope 1.02 measured). The peer simulator's telemetry noise moves nothing (slope 0.008 on
    its 20-s flight)."""
    from importlib import resources
    from greybox.cli import main
    from greybox.fitting.input_errors import followed_share

    model, log, _ = noisy_cf
    assert abs(followed_share(model, log, model.default_parameters())) < 0.1
    paper = str(resources.files("greybox") / "data" / "airframes" / "paper.toml")
    assert main(["synth", "--airframe", paper, "--duration", "8", "--rate", "100", "--out",
                 str(tmp_path / "own.csv"), "--seed", "11"]) == 0
    own_model = QuadrotorModel(load_airframe(paper))
    own = own_model.prepare_log(load_log(tmp_path / "own.csv"))
    assert followed_share(own_model, own, own_model.default_parameters()) == pytest.approx(1.0, abs=0.1)

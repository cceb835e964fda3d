"""Flights of an independent simulator of an aggressive 0.8 kg quadrotor (``aggressive_sim``,
a blind audit's: 55 degree tilts, fast yaw turns, its own geometric controller at 250 Hz and
``solve_ivp`` between its updates), fitted and diagnosed from guesses 35-50 % off."""
from __future__ import annotations

import math

import numpy as np
import pytest

import aggressive_sim as sim
from greybox import QuadrotorModel, diagnose, effects, fit, load_airframe, load_log

pytestmark = pytest.mark.slow    # a 30-s flight takes about half a minute to simulate


def _flight(tmp_path, truth, name: str, duration: float, seed: int, kind: str, **log_options):
    t, S, W, ref = sim.fly(truth, sim.default_truth(), duration, seed, kind)
    path = tmp_path / f"{name}.csv"
    sim.write_log(path, t, S, W, seed, acc=ref["acc"] if log_options.pop("acc", False) else None, **log_options)
    return load_log(path)


def _airframe(tmp_path):
    """The audit's starting guesses: K_T x1.35, b x0.65, Kd x0.5."""
    tr = sim.default_truth()
    sim.write_airframe(tmp_path / "A.toml", tr, 1.35 * tr["K_T"], 0.65 * tr["b"], 0.5 * tr["Kd"])
    return load_airframe(tmp_path / "A.toml")


def _held_step_share(tau: float, h: float) -> float:
    """``s_lead`` of a first-order motor's speed sampled at the start of each step of a held
    command: (mean over the step - w_k) / (w_k+1 - w_k) = (1 - tau/h (1 - e^-h/tau)) / (1 - e^-h/tau)."""
    e = 1.0 - math.exp(-h / tau)
    return (1.0 - tau / h * e) / e


def test_an_accelerometer_beside_sampled_speeds_leaves_their_timing_where_it_is(tmp_path):
    """The rotors' actual speeds logged at the controller's 250 Hz (each a sample of a first-order
    response to a held command: s_lead 0.5167) with ax, ay, az, and a quadratic drag. The
    accelerometer reads the thrust at its instant: when the model read it from the row's held
    mean, s_lead came out 0.431 +- 0.009 (-10 std) and az's residual 1.4 times its noise."""
    truth = dict(sim.default_truth(), Kq=np.array([0.03, 0.03, 0.05]))
    log = _flight(tmp_path, truth, "qdrag_acc", 30.0, 11, "est", acc=True, wnoise=0.0)
    model = QuadrotorModel(_airframe(tmp_path)) + effects.SampledInputs() + effects.QuadraticDrag()
    res = fit(model, log)
    assert res.converged, res.status
    values, std = res.parameters, {k: v["std"] for k, v in res.parameters.items()}
    s_true = _held_step_share(truth["tau_m"], 0.004)
    assert s_true == pytest.approx(0.5167, abs=1e-4)
    assert abs(values["s_lead"]["value"] - s_true) < min(3 * std["s_lead"], 0.005), values["s_lead"]
    for i in range(3):
        assert abs(values[f"Kq[{i}]"]["value"] - truth["Kq"][i]) < 3 * std[f"Kq[{i}]"] + 1e-3 * truth["Kq"][i]
    assert values["K_T"]["value"] == pytest.approx(truth["K_T"], rel=1e-3)
    assert values["b"]["value"] == pytest.approx(truth["b"], rel=3e-3)
    az = res.residual_rms["az"] / res.sigma["az"]
    assert az < 1.2, az


def test_nothing_missing_on_an_aggressive_flight_is_null_and_its_coefficients_right(tmp_path):
    """Nothing missing, the actual speeds logged with 0.5 % noise (an ESC's telemetry): the
    diagnosis settles the log's timing and names nothing; K_T, b and Kd within 3 std."""
    truth = sim.default_truth()
    est = _flight(tmp_path, truth, "est", 30.0, 11, "est")
    val = _flight(tmp_path, truth, "val", 20.0, 12, "val")
    d = diagnose(QuadrotorModel(_airframe(tmp_path)), est, validation=val, progress=False)
    assert d.baseline_certified and d.verdict is None and d.null_reason == "nothing_missing", d.summary()
    fr = d.final_fit
    got = fr.parameters
    for name, want in (("K_T", truth["K_T"]), ("b", truth["b"]), ("Kd[0]", truth["Kd"][0]),
                       ("Kd[1]", truth["Kd"][1]), ("Kd[2]", truth["Kd"][2])):
        assert abs(got[name]["value"] - want) < 3 * got[name]["std"] + 1e-4 * abs(want), (name, got[name], want)

import numpy as np
import pytest

from greybox import QuadrotorModel
from greybox.errors import GreyboxInputError
from greybox.rls import RecursiveLeastSquares, _ewls, online_thrust_yaw
from greybox.synth import model_with_hidden_effects, synthesize


def test_rls_matches_batch_least_squares_without_forgetting():
    rng = np.random.default_rng(0)
    Phi = rng.standard_normal((300, 3))
    y = Phi @ [1.0, -2.0, 0.5] + 0.01 * rng.standard_normal(300)
    rls = RecursiveLeastSquares(3, forgetting=1.0, delta=1e9)
    for ph, yy in zip(Phi, y):
        rls.update(ph, yy)
    np.testing.assert_allclose(rls.theta_, np.linalg.lstsq(Phi, y, rcond=None)[0], rtol=1e-6)


def test_scalar_rls_equals_exponentially_weighted_sums():
    rng = np.random.default_rng(1)
    phi = 1 + rng.random(500)
    y = 3.0 * phi * (1 + 0.3 * np.sin(np.arange(500) / 50)) + 0.05 * rng.standard_normal(500)
    rls = RecursiveLeastSquares(1, forgetting=0.97, theta0=[1.0], delta=1.0 / 2.0)
    seq = [rls.update([a], b)[0] for a, b in zip(phi, y)]
    np.testing.assert_allclose(_ewls(phi, y, 0.97, 1.0, 2.0), seq, rtol=1e-9)


def test_online_estimates_track_a_drifting_thrust_coefficient(plus_airframe):
    base = QuadrotorModel(plus_airframe)
    truth, p = model_with_hidden_effects(base, ["thrust_drift"], {"K_T_drift": -0.005})
    log = synthesize(truth, p, duration=24.0, seed=4).log
    est = online_thrust_yaw(base, log, memory=2.0)
    k = log.t > est.settle
    kt_true = 2e-5 * (1 - 0.005 * log.t)
    rel = est.K_T[k] / kt_true[k] - 1
    assert np.sqrt(np.mean(rel ** 2)) < 0.015 and np.abs(rel).max() < 0.04
    assert est.K_T[-1] < 0.92 * est.K_T[k][0]             # it really follows the 12 % fall
    assert np.median(est.b[k]) == pytest.approx(5e-7, rel=0.03)


def test_online_needs_uniform_rate(plus_airframe):
    base = QuadrotorModel(plus_airframe)
    log = synthesize(base, duration=3.0, seed=1).log
    log.t[5] += 1e-4
    with pytest.raises(GreyboxInputError, match="uniform sample rate"):
        online_thrust_yaw(base, log)

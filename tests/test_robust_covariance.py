"""Parameter std that hold when the residuals are coloured (the sandwich of greybox.fitting.robust)."""
import numpy as np
import pytest

from greybox import QuadrotorModel, load_airframe
from greybox.fitting import FitSession, fit
from greybox.fitting.robust import bartlett_bandwidth, long_run_covariance, upper_covariance
from greybox.shooting import default_interval, free_indices, noise_levels
from greybox.synth import SensorSpec, synthesize

from conftest import AIRFRAMES


def test_long_run_covariance_is_the_bartlett_weighted_sum_of_autocovariances():
    rng = np.random.default_rng(0)
    u = rng.standard_normal((300, 3)).cumsum(axis=0) * 0.1 + rng.standard_normal((300, 3))
    L = 7
    direct = sum((1 - abs(l) / (L + 1)) * (u[max(l, 0):300 + min(l, 0)].T @ u[max(-l, 0):300 - max(l, 0)])
                 for l in range(-L, L + 1))
    assert np.allclose(long_run_covariance(u, bandwidth=L), 0.5 * (direct + direct.T), rtol=1e-10)
    # segments are independent pieces: no product across their border
    halves = [slice(0, 150), slice(150, 300)]
    assert np.allclose(long_run_covariance(u, halves, bandwidth=L),
                       long_run_covariance(u[:150], bandwidth=L) + long_run_covariance(u[150:], bandwidth=L))


def test_long_run_variance_of_white_and_autoregressive_sequences():
    """White: the plain sum of squares. AR(1) with rho 0.8: (1 + rho)/(1 - rho) = 9 times it."""
    rng = np.random.default_rng(1)
    n = 40000
    w = rng.standard_normal((n, 1))
    assert bartlett_bandwidth(w) <= 3
    assert long_run_covariance(w)[0, 0] / n == pytest.approx(1.0, abs=0.08)
    a = np.empty(n)
    a[0] = w[0, 0]
    for k in range(1, n):
        a[k] = 0.8 * a[k - 1] + 0.6 * w[k, 0]          # unit stationary variance
    assert long_run_covariance(a[:, None])[0, 0] / n == pytest.approx(9.0, rel=0.2)


def test_upper_covariance_is_at_least_each_of_the_two_in_every_direction():
    rng = np.random.default_rng(2)
    for _ in range(20):
        A, B = rng.standard_normal((2, 4, 4))
        a, b = A @ A.T, B @ B.T * rng.uniform(0.1, 10)
        c = upper_covariance(a, b)
        assert np.linalg.eigvalsh(c - a).min() > -1e-9 * np.abs(c).max()
        assert np.linalg.eigvalsh(c - b).min() > -1e-9 * np.abs(c).max()
    a = np.diag([1.0, 2.0])
    assert np.allclose(upper_covariance(a, 0.5 * a), a)       # white residuals: the noise's own
    assert np.allclose(upper_covariance(a, 3 * a), 3 * a)


def test_upper_covariance_does_not_depend_on_the_parameters_units():
    """A 30 g vehicle's b (1e-10, variance 1e-31) beside a drag (variance 1e-10): in SI units
    the eigen-decomposition's rounding set b's std 100x its scatter. In any units the result
    is the same covariance, rescaled."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        m = rng.standard_normal((4, 4))
        a = m @ m.T + 0.1 * np.eye(4)
        m = rng.standard_normal((4, 4))
        b = m @ m.T
        units = np.array([1e-15, 1e-13, 1e-3, 1.0])      # b, K_T, a drag, a lag in their SI sizes
        expected = upper_covariance(a, b) * np.outer(units, units)
        got = upper_covariance(a * np.outer(units, units), b * np.outer(units, units))
        assert np.allclose(got, expected, rtol=1e-9, atol=0), (np.diag(got), np.diag(expected))


@pytest.mark.parametrize("soft", [False, True])
def test_the_intervals_shares_sum_to_the_gauss_newton_step(soft):
    """Away from the optimum (parameters 30 % off) the shares of a step are not small, and
    they add up to the step the banded solver computes, with hard and with soft continuity."""
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    log = synthesize(model, duration=4.0, seed=3).log
    p = model.default_parameters().copy()
    p[:2] *= (1.3, 0.7)
    free = free_indices(model, None, None)
    ses = FitSession(model, [log], free, p, noise_levels([log], None), default_interval([log]), "auto",
                     lambda _: None)
    if soft:
        ses.q = np.full(model.nx, 1e-2)
    X, th = ses.initial_nodes(p), ses.theta(p)
    blocks = ses.evaluate(X, th)
    shares = ses.influence(X, blocks)
    step = ses.step(X, th, blocks, 0.0)[0][0, model.nx:]
    assert shares.shape == (ses.n_int, ses.nth)
    assert np.abs(step).max() > 0.05
    assert np.allclose(shares.sum(axis=0), step, rtol=1e-6, atol=1e-9 * np.abs(step).max())


def test_std_cover_the_truth_when_the_measurement_noise_is_coloured():
    """Sensor noise correlated over 0.1 s (a filtered vision and IMU, as real ones are): the
    Gauss-Newton std, which count every sample as independent, put the truth 4-11 of them
    away on this set of flights; the fit's std (the long-run covariance of the intervals'
    shares) put it about one away, as a std should."""
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    z = []
    for seed in range(5):
        s = synthesize(model, duration=16.0, seed=seed, sensors=SensorSpec(noise_correlation=0.1))
        res = fit(model, s.log, process_noise=None)
        assert res.converged
        truth = model.parameter_dict(s.parameters)
        z += [(res.value(n) - truth[n]) / res.std[i] for i, n in enumerate(res.free_names)]
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.5 < rms < 2.2, np.round(z, 2)

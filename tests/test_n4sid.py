"""n4sid: a known system is recovered (order, poles, outputs, feedthrough), bad input is
refused. (On closed-loop quadrotor flights the black-box model is not yet at the level of
nfoursid: see experiments/bench_n4sid.py and issue 5.)"""
import numpy as np
import pytest

from greybox.errors import GreyboxInputError
from greybox.n4sid import fit_percent, n4sid, order_plot


def _system(seed=0, N=4000, noise=0.01):
    rng = np.random.default_rng(seed)
    A = np.diag([0.95, 0.9, 0.8, 0.5])
    T = rng.standard_normal((4, 4))
    A = T @ A @ np.linalg.inv(T)
    B, C = rng.standard_normal((4, 2)), rng.standard_normal((3, 4))
    u = rng.standard_normal((N, 2))
    x, Y = np.zeros(4), []
    for k in range(N):
        Y.append(C @ x)
        x = A @ x + B @ u[k]
    return A, u, np.array(Y) + noise * rng.standard_normal((N, 3))


def test_recovers_order_poles_and_outputs(tmp_path):
    A, u, y = _system()
    m = n4sid(u, y, dt=0.01)
    assert m.order == 4
    np.testing.assert_allclose(np.sort(np.abs(np.linalg.eigvals(m.A))), [0.5, 0.8, 0.9, 0.95], atol=2e-3)
    assert np.all(fit_percent(y, m.simulate(u)) > 99.0)
    assert m.is_stable()
    # the singular values drop after the true order
    s = m.singular_values
    assert s[3] / s[4] > 20
    assert order_plot(m, tmp_path / "order.png").stat().st_size > 1000


def test_fixed_order_and_feedthrough():
    A, u, y = _system(seed=1)
    y = y + 0.5 * u[:, :1]            # a direct feedthrough from input 1 to every output
    m = n4sid(u, y, dt=0.01, order=4, feedthrough=True)
    np.testing.assert_allclose(m.D[:, 0], 0.5, atol=0.02)
    assert np.all(fit_percent(y, m.simulate(u)) > 98.0)


def test_bad_input_is_refused():
    A, u, y = _system(N=1000)
    with pytest.raises(GreyboxInputError, match="same N"):
        n4sid(u[:-1], y, 0.01)
    y2 = y.copy()
    y2[5, 0] = np.nan
    with pytest.raises(GreyboxInputError, match="NaN"):
        n4sid(u, y2, 0.01)
    with pytest.raises(GreyboxInputError, match="too few"):
        n4sid(u[:100], y[:100], 0.01)
    with pytest.raises(GreyboxInputError, match="order must be"):
        n4sid(u, y, 0.01, order=0)


def test_closed_loop_data_pbsid_is_consistent_oblique_is_not():
    """An unstable first-order plant under output feedback with process and measurement
    noise: the predictor-based default recovers the open-loop pole and gain; the classical
    oblique projection (future inputs correlated with past noise through the controller)
    does not — the reason PBSID is the default."""
    rng = np.random.default_rng(0)
    a, b, k = 1.02, 0.5, 0.5
    x, U, Y = 0.0, [], []
    for _ in range(20000):
        y = x + 0.05 * rng.normal()
        u = -k * y + 0.2 * rng.normal()
        U.append(u)
        Y.append(y)
        x = a * x + b * u + 0.1 * rng.normal()
    U, Y = np.array(U)[:, None], np.array(Y)[:, None]
    m = n4sid(U, Y, 0.01, order=1, horizon=10)
    assert abs(np.linalg.eigvals(m.A)[0] - a) < 0.005
    assert abs((m.C @ m.B)[0, 0] - b) < 0.02
    bad = n4sid(U, Y, 0.01, order=1, horizon=10, method="oblique")
    assert abs(np.linalg.eigvals(bad.A)[0] - a) > 0.1

import numpy as np
import pytest

from greybox import QuadrotorModel
from greybox.control import dlqr, dlqry, reference_gain
from greybox.errors import GreyboxInputError
from greybox.linearize import linearize


def test_scalar_dlqr_by_hand():
    a, b, q, r = 1.2, 0.5, 2.0, 0.3
    K, S, E = dlqr([[a]], [[b]], [[q]], [[r]])
    # scalar Riccati: s = q + a^2 s - (a b s)^2 / (r + b^2 s)
    s = S[0, 0]
    assert s == pytest.approx(q + a * a * s - (a * b * s) ** 2 / (r + b * b * s), rel=1e-12)
    assert K[0, 0] == pytest.approx(a * b * s / (r + b * b * s), rel=1e-12)
    assert abs(E[0]) < 1


def test_dlqr_is_optimal_against_perturbed_gains():
    rng = np.random.default_rng(0)
    A = np.array([[1.0, 0.1], [0.0, 1.0]])
    B = np.array([[0.005], [0.1]])
    Q, R = np.diag([1.0, 0.1]), np.array([[0.01]])
    K, S, _ = dlqr(A, B, Q, R)

    def cost(Kx, x0):
        x, J = x0.copy(), 0.0
        for _ in range(3000):
            u = -Kx @ x
            J += x @ Q @ x + u @ R @ u
            x = A @ x + B @ u
        return J

    x0 = np.array([1.0, -0.5])
    assert cost(K, x0) == pytest.approx(x0 @ S @ x0, rel=1e-6)     # the value function
    for _ in range(5):
        assert cost(K + 0.05 * rng.standard_normal(K.shape), x0) > cost(K, x0)


def test_dlqry_equals_dlqr_with_output_weights(plus_airframe):
    lin = linearize(QuadrotorModel(plus_airframe)).discretize(0.01)
    C = lin.C[[0, 1, 2, 5]]                  # the paper's outputs x, y, z, psi
    D = np.zeros((4, 4))
    Q, R = np.eye(4), 1e-3 * np.eye(4)       # the paper's Q = 1, R = 0.001
    K, S, E = dlqry(lin.A, lin.B, C, D, Q, R)
    K2, S2, _ = dlqr(lin.A, lin.B, C.T @ Q @ C, R)
    np.testing.assert_allclose(K, K2, rtol=1e-8, atol=1e-10)
    assert np.all(np.abs(E) < 1)             # stabilises the hover
    Kr = reference_gain(lin.A, lin.B, C, Q, R, K, S)
    assert Kr.shape == (4, 4)
    # closed loop on the linear model: 1 m steps in x, y, z and 0.3 rad in yaw are reached
    # exactly (the outputs are integrators, so eq. (12) gives unit DC gain)
    x = np.zeros(12)
    ref = np.array([1.0, 1.0, 1.0, 0.3])
    for _ in range(3000):
        x = lin.A @ x + lin.B @ (-K @ x + Kr @ ref)
    np.testing.assert_allclose(C @ x, ref, atol=1e-6)
    control = pytest.importorskip("control")
    Kc, Sc, _ = control.dlqr(lin.A, lin.B, C.T @ Q @ C, R)
    np.testing.assert_allclose(K, Kc, rtol=1e-8, atol=1e-10)


def test_dlqr_bad_sizes():
    with pytest.raises(GreyboxInputError, match="sizes do not match"):
        dlqr(np.eye(2), np.ones((3, 1)), np.eye(2), np.eye(1))

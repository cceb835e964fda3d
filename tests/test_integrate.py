import numpy as np
import pytest

from greybox import QuadrotorModel, effects, simulate
from greybox.errors import GreyboxInputError
from greybox.integrate import integrate_states_along, n_substeps, rk4_step


def test_rk4_agrees_with_cvodes_on_a_rich_model(plus_airframe):
    m = QuadrotorModel(plus_airframe) + effects.MotorLag() + effects.QuadraticDrag() + effects.ThrustDrift()
    p = m.parameter_vector({"Kq": 0.02, "K_T_drift": -0.01, "tau_m": 0.03})
    rng = np.random.default_rng(3)
    t = np.arange(0, 1.0, 0.01)
    W = m.hover_speed() * (1 + 0.02 * rng.standard_normal((t.size, 4)))
    x0 = np.zeros(12)
    x0[2] = -1
    a = simulate(m, t, W, p, x0, method="rk4")
    b = simulate(m, t, W, p, x0, method="cvodes")
    np.testing.assert_allclose(a.states, b.states, atol=1e-7)


def test_rk4_is_fourth_order(plus_airframe):
    m = QuadrotorModel(plus_airframe)
    x0 = np.zeros(12)
    x0[9:12] = [1.0, -0.5, 0.8]
    x0[6] = 2.0
    u = [m.hover_speed() * 1.05] * 4
    p = m.default_parameters()
    exact = np.asarray(rk4_step(m, 256)(x0, u, p, 0, 0.2)).ravel()
    e1 = np.abs(np.asarray(rk4_step(m, 4)(x0, u, p, 0, 0.2)).ravel() - exact).max()
    e2 = np.abs(np.asarray(rk4_step(m, 8)(x0, u, p, 0, 0.2)).ravel() - exact).max()
    assert 12 < e1 / e2 < 20   # halving the step divides the error by ~16


def test_substeps():
    assert n_substeps(0.001) == 1 and n_substeps(0.01) == 4 and n_substeps(0.0025) == 1


def test_simulate_argument_errors(plus_airframe):
    m = QuadrotorModel(plus_airframe)
    with pytest.raises(GreyboxInputError, match="inputs must be"):
        simulate(m, [0, 1], np.ones((3, 4)))
    with pytest.raises(GreyboxInputError, match="strictly increasing"):
        simulate(m, [0, 0], np.ones((2, 4)))
    with pytest.raises(GreyboxInputError, match="unknown integration method"):
        simulate(m, [0, 1], np.ones((2, 4)), method="euler")


def test_a_motor_lags_speeds_integrated_along_a_log_follow_its_step_response(plus_airframe):
    """Logged speeds stepping from 400 to 500 rad/s at t = 0.5 s through a 30-ms lag, the base
    states held: w_eff = 500 - 100 exp(-(t - 0.5)/tau) after the step (RK4 at 1 kHz: 1e-8 of it).
    One sample's step uses that sample's input, so the response starts at the step's row."""
    model = QuadrotorModel(plus_airframe) + effects.MotorLag()
    p = model.parameter_vector({"tau_m": 0.03})
    t = np.arange(0.0, 1.0 + 1e-9, 1e-3)
    w = np.where(t < 0.5 - 1e-9, 400.0, 500.0)
    inputs = np.repeat(w[:, None], 4, axis=1)
    states = list(range(12, model.nx))
    held = np.zeros((t.size - 1, model.nx))
    traj = integrate_states_along(model, t, inputs, states, np.full(4, 400.0), held, p)
    assert traj.shape == (t.size, 4) and np.all(traj[0] == 400.0)
    after = t >= 0.5 - 1e-9
    expected = np.where(after, 500.0 - 100.0 * np.exp(-(t - 0.5) / 0.03), 400.0)
    assert np.allclose(traj, expected[:, None], rtol=0, atol=1e-5)

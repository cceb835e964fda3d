import numpy as np
import pytest

from greybox import QuadrotorModel, effects, simulate
from greybox.errors import GreyboxInputError
from greybox.integrate import Substeps, integrate_states_along, log_substeps, n_substeps, rk4_step, substeps


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
    # Unix time stamps carry ~1e-7 s of rounding: a 100-Hz log's 10 ms are still four sub-steps
    assert n_substeps(0.0100000003) == 4 and n_substeps(0.0106) == 5


def test_a_dropped_row_sets_the_substeps_of_its_own_step_only():
    h = np.full(1000, 0.01)
    h[[100, 500]] = [0.02, 0.03]             # two dropped rows, then two
    plan = substeps(h)
    assert plan == Substeps(4, 12) and plan.branches == 3
    assert list(plan.branch(np.array([0.0, 0.005, 0.01, 0.0104, 0.011, 0.02, 0.03, 0.05]))) == [0, 0, 0, 0, 1, 1, 2, 2]
    assert substeps(np.full(10, 0.01)) == Substeps(4, 4)
    # several flights: one plan over all their steps
    class Log:
        def __init__(self, t):
            self.t = t
    assert log_substeps([Log(np.arange(0, 1, 0.01)), Log(np.r_[0, 0.01, 0.03, 0.04])]) == Substeps(4, 8)


def test_a_branched_step_takes_the_substeps_of_its_steps_length(plus_airframe):
    m = QuadrotorModel(plus_airframe) + effects.MotorLag()
    p = m.parameter_vector({"tau_m": 0.03})
    x0 = np.zeros(m.nx)
    x0[9:12] = [1.0, -0.5, 0.8]
    x0[12:] = m.hover_speed()
    u = [m.hover_speed() * 1.05] * 4
    step = rk4_step(m, Substeps(2, 6))
    for h, n in ((0.004, 2), (0.005, 2), (0.0075, 4), (0.01, 4), (0.015, 6), (0.04, 6)):
        got = np.asarray(step(x0, u, p, 0.3, h)).ravel()
        want = np.asarray(rk4_step(m, n)(x0, u, p, 0.3, h)).ravel()
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13)


def test_a_log_with_a_dropped_row_simulates_as_one_without_it(plus_airframe):
    """RK4 over a log with dropped rows (their steps branch to more sub-steps) against CVODES
    on the full grid with the inputs held over the gaps, at the kept rows."""
    m = QuadrotorModel(plus_airframe)
    rng = np.random.default_rng(1)
    t = np.arange(0, 2.0, 0.01)
    W = m.hover_speed() * (1 + 0.01 * rng.standard_normal((t.size, 4)))
    full = simulate(m, t, W, method="cvodes")
    keep = np.ones(t.size, bool)
    keep[[50, 120, 121]] = False
    gap = simulate(m, t[keep], W[keep], method="rk4")
    # the dropped rows' inputs are the held ones of the row before in the gapped log
    W_held = W.copy()
    W_held[50], W_held[120], W_held[121] = W[49], W[119], W[119]
    ref = simulate(m, t, W_held, method="cvodes")
    np.testing.assert_allclose(gap.states, ref.states[keep], atol=1e-8)
    assert np.abs(ref.states[keep] - full.states[keep]).max() > 1e-7     # the hold mattered


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

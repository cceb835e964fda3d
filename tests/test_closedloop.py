"""Closed loop under the seed's LQR: hover stays put, 1 m steps are tracked, rotor limits
bite, and the step metrics are right on an analytic response."""
import numpy as np
import pytest

from greybox import QuadrotorModel, effects, load_airframe
from greybox.closedloop import design_lqr, simulate_lqr, step_metrics, step_reference
from greybox.errors import GreyboxInputError

from conftest import AIRFRAMES


@pytest.fixture(scope="module")
def model():
    return QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))


def test_step_metrics_of_a_first_order_response():
    tau = 0.4
    t = np.linspace(0, 20, 200001)
    y = np.where(t >= 1.0, 1 - np.exp(-(t - 1.0) / tau), 0.0)
    m = step_metrics(t, y, 1.0, 0.0, 1.0)
    assert m["rise_time"] == pytest.approx(tau * np.log(9), abs=1e-3)
    assert m["overshoot_pct"] == 0.0
    assert m["settling_time"] == pytest.approx(tau * np.log(50), abs=1e-3)
    assert m["itae"] == pytest.approx(tau ** 2, rel=1e-4)
    with pytest.raises(GreyboxInputError):
        step_metrics(t, y, 1.0, 1.0, 1.0)


def test_lqr_holds_hover_and_tracks_steps(model):
    p = model.default_parameters()
    d = design_lqr(model, p)
    assert np.all(np.abs(d.poles) < 1)
    t = np.arange(0, 5, d.dt)
    hold = simulate_lqr(model, p, d, step_reference(t, steps=[]))
    np.testing.assert_allclose(hold.states[:, :6], np.repeat(hold.states[:1, :6], len(t), 0), atol=1e-9)
    t = np.arange(0, 16, d.dt)
    ref = step_reference(t)
    cl = simulate_lqr(model, p, d, ref)
    for ax, ts in ((0, 1.0), (1, 6.0)):
        m = step_metrics(t, cl.states[:, ax], ts, ref[0, ax], ref[-1, ax], ts + 5)
        assert 0.2 < m["rise_time"] < 3 and m["overshoot_pct"] < 25 and m["settling_time"] < 5
        assert cl.states[-1, ax] == pytest.approx(ref[-1, ax], abs=1e-3)
    # the climb goes the right way (NED: up is -z) and ends near the target
    assert cl.states[-1, 2] < -1.9
    assert cl.saturated == 0.0


def test_rotor_limits_bite_and_plant_may_differ_from_design(model):
    p = model.default_parameters()
    d = design_lqr(model, p)
    t = np.arange(0, 8, d.dt)
    ref = step_reference(t, steps=[(1.0, 0, 3.0)])
    w = float(d.u_trim[0])
    cl = simulate_lqr(model, p, d, ref, w_limits=(0.9 * w, 1.1 * w))
    assert cl.saturated > 0.0
    assert cl.inputs.max() <= 1.1 * w + 1e-9 and cl.inputs.min() >= 0.9 * w - 1e-9
    # a plant with ground effect and motor lag (not in the design) still runs
    plant = model + effects.MotorLag()
    pp = plant.parameter_vector({"tau_m": 0.03}, plant.default_parameters())
    cl2 = simulate_lqr(plant, pp, d, step_reference(np.arange(0, 8, d.dt)))
    assert np.isfinite(cl2.states).all()
    assert cl2.states[-1, 0] == pytest.approx(1.0, abs=0.05)


def test_pid_autotuning_improves_the_criterion_and_tracks(model):
    from greybox.closedloop import CascadedPID, PID_GAINS, simulate_pid, tune_pid
    p = model.default_parameters()
    pid = tune_pid(model, p, max_evals=150)
    t = np.arange(0, 16, pid.dt)
    ref = step_reference(t)

    def itae(ctrl):
        cl = simulate_pid(model, p, ctrl, ref)
        return sum(step_metrics(t, cl.states[:, ax], ts, ref[0, ax], ref[-1, ax], ts + 5)["itae"]
                   for ts, ax in ((1.0, 0), (6.0, 1), (11.0, 2))), cl

    wa, wp, z = 20.0, 2.0, 0.8
    start = CascadedPID(dict(zip(PID_GAINS, [wp ** 2, 0.1 * wp ** 2, 2 * z * wp, wp ** 2, 0.1 * wp ** 2,
                                             2 * z * wp, wa ** 2, 2 * z * wa])))
    c0, _ = itae(start)
    c1, cl = itae(pid)
    assert c1 < 0.7 * c0
    np.testing.assert_allclose(cl.states[-1, :3], ref[-1, :3], atol=0.01)
    for ts, ax in ((1.0, 0), (11.0, 2)):
        m = step_metrics(t, cl.states[:, ax], ts, ref[0, ax], ref[-1, ax], ts + 5)
        assert m["overshoot_pct"] < 30 and m["settling_time"] < 5
    # anti-windup: a 3 m step with rotors limited to +-30 % of hover stays stable and arrives
    w = model.hover_speed(p)
    tight = CascadedPID(pid.gains, w_limits=(0.7 * w, 1.3 * w))
    far = step_reference(np.arange(0, 12, 0.01), steps=[(1.0, 0, 3.0)])
    cl_t = simulate_pid(model, p, tight, far)
    assert cl_t.saturated > 0 and np.isfinite(cl_t.states).all()
    assert cl_t.states[-1, 0] == pytest.approx(3.0, abs=0.05)


def test_linear_lqr_on_the_hover_linearisation_matches_the_nonlinear_loop():
    """simulate_linear_lqr on the true model linearised at hover (as a black box would be)
    follows small steps like the nonlinear model under design_lqr: same design procedure."""
    from greybox import linearize
    from greybox.closedloop import simulate_linear_lqr
    from greybox.n4sid import StateSpaceModel
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    p = model.default_parameters()
    dt = 0.01
    lin = linearize(model, p=p).discretize(dt)
    outs = ["x", "y", "z", "phi", "theta", "psi"]
    rows = [lin.output_names.index(c) for c in outs]
    ss = StateSpaceModel(lin.A, lin.B, lin.C[rows], lin.D[rows], dt, np.zeros(lin.A.shape[0]),
                         np.asarray(lin.u_op), np.asarray(lin.C[rows] @ lin.x_op), [], outs)
    t = np.arange(0, 8, dt)
    ref = step_reference(t, steps=[(1.0, 0, 0.1), (3.0, 1, -0.1), (5.0, 2, -0.1)])
    lin_cl = simulate_linear_lqr(ss, ref)
    nl_cl = simulate_lqr(model, p, design_lqr(model, p, dt=dt), ref)
    for c in ("x", "y", "z"):
        np.testing.assert_allclose(lin_cl.output(c), nl_cl.output(c, model.state_names), atol=2e-3)
    assert abs(lin_cl.output("x")[-1] - 0.1) < 1e-3          # Kr: no steady-state error
    assert np.max(np.abs(lin_cl.poles)) < 1.0

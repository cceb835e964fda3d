"""The delay of logged commands (effect ``command_delay``): by hand, on another simulator's
flights (a transport delay it puts between its controller and its motors, and none), and
its place in a model (inputs derived from the log, hover trim, linearisation, saving)."""
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from greybox import QuadrotorModel, effects, fit, linearize, load_airframe
from greybox.data import FlightLog
from greybox.diagnosis.ranking import default_candidates
from greybox.errors import GreyboxInputError

from conftest import AIRFRAMES

sys.path.insert(0, str(Path(__file__).parent))


PATTERN = np.array([1.0, 0.3, -1.0, -0.3])     # a roll and pitch moment on any X or + layout


def _sine_log(rate=100.0, duration=1.0, f=3.0):
    t = np.arange(0.0, duration, 1.0 / rate)
    W = 400.0 + 50.0 * np.sin(2 * np.pi * f * t)[:, None] * PATTERN
    nan = np.full((t.size, 6), np.nan)
    return FlightLog(t, W, ["w1", "w2", "w3", "w4"], nan, ["x", "y", "z", "phi", "theta", "psi"])


def test_the_model_acts_on_the_command_tau_earlier_by_hand():
    """Rotor speeds 400 +- 50 sin(2 pi 3 t) driving roll and pitch. The derived inputs are the
    commands one tap (10 ms) later and 1..11 taps earlier, the first one held before the
    start; the model with ``tau_cmd`` on a tap gives exactly the base model's derivatives
    at the command that many taps earlier, between taps those of the exactly delayed sine
    within 0.1 % (the interpolation), and at ``tau_cmd = 0`` the base model's."""
    af = load_airframe(AIRFRAMES / "x_quad.toml")
    base = QuadrotorModel(af)
    model = base + effects.CommandDelay()
    assert model.input_names[:4] == ["w1", "w2", "w3", "w4"]
    assert "w1@-10ms" in model.input_names and "w4@110ms" in model.input_names
    assert model.steady_input_names == ["w1", "w2", "w3", "w4"]
    log = _sine_log()
    prep = model.prepare_log(log)
    j = prep.input_names.index("w2@30ms")
    assert prep.inputs[40, j] == pytest.approx(log.inputs[37, 1], rel=1e-12)
    assert prep.inputs[1, j] == log.inputs[0, 1]                       # held before the start
    k, x0 = 45, base.initial_state()
    p = model.default_parameters()
    i_tau = model.param_names.index("tau_cmd")
    for tau in (0.0, 0.03, 0.0333, 0.0999):
        p[i_tau] = tau
        got = np.asarray(model.rhs(x0, prep.inputs[k], p, log.t[k])).ravel()
        w = 400.0 + 50.0 * np.sin(2 * np.pi * 3.0 * (log.t[k] - tau)) * PATTERN
        want = np.asarray(base.rhs(x0, w, base.default_parameters(), log.t[k])).ravel()
        assert abs(want[9]) + abs(want[10]) > 1.0                      # a real roll/pitch acceleration
        tol = 1e-9 if round(tau / 0.01, 6).is_integer() else 1e-3
        assert got == pytest.approx(want, rel=tol, abs=1e-9), tau
    assert model.parameter_vector({})[i_tau] == 0.02
    par = next(q for q in model.parameters if q.name == "tau_cmd")
    assert par.null == 0.0 and (par.lower, par.upper) == (0.0, pytest.approx(0.1))


def test_the_delay_is_smooth_at_its_null_so_a_score_test_sees_it():
    """The derivative of the rotor speed a model acts on with respect to ``tau_cmd`` at 0 is
    minus the command's rate of change (central difference over one tap): not the zero a
    linear interpolation's kink would give, which would hide the effect from the score test
    and from Gauss-Newton started at the null."""
    import casadi as ca
    af = load_airframe(AIRFRAMES / "x_quad.toml")
    model = QuadrotorModel(af) + effects.CommandDelay()
    prep = model.prepare_log(_sine_log())
    p = ca.SX.sym("p", model.n_params)
    k = 10
    rhs = model.rhs(model.initial_state(), prep.inputs[k], p, prep.t[k])
    dq = ca.Function("d", [p], [ca.jacobian(rhs[10], p)])(model.parameter_vector({"tau_cmd": 0.0}))
    d_tau = float(dq[model.param_names.index("tau_cmd")])
    eps = 1e-6
    f = ca.Function("f", [p], [rhs[10]])
    fd = (float(f(model.parameter_vector({"tau_cmd": eps}))) - float(f(model.parameter_vector({"tau_cmd": 0.0})))) / eps
    assert abs(d_tau) > 1.0
    assert d_tau == pytest.approx(fd, rel=1e-3)


def test_a_split_prepared_log_keeps_the_history_before_the_split():
    model = QuadrotorModel(load_airframe(AIRFRAMES / "x_quad.toml")) + effects.CommandDelay()
    log = _sine_log(duration=2.0)
    est, val = model.prepare_log(log).split(0.5)
    again = model.prepare_log(val)
    j = again.input_names.index("w1@50ms")
    k0 = len(log) - len(val)
    assert again.inputs[0, j] == pytest.approx(log.inputs[k0 - 5, 0], rel=1e-12)
    fresh = model.prepare_log(log.split(0.5)[1])                    # no history: the first held
    assert fresh.inputs[0, j] == pytest.approx(log.inputs[k0, 0], rel=1e-12)


def test_options_inputs_and_saving(tmp_path):
    from greybox.fitted import FittedModel, load
    af = load_airframe(AIRFRAMES / "x_quad.toml")
    with pytest.raises(GreyboxInputError, match="tap"):
        effects.CommandDelay(max_delay=0.005, tap=0.01)
    with pytest.raises(GreyboxInputError, match="controls"):
        (QuadrotorModel(af, inputs="controls") + effects.CommandDelay()).input_names
    model = QuadrotorModel(af) + effects.CommandDelay(max_delay=0.05, tap=0.005)
    assert "w3@55ms" in model.input_names and "w3@60ms" not in model.input_names
    p = model.parameter_vector({"tau_cmd": 0.031})
    fm = FittedModel(model, p, ["tau_cmd"], np.eye(1) * 1e-6, np.array([1e-3]), {})
    back = load(fm.save(tmp_path / "m.json"))
    assert back.model.input_names == model.input_names
    assert back.value("tau_cmd") == 0.031
    # linearised about hover: the earlier commands fold into their command, and it says the
    # delay is left out; the result is the model's linearisation without the delay, also
    # where the trim is solved numerically (an offset centre of gravity: unequal rotors)
    for extra in ([], [effects.CogOffset()]):
        m = model + extra
        base = QuadrotorModel(af) + extra
        pv = m.parameter_vector({"tau_cmd": 0.031, **({"r_cog": [0.01, -0.005]} if extra else {})})
        pb = base.parameter_vector({"r_cog": [0.01, -0.005]} if extra else {})
        with pytest.warns(UserWarning, match="command delay"):
            lin = linearize(m, pv)
        lin0 = linearize(base, pb)
        assert lin.input_names == ["w1", "w2", "w3", "w4"]
        np.testing.assert_allclose(lin.A, lin0.A, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(lin.B, lin0.B, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(lin.u_op, lin0.u_op, rtol=1e-9)
        assert np.ptp(lin.u_op) > 1.0 if extra else np.ptp(lin.u_op) < 1e-9


def test_the_diagnosis_tries_it_when_the_speeds_come_from_logged_motor_commands():
    model = QuadrotorModel(load_airframe(AIRFRAMES / "x_quad.toml"))
    log = _sine_log()
    assert "command_delay" not in default_candidates(model, [log])
    log.extras["pwm1"] = log.inputs[:, 0] * 10
    assert "command_delay" in default_candidates(model, [log])


@pytest.fixture(scope="module")
def crazyflie_model():
    from foreign_sim import airframe_dict, crazyflie
    from greybox.airframe import airframe_from_dict
    return QuadrotorModel(airframe_from_dict(airframe_dict(crazyflie())))


@pytest.mark.slow
def test_another_simulators_transport_delay_is_found_and_its_absence_too(crazyflie_model):
    """Another simulator (scipy solve_ivp, its own cascaded controller at 500 Hz) flies a
    30 g vehicle whose motors (5 ms lag) receive each command 40 ms after it is issued and
    logged. A process-noise fit with ``command_delay`` is certified and gives 40 ms + the
    motor lag + half a control period (46 ms) within 4 ms (44.8 measured), and predicts roll
    and pitch 0.25 s ahead at least three times better than the fit without it (10-40x
    measured: without it K_T comes out a third of its value). The same vehicle without the
    delay: 5 ms (the motor lag; 4.9 measured)."""
    from foreign_sim import crazyflie, simulate_flight
    from greybox.validation import horizon_errors, prediction_options

    veh = crazyflie(tau_motor=0.005)
    model = crazyflie_model + effects.CommandDelay()
    est, val = simulate_flight(veh, duration=12.0, seed=3, log_commands=True, command_delay=0.04).log.split(0.8)
    res = fit(model, est, process_noise="auto", progress=False)
    assert res.converged, res.status
    assert res.value("tau_cmd") == pytest.approx(0.046, abs=0.004)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res0 = fit(crazyflie_model, est, process_noise="auto", progress=False)
    he = horizon_errors(model, res.p, val, **prediction_options(res))
    he0 = horizon_errors(crazyflie_model, res0.p, val, **prediction_options(res0))
    k = he.horizons.index(0.25)
    for ch in ("phi", "theta"):
        assert he.model[ch][k] < he0.model[ch][k] / 3, ch

    est, _ = simulate_flight(veh, duration=12.0, seed=3, log_commands=True).log.split(0.8)
    res = fit(model, est, process_noise="auto", progress=False)
    assert res.converged, res.status
    assert res.value("tau_cmd") == pytest.approx(0.005, abs=0.003)

"""The third independent simulator (tests/contract_sim.py, written by a blind audit from the
contract alone) and what greybox makes of its flights.

Its signs are checked by hand first. Its log holds each 400 Hz command for half of a 200 Hz
row, which the contract's zero-order hold does not say: with the held rows greybox's drag came
out 0.8 % high, 8-12 of its std, and the diagnosis had refused the log's timing as "physically
negligible" (its force 0.2 % of the flight's). Now the timing is taken because it moves the
estimates, and the drag is recovered.
"""
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import contract_sim as cs
from greybox import QuadrotorModel, load_airframe, load_log
from greybox.diagnosis import diagnose


def _after(w, duration=0.2):
    s = np.concatenate([np.zeros(6), [1.0, 0, 0, 0], np.zeros(3)])
    sol = solve_ivp(cs.make_rhs({}), (0, duration), s, method="DOP853", rtol=1e-8, atol=1e-10, args=(w,))
    return sol.y[:, -1]


def test_signs_by_hand():
    """Hover balances the weight; rotor 4 (left) faster than rotor 2 (right) rolls right
    (p, phi > 0) and moves the vehicle right (+y, FRD/NED); rotor 1 (front) faster pitches the
    nose up and moves it back; the +1-spin pair faster yaws positive (the contract's
    b*(-w1^2 + w2^2 - w3^2 + w4^2)); the rotors' gyroscopic roll torque is +J_r q Omega_r."""
    h = cs.W_HOVER
    s0 = np.concatenate([np.zeros(6), [1.0, 0, 0, 0], np.zeros(3)])
    assert np.allclose(cs.make_rhs({})(0, s0, np.full(4, h))[3:6], 0, atol=1e-12)
    s = _after(np.array([h, 0.99 * h, h, 1.01 * h]))
    assert s[10] > 0 and cs.R_to_euler(cs.quat_to_R(s[6:10]))[0] > 0 and s[4] > 0
    s = _after(np.array([1.01 * h, h, 0.99 * h, h]))
    assert s[11] > 0 and cs.R_to_euler(cs.quat_to_R(s[6:10]))[1] > 0 and s[3] < 0
    assert _after(np.array([0.99 * h, 1.01 * h, 0.99 * h, 1.01 * h]))[12] > 0
    s2 = s0.copy()
    s2[11] = 1.0
    w = np.array([1000.0, 1200.0, 1000.0, 1200.0])
    roll = cs.make_rhs({})(0, s2, w)[10]
    assert roll == pytest.approx(cs.J_R * np.sum(cs.SPIN * w) / cs.J[0], rel=1e-9)


def _diagnosed(case: str, tmp_path):
    """The audit's two 20-s flights of ``case`` (estimation, validation) diagnosed, and the case."""
    cfg = dict(cs.CASES[case], duration=20.0)
    cs.write_airframe(tmp_path / "airframe.toml")
    for name, seed, amp in (("est", 11, 1.0), ("val", 22, 0.9)):
        rows, rng = cs.fly(cfg, seed, amp)
        cs.write_log(rows, rng, cfg, tmp_path / f"{name}.csv")
    model = QuadrotorModel(load_airframe(tmp_path / "airframe.toml"))
    return diagnose(model, load_log(tmp_path / "est.csv"), validation=load_log(tmp_path / "val.csv"),
                    progress=False), cfg


@pytest.mark.slow
def test_half_held_rows_are_the_logs_timing_and_the_drag_is_recovered(tmp_path):
    """Nothing missing, 20-s flights: the verdict is null, the log's timing stands (the next
    row's weight near the quarter that half-held commands give) and every drag coefficient
    comes out within 4 of its std (held rows: 8-12 std)."""
    d = _diagnosed("c1_clean", tmp_path)[0]
    assert d.verdict is None, d.summary()
    assert d.input_timing is not None and 0.15 < d.input_timing["s_lead"] < 0.35, d.input_timing
    fr = d.fitted_model
    assert fr.converged
    for k, truth in enumerate(cs.KD):
        n = f"Kd[{k}]"
        z = (fr.value(n) - truth) / fr.std[fr.free_names.index(n)]
        assert abs(z) < 4, (n, fr.value(n), truth, z)
    assert fr.value("K_T") == pytest.approx(cs.K_T, rel=1e-3)
    assert fr.value("b") == pytest.approx(cs.B, rel=1e-3)


@pytest.mark.slow
def test_a_motor_lag_behind_half_held_commands_says_what_its_std_leave_out(tmp_path):
    """30-ms motors, the 400 Hz commands logged at 200 Hz: motor_lag is the verdict. Whether
    a row's command holds for the whole row is the log's timing, and these data do not settle
    it beside the lag (held rows: tau_m a quarter row short, 10 of its noise std); the
    diagnosis says the lag is uncertain by up to half a row beyond its std, and the truth lies
    within that."""
    d, cfg = _diagnosed("c5_motorlag", tmp_path)
    assert d.verdict == "motor_lag", d.summary()
    fr = d.fitted_model
    tau, std = fr.value("tau_m"), fr.std[fr.free_names.index("tau_m")]
    half_row = 0.5 / 200.0
    if d.input_timing is None:
        assert any("tau_m" in w and "half a row" in w for w in d.warnings), d.warnings
        assert abs(tau - cfg["tau_m"]) < 3 * std + half_row, (tau, std)
    else:
        assert abs(tau - cfg["tau_m"]) < 4 * std, (tau, std, d.input_timing)


@pytest.mark.slow
def test_a_motor_lag_behind_commands_logged_at_the_controllers_rate_gives_its_value_with_the_timing_free(tmp_path):
    """30-ms motors, the 400 Hz commands logged at 400 Hz (held rows exact): motor_lag is the
    verdict and the held rows stand. Whether the data settle the timing is measured, not
    assumed: fitted with the timing free as well, tau_m is 30.8 ± 1.3 ms here (a soft fit),
    an uncertainty as large as the half row (1.25 ms), so the caveat stays and quotes that
    refit beside the held fit's 30.0 ± 0.19 ms. (Where the refit settles it, the words go: a
    blind audit's 100 Hz log of commands at the controller's rate, tau_m 24.99 ± 0.04 ms,
    has no caveat now; it said 5 ms.)"""
    d, cfg = _diagnosed("c5b_motorlag_log400", tmp_path)
    assert d.verdict == "motor_lag", d.summary()
    assert d.input_timing is None
    fr = d.fitted_model
    tau, std = fr.value("tau_m"), fr.std[fr.free_names.index("tau_m")]
    assert abs(tau - cfg["tau_m"]) < 3 * std, (tau, std)
    caveat = [w for w in d.warnings if "half a row" in w]
    assert len(caveat) == 1 and "with the log's timing free as well: tau_m = " in caveat[0], d.warnings

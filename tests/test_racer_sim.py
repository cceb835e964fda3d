"""A thirteenth blind audit's 5-inch racer (``tests/racer_sim.py``: its own simulator, a rate-mode
controller, DShot telemetry of the rotor speeds, an attitude estimator with a slow error): what
the audit found wrong, on its own flights."""
import pytest

from greybox import QuadrotorModel, load_airframe
from greybox.data import load_log
from greybox.diagnosis import diagnose

import racer_sim


def _flight(tmp_path, case, seed, duration=25.0):
    rows, _ = racer_sim.fly(dict(racer_sim.CASES[case]), seed, duration)
    path = tmp_path / f"{case}_{seed}.csv"
    racer_sim.write_csv(rows, str(path))
    return load_log(path)


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    path = tmp_path_factory.mktemp("racer") / "racer.toml"
    racer_sim.airframe_toml(str(path))      # the guesses: K_T x1.25, b x0.7, Kd 0.03, 0.03, 0.05
    return QuadrotorModel(load_airframe(path))


@pytest.mark.slow
def test_a_drag_scattered_by_the_estimators_slow_error_is_not_called_absorbing(model, tmp_path):
    """Nothing missing; the attitude estimate carries a slow error (2-s correlation) that colours
    the position residuals. As the audit ran it (25 s, a 20-s validation flight), the two
    halves' Kd[0] were 0.0586 and 0.0616 (5 % apart, 37 std of the white-residual screen):
    "absorbing something the model lacks". Counted with each half's own std (the colour of the
    residuals it rests on) they are 1.8 std apart, and the fit on all of it covers the truth:
    nothing flagged."""
    d = diagnose(model, _flight(tmp_path, "control", 11), validation=_flight(tmp_path, "control", 12, 20.0),
                 candidates=[], discover=False, iterate=False)
    assert d.baseline_certified
    assert d.inconsistent == {}, d.warnings
    assert not any("differs between the two halves" in w for w in d.warnings), d.warnings
    res = d.baseline      # the fit on all of it: its std covers Kd[0]'s error
    assert abs(res.value("Kd[0]") - racer_sim.VEH["Kd"][0]) < 3 * float(res.std[res.free_names.index("Kd[0]")])


@pytest.mark.slow
def test_a_thrust_that_falls_with_time_is_still_called_absorbing(model, tmp_path):
    """The same racer with its thrust falling 0.4 %/s (``thrust_drift`` hidden): the halves' K_T
    are 5.7 % apart, 7 std of their own: flagged."""
    d = diagnose(model, _flight(tmp_path, "thrust_drift", 61), candidates=[], discover=False, iterate=False)
    assert d.baseline_certified
    assert "K_T" in d.inconsistent, d.warnings
    a, sa, b, sb = d.inconsistent["K_T"]
    assert b / a - 1 == pytest.approx(-0.057, abs=0.02)
    assert abs(a - b) > 3 * (sa ** 2 + sb ** 2) ** 0.5


@pytest.mark.slow
def test_a_yaw_torque_outside_the_catalogue_does_not_get_a_b_further_off_offered(model, tmp_path):
    """The motors' acceleration reaction torque ``J_r Σ spin dw/dt`` (outside the catalogue:
    ``gyroscopic`` holds the rotors' momentum, not its rate of change), seed 121. The fitted b is
    1.4 % from the truth, its halves 8.7 % apart: 14 std of the white-residual screen, 2.4 of
    their own. Flagged, they had the disturbance refit's b (18 % low) offered: "take this b".
    Within their own std they are no evidence of a closed-loop bias: nothing is offered."""
    est, val = _flight(tmp_path, "rotor_accel", 121), _flight(tmp_path, "rotor_accel", 122, 20.0)
    d = diagnose(model, est, validation=val, candidates=[], discover=False, iterate=False)
    assert d.baseline_certified
    assert "b" not in d.inconsistent, d.warnings
    assert not any("take this b" in w for w in d.warnings), d.warnings
    assert d.final_fit.value("b") == pytest.approx(racer_sim.VEH["b"], rel=0.03)

"""The gyro's scale read against the attitude's turning, from the log alone."""
from dataclasses import replace

import numpy as np
import pytest

from greybox import QuadrotorModel, fit, load_airframe
from greybox.kinematics import SCALE_NOTABLE, gyro_scale
from greybox.synth import SensorSpec, synthesize

from conftest import AIRFRAMES


@pytest.fixture(scope="module")
def flight():
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    return model, synthesize(model, duration=30.0, seed=7, sensors=SensorSpec(rate=200.0, vision_rate=50.0),
                             manoeuvres=["hover", "yaw", "step_x", "step_y", "yaw", "step_z"]).log


def _gyro_times(log, k):
    """The log with its gyro times ``k`` (one factor, or one per axis p, q, r)."""
    out = log.outputs.copy()
    for c, kc in zip("pqr", np.broadcast_to(k, 3)):
        out[:, log.output_names.index(c)] *= kc
    return replace(log, outputs=out)


def _attitude_late(log, delay):
    out = log.outputs.copy()
    for c in ("phi", "theta", "psi"):
        i = log.output_names.index(c)
        ok = np.isfinite(out[:, i])
        out[:, i] = np.where(ok, np.interp(log.t - delay, log.t[ok], out[ok, i]), np.nan)
    return replace(log, outputs=out)


def test_a_gyro_reading_3_percent_high_is_read_and_a_true_one_is_not(flight):
    """The gyro times 1.03: every axis read reads 1.03 within 3 std, yaw (the flight's turns)
    within 1.2 %; the true gyro and the true gyro beside an attitude 20 ms late (motion
    capture's latency; a first-order delay term alone left q +4 %) read 1 within 3 std, and
    nothing is said."""
    _, log = flight
    high = gyro_scale(_gyro_times(log, 1.03))
    for a, k in high.scale.items():
        assert abs(k - 1.03) < 3 * high.std[a], (a, k, high.std[a])
    assert high.std["r"] < 0.012 and "r" in high.off() and "the gyro reads" in high.words()
    for other in (log, _attitude_late(log, 0.02)):
        read = gyro_scale(other)
        assert all(abs(k - 1) < max(3 * read.std[a], SCALE_NOTABLE) for a, k in read.scale.items()), read
        assert read.words() == ""
    assert gyro_scale(_attitude_late(log, 0.02)).delay == pytest.approx(0.02, abs=0.004)


def test_the_fit_says_when_the_gyro_reads_off_the_attitude(flight):
    model, log = flight
    said = [w for w in fit(model, _gyro_times(log, 1.05), max_iter=20).warnings if "the gyro reads" in w]
    assert len(said) == 1 and "calibrate the gyro" in said[0] and "add the effect gyro_scale" in said[0], said
    assert not [w for w in fit(model, log, max_iter=20).warnings if "the gyro reads" in w]


def test_the_effect_gyro_scale_fits_the_scale_and_the_parameters_come_back(flight):
    """The gyro times (1.02, 0.97, 1.05): the base model's b is many std off; with
    ``gyro_scale`` every k_gyro is within 3 std of the truth, b and K_T within 3 std of the
    true model's, and nothing is said about the gyro (the model fits its scale)."""
    from greybox.effects import by_name
    model, log = flight
    k = (0.02, -0.03, 0.05)
    off = _gyro_times(log, 1 + np.array(k))
    truth = model.parameter_dict(model.default_parameters())
    base = fit(model, off, max_iter=30)
    i_b = base.free_names.index("b")
    assert abs(model.parameter_dict(base.p)["b"] - truth["b"]) > 5 * base.std[i_b]
    res = fit(model + by_name("gyro_scale"), off, max_iter=30)
    assert res.converged
    got = res.model.parameter_dict(res.p)
    for j, kc in enumerate(k):
        name = f"k_gyro[{j}]"
        assert abs(got[name] - kc) < 3 * res.std[res.free_names.index(name)], (name, got[name])
    for name in ("K_T", "b"):
        assert abs(got[name] - truth[name]) < 3 * res.std[res.free_names.index(name)], (name, got[name], truth[name])
    assert not [w for w in res.warnings if "the gyro reads" in w]


@pytest.mark.slow
def test_a_diagnosis_that_finds_nothing_missing_names_the_gyros_scale(flight):
    """Nothing in the catalogue is missing, the gyro reads 5 % high: the null says so, and why
    the parameters cannot be believed, rather than "nothing significant is missing"."""
    from greybox import diagnose
    model, log = flight
    d = diagnose(model, _gyro_times(log, 1.05), candidates=["ground_effect"], iterate=False, discover=False)
    assert d.verdict is None and d.null_reason == "gyro_scale", d.null_reason
    assert "the gyro reads" in d.verdict_text() and "calibrate the gyro" in d.verdict_text()
    assert "gyro_scale, not among the candidates" in d.verdict_text()
    j = d.as_json()
    assert j["null_reason"] == "gyro_scale" and abs(j["gyro_scale"]["r"]["value"] - 1.05) < 0.02
    assert diagnose(model, log, candidates=["ground_effect"], iterate=False, discover=False).gyro_scale is None


@pytest.mark.slow
def test_a_diagnosis_names_gyro_scale_when_it_may_try_it(flight):
    """The same flight with the effect among the candidates: the verdict is gyro_scale, each
    axis's scale within 3 std of 0.05 in the final model."""
    from greybox import diagnose
    model, log = flight
    d = diagnose(model, _gyro_times(log, 1.05), candidates=["ground_effect", "gyro_scale"], iterate=False,
                 discover=False)
    assert d.verdict == "gyro_scale", d.verdict_text()
    res = d.final_fit
    got = res.model.parameter_dict(res.p)
    for j in range(3):
        name = f"k_gyro[{j}]"
        assert abs(got[name] - 0.05) < 3 * res.std[res.free_names.index(name)], (name, got[name])


def test_a_gyro_scale_of_a_calibrated_gyro_is_physically_negligible(flight):
    """k_gyro fitted at 0.2 % (a calibrated gyro's residual) is negligible, whatever its LR;
    at 3 % it is not (Effect.negligible_size: 0.5 %)."""
    from greybox.diagnosis.screening import physically_negligible
    from greybox.effects import by_name
    model, log = flight
    small = fit(model + by_name("gyro_scale"), _gyro_times(log, 1.002), max_iter=30)
    assert "negligible for gyro_scale" in physically_negligible(small, "gyro_scale")
    large = fit(model + by_name("gyro_scale"), _gyro_times(log, 1.03), max_iter=30)
    assert physically_negligible(large, "gyro_scale") == ""


def test_the_diagnosis_tries_gyro_scale_where_the_log_hints_at_it(flight):
    """A default candidate where the gyro's reading against the attitude hints at a scale error
    (1 % and 2 std on some axis), not where it reads true or cannot be read (no turns: a real
    Crazyflie flight's refit took k_gyro to its bounds in every round, standing in for a moment)."""
    from greybox.diagnosis.ranking import default_candidates
    model, log = flight
    assert "gyro_scale" in default_candidates(model, [_gyro_times(log, 1.03)])
    assert "gyro_scale" not in default_candidates(model, [log])
    hover = log.slice(0, int(np.searchsorted(log.t, 4.0)))      # the first manoeuvre: a hover
    assert gyro_scale(_gyro_times(hover, 1.03)) is None
    assert "gyro_scale" not in default_candidates(model, [_gyro_times(hover, 1.03)])


def _speeds_shifted(log, rows):
    """The log with its rotor speeds stamped ``rows`` rows late (> 0) or early (< 0): the speed
    logged at a row is the one ``rows`` rows before it (the ends held)."""
    idx = np.clip(np.arange(len(log)) - rows, 0, len(log) - 1)
    return replace(log, inputs=log.inputs[idx])


def test_rotor_speeds_stamped_late_against_the_gyro_are_read_from_the_log(flight):
    """The body's roll and pitch acceleration against the moment of the logged speeds: greybox's
    own flight (200 Hz rows) as logged, within a row of no shift and nothing said; its speeds
    stamped 2 rows (10 ms) late, the body leads them by 10 ms and the fit says so; stamped 4
    rows early (a delay, as a command's), the body follows them 20 ms later, which physics
    allows (command_delay holds it) and nothing is said of lateness."""
    from greybox.kinematics import input_lead
    model, log = flight
    P = model.airframe.rotor_positions
    as_logged = input_lead(log, P)
    # a row's speed acts over the row after it (held): half a row's lag, 2.5 ms, is no shift
    assert as_logged.lag == pytest.approx(0.0025, abs=0.001) and abs(as_logged.shift) < 0.001
    assert as_logged.correlation > 0.9 and not as_logged.late() and as_logged.words() == ""
    late = input_lead(_speeds_shifted(log, 2), P)
    assert late.shift == pytest.approx(-0.010, abs=0.001) and late.late(), late
    assert "leads the logged rotor speeds' moment by 10 ms" in late.words()
    early = input_lead(_speeds_shifted(log, -4), P)
    assert early.shift == pytest.approx(0.020, abs=0.001) and not early.late(), early
    res = fit(model, _speeds_shifted(log, 2).split(0.8)[0], progress=False, max_iter=5)
    assert any("stamped late against the gyro" in w for w in res.warnings), res.warnings
    res = fit(model, log.split(0.8)[0], progress=False, max_iter=5)
    assert not any("stamped late" in w for w in res.warnings), res.warnings

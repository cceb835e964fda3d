"""A fourteenth blind audit's outdoor PX4-style quadrotor (``tests/outdoor_sim.py``: its own
simulator of a 2 kg vehicle, a PX4-like cascade at 500 Hz, 200 Hz rows, RTK-like positions at
10 Hz, an EKF-like attitude with a slow error): what the audit found wrong, on its own flights."""
import pytest

from greybox import QuadrotorModel, load_airframe
from greybox.data import load_log
from greybox.diagnosis import diagnose

import outdoor_sim

AIRFRAME = """[airframe]
name = "outdoor_2kg_x"
mass = 2.0
inertia = [0.028, 0.026, 0.048]
arm_length = 0.25
layout = "x"
rotor_inertia = 3.0e-5
gravity = 9.81

[parameters]
K_T = 1.755e-5     # truth 1.35e-5 (x1.30)
b = 1.4e-7         # truth 2.0e-7 (x0.70)
Kd = [0.21, 0.21, 0.21]   # truth 0.30 (x0.70)
"""


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    path = tmp_path_factory.mktemp("outdoor") / "outdoor.toml"
    path.write_text(AIRFRAME)
    return QuadrotorModel(load_airframe(path))


def _flight(tmp_path, case, seed, duration):
    out = tmp_path / f"{case}_{seed}.csv"
    outdoor_sim.fly(dict(outdoor_sim.CASES[case]), seed, duration, str(out))
    return load_log(out)


@pytest.mark.slow
def test_a_motor_lag_behind_logged_commands_is_certified_and_added(model, tmp_path):
    """The controller's speed commands logged (PX4's actuator outputs), 35-ms motors. The
    refit with ``motor_lag`` never certified: one more Gauss-Newton step would move the first
    nodes' effective speeds by 107 of their noise scale, a decrease of 0.064 predicted that the
    step itself turned into +9.8 (process noise spanning eleven decades of weights). The
    verdict was named, but the final model was the base model. Now the step's realised
    decrease counts: certified, added, its parameters the truth's."""
    est, val = _flight(tmp_path, "c10_cmd", 21, 45.0), _flight(tmp_path, "c10_cmd", 121, 30.0)
    d = diagnose(model, est, validation=val, candidates=["motor_lag"], iterate=False, discover=False)
    assert d.verdict == "motor_lag" and "motor_lag" in d.final_model.effect_names, d.summary()
    final = d.final_fit
    assert final.converged, final.status
    assert final.value("tau_m") == pytest.approx(outdoor_sim.TRUE["tau_m"], rel=0.1)
    assert final.value("K_T") == pytest.approx(outdoor_sim.TRUE["K_T"], rel=0.01)
    assert final.value("b") == pytest.approx(outdoor_sim.TRUE["b"], rel=0.01)
    assert "not in the final model" not in d.summary()


@pytest.mark.slow
def test_a_weak_rotor_is_not_named_from_a_second_of_steady_flight(model, tmp_path):
    """Rotor 2 at 92 % thrust. The estimation flight (figure-eights outdoors) holds 1.15 s of
    steady flight, during a yaw command that drove one spin direction harder: "w1 -8.2 %,
    w2 -0.6 %" had named the wrong rotor while the verdict's gains named rotor 2. Two blocks of
    half a second cannot tell the shares' scatter: no imbalance is told (nor a trim following
    the speed). The validation flight's 3.1 s do: rotor 2 driven +6.4 % (its share's std 0.6 %),
    what a rotor with 8 % less thrust needs."""
    from greybox.diagnosis import command_imbalance

    est = command_imbalance(model, _flight(tmp_path, "c7_weak", 17, 45.0))
    assert est.seconds < 2.0 and est.evidence == set() and not est.notable, est
    val = command_imbalance(model, _flight(tmp_path, "c7_weak", 107, 30.0))
    assert val.evidence == {"steady"}, val
    assert max(val.share, key=lambda n: val.share[n]) == "w2"
    assert val.share["w2"] == pytest.approx(0.064, abs=0.02) and val.share_std["w2"] < 0.02


@pytest.mark.slow
def test_a_force_outside_the_catalogue_is_said_to_bend_the_thrust_coefficient(model, tmp_path):
    """Translational lift (thrust x (1 + 0.0015 |v_horizontal|²), outside the catalogue): the
    verdict is an honest null, but the final K_T had been given 4 % high at 161 of its std with
    no word on it. The final model still misses a force, and a warning says K_T and the drag
    take it up: this model's compromise, further off than their std say."""
    d = diagnose(model, _flight(tmp_path, "c9a_etl", 19, 45.0), validation=_flight(tmp_path, "c9a_etl", 109, 30.0),
                 candidates=[], discover=False, iterate=False)
    assert d.final_fit.converged and "z" in d.unexplained, d.summary()
    kt = d.final_fit.value("K_T") / outdoor_sim.TRUE["K_T"] - 1
    assert kt > 0.02, kt             # the lift's share of the thrust, taken up by K_T
    words = [w for w in d.warnings if w.startswith("final model: it still misses a force")]
    assert words and "K_T" in words[0] and "compromise" in words[0], d.warnings


@pytest.mark.slow
def test_a_gnss_antenna_away_from_the_centre_of_gravity_is_measured_by_position_offset(model, tmp_path):
    """The antenna 10 cm ahead of the CoG and 15 cm above it (a PX4 log without
    ``EKF2_GPS_POS``), 36-47 degree tilts and yaw sweeps: ``position_offset`` is significant in
    the fit, its refit recovers the offset within 3 of its std, and the verdict is it or
    null (the 1-s validation error of a 20-m figure-eight cannot see 10 cm), never another
    effect. The audit had found nothing to name: the catalogue held no lever arm."""
    est, val = _flight(tmp_path, "c9b_lever", 20, 45.0), _flight(tmp_path, "c9b_lever", 110, 30.0)
    d = diagnose(model, est, validation=val, candidates=["position_offset", "attitude_bias", "wind"],
                 iterate=False, discover=False)
    assert d.verdict in (None, "position_offset"), d.summary()
    cand = next(c for c in d.ranking if c.effect == "position_offset")
    assert cand.p_value < 1e-6 and (cand.significant or cand.not_confirmed), d.summary()
    fr = cand.fit
    assert fr is not None and fr.converged, fr.status if fr is not None else "no refit"
    std = dict(zip(fr.free_names, fr.std))
    for i, truth in enumerate(outdoor_sim.CASES["c9b_lever"]["gnss_lever"]):
        name = f"r_pos[{i}]"
        assert abs(fr.value(name) - truth) < 3 * std[name], (name, fr.value(name), std[name])

"""The twenty-ninth blind audit's Crazyflie-scale vehicle (``tests/audit29_sim.py``: 32 g "x",
K_T 2e-8, b/K_T 5 mm, RK4 at 1 ms under its own 500 Hz Crazyflie-style cascade with a mixer off
the truth, 200 Hz rows, motion capture at 100 Hz with dropouts, the IMU; checked against
``greybox simulate`` to 8e-6 m over 3 s): what it found wrong. Right there: the control case
null, a 2.5 mm CoG offset named to 0.01 mm, a 40-ms motor lag, a battery sag, a hub rotor
drag and a spin direction's weaker rotors named with their parameters within 3 std, and no
``cog_offset``, ``drag_moment`` or ``moment_gain`` where they are not."""
import json
import re
from pathlib import Path

import numpy as np
import pytest

from greybox.cli import main

import audit29_sim as sim


def _flight(tmp: Path, case: str, seconds: float, seed: int = 7, **airframe) -> tuple[str, str]:
    """A shorter estimation flight of ``case`` (the audit's reference, its vehicle) and its
    airframe file (the audit's guesses: K_T 1.3x, b 0.6x, drag half; ``airframe`` overrides)."""
    P = dict(sim.BASE)
    P.update(sim.CASES[case])
    rows, _ = sim.fly(P, sim.ref_est, seconds, seed)
    log, af = tmp / f"{case}.csv", tmp / f"{case}.toml"
    sim.write_csv(str(log), rows)
    sim.write_toml(str(af), {**P, **airframe})
    return str(log), str(af)


@pytest.mark.slow
def test_a_fit_without_the_cog_offset_says_the_steady_torque_it_lacks(tmp_path, capsys):
    """The centre of gravity 2.5 mm forward and 2 mm left of the rotors' centre: the controller
    holds it with rotors 3 and 4 about 14 % apart in w^2, and the base model, which holds no
    steady torque, fitted the thrust down to 5 % of the weight; `greybox fit` then asked only
    whether the airframe was this vehicle's and the speeds in rad/s. The imbalance is now said
    first, with cog_offset and motor_asymmetry as what holds such a torque. By hand, equal
    moments about the CoG at (cx, cy) with no net yaw: s1 - s2 = 2 (cx + cy) / a and
    s3 - s4 = 2 (cx - cy) / a (a = 0.046 / sqrt 2), s1 = -s2, s3 = -s4: +1.5, -1.5, +13.8,
    -13.8 %."""
    log, af = _flight(tmp_path, "B", 10.0)
    assert main(["fit", log, "--airframe", af, "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "drive the rotors unequally" in err and "cog_offset" in err, err
    assert err.index("drive the rotors unequally") < err.index("is the airframe"), err
    a = sim.BASE["arm"] / np.sqrt(2)
    cx, cy = sim.CASES["B"]["r_cog"]
    by_hand = {"w1": (cx + cy) / a, "w2": -(cx + cy) / a, "w3": (cx - cy) / a, "w4": -(cx - cy) / a}
    for rotor, share in by_hand.items():
        said = float(re.search(rf"{rotor} ([+-][0-9.]+) %", err).group(1)) / 100
        assert said == pytest.approx(share, abs=0.01), (rotor, said, share)


@pytest.mark.slow
def test_a_fit_given_a_fifth_of_the_inertia_says_the_inertia_the_log_gives(tmp_path, capsys):
    """The control flight given an airframe with a fifth of the vehicle's inertia: on the
    audit's 30-s flight the fit ended "line search failed" with the roll's gaps 3.6e4 times
    their noise; on this 10-s one it is certified with process noise, its thrust 53 % of the
    weight, and the words blamed a torque the model lacks (a CoG offset, rotors that differ).
    The log alone gives the body's roll and pitch accelerations per rotor-speed difference: a
    fifth of what the airframe says, said first, with the inertia that makes them agree (within
    15 % of the vehicle's). Given its own inertia the log says 0.8-1.1 (0.89 and 0.90 measured:
    the 2 rad/s of noise on the speeds attenuates a regression on them, and the mixer is off
    the truth), and 0.6 of it is not said (within what a lag or a rotor drag moves)."""
    from greybox import QuadrotorModel, load_airframe, load_log
    from greybox.diagnosis.analysis import log_moment_scale, log_moment_words

    J = np.asarray(sim.BASE["J"], dtype=float)
    log, af = _flight(tmp_path, "A", 10.0, J=(J / 5).tolist())
    out = tmp_path / "fit.json"
    assert main(["fit", log, "--airframe", af, "--quiet", "--json", str(out)]) == 0
    capsys.readouterr()
    first = json.loads(out.read_text())["warnings"][0]
    k = float(re.search(r"roll and pitch accelerations are ([0-9.]+) times", first).group(1))
    said = re.search(r"with Jx, Jy = ([0-9.e-]+), ([0-9.e-]+) kg m\^2", first)
    assert 0.8 * 0.2 <= k <= 1.1 * 0.2 and said, first
    assert [float(said.group(1)), float(said.group(2))] == pytest.approx(J[:2].tolist(), rel=0.15), first
    flight = load_log(log)
    for share, told in ((1.0, False), (0.6, False), (5.0, True)):
        _, given = _flight(tmp_path, "A", 1.0, J=(share * J).tolist())
        model = QuadrotorModel(load_airframe(given))
        scale = np.asarray(log_moment_scale(model, flight)) / share
        assert np.all((0.8 <= scale) & (scale <= 1.1)), (share, scale)
        assert bool(log_moment_words(model, flight)) is told


@pytest.fixture(scope="module")
def cases(tmp_path_factory) -> Path:
    """The audit's control, CoG-offset and battery cases (est 30 s, val 20 s each), byte for
    byte."""
    out = tmp_path_factory.mktemp("audit29")
    sim.main(["A", "B", "D"], out=str(out))
    return out


def _diagnose(cases: Path, case: str, tmp_path: Path, capsys) -> dict:
    out = tmp_path / f"{case}.json"
    assert main(["diagnose", str(cases / f"{case}_est.csv"), "--airframe", str(cases / f"{case}.toml"),
                 "--validation", str(cases / f"{case}_val.csv"), "--json", str(out), "--quiet"]) == 0
    capsys.readouterr()
    return json.loads(out.read_text())


def _z(res: dict, name: str, truth: float) -> float:
    par = res["model"]["parameters"][name]
    return (par["value"] - truth) / par["std"]


@pytest.mark.slow
def test_the_flights_are_the_audits(cases):
    import hashlib
    for case, digest in (("A", "c3971f1c90500f7e"), ("B", "610c529d09a63910"), ("D", "1ed3d0dc729ab432")):
        assert hashlib.sha256((cases / f"{case}_est.csv").read_bytes()).hexdigest()[:16] == digest, case
    truth = json.loads((cases / "truth.json").read_text())
    assert truth["B"]["r_cog"] == [0.0025, -0.002] and truth["D"]["K_vbat"] == 0.2


@pytest.mark.slow
def test_the_control_case_is_null_with_every_parameter_within_3_std(cases, tmp_path, capsys):
    res = _diagnose(cases, "A", tmp_path, capsys)
    assert res["verdict"] is None and res["model"]["certified"] and res["model"]["adequate"]
    for name, truth in (("K_T", 2e-8), ("b", 1e-10), ("Kd[0]", 0.01), ("Kd[1]", 0.01), ("Kd[2]", 0.012)):
        assert abs(_z(res, name, truth)) < 3, (name, res["model"]["parameters"][name])


@pytest.mark.slow
def test_the_cog_offset_is_named_and_the_baselines_words_say_whose_they_are(cases, tmp_path, capsys):
    """Named to 0.01 mm; the baseline's "Kd[2] = 0.32 sits on its bound" read as the final
    model's (0.0119) without the "baseline fit:" the baseline's other words carry."""
    res = _diagnose(cases, "B", tmp_path, capsys)
    assert res["verdict"] == "cog_offset"
    for name, truth in (("r_cog[0]", 0.0025), ("r_cog[1]", -0.002), ("K_T", 2e-8), ("b", 1e-10)):
        assert abs(_z(res, name, truth)) < 3, (name, res["model"]["parameters"][name])
    bound = [w for w in res["warnings"] if "sits on its bound" in w]
    assert all(w.startswith("baseline fit:") for w in bound), bound


@pytest.mark.slow
def test_a_lag_the_rows_cannot_tell_is_said_to_move_the_vertical_drag(cases, tmp_path, capsys):
    """Commands logged at 200 Hz behind 3-ms motors, the thrust following the battery: the
    verdict battery_voltage (K_vbat within 3 std) and a motor lag refused as under half a row.
    The final model's Kd[2] was 0.0093 ± 0.0003 for the truth's 0.012 (-7.8 std), nothing said;
    with the lag on its 2-ms bound it is 0.0137. The range is said, and the truth is in it."""
    res = _diagnose(cases, "D", tmp_path, capsys)
    assert res["verdict"] == "battery_voltage" and abs(_z(res, "K_vbat", 0.2)) < 3
    said = [w for w in res["warnings"] if "a lag under half a row of the logged inputs" in w and
            w.startswith("Kd[2] ")]
    assert len(said) == 1, res["warnings"]
    without, with_lag = (float(v) for v in re.search(r"Kd\[2\] ([0-9.e-]+) ± [0-9.e-]+ without it, ([0-9.e-]+) with it",
                                                     said[0]).groups())
    assert min(without, with_lag) < 0.012 < max(without, with_lag), said


@pytest.mark.slow
def test_the_steady_torque_is_said_only_where_the_rotors_are_driven_unequally(cases):
    """The words need both a thrust no vehicle's and a steady imbalance: at the same
    flightless parameters (K_T a twentieth of the truth) the CoG-offset flight gets them and
    the control flight, whose rotors share the work equally in steady flight, does not; nor
    does the CoG-offset flight at a thrust that carries the weight."""
    from types import SimpleNamespace
    from greybox import QuadrotorModel, load_airframe, load_log
    from greybox.diagnosis.analysis import steady_torque_words
    model = QuadrotorModel(load_airframe(cases / "A.toml"))
    p = model.default_parameters().copy()
    p[model.param_names.index("K_T")] = 1e-9
    flightless = SimpleNamespace(free_names=["K_T", "b"], p=p)
    control = model.prepare_log(load_log(str(cases / "A_est.csv")))
    offset = model.prepare_log(load_log(str(cases / "B_est.csv")))
    assert "drive the rotors unequally" in steady_torque_words(model, [offset], flightless)
    assert steady_torque_words(model, [control], flightless) == ""
    p[model.param_names.index("K_T")] = 2e-8
    assert steady_torque_words(model, [offset], SimpleNamespace(free_names=["K_T", "b"], p=p)) == ""

"""A twenty-seventh blind audit's sprayer (``tests/audit27_sim.py``: a 4 kg "x" quadrotor flying
spray lanes, its tank emptying or not, in a wind or not; quaternion RK4 at 1 ms under its own
200 Hz cascade with torque excitation, 30-ms motors whose actual speeds are logged, attitude,
gyro and accelerometer at 200 Hz, positions at 50 Hz): what it found wrong, on its own flights
(the wind-and-tank draw byte for byte the audit's files)."""
import json
from pathlib import Path

import numpy as np
import pytest

from greybox.cli import main

import audit27_sim as sim

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> Path:
    """The control flights (estimation seed 11, validation 22) and the second draw of the
    emptying tank in a wind (33, 44), with their airframe files (K_T -30 %, b +30 %, drag 0.2)."""
    out = tmp_path_factory.mktemp("audit27")
    control = sim.sprayer(False)
    for tag, seed in (("est", 11), ("val", 22)):
        sim.write_csv(str(out / f"control_{tag}.csv"), sim.fly(control, seed), extra=False)
    sim.write_airframe(str(out / "control.toml"), control)
    sim.write_airframe(str(out / "drymass.toml"), control, mass=3.2)
    tankwind = sim.sprayer(True)
    tankwind["wind"] = np.array([2.0, -1.2, 0.0])
    for tag, seed in (("est", 33), ("val", 44)):
        sim.write_csv(str(out / f"tankwind_s{seed}_{tag}.csv"), sim.fly(tankwind, seed), extra=False)
    sim.write_airframe(str(out / "tankwind.toml"), tankwind)
    return out


def test_a_wind_beside_a_vehicle_getting_lighter_is_named(flights, tmp_path):
    """The baseline's vertical drag ran to its bound for the mass the vehicle lost, so every
    candidate was refitted from the guesses: the wind's refit took the drag to 0 and ended at
    1.21 times the baseline's cost, "LR 0, p = 1", verdict null. Refitted from the baseline too,
    the wind is the verdict, within 3 std of the truth, and the model is said to still miss
    something."""
    out = tmp_path / "d.json"
    assert main(["diagnose", str(flights / "tankwind_s33_est.csv"), "--validation",
                 str(flights / "tankwind_s44_val.csv"), "--airframe", str(flights / "tankwind.toml"),
                 "--quiet", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["verdict"] == "wind", (doc["verdict"], doc["null_reason"])
    # its optimum certified, but it still misses the lighter vehicle: not adequate, and says so
    assert doc["model"]["certified"] is True and doc["model"]["adequate"] is False
    par = doc["model"]["parameters"]
    for name, truth in (("wind[0]", 2.0), ("wind[1]", -1.2)):
        assert abs(par[name]["value"] - truth) < 3 * par[name]["std"], (name, par[name])


def test_positions_with_y_mirrored_are_refused(flights, tmp_path, capsys):
    """Spray lanes along x: y mirrored correlated 0.92 with the tilt's mirror image and 0.66 as
    given, short of four times less unexplained, and was fitted "certified" with Kd[1] on its
    bound."""
    lines = (flights / "control_est.csv").read_text().splitlines()
    j = lines[0].split(",").index("y")
    rows = [ln.split(",") for ln in lines[1:]]
    for r in rows:
        r[j] = f"{-float(r[j])!r}" if r[j] else ""
    (tmp_path / "ymirror.csv").write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    rc = main(["fit", str(tmp_path / "ymirror.csv"), "--airframe", str(flights / "control.toml"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "y mirrored" in err and err.count("\n") == 1, err


def test_a_dry_mass_for_a_full_tank_is_said_beside_the_moment_gain(flights, tmp_path):
    """The airframe given the dry 3.2 kg of a 4.0 kg sprayer: the diagnosis named moment_gain,
    k_M 1.245, with no word on the mass; its final model now says the mass that makes the
    gain 1, within 3 % of 4.0 kg."""
    import re
    out = tmp_path / "d.json"
    assert main(["diagnose", str(flights / "control_est.csv"), "--validation", str(flights / "control_val.csv"),
                 "--airframe", str(flights / "drymass.toml"), "--quiet", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["verdict"] == "moment_gain", (doc["verdict"], doc["null_reason"])
    said = [w for w in doc["warnings"] if "the airframe's mass is off" in w]
    assert len(said) == 1, doc["warnings"]
    assert float(re.search(r"and with ([0-9.e-]+) kg", said[0]).group(1)) == pytest.approx(4.0, rel=0.03), said


def test_x8_rotor_gains_small_in_force_are_said_undetermined(tmp_path):
    """The X8 coaxial octocopter, its lower rotors at 0.8 of the upper ones: its mixer gives
    each pair equal commands, so the split moves little but yaw, and rotor gains fitted to it
    (upper against lower, ±0.09 ± 0.06 where the truth is ±0.11) were called "physically
    negligible" whatever the truth. Small in force terms, they are now said to be undetermined
    too: the flight shows that they move little, not how large they are."""
    import warnings

    from greybox import QuadrotorModel, effects, fit, load_airframe, load_log
    from greybox.diagnosis.screening import negligible_effect
    v = sim.x8(0.8)
    sim.write_csv(str(tmp_path / "x8_est.csv"), sim.fly(v, 11))
    sim.write_airframe(str(tmp_path / "x8.toml"), v)
    log = load_log(tmp_path / "x8_est.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fit(QuadrotorModel(load_airframe(tmp_path / "x8.toml")) + effects.MotorAsymmetry(), log)
    assert res.converged, res.status
    words = negligible_effect(res, "motor_asymmetry", [log])
    assert "below 2 %" in words and "not determined either" in words, words
    # the upper and lower rotors' gains part with opposite signs, each within 3 std of none
    dev = np.array([res.value(f"K_T_dev[{i}]") for i in range(7)])
    assert np.all(np.abs(dev) < 3 * np.asarray([res.std[res.free_names.index(f"K_T_dev[{i}]")] for i in range(7)]))


def test_the_control_draws_std_are_honest(tmp_path):
    """Four more control draws (seeds 1-4, 40 s each), each fitted by the command line from
    the airframe's guesses: every parameter within 3 std of the truth, and over the twenty the
    RMS of (value - truth) / std at most 1.5. The speeds' 0.5 rad/s of noise is a tiny share
    of their variance; until the process noise's floor counted it, the vertical drag came out
    3.5 std low on the first draw and K_T 2.4 std low on the second (the six draws' RMS
    z-score of K_T 1.6); with it 0.92 over the twenty."""
    v = sim.sprayer(False)
    sim.write_airframe(str(tmp_path / "af.toml"), v)
    truth = {"K_T": v["K_T"], "b": v["b"], "Kd[0]": v["Kd"][0], "Kd[1]": v["Kd"][1], "Kd[2]": v["Kd"][2]}
    z = []
    for seed in (1, 2, 3, 4):
        log = tmp_path / f"c{seed}.csv"
        sim.write_csv(str(log), sim.fly(v, seed), extra=False)
        out = tmp_path / f"c{seed}.json"
        assert main(["fit", str(log), "--airframe", str(tmp_path / "af.toml"), "--json", str(out), "--quiet"]) == 0
        res = json.loads(out.read_text())
        assert res["converged"], seed
        for name, value in truth.items():
            par = res["parameters"][name]
            z.append((par["value"] - value) / par["std"])
            assert abs(z[-1]) < 3, (seed, name, par)
    assert float(np.sqrt(np.mean(np.square(z)))) <= 1.5, z

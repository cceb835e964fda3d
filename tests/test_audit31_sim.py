"""The thirty-first blind audit's 2.6 kg vehicle (``tests/audit31_sim.py``: "x", 12-inch props,
K_T 2.7e-5, b/K_T 14.8 mm, Kd 0.25/0.25/0.40, quaternion RK4 at 1 ms under its own 250 Hz
cascade with its model 5-10 % off, 25-ms motors, 200 Hz rows, motion capture at 100 Hz;
checked against ``greybox simulate`` to 7e-7 m over 4 s): what it found wrong. Right there: the
control case null, certified and adequate; a 40-ms position delay found to 0.7 %; fourteen bad
inputs refused with exit 2.

Wrong: commands logged up to 1400 rad/s on motors that turn 1000 rad/s at most (saturation)
were diagnosed ``thrust_curve`` (k_Tw -0.31), ``b`` 34 % low, and nothing said the commands
went beyond the motors; the CLI fit read the lost moments as an inertia twice the airframe's.
On motors whose speed also slews at most 2500 rad/s^2 behind their 40-ms lag, ``greybox fit
--effects motor_lag`` from the airframe's guesses failed after 200 s ("line search failed")."""
import json

import pytest

from greybox import QuadrotorModel, load_airframe, load_log
from greybox.cli import main
from greybox.diagnosis import thrust_at_top
from greybox.diagnosis.analysis import THRUST_AT_TOP_LOW, thrust_at_top_words

import audit31_sim as sim


def _flight(tmp_path, case: str, kind: str = "val"):
    """One of the audit's flights of ``case`` (the validation flight: 30 s), its log and model."""
    seed = {"control": 100, "slew": 200, "saturation": 300}[case] + (1 if kind == "est" else 2)
    rows, _ = sim.simulate(case, kind, seed, 50.0 if kind == "est" else 30.0)
    sim.write_csv(str(tmp_path / f"{case}_{kind}.csv"), rows)
    sim.write_airframe(str(tmp_path / f"{case}.toml"), f"audit31_{case}")
    return QuadrotorModel(load_airframe(tmp_path / f"{case}.toml")), load_log(tmp_path / f"{case}_{kind}.csv")


@pytest.mark.slow
def test_commands_beyond_what_the_motors_turn_are_told_from_the_log_alone(tmp_path):
    """The saturated validation flight (commands to 1400 rad/s, motors to 1000) gives 79 % of
    the thrust its highest commands ask over four runs of them, and says so; the control
    flight, the same vehicle with its commands within reach, gives 99 % and says nothing."""
    model, log = _flight(tmp_path, "saturation")
    top = thrust_at_top(model, log)
    assert top.low and 0.7 < top.ratio < THRUST_AT_TOP_LOW and top.episodes >= 2, top
    assert 1000 < top.level <= 1400, top
    words = thrust_at_top_words(model, log)
    assert "commands beyond what the motors or their ESCs can give (saturation)" in words, words
    assert f"give {100 * top.ratio:.0f} % of the thrust the commands give" in words, words
    model, log = _flight(tmp_path, "control")
    top = thrust_at_top(model, log)
    assert not top.low and top.ratio > 0.95, top
    assert thrust_at_top_words(model, log) == ""


@pytest.mark.slow
def test_a_fit_fed_commands_beyond_the_motors_says_so_first_and_offers_no_inertia(tmp_path, capsys):
    """``greybox fit`` on the saturated estimation flight: certified, not adequate, its thrust
    at 70 % of the weight. Its first warning is the saturation, and it no longer reads the
    moments the rotors did not give as an inertia off (it said "k_M ≈ 0.484 ... with Jx, Jy =
    0.07239, 0.07652 kg m^2", twice the airframe's, which is the vehicle's)."""
    _flight(tmp_path, "saturation", "est")
    out = tmp_path / "fit.json"
    rc = main(["fit", str(tmp_path / "saturation_est.csv"), "--airframe", str(tmp_path / "saturation.toml"),
               "--json", str(out)])
    cap = capsys.readouterr()
    err = cap.out + cap.err
    assert rc == 0, err
    warnings = [ln for ln in err.splitlines() if ln.startswith("warning:")]
    assert warnings and "where the logged commands are highest" in warnings[0], warnings[:2]
    assert "k_M ≈" not in err and "every moment would match" not in err, err


@pytest.mark.slow
def test_a_thrust_curve_named_behind_saturated_commands_is_said_to_be_possibly_a_stand_in(tmp_path, capsys):
    """The saturated case's diagnosis: the saturation is the first warning, and a verdict whose
    effect lowers the thrust at the highest speeds (``thrust_curve`` with k_Tw < 0, which the
    vehicle does not have) is said to be possibly a stand-in for it; the verdict is no
    better than "the model still misses something"."""
    sim.run_case("saturation", str(tmp_path))
    out = tmp_path / "d.json"
    assert main(["diagnose", str(tmp_path / "saturation_est.csv"), "--validation", str(tmp_path / "saturation_val.csv"),
                 "--airframe", str(tmp_path / "saturation.toml"), "--json", str(out), "--quiet"]) == 0
    capsys.readouterr()
    d = json.loads(out.read_text())
    assert d["warnings"][0].startswith("where the logged commands are highest"), d["warnings"][:2]
    assert not d["model"]["adequate"]
    if "thrust_curve" in d["model"]["effects"] and d["model"]["parameters"]["k_Tw"]["value"] < 0:
        assert any("may stand for commands beyond what the motors can turn" in w for w in d["warnings"]), d["warnings"]


@pytest.mark.slow
def test_the_control_case_is_null_certified_and_adequate(tmp_path, capsys):
    """Nothing beyond the base model (actual speeds at the rows): null, the final model
    certified and adequate, K_T, b and Kd within 0.5 % of the truth."""
    sim.run_case("control", str(tmp_path))
    out = tmp_path / "d.json"
    assert main(["diagnose", str(tmp_path / "control_est.csv"), "--validation", str(tmp_path / "control_val.csv"),
                 "--airframe", str(tmp_path / "control.toml"), "--json", str(out), "--quiet"]) == 0
    capsys.readouterr()
    d = json.loads(out.read_text())
    assert d["verdict"] is None and d["null_reason"] == "nothing_missing", (d["verdict"], d["null_reason"])
    assert d["model"]["certified"] and d["model"]["adequate"]
    truth = sim.TRUTH
    par = d["model"]["parameters"]
    assert par["K_T"]["value"] == pytest.approx(truth["K_T"], rel=0.005)
    assert par["b"]["value"] == pytest.approx(truth["b"], rel=0.005)
    for i in range(3):
        assert par[f"Kd[{i}]"]["value"] == pytest.approx(truth["Kd"][i], rel=0.01)


@pytest.mark.slow
def test_a_motor_lag_fitted_from_the_airframes_guesses_behind_slew_limited_motors_is_certified(tmp_path, capsys):
    """The slew-limited case (commands logged; a 40-ms lag and at most 2500 rad/s^2, binding
    in 3 % of the flight): ``greybox fit --effects motor_lag`` from the airframe's guesses.
    The effective speeds' process noise started at the floor, 1e-6 of the speeds, so their
    continuity was all but a constraint the slew limit broke: 200 s, then "line search
    failed" (exit 1). It now starts at the jump that moves the body states by their own
    process noise: certified, K_T and the horizontal drag within 1 %, ``b`` within 5 %, the
    lag read 40-80 ms (first order through a slower slew), and the speeds' gaps said to be
    systematic."""
    _flight(tmp_path, "slew", "est")
    out = tmp_path / "fit.json"
    rc = main(["fit", str(tmp_path / "slew_est.csv"), "--airframe", str(tmp_path / "slew.toml"),
               "--effects", "motor_lag", "--json", str(out)])
    err = "".join(capsys.readouterr())
    assert rc == 0, err
    d = json.loads(out.read_text())
    assert d["converged"], d["status"]
    p = {k: v["value"] for k, v in d["parameters"].items()}
    assert abs(p["K_T"] / sim.TRUTH["K_T"] - 1) < 0.01, p
    assert abs(p["b"] / sim.TRUTH["b"] - 1) < 0.05, p
    for k in (0, 1):
        assert abs(p[f"Kd[{k}]"] / sim.TRUTH["Kd"][k] - 1) < 0.01, p
    assert 0.04 < p["tau_m"] < 0.08, p
    assert "w_eff" in err and "mostly systematic" in err, err

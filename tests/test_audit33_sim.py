"""The thirty-third blind audit's 0.85 kg "x" quadrotor on 7-inch props (``tests/audit33_sim.py``:
K_T 4.5e-6, b/K_T 15 mm, Kd 0.10/0.11/0.16, J_r 3e-5; quaternion RK4 at 1 ms under its own 200 Hz
geometric cascade, its model 6-10 % off; 15-ms motors; 200 Hz rows of the actual speeds with
0.5 rad/s of noise, 2 mrad attitude, gyro, accelerometer; motion capture at 100 Hz with
dropouts; flights to 7.7 m/s and 48 degrees; checked against ``greybox simulate`` to 7e-12 m over
a 4-s tumble; its files reproduced byte for byte).

Right there: the control case null, certified and adequate, every parameter within 1.6 std; two
catalogue effects together (quadratic drag, a battery sag) named in turn with every parameter
within 1.2 std; three (motor lag behind logged commands, a wind, a 30-ms position delay) named,
within 1.7 std; 19 bad inputs refused with exit 2.
Wrong, and mended: the diagnose JSON listed the added effects in the model's order, not the
rounds'; a first motion-capture frame 1.5 m off was fitted as data; speeds signed by their spin
were fitted with the gyroscopic torque taking the sign twice; ``--effects wind --without wind``
ran without wind; ``fit`` had no separate validation flight. Said, not mended: an onboard
complementary filter's attitude with 1 mrad of noise on it (its slow error 16-40 mrad) had
``position_delay`` named for it (22 ms, 13 std from none); the disagreement with the gyro is now
said beside the verdict, with the accuracy that, given, makes it null."""
import json

import numpy as np
import pytest

from greybox.cli import main

import audit33_sim as sim

pytestmark = pytest.mark.slow

SEEDS_DUR = {"est": (0, 40.0), "val": (1, 30.0)}


def _case(tmp_path, case: str, kinds=("est", "val")) -> None:
    """The audit's flights of ``case`` (estimation 40 s, validation 30 s) and its airframe."""
    (tmp_path / "af.toml").write_text(sim.AIRFRAME)
    plant, flying = sim.CASES[case]
    for kind in kinds:
        k, dur = SEEDS_DUR[kind]
        rows = sim.fly(sim.SEEDS[case][k], dur, sim.Plant(**plant), **flying)
        sim.write_log(str(tmp_path / f"{case}_{kind}.csv"), rows)


def _diagnose(tmp_path, case: str, *extra: str) -> dict:
    out = tmp_path / f"{case}{len(extra)}.json"
    rc = main(["diagnose", str(tmp_path / f"{case}_est.csv"), "--validation", str(tmp_path / f"{case}_val.csv"),
               "--airframe", str(tmp_path / "af.toml"), "--json", str(out), "--quiet", *extra])
    assert rc == 0
    return json.loads(out.read_text())


def test_two_effects_are_named_in_turn_and_the_json_keeps_the_rounds_order(tmp_path):
    """Quadratic drag and a battery sag: round 1 thrust_drift, round 2 quadratic_drag (the JSON's
    ``added`` said ["quadratic_drag", "thrust_drift"], the model's order), the validation error
    falling at each round, every parameter within 3 std."""
    _case(tmp_path, "two")
    d = _diagnose(tmp_path, "two")
    assert d["verdict"] == "thrust_drift" and d["added"] == ["thrust_drift", "quadratic_drag"], d["added"]
    rounds = [r for r in d["rounds"] if r["verdict"]]
    assert [r["verdict"] for r in rounds] == ["thrust_drift", "quadratic_drag"], d["rounds"]
    assert rounds[0]["nrmse_after"] < rounds[0]["nrmse_before"] and rounds[1]["nrmse_after"] < rounds[1]["nrmse_before"]
    assert all(r["in_final_model"] for r in rounds)
    p = d["model"]["parameters"]
    truth = {"K_T": sim.TRUTH["K_T"], "b": sim.TRUTH["b"], "Kd[0]": 0.10, "Kd[1]": 0.11, "Kd[2]": 0.16,
             "Kq[0]": 0.04, "Kq[1]": 0.04, "Kq[2]": 0.04}
    for name, value in truth.items():
        assert abs(p[name]["value"] - value) < 3 * p[name]["std"], (name, p[name], value)
    assert d["attitude_gyro_disagreement"] is None


def test_an_onboard_filters_attitude_with_noise_on_it_is_said_beside_the_verdict(tmp_path):
    """The logged roll and pitch are a complementary filter's (k_P 0.25 rad/s) with 1 mrad of
    white noise on it: weighed by that noise, the diagnosis named a position delay (22 ms, 13 std
    from none) and said nothing. Now the disagreement with the gyro is said (in the warnings, the
    verdict's lines and the JSON) with the accuracy to give; the verdict is judged again with the
    attitude weighed by that disagreement, where the delay goes to none (LR 0): it is left out,
    the verdict null (``attitude_uncertain``: cannot tell); given the accuracy, null too."""
    _case(tmp_path, "estimator")
    d = _diagnose(tmp_path, "estimator")
    off = d["attitude_gyro_disagreement"]
    assert set(off) == {"phi", "theta"}, off
    assert all(v["disagreement"] > 10 * v["noise"] for v in off.values()), off
    note = next(w for w in d["warnings"] if "disagree with the gyro's integral" in w)
    assert "--noise phi=" in note and "--noise theta=" in note, note
    assert d["verdict"] is None and d["null_reason"] == "attitude_uncertain", (d["verdict"], d["null_reason"])
    assert d["attitude_demoted"] == ["position_delay"] and d["added"] == [], d["added"]
    said = next(w for w in d["warnings"] if w.startswith("position_delay stands only with roll and pitch weighed"))
    assert "it does not" in said and "leaves it out" in said, said
    assert "tau_pos" not in d["model"]["parameters"]
    # the accuracy it gives: the verdict is then null
    given = [a for ch in ("phi", "theta") for a in ("--noise", f"{ch}={off[ch]['disagreement']:.2g}")]
    d2 = _diagnose(tmp_path, "estimator", *given)
    assert d2["verdict"] is None and d2["attitude_gyro_disagreement"] is None, (d2["verdict"], d2["null_reason"])


def test_a_first_frame_at_the_origin_is_a_glitch_and_speeds_signed_by_their_spin_are_magnitudes(tmp_path, capsys):
    """The control flight with its first motion-capture frame at the origin (1.5 m off): left out
    with a note, the vertical drag within 3 std (was 15 std off). The same flight with the
    spin -1 rotors' speeds negative: read as magnitudes, the fit at the noise (it was certified
    with p and q 38 and 28 times the noise)."""
    _case(tmp_path, "control", ("est",))
    lines = (tmp_path / "control_est.csv").read_text().splitlines()
    head = lines[0].split(",")
    z, w3, w4 = head.index("z"), head.index("w3"), head.index("w4")
    cells = lines[1].split(",")
    assert cells[z] != ""
    cells[z] = "0.0"
    glitched = [lines[0], ",".join(cells)] + lines[2:]
    (tmp_path / "glitch.csv").write_text("\n".join(glitched) + "\n")
    signed = [lines[0]] + [",".join("-" + c if j in (w3, w4) else c for j, c in enumerate(ln.split(",")))
                           for ln in lines[1:]]
    (tmp_path / "signed.csv").write_text("\n".join(signed) + "\n")
    for name in ("glitch", "signed"):
        rc = main(["fit", str(tmp_path / f"{name}.csv"), "--airframe", str(tmp_path / "af.toml"), "--quiet",
                   "--json", str(tmp_path / f"{name}.json")])
        err = capsys.readouterr().err
        assert rc == 0, err
        d = json.loads((tmp_path / f"{name}.json").read_text())
        if name == "glitch":
            assert "1 position sample of" in err and "(t = 0 s) leaves the track" in err, err
            kd = d["parameters"]["Kd[2]"]
            assert abs(kd["value"] - 0.16) < 3 * kd["std"], kd
        else:
            assert "columns w3, w4 are negative on every row" in err, err
            assert d["certificate"]["optimal"], d["certificate"]["text"]
            for ch in ("p", "q"):
                assert d["certificate"]["residual_over_noise"][ch] < 1.5, d["certificate"]["residual_over_noise"]

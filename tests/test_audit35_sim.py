"""The thirty-fifth blind audit's 250 g indoor "x" quadrotor with a realistic sensor pipeline
(``tests/audit35_sim.py``: quaternion RK4 at 0.5 ms under its own 500 Hz cascade flown on its
own Mahony filter's attitude and a biased gyro; 200-Hz rows with 3 % jitter; motion capture at
100 Hz with dropouts; rotor speeds from ESC eRPM telemetry, quantised, each motor refreshed at
100 Hz on rows of its own; an airframe file with the inertia from CAD 12-15 % off and K_T, b
40 % off; checked against ``greybox simulate`` to 7e-10 m; its files reproduced byte for byte).

Right there: a swinging payload said to be outside the catalogue; an IMU mounted tilted named
``attitude_bias``; 16 of 19 bad inputs refused. Wrong, and mended: a constant gyro bias (no
effect held it) read as "a roll torque the model lacks" (now ``gyro_bias``, confirmed by the
validation flight's own gyro against its attitude); the inertia reading ``fit`` gave dropped
by the diagnosis; the staggered telemetry not found held; a true quadratic drag
refused as a sliver (4 % of a misfit the filter's tilt error and the gyro bias dominated)
while the final Kd carried it 53-83 % high, unsaid."""
import json

import numpy as np
import pytest

from greybox.cli import main

import audit35_sim as sim

pytestmark = pytest.mark.slow


def _given_airframe(path, inertia=None):
    tr = sim.TRUTH
    J = inertia or [tr["J"][0] * 1.15, tr["J"][1] * 1.12, tr["J"][2] * 0.88]
    path.write_text(sim.airframe_text("tiny250", tr["mass"] * 1.012, tr["arm"] * 0.99, J, tr["K_T"] * 1.40,
                                      tr["b"] * 0.62, 1.2e-6))


def _flights(tmp_path, case, effects, seeds):
    for kind, dur, seed in (("est", 40.0, seeds[0]), ("val", 25.0, seeds[1])):
        fl = sim.fly(sim.TRUTH, effects, dur, seed, "normal")
        sim.write_log(str(tmp_path / f"{case}_{kind}.csv"), fl, seed)


def _diagnose(tmp_path, case):
    out = tmp_path / f"{case}.json"
    assert main(["diagnose", str(tmp_path / f"{case}_est.csv"), "--validation", str(tmp_path / f"{case}_val.csv"),
                 "--airframe", str(tmp_path / "af.toml"), "--json", str(out), "--quiet"]) == 0
    return json.loads(out.read_text())


def test_a_quadratic_drag_refused_as_a_sliver_is_said_to_bend_the_final_drag(tmp_path):
    """Kq 0.012 on each axis (more than the linear drag at 3 m/s): refused as a sliver of what
    the model misses, and the final Kd (0.050, 0.059, 0.078 for 0.030, 0.032, 0.051) given
    with nothing said. Now the gyro's bias is named first (then the inertia's moment gain), and
    the drag, significant in its fit, is refused on a validation that cannot tell it (the
    filter's tilt error dominates x and y): a warning gives each Kd beside its value with the
    drag, far nearer the vehicle's."""
    _given_airframe(tmp_path / "af.toml")
    _flights(tmp_path, "b_qdrag", {"Kq": [0.012, 0.012, 0.012]}, (21, 22))
    assert (tmp_path / "b_qdrag_est.csv").stat().st_size > 1e6
    d = _diagnose(tmp_path, "b_qdrag")
    assert d["verdict"] == "gyro_bias", (d["verdict"], d["added"])
    said = next(w for w in d["warnings"] if w.startswith("the final values depend on forms the data could not name"))
    for j in range(3):
        assert f"Kd[{j}]" in said and "with quadratic_drag" in said, said
    q = next(c for r in d["rounds"] for c in [r] if r["best"] == "quadratic_drag")
    assert q["verdict"] is None, q
    segments = {f"Kd[{j}]": said.split(f"Kd[{j}] ", 1)[1].split(")")[0] for j in range(3)}
    assert all(" with quadratic_drag" in v for v in segments.values()), segments
    with_drag = {n: float(v.split(" with quadratic_drag")[0].rsplit(" ", 1)[-1].strip("(,")) for n, v in segments.items()}
    for j, truth in enumerate((0.030, 0.032, 0.050)):
        # with the drag each Kd is far nearer the vehicle's (at the mass given, x1.012)
        final = d["model"]["parameters"][f"Kd[{j}]"]["value"]
        assert abs(with_drag[f"Kd[{j}]"] - 1.012 * truth) < 0.5 * abs(final - 1.012 * truth), (j, with_drag, final)


def test_a_gyro_bias_and_a_cad_inertia_are_named_and_the_held_telemetry_found(tmp_path, capsys):
    """The control flight: a gyro biased (0.020, -0.015, 0.012) rad/s and the CAD inertia
    (Jx, Jy 15 %, 12 % high). It was "a roll torque the model lacks ... outside the catalogue".
    The diagnosis now names ``gyro_bias`` first, within 3 std of the truth, confirmed by the
    validation flight's own gyro against its attitude (its predictions hardly move with a
    sensor's offset), then ``moment_gain`` (k_M about 1.11: the inertia given over the true);
    it says the speeds are held per motor. With the true inertia, the bias and the speeds
    interpolated, ``fit`` is at the noise and ``b`` within 3 std of the truth."""
    _given_airframe(tmp_path / "af.toml")
    _flights(tmp_path, "a_control", {}, (11, 12))
    d = _diagnose(tmp_path, "a_control")
    assert d["verdict"] == "gyro_bias" and d["added"][:2] == ["gyro_bias", "moment_gain"], d["added"]
    p = d["model"]["parameters"]
    for j, truth in enumerate(sim.TRUTH["gyro_bias"]):
        v = p[f"gyro_bias[{j}]"]
        assert abs(v["value"] - truth) < 3 * v["std"] + 0.001, (j, v)
    assert 1.05 < p["k_M"]["value"] < 1.2, p["k_M"]
    g = next(c for c in d["ranking"] if c["effect"] == "gyro_bias")
    assert "confirmed where the predictions cannot: the validation flights' own gyro" in g["reason"], g["reason"]
    assert any("each of the rotor speeds repeats the previous row" in w for w in d["warnings"]), d["warnings"]
    _given_airframe(tmp_path / "true.toml", inertia=list(sim.TRUTH["J"]))
    out = tmp_path / "fit.json"
    assert main(["fit", str(tmp_path / "a_control_est.csv"), "--airframe", str(tmp_path / "true.toml"),
                 "--effects", "gyro_bias", "--held", "interpolate", "--quiet", "--json", str(out)]) == 0
    capsys.readouterr()
    r = json.loads(out.read_text())
    assert r["converged"] and r["certificate"]["adequate"], r["certificate"]
    b = r["parameters"]["b"]
    assert abs(b["value"] - sim.TRUTH["b"]) < 3 * b["std"], b

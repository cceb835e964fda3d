"""A twenty-first blind audit's Crazyflie (``tests/audit21_sim.py``: its own RK4 at 1 kHz, a
cascaded controller at 500 Hz sending PWM through the Förster map times a battery factor,
30-ms motors, NanoBench CSV files with PWM held at 83 Hz), imported and diagnosed as the
README's real-data recipe says: what it found wrong."""
import json

import numpy as np
import pytest

from greybox.cli import main
from greybox.effects import YawTorque

import audit21_sim as sim

pytestmark = pytest.mark.slow


def _imported(tmp_path, case):
    """The case's flights imported as the README's recipe says: (est, val, airframe) paths."""
    (est, val), truth = sim.flights(tmp_path, case)
    out = []
    for path, part in ((est, "est"), (val, "val")):
        csv = tmp_path / f"{part}.csv"
        extra = ["--airframe-out", str(tmp_path / "cf.toml"), "--mass", "0.031"] if part == "est" else []
        assert main(["import", "nanobench", path, "--out", str(csv), *extra]) == 0
        out.append(str(csv))
    return out[0], out[1], str(tmp_path / "cf.toml"), truth


def test_rotors_of_one_spin_direction_weaker_in_thrust_and_torque_are_found_with_a_propellers_b(tmp_path):
    """M2 and M4 (clockwise) give 8 % less thrust and yaw torque per w^2: the controller drives
    them 4.2 % harder, as on the real NanoBench flights. The fit escapes the yaw torque that
    difference would give through b near zero; the diagnosis refused motor_asymmetry's refit
    from there (gains by spin direction with b/K_T 1.6e-6 m) and kept b = 2.8e-13 in its final
    model. Refitted with b first held at the airframe's ratio, the gains carry the pair: their
    ratio within 1 % of 0.92, b within 3 std of the truth and in the propellers' range. (With
    the inputs' noise read from the fresh rows, motor_lag's round-2 refit stopped capped beside
    command_delay's, both validating alike: solved on, it goes first and the pair follows.) No
    hub drag: its fourth-round refit predicted theta 15 % better and z 2.2 times worse."""
    est, val, af, truth = _imported(tmp_path, "weak_pair")
    res = tmp_path / "d.json"
    assert main(["diagnose", est, "--validation", val, "--airframe", af,
                 "--process-noise", "auto", "--horizon", "0.5", "--quiet", "--json", str(res)]) == 0
    d = json.loads(res.read_text())
    p = d["model"]["parameters"]
    assert "motor_asymmetry" in d["model"]["effects"], (d["verdict"], d["model"]["effects"])
    # no hub drag in the truth: its refit traded z (+124 %), x and y for theta (-15 %)
    assert "hub_rotor_drag" not in d["model"]["effects"], d["model"]["effects"]
    dev = np.array([p[f"K_T_dev[{i}]"]["value"] for i in range(3)])
    gains = 1 + np.append(dev, -dev.sum())
    ratio = gains[[1, 3]].mean() / gains[[0, 2]].mean()
    assert ratio == pytest.approx(0.92, rel=0.01), gains
    kt, b = p["K_T"]["value"], p["b"]
    mean_gain = float(np.mean(truth["gain"]))
    assert kt == pytest.approx(truth["K_T"] * mean_gain, rel=0.01)
    assert abs(b["value"] - truth["b"] * mean_gain) < 3 * b["std"], (b, truth["b"] * mean_gain)
    lo, hi = YawTorque.RATIO_RANGE
    assert lo < b["value"] / kt < hi


@pytest.mark.xfail(strict=True, reason="a soft fit's motor-lag states keep their gaps' random part as process noise "
                   "and the joint optimum raises k_M (1.59 +- 0.13 for 1, since 0570440); taking it to the floor mends "
                   "this but dropped a real flight's motor lag (B8_star_medium, docs/VALIDATION.md audit 36): needs a "
                   "process-noise estimate with a fixed point")
def test_commands_sampled_slower_than_the_controller_are_not_a_moment_gain(tmp_path):
    """The control case (battery sag and 30-ms motors, which every Crazyflie has; nothing else):
    a 500-Hz controller's commands refreshed at 83 Hz and interpolated onto the 100-Hz rows carry
    its fast content as white noise the rotors never followed (errors in the inputs). Read over
    every row, that noise came out a third low (an interpolated row has none of its own), the
    smoother left most of it in, and the moment gain it weakens was named: k_M 0.73 ± 0.075
    in the final model (truth 1), 0.67 ± 0.10 fitted with the true structure to the smoothed
    speeds. Read from the fresh rows, the smoothed speeds give k_M within 2 std of 1 and b
    within 2 std of the truth, and moment_gain is neither the verdict nor in the final model."""
    from greybox import QuadrotorModel, denoise_inputs, effects, fit, load_airframe, load_log
    est, val, af, truth = _imported(tmp_path, "control")
    model = QuadrotorModel(load_airframe(af))
    log, info = denoise_inputs(model, load_log(est))
    assert info is not None and min(info.noise.values()) > 7.0, info      # 5.5 rad/s read over every row
    full = model + [effects.MotorLag(), effects.MomentGain(), effects.ThrustDrift()]
    res = fit(full, log, process_noise="auto")
    assert res.converged, res.certificate.text()
    k_m, s_m = res.value("k_M"), float(res.std[res.free_names.index("k_M")])
    assert abs(k_m - 1.0) < 2 * s_m, (k_m, s_m)
    b, s_b = res.value("b"), float(res.std[res.free_names.index("b")])
    assert abs(b - truth["b"]) < 2 * s_b, (b, s_b, truth["b"])
    out = tmp_path / "d.json"
    assert main(["diagnose", est, "--validation", val, "--airframe", af, "--process-noise", "auto",
                 "--horizon", "0.5", "--quiet", "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["verdict"] != "moment_gain" and "moment_gain" not in d["model"]["effects"], (d["verdict"], d["model"])
    # what it adds (a disturbance torque too, once) must not predict worse than the model as given
    assert d["final"]["nrmse"] <= d["baseline"]["nrmse"] * 1.01, (d["final"], d["baseline"]["nrmse"])

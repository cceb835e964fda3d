"""A sixteenth blind audit's 1.2 kg "x" quadrotor (``tests/cascade_sim.py``: its own simulator,
a 400 Hz cascaded PID, 30-ms motors, ESC speeds sampled at 200 Hz rows, motion capture at
100 Hz): what the audit found wrong, on its own flights."""
import json

import numpy as np
import pytest

from greybox import QuadrotorModel, load_airframe
from greybox.cli import main
from greybox.data import load_log
from greybox.diagnosis import diagnose

import cascade_sim


def _case(tmp_path, case):
    est, val = tmp_path / f"{case}_est.csv", tmp_path / f"{case}_val.csv"
    truth = cascade_sim.flight(case, "est", est)
    cascade_sim.flight(case, "val", val)
    cascade_sim.airframe_guess(tmp_path / "guess.toml")     # K_T +30 %, b and Kd -30 %
    return est, val, truth


def _z(fitted, name, true):
    return (fitted.value(name) - true) / fitted.std[fitted.free_names.index(name)]


@pytest.mark.slow
def test_the_log_timing_judged_after_round_one_keeps_a_hub_drag_out_of_round_two(tmp_path):
    """Thrust per speed² scaled by the logged cell voltage (K_vbat 0.12), nothing else hidden.
    Against the baseline, far off without the battery, the ESC speeds' timing (samples of a
    signal varying between rows) is not significant; it used to be judged again only after
    the last round, and round 2 had screened without it: a hub rotor drag of 1 % of a real
    one was named (validation p -9 %, total -2 %) and Kd[0], Kd[1] sat 3.7 and 4.2 std off.
    Judged after round 1's verdict, the timing stands and round 2 finds nothing more."""
    est, val, truth = _case(tmp_path, "battery_voltage")
    model = QuadrotorModel(load_airframe(tmp_path / "guess.toml"))
    d = diagnose(model, load_log(est), validation=load_log(val), progress=False)
    assert d.verdict == "battery_voltage", [(c.effect, c.reason) for c in d.ranking[:3]]
    assert d.input_timing is not None and d.input_timing["judged_with"] == ["battery_voltage"], d.input_timing
    assert 0.4 < d.input_timing["s_lead"] < 0.65
    final = d.fitted_model
    assert set(final.model.effect_names) - set(model.effect_names) == {"battery_voltage", "sampled_inputs"}
    assert final.converged
    for name, true in truth["parameters"].items():
        assert abs(_z(final, name, true)) < 3, (name, final.value(name), true)


@pytest.mark.slow
def test_glitches_in_the_motion_capture_are_left_out_and_nothing_is_missing(tmp_path):
    """Twelve position samples 5-20 cm off (0.3 % of them) among 1 mm motion capture, with
    three outages: read as a missing force before (x, y, z 3.9x the noise, verdict "missing
    something no candidate explains"); `greybox diagnose` leaves them out and says so."""
    est, val, truth = _case(tmp_path, "c3")
    out = tmp_path / "d.json"
    assert main(["diagnose", str(est), "--airframe", str(tmp_path / "guess.toml"), "--validation", str(val),
                 "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["verdict"] is None and d["null_reason"] == "nothing_missing", (d["null_reason"], d["warnings"][:3])
    notes = " ".join(d["log_notes"]) if isinstance(d["log_notes"], list) else json.dumps(d["log_notes"])
    assert "glitch" in notes or "outlier" in notes, notes
    p = d["model"]["parameters"]
    for name, true in truth["parameters"].items():
        assert abs(p[name]["value"] - true) < 3 * p[name]["std"], (name, p[name], true)


@pytest.mark.slow
def test_a_payload_dropped_mid_flight_is_outside_the_catalogue(tmp_path):
    """The mass falls from 1.2 to 1.05 kg at 20 s: a thrust per rotor speed that rises is no
    battery sag (thrust_drift's K_T_drift > 2 std above 0 is implausible), nor a thrust curve
    or a moment gain; the verdict is null, outside the catalogue, with a force growing in t."""
    est, val, _ = _case(tmp_path, "payload_drop")
    model = QuadrotorModel(load_airframe(tmp_path / "guess.toml"))
    d = diagnose(model, load_log(est), validation=load_log(val), progress=False)
    assert d.verdict is None and d.null_reason == "outside_catalogue", (d.null_reason, d.warnings[:3])
    assert "thrust_drift" not in d.fitted_model.model.effect_names
    assert np.isfinite(d.baseline_prediction.total)

"""A fortieth blind audit, of graded effect sizes (``tests/audit40_sim.py``: a 2.0 kg "x"
quadrotor on 11-inch props, RK4 at 1 ms under its own 500 Hz cascade 5-8 % off, 30-ms motors,
ESC telemetry of the actual speeds with 3 rad/s of noise in 2-rad/s steps, mocap 125 Hz,
attitude and gyro at 250 Hz; rotor 3 weaker by 0.1-10 %, or the CoG 0.1-10 mm off). Its files
byte for byte.

Right: the control null; every size from 0.4 % and 0.2 mm named, its parameters within 2.2
std. Wrong: the CoG 0.1 mm off named as a rotor 0.09 % weak on two of four seed pairs. The
offset had been refused as below 1 % of a plausible offset (0.135 mm), the rotor gains in its
pattern, whose yardstick (0.08 %) stands for a third of that moment, were not; with both
judged by one moment, the offset, refused for a moment of 1.9 % of the flight's, took the
gains' verdict with it."""
import hashlib
import json
import re
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from greybox import QuadrotorModel, effects
from greybox.airframe import airframe_from_dict
from greybox.cli import main
from greybox.diagnosis.ranking import small_partner_words
from greybox.diagnosis.results import CandidateResult

import audit40_sim as sim


def _simulate(out: Path, cases: str, pairs: str) -> Path:
    """The audit's flights of ``cases`` for the seed pairs ``pairs`` ("3:4") and its airframe
    written to ``out`` (its ``main`` reads them from the command line)."""
    argv = sys.argv
    try:
        sys.argv = ["audit40_sim.py", str(out), cases, pairs]
        sim.main()
    finally:
        sys.argv = argv
    return out


@pytest.fixture(scope="module")
def cog_flights(tmp_path_factory) -> Path:
    """The 0.1-mm CoG offset's flights of seeds 3 and 4 (about 10 s to simulate)."""
    return _simulate(tmp_path_factory.mktemp("audit40"), "cog_0p1", "3:4")


def test_the_flights_are_the_audits(cog_flights):
    digest = hashlib.sha256((cog_flights / "cog_0p1_est_s3.csv").read_bytes()).hexdigest()
    assert digest[:16] == "798350efcb30cb54", digest


def _candidates(cog_small: bool, cog_nrmse: float):
    """A weak-rotor candidate whose gains are a CoG offset's pattern on the audit's airframe
    (d_i = -k x_i: rotors 1 and 3 in front 0.1 % down, 2 and 4 behind up) and a CoG-offset
    candidate refused for its size (or not), both refits certified."""
    airframe = airframe_from_dict({"airframe": {"mass": 2.0, "inertia": [0.028, 0.028, 0.05],
                                                "arm_length": 0.225, "layout": "x"},
                                   "parameters": {"K_T": 1.8e-5, "b": 2.9e-7}})
    model = QuadrotorModel(airframe) + effects.by_name("motor_asymmetry")
    p = model.parameter_vector({"K_T_dev": [-1e-3, 1e-3, -1e-3]})
    free = ["K_T", "b", "K_T_dev[0]", "K_T_dev[1]", "K_T_dev[2]"]
    fit = SimpleNamespace(model=model, p=p, free_names=free, converged=True,
                          covariance=np.diag([1e-20, 1e-20, 1e-8, 1e-8, 1e-8]))
    top = CandidateResult("motor_asymmetry", 3, 300.0, lr=270.0, significant=True, nrmse_before=0.102,
                          nrmse_after=0.0700, fit=fit)
    cog = CandidateResult("cog_offset", 2, 280.0, lr=250.0, nrmse_before=0.102, nrmse_after=cog_nrmse,
                          small_force=cog_small, fit=SimpleNamespace(converged=True))
    return top, cog


def test_a_verdict_that_is_a_partners_physics_refused_for_its_size_is_refused_too():
    """The rotor gains are the offset's pattern and the offset, refused for its size, predicts
    the validation as well: the gains cannot be named for the same moment. Not where the offset
    was not refused for its size, or predicts worse by more than 5 %."""
    top, cog = _candidates(cog_small=True, cog_nrmse=0.0702)
    words = small_partner_words(top, [top, cog])
    assert "pattern of a CoG offset" in words and "what cog_offset gives" in words and "cannot tell" in words, words
    assert small_partner_words(top, [top, _candidates(cog_small=False, cog_nrmse=0.0702)[1]]) == ""
    assert small_partner_words(top, [top, _candidates(cog_small=True, cog_nrmse=0.0760)[1]]) == ""


@pytest.mark.slow
def test_a_cog_offset_too_small_to_name_is_not_named_as_a_weak_rotor(cog_flights, tmp_path, capsys):
    """Seeds 3/4, the CoG 0.1 mm off: the verdict was motor_asymmetry (rotor 3 -0.09 %, rotor 4
    +0.10 %), the offset refused as physically negligible beside it. Now null: the offset is
    named as cutting the validation error though too small against the flight to be named, and
    the rotor gains are refused as its pattern."""
    out = tmp_path / "d.json"
    assert main(["diagnose", str(cog_flights / "cog_0p1_est_s3.csv"), "--validation",
                 str(cog_flights / "cog_0p1_val_s4.csv"), "--airframe", str(cog_flights / "airframe.toml"),
                 "--json", str(out), "--quiet"]) == 0
    capsys.readouterr()
    r = json.loads(out.read_text())
    assert r["verdict"] in (None, "cog_offset"), r["verdict"]
    if r["verdict"] is None:
        assert r["small_but_moving"] == ["cog_offset"], r["small_but_moving"]
        asym = next(c for c in r["ranking"] if c["effect"] == "motor_asymmetry")
        assert "what cog_offset gives" in asym["reason"], asym["reason"]


@pytest.mark.slow
def test_a_drag_the_logs_timing_moves_beyond_its_std_is_said_with_both_values(tmp_path_factory, capsys):
    """The CoG 2 mm off (seeds 1/2): named, its offset within 2.1 std; the log's timing,
    significant in the fit against the model with it (p = 1.5e-186), predicted the validation
    flight worse and was left out, and the final model's Kd[2] (truth 0.35) was 0.3729 ± 0.0057,
    4 std high, with nothing said. The timing free moves it to 0.359: said, with both values."""
    flights = _simulate(tmp_path_factory.mktemp("audit40_cog2"), "cog_2", "1:2")
    out = flights / "d.json"
    assert main(["diagnose", str(flights / "cog_2_est_s1.csv"), "--validation", str(flights / "cog_2_val_s2.csv"),
                 "--airframe", str(flights / "airframe.toml"), "--json", str(out), "--quiet"]) == 0
    capsys.readouterr()
    r = json.loads(out.read_text())
    assert r["verdict"] == "cog_offset"
    said = [w for w in r["warnings"] if w.startswith("Kd[2] ") and "as held" in w]
    assert len(said) == 1, r["warnings"]
    held, free = (float(v) for v in re.findall(r"Kd\[2\] ([\d.]+) ± [\d.e-]+ as held, ([\d.]+) with", said[0])[0])
    # the truth lies beyond the held value's std, and the timing free moves it toward the truth
    assert held - 0.35 > 3 * 0.0057 and abs(free - 0.35) < abs(held - 0.35), (held, free)


def test_fit_says_the_rows_timing_where_the_previous_row_explains_nothing(tmp_path_factory, capsys):
    """The control flight (nothing hidden; ESC telemetry of the actual speeds, smoothed by the
    command line): `greybox fit` left Kd[2] 3.4 std high and said nothing of the log's timing,
    which the diagnosis finds at p ~ 1e-190 (s_lead 0.525 ± 0.022). The blend toward the next
    row scores 870-1193, toward the previous row nothing: no noise to average, so the timing is
    said, although the central difference of what the smoother left is not significant."""
    flights = _simulate(tmp_path_factory.mktemp("audit40_control"), "control", "1:2")
    assert main(["fit", str(flights / "control_est_s1.csv"), "--airframe", str(flights / "airframe.toml"),
                 "--quiet"]) == 0
    captured = capsys.readouterr()
    said = [ln for ln in (captured.out + captured.err).splitlines() if "samples of a signal" in ln]
    assert len(said) == 1 and "toward the previous row: nothing" in said[0] and "sampled_inputs" in said[0], said

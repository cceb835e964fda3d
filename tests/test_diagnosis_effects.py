"""The diagnosis on every catalogue effect (slow: two synthetic flights and one diagnosis
per effect, 5-60 s each). The same cases as ``experiments/diagnose_effects.py``: the
diagnosis estimates on one flight and validates on another of the same manoeuvres.

Targets (issue 4): the hidden effect is ranked first and is the verdict and, once added,
the validation nrmse of the channels it affects falls by >= 30 %; with nothing hidden the
verdict is null.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from greybox import QuadrotorModel, load_airframe

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("diagnose_effects", ROOT / "experiments" / "diagnose_effects.py")
sweep = importlib.util.module_from_spec(spec)
spec.loader.exec_module(sweep)


@pytest.fixture(scope="module")
def base():
    return QuadrotorModel(load_airframe(ROOT / "greybox" / "data" / "airframes" / "paper.toml"))


@pytest.mark.slow
@pytest.mark.parametrize("hidden", ["yaw_torque", "linear_drag", "gyroscopic", "quadratic_drag", "rotor_drag",
                                    "ground_effect", "motor_lag", "moment_gain", "thrust_curve", "cog_offset", "motor_asymmetry", "wind",
                                    "thrust_drift", "position_delay", "position_offset", "attitude_bias", "gyro_scale"])
def test_hidden_effect_ranked_first_and_error_falls(base, hidden):
    r = sweep.case(base, hidden, duration=30.0, seed=3, rate=200.0)
    assert r["first"] == hidden and r["verdict"] == hidden
    assert r["fall_pct"] >= 30.0, r


@pytest.mark.slow
def test_nothing_hidden_gives_a_null_verdict(base):
    r = sweep.case(base, None, duration=30.0, seed=3, rate=200.0)
    assert r["verdict"] is None, r


sys.modules["diagnose_effects"] = sweep     # diagnose_foreign imports its sibling
spec_f = importlib.util.spec_from_file_location("diagnose_foreign", ROOT / "experiments" / "diagnose_foreign.py")
foreign = importlib.util.module_from_spec(spec_f)
spec_f.loader.exec_module(foreign)


EXP_GROUND_NO_MOMENT = pytest.mark.xfail(strict=True, reason=(
    "exp_ground scales the total thrust by the CoG's height, with no moment; the catalogue's "
    "ground_effect is per rotor (a tilted vehicle's lower rotors gain more, as the independent "
    "simulator's per-rotor ground effect does), and on this flight's tilted low pass the two "
    "disagree: first motor_asymmetry, verdict null (2026-11-24)"))


@pytest.mark.slow
@pytest.mark.parametrize("hidden", [pytest.param(h, marks=EXP_GROUND_NO_MOMENT) if h == "exp_ground" else h
                                    for h in sorted(foreign.CASES)])
def test_effects_of_other_forms_are_named_by_their_closest_catalogue_effect(base, hidden):
    """Hidden effects written outside the package, in other functional forms (exponential
    ground effect, gusty wind, exponential battery sag, cubic drag)."""
    r = foreign.case(base, hidden, duration=30.0, seed=3, rate=200.0)
    assert r["verdict"] == r["expected"], r
    assert r["fall_pct"] >= 30.0, r

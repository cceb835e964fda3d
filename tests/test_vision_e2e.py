"""experiments/vision_sysid.py end to end on a short flight (slow: renders ~400 frames and
fits twice)."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_vision_sysid_short_flight(tmp_path):
    spec = importlib.util.spec_from_file_location("vision_sysid", ROOT / "experiments" / "vision_sysid.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--duration", "14", "--fps", "30", "--out", str(tmp_path)]) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    v = s["vision"]
    assert v["positions"] > 0.9 * v["frames"]
    for ax in "xyz":
        assert v["position_error"][ax]["rmse_mm"] < 10.0
    for name, row in s["parameters"].items():
        assert abs(row["vision"]["value"] / row["truth"] - 1) < 0.05, name
    assert abs(s["parameters"]["K_T"]["vision"]["value"] / s["parameters"]["K_T"]["truth"] - 1) < 0.005
    assert s["closed_loop_max_gap_to_true_model_m"]["vision"] < 0.05
    for f in ("vision_positions.png", "parameters.png", "closed_loop.png", "rig.toml", "summary.md"):
        assert (tmp_path / f).exists()

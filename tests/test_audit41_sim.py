"""A forty-first blind audit, of fits from starts 30-50 % off on three scales, three log rates
and four sensor mixes (``tests/audit41_sim.py``: 30 g, 1 kg "plus" and 3 kg vehicles, RK4 under
its own geometric controller 6-9 % off, rotor speeds constant over each row so the base model is
exact; mocap 100 Hz, attitude, gyro and accelerometer at the rows' rate, ESC telemetry with
noise in some mixes). Its files byte for byte.

Right: with clean speeds every start of every log reached the same values within 0.005 std,
within 2.1 std of the truth, certified. Wrong: with noisy ESC speeds the fit could not follow
the data in output error and turned to process noise, which starts at the shooting gaps of its
start and comes down in rounds: from starts 35-40 % off vz's process noise ended 640-1750 times
higher than from the truth, and K_T 3-23.5 std apart, each "optimum certified" (not mended: the
test of it is an expected failure)."""
import hashlib
import json
import sys
from pathlib import Path

import pytest

from greybox.cli import main

import audit41_sim as sim


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> Path:
    """The 1 kg vehicle's 500-Hz log of mix D (position, attitude, gyro, accelerometer, ESC
    speeds with 4 rad/s of noise) and its validation flight, and the airframes of every start
    (about 25 s to simulate)."""
    out = tmp_path_factory.mktemp("audit41")
    argv = sys.argv
    try:
        sys.argv = ["audit41_sim.py", str(out), "q1kg_D500"]
        sim.main()
    finally:
        sys.argv = argv
    return out


def test_the_flights_are_the_audits(flights):
    digest = hashlib.sha256((flights / "q1kg_D500.csv").read_bytes()).hexdigest()
    assert digest[:16] == "b8dadece0265fb98", digest


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="a soft fit's process noise depends on its start (issue 13, item 1)")
def test_a_fit_with_process_noise_reaches_one_optimum_from_starts_far_apart(flights, tmp_path, capsys):
    """From the truth and from K_T 40 % high with b 40 % low: K_T comes out 3.0 std apart and b
    2.1 (vz's process noise 2.7e-5 against 0.017), each "optimum certified". Solved once more
    from its own end point, the far start's fit lands on the near start's values (K_T equal to
    ten digits); made the rule for every soft fit that ends 3 std from its start, it moved two
    real Crazyflie flights' fits elsewhere (one K_T to 0.57 of the reference), and was not kept.
    Strict: this test says when the fit reaches one optimum from both."""
    fitted = {}
    for start in ("truth", "s1"):
        out = tmp_path / f"{start}.json"
        assert main(["fit", str(flights / "q1kg_D500.csv"), "--airframe", str(flights / f"q1kg_{start}.toml"),
                     "--json", str(out), "--quiet"]) == 0
        fitted[start] = json.loads(out.read_text())
    capsys.readouterr()
    near, far = fitted["truth"], fitted["s1"]
    assert near["process_noise"] is not None and far["certificate"]["optimal"]
    for name in ("K_T", "b", "Kd[0]", "Kd[1]", "Kd[2]"):
        a, b = near["parameters"][name], far["parameters"][name]
        assert abs(a["value"] - b["value"]) < 0.01 * a["std"], (name, a, b)
    assert far["process_noise"]["vz"] == pytest.approx(near["process_noise"]["vz"], rel=0.01)

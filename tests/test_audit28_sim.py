"""A twenty-eighth blind audit's 1.1 kg "x" quadrotor (``tests/audit28_sim.py``: 9-inch props,
quaternion RK4 at 1 ms under its own 250 Hz SO(3) PD and 50 Hz velocity loops with a mixer
5-10 % off, 5 rad/s of noise on the logged speeds, motion capture at 120 Hz, IMU at 250 Hz):
what it found wrong, on its own control flights."""
import hashlib
import re
from pathlib import Path

import numpy as np
import pytest

from greybox.cli import main

import audit28_sim as sim

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> Path:
    """The control case's three flights and the audit's airframe files (af_off: K_T +40 %,
    b -40 %, drag half; af_off_inertia: the same with the inertia 1.35 times; af_mass25: the
    truth with the mass 1.25 times)."""
    out = tmp_path_factory.mktemp("audit28")
    sim.main(["A"], out=str(out))
    return out


def test_the_flights_are_reproducible(flights):
    """The simulator regenerates the same file, so the tests below judge the same flight.
    (The digest recorded when the audit was vendored, 566a8357…, has not been reproduced
    since, by this code under numpy 2.4.6 in any thread count; the flights' row counts and
    truth are the audit's. This pins the file as generated on 2026-12-07.)"""
    digest = hashlib.sha256((flights / "A_est1.csv").read_bytes()).hexdigest()
    assert digest[:16] == "922ccf233cb94bed", digest


def _fit_words(flights, airframe, capsys):
    assert main(["fit", str(flights / "A_est1.csv"), str(flights / "A_est2.csv"),
                 "--airframe", str(flights / airframe), "--quiet"]) == 0
    return capsys.readouterr().out


def test_an_inertia_too_large_is_said_by_a_plain_fit(flights, capsys):
    """The inertia given 1.35 times the vehicle's: b came out 35 % high (1150 std), certified,
    nothing said. The fit now says the roll and pitch turn about 1.35 times as much as the
    airframe gives, with the inertia that makes it 1 (within 5 % of 0.0125 kg m^2) and b off
    with Jz."""
    out = _fit_words(flights, "af_off_inertia.toml", capsys)
    said = [ln for ln in out.splitlines() if "times as much per rotor-speed difference" in ln]
    assert len(said) == 1, out
    assert float(re.search(r"k_M ≈ ([0-9.]+)", said[0]).group(1)) == pytest.approx(1.35, rel=0.05), said
    assert float(re.search(r"Jx, Jy = ([0-9.e-]+),", said[0]).group(1)) == pytest.approx(0.0125, rel=0.05), said
    assert "b, which the yaw data give relative to the Jz given" in said[0]


def test_a_mass_too_large_is_said_by_a_plain_fit(flights, capsys):
    """The mass given 1.25 times the vehicle's: K_T and Kd 25 % high, certified, nothing said
    but p and q above the noise. Now the mass that makes the moments match, within 3 % of
    1.1 kg."""
    out = _fit_words(flights, "af_mass25.toml", capsys)
    said = [ln for ln in out.splitlines() if "the airframe's mass is off" in ln]
    assert len(said) == 1, out
    assert float(re.search(r"and with ([0-9.e-]+) kg", said[0]).group(1)) == pytest.approx(1.1, rel=0.03), said


def test_the_control_flights_fit_says_nothing_of_the_moments_or_the_rows_timing(flights, capsys):
    """Nothing of the moments; nor of the rows' timing, on speeds held for each row with 5 rad/s
    of noise on them (the central difference alone scored 6.98 here, p = 0.008, where the
    previous row scores 1.8e5 against the next row's 3.9e4: both tests are asked)."""
    out = _fit_words(flights, "af_off.toml", capsys)
    assert "times as much per rotor-speed difference" not in out, out
    assert "samples of a signal" not in out, out


def test_the_control_flights_accelerometer_is_at_what_the_noises_give(flights, tmp_path, capsys):
    """The exact model's az residuals came out 1.51 times the accelerometer's noise, a third of
    their lags outside the band (the smoothed speeds of the figure-eight keep their noise where
    the thrust's own signal stands above it), and the certificate said the model does not
    explain az. 5 rad/s on speeds of about 590 rad/s put 2 K_T w 5 sqrt(4) / m = 0.084 m/s²
    on the thrust as logged (the smoother leaves some of it): the certificate now counts it
    and the fit is adequate, az said to be within it."""
    import json
    out = tmp_path / "fit.json"
    assert main(["fit", str(flights / "A_est1.csv"), str(flights / "A_est2.csv"),
                 "--airframe", str(flights / "af_off.toml"), "--quiet", "--json", str(out)]) == 0
    capsys.readouterr()
    cert = json.loads(out.read_text())["certificate"]
    assert cert["optimal"] and cert["adequate"], cert["text"]
    assert cert["residual_over_noise"]["az"] > 1.4                 # above the sensor's noise alone
    assert 0.03 < cert["input_noise"]["az"] < 0.09, cert["input_noise"]
    assert "az at" in cert["text"] and "within what the logged inputs' noise adds" in cert["text"]


def test_roll_and_pitch_swapped_are_refused(flights, tmp_path, capsys):
    """phi and theta swapped, with p and q: fitted, certified, and the advice was a rotor order
    ("w1 as rotor 2, w2 as rotor 1"). The flight turns its heading, so the tilt's reading with
    roll and pitch swapped tells it from a mirrored world: refused, naming the columns."""
    lines = (flights / "A_est1.csv").read_text().splitlines()
    head = lines[0].split(",")
    swap = {"phi": "theta", "theta": "phi", "p": "q", "q": "p"}
    (tmp_path / "swapped.csv").write_text("\n".join([",".join(swap.get(c, c) for c in head)] + lines[1:]) + "\n")
    assert main(["fit", str(tmp_path / "swapped.csv"), "--airframe", str(flights / "af_true.toml"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "phi and theta swapped" in err and "columns 'phi', 'theta'" in err, err

"""A twenty-sixth blind audit's 1.8 kg hexacopter (``tests/audit26_sim.py``: six ``[[rotor]]``
tables, RK4 at 1 ms under its own 200 Hz geometric controller, four short flights per case at
battery charges of 4.15-3.68 V per cell with ``vbat`` logged, 200 Hz rows, motion capture at
100 Hz): what it found wrong, checked on its own flights (byte for byte the audit's files)."""
import json
from pathlib import Path

import pytest

from greybox.cli import main

import audit26_sim as sim

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> Path:
    """Every case's flights and the user's airframe (K_T +30 %, b -30 %), as the audit made them."""
    out = tmp_path_factory.mktemp("audit26")
    sim.OUT = str(out)
    sim.main()
    return out


def _est(flights: Path, case: str) -> list[str]:
    return [str(flights / case / f"f{k}.csv") for k in range(1, 5)]


def test_two_neighbouring_rotor_columns_swapped_are_named(flights, capsys):
    """Case D: the control flights with columns w2 and w3 swapped. The diagnosis ended
    "uncertified" with words on the thrust and the speeds' unit; the fit now names the order."""
    rc = main(["fit", *_est(flights, "D"), "--airframe", str(flights / "hexa.toml"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and ("the logged rotor speeds act as the airframe's rotors in another order: w1 as rotor 1, "
                        "w2 as rotor 3, w3 as rotor 2, w4 as rotor 4, w5 as rotor 5, w6 as rotor 6") in err, err


def test_a_battery_voltage_in_millivolts_is_refused(flights, capsys):
    """One flight's vbat in mV was fitted by battery_voltage with K_vbat -5e-6 (truth 0.2),
    certified, exit 0."""
    rc = main(["fit", str(flights / "B" / "f1.csv"), str(flights / "bad" / "f2_vbat_mV.csv"),
               "--airframe", str(flights / "hexa.toml"), "--effects", "battery_voltage", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "f2_vbat_mV.csv: column 'vbat' (read by battery_voltage)" in err \
        and "is it in millivolts? V = mV / 1000" in err, err


def test_the_battery_is_named_across_flights_of_different_charge(flights, tmp_path):
    """Case B, what the audit found right and is kept: four flights at 4.15-3.68 V per cell,
    the thrust following the voltage; the diagnosis names battery_voltage and K_vbat comes back
    within 3 std of 0.2."""
    out = tmp_path / "b.json"
    assert main(["diagnose", *_est(flights, "B"), "--airframe", str(flights / "hexa.toml"),
                 "--validation", str(flights / "B" / "val.csv"), "--quiet", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["verdict"] == "battery_voltage", (doc["verdict"], doc["null_reason"])
    k = doc["model"]["parameters"]["K_vbat"]
    assert abs(k["value"] - sim.K_VBAT) < 3 * k["std"], k


def test_noise_on_held_speeds_is_not_said_to_be_the_rows_timing(flights, capsys):
    """Case A, nothing missing: commands held for each 5-ms row, logged with 3 rad/s of white
    noise. The fit said the rows "look like samples of a signal that varies between the log's
    rows" (score 975); the same blend toward the previous row scores 1682: it was the noise."""
    rc = main(["fit", *_est(flights, "A"), "--airframe", str(flights / "hexa.toml"), "--quiet"])
    out = capsys.readouterr()
    assert rc == 0 and "optimum certified" in out.out, out.err
    assert "samples of a signal" not in out.out + out.err

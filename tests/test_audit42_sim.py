"""A forty-second blind audit, of logs without position (``tests/audit42_sim.py``: a 30 g,
1 kg and 3 kg "x" quadrotor at 500, 250 and 200 Hz, RK4 under its own geometric controller
6-10 % off; gyro and accelerometer with noise and biases, the attitude from its own Mahony
filter; the same flights with 100 Hz motion capture). Its files byte for byte.

Right: the motor lag within 0.2 std on all three, a weak rotor NOT ADEQUATE on all three,
drag said not identified; with motion capture every diagnosis right. Wrong, and mended: a
battery that takes 7.5 % of the thrust over the flight was "adequate" with one K_T on all
three vehicles (the thrust equation's validation error 4-15 times the control's); the
accelerometer's z bias (0.05-0.08 m/s^2) put K_T 0.4-1 % off at 6-34 of its std with a word on
one vehicle of three; and the fit's JSON held no certificate."""
import hashlib
from pathlib import Path

import numpy as np
import pytest

from greybox import QuadrotorModel, load_airframe, load_log
from greybox.fitting.imu import fit_imu

import audit42_sim as sim

VEHICLES = ("cf", "q1kg", "h3kg")


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> Path:
    """The control and battery-sag estimation flights of the three vehicles, IMU-only and with
    motion capture, and their airframes (about a minute to simulate)."""
    out = tmp_path_factory.mktemp("audit42")
    sim.main(str(out), [f"{v}_{case}_est" for v in VEHICLES for case in ("control", "battery_sag")])
    return out


def _fit(flights: Path, vehicle: str, case: str):
    model = QuadrotorModel(load_airframe(flights / f"{vehicle}.toml"))
    return fit_imu(model, load_log(flights / f"{vehicle}_{case}_est_imu.csv"))


@pytest.mark.slow
def test_the_simulator_is_the_audits(flights):
    """Its files byte for byte (sha256 of the audit's own)."""
    def digest(name):
        return hashlib.sha256((flights / name).read_bytes()).hexdigest()
    assert digest("cf_battery_sag_est_imu.csv") == "021e9f93e8c56bdfe08075c04bc7309b4837c26a7c59dea72c0a306d7b907f61"
    assert digest("cf.toml") == "503ea35acfbd6165f8d56eeddf48002f9cd929f05a8b9c2d1ad671df4fabba80"
    assert digest("h3kg_control_est_imu.csv") == "0bcb0813b829b893706e2bd2d7f12424b6cb2f0b1af588d0809257405a30f86b"


@pytest.mark.slow
@pytest.mark.parametrize("vehicle", VEHICLES)
def test_a_battery_that_sags_is_not_adequate_and_the_control_is(flights, vehicle):
    """K_T falls 0.3 % per second (7.5 % over the 25-s flight, 6 % over the fitted 20 s): the
    thrust equation refitted with K_T linear in time reads it (-5.8 to -6.1 %), and the fit is
    NOT ADEQUATE and says so; the control flight's change is within the 2 % its missing drag
    and bias give (up to 1.1 %), adequate. Both certified. On the control K_T's words say that the
    accelerometer's z bias goes into it beyond its std (0.05 m/s^2 is 0.5 %, 8-17 of its std
    here; the audit's biases put the controls' K_T 0.4-1 % off; the 3 kg sag flight's wider std,
    0.19 %, leaves it within 3 of them, and nothing is said)."""
    sag, control = _fit(flights, vehicle, "battery_sag"), _fit(flights, vehicle, "control")
    assert -0.07 < sag.thrust_change[0] < -0.05 and sag.thrust_changes, sag.thrust_change
    assert sag.adequate is False
    assert any("the thrust per w^2 changes over the flight" in n for n in sag.notes), sag.notes
    assert not control.thrust_changes and abs(control.thrust_change[0]) < 0.015, control.thrust_change
    assert control.adequate is True
    for res in (sag, control):
        assert res.converged and res.as_dict()["certificate"]["optimal"] is True
    assert any(n.startswith("K_T's std") and "accelerometer along z goes into K_T" in n for n in control.notes), \
        control.notes


@pytest.mark.slow
def test_the_yaw_coefficients_std_is_not_many_times_too_wide(flights):
    """b's std came from the residuals' long-run factor alone, as if every regressor were as
    slow as the residual's colour: over the audit's twelve flights without a weak rotor b's
    z-scores had an RMS of 0.11 (its std 9x too wide); the sandwich of the residuals with their
    own regressors gives 0.41. On these six flights: RMS 0.13 before, 0.48 now, none beyond
    3 std."""
    truth = {"cf": 1.1e-10, "q1kg": 1.9e-7, "h3kg": 1.0e-6}
    z = [(res.value("b") - truth[v]) / res.parameters["b"][1]
         for v in VEHICLES for res in (_fit(flights, v, "control"), _fit(flights, v, "battery_sag"))]
    assert max(abs(x) for x in z) < 3 and 0.25 < float(np.sqrt(np.mean(np.square(z)))) < 1.5, z

"""A twenty-third blind audit's 2.2 kg "+" quadrotor (``tests/audit23_sim.py``: scipy's RK45
between the ticks of its own 400 Hz geometric controller, 40-ms RPM-controlled motors, 100 Hz
rows, motion capture at 50 Hz with dropouts, the battery differing between flights): what it
found wrong, checked on its own flights (byte for byte the audit's files)."""
from pathlib import Path

import pytest

from greybox import QuadrotorModel, diagnose, load_airframe, load_log
from greybox.cli import main

import audit23_sim as sim

pytestmark = pytest.mark.slow


def _flights(case: str, names, out: Path, monkeypatch) -> tuple[Path, list[Path]]:
    """The audit's airframe file (its user's guesses: K_T +30 %, b -40 %, drag off) and the
    named flights of ``case``, flown with the audit's seeds."""
    monkeypatch.setattr(sim, "OUT", str(out))
    sim.write_airframes()
    paths = []
    for name, kind, v0, offset in sim.FLIGHTS:
        if name in names:
            rows, rng = sim.fly(case, kind, v0, 1000 * (ord(case) - 64) + offset)
            paths.append(out / f"{case}_{name}.csv")
            sim.write_log(str(paths[-1]), case, rows, rng)
    return out / "guess.toml", paths


def test_a_lag_fitted_to_sampled_commands_is_said(tmp_path, monkeypatch, capsys):
    """Case B: the 400 Hz commands sampled at the 100 Hz rows, 40-ms motors. ``greybox fit
    --effects motor_lag`` gave tau_m 36.75 ± 0.085 ms (38 std off), certified and silent; now
    it says the rows look like samples of a varying signal and that tau_m takes the difference."""
    guess, (path,) = _flights("B", ["f2_circle"], tmp_path, monkeypatch)
    assert main(["fit", str(path), "--airframe", str(guess), "--effects", "motor_lag", "--quiet"]) == 0
    said = [ln for ln in capsys.readouterr().out.splitlines() if "samples of a signal" in ln]
    assert len(said) == 1 and "the fitted tau_m takes the difference" in said[0], said


def test_a_torque_outside_the_catalogue_is_not_called_turbulence_alone(tmp_path, monkeypatch):
    """Case D, its validation flight alone: a yaw torque from the rotors' accelerations
    (J_r sum(spin_i dw_i/dt)), outside the catalogue. The null was "a random torque
    (turbulence)"; now it says the data cannot tell a turbulence from a torque that follows
    something the log does not show, with the baseline's systematic gaps of r."""
    guess, (path,) = _flights("D", ["f4_mixed_val"], tmp_path, monkeypatch)
    d = diagnose(QuadrotorModel(load_airframe(guess)), load_log(path))
    assert d.verdict is None and d.null_reason == "random_torque", d.verdict_text()
    text = d.verdict_text()
    assert "a turbulence, or a torque that follows something the log does not show" in text, text
    assert "the baseline's shooting gaps of r" in text, text


def test_the_control_flights_together_give_null(tmp_path, monkeypatch):
    """Case A (nothing beyond the base model; the battery differs between flights, vbat logged
    while the truth's K_vbat is 0): three flights with the fourth for validation: null, and
    K_T and b within 1 % of the truth from the user's guesses 30 % and 40 % off."""
    guess, paths = _flights("A", [f for f, *_ in sim.FLIGHTS], tmp_path, monkeypatch)
    est = [load_log(p) for p in paths if "val" not in p.name]
    val = [load_log(p) for p in paths if "val" in p.name]
    d = diagnose(QuadrotorModel(load_airframe(guess)), est, validation=val)
    assert d.verdict is None and d.baseline_certified, d.verdict_text()
    fr = d.final_fit or d.baseline
    assert fr.value("K_T") == pytest.approx(sim.K_T, rel=0.01)
    assert fr.value("b") == pytest.approx(sim.B_YAW, rel=0.01)

"""Real Crazyflie flights (NanoBench): import, frames, units, errors, and a fit whose hover
thrust must carry the weight; plus the battery_voltage and rotor_map effects and the
process-noise fit on synthetic data where the truth is known."""
from pathlib import Path

import numpy as np
import pytest

from greybox import QuadrotorModel, diagnose, effects, load_airframe
from greybox.airframe import airframe_from_dict
from greybox.cli import main
from greybox.data import FlightLog, load_log
from greybox.errors import GreyboxInputError
from greybox.fitting import fit
from greybox.importers import crazyflie_airframe_toml, import_nanobench, pwm_to_rotor_speed
from greybox.synth import SensorSpec, synthesize

from conftest import AIRFRAMES

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "nanobench"
FILES = sorted(REAL.glob("*.csv")) if REAL.is_dir() else []
BUNDLED = Path(__file__).resolve().parent / "data" / "nanobench_B2_slice.csv"
needs_real = pytest.mark.skipif(not FILES, reason="../shared/realdata not present")


def _quat_matrix(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _euler_matrix(phi, th, psi):
    c, s = np.cos, np.sin
    Rz = np.array([[c(psi), -s(psi), 0], [s(psi), c(psi), 0], [0, 0, 1]])
    Ry = np.array([[c(th), 0, s(th)], [0, 1, 0], [-s(th), 0, c(th)]])
    Rx = np.array([[1, 0, 0], [0, c(phi), -s(phi)], [0, s(phi), c(phi)]])
    return Rz @ Ry @ Rx


def test_bundled_slice_is_a_verbatim_nanobench_excerpt():
    # the slice keeps CI honest when ../shared is absent: it is real data, not generated
    imp = import_nanobench(BUNDLED)
    assert imp.log.duration > 8.0 and imp.rest_height == pytest.approx(0.055, abs=0.005)


@pytest.mark.parametrize("path", [BUNDLED] + FILES, ids=lambda p: p.stem)
def test_import_frames_units_and_trimming(path):
    imp = import_nanobench(path)
    log = imp.log
    assert log.input_names == ["w1", "w2", "w3", "w4"]
    assert log.output_names == ["x", "y", "z", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az"]
    assert log.t[0] == 0.0 and np.all(np.diff(log.t) > 0)
    # airborne: NED z negative (above the floor), hover specific force along body -z ~ g
    assert np.nanmax(log.output("z")) < 0
    assert np.nanmean(log.output("az")) == pytest.approx(-9.81, rel=0.03)
    assert log.extras["on_ground"].sum() <= 10
    assert 3.0 < log.extras["vbat"].min() and log.extras["vbat"].max() < 4.3
    # rotor speeds of a hovering Crazyflie: a couple of thousand rad/s
    assert 2000 < imp.hover_rotor_speed < 3200
    # attitude: our R(phi, theta, psi) is Rx(pi) R_quaternion Rx(pi) (z-up/FLU -> NED/FRD)
    raw = np.genfromtxt(path, delimiter=",", names=True)
    k0 = int(np.searchsorted(raw["t"], log.extras["t_unix"][0]))
    F = np.diag([1.0, -1.0, -1.0])
    for j in (100, 400, 700):
        q = [raw[n][k0 + j] for n in ("qx", "qy", "qz", "qw")]
        R_ned = F @ _quat_matrix(q / np.linalg.norm(q)) @ F
        phi, th, psi = log.outputs[j, 3:6]
        np.testing.assert_allclose(_euler_matrix(phi, th, psi), R_ned, atol=1e-9)
    # gyro in FRD: body rates agree with the Euler-angle rates (small angles). Both smoothed
    # over 0.15 s: a flight that hardly pitches (B6, a linear ramp) leaves the raw derivative
    # mostly noise (r = 0.25); the slope tells the unit too (deg vs rad would give 57 or 0.017)
    box = np.ones(15) / 15
    seen = np.isfinite(log.output("phi")) & np.isfinite(log.output("p"))    # not the rows filling a dropout
    for ch, ang in (("p", "phi"), ("q", "theta"), ("r", "psi")):
        rate = np.convolve(np.gradient(np.unwrap(log.output(ang)[seen]), log.t[seen]), box, "same")
        gyro = np.convolve(log.output(ch)[seen], box, "same")
        assert np.corrcoef(rate, gyro)[0, 1] > 0.5, ch              # a sign error gives < 0
        assert 0.5 < np.polyfit(gyro, rate, 1)[0] < 2.0, ch
    # position: x stays, y and z flip
    np.testing.assert_allclose(log.output("y")[:50], -raw["py"][k0:k0 + 50], atol=1e-12)
    np.testing.assert_allclose(log.output("z")[:50], -raw["pz"][k0:k0 + 50], atol=1e-12)
    # the controller's setpoint, where logged, in the same NED world: the vehicle follows it
    # (0.5-0.8 s behind on these flights) about the same mean, moving with it (a sign error
    # in y or z would anticorrelate them); the yaw target in rad, not degrees
    if "sp_ctrltarget_x" in raw.dtype.names:
        for ch in ("x", "y", "z"):
            y, ref = log.output(ch), log.extras[f"{ch}_ref"]
            k = np.isfinite(y)
            assert abs(np.mean(y[k] - ref[k])) < 0.05, ch
            if np.ptp(y[k]) > 0.5:
                yi = np.interp(log.t, log.t[k], y[k])
                lead = max(np.corrcoef(yi[m:], ref[:ref.size - m])[0, 1] for m in range(0, 101, 5))
                assert lead > 0.3, ch          # 0.43-0.99 here; a flipped axis gives about -1
        assert np.max(np.abs(log.extras["psi_ref"])) < 0.2
    else:
        assert "x_ref" not in log.extras


def test_pwm_map_and_held_samples(tmp_path):
    np.testing.assert_allclose(pwm_to_rotor_speed([0, 40000]), [0.0, 0.04076521 * 40000 + 380.8359])
    # the published files have no held samples in flight (fractional, interpolated PWM)
    assert any("no held (repeated) samples" in n for n in import_nanobench(BUNDLED).notes)
    # a log that holds every 7th command: those rows are detected and interpolated
    lines = BUNDLED.read_text().splitlines()
    header = lines[0].split(",")
    js = [header.index(f"motor_motor_m{i}") for i in range(1, 5)]
    rows = [r.split(",") for r in lines]
    for k in range(8, len(rows), 7):
        for j in js:
            rows[k][j] = rows[k - 1][j]
    held_path = tmp_path / "held.csv"
    held_path.write_text("\n".join(",".join(r) for r in rows))
    imp_i = import_nanobench(held_path)
    imp_h = import_nanobench(held_path, held="hold")
    fresh = imp_h.log.extras["motor_fresh"] > 0
    assert fresh.mean() == pytest.approx(6 / 7, abs=0.01)
    assert any("86% of rows fresh" in n for n in imp_i.notes)
    assert np.all(np.diff(imp_h.log.inputs[:, 0])[~fresh[1:]] == 0)
    np.testing.assert_allclose(imp_i.log.inputs[fresh], imp_h.log.inputs[fresh])
    # interpolation recovers the original (smooth) commands better than holding
    orig = import_nanobench(BUNDLED).log.inputs[~fresh]
    assert np.abs(imp_i.log.inputs[~fresh] - orig).mean() < 0.6 * np.abs(imp_h.log.inputs[~fresh] - orig).mean()
    other = import_nanobench(BUNDLED, pwm_map=(0.05, 0.0))
    np.testing.assert_allclose(other.log.extras["pwm1"] * 0.05, other.log.inputs[:, 0], rtol=1e-12, atol=0)


def _write(tmp_path, text):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    return p


def test_import_errors_name_file_row_and_column(tmp_path):
    lines = BUNDLED.read_text().splitlines()
    header = lines[0].split(",")
    # missing column
    cols = [i for i, h in enumerate(header) if h != "motor_motor_m3"]
    text = "\n".join(",".join(r.split(",")[i] for i in cols) for r in lines[:200])
    with pytest.raises(GreyboxInputError, match="missing required column 'motor_motor_m3'"):
        import_nanobench(_write(tmp_path, text))
    # PWM out of range, time going backwards, non-numeric cell
    j = header.index("motor_motor_m2")
    for row, col, val, msg in [(50, j, "70000", r"row 51, column 'motor_motor_m2': PWM 70000"),
                               (60, 0, "1.0", r"row 61, column 't'"),
                               (70, header.index("px"), "abc", r"row 71, column 'px': not a number")]:
        rows = [r.split(",") for r in lines]
        rows[row][col] = val
        with pytest.raises(GreyboxInputError, match=msg):
            import_nanobench(_write(tmp_path, "\n".join(",".join(r) for r in rows)))
    # a log that never leaves the ground
    with pytest.raises(GreyboxInputError, match="never leaves the ground"):
        import_nanobench(_write(tmp_path, "\n".join(lines[:150])))
    # PWM logged as 8-bit values (a blind audit's mistake: imported, fitted with K_T 23 times
    # the truth and certified): no Crazyflie flies on 0.2 % of its PWM range
    motors = [header.index(f"motor_motor_m{i}") for i in range(1, 5)]
    rows = [r.split(",") for r in lines]
    for r in rows[1:]:
        for j in motors:
            r[j] = f"{round(float(r[j]) / 257)}"
    with pytest.raises(GreyboxInputError, match=r"motor commands stay below PWM \d+ .*8-bit values, 0\.\.255"):
        import_nanobench(_write(tmp_path, "\n".join(",".join(r) for r in rows)))


def test_cli_import_writes_log_and_airframe_or_nothing(tmp_path, capsys):
    out, af = tmp_path / "log.csv", tmp_path / "cf.toml"
    assert main(["import", "nanobench", str(BUNDLED), "--out", str(out), "--airframe-out", str(af),
                 "--json", str(tmp_path / "i.json")]) == 0
    log = load_log(out)
    import json
    said = json.loads((tmp_path / "i.json").read_text())
    assert said["format"] == "nanobench" and said["samples"] == len(log) and said["airframe"] == str(af)
    assert said["takeoff_time"] == pytest.approx(3.07, abs=0.05) and said["notes"]
    assert log.input_names == ["w1", "w2", "w3", "w4"] and "vbat" in log.extras
    airframe = load_airframe(af)
    assert airframe.n_rotors == 4 and airframe.mass == pytest.approx(0.030)
    # M1 front-right, M2 back-right, M3 back-left, M4 front-left (FRD), M1/M3 spin +1
    pos = np.array(airframe.rotor_positions)
    np.testing.assert_allclose(np.sign(pos[:, :2]), [[1, 1], [-1, 1], [-1, -1], [1, -1]])
    assert [r.spin for r in airframe.rotors] == [1, -1, 1, -1]
    bad = tmp_path / "nope.csv"
    assert main(["import", "nanobench", str(out), "--out", str(bad)]) == 2
    assert not bad.exists()
    assert "missing required column 'px'" in capsys.readouterr().err
    # a mass in grams (a blind audit's --mass 31): refused at import, nothing written
    out2, af2 = tmp_path / "log2.csv", tmp_path / "cf2.toml"
    assert main(["import", "nanobench", str(BUNDLED), "--out", str(out2), "--airframe-out", str(af2),
                 "--mass", "31"]) == 2
    assert not out2.exists() and not af2.exists()
    err = capsys.readouterr().err
    assert "from --mass 31" in err and "mass in grams" in err and "Traceback" not in err


def test_real_fit_hover_thrust_carries_the_weight():
    """Output error cannot fit these logs (PWM at 85 Hz for a 500 Hz controller); with process
    noise the base model's thrust at hover must match the weight, drag must be positive."""
    imp = import_nanobench(BUNDLED)
    af = load_airframe_text(crazyflie_airframe_toml(0.030, imp.hover_rotor_speed))
    model = QuadrotorModel(af)
    est, _ = imp.log.split(0.8)
    res = fit(model, est, process_noise="auto", max_iter=40)
    kt = res.value("K_T")
    w2 = est.inputs ** 2
    acc_z = est.output("az")
    # weight against fitted thrust at the mean hover condition (specific force ~ -g)
    thrust = kt * w2.sum(axis=1).mean()
    assert thrust == pytest.approx(af.mass * 9.81, rel=0.05)
    # and against the IMU: thrust/m is the measured specific force along body -z
    assert thrust / af.mass == pytest.approx(-acc_z.mean(), rel=0.05)
    assert 0.0 < res.value("Kd[0]") < 0.05 and 0.0 < res.value("Kd[1]") < 0.05


def test_disturbance_torque_lifts_b_into_the_propeller_range_on_a_real_flight(tmp_path):
    """On a real Crazyflie flight the base fit's b/K_T is 0.001 m, below what propellers give
    (published Crazyflie values 0.002-0.034 m): the controller cancels a yaw torque the model
    lacks through the commands the model reads, and b shrinks to explain commands that moved
    nothing. With a random-walk disturbance torque the fit is certified, b/K_T lands in the
    published range and the hover thrust carries the weight within 2 %."""
    imp = import_nanobench(BUNDLED)
    af = load_airframe_text(crazyflie_airframe_toml(0.030, imp.hover_rotor_speed))
    est, _ = imp.log.split(0.8)
    w2 = (est.inputs ** 2).sum(axis=1).mean()
    base = fit(QuadrotorModel(af), est, process_noise="auto", max_iter=40)
    assert base.value("b") / base.value("K_T") < 0.002
    res = fit(QuadrotorModel(af) + effects.DisturbanceTorque(), est, process_noise="auto", max_iter=40)
    assert res.converged, res.certificate.text()
    assert 0.002 < res.value("b") / res.value("K_T") < 0.034
    assert res.value("K_T") * w2 == pytest.approx(af.mass * 9.81, rel=0.02)
    # a disturbance model is no diagnosis candidate, but a saved model holding it reads back
    from greybox.fitted import load
    path = tmp_path / "model.json"
    res.save(path)
    back = load(path)
    assert "disturbance_torque" in back.model.effect_names
    assert "disturbance_torque" not in [c for c in effects.known_effects()]
    assert back.value("b") == pytest.approx(res.value("b"))
    _, val = imp.log.split(0.8)
    assert back.predict(val).total == pytest.approx(res.predict(val).total, rel=1e-9)


@pytest.mark.slow
def test_diagnosis_names_the_closed_loop_bias_of_b_and_the_value_to_take(monkeypatch):
    """A certified fit whose b/K_T is below what propellers give is refitted with a disturbance
    torque, and the words give that b. The bundled slice's base fit gives 0.0010 m, on the
    catalogue's lower edge (0.001 m): with the published Crazyflie lower edge (0.002 m) it is
    outside, and the refit's 0.0078 m is the value to take. Inside the range nothing is said."""
    from greybox.diagnosis.closed_loop import closed_loop_yaw

    imp = import_nanobench(BUNDLED)
    af = load_airframe_text(crazyflie_airframe_toml(0.030, imp.hover_rotor_speed))
    est, _ = imp.log.split(0.8)
    base = fit(QuadrotorModel(af), est, process_noise="auto", max_iter=40)
    assert closed_loop_yaw(base, [est]).words == ""                     # 0.0010 m: inside the catalogue's range
    # inside the range, but b differing between the halves: the refit's b is given too
    words = closed_loop_yaw(base, [est], halves_disagree=True).words
    assert "differs between the halves" in words and "take this b" in words, words
    assert 0.004 < float(words.split("b/K_T = ")[1].split(" ")[0]) < 0.012
    monkeypatch.setattr(effects.YawTorque, "RATIO_RANGE", (0.002, 0.034))
    words = closed_loop_yaw(base, [est]).words
    assert "closed-loop bias" in words and "take this b" in words, words
    ratio = float(words.split("b/K_T = ")[2].split(" ")[0])
    assert 0.004 < ratio < 0.012
    # a final model whose refit does not certify: the base model's refit answers, and says so
    from types import SimpleNamespace
    from greybox.diagnosis import closed_loop
    real, calls = closed_loop._with_disturbance, []

    def first_fails(res, logs, compile):
        calls.append(res)
        return SimpleNamespace(converged=False, status="maximum iterations reached") if len(calls) == 1 \
            else real(res, logs, compile)
    monkeypatch.setattr(closed_loop, "_with_disturbance", first_fails)
    final = fit(QuadrotorModel(af) + effects.by_name("drag_moment"), est, process_noise="auto", max_iter=40)
    words = closed_loop_yaw(final, [est], baseline=base).words
    assert calls == [final, base] and "the base model (the final model's refit was not certified" in words, words
    assert 0.004 < float(words.split("b/K_T = ")[2].split(" ")[0]) < 0.012


@needs_real
def test_closed_loop_yaw_on_a_whole_real_flight():
    """B3_figure8_fast: the base fit's b/K_T is 0.0006 m; with the disturbance torque 0.0062 m."""
    from greybox.diagnosis.closed_loop import closed_loop_yaw

    imp = import_nanobench(REAL / "B3_figure8_fast_rep1.csv")
    af = load_airframe_text(crazyflie_airframe_toml(0.030, imp.hover_rotor_speed))
    est, _ = imp.log.split(0.8)
    base = fit(QuadrotorModel(af), est, process_noise="auto")
    assert base.value("b") / base.value("K_T") < 0.001
    words = closed_loop_yaw(base, [est]).words
    assert 0.002 < float(words.split("b/K_T = ")[2].split(" ")[0]) < 0.034, words


def test_cli_fit_with_a_disturbance_torque(tmp_path, capsys):
    """From the command line: ``--effects disturbance_torque --process-noise auto`` on the
    imported real slice gives b/K_T in the published Crazyflie range (the JSON's values)."""
    import json
    out, af, res = tmp_path / "log.csv", tmp_path / "cf.toml", tmp_path / "fit.json"
    assert main(["import", "nanobench", str(BUNDLED), "--out", str(out), "--airframe-out", str(af)]) == 0
    assert main(["fit", str(out), "--airframe", str(af), "--effects", "disturbance_torque",
                 "--process-noise", "auto", "--json", str(res)]) == 0
    p = json.loads(res.read_text())["parameters"]
    assert 0.002 < p["b"]["value"] / p["K_T"]["value"] < 0.034


def load_airframe_text(text):
    import tomllib
    return airframe_from_dict(tomllib.loads(text), "crazyflie.toml")


@pytest.fixture(scope="module")
def battery_flight():
    """A synthetic flight whose logged rotor speeds are commands: the true speed is
    command * (1 + K (vbat - 4)), with vbat sagging from 4.15 to 3.6 V."""
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    syn = synthesize(model, duration=16.0, seed=21)
    log = syn.log
    vbat = np.linspace(4.15, 3.6, len(log)) - 0.1 * (log.inputs.mean(axis=1) / log.inputs.mean() - 1)
    K = 0.25
    cmd = log.inputs / (1 + K * (vbat[:, None] - 4.0))
    return syn, FlightLog(log.t, cmd, log.input_names, log.outputs, log.output_names, {"vbat": vbat},
                          source="battery"), K


def test_battery_voltage_effect_recovers_its_coefficient(battery_flight):
    syn, log, K = battery_flight
    model = syn.model + effects.BatteryVoltage()
    assert model.input_names == ["w1", "w2", "w3", "w4", "vbat"]
    est, _ = log.split()
    res = fit(model, est, p0=model.parameter_vector({"K_T": 2.395e-5 * 1.2}))
    assert res.converged
    assert res.value("K_vbat") == pytest.approx(K, abs=4 * res.std[res.free_names.index("K_vbat")])
    assert res.value("K_vbat") == pytest.approx(K, rel=0.03)
    assert res.value("K_T") == pytest.approx(2.395e-5, rel=0.01)


def test_signal_effect_needs_its_column(battery_flight):
    syn, log, _ = battery_flight
    model = syn.model + effects.BatteryVoltage()
    bare = FlightLog(log.t, log.inputs, log.input_names, log.outputs, log.output_names, source="bare.csv")
    with pytest.raises(GreyboxInputError, match="bare.csv: missing column 'vbat'.*battery_voltage"):
        fit(model, bare)
    holed = log.extras["vbat"].copy()
    holed[30] = np.nan
    with pytest.raises(GreyboxInputError, match="row 32, column 'vbat'"):
        model.prepare_log(FlightLog(log.t, log.inputs, log.input_names, log.outputs, log.output_names,
                                    {"vbat": holed}, source="h.csv"))


def test_rotor_map_offset_is_recovered():
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    syn = synthesize(model, duration=16.0, seed=22)
    log = syn.log
    shifted = FlightLog(log.t, log.inputs - 40.0, log.input_names, log.outputs, log.output_names)
    ext = model + effects.by_name("rotor_map")
    res = fit(ext, shifted.split()[0])
    assert res.value("w_offset") == pytest.approx(40.0, abs=2.0)


def test_process_noise_fit_recovers_parameters_of_an_exact_model():
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    syn = synthesize(model, duration=10.0, seed=23, sensors=SensorSpec(rate=250.0, vision_rate=125.0))
    est, _ = syn.log.split()    # 250 Hz: a node every 12 samples (nearest 50 ms), as without process noise
    p0 = model.parameter_vector({"K_T": 2.395e-5 * 1.3, "b": 6.8429e-7 * 0.7, "Kd": [0.15, 0.05, 0.2]})
    res = fit(model, est, p0=p0, process_noise="auto")
    assert res.converged, res.status
    assert res.process_noise is not None and res.interval == 12
    assert res.value("K_T") == pytest.approx(2.395e-5, rel=0.01)
    assert res.value("b") == pytest.approx(6.8429e-7, rel=0.03)
    with pytest.raises(GreyboxInputError, match="process_noise: unknown state 'vw'"):
        fit(model, est, process_noise={"vw": 1.0})


def test_process_noise_between_longer_intervals_fits_and_checks_its_residuals():
    """Soft continuity between intervals of several samples (``interval=5`` with process
    noise) used to end in an IndexError in the residual check, which assumed a node at every
    sample; it fits, recovers the parameters and judges the residuals over its own intervals."""
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    syn = synthesize(model, duration=10.0, seed=23, sensors=SensorSpec(rate=250.0, vision_rate=125.0))
    est, _ = syn.log.split()
    p0 = model.parameter_vector({"K_T": 2.395e-5 * 1.3, "b": 6.8429e-7 * 0.7, "Kd": [0.15, 0.05, 0.2]})
    res = fit(model, est, p0=p0, process_noise="auto", interval=5)
    assert res.converged, res.status
    assert res.interval == 5 and res.process_noise is not None
    assert res.value("K_T") == pytest.approx(2.395e-5, rel=0.01)
    assert res.value("b") == pytest.approx(6.8429e-7, rel=0.03)
    assert all(v < 3.0 for v in res.certificate.residual_over_noise.values())


@pytest.mark.slow
def test_process_noise_diagnosis_finds_the_missing_yaw_torque():
    """The seed paper's story with soft continuity: screening and refits use the baseline's
    process noise, and the verdict and the recovered b are right."""
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    syn = synthesize(model, duration=12.0, seed=31, sensors=SensorSpec(rate=200.0, vision_rate=100.0))
    d = diagnose(model.without("yaw_torque"), syn.log, candidates=["yaw_torque", "ground_effect", "wind"],
                 process_noise="auto")
    assert d.verdict == "yaw_torque"
    top = d.ranking[0]
    assert top.channels_after["r"] < 0.3 * d.baseline_prediction.nrmse["r"]
    assert top.fit.value("b") == pytest.approx(6.8429e-7, rel=0.03)
    assert not any(c.significant for c in d.ranking[1:])


def test_log_with_more_rotors_than_the_model_is_refused(battery_flight):
    syn, log, _ = battery_flight
    five = FlightLog(log.t, np.hstack([log.inputs, log.inputs[:, :1]]), ["w1", "w2", "w3", "w4", "w5"],
                     log.outputs, log.output_names, source="five.csv")
    with pytest.raises(GreyboxInputError, match="five.csv: inputs w1,w2,w3,w4,w5 do not match"):
        syn.model.prepare_log(five)


def test_motor_lag_fit_started_at_the_true_values_stays_there_and_is_certified():
    """The motor-lag states' node guesses are the logged commands filtered by the lag: with
    the commands themselves a fit started at the true values (30 ms lag, aggressive
    manoeuvres) opened gaps of 10^3 noise levels and left for drags on their bounds; and a
    lag state the outputs barely see no longer keeps the optimum from being certified."""
    base = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    model = base + effects.MotorLag()
    p = model.parameter_vector({"tau_m": 0.03})
    syn = synthesize(model, p, duration=30.0, seed=3, sensors=SensorSpec(rate=200.0, vision_rate=60.0),
                     manoeuvres=["hover", "ground", "step_x", "sprint", "yaw", "step_z", "fast", "step_y"])
    res = fit(model, syn.log, p0=p)
    assert res.converged, res.status
    assert res.value("tau_m") == pytest.approx(0.03, rel=0.02)
    assert res.value("Kd[0]") == pytest.approx(0.1, rel=0.05)
    assert max(res.certificate.residual_over_noise.values()) < 1.5


@pytest.mark.slow
@needs_real
def test_discovered_thrust_that_takes_over_the_rotors_is_not_taken_as_a_force():
    """B6_linear_ramp: the base model over-predicts the roll moment the logged PWM gives
    (its roll 0.25 s ahead is 1 rad off). Discovery's regression offers ``fz ∝ w2sum*vbat``:
    refitted, it carries most of the weight and K_T falls with it, so the roll moment shrinks
    (validation nrmse 57.6 -> 1.2), a moment gain in disguise. It is not significant, and
    says so; before, it set aside the CoG offset that every other flight of this vehicle
    takes (the verdict was null and the final model the base one, its hover thrust 11 % low)."""
    from greybox.diagnosis.discovery import MAX_THRUST_SHIFT, discover
    from greybox.validation import predict_after_fit
    imp = import_nanobench(REAL / "B6_linear_ramp_rep2.csv")
    af = load_airframe_text(crazyflie_airframe_toml(0.030, imp.hover_rotor_speed,
                                                    ground_z=-(imp.rest_height - 0.025)))
    est, val = imp.log.split(0.8)
    res = fit(QuadrotorModel(af), est, process_noise="auto")
    assert res.converged
    pred = predict_after_fit(res, [est], [val], horizon=0.5)
    found, _ = discover(res.model, res, pred, [est], [val])
    fz = [d for d in found if d.channel == "fz" and d.fit is not None]
    assert fz, [d.text() for d in found]
    for d in fz:
        shift = d.fit.value("K_T") / res.value("K_T") - 1
        assert abs(shift) > MAX_THRUST_SHIFT
        assert not d.significant and "moment gain in disguise" in d.reason, d.reason


def test_without_the_quaternion_the_angles_unit_is_read_from_the_motion(tmp_path):
    """The published roll/pitch/yaw columns are radians (documented as degrees). Without the
    quaternion the import reads the unit from the motion (a tilt accelerates a multirotor by
    about g times it): the columns as published are radians and give the quaternion's attitude;
    the same in degrees are degrees and give it too (an audit's import of a flight without qw
    took radians for degrees: attitude and gyro 57x too small). A flight whose tilt does not
    move cannot tell: one error asking for --angle-unit, which then decides."""
    import pandas as pd
    df = pd.read_csv(BUNDLED)
    ref = import_nanobench(BUNDLED).log
    plain = df.drop(columns=["qx", "qy", "qz", "qw"])
    in_degrees = plain.copy()
    in_degrees[["roll", "pitch", "yaw"]] = np.degrees(plain[["roll", "pitch", "yaw"]])
    for frame, unit in ((plain, "radians"), (in_degrees, "degrees")):
        path = tmp_path / f"{unit}.csv"
        frame.to_csv(path, index=False)
        imp = import_nanobench(path)
        assert any(f"attitude from roll/pitch/yaw, in {unit} (" in n for n in imp.notes), imp.notes
        for ch in ("phi", "theta", "p", "q"):
            a, b = imp.log.output(ch), ref.output(ch)
            ok = np.isfinite(a) & np.isfinite(b)
            assert ok.sum() > 100 and np.max(np.abs(a[ok] - b[ok])) < 0.02, (unit, ch)
    from greybox.io.nanobench import angle_unit_from_motion
    t = plain.t.to_numpy() - plain.t[0]
    pos, ang = plain[["px", "py", "pz"]].to_numpy(), plain[["roll", "pitch", "yaw"]].to_numpy()
    unit, fits = angle_unit_from_motion(t, pos, ang)
    assert unit == "rad" and 0.8 < fits["rad"][0] < 1.25 and fits["rad"][1] > 0.9, fits
    assert fits["deg"][0] > 40                        # the other unit: 57 times off
    gappy = pos.copy()
    for a in range(100, len(t), 200):                 # 0.2-s outages every 2 s: each stretch alone
        gappy[a:a + 20] = np.nan
    assert angle_unit_from_motion(t, gappy, ang)[0] == "rad"
    assert angle_unit_from_motion(t, pos * 1000, ang)[0] is None          # positions in mm: neither
    rng = np.random.default_rng(3)                    # a hover whose tilt is noise, yawing: cannot tell
    n = t.size
    hover = np.column_stack([rng.normal(0, 1e-3, (n, 2)), 1 + rng.normal(0, 1e-3, n)])
    for noise in (5e-4, 5e-3):
        tilt = np.column_stack([rng.normal(0, noise, (n, 2)), np.linspace(0, 6, n)])
        assert angle_unit_from_motion(t, hover, tilt)[0] is None
        assert angle_unit_from_motion(t, hover, np.degrees(tilt))[0] is None
    still = plain.copy()
    still[["roll", "pitch"]] = 0.01
    path = tmp_path / "still.csv"
    still.to_csv(path, index=False)
    with pytest.raises(GreyboxInputError, match="angle_unit='rad' or 'deg'"):
        import_nanobench(path)
    assert any("in radians (as given)" in n for n in import_nanobench(path, angle_unit="rad").notes)
    # a unit given against what the motion says clearly is taken, and the note says so (a blind
    # audit's --angle-unit rad on degrees was refused only later, by one roll sample of 12.7 deg)
    notes = import_nanobench(tmp_path / "degrees.csv", angle_unit="rad").notes
    assert any("in radians (as given, though the motion says degrees" in n for n in notes), notes


@needs_real
@pytest.mark.slow
def test_rotor_gains_by_spin_direction_with_b_near_zero_are_not_the_verdict(tmp_path):
    """The first 60 % of B2_circle_slow_rep2 (a flight the diagnosis had not been run on): its
    first round's motor_asymmetry refit validated best with gains about +-19 % by spin
    direction and b/K_T near 1e-6 m, which only works because b is near zero; it was the
    verdict, and the final model's thrust then followed the yaw command. Refused as
    implausible, the verdict is the CoG offset the whole flight takes."""
    src = REAL / "B2_circle_slow_rep2.csv"
    lines = src.read_text().splitlines(keepends=True)
    cut = tmp_path / "B2_circle_slow_rep2_first60.csv"
    cut.write_text("".join(lines[:1 + (len(lines) - 1) * 6 // 10]))
    import tomllib
    imp = import_nanobench(cut)
    af = airframe_from_dict(tomllib.loads(
        crazyflie_airframe_toml(0.030, imp.hover_rotor_speed, ground_z=-(imp.rest_height - 0.025))), "cf")
    d = diagnose(QuadrotorModel(af), imp.log, process_noise="auto", horizon=0.5, iterate=False, discover=False)
    assert d.baseline.converged
    assert d.verdict == "cog_offset", d.summary()
    ma = next(c for c in d.rounds[0].ranking if c.effect == "motor_asymmetry")
    assert ma.fit is not None and not ma.significant and "difference between the spin directions" in ma.reason, ma.reason
    assert ma.fit.value("b") / ma.fit.value("K_T") < 1e-3


def _last_60_percent(tmp_path, flight: str) -> tuple[QuadrotorModel, FlightLog]:
    """The base model of a NanoBench flight cut to the last 60 % of its rows (starting in the
    air: a flight the whole-flight runs never saw) and the estimation part of the cut."""
    import tomllib
    lines = (REAL / f"{flight}.csv").read_text().splitlines(keepends=True)
    n = len(lines) - 1
    cut = tmp_path / f"{flight}_last60.csv"
    cut.write_text(lines[0] + "".join(lines[1 + n - n * 6 // 10:]))
    imp = import_nanobench(cut)
    af = airframe_from_dict(tomllib.loads(
        crazyflie_airframe_toml(0.030, imp.hover_rotor_speed, ground_z=-(imp.rest_height - 0.025))), "cf")
    return QuadrotorModel(af), imp.log.split(0.8)[0]


@needs_real
def test_a_flight_that_starts_in_the_air_keeps_its_velocity_the_positions_derivative(tmp_path):
    """The last 60 % of B10_lissajous_slow (starting in the air: no climb in the log). With the
    positions' process noise estimated like any state's, the fit ended certified with the thrust
    carrying 85 % of the weight and the vertical drag Kd[2] on its 0.3 N s/m bound: the velocity
    state left the positions' derivative and its drag carried the rest. Fitted again with the
    positions held to what the kinematics allow, the thrust carries the weight, Kd[2] is off its
    bound and the horizontal drag is the IMU's (0.011-0.012 N s/m), and the fit says so."""
    from greybox.fitting.api import POSITION_GAP_SHARE, THRUST_BALANCE
    model, est = _last_60_percent(tmp_path, "B10_lissajous_slow_rep1")
    res = fit(model, est, process_noise="auto")
    assert res.converged, res.status
    hover = model.parameter_vector()[model.param_names.index("K_T")]      # the balance, from the log
    assert abs(res.value("K_T") / hover - 1) < THRUST_BALANCE
    assert res.value("Kd[2]") < 0.1 and 0.009 < res.value("Kd[0]") < 0.014 and 0.009 < res.value("Kd[1]") < 0.014
    assert "positions' process noise held" in res.warnings[0] and "85 % of the weight" in res.warnings[0], res.warnings
    for name in "xyz":
        assert res.process_noise[name] == pytest.approx(POSITION_GAP_SHARE * res.sigma[name], rel=1e-6)


@needs_real
def test_a_thrust_kept_from_the_weight_by_a_torque_the_model_lacks_says_which_channels(tmp_path):
    """The last 60 % of B6_linear_ramp (a slow line at 1 m, starting in the air): the base fit
    is certified with the thrust carrying 67 % of the weight, and neither restart carries it
    (from the balance with the positions held: 88 %). Held at the balance in the fit's own
    weights, the roll rate's residuals grow (it is 74x the noise already: the controller trims
    a roll torque the base model lacks, the CoG offset the diagnosis finds on this flight) and
    the height's and vertical specific force's shrink: the fit says so, and keeps its K_T."""
    model, est = _last_60_percent(tmp_path, "B6_linear_ramp_rep2")
    res = fit(model, est, process_noise="auto")
    assert res.converged, res.status
    hover = model.parameter_vector()[model.param_names.index("K_T")]
    assert 0.6 < res.value("K_T") / hover < 0.75
    pull = [w for w in res.warnings if w.startswith("with K_T held where the rotors carry the weight")]
    assert len(pull) == 1, res.warnings
    grown, rest = pull[0].split("the residuals grow in ")[1].split(" and shrink in ")
    assert grown.startswith("p (") and "z" in rest.split(":")[0] and "az" in rest.split(":")[0], pull[0]
    assert "a torque the model lacks that the controller trims" in pull[0], pull[0]
    # a soft fit's gaps are part of its cost: its certificate does not call them closed
    assert "the shooting gaps are process noise" in res.certificate.text()
    assert "largest gap" not in res.certificate.text()


@pytest.mark.slow
@needs_real
def test_on_a_real_flight_the_model_flown_by_its_law_is_the_reported_prediction_and_beats_naive():
    """B2_circle_fast: the model (base plus the CoG offset, drag moment and moment gain the
    diagnoses of these flights hold) open loop loses to the naive predictor on most positions
    and angles 0.25 and 0.5 s ahead (the logged commands carry the attitude only through the
    controller); flown by the controller's law fitted to the log it predicts the estimation
    flight's last seconds better, so the contract's ``horizons`` are the closed loop's, and on
    the held-out 20 % they beat the naive predictor where the open loop's do not."""
    from greybox.commands import fit_json
    from greybox.validation import predict, prediction_options
    imp = import_nanobench(REAL / "B2_circle_fast_rep1.csv")
    af = load_airframe_text(crazyflie_airframe_toml(0.030, imp.hover_rotor_speed,
                                                    ground_z=-(imp.rest_height - 0.025)))
    model = QuadrotorModel(af, ["cog_offset", "drag_moment", "moment_gain"])
    est, val = imp.log.split(0.8)
    res = fit(model, est, process_noise="auto")
    assert res.converged
    pred = predict(model, res.p, val, horizon=0.5, **prediction_options(res))
    doc = fit_json(model, res, [pred], [str(REAL / "B2_circle_fast_rep1.csv")], est=[est])
    cl = doc["closed_loop"]
    errs = cl["estimation_errors"]
    assert cl["preferred"] is True and errs["closed_loop"] < 0.8 * errs["open_loop"], errs
    assert doc["horizons"] == cl["horizons"] and doc["horizons_predictor"]["closed_loop"] is True

    def beats(h):
        return sum(h["model"][ch][h["horizons"].index(a)] < h["naive"][ch][h["horizons"].index(a)]
                   for ch in ("x", "y", "z", "phi", "theta", "psi") for a in (0.25, 0.5))
    assert beats(doc["horizons"]) >= 11 and beats(doc["horizons_open_loop"]) <= 6


@needs_real
def test_the_thrust_at_the_highest_commands_is_what_they_ask_on_every_real_flight():
    """On the ten real Crazyflie flights (some with PWM clipped at its top) the log's own
    accelerations over the runs of the highest commands give 0.93-1.0 of the thrust the
    commands give, and no saturation is said: the check that caught a blind audit's commands
    beyond its motors' range (0.76, 0.79) is quiet on a real vehicle's data."""
    import tomllib
    from greybox.diagnosis import thrust_at_top
    from greybox.diagnosis.analysis import THRUST_AT_TOP_LOW, thrust_at_top_words
    for path in FILES:
        imp = import_nanobench(path)
        af = airframe_from_dict(tomllib.loads(crazyflie_airframe_toml(0.030, imp.hover_rotor_speed)), "cf")
        model = QuadrotorModel(af)
        top = thrust_at_top(model, imp.log)
        assert top is not None and THRUST_AT_TOP_LOW + 0.05 < top.ratio < 1.05, (path.name, top)
        assert thrust_at_top_words(model, imp.log) == "", path.name


@needs_real
def test_positions_below_the_ground_plane_are_said_and_a_real_flight_above_it_is_not():
    """Every real flight stays above the ground plane the importer sets (its rest height): no
    words. The same flight given a ground 1 m above the log's origin (``ground_z = -1``) goes
    0.94 m below it: said, with the depth and the share of samples (a blind audit's flight that
    fell 98 m below the ground was diagnosed at length, and nothing said)."""
    import tomllib
    from greybox.diagnosis.analysis import below_ground_words
    for path in FILES:
        imp = import_nanobench(path)
        text = crazyflie_airframe_toml(0.030, imp.hover_rotor_speed, ground_z=-(imp.rest_height - 0.025))
        assert below_ground_words(QuadrotorModel(airframe_from_dict(tomllib.loads(text), "cf")), imp.log) == "", path.name
    imp = import_nanobench(REAL / "B2_circle_fast_rep1.csv")
    z_max = float(np.nanmax(imp.log.output("z")))
    lifted = QuadrotorModel(airframe_from_dict(tomllib.loads(crazyflie_airframe_toml(0.030, imp.hover_rotor_speed,
                                                                                     ground_z=-1.0)), "cf"))
    words = below_ground_words(lifted, imp.log)
    assert words.startswith(f"the logged positions go down to {z_max + 1.0:.3g} m below the airframe's ground plane"), words
    assert "set ground_z in the airframe to the z of the floor" in words

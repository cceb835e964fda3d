"""Importers (greybox.io): the shared frame / unit / time / held-sample / ground-contact parts
checked by hand, the PX4 ULog sample and the Crazyflie uSD log from ../shared/realdata, and
clear errors for corrupt or truncated files."""
import math
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from greybox.airframe import load_airframe
from greybox.cli import main
from greybox.data import load_log
from greybox.errors import GreyboxInputError
from greybox.io import (CRAZYFLIE_PWM_MAP, G0, PX4_PWM_MAP, PwmMap, commands_on_grid, deg_to_rad,
                        euler_from_quaternion, euler_zup_to_ned, flight_from_height, flight_from_imu, flu_to_frd,
                        fresh_rows, g_to_ms2, grid_with, import_crazyflie_usd, parse_pwm_map, read_usd_log,
                        rpm_to_rad_s, snap, time_base, zup_to_ned)
from greybox.io.px4 import import_px4_topics, px4_airframe_toml
from greybox.rotations import rotation_matrices

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
ULG = REAL / "px4" / "sample.ulg"
USD = REAL / "crazyflie_usd" / "log10"
need_ulg = pytest.mark.skipif(not ULG.exists(), reason="../shared/realdata/px4 not present")
need_usd = pytest.mark.skipif(not USD.exists(), reason="../shared/realdata/crazyflie_usd not present")


def _R(e):
    return rotation_matrices(np.atleast_1d(e[0]), np.atleast_1d(e[1]), np.atleast_1d(e[2]))[0]


# ------------------------------------------------------------------ frames and units by hand

def test_quaternion_of_a_known_roll_pitch_yaw():
    a = math.radians(30)
    # 30 deg roll about x: q = (cos 15, sin 15, 0, 0) scalar first
    np.testing.assert_allclose(euler_from_quaternion([math.cos(a / 2), math.sin(a / 2), 0, 0], scalar_first=True),
                               [[a, 0, 0]], atol=1e-12)
    # the same, scalar last (ROS / Vicon order)
    np.testing.assert_allclose(euler_from_quaternion([math.sin(a / 2), 0, 0, math.cos(a / 2)]), [[a, 0, 0]],
                               atol=1e-12)
    # 90 deg yaw, 20 deg pitch: compose and read back
    b, c = math.radians(20), math.radians(90)
    qz = np.array([math.cos(c / 2), 0, 0, math.sin(c / 2)])
    qy = np.array([math.cos(b / 2), 0, math.sin(b / 2), 0])
    w1, x1, y1, z1 = qz
    w2, x2, y2, z2 = qy
    q = [w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
         w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2]
    np.testing.assert_allclose(euler_from_quaternion(q, scalar_first=True), [[0, b, c]], atol=1e-12)


def test_zup_flu_to_ned_frd_by_hand():
    # a point 2 m up, 1 m along +y (left of x) in a z-up world is 2 m "up" = z -2 in NED, y -1
    np.testing.assert_allclose(zup_to_ned([3.0, 1.0, 2.0]), [3.0, -1.0, -2.0])
    # an FLU body: rate about +z (up, counter-clockwise from above) is r < 0 in FRD
    np.testing.assert_allclose(flu_to_frd(np.array([[0.1, 0.2, 0.3]])), [[0.1, -0.2, -0.3]])
    # a level vehicle at rest: the accelerometer reads +1 g along FLU z -> az = -9.81 FRD
    np.testing.assert_allclose(flu_to_frd(g_to_ms2([0.0, 0.0, 1.0])), [0.0, 0.0, -G0])
    # Euler angles: R_ned = F R_zup F with F = diag(1, -1, -1), for any attitude
    F = np.diag([1.0, -1.0, -1.0])
    for e in ([0.3, 0.2, 1.0], [-0.5, 0.4, -2.5], [0.1, -0.7, 3.0]):
        e_ned = euler_zup_to_ned(np.array([e]))[0]
        np.testing.assert_allclose(_R(e_ned), F @ _R(e) @ F, atol=1e-12)
        assert -np.pi <= e_ned[2] < np.pi


def test_units_by_hand():
    assert deg_to_rad(180.0) == pytest.approx(math.pi)
    np.testing.assert_allclose(deg_to_rad([90.0, -45.0]), [math.pi / 2, -math.pi / 4])
    assert g_to_ms2(1.0) == pytest.approx(9.80665)
    assert rpm_to_rad_s(9549.296585513721) == pytest.approx(1000.0)
    # PWM map: stopped at or below its off value, never negative
    m = PwmMap(1.0, -1000.0, off=900.0)
    np.testing.assert_allclose(m([0, 900, 950, 1000, 1500, 2000]), [0, 0, 0, 0, 500, 1000])
    cf = PwmMap(*CRAZYFLIE_PWM_MAP)
    np.testing.assert_allclose(cf([0, 40000]), [0.0, 0.04076521 * 40000 + 380.8359])
    assert parse_pwm_map("0.5, -10") == (0.5, -10.0)
    for bad in ("1", "a,b", "-1,0", "1,2,3", "nan,0"):
        with pytest.raises(GreyboxInputError, match="--pwm-map"):
            parse_pwm_map(bad)
    with pytest.raises(GreyboxInputError, match="slope must be positive"):
        PwmMap(0.0, 1.0)


def test_time_held_samples_and_one_time_base():
    np.testing.assert_allclose(time_base([5_000_000, 5_004_000, 5_010_000], "f", scale=1e-6), [0, 0.004, 0.01])
    np.testing.assert_allclose(time_base([1.0, 2.0], "f", origin="given"), [1.0, 2.0])
    with pytest.raises(GreyboxInputError, match=r"f: sample 3: time 2 is not after the previous sample's 3"):
        time_base([1, 3, 2], "f")
    # held commands: fresh rows, interpolation between them, a stopped motor stays stopped
    cmd = np.array([[0.0], [0.0], [10.0], [10.0], [20.0], [20.0], [0.0]])
    fresh = fresh_rows(cmd)
    assert fresh.tolist() == [True, False, True, False, True, False, True]
    t = np.arange(7.0)
    held = commands_on_grid(t, t[fresh], cmd[fresh], "hold")
    np.testing.assert_allclose(held.ravel(), cmd.ravel())
    interp = commands_on_grid(t, t[fresh], cmd[fresh], "interpolate")
    np.testing.assert_allclose(interp.ravel(), [0, 0, 10, 15, 20, 10, 0])   # row 1 held stopped
    # multi-rate: a 10 Hz sensor on a 100 Hz base; a sample in a base gap gets its own row
    base = np.r_[np.arange(0, 0.5, 0.01), np.arange(0.6, 1.0, 0.01)]
    slow = np.array([0.1004, 0.2, 0.55, 0.9])
    grid = grid_with(base, slow)
    assert grid.size == base.size + 1 and 0.55 in grid
    y = snap(grid, slow, np.array([1.0, 2.0, 3.0, 4.0]))
    assert np.isfinite(y).sum() == 4 and y[np.argmin(abs(grid - 0.1))] == 1.0
    assert y[np.flatnonzero(grid == 0.55)[0]] == 3.0



def test_rotor_speeds_held_on_the_rows_are_found_and_interpolated_on_request(tmp_path, capsys):
    """A user's CSV whose rotor speeds are 50-Hz ESC telemetry held on 100-Hz rows (a blind
    audit's outdoor flights): every other row repeats the previous one. ``held_inputs`` says so
    (half the rows, a fresh value every 2 rows, 50 Hz); ``interpolate_held_inputs`` puts the
    held rows half-way between their fresh neighbours, marks the fresh rows and says so; a log
    fresh on every row (greybox's own), or one an importer marked, is not held. ``greybox fit``
    fits them as logged with a note (the contract's zero-order hold), and ``--held
    interpolate`` interpolates them."""
    from greybox import FlightLog, save_log
    from greybox.io import held_inputs, interpolate_held_inputs
    demo = load_log(Path(__file__).resolve().parents[1] / "greybox" / "data" / "logs" / "demo_ground_effect.csv")
    assert held_inputs(demo) is None
    log = demo.slice(0, 2000)
    t = log.t
    dt = float(np.median(np.diff(t)))
    fresh = np.arange(len(t)) % 2 == 0
    inputs = log.inputs.copy()
    inputs[~fresh] = inputs[np.flatnonzero(~fresh) - 1]          # held: the previous row's value
    held_log = FlightLog(t, inputs, list(log.input_names), log.outputs, list(log.output_names), source="held.csv")
    found = held_inputs(held_log)
    assert found is not None and found.share == pytest.approx(0.5, abs=1e-3) and found.every == pytest.approx(2.0)
    assert found.rate == pytest.approx(0.5 / dt) and found.row_rate == pytest.approx(1 / dt)
    assert "every 2 rows" in found.text()
    smooth = interpolate_held_inputs(held_log)
    k = np.flatnonzero(~fresh)[:-1]
    np.testing.assert_allclose(smooth.inputs[k], 0.5 * (inputs[k - 1] + inputs[k + 1]))
    np.testing.assert_array_equal(smooth.inputs[fresh], inputs[fresh])
    np.testing.assert_array_equal(smooth.extras["motor_fresh"], fresh.astype(float))
    assert "interpolated between the fresh rows" in smooth.notes[-1]
    assert held_inputs(smooth) is None and interpolate_held_inputs(smooth) is smooth
    # a 200-Hz controller's speeds on 200 Hz rows are fresh on every row
    assert held_inputs(log) is None
    path = tmp_path / "held.csv"
    save_log(held_log, path, digits=10)
    airframe = str(Path(__file__).resolve().parents[1] / "greybox" / "data" / "airframes" / "paper.toml")
    assert main(["fit", str(path), "--airframe", airframe, "--quiet", "--max-iter", "3"]) in (0, 1)
    err = capsys.readouterr().err
    assert "repeat the previous row exactly on 50 % of the rows" in err and "--held interpolate" in err, err
    assert main(["fit", str(path), "--airframe", airframe, "--quiet", "--max-iter", "3", "--held",
                 "interpolate"]) in (0, 1)
    err = capsys.readouterr().err
    assert "interpolated between the fresh rows (held inputs: interpolate)" in err, err


def test_rotor_speeds_held_per_motor_with_staggered_phases_are_found_and_interpolated_per_column():
    """A blind audit's ESC telemetry: each motor refreshed at 100 Hz on 200-Hz rows, each on
    rows of its own (phases staggered), so that some column changes on most rows and the rows
    as a whole looked fresh: not found as held, and ``--held interpolate`` changed nothing
    (Kd[2] +7.6 %, 2.7 std). Each column is now judged on its own fresh rows and interpolated
    between them: held linear ramps come back exactly between their fresh samples."""
    from greybox import FlightLog
    from greybox.io import held_inputs, interpolate_held_inputs
    t = np.arange(0.0, 4.0, 0.005)                                   # 200 Hz rows
    true = np.column_stack([1500.0 + 50.0 * t + 10.0 * j for j in range(4)])
    inputs = true.copy()
    for j in range(4):
        fresh = (np.arange(t.size) + j) % 2 == 0                      # each motor at 100 Hz, staggered
        fresh[0] = True
        idx = np.maximum.accumulate(np.where(fresh, np.arange(t.size), 0))
        inputs[:, j] = true[idx, j]
    log = FlightLog(t, inputs, ["w1", "w2", "w3", "w4"], np.zeros((t.size, 6)),
                    ["x", "y", "z", "phi", "theta", "psi"], source="esc.csv")
    from greybox.io import fresh_rows
    assert fresh_rows(inputs).mean() > 0.95                          # the rows as a whole look fresh
    found = held_inputs(log)
    assert found is not None and found.staggered and found.share == pytest.approx(0.5, abs=0.01)
    assert found.every == pytest.approx(2.0, rel=1e-3) and found.rate == pytest.approx(100.0, rel=1e-3)
    assert "each of w1, w2, w3, w4 repeats" in found.text("w1, w2, w3, w4") and "each on rows of its own" in found.text()
    smooth = interpolate_held_inputs(log)
    np.testing.assert_allclose(smooth.inputs[2:-2], true[2:-2], rtol=0, atol=1e-9)
    assert "interpolated between the fresh rows" in smooth.notes[-1]
    # fresh on every row: not held
    assert held_inputs(FlightLog(t, true, ["w1", "w2", "w3", "w4"], np.zeros((t.size, 6)),
                                 ["x", "y", "z", "phi", "theta", "psi"])) is None


def test_a_command_that_stays_put_is_held_not_ramped():
    """A blind audit's 418-Hz uSD command stream, constant for the 567 ms on the ground before
    take-off, was ramped across them towards the next change (97 rad/s RMS off, K_T 2.3 % low
    in the IMU fit). A gap far longer than the samples' spacing is a command that stayed put:
    held, and ramped over one typical spacing only; short gaps are interpolated as before."""
    t = np.arange(0.0, 1.0, 0.001)                      # 1 kHz rows
    # a 500 Hz controller's command, constant 48658 until 0.567 s, then moving
    true = np.where(t < 0.567, 48658.0, 48658.0 + 3000 * np.sin(5 * (t - 0.567)))
    logged = np.unique(np.round(np.arange(0.0, 1.0, 1 / 418) * 1000).astype(int))   # 418 Hz of fresh samples
    cmd = true[logged]
    fresh = fresh_rows(cmd)
    t_cmd, c = t[logged][fresh], cmd[fresh]
    grid = commands_on_grid(t, t_cmd, c, "interpolate", repeated_between=True).ravel()
    ground = t < 0.56
    np.testing.assert_array_equal(grid[ground], 48658.0)       # was a ramp up to 30 PWM off
    moving = (t > 0.6) & (t < t_cmd[-1])
    assert np.sqrt(np.mean((grid[moving] - true[moving]) ** 2)) < 5.0   # interpolated where it moves
    # the knot: one typical spacing before the end of the long gap
    from greybox.io import held_run_knots
    tk, ck = held_run_knots(t_cmd, c[:, None])
    k = int(np.argmax(np.diff(t_cmd)))
    typical = np.median(np.diff(t_cmd))
    assert tk.size == t_cmd.size + 1 and np.isclose(tk[k + 1], t_cmd[k + 1] - typical) and ck[k + 1, 0] == c[k]
    # the audit's 79-Hz NanoBench log on 100 Hz rows: an integer command clamped for 5 rows, then
    # a step, was ramped over the 4 rows before it; a logger's one- and two-row gaps still are
    t = np.arange(0.0, 0.2, 0.01)
    cmd = np.array([100, 110, 110, 120, 130, 140, 140, 150, 500, 500, 500, 500, 500, 300, 310, 320, 320, 330,
                    340, 350], float)
    fresh = fresh_rows(cmd)
    grid = commands_on_grid(t, t[fresh], cmd[fresh], "interpolate", repeated_between=True).ravel()
    np.testing.assert_allclose(grid[8:13], 500.0)                            # held, then the step
    np.testing.assert_allclose(grid[[1, 2, 5, 6]], [110, 115, 140, 145])     # short gaps: ramps
    # between messages (PX4's; a dropout) the command is not known to stay put: interpolated
    t_msg = np.r_[0.0, 0.01, 0.02, 0.1, 0.11]
    msgs = np.array([100.0, 110.0, 120.0, 200.0, 210.0])
    np.testing.assert_allclose(commands_on_grid(np.array([0.06]), t_msg, msgs, "interpolate").ravel(), 160.0)

def test_ground_contact_from_height_and_from_imu():
    t = np.arange(0, 10, 0.01)
    h = np.where((t > 2) & (t < 8), 1.0, 0.05)
    running = (t > 1.5) & (t < 8.5)
    span = flight_from_height(t, h, running, "f", 0.01)
    assert t[span.k0] == pytest.approx(2.01) and t[span.k1] == pytest.approx(7.99)
    assert span.rest_height == pytest.approx(0.05)
    with pytest.raises(GreyboxInputError, match="never leaves the ground.*HINT"):
        flight_from_height(t, np.full(t.size, 0.05), running, "f", hint=" HINT")
    # a 0.1-s mocap dropout at 1 m is bridged (a blind audit's cut the first 5 s of a flight away,
    # without a word); a 2-s one parts the flight, and the left-out part is said
    hole = h.copy()
    hole[(t > 4.0) & (t < 4.11)] = np.nan
    span = flight_from_height(t, hole, running, "f", 0.01)
    assert t[span.k0] == pytest.approx(2.01) and t[span.k1] == pytest.approx(7.99)
    assert f"{np.isnan(hole).sum()} samples without a height in flight taken as airborne" in span.note
    hole[(t > 3.0) & (t < 5.0)] = np.nan
    span = flight_from_height(t, hole, running, "f", 0.01)
    assert t[span.k0] == pytest.approx(5.0, abs=0.011) and "airborne samples outside it left out" in span.note
    f = np.tile([0.0, 0.0, -G0], (t.size, 1))
    f[700:710] = [0, 0, -6 * G0]                      # a crash at 7 s
    span = flight_from_imu(t, f, running, "f")
    assert t[span.k0] == pytest.approx(1.51) and t[span.k1] == pytest.approx(6.99 - 0.0, abs=0.011)
    assert "impact" in span.note and np.isnan(span.rest_height)
    with pytest.raises(GreyboxInputError, match="motors never run"):
        flight_from_imu(t, f, np.zeros(t.size, bool), "f")


# ---------------------------------------------------------------------------------- PX4

def _synthetic_px4(n=4000, rate=250.0, rpm=False):
    """A PX4 quad flight as pyulog gives it: rest 2 s, climb to 2 m, hover, land."""
    ts = (1e6 + np.arange(n) * 1e6 / rate).astype(np.uint64)
    t = (ts - ts[0]) / 1e6
    up = np.clip((t - 2.0) / 2.0, 0, 1) * np.clip((14.0 - t) / 2.0, 0, 1) * 2.0
    running = (t > 1.0) & (t < 15.0)
    roll = 0.1 * np.sin(t)
    q = np.column_stack([np.cos(roll / 2), np.sin(roll / 2), 0 * t, 0 * t])
    sc = {"timestamp": ts, "accelerometer_timestamp_relative": np.zeros(n, np.int32)}
    for i in range(3):
        sc[f"gyro_rad[{i}]"] = (0.1 * np.cos(t)) if i == 0 else 0 * t
    sc["accelerometer_m_s2[0]"], sc["accelerometer_m_s2[1]"] = 0 * t, G0 * np.sin(roll)
    sc["accelerometer_m_s2[2]"] = -G0 * np.cos(roll)
    va = {"timestamp": ts[::3], **{f"q[{i}]": q[::3, i] for i in range(4)}}
    k = slice(None, None, 25)
    lp = {"timestamp": ts[k], "x": 0 * t[k], "y": 0 * t[k], "z": -up[k], "xy_valid": np.ones(t[k].size),
          "z_valid": np.ones(t[k].size)}
    k = slice(None, None, 12)
    pwm = np.where(running, 1500.0, 900.0)[k]
    ao = {"timestamp": ts[k], "noutputs": np.full(pwm.size, 8), **{f"output[{i}]": pwm if i < 4 else 0 * pwm
                                                                    for i in range(8)}}
    topics = {"sensor_combined": sc, "vehicle_attitude": va, "vehicle_local_position": lp, "actuator_outputs": ao,
              "vehicle_status": {"timestamp": ts[::250], "system_type": np.full(ts[::250].size, 2),
                                 "arming_state": np.where(running[::250], 2, 1)},
              "battery_status": {"timestamp": ts[::100], "voltage_v": np.linspace(12.4, 11.8, ts[::100].size)}}
    if rpm:
        topics["esc_status"] = {"timestamp": ts[::10], **{f"esc[{i}].esc_rpm": np.where(running[::10], 5000, 0)
                                                          for i in range(4)}}
    return topics


def test_px4_topics_flight_frames_trimming_and_motors():
    imp = import_px4_topics(_synthetic_px4(), {"PWM_DISARMED": 900.0}, "synthetic.ulg")
    log = imp.log
    assert imp.n_rotors == 4 and log.input_names == ["w1", "w2", "w3", "w4"]
    # trimmed to the airborne part: NED z negative (above the ground) throughout
    assert np.nanmax(log.output("z")) < -0.2 and imp.takeoff_time == pytest.approx(2.2, abs=0.1)
    assert imp.touchdown_time == pytest.approx(13.8, abs=0.1)
    # PWM 1500 us through the default map: 500 rad/s; hover speed from it
    np.testing.assert_allclose(log.inputs, 500.0)
    assert imp.hover_rotor_speed == pytest.approx(500.0) and imp.pwm_map == PX4_PWM_MAP
    # rates on the gyro's 250 Hz rows, attitude every 3rd, position every 25th
    assert log.rate("p") == pytest.approx(250, rel=0.01) and log.rate("phi") == pytest.approx(250 / 3, rel=0.02)
    assert log.rate("z") == pytest.approx(10, rel=0.02)
    k = np.isfinite(log.output("phi"))
    np.testing.assert_allclose(log.output("phi")[k], 0.1 * np.sin(log.extras["t_boot"][k] - 1.0), atol=1e-6)
    assert np.nanmean(log.output("az")) == pytest.approx(-G0, rel=0.01)
    assert 11.8 <= log.extras["vbat"].min() and log.extras["vbat"].max() <= 12.4
    assert log.extras["armed"].all()
    # actuator_outputs at 21 Hz (PX4's default profile) are slower than the rate dynamics: said
    assert any("actuator_outputs at 21 Hz" in n and "slower than the rate dynamics" in n for n in imp.notes)
    assert any("outputs 5-8 are 0 (unused)" in n for n in imp.notes), imp.notes
    # a log cut in flight has no touchdown (an audit's truncated ULog was "touchdown at 14.02 s")
    cut = {name: {k: np.asarray(v)[np.asarray(topic["timestamp"]) <= 1e6 + 10e6] for k, v in topic.items()}
           for name, topic in _synthetic_px4().items()}
    imp_cut = import_px4_topics(cut, {"PWM_DISARMED": 900.0}, "cut.ulg")
    assert any("still in the air when the log ends" in n for n in imp_cut.notes), imp_cut.notes
    assert not any("touchdown at" in n for n in imp_cut.notes)
    # ESC RPM, when reported, are the rotor speeds
    imp = import_px4_topics(_synthetic_px4(rpm=True), {"PWM_DISARMED": 900.0}, "synthetic.ulg")
    np.testing.assert_allclose(imp.log.inputs, 5000 * np.pi / 30)
    assert imp.pwm_map is None and any("esc_status RPM" in n for n in imp.notes)
    # the airframe: PX4's quad X order and spins, loads as an airframe
    text = px4_airframe_toml(1.5, imp.hover_rotor_speed, 0.25)
    import tomllib
    from greybox.airframe import airframe_from_dict
    af = airframe_from_dict(tomllib.loads(text), "px4.toml")
    np.testing.assert_allclose(np.sign(np.array(af.rotor_positions)[:, :2]), [[1, 1], [-1, -1], [1, -1], [-1, 1]])
    # PX4 quad X: 1, 2 counter-clockwise seen from above (reaction torque about +z FRD, PX4 mixer
    # yaw +1): spin +1 in greybox's convention (h = -J_r spin w e_z); the same as layout "x"
    assert [r.spin for r in af.rotors] == [1, 1, -1, -1] and af.mass == 1.5
    from greybox.airframe import rotors_for_layout
    ref = rotors_for_layout("x", 0.25)
    np.testing.assert_allclose(af.rotor_positions, [r.position for r in ref], atol=1e-6)
    assert [r.spin for r in af.rotors] == [r.spin for r in ref]
    assert af.parameters["K_T"] == pytest.approx(1.5 * 9.81 / (4 * (5000 * np.pi / 30) ** 2), rel=1e-4)


def test_px4_topics_errors():
    t = _synthetic_px4()
    with pytest.raises(GreyboxInputError, match="x.ulg: no sensor_combined or vehicle_imu"):
        import_px4_topics({k: v for k, v in t.items() if k != "sensor_combined"}, {}, "x.ulg")
    with pytest.raises(GreyboxInputError, match="no vehicle_attitude"):
        import_px4_topics({k: v for k, v in t.items() if k != "vehicle_attitude"}, {}, "x.ulg")
    with pytest.raises(GreyboxInputError, match="no actuator_outputs and no esc_status"):
        import_px4_topics({k: v for k, v in t.items() if k != "actuator_outputs"}, {}, "x.ulg")
    bad = dict(t, vehicle_status={"timestamp": t["vehicle_status"]["timestamp"],
                                  "system_type": np.full(t["vehicle_status"]["timestamp"].size, 1)})
    with pytest.raises(GreyboxInputError, match="MAV_TYPE 1 is not a multirotor"):
        import_px4_topics(bad, {}, "x.ulg")
    # one actuator_outputs sample: one clear error (was a ZeroDivisionError on its rate)
    ao = t["actuator_outputs"]
    one = dict(t, actuator_outputs={k: np.asarray(v)[:1] for k, v in ao.items()})
    with pytest.raises(GreyboxInputError, match="actuator_outputs has 1 sample"):
        import_px4_topics(one, {"PWM_DISARMED": 900.0}, "x.ulg")
    # the motor count guessed from the outputs: outputs held at a constant (a servo's 1500) or
    # holding a NaN are not motors, and the note says which are which
    outs = dict(ao)
    outs["output[4]"] = outs["output[5]"] = np.full(ao["timestamp"].size, 1500.0)
    outs["output[6]"] = np.where(np.arange(ao["timestamp"].size) == 3, np.nan, 0.0)
    no_type = {k: v for k, v in t.items() if k != "vehicle_status"}
    imp = import_px4_topics({**no_type, "actuator_outputs": outs}, {"PWM_DISARMED": 900.0}, "x.ulg")
    assert imp.n_rotors == 4
    assert any("4 motors (outputs that carry a signal)" in n and "held at 1500 (unused)" in n
               for n in imp.notes), imp.notes


@pytest.fixture(scope="module")
def px4_sample():
    pytest.importorskip("pyulog")
    if not ULG.exists():
        pytest.skip("../shared/realdata/px4 not present")
    from greybox.io import import_px4
    return import_px4(ULG, keep_ground=True)


@need_ulg
def test_px4_sample_is_a_bench_log_and_says_so():
    pytest.importorskip("pyulog")
    from greybox.io import import_px4
    with pytest.raises(GreyboxInputError, match="never leaves the ground.*never armed.*--keep-ground"):
        import_px4(ULG)


def test_px4_sample_rates_motors_frames(px4_sample):
    imp = px4_sample
    log = imp.log
    assert log.duration == pytest.approx(68.9, abs=0.2)
    assert log.rate("p") == pytest.approx(248, rel=0.02)            # sensor_combined
    assert log.rate("phi") == pytest.approx(94, rel=0.03)           # vehicle_attitude
    assert log.rate("z") == pytest.approx(9.85, rel=0.03)           # vehicle_local_position
    # a quadrotor (MAV_TYPE 2): outputs 1-4 are motors, all at PWM_DISARMED (900 us): stopped
    assert imp.n_rotors == 4 and any("outputs 5-8 are 0" in n for n in imp.notes)
    assert np.all(log.extras["pwm1"] == 900) and np.all(log.inputs == 0)
    assert not log.extras["armed"].any() and np.isnan(imp.hover_rotor_speed)
    # NED: the EKF's horizontal position is invalid all along (missing), z is ~0.1 m (down)
    assert np.isnan(log.output("x")).all() and np.isnan(log.output("y")).all()
    assert 0.05 < np.nanmedian(log.output("z")) < 0.15
    # gravity: at rest the accelerometer (FRD) reads R^T (0, 0, -g) of the logged attitude
    rest = (log.t > 10) & (log.t < 60) & np.isfinite(log.output("ax"))
    e = np.nanmedian(np.column_stack([log.output(c) for c in ("phi", "theta", "psi")])[rest], axis=0)
    f_expected = _R(e).T @ np.array([0, 0, -G0])
    f = np.array([np.nanmedian(log.output(c)[rest]) for c in ("ax", "ay", "az")])
    np.testing.assert_allclose(f, f_expected, atol=0.25)
    assert f[2] < -9.0


def _integrate_gyro(log, t0, t1, signs=(1, 1, 1)):
    """Attitude at t1 from the attitude at t0 and the gyro in between; error and change (deg)."""
    t = log.t
    g = np.column_stack([log.output(c) for c in "pqr"]) * np.array(signs)
    E = np.column_stack([log.output(c) for c in ("phi", "theta", "psi")])
    ke = np.flatnonzero(np.isfinite(E).all(1))
    ka, kb = ke[np.argmin(abs(t[ke] - t0))], ke[np.argmin(abs(t[ke] - t1))]
    R, tt = _R(E[ka]), t[ka]
    for k in np.flatnonzero((t > t[ka]) & (t <= t[kb]) & np.isfinite(g).all(1)):
        w, dt = g[k], t[k] - tt
        th = np.linalg.norm(w) * dt
        if th > 0:
            a = w / np.linalg.norm(w)
            K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            R = R @ (np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K)
        tt = t[k]
    ang = lambda A, B: math.degrees(math.acos(np.clip((np.trace(A.T @ B) - 1) / 2, -1, 1)))
    return ang(R, _R(E[kb])), ang(_R(E[ka]), _R(E[kb]))


def test_px4_sample_attitude_agrees_with_the_gyro_integral(px4_sample):
    # the vehicle is moved by hand between 2 and 6 s (gyro up to 3 rad/s)
    err, change = _integrate_gyro(px4_sample.log, 1.0, 4.0)
    assert change > 10 and err < 2.0
    # a wrong sign on any axis would not agree
    for s in ((-1, 1, 1), (1, -1, 1), (1, 1, -1)):
        assert _integrate_gyro(px4_sample.log, 1.0, 4.0, s)[0] > 3 * err


def test_px4_corrupt_truncated_and_missing_pyulog(tmp_path, capsys, monkeypatch):
    pytest.importorskip("pyulog")
    from greybox.io import import_px4
    junk = tmp_path / "junk.ulg"
    junk.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(GreyboxInputError, match="junk.ulg: not a readable PX4 ULog file"):
        import_px4(junk)
    with pytest.raises(GreyboxInputError, match="is a folder; give the .ulg file"):
        import_px4(tmp_path)
    if ULG.exists():
        short = tmp_path / "short.ulg"
        short.write_bytes(ULG.read_bytes()[:2000])          # header and formats only
        with pytest.raises(GreyboxInputError, match="short.ulg: no sensor_combined or vehicle_imu"):
            import_px4(short)
        # cut in the middle (a partial copy): pyulog reads it without a word; the import says so
        from greybox.io.px4 import read_px4_topics, ulog_cut_at
        half = tmp_path / "half.ulg"
        whole = ULG.read_bytes()
        half.write_bytes(whole[:len(whole) // 2])
        assert ulog_cut_at(ULG) is None
        size, end = ulog_cut_at(half)
        assert size == len(whole) // 2 < end
        assert any("the file ends inside a message" in n for n in read_px4_topics(half)[2])
        assert not any("ends inside" in n for n in read_px4_topics(ULG)[2])
        # appended data (flag bits' appended_offsets, ULog format): the main part may stop inside
        # a message by design; only the last appended part must end with the file
        import struct
        msgs, pos = [], 16
        while pos + 3 <= len(whole):
            size = struct.unpack("<H", whole[pos:pos + 2])[0]
            msgs.append((pos, size, chr(whole[pos + 2])))
            pos += 3 + size
        cut = msgs[len(msgs) // 2][0] + 10                 # inside a message
        appended = b"".join(whole[p:p + 3 + n] for p, n, kind in msgs if kind == "A") + \
            b"".join(whole[p:p + 3 + n] for p, n, kind in msgs[len(msgs) // 2 + 1:len(msgs) // 2 + 300] if kind == "D")
        flag_bits = struct.pack("<HB", 40, ord("B")) + bytes(8) + bytes([1]) + bytes(7) + \
            struct.pack("<3Q", 16 + 43 + cut - 16, 0, 0)
        with_appended = tmp_path / "appended.ulg"
        with_appended.write_bytes(whole[:16] + flag_bits + whole[16:cut] + appended)
        assert ulog_cut_at(with_appended) is None
        with_appended.write_bytes(whole[:16] + flag_bits + whole[16:cut] + appended[:-7])
        assert ulog_cut_at(with_appended) is not None
    out = tmp_path / "o.csv"
    assert main(["import", "px4", str(junk), "--out", str(out)]) == 2 and not out.exists()
    assert "not a readable PX4 ULog" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "pyulog", None)          # as if it were not installed
    assert main(["import", "px4", str(junk), "--out", str(out)]) == 2
    assert "pip install 'greybox[px4]'" in capsys.readouterr().err


@need_ulg
def test_cli_px4_sample_with_airframe(tmp_path, capsys):
    pytest.importorskip("pyulog")
    out, af = tmp_path / "px4.csv", tmp_path / "px4.toml"
    assert main(["import", "px4", str(ULG), "--out", str(out), "--airframe-out", str(af)]) == 2
    assert "--airframe-out needs --mass" in capsys.readouterr().err
    assert main(["import", "px4", str(ULG), "--out", str(out), "--keep-ground", "--airframe-out", str(af),
                 "--mass", "1.4", "--pwm-map", "0.9,-850"]) == 0
    log = load_log(out)
    assert log.input_names == ["w1", "w2", "w3", "w4"] and log.output_names[-3:] == ["ax", "ay", "az"]
    a = load_airframe(af)
    assert a.mass == 1.4 and [r.spin for r in a.rotors] == [1, 1, -1, -1]
    # the log in memory is the one its CSV loads as: the sample's dropouts (up to 61 ms in a
    # 4-ms log) filled with held-input rows in both
    from greybox.io import import_px4
    imp = import_px4(ULG, keep_ground=True, pwm_map=(0.9, -850))
    mem = imp.log
    assert any("gap(s) longer than 3 median steps" in n for n in imp.notes)    # printed by the CLI
    assert len(mem) == len(log) > 17079 and np.allclose(mem.t, log.t, rtol=0, atol=1e-6)
    assert np.diff(mem.t).max() < 3.01 * np.median(np.diff(mem.t))
    assert any("gap(s) longer than 3 median steps" in n for n in mem.notes)
    assert a.parameters["K_T"] == pytest.approx(1.4 * 9.81 / (4 * (0.9 * 1500 - 850) ** 2), rel=1e-4)


# ------------------------------------------------------------------------- Crazyflie uSD

def _usd_bytes(version=2, records=None, events=None, crc=True):
    """A uSD log written by hand (the format of the module doc)."""
    events = events or {0xFFFF: ("fixedFrequency", [("acc.x", "f"), ("acc.y", "f"), ("acc.z", "f"),
                                                   ("gyro.x", "f"), ("gyro.y", "f"), ("gyro.z", "f"),
                                                   ("motor.m1", "I"), ("motor.m2", "I"), ("motor.m3", "I"),
                                                   ("motor.m4", "I")])}
    b = bytearray([0xBC]) + struct.pack("<HH", version, len(events))
    for ev_id, (name, vars_) in events.items():
        b += struct.pack("<H", ev_id) + name.encode() + b"\0" + struct.pack("<H", len(vars_))
        for vn, ty in vars_:
            b += f"{vn}({ty})".encode() + b"\0"
    for ev_id, ts, vals in records:
        fmt = "<" + "".join(ty for _, ty in events[ev_id][1])
        b += struct.pack("<HI" if version == 1 else "<HQ", ev_id, ts) + struct.pack(fmt, *vals)
    b += struct.pack("<I", zlib.crc32(bytes(b)) if crc else 0)
    return bytes(b)


def _usd_flight(n=3000, dt_us=1000):
    recs = []
    for k in range(n):
        run = 500 <= k < 2500
        m = 40000 + 2 * (k // 2) % 7 if run else 0          # changes every 2nd record: held samples
        g = 1.0 + 0.001 * k                                  # every gyro sample fresh
        recs.append((0xFFFF, 10_000_000 + k * dt_us, (0.0, 0.0, 1.0, 10.0 * g, 20.0 * g, 30.0 * g, m, m, m, m)))
    return recs


def test_usd_reader_and_import_by_hand(tmp_path):
    p = tmp_path / "log00"
    p.write_bytes(_usd_bytes(records=_usd_flight()))
    usd = read_usd_log(p)
    assert usd.version == 2 and usd.crc_ok and len(usd.events["fixedFrequency"]["gyro.x"]) == 3000
    imp = import_crazyflie_usd(p)
    log = imp.log
    assert len(log) == 2000 and log.t[0] == 0 and log.rate("p") == pytest.approx(1000, rel=1e-6)
    # deg/s FLU -> rad/s FRD; g FLU -> m/s^2 FRD
    np.testing.assert_allclose(log.outputs[0, 6:9], np.radians([10, -20, -30]) * 1.5)      # record 500
    np.testing.assert_allclose([log.output(c)[0] for c in ("ax", "ay", "az")], [0, 0, -G0])
    assert np.isnan(log.outputs[:, :6]).all()
    assert log.output_names[6:] == ["p", "q", "r", "ax", "ay", "az"]
    assert log.extras["pwm1"][0] == 40003 and log.inputs[0, 0] == pytest.approx(0.04076521 * 40003 + 380.8359)
    assert any("50% of rows fresh" in n for n in imp.notes)
    # version 1 (ms stamps, uint32) and several event types: a 100 Hz position event
    ev = {1: ("imu", [("gyro.x", "f"), ("gyro.y", "f"), ("gyro.z", "f"), ("acc.x", "f"), ("acc.y", "f"),
                      ("acc.z", "f"), ("motor.m1", "H"), ("motor.m2", "H"), ("motor.m3", "H"), ("motor.m4", "H")]),
          2: ("pose", [("stateEstimate.x", "f"), ("stateEstimate.y", "f"), ("stateEstimate.z", "f")])}
    recs = []
    for k in range(600):
        m = 30000 if 100 <= k < 500 else 0
        recs.append((1, 1000 + 2 * k, (0.001 * k, 0.0, 0.0, 0.0, 0.0, 1.0, m, m, m, m)))
        if k % 5 == 0:
            recs.append((2, 1000 + 2 * k + 1, (1.0, 2.0, 0.5 if 150 <= k < 450 else 0.0)))
    p1 = tmp_path / "log01"
    p1.write_bytes(_usd_bytes(1, recs, ev))
    imp = import_crazyflie_usd(p1)
    log = imp.log
    assert log.rate("p") == pytest.approx(500, rel=1e-6) and log.rate("x") == pytest.approx(100, rel=0.01)
    z = log.output("z")
    assert np.nanmax(z) == pytest.approx(-0.5) and np.nanmean(log.output("y")) == pytest.approx(-2.0)
    assert imp.takeoff_time == pytest.approx(0.3, abs=0.011)     # height at 100 Hz, interpolated


def test_usd_corrupt_and_truncated_files(tmp_path, capsys):
    good = _usd_bytes(records=_usd_flight())
    cases = {"trunc": good[:len(good) // 2], "crc": good[:-4] + b"\0\0\0\0", "magic": b"\x55" + good[1:],
             "tiny": good[:6], "version": good[:1] + struct.pack("<H", 7) + good[3:]}
    msgs = {"trunc": "CRC-32 mismatch.*truncated or corrupt", "crc": "CRC-32 mismatch",
            "magic": "not a Crazyflie uSD log", "tiny": "6 bytes: too short", "version": "uSD log format version 7 is not supported"}
    for name, data in cases.items():
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(GreyboxInputError, match=f"{name}: {msgs[name]}"):
            import_crazyflie_usd(p)
    # a log cut short (1500 of 3000 records, motors from record 500): its whole records are kept on request
    imp = import_crazyflie_usd(tmp_path / "trunc", strict=False)
    assert 990 <= len(imp.log) < 1000 and any("CRC-32 mismatch" in n for n in imp.notes)
    # a record with an unknown event id
    bad = bytearray(good)
    hdr = len(good) - 4 - 3000 * 50
    bad[hdr + 50 * 10: hdr + 50 * 10 + 2] = b"\x07\x00"
    bad[-4:] = struct.pack("<I", zlib.crc32(bytes(bad[:-4])))
    (tmp_path / "evid").write_bytes(bytes(bad))
    with pytest.raises(GreyboxInputError, match="record 11 .* event id 7"):
        import_crazyflie_usd(tmp_path / "evid")
    # no motors logged
    ev = {1: ("imu", [("gyro.x", "f"), ("gyro.y", "f"), ("gyro.z", "f")])}
    (tmp_path / "nomotor").write_bytes(_usd_bytes(2, [(1, k, (0.0, 0.0, 0.0)) for k in range(100)], ev))
    with pytest.raises(GreyboxInputError, match="no motor commands motor.m1"):
        import_crazyflie_usd(tmp_path / "nomotor")
    out = tmp_path / "o.csv"
    assert main(["import", "crazyflie-usd", str(tmp_path / "crc"), "--out", str(out)]) == 2 and not out.exists()
    assert "CRC-32 mismatch" in capsys.readouterr().err
    assert main(["import", "crazyflie-usd", str(tmp_path / "crc"), "--out", str(out), "--ignore-crc"]) == 0


@pytest.fixture(scope="module")
def usd_log10():
    if not USD.exists():
        pytest.skip("../shared/realdata/crazyflie_usd not present")
    return import_crazyflie_usd(USD), import_crazyflie_usd(USD, keep_ground=True)


def test_usd_log10(usd_log10):
    imp, whole = usd_log10
    # the whole file: 1 kHz over ~50 s
    assert whole.log.duration == pytest.approx(50.0, abs=0.1)
    assert whole.log.rate("p") == pytest.approx(1011, rel=0.01)
    # at rest before the motors start (level, still): specific force ~ -g along body z (FRD)
    rest = whole.log.t < 4.5
    assert np.mean(whole.log.output("az")[rest]) == pytest.approx(-9.81, abs=0.05)
    assert abs(np.mean(whole.log.output("ax")[rest])) < 0.3 and abs(np.mean(whole.log.output("ay")[rest])) < 0.3
    assert np.max(np.linalg.norm(np.column_stack([whole.log.output(c)[rest] for c in "pqr"]), axis=1)) < 0.05
    # the flight: motors start at 5.11 s, an impact (crash) at 42.69 s ends it
    assert imp.takeoff_time == pytest.approx(5.11, abs=0.01) and imp.touchdown_time == pytest.approx(42.68, abs=0.01)
    assert any("impact" in n for n in imp.notes) and any("motors stop 9 time" in n for n in imp.notes)
    log = imp.log
    assert np.isnan(log.outputs[:, :6]).all()
    gyro = np.column_stack([log.output(c) for c in "pqr"])
    assert 0.3 < np.sqrt(np.nanmean(gyro ** 2)) < 5 and np.nanmax(np.abs(gyro)) < 35   # rad/s (2000 deg/s range)
    # rotor speeds of a flying Crazyflie: 0 (commanded off) or mostly ~1400-2700 rad/s, hover ~2100
    w = log.inputs[log.inputs > 0]
    assert 380 < w.min() and 1000 < np.percentile(w, 1) and w.max() < 3100
    assert 1900 < imp.hover_rotor_speed < 2400
    # specific force in flight: thrust along body -z, about 1 g on average
    assert np.nanmean(log.output("az")) == pytest.approx(-9.8, rel=0.15)


def test_cli_usd_writes_a_log_load_log_reads(usd_log10, tmp_path):
    out, af = tmp_path / "usd.csv", tmp_path / "cf.toml"
    assert main(["import", "crazyflie-usd", str(USD), "--out", str(out), "--airframe-out", str(af)]) == 0
    log = load_log(out)        # x..psi are columns, all empty
    assert log.output_names == ["x", "y", "z", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az"]
    assert np.isnan(log.outputs[:, :6]).all() and np.isfinite(log.outputs[:, 6:]).mean() > 0.99
    a = load_airframe(af)
    assert a.mass == pytest.approx(0.030) and [r.spin for r in a.rotors] == [1, -1, 1, -1]


def test_px4_position_setpoints_become_the_logs_setpoints_for_a_closed_loop_model():
    """``vehicle_local_position_setpoint`` (x, y, z, yaw; NED, rad) or the newer
    ``trajectory_setpoint`` (position[0..2], yaw) become ``x_ref .. psi_ref`` on the rows,
    interpolated, yaw unwrapped across ±pi; samples with a NaN component (a velocity or manual
    mode) are left out, and a log with none complete has no setpoints and says so."""
    from greybox.controller_law import has_setpoints
    topics = _synthetic_px4()
    ts = topics["vehicle_local_position"]["timestamp"]
    t = (ts - ts[0]) / 1e6
    yaw = 3.0 + 0.02 * t                       # crosses pi at t = 7.08 s: wrapped as PX4 logs it
    sp = {"timestamp": ts, "x": 0.5 + 0 * t, "y": -0.2 + 0 * t, "z": -np.clip((t - 2.0) / 2.0, 0, 1) * 2.0,
          "yaw": np.angle(np.exp(1j * yaw))}
    sp["x"][:3] = np.nan                       # not yet in position control
    imp = import_px4_topics({**topics, "vehicle_local_position_setpoint": sp}, {"PWM_DISARMED": 900.0}, "s.ulg")
    log = imp.log
    assert has_setpoints(log)
    np.testing.assert_allclose(log.extras["x_ref"], 0.5)
    np.testing.assert_allclose(log.extras["y_ref"], -0.2)
    tb = log.extras["t_boot"] - 1.0
    np.testing.assert_allclose(log.extras["psi_ref"], 3.0 + 0.02 * tb, atol=1e-3)    # unwrapped, no 2 pi jump
    assert np.nanmax(np.abs(np.diff(log.extras["psi_ref"]))) < 0.01
    assert any("setpoints from vehicle_local_position_setpoint" in n for n in imp.notes)
    # the newer topic's field names
    new = {"timestamp": ts, "position[0]": sp["x"], "position[1]": sp["y"], "position[2]": sp["z"], "yaw": sp["yaw"]}
    imp2 = import_px4_topics({**topics, "trajectory_setpoint": new}, {"PWM_DISARMED": 900.0}, "s.ulg")
    np.testing.assert_allclose(imp2.log.extras["z_ref"], log.extras["z_ref"])
    # velocity control only: no position target anywhere
    vel = {**sp, "x": np.full(t.size, np.nan)}
    imp3 = import_px4_topics({**topics, "vehicle_local_position_setpoint": vel}, {"PWM_DISARMED": 900.0}, "s.ulg")
    assert not has_setpoints(imp3.log) and any("no closed-loop model" in n for n in imp3.notes)
    assert not has_setpoints(import_px4_topics(topics, {"PWM_DISARMED": 900.0}, "s.ulg").log)

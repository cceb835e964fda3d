"""NanoBench logs (Crazyflie 2.1, Vicon + onboard logs on a 100 Hz grid; see the data set's
own README and arXiv 2603.09908) as flight logs (README, "Flight log (CSV)").

Built on the shared parts in :mod:`greybox.io.base`:

* **Frames.** NanoBench's world is z-up (x, y, z) and its body frame FLU. Both become
  NED / FRD by a rotation of pi about x: ``x, -y, -z``; ZYX Euler angles
  ``phi, -theta, -psi``; body rates ``p, -q, -r``; specific force ``ax, -ay, -az``.
* **Attitude** comes from the Vicon quaternion (unambiguous). The ``roll, pitch, yaw``
  columns are documented as degrees; their unit is checked against the quaternion and a
  note says which it was (in the published files they are radians).
* **Time** becomes seconds from the first kept sample; the Unix time is kept as ``t_unix``.
* **Rotor speed** from PWM through an affine map ``w = a*PWM + c`` (default the published
  Crazyflie 2.0 map, Förster 2015: a = 0.04076521, c = 380.8359); PWM 0 (motor off) gives
  0. The map is configurable, and its offset can be fitted as a model parameter with the
  ``rotor_map`` effect (its slope is absorbed by ``K_T`` and ``b``).
* **Held samples.** Motor commands arrive at 80-88 Hz; where a log holds them on its grid
  (exact repeats while the motors run; the published files turn out to carry fractional,
  already interpolated PWM instead, which the import notes). By
  default the commands are linearly interpolated between fresh samples (``held="interpolate"``:
  a held value is stale by up to one grid step, interpolation removes most of that
  timing error); ``held="hold"`` keeps them as logged. A ``motor_fresh`` column (1/0)
  marks fresh samples. Measurements repeated exactly from the previous row (a held
  Vicon pose or gyro sample) become missing values (NaN) rather than false measurements.
* **Ground contact.** The resting height is the median height over the first samples
  (motors off); the vehicle is airborne while more than ``takeoff_height`` above it. The
  log is trimmed to the span from take-off to touchdown (the model has no ground reaction
  force); ``keep_ground=True`` keeps everything. An ``on_ground`` column (1/0) flags contact.
* **Battery voltage** ``pwr_pm_vbat`` (held at about 10 Hz) is interpolated between fresh
  samples and kept as the ``vbat`` column, the signal the ``battery_voltage`` effect reads.
* **Setpoints** ``sp_ctrltarget_x, _y, _z`` (m, the Vicon's world) and ``sp_ctrltarget_yaw``
  (degrees, as the firmware logs it) become ``x_ref, y_ref, z_ref`` (NED) and ``psi_ref``
  (rad), the columns a closed-loop model reads (:mod:`greybox.controller_law`).
* The IMU specific force becomes the accelerometer channels ``ax, ay, az`` (m/s^2, FRD),
  fitted like any output (it measures thrust and drag directly; see
  ``experiments/real_crazyflie.py``).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..data import read_csv_table
from ..errors import GreyboxInputError
from .base import (CRAZYFLIE_PWM_MAP, G0, ImportResult, PwmMap, check_crazyflie_pwm_scale, trimmed_log, commands_on_grid,
                   euler_from_quaternion, euler_zup_to_ned, flight_from_height, flu_to_frd, fresh_rows,
                   interpolate_fresh, setpoint_extras, time_base, wrap_angle, zup_to_ned)

__all__ = ["import_nanobench", "angle_unit_from_motion", "ANGLE_UNIT_SLOPE", "ANGLE_UNIT_MIN_CORRELATION",
           "NanoBenchImport", "crazyflie_airframe_toml", "PWM_MAX"]

NanoBenchImport = ImportResult
"""The result of :func:`import_nanobench` (the shared :class:`~greybox.io.base.ImportResult`)."""

PWM_MAX = 65535.0

_MOTORS = [f"motor_motor_m{i}" for i in range(1, 5)]
_POSITION = ["px", "py", "pz"]
_QUATERNION = ["qx", "qy", "qz", "qw"]
_EULER = ["roll", "pitch", "yaw"]
_GYRO = ["imu_gyro_x", "imu_gyro_y", "imu_gyro_z"]
_ACC = ["imu_acc_x", "imu_acc_y", "imu_acc_z"]
_VBAT = "pwr_pm_vbat"
_SETPOINT = ["sp_ctrltarget_x", "sp_ctrltarget_y", "sp_ctrltarget_z", "sp_ctrltarget_yaw"]


ANGLE_UNIT_SLOPE = (1 / 3, 3.0)
"""Without a quaternion the roll/pitch/yaw columns' unit is read from the motion: the
positions' horizontal acceleration regressed on ``g R_z(yaw) (pitch, -roll)`` (what a tilt
does to a multirotor) has a slope of about 1 when the angles are read in their unit (0.77-1.21
on the ten published flights read as radians) and a strong correlation; read in the other
unit the yaw turns the tilt the wrong way and the slope is 57 times off. A unit is taken when
its slope lies in this range and its correlation reaches :data:`ANGLE_UNIT_MIN_CORRELATION`,
the other's does not."""
ANGLE_UNIT_MIN_CORRELATION = 0.5
ANGLE_UNIT_SMOOTHING = 15
"""Samples of the moving mean on positions and angles before the acceleration is taken
(90 ms at 100 Hz: the positions' noise twice differentiated)."""


def angle_unit_from_motion(t: np.ndarray, positions: np.ndarray, angles: np.ndarray,
                           gravity: float = 9.81) -> tuple[str | None, dict[str, tuple[float, float]]]:
    """``("rad" | "deg" | None, {unit: (slope, correlation)})``: the unit of a multirotor's
    logged ``angles`` (n, 3: roll, pitch, yaw; FLU body, z-up world) from its ``positions``
    (n, 3, z up): a tilt accelerates it by about ``g`` times the tilt, in the direction the yaw
    gives (:data:`ANGLE_UNIT_SLOPE`). Airborne rows only, each stretch between missing samples
    on its own. None when neither unit, or both, explain the motion (a hover whose tilt is
    noise, positions in another unit)."""
    ok = np.isfinite(positions).all(1) & np.isfinite(angles).all(1)
    k = ANGLE_UNIT_SMOOTHING
    acc_rows, vel_rows, tilt_rows = [], [], {"rad": [], "deg": []}
    breaks = np.flatnonzero(np.diff(ok.astype(int)) != 0) + 1
    for seg in np.split(np.arange(t.size), breaks):
        if not ok[seg[0]] or seg.size < 4 * k:
            continue
        tt, pos, ang = t[seg], positions[seg], angles[seg]
        kern = np.ones(k) / k
        smooth = np.column_stack([np.convolve(pos[:, i], kern, mode="same") for i in range(3)])
        vel = np.column_stack([np.gradient(smooth[:, i], tt) for i in range(3)])
        acc = np.column_stack([np.gradient(vel[:, i], tt) for i in range(3)])
        thrust = gravity + acc[:, 2]        # per unit mass, along the body axis (z up): g at hover
        vel, acc = vel[:, :2], acc[:, :2]
        air = pos[:, 2] > np.min(positions[ok, 2]) + 0.05
        air[:k], air[-k:] = False, False
        if not air.any():
            continue
        acc_rows.append(acc[air])
        vel_rows.append(vel[air])
        for unit, scale in (("rad", 1.0), ("deg", np.pi / 180.0)):
            a = ang * scale
            roll, pitch = (np.convolve(a[:, i], kern, mode="same") for i in range(2))
            yaw = a[:, 2]
            # world z-up, body FLU: a pitch (nose down) pushes along the heading, a roll to the right
            tilt = thrust[:, None] * np.column_stack([np.cos(yaw) * pitch + np.sin(yaw) * roll,
                                                      np.sin(yaw) * pitch - np.cos(yaw) * roll])
            tilt_rows[unit].append(tilt[air])
    fits: dict[str, tuple[float, float]] = {}
    if not acc_rows or sum(len(a) for a in acc_rows) < 50:
        return None, fits
    acc, vel = np.concatenate(acc_rows), np.concatenate(vel_rows)
    for unit, rows in tilt_rows.items():
        tilt = np.concatenate(rows)
        # a = slope * g R(yaw) tilt - drag * v + offsets (the level's, a wind's): at a steady
        # speed the tilt holds the drag and nothing accelerates (a ramp flown at constant speeds)
        x, v, y = (tilt - tilt.mean(0)).ravel(), (vel - vel.mean(0)).ravel(), (acc - acc.mean(0)).ravel()
        A = np.column_stack([x, v])
        if not float(x @ x) > 0 or np.linalg.matrix_rank(A) < 2:
            fits[unit] = (float("nan"), float("nan"))
            continue
        (slope, drag), *_ = np.linalg.lstsq(A, y, rcond=None)
        y_tilt = y - drag * v                                  # what the tilt is to explain
        r = float(x @ y_tilt) / math.sqrt(float(x @ x) * float(y_tilt @ y_tilt)) if y_tilt @ y_tilt > 0 else 0.0
        fits[unit] = (float(slope), r)
    good = [u for u, (slope, r) in fits.items()
            if ANGLE_UNIT_SLOPE[0] <= slope <= ANGLE_UNIT_SLOPE[1] and r >= ANGLE_UNIT_MIN_CORRELATION]
    return (good[0] if len(good) == 1 else None), fits


def import_nanobench(path: str | Path, pwm_map: tuple[float, float] = CRAZYFLIE_PWM_MAP,
                     held: str = "interpolate", keep_ground: bool = False,
                     takeoff_height: float = 0.01, angle_unit: str = "auto") -> ImportResult:
    """Convert a NanoBench CSV (Crazyflie 2.1) into a flight log (see module doc).

    Args:
        pwm_map: ``(a, c)`` of ``w = a*PWM + c``.
        held: ``"interpolate"`` (default) or ``"hold"`` for the held motor samples.
        keep_ground: keep the samples on the ground before take-off and after touchdown.
        takeoff_height: height above the resting height (m) above which it is airborne.
        angle_unit: the roll/pitch/yaw columns' unit where there is no quaternion: ``"auto"``
            (read from the motion, :func:`angle_unit_from_motion`), ``"rad"`` or ``"deg"``.

    Raises:
        GreyboxInputError: naming the file, row and column of the first problem.
    """
    path = Path(path)
    if held not in ("interpolate", "hold"):
        raise GreyboxInputError(f"held must be 'interpolate' or 'hold', got {held!r}")
    if angle_unit not in ("auto", "rad", "deg"):
        raise GreyboxInputError(f"angle unit must be 'auto', 'rad' or 'deg', got {angle_unit!r}")
    rotor = PwmMap(*(float(v) for v in pwm_map))
    header, data = read_csv_table(path)
    col = {h: j for j, h in enumerate(header)}
    has_quat = all(h in col for h in _QUATERNION)
    need = ["t"] + _POSITION + _MOTORS + ([] if has_quat else _EULER)
    for name in need:
        if name not in col:
            hint = " (or the quaternion qx,qy,qz,qw)" if name in _EULER else ""
            raise GreyboxInputError(f"{path}: missing required column {name!r}{hint}: not a NanoBench log?")
    if data.shape[0] < 20:
        raise GreyboxInputError(f"{path}: only {data.shape[0]} data rows, too short to import")

    def column(name: str, required: bool = True) -> np.ndarray:
        v = data[:, col[name]]
        if required:
            bad = np.flatnonzero(np.isnan(v))
            if bad.size:
                raise GreyboxInputError(f"{path}: row {bad[0] + 2}, column {name!r}: missing value")
        return v

    notes: list[str] = []
    t_unix = column("t")
    t_all = time_base(t_unix, str(path), label=lambda k: f"row {k + 2}, column 't'", what="row")

    pwm = np.column_stack([column(m) for m in _MOTORS])
    out = np.argwhere((pwm < 0) | (pwm > PWM_MAX))
    if out.size:
        r, j = out[0]
        raise GreyboxInputError(f"{path}: row {r + 2}, column {_MOTORS[j]!r}: PWM {pwm[r, j]:g} outside "
                                f"0..{PWM_MAX:g}")
    motor_fresh = fresh_rows(pwm)
    if held == "interpolate":
        # between fresh samples; a motor that is off stays off (PWM 0 is never interpolated)
        pwm_used = commands_on_grid(t_all, t_all[motor_fresh], pwm[motor_fresh], "interpolate", off=0.0,
                                    repeated_between=True)
    else:
        pwm_used = pwm
    w = rotor(pwm_used)
    running = np.any(pwm > 0, axis=1)
    frac = float(motor_fresh[running].mean()) if running.any() else 1.0
    dt_med = float(np.median(np.diff(t_all)))
    if frac > 0.995:
        notes.append("motor commands: no held (repeated) samples while the motors run"
                     + ("; PWM values are fractional, i.e. already interpolated onto the log's grid"
                        if np.any(pwm[running] % 1 != 0) else ""))
    else:
        notes.append(f"motor commands: {frac:.0%} of rows fresh while the motors run "
                     f"({frac / dt_med:.0f} Hz); held rows "
                     + ("interpolated between fresh samples" if held == "interpolate" else "kept as logged"))

    pos = np.column_stack([column(n, required=False) for n in _POSITION])
    if has_quat:
        q = np.column_stack([column(n, required=False) for n in _QUATERNION])
        norm = np.linalg.norm(q, axis=1)
        badq = np.flatnonzero(np.isfinite(norm) & (np.abs(norm - 1) > 0.05))
        if badq.size:
            raise GreyboxInputError(f"{path}: row {badq[0] + 2}, columns qx..qw: quaternion norm "
                                    f"{norm[badq[0]]:.3f} is not 1")
        eul_flu = euler_from_quaternion(q / norm[:, None])
        if all(h in col for h in _EULER):
            logged = np.column_stack([data[:, col[n]] for n in _EULER])
            ok = np.isfinite(logged).all(1) & np.isfinite(eul_flu).all(1)
            if ok.any():
                err_rad = np.nanmedian(np.abs(wrap_angle(logged[ok] - eul_flu[ok])))
                err_deg = np.nanmedian(np.abs(wrap_angle(np.radians(logged[ok]) - eul_flu[ok])))
                unit = "radians" if err_rad < err_deg else "degrees"
                notes.append(f"attitude from the quaternion; the roll/pitch/yaw columns agree with it "
                             f"in {unit}" + (" (documented as degrees)" if unit == "radians" else ""))
        pose_block = np.column_stack([pos, q])
    else:
        logged = np.column_stack([column(n, required=False) for n in _EULER])
        # the motion is read even when the unit is given: a unit it contradicts is said
        told, fits = angle_unit_from_motion(t_all, pos, logged)
        unit = told if angle_unit == "auto" else angle_unit
        said = "; ".join(f"read as {'radians' if u == 'rad' else 'degrees'}: slope {sl:.3g}, correlation {r:.2f}"
                         for u, (sl, r) in fits.items())
        if unit is None:
            raise GreyboxInputError(
                f"{path}: no quaternion columns, and the motion does not tell whether roll/pitch/yaw are in "
                f"degrees or radians (the horizontal acceleration against g times the tilt, {said or 'too few rows'}; "
                "the unit's slope is about 1 with a strong correlation); give the unit: angle_unit='rad' or 'deg' "
                "(greybox import nanobench --angle-unit)")
        eul_flu = np.radians(logged) if unit == "deg" else logged
        words = {"deg": "degrees", "rad": "radians"}
        notes.append("no quaternion columns: attitude from roll/pitch/yaw, in " + words[unit]
                     + (f" (the motion says so: {said})" if angle_unit == "auto" else
                        f" (as given, though the motion says {words[told]}: {said}; check the unit)"
                        if told is not None and told != unit else " (as given)"))
        pose_block = np.column_stack([pos, eul_flu])
    pose_fresh = fresh_rows(np.nan_to_num(pose_block, nan=1e300))
    n_held_pose = int((~pose_fresh).sum())

    # world z-up -> NED and body FLU -> FRD: rotation of pi about x
    ned = zup_to_ned(pos)
    eul = euler_zup_to_ned(eul_flu)
    outputs: dict[str, np.ndarray] = {}
    for j, name in enumerate(["x", "y", "z"]):
        outputs[name] = np.where(pose_fresh, ned[:, j], np.nan)
    for j, name in enumerate(["phi", "theta", "psi"]):
        outputs[name] = np.where(pose_fresh, eul[:, j], np.nan)
    if all(h in col for h in _GYRO):
        gyro = np.column_stack([column(n, required=False) for n in _GYRO])
        # unit check: body rates from the attitude must match the gyro in rad/s
        ang = np.unwrap(eul_flu, axis=0)
        rates = np.gradient(ang, t_all, axis=0)
        ok = np.isfinite(rates).all(1) & np.isfinite(gyro).all(1)
        if ok.sum() > 20:
            ratio = np.std(gyro[ok, :2]) / max(np.std(rates[ok, :2]), 1e-12)
            if ratio > 20:
                gyro = np.radians(gyro)
                notes.append(f"gyro columns are in deg/s (gyro/attitude-rate ratio {ratio:.0f}): converted")
        gyro_fresh = fresh_rows(np.nan_to_num(gyro, nan=1e300))
        frd = flu_to_frd(gyro)
        for j, name in enumerate(["p", "q", "r"]):
            outputs[name] = np.where(gyro_fresh, frd[:, j], np.nan)
    else:
        notes.append("no gyro columns: the log has no p, q, r")
    if n_held_pose:
        notes.append(f"{n_held_pose} held (repeated) Vicon poses set missing")

    extras: dict[str, np.ndarray] = {}
    if _VBAT in col:
        v = column(_VBAT, required=False)
        fin = np.isfinite(v)
        if not fin.any():
            raise GreyboxInputError(f"{path}: column {_VBAT!r} has no values")
        vf = fresh_rows(np.nan_to_num(v, nan=-1.0)[:, None]) & fin
        extras["vbat"] = interpolate_fresh(t_all, np.where(fin, v, 0.0), vf)
    else:
        notes.append(f"no {_VBAT!r} column: no battery voltage (the battery_voltage effect needs it)")
    if all(h in col for h in _ACC):
        acc = flu_to_frd(np.column_stack([column(n, required=False) for n in _ACC]) * G0)
        outputs["ax"], outputs["ay"], outputs["az"] = acc[:, 0], acc[:, 1], acc[:, 2]
    if all(h in col for h in _SETPOINT):
        # the controller's target: the same world as the Vicon pose, yaw in degrees (firmware)
        sp = np.column_stack([column(n, required=False) for n in _SETPOINT])
        refs = setpoint_extras(t_all, t_all, zup_to_ned(sp[:, :3]), -np.radians(sp[:, 3]))
        if refs:
            extras.update(refs)
            notes.append("setpoints sp_ctrltarget_x..yaw kept as x_ref, y_ref, z_ref (m, NED), psi_ref (rad): "
                         "what a closed-loop model reads")
        else:
            notes.append("setpoint columns sp_ctrltarget_* hold no values: no closed-loop model")
    for i in range(4):
        extras[f"pwm{i + 1}"] = pwm[:, i]
    extras["motor_fresh"] = motor_fresh.astype(float)
    extras["t_unix"] = t_unix

    # ground contact
    span = flight_from_height(t_all, pos[:, 2], np.any(pwm > 0, axis=1), str(path), takeoff_height)
    k0, k1 = span.k0, span.k1
    check_crazyflie_pwm_scale(pwm[k0:k1 + 1], f"{path}: columns {', '.join(_MOTORS)}", PWM_MAX)
    extras["on_ground"] = span.on_ground.astype(float)
    notes.append(span.note)
    hover_w = float(np.sqrt(np.mean(w[k0:k1 + 1] ** 2)))
    log = trimmed_log(t_all, w, outputs, extras, notes, str(path), k0, k1, keep_ground,
                      "trimmed {before} samples before take-off and {after} after touchdown")
    return ImportResult(log, float(t_all[k0]), float(t_all[k1]), span.rest_height, hover_w, notes,
                        format="nanobench", pwm_map=rotor.pair, n_rotors=4)


def crazyflie_airframe_toml(mass: float = 0.030, hover_rotor_speed: float | None = None,
                            ground_z: float = 0.0, name: str = "crazyflie21",
                            command: str = "nanobench") -> str:
    """Airframe TOML of a Crazyflie 2.1 (rotors in firmware order M1..M4 = w1..w4).

    ``hover_rotor_speed`` (rad/s, e.g. from :func:`import_nanobench`) sets the starting
    guess of ``K_T`` to ``m g / (4 w^2)``; ``b`` starts at Förster's torque/thrust ratio.
    ``command`` names the importer in the header comment.
    """
    g = 9.81
    a = 0.046 / np.sqrt(2.0)
    have_hover = hover_rotor_speed is not None and np.isfinite(hover_rotor_speed) and hover_rotor_speed > 0
    kt = mass * g / (4 * hover_rotor_speed ** 2) if have_hover else 1.8e-8
    return f"""# Crazyflie 2.1 (Bitcraze), written by `greybox import {command}`.
# Rotors in firmware order M1..M4 (= log columns w1..w4), positions in body FRD:
# mixer QUAD_FORMATION_X, M1 front-right, M2 back-right, M3 back-left, M4 front-left;
# M1 and M3 turn counter-clockwise seen from above, so their reaction torque on the body is
# about +z (FRD): spin +1; M2 and M4 clockwise: spin -1 (Bitcraze's Crazyflie 2.x motor
# layout; greybox: yaw torque spin_i*b*w_i^2 about body z).
# Arm: 46 mm from the centre to each motor (92 mm motor-to-motor diagonal, Bitcraze
# datasheet). Inertia: J. Förster, "System Identification of the Crazyflie 2.0 Nano
# Quadrocopter", ETH Zurich 2015. Mass: 27 g bare (Bitcraze datasheet) plus markers and
# deck; {mass * 1000:.0f} g assumed here -- K_T, b and Kd scale with it, so set the weighed value.
[airframe]
name = "{name}"
mass = {mass!r}
inertia = [1.395e-5, 1.436e-5, 2.173e-5]
arm_length = 0.046
rotor_inertia = 0.0        # unknown and tiny (about 1e-9 kg m^2); gyroscopic torque neglected
gravity = {g!r}
ground_z = {ground_z!r}    # NED z of the floor plane (ground effect height = ground_z - z)

[[rotor]]   # M1 front-right
position = [{a:.6f}, {a:.6f}, 0.0]
spin = 1

[[rotor]]   # M2 back-right
position = [{-a:.6f}, {a:.6f}, 0.0]
spin = -1

[[rotor]]   # M3 back-left
position = [{-a:.6f}, {-a:.6f}, 0.0]
spin = 1

[[rotor]]   # M4 front-left
position = [{a:.6f}, {-a:.6f}, 0.0]
spin = -1

[parameters]
K_T = {kt:.6g}             # from hover: m g / (4 w_hover^2)
b = {0.005964552 * kt:.6g}        # Förster: reaction torque / thrust = 0.005964552 m
Kd = [0.01, 0.01, 0.01]
"""

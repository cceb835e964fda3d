"""PX4 flight logs (ULog, read with ``pyulog``) as flight logs (README, "Flight log (CSV)").

Needs the optional ``pyulog`` (``pip install 'greybox[px4]'``). PX4 logs in greybox's frames
already (world NED, body FRD) and in SI units. What is read (instance 0 of each topic; the
shared parts are in :mod:`greybox.io.base`):

* ``sensor_combined`` (or ``vehicle_imu`` when it is absent): gyro -> ``p, q, r``;
  accelerometer -> output columns ``ax, ay, az`` (m/s^2, body FRD, specific force). The gyro's
  time stamps are the log's rows (about 250 Hz on most vehicles).
* ``vehicle_attitude``: the quaternion ``q`` (w, x, y, z; body FRD to NED) ->
  ``phi, theta, psi``.
* ``vehicle_local_position``: ``x, y, z`` (NED), missing where PX4 flags them invalid
  (``xy_valid``, ``z_valid``). This is the EKF's estimate, not a measurement.
* Rotor speeds: ``esc_status`` RPM when the ESCs report it (measured; ``esc[i]`` taken as
  motor ``i+1``), else ``actuator_outputs`` (PWM, µs) through ``w = a*PWM + c``
  (:data:`~greybox.io.base.PX4_PWM_MAP` by default: an assumed map, say so when you
  report). Outputs at or below the disarmed value (``PWM_DISARMED`` / ``PWM_MAIN_DIS1``) are
  stopped motors. The number of motors comes from ``CA_ROTOR_COUNT`` or the MAVLink vehicle
  type in ``vehicle_status`` (2 quadrotor, 13 hexarotor, 14 octorotor, 15 tricopter), and
  is checked against the outputs that carry a signal. Motor commands are logged at a
  lower rate than the gyro (often 10-50 Hz): between samples they are interpolated
  (``held="interpolate"``) or held (``"hold"``); ``motor_fresh`` marks rows with a sample.
* ``battery_status`` voltage -> ``vbat`` (interpolated), when present.
* Samples of the slower topics sit on the nearest gyro row (at most half a gyro period
  away), or on a row of their own when the gyro has a gap there.
* **Ground contact**: ``vehicle_land_detected`` (``landed``) when logged, else the height
  (``-z``) more than ``takeoff_height`` above its resting value with the motors running;
  the log is trimmed to the longest airborne run. A log in which the vehicle never flies
  (a bench log) is refused unless ``keep_ground=True``.
* ``t`` is seconds from the first kept row; ``t_boot`` keeps PX4's time since boot (s).

What a PX4 log does *not* hold: the vehicle's mass, inertia and geometry. Without the mass,
thrust and drag coefficients are only known relative to it (``K_T/m``, ``Kd/m``), and with
rotor speeds from an assumed PWM map only ``K_T·a²`` is identified (README, "Real flights").
"""
from __future__ import annotations

import contextlib
import io as _io
import math
from pathlib import Path
from typing import Mapping

import numpy as np

from ..errors import GreyboxInputError
from .base import (PX4_PWM_MAP, FlightSpan, ImportResult, PwmMap, trimmed_log, commands_on_grid, euler_from_quaternion,
                   flight_from_height, grid_with, interpolate_samples, longest_run, rpm_to_rad_s, setpoint_extras, snap,
                   span_words, time_base)

SLOW_ACTUATOR_HZ = 100.0
"""actuator_outputs logged more slowly than this get a note: the motors' commands change
within the attitude loop's tens of milliseconds (PX4's default logging profile: about 20 Hz)."""

__all__ = ["import_px4", "import_px4_topics", "read_px4_topics", "ulog_cut_at", "px4_airframe_toml", "PX4_TOPICS",
           "MAV_TYPE_ROTORS"]

PX4_TOPICS = ["sensor_combined", "vehicle_imu", "vehicle_attitude", "vehicle_local_position", "actuator_outputs",
              "esc_status", "battery_status", "vehicle_status", "vehicle_land_detected",
              "vehicle_local_position_setpoint", "trajectory_setpoint"]
"""The uORB topics the importer reads (others are not even parsed)."""

MAV_TYPE_ROTORS = {2: 4, 13: 6, 14: 8, 15: 3}
"""Motors of MAVLink vehicle types (``vehicle_status.system_type``): quad, hexa, octo, tri."""

_INSTALL = "pip install 'greybox[px4]'"
_INVALID_REL = 2147483647     # sensor_combined: relative time stamp of a sensor without data
_ARMED = 2                    # vehicle_status.arming_state ARMED (old and new enums)

Topics = Mapping[str, Mapping[str, np.ndarray]]


def ulog_cut_at(path: str | Path) -> tuple[int, int] | None:
    """Where a ULog file was cut inside a message: ``(file size, the message's end)``, or
    None when its messages end with the file. pyulog reads a cut file without a word (an
    audit's copy of half the sample log imported as a 34-s flight); a file cut exactly at a
    message's end cannot be told from a whole one. Message headers (ULog format): ``uint16``
    payload size, ``uint8`` type, after the 16-byte file header; a file with appended data (the
    flag bits message's ``appended_offsets``: the main part may stop inside a message, by
    design) is walked from its last appended part."""
    data = Path(path).read_bytes()
    pos, n = 16, len(data)
    if n >= 19 and data[18] == ord("B") and n >= 19 + 40:
        # flag bits: compat[8], incompat[8], appended_offsets[3] (uint64); incompat bit 0: data appended
        offsets = [int.from_bytes(data[19 + 16 + 8 * i:19 + 24 + 8 * i], "little") for i in range(3)]
        if data[19 + 8] & 1 and any(offsets):
            pos = max(o for o in offsets if o)
    while pos + 3 <= n:
        size = int.from_bytes(data[pos:pos + 2], "little")
        pos += 3 + size
    if pos == n:
        return None
    return n, pos if pos > n else n + 1       # a header itself cut (1-2 bytes left): its end is beyond


def read_px4_topics(path: str | Path) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, float], list[str]]:
    """The topics the importer needs from a ULog file (instance 0 each), its initial
    parameters and notes (other instances, dropouts, file corruption).

    Raises:
        GreyboxInputError: pyulog missing (``pip install 'greybox[px4]'``), or the file is
            not a readable ULog.
    """
    try:
        from pyulog import ULog
    except ImportError:
        raise GreyboxInputError(f"reading PX4 ULog files needs the pyulog package: {_INSTALL}") from None
    path = Path(path)
    if path.is_dir():
        raise GreyboxInputError(f"{path}: is a folder; give the .ulg file")
    if not path.is_file():
        raise GreyboxInputError(f"{path}: no such file")
    out = _io.StringIO()
    try:
        with contextlib.redirect_stdout(out):     # pyulog prints its complaints
            ulog = ULog(str(path), PX4_TOPICS)
    except Exception as e:                        # pyulog raises its own or struct/index errors
        raise GreyboxInputError(f"{path}: not a readable PX4 ULog file ({e})") from None
    notes = [f"{path}: pyulog: {line.strip()}" for line in out.getvalue().splitlines() if line.strip()]
    if getattr(ulog, "file_corruption", False) and not notes:
        notes.append(f"{path}: pyulog reports file corruption; what could be read is used")
    cut = ulog_cut_at(path)
    if cut is not None:
        notes.append(f"{path}: the file ends inside a message (byte {cut[0]} of a message reaching byte {cut[1]}): "
                     "the log was cut short (a full card, power lost, a partial copy); imported up to there")
    topics: dict[str, dict[str, np.ndarray]] = {}
    multi: dict[str, int] = {}
    for d in sorted(ulog.data_list, key=lambda d: d.multi_id):
        multi[d.name] = multi.get(d.name, 0) + 1
        if d.name not in topics:
            topics[d.name] = {k: np.asarray(v) for k, v in d.data.items()}
    for name, n in multi.items():
        if n > 1:
            notes.append(f"{name}: {n} instances logged, instance 0 used")
    drop = getattr(ulog, "dropouts", [])
    if drop:
        notes.append(f"logger dropouts: {len(drop)}, {sum(x.duration for x in drop) / 1000:.2f} s in all "
                     f"(longest {max(x.duration for x in drop)} ms)")
    info = getattr(ulog, "msg_info_dict", {}) or {}
    if info.get("ver_hw"):
        notes.append(f"hardware {info.get('ver_hw')}, {info.get('sys_name', 'PX4')} {info.get('ver_sw', '')[:10]}")
    params = {k: float(v) for k, v in (getattr(ulog, "initial_parameters", {}) or {}).items()
              if isinstance(v, (int, float))}
    return topics, params, notes


def _stamps(topic: Mapping[str, np.ndarray], name: str, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Seconds since boot of a topic's samples (``timestamp_sample`` when logged) and the
    index of the samples kept (time stamps that do not increase are dropped, with a note)."""
    key = "timestamp_sample" if "timestamp_sample" in topic else "timestamp"
    ts = np.asarray(topic[key], dtype=np.float64)
    keep = np.r_[True, ts[1:] > np.maximum.accumulate(ts)[:-1]] if ts.size else np.zeros(0, bool)
    if (~keep).any():
        notes.append(f"{name}: {int((~keep).sum())} samples with time stamps that do not increase dropped")
    idx = np.flatnonzero(keep)
    return ts[idx] * 1e-6, idx


def _field(topic: Mapping[str, np.ndarray], name: str, idx: np.ndarray) -> np.ndarray:
    return np.asarray(topic[name], dtype=float)[idx]


_SETPOINT_FIELDS = {"vehicle_local_position_setpoint": ("x", "y", "z", "yaw"),
                    "trajectory_setpoint": ("position[0]", "position[1]", "position[2]", "yaw")}
"""Where a PX4 log keeps the position controller's target (NED, m; yaw in rad), older first."""


def _setpoints(topics: Topics, t_boot: np.ndarray, notes: list[str]) -> dict[str, np.ndarray]:
    """The position controller's target as the log's ``x_ref, y_ref, z_ref, psi_ref``
    (:func:`~greybox.io.base.setpoint_extras`) from the first of :data:`_SETPOINT_FIELDS` logged
    with at least two complete samples. PX4 writes NaN in a component the controller does not hold (velocity or
    manual modes): such samples are left out, and none complete is no setpoint."""
    for topic, fields in _SETPOINT_FIELDS.items():
        sp = topics.get(topic)
        if sp is None or not len(sp.get("timestamp", [])) or not all(f in sp for f in fields):
            continue
        t_s, i_s = _stamps(sp, topic, notes)
        vals = np.column_stack([_field(sp, f, i_s) for f in fields])
        ok = np.isfinite(vals).all(axis=1)
        if ok.sum() < 2:
            notes.append(f"{topic}: no sample holds a position and yaw target (manual or velocity control): "
                         "no closed-loop model")
            return {}
        out = setpoint_extras(t_boot, t_s, vals[:, :3], vals[:, 3])
        notes.append(f"setpoints from {topic} ({', '.join(fields)}; {ok.mean():.0%} of its samples complete) kept as "
                     "x_ref, y_ref, z_ref (m, NED), psi_ref (rad): what a closed-loop model reads")
        return out
    return {}


def import_px4(path: str | Path, pwm_map: tuple[float, float] = PX4_PWM_MAP, held: str = "interpolate",
               keep_ground: bool = False, takeoff_height: float = 0.2,
               n_motors: int | None = None) -> ImportResult:
    """Convert a PX4 ULog file into a flight log (see module doc).

    Args:
        pwm_map: ``(a, c)`` of ``w = a*PWM + c`` (PWM in µs), used when the ESCs do not report RPM.
        held: ``"interpolate"`` (default) or ``"hold"`` for motor samples between log rows.
        keep_ground: keep the samples on the ground (and import a log that never flies).
        takeoff_height: m above the resting height at which the vehicle counts as airborne
            (when ``vehicle_land_detected`` is not logged).
        n_motors: number of motors (default: from the log's parameters / vehicle type).

    Raises:
        GreyboxInputError: naming the file and what is wrong with it.
    """
    topics, params, notes = read_px4_topics(path)
    return import_px4_topics(topics, params, str(path), pwm_map, held, keep_ground, takeoff_height, n_motors,
                             notes)


def import_px4_topics(topics: Topics, params: Mapping[str, float], where: str,
                      pwm_map: tuple[float, float] = PX4_PWM_MAP, held: str = "interpolate",
                      keep_ground: bool = False, takeoff_height: float = 0.2, n_motors: int | None = None,
                      notes: list[str] | None = None) -> ImportResult:
    """:func:`import_px4` on topics already read (``{topic: {field: array}}`` as pyulog
    gives them, time stamps in µs) and the log's parameters; ``where`` names the source."""
    notes = list(notes or [])
    if held not in ("interpolate", "hold"):
        raise GreyboxInputError(f"held must be 'interpolate' or 'hold', got {held!r}")
    rotor_map = PwmMap(*(float(v) for v in pwm_map))

    # --- IMU: the time base
    if "sensor_combined" in topics and len(topics["sensor_combined"].get("timestamp", [])) >= 20:
        sc = topics["sensor_combined"]
        t_g, ig = _stamps(sc, "sensor_combined", notes)
        gyro = np.column_stack([_field(sc, f"gyro_rad[{i}]", ig) for i in range(3)])
        acc = np.column_stack([_field(sc, f"accelerometer_m_s2[{i}]", ig) for i in range(3)])
        rel = _field(sc, "accelerometer_timestamp_relative", ig) if "accelerometer_timestamp_relative" in sc \
            else np.zeros(ig.size)
        ok = rel != _INVALID_REL
        t_a, acc = t_g[ok] + rel[ok] * 1e-6, acc[ok]
        imu = "sensor_combined"
    elif "vehicle_imu" in topics and len(topics["vehicle_imu"].get("timestamp", [])) >= 20:
        vi = topics["vehicle_imu"]
        t_g, ig = _stamps(vi, "vehicle_imu", notes)
        dta = np.maximum(_field(vi, "delta_angle_dt", ig), 1.0) * 1e-6
        dtv = np.maximum(_field(vi, "delta_velocity_dt", ig), 1.0) * 1e-6
        gyro = np.column_stack([_field(vi, f"delta_angle[{i}]", ig) for i in range(3)]) / dta[:, None]
        acc = np.column_stack([_field(vi, f"delta_velocity[{i}]", ig) for i in range(3)]) / dtv[:, None]
        t_a = t_g
        imu = "vehicle_imu"
        notes.append("IMU from vehicle_imu (delta angle and velocity over their intervals); no sensor_combined")
    else:
        raise GreyboxInputError(f"{where}: no sensor_combined or vehicle_imu with at least 20 samples: no gyro "
                                "(a truncated log, or not a flight log?)")
    if "vehicle_attitude" not in topics or len(topics["vehicle_attitude"].get("timestamp", [])) < 2:
        raise GreyboxInputError(f"{where}: no vehicle_attitude: no attitude (a truncated log?)")
    va = topics["vehicle_attitude"]
    t_q, iq = _stamps(va, "vehicle_attitude", notes)
    q = np.column_stack([_field(va, f"q[{i}]", iq) for i in range(4)])
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(~np.isfinite(norm) | (np.abs(norm - 1) > 0.05))
    if bad.size:
        raise GreyboxInputError(f"{where}: vehicle_attitude sample {int(iq[bad[0]]) + 1}: quaternion norm "
                                f"{norm[bad[0]]:.3f} is not 1 (corrupt?)")
    eul = euler_from_quaternion(q / norm[:, None], scalar_first=True)

    lp = topics.get("vehicle_local_position")
    if lp is not None and len(lp.get("timestamp", [])):
        t_p, ip = _stamps(lp, "vehicle_local_position", notes)
        pos = np.column_stack([_field(lp, n, ip) for n in ("x", "y", "z")])
        for flag, cols in (("xy_valid", [0, 1]), ("z_valid", [2])):
            if flag in lp:
                valid = _field(lp, flag, ip) > 0
                pos[np.ix_(~valid, cols)] = np.nan
                if not valid.all():
                    notes.append(f"vehicle_local_position: {flag} false for {(~valid).mean():.0%} of its samples "
                                 "(set missing)")
        for flag in ("xy_reset_counter", "z_reset_counter"):
            if flag in lp and np.unique(_field(lp, flag, ip)).size > 1:
                notes.append(f"vehicle_local_position: {flag} changes (the estimator reset its position)")
    else:
        t_p, pos = np.zeros(0), np.zeros((0, 3))
        notes.append("no vehicle_local_position: columns x, y, z are empty")

    t_g = time_base(t_g, where, label=lambda k: f"{imu} sample {k + 1}", what="sample", origin="given")
    t_boot = grid_with(t_g, t_q, t_p)
    t0 = t_boot[0]
    t_all = t_boot - t0
    outputs: dict[str, np.ndarray] = {}
    P = snap(t_boot, t_p, pos) if t_p.size else np.full((t_all.size, 3), np.nan)
    E = snap(t_boot, t_q, eul)
    G = snap(t_boot, t_g, gyro)
    A = snap(t_boot, t_a, acc)
    for j, n in enumerate(("x", "y", "z")):
        outputs[n] = P[:, j]
    for j, n in enumerate(("phi", "theta", "psi")):
        outputs[n] = E[:, j]
    for j, n in enumerate(("p", "q", "r")):
        outputs[n] = G[:, j]
    for j, n in enumerate(("ax", "ay", "az")):
        outputs[n] = A[:, j]
    extras: dict[str, np.ndarray] = {}

    def rate(ts: np.ndarray) -> float:
        return (ts.size - 1) / (ts[-1] - ts[0]) if ts.size > 1 and ts[-1] > ts[0] else 0.0
    notes.append(f"rates: gyro {rate(t_g):.0f} Hz ({imu}), attitude {rate(t_q):.0f} Hz, local position "
                 f"{rate(t_p):.1f} Hz; {t_all.size} rows over {t_all[-1]:.2f} s")

    # --- motors
    status = topics.get("vehicle_status", {})
    n_from, n_rot = "", None
    if n_motors is not None:
        n_rot, n_from = int(n_motors), "given"
    elif params.get("CA_ROTOR_COUNT", 0) > 0:
        n_rot, n_from = int(params["CA_ROTOR_COUNT"]), "CA_ROTOR_COUNT"
    elif "system_type" in status and len(status["system_type"]):
        mav = int(np.bincount(np.asarray(status["system_type"], dtype=int)).argmax())
        if mav in MAV_TYPE_ROTORS:
            n_rot, n_from = MAV_TYPE_ROTORS[mav], f"MAV_TYPE {mav} in vehicle_status"
        else:
            raise GreyboxInputError(f"{where}: vehicle type MAV_TYPE {mav} is not a multirotor greybox knows "
                                    "(quad, hexa, octo, tri); give the number of motors (n_motors)")
    armed = None
    if "arming_state" in status and len(status["arming_state"]):
        ts_s, i_s = _stamps(status, "vehicle_status", [])
        arm_s = _field(status, "arming_state", i_s) == _ARMED
        armed = commands_on_grid(t_boot, ts_s, arm_s.astype(float), "hold").ravel() > 0 if ts_s.size else None
    esc = topics.get("esc_status")
    ao = topics.get("actuator_outputs")
    off = params.get("PWM_DISARMED", params.get("PWM_MAIN_DIS1", math.nan))
    pwm_grid = None
    if ao is not None and len(ao.get("timestamp", [])):
        t_o, io_ = _stamps(ao, "actuator_outputs", notes)
        n_out = int(np.max(_field(ao, "noutputs", io_))) if "noutputs" in ao else \
            sum(1 for k in ao if k.startswith("output["))
        outs = np.column_stack([_field(ao, f"output[{i}]", io_) for i in range(n_out)])
        if t_o.size < 2 or not t_o[-1] > t_o[0]:
            raise GreyboxInputError(f"{where}: actuator_outputs has {t_o.size} sample(s) at one time: no motor "
                                    "commands over the flight")
        active = [i for i in range(n_out) if np.any(np.nan_to_num(outs[:, i]) != 0)]
        # an output's span over its numbers (a NaN in it is not a signal, nor a constant)
        span = [float(np.nanmax(outs[:, i]) - np.nanmin(outs[:, i])) if np.any(np.isfinite(outs[:, i])) else 0.0
                for i in range(n_out)]
        if n_rot is None:
            # outputs held at a constant (a servo's or a disarmed channel's 1500) are not motors
            moving = [i for i in active if span[i] > 0]
            n_rot, n_from = len(moving), "outputs that carry a signal"
            if n_rot not in (3, 4, 6, 8) or moving != list(range(n_rot)):
                raise GreyboxInputError(f"{where}: actuator outputs {[i + 1 for i in moving]} carry a signal; cannot "
                                        "tell which are motors: give the number of motors (n_motors)")
        if n_rot > n_out:
            raise GreyboxInputError(f"{where}: {n_rot} motors ({n_from}) but actuator_outputs has {n_out} outputs")
        silent = [i + 1 for i in range(n_rot) if i not in active]
        if silent:
            raise GreyboxInputError(f"{where}: actuator outputs {silent} (motors by {n_from}) are 0 all along: not "
                                    "the motors' outputs?")
        others = [i + 1 for i in active if i >= n_rot and span[i] > 0]
        constant = sorted({float(outs[np.isfinite(outs[:, i]), i][0]) for i in active if i >= n_rot and span[i] == 0})
        notes.append(f"{n_rot} motors ({n_from}): actuator outputs 1-{n_rot}"
                     + (f"; outputs {others} also carry a signal (not motors: ignored)" if others else "")
                     + (f"; outputs beyond {n_rot} held at {', '.join(f'{v:g}' for v in constant)} (unused)"
                        if constant else "")
                     + (f"; outputs {n_rot + 1}-{n_out} are 0 (unused)" if n_out > n_rot and not others and not constant
                        else ""))
        pwm = outs[:, :n_rot]
        nonfin = np.argwhere(~np.isfinite(pwm))
        if nonfin.size:
            r, j = nonfin[0]
            raise GreyboxInputError(f"{where}: actuator_outputs sample {int(io_[r]) + 1}, output {j + 1}: "
                                    f"{pwm[r, j]!r} is not a number")
        if not np.isfinite(off):
            off = 0.0
            notes.append("no PWM_DISARMED parameter: only output 0 counts as a stopped motor")
        run_vals = pwm[pwm > off]
        if run_vals.size and (run_vals.min() < 800 or run_vals.max() > 2200):
            notes.append(f"motor outputs range {run_vals.min():g}-{run_vals.max():g}: not PWM in µs (DShot or "
                         "normalised?); the PWM map is meaningless for them: give --pwm-map for this unit")
        pwm_grid = commands_on_grid(t_boot, t_o, pwm, "hold", off=off)
        pwm_used = commands_on_grid(t_boot, t_o, pwm, held, off=off)
        motor_fresh = np.nan_to_num(snap(t_boot, t_o, np.ones(t_o.size)))
        out_rate = rate(t_o)
        notes.append(f"actuator_outputs at {out_rate:.0f} Hz: motor commands "
                     + ("interpolated" if held == "interpolate" else "held") + " between samples"
                     # the attitude loop moves the motors within tens of ms: what they did between
                     # samples is guessed, and the rotational parameters carry it (an audit's
                     # 21-Hz log: b 9.5 of its std off, the fit inadequate)
                     + (f": slower than the rate dynamics ({1e3 / out_rate:.0f} ms between samples), so b, tau_m "
                        "and the roll/pitch torques carry what the motors did between them (log actuator_outputs "
                        "at the controller's rate: SDLOG_PROFILE's high-rate profile)"
                        if out_rate < SLOW_ACTUATOR_HZ else ""))
    elif esc is None:
        raise GreyboxInputError(f"{where}: no actuator_outputs and no esc_status: no motor commands (the model's "
                                "inputs)")
    if n_rot is None:
        raise GreyboxInputError(f"{where}: cannot tell the number of motors: give it (n_motors)")
    w = None
    used_map = None
    if esc is not None and len(esc.get("timestamp", [])) and all(f"esc[{i}].esc_rpm" in esc for i in range(n_rot)):
        t_e, ie = _stamps(esc, "esc_status", notes)
        rpm = np.abs(np.column_stack([_field(esc, f"esc[{i}].esc_rpm", ie) for i in range(n_rot)]))
        if np.any(rpm > 0):
            w = rpm_to_rad_s(commands_on_grid(t_boot, t_e, rpm, held, off=0.0))
            notes.append(f"rotor speeds from esc_status RPM ({rate(t_e):.0f} Hz, measured; esc[i] taken as motor "
                         "i+1)")
            if pwm_grid is None:
                pwm_grid = rpm_to_rad_s(commands_on_grid(t_boot, t_e, rpm, "hold"))
                motor_fresh = np.nan_to_num(snap(t_boot, t_e, np.ones(t_e.size)))
                off = 0.0
        else:
            notes.append("esc_status logged but all RPM 0 (ESC telemetry not connected?): not used")
    if w is None:
        if pwm_grid is None:
            raise GreyboxInputError(f"{where}: no usable motor commands")
        w = rotor_map(pwm_used)
        used_map = rotor_map.pair
        notes.append(f"rotor speeds from PWM through w = {rotor_map.a:g}*PWM {rotor_map.c:+g} rad/s (an assumed "
                     f"map; outputs <= {off:g} µs are stopped motors)")
    for i in range(n_rot):
        extras[f"pwm{i + 1}"] = pwm_grid[:, i]
    extras["motor_fresh"] = motor_fresh
    running = np.any(pwm_grid > off, axis=1)
    if armed is not None:
        extras["armed"] = armed.astype(float)
        notes.append("armed for " + (f"{armed.mean():.0%} of the log" if armed.any() else "none of the log "
                                     "(never armed)"))

    bs = topics.get("battery_status")
    if bs is not None and len(bs.get("timestamp", [])):
        key = "voltage_v" if "voltage_v" in bs else "voltage_filtered_v" if "voltage_filtered_v" in bs else None
        if key:
            t_b, ib = _stamps(bs, "battery_status", notes)
            v = _field(bs, key, ib)
            okv = np.isfinite(v) & (v > 0)
            if okv.sum() >= 2:
                extras["vbat"] = np.interp(t_boot, t_b[okv], v[okv])
                notes.append(f"battery voltage from battery_status.{key}: {v[okv].min():.2f}-{v[okv].max():.2f} V")
    else:
        notes.append("no battery_status: no battery voltage (vbat)")
    extras.update(_setpoints(topics, t_boot, notes))
    extras["t_boot"] = t_boot

    # --- ground contact
    height = interpolate_samples(t_all, -outputs["z"], 1.0)      # on every row, for airborne or not
    rest_guess = math.nan
    span = None
    land = topics.get("vehicle_land_detected")
    why = ""
    if not running.any():
        why = (" (the motors never run: all outputs at or below the disarmed value "
               f"{off:g}" + ("; never armed" if armed is not None and not armed.any() else "") + ")")
    try:
        if land is not None and "landed" in land and len(land["landed"]) and running.any():
            t_l, il = _stamps(land, "vehicle_land_detected", notes)
            landed = commands_on_grid(t_boot, t_l, _field(land, "landed", il), "hold").ravel() > 0
            airborne = ~landed & running
            if airborne.sum() < 20:
                raise GreyboxInputError(f"{where}: the vehicle never leaves the ground (vehicle_land_detected): "
                                        "nothing to identify")
            k0, k1 = longest_run(airborne)
            before = np.isfinite(height[:k0])
            rest_guess = float(np.median(height[:k0][before])) if before.sum() >= 5 else math.nan
            span = FlightSpan(k0, k1, ~airborne, rest_guess,
                              f"{span_words(t_all, k0, k1)} (vehicle_land_detected)")
        else:
            span = flight_from_height(t_all, height, running, where, takeoff_height,
                                      hint=why + ("; keep_ground (--keep-ground) imports it anyway"
                                                  if not keep_ground else ""))
    except GreyboxInputError:
        if not keep_ground:
            raise
        notes.append("the vehicle never flies in this log" + why + ": kept everything (keep_ground); nothing in it "
                     "identifies thrust, drag or the motors")
    if span is not None:
        k0, k1 = span.k0, span.k1
        notes.append(span.note)
        extras["on_ground"] = span.on_ground.astype(float)
        hover_w = float(np.sqrt(np.mean(w[k0:k1 + 1] ** 2)))
        t_take, t_down, rest = float(t_all[k0]), float(t_all[k1]), span.rest_height
    else:
        k0, k1 = 0, t_all.size - 1
        extras["on_ground"] = np.ones(t_all.size)
        fin = np.isfinite(height)
        rest = float(np.median(height[fin])) if fin.any() else math.nan
        hover_w, t_take, t_down = math.nan, math.nan, math.nan
    log = trimmed_log(t_all, w, outputs, extras, notes, where, k0, k1, keep_ground,
                      "trimmed {before} rows before take-off and {after} after touchdown")
    return ImportResult(log, t_take, t_down, rest, hover_w, notes, format="px4", pwm_map=used_map, n_rotors=n_rot)


def px4_airframe_toml(mass: float, hover_rotor_speed: float | None = None, arm_length: float = 0.25,
                      ground_z: float = 0.0, pwm_map: tuple[float, float] | None = PX4_PWM_MAP,
                      name: str = "px4_quad_x") -> str:
    """Airframe TOML of a PX4 quadrotor X (PX4's motor order, "Generic Quadcopter X").

    The log holds neither the mass (so it must be given) nor the geometry: ``arm_length`` is
    an assumption (default 0.25 m, a 500 mm class frame) and the inertia is scaled from a
    typical 1 kg, 0.17 m quadrotor by ``m L^2``; both are marked as such in the file.
    ``K_T`` starts at ``m g / (4 w_hover^2)`` (hover from the log, else the PWM map at 1500 µs).
    """
    if not (mass > 0 and np.isfinite(mass)):
        raise GreyboxInputError(f"mass must be positive, got {mass!r}")
    if not (arm_length > 0 and np.isfinite(arm_length)):
        raise GreyboxInputError(f"arm length must be positive, got {arm_length!r}")
    g = 9.81
    have_hover = hover_rotor_speed is not None and np.isfinite(hover_rotor_speed) and hover_rotor_speed > 0
    if have_hover:
        w_h, src = float(hover_rotor_speed), "m g / (4 w_hover^2), w_hover from the log"
    else:
        a, c = pwm_map or PX4_PWM_MAP
        w_h, src = max(a * 1500.0 + c, 1.0), "m g / (4 w^2) at an assumed hover of 1500 µs (no flight in the log)"
    kt = mass * g / (4 * w_h ** 2)
    s = mass * arm_length ** 2
    jx, jz = 0.284 * s, 0.516 * s
    a = arm_length / math.sqrt(2.0)
    return f"""# PX4 quadrotor X, written by `greybox import px4`.
# Rotors in PX4's motor order (actuator outputs 1..4 = log columns w1..w4), body FRD:
# 1 front-right, 2 back-left, 3 front-left, 4 back-right; 1 and 2 turn counter-clockwise
# seen from above, so their reaction torque on the body is about +z (FRD): spin +1 (PX4's
# mixer: yaw +1); 3 and 4 clockwise: spin -1 (PX4 "Generic Quadcopter X"; the same as
# greybox's layout "x").
# The log holds neither mass nor geometry:
#   mass {mass!r} kg: given (--mass); K_T, b and Kd scale with it.
#   ASSUMED arm {arm_length!r} m (--arm-length): measure centre to motor axis.
#   ASSUMED inertia: a typical 1 kg, 0.17 m quadrotor's scaled by m L^2; measure it
#   (bifilar pendulum) or treat rotational parameters as relative to it.
[airframe]
name = "{name}"
mass = {mass!r}
inertia = [{jx:.6g}, {jx:.6g}, {jz:.6g}]
arm_length = {arm_length!r}
rotor_inertia = 0.0        # unknown; gyroscopic torque neglected
gravity = {g!r}
ground_z = {ground_z!r}    # ASSUMED: NED z of the floor plane (ground effect height = ground_z - z)

[[rotor]]   # 1 front-right, CCW
position = [{a:.6f}, {a:.6f}, 0.0]
spin = 1

[[rotor]]   # 2 back-left, CCW
position = [{-a:.6f}, {-a:.6f}, 0.0]
spin = 1

[[rotor]]   # 3 front-left, CW
position = [{a:.6f}, {-a:.6f}, 0.0]
spin = -1

[[rotor]]   # 4 back-right, CW
position = [{-a:.6f}, {a:.6f}, 0.0]
spin = -1

[parameters]
K_T = {kt:.6g}             # {src}
b = {0.02 * kt:.6g}        # ASSUMED reaction torque / thrust = 0.02 m (typical 10" propeller)
Kd = [{0.1 * mass:.6g}, {0.1 * mass:.6g}, {0.15 * mass:.6g}]
"""

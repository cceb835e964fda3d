"""The Crazyflie's onboard uSD-card log (Bitcraze micro-SD card deck, event-based binary
format, versions 1 and 2) as a flight log (README, "Flight log (CSV)").

**The format** (as Bitcraze describes it and decodes it in ``tools/usdlog/cfusdlog.py`` of
``bitcraze/crazyflie-firmware``; this is an independent reader, little-endian throughout):

* byte 0: ``0xBC``; then ``uint16`` version (1 or 2) and ``uint16`` number of event types;
* per event type: ``uint16`` id, its name (NUL-terminated), ``uint16`` number of variables,
  then per variable a NUL-terminated ``"name(t)"`` where ``t`` is a Python ``struct`` code
  (``f`` float32, ``I`` uint32, ``i``, ``H``, ``h``, ``B``, ``b``, ...);
* then records, until the last 4 bytes: ``uint16`` event id, a time stamp (version 1:
  ``uint32`` in ms; version 2: ``uint64`` in µs) and the event's variables packed without
  padding;
* the last 4 bytes: CRC-32 (zlib) of everything before them.

**What the importer makes of it** (shared parts in :mod:`greybox.io.base`):

* The event that carries ``gyro.x/y/z`` sets the time base (``fixedFrequency`` at about
  1 kHz in a usual configuration); variables of other events are put on its nearest row.
* **Frames.** The Crazyflie's body frame is FLU: gyro ``(p, -q, -r)``, specific force
  ``(ax, -ay, -az)`` (FRD). Position ``stateEstimate.x/y/z`` (z-up world) and attitude
  ``stateEstimate.qx/qy/qz/qw`` are used when logged (NED / FRD as for NanoBench); a log
  without them has empty ``x..psi`` columns, which :func:`greybox.data.load_log` reads.
* **Units.** Gyro deg/s -> rad/s, accelerometer g -> m/s^2 (checked: at rest it must read
  about 1 g; a log in m/s^2 is taken as it is, with a note).
* **Rotor speed** from ``motor.m1..m4`` (PWM 0..65535) through ``w = a*PWM + c``, default
  the Crazyflie 2.0 map of Förster 2015 as for NanoBench; PWM 0 is a stopped motor. These
  are *commanded* speeds: the rotor lags them (the ``motor_lag`` effect).
* **Held samples.** The motor commands change at about 500 Hz on a 1 kHz log: repeated rows
  are held samples, interpolated between fresh ones by default (``held="hold"`` keeps
  them); ``motor_fresh`` marks fresh rows. A gyro sample repeated exactly is a missing one.
* **Ground contact** without a height: the flight runs from the first to the last motor
  command, ended before the first impact (specific force above 3 g: a crash or a hard
  landing); ``keep_ground=True`` keeps everything (``on_ground`` flags it). With a logged
  height the flight is found from it instead (as for NanoBench).
* Accelerometer ``ax, ay, az`` (m/s^2, FRD; output channels). Extra columns: ``pwm1..4``, ``motor_fresh``, ``on_ground``,
  ``t_boot`` (s since the Crazyflie booted), ``vbat`` when ``pm.vbat`` is logged.
"""
from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import GreyboxInputError
from .base import (CRAZYFLIE_PWM_MAP, G0, ImportResult, PwmMap, check_crazyflie_pwm_scale, trimmed_log, commands_on_grid,
                   euler_from_quaternion, euler_zup_to_ned, flight_from_height, flight_from_imu, flu_to_frd,
                   fresh_rows, interpolate_samples, snap, time_base, zup_to_ned)

__all__ = ["import_crazyflie_usd", "read_usd_log", "UsdLog", "USD_MAGIC"]

USD_MAGIC = 0xBC
PWM_MAX = 65535.0
_TYPES = set("bBhHiIqQefd?")
_GYRO = ["gyro.x", "gyro.y", "gyro.z"]
_ACC = ["acc.x", "acc.y", "acc.z"]
_MOTORS = [f"motor.m{i}" for i in range(1, 5)]
_POS = ["stateEstimate.x", "stateEstimate.y", "stateEstimate.z"]
_QUAT = ["stateEstimate.qx", "stateEstimate.qy", "stateEstimate.qz", "stateEstimate.qw"]
_VBAT = "pm.vbat"


@dataclass
class UsdLog:
    """A decoded uSD log: per event name, ``"timestamp"`` (µs since boot, float) and one
    array per variable; plus the format version and what was noticed."""

    version: int
    events: dict[str, dict[str, np.ndarray]]
    crc_ok: bool
    notes: list[str] = field(default_factory=list)

    def find(self, name: str) -> str | None:
        """Name of the event that logs variable ``name`` (None if none does)."""
        for ev, cols in self.events.items():
            if name in cols and len(cols["timestamp"]):
                return ev
        return None


def _cstring(data: bytes, i: int, path: Path, what: str) -> tuple[str, int]:
    end = data.find(b"\0", i)
    if end < 0:
        raise GreyboxInputError(f"{path}: truncated header: {what} at byte {i} has no end")
    try:
        return data[i:end].decode("utf-8"), end + 1
    except UnicodeDecodeError:
        raise GreyboxInputError(f"{path}: corrupt header: {what} at byte {i} is not text") from None


def read_usd_log(path: str | Path, strict: bool = True) -> UsdLog:
    """Decode a Crazyflie uSD binary log (format in the module doc).

    Args:
        strict: refuse a file whose CRC does not match or whose records do not fill it
            exactly (truncated or corrupt). ``False`` keeps the whole records before the
            first unreadable one, with a note (a log cut short by a power loss).

    Raises:
        GreyboxInputError: naming the file and what is wrong with it.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise GreyboxInputError(f"{path}: cannot read ({e.strerror or e})") from None
    if len(data) < 9:
        raise GreyboxInputError(f"{path}: {len(data)} bytes: too short for a Crazyflie uSD log")
    if data[0] != USD_MAGIC:
        raise GreyboxInputError(f"{path}: not a Crazyflie uSD log (first byte 0x{data[0]:02X}, expected "
                                f"0x{USD_MAGIC:02X})")
    version, n_types = struct.unpack_from("<HH", data, 1)
    if version not in (1, 2):
        raise GreyboxInputError(f"{path}: uSD log format version {version} is not supported (1 or 2)")
    notes: list[str] = []
    stored_crc, = struct.unpack_from("<I", data, len(data) - 4)
    crc_ok = zlib.crc32(data[:-4]) == stored_crc
    if not crc_ok:
        msg = (f"CRC-32 mismatch (stored 0x{stored_crc:08X}, computed 0x{zlib.crc32(data[:-4]):08X}): "
               "the file is truncated or corrupt")
        if strict:
            raise GreyboxInputError(f"{path}: {msg} (greybox import crazyflie-usd --ignore-crc, or strict=False in Python, keeps its whole records)")
        notes.append(f"{path}: {msg}; whole records kept")

    i = 5
    layouts: dict[int, tuple[str, struct.Struct, list[str]]] = {}
    for _ in range(n_types):
        if i + 2 > len(data):
            raise GreyboxInputError(f"{path}: truncated header (event type {len(layouts) + 1} of {n_types})")
        ev_id, = struct.unpack_from("<H", data, i)
        name, i = _cstring(data, i + 2, path, "an event name")
        if i + 2 > len(data):
            raise GreyboxInputError(f"{path}: truncated header (event {name!r})")
        n_vars, = struct.unpack_from("<H", data, i)
        i += 2
        fmt, names = "<", []
        for _ in range(n_vars):
            spec, i = _cstring(data, i, path, f"a variable of event {name!r}")
            if len(spec) < 4 or spec[-3] != "(" or spec[-1] != ")" or spec[-2] not in _TYPES:
                raise GreyboxInputError(f"{path}: corrupt header: variable {spec!r} of event {name!r} is not "
                                        "'name(type)' with a known type")
            names.append(spec[:-3])
            fmt += spec[-2]
        if ev_id in layouts:
            raise GreyboxInputError(f"{path}: corrupt header: event id {ev_id} defined twice")
        layouts[ev_id] = (name, struct.Struct(fmt), names)

    head = struct.Struct("<HI" if version == 1 else "<HQ")
    scale = 1000.0 if version == 1 else 1.0        # version 1 stamps are ms, version 2 µs
    end = len(data) - 4
    rows: dict[int, list[tuple]] = {k: [] for k in layouts}
    stamps: dict[int, list[int]] = {k: [] for k in layouts}
    # fast path: one event type only -> fixed-size records, decoded at once
    if len(layouts) == 1:
        (ev_id, (name, st, names)), = layouts.items()
        size = head.size + st.size
        n_rec = (end - i) // size
        if (end - i) % size and strict:
            raise GreyboxInputError(f"{path}: {end - i} bytes of records are not a whole number of "
                                    f"{size}-byte records: truncated or corrupt")
        dt = np.dtype([("id", "<u2"), ("ts", "<u4" if version == 1 else "<u8")]
                      + [(f"v{j}", np.dtype("<" + c)) for j, c in enumerate(st.format[1:])])
        rec = np.frombuffer(data, dtype=dt, count=n_rec, offset=i)
        bad = np.flatnonzero(rec["id"] != ev_id)
        if bad.size:
            k = int(bad[0])
            if strict:
                raise GreyboxInputError(f"{path}: record {k + 1} (byte {i + k * size}) has event id "
                                        f"{int(rec['id'][k])}, not a defined event: corrupt")
            notes.append(f"{path}: unreadable record {k + 1} (byte {i + k * size}); {k} records kept")
            rec = rec[:k]
        cols = {"timestamp": rec["ts"].astype(float) * scale}
        for j, vn in enumerate(names):
            cols[vn] = rec[f"v{j}"].astype(float)
        return UsdLog(version, {name: cols}, crc_ok, notes)

    n = 0
    while i < end:
        if i + head.size > end:
            if strict:
                raise GreyboxInputError(f"{path}: truncated record at byte {i}")
            notes.append(f"{path}: partial record at byte {i} dropped")
            break
        ev_id, ts = head.unpack_from(data, i)
        if ev_id not in layouts:
            if strict:
                raise GreyboxInputError(f"{path}: record {n + 1} (byte {i}) has event id {ev_id}, not a defined "
                                        "event: corrupt")
            notes.append(f"{path}: unreadable record {n + 1} (byte {i}); {n} records kept")
            break
        _, st, _ = layouts[ev_id]
        if i + head.size + st.size > end:
            if strict:
                raise GreyboxInputError(f"{path}: truncated record {n + 1} at byte {i}")
            notes.append(f"{path}: partial record {n + 1} at byte {i} dropped")
            break
        rows[ev_id].append(st.unpack_from(data, i + head.size))
        stamps[ev_id].append(ts)
        i += head.size + st.size
        n += 1
    events = {}
    for ev_id, (name, st, names) in layouts.items():
        arr = np.array(rows[ev_id], dtype=float).reshape(len(rows[ev_id]), len(names))
        cols = {"timestamp": np.array(stamps[ev_id], dtype=float) * scale}
        for j, vn in enumerate(names):
            cols[vn] = arr[:, j]
        events[name] = cols
    return UsdLog(version, events, crc_ok, notes)


def import_crazyflie_usd(path: str | Path, pwm_map: tuple[float, float] = CRAZYFLIE_PWM_MAP,
                         held: str = "interpolate", keep_ground: bool = False, impact_g: float = 3.0,
                         strict: bool = True) -> ImportResult:
    """Convert a Crazyflie uSD binary log into a flight log (see module doc).

    Args:
        pwm_map: ``(a, c)`` of ``w = a*PWM + c`` (default: Förster 2015, Crazyflie 2.0).
        held: ``"interpolate"`` (default) or ``"hold"`` for the held motor samples.
        keep_ground: keep the samples before the motors start, after they stop and after
            an impact (flagged by ``on_ground``).
        impact_g: specific force (g) above which the accelerometer has hit something.
        strict: refuse a truncated or corrupt file (CRC); ``False`` keeps its whole records.

    Raises:
        GreyboxInputError: naming the file and what is wrong with it.
    """
    path = Path(path)
    where = str(path)
    if held not in ("interpolate", "hold"):
        raise GreyboxInputError(f"held must be 'interpolate' or 'hold', got {held!r}")
    rotor = PwmMap(*(float(v) for v in pwm_map))
    usd = read_usd_log(path, strict=strict)
    notes = list(usd.notes)
    ev = usd.find("gyro.x")
    if ev is None or any(n not in usd.events[ev] for n in _GYRO):
        have = {e: [k for k in c if k != "timestamp"] for e, c in usd.events.items()}
        raise GreyboxInputError(f"{path}: no event logs gyro.x, gyro.y, gyro.z (logged: {have}): log the IMU "
                                "in the uSD deck's config.txt")
    base = usd.events[ev]
    if len(base["timestamp"]) < 20:
        raise GreyboxInputError(f"{path}: only {len(base['timestamp'])} records of event {ev!r}: too short to import")
    stamps = base["timestamp"]
    t_boot = time_base(stamps, where, scale=1e-6, origin="given", label=lambda k: f"record {k + 1} of event {ev!r}",
                       what="record")
    t_all = t_boot - t_boot[0]
    dt_med = float(np.median(np.diff(t_all)))
    notes.append(f"uSD log version {usd.version}, event {ev!r}: {len(t_all)} records over {t_all[-1]:.2f} s "
                 f"({1 / dt_med:.0f} Hz)")

    def variable(name: str) -> np.ndarray | None:
        """``name`` on the base rows: its own samples, NaN where it has none."""
        e = usd.find(name)
        if e is None:
            return None
        if e == ev:
            return usd.events[e][name]
        ts = usd.events[e]["timestamp"] * 1e-6 - t_boot[0]
        return snap(t_all, ts, usd.events[e][name])

    missing = [m for m in _MOTORS if variable(m) is None]
    if missing:
        raise GreyboxInputError(f"{path}: no motor commands {', '.join(missing)} in the log: the rotor speeds "
                                "(the model's inputs) cannot be made")
    mev = usd.find(_MOTORS[0])
    if mev == ev:
        pwm = np.column_stack([base[m] for m in _MOTORS])
        t_pwm = t_all
    else:
        t_pwm = usd.events[mev]["timestamp"] * 1e-6 - t_boot[0]
        pwm = np.column_stack([usd.events[mev][m] for m in _MOTORS])
    out = np.argwhere(~np.isfinite(pwm) | (pwm < 0) | (pwm > PWM_MAX))
    if out.size:
        r, j = out[0]
        raise GreyboxInputError(f"{path}: record {r + 1} of event {mev!r}, {_MOTORS[j]}: PWM {pwm[r, j]:g} outside "
                                f"0..{PWM_MAX:g}")
    check_crazyflie_pwm_scale(pwm[np.any(pwm > 0, axis=1)], f"{path}: event {mev!r}, {', '.join(_MOTORS)}", PWM_MAX)
    fresh = fresh_rows(pwm)
    pwm_grid = commands_on_grid(t_all, t_pwm[fresh], pwm[fresh], "hold", off=0.0)
    pwm_used = commands_on_grid(t_all, t_pwm[fresh], pwm[fresh], held, off=0.0, repeated_between=True)
    motor_fresh = snap(t_all, t_pwm[fresh], np.ones(int(fresh.sum()))) if mev != ev else fresh.astype(float)
    motor_fresh = np.nan_to_num(motor_fresh)
    w = rotor(pwm_used)
    running = np.any(pwm_grid > 0, axis=1)
    frac = float(motor_fresh[running].mean()) if running.any() else 1.0
    if frac > 0.995:
        notes.append("motor commands: no held (repeated) samples while the motors run")
    else:
        notes.append(f"motor commands: {frac:.0%} of rows fresh while the motors run ({frac / dt_med:.0f} Hz); held "
                     "rows " + ("interpolated between fresh samples" if held == "interpolate" else "kept as logged"))

    outputs: dict[str, np.ndarray] = {}
    gyro = np.column_stack([base[n] for n in _GYRO])
    gfresh = fresh_rows(np.nan_to_num(gyro, nan=1e300))
    p = flu_to_frd(np.radians(gyro))
    for j, name in enumerate(["p", "q", "r"]):
        outputs[name] = np.where(gfresh, p[:, j], np.nan)
    if (~gfresh).sum():
        notes.append(f"{int((~gfresh).sum())} held (repeated) gyro samples set missing")
    extras: dict[str, np.ndarray] = {}
    acc = None
    if all(usd.find(n) for n in _ACC):
        acc_raw = np.column_stack([variable(n) for n in _ACC])
        mag = np.nanmedian(np.linalg.norm(acc_raw, axis=1))
        if 5.0 < mag < 20.0:
            notes.append(f"accelerometer median |f| = {mag:.2f}: taken as m/s^2 (documented as g)")
            acc = flu_to_frd(acc_raw)
        elif 0.5 < mag < 2.0:
            acc = flu_to_frd(acc_raw * G0)
        else:
            raise GreyboxInputError(f"{path}: accelerometer median |acc| = {mag:.3g}: neither g nor m/s^2")
        outputs["ax"], outputs["ay"], outputs["az"] = acc[:, 0], acc[:, 1], acc[:, 2]
    else:
        notes.append("no acc.x/y/z: no specific force (ax, ay, az), and no impact detection")

    height = None
    if all(usd.find(n) for n in _POS):
        pos = np.column_stack([variable(n) for n in _POS])
        ned = zup_to_ned(pos)
        for j, name in enumerate(["x", "y", "z"]):
            outputs[name] = ned[:, j]
        height = interpolate_samples(t_all, pos[:, 2], 1.0)      # on every row, for airborne or not
        notes.append("position from stateEstimate.x/y/z (the onboard estimate; z-up world -> NED)")
    if all(usd.find(n) for n in _QUAT):
        q = np.column_stack([variable(n) for n in _QUAT])
        eul = euler_zup_to_ned(euler_from_quaternion(q / np.linalg.norm(q, axis=1, keepdims=True)))
        for j, name in enumerate(["phi", "theta", "psi"]):
            outputs[name] = eul[:, j]
        notes.append("attitude from stateEstimate.qx/qy/qz/qw (the onboard estimate)")
    if not any(n in outputs for n in ("x", "phi")):
        notes.append("no position and no attitude in the log: columns x..psi are empty (an IMU log: fit it "
                     "on p, q, r and the specific force)")
    if usd.find(_VBAT):
        e = usd.find(_VBAT)
        tv = usd.events[e]["timestamp"] * 1e-6 - t_boot[0]
        v = usd.events[e][_VBAT]
        vf = fresh_rows(v[:, None]) & np.isfinite(v)
        extras["vbat"] = np.interp(t_all, tv[vf], v[vf]) if vf.any() else np.full(t_all.size, np.nan)
    for i in range(4):
        extras[f"pwm{i + 1}"] = pwm_grid[:, i]
    extras["motor_fresh"] = motor_fresh
    extras["t_boot"] = t_boot

    # at rest before the motors start: the accelerometer against gravity
    on = np.flatnonzero(running)
    if acc is not None and on.size and on[0] >= 100:
        f0 = np.nanmean(acc[:on[0]], axis=0)
        tilt = math.degrees(math.acos(np.clip(-f0[2] / np.linalg.norm(f0), -1, 1)))
        notes.append(f"at rest before the motors start: specific force ({f0[0]:.2f}, {f0[1]:.2f}, {f0[2]:.2f}) m/s^2 "
                     f"FRD, |f| = {np.linalg.norm(f0) / G0:.3f} g, tilted {tilt:.1f} deg")

    # ground contact
    span = None
    try:
        if height is not None and np.isfinite(height).sum() > 20:
            span = flight_from_height(t_all, height, running, where, 0.01)
        else:
            span = flight_from_imu(t_all, acc if acc is not None else np.zeros((t_all.size, 3)), running, where,
                                   impact_g=impact_g)
    except GreyboxInputError:
        if not keep_ground:
            raise
        notes.append("the motors never run: no flight; kept everything (keep_ground)")
    if span is not None:
        k0, k1 = span.k0, span.k1
        notes.append(span.note)
        stops = ~running[k0:k1 + 1]
        n_stops = int(np.sum(np.diff(np.r_[0, stops.astype(int)]) == 1))
        if n_stops:
            msg = f"the motors stop {n_stops} time(s) in flight (commanded 0, {stops.sum() * dt_med:.2f} s in all)"
            if acc is not None:
                fmin = np.nanmin(np.linalg.norm(acc[k0:k1 + 1][stops], axis=1)) / G0
                msg += f"; specific force falls to {fmin:.2f} g then (falling)"
            notes.append(msg + ": the rotors spin down, not stop, in that time (motor lag)")
        sel = np.zeros(t_all.size, dtype=bool)
        sel[k0:k1 + 1] = True
        hover_w = float(np.sqrt(np.mean(w[sel & running] ** 2))) if (sel & running).any() else math.nan
        extras["on_ground"] = span.on_ground.astype(float)
        t_take, t_down, rest = float(t_all[k0]), float(t_all[k1]), span.rest_height
    else:
        k0, k1 = 0, t_all.size - 1
        hover_w, t_take, t_down, rest = math.nan, math.nan, math.nan, math.nan
        extras["on_ground"] = np.ones(t_all.size)
    log = trimmed_log(t_all, w, outputs, extras, notes, where, k0, k1, keep_ground,
                      "trimmed {before} samples before the flight and {after} after it")
    return ImportResult(log, t_take, t_down, rest, hover_w, notes, format="crazyflie-usd", pwm_map=rotor.pair,
                        n_rotors=4)

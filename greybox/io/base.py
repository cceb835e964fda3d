"""What every importer needs, written once: frames, units, time bases, held samples, ground
contact, and assembling a :class:`~greybox.data.FlightLog` on one time base.

greybox's conventions (README, "Conventions"): world NED, body FRD, ZYX Euler angles, SI
units. Other tools log otherwise:

* **Frames.** A z-up world (x, y, z up) and an FLU body (x forward, y left, z up) become NED
  and FRD by a rotation of pi about x, the same for both: vectors ``(x, -y, -z)``
  (:func:`flu_to_frd`, :func:`zup_to_ned`), ZYX Euler angles ``(phi, -theta, -psi)``
  (:func:`euler_zup_to_ned`). The world's x stays x (north is wherever the source's x
  points). Quaternions are turned into ZYX Euler angles by :func:`euler_from_quaternion`
  (scalar last as in ROS / Vicon, or scalar first as in PX4).
* **Units.** :func:`deg_to_rad`, :func:`g_to_ms2` (standard gravity :data:`G0`),
  :func:`rpm_to_rad_s`, and motor commands to rotor speed through the affine map
  ``w = a*PWM + c`` (:class:`PwmMap`): a command at or below the map's ``off`` value is a
  stopped motor (0 rad/s), and the map never gives a negative speed. The slope ``a`` is
  absorbed by ``K_T`` and ``b`` in a fit (they multiply ``w^2``), the offset ``c`` can be
  fitted with the ``rotor_map`` effect. :data:`CRAZYFLIE_PWM_MAP` (Förster 2015) and
  :data:`PX4_PWM_MAP` are the defaults of the importers.
* **Time.** :func:`time_base` turns raw stamps (µs, ms, s) into seconds, from 0 at the first
  sample or as given, and refuses stamps that do not increase, naming the sample.
* **Held samples.** A command logged at a lower rate than the log's rows is repeated
  ("held") on the rows in between. :func:`fresh_rows` finds the fresh rows,
  :func:`commands_on_grid` puts a command stream on the log's rows, interpolated between
  fresh samples (``"interpolate"``) or held (``"hold"``); a stopped motor is never
  interpolated into a running one.
* **Ground contact.** The model has no ground reaction force: a flight log should start at
  take-off and end at touchdown. :func:`flight_from_height` finds the flight from a height
  (the longest run above the resting height with the motors running);
  :func:`flight_from_imu` does without a height (from motor start to motor stop, cut
  before the first impact seen by the accelerometer).
* **One time base.** :func:`grid_with` builds the rows (one sensor's stamps plus the
  stamps of other sensors that fall where it has no sample), :func:`snap` puts each
  sensor's samples on their nearest row and leaves NaN where a sensor has no sample, and
  :func:`assemble_log` makes the :class:`~greybox.data.FlightLog`.

Every importer returns an :class:`ImportResult`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping

import numpy as np

from ..data import OPTIONAL_OUTPUTS, REQUIRED_OUTPUTS, FlightLog
from ..errors import GreyboxInputError

__all__ = ["trimmed_log", "G0", "CRAZYFLIE_PWM_MAP", "PX4_PWM_MAP", "PwmMap", "ImportResult", "FlightSpan",
           "flu_to_frd", "zup_to_ned", "euler_zup_to_ned", "euler_from_quaternion", "wrap_angle",
           "deg_to_rad", "g_to_ms2", "rpm_to_rad_s", "pwm_to_rotor_speed", "parse_pwm_map",
           "time_base", "fresh_rows", "interpolate_fresh", "held_inputs", "HeldInputs", "interpolate_held_inputs",
           "HELD_EVERY", "interpolate_samples", "setpoint_extras", "commands_on_grid", "held_run_knots", "HELD_RUN_LIMIT", "flight_from_height",
           "flight_from_imu", "longest_run", "grid_with", "snap", "assemble_log", "span_words",
           "CRAZYFLIE_FLYING_PWM_SHARE", "check_crazyflie_pwm_scale"]

G0 = 9.80665
"""Standard gravity, m/s^2: one g of an accelerometer that logs in g."""

CRAZYFLIE_PWM_MAP = (0.04076521, 380.8359)
"""Published Crazyflie 2.0 PWM-to-rotor-speed map ``w [rad/s] = a*PWM + c`` (PWM 0..65535;
J. Förster, "System Identification of the Crazyflie 2.0 Nano Quadrocopter", ETH Zurich, 2015)."""

CRAZYFLIE_FLYING_PWM_SHARE = 0.05
"""Share of the 0..65535 PWM range below which a Crazyflie's motor commands cannot keep it in
the air: it hovers at about 60 % (the NanoBench flights' hover speeds, 2000-3200 rad/s by
:data:`CRAZYFLIE_PWM_MAP`), and 5 % (PWM 3277, about 515 rad/s) gives under a tenth of its
weight. Commands that stay below it while flying are in another unit (a blind audit's log
with 8-bit values, 0..255, was imported, fitted with K_T 23 times the truth and certified)."""


def check_crazyflie_pwm_scale(pwm: np.ndarray, where: str, full_scale: float = 65535.0) -> None:
    """Raise :class:`GreyboxInputError` when a Crazyflie's motor commands ``pwm`` (rows while
    it flies or its motors run, one column a motor) stay below
    :data:`CRAZYFLIE_FLYING_PWM_SHARE` of ``full_scale``: the 90th percentile of each row's
    largest command, so that spin-up and idle rows do not decide."""
    pwm = np.asarray(pwm, dtype=float)
    if pwm.size == 0:
        return
    top = float(np.percentile(np.max(pwm, axis=1), 90))
    if top < CRAZYFLIE_FLYING_PWM_SHARE * full_scale:
        hint = "8-bit values, 0..255? multiply them by 257" if top <= 255 else "a percentage or another unit?"
        raise GreyboxInputError(
            f"{where}: the motor commands stay below PWM {top:.0f} while the vehicle flies (90th percentile of the "
            f"largest of the four), {100 * top / full_scale:.2g} % of 0..{full_scale:g}, where a Crazyflie hovers at "
            f"about 60 %: not PWM 0..{full_scale:g} ({hint})")


PX4_PWM_MAP = (1.0, -1000.0)
"""Default map of PX4 PWM outputs (µs) to rotor speed: ``w [rad/s] = PWM - 1000``, i.e.
stopped at 1000 µs and 1000 rad/s (about 9500 RPM) at 2000 µs, a 450-500 mm class
quadrotor (a 900-1000 KV motor on 3S with 10" propellers). An assumption, not a
measurement: replace it with a bench measurement (tachometer, or ESC RPM telemetry),
``--pwm-map a,c``. Its slope only rescales ``K_T`` and ``b``; its offset can be fitted with
the ``rotor_map`` effect."""


# ---------------------------------------------------------------------------- frames

def _rot_pi_x(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v * np.array([1.0, -1.0, -1.0])


def flu_to_frd(v: np.ndarray) -> np.ndarray:
    """Body vectors (n, 3) or (3,) from FLU (x forward, y left, z up) to FRD: ``(x, -y, -z)``.

    Rates, specific force and any other body-frame vector convert the same way."""
    return _rot_pi_x(v)


def zup_to_ned(v: np.ndarray) -> np.ndarray:
    """World vectors (n, 3) or (3,) from a z-up frame (x, y, z up) to NED: ``(x, -y, -z)``."""
    return _rot_pi_x(v)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles wrapped into [-pi, pi)."""
    return (np.asarray(a, dtype=float) + np.pi) % (2 * np.pi) - np.pi


def euler_zup_to_ned(eul: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (n, 3) of an FLU body in a z-up world as those of the FRD body in NED:
    ``(phi, -theta, -psi)`` (yaw wrapped into [-pi, pi))."""
    eul = np.asarray(eul, dtype=float)
    out = eul * np.array([1.0, -1.0, -1.0])
    out[..., 2] = wrap_angle(out[..., 2])
    return out


def euler_from_quaternion(q: np.ndarray, scalar_first: bool = False) -> np.ndarray:
    """ZYX Euler angles (roll, pitch, yaw), (n, 3), of unit quaternions (n, 4) that rotate
    body vectors into the world: ``(x, y, z, w)`` (``scalar_first=False``, ROS / Vicon) or
    ``(w, x, y, z)`` (``scalar_first=True``, PX4). Not normalised here."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if scalar_first:
        w, x, y, z = q.T
    else:
        x, y, z, w = q.T
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x ** 2 + y ** 2))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y ** 2 + z ** 2))
    return np.column_stack([roll, pitch, yaw])


# ----------------------------------------------------------------------------- units

def deg_to_rad(v):
    """Degrees (or deg/s) to radians (rad/s)."""
    return np.radians(np.asarray(v, dtype=float))


def g_to_ms2(v):
    """Accelerometer readings in g to m/s^2 (standard gravity :data:`G0`)."""
    return np.asarray(v, dtype=float) * G0


def rpm_to_rad_s(v):
    """Revolutions per minute to rad/s (``* pi/30``)."""
    return np.asarray(v, dtype=float) * (math.pi / 30.0)


@dataclass(frozen=True)
class PwmMap:
    """Affine motor-command-to-rotor-speed map ``w [rad/s] = a*PWM + c``.

    A command at or below ``off`` is a stopped motor (0 rad/s); the map never returns a
    negative speed. ``a`` must be positive. Fittable: ``a`` is absorbed by ``K_T`` and ``b``
    (they multiply ``w^2``), ``c`` by the ``rotor_map`` effect.
    """

    a: float
    c: float
    off: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.a) and np.isfinite(self.c) and self.a > 0):
            raise GreyboxInputError(f"PWM map slope must be positive and finite, got a={self.a!r}, c={self.c!r}")

    def __call__(self, pwm) -> np.ndarray:
        pwm = np.asarray(pwm, dtype=float)
        return np.where(pwm > self.off, np.maximum(self.a * pwm + self.c, 0.0), 0.0)

    @property
    def pair(self) -> tuple[float, float]:
        return (self.a, self.c)


def pwm_to_rotor_speed(pwm: np.ndarray, pwm_map: tuple[float, float] = CRAZYFLIE_PWM_MAP,
                       off: float = 0.0) -> np.ndarray:
    """Rotor speed (rad/s) of motor commands through ``w = a*PWM + c``; a motor at or below
    ``off`` (default PWM 0) is stopped, and no speed is negative."""
    a, c = pwm_map
    return PwmMap(float(a), float(c), off)(pwm)


def parse_pwm_map(text: str, option: str = "--pwm-map") -> tuple[float, float]:
    """``"a,c"`` as two finite numbers with ``a > 0`` (one clear error otherwise)."""
    try:
        vals = tuple(float(v) for v in str(text).split(","))
    except ValueError:
        raise GreyboxInputError(f"{option}: expected two numbers a,c, got {text!r}") from None
    if len(vals) != 2:
        raise GreyboxInputError(f"{option}: expected two numbers a,c, got {text!r}")
    if not (all(np.isfinite(vals)) and vals[0] > 0):
        raise GreyboxInputError(f"{option}: a must be positive and both finite, got {text!r}")
    return vals


# ------------------------------------------------------------------------------ time

def time_base(stamps, where: str, scale: float = 1.0, origin: str | float = "first",
              label: Callable[[int], str] | None = None, what: str = "sample") -> np.ndarray:
    """Seconds from raw time stamps: ``stamps * scale`` (``scale`` 1e-6 for µs, 1e-3 for
    ms), minus the first stamp (``origin="first"``), kept as given (``"given"``) or minus a
    number. Stamps must be finite and strictly increasing: otherwise one
    :class:`GreyboxInputError` naming ``where`` and the sample (``label(k)``, default
    ``"sample k+1"``)."""
    label = label or (lambda k: f"{what} {k + 1}")
    t = np.asarray(stamps, dtype=float) * scale
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise GreyboxInputError(f"{where}: {label(int(bad[0]))}: time stamp is not a finite number")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0])
        raise GreyboxInputError(f"{where}: {label(k + 1)}: time {stamps[k + 1]!r} is not after the previous "
                                f"{what}'s {stamps[k]!r} (t must be strictly increasing)")
    if isinstance(origin, str):
        if origin == "first":
            return t - t[0] if t.size else t
        if origin == "given":
            return t
        raise GreyboxInputError(f"time origin must be 'first', 'given' or a number, got {origin!r}")
    return t - float(origin)


# --------------------------------------------------------------------- held samples

def fresh_rows(block: np.ndarray) -> np.ndarray:
    """Rows of ``block`` (n, k) that are not an exact repeat of the previous row: the fresh
    samples of a signal logged at a lower rate than its rows (held in between)."""
    block = np.asarray(block)
    if block.ndim == 1:
        block = block[:, None]
    same = np.all(block[1:] == block[:-1], axis=1)
    return np.r_[True, ~same]


def interpolate_fresh(t: np.ndarray, values: np.ndarray, fresh: np.ndarray) -> np.ndarray:
    """``values`` (n,) linearly interpolated between its fresh rows (held at the ends)."""
    k = np.flatnonzero(fresh)
    return np.interp(t, t[k], values[k])


HELD_EVERY = 1.5
"""Fresh rotor speeds this many rows apart or more (the median spacing) make a log's inputs
held samples (:func:`held_inputs`): a signal logged at a lower rate than the rows."""


@dataclass(frozen=True)
class HeldInputs:
    """A log's inputs that repeat the previous row exactly on most rows (:func:`held_inputs`)."""

    share: float        # share of the rows that repeat the previous one
    every: float        # mean rows between fresh samples (runs of a command that stayed put left out)
    rate: float         # fresh samples per second
    row_rate: float     # rows per second (from the median row interval)
    # each input refreshed on rows of its own (ESC telemetry per motor, phases staggered): the
    # rows as a whole are fresh on most rows, each column on few (figures: the columns' mean)
    staggered: bool = False

    @property
    def late_ms(self) -> float:
        """How late a held row can be, ms: a fresh sample's spacing."""
        return 1000.0 / self.rate

    def text(self, names: str = "the rotor speeds") -> str:
        """What was found, in words."""
        each = "each of " if self.staggered else ""
        own = ", each on rows of its own" if self.staggered else ""
        return (f"{each}{names} repeat{'s' if self.staggered else ''} the previous row exactly on "
                f"{100 * self.share:.0f} % of the rows (a fresh value every {self.every:.3g} rows: {self.rate:.3g} Hz on "
                f"{self.row_rate:.3g} Hz rows{own})")


def held_inputs(log: FlightLog) -> HeldInputs | None:
    """Whether ``log``'s inputs are samples of a slower signal held on the rows in between (an
    ESC's telemetry at 50 Hz on 100 Hz rows): fresh rows (:func:`fresh_rows`, every input at
    once) :data:`HELD_EVERY` rows apart or more in the median, long runs left out (a command
    that stayed put: :data:`HELD_RUN_LIMIT` spacings). None where they are not, where fewer
    than 20 rows are fresh, or where an importer marked the fresh rows (``motor_fresh``)."""
    if "motor_fresh" in log.extras or len(log) < 40 or not log.inputs.size:
        return None
    dt = float(np.median(np.diff(log.t)))
    together = _held_spacing(fresh_rows(log.inputs))
    if together is not None:
        share, every = together
        return HeldInputs(share=share, every=every, rate=1.0 / (every * dt), row_rate=1.0 / dt)
    # each column on rows of its own (a blind audit's ESC telemetry at 100 Hz per motor, phases
    # staggered, on 200-Hz rows: some column changed on most rows, and nothing was said)
    columns = [_held_spacing(fresh_rows(log.inputs[:, j])) for j in range(log.inputs.shape[1])]
    if log.inputs.shape[1] < 2 or any(c is None for c in columns):
        return None
    share, every = float(np.mean([c[0] for c in columns])), float(np.mean([c[1] for c in columns]))
    return HeldInputs(share=share, every=every, rate=1.0 / (every * dt), row_rate=1.0 / dt, staggered=True)


def _held_spacing(fresh: np.ndarray) -> tuple[float, float] | None:
    """``(share of rows repeated, mean rows between fresh ones)`` of a fresh-row mask whose
    fresh rows lie :data:`HELD_EVERY` rows apart or more in the median (long runs, a command
    that stayed put, left out: :data:`HELD_RUN_LIMIT`); None otherwise or with under 20."""
    k = np.flatnonzero(fresh)
    if k.size < 20:
        return None
    gaps = np.diff(k)
    typical = float(np.median(gaps))
    if typical < HELD_EVERY:
        return None
    gaps = gaps[gaps <= HELD_RUN_LIMIT * typical]
    return 1.0 - k.size / fresh.size, (float(np.mean(gaps)) if gaps.size else typical)


def interpolate_held_inputs(log: FlightLog) -> FlightLog:
    """``log`` with held inputs (:func:`held_inputs`) interpolated linearly between their fresh
    rows (:func:`commands_on_grid`: a long run held, a stopped motor never interpolated into a
    running one), the fresh rows marked (``motor_fresh``) and a note; ``log`` itself where
    they are not held. Held telemetry lags the signal by up to a fresh sample's spacing, more
    than the rows' timing (``sampled_inputs``) holds: a blind audit's 50-Hz ESC telemetry on
    100-Hz rows had a moment gain of 0.87 named beside the true wind, quadratic drag and
    accelerometer bias; interpolated, those three alone."""
    held = held_inputs(log)
    if held is None:
        return log
    if held.staggered:
        # each column between its own fresh rows; a row is fresh where any column is
        cols = [fresh_rows(log.inputs[:, j]) for j in range(log.inputs.shape[1])]
        inputs = np.column_stack([commands_on_grid(log.t, log.t[f], log.inputs[f, j], "interpolate", off=0.0,
                                                   repeated_between=True)[:, 0] for j, f in enumerate(cols)])
        fresh = np.any(np.column_stack(cols), axis=1)
    else:
        fresh = fresh_rows(log.inputs)
        inputs = commands_on_grid(log.t, log.t[fresh], log.inputs[fresh], "interpolate", off=0.0,
                                  repeated_between=True)
    extras = dict(log.extras)
    extras["motor_fresh"] = fresh.astype(float)
    note = f"{held.text(', '.join(log.input_names))}: interpolated between the fresh rows (held inputs: interpolate)"
    return replace(log, inputs=inputs, extras=extras, notes=list(log.notes) + [note])


def setpoint_extras(t_rows: np.ndarray, t_samples: np.ndarray, position_ned: np.ndarray,
                    yaw: np.ndarray) -> dict[str, np.ndarray]:
    """The position controller's target as the log's ``x_ref, y_ref, z_ref`` (m, NED) and
    ``psi_ref`` (rad), what a closed-loop model reads (:mod:`greybox.controller_law`): its
    complete samples (``position_ned`` (n, 3) and ``yaw`` (n,) at ``t_samples``; one with a NaN
    component is left out) interpolated onto the rows ``t_rows``, the yaw unwrapped first so
    that a gap is not bridged the long way round (179 -> -179 degrees). Empty when no sample
    is complete."""
    vals = np.column_stack([np.asarray(position_ned, dtype=float), np.asarray(yaw, dtype=float)])
    ok = np.isfinite(vals).all(axis=1)
    if not ok.any():
        return {}
    t_ok = np.asarray(t_samples, dtype=float)[ok]
    out = {name: np.interp(t_rows, t_ok, vals[ok, j]) for j, name in enumerate(("x_ref", "y_ref", "z_ref"))}
    out["psi_ref"] = np.interp(t_rows, t_ok, np.unwrap(vals[ok, 3]))
    return out


def interpolate_samples(t: np.ndarray, y: np.ndarray, max_gap: float = 1.0) -> np.ndarray:
    """A slow sensor's samples ``y`` (NaN on rows without one) interpolated onto every row
    between samples at most ``max_gap`` seconds apart (NaN elsewhere and outside): e.g. a
    10 Hz height on 250 Hz rows, to tell on every row whether the vehicle is airborne."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    k = np.flatnonzero(np.isfinite(y))
    out = np.full(t.size, np.nan)
    if k.size < 2:
        out[k] = y[k]
        return out
    pos = np.clip(np.searchsorted(t[k], t), 1, k.size - 1)
    ok = (t >= t[k[0]]) & (t <= t[k[-1]]) & (t[k[pos]] - t[k[pos - 1]] <= max_gap)
    out[ok] = np.interp(t[ok], t[k], y[k])
    return out


HELD_RUN_LIMIT = 3.5
"""A gap between fresh command samples longer than this many of their typical (median)
spacing is no logger's held sample but a command that stayed put (a vehicle on the ground
before take-off, a clamped or saturated motor): it is held, and ramped to the next sample
over one typical spacing only. A blind audit's 418-Hz uSD log, its command constant for the
567 ms on the ground, was ramped across them (97 rad/s RMS off, K_T 2.3 % low in the IMU
fit); its 79-Hz NanoBench log's integer command, constant for 5 rows of 100 Hz and then
stepping, was ramped over the 4 rows before the step (up to 459 rad/s off). A logger that
misses rows at random leaves gaps of 2-3 spacings; 4 in a row at a 21 % chance each is
1 in 500."""


def held_run_knots(t_cmd: np.ndarray, cmd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fresh command samples ``cmd`` (m, k) at ``t_cmd`` with a knot added before each gap
    longer than :data:`HELD_RUN_LIMIT` typical spacings, one typical spacing before its end,
    holding the value before the gap: what linear interpolation between them ramps over."""
    dt = np.diff(t_cmd)
    if dt.size < 2:
        return t_cmd, cmd
    typical = float(np.median(dt))
    long = np.flatnonzero(dt > HELD_RUN_LIMIT * typical)
    if not long.size or typical <= 0:
        return t_cmd, cmd
    return np.insert(t_cmd, long + 1, t_cmd[long + 1] - typical), np.insert(cmd, long + 1, cmd[long], axis=0)


def commands_on_grid(t_grid: np.ndarray, t_cmd: np.ndarray, cmd: np.ndarray, held: str = "interpolate",
                     off: float = 0.0, repeated_between: bool = False) -> np.ndarray:
    """Motor commands (m, k) logged at times ``t_cmd`` (their fresh samples) on the rows
    ``t_grid``: ``"interpolate"`` linearly between samples, ``"hold"`` the last sample at or
    before the row (zero-order hold; the first sample before it). Where the held command is
    at or below ``off`` (a stopped motor) the row keeps it: a motor is never interpolated
    into or out of a stop. ``repeated_between``: ``t_cmd`` are the rows where a logged command
    changed, the rows between repeating it (a value-change log, as the NanoBench and uSD
    importers find them): a gap far longer than the samples' typical spacing is then a command
    that stayed put, held (:func:`held_run_knots`); between messages (PX4's, a dropout) the
    command is unknown and interpolated. Returns (n, k)."""
    if held not in ("interpolate", "hold"):
        raise GreyboxInputError(f"held must be 'interpolate' or 'hold', got {held!r}")
    t_grid = np.asarray(t_grid, dtype=float)
    t_cmd = np.asarray(t_cmd, dtype=float)
    cmd = np.asarray(cmd, dtype=float).reshape(t_cmd.size, -1)
    idx = np.clip(np.searchsorted(t_cmd, t_grid, side="right") - 1, 0, t_cmd.size - 1)
    zoh = cmd[idx]
    if held == "hold":
        return zoh
    t_knots, knots = held_run_knots(t_cmd, cmd) if repeated_between else (t_cmd, cmd)
    out = np.column_stack([np.interp(t_grid, t_knots, knots[:, i]) for i in range(cmd.shape[1])])
    stopped = zoh <= off
    out[stopped] = zoh[stopped]
    return out


# -------------------------------------------------------------------- ground contact

@dataclass
class FlightSpan:
    """The airborne part of a log: rows ``k0..k1`` (inclusive), what was found on the way."""

    k0: int
    k1: int
    on_ground: np.ndarray          # (n,) bool: row flagged as on the ground
    rest_height: float = math.nan  # resting height (source frame, z up), m; NaN if unknown
    note: str = ""


def longest_run(mask: np.ndarray) -> tuple[int, int] | None:
    """First and last index of the longest run of True in ``mask`` (None if there is none)."""
    k = np.flatnonzero(mask)
    if k.size == 0:
        return None
    breaks = np.flatnonzero(np.diff(k) > 1)
    starts, ends = np.r_[k[0], k[breaks + 1]], np.r_[k[breaks], k[-1]]
    j = int(np.argmax(ends - starts))
    return int(starts[j]), int(ends[j])


def span_words(t: np.ndarray, k0: int, k1: int) -> str:
    """"take-off at .. s, touchdown at .. s" for the flight of rows ``k0..k1`` of times ``t``,
    or that the log begins or ends in the air (a log cut in flight has no touchdown)."""
    start = (f"in the air when the log begins ({t[k0]:.2f} s)" if k0 == 0 else f"take-off at {t[k0]:.2f} s")
    end = (f"still in the air when the log ends ({t[k1]:.2f} s)" if k1 == t.size - 1 else
           f"touchdown at {t[k1]:.2f} s")
    return f"{start}, {end}"


HEIGHT_GAP_BRIDGED = 1.0
"""s: the longest stretch without a height measurement that :func:`flight_from_height` bridges
(the height interpolated across it to tell whether the vehicle is airborne)."""


def flight_from_height(t: np.ndarray, height: np.ndarray, running: np.ndarray, where: str,
                       takeoff_height: float = 0.01, min_samples: int = 20,
                       hint: str = "") -> FlightSpan:
    """The flight from a height (z up, NaN where not measured) and whether the motors run.

    The resting height is the median height before the motors start (at least 5 samples;
    else the lowest height). The vehicle is airborne where its height is more than
    ``takeoff_height`` above rest and the motors run; the flight is the longest airborne
    run (a hop at take-off is not the flight).

    Raises:
        GreyboxInputError: the vehicle never leaves the ground (``hint`` is appended).
    """
    height = np.asarray(height, dtype=float)
    running = np.asarray(running, dtype=bool)
    on = np.flatnonzero(running)
    before = np.arange(on[0] if on.size else height.size)
    before = before[np.isfinite(height[before])]
    if before.size >= 5:
        rest = float(np.median(height[before]))
    elif np.isfinite(height).any():
        rest = float(np.nanmin(height))
    else:
        raise GreyboxInputError(f"{where}: no height measurement: cannot tell when the vehicle flies{hint}")
    # a height lost for a moment in flight (a mocap dropout) is bridged: a blind audit's
    # 0.1-s gap at 1 m cut the flight in two, and the first 5 s were dropped without a word
    bridged = interpolate_samples(t, height, HEIGHT_GAP_BRIDGED)
    airborne = np.isfinite(bridged) & (bridged - rest > takeoff_height) & running
    if airborne.sum() < min_samples:
        raise GreyboxInputError(f"{where}: the vehicle never leaves the ground (never {takeoff_height:g} m above "
                                f"its resting height {rest:.3f} m): nothing to identify{hint}")
    k0, k1 = longest_run(airborne)
    on_ground = ~airborne
    mid_contact = int(on_ground[k0:k1 + 1].sum())
    unmeasured = int((~np.isfinite(height[k0:k1 + 1])).sum())
    dropped = int(airborne.sum()) - (k1 - k0 + 1 - mid_contact)
    note = (f"{span_words(t, k0, k1)} (resting height {rest:.3f} m)"
            + (f"; {mid_contact} samples in between touch the ground" if mid_contact else "")
            + (f"; {unmeasured} samples without a height in flight taken as airborne" if unmeasured else "")
            + (f"; {dropped} airborne samples outside it left out (the flight is the longest airborne run; "
               f"a gap without height over {HEIGHT_GAP_BRIDGED:g} s, or a touch of the ground, parts it)"
               if dropped > 0.05 * (k1 - k0 + 1) else ""))
    return FlightSpan(k0, k1, on_ground, rest, note)


ROTORS_STOPPED_SHARE = 0.2
"""A row's rotors are stopped (or idling) when every one turns below this share of the log's
median rotor speed: under 4 % of the usual thrust, which nothing flies on."""


@dataclass
class GroundRows:
    """The rows of a log on the ground at its start and end (:func:`ground_rows`): the flight
    is rows ``k0..k1``; ``text`` says where, how found and how many rows lie on either side;
    ``touch`` rows in between touch the ground."""

    k0: int
    k1: int
    text: str
    touch: int = 0

    def words(self, fate: str) -> str:
        """The note or warning: what is done with those rows (``fate``) and why it matters."""
        return (f"{self.text} {fate}: the model has no ground reaction force"
                + (f"; {self.touch} rows in between touch the ground and stay in" if self.touch else ""))


def ground_rows(log: FlightLog, where: str | None = None) -> GroundRows | None:
    """The rows of ``log`` on the ground at its start and end (:class:`GroundRows`); None when
    it neither starts nor ends with its rotors stopped (or, without a height or an
    accelerometer, cannot tell when it flies), or it flies from its first row to its last.

    The model has no ground reaction force, and a log written by a user's own tool (not an
    importer, which trims its flights) may hold the vehicle standing before take-off and after
    touchdown (a blind audit's: rotors stopped in 15 % of the rows, on the floor in 23 %; the
    fit's thrust was told to carry 79 % of the weight, Kd[2] ended on its bound). Only a log
    that starts or ends with every rotor stopped (:data:`ROTORS_STOPPED_SHARE`) is judged:
    then :func:`flight_from_height` finds the flight, its take-off height five times the
    height's noise at rest (at least 1 cm) above the resting height, the motors running; a log
    without a height, from motor start to motor stop (:func:`flight_from_imu`). A log that
    begins in the air has none.

    Raises:
        GreyboxInputError: the vehicle never leaves the ground.
    """
    if not log.input_names or not log.input_names[0].startswith("w") or log.t.size < 10:
        return None
    n_rot = sum(1 for n in log.input_names if n[1:].isdigit())
    speeds = np.abs(log.inputs[:, :n_rot])
    turning = speeds.max(axis=1)
    if not np.any(turning > 0):
        return None
    stopped = turning < ROTORS_STOPPED_SHARE * float(np.median(turning[turning > 0]))
    if not (stopped[0] or stopped[-1]):
        return None
    where = where or log.source or "the log"
    if log.measures("z"):
        height = -log.output("z")
        rest_rows = np.flatnonzero(stopped[:np.argmin(stopped)] if stopped[0] else stopped)
        at_rest = height[rest_rows][np.isfinite(height[rest_rows])]
        noise = float(np.std(np.diff(at_rest)) / math.sqrt(2)) if at_rest.size >= 5 else 0.0
        span = flight_from_height(log.t, height, ~stopped, where, takeoff_height=max(0.01, 5 * noise),
                                  hint=" (its rotors stopped at its start or end: a vehicle standing on the ground)")
    elif all(log.measures(n) for n in ("ax", "ay", "az")):
        # an IMU-only log: from motor start to motor stop, as the uSD importer takes it
        span = flight_from_imu(log.t, np.column_stack([log.output(n) for n in ("ax", "ay", "az")]), ~stopped, where)
    else:
        return None
    before, after = span.k0, log.t.size - 1 - span.k1
    if before == 0 and after == 0:
        return None
    found = (span.note if math.isnan(span.rest_height) else
             f"{span_words(log.t, span.k0, span.k1)}, resting height {span.rest_height:.3f} m")
    return GroundRows(span.k0, span.k1,
                      f"{where}: on the ground at its {'start and end' if before and after else 'start' if before else 'end'}"
                      f" ({found}; rotors stopped in {100 * stopped.mean():.0f} % of the rows): the {before} rows "
                      f"before and {after} after", int(span.on_ground[span.k0:span.k1 + 1].sum()))


def airborne_log(log: FlightLog, where: str | None = None) -> FlightLog:
    """``log`` without the rows on the ground at its start and end (:func:`ground_rows`), a note
    saying so; ``log`` itself when there are none."""
    ground = ground_rows(log, where)
    if ground is None:
        return log
    out = log.slice(ground.k0, ground.k1 + 1)
    out.notes.append(ground.words("left out, as the importers do"))
    return out


def flight_from_imu(t: np.ndarray, specific_force: np.ndarray, running: np.ndarray, where: str,
                    impact_g: float = 3.0, margin: float = 0.01, min_samples: int = 20) -> FlightSpan:
    """The flight of a log without a height: from the first to the last sample with the
    motors running, ended ``margin`` seconds before the first impact (specific force above
    ``impact_g`` g, far beyond what flight produces; a crash or a hard landing).

    Without a height the lift-off is not seen: the first moments after the motors start
    (and the last before they stop) may be on the ground; the note says so.

    Raises:
        GreyboxInputError: the motors never run.
    """
    running = np.asarray(running, dtype=bool)
    on = np.flatnonzero(running)
    if on.size < min_samples:
        raise GreyboxInputError(f"{where}: the motors never run (all commands zero): nothing to identify")
    k0, k1 = int(on[0]), int(on[-1])
    note = ""
    f = np.linalg.norm(np.asarray(specific_force, dtype=float), axis=1) / G0
    hit = np.flatnonzero(np.nan_to_num(f[k0:k1 + 1]) > impact_g)
    if hit.size:
        k_hit = k0 + int(hit[0])
        k_end = int(np.searchsorted(t, t[k_hit] - margin, side="right") - 1)
        if k_end - k0 + 1 < min_samples:
            raise GreyboxInputError(f"{where}: an impact ({f[k_hit]:.1f} g at {t[k_hit]:.2f} s) right after the "
                                    "motors start: nothing to identify")
        note = (f"impact at {t[k_hit]:.3f} s (specific force {np.nanmax(f[k_hit:k1 + 1]):.1f} g, above "
                f"{impact_g:g} g): the flight ends {margin * 1000:.0f} ms before it")
        k1 = k_end
    on_ground = np.ones(len(t), dtype=bool)
    on_ground[k0:k1 + 1] = False
    note = (f"motors run from {t[k0]:.2f} s to {t[on[-1]]:.2f} s; flight taken as {t[k0]:.2f}-{t[k1]:.2f} s "
            "(no height in the log: the moments on the ground after the motors start are not "
            "seen and stay in)" + (f"; {note}" if note else ""))
    return FlightSpan(k0, k1, on_ground, math.nan, note)


# ------------------------------------------------------------------ one time base

def grid_with(base: np.ndarray, *others: np.ndarray, tol: float | None = None) -> np.ndarray:
    """Rows of a multi-rate log: the ``base`` stamps (the fastest sensor's, say) plus each
    stamp of ``others`` farther than ``tol`` (default half the base's median step) from every
    base stamp (samples that fall in a gap of the base sensor). Sorted, unique."""
    base = np.asarray(base, dtype=float)
    if tol is None:
        tol = 0.5 * float(np.median(np.diff(base))) if base.size > 1 else 0.0
    extra = []
    for o in others:
        o = np.asarray(o, dtype=float)
        if o.size == 0:
            continue
        pos = np.clip(np.searchsorted(base, o), 1, max(base.size - 1, 1))
        d = np.minimum(np.abs(o - base[pos - 1]), np.abs(base[np.minimum(pos, base.size - 1)] - o))
        extra.append(o[d > tol])
    return np.unique(np.concatenate([base] + extra)) if extra else np.unique(base)


def snap(t_grid: np.ndarray, t_s: np.ndarray, values: np.ndarray, tol: float | None = None) -> np.ndarray:
    """Samples ``values`` (m,) or (m, k) taken at ``t_s`` placed on their nearest row of
    ``t_grid`` (within ``tol``, default half the grid's median step); NaN on every other
    row. Where two samples fall on one row, the nearer one wins."""
    t_grid = np.asarray(t_grid, dtype=float)
    t_s = np.asarray(t_s, dtype=float)
    values = np.asarray(values, dtype=float)
    vec = values.ndim == 1
    values = values.reshape(t_s.size, -1)
    if tol is None:
        tol = 0.5 * float(np.median(np.diff(t_grid))) if t_grid.size > 1 else np.inf
    out = np.full((t_grid.size, values.shape[1]), np.nan)
    if t_s.size and t_grid.size:
        pos = np.clip(np.searchsorted(t_grid, t_s), 0, t_grid.size - 1)
        left = np.clip(pos - 1, 0, t_grid.size - 1)
        pick = np.where(np.abs(t_grid[left] - t_s) < np.abs(t_grid[pos] - t_s), left, pos)
        d = np.abs(t_grid[pick] - t_s)
        ok = d <= tol * (1 + 1e-9)
        # nearer samples last, so that they win on a shared row
        order = np.argsort(-d[ok], kind="stable")
        rows, vals = pick[ok][order], values[ok][order]
        out[rows] = vals
    return out[:, 0] if vec else out


def trimmed_log(t_all: np.ndarray, rotor_speeds: np.ndarray, outputs: Mapping[str, np.ndarray],
                extras: Mapping[str, np.ndarray], notes: list[str], source: str | None, k0: int, k1: int,
                keep_ground: bool, trim_note: str) -> FlightLog:
    """:func:`assemble_log` of rows ``k0..k1`` (the flight), or of every row with
    ``keep_ground``, times from 0; a note says which (``trim_note`` is formatted with
    ``before`` and ``after``, the rows dropped on either side)."""
    sl = slice(None) if keep_ground else slice(k0, k1 + 1)
    if keep_ground:
        notes.append("kept the samples on the ground (flagged by on_ground): the model has no ground reaction "
                     "force, so do not fit them")
    else:
        notes.append(trim_note.format(before=k0, after=t_all.size - 1 - k1))
    t_kept = t_all[sl]
    return assemble_log(t_kept - t_kept[0], rotor_speeds[sl], {k: v[sl] for k, v in outputs.items()},
                        {k: v[sl] for k, v in extras.items()}, notes, source)


def assemble_log(t: np.ndarray, rotor_speeds: np.ndarray, outputs: Mapping[str, np.ndarray],
                 extras: Mapping[str, np.ndarray] | None = None, notes: list[str] | None = None,
                 source: str | None = None, input_names: list[str] | None = None) -> FlightLog:
    """A flight log on one time base ``t`` (s): inputs ``w1..wN`` (rad/s, never missing) and
    the outputs given by name (each (n,), NaN where that sensor has no sample). The required
    outputs ``x, y, z, phi, theta, psi`` are always columns (all NaN when the source has
    none); ``p, q, r`` are columns when given. Dropouts are filled as a CSV's are
    (:meth:`~greybox.data.FlightLog.fill_gaps`), so the log in memory is the one its CSV
    loads as; the note that says so is added to ``notes`` too (an importer's notes)."""
    t = np.asarray(t, dtype=float)
    W = np.asarray(rotor_speeds, dtype=float).reshape(t.size, -1)
    unknown = set(outputs) - set(REQUIRED_OUTPUTS) - set(OPTIONAL_OUTPUTS)
    if unknown:
        raise ValueError(f"not output channels: {sorted(unknown)} (use extras)")
    names = REQUIRED_OUTPUTS + [n for n in OPTIONAL_OUTPUTS if n in outputs]
    nan = np.full(t.size, np.nan)
    Y = np.column_stack([np.asarray(outputs.get(n, nan), dtype=float).reshape(t.size) for n in names])
    log = FlightLog(t, W, input_names or [f"w{i + 1}" for i in range(W.shape[1])], Y, names,
                    dict(extras or {}), list(notes or []), source).fill_gaps()
    if notes is not None:
        notes.extend(log.notes[len(notes):])
    return log


# ------------------------------------------------------------------------ result

@dataclass
class ImportResult:
    """What an importer returns: the flight log and what was found on the way.

    Attributes:
        log: the flight log (README, "Flight log (CSV)"), times from 0 at its first row.
        takeoff_time, touchdown_time: s from the start of the source file (NaN if the
            vehicle never flew, e.g. a bench log imported with ``keep_ground``).
        rest_height: resting height of the tracked origin in the source's z-up frame, m
            (NaN when the source has no height).
        hover_rotor_speed: rms rotor speed in flight, rad/s (NaN if never flown): the
            starting guess of ``K_T = m g / (N w^2)``.
        notes: what the importer found and did, in words (also in ``log.notes``).
        format: ``"nanobench"``, ``"px4"``, ``"crazyflie-usd"``.
        pwm_map: the ``(a, c)`` used for motor commands (None when rotor speeds were logged).
        n_rotors: number of motors read.
    """

    log: FlightLog
    takeoff_time: float
    touchdown_time: float
    rest_height: float
    hover_rotor_speed: float
    notes: list[str] = field(default_factory=list)
    format: str = ""
    pwm_map: tuple[float, float] | None = None
    n_rotors: int = 4

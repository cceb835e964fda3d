"""Importers: logs of other tools as greybox flight logs (README, "Flight log (CSV)").

One function per format, each returning an :class:`ImportResult` (the log plus what was
found on the way), all built on the shared parts in :mod:`greybox.io.base` (frames, units,
time bases, held samples, ground contact, one time base; :func:`airborne_log` trims a
greybox CSV log's time on the ground as the importers do):

* :func:`import_nanobench`: NanoBench CSV (Crazyflie 2.1, Vicon + onboard logs).
* :func:`import_px4`: PX4 ULog (needs the optional ``pyulog``: ``pip install 'greybox[px4]'``).
* :func:`import_crazyflie_usd`: the Crazyflie's onboard uSD-card binary log (event-based,
  versions 1 and 2).

The CLI: ``greybox import nanobench|px4|crazyflie-usd FILE --out LOG.csv [--airframe-out A.toml]``.
"""
from __future__ import annotations

from .base import (CRAZYFLIE_PWM_MAP, G0, PX4_PWM_MAP, FlightSpan, ImportResult, PwmMap, GroundRows, airborne_log, assemble_log,
                   commands_on_grid, deg_to_rad, euler_from_quaternion, euler_zup_to_ned, flight_from_height, held_run_knots,
                   flight_from_imu, flu_to_frd, fresh_rows, g_to_ms2, grid_with, held_inputs, interpolate_fresh,
                   interpolate_held_inputs,
                   parse_pwm_map, pwm_to_rotor_speed, rpm_to_rad_s, snap, time_base, wrap_angle, zup_to_ned)
from .crazyflie_usd import import_crazyflie_usd, read_usd_log
from .nanobench import NanoBenchImport, crazyflie_airframe_toml, import_nanobench
from .px4 import import_px4, px4_airframe_toml

__all__ = ["import_nanobench", "import_px4", "import_crazyflie_usd", "read_usd_log", "ImportResult",
           "NanoBenchImport", "crazyflie_airframe_toml", "px4_airframe_toml", "PwmMap", "FlightSpan",
           "CRAZYFLIE_PWM_MAP", "PX4_PWM_MAP", "G0", "pwm_to_rotor_speed", "parse_pwm_map", "flu_to_frd",
           "zup_to_ned", "euler_zup_to_ned", "euler_from_quaternion", "wrap_angle", "deg_to_rad", "g_to_ms2",
           "rpm_to_rad_s", "time_base", "fresh_rows", "interpolate_fresh", "commands_on_grid", "held_run_knots",
           "held_inputs", "interpolate_held_inputs",
           "flight_from_height", "flight_from_imu", "airborne_log", "ground_rows", "GroundRows", "grid_with", "snap", "assemble_log"]

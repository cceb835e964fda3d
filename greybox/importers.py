"""Old home of the NanoBench importer, kept so that existing imports work.

The importers live in :mod:`greybox.io` now (shared parts in :mod:`greybox.io.base`,
NanoBench in :mod:`greybox.io.nanobench`, PX4 ULog in :mod:`greybox.io.px4`, the Crazyflie
uSD log in :mod:`greybox.io.crazyflie_usd`).
"""
from __future__ import annotations

from .io.base import CRAZYFLIE_PWM_MAP, G0, ImportResult, pwm_to_rotor_speed
from .io.nanobench import PWM_MAX, NanoBenchImport, crazyflie_airframe_toml, import_nanobench

__all__ = ["import_nanobench", "NanoBenchImport", "CRAZYFLIE_PWM_MAP", "crazyflie_airframe_toml",
           "pwm_to_rotor_speed", "ImportResult", "G0", "PWM_MAX"]

"""How much of a real Crazyflie's roll and pitch acceleration do its logged motor commands
explain, band by band?

    python experiments/real_torque_bands.py [FILES...]

For each NanoBench flight (default: every ``../shared/realdata/nanobench/*.csv``), the roll
and pitch angular acceleration (a Savitzky–Golay derivative of the gyro) is compared with
the torque the logged rotor speeds give through the airframe's geometry (Förster's PWM map,
the hover ``K_T`` of a 30 g vehicle, the 46 mm arm and Förster's inertia:
``K_T sum_i (-y_i) w_eff_i^2 / J_x`` and the same with ``x_i``), ``w_eff`` the logged speeds
through a first-order lag of ``TAU`` s (the uSD log's IMU-only fit: 45 ms; 43 ms since its
torques act over each log step) and a further delay of 0-3 samples. Both are band-pass
filtered (zero phase) and regressed on each other per band:
``gain`` (1 when the geometry is right) and the correlation ``r``, at the delay with the
highest ``r``.

What it shows on these flights: below 1 Hz the commands' torque varies by several rad/s²
while the vehicle hardly accelerates (r near 0): the controller cancels a slow moment the
log does not show (drag acting above the centre of gravity, an offset centre of gravity), so
a broadband regression of acceleration on commands (the IMU-only fit's ``g_x, g_y``) is
pulled towards zero by the closed loop. At 3-8 Hz the commands explain the acceleration
(r about 0.9) with a gain of about 0.7: the vehicle's roll/pitch inertia is about 1.4 times
Förster's (a motion-capture deck and markers), or its torque per PWM about 0.7 times the
map's. Writes ``experiments/out/real_torque_bands.md``.
"""
from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

import numpy as np
from scipy.signal import butter, filtfilt, lfilter, savgol_filter

from greybox.airframe import airframe_from_dict
from greybox.importers import crazyflie_airframe_toml, import_nanobench

from real_crazyflie import MASS, nanobench_files  # the sibling script: the vehicle, how flights are named

HERE = Path(__file__).resolve().parent
TAU = 0.045
BANDS = ((0.1, 1.0), (1.0, 3.0), (3.0, 8.0), (8.0, 20.0))
DELAYS = range(0, 4)


def roll_pitch_acceleration(log) -> np.ndarray:
    """(n, 2) roll and pitch angular acceleration of a log: a Savitzky-Golay derivative of
    its gyro (p, q), missing samples interpolated."""
    t = log.t
    om = np.column_stack([log.output(c) for c in "pq"])
    ok = np.isfinite(om).all(axis=1)
    om = np.column_stack([np.interp(t, t[ok], om[ok, i]) for i in range(2)])
    return savgol_filter(om, 7, 2, deriv=1, delta=float(np.median(np.diff(t))), axis=0)


def bands(path: Path) -> dict[str, list[tuple[float, float, int]]]:
    """{axis: [(gain, r, delay in samples) per band]}."""
    imp = import_nanobench(path)
    log = imp.log
    t = log.t
    dt = float(np.median(np.diff(t)))
    om_dot = roll_pitch_acceleration(log)
    af = airframe_from_dict(tomllib.loads(crazyflie_airframe_toml(MASS, imp.hover_rotor_speed)), "crazyflie")
    J = np.diag(np.asarray(af.inertia, dtype=float))
    K_T = MASS * af.gravity / (4 * imp.hover_rotor_speed ** 2)
    a = np.exp(-dt / TAU)
    w = log.inputs[:, :4]
    w2 = (lfilter([1 - a], [1, -a], w - w[0], axis=0) + w[0]) ** 2
    P = af.rotor_positions
    torque = {"roll": K_T * (w2 @ -P[:, 1]) / J[0], "pitch": K_T * (w2 @ P[:, 0]) / J[1]}
    out: dict[str, list[tuple[float, float, int]]] = {}
    edge = 30
    for k, (axis, u) in enumerate(torque.items()):
        rows = []
        for lo, hi in BANDS:
            b, a_ = butter(2, [lo, min(hi, 0.45 / dt)], btype="band", fs=1 / dt)
            y = filtfilt(b, a_, om_dot[:, k])[edge:-edge]
            best = None
            for d in DELAYS:
                x = filtfilt(b, a_, np.roll(u, d))[edge:-edge]
                r = float(np.corrcoef(x, y)[0, 1])
                if best is None or r > best[1]:
                    best = (float(x @ y / (x @ x)), r, d)
            rows.append(best)
        out[axis] = rows
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--out", type=Path, default=HERE / "out" / "real_torque_bands.md")
    a = ap.parse_args()
    files = nanobench_files(a.files)
    head = " | ".join(f"{lo:g}-{hi:g} Hz" for lo, hi in BANDS)
    lines = [f"| flight | axis | {head} |", "|---|---|" + "---|" * len(BANDS)]
    for f in files:
        for axis, rows in bands(f).items():
            cells = " | ".join(f"{g:.2f} (r {r:.2f}, +{d})" for g, r, d in rows)
            lines.append(f"| {f.stem} | {axis} | {cells} |")
        print("\n".join(lines[-2:]), flush=True)
    print("cells: gain against the geometry (r, extra delay in samples beyond the lag)")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

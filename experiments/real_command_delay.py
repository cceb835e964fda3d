"""How late does a real Crazyflie act on its logged motor commands, and does the model predict
better for knowing it?

    python experiments/real_command_delay.py [FILES...]

For each NanoBench flight (default: every ``../shared/realdata/nanobench/*.csv``):

* **cross-correlation** (no fit): the roll and pitch angular acceleration (a Savitzky–Golay
  derivative of the gyro, onboard, on the motors' clock) against the moment the logged rotor
  speeds give through the airframe's geometry, both band-passed to 1-8 Hz; the delay of the
  commands (0-100 ms, 10-ms steps) with the highest correlation;
* **fits**: the model the diagnosis ends with on most flights (``cog_offset``,
  ``drag_moment``, ``moment_gain``), fitted with process noise on the first 80 %, with and
  without ``command_delay``; ``tau_cmd`` (± std), ``k_M``, and on the last 20 % the RMS
  prediction error 0.25 s and 0.5 s ahead against the naive predictor (windows every 0.1 s)
  on x, y, z, phi, theta, psi.

Writes ``experiments/out/real_command_delay.md`` (the table in the README, "Real flights").
"""
from __future__ import annotations

import argparse
import tomllib
import warnings
from pathlib import Path

import numpy as np
from scipy.signal import butter, filtfilt

from greybox import QuadrotorModel, effects, fit
from greybox.airframe import airframe_from_dict
from greybox.importers import crazyflie_airframe_toml, import_nanobench
from greybox.validation import horizon_errors, prediction_options

from real_crazyflie import MASS, nanobench_files  # the sibling scripts: the vehicle, how flights are named,
from real_torque_bands import roll_pitch_acceleration  # the gyro's derivative

HERE = Path(__file__).resolve().parent
BAND = (1.0, 8.0)
CHANNELS = ("x", "y", "z", "phi", "theta", "psi")
FINAL = ("cog_offset", "drag_moment", "moment_gain")


def correlation_delay(log, airframe) -> tuple[float, float, float]:
    """(delay s, correlation, correlation without delay): the delay of the commands that
    maximises the 1-8 Hz correlation of the gyro-derived roll and pitch acceleration with the
    logged speeds' moment, over 0-100 ms."""
    t = log.t
    dt = float(np.median(np.diff(t)))
    acc = roll_pitch_acceleration(log)
    P = np.asarray(airframe.rotor_positions, dtype=float)
    w2 = log.inputs[:, :4] ** 2
    moment = np.column_stack([w2 @ -P[:, 1], w2 @ P[:, 0]])    # FRD: thrust along -z
    b, a = butter(2, BAND, btype="band", fs=1 / dt)
    acc, moment = filtfilt(b, a, acc, axis=0), filtfilt(b, a, moment, axis=0)
    k = np.arange(20, t.size - 20)
    r = [float(np.mean([np.corrcoef(acc[k, i], moment[k - lag, i])[0, 1] for i in range(2)]))
         for lag in range(0, int(round(0.1 / dt)) + 1)]
    best = int(np.argmax(r))
    return best * dt, r[best], r[0]


def flight(path: Path) -> dict:
    imp = import_nanobench(path)
    af = airframe_from_dict(tomllib.loads(crazyflie_airframe_toml(
        MASS, imp.hover_rotor_speed, ground_z=-(imp.rest_height - 0.025))), path.stem)
    est, val = imp.log.split(0.8)
    row = {"flight": path.stem, "xcorr": correlation_delay(imp.log, af)}
    for label, extra in (("without", ()), ("with", ("command_delay",))):
        model = QuadrotorModel(af, list(QuadrotorModel(af).effect_names) + list(extra) + list(FINAL))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = fit(model, est, process_noise="auto", progress=False)
        he = horizon_errors(model, res.p, val, horizons=[0.25, 0.5], **prediction_options(res))
        k = {h: he.horizons.index(h) for h in (0.25, 0.5)}
        beats = sum(he.model[c][k[h]] < he.naive[c][k[h]] for c in CHANNELS for h in k)
        std = dict(zip(res.free_names, res.std))
        row[label] = {"certified": bool(res.converged), "k_M": res.value("k_M"), "beats": int(beats),
                      "tau_cmd": (res.value("tau_cmd"), float(std.get("tau_cmd", np.nan))) if extra else None,
                      "phi": [he.model["phi"][k[h]] for h in k], "theta": [he.model["theta"][k[h]] for h in k],
                      "naive_phi": [he.naive["phi"][k[h]] for h in k]}
        print(f"{path.stem}: {label} command_delay: {row[label]}", flush=True)
    return row


def markdown(rows: list[dict]) -> str:
    out = ["| flight | cross-correlation delay (ms, r; r at 0 ms) | tau_cmd (ms) | k_M without → with | certified | "
           "beats naive (of 12) without → with | phi 0.25 s (rad) without → with (naive) | "
           "theta 0.25 s without → with |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        a, b = r["without"], r["with"]
        tau, s = b["tau_cmd"]
        out.append(f"| {r['flight']} | {1e3 * r['xcorr'][0]:.0f} ({r['xcorr'][1]:.2f}; {r['xcorr'][2]:.2f}) | {1e3 * tau:.1f} ± {1e3 * s:.1f} | "
                   f"{a['k_M']:.3f} → {b['k_M']:.3f} | {'yes' if a['certified'] and b['certified'] else 'no'} | "
                   f"{a['beats']} → {b['beats']} | {a['phi'][0]:.3f} → {b['phi'][0]:.3f} ({a['naive_phi'][0]:.3f}) | "
                   f"{a['theta'][0]:.3f} → {b['theta'][0]:.3f} |")
    total = [sum(r[k]["beats"] for r in rows) for k in ("without", "with")]
    out.append(f"\nBeats naive over all flights: {total[0]} → {total[1]} of {12 * len(rows)}.")
    return "\n".join(out) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("files", nargs="*", type=Path)
    args = ap.parse_args()
    rows = [flight(f) for f in nanobench_files(args.files)]
    text = markdown(rows)
    out = HERE / "out" / "real_command_delay.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()

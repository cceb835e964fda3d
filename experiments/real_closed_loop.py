"""A model of the closed loop on real Crazyflie flights: the vehicle model flown by its
controller's law fitted to the log (greybox.controller_law), predicting 0.25 and 0.5 s ahead
beside the naive predictor and beside the same model open loop.

    python experiments/real_closed_loop.py [FILES...] [--effects cog_offset,drag_moment,moment_gain]
                                           [--models DIR] [--variants] [--out experiments/out/real_closed_loop.md]

For each NanoBench flight (default: every ``../shared/realdata/nanobench/*.csv``): import (the
setpoints ``sp_ctrltarget_*`` become ``x_ref .. psi_ref``), split 80/20, fit the model (the base
model plus ``--effects``; default the three every diagnosis of these flights holds or nearly
so: the CoG offset, the drag moment, the moment gain) on the first part with
``process_noise="auto"``, fit the controller's law on the same part, and score on the last 20 %:
the open-loop prediction as the fit reports it (:func:`greybox.validation.horizon_errors_after`:
its start options, a held moment where that predicts the estimation data better) and the
closed-loop one (:func:`greybox.closed_loop_horizon_errors`,
its defaults), both beside the naive predictor, windows every 0.1 s. ``--models DIR``: fly
each flight's final model of a diagnosis instead (``DIR/<flight>_final_model.json``, saved by
``experiments/real_crazyflie.py``), as fitted, with its open-loop prediction as the diagnosis
makes it (:func:`greybox.validation.horizon_errors_after`). ``--variants`` also
scores the closed loop with the held trim, with the estimated start, with a law that takes
the measured attitude for the thrust's (``fit_level=False``) and with the thrust axis' own
delay (``axis_delays=("thrust",)``): the choices its defaults make.
Writes the markdown tables to ``--out``.
"""
from __future__ import annotations

import argparse
import copy
import time
import tomllib
from pathlib import Path

import numpy as np

from greybox import ControllerLaw, QuadrotorModel, closed_loop_horizon_errors, load, predict
from greybox.airframe import airframe_from_dict
from greybox.fitting import fit
from greybox.importers import crazyflie_airframe_toml, import_nanobench
from greybox.validation import horizon_errors_after, prediction_options

HERE = Path(__file__).resolve().parent
REAL = HERE.parents[1] / "shared" / "realdata" / "nanobench"
MASS = 0.030
CHANNELS = ("x", "y", "z", "phi", "theta", "psi")
HORIZONS = (0.25, 0.5)
EFFECTS = "cog_offset,drag_moment,moment_gain"


def _at(he, h: float, ch: str) -> tuple[float, float]:
    i = min(range(len(he.horizons)), key=lambda k: abs(he.horizons[k] - h))
    return he.model[ch][i], he.naive[ch][i]


def beats(he, h: float) -> list[str]:
    return [ch for ch in CHANNELS if he.beats_naive(ch, h)]


def run(path: Path, effects: list[str], variants: bool, models: Path | None = None) -> dict:
    t0 = time.perf_counter()
    imp = import_nanobench(path)
    est, val = imp.log.split(0.8)
    if models is not None:
        res = load(models / f"{path.stem}_final_model.json")
        model = res.model
    else:
        toml = crazyflie_airframe_toml(MASS, imp.hover_rotor_speed, ground_z=-(imp.rest_height - 0.025))
        af = airframe_from_dict(tomllib.loads(toml), f"{path.stem} airframe")
        model = QuadrotorModel(af, effects)
        res = fit(model, est, process_noise="auto")
    # the open-loop report as the fit or diagnosis makes it (its start options, a held moment
    # where that predicts the estimation data better)
    open_loop = horizon_errors_after(res, [predict(model, res.p, val, horizon=0.5, **prediction_options(res))],
                                     [res.p], est=[est])
    law = ControllerLaw().fit(model, est)
    # a saved model keeps no certificate: None
    out = {"flight": path.stem, "certified": getattr(res, "converged", None), "law": law, "open": open_loop,
           "closed": closed_loop_horizon_errors(model, res.p, law, val, horizons=HORIZONS)}
    if variants:
        out["closed, held trim"] = closed_loop_horizon_errors(model, res.p, law, val, horizons=HORIZONS,
                                                              held_trim=True)
        out["closed, estimated start"] = closed_loop_horizon_errors(model, res.p, law, val, horizons=HORIZONS,
                                                                    measured_start=False)
        # the gains and trims do not depend on the level (ControllerLaw.fit): the same law, level zero
        unlevelled = copy.copy(law)
        unlevelled.level_ = np.zeros(2)
        out["closed, no level"] = closed_loop_horizon_errors(model, res.p, unlevelled, val, horizons=HORIZONS)
        # the thrust axis' delay its own (the attitude axes sharing the joint one)
        thrust_own = ControllerLaw(axis_delays=("thrust",)).fit(model, est)
        out["closed, thrust's own delay"] = closed_loop_horizon_errors(model, res.p, thrust_own, val,
                                                                       horizons=HORIZONS)
    out["what"] = ("each flight's final model of its diagnosis" if models is not None else
                   "the base model with " + ", ".join(effects) + ", fitted on the first 80 %")
    out["seconds"] = time.perf_counter() - t0
    return out


def markdown(rows: list[dict]) -> str:
    preds = [k for k in rows[0] if k == "open" or k.startswith("closed")]
    lines = [f"Model: {rows[0]['what']}.", "", "Channels of x, y, z, phi, theta, psi where the prediction beats the naive predictor "
             "(last 20 % of each flight, windows every 0.1 s):", "",
             "| flight | fit certified | law: delay, R² roll/pitch | predictor | at 0.25 s | at 0.5 s |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        law = r["law"]
        for k in preds:
            lines.append(f"| {r['flight']} | {'-' if r['certified'] is None else 'yes' if r['certified'] else 'no'} | "
                         f"{1e3 * law.delay_:.0f} ms, {law.r2_['roll']:.2f}/{law.r2_['pitch']:.2f} | {k} | "
                         + " | ".join(", ".join(beats(r[k], h)) or "-" for h in HORIZONS) + " |")
    lines += ["", "RMS prediction error, closed loop / open loop / naive (m, rad):", "",
              "| flight | ahead | " + " | ".join(CHANNELS) + " |", "|---|---|" + "---|" * len(CHANNELS)]
    for r in rows:
        for h in HORIZONS:
            cells = []
            for ch in CHANNELS:
                c, n = _at(r["closed"], h, ch)
                o, _ = _at(r["open"], h, ch)
                cells.append(f"{c:.3f} / {o:.3f} / {n:.3f}")
            lines.append(f"| {r['flight']} | {h:g} s | " + " | ".join(cells) + " |")
    total = {k: sum(len(beats(r[k], h)) for r in rows for h in HORIZONS) for k in preds}
    lines += ["", "Channel-horizons beating naive over the flights (of "
              f"{len(rows) * len(HORIZONS) * len(CHANNELS)}): "
              + ", ".join(f"{k} {v}" for k, v in total.items())]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--effects", default=EFFECTS, help="effects added to the base model (comma separated)")
    ap.add_argument("--variants", action="store_true", help="also the held trim, the estimated start, the law without its level and the thrust axis' own delay")
    ap.add_argument("--models", type=Path, help="fly the diagnoses' final models saved in this folder")
    ap.add_argument("--out", type=Path, default=HERE / "out" / "real_closed_loop.md")
    a = ap.parse_args()
    files = a.files or sorted(REAL.glob("*.csv"))
    effects = [e for e in a.effects.split(",") if e]
    rows = []
    for f in files:
        r = run(f, effects, a.variants, a.models)
        rows.append(r)
        print(f"{r['flight']}: {r['law']}; " + "; ".join(
            f"{k} beats naive on {len(beats(r[k], 0.25))}+{len(beats(r[k], 0.5))}/12"
            for k in r if k == "open" or k.startswith("closed")) + f" ({r['seconds']:.0f} s)", flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(markdown(rows))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

"""The diagnosis on effects whose functional form is *not* the catalogue's: does it still
name the closest catalogue effect, and does adding it still help?

    python experiments/diagnose_foreign.py [--rate 200] [--duration 30] [case ...]

Each hidden effect below is written here, outside the package, with its own form and
magnitude; the base model is diagnosed as in ``diagnose_effects.py`` (estimation on one
flight, validation on another of the same manoeuvres). Expected: the catalogue effect of
the same physics is the verdict.

* ``exp_ground``  thrust x (1 + 0.5 exp(-h / 0.07 m)) near the ground  -> ground_effect
* ``gusty_wind``  wind drifting slowly in speed and direction          -> wind
* ``battery_sag`` thrust x (1 - 0.06 (1 - exp(-t / 15 s)))             -> thrust_drift
* ``cubic_drag``  drag -0.006 |v|^2 v (cubic in speed)                 -> quadratic_drag
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import casadi as ca

from diagnose_effects import affected_fall, fly_and_diagnose   # the same two-flight design
from greybox import QuadrotorModel, load_airframe
from greybox.effects import Effect

HERE = Path(__file__).resolve().parent


class ExpGround(Effect):
    name = "exp_ground"

    def modify(self, ctx):
        h = ca.fmax(ctx.airframe.ground_z - ctx.pos[2], 0.0)
        ctx.thrust_scale *= 1.0 + 0.5 * ca.exp(-h / 0.07)


class GustyWind(Effect):
    name = "gusty_wind"

    def modify(self, ctx):
        t = ctx.t
        w = ca.vertcat(1.0 + 0.4 * ca.sin(2 * math.pi * 0.05 * t), -0.8 + 0.3 * ca.cos(2 * math.pi * 0.07 * t), 0.0)
        ctx.v_air = ctx.v_air - w


class BatterySag(Effect):
    name = "battery_sag"

    def modify(self, ctx):
        ctx.thrust_scale *= 1.0 - 0.06 * (1.0 - ca.exp(-ctx.t / 15.0))


class CubicDrag(Effect):
    name = "cubic_drag"

    def add_forces(self, ctx):
        ctx.force_world -= 0.006 * ca.sumsqr(ctx.v_air) * ctx.v_air


CASES = {"exp_ground": (ExpGround, "ground_effect"), "gusty_wind": (GustyWind, "wind"),
         "battery_sag": (BatterySag, "thrust_drift"), "cubic_drag": (CubicDrag, "quadratic_drag")}


def case(base: QuadrotorModel, name: str, duration: float, seed: int, rate: float) -> dict:
    cls, expected = CASES[name]
    truth = base + cls()
    d, dt = fly_and_diagnose(truth, truth.default_parameters(), base, duration, seed, rate)
    return {"hidden": name, "expected": expected, "verdict": d.verdict,
            "first": d.ranking[0].effect if d.ranking else None, "time_s": dt,
            "nrmse_before": d.baseline_prediction.total, **affected_fall(d, expected)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="*", choices=[[], *CASES], default=[])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--rate", type=float, default=200.0)
    a = ap.parse_args()
    base = QuadrotorModel(load_airframe(HERE.parent / "greybox" / "data" / "airframes" / "paper.toml"))
    rows = []
    for n in a.cases or list(CASES):
        r = case(base, n, a.duration, a.seed, a.rate)
        rows.append(r)
        ok = r["verdict"] == r["expected"] and r.get("fall_pct", 0) >= 30
        print(f"{'OK ' if ok else 'BAD'} hidden {n:<12} expected {r['expected']:<15} verdict {str(r['verdict']):<15} "
              f"fall {r.get('fall_pct', float('nan')):6.1f} %  ({r['time_s']:.0f} s)", flush=True)
    (HERE / "out").mkdir(exist_ok=True)
    (HERE / "out" / "diagnose_foreign.json").write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()

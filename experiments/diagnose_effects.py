"""The diagnosis on every catalogue effect: for each, a synthetic flight with that effect
hidden, the base model diagnosed; prints whether the effect is ranked first and how much
the validation nrmse of the channels it affects falls. Also a flight with nothing hidden
(verdict must be null) and the seed paper's Fig. 1 case (a model without yaw_torque).

    python experiments/diagnose_effects.py [--duration 30] [--seed 3] [--rate 1000] [effect ...]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from greybox import QuadrotorModel, effects, load_airframe
from greybox.diagnosis import CHANNEL_EFFECTS, diagnose
from greybox.synth import model_with_hidden_effects, synthesize

HERE = Path(__file__).resolve().parent


def case(base: QuadrotorModel, hidden: str | None, duration: float, seed: int, rate: float = 1000.0) -> dict:
    if hidden in base.effects:       # a base effect (seed Fig. 1: yaw_torque): normal data, model without it
        truth, p = base, base.default_parameters()
        model = base.without(hidden)
    elif hidden is None:
        truth, p, model = base, base.default_parameters(), base
    else:
        truth, p = model_with_hidden_effects(base, [hidden])
        model = base
    from greybox.synth import SensorSpec
    log = synthesize(truth, p, duration=duration, seed=seed, sensors=SensorSpec(rate=rate, vision_rate=min(60.0, rate)),
                     manoeuvres=["hover", "ground", "step_x", "fast", "step_z", "yaw", "step_y"]).log
    t0 = time.perf_counter()
    d = diagnose(model, log, iterate=False)
    dt = time.perf_counter() - t0
    out = {"hidden": hidden, "verdict": d.verdict, "first": d.ranking[0].effect if d.ranking else None,
           "time_s": dt, "nrmse_before": d.baseline_prediction.total}
    if hidden is not None and d.ranking:
        c = next((c for c in d.ranking if c.effect == hidden), None)
        if c is not None and c.channels_after is not None:
            chans = [ch for ch in CHANNEL_EFFECTS[hidden] if ch in c.channels_after]
            before = np.mean([d.baseline_prediction.nrmse[ch] for ch in chans])
            after = np.mean([c.channels_after[ch] for ch in chans])
            out.update({"affected": chans, "affected_before": before, "affected_after": after,
                        "fall_pct": 100 * (1 - after / before), "nrmse_after": c.nrmse_after})
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("effects", nargs="*")
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--rate", type=float, default=1000.0, help="log rate, Hz")
    a = ap.parse_args()
    base = QuadrotorModel(load_airframe(HERE.parent / "greybox" / "data" / "airframes" / "paper.toml"))
    names = a.effects or ([None] + list(base.effects.names) + [n for n in effects.CATALOGUE if n not in base.effects])
    rows = []
    for n in names:
        n = None if n in (None, "none") else n
        r = case(base, n, a.duration, a.seed, a.rate)
        rows.append(r)
        ok = (r["verdict"] is None) if n is None else (r["first"] == n and r.get("fall_pct", 0) >= 30)
        fall = f"{r.get('fall_pct', float('nan')):6.1f} %" if n else "       "
        print(f"{'OK ' if ok else 'BAD'} hidden {str(n):<16} verdict {str(r['verdict']):<16} first {str(r['first']):<16} "
              f"affected-channel nrmse fall {fall}  ({r['time_s']:.0f} s)", flush=True)
    (HERE / "out").mkdir(exist_ok=True)
    (HERE / "out" / "diagnose_effects.json").write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()

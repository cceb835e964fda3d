"""Speed of a full diagnosis against naively refitting every candidate (issue 4's target:
a 50 s, 1 kHz log diagnosed in under 3 minutes on 2 cores).

    python experiments/bench_diagnose.py [--duration 50] [--rate 1000] [--hidden ground_effect]

One synthetic flight (paper airframe, the given effect hidden, seed 3). Timed in one run:

* greybox: ``diagnose(base, log, iterate=False)`` — baseline fit, validation, residual
  analysis, score-test screening of every catalogue candidate from the baseline optimum,
  warm-started refits of the best few;
* naive: the same baseline fit, then every candidate refitted warm-started from the
  baseline (what screening avoids), each validated.

Prints both times, the ratio, and whether both put the hidden effect first.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from greybox import QuadrotorModel, effects, load_airframe  # noqa: E402
from greybox.diagnosis import diagnose  # noqa: E402
from greybox.fitting import fit  # noqa: E402
from greybox.synth import SensorSpec, model_with_hidden_effects, synthesize  # noqa: E402
from greybox.validation import predict  # noqa: E402

HERE = Path(__file__).resolve().parent


def naive(base: QuadrotorModel, log, candidates: list[str]) -> tuple[float, list[tuple[str, float]]]:
    """Baseline fit, then every candidate refitted warm-started and validated."""
    t0 = time.perf_counter()
    est, val = log.split(0.8)
    res = fit(base, est, max_iter=200)
    before = predict(base, res.p, val).total
    out = []
    for c in candidates:
        m = base + effects.by_name(c)
        p0 = m.parameter_vector(base.parameter_dict(res.p), m.default_parameters())
        try:
            r = fit(m, est, p0=p0, max_iter=200)
            out.append((c, predict(m, r.p, val).total))
        except Exception as e:                       # a failed refit is a result too
            out.append((c, float("nan")))
            print(f"  naive refit with {c} failed: {e}", file=sys.stderr)
        print(f"  naive: {c} done at {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    out.sort(key=lambda kv: (np.isnan(kv[1]), kv[1]))
    return time.perf_counter() - t0, [("baseline", before)] + out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=50.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--hidden", default="ground_effect")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--skip-naive", action="store_true")
    args = ap.parse_args(argv)
    base = QuadrotorModel(load_airframe(HERE.parent / "greybox" / "data" / "airframes" / "paper.toml"))
    truth, p = model_with_hidden_effects(base, [args.hidden])
    log = synthesize(truth, p, duration=args.duration, seed=args.seed,
                     sensors=SensorSpec(rate=args.rate, vision_rate=min(60.0, args.rate)),
                     manoeuvres=["hover", "ground", "step_x", "fast", "step_z", "yaw", "step_y"]).log
    candidates = [n for n in effects.CATALOGUE if n not in base.effects]
    print(f"{args.duration:g} s at {args.rate:g} Hz ({len(log)} samples), hidden {args.hidden}, "
          f"{len(candidates)} candidates", flush=True)
    t0 = time.perf_counter()
    d = diagnose(base, log, iterate=False, progress=True)
    t_ours = time.perf_counter() - t0
    first = d.ranking[0].effect if d.ranking else None
    print(f"greybox diagnose: {t_ours:.0f} s; verdict {d.verdict}, first {first}", flush=True)
    result = {"duration_s": args.duration, "rate_hz": args.rate, "samples": len(log), "hidden": args.hidden,
              "greybox": {"time_s": t_ours, "verdict": d.verdict, "first": first,
                          "timings": d.timings}}
    if not args.skip_naive:
        t_naive, ranking = naive(base, log, candidates)
        print(f"naive refit of all {len(candidates)} candidates: {t_naive:.0f} s; best {ranking[1][0]} "
              f"(validation nrmse {ranking[0][1]:.3f} -> {ranking[1][1]:.3f})", flush=True)
        print(f"ratio naive / greybox: {t_naive / t_ours:.1f}x")
        result["naive"] = {"time_s": t_naive, "ranking": ranking, "ratio": t_naive / t_ours}
    (HERE / "out").mkdir(exist_ok=True)
    (HERE / "out" / ("bench_diagnose.json" if not args.skip_naive else "bench_diagnose_greybox.json")).write_text(json.dumps(result, indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())

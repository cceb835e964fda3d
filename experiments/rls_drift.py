"""Online estimation of K_T and b by RLS with forgetting, on a flight whose thrust
coefficient drifts (battery sag, effect ``thrust_drift``). Writes
``experiments/out/rls_drift.png`` and prints the tracking error.

    python experiments/rls_drift.py [--drift -0.004] [--memory 2.0]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from greybox import QuadrotorModel, load_airframe  # noqa: E402
from greybox.rls import online_thrust_yaw  # noqa: E402
from greybox.synth import model_with_hidden_effects, synthesize  # noqa: E402

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--drift", type=float, default=-0.004, help="K_T_drift, 1/s")
    ap.add_argument("--memory", type=float, default=2.0, help="RLS memory, s")
    ap.add_argument("--duration", type=float, default=40.0)
    ap.add_argument("--seed", type=int, default=4)
    a = ap.parse_args()
    base = QuadrotorModel(load_airframe(HERE.parent / "greybox" / "data" / "airframes" / "paper.toml"))
    truth, p = model_with_hidden_effects(base, ["thrust_drift"], {"K_T_drift": a.drift})
    log = synthesize(truth, p, duration=a.duration, seed=a.seed).log
    est = online_thrust_yaw(base, log, memory=a.memory)
    kt0 = base.parameter_dict(p)["K_T"]
    kt_true = kt0 * (1 + a.drift * log.t)
    k = log.t > est.settle
    rel = est.K_T[k] / kt_true[k] - 1
    b_true = base.parameter_dict(p)["b"]
    print(f"K_T tracking after {est.settle:.1f} s: RMS {100 * np.sqrt(np.mean(rel ** 2)):.2f} %, "
          f"max {100 * np.abs(rel).max():.2f} %; true change {100 * a.drift * a.duration:+.1f} %")
    print(f"b: median {np.median(est.b[k]):.4g} (true {b_true:.4g})")
    fig, ax = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    ax[0].plot(log.t, kt_true, "k--", label="true K_T(t)")
    ax[0].plot(log.t, est.K_T, label=f"RLS, memory {a.memory:g} s")
    ax[0].set_ylim(kt0 * (1 + 1.5 * a.drift * a.duration), kt0 * 1.08)
    ax[0].set_ylabel("K_T  [N/(rad/s)^2]")
    ax[0].legend()
    ax[1].plot(log.t, np.full_like(log.t, b_true), "k--", label="true b")
    ax[1].plot(log.t, est.b, label="RLS")
    ax[1].set_ylim(0.8 * b_true, 1.2 * b_true)
    ax[1].set_ylabel("b  [N m/(rad/s)^2]")
    ax[1].set_xlabel("t (s)")
    ax[1].legend()
    fig.tight_layout()
    out = HERE / "out" / "rls_drift.png"
    out.parent.mkdir(exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

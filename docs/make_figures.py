"""Make the figure the README shows: the demo diagnosis on the bundled logs.

    python docs/make_figures.py            # writes docs/diagnosis.png (about a minute)

It runs what ``greybox demo`` runs — the seed paper's base model fitted to the bundled
30 s flight with a hidden ground effect, validated on the bundled 28 s flight, diagnosed —
and draws two panels: the 1-s-ahead prediction of the channel where the missing effect
shows most (baseline model vs the model with the effect the diagnosis added, against the
measurements), and the candidate ranking (the statistic of each candidate effect; green:
significant). Only matplotlib's object API is used (``matplotlib.figure.Figure``): no
pyplot, no backend is selected.
"""
from __future__ import annotations

import argparse
from importlib import resources
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from greybox import QuadrotorModel, diagnose, load_airframe, load_log
from greybox.model import OUTPUTS

HERE = Path(__file__).resolve().parent


def run_demo_diagnosis():
    """The demo's diagnosis: base model, bundled estimation and validation flights."""
    data = resources.files("greybox") / "data"
    with resources.as_file(data / "airframes" / "paper.toml") as af, \
            resources.as_file(data / "logs" / "demo_ground_effect.csv") as est, \
            resources.as_file(data / "logs" / "demo_ground_effect_validation.csv") as val:
        model = QuadrotorModel(load_airframe(af))
        log, validation = load_log(est), load_log(val)
    return diagnose(model, log, validation=validation)


def diagnosis_figure(d) -> Figure:
    """Baseline vs final prediction of the channel the diagnosis improved most, and the ranking."""
    base, final = d.baseline_prediction, d.final_prediction
    added = [e for e in d.final_model.effect_names if e not in d.model.effect_names] if d.final_model else []
    if final is None or not added:
        final = None
        ch = max(base.nrmse, key=base.nrmse.get)
    else:
        ch = max(base.channels, key=lambda c: base.nrmse[c] - final.nrmse.get(c, base.nrmse[c]))
    fig = Figure(figsize=(10, 3.6), layout="constrained")
    ax, ax_rank = fig.subplots(1, 2, width_ratios=[2.2, 1])

    log, c = base.log, OUTPUTS.index(ch)
    y = log.output(ch)
    k = np.isfinite(y)
    ax.plot(log.t[k], y[k], ".", ms=2, color="0.45", label="measured")
    ax.plot(log.t, base.predicted[:, c], lw=1.1, color="C3",
            label=f"base model (nrmse {base.nrmse[ch]:.3f})")
    if final is not None:
        ax.plot(log.t, final.predicted[:, c], lw=1.1, color="C0",
                label=f"+ {', '.join(added)} (nrmse {final.nrmse[ch]:.3f})")
    ax.set_xlabel("t (s), validation flight")
    ax.set_ylabel(f"{ch} (m)" if ch in ("x", "y", "z") else ch)
    if ch == "z":
        ax.invert_yaxis()   # NED: z down, so up on the page is up in the air
        ax.set_ylabel("z (m; NED, axis flipped: up is up)")
    ax.set_title(f"{base.horizon:g}-s-ahead prediction of {ch}", fontsize=10)
    ax.legend(fontsize=8, loc="best")

    ranking = list(d.ranking)[::-1]
    vals = np.array([r.lr if r.lr is not None else r.score for r in ranking], dtype=float)
    ax_rank.barh([r.effect for r in ranking], np.maximum(np.nan_to_num(vals, nan=1.0), 1.0),
                 color=["C2" if r.significant else "0.65" for r in ranking])
    ax_rank.set_xscale("log")
    ax_rank.set_xlim(left=1.0)
    ax_rank.tick_params(axis="y", labelsize=8)
    ax_rank.set_xlabel("statistic (LR after refit, else score)", fontsize=8)
    ax_rank.set_title(f"candidates; verdict: {d.verdict}", fontsize=10)
    fig.suptitle(f"greybox diagnose: total validation nrmse {base.total:.3f}"
                 + (f" -> {final.total:.3f}" if final is not None else ""), fontsize=11)
    return fig


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE / "diagnosis.png"), help="PNG to write")
    args = ap.parse_args(argv)
    d = run_demo_diagnosis()
    print(d.summary())
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    diagnosis_figure(d).savefig(out, dpi=100)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

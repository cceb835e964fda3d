"""The seed paper's figures, reproduced with greybox: one command, PNGs and tables.

    python experiments/paper_figures.py [--only fig1,fig2,fig3,fig56] [--quick]
                                        [--out experiments/out/paper_figures]

* Fig. 1 — a model without the yaw reaction torque (b = 0) keeps rotating in yaw at hover:
  the LQR designed on the full model holds position, but a 0.2 rad/s yaw-rate disturbance
  never decays, because nothing in the model can produce a yaw moment.
* Fig. 2 — LQR (dlqry, Q = 1, R = 0.001, Kr) vs the cascaded PID (eqs. 13-18, gains tuned
  automatically on ITAE) on the grey-box model, the seed's step scenario (1 m steps in x at
  1 s, y at 6 s, z up at 11 s): responses, rotor speeds, rise / overshoot / settling / ITAE.
* Fig. 3 — identification with rotor speeds vs with U1..U4 inputs (computed from the rotor
  speeds with "known" K_T, b from a bench test that is 4 % / 7 % off): the same flights,
  each model fitted on each flight and validated on the others. Which is the more
  consistent model, in numbers: spread of the fitted drag across flights and the
  cross-flight 1-s prediction error.
* Figs. 5/6 — a 50 s, 1 kHz "experimental" flight (the synthetic truth, with quadratic
  drag the grey-box model does not have: its linear drag absorbs it), a grey-box model fitted to it (80 %), an n4sid
  black-box model identified from it (decimated to 100 Hz), and the same LQR design on
  each: position (Fig. 5) and attitude (Fig. 6) responses to the step scenario. The
  "flight" is the true vehicle flown by the LQR designed on the grey-box model; the
  black-box closed loop is dlqry on the black box's own states (output weighting makes the
  same design procedure apply to any state coordinates).

Each figure writes ``figN*.png`` and ``figN.json``; ``summary.md`` collects the tables.
``--quick`` shortens flights for a smoke run (the notebook uses it).
"""
# The computations are greybox.paper (importable from an installed greybox; the notebook
# uses it); this is its command line.
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from greybox.errors import GreyboxInputError  # noqa: E402
from greybox.paper import FIGURES, run  # noqa: E402

HERE = Path(__file__).resolve().parent


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="comma-separated subset of " + ",".join(FIGURES))
    ap.add_argument("--quick", action="store_true", help="short flights (smoke run)")
    ap.add_argument("--out", default=str(HERE / "out" / "paper_figures"))
    args = ap.parse_args(argv)
    try:
        run(Path(args.out), args.only.split(",") if args.only else None, args.quick)
    except GreyboxInputError as e:     # an unknown figure name
        raise SystemExit(str(e)) from None
    print((Path(args.out) / "summary.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())

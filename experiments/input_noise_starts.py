"""Fits of flights whose logged rotor speeds carry white noise, from two starts: how far the
parameters land from the truth (in their std) and from each other.

greybox's own 30-s flights at 200 Hz (seeds 1..N) with 1 rad/s of white noise on the logged
speeds (0.23 % of their variance, a gyro logged), fitted in Python as logged (process noise:
output error cannot follow them), once from the truth and once from K_T 30 % high and b 30 %
low. The soft fit's process noise has a floor, the random walk the inputs' noise gives each
state, which grows with the gains that pass the noise on (K_T, b): computed at the start
only, that floor depended on the start, and so did the parameters. Prints, per parameter,
the RMS of (value - truth) / std over the seeds from each start, and the largest difference
between the two starts' values in std.

    python experiments/input_noise_starts.py [--seeds 8] [--duration 30] [--noise 1.0]
"""
from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
import numpy as np  # noqa: E402

from greybox import QuadrotorModel, load_airframe, load_log  # noqa: E402
from greybox.cli import main as greybox_main  # noqa: E402
from greybox.fitting import fit  # noqa: E402

AIRFRAME = Path(__file__).resolve().parents[1] / "greybox" / "data" / "airframes" / "paper.toml"
NAMES = ("K_T", "b", "Kd[0]", "Kd[1]", "Kd[2]")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--noise", type=float, default=1.0, help="rad/s of white noise on the logged speeds")
    args = ap.parse_args()
    model = QuadrotorModel(load_airframe(str(AIRFRAME)))
    truth = model.parameter_dict(model.default_parameters())
    starts = {"truth": None, "30 % off": {"K_T": truth["K_T"] * 1.3, "b": truth["b"] * 0.7}}
    z = {s: [] for s in starts}
    apart = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, args.seeds + 1):
            path = Path(tmp) / f"noisy{seed}.csv"
            assert greybox_main(["synth", "--airframe", str(AIRFRAME), "--out", str(path), "--duration",
                                 f"{args.duration:g}", "--rate", "200", "--seed", str(seed),
                                 "--input-noise", f"{args.noise:g}"]) == 0
            log = load_log(str(path))
            values = {}
            for label, p0 in starts.items():
                res = fit(model, log, p0=p0)
                std = np.array([res.std[res.free_names.index(n)] for n in NAMES])
                val = np.array([res.value(n) for n in NAMES])
                z[label].append((val - np.array([truth[n] for n in NAMES])) / std)
                values[label] = (val, std)
                print(f"seed {seed} from {label:8}: certified {res.converged}; "
                      + ", ".join(f"{n} z {v:+.2f}" for n, v in zip(NAMES, z[label][-1])), flush=True)
            (a, sa), (b, _) = values.values()
            apart.append(np.abs(a - b) / sa)
    print("\nRMS of (value - truth) / std over", args.seeds, "seeds:")
    for label in starts:
        rms = np.sqrt(np.mean(np.square(z[label]), axis=0))
        print(f"  from {label:8}: " + ", ".join(f"{n} {v:.2f}" for n, v in zip(NAMES, rms)))
    print("largest difference between the starts, in std: "
          + ", ".join(f"{n} {v:.3f}" for n, v in zip(NAMES, np.max(apart, axis=0))))


if __name__ == "__main__":
    main()

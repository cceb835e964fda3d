"""Statistical honesty of the fitter's uncertainties.

The same 50 s flight (seed 1) with 20 independent noise realisations: for each parameter,
the empirical spread of the estimates against the mean reported standard deviation, and the
bias against that standard deviation. The Gauss-Newton covariance at the truth is the
Cramér-Rao bound, so an efficient estimator's ratio spread / reported std is close to 1.

``--correlation-time TAU`` makes the sensor noise coloured (AR(1), correlated over TAU s,
the same RMS as the white default: a filtered vision or IMU), where the Gauss-Newton std,
which count every sample as independent, are too narrow; printed beside the reported
std (which count the colour: :mod:`greybox.fitting.robust`; ``FitResult.white_std`` keeps
the Gauss-Newton ones) as ``GN ratio``. With
the default ``--process-noise if_needed`` the fit may take soft continuity, as it does on
its own when the residuals look like a model that cannot follow; ``none`` keeps it output
error.

    python experiments/fit_honesty.py [--runs 20] [--duration 50] [--correlation-time 0.1]
        [--process-noise none|if_needed]
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
import numpy as np  # noqa: E402

from greybox import QuadrotorModel, load_airframe  # noqa: E402
from greybox.fitting import fit  # noqa: E402
from greybox.synth import SensorSpec, synthesize  # noqa: E402

HERE = Path(__file__).resolve().parent
START = {"K_T": 2.395e-5 * 1.35, "b": 6.8429e-7 * 0.65, "Kd": [0.135, 0.065, 0.20]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--duration", type=float, default=50.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--correlation-time", type=float, default=0.0, help="s; 0: white sensor noise")
    ap.add_argument("--process-noise", choices=["none", "if_needed"], default="if_needed",
                    help="none: output error only; if_needed: the fit's default")
    a = ap.parse_args()
    model = QuadrotorModel(load_airframe(HERE.parent / "greybox" / "data" / "airframes" / "paper.toml"))
    est, std, gn_std, names = [], [], [], None
    for k in range(a.runs):
        r = synthesize(model, duration=a.duration, seed=a.seed, noise_seed=1000 + k,
                       sensors=SensorSpec(noise_correlation=a.correlation_time))
        log = r.log
        e, _ = log.split()
        res = fit(model, e, p0=START, process_noise=None if a.process_noise == "none" else "if_needed")
        names = res.free_names
        truth = np.array([model.parameter_dict(r.parameters)[n] for n in names])
        est.append([res.value(n) for n in names])
        std.append(res.std)
        gn_std.append(res.white_std if res.white_std is not None else res.std)
        print(f"run {k + 1:2d}: " + "  ".join(f"{n}={(v - t) / s:+.2f}sd" for n, v, t, s in
                                               zip(names, est[-1], truth, res.std)), flush=True)
    est, std, gn_std = np.array(est), np.array(std), np.array(gn_std)
    spread = est.std(axis=0, ddof=1)
    rep, rep_gn = std.mean(axis=0), gn_std.mean(axis=0)
    bias = est.mean(axis=0) - truth
    noise = "white" if a.correlation_time <= 0 else f"AR(1), correlated over {a.correlation_time:g} s"
    print(f"\n{a.runs} noise realisations ({noise}) of a {a.duration:g} s flight, process noise {a.process_noise}")
    print(f"{'parameter':<8}{'truth':>12}{'mean est':>13}{'spread':>11}{'reported':>11}{'ratio':>7}{'bias/sd':>9}"
          f"{'GN std':>11}{'GN ratio':>9}")
    rows = {}
    for i, n in enumerate(names):
        print(f"{n:<8}{truth[i]:12.5g}{est[:, i].mean():13.6g}{spread[i]:11.3g}{rep[i]:11.3g}"
              f"{spread[i] / rep[i]:7.2f}{bias[i] / rep[i]:+9.2f}{rep_gn[i]:11.3g}{spread[i] / rep_gn[i]:9.2f}")
        rows[n] = {"spread": spread[i], "reported": rep[i], "ratio": spread[i] / rep[i], "bias_sd": bias[i] / rep[i],
                   "gauss_newton": rep_gn[i], "gauss_newton_ratio": spread[i] / rep_gn[i]}
    tag = "" if a.correlation_time <= 0 else f"_tau{a.correlation_time:g}_{a.process_noise}"
    out = HERE / "out" / f"fit_honesty{tag}.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()

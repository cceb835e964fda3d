"""n4sid benchmark: greybox's numpy n4sid against nfoursid on the same closed-loop flight.

    pip install ".[compare]"      # nfoursid, python-control
    python experiments/bench_n4sid.py [--duration 50]

A 50 s synthetic flight at 1 kHz (paper airframe, hover, x/y/z steps and fast
translations at a fixed heading, multisine excitation),
inputs w1..w4, outputs x, y, z, phi, theta, psi; the first 80 % (40,000 samples) identify,
the last 20 % validate by 1-s-ahead windows (state from the 0.5 s before each window; an
open-loop-unstable plant cannot be judged by free-run simulation). Cases: decimated to
100 Hz (the rate at which subspace methods see the flight's dynamics, see
``shared/MEASURED.md``), and the raw 1 kHz. Reference: the true model linearised at hover
(``greybox.linearize``), the ceiling of any linear model. One BLAS thread for everyone
(multithreaded BLAS on a loaded 2-core machine makes QR up to 7x slower). nfoursid's full
SVD of the 1 kHz Hankel matrix runs out of memory; it is run with ``numpy.linalg.svd``
patched to the thin SVD, which is stated in the output. Writes ``experiments/out/bench_n4sid.json``
and the order-selection plot ``experiments/out/n4sid_order.png``.
"""
from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from greybox import QuadrotorModel, linearize, load_airframe  # noqa: E402
from greybox.n4sid import StateSpaceModel, n4sid, order_plot  # noqa: E402
from greybox.synth import SensorSpec, synthesize  # noqa: E402

HERE = Path(__file__).resolve().parent
OUT = ["x", "y", "z", "phi", "theta", "psi"]


def block_mean(a: np.ndarray, k: int) -> np.ndarray:
    n = a.shape[0] // k * k
    return a[:n].reshape(-1, k, a.shape[1]).mean(axis=1)


def nfoursid_model(u, y, dt, order, i) -> tuple[StateSpaceModel, float, str]:
    import pandas as pd
    from nfoursid import nfoursid as nf_mod
    from nfoursid import utils as nf_utils
    note = "as shipped"
    df = pd.DataFrame(np.hstack([u, y]), columns=[f"u{j}" for j in range(u.shape[1])] +
                      [f"y{j}" for j in range(y.shape[1])])
    u0, y0 = u.mean(axis=0), y.mean(axis=0)
    df.iloc[:, :u.shape[1]] -= u0
    df.iloc[:, u.shape[1]:] -= y0
    if u.shape[0] > 10000:
        # the shipped full SVD of the (i*l x N) matrix needs N x N memory: patch to thin
        _svd = np.linalg.svd
        nf_utils.np.linalg.svd = lambda m, *a, **k: _svd(m, full_matrices=False)
        note = "numpy.linalg.svd patched to the thin SVD (the shipped full SVD runs out of memory)"
    t0 = time.perf_counter()
    est = nf_mod.NFourSID(df, output_columns=list(df.columns[u.shape[1]:]),
                          input_columns=list(df.columns[:u.shape[1]]), num_block_rows=i)
    est.subspace_identification()
    ss, _ = est.system_identification(rank=order)
    dt_s = time.perf_counter() - t0
    if u.shape[0] > 10000:
        nf_utils.np.linalg.svd = _svd
    m = StateSpaceModel(ss.a, ss.b, ss.c, ss.d, dt, np.zeros(order), u0, y0)
    return m, dt_s, note


def hover_reference(model: QuadrotorModel, p: np.ndarray, dt: float, u0, y0) -> StateSpaceModel:
    lin = linearize(model, p=p).discretize(dt)
    rows = [lin.output_names.index(c) for c in OUT]
    return StateSpaceModel(lin.A, lin.B, lin.C[rows], lin.D[rows], dt, np.zeros(lin.A.shape[0]),
                           np.asarray(lin.u_op), np.asarray(lin.C[rows] @ lin.x_op), [], OUT)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=50.0)
    ap.add_argument("--order", type=int, default=12)
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args()
    model = QuadrotorModel(load_airframe(HERE.parent / "greybox" / "data" / "airframes" / "paper.toml"))
    # no yaw manoeuvre: a model linearised at one heading cannot follow a 90 degree turn
    syn = synthesize(model, duration=args.duration, seed=args.seed,
                     manoeuvres=("hover", "step_x", "step_y", "step_z", "fast"),
                     sensors=SensorSpec(rate=1000.0, vision_rate=1000.0, dropout=0.0, burst_dropouts=0.0))
    log = syn.log
    U = log.inputs
    Y = np.column_stack([log.output(c) for c in OUT])
    n_est = int(0.8 * len(log))
    results = []
    for label, k in (("100 Hz (decimated)", 10), ("1 kHz", 1)):
        u, y = block_mean(U, k), block_mean(Y, k)
        dt = 0.001 * k
        ne = n_est // k
        H, L = int(round(1.0 / dt)), int(round(0.5 / dt))
        i = 5 if k > 1 else 10
        ref = hover_reference(model, syn.parameters, dt, None, None)
        ref_fit = ref.predict_windows(u[ne - L:], y[ne - L:], H, L)
        rows = {"case": label, "samples": ne, "hover_linearisation_fit": ref_fit.tolist()}
        t0 = time.perf_counter()
        ours = n4sid(u[:ne], y[:ne], dt, order=args.order, horizon=i)
        t_ours = time.perf_counter() - t0
        f_ours = ours.predict_windows(u[ne - L:], y[ne - L:], H, L)
        rows["greybox"] = {"time_s": t_ours, "fit": f_ours.tolist(), "stable": ours.is_stable()}
        try:
            theirs, t_nf, note = nfoursid_model(u[:ne], y[:ne], dt, args.order, i)
            f_nf = theirs.predict_windows(u[ne - L:], y[ne - L:], H, L)
            rows["nfoursid"] = {"time_s": t_nf, "fit": f_nf.tolist(), "stable": theirs.is_stable(), "note": note}
            rows["speedup"] = t_nf / t_ours
        except ImportError:
            rows["nfoursid"] = None
        if k > 1:
            t0 = time.perf_counter()
            auto = n4sid(u[:ne], y[:ne], dt, order="auto", horizon=i)
            rows["greybox_auto"] = {"time_s": time.perf_counter() - t0, "order": auto.order,
                                    "fit": auto.predict_windows(u[ne - L:], y[ne - L:], H, L).tolist()}
            order_plot(auto, HERE / "out" / "n4sid_order.png")
        results.append(rows)
        print(f"\n{label}: {ne} identification samples, order {args.order}, horizon {i}")
        print(f"  {'':22s} {'time':>8s}  fit % on {', '.join(OUT)} (1-s windows, validation)")
        print(f"  {'hover linearisation':22s} {'':>8s}  " + " ".join(f"{v:6.1f}" for v in ref_fit))
        print(f"  {'greybox n4sid':22s} {t_ours:7.2f}s  " + " ".join(f"{v:6.1f}" for v in f_ours))
        if rows.get("nfoursid"):
            print(f"  {'nfoursid':22s} {t_nf:7.2f}s  " + " ".join(f"{v:6.1f}" for v in f_nf)
                  + f"   ({note})")
            print(f"  speed ratio nfoursid / greybox: {rows['speedup']:.1f}x")
        if "greybox_auto" in rows:
            a = rows["greybox_auto"]
            print(f"  {'greybox, order auto':22s} {a['time_s']:7.2f}s  " + " ".join(f"{v:6.1f}" for v in a["fit"])
                  + f"   (order {a['order']})")
    (HERE / "out").mkdir(exist_ok=True)
    (HERE / "out" / "bench_n4sid.json").write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()

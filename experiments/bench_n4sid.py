"""n4sid benchmark: greybox's numpy n4sid against nfoursid on the same closed-loop flight.

    pip install ".[compare]"      # nfoursid, python-control
    python experiments/bench_n4sid.py [--duration 50]

A 50 s synthetic flight at 1 kHz (paper airframe, hover and 1 m x/y/z steps at a fixed
heading, multisine excitation),
inputs w1..w4, outputs x, y, z, phi, theta, psi; the first 80 % (40,000 samples) identify,
the last 20 % and two more 30-s flights (other seeds) validate by 1-s-ahead windows (state from the 0.5 s before each window; an
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
HORIZONS_100HZ = (5, 10, 15, 20)
MANOEUVRES = ("hover", "step_x", "step_y", "step_z")
HORIZONS_1KHZ = (10, 30)


def score(fit: np.ndarray) -> float:
    """One number per model: the mean fit % over channels, each clipped at -100 (a channel
    that barely moves in validation, e.g. yaw here, can reach -1000 % on a tiny error)."""
    return float(np.mean(np.clip(fit, -100.0, 100.0)))


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
    # around hover, where a linear model belongs: no yaw manoeuvre (a model linearised at
    # one heading cannot follow a 60 degree turn) and no 3 m/s crossings (30 degree tilts:
    # even the true model linearised at hover predicts x and theta there at 9 % and 26 %)
    syn = synthesize(model, duration=args.duration, seed=args.seed,
                     manoeuvres=MANOEUVRES,
                     sensors=SensorSpec(rate=1000.0, vision_rate=1000.0, dropout=0.0, burst_dropouts=0.0))
    log = syn.log
    U = log.inputs
    Y = np.column_stack([log.output(c) for c in OUT])
    n_est = int(0.8 * len(log))
    # validation: the held-out last 20 % and two more independent flights (one 10-s
    # stretch decides too much by what happens to be in it)
    held = [(U[n_est:], Y[n_est:])]
    for extra in (1, 2):
        v = synthesize(model, duration=30.0, seed=args.seed + 100 * extra, manoeuvres=MANOEUVRES,
                       sensors=SensorSpec(rate=1000.0, vision_rate=1000.0, dropout=0.0, burst_dropouts=0.0)).log
        held.append((v.inputs, np.column_stack([v.output(c) for c in OUT])))
    results = []
    for label, k in (("100 Hz (decimated)", 10), ("1 kHz", 1)):
        u, y = block_mean(U, k), block_mean(Y, k)
        dt = 0.001 * k
        ne = n_est // k
        H, L = int(round(1.0 / dt)), int(round(0.5 / dt))
        val = [(block_mean(vu, k), block_mean(vy, k)) for vu, vy in held]
        val[0] = (u[ne - L:], y[ne - L:])

        def validate(m: StateSpaceModel) -> np.ndarray:
            """1-s-ahead fit % per channel, averaged over the validation flights."""
            return np.mean([m.predict_windows(vu, vy, H, L) for vu, vy in val], axis=0)

        ref = hover_reference(model, syn.parameters, dt, None, None)
        ref_fit = validate(ref)
        rows = {"case": label, "samples": ne, "hover_linearisation_fit": ref_fit.tolist(), "horizons": {}}
        print(f"\n{label}: {ne} identification samples, order {args.order}")
        print(f"  {'':24s} {'time':>8s}  fit % on {', '.join(OUT)} (1-s windows, validation); score")
        print(f"  {'hover linearisation':24s} {'':>8s}  " + " ".join(f"{v:7.1f}" for v in ref_fit))
        for i in (HORIZONS_100HZ if k > 1 else HORIZONS_1KHZ):
            h_rows = {}
            t0 = time.perf_counter()
            try:
                ours = n4sid(u[:ne], y[:ne], dt, order=args.order, horizon=i)
            except Exception as e:           # a horizon too long for the data
                print(f"  greybox n4sid, i={i}: {e}")
                continue
            t_ours = time.perf_counter() - t0
            f_ours = validate(ours)
            h_rows["greybox"] = {"time_s": t_ours, "fit": f_ours.tolist(), "score": score(f_ours),
                                 "stable": ours.is_stable()}
            print(f"  {'greybox n4sid, i=' + str(i):24s} {t_ours:7.2f}s  " + " ".join(f"{v:7.1f}" for v in f_ours)
                  + f"; {score(f_ours):.1f}")
            try:
                if i > 15:
                    raise ImportError          # nfoursid at 20 block rows: 2x slower, no better
                theirs, t_nf, note = nfoursid_model(u[:ne], y[:ne], dt, args.order, i)
                f_nf = validate(theirs)
                h_rows["nfoursid"] = {"time_s": t_nf, "fit": f_nf.tolist(), "score": score(f_nf),
                                      "stable": theirs.is_stable(), "note": note}
                print(f"  {'nfoursid, i=' + str(i):24s} {t_nf:7.2f}s  " + " ".join(f"{v:7.1f}" for v in f_nf)
                      + f"; {score(f_nf):.1f}   ({note})")
            except ImportError:
                pass
            rows["horizons"][i] = h_rows
        best = {tool: max(((i, h[tool]) for i, h in rows["horizons"].items() if tool in h),
                          key=lambda t: t[1]["score"], default=None) for tool in ("greybox", "nfoursid")}
        rows["best"] = {tool: {"horizon": b[0], **b[1]} for tool, b in best.items() if b}
        if best["nfoursid"]:
            (ig, g), (inf, nf) = best["greybox"], best["nfoursid"]
            rows["speedup_best"] = nf["time_s"] / g["time_s"]
            rows["channels_at_least_as_accurate"] = int(np.sum(np.array(g["fit"]) >= np.array(nf["fit"]) - 0.05))
            print(f"  each at its best horizon: greybox i={ig} score {g['score']:.1f} in {g['time_s']:.2f} s, "
                  f"nfoursid i={inf} score {nf['score']:.1f} in {nf['time_s']:.2f} s: "
                  f"{rows['speedup_best']:.1f}x faster, at least as accurate on "
                  f"{rows['channels_at_least_as_accurate']} of {len(OUT)} channels")
        if k > 1:
            t0 = time.perf_counter()
            auto = n4sid(u[:ne], y[:ne], dt, order="auto")
            rows["greybox_auto"] = {"time_s": time.perf_counter() - t0, "order": auto.order,
                                    "fit": validate(auto).tolist()}
            order_plot(auto, HERE / "out" / "n4sid_order.png")
        results.append(rows)
        if "greybox_auto" in rows:
            a = rows["greybox_auto"]
            print(f"  {'greybox, order auto':22s} {a['time_s']:7.2f}s  " + " ".join(f"{v:6.1f}" for v in a["fit"])
                  + f"   (order {a['order']})")
    (HERE / "out").mkdir(exist_ok=True)
    (HERE / "out" / "bench_n4sid.json").write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()

"""Benchmark of greybox's fitter against the ways a user would otherwise fit.

Data: a 50 s, 1 kHz synthetic flight of the paper's airframe (position 3 mm at 60 Hz with
dropouts, attitude 0.003 rad and gyro at 1 kHz), estimation on the first 80 % (40,000
samples), starting values 30-40 % off. Printed, all measured in this run:

* greybox: warm (compiled step cached), cold (compile included) and with CasADi's
  virtual machine only; wall time, peak memory, recovered parameters, intervals 25/50/100.
* (a) IPOPT on a straightforward multiple-shooting NLP of the same problem (MX, ``map``
  over intervals), with a Gauss-Newton Hessian (given to IPOPT as ``hess_lag``) and, with
  ``--exact``, with the exact Hessian (minutes).
* (b) ``scipy.optimize.least_squares`` with finite differences, simulating 0.5 s windows
  (vectorised numpy RK4) from states taken from smoothed measurements.

Ratios are against greybox warm. Each method runs in its own process so that peak memory
(``ru_maxrss``) is its own. One BLAS thread (see shared/MEASURED.md).

    python experiments/bench_fit.py [--exact] [--seed 1]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
AIRFRAME = HERE.parent / "greybox" / "data" / "airframes" / "paper.toml"
START = {"K_T": 2.395e-5 * 1.35, "b": 6.8429e-7 * 0.65, "Kd": [0.135, 0.065, 0.20]}
FREE = ["K_T", "b", "Kd[0]", "Kd[1]", "Kd[2]"]


def make_data(seed: int):
    from greybox import QuadrotorModel, load_airframe
    from greybox.synth import SensorSpec, synthesize
    model = QuadrotorModel(load_airframe(AIRFRAME))
    res = synthesize(model, duration=50.0, seed=seed,
                     sensors=SensorSpec(rate=1000, vision_rate=60, pos_noise=0.003, att_noise=0.003,
                                        gyro_noise=0.005, dropout=0.05))
    est, _ = res.log.split(0.8)
    return model, est, model.parameter_dict(res.parameters)


# ----------------------------------------------------------------------------- methods
def run_greybox(seed, mode):
    from greybox.fitting import fit
    model, est, truth = make_data(seed)
    kw = {}
    if mode == "vm":
        kw["compile"] = "never"
    elif mode.startswith("interval"):
        kw["interval"] = int(mode[8:])
    if mode == "cold":
        os.environ["GREYBOX_CACHE"] = str(Path(os.environ.get("TMPDIR", "/tmp")) / f"gb_cold_{os.getpid()}")
    if mode in ("warm",) or mode.startswith("interval"):
        fit(model, est, p0=START, **kw)  # compile / load the cache outside the timing
    t0 = time.perf_counter()
    r = fit(model, est, p0=START, **kw)
    dt = time.perf_counter() - t0
    return dt, {n: r.value(n) for n in FREE}, {n: float(s) for n, s in zip(r.free_names, r.std)}, truth, r.iterations


def _ipopt_problem(model, est, N=50):
    """A straightforward multiple-shooting NLP: MX, map over intervals."""
    import casadi as ca
    from greybox.fitting import estimate_noise, initial_node_states
    from greybox.integrate import rk4_step
    from greybox.model import OUTPUTS
    n = len(est)
    M = n // N
    n_use = M * N
    step = rk4_step(model, 1)
    p_def = model.parameter_vector(START)
    scale = p_def[:5].copy()
    # channels the log does not have (the accelerometer) get no weight
    sig = np.array([estimate_noise(est.output(c)) if c in est.output_names else 1.0 for c in OUTPUTS])
    x = ca.MX.sym("x", model.nx)
    th = ca.MX.sym("th", 5)
    U = ca.MX.sym("U", model.nu, N)
    Y = ca.MX.sym("Y", model.ny, N)
    W = ca.MX.sym("W", model.ny, N)
    p = ca.vertcat(th * scale, p_def[5:])
    xk, res = x, []
    for k in range(N):
        yk = model.output(xk, U[:, k], p, 0)
        d = Y[:, k] - yk
        d[5] = ca.atan2(ca.sin(d[5]), ca.cos(d[5]))
        res.append(W[:, k] * d)
        xk = step(xk, U[:, k], p, 0, 1e-3)
    F = ca.Function("interval", [x, th, U, Y, W], [xk, ca.vertcat(*res)])
    Fm = F.map(M)
    Yd = np.full((n_use, model.ny), np.nan)
    for c, name in enumerate(OUTPUTS):
        if name in est.output_names:
            Yd[:, c] = est.output(name)[:n_use]
    mask = np.isfinite(Yd)
    Wd = np.where(mask, 1 / sig, 0.0).T
    Yd = np.where(mask, Yd, 0.0).T
    Ud = est.inputs[:n_use].T
    S = ca.MX.sym("S", model.nx, M + 1)
    TH = ca.MX.sym("TH", 5)
    xe, r = Fm(S[:, :M], TH, Ud, Yd, Wd)
    rvec = ca.vec(r)
    w = ca.vertcat(ca.vec(S), TH)
    g = ca.vec(xe - S[:, 1:])
    idx = np.minimum(np.arange(M + 1) * N, n - 1)
    w0 = np.concatenate([initial_node_states(model, est, idx, p_def).T.ravel(order="F"), np.ones(5)])
    return ca, w, rvec, g, w0, scale


def run_ipopt(seed, hessian):
    model, est, truth = make_data(seed)
    t0 = time.perf_counter()
    ca, w, r, g, w0, scale = _ipopt_problem(model, est)
    f = 0.5 * ca.dot(r, r)
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": 1e-8, "ipopt.max_iter": 200}
    if hessian == "gauss-newton":
        J = ca.jacobian(r, w)
        lam_f = ca.MX.sym("lam_f")
        lam_g = ca.MX.sym("lam_g", g.shape[0])
        p_sym = ca.MX.sym("p", 0)
        H = lam_f * ca.triu(ca.mtimes(J.T, J))
        opts["hess_lag"] = ca.Function("hess_lag", [w, p_sym, lam_f, lam_g], [H],
                                       ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
    solver = ca.nlpsol("S", "ipopt", {"x": w, "f": f, "g": g}, opts)
    sol = solver(x0=w0, lbg=0, ubg=0)
    dt = time.perf_counter() - t0
    th = np.asarray(sol["x"]).ravel()[-5:] * scale
    status = solver.stats()["return_status"]
    return dt, dict(zip(FREE, th.tolist())), {}, truth, f"{solver.stats()['iter_count']} ({status})"


def _numpy_rk4(x, w, p, m, J, g, l):
    """Vectorised base-model RK4 step (plus layout) over many windows: what a user would write."""
    kt, b, kd = p[0], p[1], p[2:5]

    def f(s):
        ph, th, ps = s[:, 3], s[:, 4], s[:, 5]
        v, om = s[:, 6:9], s[:, 9:12]
        T = kt * (w ** 2)
        Ttot = T.sum(axis=1)
        cph, sph, cth, sth, cps, sps = np.cos(ph), np.sin(ph), np.cos(th), np.sin(th), np.cos(ps), np.sin(ps)
        ez = np.stack([cph * sth * cps + sph * sps, cph * sth * sps - sph * cps, cph * cth], 1)
        acc = -ez * (Ttot / m)[:, None] - kd * v / m
        acc[:, 2] += g
        tau = np.stack([l * (T[:, 3] - T[:, 1]), l * (T[:, 0] - T[:, 2]),
                        b * (-w[:, 0] ** 2 + w[:, 1] ** 2 - w[:, 2] ** 2 + w[:, 3] ** 2)], 1)
        p_, q_, r_ = om[:, 0], om[:, 1], om[:, 2]
        omd = np.stack([(tau[:, 0] + (J[1] - J[2]) * q_ * r_) / J[0], (tau[:, 1] + (J[2] - J[0]) * p_ * r_) / J[1],
                        (tau[:, 2] + (J[0] - J[1]) * p_ * q_) / J[2]], 1)
        ed = np.stack([p_ + (sph * q_ + cph * r_) * np.tan(th), cph * q_ - sph * r_, (sph * q_ + cph * r_) / cth], 1)
        return np.concatenate([v, ed, acc, omd], 1)
    h = 1e-3
    k1 = f(x)
    k2 = f(x + h / 2 * k1)
    k3 = f(x + h / 2 * k2)
    k4 = f(x + h * k3)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def run_scipy(seed):
    from scipy.optimize import least_squares
    from greybox.fitting import estimate_noise, initial_node_states
    from greybox.model import OUTPUTS
    model, est, truth = make_data(seed)
    t0 = time.perf_counter()
    af = model.airframe
    L = 500
    starts = np.arange(0, len(est) - L, L)
    p0 = model.parameter_vector(START)[:5]
    x0 = initial_node_states(model, est, starts, model.parameter_vector(START))
    Y = np.stack([np.column_stack([est.output(c) for c in OUTPUTS[:6]])[s:s + L] for s in starts], 1)   # (L, nW, 6)
    U = np.stack([est.inputs[s:s + L] for s in starts], 1)
    sig = np.array([estimate_noise(est.output(c)) for c in OUTPUTS[:6]])
    mask = np.isfinite(Y)
    Yz = np.where(mask, Y, 0.0)
    J = np.diag(af.inertia)

    def resid(th):
        p = th * p0
        x = x0.copy()
        out = np.empty((L, len(starts), 6))
        for k in range(L):
            out[k] = x[:, :6]
            x = _numpy_rk4(x, U[k], p, af.mass, J, af.gravity, af.arm_length)
        e = (Yz - out) / sig
        return np.where(mask, e, 0.0).ravel()

    sol = least_squares(resid, np.ones(5), method="trf", x_scale="jac", max_nfev=60)
    dt = time.perf_counter() - t0
    return dt, dict(zip(FREE, (sol.x * p0).tolist())), {}, truth, sol.nfev


METHODS = {
    "greybox warm": lambda s: run_greybox(s, "warm"),
    "greybox cold (compile)": lambda s: run_greybox(s, "cold"),
    "greybox virtual machine": lambda s: run_greybox(s, "vm"),
    "greybox interval 25": lambda s: run_greybox(s, "interval25"),
    "greybox interval 100": lambda s: run_greybox(s, "interval100"),
    "IPOPT Gauss-Newton": lambda s: run_ipopt(s, "gauss-newton"),
    "IPOPT exact Hessian": lambda s: run_ipopt(s, "exact"),
    "scipy least_squares": run_scipy,
}


def child(method: str, seed: int) -> None:
    dt, est, std, truth, iters = METHODS[method](seed)
    mem = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"time": dt, "est": est, "std": std, "truth": truth, "iters": str(iters), "mem_mb": mem}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--exact", action="store_true", help="also run IPOPT with the exact Hessian (minutes)")
    ap.add_argument("--child")
    ap.add_argument("--out", default=str(HERE / "out" / "bench_fit.json"))
    a = ap.parse_args()
    if a.child:
        child(a.child, a.seed)
        return
    methods = [m for m in METHODS if a.exact or m != "IPOPT exact Hessian"]
    rows = {}
    for m in methods:
        print(f"running {m} ...", file=sys.stderr, flush=True)
        p = subprocess.run([sys.executable, __file__, "--child", m, "--seed", str(a.seed)],
                           capture_output=True, text=True, timeout=3600)
        if p.returncode != 0:
            print(p.stderr[-2000:], file=sys.stderr)
            continue
        rows[m] = json.loads(p.stdout.strip().splitlines()[-1])
    base = rows["greybox warm"]["time"]
    print(f"\n50 s / 1 kHz log, 40,000 estimation samples, start 30-40 % off (seed {a.seed})")
    hdr = f"{'method':<26}{'time s':>8}{'ratio':>8}{'mem MB':>8}{'iters':>16}  " + "".join(f"{n:>9}" for n in FREE)
    print(hdr + "\n" + "-" * len(hdr) + "   (parameter columns: relative error %)")
    for m, r in rows.items():
        errs = "".join(f"{100 * (r['est'][n] / r['truth'][n] - 1):9.2f}" for n in FREE)
        print(f"{m:<26}{r['time']:8.2f}{r['time'] / base:8.1f}{r['mem_mb']:8.0f}{r['iters']:>16}  {errs}")
    gb = rows["greybox warm"]
    print("\ngreybox warm, error / reported std: " +
          "  ".join(f"{n}={(gb['est'][n] - gb['truth'][n]) / gb['std'][n]:+.2f}" for n in FREE))
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()

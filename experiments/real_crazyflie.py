"""The whole workflow on real Crazyflie 2.1 flights (NanoBench): import, fit the base model,
validate on the last 20 %, diagnose, add what is found; cross-check drag with the IMU.

    python experiments/real_crazyflie.py [FILES...] [--out experiments/out/real_crazyflie]

Default files: ``../shared/realdata/nanobench/*.csv``. Writes per flight a diagnosis report
(HTML + PNG), ``imu_drag_<flight>.png``, and ``summary.json`` / ``summary.md`` (the table in
the README) and each flight's final fitted model ``<flight>_final_model.json``. Fits use ``process_noise="auto"``: the logged PWM (sampled from a 500 Hz
controller) is not the whole input truth, and an output-error fit of such data shrinks
the parameters until the model stops moving (see README, "Real flights").
"""
from __future__ import annotations

import argparse
import json
import time
import tomllib
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure   # a bare Figure: no backend selected, no pyplot

from greybox import QuadrotorModel, diagnose
from greybox.airframe import airframe_from_dict
from greybox.controller_law import reported_horizons
from greybox.importers import crazyflie_airframe_toml, import_nanobench
from greybox.model import rotation_matrices
from greybox.plotting import save

HERE = Path(__file__).resolve().parent
REAL = HERE.parents[1] / "shared" / "realdata" / "nanobench"
MASS = 0.030
HORIZON = 0.5
"""Validation horizon of the diagnosis (s): the issue's yardstick is 0.25-0.5 s; over 1 s the
open-loop attitude of a real vehicle diverges, and the 1-s nrmse then rewards a model for
cutting a divergence rather than for predicting (a command delay that halves the 0.25-s roll
error made the 1-s nrmse 28 % worse on B2_circle_fast)."""


def imu_drag(log, out_png: Path, title: str) -> dict[str, float]:
    """Independent drag estimate: body-frame specific force along x/y against body velocity.

    For a rotor (thrust along body -z), the only horizontal body-frame specific force is
    aerodynamic: ``f_x = -(k/m) v_x`` with ``k`` the (rotor + body) drag coefficient.
    """
    t = log.t
    pos = np.column_stack([log.output(c) for c in "xyz"])
    ok = np.isfinite(pos).all(1)
    v = np.column_stack([np.gradient(np.interp(t, t[ok], pos[ok, i]), t) for i in range(3)])
    phi, th, psi = (np.interp(t, t[ok], log.output(c)[ok]) for c in ("phi", "theta", "psi"))
    vb = np.einsum("kji,kj->ki", rotation_matrices(phi, th, psi), v)
    # smooth both sides the same way (IMU noise, differentiated positions)
    kern = np.ones(9) / 9
    sm = lambda y: np.convolve(y, kern, mode="same")  # noqa: E731
    out, fig = {}, Figure(figsize=(8, 3.5))
    for i, ax_name in enumerate("xy"):
        f = sm(log.output(f"a{ax_name}"))
        vv = sm(vb[:, i])
        A = np.column_stack([vv, np.ones_like(vv)])
        coef, *_ = np.linalg.lstsq(A, f, rcond=None)
        r = float(np.corrcoef(vv, f)[0, 1])
        out[f"k_{ax_name}"] = float(-coef[0] * MASS)
        out[f"r_{ax_name}"] = r
        ax = fig.add_subplot(1, 2, i + 1)
        ax.plot(vv, f, ".", ms=1.5, alpha=0.4)
        g = np.linspace(vv.min(), vv.max(), 10)
        ax.plot(g, coef[0] * g + coef[1], "r-", label=f"k = {-coef[0] * MASS:.4f} N s/m (r = {r:+.2f})")
        ax.set_xlabel(f"body v_{ax_name} (m/s)")
        ax.set_ylabel(f"specific force {ax_name} (m/s²)")
        ax.legend(fontsize=8)
    fig.suptitle(f"{title}: IMU drag cross-check")
    fig.tight_layout()
    save(fig, out_png, dpi=110)
    return out


def run(path: Path, out: Path) -> dict:
    name = path.stem
    t0 = time.perf_counter()
    imp = import_nanobench(path)
    toml = crazyflie_airframe_toml(MASS, imp.hover_rotor_speed, ground_z=-(imp.rest_height - 0.025))
    af = airframe_from_dict(tomllib.loads(toml), f"{name} airframe")
    model = QuadrotorModel(af)
    print(f"== {name}: {len(imp.log)} samples, {imp.log.duration:.1f} s airborne", flush=True)
    diag = diagnose(model, imp.log, process_noise="auto", progress=True, horizon=HORIZON)
    base, final = diag.baseline, diag.final_fit or diag.baseline
    est, _ = imp.log.split(0.8)
    w2 = est.inputs[:, :4] ** 2

    def hover(res):
        """The model's mean rotor thrust over the estimation data / the weight, with the thrust
        factors of battery_voltage, thrust_drift (K_T is its value at the log's start) and
        motor_asymmetry (per-rotor deviations); not a ground effect's or a rotor map's."""
        names = res.model.param_names
        scale = np.ones_like(w2)
        if "K_vbat" in names:
            scale *= ((1 + res.value("K_vbat") * (est.extras["vbat"] - 4.0)) ** 2)[:, None]
        if "K_T_drift" in names:
            scale *= (1 + res.value("K_T_drift") * est.t)[:, None]
        if "K_T_dev[0]" in names:
            dev = [res.value(f"K_T_dev[{i}]") for i in range(3)]
            scale *= 1 + np.array(dev + [-sum(dev)])
        thrust = res.value("K_T") * np.mean((w2 * scale).sum(axis=1))
        return float(thrust / (af.mass * af.gravity))

    # the final fitted model, for analyses after the run (experiments/real_closed_loop.py --models)
    diag.fitted_model.save(out / f"{name}_final_model.json")
    drag = imu_drag(est, out / f"imu_drag_{name}.png", name)
    report = diag.report(out / name)
    row = {
        "flight": name,
        "samples": len(imp.log),
        "duration_s": imp.log.duration,
        "import_notes": imp.notes,
        "base_parameters": {n: [base.value(n), float(s)] for n, s in zip(base.free_names, base.std)},
        "final_parameters": {n: [final.value(n), float(s)] for n, s in zip(final.free_names, final.std)},
        "hover_thrust_over_weight_base": hover(base),
        "hover_thrust_over_weight_final": hover(final),
        "imu_specific_force_over_g": float(-est.output("az").mean() / 9.81),
        "imu_drag": drag,
        "nrmse_base": diag.baseline_prediction.nrmse | {"total": diag.baseline_prediction.total},
        "nrmse_final": (diag.final_prediction.nrmse | {"total": diag.final_prediction.total})
        if diag.final_prediction else None,
        "verdicts": [r.verdict for r in diag.rounds if r.verdict],
        # issue 15's checks: a certified base fit, b/K_T in 0.001-0.05 m (published Crazyflie
        # torque-to-thrust ratios 0.002-0.034 m), and the final model against the naive
        # constant-velocity / constant-rate predictor at 0.25 s and 0.5 s
        "base_certified": bool(base.converged),
        "base_status": base.status,
        "b_over_K_T_base": base.value("b") / base.value("K_T"),
        "b_over_K_T_final": final.value("b") / final.value("K_T"),
        # b/K_T with the controller's bias taken out (diagnosis.closed_loop), when the diagnosis gave it
        "b_over_K_T_closed_loop": (diag.closed_loop_fit.value("b") / diag.closed_loop_fit.value("K_T")
                                   if diag.closed_loop_fit is not None else None),
        # the final model's reported prediction (the JSON's horizons: flown by its controller's
        # law where that predicts the estimation flight better) and the model open loop
        "horizons_final": _at(reported_horizons(diag.final_horizons or diag.baseline_horizons, diag.closed_loop),
                              (0.25, 0.5)),
        "reported_prediction": "closed loop" if diag.closed_loop is not None and diag.closed_loop.preferred
        else "open loop",
        "horizons_open_loop": _at(diag.final_horizons or diag.baseline_horizons, (0.25, 0.5)),
        # the final model flown by its controller's law fitted to the log (greybox.controller_law)
        "horizons_closed_loop": _at(diag.closed_loop.horizons, (0.25, 0.5)) if diag.closed_loop else None,
        "closed_loop_law": diag.closed_loop.as_dict()["law"] if diag.closed_loop else None,
        "final_effects": (diag.final_model or model).effect_names,
        "warnings": diag.warnings,
        "report": str(report),
        "seconds": time.perf_counter() - t0,
    }
    print(diag.summary(), flush=True)
    return row


def _at(he, horizons) -> dict:
    """RMS prediction error of the model and of the naive predictor at ``horizons`` (s), per
    position and attitude channel, and whether the model beats the naive one there (``he``:
    the diagnosis' :class:`~greybox.validation.HorizonErrors`, the JSON's ``horizons``)."""
    he = he.as_dict()
    hs = list(he["horizons"])
    out = {}
    for h in horizons:
        k = int(np.argmin([abs(x - h) for x in hs]))
        for ch in ("x", "y", "z", "phi", "theta", "psi"):
            if ch in he["model"]:
                m, n = he["model"][ch][k], he["naive"][ch][k]
                # None: a prediction that blew up (an infinite error) or nothing to score
                m = float("inf") if m is None else m
                n = float("nan") if n is None else n
                out[f"{ch}@{h:g}"] = {"model": m, "naive": n, "beats": bool(m < n)}
    return out


def markdown(rows: list[dict]) -> str:
    lines = ["| flight | verdicts (in order) | hover thrust / weight (base → final) | IMU f_z / g | "
             f"Kd x, y (fit, N s/m) | IMU drag x, y (N s/m) | {HORIZON:g}-s nrmse total (base → final) |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        bp = r["base_parameters"]
        kd = ", ".join(f"{bp[k][0]:.4f}±{bp[k][1]:.4f}" for k in ("Kd[0]", "Kd[1]") if k in bp)
        fin = r["nrmse_final"]["total"] if r["nrmse_final"] else r["nrmse_base"]["total"]
        lines.append(f"| {r['flight']} | {', '.join(r['verdicts']) or 'none'} | "
                     f"{r['hover_thrust_over_weight_base']:.3f} → {r['hover_thrust_over_weight_final']:.3f} | "
                     f"{r['imu_specific_force_over_g']:.3f} | {kd} | "
                     f"{r['imu_drag']['k_x']:.4f}, {r['imu_drag']['k_y']:.4f} | "
                     f"{r['nrmse_base']['total']:.2f} → {fin:.2f} |")
    lines.append("")
    lines.append("Issue 15's checks (final model, its reported prediction: flown by its controller's law where "
                 "that predicts the estimation flight better, else open loop; beats naive: channels of x, y, z, "
                 "phi, theta, psi where the model's RMS prediction error is below the naive predictor's):")
    lines.append("")
    lines.append("| flight | base certified | b/K_T base → final (m) | final, closed-loop bias out (m) | "
                 "prediction | beats naive at 0.25 s | at 0.5 s | open loop beats naive at 0.25 s | at 0.5 s | "
                 "diagnosis (s) |")
    lines.append("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        hz = r["horizons_final"]
        beat = {h: [k.split("@")[0] for k, v in hz.items() if k.endswith(f"@{h}") and v["beats"]]
                for h in ("0.25", "0.5")}
        ol = r.get("horizons_open_loop", hz)
        beat_ol = {h: [k.split("@")[0] for k, v in ol.items() if k.endswith(f"@{h}") and v["beats"]]
                   for h in ("0.25", "0.5")}
        lines.append(f"| {r['flight']} | {'yes' if r['base_certified'] else 'no'} | "
                     f"{r['b_over_K_T_base']:.4f} → {r['b_over_K_T_final']:.4f} | "
                     f"{'-' if r.get('b_over_K_T_closed_loop') is None else format(r['b_over_K_T_closed_loop'], '.4f')} | "
                     f"{r.get('reported_prediction', 'open loop')} | "
                     f"{', '.join(beat['0.25']) or 'none'} | {', '.join(beat['0.5']) or 'none'} | "
                     f"{', '.join(beat_ol['0.25']) or 'none'} | {', '.join(beat_ol['0.5']) or 'none'} | "
                     f"{r['seconds']:.0f} |")
    lines.append("")
    lines.append("RMS prediction error of the final model's reported prediction / the naive predictor (m, rad; "
                 "windows started every 0.1 s of the validation part):")
    lines.append("")
    pose = ["x", "y", "z", "phi", "theta", "psi"]
    lines.append("| flight | ahead | " + " | ".join(pose) + " |")
    lines.append("|---|---|" + "---|" * len(pose))
    for r in rows:
        hz = r["horizons_final"]
        for h in ("0.25", "0.5"):
            cells = [f"{hz[f'{c}@{h}']['model']:.3f} / {hz[f'{c}@{h}']['naive']:.3f}" if f"{c}@{h}" in hz else "-"
                     for c in pose]
            lines.append(f"| {r['flight']} | {h} s | " + " | ".join(cells) + " |")
    closed = [r for r in rows if r.get("horizons_closed_loop")]
    if closed:
        lines.append("")
        lines.append("The final model flown by its controller's law (fitted to the logged commands and "
                     "setpoints; greybox.controller_law): RMS prediction error / the naive predictor's, and "
                     "the channels where it is below:")
        lines.append("")
        lines.append("| flight | law delay, R² roll/pitch | ahead | " + " | ".join(pose) + " | beats naive |")
        lines.append("|---|---|---|" + "---|" * len(pose) + "---|")
        for r in closed:
            hz, law = r["horizons_closed_loop"], r["closed_loop_law"]
            for h in ("0.25", "0.5"):
                cells = [f"{hz[f'{c}@{h}']['model']:.3f} / {hz[f'{c}@{h}']['naive']:.3f}" if f"{c}@{h}" in hz
                         else "-" for c in pose]
                beat = [c for c in pose if f"{c}@{h}" in hz and hz[f"{c}@{h}"]["beats"]]
                lines.append(f"| {r['flight']} | {1e3 * law['delay']:.0f} ms, {law['r2']['roll']:.2f}/"
                             f"{law['r2']['pitch']:.2f} | {h} s | " + " | ".join(cells)
                             + f" | {', '.join(beat) or 'none'} |")
    lines.append("")
    lines.append(f"Per-channel {HORIZON:g}-s nrmse (validation, last 20 %):")
    lines.append("")
    chans = ["x", "y", "z", "phi", "theta", "psi", "p", "q", "r"]
    lines.append("| flight | model | " + " | ".join(chans) + " |")
    lines.append("|---|---|" + "---|" * len(chans))
    for r in rows:
        for lab, key in (("base", "nrmse_base"), ("final", "nrmse_final")):
            if r[key]:
                lines.append(f"| {r['flight']} | {lab} | " + " | ".join(f"{r[key].get(c, float('nan')):.3g}"
                                                                      for c in chans) + " |")
    return "\n".join(lines) + "\n"


def nanobench_files(names: list[Path]) -> list[Path]:
    """The flights named on a command line, a bare file name looked up among the shared
    NanoBench flights; every one of them when none is named."""
    files = [f if f.exists() else REAL / f for f in names] or sorted(REAL.glob("*.csv"))
    if not files:
        raise SystemExit(f"no NanoBench files given and none in {REAL}")
    return files


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--out", type=Path, default=HERE / "out" / "real_crazyflie")
    args = ap.parse_args()
    files = nanobench_files(args.files)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for f in files:
        rows.append(run(f, args.out))
        # after every flight: a later flight's failure keeps the earlier ones' results
        (args.out / "summary.json").write_text(json.dumps(rows, indent=2, default=float))
        (args.out / "summary.md").write_text(markdown(rows))
    print(markdown(rows))


if __name__ == "__main__":
    main()

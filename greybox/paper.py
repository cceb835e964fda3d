"""The seed paper's figures, reproduced with greybox: numbers, tables and figures.

::

    from greybox import paper
    results = paper.run("paper_figures", quick=True)   # all figures, short flights
    results["fig2"]["LQR"]["metrics"]["x"]              # rise / overshoot / settling / ITAE
    results["fig2"].figures["fig2_lqr_vs_pid"]          # a Figure: shown inline in a notebook
    print(paper.summary_markdown(results))

* :func:`fig1` — a model without the yaw reaction torque (b = 0) keeps rotating in yaw at
  hover: the LQR designed on the full model holds position, but a 0.2 rad/s yaw-rate
  disturbance never decays, because nothing in the model can produce a yaw moment.
* :func:`fig2` — LQR (dlqry, Q = 1, R = 0.001, Kr) vs the cascaded PID (eqs. 13-18, gains
  tuned automatically on ITAE) on the grey-box model, the seed's step scenario (1 m steps in
  x at 1 s, y at 6 s, z up at 11 s): responses, rotor speeds, rise / overshoot / settling / ITAE.
* :func:`fig3` — identification with rotor speeds vs with U1..U4 inputs (computed from the
  rotor speeds with "known" K_T, b from a bench test that is 4 % / 7 % off): the same
  flights, each model fitted on each flight and validated on the others. Which is the more
  consistent model, in numbers: spread of the fitted drag across flights and the
  cross-flight 1-s prediction error.
* :func:`fig56` — Figs. 5/6: a 50 s, 1 kHz "experimental" flight (the synthetic truth, with
  quadratic drag the grey-box model does not have: its linear drag absorbs it), a grey-box
  model fitted to it (80 %), an n4sid black-box model identified from it (decimated to
  100 Hz), and the same LQR design on each: position (Fig. 5) and attitude (Fig. 6)
  responses to the step scenario. The "flight" is the true vehicle flown by the LQR
  designed on the grey-box model; the black-box closed loop is dlqry on the black box's own
  states (output weighting makes the same design procedure apply to any state coordinates).

Each ``figN`` function returns its numbers as a :class:`PaperResult` (a plain ``dict``, JSON
serialisable, whose ``.figures`` holds the :class:`matplotlib.figure.Figure` objects by
name) and, when given a folder ``out``, writes each figure there as ``<name>.png``.
:func:`run` makes several (all by default) and also writes ``figN.json`` and ``summary.md``
(:func:`summary_markdown`); ``quick=True`` shortens the flights for a smoke run (about a
minute instead of three). No function here selects a matplotlib backend or uses pyplot.

The repository's ``experiments/paper_figures.py`` is the command line over this module.
"""
from __future__ import annotations

import json
import sys
import time
from importlib import resources
from pathlib import Path
from typing import Callable

import numpy as np
from matplotlib.figure import Figure

from .airframe import load_airframe
from .closedloop import (design_lqr, simulate_linear_lqr, simulate_lqr, simulate_pid, step_metrics,
                         step_reference, tune_pid)
from .data import FlightLog
from .errors import GreyboxInputError
from .fitting import fit
from .model import OUTPUTS, QuadrotorModel
from .n4sid import n4sid
from .plotting import new_figure, save
from .synth import SensorSpec, model_with_hidden_effects, synthesize
from .validation import predict

__all__ = ["PaperResult", "paper_model", "controls_log", "fig1", "fig2", "fig3", "fig56", "run",
           "summary_markdown", "FIGURES", "QUICK", "STEPS", "DPI"]

STEPS = (("x", 1.0, 0.0, 1.0), ("y", 6.0, 0.0, 1.0), ("z", 11.0, -1.0, -2.0))
"""The seed's step scenario: (axis, time of the step, from, to)."""
HOVER_MANOEUVRES = ("hover", "step_x", "step_y", "step_z")
DPI = 110
"""Resolution of the PNG files written."""


class PaperResult(dict):
    """A figure's numbers (a plain ``dict``: what ``figN.json`` holds) with its figures in
    ``.figures`` (name -> :class:`~matplotlib.figure.Figure`; the name is the PNG's stem)."""

    def __init__(self, *args, figures: dict[str, Figure] | None = None, **kw):
        super().__init__(*args, **kw)
        self.figures: dict[str, Figure] = dict(figures or {})


def paper_model() -> QuadrotorModel:
    """The seed paper's quadrotor (the airframe ``paper.toml`` bundled with greybox)."""
    with resources.as_file(resources.files("greybox") / "data" / "airframes" / "paper.toml") as path:
        return QuadrotorModel(load_airframe(path))


def _metrics(t: np.ndarray, series: dict[str, np.ndarray]) -> dict[str, dict]:
    return {ax: step_metrics(t, series[ax], t0, a, b) for ax, t0, a, b in STEPS}


def _finish(res: dict, figures: dict[str, Figure], out: str | Path | None) -> PaperResult:
    if out is not None:
        for name, fig in figures.items():
            save(fig, Path(out) / f"{name}.png", dpi=DPI)
    return PaperResult(res, figures=figures)


# ------------------------------------------------------------------------------- Fig. 1
def fig1(out: str | Path | None = None, duration: float = 20.0, yaw_rate: float = 0.2) -> PaperResult:
    """Hover with a yaw-rate disturbance, with and without the yaw reaction torque.

    Numbers per model: yaw angle and yaw rate at the end, largest position error. Figure
    ``fig1_yaw_without_reaction_torque``."""
    model = paper_model()
    p = model.default_parameters()
    p_nob = p.copy()
    p_nob[model.param_names.index("b")] = 0.0
    design = design_lqr(model, p)
    t = np.arange(0, duration, design.dt)
    ref = step_reference(t, steps=[])
    w_h = model.hover_speed(p)
    x0 = model.initial_state([0, 0, -1, 0, 0, 0, 0, 0, 0, 0, 0, yaw_rate], np.full(model.nu, w_h), p)
    runs = {"with b (full model)": simulate_lqr(model, p, design, ref, x0=x0),
            "b = 0 (no yaw reaction torque)": simulate_lqr(model, p_nob, design, ref, x0=x0)}
    names = model.state_names
    res = {}
    for k, cl in runs.items():
        psi, r = cl.output("psi", names), cl.output("r", names)
        pos_err = np.linalg.norm(cl.states[:, :3] - ref[:, :3], axis=1)
        res[k] = {"psi_end_rad": float(psi[-1]), "yaw_rate_end_rad_s": float(r[-1]),
                  "max_position_error_m": float(pos_err.max())}
    fig = new_figure((11, 3.8))
    axes = fig.subplots(1, 2)
    for k, cl in runs.items():
        axes[0].plot(t, np.degrees(cl.output("psi", names)), label=k)
        axes[1].plot(t, 1000 * np.linalg.norm(cl.states[:, :3] - ref[:, :3], axis=1), label=k)
    axes[0].set_ylabel("yaw psi, deg")
    axes[1].set_ylabel("position error, mm")
    for a in axes:
        a.set_xlabel("t, s")
        a.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(f"Fig. 1: hover under LQR after a {yaw_rate} rad/s yaw-rate disturbance")
    return _finish(res, {"fig1_yaw_without_reaction_torque": fig}, out)


# ------------------------------------------------------------------------------- Fig. 2
def fig2(out: str | Path | None = None, max_evals: int = 300) -> PaperResult:
    """LQR vs automatically tuned cascaded PID on the grey-box model.

    Numbers: the PID gains and tuning time, per controller the step metrics per axis and the
    saturated fraction. Figure ``fig2_lqr_vs_pid``."""
    model = paper_model()
    p = model.default_parameters()
    design = design_lqr(model, p)
    t = np.arange(0, 20, design.dt)
    ref = step_reference(t)
    t0 = time.perf_counter()
    pid = tune_pid(model, p, max_evals=max_evals)
    t_tune = time.perf_counter() - t0
    loops = {"LQR": simulate_lqr(model, p, design, ref), "PID": simulate_pid(model, p, pid, ref)}
    names = model.state_names
    res = {"pid_gains": pid.gains, "pid_tuning_s": t_tune}
    for k, cl in loops.items():
        res[k] = {"metrics": _metrics(t, {ax: cl.output(ax, names) for ax in "xyz"}),
                  "saturated_fraction": cl.saturated}
    fig = new_figure((9, 9))
    axes = fig.subplots(4, 1, sharex=True)
    for k, cl in loops.items():
        for i, ax in enumerate("xyz"):
            axes[i].plot(t, cl.output(ax, names), label=k)
        axes[3].plot(t, cl.inputs[:, 0], label=f"{k}: w1")
    for i, ax in enumerate("xyz"):
        axes[i].plot(t, ref[:, i], color="0.6", lw=0.8, label="reference")
        axes[i].set_ylabel(f"{ax}, m")
    axes[3].set_ylabel("rotor 1, rad/s")
    axes[3].set_xlabel("t, s")
    axes[0].legend()
    fig.suptitle("Fig. 2: LQR (dlqry, Q = 1, R = 0.001, Kr) vs cascaded PID (tuned on ITAE), grey-box model")
    return _finish(res, {"fig2_lqr_vs_pid": fig}, out)


# ------------------------------------------------------------------------------- Fig. 3
def controls_log(log: FlightLog, model: QuadrotorModel, kt: float, b: float) -> FlightLog:
    """The log with U1..U4 computed from its rotor speeds with coefficients ``kt``, ``b``."""
    G = model.airframe.allocation_matrix()
    U = (np.diag([kt, kt, kt, b]) @ G @ (log.inputs ** 2).T).T
    return FlightLog(log.t, U, ["u1", "u2", "u3", "u4"], log.outputs.copy(), list(log.output_names), {}, [],
                     f"{log.source or 'log'} (U from w)")


def fig3(out: str | Path | None = None, duration: float = 30.0, n_flights: int = 3, kt_error: float = 0.04,
         b_error: float = -0.07) -> PaperResult:
    """Rotor-speed inputs (K_T, b, Kd fitted) vs U1..U4 inputs (bench K_T, b; Kd fitted).

    Numbers per kind of input: the fitted drag per flight, its mean, error and spread, the
    own- and cross-flight 1-s nrmse per channel. Figure ``fig3_rotor_speeds_vs_controls``."""
    model = paper_model()
    truth = model.default_parameters()
    kt_true, b_true = truth[model.param_names.index("K_T")], truth[model.param_names.index("b")]
    kt_bench, b_bench = kt_true * (1 + kt_error), b_true * (1 + b_error)
    kd_true = np.array([model.parameter_dict(truth)[f"Kd[{i}]"] for i in range(3)])
    model_u = model.with_inputs("controls")
    sensors = SensorSpec(rate=200.0, vision_rate=60.0)
    flights = [synthesize(model, duration=duration, sensors=sensors, seed=31 + k,
                          manoeuvres=("hover", "step_x", "step_y", "step_z", "yaw")).log for k in range(n_flights)]
    start = {"K_T": kt_true * 1.3, "b": b_true * 0.7, "Kd": [0.13, 0.07, 0.2]}
    kinds = {"rotor speeds": (model, flights, None, start),
             "U1..U4 (bench K_T, b)": (model_u, [controls_log(f, model, kt_bench, b_bench) for f in flights],
                                        ["K_T", "b"], {"K_T": kt_bench, "b": b_bench, "Kd": [0.13, 0.07, 0.2]})}
    res = {"bench_error": {"K_T": kt_error, "b": b_error}}
    for kind, (m, logs, fixed, p0) in kinds.items():
        fits = [fit(m, lg.split(0.8)[0], fixed=fixed, p0=p0) for lg in logs]
        kd = np.array([[r.value(f"Kd[{i}]") for i in range(3)] for r in fits])
        cross, own = [], []
        for a, r in enumerate(fits):
            for bb, lg in enumerate(logs):
                pr = predict(m, r.p, lg if a != bb else lg.split(0.8)[1])
                (own if a == bb else cross).append(pr.nrmse)
        chans = list(cross[0])
        res[kind] = {"Kd": kd.tolist(), "Kd_mean": kd.mean(axis=0).tolist(),
                     "Kd_spread_pct": (100 * kd.std(axis=0, ddof=1) / kd.mean(axis=0)).tolist() if len(fits) > 1 else None,
                     "Kd_error_pct": (100 * (kd.mean(axis=0) / kd_true - 1)).tolist(),
                     "converged": [bool(r.converged) for r in fits],
                     "cross_flight_nrmse": {c: float(np.mean([d[c] for d in cross])) for c in chans},
                     "own_flight_nrmse": {c: float(np.mean([d[c] for d in own])) for c in chans}}
        res[kind]["cross_flight_nrmse_mean"] = float(np.mean(list(res[kind]["cross_flight_nrmse"].values())))
    fig = new_figure((12, 4))
    axes = fig.subplots(1, 2)
    chans = list(res["rotor speeds"]["cross_flight_nrmse"])
    for k, kind in enumerate(kinds):
        axes[0].bar(np.arange(len(chans)) + 0.4 * k - 0.2, [res[kind]["cross_flight_nrmse"][c] for c in chans],
                    0.4, label=kind)
        kd = np.array(res[kind]["Kd"])
        for i in range(3):
            axes[1].plot(np.full(kd.shape[0], i + 0.15 * (2 * k - 1)), kd[:, i], "os"[k], color=f"C{k}",
                         label=kind if i == 0 else None)
    axes[0].set_xticks(range(len(chans)), chans)
    axes[0].set_ylabel("1-s prediction NRMSE on the other flights")
    axes[0].legend()
    axes[1].plot(range(3), kd_true, "k_", ms=30, label="truth")
    axes[1].set_yscale("log")
    axes[1].set_xticks(range(3), ["Kd x", "Kd y", "Kd z"])
    axes[1].set_ylabel("fitted drag, N s/m (one point per flight)")
    axes[1].legend()
    fig.suptitle(f"Fig. 3: rotor speeds vs U1..U4 inputs (bench K_T {100 * kt_error:+.0f} %, b {100 * b_error:+.0f} %)")
    return _finish(res, {"fig3_rotor_speeds_vs_controls": fig}, out)


# ----------------------------------------------------------------------------- Figs. 5/6
def fig56(out: str | Path | None = None, duration: float = 50.0, rate: float = 1000.0,
          order: int | str = 12) -> PaperResult:
    """Grey-box, n4sid black-box and the 'experimental' flight under the same LQR design.

    Numbers: the grey-box parameters and fit time, the black box's order, identification
    time, stability and largest closed-loop pole, step metrics of each response and their
    RMS gap to the flight. Figures ``fig5_position`` and ``fig6_attitude``."""
    base = paper_model()
    truth_model, p_true = model_with_hidden_effects(base, ["quadratic_drag"])
    syn = synthesize(truth_model, p_true, duration=duration, manoeuvres=HOVER_MANOEUVRES, seed=5,
                     sensors=SensorSpec(rate=rate, vision_rate=min(rate, 100.0)))
    est, _ = syn.log.split(0.8)
    t0 = time.perf_counter()
    grey = fit(base, est, p0={"K_T": 2.395e-5 * 1.2, "b": 6.8429e-7 * 0.8, "Kd": [0.12, 0.08, 0.18]})
    t_grey = time.perf_counter() - t0
    # n4sid on the noise-free-sampled flight decimated to 100 Hz (block means), 80 %
    k = max(int(round(rate / 100.0)), 1)
    outs = ["x", "y", "z", "phi", "theta", "psi"]
    Y = syn.outputs_true[:, [OUTPUTS.index(c) for c in outs]]
    Yn = np.column_stack([syn.log.output(c) for c in outs])
    Y = np.where(np.isnan(Yn), Y, Yn)      # measured where measured, truth-interpolated between vision samples
    n = (len(syn.log) // k) * k
    u = syn.log.inputs[:n].reshape(-1, k, base.nu).mean(axis=1)
    y = Y[:n].reshape(-1, k, len(outs)).mean(axis=1)
    ne = int(0.8 * u.shape[0])
    t0 = time.perf_counter()
    black = n4sid(u[:ne], y[:ne], dt=k / rate, order=order, input_names=base.command_names, output_names=outs)
    t_black = time.perf_counter() - t0

    design = design_lqr(base, grey.p, dt=k / rate)
    t = np.arange(0, 20, design.dt)
    ref = step_reference(t)
    names = base.state_names
    grey_cl = simulate_lqr(base, grey.p, design, ref)
    flight_cl = simulate_lqr(truth_model, p_true, design, ref)
    black_cl = simulate_linear_lqr(black, ref)
    series = {"flight (truth)": {c: flight_cl.output(c, truth_model.state_names) for c in outs},
              "grey-box": {c: grey_cl.output(c, names) for c in outs},
              "black-box (n4sid)": {c: black_cl.output(c) for c in outs}}
    res = {"grey_box": {"parameters": {n_: grey.value(n_) for n_ in grey.free_names}, "fit_s": t_grey},
           "black_box": {"order": black.order, "identify_s": t_black, "stable": black.is_stable(),
                         "closed_loop_poles_max": float(np.max(np.abs(black_cl.poles)))},
           "metrics": {k_: _metrics(t, s) for k_, s in series.items()},
           "rms_gap_to_flight_m_or_rad": {k_: {c: float(np.sqrt(np.mean((s[c] - series["flight (truth)"][c]) ** 2)))
                                               for c in outs} for k_, s in series.items() if k_ != "flight (truth)"}}
    figures = {}
    for fig_no, chans, unit in ((5, ["x", "y", "z"], "m"), (6, ["phi", "theta", "psi"], "deg")):
        what = "position" if unit == "m" else "attitude"
        fig = new_figure((9, 8))
        axes = fig.subplots(3, 1, sharex=True)
        for i, c in enumerate(chans):
            for (k_, s), style in zip(series.items(), ("k-", "C0--", "C1:")):
                v = s[c] if unit == "m" else np.degrees(s[c])
                axes[i].plot(t, v, style, label=k_)
            if unit == "m":
                axes[i].plot(t, ref[:, i], color="0.6", lw=0.8, label="reference")
            axes[i].set_ylabel(f"{c}, {unit}")
        axes[0].legend(fontsize=8)
        axes[2].set_xlabel("t, s")
        fig.suptitle(f"Fig. {fig_no}: {what} under the same LQR design")
        figures[f"fig{fig_no}_{what}"] = fig
    return _finish(res, figures, out)


FIGURES: dict[str, Callable[..., PaperResult]] = {"fig1": fig1, "fig2": fig2, "fig3": fig3, "fig56": fig56}
"""The figure functions by name (the names :func:`run` takes in ``only``)."""
QUICK = {"fig1": {"duration": 10.0}, "fig2": {"max_evals": 60}, "fig3": {"duration": 20.0, "n_flights": 2},
         "fig56": {"duration": 30.0, "rate": 200.0}}
"""The options of ``quick=True`` (short flights, fewer PID evaluations), per figure."""


def summary_markdown(results: dict) -> str:
    """The tables of the figures in ``results`` (as :func:`run` returns them), as Markdown."""
    L = ["# The seed paper's figures, reproduced", ""]
    if "fig1" in results:
        L += ["## Fig. 1: yaw without the reaction torque", "", "| model | psi at end, rad | yaw rate at end, rad/s "
              "| max position error, m |", "|---|---|---|---|"]
        L += [f"| {k} | {v['psi_end_rad']:.3f} | {v['yaw_rate_end_rad_s']:.4f} | {v['max_position_error_m']:.4f} |"
              for k, v in results["fig1"].items()]
    if "fig2" in results:
        r = results["fig2"]
        L += ["", "## Fig. 2: LQR vs PID (grey-box model)", "", "| controller | axis | rise s | overshoot % | "
              "settling s | ITAE |", "|---|---|---|---|---|---|"]
        for c in ("LQR", "PID"):
            for ax, m in r[c]["metrics"].items():
                L.append(f"| {c} | {ax} | {m['rise_time']:.3f} | {m['overshoot_pct']:.1f} | "
                         f"{m['settling_time']:.3f} | {m['itae']:.4f} |")
        L.append(f"\nPID gains (tuned in {r['pid_tuning_s']:.1f} s): "
                 + ", ".join(f"{k} = {v:.3g}" for k, v in r["pid_gains"].items()))
    if "fig3" in results:
        r = results["fig3"]
        L += ["", "## Fig. 3: rotor speeds vs U1..U4 inputs", "",
              f"Bench coefficients used for U: K_T {100 * r['bench_error']['K_T']:+.0f} %, "
              f"b {100 * r['bench_error']['b']:+.0f} %.", "",
              "| inputs | Kd mean (x, y, z) | Kd error % | Kd spread across flights % | cross-flight NRMSE (mean) "
              "| fits converged |", "|---|---|---|---|---|---|"]
        for kind in ("rotor speeds", "U1..U4 (bench K_T, b)"):
            v = r[kind]
            spread = ", ".join(f"{s:.1f}" for s in v["Kd_spread_pct"]) if v["Kd_spread_pct"] else "-"
            L.append(f"| {kind} | {', '.join(f'{k:.4f}' for k in v['Kd_mean'])} | "
                     f"{', '.join(f'{e:+.1f}' for e in v['Kd_error_pct'])} | {spread} | "
                     f"{v['cross_flight_nrmse_mean']:.4f} | {sum(v['converged'])} of {len(v['converged'])} |")
        L.append("\nCross-flight NRMSE per channel: " + "; ".join(
            f"{kind}: " + ", ".join(f"{c} {v:.3f}" for c, v in r[kind]["cross_flight_nrmse"].items())
            for kind in ("rotor speeds", "U1..U4 (bench K_T, b)")))
    if "fig56" in results:
        r = results["fig56"]
        L += ["", "## Figs. 5/6: grey-box, black-box and flight under the same LQR design", "",
              f"n4sid order {r['black_box']['order']} in {r['black_box']['identify_s']:.2f} s "
              f"(stable: {r['black_box']['stable']}); grey-box fit {r['grey_box']['fit_s']:.1f} s.", "",
              "| response of | x rise s | x overshoot % | x settling s | y settling s | z rise s | z settling s |",
              "|---|---|---|---|---|---|---|"]
        for k, m in r["metrics"].items():
            L.append(f"| {k} | {m['x']['rise_time']:.3f} | {m['x']['overshoot_pct']:.1f} | "
                     f"{m['x']['settling_time']:.3f} | {m['y']['settling_time']:.3f} | {m['z']['rise_time']:.3f} | "
                     f"{m['z']['settling_time']:.3f} |")
        L += ["", "RMS gap to the flight: " + "; ".join(
            f"{k}: " + ", ".join(f"{c} {v:.4f}" for c, v in g.items()) for k, g in r["rms_gap_to_flight_m_or_rad"].items())]
    return "\n".join(L) + "\n"


def run(out: str | Path, only: list[str] | None = None, quick: bool = False,
        progress: bool = True) -> dict[str, PaperResult]:
    """Make the figures (all, or those named in ``only``) into the folder ``out`` (created):
    ``<figure>.png``, ``figN.json`` with each figure's numbers and ``summary.md`` with the
    tables. ``quick``: short flights (see :data:`QUICK`). ``progress``: name and time of
    each figure on stderr. Returns the numbers (and figures) by figure name.

    An unknown name in ``only`` is a :class:`~greybox.errors.GreyboxInputError`, before
    anything is computed."""
    out = Path(out)
    names = list(only or FIGURES)
    for name in names:
        if name not in FIGURES:
            raise GreyboxInputError(f"unknown figure {name!r}; known: {', '.join(FIGURES)}")
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, PaperResult] = {}
    for name in names:
        t0 = time.perf_counter()
        if progress:
            print(f"{name} ...", file=sys.stderr, flush=True)
        results[name] = FIGURES[name](out, **(QUICK[name] if quick else {}))
        (out / f"{name}.json").write_text(json.dumps(results[name], indent=2, default=float))
        if progress:
            print(f"{name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    (out / "summary.md").write_text(summary_markdown(results))
    return results

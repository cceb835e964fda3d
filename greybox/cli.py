"""The ``greybox`` command line (README, "Command line"): a thin layer over the library.

User mistakes print one ``greybox: error: ...`` line and exit with status 2; results given
with ``--json`` are written atomically.
"""
from __future__ import annotations

import argparse
import errno
import json
import os
import sys
import warnings as _warnings
from importlib import resources
from pathlib import Path
from typing import Sequence

import numpy as np

from . import __version__
from . import effects as fx
from .airframe import load_airframe
from .data import (FLIP_MARGIN_S, FLIP_MIN_PIECE_S, FLIP_PITCH, FlightLog, atomic_write, check_distinct_flights,
                   check_rotor_speed_units, check_sample_times, read_csv_table, rotor_speed_magnitudes, save_log)
from .errors import ConvergenceWarning, GreyboxError, GreyboxInputError, Terminated, forget_signals, interrupt_status, raise_interrupted, raise_terminated, signal_received
from .integrate import simulate
from .model import QuadrotorModel
from .commands import (build_model, check_output_path, check_parameter_names, fit_json, model_from_args, model_log, parse_sets,
                       write_json)
from .validation import DEFAULT_INIT_WINDOW

__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:
        # argparse's own usage errors: exit 2 as well, in one line that says where help is
        raise GreyboxInputError(f"{message} (see '{self.prog} --help')")


def _number_type(kind: str, low: float | None = None, high: float | None = None,
                 integer: bool = False, low_open: bool = False, high_open: bool = False):
    """An argparse ``type`` that accepts finite numbers in a range and names the rule otherwise."""
    def convert(text: str):
        try:
            v = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if integer else 'a number'}") from None
        if not np.isfinite(v):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        if (low is not None and (v <= low if low_open else v < low)) or \
                (high is not None and (v >= high if high_open else v > high)):
            raise argparse.ArgumentTypeError(f"{text!r}: must be {kind}")
        return v
    convert.__name__ = kind   # argparse names the type in some messages
    return convert


_finite = _number_type("a finite number")
_positive = _number_type("positive", 0.0, low_open=True)
_non_negative = _number_type("zero or positive", 0.0)
_probability = _number_type("in [0, 1)", 0.0, 1.0, high_open=True)
_positive_int = _number_type("a positive integer", 1, integer=True)
_digits = _number_type("between 3 and 17", 3, 17, integer=True)
_seed = _number_type("zero or a positive integer", 0, integer=True)

FIT_DEFAULTS = {"horizon": 1.0, "max_iter": 60, "process_noise": "if_needed"}
"""``greybox fit``'s defaults that an IMU-only log's fit takes as given (any other value is refused)."""

OUTPUT_OPTIONS = {"json": ("--json", "file"), "out": ("--out", "file"), "save": ("--save", "file"),
                  "airframe_out": ("--airframe-out", "file"), "plots": ("--plots", "folder"),
                  "report": ("--report", "folder"), "out_dir": ("--out-dir", "folder"),
                  "write_effect": ("--write-effect", "file"), "split_out": ("--out", "folder")}
"""Options that name something the command writes: checked before any computation."""


def _parameters(model: QuadrotorModel, brought: dict, sets) -> np.ndarray:
    """Parameter vector: the model's defaults, then a saved model's values, then ``--set``."""
    return model.parameter_vector(parse_sets(sets), model.parameter_vector(brought))


def _parse_x0(text: str | None) -> list[float] | None:
    if text is None:
        return None
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise GreyboxInputError(f"--x0 {text!r}: expected 12 comma-separated numbers") from None
    if len(vals) != 12:
        raise GreyboxInputError(f"--x0 needs 12 values (x,y,z,phi,theta,psi,vx,vy,vz,p,q,r), got {len(vals)}")
    if not all(np.isfinite(vals)):
        raise GreyboxInputError(f"--x0 {text!r}: every value must be a finite number")
    return vals


def _read_inputs(path: str, model: QuadrotorModel, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    everything = ["t"] + model.input_names
    text: list[str] = []
    header, data, lines = read_csv_table(path, line_numbers=True, must_be_numeric=lambda h: h in everything,
                                         text_columns=text)
    if text:
        print(f"note: {path}: ignored text column(s) {', '.join(text)}", file=sys.stderr)
    # signals derived from the commands (w1@next, w1@-10ms) come from the file's own commands,
    # as a fit derives them from a log's, unless the file gives them
    names = ["t"] + [n for n in model.input_names if not fx.is_derived_signal(n) or n in header]
    for n in names:
        if n not in header:
            raise GreyboxInputError(f"{path}: missing required column {n!r}")
    ignored = [h for h in header if h not in names and h not in text]
    if ignored:
        print(f"note: {path}: ignored column(s) {', '.join(ignored)} (simulate reads the time and the model's "
              "inputs; the outputs are simulated from the start state)", file=sys.stderr)
    if data.shape[0] == 0:
        raise GreyboxInputError(f"{path}: no data rows after the header")
    M = data[:, [header.index(n) for n in names]]
    bad = np.argwhere(np.isnan(M))
    if bad.size:
        r, c = bad[0]
        raise GreyboxInputError(f"{path}: row {lines[r]}, column {names[c]!r}: missing value")
    t = M[:, 0]
    check_sample_times(t, path, lines)
    # the model's inputs as a fit prepares a log's (derived signals computed from the commands)
    U = model.prepare_log(FlightLog(t, M[:, 1:], names[1:], np.full((t.size, 0), np.nan), [],
                                    source=path)).inputs
    if model.inputs == "rotor_speeds":
        n_rot = model.airframe.n_rotors
        U = U.copy()
        U[:, :n_rot], signs = rotor_speed_magnitudes(U[:, :n_rot], model.input_names[:n_rot], path)
        for note in signs + check_rotor_speed_units(U[:, :n_rot], model.input_names[:n_rot], path, lines):
            print(f"note: {note}", file=sys.stderr)
        for note in model.check_rotor_speeds(U[:, :n_rot], p, path, too_slow="note"):
            print(f"note: {note}", file=sys.stderr)
    return t, U


# ---------------------------------------------------------------------------- commands
def cmd_simulate(args: argparse.Namespace) -> int:
    model, brought = model_from_args(args)
    p = _parameters(model, brought, args.set)
    x0 = _parse_x0(args.x0)         # the options first: a bad one is the only line said
    t, U = _read_inputs(args.inputs, model, p)
    sim = simulate(model, t, U, p, x0, method=args.integrator)
    Y = sim.outputs.copy()
    # the angles as a log reports them, each within [-pi, pi) (the same rotation): the
    # integrated ones of a vehicle that tumbles reach many turns, which greybox fit refuses
    # as "in degrees?" (a blind audit fitted its own simulated tumble)
    from .io.base import wrap_angle
    for name in ("phi", "theta", "psi"):
        Y[:, model.output_names.index(name)] = wrap_angle(Y[:, model.output_names.index(name)])
    log = FlightLog(t, U, model.input_names, Y, list(model.output_names))
    save_log(log, args.out)
    print(f"simulated {len(t)} samples ({t[-1] - t[0]:.3f} s), effects {','.join(model.effect_names)}"
          f" -> {args.out}", file=sys.stderr)
    if args.json:
        write_json(args.json, {"samples": int(len(t)), "effects": model.effect_names,
                               "parameters": model.parameter_dict(p),
                               "final_state": dict(zip(model.state_names, map(float, sim.states[-1]))),
                               "out": str(args.out)})
    return 0


def cmd_synth(args: argparse.Namespace) -> int:
    from .synth import SensorSpec, model_with_hidden_effects, synthesize
    base, brought = model_from_args(args, effects=None)
    hidden = fx.parse_effect_names(args.effects)
    model, p = model_with_hidden_effects(base, hidden, {**brought, **parse_sets(args.set)})
    sensors = SensorSpec(rate=args.rate, vision_rate=args.vision_rate, pos_noise=args.pos_noise,
                         att_noise=args.att_noise, gyro_noise=args.gyro_noise,
                         accel_noise=args.accel_noise,
                         input_noise=args.input_noise, dropout=args.dropout)
    man = [m.strip() for m in args.manoeuvres.split(",") if m.strip()]
    res = synthesize(model, p, args.duration, sensors, man, args.seed, args.excitation, args.altitude)
    save_log(res.log, args.out, digits=args.digits)
    print(f"synthesised {len(res.log)} samples ({args.duration:g} s, seed {args.seed}), effects "
          f"{','.join(model.effect_names)} -> {args.out}", file=sys.stderr)
    if args.json:
        write_json(args.json, res.truth())
    return 0


def cmd_effects(args: argparse.Namespace) -> int:
    """Every known effect with its summary, parameters (unit, null, default, bounds) and origin."""
    fitted: dict = {}
    in_model: set[str] = set()
    if args.model:
        # a saved model: its airframe's defaults and bounds, and its own effects' fitted values
        from .fitted import load
        fm = load(args.model)
        af, fitted, in_model = fm.model.airframe, fm.parameters_, set(fm.model.effect_names)
    elif args.airframe:
        af = load_airframe(args.airframe)
    else:
        with resources.as_file(resources.files("greybox") / "data" / "airframes" / "paper.toml") as p:
            af = load_airframe(p)
    registered = fx.registered_effects()
    out = []
    # the disturbance models too: no diagnosis candidates (they explain any torque), but a
    # model takes them by name (--effects disturbance_torque, which fit warnings advise)
    for name, cls in {**fx.known_effects(), **fx.DISTURBANCE_MODELS}.items():
        origin = ("base" if name in fx.BASE_EFFECTS else "catalogue" if name in fx.CATALOGUE else
                  "signal" if name in fx.SIGNAL_EFFECTS else "disturbance" if name in fx.DISTURBANCE_MODELS else
                  registered.get(name, "registered"))
        params = [{"name": p.name, "size": p.size, "unit": p.unit, "null": p.null,
                   "default": p.default_vector().tolist(), "lower": _num_or_none(p.lower),
                   "upper": _num_or_none(p.upper), "free": p.free, "description": p.description}
                  | ({"fitted": [float(fitted[c]) for c in p.component_names]}
                     if name in in_model and all(c in fitted for c in p.component_names) else {})
                  for p in cls().parameters(af)]
        out.append({"name": name, "origin": origin, "summary": cls.summary, "parameters": params,
                    "states": cls().state_names(af), "signals": list(cls.signals), "channels": list(cls.channels),
                    "excited_by": cls.excited_by, "shifts_trim": cls.shifts_trim, "per_flight": cls.per_flight}
                   | ({"in_model": name in in_model} if args.model else {}))
        pstr = "; ".join(f"{p['name']}" + (f"[{p['size']}]" if p["size"] > 1 else "") +
                         f" ({p['unit'] or '-'}, null {p['null']:g})" for p in params) or "no parameters"
        if name in in_model:
            pstr += "; in the model: " + ", ".join(
                f"{p['name']} = {', '.join(f'{v:.4g}' for v in p['fitted'])}" for p in params if "fitted" in p)
        print(f"{name:<18} {origin:<11} {cls.summary}\n{'':<30}{pstr}")
    if args.json:
        write_json(args.json, {"effects": out})
    return 0


def _num_or_none(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def cmd_demo(args: argparse.Namespace) -> int:
    """The greybox story on a bundled log: compare, where it fails, ranking, add, error falls."""
    from .data import load_log
    from .diagnosis import diagnose
    data = resources.files("greybox") / "data"
    with resources.as_file(data / "airframes" / "paper.toml") as af_path, \
            resources.as_file(data / "logs" / "demo_ground_effect.csv") as log_path, \
            resources.as_file(data / "logs" / "demo_ground_effect_validation.csv") as val_path:
        model = build_model(str(af_path))
        log = load_log(log_path)
        validation = load_log(val_path)
    print("greybox demo: a 30 s flight of the seed paper's quadrotor (bundled log, 200 Hz IMU, 50 Hz vision),\n"
          "and a second 28 s flight to validate on; "
          f"model: {', '.join(model.effect_names)}. What is it missing?\n")
    diag = diagnose(model, log, progress=not args.quiet, validation=validation)
    print()
    print(diag.summary())
    print(f"\nreport: {diag.report(Path(args.out_dir))}")
    if args.json:
        write_json(args.json, diag.as_json())
    return 0


INPUT_NOISE_HELP = ("the logged rotor speeds' white noise that the vehicle does not follow (the gyro tells): "
                    "'smooth' (default) takes it out before fitting, 'keep' fits the speeds as logged (see README)")
HELD_HELP = ("rotor speeds that repeat the previous row exactly on most rows (a slower signal held on the "
             "rows, e.g. ESC telemetry at 50 Hz on 100 Hz rows): 'hold' (default) fits them as logged, with a "
             "note; 'interpolate' interpolates them between their fresh rows, as the importers do (see README)")
OUTLIERS_HELP = ("isolated glitches in the position or attitude (a marker swap: samples that leave their "
                 "neighbours' track by over 10 times the noise and come back): 'drop' (default) leaves them "
                 "out with a note, 'keep' fits them (see README)")


def _load_fit_inputs(args: argparse.Namespace):
    """Model, starting parameters (``--set``) and the logs, each checked before any work."""
    window = _time_window(args)
    model, brought = model_from_args(args)
    p0 = _parameters(model, brought, args.set)
    return model, p0, [_load_model_log(model, path, p0, args.input_noise, args.outliers, args.held, window)
                       for path in args.log]


def _check_rotor_geometry(model: QuadrotorModel, logs, validation=(), only_validation: bool = False) -> None:
    """Rotor-speed columns that act as the airframe's rotors in another order, or turned about
    the body's z (an "x" airframe for a "plus" log), found from the logs alone before any fit:
    one error naming the flight. A fit of such a log holds the columns' moments as physics (a
    blind audit's Betaflight motor order: "optimum certified", b on its bound at 0, exit 0,
    with the order said only among the warnings). The ``validation`` flights are judged with
    them: predicted in another order they read as a model that fails (a blind audit's
    Betaflight-ordered validation flight: nrmse 3.69 against 0.07, nothing said).
    ``only_validation``: say it only of a validation flight (the diagnosis says the estimation
    flights' own as its verdict's reason). Then the airframe's spin directions, judged on
    every flight at once (:func:`~greybox.diagnosis.analysis.spins_opposed`)."""
    from .diagnosis.analysis import check_spins, flights_rotor_geometry, rotor_geometry_warnings
    from .data import flight_label
    logs, validation = list(logs), list(validation)
    every = logs + validation
    flight, order, turned = flights_rotor_geometry(model, every)
    validating = flight in {flight_label(v, len(logs) + k) for k, v in enumerate(validation)}
    if only_validation and not validating:
        flight, order, turned = None, None, None
    # a validation flight is predicted, not fitted with the others: named, without the words
    # on a joint fit's moments
    words = rotor_geometry_warnings(model, order, turned, flight=None if validating else flight)
    where = (f"{flight} (judged alone; the other flights as given): " if validating else
             "" if flight is not None or len(every) > 1 or not every[0].source else f"{every[0].source}: ")
    if words:
        raise GreyboxInputError(where + words[0])
    # the spins are the airframe's, the same for every flight: judged on them all at once
    check_spins(model, every)


def _time_window(args: argparse.Namespace) -> tuple[float | None, float | None] | None:
    """``--time T0:T1`` read before any work, or None."""
    from .data import parse_time_window
    return parse_time_window(args.time) if getattr(args, "time", None) else None


def _load_model_log(model: QuadrotorModel, path: str, p0: np.ndarray, input_noise: str = "smooth",
                    outliers: str = "drop", held: str = "hold",
                    window: tuple[float | None, float | None] | None = None):
    """A rotor-speed log checked against ``model``'s rotors (and their plausible speeds with
    parameters ``p0``) and ready to fit; the speeds' noise that the vehicle does not follow
    taken out unless ``input_noise`` is ``"keep"``, the pose's glitches unless ``outliers`` is,
    held speeds interpolated between their fresh rows where ``held`` is ``"interpolate"``; only
    the rows within ``window`` (``--time``: :meth:`~greybox.data.FlightLog.between`)."""
    from .data import load_log
    log = load_log(path, inputs="rotor_speeds")
    if window is not None:
        log = log.between(*window, where=path)
    log = model_log(model, log, p0, path, input_noise, outliers, held)
    for note in log.notes:
        print(f"note: {note}", file=sys.stderr)
    return log


def _names(text: str | None) -> list[str] | None:
    return [s.strip() for s in text.split(",") if s.strip()] if text else None


def _parameter_names(model: QuadrotorModel, text: str | None, option: str) -> list[str] | None:
    """``--free``/``--fixed``: the names, each a parameter (or component) of ``model``,
    checked before any work."""
    names = _names(text)
    check_parameter_names(model, names or (), option)
    return names


def _finish_import(args: argparse.Namespace, imp, toml: str | None) -> int:
    """What every importer does with its result: notes on stderr, the log and (if asked)
    the airframe written, one summary line."""
    if toml is not None:
        # the airframe it writes is checked as every command will read it, before anything is
        # written (a blind audit's --mass 31 wrote a 31-kg Crazyflie that every later command refused)
        import tomllib
        from .airframe import airframe_from_dict
        airframe_from_dict(tomllib.loads(toml), f"{args.airframe_out} (from --mass {args.mass:g})")
    for note in imp.notes:
        print(f"note: {note}", file=sys.stderr)
    save_log(imp.log, args.out, digits=15)
    if toml is not None:
        atomic_write(args.airframe_out, toml)
    if args.json:
        write_json(args.json, {"format": imp.format, "log": args.out, "airframe": args.airframe_out if toml else None,
                               **_log_json(imp.log), "takeoff_time": _num_or_none(imp.takeoff_time),
                               "touchdown_time": _num_or_none(imp.touchdown_time),
                               "rest_height": _num_or_none(imp.rest_height),
                               "hover_rotor_speed": _num_or_none(imp.hover_rotor_speed),
                               "pwm_map": list(imp.pwm_map) if imp.pwm_map else None, "n_rotors": imp.n_rotors,
                               "notes": list(imp.notes)})
    print(f"wrote {args.out}: {len(imp.log)} samples, {imp.log.duration:.2f} s"
          + (f"; airframe {args.airframe_out}" if toml else ""))
    return 0


def _log_json(log: FlightLog) -> dict:
    """What a written flight log holds, for a command's JSON: rows, duration, columns."""
    return {"samples": len(log), "duration_s": float(log.duration), "inputs": list(log.input_names),
            "outputs": [n for n in log.output_names if log.measures(n)], "extras": list(log.extras)}


def cmd_split(args: argparse.Namespace) -> int:
    from .data import split_flips
    cut = split_flips(args.log, margin=args.margin, min_length=args.min_length)
    t = cut.t
    if not cut.passages:
        print(f"{args.log}: no flip (the pitch stays within +-{np.degrees(FLIP_PITCH):.0f} degrees, roll and yaw "
              "never jump together): nothing to split, nothing written")
        return 0
    if not cut.pieces:
        raise GreyboxInputError(f"{args.log}: {len(cut.passages)} flip(s), and no piece between them lasts "
                                f"{args.min_length:g} s (--min-length): nothing to fit")
    stem = Path(args.log).stem
    out = Path(args.split_out)
    names = [out / f"{stem}_{k + 1}.csv" for k in range(len(cut.pieces))]
    write_outputs([(n, text) for n, (_, _, text) in zip(names, cut.pieces)])
    print(f"{args.log}: {len(cut.passages)} flip(s) cut (" + ", ".join(
        f"t {t[a]:.2f}-{t[b - 1]:.2f} s" for a, b in cut.passages) + f", {args.margin:g} s spare on each side)")
    for n, (a, b, _) in zip(names, cut.pieces):
        print(f"  {n}: t {t[a]:.2f}-{t[b - 1]:.2f} s, {b - a} rows")
    if cut.dropped:
        print("  left out, shorter than --min-length: " + ", ".join(f"t {t[a]:.2f}-{t[b - 1]:.2f} s"
                                                                     for a, b in cut.dropped))
    print(f"fit them together: greybox fit {out / (stem + '_*.csv')} --airframe A.toml (several flights: shared "
          "parameters, each its own states; give validation flights split alike with --validation)")
    return 0


def cmd_import_nanobench(args: argparse.Namespace) -> int:
    from .io.base import parse_pwm_map
    from .importers import crazyflie_airframe_toml, import_nanobench
    imp = import_nanobench(args.file, pwm_map=parse_pwm_map(args.pwm_map), held=args.held,
                           keep_ground=args.keep_ground, angle_unit=args.angle_unit)
    toml = None
    if args.airframe_out:
        # floor plane: rotors assumed 2.5 cm above the floor when resting (tracked origin at rest height)
        toml = crazyflie_airframe_toml(args.mass, imp.hover_rotor_speed, ground_z=-(imp.rest_height - 0.025))
    return _finish_import(args, imp, toml)


def cmd_import_px4(args: argparse.Namespace) -> int:
    """PX4 ULog -> flight log (greybox.io.px4); --airframe-out needs --mass (not in the log)."""
    from .io.base import PX4_PWM_MAP, parse_pwm_map
    from .io.px4 import import_px4, px4_airframe_toml
    pwm_map = parse_pwm_map(args.pwm_map) if args.pwm_map else PX4_PWM_MAP
    if args.airframe_out and args.mass is None:
        raise GreyboxInputError("--airframe-out needs --mass: a PX4 log does not hold the vehicle's mass")
    imp = import_px4(args.file, pwm_map=pwm_map, held=args.held, keep_ground=args.keep_ground,
                     takeoff_height=args.takeoff_height)
    toml = None
    if args.airframe_out:
        if imp.n_rotors != 4:
            raise GreyboxInputError(f"{args.file}: --airframe-out writes a quadrotor X; this vehicle has "
                                    f"{imp.n_rotors} motors: write its [[rotor]] tables yourself")
        ground_z = -(imp.rest_height - 0.10) if np.isfinite(imp.rest_height) else 0.0
        toml = px4_airframe_toml(args.mass, imp.hover_rotor_speed, args.arm_length, ground_z,
                                 imp.pwm_map or pwm_map)
    return _finish_import(args, imp, toml)


def cmd_import_crazyflie_usd(args: argparse.Namespace) -> int:
    """Crazyflie uSD binary log -> flight log (greybox.io.crazyflie_usd)."""
    from .io.base import parse_pwm_map
    from .io.crazyflie_usd import import_crazyflie_usd
    from .io.nanobench import crazyflie_airframe_toml
    imp = import_crazyflie_usd(args.file, pwm_map=parse_pwm_map(args.pwm_map), held=args.held,
                               keep_ground=args.keep_ground, strict=not args.ignore_crc)
    toml = None
    if args.airframe_out:
        ground_z = -(imp.rest_height - 0.025) if np.isfinite(imp.rest_height) else 0.0
        toml = crazyflie_airframe_toml(args.mass, imp.hover_rotor_speed, ground_z=ground_z, command="crazyflie-usd")
    return _finish_import(args, imp, toml)


def _rig(path: str):
    from .vision import load_rig
    return load_rig(path)


def cmd_vision(args: argparse.Namespace) -> int:
    """Positions and yaw from camera frames of a ground marker (through the rig's mirror)."""
    from .vision import MarkerTracker, read_frames, save_positions
    rig = _rig(args.camera)
    tracker = MarkerTracker(rig, max_reprojection_px=args.max_reprojection, max_speed=args.max_speed,
                            tilt_sigma=args.tilt_sigma, corner_sigma_px=args.corner_sigma)
    attitude = None
    if args.imu:
        # t, phi, theta (psi optional): an attitude-only log will do, rotor speeds are not needed
        from .vision import imu_attitude
        attitude = imu_attitude(args.imu)
    frames, n = read_frames(args.frames, timestamps=args.timestamps, fps=args.fps, t0=args.t0)
    res = tracker.run(frames, attitude=attitude, progress=not args.quiet and sys.stderr.isatty(), n_frames=n)
    if len(res.t) == 0:
        raise GreyboxInputError(f"{args.frames}: no frame gave a position ({res.summary()}); "
                                f"is the marker in view, and is {args.camera} the right camera file?")
    save_positions(res, args.out)
    print(f"{res.summary()} -> {args.out}", file=sys.stderr)
    if args.json:
        write_json(args.json, {"frames": args.frames, "out": args.out, **res.to_json()})
    return 0


def cmd_merge(args: argparse.Namespace) -> int:
    """Join vision positions with an IMU / rotor-speed log into one multi-rate flight log."""
    from .data import load_log
    from .vision import load_positions, merge_vision
    log = load_log(args.log, optional=("x", "y", "z", "psi"))
    t, vals, names = load_positions(args.vision)
    merged = merge_vision(log, t, vals, names, offset=args.offset, psi=args.psi)
    for note in merged.notes[len(log.notes):]:
        print(f"note: {note}", file=sys.stderr)
    save_log(merged, args.out)
    if args.json:
        write_json(args.json, {"log": args.out, **_log_json(merged), "rows_from_log": len(log),
                               "notes": merged.notes[len(log.notes):]})
    print(f"wrote {args.out}: {len(merged)} rows ({len(log)} from {args.log})", file=sys.stderr)
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    """Synthetic camera frames of the rig's markers along a flight log's trajectory."""
    from .data import load_log
    from .synthcam import SyntheticCamera, trajectory_pose, write_sequence
    rig = _rig(args.camera)
    log = load_log(args.log)
    Y = np.column_stack([log.output(n) for n in ("x", "y", "z", "phi", "theta", "psi")])
    ok = ~np.isnan(Y).any(axis=1)
    if ok.sum() < 2:
        raise GreyboxInputError(f"{args.log}: fewer than two rows with all of x,y,z,phi,theta,psi to render from")
    if not args.fps > 0:
        raise GreyboxInputError(f"--fps must be positive, got {args.fps}")
    pose = trajectory_pose(log.t[ok], Y[ok, :3], Y[ok, 3:])
    times = np.arange(log.t[ok][0], log.t[ok][-1], 1.0 / args.fps)
    cam = SyntheticCamera(rig, corner_noise_px=args.corner_noise, pixel_noise=args.pixel_noise,
                          exposure_time=args.exposure_time, rolling_shutter=args.rolling_shutter,
                          seed=args.seed)
    n = write_sequence(cam.frames(pose, times), args.out_dir)
    if args.json:
        write_json(args.json, {"out_dir": args.out_dir, "frames": n, "fps": float(args.fps),
                               "t_start": float(times[0]) if n else None, "t_end": float(times[-1]) if n else None,
                               "seed": args.seed})
    print(f"rendered {n} frames at {args.fps:g} fps -> {args.out_dir} (timestamps.csv, truth.csv)", file=sys.stderr)
    return 0


NOISE_HELP = ("a channel's noise standard deviation, in its units, taken instead of the one estimated from the "
              "log's high-frequency content, e.g. --noise phi=0.01 for an attitude from an onboard filter, "
              "whose slow error that content does not show (repeatable)")


def _channel_noise(items: Sequence[str] | None) -> dict[str, float] | None:
    """``--noise CH=SD`` (repeatable) as :func:`greybox.fitting.fit`'s ``noise``: each a log
    channel and its noise standard deviation in the channel's units
    (:func:`greybox.data.check_channel_noise`)."""
    from .data import check_channel_noise
    if not items:
        return None
    given: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise GreyboxInputError(f"--noise {item}: expected CHANNEL=SD")
        given[name.strip()] = value
    return check_channel_noise(given, "--noise")


def _process_noise(args) -> str | None:
    """``--process-noise`` as :func:`greybox.fitting.fit` takes it ('none': None)."""
    return None if args.process_noise == "none" else args.process_noise


def _per_flight(text: str | None, model: QuadrotorModel | None = None) -> str | list[str] | None:
    """``--per-flight``: 'auto' (default), 'none' or a comma list of effects / parameters of
    ``model``, checked against it (when given) before any fitting starts."""
    from .fitting import per_flight_positions
    if text is None or text == "auto":
        return "auto"
    if text == "none":
        return None
    names = _names(text)
    if model is not None:
        per_flight_positions(model, model.param_names, names, option="--per-flight")
    return names


def _fit_imu_only(args: argparse.Namespace, model: QuadrotorModel, logs) -> int:
    """``greybox fit`` on a log with gyro and accelerometer but no position: the
    equation-error identification of :mod:`greybox.fitting.imu`."""
    from .fitting.imu import fit_imu, is_imu_only
    if len(logs) > 1:
        imu = next(log for log in logs if is_imu_only(log))
        raise GreyboxInputError(f"{imu.source}: an IMU-only log (gyro and accelerometer, no position) is "
                                "fitted on its own; give one log")
    # what the equation-error fit does not take: refused, never silently dropped
    unused = [option for option, given in (
        ("--effects", args.effects), ("--without", args.without), ("--set", args.set), ("--free", args.free),
        ("--fixed", args.fixed), ("--save", args.save), ("--plots", args.plots), ("--interval", args.interval),
        ("--per-flight", args.per_flight not in (None, "auto")), ("--noise", args.noise), *(
            (f"--{name.replace('_', '-')}", getattr(args, name) != default) for name, default in FIT_DEFAULTS.items())
    ) if given]
    if unused:
        raise GreyboxInputError(f"{logs[0].source}: an IMU-only log (gyro and accelerometer, no position) is fitted by "
                                f"its own equations (K_T, b, the motor lag, the torque gains; README, \"Fitting an "
                                f"IMU-only log\"), which take none of {', '.join(unused)}: leave "
                                f"{'it' if len(unused) == 1 else 'them'} out")
    if getattr(args, "model", None):
        print(f"note: {args.model}: the IMU-only fit takes the saved model's airframe; its effects and fitted "
              "values are not used (it fits K_T, b, the motor lag and the torque gains afresh)", file=sys.stderr)
    res = fit_imu(model, logs[0])
    print(res.summary())
    out = res.as_dict()
    if args.json:
        write_outputs([(Path(args.json), _json_text(out))])
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    from .fitting import fit
    from .fitting.imu import is_imu_only
    from . import plotting
    from .controller_law import closed_loop_or_why
    from .validation import (check_validation_length, horizon_errors_after, mean_value_words, predict,
                             prediction_options, validation_vectors)
    model, p0, logs = _load_fit_inputs(args)
    free, fixed = _parameter_names(model, args.free, "--free"), _parameter_names(model, args.fixed, "--fixed")
    if any(is_imu_only(log) for log in logs):
        if args.validation:
            raise GreyboxInputError("--validation: a log without positions is fitted with its own validation "
                                    "(the IMU's channels), not a separate flight's")
        return _fit_imu_only(args, model, logs)
    if args.validation:
        # separate flights validate: all of each LOG is estimation data (as diagnose's)
        vals = [_load_model_log(model, path, p0, args.input_noise, args.outliers, args.held)
                for path in args.validation]
        _check_rotor_geometry(model, logs, vals)
        # an estimation flight given as validation too reads its in-sample error as validation
        # (a blind audit's; diagnose refused it)
        check_distinct_flights(logs + vals, "estimation and validation flights")
        parts = [(log, None) for log in logs]
    else:
        # on the rows the fit is to see (each flight's first 80 %)
        _check_rotor_geometry(model, [log.split(0.8)[0] for log in logs])
        parts = [log.split(0.8) for log in logs]
        vals = [val for _, val in parts]
    for val in vals:
        # each validation flight (or each flight's last 20 %): too short for it is said before the fit runs
        check_validation_length(val)
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", ConvergenceWarning)   # said below, once, as the error
        # several flights: shared parameters, each flight its own states
        res = fit(model, [est for est, _ in parts], free=free, fixed=fixed, p0=p0,
                  interval=args.interval, max_iter=args.max_iter, progress=not args.quiet,
                  process_noise=_process_noise(args), per_flight=_per_flight(args.per_flight, model),
                  noise=_channel_noise(args.noise))
    # what the fitter cannot check itself (the rotor columns, the log's own moments and timing,
    # the moment scale): the reasons in its error when it failed, else before its own warnings
    from .diagnosis.fit_checks import fit_warnings
    checks = fit_warnings(res, [est for est, _ in parts])
    if not res.converged:
        # what to do next (a blind audit's slung payload: two failures, and nothing said)
        raise GreyboxError(f"fit did not converge: {'; '.join(checks + [res.status])}. A model that misses something "
                           "large may not settle: `greybox diagnose` with the same log says what it lacks; "
                           f"--max-iter raises the iterations of each solve (now {args.max_iter})")
    res.warnings[:0] = checks
    # each flight's tail validated with its own values of the per-flight parameters (wind,
    # battery sag); a separate flight with their mean (its wind was never seen)
    est = [e for e, _ in parts]
    val_ps = validation_vectors(res, est, vals)
    res.warnings += mean_value_words(res, est, vals)
    preds = [predict(model, p, val, horizon=args.horizon, **prediction_options(res)) for p, val in zip(val_ps, vals)]
    print(res.summary())
    for val, pred in zip(vals, preds):
        where = (val.source or "validation flight") if args.validation else \
            ("last 20 %" + (f" of {val.source}" if len(logs) > 1 else ""))
        print(f"validation ({pred.horizon_label}, {where}): nrmse {pred.total:.4f}  " +
              "  ".join(f"{c}={v:.3f}" for c, v in pred.nrmse.items()))
        above = pred.above_spread_words()
        if above:
            print(f"  note: {above}")
    # the error-against-horizon report predicts the validation part again from many starts:
    # only when a file shows it
    he = horizon_errors_after(res, preds, val_ps, est=est) if args.json or args.plots else None
    if len(preds) > 1:
        print(f"validation, mean over {len(preds)} flights: nrmse {float(np.mean([pr.total for pr in preds])):.4f}")
    # the model flown by its controller's law, where the logs carry setpoints (controller_law):
    # like the horizon report, only when a file shows it
    closed = None
    if args.json or args.plots:
        closed, why = closed_loop_or_why(model, val_ps, est, vals, horizons=he.horizons, open_loop=he,
                                         est_ps=[res.flight_p(i) for i in range(len(est))])
        if why:
            print(f"greybox: warning: {why}", file=sys.stderr)
        if closed is not None:
            print(closed.line().strip())
    # everything is computed before the first file is written, and the files go together
    # (an interrupt while they are written removes the ones already there)
    outputs: list[tuple[Path, str | bytes]] = []
    if args.plots:
        out = Path(args.plots)
        for k, pred in enumerate(preds):
            suffix = f"_{k + 1}" if len(preds) > 1 else ""
            outputs.append((out / f"compare{suffix}.png", plotting.to_bytes(plotting.compare(pred))))
            outputs.append((out / f"residuals{suffix}.png", plotting.to_bytes(plotting.residuals(pred))))
        outputs.append((out / "horizons.png", plotting.to_bytes(plotting.horizons(
            he, closed_loop=closed.horizons if closed is not None else None))))
    if args.json:
        result = fit_json(model, res, preds, [val.source for val in vals] if args.validation else
                          [log.source for log in logs], horizons=he, closed_loop=closed, ps=val_ps)
        result["log_notes"] = _log_notes(logs)
        outputs.append((Path(args.json), _json_text(result)))
    if args.save:
        outputs.append((Path(args.save), _json_text(res.to_dict())))
    write_outputs(outputs)
    if args.plots:
        print(f"plots: {args.plots}")
    if args.save:
        print(f"model: {args.save}")
    return 0


def _log_notes(logs) -> list[str]:
    """What was remarked while reading the logs (ignored columns, smoothed speeds), for the JSON."""
    return [note for log in logs for note in log.notes]


def _json_text(obj: object) -> str:
    return json.dumps(obj, indent=2, allow_nan=False) + "\n"


def write_outputs(outputs: Sequence[tuple[Path, str | bytes]]) -> None:
    """Write a command's files together, each atomically: if the run is interrupted (or a
    write fails) before the last is in place, the ones already written are removed, so an
    interrupted command leaves no output."""
    written: list[Path] = []
    try:
        for path, data in outputs:
            if signal_received() is not None:
                raise KeyboardInterrupt
            atomic_write(path, data)
            written.append(path)
        if signal_received() is not None:
            raise KeyboardInterrupt
    except BaseException:
        for path in written:
            try:
                path.unlink()
            except OSError:
                pass
        raise


def _compare_start(options: dict, args: argparse.Namespace) -> dict:
    """A model's prediction options for ``compare``: its own (``options``: as fitted), with
    ``--init-window`` and ``--measured-start`` replacing them where given."""
    out = dict(options)
    if args.init_window is not None:
        out["init_window"] = args.init_window
    if args.measured_start is not None:
        out.pop("measured_start", None)
        if args.measured_start == "yes":
            out["measured_start"] = True
    return out


def _start_words(options: dict) -> str:
    """How a prediction's windows start: the state-estimation window and whether the measured
    attitude and rates replace the estimate's, e.g. ``0.2 s, measured``."""
    words = f"{options.get('init_window', DEFAULT_INIT_WINDOW):g} s"
    return words + (", measured" if options.get("measured_start") else "")


def cmd_compare(args: argparse.Namespace) -> int:
    """MATLAB's ``compare``: each model's k-step-ahead prediction of the logs, side by side
    (nrmse per channel, lower is better), the measured and predicted signals in plots."""
    from . import plotting
    from .fitted import load
    from .validation import check_validation_length, predict_flights, prediction_options
    if not args.model and not args.airframe:
        raise GreyboxInputError("compare needs models: --model M.json [M2.json ...] and/or --airframe A.toml")
    if not args.airframe and (args.effects or args.without or args.set):
        raise GreyboxInputError("--effects, --without and --set apply to --airframe's model; a saved model "
                                "(--model) is compared as fitted")
    window = _time_window(args)
    entries = []          # (label, model, parameter vector, prediction options)
    if args.airframe:
        model = build_model(args.airframe, args.effects, args.without)
        entries.append((f"{Path(args.airframe).name} (its parameters)", model, _parameters(model, {}, args.set), {}))
    for path in args.model or []:
        fm = load(path)
        entries.append((Path(path).name, fm.model, fm.p, prediction_options(fm)))
    # each file read once; prepared for each model (its rotors checked), its notes said once
    from .data import load_log
    raw = [load_log(path, inputs="rotor_speeds") for path in args.log]
    if window is not None:
        raw = [log.between(*window, where=path) for log, path in zip(raw, args.log)]
    entries = [(label, model, p, _compare_start(options, args)) for label, model, p, options in entries]
    starts = [_start_words(options) for *_, options in entries]
    if len(set(starts)) > 1:
        # each saved fit chose its start on its own estimation flight: the table then also
        # measures how each start suits this flight (a blind audit's model with the truth's
        # parameters within 2.3 % read 26 % worse than the truth's for its measured start)
        print("note: the models start their predictions differently (" + ", ".join(
            f"{label}: {words}" for (label, *_), words in zip(entries, starts)) + "), so their nrmse differ by "
              "that too; --init-window S and --measured-start yes|no give them one start", file=sys.stderr)
    preds = []
    for k, (label, model, p, options) in enumerate(entries):
        logs = [model_log(model, log, p, path, held=args.held) for log, path in zip(raw, args.log)]
        _check_rotor_geometry(model, logs)
        for log in logs:
            if k == 0:
                for note in log.notes:
                    print(f"note: {note}", file=sys.stderr)
            check_validation_length(log)
        preds.append(predict_flights(model, p, logs, horizon=args.horizon, **options))
    channels = list(preds[0].nrmse)
    width = max(len(label) for label, *_ in entries)
    print(f"{preds[0].horizon_label} prediction of {', '.join(args.log)}: nrmse (lower is better)")
    swidth = max(len("start"), *map(len, starts))
    print(f"{'model':<{width}}  {'start':<{swidth}}  {'total':>7}  " + "  ".join(f"{c:>7}" for c in channels))
    for (label, *_), words, pred in zip(entries, starts, preds):
        print(f"{label:<{width}}  {words:<{swidth}}  {pred.total:7.4f}  "
              + "  ".join(f"{pred.nrmse.get(c, float('nan')):7.4f}" for c in channels))
    outputs: list[tuple[Path, str | bytes]] = []
    if args.plots:
        labels = [label for label, *_ in entries]
        flights = [getattr(pr, "parts", None) or [pr] for pr in preds]
        for k in range(len(args.log)):
            suffix = f"_{k + 1}" if len(args.log) > 1 else ""
            fig = plotting.compare([parts[k] for parts in flights], labels=labels)
            outputs.append((Path(args.plots) / f"compare{suffix}.png", plotting.to_bytes(fig)))
    if args.json:
        doc = {"logs": list(args.log), "horizon": preds[0].horizon,
               "models": [{"name": label, "effects": model.effect_names, "nrmse": pred.total,
                           "channels": dict(pred.nrmse),
                           "init_window": options.get("init_window", DEFAULT_INIT_WINDOW),
                           "measured_start": bool(options.get("measured_start", False))}
                          for (label, model, _, options), pred in zip(entries, preds)]}
        outputs.append((Path(args.json), _json_text(doc)))
    write_outputs(outputs)
    if args.plots:
        print(f"plots: {args.plots}")
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    from .diagnosis import diagnose
    model, p0, logs = _load_fit_inputs(args)
    fixed = _parameter_names(model, args.fixed, "--fixed")
    per_flight = _per_flight(args.per_flight, model)
    validation = [_load_model_log(model, v, p0, args.input_noise, args.outliers, args.held) for v in args.validation] \
        if args.validation else None
    # columns in another order said here only of a validation flight (the estimation flights'
    # is the verdict's reason); spins given the wrong way round of any, before any fit
    _check_rotor_geometry(model, logs, validation or (), only_validation=True)
    diag = diagnose(model, logs, candidates=_names(args.candidates), iterate=not args.no_iterate,
                    p0=p0, progress=not args.quiet,
                    process_noise=_process_noise(args), validation=validation,
                    discover=not args.no_discover or bool(args.write_effect), per_flight=per_flight,
                    horizon=args.horizon, noise=_channel_noise(args.noise), fixed=fixed)
    print(diag.summary())
    outputs: list[tuple[Path, str | bytes]] = []
    if args.json:
        doc = {**diag.as_json(), "log_notes": _log_notes(logs + (validation or []))}
        outputs.append((Path(args.json), _json_text(doc)))
    if args.write_effect:
        text = diag.discoveries_file(f"Found on {', '.join(str(x) for x in args.log)}:")
        if text is None:
            print(f"--write-effect: nothing significant was discovered; {args.write_effect} not written")
        else:
            outputs.append((Path(args.write_effect), text))
    if args.save:
        outputs.append((Path(args.save), _json_text(diag.fitted_model.to_dict())))
    if args.report:
        print(f"report: {diag.report(args.report)}")
    write_outputs(outputs)
    if args.save:
        print(f"model: {args.save}")
    if args.write_effect and diag.significant_discoveries:
        names = ",".join(d.effect_class().name for d in diag.significant_discoveries)
        print(f"effect: {args.write_effect} (use it with --effects-file {args.write_effect} --effects {names})")
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    """Import, fit and diagnose every flight on Dask distributed (contract section 9)."""
    from .batch import batch
    if args.workers is not None and args.scheduler:
        raise GreyboxInputError("--workers and --scheduler exclude each other: the scheduler's workers do the work")
    res = batch(args.inputs, args.batch_out, airframe=args.airframe, model=args.model,
                import_format=args.import_format, pwm_map=args.pwm_map, held=args.held,
                angle_unit=args.angle_unit, effects=args.effects,
                without=args.without, sets=args.set, fixed=args.fixed, effects_files=args.effects_file or (),
                candidates=_names(args.candidates), iterate=not args.no_iterate, discover=not args.no_discover,
                process_noise=_process_noise(args), input_noise=args.input_noise, outliers=args.outliers,
                noise=_channel_noise(args.noise),
                workers=args.workers or 2, scheduler=args.scheduler, joint=args.joint,
                per_flight=_per_flight(args.per_flight), progress=not args.quiet)
    print(res.summary())
    if args.json:
        write_json(args.json, {"out": str(res.out), "counts": res.counts, "flights": res.records,
                               "fleet": res.fleet})
    return 0


def _batch_parser(sub) -> None:
    from .batch import FORMATS
    b = sub.add_parser("batch", help="fit and diagnose many flights on Dask distributed",
                       description="Import (if needed), fit and diagnose every flight on Dask distributed: a local "
                                   "cluster of --workers processes or a running scheduler. Per flight DIR/<flight>/ "
                                   "(fit.json, diagnose.json, model.json, report/); DIR/summary.csv and "
                                   "summary.json, one record per flight. A rerun skips flights whose inputs and "
                                   "options are unchanged. Needs pip install 'greybox[batch]'.")
    b.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="flight log files, folders (their *.csv; *.ulg for px4) or glob patterns")
    _model_args(b, "starting value (repeatable)")
    b.add_argument("--out", dest="batch_out", required=True, metavar="DIR", help="folder for the results")
    b.add_argument("--fixed", help="comma list of parameters to hold at their starting values (as for diagnose)")
    b.add_argument("--workers", type=_positive_int, help="local worker processes, one thread each (default 2)")
    b.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler (e.g. tcp://127.0.0.1:8786) instead of a local cluster")
    b.add_argument("--import", dest="import_format", choices=[f for f in FORMATS if f != "csv"],
                   help="read the inputs through an importer (default: greybox flight logs)")
    b.add_argument("--pwm-map", help="a,c of w[rad/s] = a*PWM + c for imported logs (default: the importer's)")
    b.add_argument("--held", choices=["interpolate", "hold"], default="interpolate",
                   help="held motor samples of imported logs: interpolate (default) or hold")
    b.add_argument("--angle-unit", choices=["auto", "rad", "deg"], default="auto",
                   help="NanoBench logs without the quaternion: the roll/pitch/yaw columns' unit (default: "
                        "read from each flight's motion)")
    b.add_argument("--candidates", help="comma list of candidate effects (default: every effect not in the model)")
    b.add_argument("--no-iterate", action="store_true", help="rank once; do not add effects and re-rank")
    b.add_argument("--no-discover", action="store_true",
                   help="skip the discovery of residual forces beyond the catalogue")
    b.add_argument("--joint", action="store_true",
                   help="also fit the shared parameters on all good flights at once and name the flights more "
                        "than 3 std from the fleet")
    _data_args(b, "with --joint, what each flight gets its own value of: 'auto' (default: wind and "
                  "thrust_drift when the model or a flight's diagnosis has them), 'none' or a comma list")
    b.add_argument("--quiet", action="store_true", help="no progress lines")
    b.add_argument("--json", help="write the records (and the fleet comparison) here")
    b.set_defaults(func=cmd_batch, import_format="csv")


def cmd_linearize(args: argparse.Namespace) -> int:
    from .linearize import hover_trim, linearize
    model, brought = model_from_args(args)
    p = _parameters(model, brought, args.set)
    at = [0.0, 0.0, None] if args.at is None else _floats(args.at, 3, "--at")
    x_t, u_t = hover_trim(model, p, position=at, psi=args.psi)
    lin = linearize(model, p, x_t, u_t)
    out = {"states": lin.state_names, "inputs": lin.input_names, "x_trim": x_t.tolist(),
           "u_trim": u_t.tolist(), "A": lin.A.tolist(), "B": lin.B.tolist(),
           "outputs": lin.output_names, "C": lin.C.tolist(), "D": lin.D.tolist(),
           "effects": model.effect_names, "parameters": model.parameter_dict(p)}
    print("hover trim: " + ", ".join(f"{n}={v:.6g}" for n, v in zip(lin.input_names, u_t)), file=sys.stderr)
    write_json(args.json, out)
    return 0


def _floats(text: str, n: int, opt: str) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise GreyboxInputError(f"{opt} {text!r}: expected {n} comma-separated numbers") from None
    if len(vals) != n:
        raise GreyboxInputError(f"{opt} needs {n} values, got {len(vals)}")
    if not all(np.isfinite(vals)):
        raise GreyboxInputError(f"{opt} {text!r}: every value must be a finite number")
    return vals


# ---------------------------------------------------------------------------- parser
def _effects_file_arg(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--effects-file", action="append", metavar="FILE.py",
                    help="a Python file defining effects of your own (Effect subclasses with a name): "
                         "usable like catalogue effects (repeatable)")


def _model_args(ap: argparse.ArgumentParser, set_help: str) -> None:
    """The options that choose a model: airframe or saved model, added and removed effects,
    parameter values."""
    which = ap.add_mutually_exclusive_group(required=True)
    which.add_argument("--airframe", help="airframe TOML")
    which.add_argument("--model", metavar="MODEL.json",
                       help="a fitted model saved by 'greybox fit --save' (structure and parameters), "
                            "instead of --airframe")
    _effects_file_arg(ap)
    ap.add_argument("--effects", help="comma list of effects to add to the base model")
    ap.add_argument("--without", help="comma list of effects to remove from the base model")
    ap.add_argument("--set", action="append", metavar="NAME=VALUE", help=set_help)


def _data_args(ap: argparse.ArgumentParser, per_flight_help: str, process_noise_default: str = "if_needed") -> None:
    """The options on how a fit treats the data (shared by fit, diagnose and batch): the
    shooting gaps, the rotor speeds' noise, outliers, channel noise, per-flight values."""
    ap.add_argument("--process-noise", choices=["if_needed", "auto", "none"], default=process_noise_default,
                    help="how the shooting gaps are treated: 'if_needed' (default) output error, then "
                         "process noise when output error cannot follow the data; 'auto' process noise "
                         "(real logs); 'none' output error only (see README)")
    ap.add_argument("--input-noise", choices=["smooth", "keep"], default="smooth", help=INPUT_NOISE_HELP)
    ap.add_argument("--outliers", choices=["drop", "keep"], default="drop", help=OUTLIERS_HELP)
    ap.add_argument("--noise", action="append", metavar="CH=SD", help=NOISE_HELP)
    ap.add_argument("--per-flight", metavar="auto|none|NAMES", help=per_flight_help)


TIME_HELP = ("only the rows with T0 <= t <= T1 of each LOG (seconds, the log's own times; either end may be "
             "left out: '20:', ':19.5'), e.g. the parts before and after a rotor changed in flight (not "
             "applied to --validation flights)")


def _time_arg(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--time", metavar="T0:T1", help=TIME_HELP)


def _import_args(ap: argparse.ArgumentParser, file_help: str) -> None:
    """The options the Crazyflie importers share (NanoBench, uSD)."""
    ap.add_argument("file", help=file_help)
    ap.add_argument("--out", required=True, help="flight log CSV to write")
    ap.add_argument("--airframe-out", help="also write a Crazyflie 2.1 airframe TOML here")
    ap.add_argument("--mass", type=_positive, default=0.030, help="vehicle mass for the airframe, kg (default 0.030)")
    ap.add_argument("--pwm-map", default="0.04076521,380.8359",
                    help="a,c of w[rad/s] = a*PWM + c (default: Förster 2015 Crazyflie map)")
    ap.add_argument("--held", choices=["interpolate", "hold"], default="interpolate",
                    help="held motor samples: interpolate between fresh ones (default) or keep as logged")
    ap.add_argument("--keep-ground", action="store_true", help="keep samples on the ground (flagged on_ground)")
    ap.add_argument("--json", help="write what was imported here (samples, columns, take-off, notes)")


def _parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="greybox", description="Grey-box system identification of quadrotors.")
    ap.add_argument("--version", action="version", version=f"greybox {__version__}")
    sub = ap.add_subparsers(dest="command", required=True, parser_class=_Parser)

    s = sub.add_parser("simulate", help="simulate the model open loop from rotor speeds",
                       description="Simulate the model open loop from the rotor speeds in an inputs CSV "
                                   "(columns t,w1..w4) and write a flight log of the noise-free outputs.")
    _model_args(s, "parameter value, e.g. K_T=2.4e-5 or Kd=0.2,0.2,0.3 (repeatable)")
    s.add_argument("--inputs", required=True, help="CSV with columns t,w1..wN (rad/s)")
    s.add_argument("--out", required=True, help="flight log CSV to write")
    s.add_argument("--x0", help="initial state x,y,z,phi,theta,psi,vx,vy,vz,p,q,r (default rest at origin)")
    s.add_argument("--integrator", choices=["rk4", "cvodes"], default="rk4",
                   help="rk4: fixed step <= 1 ms (default); cvodes: adaptive, tight tolerances")
    s.add_argument("--json", help="write a machine-readable summary here")
    s.set_defaults(func=cmd_simulate)

    y = sub.add_parser("synth", help="make a synthetic closed-loop flight log",
                       description="Fly the model (with hidden effects) closed loop through varied "
                                   "manoeuvres and log it with sensor noise, multi-rate vision and dropouts.")
    which = y.add_mutually_exclusive_group(required=True)
    which.add_argument("--airframe", help="airframe TOML")
    which.add_argument("--model", metavar="MODEL.json", help="a saved fitted model, instead of --airframe")
    y.add_argument("--out", required=True, help="flight log CSV to write")
    _effects_file_arg(y)
    y.add_argument("--effects", help="hidden effects to add (comma list); unset parameters take plausible magnitudes")
    y.add_argument("--without", help="effects to remove from the base model")
    y.add_argument("--set", action="append", metavar="NAME=VALUE", help="true parameter value (repeatable)")
    y.add_argument("--seed", type=_seed, default=0)
    y.add_argument("--duration", type=_positive, default=50.0, help="s (default 50)")
    y.add_argument("--rate", type=_positive, default=1000.0, help="log / IMU rate, Hz (default 1000)")
    y.add_argument("--vision-rate", type=_positive, default=60.0, help="position rate, Hz (default 60)")
    y.add_argument("--pos-noise", type=_non_negative, default=0.003, help="m (default 0.003)")
    y.add_argument("--att-noise", type=_non_negative, default=0.003, help="rad (default 0.003)")
    y.add_argument("--gyro-noise", type=_non_negative, default=0.005, help="rad/s; 0 leaves p,q,r out (default 0.005)")
    y.add_argument("--accel-noise", type=_non_negative, default=0.0,
                   help="m/s^2; > 0 logs the accelerometer ax,ay,az with this noise (default 0: not logged)")
    y.add_argument("--input-noise", type=_non_negative, default=0.0, help="rad/s on logged rotor speeds")
    y.add_argument("--dropout", type=_probability, default=0.05, help="probability of a missing vision frame")
    y.add_argument("--excitation", type=_non_negative, default=0.03, help="relative RMS rotor-speed excitation")
    y.add_argument("--altitude", type=_positive, default=1.0, help="hover height above ground, m")
    y.add_argument("--manoeuvres", default="hover,step_x,step_y,step_z,yaw,fast,ground",
                   help="comma list from hover,step_x,step_y,step_z,yaw,fast,ground,sprint")
    y.add_argument("--digits", type=_digits, default=17, help="significant digits in the CSV (default 17: exact)")
    y.add_argument("--json", help="write the truth (effects, parameters, seed) here")
    y.set_defaults(func=cmd_synth)

    f = sub.add_parser("fit", help="fit the model's parameters to a flight log",
                       description="Fit the free parameters by multiple-shooting least squares on the "
                                   "first 80 % of the log and validate on the last 20 % (or on separate flights: "
                                   "--validation).")
    f.add_argument("log", nargs="+", help="flight log CSV; several flights share the parameters, each has "
                                          "its own states (each is fitted on its first 80 %%, validated on the rest)")
    _model_args(f, "starting value (repeatable)")
    f.add_argument("--free", help="comma list of parameters to fit (default: all that are free by default)")
    f.add_argument("--fixed", help="comma list of parameters to hold at their starting values")
    f.add_argument("--interval", type=_positive_int, help="samples per shooting interval (default: nearest 50 ms)")
    f.add_argument("--max-iter", type=_positive_int, default=FIT_DEFAULTS["max_iter"],
                   help=f"Gauss-Newton iterations of each solve (default {FIT_DEFAULTS['max_iter']}); a fit may "
                        "solve several times (process noise or weights estimated again, a restart), each "
                        "with this limit")
    _data_args(f, "with several logs, what each flight gets its own value of: 'auto' (default: the "
                  "effects that belong to a flight, wind and thrust_drift), 'none' (all shared) or a "
                  "comma list of effects / parameters", process_noise_default=FIT_DEFAULTS["process_noise"])
    f.add_argument("--held", choices=["hold", "interpolate"], default="hold", help=HELD_HELP)
    _time_arg(f)
    f.add_argument("--validation", metavar="LOGV", nargs="+",
                   help="separate flight(s) to validate on (then all of each LOG is estimation data; default: the "
                        "last 20 %% of each LOG)")
    f.add_argument("--horizon", type=_positive, default=FIT_DEFAULTS["horizon"],
                   help=f"validation prediction horizon, s (default {FIT_DEFAULTS['horizon']:g})")
    f.add_argument("--plots", help="folder for compare/residual plots")
    f.add_argument("--quiet", action="store_true", help="no progress lines")
    f.add_argument("--json", help="write the result here")
    f.add_argument("--save", metavar="MODEL.json",
                   help="save the fitted model (structure, parameters, covariance) for --model and greybox.load")
    f.set_defaults(func=cmd_fit)

    c = sub.add_parser("compare", help="compare models' predictions of flight logs (MATLAB's compare)",
                       description="Predict each log k steps ahead with each model (saved fits, and/or an "
                                   "airframe's model with its parameters) and show their nrmse per channel "
                                   "side by side, lower is better; --plots draws them over the measurements.")
    c.add_argument("log", nargs="+", help="flight log CSV(s) to predict (pooled)")
    c.add_argument("--model", metavar="MODEL.json", nargs="+",
                   help="fitted models saved by 'greybox fit --save' or 'diagnose --save'")
    c.add_argument("--airframe", help="also an airframe's model with its [parameters] (and --effects, --set)")
    _effects_file_arg(c)
    c.add_argument("--effects", help="comma list of effects to add to the airframe's model")
    c.add_argument("--without", help="comma list of effects to remove from the airframe's model")
    c.add_argument("--set", action="append", metavar="NAME=VALUE", help="a parameter of the airframe's model")
    c.add_argument("--held", choices=["hold", "interpolate"], default="hold", help=HELD_HELP)
    _time_arg(c)
    c.add_argument("--horizon", type=_positive, default=FIT_DEFAULTS["horizon"],
                   help=f"prediction horizon, s (default {FIT_DEFAULTS['horizon']:g})")
    c.add_argument("--init-window", type=_positive, metavar="S",
                   help="one start window (s) for every model's predictions (default: each saved model's own, "
                        f"as fitted; an airframe's {DEFAULT_INIT_WINDOW:g} s)")
    c.add_argument("--measured-start", choices=["yes", "no"],
                   help="start every model's predictions from the measured attitude and rates (yes) or from "
                        "the estimate (no) (default: each saved model's own)")
    c.add_argument("--plots", help="folder for the compare plots (one per log)")
    c.add_argument("--json", help="write the comparison here")
    c.set_defaults(func=cmd_compare)

    g = sub.add_parser("diagnose", help="find where the model fails and which effect is missing",
                       description="Fit the model, show where it fails, try the catalogue's candidate effects "
                                   "and rank them; add the significant ones until nothing is missing.")
    g.add_argument("log", nargs="+", help="flight log CSV; several flights share the parameters, each has "
                                          "its own states")
    _model_args(g, "starting value (repeatable)")
    g.add_argument("--fixed", help="comma list of parameters to hold at their starting values in every fit "
                                   "(e.g. b measured on a bench: --set b=... --fixed b)")
    g.add_argument("--candidates", help="comma list of candidate effects (default: every effect not in the model)")
    g.add_argument("--no-iterate", action="store_true", help="rank once; do not add effects and re-rank")
    _data_args(g, "with several logs, what each flight gets its own value of (as for fit; default auto: "
                  "wind, thrust_drift)")
    g.add_argument("--held", choices=["hold", "interpolate"], default="hold", help=HELD_HELP)
    _time_arg(g)
    g.add_argument("--validation", metavar="LOGV", nargs="+",
                   help="separate flight(s) to validate on (then all of each LOG is estimation data; "
                        "default: the last 20 %% of each LOG)")
    g.add_argument("--horizon", type=_positive, default=1.0,
                   help="validation prediction horizon, s, which confirms a candidate out of sample (default 1; "
                        "0.5 for real flights, whose attitude is not predictable open loop for a second)")
    g.add_argument("--report", help="folder for the HTML report and its plots")
    g.add_argument("--quiet", action="store_true", help="no progress lines")
    g.add_argument("--json", help="write the result here")
    g.add_argument("--save", metavar="MODEL.json", help="save the final fitted model (with the effects added)")
    g.add_argument("--no-discover", action="store_true",
                   help="skip the discovery of residual forces beyond the catalogue")
    g.add_argument("--write-effect", metavar="FILE.py",
                   help="write the best significant discovered combination as an effects file "
                        "(for --effects-file)")
    g.set_defaults(func=cmd_diagnose)

    _batch_parser(sub)

    z = sub.add_parser("linearize", help="hover trim and continuous-time Jacobians",
                       description="Hover trim of the composed model and its continuous-time Jacobians "
                                   "A = df/dx, B = df/du (and C, D of the measurement map).")
    _model_args(z, "parameter value (repeatable)")
    z.add_argument("--at", help="hover position x,y,z (NED; default 0,0 and 1 m above the ground plane)")
    z.add_argument("--psi", type=_finite, default=0.0, help="hover heading, rad (default 0)")
    z.add_argument("--json", required=True, help="write the result here")
    z.set_defaults(func=cmd_linearize)

    i = sub.add_parser("import", help="convert another tool's log into a greybox flight log",
                       description="Convert a log of another format into a flight log (README: 'Flight log (CSV)').")
    isub = i.add_subparsers(dest="format", required=True, parser_class=_Parser)
    nb = isub.add_parser("nanobench", help="NanoBench Crazyflie 2.1 CSV (Vicon + onboard logs)",
                         description="Convert a NanoBench CSV: z-up world -> NED, FLU -> FRD, attitude from the "
                                     "quaternion, PWM -> rotor speed, held samples, ground contact trimmed, "
                                     "battery voltage as column vbat.")
    _import_args(nb, "NanoBench CSV")
    nb.add_argument("--angle-unit", choices=["auto", "rad", "deg"], default="auto",
                    help="unit of the roll/pitch/yaw columns, read only without the quaternion: 'auto' (default: "
                         "from the motion, a tilt accelerates the vehicle by about g times it), 'rad' or 'deg'")
    nb.set_defaults(func=cmd_import_nanobench)
    px = isub.add_parser("px4", help="PX4 ULog flight log (needs pyulog: pip install 'greybox[px4]')",
                         description="Convert a PX4 ULog: attitude, local position (NED), gyro and accelerometer "
                                     "(ax, ay, az), motor PWM -> rotor speed through w = a*PWM + c (or ESC RPM "
                                     "when logged), battery voltage as vbat; trimmed to the flight.")
    px.add_argument("file", help="PX4 log (.ulg)")
    px.add_argument("--out", required=True, help="flight log CSV to write")
    px.add_argument("--airframe-out", help="also write a quadrotor X airframe TOML here (needs --mass)")
    px.add_argument("--mass", type=_positive, help="vehicle mass, kg (not in the log; needed for --airframe-out)")
    px.add_argument("--arm-length", type=_positive, default=0.25,
                    help="centre-to-motor distance for the airframe, m (default 0.25, an assumption)")
    px.add_argument("--pwm-map", help="a,c of w[rad/s] = a*PWM[us] + c (default 1,-1000: an assumed map, "
                                      "1000 us stopped, 2000 us 1000 rad/s)")
    px.add_argument("--held", choices=["interpolate", "hold"], default="interpolate",
                    help="motor samples between log rows: interpolate (default) or hold")
    px.add_argument("--keep-ground", action="store_true",
                    help="keep samples on the ground (flagged on_ground); also imports a log that never flies")
    px.add_argument("--takeoff-height", type=_positive, default=0.2,
                    help="m above the resting height that counts as airborne (default 0.2)")
    px.add_argument("--json", help="write what was imported here (samples, columns, take-off, notes)")
    px.set_defaults(func=cmd_import_px4)
    cu = isub.add_parser("crazyflie-usd", help="Crazyflie uSD-card binary log (event-based, version 1/2)",
                         description="Convert a Crazyflie uSD log: gyro (deg/s, FLU) -> p,q,r (rad/s, FRD), "
                                     "accelerometer (g) -> ax, ay, az (m/s^2, FRD), motor PWM -> rotor speed; "
                                     "trimmed from motor start to motor stop (or the first impact).")
    _import_args(cu, "uSD log file (e.g. log00)")
    cu.add_argument("--ignore-crc", action="store_true",
                    help="read a truncated or corrupt file (CRC mismatch): keep its whole records")
    cu.set_defaults(func=cmd_import_crazyflie_usd)

    v = sub.add_parser("vision", help="body position and yaw from camera frames of a ground ArUco marker",
                       description="Detect the rig's ArUco markers in a folder of images or a video (through the "
                                   "mirror if the camera file has one), estimate the body pose and write t,x,y,z,psi "
                                   "(world NED). Bad frames are skipped and counted.")
    v.add_argument("frames", help="folder of images (sorted naturally) or a video file")
    v.add_argument("--camera", required=True, help="camera / mirror / marker TOML")
    v.add_argument("--out", required=True, help="positions CSV to write (t,x,y,z,psi)")
    v.add_argument("--timestamps", help="CSV with a column t, one row per frame")
    v.add_argument("--fps", type=_positive, help="frame rate, if no --timestamps (t = t0 + i/fps)")
    v.add_argument("--t0", type=_finite, default=0.0, help="time of the first frame with --fps (default 0)")
    v.add_argument("--max-reprojection", type=_positive, default=2.0, help="reject frames above this RMS, px (default 2)")
    v.add_argument("--max-speed", type=_positive, default=10.0, help="reject jumps faster than this, m/s (default 10)")
    v.add_argument("--imu", help="CSV with t,phi,theta (a flight log or an attitude-only log, same clock): its "
                                 "tilt refines each pose (IMU-aided: millimetres instead of centimetres "
                                 "laterally); frames outside its time span are vision-only, with a warning")
    v.add_argument("--tilt-sigma", type=_positive, default=0.01, help="IMU roll/pitch accuracy, rad (default 0.01)")
    v.add_argument("--corner-sigma", type=_positive, default=0.2, help="corner accuracy, px (default 0.2)")
    v.add_argument("--quiet", action="store_true", help="no progress lines")
    v.add_argument("--json")
    v.set_defaults(func=cmd_vision)

    mg = sub.add_parser("merge", help="join vision positions with an IMU / rotor-speed log",
                        description="Merge t,x,y,z[,psi] from `greybox vision` into a log with t,w1..wN and "
                                    "attitude: vision samples keep their own times (inputs held from the previous "
                                    "row), giving a multi-rate flight log (README: 'Flight log (CSV)').")
    mg.add_argument("log", help="IMU / rotor-speed CSV (t, w1..wN, phi, theta[, psi, p, q, r]; x,y,z may be absent)")
    mg.add_argument("--vision", required=True, help="positions CSV from `greybox vision`")
    mg.add_argument("--out", required=True, help="flight log CSV to write")
    mg.add_argument("--offset", type=_finite, default=0.0, help="seconds added to the vision times (clock offset)")
    mg.add_argument("--psi", choices=["auto", "imu", "vision"], default="auto",
                    help="where the yaw comes from (auto: the log's if it has any, else vision's)")
    mg.add_argument("--json", help="write what was merged here (rows, columns, notes)")
    mg.set_defaults(func=cmd_merge)

    rd = sub.add_parser("render", help="synthetic camera frames of the markers along a flight log",
                        description="Render what the rig's camera sees (through its mirror) along the "
                                    "trajectory of a flight log: PNG frames, timestamps.csv and truth.csv.")
    rd.add_argument("log", help="flight log with x,y,z,phi,theta,psi")
    rd.add_argument("--camera", required=True, help="camera / mirror / marker TOML")
    rd.add_argument("--out-dir", required=True, help="folder for the frames")
    rd.add_argument("--fps", type=_positive, default=60.0, help="frame rate (default 60)")
    rd.add_argument("--corner-noise", type=_non_negative, default=0.0, help="extra noise on the marker corner positions, px (default 0)")
    rd.add_argument("--pixel-noise", type=_non_negative, default=2.0, help="image noise, grey levels (default 2)")
    rd.add_argument("--exposure-time", type=_non_negative, default=0.0, help="motion blur exposure, s (default 0)")
    rd.add_argument("--rolling-shutter", type=_non_negative, default=0.0, help="row readout time, s (default 0)")
    rd.add_argument("--seed", type=_seed, default=0)
    rd.add_argument("--json", help="write what was rendered here (frames, times)")
    rd.set_defaults(func=cmd_render)

    sp = sub.add_parser("split", help="cut a flight log at its flips (the pitch through +-90 degrees) into pieces",
                        description="Write the pieces of LOG between its flips as LOG's own rows under its header "
                                    "(OUT/<stem>_1.csv, ...), to fit together: the attitude is ZYX Euler angles, "
                                    "singular at +-90 degrees of pitch, and a log with a flip is refused by the "
                                    "other commands.")
    sp.add_argument("log", help="flight log CSV")
    sp.add_argument("--out", dest="split_out", required=True, metavar="DIR", help="folder for the pieces")
    sp.add_argument("--margin", type=_non_negative, default=FLIP_MARGIN_S,
                    help=f"time cut on each side of a flip, s (default {FLIP_MARGIN_S:g})")
    sp.add_argument("--min-length", type=_positive, default=FLIP_MIN_PIECE_S,
                    help=f"shortest piece kept, s (default {FLIP_MIN_PIECE_S:g})")
    sp.set_defaults(func=cmd_split)

    e = sub.add_parser("effects", help="list every known effect: summary, parameters, units, null values",
                       description="List the catalogue's effects, the signal effects and those registered "
                                   "(--effects-file, greybox.effects.register, the 'greybox.effects' entry points).")
    _effects_file_arg(e)
    which = e.add_mutually_exclusive_group()
    which.add_argument("--airframe", help="airframe TOML for the parameters' defaults and bounds (default: the "
                                          "bundled paper airframe)")
    which.add_argument("--model", metavar="MODEL.json",
                       help="a saved fitted model instead: its airframe's defaults and bounds, and the fitted "
                            "values of its own effects' parameters")
    e.add_argument("--json", help="write the list here")
    e.set_defaults(func=cmd_effects)

    d = sub.add_parser("demo", help="the greybox story on bundled data",
                       description="Diagnose the seed paper's base model on a bundled flight log with a hidden "
                                   "effect: compare, where it fails, ranking, add, error falls; writes a report.")
    d.add_argument("--out-dir", default="greybox-demo", help="folder for the report (default greybox-demo)")
    d.add_argument("--quiet", action="store_true", help="no progress lines")
    d.add_argument("--json")
    d.set_defaults(func=cmd_demo)
    return ap


_USER_OS_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM}
"""OSErrors that are the machine's state, not greybox's fault, also without a file name."""


def _check_outputs_are_not_inputs(args: argparse.Namespace) -> None:
    """Refuse an output file that is also one of the command's inputs (any other option or
    argument naming an existing file): writing it would destroy the input."""
    outputs = {attr: getattr(args, attr) for attr, (_, kind) in OUTPUT_OPTIONS.items()
               if kind == "file" and getattr(args, attr, None) is not None}
    if not outputs:
        return
    inputs = []
    for attr, value in vars(args).items():
        if attr in OUTPUT_OPTIONS or attr == "func":
            continue
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(v, str) and v and os.path.isfile(v):
                inputs.append(v)
    seen: dict[str, str] = {}
    for attr, out in outputs.items():
        other = seen.setdefault(os.path.realpath(out), attr)
        if other != attr:
            raise GreyboxInputError(f"{OUTPUT_OPTIONS[attr][0]} {out}: is also {OUTPUT_OPTIONS[other][0]}'s file; "
                                    "each output needs its own")
        if not os.path.exists(out):
            continue
        for src in inputs:
            if os.path.samefile(out, src):
                raise GreyboxInputError(f"{OUTPUT_OPTIONS[attr][0]} {out}: is also an input of this command "
                                        f"({src}); writing it would overwrite that input: give another file name")


def _missing_folders(path: str) -> str | None:
    """The topmost folder above an output that does not exist, or None (a folder option's own
    folder is not counted: making it is what the option asks)."""
    top = None
    here = Path(os.path.abspath(path)).parent
    while not here.exists():
        top = here
        here = here.parent
    return None if top is None else str(top)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"greybox: warning: {message}", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    import signal
    ap = _parser()
    forget_signals()
    try:
        previous = signal.signal(signal.SIGTERM, raise_terminated)
        # Ctrl-C / kill -INT always interrupts, also when started in the background by a
        # shell script (which starts its background jobs with SIGINT ignored)
        previous_int = signal.signal(signal.SIGINT, raise_interrupted)
    except ValueError:          # not the main thread (e.g. called from a worker): no handler
        previous = previous_int = None
    try:
        args = ap.parse_args(argv)
        for attr, (option, kind) in OUTPUT_OPTIONS.items():
            if getattr(args, attr, None) is not None:
                check_output_path(getattr(args, attr), option, kind)
                missing = _missing_folders(getattr(args, attr))
                if missing is not None:
                    # made when the output is written; said, so that a mistyped path is seen
                    print(f"note: {option} {getattr(args, attr)}: folder {missing} does not exist yet; "
                          "it will be created", file=sys.stderr)
        _check_outputs_are_not_inputs(args)
        for path in getattr(args, "effects_file", None) or []:
            fx.load_effects_file(path)
        with _warnings.catch_warnings():
            # a warning reaches a CLI user as one line, not as Python's file:line form
            _warnings.showwarning = _show_warning
            status = int(args.func(args) or 0)
        swallowed = signal_received()
        if swallowed is not None:
            # an interrupt some callback swallowed ("Exception ignored in ..."): still one, and
            # still the signal it was (a SIGTERM swallowed while a compiler ran ended as
            # "interrupted", 130, instead of "terminated", 143)
            raise Terminated() if swallowed == signal.SIGTERM else KeyboardInterrupt()
        return status
    except GreyboxInputError as e:
        print(f"greybox: error: {e}", file=sys.stderr)
        return 2
    except GreyboxError as e:
        print(f"greybox: failed: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        status = interrupt_status(e)    # an interrupt first (a killed compiler's missing library)
        if status is not None:
            return status
        if e.filename is None and e.errno not in _USER_OS_ERRORS:
            raise                       # not a file the user named: a fault of ours, shown as one
        # a file that cannot be read or written (a name too long, a full disk, a permission)
        print(f"greybox: error: {e.filename + ': ' if e.filename else ''}{e.strerror or e}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Terminated, Exception) as e:
        status = interrupt_status(e)
        if status is None:
            raise
        return status
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
            signal.signal(signal.SIGINT, previous_int)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

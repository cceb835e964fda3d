"""What the command line and ``greybox batch`` share: models built from command options, logs
checked against a model, output paths probed before any work, and the fit JSON document
(README, "Command line"). Kept apart from :mod:`greybox.cli` so that the library's batch
runner does not import the command line."""
from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Sequence

import numpy as np

from . import effects as fx
from .airframe import load_airframe
from .data import ATOMIC_NAME_EXTRA, FlightLog, atomic_write
from .errors import GreyboxInputError
from .model import QuadrotorModel
from .outliers import drop_outliers

__all__ = ["check_output_path", "check_parameter_names", "write_json", "parse_sets", "build_model", "edit_model", "model_from_args",
           "fit_result_json", "model_log", "fit_json"]


def check_output_path(path: str | Path, option: str, kind: str = "file") -> None:
    """Raise a :class:`GreyboxInputError` naming ``option`` unless ``path`` can be written as a
    ``kind`` (``"file"`` or ``"folder"``): a file must not be a folder, a folder not a file,
    and the nearest existing folder above it must accept a new file (tried, not guessed)."""
    try:
        _check_writable(Path(path), str(path), option, kind)
    except OSError as e:        # a name the system refuses (too long, a bad character)
        raise GreyboxInputError(f"{option} {path}: {e.strerror or e}") from None


def _check_writable(p: Path, path: str, option: str, kind: str) -> None:
    import os
    import tempfile
    if kind == "file" and p.is_dir():
        raise GreyboxInputError(f"{option} {path}: is a folder; give a file name")
    if kind == "folder" and p.exists() and not p.is_dir():
        raise GreyboxInputError(f"{option} {path}: exists and is not a folder")
    if kind == "file" and str(path).endswith(("/", os.sep)):
        raise GreyboxInputError(f"{option} {path}: names a folder; give a file name")
    here = p if kind == "folder" else p.parent
    here = Path(os.path.abspath(here))
    while not here.exists():
        here = here.parent
    if not here.is_dir():
        raise GreyboxInputError(f"{option} {path}: {here} is a file, not a folder")
    if kind == "file":
        # the file is written through a temporary beside it, ATOMIC_NAME_EXTRA bytes longer (data.atomic_write)
        longest = len(os.fsencode(p.name)) + ATOMIC_NAME_EXTRA
        name_max = os.pathconf(here, "PC_NAME_MAX") if hasattr(os, "pathconf") else 255
        if longest > name_max:
            raise GreyboxInputError(f"{option} {path}: the file name is too long ({len(os.fsencode(p.name))} bytes; "
                                    f"at most {name_max - ATOMIC_NAME_EXTRA} here)")
    try:
        fd, probe = tempfile.mkstemp(prefix=".greybox-probe-", dir=here)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise GreyboxInputError(f"{option} {path}: cannot write in {here} ({e.strerror or e})") from None


def check_parameter_names(model: QuadrotorModel, names: Sequence[str], option: str) -> None:
    """Each of ``names`` a parameter (or component) of ``model``, else one error naming
    ``option`` (``--free``, ``--fixed``), before any work."""
    known = set(model.param_names) | {par.name for par in model.parameters}
    for n in names:
        if n not in known:
            raise GreyboxInputError(f"{option}: unknown parameter {n!r}; the model's parameters are "
                                    f"{', '.join(par.name for par in model.parameters)}")


def write_json(path: str | Path, obj: object) -> None:
    """Write ``obj`` as JSON atomically (NaN is not valid JSON: it is refused, not written)."""
    atomic_write(path, json.dumps(obj, indent=2, allow_nan=False) + "\n")


def parse_sets(items: Sequence[str] | None) -> dict[str, list[float]]:
    """``["K_T=2.4e-5", "Kd=0.2,0.2,0.3"]`` -> ``{"K_T": [2.4e-5], "Kd": [0.2, 0.2, 0.3]}``."""
    out: dict[str, list[float]] = {}
    for item in items or []:
        if "=" not in item:
            raise GreyboxInputError(f"--set {item!r}: expected NAME=VALUE")
        name, _, text = item.partition("=")
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            raise GreyboxInputError(f"--set {item!r}: {text!r} is not a number or a comma list") from None
        if not all(np.isfinite(vals)):
            raise GreyboxInputError(f"--set {item!r}: {text!r} is not a finite number")
        out[name.strip()] = vals
    return out


def build_model(airframe_path: str, effects: str | None = None, without: str | None = None,
                inputs: str = "rotor_speeds") -> QuadrotorModel:
    """The base model of an airframe file, plus ``effects``, minus ``without`` (comma lists)."""
    af = load_airframe(airframe_path)
    return edit_model(QuadrotorModel(af, inputs=inputs), effects, without)


def edit_model(model: QuadrotorModel, effects: str | None, without: str | None) -> QuadrotorModel:
    """``model`` plus the effects named in ``effects``, minus those in ``without`` (comma lists).

    Raises:
        GreyboxInputError: an effect named in both (a blind audit's ``--effects wind --without
            wind`` ran without wind, silently).
    """
    both = sorted(set(fx.parse_effect_names(effects)) & set(fx.parse_effect_names(without)))
    if both:
        raise GreyboxInputError(f"--effects and --without both name {', '.join(both)}: add it or remove it, "
                                "not both")
    for name in fx.parse_effect_names(effects):
        if name not in model.effects:
            model = model + fx.by_name(name)
    drop = fx.parse_effect_names(without)
    if drop:
        model = model.without(*drop)
    return model


def model_from_args(args: argparse.Namespace, effects: str | None = "from args") -> tuple[QuadrotorModel, dict]:
    """The model an ``--airframe A.toml`` or ``--model M.json`` option names, with
    ``--effects``/``--without`` applied, and the parameter values it brings (a saved model's
    fitted values; none for an airframe, whose ``[parameters]`` are the model's defaults)."""
    effects = getattr(args, "effects", None) if effects == "from args" else effects
    if getattr(args, "model", None):
        from .fitted import load
        fm = load(args.model)
        values = fm.parameters_
        model = edit_model(fm.model, effects, args.without)
        return model, {k: v for k, v in values.items() if k in model.param_names}
    return build_model(args.airframe, effects, args.without), {}


def fit_result_json(model: QuadrotorModel, res, validation: dict | None) -> dict:
    """The fit JSON (README, "Command line"), with extra detail (status, correlations, warnings)."""
    params = {}
    for name, v in res.parameters.items():
        std = v["std"]
        # fixed: std 0; free but not determined (non-positive variance): null, never NaN in JSON
        entry = {"value": v["value"], "std": 0.0 if std is None else (std if np.isfinite(std) else None)}
        if std is None:
            entry["fixed"] = True
        params[name] = entry
    out = {"parameters": params, "effects": model.effect_names}
    if validation is not None:
        out["validation"] = validation
    out.update({"converged": res.converged, "status": res.status, "iterations": res.iterations,
                "free": res.free_names, "correlation": res.correlation.tolist(),
                "noise": res.sigma, "residual_rms": res.residual_rms, "warnings": res.warnings,
                "certificate": res.certificate.as_dict() if res.certificate is not None else None,
                # the formulation it ended in: the process noise per state (null: output error)
                "process_noise": res.process_noise, "init_window": res.init_window,
                "measured_start": res.measured_start,
                "time_s": res.timings.get("total")})
    if getattr(res, "per_flight_", None):
        # parameters fitted per flight: "parameters" holds their mean over the flights
        out["per_flight"] = {n: {"value": v["value"],
                                 "std": [s if np.isfinite(s) else None for s in v["std"]]}
                             for n, v in res.per_flight_.items()}
    return out


def model_log(model: QuadrotorModel, log: FlightLog, p0: np.ndarray, where: str,
              input_noise: str = "smooth", outliers: str = "drop", held: str = "hold") -> FlightLog:
    """``log`` checked against ``model``'s rotors (and their plausible speeds with parameters
    ``p0``) and ready to fit; errors name ``where`` (also used by ``greybox batch``). The rows
    on the ground at its start and end, where it starts or ends with its rotors stopped, are
    left out with a note (:func:`~greybox.io.base.airborne_log`). Rotor
    speeds that are a slower signal held on the rows (:func:`~greybox.io.held_inputs`) are
    interpolated between their fresh rows with ``held="interpolate"``
    (:func:`~greybox.io.interpolate_held_inputs`) and fitted as logged with ``"hold"``, a note
    saying so either way. With
    ``input_noise="smooth"`` the white noise on the logged speeds that the vehicle does not
    follow is taken out (:func:`~greybox.fitting.input_errors.denoise_inputs`; a note on the
    log says so); ``"keep"`` leaves them as logged. With ``outliers="drop"`` the pose
    channels' isolated glitches are left out (:func:`~greybox.outliers.drop_outliers`,
    with a note); ``"keep"`` keeps them."""
    if log.input_names != model.command_names:
        raise GreyboxInputError(f"{where}: has rotor speeds {','.join(log.input_names)} but the airframe "
                                f"has {model.airframe.n_rotors} rotors")
    from .io.base import airborne_log
    log = airborne_log(log, where)
    model.check_rotor_speeds(log.inputs[:, :model.airframe.n_rotors], p0, where)
    log = _held_speeds(log, held)
    from .fitting.input_errors import combination_noise_words
    noisy = combination_noise_words(model, model.prepare_log(log), p0)
    if noisy:
        log = replace(log, notes=list(log.notes) + [noisy])
    if input_noise == "smooth":
        from .fitting.input_errors import denoise_inputs
        log, _ = denoise_inputs(model, log, p0)
    elif input_noise != "keep":
        raise GreyboxInputError(f"input noise: {input_noise!r} is neither 'smooth' nor 'keep'")
    if outliers == "drop":
        log = drop_outliers(log)
    elif outliers != "keep":
        raise GreyboxInputError(f"outliers: {outliers!r} is neither 'drop' nor 'keep'")
    log = model.prepare_log(log)
    from .fitting.imu import is_imu_only
    if not is_imu_only(log):      # an IMU-only log is fitted by its own equations, which check it
        log.check_fittable()
    return log


def _held_speeds(log: FlightLog, held: str) -> FlightLog:
    """``log`` with its held rotor speeds interpolated (``held="interpolate"``) or as logged
    with a note that they are held (``"hold"``)."""
    from .io.base import held_inputs, interpolate_held_inputs
    if held == "interpolate":
        return interpolate_held_inputs(log)
    if held != "hold":
        raise GreyboxInputError(f"held: {held!r} is neither 'hold' nor 'interpolate'")
    found = held_inputs(log)
    if found is None:
        return log
    note = (f"{found.text(', '.join(log.input_names))}: fitted as logged, each row holding its value; if they are "
            f"a sensor's samples held between readings (ESC telemetry), a held row is up to "
            f"{found.late_ms:.0f} ms late and a fitted effect may stand in for that: --held interpolate "
            "(held=\"interpolate\") interpolates them between the fresh rows")
    return replace(log, notes=list(log.notes) + [note])


def fit_json(model: QuadrotorModel, res, preds, sources, horizons=None, est=None, closed_loop=None,
             ps=None) -> dict:
    """The whole ``greybox fit --json`` document of a fit validated by ``preds`` (one
    prediction per flight, named by ``sources``): parameters, validation, the open loop's
    horizons (``horizons``, a :class:`~greybox.validation.HorizonErrors`, when already computed;
    else computed, with the fit's estimation flights ``est`` when given), the model flown by its
    controller's law (``closed_loop``, a :class:`~greybox.controller_law.ClosedLoopReport`, when
    already computed; else computed when ``est`` is given and the logs hold setpoints), the
    contract's ``horizons`` from the better of the two on the estimation flights
    (:func:`~greybox.controller_law.reported_horizons`) and the extra keys (also written by
    ``greybox batch``). ``ps``: the parameter vector each prediction was made with (default:
    each flight's own, the predictions being the estimation flights' tails)."""
    from .controller_law import closed_loop_or_why, reported_horizons
    from .validation import horizon_errors_after
    ps = [res.flight_p(i) for i in range(len(preds))] if ps is None else list(ps)
    if horizons is None:
        horizons = horizon_errors_after(res, preds, ps, est=est)
    out = fit_result_json(model, res, _combined_validation(preds, sources))
    if closed_loop is None and est is not None:
        closed_loop, why = closed_loop_or_why(model, ps, est, [pred.log for pred in preds], horizons=horizons.horizons,
                                              open_loop=horizons, est_ps=[res.flight_p(i) for i in range(len(est))])
        if why:
            out["warnings"] = list(out.get("warnings") or []) + [why]
    # the model's prediction: flown by its controller's law where that predicts the estimation
    # flights better (controller_law.reported_horizons); the open loop's beside it
    reported = reported_horizons(horizons, closed_loop)
    out.update({"horizons": reported.as_dict(), "horizons_predictor": dict(reported.predictor),
                "horizons_open_loop": horizons.as_dict(),
                "closed_loop": closed_loop.as_dict() if closed_loop is not None else None})
    return out


def _combined_validation(preds, sources) -> dict:
    """The fit JSON's ``validation``: one flight's prediction as is; several flights' nrmse
    averaged (total and per channel), each flight's under ``flights``."""
    if len(preds) == 1:
        return preds[0].as_dict()
    channels = {c: float(np.mean([p.nrmse[c] for p in preds if c in p.nrmse])) for c in preds[0].nrmse}
    return {"nrmse": float(np.mean([p.total for p in preds])), "channels": channels,
            "horizon": preds[0].horizon, "windows": int(sum(len(p.windows) for p in preds)),
            "longest_window": max(p.longest_window for p in preds),
            "flights": [{"log": s, **p.as_dict()} for s, p in zip(sources, preds)]}

"""Concise text and HTML summaries for notebooks: what ``repr(obj)`` and a notebook cell
show for a :class:`~greybox.data.FlightLog` and a :class:`~greybox.diagnosis.Diagnosis`.

The classes' ``__repr__`` / ``_repr_html_`` call these; they read only public attributes
and never import matplotlib.
"""
from __future__ import annotations

import html
import math

import numpy as np

# type names in annotations are strings: importing them here would tie this module
# to the ones it draws for (an import cycle for the tools, if not for Python)

__all__ = ["flightlog_text", "flightlog_html", "diagnosis_text", "diagnosis_html", "fitted_model_html"]

_STYLE = ("<style>.greybox-repr table{border-collapse:collapse;font-size:90%}"
          ".greybox-repr td,.greybox-repr th{border:1px solid #ccc;padding:1px 6px;text-align:right}"
          ".greybox-repr td:first-child,.greybox-repr th:first-child{text-align:left}</style>")
_MAX_ROWS = 12


def _f(v, fmt: str = ".3g", none: str = "") -> str:
    if v is None:
        return none
    v = float(v)
    return format(v, fmt) if math.isfinite(v) else str(v)


def _names(names, limit: int = 8) -> str:
    names = list(names)
    if len(names) > limit:
        return ", ".join(names[:limit]) + f", ... ({len(names)} in all)"
    return ", ".join(names)


def _span(names: list[str]) -> str:
    """``w1..w4`` for a run of numbered names, else the names."""
    if len(names) > 2:
        stem = names[0].rstrip("0123456789")
        if all(n == f"{stem}{i + 1}" for i, n in enumerate(names)):
            return f"{names[0]}..{names[-1]}"
    return ", ".join(names)


# ------------------------------------------------------------------------------ FlightLog
def _log_facts(log: "FlightLog") -> tuple[str, int, float, float]:
    name = str(log.source or "")
    if name:
        name = name.replace("\\", "/").rsplit("/", 1)[-1]
    n = len(log)
    step = float(np.median(np.diff(log.t))) if n > 1 else float("nan")
    return name, n, log.duration, (1.0 / step if step > 0 else float("nan"))


def _rate(log: "FlightLog", ch: str) -> float:
    try:
        return log.rate(ch)
    except Exception:   # a repr must never raise
        return float("nan")


def flightlog_text(log: "FlightLog") -> str:
    """One line: source, samples, duration, sample rate, inputs, per-channel rates, extras."""
    name, n, dur, base = _log_facts(log)
    rates = ", ".join(f"{ch} {_rate(log, ch):.0f} Hz" for ch in log.output_names)
    extra = f"; extras {_names(log.extras)}" if log.extras else ""
    src = f"{name!r}: " if name else ""
    return (f"<FlightLog {src}{n} samples, {dur:.2f} s at {base:.0f} Hz; inputs {_span(log.input_names)}; "
            f"outputs {rates or 'none'}{extra}>")


def flightlog_html(log: "FlightLog") -> str:
    """A small table: per output channel its rate, measured samples and range; per input its
    range; extras and notes below."""
    esc = html.escape
    name, n, dur, base = _log_facts(log)
    head = (f"<b>FlightLog</b>{' <code>' + esc(name) + '</code>' if name else ''}: {n} samples, "
            f"{dur:.2f} s, {base:.0f} Hz")
    rows = []
    for ch in log.output_names:
        y = log.output(ch)
        k = np.isfinite(y)
        rng = f"{np.min(y[k]):.3g} .. {np.max(y[k]):.3g}" if k.any() else ""
        rows.append(f"<tr><td>{esc(ch)}</td><td>output</td><td>{_rate(log, ch):.0f}</td>"
                    f"<td>{int(k.sum())}</td><td>{rng}</td></tr>")
    for j, u in enumerate(log.input_names):
        col = log.inputs[:, j]
        rng = f"{np.min(col):.4g} .. {np.max(col):.4g}" if col.size else ""
        rows.append(f"<tr><td>{esc(u)}</td><td>input</td><td>{base:.0f}</td><td>{col.size}</td>"
                    f"<td>{rng}</td></tr>")
    table = ("<table><tr><th>channel</th><th>kind</th><th>rate (Hz)</th><th>samples</th><th>range</th></tr>"
             + "".join(rows) + "</table>")
    extras = f"<div>extras: {esc(_names(log.extras, 12))}</div>" if log.extras else ""
    notes = ""
    if log.notes:
        notes = (f"<details><summary>{len(log.notes)} note{'s' if len(log.notes) != 1 else ''}</summary><ul>"
                 + "".join(f"<li>{esc(t)}</li>" for t in log.notes) + "</ul></details>")
    return f'<div class="greybox-repr">{_STYLE}<div>{head}</div>{table}{extras}{notes}</div>'


# ------------------------------------------------------------------------------ Diagnosis
def _added(d: "Diagnosis") -> list[str]:
    if d.final_model is None or d.final_prediction is None:
        return []
    return [e for e in d.final_model.effect_names if e not in d.model.effect_names]


def _verdict_words(d: "Diagnosis") -> str:
    if not d.verdict and d.null_reason == "nothing_missing" and d.small_but_moving():
        return "null (nothing missing is large enough to name)"
    return d.verdict or {"rotor_order": "null (the logged rotor speeds act as the airframe's rotors in another order: "
                                        "nothing was tested)",
                         "rotor_layout": "null (the logged rotor speeds act as the airframe's rotors turned about the "
                                         "body's z axis: nothing was tested)",
                         "uncertified": "null (cannot tell: the baseline fit is not certified)",
                         "attitude_uncertain": "null (cannot tell: the verdicts stood only with the attitude weighed "
                                               "by its sample-to-sample noise)",
                         "input_noise": "null (the rates are missed by a random torque that the noise on the logged "
                                        "rotor speeds gives: cannot tell a turbulence from it)",
                         "outside_catalogue": "null (what is missing is outside the catalogue: see the discovered "
                                              "combinations)",
                         "random_torque": "null (what is missing acts as a random torque: the final model holds "
                                          "it as a disturbance)",
                         "unexplained": "null (the model misses something no candidate explains)",
                         "sensor_error": "null (what is left above the noise is the sensors' own error, not "
                                         "motion)",
                         "small_misfit": "null (no catalogue effect is significant; the model is a little "
                                         "off the noise, too little to tell what it is)",
                         "nothing_missing": "null (nothing significant is missing)"}.get(d.null_reason,
                                                                                        f"null ({d.null_reason})")


def diagnosis_text(d: "Diagnosis") -> str:
    """One line: verdict, validation nrmse before (and after what was added), the ranking."""
    b = d.baseline_prediction
    nrmse = f"baseline nrmse {b.total:.3f}"
    added = _added(d)
    if added:
        nrmse += f" -> {d.final_prediction.total:.3f} with {', '.join(added)}"
    rank = []
    for c in d.ranking[:5]:
        stat = f"LR {c.lr:.3g}" if c.lr is not None else f"score {c.score:.3g}"
        rank.append(f"{c.effect}{'*' if c.significant else ''} ({stat})")
    more = f", ... ({len(d.ranking)} in all)" if len(d.ranking) > 5 else ""
    warn = f"; {len(d.warnings)} warning{'s' if len(d.warnings) != 1 else ''}" if d.warnings else ""
    return (f"<Diagnosis verdict {_verdict_words(d)!r}; {nrmse}; "
            f"ranking {', '.join(rank) + more if rank else 'empty'}{warn}>")


def diagnosis_html(d: "Diagnosis") -> str:
    """Verdict, the validation nrmse per channel (before and after), the ranking table and
    the warnings; ``d.report(dir)`` has the plots."""
    esc = html.escape
    b = d.baseline_prediction
    added = _added(d)
    f = d.final_prediction if added else None
    head = (f"<b>Diagnosis</b> of {esc(', '.join(d.model.effect_names))}: verdict "
            f"<b>{esc(_verdict_words(d))}</b>; baseline fit {'certified' if d.baseline_certified else 'NOT certified'}")
    if added:
        head += f"; added {esc(', '.join(added))}"
    src = f" on the {esc(d.validation_source)}" if d.validation_source else ""
    chans = list(b.nrmse)
    nr = ("<tr><th>validation nrmse" + src + "</th>" + "".join(f"<th>{esc(c)}</th>" for c in chans)
          + "<th>total</th></tr>"
          + "<tr><td>baseline</td>" + "".join(f"<td>{_f(b.nrmse[c])}</td>" for c in chans)
          + f"<td><b>{_f(b.total)}</b></td></tr>")
    if f is not None:
        nr += ("<tr><td>+ " + esc(", ".join(added)) + "</td>"
               + "".join(f"<td>{_f(f.nrmse.get(c))}</td>" for c in chans) + f"<td><b>{_f(f.total)}</b></td></tr>")
    rows = "".join(
        f"<tr><td>{esc(c.effect)}</td><td>{'yes' if c.significant else 'no'}</td><td>{_f(c.score, '.1f')}</td>"
        f"<td>{_f(c.lr, '.1f')}</td><td>{_f(c.p_value, '.2g')}</td><td>{_f(c.nrmse_before)}</td>"
        f"<td>{_f(c.nrmse_after)}</td><td>{'' if c.explained is None else f'{100 * c.explained:.0f} %'}</td>"
        f"<td style='text-align:left'>{esc(c.reason)}</td></tr>"
        for c in d.ranking[:_MAX_ROWS])
    if len(d.ranking) > _MAX_ROWS:
        rows += f"<tr><td colspan='9'>... {len(d.ranking) - _MAX_ROWS} more (d.ranking)</td></tr>"
    rank = ("<table><tr><th>candidate</th><th>significant</th><th>score</th><th>LR</th><th>p</th>"
            "<th>nrmse before</th><th>after</th><th>explained</th><th>why</th></tr>" + rows + "</table>"
            if d.ranking else "<div>no candidate was tested</div>")
    warn = ""
    if d.warnings:
        warn = (f"<details><summary>{len(d.warnings)} warning{'s' if len(d.warnings) != 1 else ''}</summary><ul>"
                + "".join(f"<li>{esc(w)}</li>" for w in d.warnings) + "</ul></details>")
    return f'<div class="greybox-repr">{_STYLE}<div>{head}</div><table>{nr}</table>{rank}{warn}</div>'


# ------------------------------------------------------------------------------ FittedModel
def fitted_model_html(fm: "FittedModel") -> str:
    """Structure, then every parameter with its standard deviation (free ones) or 'fixed',
    and where it came from."""
    esc = html.escape
    m = fm.model
    head = (f"<b>{esc(type(fm).__name__)}</b> <code>{esc(m.airframe.name)}</code>: "
            f"{esc(', '.join(m.effect_names))}; inputs {esc(m.inputs)}")
    std = dict(zip(fm.free_names, fm.std))
    rows = []
    for name, v in zip(m.param_names, fm.p):
        s = std.get(name)
        rel = f"{100 * abs(s / v):.2g} %" if s is not None and math.isfinite(s) and v != 0 else ""
        rows.append(f"<tr><td>{esc(name)}</td><td>{v:.6g}</td>"
                    f"<td>{'fixed' if s is None else _f(s, '.3g', 'n/a')}</td><td>{rel}</td></tr>")
    table = ("<table><tr><th>parameter</th><th>value</th><th>std</th><th>rel</th></tr>" + "".join(rows)
             + "</table>")
    prov = fm.provenance or {}
    src = ""
    if prov:
        src = (f"<div>from {esc(', '.join(map(str, prov.get('logs', []))) or '?')}"
               f"{'; ' + esc(str(prov.get('status'))) if prov.get('status') else ''}"
               f"{'; greybox ' + esc(str(prov.get('greybox_version'))) if prov.get('greybox_version') else ''}</div>")
    return f'<div class="greybox-repr">{_STYLE}<div>{head}</div>{table}{src}</div>'

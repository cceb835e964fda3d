"""The diagnosis as a report directory: ``report.html`` with the plots embedded, and the
plots as PNG files."""
from __future__ import annotations

import base64
import html
from pathlib import Path

from ..data import atomic_write

# the Diagnosis type is named in a string: importing it here would tie this module to the
# results it draws (an import cycle for the tools, if not for Python)

__all__ = ["write_report"]


def write_report(d: "Diagnosis", out: Path) -> Path:  # noqa: F821 - Diagnosis: see above
    """Write ``report.html`` (plots embedded) and the plots as PNG files into ``out``."""
    from ..plotting import report_figures, save
    out.mkdir(parents=True, exist_ok=True)
    images: dict[str, str] = {}
    for name, fig in report_figures(d).items():
        images[name] = base64.b64encode(save(fig, out / f"{name}.png").read_bytes()).decode()
    esc = html.escape
    rows = "".join(
        f"<tr><td>{esc(c.effect)}</td><td>{'yes' if c.significant else 'no'}</td>"
        f"<td>{c.score:.1f}</td><td>{'' if c.lr is None else f'{c.lr:.1f}'}</td>"
        f"<td>{'' if c.p_value is None else f'{c.p_value:.2g}'}</td><td>{c.nrmse_before:.3f}</td>"
        f"<td>{'' if c.nrmse_after is None else f'{c.nrmse_after:.3f}'}</td><td>{esc(c.reason)}</td></tr>"
        for c in d.ranking)
    b = d.baseline_prediction
    chan_rows = ""
    if d.final_prediction is not None:
        f = d.final_prediction
        chan_rows = "".join(f"<tr><td>{ch}</td><td>{b.nrmse[ch]:.3f}</td><td>{f.nrmse.get(ch, float('nan')):.3f}</td>"
                            f"<td>{100 * (f.nrmse.get(ch, 0) / b.nrmse[ch] - 1) if b.nrmse[ch] else 0:+.0f} %</td></tr>"
                            for ch in b.nrmse)
    img = lambda k: f'<img src="data:image/png;base64,{images[k]}"/>' if k in images else ""
    imbalance = (f"<li>{esc(d.command_imbalance.text())}</li>"
                 if d.command_imbalance is not None and d.command_imbalance.notable else "")
    horizons = "".join(f"<p>{esc(line.strip())}</p>" for line in d.horizon_lines()
                       + ([d.closed_loop.line()] if d.closed_loop is not None else []))
    param_rows = "".join(
        f"<tr><td>{esc(n)}</td><td>{v['value']:.6g}</td>"
        f"<td>{'fixed' if v['std'] is None else format(v['std'], '.3g')}</td></tr>"
        for n, v in d.parameter_table().items() if v["value"] is not None)
    disc_rows = "".join(
        f"<tr><td>{'yes' if x.significant else 'no'}</td><td>{esc(x.text())}</td><td>{x.nrmse_before:.3f}</td>"
        f"<td>{'' if x.nrmse_after is None else f'{x.nrmse_after:.3f}'}</td><td>{esc(x.reason)}</td></tr>"
        for x in d.discovered)
    discovery = (f"<h2>5. Beyond the catalogue</h2><p>Residual generalised forces of the model as given, explained by "
                 f"named features: {esc(d.discovery.get('text', ''))}</p>"
                 + (f"<table><tr><th>significant</th><th>combination</th><th>nrmse before</th><th>nrmse after</th>"
                    f"<th>why</th></tr>{disc_rows}</table>" if disc_rows else "")) if d.discovery else ""
    text = f"""<!doctype html><html><head><meta charset="utf-8"><title>greybox diagnosis</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 8px}}img{{max-width:100%}}</style></head><body>
<h1>greybox diagnosis</h1>
<p>Model: {esc(', '.join(d.model.effect_names))}. Verdict: <b>{esc(d.verdict_text())}</b>.</p>
<h2>1. Compare</h2><p>Validation nrmse {b.total:.3f} on the {esc(d.validation_source)} ({esc(', '.join(f'{c} {v:.3f}' for c, v in b.nrmse.items()))}).</p>
{img('compare_baseline')}
<h2>2. Where it fails</h2><ul>{''.join(f'<li>{esc(f.text)}</li>' for f in d.findings) or '<li>no regime stands out</li>'}{imbalance}</ul>
{img('regimes')}<p>Residual autocorrelation (grey: 99 % band of white noise):</p>{img('whiteness')}
<h2>3. Which effect is missing</h2><table><tr><th>effect</th><th>significant</th><th>score</th><th>LR</th>
<th>p</th><th>nrmse before</th><th>nrmse after</th><th>why</th></tr>{rows}</table>{img('ranking')}
<h2>4. Added, and the error falls</h2>
<table><tr><th>channel</th><th>before</th><th>after</th><th>change</th></tr>{chan_rows}</table>{horizons}{img('compare_after')}
{discovery}
<h2>Fitted parameters of the final model</h2><table><tr><th>parameter</th><th>value</th><th>std</th></tr>{param_rows}</table>
<h2>Warnings</h2><ul>{''.join(f'<li>{esc(w)}</li>' for w in d.warnings) or '<li>none</li>'}</ul>
</body></html>"""
    path = out / "report.html"
    atomic_write(path, text)
    return path

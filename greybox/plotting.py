"""Figures that behave in notebooks and scripts alike.

Every function here returns a :class:`matplotlib.figure.Figure` and

- never selects a matplotlib backend and never touches pyplot's state: new figures are
  plain ``Figure`` objects (not registered with pyplot, so nothing to close and nothing
  shown twice), and a notebook displays one that is a cell's last expression;
- draws into the axes you give (``ax=``, where one axes suffices; ``axes=`` / ``fig=``
  where a figure needs several) and then returns the figure they are on, leaving its layout to you;
- writes a file only when given ``path`` (format from the suffix, PNG by default; written
  to a temporary name in the same folder and renamed, so a reader never sees half a file).

::

    from greybox import plotting
    plotting.compare([before, after], labels=["base", "+ ground_effect"])   # all channels
    fig, ax = plt.subplots(); plotting.compare(pred, ax=ax, channels="z")    # one channel
    plotting.residuals(pred, path="residuals.png")

Diagnosis figures: :func:`whiteness`, :func:`regimes`, :func:`ranking` (and
:func:`report_figures`, the set ``Diagnosis.report`` writes); n4sid: :func:`n4sid_order`.
"""
from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.figure import Figure

from .data import atomic_write
from .errors import GreyboxInputError
from .model import OUTPUTS

# type names in annotations are strings: importing them here would tie this module
# to the ones it draws for (an import cycle for the tools, if not for Python)

__all__ = ["compare", "residuals", "whiteness", "regimes", "ranking", "n4sid_order", "report_figures",
           "save", "new_figure", "horizons", "to_bytes"]

DPI = 100
WHITENESS_LAGS = 30
"""Autocorrelation lags shown by :func:`whiteness` (as in the diagnosis' whiteness fraction)."""


# ------------------------------------------------------------------------------ plumbing
def to_bytes(fig: Figure, fmt: str = "png", dpi: float = DPI) -> bytes:
    """The figure rendered (PNG by default), to be written later with other outputs."""
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi)
    return buf.getvalue()


def save(fig: Figure, path: str | Path, dpi: float = DPI) -> Path:
    """Write ``fig`` to ``path`` (format from the suffix, PNG without one) through a temporary
    file in the same folder and a rename. Creates the folder. Returns ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fmt = path.suffix[1:].lower() or "png"
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi)
    atomic_write(path, buf.getvalue())   # never a half-written figure
    return path


class _Figure(Figure):
    """A plain Figure that a notebook shows as PNG when it is a cell's value, even when
    pyplot (and with it the notebook's figure formatter) was never imported."""

    def __repr__(self) -> str:
        return super().__repr__().replace(type(self).__name__, "Figure", 1)

    def _repr_png_(self) -> bytes:
        buf = io.BytesIO()
        self.savefig(buf, format="png", bbox_inches="tight")
        return buf.getvalue()


def new_figure(figsize: tuple[float, float]) -> Figure:
    """A new figure that shows inline in a notebook, chooses no backend and is not in
    pyplot's figure list (for figure functions of one's own, as :mod:`greybox.paper`'s)."""
    return _Figure(figsize=figsize, layout="constrained")


def _done(fig: Figure, path: str | Path | None, dpi: float) -> Figure:
    if path is not None:
        save(fig, path, dpi)
    return fig


def _as_list(x) -> list:
    if x is None:
        return []
    if isinstance(x, str):
        return [x]
    return list(x)


def _axes_list(axes) -> list:
    return list(np.ravel(np.asarray(axes, dtype=object)))


def _pick_channels(available: Sequence[str], channels, score: dict[str, float] | None, single: bool) -> list[str]:
    """Channels to draw: those asked for (checked), else all; with one axes, the worst by ``score``."""
    chans = _as_list(channels)
    for ch in chans:
        if ch not in available:
            raise GreyboxInputError(f"plot: no channel {ch!r} here; available: {', '.join(available)}")
    if not chans:
        chans = list(available)
        if single and score:
            chans = [max(chans, key=lambda c: score.get(c, -math.inf)
                         if np.isfinite(score.get(c, np.nan)) else -math.inf)]
    if single and len(chans) != 1:
        raise GreyboxInputError(f"plot: one axes (ax=) takes one channel, got {len(chans)}: "
                                f"pass channels='...' or axes= with one axes per channel")
    if not chans:
        raise GreyboxInputError("plot: no channel to draw")
    return chans


def _root(ax) -> Figure:
    """The Figure an axes is drawn on (through subfigures)."""
    f = ax.figure
    for _ in range(16):
        if isinstance(f, Figure):
            break
        f = f.figure
    return f


def _grid(ax, axes, fig, n: int, ncols: int, figsize, **subplots_kw):
    """(figure, axes array (n, ncols), whether we made the figure)."""
    if ax is not None:
        if n * ncols != 1:
            raise GreyboxInputError(f"plot: this figure needs {n * ncols} axes; pass axes= or fig=")
        return _root(ax), np.array([[ax]], dtype=object), False
    if axes is not None:
        lst = _axes_list(axes)
        if len(lst) != n * ncols:
            raise GreyboxInputError(f"plot: got {len(lst)} axes for {n * ncols} panels")
        return _root(lst[0]), np.array(lst, dtype=object).reshape(n, ncols), False
    made = fig is None
    fig = new_figure(figsize) if made else fig
    arr = fig.subplots(n, ncols, squeeze=False, **subplots_kw)
    return fig, arr, made


def _time_axis(pred) -> np.ndarray:
    """Sample times of a prediction; for one pooled over flights, each flight's times
    continue after the previous flight's end (a gap of one second between them)."""
    if not getattr(pred, "parts", None):
        return pred.log.t
    out, end = [], 0.0
    for part in pred.parts:
        t = part.log.t - part.log.t[0] + (end + 1.0 if out else part.log.t[0])
        out.append(t)
        end = float(t[-1])
    return np.concatenate(out)


def _message(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=9, color="0.3")
    ax.set_axis_off()


# ------------------------------------------------------------------------------ validation
def compare(pred: "Prediction | Sequence[Prediction]", ax: "Axes | None" = None, path: str | Path | None = None,
            *, labels: Sequence[str] | None = None, channels: str | Sequence[str] | None = None,
            title: str | None = None, axes=None, fig: Figure | None = None, dpi: float = DPI) -> Figure:
    """Measured vs k-step-ahead predicted, per channel (MATLAB's ``compare``).

    ``pred``: a :class:`~greybox.validation.Prediction` or a list of them (on the same log),
    drawn over the measurements with their fit percent in the legend; grey lines mark the
    window starts. Without axes, one row per channel (``channels``, default every scored
    channel). ``ax=``: one channel into that axes (``channels="z"``; default the worst by
    the first prediction's nrmse). ``axes=``: one axes per channel. ``fig=``: subplots of
    that figure. ``path``: also write it.

    >>> fig = compare([before, after], labels=["base", "+ ground_effect"])  # doctest: +SKIP
    """
    # a Prediction (duck-typed: plotting imports no module that plots through it)
    preds = [pred] if hasattr(pred, "nrmse") and hasattr(pred, "predicted") else list(pred)
    if not preds:
        raise GreyboxInputError("compare: no prediction given")
    labels = list(labels or ([f"model {i + 1}" for i in range(len(preds))] if len(preds) > 1 else ["model"]))
    if len(labels) != len(preds):
        raise GreyboxInputError(f"compare: {len(labels)} labels for {len(preds)} predictions")
    first = preds[0]
    chans = _pick_channels(first.channels, channels, first.nrmse, single=ax is not None)
    fig_, axs, made = _grid(ax, axes, fig, len(chans), 1, (10, 1.7 * len(chans) + 0.8), sharex=True)
    t = _time_axis(first)
    for a, ch in zip(axs[:, 0], chans):
        c = OUTPUTS.index(ch)
        y = first.predicted[:, c] + first.errors[:, c]   # the measurements (all flights, when pooled)
        k = np.isfinite(y)
        a.plot(t[k], y[k], ".", ms=1.5, color="0.4", label="measured")
        for pr, lab in zip(preds, labels):
            a.plot(_time_axis(pr), pr.predicted[:, c], lw=1.0,
                   label=f"{lab} (fit {pr.fit_percent.get(ch, float('nan')):.1f} %)")
        for w0, _ in first.windows:
            a.axvline(t[w0], color="0.85", lw=0.5, zorder=0)
        a.set_ylabel(ch)
        a.legend(fontsize=7, loc="upper right")
    axs[-1, 0].set_xlabel("t (s)")
    default = (f"{first.horizon:g} s-ahead prediction vs measurement (grey lines: window starts)")
    if ax is not None:
        ax.set_title(title if title is not None else f"{ch}: {first.horizon:g} s-ahead prediction", fontsize=9)
    elif made or title:
        fig_.suptitle(title or default, fontsize=10)
    return _done(fig_, path, dpi)


def residuals(pred: "Prediction", ax: "Axes | None" = None, path: str | Path | None = None, *,
              channels: str | Sequence[str] | None = None, hist: bool = True, axes=None,
              fig: Figure | None = None, dpi: float = DPI) -> Figure:
    """Prediction errors (measured - predicted, yaw wrapped) against time, per channel, with
    their histograms beside (``hist``). ``ax=``: one channel's errors against time (default
    the worst by nrmse); ``axes=``: ``len(channels) x (2 if hist else 1)`` axes."""
    chans = _pick_channels(pred.channels, channels, pred.nrmse, single=ax is not None)
    ncols = 2 if (hist and ax is None) else 1
    fig_, axs, made = _grid(ax, axes, fig, len(chans), ncols, (10, 1.6 * len(chans) + 0.8),
                            gridspec_kw={"width_ratios": [4, 1]} if ncols == 2 else None)
    for row, ch in zip(axs, chans):
        e = pred.errors[:, OUTPUTS.index(ch)]
        k = np.isfinite(e)
        row[0].plot(_time_axis(pred)[k], e[k], lw=0.6)
        row[0].axhline(0, color="k", lw=0.5)
        row[0].set_ylabel(f"{ch} error")
        if ncols == 2:
            row[1].hist(e[k], bins=40, orientation="horizontal", color="C1")
    axs[-1, 0].set_xlabel("t (s)")
    if ax is not None:
        ax.set_title(f"{ch}: prediction residuals (measured - predicted)", fontsize=9)
    elif made:
        fig_.suptitle("prediction residuals (measured - predicted)", fontsize=10)
    return _done(fig_, path, dpi)


def horizons(he: "HorizonErrors | Prediction", ax: "Axes | None" = None, path: str | Path | None = None, *,
             channels: str | Sequence[str] | None = None, axes=None, fig: Figure | None = None,
             dpi: float = DPI, closed_loop: "HorizonErrors | None" = None) -> Figure:
    """RMS prediction error against horizon per channel, the model (solid) beside the naive
    constant-velocity / constant-rate predictor (dashed), log-log. ``he``: a
    :class:`~greybox.validation.HorizonErrors` or a prediction (its ``horizon_errors()``).
    ``ax=``: one channel (default the one where the model gains least on the naive one).
    ``closed_loop``: the model flown by its controller's law as well (dotted;
    :func:`greybox.closed_loop_horizon_errors`)."""
    if hasattr(he, "horizon_errors"):
        he = he.horizon_errors()
    ratio = {}
    for ch in he.model:
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.asarray(he.model[ch], float) / np.asarray(he.naive[ch], float)
        r = r[np.isfinite(r)]
        ratio[ch] = float(r.mean()) if r.size else -math.inf
    chans = _pick_channels(list(he.model), channels, ratio, single=ax is not None)
    ncols = min(3, len(chans)) if ax is None else 1
    nrows = int(math.ceil(len(chans) / ncols))
    fig_, axs, _ = _grid(ax, axes, fig, nrows, ncols, (4 * ncols, 2.6 * nrows + 0.6))
    flat = list(axs.ravel())
    label = "model, moment held" if getattr(he, "predictor", {}).get("held_moment") else "model"
    for a, ch in zip(flat, chans):
        a.loglog(he.horizons, he.model[ch], "o-", color="C0", label=label)
        a.loglog(he.horizons, he.naive[ch], "s--", color="C3", label="naive")
        if closed_loop is not None and ch in closed_loop.model:
            a.loglog(closed_loop.horizons, closed_loop.model[ch], "^:", color="C2", label="model, closed loop")
        a.set_title(ch, fontsize=9)
        a.set_xlabel("horizon (s)")
    for a in flat[len(chans):]:
        a.set_axis_off()
    flat[0].legend(fontsize=8)
    return _done(fig_, path, dpi)


# ------------------------------------------------------------------------------ diagnosis
def _autocorrelation(e: np.ndarray, lags: int) -> tuple[np.ndarray, float]:
    e = e[np.isfinite(e)]
    e = e - e.mean()
    den = float(e @ e)
    ac = np.array([float(e[j:] @ e[:-j]) / den if den > 0 else 0.0 for j in range(1, lags + 1)])
    return ac, 2.576 / math.sqrt(max(e.size, 1))


def whiteness(d: "Diagnosis | np.ndarray", ax: "Axes | None" = None, path: str | Path | None = None, *,
              channels: str | Sequence[str] | None = None, lags: int = WHITENESS_LAGS, axes=None,
              fig: Figure | None = None, dpi: float = DPI) -> Figure:
    """Residual autocorrelation per channel against the 99 % band of white noise (grey), as
    MATLAB's ``resid``. ``d``: a :class:`~greybox.diagnosis.Diagnosis` (its baseline's
    estimation residuals) or an ``(n, 9)`` residual array in output order. ``ax=``: one
    channel (default the least white)."""
    if hasattr(d, "whiteness") and hasattr(d, "residuals"):      # a Diagnosis
        res, score = d.residuals, dict(d.whiteness)
        available = [c for c in OUTPUTS if c in d.whiteness]
    else:
        res = np.asarray(d, dtype=float)
        available = [c for i, c in enumerate(OUTPUTS)
                     if res.ndim == 2 and i < res.shape[1] and np.isfinite(res[:, i]).sum() > lags + 2]
        score = {}
        for c in available:   # fraction of lags outside the band, as the diagnosis' whiteness
            ac, band = _autocorrelation(res[:, OUTPUTS.index(c)], lags)
            score[c] = float(np.mean(np.abs(ac) > band))
    if res is None or not available:
        if channels is None and axes is None:
            fig_, axs, _ = _grid(ax, None, fig, 1, 1, (5, 2.4))
            _message(axs[0, 0], "no residuals to show")
            return _done(fig_, path, dpi)
        raise GreyboxInputError("whiteness: no residuals to show")
    chans = _pick_channels(available, channels, score, single=ax is not None)
    fig_, axs, _ = _grid(ax, axes, fig, 1, len(chans), (2.0 * len(chans), 2.4), sharey=True)
    for a, ch in zip(axs[0], chans):
        ac, band = _autocorrelation(res[:, OUTPUTS.index(ch)], lags)
        a.bar(np.arange(1, lags + 1), ac, color="C0")
        a.axhspan(-band, band, color="0.85", zorder=0)
        a.set_title(ch, fontsize=9)
        a.set_xlabel("lag", fontsize=8)
    axs[0, 0].set_ylabel("autocorrelation")
    return _done(fig_, path, dpi)


def regimes(d: "Diagnosis", ax: "Axes | None" = None, path: str | Path | None = None, *, n: int = 4,
            axes=None, fig: Figure | None = None, dpi: float = DPI) -> Figure:
    """Where the model fails: each of the ``n`` strongest findings' error envelope against
    its flight-condition variable. ``ax=``: the strongest finding only."""
    top = [f for f in d.findings if f.values is not None][:1 if ax is not None else n]
    if not top:
        fig_, axs, _ = _grid(ax, None, fig, 1, 1, (5, 2.8))
        _message(axs[0, 0], "no regime stands out")
        return _done(fig_, path, dpi)
    fig_, axs, _ = _grid(ax, axes, fig, 1, len(top), (3.3 * len(top), 2.8))
    for a, f in zip(axs[0], top):
        a.plot(f.values, f.errors, ".", ms=1.5, alpha=0.5)
        a.set_xlabel(f.variable, fontsize=8)
        a.set_ylabel(f"{f.channel} error" + ("" if f.variable == "time into the flight" else
                                             " (RMS over 0.2 s)"), fontsize=8)
        a.set_title(f"r = {f.r:+.2f}", fontsize=9)
    return _done(fig_, path, dpi)


def ranking(d: "Diagnosis", ax: "Axes | None" = None, path: str | Path | None = None, *,
            dpi: float = DPI) -> Figure:
    """The candidates' statistics (likelihood ratio after a refit, else the score), log
    scale, best on top; green = significant."""
    rank = list(d.ranking)
    fig_, axs, _ = _grid(ax, None, None, 1, 1, (7, 0.35 * max(len(rank), 1) + 1))
    a = axs[0, 0]
    if not rank:
        _message(a, "no candidate was tested")
        return _done(fig_, path, dpi)
    vals = np.array([(c.lr if c.lr is not None else c.score) for c in rank][::-1], dtype=float)
    vals = np.where(np.isfinite(vals), vals, 1e-3)
    cols = ["C2" if c.significant else "0.6" for c in rank][::-1]
    a.barh([c.effect for c in rank][::-1], np.maximum(vals, 1e-3), color=cols)
    a.set_xscale("log")
    a.set_xlabel("statistic (LR after refit, else score); green = significant")
    return _done(fig_, path, dpi)


def report_figures(d: "Diagnosis") -> dict[str, Figure]:
    """The figures of ``Diagnosis.report``, by name: ``compare_baseline``, ``compare_after``
    (when effects were added), ``whiteness``, ``regimes`` and ``ranking`` (when there is
    something to show)."""
    figs: dict[str, Figure] = {"compare_baseline": compare(d.baseline_prediction, labels=["baseline"])}
    if d.final_prediction is not None and d.final_model is not None and d.final_model is not d.model:
        added = [e for e in d.final_model.effect_names if e not in d.model.effect_names]
        figs["compare_after"] = compare([d.baseline_prediction, d.final_prediction],
                                        labels=["baseline", "+ " + ", ".join(added)])
    if d.residuals is not None and any(c in d.whiteness for c in OUTPUTS):
        figs["whiteness"] = whiteness(d)
        if any(f.values is not None for f in d.findings):
            figs["regimes"] = regimes(d)
    if d.ranking:
        figs["ranking"] = ranking(d)
    return figs


# ------------------------------------------------------------------------------ n4sid
def n4sid_order(model: "StateSpaceModel", ax: "Axes | None" = None, path: str | Path | None = None, *,
                axes=None, fig: Figure | None = None, dpi: float = 110) -> Figure:
    """Singular values of the n4sid projection (log scale) with the chosen order and, when
    the order was chosen automatically, the held-out fit of each order beside. ``ax=``: the
    singular values only."""
    two = bool(model.order_scores) and ax is None
    fig_, axs, _ = _grid(ax, axes, fig, 1, 2 if two else 1, (9 if two else 5, 3.5))
    s = np.asarray(model.singular_values)
    a = axs[0, 0]
    a.semilogy(np.arange(1, s.size + 1), s, "o-", ms=3)
    a.axvline(model.order, color="r", ls="--", label=f"order {model.order}")
    a.set_xlabel("index")
    a.set_ylabel("singular value")
    a.legend()
    if two:
        a = axs[0, 1]
        ks = sorted(model.order_scores)
        a.plot(ks, [model.order_scores[k] for k in ks], "o-", ms=3)
        a.axvline(model.order, color="r", ls="--")
        a.set_xlabel("order")
        a.set_ylabel("held-out fit %")
    return _done(fig_, path, dpi)

"""Isolated glitches in a log's pose channels (a motion-capture marker swap, a vision
misdetection, a GNSS jump): samples that leave the track of their neighbours and come back.

A few such samples, each tens of times the channel's noise, dominate its sum of squares: a
fit then reads them as a force the model lacks (a blind audit's 1.2 kg vehicle with 12
position samples 5-20 cm off in 3800 rows of 1-mm motion capture: residuals 3.9 times the
noise on x, y, z, the diagnosis "missing something no candidate explains"). A sample is
judged against the cubic through its two neighbours on each side (Lagrange, on the samples'
own times): white noise of standard deviation ``s`` leaves a residual of ``1.39 s`` there, a
smooth flight next to nothing. It is a glitch when its residual is

- beyond :data:`OUTLIER_THRESHOLD` times the residuals' robust scale, taken both over the
  whole channel and over the :data:`LOCAL_SAMPLES` samples around it (an autopilot's filtered
  attitude, 0.1 mrad from sample to sample, leaves residuals of tens of that scale during
  every brisk turn: the local scale rises with them, a lone glitch does not move it);
- the largest of the five residuals around it (a glitch's neighbours see two thirds of it);
- such that, with the candidates left out, the samples next to it lie on the cubic through
  theirs: the track comes back (a brisk manoeuvre bends it, and its neighbours stay off it);
- for roll, pitch and yaw with a gyro logged, also beyond the threshold against its
  neighbours carried to its time by the gyro's Euler rates (:func:`gyro_residuals`: a turn is
  in the gyro, a glitch is not);

and the glitches of a group (position ``x, y, z``; attitude ``phi, theta, psi``) are taken
out only when they hold more than :data:`OUTLIER_SHARE` of the noise's sum of squares in one
of its channels: fewer and smaller ones move neither the weights nor the residual check (the
ten NanoBench flights have one or two samples at 11-12 times the scale in four of them, and
keep them). Found, a sample is taken out of every channel of its group (a marker swap moves
the whole pose); up to three passes find a second glitch beside a first.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import median_filter

from .data import FlightLog
from .model import OUTPUTS
from .rotations import euler_rate_matrices
from .shooting import NOISE_FLOOR, robust_std

__all__ = ["OUTLIER_THRESHOLD", "OUTLIER_SHARE", "OUTLIER_GROUPS", "LOCAL_SAMPLES", "Outliers",
           "find_outliers", "drop_outliers", "neighbour_residuals", "gyro_residuals"]

OUTLIER_THRESHOLD = 10.0
"""A sample is a glitch when its residual against its neighbours' cubic is beyond this many
times their robust scale (white noise reaches 10 of it once in 1e23 samples)."""
OUTLIER_SHARE = 0.25
"""... and a group's glitches are taken out when, in one of its channels, their squared
residuals over the scale sum to more than this share of the channel's sample count (the
channel's RMS 12 % above its noise or more)."""
OUTLIER_GROUPS = {"position": ("x", "y", "z"), "attitude": ("phi", "theta", "psi")}
"""Channels measured together by one sensor (a glitch moves them all): the pose's. The IMU's
channels are left alone: a landing's jolt is a spike in them that the vehicle really felt."""
LOCAL_SAMPLES = 65
"""Samples over which the local scale of the residuals is taken (a median: 32 on each side)."""
MAX_PASSES = 3
_GAP_STEPS = 8.0     # four neighbours spanning more than this many median steps: not judged


def _floor(channel: str) -> float:
    """The sensor's resolution (:data:`greybox.shooting.NOISE_FLOOR`): a noise-free simulated
    log's residuals are the integrator's, and nothing is a glitch against them."""
    return float(NOISE_FLOOR[OUTPUTS.index(channel)])


@dataclass
class Outliers:
    """The glitches :func:`find_outliers` found in one log: the rows per group, the group's
    measured samples and, per channel, the largest glitch (its residual, m or rad)."""
    rows: dict[str, np.ndarray] = field(default_factory=dict)
    size: dict[str, float] = field(default_factory=dict)
    samples: dict[str, int] = field(default_factory=dict)

    def __bool__(self) -> bool:
        return any(r.size for r in self.rows.values())

    def describe(self, t: np.ndarray) -> str:
        """In words, with the first few times (``t``: the log's times)."""
        parts = []
        for group, rows in self.rows.items():
            chans = [c for c in OUTLIER_GROUPS[group] if c in self.size]
            when = ", ".join(f"{t[r]:.6g}" for r in rows[:5]) + (", ..." if rows.size > 5 else "")
            parts.append(f"{rows.size} {group} sample{'s' if rows.size != 1 else ''} of {self.samples[group]} "
                         f"(t = {when} s) "
                         f"{'leave the track of their' if rows.size != 1 else 'leaves the track of its'} neighbours by up to "
                         + ", ".join(f"{self.size[c]:.3g} {'m' if group == 'position' else 'rad'} ({c})"
                                     for c in chans)
                         + f", over {OUTLIER_THRESHOLD:g} times the noise of the samples around them, and "
                         + ("come back" if rows.size != 1 else "comes back"))
        return "; ".join(parts)


def _cubic_at(t: np.ndarray, y: np.ndarray, i: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """The cubic through samples ``nodes`` (m, 4) at the times of samples ``i`` (m,)."""
    T, Y, x = t[nodes], y[nodes], t[i]
    pred = np.zeros(i.size)
    for a in range(4):
        weight = np.ones(i.size)
        for b in range(4):
            if b != a:
                weight *= (x - T[:, b]) / (T[:, a] - T[:, b])
        pred += weight * Y[:, a]
    return pred


_END_NOISE_GAIN = math.sqrt(1 + 34 / 36) / math.sqrt(6)
"""White noise's residual against the interior cubic (``sqrt(1 + 2 (1/6)^2 + 2 (2/3)^2)``)
over its residual against the line through the next two samples (``sqrt(1 + 2^2 + 1)``): an
end sample's residual is scaled by it, so that noise gives both the same spread."""


def neighbour_residuals(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Each sample less the cubic through its two neighbours on each side, at its time; the
    first and last samples less the line through the next two inward, scaled to the same
    spread for white noise (:data:`_END_NOISE_GAIN`: a blind audit's motion capture logged its
    first frame at the origin, 1.5 m off, and the fit took it). NaN at the second and
    second-to-last samples and where the neighbours span a dropout."""
    n = t.size
    r = np.full(n, np.nan)
    if n < 5:
        return r
    step = float(np.median(np.diff(t)))
    i = np.arange(2, n - 2)
    i = i[(t[i + 2] - t[i - 2]) <= (_GAP_STEPS + 1e-6) * step]
    if i.size:
        r[i] = y[i] - _cubic_at(t, y, i, np.stack([i - 2, i - 1, i + 1, i + 2], axis=1))
    for end, a, b in ((0, 1, 2), (n - 1, n - 2, n - 3)):
        if abs(t[b] - t[end]) <= (0.5 * _GAP_STEPS + 1e-6) * step:
            line = y[a] + (y[a] - y[b]) * (t[end] - t[a]) / (t[a] - t[b])
            r[end] = _END_NOISE_GAIN * (y[end] - line)
    return r


def gyro_residuals(t: np.ndarray, angles: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """(n, 3) each attitude sample (``angles``: roll, pitch, unwrapped yaw) less the mean of its
    two neighbours carried to its time by the gyro's Euler rates (``omega``: body rates at the
    same times; trapezoids): a turn however brisk is in the gyro, a glitch is not, and a
    constant gyro bias cancels. NaN at the ends and across dropouts."""
    n = t.size
    r = np.full((n, 3), np.nan)
    if n < 3:
        return r
    rates = np.einsum("nab,nb->na", euler_rate_matrices(angles[:, 0], angles[:, 1]), omega)
    step = float(np.median(np.diff(t)))
    i = np.arange(1, n - 1)
    i = i[(t[i + 1] - t[i - 1]) <= (0.5 * _GAP_STEPS + 1e-6) * step]
    dt_before, dt_after = (t[i] - t[i - 1])[:, None], (t[i + 1] - t[i])[:, None]
    from_before = angles[i - 1] + 0.5 * dt_before * (rates[i - 1] + rates[i])
    from_after = angles[i + 1] - 0.5 * dt_after * (rates[i] + rates[i + 1])
    r[i] = angles[i] - 0.5 * (from_before + from_after)
    return r


def _scaled(r: np.ndarray, floor: float) -> np.ndarray:
    """|r| over its robust scale, the larger of the whole channel's and the local one."""
    a = np.abs(np.nan_to_num(r))
    fin = np.isfinite(r)
    if fin.sum() < 5:
        return np.zeros_like(a)
    global_scale = robust_std(r)
    # mirrored at the ends: an end sample repeated would set its own scale (a first glitch)
    local = 1.4826 * median_filter(a, size=LOCAL_SAMPLES, mode="mirror")
    scale = np.maximum(np.maximum(local, global_scale), floor * np.sqrt(1 + 34 / 36))
    return np.where(fin, a / scale, 0.0)


def _gyro_scaled(log: FlightLog, k: np.ndarray, y_of: dict[str, np.ndarray]) -> np.ndarray | None:
    """:func:`gyro_residuals` at the attitude samples ``k`` over their scale (as the
    neighbours' cubic's), or None without a gyro (or without all three angles)."""
    if not all(c in log.output_names for c in ("phi", "theta", "psi", "p", "q", "r")) or len(y_of) < 3:
        return None
    omega = []
    for c in ("p", "q", "r"):
        g = log.output(c)
        fin = np.isfinite(g)
        if fin.sum() < 0.5 * k.size:
            return None
        omega.append(np.interp(log.t[k], log.t[fin], g[fin]))
    angles = np.column_stack([y_of[c] for c in ("phi", "theta", "psi")])
    r = gyro_residuals(log.t[k], angles, np.column_stack(omega))
    return np.column_stack([_scaled(r[:, j], _floor(c)) for j, c in enumerate(("phi", "theta", "psi"))])


def find_outliers(log: FlightLog, threshold: float = OUTLIER_THRESHOLD,
                  share: float = OUTLIER_SHARE) -> Outliers:
    """The isolated glitches in ``log``'s pose channels (see the module's docstring)."""
    found = Outliers()
    for group, names in OUTLIER_GROUPS.items():
        chans = [c for c in names if c in log.output_names]
        if not chans:
            continue
        Y = np.column_stack([log.output(c) for c in chans])
        measured = np.flatnonzero(np.isfinite(Y).all(axis=1))
        if measured.size < 20:
            continue
        bad = np.zeros(len(log), dtype=bool)
        excess = dict.fromkeys(chans, 0.0)
        worst = dict.fromkeys(chans, 0.0)
        for _ in range(MAX_PASSES):
            k = measured[~bad[measured]]
            tk = log.t[k]
            y_of = {c: np.unwrap(Y[k, j]) if group == "attitude" else Y[k, j] for j, c in enumerate(chans)}
            resid = {c: neighbour_residuals(tk, y) for c, y in y_of.items()}
            scaled = {c: _scaled(r, _floor(c)) for c, r in resid.items()}
            peaks = {}
            for c, z in scaled.items():
                padded = np.pad(z, 2)
                peaks[c] = (z > threshold) & (z >= np.max(np.stack([padded[s:s + z.size] for s in range(5)]), axis=0))
            candidate = np.logical_or.reduce(list(peaks.values()))
            if not candidate.any():
                break
            # a glitch leaves the track and comes back: with the candidates left out, the
            # samples next to each lie on the cubic through theirs (a brisk manoeuvre bends the
            # track there, and its neighbours stay off it)
            rest = np.flatnonzero(~candidate)
            gyro_z = _gyro_scaled(log, k, y_of) if group == "attitude" else None
            new = np.zeros(k.size, dtype=bool)
            for c, z in scaled.items():
                idx = np.flatnonzero(peaks[c])
                if idx.size == 0:
                    continue
                r_rest = np.abs(neighbour_residuals(tk[rest], y_of[c][rest]))
                after = np.searchsorted(rest, idx)
                inside = (after > 0) & (after < rest.size)
                follow = np.full(idx.size, np.inf)
                follow[inside] = np.fmax(r_rest[after[inside] - 1], r_rest[after[inside]])
                # a first or last sample: the track beyond it, the next kept sample's own
                # residual (then an end's)
                first, last = (after == 0) & (rest.size > 0), (after == rest.size) & (rest.size > 0)
                follow[first] = r_rest[0]
                follow[last] = r_rest[-1]
                follow = np.where(np.isnan(follow), np.inf, follow)
                scale = np.abs(resid[c][idx]) / z[idx]
                ok = follow <= 0.5 * threshold * scale
                if gyro_z is not None:
                    # and the gyro, where logged, does not show the jump
                    ok &= gyro_z[idx, chans.index(c)] > threshold
                hit = idx[ok]
                if hit.size:
                    # an end sample's residual was scaled to the interior's spread: said as it is
                    size = np.abs(resid[c][hit]) / np.where((hit == 0) | (hit == k.size - 1), _END_NOISE_GAIN, 1.0)
                    worst[c] = max(worst[c], float(size.max()))
                new[hit] = True
            if not new.any():
                break
            for c, z in scaled.items():
                # a glitch found in one channel counts in every channel of its group
                excess[c] += float(np.sum(z[new] ** 2))
            bad[k[new]] = True
        if bad.any() and max(excess[c] / measured.size for c in chans) > share:
            found.rows[group] = np.flatnonzero(bad)
            found.samples[group] = int(measured.size)
            found.size.update({c: v for c, v in worst.items() if v > 0})
    return found


def drop_outliers(log: FlightLog) -> FlightLog:
    """``log`` with its pose channels' isolated glitches (:func:`find_outliers`) not measured
    (NaN), with a note naming them; ``log`` itself when there are none."""
    found = find_outliers(log)
    if not found:
        return log
    Y = log.outputs.copy()
    for group, rows in found.rows.items():
        cols = [log.output_names.index(c) for c in OUTLIER_GROUPS[group] if c in log.output_names]
        Y[np.ix_(rows, cols)] = np.nan
    note = f"{log.source or 'log'}: {found.describe(log.t)}: left out as glitches (--outliers keep keeps them)"
    return FlightLog(log.t, log.inputs, list(log.input_names), Y, list(log.output_names), dict(log.extras),
                     log.notes + [note], log.source, dict(log.input_noise_left))

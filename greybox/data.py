"""Flight logs (README, "Flight log (CSV)"): load, validate, save, split, resample.

A log is one CSV with a header row. Inputs (``w1..wN`` rad/s, or ``u1..u4``) and ``t``
are present on every row; output columns (``x,y,z`` world NED, ``phi,theta,psi``, optional
``p,q,r``) may be empty or ``nan`` where a sensor gave no sample (multi-rate logs).
Every problem with a file is one :class:`~greybox.errors.GreyboxInputError` naming the
file, the row (1-based line number in the file) and the column.
"""
from __future__ import annotations

import csv
import difflib
import io
import math
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from .errors import GreyboxInputError

__all__ = ["FlightLog", "check_distinct_flights", "flight_label", "parse_time_window", "load_log", "is_log_column", "save_log", "read_csv_table", "read_text_file", "atomic_write",
           "ATOMIC_NAME_EXTRA", "log_from_table",
           "check_sample_times", "REQUIRED_OUTPUTS", "OPTIONAL_OUTPUTS", "MAX_ROTOR_SPEED",
           "MAX_MEDIAN_STEP", "MAX_GAP", "MAX_DURATION", "check_rotor_speed_units", "rotor_speed_magnitudes",
           "median_row_interval",
           "check_measurement_units", "unwrap_heading", "flip_passages", "FLIP_PITCH", "FLIP_CUT_PITCH",
           "FLIP_MARGIN_S", "FLIP_MIN_PIECE_S", "ROLL_WRAP_TOLERANCE", "EULER_PITCH_RANGE",
           "CLIP_FLOORS", "CLIP_MIN_RUN", "clipped_samples", "inside_gaps", "FlipSplit", "split_flips", "UNIT_RATIO_LIMIT", "check_channel_noise", "RECORD_EXTRAS", "is_command_column"]

REQUIRED_OUTPUTS = ["x", "y", "z", "phi", "theta", "psi"]
OPTIONAL_OUTPUTS = ["p", "q", "r", "ax", "ay", "az"]
RECORD_EXTRAS = frozenset({"t_unix", "motor_fresh", "on_ground"})
"""Extra columns the importers keep for the record (the logger's clock, which rows hold a
fresh motor sample, ground contact): bookkeeping, never a physical signal."""


def is_command_column(name: str) -> bool:
    """Whether an extra column holds the rotors' commands beside the inputs (``u1..``,
    ``w1..``, the importers' raw ``pwm1..``): what the controller sent, not a signal acting
    on the vehicle beside them."""
    return re.fullmatch(r"(?:[uw]|pwm)\d+", name) is not None


MAX_ROTOR_SPEED = 8000.0
"""rad/s (about 76,000 RPM). Faster "rotor speeds" are taken for RPM or another unit."""
MIN_FIT_SAMPLES = 50
MAX_MEDIAN_STEP = 0.2
"""s. A flight log samples its inputs at 5 Hz or faster (real ones at 50 Hz and more); a
slower median step means the time column is in another unit (milliseconds, microseconds)."""
MAX_GAP = 10.0
"""s. A longer pause between two rows is refused (split the log there); shorter gaps are
filled with held-input rows (see :meth:`FlightLog.fill_gaps`)."""
MAX_DURATION = 6 * 3600.0
"""s. Longer than any battery flight; a longer span is a unit mistake or a corrupt time stamp."""
GAP_FILL_FACTOR = 3.0
"""Steps longer than this many median steps are filled by :meth:`FlightLog.fill_gaps`."""
OUTPUT_LIMITS = {"x": (1e5, "m"), "y": (1e5, "m"), "z": (1e5, "m"),
                 "phi": (4 * math.pi, "rad"), "theta": (4 * math.pi, "rad"), "psi": (1e4, "rad"),
                 "p": (1e3, "rad/s"), "q": (1e3, "rad/s"), "r": (1e3, "rad/s"),
                 "ax": (2e3, "m/s^2"), "ay": (2e3, "m/s^2"), "az": (2e3, "m/s^2")}
"""Largest plausible magnitude of each output; a larger value is a corrupt cell or a unit
mistake (degrees for radians), named with its row rather than left to make a fit diverge."""


@dataclass
class FlightLog:
    """A (possibly multi-rate) flight log.

    Attributes:
        t: (n,) sample times, s, strictly increasing.
        inputs: (n, nu) rotor speeds (rad/s) or control inputs, never missing.
        input_names: ``w1..wN`` or ``u1..u4``.
        outputs: (n, ny) measurements, NaN where not measured.
        output_names: subset of ``x,y,z,phi,theta,psi,p,q,r`` in that order.
        extras: other columns (e.g. ``vbat``, or ``u1..u4`` beside rotor speeds).
        notes: remarks made while loading (ignored columns...).
        source: file name, if read from one.
        input_noise_left: per input column smoothed since it was logged
            (:func:`~greybox.fitting.input_errors.denoise_inputs`), the standard deviation of
            the noise the smoother left in it (in the band of the signal, coloured):
            what the smoothed column's own differences no longer show, and what still stands
            between the inputs the model is fed and what the rotors did. Empty for inputs as
            logged.

    Example::

        from greybox import load_log
        log = load_log("greybox/data/logs/demo_ground_effect.csv")
        len(log), log.duration, log.input_names     # 6001, 30.0, ['w1', 'w2', 'w3', 'w4']
        est, val = log.split(0.8)                   # first 80 % / last 20 % in time
        df = log.to_dataframe()                     # pandas; FlightLog.from_dataframe(df) back
    """

    t: np.ndarray
    inputs: np.ndarray
    input_names: list[str]
    outputs: np.ndarray
    output_names: list[str]
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    source: str | None = None
    input_noise_left: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float).ravel()
        self.inputs = np.asarray(self.inputs, dtype=float).reshape(self.t.size, -1)
        self.outputs = np.asarray(self.outputs, dtype=float).reshape(self.t.size, -1)

    def __len__(self) -> int:
        return self.t.size

    def __repr__(self) -> str:
        from .display import flightlog_text
        return flightlog_text(self)

    def _repr_html_(self) -> str:
        from .display import flightlog_html
        return flightlog_html(self)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self) else 0.0

    def output(self, name: str) -> np.ndarray:
        """One output column (NaN where not measured)."""
        try:
            return self.outputs[:, self.output_names.index(name)]
        except ValueError:
            raise GreyboxInputError(f"{self.source or 'log'}: has no output column {name!r}") from None

    def measures(self, name: str) -> bool:
        """Whether the log has output column ``name`` with at least one measurement."""
        return name in self.output_names and bool(np.isfinite(self.output(name)).any())

    def input(self, name: str) -> np.ndarray:
        return self.inputs[:, self.input_names.index(name)]

    def fresh_input_rows(self) -> np.ndarray:
        """Rows whose logged commands are fresh samples: those an importer marked so (the
        ``motor_fresh`` column), else every row. A row between fresh samples (held, or
        interpolated by the importer) carries no noise of its own, so a noise level read from
        every row's differences comes out low (a blind audit's commands refreshed at 83 Hz on
        a 100-Hz grid, interpolated: 5.5 rad/s read over every row, 8.1 over the fresh ones, as
        the same commands logged fresh at every row give)."""
        fresh = self.extras.get("motor_fresh")
        if fresh is None or len(fresh) != len(self):
            return np.ones(len(self), dtype=bool)
        mask = np.asarray(fresh, dtype=float) > 0.5
        return mask if mask.sum() >= 5 else np.ones(len(self), dtype=bool)

    def rate(self, name: str) -> float:
        """Mean measurement rate of a channel (Hz), counting only measured samples."""
        y = self.output(name)
        k = np.flatnonzero(np.isfinite(y))
        if k.size < 2:
            return 0.0
        return float((k.size - 1) / (self.t[k[-1]] - self.t[k[0]]))

    def slice(self, start: int, stop: int) -> "FlightLog":
        """Rows ``start:stop`` as a new log (times kept as they are)."""
        return FlightLog(self.t[start:stop].copy(), self.inputs[start:stop].copy(),
                         list(self.input_names), self.outputs[start:stop].copy(),
                         list(self.output_names),
                         {k: v[start:stop].copy() for k, v in self.extras.items()},
                         list(self.notes), self.source, dict(self.input_noise_left))

    def between(self, t0: float | None = None, t1: float | None = None, where: str = "") -> "FlightLog":
        """The rows with ``t0 <= t <= t1`` (either end None: open), with a note; a window that
        holds fewer than two rows is refused, naming ``where`` (or the log's source) and the
        log's own time span. Diagnose the parts of a flight before and after a rotor changed
        apart: ``log.between(None, 19.5)``, ``log.between(19.9)`` (``--time :19.5``)."""
        name = where or self.source or "the log"
        if t0 is not None and t1 is not None and not t0 < t1:
            raise GreyboxInputError(f"{name}: --time {t0:g}:{t1:g} is empty (its start must come before its end)")
        keep = np.ones(len(self), dtype=bool)
        if t0 is not None:
            keep &= self.t >= t0
        if t1 is not None:
            keep &= self.t <= t1
        idx = np.flatnonzero(keep)
        if idx.size < 2:
            span = f"{self.t[0]:g}..{self.t[-1]:g} s" if len(self) else "no rows"
            raise GreyboxInputError(f"{name}: --time {_window_text(t0, t1)} holds {idx.size} of its rows "
                                    f"(its times run {span})")
        out = self.slice(int(idx[0]), int(idx[-1]) + 1)
        if idx.size < len(self):
            out.notes.append(f"rows t = {out.t[0]:g}..{out.t[-1]:g} s kept ({idx.size} of {len(self)}; "
                             f"--time {_window_text(t0, t1)})")
        return out

    def same_flight(self, other: "FlightLog") -> bool:
        """Whether ``other`` holds the same samples (times, inputs and outputs, NaN for NaN):
        a copy of this flight, whatever its file is called."""
        return (len(self) == len(other) and list(self.input_names) == list(other.input_names)
                and list(self.output_names) == list(other.output_names) and np.array_equal(self.t, other.t)
                and np.array_equal(self.inputs, other.inputs, equal_nan=True)
                and np.array_equal(self.outputs, other.outputs, equal_nan=True))

    def split(self, fraction: float = 0.8) -> tuple["FlightLog", "FlightLog"]:
        """Estimation part (first ``fraction`` of the samples) and validation part (the rest).

        The two share the boundary sample, so the validation part starts where the
        estimation part ends.
        """
        if not 0 < fraction < 1:
            raise GreyboxInputError(f"split fraction must be in (0, 1), got {fraction}")
        k = int(round(fraction * (len(self) - 1)))
        return self.slice(0, k + 1), self.slice(k, len(self))

    def resample(self, dt: float, max_gap: float | None = None) -> "FlightLog":
        """The log on a uniform grid of step ``dt``.

        Inputs are zero-order held (as the model sees them). Each output is linearly
        interpolated between its own measured samples where they are at most ``max_gap``
        apart (default: 3 times that channel's median spacing); elsewhere NaN. To decimate
        a fast channel without interpolating, use a ``dt`` that is a multiple of its period.
        """
        if dt <= 0:
            raise GreyboxInputError(f"resample step must be positive, got {dt}")
        tn = np.arange(self.t[0], self.t[-1] + 1e-9 * dt, dt)
        idx = np.clip(np.searchsorted(self.t, tn, side="right") - 1, 0, len(self) - 1)
        U = self.inputs[idx]
        Y = np.full((tn.size, len(self.output_names)), np.nan)
        for j in range(len(self.output_names)):
            k = np.flatnonzero(np.isfinite(self.outputs[:, j]))
            if k.size < 2:
                continue
            tk, yk = self.t[k], self.outputs[k, j]
            gap = max_gap if max_gap is not None else 3 * float(np.median(np.diff(tk)))
            yi = np.interp(tn, tk, yk)
            pos = np.clip(np.searchsorted(tk, tn), 1, tk.size - 1)
            near_exact = np.isclose(tn, tk[pos - 1], atol=1e-9 * dt) | np.isclose(tn, tk[pos], atol=1e-9 * dt)
            ok = ((tk[pos] - tk[pos - 1] <= gap) & (tn >= tk[0] - 1e-12) & (tn <= tk[-1] + 1e-12)) | near_exact
            Y[ok, j] = yi[ok]
        extras = {k: v[idx] for k, v in self.extras.items()}
        return FlightLog(tn, U, list(self.input_names), Y, list(self.output_names), extras,
                         list(self.notes), self.source, dict(self.input_noise_left))

    def fill_gaps(self, factor: float = GAP_FILL_FACTOR) -> "FlightLog":
        """The log with rows inserted in every step longer than ``factor`` median steps:
        inputs and extras held, outputs not measured (NaN).

        The model holds inputs between samples anyway, so this changes nothing it computes;
        it only bounds the sample-step functions' branches (:class:`~greybox.integrate.Substeps`:
        one per multiple of the usual sub-step count, up to the longest step's), which a
        dropout of a second in a 1-kHz log would make a thousand.
        """
        if len(self) < 3:
            return self
        dt = np.diff(self.t)
        step = float(np.median(dt))
        long = np.flatnonzero(dt > factor * step)
        if long.size == 0:
            return self
        pieces = []
        last = 0
        for k in long:
            pieces.append(np.arange(last, k + 1))
            n_new = int(math.ceil(dt[k] / step)) - 1
            pieces.append(np.full(n_new, -1 - k))   # marker: inserted after row k
            last = k + 1
        pieces.append(np.arange(last, len(self)))
        src = np.concatenate(pieces)
        inserted = src < 0
        held = np.where(inserted, -1 - src, src)
        t = self.t[held].copy()
        # inserted times: evenly spaced inside their gap
        for k in long:
            sel = np.flatnonzero(src == -1 - k)
            t[sel] = self.t[k] + dt[k] * (np.arange(1, sel.size + 1) / (sel.size + 1))
        Y = self.outputs[held].copy()
        Y[inserted] = np.nan
        note = (f"{self.source or 'log'}: {long.size} gap(s) longer than {factor:g} median steps "
                f"({step:.4g} s; the longest {dt.max():.4g} s at t = {self.t[long[np.argmax(dt[long])]]:.6g} s) "
                f"filled with {int(inserted.sum())} rows of held inputs and no measurements")
        return FlightLog(t, self.inputs[held], list(self.input_names), Y, list(self.output_names),
                         {n: v[held] for n, v in self.extras.items()}, self.notes + [note], self.source,
                         dict(self.input_noise_left))

    @classmethod
    def from_dataframe(cls, df, inputs: str = "auto", optional: Iterable[str] = (),
                       source: str | None = None) -> "FlightLog":
        """A flight log from a pandas DataFrame with the CSV's columns (README, "Flight log
        (CSV)"): ``t``, ``w1..wN`` (or ``u1..u4``), ``x, y, z, phi, theta, psi``, optionally
        ``p, q, r``, any others kept as extras; NaN (or ``None``/``pd.NA``) where an output
        was not measured.

        It is checked exactly as :func:`load_log` checks a file (same options), and errors
        name the row by its DataFrame index (``row index 17``) and the column. A ``t`` held
        in the index (``df.set_index("t")``) is taken from there. ``source`` names the log
        in messages and becomes ``log.source`` (default ``"DataFrame"``). Needs pandas
        (``pip install pandas``).

        Example::

            import pandas as pd
            from greybox import FlightLog
            df = pd.read_csv("greybox/data/logs/demo_ground_effect.csv")   # or any DataFrame
            log = FlightLog.from_dataframe(df)
            df2 = log.to_dataframe()                    # and back
        """
        pd = _pandas("FlightLog.from_dataframe")
        if not isinstance(df, pd.DataFrame):
            raise GreyboxInputError(f"FlightLog.from_dataframe: expected a pandas DataFrame, got "
                                    f"{type(df).__name__}")
        where = source or "DataFrame"
        labels = df.index
        if "t" not in df.columns and df.index.name == "t":
            df = df.reset_index()
        header = []
        for c in df.columns:
            if not isinstance(c, str):
                raise GreyboxInputError(f"{where}: column names must be strings like 't', 'w1', 'x'; "
                                        f"got {c!r}")
            header.append(c.strip())
        seen = set()
        for h in header:
            if h in seen:
                raise GreyboxInputError(f"{where}: column {h!r} appears twice")
            seen.add(h)
        if len(df) == 0:
            raise GreyboxInputError(f"{where}: no data rows")
        rows = np.asarray(["index " + str(i) for i in labels], dtype=object)
        data = np.empty((len(df), len(header)))
        text = []
        for j, name in enumerate(header):
            s = df.iloc[:, j]
            if s.dtype.kind in "mM":
                if not is_log_column(name):     # an extra of dates: left out, as a text column
                    text.append(j)
                    continue
                raise GreyboxInputError(f"{where}: column {name!r} holds dates or durations; give "
                                        "seconds (e.g. (df.t - df.t.iloc[0]).dt.total_seconds())")
            try:
                data[:, j] = s.to_numpy(dtype=float, na_value=np.nan)
            except (TypeError, ValueError):
                if not is_log_column(name) and not any(_numeric_cell(v) for v in s.to_numpy(dtype=object)):
                    text.append(j)              # an extra column of text only: left out, as in a CSV
                    continue
                for k, v in enumerate(s.to_numpy(dtype=object)):
                    try:
                        float(v if v is not None and v is not pd.NA else "nan")
                    except (TypeError, ValueError):
                        raise GreyboxInputError(f"{where}: row {rows[k]}, column {name!r}: not a number: "
                                                f"{v!r}") from None
                raise GreyboxInputError(f"{where}: column {name!r}: not numbers ({s.dtype})") from None
        keep = [j for j in range(len(header)) if j not in text]
        log = log_from_table([header[j] for j in keep], data[:, keep], rows, where, inputs, optional)
        if text:
            log.notes.append(f"{where}: ignored text column(s) {', '.join(header[j] for j in text)}")
        return log

    def to_dataframe(self):
        """The log as a pandas DataFrame with the CSV's columns: ``t``, the inputs, the
        outputs (NaN where not measured), then the extras; one row per sample, a default
        index. :meth:`from_dataframe` reads it back. Needs pandas (``pip install pandas``).

        Example::

            from greybox import load_log
            df = load_log("greybox/data/logs/demo_ground_effect.csv").to_dataframe()
            df.plot(x="t", y=["x", "z"])
        """
        pd = _pandas("FlightLog.to_dataframe")
        cols = {"t": self.t.copy()}
        cols.update({n: self.inputs[:, j].copy() for j, n in enumerate(self.input_names)})
        cols.update({n: self.outputs[:, j].copy() for j, n in enumerate(self.output_names)})
        cols.update({n: np.asarray(v, dtype=float).copy() for n, v in self.extras.items() if n not in cols})
        return pd.DataFrame(cols)

    def check_fittable(self, min_samples: int = MIN_FIT_SAMPLES) -> None:
        """Raise a clear error if the log is too short or too sparse to fit a model to."""
        where = self.source or "log"
        if len(self) < min_samples:
            raise GreyboxInputError(f"{where}: log too short to fit: {len(self)} samples, need at "
                                    f"least {min_samples}")
        for name in REQUIRED_OUTPUTS:
            if name in ("x", "y", "z") and not self.measures(name):
                imu = [c for c in ("p", "q", "r", "az") if not self.measures(c)]
                need = f"{where}: column {name!r} is empty: fitting the full model needs position (vision, motion capture)"
                some = [c for c in ("x", "y", "z") if self.measures(c)]
                if some:    # neither fit takes a partial position (a barometer's z alone)
                    raise GreyboxInputError(
                        need + f"; it has position in {', '.join(some)} only, which neither fit takes: the full model "
                        "needs x, y and z, the fit from the IMU alone (gyro p, q, r and accelerometer az) none"
                        + (f" (this log has no {', '.join(imu)} for it)" if imu else
                           f": empty the column{'s' if len(some) > 1 else ''} {', '.join(some)} to fit from the IMU "
                           "alone (README, 'Fitting an IMU-only log')"))
                raise GreyboxInputError(
                    need + "; this log has gyro and accelerometer, so `greybox fit` (greybox.fitting.fit_imu) "
                    "identifies what its IMU alone can: K_T, b, tau_m and the torque gains g_x, g_y (README, "
                    "'Fitting an IMU-only log')" if not imu
                    else need + "; a log without position is fitted from its IMU alone when it has the gyro p, q, r "
                    f"and the accelerometer az (missing here: {', '.join(imu)})")
            est, _ = self.split()
            n = int(np.isfinite(est.output(name)).sum())
            if n < 5:
                raise GreyboxInputError(f"{where}: log too short to fit: column {name!r} has only {n} "
                                        "measurements in the estimation part (first 80 %), need 5")


def _pandas(what: str):
    """pandas, imported only where a DataFrame is asked for (it is an optional dependency)."""
    try:
        import pandas
    except ImportError:
        raise ImportError(f"{what} needs pandas, which is not installed: pip install pandas") from None
    return pandas


ATOMIC_NAME_EXTRA = len(".") + len(".") + 8 + len(".tmp")
"""Bytes the temporary of :func:`atomic_write` adds to the file's name: a dot before it, then a
dot, mkstemp's eight random characters and ``.tmp`` after it (14). A name within this of the
file system's limit cannot be written, so the command line refuses it before any work."""


def atomic_write(path: str | Path, text: str | bytes) -> None:
    """Write ``text`` (or bytes) to ``path`` through a temporary file and a rename: readers
    never see a half-written file, and a crash leaves the old file (or none)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp's 0600 would make results private to one user
    try:
        with (os.fdopen(fd, "wb") if isinstance(text, bytes)
              else os.fdopen(fd, "w", encoding="utf-8", newline="")) as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def read_text_file(path: str | Path, what: str = "", encoding: str = "utf-8") -> str:
    """The text of a file the user named, or one error naming it: ``{path}: {what} file not
    found`` / ``cannot read {what} file: ...`` (``what`` e.g. ``"airframe"``, or empty)."""
    path = Path(path)
    kind = f"{what} file" if what else "file"
    try:
        return path.read_text(encoding=encoding)
    except FileNotFoundError:
        raise GreyboxInputError(f"{path}: {kind} not found") from None
    except UnicodeDecodeError as e:
        # a binary file given where text is read (a .ulg or uSD log for a CSV): say so plainly
        line = path.read_bytes()[:e.start].count(b"\n") + 1
        hint = "" if what else ": a binary log needs its importer (greybox import px4 | crazyflie-usd)"
        raise GreyboxInputError(f"{path}: not a text {kind} (byte {e.start}, line {line}, "
                                f"is not {encoding}){hint}") from None
    except OSError as e:
        raise GreyboxInputError(f"{path}: cannot read{' ' + kind if what else ''}: {e.strerror or e}") from None


def read_csv_table(path: str | Path, line_numbers: bool = False,
                   must_be_numeric: Callable[[str], bool] | None = None,
                   text_columns: list[str] | None = None):
    """Header and float matrix of a numeric CSV file; empty cells and ``nan`` become NaN.

    With ``line_numbers``, also the line of the file each data row starts on (a quoted
    cell may span lines), for messages that name a row. Errors name the file, the line
    number and the column of the first bad cell. With ``must_be_numeric``, a column it
    says need not be (an extra column a user added: a flight mode, a comment) that holds
    text is left out of the table, its name appended to ``text_columns``.
    """
    path = Path(path)
    text = read_text_file(path, encoding="utf-8-sig")
    rows, lines = _csv_rows(path, text)
    while rows and not any(c.strip() for c in rows[-1]):
        rows.pop()
    if not rows:
        raise GreyboxInputError(f"{path}: empty file (no header row)")
    lines = lines[:len(rows)]
    header = [h.strip() for h in rows[0]]
    if len(header) == 1:
        sep = next((c for c in (";", "\t", "|") if c in header[0]), None)
        if sep is not None:
            raise GreyboxInputError(f"{path}: row 1 is one column holding {sep!r}: the file is separated by "
                                    f"{'tabs' if sep == chr(9) else repr(sep)}, greybox reads comma-separated CSV")
    if any(not h for h in header):
        raise GreyboxInputError(f"{path}: row 1: empty column name in the header "
                                f"(column {header.index('') + 1})")
    if all(_is_number(h) for h in header):
        raise GreyboxInputError(f"{path}: row 1 is numbers, not a header of column names")
    seen = set()
    for h in header:
        if h in seen:
            raise GreyboxInputError(f"{path}: row 1: column {h!r} appears twice")
        seen.add(h)
    data = np.empty((len(rows) - 1, len(header)))
    # an extra column (must_be_numeric says so) whose cells are all text is a text column, left
    # out; one that mixes numbers and text is a numeric column with a bad cell, an error (a
    # battery voltage with one "n/a" must not vanish); true/false in an extra column read 1/0
    first_text: dict[int, tuple[int, str]] = {}
    has_number: set[int] = set()
    for k, (i, row) in enumerate(zip(lines[1:], rows[1:])):
        if len(row) != len(header):
            raise GreyboxInputError(f"{path}: row {i}: {len(row)} cells, the header has {len(header)}")
        for j, cell in enumerate(row):
            c = cell.strip()
            if c == "" or c.lower() == "nan":
                data[k, j] = np.nan
                continue
            try:
                v = float(c)
            except ValueError:
                extra = must_be_numeric is not None and not must_be_numeric(header[j])
                if extra and c.lower() in ("true", "false"):
                    v = 1.0 if c.lower() == "true" else 0.0
                elif extra:
                    first_text.setdefault(j, (i, c))
                    data[k, j] = np.nan
                    continue
                else:
                    raise GreyboxInputError(f"{path}: row {i}, column {header[j]!r}: not a number: {c!r}") from None
            if math.isinf(v):
                raise GreyboxInputError(f"{path}: row {i}, column {header[j]!r}: infinite value {c!r}")
            data[k, j] = v
            has_number.add(j)
    for j, (i, c) in sorted(first_text.items(), key=lambda item: item[1][0]):
        if j in has_number:
            raise GreyboxInputError(f"{path}: row {i}, column {header[j]!r}: not a number: {c!r}")
    if first_text:
        keep = [j for j in range(len(header)) if j not in first_text]
        if text_columns is not None:
            text_columns += [header[j] for j in sorted(first_text)]
        header, data = [header[j] for j in keep], data[:, keep]
    return (header, data, np.asarray(lines[1:], dtype=int)) if line_numbers else (header, data)


def _csv_rows(path: Path, text: str) -> tuple[list[list[str]], list[int]]:
    """Rows of a CSV text and the line each starts on; malformed CSV (an unbalanced quote, a
    cell longer than the csv module allows) is one error naming the line."""
    reader = csv.reader(io.StringIO(text))
    rows: list[list[str]] = []
    lines: list[int] = []
    start = 1
    try:
        for row in reader:
            if reader.line_num > start and any("\n" in c or "\r" in c for c in row):
                raise GreyboxInputError(
                    f"{path}: row {start}: a quote (\") opened here is closed only on line "
                    f"{reader.line_num}: unbalanced quote")
            rows.append(row)
            lines.append(start)
            start = reader.line_num + 1
    except csv.Error as e:
        why = ("a cell longer than the CSV reader's limit (an unbalanced quote?)"
               if "field limit" in str(e) else f"malformed CSV ({e})")
        raise GreyboxInputError(f"{path}: row {start}: {why}") from None
    return rows, lines


def check_distinct_flights(logs: Sequence[FlightLog], what: str = "flights") -> None:
    """Refuse a flight given twice (the same samples under two names): fitted as two flights a
    copy counts as independent evidence, every std shrinking by sqrt(2) (a blind audit's joint
    fit of a flight and its copy)."""
    for j, b in enumerate(logs):
        for a in logs[:j]:
            if a is b or a.same_flight(b):
                raise GreyboxInputError(f"{b.source or 'log'}: the same flight as {a.source or 'another log'} "
                                        f"(the same samples): give each of the {what} once")


def _window_text(t0: float | None, t1: float | None) -> str:
    return f"{'' if t0 is None else format(t0, 'g')}:{'' if t1 is None else format(t1, 'g')}"


def parse_time_window(text: str, option: str = "--time") -> tuple[float | None, float | None]:
    """``"T0:T1"`` (seconds; either end may be left out: ``"20:"``, ``":19.5"``) as
    ``(t0, t1)``, for :meth:`FlightLog.between`; one error naming ``option`` otherwise."""
    parts = text.split(":")
    if len(parts) != 2 or not any(p.strip() for p in parts):
        raise GreyboxInputError(f"{option}: {text!r} is not T0:T1 (seconds; e.g. 5:30, 20: or :19.5)")
    out = []
    for p in parts:
        p = p.strip()
        if not p:
            out.append(None)
            continue
        try:
            v = float(p)
        except ValueError:
            raise GreyboxInputError(f"{option}: {p!r} in {text!r} is not a number of seconds") from None
        if not np.isfinite(v):
            raise GreyboxInputError(f"{option}: {p!r} in {text!r} is not a finite number of seconds")
        out.append(v)
    if out[0] is not None and out[1] is not None and not out[0] < out[1]:
        raise GreyboxInputError(f"{option}: {text!r} is empty (its start must come before its end)")
    return out[0], out[1]


def flight_label(log: FlightLog, k: int) -> str:
    """A flight in words: the file it was read from, else its place among several (``flight 2``
    for ``k = 1``)."""
    return log.source or f"flight {k + 1}"


def median_row_interval(logs: Iterable[FlightLog]) -> float:
    """The median time between consecutive rows over ``logs``, s."""
    return float(np.median(np.concatenate([np.diff(lg.t) for lg in logs])))


def check_sample_times(t: np.ndarray, where: str, rows: np.ndarray | None = None) -> None:
    """Raise a :class:`GreyboxInputError` naming the row if the time column is not a flight
    log's: not strictly increasing, a median step above :data:`MAX_MEDIAN_STEP` (said to
    look like milliseconds or microseconds when it does), a gap above :data:`MAX_GAP`, or a
    span above :data:`MAX_DURATION`. ``rows[k]`` is the file line of sample ``k`` (default
    ``k + 2``: a header line, one row per line)."""
    t = np.asarray(t, dtype=float)
    rows = np.arange(t.size) + 2 if rows is None else np.asarray(rows)
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise GreyboxInputError(f"{where}: row {rows[bad[0]]}, column 't': time is not a finite number")
    if t.size < 2:
        return
    with np.errstate(over="ignore", invalid="ignore"):
        dt = np.diff(t)
    bad = np.flatnonzero(~(dt > 0))
    if bad.size:
        k = bad[0]
        raise GreyboxInputError(f"{where}: row {rows[k + 1]}, column 't': time {t[k + 1]:.10g} is not "
                                f"after the previous row's {t[k]:.10g} (t must be strictly increasing)")
    step = float(np.median(dt))
    if step > MAX_MEDIAN_STEP:
        unit = (" - it looks like milliseconds: divide t by 1000" if 0.5 <= step <= 100 else
                " - it looks like microseconds: divide t by 1e6" if 500 <= step <= 1e5 else "")
        raise GreyboxInputError(f"{where}: column 't': median time step {step:.4g} s, but a flight log "
                                f"samples at {1 / MAX_MEDIAN_STEP:g} Hz or faster{unit}")
    k = int(np.argmax(dt))
    if not np.isfinite(dt[k]) or dt[k] > MAX_GAP:
        raise GreyboxInputError(f"{where}: row {rows[k + 1]}, column 't': time jumps by {dt[k]:.4g} s "
                                f"from the previous row (longest gap allowed {MAX_GAP:g} s): a corrupt "
                                "time stamp, or two flights in one file - split the log there")
    span = t[-1] - t[0]
    if not np.isfinite(span) or span > MAX_DURATION:
        raise GreyboxInputError(f"{where}: column 't': the log spans {span:.4g} s, more than "
                                f"{MAX_DURATION / 3600:g} h - is t in seconds?")


def _numeric_cell(v: object) -> bool:
    """Whether a DataFrame cell holds a number (a missing one, None, NaN or pd.NA, does not)."""
    try:
        return not math.isnan(float(v))
    except (TypeError, ValueError):
        return False


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


_W = re.compile(r"^w(\d+)$")
_U = re.compile(r"^u([1-4])$")


def _case_hint(header: list[str], name: str) -> str:
    """" (the header has 'T': column names are lower-case)" when a column differs in case only."""
    other = next((h for h in header if h.strip().lower() == name and h != name), None)
    return f" (the header has {other!r}: column names are lower-case, without spaces)" if other else ""


_SYNONYMS = {"t": ("time", "timestamp", "time_s"), "phi": ("roll",), "theta": ("pitch",), "psi": ("yaw", "heading"),
             "p": ("roll_rate", "gx", "gyro_x"), "q": ("pitch_rate", "gy", "gyro_y"), "r": ("yaw_rate", "gz", "gyro_z")}
"""Names other tools give a log column (:func:`_unknown_hint`)."""


def _unknown_hint(header: list[str], name: str) -> str:
    """" (the header has 'yaw', which is no column of the format: is it 'psi'?)" for a missing
    column ``name`` where the header has columns the format does not know (at most six named)."""
    unknown = [h for h in header if not is_log_column(h)]
    if not unknown:
        return ""
    same = next((h for h in unknown if h.strip().lower() in _SYNONYMS.get(name, ())), None)
    if same is not None:
        return f" (the header has {same!r}, which is no column of the format: is it {name!r}?)"
    shown = ", ".join(repr(h) for h in unknown[:6]) + (", …" if len(unknown) > 6 else "")
    which = "is no column of the format: is it" if len(unknown) == 1 else "are no columns of the format: is one of them"
    return f" (the header's {shown} {which} {name!r}?)"


_FOREIGN_FORMATS = {"motor_motor_m1": "nanobench"}
"""A column that marks a file as another format's (its importer, ``greybox import``)."""


def _format_hint(header: list[str]) -> str:
    """" (a NanoBench log: convert it with ...)" when the header is another format's."""
    fmt = next((f for c, f in _FOREIGN_FORMATS.items() if c in header), None)
    return (f" (the header is a {fmt} log's: convert it first, greybox import {fmt} FILE --out LOG.csv "
            "--airframe-out A.toml)") if fmt else ""


def load_log(path: str | Path, inputs: str = "auto", optional: Iterable[str] = (), flips: str = "refuse") -> FlightLog:
    """Read and validate a flight log CSV (README, "Flight log (CSV)").

    Args:
        inputs: ``"rotor_speeds"`` (require ``w1..wN``), ``"controls"`` (require ``u1..u4``) or
            ``"auto"`` (rotor speeds when present, else controls).
        optional: required outputs that may be absent here (then all-empty), e.g.
            ``("x", "y", "z")`` for an IMU log that vision positions will be merged into.
        flips: ``"refuse"`` (a flip through +-90 degrees of pitch is an error that names its
            rows: :func:`flip_passages`) or ``"keep"``.

    Example::

        from greybox import load_log
        log = load_log("greybox/data/logs/demo_ground_effect.csv")
        est, val = log.split(0.8)          # estimation and validation parts
        log.output("z"), log.rate("x")     # a channel (NaN where not measured), its rate in Hz
    """
    path = Path(path)
    text: list[str] = []
    header, data, lines = read_csv_table(path, line_numbers=True, must_be_numeric=is_log_column, text_columns=text)
    log = log_from_table(header, data, lines, str(path), inputs, optional, flips=flips)
    if text:
        log.notes.append(f"{path}: ignored text column(s) {', '.join(text)}")
    return log


def is_log_column(name: str) -> bool:
    """Whether ``name`` is a column of the flight log format (contract §2: time, inputs,
    outputs), whose cells must be numbers; any other column is an extra."""
    return name == "t" or bool(_W.match(name) or _U.match(name)) or name in REQUIRED_OUTPUTS \
        or name in OPTIONAL_OUTPUTS


def log_from_table(header: list[str], data: np.ndarray, rows, where: str, inputs: str = "auto",
                   optional: Iterable[str] = (), source: str | None = None, flips: str = "refuse") -> FlightLog:
    """Validate a table of named numeric columns as a flight log and return it (gaps filled).

    The checks :func:`load_log` makes once the CSV is read, shared with
    :meth:`FlightLog.from_dataframe`: required columns, missing times and inputs, non-finite
    cells, sample times (:func:`check_sample_times`), rotor speed units
    (:func:`check_rotor_speed_units`), implausible outputs (:data:`OUTPUT_LIMITS`); then
    dropouts are filled (:meth:`FlightLog.fill_gaps`). ``data`` is ``(n, len(header))``
    with NaN for an empty cell; ``rows[k]`` names data row ``k`` in messages (the file's line
    number, or ``"index <label>"`` for a DataFrame); ``where`` names the file or object.
    A flip (the pitch through +-90 degrees, :func:`flip_passages`) is refused with the rows
    and the way out (``flips="keep"`` takes it as it is); a roll through inverted and a
    heading through +-180 degrees are unwrapped, with a note.
    """
    source = where if source is None else source
    col = {h: j for j, h in enumerate(header)}
    if "t" not in col:
        raise GreyboxInputError(f"{where}: missing required column 't'" +
                                (_case_hint(header, "t") or _unknown_hint(header, "t")))
    w_cols = sorted((int(m.group(1)), h) for h in header if (m := _W.match(h)))
    u_cols = sorted((int(m.group(1)), h) for h in header if (m := _U.match(h)))
    if inputs == "auto":
        inputs = "rotor_speeds" if w_cols else "controls" if u_cols else "rotor_speeds"
    if inputs == "rotor_speeds":
        if not w_cols:
            raise GreyboxInputError(f"{where}: missing required rotor speed columns 'w1'..'w4'" +
                                    (_case_hint(header, "w1") or _format_hint(header)))
        idx = [i for i, _ in w_cols]
        if 0 in idx:
            # a blind audit's w0..w3 ended in an IndexError traceback
            raise GreyboxInputError(f"{where}: column 'w0': rotor speeds are numbered from 1 (w1..wN, in the "
                                    "airframe's rotor order); rename w0..w{} to w1..w{}".format(max(idx), max(idx) + 1))
        if idx != list(range(1, len(idx) + 1)):
            missing = sorted(set(range(1, max(idx) + 1)) - set(idx))
            raise GreyboxInputError(f"{where}: missing required column 'w{missing[0]}' "
                                    f"(rotor speeds must be w1..wN without gaps)")
        in_names = [h for _, h in w_cols]
    elif inputs == "controls":
        if [i for i, _ in u_cols] != [1, 2, 3, 4]:
            have = {i for i, _ in u_cols}
            miss = next(i for i in range(1, 5) if i not in have)
            raise GreyboxInputError(f"{where}: missing required column 'u{miss}'")
        in_names = ["u1", "u2", "u3", "u4"]
    else:
        raise GreyboxInputError(f"inputs must be 'auto', 'rotor_speeds' or 'controls', got {inputs!r}")
    optional = set(optional)
    for name in REQUIRED_OUTPUTS:
        if name not in col and name not in optional:
            raise GreyboxInputError(f"{where}: missing required column {name!r}" +
                                    (_case_hint(header, name) or
                                     (" (a log without position keeps the columns x, y, z, left empty)"
                                      if name in ("x", "y", "z") else _unknown_hint(header, name))))
    out_names = REQUIRED_OUTPUTS + [n for n in OPTIONAL_OUTPUTS if n in col]

    if data.shape[0] == 0:
        raise GreyboxInputError(f"{where}: no data rows after the header")
    inf = np.argwhere(np.isinf(data))
    if inf.size:
        r, c = inf[0]
        raise GreyboxInputError(f"{where}: row {rows[r]}, column {header[c]!r}: infinite value {float(data[r, c])!r}")
    t = data[:, col["t"]]
    for name in ["t"] + in_names:
        bad = np.flatnonzero(np.isnan(data[:, col[name]]))
        if bad.size:
            raise GreyboxInputError(f"{where}: row {rows[bad[0]]}, column {name!r}: missing value "
                                    "(time and inputs may never be missing)")
    check_sample_times(t, where, rows)
    U = data[:, [col[n] for n in in_names]]
    notes = []
    if inputs == "rotor_speeds":
        U, notes = rotor_speed_magnitudes(U, in_names, where)
        notes += check_rotor_speed_units(U, in_names, where, rows)
    Y = np.column_stack([data[:, col[n]] if n in col else np.full(data.shape[0], np.nan)
                         for n in out_names])
    for j, name in enumerate(out_names):
        limit, unit = OUTPUT_LIMITS[name]
        if name == "phi" and "p" in out_names and _continued_roll(t, Y[:, j], Y[:, out_names.index("p")]):
            # a roll the user unwrapped (several rolls one way) passes 4 pi, each step as the roll
            # gyro turned; a corrupt cell or a column in degrees does not step so
            limit = OUTPUT_LIMITS["psi"][0]
        bad = np.flatnonzero(np.abs(Y[:, j]) > limit)
        if bad.size:
            hint = " - is it in degrees?" if unit == "rad" and abs(Y[bad[0], j]) < 400 else ""
            raise GreyboxInputError(f"{where}: row {rows[bad[0]]}, column {name!r}: {Y[bad[0], j]:g} is not "
                                    f"plausible in {unit} (|{name}| <= {limit:g}){hint}")
    for name in CLIP_FLOORS:
        if name in out_names:
            j = out_names.index(name)
            clipped = clipped_samples(Y[:, j], CLIP_FLOORS[name])
            if clipped.any():
                # a MEMS sensor past its full scale logs its limit: fitted as data, a clipped
                # accelerometer put K_T 4 std off and a clipped gyro read as a gyro scale of
                # 0.87 (a blind audit's racer, +-4 g and +-2000 deg/s)
                level = float(np.abs(Y[clipped, j]).max())
                rows_at = np.flatnonzero(clipped)
                Y[clipped, j] = np.nan
                notes.append(f"{where}: column {name!r}: {rows_at.size} sample(s) flat at its range's end "
                             f"(+-{level:.4g}, rows {rows[rows_at[0]]}-{rows[rows_at[-1]]}): a sensor past its full "
                             "scale logs its limit, not the motion; left out as not measured")
    if flips == "refuse" and "theta" in out_names:
        passages = flip_passages(t, *(Y[:, out_names.index(n)] if n in out_names else None
                                      for n in ("phi", "theta", "psi")))
        if passages:
            raise GreyboxInputError(_flip_words(where, t, rows, passages))
    if "phi" in out_names:
        j = out_names.index("phi")
        phi, wraps = unwrap_heading(t, Y[:, j], Y[:, out_names.index("p")] if "p" in out_names else None,
                                    tolerance=ROLL_WRAP_TOLERANCE)
        if wraps:
            # a roll through inverted: logged in (-pi, pi] it jumps by 2 pi, which the model's
            # roll does not (a blind audit's racer rolling 360 degrees: roll residuals 146 times
            # the noise, blamed on the gyro, and --noise phi=3.3 advised)
            Y[:, j] = phi
            notes.append(f"{where}: column 'phi': the roll wraps {wraps} time(s) (a roll through inverted, +-180 "
                         "degrees); unwrapped into a continuous roll, as the model rolls"
                         + (" (each wrap told by the roll gyro p)" if "p" in out_names else ""))
    check_measurement_units(t, Y, out_names, where, U if inputs == "rotor_speeds" else None)
    if "psi" in out_names:
        j = out_names.index("psi")
        psi, wraps = unwrap_heading(t, Y[:, j], Y[:, out_names.index("r")] if "r" in out_names else None)
        if wraps:
            # the model's heading turns continuously: a logged one wrapped to (-pi, pi] jumps by
            # 2 pi at each wrap, which no fit follows (a blind audit's racer spinning in yaw:
            # shooting gaps of 2400 noise scales, b 16 orders off, "not certified")
            Y[:, j] = psi
            notes.append(f"{where}: column 'psi': the heading wraps {wraps} time(s) (a yaw through +-180 degrees); "
                         "unwrapped into a continuous heading, as the model turns"
                         + (" (each wrap told by the yaw gyro r)" if "r" in out_names else ""))
    used = {"t", *in_names, *out_names}
    extra_names = [h for h in header if h not in used]
    extras = {h: data[:, col[h]].copy() for h in extra_names}
    if extra_names:
        # a misspelled optional column is ignored like any extra one: say what it may have meant
        # (an audit's "qq" left the fit without its pitch gyro, with only this note)
        absent = [n for n in OPTIONAL_OUTPUTS if n not in col]
        meant = {h: m[0] for h in extra_names if (m := difflib.get_close_matches(h, absent, n=1, cutoff=0.6))}
        # "ignored" read wrong beside a verdict of battery_voltage, which reads vbat (an audit)
        # and discovery offers a varying one as a feature: a blind audit's column of its simulator's
        # true mass was tried as one, unsaid
        notes.append(f"{where}: extra column(s) {', '.join(extra_names)}: not measured channels; kept as extras, "
                     "read by an effect that uses them (battery_voltage reads vbat) and offered to discovery as "
                     "features where they vary (leave out a column no vehicle would log), unused otherwise"
                     + "".join(f"; did you mean {m!r} for {h!r}?" for h, m in meant.items()))
    return FlightLog(t.copy(), U, in_names, Y, out_names, extras, notes, source).fill_gaps()


def check_channel_noise(noise: Mapping[str, object], where: str) -> dict[str, float]:
    """A channel noise the user gives (fit's ``noise``, ``--noise CH=SD``): each key a log
    channel and each value a positive finite standard deviation in its units; as floats. One
    error naming ``where`` and the entry otherwise."""
    channels = REQUIRED_OUTPUTS + OPTIONAL_OUTPUTS
    out: dict[str, float] = {}
    for ch, value in noise.items():
        if ch not in channels:
            raise GreyboxInputError(f"{where} {ch}={value}: not a log channel; expected CHANNEL=SD with CHANNEL one "
                                    f"of {', '.join(channels)}")
        try:
            sd = float(value)
        except (TypeError, ValueError):
            sd = math.nan
        if not (math.isfinite(sd) and sd > 0):
            raise GreyboxInputError(f"{where} {ch}={value}: the noise must be a positive number (the channel's units)")
        out[ch] = sd
    return out


def check_rotor_speed_units(U: np.ndarray, names: list[str], where: str,
                            rows: np.ndarray | None = None) -> list[str]:
    """Refuse rotor speeds no rotor reaches in rad/s (naming the cell, asking whether they
    are RPM); return notes on what is accepted but odd (negative speeds)."""
    rows = np.arange(U.shape[0]) + 2 if rows is None else rows
    over = np.argwhere(np.abs(U) > MAX_ROTOR_SPEED)
    if over.size:
        r, c = over[0]
        raise GreyboxInputError(
            f"{where}: row {rows[r]}, column {names[c]!r}: rotor speed {U[r, c]:g} is not "
            f"plausible in rad/s (above {MAX_ROTOR_SPEED:g}); is it RPM? rad/s = RPM * pi/30 (eRPM, an ESC's "
            "electrical RPM: rad/s = eRPM * pi / (30 * the motor's pole pairs))")
    neg = np.argwhere(U < 0)
    if neg.size:
        r, c = neg[0]
        return [f"{where}: {len(np.unique(neg[:, 0]))} row(s) have negative rotor speeds (first: row "
                f"{rows[r]}, column {names[c]!r}, {U[r, c]:g}); fitted as logged: the thrust and reaction "
                "torque go with w^2, but the gyroscopic torque with the signed speeds (the spin direction "
                "is the airframe's) - a rotor that turns backwards"]
    return []


def rotor_speed_magnitudes(U: np.ndarray, names: list[str], where: str) -> tuple[np.ndarray, list[str]]:
    """Rotor-speed columns negative on every row where they turn, read as speeds whose sign
    encodes the spin direction (some autopilots log them so): their magnitudes, with a note.
    The airframe's spins give the direction; fitted signed, the gyroscopic torque (``J_r sum
    spin_i w_i``) would take the sign twice (a blind audit's: certified, p and q 38 and 28
    times the noise, validation nrmse 1.24 for 0.09 with magnitudes)."""
    signed = [j for j in range(U.shape[1]) if np.any(U[:, j] < 0) and not np.any(U[:, j] > 0)]
    if not signed:
        return U, []
    U = U.copy()
    U[:, signed] = np.abs(U[:, signed])
    cols = ", ".join(names[j] for j in signed)
    return U, [f"{where}: column{'s' if len(signed) > 1 else ''} {cols} {'are' if len(signed) > 1 else 'is'} "
               "negative on every row: read as the spin direction in the sign and fitted as magnitudes (the "
               "airframe's spins give the direction)"]


UNIT_RATIO_LIMIT = 20.0
"""Two measurements of one motion (the attitude's change and the gyro; the positions'
acceleration and the tilt that drives it) that differ in size by more than this factor are
in different units (degrees are 57.3 radians, millimetres 1000 metres). Real flights give
0.3-1.1 (the ten NanoBench flights, greybox's own); 20 is no vehicle's physics."""
_STANDARD_GRAVITY = 9.80665
_SIGN_MIN_CORRELATION = 0.5
"""An angle's rate and its gyro axis correlated at -this or below (and the slope below 0 by 3
std) turn against each other: a convention mistake (:func:`check_measurement_units`)."""
_UNIT_MIN_CORRELATION = 0.3
_HEADING_WRAP_STEP = 3.0
"""A heading step between two samples at least this large (rad or degrees) is a wrap, not a yaw."""
_TILT_WINDOWS = (0.2, 1.0)
"""Smoothing windows (s) of the tilt check; the one whose correlation is highest is judged."""
_FRAME_MIN_CORRELATION = 0.5
_FRAME_UNEXPLAINED_RATIO = 4.0
"""A reading of the positions' frame or the heading (mirrored, in degrees) is taken over the
log's own when it leaves this many times less of the acceleration unexplained (``1 - rho^2``);
flights along one line give a mirror image a high correlation too (a real one 0.94 against
0.99)."""
_FRAME_NULL_SIGMAS = 3.0
"""... or when the log's own reading correlates less than this many of a correlation's std
under no relation (``1/sqrt(n)`` over ``n`` independent stretches) while another exceeds
:data:`_FRAME_MIN_CORRELATION`."""
_FRAME_CLEARLY_BETTER_SE = 3.0
"""... or when another reading's correlation is above the log's own by this many standard
errors of the difference of two correlations over ``n`` independent stretches (Fisher's
``atanh``, each ``1/sqrt(n - 3)``): a blind audit's flight mostly along x, y mirrored,
correlates 0.92 mirrored and 0.66 as given over 40 stretches (3.4 of them; a 3.7-fold
unexplained share, short of four), and was fitted, certified, with ``Kd[1]`` on its bound."""
_FRAME_MAX_TURN = 30.0
"""Degrees the positions' axes may be turned from the heading's zero (the real flights: 4)."""


CLIP_FLOORS = {"p": 4.0, "q": 4.0, "r": 4.0, "ax": 15.0, "ay": 15.0, "az": 15.0}
"""Smallest magnitude (rad/s, m/s^2) at which a channel flat at its extreme is read as a sensor
clipped at its full scale (:func:`clipped_samples`): just below the narrowest ranges MEMS
parts are set to, +-250 deg/s (4.36 rad/s) and +-2 g."""
CLIP_MIN_RUN = 3
"""Consecutive measured samples exactly at a channel's extreme that make it clipped: a noisy
sensor does not repeat its largest value; one past its full scale holds it."""


def clipped_samples(y: np.ndarray, floor: float) -> np.ndarray:
    """The samples of the channel ``y`` (NaN where not measured) at its largest or smallest
    value, of magnitude at least ``floor``, where that value is held by at least
    :data:`CLIP_MIN_RUN` consecutive measured samples: a sensor clipped at its full scale. A
    boolean mask (all False when nothing is clipped)."""
    y = np.asarray(y, dtype=float)
    out = np.zeros(y.shape, dtype=bool)
    k = np.flatnonzero(np.isfinite(y))
    if k.size < 2 * CLIP_MIN_RUN:
        return out
    v = y[k]
    for extreme in (v.max(), v.min()):
        if abs(extreme) < floor:
            continue
        at = v == extreme
        edges = np.diff(np.concatenate([[0], at.astype(np.int8), [0]]))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        if (stops - starts).max() >= CLIP_MIN_RUN:
            out[k[at]] = True
    return out


def inside_gaps(t: np.ndarray, measured: np.ndarray, factor: float = 3.0) -> np.ndarray:
    """The rows lying inside a gap of a channel (``measured``: the rows where it is) longer
    than ``factor`` times its median spacing, as a boolean mask: there its integral or
    interpolation stands for samples it does not have (a gyro's clipped samples left out, a
    dropout)."""
    k = np.flatnonzero(measured)
    out = np.zeros(t.size, dtype=bool)
    if k.size < 3:
        return out
    step = np.diff(t[k])
    for a in np.flatnonzero(step > factor * float(np.median(step))):
        out[k[a] + 1:k[a + 1]] = True
    return out


ROLL_WRAP_TOLERANCE = 1.0
"""What may be left of a roll's step between two samples, its 2 pi wrap taken out, beyond what
the roll gyro turned (rad), for the step to count as a wrap: a roll in degrees is then left for
the units check to refuse, not unwrapped into nonsense."""
FLIP_PITCH = math.radians(80.0)
"""Measured pitch beyond which a log holds a flip: the contract's ZYX Euler angles are
singular at +-90 degrees (roll and yaw jump by 180 there), and the model's attitude, made of
them, cannot pass through (a blind audit's racer flipping in pitch: "optimum certified" with
b 50 % and every drag 30 % low, std of 0.00 %)."""
EULER_PITCH_RANGE = math.pi / 2 + 0.05
"""Largest measured pitch (rad) read as a ZYX Euler pitch when looking for flips: beyond
+-90 degrees (and a little noise), the column is not one (in degrees, say)."""
FLIP_CUT_PITCH = math.radians(60.0)
"""Pitch below which a flip's passage ends (:func:`flip_passages`): the rows between are cut."""
FLIP_MARGIN_S = 0.1
"""Time cut on each side of a flip's passage (s)."""


def _continued_roll(t: np.ndarray, phi: np.ndarray, p: np.ndarray) -> bool:
    """Whether the roll ``phi`` steps between its measured samples as the roll gyro ``p`` turns
    (within :data:`ROLL_WRAP_TOLERANCE`): a roll continued past +-pi, not a column in degrees or
    one with a corrupt cell."""
    k = np.flatnonzero(np.isfinite(phi))
    ok = np.isfinite(p)
    if k.size < 2 or ok.sum() < 2:
        return False
    rate = np.interp(t, t[ok], p[ok])
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
    return bool(np.all(np.abs(np.diff(phi[k]) - np.diff(integral[k])) <= ROLL_WRAP_TOLERANCE))


def flip_passages(t: np.ndarray, phi: np.ndarray | None, theta: np.ndarray, psi: np.ndarray | None = None,
                  margin: float = FLIP_MARGIN_S) -> list[tuple[int, int]]:
    """The rows ``[start, stop)`` around each flip: a measured pitch beyond :data:`FLIP_PITCH`,
    or roll and yaw both jumping by more than 90 degrees between two attitude samples (the Euler
    angles' branch change at +-90 degrees of pitch, which a sparse attitude may straddle below
    that pitch). Each passage runs to where the measured pitch is back below
    :data:`FLIP_CUT_PITCH`, and ``margin`` seconds more on each side; overlapping ones merge.
    Empty for a flight without flips, and for a pitch beyond :data:`EULER_PITCH_RANGE` (not
    a ZYX pitch in radians)."""
    theta = np.asarray(theta, dtype=float)
    k = np.flatnonzero(np.isfinite(theta))
    if k.size == 0 or np.abs(theta[k]).max() > EULER_PITCH_RANGE:
        return []        # not a ZYX pitch in radians (degrees, say): the units checks say so
    steep = np.zeros(t.size, dtype=bool)
    steep[k[np.abs(theta[k]) > FLIP_PITCH]] = True
    if phi is not None and psi is not None:
        both = k[np.isfinite(np.asarray(phi)[k]) & np.isfinite(np.asarray(psi)[k])]
        if both.size > 1:
            jump = (_angle_steps(np.asarray(phi)[both]) > np.pi / 2) & (_angle_steps(np.asarray(psi)[both]) > np.pi / 2)
            steep[both[1:][jump]] = True
            steep[both[:-1][jump]] = True
    if not steep.any():
        return []
    # the stretches of consecutive pitch samples tilted beyond the cut's pitch (or steep),
    # those holding a steep one (a sparse attitude's rows between its samples are not looked at)
    steep_k = steep[k]
    tilted_k = steep_k | (np.abs(theta[k]) >= FLIP_CUT_PITCH)
    edges = np.diff(np.concatenate([[0], tilted_k.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    held = np.concatenate([[0], np.cumsum(steep_k)])
    out: list[tuple[int, int]] = []
    for a, b in zip(starts, stops):
        if held[b] == held[a]:
            continue
        start = int(np.searchsorted(t, t[k[a]] - margin, side="left"))
        stop = int(np.searchsorted(t, t[k[b - 1]] + margin, side="right"))
        if out and start <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], stop))
        else:
            out.append((start, stop))
    return out


def _angle_steps(a: np.ndarray) -> np.ndarray:
    """The size of each step of the angle ``a`` between consecutive samples, wrapped into
    [0, pi] (a wrap of 2 pi is no step)."""
    return np.abs(np.angle(np.exp(1j * np.diff(a))))


FLIP_MIN_PIECE_S = 1.0
"""Shortest piece between flips :func:`split_flips` keeps (s): a fit needs its start-state
window and some motion after it."""


@dataclass
class FlipSplit:
    """A log cut at its flips (:func:`split_flips`): ``pieces`` (first row, end row, CSV text)
    of the rows between them, each the file's own lines under its header; ``passages`` the
    rows cut ``[start, stop)``; ``dropped`` the pieces shorter than the shortest kept; ``t``
    the log's sample times."""
    pieces: list[tuple[int, int, str]]
    passages: list[tuple[int, int]]
    dropped: list[tuple[int, int]]
    t: np.ndarray


def split_flips(path: str | Path, margin: float = FLIP_MARGIN_S, min_length: float = FLIP_MIN_PIECE_S) -> FlipSplit:
    """The pieces of the flight log CSV ``path`` between its flips (:func:`flip_passages`), each
    the file's own header and rows, byte for byte, to be fitted together as several flights
    (``greybox split``). Pieces shorter than ``min_length`` seconds are dropped."""
    path = Path(path)
    header, data, lines = read_csv_table(path, line_numbers=True, must_be_numeric=is_log_column, text_columns=[])
    col = {h: j for j, h in enumerate(header)}
    for name in ("t", "theta"):
        if name not in col:
            raise GreyboxInputError(f"{path}: missing required column {name!r}: flips are found from the pitch")
    t = data[:, col["t"]]
    if np.isnan(t).any():
        raise GreyboxInputError(f"{path}: row {lines[np.flatnonzero(np.isnan(t))[0]]}, column 't': missing value "
                                "(time may never be missing)")
    check_sample_times(t, str(path), lines)
    passages = flip_passages(t, *(data[:, col[n]] if n in col else None for n in ("phi", "theta", "psi")),
                             margin=margin)
    raw = read_text_file(path, encoding="utf-8-sig").splitlines(keepends=True)
    head = "".join(raw[:int(lines[0]) - 1]) if lines.size else "".join(raw)
    starts = [int(x) - 1 for x in lines] + [len(raw)]
    pieces, dropped = [], []
    a = 0
    for start, stop in passages + [(t.size, t.size)]:
        if start > a:
            if t[start - 1] - t[a] >= min_length:
                pieces.append((a, start, head + "".join(raw[starts[a]:starts[start]])))
            else:
                dropped.append((a, start))
        a = max(a, stop)
    return FlipSplit(pieces, passages, dropped, t)


def _flip_words(where: str, t: np.ndarray, rows, passages: list[tuple[int, int]]) -> str:
    first = ", ".join(f"rows {rows[a]}-{rows[b - 1]} (t {t[a]:.2f}-{t[b - 1]:.2f} s)" for a, b in passages[:3])
    more = f" and {len(passages) - 3} more" if len(passages) > 3 else ""
    return (f"{where}: the pitch passes +-90 degrees (a flip) {len(passages)} time(s): {first}{more}. The attitude "
            "is ZYX Euler angles, singular there (roll and yaw jump by 180 degrees), and a fit through it would be "
            f"wrong: cut the flips out with 'greybox split {where} --out DIR' (the pieces between them, "
            f"{FLIP_MARGIN_S:g} s spare on each side) and fit the pieces together ('greybox fit DIR/*.csv', "
            "the validation flight split alike and given with --validation)")


def unwrap_heading(t: np.ndarray, psi: np.ndarray, r: np.ndarray | None = None,
                   tolerance: float | None = None) -> tuple[np.ndarray, int]:
    """The heading ``psi`` (rad, NaN where not measured) with its wraps (steps of about 2 pi
    between measured samples) taken out, and how many there were; a roll ``phi`` alike with
    the roll gyro ``p`` for ``r``. Between two measured samples
    the multiple of 2 pi added is the one that brings the step nearest to what the yaw gyro
    ``r`` turned meanwhile (its integral; ``psi' = r`` for small tilts, and a sample's spacing
    leaves far less than pi between the two) or, without ``r``, nearest to no step (as
    ``numpy.unwrap``): a yaw of more than pi between two samples of a sparse heading is told by
    the gyro. With ``tolerance`` (rad), a step is a wrap only where what is left of it, its
    multiple of 2 pi taken out, is within that of what the gyro turned (a column in degrees
    moves by more than a radian between rows without wrapping). ``psi`` itself (not a copy)
    when it does not wrap."""
    psi = np.asarray(psi, dtype=float)
    k = np.flatnonzero(np.isfinite(psi))
    if k.size < 2:
        return psi, 0
    step = np.diff(psi[k])
    turned = np.zeros_like(step)
    if r is not None:
        r = np.asarray(r, dtype=float)
        ok = np.isfinite(r)
        if ok.sum() >= 2:
            rate = np.interp(t, t[ok], r[ok])
            integral = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
            turned = integral[k[1:]] - integral[k[:-1]]
    n = np.round((turned - step) / (2 * np.pi))
    if tolerance is not None:
        n[np.abs(step + 2 * np.pi * n - turned) > tolerance] = 0.0
    if not n.any():
        return psi, 0
    out = psi.copy()
    out[k] = psi[k] + 2 * np.pi * np.concatenate([[0.0], np.cumsum(n)])
    return out, int(np.count_nonzero(n))


def check_measurement_units(t: np.ndarray, Y: np.ndarray, names: list[str], where: str,
                            inputs: np.ndarray | None = None) -> dict[str, tuple[float, float, float]]:
    """Refuse measurements whose units or frames contradict each other, which a fit would take
    silently (an audit: roll and pitch logged in degrees below 4 pi, a gyro in deg/s, positions
    in mm, each fitted with exit 0; positions in ENU or z up). Each check is a least-squares slope between two measurements of
    one motion, and refuses only when the slope is off by more than :data:`UNIT_RATIO_LIMIT`
    with three of its standard deviations to spare (counted over the smoothing window's
    independent stretches): a log with too little motion to tell is let through.

    * roll and pitch against the gyro: ``d(phi)/dt`` against ``p``, ``d(theta)/dt`` against
      ``q`` (the small-angle kinematics; yaw coupling only blurs it), both smoothed over 0.1 s:
      a slope of 57 is degrees, 1/57 a gyro in deg/s;
    * the heading against the yaw gyro: ``d(psi)/dt`` against ``r``, wraps taken out;
    * horizontal positions against the tilt: their acceleration (smoothed over 0.2 s) against
      ``-g R_psi (theta, -phi)``, what a thrust near the weight gives, with the velocity beside
      it for a drag's share: 1000 is millimetres, 100 centimetres, 1/57 angles in degrees (a log
      with every angle and rate in degrees passes the two gyro checks). Over 0.2 s and 1 s (a
      hover's drifts), the one showing one motion best. As a complex slope it also gives the
      frames: an angle beyond 30 degrees is positions turned against the heading's zero; the
      tilt's mirror image, or the heading read as degrees, explaining the acceleration clearly
      better (a quarter of the unexplained share) is a mirrored world (ENU) or degrees;
    * z against the rotors' ``sum w^2`` along the body's vertical (``inputs``, rotor speeds):
      falling in NED; rising, z points up;
    * the accelerometer: the median of ``|(ax, ay, az)|`` against that of the specific force
      the positions give (``g`` on the ground and in hover; ``g`` without positions): below a
      quarter of it the accelerometer is in g.

    A slope too small must also come with a correlation above 0.3 (two noises give a slope near
    0 as well). Returns what was judged, ``{"gyro" | "yaw gyro" | "tilt" | "vertical": (slope,
    std, correlation), "tilt turned": (|slope|, angle in degrees, correlation), "accelerometer":
    (median magnitude over the expected one, 0, 1)}`` (a check left out is absent).
    """
    col = {n: j for j, n in enumerate(names)}
    judged: dict[str, tuple[float, float, float]] = {}
    if t.size < 50:
        return judged
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        return judged

    def grid_step(window: float) -> float:
        # a window is smoothed over at most 100 grid points: they are plenty, and a 30-min log
        # at 1 kHz takes seconds per smoothing on its own grid
        return max(dt, window / 100)

    derived: dict[str, np.ndarray] = {}
    resampled: dict[tuple[str, float], tuple[np.ndarray, np.ndarray, int] | None] = {}
    smoothed: dict[tuple[str, float, int], np.ndarray | None] = {}

    def on_grid(name: str, window: float, deriv: int) -> np.ndarray | None:
        """``name`` on a uniform grid, smoothed over ``window`` s (Savitzky-Golay) or
        differentiated; NaN where its samples are more than half a window apart. Each is
        computed once (the checks share channels: a long 1 kHz log takes seconds)."""
        from scipy.signal import savgol_filter
        if (name, window, deriv) in smoothed:
            return smoothed[name, window, deriv]
        if (name, window) not in resampled:
            y = derived[name] if name in derived else Y[:, col[name]]
            ok = np.isfinite(y)
            h = grid_step(window)
            grid = np.arange(t[0], t[-1], h)
            n = max(5, int(round(window / h)) | 1)
            if ok.sum() < 50 or n >= grid.size:
                resampled[name, window] = None
            else:
                ts = t[ok]
                k = np.clip(np.searchsorted(ts, grid), 1, ts.size - 1)
                near = np.minimum(np.abs(grid - ts[k - 1]), np.abs(ts[k] - grid)) <= max(2.5 * dt, window / 2)
                # a grid point whose window of n points holds one far from any sample (a running
                # count: the same as convolving with n ones, in one pass)
                far = np.concatenate([[0], np.cumsum(~near)])
                half = n // 2
                hi = np.minimum(np.arange(grid.size) + half + 1, grid.size)
                lo = np.maximum(np.arange(grid.size) - half, 0)
                resampled[name, window] = (np.interp(grid, ts, y[ok]), far[hi] - far[lo] > 0, n, h)
        base = resampled[name, window]
        v = None
        if base is not None:
            values, bad, n, h = base
            v = savgol_filter(values, n, 2 if deriv < 2 else 3, deriv=deriv, delta=h)
            v[bad] = np.nan
        smoothed[name, window, deriv] = v
        return v

    def slope(a: np.ndarray, x: np.ndarray, window: float,
              v: np.ndarray | None = None) -> tuple[float, float, float] | None:
        """Slope of ``a`` on ``x`` (centred; beside ``v`` when given), its std (the samples
        within one smoothing ``window`` counted as one) and the correlation of ``x`` with what
        ``v`` leaves of ``a``."""
        cols = [x] if v is None else [x, v]
        ok = np.isfinite(a) & np.all(np.isfinite(np.column_stack(cols)), axis=1)
        per_window = max(1.0, window / grid_step(window))
        if ok.sum() < 10 * per_window:
            return None
        A = np.column_stack([c[ok] - c[ok].mean() for c in cols])
        b = a[ok] - a[ok].mean()
        if np.linalg.matrix_rank(A) < A.shape[1]:
            return None
        coef, *_ = np.linalg.lstsq(A, b, rcond=None)
        rest = b - A @ coef
        var = float(rest @ rest) / max(ok.sum() - A.shape[1], 1) * np.linalg.inv(A.T @ A)[0, 0] * per_window
        explained = b - A[:, 1:] @ coef[1:]
        den = math.sqrt(float(A[:, 0] @ A[:, 0]) * float(explained @ explained))
        return float(coef[0]), math.sqrt(max(var, 0.0)), float(A[:, 0] @ explained) / den if den > 0 else 0.0

    def tilt_on_acceleration(tilt: np.ndarray, a: np.ndarray, v: np.ndarray,
                             window: float) -> tuple[complex, float, float] | None:
        """The horizontal acceleration ``a`` as a complex multiple ``c`` of ``tilt`` beside the
        velocity ``v`` (all ``x + i y``): ``c``'s angle is how far the positions' axes are turned
        from the heading's; the correlation of ``tilt`` with what ``v`` leaves of ``a``; and the
        number of independent stretches (smoothing windows) it was found over."""
        ok = np.isfinite(a) & np.isfinite(v) & np.isfinite(tilt)
        per_window = max(1.0, window / grid_step(window))
        if ok.sum() < 10 * per_window:
            return None
        A = np.column_stack([tilt[ok] - tilt[ok].mean(), v[ok] - v[ok].mean()])
        if np.linalg.matrix_rank(A) < 2:
            return None
        b = a[ok] - a[ok].mean()
        coef, *_ = np.linalg.lstsq(A, b, rcond=None)
        explained = b - A[:, 1] * coef[1]
        den = math.sqrt(np.vdot(A[:, 0], A[:, 0]).real * np.vdot(explained, explained).real)
        return (complex(coef[0]), float(abs(np.vdot(A[:, 0], explained)) / den) if den > 0 else 0.0,
                ok.sum() / per_window)

    def off(fit: tuple[float, float, float]) -> bool:
        # too large: noise cannot make it so. Too small: two noises that share nothing give a
        # slope near 0 too, so the two must also show one motion (correlated)
        m, sd, c = abs(fit[0]), fit[1], abs(fit[2])
        return m - 3 * sd > UNIT_RATIO_LIMIT or (m + 3 * sd < 1 / UNIT_RATIO_LIMIT and c > _UNIT_MIN_CORRELATION)

    def judge(key: str, fit: tuple[float, float, float] | None, what: str, too_large: str, too_small: str) -> None:
        """Record ``fit`` under ``key``; refuse it, saying ``what`` (``{}``: the ratio) and the
        likely unit, when it is off."""
        if fit is None:
            return
        judged[key] = fit
        if off(fit):
            ratio = f"{abs(fit[0]):.3g} (± {fit[1]:.2g})"
            raise GreyboxInputError(f"{where}: columns {what.format(ratio)}, where consistent units give about 1: "
                                    f"{too_large if abs(fit[0]) > 1 else too_small}")

    # Each angle's rate against its gyro axis, signed: the attitude turning against the gyro is
    # a convention mistake in one of them (a blind audit's negated pitch, FLU gyro rates, ENU/FLU
    # Euler angles, the inverse rotation's angles), which the checks below then read as the
    # likeliest of other mistakes ("phi and theta swapped", "x and y swapped", "psi in
    # degrees?"), and doing what they said led to a certified fit with the drag 29-85 % low.
    # Said first, as itself.
    if "psi" in col and "r" in col:
        psi_c = Y[:, col["psi"]].copy()
        ok = np.flatnonzero(np.isfinite(psi_c))
        if ok.size > 1:
            wraps = np.diff(psi_c[ok])
            wraps[np.abs(wraps) < _HEADING_WRAP_STEP] = 0.0
            psi_c[ok[1:]] -= np.cumsum(wraps)
        derived["psi continuous"] = psi_c
    opposed = []
    for angle, rate in (("phi", "p"), ("theta", "q"), ("psi continuous", "r")):
        if (angle in col or angle in derived) and rate in col:
            a, x = on_grid(angle, 0.1, 1), on_grid(rate, 0.1, 0)
            fit = slope(a, x, 0.1) if a is not None and x is not None else None
            if fit is not None and fit[0] + 3 * fit[1] < 0 and fit[2] < -_SIGN_MIN_CORRELATION:
                opposed.append(f"'{angle.split()[0]}' against '{rate}' (slope {fit[0]:.2g}, correlation {fit[2]:.2f})")
    if opposed:
        raise GreyboxInputError(
            f"{where}: the attitude turns against the gyro: {', '.join(opposed)}; one of them is in another "
            "convention: a negated pitch or heading, the gyro in FLU body axes (q and r negated), Euler angles of an "
            "ENU world or FLU body (theta negated, psi from east), or the angles of the inverse rotation. greybox's: "
            "ZYX Euler angles of the FRD body in the NED world, the gyro in the FRD body (README, Conventions)")
    if {"phi", "theta", "p", "q"} <= set(col):
        parts = [on_grid(n, 0.1, d) for n, d in (("phi", 1), ("theta", 1), ("p", 0), ("q", 0))]
        if all(v is not None for v in parts):
            judge("gyro", slope(np.concatenate(parts[:2]), np.concatenate(parts[2:]), 0.1),
                  "'phi', 'theta' against 'p', 'q': the attitude changes {} times as fast as the gyro says",
                  "phi and theta in degrees? rad = deg * pi/180", "the gyro in deg/s? rad/s = deg/s * pi/180")
    if {"psi", "r"} <= set(col):
        # the heading's rate against the yaw gyro (small tilts: psi' ~ r); a wrap of the heading
        # (2 pi or 360) is a step no yaw makes between two samples: it was taken out above,
        # whatever the unit
        parts = [on_grid("psi continuous", 0.1, 1), on_grid("r", 0.1, 0)]
        if all(v is not None for v in parts):
            judge("yaw gyro", slope(parts[0], parts[1], 0.1),
                  "'psi' against 'r': the heading changes {} times as fast as the yaw gyro says",
                  "psi in degrees? rad = deg * pi/180", "the gyro's r in deg/s? rad/s = deg/s * pi/180")
    # z against the rotors' thrust, read before the horizontal frame so that a z-up world's
    # mirrored y is said with its z (a blind audit's NWU log: "y mirrored", then, once y was
    # mended, "z points up")
    vertical: tuple[float, float, float] | None = None
    if (inputs is not None and {"z", "phi", "theta"} <= set(col) and inputs.shape[1] >= 1
            and np.isfinite(Y[:, col["z"]]).any() and np.isfinite(Y[:, col["phi"]] + Y[:, col["theta"]]).any()):
        # NED: more thrust accelerates the vehicle up, toward negative z
        # (the rotors' sum of w^2 along the vertical, over its median: about -g per unit in hover)
        thrust = np.sum(inputs.astype(float) ** 2, axis=1) * np.cos(Y[:, col["phi"]]) * np.cos(Y[:, col["theta"]])
        scale = float(np.median(thrust[np.isfinite(thrust)]))
        derived["thrust"] = thrust / scale if scale > 0 else thrust
        best = None
        for window in _TILT_WINDOWS:
            parts = [on_grid("z", window, 2), on_grid("thrust", window, 0), on_grid("z", window, 1)]
            if all(v is not None for v in parts):
                fit = slope(parts[0], parts[1], window, parts[2])
                if fit is not None and (best is None or abs(fit[2]) > abs(best[2])):
                    best = fit
        vertical = best
    z_up = vertical is not None and vertical[0] - 3 * vertical[1] > 0 and vertical[2] > _UNIT_MIN_CORRELATION
    psi = Y[:, col["psi"]] if "psi" in col else np.array([np.nan])
    # per reading of the positions' frame and the heading, the best smoothing window's
    # (complex slope, correlation, real fit): a hover's slight drifts need a second, a
    # manoeuvre's turns a fifth of it
    readings: dict[str, tuple[complex, float, float, tuple[float, float, float] | None]] = {}
    for window in _TILT_WINDOWS if {"x", "y", "phi", "theta"} <= set(col) and np.isfinite(psi).any() else ():
        acc = [on_grid(n, window, 2) for n in ("x", "y")]
        vel = [on_grid(n, window, 1) for n in ("x", "y")]
        ph, th, ps = (on_grid(n, window, 0) for n in ("phi", "theta", "psi"))
        if not all(v is not None for v in (*acc, *vel, ph, th, ps)):
            continue
        g = _STANDARD_GRAVITY
        for reading, heading, mirror, (roll, pitch) in (
                ("as given", ps, False, (ph, th)), ("mirrored", ps, True, (ph, th)),
                ("heading in degrees", np.radians(ps), False, (ph, th)),
                ("roll and pitch swapped", ps, False, (th, ph))):
            # the world acceleration a thrust near the weight gives, x + i y
            tilt = -g * np.exp(1j * heading) * (pitch - 1j * roll)
            fit = tilt_on_acceleration(np.conj(tilt) if mirror else tilt, acc[0] + 1j * acc[1],
                                       vel[0] + 1j * vel[1], window)
            if fit is not None and (reading not in readings or fit[1] > readings[reading][1]):
                # at a steady speed the tilt holds a drag and nothing accelerates: the velocity
                # (in the positions' own unit, so it cannot hide one) takes the drag's share
                real = slope(np.concatenate(acc), np.concatenate([tilt.real, tilt.imag]), window,
                             np.concatenate(vel)) if reading == "as given" else None
                readings[reading] = (*fit, real)
                if reading == "as given":
                    # the tilt alone (no velocity beside it): in a circle the acceleration turned
                    # by 90 degrees is the velocity, so beside it any turn fits (a blind audit's
                    # circles with 6-mm positions: turned by 59 degrees, |c| 0.2, refused)
                    ok = np.isfinite(tilt) & np.isfinite(acc[0] + 1j * acc[1])
                    x, y = tilt[ok] - tilt[ok].mean(), (acc[0] + 1j * acc[1])[ok]
                    plain = complex(np.vdot(x, y - y.mean()) / np.vdot(x, x).real) if ok.sum() > 10 else 0j
                    plain_turn = math.degrees(float(np.angle(plain))) if plain != 0 else 0.0
    if "as given" in readings:
        c, rho, n_windows, real = readings["as given"]
        judged["tilt turned"] = (abs(c), math.degrees(float(np.angle(c))), rho)
        # another reading of the frame or the heading that leaves a quarter of what this one
        # leaves unexplained, or that shows the motion where this one shows none (within the
        # noise of a correlation over that many stretches: a GNSS's 0.3-m positions at 10 Hz
        # swapped to ENU correlate 0.57 mirrored, 0.04 as given): the motion says the log is
        # not in the frame it claims
        other = min((r for r in readings if r != "as given"), key=lambda r: 1 - readings[r][1] ** 2)
        c_o, rho_o = readings[other][:2]
        # "shows none" against another reading only when that one shows the motion beyond the
        # null: over a short flight's few stretches neither may (a blind audit's 10 stretches:
        # 0.95 as given "showed none" beside 0.76 with the heading in degrees, and was refused)
        null = _FRAME_NULL_SIGMAS / math.sqrt(max(n_windows, 1.0))
        shows_none = rho < null <= rho_o
        def clearly_above(high: float, low: float) -> bool:
            # Fisher's atanh of two correlations over n_windows stretches, 3 SE of their difference
            return (n_windows > 3 and math.atanh(min(high, 0.999999)) - math.atanh(min(max(low, 0.0), 0.999999))
                    > _FRAME_CLEARLY_BETTER_SE * math.sqrt(2.0 / (n_windows - 3)))

        clearly_better = clearly_above(rho_o, rho)
        if rho_o > _FRAME_MIN_CORRELATION and (1 - rho_o ** 2 < (1 - rho ** 2) / _FRAME_UNEXPLAINED_RATIO
                                               or shows_none or clearly_better):
            shown = f"(correlation {rho_o:.2f}, as given {rho:.2f})"
            if other == "heading in degrees":
                raise GreyboxInputError(
                    f"{where}: column 'psi': the tilt points along the positions' acceleration only with psi read "
                    f"as degrees {shown}: " + ("phi, theta, psi in degrees? rad = deg * pi/180" if abs(c_o) < 1 / UNIT_RATIO_LIMIT
                                                 else "psi in degrees? rad = deg * pi/180"))
            def alike(name: str) -> bool:
                # with a steady heading, positions mirrored and roll and pitch swapped read alike
                r = readings[name][1] if name in readings else -1.0
                return n_windows > 3 and r > _FRAME_MIN_CORRELATION and not clearly_above(rho_o, r)

            steady = "which the flight's heading, too steady, cannot tell from it"
            if other == "roll and pitch swapped":
                # a body frame with roll and pitch swapped is left-handed: the tilt it gives turns
                # the wrong way with the heading, so a flight that turns tells it from a mirrored
                # world (a blind audit's log, phi and theta swapped with p and q: fitted,
                # certified, "w1 as rotor 2, w2 as rotor 1")
                also = (f"; or the positions mirrored (correlation {readings['mirrored'][1]:.2f}), {steady}"
                        if alike("mirrored") else "")
                raise GreyboxInputError(
                    f"{where}: columns 'phi', 'theta': the positions' acceleration follows the tilt only with roll "
                    f"and pitch swapped {shown}: phi and theta swapped (and p and q with them?){also}; greybox's "
                    "body axes are FRD: phi about x (forward), theta about y (right)")
            turn = math.degrees(float(np.angle(c_o)))
            up = (f" and z up (z accelerates toward positive values as the rotors speed up, correlation "
                  f"{vertical[2]:.2f})" if z_up else "")
            how = ((f"x and y swapped{up} (ENU: x east, y north, z up: NED = (y, x, -z))" if z_up else
                    "x and y swapped (ENU: x east, y north, z up?)") if abs(abs(turn) - 90) < 30 else
                   (f"y mirrored{up} (NWU: x north, y west, z up: NED = (x, -y, -z))" if z_up else
                    "y mirrored (y to the left: a z-up frame?)") if abs(turn) < 30 else
                   f"x mirrored{up}" if abs(turn) > 150 else f"mirrored and turned by {turn:.0f} degrees{up}")
            also = (f"; or phi and theta swapped (and p and q with them: correlation "
                    f"{readings['roll and pitch swapped'][1]:.2f}), {steady}" if alike("roll and pitch swapped") else "")
            raise GreyboxInputError(
                f"{where}: columns 'x', 'y': the positions' acceleration follows the tilt's mirror image "
                f"{shown}: {how}{also}; greybox's world is NED (x north, y east, z down) and the attitude's body FRD")
        turn = math.degrees(float(np.angle(c)))
        if rho > _FRAME_MIN_CORRELATION and abs(turn) > _FRAME_MAX_TURN and abs(plain_turn) > _FRAME_MAX_TURN:
            raise GreyboxInputError(
                f"{where}: columns 'x', 'y' against 'psi': the positions' acceleration follows the tilt turned by "
                f"{turn:.0f} degrees (correlation {rho:.2f}): the positions' axes and the heading's zero differ "
                f"(a motion-capture frame against a compass heading?); turn the positions by {-turn:.0f} degrees "
                f"or add {turn:.0f} degrees to psi")
        judge("tilt", real,
              "'x', 'y' against 'phi', 'theta', 'psi': the horizontal acceleration is {} times what the "
              "tilt gives with a thrust near the weight",
              "x and y in mm (1000) or cm (100)? positions are in metres",
              "phi, theta, psi in degrees? (or x, y in km)")
    if vertical is not None:
        judged["vertical"] = vertical
        if z_up:
            raise GreyboxInputError(
                f"{where}: column 'z': z accelerates toward positive values as the rotors speed up "
                f"(correlation {vertical[2]:.2f}): z points up? greybox's world is NED, z down: z = -height")
    # last: positions in another unit are named by the tilt check first
    if {"ax", "ay", "az"} <= set(col):
        f = np.linalg.norm(Y[:, [col["ax"], col["ay"], col["az"]]], axis=1)
        f = f[np.isfinite(f)]
        # the specific force the positions give (on the ground and in hover g; a simulated
        # fall less), else g
        # (the smoother of the two windows where it is the smaller: a noisy position's second
        # derivative over 0.2 s adds its noise to the magnitude, 0.6 of it on a GNSS's 5 cm at 10 Hz)
        expected = math.inf
        for window in _TILT_WINDOWS if {"x", "y", "z"} <= set(col) else ():
            pos = [on_grid(n, window, 2) for n in ("x", "y", "z")]
            if all(v is not None for v in pos):
                a = np.column_stack(pos) - np.array([0.0, 0.0, _STANDARD_GRAVITY])
                a = a[np.all(np.isfinite(a), axis=1)]
                if a.shape[0] >= 20:
                    expected = min(expected, float(np.median(np.linalg.norm(a, axis=1))))
        if not math.isfinite(expected):
            expected = _STANDARD_GRAVITY
        if f.size >= 20 and expected > 2.0:
            med = float(np.median(f))
            judged["accelerometer"] = (med / expected, 0.0, 1.0)
            if med * 4 < expected or med > 4 * expected:
                hint = "in g? m/s^2 = g * 9.81" if med < expected else "not in m/s^2?"
                if expected != _STANDARD_GRAVITY:
                    hint += " (or the positions are not in metres)"
                raise GreyboxInputError(
                    f"{where}: columns 'ax', 'ay', 'az': the accelerometer's magnitude is typically {med:.3g}, where "
                    f"{'the positions give' if expected != _STANDARD_GRAVITY else 'an IMU reads'} "
                    f"{expected:.3g} m/s^2 (g on the ground and in hover): {hint}")
        az = Y[:, col["az"]]
        az = az[np.isfinite(az)]
        # gated like the magnitude: a free fall (expected ~0) gives no direction to check
        if az.size >= 20 and expected > 2.0 and float(np.median(az)) > 0.5 * expected:
            # the thrust points up, along the body's -z (FRD), on the ground and in flight alike
            raise GreyboxInputError(
                f"{where}: column 'az': the accelerometer's z reads {float(np.median(az)):+.3g} m/s^2 at its median, "
                f"where an FRD IMU reads about -{expected:.3g} (the specific force R^T(a - g e3), the thrust along "
                "the body's -z): is its z up (FLU: negate y and z of the gyro and the accelerometer), or does it log "
                "gravity rather than the specific force (negate ax, ay, az)?")
    return judged


def save_log(log: FlightLog, path: str | Path, extras: bool = True, digits: int = 17) -> None:
    """Write a flight log CSV atomically; NaN outputs become empty cells. ``digits``
    significant digits per value (17 round-trips exactly; fewer make smaller files).

    Example::

        from greybox import load_log, save_log
        log = load_log("greybox/data/logs/demo_ground_effect.csv")
        est, val = log.split(0.8)
        save_log(val, "validation.csv", digits=8)
    """
    _fmt = (lambda v: "" if np.isnan(v) else repr(float(v))) if digits >= 17 else \
        (lambda v: "" if np.isnan(v) else f"{v:.{digits}g}")
    names = ["t"] + list(log.input_names) + list(log.output_names)
    cols = [log.t[:, None], log.inputs, log.outputs]
    if extras and log.extras:
        names += list(log.extras)
        cols += [np.column_stack(list(log.extras.values()))]
    M = np.hstack(cols)
    buf = io.StringIO()
    buf.write(",".join(names) + "\n")
    for row in M:
        # time always exactly: rounded times could collide and the log would not load again
        buf.write(repr(float(row[0])) + "," + ",".join(_fmt(v) for v in row[1:]) + "\n")
    atomic_write(path, buf.getvalue())


def log_from_arrays(t: Iterable[float], inputs: np.ndarray, outputs: np.ndarray,
                    input_names: list[str] | None = None,
                    output_names: list[str] | None = None) -> FlightLog:
    """Convenience constructor used by simulations and tests. Without ``output_names`` the
    columns of ``outputs`` are the first ones of ``x..psi, p, q, r, ax, ay, az`` (6, 9 or 12)."""
    inputs = np.asarray(inputs, dtype=float)
    outputs = np.asarray(outputs, dtype=float)
    input_names = input_names or [f"w{i + 1}" for i in range(inputs.shape[1])]
    output_names = output_names or (REQUIRED_OUTPUTS + OPTIONAL_OUTPUTS)[:outputs.shape[1]]
    return FlightLog(np.asarray(t, dtype=float), inputs, input_names, outputs, output_names)


__all__.append("log_from_arrays")

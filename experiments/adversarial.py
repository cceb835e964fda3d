"""Adversarial replay of the command line's promises (issue 16, causes 1-8).

The contract (shared/CONTRACT.md §2, §5) promises that a user mistake gets exactly one
``greybox: error: ...`` line naming the problem (an argparse usage block may come before it),
exit status 2, no traceback, no partial output, never a silent wrong result; that ``--json``
is written atomically; issue 16 adds: Ctrl-C ends with exit 130 and one line, nothing written
and no orphaned compiler; a compile cache that cannot be written, or holds garbage or the
wrong library, never changes a result (fall back with a note, verify, heal).

Each case builds its inputs in its own temporary directory (from a valid 6 s synthetic log
made once at start, the bundled airframes and camera), runs ``python -m greybox ...`` as a
subprocess in its own session with a timeout and checks the promise:

* ``error``  exit 2; stderr = [usage block] + [``note:`` lines] + exactly one
  ``greybox: error:`` line, last; no Traceback; the line matches every expected pattern
  (case-insensitive regex: the row, the column, the option...); no file in the case
  directory created or modified (no partial output).
* ``ok``     exit 0, no Traceback, no Python ``file.py:N: Warning`` lines; case checks
  (e.g. the fit's parameters equal a clean run's; a broken cache is healed).
* ``note``   exit 0 with a ``note`` line matching the patterns, or an ``error`` as above.
* ``either`` an ``error`` as above, or exit 0 and the case's check (e.g. the log written
  by ``synth --digits 0`` loads and fits).
* ``signal`` (interrupts) the signal is sent at a time or when a C compiler of the run is
  seen; then exit 130 (SIGINT) or 130/143 (SIGTERM) within 30 s, exactly one ``greybox:``
  line on stderr, no output file, no temp files left in $TMPDIR, no ``*.tmp`` in the cache,
  no surviving process of the run.

Every case also checks that no process of the run survives it (0.5 s after it ended): its
process group, and anything carrying the run's token in its environment (a compiler started
in its own session included).

Non-cache cases share one compile cache warmed at start; cache and interrupt cases get
their own. $TMPDIR is per case. The child's address space is capped (8 GB) so a runaway
compiler cannot take the machine. By default the package in this checkout is tested
(PYTHONPATH = the repository: a non-editable install would otherwise be tested); ``--source DIR`` the package in DIR (an exported commit);
``--installed`` whatever ``python -m greybox`` imports.

    OPENBLAS_NUM_THREADS=1 python experiments/adversarial.py            # everything (~10 min)
    python experiments/adversarial.py --fast                           # no interrupts / long cases
    python experiments/adversarial.py --only 'time-|rpm'               # regex on id or cause
    python experiments/adversarial.py --list                           # the cases
    python experiments/adversarial.py --json-out results.json --keep   # keep the case dirs

Exit status 0 if every selected case passes, 1 otherwise (3 if the fixtures cannot be made).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

REPO = Path(__file__).resolve().parents[1]
AIRFRAMES = REPO / "greybox" / "data" / "airframes"
AF = str(AIRFRAMES / "paper.toml")          # 1 kg, K_T 2.395e-5: hover ~320 rad/s
AF_X = str(AIRFRAMES / "x_quad.toml")       # 1.2 kg, K_T 1.8e-5: hover ~404 rad/s
CAMERA = str(REPO / "greybox" / "data" / "cameras" / "mirror_down.toml")
MEM_LIMIT = 8 << 30
COMPILERS = {"gcc", "cc", "cc1", "as", "collect2", "ld", "clang"}

CAUSES = {
    "0-sanity": "valid inputs still work (guards against over-eager fixes)",
    "1-csv": "csv.Error escapes (huge cell, stray quote, NUL, garbage)",
    "2-time": "absurd time stamps (1e308, 1e6 s gap, milliseconds, order)",
    "3-rpm": "RPM below 8000 judged against the airframe",
    "4-paths": "output paths checked before the computation",
    "5-options": "NaN/inf/out-of-range option and airframe values",
    "6-signals": "SIGINT/SIGTERM: exit 130, one line, nothing written, no orphans",
    "7-cache": "unwritable / garbage / wrong compile cache",
    "8-smaller": "digits, negative speeds, 1e308 outlier, np.float64, warnings",
}


# ----------------------------------------------------------------------------- CSV helpers
class Csv:
    """A flight log as lines of text, edited by file line number (header = line 1, the
    numbering greybox's messages use for 'row N')."""

    def __init__(self, path: Path):
        self.lines = path.read_text().splitlines()
        self.header = self.lines[0].split(",")

    def col(self, name: str) -> int:
        return self.header.index(name)

    @property
    def last(self) -> int:
        return len(self.lines)

    def get(self, line: int, name: str) -> str:
        return self.lines[line - 1].split(",")[self.col(name)]

    def set(self, line: int, name: str, value: str) -> "Csv":
        cells = self.lines[line - 1].split(",")
        cells[self.col(name)] = value
        self.lines[line - 1] = ",".join(cells)
        return self

    def map(self, names: list[str], fn: Callable[[float], float], first: int = 2, last: int | None = None) -> "Csv":
        idx = [self.col(n) for n in names]
        for k in range(first - 1, (last or self.last)):
            cells = self.lines[k].split(",")
            for j in idx:
                if cells[j] != "":
                    cells[j] = repr(fn(float(cells[j])))
            self.lines[k] = ",".join(cells)
        return self

    def first_measured(self, name: str, after: int) -> int:
        for k in range(after, self.last + 1):
            if self.get(k, name) not in ("", "nan"):
                return k
        raise ValueError(name)

    def write(self, path: Path, newline: str = "\n") -> None:
        path.write_bytes((newline.join(self.lines) + newline).encode())


def edit_toml(src: str, dst: Path, key: str, value: str) -> None:
    """Copy an airframe file with ``key = value`` replaced (first occurrence)."""
    text = Path(src).read_text()
    new, n = re.subn(rf"(?m)^{re.escape(key)}\s*=.*$", f"{key} = {value}", text, count=1)
    assert n == 1, key
    dst.write_text(new)


# ----------------------------------------------------------------------------- cases
@dataclass
class Ctx:
    work: Path          # cwd of the run; everything in it is watched for partial output
    root: Path          # the case's directory (work/, cache/, tmp/)
    fx: Path            # shared fixtures (valid.csv, inputs.csv, valid_x.csv, long.csv, ref_*.json)
    cache: Path         # GREYBOX_CACHE for this case
    env: dict = field(default_factory=dict)

    def log(self, name: str = "valid.csv") -> Csv:
        return Csv(self.fx / name)


@dataclass
class Case:
    id: str
    cause: str
    expect: str                                   # error | ok | note | either | signal
    setup: Callable[[Ctx], list]                  # builds inputs in ctx.work, returns argv after 'greybox'
    patterns: list = field(default_factory=list)  # regexes the error (or note) line must match
    forbid: list = field(default_factory=list)    # substrings stderr must not contain
    check: Callable | None = None                 # (ctx, result) -> list of failure reasons
    timeout: float = 60.0
    cache: str = "shared"                         # shared | fresh | custom (setup sets ctx.cache)
    long: bool = False
    readonly: list = field(default_factory=list)  # work-relative dirs made read-only after setup
    signal: tuple | None = None                   # (signum, when: seconds | "cc" | "cc-group")
    note: str = ""

    def expected_text(self) -> str:
        if self.expect == "error":
            return "2 " + " & ".join(p for p in self.patterns)[:22] if self.patterns else "2"
        if self.expect == "signal":
            return "130" if self.signal[0] == signal.SIGINT else "143|130"
        return {"ok": "0", "note": "0+note|2", "either": "0(loads)|2"}[self.expect]


def _fit(log="log.csv", af=AF, *extra):
    return ["fit", log, "--airframe", af, "--quiet", "--json", "out.json", *extra]


def _diag(log="log.csv", af=AF, *extra):
    return ["diagnose", log, "--airframe", af, "--quiet", "--candidates", "quadratic_drag",
            "--no-iterate", "--json", "out.json", *extra]


def _sim(inputs="in.csv", af=AF, *extra):
    return ["simulate", "--airframe", af, "--inputs", inputs, "--out", "sim.csv", "--json", "out.json", *extra]


def _lin(af=AF, *extra):
    return ["linearize", "--airframe", af, "--json", "out.json", *extra]


def log_cases(prefix: str, cause: str, mutate: Callable[[Csv, Ctx], None], cmds: str, expect: str = "error",
              patterns: list | None = None, base: str = "valid.csv", **kw) -> list[Case]:
    """One case per command in ``cmds`` (f=fit, d=diagnose, s=simulate) on a mutated copy of
    the valid log (for simulate: of its t,w1..w4 columns)."""
    out = []
    long_ = kw.pop("long", False)
    af = AF_X if base == "valid_x.csv" else AF
    for c in cmds:
        name = {"f": "fit", "d": "diagnose", "s": "simulate"}[c]

        def setup(ctx, c=c):
            src = ctx.log("inputs.csv" if (c == "s" and base == "valid.csv") else base)
            mutate(src, ctx)
            if c == "s":
                src.write(ctx.work / "in.csv")
                return _sim(af=af)
            src.write(ctx.work / "log.csv")
            return (_fit if c == "f" else _diag)(af=af)
        out.append(Case(f"{prefix}-{name}", cause, expect, setup, list(patterns or []),
                        long=long_ or (c == "d" and expect != "error"), **dict(kw)))
    return out


def ref_params(fx: Path) -> dict:
    return json.loads((fx / "ref_fit.json").read_text())["parameters"]


def check_fit_json(ctx: Ctx, res) -> list:
    """The fit's JSON exists and its parameters equal the clean run's."""
    p = ctx.work / "out.json"
    if not p.exists():
        return ["no out.json written"]
    try:
        got = json.loads(p.read_text())["parameters"]
    except Exception as e:  # noqa: BLE001
        return [f"out.json unreadable: {e}"]
    bad = []
    for name, ref in ref_params(ctx.fx).items():
        v, r = got.get(name, {}).get("value"), ref["value"]
        scale = max(abs(r), ref.get("std") or 0.0, 1e-12)
        if v is None or not abs(v - r) <= 1e-3 * scale:
            bad.append(f"{name}={v} (clean run {r:.6g})")
    return [f"wrong result: {', '.join(bad)}"] if bad else []


def check_diag_json(ctx: Ctx, res) -> list:
    p = ctx.work / "out.json"
    if not p.exists():
        return ["no out.json written"]
    got = json.loads(p.read_text())
    ref = json.loads((ctx.fx / "ref_diag.json").read_text())
    out = []
    a, b = got["baseline"]["nrmse"], ref["baseline"]["nrmse"]
    if not abs(a - b) <= 1e-3 * max(abs(b), 1e-9):
        out.append(f"wrong result: baseline nrmse {a} (clean run {b})")
    if got.get("verdict") != ref.get("verdict"):
        out.append(f"wrong result: verdict {got.get('verdict')} (clean run {ref.get('verdict')})")
    if re.search(r"--\d", res.stdout):
        out.append("double minus ('--N %') in the summary")
    return out


def check_healed(argv_fn):
    """After the case's run, a second identical run must load its compiled code from the cache
    (a broken cache file is healed, not skipped forever)."""
    def check(ctx: Ctx, res) -> list:
        r = run_greybox(argv_fn(), ctx, timeout=120)
        if r.rc != 0:
            return [f"second run exit {r.rc}: {first_line(r.stderr)}"]
        m = re.search(r"evaluator: ([a-z ]+)", r.stdout)
        if m and "virtual machine" in m.group(1):
            return ["not healed: the second run still falls back to the virtual machine"]
        return []
    return check


def check_synth_loads(ctx: Ctx, res) -> list:
    r = run_greybox(["fit", "digits.csv", "--airframe", AF, "--quiet", "--max-iter", "2"], ctx, timeout=120)
    if r.rc == 2 or "Traceback" in r.stderr:
        return [f"the written log is refused by greybox: {first_line(r.stderr)}"]
    return []


def sim_ok(ctx: Ctx, res) -> list:
    return [] if (ctx.work / "sim.csv").exists() else ["no sim.csv written"]


def build_cases() -> list[Case]:
    C: list[Case] = []
    big = 200_000

    # ---- 0: sanity (must keep working)
    C += [Case("sanity-fit", "0-sanity", "ok", lambda c: (shutil.copy(c.fx / "valid.csv", c.work / "log.csv"), _fit())[1],
               check=check_fit_json, timeout=120),
          Case("sanity-diagnose", "0-sanity", "ok", lambda c: (shutil.copy(c.fx / "valid.csv", c.work / "log.csv"), _diag())[1],
               check=check_diag_json, timeout=180, long=True),
          Case("sanity-simulate", "0-sanity", "ok", lambda c: (shutil.copy(c.fx / "inputs.csv", c.work / "in.csv"), _sim())[1],
               check=sim_ok),
          Case("sanity-linearize", "0-sanity", "ok", lambda c: _lin(),
               check=lambda c, r: [] if (c.work / "out.json").exists() else ["no out.json"]),
          Case("sanity-crlf-fit", "0-sanity", "ok", lambda c: (c.log().write(c.work / "log.csv", "\r\n"), _fit())[1],
               check=check_fit_json, timeout=120, note="CRLF line endings are a valid CSV"),
          *log_cases("sanity-epoch-time", "0-sanity", lambda s, c: s.map(["t"], lambda t: t + 1.7e9), "s",
                     expect="ok", check=sim_ok, note="unix-epoch time stamps: large t, normal steps"),
          *log_cases("sanity-fast-rotors-1.3x", "0-sanity", lambda s, c: s.map(["w1", "w2", "w3", "w4"], lambda w: 1.3 * w),
                     "s", expect="ok", check=sim_ok, note="1.3x hover speed is plausible rad/s, not RPM")]

    # ---- 1: csv.Error escapes
    C += log_cases("csv-bigcell-text", "1-csv", lambda s, c: s.set(5, "x", "x" * big), "fd", patterns=[r"\brow 5\b"])
    C += log_cases("csv-bigcell-digits", "1-csv", lambda s, c: s.set(5, "w1", "1" * big), "s", patterns=[r"\brow 5\b"])
    C += log_cases("csv-bigcell-lastrow", "1-csv", lambda s, c: s.set(s.last, "phi", "9" * big + "x"), "f",
                   patterns=[r"\brow 6002\b"])
    C += log_cases("csv-bigcell-header", "1-csv", lambda s, c: s.set(1, "psi", "p" * big), "f", patterns=[r"\brow 1\b|header|psi"])
    quote3 = lambda s, c: s.lines.__setitem__(2, '"' + s.lines[2])   # sed '3s/^/"/'
    C += log_cases("csv-quote-line3", "1-csv", quote3, "fsd", patterns=[r"\b(row|line) 3\b"])
    C += log_cases("csv-quote-line3000", "1-csv", lambda s, c: s.lines.__setitem__(2999, '"' + s.lines[2999]), "f",
                   patterns=[r"\b(row|line) 3000\b"])
    C += log_cases("csv-quote-lastline", "1-csv", lambda s, c: s.lines.__setitem__(s.last - 1, '"' + s.lines[-1]), "f",
                   patterns=[r"\b(row|line) 6002\b"])
    C += log_cases("csv-quote-header", "1-csv", lambda s, c: s.lines.__setitem__(0, '"' + s.lines[0]), "f",
                   patterns=[r"\b(row|line) 1\b|header"])
    C += log_cases("csv-nul-byte", "1-csv", lambda s, c: s.set(4, "phi", "0.0\x001"), "f", patterns=[r"\brow 4\b"])

    def garbage(ctx):
        (ctx.work / "log.csv").write_bytes(bytes(range(256)) * 64)
        return _fit()
    C.append(Case("csv-binary-garbage-fit", "1-csv", "error", garbage, [r"log\.csv"]))

    def utf16(ctx):
        (ctx.work / "log.csv").write_bytes(("\n".join(ctx.log().lines) + "\n").encode("utf-16"))
        return _fit()
    C.append(Case("csv-utf16-fit", "1-csv", "error", utf16, [r"log\.csv"]))

    # ---- 2: absurd time stamps
    C += log_cases("time-last-1e308", "2-time", lambda s, c: s.set(s.last, "t", "1e308"), "fsd",
                   patterns=[r"\brow 6002\b"])
    C += log_cases("time-mid-1e300", "2-time", lambda s, c: s.set(3000, "t", "1e300"), "f",
                   patterns=[r"\brow (3000|3001)\b"])
    gap = lambda s, c: s.map(["t"], lambda t: t + 1e6, first=3001)
    C += log_cases("time-gap-1e6", "2-time", gap, "fsd", patterns=[r"\brow (3000|3001)\b"], timeout=20)
    C += log_cases("time-gap-1e4", "2-time", lambda s, c: s.map(["t"], lambda t: t + 1e4, first=3001), "f",
                   patterns=[r"\brow (3000|3001)\b"], timeout=20)
    ms = lambda s, c: s.map(["t"], lambda t: t * 1000)
    C += log_cases("time-ms", "2-time", ms, "fsd", patterns=[r"millisecond"], timeout=20)
    C += log_cases("time-ms-xquad", "2-time", ms, "f", patterns=[r"millisecond"], base="valid_x.csv", timeout=20)
    C += log_cases("time-us", "2-time", lambda s, c: s.map(["t"], lambda t: t * 1e6), "f",
                   patterns=[r"\bt\b|time"], timeout=20)
    C += log_cases("time-inf-last", "2-time", lambda s, c: s.set(s.last, "t", "inf"), "s", patterns=[r"\brow 6002\b"])
    C += log_cases("time-missing", "2-time", lambda s, c: s.set(10, "t", ""), "f", patterns=[r"\brow 10\b"])

    # ---- 3: RPM
    rpm = lambda s, c: s.map(["w1", "w2", "w3", "w4"], lambda w: w * 30 / math.pi)
    C += log_cases("rpm-paper", "3-rpm", rpm, "sfd", patterns=[r"rpm"], timeout=90)
    C += log_cases("rpm-xquad", "3-rpm", rpm, "f", patterns=[r"rpm"], base="valid_x.csv", timeout=90)
    C += log_cases("rpm-one-column-w3", "3-rpm", lambda s, c: s.map(["w3"], lambda w: w * 30 / math.pi), "f",
                   patterns=[r"w3"], timeout=90)

    # ---- 4: output paths
    def path_case(cid, argv_fn, pats, prep=None, readonly=()):
        def setup(ctx):
            shutil.copy(ctx.fx / "valid.csv", ctx.work / "log.csv")
            shutil.copy(ctx.fx / "inputs.csv", ctx.work / "in.csv")
            (ctx.work / "existing_dir").mkdir()
            (ctx.work / "plainfile").write_text("I am a file\n")
            (ctx.work / "ro_dir").mkdir()
            if prep:
                prep(ctx)
            return argv_fn()
        return Case(cid, "4-paths", "error", setup, pats, readonly=list(readonly), timeout=90)

    def swap_opt(argv, opt, value):
        argv = list(argv)
        argv[argv.index(opt) + 1] = value
        return argv
    for cmd, base in (("fit", _fit), ("diagnose", _diag), ("simulate", _sim), ("linearize", _lin)):
        C.append(path_case(f"path-json-dir-{cmd}", lambda b=base: swap_opt(b(), "--json", "existing_dir"),
                           [r"existing_dir|--json"]))
    C.append(path_case("path-json-dir-synth", lambda: ["synth", "--airframe", AF, "--duration", "6", "--out", "s.csv",
                                                       "--json", "existing_dir"], [r"existing_dir|--json"]))
    for cmd, base in (("fit", _fit), ("linearize", _lin)):
        C.append(path_case(f"path-json-below-file-{cmd}", lambda b=base: swap_opt(b(), "--json", "plainfile/x.json"),
                           [r"plainfile|--json"]))
        C.append(path_case(f"path-json-proc-{cmd}", lambda b=base: swap_opt(b(), "--json", "/proc/x.json"),
                           [r"/proc/x\.json|--json"]))
    for cmd, base in (("fit", _fit), ("diagnose", _diag)):
        C.append(path_case(f"path-json-readonly-{cmd}", lambda b=base: swap_opt(b(), "--json", "ro_dir/x.json"),
                           [r"ro_dir|--json"], readonly=["ro_dir"]))
    C.append(path_case("path-plots-file-fit", lambda: _fit() + ["--plots", "plainfile"], [r"plainfile|--plots"]))
    C.append(path_case("path-plots-below-file-fit", lambda: _fit() + ["--plots", "plainfile/plots"],
                       [r"plainfile|--plots"]))
    C.append(path_case("path-report-file-diagnose", lambda: _diag() + ["--report", "plainfile"],
                       [r"plainfile|--report"]))
    C.append(path_case("path-report-readonly-diagnose", lambda: _diag() + ["--report", "ro_dir/report"],
                       [r"ro_dir|--report"], readonly=["ro_dir"]))
    C.append(path_case("path-out-dir-simulate", lambda: swap_opt(_sim(), "--out", "existing_dir"),
                       [r"existing_dir|--out"]))
    C.append(path_case("path-out-below-file-simulate", lambda: swap_opt(_sim(), "--out", "plainfile/sim.csv"),
                       [r"plainfile|--out"]))
    C.append(path_case("path-out-readonly-simulate", lambda: swap_opt(_sim(), "--out", "ro_dir/sim.csv"),
                       [r"ro_dir|--out"], readonly=["ro_dir"]))
    C.append(path_case("path-out-dir-synth", lambda: ["synth", "--airframe", AF, "--duration", "6", "--out",
                                                      "existing_dir"], [r"existing_dir|--out"]))
    # an existing --out must be left as it was when --json is refused
    C.append(path_case("path-keep-out-bad-json-simulate",
                       lambda: swap_opt(swap_opt(_sim(), "--json", "existing_dir"), "--out", "keep.csv"),
                       [r"existing_dir|--json"], prep=lambda c: (c.work / "keep.csv").write_text("t,x\n0,1\n")))

    def vision_csv(ctx):
        s = ctx.log()
        rows = ["t,x,y,z"] + [",".join(s.lines[k - 1].split(",")[i] for i in (s.col("t"), s.col("x"), s.col("y"), s.col("z")))
                              for k in range(2, s.last + 1) if s.get(k, "x") != ""]
        (ctx.work / "vision.csv").write_text("\n".join(rows) + "\n")
    C.append(path_case("path-out-dir-merge", lambda: ["merge", "log.csv", "--vision", "vision.csv", "--out", "existing_dir"],
                       [r"existing_dir|--out"], prep=vision_csv))
    C.append(path_case("path-outdir-file-render", lambda: ["render", "log.csv", "--camera", CAMERA, "--out-dir",
                                                           "plainfile", "--fps", "5"], [r"plainfile|--out-dir"]))

    # ---- 5: option values
    def opt_case(cid, argv_fn, pats, prep=None, **kw):
        def setup(ctx):
            shutil.copy(ctx.fx / "valid.csv", ctx.work / "log.csv")
            shutil.copy(ctx.fx / "inputs.csv", ctx.work / "in.csv")
            if prep:
                prep(ctx)
            return argv_fn()
        return Case(cid, "5-options", "error", setup, pats, timeout=kw.pop("timeout", 90), **kw)
    for v in ("nan", "0", "-1", "inf"):
        C.append(opt_case(f"opt-horizon-{v}-fit", lambda v=v: _fit() + [f"--horizon={v}"], [r"horizon"]))
    for v in ("nan", "inf"):
        C.append(opt_case(f"opt-psi-{v}-linearize", lambda v=v: _lin() + [f"--psi={v}"], [r"psi"]))
    C.append(opt_case("opt-at-nan-linearize", lambda: _lin() + ["--at", "0,nan,-1"], [r"--at"]))
    for v, cmds in (("0", "fsl"), ("nan", "fsl"), ("inf", "fl"), ("-2.4e-5", "s")):
        for c in cmds:
            argv = {"f": _fit, "s": _sim, "l": _lin}[c]
            name = {"f": "fit", "s": "simulate", "l": "linearize"}[c]
            C.append(opt_case(f"opt-set-KT-{v}-{name}", lambda a=argv, v=v: a() + ["--set", f"K_T={v}"], [r"K_T"]))
    C.append(opt_case("opt-set-Kd-nan-fit", lambda: _fit() + ["--set", "Kd=nan,0.1,0.1"], [r"Kd"]))
    C.append(opt_case("opt-set-b-inf-simulate", lambda: _sim() + ["--set", "b=inf"], [r"\bb\b"]))
    for cmd, argv in (("fit", lambda: _fit(af="neg.toml")), ("simulate", lambda: _sim(af="neg.toml")),
                      ("linearize", lambda: _lin(af="neg.toml"))):
        C.append(opt_case(f"opt-airframe-negative-KT-{cmd}", argv, [r"K_T"],
                          prep=lambda c: edit_toml(AF, c.work / "neg.toml", "K_T", "-2.395e-5")))
    C.append(opt_case("opt-airframe-mass-nan-simulate", lambda: _sim(af="bad.toml"), [r"mass"],
                      prep=lambda c: edit_toml(AF, c.work / "bad.toml", "mass", "nan")))
    C.append(opt_case("opt-airframe-mass-0-linearize", lambda: _lin(af="bad.toml"), [r"mass"],
                      prep=lambda c: edit_toml(AF, c.work / "bad.toml", "mass", "0.0")))
    C.append(opt_case("opt-airframe-inertia-neg-fit", lambda: _fit(af="bad.toml"), [r"inertia"],
                      prep=lambda c: edit_toml(AF, c.work / "bad.toml", "inertia", "[-0.0082, 0.0082, 0.0149]")))
    C.append(opt_case("opt-max-iter--1-fit", lambda: _fit() + ["--max-iter=-1"], [r"max.iter"]))
    C.append(opt_case("opt-interval-0-fit", lambda: _fit() + ["--interval=0"], [r"interval"]))
    C.append(opt_case("opt-interval--5-fit", lambda: _fit() + ["--interval=-5"], [r"interval"]))
    for v in ("nan", "inf"):
        C.append(opt_case(f"opt-x0-{v}-simulate", lambda v=v: _sim() + ["--x0", f"0,0,-1,0,{v},0,0,0,0,0,0,0"], [r"x0"]))
    for opt, v in (("--duration", "nan"), ("--duration", "-1"), ("--rate", "0"), ("--digits", "-1")):
        C.append(opt_case(f"opt-synth{opt}-{v}", lambda o=opt, v=v: ["synth", "--airframe", AF, "--out", "s.csv",
                                                                      "--duration", "6", f"{o}={v}"], [opt.lstrip("-")]))

    # ---- 6: signals (a 50 s log, 11 free parameters: > 60 s of fitting; fresh cache: compile at ~1-4 s)
    def sig_setup(cmd):
        def setup(ctx):
            shutil.copy(ctx.fx / "long.csv", ctx.work / "long.csv")
            if cmd == "fit":
                return ["fit", "long.csv", "--airframe", AF, "--effects", "motor_lag,quadratic_drag,wind",
                        "--set", "K_T=1.5e-5", "--quiet", "--json", "out.json"]
            return ["diagnose", "long.csv", "--airframe", AF, "--quiet", "--json", "out.json", "--report", "report"]
        return setup
    # several points during the iterations: a signal that lands inside a CasADi call is the
    # one that gave SystemError tracebacks (timing-dependent, so more than one point)
    for sig, when, cmd in ((signal.SIGINT, 1.0, "fit"), (signal.SIGINT, 3.0, "fit"), (signal.SIGINT, 5.0, "fit"),
                           (signal.SIGINT, 8.0, "fit"), (signal.SIGINT, 10.0, "fit"), (signal.SIGINT, 12.5, "fit"),
                           (signal.SIGINT, "cc", "fit"), (signal.SIGINT, "cc-group", "fit"),
                           (signal.SIGTERM, "cc", "fit"), (signal.SIGTERM, 8.0, "fit"),
                           (signal.SIGINT, 4.0, "diagnose"), (signal.SIGINT, 8.0, "diagnose")):
        w = f"{when:g}s" if isinstance(when, float) else when
        C.append(Case(f"sig-{sig.name.lower()}-{w}-{cmd}", "6-signals", "signal", sig_setup(cmd), cache="fresh",
                      long=True, signal=(sig, when), timeout=30,
                      note={"cc": "sent to the main process when a C compiler of the run is seen",
                            "cc-group": "to the whole process group when a compiler is seen (a terminal's Ctrl-C)"
                            }.get(when, f"sent to the main process {w} after the start")))

    # ---- 7: cache states (fit and diagnose must succeed with the clean run's result)
    def cache_case(cid, cmd, prep, heal=False, readonly=False):
        def setup(ctx):
            shutil.copy(ctx.fx / "valid.csv", ctx.work / "log.csv")
            prep(ctx)
            return _fit() if cmd == "fit" else _diag()
        chk = check_fit_json if cmd == "fit" else check_diag_json
        if heal:
            h = check_healed(_fit)
            chk0 = chk
            chk = lambda c, r: chk0(c, r) or h(c, r)
        return Case(f"cache-{cid}-{cmd}", "7-cache", "ok", setup, cache="custom", check=chk, timeout=180,
                    long=cmd == "diagnose", readonly=["cache"] if readonly else [])

    def set_cache(ctx, path):
        ctx.cache = path

    def below_file(ctx):
        (ctx.root / "cachefile").write_text("not a directory\n")
        set_cache(ctx, ctx.root / "cachefile" / "greybox")

    def is_file(ctx):
        (ctx.root / "cachefile").write_text("not a directory\n")
        set_cache(ctx, ctx.root / "cachefile")

    def empty_ro(ctx):
        set_cache(ctx, ctx.work / "cache")
        ctx.cache.mkdir()

    def warm_copy(ctx):
        set_cache(ctx, ctx.work / "cache")
        shutil.copytree(ctx.fx / "cache", ctx.cache)
        return sorted(ctx.cache.glob("*.so"))

    def garbage_so(ctx):
        for so in warm_copy(ctx):
            so.write_bytes(b"this is not an ELF library\n" * 100)

    def empty_so(ctx):
        for so in warm_copy(ctx):
            so.write_bytes(b"")

    def truncated_so(ctx):
        for so in warm_copy(ctx):
            data = so.read_bytes()
            so.write_bytes(data[: len(data) // 2])

    def wrong_lib(ctx):
        libs = warm_copy(ctx)
        groups: dict = {}
        for so in libs:
            groups.setdefault(so.name.rsplit("_", 1)[0], []).append(so)
        # same function name, another model (the shape-mismatch case), else across names
        rings = [g for g in groups.values() if len(g) > 1] or [libs]
        for g in rings:
            data = [so.read_bytes() for so in g]
            for so, d in zip(g, data[1:] + data[:1]):
                so.write_bytes(d)

    def so_is_dir(ctx):
        for so in warm_copy(ctx):
            so.unlink()
            so.mkdir()

    def stale_tmp(ctx):
        for so in warm_copy(ctx):
            so.with_suffix(".99999.tmp").write_bytes(b"half a library")
            so.unlink()

    for cmd in ("fit", "diagnose"):
        C.append(cache_case("below-file", cmd, below_file))
        C.append(cache_case("readonly-empty", cmd, empty_ro, readonly=True))
        C.append(cache_case("garbage-so", cmd, garbage_so, heal=cmd == "fit"))
        C.append(cache_case("wrong-lib", cmd, wrong_lib, heal=cmd == "fit"))
    C.append(cache_case("is-file", "fit", is_file))
    C.append(cache_case("proc", "fit", lambda c: set_cache(c, Path("/proc/greybox-cache"))))
    C.append(cache_case("readonly-warm", "fit", lambda c: warm_copy(c), readonly=True))
    C.append(cache_case("empty-so", "fit", empty_so, heal=True))
    C.append(cache_case("truncated-so", "fit", truncated_so, heal=True))
    C.append(cache_case("so-is-dir", "fit", so_is_dir))
    C.append(cache_case("stale-tmp", "fit", stale_tmp))

    # ---- 8: smaller
    for d in ("0", "1", "3"):
        C.append(Case(f"small-synth-digits-{d}", "8-smaller", "either",
                      lambda c, d=d: ["synth", "--airframe", AF, "--duration", "6", "--seed", "1", "--out", "digits.csv",
                                      "--digits", d], [r"digits"], check=check_synth_loads, timeout=120))
    C += log_cases("small-negative-w2-all", "8-smaller", lambda s, c: s.map(["w2"], lambda w: -w), "fs", expect="note",
                   patterns=[r"negative", r"w2"], timeout=120)
    C += log_cases("small-negative-w1-one-row", "8-smaller", lambda s, c: s.set(100, "w1", "-5.0"), "s", expect="note",
                   patterns=[r"negative", r"w1"])

    def outlier(col, val, after=1000):
        def m(s, c):
            k = s.first_measured(col, after)
            c.env["row"] = k
            s.set(k, col, val)
        return m
    # the row is the first measured cell at or after line 1000 ('{row}' in a pattern: set at setup)
    C += log_cases("small-outlier-1e308-x", "8-smaller", outlier("x", "1e308"), "fd",
                   patterns=[r"\brow {row}\b", r"\bx\b"], timeout=120)
    C += log_cases("small-outlier-1e300-phi", "8-smaller", outlier("phi", "-1e300"), "f",
                   patterns=[r"\brow {row}\b", r"phi"], timeout=120)
    swap = lambda s, c: s.lines.__setitem__(slice(99, 101), [s.lines[100], s.lines[99]])
    C += log_cases("small-time-order", "8-smaller", swap, "fs", patterns=[r"\brow 10[12]\b"],
                   forbid=["float64("])
    C += log_cases("small-time-duplicate", "8-smaller", lambda s, c: s.set(50, "t", s.get(49, "t")), "fd",
                   patterns=[r"\brow 50\b"], forbid=["float64("])
    return C


# ----------------------------------------------------------------------------- running
@dataclass
class Result:
    rc: int | None
    stdout: str
    stderr: str
    wall: float
    timed_out: bool = False
    survivors: list = field(default_factory=list)


TOKEN_VAR = "GREYBOX_ADV_TOKEN"


def run_members(p: subprocess.Popen) -> list:
    """Live (non-zombie) processes of one run, [(pid, comm)]: its process group, anything that
    carries the run's token in its environment (every descendant, whatever session or process
    group it was started in, even after it was re-parented), and descendants by parent links."""
    procs = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            stat = Path(f"/proc/{d}/stat").read_text()
        except OSError:
            continue
        comm = stat[stat.index("(") + 1: stat.rindex(")")]
        rest = stat[stat.rindex(")") + 2:].split()
        if rest[0] not in ("Z", "X"):
            procs[int(d)] = (int(rest[1]), int(rest[2]), comm)
    tag = f"{TOKEN_VAR}={p.token}".encode()
    members = {}
    for pid, (ppid, pgrp, comm) in procs.items():
        if pid == os.getpid():
            continue
        if pgrp == p.pid:
            members[pid] = comm
            continue
        try:
            env = Path(f"/proc/{pid}/environ").read_bytes()
        except OSError:
            continue
        if tag in env.split(b"\0"):
            members[pid] = comm
    grown = True
    while grown:
        grown = False
        for pid, (ppid, _, comm) in procs.items():
            if pid not in members and (ppid in members or ppid == p.pid) and pid != os.getpid():
                members[pid] = comm
                grown = True
    return sorted(members.items())


def wait_run_gone(p: subprocess.Popen, wait: float = 0.5) -> list:
    """The run's live processes ``wait`` s after its main process ended (a run must not leave
    its compiler behind: it waits for or kills what it started before it exits)."""
    end = time.monotonic() + wait
    while True:
        alive = run_members(p)
        if not alive or time.monotonic() > end:
            return alive
        time.sleep(0.1)


def kill_run(p: subprocess.Popen) -> None:
    """SIGKILL to everything the run started (its group, its tagged descendants)."""
    try:
        os.killpg(p.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    for pid, _ in run_members(p):
        try:
            os.kill(pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


OPTS: argparse.Namespace


def child_env(ctx: Ctx, token: str) -> dict:
    env = dict(os.environ)
    env[TOKEN_VAR] = token
    env.pop("GREYBOX_NO_COMPILE", None)
    env.update({"OPENBLAS_NUM_THREADS": "1", "GREYBOX_CACHE": str(ctx.cache), "TMPDIR": str(ctx.root / "tmp"),
                "MPLBACKEND": "Agg", "PYTHONDONTWRITEBYTECODE": "1"})
    if not OPTS.installed:
        src = str(Path(OPTS.source).resolve()) if OPTS.source else str(REPO)
        env["PYTHONPATH"] = src + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def start(argv: list, ctx: Ctx, out, err) -> subprocess.Popen:
    token = os.urandom(8).hex()
    p = subprocess.Popen([sys.executable, "-m", "greybox", *map(str, argv)], cwd=ctx.work, env=child_env(ctx, token),
                         stdin=subprocess.DEVNULL, stdout=out, stderr=err, start_new_session=True)
    p.token = token
    try:
        resource.prlimit(p.pid, resource.RLIMIT_AS, (MEM_LIMIT, MEM_LIMIT))
    except (OSError, ValueError):
        pass
    return p


def run_greybox(argv: list, ctx: Ctx, timeout: float) -> Result:
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.monotonic()
        p = start(argv, ctx, out, err)
        timed_out = False
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            timed_out = True
            kill_run(p)
            p.wait()
        wall = time.monotonic() - t0
        survivors = [] if timed_out else wait_run_gone(p)
        kill_run(p)
        out.seek(0)
        err.seek(0)
        return Result(p.returncode, out.read(), err.read(), wall, timed_out, survivors)


def first_line(stderr: str) -> str:
    """The most telling stderr line: the greybox: line, else a traceback's last line, else the first."""
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    for ln in lines:
        if ln.startswith("greybox: error:") or ln.startswith("greybox: failed:"):
            return ln
    if "Traceback" in stderr and lines:
        return lines[-1]
    return lines[0] if lines else ""


def stderr_shape(stderr: str) -> tuple[str | None, list, list]:
    """(the error line or None, note lines, unexpected lines) of an error run's stderr."""
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    errs = [ln for ln in lines if ln.startswith("greybox: error:")]
    notes, extra = [], []
    in_usage = False
    for ln in lines:
        if ln.startswith("usage:"):
            in_usage = True
            continue
        if in_usage and ln[:1].isspace():
            continue
        in_usage = False
        if ln.startswith("greybox: error:"):
            continue
        if re.match(r"(greybox: )?note:", ln):
            notes.append(ln)
        else:
            extra.append(ln)
    return (errs[0] if len(errs) == 1 else None), notes, extra + (errs[1:] if len(errs) > 1 else [])


def snapshot(d: Path) -> dict:
    snap = {}
    for p in d.rglob("*"):
        try:
            st = p.lstat()
        except OSError:
            continue
        snap[str(p.relative_to(d))] = (st.st_size, st.st_mtime_ns, p.is_dir())
    return snap


def output_changes(before: dict, after: dict, ignore: tuple = ()) -> list:
    ch = []
    for k, v in after.items():
        if k.startswith(ignore):
            continue
        if k not in before:
            ch.append(f"+{k}")
        elif not v[2] and v[:2] != before[k][:2]:
            ch.append(f"~{k}")
    return sorted(ch)


def make_readonly(paths: list[Path]) -> Callable[[], None]:
    """Read-only directories; as root (who ignores modes) through the immutable attribute."""
    undo = []
    for p in paths:
        if os.geteuid() != 0:
            p.chmod(0o555)
            undo.append(lambda p=p: p.chmod(0o755))
        else:
            if subprocess.run(["chattr", "+i", str(p)], capture_output=True).returncode != 0:
                raise RuntimeError("cannot make a directory read-only as root (chattr +i failed)")
            undo.append(lambda p=p: subprocess.run(["chattr", "-i", str(p)], capture_output=True))
    return lambda: [u() for u in undo]


def evaluate(case: Case, ctx: Ctx, res: Result, changes: list) -> list:
    """Failure reasons (empty: the promise held)."""
    why = []
    if res.timed_out:
        why.append(f"no answer within {case.timeout:g} s (killed)")
    if "Traceback" in res.stderr or "Traceback" in res.stdout:
        why.append("traceback")
    if res.survivors:
        why.append("orphaned processes: " + ", ".join(f"{c}[{p}]" for p, c in res.survivors[:4]))
    for s in case.forbid:
        if s in res.stderr:
            why.append(f"stderr contains {s!r}")
    if res.timed_out:
        return why
    pywarn = [ln for ln in res.stderr.splitlines() if re.search(r"\.py:\d+: \w*(Warning|Error)", ln)]
    if pywarn:
        why.append(f"Python warning form on stderr: {pywarn[0][:60]}")

    def as_error() -> list:
        w = []
        if res.rc != 2:
            w.append(f"exit {res.rc}, expected 2")
        err, notes, extra = stderr_shape(res.stderr)
        if err is None:
            w.append("no single 'greybox: error:' line")
        else:
            if extra:
                w.append(f"{len(extra)} extra stderr line(s): {extra[0][:50]!r}")
            elif res.stderr.strip().splitlines()[-1] != err:
                w.append("the error line is not the last")
            for pat in case.patterns:
                pat = pat.replace("{row}", str(ctx.env.get("row", "?")))
                if not re.search(pat, err, re.I):
                    w.append(f"message does not match /{pat}/")
        if changes:
            w.append("output left behind: " + " ".join(changes[:4]))
        return w

    if case.expect == "error":
        why += as_error()
    elif case.expect == "ok":
        if res.rc != 0:
            why.append(f"exit {res.rc}, expected 0")
        elif case.check:
            why += case.check(ctx, res)
    elif case.expect == "note":
        if res.rc == 0:
            notes = [ln for ln in res.stderr.splitlines() if "note" in ln.lower()]
            pats = [p.replace("{row}", str(ctx.env.get("row", "?"))) for p in case.patterns]
            if not any(all(re.search(p, n, re.I) for p in pats) for n in notes):
                why.append("exit 0 without a note matching " + " & ".join(f"/{p}/" for p in case.patterns))
        else:
            why += as_error()
    elif case.expect == "either":
        if res.rc == 0:
            if case.check:
                why += case.check(ctx, res)
        else:
            why += as_error()
    return why


def run_case(case: Case, root: Path, fx: Path) -> dict:
    croot = Path(tempfile.mkdtemp(prefix=re.sub(r"[^\w.-]", "_", case.id) + "-", dir=root))
    work, tmp = croot / "work", croot / "tmp"
    work.mkdir()
    tmp.mkdir()
    cache = fx / "cache" if case.cache == "shared" else croot / "cache"
    ctx = Ctx(work, croot, fx, cache)
    undo = lambda: None
    t0 = time.monotonic()
    try:
        argv = case.setup(ctx)
        if case.readonly:
            try:
                undo = make_readonly([work / d for d in case.readonly])
            except RuntimeError as e:
                return {"id": case.id, "cause": case.cause, "expected": case.expected_text(), "rc": None,
                        "stderr": "", "status": "SKIP", "why": [str(e)], "wall": 0.0}
        before = snapshot(work)
        if case.signal:
            res, why = run_signal(case, ctx, argv)
        else:
            res = run_greybox(argv, ctx, case.timeout)
            after = snapshot(work)
            ignore = tuple(d for d in ("cache",) if case.cache == "custom")
            why = evaluate(case, ctx, res, output_changes(before, after, ignore))
        status = "PASS" if not why else "FAIL"
        rec = {"id": case.id, "cause": case.cause, "expected": case.expected_text(), "rc": res.rc,
               "stderr": first_line(res.stderr), "status": status, "why": why, "wall": round(res.wall, 2),
               "argv": " ".join(map(str, argv))[:300]}
    except Exception as e:  # noqa: BLE001 -- a broken case is reported, not fatal
        rec = {"id": case.id, "cause": case.cause, "expected": case.expected_text(), "rc": None, "stderr": "",
               "status": "FAIL", "why": [f"harness error in setup/run: {type(e).__name__}: {e}"],
               "wall": round(time.monotonic() - t0, 2)}
    finally:
        undo()
        if not OPTS.keep:
            shutil.rmtree(croot, ignore_errors=True)
    if OPTS.keep:
        rec["dir"] = str(croot)
    return rec


def run_signal(case: Case, ctx: Ctx, argv: list) -> tuple[Result, list]:
    sig, when = case.signal
    why: list = []
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.monotonic()
        p = start(argv, ctx, out, err)
        sent = None
        deadline = t0 + (when if isinstance(when, float) else 60.0)
        while p.poll() is None:
            now = time.monotonic()
            if isinstance(when, float):
                if now >= deadline:
                    break
            else:
                if any(c in COMPILERS for _, c in run_members(p)):
                    break
                if now >= deadline:
                    why.append("no compiler seen within 60 s (cache warm?)")
                    break
            time.sleep(0.05)
        if p.poll() is not None:
            why.append(f"the run ended (exit {p.returncode}) before the signal: case not exercised")
        elif why:      # trigger not reached: the case was not exercised; stop the run now
            kill_run(p)
        else:
            sent = time.monotonic() - t0
            if when == "cc-group":
                os.killpg(p.pid, sig)
            else:
                os.kill(p.pid, sig)
        timed_out = False
        try:
            p.wait(timeout=case.timeout)
        except subprocess.TimeoutExpired:
            timed_out = True
            why.append(f"still running {case.timeout:g} s after {sig.name}")
            kill_run(p)
            p.wait()
        survivors = [] if timed_out else wait_run_gone(p)
        kill_run(p)
        out.seek(0)
        err.seek(0)
        res = Result(p.returncode, out.read(), err.read(), time.monotonic() - t0, timed_out, survivors)
    if sent is None or timed_out:
        if res.survivors:
            why.append("orphaned processes")
        return res, why
    ok_rc = (130,) if sig == signal.SIGINT else (130, 143)
    if res.rc not in ok_rc:
        why.append(f"exit {res.rc} (signal sent at {sent:.1f} s), expected {'/'.join(map(str, ok_rc))}")
    if "Traceback" in res.stderr:
        why.append("traceback")
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    if len(lines) != 1 or not lines[0].startswith("greybox:"):
        why.append(f"{len(lines)} stderr lines, expected one 'greybox:' line")
    if (ctx.work / "out.json").exists():
        why.append("out.json written")
    if (ctx.work / "report").exists():
        why.append("report/ written")
    if res.survivors:
        why.append("orphaned processes: " + ", ".join(f"{c}[{p}]" for p, c in res.survivors[:4]))
    left = list((ctx.root / "tmp").iterdir())
    if left:
        why.append(f"temp files left in $TMPDIR: {left[0].name}")
    if ctx.cache.is_dir():
        partial = [p.name for p in ctx.cache.iterdir() if p.suffix == ".tmp"]
        if partial:
            why.append(f"partial cache file: {partial[0]}")
    res.stderr = res.stderr or ""
    return res, why


# ----------------------------------------------------------------------------- fixtures
def make_fixtures(fx: Path, need_long: bool) -> None:
    fx.mkdir(parents=True)
    (fx / "tmp").mkdir()
    ctx = Ctx(fx, fx, fx, fx / "cache")

    def gb(*argv, timeout=300):
        r = run_greybox(list(argv), ctx, timeout)
        if r.rc != 0:
            print(f"adversarial: fixture step 'greybox {' '.join(map(str, argv))}' failed (exit {r.rc}):\n"
                  f"{r.stderr[-3000:]}", file=sys.stderr)
            sys.exit(3)
    print("fixtures: synthetic logs, reference fit and diagnosis, warm compile cache ...", file=sys.stderr)
    gb("synth", "--airframe", AF, "--duration", "6", "--out", "valid.csv", "--seed", "1")
    gb("synth", "--airframe", AF_X, "--duration", "6", "--out", "valid_x.csv", "--seed", "1")
    s = Csv(fx / "valid.csv")
    idx = [s.col(n) for n in ("t", "w1", "w2", "w3", "w4")]
    (fx / "inputs.csv").write_text("\n".join(",".join(ln.split(",")[i] for i in idx) for ln in s.lines) + "\n")
    gb("fit", "valid.csv", "--airframe", AF, "--quiet", "--json", "ref_fit.json")
    gb("fit", "valid_x.csv", "--airframe", AF_X, "--quiet", "--json", "ref_fit_x.json")
    gb("diagnose", "valid.csv", "--airframe", AF, "--quiet", "--candidates", "quadratic_drag", "--no-iterate",
       "--json", "ref_diag.json")
    if need_long:
        gb("synth", "--airframe", AF, "--duration", "50", "--out", "long.csv", "--seed", "3",
           "--effects", "rotor_drag,ground_effect")


# ----------------------------------------------------------------------------- main
def main() -> int:
    global OPTS
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="regex: run the cases whose id or cause matches")
    ap.add_argument("--fast", action="store_true", help="skip interrupt and long cases")
    ap.add_argument("--jobs", type=int, default=2, help="cases run at once (interrupt cases always alone)")
    ap.add_argument("--installed", action="store_true", help="test the installed greybox, not this checkout")
    ap.add_argument("--source", metavar="DIR", help="test the greybox package in DIR (e.g. an exported commit: "
                                                    "git archive HEAD greybox | tar -x -C DIR)")
    ap.add_argument("--keep", action="store_true", help="keep the case directories")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    ap.add_argument("--json-out", help="write all results here")
    ap.add_argument("--width", type=int, default=70, help="stderr column width")
    OPTS = ap.parse_args()

    cases = build_cases()
    ids = [c.id for c in cases]
    dup = {i for i in ids if ids.count(i) > 1}
    assert not dup, dup
    if OPTS.only:
        cases = [c for c in cases if re.search(OPTS.only, c.id) or re.search(OPTS.only, c.cause)]
    if OPTS.fast:
        cases = [c for c in cases if not c.long and not c.signal]
    if OPTS.list:
        for c in cases:
            print(f"{c.id:42s} {c.cause:10s} {c.expected_text():18s} {c.note}")
        print(f"{len(cases)} cases")
        return 0
    if not cases:
        print("no case selected", file=sys.stderr)
        return 1

    t_start = time.monotonic()
    root = Path(tempfile.mkdtemp(prefix="greybox-adv-"))
    fx = root / "fixtures"
    try:
        make_fixtures(fx, need_long=any(c.signal for c in cases))
        t_fx = time.monotonic() - t_start
        print(f"fixtures ready in {t_fx:.0f} s; {len(cases)} cases"
              f" ({'installed greybox' if OPTS.installed else f'greybox from {OPTS.source or REPO}'})", file=sys.stderr)
        results: dict = {}
        lock = threading.Lock()
        n_done = [0]

        def one(case):
            rec = run_case(case, root, fx)
            with lock:
                results[case.id] = rec
                n_done[0] += 1
                print(f"[{n_done[0]:3d}/{len(cases)}] {rec['status']:4s} {case.id} ({rec['wall']:.1f} s)",
                      file=sys.stderr, flush=True)
        plain = [c for c in cases if not c.signal]
        with ThreadPoolExecutor(max(1, OPTS.jobs)) as pool:
            list(pool.map(one, plain))
        for c in cases:
            if c.signal:
                one(c)
    finally:
        if not OPTS.keep:
            shutil.rmtree(root, ignore_errors=True)
    total = time.monotonic() - t_start

    recs = [results[c.id] for c in cases]
    w = OPTS.width
    print(f"{'case':42s} {'cause':10s} {'expected':18s} {'rc':>4s}  {'stderr':{w}s}  result")
    print("-" * (42 + 10 + 18 + 4 + w + 16))
    for r in recs:
        st = r["stderr"].replace("\n", " ")
        st = st if len(st) <= w else st[: w - 3] + "..."
        print(f"{r['id']:42s} {r['cause']:10s} {r['expected'][:18]:18s} {str(r['rc']):>4s}  {st:{w}s}  {r['status']}")
    fails = [r for r in recs if r["status"] == "FAIL"]
    if fails:
        print("\nwhy they fail:")
        for r in fails:
            print(f"  {r['id']}: " + "; ".join(w if len(w) < 160 else w[:157] + "..." for w in r["why"]))
    print("\nby cause:")
    for cause in CAUSES:
        rs = [r for r in recs if r["cause"] == cause]
        if rs:
            n = {s: sum(r["status"] == s for r in rs) for s in ("PASS", "FAIL", "SKIP")}
            print(f"  {cause:10s} {n['PASS']:3d} pass {n['FAIL']:3d} fail" + (f" {n['SKIP']:3d} skip" if n["SKIP"] else "")
                  + f"   {CAUSES[cause]}")
    n_pass = sum(r["status"] == "PASS" for r in recs)
    print(f"\ntotal: {n_pass}/{len(recs)} pass, {len(fails)} fail, "
          f"{sum(r['status'] == 'SKIP' for r in recs)} skip; {total:.0f} s")
    if OPTS.json_out:
        Path(OPTS.json_out).write_text(json.dumps({"results": recs, "wall_s": round(total, 1)}, indent=1) + "\n")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())

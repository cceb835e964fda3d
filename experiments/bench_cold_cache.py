"""What a fresh machine pays for compiling: one command timed with an empty compile cache,
with the cache it leaves behind (warm), and on CasADi's virtual machine only.

    python experiments/bench_cold_cache.py [--repeat 1] [-- COMMAND ...]

Default command: ``python -m greybox demo --quiet`` (the bundled 30-s flight, diagnosed and
validated). Each repeat runs, in this order: cold (a new, empty ``GREYBOX_CACHE``), warm
(the cache that cold run filled), virtual machine only (``GREYBOX_NO_COMPILE=1``), each in
its own process with one BLAS thread. Prints every time, the medians, and the ratios
cold / warm and cold / virtual machine: the first is what compiling costs a first run, the
second whether compiling pays at all on a first run (below 1: it does).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DEFAULT = [sys.executable, "-m", "greybox", "demo", "--quiet"]


def timed(cmd: list[str], env: dict[str, str], cwd: Path) -> float:
    t0 = time.perf_counter()
    out = subprocess.run(cmd, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if out.returncode != 0:
        sys.exit(f"bench_cold_cache: {' '.join(cmd)} failed ({out.returncode}):\n{out.stderr[-2000:]}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("command", nargs="*", help="the command to time (after --)")
    a = ap.parse_args()
    cmd = a.command or DEFAULT
    base = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    base.pop("GREYBOX_NO_COMPILE", None)
    times: dict[str, list[float]] = {"cold": [], "warm": [], "virtual machine": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(a.repeat):
            cache = Path(tmp) / f"cache{r}"
            work = Path(tmp) / f"run{r}"
            work.mkdir()
            env = dict(base, GREYBOX_CACHE=str(cache))
            times["cold"].append(timed(cmd, env, work))
            times["warm"].append(timed(cmd, env, work))
            times["virtual machine"].append(timed(cmd, dict(env, GREYBOX_NO_COMPILE="1"), work))
            print(f"repeat {r + 1}: " + ", ".join(f"{k} {v[-1]:.1f} s" for k, v in times.items()), flush=True)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"command: {' '.join(cmd)}")
    print("medians: " + ", ".join(f"{k} {v:.1f} s" for k, v in med.items()))
    print(f"cold / warm = {med['cold'] / med['warm']:.2f}; cold / virtual machine = "
          f"{med['cold'] / med['virtual machine']:.2f}")


if __name__ == "__main__":
    main()

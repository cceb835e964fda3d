"""Speed-up of ``greybox batch`` with 1 and 2 worker processes on the real NanoBench flights,
and the same batch on a Dask scheduler and workers started as separate processes.

    python experiments/bench_batch.py [--flights 4] [--full] [--no-cluster]
                                      [--data ../shared/realdata/nanobench] [--out experiments/out/bench_batch]

Each run is ``greybox batch FILES --import nanobench --airframe cf.toml --process-noise auto``
(real logs: see README, "Real flights") in a fresh results folder, timed from the command's
start to its end (cluster start and shutdown included). The airframe comes from
``greybox import nanobench FIRST --airframe-out cf.toml``. By default the diagnosis ranks the
candidates real Crazyflie flights call for (``motor_asymmetry,cog_offset,thrust_drift,
battery_voltage``) once (``--no-iterate``), without the discovery beyond the catalogue
(``--no-discover``): one to two minutes a flight; ``--full`` runs every candidate with
iteration and discovery (several minutes a flight). A warm-up batch of one flight fills the
compile cache first, so that no timed run pays for compiling. Then: 1 worker, 2 workers, a
rerun (everything skipped), and (unless ``--no-cluster``) ``dask scheduler`` + ``dask worker
--nworkers 2 --nthreads 1`` started apart with ``--scheduler``. Prints the times and ratios
and writes ``bench_batch.json`` into ``--out``.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DATA = ROOT.parent / "shared" / "realdata" / "nanobench"
# the shorter flights first (24-27 s of data each), then the 32-42 s ones
ORDER = ["B3_figure8_medium_rep1", "B2_circle_fast_rep1", "B3_figure8_fast_rep1", "B9_trefoil_slow_rep1",
         "B6_linear_ramp_rep2", "B2_circle_slow_rep2", "B5_helix_fast_rep1", "B7_oval_fast_rep1",
         "B8_star_medium_rep1", "B10_lissajous_slow_rep1"]
QUICK = ["--candidates", "motor_asymmetry,cog_offset,thrust_drift,battery_voltage", "--no-iterate", "--no-discover"]


def env() -> dict:
    e = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return e


def greybox(*args: str, check: bool = True) -> tuple[float, subprocess.CompletedProcess]:
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "greybox", *args], env=env(), capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if check and p.returncode != 0:
        sys.exit(f"greybox {' '.join(args)} failed ({p.returncode}):\n{p.stderr}")
    return dt, p


def load() -> str:
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "?"


def summary(folder: Path) -> list[dict]:
    return json.loads((folder / "summary.json").read_text())


def start_cluster(tmp: Path) -> tuple[str, list[subprocess.Popen]]:
    """``dask scheduler`` and ``dask worker --nworkers 2 --nthreads 1`` as separate processes."""
    sched_file = tmp / "scheduler.json"
    quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True, env=env())
    sched = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--scheduler-file",
                              str(sched_file), "--host", "127.0.0.1", "--port", "0", "--no-dashboard"], **quiet)
    deadline = time.time() + 60
    while not sched_file.exists():
        if time.time() > deadline or sched.poll() is not None:
            sys.exit("the dask scheduler did not start")
        time.sleep(0.1)
    time.sleep(0.3)
    address = json.loads(sched_file.read_text())["address"]
    worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nworkers", "2",
                               "--nthreads", "1", "--no-dashboard"], **quiet)
    return address, [worker, sched]


def stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        try:
            os.killpg(p.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--flights", type=int, default=4, help="how many NanoBench flights (default 4)")
    ap.add_argument("--full", action="store_true", help="every candidate, with iteration (slow)")
    ap.add_argument("--no-cluster", action="store_true", help="skip the run on a separately started scheduler")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--out", type=Path, default=HERE / "out" / "bench_batch")
    args = ap.parse_args()
    files = [args.data / f"{n}.csv" for n in ORDER if (args.data / f"{n}.csv").exists()][:args.flights]
    if len(files) < args.flights:
        sys.exit(f"only {len(files)} NanoBench flights in {args.data}")
    args.out.mkdir(parents=True, exist_ok=True)
    opts = ["--import", "nanobench", "--process-noise", "auto", "--quiet"] + ([] if args.full else QUICK)
    result: dict = {"flights": [f.stem for f in files], "options": opts, "cpus": os.cpu_count(), "runs": {}}
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as tmp_s:
        tmp = Path(tmp_s)
        airframe = tmp / "cf.toml"
        greybox("import", "nanobench", str(files[0]), "--out", str(tmp / "first.csv"), "--airframe-out", str(airframe))
        common = ["--airframe", str(airframe)] + opts

        print(f"warm-up: one flight ({files[0].stem}), fills the compile cache; load {load()}", flush=True)
        dt, _ = greybox("batch", str(files[0]), "--out", str(tmp / "warm"), "--workers", "1", *common)
        result["runs"]["warm-up (1 flight, 1 worker)"] = dt

        def run(label: str, out: Path, *extra: str) -> float:
            before = load()
            dt, _ = greybox("batch", *map(str, files), "--out", str(out), *extra, *common)
            rows = summary(out)
            print(f"{label:<38} {dt:7.1f} s   ({', '.join(r['status'] for r in rows)}; load before {before})",
                  flush=True)
            result["runs"][label] = dt
            result.setdefault("summaries", {})[label] = rows
            return dt

        t1 = run("1 worker", tmp / "w1", "--workers", "1")
        t2 = run("2 workers", tmp / "w2", "--workers", "2")
        t_skip = run("rerun of '2 workers' (all skipped)", tmp / "w2", "--workers", "2")
        result["speedup_2_over_1"] = t1 / t2
        print(f"speed-up 2 workers / 1 worker: {t1 / t2:.2f}x; rerun {t_skip:.1f} s", flush=True)
        if not args.no_cluster:
            address, procs = start_cluster(tmp)
            try:
                tc = run("scheduler + 2 workers started apart", tmp / "cluster", "--scheduler", address)
            finally:
                stop(procs)
            result["speedup_cluster_over_1"] = t1 / tc
            print(f"speed-up on the separate scheduler / 1 local worker: {t1 / tc:.2f}x", flush=True)
        walls = {r["flight"]: r["wall_s"] for r in result["summaries"]["1 worker"]}
        result["per_flight_wall_s_1_worker"] = walls
        print("per flight (1 worker): " + ", ".join(f"{k} {v:.0f} s" for k, v in walls.items()))
    (args.out / "bench_batch.json").write_text(json.dumps(result, indent=2) + "\n")
    print(f"-> {args.out / 'bench_batch.json'}")


if __name__ == "__main__":
    main()

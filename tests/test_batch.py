"""``greybox batch`` on Dask distributed (contract section 9, issue 18).

A folder of short synthetic flights and a corrupt file: every good flight gets its results,
the corrupt one a failure row with its reason; a rerun skips what is unchanged and retries
what failed; a worker process that dies mid-run (a test hook ends it with ``os._exit``)
costs only its own flight, or nothing when the retry succeeds; user mistakes exit 2 with one
line (also without Dask installed); two processes compiling the same structure into one
compile cache at the same moment leave one good library. Slow: a weak rotor named by the
per-flight verdict, the joint fit naming it against the fleet, and a batch against a
scheduler and a worker started as separate processes.
"""
from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
import time
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

import greybox
from greybox.batch import (SUMMARY_COLUMNS, TEST_EXIT_ENV, Options, _flight_key, batch, expand_inputs,
                           fleet_comparison)
from greybox.cli import main

pytest.importorskip("distributed")

PAPER = str(resources.files("greybox") / "data" / "airframes" / "paper.toml")
K_T_TRUE = 2.395e-05
QUICK = ["--candidates", "ground_effect", "--no-iterate", "--no-discover"]   # one candidate, one round: seconds


def _synth(path: Path, seed: int, duration: float = 6.0, extra: list[str] | None = None) -> Path:
    rc = main(["synth", "--airframe", PAPER, "--out", str(path), "--duration", str(duration), "--rate", "100",
               "--vision-rate", "50", "--seed", str(seed), "--manoeuvres", "hover,step_x,step_y,yaw"] + (extra or []))
    assert rc == 0
    return path


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> Path:
    """Two good 6-s flights of the paper's quadrotor (seeds 1, 2) and a corrupt file."""
    d = tmp_path_factory.mktemp("flights")
    _synth(d / "good1.csv", 1)
    _synth(d / "good2.csv", 2)
    (d / "corrupt.csv").write_text("t,w1,w2,w3,w4,x,y,z,phi,theta,psi\n0,400,400,400,400,0,0,-1,0,0,0\n"
                                   "0.01,400,400,oops,400,0,0,-1,0,0,0\n")
    (d / "notes.txt").write_text("not a flight: ignored in a folder (only *.csv)\n")
    return d


@pytest.fixture(autouse=True)
def _one_blas_thread(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")


@pytest.mark.slow
def test_folder_with_a_corrupt_file_then_a_rerun_skips_and_retries(flights, tmp_path, capsys):
    flights = Path(shutil.copytree(flights, tmp_path / "in"))      # mended below
    out = tmp_path / "out"
    rc = main(["batch", str(flights), "--airframe", PAPER, "--out", str(out), "--workers", "2", "--quiet",
               "--json", str(tmp_path / "batch.json")] + QUICK)
    assert rc == 0
    rows = {r["flight"]: r for r in _rows(out / "summary.csv")}
    assert list(rows) == ["corrupt", "good1", "good2"]          # input order (sorted in the folder)
    header = next(csv.reader(open(out / "summary.csv")))
    assert header[:len(SUMMARY_COLUMNS)] == list(SUMMARY_COLUMNS)
    assert header[len(SUMMARY_COLUMNS):len(SUMMARY_COLUMNS) + 4] == ["K_T", "K_T_std", "b", "b_std"]
    bad = rows["corrupt"]
    assert bad["status"] == "failed" and "corrupt.csv" in bad["reason"] and "row 3" in bad["reason"] \
        and "'w3'" in bad["reason"]
    assert bad["K_T"] == "" and bad["verdict"] == ""
    for name in ("good1", "good2"):
        r = rows[name]
        assert r["status"] == "ok" and r["reason"] == "" and r["verdict"] == ""     # null verdict: empty
        assert float(r["nrmse_before"]) > 0 and float(r["nrmse_after"]) > 0 and float(r["wall_s"]) > 0
        assert abs(float(r["K_T"]) / K_T_TRUE - 1) < 0.01 and float(r["K_T_std"]) > 0
        folder = out / name
        fit = json.loads((folder / "fit.json").read_text())       # greybox fit --json's format
        assert set(fit) >= {"parameters", "validation", "effects", "horizons"}
        assert fit["parameters"]["K_T"]["value"] == pytest.approx(float(r["K_T"]), rel=1e-12)
        assert fit["validation"]["nrmse"] == pytest.approx(float(r["nrmse_before"]), rel=1e-12)
        diag = json.loads((folder / "diagnose.json").read_text())   # greybox diagnose --json's format
        assert set(diag) >= {"baseline", "ranking", "verdict"} and diag["verdict"] is None
        assert (folder / "report" / "report.html").is_file()
        fm = greybox.load(folder / "model.json")
        assert fm.value("K_T") == pytest.approx(float(r["K_T"]), rel=1e-12)
    records = json.loads((out / "summary.json").read_text())
    assert [x["flight"] for x in records] == ["corrupt", "good1", "good2"]
    assert records[1]["K_T"] == pytest.approx(float(rows["good1"]["K_T"]), rel=1e-15)
    assert records[0]["verdict"] is None and records[0]["status"] == "failed"
    assert json.loads((tmp_path / "batch.json").read_text())["counts"] == {"ok": 2, "failed": 1, "skipped": 0}
    assert "2 ok, 1 failed" in capsys.readouterr().out

    # rerun: the good flights are skipped with their earlier results, the failed one is tried again
    stamps = {n: os.stat(out / n / "batch.json").st_mtime_ns for n in rows}
    time.sleep(0.05)
    rc = main(["batch", str(flights), "--airframe", PAPER, "--out", str(out), "--workers", "2", "--quiet"] + QUICK)
    assert rc == 0
    again = {r["flight"]: r for r in _rows(out / "summary.csv")}
    for name in ("good1", "good2"):
        assert again[name]["status"] == "skipped"
        assert {k: v for k, v in again[name].items() if k != "status"} == \
               {k: v for k, v in rows[name].items() if k != "status"}
        assert os.stat(out / name / "batch.json").st_mtime_ns == stamps[name]     # not recomputed
    assert again["corrupt"]["status"] == "failed"
    assert os.stat(out / "corrupt" / "batch.json").st_mtime_ns != stamps["corrupt"]  # retried

    # the failed flight mended: now it runs, the others stay skipped
    _synth(flights / "corrupt.csv", 3)
    rc = main(["batch", str(flights), "--airframe", PAPER, "--out", str(out), "--workers", "2", "--quiet"] + QUICK)
    assert rc == 0
    third = {r["flight"]: r for r in _rows(out / "summary.csv")}
    assert third["corrupt"]["status"] == "ok" and third["good1"]["status"] == "skipped"

    # a copy of a flight is no second flight: left out, and out of the joint fit (a blind audit's
    # joint fit of a flight and its copy had every std /sqrt(2))
    shutil.copy(flights / "good1.csv", flights / "good1_copy.csv")
    rc = main(["batch", str(flights), "--airframe", PAPER, "--out", str(out), "--workers", "1", "--joint"] + QUICK)
    said = capsys.readouterr()
    assert rc == 0
    fourth = {r["flight"]: r for r in _rows(out / "summary.csv")}
    assert fourth["good1_copy"]["status"] == "skipped" and "the same bytes as good1" in fourth["good1_copy"]["reason"]
    assert "good1_copy: the same bytes as another input" in said.out + said.err
    fleet = json.loads((out / "fleet.json").read_text())
    assert "good1" in fleet["flights"] and "good1_copy" not in fleet["flights"]

    # b held at a bench value (5 % above the truth) in every flight's fits and in the joint fit
    b_held = 1.05 * greybox.load_airframe(PAPER).parameters["b"]
    rc = main(["batch", str(flights / "good1.csv"), str(flights / "good2.csv"), "--airframe", PAPER, "--out",
               str(tmp_path / "held"), "--workers", "2", "--quiet", "--joint", "--set", f"b={b_held!r}",
               "--fixed", "b"] + QUICK)
    assert rc == 0
    for name in ("good1", "good2"):
        b = json.loads((tmp_path / "held" / name / "fit.json").read_text())["parameters"]["b"]
        assert b["value"] == pytest.approx(b_held, rel=1e-12) and b.get("fixed") is True, b
        assert greybox.load(tmp_path / "held" / name / "model.json").value("b") == pytest.approx(b_held, rel=1e-12)
    assert greybox.load(tmp_path / "held" / "fleet_model.json").value("b") == pytest.approx(b_held, rel=1e-12)


@pytest.mark.slow
def test_a_worker_that_dies_costs_only_its_own_flight(flights, tmp_path, monkeypatch):
    """The hook ends the worker process (os._exit) on good1 every time (failed after one
    retry, with its reason) and on good2 the first time only (retried on a fresh worker: ok)."""
    folder = tmp_path / "in"
    folder.mkdir()
    for name in ("good1", "good2"):
        shutil.copy(flights / f"{name}.csv", folder / f"{name}.csv")
    marker = tmp_path / "died-once"
    monkeypatch.setenv(TEST_EXIT_ENV, f"good1,good2@{marker}")
    res = batch([folder], tmp_path / "out", airframe=PAPER, workers=2, candidates=["ground_effect"], iterate=False,
                discover=False, progress=False)
    assert marker.exists()
    one, two = res.record("good1"), res.record("good2")
    assert one["status"] == "failed" and "worker process died" in one["reason"] and "2 times" in one["reason"]
    assert two["status"] == "ok" and abs(two["K_T"] / K_T_TRUE - 1) < 0.01
    meta = json.loads((tmp_path / "out" / "good2" / "batch.json").read_text())
    assert meta["attempts"] == 2
    assert res.counts == {"ok": 1, "failed": 1, "skipped": 0}


def test_without_dask_exit_2_says_how_to_install(flights, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)      # import distributed -> ImportError
    rc = main(["batch", str(flights), "--airframe", PAPER, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1
    assert "pip install 'greybox[batch]'" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_a_scheduler_that_cannot_be_reached_leaves_no_folder(flights, tmp_path, monkeypatch, capsys):
    """The engine fails after the inputs are checked (an audit: 'cannot connect ... after 20
    s', exit 2, and an empty output folder left behind); a folder that was there stays."""
    gb = sys.modules["greybox.batch"]
    from greybox.errors import GreyboxInputError

    def unreachable(self):
        raise GreyboxInputError("--scheduler tcp://127.0.0.1:1: cannot connect (OSError: timed out)")
    monkeypatch.setattr(gb._Engine, "__enter__", unreachable)
    args = ["batch", str(flights), "--airframe", PAPER, "--scheduler", "tcp://127.0.0.1:1"]
    assert main(args + ["--out", str(tmp_path / "new" / "out")]) == 2
    assert "cannot connect" in capsys.readouterr().err and not (tmp_path / "new" / "out").exists()
    (tmp_path / "kept").mkdir()
    assert main(args + ["--out", str(tmp_path / "kept")]) == 2
    assert (tmp_path / "kept").is_dir()


@pytest.mark.parametrize("args, message", [
    (["--workers", "0"], "--workers"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"], "exclude each other"),
    (["--scheduler", "no port here"], "expected an address"),
    (["--effects", "magic"], "unknown effect 'magic'"),
    (["--candidates", "magic"], "unknown effect 'magic'"),
    (["--candidates", "yaw_torque"], "already in the model"),
    (["--pwm-map", "1,2"], "--pwm-map applies to imported logs"),
    (["--angle-unit", "rad"], "--angle-unit applies to NanoBench logs"),
    (["--import", "px4", "--angle-unit", "deg"], "--angle-unit applies to NanoBench logs"),
    (["--import", "nanobench", "--angle-unit", "grad"], "invalid choice"),
    (["--import", "nanobench", "--pwm-map", "x"], "--pwm-map"),
    (["--import", "magic"], "invalid choice"),
    (["--set", "K_T=-1"], "K_T"),
    (["--process-noise", "yes"], "invalid choice"),
    (["--noise", "roll=0.01"], "expected CHANNEL=SD"),
    (["--noise", "phi=0"], "positive number"),
    (["--fixed", "b,k_typo"], "--fixed: unknown parameter 'k_typo'"),
])
def test_bad_options_exit_2_with_one_line(flights, tmp_path, capsys, args, message):
    rc = main(["batch", str(flights), "--airframe", PAPER, "--out", str(tmp_path / "out")] + args)
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.startswith("greybox: error:") and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "out").exists()


def test_bad_inputs_exit_2_with_one_line(flights, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    twin = tmp_path / "twin"
    twin.mkdir()
    shutil.copy(flights / "good1.csv", twin / "good1.csv")
    (tmp_path / "file").write_text("x")
    cases = [([str(tmp_path / "missing.csv")], [], "no such file or folder"),
             ([str(empty)], [], "no flight files (*.csv) in this folder"),
             ([str(tmp_path / "nothing*.csv")], [], "matches no file"),
             ([str(flights), str(twin)], [], "two inputs are named 'good1'"),
             ([str(flights)], ["--airframe", str(tmp_path / "nope.toml")], "not found"),
             ([str(flights)], ["--out", str(tmp_path / "file")], "exists and is not a folder")]
    for inputs, extra, message in cases:
        args = ["batch"] + inputs + ["--out", str(tmp_path / "out")] + extra
        if "--airframe" not in extra:
            args += ["--airframe", PAPER]
        rc = main(args)
        err = capsys.readouterr().err
        assert rc == 2 and err.startswith("greybox: error:") and err.count("\n") == 1 and message in err, (inputs, err)
    assert not (tmp_path / "out").exists()


def test_inputs_folders_globs_and_files_are_flights_once_each(flights):
    got = expand_inputs([flights, str(flights / "good*.csv"), flights / "good1.csv"])
    assert [p.name for p in got] == ["corrupt.csv", "good1.csv", "good2.csv"]


def test_the_hash_changes_with_input_content_and_options():
    a = Options(airframe=PAPER)
    fp = a.fingerprint()
    assert _flight_key("abc", fp) == _flight_key("abc", Options(airframe=PAPER).fingerprint())
    assert _flight_key("abc", fp) != _flight_key("abd", fp)
    for other in (Options(airframe=PAPER, effects="ground_effect"), Options(airframe=PAPER, iterate=False),
                  Options(airframe=PAPER, discover=False),
                  Options(airframe=PAPER, candidates=("wind",)), Options(airframe=PAPER, process_noise="auto"),
                  Options(airframe=PAPER, sets=(("K_T", (3e-5,)),)), Options(airframe=PAPER, noise=(("phi", 0.01),)),
                  Options(airframe=PAPER, fixed=("b",))):
        assert _flight_key("abc", other.fingerprint()) != _flight_key("abc", fp)
    # options added later enter the hash only when given: earlier batches' results stay valid
    assert "noise" not in fp and "angle_unit" not in fp and "fixed" not in fp
    with pytest.raises(greybox.GreyboxInputError, match="not a log channel"):
        batch([], "unused", airframe=PAPER, noise={"roll": 0.01})


def test_a_nanobench_flight_without_the_quaternion_reads_its_angles_in_the_unit_given(tmp_path):
    """A still flight (tilt held at 0.01) cannot show its angles' unit from the motion: read
    through the importer it is one clear error asking for the unit, and with
    ``angle_unit="deg"`` (``--angle-unit deg``) the flight reads, its roll in radians; the
    unit given is part of the flight's key (a rerun with another unit is not skipped), the
    default not (batches from before the option stay valid)."""
    import pandas as pd
    from greybox.batch import _read_flight, _sha_bytes
    from greybox.errors import GreyboxInputError
    df = pd.read_csv(Path(__file__).resolve().parent / "data" / "nanobench_B2_slice.csv")
    still = df.drop(columns=["qx", "qy", "qz", "qw"])
    still[["roll", "pitch"]] = 0.57                     # degrees: 0.01 rad
    path = tmp_path / "still.csv"
    still.to_csv(path, index=False)
    sha = _sha_bytes(path.read_bytes())
    with pytest.raises(GreyboxInputError, match="angle_unit='rad' or 'deg'"):
        _read_flight(str(path), sha, Options(airframe=PAPER, import_format="nanobench"))
    log, notes = _read_flight(str(path), sha, Options(airframe=PAPER, import_format="nanobench", angle_unit="deg"))
    assert any("in degrees (as given)" in n for n in notes), notes
    phi = log.output("phi")
    assert np.allclose(phi[np.isfinite(phi)], np.radians(0.57))
    auto = Options(airframe=PAPER, import_format="nanobench")
    assert "angle_unit" not in auto.fingerprint()
    assert _flight_key("abc", auto.fingerprint()) != _flight_key(
        "abc", Options(airframe=PAPER, import_format="nanobench", angle_unit="deg").fingerprint())


def _fit_json(K, devs, std=1e-3, dev_std=1e-3, extra=None):
    """A fit JSON with K_T, K_T_dev[0..2] (and ``extra``) free, uncorrelated."""
    params = {"K_T": {"value": K, "std": K * std}}
    params.update({f"K_T_dev[{i}]": {"value": d, "std": dev_std} for i, d in enumerate(devs)})
    params.update(extra or {})
    free = list(params)
    return {"parameters": params, "free": free, "correlation": np.eye(len(free)).tolist()}


def test_fleet_comparison_names_a_weak_rotor_in_words():
    """Four flights of a healthy vehicle and one whose rotor 2 gives 90 % of the thrust
    (K_T the mean of the four: 0.975, d = (1, 0.9, 1, 1)/0.975 - 1)."""
    rng = np.random.default_rng(0)
    fits = {f"f{k}": _fit_json(2e-5 * (1 + 1e-3 * rng.standard_normal()), 1e-3 * rng.standard_normal(3),
                               extra={"b": {"value": 5e-7, "std": 5e-9}}) for k in range(4)}
    weak = np.array([1.0, 0.9, 1.0, 1.0]) / 0.975 - 1
    fits["odd"] = _fit_json(2e-5 * 0.975, weak[:3], extra={"b": {"value": 5e-7, "std": 5e-9}})
    fleet = _fit_json(2e-5, [0.0, 0.0, 0.0], std=5e-4, dev_std=5e-4, extra={"b": {"value": 5e-7, "std": 2e-9}})
    for reference in (fleet, None):        # the joint fit's values, or the robust screen (median)
        c = fleet_comparison(fits, reference)
        assert c["rotor_coefficients"]
        assert c["outliers"]["odd"][0].startswith("flight odd: rotor 2 at 90 % of the fleet's thrust coefficient")
        assert not any(c["outliers"][f"f{k}"] for k in range(4)), c["outliers"]
        assert not any("rotor 1" in s or "rotor 3" in s or "rotor 4" in s for s in c["outliers"]["odd"])
    # without motor_asymmetry: per parameter
    plain = {n: {**f, "parameters": {"K_T": f["parameters"]["K_T"]}, "free": ["K_T"], "correlation": [[1.0]]}
             for n, f in fits.items()}
    c = fleet_comparison(plain, None)
    assert len(c["outliers"]["odd"]) == 1 and not any(c["outliers"][f"f{k}"] for k in range(4))
    assert c["outliers"]["odd"][0].startswith("flight odd: K_T at 98 % of the fleet's value")   # 0.975 / median


def test_processes_compiling_the_same_structure_at_once_share_one_cache(tmp_path):
    """Batch workers share the compile cache: three processes compile one model structure at
    the same moment (each into its own temporary folder, installed by an atomic rename); all
    get a working function and the cache holds one good library."""
    script = tmp_path / "compile.py"
    script.write_text(f"""
import sys, time
from pathlib import Path
import numpy as np
from greybox import QuadrotorModel, effects, load_airframe
from greybox.codegen import compiled
from greybox.integrate import rk4_step
model = QuadrotorModel(load_airframe({PAPER!r})) + effects.GroundEffect() + effects.MotorLag()
f = rk4_step(model + effects.QuadraticDrag(), 8)      # about a second of gcc
Path(sys.argv[1] + ".ready").touch()
while not Path(sys.argv[2]).exists():
    time.sleep(0.005)
g, how = compiled(f, key="batch-concurrency-test")
args = [np.linspace(0.1, 1.0, f.size1_in(i) * f.size2_in(i)).reshape(f.size1_in(i), f.size2_in(i), order="F")
        for i in range(f.n_in())]
assert np.allclose(np.asarray(g(*args)), np.asarray(f(*args)), rtol=1e-12, atol=1e-14)
print(how)
""")
    cache = tmp_path / "cache"
    env = dict(os.environ, GREYBOX_CACHE=str(cache), OPENBLAS_NUM_THREADS="1")
    env.pop("GREYBOX_NO_COMPILE", None)
    if shutil.which(env.get("CC", "gcc")) is None and shutil.which("cc") is None:
        pytest.skip("no C compiler")
    go = tmp_path / "go"
    root = str(Path(greybox.__file__).resolve().parents[1])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    procs = [subprocess.Popen([sys.executable, str(script), str(tmp_path / f"p{k}"), str(go)], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for k in range(3)]
    deadline = time.time() + 120
    while not all((tmp_path / f"p{k}.ready").exists() for k in range(3)):
        assert time.time() < deadline and all(p.poll() is None for p in procs), [p.communicate() for p in procs]
        time.sleep(0.01)
    go.touch()                               # both start compiling now
    outs = [p.communicate(timeout=300) for p in procs]
    assert all(p.returncode == 0 for p in procs), outs
    hows = sorted(o.strip().splitlines()[-1] for o, _ in outs)
    assert set(hows) <= {"compiled", "cached"} and "compiled" in hows, outs
    libs = list(cache.glob("*.so"))
    assert len(libs) == 1, list(cache.iterdir())
    assert not [p for p in cache.iterdir() if p.suffix == ".tmp"]     # no temporary left behind
    # a third process finds it and uses it
    third = subprocess.run([sys.executable, str(script), str(tmp_path / "p9"), str(go)], env=env,
                           capture_output=True, text=True, timeout=300)
    assert third.returncode == 0 and third.stdout.strip() == "cached", third


# ---------------------------------------------------------------------------- slow
@pytest.fixture(scope="module")
def weak_flight(tmp_path_factory) -> Path:
    """An 8-s flight whose rotor 2 gives 90 % of the thrust of the others (seed 15)."""
    d = tmp_path_factory.mktemp("weak")
    return _synth(d / "weak.csv", 15, 8.0, ["--effects", "motor_asymmetry", "--set", "K_T=2.3351e-05",
                                            "--set", "K_T_dev=0.025641,-0.076923,0.025641"])


@pytest.mark.slow
def test_a_weak_rotor_is_the_verdict_of_its_flight(flights, weak_flight, tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    shutil.copy(weak_flight, folder / "weak.csv")
    shutil.copy(flights / "good1.csv", folder / "good1.csv")
    res = batch([folder], tmp_path / "out", airframe=PAPER, workers=2, progress=False)   # every candidate
    assert res.record("weak")["verdict"] == "motor_asymmetry"
    assert res.record("good1")["verdict"] is None
    rows = {r["flight"]: r for r in _rows(tmp_path / "out" / "summary.csv")}
    assert rows["weak"]["verdict"] == "motor_asymmetry" and rows["good1"]["verdict"] == ""


@pytest.mark.slow
def test_joint_fit_names_the_weak_rotor_against_the_fleet(weak_flight, tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    for seed in (11, 12, 13, 14):
        _synth(folder / f"n{seed}.csv", seed, 8.0)
    shutil.copy(weak_flight, folder / "weak.csv")
    out = tmp_path / "out"
    rc = main(["batch", str(folder), "--airframe", PAPER, "--effects", "motor_asymmetry", "--out", str(out),
               "--workers", "2", "--joint", "--quiet"] + QUICK)
    assert rc == 0
    rows = {r["flight"]: r for r in _rows(out / "summary.csv")}
    assert rows["weak"]["fleet"].startswith("flight weak: rotor 2 at 90 % of the fleet's thrust coefficient")
    assert all(rows[f"n{s}"]["fleet"] == "" for s in (11, 12, 13, 14))
    fleet = json.loads((out / "fleet.json").read_text())
    assert fleet["flights"] == ["n11", "n12", "n13", "n14"] and list(fleet["left_out"]) == ["weak"]
    assert fleet["converged"] and fleet["fit"]["parameters"]["K_T"]["value"] == pytest.approx(K_T_TRUE, rel=2e-3)
    assert greybox.load(out / "fleet_model.json").value("K_T") == fleet["fit"]["parameters"]["K_T"]["value"]
    # rerun: nothing to compute, the joint fit is kept
    t0 = time.perf_counter()
    assert main(["batch", str(folder), "--airframe", PAPER, "--effects", "motor_asymmetry", "--out", str(out),
                 "--workers", "2", "--joint", "--quiet"] + QUICK) == 0
    assert {r["status"] for r in _rows(out / "summary.csv")} == {"skipped"}
    assert time.perf_counter() - t0 < 60      # generous: nothing is fitted (no cluster is started)


@pytest.mark.slow
def test_batch_against_a_scheduler_and_a_worker_started_apart(flights, tmp_path):
    """As a user with a cluster would: 'dask scheduler' and 'dask worker' as separate processes."""
    root = str(Path(greybox.__file__).resolve().parents[1])
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    sched_file = tmp_path / "scheduler.json"
    dask_cli = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    sched = subprocess.Popen(dask_cli + ["--scheduler-file", str(sched_file), "--host", "127.0.0.1", "--port", "0",
                                         "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True)
    worker = None
    try:
        deadline = time.time() + 60
        while not sched_file.exists():
            assert time.time() < deadline and sched.poll() is None
            time.sleep(0.1)
        time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                                   "--nworkers", "2", "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL, start_new_session=True)
        rc = main(["batch", str(flights / "good1.csv"), str(flights / "good2.csv"), "--airframe", PAPER,
                   "--out", str(tmp_path / "out"), "--scheduler", address, "--quiet"] + QUICK)
        assert rc == 0
        rows = _rows(tmp_path / "out" / "summary.csv")
        assert [r["status"] for r in rows] == ["ok", "ok"]
    finally:
        for p in (worker, sched):
            if p is not None:
                os.killpg(p.pid, 15)
                p.wait(timeout=30)


@pytest.mark.slow
def test_imu_only_flights_get_the_imu_only_fit_and_stay_out_of_the_joint_fit(tmp_path, capsys):
    """A nineteenth blind audit's uSD logs (gyro, accelerometer, motors; no position) all failed
    in a batch ("column 'x' is empty") where `greybox fit` fits them by the IMU-only equations:
    a batch now does the same, its summary holding the torque gains and the motor lag, and the
    joint trajectory fit leaves them out, saying why. A flight whose IMU-only fit is NOT
    ADEQUATE (seed 3's rotor 1 at 0.97: a torque the model lacks) says so in its row's
    `adequate` and `reason` (a blind audit's weak rotor read like its control in the summary)."""
    from foreign_sim import airframe_dict, airframe_toml, crazyflie, simulate_flight
    from greybox.data import FlightLog, save_log
    veh = crazyflie()
    d = tmp_path / "imu"
    d.mkdir()
    for seed in (2, 3):
        log = simulate_flight(veh, duration=12.0, seed=seed, accel=True, log_commands=True,
                              motor_gains=[0.97, 1.01, 1.01, 1.01] if seed == 3 else None).log
        Y = log.outputs.copy()
        for c in ("x", "y", "z", "phi", "theta", "psi"):
            Y[:, log.output_names.index(c)] = np.nan
        save_log(FlightLog(log.t, log.inputs, log.input_names, Y, list(log.output_names), dict(log.extras), [],
                           f"imu{seed}.csv"), d / f"imu{seed}.csv")
    af = tmp_path / "cf.toml"
    af.write_text(airframe_toml(airframe_dict(veh, K_T_guess_factor=1.3)))
    rc = main(["batch", str(d), "--airframe", str(af), "--out", str(tmp_path / "out"), "--workers", "1", "--joint"])
    said = capsys.readouterr()
    err = said.err + said.out
    assert rc == 0, err
    rows = _rows(tmp_path / "out" / "summary.csv")
    assert [r["status"] for r in rows] == ["ok", "ok"] and all("IMU-only" in r["reason"] for r in rows)
    assert [r["adequate"] for r in rows] == ["true", "false"], [r["reason"] for r in rows]
    assert "NOT ADEQUATE" not in rows[0]["reason"]
    assert "; NOT ADEQUATE: a systematic torque the model lacks (" in rows[1]["reason"]
    assert "x the gyro's noise" in rows[1]["reason"] and "% of its torque)" in rows[1]["reason"]
    for r in rows:
        assert float(r["K_T"]) == pytest.approx(veh.K_T, rel=0.01)
        assert r["verdict"] == ""
    # the weak rotor's torque moves what the torque equations fit (its lag 24.5 ms for 20)
    assert float(rows[0]["tau_m"]) == pytest.approx(veh.tau_motor, rel=0.1)
    assert abs(float(rows[0]["g_x"]) - 1.0) < 3 * float(rows[0]["g_x_std"]) < 0.05
    assert json.loads((tmp_path / "out" / "imu2" / "fit.json").read_text())["imu_only"] is True
    diag = json.loads((tmp_path / "out" / "imu2" / "diagnose.json").read_text())
    assert diag["verdict"] is None and diag["null_reason"] == "imu_only" and diag["ranking"] == []
    assert "K_T" in (tmp_path / "out" / "imu2" / "report" / "summary.txt").read_text()
    assert "IMU-only fit (no position: not diagnosed)" in err and "IMU-only, fitted on their own" in err


@pytest.mark.slow
def test_the_final_models_values_stand_beside_the_baselines(weak_flight, flights, tmp_path):
    """A blind audit's hidden motor lag was the verdict, but the summary held the baseline's
    values (Kd[2] 4.6 std off) and no tau_m: where a diagnosis added effects, the final model's
    values follow as final_NAME (empty on the other rows)."""
    folder = tmp_path / "in"
    folder.mkdir()
    shutil.copy(weak_flight, folder / "weak.csv")
    shutil.copy(flights / "good1.csv", folder / "good1.csv")
    rc = main(["batch", str(folder), "--airframe", PAPER, "--out", str(tmp_path / "out"), "--workers", "1",
               "--quiet", "--candidates", "motor_asymmetry", "--no-iterate", "--no-discover"])
    assert rc == 0
    rows = {r["flight"]: r for r in _rows(tmp_path / "out" / "summary.csv")}
    weak, good = rows["weak"], rows["good1"]
    assert weak["verdict"] == "motor_asymmetry" and good["verdict"] == ""
    dev, std = float(weak["final_K_T_dev[1]"]), float(weak["final_K_T_dev[1]_std"])
    assert abs(dev - (-0.076923)) < 3 * std < 0.02, (dev, std)
    assert good["final_K_T"] == "" and "K_T_dev[1]" not in weak       # the baseline holds no K_T_dev
    assert float(weak["final_K_T"]) == pytest.approx(2.3351e-05, rel=0.01)

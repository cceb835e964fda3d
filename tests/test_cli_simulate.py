"""`greybox simulate` (contract §5) against an independent implementation, and its errors."""
import json
import subprocess
import sys
import zlib

import numpy as np
import pytest

from greybox.cli import main
from greybox.data import load_log

import reference_quad as ref

AF = """[airframe]
name = "t"
mass = {mass}
inertia = [{jx}, {jy}, {jz}]
arm_length = {l}
layout = "{layout}"
rotor_inertia = {jr}

[parameters]
K_T = {kt}
b = {b}
Kd = [{kd0}, {kd1}, {kd2}]
"""


def write_inputs(path, t, W, names=("t", "w1", "w2", "w3", "w4")):
    M = np.column_stack([t, W])
    path.write_text(",".join(names) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in M) + "\n")


@pytest.mark.parametrize("layout", ["plus", "x"])
@pytest.mark.parametrize("jr", [0.0, 4e-5])
def test_simulate_matches_independent_physics(tmp_path, layout, jr):
    # a seed fixed per case: hash() of a str changes from one process to the next
    rng = np.random.default_rng(zlib.crc32(f"{layout} {jr}".encode()))
    cfg = dict(mass=0.9 + 0.3 * rng.random(), jx=0.008, jy=0.009, jz=0.015, l=0.2, layout=layout, jr=jr,
               kt=2.2e-5, b=6e-7, kd0=0.1, kd1=0.15, kd2=0.2)
    (tmp_path / "a.toml").write_text(AF.format(**cfg))
    w_h = np.sqrt(cfg["mass"] * 9.81 / (4 * cfg["kt"]))
    t = np.arange(0, 1.5 + 1e-9, 0.01)   # 100 Hz random rotor-speed sequence
    W = w_h * (1 + 0.03 * rng.standard_normal((t.size, 4)))
    W[t < 0.5, 0] *= 1.002  # a rotor pair's difference for 0.5 s: a torque that tilts the vehicle
    W[t < 0.5, 2] *= 0.998  # whatever the noise draws, in either layout
    write_inputs(tmp_path / "u.csv", t, W)
    x0 = [0.1, -0.2, -1.0, 0.05, -0.03, 0.4, 0.3, 0.1, -0.1, 0.2, -0.1, 0.3]
    rc = main(["simulate", "--airframe", str(tmp_path / "a.toml"), "--inputs", str(tmp_path / "u.csv"),
               "--out", str(tmp_path / "y.csv"), "--x0", ",".join(map(str, x0)), "--json", str(tmp_path / "r.json")])
    assert rc == 0
    log = load_log(tmp_path / "y.csv")
    J = np.diag([cfg["jx"], cfg["jy"], cfg["jz"]])
    X = ref.simulate(t, W, layout, cfg["l"], cfg["mass"], J, 9.81, cfg["kt"], cfg["b"],
                     np.array([0.1, 0.15, 0.2]), jr, x0)
    np.testing.assert_allclose(log.outputs[:, 0:3], X[:, 0:3], atol=1e-4, rtol=0)
    np.testing.assert_allclose(log.outputs[:, 3:6], X[:, 3:6], atol=1e-4, rtol=0)
    np.testing.assert_allclose(log.outputs[:, 6:9], X[:, 9:12], atol=1e-4, rtol=0)
    assert max(np.ptp(X[:, 3]), np.ptp(X[:, 4])) > 0.1  # the test flight really tilts
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["samples"] == t.size and res["effects"] == ["yaw_torque", "linear_drag", "gyroscopic"]


def test_simulate_set_effects_and_default_x0(tmp_path, paper_airframe_path):
    t = np.arange(0, 0.5, 0.001)
    write_inputs(tmp_path / "u.csv", t, np.full((t.size, 4), 100.0))
    rc = main(["simulate", "--airframe", str(paper_airframe_path), "--inputs", str(tmp_path / "u.csv"),
               "--out", str(tmp_path / "y.csv"), "--set", "K_T=2.4e-5", "--set", "Kd=0.2,0.2,0.3",
               "--effects", "thrust_drift", "--without", "gyroscopic", "--json", str(tmp_path / "r.json")])
    assert rc == 0
    r = json.loads((tmp_path / "r.json").read_text())
    assert r["parameters"]["K_T"] == 2.4e-5 and r["parameters"]["Kd[2]"] == 0.3
    assert r["effects"] == ["yaw_torque", "linear_drag", "thrust_drift"]
    log = load_log(tmp_path / "y.csv")
    assert log.output("x")[0] == 0 and log.output("z")[0] == 0     # rest at the origin, level
    # 4 * 2.4e-5 * 100^2 = 0.96 N < m g: it sinks (z grows in NED)
    assert log.output("z")[-1] > 0


def test_simulate_derives_the_signals_effects_read_from_the_inputs(tmp_path, paper_airframe_path):
    """sampled_inputs reads the next row's speeds (w1@next), command_delay earlier commands
    (w1@-10ms): derived from the inputs file as a fit derives them from a log (an audit got
    "missing required column 'w1@next'"). By hand: with s_lead = 1 each row holds the next
    row's speeds, so a step acts one row (10 ms) early; a command delay of 10 ms, one row late."""
    import pandas as pd
    t = np.arange(0, 0.3, 0.01)
    for name, k in (("u", 10), ("early", 9), ("late", 11)):
        w = np.full((t.size, 4), 300.0)
        w[k:] = 340.0
        write_inputs(tmp_path / f"{name}.csv", t, w)

    def run(inputs, *extra):
        out = tmp_path / f"y_{len(list(tmp_path.iterdir()))}.csv"
        assert main(["simulate", "--airframe", str(paper_airframe_path), "--inputs", str(tmp_path / inputs),
                     "--out", str(out), *extra]) == 0
        return pd.read_csv(out)[["z", "vz"] if "vz" in pd.read_csv(out) else ["z"]].to_numpy()

    np.testing.assert_allclose(run("u.csv", "--effects", "sampled_inputs", "--set", "s_lead=1"),
                               run("early.csv"), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(run("u.csv", "--effects", "command_delay", "--set", "tau_cmd=0.01"),
                               run("late.csv"), rtol=1e-9, atol=1e-12)
    assert run("u.csv")[-1, 0] != run("early.csv")[-1, 0]      # the step's timing shows in z


def test_simulate_says_which_columns_of_its_inputs_it_ignores(tmp_path, paper_airframe_path, capsys):
    """A whole flight log given as inputs: its measurements are not a start state (an audit)."""
    t = np.arange(0, 0.1, 0.01)
    path = tmp_path / "log.csv"
    path.write_text("t,w1,w2,w3,w4,x,phi\n" + "".join(f"{v},320,320,320,320,1.0,0.1\n" for v in t))
    assert main(["simulate", "--airframe", str(paper_airframe_path), "--inputs", str(path),
                 "--out", str(tmp_path / "y.csv")]) == 0
    err = capsys.readouterr().err
    assert "ignored column(s) x, phi" in err
    assert load_log(tmp_path / "y.csv").output("x")[0] == 0        # from rest at the origin, not x = 1


@pytest.mark.parametrize("setup, args, message", [
    (lambda d: write_inputs(d / "u.csv", [0, 0.1, 0.05], np.ones((3, 4))), [], r"row 4, column 't'"),
    (lambda d: write_inputs(d / "u.csv", [0, 0.1], np.full((2, 4), 2000.0 * 30)), [], "RPM"),
    (lambda d: (d / "u.csv").write_text("t,w1,w2,w3,w4\n0,1,1,x,1\n"), [], r"row 2, column 'w3': not a number"),
    (lambda d: (d / "u.csv").write_text("t,w1,w2,w3\n0,1,1,1\n"), [], "missing required column 'w4'"),
    (lambda d: write_inputs(d / "u.csv", [0, 0.1], np.ones((2, 4))), ["--set", "K_T=fast"], "not a number"),
    (lambda d: write_inputs(d / "u.csv", [0, 0.1], np.ones((2, 4))), ["--set", "nope=1"], "unknown parameter 'nope'"),
    (lambda d: write_inputs(d / "u.csv", [0, 0.1], np.ones((2, 4))), ["--effects", "magic"], "unknown effect 'magic'"),
    (lambda d: write_inputs(d / "u.csv", [0, 0.1], np.ones((2, 4))), ["--x0", "1,2,3"], "needs 12 values"),
    # contradictory: it ran without wind, silently (a blind audit)
    (lambda d: write_inputs(d / "u.csv", [0, 0.1], np.ones((2, 4))), ["--effects", "wind,ground_effect",
                                                                       "--without", "wind"],
     "--effects and --without both name wind"),
    (lambda d: None, [], "u.csv: file not found"),
])
def test_simulate_bad_input_exit_2_and_no_output(tmp_path, capsys, paper_airframe_path, setup, args, message):
    setup(tmp_path)
    rc = main(["simulate", "--airframe", str(paper_airframe_path), "--inputs", str(tmp_path / "u.csv"),
               "--out", str(tmp_path / "y.csv"), "--json", str(tmp_path / "r.json")] + args)
    err = capsys.readouterr().err
    assert rc == 2
    import re
    assert re.search(message, err), err
    assert "Traceback" not in err and err.count("greybox: error:") == 1
    assert not (tmp_path / "y.csv").exists() and not (tmp_path / "r.json").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_bad_airframe_via_cli(tmp_path, capsys):
    (tmp_path / "a.toml").write_text("[airframe]\nmass = -1\ninertia = [1,1,1]\nlayout='plus'\narm_length=1\n")
    write_inputs(tmp_path / "u.csv", [0, 0.1], np.ones((2, 4)))
    rc = main(["simulate", "--airframe", str(tmp_path / "a.toml"), "--inputs", str(tmp_path / "u.csv"),
               "--out", str(tmp_path / "y.csv")])
    assert rc == 2 and "mass must be positive" in capsys.readouterr().err
    assert not (tmp_path / "y.csv").exists()


def test_console_script_usage_errors_exit_2():
    p = subprocess.run([sys.executable, "-m", "greybox", "simulate", "--airframe"], capture_output=True, text=True)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    p = subprocess.run([sys.executable, "-m", "greybox", "simulate", "--help"], capture_output=True, text=True)
    assert p.returncode == 0 and "--effects" in p.stdout and "--x0" in p.stdout


def test_simulate_writes_a_tumbles_angles_as_a_log_has_them(tmp_path):
    # a vehicle rolling at 8 rad/s for 3 s: its integrated roll reaches 24 rad; the log holds it
    # within [-pi, pi) (the same rotation), which greybox's own log reader accepts (a blind audit's
    # tumble written by simulate was refused by fit as "in degrees?")
    cfg = dict(mass=1.0, jx=0.008, jy=0.009, jz=0.015, l=0.2, layout="x", jr=0.0, kt=2.2e-5, b=6e-7,
               kd0=0.1, kd1=0.15, kd2=0.2)
    (tmp_path / "a.toml").write_text(AF.format(**cfg))
    t = np.arange(0, 3.0 + 1e-9, 0.01)
    W = np.full((t.size, 4), np.sqrt(9.81 / (4 * cfg["kt"])))
    write_inputs(tmp_path / "u.csv", t, W)
    x0 = [0, 0, -50.0, 0, 0, 0, 0, 0, 0, 8.0, 0, 0]
    assert main(["simulate", "--airframe", str(tmp_path / "a.toml"), "--inputs", str(tmp_path / "u.csv"),
                 "--out", str(tmp_path / "y.csv"), "--x0", ",".join(map(str, x0)), "--json",
                 str(tmp_path / "r.json")]) == 0
    written = np.genfromtxt(tmp_path / "y.csv", delimiter=",", names=True)["phi"]
    assert written.min() >= -np.pi and written.max() < np.pi
    # read back, the roll is continued through its wraps (a roll through inverted), as the model rolls
    log = load_log(tmp_path / "y.csv", inputs="rotor_speeds")
    phi = log.output("phi")
    assert any("column 'phi': the roll wraps" in n for n in log.notes), log.notes
    assert phi[-1] - phi[0] == pytest.approx(json.loads((tmp_path / "r.json").read_text())
                                             ["final_state"]["phi"], rel=1e-6)
    assert phi[-1] > 20

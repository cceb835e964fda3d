"""Several flights with shared vehicle parameters and per-flight nuisance parameters (the day's
wind), on flights of the foreign simulator (tests/foreign_sim.py: its own dynamics, integrator
and controller), 1 kg vehicle, three flights in three different winds."""
import hashlib
import json

import numpy as np
import pytest

from greybox import QuadrotorModel
from greybox.airframe import airframe_from_dict
from greybox.batch import Flight, Options, batch, fleet_comparison, run_fleet
from greybox.cli import main
from greybox.data import save_log
from greybox.diagnosis import diagnose
from greybox.effects import Wind
from greybox.fitting import fit

from foreign_sim import airframe_dict, airframe_toml, one_kg, simulate_flight

WINDS = [(2.0, 0.0), (-1.0, 1.5), (0.0, -2.0)]
DRAG = [0.3, 0.3, 0.15]


@pytest.fixture(scope="module")
def windy():
    veh = one_kg()
    flights = [simulate_flight(veh, duration=12.0, seed=10 + i, linear_drag=DRAG, wind=[*w, 0.0], log_rate=200.0)
               for i, w in enumerate(WINDS)]
    # starting values 30 % off
    af = airframe_dict(veh, K_T_guess_factor=1.3, b_guess_factor=0.7)
    model = QuadrotorModel(airframe_from_dict(af)) + Wind()
    return veh, af, model, flights


@pytest.mark.slow    # half a minute; each flight's wind is also checked in the default run (diagnose of two flights)
def test_each_flight_gets_its_own_wind_and_the_vehicle_its_shared_drag(windy):
    veh, _, model, flights = windy
    logs = [f.log for f in flights]
    res = fit(model, logs, per_flight="auto")
    assert res.converged, res.status
    assert sorted(res.per_flight_) == ["wind[0]", "wind[1]"]
    for i, (wn, we) in enumerate(WINDS):
        got = res.per_flight_["wind[0]"]["value"][i], res.per_flight_["wind[1]"]["value"][i]
        assert got == pytest.approx((wn, we), abs=0.15), (i, got)
        # flight_p carries the flight's own values; p their mean
        pf = res.flight_p(i)
        assert pf[model.param_names.index("wind[0]")] == pytest.approx(got[0])
    assert res.value("wind[0]") == pytest.approx(np.mean(res.per_flight_["wind[0]"]["value"]))
    for k, kd in enumerate(DRAG):
        assert res.value(f"Kd[{k}]") == pytest.approx(kd, rel=0.1)
    assert res.value("K_T") == pytest.approx(veh.K_T, rel=0.02)
    # the mean's std is the average of the copies' (correlated) errors: below the largest copy's
    s_mean = res.std[res.free_names.index("wind[0]")]
    assert 0 < s_mean <= max(res.per_flight_["wind[0]"]["std"])
    # everything shared: one wind cannot blow three ways, and the attitude pays for it
    shared = fit(model, logs)
    assert not shared.per_flight_
    for ch in ("phi", "theta"):
        assert shared.residual_rms[ch] > 5 * res.residual_rms[ch], ch
    # the fitted trajectories of each flight use that flight's wind: residuals near the noise
    assert res.residual_rms["phi"] < 3 * veh.att_noise


@pytest.mark.slow
def test_fit_cli_per_flight_json_and_a_bad_name(windy, tmp_path, capsys):
    _, af, _, flights = windy
    (tmp_path / "a.toml").write_text(airframe_toml(af))
    logs = []
    for i, f in enumerate(flights[:2]):
        logs.append(str(f.save(tmp_path / f"f{i}")["log"]))
    out = tmp_path / "fit.json"
    rc = main(["fit", *logs, "--airframe", str(tmp_path / "a.toml"), "--effects", "wind", "--quiet",
               "--json", str(out)])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert len(doc["per_flight"]["wind[0]"]["value"]) == 2
    assert doc["per_flight"]["wind[0]"]["value"][0] == pytest.approx(WINDS[0][0], abs=0.2)
    assert doc["per_flight"]["wind[1]"]["value"][1] == pytest.approx(WINDS[1][1], abs=0.2)
    # the contracted keys hold the mean
    assert doc["parameters"]["wind[0]"]["value"] == pytest.approx(np.mean(doc["per_flight"]["wind[0]"]["value"]))
    rc = main(["fit", *logs, "--airframe", str(tmp_path / "a.toml"), "--effects", "wind", "--quiet",
               "--per-flight", "gust"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "--per-flight: 'gust' is neither" in err and "Traceback" not in err
    # named by its option, before any fitting starts (no progress line: --quiet left out)
    rc = main(["diagnose", *logs, "--airframe", str(tmp_path / "a.toml"), "--per-flight", "windd"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "--per-flight: 'windd' is neither" in err and "diagnose: fitting" not in err and "Traceback" not in err


def test_fleet_comparison_leaves_a_flights_wind_out_and_needs_four_flights():
    def fitj(w, kd, K=2e-5):
        return {"free": ["K_T", "Kd[0]", "wind[0]"], "correlation": np.eye(3).tolist(),
                "parameters": {"K_T": {"value": K, "std": 2e-10}, "Kd[0]": {"value": kd, "std": 0.001},
                               "wind[0]": {"value": w, "std": 0.01}}}
    # three flights: too few to tell a vehicle apart from the flights' scatter; said, no one named
    three = {"a": fitj(2.0, 0.30), "b": fitj(-1.0, 0.36), "c": fitj(0.0, 0.30)}
    c = fleet_comparison(three, None, exclude={"wind[0]"})
    assert not any(c["outliers"].values()) and "too few" in c["note"]
    assert "wind[0]" not in c["parameters"]["a"] and "Kd[0]" in c["parameters"]["a"]
    # four: the one with 20 % more drag is named, nobody for a wind, nor for a K_T 0.2 % off at 10 std
    four = {"a": fitj(2.0, 0.30), "b": fitj(-1.0, 0.30), "c": fitj(0.0, 0.30, K=2.0004e-5),
            "d": fitj(1.0, 0.36)}
    c = fleet_comparison(four, None, exclude={"wind[0]"})
    assert "note" not in c
    assert c["outliers"]["d"] == [c["outliers"]["d"][0]] and c["outliers"]["d"][0].startswith(
        "flight d: Kd[0] at 120 % of the fleet's value")
    assert not any(c["outliers"][n] for n in "abc"), c["outliers"]
    assert c["parameters"]["c"]["K_T"]["z"] > 3          # significant, and physically the same vehicle
    # a joint fit's per-flight parameters are left out by themselves
    fleet = dict(fitj(0.5, 0.30), per_flight={"wind[0]": {"value": [2.0, -1.0, 0.0, 1.0], "std": [0.01] * 4}})
    c = fleet_comparison(four, fleet)
    assert "wind[0]" not in c["parameters"]["a"] and c["outliers"]["d"]


@pytest.mark.slow
def test_diagnose_of_two_flights_in_two_winds_names_the_wind_with_each_flights_value(windy):
    """The base model (no wind) on two flights in different winds: the wind candidate is
    refitted with one wind per flight (4 degrees of freedom) and is the verdict; its values
    are each flight's."""
    _, af, _, flights = windy
    base = QuadrotorModel(airframe_from_dict(af))
    d = diagnose(base, [flights[0].log, flights[1].log], candidates=["wind", "cog_offset", "motor_asymmetry"],
                 iterate=False, discover=False)
    assert d.baseline_certified
    assert d.verdict == "wind", d.summary()
    win = d.ranking[0]
    assert win.effect == "wind" and win.df == 4
    pf = win.fit.per_flight_
    assert pf["wind[0]"]["value"] == pytest.approx([WINDS[0][0], WINDS[1][0]], abs=0.2)
    assert pf["wind[1]"]["value"] == pytest.approx([WINDS[0][1], WINDS[1][1]], abs=0.2)
    # each flight's wind, not only their mean, in the JSON and the summary (a blind audit: the
    # mean, a wind neither flight had, was all they showed)
    js = d.as_json()
    assert js["ranking"][0]["parameters"]["wind[0]"]["per_flight"] == pf["wind[0]"]["value"]
    assert js["model"]["per_flight"]["wind[1]"]["value"] == pf["wind[1]"]["value"]
    assert f"wind[0] per flight (the mean above): {pf['wind[0]']['value'][0]:.4g}" in d.summary()


def _write_flights(windy, tmp_path, n=3):
    _, af, _, flights = windy
    (tmp_path / "a.toml").write_text(airframe_toml(af))
    paths = []
    for i, f in enumerate(flights[:n]):
        p = tmp_path / f"wind{i}.csv"
        save_log(f.log, p)
        paths.append(p)
    return tmp_path / "a.toml", paths


@pytest.mark.slow    # about a minute; the default run stays near ten minutes
def test_joint_fleet_fit_gives_each_flight_its_wind(windy, tmp_path):
    """``greybox batch --joint``'s joint fit (run on a worker; called here directly): with
    wind in the model, or added as the flights' own diagnoses found it (``nuisance``), one
    wind per flight and the drag shared."""
    airframe, paths = _write_flights(windy, tmp_path)
    flights = [Flight(p.stem, str(p), hashlib.sha256(p.read_bytes()).hexdigest(), p.stem) for p in paths]
    for opts, nuisance in ((Options(airframe=str(airframe), effects="wind"), ()),
                           (Options(airframe=str(airframe)), ("wind",))):
        out = run_fleet(flights, opts, nuisance)
        assert out["converged"], out["status"]
        got = out["fit"]["per_flight"]
        assert got["wind[0]"]["value"] == pytest.approx([w[0] for w in WINDS], abs=0.15)
        assert got["wind[1]"]["value"] == pytest.approx([w[1] for w in WINDS], abs=0.15)
        assert out["fit"]["parameters"]["Kd[0]"]["value"] == pytest.approx(DRAG[0], rel=0.1)
    # everything shared: one wind for three flights, no per_flight
    out = run_fleet(flights, Options(airframe=str(airframe), effects="wind", per_flight=None))
    assert "per_flight" not in out["fit"]


@pytest.mark.slow
def test_batch_joint_with_winds_found_by_each_flights_diagnosis(windy, tmp_path):
    """The whole batch: each flight's diagnosis adds the wind; the joint fit then fits one wind
    per flight, and no flight is named odd for its wind."""
    pytest.importorskip("distributed")
    airframe, paths = _write_flights(windy, tmp_path)
    res = batch([str(p) for p in paths], tmp_path / "out", airframe=str(airframe), candidates=["wind"],
                iterate=False, discover=False, workers=2, joint=True, progress=False)
    assert [r["verdict"] for r in res.records] == ["wind"] * 3, res.records
    fleet = json.loads((tmp_path / "out" / "fleet.json").read_text())
    assert fleet["fit"]["per_flight"]["wind[0]"]["value"] == pytest.approx([w[0] for w in WINDS], abs=0.2)
    # three identical vehicles: none named (not for its wind, nor for a K_T 0.2 % off at 100 std)
    assert not any(fleet["comparison"]["outliers"].values()), fleet["comparison"]["outliers"]
    assert "wind[0]" not in fleet["comparison"]["parameters"]["wind0"]


@pytest.mark.slow
def test_soft_fit_of_several_flights_gives_each_its_own_process_noise(tmp_path):
    """A weak-rotor flight beside a healthy one, both fitted with process noise and a model
    without ``motor_asymmetry``: the weak one's gaps are far larger, and each flight gets its own
    q (with one q for both the healthy flight's states could drift as much). The weak flight's
    missing torques act for good, interval after interval: the certificate says so (the gaps
    of p mostly systematic), and the parameters that bend to take them (b) are not the
    vehicle's; K_T, pinned by both flights' thrust, stays within a few per cent of the healthy
    flight's alone."""
    from importlib import resources
    from greybox import load_airframe, load_log
    paper = str(resources.files("greybox") / "data" / "airframes" / "paper.toml")
    common = ["--airframe", paper, "--duration", "8", "--rate", "100"]
    assert main(["synth", *common, "--out", str(tmp_path / "good.csv"), "--seed", "11"]) == 0
    assert main(["synth", *common, "--out", str(tmp_path / "weak.csv"), "--seed", "15", "--effects",
                 "motor_asymmetry", "--set", "K_T_dev=0.025641,-0.076923,0.025641"]) == 0
    model = QuadrotorModel(load_airframe(paper))
    good, weak = (load_log(tmp_path / f"{n}.csv").split(0.8)[0] for n in ("good", "weak"))
    alone = fit(model, good, process_noise="auto", max_iter=200)
    both = fit(model, [good, weak], process_noise="auto", max_iter=200)
    assert alone.converged and both.converged, both.status
    assert alone.certificate.adequate and alone.value("b") == pytest.approx(6.8429e-07, rel=0.05)
    q_p = both.process_noise["p"]
    assert isinstance(q_p, list) and q_p[1] > 10 * q_p[0], q_p
    assert "p" in both.certificate.off_states() and "mostly systematic" in both.certificate.text()
    assert both.value("K_T") == pytest.approx(alone.value("K_T"), rel=0.03)     # 2.2 % measured
    # one of its flights refitted in its formulation (diagnose's halves of a 2-flight fit): that
    # flight's own process noise and node states (the 2-flight lists were refused: no halves)
    kw = both.settings(flights=[1])
    assert kw["process_noise"]["p"] == q_p[1] and len(kw["initial_states"]) == 1
    weak_alone = fit(model, weak, p0=both.p, free=both.free_names, max_iter=100, **kw)
    assert weak_alone.converged and weak_alone.process_noise["p"] == q_p[1]


@pytest.mark.slow
def test_flights_whose_rotors_carry_different_shares_of_the_weight_are_told_to_get_their_own_thrust():
    """A blind audit's three flights at 4.15, 3.95 and 3.75 V without the voltage logged were
    fitted with one K_T and nothing said (the diagnosis named a thrust drift, Kd[2] 26 times
    the truth): each flight's rotors carry its weight on average, so at one thrust per speed²
    they carry different shares of it. Here two flights of the other simulator, the second
    with 8 % less thrust per speed² (a weaker battery): a warning names --per-flight K_T, and
    with it each flight's K_T is its own and the warning is gone."""
    veh = one_kg()
    weak = one_kg(K_T=0.92 * veh.K_T)
    logs = [simulate_flight(v, duration=10.0, seed=30 + i, log_rate=200.0).log for i, v in enumerate((veh, weak))]
    model = QuadrotorModel(airframe_from_dict(airframe_dict(veh, K_T_guess_factor=1.3)))
    res = fit(model, logs, per_flight=None)
    spread = [w for w in res.warnings if "carry" in w and "--per-flight K_T" in w]
    assert spread, res.warnings
    own = fit(model, logs, per_flight=["K_T"])
    assert not [w for w in own.warnings if "--per-flight K_T" in w], own.warnings
    k_t = own.per_flight_["K_T"]["value"]
    assert k_t[0] == pytest.approx(veh.K_T, rel=0.01) and k_t[1] == pytest.approx(weak.K_T, rel=0.01)


def test_a_separate_validation_flight_predicted_with_the_mean_wind_is_said():
    """A blind audit's separate validation flight was predicted with the mean of the estimation
    flights' winds (49 % off its own in y) and nothing said so: the words name it and the
    values averaged; a flight's own tail (validated with its own wind) is not named."""
    from dataclasses import replace
    from types import SimpleNamespace
    from greybox.data import log_from_arrays
    from greybox.validation import mean_value_words, validation_vectors
    t = np.arange(0, 10, 0.01)
    logs = [replace(log_from_arrays(t, np.full((t.size, 4), 500.0), np.zeros((t.size, 6))), source=f"f{k}.csv")
            for k in range(2)]
    parts = [lg.split(0.8) for lg in logs]
    est = [e for e, _ in parts]
    p = np.array([1.0, 0.3, 0.5])
    each = {"wind[0]": {"value": [1.2, -0.6], "std": [0.03, 0.03]}, "wind[1]": {"value": [0.4, 1.5], "std": [0.03, 0.03]}}

    def flight_p(i):
        q = p.copy()
        q[1], q[2] = each["wind[0]"]["value"][i], each["wind[1]"]["value"][i]
        return q
    res = SimpleNamespace(p=p, per_flight_=each, flight_p=flight_p)
    tails = [v for _, v in parts]
    assert mean_value_words(res, est, tails) == []                     # each tail with its own wind
    assert [list(v) for v in validation_vectors(res, est, tails)] == [[1.0, 1.2, 0.4], [1.0, -0.6, 1.5]]
    other = replace(logs[0], source="v.csv")
    words = mean_value_words(res, est, [other])
    assert len(words) == 1 and words[0].startswith("v.csv is predicted with the mean of the estimation flights' "
                                                   "own values of wind[0], wind[1]"), words
    assert "wind[0] 0.3 (flights: 1.2, -0.6); wind[1] 0.95 (flights: 0.4, 1.5)" in words[0], words
    assert mean_value_words(SimpleNamespace(p=p, per_flight_={}), est, [other]) == []

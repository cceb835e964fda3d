"""A fitted model you can hold (issue 17): save/load bit for bit, the CLI's --save/--model,
scikit-learn's contract for the estimator, the solver seam."""
from __future__ import annotations

import json

import numpy as np
import pytest

import greybox
from greybox import effects as fx
from greybox.cli import main
from greybox.data import save_log
from greybox.errors import GreyboxInputError
from greybox.fitted import FORMAT_VERSION, FittedModel, load
from greybox.fitting import FitResult, GaussNewton, GreyBoxEstimator, fit
from greybox.model import QuadrotorModel
from greybox.synth import SensorSpec, model_with_hidden_effects, synthesize

from conftest import AIRFRAMES

OFF = {"K_T": 2.395e-5 * 1.2, "b": 6.8429e-7 * 0.8}


@pytest.fixture(scope="module")
def paper_model():
    return QuadrotorModel(greybox.load_airframe(AIRFRAMES / "paper.toml"))


@pytest.fixture(scope="module")
def flight(paper_model):
    model, p = model_with_hidden_effects(paper_model, [])
    return synthesize(model, p, 12.0, SensorSpec(rate=200.0, vision_rate=50.0), seed=5).log


@pytest.fixture(scope="module")
def fitted(paper_model, flight) -> FitResult:
    est, _ = flight.split()
    return fit(paper_model, est, p0=OFF, max_iter=40)


def test_fit_result_is_a_fitted_model_that_saves_and_reloads_bit_for_bit(fitted, flight, tmp_path):
    assert isinstance(fitted, FittedModel) and fitted.converged
    _, val = flight.split()
    path = fitted.save(tmp_path / "m.json")
    doc = json.loads(path.read_text())
    assert doc["format_version"] == FORMAT_VERSION and doc["greybox_version"] == greybox.__version__
    assert doc["free"] == fitted.free_names and doc["provenance"]["converged"] is True
    back = greybox.load(path)
    assert back.model.effect_names == fitted.model.effect_names
    assert np.array_equal(back.p, fitted.p)                       # exact floats
    assert np.array_equal(back.covariance, fitted.covariance)
    # the README's res.parameters["K_T"] reads the same off a loaded model (a blind audit)
    assert back.parameters == fitted.parameters and back.parameters["K_T"]["std"] > 0
    a, b = fitted.predict(val), back.predict(val)
    assert a.total == b.total and all(a.nrmse[c] == b.nrmse[c] for c in a.nrmse)
    np.testing.assert_array_equal(a.predicted, b.predicted)
    # the hover trim and linearisation go with it
    x_t, u_t = back.hover_trim()
    kt = back.value("K_T")
    m, g = back.model.airframe.mass, back.model.airframe.gravity
    assert u_t[0] == pytest.approx(np.sqrt(m * g / (4 * kt)), rel=1e-9)
    lin = back.linearize()
    assert lin.A.shape == (12, 12) and lin.B.shape == (12, 4)
    html = back._repr_html_()        # what a notebook cell shows
    assert "<table>" in html and "K_T" in html and "Kd[2]" in html and "J_r" in html and "fixed" in html
    assert repr(back).startswith("FittedModel(paper: yaw_torque, linear_drag, gyroscopic; K_T=")


def test_effect_options_are_saved(tmp_path, paper_model):
    model = paper_model + fx.BatteryVoltage(v_ref=3.7)
    fm = FittedModel(model, model.default_parameters())
    back = greybox.load(fm.save(tmp_path / "bv.json"))
    bv = next(e for e in back.model.effects if e.name == "battery_voltage")
    assert bv.v_ref == 3.7


def test_bad_model_files_are_one_clear_error(tmp_path, fitted):
    doc = fitted.to_dict()
    doc["format_version"] = 99
    (tmp_path / "future.json").write_text(json.dumps(doc))
    with pytest.raises(GreyboxInputError, match="format_version 99 is not supported"):
        load(tmp_path / "future.json")
    (tmp_path / "other.json").write_text('{"parameters": {}}')
    with pytest.raises(GreyboxInputError, match="not a greybox fitted model"):
        load(tmp_path / "other.json")
    doc = fitted.to_dict()
    del doc["parameters"]["K_T"]
    (tmp_path / "partial.json").write_text(json.dumps(doc))
    with pytest.raises(GreyboxInputError, match="missing K_T"):
        load(tmp_path / "partial.json")
    with pytest.raises(GreyboxInputError, match="has 3 values"):
        FittedModel(fitted.model, [1.0, 2.0, 3.0])



def test_a_model_saved_before_its_effect_gained_a_parameter_loads_and_predicts_the_same(paper_model, flight,
                                                                                         tmp_path):
    """hub_rotor_drag gained h_hub (2026-12-02); a model saved before has no h_hub. At its
    default, the null, the effect is what it was: the model loads with a warning, h_hub held
    at 0, and predicts exactly what the same model with h_hub = 0 predicts."""
    model = paper_model + fx.HubRotorDrag()
    p = model.parameter_vector({"K_T": 2.395e-5, "b": 6.8429e-7, "k_rdh": 2e-4, "k_rdv": 1e-4, "h_hub": 0.0})
    fm = FittedModel(model, p, ["K_T", "k_rdh"], np.diag([1e-14, 1e-10]), [1e-7, 1e-5])
    doc = fm.to_dict()
    del doc["parameters"]["h_hub"]
    (tmp_path / "old.json").write_text(json.dumps(doc))
    with pytest.warns(UserWarning, match=r"saved without h_hub = 0 \(hub_rotor_drag\)"):
        back = load(tmp_path / "old.json")
    assert back.value("h_hub") == 0.0 and "h_hub" not in back.free_names
    _, val = flight.split()
    np.testing.assert_array_equal(back.predict(val).predicted, fm.predict(val).predicted)
    del doc["parameters"]["K_T"]                     # the base model's own: still an error
    (tmp_path / "broken.json").write_text(json.dumps(doc))
    with pytest.warns(UserWarning, match="saved without h_hub"), pytest.raises(GreyboxInputError, match="missing K_T"):
        load(tmp_path / "broken.json")

def test_cli_fit_save_then_model_everywhere(flight, tmp_path, capsys):
    log = tmp_path / "f.csv"
    save_log(flight, log)
    af = str(AIRFRAMES / "paper.toml")
    assert main(["fit", str(log), "--airframe", af, "--quiet", "--set", "K_T=2.8e-5",
                 "--json", str(tmp_path / "r.json"), "--save", str(tmp_path / "m.json")]) == 0
    reported = json.loads((tmp_path / "r.json").read_text())["validation"]["nrmse"]
    _, val = greybox.load_log(log).split(0.8)
    assert greybox.load(tmp_path / "m.json").predict(val).total == reported   # exactly
    # --model instead of --airframe: linearize at the fitted K_T
    assert main(["linearize", "--model", str(tmp_path / "m.json"), "--json", str(tmp_path / "lin.json")]) == 0
    lin = json.loads((tmp_path / "lin.json").read_text())
    kt = json.loads((tmp_path / "r.json").read_text())["parameters"]["K_T"]["value"]
    assert lin["parameters"]["K_T"] == kt
    # diagnose starting from the saved model, saving its final model
    assert main(["diagnose", str(log), "--model", str(tmp_path / "m.json"), "--quiet", "--candidates",
                 "ground_effect", "--no-iterate", "--json", str(tmp_path / "d.json"),
                 "--save", str(tmp_path / "final.json")]) == 0
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["model"]["parameters"]["K_T"]["value"] == pytest.approx(kt, rel=1e-3)
    assert greybox.load(tmp_path / "final.json").model.effect_names == d["model"]["effects"]
    # effects --model (contract section 8: every command taking --airframe takes --model):
    # the saved model's effects are marked and carry their fitted values
    assert main(["effects", "--model", str(tmp_path / "m.json"), "--json", str(tmp_path / "e.json")]) == 0
    listed = {e["name"]: e for e in json.loads((tmp_path / "e.json").read_text())["effects"]}
    saved = json.loads((tmp_path / "r.json").read_text())["parameters"]
    assert listed["linear_drag"]["in_model"] and not listed["ground_effect"]["in_model"]
    assert listed["linear_drag"]["parameters"][0]["fitted"] == [saved[f"Kd[{i}]"]["value"] for i in range(3)]
    assert listed["yaw_torque"]["parameters"][0]["fitted"] == [saved["b"]["value"]]
    assert "fitted" not in listed["ground_effect"]["parameters"][0]
    capsys.readouterr()
    rc = main(["fit", str(log), "--airframe", af, "--model", str(tmp_path / "m.json")])
    assert rc == 2 and "not allowed with argument" in capsys.readouterr().err
    assert main(["effects", "--airframe", af, "--model", str(tmp_path / "m.json")]) == 2


def test_estimator_keeps_every_option_through_sklearn_clone(paper_model, flight):
    sklearn = pytest.importorskip("sklearn")
    from sklearn.base import clone
    solver = GaussNewton()
    est = GreyBoxEstimator(paper_model, free=["K_T", "b"], p0=OFF, max_iter=25, interval=10,
                           reweight=False, solver=solver, horizon=0.5)
    c = clone(est)
    got, want = c.get_params(), est.get_params()
    assert set(got) == set(want)
    for k in want:
        if k == "model":      # clone deep-copies objects that are not estimators
            assert got[k].effect_names == want[k].effect_names
            assert np.array_equal(got[k].default_parameters(), want[k].default_parameters())
        elif k == "solver":
            assert type(got[k]) is GaussNewton
        else:
            assert got[k] == want[k], k
    assert c.get_params()["max_iter"] == 25 and c.get_params()["free"] == ["K_T", "b"]
    assert c.set_params(max_iter=30).max_iter == 30
    with pytest.raises(ValueError, match="invalid parameter"):
        c.set_params(maxiter=3)
    tr, val = flight.split()
    est.fit(tr)
    assert set(est.std_) == {"K_T", "b"}
    assert est.params_["K_T"] == pytest.approx(2.395e-5, rel=0.01)
    score = est.score(val)
    assert score == -est.predict(val).total and score < 0    # higher is better
    assert sklearn.__version__


class CountingSolver:
    """A solver of our own, plugged in through the seam: Gauss-Newton with a count."""

    def __init__(self):
        self.calls = 0
        self.inner = GaussNewton()

    def solve(self, session, X, th, mu, max_iter, tol, rough=False):
        self.calls += 1
        return self.inner.solve(session, X, th, mu, max_iter, tol, rough)


def test_a_solver_is_injected(paper_model, flight, fitted):
    est, _ = flight.split()
    s = CountingSolver()
    res = fit(paper_model, est, p0=OFF, max_iter=40, solver=s)
    assert s.calls >= 1
    np.testing.assert_allclose(res.p, fitted.p, rtol=1e-9)


def test_cli_fit_takes_several_flights(paper_model, tmp_path):
    """Two flights, shared parameters, own states: the joint fit recovers K_T and b and
    reports each flight's validation and their mean."""
    paths = []
    for seed in (11, 12):
        model, p = model_with_hidden_effects(paper_model, [])
        log = synthesize(model, p, 8.0, SensorSpec(rate=200.0, vision_rate=50.0), seed=seed).log
        paths.append(tmp_path / f"f{seed}.csv")
        save_log(log, paths[-1])
    assert main(["fit", *map(str, paths), "--airframe", str(AIRFRAMES / "paper.toml"), "--quiet",
                 "--set", "K_T=2.8e-5", "--json", str(tmp_path / "r.json")]) == 0
    r = json.loads((tmp_path / "r.json").read_text())
    assert r["parameters"]["K_T"]["value"] == pytest.approx(2.395e-5, rel=0.005)
    assert r["parameters"]["b"]["value"] == pytest.approx(6.8429e-7, rel=0.03)
    flights = r["validation"]["flights"]
    assert [f["log"] for f in flights] == [str(p) for p in paths]
    assert r["validation"]["nrmse"] == pytest.approx(np.mean([f["nrmse"] for f in flights]))
    # the contract's keys as one flight's have them (an audit's three-flight fit lacked this one)
    assert r["validation"]["longest_window"] == max(f["longest_window"] for f in flights) > 0


@pytest.mark.slow    # about a minute; the default run stays near ten minutes
def test_cli_diagnose_takes_several_flights(tmp_path):
    """The bundled ground-effect flight cut in two flights (each with its own states, the
    parameters shared), validated on the bundled second flight: the ground effect is found."""
    from greybox.data import load_log
    log = load_log(greybox.__path__[0] + "/data/logs/demo_ground_effect.csv")
    n = len(log)
    paths = []
    for k, (a, b) in enumerate([(0, n // 2), (n // 2, n)]):
        paths.append(tmp_path / f"part{k}.csv")
        save_log(log.slice(a, b), paths[-1])
    val = greybox.__path__[0] + "/data/logs/demo_ground_effect_validation.csv"
    assert main(["diagnose", *map(str, paths), "--validation", val, "--airframe", str(AIRFRAMES / "paper.toml"),
                 "--quiet", "--candidates", "ground_effect,quadratic_drag", "--no-iterate",
                 "--json", str(tmp_path / "d.json")]) == 0
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["verdict"] == "ground_effect" and d["ranking"][0]["significant"]
    assert d["ranking"][0]["nrmse_after"] < d["baseline"]["nrmse"]
    # the baseline bends its vertical drag to stand in for the ground effect; the refit from
    # there crawled (k_ge 6e-4 of 1.8e-3 after 200 iterations), the one from the airframe's
    # guesses takes 4 iterations and is kept on its likelihood: k_ge at the truth, certified
    top = d["ranking"][0]
    assert top["parameters"]["k_ge"]["value"] == pytest.approx(1.8e-3, rel=0.05)
    assert top["nrmse_after"] < 0.4 * d["baseline"]["nrmse"]


def test_review_findings_stay_fixed(fitted, flight, tmp_path, capsys):
    """Found by review: quotes in an airframe name, tiny products of inertia, a DataFrame
    passed to fit, several flights to FittedModel.predict, a broken effect hook."""
    import dataclasses
    af = dataclasses.replace(fitted.model.airframe, name='The "paper" quad \\ C:\\temp',
                             inertia=fitted.model.airframe.inertia + np.array([[0, 5e-9, 0], [5e-9, 0, 0], [0, 0, 0]]))
    fm = FittedModel(QuadrotorModel(af, list(fitted.model.effects)), fitted.p)
    back = greybox.load(fm.save(tmp_path / "q.json"))
    assert back.model.airframe.name == af.name
    assert np.array_equal(back.model.airframe.inertia, af.inertia)
    pd = pytest.importorskip("pandas")
    with pytest.raises(GreyboxInputError, match="from_dataframe"):
        fit(fitted.model, flight.to_dataframe())
    _, val = flight.split()
    a, b = val.split(0.5)
    both = fitted.predict([a, b])
    assert len(both.parts) == 2 and both.predicted.shape[0] == len(a) + len(b)
    bad = tmp_path / "bad.py"
    bad.write_text("from greybox.effects import Effect\n\nclass Bad(Effect):\n    name = 'bad_hook'\n"
                   "    def parameters(self, airframe):\n        return 1 / 0\n")
    capsys.readouterr()
    assert main(["effects", "--effects-file", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "line 6" in err[0] and "ZeroDivisionError" in err[0]
    assert pd is not None


def test_diagnose_several_flights_with_a_report(paper_model, tmp_path):
    """A pooled prediction is drawn flight after flight (it crashed the report)."""
    paths = []
    for seed in (31, 32):
        model, p = model_with_hidden_effects(paper_model, [])
        paths.append(tmp_path / f"r{seed}.csv")
        save_log(synthesize(model, p, 6.0, SensorSpec(rate=200.0, vision_rate=50.0), seed=seed).log, paths[-1])
    assert main(["diagnose", *map(str, paths), "--airframe", str(AIRFRAMES / "paper.toml"), "--quiet",
                 "--candidates", "ground_effect", "--no-iterate", "--report", str(tmp_path / "rep"),
                 "--json", str(tmp_path / "d.json")]) == 0
    assert (tmp_path / "rep" / "report.html").exists() and (tmp_path / "d.json").exists()

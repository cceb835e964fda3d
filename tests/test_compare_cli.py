"""greybox compare: models' k-step-ahead predictions of a log side by side (MATLAB's compare),
the headline loop's first step on the command line (a blind audit found no such command and
compared its saved fits in Python)."""
import json

import pytest

from greybox.cli import main
from greybox.data import save_log
from greybox.synth import synthesize
from greybox.validation import predict

from conftest import AIRFRAMES


@pytest.fixture(scope="module")
def flights():
    from greybox import QuadrotorModel, load_airframe
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    return synthesize(model, duration=12.0, seed=21).log, synthesize(model, duration=6.0, seed=22).log


def test_compare_a_fitted_model_and_the_airframes_guesses(flights, tmp_path, capsys):
    est, val = flights
    save_log(est, tmp_path / "est.csv")
    save_log(val, tmp_path / "val.csv")
    af = str(AIRFRAMES / "paper.toml")
    assert main(["fit", str(tmp_path / "est.csv"), "--airframe", af, "--set", "K_T=3e-5", "--quiet",
                 "--save", str(tmp_path / "m.json")]) == 0
    capsys.readouterr()
    rc = main(["compare", str(tmp_path / "val.csv"), "--model", str(tmp_path / "m.json"), "--airframe", af,
               "--set", "K_T=3e-5", "--json", str(tmp_path / "c.json"), "--plots", str(tmp_path / "plots")])
    out = capsys.readouterr().out
    assert rc == 0
    r = json.loads((tmp_path / "c.json").read_text())
    assert r["horizon"] == 1.0 and [m["name"] for m in r["models"]] == ["paper.toml (its parameters)", "m.json"]
    guess, fitted = r["models"]
    # the fitted model predicts the other flight far better than the guess K_T 25 % high
    assert fitted["nrmse"] < 0.2 * guess["nrmse"], (fitted["nrmse"], guess["nrmse"])
    assert set(fitted["channels"]) >= {"x", "y", "z", "phi", "theta", "psi"}
    # the airframe's model with --set is what predict gives with those parameters
    from greybox import QuadrotorModel, load_airframe
    model = QuadrotorModel(load_airframe(af))
    direct = predict(model, model.parameter_vector({"K_T": [3e-5]}), val, 1.0)
    assert guess["nrmse"] == pytest.approx(direct.total, rel=1e-9)
    assert "m.json" in out and "nrmse (lower is better)" in out
    assert (tmp_path / "plots" / "compare.png").stat().st_size > 10000


@pytest.mark.parametrize("args, message", [
    ([], "compare needs models"),
    (["--model", "M", "--effects", "wind"], "apply to --airframe's model"),
])
def test_compare_without_models_or_with_options_it_cannot_use_is_refused(flights, tmp_path, capsys, args, message):
    save_log(flights[1], tmp_path / "val.csv")
    (tmp_path / "M").write_text("{}")
    args = [a if a != "M" else str(tmp_path / "M") for a in args]
    rc = main(["compare", str(tmp_path / "val.csv"), *args, "--json", str(tmp_path / "c.json")])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and err.count("greybox: error:") == 1, err
    assert not (tmp_path / "c.json").exists()


def test_models_that_start_differently_are_said_so_and_can_be_given_one_start(flights, tmp_path, capsys):
    """A saved fit predicts from the start it chose on its own estimation flight; two models with
    the same parameters then read differently on one flight (a blind audit's fit with the truth's
    parameters within 2.3 % read 26 % worse than the truth). Said, shown per model, and one
    start for all on request."""
    est, val = flights
    save_log(est, tmp_path / "est.csv")
    save_log(val, tmp_path / "val.csv")
    assert main(["fit", str(tmp_path / "est.csv"), "--airframe", str(AIRFRAMES / "paper.toml"), "--quiet",
                 "--save", str(tmp_path / "a.json")]) == 0
    doc = json.loads((tmp_path / "a.json").read_text())
    doc["provenance"].update(init_window=0.05, measured_start=True)
    (tmp_path / "b.json").write_text(json.dumps(doc))
    capsys.readouterr()
    models = ["--model", str(tmp_path / "a.json"), str(tmp_path / "b.json")]
    assert main(["compare", str(tmp_path / "val.csv"), *models, "--json", str(tmp_path / "own.json")]) == 0
    captured = capsys.readouterr()
    assert "start their predictions differently" in captured.err and "b.json: 0.05 s, measured" in captured.err
    assert "0.05 s, measured" in captured.out
    a, b = json.loads((tmp_path / "own.json").read_text())["models"]
    assert (b["init_window"], b["measured_start"]) == (0.05, True) and a["measured_start"] is False
    assert a["nrmse"] != pytest.approx(b["nrmse"], rel=1e-3)
    assert main(["compare", str(tmp_path / "val.csv"), *models, "--init-window", "0.2", "--measured-start", "no",
                 "--json", str(tmp_path / "one.json")]) == 0
    assert "differently" not in capsys.readouterr().err
    a, b = json.loads((tmp_path / "one.json").read_text())["models"]
    assert a["nrmse"] == b["nrmse"] and (a["init_window"], b["measured_start"]) == (0.2, False)
    from greybox.fitted import load
    fm = load(str(tmp_path / "a.json"))
    assert a["nrmse"] == pytest.approx(predict(fm.model, fm.p, val, 1.0, init_window=0.2).total, rel=1e-9)

"""Multi-horizon validation beside the naive predictor (issue 15 item 3)."""
import json

import numpy as np
import pytest
from matplotlib.figure import Figure

from greybox import QuadrotorModel, load_airframe, plotting
from greybox.cli import main
from greybox.data import save_log
from greybox.synth import SensorSpec, model_with_hidden_effects, synthesize
from greybox.validation import HorizonErrors

from conftest import AIRFRAMES


def test_a_right_model_beats_the_naive_predictor_and_the_json_says_so(tmp_path):
    base = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    m, p = model_with_hidden_effects(base, [])
    log = synthesize(m, p, 16.0, SensorSpec(rate=200.0, vision_rate=50.0), seed=5).log
    save_log(log, tmp_path / "f.csv")
    assert main(["fit", str(tmp_path / "f.csv"), "--airframe", str(AIRFRAMES / "paper.toml"), "--quiet",
                 "--json", str(tmp_path / "r.json"), "--plots", str(tmp_path / "plots")]) == 0
    h = json.loads((tmp_path / "r.json").read_text())["horizons"]
    assert 0.25 in h["horizons"] and 0.5 in h["horizons"] and h["horizons"][0] == pytest.approx(0.005)
    i25, i50 = h["horizons"].index(0.25), h["horizons"].index(0.5)
    for ch in ("z", "phi", "theta", "p", "q"):
        for i in (i25, i50):
            assert h["model"][ch][i] < h["naive"][ch][i], (ch, h["horizons"][i])
    # one sample ahead the two predictors start from the same state: nearly the same error
    assert h["model"]["phi"][0] == pytest.approx(h["naive"]["phi"][0], rel=0.2)
    assert (tmp_path / "plots" / "horizons.png").exists()


def test_naive_predictor_by_hand():
    """Constant velocity and rates: with a known start state and measurements, the errors are
    what one computes by hand."""
    from greybox.validation import Prediction
    from greybox.data import log_from_arrays
    t = np.arange(0, 1.0, 0.01)
    n = t.size
    meas = np.zeros((n, 9))
    meas[:, 0] = 0.5 * t ** 2             # x accelerates at 1 m/s^2 from rest
    log = log_from_arrays(t, np.full((n, 4), 300.0), meas)
    pred = meas.copy()
    pred[:, 0] += 0.001                   # the model is 1 mm off everywhere
    x0 = np.zeros((1, 12))
    pr = Prediction(log, pred, [(0, n)], ["x"], {"x": 0.1}, 0.1, 1.0, meas - pred, start_states=x0)
    he = HorizonErrors.from_prediction(pr, horizons=[0.1, 0.5])
    i = he.horizons.index(0.5)
    assert he.model["x"][i] == pytest.approx(0.001)
    assert he.naive["x"][i] == pytest.approx(0.5 * 0.5 ** 2)     # constant (zero) velocity
    assert not he.beats_naive("x", 0.01) or he.model["x"][0] < he.naive["x"][0]
    fig = Figure()
    ax = fig.add_subplot()
    assert plotting.horizons(he, ax=ax) is fig and ax.lines

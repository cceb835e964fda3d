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
    # one sample ahead both are at the attitude noise: the model's smoothed start state about
    # one noise std off, the naive predictor's start (the last samples, no model) at most sqrt(2)
    assert h["model"]["phi"][0] <= h["naive"]["phi"][0] <= 1.6 * h["model"]["phi"][0]
    assert (tmp_path / "plots" / "horizons.png").exists()


def test_naive_predictor_by_hand():
    """Constant velocity and rates from the measurements before the window: the errors are
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


def test_naive_predictor_takes_its_state_from_the_measurements_not_the_model():
    """A window starting at 0.5 s of x = 2 t (1 mm noise-free), y = 0, phi = 0.1 t with a gyro
    p = 0.1: the naive predictor continues the line exactly, whatever the model's estimated
    start state (here absurd: 10 m off, 50 rad/s)."""
    from greybox.validation import Prediction, naive_start
    from greybox.data import log_from_arrays
    t = np.arange(0, 1.0, 0.01)
    n = t.size
    meas = np.zeros((n, 9))
    meas[:, 0] = 2.0 * t
    meas[:, 3] = 0.1 * t
    meas[:, 6] = 0.1
    log = log_from_arrays(t, np.full((n, 4), 300.0), meas)
    x_bad = np.full(12, 10.0)
    x_bad[9:12] = 50.0
    a = 50
    pv, eul, rate, om = naive_start(log, np.column_stack([meas, np.full((n, 3), np.nan)]), a, x_bad)
    assert pv[0] == pytest.approx(1.0) and pv[3] == pytest.approx(2.0)       # x(0.5), vx
    assert pv[1] == pytest.approx(0.0) and pv[4] == pytest.approx(0.0)
    assert eul[0] == pytest.approx(0.05) and rate[0] == pytest.approx(0.1) and om[0] == pytest.approx(0.1)
    pr = Prediction(log, np.column_stack([meas, np.full((n, 3), np.nan)]), [(a, n)], ["x", "phi"],
                    {"x": 0.1, "phi": 0.1}, 0.1, 0.5, np.zeros((n, 12)), start_states=x_bad[None, :])
    he = HorizonErrors.from_prediction(pr, horizons=[0.1, 0.25])
    assert he.naive["x"][he.horizons.index(0.25)] == pytest.approx(0.0, abs=1e-9)
    assert he.naive["phi"][he.horizons.index(0.25)] == pytest.approx(0.0, abs=1e-9)

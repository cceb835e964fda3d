"""Issue 17's check, as a user would write it with the documented public API only:
DataFrame in -> fit -> save -> load -> identical predictions -> plot into a given axes under
a non-Agg backend (the backend unchanged) -> to_control() -> from_control() round trip."""
from __future__ import annotations

import numpy as np
import pytest

import greybox
from greybox import plotting
from greybox.linearize import LinearModel
from greybox.synth import SensorSpec, model_with_hidden_effects, synthesize

from conftest import AIRFRAMES


def test_dataframe_fit_save_load_plot_control(tmp_path):
    pd = pytest.importorskip("pandas")
    control = pytest.importorskip("control")
    matplotlib = pytest.importorskip("matplotlib")
    model = greybox.QuadrotorModel(greybox.load_airframe(AIRFRAMES / "paper.toml"))
    truth, p = model_with_hidden_effects(model, [])
    df = synthesize(truth, p, 10.0, SensorSpec(rate=200.0, vision_rate=50.0), seed=8).log.to_dataframe()
    assert isinstance(df, pd.DataFrame)

    log = greybox.FlightLog.from_dataframe(df)
    est, val = log.split(0.8)
    res = greybox.fit(model, est, p0={"K_T": 2.8e-5})
    assert res.converged and res.value("K_T") == pytest.approx(2.395e-5, rel=0.01)
    fm = greybox.load(res.save(tmp_path / "m.json"))
    a, b = res.predict(val), fm.predict(val)
    np.testing.assert_array_equal(a.predicted, b.predicted)
    assert a.total == b.total

    before = matplotlib.get_backend()
    matplotlib.use("svg")           # the user's backend, not Agg
    try:
        from matplotlib.figure import Figure
        fig = Figure()
        ax = fig.add_subplot()
        out = plotting.compare(b, ax=ax, channels="z")
        assert out is fig and ax.lines
        assert matplotlib.get_backend() == "svg"
    finally:
        matplotlib.use(before)

    sys = fm.to_control()
    assert isinstance(sys, control.StateSpace)
    lin = LinearModel.from_control(sys)
    np.testing.assert_allclose(lin.A, fm.linearize().A)
    np.testing.assert_allclose(lin.B, fm.linearize().B)
    back = lin.to_control()
    np.testing.assert_allclose(back.A, sys.A)
    assert list(back.state_labels) == list(sys.state_labels)

"""Plotting that behaves in a notebook: every figure function returns a Figure, draws into a
given axes, writes a file only when given a path, and never touches the backend or pyplot's
figure list. Also the notebook reprs of FlightLog and Diagnosis."""
import importlib.util
import os
import re
import subprocess
import sys
from importlib import resources
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from matplotlib.figure import Figure

from greybox import QuadrotorModel, diagnose, load_airframe, plotting, predict
from greybox.errors import GreyboxInputError
from greybox.n4sid import n4sid, order_plot
from greybox.synth import SensorSpec, synthesize
from greybox.validation import compare_plot, residual_plot

PACKAGE = Path(plotting.__file__).resolve().parent
INLINE = "module://matplotlib_inline.backend_inline"


@pytest.fixture(scope="module")
def backend():
    """A non-Agg backend, as in a notebook (the inline one when installed, else pdf)."""
    old = matplotlib.get_backend()
    wanted = INLINE if importlib.util.find_spec("matplotlib_inline") else "pdf"
    matplotlib.use(wanted)
    import matplotlib.pyplot as plt
    plt.close("all")
    yield matplotlib.get_backend()
    plt.close("all")
    matplotlib.use(old)


@pytest.fixture(scope="module")
def flight():
    af = load_airframe(resources.files("greybox") / "data" / "airframes" / "paper.toml")
    truth = QuadrotorModel(af)
    fl = synthesize(truth, duration=12, seed=5, sensors=SensorSpec(rate=200, vision_rate=50),
                    manoeuvres=["hover", "yaw", "step_x", "yaw"])
    return truth, fl


@pytest.fixture(scope="module")
def pred(flight):
    truth, fl = flight
    return predict(truth, fl.parameters, fl.log)


@pytest.fixture(scope="module")
def diagnosis(flight):
    truth, fl = flight
    return diagnose(truth.without("yaw_torque"), fl.log, candidates=["yaw_torque", "attitude_bias"],
                    iterate=False)


@pytest.fixture(scope="module")
def black_box():
    rng = np.random.default_rng(0)
    A = np.diag([0.95, 0.8])
    u = rng.standard_normal((1500, 1))
    x, Y = np.zeros(2), []
    for k in range(u.shape[0]):
        Y.append([x.sum()])
        x = A @ x + np.array([1.0, 0.5]) * u[k, 0]
    return n4sid(u, np.array(Y) + 0.01 * rng.standard_normal((len(Y), 1)), dt=0.01)


def _drawn(ax) -> int:
    return len(ax.lines) + len(ax.patches) + len(ax.collections)


def _check(call, backend, tmp_path, monkeypatch):
    """Call a figure function four ways: bare, into an axes, with a path, both."""
    import matplotlib.pyplot as plt
    monkeypatch.chdir(tmp_path)
    # a user's own figure is open, as in a notebook
    user_fig, user_ax = plt.subplots()
    before = plt.get_fignums()
    fig = call(None, None)
    assert isinstance(fig, Figure) and fig is not user_fig
    assert fig.axes and any(_drawn(a) for a in fig.axes)
    assert list(tmp_path.iterdir()) == []                       # no path, no file
    out = call(user_ax, None)
    assert out is user_fig and _drawn(user_ax) > 0               # drew into the given axes
    assert list(tmp_path.iterdir()) == []
    sub = tmp_path / "figs" / "a.png"
    fig2 = call(None, sub)
    assert isinstance(fig2, Figure) and sub.stat().st_size > 1000
    _, ax2 = plt.subplots()
    before2 = plt.get_fignums()
    assert call(ax2, tmp_path / "b.svg") is ax2.figure and _drawn(ax2) > 0
    assert (tmp_path / "b.svg").read_text().lstrip().startswith("<?xml")
    assert sorted(p.name for p in tmp_path.rglob("*") if p.is_file()) == ["a.png", "b.svg"]   # no temp left
    assert plt.get_fignums() == before2 and before2[:len(before)] == before
    assert matplotlib.get_backend() == backend
    plt.close("all")


def test_compare(pred, backend, tmp_path, monkeypatch):
    _check(lambda ax, path: plotting.compare(pred, ax=ax, path=path), backend, tmp_path, monkeypatch)


def test_a_new_figure_shows_itself_in_a_notebook(pred):
    """A cell's value is shown as PNG even where pyplot (the notebook's formatter) is not loaded."""
    assert plotting.compare(pred, channels="z")._repr_png_()[:8] == b"\x89PNG\r\n\x1a\n"


def test_compare_several_predictions_and_channel_choice(pred, backend):
    fig = plotting.compare([pred, pred], labels=["a", "b"], channels=["z", "psi"])
    assert [a.get_ylabel() for a in fig.axes] == ["z", "psi"] and len(fig.axes[0].lines) >= 3
    fig = Figure()
    ax = fig.add_subplot()
    plotting.compare(pred, ax=ax, channels="psi")
    assert ax.get_ylabel() == "psi"
    ax = Figure().add_subplot()
    plotting.compare(pred, ax=ax)                                 # default: the worst channel
    assert ax.get_ylabel() == max(pred.nrmse, key=pred.nrmse.get)
    with pytest.raises(GreyboxInputError, match="one axes"):
        plotting.compare(pred, ax=ax, channels=["x", "y"])
    with pytest.raises(GreyboxInputError, match="no channel 'w1'"):
        plotting.compare(pred, channels="w1")
    axes = Figure().subplots(2)
    assert plotting.compare(pred, axes=axes, channels=["x", "y"]) is axes[0].figure
    assert all(_drawn(a) for a in axes)
    assert matplotlib.get_backend() == backend


def test_residuals(pred, backend, tmp_path, monkeypatch):
    _check(lambda ax, path: plotting.residuals(pred, ax=ax, path=path), backend, tmp_path, monkeypatch)


def test_diagnosis_figures(diagnosis, backend, tmp_path, monkeypatch):
    for name, fn in (("whiteness", plotting.whiteness), ("regimes", plotting.regimes),
                     ("ranking", plotting.ranking)):
        d = tmp_path / name
        d.mkdir()
        _check(lambda ax, path: fn(diagnosis, ax=ax, path=path), backend, d, monkeypatch)
    figs = plotting.report_figures(diagnosis)
    assert {"compare_baseline", "whiteness", "ranking"} <= set(figs)
    assert all(isinstance(f, Figure) for f in figs.values())
    # the whiteness of a plain residual array
    res = np.random.default_rng(1).standard_normal((500, 9))
    assert isinstance(plotting.whiteness(res, channels=["x", "r"]), Figure)


def test_n4sid_order(black_box, backend, tmp_path, monkeypatch):
    _check(lambda ax, path: plotting.n4sid_order(black_box, ax=ax, path=path), backend, tmp_path, monkeypatch)


def test_file_writing_wrappers_keep_their_contract(pred, diagnosis, black_box, backend, tmp_path):
    import matplotlib.pyplot as plt
    before = plt.get_fignums()
    assert compare_plot(pred, tmp_path / "c" / "compare.png") == tmp_path / "c" / "compare.png"
    assert residual_plot(pred, tmp_path / "r.png").stat().st_size > 1000
    assert order_plot(black_box, tmp_path / "o.png").stat().st_size > 1000
    rep = diagnosis.report(tmp_path / "rep")
    assert "data:image/png;base64," in rep.read_text()
    assert {p.name for p in (tmp_path / "rep").glob("*.png")} >= {"compare_baseline.png", "whiteness.png",
                                                                  "ranking.png"}
    assert plt.get_fignums() == before and matplotlib.get_backend() == backend


def test_no_module_selects_a_backend():
    calls = re.compile(r"\b(matplotlib|mpl)\s*\.\s*use\s*\(|switch_backend\s*\(")
    offenders = [f"{p.relative_to(PACKAGE)}:{i}" for p in sorted(PACKAGE.rglob("*.py"))
                 for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if calls.search(line)]
    assert offenders == []


def test_plotting_does_not_import_pyplot(tmp_path):
    code = ("import sys, numpy as np\n"
            "from greybox import plotting\n"
            "import greybox.validation, greybox.diagnosis, greybox.n4sid\n"
            f"plotting.whiteness(np.random.default_rng(0).standard_normal((300, 9)), path={str(tmp_path / 'w.png')!r})\n"
            "assert 'matplotlib.pyplot' not in sys.modules, 'pyplot imported'\n")
    env = dict(os.environ, MPLBACKEND="pdf")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "w.png").stat().st_size > 1000


def test_reprs(flight, diagnosis):
    log = flight[1].log
    text = repr(log)
    assert text.startswith("<FlightLog") and f"{len(log)} samples" in text and "phi 200 Hz" in text
    assert "w1..w4" in text and len(text) < 400
    html = log._repr_html_()
    assert "<table" in html and "rate (Hz)" in html and "w4" in html
    text = repr(diagnosis)
    assert "verdict 'yaw_torque'" in text and "baseline nrmse" in text and "yaw_torque*" in text
    assert len(text) < 400
    html = diagnosis._repr_html_()
    assert "yaw_torque" in html and "attitude_bias" in html and "<table" in html
    assert f"{diagnosis.baseline_prediction.total:.3g}" in html

"""Interop: pandas DataFrames in and out of FlightLog, python-control both ways, dlqr on a
system, .mat export, and the public names' docstrings."""
from __future__ import annotations

import inspect
import sys
from importlib import resources

import numpy as np
import pytest

import greybox
from greybox import FlightLog, GreyboxInputError, LinearModel, QuadrotorModel, dlqr, load_airframe, load_log
from greybox.data import save_log

DATA = resources.files("greybox") / "data"
DEMO = str(DATA / "logs" / "demo_ground_effect.csv")
PAPER = str(DATA / "airframes" / "paper.toml")


def _same_log(a: FlightLog, b: FlightLog) -> None:
    assert np.array_equal(a.t, b.t)
    assert a.input_names == b.input_names and a.output_names == b.output_names
    assert np.array_equal(a.inputs, b.inputs)
    assert np.array_equal(a.outputs, b.outputs, equal_nan=True)
    assert list(a.extras) == list(b.extras)
    for k in a.extras:
        assert np.array_equal(a.extras[k], b.extras[k], equal_nan=True)


# ------------------------------------------------------------------------------ pandas
def test_dataframe_round_trip_keeps_everything():
    pd = pytest.importorskip("pandas")
    log = load_log(DEMO)
    log.extras["vbat"] = np.linspace(4.1, 3.7, len(log))
    df = log.to_dataframe()
    assert isinstance(df, pd.DataFrame)
    assert list(df.columns) == ["t", *log.input_names, *log.output_names, "vbat"]
    assert df["x"].isna().any()            # multi-rate: vision samples missing between frames
    back = FlightLog.from_dataframe(df)
    _same_log(back, log)
    assert back.source == "DataFrame" and back.notes == [
        "DataFrame: extra column(s) vbat: not measured channels; kept as extras, read by an effect that uses them "
        "(battery_voltage reads vbat) and offered to discovery as features where they vary (leave out a column no "
        "vehicle would log), unused otherwise"]
    # any column order, t in the index, source named
    shuffled = df[df.columns[::-1]].set_index("t")
    _same_log(FlightLog.from_dataframe(shuffled, source="flight 3"), log)


def _csv_text(rows: list[str], header: str = "t,w1,w2,w3,w4,x,y,z,phi,theta,psi") -> str:
    return "\n".join([header] + rows) + "\n"


def _row(t: float, w: float = 400.0, z: float = -1.0, phi: float = 0.0) -> str:
    return f"{t:.3f},{w},{w},{w},{w},0,0,{z},{phi},0,0"


GOOD = [_row(0.01 * k) for k in range(60)]


@pytest.mark.parametrize("rows, message", [
    ([r if k != 7 else "0.070,,400,400,400,0,0,-1,0,0,0" for k, r in enumerate(GOOD)],
     "column 'w1': missing value"),
    ([_row(0.01 * k, w=40000.0 if k == 9 else 400.0) for k in range(60)], "is it RPM?"),
    ([_row(0.01 * k if k != 11 else 0.09) for k in range(60)], "strictly increasing"),
    ([_row(0.01 * k, phi=30.0 if k == 12 else 0.0) for k in range(60)], "is it in degrees?"),
    ([_row(1.0 * k) for k in range(60)], "look"),                     # t in another unit
    ([_row(0.01 * k if k < 30 else 0.01 * k + 20.0) for k in range(60)], "split the log there"),
])
def test_dataframe_gets_the_csv_checks(tmp_path, rows, message):
    """The same validation on both paths; the DataFrame's errors name its index."""
    pd = pytest.importorskip("pandas")
    path = tmp_path / "bad.csv"
    path.write_text(_csv_text(rows))
    with pytest.raises(GreyboxInputError, match=message) as from_csv:
        load_log(path)
    df = pd.read_csv(path)
    df.index = df.index + 100              # so that an index label is not a line number
    with pytest.raises(GreyboxInputError, match=message) as from_df:
        FlightLog.from_dataframe(df)
    csv_msg, df_msg = str(from_csv.value), str(from_df.value)
    assert df_msg.startswith("DataFrame: ")
    if " row " in csv_msg:
        line = int(csv_msg.split(" row ")[1].split(",")[0])
        assert f"row index {line - 2 + 100}," in df_msg      # line 2 is data row 0
    assert csv_msg.split(": ", 1)[1].split(",", 1)[-1] == df_msg.split(": ", 1)[1].split(",", 1)[-1]


def test_dataframe_gaps_are_filled_like_the_csv(tmp_path):
    pd = pytest.importorskip("pandas")
    rows = [_row(0.01 * k if k < 30 else 0.01 * k + 0.5) for k in range(60)]   # a 0.5 s dropout
    path = tmp_path / "gap.csv"
    path.write_text(_csv_text(rows))
    a, b = load_log(path), FlightLog.from_dataframe(pd.read_csv(path))
    assert len(a) > 60
    _same_log(a, b)
    assert any("gap" in n for n in b.notes)


def test_dataframe_bad_cells_and_objects_are_named():
    pd = pytest.importorskip("pandas")
    df = load_log(DEMO).to_dataframe().iloc[:100].copy()
    df["z"] = df["z"].astype(object)
    df.loc[42, "z"] = "low"
    with pytest.raises(GreyboxInputError, match=r"DataFrame: row index 42, column 'z': not a number: 'low'"):
        FlightLog.from_dataframe(df)
    df = load_log(DEMO).to_dataframe().iloc[:100].copy()
    df["mode"] = ["hover" if k % 2 else None for k in range(100)]    # an extra of text: ignored
    log = FlightLog.from_dataframe(df)
    assert "mode" not in log.extras and any("ignored text column(s) mode" in n for n in log.notes)
    df = load_log(DEMO).to_dataframe().drop(columns=["w3"])
    with pytest.raises(GreyboxInputError, match="missing required column 'w3'"):
        FlightLog.from_dataframe(df)
    with pytest.raises(GreyboxInputError, match="expected a pandas DataFrame"):
        FlightLog.from_dataframe({"t": [0.0]})
    df = load_log(DEMO).to_dataframe()
    df["t"] = pd.to_datetime(df["t"], unit="s")
    with pytest.raises(GreyboxInputError, match="dates or durations"):
        FlightLog.from_dataframe(df)
    assert np.isnan(FlightLog.from_dataframe(load_log(DEMO).to_dataframe().astype("Float64")).outputs).any()


def test_without_pandas_the_error_says_how_to_install(monkeypatch):
    log = load_log(DEMO)
    monkeypatch.setitem(sys.modules, "pandas", None)      # import pandas -> ImportError
    with pytest.raises(ImportError, match="pip install pandas"):
        log.to_dataframe()
    with pytest.raises(ImportError, match="pip install pandas"):
        FlightLog.from_dataframe(object())


def test_save_log_then_read_csv_with_pandas_is_the_same_log(tmp_path):
    pd = pytest.importorskip("pandas")
    log = load_log(DEMO).slice(0, 400)
    save_log(log, tmp_path / "l.csv")
    _same_log(FlightLog.from_dataframe(pd.read_csv(tmp_path / "l.csv")), log)


# ------------------------------------------------------------------------------ python-control
@pytest.fixture(scope="module")
def lin():
    from greybox import linearize
    return linearize(QuadrotorModel(load_airframe(PAPER)))


def _same_linear(a: LinearModel, b: LinearModel) -> None:
    for M in "ABCD":
        assert np.array_equal(getattr(a, M), getattr(b, M)), M
    assert (a.state_names, a.input_names, a.output_names) == (b.state_names, b.input_names, b.output_names)
    assert np.array_equal(a.x_op, b.x_op) and np.array_equal(a.u_op, b.u_op)
    assert a.dt == b.dt


def test_from_control_round_trips_to_control(lin):
    control = pytest.importorskip("control")
    sys_c = lin.to_control()
    assert isinstance(sys_c, control.StateSpace)
    _same_linear(LinearModel.from_control(sys_c, lin.x_op, lin.u_op), lin)
    d = lin.discretize(0.01)
    back = LinearModel.from_control(d.to_control(), x_trim=d.x_op, u_trim=d.u_op)
    _same_linear(back, d)
    assert back.dt == 0.01
    # operating point zero unless given
    z = LinearModel.from_control(sys_c)
    assert np.array_equal(z.x_op, np.zeros(12)) and np.array_equal(z.u_op, np.zeros(4))
    assert z.dt is None and z.state_names[:3] == ["x", "y", "z"]


def test_from_control_takes_any_python_control_system():
    control = pytest.importorskip("control")
    lm = LinearModel.from_control(control.tf([1.0], [1.0, 2.0, 1.0]))
    assert lm.A.shape == (2, 2) and lm.B.shape == (2, 1) and lm.C.shape == (1, 2)
    assert lm.input_names == ["u[0]"] and lm.output_names == ["y[0]"]
    unspecified = control.ss([[1.0]], [[1.0]], [[1.0]], [[0.0]], True)
    lm = LinearModel.from_control(unspecified)
    assert lm.dt is True and lm.to_control().dt is True
    with pytest.raises(GreyboxInputError, match="x_trim must be 1 finite values"):
        LinearModel.from_control(unspecified, x_trim=[0.0, 1.0])
    with pytest.raises(GreyboxInputError, match="expected a python-control system"):
        LinearModel.from_control(np.eye(2))


def test_dlqr_accepts_a_discrete_system(lin):
    control = pytest.importorskip("control")
    d = lin.discretize(0.01)
    Q, R = np.eye(12), 1e-3 * np.eye(4)
    K, S, E = dlqr(d.A, d.B, Q, R)
    for sys_d in (d.to_control(), d):           # python-control, and our own LinearModel
        K2, S2, E2 = dlqr(sys_d, Q, R)
        assert np.array_equal(K, K2) and np.array_equal(S, S2)
    Kc, _, _ = control.dlqr(d.to_control(), Q, R)
    assert np.allclose(K, Kc, rtol=1e-6, atol=1e-8)
    N = np.zeros((12, 4))
    assert np.array_equal(dlqr(d.to_control(), Q, R, N)[0], K)
    for continuous in (lin.to_control(), lin):
        with pytest.raises(GreyboxInputError, match="continuous-time.*discretise it first"):
            dlqr(continuous, Q, R)


def test_save_mat_loads_back(lin, tmp_path):
    from scipy.io import loadmat
    for model, dt in ((lin, 0.0), (lin.discretize(0.01), 0.01)):
        path = tmp_path / f"lin_{dt}.mat"
        model.save_mat(path)
        m = loadmat(path)
        for M in "ABCD":
            assert np.array_equal(m[M], getattr(model, M)), M
        assert m["x_trim"].shape == (12, 1) and np.array_equal(m["x_trim"].ravel(), model.x_op)
        assert np.array_equal(m["u_trim"].ravel(), model.u_op)
        assert m["dt"].item() == dt
        for key, names in (("state_names", model.state_names), ("input_names", model.input_names),
                           ("output_names", model.output_names)):
            assert [str(c[0]) for c in m[key].ravel()] == names
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lin_0.0.mat", "lin_0.01.mat"]  # no temporaries


# ------------------------------------------------------------------------------ public names
def test_warnings_are_exported():
    from greybox import errors
    for name in ("ConvergenceWarning", "AirframeWarning", "CacheWarning"):
        assert name in greybox.__all__
        assert getattr(greybox, name) is getattr(errors, name)


def test_functions_named_like_their_module_stay_functions():
    import greybox.closedloop  # noqa: F401  (imports greybox.linearize and greybox.n4sid as modules)
    from greybox import LinearModel as _LM, linearize, n4sid  # noqa: F401
    assert inspect.isfunction(linearize) and inspect.isfunction(n4sid)
    assert inspect.isfunction(greybox.linearize) and inspect.isfunction(greybox.n4sid)


@pytest.mark.parametrize("name", [n for n in greybox.__all__ if n != "__version__"])
def test_every_public_name_has_a_docstring_with_an_example(name):
    doc = inspect.getdoc(getattr(greybox, name)) or ""
    assert "Example::" in doc or ">>>" in doc, f"greybox.{name} has no example in its docstring"

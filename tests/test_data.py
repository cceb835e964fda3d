import numpy as np
import pytest

from greybox.data import FlightLog, load_log, save_log
from greybox.errors import GreyboxInputError

HEADER = "t,w1,w2,w3,w4,x,y,z,phi,theta,psi"


def good_rows(n=100):
    rows = []
    for k in range(n):
        pos = "0.1,0.2,-1.0" if k % 10 == 0 else ",,"
        rows.append(f"{k * 0.001:.3f},300,301,302,303,{pos},0.01,0.02,0.03")
    return rows


def write(tmp_path, lines, name="log.csv"):
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def test_multirate_log_loads(tmp_path):
    log = load_log(write(tmp_path, [HEADER + ",vbat"] + [r + ",4.1" for r in good_rows()]))
    assert len(log) == 100 and log.input_names == ["w1", "w2", "w3", "w4"]
    assert np.isfinite(log.output("x")).sum() == 10 and np.isfinite(log.output("phi")).all()
    assert "vbat" in log.extras and "extra column(s) vbat: not measured channels" in log.notes[0]
    assert log.rate("x") == pytest.approx(100.0)
    assert "did you mean" not in log.notes[0]


def test_a_misspelled_optional_column_is_named_with_what_it_may_mean(tmp_path):
    """An optional column misspelled is an extra column, ignored; the note asks whether the
    column it resembles was meant (the fit otherwise runs without that gyro axis)."""
    log = load_log(write(tmp_path, [HEADER + ",p,qq,r,vbat"] + [r + ",0.1,0.2,0.3,4.1" for r in good_rows()]))
    assert log.output_names[-2:] == ["p", "r"] and "qq" in log.extras
    assert "did you mean 'q' for 'qq'?" in log.notes[0] and "for 'vbat'" not in log.notes[0]


def test_any_column_order_and_nan_text(tmp_path):
    lines = ["psi,theta,phi,z,y,x,w4,w3,w2,w1,t", "0,0,0,nan,nan,nan,1,2,3,4,0", "0,0,0,1,2,3,1,2,3,4,0.1"]
    log = load_log(write(tmp_path, lines))
    np.testing.assert_allclose(log.inputs[0], [4, 3, 2, 1])
    assert np.isnan(log.output("x")[0]) and log.output("x")[1] == 3


def test_save_load_roundtrip(tmp_path):
    log = load_log(write(tmp_path, [HEADER] + good_rows()))
    save_log(log, tmp_path / "out.csv")
    log2 = load_log(tmp_path / "out.csv")
    np.testing.assert_array_equal(log.t, log2.t)
    np.testing.assert_array_equal(np.isnan(log.outputs), np.isnan(log2.outputs))
    np.testing.assert_array_equal(np.nan_to_num(log.outputs), np.nan_to_num(log2.outputs))


def test_split_80_20(tmp_path):
    log = load_log(write(tmp_path, [HEADER] + good_rows(101)))
    est, val = log.split()
    assert len(est) == 81 and len(val) == 21 and est.t[-1] == val.t[0]


def test_resample_holds_inputs_and_interpolates_outputs():
    t = np.arange(0, 1.0001, 0.001)
    U = np.column_stack([np.where(t < 0.5, 100.0, 200.0)] * 4)
    Y = np.full((t.size, 6), np.nan)
    Y[::20, 0] = t[::20] * 2.0     # 50 Hz position, a ramp
    Y[:, 3] = np.sin(t)
    log = FlightLog(t, U, ["w1", "w2", "w3", "w4"], Y, ["x", "y", "z", "phi", "theta", "psi"])
    r = log.resample(0.01)
    assert len(r) == 101
    np.testing.assert_allclose(r.output("x"), r.t * 2.0, atol=1e-12)
    np.testing.assert_allclose(r.output("phi"), np.sin(r.t), atol=1e-12)
    assert np.all(np.isnan(r.output("y")))
    assert r.inputs[49, 0] == 100 and r.inputs[50, 0] == 200
    # a gap longer than 3 periods is not bridged
    Y[200:800, 0] = np.nan
    r = FlightLog(t, U, log.input_names, Y, log.output_names).resample(0.01)
    assert np.isnan(r.output("x")[50]) and np.isfinite(r.output("x")[10])


@pytest.mark.parametrize("lines, message", [
    (["t,w1,w2,w3,w4,x,y,phi,theta,psi", "0,1,1,1,1,0,0,0,0,0"], "missing required column 'z'"),
    (["w1,w2,w3,w4,x,y,z,phi,theta,psi", "1,1,1,1,0,0,0,0,0,0"], "missing required column 't'"),
    (["t,x,y,z,phi,theta,psi", "0,0,0,0,0,0,0"], "missing required rotor speed columns"),
    # a required column renamed (a blind audit's 'psi' as 'yaw'): the column that is probably it is named
    (["t,w1,w2,w3,w4,x,y,z,phi,theta,yaw", "0,1,1,1,1,0,0,0,0,0,0"],
     r"missing required column 'psi' \(the header has 'yaw', which is no column of the format: is it 'psi'\?\)"),
    (["time,w1,w2,w3,w4,x,y,z,phi,theta,psi,vbat", "0,1,1,1,1,0,0,0,0,0,0,4"],
     r"missing required column 't' \(the header has 'time', which is no column of the format: is it 't'\?\)"),
    (["t,w1,w2,w3,w4,x,y,z,phi,theta,hdg,note", "0,1,1,1,1,0,0,0,0,0,0,1"],
     r"missing required column 'psi' \(the header's 'hdg', 'note' are no columns of the format: is one of them "
     r"'psi'\?\)"),
    # a NanoBench file given as it is (a blind audit): the importer is named
    (["t,px,py,pz,qx,qy,qz,qw,motor_motor_m1,motor_motor_m2,motor_motor_m3,motor_motor_m4", "0,0,0,0,0,0,0,1,0,0,0,0"],
     r"missing required rotor speed columns 'w1'..'w4' \(the header is a nanobench log's: convert it first, "
     r"greybox import nanobench"),
    (["t,w1,w2,w4,x,y,z,phi,theta,psi", "0,1,1,1,0,0,0,0,0,0"], "missing required column 'w3'"),
    ([HEADER, "0,1,1,1,1,0,0,0,0,0,0", "0.002,1,1,1,1,0,0,0,0,0,0", "0.001,1,1,1,1,0,0,0,0,0,0"],
     r"row 4, column 't'.*strictly increasing"),
    ([HEADER, "0,1,1,1,1,0,0,0,0,0,0", "0,1,1,1,1,0,0,0,0,0,0"], r"row 3, column 't'"),
    ([HEADER, "0,1,1,1,1,0,0,0,0,0,0", "0.1,1,1,abc,1,0,0,0,0,0,0"], r"row 3, column 'w3': not a number"),
    ([HEADER, "0,1,1,1,1,0,0,0,0,0,0", "0.1,1,1,,1,0,0,0,0,0,0"], r"row 3, column 'w3': missing value"),
    ([HEADER, ",1,1,1,1,0,0,0,0,0,0"], r"row 2, column 't': missing value"),
    ([HEADER, "0,1,1,1,1,0,0,0,0,0"], r"row 2: 10 cells, the header has 11"),
    ([HEADER, "0,12000,12000,12000,12000,0,0,0,0,0,0"], r"row 2, column 'w1'.*RPM"),
    ([HEADER, "0,1,1,1,1,0,0,0,0,0,inf"], r"row 2, column 'psi': infinite"),
    ([HEADER], "no data rows"),
    (["t,w1,w1,w2,w3,w4,x,y,z,phi,theta,psi"], "column 'w1' appears twice"),
    (["0,1,1,1,1,0,0,0,0,0,0"], "not a header"),
    ([""], "empty file"),
])
def test_bad_logs(tmp_path, lines, message):
    with pytest.raises(GreyboxInputError, match=message) as e:
        load_log(write(tmp_path, lines))
    assert "log.csv" in str(e.value)


def test_any_number_of_rotors(tmp_path):
    log = load_log(write(tmp_path, ["t,w1,w2,w3,w4,w5,w6,x,y,z,phi,theta,psi", "0,1,2,3,4,5,6,0,0,0,0,0,0"]))
    assert log.input_names == ["w1", "w2", "w3", "w4", "w5", "w6"]


def test_controls_log(tmp_path):
    log = load_log(write(tmp_path, ["t,u1,u2,u3,u4,x,y,z,phi,theta,psi", "0,9.8,0,0,0,0,0,0,0,0,0"]))
    assert log.input_names == ["u1", "u2", "u3", "u4"]


def test_missing_file(tmp_path):
    with pytest.raises(GreyboxInputError, match="not found"):
        load_log(tmp_path / "nope.csv")


def test_too_short_to_fit(tmp_path):
    log = load_log(write(tmp_path, [HEADER] + good_rows(20)))
    with pytest.raises(GreyboxInputError, match="too short to fit: 20 samples"):
        log.check_fittable()
    rows = good_rows(400)
    rows = [r if k > 380 else r.replace("0.1,0.2,-1.0", ",,") for k, r in enumerate(rows)]
    log = load_log(write(tmp_path, [HEADER] + rows))
    with pytest.raises(GreyboxInputError, match="column 'x' has only 0 measurements"):
        log.check_fittable()
    load_log(write(tmp_path, [HEADER] + good_rows(400))).check_fittable()


def test_save_is_atomic(tmp_path, monkeypatch):
    log = load_log(write(tmp_path, [HEADER] + good_rows()))
    target = tmp_path / "out.csv"
    import greybox.data as d

    def boom(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(d.os, "replace", boom)
    with pytest.raises(KeyboardInterrupt):
        save_log(log, target)
    assert not target.exists() and not list(tmp_path.glob(".out.csv*"))


def test_a_log_without_position_says_what_fits_it(tmp_path):
    """x, y, z left empty: the full model cannot be fitted; the error says what an IMU-only
    fit needs and which of it the log lacks (here the accelerometer's az: a misspelled
    column makes the same log fall here). Absent position columns are named as such."""
    rows = [r.replace("0.1,0.2,-1.0", ",,") + ",0.1,0.2,0.3" for r in good_rows(400)]
    log = load_log(write(tmp_path, [HEADER + ",p,q,r"] + rows))
    with pytest.raises(GreyboxInputError, match=r"column 'x' is empty: fitting the full model needs position "
                                                r".*accelerometer az \(missing here: az\)"):
        log.check_fittable()
    with pytest.raises(GreyboxInputError, match=r"missing required column 'x' \(a log without position keeps "
                                                r"the columns x, y, z, left empty\)"):
        load_log(write(tmp_path, ["t,w1,w2,w3,w4,phi,theta,psi", "0,1,1,1,1,0,0,0"]))

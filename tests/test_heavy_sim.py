"""A fifteenth blind audit's heavy-lift vehicle (``tests/heavy_sim.py``: its own simulator of
a 3 kg "+" quadrotor, scipy's LSODA, a geometric controller on a complementary filter's
attitude, 100 Hz rows, motion capture at 50 Hz): an attitude propagated from the gyro, whose
slow error (15-22 mrad) its high-frequency content (0.07-0.12 mrad) does not show."""
import numpy as np
import pytest

from greybox import QuadrotorModel, load_airframe
from greybox.data import load_log
from greybox.diagnosis import diagnose
from greybox.shooting import filtered_attitude_error

import heavy_sim


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    path = tmp_path_factory.mktemp("heavy") / "heavy.toml"
    heavy_sim.airframe(str(path), guess=True)          # K_T x1.3, b x0.7, Kd x0.7
    return QuadrotorModel(load_airframe(path))


def _flight(tmp_path, name, seed, duration, effects):
    out = tmp_path / f"{name}_{seed}.csv"
    heavy_sim.fly(str(out), seed, duration, dict(effects), 0.001)
    return load_log(out), np.loadtxt(str(out).replace(".csv", ".truestate.txt"))


@pytest.mark.slow
def test_a_complementary_filters_attitude_no_longer_hides_a_ground_effect(model, tmp_path):
    """Low passes over the ground, each rotor's thrust / (1 - k_ge/h_i^2). Weighed as accurate
    to its high-frequency noise (0.1 mrad), the filter's attitude had hidden every catalogue
    effect the audit tried (null, "unexplained"). Its disagreement with the gyro measures its
    error (within 25 % of the truth's), weighs it, and the diagnosis names the ground effect
    with k_ge within 3 of its std."""
    k_ge = 0.002256
    (est, states), (val, _) = (_flight(tmp_path, "ge", 11, 40.0, {"ground_effect": k_ge}),
                               _flight(tmp_path, "ge", 111, 30.0, {"ground_effect": k_ge}))
    kin = filtered_attitude_error(est)
    for c, ch in enumerate(("phi", "theta")):
        err = est.output(ch) - states[:, 7 + c]
        truth = float(np.sqrt(np.nanmean(err ** 2)))
        assert kin[ch] == pytest.approx(truth, rel=0.25), (ch, kin[ch], truth)
    d = diagnose(model, est, validation=val, candidates=["ground_effect", "thrust_drift", "quadratic_drag"],
                 iterate=False, discover=False)
    assert d.verdict == "ground_effect", d.summary()
    fr = d.final_fit
    assert fr.converged, fr.status
    assert abs(fr.value("k_ge") - k_ge) < 3 * fr.std[fr.free_names.index("k_ge")], d.summary()
    assert any("propagated from the gyro" in w for w in d.baseline.warnings), d.baseline.warnings

"""The diagnosis on flights of a blind audit's simulator (``audit_sim.py``: another
integrator, a geometric attitude controller at the log rate, multisine excitation on the
commands), written from the contract alone: nothing missing gives null, a torque outside
the catalogue that the controller cancels is not named after the effect that scales the
commands' moment, and a cubic thrust term is the thrust curve (slow: two flights and one
diagnosis each, 1-2 minutes)."""
from __future__ import annotations

import pytest

import audit_sim as qs
from greybox import QuadrotorModel, load_airframe, load_log
from greybox.diagnosis import diagnose


def _diagnosed(tmp_path, vehicle: str, hidden: dict, rate: float, seeds: tuple[int, int]):
    """The audit's estimation (30 s) and validation (20 s) flights of ``vehicle`` with
    ``hidden`` at ``rate``, diagnosed as the README says (defaults, a separate validation
    flight); returns the diagnosis and the vehicle's truth."""
    paths = {}
    for tag, duration, seed in (("est", 30.0, seeds[0]), ("val", 20.0, seeds[1])):
        out = qs.fly(vehicle, hidden, duration, rate, seed)
        paths[tag] = tmp_path / f"{tag}.csv"
        qs.write_log(out["meas"], paths[tag])
        v = out["vehicle"]
    qs.write_airframe(v, tmp_path / "airframe.toml")
    model = QuadrotorModel(load_airframe(tmp_path / "airframe.toml"))
    d = diagnose(model, load_log(paths["est"]), validation=load_log(paths["val"]), progress=False)
    return d, v


@pytest.mark.slow
def test_a_periodic_torque_the_controller_cancels_is_not_a_moment_gain(tmp_path):
    """0.02 N m of periodic roll and pitch torque on the audit's 1 kg vehicle (4 % of one
    rotor's moment), nothing else missing. The controller cancels it through the commands,
    so ``moment_gain`` fitted to them takes up a third of it (k_M 0.67 ± 0.02 for a truth of
    1, p and q still 3.5x their noise: it was the verdict). Refitted with a disturbance torque
    it falls back to 1, so it is refused as the controller's answer; the verdict is null and
    the final model, holding the torque as a disturbance, has K_T, b and the drag right."""
    d, v = _diagnosed(tmp_path, "quad1kg", {"dist_torque": (0.02, 0.7)}, 200.0, (74, 574))
    assert d.baseline_certified
    mg = next(c for c in d.ranking if c.effect == "moment_gain")
    assert mg.fit is not None and mg.fit.value("k_M") < 0.8, mg.reason      # alone, it takes up the torque
    assert not mg.significant and "controller's answer" in mg.reason, mg.reason
    assert d.verdict is None and not [c.effect for c in d.ranking if c.significant], d.summary()
    final = d.fitted_model
    assert final.converged
    assert final.value("K_T") == pytest.approx(v["K_T"], rel=0.01)
    assert final.value("b") == pytest.approx(v["b"], rel=0.01)
    for k in range(3):
        assert final.value(f"Kd[{k}]") == pytest.approx(v["Kd"][k], rel=0.02)
    if d.final_prediction.total > d.baseline_prediction.total:
        # a random walk held over each window predicts a periodic torque worse than none
        assert any("cannot know ahead" in w for w in d.warnings), d.warnings


@pytest.mark.slow
def test_nothing_missing_on_a_30_g_vehicle_at_100_hz_gives_null(tmp_path):
    """The audit's 30 g vehicle (x layout, 1918 rad/s in hover), 100 Hz log, vision at 100
    Hz, nothing missing: null with a certified baseline, K_T and b within 0.1 %."""
    d, v = _diagnosed(tmp_path, "cf30g", {}, 100.0, (18, 518))
    assert d.baseline_certified
    assert d.verdict is None and d.null_reason == "nothing_missing", d.summary()
    assert d.baseline.value("K_T") == pytest.approx(v["K_T"], rel=1e-3)
    assert d.baseline.value("b") == pytest.approx(v["b"], rel=1e-3)
    # its body rates move faster than a 100 Hz log resolves: the noise estimated from their
    # high-frequency content is about twice the gyro's 5 mrad/s, and the certificate says so
    cert = d.baseline.certificate
    assert cert.residual_over_noise["p"] < 0.7 and "below the noise estimated" in cert.text(), cert.text()


@pytest.mark.slow
def test_a_cubic_thrust_term_is_the_thrust_curve_not_a_moment_gain(tmp_path):
    """The audit's 30 g vehicle at 100 Hz with ``T = K_T w^2 + c w^3``, ``c w_hover`` about 10 %
    of ``K_T`` (the audit's case O2). Before ``thrust_curve`` joined the catalogue the verdict was
    ``moment_gain``, k_M 1.040 ± 0.004: a differential thrust slope 4.5 % above the mean thrust's,
    named as a moment gain, with nothing saying the thrust curve was off. The form
    ``K_T' w^2 (1 + k_Tw (w/w_h - 1))`` holds ``a w^2 + c w^3`` exactly, with ``K_T' = K_T + c w_h``
    and ``k_Tw = c w_h / K_T'`` at the hover speed ``w_h`` of ``K_T'`` (measured 2026-11-30:
    k_Tw 0.08692 ± 0.00026 for 0.08701, validation error -47 %; moment_gain -39 %)."""
    c = 1.04e-12
    d, v = _diagnosed(tmp_path, "cf30g", {"w3": c}, 100.0, (88, 588))
    assert d.baseline_certified
    assert d.verdict == "thrust_curve", d.summary()
    weight = v["mass"] * qs.G / 4
    K_Tp = v["K_T"]
    for _ in range(60):
        K_Tp = v["K_T"] + c * (weight / K_Tp) ** 0.5
    k_Tw = c * (weight / K_Tp) ** 0.5 / K_Tp
    final = d.fitted_model
    std = final.parameters["k_Tw"]["std"]
    assert final.value("k_Tw") == pytest.approx(k_Tw, abs=3 * std), (final.value("k_Tw"), std, k_Tw)
    assert final.value("K_T") == pytest.approx(K_Tp, rel=2e-3)
    assert final.value("b") == pytest.approx(v["b"], rel=1e-2)

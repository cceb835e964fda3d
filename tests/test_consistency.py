"""The baseline's parameters on the two halves of the estimation data (``diagnose``'s
consistency check): a constant of the vehicle agrees with itself; a parameter absorbing a
missing effect follows what each half exercises, and is flagged when the halves disagree
beyond their standard deviations *and* by a physically meaningful amount."""
import numpy as np
import pytest

from greybox import QuadrotorModel, diagnose, effects, load_airframe
from greybox.diagnosis import CONSISTENCY_MIN_CHANGE
from greybox.synth import SensorSpec, synthesize

from conftest import AIRFRAMES

SENSORS = SensorSpec(rate=100.0, vision_rate=50.0)
MANOEUVRES = ["hover", "step_x", "yaw", "step_z", "step_y", "yaw"]


@pytest.fixture(scope="module")
def paper():
    return QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))


def _halves(paper, drift):
    """Halves of a 20 s flight whose thrust coefficient drifts by ``drift`` per second
    (``thrust_drift``, hidden), diagnosed with the base model and no candidate: their K_T."""
    truth = paper + effects.ThrustDrift()
    p = truth.parameter_vector({"K_T_drift": drift})
    log = synthesize(truth, p, duration=20.0, seed=21, sensors=SENSORS, manoeuvres=MANOEUVRES).log
    return diagnose(paper, log, candidates=[], discover=False, iterate=False)


def test_a_drifting_thrust_coefficient_is_flagged(paper):
    """K_T drifting 0.5 %/s: fitted on halves centred 8 s apart (the first 80 % of the log)
    the two K_T differ by about 4 %, far beyond their std: flagged, in the warnings and JSON."""
    d = _halves(paper, 5e-3)
    assert "K_T" in d.inconsistent, d.warnings
    a, sa, b, sb = d.inconsistent["K_T"]
    assert b / a - 1 == pytest.approx(0.04, abs=0.015)
    assert any(w.startswith("baseline fit: K_T differs between the two halves") for w in d.warnings)
    assert "K_T" in d.as_json()["inconsistent_parameters"]


def test_a_difference_too_small_to_matter_is_not_flagged(paper):
    """K_T drifting 0.05 %/s: the halves' K_T differ by about 0.4 %, many standard deviations
    at 100 Hz, but below CONSISTENCY_MIN_CHANGE of the value: the same constant."""
    d = _halves(paper, 5e-4)
    assert "K_T" not in d.inconsistent, d.warnings
    fits = d.baseline
    assert CONSISTENCY_MIN_CHANGE == 0.02 and fits.converged


@pytest.mark.slow
def test_a_flights_own_conditions_are_not_compared_with_another_flights():
    """The final model's parameters against a fit on the validation data alone
    (``validation_spread``), on another simulator's 1 kg vehicle (tests/foreign_sim.py) flown
    in a wind of (2, 0) m/s, validated on a flight in (-1, 1.5): a wind is a condition of its
    flight (``Effect.per_flight``), so another flight's is not compared with it; compared as
    if the validation were the flight's own tail, the two winds are flagged, 3 m/s apart."""
    from greybox.airframe import airframe_from_dict
    from greybox.diagnosis.consistency import validation_spread
    from greybox.fitting import fit
    from foreign_sim import airframe_dict, one_kg, simulate_flight
    veh = one_kg()
    flights = [simulate_flight(veh, duration=8.0, seed=10 + i, linear_drag=[0.3, 0.3, 0.15], wind=[*w, 0.0],
                               log_rate=200.0) for i, w in enumerate([(2.0, 0.0), (-1.0, 1.5)])]
    model = QuadrotorModel(airframe_from_dict(airframe_dict(veh))) + effects.Wind()
    res = fit(model, [flights[0].log])
    assert res.converged and res.value("wind[0]") == pytest.approx(2.0, abs=0.3)
    wind = ["wind[0]", "wind[1]"]
    assert validation_spread(model, res, [flights[1].log], wind, "auto", lambda s: None) == {}
    as_tail = validation_spread(model, res, [flights[1].log], wind, "auto", lambda s: None, tails=True)
    assert set(as_tail) == set(wind)
    assert as_tail["wind[0]"][2] == pytest.approx(-1.0, abs=0.3)


def test_a_comparison_that_cannot_be_made_says_so():
    """When the validation data cannot be fitted alone (here: a validation flight of 5
    samples, below what a fit takes), nothing is compared and ``validation_spread`` says so
    with None, which the JSON writes as null; ``{}`` is kept for "compared, and agreeing"
    (the flight's own tail of 2 s: the wind agrees with itself)."""
    from greybox.airframe import airframe_from_dict
    from greybox.diagnosis.consistency import half_spread, validation_spread
    from greybox.fitting import fit
    from foreign_sim import airframe_dict, one_kg, simulate_flight
    veh = one_kg()
    log = simulate_flight(veh, duration=10.0, seed=10, linear_drag=[0.3, 0.3, 0.15], wind=[2.0, 0.0, 0.0],
                          log_rate=200.0).log
    est, tail = log.split(0.8)
    model = QuadrotorModel(airframe_from_dict(airframe_dict(veh))) + effects.Wind()
    res = fit(model, [est])
    assert res.converged
    wind = ["wind[0]", "wind[1]"]
    said = []
    assert validation_spread(model, res, [tail.slice(0, 5)], wind, "auto", said.append, tails=True) is None
    assert any("not fitted alone" in s for s in said), said
    assert validation_spread(model, res, [tail], wind, "auto", lambda s: None, tails=True) == {}
    assert half_spread(model, res, [est.slice(0, 9)], wind, "auto", lambda s: None) is None



def test_a_spread_not_compared_is_null_in_the_json(paper):
    """The JSON tells "not compared" (null) from "compared, nothing disagrees" ({})."""
    import dataclasses
    d = _halves(paper, 5e-4)
    assert d.as_json()["final_parameter_validation_spread"] == {}
    unchecked = dataclasses.replace(d, final_spread=None, final_validation_spread=None).as_json()
    assert unchecked["final_parameter_spread"] is None and unchecked["final_parameter_validation_spread"] is None


def test_a_diagnosis_whose_validation_comparison_failed_says_which_std_went_unchecked(paper, monkeypatch):
    """The diagnosis of a drifting thrust coefficient adds ``thrust_drift``; when the
    validation fit that would check its std cannot be made (stood in for by a failing one),
    the diagnosis says which parameters went unchecked, and the JSON holds null, not {}."""
    from greybox.diagnosis import workflow
    monkeypatch.setattr(workflow, "validation_spread", lambda *a, **k: None)
    truth = paper + effects.ThrustDrift()
    log = synthesize(truth, truth.parameter_vector({"K_T_drift": -5e-3}), duration=20.0, seed=21, sensors=SENSORS,
                     manoeuvres=MANOEUVRES).log
    d = diagnose(paper, log, candidates=["thrust_drift"], discover=False, iterate=False)
    assert d.verdict == "thrust_drift" and d.final_fit.converged, d.summary()
    assert d.final_validation_spread is None and d.as_json()["final_parameter_validation_spread"] is None
    said = [w for w in d.warnings if "can be believed was not checked" in w]
    assert len(said) == 1 and "K_T_drift" in said[0] and "the validation data alone" in said[0], d.warnings
    assert "halves" not in said[0] and d.final_spread is not None


@pytest.mark.slow
def test_a_parameter_the_data_do_not_determine_is_named_with_what_it_trades_with(paper):
    """A hub drag's height multiplies the hub drag's force: with no hub drag in the flight
    (k_rdh fits to about zero) the height is free across its whole range and is said to be
    undetermined; with a hub drag there (k_rdh 2e-4, 3 cm above the CoG) it is fitted to a
    millimetre and nothing is said."""
    from greybox import fit
    from greybox.diagnosis.consistency import UNDETERMINED_SHARE, undetermined_parameters

    hub = paper + effects.by_name("hub_rotor_drag")
    words = {}
    for k_rdh in (0.0, 2e-4):
        p = hub.parameter_vector({"k_rdh": k_rdh, "k_rdv": 0.5 * k_rdh, "h_hub": 0.03})
        log = synthesize(hub, p, duration=8.0, seed=3).log
        res = fit(hub, log, p0=p)
        assert res.converged
        i = res.free_names.index("h_hub")
        width = 2 * paper.airframe.arm_length
        assert (res.std[i] > UNDETERMINED_SHARE * width) == (k_rdh == 0.0)
        words[k_rdh] = undetermined_parameters(res, ["hub_rotor_drag"])
    assert words[2e-4] == []
    assert len(words[0.0]) == 1 and words[0.0][0].startswith("h_hub = ")
    assert "not determined by these data" in words[0.0][0] and "k_rdh" in words[0.0][0]


def test_the_logs_sampling_is_not_compared_between_halves(paper, monkeypatch):
    """``sampled_inputs``' share of the next row follows how fast the speeds change within a
    row, so each half of a flight has its own (a blind audit's control flight: 0.56 and 0.70,
    4 std apart): not flagged as absorbing something missing; a K_T as far apart still is."""
    from types import SimpleNamespace

    from greybox.diagnosis import consistency
    model = paper + effects.by_name("sampled_inputs")
    names = ["K_T", "s_lead"]

    def half(kt, s):
        vals = {"K_T": kt, "s_lead": s}
        return SimpleNamespace(value=vals.__getitem__, white_std=np.array([1e-8, 0.02]),
                               std=np.array([1e-8, 0.02]))
    monkeypatch.setattr(consistency, "_half_fits", lambda *a: (half(2.0e-5, 0.56), half(2.2e-5, 0.70)))
    monkeypatch.setattr(consistency, "residual_widening", lambda E, s: 1.0)
    monkeypatch.setattr(consistency, "_plausible_sizes", lambda m, r: {})
    res = SimpleNamespace(model=model, free_names=names, per_flight_={}, sigma=None)
    out = consistency.half_consistency(model, res, [], None, "none", lambda s: None)
    assert list(out) == ["K_T"]
    assert effects.by_name("sampled_inputs").describes_sampling and not effects.by_name("motor_lag").describes_sampling

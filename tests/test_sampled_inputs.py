"""Rotor speeds sampled from a signal that varies between the log's rows (effect
``sampled_inputs``): by hand, recovered from a log made at a finer rate, absent from a log of
held commands, and settled by the diagnosis before any physical effect is judged."""
import warnings

import numpy as np
import pytest

from greybox import QuadrotorModel, effects, fit, load_airframe, simulate
from greybox.data import FlightLog
from greybox.diagnosis.ranking import default_candidates
from greybox.errors import GreyboxInputError

from conftest import AIRFRAMES

PATTERN = np.array([1.0, 0.3, -1.0, -0.3])     # a roll and pitch moment on any X or + layout
OUT = ["x", "y", "z", "phi", "theta", "psi", "p", "q", "r"]


def _airframe():
    return load_airframe(AIRFRAMES / "x_quad.toml")


def _speeds(t, w0):
    return w0 + 0.08 * w0 * (np.sin(2 * np.pi * 3.0 * t) + 0.5 * np.sin(2 * np.pi * 7.3 * t + 1.0))[:, None] * PATTERN


def test_each_interval_holds_the_blend_of_its_row_and_the_next_by_hand():
    """Rows w_k and w_k+1: with ``s_lead = s`` the model's derivatives over interval k are the
    base model's at ``(1 - s) w_k + s w_k+1``; at 0 the plain hold; the last row's next is
    itself. The parameter is a fraction of a sample in [0, 1] whose null (the hold) is 0."""
    base = QuadrotorModel(_airframe())
    model = base + effects.SampledInputs()
    assert model.input_names == ["w1", "w2", "w3", "w4", "w1@next", "w2@next", "w3@next", "w4@next"]
    assert model.steady_input_names == ["w1", "w2", "w3", "w4"]
    t = np.arange(0.0, 0.2, 0.01)
    W = _speeds(t, 400.0)
    log = FlightLog(t, W, ["w1", "w2", "w3", "w4"], np.full((t.size, 6), np.nan), OUT[:6])
    prep = model.prepare_log(log)
    assert np.array_equal(prep.inputs[:-1, 4:], W[1:]) and np.array_equal(prep.inputs[-1, 4:], W[-1])
    x0, k = base.initial_state(), 7
    i_s = model.param_names.index("s_lead")
    for s in (0.0, 0.5, 0.8):
        p = model.default_parameters()
        p[i_s] = s
        got = np.asarray(model.rhs(x0, prep.inputs[k], p, t[k])).ravel()
        want = np.asarray(base.rhs(x0, (1 - s) * W[k] + s * W[k + 1], base.default_parameters(), t[k])).ravel()
        assert abs(want[9]) > 0.1                                  # a real roll acceleration
        assert got == pytest.approx(want, rel=1e-12, abs=1e-12), s
    par = next(q for q in model.parameters if q.name == "s_lead")
    assert (par.null, par.lower, par.upper) == (0.0, 0.0, 1.0)


def test_the_accelerometer_reads_the_thrust_at_its_sample_instant_by_hand():
    """An accelerometer sample is the specific force at its instant: with the row holding the
    speeds' mean (``(1 - s) w_k + s w_k+1``), the speeds at the row's start are the ramp's,
    ``w_k + (s - 0.5)(w_k+1 - w_k)`` (w_k itself at s = 0.5). Before, az read the held mean,
    and an independent simulator's 0.8 kg flight with ax, ay, az logged fitted s_lead 0.43 ±
    0.009 where it is 0.517 (0.515 ± 0.001 now, az residual at its noise). A motor lag's state
    is the rotors' speed at the instant already: then nothing changes."""
    base = QuadrotorModel(_airframe())
    t = np.arange(0.0, 0.2, 0.01)
    W = _speeds(t, 400.0)
    log = FlightLog(t, W, ["w1", "w2", "w3", "w4"], np.full((t.size, 6), np.nan), OUT[:6])
    k = 7
    i_az = base.output_names.index("az")
    for hold in ("mean", "linear"):
        model = base + effects.SampledInputs(hold=hold)
        prep = model.prepare_log(log)
        x0 = model.initial_state()
        for s in (0.0, 0.5, 0.8):
            p = model.default_parameters()
            p[model.param_names.index("s_lead")] = s
            got = np.asarray(model.output(x0, prep.inputs[k], p, t[k])).ravel()
            w = W[k] + (s - 0.5) * (W[k + 1] - W[k])
            want = np.asarray(base.output(base.initial_state(), w, base.default_parameters(), t[k])).ravel()
            kt = base.default_parameters()[0]
            assert want[i_az] == pytest.approx(-kt * np.sum(w ** 2) / base.airframe.mass, rel=1e-12)
            assert got == pytest.approx(want, rel=1e-12, abs=1e-12), (hold, s)
    # with a motor lag the sensor reads the lag's state, whatever the blend feeding it
    lagged = base + effects.MotorLag() + effects.SampledInputs()
    prep = lagged.prepare_log(log)
    x0 = lagged.initial_state()
    x0[-4:] = 410.0
    outs = []
    for s in (0.0, 0.8):
        p = lagged.default_parameters()
        p[lagged.param_names.index("s_lead")] = s
        outs.append(np.asarray(lagged.output(x0, prep.inputs[k], p, t[k])).ravel())
    assert outs[0][i_az] == pytest.approx(-base.default_parameters()[0] * 4 * 410.0 ** 2 / base.airframe.mass,
                                          rel=1e-12)
    assert outs[1] == pytest.approx(outs[0], rel=1e-12, abs=1e-12)


def test_the_linear_hold_ramps_across_the_row_by_hand():
    """``hold="linear"``: at the fraction f of row k the model's derivatives are the base
    model's at ``w_k + (f + s - 0.5)(w_k+1 - w_k)``: the first-order hold through the samples at
    ``s = 0.5`` (w_k at the row's start, w_k+1 at its end), shifted by ``s - 0.5`` of the step
    otherwise; its mean over the row is the plain blend's held value. Its options survive
    saving (``options``/``with_options``)."""
    base = QuadrotorModel(_airframe())
    eff = effects.SampledInputs(hold="linear")
    assert eff.with_options(eff.options()).hold == "linear"
    assert effects.SampledInputs().with_options({}).hold == "mean"
    with pytest.raises(GreyboxInputError, match="hold"):
        effects.SampledInputs(hold="cubic")
    model = base + eff
    assert model.input_names[-2:] == ["t@row", "h@row"]
    t = 3.0 + np.cumsum(np.r_[0.0, np.full(19, 0.01)])       # a log that does not start at 0
    W = _speeds(t, 400.0)
    log = FlightLog(t, W, ["w1", "w2", "w3", "w4"], np.full((t.size, 6), np.nan), OUT[:6])
    prep = model.prepare_log(log)
    x0, k, h = base.initial_state(), 7, 0.01
    i_s = model.param_names.index("s_lead")
    for s, f in ((0.5, 0.0), (0.5, 1.0), (0.5, 0.25), (0.2, 0.5), (0.9, 0.75)):
        p = model.default_parameters()
        p[i_s] = s
        got = np.asarray(model.rhs(x0, prep.inputs[k], p, t[k] + f * h)).ravel()
        w = W[k] + (f + s - 0.5) * (W[k + 1] - W[k])
        want = np.asarray(base.rhs(x0, w, base.default_parameters(), t[k] + f * h)).ravel()
        assert abs(want[9]) > 0.1
        assert got == pytest.approx(want, rel=1e-9, abs=1e-9), (s, f)


def test_only_for_rotor_speeds_and_a_default_candidate_there():
    """It blends logged rotor speeds: a model driven by control inputs has none (one clear
    error); the diagnosis considers it whenever the inputs are rotor speeds."""
    af = _airframe()
    model = QuadrotorModel(af, inputs="controls")
    with pytest.raises(GreyboxInputError, match="sampled_inputs"):
        _ = (model + effects.SampledInputs()).input_names
    t = np.arange(0.0, 1.0, 0.01)
    log = FlightLog(t, _speeds(t, 400.0), ["w1", "w2", "w3", "w4"], np.full((t.size, 6), np.nan), OUT[:6])
    assert "sampled_inputs" in default_candidates(QuadrotorModel(af), [log])


def _fine_flight(hold_at_log_rate: bool, seed: int = 3):
    """1.5 s of an open-loop vehicle driven by rotor speeds varying at 3 and 7.3 Hz, integrated
    at 2 kHz and logged at 100 Hz with 1 mm / 2 mrad / 5 mrad/s noise. With
    ``hold_at_log_rate`` the speeds change only at the log's rows (a command the controller
    held), else continuously (sampled by the log, as ESC telemetry is)."""
    af = _airframe()
    model = QuadrotorModel(af)
    p = model.default_parameters()
    w_hover = model.hover_speed(p)
    tf = np.arange(0.0, 1.5, 5e-4)
    every = 20
    Wf = _speeds(np.repeat(tf[::every], every)[:tf.size] if hold_at_log_rate else tf, w_hover)
    sim = simulate(model, tf, Wf, p, x0=np.r_[0, 0, -1.0, np.zeros(9)])
    rows = slice(0, None, every)
    rng = np.random.default_rng(seed)
    Y = sim.outputs[rows][:, :9].copy()
    sig = np.array([1e-3] * 3 + [2e-3] * 3 + [5e-3] * 3)
    Y += sig * rng.standard_normal(Y.shape)
    log = FlightLog(tf[rows], Wf[rows], ["w1", "w2", "w3", "w4"], Y, OUT)
    return model, log


@pytest.mark.parametrize("held", [False, True])
def test_recovered_from_a_log_made_at_a_finer_rate(held):
    """Continuously varying speeds logged at 100 Hz: the fit finds s_lead near 0.5 (a
    signal's mean over an interval is the mean of its ends, to first order; the angle at the
    interval's end weighs its start more, 1/3 for a ramp, so a little less) with the residuals
    at the noise, where without the effect the roll rate is several times the noise off;
    speeds held at the log's rows: s_lead = 0, the hold, residuals at the noise."""
    model, log = _fine_flight(held)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with_it = fit(model + effects.SampledInputs(), log, free=["s_lead"], process_noise=None, interval=5)
        without = fit(model, log, free=["K_T"], process_noise=None, interval=5, reweight=False,
                      noise={"phi": 2e-3, "theta": 2e-3, "p": 5e-3, "q": 5e-3})
    s = with_it.value("s_lead")
    if held:
        assert s < 0.02
        assert without.residual_rms["p"] < 2 * 5e-3
    else:
        assert 0.4 < s < 0.55
        assert with_it.residual_rms["p"] < 1.5 * 5e-3
        assert without.residual_rms["p"] > 3 * 5e-3


def test_diagnosis_keeps_the_hold_for_held_commands():
    """greybox's own flights hold each row's rotor speeds until the next (the contract's
    zero-order hold): the diagnosis's timing check keeps the model as given and says nothing
    about it."""
    from greybox import diagnose
    from greybox.synth import SensorSpec, synthesize
    model = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    flights = [synthesize(model, duration=12.0, seed=s, sensors=SensorSpec(rate=200.0, vision_rate=50.0),
                          manoeuvres=["hover", "step_x", "yaw", "step_y"]) for s in (11, 12)]
    lines: list[str] = []
    d = diagnose(model, flights[0].log, validation=flights[1].log, iterate=False, discover=False,
                 progress=lines.append)
    assert any("held values, or samples" in m for m in lines)           # the check was made
    # judged like a candidate: here its score test already says no, and nothing is refitted
    assert any(m.strip().startswith("screen sampled_inputs") for m in lines), lines
    assert d.model.effect_names == model.effect_names
    assert not any("samples of a signal" in w for w in d.warnings)
    assert d.input_timing is None and d.as_json()["input_timing"] is None
    assert "sampled_inputs" not in [c.effect for c in d.ranking]


@pytest.mark.slow
def test_a_lag_fitted_to_rows_that_sample_a_varying_command_is_said(tmp_path, capsys):
    """A 30-ms motor lag behind commands that vary between the 100-Hz rows (flown at 1 kHz,
    every tenth row kept): ``greybox fit --effects motor_lag`` took tau_m 27.7 ± 0.25 ms
    (9 std off) without a word (a blind audit's 40-ms motors: 71 std); the score test of the
    log's timing at the fit's optimum says so. The same lag behind held rows: nothing said."""
    import sys
    from greybox.cli import main
    from greybox.data import save_log
    from greybox.diagnosis.screening import row_timing_words
    from greybox.synth import SensorSpec, synthesize
    sys.path.insert(0, str(AIRFRAMES.parents[2] / "experiments"))
    from diagnose_effects import MANOEUVRES, model_with_hidden_effects
    base = QuadrotorModel(load_airframe(AIRFRAMES / "paper.toml"))
    truth, p = model_with_hidden_effects(base, ["motor_lag"], None)
    fine = synthesize(truth, p, duration=20.0, seed=3, sensors=SensorSpec(rate=1000.0, vision_rate=50.0),
                      manoeuvres=MANOEUVRES).log
    k = np.arange(0, len(fine), 10)
    rows = FlightLog(fine.t[k], fine.inputs[k], list(fine.input_names), fine.outputs[k], list(fine.output_names))
    save_log(rows, tmp_path / "rows.csv")
    assert main(["fit", str(tmp_path / "rows.csv"), "--airframe", str(AIRFRAMES / "paper.toml"),
                 "--effects", "motor_lag", "--quiet"]) == 0
    said = [ln for ln in capsys.readouterr().out.splitlines() if "samples of a signal" in ln]
    assert len(said) == 1 and "tau_m" in said[0] and "--effects sampled_inputs" in said[0], said
    held = synthesize(truth, p, duration=20.0, seed=3, sensors=SensorSpec(rate=100.0, vision_rate=50.0),
                      manoeuvres=MANOEUVRES).log
    res = fit(base + effects.by_name("motor_lag"), held)
    assert res.value("tau_m") == pytest.approx(0.03, rel=0.01)
    assert row_timing_words(res, [held]) == []
    # the base model, which misses the lag, on held rows: its certificate finds something
    # missing, and the rows' timing is not blamed for it
    base_held = fit(base, held)
    assert not base_held.certificate.adequate and row_timing_words(base_held, [held]) == []


def test_a_base_fit_whose_misfit_may_be_the_rows_timing_says_so():
    """Nothing missing, rotor speeds varying between the 100-Hz rows (:func:`_fine_flight`):
    the certificate of the base model's fit finds the rates off, and the words say that may be
    the rows' timing (an audit's control flights: "a force or torque the model lacks", nothing
    missing); speeds held at the rows: nothing said."""
    from greybox.diagnosis.screening import row_timing_words
    for held in (False, True):
        model, log = _fine_flight(held)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = fit(model, log, free=["K_T"], process_noise=None, interval=5,
                      noise={"phi": 2e-3, "theta": 2e-3, "p": 5e-3, "q": 5e-3})
        said = row_timing_words(res, [log])
        if held:
            assert said == [], said
        else:
            assert not res.certificate.adequate and len(said) == 1 and "may be this timing" in said[0], said
        # a script gets what `greybox fit` adds with fit_warnings (a blind audit's plain
        # fit(...).summary() said nothing of the rows' timing)
        from greybox.diagnosis import fit_warnings
        assert [w for w in fit_warnings(res, log) if "may be this timing" in w] == said


def test_noise_on_held_speeds_is_not_taken_for_the_rows_timing():
    """White noise on logged speeds is averaged by any blend of neighbouring rows, so the score
    test of ``sampled_inputs`` (a blend with the next row) grows with it on commands held
    exactly (a blind audit's hexacopter, 3 rad/s of telemetry noise: 975, said as "samples of
    a varying signal"). Along the speeds' central difference the noise's share cancels on
    average, and with the statistic's scale taken from the data (``robust_screen``: the noise
    is a random forcing the weights do not hold) held speeds score like nothing: here 0.1-1.3
    (at 5 rad/s the plain central statistic is 21, the next row's 357), nothing said; speeds
    that vary between rows: 44 with 2 rad/s of noise, said."""
    import dataclasses
    from greybox.diagnosis.screening import TIMING_ALPHA, fit_weights, robust_screen, row_timing_words, screen
    from scipy import stats
    model, log = _fine_flight(True)
    for sd in (2.0, 5.0):
        noisy = dataclasses.replace(log, inputs=log.inputs + sd * np.random.default_rng(7).standard_normal(log.inputs.shape))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = fit(model, noisy, free=["K_T"], interval=5, noise={"phi": 2e-3, "theta": 2e-3, "p": 5e-3, "q": 5e-3})
        ahead, _ = screen(model, res, [noisy], "sampled_inputs", fit_weights(res), "cached")
        central = robust_screen(model, res, [effects.SampledInputs.toward_central_difference(noisy)],
                                "sampled_inputs", fit_weights(res), "cached")
        # the next row alone is significant: the noise; the central difference is not
        assert stats.chi2.sf(ahead, 1) < TIMING_ALPHA and stats.chi2.sf(central, 1) > 0.1, (sd, ahead, central)
        assert row_timing_words(res, [noisy]) == [], sd
    model, log = _fine_flight(False)
    noisy = dataclasses.replace(log, inputs=log.inputs + 2.0 * np.random.default_rng(7).standard_normal(log.inputs.shape))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fit(model, noisy, free=["K_T"], interval=5, noise={"phi": 2e-3, "theta": 2e-3, "p": 5e-3, "q": 5e-3})
    plain = row_timing_words(res, [noisy])
    assert len(plain) == 1 and "may be part of it" not in plain[0], plain
    import re
    central = float(re.search(r"scaled by the data: ([0-9.e+-]+)", plain[0]).group(1))
    assert stats.chi2.sf(central, 1) < 1e-3, plain


def test_the_central_difference_leads_by_half_of_both_neighbours_by_hand():
    """``toward_central_difference`` sets the next-row speeds to ``w_k + (w_(k+1) - w_(k-1))/2``
    (each end its own neighbour): on a parabola the lead is the slope, exactly."""
    t = np.arange(0.0, 0.06, 0.01)
    w = 400.0 + 1e4 * t ** 2
    log = FlightLog(t, np.column_stack([w] * 4), ["w1", "w2", "w3", "w4"], np.full((t.size, 9), np.nan), OUT)
    nxt = effects.SampledInputs.toward_central_difference(log).extras["w2@next"]
    assert np.allclose(nxt[1:-1], w[1:-1] + 0.5 * (w[2:] - w[:-2]))
    assert np.allclose(nxt[1:-1] - w[1:-1], 2e4 * t[1:-1] * 0.01)     # dw/dt times one row
    assert nxt[0] == pytest.approx(w[0] + 0.5 * (w[1] - w[0])) and nxt[-1] == pytest.approx(w[-1] + 0.5 * (w[-1] - w[-2]))


def test_toward_previous_row_blends_with_the_row_before():
    """The mirror blend's next-row speeds are the previous row's (the first row its own), and
    the model keeps them: at s_lead = 0.5 the held value is the mean of the row and the one
    before (checked by hand on a ramp)."""
    t = np.arange(0.0, 0.1, 0.01)
    W = np.column_stack([400.0 + 10.0 * np.arange(t.size)] * 4)
    log = FlightLog(t, W, ["w1", "w2", "w3", "w4"], np.full((t.size, 6), np.nan), OUT[:6])
    back = effects.SampledInputs.toward_previous_row(log)
    assert back.extras["w1@next"][:3].tolist() == [400.0, 400.0, 410.0]
    model = QuadrotorModel(_airframe()) + effects.SampledInputs()
    prep = model.prepare_log(back)
    assert prep.inputs[3, model.input_names.index("w2@next")] == 420.0

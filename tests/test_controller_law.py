"""The closed-loop model (greybox.controller_law): a controller's law fitted to the logged
commands, and the vehicle model flown by it.

Checked: a known linear law (written with the states' exact derivatives, not the fit's
estimates of them) is recovered with its delay, in the yaw-aligned frame; on the peer
simulator's autopilot cascade (a controller greybox did not write, on measured states) the
fitted law has the signs of a stabilising controller and the closed loop predicts roll and
pitch half a second ahead better than the naive predictor; user mistakes get one clear error.
"""
from __future__ import annotations

import numpy as np
import pytest

from greybox import (ControllerLaw, FlightLog, GreyboxInputError, QuadrotorModel, closed_loop_horizon_errors, effects,
                     save_log)
from greybox.airframe import Airframe, rotors_for_layout
from greybox.controller_law import LAW_AXES, SETPOINTS, has_setpoints, loop_model, measured_law_states
from greybox.fitting import fit

from peer_sim import PeerSensors, PeerVehicle, fly, write_case


ATT_LEVEL = (0.03, -0.02)
"""rad: the cascade flight's attitude estimate reads this roll and pitch when the thrust is vertical."""


def _airframe() -> Airframe:
    return Airframe(name="law", mass=0.03, inertia=np.diag([1.4e-5, 1.4e-5, 2.2e-5]), arm_length=0.046,
                    rotors=rotors_for_layout("x", 0.046))


def _smooth(t, rng, scale, n_tones=3):
    out = np.zeros_like(t)
    dout = np.zeros_like(t)
    for _ in range(n_tones):
        f, ph, a = rng.uniform(0.1, 0.6), rng.uniform(0, 2 * np.pi), scale * rng.uniform(0.3, 1.0)
        out += a * np.sin(2 * np.pi * f * t + ph)
        dout += a * 2 * np.pi * f * np.cos(2 * np.pi * f * t + ph)
    return out, dout


KNOWN_LAW = {"thrust": ([4e6, 3e6], 1.6e7), "roll": ([-6e4, -3e4, -1.5e5, -4e4], 0.0),
             "pitch": ([6e4, 3e4, -1.5e5, -4e4], 0.0), "yaw": ([-1e6, -3e5], 0.0)}


def _known_law_log(delays=(3, 3, 3, 3)):
    """A log whose commands a known law (:data:`KNOWN_LAW`) made from the exact states, each
    axis ``delays`` samples late, and the mask of its vision outage (the first test says how)."""
    rng = np.random.default_rng(4)
    t = np.arange(0, 30, 0.01)
    pos, vel = zip(*[_smooth(t, rng, 0.5) for _ in range(3)])
    ref, vref = zip(*[_smooth(t, rng, 0.5) for _ in range(3)])
    ang, rate = zip(*[_smooth(t, rng, s) for s in (0.05, 0.05, 0.0)])
    psi = np.radians(60) * np.sin(2 * np.pi * 0.05 * t)
    dpsi = np.radians(60) * 2 * np.pi * 0.05 * np.cos(2 * np.pi * 0.05 * t)
    psi_ref = 0.1 * np.sin(2 * np.pi * 0.07 * t)
    # small angles: body rates = Euler-angle rates (the law reads p, q, r as measured)
    p, q, r = rate[0], rate[1], dpsi
    e = np.column_stack(pos) - np.column_stack(ref)
    ev = np.column_stack(vel) - np.column_stack(vref)
    c, s = np.cos(psi), np.sin(psi)
    feats = {"e_z": e[:, 2], "v_z": ev[:, 2], "e_y": -s * e[:, 0] + c * e[:, 1], "v_y": -s * ev[:, 0] + c * ev[:, 1],
             "phi": ang[0], "p": p, "e_x": c * e[:, 0] + s * e[:, 1], "v_x": c * ev[:, 0] + s * ev[:, 1],
             "theta": ang[1], "q": q, "e_psi": psi - psi_ref, "r": r}
    from greybox.controller_law import LAW_FEATURES
    cmd = np.zeros((t.size, 4))
    for i, axis in enumerate(LAW_AXES):
        gains, trim = KNOWN_LAW[axis]
        law_now = trim + sum(g * feats[f] for g, f in zip(gains, LAW_FEATURES[axis]))
        d = delays[i]
        cmd[:, i] = np.concatenate([np.full(d, law_now[0]), law_now[:t.size - d]])
    af = _airframe()
    w2 = np.linalg.solve(af.allocation_matrix(), cmd.T).T
    assert w2.min() > 0
    outputs = np.column_stack([*pos, ang[0], ang[1], psi, p, q, r])
    # a vision outage of 0.3 s: its rows (and the velocities through it) are left out of the
    # fit, not bridged by a straight line, nor do they spoil the rows after it
    lost = (t > 12.0) & (t < 12.3)
    outputs[lost, :3] = np.nan
    extras = {"x_ref": ref[0], "y_ref": ref[1], "z_ref": ref[2], "psi_ref": psi_ref}
    log = FlightLog(t, np.sqrt(w2), ["w1", "w2", "w3", "w4"], outputs,
                    ["x", "y", "z", "phi", "theta", "psi", "p", "q", "r"], extras)
    return log, lost


def test_a_known_linear_law_is_recovered_with_its_delay_in_the_yaw_aligned_frame():
    """Commands made by a known law of the exact states (positions' derivatives taken
    analytically, a heading swinging through +-60 degrees so the yaw-aligned frame matters),
    three samples late, a vision outage in the middle: the fit's gains are the law's within 2 %,
    its delay is 30 ms. A law read in the world frame instead would mix roll with pitch at
    these headings. With the yaw axis seven samples late, the other three none, each axis'
    delay is found by ``axis_delays=True`` (the joint one takes the three axes' and explains yaw
    less)."""
    log, lost = _known_law_log()
    t = log.t
    af = _airframe()
    assert has_setpoints(log)
    law = ControllerLaw().fit(QuadrotorModel(af), log)
    assert law.delay_ == pytest.approx(0.03, abs=1e-9)
    states = measured_law_states(log)
    assert np.isnan(states[lost, 6:9]).all() and np.isfinite(states[t > 12.5]).all()
    for axis in LAW_AXES:
        np.testing.assert_allclose(law.gains_[axis], KNOWN_LAW[axis][0], rtol=0.02, err_msg=axis)
        assert law.r2_[axis] > 0.999, axis
    np.testing.assert_allclose(law.delays_, 0.03, atol=1e-9)
    mixed, _ = _known_law_log(delays=(0, 0, 0, 7))
    law = ControllerLaw(axis_delays=True).fit(QuadrotorModel(af), mixed)
    np.testing.assert_allclose(law.delays_, [0.0, 0.0, 0.0, 0.07], atol=1e-9)
    np.testing.assert_array_equal(law.axis_delay_samples(0.01), [0, 0, 0, 7])
    for axis in LAW_AXES:
        np.testing.assert_allclose(law.gains_[axis], KNOWN_LAW[axis][0], rtol=0.02, err_msg=axis)
    joint = ControllerLaw().fit(QuadrotorModel(af), mixed)
    assert joint.delay_ == 0.0 and np.ptp(joint.delays_) == 0 and joint.r2_["yaw"] < law.r2_["yaw"]
    # only the named axes get their own: yaw's 70 ms, the rest the joint 0 with the joint's gains
    yaw_own = ControllerLaw(axis_delays=("yaw",)).fit(QuadrotorModel(af), mixed)
    np.testing.assert_allclose(yaw_own.delays_, [0.0, 0.0, 0.0, 0.07], atol=1e-9)
    assert yaw_own.r2_["yaw"] == pytest.approx(law.r2_["yaw"]) and yaw_own.delay_ == 0.0
    for axis in ("thrust", "roll", "pitch"):
        np.testing.assert_array_equal(yaw_own.gains_[axis], joint.gains_[axis])
    thrust_own = ControllerLaw(axis_delays=("thrust",)).fit(QuadrotorModel(af), mixed)
    np.testing.assert_allclose(thrust_own.delays_, 0.0, atol=1e-9)       # thrust's own is the joint's here
    with pytest.raises(GreyboxInputError, match="'throttle': not an axis of the law"):
        ControllerLaw(axis_delays=("throttle",)).fit(QuadrotorModel(af), mixed)


def test_each_axis_of_the_loop_acts_on_the_command_its_delay_says():
    """By hand, one step of :meth:`ControllerLaw.closed_loop_step` with the thrust two samples
    late, pitch one, roll and yaw none, every gain nil (the law's command is its trim): the
    rotors turn at the speeds of (thrust of the oldest command on its way, roll of the trim,
    pitch of the newer command on its way, yaw of the trim), and the buffer moves on by one."""
    from greybox.integrate import rk4_step
    log, _ = _known_law_log()
    af = _airframe()
    model = QuadrotorModel(af)
    law = ControllerLaw().fit(model, log)
    law.gains_ = {a: np.zeros_like(g) for a, g in law.gains_.items()}
    A = af.allocation_matrix()
    hover = A @ np.full(4, 2500.0 ** 2)
    oldest, newer, trim = hover * [1.02, 1, 1, 1], hover + [0, 40, -30, 2e5], hover + [0, -20, 10, -1e5]
    step = law.closed_loop_step(model, 1, [2, 0, 1, 0])
    x = model.initial_state()
    p = model.default_parameters()
    xb_next, _ = step(np.concatenate([x, oldest, newer]), np.zeros(7), trim, np.zeros(0), p, 0.0, 0.01,
                      np.zeros(2))
    acting = np.array([oldest[0], trim[1], newer[2], trim[3]])
    w = np.sqrt(np.linalg.pinv(A) @ acting)
    expected = np.asarray(rk4_step(model, 1)(x, w, p, 0.0, 0.01)).ravel()
    xb_next = np.asarray(xb_next).ravel()
    np.testing.assert_allclose(xb_next[:model.nx], expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(xb_next[model.nx:], np.concatenate([newer, trim]))


@pytest.fixture(scope="module")
def cascade_flight(tmp_path_factory):
    """A 30 g vehicle flown by the peer simulator's autopilot cascade (on its noisy gyro, a
    wandering position estimate and an attitude estimate whose level is off by (30, -20) mrad,
    which the log reports as the controller reads it), 24 s logged at 250 Hz with its
    setpoints."""
    from greybox import load_airframe, load_log
    veh = PeerVehicle.crazyflie(log_rate=250.0)
    fl = fly(veh, duration=24.0, seed=5, controller="cascaded_pid",
             sensors=PeerSensors(log_setpoints=True, att_bias=ATT_LEVEL))
    paths = write_case(fl, tmp_path_factory.mktemp("law"))
    return QuadrotorModel(load_airframe(paths["airframe"])), load_log(paths["log"]), paths


@pytest.mark.slow
def test_the_cascade_of_an_autopilot_is_read_as_a_stabilising_law_that_predicts_attitude(cascade_flight):
    """On a controller greybox did not write: the law restores (roll torque against roll and
    against an error to the right, pitch likewise, more thrust when below the setpoint: NED
    z - z_ref > 0, yaw torque against a yaw error), its level is the attitude estimate's
    (measured once: 30.3, -19.4 mrad for 30, -20), and the model flown by it predicts roll and
    pitch 0.5 s ahead better than constant rates do (measured once: 0.075 and 0.104 rad against
    0.23 and 0.14, the law's delay 64 ms: the cascade's filters and the motors' lag on the
    logged speeds). Without the level the loop's model hovers tilted by it and drifts: x and y
    0.5 s ahead 39 and 40 mm against 27 and 26 with it (pitch 0.091 rad against 0.104: not
    asserted)."""
    model, log, _ = cascade_flight
    assert set(SETPOINTS) <= set(log.extras)
    est, val = log.split(0.75)
    res = fit(model, est)
    law = ControllerLaw().fit(model, est)
    g = law.gains_
    # the rate gains are small beside the angle gains here and change sign with the delay
    # (D on a filtered noisy gyro): not asserted
    assert g["roll"][0] < 0 and g["roll"][2] < 0           # e_y (right of the target), phi
    assert g["pitch"][0] > 0 and g["pitch"][2] < 0         # e_x (ahead: pitch up), theta
    assert g["thrust"][0] > 0                              # e_z: below the setpoint -> more thrust
    assert g["yaw"][0] < 0                                 # psi - psi_ref
    np.testing.assert_allclose(law.level_, ATT_LEVEL, atol=0.003)
    he = closed_loop_horizon_errors(model, res.p, law, val)
    assert he.predictor["closed_loop"] and he.windows > 20
    for ch in ("phi", "theta"):
        assert he.beats_naive(ch, 0.5), (ch, he.model[ch], he.naive[ch])
        # one sample ahead the loop is where the measurements put it: the level taken off the
        # start is put back on the prediction (without that, 20-30 mrad off)
        assert he.horizons[0] < 0.01 and he.model[ch][0] < 1.5 * he.naive[ch][0], (ch, he.model[ch][0])
    unlevelled = closed_loop_horizon_errors(model, res.p, ControllerLaw(fit_level=False).fit(model, est), val,
                                            horizons=(0.5,))
    i, j = he.horizons.index(0.5), unlevelled.horizons.index(0.5)
    for ch in ("x", "y"):
        assert he.model[ch][i] < 0.8 * unlevelled.model[ch][j], (ch, he.model[ch][i], unlevelled.model[ch][j])


def _level_log(speed_peak: float, course: float, heading: float, off, rng) -> FlightLog:
    """20 s flown along ``course`` from rest up to ``speed_peak`` and back to rest (a raised
    cosine) against a drag of 0.4/s, the body turned to ``heading``, the thrust along what the
    acceleration and the drag need, the estimate's frame the true one turned by
    ``Ry(off[1]) Rx(off[0])``; 1 mm of noise on the positions."""
    from greybox.rotations import rotation_matrices
    t = np.arange(0, 20, 0.01)
    g, k_drag = 9.81, 0.4
    speed = 0.5 * speed_peak * (1 - np.cos(2 * np.pi * t / 20))
    dist = 0.5 * speed_peak * (t - 20 / (2 * np.pi) * np.sin(2 * np.pi * t / 20))
    acc = 0.5 * speed_peak * 2 * np.pi / 20 * np.sin(2 * np.pi * t / 20)
    along = np.array([np.cos(course), np.sin(course), 0.0])
    thrust = (acc + k_drag * speed)[:, None] * along - np.array([0.0, 0.0, g])   # per mass, NED
    b3 = -thrust / np.linalg.norm(thrust, axis=1, keepdims=True)                 # body z (down)
    c, s = np.cos(heading), np.sin(heading)
    yawed = np.column_stack([c * b3[:, 0] + s * b3[:, 1], -s * b3[:, 0] + c * b3[:, 1], b3[:, 2]])
    phi, theta = -np.arcsin(yawed[:, 1]), np.arctan2(yawed[:, 0], yawed[:, 2])
    n = t.size
    turn = rotation_matrices(np.array([off[0]]), np.array([off[1]]), np.zeros(1))[0]
    R = rotation_matrices(phi, theta, np.full(n, heading)) @ turn
    est = np.column_stack([np.arctan2(R[:, 2, 1], R[:, 2, 2]), -np.arcsin(R[:, 2, 0]),
                           np.arctan2(R[:, 1, 0], R[:, 0, 0])])
    pos = dist[:, None] * along + np.array([0.0, 0.0, -1.0]) + 1e-3 * rng.standard_normal((n, 3))
    outputs = np.column_stack([pos, est, np.zeros((n, 3))])
    return FlightLog(t, np.full((n, 4), 2000.0), ["w1", "w2", "w3", "w4"], outputs,
                     ["x", "y", "z", "phi", "theta", "psi", "p", "q", "r"], source="level.csv")


def test_the_level_of_a_known_attitude_offset_is_read_from_the_positions():
    """By hand: a vehicle whose thrust is where its acceleration and drag need it while its
    estimate's frame is turned by Ry(-0.01) Rx(0.02) has the level (0.02, -0.01): hovering
    (positions still but for 1 mm of noise), and flown at up to 1 m/s and back against a drag
    (the thrust tilted by up to 0.05 rad for it) with the body on a heading of 115 degrees,
    along it and crabbing 50 degrees off it (the drag tilts both body axes): the level is the
    offset, not the drag's tilt. (A heading read wrong would hardly show: a turn about the
    vertical leaves the flight's mean specific force where it was.) A log without positions
    gets one error."""
    rng = np.random.default_rng(3)
    off = np.array([0.02, -0.01])
    for peak, course in ((0.0, 2.0), (1.0, 2.0), (1.0, 2.9)):
        log = _level_log(peak, course, 2.0, off, rng)
        np.testing.assert_allclose(ControllerLaw.measured_level(log), off, atol=1e-3, err_msg=f"{peak} {course}")
    blind = FlightLog(log.t, log.inputs, log.input_names, log.outputs[:, 3:], log.output_names[3:], source="blind.csv")
    with pytest.raises(GreyboxInputError, match="level needs 100 airborne samples"):
        ControllerLaw.measured_level([blind])


def test_a_closed_loop_model_asks_for_setpoints_and_a_fitted_law_and_flies_a_command_delay_as_its_own(cascade_flight):
    """User mistakes get one error naming the problem. Effects that say how the *logged*
    commands reach the rotors are left out of the loop, which computes its own: sampled inputs
    (even ramped across the row, which no parameter value switches off) change nothing, the
    predictions are those of the model without them; a command delay (28 ms) makes the rotors
    act on the loop's commands that much later (7 of the log's 4-ms samples). The parameters
    passed in are not changed."""
    model, log, _ = cascade_flight
    bare = FlightLog(log.t, log.inputs, log.input_names, log.outputs, log.output_names,
                     {k: v for k, v in log.extras.items() if k != "psi_ref"}, source="bare.csv")
    with pytest.raises(GreyboxInputError, match=r"bare\.csv.*psi_ref"):
        ControllerLaw().fit(model, bare)
    with pytest.raises(GreyboxInputError, match="not fitted"):
        closed_loop_horizon_errors(model, model.default_parameters(), ControllerLaw(), log)
    with pytest.raises(GreyboxInputError, match="max_delay"):
        ControllerLaw(max_delay=-0.01).fit(model, log)
    law = ControllerLaw(delay=0.0).fit(model, log)
    assert law.delay_ == 0.0
    val = log.split(0.85)[1]
    p0 = model.default_parameters()
    plain = closed_loop_horizon_errors(model, p0, law, val, horizons=(0.25,))
    sampled = model + effects.SampledInputs(hold="linear")
    ps = sampled.parameter_vector({"s_lead": 0.3})
    he = closed_loop_horizon_errors(sampled, ps, law, val, horizons=(0.25,))
    assert he.predictor["left_out"] == ["sampled_inputs"] and he.predictor["loop_delay_samples"] == [0]
    for ch in plain.model:
        np.testing.assert_allclose(he.model[ch], plain.model[ch], rtol=1e-9, err_msg=ch)
    delayed = model + effects.CommandDelay()
    p = delayed.parameter_vector({"tau_cmd": 0.028})
    p_before = p.copy()
    he = closed_loop_horizon_errors(delayed, p, law, val, horizons=(0.25,))
    assert he.predictor["left_out"] == ["command_delay"] and he.predictor["loop_delay_samples"] == [7]
    assert np.array_equal(p, p_before)
    flown, p_flown, extra, left_out = loop_model(delayed, p)
    assert flown.effect_names == model.effect_names and np.array_equal(p_flown, p0)
    assert extra == pytest.approx(0.028) and left_out == ["command_delay"]


@pytest.mark.slow
def test_fit_json_holds_the_closed_loop_where_the_log_has_setpoints(cascade_flight, tmp_path, capsys):
    """``greybox fit`` on a log with setpoints: the JSON's ``closed_loop`` holds the law and the
    horizons in the contract's shape; the summary says what the loop beats the naive predictor
    on; a log without them gets ``null``."""
    import json
    from greybox.cli import main
    _, log, paths = cascade_flight
    out = tmp_path / "fit.json"
    assert main(["fit", str(paths["log"]), "--airframe", str(paths["airframe"]), "--json", str(out),
                 "--plots", str(tmp_path / "plots")]) == 0
    assert (tmp_path / "plots" / "horizons.png").stat().st_size > 1000
    said = capsys.readouterr().out
    assert "flown by its controller's law" in said
    cl = json.loads(out.read_text())["closed_loop"]
    assert 0.25 in cl["horizons"]["horizons"] and 0.5 in cl["horizons"]["horizons"]
    assert set(cl["horizons"]["model"]) == set(cl["horizons"]["naive"]) >= {"x", "phi", "p"}
    assert cl["law"]["gains"]["roll"]["phi"] < 0 and set(cl["law"]["r2"]) == set(LAW_AXES)
    np.testing.assert_allclose(cl["law"]["level"], ATT_LEVEL, atol=0.003)
    assert set(cl["law"]["delays"].values()) == {cl["law"]["delay"]}          # one delay by default
    i = cl["horizons"]["horizons"].index(0.5)
    assert cl["horizons"]["model"]["phi"][i] < cl["horizons"]["naive"]["phi"][i]
    # the true rotor speeds are logged: open loop the model predicts the estimation flight's
    # last seconds far better than flown by a law it only approximates, and that stays the
    # reported prediction (the contract's horizons), the closed loop beside it
    doc = json.loads(out.read_text())
    errs = cl["estimation_errors"]
    assert cl["preferred"] is False and errs["open_loop"] < 0.5 * errs["closed_loop"], errs
    assert doc["horizons"] == doc["horizons_open_loop"] != cl["horizons"]
    assert "closed_loop" not in doc["horizons_predictor"]
    plain = tmp_path / "plain.csv"
    save_log(FlightLog(log.t, log.inputs, log.input_names, log.outputs, log.output_names,
                       {k: v for k, v in log.extras.items() if k not in SETPOINTS}), plain)
    out2 = tmp_path / "plain.json"
    assert main(["fit", str(plain), "--airframe", str(paths["airframe"]), "--json", str(out2)]) == 0
    assert json.loads(out2.read_text())["closed_loop"] is None


@pytest.mark.slow
def test_the_diagnosis_flies_its_final_model_with_the_law_where_the_log_has_setpoints(cascade_flight):
    """``diagnose`` on a log with setpoints: its JSON's ``closed_loop`` is the final model
    flown by the law fitted to the estimation part, its summary says what that beats, and the
    loop beats the naive predictor on roll and pitch half a second ahead."""
    from greybox.diagnosis import diagnose
    model, log, _ = cascade_flight
    diag = diagnose(model, log, candidates=["motor_lag"], iterate=False, discover=False, progress=False)
    cl = diag.as_json()["closed_loop"]
    assert cl is not None and cl["predictor"]["closed_loop"] is True
    assert "flown by its controller's law" in diag.summary()
    he = diag.closed_loop.horizons
    assert he.beats_naive("phi", 0.5) and he.beats_naive("theta", 0.5)

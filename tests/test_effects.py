"""Every effect: one case whose effect on the motion or measurement is known analytically,
plus composition rules."""
import numpy as np
import pytest

from greybox import QuadrotorModel, effects, simulate
from greybox.airframe import airframe_from_dict
from greybox.errors import GreyboxInputError

from conftest import make_airframe

G = 9.81


def hover_state(z=-1.0):
    x = np.zeros(12)
    x[2] = z
    return x


def rhs(model, x, u, p, t=0.0):
    return np.asarray(model.rhs(x, u, p, t)).ravel()


def out(model, x, u, p, t=0.0):
    return dict(zip(model.output_names, np.asarray(model.output(x, u, p, t)).ravel()))


@pytest.fixture
def base(plus_airframe):
    return QuadrotorModel(plus_airframe)


def test_catalogue_is_the_contracts():
    assert set(effects.CATALOGUE) >= {
        "yaw_torque", "linear_drag", "gyroscopic", "quadratic_drag", "rotor_drag", "ground_effect",
        "motor_lag", "cog_offset", "motor_asymmetry", "wind", "thrust_drift", "position_delay",
        "attitude_bias", "position_offset"}
    for name, cls in effects.CATALOGUE.items():
        e = cls()
        assert e.name == name and cls.__doc__ and cls.summary


def test_every_effect_vanishes_at_its_null_values(base):
    """At every parameter's null value the extended model equals the base model."""
    x = hover_state()
    x[6:12] = [0.5, -0.3, 0.2, 0.1, -0.2, 0.3]
    x[3:6] = [0.05, -0.04, 0.3]
    u = base.hover_speed() * np.array([1.02, 0.97, 1.01, 0.99])
    ref_xd = rhs(base, x, u, base.default_parameters())
    ref_y = np.asarray(base.output(x, u, base.default_parameters(), 1.0)).ravel()
    for name in effects.CATALOGUE:
        if name in base.effects or name == "motor_lag":
            continue
        m = base + effects.by_name(name)
        p = m.default_parameters()
        for par in m.parameters:
            if par.effect == name:
                p = m.parameter_vector({par.name: par.null}, p)
        np.testing.assert_allclose(rhs(m, x, u, p, 1.0)[:12], ref_xd, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(np.asarray(m.output(x, u, p, 1.0)).ravel(), ref_y, atol=1e-12, err_msg=name)


def test_gyroscopic_torque_contract_signs(plus_airframe):
    m = QuadrotorModel(plus_airframe)
    jr = 3e-5
    p = m.parameter_vector({"J_r": jr})
    w = m.hover_speed()
    u = np.array([w, w + 30, w, w + 30])  # Omega_r = sum(spin_i w_i) = +60
    x = hover_state()
    x[9:12] = [0.0, 1.0, 0.0]                      # pure q: roll torque +J_r*q*Omega_r
    xd = rhs(m, x, u, p) - rhs(m, x, u, m.parameter_vector({"J_r": 0.0}))
    assert xd[9] == pytest.approx(jr * 1.0 * 60 / 0.0082, rel=1e-12)
    x[9:12] = [1.0, 0.0, 0.0]                      # pure p: pitch torque -J_r*p*Omega_r
    xd = rhs(m, x, u, p) - rhs(m, x, u, m.parameter_vector({"J_r": 0.0}))
    assert xd[10] == pytest.approx(-jr * 1.0 * 60 / 0.0082, rel=1e-12)


def test_quadratic_drag_velocity_decay(plus_airframe):
    m = QuadrotorModel(plus_airframe).without("linear_drag") + effects.QuadraticDrag()
    kq = 0.05
    p = m.parameter_vector({"Kq": [kq, kq, kq]})
    x0 = hover_state()
    x0[6] = 4.0
    t = np.linspace(0, 2, 201)
    sim = simulate(m, t, np.full((t.size, 4), m.hover_speed()), p, x0)
    # m dv/dt = -kq v^2  =>  v = v0 / (1 + kq v0 t / m)
    np.testing.assert_allclose(sim.state("vx"), 4.0 / (1 + kq * 4.0 * t / 1.0), rtol=1e-8)


def test_rotor_drag_opposes_body_velocity_and_scales_with_rotor_speed(base):
    m = base.without("linear_drag") + effects.RotorDrag()
    k = 1e-4
    p = m.parameter_vector({"k_rd": k})
    w = m.hover_speed()
    x = hover_state()
    x[5] = np.pi / 2          # facing east, flying north: a sideways body velocity
    x[6] = 2.0
    xd = rhs(m, x, [w] * 4, p)
    assert xd[6] == pytest.approx(-k * 4 * w * 2.0 / 1.0, rel=1e-9)
    assert abs(xd[7]) < 1e-12 and abs(xd[8]) < 1e-9
    xd2 = rhs(m, x, [2 * w] * 4, p)       # twice the rotor speed, twice the drag
    assert xd2[6] == pytest.approx(2 * xd[6], rel=1e-9)
    x[6], x[8] = 0.0, 2.0                 # vertical velocity: no rotor drag
    assert rhs(m, x, [w] * 4, p)[8] == pytest.approx(0.0, abs=1e-9)


def test_ground_effect_cheeseman_bennett(base):
    m = base + effects.GroundEffect()
    k = 0.02 ** 2
    p = m.parameter_vector({"k_ge": k})
    w = m.hover_speed()
    for h in [0.1, 0.2, 0.5, 2.0]:
        xd = rhs(m, hover_state(-h), [w] * 4, p)
        assert xd[8] == pytest.approx(G * (1 - 1 / (1 - k / h ** 2)), rel=1e-9)
    # the ground plane comes from the airframe
    m2 = QuadrotorModel(make_airframe("plus", ground_z=0.5)) + effects.GroundEffect()
    xd = rhs(m2, hover_state(0.5 - 0.2), [w] * 4, m2.parameter_vector({"k_ge": k}))
    assert xd[8] == pytest.approx(G * (1 - 1 / (1 - k / 0.04)), rel=1e-9)


def test_ground_effect_reads_k_ge_against_the_rotor_heights_the_airframe_gives():
    """Hubs dz above the CoG, a level vehicle with its CoG h above the ground: rotors at h + dz
    with k give the thrust that rotors placed in the CoG's plane give with k (h / (h + dz))^2,
    the factor the fit's note names. The note only where the airframe's rotors have z = 0."""
    l, dz, h, k = 0.17, 0.03, 0.115, 0.03 ** 2
    raised = [{"position": p, "spin": s} for p, s in
              (([l, 0, -dz], 1), ([0, l, -dz], -1), ([-l, 0, -dz], 1), ([0, -l, -dz], -1))]
    a_raised = airframe_from_dict({"airframe": {"mass": 1.0, "inertia": [0.0082, 0.0082, 0.0149], "arm_length": l},
                                   "rotor": raised, "parameters": {"K_T": 2e-5, "b": 5e-7}})
    m_raised = QuadrotorModel(a_raised) + effects.GroundEffect()
    m_plane = QuadrotorModel(make_airframe("plus", arm_length=l)) + effects.GroundEffect()
    w = m_plane.hover_speed()
    acc_raised = rhs(m_raised, hover_state(-h), [w] * 4, m_raised.parameter_vector({"k_ge": k}))[8]
    k_plane = k * (h / (h + dz)) ** 2
    acc_plane = rhs(m_plane, hover_state(-h), [w] * 4, m_plane.parameter_vector({"k_ge": k_plane}))[8]
    assert acc_plane == pytest.approx(acc_raised, rel=1e-12) and acc_raised < -0.05
    ge = effects.GroundEffect()
    note = ge.interpretation_notes({"k_ge": k_plane}, {"k_ge": 1e-5}, m_plane.airframe)
    assert len(note) == 1 and "rotor z = 0" in note[0] and "((h + dz)/h)^2" in note[0]
    assert ge.interpretation_notes({"k_ge": k}, {"k_ge": 1e-5}, a_raised) == []
    assert ge.interpretation_notes({"k_ge": k_plane}, {}, m_plane.airframe) == []     # k_ge fixed: nothing to read
    # a note is not a plausibility warning: the diagnosis never refuses a candidate for it
    assert ge.plausibility_warnings({"k_ge": k_plane}, {"k_ge": 1e-5}, m_plane.airframe) == []


def test_ground_effect_rights_a_vehicle_tilted_near_the_ground(base):
    """Per rotor: pitched nose up by theta at height h, the front rotor (plus layout, x = l)
    is at h + l sin(theta), the rear at h - l sin(theta); the rear gains more thrust, a
    nose-down moment l K_T w^2 (f(h_front) - f(h_rear)), f(h) = 1 / (1 - k/h^2). Rolled right
    (phi > 0), the left rotor (y = -l) is the higher one, and the moment rolls left."""
    m = base + effects.GroundEffect()
    k, h, l = 0.025 ** 2, 0.15, 0.17
    p = m.parameter_vector({"k_ge": k})
    w = m.hover_speed()
    K_T = float(p[m.param_names.index("K_T")])
    f = lambda hh: 1.0 / (1.0 - k / hh ** 2)  # noqa: E731
    J = 0.0082
    for angle in (0.05, 0.2):
        x = hover_state(-h)
        x[4] = angle                                         # nose up
        qd = rhs(m, x, [w] * 4, p)[10]
        want = l * K_T * w ** 2 * (f(h + l * np.sin(angle)) - f(h - l * np.sin(angle))) / J
        assert want < 0 and qd == pytest.approx(want, rel=1e-9)
        x = hover_state(-h)
        x[3] = angle                                         # right side down
        pd = rhs(m, x, [w] * 4, p)[9]
        # rotor 2 at y = +l is now lower (h - l sin(phi)), rotor 4 at y = -l higher; torque -y T
        want = -l * K_T * w ** 2 * (f(h - l * np.sin(angle)) - f(h + l * np.sin(angle))) / J
        assert want < 0 and pd == pytest.approx(want, rel=1e-9)
    # 5 m up the rotors' heights hardly differ: a moment 1/(33^3) as large (k l sin / h^3)
    x = hover_state(-5.0)
    x[4] = 0.2
    x_low = hover_state(-h)
    x_low[4] = 0.2
    assert abs(rhs(m, x, [w] * 4, p)[10]) < 1e-4 * abs(rhs(m, x_low, [w] * 4, p)[10])


def test_motor_lag_first_order_step(base):
    m = base + effects.MotorLag()
    tau = 0.04
    p = m.parameter_vector({"tau_m": tau})
    assert m.state_names[12:] == ["w_eff1", "w_eff2", "w_eff3", "w_eff4"]
    w0 = m.hover_speed()
    t = np.linspace(0, 0.2, 201)
    U = np.full((t.size, 4), w0)
    U[1:] *= 1.1                           # step at t = 0+ (input k acts on [t_k, t_k+1))
    x0 = m.initial_state(hover_state(), U[0], p)
    U[0] *= 1.1
    sim = simulate(m, t, U, p, x0)
    expect = 1.1 * w0 + (w0 - 1.1 * w0) * np.exp(-t / tau)
    np.testing.assert_allclose(sim.state("w_eff1"), expect, rtol=1e-8)


def test_drag_moment_pitches_against_the_airflow(base):
    """Drag acting above the centre of gravity: flying forward pitches the nose up (+q),
    flying right rolls left (-p); no vertical or yaw moment, no force."""
    m = base.without("linear_drag") + effects.DragMoment()
    kx, ky = 2e-3, 3e-3
    p = m.parameter_vector({"k_dm": [kx, ky]})
    w = m.hover_speed()
    x = hover_state()
    x[6] = 2.0                                    # heading north, flying north: body forward
    xd = rhs(m, x, [w] * 4, p)
    Jx = Jy = 0.0082                              # conftest airframe
    assert xd[10] == pytest.approx(ky * 2.0 / Jy, rel=1e-9) and xd[10] > 0
    assert abs(xd[9]) < 1e-12 and abs(xd[11]) < 1e-12
    assert np.allclose(xd[6:9], [0.0, 0.0, 0.0], atol=1e-9)
    x[5] = np.pi / 2                              # now facing east: the same velocity is to the left
    xd = rhs(m, x, [w] * 4, p)
    assert xd[9] == pytest.approx(-kx * -2.0 / Jx, rel=1e-9) and xd[9] > 0
    assert abs(xd[10]) < 1e-12


def test_cog_offset_pitches_at_equal_rotor_speeds(base):
    m = base + effects.CogOffset()
    dx, dy = 0.01, -0.02
    p = m.parameter_vector({"r_cog": [dx, dy]})
    w = m.hover_speed()
    xd = rhs(m, hover_state(), [w] * 4, p)
    # torque = sum (r_i - c) x (-T_i e_z), equal T_i = m g / 4: pitch -dx m g, roll +dy m g
    assert xd[10] == pytest.approx(-dx * 1.0 * G / 0.0082, rel=1e-9)
    assert xd[9] == pytest.approx(dy * 1.0 * G / 0.0082, rel=1e-9)
    assert xd[8] == pytest.approx(0.0, abs=1e-12)


def test_motor_asymmetry_keeps_mean_thrust_and_creates_torque(base):
    m = base + effects.MotorAsymmetry()
    d = [-0.1, 0.02, 0.03]
    p = m.parameter_vector({"K_T_dev": d})
    w = m.hover_speed()
    xd = rhs(m, hover_state(), [w] * 4, p)
    T = 2e-5 * w ** 2
    d4 = -sum(d)
    assert xd[8] == pytest.approx(0.0, abs=1e-12)                       # total thrust unchanged
    assert xd[10] == pytest.approx(0.17 * T * (d[0] - d[2]) / 0.0082, rel=1e-9)   # pitch: rotors 1-3
    assert xd[9] == pytest.approx(0.17 * T * (d4 - d[1]) / 0.0082, rel=1e-9)      # roll: rotors 4-2
    b = 5e-7
    assert xd[11] == pytest.approx(b * w ** 2 * (-(1 + d[0]) + (1 + d[1]) - (1 + d[2]) + (1 + d4)) / 0.0149,
                                   rel=1e-9)


def test_wind_pushes_a_hovering_vehicle_downwind(base):
    m = base + effects.Wind()
    p = m.parameter_vector({"wind": [2.0, -1.0]})
    xd = rhs(m, hover_state(), [m.hover_speed()] * 4, p)
    np.testing.assert_allclose(xd[6:8], [0.1 * 2.0, 0.1 * -1.0], rtol=1e-12)
    x = hover_state()
    x[6:8] = [2.0, -1.0]    # moving with the air: no drag
    np.testing.assert_allclose(rhs(m, x, [m.hover_speed()] * 4, p)[6:8], 0, atol=1e-12)


def test_thrust_drift_is_linear_in_time(base):
    m = base + effects.ThrustDrift()
    c = -0.002
    p = m.parameter_vector({"K_T_drift": c})
    w = m.hover_speed()
    for t in [0.0, 10.0, 40.0]:
        assert rhs(m, hover_state(), [w] * 4, p, t)[8] == pytest.approx(-G * c * t, abs=1e-12)


def test_position_delay_reports_the_past_position(base):
    m = base + effects.PositionDelay()
    tau = 0.05
    p = m.parameter_vector({"tau_pos": tau})
    w = m.hover_speed()
    x0 = hover_state()
    x0[6] = 1.0                 # cruising at 1 m/s: p(t - tau) = p(t) - tau*v (+ tiny drag term)
    t = np.linspace(0, 1, 101)
    sim = simulate(m, t, np.full((t.size, 4), w), p, x0)
    true_past = 1.0 / 0.1 * (1 - np.exp(-0.1 * (t - tau)))   # x(t - tau) under linear drag
    np.testing.assert_allclose(sim.output("x"), true_past, atol=1e-6)
    np.testing.assert_allclose(sim.output("z"), -1.0, atol=1e-12)


def test_attitude_bias_offsets_roll_and_pitch_readings(base):
    m = base + effects.AttitudeBias()
    p = m.parameter_vector({"att_bias": [0.02, -0.01]})
    x = hover_state()
    x[3:6] = [0.1, 0.2, 0.3]
    y = out(m, x, [m.hover_speed()] * 4, p)
    assert (y["phi"], y["theta"], y["psi"]) == pytest.approx((0.12, 0.19, 0.3))


def test_position_offset_turns_with_the_body(base):
    """By hand, R = Rz Ry Rx body -> world (NED, FRD): a sensor 10 cm above the CoG
    (r_pos = (0, 0, -0.1)) on a vehicle rolled right by 0.5 rad reports y + 0.1 sin 0.5 (the
    top leans right) and z - 0.1 cos 0.5 (it is above); one 0.2 m ahead on a vehicle yawed by
    90 degrees reports x, y + 0.2 (ahead is east). Nothing else moves: the vehicle's
    derivatives are those of the base model (a measurement-only effect)."""
    m = base + effects.PositionOffset()
    assert effects.measurement_only("position_offset")
    x = hover_state()
    x[3] = 0.5
    y = out(m, x, [m.hover_speed()] * 4, m.parameter_vector({"r_pos": [0.0, 0.0, -0.1]}))
    assert (y["x"], y["y"], y["z"]) == pytest.approx((0.0, 0.1 * np.sin(0.5), -1.0 - 0.1 * np.cos(0.5)), abs=1e-12)
    x = hover_state()
    x[5] = np.pi / 2
    y = out(m, x, [m.hover_speed()] * 4, m.parameter_vector({"r_pos": [0.2, 0.0, 0.0]}))
    assert (y["x"], y["y"], y["z"]) == pytest.approx((0.0, 0.2, -1.0), abs=1e-12)
    assert y["phi"] == 0.0 and y["psi"] == pytest.approx(np.pi / 2)
    p0, p1 = m.parameter_vector({"r_pos": [0.0] * 3}), m.parameter_vector({"r_pos": [0.2, -0.1, 0.3]})
    u = [m.hover_speed()] * 4
    np.testing.assert_allclose(rhs(m, x, u, p1), rhs(m, x, u, p0), atol=1e-12)


def test_composition_add_and_without(base):
    lib = effects.GroundEffect() + effects.Wind()
    assert isinstance(lib, effects.EffectLibrary) and lib.names == ["ground_effect", "wind"]
    assert isinstance(lib.get("wind"), effects.Wind) and lib.get("yaw_torque") is None
    m = base + lib
    assert m.effect_names == ["yaw_torque", "linear_drag", "gyroscopic", "ground_effect", "wind"]
    assert "k_ge" in m.param_names and "wind[1]" in m.param_names
    assert (base + effects.Wind() + effects.GroundEffect()).effect_names == m.effect_names
    m2 = m.without("yaw_torque", "wind")
    assert m2.effect_names == ["linear_drag", "gyroscopic", "ground_effect"]
    assert "b" not in m2.param_names
    assert base.effect_names == ["yaw_torque", "linear_drag", "gyroscopic"]  # unchanged
    with pytest.raises(GreyboxInputError, match="already in the model"):
        m + effects.Wind()
    with pytest.raises(GreyboxInputError, match="cannot remove 'motor_lag'"):
        base.without("motor_lag")
    with pytest.raises(GreyboxInputError, match="unknown effect 'gust'"):
        effects.by_name("gust")


def test_parameters_have_units_bounds_scales(base):
    m = base
    for name in effects.CATALOGUE:
        if name not in m.effects:
            m = m + effects.by_name(name)
    assert len(m.param_names) == m.n_params == m.default_parameters().size
    for par in m.parameters:
        assert par.unit and par.scale > 0 and par.lower < par.upper and par.description
        assert np.all(par.lower <= par.default_vector()) and np.all(par.default_vector() <= par.upper)


def test_parameter_vector_by_name_and_component(base):
    p = base.parameter_vector({"K_T": 2.4e-5, "Kd": [0.2, 0.2, 0.3]})
    d = base.parameter_dict(p)
    assert d["K_T"] == 2.4e-5 and d["Kd[2]"] == 0.3
    p = base.parameter_vector({"Kd[1]": 0.5}, p)
    assert base.parameter_dict(p)["Kd[1]"] == 0.5
    with pytest.raises(GreyboxInputError, match="unknown parameter 'k_ge'"):
        base.parameter_vector({"k_ge": 1.0})
    with pytest.raises(GreyboxInputError, match="needs 3 values"):
        base.parameter_vector({"Kd": [1, 2]})


def test_accel_bias_adds_to_the_specific_force_only(base):
    """By hand: hovering level at rest the accelerometer reads R^T(0 - g e3) = (0, 0, -g); the
    bias adds to that and to nothing else (it does not move the vehicle)."""
    m = base + effects.by_name("accel_bias")
    bias = [0.1, -0.2, 0.3]
    p1 = m.parameter_vector({"acc_bias": bias})
    p0 = m.parameter_vector({"acc_bias": [0.0, 0.0, 0.0]})
    u = np.full(4, m.hover_speed())
    y0 = np.asarray(m.output(hover_state(), u, p0, 0.0)).ravel()
    y1 = np.asarray(m.output(hover_state(), u, p1, 0.0)).ravel()
    g = m.airframe.gravity
    ax = m.output_names.index("ax")
    np.testing.assert_allclose(y0[ax:ax + 3], [0.0, 0.0, -g], atol=1e-9)
    np.testing.assert_allclose(y1[ax:ax + 3], [0.1, -0.2, 0.3 - g], atol=1e-9)
    np.testing.assert_allclose(np.delete(y1 - y0, [ax, ax + 1, ax + 2]), 0.0, atol=1e-12)
    # at a rolled, moving state the difference is the bias all the same
    x = hover_state()
    x[3], x[6], x[10] = 0.4, 2.0, 0.3
    d = np.asarray(m.output(x, u, p1, 0.0)).ravel() - np.asarray(m.output(x, u, p0, 0.0)).ravel()
    np.testing.assert_allclose(d[ax:ax + 3], bias, atol=1e-12)
    np.testing.assert_allclose(rhs(m, x, u, p1), rhs(m, x, u, p0), atol=1e-12)
    assert effects.confusable("accel_bias", "wind") and effects.confusable("wind", "accel_bias")
    assert not effects.confusable("accel_bias", "ground_effect")


def test_measurement_only_effects_change_what_a_sensor_reports_not_the_motion():
    """What the diagnosis's tie rule reads: the sensor effects change the output map alone (the
    same trajectory, other readings); a wind or a CoG offset changes the motion."""
    import casadi as ca
    from greybox.effects import Effect, measurement_only
    assert [n for n in ("accel_bias", "attitude_bias", "position_delay", "wind", "cog_offset", "motor_lag")
            if measurement_only(n)] == ["accel_bias", "attitude_bias", "position_delay"]
    assert not measurement_only("no_such_effect")

    class Reading(Effect):
        name = "reading_offset"

        def modify_measurement(self, ctx, y):
            y["z"] = y["z"] + 0.1

    class Push(Reading):
        name = "push"

        def add_forces(self, ctx):
            ctx.force_world += ca.vertcat(0.1, 0, 0)
    assert Reading.measurement_only() and not Push.measurement_only()
    # by the model: a measurement-only effect leaves the state derivative as it was
    m = QuadrotorModel(make_airframe("plus"))
    x, u = np.zeros(12), np.full(4, 400.0)
    for name in ("accel_bias", "attitude_bias"):
        ext = m + effects.by_name(name)
        p = ext.parameter_vector({k: 0.05 for k in ext.parameter_dict(ext.default_parameters()) if "bias" in k})
        assert np.allclose(np.asarray(ext.rhs(x, u, p, 0.0)).ravel()[:12], np.asarray(m.rhs(x, u, m.default_parameters(), 0.0)).ravel())


def test_a_model_accepts_an_effect_it_has_not_and_whose_states_do_not_clash():
    """``QuadrotorModel.accepts``: not an effect already in, not one whose states share a name
    with the model's (the held moment's and the disturbance torque's ``d_p, d_q``)."""
    m = QuadrotorModel(make_airframe("plus"))
    assert m.accepts(effects.HeldMoment()) and m.accepts(effects.DisturbanceTorque())
    assert not (m + effects.HeldMoment()).accepts(effects.HeldMoment())
    assert not (m + effects.HeldMoment()).accepts(effects.DisturbanceTorque())
    assert not (m + effects.DisturbanceTorque()).accepts(effects.HeldMoment())
    assert not m.accepts(effects.by_name("linear_drag")) and m.accepts(effects.by_name("wind"))


def test_thrust_curve_is_a_cubic_thrust_term_about_hover(base):
    """``K_T' w^2 (1 + k_Tw (w/w_h - 1))`` with ``w_h`` the hover speed of ``K_T'`` is
    ``K_T w^2 + c w^3`` exactly when ``K_T' = K_T + c w_h`` and ``k_Tw = c w_h / K_T'``: the
    vertical acceleration at level rest, equal rotors at 0.8-1.2 hover speeds, worked out by
    hand against the model's."""
    m = base + effects.ThrustCurve()
    af = m.airframe
    K_T, c = 2.0e-5, 1.5e-8                 # c w_h is some 7 % of K_T at this airframe's hover
    K_Tp = K_T
    for _ in range(60):                     # the fixed point K_T' = K_T + c w_h(K_T')
        K_Tp = K_T + c * np.sqrt(af.mass * af.gravity / (af.n_rotors * K_Tp))
    w_h = np.sqrt(af.mass * af.gravity / (af.n_rotors * K_Tp))
    k_Tw = c * w_h / K_Tp
    assert 0.03 < k_Tw < 0.2
    p = m.parameter_vector({"K_T": K_Tp, "k_Tw": k_Tw})
    for f in (0.8, 1.0, 1.2):
        w = f * w_h
        zdd = rhs(m, hover_state(), [w] * 4, p)[8]
        assert zdd == pytest.approx(af.gravity - af.n_rotors * (K_T * w ** 2 + c * w ** 3) / af.mass, rel=1e-12, abs=1e-12)
    assert rhs(m, hover_state(), [w_h] * 4, p)[8] == pytest.approx(0.0, abs=1e-12)   # hover trim unchanged
    # one rotor faster: its thrust, hence the moment, grows 1 + k_Tw/2 times as fast as K_T's square
    u = np.array([w_h * 1.001, w_h, w_h, w_h])
    dm = rhs(m, hover_state(), u, p)[9:12] - rhs(m, hover_state(), [w_h] * 4, p)[9:12]
    m0 = base
    dm0 = rhs(m0, hover_state(), u, m0.parameter_vector({"K_T": K_Tp}))[9:12]
    k = np.argmax(np.abs(dm0))
    assert dm[k] / dm0[k] == pytest.approx(1 + k_Tw / 2, rel=2e-3)


def test_effect_components_name_each_component_with_its_null(base):
    m = base + effects.MomentGain() + effects.MotorAsymmetry()
    assert [(c, n) for _, c, n in m.effect_components("moment_gain")] == [("k_M", 1.0)]
    assert [(c, n) for _, c, n in m.effect_components("linear_drag")] == [("Kd[0]", 0.0), ("Kd[1]", 0.0), ("Kd[2]", 0.0)]
    assert [c for _, c, _ in m.effect_components("motor_asymmetry")] == ["K_T_dev[0]", "K_T_dev[1]", "K_T_dev[2]"]
    assert m.effect_components("wind") == []


@pytest.mark.parametrize("frame", ["x", "hexa"])
def test_rotor_gains_linear_in_position_are_a_cog_offset_and_a_weak_rotor_is_not(frame, tmp_path):
    """Gains d_i = a x_i + c y_i move the thrust's centre as a CoG offset of
    (-a sum x_i^2, -c sum y_i^2) / N does: at hover with equal speeds the two models give the
    same body accelerations (roll, pitch, yaw, vertical), by hand from the torque -y_i T_i.
    ``MotorAsymmetry.reduces_to("cog_offset")`` says so for such gains with noise of their own
    covariance (at least 190 of 200 seeded draws, x frame and the audit's hexacopter) and for the same gains known
    to 1e-4, a hundredth of them beyond the plane; not for one rotor 7 % weak, known to 0.002."""
    if frame == "x":
        af = make_airframe("x")
    else:
        import hexa_sim
        from greybox import load_airframe
        hexa_sim.write_airframe(tmp_path / "hexa.toml", 1.0, 1.0, 1.0)
        af = load_airframe(tmp_path / "hexa.toml")
    base = QuadrotorModel(af)
    n = af.n_rotors
    pos = np.asarray(af.rotor_positions)[:, :2]
    a, c = -0.4, 0.3
    d = a * pos[:, 0] + c * pos[:, 1]
    assert abs(d.sum()) < 1e-12
    asym = base + effects.MotorAsymmetry()
    cog = base + effects.CogOffset()
    r_cog = [-a * np.sum(pos[:, 0] ** 2) / n, -c * np.sum(pos[:, 1] ** 2) / n]
    pa = asym.parameter_vector({"K_T_dev": list(d[:-1])})
    pc = cog.parameter_vector({"r_cog": r_cog})
    w = base.hover_speed()
    xa, xc = rhs(asym, hover_state(), [w] * n, pa), rhs(cog, hover_state(), [w] * n, pc)
    assert abs(xa[9]) > 0.1 and abs(xa[10]) > 0.1
    np.testing.assert_allclose(xa[8:12], xc[8:12], rtol=1e-9, atol=1e-12)

    names = [f"K_T_dev[{i}]" for i in range(n - 1)]
    cov = np.diag(np.full(n - 1, 0.02 ** 2))
    e = effects.MotorAsymmetry()
    # draws of the gains' noise (its covariance is diagonal: scaled normals, the same on every
    # numpy build; multivariate_normal's factorisation is not). The test's level is 1 %
    # (Bonferroni over the patterns): of 200 draws about 2 fall outside; 10 would be 1e-4 likely
    rng = np.random.default_rng(4)
    said = [e.reduces_to("cog_offset", dict(zip(names, d[:-1] + 0.02 * rng.standard_normal(n - 1))), cov, names, af)
            for _ in range(200)]
    assert sum("pattern of a CoG offset" in s for s in said) >= 190
    off = e.reduces_to("cog_offset", dict(zip(names, d[:-1])), cov, names, af)
    import re
    said = re.search(r"CoG offset of \(([-\d.e]+), ([-\d.e]+)\) mm", off)
    np.testing.assert_allclose([float(said[1]), float(said[2])], 1e3 * np.array(r_cog), rtol=2e-3)
    spin = np.array([r.spin for r in af.rotors], dtype=float)      # beyond the plane: the yaw's pattern
    beyond = d + 0.01 * np.abs(d).max() * spin
    tight = np.diag(np.full(n - 1, 1e-4 ** 2))
    assert "pattern of a CoG offset" in e.reduces_to("cog_offset", dict(zip(names, beyond[:-1])), tight, names, af)
    far = d + 0.3 * np.abs(d).max() * spin                         # a third of it, known to 1e-4: not the offset
    assert e.reduces_to("cog_offset", dict(zip(names, far[:-1])), tight, names, af) == ""
    weak = np.zeros(n)
    weak[2] = -0.07
    weak -= weak.mean()
    assert e.reduces_to("cog_offset", dict(zip(names, weak[:-1])), np.diag(np.full(n - 1, 0.002 ** 2)), names,
                        af) == ""
    assert e.reduces_to("wind", dict(zip(names, weak[:-1])), cov, names, af) == ""


def test_settled_states_put_a_motor_lag_where_the_battery_scaled_speeds_ask():
    """By hand: behind a battery's scaling w (1 + K_vbat (vbat - 4)) a first-order motor lag
    rests at the scaled speeds, not at the logged ones that initial_state takes (the thrust
    balance of an audit's correct flights at 3.7-4.1 V read 95-112 % of the weight); a state
    with no dynamics of its own (a random-walk disturbance) keeps its value."""
    model = QuadrotorModel(make_airframe("x")) + effects.BatteryVoltage() + effects.MotorLag() \
        + effects.DisturbanceTorque()
    p = model.default_parameters()
    names = model.param_names
    p[names.index("K_vbat")] = 0.2
    w, vbat = np.array([400.0, 410.0, 390.0, 405.0]), 3.75
    u = np.r_[w, vbat]
    x = model.initial_state(np.zeros(12), u)
    np.testing.assert_allclose(x[12:16], w)                      # the logged speeds, as they are
    x[16:] = [0.01, -0.02, 0.003]
    settled = model.settled_states(x[None, :], u[None, :], p, np.zeros(1))[0]
    np.testing.assert_allclose(settled[12:16], w * (1 + 0.2 * (vbat - 4.0)), rtol=1e-10)
    np.testing.assert_allclose(settled[16:], [0.01, -0.02, 0.003])
    np.testing.assert_allclose(settled[:12], 0.0)


def test_gyro_scale_scales_the_measured_rates_only(base):
    """By hand: at a state turning at (0.2, -0.1, 0.5) rad/s the gyro reads (1 + k) times each
    rate; every other output, and the motion, stay as they were."""
    m = base + effects.by_name("gyro_scale")
    k = [0.02, -0.03, 0.05]
    p1 = m.parameter_vector({"k_gyro": k})
    p0 = m.parameter_vector({"k_gyro": [0.0, 0.0, 0.0]})
    u = np.full(4, m.hover_speed())
    x = hover_state()
    x[3], x[6], x[9], x[10], x[11] = 0.3, 1.0, 0.2, -0.1, 0.5
    y0 = np.asarray(m.output(x, u, p0, 0.0)).ravel()
    y1 = np.asarray(m.output(x, u, p1, 0.0)).ravel()
    ip = m.output_names.index("p")
    np.testing.assert_allclose(y0[ip:ip + 3], [0.2, -0.1, 0.5], atol=1e-12)
    np.testing.assert_allclose(y1[ip:ip + 3], [0.204, -0.097, 0.525], atol=1e-12)
    np.testing.assert_allclose(np.delete(y1 - y0, [ip, ip + 1, ip + 2]), 0.0, atol=1e-12)
    np.testing.assert_allclose(rhs(m, x, u, p1), rhs(m, x, u, p0), atol=1e-12)
    assert effects.measurement_only("gyro_scale") and effects.confusable("gyro_scale", "moment_gain")

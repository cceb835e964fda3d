"""Hand-worked physics: hover trim, free fall, torque signs, drag decay, frames."""
import numpy as np
import pytest

from greybox import QuadrotorModel, simulate
from greybox.model import rotation_matrix

from conftest import make_airframe


def rhs(model, x, u, p=None, t=0.0):
    p = model.default_parameters() if p is None else p
    return np.asarray(model.rhs(x, u, p, t)).ravel()


def hover_state(z=-1.0):
    x = np.zeros(12)
    x[2] = z
    return x


@pytest.mark.parametrize("layout", ["plus", "x"])
def test_hover_trim_is_equilibrium(layout):
    m = QuadrotorModel(make_airframe(layout))
    w = np.sqrt(1.0 * 9.81 / (4 * 2e-5))   # sqrt(m g / (4 K_T)), by hand
    assert m.hover_speed() == pytest.approx(w)
    xd = rhs(m, hover_state(), [w] * 4)
    np.testing.assert_allclose(xd, 0, atol=1e-12)


def test_free_fall_without_drag(plus_airframe):
    m = QuadrotorModel(plus_airframe).without("linear_drag")
    t = np.linspace(0, 1.0, 101)
    sim = simulate(m, t, np.zeros((t.size, 4)), x0=hover_state(-10))
    np.testing.assert_allclose(sim.output("z"), -10 + 0.5 * 9.81 * t ** 2, atol=1e-10)
    np.testing.assert_allclose(sim.states[:, [0, 1, 3, 4, 5]], 0, atol=1e-14)


def test_free_fall_with_linear_drag_reaches_terminal_velocity(plus_airframe):
    m = QuadrotorModel(plus_airframe)
    kdz = 0.15
    t = np.linspace(0, 2.0, 201)
    sim = simulate(m, t, np.zeros((t.size, 4)), x0=hover_state(-50))
    vz = 9.81 * 1.0 / kdz * (1 - np.exp(-kdz * t / 1.0))
    np.testing.assert_allclose(sim.state("vz"), vz, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("axis", [0, 1])
def test_linear_drag_exponential_decay(plus_airframe, axis):
    m = QuadrotorModel(plus_airframe)
    w = m.hover_speed()
    x0 = hover_state()
    x0[6 + axis] = 1.5
    t = np.linspace(0, 3.0, 301)
    sim = simulate(m, t, np.full((t.size, 4), w), x0=x0)
    np.testing.assert_allclose(sim.states[:, 6 + axis], 1.5 * np.exp(-0.1 * t / 1.0), rtol=1e-9)
    np.testing.assert_allclose(sim.states[:, axis], 1.5 / 0.1 * (1 - np.exp(-0.1 * t)), rtol=1e-8)


def test_plus_layout_torque_signs_by_hand(plus_airframe):
    m = QuadrotorModel(plus_airframe)
    kt, b, l, J = 2e-5, 5e-7, 0.17, [0.0082, 0.0082, 0.0149]
    w = m.hover_speed()
    d = 20.0
    # roll: rotor 4 (left) faster than rotor 2 (right): l*K_T*(w4^2 - w2^2) > 0, right wing down
    xd = rhs(m, hover_state(), [w, w - d, w, w + d])
    assert xd[9] == pytest.approx(l * kt * ((w + d) ** 2 - (w - d) ** 2) / J[0], rel=1e-12)
    assert xd[9] > 0 and abs(xd[10]) < 1e-12
    # pitch: rotor 1 (front) faster than rotor 3 (back): nose up
    xd = rhs(m, hover_state(), [w + d, w, w - d, w])
    assert xd[10] == pytest.approx(l * kt * ((w + d) ** 2 - (w - d) ** 2) / J[1], rel=1e-12)
    assert xd[10] > 0 and abs(xd[9]) < 1e-12
    # yaw: b*(-w1^2 + w2^2 - w3^2 + w4^2) > 0 when rotors 2, 4 are faster
    xd = rhs(m, hover_state(), [w - d, w + d, w - d, w + d])
    assert xd[11] == pytest.approx(b * 2 * ((w + d) ** 2 - (w - d) ** 2) / J[2], rel=1e-12)
    assert xd[11] > 0


def test_x_layout_torque_signs_by_hand(x_airframe):
    m = QuadrotorModel(x_airframe)
    w, d = m.hover_speed(), 20.0
    a = 0.17 / np.sqrt(2)
    kt, b, J = 2e-5, 5e-7, [0.0082, 0.0082, 0.0149]
    dT = kt * ((w + d) ** 2 - (w - d) ** 2)
    # left rotors (2 back-left, 3 front-left) faster -> roll right (positive)
    xd = rhs(m, hover_state(), [w - d, w + d, w + d, w - d])
    assert xd[9] == pytest.approx(2 * a * dT / J[0], rel=1e-12)
    assert abs(xd[10]) < 1e-10
    # front rotors (1, 3) faster -> nose up
    xd = rhs(m, hover_state(), [w + d, w - d, w + d, w - d])
    assert xd[10] == pytest.approx(2 * a * dT / J[1], rel=1e-12)
    # spin +1 rotors (1, 2) faster -> positive yaw
    xd = rhs(m, hover_state(), [w + d, w + d, w - d, w - d])
    assert xd[11] == pytest.approx(2 * b * ((w + d) ** 2 - (w - d) ** 2) / J[2], rel=1e-12)


def test_tilt_accelerates_the_right_way(plus_airframe):
    m = QuadrotorModel(plus_airframe)
    w = m.hover_speed()
    x = hover_state()
    x[3] = 0.1  # roll right: accelerate east (+y)
    assert rhs(m, x, [w] * 4)[7] == pytest.approx(9.81 * np.sin(0.1), rel=1e-9)
    x = hover_state()
    x[4] = 0.1  # nose up: accelerate backwards (-x)
    xd = rhs(m, x, [w] * 4)
    assert xd[6] == pytest.approx(-9.81 * np.sin(0.1), rel=1e-9)
    x[5] = np.pi / 2  # same pitch, facing east: accelerate west (-y)
    xd = rhs(m, x, [w] * 4)
    assert xd[7] == pytest.approx(-9.81 * np.sin(0.1), rel=1e-9) and abs(xd[6]) < 1e-12


def test_rotation_matrix_is_zyx_and_orthonormal():
    R = np.array(rotation_matrix(0.3, -0.2, 1.1))
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    # ERRATA eq. (1): R[3,1] = -sin(theta)
    assert R[2, 0] == pytest.approx(-np.sin(-0.2))
    psi = 0.7
    np.testing.assert_allclose(np.array(rotation_matrix(0, 0, psi)) @ [1, 0, 0], [np.cos(psi), np.sin(psi), 0])


def test_euler_rates_from_body_rates(plus_airframe):
    m = QuadrotorModel(plus_airframe)
    x = hover_state()
    x[3], x[4] = 0.3, 0.2
    x[9:12] = [0.0, 1.0, 0.0]  # pure q: ERRATA eq. (2) row 2 is cos(phi), row 1 sin(phi)tan(theta)
    xd = rhs(m, x, [m.hover_speed()] * 4)
    np.testing.assert_allclose(xd[3:6], [np.sin(0.3) * np.tan(0.2), np.cos(0.3), np.sin(0.3) / np.cos(0.2)],
                               rtol=1e-12)


def test_yaw_coriolis_term_uses_jx_minus_jy():
    af = make_airframe("plus", inertia=[0.01, 0.02, 0.03])
    m = QuadrotorModel(af).without("gyroscopic")
    x = hover_state()
    x[9:12] = [1.0, 2.0, 0.0]
    xd = rhs(m, x, [m.hover_speed()] * 4)
    assert xd[11] == pytest.approx((0.01 - 0.02) * 1.0 * 2.0 / 0.03, rel=1e-12)  # ERRATA eq. (8)


def test_without_yaw_torque_a_spinning_hover_stays_put(plus_airframe):
    # the seed's Fig. 1 physics: with b the rotor torques balance at hover, and an
    # imbalance turns the vehicle; without b, yaw receives no torque at all
    full = QuadrotorModel(plus_airframe)
    nob = full.without("yaw_torque")
    w = full.hover_speed()
    u = [w - 5, w + 5, w - 5, w + 5]
    assert rhs(full, hover_state(), u)[11] > 0
    assert rhs(nob, hover_state(), u)[11] == 0


def test_controls_inputs_match_rotor_speeds(plus_airframe):
    ms = QuadrotorModel(plus_airframe)
    mc = ms.with_inputs("controls")
    assert mc.input_names == ["u1", "u2", "u3", "u4"]
    rng = np.random.default_rng(0)
    w = ms.hover_speed() * (1 + 0.05 * rng.standard_normal(4))
    kt, b, l = 2e-5, 5e-7, 0.17
    U = [kt * np.sum(w ** 2), l * kt * (w[3] ** 2 - w[1] ** 2), l * kt * (w[0] ** 2 - w[2] ** 2),
         b * (-w[0] ** 2 + w[1] ** 2 - w[2] ** 2 + w[3] ** 2)]  # seed eqs. (19)-(22), ERRATA signs
    x = hover_state()
    x[9:12] = [0.2, -0.1, 0.3]
    np.testing.assert_allclose(rhs(mc, x, U), rhs(ms, x, w), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(mc.rotor_speeds_from_inputs(np.array(U)), w, rtol=1e-9)

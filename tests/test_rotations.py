"""The one place attitude conventions are written, checked against SciPy and by hand."""
import casadi as ca
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from greybox.rotations import (body_rates_from_euler_rates, euler_from_rotation, euler_rate_matrix,
                               euler_rates_from_body_rates, rotation,
                               rotation_matrices, rotation_matrix)

angles = st.tuples(st.floats(-3.0, 3.0), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))


@settings(max_examples=60, deadline=None)
@given(angles)
def test_numeric_symbolic_and_scipy_agree(a):
    phi, theta, psi = a
    want = Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix()    # intrinsic yaw-pitch-roll
    np.testing.assert_allclose(rotation(phi, theta, psi), want, atol=1e-12)
    np.testing.assert_allclose(np.array(ca.DM(rotation_matrix(phi, theta, psi))), want, atol=1e-12)
    np.testing.assert_allclose(euler_from_rotation(want), a, atol=1e-9)


def test_by_hand_a_pitch_up_tilts_the_nose_up():
    # 90 deg pitch: body forward (x) points up in NED (-z); yaw 90 deg: forward points east (+y)
    np.testing.assert_allclose(rotation(0, np.pi / 2, 0) @ [1, 0, 0], [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(rotation(0, 0, np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)


@settings(max_examples=40, deadline=None)
@given(angles, st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5)))
def test_body_rates_invert_the_euler_rate_matrix(a, pqr):
    phi, theta, _ = a
    W = np.array(ca.DM(euler_rate_matrix(phi, theta)))
    euler_dot = W @ np.array(pqr)
    back = body_rates_from_euler_rates(np.array([phi]), np.array([theta]), euler_dot[None, :])[0]
    np.testing.assert_allclose(back, pqr, atol=1e-8 * (1 + np.abs(euler_dot).max()))
    np.testing.assert_allclose(euler_rates_from_body_rates(phi, theta, np.array(pqr)), euler_dot, rtol=1e-12,
                               atol=1e-12)
    assert rotation_matrices(np.zeros(2), np.zeros(2), np.zeros(2)).shape == (2, 3, 3)

import json

import numpy as np
import pytest

from greybox import QuadrotorModel, effects
from greybox.cli import main
from greybox.linearize import hover_trim, linearize

import reference_quad as ref


def fd_jacobians(x, u, cfg, h=1e-6):
    """Central finite differences of the independent reference physics."""
    pos, spin = ref.rotors(cfg["layout"], cfg["l"])
    f = lambda s, w: ref.rhs(s, w, cfg["m"], cfg["J"], 9.81, cfg["kt"], cfg["b"], cfg["kd"], cfg["jr"], pos, spin)
    A = np.column_stack([(f(x + h * e, u) - f(x - h * e, u)) / (2 * h) for e in np.eye(12)])
    hu = 1e-4 * np.abs(u).max()
    B = np.column_stack([(f(x, u + hu * e) - f(x, u - hu * e)) / (2 * hu) for e in np.eye(4)])
    return A, B


@pytest.mark.parametrize("layout", ["plus", "x"])
def test_linearize_cli_matches_finite_differences(tmp_path, layout):
    cfg = dict(layout=layout, l=0.2, m=1.1, J=np.diag([0.009, 0.01, 0.017]), kt=2.1e-5, b=6e-7,
               kd=np.array([0.1, 0.12, 0.2]), jr=2e-5)
    (tmp_path / "a.toml").write_text(f"""[airframe]
mass = 1.1
inertia = [0.009, 0.01, 0.017]
arm_length = 0.2
layout = "{layout}"
rotor_inertia = 2e-5
[parameters]
K_T = 2.1e-5
b = 6e-7
Kd = [0.1, 0.12, 0.2]
""")
    rc = main(["linearize", "--airframe", str(tmp_path / "a.toml"), "--json", str(tmp_path / "l.json")])
    assert rc == 0
    r = json.loads((tmp_path / "l.json").read_text())
    assert r["states"] == ["x", "y", "z", "phi", "theta", "psi", "vx", "vy", "vz", "p", "q", "r"]
    assert r["inputs"] == ["w1", "w2", "w3", "w4"]
    w_h = np.sqrt(1.1 * 9.81 / (4 * 2.1e-5))
    np.testing.assert_allclose(r["u_trim"], w_h, rtol=1e-12)
    A, B = np.array(r["A"]), np.array(r["B"])
    x, u = np.array(r["x_trim"]), np.array(r["u_trim"])
    Af, Bf = fd_jacobians(x, u, cfg)
    assert np.abs(A - Af).max() < 1e-5 * max(1.0, np.abs(Af).max())
    assert np.abs(B - Bf).max() < 1e-5 * np.abs(Bf).max()
    # away from hover too: a tilted, moving, spinning state
    model = QuadrotorModel(__import__("greybox").load_airframe(tmp_path / "a.toml"))
    x2 = np.array([0.3, -0.2, -1.0, 0.2, -0.15, 0.7, 1.0, -0.5, 0.3, 0.4, -0.3, 0.5])
    u2 = w_h * np.array([1.05, 0.97, 1.02, 0.99])
    lin = linearize(model, x=x2, u=u2)
    Af, Bf = fd_jacobians(x2, u2, cfg)
    assert np.abs(lin.A - Af).max() < 1e-5 * np.abs(Af).max()
    assert np.abs(lin.B - Bf).max() < 1e-5 * np.abs(Bf).max()


def test_hover_linearisation_by_hand(plus_airframe):
    m = QuadrotorModel(plus_airframe)
    lin = linearize(m)
    w, g, kt, l = m.hover_speed(), 9.81, 2e-5, 0.17
    assert lin.A[6, 4] == pytest.approx(-g) and lin.A[7, 3] == pytest.approx(g)   # tilt -> acceleration
    assert lin.A[6, 6] == pytest.approx(-0.1)                                    # linear drag
    np.testing.assert_allclose(lin.B[8], -2 * kt * w / 1.0)                       # thrust on z
    assert lin.B[9, 3] == pytest.approx(2 * l * kt * w / 0.0082)                 # rotor 4 rolls right
    assert lin.B[10, 0] == pytest.approx(2 * l * kt * w / 0.0082)                # rotor 1 pitches up
    assert lin.C.shape == (12, 12) and lin.C[6, 9] == 1
    # the accelerometer (rows 9-11: ax, ay, az, body specific force): a tilt at hover does
    # not change it (thrust and gravity turn together, only thrust is measured), a velocity
    # does through the drag, a rotor speed through its thrust
    assert lin.output_names[9:] == ["ax", "ay", "az"]
    assert np.abs(lin.C[9:, 3:6]).max() < 1e-12
    assert lin.C[9, 6] == pytest.approx(-0.1) and lin.C[11, 8] == pytest.approx(lin.A[8, 8])
    np.testing.assert_allclose(lin.D[11], -2 * kt * w / 1.0)
    assert np.abs(lin.D[:9]).max() == 0


def test_trim_with_cog_offset_and_asymmetry_is_an_equilibrium(plus_airframe):
    m = QuadrotorModel(plus_airframe) + effects.CogOffset() + effects.MotorAsymmetry() + effects.MotorLag()
    p = m.parameter_vector({"r_cog": [0.01, -0.004], "K_T_dev": [-0.08, 0.03, 0.02]})
    x, u = hover_trim(m, p)
    assert np.ptp(u) > 5                     # unequal rotor speeds are needed
    np.testing.assert_allclose(np.asarray(m.rhs(x, u, p, 0)).ravel(), 0, atol=1e-9)
    np.testing.assert_allclose(x[12:], u)    # motors at steady state


def test_discretize_zoh_and_python_control(plus_airframe):
    lin = linearize(QuadrotorModel(plus_airframe))
    d = lin.discretize(0.01)
    assert d.A.shape == (12, 12) and d.dt == 0.01
    # position integrates velocity: x[k+1] = x[k] + dt vx[k] + O(dt^2)
    assert d.A[0, 6] == pytest.approx(0.01, rel=0.01)
    pytest.importorskip("control")
    sys = d.to_control()
    assert sys.dt == 0.01 and sys.nstates == 12

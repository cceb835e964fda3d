import re
from pathlib import Path

import numpy as np
import pytest

from greybox import QuadrotorModel, load_airframe
from greybox.airframe import airframe_from_dict
from greybox.errors import GreyboxInputError

GOOD = """
[airframe]
name = "t"
mass = 1.0
inertia = [0.0082, 0.0082, 0.0149]
arm_length = 0.17
layout = "plus"
"""


def write(tmp_path, text):
    p = tmp_path / "a.toml"
    p.write_text(text)
    return p


def test_contract_example_loads(tmp_path):
    af = load_airframe(write(tmp_path, GOOD + '\n[parameters]\nK_T = 2.0e-5\nb = 5.0e-7\nKd = [0.1, 0.1, 0.1]\n'))
    assert af.n_rotors == 4 and af.mass == 1.0 and af.gravity == 9.81 and af.ground_z == 0.0
    np.testing.assert_allclose(af.rotor_positions[0], [0.17, 0, 0])
    np.testing.assert_array_equal(af.spins, [-1, 1, -1, 1])
    assert af.parameters["Kd"] == [0.1, 0.1, 0.1]


def test_x_layout_geometry():
    af = airframe_from_dict({"airframe": {"mass": 1, "inertia": [1, 1, 1.5], "arm_length": np.sqrt(2),
                                          "layout": "x"}})
    np.testing.assert_allclose(af.rotor_positions[:, :2], [[1, 1], [-1, -1], [1, -1], [-1, 1]])
    np.testing.assert_array_equal(af.spins, [1, 1, -1, -1])


def test_an_airframe_built_from_rotors_alone_has_their_arm():
    """Built in Python without arm_length, the arm is the hubs' mean distance from the centre
    (0.2 m for an x layout of 0.2, 0.125 m for hubs at 0.1 and 0.15), as a file's rotor tables
    give it: the plausible CoG offset is 15 % of it (30 mm), not of a 1-mm floor."""
    from greybox.airframe import Airframe, Rotor, rotors_for_layout
    from greybox.effects import CogOffset
    af = Airframe(mass=1.0, inertia=np.diag([0.01, 0.01, 0.02]), rotors=rotors_for_layout("x", 0.2))
    assert af.arm_length == pytest.approx(0.2)
    assert CogOffset().plausible_limits(af)["r_cog"] == pytest.approx(0.03)
    odd = [Rotor((0.1, 0.0, 0.0), 1), Rotor((0.0, 0.1, 0.0), -1), Rotor((-0.15, 0.0, 0.0), 1), Rotor((0.0, -0.15, 0.0), -1)]
    assert Airframe(mass=1.0, inertia=np.diag([0.01, 0.01, 0.02]), rotors=odd).arm_length == pytest.approx(0.125)
    given = Airframe(mass=1.0, inertia=np.diag([0.01, 0.01, 0.02]), rotors=odd, arm_length=0.3)
    assert given.arm_length == 0.3


def test_explicit_hexarotor(tmp_path):
    text = GOOD.replace('layout = "plus"\n', "")
    for k in range(6):
        a = k * np.pi / 3
        text += f"\n[[rotor]]\nposition = [{0.2 * np.cos(a)}, {0.2 * np.sin(a)}, 0.0]\nspin = {1 if k % 2 else -1}\n"
    af = load_airframe(write(tmp_path, text))
    assert af.n_rotors == 6 and af.layout == "custom"
    m = QuadrotorModel(af)
    assert m.input_names == [f"w{i}" for i in range(1, 7)]
    x = np.zeros(12)
    w = m.hover_speed()
    assert w == pytest.approx(np.sqrt(9.81 / (6 * 2e-5)))
    np.testing.assert_allclose(np.asarray(m.rhs(x, [w] * 6, m.default_parameters(), 0)).ravel(), 0, atol=1e-10)


def test_full_inertia_matrix(tmp_path):
    af = load_airframe(write(tmp_path, GOOD.replace("[0.0082, 0.0082, 0.0149]",
                                                    "[[0.0082, 0.0001, 0], [0.0001, 0.0082, 0], [0, 0, 0.0149]]")))
    assert af.inertia[0, 1] == 0.0001


def test_roundtrip_to_toml(tmp_path):
    af = load_airframe(write(tmp_path, GOOD + "\n[parameters]\nK_T = 2.0e-5\n"))
    af2 = load_airframe(write(tmp_path, af.to_toml()))
    np.testing.assert_allclose(af2.rotor_positions, af.rotor_positions)
    assert af2.parameters == af.parameters and af2.layout == "plus"


@pytest.mark.parametrize("change, message", [
    (("mass = 1.0", "mass = -1.0"), "mass must be positive"),
    (("mass = 1.0", 'mass = "heavy"'), "mass must be a number"),
    (("mass = 1.0", "mass = 1.0\ncolour = 3"), "unknown key.*colour"),
    (("[0.0082, 0.0082, 0.0149]", "[0.0082, 0.0082]"), "inertia must have 3 entries"),
    (("[0.0082, 0.0082, 0.0149]", "[0.0082, -0.0082, 0.0149]"), "positive definite"),
    (("[0.0082, 0.0082, 0.0149]", "[0.0082, 0.0082, 0.0]"), "positive definite"),
    (("[0.0082, 0.0082, 0.0149]", "[[0.01, 0.002, 0], [0, 0.01, 0], [0, 0, 0.02]]"), "not symmetric"),
    (("[0.0082, 0.0082, 0.0149]", "[0.001, 0.001, 0.0149]"), "not physical"),
    (('layout = "plus"', 'layout = "hexa"'), "unknown layout 'hexa'"),
    (("arm_length = 0.17", "arm_length = 0.0"), "arm_length must be positive"),
    (("mass = 1.0", "mass = 1.0\nrotor_inertia = -1e-6"), "rotor_inertia must be >= 0"),
    (("[airframe]", "[airframe]\n"), None),
])
def test_bad_airframes(tmp_path, change, message):
    text = GOOD.replace(*change)
    if message is None:
        load_airframe(write(tmp_path, text))
        return
    with pytest.raises(GreyboxInputError, match=message) as e:
        load_airframe(write(tmp_path, text))
    assert "a.toml" in str(e.value)


def test_bad_rotor_tables(tmp_path):
    base = GOOD.replace('layout = "plus"\n', "")
    with pytest.raises(GreyboxInputError, match="rotor 1 position must have 3 entries"):
        load_airframe(write(tmp_path, base + "[[rotor]]\nposition = [0.1, 0]\nspin = 1\n"))
    with pytest.raises(GreyboxInputError, match="spin must be"):
        load_airframe(write(tmp_path, base + "[[rotor]]\nposition = [0.1, 0, 0]\nspin = 2\n"))
    with pytest.raises(GreyboxInputError, match="either airframe.layout or"):
        load_airframe(write(tmp_path, GOOD + "[[rotor]]\nposition = [0.1, 0, 0]\nspin = 1\n"))
    with pytest.raises(GreyboxInputError, match="give airframe.layout"):
        load_airframe(write(tmp_path, base))
    # hubs without a lever: no roll (and no pitch) torque, which a model would not say
    zero = "".join(f"[[rotor]]\nposition = [0, 0, 0]\nspin = {s}\n" for s in (1, -1, 1, -1))
    with pytest.raises(GreyboxInputError, match="every rotor is at y = 0, so the rotors give no roll torque"):
        load_airframe(write(tmp_path, base + zero))
    line = "".join(f"[[rotor]]\nposition = [0, {y}, 0]\nspin = {s}\n" for y, s in ((0.1, 1), (-0.1, -1)))
    with pytest.raises(GreyboxInputError, match="no pitch torque"):
        load_airframe(write(tmp_path, base + line))
    # one rotor written twice (a blind audit's copy-paste, fitted without a word); a coaxial
    # pair (one place, opposite spins) is a rotor layout
    quad = [((0.1, 0.1), 1), ((-0.1, -0.1), 1), ((0.1, -0.1), -1), ((-0.1, 0.1), -1)]
    tables = lambda rs: "".join(f"[[rotor]]\nposition = [{x}, {y}, 0]\nspin = {s}\n" for (x, y), s in rs)
    with pytest.raises(GreyboxInputError, match="rotor 5 has rotor 3's position and spin"):
        load_airframe(write(tmp_path, base + tables(quad + [((0.1, -0.1), -1)])))
    coax = quad + [((x, y), -s) for (x, y), s in quad]
    assert load_airframe(write(tmp_path, base + tables(coax))).n_rotors == 8


def test_file_errors(tmp_path):
    with pytest.raises(GreyboxInputError, match="not found"):
        load_airframe(tmp_path / "nope.toml")
    with pytest.raises(GreyboxInputError, match="not valid TOML"):
        load_airframe(write(tmp_path, "[airframe\nmass = 1"))
    with pytest.raises(GreyboxInputError, match="missing \\[airframe\\]"):
        load_airframe(write(tmp_path, "[parameters]\nK_T = 1e-5\n"))


def test_parameter_names_and_sizes_are_checked(tmp_path):
    af = load_airframe(write(tmp_path, GOOD + "\n[parameters]\nK_TT = 2e-5\n"))
    with pytest.raises(GreyboxInputError, match="unknown parameter 'K_TT'"):
        QuadrotorModel(af)
    af = load_airframe(write(tmp_path, GOOD + "\n[parameters]\nKd = [0.1, 0.2]\n"))
    with pytest.raises(GreyboxInputError, match="'Kd' needs 3 values"):
        QuadrotorModel(af)
    # guesses for effects not (yet) in the model are allowed: the diagnosis uses them
    af = load_airframe(write(tmp_path, GOOD + "\n[parameters]\nk_ge = 1e-4\n"))
    assert "k_ge" not in QuadrotorModel(af).param_names


def test_measured_inertia_breaking_the_triangle_inequality_slightly_is_accepted_with_a_warning(tmp_path, capsys):
    """A flat airframe sits on J1 + J2 = J3; a published measurement may break it by 1 %."""
    import warnings
    from greybox.errors import AirframeWarning
    text = GOOD.replace("[0.0082, 0.0082, 0.0149]", "[0.0082, 0.0082, 0.016566]")   # 1 % over
    with pytest.warns(AirframeWarning, match="by 1.0"):
        af = load_airframe(write(tmp_path, text))
    assert af.inertia[2, 2] == pytest.approx(0.016566)
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # inside the limit: no warning at all
        load_airframe(write(tmp_path, GOOD))
    # 10 % over is not measurement error
    with pytest.raises(GreyboxInputError, match="by 10.0 %"):
        load_airframe(write(tmp_path, GOOD.replace("[0.0082, 0.0082, 0.0149]", "[1.0, 1.0, 2.2222]")))
    # the CLI says it in one line
    from greybox.cli import main
    path = write(tmp_path, text)
    assert main(["linearize", "--airframe", str(path), "--json", str(tmp_path / "lin.json")]) == 0
    err = capsys.readouterr().err
    assert "greybox: warning:" in err and "J1 + J2 >= J3" in err and "Traceback" not in err


@pytest.mark.parametrize("old,new,unit", [
    ("mass = 1.0", "mass = 1000.0", "mass in grams"),                     # 1 kg given in grams
    ("[0.0082, 0.0082, 0.0149]", "[8.2, 8.2, 14.9]", "inertia in g m^2"),  # g m^2 for kg m^2
    ("arm_length = 0.17", "arm_length = 170", "in cm or mm"),             # mm for m
])
def test_mass_inertia_and_arm_of_no_vehicle_name_the_likely_unit(tmp_path, capsys, old, new, unit):
    """A multirotor's largest moment of inertia lies near 0.15-0.55 x m L^2 (the motors alone,
    a quarter of the mass at L, give 0.25); a unit slip moves it by 1e3 or more: one error
    naming the unit, before any log is read (a blind audit's mass in grams was blamed on the
    rotor speeds' units)."""
    assert old in GOOD
    path = write(tmp_path, GOOD.replace(old, new))
    with pytest.raises(GreyboxInputError, match=re.escape(unit)):
        load_airframe(path)
    from greybox.cli import main
    assert main(["linearize", "--airframe", str(path), "--json", str(tmp_path / "lin.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and unit in err
    assert not (tmp_path / "lin.json").exists()
    # the shipped airframes and a Crazyflie's published numbers (27 g, 46 mm, 1.4e-5 / 2.2e-5) pass
    for name in ("paper.toml", "x_quad.toml"):
        load_airframe(Path(__file__).resolve().parents[1] / "greybox" / "data" / "airframes" / name)
    load_airframe(write(tmp_path, GOOD.replace("mass = 1.0", "mass = 0.027").replace("arm_length = 0.17",
                  "arm_length = 0.046").replace("[0.0082, 0.0082, 0.0149]", "[1.4e-5, 1.4e-5, 2.2e-5]")))


def test_a_mass_that_does_not_fit_the_inertia_and_arm_is_accepted_with_a_warning(tmp_path):
    """Jzz / (m L^2) is 0.52 here (0.0149 / (1 * 0.17^2)); motors and propellers at L hold it
    above 0.1 on any multirotor. Twenty times the mass gives 0.026 (a blind audit's Crazyflie
    file with ten times its mass, 0.033, was fitted with K_T and Kd ten times the truth
    without a word), a fifth of it 2.6: a warning that names the mass, not an error (it may
    be a dense vehicle)."""
    import warnings
    from greybox.errors import AirframeWarning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_airframe(write(tmp_path, GOOD.replace("mass = 1.0", "mass = 3.0")))      # 0.17: no word
    with pytest.warns(AirframeWarning, match=r"is 0\.026 x mass x L\^2 .* is the mass right"):
        af = load_airframe(write(tmp_path, GOOD.replace("mass = 1.0", "mass = 20.0")))
    assert af.mass == 20.0
    with pytest.warns(AirframeWarning, match=r"is 2\.6 x mass x L\^2 .* inertia too large"):
        load_airframe(write(tmp_path, GOOD.replace("mass = 1.0", "mass = 0.2")))
    # a unit (mass in grams) stays an error
    with pytest.raises(GreyboxInputError, match="mass in grams"):
        load_airframe(write(tmp_path, GOOD.replace("mass = 1.0", "mass = 1000.0")))

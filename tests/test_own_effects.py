"""Effects of your own are first-class (issue 14 item 1): registered by decorator, file or
entry point, used like catalogue effects by every command; what the code knows about an
effect lives on its class; the compile cache is keyed by what was compiled."""
from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest

import greybox
from greybox import codegen
from greybox import effects as fx
from greybox.cli import main
from greybox.errors import GreyboxInputError
from greybox.model import QuadrotorModel
from greybox.parameters import Parameter
from greybox.shooting import ShootingProblem

from conftest import AIRFRAMES

PAPER = str(AIRFRAMES / "paper.toml")

RATE_DAMPING = textwrap.dedent('''
    """A body-rate damping torque -k * omega, written against greybox's public Effect API."""
    from greybox.effects import Effect
    from greybox.parameters import Parameter


    class RateDamping(Effect):
        name = "rate_damping"
        summary = "body-rate damping torque -k_w * omega (per axis)"
        excited_by = "fast roll, pitch and yaw rates"
        channels = ("phi", "theta", "psi", "p", "q", "r")

        def parameters(self, airframe):
            return [Parameter(name="k_w", size=3, default=0.0, unit="N m s", lower=0.0, upper=1.0,
                              scale=1e-3, null=0.0, free=True, description="rate damping per body axis",
                              effect=self.name)]

        def plausible_values(self, airframe, K_T):
            return {"k_w": [0.02, 0.02, 0.01]}

        def add_forces(self, ctx):
            ctx.torque_body -= ctx.params["k_w"] * ctx.omega
''')


@pytest.fixture
def effect_file(tmp_path):
    """The file of a user effect, ``rate_damping``; whatever a test registers from it is
    forgotten after the test: the registry is process-wide, and a later test in the same
    run (the peer simulator's rate damping, which must stay outside the catalogue) would
    otherwise find it among the default candidates."""
    path = tmp_path / "rate_damping.py"
    path.write_text(RATE_DAMPING)
    yield path
    if "rate_damping" in fx.registered_effects():
        fx.unregister("rate_damping")


def test_register_decorator_and_clear_errors():
    @fx.register
    class SpinDown(fx.Effect):
        name = "test_spin_down"
        summary = "yaw damping -k*r"

        def parameters(self, airframe):
            return [Parameter("k_r", 1, 0.0, "N m s", 0.0, 1.0, 1e-3, 0.0, True, "yaw damping", self.name)]

        def add_forces(self, ctx):
            ctx.torque_body[2] -= ctx.params["k_r"] * ctx.omega[2]

    assert fx.known_effects()["test_spin_down"] is SpinDown
    model = QuadrotorModel(greybox.load_airframe(PAPER), ["yaw_torque", "test_spin_down"])
    assert "k_r" in model.param_names
    # a hand-checkable consequence: spinning at r = 2 rad/s with k_r = 0.01 decelerates at k_r r / J_z
    p = model.parameter_vector({"k_r": 0.01, "b": 0.0})
    x = np.zeros(model.nx)
    x[11] = 2.0
    rdot = float(np.asarray(model.rhs(x, np.zeros(4), p, 0)).ravel()[11])
    assert rdot == pytest.approx(-0.01 * 2.0 / model.airframe.inertia[2, 2])

    class Clash(fx.Effect):
        name = "ground_effect"
    with pytest.raises(GreyboxInputError, match="already taken"):
        fx.register(Clash)

    class Shouting(fx.Effect):
        name = "Wind2"
    with pytest.raises(GreyboxInputError, match="lowercase"):
        fx.register(Shouting)
    with pytest.raises(GreyboxInputError, match="effects-file"):
        fx.by_name("no_such_effect")


def test_a_parameter_name_is_one_effects_only(effect_file):
    """Parameters are named alike in the vector, [parameters], --set and JSON: an effect that
    reuses another's parameter name is refused when registered and when put in a model (the
    README's rate-damping example's ``k_w`` once was ``thrust_curve``'s too: a model with both
    had one ``k_w`` of the wrong size and failed deep inside CasADi)."""
    fx.load_effects_file(effect_file)
    af = greybox.load_airframe(PAPER)
    both = QuadrotorModel(af, ["yaw_torque", "rate_damping", "thrust_curve"])
    assert {"k_w[0]", "k_Tw"} <= set(both.param_names)
    xdot = np.asarray(both.rhs(both.initial_state(), [400.0] * 4, both.default_parameters(), 0.0)).ravel()
    assert np.all(np.isfinite(xdot))

    class DragAgain(fx.Effect):
        name = "test_drag_again"

        def parameters(self, airframe):
            return [Parameter("Kd", 3, 0.0, "N s/m", 0.0, 1.0, 1e-3, 0.0, True, "drag", self.name)]
    with pytest.raises(GreyboxInputError, match="'Kd' .*linear_drag"):
        fx.register(DragAgain)
    assert "test_drag_again" not in fx.known_effects()
    # not registered, put in a model directly: refused there, and not accepted as a candidate
    model = QuadrotorModel(af)
    assert not model.accepts(DragAgain())
    with pytest.raises(GreyboxInputError, match="effect 'linear_drag' and effect 'test_drag_again' both have .*'Kd'"):
        QuadrotorModel(af, list(model.effects) + [DragAgain()])


def test_effects_file_everywhere_on_the_command_line(effect_file, tmp_path, capsys):
    # listed, with its parameters
    assert main(["effects", "--effects-file", str(effect_file), "--json", str(tmp_path / "e.json")]) == 0
    listed = {e["name"]: e for e in json.loads((tmp_path / "e.json").read_text())["effects"]}
    assert listed["rate_damping"]["origin"] == str(effect_file)
    assert listed["rate_damping"]["parameters"][0]["name"] == "k_w"
    assert {"hub_rotor_drag", "ground_effect", "yaw_torque"} <= set(listed)
    # the disturbance models a fit warning advises (--effects disturbance_torque) are listed too
    assert listed["disturbance_torque"]["origin"] == "disturbance" and listed["held_moment"]["origin"] == "disturbance"
    assert listed["disturbance_torque"]["states"]
    # in an airframe's [parameters], with --effects and --set
    af = tmp_path / "af.toml"
    af.write_text(open(PAPER).read().replace("[parameters]\n", "[parameters]\nk_w = [0.01, 0.01, 0.005]\n"))
    assert main(["linearize", "--airframe", str(af), "--effects-file", str(effect_file), "--effects",
                 "rate_damping", "--set", "k_w=0.02,0.02,0.01", "--json", str(tmp_path / "lin.json")]) == 0
    lin = json.loads((tmp_path / "lin.json").read_text())
    assert lin["effects"][-1] == "rate_damping" and lin["parameters"]["k_w[2]"] == 0.01
    A = np.array(lin["A"])
    r = lin["states"].index("r")
    assert A[r, r] == pytest.approx(-0.01 / 0.034, rel=0.05) or A[r, r] < 0   # damping on r
    # a broken file: one line naming the file and the line
    bad = tmp_path / "bad.py"
    bad.write_text("from greybox.effects import Effect\n\nclass X(Effect):\n    name = 'x_eff'\n    oops(\n")
    capsys.readouterr()
    assert main(["effects", "--effects-file", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "line 5" in err[0]


def test_an_error_in_an_effect_files_hook_is_one_line_naming_the_file_line_and_hook(tmp_path, capsys):
    # the file loads and registers (its parameters describe themselves), but add_forces reads
    # a parameter it never declared: that shows only when a model is built (a blind audit got
    # a 31-line traceback and exit 1 from `greybox linearize`)
    path = tmp_path / "bad_hook.py"
    path.write_text(RATE_DAMPING.replace('ctx.params["k_w"]', 'ctx.params["nonexistent"]')
                    .replace('"rate_damping"', '"bad_hook"').replace('"k_w"', '"k_bad"'))
    out = tmp_path / "lin.json"
    try:
        capsys.readouterr()
        assert main(["linearize", "--airframe", PAPER, "--effects-file", str(path), "--effects", "bad_hook",
                     "--json", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        line = next(i for i, t in enumerate(RATE_DAMPING.splitlines(), 1) if "ctx.params" in t)
        assert len(err) == 1 and str(path) in err[0] and f"line {line}" in err[0]
        assert "add_forces()" in err[0] and "KeyError" in err[0] and "nonexistent" in err[0]
        assert not out.exists()
        # in Python the file's effect says the same
        with pytest.raises(GreyboxInputError, match=f"line {line}: effect 'bad_hook', add_forces"):
            QuadrotorModel(greybox.load_airframe(PAPER), [fx.by_name("bad_hook")]).output
    finally:
        if "bad_hook" in fx.registered_effects():
            fx.unregister("bad_hook")


@pytest.mark.slow    # about a minute; the file on every command is checked in the default run
def test_own_effect_is_ranked_first_on_a_flight_that_has_it(effect_file, tmp_path, capsys):
    """A flight with body-rate damping (the user's own effect, k_w as the file's plausible
    values): the diagnosis names it first, ahead of catalogue effects that also touch rates."""
    log = tmp_path / "damped.csv"
    assert main(["synth", "--airframe", PAPER, "--effects-file", str(effect_file), "--effects", "rate_damping",
                 "--duration", "24", "--rate", "200", "--vision-rate", "50", "--seed", "4",
                 "--manoeuvres", "hover,yaw,step_x,fast,step_y,yaw", "--out", str(log)]) == 0
    capsys.readouterr()
    assert main(["diagnose", str(log), "--airframe", PAPER, "--effects-file", str(effect_file), "--quiet",
                 "--candidates", "rate_damping,hub_rotor_drag,motor_lag,cog_offset", "--no-iterate",
                 "--json", str(tmp_path / "d.json")]) == 0
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["ranking"][0]["effect"] == "rate_damping" and d["ranking"][0]["significant"]
    assert d["verdict"] == "rate_damping"


def test_hub_rotor_drag_damps_rates_by_hand():
    af = greybox.load_airframe(AIRFRAMES / "x_quad.toml")
    m = QuadrotorModel(af) + fx.HubRotorDrag()
    p = m.parameter_vector({"k_rdh": 1e-4, "k_rdv": 2e-4, "b": 0.0, "Kd": 0.0, "J_r": 0.0})
    w = np.full(4, 300.0)
    x = np.zeros(m.nx)
    x[11] = 2.0                                        # yaw rate: in-plane hub velocities r * arm
    rdot = float(np.asarray(m.rhs(x, w, p, 0)).ravel()[11])
    assert rdot == pytest.approx(-1e-4 * 4 * 300 * af.arm_length ** 2 * 2.0 / af.inertia[2, 2], rel=1e-9)
    x = np.zeros(m.nx)
    x[9] = 3.0                                         # roll rate: axial hub velocities p * y_i
    pdot = float(np.asarray(m.rhs(x, w, p, 0)).ravel()[9])
    y = af.rotor_positions[:, 1]
    assert pdot == pytest.approx(-2e-4 * 300 * 3.0 * float((y ** 2).sum()) / af.inertia[0, 0], rel=1e-9)
    x = np.zeros(m.nx)
    x[6] = 1.0                                         # 1 m/s forward, level: the summed rotor_drag force
    ax = float(np.asarray(m.rhs(x, w, p, 0)).ravel()[6])
    assert ax == pytest.approx(-1e-4 * 4 * 300 / af.mass, rel=1e-9)



def test_hub_rotor_drag_above_the_centre_of_gravity_by_hand():
    """Hubs h above the CoG (body -z): flying forward, each hub's drag -w k [v, 0, 0] acts at
    (x_i, y_i, -h), torque (0, h w k v, y_i w k v): the nose pitches up by 4 h w k v / J_y,
    yaw cancels. Rolling at p, each hub moves sideways at p h: F_y = -w k p h at -h, a roll
    damping 4 w k h^2 p on top of the axial part's w k_rdv sum(y_i^2) p."""
    af = greybox.load_airframe(AIRFRAMES / "x_quad.toml")
    m = QuadrotorModel(af) + fx.HubRotorDrag()
    h, k, kv, w0 = 0.02, 1e-4, 2e-4, 300.0
    p = m.parameter_vector({"k_rdh": k, "k_rdv": kv, "h_hub": h, "b": 0.0, "Kd": 0.0, "J_r": 0.0})
    w = np.full(4, w0)
    x = np.zeros(m.nx)
    x[6] = 1.0                                         # 1 m/s forward, level
    xd = np.asarray(m.rhs(x, w, p, 0)).ravel()
    assert xd[10] == pytest.approx(4 * h * w0 * k * 1.0 / af.inertia[1, 1], rel=1e-9)
    assert xd[10] > 0                                   # nose up, against the airflow
    assert xd[9] == pytest.approx(0.0, abs=1e-12) and xd[11] == pytest.approx(0.0, abs=1e-12)
    x = np.zeros(m.nx)
    x[9] = 3.0                                         # roll rate
    xd = np.asarray(m.rhs(x, w, p, 0)).ravel()
    y = af.rotor_positions[:, 1]
    damping = w0 * 3.0 * (kv * float((y ** 2).sum()) + 4 * k * h ** 2)
    assert xd[9] == pytest.approx(-damping / af.inertia[0, 0], rel=1e-9)
    # the hubs' sideways drag in body y, seen in the world (level, psi = 0: y is east)
    assert xd[7] == pytest.approx(-4 * w0 * k * 3.0 * h / af.mass, rel=1e-9)
    # a drag of zero at any height is no drag: the height alone never makes the effect
    q = m.parameter_vector({"k_rdh": 0.0, "k_rdv": 0.0, "h_hub": h, "b": 0.0, "Kd": 0.0, "J_r": 0.0})
    assert np.allclose(np.asarray(m.rhs(x, w, q, 0)).ravel()[6:12],
                       np.asarray((QuadrotorModel(af)).rhs(x[:12], w, QuadrotorModel(af).parameter_vector(
                           {"b": 0.0, "Kd": 0.0, "J_r": 0.0}), 0)).ravel()[6:12])
    assert fx.HubRotorDrag.shape_parameters == ("h_hub",)

def test_compile_key_follows_effect_options_and_user_source(effect_file):
    """The compile cache is keyed by the function itself: another option value or an edited
    user effect is another library, the same model built twice is the same one."""
    af = greybox.load_airframe(PAPER)

    def lib(model):
        blk = ShootingProblem.step_functions(model, [0], 1)[0]
        return codegen.library_path(blk, "-O1")

    keys = [lib(QuadrotorModel(af) + fx.BatteryVoltage(v_ref=v)) for v in (4.0, 3.7)]
    assert keys[0] != keys[1]
    assert lib(QuadrotorModel(af) + fx.BatteryVoltage(v_ref=4.0)) == keys[0]
    fx.load_effects_file(effect_file)
    k1 = lib(QuadrotorModel(af, ["rate_damping"]))
    effect_file.write_text(RATE_DAMPING.replace("-= ctx.params", "-= 2 * ctx.params"))
    fx.load_effects_file(effect_file)
    k2 = lib(QuadrotorModel(af, ["rate_damping"]))
    assert k1 != k2


def test_hub_height_bounds_follow_the_rotors_when_the_airframe_gives_no_arm():
    """Explicit [[rotor]] tables may leave arm_length out: the airframe takes the rotors'
    distance from the centre, and the hub height's bounds and scale follow it (never a zero
    range)."""
    from greybox.airframe import airframe_from_dict
    rotors = [{"position": [0.2 * np.cos(a), 0.2 * np.sin(a), 0.0], "spin": 1 if k % 2 else -1}
              for k, a in enumerate(np.arange(6) * np.pi / 3)]
    af = airframe_from_dict({"airframe": {"name": "hex", "mass": 1.5, "inertia": [0.02, 0.02, 0.04]},
                             "rotor": rotors, "parameters": {"K_T": 2e-5}})
    h = next(p for p in fx.HubRotorDrag().parameters(af) if p.name == "h_hub")
    assert (h.lower, h.upper) == pytest.approx((-0.2, 0.2)) and h.scale == pytest.approx(0.05)


def test_drag_moment_and_hub_rotor_drag_are_told_apart_by_what_the_hubs_do():
    """With the hubs' height, hub_rotor_drag has drag_moment's moment too: what tells them apart
    is that the hubs' drag scales with the rotor speed and damps the rates (either order)."""
    for a, b in (("drag_moment", "hub_rotor_drag"), ("hub_rotor_drag", "drag_moment")):
        words = fx.distinguishing_manoeuvre(a, b)
        assert "different thrust levels" in words and "damp the rates" in words
        assert "plane of the centre of gravity" not in words

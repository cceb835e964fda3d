"""The fitter's per-sample step functions against the quantities they stand for, written out
independently: the state after one sample (RK4, ``n_sub`` sub-steps), the sensitivity
``d x_next / d (x, theta)`` times the incoming one, and the sample's Gauss-Newton terms
``J'J``, ``J'e`` and ``e*e`` from the Jacobian of the whole sample step taken in one piece."""
import casadi as ca
import numpy as np
import pytest

import greybox
from greybox import QuadrotorModel, codegen
from greybox import effects as fx
from greybox.integrate import Substeps, rk4_step
from greybox.model import OUTPUTS
from greybox.shooting import ShootingProblem

PAPER = greybox.__path__[0] + "/data/airframes/paper.toml"


def reference_blocks(model, free_idx, n_sub, args):
    """The sample's blocks from the Jacobian of the whole RK4 step (all sub-steps in one
    expression) and of the weighted residual, multiplied out with numpy."""
    x, S, H, g, c, u, t, h, ym, w, th, sc, pfix = args
    nx = model.nx
    xs = ca.SX.sym("x", nx)
    ts = ca.SX.sym("th", len(free_idx))
    p = ca.SX(ca.DM(pfix))
    for i, k in enumerate(free_idx):
        p[k] = ts[i] * sc[i]
    xn = rk4_step(model, n_sub)(xs, u, p, t, h)
    d = ym - model.output(xs, u, p, t)
    psi = OUTPUTS.index("psi")
    d[psi] = ca.atan2(ca.sin(d[psi]), ca.cos(d[psi]))
    e = w * d
    z = ca.vertcat(xs, ts)
    f = ca.Function("ref", [xs, ts], [xn, ca.jacobian(xn, z), e, ca.jacobian(e, z)])
    xn_v, Jx, e_v, Je = (np.asarray(a) for a in f(x, th))
    E = np.vstack([S, np.hstack([np.zeros((len(free_idx), nx)), np.eye(len(free_idx))])])
    Sn = Jx @ E
    Jes = Je @ E
    return [xn_v.ravel(), Sn, H + Jes.T @ Jes, g + Jes.T @ e_v.ravel(), c + e_v.ravel() ** 2]


def sample_args(model, free_idx, rng, h):
    """A sample's arguments of the blocks function: a moving state with rotors near 500 rad/s,
    a random sensitivity and accumulated blocks, a yaw measured one turn on, step ``h``."""
    nx, nth, ny = model.nx, len(free_idx), model.ny
    nz = nx + nth
    p = model.default_parameters()
    sc = np.where(p[free_idx] != 0, p[free_idx], 1e-2)
    x = np.zeros(nx)
    x[:12] = rng.normal(size=12) * [1, 1, 1, .3, .3, 3, 1, 1, 1, 2, 2, 2]
    x[12:] = 500.0 + rng.normal(size=nx - 12) * 20
    u = 500.0 + rng.normal(size=model.nu) * 30
    ym = np.zeros(ny)
    ym[:12] = x[:12] + rng.normal(size=12) * 0.05
    ym[5] += 2 * np.pi                   # a yaw measured one turn on: the residual is wrapped
    J = rng.normal(size=(2 * nz, nz))
    return [x, rng.normal(size=(nx, nz)), J.T @ J, rng.normal(size=nz), rng.uniform(size=ny),
            u, 0.3, h, ym, rng.uniform(1, 10, size=ny), 1.0 + 0.1 * rng.normal(size=nth), sc, p]


def value_args(args):
    """The value function's arguments from the blocks function's (``sample_args``)."""
    x, S, H, g, c, u, t, h, ym, w, th, sc, p = args
    return (x, c, u, t, h, ym, w, th, sc, p)


@pytest.mark.parametrize("effects,n_sub", [([], 1), (["motor_lag", "drag_moment"], 3),
                                           (["moment_gain", "battery_voltage"], 4)])
def test_step_blocks_equal_the_jacobian_of_the_whole_step(effects, n_sub):
    af = greybox.load_airframe(PAPER)
    model = QuadrotorModel(af) + [fx.by_name(e) for e in effects]
    rng = np.random.default_rng(3)
    free_idx = sorted(rng.choice(model.n_params, size=min(5, model.n_params), replace=False).tolist())
    args = sample_args(model, free_idx, rng, 0.004)
    blk, val = ShootingProblem.step_functions(model, free_idx, n_sub)
    got = [np.asarray(a) for a in blk(*args)]
    want = reference_blocks(model, free_idx, n_sub, args)
    for a, b in zip(got, want):
        np.testing.assert_allclose(a.reshape(np.shape(b)), b, rtol=1e-9, atol=1e-9 * np.abs(b).max())
    assert np.array_equal(got[2], got[2].T)          # J'J assembled symmetric
    xn_v, c_v = (np.asarray(a).ravel() for a in val(*value_args(args)))
    np.testing.assert_allclose(xn_v, want[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(c_v, want[4], rtol=1e-12)


@pytest.mark.parametrize("h,n_sub", [(0.004, 2), (0.0075, 4), (0.012, 6)])
def test_a_long_steps_blocks_take_the_substeps_of_its_branch(h, n_sub):
    """A log with dropped rows: a sample's blocks over a step of 4 ms take 2 sub-steps, over
    7.5 ms 4, over 12 ms 6 -- each as the unbranched step functions with that count."""
    af = greybox.load_airframe(PAPER)
    model = QuadrotorModel(af) + fx.by_name("motor_lag")
    free_idx = [0, 1, model.param_names.index("tau_m")]
    args = sample_args(model, free_idx, np.random.default_rng(5), h)
    blk, val = ShootingProblem.step_functions(model, free_idx, Substeps(2, 6))
    blk_n, val_n = ShootingProblem.step_functions(model, free_idx, n_sub)
    got = [np.asarray(a) for a in blk(*args)]
    want = [np.asarray(a) for a in blk_n(*args)]
    for a, b in zip(got, want):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13 * np.abs(b).max())
    np.testing.assert_allclose(got[0].ravel(), reference_blocks(model, free_idx, n_sub, args)[0], rtol=1e-12)
    for a, b in zip(val(*value_args(args)), val_n(*value_args(args))):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-13, atol=1e-13)


def test_code_size_counts_the_functions_an_mx_graph_calls_once():
    x = ca.SX.sym("x", 3)
    f = ca.Function("f", [x], [ca.sin(x) * x])
    X = ca.MX.sym("X", 3)
    g = ca.Function("g", [X], [f(f(X)) + X])
    assert codegen.code_size(f) == f.n_instructions()
    assert codegen.code_size(g) == g.n_instructions() + f.n_instructions()


def test_code_size_counts_a_conditionals_branches_and_what_they_call_once():
    x = ca.SX.sym("x", 3)
    f = ca.Function("f", [x], [ca.sin(x) * x])
    X = ca.MX.sym("X", 3)
    once = ca.Function("once", [X], [f(X)])
    twice = ca.Function("twice", [X], [f(f(X))])
    switch = ca.Function.conditional("switch", [once], twice)
    k = ca.MX.sym("k")
    g = ca.Function("g", [k, X], [switch(k, X)])
    assert codegen.code_size(g) == (g.n_instructions() + once.n_instructions() + twice.n_instructions()
                                    + f.n_instructions())


def test_code_size_of_a_branched_step_counts_the_rk4_it_repeats():
    """A branched step (dropped rows) is an MX wrapper around the SX RK4 step it repeats:
    its size is at least the RK4 step's (a wrapper of the same name as its callee once hid
    it: 34 instructions counted for 2132, compiles started nine times too early)."""
    model = QuadrotorModel(greybox.load_airframe(PAPER))
    plain = rk4_step(model, 4)
    branched = rk4_step(model, Substeps(4, 8))
    assert codegen.code_size(branched) > codegen.code_size(plain)
    val_plain = ShootingProblem.step_functions(model, [0, 1], 4)[1]
    val_branched = ShootingProblem.step_functions(model, [0, 1], Substeps(4, 8))[1]
    assert codegen.code_size(val_branched) > codegen.code_size(val_plain)


@pytest.mark.filterwarnings("ignore::greybox.errors.ConvergenceWarning")
def test_the_diagnosis_queues_the_very_functions_its_refits_run(tmp_path, monkeypatch):
    """The step functions the diagnosis queues for compiling ahead of a round's refits are
    the objects the refits' problems use (built once; the library names agree)."""
    from greybox.diagnosis.screening import queue_refit_builds
    monkeypatch.setenv("GREYBOX_CACHE", str(tmp_path))
    queued = []
    monkeypatch.setattr(codegen, "queue_builds", lambda fs, opt="-O1": queued.extend(fs))
    log = greybox.load_log(greybox.__path__[0] + "/data/logs/demo_ground_effect.csv").split(0.3)[0]
    model = QuadrotorModel(greybox.load_airframe(PAPER))
    res = greybox.fit(model, log, compile="never", max_iter=3, process_noise=None)
    queue_refit_builds(model, res, ["motor_lag"], 2)
    ext = model + fx.by_name("motor_lag")
    free_idx = [ext.param_names.index(n) for n in res.free_names + ["tau_m"]]
    shared = ShootingProblem.shared_step_functions(ext, sorted(free_idx), 2)
    assert shared["blocks"] in queued and shared["value"] in queued
    assert ShootingProblem.shared_step_functions(ext, [], 2)["blocks"] in queued
    # a validation log with a dropped row predicts with its own plan: queued too
    queued.clear()
    queue_refit_builds(model, res, ["motor_lag"], 2, [Substeps(2, 2), Substeps(2, 6)])
    assert ShootingProblem.shared_step_functions(ext, [], Substeps(2, 6))["blocks"] in queued
    assert ShootingProblem.shared_step_functions(ext, [], 2)["blocks"] in queued
    # the refit's problem builds nothing again
    monkeypatch.setattr(ShootingProblem, "step_functions",
                        staticmethod(lambda *a: pytest.fail("step functions built a second time")))
    ShootingProblem(ext, sorted(free_idx), 10, 2, "never")

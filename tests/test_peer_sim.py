"""The second independent simulator (tests/peer_sim.py) and what greybox makes of its flights.

The simulator's physics is checked by hand (signs, frames, conservation) before greybox is
judged on it. Then: a log with exact time stamps and rotor speeds fits at the sensor noise in
output error, K_T and b exact; the same flight with time stamps jittered by a tenth of a sample
period (as a logger's are) cannot be followed by an open-loop unstable body in output error,
and ``fit`` then solves with process noise, certified, at the noise, K_T and b within 1 %.
"""
import math
from pathlib import Path

import numpy as np
import pytest

from greybox import FlightLog, QuadrotorModel, denoise_inputs, load_airframe, load_log
from greybox.airframe import rotors_for_layout
from greybox.effects import AttitudeBias, by_name
from greybox.diagnosis import diagnose
from greybox.diagnosis.consistency import half_spread, validation_spread
from greybox.fitting import fit

from peer_sim import (PeerBattery, PeerDynamics, PeerEffects, PeerSensors, PeerVehicle, airframe_text, fly,
                      quat_to_rot, rot_to_euler, write_case)

HERE = Path(__file__).resolve().parent


def test_independent_of_greybox():
    src = (HERE / "peer_sim.py").read_text()
    assert "import greybox" not in src and "from greybox" not in src


def _hover_state(veh, w=None):
    s = np.zeros(17)
    s[6] = 1.0
    s[2] = -1.0
    s[13:17] = veh.w_hover if w is None else w
    return s


def test_hover_balances_gravity_and_torques_by_hand():
    veh = PeerVehicle.one_kg()
    dyn = PeerDynamics(veh, PeerEffects(), np.random.default_rng(0))
    acc, M = dyn.loads(_hover_state(veh))
    assert np.allclose(acc, 0.0, atol=1e-12) and np.allclose(M, 0.0, atol=1e-12)
    # front-left rotor (4, at (+a, -a)) faster by dT: roll moment +a dT (right side down, FRD),
    # pitch moment +a dT (nose up), yaw moment spin_4 b dw^2 = +b dw^2
    w = np.full(4, veh.w_hover)
    w[3] *= 1.1
    dT = veh.K_T * (w[3] ** 2 - veh.w_hover ** 2)
    a = veh.arm / math.sqrt(2)
    _, M = dyn.loads(_hover_state(veh, w))
    assert M == pytest.approx([a * dT, a * dT, veh.b * (w[3] ** 2 - veh.w_hover ** 2)], rel=1e-9)
    # more thrust accelerates up: world z (down) negative
    acc, _ = dyn.loads(_hover_state(veh, w))
    assert acc[2] == pytest.approx(-dT / veh.mass, rel=1e-9)


@pytest.mark.slow
def test_the_cascaded_pid_flies_on_what_the_vehicle_measures_and_holds_a_weak_rotor_where_its_moment_cancels():
    """The second controller (an autopilot's cascade) reads the gyro with its noise, so its
    commands carry that noise (the geometric controller's do not: it reads the true state);
    in the first 1.5-s hold a rotor at 90 % thrust is driven 1/sqrt(0.9) = 1.054 times as fast
    as the others (zero moment: its thrust equals theirs), whichever controller trims it; the
    flights differ by the controller alone (the seed's other draws are the same); an unknown
    controller is refused."""
    weak = PeerEffects(motor_gains=[1.0, 1.0, 0.9, 1.0])
    speeds = {}
    for controller in ("geometric", "cascaded_pid"):
        for noise in (0.0, 0.005):
            veh = PeerVehicle.one_kg(log_rate=250.0, gyro_noise=noise)
            f = fly(veh, duration=3.0, seed=3, effects=weak, low_hovers=False, controller=controller)
            speeds[controller, noise] = w = np.column_stack([f.columns[f"w{i}"] for i in range(1, 5)])
            hold = f.columns["t"] < 1.4
            assert np.median(w[hold, 2] / w[hold, 0]) == pytest.approx(1 / math.sqrt(0.9), rel=0.003)
            assert np.median(w[hold, 2] / w[hold, 1]) == pytest.approx(1 / math.sqrt(0.9), rel=0.003)
            assert f.truth["controller"] == controller
    assert np.array_equal(speeds["geometric", 0.0], speeds["geometric", 0.005])
    assert not np.allclose(speeds["cascaded_pid", 0.0], speeds["cascaded_pid", 0.005], rtol=1e-6, atol=0)
    # the controller alone differs: the same seed's other draws (its model errors, the time stamps)
    a, b = (fly(PeerVehicle.one_kg(log_rate=250.0), duration=1.0, seed=3, controller=c)
            for c in ("geometric", "cascaded_pid"))
    assert a.truth["controller_model"] == b.truth["controller_model"]
    assert np.array_equal(a.columns["t"], b.columns["t"])
    with pytest.raises(ValueError, match="controller"):
        fly(PeerVehicle.one_kg(), duration=1.0, controller="lqr")


def test_slung_load_hangs_on_its_weight_and_swings_as_a_pendulum():
    """By hand: hanging at rest below a hovering vehicle, the cable pulls it down by the load's
    weight (the rotors at the hover speed of vehicle and load together hold both still); under
    a vehicle too heavy to move, a load pushed 0.1 rad aside swings with the period
    2 pi sqrt(L / g) of a pendulum and pulls the vehicle sideways by m_L g sin(angle)."""
    from dataclasses import replace
    m_l, length = 0.1, 0.5
    veh = PeerVehicle.one_kg()
    fx = PeerEffects(slung_load=[m_l, length])
    dyn = PeerDynamics(veh, fx, np.random.default_rng(0))
    g = veh.gravity
    w_both = math.sqrt((veh.mass + m_l) * g / (4 * veh.K_T))
    s = np.concatenate([_hover_state(veh, np.full(4, w_both)), [0.0, 0.0, -1.0 + 1.005 * length], np.zeros(3)])
    assert dyn.cable_force(s) == pytest.approx([0.0, 0.0, m_l * g], rel=1e-12)
    rhs = dyn.rhs(s, np.full(4, w_both))
    assert np.allclose(rhs[3:6], 0.0, atol=1e-12) and np.allclose(rhs[20:23], 0.0, atol=1e-12)
    # slack (the load above its cable's length): no pull at all
    s_slack = s.copy()
    s_slack[19] = -1.0 + 0.9 * length
    assert np.all(dyn.cable_force(s_slack) == 0.0)
    # a pendulum under a 1000-kg vehicle held up by its rotors
    heavy = replace(veh, mass=1000.0)
    dyn = PeerDynamics(heavy, fx, np.random.default_rng(0))
    w_heavy = np.full(4, math.sqrt((heavy.mass + m_l) * g / (4 * heavy.K_T)))
    angle0 = 0.1
    stretched = length + m_l * g * math.cos(angle0) / (m_l * g / (0.005 * length))
    s = np.concatenate([_hover_state(heavy, w_heavy),
                        [stretched * math.sin(angle0), 0.0, -1.0 + stretched * math.cos(angle0)], np.zeros(3)])
    f0 = dyn.cable_force(s)
    assert f0[0] == pytest.approx(m_l * g * math.sin(angle0), rel=0.01)
    dt, x = 1e-3, []
    for _ in range(3000):
        x.append(s[17] - s[0])
        s = dyn.rk4(s, w_heavy, dt)
    x = np.array(x)
    up = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))          # upward zero crossings
    period = float(np.mean(np.diff(up))) * dt
    assert period == pytest.approx(2 * math.pi * math.sqrt(length / g), rel=0.01)


def test_quaternion_rotation_and_euler_angles_agree_with_zyx():
    phi, theta, psi = 0.3, -0.2, 1.1
    cz, sz, cy, sy, cx, sx = math.cos(psi), math.sin(psi), math.cos(theta), math.sin(theta), math.cos(phi), math.sin(phi)
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    R = Rz @ Ry @ Rx
    # the quaternion of R (Shepperd), back through quat_to_rot
    w = 0.5 * math.sqrt(1 + np.trace(R))
    q = np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])
    assert np.allclose(quat_to_rot(q), R, atol=1e-12)
    assert rot_to_euler(R) == pytest.approx((phi, theta, psi), abs=1e-12)


def test_free_rotation_conserves_angular_momentum_and_energy():
    """No thrust, no gravity effects on the rotation: RK4 on the quaternion keeps the body's
    world-frame angular momentum and its kinetic energy."""
    veh = PeerVehicle.one_kg(rotor_inertia=0.0)
    dyn = PeerDynamics(veh, PeerEffects(), np.random.default_rng(0))
    s = _hover_state(veh, w=np.zeros(4))
    s[10:13] = [1.0, 0.2, -0.7]
    J = veh.J

    def invariants(s):
        R = quat_to_rot(s[6:10])
        om = s[10:13]
        return R @ (J @ om), 0.5 * om @ J @ om
    L0, E0 = invariants(s)
    for _ in range(2000):
        s = dyn.rk4(s, np.zeros(4), 1e-3)
    L1, E1 = invariants(s)
    assert np.allclose(L1, L0, rtol=1e-7, atol=1e-12) and E1 == pytest.approx(E0, rel=1e-7)


def test_rotor_drag_at_the_hubs_damps_yaw_rate():
    """The peer simulator's rotor drag acts on each hub's own velocity, omega x r_i included:
    a yawing vehicle feels a yaw moment against its rate, -k sum(w_i) |r_i|^2 r (hubs in the
    rotor plane of the CoG)."""
    veh = PeerVehicle.crazyflie(hub_height=0.0)
    k = 1e-6
    dyn = PeerDynamics(veh, PeerEffects(rotor_drag=k), np.random.default_rng(0))
    s = _hover_state(veh)
    s[12] = 2.0
    _, M = dyn.loads(s)
    assert M[2] == pytest.approx(-k * 4 * veh.w_hover * veh.arm ** 2 * 2.0, rel=1e-9)


def test_ground_effect_is_cheeseman_bennett_per_rotor():
    veh = PeerVehicle.one_kg(hub_height=0.0)
    dyn = PeerDynamics(veh, PeerEffects(ground_effect=True), np.random.default_rng(0))
    s = _hover_state(veh)
    s[2] = -0.2                                      # 0.2 m above the floor
    acc, _ = dyn.loads(s)
    factor = 1 / (1 - (veh.rotor_radius / (4 * 0.2)) ** 2)
    assert -acc[2] + veh.gravity == pytest.approx(veh.gravity * factor, rel=1e-9)


def test_battery_sags_with_current_and_open_loop_motors_follow_its_voltage():
    """The battery by hand: at hover the rotors draw ``4 b w^3 / efficiency`` watts, so the
    voltage is the root of ``V^2 - V_oc V + r P = 0``; a motor commanded to the hover speed
    spins at it where the battery gives the ESC's voltage, and slower below it (the DC
    motor's quadratic ``Ke w + c w^2 = duty V``), by about ``dV / ((1 + load_share) V)``."""
    veh = PeerVehicle.crazyflie()
    bat = PeerBattery(v_full=4.1, r_int=0.2, v_esc=3.8, efficiency=0.5, load_share=0.5)
    dyn = PeerDynamics(veh, PeerEffects(battery=bat), np.random.default_rng(0))
    w = np.full(4, veh.w_hover)
    power = 4 * veh.b * veh.w_hover ** 3 / 0.5
    v, current = dyn.battery_voltage(w)
    assert v * v - 4.1 * v + 0.2 * power == pytest.approx(0.0, abs=1e-12)
    assert current == pytest.approx(power / v, rel=1e-12) and 3.5 < v < 4.1
    dyn.charge = (4.1 - 3.8 - 0.2 * power / 3.8) / bat.drain    # open-circuit voltage down to 3.8 + r I(3.8 V)
    v, _ = dyn.battery_voltage(w)
    assert v == pytest.approx(3.8, abs=1e-9)
    assert dyn.motor_target(w, w) == pytest.approx(w, rel=1e-12)
    dyn.charge += 0.1 / bat.drain                                 # 0.1 V lower
    v2, _ = dyn.battery_voltage(w)
    slower = dyn.motor_target(w, w) / w - 1.0
    assert slower == pytest.approx((v2 / 3.8 - 1.0) / 1.5, rel=0.02) and np.all(slower < 0)
    assert dyn.hover_speed_ratio(v2) == pytest.approx(1.0 + slower[0], rel=1e-12)


@pytest.mark.slow
def test_longer_steps_certify_a_fit_that_full_steps_take_hundreds_of_iterations_to(tmp_path):
    """Gauss-Newton converges linearly on a large-residual fit: a motor lag refitted on a flight
    whose logged commands drive motors that also follow the sagging battery (which the model
    lacks) took 0.2 of cost per full step for 400 steps and ended uncertified. Longer steps
    along the Gauss-Newton direction while the cost keeps falling (``GaussNewton``'s
    ``extrapolate``) reach a certified optimum, at a cost no higher, in a fraction of the
    iterations; with them off the same budget ends short."""
    import warnings
    from greybox import ConvergenceWarning
    from greybox.fitting import GaussNewton
    flight = fly(PeerVehicle.crazyflie(log_rate=100.0), duration=12.0, seed=1,
                 effects=PeerEffects(battery=PeerBattery()), sensors=PeerSensors(log_commands=True))
    paths = write_case(flight, tmp_path, name="s1")
    model, log = QuadrotorModel(load_airframe(paths["airframe"])), load_log(paths["log"])
    base = fit(model, log, process_noise="auto")
    assert base.converged and base.process_noise is not None
    lagged = model + by_name("motor_lag")
    # the diagnosis's rule for a candidate's new states: a random walk over the flight below
    # 1e-4 of the hover speed, so the lag must explain the data through its physics
    q = dict(base.process_noise, **{s: 1e-4 * base.model.hover_speed(base.p) / math.sqrt(len(log.t))
                                    for s in lagged.state_names if s.startswith("w_eff")})
    p0 = lagged.parameter_vector(base.model.parameter_dict(base.p), lagged.default_parameters())
    runs = {}
    for label, solver in (("longer", GaussNewton()), ("full", GaussNewton(extrapolate=1.0))):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            runs[label] = fit(lagged, log, p0=p0, noise=base.sigma, reweight=False, max_iter=150,
                              interval=base.interval, process_noise=q, solver=solver)
    longer, full = runs["longer"], runs["full"]
    assert longer.converged, longer.status
    assert not full.converged and "maximum iterations" in full.status, full.status
    assert longer.cost <= full.cost + 1e-6 * full.cost
    assert longer.iterations < 0.8 * 150
    assert 0.01 < longer.value("tau_m") < 0.025


@pytest.fixture(scope="module")
def cf_flights(tmp_path_factory):
    """A 30 g vehicle, 20 s at 500 Hz: once with exact time stamps, once jittered."""
    d = tmp_path_factory.mktemp("peer")
    out = {}
    for label, jitter in (("exact", 0.0), ("jittered", 0.1)):
        fl = fly(PeerVehicle.crazyflie(), duration=20.0, seed=1, sensors=PeerSensors(time_jitter=jitter))
        out[label] = (write_case(fl, d / label), fl.truth["greybox_equivalent"])
    return out


@pytest.mark.slow
def test_log_is_read_as_a_users_file(cf_flights):
    paths, _ = cf_flights["jittered"]
    log = load_log(paths["log"])
    dt = np.diff(log.t)
    assert log.input_names == ["w1", "w2", "w3", "w4"]
    assert 0.9 * 0.002 < dt.min() < dt.max() < 1.1 * 0.002           # jittered, still increasing
    measured = np.isfinite(log.output("x")).mean()
    assert 0.15 < measured < 0.2            # 100 Hz of 500 Hz, 5 % lost and a 0.4 s stretch


def test_exact_log_fits_at_the_noise_in_output_error(cf_flights):
    paths, truth = cf_flights["exact"]
    model = QuadrotorModel(load_airframe(paths["airframe"]))
    est, _ = load_log(paths["log"]).split(0.8)
    res = fit(model, est, process_noise=None)
    assert res.converged and res.certificate.adequate, res.certificate.text()
    assert res.value("K_T") == pytest.approx(truth["K_T"], rel=0.005)
    assert res.value("b") == pytest.approx(truth["b"], rel=0.005)


def test_jittered_time_stamps_make_fit_use_process_noise(cf_flights):
    """A tenth of a sample period of jitter is a random torque impulse at every sample; the
    body integrates it, and output error cannot follow (certified, far above the noise). The
    default fit sees that and solves with process noise: certified, at the noise, K_T and b
    within 1 %."""
    paths, truth = cf_flights["jittered"]
    model = QuadrotorModel(load_airframe(paths["airframe"]))
    est, _ = load_log(paths["log"]).split(0.8)
    strict = fit(model, est, process_noise=None)
    assert not strict.certificate.adequate                 # what the default has to catch
    res = fit(model, est)
    assert res.process_noise is not None and res.converged
    assert res.certificate.adequate, res.certificate.text()
    assert any("fitted with process noise" in w for w in res.warnings)
    assert res.value("K_T") == pytest.approx(truth["K_T"], rel=0.01)
    assert res.value("b") == pytest.approx(truth["b"], rel=0.01)
    assert res.init_window in (0.05, 0.1, 0.2, 0.5)


@pytest.mark.parametrize("k_t_factor, duration, seed", [(1.4, 6.0, 1), pytest.param(0.6, 6.0, 1, marks=pytest.mark.slow),
                                                          (1.4, 8.0, 3)])
@pytest.mark.slow
def test_a_fit_that_lets_the_thrust_go_is_started_again_where_the_rotors_carry_the_weight(tmp_path, k_t_factor,
                                                                                          duration, seed):
    """A 6-s flight of the 30 g vehicle with 1 % noise on its logged speeds, started with K_T
    40 % off: output error cannot follow, and process noise started at the size of the vertical
    gaps that start leaves lets the noise pull K_T down (60-80 % low, certified). The fit sees
    its thrust far from the weight, starts again from K_T where the rotors carry it, and keeps
    that fit: K_T within 2 % of the truth (the first one's value in its warning). An 8-s flight
    ends 19 % low, its speeds as logged (11 % low) or smoothed: inside the 20 % the restart
    once waited for, with a validation z nrmse of 82 (tilt now counted, 10 %)."""
    fl = fly(PeerVehicle.crazyflie(), duration=duration, seed=seed, sensors=PeerSensors(speed_noise=0.01))
    paths = write_case(fl, tmp_path, K_T_factor=k_t_factor)
    model = QuadrotorModel(load_airframe(paths["airframe"]))
    est, _ = load_log(paths["log"]).split(0.8)
    res = fit(model, est)
    assert res.converged, res.status
    assert res.value("K_T") == pytest.approx(fl.truth["greybox_equivalent"]["K_T"], rel=0.02)
    restart = [w for w in res.warnings if w.startswith("started again from K_T")]
    assert restart and "% of the weight" in restart[0]
    assert not any("of the weight on average" in w for w in res.warnings)     # no thrust warning left


@pytest.mark.slow
def test_a_filtered_attitude_is_the_sensors_error_and_output_error_stays(tmp_path):
    """The 30 g vehicle with exact time stamps, its attitude logged as an estimator gives it
    (the error correlated over 50 ms): the output-error fit is right but its attitude
    residuals stand several times above the high-frequency noise estimate. The gyro does not
    share them (not motion), so the fit keeps output error, and K_T and b come out within
    0.05 %."""
    fl = fly(PeerVehicle.crazyflie(), duration=20.0, seed=1, sensors=PeerSensors(time_jitter=0.0, att_correlation=0.05))
    paths, truth = write_case(fl, tmp_path), fl.truth["greybox_equivalent"]
    model = QuadrotorModel(load_airframe(paths["airframe"]))
    est, _ = load_log(paths["log"]).split(0.8)
    res = fit(model, est)
    assert res.converged and res.process_noise is None, res.warnings
    off = set(res.certificate.off_channels())
    assert off and off <= {"phi", "theta", "psi"} and set(res.certificate.sensor_error) == off, res.certificate.text()
    assert res.value("K_T") == pytest.approx(truth["K_T"], rel=5e-4)
    assert res.value("b") == pytest.approx(truth["b"], rel=5e-4)


def test_airframe_text_is_what_greybox_reads(tmp_path):
    veh = PeerVehicle.crazyflie()
    p = tmp_path / "a.toml"
    p.write_text(airframe_text(veh, K_T_factor=1.0, b_factor=1.0))
    af = load_airframe(p)
    model = QuadrotorModel(af)
    pd = model.parameter_dict(model.default_parameters())
    assert pd["K_T"] == pytest.approx(veh.K_T) and pd["b"] == pytest.approx(veh.b)
    assert af.mass == veh.mass


# frames that are no square X (experiments/diagnose_peer_sim.py flies the same three)
FRAMES = {"deadcat_racer": PeerVehicle.deadcat_racer, "h_frame_1kg": PeerVehicle.h_frame_1kg,
          "px4_order_1kg": PeerVehicle.px4_order_1kg}


@pytest.mark.parametrize("frame", list(FRAMES))
def test_a_frame_that_is_no_square_x_turns_as_its_rotor_tables_say(tmp_path, frame):
    """The airframe the simulator writes puts each rotor where the simulator flies it: the body
    rates' derivatives of greybox's model equal the simulator's for the same rotor speeds, and
    by hand, one rotor spun up from hover on the dead cat's wide front-right arm (0.10 m to the
    right)
    rolls the vehicle left at K_T dw^2 0.10 / J_x and yaws it by its spin's sign."""
    veh = FRAMES[frame]()
    p = tmp_path / "a.toml"
    p.write_text(airframe_text(veh, K_T_factor=1.0, b_factor=1.0))
    model = QuadrotorModel(load_airframe(p))
    assert np.allclose(model.airframe.rotor_positions[:, :2], np.asarray(veh.rotor_xy))
    assert np.array_equal(model.airframe.spins, veh.spins)
    if frame == "px4_order_1kg":
        # PX4's quad X is greybox's layout "x": the same rotors, positions and spins, in order
        x = rotors_for_layout("x", 0.225)
        assert np.allclose(model.airframe.rotor_positions, [r.position for r in x])
        assert list(model.airframe.spins) == [r.spin for r in x]
    dyn = PeerDynamics(veh, PeerEffects(), np.random.default_rng(0))
    rng = np.random.default_rng(1)
    for _ in range(3):
        w = veh.w_hover * (1 + 0.2 * rng.standard_normal(4))
        s = np.zeros(17)
        s[2], s[6], s[13:17] = -1.0, 1.0, w            # level, at rest, the rotors at w
        peer_omdot = dyn.rhs(s, w)[10:13]
        x = np.zeros(model.nx)
        x[2] = -1.0
        gb = np.asarray(model.rhs(x, w, model.default_parameters(), 0.0)).ravel()
        assert np.allclose(gb[9:12], peer_omdot, rtol=1e-9, atol=1e-9 * np.abs(peer_omdot).max())
    if frame == "deadcat_racer":
        w = np.full(4, veh.w_hover)
        w[0] = veh.w_hover * 1.1
        x = np.zeros(model.nx)
        x[2] = -1.0
        gb = np.asarray(model.rhs(x, w, model.default_parameters(), 0.0)).ravel()
        dw2 = (1.21 - 1.0) * veh.w_hover ** 2
        assert gb[9] == pytest.approx(-veh.K_T * dw2 * 0.10 / veh.inertia[0], rel=1e-9)   # right arm up: roll left
        assert gb[10] == pytest.approx(veh.K_T * dw2 * 0.075 / veh.inertia[1], rel=1e-9)  # front arm up: nose up
        assert gb[11] == pytest.approx(-veh.b * dw2 / veh.inertia[2], rel=1e-9)            # spin -1


@pytest.mark.slow
def test_frames_that_are_no_square_x_are_diagnosed_as_flown(tmp_path):
    """The dead-cat racer with nothing missing is null, nothing unexplained; the 1.2 kg square X
    with its rotors in PX4's order (front-right, back-left, front-left, back-right; greybox's
    layout "x") and the third of them, front-left, at 90 % is ``motor_asymmetry`` with that
    rotor the weak one (its deviation -0.077 from the rotors' mean, every deviation within 3 std
    of the truth's). K_T and b within 1 % on both (they come out within 0.1 %)."""
    for frame, effects, seeds in (("deadcat_racer", PeerEffects(), (1, 2)),
                                  ("px4_order_1kg", PeerEffects(motor_gains=[1.0, 1.0, 0.9, 1.0]), (1, 2))):
        veh = FRAMES[frame]()
        flights = [fly(veh, duration=20.0, seed=s, effects=effects) for s in seeds]
        paths = [write_case(f, tmp_path / frame, name=f"seed{s}") for f, s in zip(flights, seeds)]
        model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
        (est, _), (val, _) = (denoise_inputs(model, load_log(p["log"])) for p in paths)
        d = diagnose(model, est, validation=val)
        truth = flights[0].truth["greybox_equivalent"]
        final = d.final_fit or d.baseline
        assert d.baseline_certified, (frame, d.summary())
        assert final.value("K_T") == pytest.approx(truth["K_T"], rel=0.01), frame
        assert final.value("b") == pytest.approx(truth["b"], rel=0.01), frame
        if frame == "deadcat_racer":
            assert d.verdict is None and not d.unexplained and not d.unexplained_gaps, d.summary()
            continue
        assert d.verdict == "motor_asymmetry", d.summary()
        devs = [final.value(f"K_T_dev[{i}]") for i in range(3)]
        assert int(np.argmin(devs + [-sum(devs)])) == 2
        for i in range(3):
            std = final.std[final.free_names.index(f"K_T_dev[{i}]")]
            assert abs(devs[i] - truth["K_T_dev"][i]) < 3 * std, (i, devs[i], truth["K_T_dev"][i], std)


@pytest.mark.slow
def test_a_swinging_slung_load_leaves_systematic_velocity_gaps(tmp_path):
    """A 0.1-kg load on a 0.5-m cable under the 1.2 kg vehicle (logged at 200 Hz; the airframe
    carries both masses, as a user weighs them): the cable's pull is a force no effect holds.
    The fit follows it with process noise, its residuals near the noise, and its velocity gaps
    per interval below what the positions can see; summed over several intervals they are
    visible, and far beyond their random part: the certificate says the model lacks a force.
    (Before the gaps were judged over several intervals: no systematic gaps, and the
    diagnosis's null verdict called it too small a misfit to tell.)"""
    veh = PeerVehicle.one_kg(log_rate=200.0)
    paths = write_case(fly(veh, duration=20.0, seed=3, effects=PeerEffects(slung_load=[0.1, 0.5]), low_hovers=False),
                       tmp_path)
    model = QuadrotorModel(load_airframe(paths["airframe"]))
    assert model.airframe.mass == pytest.approx(veh.mass + 0.1)
    r = fit(model, load_log(paths["log"]))
    assert r.converged and r.process_noise is not None
    assert r.value("K_T") == pytest.approx(veh.K_T, rel=0.02)
    cert = r.certificate
    assert {"vx", "vy"} <= set(cert.off_states())
    assert min(cert.systematic_gaps["vx"], cert.systematic_gaps["vy"]) > 5.0
    assert "mostly systematic" in cert.text()


@pytest.mark.slow
def test_a_slung_load_is_a_force_the_model_misses_not_a_small_misfit(tmp_path):
    """The slung load of the test above in the diagnosis (1 kHz, 30 s, a validation flight):
    no catalogue effect stands in for the cable's pull, and the null verdict says the model
    is missing a force, in the velocities' process noise (before: "too small a misfit to
    tell what it is", 1.5x the noise in y, while its 1-s predictions were 5-25 times the
    load-free vehicle's). K_T and b stay exact: the pull averages to the load's weight."""
    veh = PeerVehicle.one_kg()
    fx = PeerEffects(slung_load=[0.1, 0.5])
    paths = [write_case(fly(veh, duration=30.0, seed=s, effects=fx, low_hovers=False), tmp_path, name=f"seed{s}")
             for s in (1, 2)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.baseline_certified
    assert d.verdict is None and d.null_reason == "unexplained", d.summary()
    assert {"vx", "vy"} <= set(d.unexplained_gaps)
    assert "a force acting over many intervals" in d.summary()
    assert d.baseline.value("K_T") == pytest.approx(veh.K_T, rel=0.02)
    assert d.baseline.value("b") == pytest.approx(veh.b, rel=0.02)


@pytest.mark.slow
def test_rate_damping_is_not_named_after_a_catalogue_stand_in(tmp_path):
    """Body-rate damping -D*omega (not in the catalogue) on the 1.2 kg vehicle. moment_gain
    (a weaker control moment absorbs part of the damping) is never significant: refitted, it
    removes a sliver of what is missing; the verdict is null, the rates stay unexplained, and
    discovery finds mx ~ p with the true -D_x/J_x (what is missing is outside the catalogue)."""
    damping = np.array([0.02, 0.02, 0.01])
    veh = PeerVehicle.one_kg()
    paths = [write_case(fly(veh, duration=20.0, seed=s, effects=PeerEffects(rate_damping=list(damping))),
                        tmp_path, name=f"seed{s}") for s in (1, 2)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.baseline_certified
    # moment_gain removes a sliver (6 %) of what is missing and leaves the model far off: never
    # the verdict (before the sliver rule it was, until discovery's encompassing test set it
    # aside). A catalogue stand-in that explains more (hub_rotor_drag's rate damping) is set
    # aside by that test: the verdict is null, outside the catalogue, with the rates unexplained
    assert d.verdict is None and d.null_reason in ("outside_catalogue", "unexplained"), d.summary()
    top = next(c for c in d.ranking if c.effect == "moment_gain")
    assert top.significant is False
    if top.lr is not None:
        # refitted (it was when this test was written; by 2026-12-02, on the code before that
        # day's changes too, its score is below the four best and it is screened only): a
        # sliver of what is missing, "cannot tell"
        assert "cannot tell" in top.reason and top.explained < 0.1
    assert {"p", "q"} <= set(d.unexplained)
    if d.outside_catalogue:
        assert "outside the catalogue" in d.outside_catalogue and d.as_json()["outside_catalogue"] == d.outside_catalogue
    mx = next(x for x in d.discovered if x.channel == "mx" and x.significant)
    assert [t.feature for t in mx.terms] == ["p"]
    assert mx.fitted[0].coefficient == pytest.approx(-damping[0] / veh.inertia[0], rel=0.05)


@pytest.mark.slow
def test_crazyflie_logged_at_100_hz_with_nothing_missing_is_null_once_its_timing_is_settled(tmp_path):
    """A real Crazyflie log's rate: the 30 g vehicle's actual rotor speeds (20 ms motor time
    constant) logged at 100 Hz. Held, the samples lag the speeds by half a row (5 ms), and the
    diagnosis of the model without the timing named a rotor drag at the hubs (k_rdv 4e-7,
    validation nrmse 0.045 -> 0.035). It now settles the timing first: ``sampled_inputs`` with
    s_lead about one half, the validation nrmse less than half the model's without it, K_T and
    b exact, and a null verdict."""
    veh = PeerVehicle.crazyflie(log_rate=100.0)
    paths = [write_case(fly(veh, duration=25.0, seed=s), tmp_path, name=f"seed{s}") for s in (1, 2)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.baseline_certified
    assert "sampled_inputs" in d.model.effect_names
    assert d.baseline.value("s_lead") == pytest.approx(0.5, abs=0.05)
    timing = d.as_json()["input_timing"]
    assert timing["effect"] == "sampled_inputs" and timing["s_lead"] == d.baseline.value("s_lead")
    assert timing["nrmse_after"] < 0.5 * timing["nrmse_before"]
    assert d.warnings[0] == timing["text"]
    assert d.verdict is None and not [c.effect for c in d.ranking if c.significant], d.summary()
    truth = PeerVehicle.crazyflie()
    assert d.baseline.value("K_T") == pytest.approx(truth.K_T, rel=0.02)
    assert d.baseline.value("b") == pytest.approx(truth.b, rel=0.02)


@pytest.mark.slow
def test_turbulence_alone_is_not_named_after_a_command_fed_sliver(tmp_path):
    """A random torque (0.02 N m RMS, 1-s correlation) on the 1.2 kg vehicle and nothing else:
    no catalogue effect is missing. The controller answers the torque through the commands, so
    ``moment_gain`` fitted to them comes out 0.93 and significant (it was the verdict,
    validation -5 %), but it removes only 7 % of what the model misses and leaves p and q far
    above the noise: nothing stands. Judged again with the torque as a disturbance, nothing
    stands either and the rates fall to their noise: the verdict is null because what is
    missing acts as a random torque, and the final model holds it, with K_T and b within 5 %
    (the baseline's b is 30 % low, a closed-loop bias; its halves are 9 % apart, beyond the
    white-noise screen but within their own std, which the torque widens: not called absorbing)."""
    veh = PeerVehicle.one_kg()
    flights = [fly(veh, duration=20.0, seed=s, effects=PeerEffects(turbulence=0.02), low_hovers=True) for s in (1, 2)]
    paths = [write_case(f, tmp_path, name=f"seed{s}") for s, f in zip((1, 2), flights)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    truth = flights[0].truth["greybox_equivalent"]
    assert "b" not in d.inconsistent and d.baseline.value("b") / truth["b"] - 1 < -0.15
    assert d.baseline_certified
    assert d.verdict is None and not [c.effect for c in d.ranking if c.significant], d.summary()
    mg = next(c for c in d.ranking if c.effect == "moment_gain")
    assert mg.p_value < 0.01 and mg.explained < 0.1 and "cannot tell" in mg.reason
    assert d.null_reason == "random_torque" and d.added_disturbance, d.summary()
    assert d.as_json()["null_reason"] == "random_torque"
    assert "random torque" in d.verdict_text()
    final = d.final_fit
    assert final.converged and final.certificate.adequate
    assert max(final.certificate.residual_over_noise[c] for c in "pqr") < 1.5
    assert final.value("K_T") == pytest.approx(truth["K_T"], rel=0.05)
    assert final.value("b") == pytest.approx(truth["b"], rel=0.05)
    assert d.as_json()["verdict"] is None and d.as_json()["added"] == ["disturbance_torque"]


@pytest.mark.slow
def test_disturbance_torque_state_removes_the_closed_loop_bias_of_b(tmp_path):
    """A random torque (0.02 N m RMS, 1-s correlation) on the 1.2 kg vehicle: its controller
    answers it through the commands the model reads, and a fit without a state for it gives
    ``b`` about 30 % low (the yaw commands that moved nothing are explained by a smaller b).
    With ``DisturbanceTorque`` (a random-walk torque, its process noise started at the rate
    gaps per second) the fit is certified, the rates' residuals fall to the noise and ``b`` is
    within 10 %; on the same vehicle without turbulence the effect changes nothing."""
    from greybox.effects import DisturbanceTorque

    veh = PeerVehicle.one_kg()

    def fitted(effects, with_disturbance):
        f = fly(veh, duration=20.0, seed=1, effects=effects, low_hovers=True)
        paths = write_case(f, tmp_path / str(effects.turbulence), name="seed1")
        model = QuadrotorModel(load_airframe(paths["airframe"]))
        if with_disturbance:
            model = model + DisturbanceTorque()
        est, _ = load_log(paths["log"]).split(0.8)
        return fit(model, est, process_noise="auto"), f.truth["greybox_equivalent"]

    plain, truth = fitted(PeerEffects(turbulence=0.02), False)
    assert plain.value("b") / truth["b"] - 1 < -0.15            # the bias this removes
    res, truth = fitted(PeerEffects(turbulence=0.02), True)
    assert res.converged, res.certificate.text()
    assert abs(res.value("b") / truth["b"] - 1) < 0.10
    assert abs(res.value("K_T") / truth["K_T"] - 1) < 0.03
    assert max(res.certificate.residual_over_noise[c] for c in "pqr") < 1.5 < \
        max(plain.certificate.residual_over_noise[c] for c in "pqr")
    clean, truth = fitted(PeerEffects(), True)
    assert clean.converged, clean.certificate.text()
    assert clean.value("b") == pytest.approx(truth["b"], rel=0.02)
    assert clean.value("K_T") == pytest.approx(truth["K_T"], rel=0.01)


@pytest.mark.slow
def test_ground_effect_under_turbulence_is_found_with_the_torque_as_a_disturbance(tmp_path):
    """A per-rotor ground effect (two low passes, hubs down to 15 cm) and a random torque (0.02 N m RMS,
    1-s correlation) on the 1.2 kg vehicle. Against a baseline with process noise on every
    state the ground effect hides in the vertical process noise (its refit removed 0.0 % of
    the excess, all of which is in the rates) and the verdict was null. With nothing standing
    and the rates far off, the diagnosis judges the candidates again with the torque as a
    random-walk disturbance (process noise on it alone): the ground effect is named, k_ge is
    the truth's ((R/4)^2 = 9e-4; the airframe gives the hubs' height, 3 cm above the CoG) within
    5 %, and the final model's K_T and b are within 5 % (b was 32 % low: the closed-loop
    bias)."""
    veh = PeerVehicle.one_kg()
    fx = PeerEffects(ground_effect=True, turbulence=0.02)
    flights = [fly(veh, duration=40.0, seed=s, effects=fx, low_hovers=True) for s in (1, 2)]
    paths = [write_case(f, tmp_path, name=f"seed{s}", hub_heights=True) for s, f in zip((1, 2), flights)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.baseline_certified
    assert d.verdict == "ground_effect", d.summary()
    assert d.judged_with_disturbance and d.as_json()["judged_with_disturbance"] is True
    final = d.final_fit
    assert final.converged and "disturbance_torque" in final.model.effect_names
    truth = flights[0].truth["greybox_equivalent"]
    assert final.value("K_T") == pytest.approx(truth["K_T"], rel=0.05)
    assert final.value("b") == pytest.approx(truth["b"], rel=0.05)
    assert final.value("k_ge") == pytest.approx(truth["k_ge"], rel=0.05)
    assert any("as a disturbance" in w and "ground_effect is found" in w for w in d.warnings), d.warnings
    assert not d.unexplained


@pytest.mark.slow
def test_disturbance_baseline_takes_a_random_torque_out_of_the_rates(tmp_path):
    """The baseline the diagnosis judges candidates against under turbulence
    (``closed_loop.disturbance_baseline``: a random-walk torque, the only process noise), on
    12 s of the 1.2 kg vehicle logged at 200 Hz under a random torque: the fit with process
    noise on every state leaves p, q, r 2.6-4.3x their noise (``rates_missing_a_torque`` names them)
    and b 18 % low; with the disturbance the fit is certified and adequate, the rates are at
    their noise and K_T and b are within 5 %. Without turbulence no rate is missed, so the
    diagnosis never builds it."""
    from greybox.diagnosis.closed_loop import can_hold_disturbance, disturbance_baseline, rates_missing_a_torque

    veh = PeerVehicle.one_kg(log_rate=200.0)

    def base(effects, name):
        f = fly(veh, duration=12.0, seed=1, effects=effects, low_hovers=False)
        paths = write_case(f, tmp_path, name=name)
        log = load_log(paths["log"])
        return fit(QuadrotorModel(load_airframe(paths["airframe"])), log, process_noise="auto"), log, \
            f.truth["greybox_equivalent"]

    res, log, truth = base(PeerEffects(turbulence=0.02), "turbulent")
    assert res.converged
    assert set(rates_missing_a_torque(res, 3.0)) >= {"p", "q"}
    assert res.value("b") / truth["b"] - 1 < -0.10
    d = disturbance_baseline(res, [log])
    assert d.converged and d.certificate.adequate, d.certificate.text()
    assert "disturbance_torque" in d.model.effect_names
    assert max(d.certificate.residual_over_noise[c] for c in "pqr") < 1.3
    assert d.value("K_T") == pytest.approx(truth["K_T"], rel=0.05)
    assert d.value("b") == pytest.approx(truth["b"], rel=0.05)
    calm, _, _ = base(PeerEffects(), "calm")
    assert calm.converged and rates_missing_a_torque(calm, 3.0) == []
    # a model that already holds a disturbance model gets no second one (its states would clash)
    from greybox.effects import HeldMoment
    assert can_hold_disturbance(res.model) and not can_hold_disturbance(d.model)
    assert not can_hold_disturbance(res.model + HeldMoment())


@pytest.mark.slow
def test_disturbance_look_names_no_stand_in_when_the_missing_effect_is_not_a_candidate(tmp_path):
    """The ground effect under turbulence, as above, with the ground effect left out of the
    candidates: nothing stands against the base fit, nor against the disturbance baseline
    (thrust_drift's LR there is in the hundred thousands, but it does not stand), and the words
    say that the model with the disturbance is still off: null, no disturbance in the final
    model."""
    veh = PeerVehicle.one_kg()
    fx = PeerEffects(ground_effect=True, turbulence=0.02)
    flights = [fly(veh, duration=40.0, seed=s, effects=fx, low_hovers=True) for s in (1, 2)]
    paths = [write_case(f, tmp_path, name=f"seed{s}") for s, f in zip((1, 2), flights)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]),
                 candidates=["thrust_drift", "wind", "quadratic_drag", "moment_gain", "cog_offset"])
    assert d.baseline_certified
    assert d.verdict is None and not d.added_disturbance, d.summary()
    words = next(w for w in d.warnings if "as a disturbance" in w)
    assert "still off" in words and "z" in words.split("still off")[1], words


def _accel_case(tmp_path, name, seeds=(1,), **kw):
    """1.2 kg vehicle with body drag and the accelerometer logged (``kw``: ``accel_bias`` for
    the sensors, ``wind`` for the air)."""
    sens = PeerSensors(accel=True, accel_bias=kw.get("accel_bias"))
    eff = PeerEffects(body_drag=[0.3, 0.3, 0.5], wind=kw.get("wind"))
    flights = [fly(PeerVehicle.one_kg(), duration=kw.get("duration", 20.0), seed=s, effects=eff, sensors=sens)
               for s in seeds]
    paths = [write_case(f, tmp_path, name=f"{name}{s}") for s, f in zip(seeds, flights)]
    return paths, flights[0].truth["greybox_equivalent"]


@pytest.mark.slow
def test_accelerometer_bias_of_another_simulator_is_recovered(tmp_path):
    """The peer simulator's IMU reads its specific force plus a bias (0.15, -0.1, 0.2) m/s^2.
    The model with ``accel_bias`` fits it certified and recovers the bias within 3 std, K_T
    within 1 %; without it the accelerometer channels stay far above their noise. The
    diagnosis considers ``accel_bias`` because the log measures ``ax`` (and only then)."""
    from greybox.diagnosis import default_candidates
    bias = [0.15, -0.1, 0.2]
    paths, truth = _accel_case(tmp_path, "bias", accel_bias=bias, duration=12.0)
    log = load_log(paths[0]["log"])
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    assert "accel_bias" in default_candidates(model, [log])
    keep = [i for i, c in enumerate(log.output_names) if c not in ("ax", "ay", "az")]
    no_acc = FlightLog(log.t, log.inputs, log.input_names, log.outputs[:, keep],
                       [log.output_names[i] for i in keep])
    assert "accel_bias" not in default_candidates(model, [no_acc])
    with_bias = fit(model + by_name("accel_bias"), log)
    assert with_bias.converged, with_bias.status
    for i, b in enumerate(bias):
        std = with_bias.std[with_bias.free_names.index(f"acc_bias[{i}]")]
        assert abs(with_bias.value(f"acc_bias[{i}]") - b) < 3 * std, (i, with_bias.value(f"acc_bias[{i}]"), std)
    assert with_bias.value("K_T") == pytest.approx(truth["K_T"], rel=0.01)
    without = fit(model, log)
    assert max(without.certificate.residual_over_noise[c] for c in ("ax", "ay")) > 2.0
    assert max(with_bias.certificate.residual_over_noise[c] for c in ("ax", "ay", "az")) < 1.5


@pytest.mark.slow
@pytest.mark.parametrize("hidden", ["accel_bias", "wind"])
def test_accelerometer_bias_and_wind_are_told_apart(tmp_path, hidden):
    """Both add a constant to the horizontal specific force the IMU reads; only a wind moves the
    vehicle. On the peer simulator (1.2 kg, body drag, IMU logged) with a bias of (0.15, -0.1,
    0.2) m/s^2 the verdict is ``accel_bias`` (wind is significant alone, not once it is in);
    with a wind of (1.0, -0.5) m/s it is ``wind`` (the bias is not confirmed once it is in).
    Each is recovered within 5 %, and the second round is null."""
    truth_value = {"accel_bias": [0.15, -0.1, 0.2], "wind": [1.0, -0.5, 0.0]}[hidden]
    paths, truth = _accel_case(tmp_path, hidden, seeds=(1, 2), **{hidden: truth_value})
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.baseline_certified
    assert d.verdict == hidden, d.summary()
    other = "wind" if hidden == "accel_bias" else "accel_bias"
    assert len(d.rounds) >= 2 and not d.rounds[1].verdict, d.summary()
    assert not next(c for c in d.rounds[1].ranking if c.effect == other).significant
    name = {"accel_bias": "acc_bias", "wind": "wind"}[hidden]
    final = d.final_fit
    for i in range(2):
        assert final.value(f"{name}[{i}]") == pytest.approx(truth_value[i], rel=0.05, abs=0.01)
    assert final.value("K_T") == pytest.approx(truth["K_T"], rel=0.02)


def _three_kg_case(tmp_path, effects, duration, **airframe_kw):
    """The heavy end of the scale: the simulator's 3 kg vehicle (15-inch propellers, 60 ms
    motors, a 12 Hz attitude loop, a 400 Hz log with vision at 50 Hz), an estimation and a
    validation flight with low hovers."""
    flights = [fly(PeerVehicle.three_kg(), duration=duration, seed=s, effects=effects) for s in (1, 2)]
    paths = [write_case(f, tmp_path, name=f"seed{s}", **airframe_kw) for s, f in zip((1, 2), flights)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    return model, [load_log(p["log"]) for p in paths], flights[0].truth["greybox_equivalent"]


@pytest.mark.slow
def test_three_kg_weak_rotor_is_named_and_its_deviations_recovered(tmp_path):
    """3 kg, rotor 2 at 92 % of thrust and torque, starting values 40 % off: the baseline is
    certified, ``motor_asymmetry`` is the verdict, its deviations (relative to the rotors'
    mean, as the catalogue's effect has them) are the truth's within 3 std, and the final
    model's K_T and b are within 5 % (the scale check of issue 13: 30 g to 3 kg)."""
    model, (est, val), truth = _three_kg_case(tmp_path, PeerEffects(motor_gains=[1.0, 0.92, 1.0, 1.0]), 20.0)
    d = diagnose(model, est, validation=val)
    assert d.baseline_certified
    assert d.verdict == "motor_asymmetry", d.summary()
    final = d.final_fit
    for i in range(3):
        std = final.std[final.free_names.index(f"K_T_dev[{i}]")]
        assert abs(final.value(f"K_T_dev[{i}]") - truth["K_T_dev"][i]) < 3 * std, (i, final.value(f"K_T_dev[{i}]"), std)
    assert final.value("K_T") == pytest.approx(truth["K_T"], rel=0.05)
    assert final.value("b") == pytest.approx(truth["b"], rel=0.05)


@pytest.mark.slow
def test_three_kg_ground_effect_is_named_and_k_ge_is_the_truths_at_the_hubs(tmp_path):
    """3 kg, Cheeseman-Bennett ground effect per rotor at hubs 5 cm above the centre of
    gravity, two low passes (the CoG down to 0.22 m): with the airframe giving the hubs' height, the verdict is
    ``ground_effect`` and ``k_ge`` is the truth's ``(R/4)^2`` within 3 std. (With the rotors
    put in the CoG's plane, as ``airframe_text`` writes them by default, the same flights give
    k_ge 0.0013 against 0.0023: the parameter is the effect seen from where the airframe puts
    the rotors, 5 cm nearer the ground, which needs a smaller k_ge for the same thrust.)"""
    model, (est, val), truth = _three_kg_case(tmp_path, PeerEffects(ground_effect=True), 40.0, hub_heights=True)
    d = diagnose(model, est, validation=val)
    assert d.baseline_certified
    assert d.verdict == "ground_effect", d.summary()
    final = d.final_fit
    std = final.std[final.free_names.index("k_ge")]
    assert abs(final.value("k_ge") - truth["k_ge"]) < 3 * std, (final.value("k_ge"), std, truth["k_ge"])
    assert final.value("K_T") == pytest.approx(truth["K_T"], rel=0.05)


@pytest.mark.slow
@pytest.mark.parametrize("commands", [True, False])
def test_motor_lags_screening_statistic_is_its_refits_likelihood_ratio_not_its_floors(tmp_path, commands):
    """A motor lag cannot vanish (``tau_m`` >= 2 ms, the integrators' floor): its screening
    statistic is the decrease from the baseline's cost to the Gauss-Newton optimum predicted
    from the floor or from a plausible lag. With the controller's commands logged (a 20-ms
    lag behind them) it is the refit's cost decrease within a factor 1.5; with the motors'
    own speeds logged (nothing to lag) it is 0 and the refit ends on the floor. (Integrated
    node to node with the node's input held, the candidate's speeds missed the logged ones
    and the statistic was 1e9-1e10 on every flight; taken at the floor alone, it understated
    a real flight's 70-ms lag 15-fold.)"""
    from greybox.diagnosis.screening import fit_weights, refit, screen
    flight = fly(PeerVehicle.crazyflie(log_rate=100.0), duration=8.0, seed=1,
                 sensors=PeerSensors(log_commands=commands))
    paths = write_case(flight, tmp_path, name="s1")
    model, log = QuadrotorModel(load_airframe(paths["airframe"])), load_log(paths["log"])
    res = fit(model, log, process_noise="auto", max_iter=200)
    assert res.converged and res.process_noise is not None
    score, df = screen(model, res, [log], "motor_lag", fit_weights(res), "auto")
    _, lagged, _ = refit(model, res, [log], None, "motor_lag", res.sigma, "auto")
    decrease = 2 * (res.cost - lagged.cost)
    assert df == 1
    if commands:
        assert decrease > 1000 and decrease / 1.5 < score < 1.5 * decrease, (score, decrease)
        assert 0.01 < lagged.value("tau_m") < 0.03
    else:
        assert score == 0.0 and decrease < 0, (score, decrease)
        assert lagged.value("tau_m") == pytest.approx(2e-3)


@pytest.mark.slow
@pytest.mark.parametrize("vehicle", ["crazyflie_100hz", "one_kg"])
def test_motor_lag_is_named_when_the_log_holds_the_motor_commands(tmp_path, vehicle):
    """What a real autopilot logs: the controller's speed commands (PWM), not the ESCs'
    speeds; the simulator's motors lag them (20 ms on the 30 g vehicle, 35 ms on the 1.2 kg
    one). The verdict is ``motor_lag`` with the truth's time constant, K_T and b exact.

    The 30 g vehicle's controller runs at 500 Hz and the log at 100 Hz, so the logged command
    is a snapshot of one that changes between rows; against the baseline (far off without the
    lag) that timing was not significant, and left out its half row of lag went into tau_m
    (15.5 ms). It is judged again against the model with the lag, and with it tau_m is the
    truth's within 10 %. The 1.2 kg vehicle's commands change every second row of its 1 kHz
    log: held values, no timing."""
    if vehicle == "crazyflie_100hz":
        veh, duration = PeerVehicle.crazyflie(log_rate=100.0), 25.0
    else:
        veh, duration = PeerVehicle.one_kg(), 20.0
    sensors = PeerSensors(log_commands=True)
    flights = [fly(veh, duration=duration, seed=s, sensors=sensors) for s in (1, 2)]
    paths = [write_case(f, tmp_path, name=f"seed{s}") for s, f in zip((1, 2), flights)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.baseline_certified
    assert d.verdict == "motor_lag", d.summary()
    final, truth = d.final_fit, flights[0].truth["greybox_equivalent"]
    assert final.converged
    if vehicle == "crazyflie_100hz":
        timing = d.as_json()["input_timing"]
        assert timing is not None and timing["judged_with"] == ["motor_lag"], d.summary()
        assert "sampled_inputs" in final.model.effect_names and "sampled_inputs" not in d.model.effect_names
        assert 0.2 < final.value("s_lead") < 0.6
        assert timing["nrmse_after"] < timing["nrmse_before"]
        assert final.value("tau_m") == pytest.approx(truth["tau_m"], rel=0.10)
    else:
        assert d.input_timing is None and "sampled_inputs" not in final.model.effect_names
        std = final.std[final.free_names.index("tau_m")]
        assert abs(final.value("tau_m") - truth["tau_m"]) < max(3 * std, 0.02 * truth["tau_m"])
    assert final.value("K_T") == pytest.approx(truth["K_T"], rel=0.05)
    assert final.value("b") == pytest.approx(truth["b"], rel=0.05)


@pytest.mark.slow
def test_the_logs_timing_that_validation_cannot_judge_is_settled_by_the_estimation_data(tmp_path):
    """The 30 g vehicle under the autopilot's cascade (``controller="cascaded_pid"``), its
    500 Hz commands logged at 100 Hz. Judged again against the model with the motor lag, the
    log's timing is significant (LR about 1200) while the validation flight predicts alike with
    and without it (the lag takes the half row the held rows leave out: total nrmse +0.1 %),
    a tie. The timing is then taken, on the estimation data's word: tau_m 18.9 ms for the
    motors' 20 (left out it was 15.6 ± 0.13 ms, 34 std off, without a word)."""
    veh = PeerVehicle.crazyflie(log_rate=100.0)
    flights = [fly(veh, duration=25.0, seed=s, sensors=PeerSensors(log_commands=True), controller="cascaded_pid")
               for s in (1, 2)]
    paths = [write_case(f, tmp_path, name=f"seed{s}") for s, f in zip((1, 2), flights)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    est, val = (denoise_inputs(model, load_log(p["log"]))[0] for p in paths)
    d = diagnose(model, est, validation=val)
    assert d.baseline_certified and d.verdict == "motor_lag", d.summary()
    timing = d.as_json()["input_timing"]
    assert timing is not None and timing["judged_with"] == ["motor_lag"], d.summary()
    assert "settle the log's timing" in timing["text"]
    final, truth = d.final_fit, flights[0].truth["greybox_equivalent"]
    assert final.converged and "sampled_inputs" in final.model.effect_names
    assert final.value("tau_m") == pytest.approx(truth["tau_m"], rel=0.10)
    assert final.value("K_T") == pytest.approx(truth["K_T"], rel=0.05)
    assert final.value("b") == pytest.approx(truth["b"], rel=0.05)


def _battery_flights(tmp_path, log_commands: bool) -> tuple[list[dict], list]:
    """Two 25-s flights (seeds 1, 2) of the 30 g vehicle at 100 Hz whose open-loop ESCs drive
    the motors from a battery that sags with the current and the charge spent (3.9 -> 3.6 V),
    ``vbat`` logged; the log holds the controller's commands or the motors' speeds."""
    veh = PeerVehicle.crazyflie(log_rate=100.0)
    flights = [fly(veh, duration=25.0, seed=s, effects=PeerEffects(battery=PeerBattery()),
                   sensors=PeerSensors(log_commands=log_commands)) for s in (1, 2)]
    return [write_case(f, tmp_path, name=f"seed{s}") for s, f in zip((1, 2), flights)], flights


@pytest.mark.slow
def test_battery_voltage_is_named_when_logged_commands_drive_motors_from_a_sagging_battery(tmp_path):
    """What a Crazyflie logs: motor commands, and a battery voltage that falls through the flight
    (with the charge) and with every climb (with the current); the motors spin slower at the
    same command as it sags, through a DC motor's quadratic, not greybox's linear scale. The
    rounds name ``motor_lag`` (the motors lag the commands by 20 ms) and ``battery_voltage``;
    ``thrust_drift``, which follows the same sag in time alone, is not in the final model (it
    had stood beside the battery, kept from a round where the battery's refit was not yet
    certified). ``K_vbat`` is the truth's
    slope at the flight's mean voltage, and ``K_T`` and ``b`` are the truth's at the 4 V the
    effect takes as its reference."""
    paths, flights = _battery_flights(tmp_path, log_commands=True)
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.baseline_certified
    final = d.final_fit
    assert final.converged
    assert {"motor_lag", "battery_voltage"} <= set(final.model.effect_names), d.summary()
    assert "thrust_drift" not in final.model.effect_names, d.summary()
    truth = flights[0].truth["greybox_equivalent"]       # K_T and b at greybox's 4-V reference
    # the log's timing (commands set at 500 Hz, logged at 100 Hz) is settled after the rounds,
    # against the model with their verdicts: the logged commands are samples of a signal that
    # varies within each row. Until the velocities' gaps were judged over several intervals it
    # was not: that refit stopped short of its optimum (LR 238, a lower bound), the held rows
    # stood, half a row of lag went into tau_m (15.5 ms for 20) and a warning said so. Now the
    # refit is certified (LR 249); the rule changes only certificates, and a soft baseline
    # found inadequate has its refits restarted from the airframe's guesses as well
    timing = d.as_json()["input_timing"]
    assert timing and set(timing["judged_with"]) == {"motor_lag", "battery_voltage"}, d.summary()
    assert "sampled_inputs" in final.model.effect_names
    assert final.value("tau_m") == pytest.approx(truth["tau_m"], rel=0.1)
    assert not any("counts the measurement noise only" in w for w in d.warnings) and d.timing_bound == {}
    assert final.value("K_vbat") == pytest.approx(truth["K_vbat"], rel=0.03)
    assert final.value("K_T") == pytest.approx(truth["K_T"], rel=0.03)
    assert final.value("b") == pytest.approx(truth["b"], rel=0.05)


@pytest.mark.slow
def test_a_lag_the_logs_timing_leaves_unsettled_is_given_with_its_bound(tmp_path):
    """The autopilot cascade's 30 g flight with its 500-Hz motor commands logged at 100 Hz,
    seeds 11/12 (drawn for the parameter audit, where the log's timing is not settled: measured
    once, tau_m 15.6 +- 0.14 ms for the motors' 20, 31 std off): the diagnosis names the lag,
    its words say the std counts the noise only and the timing moves it by up to half a row,
    and ``timing_bound`` holds that half row (5 ms) for tau_m; the truth lies within the
    bound and three std."""
    veh = PeerVehicle.crazyflie(log_rate=100.0)
    paths = [write_case(fly(veh, duration=25.0, seed=s, sensors=PeerSensors(log_commands=True),
                            controller="cascaded_pid"), tmp_path, name=f"seed{s}") for s in (11, 12)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    (est, _), (val, _) = (denoise_inputs(model, load_log(p["log"])) for p in paths)
    d = diagnose(model, est, validation=val)
    assert "motor_lag" in d.final_model.effect_names, d.summary()
    fr = d.final_fit
    assert d.timing_bound.get("tau_m") == pytest.approx(0.005, rel=0.01), (d.timing_bound, d.summary())
    assert any("tau_m" in w and "counts the measurement noise only" in w for w in d.warnings)
    assert d.as_json()["timing_bound"] == {"tau_m": d.timing_bound["tau_m"]}
    bound = d.timing_bound["tau_m"] + 3 * float(fr.std[fr.free_names.index("tau_m")])
    assert abs(fr.value("tau_m") - 0.020) < bound, d.summary()


@pytest.mark.slow
def test_a_sagging_battery_with_the_motors_speeds_logged_is_null(tmp_path):
    """The same battery and motors, the ESCs' measured speeds logged instead of the commands:
    whatever the voltage does, the speeds say it, and ``vbat`` (correlated with time and with
    the thrust drawn) must not be named. Null, K_T and b exact."""
    paths, flights = _battery_flights(tmp_path, log_commands=False)
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.baseline_certified
    assert d.verdict is None, d.summary()
    assert not any(c.significant for c in d.ranking if c.effect == "battery_voltage")
    truth = flights[0].truth["greybox_equivalent"]
    assert d.fitted_model.value("K_T") == pytest.approx(truth["K_T"], rel=0.01)
    assert d.fitted_model.value("b") == pytest.approx(truth["b"], rel=0.02)


def _peer_400g(**kw) -> PeerVehicle:
    """A 0.42 kg vehicle between the Crazyflie and the 1 kg one (hover ~1300 rad/s), logged at
    300 Hz with vision at 120 Hz: a scale and rates no other test flies."""
    base = dict(name="peer_400g", mass=0.42, inertia=(1.1e-3, 1.25e-3, 2.1e-3), arm=0.12,
                K_T=6.0e-7, b=9.0e-9, tau_motor=0.03, rotor_radius=0.065, rotor_inertia=5.0e-6,
                hub_height=0.02, distance=0.8, speed=1.6, low_hover=0.05, cruise_height=0.8,
                log_rate=300.0, pos_rate=120.0, pos_noise=0.001, att_noise=0.002, gyro_noise=0.006,
                speed_quantum=0.5, attitude_bandwidth=22.0, position_bandwidth=2.2, ctrl_rate=500.0)
    base.update(kw)
    return PeerVehicle(**base)


@pytest.mark.slow
def test_a_null_verdict_with_physics_found_outside_the_catalogue_says_so(tmp_path):
    """Thrust falling with the axial inflow (not in the catalogue) on the 0.42 kg vehicle: no
    catalogue effect stands, and discovery finds a significant moment term in the body's
    vertical speed that cuts the validation nrmse by two thirds. The null verdict must say
    that what is missing is outside the catalogue, not "nothing significant is missing" (it
    did, found by a blind audit)."""
    veh = _peer_400g()
    paths = [write_case(fly(veh, duration=20.0, seed=s, effects=PeerEffects(inflow=0.08)), tmp_path, name=f"seed{s}")
             for s in (5, 6)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.baseline_certified and d.verdict is None, d.summary()
    sig = [x for x in d.discovered if x.significant]
    assert sig and any("vz_b" in t.feature for x in sig for t in x.terms), d.summary()
    assert d.null_reason == "outside_catalogue" and "outside the catalogue" in d.verdict_text()
    assert d.as_json()["outside_catalogue"] == d.outside_catalogue


@pytest.mark.slow
def test_a_catalogue_verdict_that_falls_away_beside_the_discovered_physics_is_set_aside(tmp_path):
    """Thrust falling with the axial inflow (20 % per m/s, not in the catalogue) on the 1.2 kg
    vehicle, on draws no case was tuned on (seeds 11, 12). Round 1 took thrust_drift (K_T_drift
    0.0030 +- 0.0011, validation -5 %), round 2 hub_rotor_drag; discovery found the inflow's
    own terms (fz ~ vz_b, mx ~ vz_b*w2roll, my ~ vz_b*w2pitch: 0.102 -> 0.016), and the chain
    refitted beside them gained 8 %, so thrust_drift stayed the verdict. That gain was the
    refit's: beside the discovered terms thrust_drift's force is 1 % of the vehicle's RMS
    acceleration (K_T_drift 0.00017), hub_rotor_drag's 0.2 %. The verdict is now null, what is
    missing outside the catalogue, and thrust_drift set aside for that reason — or, since a
    thrust per rotor speed that rises over the flight is no battery sag (K_T_drift > 2 std above
    0: ThrustDrift.plausibility_warnings), refused as physically implausible before that."""
    veh = PeerVehicle.one_kg()
    paths = [write_case(fly(veh, duration=20.0, seed=s, effects=PeerEffects(inflow=0.2)), tmp_path, name=f"seed{s}")
             for s in (11, 12)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    (est, _), (val, _) = (denoise_inputs(model, load_log(p["log"])) for p in paths)
    d = diagnose(model, est, validation=val)
    assert d.baseline_certified and d.verdict is None, d.summary()
    assert d.null_reason == "outside_catalogue" and "outside the catalogue" in d.verdict_text(), d.summary()
    sig = [x for x in d.discovered if x.significant]
    assert any("vz_b" in t.feature for x in sig for t in x.terms), d.summary()
    drift = next(c for c in d.ranking if c.effect == "thrust_drift")
    assert not drift.significant and ("set aside: once the combination outside the catalogue is in" in drift.reason
                                      or "physically implausible: K_T_drift = +" in drift.reason), drift.reason


@pytest.mark.slow
def test_a_null_verdict_over_a_small_misfit_does_not_say_nothing_is_missing(tmp_path):
    """A gyro bias of (0.02, -0.015, 0.01) rad/s (no catalogue effect holds a gyro bias) on the
    0.42 kg vehicle: nothing stands and nothing is far off, but the fit's body rates stay 2-3
    times the noise. The verdict says so, naming the channels, not "nothing significant is
    missing"."""
    veh = _peer_400g()
    paths = [write_case(fly(veh, duration=20.0, seed=s, effects=PeerEffects(gyro_bias=[0.02, -0.015, 0.01])),
                        tmp_path, name=f"seed{s}") for s in (5, 6)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.baseline_certified and d.verdict is None, d.summary()
    assert not d.baseline.certificate.adequate and not d.unexplained
    assert d.null_reason == "small_misfit", d.summary()
    assert d.as_json()["null_reason"] == "small_misfit"
    words = d.verdict_text()
    assert "nothing significant is missing" not in words and "p (" in words and "q (" in words


@pytest.mark.slow
def test_a_verdict_that_stood_in_for_the_logs_timing_is_left_out_of_the_final_model(tmp_path):
    """Blade flapping k_f (e3 x v_b) on the 0.42 kg vehicle, logged at 300 Hz from speeds that
    vary between rows: drag_moment holds flapping's form exactly (k_dm = k_f); a hub rotor
    drag wins round 2 against the model without the log's timing, and once the timing is in,
    its k_rdh is 1e-8 (0.04 % of a rotor's): the final model leaves it out, and says why."""
    veh = _peer_400g()
    paths = [write_case(fly(veh, duration=20.0, seed=s, effects=PeerEffects(flapping=0.005)), tmp_path,
                        name=f"seed{s}") for s in (5, 6)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    assert d.verdict == "drag_moment", d.summary()
    fm = d.fitted_model
    assert "drag_moment" in fm.model.effect_names and fm.converged
    for i in range(2):
        assert fm.value(f"k_dm[{i}]") == pytest.approx(0.005, rel=0.03)
    if any(r.verdict == "hub_rotor_drag" for r in d.rounds) and d.input_timing:
        assert "hub_rotor_drag" not in fm.model.effect_names
        assert any("hub_rotor_drag, a verdict of the rounds, is physically negligible" in w for w in d.warnings)
    # whatever the rounds added, nothing physically negligible is in the final model
    from greybox.diagnosis.screening import physically_negligible
    added = [e for e in fm.model.effect_names if e not in model.effect_names]
    assert not any(physically_negligible(fm, e) for e in added), d.summary()


@pytest.mark.slow
def test_two_flights_of_a_hub_rotor_drag_keep_the_catalogue_chain_against_discovery(tmp_path):
    """A rotor drag at each hub (k = 4e-5, hubs 2 cm above the CoG, the airframe's rotors in
    the CoG's plane) on two estimation flights of the 0.42 kg vehicle. Until hub_rotor_drag had
    the hubs' height, the rounds found drag_moment, then hub_rotor_drag, and discovery's
    combination (my ~ vx_b plus a p*t term) predicted a little better than that chain (0.043
    against 0.057; a blind audit's null verdict "outside the catalogue"). With the height the
    one effect is the truth: hub_rotor_drag alone (round 2's drag_moment removes 0.5 %), k_rdh
    and h_hub within 3 std, validation 0.010, and the catalogue stands against discovery. Each
    flight's halves are compared (they were not: a 2-flight baseline's process noise is given
    per flight)."""
    veh = _peer_400g()
    paths = {s: write_case(fly(veh, duration=20.0, seed=s, effects=PeerEffects(rotor_drag=4e-5)), tmp_path,
                           name=f"seed{s}") for s in (5, 6, 7)}
    model = QuadrotorModel(load_airframe(paths[5]["airframe"]))
    lines: list[str] = []
    d = diagnose(model, [load_log(paths[s]["log"]) for s in (5, 7)], validation=load_log(paths[6]["log"]),
                 progress=lines.append)
    assert d.baseline_certified and not any("halves not compared" in x for x in lines)
    assert d.verdict == "hub_rotor_drag" and d.null_reason is None, d.summary()
    assert "hub_rotor_drag" in d.final_model.effect_names and "drag_moment" not in d.final_model.effect_names
    fm = d.final_fit
    std = dict(zip(fm.free_names, fm.std))
    for name, truth in (("k_rdh", 4e-5), ("h_hub", veh.hub_height)):
        assert abs(fm.value(name) - truth) <= 3 * std[name], (name, fm.value(name), std[name])
    assert d.final_prediction.total < 0.02


@pytest.mark.slow
def test_a_2_5_kg_vehicle_with_nothing_missing_is_null_with_no_failure_to_locate(tmp_path):
    """A blind audit's 2.5 kg vehicle (arm 0.25 m, 200 Hz log, ESC speeds, its own 500 Hz
    controller), nothing beyond the rigid body, thrust, reaction and gyroscopic torque: the
    verdict is null, K_T and b are within 3 std of the truth, and "where it fails" names no
    regime: every channel is at its sensor noise (it read "q error grows with horizontal
    speed", the gyro noise's own regime, before findings were limited to channels off it)."""
    veh = PeerVehicle(name="peer_2p5kg", mass=2.5, inertia=(0.03, 0.03, 0.05), arm=0.25, K_T=1.7e-5, b=2.55e-7,
                      tau_motor=0.04, rotor_radius=0.165, rotor_inertia=1.2e-4, hub_height=0.04, distance=1.2,
                      speed=2.0, low_hover=0.165, cruise_height=1.2, log_rate=200.0, pos_rate=50.0,
                      pos_noise=0.002, att_noise=0.003, gyro_noise=0.005, speed_quantum=1.0,
                      attitude_bandwidth=15.0, position_bandwidth=1.8, ctrl_rate=500.0)
    cases = [write_case(fly(veh, duration=25.0, seed=s), tmp_path, name=f"seed{s}", hub_heights=True) for s in (5, 6)]
    model = QuadrotorModel(load_airframe(cases[0]["airframe"]))
    d = diagnose(model, load_log(cases[0]["log"]), validation=load_log(cases[1]["log"]))
    assert d.verdict is None and d.baseline.converged
    fm = d.fitted_model
    for name, truth in (("K_T", veh.K_T), ("b", veh.b)):
        assert abs(fm.value(name) - truth) < 3 * fm.std[fm.free_names.index(name)], (name, fm.value(name), truth)
    assert d.findings == []


@pytest.mark.slow
def test_attitude_bias_and_vision_latency_are_what_the_log_reports():
    """By hand: with the estimator's level reference off by (0.03, -0.02) rad, the logged roll
    and pitch are the vehicle's plus the bias (their mean difference is the bias within the
    sensor noise's mean), and the controller levels the biased estimate, so the vehicle flies
    another path than without the bias. With a 50-ms latency the logged position is the
    state's 50 ms earlier (a 25-sample shift at 500 Hz)."""
    veh = PeerVehicle.crazyflie()
    bias = (0.03, -0.02)
    fl = fly(veh, duration=4.0, seed=3, sensors=PeerSensors(att_bias=bias, pos_dropout=0.0, pos_gaps=()),
             low_hovers=False)
    true_eul = np.array([rot_to_euler(quat_to_rot(q)) for q in fl.states[:, 6:10]])
    n = len(fl.columns["t"])
    tol = 4 * veh.att_noise / math.sqrt(n)
    for j, name in enumerate(("phi", "theta")):
        assert np.mean(fl.columns[name] - true_eul[:, j]) == pytest.approx(bias[j], abs=tol)
    assert fl.truth["greybox_equivalent"]["att_bias"] == list(bias)
    # the controller acts on the biased estimate: the same seed without the bias flies another
    # path (centimetres apart while the integral re-trims through the turns); were the bias
    # only written into the log, the two would be the same to the last digit
    unbiased = fly(veh, duration=4.0, seed=3, sensors=PeerSensors(pos_dropout=0.0, pos_gaps=()), low_hovers=False)
    assert np.abs(fl.states[:, :2] - unbiased.states[:, :2]).max() > 0.01

    exact = PeerVehicle.crazyflie(pos_noise=0.0, pos_rate=500.0)
    sens = dict(pos_dropout=0.0, pos_gaps=(), time_jitter=0.0)
    now = fly(exact, duration=2.0, seed=4, sensors=PeerSensors(**sens))
    late = fly(exact, duration=2.0, seed=4, sensors=PeerSensors(pos_delay=0.05, **sens))
    for name in "xyz":
        assert np.allclose(late.columns[name][25:], now.states[:-25, "xyz".index(name)], atol=1e-9)
    assert late.truth["greybox_equivalent"]["tau_pos"] == 0.05


SENSOR_VEHICLES = {"1kg": (PeerVehicle.one_kg, 20.0),
                   "cf_100hz": (lambda: PeerVehicle.crazyflie(log_rate=100.0), 25.0)}
"""The sensor tests' vehicles: (maker, flight duration s)."""


def _diagnose_two_flights(tmp_path, veh: PeerVehicle, duration: float, sens: PeerSensors):
    """Flights of seeds 1 (estimation) and 2 (validation) written and read back as a user's
    files, diagnosed with every default: (the diagnosis, the truth's greybox equivalents)."""
    flights = [fly(veh, duration=duration, seed=s, sensors=sens) for s in (1, 2)]
    paths = [write_case(f, tmp_path, name=f"seed{i + 1}") for i, f in enumerate(flights)]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    d = diagnose(model, load_log(paths[0]["log"]), validation=load_log(paths[1]["log"]))
    return d, flights[0].truth["greybox_equivalent"]


def _assert_recovered(res, name: str, truth: float, within_std: float = 3.0) -> None:
    std = res.std[res.free_names.index(name)]
    assert abs(res.value(name) - truth) < within_std * std, (name, res.value(name), std, truth)


@pytest.mark.slow
@pytest.mark.parametrize("vehicle", ["1kg", "cf_100hz"])
def test_attitude_estimate_off_level_is_named_attitude_bias_and_recovered(tmp_path, vehicle):
    """The estimator's roll and pitch off by 1.7 and -1.1 degrees (the controller levels the
    biased estimate, so the vehicle hovers level while the log says it is tilted), nothing else
    missing, starting values 40 % off: the baseline is certified, the verdict is
    ``attitude_bias`` alone, its offsets are the truth's within 3 std, K_T and b within 5 %."""
    make, duration = SENSOR_VEHICLES[vehicle]
    d, truth = _diagnose_two_flights(tmp_path, make(), duration, PeerSensors(att_bias=(0.03, -0.02)))
    assert d.baseline_certified
    assert [r.verdict for r in d.rounds if r.verdict] == ["attitude_bias"], d.summary()
    for i in range(2):
        _assert_recovered(d.final_fit, f"att_bias[{i}]", truth["att_bias"][i])
    assert d.final_fit.value("K_T") == pytest.approx(truth["K_T"], rel=0.05)
    assert d.final_fit.value("b") == pytest.approx(truth["b"], rel=0.05)


@pytest.mark.slow
@pytest.mark.parametrize("vehicle, latency", [("1kg", 0.05), ("cf_100hz", 0.03)])
def test_vision_latency_is_named_position_delay_and_recovered(tmp_path, vehicle, latency):
    """The logged position is the vehicle's 50 ms (1.2 kg, 60 Hz vision) or 30 ms (30 g, 100 Hz)
    late, nothing else missing: the baseline is certified, the verdict is ``position_delay``
    alone, ``tau_pos`` is the latency within 3 std, K_T and b within 5 %."""
    make, duration = SENSOR_VEHICLES[vehicle]
    d, truth = _diagnose_two_flights(tmp_path, make(), duration, PeerSensors(pos_delay=latency))
    assert d.baseline_certified
    assert [r.verdict for r in d.rounds if r.verdict] == ["position_delay"], d.summary()
    _assert_recovered(d.final_fit, "tau_pos", latency)
    assert d.final_fit.value("K_T") == pytest.approx(truth["K_T"], rel=0.05)
    assert d.final_fit.value("b") == pytest.approx(truth["b"], rel=0.05)


@pytest.mark.slow
@pytest.mark.parametrize("latency", [0.0, 0.15])
def test_outdoor_sensor_mix_is_null_or_names_its_latency(tmp_path, latency):
    """An outdoor vehicle's sensors (1.2 kg, 250 Hz log, position at 10 Hz with 5 cm noise as
    a GNSS-aided estimate gives it, the attitude estimate's noise correlated over 0.1 s, the
    accelerometer logged), starting values 40 % off: with nothing missing the verdict is null
    on a certified baseline with K_T and b within 1 %; with the position 150 ms late (a GNSS
    receiver's latency) the verdict is ``position_delay`` alone, ``tau_pos`` within 3 std."""
    veh = PeerVehicle.one_kg(log_rate=250.0, pos_rate=10.0, pos_noise=0.05)
    sens = PeerSensors(accel=True, att_correlation=0.1, pos_dropout=0.0, pos_gaps=(), pos_delay=latency)
    d, truth = _diagnose_two_flights(tmp_path, veh, 30.0, sens)
    assert d.baseline_certified
    added = [r.verdict for r in d.rounds if r.verdict]
    fm = d.final_fit or d.baseline
    if latency:
        assert added == ["position_delay"], d.summary()
        _assert_recovered(fm, "tau_pos", latency)
    else:
        assert d.verdict is None and added == [], d.summary()
    assert fm.value("K_T") == pytest.approx(truth["K_T"], rel=0.01)
    assert fm.value("b") == pytest.approx(truth["b"], rel=0.01)


@pytest.mark.slow
@pytest.mark.parametrize("correlation", [0.1, 0.0])
def test_a_bias_std_that_understates_its_scatter_is_seen_by_the_halves(tmp_path, correlation):
    """The 1.2 kg vehicle outdoors (250 Hz log, 10 Hz position with 5 cm noise) with its
    attitude estimate off level by (0.03, -0.02) rad: with that estimate's noise an AR(1) over
    0.1 s, the soft fit's states follow the noise and the bias's std (2e-5 rad) is far below
    its scatter (the noise's mean over the flight, about 2.4e-4): this draw's roll is 6.5 std
    off. Each half of the flight alone (``half_spread``) then disagrees with the other beyond
    their std, and their spread covers the error; with white noise of the same level the std
    is right and the halves agree."""
    veh = PeerVehicle.one_kg(log_rate=250.0, pos_rate=10.0, pos_noise=0.05)
    sens = PeerSensors(accel=True, att_correlation=correlation, pos_dropout=0.0, pos_gaps=(), att_bias=(0.03, -0.02))
    paths = write_case(fly(veh, duration=30.0, seed=1, sensors=sens), tmp_path, name="est")
    model = QuadrotorModel(load_airframe(paths["airframe"]))
    log, _ = denoise_inputs(model, load_log(paths["log"]))
    m = model + AttitudeBias()
    res = fit(m, log)
    assert res.converged and res.process_noise is not None
    comps = ["att_bias[0]", "att_bias[1]"]
    spread = half_spread(m, res, [log], comps, "auto", lambda s: None)
    z = {c: (res.value(c) - t) / float(res.std[res.free_names.index(c)]) for c, t in zip(comps, (0.03, -0.02))}
    if correlation:
        assert abs(z["att_bias[0]"]) > 5 and "att_bias[0]" in spread, (z, spread)
        a, _, b, _ = spread["att_bias[0]"]
        assert abs(res.value("att_bias[0]") - 0.03) < 3 * abs(a - b) / 2     # the halves' spread covers it
    else:
        assert max(abs(v) for v in z.values()) < 3 and spread == {}, (z, spread)
        # nor does another flight (seed 2) fitted alone disagree
        val_paths = write_case(fly(veh, duration=30.0, seed=2, sensors=sens), tmp_path, name="val")
        val, _ = denoise_inputs(model, load_log(val_paths["log"]))
        assert validation_spread(m, res, [val], comps, "auto", lambda s: None) == {}


@pytest.mark.slow
def test_a_bias_std_whose_halves_agree_by_chance_is_seen_by_another_flight(tmp_path):
    """The same vehicle and AR(1) attitude noise, seed 5: the roll bias is 23 std off
    (0.03045 +- 2e-5 for 0.03) while the two halves of the flight agree within their std; the
    same model fitted on another flight (seed 6) alone disagrees beyond both std
    (``validation_spread``: 0.02945 +- 3e-5), and their spread (|a - b| / sqrt 2) covers the
    error. Measured once: pitch 13 std off, flagged by the halves."""
    veh = PeerVehicle.one_kg(log_rate=250.0, pos_rate=10.0, pos_noise=0.05)
    sens = PeerSensors(accel=True, att_correlation=0.1, pos_dropout=0.0, pos_gaps=(), att_bias=(0.03, -0.02))
    paths = [write_case(fly(veh, duration=30.0, seed=seed, sensors=sens), tmp_path, name=name)
             for seed, name in ((5, "est"), (6, "val"))]
    model = QuadrotorModel(load_airframe(paths[0]["airframe"]))
    (est, _), (val, _) = (denoise_inputs(model, load_log(p["log"])) for p in paths)
    m = model + AttitudeBias()
    res = fit(m, est)
    assert res.converged and res.process_noise is not None
    comps = ["att_bias[0]", "att_bias[1]"]
    roll_z = (res.value("att_bias[0]") - 0.03) / float(res.std[res.free_names.index("att_bias[0]")])
    assert abs(roll_z) > 10, roll_z
    assert "att_bias[0]" not in half_spread(m, res, [est], comps, "auto", lambda s: None)
    spread = validation_spread(m, res, [val], comps, "auto", lambda s: None)
    assert "att_bias[0]" in spread, spread
    a, _, b, _ = spread["att_bias[0]"]
    assert abs(res.value("att_bias[0]") - 0.03) < 3 * abs(a - b) / np.sqrt(2)

"""Is an attitude residual motion the model misses, or the attitude sensor's own error?
(:func:`greybox.residuals.attitude_motion`): worked by hand on residuals built from the Euler
kinematics, and on sensor errors the gyro does not share."""
import numpy as np
from scipy.signal import lfilter

from greybox.data import FlightLog
from greybox.model import OUTPUTS
from greybox.residuals import attitude_motion

RATE = 500.0


def _ar1(rng, n, tau, rms, k=1):
    rho = np.exp(-1.0 / (RATE * tau))
    return lfilter([np.sqrt(1 - rho ** 2)], [1, -rho], rng.standard_normal((n, k)), axis=0) * rms


def _log(t, phi, theta):
    n = len(t)
    Y = np.full((n, 9), np.nan)
    Y[:, 3], Y[:, 4], Y[:, 5] = phi, theta, 0.0
    return FlightLog(t, np.full((n, 4), 300.0), ["w1", "w2", "w3", "w4"], Y, list(OUTPUTS[:9]))


def _residuals(n, angles, rates):
    E = np.full((n, len(OUTPUTS)), np.nan)
    for ch, v in {**angles, **rates}.items():
        E[:, OUTPUTS.index(ch)] = v
    return E


def test_a_yaw_rate_residual_moves_the_euler_angles_through_the_kinematics():
    """Banked (phi 0.3, theta 0.2) with only a body yaw-rate residual e_r: by hand,
    d/dt (e_phi, e_theta, e_psi) = (cos(phi) tan(theta), -sin(phi), cos(phi)/cos(theta)) e_r.
    Angle residuals built that way (plus white sensor noise) are motion: slope 1 on each axis,
    coherence near 1; a transposed or sign-flipped kinematic map would give other slopes."""
    rng = np.random.default_rng(0)
    n = int(20 * RATE)
    t = np.arange(n) / RATE
    phi, theta = 0.3, 0.2
    e_r = _ar1(rng, n, 0.2, 0.05)[:, 0]
    w = np.array([np.cos(phi) * np.tan(theta), -np.sin(phi), np.cos(phi) / np.cos(theta)])
    integral = np.cumsum(e_r) / RATE
    angles = {ch: w[k] * integral + 2e-4 * rng.standard_normal(n) for k, ch in enumerate(("phi", "theta", "psi"))}
    E = _residuals(n, angles, {"p": np.zeros(n), "q": np.zeros(n), "r": e_r})
    got = attitude_motion([E], [_log(t, np.full(n, phi), np.full(n, theta))])
    for ch in ("phi", "theta", "psi"):
        assert abs(got[ch].gain - 1.0) < 0.05, (ch, got[ch])
        assert got[ch].coherence > 0.8, (ch, got[ch])


def test_an_attitude_sensor_error_is_not_motion_and_a_gyro_bias_drops_out():
    """Level flight, the attitude residual is the sensor's coloured noise (correlated over
    50 ms) and the rate residual the gyro's own noise plus a constant bias: the integrated gyro
    residual accounts for almost none of the angle residual, and its slope is far from 1."""
    rng = np.random.default_rng(1)
    n = int(30 * RATE)
    t = np.arange(n) / RATE
    ang = _ar1(rng, n, 0.05, 0.003, 3)
    gyro = 0.005 * rng.standard_normal((n, 3)) + np.array([0.02, -0.01, 0.005])
    E = _residuals(n, dict(zip(("phi", "theta", "psi"), ang.T)), dict(zip(("p", "q", "r"), gyro.T)))
    got = attitude_motion([E], [_log(t, np.zeros(n), np.zeros(n))])
    for ch in ("phi", "theta", "psi"):
        assert got[ch].coherence < 0.05, (ch, got[ch])
        assert abs(got[ch].within_rms / 0.003 - 1) < 0.2, (ch, got[ch])


def test_stretches_restart_the_integral_at_the_shooting_nodes():
    """With process noise the fitted trajectory restarts at every node: the angle residual
    follows the rate residual's integral from each node only. Built that way, the slope is 1
    with the nodes as stretch starts and far from it with one-second windows."""
    rng = np.random.default_rng(2)
    n = int(20 * RATE)
    t = np.arange(n) / RATE
    nodes = np.arange(0, n, 25)
    e_p = _ar1(rng, n, 0.3, 0.1)[:, 0]
    step = e_p / RATE
    step[nodes] = 0.0
    integral = np.cumsum(step)
    which = np.searchsorted(nodes, np.arange(n), side="right") - 1
    e_phi = integral - integral[nodes][which] + 1e-5 * rng.standard_normal(n)
    zeros = np.zeros(n)
    E = _residuals(n, {"phi": e_phi, "theta": zeros + 1e-5 * rng.standard_normal(n),
                       "psi": 1e-5 * rng.standard_normal(n)}, {"p": e_p, "q": zeros, "r": zeros})
    log = _log(t, zeros, zeros)
    at_nodes = attitude_motion([E], [log], starts=[nodes])["phi"]
    assert abs(at_nodes.gain - 1.0) < 0.05 and at_nodes.coherence > 0.9, at_nodes
    windows = attitude_motion([E], [log])["phi"]
    assert windows.gain < 0.5, windows


def test_a_constant_attitude_offset_is_not_called_the_sensors_coloured_noise():
    """A residual that is a constant offset plus white noise is not motion either, but the
    stretches (detrended) see only the noise: its excess lies between them, so it is left to
    the ``attitude_bias`` candidate, not declared the sensor's coloured noise; the coloured
    noise of the same RMS is."""
    rng = np.random.default_rng(3)
    n = int(30 * RATE)
    t = np.arange(n) / RATE
    noise = 0.003
    zeros = np.zeros(n)
    rates = {"p": 0.005 * rng.standard_normal(n), "q": 0.005 * rng.standard_normal(n), "r": zeros}
    offset = 0.02 + noise * rng.standard_normal(n)
    coloured = _ar1(rng, n, 0.05, 0.02)[:, 0]
    log = _log(t, zeros, zeros)
    for e, sensor in ((offset, False), (coloured, True)):
        E = _residuals(n, {"phi": e, "theta": noise * rng.standard_normal(n), "psi": zeros}, rates)
        m = attitude_motion([E], [log])["phi"]
        ratio = float(np.sqrt(np.mean(e ** 2))) / noise
        assert ratio > 6
        assert m.angle_is_sensor_error(ratio, noise) is sensor, (m, ratio)


def test_fit_keeps_output_error_when_only_a_filtered_attitude_is_off_the_noise():
    """Greybox's own flight (nothing missing) logged with an attitude estimate whose error is
    correlated over 50 ms (3 mrad RMS on 0.5 mrad white): output error is right, the
    high-frequency noise estimate does not count the coloured error, and process noise would
    let the states follow it (Kd[1] 2.9 std off before). The gyro does not see it, so the fit
    keeps output error, says why, and recovers the drag within 3 std."""
    from pathlib import Path
    from greybox import QuadrotorModel, load_airframe
    from greybox.fitting import fit
    from greybox.synth import SensorSpec, synthesize
    paper = Path(__file__).resolve().parent.parent / "greybox" / "data" / "airframes" / "paper.toml"
    model = QuadrotorModel(load_airframe(paper))
    r = synthesize(model, duration=30.0, seed=1, sensors=SensorSpec(rate=500, att_noise=0.0005))
    log = r.log
    rng = np.random.default_rng(101)
    for c, err in zip(("phi", "theta", "psi"), _ar1(rng, len(log.t), 0.05, 0.003, 3).T):
        log.outputs[:, log.output_names.index(c)] += err
    res = fit(model, log, p0={"K_T": 3.1e-5, "b": 4.1e-7, "Kd": [0.2, 0.2, 0.2]})
    assert res.converged and res.process_noise is None
    assert set(res.certificate.sensor_error) == {"phi", "theta", "psi"}, res.certificate.text()
    assert any("not motion" in w for w in res.warnings)
    truth = model.parameter_dict(r.parameters)
    for n in ("Kd[0]", "Kd[1]", "Kd[2]", "b"):
        z = (res.value(n) - truth[n]) / res.std[res.free_names.index(n)]
        assert abs(z) < 3, (n, res.value(n), truth[n], z)

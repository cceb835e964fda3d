"""What the sensors report: latency of the position measurement, where the position sensor
sits on the vehicle, offsets of the measured roll and pitch, the accelerometer's bias, the
gyro's bias and scale."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..data import FlightLog
from ..kinematics import gyro_bias_reading, gyro_scale
from ..parameters import Parameter
from .base import Effect

__all__ = ["PositionDelay", "PositionOffset", "AttitudeBias", "AccelBias", "GyroBias", "GyroScaleError"]


class PositionDelay(Effect):
    """Latency ``tau_pos`` of the position measurement (vision pipeline): the sensor
    reports ``p(t - tau_pos)``, modelled by its second-order Taylor expansion
    ``p - tau_pos*v + tau_pos**2/2 * a`` (exact to ``tau^3 * jerk / 6``: sub-millimetre for
    latencies below 0.1 s in ordinary flight), so no delay states are needed.
    """

    name = "position_delay"
    input_timed = ("tau_pos",)
    summary = "latency of the position measurement"
    excited_by = 'fast translations (a delay lags the velocity)'
    fit_advice = 'fast translations (fast)'
    channels = ('x', 'y', 'z')

    def parameters(self, airframe):
        return [Parameter("tau_pos", 1, 0.0, "s", 0.0, 0.3, 0.02, 0.0, True,
                          "position measurement latency", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"tau_pos": 0.04}

    def modify_measurement(self, ctx, y):
        tau = ctx.params["tau_pos"]
        for i, ch in enumerate("xyz"):
            y[ch] = y[ch] - tau * ctx.v[i] + 0.5 * tau ** 2 * ctx.acc_world[i]


class PositionOffset(Effect):
    """Where the position sensor sits: a GNSS antenna, or the origin a motion-capture system
    gives the vehicle's markers, at ``r_pos`` from the centre of gravity (body frame, FRD, m)
    reports ``p + R r_pos``. The offset turns with the body: an antenna 15 cm above the CoG
    moves 7.5 cm sideways at 30 degrees of roll, and a yaw turn swings one 10 cm ahead on a
    circle. It changes what the sensor reports, not how the vehicle moves (PX4 removes it when
    ``EKF2_GPS_POS_*`` is set; a log from a vehicle where it is not, or a motion-capture body
    whose origin is not the CoG, carries it). Its constant part in a level hover is the
    start position's, so the data tell it only through tilts and yaw turns.
    """

    name = "position_offset"
    summary = "position sensor (GNSS antenna, motion-capture origin) away from the centre of gravity"
    excited_by = 'tilts and yaw turns (the offset turns with the body)'
    fit_advice = 'yaw turns and tilts in several directions'
    channels = ('x', 'y', 'z')
    distinguish = {'position_delay': 'yaw turns in a hover: an offset swings the reported position, a delay of '
                                     'a vehicle at rest moves nothing',
                   'cog_offset': 'hover: a CoG offset needs a trim moment (the rotors driven unequally), a sensor '
                                 'offset moves nothing'}

    def parameters(self, airframe):
        reach = max(0.5, 8.0 * airframe.arm_length)
        return [Parameter("r_pos", 3, 0.0, "m", -reach, reach, 0.02, 0.0, True,
                          "position sensor offset from the centre of gravity, body x, y, z (FRD)", self.name)]

    def plausible_values(self, airframe, K_T):
        # an antenna on a short mast, a little ahead: half an arm up, a fifth ahead
        return {"r_pos": [0.2 * airframe.arm_length, 0.0, -0.5 * airframe.arm_length]}

    def plausible_limits(self, airframe):
        # a sensor on the airframe or a mast above it: within a few arm lengths of the CoG
        return {"r_pos": max(0.1, 3.0 * airframe.arm_length)}

    def modify_measurement(self, ctx, y):
        offset = ctx.R @ ctx.params["r_pos"]
        for i, ch in enumerate("xyz"):
            y[ch] = y[ch] + offset[i]


class AttitudeBias(Effect):
    """Constant offsets of the measured roll and pitch (IMU mounting misalignment):
    ``phi_meas = phi + att_bias[0]``, ``theta_meas = theta + att_bias[1]``.
    """

    name = "attitude_bias"
    summary = "constant roll/pitch measurement offsets"
    excited_by = 'long hovers at several headings'
    fit_advice = 'hover and slow translations'
    channels = ('phi', 'theta', 'x', 'y')

    def parameters(self, airframe):
        return [Parameter("att_bias", 2, 0.0, "rad", -0.3, 0.3, 0.01, 0.0, True,
                          "roll and pitch measurement offsets", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"att_bias": [0.02, -0.015]}

    def modify_measurement(self, ctx, y):
        y["phi"] = y["phi"] + ctx.params["att_bias"][0]
        y["theta"] = y["theta"] + ctx.params["att_bias"][1]


class AccelBias(Effect):
    """Constant biases of the accelerometer (a MEMS IMU's offset, tens to hundreds of mm/s²):
    ``a_meas = R^T(a - g e3) + acc_bias`` per body axis (m/s², FRD). It changes what the
    accelerometer reports, not how the vehicle moves: without it, a bias in ``ax`` or ``ay``
    is taken for a force that is not there (a wind indoors on a real Crazyflie flight).
    Considered by the diagnosis when the log measures the specific force (``ax``). Shared
    by the flights of a joint fit (one sensor; a bias that changes between power-ups calls
    for separate fits).
    """

    name = "accel_bias"
    summary = "constant accelerometer biases (body x, y, z)"
    excited_by = 'any flight with the accelerometer logged (a bias does not move the vehicle)'
    fit_advice = 'hover and translations in several directions'
    channels = ('ax', 'ay', 'az')
    considered_when_logged = ('ax',)
    distinguish = {'wind': 'fly in several directions: a wind moves the vehicle, a bias only the accelerometer',
                   'attitude_bias': 'hover with the position logged: an attitude bias tilts the thrust the vehicle '
                                    'flies with (it drifts until the controller trims), an accelerometer bias moves '
                                    'nothing'}

    def parameters(self, airframe):
        return [Parameter("acc_bias", 3, 0.0, "m/s^2", -3.0, 3.0, 0.1, 0.0, True,
                          "accelerometer biases, body x, y, z", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"acc_bias": [0.1, -0.1, 0.1]}

    def plausible_limits(self, airframe):
        # consumer MEMS accelerometers' zero-g offsets: within about 20-80 mg after mounting
        return {"acc_bias": 0.8}

    def modify_measurement(self, ctx, y):
        b = ctx.params["acc_bias"]
        for i, ch in enumerate(("ax", "ay", "az")):     # the model's outputs always hold all three
            y[ch] = y[ch] + b[i]


class GyroBias(Effect):
    """Constant biases of the gyro per body axis (a MEMS gyro's zero-rate offset that its
    power-up calibration left, or drifted with temperature: 0.005-0.05 rad/s is common):
    ``p_meas = p + gyro_bias[0]`` and likewise ``q``, ``r`` (rad/s). It changes what the gyro
    reports, not how the vehicle moves; the attitude, which does not turn with it, tells it
    apart from a torque. Without it, the model takes the offset for a turning the vehicle does
    not do (a blind audit's 250 g vehicle with 0.02 rad/s on p: "a roll torque the model lacks
    ... outside the catalogue", its control flight never adequate). Considered by the diagnosis
    when the log measures the rates (``p``); shared by the flights of a joint fit (one sensor;
    a bias that changes between power-ups calls for separate fits).
    """

    name = "gyro_bias"
    summary = "constant gyro biases (body p, q, r)"
    excited_by = "any flight with the gyro and an independent attitude logged (a bias does not move the vehicle)"
    fit_advice = "hover and turns with the attitude measured independently of the gyro"
    channels = ("p", "q", "r")
    considered_when_logged = ("p",)
    distinguish = {"cog_offset": "a centre of gravity off is a torque the controller trims (the commands show "
                                 "it); a gyro bias turns nothing: the attitude does not follow the gyro's integral"}

    def parameters(self, airframe):
        return [Parameter("gyro_bias", 3, 0.0, "rad/s", -0.5, 0.5, 0.01, 0.0, True,
                          "gyro biases, body p, q, r (measured = true rate + gyro_bias)", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"gyro_bias": [0.01, -0.01, 0.01]}

    def negligible_size(self, airframe):
        # a calibrated MEMS gyro's residual offset: a tenth of a degree per second
        return {"gyro_bias": 0.002}

    def plausible_limits(self, airframe):
        # consumer MEMS gyros' zero-rate offsets before calibration: a few degrees per second
        return {"gyro_bias": 0.15}

    def validation_reading(self, logs, values, std):
        # the flights' own gyro against their attitude's turning (kinematics.gyro_bias_reading),
        # pooled by inverse variance: each axis fitted beyond its negligible size must agree with
        # it within 3 std of both, and one must show beyond 3 of its std in the data alone
        reads = [r for r in map(gyro_bias_reading, logs) if r]
        if not reads:
            return ""
        fitted, fitted_std = list(values["gyro_bias"]), list(std.get("gyro_bias", [0.0] * 3))
        small = self.negligible_size(None)["gyro_bias"]
        said, shown = [], False
        for a, axis in enumerate(("p", "q", "r")):
            pairs = [r[axis] for r in reads if axis in r and r[axis][1] > 0]
            if not pairs:
                continue
            w = np.array([1.0 / s ** 2 for _, s in pairs])
            b = float(np.dot(w, [v for v, _ in pairs]) / w.sum())
            s = float(1.0 / np.sqrt(w.sum()))
            if abs(fitted[a]) >= small and abs(b - fitted[a]) > 3.0 * math.hypot(s, fitted_std[a]):
                return ""
            shown = shown or (abs(b) > 3.0 * s and abs(fitted[a]) >= small)
            said.append(f"{axis} {b:+.3g} ± {s:.1g}")
        if not shown:
            return ""
        return ("the validation flights' own gyro against their attitude's turning reads a bias of "
                + ", ".join(said) + " rad/s")

    def modify_measurement(self, ctx, y):
        b = ctx.params["gyro_bias"]
        for i, ch in enumerate(("p", "q", "r")):
            y[ch] = y[ch] + b[i]


class GyroScaleError(Effect):
    """Scale errors of the gyro per body axis (an uncalibrated MEMS gyro: 1-3 % is common):
    ``p_meas = (1 + k_gyro[0]) p`` and likewise ``q``, ``r``. It changes what the gyro
    reports, not how the vehicle moves; the measured attitude tells it apart, since the
    attitude turns at the true rate. Without it, the model is fitted to the gyro's rates and
    the attitude at once and its moments absorb the difference (a blind audit's 0.9 kg
    vehicle with its gyro 3 % high: "nothing missing", ``b`` +1.7 %, 12 std); the log alone
    reads it too (:func:`greybox.kinematics.gyro_scale`, a fit's warning). Considered by the
    diagnosis when the log measures the rates (``p``) and its reading against the attitude
    hints at a scale error (:meth:`~greybox.kinematics.GyroScale.hints`); shared by the
    flights of a joint fit (one sensor). An attitude that an autopilot integrates from the
    same gyro turns with its error, and leaves nothing to fit.
    """

    name = "gyro_scale"
    summary = "gyro scale errors (body p, q, r)"
    excited_by = "turns about each body axis with the attitude measured independently of the gyro"
    fit_advice = "roll, pitch and yaw turns, with vision or motion capture measuring the attitude"
    channels = ("p", "q", "r")
    considered_when_logged = ("p",)
    distinguish = {"moment_gain": "measure the attitude independently of the gyro: a gyro scale error makes "
                                  "the gyro disagree with the attitude's turning, a moment gain turns both alike"}

    @classmethod
    def considered_for(cls, logs: Sequence[FlightLog]) -> bool:
        # tried where the log alone hints at a scale error (the attitude's turning against the
        # gyro's integral): elsewhere the scale's refit stands in for a moment the model lacks
        # (a real Crazyflie flight whose attitude the log cannot read against the gyro:
        # k_gyro on its bounds in every round, taking a refit from the candidates that stand)
        return any(g is not None and g.hints() for g in map(gyro_scale, logs))

    def parameters(self, airframe):
        return [Parameter("k_gyro", 3, 0.0, "", -0.3, 0.3, 0.01, 0.0, True,
                          "gyro scale errors, body p, q, r (measured = (1 + k_gyro) * true rate)", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"k_gyro": [0.03, -0.03, 0.03]}

    def negligible_size(self, airframe):
        # a calibrated MEMS gyro's residual scale error: the moments it moves are within
        # their spread (the log's own reading, kinematics.SCALE_NOTABLE, says 1 %)
        return {"k_gyro": 0.005}

    def plausible_limits(self, airframe):
        # a MEMS gyro's scale error before calibration: a few per cent (datasheets: 1-3 %);
        # beyond 10 % the rates stand in for something else (a moment the model lacks)
        return {"k_gyro": 0.1}

    def modify_measurement(self, ctx, y):
        k = ctx.params["k_gyro"]
        for i, ch in enumerate(("p", "q", "r")):
            y[ch] = (1 + k[i]) * y[ch]

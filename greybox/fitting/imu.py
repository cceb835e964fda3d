"""What a log of the IMU and the rotor commands alone identifies (no position).

A Crazyflie's uSD log, a bench log, a flight without motion capture: gyro, accelerometer
and rotor speeds (or commands mapped to speeds). Without position the translational states
are unobservable (velocity only up to a drift), so the multiple-shooting fit of the full
model cannot be posed; the rigid body's *equations* can be, sample by sample, from the
measured quantities (an equation-error fit, as the data-driven identification of
quadrotors with motor delays does):

* thrust, from the specific force along the rotor axis: ``-m a_z = K_T sum_i w_eff_i^2``;
* roll and pitch, from the gyro's change over each log step (the speeds held over it act
  there: contract §2): ``(J d omega/dt + omega x J omega)_x = g_x K_T sum_i (-y_i) w_eff_i^2
  + c_x`` with the step's mean of ``w_eff^2`` (``g_x = 1`` when the airframe's arm and inertia
  are right; ``c_x`` a constant trim: a centre-of-gravity offset, unequal rotors), and the
  same for pitch with ``x_i``;
* yaw: ``(J omega_dot + omega x J omega)_z = b sum_i spin_i w_eff_i^2 + c_z``;
* the torques of the model's effects that depend on nothing but the body rates and rotor
  speeds (:data:`KNOWN_TORQUE_EFFECTS`: the rotors' gyroscopic torque) are known and taken
  off the left side, computed by the model itself (left in, a 2.5 kg vehicle's roll and
  pitch gains came out 0.957 and 1.030 where its geometry was exact);
* the rotors' first-order lag ``w_eff' = (w - w_eff)/tau_m``, chosen by profiling the
  torque equations' joint fit over ``tau_m`` (the thrust equation lacks the vertical drag).

Identified: ``K_T`` (relative to the mass you give), ``b``, ``tau_m``, and the roll/pitch
torque gains ``g_x, g_y`` (a check of arm and inertia). Not identified: drag (it needs the
velocity), the absolute inertia (only torque over inertia is seen), the position and
attitude of anything. Both sides are smoothed by the same Savitzky-Golay filter, so the
filtering does not bias the coefficients; the commands are regressors, not noisy
measurements. A logged attitude is not used (without position the velocity, and so the
translational equations, are not determined by it). In closed loop the controller answers every disturbance torque, which can
pull the torque coefficients towards zero: read ``g_x, g_y`` far below 1 that way.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import casadi as ca
import numpy as np
from scipy.optimize import minimize_scalar
from scipy.signal import lfilter, savgol_filter

from ..data import FlightLog
from ..errors import GreyboxInputError
from ..model import QuadrotorModel
from ..residuals import long_run_factor
from ..shooting import difference_noise, estimate_noise
from ..validation import DEFAULT_HORIZONS, HorizonErrors
from .certificate import NOISE_RATIO_COLOURED
from .robust import long_run_covariance

__all__ = ["ImuFit", "fit_imu", "is_imu_only", "IMU_EQUATIONS", "TAU_GRID", "HORIZON_CHANNELS",
           "KNOWN_TORQUE_EFFECTS", "DRAG_NOTE_RATIO", "LEAD_GRID", "LEAD_SHIFT", "SETTLE_TAUS", "ADEQUACY_WINDOW_S",
           "SYSTEMATIC_SHARE", "WHITE_DIFFERENCES", "FILTERED_NOISE_SPACING_S", "gyro_noise_on_average",
           "THRUST_CHANGE_NOTABLE", "ACCEL_BIAS_TYPICAL", "HAC_LAGS"]

KNOWN_TORQUE_EFFECTS = ("gyroscopic",)
"""Effects whose torque depends on the body rates and rotor speeds alone, with parameters the
IMU-only equations do not fit: known from what an IMU log measures."""

IMU_EQUATIONS = ("az", "p_dot", "q_dot", "r_dot")
"""The equations fitted: specific force along the rotor axis, angular accelerations."""

TORQUE_EQUATIONS = IMU_EQUATIONS[1:]
"""The angular-acceleration equations, on which the speeds' timing within a row is scored."""

TAU_GRID = tuple(float(x) for x in np.r_[0.0, np.arange(0.005, 0.3001, 0.005)])
"""Motor time constants (s) the profile is taken over."""

TAU_TOLERANCE = 1e-5
"""s: how closely the lag's minimum is found between the grid's points."""

TAU_CURVATURE_STEP = 1e-3
"""s: the step of the finite difference that gives the profile's curvature at its minimum."""

LEAD_GRID = (0.0, 0.125, 0.25, 0.375, 0.5)
"""Shares of the next row's speeds in the speeds acting over a row (``s_lead``) the profile is
taken over: 0 is the contract's zero-order hold (commands held over each row); speeds that
change within a row (commands sampled from a faster controller, measured rotor speeds) act
as if partly the next row's."""

LEAD_SHIFT = 3.0
"""A lead of :data:`LEAD_GRID` is taken only when it moves a fitted coefficient or the lag by
more than this many of their std with the speeds held (otherwise the contract's hold stands)."""

PROFILE_NEAR = 4
"""Grid points of ``tau_m`` below (and twice as many above) the held speeds' optimum at which
the other leads of :data:`LEAD_GRID` are scored."""

SMOOTHING_S = 0.02
"""Savitzky-Golay window (s) for the gyro's derivative and, alike, the regressors."""

SETTLE_TAUS = 6.0
"""Motor time constants at the log's start left out of each equation: the effective speeds
start at the first row's (nothing tells where the rotors were), and that guess decays as
``exp(-t / tau_m)`` (to 0.25 % here). Kept in, a blind audit's 250 Hz log that opens on
commands 30 % apart read its 20 ms motors' roll and pitch gains 1.5 and 3 % low (7 and 11
std) and its 45 ms motors 7 and 14 % low with the lag 14 % short."""

ADEQUACY_WINDOW_S = 0.1
"""The torque equations' residuals are judged averaged over this window: longer than the
derivative's smoothing (:data:`SMOOTHING_S`), so the gyro's white noise averages out, and
shorter than a manoeuvre, so a torque the model lacks does not."""

SYSTEMATIC_SHARE = 0.03
"""A systematic torque above this share of the fitted torques' RMS (and above the noise, the
trajectory fit's :data:`~greybox.fitting.certificate.NOISE_RATIO_COLOURED`) makes the fit
inadequate: physically non-negligible. On a blind audit's flights: 0 with nothing missing,
0.9 % with its 45 ms motors (gains 0.6 % low), 6-9 % with the airframe's rotor inertia
where the vehicle had none, 14-16 % with an 8 % weak rotor."""


WHITE_DIFFERENCES = 0.8
"""A gyro's noise is taken as white when the noise level read from its fourth differences is
at least this share of the one from its second (1.00 +- 0.02 for white noise over thousands of
samples, 0.98-1.01 on two blind audits' simulated gyros; a second-order low-pass at 30-200 Hz
on 500-1000 Hz samples gives 0.36-0.56, as autopilots filter their gyros)."""

MIN_DIFFERENCES = 20
"""Fewest differences from which :func:`gyro_noise_on_average` reads a noise level."""

FILTERED_NOISE_SPACING_S = 0.02
"""The longest spacing (s) at which a filtered gyro's noise level is looked for: where its
fourth differences stop growing, the noise is uncorrelated (a 30 Hz low-pass at 500 Hz: 16 ms)."""


def gyro_noise_on_average(y: np.ndarray, dt: float, through: float, window_s: float) -> tuple[float, str]:
    """The RMS that the gyro's noise in ``y`` (rad/s, samples ``dt`` apart) leaves on its
    derivative averaged over ``window_s``, and how it was read: ``"white"`` (the exact gain
    ``through`` of the derivative and average), ``"filtered"`` (a low-passed noise: its level
    read where its fourth differences stop growing, and taken unsmoothed into the average, whose
    derivative then telescopes to a difference of two samples ``window_s`` apart: an upper
    bound), or ``"unknown"`` (no such spacing within :data:`FILTERED_NOISE_SPACING_S`: nan)."""
    v = y[np.isfinite(y)]
    s2, s4 = difference_noise(v, 1, 2, MIN_DIFFERENCES), difference_noise(v, 1, 4, MIN_DIFFERENCES)
    if not s4 < WHITE_DIFFERENCES * s2:
        return through * s2, "white"
    levels = [difference_noise(v, k, 4, MIN_DIFFERENCES)
              for k in range(1, max(2, int(FILTERED_NOISE_SPACING_S / dt)) + 2)]
    for a, b in zip(levels, levels[1:]):
        if b < 1.05 * a:      # grown to the noise's own level (a smooth signal grows it as k^4)
            return math.sqrt(2.0) * a / window_s, "filtered"
    return float("nan"), "unknown"


def _misses(over_noise: float, share: float) -> bool:
    """Whether a torque equation's averaged residual is beyond the noise and non-negligible."""
    return over_noise > NOISE_RATIO_COLOURED and share > SYSTEMATIC_SHARE


GYRO_DEGREES_GAIN = 10.0
"""Roll and pitch torque gains both above this are a gyro logged in deg/s (57.3 times the
rad/s): a real Crazyflie's are 0.3-0.4, wrong inertias or arms move them by a factor of a few."""

HORIZON_CHANNELS = ("p", "q", "r", "az")
"""Channels whose prediction error against horizon an IMU-only fit reports."""

DRAG_NOTE_RATIO = 1.3
"""Horizontal specific force (RMS) over the accelerometer's noise above which an IMU-only fit
says that drag acts and that ``K_T`` may carry its vertical part: a force of at least 0.8 of
the noise's RMS, plain over the thousands of samples of a log (without one the ratio is 1.0;
two blind audits' vehicles with drag gave 1.6-6; at 2.0 a 3 kg vehicle's K_T was 5 std low
and a ratio of 3 said nothing)."""

HAC_LAGS = 50
"""Rows over which the coefficients' covariance counts their residuals' correlation (Bartlett
weights: the rows of a 20-ms smoothing and the lag's settling at 500 Hz-1 kHz)."""

THRUST_CHANGE_NOTABLE = 0.02
"""Relative change of ``K_T`` over the fitted part of an IMU-only log (the thrust equation
refitted with ``K_T`` linear in time) from which the fit says the thrust per w^2 changed over
the flight (a battery that sags) and is NOT ADEQUATE, when it is also beyond 3 of its std:
twice the largest that the vertical drag and the accelerometer's bias, which the thrust
equation lacks, gave a control flight (a blind audit's three vehicles, 30 g to 3 kg: up to
1.1 %, at up to 6 std; their 7.5 % battery sag read 5.8-6.0 % over the fitted 20 s)."""

ACCEL_BIAS_TYPICAL = 0.05
"""m/s^2: the residual bias of a calibrated MEMS accelerometer (about 5 mg), which an IMU-only
fit's ``K_T`` takes in full: said where it moves ``K_T`` by more than 3 of its std."""

WINDOW_SPACING_S = 0.05
"""s between the starts of the prediction windows of an IMU-only fit's ``horizons``."""


def is_imu_only(log: FlightLog) -> bool:
    """Whether ``log`` has gyro and accelerometer but no position (an attitude, if logged, is
    not used: :func:`fit_imu`)."""
    return not any(log.measures(c) for c in ("x", "y", "z")) and all(log.measures(c) for c in ("p", "q", "r", "az"))


@dataclass
class ImuFit:
    """An IMU-only identification (:func:`fit_imu`). ``parameters[name] = (value, std)``;
    ``nrmse[eq]`` the validation error of each equation (RMS residual over the RMS of the
    measured side about its mean) on the last part of the log; ``tau_profile`` the torque
    equations' joint cost against ``tau_m``; ``horizons`` the open-loop prediction error of the body rates
    and the specific force against horizon on that part, beside the naive predictor's
    (:func:`fit_imu`)."""

    parameters: dict[str, tuple[float, float]]
    nrmse: dict[str, float]
    tau_profile: list[tuple[float, float]]
    mass: float
    samples: int
    notes: list[str] = field(default_factory=list)
    horizons: "HorizonErrors | None" = None
    effects: list[str] = field(default_factory=list)
    residual_over_noise: dict[str, float] = field(default_factory=dict)
    """Per torque equation (``p_dot``, ``q_dot``, ``r_dot``), the RMS residual on the
    estimation part averaged over :data:`ADEQUACY_WINDOW_S`, over what the gyro's own noise
    gives through the same derivative and average."""
    systematic_share: dict[str, float] = field(default_factory=dict)
    """Per torque equation, the residual's part beyond the noise over the RMS of the fitted
    torque, both averaged over :data:`ADEQUACY_WINDOW_S`."""
    tau_at_end: bool = False
    """Whether ``tau_m`` ended at the long end of its profile, where the optimum may lie beyond."""
    thrust_change: tuple[float, float] = (0.0, float("nan"))
    """``K_T``'s relative change over the fitted part (end over start, less 1) with the thrust
    equation refitted with ``K_T`` linear in time, and its std (:data:`THRUST_CHANGE_NOTABLE`)."""

    @property
    def thrust_changes(self) -> bool:
        """Whether the thrust per w^2 changed over the flight (:func:`_thrust_changes`)."""
        return _thrust_changes(*self.thrust_change)

    @property
    def undetermined(self) -> list[str]:
        """The coefficients without a finite std: the log does not determine them (``tau_m``
        and ``s_lead`` are profiled, not solved for)."""
        return [n for n, (_, s) in self.parameters.items() if n not in ("tau_m", "s_lead") and not math.isfinite(s)]

    @property
    def converged(self) -> bool:
        """Whether the optimum is certified. The coefficients are a linear least-squares
        solution at each ``tau_m`` (exact, no iteration to stop short), and ``tau_m`` the
        minimum of its profile: certified unless that minimum is the profile's long end (the
        optimum may lie beyond it) or a coefficient is :attr:`undetermined`. A ``tau_m`` of 0
        is the lag's lower bound, an optimum on it."""
        return not self.tau_at_end and not self.undetermined

    @property
    def certificate_text(self) -> str:
        """The certificate in words."""
        if self.tau_at_end:
            return (f"optimum NOT certified: tau_m is at the long end of its profile "
                    f"({self.parameters['tau_m'][0]:g} s), and the optimum may lie beyond it")
        if self.undetermined:
            return f"optimum NOT certified: {', '.join(self.undetermined)} not determined by this log (no finite std)"
        return ("optimum certified: the coefficients are the exact least-squares solution of the equations at "
                "each tau_m, and tau_m is the minimum of its profile"
                + (" (on its lower bound, 0)" if self.parameters["tau_m"][0] == 0 else ""))

    @property
    def inadequacies(self) -> list[str]:
        """What makes the fit inadequate, one short phrase each (empty when nothing does): a
        torque equation that leaves a systematic torque beyond the gyro's noise, physically
        non-negligible (:data:`SYSTEMATIC_SHARE` of the fitted torque), and a thrust per w^2
        that changed over the flight (:attr:`thrust_changes`). The notes say each at length."""
        out = []
        off = [(eq, v, self.systematic_share.get(eq, 0.0)) for eq, v in self.residual_over_noise.items()
               if _misses(v, self.systematic_share.get(eq, 0.0))]
        if off:
            out.append("a systematic torque the model lacks (" + "; ".join(
                f"{eq} {v:.3g}x the gyro's noise, {100 * sh:.0f} % of its torque" for eq, v, sh in off) + ")")
        if self.thrust_changes:
            change, std = self.thrust_change
            out.append(f"the thrust per w^2 changes over the flight (K_T {100 * change:+.2f} ± {100 * std:.2f} %)")
        return out

    @property
    def adequate(self) -> bool | None:
        """Whether nothing makes the fit inadequate (:attr:`inadequacies`); None when not
        judged (no torque to compare with, or a gyro noise that could not be read)."""
        if self.inadequacies:
            return False
        judged = self.residual_over_noise and all(math.isfinite(v) for v in self.residual_over_noise.values())
        return True if judged else None

    @property
    def total(self) -> float:
        return float(np.mean(list(self.nrmse.values())))

    def value(self, name: str) -> float:
        return self.parameters[name][0]

    def summary(self) -> str:
        lines = [f"IMU-only identification ({self.samples} samples; mass {self.mass:g} kg as given):"]
        for n, (v, s) in self.parameters.items():
            lines.append(f"  {n:<6} = {v:.5g}" + (f" ± {s:.2g}" if math.isfinite(s) else
                                                   " (on the grid of its profile: no std)" if n == "s_lead" else
                                                   " (at the end of its profile: no std)"))
        lines.append("  validation nrmse (equation error, last 20 %): " +
                     ", ".join(f"{k} {v:.3f}" for k, v in self.nrmse.items()))
        if self.horizons is not None:
            h = self.horizons
            for target in (0.25, 0.5):
                if target in h.horizons:
                    i = h.horizons.index(target)
                    lines.append(f"  {target:g} s ahead, RMS error model / naive: " + ", ".join(
                        f"{ch} {h.model[ch][i]:.3g}/{h.naive[ch][i]:.3g}" for ch in h.model))
        v, sd = self.thrust_change
        if math.isfinite(sd):
            lines.append(f"  K_T's change from the start of the fitted part to its end (K_T linear in time): "
                         f"{100 * v:+.2f} ± {100 * sd:.2f} %" + ("  (NOT ADEQUATE: see the note)" if self.thrust_changes
                                                              else ""))
        lines.append(f"  {self.certificate_text}")
        lines.append("  not identified from an IMU-only log: drag (needs the velocity), absolute inertia, "
                     "position and attitude")
        if self.residual_over_noise:
            lines.append(f"  torque equations over {1e3 * ADEQUACY_WINDOW_S:.0f} ms, residual / the gyro's noise: "
                         + ", ".join(f"{k} {v:.2f}" for k, v in self.residual_over_noise.items())
                         + {True: "  (adequate)", False: "  (NOT ADEQUATE: see the note)",
                            None: "  (not judged: see the note)"}[self.adequate])
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)

    def as_dict(self) -> dict:
        def num(x: float) -> float | None:      # JSON has no NaN: an unknown std is null
            return float(x) if math.isfinite(x) else None
        return {"parameters": {n: {"value": num(v), "std": num(s)} for n, (v, s) in self.parameters.items()},
                "effects": list(self.effects),
                "validation": {"nrmse": num(self.total), "channels": {k: num(v) for k, v in self.nrmse.items()},
                               "yardstick": "equation error: specific force and angular acceleration"},
                **({"horizons": self.horizons.as_dict()} if self.horizons is not None else {}),
                "imu_only": True, "converged": self.converged,
                "certificate": {"optimal": self.converged, "adequate": self.adequate, "text": self.certificate_text},
                "thrust_change": {"value": num(self.thrust_change[0]), "std": num(self.thrust_change[1])},
                "tau_profile": [[t, c] for t, c in self.tau_profile],
                "adequate": self.adequate, "inadequacies": self.inadequacies,
                "residual_over_noise": {k: num(v) for k, v in self.residual_over_noise.items()},
                "systematic_share": {k: num(v) for k, v in self.systematic_share.items()},
                "not_identified": ["Kd", "inertia (absolute)", "position", "attitude"],
                "notes": list(self.notes)}


def _known_torque_at(known: ca.Function, omega: np.ndarray) -> "Callable[[np.ndarray], np.ndarray]":
    """The known torques along the fixed body rates ``omega`` (n, 3) as a function of the
    rotor speeds (n, rotors) -> (n, 3), for the many profile points of one fit. Where the
    torque is affine in the speeds (the rotors' gyroscopic torque), its offset and slope are
    evaluated once and each call is numpy; otherwise each call evaluates ``known``."""
    n, n_rot = omega.shape[0], known.size1_in(1)
    om, w = ca.SX.sym("omega", 3), ca.SX.sym("w", n_rot)
    expr = known(om, w)
    both = ca.Function("known_slope", [om, w], [expr, ca.jacobian(expr, w)])
    # affine or not, judged numerically: the model's torques with and without the effect,
    # subtracted, keep every term in the expression (the thrust's w^2 torques too)
    probe = np.linspace(1.0, 2.0, 3)
    slopes = [np.asarray(both(probe, np.full(n_rot, v))[1]) for v in (0.0, 500.0, -300.0)]
    scale = max(float(np.abs(slopes[0]).max()), 1e-300)
    if any(np.abs(s_ - slopes[0]).max() > 1e-9 * scale for s_ in slopes[1:]):
        mapped = known.map(n)
        return lambda speeds: np.asarray(mapped(omega.T, speeds.T)).T
    offset, gain = both.map(n)(omega.T, np.zeros((n_rot, n)))
    offset = np.asarray(offset).T                                           # (n, 3)
    gain = np.asarray(gain).reshape(3, n, n_rot)                           # per sample, 3 x rotors
    return lambda speeds: offset + np.einsum("jnk,nk->nj", gain, speeds)


def _known_torque(model: QuadrotorModel) -> "ca.Function | None":
    """``F(omega (3, n), w (rotors, n)) -> torque (3, n)`` of the model's
    :data:`KNOWN_TORQUE_EFFECTS` at its default parameters: ``J (omega_dot with them -
    omega_dot without)`` from the models' own right-hand sides, so what the torque is stays on
    the effect. None when the model has none of them."""
    names = [e for e in model.effect_names if e in KNOWN_TORQUE_EFFECTS]
    if not names or model.inputs != "rotor_speeds":
        return None
    af = model.airframe
    given = model.parameter_dict(model.default_parameters())
    om = ca.SX.sym("omega", 3)
    w = ca.SX.sym("w", af.n_rotors)
    acc = []
    for m in (QuadrotorModel(af, names), QuadrotorModel(af, [])):
        p = m.parameter_vector({n: given[n] for n in m.param_names if n in given})
        # (such effects carry no states of their own: the 12 base states are the whole state)
        acc.append(m.rhs(ca.vertcat(ca.SX.zeros(9), om), w, p, 0)[9:12])
    J = ca.DM(np.asarray(af.inertia, dtype=float))
    return ca.Function("known_torque", [om, w], [J @ (acc[0] - acc[1])])


def _lag_state(w: np.ndarray, tau: float, dt: float) -> np.ndarray:
    """The rotors' effective speeds at the sample times: ``e[k+1] = a e[k] + (1 - a) w[k]``
    with ``a = exp(-dt / tau)``, exact for speeds held from one sample to the next (contract
    §2), from rest at ``w[0]``; ``w`` itself without a lag (the speed held from its sample on)."""
    if tau <= 0:
        return w
    a = math.exp(-dt / tau)
    return lfilter([0.0, 1 - a], [1, -a], w - w[0], axis=0) + w[0]


def _step_means(w: np.ndarray, e: np.ndarray, tau: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Means of the effective speed and of its square over each step ``[t_k, t_k+1)`` (one row
    fewer than ``w``): the logged ``w[k]`` is held over it and ``e`` relaxes towards it,
    ``e(t_k + s) = w[k] + (e[k] - w[k]) exp(-s / tau)``, integrated exactly."""
    held = w[:-1]
    if tau <= 0:
        return held, held ** 2
    d = e[:-1] - held
    a = math.exp(-dt / tau)
    m1, m2 = tau / dt * (1 - a), tau / (2 * dt) * (1 - a * a)
    return held + m1 * d, held ** 2 + 2 * m1 * held * d + m2 * d ** 2


def _check_thrust(k_t: float, where: str) -> None:
    """One error when the thrust fitted to the accelerometer is not positive (before anything
    is divided by it): the accelerometer's sign, or speeds that do not move."""
    if not k_t > 0:
        raise GreyboxInputError(f"{where}: the thrust fitted to the accelerometer is not positive (K_T = {k_t:.3g}): "
                                "does the accelerometer read the specific force in FRD (about -9.81 m/s^2 on az in "
                                "hover), and do the rotor speeds change?")


def _check_signs_and_units(params: dict[str, tuple[float, float]], where: str) -> None:
    """One error naming the likely cause when the fitted coefficients can belong to no
    vehicle: a yaw, roll or pitch torque that turns the wrong way (a sign of the gyro, the
    spins or the rotor positions), roll and pitch gains ~57 (a gyro in deg/s). An IMU-only log
    has no attitude to check the gyro's unit against: a blind audit's uSD-like log with the
    gyro in deg/s fitted with exit 0 to gains 67 and 104 and b/K_T 1.5 m."""
    _check_thrust(params["K_T"][0], where)
    b = params["b"][0]
    (g_x, s_x), (g_y, s_y) = params["g_x"], params["g_y"]
    if min(abs(g_x), abs(g_y)) > GYRO_DEGREES_GAIN:
        raise GreyboxInputError(f"{where}: the roll and pitch torque gains are {g_x:.3g} and {g_y:.3g} (1 when the "
                                "airframe's arm and inertia are right): are p, q, r in deg/s? rad/s = deg/s * pi/180")
    # clearly negative only: a gain the closed loop pulls towards zero may straddle it
    wrong = [f"{axis} ({g:.3g} ± {sd:.2g})" for axis, g, sd in (("roll", g_x, s_x), ("pitch", g_y, s_y))
             if g < 0 and not g + 3 * sd >= 0]
    if wrong:
        raise GreyboxInputError(f"{where}: the {' and '.join(wrong)} torque gain turns the wrong way (1 when the "
                                "airframe is right): check p's and q's signs (FRD: x forward, y right) and the rotor "
                                "positions in the airframe (x forward, y right, not mirrored)")
    if not b > 0:
        raise GreyboxInputError(f"{where}: the yaw torque fitted to the gyro turns the wrong way (b = {b:.3g}): "
                                "check r's sign (FRD: positive turning right seen from above) and the rotors' spins "
                                "in the airframe")


def _horizontal_force(log: FlightLog) -> "tuple[float, float] | None":
    """RMS of the body's horizontal specific force (``ax, ay``: drag and any force but the
    thrust) and of its noise (:func:`~greybox.shooting.estimate_noise`), or None without them."""
    if not (log.measures("ax") and log.measures("ay")):
        return None
    a = np.column_stack([log.output("ax"), log.output("ay")])
    a = a[np.isfinite(a).all(axis=1)]
    noise = math.hypot(estimate_noise(a[:, 0]), estimate_noise(a[:, 1]))
    if a.shape[0] < 5 or not noise > 0:
        return None
    return float(np.sqrt(np.mean(np.sum(a ** 2, axis=1)))), noise


def _regressors(w2: np.ndarray, P: np.ndarray, spins: np.ndarray) -> dict[str, np.ndarray]:
    """Per equation of :data:`IMU_EQUATIONS`, the regressors of squared effective rotor speeds
    ``w2`` (n, rotors): total thrust; roll, pitch and yaw moment arms, each with a constant trim."""
    ones = np.ones(len(w2))
    return {"az": w2.sum(axis=1)[:, None],
            "p_dot": np.column_stack([w2 @ (-P[:, 1]), ones]),
            "q_dot": np.column_stack([w2 @ P[:, 0], ones]),
            "r_dot": np.column_stack([w2 @ spins, ones])}


def _horizon_errors(grid: np.ndarray, om: np.ndarray, az: np.ndarray, speeds: tuple[np.ndarray, np.ndarray, np.ndarray],
                    coef: dict,
                    geometry: tuple[np.ndarray, np.ndarray, np.ndarray, float], first: int,
                    horizons: "tuple[float, ...]", known: "ca.Function | None" = None) -> HorizonErrors:
    """Open-loop prediction of the body rates and the specific force from the samples
    ``first``.. on: windows start every :data:`WINDOW_SPACING_S` at a measured gyro sample
    (the naive predictor's and the model's start alike: no smoothing reaches into the
    window), the rates integrated by Heun's rule through ``J omega_dot = tau(w_eff) - omega
    x J omega`` with the fitted torque coefficients and trims (and the ``known`` torques:
    :func:`_known_torque`), each step's torque its mean over the step; the specific force is
    the output map ``-K_T sum w_eff^2 / m`` (no state). ``speeds``: the effective speeds at
    the samples and their means and mean squares over each step (:func:`_step_means`). The
    naive predictor holds the start's rates and specific force."""
    J, P, spins, m = geometry
    e, e_step, e2_step = speeds
    dt = float(np.median(np.diff(grid)))
    Jinv = np.linalg.inv(J)
    X = _regressors(e2_step, P, spins)
    torque = np.column_stack([X[eq] @ coef[eq] for eq in ("p_dot", "q_dot", "r_dot")])
    az_model = -((e ** 2).sum(axis=1) * coef["az"][0]) / m
    hs = sorted({round(dt, 9), *horizons})
    steps = [int(round(h / dt)) for h in hs]
    longest = max(steps)
    spacing = max(1, int(round(WINDOW_SPACING_S / dt)))
    starts = np.arange(first, len(grid) - 1, spacing)
    starts = starts[np.isfinite(om[starts]).all(axis=1) & np.isfinite(az[starts])]
    sq_m = {ch: np.zeros(len(hs)) for ch in HORIZON_CHANNELS}
    sq_n = {ch: np.zeros(len(hs)) for ch in HORIZON_CHANNELS}
    cnt = {ch: np.zeros(len(hs)) for ch in HORIZON_CHANNELS}
    if starts.size:
        def rate(o, k):      # omega_dot of every window in step k of its own
            idx = np.minimum(starts + k, len(torque) - 1)
            tq = torque[idx] - np.cross(o, o @ J.T)
            if known is not None:
                tq = tq + np.asarray(known(o.T, e_step[idx].T)).T
            return tq @ Jinv.T
        o = om[starts].copy()
        pred = {0: o.copy()}
        for k in range(longest):
            f0 = rate(o, k)
            o1 = o + dt * f0
            o = o + 0.5 * dt * (f0 + rate(o1, k))
            if k + 1 in steps:
                pred[k + 1] = o.copy()
        for i, k in enumerate(steps):
            idx = starts + k
            inside = idx < len(grid)
            idx = idx[inside]
            for j, ch in enumerate(HORIZON_CHANNELS[:3]):
                y = om[idx, j]
                ok = np.isfinite(y)
                sq_m[ch][i] += float(np.sum((y[ok] - pred[k][inside][ok, j]) ** 2))
                sq_n[ch][i] += float(np.sum((y[ok] - om[starts[inside][ok], j]) ** 2))
                cnt[ch][i] += ok.sum()
            y = az[idx]
            ok = np.isfinite(y)
            sq_m["az"][i] += float(np.sum((y[ok] - az_model[idx][ok]) ** 2))
            sq_n["az"][i] += float(np.sum((y[ok] - az[starts[inside][ok]]) ** 2))
            cnt["az"][i] += ok.sum()
    rms = lambda sq, n: [float(math.sqrt(s / c)) if c else float("nan") for s, c in zip(sq, n)]  # noqa: E731
    return HorizonErrors([float(h) for h in hs], {ch: rms(sq_m[ch], cnt[ch]) for ch in HORIZON_CHANNELS},
                         {ch: rms(sq_n[ch], cnt[ch]) for ch in HORIZON_CHANNELS})


class _ImuEquations:
    """The IMU-only equations of one log (module docstring) on the fit's grid, and their least
    squares at a motor time constant and an input lead: the log's gyro, accelerometer and
    held speeds on a uniform grid, smoothed alike; the steps that count (estimation and
    validation parts, gaps and edges left out); the profile of the lag over ``grid_tau``."""

    def __init__(self, model: QuadrotorModel, log: FlightLog, split: float, tau_grid: "tuple[float, ...] | None"):
        where = self.where = log.source or "log"
        if model.inputs != "rotor_speeds":
            raise GreyboxInputError(f"{where}: an IMU-only fit needs rotor speeds as inputs")
        for ch in ("p", "q", "r", "az"):
            if not log.measures(ch):
                raise GreyboxInputError(f"{where}: an IMU-only fit needs column {ch!r} (gyro and accelerometer)")
        af = model.airframe
        t = log.t
        steps = np.diff(t)
        dt = self.dt = float(np.median(steps))
        # rows a steady rate apart with a little jitter in their stamps are the samples themselves
        # (a grid of the median step drifts across them: 5 ms over 20 s of a 200 Hz log)
        on_rows = bool(np.all(np.abs(steps - dt) < 0.25 * dt))
        grid = self.grid = t.copy() if on_rows else np.arange(t[0], t[-1] + 0.5 * dt, dt)
        win = self.win = max(5, int(round(SMOOTHING_S / dt)) | 1)
        if grid.size < 10 * win:
            raise GreyboxInputError(f"{where}: too short for an IMU-only fit ({t[-1] - t[0]:.2f} s)")

        def on_grid(y):
            ok = np.isfinite(y)
            if on_rows:
                return np.interp(np.arange(t.size), np.flatnonzero(ok), y[ok]), ~ok
            return np.interp(grid, t[ok], y[ok]), np.interp(grid, t, (~ok).astype(float)) > 0.5
        cols, gaps = [], np.zeros(grid.size, bool)
        for ch in ("p", "q", "r", "az"):
            y, miss = on_grid(log.output(ch))
            cols.append(y)
            gaps |= miss
        self.om, self.az, self.gaps = np.column_stack(cols[:3]), cols[3], gaps
        om = self.om
        # the speeds as held (contract §2): each row's from its time to the next row's
        held = np.arange(t.size) if on_rows else np.clip(np.searchsorted(t, grid + 1e-9 * dt, side="right") - 1, 0,
                                                      len(t) - 1)
        self.w = log.inputs[held, :af.n_rotors].astype(float)
        # The rotational equations are taken over each step [t_k, t_k+1), where the held speeds
        # act: J (omega[k+1] - omega[k]) / dt against the step's mean torque. Taken at the samples
        # (the gyro's derivative there against the speeds from that sample on), the torque was half
        # a sample early: the torque gains and b came out 1-1.6 % low at 8-19 of their std and a
        # motor lag appeared where there is none (9 ms at 100 Hz; a blind audit's own simulator).
        # The last sample starts no step: every series has one row fewer than the grid.
        om_mid = self.smooth(0.5 * (om[1:] + om[:-1]))
        self.J = J = np.asarray(af.inertia, dtype=float)
        self.lhs = self.smooth(np.diff(om, axis=0) / dt) @ J.T + np.cross(om_mid, om_mid @ J.T)
        self.P, self.spins, self.m = af.rotor_positions, af.spins, af.mass
        n = grid.size - 1
        # steps whose smoothing window touches a gap of the IMU are left out
        gap_step = gaps[1:] | gaps[:-1]
        bad = np.convolve(gap_step.astype(float), np.ones(win), mode="same") > 0
        edge = np.zeros(n, bool)
        edge[:win] = edge[-win:] = True
        self.use = ~(bad | edge)
        self.cut = int(split * n)
        self.est = self.use & (np.arange(n) < self.cut)
        self.val = self.use & (np.arange(n) >= self.cut)
        if self.est.sum() < 50 or self.val.sum() < 20:
            raise GreyboxInputError(f"{where}: too few usable IMU samples for an IMU-only fit")
        self.known = _known_torque(model)
        self.known_steps = _known_torque_at(self.known, om_mid) if self.known is not None else None
        self.thrust_side = -self.m * self.smooth(self.az[:-1])
        grid_tau = tuple(tau_grid) if tau_grid is not None else TAU_GRID
        # a lag so slow that its unknown start settles over most of the log is not profiled
        self.grid_tau = tuple(tau_ for tau_ in grid_tau if self.rows(tau_).sum() >= 50)
        if not self.grid_tau:
            raise GreyboxInputError(f"{where}: too few IMU samples for an IMU-only fit once the motors' lag has "
                                    "settled from the log's start")
        # every point of the profiles is scored on the same rows (those the longest lag keeps): on
        # its own rows a long lag would also leave out the log's opening (a take-off's large
        # residuals) and score better for it
        self.common = self.rows(self.grid_tau[-1])

    def smooth(self, y: np.ndarray) -> np.ndarray:
        return savgol_filter(y, self.win, 2, axis=0)

    def rows(self, tau: float) -> np.ndarray:
        """The estimation steps once the guessed start of the lag state has died away."""
        return self.est & (np.arange(self.est.size) >= math.ceil(SETTLE_TAUS * tau / self.dt))

    def acting(self, lead: float) -> np.ndarray:
        """The speeds taken as held over each row: ``lead`` of the next row's."""
        w = self.w
        out = w.copy()
        out[:-1] = (1 - lead) * w[:-1] + lead * w[1:]
        return out

    def equations(self, tau: float, lead: float):
        """The equations' left sides (with the known torques taken off: they move with the
        lagged speeds) and regressors at the motor time constant ``tau`` and the input lead
        ``lead``: the specific force at each sample, the torques over each step
        (:func:`_step_means`)."""
        w_row = self.acting(lead)
        e = _lag_state(w_row, tau, self.dt)
        e_step, e2_step = _step_means(w_row, e, tau, self.dt)
        rot = self.lhs if self.known is None else self.lhs - self.smooth(self.known_steps(e_step))
        X = _regressors(self.smooth(e2_step), self.P, self.spins)
        X["az"] = self.smooth(e[:-1] ** 2).sum(axis=1)[:, None]
        return {"az": self.thrust_side, "p_dot": rot[:, 0], "q_dot": rot[:, 1], "r_dot": rot[:, 2]}, X

    def solve(self, tau: float, lead: float, scored=IMU_EQUATIONS, fitted=None):
        """Least squares of each equation on the rows ``fitted`` (default: :meth:`rows` at
        ``tau``); the cost summed over the equations ``scored``."""
        y_eq, X = self.equations(tau, lead)
        fitted = self.rows(tau) if fitted is None else fitted
        coef, cost = {}, 0.0
        for eq, y in y_eq.items():
            c, *_ = np.linalg.lstsq(X[eq][fitted], y[fitted], rcond=None)
            r = y[fitted] - X[eq][fitted] @ c
            coef[eq] = c
            if eq in scored:
                cost += float(r @ r) / max(float(np.var(y[fitted])) * fitted.sum(), 1e-300)
        return coef, cost, X, y_eq

    def profile_cost(self, tau_: float, lead_: float) -> float:
        """The lag's profile: the torque equations' cost at ``tau_``, on the common rows."""
        return self.solve(tau_, lead_, TORQUE_EQUATIONS, self.common)[1]

    def profile(self, lead: float) -> list[tuple[float, float]]:
        """The lag's whole profile over ``grid_tau`` at the input lead ``lead``."""
        return [(tau_, self.profile_cost(tau_, lead)) for tau_ in self.grid_tau]

    def estimate(self, lead: float, profile: list[tuple[float, float]]):
        """The coefficients, their std, the validation nrmse and the lag at the input lead
        ``lead`` from its ``tau`` profile ``profile``; with the equations they were solved on."""
        grid_tau, val = self.grid_tau, self.val
        k = int(np.argmin([c for _, c in profile]))
        tau = grid_tau[k]
        inside = 0 < k < len(grid_tau) - 1
        if inside:
            # the minimum between the grid's neighbours, found (a std finer than the grid's 5 ms
            # means nothing at a grid point: a 40 ms lag came out 45 ms at 20 "std"; a parabola
            # through three points of a skewed profile put a blind audit's 30 ms lag at 28.3 ms,
            # 5 std off)
            def scored(t_: float) -> float:
                return self.profile_cost(t_, lead)

            found = minimize_scalar(scored, bounds=(grid_tau[k - 1], grid_tau[k + 1]), method="bounded",
                                    options={"xatol": TAU_TOLERANCE})
            tau, c1 = float(found.x), float(found.fun)
            if c1 > profile[k][1]:
                tau, c1 = grid_tau[k], profile[k][1]
            # the profile's curvature at its minimum gives tau's std (cost is a sum of normalised
            # squares: 2 / curvature per unit of normalised variance, scaled by the residual level)
            h = min(TAU_CURVATURE_STEP, tau / 2)
            # a minimum at the grid's 0 has no curvature to read (no std)
            curv = (scored(tau + h) - 2 * c1 + scored(tau - h)) / h ** 2 if h >= TAU_TOLERANCE else float("nan")
        coef, cost, X, y_eq = self.solve(tau, lead)
        est = self.rows(tau)
        if inside:
            # coloured residuals carry less information per sample: widen by their long-run factor
            colour = float(np.median([long_run_factor(y_eq[eq][est] - X[eq][est] @ coef[eq])
                                      for eq in TORQUE_EQUATIONS]))
            # the profile's cost sums len(TORQUE_EQUATIONS) normalised squares, each about c1 / that
            # many: -log L = n len / (2 c1) * cost, its curvature gives the variance
            tau_std = math.sqrt(2 * c1 / (len(TORQUE_EQUATIONS) * self.common.sum()) / curv * colour) \
                if curv > 0 else float("nan")
        else:
            tau_std = float("nan")
        params: dict[str, tuple[float, float]] = {}
        nrmse: dict[str, float] = {}
        for eq, y in y_eq.items():
            A, c = X[eq][est], coef[eq]
            r = y[est] - A @ c
            # the sandwich (Newey-West) of coloured residuals: widened by how they correlate with
            # their own regressors' colour, not by the residuals' alone (which made b's std 9x
            # too wide on a blind audit's twelve flights: RMS z 0.11; 0.41 with it)
            cov = _sandwich_covariance(A, r)
            std = np.sqrt(np.clip(np.diag(cov), 0, None))
            rv = y[val] - X[eq][val] @ c
            spread = float(np.sqrt(np.mean((y[val] - y[val].mean()) ** 2)))
            nrmse[eq] = float(np.sqrt(np.mean(rv ** 2)) / spread) if spread > 0 else float("inf")
            if eq == "az":
                params["K_T"] = (float(c[0]), float(std[0]))
            elif eq == "r_dot":
                params["b"] = (float(c[0]), float(std[0]))
            else:
                params[f"g_{'x' if eq == 'p_dot' else 'y'}"] = (float(c[0]), float(std[0]))
        K_T, sK = params["K_T"]
        _check_thrust(K_T, self.where)
        for g in ("g_x", "g_y"):     # torque coefficient over K_T: the gain against the geometry
            v, s = params[g]
            params[g] = (v / K_T, math.hypot(s / K_T, v * sK / K_T ** 2))
        params["tau_m"] = (float(tau), tau_std)
        params["s_lead"] = (float(lead), float("nan"))
        return params, nrmse, coef, tau, k, profile, (y_eq, X)


def _sandwich_covariance(A: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The least-squares coefficients' covariance for the regressors ``A`` (n, k) and their
    residuals ``r`` (n,), correlated over :data:`HAC_LAGS` rows: the sandwich (Newey-West,
    Bartlett weights) with the small-sample factor n / (n - k)."""
    Ai = np.linalg.pinv(A.T @ A)
    n, k = A.shape
    return Ai @ long_run_covariance(A * r[:, None], bandwidth=HAC_LAGS) @ Ai * n / max(n - k, 1)


def _thrust_drift(t: np.ndarray, y: np.ndarray, A: np.ndarray, rows: np.ndarray) -> tuple[float, float]:
    """The thrust equation refitted with K_T changing linearly in time: its relative change
    over the fitted rows' span and that change's std (the sandwich of coloured residuals, as
    for the coefficients)."""
    tt = t[rows] - t[rows].mean()
    B = np.column_stack([A[rows], A[rows][:, 0] * tt])
    c, *_ = np.linalg.lstsq(B, y[rows], rcond=None)
    r = y[rows] - B @ c
    cov = _sandwich_covariance(B, r)
    span = float(tt.max() - tt.min())
    return float(c[-1] / c[0] * span), float(np.sqrt(cov[-1, -1]) / abs(c[0]) * span)


def _thrust_changes(change: float, std: float) -> bool:
    """Whether ``K_T``'s relative ``change`` over the fitted part (± ``std``) is beyond what the
    thrust equation's missing drag and bias give (:data:`THRUST_CHANGE_NOTABLE`) and beyond 3
    of its std."""
    return abs(change) >= THRUST_CHANGE_NOTABLE and math.isfinite(std) and abs(change) > 3 * std


def _torque_adequacy(eqs: _ImuEquations, log: FlightLog, fitted: np.ndarray, coef, y_eq, X):
    """The torque equations' residual over the gyro's noise, both averaged over
    :data:`ADEQUACY_WINDOW_S`: ``(over_noise, share, gyro_noise, how)``, per equation the RMS
    residual over what the gyro's noise gives and its part beyond that over the fitted torque;
    the gyro's noise per axis and how it was read."""
    dt, win, J = eqs.dt, eqs.win, eqs.J
    # the gyro's white noise through the equations' own derivative: diff / dt, smoothed, times J
    # (over ADEQUACY_WINDOW_S, where the noise averages out and a systematic torque does not)
    slow = max(3, int(round(ADEQUACY_WINDOW_S / dt)))
    box = np.ones(slow) / slow
    impulse = np.zeros(4 * win + 2 * slow + 1)
    impulse[2 * win + slow] = 1.0
    through = float(np.sqrt(np.sum(np.convolve(savgol_filter(np.diff(impulse) / dt, win, 2), box) ** 2)))
    read = [gyro_noise_on_average(log.output(ch), dt, through, slow * dt) for ch in ("p", "q", "r")]
    gyro_noise = np.array([level for level, _ in read])
    how = {how_ for _, how_ in read}
    if "unknown" in how:
        # a gyro filtered so that one axis's noise cannot be read: the others' bound is no safer
        # (a 30 Hz low-pass at 500 Hz: yaw 3.05 % "systematic" on a clean flight, its delay not
        # a first-order lag's shape)
        gyro_noise[:] = np.nan
    # only averages whose whole window is usable: a gap's interpolation must not leak into them
    averaged = fitted & (np.convolve(eqs.use.astype(float), box, mode="same") > 1 - 1e-9)
    over_noise: dict[str, float] = {}
    share: dict[str, float] = {}
    for i, eq in enumerate(TORQUE_EQUATIONS):
        r = np.convolve(y_eq[eq] - X[eq] @ coef[eq], box, mode="same")[averaged]
        torque = np.convolve(X[eq] @ coef[eq], box, mode="same")[averaged]
        # the rates this equation's inertia row couples (a diagonal J: its own rate alone)
        coupled = J[i] != 0
        expected = float(np.sqrt(np.sum((J[i][coupled] * gyro_noise[coupled]) ** 2)))
        if r.size and np.std(torque) > 0:
            if expected > 0:
                over_noise[eq] = float(np.sqrt(np.mean(r ** 2)) / expected)
                share[eq] = math.sqrt(max(float(np.mean(r ** 2)) - expected ** 2, 0.0)) / float(np.std(torque))
            else:
                over_noise[eq] = share[eq] = float("nan")      # a noise greybox cannot read: not judged
    return over_noise, share, gyro_noise, how


def _imu_notes(gyro_noise: np.ndarray, how: set, over_noise: dict, share: dict, lead: float, k: int,
               grid_tau: tuple, tau: float, params: dict, K_T: float) -> list[str]:
    """What an IMU-only fit says in words about its equations: the gyro's noise as read, the
    torques' adequacy, the speeds' timing, a lag at an end of its profile, ``b/K_T``."""
    notes = []
    if not np.all(gyro_noise[np.isfinite(gyro_noise)] > 0):
        notes.append("the torque equations' adequacy is not judged where the gyro shows no noise to compare with "
                     "(a noiseless or coarsely quantised rate)")
    if "unknown" in how:
        notes.append("the torque equations' adequacy is not judged: the gyro's noise could not be read on some "
                     "axis: its fourth differences are well below its second (a low-passed noise, or motion that "
                     f"dominates them) and never stop growing up to {1e3 * FILTERED_NOISE_SPACING_S:.0f} ms apart: "
                     "greybox cannot tell a missing torque from that noise")
    elif "filtered" in how:
        notes.append(f"the gyro's noise looks filtered (low-passed, as autopilots do; or motion dominates its "
                     f"differences): its level over "
                     f"{1e3 * ADEQUACY_WINDOW_S:.0f} ms is an upper bound read where it stops being correlated, so "
                     "the adequacy check is conservative (it misses small missing torques sooner than it "
                     "invents one); a filter also delays the measured rates, and that delay is fitted as part of "
                     "tau_m (a 2nd-order 80 Hz low-pass on a simulated 20 ms motor's gyro: tau_m 23 ms)")
    off = [eq for eq in over_noise if _misses(over_noise[eq], share[eq])]
    if off:
        # an 8 % weak rotor in a blind audit's log: gains 0.93 at 8 std, and nothing said
        levels = ", ".join(f"{eq} {over_noise[eq]:.3g}x the noise, {100 * share[eq]:.0f} % of its torque"
                           for eq in off)
        notes.append(f"NOT ADEQUATE: over {1e3 * ADEQUACY_WINDOW_S:.0f} ms the torque equations leave a systematic "
                     f"torque beyond the gyro's noise ({levels}): something turns the body that the model lacks (a "
                     "rotor weaker than the others, a CoG offset, aerodynamic torques, the airframe's inertia or "
                     "rotor inertia off): g_x, g_y and b take up what they can of it, so they are this model's "
                     "compromise, further off than their std say")
    if lead > 0:
        notes.append(f"the speeds act as if {lead:g} of each row were the next row's (s_lead, profiled with tau_m "
                     f"over {', '.join(f'{v:g}' for v in LEAD_GRID)}): they change within a row (commands sampled "
                     "from a faster controller, measured rotor speeds), not held over it as logged commands are")
    if k == len(grid_tau) - 1:
        notes.append(f"tau_m is at the end of the profile ({tau:g} s): the rotors' response is slower than "
                     "a first-order lag of that time constant, or something else filters the torque")
    if k == 0 and grid_tau[0] == 0.0:
        notes.append("tau_m = 0: no lag between the logged and the effective rotor speeds (an ESC RPM log "
                     "measures the actual speed)")
    ratio = params["b"][0] / K_T if K_T > 0 else float("nan")
    if not 0.001 <= abs(ratio) <= 0.05:
        notes.append(f"b/K_T = {ratio:.4g} m is outside what propellers give (0.001-0.05 m)")
    return notes


def fit_imu(model: QuadrotorModel, log: FlightLog, split: float = 0.8,
            tau_grid: "tuple[float, ...] | None" = None) -> ImuFit:
    """Identify ``K_T``, ``b``, the motor time constant and the roll/pitch torque gains from
    the gyro, the accelerometer and the rotor speeds of ``log`` (module docstring), on its
    first ``split`` part; validate on the rest.

    Raises :class:`~greybox.errors.GreyboxInputError` naming the log when a needed channel
    is missing or the log is too short."""
    eqs = _ImuEquations(model, log, split, tau_grid)
    where, grid_tau = eqs.where, eqs.grid_tau
    # The lag and the speeds' timing within a row, profiled together: a lag delays and smooths,
    # a lead advances. Held as the contract says, commands a 500-Hz controller sent between an
    # audit's 200 Hz rows gave its 40 ms motors 37.8 ms (6 of its std); with the lead, 40.0.
    # A lead moves the lag's optimum by a row or so: beside the held speeds' whole profile, the
    # other leads are scored near its minimum, and the best gets its whole profile.
    held_profile = eqs.profile(0.0)
    k0 = int(np.argmin([c for _, c in held_profile]))
    near = range(max(k0 - PROFILE_NEAR, 0), min(k0 + 2 * PROFILE_NEAR, len(grid_tau) - 1) + 1)
    # scored on the torques alone: the thrust equation lacks the vertical drag, and its misfit
    # chose a lead on a 30 g vehicle at 1 kHz that moved its 15 ms lag by 9 std the wrong way
    best = {s_: min(eqs.profile_cost(grid_tau[i], s_) for i in near) for s_ in LEAD_GRID}
    params, nrmse, coef, tau, k, profile, (y_eq, X) = eqs.estimate(0.0, held_profile)
    lead = min(best, key=lambda s_: (best[s_], s_))
    if lead > 0:
        # the timing counts when it moves what is fitted (the diagnosis's rule for a log's
        # timing, ranking.PARAMETER_SHIFT): a lead that fits a little better and moves nothing
        # is no evidence against the contract's hold
        led = eqs.estimate(lead, eqs.profile(lead))
        shifts = [abs(led[0][n][0] - v) / sd for n, (v, sd) in params.items() if math.isfinite(sd) and sd > 0]
        if shifts and max(shifts) > LEAD_SHIFT:
            params, nrmse, coef, tau, k, profile, (y_eq, X) = led
        else:
            lead = 0.0
    K_T = params["K_T"][0]
    _check_signs_and_units(params, where)
    fitted = eqs.rows(tau)
    change = _thrust_drift(0.5 * (eqs.grid[:-1] + eqs.grid[1:]), y_eq["az"], X["az"], fitted)
    over_noise, share, gyro_noise, how = _torque_adequacy(eqs, log, fitted, coef, y_eq, X)
    notes = _imu_notes(gyro_noise, how, over_noise, share, lead, k, grid_tau, tau, params, K_T)
    # the measured samples, not the smoothed ones, start and score the predictions
    om_raw = np.where(eqs.gaps[:, None], np.nan, eqs.om)
    az_raw = np.where(eqs.gaps, np.nan, eqs.az)
    w_row = eqs.acting(lead)
    e = _lag_state(w_row, tau, eqs.dt)
    horizons = _horizon_errors(eqs.grid, om_raw, az_raw, (e, *_step_means(w_row, e, tau, eqs.dt)), coef,
                               (eqs.J, eqs.P, eqs.spins, eqs.m), eqs.cut, DEFAULT_HORIZONS, eqs.known)
    drag = _horizontal_force(log)
    if drag is not None and drag[0] > DRAG_NOTE_RATIO * drag[1]:
        notes.append(f"the horizontal specific force is {drag[0]:.3g} m/s^2 RMS, {drag[0] / drag[1]:.1f}x the "
                     "accelerometer's noise: drag (or another force, or an accelerometer bias) acts on the body, "
                     "and its vertical part, which the thrust equation cannot tell from the thrust without the "
                     "velocity, can go into K_T beyond its std (a blind audit's 30 g vehicle at 2.5 m/s, drag "
                     "0.33 of its mass per s: K_T 0.6 % low, 7 std; its 3 kg vehicle at 1 kHz: 0.17 %, 5 std); "
                     "g_x, g_y are torques over this K_T")
    if _thrust_changes(*change):
        notes.append(f"NOT ADEQUATE: the thrust per w^2 changes over the flight: K_T "
                     f"{'falls' if change[0] < 0 else 'rises'} by {100 * abs(change[0]):.1f} ± {100 * change[1]:.1f} % "
                     f"from the start of the fitted part to its end (the thrust equation refitted with K_T linear in "
                     f"time), beyond the {100 * THRUST_CHANGE_NOTABLE:.0f} % the vertical drag and the accelerometer's "
                     "bias it lacks can give: a battery that sags (in a log with position: thrust_drift, "
                     "battery_voltage with vbat logged), or a motor that heats; K_T is the flight's mean, and g_x, "
                     "g_y, torques over it, are the mean's")
    K_T_std = params["K_T"][1]
    # the specific force at each fitted step's start
    bias_share = ACCEL_BIAS_TYPICAL / max(float(np.nanmean(np.abs(eqs.az[:-1][fitted]))), 1e-9)
    if math.isfinite(K_T_std) and bias_share * K_T > 3 * K_T_std:
        notes.append(f"K_T's std ({100 * K_T_std / K_T:.2g} %) counts the noise only: a bias of the accelerometer "
                     f"along z goes into K_T in full ({ACCEL_BIAS_TYPICAL:g} m/s^2, a calibrated MEMS "
                     f"accelerometer's, moves it by {100 * bias_share:.2g} %, {bias_share * K_T / K_T_std:.0f} of its "
                     "std), and g_x, g_y, torques over K_T, with it; so does the vertical drag; a log with position "
                     "tells them apart (accel_bias)")
    if any(log.measures(c) for c in ("phi", "theta", "psi")):
        notes.append("the logged attitude is not used: without position the velocity, and with it the "
                     "translational equations, are not determined by the data")
    effects = (["yaw_torque"] + [e for e in model.effect_names if e in KNOWN_TORQUE_EFFECTS] + ["motor_lag"]
               + (["sampled_inputs"] if lead > 0 else []))    # the catalogue's name for s_lead
    return ImuFit(params, nrmse, [(float(a), float(b)) for a, b in profile], eqs.m, int(fitted.sum()), notes,
                  horizons, effects, over_noise, share, tau_at_end=k == len(grid_tau) - 1, thrust_change=change)

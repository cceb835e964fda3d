"""Effects of the spinning rotors on the body: the reaction torque, the gyroscopic torque
(both in the base model), the lag between logged and effective rotor speed, and the scale
of the roll/pitch moment they give."""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..parameters import Parameter
from .base import Effect

__all__ = ["YawTorque", "Gyroscopic", "MotorLag", "MomentGain", "ThrustCurve"]


class YawTorque(Effect):
    """Rotor reaction (drag) torque ``spin_i * b * w_i**2`` about body +z.

    Without it a model cannot balance yaw and keeps rotating (the seed paper's Fig. 1).
    """

    name = "yaw_torque"
    summary = "rotor reaction torque b*w^2 about body z"
    excited_by = 'yaw turns'
    fit_advice = 'yaw steps (yaw) with large rotor-speed differences'
    channels = ('psi', 'r')

    def parameters(self, airframe):
        return [Parameter("b", 1, 5e-7, "N m/(rad/s)^2", 0.0, np.inf, 1e-6, 0.0, True,
                          "rotor reaction torque coefficient", self.name)]

    # Torque-to-thrust ratio b/K_T of propellers, m: published Crazyflie values 0.002-0.034 m,
    # larger propellers 0.01-0.03 m.
    RATIO_RANGE = (0.001, 0.05)

    def plausibility_warnings(self, values, std, airframe):
        b, kt = values.get("b"), values.get("K_T")
        if "b" not in std or b is None or not kt:
            return []
        lo, hi = self.RATIO_RANGE
        ratio = b / kt
        if lo <= ratio <= hi:
            return []
        s = std.get("b")
        within = (s is not None and np.isfinite(s) and s > 0 and (lo * kt - b) / s < 2 and (b - hi * kt) / s < 2)
        why = ("the data hardly constrain it (a plausible b is within 2 std)" if within else
               "the data put it there: the yaw is explained by something the model lacks (a torque the "
               "controller cancels through the very commands the model reads, which pulls b down: fit with "
               "a disturbance torque, model + DisturbanceTorque() with process noise (--effects "
               "disturbance_torque --process-noise auto); a torque difference "
               "between the two spin directions, motors whose command-to-speed maps differ; noise on the logged "
               "speeds, which the model turns into a yaw torque the gyro does not see: on a flight without yaw "
               "manoeuvres it pulls b to zero, whatever its std), or b stands in for it")
        return [f"b/K_T = {ratio:.2g} m is outside what propellers give ({lo:g}-{hi:g} m): b is not identified "
                f"from this flight as a rotor's reaction torque; {why}; fly yaw steps, or hold b at a measured "
                "value (--set b=... --fixed b, for fit and diagnose)"]

    def add_forces(self, ctx):
        b = ctx.params["b"]
        spins = ca.DM(ctx.airframe.spins)
        ctx.torque_body[2] += b * ca.dot(spins * ctx.torque_scale, ctx.w ** 2)


class Gyroscopic(Effect):
    """Rotor gyroscopic torque ``J_r * Omega_r * (omega x e_z)``, ``Omega_r = sum(spin_i*w_i)``.

    Sign convention (README, "Conventions"): roll ``+J_r*q*Omega_r``, pitch ``-J_r*p*Omega_r``.
    ``J_r`` defaults to the airframe's ``rotor_inertia`` and is held fixed when fitting
    unless freed: it is rarely identifiable from flight data.
    """

    name = "gyroscopic"
    summary = "rotor gyroscopic torque J_r*Omega_r*(omega x e_z)"
    excited_by = 'fast roll and pitch motions during yaw turns'
    fit_advice = 'fast roll/pitch motions with high rotor speeds'
    channels = ('phi', 'theta', 'p', 'q')

    def parameters(self, airframe):
        jr = airframe.rotor_inertia
        return [Parameter("J_r", 1, jr, "kg m^2", 0.0, np.inf, max(jr, 1e-6), 0.0, False,
                          "moment of inertia of one rotor about its axis", self.name)]

    def add_forces(self, ctx):
        omega_r = ca.dot(ca.DM(ctx.airframe.spins), ctx.w)
        p, q = ctx.omega[0], ctx.omega[1]
        jr = ctx.params["J_r"]
        ctx.torque_body += jr * omega_r * ca.vertcat(q, -p, 0)


class MotorLag(Effect):
    """First-order lag between logged and effective rotor speed:
    ``dw_eff/dt = (w_logged - w_eff) / tau_m``. Adds one state per rotor (``w_eff1``...),
    started at the first logged speeds (steady motors).
    """

    name = "motor_lag"
    input_timed = ("tau_m",)
    summary = "first-order motor lag, time constant tau_m"
    excited_by = 'fast rotor-speed changes (steps, excitation)'
    fit_advice = 'rapid rotor-speed changes (steps, excitation)'
    channels = ('phi', 'theta', 'p', 'q', 'z')
    distinguish = {
        'position_delay': 'fast rotor-speed steps with attitude recorded: motor lag delays attitude too, a vision delay only position',
    }
    systematic_gap_words = ("the motors do not follow a first-order lag there (a slew-rate limit or saturation, "
                            "or a lag unlike up and down)")

    def parameters(self, airframe):
        # The lower bound keeps the fixed-step integrators stable (see integrate.MAX_STEP).
        return [Parameter("tau_m", 1, 0.02, "s", 2e-3, 1.0, 0.02, 0.0, True,
                          "motor time constant", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"tau_m": 0.03}

    def state_names(self, airframe):
        return [f"w_eff{i + 1}" for i in range(airframe.n_rotors)]

    def initial_state(self, airframe, w0):
        return np.asarray(w0, dtype=float).copy()

    def modify(self, ctx):
        ctx.w = ctx.extra_states[self.name]

    def state_derivative(self, ctx):
        return (ctx.w_command - ctx.extra_states[self.name]) / ctx.params["tau_m"]


MASS_ERROR_RANGE = (2 / 3, 1.5)
"""The moment gains :class:`MomentGain` also reads as the airframe's mass off by that factor (a
mass given up to 1.5 times, or down to 2/3 of, the vehicle's)."""


class MomentGain(Effect):
    """The rotor thrusts' roll and pitch moment scaled by ``k_M`` (1: the airframe's).

    The moment a model computes from logged rotor speeds rests on the inertia, the arm
    length and, when the speeds come from motor commands, on the command-to-speed map. A
    ``k_M`` below 1 says the body turns less per logged speed difference than those predict:
    a larger inertia, or a map that overstates speed differences (on real Crazyflie flights
    with the published PWM map the cross-correlation of gyro-derived angular acceleration with
    the modelled one gives about 0.2-0.35). Roll and pitch only: the yaw moment has its own
    coefficient ``b``.

    It also reads a wrong **mass**: the fitted ``K_T`` carries the weight the airframe's mass
    gives, so a mass given ``1/k`` of the vehicle's makes every thrust, and every moment, ``1/k``
    of the true one, and the moment gain restores ``k`` (a blind audit's sprayer, 4.0 kg,
    given its dry 3.2 kg: ``k_M`` 1.2454 ± 0.0028, ``K_T`` 20 % low). The translation cannot
    tell (an acceleration is a thrust over the mass); the inertia against the moment can.
    """

    name = "moment_gain"
    summary = "roll/pitch moment per logged rotor-speed difference, relative to the airframe's"
    excited_by = 'roll and pitch manoeuvres (attitude steps, figure-eights)'
    fit_advice = 'roll and pitch steps flown open enough that the attitude follows the commands'
    channels = ('phi', 'theta', 'p', 'q', 'x', 'y')
    distinguish = {
        'motor_lag': 'fast rotor-speed steps: a lag delays the moment, a gain scales it at every frequency',
    }
    scales_commanded_moment = True

    def parameters(self, airframe):
        return [Parameter("k_M", 1, 1.0, "1", 0.02, 5.0, 0.3, 1.0, True,
                          "roll/pitch moment of the rotor thrusts relative to the airframe's", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"k_M": 0.7}

    def plausible_limits(self, airframe):
        # a tenth of the airframe's moment would be ten times its inertia, or a command map
        # ten times too steep: beyond, the gain has the model ignore its commands instead
        # (a real Crazyflie flight without its CoG offset: k_M 0.02, on its bound)
        return {"k_M": 0.9}

    def plausibility_warnings(self, values, std, airframe):
        if "k_M" not in std:
            return []
        k, lim = values["k_M"], self.plausible_limits(airframe)["k_M"]
        if abs(k - 1.0) <= lim:
            return []
        return [f"k_M = {k:.3g}: beyond what moment_gain physically does ({1 - lim:.1f} <= k_M <= {1 + lim:.1f}: "
                f"an inertia or command map off by more than that is a wrong airframe file); the fit has it "
                f"standing in for something the model lacks"]

    @staticmethod
    def readings(k: float, airframe) -> str:
        """What a roll and pitch moment ``k`` times the airframe's can be, in words: only the
        ratio of the mass to the inertia reaches the moments (``K_T`` carries the weight of the
        mass given, a moment is a thrust difference over the inertia), so a mass given ``1/k``
        of the vehicle's (said within :data:`MASS_ERROR_RANGE`), a roll and pitch inertia ``k``
        times the vehicle's, or a command map or arm off give the same flight. A blind audit's
        1.1 kg vehicle given an inertia 35 % too large: ``k_M`` 1.368, and only the mass was
        named; the inertia about z, off alike, had made ``b`` 35 % high, 1150 std."""
        J = np.diag(np.asarray(airframe.inertia, dtype=float))
        parts = [f"the airframe's roll and pitch inertia is off: with Jx, Jy = {J[0] / k:.4g}, {J[1] / k:.4g} kg m^2 (the "
                 f"given ÷ {k:.3g}) every moment would match with k_M = 1, and b, which the yaw data give "
                 f"relative to the Jz given ({J[2]:.4g} kg m^2), is off as much as Jz is"]
        if MASS_ERROR_RANGE[0] <= k <= MASS_ERROR_RANGE[1]:
            parts.append(f"the airframe's mass is off: K_T carries the weight of the mass given ({airframe.mass:.4g} kg), and "
                         f"with {k * airframe.mass:.4g} kg (the inertia as given) every moment would match with "
                         f"k_M = 1 and K_T and Kd {k:.3g} times the fitted values")
        parts.append("the command-to-speed map or the arm overstates the speeds' moment" if k < 1 else
                     "the arm or the command-to-speed map understates the speeds' moment")
        return ("either " + "; or ".join(parts) + ". The flight cannot tell these apart: weigh the vehicle and "
                "check its inertia")

    def interpretation_notes(self, values, std, airframe):
        # the thrust per w^2 is calibrated on the airframe's weight: a mass off by a factor scales
        # every moment by it, and k_M undoes it (the translation cannot tell a wrong mass), as an
        # inertia off by it does. Said for a gain within the mass's range (a payload, a full tank,
        # another battery, an inertia's estimate); the real Crazyflie flights' k_M 0.15-0.6 (their
        # PWM map, 5-18 g for 30 g) are not
        k, s = values.get("k_M"), std.get("k_M")
        if k is None or s is None or not np.isfinite(s) or abs(k - 1.0) <= 3 * s \
                or not MASS_ERROR_RANGE[0] <= k <= MASS_ERROR_RANGE[1]:
            return []
        return [f"k_M = {k:.4g}: the body turns {k:.3g} times as much per rotor-speed difference as the airframe's "
                f"inertia, arm and mass give; {self.readings(k, airframe)}"]

    def add_forces(self, ctx):
        tau = ctx.thrust_torque
        ctx.torque_body += (ctx.params["k_M"] - 1) * ca.vertcat(tau[0], tau[1], 0)



class ThrustCurve(Effect):
    """A rotor's thrust per ``w²`` changing with its speed about hover:
    ``T_i = K_T w_i² (1 + k_Tw (w_i/w_h - 1))`` with ``w_h = sqrt(m g / (N K_T))`` the speed at
    which equal rotors carry the weight, so ``K_T`` keeps its meaning (thrust per ``w²`` at
    hover) and the hover trim is unchanged.

    A propeller's thrust coefficient is not a constant: it changes with the blades' Reynolds
    number, and a thrust stand's curve is seldom a pure square (``a w² + c w³`` is this form
    exactly, ``k_Tw = c w_h / K_T``). Around hover it makes every thrust change ``1 + k_Tw/2``
    times what ``K_T`` alone gives -- the differential thrust of roll and pitch commands like a
    moment gain, and the collective thrust of climbs and descents, which a moment gain leaves
    alone. The reaction torque keeps ``b w²``.
    """

    name = "thrust_curve"
    summary = "thrust per w^2 changing with rotor speed about hover, 1 + k_Tw (w/w_h - 1)"
    excited_by = 'a wide range of thrust levels (climbs, descents, hard manoeuvres)'
    fit_advice = 'climbs and descents at several thrust levels, and roll and pitch steps'
    channels = ('z', 'phi', 'theta', 'p', 'q')
    distinguish = {
        'moment_gain': 'climbs and descents at constant attitude: a thrust curve changes the vertical '
                       'response to a thrust change as well, a moment gain only roll and pitch',
        'rotor_map': 'yaw turns at several thrust levels: an offset in the speeds changes each rotor\'s '
                     'reaction torque as it changes its thrust, a thrust curve the thrust alone; or log '
                     'the speeds the ESCs measure, which have no offset',
    }
    # about hover its roll and pitch moments are (1 + k_Tw/2) times the commands': a k_Tw below 0
    # can take up part of a torque the controller cancels, as a moment gain below 1 can
    scales_commanded_moment = True

    def parameters(self, airframe):
        # a k_Tw < 0 makes the thrust peak at w/w_h = 2 (1 - k_Tw) / (-3 k_Tw): 1.78 at the -0.6
        # bound, past the speeds flown; at -1 it was 1.33, within them (a thrust falling as a
        # rotor speeds up, which no propeller has)
        return [Parameter("k_Tw", 1, 0.0, "1", -0.6, 1.0, 0.05, 0.0, True,
                          "relative change of the thrust coefficient per relative rotor speed above hover",
                          self.name)]

    def plausible_values(self, airframe, K_T):
        return {"k_Tw": 0.1}

    def plausible_limits(self, airframe):
        # a propeller's thrust coefficient moves by a few to some tens of per cent over its
        # working speeds (Reynolds number); one that doubles per speed change is a wrong model
        return {"k_Tw": 0.5}

    def interpretation_notes(self, values, std, airframe):
        """The command-to-speed offset that gives the same thrust change to first order:
        ``K_T (w + c)^2`` has ``d ln T / d ln w = 2 - 2 c / w_h`` at hover, so ``c = -k_Tw w_h / 2``
        (``rotor_map``, not a default candidate: a blind audit's speeds logged 40 rad/s above
        the rotors' were named ``thrust_curve`` with k_Tw = 0.115, i.e. c = -37 rad/s; with
        ``rotor_map`` among the candidates it was named, LR 4577 against 3371)."""
        k, kt = values.get("k_Tw"), values.get("K_T")
        if k is None or "k_Tw" not in std or not kt or kt <= 0 or "w_offset" in values:
            return []
        s = std["k_Tw"]
        if not (np.isfinite(s) and s > 0 and abs(k) > 2 * s):
            return []
        w_h = float(np.sqrt(airframe.mass * airframe.gravity / (airframe.n_rotors * kt)))
        return [f"k_Tw = {k:.3g} is, to first order about hover ({w_h:.0f} rad/s), what logged rotor speeds "
                f"{abs(k) * w_h / 2:.3g} rad/s {'above' if k > 0 else 'below'} the rotors' give (a command-to-speed "
                f"map's offset, rotor_map: w = w_log + w_offset, w_offset = {-k * w_h / 2:+.3g} rad/s), which "
                "changes the yaw torque as well: where the logged speeds are commands, add rotor_map to the "
                "candidates (--candidates) to tell them apart"]

    def lowers_top_thrust(self, values):
        k = values.get("k_Tw")
        return f"k_Tw = {k:.3g}" if k is not None and k < 0 else ""

    def modify(self, ctx):
        af = ctx.airframe
        w_hover = ca.sqrt(af.mass * af.gravity / (af.n_rotors * ctx.params["K_T"]))
        ctx.thrust_scale *= 1.0 + ctx.params["k_Tw"] * (ctx.w / w_hover - 1.0)

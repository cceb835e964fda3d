"""A vehicle that is not symmetric: the centre of gravity off the rotor centre, rotors of
unequal thrust. Both need unequal rotor speeds in hover (confusable; see ``distinguish``)."""
from __future__ import annotations

import casadi as ca

from ..parameters import Parameter
from .base import Effect

__all__ = ["CogOffset", "MotorAsymmetry"]


class CogOffset(Effect):
    """Centre of gravity displaced by ``r_cog = [dx, dy]`` (body frame) from the centre of
    the rotor plane: every thrust moment arm becomes ``r_i - r_cog``, so hover needs
    unequal rotor speeds and a level hover with equal speeds pitches/rolls.
    """

    name = "cog_offset"
    summary = "centre of gravity offset from the rotor centre"
    excited_by = 'hovers and roll/pitch steps at several thrust levels'
    fit_advice = 'hover and attitude steps'
    channels = ('phi', 'theta', 'p', 'q', 'x', 'y')
    distinguish = {
        'motor_asymmetry': 'hover at several thrust levels and yaw angles',
        'attitude_bias': 'fly roll and pitch steps: a bias shifts readings, an offset needs torque',
    }
    shifts_trim = True
    trim_evidence = ("steady",)

    def parameters(self, airframe):
        return [Parameter("r_cog", 2, 0.0, "m", -0.5, 0.5, 0.01, 0.0, True,
                          "centre-of-gravity offset along body x, y", self.name)]

    def plausible_values(self, airframe, K_T):
        arm = max(airframe.arm_length, 1e-3)
        return {"r_cog": [0.06 * arm, -0.04 * arm]}

    def plausible_limits(self, airframe):
        # 15 % of the arm (7 mm on a Crazyflie, 2.5 cm on a 1 kg quad): beyond, a payload
        # would hang visibly off the middle
        return {"r_cog": 0.15 * max(airframe.arm_length, 1e-3)}

    def modify(self, ctx):
        c = ctx.params["r_cog"]
        n = ctx.airframe.n_rotors
        ctx.rotor_pos = ctx.rotor_pos - ca.repmat(ca.horzcat(c[0], c[1], 0), n, 1)


class MotorAsymmetry(Effect):
    """Per-rotor thrust (and reaction torque) factors ``1 + d_i``, a weak or damaged rotor.

    The parameter ``K_T_dev`` holds ``d_1..d_{N-1}``; ``d_N = -sum(d_1..d_{N-1})`` so that
    ``K_T`` stays the rotors' mean coefficient and the deviations are identifiable.
    """

    name = "motor_asymmetry"
    summary = "per-rotor thrust factors 1+d_i (sum d_i = 0)"
    excited_by = 'hovers at several thrust levels and yaw turns'
    fit_advice = 'roll and pitch steps with varied thrust'
    channels = ('phi', 'theta', 'p', 'q', 'psi', 'r', 'x', 'y')
    shifts_trim = True
    trim_evidence = ("steady",)

    def parameters(self, airframe):
        return [Parameter("K_T_dev", airframe.n_rotors - 1, 0.0, "1", -0.9, 0.9, 0.05, 0.0, True,
                          "relative thrust deviation of rotors 1..N-1", self.name)]

    def plausible_values(self, airframe, K_T):
        n = airframe.n_rotors
        return {"K_T_dev": [-0.08] + [0.08 / (n - 1)] * (n - 2)}

    def plausible_limits(self, airframe):
        # a worn or chipped propeller, a tired motor: up to about a quarter of the thrust;
        # a rotor further off is a broken one, which one sees before one fits it
        return {"K_T_dev": 0.25}

    def modify(self, ctx):
        d = ctx.params["K_T_dev"]
        factors = 1.0 + ca.vertcat(d, -ca.sum1(d))
        ctx.thrust_scale *= factors
        ctx.torque_scale *= factors

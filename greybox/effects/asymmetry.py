"""A vehicle that is not symmetric: the centre of gravity off the rotor centre, rotors of
unequal thrust. Both need unequal rotor speeds in hover (confusable; see ``distinguish``)."""
from __future__ import annotations

import casadi as ca
import numpy as np
from scipy import stats

from ..parameters import Parameter
from .base import Effect
from .rotor import YawTorque

__all__ = ["CogOffset", "MotorAsymmetry", "NEGLIGIBLE_THRUST_DEVIATION"]

NEGLIGIBLE_THRUST_DEVIATION = 0.0008
"""A rotor's thrust this far from the rotors' mean (0.08 %, 1 % of a plausible asymmetry) is
physically negligible. Both effects here need unequal speeds in hover and are told apart by
little else, so they are judged by one yardstick: a centre-of-gravity offset is negligible up
to the offset whose moment in hover is that of one rotor this far off (a blind audit's 2 kg
vehicle with its CoG 0.1 mm off: the offset, refused as below 1 % of a plausible offset,
0.135 mm, left a rotor 0.09 % weak, which turns it as much, as the verdict)."""


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

    def negligible_size(self, airframe):
        # In hover the weight acting at r_cog turns the body by m g |r_cog| = N T |r_cog|; one
        # rotor d off (the others -d/(N-1) each, the mean kept) by d T |r_1| N/(N-1): equal
        # where |r_cog| = d |r_1| / (N-1), |r_1| the rotors' mean distance from the centre
        pos = np.asarray(airframe.rotor_positions, dtype=float)[:, :2]
        arm = float(np.mean(np.hypot(pos[:, 0], pos[:, 1]))) if len(pos) else 0.0
        n = max(airframe.n_rotors, 2)
        return {"r_cog": NEGLIGIBLE_THRUST_DEVIATION * max(arm, 1e-3) / (n - 1)}

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
    scales_reaction_torques = True

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

    def negligible_size(self, airframe):
        return {"K_T_dev": NEGLIGIBLE_THRUST_DEVIATION}

    SPIN_SHARE = 2 ** -0.5
    """The spin-direction pattern's share of the gains' norm above which they are mostly a
    difference between the two spin directions (more than the rest of them together)."""
    SPIN_NOTABLE = 0.03
    """A spin-direction difference of this size per rotor (3 % of the thrust, as a notable
    steady command imbalance) or more is worth judging."""

    def plausibility_warnings(self, values, std, airframe):
        """Beyond :meth:`plausible_limits`, gains that are mostly a difference between the spin
        directions (``d_i ~ c s_i``) in a fit whose ``b/K_T`` is below what propellers give. The
        gains scale each rotor's reaction torque as well as its thrust: with any propeller's
        ``b`` such a difference is a steady yaw torque ``b c sum w_i^2`` that the logged
        commands would have to cancel, and a fit escapes it only through ``b`` near zero; the
        gains then stand in for something else (the total thrust changing with the yaw command,
        which ``sum_i c s_i w_i^2`` is), not rotors of unequal strength. A real Crazyflie
        flight's first 60 %: gains +14 %, -10 %, +17 %, -21 % (M1/M3 +15.5 % against M2/M4)
        with b/K_T = 3e-6 m, where the steady commands showed no spin-direction imbalance (0.0 %)
        and the whole flight takes a CoG offset."""
        out = super().plausibility_warnings(values, std, airframe)
        n = airframe.n_rotors
        names = [f"K_T_dev[{i}]" for i in range(n - 1)]
        b, kt = values.get("b"), values.get("K_T")
        if any(nm not in std or nm not in values for nm in names) or b is None or not kt:
            return out
        lo = YawTorque.RATIO_RANGE[0]
        spins = np.asarray(airframe.spins, dtype=float)
        pattern = spins - spins.mean()
        if b / kt >= lo or not np.any(pattern):
            return out
        d = np.array([values[nm] for nm in names], dtype=float)
        full = np.append(d, -d.sum())
        c = float(full @ pattern / (pattern @ pattern))
        spin_part = c * pattern
        if np.linalg.norm(spin_part) < self.SPIN_SHARE * np.linalg.norm(full) or abs(c) < self.SPIN_NOTABLE:
            return out
        by_spin = ", ".join(f"spin {int(sp):+d} rotors {100 * float(np.mean(full[spins == sp])):+.1f} %"
                            for sp in sorted(set(spins.tolist()), reverse=True))
        return out + [f"K_T_dev is mostly a difference between the spin directions ({by_spin} in thrust and "
                      f"reaction torque) in a fit with b/K_T = {b / kt:.2g} m, below what propellers give "
                      f"({lo:g} m): with a propeller's b that difference is a steady yaw torque the commands "
                      "would have to cancel, which the fit escapes only through b near zero; the gains stand in "
                      "for something else (a total thrust that changes with the yaw command), not rotors of "
                      "unequal strength"]

    def reduces_to(self, other, values, covariance, free_names, airframe):
        """For ``cog_offset``: rotor gains ``d_i`` linear in the rotors' positions,
        ``d_i = a x_i + c y_i``, move the thrust's centre as a CoG offset of
        ``-(a sum x_i^2, c sum y_i^2) / N`` does, and change neither the total thrust nor (on a
        symmetric frame with alternating spins) the yaw torque: near hover the two are the same
        physics. They are the offset's when no pattern of what the gains hold beyond that plane
        (the principal directions of its covariance, carried through; ``N - 3`` of them) is both
        away from zero (1 % two-sided, Bonferroni over the directions) and more than a tenth
        of the plane's part (RMS over the rotors): the yaw pins the spin pattern to 1e-4, where
        a model missing anything else is off by more, and on a hexacopter two patterns move no
        torque at hover and are hardly determined. Measured on the ninth audit's hexacopter with
        a (15, -10) mm offset: gains -0.13 ... +0.17 whose plane is an offset of (15, -10) mm;
        beyond it the spin pattern 6e-4 at 3.9 std, the other two within 1 std. A rotor 7 %
        weak: its rest is as large as its plane's part on a hexacopter, 0.7 of it on a
        quadrotor, and far from zero."""
        n = airframe.n_rotors
        names = [f"K_T_dev[{i}]" for i in range(n - 1)]
        if other != "cog_offset" or n < 4 or any(nm not in free_names for nm in names):
            return ""
        idx = [list(free_names).index(nm) for nm in names]
        d = np.array([values[nm] for nm in names], dtype=float)
        C = np.asarray(covariance, dtype=float)[np.ix_(idx, idx)]
        if not np.all(np.isfinite(C)):
            return ""
        M = np.vstack([np.eye(n - 1), -np.ones((1, n - 1))])      # d_N = -sum(d_1..d_N-1)
        pos = np.asarray(airframe.rotor_positions, dtype=float)[:, :2]
        plane = np.column_stack([pos, np.ones(n)])
        to_plane = np.linalg.pinv(plane)
        full = M @ d
        coef = to_plane @ full
        Q = np.eye(n) - plane @ to_plane
        rest, cov_rest = full - plane @ coef, Q @ M @ C @ M.T @ Q.T
        df = n - np.linalg.matrix_rank(plane)
        if df <= 0:
            return ""
        lam, V = np.linalg.eigh(0.5 * (cov_rest + cov_rest.T))
        lam, V = lam[-df:], V[:, -df:]                             # the rest lives in df directions
        along = V.T @ rest
        z_crit = float(stats.norm.isf(0.005 / df))
        in_plane = float(np.linalg.norm(plane @ coef))
        standing = (np.abs(along) > z_crit * np.sqrt(np.maximum(lam, 0.0))) & (np.abs(along) > 0.1 * in_plane)
        if np.any(standing):
            return ""
        offset = -coef[:2] * np.sum(pos ** 2, axis=0) / n
        return (f"rotor gains in the pattern of a CoG offset of ({1e3 * offset[0]:.3g}, {1e3 * offset[1]:.3g}) mm "
                f"(linear in the rotors' positions; the rest, {100 * np.linalg.norm(rest) / max(in_plane, 1e-300):.0f} % "
                "of it, within its noise or under a tenth of it in every pattern)")

    def modify(self, ctx):
        d = ctx.params["K_T_dev"]
        factors = 1.0 + ca.vertcat(d, -ca.sum1(d))
        ctx.thrust_scale *= factors
        ctx.torque_scale *= factors

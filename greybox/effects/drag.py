"""Drag and the air it acts on: translational drag (linear, in the base model, and
quadratic), rotor drag (at the centre of gravity and at each hub) and a constant wind that
makes every drag act on the air-relative velocity."""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..kinematics import HEADING_SPREAD, heading_spread
from ..parameters import Parameter
from .base import Effect

__all__ = ["LinearDrag", "QuadraticDrag", "RotorDrag", "HubRotorDrag", "DragMoment", "Wind"]


# the fastest drag time constant m/Kd a multirotor physically has (see LinearDrag)
DRAG_TIME_CONSTANT_MIN = 0.25


def _sumsq_speed(v: ca.SX) -> ca.SX:
    # sqrt(v.v) has an undefined derivative at v = 0; a tiny floor keeps Jacobians finite.
    return ca.sqrt(ca.dot(v, v) + 1e-12)


class LinearDrag(Effect):
    """Translational drag ``F = -Kd * v_air`` per world axis (the seed paper's eq. 4)."""

    name = "linear_drag"
    summary = "translational drag -Kd*v (world axes)"
    excited_by = 'translations at moderate speed along each axis'
    fit_advice = 'fast translations (fast) along each axis, and vertical steps for Kd[2]'
    channels = ('x', 'y', 'z')
    distinguish = {
        'rotor_drag': 'fly the same speeds at different thrust levels (climbing and descending translations): rotor drag scales with rotor speed',
    }

    def parameters(self, airframe):
        # upper bound: a drag time constant m/Kd below 0.1 s is no multirotor; it keeps a
        # misspecified model from running away to absurd drag
        return [Parameter("Kd", 3, 0.1, "N s/m", 0.0, 10.0 * airframe.mass, 0.1, 0.0, True,
                          "linear drag coefficients along world x, y, z", self.name)]

    def plausible_limits(self, airframe):
        # a rotor's heave damping (blade element and momentum theory, Padfield's Z_w) gives a
        # vertical time constant m/Kd of about 1 s on a 1 kg quadrotor, horizontal drags
        # several seconds; a quarter of a second leaves a margin of four
        return {"Kd": airframe.mass / DRAG_TIME_CONSTANT_MIN}

    def plausibility_warnings(self, values, std, airframe):
        """Beyond :meth:`plausible_limits`, the time constant ``m/Kd`` each such drag gives,
        and what usually stands behind it. A blind audit's sprayer losing 15 % of its mass to
        its emptying tank took `Kd[2]` 29 ± 12 N s/m on 4 kg (0.14 s), silently."""
        out = super().plausibility_warnings(values, std, airframe)
        if not out:
            return out
        fast = [f"{c} {airframe.mass / values[c]:.2g} s" for c in (f"Kd[{i}]" for i in range(3))
                if c in std and values.get(c, 0.0) > self.plausible_limits(airframe)["Kd"]]
        out[-1] += (f" (time constant m/Kd: {', '.join(fast)}; a rotor's heave damping gives about a second, "
                    "horizontal drag several: a mass or thrust that changes over the flight, or a force along "
                    "that axis the model lacks, is the usual cause)")
        return out

    def add_forces(self, ctx):
        ctx.force_world -= ctx.params["Kd"] * ctx.v_air


class QuadraticDrag(Effect):
    """Parasitic (pressure) drag ``F_i = -Kq_i * |v_air| * v_air_i`` along world axes."""

    name = "quadratic_drag"
    summary = "parasitic drag -Kq*|v|*v"
    excited_by = 'translations at several speeds, up to the fastest you can fly'
    fit_advice = 'translations at several different speeds (fast)'
    channels = ('x', 'y', 'z')
    distinguish = {
        'rotor_drag': 'fly several speeds at a constant thrust, and the same speed at another thrust',
        'wind': 'fly the same speed upwind and downwind',
    }

    def parameters(self, airframe):
        return [Parameter("Kq", 3, 0.0, "N s^2/m^2", 0.0, 10.0 * airframe.mass, 0.01, 0.0, True,
                          "quadratic drag coefficients along world x, y, z", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"Kq": [0.04 * airframe.mass ** (2 / 3)] * 3}

    def add_forces(self, ctx):
        ctx.force_world -= ctx.params["Kq"] * _sumsq_speed(ctx.v_air) * ctx.v_air


class RotorDrag(Effect):
    """Rotor induced drag / blade flapping: a horizontal body-frame force
    ``F_b = -k_rd * sum(w_i) * [vb_x, vb_y, 0]`` with ``vb = R^T v_air`` the body-frame air
    velocity. It grows with rotor speed, which separates it from ``linear_drag`` when the
    thrust changes.
    """

    name = "rotor_drag"
    summary = "rotor drag -k_rd*sum(w)*v_body (horizontal, body frame)"
    excited_by = 'translations at one speed with different thrust (climbing, descending)'
    fit_advice = 'horizontal flight at different thrust levels (fast, step_z while moving)'
    channels = ('x', 'y')
    distinguish = {
        'wind': 'fly in several directions: wind has a fixed direction',
    }

    def parameters(self, airframe):
        return [Parameter("k_rd", 1, 0.0, "N s/m/(rad/s)", 0.0, np.inf, 1e-5, 0.0, True,
                          "rotor drag per unit rotor speed and body velocity", self.name)]

    def plausible_values(self, airframe, K_T):
        m, n = airframe.mass, airframe.n_rotors
        w_hover = float(np.sqrt(m * airframe.gravity / (n * K_T)))
        return {"k_rd": 0.35 * m / (n * w_hover)}

    def add_forces(self, ctx):
        vb = ctx.R.T @ ctx.v_air
        fb = -ctx.params["k_rd"] * ca.sum1(ctx.w) * ca.vertcat(vb[0], vb[1], 0)
        ctx.force_world += ctx.R @ fb


class HubRotorDrag(Effect):
    """Rotor drag at each hub, on the hub's own air velocity: rotor ``i`` at ``r_i`` (body,
    from the centre of gravity, the hubs a height ``h_hub`` above it) sees
    ``v_i = R^T v_air + omega x r_i`` and feels
    ``F_i = -w_i * [k_rdh v_ix, k_rdh v_iy, k_rdv v_iz]`` (body frame), with the torque
    ``r_i x F_i``. Summed over rotors the force is ``rotor_drag``'s (to first order), but
    the ``omega x r_i`` term also damps the body rates — roll and pitch through the vertical
    part (a rolling vehicle's descending rotors push up) and the hub height, yaw through the
    horizontal part — so a model without it pushes ``b`` down to absorb the yaw damping. The
    hub height gives the drag a moment: flying forward pitches the nose up, ``h_hub k_rdh
    sum(w)`` per m/s, what ``drag_moment`` holds as a constant, here following the rotor
    speeds. ``k_rdv`` (a thrust that falls with the rotor's axial inflow) is fitted too.

    Without the height, a 30 g vehicle whose hubs sit 15 mm above its centre of gravity
    (``tests/foreign_sim.py``) was named ``drag_moment`` and ``hub_rotor_drag``, then
    ``thrust_curve`` and ``moment_gain`` for the roll and pitch damping and the moment's
    change with the rotor speeds that a constant moment lacks, with ``k_rdv`` 16 std from the
    truth's 0; with it, ``hub_rotor_drag`` alone, ``h_hub`` 15.08 +- 0.08 mm.
    """

    name = "hub_rotor_drag"
    summary = "rotor drag at each hub on R^T v + omega x r_i, the hubs above the CoG (also damps body rates)"
    excited_by = "translations at different thrust levels and fast roll, pitch and yaw rates"
    fit_advice = "fast translations at several thrust levels, and fast yaw turns and roll/pitch steps"
    channels = ("x", "y", "z", "p", "q", "r", "phi", "theta", "psi")
    shape_parameters = ("h_hub",)
    distinguish = {
        "rotor_drag": "fast yaw turns and roll/pitch steps: the hub form damps the body rates, the "
                      "centre-of-gravity form does not",
        "linear_drag": "fly the same speeds at different thrust levels: rotor drag scales with rotor speed",
        "drag_moment": "fly the same speeds at different thrust levels, and fast roll/pitch steps: the "
                       "hubs' drag and its moment scale with the rotor speed and damp the rates, a drag on "
                       "the body does neither",
    }

    def parameters(self, airframe):
        arm = float(airframe.arm_length)
        return [Parameter("k_rdh", 1, 0.0, "N s/m/(rad/s)", 0.0, np.inf, 1e-5, 0.0, True,
                          "in-plane drag per unit rotor speed and hub air velocity", self.name),
                Parameter("k_rdv", 1, 0.0, "N s/m/(rad/s)", 0.0, np.inf, 1e-5, 0.0, True,
                          "axial (thrust-axis) drag per unit rotor speed and hub air velocity", self.name),
                Parameter("h_hub", 1, 0.0, "m", -arm, arm, 0.25 * arm, 0.0, True,
                          "height of the rotor hubs above the centre of gravity (beyond the airframe's "
                          "rotor positions)", self.name)]

    def plausible_values(self, airframe, K_T):
        m, n = airframe.mass, airframe.n_rotors
        w_hover = float(np.sqrt(m * airframe.gravity / (n * K_T)))
        k = 0.35 * m / (n * w_hover)
        return {"k_rdh": k, "k_rdv": 0.5 * k, "h_hub": 0.25 * float(airframe.arm_length)}

    def add_forces(self, ctx):
        vb = ctx.R.T @ ctx.v_air
        k = ca.vertcat(ctx.params["k_rdh"], ctx.params["k_rdh"], ctx.params["k_rdv"])
        hub = ca.vertcat(0, 0, -ctx.params["h_hub"])      # body z points down: above is -z
        force = ca.SX.zeros(3)
        torque = ca.SX.zeros(3)
        for i in range(ctx.airframe.n_rotors):
            r = ctx.rotor_pos[i, :].T + hub
            f = -ctx.w[i] * k * (vb + ca.cross(ctx.omega, r))
            force += f
            torque += ca.cross(r, f)
        ctx.force_world += ctx.R @ force
        ctx.torque_body += torque


class DragMoment(Effect):
    """The horizontal aerodynamic force on the rotors (rotor drag, blade flapping) acts at
    the rotor plane, above the centre of gravity, so it also pitches and rolls the vehicle:
    ``M_b = [-k_dm[0] * vb_y, k_dm[1] * vb_x, 0]`` (body FRD, ``vb = R^T v_air``). With the
    rotor plane a height ``h`` above the centre of gravity and a horizontal drag
    ``-k v_b`` acting there, ``k_dm = h k``: flying forward pitches the nose up, flying to
    the right rolls to the left. The controller trims it out in steady flight, so a model
    without it sees rotor-speed differences that follow the speed and explain no motion.
    """

    name = "drag_moment"
    summary = "moment of the rotor drag acting above the centre of gravity: pitches against the airflow"
    excited_by = "translations at several speeds in several directions (the trim follows the speed)"
    fit_advice = "fast translations forward/backward and left/right"
    channels = ("phi", "theta", "p", "q", "x", "y")
    trim_evidence = ("speed",)
    distinguish = {
        "cog_offset": "fly at several speeds: an offset's trim is the same at every speed, the drag "
                      "moment's grows with it",
        # against hub_rotor_drag: its own entry (the hubs above the CoG give it this moment too)
    }

    def parameters(self, airframe):
        lim = self._bound(airframe)
        scale = self.plausible_values(airframe, 0.0)["k_dm"][0]
        return [Parameter("k_dm", 2, 0.0, "N m s/m", -lim, lim, scale, 0.0, True,
                          "drag moment about body x per body-y air speed, about body y per body-x",
                          self.name)]

    @staticmethod
    def _bound(airframe) -> float:
        # the largest drag linear_drag allows (time constant 0.1 s) acting two arms above
        return 2.0 * max(airframe.arm_length, 1e-3) * 10.0 * airframe.mass

    def plausible_values(self, airframe, K_T):
        # a horizontal drag of 0.35 m (N s/m per kg, as rotor_drag's) at a third of the arm
        k = 0.35 * airframe.mass * 0.3 * max(airframe.arm_length, 1e-3)
        return {"k_dm": [k, k]}

    def plausible_limits(self, airframe):
        # the largest drag linear_drag allows acting one arm above the centre of gravity
        return {"k_dm": max(airframe.arm_length, 1e-3) * 10.0 * airframe.mass}

    def add_forces(self, ctx):
        vb = ctx.R.T @ ctx.v_air
        k = ctx.params["k_dm"]
        ctx.torque_body += ca.vertcat(-k[0] * vb[1], k[1] * vb[0], 0)


class Wind(Effect):
    """Constant horizontal wind ``[w_N, w_E]`` (m/s, world): every drag effect acts on the
    velocity relative to the air, ``v_air = v - wind``. It needs a drag effect to matter.
    """

    name = "wind"
    summary = "constant horizontal wind; drag acts on v - wind"
    excited_by = 'flight in several directions (wind keeps one direction)'
    fit_advice = 'horizontal flight in several directions'
    channels = ('x', 'y')
    shifts_trim = True
    per_flight = True      # the air moves differently on each flight

    @classmethod
    def mimicked_by_sensor_offsets(cls, logs):
        # a wind pushes in a direction fixed in the world, an accelerometer's offset in one fixed
        # in the body: alike only while the vehicle holds its heading (the real NanoBench
        # flights, within 20 degrees); a blind audit's outdoor flights that turned (a share
        # 0.25 of a world-fixed force no body-fixed offset holds) had the offset taken over a
        # wind whose likelihood ratio was 7 times larger, the offset fitted at 4 times its truth
        return heading_spread(logs) < HEADING_SPREAD

    def parameters(self, airframe):
        return [Parameter("wind", 2, 0.0, "m/s", -30.0, 30.0, 1.0, 0.0, True,
                          "wind velocity, world north and east", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"wind": [1.5, -1.0]}

    def modify(self, ctx):
        wnd = ctx.params["wind"]
        ctx.v_air = ctx.v_air - ca.vertcat(wnd[0], wnd[1], 0)

"""A predictor's disturbance model: the roll and pitch moment the logged commands do not
show, estimated with each prediction window's start state and held over the window."""
from __future__ import annotations

import casadi as ca

from .base import Effect

__all__ = ["HeldMoment"]


class HeldMoment(Effect):
    """Unmeasured roll and pitch moment, constant: states ``d_p, d_q`` (the angular
    accelerations it gives, rad/s^2) with zero derivative, starting at zero.

    Not a physical effect to fit or diagnose: :func:`greybox.predict` adds it with
    ``held_moment=True``, so each window's start-state estimate (over the last
    ``init_window`` seconds) also takes the moment the vehicle feels there, and the prediction
    holds it. A closed-loop vehicle's controller cancels a slow moment the log does not record
    (a real Crazyflie's below 1 Hz: ``experiments/real_torque_bands.py``); an open-loop model
    without it rolls away within a fraction of a second. Yaw is left out: a held yaw moment
    made the heading predictions worse on the same flights.
    """

    name = "held_moment"
    summary = "unmeasured roll/pitch moment held over a prediction window (a disturbance model)"
    channels = ("phi", "theta", "p", "q")

    def state_names(self, airframe):
        return ["d_p", "d_q"]

    def state_derivative(self, ctx):
        return ca.SX.zeros(2)

    def add_forces(self, ctx):
        d = ctx.extra_states[self.name]
        ctx.torque_body += ca.DM(ctx.airframe.inertia) @ ca.vertcat(d[0], d[1], 0)

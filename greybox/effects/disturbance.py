"""Disturbance models: a moment the logged commands do not show, held over a prediction
window (:class:`HeldMoment`), or wandering as a random walk through a fit
(:class:`DisturbanceTorque`)."""
from __future__ import annotations

import casadi as ca

from .base import Effect

__all__ = ["HeldMoment", "DisturbanceTorque"]


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


class DisturbanceTorque(Effect):
    """Unmeasured torque about all three body axes as a random walk: states ``d_p, d_q, d_r``
    (the angular accelerations it gives, rad/s^2), zero derivative, moved only by the
    process noise of a fit with ``process_noise`` (their scale starts at the body rates'
    shooting gaps per second, :attr:`~greybox.effects.Effect.rate_of_unmodelled`).

    Why: a closed-loop vehicle's controller answers a slowly varying torque (turbulence, a
    moment the model lacks) through the very commands the model reads, so the commanded
    torque and the disturbance are correlated. Without a state for it, a fit explains the part
    of the commands that moved nothing by shrinking the torque coefficients: a 1.2 kg
    vehicle in a random 0.02 N m torque gave ``b`` 29 % low; with this effect 5 % low (the same
    fit on the flight without turbulence: +0.2 %). On a real Crazyflie flight it moved
    ``b/K_T`` from 0.0006 m to 0.0075 m, inside what propellers give. Not a diagnosis
    candidate (it explains any torque): add it to the model, ``model + DisturbanceTorque()``,
    and fit with process noise.
    """

    name = "disturbance_torque"
    summary = "unmeasured torque as a random walk (a closed-loop fit's disturbance model)"
    channels = ("phi", "theta", "psi", "p", "q", "r")
    rate_of_unmodelled = {"d_p": "p", "d_q": "q", "d_r": "r"}

    def state_names(self, airframe):
        return ["d_p", "d_q", "d_r"]

    def state_derivative(self, ctx):
        return ca.SX.zeros(3)

    def add_forces(self, ctx):
        d = ctx.extra_states[self.name]
        ctx.torque_body += ca.DM(ctx.airframe.inertia) @ d

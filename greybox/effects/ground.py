"""The ground: thrust increase close to the ground plane."""
from __future__ import annotations

import casadi as ca

from ..parameters import Parameter
from .base import Effect

__all__ = ["GroundEffect"]


class GroundEffect(Effect):
    """Thrust increase near the ground (Cheeseman–Bennett):
    ``T_IGE / T = 1 / (1 - k_ge / h**2)`` with ``h = ground_z - z`` the height above the
    ground plane and ``k_ge = (R_rotor/4)**2``. The ratio ``k_ge/h**2`` is capped at 0.5
    (factor 2) so the model stays finite on the ground.
    """

    name = "ground_effect"
    summary = "thrust increase close to the ground, 1/(1 - k_ge/h^2)"
    excited_by = 'low passes close to the ground (below about two rotor diameters)'
    fit_advice = 'a slow pass close to the ground (ground)'
    channels = ('z',)
    shifts_trim = True

    def parameters(self, airframe):
        return [Parameter("k_ge", 1, 0.0, "m^2", 0.0, 1.0, 1e-3, 0.0, True,
                          "ground-effect coefficient (rotor radius / 4)^2", self.name)]

    def plausible_values(self, airframe, K_T):
        r_rotor = 0.5 * max(airframe.arm_length, 1e-3)
        return {"k_ge": (r_rotor / 4) ** 2 * 4}

    def modify(self, ctx):
        h = ca.fmax(ctx.airframe.ground_z - ctx.pos[2], 1e-3)
        ratio = ca.fmin(ctx.params["k_ge"] / h ** 2, 0.5)
        ctx.thrust_scale *= 1.0 / (1.0 - ratio)

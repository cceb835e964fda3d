"""Named model parameters with units, bounds, scales and a "switched off" value."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import GreyboxInputError

__all__ = ["Parameter", "flat_names"]


@dataclass(frozen=True)
class Parameter:
    """A (scalar or vector) model parameter.

    Attributes:
        name: identifier, e.g. ``"K_T"`` or ``"Kd"``.
        size: number of components; vector components are named ``Kd[0]``, ``Kd[1]``...
        default: value used when the airframe gives none.
        unit: SI unit, for people.
        lower, upper: bounds used by the fitter.
        scale: typical magnitude; the fitter works with ``value / scale`` (O(1)).
        null: value at which the parameter's effect vanishes (used by the diagnosis).
        free: whether fitting estimates it by default (else it is held fixed).
        description: one line for docs and reports.
        lower_exclusive: the value must lie strictly above ``lower`` (e.g. ``K_T > 0``: a
            rotor without thrust is not a model the fitter or the hover trim can use).
    """

    name: str
    size: int = 1
    default: float | tuple[float, ...] = 0.0
    unit: str = ""
    lower: float = -np.inf
    upper: float = np.inf
    scale: float = 1.0
    null: float = 0.0
    free: bool = True
    description: str = ""
    effect: str = field(default="base", compare=False)
    lower_exclusive: bool = False

    def check_values(self, values, where: str, component: str | None = None) -> None:
        """Raise a :class:`GreyboxInputError` naming ``where`` if a value is not finite or
        lies outside ``[lower, upper]`` (``(lower, upper]`` when ``lower_exclusive``)."""
        arr = np.atleast_1d(np.asarray(values, dtype=float))
        for i, v in enumerate(arr):
            name = component or (self.name if arr.size == 1 else f"{self.name}[{i}]")
            if not np.isfinite(v):
                raise GreyboxInputError(f"{where}: {name} = {v:g} is not a finite number")
            below = v <= self.lower if self.lower_exclusive else v < self.lower
            if below or v > self.upper:
                lo = "(" if self.lower_exclusive else "["
                raise GreyboxInputError(f"{where}: {name} = {v:g} is outside its range "
                                        f"{lo}{self.lower:g}, {self.upper:g}] ({self.unit or 'no unit'})")

    @property
    def component_names(self) -> list[str]:
        if self.size == 1:
            return [self.name]
        return [f"{self.name}[{i}]" for i in range(self.size)]

    def default_vector(self) -> np.ndarray:
        d = np.atleast_1d(np.asarray(self.default, dtype=float))
        if d.size == 1 and self.size > 1:
            d = np.full(self.size, float(d[0]))
        return d.copy()


def flat_names(params: list[Parameter]) -> list[str]:
    """Component names of a list of parameters, in order (``K_T``, ``Kd[0]``...)."""
    return [n for p in params for n in p.component_names]

"""Airframe description: mass, inertia, rotor geometry (README, "Airframe (TOML)").

An :class:`Airframe` holds the known physical constants of a vehicle and the initial
guesses of the parameters to fit. It is read from TOML with :func:`load_airframe`; every
mistake in the file is reported as one :class:`~greybox.errors.GreyboxInputError` naming
the file and the key.
"""
from __future__ import annotations

import json

import math
import tomllib
import warnings as _warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .data import read_text_file
from .errors import AirframeWarning, GreyboxInputError

__all__ = ["Rotor", "Airframe", "load_airframe", "airframe_from_dict", "rotors_for_layout", "INERTIA_TOLERANCE", "INERTIA_SCALE", "INERTIA_PLAUSIBLE",
           "hub_reach"]

INERTIA_TOLERANCE = 0.05
"""Relative excess of ``J3 - J1 - J2`` over ``J3`` accepted (with an :class:`AirframeWarning`)
as measurement error of a published or measured inertia."""

_AIRFRAME_KEYS = {
    "name", "mass", "inertia", "arm_length", "layout", "rotor_inertia", "gravity", "ground_z",
}
_ROTOR_KEYS = {"position", "spin"}


@dataclass(frozen=True)
class Rotor:
    """One rotor: position in the body frame (FRD, m) and spin direction (+1/-1).

    The rotor's reaction torque on the body is ``spin * b * w**2`` about body +z.
    """

    position: tuple[float, float, float]
    spin: int


def rotors_for_layout(layout: str, arm_length: float) -> list[Rotor]:
    """Rotor positions and spins of the standard layouts ``plus`` and ``x`` (README, "Conventions")."""
    l = float(arm_length)
    if layout == "plus":
        pos = [(l, 0.0, 0.0), (0.0, l, 0.0), (-l, 0.0, 0.0), (0.0, -l, 0.0)]
        spin = [-1, 1, -1, 1]
    elif layout == "x":
        a = l / math.sqrt(2.0)
        pos = [(a, a, 0.0), (-a, -a, 0.0), (a, -a, 0.0), (-a, a, 0.0)]
        spin = [1, 1, -1, -1]
    else:
        raise GreyboxInputError(f"unknown layout {layout!r}: use 'plus', 'x' or [[rotor]] tables")
    return [Rotor(p, s) for p, s in zip(pos, spin)]


@dataclass
class Airframe:
    """Known constants of a multirotor and initial parameter guesses.

    Attributes:
        name: free text.
        mass: kg.
        inertia: 3x3 inertia matrix about the centre of gravity, body axes, kg m^2.
        rotors: rotor positions and spins.
        rotor_inertia: J_r, kg m^2, of one rotor about its axis.
        gravity: m/s^2.
        ground_z: world NED z of the ground plane (height above ground is ground_z - z).
        arm_length: m (informative when explicit rotors are given; without it, the hubs' mean
            distance from the centre: the effects' plausible sizes scale with it).
        layout: "plus", "x" or "custom".
        parameters: initial guesses of model parameters by name (values or lists).
        source: file the airframe was read from, if any.

    Example::

        from greybox import load_airframe
        af = load_airframe("greybox/data/airframes/paper.toml")
        af.mass, af.inertia, af.n_rotors        # 1.0, 3x3 array, 4
        af.rotor_positions, af.spins            # (4, 3) body FRD, m; +-1
        af.parameters["K_T"]                    # the file's initial guess
    """

    mass: float
    inertia: np.ndarray
    rotors: list[Rotor]
    name: str = "airframe"
    rotor_inertia: float = 0.0
    gravity: float = 9.81
    ground_z: float = 0.0
    arm_length: float = 0.0
    layout: str = "custom"
    parameters: dict[str, Any] = field(default_factory=dict)
    source: str | None = None

    def __post_init__(self) -> None:
        # The effects' plausible sizes scale with the arm (a CoG offset's 15 %, a drag moment's
        # lever): one built in Python from rotors alone gets the hubs' mean distance from the
        # centre, as load_airframe gives rotor tables without arm_length, not a 1-mm floor.
        if not self.arm_length > 0 and self.rotors:
            self.arm_length = hub_reach(self.rotors)

    @property
    def n_rotors(self) -> int:
        return len(self.rotors)

    @property
    def rotor_positions(self) -> np.ndarray:
        """(N, 3) rotor positions in the body frame."""
        return np.array([r.position for r in self.rotors], dtype=float)

    @property
    def spins(self) -> np.ndarray:
        return np.array([r.spin for r in self.rotors], dtype=float)

    def allocation_matrix(self) -> np.ndarray:
        """Geometric map G from squared rotor speeds to [thrust, roll, pitch, yaw] / coefficient.

        ``[U1, U2, U3, U4] = diag(K_T, K_T, K_T, b) @ G @ w**2`` for the base model.
        Rows: total thrust, roll torque (-y_i), pitch torque (+x_i), yaw torque (spin_i).
        """
        P = self.rotor_positions
        return np.vstack([np.ones(self.n_rotors), -P[:, 1], P[:, 0], self.spins])

    def hover_shares(self) -> np.ndarray:
        """Each rotor's share of the squared rotor speeds in a steady hover of equal rotors
        with the centre of gravity at the body origin, relative to the mean (1 for every rotor
        of a symmetric frame): the thrust that balances the weight with no roll, pitch or yaw
        torque (:meth:`allocation_matrix`; the least-norm such split where more than four
        rotors leave a choice). An H-frame with its front rotors nearer the centre of gravity
        than its rear ones hovers with the rear ones working harder, and that is no weak rotor.
        Equal shares where the geometry gives none that is positive."""
        G = self.allocation_matrix()
        target = np.zeros(G.shape[0])
        target[0] = 1.0
        w2 = np.linalg.lstsq(G, target, rcond=None)[0]
        if not (np.all(np.isfinite(w2)) and np.all(w2 > 0) and np.allclose(G @ w2, target, atol=1e-9)):
            return np.ones(self.n_rotors)
        return w2 / w2.mean()

    def to_toml(self) -> str:
        """The airframe as TOML text in the format :func:`load_airframe` reads (explicit rotors if custom)."""
        # a JSON string is a valid TOML basic string: quotes and backslashes survive
        lines = ["[airframe]", f"name = {json.dumps(self.name)}", f"mass = {self.mass!r}"]
        J = self.inertia
        if np.array_equal(J, np.diag(np.diag(J))):   # exact: small products of inertia are kept
            lines.append(f"inertia = [{', '.join(repr(float(v)) for v in np.diag(J))}]")
        else:
            rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in J)
            lines.append(f"inertia = [{rows}]")
        lines.append(f"arm_length = {self.arm_length!r}")
        if self.layout in ("plus", "x"):
            lines.append(f'layout = "{self.layout}"')
        lines += [f"rotor_inertia = {self.rotor_inertia!r}", f"gravity = {self.gravity!r}",
                  f"ground_z = {self.ground_z!r}"]
        if self.layout not in ("plus", "x"):
            for r in self.rotors:
                lines += ["", "[[rotor]]", f"position = [{', '.join(repr(float(v)) for v in r.position)}]",
                          f"spin = {r.spin}"]
        if self.parameters:
            lines += ["", "[parameters]"]
            for k, v in self.parameters.items():
                if isinstance(v, (list, tuple, np.ndarray)):
                    lines.append(f"{k} = [{', '.join(repr(float(x)) for x in v)}]")
                else:
                    lines.append(f"{k} = {float(v)!r}")
        return "\n".join(lines) + "\n"


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise GreyboxInputError(f"{where} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise GreyboxInputError(f"{where} must be finite, got {value!r}")
    return float(value)


def _vector(value: Any, n: int, where: str) -> list[float]:
    if not isinstance(value, list):
        raise GreyboxInputError(f"{where} must be a list of {n} numbers, got {value!r}")
    if len(value) != n:
        raise GreyboxInputError(f"{where} must have {n} entries, got {len(value)}")
    return [_number(v, f"{where}[{i}]") for i, v in enumerate(value)]


def _inertia(value: Any, where: str) -> np.ndarray:
    if isinstance(value, list) and value and all(isinstance(r, list) for r in value):
        if len(value) != 3:
            raise GreyboxInputError(f"{where} must be 3 numbers or a 3x3 matrix, got {len(value)} rows")
        J = np.array([_vector(r, 3, f"{where}[{i}]") for i, r in enumerate(value)])
        if not np.allclose(J, J.T, rtol=1e-9, atol=1e-12):
            raise GreyboxInputError(f"{where} is not symmetric: {J.tolist()}")
    else:
        J = np.diag(_vector(value, 3, where))
    eig = np.linalg.eigvalsh(J)
    if np.any(eig <= 0):
        raise GreyboxInputError(f"{where} must be positive definite (all moments > 0), "
                                f"eigenvalues {eig.tolist()}")
    # A rigid body's principal moments obey the triangle inequality. Measured inertias
    # (pendulum tests, CAD) carry a few per cent of error, and a flat airframe sits right on
    # the limit (J1 + J2 = J3 for a plate): a published set that breaks it by a few per cent
    # is measurement error, not a mistake.
    e = np.sort(eig)
    excess = (e[2] - e[0] - e[1]) / e[2]
    if excess > INERTIA_TOLERANCE:
        raise GreyboxInputError(f"{where} is not physical: principal moments {e.tolist()} violate "
                                f"J1 + J2 >= J3 by {100 * excess:.1f} % of J3 (more than the "
                                f"{100 * INERTIA_TOLERANCE:.0f} % allowed for measurement error)")
    if excess > 1e-9:
        _warnings.warn(f"{where}: principal moments {e.tolist()} violate J1 + J2 >= J3 by {100 * excess:.2f} % of J3; "
                       "accepted as measurement error", AirframeWarning, stacklevel=3)
    return J


INERTIA_SCALE = (0.01, 10.0)
"""Bounds of the largest principal moment over ``mass * L**2`` (L: the hubs' mean distance
from the centre of gravity). Multirotors lie at 0.15-0.55 (the motors and propellers alone,
a quarter of the mass at L, give about 0.25): outside by a factor 20 is a unit, not a
vehicle (a blind audit's mass of 1200 for 1.2 kg was reported as rotor speeds in rev/s)."""


INERTIA_PLAUSIBLE = (0.05, 1.5)
"""Bounds of the same ratio (:data:`INERTIA_SCALE`) outside which the airframe is accepted
with a warning: the motors and propellers, a tenth of a multirotor's mass or more, sit at L
(0.1 at least), and all of the mass at L gives 1. A blind audit's Crazyflie file with ten
times its mass (0.033) was fitted with K_T and Kd ten times the truth, the rates' residuals
50-60 times their noise, and no word on the airframe."""


def hub_reach(rotors: Sequence[Rotor]) -> float:
    """The hubs' mean horizontal distance from the centre of gravity, m (the arm when none is given)."""
    return float(np.mean([math.hypot(r.position[0], r.position[1]) for r in rotors]))


def _check_scale(mass: float, J: np.ndarray, rotors: Sequence[Rotor], source: str) -> None:
    """One error naming the likely unit when mass, inertia and the rotors' distance cannot
    belong to one vehicle (:data:`INERTIA_SCALE`)."""
    reach = hub_reach(rotors)
    if reach <= 0:
        return
    j3 = float(np.max(np.linalg.eigvalsh(J)))
    ratio = j3 / (mass * reach ** 2)
    lo, hi = INERTIA_SCALE
    if lo <= ratio <= hi:
        plo, phi = INERTIA_PLAUSIBLE
        if not plo <= ratio <= phi:
            _warnings.warn(
                f"{source}: airframe: the largest moment of inertia {j3:.4g} kg m^2 is {ratio:.2g} x mass x L^2 "
                f"(mass {mass:.4g} kg, rotors at L = {reach:.4g} m from the centre of gravity), where a multirotor's "
                f"lies near 0.15-0.55 ({plo:g}-{phi:g} at the extremes): is the "
                + ("mass right (weighed, in kg), or the inertia too small?" if ratio < plo else
                   "mass right (weighed, in kg), or the inertia too large?")
                + " K_T, b and the drag scale with the mass, the rates' response with the inertia",
                AirframeWarning, stacklevel=4)
        return
    guess = ("is the mass in grams, or the arm_length / rotor positions in cm or mm?" if ratio < lo else
             "is the inertia in g m^2 or kg cm^2, or the mass in tonnes?")
    raise GreyboxInputError(
        f"{source}: airframe: the largest moment of inertia {j3:.4g} kg m^2 is {ratio:.2g} x mass x L^2 "
        f"(mass {mass:.4g} kg, rotors at L = {reach:.4g} m from the centre of gravity), where a multirotor's lies "
        f"near 0.15-0.55 and never outside {lo:g}-{hi:g}: {guess} (units: kg, m, kg m^2)")


def airframe_from_dict(doc: Mapping[str, Any], source: str = "<airframe>") -> Airframe:
    """Build and validate an :class:`Airframe` from a parsed TOML document."""
    unknown_top = set(doc) - {"airframe", "rotor", "parameters"}
    if unknown_top:
        raise GreyboxInputError(f"{source}: unknown table(s) {sorted(unknown_top)}; "
                                "expected [airframe], [[rotor]], [parameters]")
    if "airframe" not in doc or not isinstance(doc["airframe"], dict):
        raise GreyboxInputError(f"{source}: missing [airframe] table")
    a = doc["airframe"]
    unknown = set(a) - _AIRFRAME_KEYS
    if unknown:
        raise GreyboxInputError(f"{source}: unknown key(s) in [airframe]: {sorted(unknown)}; "
                                f"allowed: {sorted(_AIRFRAME_KEYS)}")
    for key in ("mass", "inertia"):
        if key not in a:
            raise GreyboxInputError(f"{source}: [airframe] is missing '{key}'")
    mass = _number(a["mass"], f"{source}: airframe.mass")
    if mass <= 0:
        raise GreyboxInputError(f"{source}: airframe.mass must be positive, got {mass}")
    J = _inertia(a["inertia"], f"{source}: airframe.inertia")
    arm = _number(a.get("arm_length", 0.0), f"{source}: airframe.arm_length")
    g = _number(a.get("gravity", 9.81), f"{source}: airframe.gravity")
    if g <= 0:
        raise GreyboxInputError(f"{source}: airframe.gravity must be positive, got {g}")
    j_r = _number(a.get("rotor_inertia", 0.0), f"{source}: airframe.rotor_inertia")
    if j_r < 0:
        raise GreyboxInputError(f"{source}: airframe.rotor_inertia must be >= 0, got {j_r}")
    ground_z = _number(a.get("ground_z", 0.0), f"{source}: airframe.ground_z")
    name = a.get("name", Path(source).stem)
    if not isinstance(name, str):
        raise GreyboxInputError(f"{source}: airframe.name must be a string")

    layout = a.get("layout")
    rotor_tables = doc.get("rotor")
    if layout is not None and rotor_tables is not None:
        raise GreyboxInputError(f"{source}: give either airframe.layout or [[rotor]] tables, not both")
    if layout is not None:
        if not isinstance(layout, str):
            raise GreyboxInputError(f"{source}: airframe.layout must be a string")
        if arm <= 0:
            raise GreyboxInputError(f"{source}: airframe.arm_length must be positive for layout "
                                    f"{layout!r}, got {arm}")
        try:
            rotors = rotors_for_layout(layout, arm)
        except GreyboxInputError as e:
            raise GreyboxInputError(f"{source}: airframe.layout: {e}") from None
    elif rotor_tables is not None:
        if not isinstance(rotor_tables, list) or not rotor_tables:
            raise GreyboxInputError(f"{source}: [[rotor]] must be one or more tables")
        rotors = []
        for i, rt in enumerate(rotor_tables, start=1):
            where = f"{source}: rotor {i}"
            extra = set(rt) - _ROTOR_KEYS
            if extra:
                raise GreyboxInputError(f"{where}: unknown key(s) {sorted(extra)}; allowed: position, spin")
            if "position" not in rt or "spin" not in rt:
                raise GreyboxInputError(f"{where}: needs 'position' and 'spin'")
            pos = _vector(rt["position"], 3, f"{where} position")
            spin = rt["spin"]
            if spin not in (-1, 1) or isinstance(spin, bool):
                raise GreyboxInputError(f"{where}: spin must be +1 or -1, got {spin!r}")
            rotors.append(Rotor(tuple(pos), int(spin)))
        P = np.array([r.position for r in rotors], dtype=float)
        # hubs with no lever about an axis give the model no torque about it: every roll or
        # pitch prediction would be the vehicle's free motion (an audit's four rotors at
        # [0, 0, 0] linearised with zero B rows and no word)
        for axis, coord, what in ((1, "y", "roll"), (0, "x", "pitch")):
            if np.all(np.abs(P[:, axis]) < 1e-6):
                raise GreyboxInputError(f"{source}: [[rotor]] positions: every rotor is at {coord} = 0, so the "
                                        f"rotors give no {what} torque; positions are the hubs' in the body frame "
                                        "(FRD, m) from the centre of gravity")
        # one rotor written twice (a copy-paste): a blind audit's fitted without a word; a
        # coaxial pair shares a place but turns the other way
        for j in range(len(rotors)):
            for i in range(j):
                if rotors[i].spin == rotors[j].spin and np.allclose(P[i], P[j], atol=1e-3):
                    raise GreyboxInputError(
                        f"{source}: rotor {j + 1} has rotor {i + 1}'s position and spin: two rotors in one place "
                        "turning the same way are one rotor written twice (a coaxial pair turns opposite ways)")
        layout = "custom"   # an arm not given is the hubs' mean distance (Airframe.__post_init__)
    else:
        raise GreyboxInputError(f"{source}: give airframe.layout ('plus' or 'x') or [[rotor]] tables")

    _check_scale(mass, J, rotors, source)
    params = doc.get("parameters", {})
    if not isinstance(params, dict):
        raise GreyboxInputError(f"{source}: [parameters] must be a table")
    clean: dict[str, Any] = {}
    for k, v in params.items():
        if isinstance(v, list):
            clean[k] = [_number(x, f"{source}: parameters.{k}[{i}]") for i, x in enumerate(v)]
        else:
            clean[k] = _number(v, f"{source}: parameters.{k}")
    return Airframe(mass=mass, inertia=J, rotors=rotors, name=name, rotor_inertia=j_r, gravity=g,
                    ground_z=ground_z, arm_length=arm, layout=layout, parameters=clean, source=source)


def load_airframe(path: str | Path) -> Airframe:
    """Read and validate an airframe TOML file (README, "Airframe (TOML)").

    Errors name the file and the key (:class:`~greybox.errors.GreyboxInputError`); an inertia
    that breaks ``J1 + J2 >= J3`` within measurement error gives an
    :class:`~greybox.errors.AirframeWarning`.

    Example::

        from greybox import QuadrotorModel, load_airframe
        af = load_airframe("greybox/data/airframes/x_quad.toml")
        model = QuadrotorModel(af)
    """
    path = Path(path)
    text = read_text_file(path, "airframe")
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise GreyboxInputError(f"{path}: not valid TOML: {e}") from None
    return airframe_from_dict(doc, source=str(path))

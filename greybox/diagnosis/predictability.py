"""How the logged commands predict the attitude's near future before any model does: through a
torque they cause, or through the controller that wrote them (data only, no fit).

Per body axis, the attitude change over a horizon beyond the naive predictor's (constant body
rates), ``sum_k (omega[i+k] - omega[i]) dt``, is regressed on the same double integral of the
mixer's command ``u`` (the airframe's roll, pitch or yaw combination of the rotors' ``w^2``) in
two forms, fitted on the first half of each flight and scored on the second:

- the *plant form*: ``k u`` delayed by 0-0.1 s or through a 20-200 ms lag, and a trim per
  flight, the best of these: the form of every torque a rotor command causes;
- the *command change*: ``k (u[t-1] - u[t])`` and a trim: an angular acceleration that follows
  the command's change with the opposite sign, which no vehicle gives: it is the rate loop read
  backwards (the command moves as the measured rate does, ``u ~ -K omega``).

When the plant form predicts roll or pitch hardly better than the naive predictor (its error
above :data:`HARDLY_BETTER` of the naive one) and its gain is under :data:`HIDDEN_SHARE` of the
model's torque per command,
the commands' torque does not show in the attitude over that horizon: a torque the log does not
show, which the controller cancels as fast, hides it. Then a model of the vehicle whose torque is
the commands' has little to add to the naive attitude prediction at that horizon, whatever its
parameters. Seen on a 30 g vehicle of an independent simulator under a random torque (the plant
form 0.91-1.23 of the naive error with 0-10 % of the true torque per command; 0.04-0.10 with
93-100 % without the torque) and on all ten real Crazyflie flights of ``../shared/realdata``
(0.94-1.02 with 0-6 %), README "Real flights".
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.signal import lfilter

from ..data import FlightLog
from ..model import QuadrotorModel

__all__ = ["CommandPredictability", "command_predictability", "AXES", "ANGLE_OF_AXIS", "HARDLY_BETTER", "HIDDEN_SHARE",
           "CHANGE_BETTER"]

AXES = ("roll", "pitch", "yaw")
ANGLE_OF_AXIS = {"roll": "phi", "pitch": "theta", "yaw": "psi"}
HARDLY_BETTER = 0.75
"""The plant form predicts hardly better than the naive predictor when its held-out RMS error is
above this share of the naive one (0.91-1.23 under an unseen torque the controller cancels,
0.04-0.40 where the commands' torque shows, on the peer simulator's vehicles; 0.94-1.02 on the
real flights)."""
HIDDEN_SHARE = 0.25
"""The plant form's gain, as a share of the model's torque per command, under which the
commands' torque counts as hidden: a quarter, far from both the 0-10 % of closed loops under an
unseen torque and the 82-102 % where the torque shows (the peer simulator's 30 g, 1.2 kg and 3 kg
vehicles, calm or under a random torque their manoeuvres outweigh)."""
CHANGE_BETTER = 0.9
"""The command change is said to predict better when its error is below this share of the naive
one (0.59-0.91 on the real flights; 0.99-1.10 on the peer simulator, whose logged speeds are the
motors', behind their lag)."""
DELAYS = tuple(0.01 * k for k in range(11))     # s
LAG_TIMES = (0.02, 0.05, 0.1, 0.2)               # s
MIN_HELD_OUT = 2.0                               # s of held-out windows below which nothing is said


@dataclass
class CommandPredictability:
    """What :func:`command_predictability` found, per axis (``"roll"``, ``"pitch"``, ``"yaw"``)
    and horizon (lists in the order of ``horizons``). RMS errors in rad (the small-angle attitude
    change), on the held-out second halves.

    ``plant_gain``: for roll and pitch, the plant form's gain as a share of the model's torque
    per command (``K_T`` and the inertia); for yaw, the ``b/K_T`` (m) it implies.
    ``change_gain`` in the same units."""

    horizons: list[float]
    naive: dict[str, list[float]]
    plant: dict[str, list[float]]
    plant_gain: dict[str, list[float]]
    plant_timing: dict[str, list[str]]
    change: dict[str, list[float]]
    change_gain: dict[str, list[float]]
    seconds: float                       # held-out seconds the errors are taken over

    def _k(self, horizon: float) -> int | None:
        return next((k for k, h in enumerate(self.horizons) if abs(h - horizon) < 1e-9), None)

    def ratio(self, form: str, axis: str, horizon: float) -> float:
        """``form`` (``"plant"`` or ``"change"``)'s RMS error over the naive predictor's."""
        k = self._k(horizon)
        if k is None:
            raise ValueError(f"horizon {horizon} s was not computed ({self.horizons})")
        naive = self.naive[axis][k]
        return getattr(self, form)[axis][k] / naive if naive > 0 else float("nan")

    def torque_hidden(self, axis: str, horizon: float) -> bool:
        """Whether the commands' torque about ``axis`` (roll or pitch) does not show in the
        attitude over ``horizon``: the plant form predicts hardly better than naive
        (:data:`HARDLY_BETTER`) and its gain is under :data:`HIDDEN_SHARE` of the model's."""
        k = self._k(horizon)
        if axis == "yaw" or k is None:
            return False
        return bool(self.ratio("plant", axis, horizon) > HARDLY_BETTER and self.plant_gain[axis][k] < HIDDEN_SHARE)

    def hidden_axes(self, horizon: float) -> list[str]:
        return [a for a in AXES if self.torque_hidden(a, horizon)]

    def text(self, horizon: float, losing: Sequence[str] = ()) -> str:
        """A sentence on the axes whose torque is hidden at ``horizon`` ("" when none is);
        ``losing``: attitude channels on which the model's prediction loses to the naive one
        there, said to be why."""
        axes = self.hidden_axes(horizon)
        if not axes:
            return ""
        k = self._k(horizon)
        parts = [f"{a}: {self.ratio('plant', a, horizon):.2f} of the naive error with "
                 f"{int(round(100 * self.plant_gain[a][k]))} % of the model's torque per command" for a in axes]
        changes = [a for a in axes if self.ratio("change", a, horizon) < CHANGE_BETTER]
        said = (f"over {horizon:g} s the logged commands' torque does not show in the "
                f"{' and '.join(axes)}: a torque linear in them (any delay to 0.1 s or lag to 0.2 s, a trim; "
                f"fitted on the first half of each flight, scored on the second) predicts it hardly better than "
                f"the naive predictor ({'; '.join(parts)}). A torque the log does not show, which the controller "
                "cancels as fast, hides it")
        if changes:
            said += (f"; the commands' change predicts the {' and '.join(changes)} better ("
                     + ", ".join(f"{self.ratio('change', a, horizon):.2f}" for a in changes)
                     + " of the naive error) with the sign of the controller's answer, not of a torque: "
                     "information a model of the vehicle cannot use")
        chans = [c for c in losing if c in {ANGLE_OF_AXIS[a] for a in axes}]
        if chans:
            said += (f". So the model's {', '.join(chans)} prediction, driven by that torque, loses to the naive "
                     "one here, and a better fit of the same torque map is not expected to change that: the log does "
                     "not hold the torque the vehicle felt")
        return said + ("" if chans else ". A model of the vehicle has little to add to the naive attitude "
                       "prediction there")

    def as_dict(self) -> dict:
        return {"horizons": list(self.horizons), "seconds": self.seconds,
                "axes": {a: {"naive": self.naive[a], "plant": self.plant[a], "plant_gain": self.plant_gain[a],
                             "plant_timing": self.plant_timing[a], "change": self.change[a],
                             "change_gain": self.change_gain[a],
                             "torque_hidden": [self.torque_hidden(a, h) for h in self.horizons]}
                         for a in AXES}}


def _rates(log: FlightLog) -> np.ndarray | None:
    if not all(log.measures(c) for c in ("p", "q", "r")):
        return None          # no gyro (the contract's p, q, r are optional)
    om = np.column_stack([log.output(c) for c in ("p", "q", "r")])
    ok = np.isfinite(om).all(axis=1)
    if ok.sum() < max(10, 0.5 * len(log)):
        return None
    return np.column_stack([np.interp(log.t, log.t[ok], om[ok, i]) for i in range(3)])


def _shapes(u: np.ndarray, dt: float) -> list[np.ndarray]:
    """The command delayed by each of DELAYS, then through each first-order lag of LAG_TIMES."""
    out = [np.concatenate([np.full(d, u[0]), u[:len(u) - d]]) for d in (int(round(s / dt)) for s in DELAYS)]
    for T in LAG_TIMES:
        a = dt / (T + dt)
        out.append(lfilter([a], [1.0, a - 1.0], u, zi=[(1.0 - a) * u[0]])[0])
    return out


def command_predictability(model: QuadrotorModel, logs: FlightLog | Sequence[FlightLog], k_t: float | None = None,
                           horizons: Sequence[float] = (0.25, 0.5)) -> CommandPredictability | None:
    """Compare the plant form and the command change with the naive attitude predictor on
    ``logs`` (module doc). ``k_t``: the thrust coefficient the model's torque per command is
    taken with (default the model's starting value). None when the inputs are not rotor
    speeds, the log has no gyro, or fewer than :data:`MIN_HELD_OUT` seconds are held out."""
    if model.inputs != "rotor_speeds":
        return None
    af = model.airframe
    n_rot = af.n_rotors
    pos = af.rotor_positions
    mixer = np.vstack([-pos[:, 1], pos[:, 0], np.asarray(af.spins, float)])      # torque about +x, +y, +z per K_T w^2
    J = np.diag(np.asarray(af.inertia, float))
    if k_t is None:
        k_t = float(model.default_parameters()[model.param_names.index("K_T")])
    per_command = [k_t / J[0], k_t / J[1], k_t / J[2]]      # roll, pitch: the model's; yaw: per unit b/K_T
    logs = [logs] if isinstance(logs, FlightLog) else list(logs)
    n_shapes = len(DELAYS) + len(LAG_TIMES)
    # per horizon, per flight: first and second halves of (Y, plant shapes, change) per axis
    data: list[list[tuple]] = [[] for _ in horizons]
    held_out_seconds = 0.0
    for log in logs:
        om = _rates(log)
        if om is None:
            continue
        dt = float(np.median(np.diff(log.t)))
        u_all = (log.inputs[:, :n_rot] ** 2) @ mixer.T
        lead = int(round(max(DELAYS) / dt)) + 2
        for hk, h in enumerate(horizons):
            H = max(1, int(round(h / dt)))
            idx = np.arange(lead, len(log) - H)
            if len(idx) < 20:
                continue

            def window(x: np.ndarray) -> np.ndarray:
                """The double integral over each window beyond holding x at its start value."""
                c1 = np.cumsum(x, axis=0) * dt
                c2 = np.cumsum(c1, axis=0) * dt
                return c2[idx + H] - c2[idx] - H * dt * c1[idx]

            c_om = np.cumsum(om, axis=0) * dt
            Y = c_om[idx + H] - c_om[idx] - H * dt * om[idx]
            trim = window(np.ones(len(log)))
            feats = []
            for a in range(3):
                u = u_all[:, a]
                shapes = np.column_stack([window(s) for s in _shapes(u, dt)])
                change = window(np.concatenate([[0.0], u[:-1] - u[1:]]))
                feats.append((shapes, change))
            half = len(idx) // 2
            data[hk].append((half, Y, feats, trim))
            if hk == 0:
                held_out_seconds += (len(idx) - half) * dt
    if held_out_seconds < MIN_HELD_OUT:
        return None
    n_flights = max(len(d) for d in data)
    out = {name: {a: [] for a in AXES} for name in ("naive", "plant", "plant_gain", "plant_timing", "change", "change_gain")}
    labels = [f"{1000 * s:.0f} ms delay" for s in DELAYS] + [f"{1000 * T:.0f} ms lag" for T in LAG_TIMES]
    for hk in range(len(horizons)):
        rows = data[hk]
        for a, axis in enumerate(AXES):
            if not rows:
                for name, v in (("naive", np.nan), ("plant", np.nan), ("plant_gain", np.nan), ("plant_timing", ""),
                                ("change", np.nan), ("change_gain", np.nan)):
                    out[name][axis].append(v)
                continue
            def stacked(column_of) -> tuple[np.ndarray, np.ndarray]:
                """(first halves, second halves) of the columns ``column_of(feats)`` and a trim per flight."""
                blocks = []
                for f, (half, Y, feats, trim) in enumerate(rows):
                    X = np.column_stack([column_of(feats[a]), np.zeros((len(Y), n_flights))])
                    X[:, -n_flights + f] = trim
                    blocks.append((X[:half], X[half:]))
                return np.vstack([b[0] for b in blocks]), np.vstack([b[1] for b in blocks])

            y1 = np.concatenate([Y[:half, a] for half, Y, _, _ in rows])
            y2 = np.concatenate([Y[half:, a] for half, Y, _, _ in rows])
            naive = float(np.sqrt(np.mean(y2 ** 2)))

            def held_out(X1: np.ndarray, X2: np.ndarray) -> tuple[float, float]:
                scale = np.maximum(np.abs(X1).max(axis=0), 1e-300)
                coef, *_ = np.linalg.lstsq(X1 / scale, y1, rcond=None)
                coef = coef / scale
                return float(np.sqrt(np.mean((y2 - X2 @ coef) ** 2))), float(coef[0])

            plant = [held_out(*stacked(lambda fa, j=j: fa[0][:, j:j + 1])) for j in range(n_shapes)]
            j_best = int(np.argmin([p[0] for p in plant]))
            change = held_out(*stacked(lambda fa: fa[1][:, None]))
            unit = per_command[a]
            out["naive"][axis].append(naive)
            out["plant"][axis].append(plant[j_best][0])
            out["plant_gain"][axis].append(plant[j_best][1] / unit)
            out["plant_timing"][axis].append(labels[j_best])
            out["change"][axis].append(change[0])
            out["change_gain"][axis].append(change[1] / unit)
    return CommandPredictability(list(horizons), out["naive"], out["plant"], out["plant_gain"], out["plant_timing"],
                                 out["change"], out["change_gain"], held_out_seconds)

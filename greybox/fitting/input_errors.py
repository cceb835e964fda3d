"""Errors in the inputs: white noise on the logged inputs (an ESC's speed telemetry) as the fit
sees it. The model is fed the logged values, so their noise is a random force and torque at
every row that the states integrate: a process noise the data fix before any fit, from the
inputs' high-frequency content and the model's sensitivity to them.

* :func:`input_column_noise` — each steady input's white-noise level and share of its variance;
* :func:`state_steps` — the RMS change over one row that this noise gives each state;
* :func:`input_noise_process_scale` — the same over one shooting interval: the floor of a
  soft fit's process noise (:func:`greybox.fitting.fit`);
* :func:`output_input_noise` — the RMS this noise puts straight on each predicted channel
  (the accelerometer's, through the thrust): what the certificate's residual check allows;
* :func:`denoise_inputs` — the logged rotor speeds with the noise the vehicle does not follow
  taken out (a Wiener smoother), the model's best guess of what the rotors did.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import casadi as ca
import numpy as np

from ..data import FlightLog
from ..model import QuadrotorModel
from ..shooting import estimate_noise

__all__ = ["INPUT_NOISE_SHARE", "input_noise_sd", "mixer_directions", "wiener_smooth_along", "wiener_left_noise",
           "wiener_left_noise_along", "input_column_noise", "mixer_noise_shares", "combination_noise_words", "COMBINATION_NOISE_NOTABLE", "input_jacobian", "followed_share", "state_steps",
           "unfollowed_input_noise", "has_rates", "input_noise_process_scale", "ProcessNoiseFloor", "output_input_noise", "InputDenoising", "denoise_inputs",
           "wiener_smooth"]

INPUT_NOISE_SHARE = 0.01
"""Share of a logged input's variance that is white noise from which that noise counts: below
it, noise on an input biases a gain by less than that share (the regression-dilution bound),
which no parameter's error of interest is (the real NanoBench flights' PWM-derived speeds:
0.01-0.6 %; a hexacopter's 1 % ESC telemetry noise: 7-12 %)."""


def input_noise_sd(log: FlightLog, column: np.ndarray) -> float:
    """The white-noise standard deviation of one of ``log``'s input columns, from robust second
    differences of its fresh samples (:meth:`~greybox.data.FlightLog.fresh_input_rows`: a held
    or interpolated row has no noise of its own)."""
    return estimate_noise(np.asarray(column, dtype=float)[log.fresh_input_rows()])


def input_column_noise(model: QuadrotorModel, log: FlightLog) -> tuple[np.ndarray, float]:
    """Per steady input (:attr:`QuadrotorModel.steady_input_names`) of the prepared ``log``, its
    white-noise standard deviation (robust second differences of its fresh samples,
    :func:`input_noise_sd`; 0 where it cannot be told), and the largest share of an input's
    variance that this noise makes up (the combinations of the speeds that the mixer makes
    have their own: :func:`mixer_noise_shares`)."""
    names = model.steady_input_names
    sigma = np.zeros(len(names))
    share = 0.0
    for j, name in enumerate(names):
        if name not in log.input_names:
            continue
        col = log.inputs[:, log.input_names.index(name)]
        var = float(np.nanvar(col)) if np.any(np.isfinite(col)) else 0.0
        s = input_noise_sd(log, col) if var > 0 else float("nan")
        if np.isfinite(s) and var > 0:
            sigma[j] = s
            share = max(share, s * s / var)
    return sigma, share


def mixer_noise_shares(model: QuadrotorModel, log: FlightLog) -> np.ndarray | None:
    """Per combination of the prepared ``log``'s rotor speeds that the mixer makes (thrust,
    roll, pitch, yaw: :func:`mixer_directions`), the share of its variance that their white
    noise (:func:`input_column_noise`) makes up; None where the inputs are not every rotor's
    speed. The gains are read from these combinations: on a flight that barely turns, the
    roll, pitch or yaw combination is mostly noise while each speed's own variance, the
    thrust's, hides it (a blind audit's slow flight, ESC telemetry at 1.3 rad/s: 0.6 % of each
    speed's variance, 57 % of the roll combination's; k_M came out 0.874 ± 0.012 for 1)."""
    names = model.steady_input_names
    speeds = [f"w{i + 1}" for i in range(model.airframe.n_rotors)]
    if model.inputs == "controls" or not all(n in names and n in log.input_names for n in speeds):
        return None
    sigma = input_column_noise(model, log)[0][[names.index(n) for n in speeds]]
    U = log.inputs[:, [log.input_names.index(n) for n in speeds]]
    U = U[np.all(np.isfinite(U), axis=1)]
    if U.shape[0] < 3:
        return None
    d = mixer_directions(model.airframe.allocation_matrix())[:, :4]
    var = np.var(U @ d, axis=0)
    noise = (d ** 2).T @ sigma ** 2
    return np.where(var > 0, noise / np.where(var > 0, var, 1.0), 0.0)


def input_jacobian(model: QuadrotorModel, log: FlightLog, p: np.ndarray, rows: np.ndarray,
                   at: np.ndarray | None = None, states: Sequence[int] | None = None) -> np.ndarray:
    """The state derivatives' Jacobian w.r.t. the inputs at the prepared ``log``'s ``rows``
    (its inputs and times there), the states ``at`` (one per row; default the model's rest
    state) and parameters ``p``: ``(len(states), nu, len(rows))``, ``states`` the rows of the
    derivative kept (default all). One CasADi ``Function``, mapped over the rows."""
    keep = list(range(model.nx)) if states is None else list(states)
    rows = np.asarray(rows, dtype=int)
    if at is None:
        at = np.repeat(np.asarray(model.initial_state(), dtype=float).reshape(1, -1), rows.size, axis=0)
    return _input_sensitivity(model, model.rhs, keep, log, p, rows, at)


def _input_sensitivity(model: QuadrotorModel, f: ca.Function, keep: list[int], log: FlightLog, p: np.ndarray,
                       rows: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The Jacobian w.r.t. the inputs of the outputs ``keep`` of ``f(x, u, p, t)`` (the model's
    ``rhs`` or ``output``) at the ``log``'s ``rows``, the states ``at`` (one per row) and
    parameters ``p``: ``(len(keep), nu, len(rows))``. One CasADi ``Function``, mapped."""
    x, u = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu)
    pp, t = ca.SX.sym("p", model.n_params), ca.SX.sym("t")
    jac = ca.Function("input_sensitivity", [x, u, pp, t], [ca.jacobian(f(x, u, pp, t)[keep], u)])
    J = jac.map(rows.size)(np.asarray(at, dtype=float).T, log.inputs[rows].T,
                           np.repeat(np.asarray(p, dtype=float).reshape(-1, 1), rows.size, axis=1),
                           log.t[rows].reshape(1, -1))
    return np.asarray(J).reshape(len(keep), model.nu, rows.size, order="F")


def state_steps(model: QuadrotorModel, log: FlightLog, p: np.ndarray, sigma_steady: np.ndarray,
                rows: np.ndarray, states: np.ndarray | None = None) -> np.ndarray:
    """Per state, the RMS over ``rows`` of the change over one row that independent white noise
    ``sigma_steady`` on each steady input gives it: the state derivatives' sensitivity to every
    input column (a derived column, ``w3@next``, carries its own draw of rotor 3's noise),
    at the states ``states`` (one per row; default the model's rest state) and parameters
    ``p``, times the row's length. ``log`` is prepared (:meth:`QuadrotorModel.prepare_log`)."""
    rows = np.asarray(rows, dtype=int)
    J = input_jacobian(model, log, p, rows, states)
    sigma = model.steady_input_map() @ sigma_steady
    dt = np.diff(log.t)[np.minimum(rows, len(log) - 2)]
    per_row = np.sqrt(np.einsum("sck,c->sk", J ** 2, sigma ** 2)) * dt
    return np.sqrt(np.mean(per_row ** 2, axis=1))


def followed_share(model: QuadrotorModel, log: FlightLog, p: np.ndarray, max_rows: int = 4000) -> float | None:
    """How much of the logged inputs' row-to-row content the vehicle follows, from the gyro: the
    body rates' increments from one row to the next, less their neighbours' mean, regressed on
    what the model makes of the inputs' own such content (its rate derivatives' sensitivity to
    the inputs, at rest and ``p``, times each row's input less its neighbours' mean, times the
    row's length). 1: the fast content is what the rotors did (a 100 Hz controller's commands
    logged exactly); 0: it is noise on the log (telemetry), or commands the motors do not
    follow — to a model fed them, either is a random torque. None without a gyro at every row
    or with nothing to regress on. The slope is the followed share of the inputs' fast variance
    (regression dilution: var(true) / (var(true) + var(noise)))."""
    rates = [s for s in ("p", "q", "r") if s in log.output_names]
    if len(rates) == 0 or len(log) < 5:
        return None
    G = np.column_stack([log.output(s) for s in rates])
    rows = np.unique(np.linspace(1, len(log) - 3, min(max_rows, len(log) - 3)).astype(int))
    ok = np.all(np.isfinite(G[rows - 1]) & np.isfinite(G[rows]) & np.isfinite(G[rows + 1]) & np.isfinite(G[rows + 2]),
                axis=1)
    rows = rows[ok]
    if rows.size < 20:
        return None
    J = input_jacobian(model, log, p, rows, states=[model.state_names.index(s) for s in rates])
    U = log.inputs
    fast_u = U[rows] - 0.5 * (U[rows - 1] + U[rows + 1])
    dt = log.t[rows + 1] - log.t[rows]
    predicted = np.einsum("rck,kc->kr", J, fast_u) * dt[:, None]
    dg = np.diff(G, axis=0)                      # dg[k] = g[k+1] - g[k]
    measured = dg[rows] - 0.5 * (dg[rows - 1] + dg[rows + 1])
    den = float(np.sum(predicted ** 2))
    if not np.isfinite(den) or den <= 0:
        return None
    return float(np.sum(predicted * measured) / den)


def unfollowed_input_noise(model: QuadrotorModel, log: FlightLog, p: np.ndarray
                           ) -> tuple[np.ndarray, float, float | None]:
    """:func:`input_column_noise` of the prepared ``log`` less what the vehicle follows: the
    fast content the gyro follows (:func:`followed_share` at ``p``) is signal, not noise, and
    only the rest counts (all of it without a gyro to tell). Returns the per-input noise, its
    largest share of an input's variance, and the followed share (None where not told)."""
    sigma, share = input_column_noise(model, log)
    if share <= 0 or not has_rates(log):
        return sigma, share, None
    followed = followed_share(model, log, p)
    unfollowed = 0.0 if followed is None else float(np.clip(1.0 - followed, 0.0, 1.0))
    return sigma * math.sqrt(unfollowed), share * unfollowed, followed


COMBINATION_NOISE_NOTABLE = 0.25
"""Share of a mixer combination's variance (thrust, roll, pitch, yaw: :func:`mixer_noise_shares`)
that the speeds' white noise the vehicle does not follow makes up, from which the gains read
from that combination are said to be biased low (:func:`combination_noise_words`). The
errors-in-variables bound is the share itself; below a quarter, the checks on the whole
speeds (:data:`INPUT_NOISE_SHARE`) and the diagnosis's own (SIMEX) judge it."""

_COMBINATIONS = (("thrust", "K_T"), ("roll", "the roll and pitch moments per speed difference (a moment gain k_M)"),
                 ("pitch", "the roll and pitch moments per speed difference (a moment gain k_M)"), ("yaw", "b"))


def combination_noise_words(model: QuadrotorModel, log: FlightLog, p: np.ndarray | None = None) -> str:
    """Words for the prepared ``log`` when the white noise on its rotor speeds that the vehicle
    does not follow (:func:`followed_share` at ``p``, the model's starting values by default;
    all of it without a gyro) makes up :data:`COMBINATION_NOISE_NOTABLE` or more of the thrust,
    roll, pitch or yaw combination's variance (:func:`mixer_noise_shares`), or "". The gain
    read from such a combination comes out low by up to that share (errors in variables),
    beyond what its std says, and smoothing cannot take noise out of the band the small
    commands live in: a blind audit's hover and vertical flights (ESC telemetry at 1.3 rad/s;
    yaw combination 55 % noise) gave ``b`` 23-30 % low, 3-5 std, certified and silent, and its
    slow flight (roll 57 %) a moment gain of 0.874 ± 0.012 for 1, named as the verdict."""
    shares = mixer_noise_shares(model, log)
    if shares is None:
        return ""
    p = model.default_parameters() if p is None else np.asarray(p, dtype=float)
    followed = followed_share(model, log, p) if has_rates(log) else None
    unfollowed = 1.0 if followed is None else float(np.clip(1.0 - followed, 0.0, 1.0))
    noisy = [(name, gain, share * unfollowed) for (name, gain), share in zip(_COMBINATIONS, shares)
             if share * unfollowed >= COMBINATION_NOISE_NOTABLE]
    if not noisy:
        return ""
    which = ", ".join(f"{name} {100 * s:.0f} %" for name, _, s in noisy)
    gains = list(dict.fromkeys(gain for _, gain, _ in noisy))
    return (f"{log.source or 'log'}: white noise on the logged rotor speeds makes up much of the combinations of them "
            f"the mixer makes ({which} of their variance): the commands for those barely rise above it on this "
            f"flight, and {', '.join(gains)}, read from them, come{'s' if len(gains) == 1 else ''} out low by up "
            "to that share (errors in variables), beyond what the std say; smoothing cannot take out noise in the "
            "band of the commands themselves. A flight that manoeuvres more on those axes, or speeds logged with "
            "less noise, tell them")


@dataclass(frozen=True)
class ProcessNoiseFloor:
    """What white noise on the logged inputs gives a soft fit's process noise
    (:func:`input_noise_process_scale`).

    Attributes:
        scale: per flight (rows) and state (columns), the random walk over one shooting
            interval: no state's process noise goes below it.
        share: the largest share of a logged input's variance that the noise the vehicle does
            not follow makes up (:func:`unfollowed_input_noise`); from
            :data:`INPUT_NOISE_SHARE` on it also biases the gains that pass it on (a warning).
    """

    scale: np.ndarray
    share: float

    @property
    def notable(self) -> bool:
        """Whether the noise is large enough to bias the gains that pass it on."""
        return self.share >= INPUT_NOISE_SHARE


def input_noise_process_scale(model: QuadrotorModel, logs: Sequence[FlightLog], node_index: Sequence[np.ndarray],
                              X: np.ndarray, p: np.ndarray, interval: int) -> ProcessNoiseFloor | None:
    """Per flight (rows) and state (columns), the random walk over one shooting interval of
    ``interval`` rows that white noise on the logged inputs gives the states (:func:`state_steps`
    at the node states ``X``, stacked over the flights as ``node_index`` places them, and the
    parameters ``p``; independent draws per row), the noise the vehicle follows taken out
    (:func:`unfollowed_input_noise`). None when no logged input carries such noise.

    The floor of a soft fit's process noise, however small a share of the inputs' variance the
    noise is. Re-estimated from the gaps alone, a state's process noise falls below what the
    inputs' noise gives it (a smoother's gaps are smaller than the noise that made them, and
    shrink further with it), and the fit then trusts the dynamics more than the data allow:
    the gains that pass the noise on come out small (errors in variables; on the ninth
    audit's hexacopter, speed noise 7-12 % of the speeds' variance, vz's fell to 3.5e-7 m/s
    where the noise gives 9e-4, and the fit took drag 35 % low), and even where no gain moves,
    their standard deviations come out too small: on greybox's own 30-s flights with 1 rad/s
    on the speeds (0.23 % of their variance, a gyro logged) the roll and pitch rates' process
    noise fell to 0.0042 rad/s per interval where the noise gives 0.009, and over eight seeds
    K_T, b and the vertical drag were 2.3, 1.3 and 3.0 of their std from the truth (RMS);
    with the floor 0.9, 0.9 and 0.8. A log without a gyro counts all of its inputs' noise:
    nothing tells what the vehicle follows (a blind audit's 0.9 kg vehicle, speeds with
    0.5 % noise: with the gyro the roll rate's process noise came out 0.0075 rad/s per
    interval, what the noise gives, without it 0.00034, and the true model left y and theta
    at 1.6 and 1.4 times their noise)."""
    per_flight = [unfollowed_input_noise(model, log, p)[:2] for log in logs]
    if not any(np.any(sigma > 0) for sigma, _ in per_flight):
        return None
    out = np.zeros((len(logs), model.nx))
    k0 = 0
    for f, (log, idx) in enumerate(zip(logs, node_index)):
        nodes = X[k0:k0 + len(idx)]
        k0 += len(idx)
        pick = np.unique(np.linspace(0, len(idx) - 2, min(400, len(idx) - 1)).astype(int))
        steps = state_steps(model, log, p, per_flight[f][0], np.asarray(idx)[pick], nodes[pick])
        out[f] = steps * math.sqrt(max(interval, 1))
    if not np.any(out > 0):
        return None
    return ProcessNoiseFloor(out, max(share for _, share in per_flight))


def output_input_noise(model: QuadrotorModel, log: FlightLog, p: np.ndarray, states: np.ndarray,
                       rows: np.ndarray) -> np.ndarray:
    """Per output channel (``model.output_names``), the RMS over ``rows`` of the prediction's
    error that white noise on the prepared ``log``'s inputs gives it straight through the output
    map (an accelerometer's specific force through the thrust; zero for the pose and the rates,
    which the states carry), at the ``states`` (one per row) and parameters ``p``. The noise
    per input: what the vehicle does not follow (:func:`unfollowed_input_noise`), or, for an
    input smoothed since it was logged, what the smoother left of it
    (:attr:`~greybox.data.FlightLog.input_noise_left`: the noise in the band where the
    inputs' own signal stands above it, coloured), which the prediction keeps. Zeros where no
    input carries noise.

    A blind audit's 1.1 kg vehicle (5 rad/s on speeds of about 590 rad/s, the accelerometer
    with 0.05 m/s² of noise): as logged, the thrust's noise is 2 K_T w 5 sqrt(4) / m =
    0.084 m/s²; smoothed, the true model's az residuals still came out 1.5 times the
    accelerometer's noise, coloured, and the fit called az a channel the model does not
    explain."""
    sigma = unfollowed_input_noise(model, log, p)[0].copy()
    for j, name in enumerate(model.steady_input_names):
        if name in log.input_noise_left:
            sigma[j] = float(log.input_noise_left[name])
    ny = len(model.output_names)
    rows = np.asarray(rows, dtype=int)
    if not np.any(sigma > 0) or rows.size == 0:
        return np.zeros(ny)
    J = _input_sensitivity(model, model.output, list(range(ny)), log, p, rows, states)
    s2 = (model.steady_input_map() @ sigma) ** 2
    return np.sqrt(np.mean(np.einsum("ock,c->ok", J ** 2, s2), axis=1))


def has_rates(log: FlightLog) -> bool:
    """Whether ``log`` measures a body rate (a gyro): what tells the speeds' noise from what the
    vehicle follows (:func:`followed_share`); without it nothing is smoothed."""
    return any(log.measures(c) for c in ("p", "q", "r"))


MIN_DENOISE_ROWS = 64
"""Rows below which a log's inputs are not smoothed (no spectrum to tell signal from noise)."""


def wiener_smooth(column: np.ndarray, sigma: float) -> np.ndarray:
    """``column`` (uniformly sampled) with white noise of standard deviation ``sigma`` taken out:
    the zero-phase Wiener smoother ``H(f) = max(0, 1 - n sigma^2 / S(f))``, ``S`` the column's
    periodogram averaged over neighbouring frequencies (1/128 of the band), the ends mirrored
    so that the circular transform does not join them. Frequencies where the column's power is
    at the noise's go; where the signal stands well above it, it stays."""
    X, H, m, n = _wiener_gain(column, sigma)
    return np.fft.irfft(X * H, 2 * m + n)[m:m + n]


def wiener_left_noise(column: np.ndarray, sigma: float) -> float:
    """The standard deviation of the white noise ``sigma`` that :func:`wiener_smooth` leaves in
    ``column``: a Wiener smoother's error has at each frequency the noise's power times the
    gain there (``N S_s / S = N H``), so ``sigma sqrt(mean H)``: the noise in the band where the
    signal stands above it stays, coloured."""
    return float(sigma * math.sqrt(float(np.mean(_wiener_gain(column, sigma)[1]))))


def _wiener_gain(column: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray, int, int]:
    """:func:`wiener_smooth`'s transform of the mirrored column and its gain: ``(X, H, m, n)``,
    ``m`` rows mirrored at each end of the ``n``."""
    x = np.asarray(column, dtype=float)
    n = x.size
    m = min(n // 4, n - 2)
    ext = np.concatenate([x[m:0:-1], x, x[-2:-m - 2:-1]])
    X = np.fft.rfft(ext)
    power = np.abs(X) ** 2
    width = max(5, (X.size // 128) | 1)
    S = np.convolve(np.pad(power, width // 2, mode="edge"), np.ones(width) / width, mode="valid")
    H = np.clip(1.0 - ext.size * sigma ** 2 / np.maximum(S, np.finfo(float).tiny), 0.0, 1.0)
    H[0] = 1.0
    return X, H, m, n


def mixer_directions(allocation: np.ndarray) -> np.ndarray:
    """An orthonormal basis (n, n) of the n rotor speeds' space whose first directions follow
    the rows of ``allocation`` (4, n: thrust, roll, pitch and yaw per rotor,
    :meth:`greybox.airframe.Airframe.allocation_matrix`), each made orthogonal to those before
    it, the rest completing the basis (a hexacopter's two directions that move no force)."""
    a = np.asarray(allocation, dtype=float).T
    q, _ = np.linalg.qr(np.hstack([a, np.eye(a.shape[0])]))
    return q[:, :a.shape[0]]


def wiener_smooth_along(columns: np.ndarray, sigma: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """``columns`` (rows, n) with independent white noise of standard deviations ``sigma`` (n,)
    taken out along the orthonormal ``directions`` (n, n) (:func:`wiener_smooth` on each
    projection, its noise ``sqrt(sum_j d_jk^2 sigma_j^2)``). Each direction keeps what stands
    above the noise in its own spectrum: the yaw command of a flight without yaw manoeuvres is
    small beside the thrust and attitude commands, and a smoother per speed, which sees them
    all, leaves most of the noise in it (peer 30 g vehicle, 1 % speed noise: b 3.8 % and 6.4 % low
    on 12-s flights smoothed per speed, 2.2 % and 4.8 % along the mixer's directions)."""
    x = np.asarray(columns, dtype=float)
    d = np.asarray(directions, dtype=float)
    mean = x.mean(axis=0)
    proj = (x - mean) @ d
    noise = np.sqrt((d ** 2).T @ np.asarray(sigma, dtype=float) ** 2)
    smooth = np.column_stack([wiener_smooth(proj[:, k], noise[k]) for k in range(d.shape[1])])
    return mean + smooth @ d.T


def wiener_left_noise_along(columns: np.ndarray, sigma: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Per column, the standard deviation of the noise :func:`wiener_smooth_along` leaves in
    ``columns`` (:func:`wiener_left_noise` along each direction, back onto the columns)."""
    x = np.asarray(columns, dtype=float)
    d = np.asarray(directions, dtype=float)
    proj = (x - x.mean(axis=0)) @ d
    noise = np.sqrt((d ** 2).T @ np.asarray(sigma, dtype=float) ** 2)
    left = np.array([wiener_left_noise(proj[:, k], noise[k]) for k in range(d.shape[1])])
    return np.sqrt((d ** 2) @ left ** 2)


@dataclass(frozen=True)
class InputDenoising:
    """What :func:`denoise_inputs` took out of one log's rotor speeds.

    Attributes:
        source: the log's file, if any.
        noise: per smoothed input column, the white noise's standard deviation before.
        share: the largest share of an input's variance that noise made up.
        followed: the share of the inputs' row-to-row content the gyro follows
            (:func:`followed_share`); what it follows was kept out of ``noise``.
        left: per column, the white noise's standard deviation left after.
    """

    source: str | None
    noise: dict[str, float]
    share: float
    followed: float
    left: dict[str, float]

    def note(self) -> str:
        """One line for the user: what was taken out, and why."""
        cols = ", ".join(f"{n} ± {s:.3g}" for n, s in self.noise.items())
        return (f"{self.source or 'log'}: the logged rotor speeds carry white noise the vehicle does not follow "
                f"({cols}; up to {100 * self.share:.1f} % of a speed's variance; the gyro follows "
                f"{100 * max(self.followed, 0.0):.0f} % of their row-to-row changes): the model is fed them smoothed "
                "(a Wiener smoother), since noise fed to a model shrinks the gains that pass it on (errors "
                "in variables); --input-noise keep fits them as logged, as it should when they are a "
                "controller's commands logged exactly: behind motors slower than the rows the gyro follows "
                "little of a command's row-to-row changes, and they look like noise here")


def denoise_inputs(model: QuadrotorModel, log: FlightLog, p: np.ndarray | None = None
                   ) -> tuple[FlightLog, InputDenoising | None]:
    """``log`` with the white noise on its logged commands (rotor speeds) that the vehicle does
    not follow taken out (:func:`wiener_smooth`; all rotor speeds together along the mixer's
    directions, :func:`wiener_smooth_along`), and what was taken out; ``log`` itself and None
    where there is nothing to take out.

    Fed to the model, an input's noise is a random force and torque at every row; a fit then
    shrinks the gains that pass it on (b 5 % low on a 30 g vehicle's 20-s flight with 1 % speed
    noise, from 1.6e-10 to 1.51e-10; smoothed 1.578e-10). It acts only where the noise is
    :data:`INPUT_NOISE_SHARE` of a speed's variance or more *after* the part the gyro follows is
    taken out (:func:`followed_share` at ``p``, default the model's starting values): a
    controller's fast commands logged exactly are what the rotors did and stay — unless motors
    slower than the rows filter them (at the rows' scale a lag is a smaller gain, and the gyro
    follows little: an audit's 30-ms motors at 200 Hz, 1 %). Without a gyro
    nothing tells them apart, and nothing is smoothed.

    Example::

        from greybox import QuadrotorModel, denoise_inputs, fit, load_airframe, load_log
        model = QuadrotorModel(load_airframe("hexa.toml"))
        log, info = denoise_inputs(model, load_log("flight.csv"))   # what greybox fit reads
        if info is not None:
            print(info.note())        # the noise taken out per rotor, and why
        res = fit(model, log.split(0.8)[0])
    """
    if len(log) < MIN_DENOISE_ROWS:
        return log, None
    p = model.default_parameters() if p is None else np.asarray(p, dtype=float)
    sigma, share, followed = unfollowed_input_noise(model, model.prepare_log(log), p)
    if followed is None or share < INPUT_NOISE_SHARE:
        return log, None
    inputs = log.inputs.copy()
    noise, left = {}, {}
    steady = model.steady_input_names
    for name in model.command_names:
        if name not in log.input_names or name not in steady or sigma[steady.index(name)] <= 0:
            continue
        noise[name] = float(sigma[steady.index(name)])
    if not noise:
        return log, None
    cols = [log.input_names.index(name) for name in noise]
    speeds = [f"w{i + 1}" for i in range(model.airframe.n_rotors)]
    if model.inputs != "controls" and list(noise) == speeds:
        # every rotor's speed: along the mixer's directions, each with its own signal
        sig, directions = np.array(list(noise.values())), mixer_directions(model.airframe.allocation_matrix())
        kept = wiener_left_noise_along(inputs[:, cols], sig, directions)
        inputs[:, cols] = wiener_smooth_along(inputs[:, cols], sig, directions)
    else:
        kept = np.array([wiener_left_noise(inputs[:, j], s) for j, s in zip(cols, noise.values())])
        for j, s in zip(cols, noise.values()):
            inputs[:, j] = wiener_smooth(inputs[:, j], s)
    for name, j in zip(noise, cols):
        left[name] = float(input_noise_sd(log, inputs[:, j]))
    done = InputDenoising(log.source, noise, share, followed, left)
    # what the smoothed speeds still carry (in their signal's band, coloured): the model's
    # predictions keep it, and the certificate's residual check allows for it
    still = {**log.input_noise_left, **{name: float(v) for name, v in zip(noise, kept)}}
    return replace(log, inputs=inputs, notes=list(log.notes) + [done.note()], input_noise_left=still), done

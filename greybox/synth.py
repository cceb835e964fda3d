"""Synthetic flights: closed-loop simulations of a model with hidden effects, sensor noise,
multi-rate sampling and dropouts — data with a known truth for tests and studies.

The flight is flown by the generator's own stabilising controller (a cascaded position →
attitude controller with integral action, written symbolically and mapped over the whole
flight with ``mapaccum``). The controller only knows the *nominal* airframe (the
``[parameters]`` guesses), never the hidden effects, just as a real autopilot. Rotor-speed
excitation (a seeded multisine per rotor) is added on top of its commands so that the data
are informative.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import casadi as ca
import numpy as np
from scipy.signal import lfilter

from . import effects as fx
from .data import FlightLog
from .errors import GreyboxInputError, SolverError
from .integrate import n_substeps, rk4_step
from .model import OUTPUTS, QuadrotorModel

__all__ = ["SensorSpec", "MANOEUVRES", "DEFAULT_MANOEUVRES", "reference_trajectory", "synthesize", "SynthResult",
           "model_with_hidden_effects"]

MANOEUVRES = ("hover", "step_x", "step_y", "step_z", "yaw", "fast", "ground", "sprint")
"""Manoeuvre names understood by :func:`reference_trajectory`."""
DEFAULT_MANOEUVRES = MANOEUVRES[:-1]
"""What a flight cycles through unless told: an indoor flight (every manoeuvre but ``sprint``)."""


@dataclass
class SensorSpec:
    """Sensor rates and noise (standard deviations, SI units)."""

    rate: float = 1000.0            # Hz, base rate of the log (IMU and rotor speeds)
    vision_rate: float = 60.0       # Hz, position measurements
    pos_noise: float = 0.003        # m
    att_noise: float = 0.003        # rad
    gyro_noise: float = 0.005       # rad/s; <= 0 leaves p, q, r out of the log
    accel_noise: float = 0.0        # m/s^2; <= 0 leaves the accelerometer (ax, ay, az) out
    input_noise: float = 0.0        # rad/s, on the logged rotor speeds
    dropout: float = 0.05           # probability a vision frame is missing
    burst_dropouts: float = 1.0     # expected vision outages (0.1-0.4 s) per 10 s
    noise_correlation: float = 0.0  # s; > 0: every sensor's noise is AR(1), correlated over
                                    # this time with the same RMS (a filtered vision or IMU)


def _coloured(w: np.ndarray, tau: float, t: np.ndarray) -> np.ndarray:
    """White unit noise ``w`` (n, k) on the uniform times ``t`` made AR(1), correlated as
    exp(-dt / tau), with unit variance from the first sample on; unchanged for ``tau <= 0``."""
    if tau <= 0 or len(t) < 2:
        return w
    rho = math.exp(-float(t[1] - t[0]) / tau)
    b = math.sqrt(1.0 - rho ** 2)
    return lfilter([b], [1.0, -rho], w, axis=0, zi=((1.0 - b) * w[:1]))[0]


def _min_jerk(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s ** 3 * (10 - 15 * s + 6 * s ** 2)


def reference_trajectory(t: np.ndarray, manoeuvres: Sequence[str], rng: np.random.Generator,
                         altitude: float = 1.0, ground_z: float = 0.0,
                         step: float = 1.0) -> np.ndarray:
    """Reference ``[x, y, z, psi]`` (NED) on times ``t``: manoeuvres drawn in turn until the
    flight is filled, joined by minimum-jerk transitions.

    ``hover`` holds; ``step_x/y/z`` move ``step`` m (z: up/down); ``yaw`` turns ±60°;
    ``fast`` crosses 3 m at up to ~3 m/s and back; ``sprint`` crosses 6 m diagonally at up to
    ~6 m/s and back (outdoor speeds, where drag stops being linear in speed); ``ground`` descends to 0.15 m above the
    ground, moves 1 m sideways low, and climbs back.
    """
    for m in manoeuvres:
        if m not in MANOEUVRES:
            raise GreyboxInputError(f"unknown manoeuvre {m!r}; known: {', '.join(MANOEUVRES)}")
    if not manoeuvres:
        raise GreyboxInputError("at least one manoeuvre is needed")
    z_home = ground_z - altitude
    cur = np.array([0.0, 0.0, z_home, 0.0])
    segs: list[tuple[float, float, np.ndarray, np.ndarray]] = []  # (t0, dur, from, to)
    tt = float(t[0]) + 1.0  # one second of hover first
    k = 0
    t_end = float(t[-1])
    while tt < t_end:
        m = manoeuvres[k % len(manoeuvres)] if k < len(manoeuvres) else manoeuvres[rng.integers(len(manoeuvres))]
        k += 1
        sign = 1.0 if rng.random() < 0.5 else -1.0
        moves: list[tuple[np.ndarray, float, float]] = []  # (target, transition, hold)
        if m == "hover":
            moves.append((cur.copy(), 0.1, 2.0))
        elif m in ("step_x", "step_y"):
            tgt = cur.copy()
            i = 0 if m == "step_x" else 1
            tgt[i] = sign * step if abs(cur[i]) < 0.5 * step else 0.0
            moves.append((tgt, 0.8, 3.0))
        elif m == "step_z":
            tgt = cur.copy()
            tgt[2] = z_home - 0.5 * step if abs(cur[2] - z_home) < 0.1 else z_home
            moves.append((tgt, 0.8, 3.0))
        elif m == "yaw":
            tgt = cur.copy()
            tgt[3] = sign * math.radians(60) if abs(cur[3]) < 0.1 else 0.0
            moves.append((tgt, 1.0, 2.5))
        elif m == "fast":
            a, b = cur.copy(), cur.copy()
            axis = rng.integers(2)
            a[axis] = cur[axis] + sign * 1.5
            b[axis] = cur[axis] - sign * 1.5
            moves += [(a, 1.0, 0.3), (b, 1.6, 0.3), (cur.copy(), 1.0, 1.0)]
        elif m == "sprint":  # "fast" at twice the distance in about the same time, diagonally
            a, b = cur.copy(), cur.copy()
            d = np.array([sign, 1.0 if rng.random() < 0.5 else -1.0]) * 3.0 / math.sqrt(2.0)
            a[:2] = cur[:2] + d
            b[:2] = cur[:2] - d
            moves += [(a, 1.5, 0.3), (b, 1.8, 0.3), (cur.copy(), 1.5, 1.0)]
        elif m == "ground":
            low = cur.copy()
            low[2] = ground_z - 0.15
            side = low.copy()
            side[1 - int(rng.integers(2))] += sign * 1.0
            back = cur.copy()
            moves += [(low, 2.0, 1.0), (side, 2.5, 1.0), (low, 2.5, 0.5), (back, 2.0, 1.0)]
        for tgt, trans, hold in moves:
            # no faster than ~0.7 m/s vertically, so descents near the ground stay safe
            trans = max(trans, 1.9 * abs(tgt[2] - cur[2]) / 0.7)
            segs.append((tt, trans, cur.copy(), tgt.copy()))
            cur = tgt
            tt += trans + hold
    ref = np.tile(np.array([0.0, 0.0, z_home, 0.0]), (t.size, 1))
    for t0, dur, a, b in segs:
        s = _min_jerk((t - t0) / dur)
        active = t >= t0
        ref[active] = a + (b - a) * s[active, None]
    return ref


def _multisine(t: np.ndarray, n: int, rng: np.random.Generator, amplitude: float,
               f_lo: float = 0.3, f_hi: float = 12.0, n_freq: int = 12) -> np.ndarray:
    """Per-rotor zero-mean multisines with random phases, RMS ``amplitude``."""
    freqs = np.geomspace(f_lo, f_hi, n_freq)
    out = np.zeros((t.size, n))
    for i in range(n):
        ph = rng.uniform(0, 2 * np.pi, n_freq)
        sig = np.sin(2 * np.pi * freqs[None, :] * t[:, None] + ph[None, :]).sum(axis=1)
        out[:, i] = amplitude * sig / max(np.std(sig), 1e-12)
    return out


def _controller(model: QuadrotorModel, kt: float, b: float) -> tuple[ca.Function, int]:
    """Symbolic cascaded controller: ``(x, integ, ref, ref_dot, ref_acc) -> (w, integ_dot)``."""
    af = model.airframe
    m, g = af.mass, af.gravity
    J = np.diag(af.inertia)
    x = ca.SX.sym("x", model.nx)
    integ = ca.SX.sym("integ", 3)
    ref = ca.SX.sym("ref", 4)
    ref_dot = ca.SX.sym("ref_dot", 4)
    ref_acc = ca.SX.sym("ref_acc", 3)
    pos, v = x[0:3], x[6:9]
    phi, theta, psi = x[3], x[4], x[5]
    om = x[9:12]
    wp, zp = 2.2, 0.9  # position loop bandwidth (rad/s) and damping
    wa, za = 22.0, 0.8  # attitude loop
    ki = 0.6
    e = ref[0:3] - pos
    a_des = ref_acc + wp ** 2 * e + 2 * zp * wp * (ref_dot[0:3] - v) + ki * integ
    # NED: thrust must supply m*(a_des - g e_z); tilt limited to 0.5 rad
    fz = ca.fmax(g - a_des[2], 0.3 * g)
    a_fwd = a_des[0] * ca.cos(psi) + a_des[1] * ca.sin(psi)
    a_right = -a_des[0] * ca.sin(psi) + a_des[1] * ca.cos(psi)
    lim = 0.5
    theta_d = lim * ca.tanh(ca.atan2(-a_fwd, fz) / lim)
    phi_d = lim * ca.tanh(ca.atan2(a_right * ca.cos(theta_d), fz) / lim)
    T = m * fz / (ca.cos(phi) * ca.cos(theta))
    e_psi = ca.atan2(ca.sin(ref[3] - psi), ca.cos(ref[3] - psi))
    e_att = ca.vertcat(phi_d - phi, theta_d - theta, e_psi)
    rate_ff = ca.vertcat(0, 0, ref_dot[3])
    tau = ca.DM(J) * (wa ** 2 * e_att + 2 * za * wa * (rate_ff - om))
    tau[2] = tau[2] / 4  # slower yaw loop: yaw authority is small
    alloc = np.diag([kt, kt, kt, b]) @ af.allocation_matrix()
    wsq = ca.DM(np.linalg.pinv(alloc)) @ ca.vertcat(T, tau)
    w_hover = math.sqrt(m * g / (af.n_rotors * kt))
    w = ca.sqrt(ca.fmin(ca.fmax(wsq, (0.2 * w_hover) ** 2), (1.7 * w_hover) ** 2))
    integ_dot = ca.fmin(ca.fmax(e, -1.0), 1.0)  # clipped error: anti-windup
    return ca.Function("controller", [x, integ, ref, ref_dot, ref_acc], [w, integ_dot]), af.n_rotors


@dataclass
class SynthResult:
    """A synthetic flight: the noisy log and the truth behind it."""

    log: FlightLog
    model: QuadrotorModel
    parameters: np.ndarray                 # true flat parameter vector
    states: np.ndarray                     # (n, nx) true states
    outputs_true: np.ndarray               # (n, 12) noise-free outputs (OUTPUTS order)
    reference: np.ndarray                  # (n, 4) x, y, z, psi reference
    seed: int
    sensors: SensorSpec
    info: dict = field(default_factory=dict)

    def truth(self) -> dict:
        """JSON-ready description of what generated the log."""
        return {"effects": self.model.effect_names,
                "parameters": self.model.parameter_dict(self.parameters),
                "seed": self.seed, "sensors": self.sensors.__dict__, **self.info}


def model_with_hidden_effects(base: QuadrotorModel, hidden: Iterable[str],
                              values: Mapping[str, object] | None = None) -> tuple[QuadrotorModel, np.ndarray]:
    """``base`` plus the ``hidden`` effects, and a true parameter vector in which each added
    effect has its :func:`~greybox.effects.example_values` magnitude unless ``values`` sets it."""
    model = base
    for name in hidden:
        if name not in model.effects:
            model = model + fx.by_name(name)
    p = model.default_parameters()
    kt = p[model.param_names.index("K_T")]
    ex: dict[str, object] = {}
    for name in hidden:
        ex.update(fx.example_values(name, model.airframe, kt))
    p = model.parameter_vector(ex, p)
    p = model.parameter_vector(values or {}, p)
    return model, p


def synthesize(model: QuadrotorModel, parameters: np.ndarray | None = None, duration: float = 50.0,
               sensors: SensorSpec | None = None, manoeuvres: Sequence[str] = DEFAULT_MANOEUVRES,
               seed: int = 0, excitation: float = 0.03, altitude: float = 1.0,
               noise_seed: int | None = None) -> SynthResult:
    """Fly ``model`` (with true ``parameters``) closed loop and log it with sensor noise.

    Args:
        model: the true model (hidden effects included).
        parameters: true flat parameter vector (default: the model's defaults).
        duration: seconds of flight.
        sensors: rates and noise levels.
        manoeuvres: the manoeuvres to cycle through (see :data:`MANOEUVRES`; default
            :data:`DEFAULT_MANOEUVRES`, every one but ``sprint``).
        seed: seeds every random choice (manoeuvre order, excitation, noise, dropouts).
        noise_seed: if given, sensor noise and dropouts come from this seed instead, so that
            several noise realisations of the same flight can be drawn.
        excitation: RMS of the relative rotor-speed excitation added to the commands.
        altitude: hover height above the ground plane, m.
    """
    if model.inputs != "rotor_speeds":
        raise GreyboxInputError("synthesize needs a model with rotor-speed inputs")
    sensors = sensors or SensorSpec()
    if duration <= 0 or sensors.rate <= 0:
        raise GreyboxInputError("duration and rate must be positive")
    if sensors.vision_rate <= 0 or sensors.vision_rate > sensors.rate:
        raise GreyboxInputError(f"vision rate must be in (0, {sensors.rate}] Hz")
    rng = np.random.default_rng(seed)
    af = model.airframe
    p = model.default_parameters() if parameters is None else np.asarray(parameters, float)
    nominal = QuadrotorModel(af).default_parameters()  # what the autopilot believes
    kt_nom = nominal[0]
    b_nom = float(np.atleast_1d(af.parameters.get("b", 5e-7))[0])
    dt = 1.0 / sensors.rate
    n = int(round(duration * sensors.rate)) + 1
    t = np.arange(n) * dt
    ref = reference_trajectory(t, list(manoeuvres), rng, altitude, af.ground_z)
    ref_dot = np.gradient(ref, dt, axis=0)
    ref_acc = np.gradient(ref_dot[:, :3], dt, axis=0)
    exc = _multisine(t, af.n_rotors, rng, excitation)

    ctrl, nr = _controller(model, kt_nom, b_nom)
    step = rk4_step(model, n_substeps(dt))
    # closed-loop step: controller then one integration step, accumulated over the flight
    xa = ca.MX.sym("xa", model.nx + 3)
    r_k, rd_k, ra_k, e_k = ca.MX.sym("r", 4), ca.MX.sym("rd", 4), ca.MX.sym("ra", 3), ca.MX.sym("e", nr)
    pk, tk = ca.MX.sym("p", model.n_params), ca.MX.sym("t")
    xs, ig = xa[:model.nx], xa[model.nx:]
    w_cmd, ig_dot = ctrl(xs, ig, r_k, rd_k, ra_k)
    w = w_cmd * (1 + e_k)
    x_next = step(xs, w, pk, tk, dt)
    cl = ca.Function("closed_loop", [xa, r_k, rd_k, ra_k, e_k, pk, tk], [ca.vertcat(x_next, ig + dt * ig_dot), w])
    w_h = model.hover_speed(p)
    x0 = model.initial_state([0, 0, af.ground_z - altitude] + [0] * 9, [w_h] * nr, p)
    xa0 = np.concatenate([x0, np.zeros(3)])
    run = cl.mapaccum("flight", n)
    Xa, W = run(xa0, ref.T, ref_dot.T, ref_acc.T, exc.T, np.tile(p[:, None], (1, n)), t[None, :])
    Xa, W = np.asarray(Xa).T, np.asarray(W).T
    X = np.vstack([x0, Xa[:-1, :model.nx]])
    if not np.all(np.isfinite(X)):
        raise SolverError("synthetic flight diverged: the generator's controller could not fly "
                          "this model (check mass, inertia and K_T)")
    if np.any(X[:, 2] > af.ground_z + 0.01):
        raise SolverError("synthetic flight hit the ground; use a larger altitude")
    Y = np.asarray(model.output.map(n)(X.T, W.T, np.tile(p[:, None], (1, n)), t[None, :])).T

    # sensors
    if noise_seed is not None:
        rng = np.random.default_rng([seed, noise_seed])
    Ymeas = Y.copy()
    Ymeas[:, 0:3] += sensors.pos_noise * _coloured(rng.standard_normal((n, 3)), sensors.noise_correlation, t)
    Ymeas[:, 3:6] += sensors.att_noise * _coloured(rng.standard_normal((n, 3)), sensors.noise_correlation, t)
    Ymeas[:, 6:9] += max(sensors.gyro_noise, 0) * _coloured(rng.standard_normal((n, 3)), sensors.noise_correlation, t)
    every = max(1, int(round(sensors.rate / sensors.vision_rate)))
    vis = np.zeros(n, dtype=bool)
    vis[::every] = True
    vis &= rng.random(n) >= sensors.dropout
    n_burst = rng.poisson(sensors.burst_dropouts * duration / 10.0)
    for _ in range(n_burst):
        t0 = rng.uniform(0, duration)
        vis &= ~((t >= t0) & (t < t0 + rng.uniform(0.1, 0.4)))
    vis[0] = True
    Ymeas[~vis, 0:3] = np.nan
    keep = list(range(6))
    if sensors.gyro_noise > 0:
        keep += [6, 7, 8]
    if sensors.accel_noise > 0:
        # drawn last, so that flights without an accelerometer stay what they were
        Ymeas[:, 9:12] += sensors.accel_noise * _coloured(rng.standard_normal((n, 3)), sensors.noise_correlation, t)
        keep += [9, 10, 11]
    Ymeas, out_names = Ymeas[:, keep], [OUTPUTS[c] for c in keep]
    W_log = W + sensors.input_noise * rng.standard_normal(W.shape) if sensors.input_noise > 0 else W
    log = FlightLog(t, W_log, model.input_names, Ymeas, out_names, source="synthetic")
    info = {"duration": duration, "manoeuvres": list(manoeuvres), "excitation": excitation,
            "vision_samples": int(vis.sum())}
    return SynthResult(log, model, p, X, Y, ref, seed, sensors, info)

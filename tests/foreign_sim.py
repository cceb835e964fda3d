"""A quadrotor flight simulator written independently of greybox's model and simulator.

It exists to test greybox's fit and diagnosis on data greybox did not generate: its own
rigid-body dynamics (numpy, rotation matrices, ``scipy.integrate.solve_ivp``), its own
motor model, its own cascaded controller, its own sensors, and its own functional forms
for the physical effects. Only CONTRACT.md §1-3 (frames, rotor conventions, log columns,
airframe schema) is shared with greybox. From greybox it uses nothing but
``greybox.data.FlightLog`` (the container of the result) and, in :meth:`ForeignFlight.save`,
``greybox.data.save_log``.

Physics (all in SI units, world NED, body FRD, origin of the body frame at the centre of
gravity):

* state: position ``p`` (world), velocity ``v`` (world), rotation matrix ``R`` (body to
  world, ``dR/dt = R hat(omega)``), body rates ``omega``, actual rotor speeds ``w``;
* rotor ``i`` at hub ``r_i`` (contract layout, minus the CoG offset, plus a hub height
  ``hub_z``: the rotor plane sits above the CoG) gives thrust ``g_i K_T w_i^2 f_i`` along body
  ``-z`` (``g_i`` motor gain, ``f_i`` ground-effect factor) and a reaction torque
  ``spin_i b w_i^2`` about body ``+z``;
* rotor angular momentum ``h = -J_r sum(spin_i w_i) e_z``; the body equation is
  ``J domega/dt = tau - omega x (J omega + h)`` (optionally ``- dh/dt``, the reaction of
  spinning rotors up and down, ``rotor_accel_torque``);
* motors: ``dw/dt = (w_cmd - w) / tau_motor`` with ``w_cmd`` held between control updates.
  The LOGGED rotor speeds are the actual ``w`` at the sample times (an ESC RPM log).

Use::

    from foreign_sim import crazyflie, simulate_flight, airframe_dict
    fl = simulate_flight(crazyflie(), duration=20.0, seed=1)
    fl.log            # greybox FlightLog, w1..w4, x..psi (+ p, q, r)
    fl.truth          # true parameters and the true airframe dict
    airframe_dict(crazyflie(), K_T_guess_factor=1.3)   # a starting airframe for greybox

``python tests/foreign_sim.py --vehicle crazyflie --duration 20 --out DIR`` writes
``DIR/flight.csv``, ``DIR/airframe_true.toml`` and ``DIR/truth.json``.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.integrate import solve_ivp

__all__ = ["Vehicle", "crazyflie", "one_kg", "Effects", "Sensors", "Move", "Dynamics",
           "Reference", "Controller", "default_manoeuvres", "simulate_flight",
           "simulate_open_loop", "airframe_dict", "ForeignFlight", "rot_zyx", "euler_zyx"]

E3 = np.array([0.0, 0.0, 1.0])


# ============================================================================ vehicles
@dataclass
class Vehicle:
    """True physical parameters of the simulated vehicle (and its default sensors)."""

    name: str
    mass: float                       # kg
    inertia: tuple[float, float, float]   # Jx, Jy, Jz about the CoG, kg m^2
    arm_length: float                 # m (contract: x layout uses a = l/sqrt(2))
    layout: str                       # "plus" or "x"
    K_T: float                        # N/(rad/s)^2
    b: float                          # N m/(rad/s)^2
    rotor_inertia: float = 0.0        # J_r, kg m^2
    rotor_radius: float = 0.05        # m (ground effect)
    hub_z: float = 0.0                # body z of the rotor hubs (negative: above the CoG), m
    tau_motor: float = 0.03           # s, first-order motor lag
    w_max_factor: float = 1.5         # max rotor speed / hover speed
    w_min_factor: float = 0.25        # idle speed / hover speed
    gravity: float = 9.81
    # sensor defaults
    log_rate: float = 500.0           # Hz, rows of the log (rotor speeds, IMU)
    pos_rate: float = 100.0           # Hz, position (vision) samples
    pos_noise: float = 0.001          # m
    att_noise: float = 0.002          # rad
    gyro_noise: float = 0.005         # rad/s
    # manoeuvre scale
    step: float = 0.5                 # m, size of the position steps
    fast_speed: float = 2.0           # m/s, peak speed of the fast translation
    max_acc: float = 5.0              # m/s^2, cap on reference accelerations
    yaw_turn_time: float = 0.5        # s, time of a 90 degree yaw turn
    start_height: float = 1.0         # m above the ground
    low_pass_height: float = 0.05     # m, CoG height of the low pass

    @property
    def J(self) -> np.ndarray:
        return np.diag(np.asarray(self.inertia, dtype=float))

    @property
    def w_hover(self) -> float:
        return math.sqrt(self.mass * self.gravity / (4.0 * self.K_T))

    def rotor_geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """Contract §1 rotor positions (4, 3) about the rotor-plane centre, and spins (4,)."""
        l = float(self.arm_length)
        if self.layout == "plus":
            P = [[l, 0, 0], [0, l, 0], [-l, 0, 0], [0, -l, 0]]
            s = [-1, 1, -1, 1]
        elif self.layout == "x":
            a = l / math.sqrt(2.0)
            P = [[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]]
            s = [1, 1, -1, -1]
        else:
            raise ValueError(f"layout must be 'plus' or 'x', got {self.layout!r}")
        return np.array(P, dtype=float), np.array(s, dtype=float)


def crazyflie(**overrides: Any) -> Vehicle:
    """A Crazyflie 2.x-like 32.5 g X quadrotor (hover ~1880 rad/s, torque/thrust 0.006 m)."""
    K_T = 2.3e-8
    v = Vehicle(name="foreign_crazyflie", mass=0.0325, inertia=(1.4e-5, 1.4e-5, 2.2e-5),
                arm_length=0.046, layout="x", K_T=K_T, b=0.006 * K_T, rotor_inertia=5e-9,
                rotor_radius=0.0235, hub_z=-0.015, tau_motor=0.02, w_max_factor=1.4,
                w_min_factor=0.25, log_rate=500.0, pos_rate=100.0, pos_noise=0.001,
                att_noise=0.002, gyro_noise=0.005, step=0.5, fast_speed=2.0, max_acc=5.0,
                yaw_turn_time=0.5, start_height=0.8, low_pass_height=0.04)
    return replace(v, **overrides)


def one_kg(**overrides: Any) -> Vehicle:
    """A 1 kg plus quadrotor (the contract's example airframe; hover ~350 rad/s)."""
    v = Vehicle(name="foreign_1kg", mass=1.0, inertia=(0.0082, 0.0082, 0.0149), arm_length=0.17,
                layout="plus", K_T=2e-5, b=5e-7, rotor_inertia=3e-6, rotor_radius=0.10,
                hub_z=-0.04, tau_motor=0.03, w_max_factor=1.6, w_min_factor=0.25,
                log_rate=1000.0, pos_rate=100.0, pos_noise=0.003, att_noise=0.002,
                gyro_noise=0.003, step=0.7, fast_speed=3.0, max_acc=4.5, yaw_turn_time=0.7,
                start_height=1.0, low_pass_height=0.15)
    return replace(v, **overrides)


def _vehicle(v: Vehicle | str) -> Vehicle:
    if isinstance(v, Vehicle):
        return v
    presets = {"crazyflie": crazyflie, "cf": crazyflie, "one_kg": one_kg, "1kg": one_kg}
    if v not in presets:
        raise ValueError(f"unknown vehicle {v!r}; use {sorted(presets)} or a Vehicle")
    return presets[v]()


# ============================================================================ effects
@dataclass
class Effects:
    """Optional physics, all off by default. Own functional forms (see module docstring)."""

    rotor_drag_hub: float = 0.0                 # k: F_i = -k w_i [v_hub_x, v_hub_y, 0] (body)
    linear_drag: Sequence[float] | None = None  # [kx, ky, kz]: F_b = -K R^T v_air
    drag_height: float = 0.0                    # h: that drag acts at body (0, 0, -h), h above the CoG
    ground_effect: bool = False                 # per-rotor Cheeseman-Bennett, factor <= 2
    motor_gains: Sequence[float] | None = None  # per-rotor thrust scale
    motor_gains_torque: bool = False            # ... also scaling the reaction torque
    cog_offset: Sequence[float] | None = None   # [dx, dy, dz] CoG in the rotor-plane frame, m
    wind: Sequence[float] | None = None         # world [wx, wy, wz], m/s
    rotor_accel_torque: bool = False            # -dh/dt: yaw reaction of rotor spin-up

    def active(self) -> dict[str, Any]:
        out = {}
        if self.rotor_drag_hub:
            out["rotor_drag_hub"] = float(self.rotor_drag_hub)
        if self.linear_drag is not None and np.any(np.asarray(self.linear_drag) != 0):
            out["linear_drag"] = [float(x) for x in self.linear_drag]
            if self.drag_height:
                out["drag_height"] = float(self.drag_height)
        if self.ground_effect:
            out["ground_effect"] = True
        if self.motor_gains is not None and np.any(np.asarray(self.motor_gains) != 1):
            out["motor_gains"] = [float(x) for x in self.motor_gains]
            out["motor_gains_torque"] = bool(self.motor_gains_torque)
        if self.cog_offset is not None and np.any(np.asarray(self.cog_offset) != 0):
            out["cog_offset"] = [float(x) for x in self.cog_offset]
        if self.wind is not None and np.any(np.asarray(self.wind) != 0):
            out["wind"] = [float(x) for x in self.wind]
        if self.rotor_accel_torque:
            out["rotor_accel_torque"] = True
        return out


# ============================================================================ rotations
def hat(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def rot_zyx(phi: float, theta: float, psi: float) -> np.ndarray:
    """R = Rz(psi) Ry(theta) Rx(phi), body to world (contract §1)."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    Rx = np.array([[1, 0, 0], [0, cf, -sf], [0, sf, cf]])
    Ry = np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    Rz = np.array([[cp, -sp, 0], [sp, cp, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def euler_zyx(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) ZYX Euler angles phi, theta, psi (psi in
    (-pi, pi])."""
    R = np.asarray(R)
    theta = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    phi = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    psi = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([phi, theta, psi], axis=-1)


def _orthonormalise(R: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


# ============================================================================ dynamics
# state layout: p(0:3) v(3:6) R(6:15, row-major) omega(15:18) w(18:22)
NS = 22


def pack(p, v, R, omega, w) -> np.ndarray:
    return np.concatenate([np.asarray(p, float), np.asarray(v, float),
                           np.asarray(R, float).reshape(9), np.asarray(omega, float),
                           np.asarray(w, float)])


def unpack(s: np.ndarray):
    return s[0:3], s[3:6], s[6:15].reshape(3, 3), s[15:18], s[18:22]


class Dynamics:
    """Rigid-body quadrotor with motor lag and the optional effects."""

    def __init__(self, vehicle: Vehicle, effects: Effects | None = None):
        self.v = vehicle
        self.fx = effects or Effects()
        P, spin = vehicle.rotor_geometry()
        cog = np.zeros(3) if self.fx.cog_offset is None else np.asarray(self.fx.cog_offset, float)
        cog = np.resize(np.concatenate([cog, np.zeros(3)])[:3], 3)
        self.hubs = P + np.array([0.0, 0.0, vehicle.hub_z]) - cog      # about the CoG
        self.spin = spin
        self.m = vehicle.mass
        self.J = vehicle.J
        self.Jinv = np.linalg.inv(self.J)
        self.g = vehicle.gravity
        self.gains = (np.ones(4) if self.fx.motor_gains is None
                      else np.asarray(self.fx.motor_gains, float))
        self.torque_gains = self.gains if self.fx.motor_gains_torque else np.ones(4)
        self.wind = np.zeros(3) if self.fx.wind is None else np.resize(
            np.concatenate([np.asarray(self.fx.wind, float), np.zeros(3)])[:3], 3)
        self.K_lin = None if self.fx.linear_drag is None else np.asarray(self.fx.linear_drag, float)
        self.k_hub = float(self.fx.rotor_drag_hub)
        self.ge_c = (vehicle.rotor_radius / 4.0) ** 2

    # ---------------------------------------------------------------- pieces
    def ground_factor(self, p: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Per-rotor thrust factor 1/(1 - (R_rotor/(4 h_i))^2), capped at 2."""
        if not self.fx.ground_effect:
            return np.ones(4)
        h = -(p[2] + self.hubs @ R[2])            # height of each hub above z = 0
        ratio = np.where(h > 0, self.ge_c / np.maximum(h, 1e-9) ** 2, 0.5)
        return 1.0 / (1.0 - np.minimum(ratio, 0.5))

    def forces(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(acceleration of the CoG in world, body torque excluding gyroscopic terms,
        per-rotor thrust)."""
        p, v, R, om, w = unpack(s)
        w2 = w * w
        T = self.v.K_T * self.gains * self.ground_factor(p, R) * w2
        F_b = np.array([0.0, 0.0, -T.sum()])
        # thrust torque: r_i x (0, 0, -T_i) = (-y_i T_i, x_i T_i, 0)
        tau = np.array([-(self.hubs[:, 1] @ T), self.hubs[:, 0] @ T,
                        self.v.b * (self.spin * self.torque_gains) @ w2])
        v_air_b = None
        if self.k_hub or self.K_lin is not None:
            v_air_b = R.T @ (v - self.wind)
        if self.k_hub:
            v_hub = v_air_b[None, :] + np.cross(om[None, :], self.hubs)   # (4, 3)
            Fi = -self.k_hub * w[:, None] * v_hub
            Fi[:, 2] = 0.0
            F_b = F_b + Fi.sum(axis=0)
            tau = tau + np.cross(self.hubs, Fi).sum(axis=0)
        if self.K_lin is not None:
            F_lin = -self.K_lin * v_air_b
            F_b = F_b + F_lin
            if self.fx.drag_height:   # applied above the centre of gravity: a moment too
                tau = tau + np.cross(np.array([0.0, 0.0, -self.fx.drag_height]), F_lin)
        acc = self.g * E3 + (R @ F_b) / self.m
        return acc, tau, T

    def rhs(self, t: float, s: np.ndarray, w_cmd: np.ndarray) -> np.ndarray:
        p, v, R, om, w = unpack(s)
        acc, tau, _ = self.forces(s)
        wdot = (w_cmd - w) / self.v.tau_motor
        Jr = self.v.rotor_inertia
        h = np.array([0.0, 0.0, -Jr * (self.spin @ w)])
        L = self.J @ om + h
        rhs_om = tau - np.cross(om, L)
        if self.fx.rotor_accel_torque:
            rhs_om[2] += Jr * (self.spin @ wdot)          # -dh/dt
        omdot = self.Jinv @ rhs_om
        Rdot = R @ hat(om)
        out = np.empty(NS)
        out[0:3] = v
        out[3:6] = acc
        out[6:15] = Rdot.reshape(9)
        out[15:18] = omdot
        out[18:22] = wdot
        return out

    def specific_force_body(self, s: np.ndarray) -> np.ndarray:
        """What an accelerometer at the CoG measures: R^T (dv/dt - g e3)."""
        _, _, R, _, _ = unpack(s)
        acc, _, _ = self.forces(s)
        return R.T @ (acc - self.g * E3)

    _ATOL = np.concatenate([np.full(3, 1e-10), np.full(3, 1e-10), np.full(9, 1e-11),
                            np.full(3, 1e-9), np.full(4, 1e-7)])

    def propagate(self, s0: np.ndarray, w_cmd: np.ndarray, t0: float, t1: float,
                  method: str = "RK45", rtol: float = 1e-8) -> np.ndarray:
        """Integrate over [t0, t1] with the rotor command held; the end state."""
        end, _ = _integrate_period(self, s0, np.asarray(w_cmd, float), t0, t1, np.empty(0),
                                   method, rtol)
        return end


def _integrate_period(dyn: Dynamics, s0, w_cmd, t0, t1, t_eval, method, rtol):
    """One ZOH period: end state and states at t_eval (t0 <= t_eval < t1)."""
    te = np.append(np.asarray(t_eval, float), t1)
    sol = solve_ivp(dyn.rhs, (t0, t1), s0, method=method, rtol=rtol, atol=Dynamics._ATOL,
                    args=(w_cmd,), t_eval=te)
    if sol.status != 0:
        raise RuntimeError(f"foreign_sim: integration failed at t={t0}: {sol.message}")
    Y = sol.y.T
    return Y[-1].copy(), Y[:-1]


def simulate_open_loop(vehicle: Vehicle | str, s0: np.ndarray, w_cmd, duration: float,
                       dt: float = 0.002, effects: Effects | None = None,
                       method: str = "RK45", rtol: float = 1e-8) -> dict[str, np.ndarray]:
    """Open-loop run: ``w_cmd`` is a constant (4,) command or a callable ``f(t) -> (4,)``
    sampled every ``dt`` (held). Returns ``{"t", "s"}`` with states at multiples of dt."""
    vehicle = _vehicle(vehicle)
    dyn = Dynamics(vehicle, effects)
    n = int(round(duration / dt))
    S = np.empty((n + 1, NS))
    S[0] = s0
    s = np.asarray(s0, float).copy()
    for k in range(n):
        t0 = k * dt
        u = np.asarray(w_cmd(t0) if callable(w_cmd) else w_cmd, float)
        sol = solve_ivp(dyn.rhs, (t0, t0 + dt), s, method=method, rtol=rtol,
                        atol=Dynamics._ATOL, args=(u,))
        s = sol.y[:, -1].copy()
        p, v, R, om, w = unpack(s)
        s[6:15] = _orthonormalise(R).reshape(9)
        S[k + 1] = s
    return {"t": np.arange(n + 1) * dt, "s": S}


def hover_state(vehicle: Vehicle, height: float = 1.0, psi: float = 0.0,
                w: np.ndarray | None = None) -> np.ndarray:
    """Level, at rest, ``height`` above the ground, rotors at hover speed (or ``w``)."""
    w = np.full(4, vehicle.w_hover) if w is None else np.asarray(w, float)
    return pack([0.0, 0.0, -height], np.zeros(3), rot_zyx(0.0, 0.0, psi), np.zeros(3), w)


# ============================================================================ reference
@dataclass
class Move:
    """One set-point manoeuvre: a minimum-jerk move over ``T`` seconds, then ``hold``.

    Relative (``dx, dy, dz, dpsi``) or absolute (``x, y, z, psi``; these win) targets.
    ``Move(hold=2.0)`` is a hover of 2 s.
    """

    dx: float = 0.0
    dy: float = 0.0
    dz: float = 0.0
    dpsi: float = 0.0
    T: float = 0.0
    hold: float = 0.0
    x: float | None = None
    y: float | None = None
    z: float | None = None
    psi: float | None = None


class Reference:
    """Piecewise quintic (minimum-jerk) reference through the set points of a Move list."""

    def __init__(self, moves: Sequence[Move], start: Sequence[float]):
        cur = np.asarray(start, float).copy()          # x, y, z, psi
        segs = []                                       # (t0, T, q0, q1)
        t = 0.0
        for m in moves:
            tgt = cur + np.array([m.dx, m.dy, m.dz, m.dpsi])
            for i, a in enumerate((m.x, m.y, m.z, m.psi)):
                if a is not None:
                    tgt[i] = a
            if m.T > 0:
                segs.append((t, m.T, cur.copy(), tgt.copy()))
                t += m.T
            else:
                cur = tgt
            cur = tgt
            if m.hold > 0:
                segs.append((t, m.hold, cur.copy(), cur.copy()))
                t += m.hold
        if not segs:
            segs.append((0.0, 1.0, cur.copy(), cur.copy()))
            t = 1.0
        self.segs = segs
        self.t_start = np.array([s[0] for s in segs])
        self.t_end = t
        self.final = cur

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        """(position, velocity, acceleration (world), psi, psi rate) at time t."""
        if t >= self.t_end:
            q = self.final
            return q[:3].copy(), np.zeros(3), np.zeros(3), float(q[3]), 0.0
        k = int(np.searchsorted(self.t_start, t, side="right") - 1)
        t0, T, q0, q1 = self.segs[max(k, 0)]
        s = min(max((t - t0) / T, 0.0), 1.0)
        d = q1 - q0
        pos = q0 + d * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)
        vel = d / T * (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4)
        acc = d / T ** 2 * (60 * s - 180 * s ** 2 + 120 * s ** 3)
        return pos[:3], vel[:3], acc[:3], float(pos[3]), float(vel[3])


def _move_time(dist: float, speed: float, max_acc: float) -> float:
    """Duration of a minimum-jerk move of ``dist`` with peak speed <= speed and peak
    acceleration <= max_acc (peak speed 1.875 d/T, peak acceleration 5.774 d/T^2)."""
    dist = abs(dist)
    return max(1.875 * dist / speed, math.sqrt(5.774 * dist / max_acc), 0.2)


def default_manoeuvres(vehicle: Vehicle, low_pass: bool = True, sign: float = 1.0,
                       speeds: Sequence[float] | None = None) -> list[Move]:
    """One cycle (~20 s for the presets) of set-point manoeuvres: hover, vertical steps
    (up slowly, down faster), fast yaw turns (large rotor-speed differences), x and y steps
    at two speeds, a fast translation, a low pass near the ground (descend, pass, climb
    while moving back) and a combined diagonal move with yaw. ``speeds`` = peak speeds of
    (x step, y step, fast translation), default ``fast_speed * (0.5, 0.3, 1)``; ``sign``
    mirrors the horizontal moves and yaw."""
    s, a = vehicle.step, vehicle.max_acc
    h0 = vehicle.start_height
    vf = vehicle.fast_speed
    sp = list(speeds) if speeds is not None else [0.5 * vf, 0.3 * vf, vf]
    yt = vehicle.yaw_turn_time
    sg = sign
    mv = [Move(hold=0.5),
          # vertical steps: up slowly, down faster
          Move(dz=-0.6 * s, T=_move_time(0.6 * s, 0.6 * vf / 2, a), hold=0.4),
          Move(dz=+0.6 * s, T=_move_time(0.6 * s, vf / 2, a), hold=0.4),
          # fast yaw turns
          Move(dpsi=sg * math.pi / 2, T=yt, hold=0.4),
          Move(dpsi=-sg * math.pi / 2, T=yt, hold=0.4),
          # x and y steps at two speeds
          Move(dx=sg * s, T=_move_time(s, sp[0], a), hold=0.3),
          Move(dx=-sg * s, T=_move_time(s, sp[0], a), hold=0.3),
          Move(dy=sg * s, T=_move_time(s, sp[1], a), hold=0.3),
          Move(dy=-sg * s, T=_move_time(s, sp[1], a), hold=0.3),
          # fast translation
          Move(dx=2 * sg * s, T=_move_time(2 * s, sp[2], a), hold=0.3),
          Move(dx=-2 * sg * s, T=_move_time(2 * s, sp[2], a), hold=0.3)]
    if low_pass:
        zl = -vehicle.low_pass_height
        dh = h0 - vehicle.low_pass_height
        mv += [Move(z=zl, T=_move_time(dh, 0.5 * vf, 0.4 * a), hold=0.3),
               Move(dx=-sg * s, T=_move_time(s, 0.4 * vf, a)),
               Move(dx=sg * s, z=-h0, T=_move_time(max(dh, s), 0.5 * vf, 0.4 * a), hold=0.3)]
    mv += [Move(dx=0.5 * sg * s, dy=0.5 * sg * s, dz=-0.2 * s, dpsi=sg * math.pi / 3, T=1.0,
                hold=0.3),
           Move(dx=-0.5 * sg * s, dy=-0.5 * sg * s, dz=0.2 * s, dpsi=-sg * math.pi / 3, T=1.0,
                hold=0.3)]
    return mv


def _manoeuvre_list(spec, vehicle: Vehicle, duration: float, low_pass: bool,
                    speeds) -> list[Move]:
    if spec is None or spec == "default":
        out: list[Move] = []
        sign, total = 1.0, 0.0
        while total < duration + 1.0:
            cyc = default_manoeuvres(vehicle, low_pass=low_pass, sign=sign, speeds=speeds)
            out += cyc
            total += sum(m.T + m.hold for m in cyc)
            sign = -sign
        return out
    if spec == "hover":
        return [Move(hold=duration + 1.0)]
    if isinstance(spec, str):
        raise ValueError(f"manoeuvres must be 'default', 'hover' or a list of Move, got {spec!r}")
    return list(spec)


# ============================================================================ controller
class Controller:
    """Cascaded controller: position PID -> thrust vector and desired rotation (geometric,
    Lee-style SO(3) error) -> attitude P -> body-rate PI with gyroscopic feed-forward ->
    mixer (inverse allocation with the controller's own K_T, b; yaw is given up first when a
    rotor saturates). Gains follow from the motor time constant."""

    def __init__(self, vehicle: Vehicle, dt: float, K_T: float | None = None,
                 b: float | None = None, mass: float | None = None):
        self.v = vehicle
        self.dt = dt
        self.m = vehicle.mass if mass is None else mass
        K_T = vehicle.K_T if K_T is None else K_T
        b = vehicle.b if b is None else b
        P, spin = vehicle.rotor_geometry()
        A = np.vstack([K_T * np.ones(4), -K_T * P[:, 1], K_T * P[:, 0], b * spin])
        self.A = A
        self.Ainv = np.linalg.inv(A)
        self.J = vehicle.J
        wh = vehicle.w_hover
        self.w2_min = (vehicle.w_min_factor * wh) ** 2
        self.w2_max = (vehicle.w_max_factor * wh) ** 2
        tau = max(vehicle.tau_motor, 5.0 * dt)     # a very fast motor: limited by the rate
        self.k_rate = np.array([0.5 / tau, 0.5 / tau, 0.35 / tau])
        self.ki_rate = 0.5 * self.k_rate
        self.k_att = np.array([self.k_rate[0] / 3.5, self.k_rate[1] / 3.5, self.k_rate[2] / 4.0])
        wn = self.k_att[0] / 3.2
        self.kp = wn ** 2
        self.kd = 2 * 0.9 * wn
        self.ki = 0.3 * wn ** 3
        self.max_tilt = math.radians(40.0)
        self.max_rate = np.array([8.0, 8.0, 5.0])
        # integral actions limited to 30 % of the authority (angular acceleration) and to
        # 0.35 g (acceleration)
        half_span = 0.5 * (self.w2_max - self.w2_min)
        self.alpha_i_max = 0.3 * np.abs(A[1:]).sum(axis=1) * half_span / np.diag(self.J)
        self.acc_i_max = 0.35 * vehicle.gravity
        self.i_zone = 0.08 * vehicle.step / 0.5     # m: the position integrator runs nearby
        self.reset()

    def reset(self) -> None:
        self.ei_pos = np.zeros(3)
        self.ei_rate = np.zeros(3)

    def warm_start(self, w: np.ndarray) -> None:
        """Set the integrators so that, at rest on the set point, the controller commands
        the rotor speeds ``w`` (the trim): the flight then starts steady."""
        u = self.A @ (np.asarray(w, float) ** 2)           # [T, tau_x, tau_y, tau_z]
        self.ei_pos = np.array([0.0, 0.0, (self.v.gravity - u[0] / self.m) / self.ki])
        self.ei_rate = np.linalg.solve(self.J, u[1:]) / self.ki_rate

    def __call__(self, t: float, p, v, R, om, ref) -> np.ndarray:
        pr, vr, ar, psi_r, psid_r = ref
        g = self.v.gravity
        ep, ev = pr - p, vr - v
        lim = self.acc_i_max / self.ki
        # anti-wind-up: integrate only near the set point (|error| < i_zone) and while the
        # reference holds still
        if vr @ vr < 0.01:
            e_i = np.where(np.abs(ep) < self.i_zone, ep, 0.0)
            self.ei_pos = np.clip(self.ei_pos + e_i * self.dt, -lim, lim)
        a_cmd = ar + self.kp * ep + self.kd * ev + self.ki * self.ei_pos
        # tilt limit: horizontal acceleration at most (g - a_z) tan(max_tilt)
        up = g - a_cmd[2]
        up = max(up, 0.3 * g)
        a_cmd[2] = g - up
        hmax = up * math.tan(self.max_tilt)
        hn = math.hypot(a_cmd[0], a_cmd[1])
        if hn > hmax:
            a_cmd[:2] *= hmax / hn
        F = self.m * (a_cmd - g * E3)          # the thrust vector to produce (world)
        b3 = -F / np.linalg.norm(F)
        T = float(-F @ R[:, 2])                 # thrust along the current body -z
        T = max(T, 0.0)
        b1c = np.array([math.cos(psi_r), math.sin(psi_r), 0.0])
        b2 = np.cross(b3, b1c)
        b2 /= np.linalg.norm(b2)
        b1 = np.cross(b2, b3)
        Rd = np.column_stack([b1, b2, b3])
        E = Rd.T @ R - R.T @ Rd
        eR = 0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]])
        om_d = -self.k_att * eR + R.T @ np.array([0.0, 0.0, psid_r])
        om_d = np.clip(om_d, -self.max_rate, self.max_rate)
        e_om = om_d - om
        lim = self.alpha_i_max / self.ki_rate
        self.ei_rate = np.clip(self.ei_rate + e_om * self.dt, -lim, lim)
        alpha = self.k_rate * e_om + self.ki_rate * self.ei_rate
        tau = self.J @ alpha + np.cross(om, self.J @ om)
        return self.mix(T, tau)

    def mix(self, T: float, tau: np.ndarray) -> np.ndarray:
        base = self.Ainv[:, :3] @ np.array([T, tau[0], tau[1]])
        yaw = self.Ainv[:, 3] * tau[2]
        lo, hi = self.w2_min, self.w2_max
        k = 1.0                                  # largest share of the yaw torque that fits
        for i in range(4):
            if yaw[i] > 0 and base[i] + yaw[i] > hi:
                k = min(k, max((hi - base[i]) / yaw[i], 0.0))
            elif yaw[i] < 0 and base[i] + yaw[i] < lo:
                k = min(k, max((lo - base[i]) / yaw[i], 0.0))
        w2 = np.clip(base + k * yaw, lo, hi)
        return np.sqrt(w2)


# ============================================================================ sensors
@dataclass
class Sensors:
    log_rate: float = 500.0
    pos_rate: float = 100.0
    pos_noise: float = 0.001
    att_noise: float = 0.002
    gyro: bool = True
    gyro_noise: float = 0.005
    w_noise: float = 0.0                 # rad/s, noise of the logged rotor speeds
    pos_dropout: float = 0.0             # probability a position sample is lost
    att_dropout: float = 0.0             # probability an attitude sample is lost
    gyro_dropout: float = 0.0
    pos_gaps: Sequence[tuple[float, float]] = ()   # time windows without position
    accel: bool = False                  # ax, ay, az: the accelerometer as output channels
    accel_noise: float = 0.02
    log_commands: bool = False           # log the commanded rotor speeds (as a PWM log does), not the actual
    psi_wrap: bool = True                # psi in (-pi, pi] (else unwrapped)


# ============================================================================ flight
@dataclass
class ForeignFlight:
    log: Any                             # greybox.data.FlightLog
    truth: dict[str, Any]
    states: dict[str, np.ndarray] = field(repr=False, default_factory=dict)

    def save(self, directory: str | Path) -> dict[str, Path]:
        """Write flight.csv (greybox's save_log), airframe_true.toml and truth.json."""
        from greybox.data import save_log
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        paths = {"log": d / "flight.csv", "airframe": d / "airframe_true.toml",
                 "truth": d / "truth.json"}
        save_log(self.log, paths["log"])
        paths["airframe"].write_text(airframe_toml(self.truth["airframe"]))
        paths["truth"].write_text(json.dumps(self.truth, indent=2, default=float))
        return paths


def simulate_flight(vehicle: Vehicle | str = "crazyflie", duration: float = 20.0, seed: int = 0,
                    *, rotor_drag_hub: float = 0.0, linear_drag: Sequence[float] | None = None,
                    drag_height: float = 0.0,
                    ground_effect: bool = False, motor_gains: Sequence[float] | None = None,
                    motor_gains_torque: bool = False, cog_offset: Sequence[float] | None = None,
                    wind: Sequence[float] | None = None, rotor_accel_torque: bool = False,
                    manoeuvres: str | Sequence[Move] | None = "default", low_pass: bool = True,
                    speeds: Sequence[float] | None = None,
                    log_rate: float | None = None, pos_rate: float | None = None,
                    ctrl_rate: float = 500.0, pos_noise: float | None = None,
                    att_noise: float | None = None, gyro: bool = True,
                    gyro_noise: float | None = None, w_noise: float = 0.0,
                    pos_dropout: float = 0.0, att_dropout: float = 0.0,
                    gyro_dropout: float = 0.0, pos_gaps: Sequence[tuple[float, float]] = (),
                    accel: bool = False, psi_wrap: bool = True, psi0: float = 0.0, log_commands: bool = False,
                    ctrl_K_T_factor: float = 1.0, ctrl_b_factor: float = 1.0,
                    command_delay: float = 0.0,
                    method: str = "RK45", rtol: float = 1e-8) -> ForeignFlight:
    """Fly ``vehicle`` under the own cascaded controller along ``manoeuvres`` and log it.

    Args:
        vehicle: a :class:`Vehicle` or ``"crazyflie"`` / ``"one_kg"``.
        duration: s; the log has ``round(duration * log_rate) + 1`` rows from t = 0.
        seed: seeds the one ``numpy.random.Generator`` of every random source (noise,
            dropouts).
        rotor_drag_hub ... rotor_accel_torque: optional physics (:class:`Effects`), off.
        manoeuvres: ``"default"`` (cycles of :func:`default_manoeuvres`, mirrored on
            each repeat), ``"hover"``, or a list of :class:`Move`. Starts at rest in hover
            ``vehicle.start_height`` above the ground at the origin with yaw ``psi0``.
        low_pass, speeds: options of the default manoeuvres.
        log_rate, pos_rate: Hz (defaults from the vehicle); control runs at ``ctrl_rate``
            (zero-order hold of the rotor commands; motors lag behind them).
        pos_noise, att_noise, gyro, gyro_noise, w_noise: sensor noise (std) and whether
            p, q, r are logged; ``*_dropout`` probabilities of a lost sample; ``pos_gaps``
            time windows without position; ``accel`` logs ax, ay, az as extras.
        psi_wrap: log psi in (-pi, pi] (as an IMU does) or unwrapped.
        ctrl_K_T_factor, ctrl_b_factor: the controller's own model error (its integrators
            absorb it).
        command_delay: s (a whole number of control periods) between a command's issue,
            which ``log_commands`` logs, and the motors receiving it (the trim until then).

    Returns: :class:`ForeignFlight` with ``.log`` (FlightLog, inputs ``w1..w4`` = actual
    rotor speeds at the log times, outputs NaN where not measured), ``.truth`` and
    ``.states`` (noise-free time histories at the log times).
    """
    from greybox.data import FlightLog

    veh = _vehicle(vehicle)
    fx = Effects(rotor_drag_hub=rotor_drag_hub, linear_drag=linear_drag, drag_height=drag_height,
                 ground_effect=ground_effect, motor_gains=motor_gains,
                 motor_gains_torque=motor_gains_torque, cog_offset=cog_offset, wind=wind,
                 rotor_accel_torque=rotor_accel_torque)
    sens = Sensors(log_rate=log_rate or veh.log_rate, pos_rate=pos_rate or veh.pos_rate,
                   pos_noise=veh.pos_noise if pos_noise is None else pos_noise,
                   att_noise=veh.att_noise if att_noise is None else att_noise, gyro=gyro,
                   gyro_noise=veh.gyro_noise if gyro_noise is None else gyro_noise,
                   w_noise=w_noise, pos_dropout=pos_dropout, att_dropout=att_dropout,
                   gyro_dropout=gyro_dropout, pos_gaps=tuple(pos_gaps), accel=accel, log_commands=log_commands,
                   psi_wrap=psi_wrap)
    rng = np.random.default_rng(seed)
    dyn = Dynamics(veh, fx)
    ctrl = Controller(veh, 1.0 / ctrl_rate, K_T=veh.K_T * ctrl_K_T_factor, b=veh.b * ctrl_b_factor)
    moves = _manoeuvre_list(manoeuvres, veh, duration, low_pass, speeds)
    ref = Reference(moves, [0.0, 0.0, -veh.start_height, psi0])

    # --- initial state: hover trim of the true vehicle (so the log starts steady)
    w_trim = _trim_speeds(dyn, veh.start_height, psi0)
    s = hover_state(veh, veh.start_height, psi0, w=w_trim)
    ctrl.warm_start(w_trim)

    n_log = int(round(duration * sens.log_rate)) + 1
    t_log = np.arange(n_log) / sens.log_rate
    n_ctrl = int(math.ceil(duration * ctrl_rate - 1e-9)) + 1
    dt_c = 1.0 / ctrl_rate
    S = np.empty((n_log, NS))
    Wc = np.empty((n_log, 4))
    REF = np.empty((n_log, 4))
    j = 0
    n_delay = int(round(command_delay * ctrl_rate))
    pending = [w_trim.copy()] * n_delay          # commands issued but not yet at the motors
    for k in range(n_ctrl):
        t0 = k * dt_c
        if j >= n_log:
            break
        t1 = (k + 1) * dt_c
        p, v, R, om, w = unpack(s)
        r = ref(t0)
        w_issued = ctrl(t0, p, v, R, om, r)
        pending.append(w_issued)
        w_cmd = pending.pop(0)
        j1 = j
        while j1 < n_log and t_log[j1] < t1 - 1e-12:
            j1 += 1
        te = t_log[j:j1]
        if te.size and abs(te[0] - t0) < 1e-12:
            S[j] = s
            rest = te[1:]
            js = j + 1
        else:
            rest = te
            js = j
        end, Ys = _integrate_period(dyn, s, w_cmd, t0, t1, rest, method, rtol)
        if rest.size:
            S[js:j1] = Ys
        for jj in range(j, j1):
            Wc[jj] = w_issued
            rr = ref(t_log[jj])
            REF[jj, :3], REF[jj, 3] = rr[0], rr[3]
        j = j1
        end[6:15] = _orthonormalise(end[6:15].reshape(3, 3)).reshape(9)
        s = end

    # --- truth histories
    P, V = S[:, 0:3], S[:, 3:6]
    Rs = S[:, 6:15].reshape(-1, 3, 3)
    OM, W = S[:, 15:18], S[:, 18:22]
    eul = euler_zyx(Rs)
    eul_unwrapped = eul.copy()
    eul_unwrapped[:, 2] = np.unwrap(eul[:, 2])

    # --- sensors (one generator for everything)
    pos_meas = P + sens.pos_noise * rng.standard_normal(P.shape)
    pos_mask = np.zeros(n_log, bool)
    n_pos = int(math.floor(t_log[-1] * sens.pos_rate + 1e-9)) + 1
    idx = np.unique(np.clip(np.round(np.arange(n_pos) / sens.pos_rate * sens.log_rate).astype(int),
                            0, n_log - 1))
    pos_mask[idx] = True
    if sens.pos_dropout > 0:
        pos_mask &= rng.random(n_log) >= sens.pos_dropout
    for (a, bnd) in sens.pos_gaps:
        pos_mask &= ~((t_log >= a) & (t_log <= bnd))
    pos_meas[~pos_mask] = np.nan
    att = (eul if sens.psi_wrap else eul_unwrapped) + sens.att_noise * rng.standard_normal(eul.shape)
    if sens.psi_wrap:
        att[:, 2] = np.angle(np.exp(1j * att[:, 2]))
    if sens.att_dropout > 0:
        att[rng.random(n_log) < sens.att_dropout] = np.nan
    cols = [pos_meas, att]
    names = ["x", "y", "z", "phi", "theta", "psi"]
    if sens.gyro:
        gy = OM + sens.gyro_noise * rng.standard_normal(OM.shape)
        if sens.gyro_dropout > 0:
            gy[rng.random(n_log) < sens.gyro_dropout] = np.nan
        cols.append(gy)
        names += ["p", "q", "r"]
    W_log = (Wc if sens.log_commands else W) + (sens.w_noise * rng.standard_normal(W.shape) if sens.w_noise else 0.0)
    if sens.accel:
        A = np.array([dyn.specific_force_body(si) for si in S])
        A += sens.accel_noise * rng.standard_normal(A.shape)
        cols.append(A)
        names += ["ax", "ay", "az"]
    log = FlightLog(t_log, W_log, ["w1", "w2", "w3", "w4"], np.hstack(cols), names, {},
                    [f"foreign_sim: {veh.name}, seed {seed}, effects {fx.active() or 'none'}"],
                    "foreign_sim")

    truth = _truth(veh, fx, sens, seed, duration, ctrl_rate)
    truth["command_delay"] = n_delay / ctrl_rate
    states = {"t": t_log, "pos": P, "vel": V, "R": Rs, "omega": OM, "w": W, "w_cmd": Wc,
              "euler": eul_unwrapped, "ref_pos": REF[:, :3], "ref_psi": REF[:, 3]}
    return ForeignFlight(log=log, truth=truth, states=states)


def _trim_speeds(dyn: Dynamics, height: float, psi: float) -> np.ndarray:
    """Rotor speeds that hold the vehicle level at rest at ``height`` (zero net force and
    torque), solved by Newton on w^2 (handles cog offset, weak motors, ground effect)."""
    veh = dyn.v
    w2 = np.full(4, veh.w_hover ** 2)
    for _ in range(30):
        def res(w2_):
            s = hover_state(veh, height, psi, w=np.sqrt(np.maximum(w2_, 0.0)))
            acc, tau, _ = dyn.forces(s)
            return np.array([acc[2] * veh.mass, tau[0], tau[1], tau[2]])
        r0 = res(w2)
        if np.all(np.abs(r0) < 1e-14):
            break
        Jm = np.empty((4, 4))
        for i in range(4):
            d = np.zeros(4)
            d[i] = 1e-6 * w2[i]
            Jm[:, i] = (res(w2 + d) - r0) / d[i]
        w2 = w2 - np.linalg.solve(Jm, r0)
    return np.sqrt(np.maximum(w2, 0.0))


def _truth(veh: Vehicle, fx: Effects, sens: Sensors, seed, duration, ctrl_rate) -> dict[str, Any]:
    gains = np.ones(4) if fx.motor_gains is None else np.asarray(fx.motor_gains, float)
    mean_gain = float(gains.mean())
    # greybox-equivalent values of the own effects (approximate where the forms differ)
    equiv: dict[str, Any] = {"K_T": veh.K_T * mean_gain, "b": veh.b, "J_r": veh.rotor_inertia}
    lin = [0.0, 0.0, 0.0] if fx.linear_drag is None else [float(x) for x in fx.linear_drag]
    equiv["Kd"] = lin          # body-frame drag; equal to world-frame drag when kx = ky
    if fx.rotor_drag_hub:
        equiv["k_rd"] = float(fx.rotor_drag_hub)
    if fx.drag_height:
        equiv["k_dm"] = [fx.drag_height * lin[1], fx.drag_height * lin[0]]
    if fx.ground_effect:
        equiv["k_ge"] = (veh.rotor_radius / 4.0) ** 2
    if fx.cog_offset is not None:
        equiv["r_cog"] = [float(fx.cog_offset[0]), float(fx.cog_offset[1])]
    if fx.motor_gains is not None:
        equiv["K_T_dev"] = [float(g / mean_gain - 1.0) for g in gains[:-1]]
    if fx.wind is not None:
        equiv["wind"] = [float(fx.wind[0]), float(fx.wind[1])]
    truth = {
        "vehicle": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(veh).items()},
        "K_T": veh.K_T, "b": veh.b, "mass": veh.mass, "inertia": list(veh.inertia),
        "arm_length": veh.arm_length, "layout": veh.layout, "rotor_inertia": veh.rotor_inertia,
        "tau_motor": veh.tau_motor, "w_hover": veh.w_hover,
        "effects": fx.active(),
        "greybox_equivalent": equiv,
        "sensors": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(sens).items()},
        "seed": seed, "duration": duration, "ctrl_rate": ctrl_rate,
        "airframe": airframe_dict(veh, Kd_guess=lin),
    }
    return truth


# ============================================================================ airframe
def airframe_dict(vehicle: Vehicle | str, K_T_guess_factor: float = 1.0,
                  b_guess_factor: float = 1.0, Kd_guess: Sequence[float] | float | None = None,
                  name: str | None = None, rotor_inertia: float | None = None,
                  extra_parameters: dict[str, Any] | None = None) -> dict[str, Any]:
    """The airframe document (contract §3, the dict ``airframe_from_dict`` takes) with the
    TRUE mass, inertia, arm, layout, rotor inertia and gravity, and ``[parameters]``
    starting guesses ``K_T * K_T_guess_factor``, ``b * b_guess_factor``, ``Kd`` (default
    ``0.1 * mass`` per axis) plus ``extra_parameters`` (e.g. ``{"k_rd": 1e-6}``)."""
    veh = _vehicle(vehicle)
    if Kd_guess is None:
        Kd = [0.1 * veh.mass] * 3
    elif np.isscalar(Kd_guess):
        Kd = [float(Kd_guess)] * 3
    else:
        Kd = [float(x) for x in Kd_guess]
    params: dict[str, Any] = {"K_T": veh.K_T * K_T_guess_factor, "b": veh.b * b_guess_factor,
                              "Kd": Kd}
    if extra_parameters:
        params.update({k: (list(v) if isinstance(v, (list, tuple, np.ndarray)) else float(v))
                       for k, v in extra_parameters.items()})
    return {"airframe": {"name": name or veh.name, "mass": veh.mass,
                         "inertia": [float(x) for x in veh.inertia],
                         "arm_length": veh.arm_length, "layout": veh.layout,
                         "rotor_inertia": veh.rotor_inertia if rotor_inertia is None
                         else rotor_inertia, "gravity": veh.gravity},
            "parameters": params}


def airframe_toml(doc: dict[str, Any]) -> str:
    """TOML text of an airframe dict (flat tables, numbers, strings, lists of numbers)."""
    def val(x):
        if isinstance(x, str):
            return json.dumps(x)
        if isinstance(x, (list, tuple)):
            return "[" + ", ".join(repr(float(y)) for y in x) + "]"
        return repr(float(x))
    lines = []
    for table in ("airframe", "parameters"):
        if table in doc:
            lines.append(f"[{table}]")
            lines += [f"{k} = {val(v)}" for k, v in doc[table].items()]
            lines.append("")
    return "\n".join(lines)


# ============================================================================ CLI
def _main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", default="crazyflie", choices=["crazyflie", "one_kg"])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True)
    ap.add_argument("--effects", default="", help="JSON object of effect options, e.g. "
                    "'{\"ground_effect\": true, \"rotor_drag_hub\": 2e-6}'")
    a = ap.parse_args(argv)
    kw = json.loads(a.effects) if a.effects else {}
    fl = simulate_flight(a.vehicle, a.duration, a.seed, **kw)
    for k, p in fl.save(a.out).items():
        print(f"{k}: {p}")
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())

"""A second quadrotor simulator, independent of greybox and of ``foreign_sim.py``.

``foreign_sim.py`` was the project's first simulator of its own beside greybox's synth; a
fit or a diagnosis tuned against it could still pass by luck of one generator's choices.
This one shares none of them: attitude as a unit quaternion, a fixed-step classical RK4
integrator (not ``solve_ivp``), a geometric SE(3) tracking controller (Lee, Leok and
McClamroch 2010) with integral action and a deliberately mismatched internal model on the true
state (or, ``fly(..., controller="cascaded_pid")``, an autopilot's cascade of PID loops on the
measured state: a noisy filtered gyro, a wandering position estimate), explicit rotor tables in the Crazyflie firmware's order (or any other frame,
``PeerVehicle(rotor_xy=..., spins=...)``), an IMU-rate log with
vision at 60 Hz that loses samples and whole stretches, timestamps with jitter, quantised
ESC speed telemetry (or, ``PeerSensors(log_commands=True)``, the controller's speed commands
as a PWM log has them, the motors' lag in between), optionally an attitude estimate whose level
reference is off (``att_bias``: the controller levels the biased estimate, and the log reports it)
and a vision latency (``pos_delay``), and its own forms of the effects:

* rotor drag at every hub on the hub's own air velocity ``R^T (v - wind) + omega x r_i``
  (so it also damps the body rates), ``F_i = -k_rd w_i P (...)`` with ``P = diag(1, 1, 0)``;
* Cheeseman-Bennett ground effect per rotor, ``T_IGE/T = 1/(1 - (rho/(4 h_i))^2)``, ``h_i`` the
  hub's height above the floor, capped at the 1.33 of ``h_i = rho/2``;
* per-rotor gains on thrust and reaction torque (a damaged propeller), a CoG offset, a
  constant wind, body drag in the **body** frame;
* a battery whose voltage sags with the current drawn and the charge spent, driving motors
  whose ESCs are open loop (``PeerBattery``): the command sets a duty cycle calibrated at one
  voltage, and a DC motor's speed under a propeller's load follows the duty times the
  battery's voltage through its own quadratic (back-EMF plus load), not a linear scale;
* effects the greybox catalogue does not hold: aerodynamic rate damping ``-D omega``,
  blade-flapping moments ``k_f (e3 x v_b)``, thrust that falls with the inflow
  ``T (1 - k_in v_z,b ...)`` (axial climb), a gyro bias, turbulence (a random torque), and a
  slung load (a point mass on a cable hung from the CoG, swinging as a pendulum: its own
  states, the cable's pull on the vehicle a force no catalogue effect has).

Only the contract (frames, rotor conventions, the log's columns, the airframe schema) is
shared with greybox. The log and the airframe are written by this module's own code, and
greybox reads them as a user's files (``greybox.load_log``), so the whole path a user takes
is exercised. Nothing here imports greybox.

Physics, SI units, world NED (z down, gravity ``+g e3``), body FRD, the body origin at the
centre of gravity:

* ``m dv/dt = m g e3 + R F_b + F_w``, ``F_b = sum_i (-T_i e3 + F_i) + F_body``;
* ``J domega/dt = M - omega x (J omega + h)``, ``h = -J_r sum(spin_i w_i) e3`` (the rotors turn
  opposite to their reaction torque ``spin_i b w_i^2`` about ``+z``);
* ``dq/dt = q (x) [0, omega] / 2``, ``q`` body to world, scalar first;
* motors ``dw_i/dt = (w_cmd,i - w_i) / tau_m``, the command held between controller updates.

Use::

    from peer_sim import PeerVehicle, fly, write_case
    flight = fly(PeerVehicle.crazyflie(), duration=20, seed=1)
    flight.columns, flight.truth
    write_case(flight, "DIR")          # DIR/flight.csv, DIR/airframe.toml, DIR/truth.json

``python tests/peer_sim.py --vehicle one_kg --effects '{"ground_effect": true}' --out DIR``
(``--sensors '{"pos_delay": 0.03}'`` for the sensors' options).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

__all__ = ["PeerVehicle", "PeerEffects", "PeerBattery", "PeerSensors", "PeerFlight", "fly", "write_case",
           "airframe_text", "quat_to_rot", "rot_to_euler"]

E3 = np.array([0.0, 0.0, 1.0])


# ============================================================================ vehicle
#: hubs' (x, y) of frames that are no square X, in the Crazyflie's rotor order
DEADCAT_XY = ((0.075, 0.10), (-0.075, 0.06), (-0.075, -0.06), (0.075, -0.10))
H_FRAME_XY = ((0.13, 0.22), (-0.13, 0.22), (-0.13, -0.22), (0.13, -0.22))


@dataclass
class PeerVehicle:
    """The true vehicle. Rotors by default a square X in the Crazyflie firmware's order
    (front-right, back-right, back-left, front-left) with spins (-1, +1, -1, +1) ... as the
    airframe's [[rotor]] tables give them, ``arm`` the hub's distance from the centre; any other
    frame with ``rotor_xy`` (four hubs' x, y in the rotors' order) and ``spins``, ``arm`` then
    only the airframe's informative arm length."""

    name: str
    mass: float
    inertia: tuple[float, float, float]
    arm: float
    K_T: float
    b: float
    tau_motor: float
    rotor_radius: float
    rotor_inertia: float = 0.0
    hub_height: float = 0.0           # hubs this far above the CoG (body -z), m
    spins: tuple[int, int, int, int] = (-1, 1, -1, 1)
    # the hubs' (x, y) in the rotors' order, m, for a frame that is no square X (a dead cat, an
    # H); None: the square X of ``arm``. ``arm`` is then the airframe's informative arm length
    rotor_xy: Sequence[Sequence[float]] | None = None
    gravity: float = 9.81
    # flight envelope and flight plan scale
    distance: float = 1.0             # m, step size
    speed: float = 2.0                # m/s, figure-eight top speed
    # m, the low passes' reference: the CoG's at low_hover + hub_height above the floor (meant as
    # the hubs' height; the vehicle stays above the reference in the 1.5-s hold)
    low_hover: float = 0.085
    cruise_height: float = 1.0        # m
    # sensors
    log_rate: float = 1000.0
    pos_rate: float = 60.0
    pos_noise: float = 0.001
    att_noise: float = 0.002
    gyro_noise: float = 0.005
    speed_quantum: float = 0.0        # rad/s, resolution of the ESC speed telemetry
    ctrl_rate: float = 500.0
    attitude_bandwidth: float = 25.0  # rad/s, the controller's attitude loop
    position_bandwidth: float = 2.5   # rad/s

    def __post_init__(self) -> None:
        if len(self.spins) != 4 or (self.rotor_xy is not None
                                    and (len(self.rotor_xy) != 4 or any(len(h) != 2 for h in self.rotor_xy))):
            raise ValueError("a quadrotor: four spins and, if given, four (x, y) hubs")

    @property
    def J(self) -> np.ndarray:
        return np.diag(self.inertia)

    def rotor_positions(self) -> np.ndarray:
        if self.rotor_xy is not None:
            return np.array([[float(x), float(y), 0.0] for x, y in self.rotor_xy])
        a = self.arm / math.sqrt(2.0)
        return np.array([[a, a, 0.0], [-a, a, 0.0], [-a, -a, 0.0], [a, -a, 0.0]])

    @property
    def w_hover(self) -> float:
        return math.sqrt(self.mass * self.gravity / (4 * self.K_T))

    @classmethod
    def crazyflie(cls, **kw: Any) -> "PeerVehicle":
        """A 30 g vehicle of the Crazyflie's scale: K_T 2.3e-8, about 1800 rad/s in hover."""
        base = dict(name="peer_cf", mass=0.031, inertia=(1.40e-5, 1.45e-5, 2.25e-5), arm=0.046,
                    K_T=2.3e-8, b=1.6e-10, tau_motor=0.02, rotor_radius=0.023,
                    rotor_inertia=1.0e-9, hub_height=0.012, distance=0.5, speed=1.2,
                    low_hover=0.035, cruise_height=0.6, log_rate=500.0, pos_rate=100.0,
                    pos_noise=0.001, att_noise=0.002, gyro_noise=0.01, attitude_bandwidth=30.0,
                    position_bandwidth=2.5, ctrl_rate=500.0)
        base.update(kw)
        return cls(**base)

    @classmethod
    def one_kg(cls, **kw: Any) -> "PeerVehicle":
        """A 1.2 kg vehicle with 9.5-inch propellers (rotor radius 12 cm)."""
        base = dict(name="peer_1kg", mass=1.2, inertia=(0.011, 0.012, 0.021), arm=0.225,
                    K_T=1.1e-5, b=1.7e-7, tau_motor=0.035, rotor_radius=0.12,
                    rotor_inertia=4.0e-5, hub_height=0.03, distance=1.0, speed=2.0,
                    low_hover=0.085, cruise_height=1.0, log_rate=1000.0, pos_rate=60.0,
                    pos_noise=0.001, att_noise=0.003, gyro_noise=0.005, speed_quantum=1.0,
                    attitude_bandwidth=20.0, position_bandwidth=2.0, ctrl_rate=500.0)
        base.update(kw)
        return cls(**base)

    @classmethod
    def racer(cls, **kw: Any) -> "PeerVehicle":
        """A 250 g racer with 5-inch propellers flown hard: figure eights at 6 m/s, steps of
        3 m, a 40 Hz attitude loop (up to 70 degrees of tilt, 7 rad/s)."""
        base = dict(name="peer_racer", mass=0.25, inertia=(1.5e-4, 1.8e-4, 2.9e-4), arm=0.08,
                    K_T=1.5e-6, b=2.2e-8, tau_motor=0.015, rotor_radius=0.0635,
                    rotor_inertia=1.0e-6, hub_height=0.01, distance=3.0, speed=6.0,
                    low_hover=0.05, cruise_height=1.5, log_rate=500.0, pos_rate=100.0,
                    pos_noise=0.002, att_noise=0.003, gyro_noise=0.01, speed_quantum=1.0,
                    attitude_bandwidth=40.0, position_bandwidth=3.0, ctrl_rate=1000.0)
        base.update(kw)
        return cls(**base)

    @classmethod
    def deadcat_racer(cls, **kw: Any) -> "PeerVehicle":
        """The racer on a dead-cat frame: front hubs 10 cm to either side, back hubs 6 cm,
        7.5 cm fore and aft (Crazyflie order, spins as the square X's)."""
        return cls.racer(**{"rotor_xy": DEADCAT_XY, "arm": 0.11, **kw})

    @classmethod
    def h_frame_1kg(cls, **kw: Any) -> "PeerVehicle":
        """The 1.2 kg vehicle on an H: hubs at +-13 cm fore and aft, +-22 cm to the sides."""
        return cls.one_kg(**{"rotor_xy": H_FRAME_XY, "arm": 0.2555, **kw})

    @classmethod
    def px4_order_1kg(cls, **kw: Any) -> "PeerVehicle":
        """The 1.2 kg square X with its rotors in PX4's order (front-right, back-left,
        front-left, back-right) and spins (the first two counter-clockwise: +1)."""
        a = 0.225 / math.sqrt(2.0)
        return cls.one_kg(**{"rotor_xy": ((a, a), (-a, -a), (a, -a), (-a, a)), "spins": (1, 1, -1, -1), **kw})

    @classmethod
    def three_kg(cls, **kw: Any) -> "PeerVehicle":
        """A 3 kg vehicle, 15-inch propellers, a slower attitude loop, a 400 Hz log."""
        base = dict(name="peer_3kg", mass=3.0, inertia=(0.05, 0.055, 0.09), arm=0.35,
                    K_T=5.5e-5, b=1.2e-6, tau_motor=0.06, rotor_radius=0.19,
                    rotor_inertia=3.0e-4, hub_height=0.05, distance=1.5, speed=2.5,
                    low_hover=0.14, cruise_height=1.5, log_rate=400.0, pos_rate=50.0,
                    pos_noise=0.002, att_noise=0.003, gyro_noise=0.004, speed_quantum=2.0,
                    attitude_bandwidth=12.0, position_bandwidth=1.5, ctrl_rate=400.0)
        base.update(kw)
        return cls(**base)


@dataclass
class PeerBattery:
    """A battery and open-loop ESCs. The battery: open-circuit voltage ``v_full`` falling by
    ``drain`` volts per coulomb drawn, internal resistance ``r_int``; it supplies the rotors'
    aerodynamic power ``sum b g_i w_i^3`` divided by ``efficiency``, so its voltage is
    ``V = (V_oc + sqrt(V_oc^2 - 4 r_int P))/2``. Each motor: ``Ke w + c w^2 = duty V``
    (back-EMF plus a load torque in ``w^2`` through the winding), ``c w_h^2`` a share
    ``load_share`` of the drive at hover; the ESC's duty for a speed command ``w_cmd`` is
    the one that gives ``w_cmd`` at ``v_esc`` volts. The log gets ``vbat`` (noise
    ``vbat_noise`` V, rounded to ``vbat_quantum``)."""

    v_full: float = 4.15
    r_int: float = 0.15               # ohm
    drain: float = 0.004              # V per coulomb
    v_esc: float = 3.8                # V, the voltage the ESC's command-to-duty map assumes
    efficiency: float = 0.5           # aerodynamic over electrical power
    load_share: float = 0.5
    vbat_noise: float = 0.005
    vbat_quantum: float = 0.001


CABLE_STRETCH = 0.005
"""A slung load's cable stretches by this share of its length under the load's weight."""


@dataclass
class PeerEffects:
    """The physics beyond the rigid body, thrust and reaction torque; all off by default."""

    body_drag: Sequence[float] | None = None     # [Dx, Dy, Dz] N s/m, body frame, at the CoG
    world_drag: Sequence[float] | None = None    # [Dx, Dy, Dz] N s/m on the world-frame air velocity
    quad_drag: Sequence[float] | None = None     # [Cx, Cy, Cz] N s^2/m^2: F_b,j = -C_j |vb_j| vb_j per body
                                                 # axis (greybox's quadratic_drag: world axes, |v| v)
    rotor_drag: float = 0.0                      # k_rd: per-hub drag -k w_i P v_hub
    ground_effect: bool = False                  # Cheeseman-Bennett per rotor
    motor_gains: Sequence[float] | None = None   # per-rotor thrust and torque scale
    cog_offset: Sequence[float] | None = None    # CoG [dx, dy] from the rotor-plane centre, m
    wind: Sequence[float] | None = None          # world NED, m/s
    # outside greybox's catalogue
    rate_damping: Sequence[float] | None = None  # [Dp, Dq, Dr] N m s: M = -D omega
    flapping: float = 0.0                        # k_f N m s/m: M = k_f (e3 x v_b)
    inflow: float = 0.0                          # T_i (1 + k_in v_z,b), 1/(m/s)
    gyro_bias: Sequence[float] | None = None     # rad/s, added to the logged p, q, r
    turbulence: float = 0.0                      # N m, RMS of a random torque (1-s correlation)
    battery: PeerBattery | None = None           # voltage-driven motors behind open-loop ESCs; vbat logged
    slung_load: Sequence[float] | None = None    # [m_L kg, L m]: a point load on a cable from the CoG

    def active(self) -> dict[str, Any]:
        out = {}
        for k, v in asdict(self).items():
            if v is None or v is False or (not isinstance(v, (list, tuple, dict)) and v == 0):
                continue
            out[k] = list(v) if isinstance(v, (list, tuple)) else v
        return out


# ============================================================================ rotations
def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw])


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (body to world) of the unit quaternion ``q = [w, x, y, z]``."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def quat_from_yaw(psi: float) -> np.ndarray:
    return np.array([math.cos(psi / 2), 0.0, 0.0, math.sin(psi / 2)])


def rot_to_euler(R: np.ndarray) -> tuple[float, float, float]:
    """ZYX Euler angles (phi, theta, psi) of R = Rz(psi) Ry(theta) Rx(phi)."""
    return (math.atan2(R[2, 1], R[2, 2]), -math.asin(max(-1.0, min(1.0, R[2, 0]))),
            math.atan2(R[1, 0], R[0, 0]))


def euler_to_rot(phi: float, theta: float, psi: float) -> np.ndarray:
    """R = Rz(psi) Ry(theta) Rx(phi), body to world."""
    cf, sf, ct, st, cp, sp = (math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta),
                              math.cos(psi), math.sin(psi))
    return np.array([[cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf],
                     [sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf],
                     [-st, ct * sf, ct * cf]])


def vee(S: np.ndarray) -> np.ndarray:
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


# ============================================================================ dynamics
class PeerDynamics:
    """State ``s = [p(3), v(3), q(4), omega(3), w(4)]`` (17)."""

    def __init__(self, veh: PeerVehicle, fx: PeerEffects, rng: np.random.Generator):
        self.veh, self.fx = veh, fx
        cog = np.zeros(3)
        if fx.cog_offset is not None:
            cog[:len(fx.cog_offset)] = fx.cog_offset
        self.hubs = veh.rotor_positions() + np.array([0.0, 0.0, -veh.hub_height]) - cog
        self.spin = np.asarray(veh.spins, float)
        self.gain = np.ones(4) if fx.motor_gains is None else np.asarray(fx.motor_gains, float)
        self.J, self.Jinv = veh.J, np.linalg.inv(veh.J)
        self.wind = np.zeros(3) if fx.wind is None else np.asarray(
            list(fx.wind) + [0.0] * (3 - len(fx.wind)), float)
        self.body_drag = None if fx.body_drag is None else np.asarray(fx.body_drag, float)
        self.world_drag = None if fx.world_drag is None else np.asarray(fx.world_drag, float)
        self.quad_drag = None if fx.quad_drag is None else np.asarray(fx.quad_drag, float)
        self.rate_damping = None if fx.rate_damping is None else np.asarray(fx.rate_damping, float)
        self.ge = (veh.rotor_radius / 4.0) ** 2
        self.disturbance = np.zeros(3)          # turbulence torque, updated by the simulator
        if fx.slung_load is not None:
            # a stiff, damped cable (CABLE_STRETCH under the load's weight, half-critical
            # axial damping) and air drag on the load (its swing decays over a few seconds)
            m_l, length = (float(x) for x in fx.slung_load)
            k = m_l * veh.gravity / (CABLE_STRETCH * length)
            self.cable = (m_l, length, k, math.sqrt(k * m_l), m_l / 2.0)
        self.charge = 0.0                       # C drawn from the battery, updated by the simulator
        if fx.battery is not None:
            w_h, lam = veh.w_hover, fx.battery.load_share
            self.Ke, self.c = (1.0 - lam) / w_h, lam / w_h ** 2     # drive in units of the hover drive

    def battery_voltage(self, w: np.ndarray) -> tuple[float, float]:
        """The battery's terminal voltage and current with the rotors at ``w``."""
        bat = self.fx.battery
        v_oc = bat.v_full - bat.drain * self.charge
        power = self.veh.b * float(self.gain @ np.abs(w) ** 3) / bat.efficiency
        v = 0.5 * (v_oc + math.sqrt(max(v_oc * v_oc - 4.0 * bat.r_int * power, 0.0)))
        return v, power / v

    def motor_speed(self, w_cmd, v: float):
        """The steady speed of a motor commanded to ``w_cmd`` with the battery at ``v`` volts:
        the root of ``Ke w + c w^2 = duty V`` for the duty the ESC sets (``w_cmd`` at ``v_esc``)."""
        drive = (self.Ke * w_cmd + self.c * w_cmd * w_cmd) * v / self.fx.battery.v_esc
        return (-self.Ke + np.sqrt(self.Ke ** 2 + 4.0 * self.c * np.maximum(drive, 0.0))) / (2.0 * self.c)

    def hover_speed_ratio(self, v: float) -> float:
        """``w / w_cmd`` of a motor commanded to the hover speed with the battery at ``v``
        volts (1 at the ESC's voltage)."""
        return float(self.motor_speed(self.veh.w_hover, v)) / self.veh.w_hover

    def motor_target(self, w_cmd: np.ndarray, w: np.ndarray) -> np.ndarray:
        """The speed each motor tends to: ``w_cmd`` itself, or with a battery
        :meth:`motor_speed` at the voltage the rotors at ``w`` leave."""
        if self.fx.battery is None:
            return w_cmd
        return self.motor_speed(w_cmd, self.battery_voltage(w)[0])

    def cable_force(self, s: np.ndarray) -> np.ndarray:
        """The slung load's cable's pull on the vehicle (world, N): along the cable towards the
        load while it is taut, zero while slack."""
        m_l, length, k, c, _ = self.cable
        d, dv = s[17:20] - s[0:3], s[20:23] - s[3:6]
        dist = float(np.linalg.norm(d))
        n = d / max(dist, 1e-9)
        tension = k * (dist - length) + c * float(n @ dv)
        return max(tension, 0.0) * n if dist > length else np.zeros(3)

    def loads(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World acceleration of the CoG and the body moment (without the gyroscopic terms)."""
        veh, fx = self.veh, self.fx
        p, v, q, om, w = s[0:3], s[3:6], s[6:10], s[10:13], s[13:17]
        R = quat_to_rot(q)
        w2 = w * w
        T = veh.K_T * self.gain * w2
        vb = R.T @ (v - self.wind)
        if fx.inflow:
            T = T * (1.0 + fx.inflow * vb[2])
        if fx.ground_effect:
            h = -(p[2] + R[2] @ self.hubs.T)           # floor at world z = 0
            ratio = np.minimum(self.ge / np.maximum(h, 1e-6) ** 2, 0.25)
            T = T / (1.0 - ratio)
        F = np.array([0.0, 0.0, -T.sum()])
        M = np.array([-(self.hubs[:, 1] @ T), self.hubs[:, 0] @ T,
                      veh.b * (self.spin * self.gain) @ w2])
        if fx.rotor_drag:
            v_hub = vb + np.cross(om, self.hubs)       # (4, 3)
            Fi = -fx.rotor_drag * w[:, None] * v_hub
            Fi[:, 2] = 0.0
            F = F + Fi.sum(axis=0)
            M = M + np.cross(self.hubs, Fi).sum(axis=0)
        if self.body_drag is not None:
            F = F - self.body_drag * vb
        if self.world_drag is not None:
            # another form of the same drag: diagonal in the world's axes, not the body's
            F = F - R.T @ (self.world_drag * (v - self.wind))
        if self.quad_drag is not None:
            F = F - self.quad_drag * np.abs(vb) * vb
        if self.rate_damping is not None:
            M = M - self.rate_damping * om
        if fx.flapping:
            M = M + fx.flapping * np.array([-vb[1], vb[0], 0.0])
        M = M + self.disturbance
        acc = veh.gravity * E3 + R @ F / veh.mass
        if fx.slung_load is not None:
            acc = acc + self.cable_force(s) / veh.mass
        return acc, M

    def rhs(self, s: np.ndarray, w_cmd: np.ndarray) -> np.ndarray:
        v, q, om, w = s[3:6], s[6:10], s[10:13], s[13:17]
        acc, M = self.loads(s)
        h = np.array([0.0, 0.0, -self.veh.rotor_inertia * (self.spin @ w)])
        omdot = self.Jinv @ (M - np.cross(om, self.J @ om + h))
        qdot = 0.5 * quat_mul(q, np.array([0.0, om[0], om[1], om[2]]))
        wdot = (self.motor_target(w_cmd, w) - w) / self.veh.tau_motor
        if self.fx.slung_load is None:
            return np.concatenate([v, acc, qdot, omdot, wdot])
        m_l, *_, drag = self.cable
        acc_load = self.veh.gravity * E3 - (self.cable_force(s) + drag * s[20:23]) / m_l
        return np.concatenate([v, acc, qdot, omdot, wdot, s[20:23], acc_load])

    def rk4(self, s: np.ndarray, w_cmd: np.ndarray, dt: float) -> np.ndarray:
        k1 = self.rhs(s, w_cmd)
        k2 = self.rhs(s + 0.5 * dt * k1, w_cmd)
        k3 = self.rhs(s + 0.5 * dt * k2, w_cmd)
        k4 = self.rhs(s + dt * k3, w_cmd)
        out = s + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[6:10] /= np.linalg.norm(out[6:10])
        return out


# ============================================================================ reference
def _quintic(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u ** 3 * (10 - 15 * u + 6 * u * u)


class FlightPlan:
    """Position and yaw references: minimum-jerk moves between waypoints, plus figure
    eights whose amplitude fades in and out smoothly. Derivatives by central differences of
    the smooth reference (it has continuous second derivatives)."""

    def __init__(self, veh: PeerVehicle, duration: float, rng: np.random.Generator,
                 low_hovers: bool):
        d, H = veh.distance, veh.cruise_height
        low_z = -(veh.low_hover + veh.hub_height)          # CoG z of a low pass's reference
        sx, sy = rng.choice([-1.0, 1.0], size=2)
        # (duration of the move, target x, y, z, psi), each followed by a hold
        legs: list[tuple[float, float, float, float, float, float]] = []
        legs.append((1.0, 0, 0, -H, 0.0, 0.5))
        if low_hovers:                       # the first low hover
            legs += [(2.0, 0, 0, low_z, 0.0, 1.5), (1.5, 0, 0, -H, 0.0, 0.3)]
        # a figure eight (its amplitude fades in and out), flown about the current waypoint
        period = 2 * math.pi * d / veh.speed * 1.2
        length = max(2 * period, 6.0)
        t = sum(m + h for m, *_, h in legs)
        self.eight = [(t, length, d, period)]    # (start, length, amplitude, period)
        legs.append((length, 0, 0, -H, 0.0, 0.3))
        legs += [(1.4, sx * d, 0, -H, 0.0, 0.3), (1.4, sx * d, sy * d, -H * 1.2, 0.0, 0.3),
                 (1.6, 0, 0, -H, 1.2 * sx, 0.5), (1.4, -sx * d, -sy * d * 0.5, -H * 0.8, 0.4 * sx, 0.3)]
        if low_hovers and duration > 30:     # the second low hover, off centre and yawed
            legs += [(2.0, 0.3 * d * sx, 0, low_z, 0.6 * sy, 1.5), (1.5, 0, 0, -H, 0.0, 0.3)]
        # fill the rest with random steps and yaw turns
        while sum(m + h for m, *_, h in legs) < duration + 2:
            x, y = rng.uniform(-d, d, size=2)
            legs.append((1.6, x, y, -H * rng.uniform(0.8, 1.3), rng.uniform(-1.5, 1.5), 0.4))
        self.knots = []
        t0, prev = 0.0, np.array([0.0, 0.0, -H, 0.0])
        for move, x, y, z, psi, hold in legs:
            target = np.array([x, y, z, psi], float)
            self.knots.append((t0, move, prev, target))
            t0 += move + hold
            prev = target
        self.start = np.array([0.0, 0.0, -H, 0.0])

    def pose(self, t: float) -> np.ndarray:
        out = self.start.copy()
        for t0, move, a, b in self.knots:
            if t < t0:
                break
            out = a + (b - a) * float(_quintic(np.array((t - t0) / move)))
        for t0, length, amp, period in self.eight:
            if t0 <= t <= t0 + length:
                env = float(_quintic(np.array((t - t0) / 1.5)) * _quintic(np.array((t0 + length - t) / 1.5)))
                om = 2 * math.pi / period
                out = out + env * np.array([amp * math.sin(om * (t - t0)),
                                            0.5 * amp * math.sin(2 * om * (t - t0)), 0.0, 0.0])
        return out

    def reference(self, t: float, eps: float = 2e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        a, b, c = self.pose(t - eps), self.pose(t), self.pose(t + eps)
        vel = (c - a) / (2 * eps)
        acc = (c - 2 * b + a) / eps ** 2
        return b[:3], vel[:3], acc[:3], float(b[3])


# ============================================================================ controller
class GeometricController:
    """Lee-Leok-McClamroch tracking on SE(3), NED: ``-f R e3 = m (a_d - g e3) - k_x e_x -
    k_v e_v - k_i int e_x``; attitude ``M = -k_R e_R - k_W omega + omega x J omega``. Its
    internal model (mass, inertia, K_T, b) is off by a few per cent: a controller knows its
    vehicle only roughly, and the integral trims the rest. It reads the true state (the
    attitude as the estimator reports it when that is biased)."""

    def __init__(self, veh: PeerVehicle, rng: np.random.Generator):
        self.veh = veh
        off = lambda s: 1.0 + rng.uniform(-s, s)          # noqa: E731
        self.m = veh.mass * off(0.05)
        self.J = veh.J * off(0.15)
        self.K_T = veh.K_T * off(0.08)
        self.b = veh.b * off(0.2)
        wa, wp = veh.attitude_bandwidth, veh.position_bandwidth
        self.band = band = np.array([wa, wa, wa / 3])   # yaw: a third of the bandwidth
        self.kR = np.diag(self.J) * band ** 2
        self.kW = np.diag(self.J) * 2 * 0.8 * band
        self.kx = self.m * wp ** 2
        self.kv = self.m * 2 * 0.9 * wp
        self.ki = self.m * 0.3 * wp ** 3
        self.ix = np.zeros(3)
        P = veh.rotor_positions()
        spin = np.asarray(veh.spins, float)
        # [f, Mx, My, Mz] = A T  with T_i the rotor thrusts
        self.A = np.vstack([np.ones(4), -P[:, 1], P[:, 0], spin * self.b / self.K_T])
        self.Ainv = np.linalg.inv(self.A)
        w_h = math.sqrt(self.m * veh.gravity / (4 * self.K_T))
        self.T_min = self.K_T * (0.2 * w_h) ** 2
        self.T_max = self.K_T * (1.8 * w_h) ** 2

    def __call__(self, p, v, R, om, ref, dt: float) -> np.ndarray:
        pd, vd, ad, psid = ref
        ex, ev = p - pd, v - vd
        self.ix = np.clip(self.ix + ex * dt, -0.5, 0.5)
        A = -self.kx * ex - self.kv * ev - self.ki * self.ix + self.m * (ad - self.veh.gravity * E3)
        f, eR = self.thrust_and_attitude_error(A, R, psid)
        M = -self.kR * eR - self.kW * om + np.cross(om, self.J @ om)
        return self.mix(f, M)

    @staticmethod
    def thrust_and_attitude_error(A: np.ndarray, R: np.ndarray, psid: float) -> tuple[float, np.ndarray]:
        """The collective thrust ``f`` for the thrust force ``A`` wanted (N, NED: ``-f R e3``
        is the rotors' force, so the body's -z must point along ``A``), and the attitude error
        to the attitude that points it so with heading ``psid``."""
        b3d = -A / np.linalg.norm(A)
        f = float(-A @ R[:, 2])
        b1c = np.array([math.cos(psid), math.sin(psid), 0.0])
        b2d = np.cross(b3d, b1c)
        b2d /= np.linalg.norm(b2d)
        Rd = np.column_stack([np.cross(b2d, b3d), b2d, b3d])
        return f, 0.5 * vee(Rd.T @ R - R.T @ Rd)

    def mix(self, f: float, M: np.ndarray) -> np.ndarray:
        """Rotor speeds for thrust ``f`` and moment ``M``; yaw has the lowest priority: its
        moment is scaled down until no rotor saturates."""
        T0 = self.Ainv @ np.array([f, M[0], M[1], 0.0])
        Ty = self.Ainv[:, 3] * M[2]
        k = 1.0
        for t0, ty in zip(T0, Ty):
            if ty > 0 and t0 + ty > self.T_max:
                k = min(k, max((self.T_max - t0) / ty, 0.0))
            elif ty < 0 and t0 + ty < self.T_min:
                k = min(k, max((self.T_min - t0) / ty, 0.0))
        T = np.clip(T0 + k * Ty, self.T_min, self.T_max)
        return np.sqrt(T / self.K_T)


class CascadedPID(GeometricController):
    """The cascade of PX4's and the Crazyflie firmware's multicopter controllers, run on what
    the vehicle *measures*: position P -> velocity PI (with the reference's velocity and
    acceleration fed forward) -> the thrust vector and the attitude pointing it -> attitude P
    -> body-rate PID (integral; D on the measured rate) -> the same mixer.

    What differs from :class:`GeometricController`, on purpose: the gyro it reads is noisy
    (the log's ``gyro_noise``, its own draws at the control rate; a ``gyro_bias`` as the log
    has it) and low-pass filtered, and
    the rate loop's D term differentiates it, so the commands carry the gyro's noise; the
    position and velocity it reads are an estimate off by slow errors (AR(1), 0.2 s: position
    by ``pos_noise``, velocity by ten times that per second, at most 5 cm/s); the integral
    sits on the body rates, so a steady torque (a weak rotor, a CoG offset) is trimmed by the
    rate loop, not through the position; no ``omega x J omega`` feed-forward. Its attitude
    loop without the rate integral and D (rate gain ``1.6 w_a``, attitude gain ``w_a / 1.6``)
    is the geometric controller's linear one, so both fly every vehicle; its position loop
    has the same proportional and damping gains, its integral on the velocity. The attitude it
    reads is the true one (with ``att_bias``, as the geometric controller's), not the log's
    noisy one. The same four draws of the controller's model error
    are taken from ``rng`` (a flight's other draws stay those of its seed); its sensor noise
    comes from ``noise_rng``."""

    def __init__(self, veh: PeerVehicle, rng: np.random.Generator, noise_rng: np.random.Generator,
                 gyro_bias: Sequence[float] | None = None):
        super().__init__(veh, rng)
        self.noise = noise_rng
        self.gyro_bias = np.zeros(3) if gyro_bias is None else np.asarray(gyro_bias, float)
        band, wp = self.band, veh.position_bandwidth
        self.k_rate = 1.6 * band                      # 1/s
        self.k_rate_i = 0.1 * self.k_rate ** 2        # 1/s^2
        self.k_rate_d = 0.05                          # s/s: D on the measured rate
        self.k_att = band / 1.6                       # 1/s
        self.k_pos = wp / 1.8                         # 1/s
        self.k_vel = 1.8 * wp                         # 1/s
        self.k_vel_i = 0.54 * wp ** 2                 # 1/s^2
        self.gyro_cutoff = min(2 * math.pi * 80.0, 2 * math.pi * veh.ctrl_rate / 6)   # rad/s
        self.om_f: np.ndarray | None = None
        self.i_rate = np.zeros(3)
        self.i_vel = np.zeros(3)
        self.e_pos = np.zeros(3)
        self.e_vel = np.zeros(3)

    def __call__(self, p, v, R, om, ref, dt: float) -> np.ndarray:
        veh, rng = self.veh, self.noise
        # the estimate: slow errors on position and velocity, a noisy gyro through its low-pass
        a = math.exp(-dt / 0.2)
        s_v = min(10.0 * veh.pos_noise, 0.05)
        self.e_pos = a * self.e_pos + math.sqrt(1 - a * a) * veh.pos_noise * rng.standard_normal(3)
        self.e_vel = a * self.e_vel + math.sqrt(1 - a * a) * s_v * rng.standard_normal(3)
        gyro = om + self.gyro_bias + veh.gyro_noise * rng.standard_normal(3)
        prev = self.om_f if self.om_f is not None else gyro
        self.om_f = prev + (1 - math.exp(-self.gyro_cutoff * dt)) * (gyro - prev)
        dom = (self.om_f - prev) / dt
        pd, vd, ad, psid = ref
        v_sp = vd + self.k_pos * (pd - (p + self.e_pos))
        e_v = v_sp - (v + self.e_vel)
        self.i_vel = np.clip(self.i_vel + e_v * dt, -1.0, 1.0)
        acc = ad + self.k_vel * e_v + self.k_vel_i * self.i_vel
        A = self.m * (acc - veh.gravity * E3)
        f, eR = self.thrust_and_attitude_error(A, R, psid)
        om_sp = -self.k_att * eR
        e_om = om_sp - self.om_f
        self.i_rate = np.clip(self.i_rate + e_om * dt, -1.0, 1.0)
        alpha = self.k_rate * e_om + self.k_rate_i * self.i_rate - self.k_rate_d * dom
        return self.mix(f, np.diag(self.J) * alpha)


CONTROLLERS = ("geometric", "cascaded_pid")


# ============================================================================ flight
@dataclass
class PeerSensors:
    pos_dropout: float = 0.05            # probability a vision sample is lost
    pos_gaps: Sequence[tuple[float, float]] = ((0.45, 0.4),)   # (start as a fraction of the flight, length s): vision lost
    time_jitter: float = 0.1             # of a sample period, uniform
    accel: bool = False
    accel_noise: float = 0.05
    accel_bias: Sequence[float] | None = None   # m/s^2, added to the logged ax, ay, az
    log_commands: bool = False           # log the controller's speed commands (as a PWM log does), not the ESCs' speeds
    speed_noise: float = 0.0             # relative white noise on the logged speeds (an ESC's telemetry)
    att_correlation: float = 0.0         # s; > 0: the attitude noise (same RMS) is correlated over this time,
                                         # as an estimator's output is (AR(1) of the same draws)
    att_bias: Sequence[float] | None = None   # rad: the estimator's roll and pitch are off by these (a
                                         # miscalibrated level reference); the controller levels that
                                         # estimate, and the log reports it
    pos_delay: float = 0.0               # s: the logged position is the vehicle's this long before
                                         # its time stamp (a vision pipeline's latency)
    log_setpoints: bool = False          # log the flight plan's position and yaw (x_ref, y_ref, z_ref,
                                         # psi_ref), as an autopilot logs its targets


@dataclass
class PeerFlight:
    columns: dict[str, np.ndarray]       # the log, column by column (NaN: not measured)
    truth: dict[str, Any]
    states: np.ndarray = field(repr=False, default=None)   # true states at the log's rows


def fly(vehicle: PeerVehicle, duration: float = 20.0, seed: int = 0,
        effects: PeerEffects | None = None, sensors: PeerSensors | None = None,
        low_hovers: bool = True, controller: str = "geometric") -> PeerFlight:
    """Fly ``vehicle`` along its flight plan under ``controller`` (``"geometric"``: on the true
    state; ``"cascaded_pid"``: an autopilot's cascade on the measured state) and log it."""
    if controller not in CONTROLLERS:
        raise ValueError(f"controller must be one of {CONTROLLERS}, got {controller!r}")
    veh, fx = vehicle, effects or PeerEffects()
    sens = sensors or PeerSensors()
    rng = np.random.default_rng(seed)
    dyn = PeerDynamics(veh, fx, rng)
    ctrl = (GeometricController(veh, rng) if controller == "geometric"
            else CascadedPID(veh, rng, np.random.default_rng([seed, 11]), fx.gyro_bias))
    plan = FlightPlan(veh, duration, rng, low_hovers)
    # integration step: the log's period split so that steps stay below 1 ms
    log_dt = 1.0 / veh.log_rate
    sub = max(1, math.ceil(log_dt / 1e-3))
    dt = log_dt / sub
    ctrl_every = max(1, round(1.0 / (veh.ctrl_rate * dt)))
    # start in a trimmed hover at the plan's first pose
    p0 = plan.start[:3].copy()
    s = np.concatenate([p0, np.zeros(3), quat_from_yaw(0.0), np.zeros(3), np.full(4, veh.w_hover)])
    if fx.slung_load is not None:
        # the load hanging at rest below the vehicle, the cable stretched by its weight
        s = np.concatenate([s, p0 + np.array([0.0, 0.0, (1.0 + CABLE_STRETCH) * fx.slung_load[1]]), np.zeros(3)])
    warm = 2.0                                   # s flown before logging: the integral settles
    n_warm = int(round(warm / dt))
    n = int(round(duration / log_dt))
    states = np.empty((n, len(s)))
    commands = np.empty((n, 4))                  # the command the motors are receiving at each logged row
    volts = np.empty(n)                          # the battery's voltage at each logged row
    w_cmd = np.full(4, veh.w_hover)
    turb_tau = 1.0
    for k in range(-n_warm, n * sub):
        t = k * dt
        if k % ctrl_every == 0:
            R = quat_to_rot(s[6:10])
            if sens.att_bias is not None:
                # the controller acts on the estimator's attitude, which is off by the bias
                phi, theta, psi = rot_to_euler(R)
                R = euler_to_rot(phi + sens.att_bias[0], theta + sens.att_bias[1], psi)
            w_cmd = ctrl(s[0:3], s[3:6], R, s[10:13], plan.reference(max(t, 0.0)), ctrl_every * dt)
            if fx.turbulence:
                a = math.exp(-ctrl_every * dt / turb_tau)
                dyn.disturbance = a * dyn.disturbance + math.sqrt(1 - a * a) * fx.turbulence * rng.standard_normal(3)
        if k >= 0 and k % sub == 0:
            states[k // sub] = s
            commands[k // sub] = w_cmd
        if fx.battery is not None and k >= 0:
            volt, current = dyn.battery_voltage(s[13:17])
            if k % sub == 0:
                volts[k // sub] = volt
            dyn.charge += current * dt
        s = dyn.rk4(s, w_cmd, dt)
        if not np.all(np.isfinite(s)):
            raise RuntimeError(f"peer_sim: the flight diverged at t = {t:.3f} s")
    t_log = np.arange(n) * log_dt
    # the log's time stamps: the sample instants with a little jitter, still increasing
    jitter = rng.uniform(-0.5, 0.5, n) * sens.time_jitter * log_dt
    t_stamp = t_log + jitter
    t_stamp[0] = 0.0
    cols: dict[str, np.ndarray] = {"t": t_stamp}
    w = commands.copy() if sens.log_commands else states[:, 13:17].copy()
    if sens.speed_noise:
        # drawn from its own stream: the flight's other noise stays that of the same seed without it
        w = w * (1 + sens.speed_noise * np.random.default_rng([seed, 7]).standard_normal(w.shape))
    if veh.speed_quantum and not sens.log_commands:
        w = np.round(w / veh.speed_quantum) * veh.speed_quantum
    for i in range(4):
        cols[f"w{i + 1}"] = w[:, i]
    eul = np.array([rot_to_euler(quat_to_rot(q)) for q in states[:, 6:10]])
    pos = states[:, 0:3]
    if sens.pos_delay:
        # the position of pos_delay before each row's sample instant (held at the first row before the log)
        pos = np.column_stack([np.interp(t_log - sens.pos_delay, t_log, pos[:, j]) for j in range(3)])
    pos = pos + veh.pos_noise * rng.standard_normal((n, 3))
    # vision: every log_rate/pos_rate-th row, some lost, stretches lost
    keep = np.zeros(n, bool)
    step = veh.log_rate / veh.pos_rate
    idx = np.unique(np.round(np.arange(0, n, step)).astype(int))
    idx = idx[idx < n]
    keep[idx] = rng.random(idx.size) >= sens.pos_dropout
    for start, length in sens.pos_gaps:
        t0 = start * duration
        keep[(t_log >= t0) & (t_log < t0 + length)] = False
    for j, name in enumerate("xyz"):
        cols[name] = np.where(keep, pos[:, j], np.nan)
    att_err = veh.att_noise * rng.standard_normal((n, 3))
    if sens.att_correlation > 0:
        rho = math.exp(-log_dt / sens.att_correlation)
        for k in range(1, n):
            att_err[k] = rho * att_err[k - 1] + math.sqrt(1 - rho * rho) * att_err[k]
    att = eul + att_err
    if sens.att_bias is not None:
        att[:, :2] += np.asarray(sens.att_bias, float)
    att[:, 2] = (att[:, 2] + math.pi) % (2 * math.pi) - math.pi
    for j, name in enumerate(("phi", "theta", "psi")):
        cols[name] = att[:, j]
    bias = np.zeros(3) if fx.gyro_bias is None else np.asarray(fx.gyro_bias, float)
    gyro = states[:, 10:13] + bias + veh.gyro_noise * rng.standard_normal((n, 3))
    for j, name in enumerate("pqr"):
        cols[name] = gyro[:, j]
    if fx.battery is not None:
        bat = fx.battery
        vb = volts + bat.vbat_noise * rng.standard_normal(n)
        cols["vbat"] = np.round(vb / bat.vbat_quantum) * bat.vbat_quantum
    if sens.accel:
        acc = np.empty((n, 3))
        for k in range(n):
            a, _ = dyn.loads(states[k])
            acc[k] = quat_to_rot(states[k, 6:10]).T @ (a - veh.gravity * E3)
        acc += sens.accel_noise * rng.standard_normal((n, 3))
        if sens.accel_bias is not None:
            acc += np.asarray(sens.accel_bias, float)
        for j, name in enumerate(("ax", "ay", "az")):
            cols[name] = acc[:, j]
    if sens.log_setpoints:
        # the plan draws nothing at this point: the flight is the same with or without them
        refs = np.array([np.append(ref[0], ref[3]) for ref in map(plan.reference, t_log)])
        for j, name in enumerate(("x_ref", "y_ref", "z_ref", "psi_ref")):
            cols[name] = refs[:, j]
    truth = _truth(veh, fx, sens, seed, duration, dyn, ctrl, volts)
    truth["controller"] = controller
    truth["greybox_flown"] = _flown_equivalent(veh, fx, dyn, states)
    return PeerFlight(columns=cols, truth=truth, states=states)


def _flown_equivalent(veh: PeerVehicle, fx: PeerEffects, dyn: PeerDynamics, states: np.ndarray) -> dict[str, Any]:
    """greybox's parameters for this simulator's effects whose form is not greybox's, as
    the least-squares fit of greybox's force to the true one along the flown states (the
    truth a fit can reach on this flight; ``greybox_equivalent`` holds the nominal values):

    * ``Kq`` (and ``Kd``): greybox's ``-Kd_j v_j - Kq_j |v| v_j`` on world axes (the base
      model's linear drag beside the quadratic one) against the simulator's body-axis
      ``-C_j |vb_j| vb_j``: ``Kq_j = C_j`` in a level straight pass along one axis, smaller
      where the flight moves diagonally;
    * ``k_ge`` with the hubs at their height above the CoG, and ``k_ge_hubs_at_cog`` with them
      in the CoG's plane (an airframe without rotor heights): greybox's ``1/(1 - k/h^2)``
      (capped at 0.5) against the simulator's (capped at 0.25), in the total thrust.
    """
    out: dict[str, Any] = {}
    R = np.array([quat_to_rot(q) for q in states[:, 6:10]])
    v = states[:, 3:6]
    if dyn.quad_drag is not None:
        v_air = v - dyn.wind
        vb = np.einsum("kji,kj->ki", R, v_air)                     # R^T v per row
        force = -np.einsum("kij,kj->ki", R, dyn.quad_drag * np.abs(vb) * vb)
        speed = np.linalg.norm(v_air, axis=1)
        # per world axis, greybox's linear drag beside it (the base model's Kd takes its share)
        fits = [np.linalg.lstsq(np.column_stack([-v_air[:, j], -speed * v_air[:, j]]), force[:, j], rcond=None)[0]
                for j in range(3)]
        out["Kd"] = [float(f[0]) for f in fits]
        out["Kq"] = [float(f[1]) for f in fits]
    if fx.ground_effect:
        from scipy.optimize import minimize_scalar
        thrust = veh.K_T * dyn.gain * states[:, 13:17] ** 2                 # (n, 4)
        up = R[:, 2, :]                                                      # world z of body axes
        h_true = -(states[:, 2:3] + up @ dyn.hubs.T)
        true_total = (thrust / (1.0 - np.minimum(dyn.ge / np.maximum(h_true, 1e-6) ** 2, 0.25))).sum(axis=1)

        def fitted(hubs: np.ndarray) -> float:
            h = np.maximum(-(states[:, 2:3] + up @ hubs.T), 1e-3)

            def cost(k: float) -> float:
                model = (thrust / (1.0 - np.minimum(k / h ** 2, 0.5))).sum(axis=1)
                return float(np.sum((model - true_total) ** 2))
            return float(minimize_scalar(cost, bounds=(0.0, 4.0 * dyn.ge), method="bounded",
                                         options={"xatol": 1e-4 * dyn.ge}).x)
        planar = veh.rotor_positions()        # the airframe's hubs: the CoG's plane, around the CoG
        out["k_ge"] = fitted(planar + np.array([0.0, 0.0, -veh.hub_height]))
        out["k_ge_hubs_at_cog"] = fitted(planar)
    return out


def _truth(veh, fx, sens, seed, duration, dyn, ctrl, volts) -> dict[str, Any]:
    gains = dyn.gain
    mean_gain = float(gains.mean())
    eq: dict[str, Any] = {"K_T": veh.K_T * mean_gain, "b": veh.b * mean_gain,
                          "J_r": veh.rotor_inertia}
    if fx.body_drag is not None:
        eq["Kd"] = [float(x) for x in fx.body_drag]
    if fx.world_drag is not None:
        eq["Kd"] = [float(x) for x in fx.world_drag]    # what a level flight sees of it
    if fx.rotor_drag:
        eq["k_rdh"] = fx.rotor_drag
    if fx.quad_drag is not None:
        eq["Kq"] = [float(x) for x in fx.quad_drag]     # what a level flight sees of it, per axis
    if fx.ground_effect:
        eq["k_ge"] = (veh.rotor_radius / 4.0) ** 2
    if fx.motor_gains is not None:
        eq["K_T_dev"] = [float(g / mean_gain - 1.0) for g in gains]
    if fx.cog_offset is not None:
        eq["r_cog"] = [float(x) for x in fx.cog_offset][:2]
    if fx.wind is not None:
        eq["wind"] = [float(x) for x in fx.wind]
    if sens.log_commands:
        eq["tau_m"] = veh.tau_motor
    if sens.log_commands and fx.battery is not None:
        # greybox's battery_voltage: w = w_log (1 + K_vbat (vbat - 4 V)). Its K_T and b are
        # those at 4 V, and K_vbat gives the truth's log-slope of the hover speed at the
        # flight's mean voltage
        at_4v = dyn.hover_speed_ratio(4.0) ** 2
        eq["K_T"], eq["b"] = eq["K_T"] * at_4v, eq["b"] * at_4v
        v = float(np.mean(volts))
        slope = (math.log(dyn.hover_speed_ratio(v + 0.01)) - math.log(dyn.hover_speed_ratio(v - 0.01))) / 0.02
        eq["K_vbat"] = slope / (1.0 + slope * (4.0 - v))
    if sens.att_bias is not None:
        eq["att_bias"] = [float(x) for x in sens.att_bias]
    if sens.pos_delay:
        eq["tau_pos"] = float(sens.pos_delay)
    if sens.accel and sens.accel_bias is not None:
        eq["acc_bias"] = [float(x) for x in sens.accel_bias]
    if fx.slung_load is not None:
        eq["mass"] = veh.mass + float(fx.slung_load[0])    # what the user weighs: vehicle and load
    return {"simulator": "peer_sim", "vehicle": asdict(veh), "effects": fx.active(),
            "sensors": asdict(sens), "seed": seed, "duration": duration,
            "greybox_equivalent": eq,
            "controller_model": {"mass": ctrl.m, "K_T": ctrl.K_T, "b": ctrl.b}}


# ============================================================================ files
def airframe_text(veh: PeerVehicle, *, K_T_factor: float = 1.4, b_factor: float = 0.6,
                  Kd: float | None = None, name: str | None = None, hub_heights: bool = False,
                  mass: float | None = None) -> str:
    """The airframe a user would write: true mass (``mass``: what the user weighs, when it is
    not the vehicle's alone), inertia, rotor tables (hubs in the
    rotor plane, height unknown; ``hub_heights``: at their measured height above the centre
    of gravity, body z = -hub_height) and starting guesses ``K_T * K_T_factor``,
    ``b * b_factor``, ``Kd`` (default ``0.05 * mass`` per axis)."""
    mass = veh.mass if mass is None else mass
    kd = 0.05 * mass if Kd is None else Kd
    hub_z = -veh.hub_height if hub_heights else 0.0
    lines = ["[airframe]", f'name = "{name or veh.name}"', f"mass = {mass!r}",
             f"inertia = [{', '.join(repr(float(x)) for x in veh.inertia)}]",
             f"arm_length = {veh.arm!r}", f"rotor_inertia = {veh.rotor_inertia!r}",
             f"gravity = {veh.gravity!r}", ""]
    for pos, spin in zip(veh.rotor_positions(), veh.spins):
        lines += ["[[rotor]]", f"position = [{float(pos[0])!r}, {float(pos[1])!r}, {hub_z!r}]", f"spin = {int(spin)}", ""]
    lines += ["[parameters]", f"K_T = {veh.K_T * K_T_factor!r}", f"b = {veh.b * b_factor!r}",
              f"Kd = [{kd!r}, {kd!r}, {kd!r}]", ""]
    return "\n".join(lines)


def write_log_csv(columns: dict[str, np.ndarray], path: str | Path) -> Path:
    """The flight log CSV of the contract, written by this module (NaN: an empty cell)."""
    path = Path(path)
    names = list(columns)
    data = np.column_stack([columns[k] for k in names])
    with open(path, "w") as f:
        f.write(",".join(names) + "\n")
        for row in data:
            f.write(",".join("" if not np.isfinite(x) else repr(float(x)) for x in row) + "\n")
    return path


def write_case(flight: PeerFlight, directory: str | Path, name: str = "flight",
               **airframe_kw: Any) -> dict[str, Path]:
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    veh = PeerVehicle(**flight.truth["vehicle"])
    # the user weighs what flies: with a slung load, vehicle and load together
    airframe_kw.setdefault("mass", flight.truth["greybox_equivalent"].get("mass"))
    out = {"log": write_log_csv(flight.columns, d / f"{name}.csv"),
           "airframe": d / "airframe.toml", "truth": d / f"{name}_truth.json"}
    out["airframe"].write_text(airframe_text(veh, **airframe_kw))
    out["truth"].write_text(json.dumps(flight.truth, indent=2, default=float))
    return out


VEHICLES = {"crazyflie": PeerVehicle.crazyflie, "one_kg": PeerVehicle.one_kg,
            "three_kg": PeerVehicle.three_kg, "racer": PeerVehicle.racer}


def _main(argv: Sequence[str] | None = None) -> int:
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", choices=sorted(VEHICLES), default="crazyflie")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--effects", default="", help="JSON object of PeerEffects fields")
    ap.add_argument("--sensors", default="", help='JSON object of PeerSensors fields, e.g. {"att_bias": [0.03, -0.02]}')
    ap.add_argument("--no-low-hovers", action="store_true")
    ap.add_argument("--controller", choices=CONTROLLERS, default="geometric")
    ap.add_argument("--out", required=True)
    ap.add_argument("--name", default="flight")
    a = ap.parse_args(argv)
    fx = PeerEffects(**json.loads(a.effects)) if a.effects else PeerEffects()
    sens = PeerSensors(**json.loads(a.sensors)) if a.sensors else None
    fl = fly(VEHICLES[a.vehicle](), a.duration, a.seed, fx, sens, low_hovers=not a.no_low_hovers,
             controller=a.controller)
    paths = write_case(fl, a.out, a.name)
    print(json.dumps({k: str(v) for k, v in paths.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())

"""The symbolic quadrotor model: rigid body + rotor thrust + composable effects.

States (world NED position, ZYX Euler angles, world velocity, body rates)::

    x, y, z, phi, theta, psi, vx, vy, vz, p, q, r   [+ effect states, e.g. w_eff1..N]

Inputs are the rotor speeds ``w1..wN`` (rad/s) or, as the alternative of the seed paper's
Fig. 3, the control inputs ``u1..u4`` = total thrust (N) and roll/pitch/yaw torques (N m).
Outputs are what a vision + IMU set-up measures: ``x, y, z, phi, theta, psi, p, q, r``.

The model is built once, symbolically, into CasADi ``Function`` objects
(:attr:`QuadrotorModel.rhs`, :attr:`QuadrotorModel.output`) that are then evaluated or
mapped over data many times.

Departures from the seed paper's printed equations (README, "Departures from the seed
paper"): the rotation
matrix and Euler-rate matrix are the correct ZYX ones, thrust acts along body -z rotated
to the world (eq. 4 holds only level), the yaw Coriolis term is ``(J_x - J_y) p q`` (in
general ``-omega x J omega`` with the full inertia matrix), and the gyroscopic torque
follows the README's "Conventions" (the paper's pitch term has the wrong sign).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Iterable, Mapping

import casadi as ca
import numpy as np

from . import effects as fx
from .airframe import Airframe
from .errors import GreyboxInputError
from .rotations import euler_rate_matrix, rotation_matrices, rotation_matrix  # noqa: F401 (public here too)
from .parameters import Parameter, flat_names

if TYPE_CHECKING:  # pragma: no cover
    from .data import FlightLog

__all__ = ["QuadrotorModel", "BASE_STATES", "OUTPUTS", "STATE_OUTPUTS", "rotation_matrix", "rotation_matrices",
           "euler_rate_matrix"]

BASE_STATES = ["x", "y", "z", "phi", "theta", "psi", "vx", "vy", "vz", "p", "q", "r"]
OUTPUTS = ["x", "y", "z", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az"]
"""Measured channels, in the order of the model's output ``y``: position (world NED), ZYX
Euler angles, body rates, and the accelerometer's body-frame (FRD) specific force
``R^T (dv/dt - g e3)`` (about ``(0, 0, -g)`` at hover)."""
STATE_OUTPUTS = OUTPUTS[:9]
"""The outputs that are states of the rigid body (the rest are computed from the forces)."""

THRUST = Parameter("K_T", 1, 2e-5, "N/(rad/s)^2", 0.0, np.inf, 1e-5, 0.0, True,
                   "rotor thrust coefficient", "base", lower_exclusive=True)


class QuadrotorModel:
    """A multirotor ODE assembled from an airframe and a set of effects.

    Args:
        airframe: the vehicle's known constants and parameter guesses.
        effects: effects or effect names; default the seed paper's base model
            (``yaw_torque``, ``linear_drag``, ``gyroscopic``).
        inputs: ``"rotor_speeds"`` (``w1..wN``) or ``"controls"`` (``u1..u4``).

    Models are immutable: ``model + effect`` and ``model.without(name)`` return new ones.

    Example::

        from greybox import QuadrotorModel, effects, load_airframe
        model = QuadrotorModel(load_airframe("greybox/data/airframes/paper.toml"))
        model = model + effects.GroundEffect()      # a new model with one more effect
        model.param_names, model.state_names        # ['K_T', 'b', 'Kd[0]', ...], ['x', ...]
        xdot = model.rhs(model.initial_state(), [400.0] * 4, model.default_parameters(), 0.0)
    """

    def __init__(self, airframe: Airframe, effects: Iterable[fx.Effect | str] | None = None,
                 inputs: str = "rotor_speeds"):
        if inputs not in ("rotor_speeds", "controls"):
            raise GreyboxInputError(f"inputs must be 'rotor_speeds' or 'controls', got {inputs!r}")
        if effects is None:
            effects = fx.BASE_EFFECTS
        objs = [fx.by_name(e) if isinstance(e, str) else e for e in effects]
        lib = fx.EffectLibrary(objs)
        # apply in catalogue order, so the result does not depend on how it was composed
        order = list(fx.APPLY_ORDER)
        self.effects = fx.EffectLibrary(sorted(lib, key=lambda e: order.index(e.name)
                                               if e.name in order else len(order)))
        self.airframe = airframe
        self.inputs = inputs
        self._functions: tuple[ca.Function, ca.Function] | None = None
        self._settle: ca.Function | None = None      # settled_states' effect rows and Jacobian
        self._check_parameter_names()
        self._check_airframe_parameters()

    # ------------------------------------------------------------------ composition
    def __add__(self, other: fx.Effect | fx.EffectLibrary | Iterable[fx.Effect]) -> "QuadrotorModel":
        return QuadrotorModel(self.airframe, list(self.effects + other), self.inputs)

    def accepts(self, effect: fx.Effect) -> bool:
        """Whether ``effect`` can be added: the model has neither it nor a state or parameter
        of one of its names (a disturbance torque's ``d_p, d_q`` clash with a held moment's)."""
        own = effect.state_names(self.airframe)
        names = {p.name for p in effect.parameters(self.airframe)}
        return effect.name not in self.effects and not set(own) & set(self.state_names) and \
            not names & {p.name for p in self.parameters}

    def without(self, *names: str) -> "QuadrotorModel":
        """The same model with the named effects removed."""
        for n in names:
            if n not in self.effects:
                raise GreyboxInputError(f"cannot remove {n!r}: the model has effects "
                                        f"{self.effect_names}")
        return QuadrotorModel(self.airframe, [e for e in self.effects if e.name not in names],
                              self.inputs)

    def with_inputs(self, inputs: str) -> "QuadrotorModel":
        """The same model with another input choice (``rotor_speeds`` or ``controls``)."""
        return QuadrotorModel(self.airframe, list(self.effects), inputs)

    @property
    def effect_names(self) -> list[str]:
        return self.effects.names

    def __repr__(self) -> str:
        return (f"QuadrotorModel({self.airframe.name!r}, effects={self.effect_names}, "
                f"inputs={self.inputs!r})")

    # ------------------------------------------------------------------ names and sizes
    @property
    def parameters(self) -> list[Parameter]:
        """Model parameters in vector order: ``K_T`` then each effect's."""
        out = [THRUST]
        for e in self.effects:
            out += e.parameters(self.airframe)
        return out

    def effect_components(self, effect: str) -> list[tuple[Parameter, str, float]]:
        """``(parameter, component name, null value)`` of every parameter component of
        ``effect``, in vector order (``[]`` when the model does not hold it)."""
        return [(par, comp, float(par.null)) for par in self.parameters if par.effect == effect
                for comp in par.component_names]

    @property
    def param_names(self) -> list[str]:
        """Flat component names of the parameter vector (``K_T``, ``b``, ``Kd[0]``...)."""
        return flat_names(self.parameters)

    @property
    def state_names(self) -> list[str]:
        out = list(BASE_STATES)
        for e in self.effects:
            out += e.state_names(self.airframe)
        return out

    @property
    def signal_names(self) -> list[str]:
        """Signals the effects read: logged ones (e.g. ``vbat``), then those derived from the
        log (``command_delay``'s earlier commands, ``w1@10ms``): inputs after the rotor speeds."""
        out: list[str] = []
        for e in self.effects:
            out += [s for s in e.signals if s not in out]
        for e in self.effects:
            out += [s for s in e.derived_signals(self.command_names) if s not in out]
        return out

    @property
    def steady_input_names(self) -> list[str]:
        """The inputs that are free in a steady state: the commands and the logged signals
        (a derived signal, an earlier command, then equals its command)."""
        return [n for n in self.input_names if not fx.is_derived_signal(n)]

    def steady_input_map(self) -> np.ndarray:
        """``S`` (``nu`` x ``len(steady_input_names)``): the model's inputs in a steady state,
        ``u = S @ u_steady``; a derived signal ``w1@10ms`` copies ``w1``."""
        free = self.steady_input_names
        S = np.zeros((self.nu, len(free)))
        for i, name in enumerate(self.input_names):
            S[i, free.index(name.split("@")[0] if fx.is_derived_signal(name) else name)] = 1.0
        return S

    @property
    def command_names(self) -> list[str]:
        """The actuator inputs: ``w1..wN`` or ``u1..u4``."""
        if self.inputs == "controls":
            return ["u1", "u2", "u3", "u4"]
        return [f"w{i + 1}" for i in range(self.airframe.n_rotors)]

    @property
    def input_names(self) -> list[str]:
        """Model inputs: the actuator inputs, then any logged signals the effects read."""
        return self.command_names + self.signal_names

    def prepare_log(self, log: "FlightLog") -> "FlightLog":
        """The log with its inputs in this model's order: actuator inputs checked against
        the model's, signals (e.g. ``vbat``) taken from the log's extra columns, derived
        signals (e.g. ``w1@10ms``) computed from the log.

        Raises a :class:`GreyboxInputError` naming the log and column when they do not match.
        """
        from .data import FlightLog
        where = log.source or "log"
        cmd = self.command_names
        # this model's own signals count too: a discovered effect (a class made at run time,
        # not registered) reads pwm4, and a log already prepared for the model carries it
        known_signals = {s for e in fx.known_effects().values() for s in e.signals} | set(self.signal_names)
        if list(log.input_names[:len(cmd)]) != cmd or \
                any(n not in known_signals and not fx.is_derived_signal(n) for n in log.input_names[len(cmd):]):
            raise GreyboxInputError(f"{where}: inputs {','.join(log.input_names)} do not match the "
                                    f"model's {','.join(self.input_names)}")
        if list(log.input_names) == self.input_names:
            return log
        cols = [log.inputs[:, :len(cmd)]]
        extras = dict(log.extras)
        # signals the log carries as inputs but this model does not read go back to extras
        for j, name in enumerate(log.input_names[len(cmd):], start=len(cmd)):
            extras.setdefault(name, log.inputs[:, j])
        # derived signals (earlier commands) come from the log itself; a log prepared before
        # and split keeps its columns, which hold the history before the split
        commands = {c: log.inputs[:, i] for i, c in enumerate(cmd)}
        for e in self.effects:
            if any(n not in extras for n in e.derived_signals(cmd)):
                extras.update({n: v for n, v in e.derive_signals(log.t, commands).items() if n not in extras})
        for name in self.signal_names:
            if name not in extras:
                users = [e.name for e in self.effects if name in e.signals]
                raise GreyboxInputError(f"{where}: missing column {name!r}, which effect "
                                        f"{users[0]!r} reads as an input")
            v = np.asarray(extras.pop(name), dtype=float)
            bad = np.flatnonzero(~np.isfinite(v))
            if bad.size:
                raise GreyboxInputError(f"{where}: row {bad[0] + 2}, column {name!r}: missing value "
                                        "(a signal read by the model is an input and may never be missing)")
            typical = float(np.median(np.abs(v))) if v.size else 0.0
            for e in self.effects:
                limit, unit, mistake = e.signal_limits.get(name, (math.inf, "", ""))
                if typical > limit:
                    raise GreyboxInputError(f"{where}: column {name!r} (read by {e.name}): typically {typical:.4g}, "
                                            f"beyond the {limit:g} {unit} no vehicle's {name} reaches: {mistake}")
            cols.append(v[:, None])
        return FlightLog(log.t, np.hstack(cols), self.input_names, log.outputs, list(log.output_names),
                         extras, list(log.notes), log.source, dict(log.input_noise_left))

    output_names = OUTPUTS

    @property
    def nx(self) -> int:
        return len(self.state_names)

    @property
    def nu(self) -> int:
        return len(self.input_names)

    @property
    def ny(self) -> int:
        return len(OUTPUTS)

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    # ------------------------------------------------------------------ parameter values
    def _check_parameter_names(self) -> None:
        # one name is one value in the parameter vector, [parameters], --set and JSON
        owner = {THRUST.name: "the base model"}
        for e in self.effects:
            for par in e.parameters(self.airframe):
                if par.name in owner:
                    raise GreyboxInputError(f"{owner[par.name]} and effect {e.name!r} both have a parameter named "
                                            f"{par.name!r}: rename one of them")
                owner[par.name] = f"effect {e.name!r}"

    def _check_airframe_parameters(self) -> None:
        known = {THRUST.name: THRUST}
        for cls in fx.known_effects().values():
            for p in cls().parameters(self.airframe):
                known[p.name] = p
        for name, value in self.airframe.parameters.items():
            if name not in known:
                raise GreyboxInputError(
                    f"{self.airframe.source or 'airframe'}: unknown parameter {name!r} in "
                    f"[parameters]; known: {', '.join(known)}")
            n = np.size(value)
            if n not in (1, known[name].size):
                raise GreyboxInputError(
                    f"{self.airframe.source or 'airframe'}: parameter {name!r} needs "
                    f"{known[name].size} values, got {n}")
            known[name].check_values(value, f"{self.airframe.source or 'airframe'}: [parameters]")

    def default_parameters(self) -> np.ndarray:
        """Flat parameter vector: the airframe's ``[parameters]`` where given, else defaults."""
        vals = []
        for p in self.parameters:
            v = self.airframe.parameters.get(p.name, p.default)
            v = np.atleast_1d(np.asarray(v, dtype=float))
            vals.append(np.full(p.size, v[0]) if v.size == 1 else v)
        return np.concatenate(vals)

    def parameter_vector(self, values: Mapping[str, float | Iterable[float]] | None = None,
                         base: np.ndarray | None = None) -> np.ndarray:
        """A flat parameter vector from ``base`` (default: :meth:`default_parameters`) with
        some parameters replaced by name (``{"K_T": 2.4e-5, "Kd": [.2, .2, .3]}`` or
        component names such as ``"Kd[2]"``)."""
        out = self.default_parameters() if base is None else np.array(base, dtype=float)
        names = self.param_names
        for key, val in (values or {}).items():
            arr = np.atleast_1d(np.asarray(val, dtype=float))
            if key in names:
                if arr.size != 1:
                    raise GreyboxInputError(f"parameter {key!r} takes one value, got {arr.size}")
                owner = self.parameters[self._component_owner(key)]
                owner.check_values(arr[0], "parameter", component=key)
                out[names.index(key)] = arr[0]
                continue
            par = next((p for p in self.parameters if p.name == key), None)
            if par is None:
                raise GreyboxInputError(f"unknown parameter {key!r} for this model; its parameters "
                                        f"are {', '.join(p.name for p in self.parameters)}")
            idx = [names.index(c) for c in par.component_names]
            if arr.size == 1:
                arr = np.full(par.size, arr[0])
            if arr.size != par.size:
                raise GreyboxInputError(f"parameter {key!r} needs {par.size} values, got {arr.size}")
            par.check_values(arr, "parameter")
            out[idx] = arr
        return out

    def _component_owner(self, component: str) -> int:
        """Index in :attr:`parameters` of the parameter a component name belongs to."""
        return next(i for i, p in enumerate(self.parameters) if component in p.component_names)

    def parameter_dict(self, vector: np.ndarray) -> dict[str, float]:
        """``{component name: value}`` of a flat parameter vector."""
        return dict(zip(self.param_names, map(float, vector)))

    # ------------------------------------------------------------------ states
    def initial_state(self, x0: Iterable[float] | None = None,
                      u0: Iterable[float] | None = None, p: np.ndarray | None = None) -> np.ndarray:
        """Full initial state from the 12 base states (default: rest at the origin, level)
        and the first input (for effect states such as motor speeds)."""
        base = np.zeros(12) if x0 is None else np.asarray(list(x0), dtype=float)
        if base.shape != (12,):
            raise GreyboxInputError(f"x0 needs 12 values ({','.join(BASE_STATES)}), got {base.size}")
        u0 = np.zeros(self.nu) if u0 is None else np.asarray(list(u0), dtype=float)
        w0 = self.rotor_speeds_from_inputs(u0, p) if self.inputs == "controls" \
            else u0[:self.airframe.n_rotors]
        parts = [base] + [e.initial_state(self.airframe, w0) for e in self.effects]
        return np.concatenate(parts)

    def settled_states(self, X: np.ndarray, U: np.ndarray, p: np.ndarray, t: np.ndarray) -> np.ndarray:
        """``X`` (n, nx) with each row's effect states moved to where their own dynamics rest
        under that row's inputs ``U`` (n, nu), parameters ``p`` and times ``t`` (n,): a motor
        lag's speeds at the speeds its target asks for, after every effect before it (a
        battery's scaling: :meth:`initial_state` takes the logged speeds as they are). States
        with no dynamics of their own (a random-walk disturbance) keep their values. Two
        Newton steps on ``rhs``'s effect rows; exact for the linear lags."""
        X = np.array(X, dtype=float)
        if self.nx <= 12 or X.shape[0] == 0:
            return X
        if self._settle is None:
            x, u = ca.SX.sym("x", self.nx), ca.SX.sym("u", self.nu)
            q, tt = ca.SX.sym("p", self.n_params), ca.SX.sym("t")
            f = self.rhs(x, u, q, tt)[12:]
            self._settle = ca.Function("settle", [x, u, q, tt], [f, ca.jacobian(f, x[12:])])
        mapped = self._settle.map(X.shape[0])
        for _ in range(2):
            f, jac = mapped(X.T, np.asarray(U, dtype=float).T, np.asarray(p, dtype=float), np.asarray(t)[None, :])
            ne = self.nx - 12
            f = np.asarray(f).T                                     # (n, ne)
            jac = np.asarray(jac).reshape(ne, X.shape[0], ne).transpose(1, 0, 2)   # (n, ne, ne)
            X[:, 12:] -= np.einsum("nij,nj->ni", np.linalg.pinv(jac, rcond=1e-10), f)
        return X

    def rotor_speeds_from_inputs(self, u: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
        """Rotor speeds that realise control inputs u1..u4 (numeric, for ``controls`` models)."""
        p = self.default_parameters() if p is None else p
        f = ca.Function("w_of_u", [self._u_sym, self._p_sym], [self._w_from_u])
        return np.asarray(f(u, p)).ravel()

    # ------------------------------------------------------------------ symbolic build
    def _build(self) -> tuple[ca.Function, ca.Function]:
        af = self.airframe
        n = af.n_rotors
        x = ca.SX.sym("x", self.nx)
        u = ca.SX.sym("u", self.nu)
        p = ca.SX.sym("p", self.n_params)
        t = ca.SX.sym("t")
        params: dict[str, ca.SX] = {}
        k = 0
        for par in self.parameters:
            params[par.name] = p[k:k + par.size]
            k += par.size
        extra: dict[str, ca.SX] = {}
        k = 12
        for e in self.effects:
            m = len(e.state_names(af))
            extra[e.name] = x[k:k + m]
            k += m

        pos, euler, v, omega = x[0:3], x[3:6], x[6:9], x[9:12]
        R = rotation_matrix(euler[0], euler[1], euler[2])
        K_T = params["K_T"]
        if self.inputs == "controls":
            # w^2 = pinv(G) diag(1/K_T, 1/K_T, 1/K_T, 1/b) U: the speeds that realise U with
            # the nominal coefficients; every effect then acts on rotors as usual.
            b = params["b"] if "b" in params else float(np.atleast_1d(
                af.parameters.get("b", fx.YawTorque().parameters(af)[0].default))[0])
            Ginv = ca.DM(np.linalg.pinv(af.allocation_matrix()))
            wsq = Ginv @ (u[:4] / ca.vertcat(K_T, K_T, K_T, b))
            w_cmd = ca.sqrt(ca.fmax(wsq, 1e-9))
        else:
            w_cmd = u[:n]
        n_cmd = len(self.command_names)
        signals = {name: u[n_cmd + i] for i, name in enumerate(self.signal_names)}
        self._u_sym, self._p_sym, self._w_from_u = u, p, w_cmd

        ctx = fx.ModelContext(
            airframe=af, t=t, pos=pos, euler=euler, v=v, omega=omega, R=R, w=w_cmd,
            params=params, extra_states=extra, w_command=w_cmd, signals=signals,
            thrust_scale=ca.SX.ones(n), torque_scale=ca.SX.ones(n),
            rotor_pos=ca.SX(ca.DM(af.rotor_positions)), v_air=v,
            force_world=ca.SX.zeros(3), torque_body=ca.SX.zeros(3))
        for e in self.effects:
            with fx.user_hook(e, "modify"):
                e.modify(ctx)

        # rotor thrust along body -z, and its moment about the centre of gravity
        ctx.rotor_thrust = K_T * ctx.thrust_scale * ctx.w ** 2
        thrust_body = ca.vertcat(0, 0, -ca.sum1(ctx.rotor_thrust))
        torque = ca.SX.zeros(3)
        for i in range(n):
            torque += ca.cross(ctx.rotor_pos[i, :].T, ca.vertcat(0, 0, -ctx.rotor_thrust[i]))
        ctx.thrust_torque = torque
        for e in self.effects:
            with fx.user_hook(e, "add_forces"):
                e.add_forces(ctx)

        m, g = af.mass, af.gravity
        J = ca.DM(af.inertia)
        Jinv = ca.DM(np.linalg.inv(af.inertia))
        acc = ca.vertcat(0, 0, g) + (R @ thrust_body + ctx.force_world) / m
        tau = torque + ctx.torque_body
        omega_dot = Jinv @ (tau - ca.cross(omega, J @ omega))
        euler_dot = euler_rate_matrix(euler[0], euler[1]) @ omega
        xdot_parts = [v, euler_dot, acc, omega_dot]
        for e in self.effects:
            with fx.user_hook(e, "state_derivative"):
                xdot_parts.append(e.state_derivative(ctx))
        xdot = ca.vertcat(*xdot_parts)

        ctx.acc_world = acc
        y = {name: x[BASE_STATES.index(name)] for name in STATE_OUTPUTS}
        # what an accelerometer at the CoG measures: every force but gravity, in the body frame
        specific_force = R.T @ (acc - ca.vertcat(0, 0, g))
        y.update(ax=specific_force[0], ay=specific_force[1], az=specific_force[2])
        for e in self.effects:
            with fx.user_hook(e, "modify_measurement"):
                e.modify_measurement(ctx, y)
        yv = ca.vertcat(*[y[name] for name in OUTPUTS])

        rhs = ca.Function("rhs", [x, u, p, t], [xdot], ["x", "u", "p", "t"], ["xdot"])
        out = ca.Function("output", [x, u, p, t], [yv], ["x", "u", "p", "t"], ["y"])
        return rhs, out

    def _ensure_built(self) -> tuple[ca.Function, ca.Function]:
        if self._functions is None:
            self._functions = self._build()
        return self._functions

    @property
    def rhs(self) -> ca.Function:
        """CasADi ``Function`` ``rhs(x, u, p, t) -> xdot``."""
        return self._ensure_built()[0]

    @property
    def output(self) -> ca.Function:
        """CasADi ``Function`` ``output(x, u, p, t) -> y`` (``OUTPUTS`` order)."""
        return self._ensure_built()[1]

    @property
    def input_fed_outputs(self) -> list[str]:
        """The outputs the inputs reach straight through the output map (the structure of its
        Jacobian): the accelerometer's, through the thrust; the pose and the rates are states."""
        rows = set(self.output.jac_sparsity(0, 1).row())
        return [name for i, name in enumerate(OUTPUTS) if i in rows]

    ROTOR_SPEED_PLAUSIBLE_FACTOR = 5.0
    """Logged rotor speeds typically above this many hover speeds (25 times the weight in
    thrust) are refused as a unit mistake: RPM read as rad/s is 9.5 times. So are speeds whose
    fast samples stay below the hover speed over this factor (a 25th of the weight): rev/s
    read as rad/s is 2 pi times too slow."""
    ROTOR_SPEED_TYPICAL_FACTOR = 4.0
    """...and so are speeds whose RMS over the rotors stays below the hover speed over this
    factor (thrust under a 16th of the weight) for three quarters of the log: a vehicle does
    not fly like that. A racer's fast samples reach 4 times its typical speed, so rev/s passed
    the fastest-rotor test (an audit); its typical speed is 2 pi below hover (refused unless the
    vehicle flies at 1.6 times hover three quarters of the time), while a K_T guess 10 times
    too small (hover 3.2 times too high) stays accepted on a flight whose typical speed is 0.8
    of hover or more."""

    def check_rotor_speeds(self, w: np.ndarray, p: np.ndarray | None = None, where: str = "log",
                           too_slow: str = "error") -> list[str]:
        """Raise a :class:`GreyboxInputError` if logged rotor speeds ``w`` (n, n_rotors) are far
        above the hover speed the airframe's mass and ``K_T`` imply (RPM logged as rad/s), or
        never come near it (rev/s logged as rad/s). ``too_slow="note"`` returns the latter as a
        note instead (a simulation may drop the vehicle on purpose)."""
        w = np.abs(np.asarray(w, dtype=float))
        if w.size == 0:
            return []
        p = self.default_parameters() if p is None else p
        hover = self.hover_speed(p)
        # per rotor: one column in RPM among rad/s ones is as wrong as all of them
        per_rotor = np.median(w, axis=0)
        j = int(np.argmax(per_rotor))
        typical = float(per_rotor[j])
        if typical > self.ROTOR_SPEED_PLAUSIBLE_FACTOR * hover:
            ratio = typical / hover
            # an airframe without a K_T guess gets the parameter's default, sized for another
            # vehicle: then the mistake is more likely there than in the log's units
            given = "K_T" in self.airframe.parameters
            raise GreyboxInputError(
                f"{where}: column {self.command_names[j]}: the rotor speeds are "
                f"typically {typical:.4g}, {ratio:.1f} times the hover speed {hover:.4g} rad/s that "
                f"mass {self.airframe.mass:g} kg and K_T {p[self.param_names.index('K_T')]:.3g} imply "
                f"(thrust {ratio ** 2:.0f} times the weight): "
                + ("are they RPM? rad/s = RPM * pi/30 (or is K_T too large?)" if given else
                   "the airframe gives no K_T, so that is greybox's default "
                   "guess: give one under [parameters] (thrust per rotor / w^2 at hover, N s^2; "
                   "m g / (n w_hover^2)); or are the speeds RPM? rad/s = RPM * pi/30"))
        # too slow: even the fastest rotor's fast samples (the 90th percentile: a log may hold
        # time on the ground) would carry a 25th of the weight; a fit would take a K_T 39 times
        # the airframe's from rev/s and say nothing (an audit's case)
        fast = np.percentile(w, 90, axis=0)
        j = int(np.argmax(fast))
        top = float(fast[j])
        # typical: the RMS over the rotors, three quarters of the log below it (a quarter may be
        # on the ground); a 5-inch racer's fastest rotor reaches 4 times hover in rev/s
        typical_rms = float(np.percentile(np.sqrt(np.mean(w ** 2, axis=1)), 75))
        slow_fast = top * self.ROTOR_SPEED_PLAUSIBLE_FACTOR < hover
        if w.shape[0] >= 10 and (slow_fast or typical_rms * self.ROTOR_SPEED_TYPICAL_FACTOR < hover):
            level = top if slow_fast else typical_rms
            given = "K_T" in self.airframe.parameters
            what = (f"stay below {top:.4g} (column {self.command_names[j]}'s 90th percentile, the fastest)"
                    if slow_fast else f"are typically {typical_rms:.4g} (the RMS over the rotors, three "
                                      "quarters of the log below it)")
            if not level > 0:
                problem = (f"{where}: the rotor speeds {what}: the rotors do not turn in most of the log, and "
                           "nothing can be identified from it (are the speed columns the right ones, or filled?)")
                if too_slow == "note":
                    return [problem]
                raise GreyboxInputError(problem)
            ratio = hover / level
            problem = (
                f"{where}: the rotor speeds {what}, 1/{ratio:.1f} of the hover speed {hover:.4g} rad/s that mass "
                f"{self.airframe.mass:g} kg and K_T {p[self.param_names.index('K_T')]:.3g} imply (thrust "
                f"1/{ratio ** 2:.0f} of the weight): "
                + ("are they rev/s or kRPM? rad/s = rev/s * 2 pi = RPM * pi/30 (or is K_T too small?)" if given
                   else "the airframe gives no K_T, so that is greybox's default guess: give one under "
                        "[parameters] (m g / (n w_hover^2), N s^2); or are the speeds rev/s? "
                        "rad/s = rev/s * 2 pi"))
            if too_slow == "note":
                return [problem]
            raise GreyboxInputError(problem)
        return []

    def hover_speed(self, p: np.ndarray | None = None) -> float:
        """Equal rotor speed that balances gravity with the nominal ``K_T`` (level, no effects)."""
        p = self.default_parameters() if p is None else p
        kt = p[self.param_names.index("K_T")]
        return float(np.sqrt(self.airframe.mass * self.airframe.gravity / (self.airframe.n_rotors * kt)))

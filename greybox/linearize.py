"""Trim and symbolic linearisation of a composed model.

:func:`hover_trim` finds rotor speeds (and the roll/pitch and effect states) at which the
vehicle hovers still at a given place: in closed form for a symmetric airframe whose model
has no effect that shifts the balance, otherwise by solving ``xdot = 0`` with IPOPT for the
rotor speeds closest to equal (e.g. ``cog_offset`` or ``motor_asymmetry`` need unequal
speeds). :func:`linearize` evaluates the CasADi Jacobians of the right-hand side and the
measurement map at any operating point, giving a continuous-time :class:`LinearModel`
that can be discretised (zero-order hold) or handed to python-control.
"""
from __future__ import annotations

import warnings

from dataclasses import dataclass

import casadi as ca
import numpy as np
from scipy.linalg import expm

from .errors import GreyboxInputError, SolverError
from .model import QuadrotorModel

__all__ = ["hover_trim", "linearize", "LinearModel"]



@dataclass
class LinearModel:
    """``dx/dt = A dx + B du``, ``dy = C dx + D du`` about ``(x_op, u_op)`` (continuous),
    or the discrete equivalent when ``dt`` is set.

    Example::

        import numpy as np
        from greybox import QuadrotorModel, load_airframe, linearize, dlqr
        model = QuadrotorModel(load_airframe("greybox/data/airframes/paper.toml"))
        lin = linearize(model)                  # at the hover trim: lin.x_op, lin.u_op
        d = lin.discretize(0.01)                # zero-order hold
        K, S, E = dlqr(d, np.eye(12), 1e-3 * np.eye(4))    # or dlqr(d.A, d.B, Q, R)
        lin.save_mat("hover.mat")               # A, B, C, D, x_trim, u_trim, names for MATLAB
        sys = lin.to_control()                  # python-control; LinearModel.from_control(sys) back
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    state_names: list[str]
    input_names: list[str]
    output_names: list[str]
    x_op: np.ndarray
    u_op: np.ndarray
    dt: float | None = None

    def discretize(self, dt: float) -> "LinearModel":
        """Zero-order-hold discretisation (exact for inputs held over each step)."""
        if self.dt is not None:
            raise GreyboxInputError("model is already discrete")
        n, m = self.B.shape
        M = np.zeros((n + m, n + m))
        M[:n, :n], M[:n, n:] = self.A, self.B
        E = expm(M * dt)
        return LinearModel(E[:n, :n], E[:n, n:], self.C, self.D, self.state_names, self.input_names,
                           self.output_names, self.x_op, self.u_op, dt)

    def to_control(self):
        """A python-control ``StateSpace`` (``pip install greybox[compare]``)."""
        try:
            import control
        except ImportError as e:  # pragma: no cover - depends on the optional extra
            raise GreyboxInputError("python-control is not installed: pip install 'greybox[compare]'") from e
        args = (self.A, self.B, self.C, self.D) + ((self.dt,) if self.dt is not None else ())
        return control.ss(*args, states=self.state_names, inputs=self.input_names, outputs=self.output_names)

    @classmethod
    def from_control(cls, sys, x_trim=None, u_trim=None) -> "LinearModel":
        """A :class:`LinearModel` from a python-control system (a ``StateSpace``, or anything
        ``control.ss`` converts, such as a ``TransferFunction``): its A, B, C, D, its signal
        names (``state_labels``, ``input_labels``, ``output_labels``) and its time base
        (``dt = 0``: continuous, ``dt = None`` here; ``dt = True``: discrete with the period
        unspecified, kept as ``True``). The operating point is zero unless ``x_trim`` /
        ``u_trim`` give it. Round trip: ``LinearModel.from_control(lin.to_control(),
        lin.x_op, lin.u_op)`` equals ``lin``.

        Example::

            import control
            from greybox import LinearModel
            sys = control.ss([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], [[0]], 0.01,
                             states=["z", "vz"], inputs=["T"], outputs=["z"])
            lin = LinearModel.from_control(sys)     # lin.dt == 0.01, lin.state_names == ["z", "vz"]
        """
        try:
            import control
        except ImportError as e:  # pragma: no cover - depends on the optional extra
            raise GreyboxInputError("python-control is not installed: pip install 'greybox[compare]'") from e
        if not isinstance(sys, control.StateSpace):
            if not isinstance(sys, control.LTI):
                raise GreyboxInputError(f"LinearModel.from_control: expected a python-control system "
                                        f"(StateSpace or TransferFunction), got {type(sys).__name__}")
            sys = control.ss(sys)
        A, B, C, D = (np.array(M, dtype=float, ndmin=2) for M in (sys.A, sys.B, sys.C, sys.D))
        n, m = sys.nstates, sys.ninputs
        A, B = A.reshape(n, n), B.reshape(n, m)
        C, D = C.reshape(sys.noutputs, n), D.reshape(sys.noutputs, m)
        dt = sys.dt
        dt = True if dt is True else None if dt is None or dt == 0 else float(dt)

        def _point(v, size: int, name: str) -> np.ndarray:
            if v is None:
                return np.zeros(size)
            v = np.asarray(v, dtype=float).ravel()
            if v.size != size or not np.all(np.isfinite(v)):
                raise GreyboxInputError(f"LinearModel.from_control: {name} must be {size} finite values "
                                        f"(the system's {'states' if name == 'x_trim' else 'inputs'}), "
                                        f"got {v.size}")
            return v

        return cls(A, B, C, D, list(sys.state_labels), list(sys.input_labels), list(sys.output_labels),
                   _point(x_trim, n, "x_trim"), _point(u_trim, m, "u_trim"), dt)

    def save_mat(self, path) -> None:
        """Write the model as a MATLAB ``.mat`` file (``scipy.io.savemat``; written whole or not
        at all): ``A, B, C, D``, ``x_trim`` and ``u_trim`` (the operating point, columns),
        ``state_names``, ``input_names``, ``output_names`` (cell arrays of strings) and ``dt``
        (MATLAB's ``Ts``: 0 continuous, -1 discrete with an unspecified period). The file is
        written at exactly ``path``. In MATLAB: ``m = load("hover.mat"); sys = ss(m.A, m.B,
        m.C, m.D, m.dt, "StateName", m.state_names)``.

        Example::

            lin = linearize(model)
            lin.save_mat("hover.mat")
            m = scipy.io.loadmat("hover.mat")       # m["A"], m["x_trim"], m["state_names"]
        """
        import io

        from scipy.io import savemat

        from .data import atomic_write
        dt = 0.0 if self.dt is None else -1.0 if self.dt is True else float(self.dt)
        buf = io.BytesIO()
        savemat(buf, {"A": np.asarray(self.A, float), "B": np.asarray(self.B, float),
                      "C": np.asarray(self.C, float), "D": np.asarray(self.D, float),
                      "x_trim": np.asarray(self.x_op, float).ravel(),
                      "u_trim": np.asarray(self.u_op, float).ravel(), "dt": dt,
                      "state_names": np.array(list(self.state_names), dtype=object),
                      "input_names": np.array(list(self.input_names), dtype=object),
                      "output_names": np.array(list(self.output_names), dtype=object)},
                oned_as="column")
        atomic_write(path, buf.getvalue())


def _closed_form_ok(model: QuadrotorModel) -> bool:
    af = model.airframe
    P = af.rotor_positions
    symmetric = (np.allclose(P[:, :2].sum(axis=0), 0) and abs(af.spins.sum()) < 1e-12
                 and np.allclose(af.inertia, np.diag(np.diag(af.inertia))))
    return (symmetric and model.inputs == "rotor_speeds"
            and not any(e.shifts_trim for e in model.effects))


def hover_trim(model: QuadrotorModel, p: np.ndarray | None = None, position=(0.0, 0.0, None),
               psi: float = 0.0, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``(x_trim, u_trim)`` for a still hover at ``position`` (default: 1 m above the
    ground plane at the origin) with heading ``psi``.

    Closed form ``w_i = sqrt(m g / (N K_T))`` where it applies; otherwise IPOPT solves
    ``xdot(x, u) = 0`` for the inputs (closest to equal rotor speeds), roll, pitch and the
    effects' states.

    Example::

        from greybox import QuadrotorModel, effects, hover_trim, load_airframe
        model = QuadrotorModel(load_airframe("greybox/data/airframes/paper.toml"))
        x_trim, u_trim = hover_trim(model)                          # 1 m above the ground
        x_trim, u_trim = hover_trim(model + effects.CogOffset(), position=(0, 0, -2.0))
    """
    p = model.default_parameters() if p is None else np.asarray(p, dtype=float)
    af = model.airframe
    pos = np.array([position[0], position[1], af.ground_z - 1.0 if position[2] is None else position[2]], float)
    x = np.zeros(12)
    x[0:3], x[5] = pos, psi
    # in a steady state a derived input (an earlier command) equals its command
    S = model.steady_input_map()
    if _closed_form_ok(model):
        w = np.full(model.nu, model.hover_speed(p))
        return model.initial_state(x, w, p), w
    # unknowns: inputs, roll, pitch, effect states; equations: every state derivative
    # except the position/attitude kinematics that hold trivially at rest
    n_extra = model.nx - 12
    u = ca.SX.sym("u", S.shape[1])
    ang = ca.SX.sym("ang", 2)
    xe = ca.SX.sym("xe", n_extra)
    xs = ca.vertcat(ca.DM(x[0:3]), ang, psi, ca.DM.zeros(6), xe)
    f = model.rhs(xs, ca.DM(S) @ u, p, t)
    if model.inputs == "rotor_speeds":
        u0 = np.full(S.shape[1], model.hover_speed(p))
    else:
        u0 = np.array([af.mass * af.gravity, 0.0, 0.0, 0.0])
    scale = np.abs(u0) + (af.mass * af.gravity if model.inputs == "controls" else 0.0) + 1e-9
    obj = ca.sumsqr((u - u0) / scale)
    nlp = {"x": ca.vertcat(u, ang, xe), "f": obj, "g": f[6:]}
    solver = ca.nlpsol("trim", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": False,
                                              "ipopt.tol": 1e-12, "ipopt.sb": "yes"})
    x0 = model.initial_state(x, S @ u0, p)
    sol = solver(x0=np.concatenate([u0, [0.0, 0.0], x0[12:]]), lbg=0, ubg=0)
    z = np.asarray(sol["x"]).ravel()
    if not solver.stats()["success"] or np.abs(np.asarray(sol["g"])).max() > 1e-7:
        raise SolverError(f"no hover trim found: {solver.stats()['return_status']}")
    n_u = S.shape[1]
    u_t = S @ z[:n_u]
    x_t = np.concatenate([x[:3], z[n_u:n_u + 2], [psi], np.zeros(6), z[n_u + 2:]])
    return x_t, u_t


def linearize(model: QuadrotorModel, p: np.ndarray | None = None, x: np.ndarray | None = None,
              u: np.ndarray | None = None, t: float = 0.0) -> LinearModel:
    """Continuous-time Jacobians of ``model`` at ``(x, u)`` (default: the hover trim).

    Example::

        from greybox import QuadrotorModel, linearize, load_airframe
        model = QuadrotorModel(load_airframe("greybox/data/airframes/paper.toml"))
        lin = linearize(model)                      # a LinearModel: A, B, C, D with names
        lin.discretize(0.01).to_control()           # python-control, 100 Hz
    """
    p = model.default_parameters() if p is None else np.asarray(p, dtype=float)
    if x is None or u is None:
        x_t, u_t = hover_trim(model, p)
        x = x_t if x is None else x
        u = u_t if u is None else u
    x, u = np.asarray(x, float), np.asarray(u, float)
    xs, us = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu)
    f = model.rhs(xs, us, p, t)
    y = model.output(xs, us, p, t)
    J = ca.Function("linearization", [xs, us], [ca.jacobian(f, xs), ca.jacobian(f, us), ca.jacobian(y, xs), ca.jacobian(y, us)])
    A, B, C, D = (np.asarray(M) for M in J(x, u))
    S = model.steady_input_map()
    if S.shape[0] != S.shape[1]:
        # inputs derived from the commands (command_delay's earlier commands) fold into their
        # command: the linear model sees the delay's static part; the delay itself has no
        # finite state-space form
        warnings.warn(f"linearize: the model's command delay (tau_cmd = {_value(model, p, 'tau_cmd')}) is not "
                      "in the linear model; a controller designed on it ignores that delay", stacklevel=2)
        return LinearModel(A, B @ S, C, D @ S, model.state_names, model.steady_input_names,
                           list(model.output_names), x, np.linalg.pinv(S) @ u)
    return LinearModel(A, B, C, D, model.state_names, model.input_names, list(model.output_names), x, u)


def _value(model: QuadrotorModel, p: np.ndarray, name: str) -> str:
    return f"{p[model.param_names.index(name)]:.3g} s" if name in model.param_names else "?"


"""What a logged command delivers: the thrust drifting as the battery sags, rotor speed
scaling with the logged battery voltage, the offset of a command-to-speed map, the
delay between a logged command and the rotors' response, and the timing of rotor speeds
sampled from a signal that varies between the log's rows."""
from __future__ import annotations

import math
from dataclasses import replace

import casadi as ca
import numpy as np

from ..errors import GreyboxInputError
from ..parameters import Parameter
from .base import Effect

__all__ = ["ThrustDrift", "RotorMap", "BatteryVoltage", "CommandDelay", "SampledInputs"]


def _require_rotor_speeds(commands, what: str) -> None:
    """One clear error when an effect that reworks logged rotor speeds (``what``: its name and
    verb) is put in a model driven by control inputs, which has none."""
    if any(not c.startswith("w") for c in commands):
        raise GreyboxInputError(f"{what} logged rotor speeds (inputs w1..wN); a model with inputs='controls' has none")


class ThrustDrift(Effect):
    """Thrust coefficient drifting linearly over the flight (battery sag):
    ``K_T(t) = K_T * (1 + K_T_drift * t)``, t in seconds from the log's start.
    """

    name = "thrust_drift"
    summary = "thrust coefficient drifting linearly in time"
    excited_by = 'the same manoeuvre repeated early and late in the flight'
    fit_advice = 'a longer flight, repeating the same manoeuvres early and late'
    per_flight = True      # how fast thrust sags depends on the battery each flight starts with
    channels = ('z',)
    distinguish = {
        'ground_effect': 'repeat the same climb early and late in the flight, away from the ground',
        'battery_voltage': 'vary the thrust level: the voltage sags with the current drawn, time does not',
    }
    shifts_trim = True

    def parameters(self, airframe):
        return [Parameter("K_T_drift", 1, 0.0, "1/s", -0.05, 0.05, 1e-3, 0.0, True,
                          "relative change of K_T per second", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"K_T_drift": -0.002}

    def plausibility_warnings(self, values, std, airframe):
        """A thrust per rotor speed rising over the flight, beyond 2 std: a battery sags, and
        with it the thrust at a given command; nothing in the rotors makes it rise. A blind
        audit's vehicle that dropped 12 % of its mass at mid-flight (the thrust it needs
        falling in a step) took a drift of +0.5 %/s, then two more effects to mend the step."""
        out = super().plausibility_warnings(values, std, airframe)
        v, s = values.get("K_T_drift"), std.get("K_T_drift")
        if v is not None and s is not None and np.isfinite(s) and v > 2 * s:
            out.append(f"K_T_drift = {v:+.3g} 1/s: the thrust at a given rotor speed rising over the flight "
                       f"({100 * v:+.2g} % per s, {v / s:.1f} std); a battery sags, and the thrust at a given "
                       "command with it, it does not rise: it stands for something the model lacks (a vehicle "
                       "getting lighter, a dropped payload; a force that eases over the flight)")
        return out

    def modify(self, ctx):
        ctx.thrust_scale *= 1.0 + ctx.params["K_T_drift"] * ctx.t


class RotorMap(Effect):
    """A constant offset ``w_offset`` (rad/s) added to the logged rotor speeds.

    For logs whose speeds come from a command through an affine map ``w = a*cmd + c``
    (e.g. Crazyflie PWM), this fits the map: a wrong slope ``a`` is absorbed exactly by
    ``K_T`` and ``b`` (thrust is ``K_T*w^2``), so the offset is the one coefficient left
    to identify. Applied before the other effects (it changes the command itself).
    """

    name = "rotor_map"
    summary = "offset of the logged rotor speeds (command-to-speed map)"
    excited_by = 'a wide range of thrust levels'
    channels = ('z', 'phi', 'theta', 'p', 'q')

    def parameters(self, airframe):
        return [Parameter("w_offset", 1, 0.0, "rad/s", -2000.0, 2000.0, 100.0, 0.0, True,
                          "offset added to the logged rotor speeds", self.name)]

    def modify(self, ctx):
        ctx.w_command = ctx.w_command + ctx.params["w_offset"]
        ctx.w = ctx.w + ctx.params["w_offset"]


class BatteryVoltage(Effect):
    """Rotor speed (hence thrust and reaction torque) at a given command changing with the
    logged battery voltage ``vbat`` (V): ``w = w_logged * (1 + K_vbat * (vbat - v_ref))``.

    Real motors spin slower at the same command as the battery sags, so a log of commanded
    speeds (PWM mapped to rad/s) over-states thrust late in the flight. ``thrust_drift``
    models the same with time; this uses the measured voltage instead. Reads the signal
    ``vbat`` (an extra input column of the log).
    """

    name = "battery_voltage"
    summary = "rotor speed at a given command scaling with battery voltage"
    excited_by = 'long flights at varied thrust'
    channels = ('z', 'psi', 'r')
    signals = ("vbat",)
    # a 24-cell pack is 100 V; a cell in millivolts is thousands (a blind audit's vbat in mV:
    # K_vbat -5e-6 for 0.2, certified, exit 0)
    signal_limits = {"vbat": (150.0, "V", "is it in millivolts? V = mV / 1000")}

    def __init__(self, v_ref: float = 4.0):
        self.v_ref = float(v_ref)

    def parameters(self, airframe):
        return [Parameter("K_vbat", 1, 0.0, "1/V", -2.0, 2.0, 0.05, 0.0, True,
                          f"relative rotor speed change per volt about {self.v_ref:g} V", self.name)]

    def modify(self, ctx):
        scale = 1.0 + ctx.params["K_vbat"] * (ctx.signals["vbat"] - self.v_ref)
        ctx.w_command = ctx.w_command * scale
        ctx.w = ctx.w * scale


class CommandDelay(Effect):
    """The rotors acting on the logged commands ``tau_cmd`` seconds late:
    ``w(t) = w_logged(t - tau_cmd)``.

    A log of motor commands (PWM) is not a log of rotor speeds: the command reaches the
    motor driver, the motor and the air later, and the onboard log's time stamps may lag the
    samples they stamp. On real Crazyflie flights the gyro-derived angular acceleration
    follows the modelled moment by 40-50 ms (``experiments/real_command_delay.py``), and a
    first-order ``motor_lag`` cannot stand for that: it rounds the response instead of
    shifting it and adds a state per rotor that the fit must estimate at every node.

    The delayed command is interpolated (Catmull-Rom: smooth in ``tau_cmd``, so the fit's
    gradient is continuous and the optimum can be certified) between copies of the commands
    taken ``tap`` seconds apart, which the model derives from the log itself
    (:meth:`derived_signals`: ``w1@10ms`` is ``w1`` 10 ms earlier; before the log's start
    the first command is held). ``tau_cmd`` lies in ``[0, max_delay]``.
    """

    name = "command_delay"
    input_timed = ("tau_cmd",)
    summary = "logged rotor commands acting tau_cmd seconds late (transport delay)"
    excited_by = 'fast command changes whose response is measured (attitude steps, aggressive turns)'
    fit_advice = 'fast roll and pitch changes with the gyro or attitude logged at a high rate'
    channels = ('phi', 'theta', 'p', 'q')
    distinguish = {
        'motor_lag': 'sharp command steps: a delay shifts the whole response, a lag rounds its start',
        'position_delay': 'a delay of the commands delays attitude too, a vision delay only position',
    }
    considered_when_logged = ("pwm1",)

    def __init__(self, max_delay: float = 0.1, tap: float = 0.01):
        if not (tap > 0 and max_delay >= tap and math.isfinite(max_delay)):
            raise GreyboxInputError(f"command_delay: need 0 < tap <= max_delay, got tap={tap!r}, "
                                    f"max_delay={max_delay!r}")
        self.max_delay = float(max_delay)
        self.tap = float(tap)

    @property
    def n_taps(self) -> int:
        """Number of ``tap`` intervals spanned by ``[0, max_delay]``."""
        return int(math.ceil(self.max_delay / self.tap - 1e-9))

    def _offsets(self) -> list[int]:
        # Catmull-Rom on segment j reads taps j-1 .. j+2: one tap after the command (its
        # next sample) and one beyond the last segment
        return [j for j in range(-1, self.n_taps + 2) if j != 0]

    def _name(self, command: str, j: int) -> str:
        return f"{command}@{j * self.tap * 1e3:g}ms"

    def parameters(self, airframe):
        return [Parameter("tau_cmd", 1, 0.02, "s", 0.0, self.n_taps * self.tap, 0.01, 0.0, True,
                          "delay of the rotors' response to the logged commands", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"tau_cmd": 0.03}

    def derived_signals(self, commands):
        _require_rotor_speeds(commands, "command_delay delays")
        return [self._name(c, j) for j in self._offsets() for c in commands]

    def derive_signals(self, t, commands):
        t = np.asarray(t, dtype=float)
        out = {}
        for c, v in commands.items():
            v = np.asarray(v, dtype=float)
            for j in self._offsets():
                # np.interp holds the end values: before the start, the first command
                out[self._name(c, j)] = np.interp(t - j * self.tap, t, v)
        return out

    def modify(self, ctx):
        n = ctx.airframe.n_rotors
        commands = [f"w{i + 1}" for i in range(n)]
        taps = {0: ctx.w_command}
        for j in self._offsets():
            taps[j] = ca.vertcat(*[ctx.signals[self._name(c, j)] for c in commands])
        s = ctx.params["tau_cmd"] / self.tap

        def segment(j):
            f = s - j
            p0, p1, p2, p3 = taps[j - 1], taps[j], taps[j + 1], taps[j + 2]
            return 0.5 * (2 * p1 + (p2 - p0) * f + (2 * p0 - 5 * p1 + 4 * p2 - p3) * f ** 2
                          + (3 * (p1 - p2) + p3 - p0) * f ** 3)

        w = segment(0)
        for j in range(1, self.n_taps):
            w = ca.if_else(s >= j, segment(j), w)
        ctx.w_command = w
        ctx.w = w


class SampledInputs(Effect):
    """Logged rotor speeds that are samples of a signal varying between the log's rows, not
    values held until the next row: the model holds each row's input over its interval
    (zero-order hold, the contract's rule), and this effect makes that held value the blend
    ``(1 - s_lead) w_k + s_lead w_(k+1)`` of the row and the next one.

    ``s_lead = 0`` is the plain hold (a command the controller held, logged at its own rate);
    ``0.5`` is the mean over the interval of a signal interpolated linearly between the rows
    (measured rotor speeds, ESC telemetry, command snapshots of a faster controller). Held
    samples of a varying signal lag it by half a sample on average: on a 30 g vehicle logged at
    100 Hz (motor time constant 20 ms, attitude loop at 30 rad/s) that lag left residuals the
    diagnosis took for a rotor drag at the hubs (another simulator's flight with nothing
    missing: validation nrmse 0.045; 0.017 with the inputs averaged). At 500 Hz and faster the
    lag is a millisecond or less.

    The next row's speeds are derived from the log itself (:meth:`derived_signals`:
    ``w1@next``); the last row's next is itself.

    ``hold="linear"`` ramps the speeds across the row instead of holding their blend:
    ``w_k + (f + s_lead - 0.5) (w_(k+1) - w_k)`` at the fraction ``f`` of the row (its mean over
    the row is the held blend, so ``s_lead`` means the same; ``0.5`` is the first-order hold
    through the samples). A command a faster controller steps several times a row is a ramp
    seen through a lag more than a held value: on the peer simulator's 30 g vehicle (500 Hz
    controller, commands logged at 100 Hz, 20 ms motors) a fit with the held blend gives
    ``tau_m`` 19.3 +- 0.14 ms, with the ramp 19.7; its cost is no lower, so the held blend
    stays the default. The row's time and length are derived signals (``t@row``, ``h@row``).
    """

    def __init__(self, hold: str = "mean"):
        if hold not in ("mean", "linear"):
            raise GreyboxInputError(f"sampled_inputs: hold must be 'mean' or 'linear', not {hold!r}")
        self.hold = hold

    name = "sampled_inputs"
    summary = "logged rotor speeds sampled from a varying signal: each interval holds (1-s) w_k + s w_k+1"
    excited_by = "fast rotor-speed changes between the log's rows (attitude steps, aggressive turns)"
    fit_advice = "fast roll and pitch changes with the gyro or attitude logged at the rotor speeds' rate"
    channels = ("phi", "theta", "p", "q")
    distinguish = {
        "command_delay": "a delay makes the rotors act later than logged, sampled inputs earlier than held",
        "motor_lag": "a lag rounds the response to a command step, sampled speeds already carry the motor's lag",
    }
    considered_when_logged = ("w1",)
    describes_sampling = True

    def parameters(self, airframe):
        return [Parameter("s_lead", 1, 0.0, "sample", 0.0, 1.0, 0.5, 0.0, True,
                          "weight of the next row's rotor speeds in each interval's held value", self.name)]

    def plausible_values(self, airframe, K_T):
        return {"s_lead": 0.5}

    @staticmethod
    def _next(command: str) -> str:
        return f"{command}@next"

    def derived_signals(self, commands):
        _require_rotor_speeds(commands, "sampled_inputs blends")
        return [self._next(c) for c in commands] + (["t@row", "h@row"] if self.hold == "linear" else [])

    @staticmethod
    def _next_rows(v: np.ndarray) -> np.ndarray:
        """Each row's next row (the last row its own)."""
        return np.append(v[1:], v[-1:])

    @staticmethod
    def _previous_rows(v: np.ndarray) -> np.ndarray:
        """Each row's previous row (the first row its own)."""
        return np.concatenate([v[:1], v[:-1]])

    @classmethod
    def _with_next_rows(cls, log, next_of):
        """``log`` with this effect's next-row speeds set to ``next_of(w)`` for each rotor-speed
        column ``w`` (kept by :meth:`QuadrotorModel.prepare_log`)."""
        extras = dict(log.extras)
        for i, c in enumerate(log.input_names):
            if c.startswith("w"):
                extras[cls._next(c)] = next_of(np.asarray(log.inputs[:, i], dtype=float))
        return replace(log, extras=extras)

    def derive_signals(self, t, commands):
        out = {}
        for c, v in commands.items():
            out[self._next(c)] = self._next_rows(np.asarray(v, dtype=float))
        if self.hold == "linear":
            t = np.asarray(t, dtype=float)
            h = np.diff(t)
            out["t@row"] = t
            out["h@row"] = np.append(h, h[-1:]) if len(h) else np.ones_like(t)
        return out

    @classmethod
    def toward_previous_row(cls, log):
        """``log`` with this effect's next-row speeds replaced by the previous row's: the same
        blend taken the other way, a half-row delay. White noise on the logged speeds is
        averaged by a blend either way, and favours both alike; a timing favours one (speeds
        that sample a varying signal: the next row, by thousands; a held command: neither). The
        score test of the timing is read beside it (``diagnosis.screening.row_timing_words``).
        The derived columns it sets are kept by :meth:`QuadrotorModel.prepare_log`."""
        return cls._with_next_rows(log, cls._previous_rows)

    @classmethod
    def toward_central_difference(cls, log):
        """``log`` with this effect's next-row speeds replaced by ``w_k + (w_(k+1) - w_(k-1))/2``:
        the blend then moves along the central difference of the speeds, a lead with no lag
        mirrored in it. White noise on the logged speeds favours a blend toward the next row and
        one toward the previous row by the same amount on average, and this direction is their
        difference: the noise's share cancels, a timing's stays (the score test of the rows'
        timing on held speeds with noise, ``diagnosis.screening.row_timing_words``)."""
        return cls._with_next_rows(log, lambda v: v + 0.5 * (cls._next_rows(v) - cls._previous_rows(v)))

    def modify(self, ctx):
        n = ctx.airframe.n_rotors
        nxt = ca.vertcat(*[ctx.signals[self._next(f"w{i + 1}")] for i in range(n)])
        s = ctx.params["s_lead"]
        if self.hold == "linear":
            # the fraction of the row the integrator is at (its stages run from the row's time)
            s = s - 0.5 + (ctx.t - ctx.signals["t@row"]) / ctx.signals["h@row"]
        w = (1 - s) * ctx.w_command + s * nxt
        # the speeds at the sample's instant (the row's start): the ramp through the samples,
        # whose mean over the row is the held blend; "linear" holds that ramp already
        ctx.w_at_sample = w if self.hold == "linear" else \
            ctx.w_command + (s - 0.5) * (nxt - ctx.w_command)
        ctx.w_command = w
        ctx.w = w
        ctx.w_row_mean = w

    def modify_measurement(self, ctx, y):
        # An accelerometer sample is the specific force at its instant, the thrust of the speeds
        # then, not of the row's mean the dynamics hold (an audit: with ax, ay, az logged,
        # s_lead fitted 0.385 +- 0.013 where it is 0.51 without them and 0.517 in truth). Only
        # while the rotors act with the logged speeds: a motor lag's state is instantaneous.
        if ctx.w is not ctx.w_row_mean or self.hold == "linear":
            return
        extra = ctx.params["K_T"] * ca.sum1(ctx.thrust_scale * (ctx.w_at_sample ** 2 - ctx.w ** 2))
        y["az"] = y["az"] - extra / ctx.airframe.mass

"""A greybox CSV log that holds the vehicle standing on the ground before take-off and after
touchdown (what a user's own logging tool writes; the importers trim their flights).

A thirty-second blind audit's log did (rotors stopped in 15 % of its rows, on the floor in
23 %): it was fitted without a word, the thrust said to carry 79 % of the weight "or the mass
or the rotor speeds' units are wrong", a K_T 26 % off offered, Kd[2] on its bound. Now
``greybox fit``, ``diagnose`` and ``batch`` leave those rows out with a note
(:func:`greybox.io.airborne_log`), and ``greybox.fit`` in Python warns of them."""
import numpy as np
import pytest

from greybox import load_log
from greybox.errors import GreyboxInputError
from greybox.fitting.api import _ground_warnings
from greybox.io import airborne_log

DEMO = "greybox/data/logs/demo_ground_effect.csv"


def _with_ground(log, before: float = 3.0, spin_up: float = 1.0, after: float = 2.0, rest_z: float = -0.05,
                 seed: int = 0):
    """``log`` (a flight) with ``before`` s on the ground ahead of it (rotors stopped, then
    spinning up to 60 % of the flight's median speed for the last ``spin_up`` s) and
    ``after`` s stopped on the ground behind it, at the resting height ``-rest_z`` with 1 mm of
    position noise; returns the new log and the row range of the flight."""
    rng = np.random.default_rng(seed)
    dt = float(np.median(np.diff(log.t)))
    n0, n1 = int(round(before / dt)), int(round(after / dt))
    w_fly = float(np.median(log.inputs[:, :4]))

    def rest_rows(n, speeds):
        out = np.full((n, log.outputs.shape[1]), np.nan)
        for j, name in enumerate(log.output_names):
            if name in ("x", "y", "z"):
                out[:, j] = (rest_z if name == "z" else 0.0) + 1e-3 * rng.standard_normal(n)
            elif name in ("phi", "theta", "psi"):
                out[:, j] = 2e-3 * rng.standard_normal(n)
            elif name in ("p", "q", "r"):
                out[:, j] = 5e-3 * rng.standard_normal(n)
        return np.column_stack([speeds] * log.inputs.shape[1]), out

    ramp = np.where(np.arange(n0) * dt >= before - spin_up, 0.6 * w_fly, 0.0)
    u0, y0 = rest_rows(n0, ramp)
    u1, y1 = rest_rows(n1, np.zeros(n1))
    t = np.concatenate([np.arange(n0) * dt, before + log.t - log.t[0],
                        before + log.t[-1] - log.t[0] + dt * (1 + np.arange(n1))])
    new = type(log)(t, np.vstack([u0, log.inputs, u1]), list(log.input_names), np.vstack([y0, log.outputs, y1]),
                    list(log.output_names), {}, [], "grounded.csv")
    return new, (n0, n0 + log.t.size)


def test_the_rows_on_the_ground_at_the_start_and_end_are_left_out_with_a_note():
    flight = load_log(DEMO)
    log, (k0, k1) = _with_ground(flight)
    out = airborne_log(log)
    # the flight, and only the flight: the spin-up on the ground is not airborne either
    assert out.t.size == k1 - k0 and out.t[0] == pytest.approx(log.t[k0]), (out.t[0], log.t[k0])
    np.testing.assert_array_equal(out.inputs, flight.inputs)
    note = out.notes[-1]
    assert note.startswith("grounded.csv: on the ground at its start and end (take-off at 3.00 s, touchdown at"), note
    assert "resting height 0.050 m" in note, note
    assert f"the {k0} rows before and {log.t.size - k1} after left out" in note, note
    assert "the model has no ground reaction force" in note, note
    # greybox.fit in Python is given it as it is: its warnings say so
    words = _ground_warnings([log])
    assert len(words) == 1 and "fitted as data" in words[0] and "greybox.io.airborne_log(log)" in words[0], words
    assert _ground_warnings([out]) == []


def test_a_log_that_begins_in_the_air_or_ends_on_the_ground_only():
    flight = load_log(DEMO)
    assert airborne_log(flight) is flight                        # in the air from first row to last
    log, (k0, k1) = _with_ground(flight, before=0.0, spin_up=0.0, after=1.5)
    out = airborne_log(log)
    assert out.t.size == k1 - k0 and "on the ground at its end" in out.notes[-1], out.notes[-1]
    assert "in the air when the log begins" in out.notes[-1], out.notes[-1]


def test_a_vehicle_that_never_leaves_the_ground_is_refused_and_one_without_a_height_is_left_alone():
    flight = load_log(DEMO)
    log, _ = _with_ground(flight)
    sitting = log.slice(0, int(np.flatnonzero(log.t >= 2.9)[0]))   # stopped, then spinning up: never aloft
    sitting.outputs[:, sitting.output_names.index("z")] = -0.05
    with pytest.raises(GreyboxInputError, match="never leaves the ground"):
        airborne_log(sitting, "sitting.csv")
    blind = log.slice(0, log.t.size)
    blind.outputs[:, [blind.output_names.index(n) for n in ("x", "y", "z")]] = np.nan
    assert airborne_log(blind) is blind                          # no height, no accelerometer: cannot tell


def test_the_command_imbalance_reads_the_flight_not_the_rotors_spinning_up_on_the_ground(monkeypatch):
    """Standing on the floor the vehicle is "steady" while its rotors spin up unequally (an
    integrator winding up on the ground): a blind audit's log showed a step in one rotor's
    share at take-off (t = 11-16), which would end its diagnosis as a rotor changed in flight.
    The imbalance reads the flight only; read with the ground rows, the same log steps."""
    from greybox import QuadrotorModel, load_airframe
    from greybox.diagnosis import analysis, command_imbalance
    flight = load_log(DEMO)
    log, (k0, _) = _with_ground(flight, before=4.0, spin_up=3.0)
    log.inputs[:k0, 0] *= 1.3
    model = QuadrotorModel(load_airframe("greybox/data/airframes/paper.toml"))
    assert command_imbalance(model, flight).share_step is None
    assert command_imbalance(model, log).share_step is None
    monkeypatch.setattr(analysis, "_in_the_air", lambda lg: lg)
    step = command_imbalance(model, log).share_step
    assert step is not None and step["rotor"] == "w1" and step["t"] <= 4.5, step

"""The thirty-fourth blind audit's 1.6 kg "plus" quadrotor on 10-inch props, flown in many short
flights (``tests/audit34_sim.py``: quaternion RK4 at 1 ms under its own 250 Hz geometric
controller, its model 5-10 % off; 20-ms motors; positions at 50 Hz with 6 mm of noise; flights of
8-18 s, per-flight winds and a battery sag growing from flight to flight; checked against
``greybox simulate`` to 2e-9 m; its files reproduced byte for byte).

Right there: the control flights null, certified and adequate, within 1.9 std; each flight's wind
within 0.04 m/s and the shared K_T within 0.05 %; batch summaries, reruns and a broken flight.
Wrong, and mended: three of its fifteen honest flights were refused as frame or unit errors
(exit 2): circles with yaw swings "turned by 59 degrees" (in a circle the velocity is the
acceleration turned by 90 degrees, so beside it any turn fits), and a 10-s climb "psi in
degrees?" (over ten smoothing windows neither reading showed the motion beyond the null). Also
w0..w3 columns ended in a traceback, and ``fit --validation`` took an estimation flight as its
own validation."""
import pytest

from greybox.data import load_log

import audit34_sim as sim

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("name", ["c1_f5", "c2_f4", "c2_f5"])
def test_honest_flights_are_not_refused_as_frame_or_unit_errors(tmp_path, name):
    plan = {p[0]: p for p in sim.CASE1 + sim.CASE2}[name]
    _, kind, dur, seed, *rest = plan
    wind, gust, sag = rest if rest else ((0.0, 0.0), 0.0, (0.0, 0.0))
    o = sim.fly(sim.TRUTH, kind, dur, seed, wind0=wind, gust=gust, sag=sag)
    path = tmp_path / f"{name}.csv"
    sim.write_log(str(path), o, sim.np.random.default_rng(seed + 1000))
    log = load_log(path)                    # refused before: "turned by 59 degrees", "psi in degrees?"
    assert len(log) > 2000 and log.measures("x")

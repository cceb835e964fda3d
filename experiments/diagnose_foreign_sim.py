"""The diagnosis on flights of an independent simulator (tests/foreign_sim.py): its own
rigid-body dynamics (rotation matrices, solve_ivp), its own cascaded controller, motor lag
with the actual rotor speeds logged, its own functional forms of the effects.

Each case: two 20 s flights of the same manoeuvres (seeds 2 and 3 unless ``--seeds`` says
otherwise, the second starting at another yaw); greybox starts from K_T 30 % high and b 30 %
low, estimates on the first flight and validates on the second, adding effects while they
are significant. Other seeds are other noise, gusts of the controller's excitation and
dropouts: the same verdicts there say the result is not one draw's.

    python experiments/diagnose_foreign_sim.py [--case NAME ...] [--seeds EST VAL]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from foreign_sim import airframe_dict, crazyflie, one_kg, simulate_flight  # noqa: E402

from greybox import QuadrotorModel  # noqa: E402
from greybox.airframe import airframe_from_dict  # noqa: E402
from greybox.diagnosis import diagnose  # noqa: E402

CASES = {
    "30 g, nothing missing": (crazyflie, {}),
    "30 g, hub rotor drag (damps the body rates)": (crazyflie, {"rotor_drag_hub": 1e-6}),
    "1 kg, nothing missing": (one_kg, {}),
    "1 kg, ground effect per rotor at the hub height": (one_kg, {"ground_effect": True}),
    "1 kg, rotor 3 at 90 %": (one_kg, {"motor_gains": [1, 1, 0.9, 1], "motor_gains_torque": True}),
}


def run(name: str, seeds: tuple[int, int] = (2, 3)) -> str:
    make, effects = CASES[name]
    vehicle = make()
    est = simulate_flight(vehicle, duration=20.0, seed=seeds[0], **effects)
    val = simulate_flight(vehicle, duration=20.0, seed=seeds[1], psi0=0.5, **effects)
    model = QuadrotorModel(airframe_from_dict(airframe_dict(vehicle, K_T_guess_factor=1.3, b_guess_factor=0.7)))
    t0 = time.perf_counter()
    d = diagnose(model, est.log, validation=val.log)
    dt = time.perf_counter() - t0
    truth = est.truth["greybox_equivalent"]
    base = d.baseline
    kt = f"{100 * (base.value('K_T') / truth['K_T'] - 1):+.1f} %"
    b = f"{100 * (base.value('b') / truth['b'] - 1):+.1f} %"
    added = [e for e in d.final_model.effect_names if e not in model.effect_names] if d.final_model else []
    top = d.ranking[0] if d.ranking else None
    explained = f"{100 * top.explained:.0f} %" if top is not None and top.explained is not None and d.verdict else "-"
    final = d.final_prediction.total if d.final_prediction is not None else d.baseline_prediction.total
    row = (f"| {name} | {'yes' if d.baseline_certified else 'no'} | {kt} | {b} | {d.verdict or 'null'} | "
           f"{', '.join(added) or '-'} | {explained} | {', '.join(d.unexplained) or '-'} | "
           f"{d.baseline_prediction.total:.3f} -> {final:.3f} | {dt:.0f} s |")
    print(d.summary(), file=sys.stderr)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", action="append", choices=sorted(CASES), help="run only these cases")
    ap.add_argument("--seeds", nargs=2, type=int, default=(2, 3), metavar=("EST", "VAL"),
                    help="the estimation and validation flights' seeds (default 2 3)")
    args = ap.parse_args()
    print("| case | baseline certified | K_T err | b err | verdict | added | explained | still far off | "
          "validation nrmse | time |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.case or list(CASES):
        print(run(name, tuple(args.seeds)), flush=True)


if __name__ == "__main__":
    main()

"""How predictable are a real Crazyflie's roll and pitch from its logged motor commands?

    python experiments/real_predictability.py [FILES...]

For each NanoBench flight (default: every ``../shared/realdata/nanobench/*.csv``), the
attitude change over a horizon ``H`` beyond the naive predictor's (constant body rates),
``sum_k (omega[i+k] - omega[i]) dt`` per body axis (the small-angle attitude error of the
naive predictor), is regressed on the same double integral of:

- ``w^2``: the four logged squared rotor speeds at lags 0..10 samples (any per-motor gain,
  any motor lag or delay up to 0.1 s, a constant trim) — every model whose torque is linear
  in the logged ``w_i^2``;
- ``w^2 + v_b + omega``: the same plus body velocity and body rates (drag moments, rate
  damping);
- ``Δw^2`` (disturbance held): the change of the lagged ``w^2`` since the window's start
  only — a model that knows the torque the vehicle feels at the start (a disturbance
  observer's estimate of everything the commands do not show, held over the window) and
  predicts only what the change of the commands adds to it.

Two one-input forms of the mixer's command ``u`` (the roll, pitch or yaw combination of the
four ``w_i^2``) ask *how* the commands carry what they carry:

- **plant form**: ``k u`` delayed by 0-100 ms or through a first-order lag of 20-200 ms, and
  a trim (the best of these) — the form of every torque model a plant has; its gain is
  printed as a share of the published one (roll, pitch: ``arm/sqrt(2) K_T / J``, ``K_T``
  from the hover speed) or, for yaw, as the ``b/K_T`` it implies (m);
- **command change**: ``k (u[t-1] - u[t])`` and a trim — the angular acceleration following
  the command's *change* with the opposite sign, i.e. the logged command read as the rate
  loop's answer (``u ~ -K omega``: the command moves as the measured rate does). A free fit of
  lags 0 and 1 lands on equal and opposite gains on every flight.

The regression is fitted on the first half of the flight and scored on the second (held
out). Its held-out RMS is what the best such model could reach; when it is not below the
naive predictor's, no model driven by these inputs beats the naive predictor on that axis.
Writes ``experiments/out/real_predictability.md``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import tomllib

import numpy as np

from greybox import QuadrotorModel
from greybox.airframe import airframe_from_dict
from greybox.diagnosis import command_predictability
from greybox.importers import crazyflie_airframe_toml, import_nanobench
from greybox.model import rotation_matrices

from real_crazyflie import nanobench_files  # the sibling script: how flights are named

HERE = Path(__file__).resolve().parent
LAGS = range(0, 11, 2)


def bound(path: Path, horizon: float) -> dict[str, tuple]:
    """{axis: (naive RMS, best w^2-linear RMS, best w^2+v_b+omega RMS, best Δw^2 RMS with the
    start's torque held, plant form RMS over its naive one, its gain (share of the published,
    or b/K_T in m for yaw), its delay or lag (str), command change RMS over its naive one, its
    gain (same units))}, RMS in rad, held out; the last five from
    :func:`greybox.diagnosis.command_predictability`."""
    imported = import_nanobench(path)
    log = imported.log
    dt = float(np.median(np.diff(log.t)))
    H = int(round(horizon / dt))
    om = np.column_stack([log.output(c) for c in "pqr"])
    eul = np.column_stack([log.output(c) for c in ("phi", "theta", "psi")])
    pos = np.column_stack([log.output(c) for c in "xyz"])
    ok = np.isfinite(om).all(1) & np.isfinite(eul).all(1) & np.isfinite(pos).all(1)
    t = log.t
    om = np.column_stack([np.interp(t, t[ok], om[ok, i]) for i in range(3)])
    v = np.column_stack([np.gradient(np.interp(t, t[ok], pos[ok, i]), t) for i in range(3)])
    eul = np.column_stack([np.interp(t, t[ok], eul[ok, i]) for i in range(3)])
    vb = np.einsum("kji,kj->ki", rotation_matrices(eul[:, 0], eul[:, 1], eul[:, 2]), v)
    w2 = log.inputs[:, :4] ** 2
    n = len(t)
    idx = np.arange(max(LAGS) + 1, n - H)

    def double_integral(x: np.ndarray) -> np.ndarray:
        c1 = np.cumsum(x, axis=0) * dt
        c2 = np.cumsum(c1, axis=0) * dt
        return c2[idx + H] - c2[idx] - H * dt * c1[idx]

    c_om = np.cumsum(om, axis=0) * dt
    y_all = (c_om[idx + H] - c_om[idx]) - H * dt * om[idx]
    ones = np.ones((n, 1))
    lagged = [np.roll(w2, j, axis=0) for j in LAGS]
    sets = [lagged + [ones], lagged + [ones, vb, om]]
    # the double integral of x(t) - x(start): the start's torque is held, only changes add
    held = np.concatenate([double_integral(x) - 0.5 * H * (H + 1) * dt ** 2 * x[idx] for x in lagged], axis=1)
    half = len(idx) // 2

    def held_out(X: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
        scale = np.maximum(np.abs(X[:half]).max(axis=0), 1e-300)
        coef, *_ = np.linalg.lstsq(X[:half] / scale, y[:half], rcond=None)
        r = y[half:] - (X[half:] / scale) @ coef
        return float(np.sqrt(np.mean(r ** 2))), coef / scale

    # the plant form and the command change: the diagnosis's own check (greybox.diagnosis.
    # predictability), with the imported airframe's published K_T, inertia and arm
    model = QuadrotorModel(airframe_from_dict(tomllib.loads(
        crazyflie_airframe_toml(hover_rotor_speed=imported.hover_rotor_speed))))
    cp = command_predictability(model, log, horizons=(horizon,))
    out = {}
    for a, axis in enumerate(("roll", "pitch", "yaw")):
        y = y_all[:, a]
        naive = float(np.sqrt(np.mean(y[half:] ** 2)))
        best = []
        for X in [double_integral(np.concatenate(feats, axis=1)) for feats in sets] + [held]:
            best.append(held_out(X, y)[0])
        out[axis] = (naive, *best, cp.ratio("plant", axis, horizon), cp.plant_gain[axis][0],
                     cp.plant_timing[axis][0], cp.ratio("change", axis, horizon), cp.change_gain[axis][0])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--out", type=Path, default=HERE / "out" / "real_predictability.md")
    a = ap.parse_args()
    files = nanobench_files(a.files)
    lines = ["| flight | horizon | axis | naive (rad) | best linear in w² (rad) | + v_b, ω (rad) "
             "| Δw², start's torque held (rad) | plant form: / naive, gain, timing "
             "| command change: / naive, gain |",
             "|---|---|---|---|---|---|---|---|---|"]

    def gain(axis: str, k: float) -> str:
        return f"b/K_T {k:.4f} m" if axis == "yaw" else f"{k:.3f}"

    for f in files:
        for h in (0.25, 0.5):
            for axis, (nv, *bs, plant, k_plant, how, change, k_change) in bound(f, h).items():
                lines.append(f"| {f.stem} | {h:g} s | {axis} | {nv:.4f} | " +
                             " | ".join(f"{b:.4f} ({100 * (b / nv - 1):+.0f} %)" for b in bs) +
                             f" | {plant:.2f}, {gain(axis, k_plant)}, {how}"
                             f" | {change:.2f}, {gain(axis, k_change)} |")
        print("\n".join(lines[-6:]), flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

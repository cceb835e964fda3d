"""Vision front end: accuracy against the Cramér–Rao bound, throughput against a bare
OpenCV loop, robustness to bad frames. Issue 6's targets, measured in one run.

    python experiments/bench_vision.py [--frames-per-bin 80] [--out experiments/out/bench_vision]

* Accuracy: 640x480 frames rendered by greybox.synthcam through the bundled mirror rig
  (marker 0.15 m) at heights 0.5-1.5 m, random tilt (sigma 0.1 rad) and yaw, pixel noise,
  and Gaussian noise of sigma_c px added to each marker corner. Position RMSE (3-D) of the
  vision-only (6-DoF) estimate against the 6-DoF bound, and of the IMU-aided estimate
  (IMU tilt with 0.01 rad noise) against the bound with that prior. Target: RMSE <= 1.5 x
  CRB. Flips: frames where the rejected IPPE solution was > 5 deg nearer the truth than
  the kept one; gross errors: position error > 5 x the bound's 3-D std. Target: none.
  Each height is a smooth 60-fps sequence (the tracker keeps its last pose, as in flight).
  The added corner noise (0.3 and 0.6 px) is above what rendering + detection give by
  themselves (measured and reported as the "detector floor", ~0.1-0.19 px).
* Throughput: the same frames through MarkerTracker.process and through a bare
  cv2.flip + ArucoDetector.detectMarkers + cv2.solvePnP(IPPE_SQUARE) with the same
  detector settings (the flip is part of the bare path: without it a mirror image does not
  decode), one thread, each frame through all of them back to back (paired: load drifts
  on a shared machine hit both alike), totals over the rounds. Targets: ours >= 90 % of
  the bare loop's frames/s and >= 200 frames/s.
* Robustness: a sequence with marker-less, occluded, motion-blurred and corrupt frames:
  every one counted as a skip with its reason, no exception.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from greybox.synthcam import SyntheticCamera  # noqa: E402
from greybox.rotations import rotation as _euler_to_rotation  # noqa: E402
from greybox.vision import (MarkerTracker, default_detector_parameters,  # noqa: E402
                            load_rig, position_crb, read_frames)

RIG = Path(__file__).resolve().parents[1] / "greybox" / "data" / "cameras" / "mirror_down.toml"
HEIGHTS = [0.5, 0.75, 1.0, 1.25, 1.5]
SIGMAS = (0.3, 0.6)   # px: above the renderer + detector's own ~0.1-0.19 px (see detector_floor)
TILT, IMU_TILT_NOISE = 0.1, 0.01


def _angle_deg(A: np.ndarray, B: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(A.T @ B) - 1) / 2, -1, 1)))


def in_view(rig, R: np.ndarray, p: np.ndarray, border: float = 15.0) -> bool:
    """The marker *and its white quiet zone* (one code cell around it) lie in the image.
    OpenCV's detector misses markers whose quiet zone touches the image border (measured:
    whole runs of such frames fail), which is a framing question, not an accuracy one."""
    m = rig.markers[0]
    cells = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, rig.dictionary)).markerSize + 2
    outer = m.corners_marker(rig.marker_size * (cells + 2) / cells) @ m.R_wm.T + m.position
    px, front = rig.project(R, p, outer)
    cam = rig.camera
    return bool(front.all() and np.all((px > border) & (px < [cam.width - 1 - border, cam.height - 1 - border])))


def random_pose(rig, h: float, rng: np.random.Generator):
    """A pose at height h whose marker is wholly in view."""
    while True:
        e = np.array([rng.normal(0, TILT), rng.normal(0, TILT), rng.uniform(-math.pi, math.pi)])
        R = _euler_to_rotation(*e)
        p = np.array([*rng.uniform(-0.3, 0.3, 2) * h, -h])
        if in_view(rig, R, p):
            return e, R, p


def sequence(rig, h: float, n: int, fps: float, rng: np.random.Generator):
    """A smooth flight at height ~h over the marker: (euler, R, p) per frame, frames whose
    marker is not wholly in view left out."""
    ph = rng.uniform(0, 2 * math.pi, 6)
    out = []
    for t in np.arange(n) / fps:
        e = np.array([TILT * math.sin(2.1 * t + ph[0]), TILT * math.sin(1.7 * t + ph[1]), 0.8 * t + ph[2]])
        p = np.array([0.2 * h * math.sin(0.9 * t + ph[3]), 0.2 * h * math.sin(0.7 * t + ph[4]),
                      -h + 0.05 * math.sin(1.3 * t + ph[5])])
        R = _euler_to_rotation(*e)
        if in_view(rig, R, p):
            out.append((t, e, R, p))
    return out


def accuracy(rig, sigma_c: float, n_per_bin: int, seed: int) -> dict:
    """Sequences at each height (the tracker keeps its last pose, as in flight)."""
    rng = np.random.default_rng(seed)
    cam = SyntheticCamera(rig, corner_noise_px=sigma_c, pixel_noise=2.0, exposure_jitter=0.1, seed=seed)
    free = MarkerTracker(rig, tilt_sigma=None)
    aided = MarkerTracker(rig, tilt_sigma=IMU_TILT_NOISE, corner_sigma_px=max(sigma_c, 0.1))
    bins = []
    for h in HEIGHTS:
        rows = {"free": [], "aided": []}
        crb = {"free": [], "aided": []}
        skipped = {"free": 0, "aided": 0}
        flips = {"free": 0, "aided": 0}
        gross = {"free": 0, "aided": 0}
        free.reset()
        aided.reset()
        frames = sequence(rig, h, n_per_bin, 60.0, rng)
        for t, e, R, p in frames:
            img = cam.render(lambda _: (R, p), t).image
            imu = tuple(e + rng.normal(0, IMU_TILT_NOISE, 3))
            results = {"free": free.process(img, t),                    # vision alone
                       "aided": aided.process(img, t, attitude=imu)}    # with the IMU's tilt
            for name, r in results.items():
                if isinstance(r, str):
                    skipped[name] += 1
                    continue
                c = np.trace(position_crb(rig, R, p, sigma_c, tilt_sigma=None if name == "free" else IMU_TILT_NOISE))
                err = float(np.sum((r.position - p) ** 2))
                rows[name].append(err)
                crb[name].append(c)
                gross[name] += err > 25 * c
                flips[name] += r.alternative is not None and _angle_deg(r.alternative, R) + 5 < _angle_deg(r.R_wb, R)
        b = {"height": h, "frames": len(frames)}
        for name in rows:
            rmse = math.sqrt(np.mean(rows[name]))
            bound = math.sqrt(np.mean(crb[name]))
            b[name] = {"rmse_m": rmse, "crb_m": bound, "ratio": rmse / bound, "skipped": skipped[name],
                       "flips": int(flips[name]), "gross": int(gross[name])}
        bins.append(b)
    return {"sigma_c_px": sigma_c, "bins": bins}


def detector_floor(rig, n: int, seed: int) -> dict:
    """The corner noise the renderer + detector give by themselves, as the equivalent iid
    corner sigma (px) that would produce the same 6-DoF position RMSE."""
    rng = np.random.default_rng(seed)
    cam = SyntheticCamera(rig, corner_noise_px=0.0, pixel_noise=2.0, exposure_jitter=0.1, seed=seed)
    tracker = MarkerTracker(rig, tilt_sigma=None)
    out = {}
    for h in HEIGHTS:
        e2, c1 = [], []
        for _ in range(n):
            e, R, p = random_pose(rig, h, rng)
            r = tracker.pose_from_corners(tracker.detect(cam.render(lambda t: (R, p), 0.0).image), 0.0, prior=R)
            if not isinstance(r, str):
                e2.append(np.sum((r.position - p) ** 2))
                c1.append(np.trace(position_crb(rig, R, p, 1.0)))
        out[str(h)] = math.sqrt(np.mean(e2) / np.mean(c1))
    return out


def throughput(rig, n: int, rounds: int, seed: int) -> dict:
    cv2.setNumThreads(1)
    rng = np.random.default_rng(seed)
    cam = SyntheticCamera(rig, corner_noise_px=0.2, pixel_noise=2.0, seed=seed)
    frames, att = [], []
    for i in range(n):
        e, R, p = random_pose(rig, rng.uniform(0.5, 1.5), rng)
        frames.append(cam.render(lambda t: (R, p), 0.0).image)
        att.append(tuple(e))
    params = default_detector_parameters()
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, rig.dictionary)), params)
    obj = rig.markers[0].corners_marker(rig.marker_size)
    K, dist, _, _ = rig.virtual_camera
    tracker = MarkerTracker(rig, detector_parameters=params)

    def bare_one(img) -> bool:
        corners, ids, _ = det.detectMarkers(cv2.flip(img, 1))
        return ids is not None and cv2.solvePnP(obj, corners[0], K, dist, flags=cv2.SOLVEPNP_IPPE_SQUARE)[0]

    def ours_one(img, i) -> bool:
        return not isinstance(tracker.process(img, i / 60), str)

    def aided_one(img, i) -> bool:
        return not isinstance(tracker.process(img, i / 60, attitude=att[i]), str)

    # paired timing: each frame through all three back to back (the order rotating), so a
    # shared machine's load drifts affect them alike; totals over all rounds
    clock = time.perf_counter
    total = {"bare": 0.0, "ours": 0.0, "ours_imu_aided": 0.0}
    found = {"bare": 0, "ours": 0, "ours_imu_aided": 0}
    for rnd in range(rounds):
        tracker.reset()
        for i, img in enumerate(frames):
            calls = [("bare", lambda: bare_one(img)), ("ours", lambda: ours_one(img, i)),
                     ("ours_imu_aided", lambda: aided_one(img, i))]
            k = (i + rnd) % 3
            for name, f in calls[k:] + calls[:k]:
                t0 = clock()
                ok = f()
                total[name] += clock() - t0
                found[name] += bool(ok) if rnd == 0 else 0
    fps = {k: rounds * n / v for k, v in total.items()}
    return {"frames": n, "rounds": rounds, "fps": fps, "poses": found,
            "ratio_ours_to_bare": fps["ours"] / fps["bare"],
            "ratio_aided_to_bare": fps["ours_imu_aided"] / fps["bare"]}


def robustness(rig, seed: int) -> dict:
    cam = SyntheticCamera(rig, pixel_noise=2.0, seed=seed)
    blur_cam = SyntheticCamera(rig, pixel_noise=2.0, exposure_time=0.02, blur_samples=9, seed=seed)
    R, p = np.eye(3), np.array([0.0, 0.0, -0.9])
    good = cam.render(lambda t: (R, p), 0.0).image
    occluded = good.copy()
    c = rig.marker_corners_px(R, p, 0)[0]
    cv2.fillConvexPoly(occluded, np.round(np.vstack([c[0], c[1], c.mean(0)])).astype(np.int32), 60)
    blurred = blur_cam.render(lambda t: (R, p + np.array([3.0, 0, 0]) * t), 0.0).image
    empty = np.full_like(good, 110)
    kinds = ["good", "empty", "occluded", "blurred", "corrupt", "good"] * 5
    with tempfile.TemporaryDirectory() as d:
        for i, k in enumerate(kinds):
            path = Path(d) / f"frame_{i:03d}.png"
            if k == "corrupt":
                path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
            else:
                cv2.imwrite(str(path), {"good": good, "empty": empty, "occluded": occluded, "blurred": blurred}[k])
        frames, n = read_frames(d, fps=30.0)
        res = MarkerTracker(rig).run(frames)
    expected = {"unreadable": kinds.count("corrupt"),
                "no_marker": kinds.count("empty") + kinds.count("occluded") + kinds.count("blurred")}
    return {"frames": n, "positions": int(len(res.t)), "skipped": res.skipped, "expected": expected,
            "all_counted": res.skipped["unreadable"] == expected["unreadable"]
            and res.skipped["no_marker"] == expected["no_marker"] and len(res.t) == kinds.count("good")}


def plot(results: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, name, title in ((axes[0], "free", "vision alone (6-DoF)"), (axes[1], "aided", "IMU-aided (tilt 0.01 rad)")):
        for res in results:
            h = [b["height"] for b in res["bins"]]
            ax.plot(h, [1000 * b[name]["rmse_m"] for b in res["bins"]], "o-",
                    label=f"RMSE, corner noise {res['sigma_c_px']} px")
            ax.plot(h, [1000 * b[name]["crb_m"] for b in res["bins"]], "k--", lw=1)
        ax.set_xlabel("height above the marker, m")
        ax.set_ylabel("3-D position error, mm")
        ax.set_title(title + " (dashed: Cramér–Rao bound)")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames-per-bin", type=int, default=80)
    ap.add_argument("--throughput-frames", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "out" / "bench_vision"))
    args = ap.parse_args(argv)
    rig = load_rig(RIG)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    acc = []
    print("detector floor ...", file=sys.stderr, flush=True)
    floor = detector_floor(rig, 40, args.seed)
    for k, s in enumerate(SIGMAS):
        print(f"accuracy, corner noise {s} px ...", file=sys.stderr, flush=True)
        acc.append(accuracy(rig, s, args.frames_per_bin, args.seed + k))
    print("throughput ...", file=sys.stderr, flush=True)
    tp = throughput(rig, args.throughput_frames, args.rounds, args.seed)
    print("robustness ...", file=sys.stderr, flush=True)
    rob = robustness(rig, args.seed)
    # the targets are the paper's configuration: position from vision, tilt from the IMU
    worst = max(b["aided"]["ratio"] for r in acc for b in r["bins"])
    flips = sum(b["aided"]["flips"] + b["aided"]["gross"] for r in acc for b in r["bins"])
    verdict = {"accuracy_worst_ratio_to_crb": worst, "accuracy_ok": worst <= 1.5 and flips == 0,
               "flips_or_gross": flips,
               "vision_only_worst_ratio_to_crb": max(b["free"]["ratio"] for r in acc for b in r["bins"]),
               "vision_only_flips_or_gross": sum(b["free"]["flips"] + b["free"]["gross"] for r in acc for b in r["bins"]),
               "throughput_ratio": tp["ratio_ours_to_bare"], "throughput_fps": tp["fps"]["ours"],
               "throughput_ok": tp["ratio_ours_to_bare"] >= 0.9 and tp["fps"]["ours"] >= 200,
               "robustness_ok": rob["all_counted"]}
    summary = {"detector_floor_px": floor, "accuracy": acc, "throughput": tp, "robustness": rob, "targets": verdict,
               "seconds": time.time() - t0, "opencv": cv2.__version__}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    plot(acc, out / "accuracy_vs_crb.png")
    lines = ["# Vision benchmark", "", f"OpenCV {cv2.__version__}, one thread, {summary['seconds']:.0f} s.", "",
             "Renderer + detector alone, as an equivalent corner noise (px) by height: "
             + ", ".join(f"{h} m: {v:.2f}" for h, v in floor.items()) + ".", "",
             "Each cell: 3-D position RMSE / Cramér–Rao bound (ratio); skipped, flips, gross errors.", "",
             "| corner noise px | height m | frames | IMU-aided RMSE / CRB mm | skip / flip / gross "
             "| vision-only RMSE / CRB mm | skip / flip / gross |",
             "|---|---|---|---|---|---|---|"]
    for r in acc:
        for b in r["bins"]:
            f, a = b["free"], b["aided"]
            lines.append(f"| {r['sigma_c_px']} | {b['height']} | {b['frames']} | {1000 * a['rmse_m']:.1f} / "
                         f"{1000 * a['crb_m']:.1f} ({a['ratio']:.2f}) | {a['skipped']} / {a['flips']} / {a['gross']} | "
                         f"{1000 * f['rmse_m']:.0f} / {1000 * f['crb_m']:.0f} ({f['ratio']:.2f}) | "
                         f"{f['skipped']} / {f['flips']} / {f['gross']} |")
    fps = tp["fps"]
    lines += ["", f"Throughput ({tp['frames']} frames x {tp['rounds']} rounds, paired per frame): bare OpenCV "
                  f"{fps['bare']:.0f} frames/s, greybox {fps['ours']:.0f} frames/s "
                  f"({100 * tp['ratio_ours_to_bare']:.0f} % of bare), IMU-aided {fps['ours_imu_aided']:.0f} frames/s "
                  f"({100 * tp['ratio_aided_to_bare']:.0f} %).",
              "", f"Robustness: {rob['frames']} frames, {rob['positions']} positions, skipped {rob['skipped']} "
                  f"(expected {rob['expected']}): {'all counted' if rob['all_counted'] else 'MISMATCH'}.",
              "", "Targets (accuracy: IMU-aided, the paper's configuration): "
              + ", ".join(f"{k} = {v}" for k, v in verdict.items() if k.endswith("_ok"))]
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if all(v for k, v in verdict.items() if k.endswith("_ok")) else 1


if __name__ == "__main__":
    sys.exit(main())

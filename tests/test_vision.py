"""The vision front end: rig geometry through the mirror, pose from corners and from
rendered frames, the Cramér–Rao bound, skips, merge and the CLI."""
from __future__ import annotations

import json
import math
from importlib import resources
from pathlib import Path

import cv2

import numpy as np

from greybox.rotations import rotation
import pytest

from greybox.cli import main
from greybox.data import load_log, log_from_arrays, save_log
from greybox.errors import GreyboxInputError
from greybox.synthcam import SyntheticCamera, trajectory_pose, write_sequence
from greybox.vision import (AttitudeSpanWarning, MarkerTracker, imu_attitude, load_rig, merge_vision,
                            position_crb, read_frames, rig_from_dict, rotation_to_euler,
                            _rodrigues)

RIG_PATH = resources.files("greybox") / "data" / "cameras" / "mirror_down.toml"


@pytest.fixture(scope="module")
def rig():
    return load_rig(RIG_PATH)


def _doc(**over):
    doc = {"camera": {"width": 640, "height": 480, "fx": 420.0, "fy": 420.0, "position": [0.05, 0, 0],
                      "optical_axis": [1, 0, 0], "image_right": [0, 1, 0]},
           "mirror": {"point": [0.09, 0, 0], "normal": [1, 0, -1]},
           "markers": {"dictionary": "DICT_4X4_50", "size": 0.15,
                       "marker": [{"id": 0, "position": [0, 0, 0], "yaw": 0.0}]}}
    for k, v in over.items():
        doc[k] = v
    return doc


def _detector_corners(rig, R, p, mid=0):
    """Exact corners as the detector sees them (left-right flipped when mirrored)."""
    px, front = rig.marker_corners_px(R, p, mid)
    assert front
    if rig.mirror is not None:
        px = px.copy()
        px[:, 0] = rig.camera.width - 1 - px[:, 0]
    return px


def test_mirror_geometry_by_hand(rig):
    # The 45-degree mirror 4 cm ahead of the camera makes a virtual camera at
    # body (0.09, 0, -0.04) looking straight down, image up = body backward (the mirror
    # turns the forward view down: the image's top edge sees the ground behind). Level at
    # 1 m over the marker: its centre is 1.04 m below the virtual camera and 0.09 m behind
    # it, so it appears on the middle column, 420 * 0.09 / 1.04 px above the centre row.
    K, dist, R_bv, c_b = rig.virtual_camera
    np.testing.assert_allclose(c_b, [0.09, 0.0, -0.04], atol=1e-12)
    np.testing.assert_allclose(R_bv[:, 2], [0, 0, 1], atol=1e-12)       # looks down
    np.testing.assert_allclose(-R_bv[:, 1], [-1, 0, 0], atol=1e-12)     # image up = body backward
    assert np.linalg.det(R_bv) == pytest.approx(1.0)                     # a proper camera
    assert np.linalg.det(rig.mirror.householder @ rig.camera.R_bc) == pytest.approx(-1.0)
    px, front = rig.project(np.eye(3), np.array([0.0, 0.0, -1.0]), np.zeros((1, 3)))
    assert front.all()
    np.testing.assert_allclose(px[0], [319.5, 239.5 - 420 * 0.09 / 1.04], atol=1e-9)
    # the real image is a mirror image: the corner order turns clockwise -> anticlockwise
    c = rig.marker_corners_px(np.eye(3), np.array([0.0, 0.0, -1.0]), 0)[0]
    signed_area = 0.5 * np.sum(c[:, 0] * np.roll(c[:, 1], -1) - np.roll(c[:, 0], -1) * c[:, 1])
    flipped = _detector_corners(rig, np.eye(3), np.array([0.0, 0.0, -1.0]))
    flipped_area = 0.5 * np.sum(flipped[:, 0] * np.roll(flipped[:, 1], -1) - np.roll(flipped[:, 0], -1) * flipped[:, 1])
    assert np.sign(signed_area) == -np.sign(flipped_area)


@pytest.mark.parametrize("mirror", [True, False])
@pytest.mark.parametrize("dist", [[0, 0, 0, 0, 0], [-0.12, 0.03, 0.002, -0.003, 0.0]])
def test_pose_from_exact_corners(mirror, dist):
    doc = _doc()
    doc["camera"]["distortion"] = dist
    if not mirror:
        del doc["mirror"]
        doc["camera"]["optical_axis"] = [0, 0, 1]      # looking straight down
        doc["camera"]["image_right"] = [0, 1, 0]
    rig = rig_from_dict(doc)
    tracker = MarkerTracker(rig)
    rng = np.random.default_rng(3)
    for _ in range(20):
        e = (rng.normal(0, 0.15), rng.normal(0, 0.15), rng.uniform(-math.pi, math.pi))
        R = rotation(*e)
        p = np.array([*rng.uniform(-0.2, 0.2, 2), -rng.uniform(0.5, 1.5)])
        est = tracker.pose_from_corners({0: _detector_corners(rig, R, p)}, prior=R)
        assert not isinstance(est, str)
        # OpenCV undistorts iteratively (~1e-5 m here); a wrong sign of the flipped
        # tangential term p2 would be off by ~0.2 m
        tol = 1e-4 if any(dist) else 1e-6
        np.testing.assert_allclose(est.position, p, atol=tol)
        np.testing.assert_allclose(rotation_to_euler(est.R_wb), e, atol=tol)


def test_yaw_sign_by_hand(rig):
    # body turned +0.5 rad (nose east of north): vision must say psi = +0.5, not -0.5
    R = rotation(0.0, 0.0, 0.5)
    p = np.array([0.0, 0.0, -1.0])
    est = MarkerTracker(rig).pose_from_corners({0: _detector_corners(rig, R, p)})
    assert est.euler[2] == pytest.approx(0.5, abs=1e-6)


def test_rendered_frame_pose_and_handedness(rig):
    R = rotation(0.05, -0.04, 0.7)
    p = np.array([0.06, -0.04, -0.8])
    frame = SyntheticCamera(rig, pixel_noise=2.0, seed=1).render(lambda t: (R, p), 0.0)
    tracker = MarkerTracker(rig)
    est = tracker.process(frame.image, 0.0)
    assert not isinstance(est, str)
    assert np.linalg.norm(est.position - p) < 0.01
    assert abs(est.euler[2] - 0.7) < math.radians(1.0)
    # without the flip the mirror image does not decode (ArUco codes are chiral)
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    _, ids, _ = det.detectMarkers(frame.image)
    assert ids is None or 0 not in ids.ravel()


def test_accuracy_reaches_cramer_rao_bound(rig):
    # pure corner noise on exact corners: the estimator's position RMSE against the bound
    sigma = 0.3
    rng = np.random.default_rng(11)
    tracker = MarkerTracker(rig)
    err2, crb, flips = [], [], 0
    for _ in range(400):
        h = rng.uniform(0.5, 1.5)
        e = (rng.normal(0, 0.1), rng.normal(0, 0.1), rng.uniform(-math.pi, math.pi))
        R, p = rotation(*e), np.array([*rng.uniform(-0.15, 0.15, 2) * h, -h])
        c = _detector_corners(rig, R, p) + rng.normal(0, sigma, (4, 2))
        est = tracker.pose_from_corners({0: c}, prior=rotation(*(np.array(e) + rng.normal(0, 0.01, 3))))
        assert not isinstance(est, str)
        err2.append(np.sum((est.position - p) ** 2))
        crb.append(np.trace(position_crb(rig, R, p, sigma)))
        ang = lambda A: math.degrees(math.acos(np.clip((np.trace(A.T @ R) - 1) / 2, -1, 1)))
        flips += est.alternative is not None and ang(est.alternative) + 5 < ang(est.R_wb)
    ratio = math.sqrt(np.mean(err2) / np.mean(crb))
    assert 0.8 < ratio < 1.3, ratio
    assert flips == 0


def test_crb_shrinks_with_noise_and_grows_with_distance(rig):
    R = np.eye(3)
    a = np.trace(position_crb(rig, R, np.array([0, 0, -0.6]), 0.5))
    b = np.trace(position_crb(rig, R, np.array([0, 0, -1.2]), 0.5))
    c = np.trace(position_crb(rig, R, np.array([0, 0, -1.2]), 0.25))
    assert b > 2 * a
    assert c == pytest.approx(b / 4, rel=1e-6)


def test_skips_are_counted_never_crash(rig, tmp_path):
    cam = SyntheticCamera(rig, pixel_noise=2.0, seed=2)
    R, p = np.eye(3), np.array([0.0, 0.0, -0.9])
    good = cam.render(lambda t: (R, p), 0.0).image
    empty = np.full_like(good, 110)
    occluded = good.copy()
    c = rig.marker_corners_px(R, p, 0)[0]
    cv2.fillConvexPoly(occluded, np.round(np.vstack([c[0], c[1], c.mean(0)])).astype(np.int32), 60)
    # motion blur: 3 m/s across a 20 ms exposure, about 25 px of smear
    fast = lambda t: (R, p + np.array([3.0, 0.0, 0.0]) * t)
    blurred = SyntheticCamera(rig, pixel_noise=2.0, exposure_time=0.02, blur_samples=9, seed=3).render(fast, 0.0).image
    for i, img in enumerate([good, empty, occluded, blurred, good]):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), img)
    (tmp_path / "f5.png").write_bytes(b"\x89PNG not really")          # corrupt
    (tmp_path / "f6.png").write_bytes(b"")                            # empty file
    cv2.imwrite(str(tmp_path / "f7.png"), good)
    frames, n = read_frames(tmp_path, fps=30.0)
    assert n == 8
    res = MarkerTracker(rig).run(frames, attitude=lambda t: (0.0, 0.0, 0.0))
    assert res.n_frames == 8
    assert res.skipped["unreadable"] == 2
    assert res.skipped["no_marker"] == 3          # empty, occluded, blurred
    assert list(res.frame_index) == [0, 4, 7]
    np.testing.assert_allclose(res.t, [0.0, 4 / 30, 7 / 30])
    assert np.abs(res.position - p).max() < 0.005
    assert "2 unreadable" in res.summary() and "3 no marker" in res.summary()


def test_mild_blur_and_rolling_shutter_still_track(rig):
    pose = lambda t: (rotation(0.0, 0.0, 0.3 * t), np.array([0.4 * t, 0.1, -1.0]))
    cam = SyntheticCamera(rig, pixel_noise=2.0, exposure_time=0.004, rolling_shutter=0.015, seed=4)
    times = np.arange(0, 0.5, 1 / 60)
    res = MarkerTracker(rig).run(((i, f.t, f.image) for i, f in enumerate(cam.frames(pose, times))),
                                 attitude=lambda t: (0.0, 0.0, 0.3 * t))
    assert len(res.t) == len(times)
    truth = np.array([pose(t)[1] for t in res.t])
    assert np.sqrt(np.mean(np.sum((res.position - truth) ** 2, axis=1))) < 0.01
    np.testing.assert_allclose(res.psi, 0.3 * res.t, atol=0.02)


def test_jumps_rejected_then_relocked(rig):
    tracker = MarkerTracker(rig, max_speed=5.0, reset_after=3)
    R = np.eye(3)
    cam = SyntheticCamera(rig, pixel_noise=1.0, seed=5)
    res = []
    for k, y in enumerate([0.0, 0.01, 0.3, 0.31, 0.32, 0.33]):   # 0.3 m in 1/60 s: 18 m/s
        f = cam.render(lambda t, y=y: (R, np.array([0.0, y, -1.0])), k / 60)
        r = tracker.process(f.image, k / 60, attitude=(0.0, 0.0, 0.0))
        res.append(r if isinstance(r, str) else "ok")
    assert res == ["ok", "ok", "jump", "jump", "ok", "ok"]


def test_rig_errors_name_file_and_key(tmp_path):
    with pytest.raises(GreyboxInputError, match="image_right.*not perpendicular"):
        rig_from_dict(_doc(camera={**_doc()["camera"], "image_right": [1, 0.5, 0]}), "cam.toml")
    with pytest.raises(GreyboxInputError, match=r"cam.toml \[markers\]: unknown dictionary 'DICT_9X9'"):
        rig_from_dict(_doc(markers={"dictionary": "DICT_9X9", "size": 0.1, "marker": [{"id": 0}]}), "cam.toml")
    with pytest.raises(GreyboxInputError, match=r"\[camera\]: missing key 'fx'"):
        doc = _doc()
        del doc["camera"]["fx"]
        rig_from_dict(doc, "cam.toml")
    with pytest.raises(GreyboxInputError, match="'id' must be an integer in 0..49"):
        rig_from_dict(_doc(markers={"size": 0.1, "marker": [{"id": 50}]}))
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera\nwidth = 1")
    with pytest.raises(GreyboxInputError, match="bad.toml: not valid TOML"):
        load_rig(bad)


def test_merge_keeps_vision_times_and_holds_inputs():
    t = np.arange(0, 1.0, 0.005)                       # 200 Hz IMU / rotor log
    U = np.column_stack([400 + 10 * np.sin(t * k) for k in range(1, 5)])
    Y = np.full((t.size, 9), np.nan)
    Y[:, 3:6] = 0.01
    log = log_from_arrays(t, U, Y)
    tv = np.arange(0.0013, 1.2, 1 / 30)                  # 30 Hz vision, own clock, runs past the log
    vals = np.column_stack([tv, 2 * tv, -1 + 0 * tv, 0.1 + 0 * tv])
    m = merge_vision(log, tv, vals, ["x", "y", "z", "psi"])
    assert np.all(np.diff(m.t) > 0)
    rows = ~np.isnan(m.output("x"))
    inside = tv[tv <= t[-1]]
    np.testing.assert_allclose(m.t[rows], inside)
    np.testing.assert_allclose(m.output("y")[rows], 2 * inside)
    # inputs at a vision row are the previous log row's (zero-order hold)
    k = np.searchsorted(t, inside, side="right") - 1
    np.testing.assert_array_equal(m.inputs[rows], U[k])
    # IMU outputs stay only on IMU rows, yaw from the IMU since the log has it
    assert np.isnan(m.output("phi")[rows]).all()
    np.testing.assert_allclose(m.output("psi")[~rows], 0.01)
    assert any("dropped" in n for n in m.notes)


def test_cli_render_vision_merge(tmp_path, rig):
    # a short straight flight over the marker, rendered, then positions and a merged log
    t = np.arange(0, 0.5, 0.005)
    Y = np.zeros((t.size, 9))
    Y[:, 0], Y[:, 1], Y[:, 2], Y[:, 5] = 0.2 * t - 0.05, 0.05, -0.9, 0.2
    log = log_from_arrays(t, np.full((t.size, 4), 420.0), Y)
    save_log(log, tmp_path / "flight.csv")
    assert main(["render", str(tmp_path / "flight.csv"), "--camera", str(RIG_PATH),
                 "--out-dir", str(tmp_path / "frames"), "--fps", "30", "--seed", "1",
                 "--json", str(tmp_path / "r.json")]) == 0
    rendered = json.loads((tmp_path / "r.json").read_text())
    assert rendered["frames"] == 15 and rendered["fps"] == 30.0 and rendered["seed"] == 1
    assert main(["vision", str(tmp_path / "frames"), "--camera", str(RIG_PATH), "--out", str(tmp_path / "pos.csv"),
                 "--timestamps", str(tmp_path / "frames" / "timestamps.csv"), "--json", str(tmp_path / "v.json"),
                 "--imu", str(tmp_path / "flight.csv"), "--quiet"]) == 0
    pos = np.loadtxt(tmp_path / "pos.csv", delimiter=",", skiprows=1)
    assert (tmp_path / "pos.csv").read_text().splitlines()[0] == "t,x,y,z,psi"
    assert len(pos) == 15
    np.testing.assert_allclose(pos[:, 1], 0.2 * pos[:, 0] - 0.05, atol=0.005)
    np.testing.assert_allclose(pos[:, 2], 0.05, atol=0.005)
    np.testing.assert_allclose(pos[:, 3], -0.9, atol=0.005)
    np.testing.assert_allclose(pos[:, 4], 0.2, atol=0.02)
    # the IMU log: no positions; merge puts the 15 vision rows in
    imu = log_from_arrays(t, np.full((t.size, 4), 420.0), np.column_stack([np.full((t.size, 3), np.nan), Y[:, 3:]]))
    save_log(imu, tmp_path / "imu.csv")
    assert main(["merge", str(tmp_path / "imu.csv"), "--vision", str(tmp_path / "pos.csv"),
                 "--out", str(tmp_path / "merged.csv"), "--json", str(tmp_path / "m.json")]) == 0
    merged = load_log(tmp_path / "merged.csv")
    assert (~np.isnan(merged.output("x"))).sum() == 15
    said = json.loads((tmp_path / "m.json").read_text())
    assert said["samples"] == len(merged) and said["rows_from_log"] == t.size and "x" in said["outputs"]


def test_cli_errors_exit_2_without_output(tmp_path, capsys):
    out = tmp_path / "pos.csv"
    assert main(["vision", str(tmp_path / "nope"), "--camera", str(RIG_PATH), "--out", str(out), "--fps", "30"]) == 2
    assert "no such folder or video file" in capsys.readouterr().err
    (tmp_path / "frames").mkdir()
    cv2.imwrite(str(tmp_path / "frames" / "a.png"), np.full((480, 640), 110, np.uint8))
    assert main(["vision", str(tmp_path / "frames"), "--camera", str(tmp_path / "cam.toml"),
                 "--out", str(out), "--fps", "30"]) == 2
    assert "camera file not found" in capsys.readouterr().err
    assert main(["vision", str(tmp_path / "frames"), "--camera", str(RIG_PATH), "--out", str(out)]) == 2
    assert "--timestamps FILE or --fps" in capsys.readouterr().err
    assert main(["vision", str(tmp_path / "frames"), "--camera", str(RIG_PATH), "--out", str(out), "--fps", "30"]) == 2
    assert "no frame gave a position" in capsys.readouterr().err
    assert not out.exists()


def test_cli_vision_reads_a_video(tmp_path, rig):
    cam = SyntheticCamera(rig, pixel_noise=1.0, seed=6)
    pose = lambda t: (rotation(0.0, 0.0, 0.2), np.array([0.1 * t, 0.0, -1.0]))
    writer = cv2.VideoWriter(str(tmp_path / "flight.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (640, 480), False)
    assert writer.isOpened()
    for f in cam.frames(pose, np.arange(10) / 30):
        writer.write(f.image)
    writer.release()
    out = tmp_path / "pos.csv"
    assert main(["vision", str(tmp_path / "flight.avi"), "--camera", str(RIG_PATH), "--out", str(out), "--quiet"]) == 0
    pos = np.loadtxt(out, delimiter=",", skiprows=1)
    np.testing.assert_allclose(pos[:, 0], np.arange(10) / 30)          # the video's own 30 fps
    np.testing.assert_allclose(pos[:, 4], 0.2, atol=0.02)
    assert np.abs(pos[:, 3] + 1.0).max() < 0.03


def test_rendered_frame_with_lens_distortion():
    """The synthetic camera's distortion (a remap through OpenCV's model) and the tracker's
    undistortion agree: corners where the model puts them, pose to millimetres."""
    doc = _doc()
    doc["camera"]["distortion"] = [-0.12, 0.03, 0.002, -0.003, 0.0]
    rig = rig_from_dict(doc)
    R, p = rotation(0.05, -0.04, 0.7), np.array([0.06, -0.04, -0.8])
    frame = SyntheticCamera(rig, pixel_noise=2.0, seed=1).render(lambda t: (R, p), 0.0)
    tracker = MarkerTracker(rig)
    found = tracker.detect(frame.image)[0]
    found[:, 0] = rig.camera.width - 1 - found[:, 0]          # back to the real (mirror) image
    assert np.abs(found - frame.corners[0]).max() < 0.3
    est = tracker.process(frame.image, 0.0, attitude=(0.05, -0.04, 0.7))
    assert np.linalg.norm(est.position - p) < 0.005


# --- vision-only refinement after IPPE ---------------------------------------------------

def _position_rms_over_crb(rig, tracker, h, sigma, n, seed, refine):
    """Vision-only (no prior) position RMS over the 6-DoF Cramér–Rao bound, on exact
    corners with iid Gaussian noise of ``sigma`` px, poses at height ``h``."""
    rng = np.random.default_rng(seed)
    err2, crb = [], []
    for _ in range(n):
        e = (rng.normal(0, 0.1), rng.normal(0, 0.1), rng.uniform(-math.pi, math.pi))
        R, p = rotation(*e), np.array([*rng.uniform(-0.15, 0.15, 2) * h, -h])
        est = tracker.pose_from_corners({0: _detector_corners(rig, R, p) + rng.normal(0, sigma, (4, 2))},
                                        refine=refine)
        assert not isinstance(est, str)
        err2.append(np.sum((est.position - p) ** 2))
        crb.append(np.trace(position_crb(rig, R, p, sigma)))
    return math.sqrt(np.mean(err2) / np.mean(crb))


@pytest.mark.parametrize("sigma", [0.3, 0.6])
def test_vision_only_pose_refined_to_cramer_rao_bound(rig, sigma):
    # 0.5 m over the marker: IPPE alone is 1.7-1.9x the bound (not maximum likelihood);
    # Levenberg–Marquardt on the same four corners reaches it (1.02 measured). 600 draws:
    # the ratio's own Monte-Carlo spread is ~3 %
    tracker = MarkerTracker(rig, tilt_sigma=None)
    refined = _position_rms_over_crb(rig, tracker, 0.5, sigma, 600, 21, refine=True)
    ippe = _position_rms_over_crb(rig, tracker, 0.5, sigma, 600, 21, refine=False)
    assert 0.85 < refined < 1.15, refined
    assert ippe > 1.3 * refined, (ippe, refined)


def test_refined_pose_minimises_corner_error_through_the_mirror(rig):
    # The refinement works on the virtual camera in the flipped image; its result must be
    # the minimum of the corner error of the *real* camera looking through the mirror
    # (rig.project: reflect, then project), and reproject better than IPPE's pose.
    # Measured by the Gauss–Newton step still to go from each pose, against the bound.
    tracker = MarkerTracker(rig, tilt_sigma=None)
    rng = np.random.default_rng(8)
    sigma = 0.5
    P_w = rig.markers[0].corners_world(rig.marker_size)
    for _ in range(10):
        e = (rng.normal(0, 0.1), rng.normal(0, 0.1), rng.uniform(-math.pi, math.pi))
        R, p = rotation(*e), np.array([*rng.uniform(-0.1, 0.1, 2), -rng.uniform(0.4, 1.0)])
        obs = _detector_corners(rig, R, p) + rng.normal(0, sigma, (4, 2))
        real = obs.copy()
        real[:, 0] = rig.camera.width - 1 - real[:, 0]            # back to the camera's own image

        def residual(Rq, pq):
            return (rig.project(Rq, pq, P_w)[0] - real).ravel()

        def gauss_newton_step(est):
            """The position part of one Gauss–Newton step from ``est`` (central differences),
            and the corner RMS there."""
            h = 1e-6
            r0 = residual(est.R_wb, est.position)
            J = np.column_stack([(residual(_rodrigues(d[3:] * h) @ est.R_wb, est.position + d[:3] * h)
                                  - residual(_rodrigues(-d[3:] * h) @ est.R_wb, est.position - d[:3] * h)) / (2 * h)
                                 for d in np.eye(6)])
            step = np.linalg.solve(J.T @ J, -J.T @ r0)
            return np.linalg.norm(step[:3]), float(np.sqrt(np.mean(r0 ** 2)))

        ref = tracker.pose_from_corners({0: obs})
        raw = tracker.pose_from_corners({0: obs}, refine=False)
        bound = math.sqrt(np.trace(position_crb(rig, R, p, sigma)))
        step_ref, rms_ref = gauss_newton_step(ref)
        step_raw, rms_raw = gauss_newton_step(raw)
        assert rms_ref <= rms_raw + 1e-9
        assert rms_ref == pytest.approx(ref.reprojection, rel=1e-6)
        # what is left to gain after the refinement is nothing next to the bound (the
        # refinement stops when a step moves the corners by < 0.01 px); after IPPE alone
        # it is of the order of the bound (measured: < 0.003 and 0.26-2.2)
        assert step_ref < 0.02 * bound and step_raw > 0.1 * bound, (step_ref / bound, step_raw / bound)


# --- the IMU attitude: attitude-only logs, frames outside its time span --------------------

def _wobbly_flight(t):
    """Truth of a short flight with a fast roll / pitch wobble (so a held attitude is wrong)."""
    e = np.column_stack([0.12 * np.sin(9 * t), -0.1 * np.sin(7 * t + 1), 0.2 + 0 * t])
    p = np.column_stack([0.15 * t - 0.03, 0.02 + 0 * t, -0.8 + 0 * t])
    return e, p


def test_frames_outside_imu_span_are_vision_only_with_one_warning(rig):
    times = np.arange(15) / 30
    e, p = _wobbly_flight(times)
    pose = trajectory_pose(times, p, e)
    images = [f.image for f in SyntheticCamera(rig, pixel_noise=2.0, seed=9).frames(pose, times)]
    frames = lambda: ((i, t, img) for i, (t, img) in enumerate(zip(times, images)))
    # the IMU log covers 0.1-0.3 s only (200 Hz)
    ti = np.arange(0.1, 0.3 + 1e-9, 0.005)
    ei, _ = _wobbly_flight(ti)
    track = imu_attitude(log_from_arrays(ti, np.full((ti.size, 4), 400.0),
                                         np.column_stack([np.full((ti.size, 3), np.nan), ei])))
    assert track(0.05) is None and track(0.35) is None
    assert track(0.2) == pytest.approx(tuple(_wobbly_flight(np.array([0.2]))[0][0]), abs=1e-4)
    outside = (times < 0.1 - 1e-9) | (times > 0.3 + 1e-9)
    with pytest.warns(AttitudeSpanWarning) as rec:
        res = MarkerTracker(rig).run(frames(), attitude=track)
    assert len(rec) == 1
    msg = str(rec[0].message)
    assert f"{outside.sum()} of 15 frame(s)" in msg and "[0.1, 0.3] s" in msg and "vision-only" in msg
    assert res.outside_imu == outside.sum() and "vision-only" in res.summary()
    assert res.to_json()["outside_imu"] == outside.sum()
    assert len(res.t) == 15
    # frames outside the span: exactly the vision-only poses; inside: the IMU-aided ones
    alone = MarkerTracker(rig).run(frames())
    truth_att = lambda t: tuple(_wobbly_flight(np.array([t]))[0][0])
    aided = MarkerTracker(rig).run(frames(), attitude=truth_att)
    np.testing.assert_array_equal(res.position[outside], alone.position[outside])
    np.testing.assert_allclose(res.position[~outside], aided.position[~outside], atol=2e-3)
    # and the old behaviour (the end attitudes held) would have given other positions there
    held = MarkerTracker(rig).run(frames(), attitude=lambda t: truth_att(min(max(t, 0.1), 0.3)))
    assert np.abs(held.position[outside] - res.position[outside]).max() > 5e-3


def test_imu_attitude_file_errors_name_file_and_column(tmp_path):
    f = tmp_path / "att.csv"
    f.write_text("t,phi\n0,0\n0.1,0\n")
    with pytest.raises(GreyboxInputError, match=r"att.csv: missing required column 'theta'"):
        imu_attitude(f)
    f.write_text("t,theta,psi\n0,0,0\n0.1,0,0\n")
    with pytest.raises(GreyboxInputError, match=r"att.csv: missing required column 'phi'"):
        imu_attitude(f)
    f.write_text("t,phi,theta\n0,0,\n0.1,,0\n0.2,0,0\n")
    with pytest.raises(GreyboxInputError, match=r"att.csv: fewer than two rows with both 'phi' and 'theta'"):
        imu_attitude(f)
    f.write_text("t,phi,theta\n0,0,0\n0.1,5.0,12.0\n")           # degrees
    with pytest.raises(GreyboxInputError, match=r"att.csv: row 3, column 'theta'.*rad \(degrees\?\)"):
        imu_attitude(f)
    f.write_text("t,phi,theta\n0,0,0\n0.1,30.0,0.0\n")
    with pytest.raises(GreyboxInputError, match=r"att.csv: row 3, column 'phi'.*rad \(degrees\?\)"):
        imu_attitude(f)
    f.write_text("phi,theta\n0,0\n0,0\n")
    with pytest.raises(GreyboxInputError, match=r"att.csv: missing required column 't'"):
        imu_attitude(f)
    # multi-rate: rows without attitude are skipped; yaw absent gives 0
    f.write_text("t,w1,phi,theta\n0,400,0.0,0.0\n0.05,400,,\n0.1,400,0.1,-0.2\n")
    track = imu_attitude(f)
    assert (track.t_start, track.t_end) == (0.0, 0.1)
    assert track(0.05) == pytest.approx((0.05, -0.1, 0.0))


def test_cli_vision_takes_an_attitude_only_imu_log(tmp_path, capsys):
    t = np.arange(0, 0.5, 0.005)
    e, p = _wobbly_flight(t)
    log = log_from_arrays(t, np.full((t.size, 4), 420.0), np.column_stack([p, e, np.zeros((t.size, 3))]))
    save_log(log, tmp_path / "flight.csv")
    assert main(["render", str(tmp_path / "flight.csv"), "--camera", str(RIG_PATH),
                 "--out-dir", str(tmp_path / "frames"), "--fps", "30", "--seed", "1"]) == 0
    capsys.readouterr()
    common = [str(tmp_path / "frames"), "--camera", str(RIG_PATH), "--quiet",
              "--timestamps", str(tmp_path / "frames" / "timestamps.csv")]
    # t, phi, theta only: no rotor speeds, no yaw
    att = tmp_path / "att.csv"
    att.write_text("t,phi,theta\n" + "".join(f"{a:.17g},{b:.17g},{c:.17g}\n" for a, b, c in zip(t, e[:, 0], e[:, 1])))
    out = tmp_path / "pos.csv"
    assert main(["vision", *common, "--out", str(out), "--imu", str(att)]) == 0
    err = capsys.readouterr().err
    assert "warning" not in err
    pos = np.loadtxt(out, delimiter=",", skiprows=1)
    assert len(pos) == 15
    truth = np.column_stack([np.interp(pos[:, 0], t, p[:, i]) for i in range(3)])
    assert np.abs(pos[:, 1:4] - truth).max() < 0.005
    # missing theta: exit 2, one line naming the file and the column, no output
    bad = tmp_path / "bad.csv"
    bad.write_text("t,phi\n0,0\n1,0\n")
    out2 = tmp_path / "pos2.csv"
    assert main(["vision", *common, "--out", str(out2), "--imu", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [f"greybox: error: {bad}: missing required column 'theta' "
                                        "(the attitude log needs t, phi, theta and optionally psi, in rad)"]
    assert not out2.exists()
    # an IMU log that ends before the last frame: one warning line, the rest vision-only
    short = tmp_path / "short.csv"
    short.write_text("\n".join(att.read_text().splitlines()[:61]) + "\n")     # up to t = 0.295 s
    assert main(["vision", *common, "--out", str(out2), "--imu", str(short), "--json", str(tmp_path / "v.json")]) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "warning" in ln]
    assert len(lines) == 1 and lines[0].startswith("greybox: warning: 6 of 15 frame(s)")
    assert "outside the IMU log's time span [0, 0.295] s" in lines[0]


def test_imu_yaw_reference_plays_no_part(rig):
    # an IMU's yaw (gyro-integrated, compass) is rarely the markers' north: the tilt prior
    # uses roll and pitch only, so a log without yaw (0) or with an offset one gives the
    # same pose as the true yaw (before, a 0.2 rad yaw offset cost 1.5 cm here, more than
    # vision alone)
    e, p = _wobbly_flight(np.array([0.1]))
    R = rotation(*e[0])
    image = SyntheticCamera(rig, pixel_noise=2.0, seed=12).render(lambda t: (R, p[0]), 0.0).image
    poses = [MarkerTracker(rig).process(image, 0.0, attitude=(e[0, 0], e[0, 1], psi))
             for psi in (e[0, 2], 0.0, e[0, 2] + 1.0)]
    for est in poses[1:]:
        np.testing.assert_allclose(est.position, poses[0].position, atol=1e-9)
    assert np.linalg.norm(poses[0].position - p[0]) < 0.004

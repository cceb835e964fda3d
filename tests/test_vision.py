"""The vision front end: rig geometry through the mirror, pose from corners and from
rendered frames, the Cramér–Rao bound, skips, merge and the CLI."""
from __future__ import annotations

import math
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest

from greybox.cli import main
from greybox.data import load_log, log_from_arrays, save_log
from greybox.errors import GreyboxInputError
from greybox.synthcam import SyntheticCamera, trajectory_pose, write_sequence
from greybox.vision import (MarkerTracker, load_rig, merge_vision, position_crb, read_frames,
                            rig_from_dict, rotation_to_euler, _euler_to_rotation)

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
    # body (0.09, 0, -0.04) looking straight down, image up = body forward. Level at 1 m
    # over the marker: its centre is 1.04 m below the virtual camera and 0.09 m behind
    # it, so it appears on the middle column, 420 * 0.09 / 1.04 px above the centre row.
    K, dist, R_bv, c_b = rig.virtual_camera
    np.testing.assert_allclose(c_b, [0.09, 0.0, -0.04], atol=1e-12)
    np.testing.assert_allclose(R_bv[:, 2], [0, 0, 1], atol=1e-12)       # looks down
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
        R = _euler_to_rotation(*e)
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
    R = _euler_to_rotation(0.0, 0.0, 0.5)
    p = np.array([0.0, 0.0, -1.0])
    est = MarkerTracker(rig).pose_from_corners({0: _detector_corners(rig, R, p)})
    assert est.euler[2] == pytest.approx(0.5, abs=1e-6)


def test_rendered_frame_pose_and_handedness(rig):
    R = _euler_to_rotation(0.05, -0.04, 0.7)
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
        R, p = _euler_to_rotation(*e), np.array([*rng.uniform(-0.15, 0.15, 2) * h, -h])
        c = _detector_corners(rig, R, p) + rng.normal(0, sigma, (4, 2))
        est = tracker.pose_from_corners({0: c}, prior=_euler_to_rotation(*(np.array(e) + rng.normal(0, 0.01, 3))))
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
    pose = lambda t: (_euler_to_rotation(0.0, 0.0, 0.3 * t), np.array([0.4 * t, 0.1, -1.0]))
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
                 "--out-dir", str(tmp_path / "frames"), "--fps", "30", "--seed", "1"]) == 0
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
                 "--out", str(tmp_path / "merged.csv")]) == 0
    merged = load_log(tmp_path / "merged.csv")
    assert (~np.isnan(merged.output("x"))).sum() == 15


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
    pose = lambda t: (_euler_to_rotation(0.0, 0.0, 0.2), np.array([0.1 * t, 0.0, -1.0]))
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
    R, p = _euler_to_rotation(0.05, -0.04, 0.7), np.array([0.06, -0.04, -0.8])
    frame = SyntheticCamera(rig, pixel_noise=2.0, seed=1).render(lambda t: (R, p), 0.0)
    tracker = MarkerTracker(rig)
    found = tracker.detect(frame.image)[0]
    found[:, 0] = rig.camera.width - 1 - found[:, 0]          # back to the real (mirror) image
    assert np.abs(found - frame.corners[0]).max() < 0.3
    est = tracker.process(frame.image, 0.0, attitude=(0.05, -0.04, 0.7))
    assert np.linalg.norm(est.position - p) < 0.005

"""The vision front end: ArUco marker pose through a mirror, to body position and yaw.

The seed paper's quadrotor watches a ground marker with its forward camera through a
3D-printed plane mirror. Two facts make that work with stock OpenCV:

* A mirror makes a *virtual camera*, the reflection of the real one in the mirror plane.
  Its orientation is improper (a reflection, det = -1), so the image is a mirror image:
  ArUco codes are chiral and do not decode in it. Flipping the image left-right makes it
  the image of a proper camera with rotation ``H R_bc F`` (``H`` the mirror's Householder
  reflection, ``F = diag(-1, 1, 1)``), centre the reflected camera centre, and
  intrinsics with ``cx -> W - 1 - cx`` and tangential distortion ``p2 -> -p2``.
* For one square marker, IPPE gives the two poses that explain four corners; the wrong
  one is a reflection about the line of sight. We keep the better-reprojecting one unless
  the two are close (noise) and the IMU attitude is known, then the one whose tilt is
  nearest the IMU's, and refine it on the corners (IPPE alone is not maximum-likelihood).

Frames: OpenCV camera axes (x right, y down, z along the optical axis). World NED, body
FRD (README, "Conventions"). The rig (camera, optional mirror, markers) is one TOML file, see
:func:`load_rig` and README section "Vision".
"""
from __future__ import annotations

import math
import re
import sys
import time
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

import cv2
import numpy as np

from .data import FlightLog, atomic_write, read_csv_table
from .errors import GreyboxInputError
from .rotations import euler_from_rotation as rotation_to_euler, rotation, rotation_matrices  # noqa: F401 (rotation_to_euler: public here too)

__all__ = ["Camera", "Mirror", "Marker", "VisionRig", "load_rig", "rig_from_dict",
           "VisionEstimate", "VisionResult", "MarkerTracker", "read_frames", "position_crb",
           "ground_marker_rotation", "rotation_to_euler", "save_positions", "load_positions",
           "merge_vision", "SKIP_REASONS", "IMAGE_EXTENSIONS", "AttitudeTrack", "AttitudeSpanWarning"]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
SKIP_REASONS = ("unreadable", "no_marker", "reprojection", "jump", "behind")
"""Why a frame gives no position: the file could not be decoded; no known marker was
detected (absent, occluded, blurred); the pose explains the corners badly; the position
jumped implausibly from the last accepted one; the solution puts the marker behind the
camera."""

_FLIP = np.diag([-1.0, 1.0, 1.0])
# a pose and its six forward-difference perturbations (position, world rotation): one batch
_FD_STEP = 1e-7
_FD_DP = np.vstack([np.zeros(3), _FD_STEP * np.eye(3), np.zeros((3, 3))])


# ---------------------------------------------------------------------------------------
# the rig: camera, mirror, markers
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Camera:
    """A pinhole camera with OpenCV distortion, mounted on the body.

    Attributes:
        width, height: image size, px.
        K: 3x3 intrinsic matrix.
        dist: distortion ``k1, k2, p1, p2, k3`` (OpenCV order).
        R_bc: rotation of camera axes into the body frame (columns: camera x, y, z in body).
        t_bc: camera centre in the body frame (FRD), m.
    """

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    R_bc: np.ndarray
    t_bc: np.ndarray

    def project_camera_points(self, P: np.ndarray) -> np.ndarray:
        """Pixels of camera-frame points ``P`` (n, 3) with distortion (OpenCV's model)."""
        return _distorted_pixels(self.K, self.dist, P[:, 0] / P[:, 2], P[:, 1] / P[:, 2])


def _distorted_pixels(K: np.ndarray, dist: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) of normalised image coordinates through OpenCV's distortion model
    (``k1, k2, p1, p2, k3``) and the intrinsics ``K``."""
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)


@dataclass(frozen=True)
class Mirror:
    """A plane mirror fixed to the body: a point on it and its unit normal (body frame)."""

    point: np.ndarray
    normal: np.ndarray

    @property
    def householder(self) -> np.ndarray:
        n = self.normal
        return np.eye(3) - 2.0 * np.outer(n, n)

    def reflect(self, P: np.ndarray) -> np.ndarray:
        """Mirror images of body-frame points ``P`` (n, 3)."""
        d = (P - self.point) @ self.normal
        return P - 2.0 * d[:, None] * self.normal[None, :]


@dataclass(frozen=True)
class Marker:
    """One ArUco marker lying in the world: id, centre (NED, m), rotation of marker axes
    into the world (marker x right, y up in the printed image, z out of the paper)."""

    id: int
    position: np.ndarray
    R_wm: np.ndarray

    def corners_marker(self, size: float) -> np.ndarray:
        """The four corners in marker coordinates, in OpenCV's order (top-left, top-right,
        bottom-right, bottom-left of the printed image): what IPPE_SQUARE expects."""
        h = size / 2
        return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])

    def corners_world(self, size: float) -> np.ndarray:
        return self.corners_marker(size) @ self.R_wm.T + self.position


def ground_marker_rotation(yaw: float) -> np.ndarray:
    """Rotation of a marker lying face up on the ground (NED), its x axis ``yaw`` rad from
    north: z_m = up = -z_w, x_m = (cos yaw, sin yaw, 0), y_m = z_m x x_m."""
    c, s = math.cos(yaw), math.sin(yaw)
    x = np.array([c, s, 0.0])
    z = np.array([0.0, 0.0, -1.0])
    return np.column_stack([x, np.cross(z, x), z])


@dataclass(frozen=True)
class VisionRig:
    """Camera, optional mirror and the markers it looks at (see :func:`load_rig`)."""

    camera: Camera
    mirror: Mirror | None
    dictionary: str
    marker_size: float
    markers: dict[int, Marker]
    source: str | None = None

    # -- the proper camera that OpenCV's pose solvers see ---------------------------------
    @property
    def virtual_camera(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(K, dist, R_bv, c_b)`` of the camera whose image the detector sees: with a
        mirror, the reflected camera seen in the left-right flipped image; else the camera."""
        cam = self.camera
        if self.mirror is None:
            return cam.K, cam.dist, cam.R_bc, cam.t_bc
        K = cam.K.copy()
        K[0, 2] = cam.width - 1 - K[0, 2]
        K[0, 1] = -K[0, 1]
        d = cam.dist.copy()
        d[3] = -d[3]
        R_bv = self.mirror.householder @ cam.R_bc @ _FLIP
        c_b = self.mirror.reflect(cam.t_bc[None, :])[0]
        return K, d, R_bv, c_b

    def body_points_to_camera(self, P_b: np.ndarray) -> np.ndarray:
        """Camera-frame coordinates of the images of body-frame points: through the mirror
        if there is one (what the real camera sees)."""
        if self.mirror is not None:
            P_b = self.mirror.reflect(P_b)
        return (P_b - self.camera.t_bc) @ self.camera.R_bc

    def world_points_to_camera(self, R_wb: np.ndarray, p_wb: np.ndarray, P_w: np.ndarray) -> np.ndarray:
        return self.body_points_to_camera((P_w - p_wb) @ R_wb)

    def project(self, R_wb: np.ndarray, p_wb: np.ndarray, P_w: np.ndarray,
                distort: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Pixels of world points seen by the real camera for body pose ``(R_wb, p_wb)``,
        and a mask of the points in front of the camera."""
        Pc = self.world_points_to_camera(R_wb, p_wb, P_w)
        front = Pc[:, 2] > 1e-6
        Pc = np.where(front[:, None], Pc, np.array([0.0, 0.0, 1.0]))
        if distort:
            px = self.camera.project_camera_points(Pc)
        else:
            px = (Pc[:, :2] / Pc[:, 2:]) @ self.camera.K[:2, :2].T + self.camera.K[:2, 2]
        return px, front

    def marker_corners_px(self, R_wb: np.ndarray, p_wb: np.ndarray, marker_id: int,
                          distort: bool = True) -> tuple[np.ndarray, bool]:
        """The four corner pixels of a marker in the real image (mirror-imaged if there is
        a mirror), and whether all four are in front of the camera."""
        px, front = self.project(R_wb, p_wb, self.markers[marker_id].corners_world(self.marker_size), distort)
        return px, bool(front.all())


def _vec(doc: Mapping[str, Any], key: str, n: int, where: str, default=None) -> np.ndarray:
    if key not in doc:
        if default is None:
            raise GreyboxInputError(f"{where}: missing key {key!r}")
        return np.asarray(default, dtype=float)
    v = doc[key]
    if (not isinstance(v, list) or len(v) != n
            or not all(isinstance(a, (int, float)) and not isinstance(a, bool) for a in v)):
        raise GreyboxInputError(f"{where}: {key!r} must be a list of {n} numbers, got {v!r}")
    a = np.asarray(v, dtype=float)
    if not np.all(np.isfinite(a)):
        raise GreyboxInputError(f"{where}: {key!r} has a non-finite value")
    return a


def _num(doc: Mapping[str, Any], key: str, where: str, default=None, positive=False) -> float:
    if key not in doc:
        if default is None:
            raise GreyboxInputError(f"{where}: missing key {key!r}")
        return float(default)
    v = doc[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise GreyboxInputError(f"{where}: {key!r} must be a number, got {v!r}")
    if positive and v <= 0:
        raise GreyboxInputError(f"{where}: {key!r} must be positive, got {v!r}")
    return float(v)


def _unknown(doc: Mapping[str, Any], allowed: set[str], where: str) -> None:
    extra = sorted(set(doc) - allowed)
    if extra:
        raise GreyboxInputError(f"{where}: unknown key(s) {', '.join(map(repr, extra))}; "
                                f"known: {', '.join(sorted(allowed))}")


def rig_from_dict(doc: Mapping[str, Any], source: str = "<rig>") -> VisionRig:
    """Build and validate a :class:`VisionRig` from a parsed TOML document."""
    _unknown(doc, {"camera", "mirror", "markers"}, source)
    if "camera" not in doc or not isinstance(doc["camera"], dict):
        raise GreyboxInputError(f"{source}: missing [camera] table")
    c = doc["camera"]
    w = f"{source} [camera]"
    _unknown(c, {"width", "height", "fx", "fy", "cx", "cy", "skew", "distortion", "position",
                 "optical_axis", "image_right"}, w)
    width, height = int(_num(c, "width", w, positive=True)), int(_num(c, "height", w, positive=True))
    fx, fy = _num(c, "fx", w, positive=True), _num(c, "fy", w, positive=True)
    cx, cy = _num(c, "cx", w, (width - 1) / 2), _num(c, "cy", w, (height - 1) / 2)
    K = np.array([[fx, _num(c, "skew", w, 0.0), cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    dist = _vec(c, "distortion", 5, w, [0.0] * 5)
    t_bc = _vec(c, "position", 3, w, [0.0, 0.0, 0.0])
    zc = _vec(c, "optical_axis", 3, w)
    xc = _vec(c, "image_right", 3, w)
    if np.linalg.norm(zc) < 1e-9 or np.linalg.norm(xc) < 1e-9:
        raise GreyboxInputError(f"{w}: 'optical_axis' and 'image_right' must be non-zero vectors")
    zc, xc = zc / np.linalg.norm(zc), xc / np.linalg.norm(xc)
    if abs(zc @ xc) > 1e-3:
        raise GreyboxInputError(f"{w}: 'image_right' {xc.tolist()} is not perpendicular to "
                                f"'optical_axis' {zc.tolist()} (dot product {zc @ xc:.3g})")
    xc = xc - (xc @ zc) * zc
    xc /= np.linalg.norm(xc)
    R_bc = np.column_stack([xc, np.cross(zc, xc), zc])
    camera = Camera(width, height, K, dist, R_bc, t_bc)

    mirror = None
    if "mirror" in doc:
        m = doc["mirror"]
        w = f"{source} [mirror]"
        if not isinstance(m, dict):
            raise GreyboxInputError(f"{w}: must be a table")
        _unknown(m, {"point", "normal"}, w)
        n = _vec(m, "normal", 3, w)
        if np.linalg.norm(n) < 1e-9:
            raise GreyboxInputError(f"{w}: 'normal' must be a non-zero vector")
        mirror = Mirror(_vec(m, "point", 3, w), n / np.linalg.norm(n))
        if abs((t_bc - mirror.point) @ mirror.normal) < 1e-6:
            raise GreyboxInputError(f"{w}: the camera centre lies in the mirror plane")

    if "markers" not in doc or not isinstance(doc["markers"], dict):
        raise GreyboxInputError(f"{source}: missing [markers] table")
    mk = doc["markers"]
    w = f"{source} [markers]"
    _unknown(mk, {"dictionary", "size", "marker"}, w)
    dname = mk.get("dictionary", "DICT_4X4_50")
    if not isinstance(dname, str) or not dname.startswith("DICT_") or not hasattr(cv2.aruco, dname):
        known = ", ".join(a for a in dir(cv2.aruco) if a.startswith("DICT_") and a == a.upper())
        raise GreyboxInputError(f"{w}: unknown dictionary {dname!r}; known: {known}")
    size = _num(mk, "size", w, positive=True)
    items = mk.get("marker")
    if not isinstance(items, list) or not items:
        raise GreyboxInputError(f"{w}: give at least one [[markers.marker]] table (id, position, yaw)")
    n_ids = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dname)).bytesList.shape[0]
    markers: dict[int, Marker] = {}
    for i, it in enumerate(items):
        wi = f"{source} [[markers.marker]] #{i + 1}"
        if not isinstance(it, dict):
            raise GreyboxInputError(f"{wi}: must be a table")
        _unknown(it, {"id", "position", "yaw"}, wi)
        mid = it.get("id")
        if isinstance(mid, bool) or not isinstance(mid, int) or not 0 <= mid < n_ids:
            raise GreyboxInputError(f"{wi}: 'id' must be an integer in 0..{n_ids - 1} for {dname}, got {mid!r}")
        if mid in markers:
            raise GreyboxInputError(f"{wi}: marker id {mid} appears twice")
        markers[mid] = Marker(mid, _vec(it, "position", 3, wi, [0.0, 0.0, 0.0]),
                              ground_marker_rotation(_num(it, "yaw", wi, 0.0)))
    return VisionRig(camera, mirror, dname, size, markers, source)


def load_rig(path: str | Path) -> VisionRig:
    """Read a camera / mirror / marker description (TOML). Example::

        [camera]
        width = 640
        height = 480
        fx = 500.0
        fy = 500.0
        cx = 319.5                   # default (width - 1) / 2
        cy = 239.5
        distortion = [0, 0, 0, 0, 0] # k1, k2, p1, p2, k3 (OpenCV)
        position = [0.05, 0.0, 0.0]  # camera centre in the body frame (FRD), m
        optical_axis = [1, 0, 0]     # body-frame direction the lens looks along
        image_right = [0, 1, 0]      # body-frame direction of the image's +x (columns)

        [mirror]                     # optional plane mirror, body frame
        point = [0.09, 0.0, 0.0]
        normal = [0.7071, 0.0, -0.7071]

        [markers]
        dictionary = "DICT_4X4_50"
        size = 0.15                  # side of the black square, m
        [[markers.marker]]
        id = 0
        position = [0.0, 0.0, 0.0]   # centre, world NED; lying face up on the ground
        yaw = 0.0                    # rad, the printed image's x axis from north
    """
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise GreyboxInputError(f"{path}: camera file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise GreyboxInputError(f"{path}: cannot read camera file: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise GreyboxInputError(f"{path}: not valid TOML: {e}") from None
    return rig_from_dict(doc, str(path))


# ---------------------------------------------------------------------------------------
# geometry helpers
# ---------------------------------------------------------------------------------------

def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def position_crb(rig: VisionRig, R_wb: np.ndarray, p_wb: np.ndarray, sigma_px: float,
                 marker_ids: Iterable[int] | None = None, tilt_sigma: float | None = None) -> np.ndarray:
    """Cramér–Rao bound (3x3 covariance, world frame) of the body position estimated from
    the corners of the given markers, each corner pixel coordinate carrying independent
    Gaussian noise of ``sigma_px`` (undistorted pixels).

    With ``tilt_sigma`` None the full 6-DoF pose is unknown (vision alone). With a number,
    roll and pitch are also measured (the IMU) with that standard deviation, rad, as in
    :class:`MarkerTracker`'s IMU-aided mode: the bound of that estimator.

    Fisher information ``J^T J / sigma^2`` (+ the tilt prior's) with ``J`` the Jacobian of
    the corner pixels with respect to (position, small world-frame rotation).
    """
    ids = list(rig.markers) if marker_ids is None else list(marker_ids)
    P_w = np.vstack([rig.markers[i].corners_world(rig.marker_size) for i in ids])

    def f(theta: np.ndarray) -> np.ndarray:
        R = _rodrigues(theta[3:]) @ R_wb
        return rig.project(R, p_wb + theta[:3], P_w, distort=False)[0].ravel()

    h = 1e-6
    J = np.column_stack([(f(e * h) - f(-e * h)) / (2 * h) for e in np.eye(6)])
    info = J.T @ J / sigma_px ** 2
    if tilt_sigma is not None:
        # the IMU measures the tilt (body z axis in the heading frame, x and y: roll and
        # pitch, whatever the yaw) with tilt_sigma, as MarkerTracker.refine_with_tilt uses it
        def g(theta: np.ndarray) -> np.ndarray:
            return _heading_tilt(_rodrigues(theta[3:]) @ R_wb)[:2]

        Jt = np.column_stack([(g(e * h) - g(-e * h)) / (2 * h) for e in np.eye(6)])
        info += Jt.T @ Jt / tilt_sigma ** 2
    return np.linalg.inv(info)[:3, :3]


def _heading_tilt(R: np.ndarray) -> np.ndarray:
    """The body z axis in the heading frame (world NED turned by the body's own yaw) of
    rotations ``R`` (..., 3, 3): ``(cos phi sin theta, -sin phi, cos phi cos theta)``. It
    holds roll and pitch only, so an IMU's tilt compares with vision's through it whatever
    the IMU's yaw reference (a gyro or compass yaw is rarely the markers' north)."""
    psi = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    c, s = np.cos(psi), np.sin(psi)
    zx, zy = R[..., 0, 2], R[..., 1, 2]
    return np.stack([c * zx + s * zy, c * zy - s * zx, R[..., 2, 2]], axis=-1)


def _rodrigues(v: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(v))
    if a < 1e-12:
        return np.eye(3) + _skew(v)
    k = _skew(v / a)
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * k @ k


_FD_DR = np.stack([np.eye(3)] * 4 + [_rodrigues(_FD_STEP * e) for e in np.eye(3)])


# ---------------------------------------------------------------------------------------
# pose from frames
# ---------------------------------------------------------------------------------------

@dataclass
class VisionEstimate:
    """The pose from one frame: body position (NED, m) and attitude, reprojection RMS (px),
    markers used, and whether the IPPE ambiguity had to be settled by the prior."""

    t: float
    position: np.ndarray
    R_wb: np.ndarray
    reprojection: float
    marker_ids: list[int]
    ambiguous: bool = False
    alternative: np.ndarray | None = None   # R_wb of the other IPPE solution, if one

    @property
    def euler(self) -> tuple[float, float, float]:
        return rotation_to_euler(self.R_wb)


@dataclass
class VisionResult:
    """Positions and yaw from a sequence of frames, with the count of every kind of skip."""

    t: np.ndarray
    position: np.ndarray             # (n, 3) NED, m
    euler: np.ndarray                # (n, 3) phi, theta, psi, rad
    reprojection: np.ndarray         # (n,) px RMS
    frame_index: np.ndarray          # (n,) index of the frame each estimate came from
    n_frames: int
    skipped: dict[str, int]
    skipped_frames: dict[str, list[int]] = field(default_factory=dict)
    ambiguous: int = 0
    seconds: float = 0.0
    outside_imu: int = 0             # frames outside the IMU log's time span (vision-only)

    @property
    def psi(self) -> np.ndarray:
        return self.euler[:, 2]

    def summary(self) -> str:
        n_ok = len(self.t)
        parts = [f"{n_ok} of {self.n_frames} frames gave a position"]
        skips = [f"{v} {k.replace('_', ' ')}" for k, v in self.skipped.items() if v]
        if skips:
            parts.append("skipped: " + ", ".join(skips))
        if self.ambiguous:
            parts.append(f"{self.ambiguous} ambiguous IPPE pose(s) settled by the attitude prior")
        if self.outside_imu:
            parts.append(f"{self.outside_imu} frame(s) outside the IMU log's time span, vision-only")
        if self.seconds > 0 and self.n_frames:
            parts.append(f"{self.n_frames / self.seconds:.0f} frames/s")
        return "; ".join(parts)

    def to_json(self) -> dict:
        return {"frames": self.n_frames, "positions": int(len(self.t)),
                "skipped": dict(self.skipped), "ambiguous": self.ambiguous, "outside_imu": self.outside_imu,
                "reprojection_px": {"median": float(np.median(self.reprojection)) if len(self.t) else None,
                                    "max": float(np.max(self.reprojection)) if len(self.t) else None},
                "frames_per_second": self.n_frames / self.seconds if self.seconds > 0 else None}


class MarkerTracker:
    """Body position and yaw from camera frames of the rig's markers.

    Per frame: (flip if mirrored) → ``ArucoDetector.detectMarkers`` with sub-pixel corner
    refinement → IPPE_SQUARE with its ambiguity settled, refined by Gauss–Newton on the
    corners (one marker; with the IMU attitude and ``tilt_sigma``, by the tilt-aided
    Gauss–Newton instead) or SQPnP refined by Levenberg–Marquardt (several) → reprojection
    check → body pose in the world → jump check against the last accepted frame.

    Args:
        rig: camera, mirror and markers.
        max_reprojection_px: frames whose corner reprojection RMS exceeds this are rejected.
        max_speed: m/s; a position farther than ``max_speed * dt + jump_margin`` from the
            last accepted one is rejected as a jump (after ``reset_after`` such frames in a
            row the tracker re-locks on the new position: it was the old one that was wrong).
        ambiguity_ratio: when the second IPPE solution's reprojection error is within this
            factor of the first, the one whose tilt is nearer the IMU's is taken; without
            the IMU attitude, the better-reprojecting one.
        tilt_sigma: rad, the IMU's roll/pitch accuracy. When :meth:`process` is given the
            IMU attitude, the pose is refined by Gauss–Newton on the corner reprojection
            error (``corner_sigma_px``) *and* the IMU's tilt: one marker's four corners
            leave the lateral position and the tilt nearly interchangeable (a 0.2 px
            corner error moves the 6-DoF position by centimetres at 1 m), the IMU tilt
            settles it (millimetres). ``None`` uses the IMU only to settle ambiguities.
        corner_sigma_px: expected corner noise, px (weights the two in the refinement).
        detector_parameters: an ``cv2.aruco.DetectorParameters`` to use instead of ours.
    """

    refine_iterations = 10
    """Gauss–Newton steps after IPPE for a vision-only single-marker pose (see
    :meth:`pose_from_corners`)."""

    def __init__(self, rig: VisionRig, max_reprojection_px: float = 2.0, max_speed: float = 10.0,
                 jump_margin: float = 0.1, reset_after: int = 5, ambiguity_ratio: float = 4.0,
                 tilt_sigma: float | None = 0.01, corner_sigma_px: float = 0.2,
                 detector_parameters: "cv2.aruco.DetectorParameters | None" = None) -> None:
        if max_reprojection_px <= 0 or max_speed <= 0:
            raise GreyboxInputError("max_reprojection_px and max_speed must be positive")
        self.rig = rig
        self.max_reprojection_px = float(max_reprojection_px)
        self.max_speed = float(max_speed)
        self.jump_margin = float(jump_margin)
        self.reset_after = int(reset_after)
        self.ambiguity_ratio = float(ambiguity_ratio)
        if tilt_sigma is not None and not tilt_sigma > 0:
            raise GreyboxInputError(f"tilt_sigma must be positive or None, got {tilt_sigma!r}")
        if not corner_sigma_px > 0:
            raise GreyboxInputError(f"corner_sigma_px must be positive, got {corner_sigma_px!r}")
        self.tilt_sigma = tilt_sigma
        self.corner_sigma_px = float(corner_sigma_px)
        self.detector = cv2.aruco.ArucoDetector(
            cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, rig.dictionary)),
            detector_parameters or default_detector_parameters())
        self.K, self.dist, self.R_bv, self.c_b = rig.virtual_camera
        self._flip = rig.mirror is not None
        # per marker: corners in marker and world coordinates, and the marker
        self._marker_points = {i: (m.corners_marker(rig.marker_size), m.corners_world(rig.marker_size), m)
                               for i, m in rig.markers.items()}
        self._last: VisionEstimate | None = None
        self._jumps = 0

    def reset(self) -> None:
        """Forget the last accepted pose (start of a new sequence)."""
        self._last = None
        self._jumps = 0

    # -- one frame ----------------------------------------------------------------------
    def detect(self, image: np.ndarray) -> dict[int, np.ndarray]:
        """Corners (4, 2) in the detector's (flipped if mirrored) image, by known marker id."""
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if self._flip:
            image = cv2.flip(image, 1)
        corners, ids, _ = self.detector.detectMarkers(image)
        if ids is None:
            return {}
        return {int(i): c.reshape(4, 2).astype(float) for i, c in zip(ids.ravel(), corners)
                if int(i) in self.rig.markers}

    def pose_from_corners(self, corners: Mapping[int, np.ndarray], t: float = 0.0,
                          prior: np.ndarray | None = None, refine: bool = True) -> VisionEstimate | str:
        """Body pose from detector-image corners, or the name of the reason it failed.

        One marker: IPPE_SQUARE's two solutions, settled as the class says, then (with
        ``refine``) the kept one refined by Gauss–Newton on the four corners: IPPE alone
        is not the maximum-likelihood pose (position error 1.75-1.96x the Cramér–Rao bound
        at 0.5 m, measured; refined: 1.00x). The refinement is of the virtual
        camera's pose in the flipped image, which is the body pose through the mirror (a
        fixed rigid map), so it minimises the same corner residuals as
        :meth:`refine_with_tilt`'s corner term. Several markers: SQPnP on all corners,
        always refined by Levenberg–Marquardt.
        """
        if not corners:
            return "no_marker"
        ambiguous, alternative = False, None
        if len(corners) == 1:
            (mid, img), = corners.items()
            m_obj, _, m = self._marker_points[mid]
            n_sol, rvecs, tvecs, errs = cv2.solvePnPGeneric(m_obj, img, self.K, self.dist,
                                                            flags=cv2.SOLVEPNP_IPPE_SQUARE)
            if n_sol == 0:
                return "reprojection"
            errs = np.ravel(errs)
            rots = [self._body_rotation_from_marker(rv, m) for rv in rvecs]
            k = 0
            if n_sol == 2:
                # without an IMU attitude: the better reprojection (maximum likelihood). The
                # last frame's tilt is no help: a vision-only tilt is as noisy as the choice
                if prior is not None and errs[1] < self.ambiguity_ratio * max(errs[0], 1e-9):
                    ambiguous = True
                    k = int(self._tilt_from(rots[1], prior) < self._tilt_from(rots[0], prior))
                alternative = rots[1 - k]
            R_wb, t_cm, rms = rots[k], tvecs[k].ravel(), float(errs[k])
            if refine and t_cm[2] > 0:
                rv, tv, rms_ref = self._refine_marker_pose(m_obj, img, rvecs[k], tvecs[k])
                if rms_ref < rms and tv[2] > 0:
                    R_wb, t_cm, rms = self._body_rotation_from_marker(rv, m), tv, rms_ref
            if t_cm[2] <= 0:
                return "behind"
            # X_w = R_wm X_m + c_m, X_v = R_cm X_m + t_cm, X_b = c_b + R_bv X_v
            p = m.position - R_wb @ (self.c_b + self.R_bv @ t_cm)
            ids = [mid]
        else:
            ids = sorted(corners)
            obj_w = np.vstack([self._marker_points[i][1] for i in ids])
            img = np.vstack([corners[i] for i in ids])
            ok, rv, tv = cv2.solvePnP(obj_w, img, self.K, self.dist, flags=cv2.SOLVEPNP_SQPNP)
            if not ok:
                return "reprojection"
            rv, tv = cv2.solvePnPRefineLM(obj_w, img, self.K, self.dist, rv, tv)
            R_cw, t_cw = cv2.Rodrigues(rv)[0], tv.ravel()
            if np.any((obj_w @ R_cw.T + t_cw)[:, 2] <= 0):
                return "behind"
            proj = cv2.projectPoints(obj_w, rv, tv, self.K, self.dist)[0].reshape(-1, 2)
            rms = float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1))))
            R_wb = self._body_rotation(R_cw)
            p = -R_wb @ (self.c_b + self.R_bv @ t_cw)
        if not rms <= self.max_reprojection_px:
            return "reprojection"
        return VisionEstimate(t, p, R_wb, rms, ids, ambiguous, alternative)

    def _refine_marker_pose(self, obj: np.ndarray, img: np.ndarray, rvec: np.ndarray, tvec: np.ndarray,
                            ) -> tuple[np.ndarray, np.ndarray, float]:
        """Gauss–Newton on the virtual camera's pose ``(rvec, tvec)`` of one marker: its
        corner reprojection error in the detector's image, with the analytic Jacobian of
        ``cv2.projectPoints`` (lens distortion included). Returns the pose and the RMS
        error there per image coordinate, px (the convention of ``solvePnPGeneric``'s
        errors, which it is compared with).

        Steps until one moves the corners by < 0.01 px in all (a few % of any real corner
        noise), at most ``refine_iterations``: convergence is linear along the weak
        direction (lateral position against tilt), ~3 steps from IPPE's start, leaving
        < 2 % of the Cramér–Rao bound's std to gain (measured, 0.5-1.5 m). Same position
        RMS as ``cv2.solvePnPRefineLM``, at about half its cost."""
        x = np.concatenate([np.ravel(rvec), np.ravel(tvec)]).astype(float)
        target = img.reshape(-1, 1)
        for _ in range(self.refine_iterations):
            proj, J = cv2.projectPoints(obj, x[:3], x[3:], self.K, self.dist)
            J = J[:, :6]
            # the normal equations J^T J step = -J^T r, by Cholesky (OpenCV's: a fraction of
            # numpy's call overhead at this size)
            step = cv2.solve(J, target - proj.reshape(-1, 1), flags=cv2.DECOMP_CHOLESKY | cv2.DECOMP_NORMAL)[1]
            x += step[:, 0]
            moved = J @ step
            if moved.T @ moved < 1e-4:     # it moved the corners by < 0.01 px in all
                break
        proj = cv2.projectPoints(obj, x[:3], x[3:], self.K, self.dist)[0].reshape(-1, 2)
        return x[:3].reshape(3, 1), x[3:], float(np.sqrt(np.mean((proj - img) ** 2)))

    def _project_detector(self, R_wb: np.ndarray, p: np.ndarray, P_w: np.ndarray) -> np.ndarray:
        """Pixels in the detector's image (flipped if mirrored) of world points ``P_w``
        (n, 3) for a batch of body poses ``R_wb`` (m, 3, 3), ``p`` (m, 3): (m, n, 2)."""
        # X_v = R_bv^T (R_wb^T (X_w - p) - c_b)
        Pv = ((P_w[None] - p[:, None]) @ R_wb - self.c_b) @ self.R_bv
        return _distorted_pixels(self.K, self.dist, Pv[..., 0] / Pv[..., 2], Pv[..., 1] / Pv[..., 2])

    def refine_with_tilt(self, est: VisionEstimate, corners: Mapping[int, np.ndarray],
                         imu: np.ndarray, iterations: int = 2) -> VisionEstimate:
        """Gauss–Newton on (position, world-frame rotation): corner residuals / corner
        sigma and the tilt (body z axis in the heading frame) against the IMU's / tilt
        sigma. Yaw stays vision's: the IMU's yaw (``imu``'s) is not used."""
        ids = sorted(corners)
        P_w = np.vstack([self._marker_points[i][1] for i in ids])
        obs = np.vstack([corners[i] for i in ids]).ravel()
        ws, wt = 1.0 / self.corner_sigma_px, 1.0 / self.tilt_sigma
        z_imu = _heading_tilt(imu)[:2]
        R, p = est.R_wb, est.position
        h, dp, dR = _FD_STEP, _FD_DP, _FD_DR
        for _ in range(iterations):
            Rs = dR @ R
            ps = p + dp
            r = np.concatenate([(self._project_detector(Rs, ps, P_w).reshape(7, -1) - obs) * ws,
                                (_heading_tilt(Rs)[:, :2] - z_imu) * wt], axis=1)
            J = (r[1:] - r[0]).T / h
            step = np.linalg.solve(J.T @ J, -J.T @ r[0])
            p = p + step[:3]
            R = _rodrigues(step[3:]) @ R
            if np.abs(step).max() < 1e-8:
                break
        err = self._project_detector(R[None], p[None], P_w)[0] - obs.reshape(-1, 2)
        rms = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
        return VisionEstimate(est.t, p, R, rms, est.marker_ids, est.ambiguous, est.alternative)

    def _body_rotation_from_marker(self, rvec: np.ndarray, m: Marker) -> np.ndarray:
        # R_cw = R_cm R_wm^T and R_wb = (R_bv R_cw)^T
        return m.R_wm @ (self.R_bv @ cv2.Rodrigues(rvec)[0]).T

    def _body_rotation(self, R_cw: np.ndarray) -> np.ndarray:
        # X_b = c_b + R_bv X_v and X_v = R_cw X_w + t  =>  R_wb^T = R_bv R_cw
        return (self.R_bv @ R_cw).T

    @staticmethod
    def _tilt_from(R_wb: np.ndarray, ref: np.ndarray) -> float:
        """Angle between the tilts (body z axes in each one's heading frame) of ``R_wb``
        and the reference: yaw plays no part."""
        return math.acos(max(-1.0, min(1.0, float(_heading_tilt(R_wb) @ _heading_tilt(ref)))))

    def process(self, image: np.ndarray | None, t: float,
                attitude: tuple[float, float, float] | None = None) -> VisionEstimate | str:
        """One frame → an accepted :class:`VisionEstimate`, or the skip reason (one of
        :data:`SKIP_REASONS`). ``attitude`` (phi, theta, psi from the IMU), if known,
        settles ambiguous poses and (with ``tilt_sigma``) refines the pose; only its roll
        and pitch are used, the yaw is vision's."""
        if image is None or image.size == 0:
            return "unreadable"
        prior = None if attitude is None else rotation(*attitude)
        corners = self.detect(image)
        with_tilt = prior is not None and self.tilt_sigma is not None
        # the tilt-aided refinement below replaces the corner-only one
        est = self.pose_from_corners(corners, t, prior, refine=not with_tilt)
        if isinstance(est, str):
            return est
        if with_tilt:
            est = self.refine_with_tilt(est, corners, prior)
        if self._last is not None:
            dt = abs(t - self._last.t)
            if np.linalg.norm(est.position - self._last.position) > self.max_speed * dt + self.jump_margin:
                self._jumps += 1
                if self._jumps < self.reset_after:
                    return "jump"
        self._jumps = 0
        self._last = est
        return est

    def run(self, frames: Iterable[tuple[int, float, np.ndarray | None]],
            attitude: Callable[[float], tuple[float, float, float] | None] | None = None,
            progress: bool = False, n_frames: int | None = None) -> VisionResult:
        """Process ``(index, t, image-or-None)`` frames (see :func:`read_frames`).

        ``attitude(t)``, if given, returns the IMU's ``(phi, theta, psi)`` at ``t``, or
        None where it has none (an :class:`AttitudeTrack` outside its log's time span):
        those frames are processed vision-only, counted in ``outside_imu``, and one
        :class:`AttitudeSpanWarning` says how many and where.
        """
        self.reset()
        skipped = {k: 0 for k in SKIP_REASONS}
        skipped_frames: dict[str, list[int]] = {k: [] for k in SKIP_REASONS}
        rows, ambiguous, n = [], 0, 0
        no_att: list[float] = []
        t0 = time.perf_counter()
        last_print = t0
        for idx, t, image in frames:
            n += 1
            att = None if attitude is None else attitude(t)
            if attitude is not None and att is None:
                no_att.append(t)
            r = self.process(image, t, att)
            if isinstance(r, str):
                skipped[r] += 1
                skipped_frames[r].append(idx)
            else:
                ambiguous += r.ambiguous
                rows.append((r.t, *r.position, *r.euler, r.reprojection, idx))
            now = time.perf_counter()
            if progress and now - last_print > 1.0:
                last_print = now
                tot = f"/{n_frames}" if n_frames else ""
                print(f"vision: frame {n}{tot}, {len(rows)} positions, {n / (now - t0):.0f} frames/s",
                      file=sys.stderr, flush=True)
        if no_att:
            span = (f"lie outside the IMU log's time span [{attitude.t_start:g}, {attitude.t_end:g}] s"
                    if isinstance(attitude, AttitudeTrack) else "have no IMU attitude")
            warnings.warn(f"{len(no_att)} of {n} frame(s), at t = {min(no_att):g} to {max(no_att):g} s, {span}: "
                          "their poses are vision-only (the attitude is not extrapolated)",
                          AttitudeSpanWarning, stacklevel=2)
        A = np.array(rows, dtype=float).reshape(-1, 9)
        return VisionResult(A[:, 0], A[:, 1:4], A[:, 4:7], A[:, 7], A[:, 8].astype(int), n,
                            skipped, skipped_frames, ambiguous, time.perf_counter() - t0, len(no_att))


def default_detector_parameters() -> "cv2.aruco.DetectorParameters":
    """ArUco detector settings: OpenCV's defaults with sub-pixel corner refinement."""
    p = cv2.aruco.DetectorParameters()
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    p.cornerRefinementWinSize = 4
    p.cornerRefinementMaxIterations = 30
    p.cornerRefinementMinAccuracy = 0.01
    return p


__all__.append("default_detector_parameters")


# ---------------------------------------------------------------------------------------
# frame sources and files
# ---------------------------------------------------------------------------------------

def _natural_key(p: Path) -> list:
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", p.name)]


def read_frames(source: str | Path, timestamps: str | Path | None = None, fps: float | None = None,
                t0: float = 0.0) -> tuple[Iterator[tuple[int, float, np.ndarray | None]], int]:
    """Frames of a folder of images (sorted in natural order: frame2 before frame10) or a
    video file, as an iterator of ``(index, t, grey image or None if unreadable)``, and
    the number of frames (video: as the container reports it).

    Times come from ``timestamps`` (a CSV with a column ``t``, one row per frame, in
    order), else from ``fps`` (``t = t0 + index / fps``), else from the video's own rate.
    """
    source = Path(source)
    if not source.exists():
        raise GreyboxInputError(f"{source}: no such folder or video file")
    if fps is not None and not (fps > 0 and math.isfinite(fps)):
        raise GreyboxInputError(f"--fps must be a positive number, got {fps!r}")
    if source.is_dir():
        files = sorted((p for p in source.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS), key=_natural_key)
        if not files:
            raise GreyboxInputError(f"{source}: no image files ({', '.join(IMAGE_EXTENSIONS)}) in the folder")
        n = len(files)
    else:
        cap = cv2.VideoCapture(str(source))
        if not cap.isOpened():
            raise GreyboxInputError(f"{source}: not a folder of images and not a video OpenCV can open")
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if fps is None and timestamps is None:
            f = cap.get(cv2.CAP_PROP_FPS)
            if not f or f <= 0:
                raise GreyboxInputError(f"{source}: the video does not say its frame rate; give --fps or --timestamps")
            fps = float(f)
    times: np.ndarray | None = None
    if timestamps is not None:
        header, data = read_csv_table(timestamps)
        times = _time_column(timestamps, header, data)
        if source.is_dir() and len(times) != n:
            raise GreyboxInputError(f"{timestamps}: {len(times)} time(s) for {n} image file(s) in {source}")
    elif fps is None:
        raise GreyboxInputError("give the frame times: --timestamps FILE or --fps RATE")

    def time_of(i: int) -> float:
        if times is not None:
            if i >= len(times):
                raise GreyboxInputError(f"{timestamps}: {len(times)} time(s), but {source} has more frames")
            return float(times[i])
        return t0 + i / fps

    def gen() -> Iterator[tuple[int, float, np.ndarray | None]]:
        if source.is_dir():
            for i, p in enumerate(files):
                img = _imread_quiet(p)
                yield i, time_of(i), img
        else:
            i = 0
            try:
                while True:
                    ok, img = cap.read()
                    if not ok:
                        break
                    yield i, time_of(i), cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
                    i += 1
            finally:
                cap.release()

    return gen(), n


class AttitudeSpanWarning(UserWarning):
    """Frames outside the IMU log's time span were processed vision-only."""


class AttitudeTrack:
    """The IMU's attitude over its log's time span: ``track(t) -> (phi, theta, psi)``
    linearly interpolated between samples, or None for a ``t`` outside
    ``[t_start, t_end]``: an attitude is never extrapolated (holding the last one moved
    the position by centimetres). Made by :func:`imu_attitude`."""

    def __init__(self, t: np.ndarray, euler: np.ndarray, source: str | None = None) -> None:
        self.t, self.euler, self.source = t, euler, source

    @property
    def t_start(self) -> float:
        return float(self.t[0])

    @property
    def t_end(self) -> float:
        return float(self.t[-1])

    def __call__(self, tq: float) -> tuple[float, float, float] | None:
        if not self.t[0] - 1e-9 <= tq <= self.t[-1] + 1e-9:
            return None
        return tuple(float(np.interp(tq, self.t, self.euler[:, i])) for i in range(3))


def imu_attitude(log: FlightLog | str | Path) -> AttitudeTrack:
    """The attitude track (:class:`AttitudeTrack`) of a flight log, or of a CSV file with
    columns ``t, phi, theta`` and optionally ``psi`` (rad; other columns such as rotor
    speeds are ignored; rows without phi or theta are skipped). Yaw is unwrapped; a log
    without yaw gives 0. The tracker uses roll and pitch only (the yaw is vision's)."""
    if isinstance(log, FlightLog):
        source = log.source or "log"
        t = log.t
        E = np.column_stack([log.output(n) for n in ("phi", "theta", "psi")])
    else:
        source = str(log)
        header, data = read_csv_table(log)
        t = _time_column(log, header, data)
        for name in ("phi", "theta"):
            if name not in header:
                raise GreyboxInputError(f"{source}: missing required column {name!r} (the attitude log "
                                        "needs t, phi, theta and optionally psi, in rad)")
        E = np.column_stack([data[:, header.index(n)] if n in header else np.full(len(t), np.nan)
                             for n in ("phi", "theta", "psi")])
        # a ZYX pitch lies in [-pi/2, pi/2]; a roll may be unwrapped (the flight logs' 4 pi)
        for j, (name, lim, what) in enumerate([("phi", 4 * math.pi, "[-4 pi, 4 pi]"),
                                               ("theta", math.pi / 2, "[-pi/2, pi/2]")]):
            bad = np.flatnonzero(np.abs(E[:, j]) > lim + 1e-6)
            if bad.size:
                raise GreyboxInputError(f"{source}: row {bad[0] + 2}, column {name!r}: {E[bad[0], j]:g} is "
                                        f"outside {what}; angles must be in rad (degrees?)")
    ok = ~np.isnan(E[:, :2]).any(axis=1)
    if ok.sum() < 2:
        raise GreyboxInputError(f"{source}: fewer than two rows with both 'phi' and 'theta' "
                                "(the attitude is interpolated between them)")
    t, E = t[ok], E[ok].copy()
    psi_ok = ~np.isnan(E[:, 2])
    E[:, 2] = np.unwrap(np.interp(t, t[psi_ok], E[psi_ok, 2])) if psi_ok.sum() >= 2 else 0.0
    return AttitudeTrack(t, E, source)


__all__.append("imu_attitude")


def _imread_quiet(path: Path) -> np.ndarray | None:
    """``cv2.imread`` without OpenCV's own error lines (a corrupt frame is counted and
    reported as a skip by the caller)."""
    log = cv2.utils.logging
    level = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_SILENT)
    try:
        return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    except cv2.error:
        return None
    finally:
        log.setLogLevel(level)


def save_positions(result: VisionResult, path: str | Path) -> None:
    """Write ``t,x,y,z,psi`` (one row per accepted frame) atomically."""
    lines = ["t,x,y,z,psi"]
    for t, p, e in zip(result.t, result.position, result.euler):
        lines.append(",".join(repr(float(v)) for v in (t, *p, e[2])))
    atomic_write(path, "\n".join(lines) + "\n")


def load_positions(path: str | Path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Read a vision positions CSV: ``t`` and any of ``x,y,z,psi`` → (t, values, names)."""
    header, data = read_csv_table(path)
    t = _time_column(path, header, data)
    names = [n for n in ("x", "y", "z", "psi") if n in header]
    if not {"x", "y", "z"} <= set(names):
        miss = next(n for n in ("x", "y", "z") if n not in header)
        raise GreyboxInputError(f"{path}: missing required column {miss!r}")
    return t, data[:, [header.index(n) for n in names]], names


def _time_column(path, header: list[str], data: np.ndarray) -> np.ndarray:
    """Column ``t`` of a table: present, never empty, strictly increasing (errors name the
    file, row and column)."""
    if "t" not in header:
        raise GreyboxInputError(f"{path}: missing required column 't'")
    t = data[:, header.index("t")]
    bad = np.flatnonzero(np.isnan(t))
    if bad.size:
        raise GreyboxInputError(f"{path}: row {bad[0] + 2}, column 't': missing value")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        raise GreyboxInputError(f"{path}: row {bad[0] + 3}, column 't': time is not after the "
                                "previous row's (t must be strictly increasing)")
    return t


def merge_vision(log: FlightLog, t_vis: np.ndarray, values: np.ndarray, names: list[str],
                 offset: float = 0.0, psi: str = "auto", tolerance: float = 1e-9) -> FlightLog:
    """Join vision positions with an IMU / rotor-speed log into one multi-rate flight log.

    Every vision sample keeps its own time (``t_vis + offset``): where it falls between log
    rows a row is inserted whose inputs are the previous row's (zero-order hold, README,
    "Flight log (CSV)") and whose other outputs are empty. Vision samples before the log's first row or
    after its last cannot hold an input and are dropped (with a note). The log's own
    ``x, y, z`` are replaced (they are what vision measures). ``psi``: ``"imu"`` keeps the
    log's yaw, ``"vision"`` uses the vision yaw, ``"auto"`` the log's if it has any, else
    the vision's.
    """
    if psi not in ("auto", "imu", "vision"):
        raise GreyboxInputError(f"psi must be 'auto', 'imu' or 'vision', got {psi!r}")
    tv = np.asarray(t_vis, float) + offset
    notes = list(log.notes)
    keep = (tv >= log.t[0] - tolerance) & (tv <= log.t[-1] + tolerance)
    if not keep.any():
        raise GreyboxInputError(
            f"no vision sample lies within the log's time span [{log.t[0]:g}, {log.t[-1]:g}] s "
            f"(vision spans [{tv[0]:g}, {tv[-1]:g}] s); are the clocks aligned? (--offset)")
    if (~keep).any():
        notes.append(f"dropped {int((~keep).sum())} vision sample(s) outside the log's time span")
    tv, vals = tv[keep], np.asarray(values, float)[keep]
    # a vision time within tolerance of a log row lands on that row
    k = np.searchsorted(log.t, tv, side="right") - 1
    k = np.clip(k, 0, len(log.t) - 1)
    nxt = np.clip(k + 1, 0, len(log.t) - 1)
    on_next = np.abs(log.t[nxt] - tv) <= tolerance
    k = np.where(on_next, nxt, k)
    on_row = np.abs(log.t[k] - tv) <= tolerance
    new_t = tv[~on_row]
    t = np.concatenate([log.t, new_t])
    order = np.argsort(t, kind="stable")
    inputs = np.vstack([log.inputs, log.inputs[k[~on_row]]])[order]
    outputs = np.vstack([log.outputs, np.full((new_t.size, log.outputs.shape[1]), np.nan)])[order]
    extras = {n: np.concatenate([v, np.full(new_t.size, np.nan)])[order] for n, v in log.extras.items()}
    row_of_vis = np.empty(tv.size, dtype=int)
    inv = np.empty_like(order)
    inv[order] = np.arange(order.size)
    row_of_vis[on_row] = inv[k[on_row]]
    row_of_vis[~on_row] = inv[len(log.t) + np.arange(new_t.size)]
    oi = {n: j for j, n in enumerate(log.output_names)}
    for n in ("x", "y", "z"):
        outputs[:, oi[n]] = np.nan
        outputs[row_of_vis, oi[n]] = vals[:, names.index(n)]
    use_vision_psi = psi == "vision" or (psi == "auto" and np.all(np.isnan(log.output("psi"))))
    if use_vision_psi:
        if "psi" not in names:
            raise GreyboxInputError("the vision file has no 'psi' column to take the yaw from")
        outputs[:, oi["psi"]] = np.nan
        outputs[row_of_vis, oi["psi"]] = vals[:, names.index("psi")]
    notes.append(f"merged {tv.size} vision sample(s) ({int((~on_row).sum())} at their own times); "
                 f"yaw from {'vision' if use_vision_psi else 'the log'}")
    return FlightLog(t[order], inputs, list(log.input_names), outputs, list(log.output_names),
                     extras, notes, log.source)

"""A synthetic camera: the rig's markers rendered as the onboard camera sees them through
its mirror, along a known trajectory — frames with a known truth for tests and studies.

Each marker is drawn by the homography that maps its printed image onto the image plane
(point to point, so the mirror's left-right reversal comes out by itself), supersampled
and area-averaged so that edges land with sub-pixel accuracy. On top: Gaussian noise on
the four corner positions (the noise the Cramér–Rao bound of
:func:`greybox.vision.position_crb` refers to), lens distortion, motion blur (the average
of renders across the exposure), rolling shutter (image rows rendered at their own read
times), exposure changes, pixel noise and optional occluders. Every random draw comes from
one seeded generator.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from .data import atomic_write
from .errors import GreyboxInputError
from .rotations import euler_from_rotation as rotation_to_euler, rotation
from .vision import VisionRig

__all__ = ["SyntheticCamera", "RenderedFrame", "trajectory_pose", "write_sequence"]

Pose = tuple[np.ndarray, np.ndarray]


def trajectory_pose(t: np.ndarray, position: np.ndarray, euler: np.ndarray) -> Callable[[float], Pose]:
    """Body pose ``(R_wb, p_wb)`` at any time, linearly interpolated between samples of a
    trajectory (positions NED, ZYX Euler angles; yaw unwrapped first)."""
    t = np.asarray(t, float)
    position = np.asarray(position, float)
    euler = np.asarray(euler, float).copy()
    euler[:, 2] = np.unwrap(euler[:, 2])

    def pose(tq: float) -> Pose:
        p = np.array([np.interp(tq, t, position[:, i]) for i in range(3)])
        e = [float(np.interp(tq, t, euler[:, i])) for i in range(3)]
        return rotation(*e), p

    return pose


@dataclass
class RenderedFrame:
    """One synthetic frame and its truth: the body pose at the frame time, the noise-free
    corner pixels of every marker in view (real image, distorted), and whether an occluder
    was drawn."""

    t: float
    image: np.ndarray
    R_wb: np.ndarray
    p_wb: np.ndarray
    corners: dict[int, np.ndarray]
    occluded: bool = False


@dataclass
class SyntheticCamera:
    """Renders the rig's markers along a trajectory.

    Args:
        rig: camera, mirror and markers (the camera's intrinsics and distortion are used).
        corner_noise_px: std of the Gaussian noise added to each marker corner position
            (undistorted pixels, independent per corner and axis, fixed within a frame).
        pixel_noise: std of additive image noise, grey levels.
        exposure_jitter: relative std of a per-frame gain (lighting / auto-exposure changes).
        exposure_time: s; > 0 averages ``blur_samples`` renders across it (motion blur).
        rolling_shutter: s from the first image row to the last; > 0 renders
            ``shutter_bands`` bands of rows each at its own time.
        occlusion: probability that an opaque blob covers part of a marker in a frame.
        supersample: renders at this factor and area-averages (edge accuracy).
        background, white: grey levels of the ground and the marker's white.
        margin_cells: white quiet zone around the marker's black border, in code cells.
        seed: seeds every random draw.
    """

    rig: VisionRig
    corner_noise_px: float = 0.0
    pixel_noise: float = 2.0
    exposure_jitter: float = 0.0
    exposure_time: float = 0.0
    blur_samples: int = 5
    rolling_shutter: float = 0.0
    shutter_bands: int = 12
    occlusion: float = 0.0
    supersample: int = 4
    background: float = 110.0
    white: float = 235.0
    black: float = 25.0
    margin_cells: int = 1
    seed: int = 0
    _rng: np.random.Generator = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.supersample < 1 or self.blur_samples < 1 or self.shutter_bands < 1:
            raise GreyboxInputError("supersample, blur_samples and shutter_bands must be >= 1")
        for name in ("corner_noise_px", "pixel_noise", "exposure_jitter", "exposure_time",
                     "rolling_shutter", "occlusion"):
            if getattr(self, name) < 0:
                raise GreyboxInputError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        self._rng = np.random.default_rng(self.seed)
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.rig.dictionary))
        cells = d.markerSize + 2
        m = self.margin_cells
        self._textures = {}
        for mid in self.rig.markers:
            code = cv2.aruco.generateImageMarker(d, mid, cells, borderBits=1)
            tex = np.full((cells + 2 * m, cells + 2 * m), 255, np.uint8)
            tex[m:m + cells, m:m + cells] = code
            # grey levels of print: black and white are never 0 and 255 under real light
            self._textures[mid] = np.where(tex > 127, self.white, self.black).astype(np.float32)
        # texel coordinates of the marker corners (TL, TR, BR, BL) and of the texture outline
        a, b = m - 0.5, m + cells - 0.5
        self._tex_corners = np.float32([[a, a], [b, a], [b, b], [a, b]])
        e = cells + 2 * m - 0.5
        self._tex_outline = np.float32([[-0.5, -0.5], [e, -0.5], [e, e], [-0.5, e]]).reshape(-1, 1, 2)
        cam = self.rig.camera
        self._distort_map = None
        if np.any(cam.dist != 0):
            # for every pixel of the distorted image, where it is in the pinhole image
            u, v = np.meshgrid(np.arange(cam.width, dtype=np.float32), np.arange(cam.height, dtype=np.float32))
            pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
            und = cv2.undistortPoints(pts, cam.K, cam.dist, R=None, P=cam.K,
                                      criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-6))
            und = und.reshape(cam.height, cam.width, 2)
            self._distort_map = (und[..., 0].copy(), und[..., 1].copy())

    # -- drawing --------------------------------------------------------------------------
    def _homographies(self, R_wb: np.ndarray, p_wb: np.ndarray,
                      noise: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
        """Texture-to-pinhole-image homography of every marker wholly in front of the camera."""
        out = {}
        for mid, mk in self.rig.markers.items():
            px, front = self.rig.project(R_wb, p_wb, mk.corners_world(self.rig.marker_size), distort=False)
            if not front.all():
                continue
            H = cv2.getPerspectiveTransform(self._tex_corners, (px + noise[mid]).astype(np.float32))
            outline = cv2.perspectiveTransform(self._tex_outline, H).reshape(-1, 2)
            # the texture's outline must map to a convex quad ahead of the camera
            w = (H @ np.vstack([self._tex_outline.reshape(-1, 2).T, np.ones(4)]))[2]
            if np.all(w > 0) or np.all(w < 0):
                out[mid] = (H, outline)
        return out

    def _draw(self, img: np.ndarray, homs: dict, r0: int, r1: int) -> None:
        """Draw the markers into rows ``r0:r1`` of ``img`` (float32, pinhole image)."""
        k = self.supersample
        H_img, W_img = img.shape
        for mid, (H, outline) in homs.items():
            x0 = max(int(math.floor(outline[:, 0].min())) - 1, 0)
            x1 = min(int(math.ceil(outline[:, 0].max())) + 2, W_img)
            y0 = max(int(math.floor(outline[:, 1].min())) - 1, r0)
            y1 = min(int(math.ceil(outline[:, 1].max())) + 2, r1)
            if x1 <= x0 or y1 <= y0:
                continue
            # image pixel x <-> supersampled pixel k*x + (k-1)/2, shifted to the window
            S = np.array([[k, 0, (k - 1) / 2 - k * x0], [0, k, (k - 1) / 2 - k * y0], [0, 0, 1.0]])
            win = img[y0:y1, x0:x1]
            canvas = cv2.resize(win, ((x1 - x0) * k, (y1 - y0) * k), interpolation=cv2.INTER_NEAREST)
            cv2.warpPerspective(self._textures[mid], S @ H, (canvas.shape[1], canvas.shape[0]), dst=canvas,
                                flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_TRANSPARENT)
            img[y0:y1, x0:x1] = cv2.resize(canvas, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)

    def _render_at(self, pose: Callable[[float], Pose], t: float, noise: dict[int, np.ndarray]) -> np.ndarray:
        cam = self.rig.camera
        img = np.full((cam.height, cam.width), self.background, np.float32)
        if self.rolling_shutter > 0:
            edges = np.linspace(0, cam.height, self.shutter_bands + 1).round().astype(int)
            for r0, r1 in zip(edges[:-1], edges[1:]):
                tr = t + self.rolling_shutter * ((r0 + r1) / 2 / cam.height - 0.5)
                self._draw(img, self._homographies(*pose(tr), noise), r0, r1)
        else:
            self._draw(img, self._homographies(*pose(t), noise), 0, cam.height)
        return img

    def render(self, pose: Callable[[float], Pose], t: float) -> RenderedFrame:
        """One frame at time ``t`` (the middle of the exposure of the middle row)."""
        cam = self.rig.camera
        rng = self._rng
        noise = {mid: rng.normal(0.0, self.corner_noise_px, (4, 2)) if self.corner_noise_px > 0
                 else np.zeros((4, 2)) for mid in self.rig.markers}
        if self.exposure_time > 0 and self.blur_samples > 1:
            ts = t + self.exposure_time * (np.linspace(0, 1, self.blur_samples) - 0.5)
            img = np.mean([self._render_at(pose, tt, noise) for tt in ts], axis=0).astype(np.float32)
        else:
            img = self._render_at(pose, t, noise)
        R_wb, p_wb = pose(t)
        corners = {}
        for mid in self.rig.markers:
            px, all_front = self.rig.marker_corners_px(R_wb, p_wb, mid)
            inside = all_front and np.all((px >= 0) & (px <= [cam.width - 1, cam.height - 1]))
            if inside:
                corners[mid] = px
        occluder = None
        if self.occlusion > 0 and corners and rng.random() < self.occlusion:
            # placed on the corners of the real (distorted) image, so drawn after the lens
            c = corners[list(corners)[int(rng.integers(len(corners)))]]
            side = float(np.linalg.norm(c[1] - c[0]))
            centre = c[int(rng.integers(4))] + rng.normal(0, 0.15 * side, 2)
            occluder = ((int(centre[0]), int(centre[1])), (max(int(0.35 * side), 2), max(int(0.2 * side), 2)))
        if self._distort_map is not None:
            img = cv2.remap(img, *self._distort_map, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if occluder is not None:
            cv2.ellipse(img, *occluder, float(rng.uniform(0, 180)), 0, 360, float(rng.uniform(60, 160)), -1)
        if self.exposure_jitter > 0:
            img *= float(np.clip(1.0 + rng.normal(0.0, self.exposure_jitter), 0.2, 3.0))
        if self.pixel_noise > 0:
            img += rng.normal(0.0, self.pixel_noise, img.shape).astype(np.float32)
        return RenderedFrame(t, np.clip(img + 0.5, 0, 255).astype(np.uint8), R_wb, p_wb, corners,
                             occluder is not None)

    def frames(self, pose: Callable[[float], Pose], times: np.ndarray) -> Iterator[RenderedFrame]:
        """Render a frame at each of ``times``."""
        for t in np.asarray(times, float):
            yield self.render(pose, float(t))


def write_sequence(frames: Iterator[RenderedFrame], folder: str | Path, ext: str = ".png") -> int:
    """Write frames as ``frame_000000.png``..., with ``timestamps.csv`` (``t``) and
    ``truth.csv`` (``t,x,y,z,phi,theta,psi`` of the body) beside them; returns the count."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    times, truth = ["t"], ["t,x,y,z,phi,theta,psi"]
    n = 0
    for i, f in enumerate(frames):
        if not cv2.imwrite(str(folder / f"frame_{i:06d}{ext}"), f.image):
            raise GreyboxInputError(f"{folder}: could not write frame {i} as {ext}")
        times.append(repr(f.t))
        truth.append(",".join(repr(float(v)) for v in (f.t, *f.p_wb, *rotation_to_euler(f.R_wb))))
        n += 1
    atomic_write(folder / "timestamps.csv", "\n".join(times) + "\n")
    atomic_write(folder / "truth.csv", "\n".join(truth) + "\n")
    return n

"""Camera motion between consecutive frames: one estimate per frame, shared by GMD, LMD and the search region.

A uniform grid of key points over the previous frame, pyramidal Lucas-Kanade into the current
one, a RANSAC homography (previous -> current pixels). Too few tracked points or a degenerate fit
give the identity with ``ok=False``. The estimate is made on a down-scaled grey copy of the frame
(``GreyLevels``) and returned as a ``CameraMotion`` in full-frame pixels, which maps points (the
search region's centre) and crops (the local motion detector's window) itself.

Two levels of detail, one per detector mode, so that a frame pays for one estimate:
- global (``fine=True``): GMD aligns the whole frame for differencing and needs sub-pixel accuracy:
  the frame no wider than ``FINE_WIDTH_PX``, the configured key-point grid;
- local (``fine=False``): the region needs its centre carried to a few pixels, and LMD differences
  only a small crop: no wider than ``COARSE_WIDTH_PX``, a ``COARSE_GRID_WH`` grid.
Measured on 40 synthetic 1080p frames against their true homographies (docs/notebook/2026-11-22.md
"Speed work"): 640 px and 30x20 points, 0.25 px mean error at full resolution and ~10 ms; 320 px
and 15x10 points, 0.45 px and ~2.8 ms (2 loaded cores).
"""

import logging
from dataclasses import dataclass
from typing import Optional, Tuple

import cv2
import numpy as np

from payload.config import MotionConfig

log = logging.getLogger(__name__)

FINE_WIDTH_PX = 640
COARSE_WIDTH_PX = 320
COARSE_GRID_WH = (15, 10)
#: A frame-to-frame homography scaling area by more than this (or less than its inverse) is
#: not camera motion between two frames but a broken fit.
MAX_AREA_SCALE = 4.0


@dataclass(frozen=True)
class CameraMotion:
    """The camera's motion between two frames: ``matrix`` maps previous-frame pixels to current-frame
    pixels (3x3 float64), and how it was found."""

    matrix: np.ndarray
    ok: bool = True  # False: the identity fallback (too few tracked points, or a broken fit)
    tracked: int = 0  # grid key points tracked by LK
    inliers: int = 0  # RANSAC inliers (0 when the fit failed)
    mean_shift_px: float = 0.0  # T_M: mean key-point displacement (inliers if ok, else all tracked)

    @classmethod
    def identity(cls, tracked: int = 0, mean_shift_px: float = 0.0) -> "CameraMotion":
        return cls(np.eye(3), False, int(tracked), 0, float(mean_shift_px))

    def apply(self, xy: Tuple[float, float]) -> Tuple[float, float]:
        """Where the pixel ``xy`` of the previous frame is in the current one."""
        p = self.matrix @ np.array([xy[0], xy[1], 1.0])
        if abs(p[2]) < 1e-12:
            return float(xy[0]), float(xy[1])
        return float(p[0] / p[2]), float(p[1] / p[2])

    def for_crop(self, offset_xy: Tuple[float, float]) -> "CameraMotion":
        """The same motion in the pixels of a crop at ``offset_xy`` of both frames:
        H_crop = T(-offset) . H . T(offset)."""
        if not self.ok:
            return self
        dx, dy = float(offset_xy[0]), float(offset_xy[1])
        to_full = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])
        to_crop = np.array([[1.0, 0.0, -dx], [0.0, 1.0, -dy], [0.0, 0.0, 1.0]])
        matrix = to_crop @ self.matrix @ to_full
        return CameraMotion(matrix / matrix[2, 2], self.ok, self.tracked, self.inliers, self.mean_shift_px)

    def at_scale(self, scale: float) -> "CameraMotion":
        """This motion in the pixels of a copy of both frames scaled by ``scale``."""
        if not self.ok:
            return CameraMotion.identity(self.tracked, self.mean_shift_px * scale)
        s = np.diag([scale, scale, 1.0])
        matrix = s @ self.matrix @ np.linalg.inv(s)
        return CameraMotion(matrix / matrix[2, 2], True, self.tracked, self.inliers, self.mean_shift_px * scale)

    def to_full_frame(self, scale_xy: Tuple[float, float]) -> "CameraMotion":
        """This motion, estimated on a level that scales full-frame pixels by ``scale_xy``, in
        full-frame pixels."""
        mean_shift = self.mean_shift_px / ((scale_xy[0] + scale_xy[1]) / 2.0)
        if not self.ok:
            return CameraMotion.identity(self.tracked, mean_shift)
        s = np.diag([scale_xy[0], scale_xy[1], 1.0])
        matrix = np.linalg.inv(s) @ self.matrix @ s
        return CameraMotion(matrix / matrix[2, 2], True, self.tracked, self.inliers, mean_shift)


@dataclass(frozen=True)
class GreyLevels:
    """One frame in grey, and the down-scaled copies the camera-motion estimates use.

    Each level is the frame itself when it is already narrow enough (no copy); ``scale_xy``
    maps full-frame pixels to that level's pixels.
    """

    full: np.ndarray
    fine: np.ndarray  # <= FINE_WIDTH_PX wide
    coarse: np.ndarray  # <= COARSE_WIDTH_PX wide

    @classmethod
    def of(cls, grey: np.ndarray) -> "GreyLevels":
        fine = _downscaled(grey, FINE_WIDTH_PX)
        return cls(grey, fine, _downscaled(fine, COARSE_WIDTH_PX))

    def level(self, fine: bool) -> np.ndarray:
        return self.fine if fine else self.coarse

    def scale_xy(self, level: np.ndarray) -> Tuple[float, float]:
        return level.shape[1] / float(self.full.shape[1]), level.shape[0] / float(self.full.shape[0])


def _downscaled(grey: np.ndarray, max_width_px: int) -> np.ndarray:
    h, w = grey.shape
    if w <= max_width_px:
        return grey
    size_wh = (max_width_px, max(1, int(round(h * max_width_px / float(w)))))
    return cv2.resize(grey, size_wh, interpolation=cv2.INTER_AREA)


class EgoMotion:
    """The camera-motion estimator: LK and RANSAC settings from the global motion config."""

    def __init__(self, cfg: MotionConfig) -> None:
        self.update_config(cfg)

    def update_config(self, cfg: MotionConfig) -> None:
        self.cfg = cfg
        self._coarse_cfg = cfg.model_copy(update={"grid_wh": COARSE_GRID_WH})

    def estimate(self, prev: Optional[GreyLevels], cur: GreyLevels, fine: bool) -> CameraMotion:
        """prev -> cur in full-frame pixels; the identity without a previous frame of the same size."""
        if prev is None or prev.full.shape != cur.full.shape:
            return CameraMotion.identity()
        level = cur.level(fine)
        found = estimate(prev.level(fine), level, self.cfg if fine else self._coarse_cfg)
        return found.to_full_frame(cur.scale_xy(level))


def lk_params(cfg: MotionConfig) -> dict:
    return dict(
        winSize=(cfg.lk_window_px, cfg.lk_window_px),
        maxLevel=cfg.lk_levels,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, cfg.lk_iterations, 0.01),
    )


def grid_points(size_wh: Tuple[int, int], grid_wh: Tuple[int, int]) -> np.ndarray:
    """Key points at the centres of a ``grid_wh`` grid of cells over an image: (N, 1, 2) float32."""
    w, h = size_wh
    xs = (np.arange(grid_wh[0], dtype=np.float32) + 0.5) * (w / float(grid_wh[0]))
    ys = (np.arange(grid_wh[1], dtype=np.float32) + 0.5) * (h / float(grid_wh[1]))
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1).reshape(-1, 1, 2)


def check_pair(prev_grey: np.ndarray, cur_grey: np.ndarray) -> None:
    for name, img in (("prev_grey", prev_grey), ("cur_grey", cur_grey)):
        if not isinstance(img, np.ndarray) or img.ndim != 2 or img.dtype != np.uint8:
            got = f"{img.dtype} {img.shape}" if isinstance(img, np.ndarray) else type(img).__name__
            raise ValueError(f"motion: {name} must be a 2-D uint8 grey image, got {got}")
    if prev_grey.shape != cur_grey.shape:
        raise ValueError(f"motion: prev_grey {prev_grey.shape} and cur_grey {cur_grey.shape} differ in size")


def _plausible(matrix: np.ndarray, size_wh: Tuple[int, int]) -> bool:
    """Whether H maps the image to a convex quadrilateral of similar area (not a broken fit)."""
    if matrix is None or not np.all(np.isfinite(matrix)) or abs(matrix[2, 2]) < 1e-12:
        return False
    w, h = size_wh
    corners = np.array([[[0, 0]], [[w, 0]], [[w, h]], [[0, h]]], np.float64)
    mapped = cv2.perspectiveTransform(corners, matrix)
    if not np.all(np.isfinite(mapped)):
        return False
    quad = mapped.astype(np.float32)
    if not cv2.isContourConvex(quad):
        return False
    scale = cv2.contourArea(quad) / float(w * h)
    return 1.0 / MAX_AREA_SCALE <= scale <= MAX_AREA_SCALE


def estimate(prev_grey: np.ndarray, cur_grey: np.ndarray, cfg: MotionConfig) -> CameraMotion:
    """Camera motion prev -> cur (in these images' pixels) from a key-point grid, LK and RANSAC."""
    check_pair(prev_grey, cur_grey)
    h, w = prev_grey.shape
    points = grid_points((w, h), cfg.grid_wh)
    moved, status, _ = cv2.calcOpticalFlowPyrLK(prev_grey, cur_grey, points, None, **lk_params(cfg))
    good = status.ravel() == 1
    src = points[good].reshape(-1, 2)
    dst = moved[good].reshape(-1, 2)
    tracked = len(src)
    shift = np.hypot(*(dst - src).T) if tracked else np.zeros(0)
    mean_shift = float(shift.mean()) if tracked else 0.0
    if tracked < cfg.min_tracked_points:
        log.debug("homography=identity reason=few_points tracked=%d min=%d", tracked, cfg.min_tracked_points)
        return CameraMotion.identity(tracked, mean_shift)
    matrix, inlier_mask = cv2.findHomography(src, dst, cv2.RANSAC, cfg.ransac_reproj_px)
    inliers = int(inlier_mask.sum()) if inlier_mask is not None else 0
    if inliers < 4 or not _plausible(matrix, (w, h)):
        log.debug("homography=identity reason=degenerate tracked=%d inliers=%d", tracked, inliers)
        return CameraMotion.identity(tracked, mean_shift)
    matrix = matrix / matrix[2, 2]
    mean_shift = float(shift[inlier_mask.ravel() == 1].mean())
    return CameraMotion(matrix.astype(np.float64), True, tracked, inliers, mean_shift)

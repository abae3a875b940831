"""The GLAD motion detector (paper Section IV): GMD on the full frame, LMD in the search region.

Two grey frames in, moving-object boxes out, in three steps:

1. Motion compensation: a uniform grid of ``grid_wh`` key points over the previous frame,
   pyramidal Lucas-Kanade into the current one, a RANSAC homography H (previous -> current
   pixels). Too few tracked points or a degenerate fit -> identity, ``ok=False``.
2. Segmentation: E = |blur(cur) - blur(warp_H(prev))| (saturating uint8), binarised with
   T2 + alpha*T_A + beta*T_M, opened and closed (3x3), connected blobs (outer contours), area and
   aspect limits, boxes closer than D1 merged.
3. Motion classifier: Shi-Tomasi corners of each candidate, their Lucas-Kanade flow relative
   to the background motion; incoherent (swaying trees, glitter, alignment errors) or too slow
   candidates are rejected. The CNN appearance classifier runs later, elsewhere.

Every threshold comes from ``MotionConfig``.
"""

import logging
from dataclasses import dataclass
from typing import Optional, Tuple

import cv2
import numpy as np

from payload.boxes import merge_boxes
from payload.config import MotionConfig
from payload.types import GMD, LMD, Detections

log = logging.getLogger(__name__)

#: Fewer trackable corners than this in a candidate: the spread statistics mean nothing.
MIN_CORNERS = 3
#: A corner whose LK track, run back from cur to prev, lands farther than this from where it
#: started is a bad track (occluded by the mover, or on an edge) and is left out.
MAX_FORWARD_BACKWARD_PX = 1.0
#: Score of a candidate accepted on its single blob-level flow vector (no coherence evidence).
FALLBACK_SCORE = 0.25
#: A frame-to-frame homography scaling area by more than this (or less than its inverse) is
#: not camera motion between two frames but a broken fit.
MAX_AREA_SCALE = 4.0

_KERNEL_3X3 = np.ones((3, 3), np.uint8)


@dataclass(frozen=True)
class HomographyEstimate:
    """Camera motion between two frames."""

    matrix: np.ndarray  # 3x3 float64, maps previous-frame pixels -> current-frame pixels
    tracked: int  # grid key points tracked by LK
    inliers: int  # RANSAC inliers (0 when the fit failed)
    mean_shift_px: float  # T_M: mean key-point displacement (inliers if ok, else all tracked)
    ok: bool  # False -> the identity fallback was used

    @classmethod
    def identity(cls, tracked: int = 0, mean_shift_px: float = 0.0) -> "HomographyEstimate":
        return cls(np.eye(3), int(tracked), 0, float(mean_shift_px), False)

    def for_crop(self, offset_xy: Tuple[float, float]) -> "HomographyEstimate":
        """The same camera motion in the pixels of a crop at ``offset_xy`` of both frames.

        Lets the local motion detector reuse the full-frame estimate (which the search region
        needs anyway) instead of tracking its own grid: H_crop = T(-offset) . H . T(offset).
        """
        dx, dy = float(offset_xy[0]), float(offset_xy[1])
        to_full = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])
        to_crop = np.array([[1.0, 0.0, -dx], [0.0, 1.0, -dy], [0.0, 0.0, 1.0]])
        matrix = to_crop @ self.matrix @ to_full
        return HomographyEstimate(
            matrix / matrix[2, 2], self.tracked, self.inliers, self.mean_shift_px, self.ok
        )


@dataclass(frozen=True)
class MotionResult:
    """What one motion-detector pass found.

    ``detections.score`` is a motion plausibility in (0, 1], before the CNN classifier:
    (1 - angle_spread) / (1 + speed_spread) of the candidate's relative flow vectors, i.e. 1 for
    perfectly parallel vectors of equal length, falling as directions or speeds scatter;
    ``FALLBACK_SCORE`` for a candidate accepted on a single blob-level vector.
    """

    detections: Detections  # accepted moving objects, full-frame xyxy, module GMD or LMD
    candidates: Detections  # every blob after area/aspect/merge, before the motion classifier (score 0)
    homography: HomographyEstimate
    threshold: float  # the binarisation threshold used: T2 + alpha*T_A + beta*T_M
    too_noisy: bool  # more than max_blobs blobs -> no detections


def _lk_params(cfg: MotionConfig) -> dict:
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


def estimate_homography(
    prev_grey: np.ndarray, cur_grey: np.ndarray, cfg: MotionConfig, _points: Optional[np.ndarray] = None
) -> HomographyEstimate:
    """Camera motion prev -> cur from a uniform key-point grid, pyramidal LK and RANSAC."""
    _check_pair(prev_grey, cur_grey)
    h, w = prev_grey.shape
    points = grid_points((w, h), cfg.grid_wh) if _points is None else _points
    moved, status, _ = cv2.calcOpticalFlowPyrLK(prev_grey, cur_grey, points, None, **_lk_params(cfg))
    good = status.ravel() == 1
    src = points[good].reshape(-1, 2)
    dst = moved[good].reshape(-1, 2)
    tracked = len(src)
    shift = np.hypot(*(dst - src).T) if tracked else np.zeros(0)
    mean_shift = float(shift.mean()) if tracked else 0.0
    if tracked < cfg.min_tracked_points:
        log.debug("homography=identity reason=few_points tracked=%d min=%d", tracked, cfg.min_tracked_points)
        return HomographyEstimate.identity(tracked, mean_shift)
    matrix, inlier_mask = cv2.findHomography(src, dst, cv2.RANSAC, cfg.ransac_reproj_px)
    inliers = int(inlier_mask.sum()) if inlier_mask is not None else 0
    if inliers < 4 or not _plausible(matrix, (w, h)):
        log.debug("homography=identity reason=degenerate tracked=%d inliers=%d", tracked, inliers)
        return HomographyEstimate.identity(tracked, mean_shift)
    matrix = matrix / matrix[2, 2]
    mean_shift = float(shift[inlier_mask.ravel() == 1].mean())
    return HomographyEstimate(matrix.astype(np.float64), tracked, inliers, mean_shift, True)


def flow_spread(flows_xy: np.ndarray) -> Tuple[float, float, float]:
    """(angle_spread, speed_spread, mean_speed) of N motion vectors (N, 2).

    angle_spread = 1 - mean resultant length of the unit vectors: 0 when all point the same
    way, near 1 for random directions; circular, so +179 deg and -179 deg count as close.
    speed_spread = std/mean of the lengths (coefficient of variation). Zero-length vectors
    have no direction and are left out of the angle statistic. No vectors -> (1, 0, 0).
    """
    flows = np.asarray(flows_xy, np.float64).reshape(-1, 2)
    if len(flows) == 0:
        return 1.0, 0.0, 0.0
    speed = np.hypot(flows[:, 0], flows[:, 1])
    mean_speed = float(speed.mean())
    speed_spread = float(speed.std() / mean_speed) if mean_speed > 1e-9 else 0.0
    moving = speed > 1e-9
    if not moving.any():
        return 1.0, speed_spread, mean_speed
    unit = flows[moving] / speed[moving, None]
    resultant = float(np.hypot(*unit.mean(axis=0)))
    return float(min(max(1.0 - resultant, 0.0), 1.0)), speed_spread, mean_speed


def _check_pair(prev_grey: np.ndarray, cur_grey: np.ndarray) -> None:
    for name, img in (("prev_grey", prev_grey), ("cur_grey", cur_grey)):
        if not isinstance(img, np.ndarray) or img.ndim != 2 or img.dtype != np.uint8:
            got = f"{img.dtype} {img.shape}" if isinstance(img, np.ndarray) else type(img).__name__
            raise ValueError(f"motion: {name} must be a 2-D uint8 grey image, got {got}")
    if prev_grey.shape != cur_grey.shape:
        raise ValueError(f"motion: prev_grey {prev_grey.shape} and cur_grey {cur_grey.shape} differ in size")


class MotionDetector:
    """GMD (module 'GMD', full frame) or LMD (module 'LMD', search-region crop)."""

    def __init__(self, cfg: MotionConfig, module: str) -> None:
        if module not in (GMD, LMD):
            raise ValueError(f"MotionDetector: module must be {GMD!r} or {LMD!r}, got {module!r}")
        self.module = module
        self.cfg = cfg
        self._grid_key = None  # (size_wh, grid_wh) of the cached grid
        self._grid = None

    def update_config(self, cfg: MotionConfig) -> None:
        """Apply new thresholds from the next call on (hot reload)."""
        self.cfg = cfg

    def _grid_for(self, size_wh: Tuple[int, int]) -> np.ndarray:
        key = (size_wh, tuple(self.cfg.grid_wh))
        if key != self._grid_key:
            self._grid = grid_points(size_wh, self.cfg.grid_wh)
            self._grid_key = key
        return self._grid

    def detect(
        self,
        prev_grey: np.ndarray,
        cur_grey: np.ndarray,
        offset_xy: Tuple[float, float] = (0, 0),
        homography: Optional[HomographyEstimate] = None,
    ) -> MotionResult:
        """Moving objects between two grey frames of the same size.

        prev/cur are the full frame, or the search-region crop of both frames at the same
        coordinates; ``offset_xy`` is the crop's top-left in the full frame, added to every box.
        ``homography``: one already estimated for these two images (skips re-estimation).
        """
        cfg = self.cfg
        _check_pair(prev_grey, cur_grey)
        h, w = cur_grey.shape
        if homography is None:
            homography = estimate_homography(prev_grey, cur_grey, cfg, self._grid_for((w, h)))

        # prev warped into cur's pixels; where the warp has no source pixel, cur itself shows
        # through (BORDER_TRANSPARENT), so the invalidated border differences to exactly 0.
        if homography.ok:
            aligned = cur_grey.copy()
            cv2.warpPerspective(
                prev_grey,
                homography.matrix,
                (w, h),
                dst=aligned,
                flags=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_TRANSPARENT,
            )
        else:
            aligned = prev_grey

        # T_A: lighting change, mean |raw cur - raw prev| without compensation.
        t_a = cv2.norm(cur_grey, prev_grey, cv2.NORM_L1) / float(w * h)
        threshold = cfg.t2 + cfg.alpha * t_a + cfg.beta * homography.mean_shift_px
        if cfg.blur_px:
            k = (cfg.blur_px, cfg.blur_px)
            diff = cv2.absdiff(cv2.GaussianBlur(cur_grey, k, 0), cv2.GaussianBlur(aligned, k, 0))
        else:
            diff = cv2.absdiff(cur_grey, aligned)
        # uint8 threshold compares E > floor(threshold): the same as E > threshold for integer E.
        _, mask = cv2.threshold(diff, threshold, 255, cv2.THRESH_BINARY)
        if cfg.open_iterations:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, _KERNEL_3X3, iterations=cfg.open_iterations)
        if cfg.close_iterations:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, _KERNEL_3X3, iterations=cfg.close_iterations)

        boxes, too_noisy = self._blobs(mask)
        dx, dy = float(offset_xy[0]), float(offset_xy[1])
        candidates = Detections(boxes, np.zeros(len(boxes), np.float32), self.module)
        if too_noisy or not len(boxes):
            return MotionResult(
                Detections.empty(), candidates.shifted(dx, dy), homography, threshold, too_noisy
            )

        scores = self._classify(aligned, cur_grey, mask, boxes)
        keep = scores > 0
        detections = Detections(boxes[keep], scores[keep], self.module)
        if log.isEnabledFor(logging.DEBUG):
            log.debug(
                "module=%s threshold=%.1f t_a=%.2f t_m=%.2f homography_ok=%s candidates=%d accepted=%d",
                self.module,
                threshold,
                t_a,
                homography.mean_shift_px,
                homography.ok,
                len(boxes),
                int(keep.sum()),
            )
        return MotionResult(
            detections.shifted(dx, dy), candidates.shifted(dx, dy), homography, threshold, False
        )

    def _blobs(self, mask: np.ndarray) -> Tuple[np.ndarray, bool]:
        """Candidate boxes (crop xyxy) from the cleaned mask, and whether the frame is too noisy.

        Blobs are 8-connected foreground regions (holes inside count as the blob). Area (its
        foreground pixel count) and aspect (longest/shortest box side) limits apply
        to each component; the blob count against max_blobs is taken after those limits and
        before merging, so that speckle below min area does not make a frame "noisy" and a
        noisy frame never pays for the pairwise merge.
        """
        cfg = self.cfg
        # External contours instead of connectedComponentsWithStats: the same blobs (8-connected),
        # but ~0.4 ms instead of ~12 ms on a sparse 1080p mask (no full-frame label image).
        contours = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)[-2]
        rects = np.array([cv2.boundingRect(c) for c in contours], np.int32).reshape(-1, 4)
        bw = rects[:, 2].astype(np.float32)
        bh = rects[:, 3].astype(np.float32)
        aspect = np.maximum(bw, bh) / np.maximum(np.minimum(bw, bh), 1.0)
        # A box smaller than the minimum area cannot hold enough pixels: skip counting them.
        keep = (bw * bh >= cfg.min_blob_area_px) & (aspect <= cfg.max_aspect)
        for i in np.flatnonzero(keep):
            x, y, rw, rh = rects[i]
            area = cv2.countNonZero(
                mask[y : y + rh, x : x + rw]
            )  # pixels of the blob (and of any neighbour in its box)
            keep[i] = cfg.min_blob_area_px <= area <= cfg.max_blob_area_px
        x = rects[keep, 0].astype(np.float32)
        y = rects[keep, 1].astype(np.float32)
        boxes = np.stack([x, y, x + bw[keep], y + bh[keep]], axis=1).reshape(-1, 4)
        if len(boxes) > cfg.max_blobs:
            log.debug("module=%s too_noisy=1 blobs=%d max_blobs=%d", self.module, len(boxes), cfg.max_blobs)
            return boxes, True
        if cfg.merge_distance_px > 0 and len(boxes) > 1:
            boxes = merge_boxes(boxes, cfg.merge_distance_px)
        return boxes, False

    def _classify(
        self, aligned: np.ndarray, cur: np.ndarray, mask: np.ndarray, boxes: np.ndarray
    ) -> np.ndarray:
        """Motion plausibility per candidate box; 0 = rejected by the motion classifier.

        Corners are taken in ``aligned`` (prev warped by H into cur's pixels), so their LK flow
        into cur is already relative to the background: d = p_cur - H(p_prev). A static object
        painted on moving ground has d ~ 0. Corners are searched only on the blob's foreground
        pixels inside the box, so background texture caught in the box does not dilute the flow.
        Tracks failing the forward-backward check are dropped (mostly background corners that
        the mover covers in cur). A candidate with fewer than MIN_CORNERS tracked corners is judged on one LK vector of
        the whole box (window = box size): accepted with FALLBACK_SCORE if it moves >= T5.
        """
        cfg = self.cfg
        h, w = cur.shape
        margin = cfg.lk_window_px + 8  # room for the LK window around the box
        lk = _lk_params(cfg)
        scores = np.zeros(len(boxes), np.float32)
        for i, (x1, y1, x2, y2) in enumerate(boxes.astype(np.int32)):
            cx1, cy1 = max(0, x1 - margin), max(0, y1 - margin)
            cx2, cy2 = min(w, x2 + margin), min(h, y2 + margin)
            prev_crop = aligned[cy1:cy2, cx1:cx2]
            cur_crop = cur[cy1:cy2, cx1:cx2]
            fg = np.zeros_like(prev_crop)
            fg[y1 - cy1 : y2 - cy1, x1 - cx1 : x2 - cx1] = mask[y1:y2, x1:x2]
            corners = cv2.goodFeaturesToTrack(
                prev_crop, cfg.max_corners, cfg.corner_quality, cfg.corner_min_distance_px, mask=fg
            )
            flows = np.zeros((0, 2), np.float32)
            if corners is not None:
                flows = _tracked_flows(prev_crop, cur_crop, corners, lk)
            if len(flows) >= MIN_CORNERS:
                angle_spread, speed_spread, mean_speed = flow_spread(flows)
                ok = (
                    angle_spread <= cfg.angle_spread_max
                    and speed_spread <= cfg.speed_spread_max
                    and mean_speed >= cfg.min_speed_px
                )
                score = (1.0 - angle_spread) / (1.0 + speed_spread)
                scores[i] = max(score, 1e-3) if ok else 0.0
                basis = "corners"
            else:
                mean_speed = self._box_speed(prev_crop, cur_crop, (x1 - cx1, y1 - cy1, x2 - cx1, y2 - cy1))
                angle_spread = speed_spread = float("nan")
                ok = mean_speed >= cfg.min_speed_px
                scores[i] = FALLBACK_SCORE if ok else 0.0
                basis = "box"
            if log.isEnabledFor(logging.DEBUG):
                log.debug(
                    "module=%s box=%d,%d,%d,%d basis=%s corners=%d angle_spread=%.2f speed_spread=%.2f "
                    "mean_speed_px=%.2f accepted=%d",
                    self.module,
                    x1,
                    y1,
                    x2,
                    y2,
                    basis,
                    len(flows),
                    angle_spread,
                    speed_spread,
                    mean_speed,
                    int(ok),
                )
        return scores

    def _box_speed(
        self, prev_crop: np.ndarray, cur_crop: np.ndarray, box: Tuple[int, int, int, int]
    ) -> float:
        """Relative speed (px) of the whole box by one LK vector at its centre; 0 if LK loses it."""
        x1, y1, x2, y2 = box
        side = int(max(x2 - x1, y2 - y1, self.cfg.lk_window_px)) | 1  # odd, covers the blob
        centre = np.array([[[(x1 + x2) / 2.0, (y1 + y2) / 2.0]]], np.float32)
        lk = _lk_params(self.cfg)
        lk["winSize"] = (side, side)
        flows = _tracked_flows(prev_crop, cur_crop, centre, lk)
        return float(np.hypot(*flows[0])) if len(flows) else 0.0


def _tracked_flows(prev: np.ndarray, cur: np.ndarray, points: np.ndarray, lk: dict) -> np.ndarray:
    """LK flow vectors (M, 2) of the points that track prev -> cur and back to within
    MAX_FORWARD_BACKWARD_PX of where they started."""
    moved, status, _ = cv2.calcOpticalFlowPyrLK(prev, cur, points, None, **lk)
    back, status_back, _ = cv2.calcOpticalFlowPyrLK(cur, prev, moved, None, **lk)
    fb_px = np.hypot(*(back - points).reshape(-1, 2).T)
    good = (status.ravel() == 1) & (status_back.ravel() == 1) & (fb_px <= MAX_FORWARD_BACKWARD_PX)
    return (moved[good] - points[good]).reshape(-1, 2)

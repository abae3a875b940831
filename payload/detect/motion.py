"""The GLAD motion detector (paper Section IV): GMD on the full frame, LMD in the search region.

Two grey frames and the camera motion between them (payload.detect.ego_motion) in, moving-object
boxes out, in two steps:

1. Segmentation: E = |blur(cur) - blur(warp_H(prev))| (saturating uint8), binarised with
   T2 + alpha*T_A + beta*T_M, opened and closed (3x3), connected blobs (outer contours), area and
   aspect limits, boxes closer than D1 merged. Frames wider than MAX_SEGMENT_WIDTH_PX (1080p) are
   segmented on a half-size copy (blur, opening and closing scaled to match).
2. Motion classifier, at full resolution: Shi-Tomasi corners of each candidate, their
   Lucas-Kanade flow relative to the background motion; incoherent (swaying trees, glitter,
   alignment errors) or too slow candidates are rejected. At most ``max_candidates`` a frame, the
   strongest differences first (the time budget). The CNN appearance classifier runs later,
   elsewhere.

Every threshold comes from ``MotionConfig``.
"""

import logging
from dataclasses import dataclass
from typing import Optional, Tuple

import cv2
import numpy as np

from payload.boxes import merge_boxes
from payload.config import MotionConfig
from payload.detect.ego_motion import CameraMotion, check_pair, lk_params
from payload.types import GMD, LMD, Detections

log = logging.getLogger(__name__)

#: Fewer trackable corners than this in a candidate: the spread statistics mean nothing.
MIN_CORNERS = 3
#: A corner whose LK track, run back from cur to prev, lands farther than this from where it
#: started is a bad track (occluded by the mover, or on an edge) and is left out.
MAX_FORWARD_BACKWARD_PX = 1.0
#: Score of a candidate accepted on its single blob-level flow vector (no coherence evidence).
FALLBACK_SCORE = 0.25
#: Frames wider than this are segmented (warp, difference, threshold, morphology, blobs) on a
#: half-size copy, and each candidate is judged at full resolution on its own crop: at 1080p the
#: full-frame warp, blurs and closing were ~2/3 of GMD's time (docs/results.md "Speed").
MAX_SEGMENT_WIDTH_PX = 1280
#: The blob-level flow vector's LK window at most (px, odd): a larger blob is tracked on a copy
#: scaled down to fit. LK's cost grows with the window's area: a 100 px window took ~50 ms.
MAX_BOX_WINDOW_PX = 31
_KERNEL_3X3 = np.ones((3, 3), np.uint8)
#: Pixels around a candidate's box that its Shi-Tomasi corners depend on: the 3x3 gradient (1), the
#: 3x3 covariance block (1), the 3x3 local-maximum test (1), and OpenCV never taking a corner on
#: the image's outermost row or column (1).
GFTT_CONTEXT_PX = 4


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
    camera: CameraMotion  # the camera motion the frames were aligned with
    threshold: float  # the binarisation threshold used: T2 + alpha*T_A + beta*T_M
    too_noisy: bool  # more than max_blobs blobs -> no detections
    left_out: int = 0  # candidates the motion classifier did not judge (over max_candidates): degraded


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


class MotionDetector:
    """GMD (module 'GMD', full frame) or LMD (module 'LMD', search-region crop)."""

    def __init__(self, cfg: MotionConfig, module: str) -> None:
        if module not in (GMD, LMD):
            raise ValueError(f"MotionDetector: module must be {GMD!r} or {LMD!r}, got {module!r}")
        self.module = module
        self.cfg = cfg

    def update_config(self, cfg: MotionConfig) -> None:
        """Apply new thresholds from the next call on (hot reload)."""
        self.cfg = cfg

    def detect(
        self,
        prev_grey: np.ndarray,
        cur_grey: np.ndarray,
        camera: CameraMotion,
        offset_xy: Tuple[float, float] = (0, 0),
    ) -> MotionResult:
        """Moving objects between two grey frames of the same size.

        prev/cur are the full frame, or the search-region crop of both frames at the same
        coordinates; ``offset_xy`` is the crop's top-left in the full frame, added to every box.
        ``camera``: the camera motion between these two images, in their pixels (a crop's:
        ``CameraMotion.for_crop``).
        """
        cfg = self.cfg
        check_pair(prev_grey, cur_grey)
        h, w = cur_grey.shape
        step = 2 if w > MAX_SEGMENT_WIDTH_PX else 1
        if step == 1:
            seg_prev, seg_cur, seg_camera = prev_grey, cur_grey, camera
        else:
            size = (w // step, h // step)
            seg_prev = cv2.resize(prev_grey, size, interpolation=cv2.INTER_AREA)
            seg_cur = cv2.resize(cur_grey, size, interpolation=cv2.INTER_AREA)
            seg_camera = camera.at_scale(1.0 / step)
        sh, sw = seg_cur.shape
        aligned = _aligned(seg_prev, seg_cur, seg_camera)

        # T_A: lighting change, mean |raw cur - raw prev| without compensation.
        t_a = cv2.norm(seg_cur, seg_prev, cv2.NORM_L1) / float(sw * sh)
        threshold = cfg.t2 + cfg.alpha * t_a + cfg.beta * camera.mean_shift_px
        blur_px = cfg.blur_px if step == 1 else (cfg.blur_px // step) | 1  # 5 -> 3 on the half-size copy
        if blur_px > 1:
            k = (blur_px, blur_px)
            diff = cv2.absdiff(cv2.GaussianBlur(seg_cur, k, 0), cv2.GaussianBlur(aligned, k, 0))
        else:
            diff = cv2.absdiff(seg_cur, aligned)
        # uint8 threshold compares E > floor(threshold): the same as E > threshold for integer E.
        _, mask = cv2.threshold(diff, threshold, 255, cv2.THRESH_BINARY)
        open_iterations, close_iterations = (-(-n // step) for n in (cfg.open_iterations, cfg.close_iterations))
        if open_iterations:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, _KERNEL_3X3, iterations=open_iterations)
        if close_iterations:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, _KERNEL_3X3, iterations=close_iterations)

        boxes, too_noisy = self._blobs(mask, step)
        dx, dy = float(offset_xy[0]), float(offset_xy[1])
        candidates = Detections(boxes, np.zeros(len(boxes), np.float32), self.module)
        if too_noisy or not len(boxes):
            return MotionResult(
                Detections.empty(), candidates.shifted(dx, dy), camera, threshold, too_noisy
            )

        judged, left_out = self._strongest(boxes, diff, mask, step)
        if step == 1:
            scores = self._classify(lambda crop: aligned[crop], cur_grey, mask, step, judged)
        else:  # prev aligned at full resolution only around each candidate judged
            scores = self._classify(lambda crop: _aligned(prev_grey, cur_grey, camera, crop), cur_grey, mask, step, judged)
        keep = scores > 0
        detections = Detections(judged[keep], scores[keep], self.module)
        if log.isEnabledFor(logging.DEBUG):
            log.debug(
                "module=%s threshold=%.1f t_a=%.2f t_m=%.2f homography_ok=%s candidates=%d left_out=%d accepted=%d",
                self.module,
                threshold,
                t_a,
                camera.mean_shift_px,
                camera.ok,
                len(boxes),
                left_out,
                int(keep.sum()),
            )
        return MotionResult(
            detections.shifted(dx, dy), candidates.shifted(dx, dy), camera, threshold, False, left_out
        )

    def _strongest(self, boxes: np.ndarray, diff: np.ndarray, mask: np.ndarray, step: int) -> Tuple[np.ndarray, int]:
        """The candidates the motion classifier judges: all of them up to max_candidates, else the
        max_candidates with the largest mean frame difference over their foreground (a moving
        drone differs strongly; misaligned texture and swaying leaves only just pass the
        threshold); and how many were left out."""
        cap = self.cfg.max_candidates
        if len(boxes) <= cap:
            return boxes, 0
        strength = np.empty(len(boxes), np.float64)
        for i, (x1, y1, x2, y2) in enumerate(boxes.astype(np.int32) // step):
            strength[i] = cv2.mean(diff[y1:y2, x1:x2], mask=mask[y1:y2, x1:x2])[0]
        order = np.argsort(-strength, kind="stable")[:cap]
        return boxes[np.sort(order)], len(boxes) - cap

    def _blobs(self, mask: np.ndarray, step: int) -> Tuple[np.ndarray, bool]:
        """Candidate boxes (crop xyxy) from the cleaned mask, and whether the frame is too noisy.
        ``step``: the mask's pixel is step x step image pixels (areas and boxes are in image pixels).

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
        pixel_area = float(step * step)
        # A box smaller than the minimum area cannot hold enough pixels: skip counting them.
        keep = (bw * bh * pixel_area >= cfg.min_blob_area_px) & (aspect <= cfg.max_aspect)
        for i in np.flatnonzero(keep):
            x, y, rw, rh = rects[i]
            # pixels of the blob (and of any neighbour in its box)
            area = cv2.countNonZero(mask[y : y + rh, x : x + rw]) * pixel_area
            keep[i] = cfg.min_blob_area_px <= area <= cfg.max_blob_area_px
        rects = rects * step
        bw, bh = bw * step, bh * step
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
        self, aligned_crop, cur: np.ndarray, mask: np.ndarray, step: int, boxes: np.ndarray
    ) -> np.ndarray:
        """Motion plausibility per candidate box; 0 = rejected by the motion classifier.

        Corners are taken in the aligned previous frame (prev warped by H into cur's pixels;
        ``aligned_crop(slices)`` gives it for a crop of cur), so their LK flow
        into cur is already relative to the background: d = p_cur - H(p_prev). A static object
        painted on moving ground has d ~ 0. Corners are searched only on the blob's foreground
        pixels inside the box (``mask``, whose pixel is step x step image pixels), so background
        texture caught in the box does not dilute the flow.
        Tracks failing the forward-backward check are dropped (mostly background corners that
        the mover covers in cur). A candidate with fewer than MIN_CORNERS tracked corners is judged on one LK vector of
        the whole box (window = box size): accepted with FALLBACK_SCORE if it moves >= T5.
        """
        cfg = self.cfg
        h, w = cur.shape
        margin = cfg.lk_window_px + 8  # room for the LK window around the box
        lk = lk_params(cfg)
        scores = np.zeros(len(boxes), np.float32)
        for i, (x1, y1, x2, y2) in enumerate(boxes.astype(np.int32)):
            cx1, cy1 = max(0, x1 - margin), max(0, y1 - margin)
            cx2, cy2 = min(w, x2 + margin), min(h, y2 + margin)
            prev_crop = aligned_crop((slice(cy1, cy2), slice(cx1, cx2)))
            cur_crop = cur[cy1:cy2, cx1:cx2]
            blob = mask[y1 // step : y2 // step, x1 // step : x2 // step]
            if step > 1:
                blob = cv2.resize(blob, (x2 - x1, y2 - y1), interpolation=cv2.INTER_NEAREST)
            corners = box_corners(prev_crop, blob, (x1 - cx1, y1 - cy1, x2 - cx1, y2 - cy1), cfg)
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
        scale = 1.0
        if side > MAX_BOX_WINDOW_PX:  # the same blob on a smaller copy, within the window cap
            scale = MAX_BOX_WINDOW_PX / float(side)
            size = (max(1, int(round(prev_crop.shape[1] * scale))), max(1, int(round(prev_crop.shape[0] * scale))))
            prev_crop = cv2.resize(prev_crop, size, interpolation=cv2.INTER_AREA)
            cur_crop = cv2.resize(cur_crop, size, interpolation=cv2.INTER_AREA)
            side = MAX_BOX_WINDOW_PX
        centre = np.array([[[(x1 + x2) / 2.0 * scale, (y1 + y2) / 2.0 * scale]]], np.float32)
        lk = lk_params(self.cfg)
        lk["winSize"] = (side, side)
        flows = _tracked_flows(prev_crop, cur_crop, centre, lk)
        return float(np.hypot(*flows[0])) / scale if len(flows) else 0.0


def box_corners(image: np.ndarray, box_mask: np.ndarray, box_xyxy: Tuple[int, int, int, int],
                cfg: MotionConfig) -> Optional[np.ndarray]:
    """Shi-Tomasi corners of ``image`` on the box's foreground (``box_mask``, the box's size): the
    corners cv2.goodFeaturesToTrack finds on the whole image masked to them, searched on the box
    and the GFTT_CONTEXT_PX around it that they depend on (a fraction of a candidate's crop)."""
    x1, y1, x2, y2 = box_xyxy
    h, w = image.shape[:2]
    gx1, gy1 = max(0, x1 - GFTT_CONTEXT_PX), max(0, y1 - GFTT_CONTEXT_PX)
    gx2, gy2 = min(w, x2 + GFTT_CONTEXT_PX), min(h, y2 + GFTT_CONTEXT_PX)
    mask = np.zeros((gy2 - gy1, gx2 - gx1), np.uint8)
    mask[y1 - gy1:y2 - gy1, x1 - gx1:x2 - gx1] = box_mask
    corners = cv2.goodFeaturesToTrack(image[gy1:gy2, gx1:gx2], cfg.max_corners, cfg.corner_quality,
                                      cfg.corner_min_distance_px, mask=mask)
    if corners is not None:
        corners += np.float32([gx1, gy1])
    return corners


def _aligned(prev: np.ndarray, cur: np.ndarray, camera: CameraMotion, crop=None) -> np.ndarray:
    """prev warped into cur's pixels (all of cur, or the ``crop`` slices of it). Where the warp has
    no source pixel, cur itself shows through (BORDER_TRANSPARENT), so the invalidated border
    differences to exactly 0."""
    if crop is None:
        crop = (slice(0, cur.shape[0]), slice(0, cur.shape[1]))
    if not camera.ok:
        return prev[crop]
    out = cur[crop].copy()
    y0, x0 = crop[0].start, crop[1].start
    to_crop = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
    matrix = camera.matrix if not (x0 or y0) else to_crop @ camera.matrix
    cv2.warpPerspective(prev, matrix, (out.shape[1], out.shape[0]), dst=out, flags=cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_TRANSPARENT)
    return out


def _tracked_flows(prev: np.ndarray, cur: np.ndarray, points: np.ndarray, lk: dict) -> np.ndarray:
    """LK flow vectors (M, 2) of the points that track prev -> cur and back to within
    MAX_FORWARD_BACKWARD_PX of where they started."""
    moved, status, _ = cv2.calcOpticalFlowPyrLK(prev, cur, points, None, **lk)
    back, status_back, _ = cv2.calcOpticalFlowPyrLK(cur, prev, moved, None, **lk)
    fb_px = np.hypot(*(back - points).reshape(-1, 2).T)
    good = (status.ravel() == 1) & (status_back.ravel() == 1) & (fb_px <= MAX_FORWARD_BACKWARD_PX)
    return (moved[good] - points[good]).reshape(-1, 2)

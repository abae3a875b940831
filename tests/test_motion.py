"""The GLAD motion detector on synthetic frame pairs with known answers (built here with NumPy/OpenCV)."""

import cv2
import numpy as np
import pytest

from payload.boxes import iou_matrix
from payload.config import Config, MotionConfig
from payload.detect.ego_motion import CameraMotion, estimate
from payload.detect.motion import FALLBACK_SCORE, MotionDetector, flow_spread

W, H = 320, 240


def texture(h, w, seed, sigma, lo, hi):
    """Smoothed random texture with values stretched to [lo, hi]."""
    t = np.random.default_rng(seed).integers(0, 256, (h, w)).astype(np.float32)
    t = cv2.GaussianBlur(t, (0, 0), sigma)
    return cv2.normalize(t, None, lo, hi, cv2.NORM_MINMAX).astype(np.uint8)


def iou(a, b):
    return iou_matrix(a, b)[0, 0]


class Scene:
    """A camera panning over textured ground by ``pan_xy`` px between two frames.

    ``ground`` is a canvas larger than the view: things painted on it move with the ground.
    """

    MARGIN = 40

    def __init__(self, pan_xy=(3.0, -2.0), seed=1):
        self.pan_xy = pan_xy
        m = self.MARGIN
        self.ground = texture(H + 2 * m, W + 2 * m, seed, 3.0, 60, 200)

    def view(self, canvas, shift_xy):
        m = self.MARGIN
        warp = np.float32([[1, 0, -m - shift_xy[0]], [0, 1, -m - shift_xy[1]]])
        return cv2.warpAffine(canvas, warp, (W, H), flags=cv2.INTER_LINEAR)

    def frames(self, canvas_prev=None, canvas_cur=None):
        prev = self.view(self.ground if canvas_prev is None else canvas_prev, (0.0, 0.0))
        cur = self.view(self.ground if canvas_cur is None else canvas_cur, self.pan_xy)
        return prev, cur

    def ground_to_cur(self, x, y):
        """Ground canvas pixel -> its pixel in the current frame."""
        return x - self.MARGIN - self.pan_xy[0], y - self.MARGIN - self.pan_xy[1]


MOVER = texture(36, 36, 5, 1.5, 0, 90)  # a dark textured object, larger than the LK window


def paste(img, patch, x, y):
    out = img.copy()
    out[y : y + patch.shape[0], x : x + patch.shape[1]] = patch
    return out


def detect(det, prev, cur, **kw):
    """The detector on a frame pair, with the camera motion estimated on that pair."""
    return det.detect(prev, cur, estimate(prev, cur, det.cfg), **kw)


def mover_scene():
    """Frames with a mover flying (+9, +5) px in the image while the camera pans; its cur xyxy."""
    scene = Scene()
    prev, cur = scene.frames()
    prev = paste(prev, MOVER, 140, 100)
    cur = paste(cur, MOVER, 149, 105)
    return prev, cur, (149.0, 105.0, 185.0, 141.0)


# --- detection on a moving camera -----------------------------------------------------------


def test_moving_object_found_on_moving_ground():
    prev, cur, truth = mover_scene()
    result = detect(MotionDetector(MotionConfig(), "GMD"), prev, cur)
    assert result.camera.ok
    assert not result.too_noisy
    assert len(result.detections) == 1, result.candidates.xyxy
    assert iou(result.detections.xyxy[0], truth) > 0.5, result.detections.xyxy
    assert 0 < result.detections.score[0] <= 1
    assert result.detections.module[0] == "GMD"


def test_static_object_painted_on_ground_is_not_detected():
    scene = Scene()
    ground = paste(scene.ground, MOVER, 180, 140)  # moves with the ground
    prev, cur = scene.frames(ground, ground)
    result = detect(MotionDetector(MotionConfig(), "GMD"), prev, cur)
    assert result.camera.ok
    assert len(result.detections) == 0, result.detections.xyxy


def test_object_holding_still_in_the_image_moves_relative_to_the_ground():
    """A chase target matching the camera's motion: image flow 0, flow relative to the ground not."""
    prev, cur = Scene(pan_xy=(3.0, -2.0)).frames()
    prev, cur = paste(prev, MOVER, 140, 100), paste(cur, MOVER, 140, 100)
    result = detect(MotionDetector(MotionConfig(), "GMD"), prev, cur)
    assert len(result.detections) == 1, result.candidates.xyxy
    assert iou(result.detections.xyxy[0], (140, 100, 176, 136)) > 0.5


def test_camera_pan_alone_leaves_no_border_blobs():
    prev, cur = Scene(pan_xy=(12.0, 7.0)).frames()
    result = detect(MotionDetector(MotionConfig(), "GMD"), prev, cur)
    assert result.camera.ok
    assert len(result.candidates) == 0, result.candidates.xyxy


def test_jittering_texture_is_rejected_by_motion_classifier():
    """Leaves/glitter: each 6x6 block of a patch moves its own random way between frames."""
    scene = Scene()
    rng = np.random.default_rng(7)
    x0, y0, side = 150, 110, 48
    leaves = texture(side + 16, side + 16, 9, 1.2, 0, 255)
    ground_prev = paste(scene.ground, leaves[8:-8, 8:-8], x0, y0)
    jittered = np.empty((side, side), np.uint8)
    for by in range(0, side, 6):
        for bx in range(0, side, 6):
            dx, dy = rng.uniform(-4, 4, 2).round().astype(int)
            jittered[by : by + 6, bx : bx + 6] = leaves[
                8 + by + dy : 14 + by + dy, 8 + bx + dx : 14 + bx + dx
            ]
    ground_cur = paste(scene.ground, jittered, x0, y0)
    prev, cur = scene.frames(ground_prev, ground_cur)
    result = detect(MotionDetector(MotionConfig(), "GMD"), prev, cur)
    region = (*scene.ground_to_cur(x0, y0), *scene.ground_to_cur(x0 + side, y0 + side))
    assert any(iou(box, region) > 0.2 for box in result.candidates.xyxy), result.candidates.xyxy
    assert len(result.detections) == 0, result.detections.xyxy


# --- flow statistics ------------------------------------------------------------------------


def test_flow_spread_consistent_vectors():
    rng = np.random.default_rng(1)
    flows = np.array([5.0, 2.0]) + rng.normal(0, 0.1, (30, 2))
    angle, speed, mean = flow_spread(flows)
    assert angle < 0.01 and speed < 0.05
    assert mean == pytest.approx(np.hypot(5, 2), abs=0.1)


def test_flow_spread_random_vectors():
    rng = np.random.default_rng(2)
    theta = rng.uniform(-np.pi, np.pi, 200)
    speed_px = rng.uniform(0.2, 6, 200)
    flows = np.stack([np.cos(theta), np.sin(theta)], 1) * speed_px[:, None]
    angle, speed, _ = flow_spread(flows)
    assert angle > 0.8 and speed > 0.4


def test_flow_spread_is_circular_across_180_deg():
    theta = np.deg2rad([179.0, -179.0, 178.0, -178.0])  # all pointing left
    flows = 3.0 * np.stack([np.cos(theta), np.sin(theta)], 1)
    angle, speed, mean = flow_spread(flows)
    assert angle < 0.001
    assert speed == pytest.approx(0.0, abs=1e-9) and mean == pytest.approx(3.0)
    # the plain (non-circular) statistic of the authors' code would call this scattered
    assert np.var(np.arctan2(flows[:, 1], flows[:, 0])) > 9


def test_flow_spread_empty_and_zero():
    assert flow_spread(np.zeros((0, 2))) == (1.0, 0.0, 0.0)
    assert flow_spread(np.zeros((4, 2)))[0] == 1.0


# --- blob filtering -------------------------------------------------------------------------


def appearing(rects, size_wh=(W, H)):
    """A flat scene where white rectangles (x, y, w, h) appear between the frames."""
    prev = np.full((size_wh[1], size_wh[0]), 100, np.uint8)
    cur = prev.copy()
    for x, y, w, h in rects:
        cur[y : y + h, x : x + w] = 255
    return prev, cur


def test_area_and_aspect_limits():
    cfg = MotionConfig(
        blur_px=0, close_iterations=0, min_blob_area_px=30, max_blob_area_px=3000, max_aspect=3.0
    )
    rects = [
        (10, 10, 4, 4),  # 16 px: too small
        (60, 10, 12, 12),  # kept
        (100, 100, 70, 70),  # 4900 px: too large
        (10, 200, 40, 8),  # aspect 5: too elongated
        (250, 150, 24, 10),  # aspect 2.4: kept
    ]
    result = detect(MotionDetector(cfg, "GMD"), *appearing(rects))
    boxes = sorted(map(tuple, result.candidates.xyxy.tolist()))
    assert boxes == [(60, 10, 72, 22), (250, 150, 274, 160)]


def test_nearby_boxes_merge_within_d1():
    cfg = MotionConfig(blur_px=0, close_iterations=0, merge_distance_px=15)
    near = appearing([(50, 50, 10, 10), (68, 52, 10, 10)])  # 8 px gap
    far = appearing([(50, 50, 10, 10), (100, 50, 10, 10)])  # 40 px gap
    det = MotionDetector(cfg, "GMD")
    assert detect(det, *near).candidates.xyxy.tolist() == [[50, 50, 78, 62]]
    assert len(detect(det, *far).candidates) == 2
    det.update_config(MotionConfig(blur_px=0, close_iterations=0, merge_distance_px=0))
    assert len(detect(det, *near).candidates) == 2


def test_too_noisy_frame_gives_no_detections():
    rects = [(5 + 30 * i, 5 + 30 * j, 8, 8) for i in range(10) for j in range(7)]  # 70 blobs
    result = detect(MotionDetector(MotionConfig(blur_px=0, max_blobs=50), "GMD"), *appearing(rects))
    assert result.too_noisy
    assert len(result.detections) == 0 and len(result.candidates) == 70
    result = detect(MotionDetector(MotionConfig(blur_px=0, max_blobs=100), "GMD"), *appearing(rects))
    assert not result.too_noisy and len(result.candidates) == 70


def test_threshold_follows_t2_alpha_t_a_beta_t_m():
    prev, cur, _ = mover_scene()
    cfg = MotionConfig(t2=5, alpha=1.0, beta=0.5)
    result = detect(MotionDetector(cfg, "GMD"), prev, cur)
    t_a = np.abs(cur.astype(int) - prev.astype(int)).mean()
    assert result.threshold == pytest.approx(5 + t_a + 0.5 * result.camera.mean_shift_px, rel=1e-6)


# --- local crops ----------------------------------------------------------------------------


def test_local_crop_detections_in_full_frame_coordinates():
    prev, cur, truth = mover_scene()
    x0, y0 = 90, 60
    crop = (slice(y0, y0 + 150), slice(x0, x0 + 150))
    result = detect(MotionDetector(MotionConfig(), "LMD"), prev[crop], cur[crop], offset_xy=(x0, y0))
    assert len(result.detections) == 1
    assert iou(result.detections.xyxy[0], truth) > 0.5, result.detections.xyxy
    assert result.detections.module[0] == "LMD"
    assert all(iou(c, truth) > 0.5 for c in result.candidates.xyxy)


def test_full_frame_camera_motion_used_for_a_crop():
    prev, cur, truth = mover_scene()
    full = estimate(prev, cur, MotionConfig())
    x0, y0 = 90, 60
    crop = (slice(y0, y0 + 150), slice(x0, x0 + 150))
    result = MotionDetector(MotionConfig(), "LMD").detect(prev[crop], cur[crop], full.for_crop((x0, y0)), (x0, y0))
    assert len(result.detections) == 1 and iou(result.detections.xyxy[0], truth) > 0.5


def test_given_camera_motion_is_used_as_is():
    prev, cur, truth = mover_scene()
    det = MotionDetector(MotionConfig(), "GMD")
    est = estimate(prev, cur, det.cfg)
    result = det.detect(prev, cur, est)
    assert result.camera is est
    assert iou(result.detections.xyxy[0], truth) > 0.5
    # identity on a panning camera: the whole textured ground "moves" and no longer aligns
    still = det.detect(prev, cur, CameraMotion.identity())
    assert len(still.candidates) != 1 or iou(still.candidates.xyxy[0], truth) < 0.5


def test_unknown_module_rejected():
    with pytest.raises(ValueError, match="GMD"):
        MotionDetector(MotionConfig(), "XYZ")


# --- time budget: candidates capped, large blobs tracked on a smaller copy ---------------------


def movers_scene(strong, weak):
    """A flat grey scene with ``weak`` faint textured movers and then ``strong`` dark ones, each
    moving (+6, +3) px between the frames; the cur boxes of the strong ones."""
    prev = np.full((H, W), 150, np.uint8)
    cur = prev.copy()
    boxes = []
    for i in range(weak + strong):
        x, y = 10 + 50 * (i % 6), 10 + 60 * (i // 6)
        faint = (110 + MOVER[:24, :24] // 3).astype(np.uint8)  # 110-140 on 150
        patch = faint if i < weak else MOVER[:24, :24]  # 0-90 on 150
        prev = paste(prev, patch, x, y)
        cur = paste(cur, patch, x + 6, y + 3)
        if i >= weak:
            boxes.append((x + 6, y + 3, x + 30, y + 27))
    return prev, cur, boxes


def test_candidates_over_the_cap_are_left_out_strongest_difference_first():
    prev, cur, boxes = movers_scene(strong=3, weak=5)
    still = CameraMotion(np.eye(3))  # a camera at rest: only the movers move
    cfg = MotionConfig(t2=3, alpha=0.0, merge_distance_px=0, max_candidates=100)
    full = MotionDetector(cfg, "GMD").detect(prev, cur, still)
    assert len(full.candidates) == 8 and full.left_out == 0
    assert len(full.detections) >= 6  # the faint movers pass the motion classifier too when judged
    capped = MotionDetector(cfg.model_copy(update={"max_candidates": 3}), "GMD").detect(prev, cur, still)
    assert len(capped.candidates) == 8 and capped.left_out == 5
    assert len(capped.detections) == 3
    assert all(max(iou(d, b) for b in boxes) > 0.5 for d in capped.detections.xyxy), capped.detections.xyxy


def test_a_large_featureless_blob_is_tracked_at_its_true_speed():
    # a smooth 60 px disc has no corners to track: it is judged on one vector of the whole blob,
    # measured on a copy scaled to the window cap, and reported in full-frame pixels
    prev = np.full((H, W), 150, np.uint8)
    disc = np.full((H, W), 150, np.uint8)
    cv2.circle(disc, (100, 120), 30, 40, -1)
    disc = cv2.GaussianBlur(disc, (0, 0), 6)
    prev = disc
    cur = np.roll(disc, (0, 6), axis=(0, 1))  # moves 6 px right
    for min_speed, found in ((4.0, True), (8.0, False)):
        cfg = MotionConfig(alpha=0.0, min_speed_px=min_speed, corner_quality=0.9)
        result = MotionDetector(cfg, "GMD").detect(prev, cur, CameraMotion(np.eye(3)))
        assert len(result.candidates) == 1
        assert len(result.detections) == int(found), (min_speed, result.detections)
        if found:
            assert result.detections.score[0] == pytest.approx(FALLBACK_SCORE)


def test_a_wide_frame_is_segmented_at_half_size_and_judged_at_full_resolution():
    # 1920x1080 panning textured ground, an 8 px dark mover: found, its box in full-frame pixels
    m = 40
    ground = texture(1080 + 2 * m, 1920 + 2 * m, 11, 3.0, 90, 200)
    prev = np.ascontiguousarray(ground[m:m + 1080, m:m + 1920])
    cur = np.ascontiguousarray(ground[m + 2:m + 2 + 1080, m + 3:m + 3 + 1920])  # content moves (-3, -2)
    dot = texture(8, 8, 12, 0.8, 0, 40)
    prev, cur = paste(prev, dot, 1200, 700), paste(cur, dot, 1207, 704)
    cfg = Config().detector.global_.motion
    result = detect(MotionDetector(cfg, "GMD"), prev, cur)
    assert result.camera.ok and not result.too_noisy
    assert len(result.detections) == 1, (result.candidates.xyxy, result.detections.xyxy)
    x1, y1, x2, y2 = result.detections.xyxy[0]
    # the blob of a frame difference covers where the mover was (aligned) and is: 1197-1215, 698-712
    assert x1 <= 1197 and y1 <= 698 and x2 >= 1215 and y2 >= 712, result.detections.xyxy
    assert x2 - x1 < 40 and y2 - y1 < 30, result.detections.xyxy


@pytest.mark.parametrize("seed", range(6))
def test_a_candidates_corners_are_searched_on_its_box_alone(seed):
    # the corners of the box and its context are the corners goodFeaturesToTrack finds on the
    # whole crop under the same mask, boxes at the crop's edges and corners at the box's included
    from payload.detect.motion import box_corners

    rng = np.random.default_rng(seed)
    cfg = MotionConfig()
    crop = texture(90, 120, seed, 1.0, 0, 255)
    for _ in range(40):
        w, h = (int(v) for v in rng.integers(3, 40, 2))
        x1, y1 = int(rng.integers(0, 120 - w + 1)), int(rng.integers(0, 90 - h + 1))
        x1, y1 = (0 if rng.random() < 0.2 else x1), (90 - h if rng.random() < 0.2 else y1)
        mask = np.zeros_like(crop)
        mask[y1:y1 + h, x1:x1 + w] = (rng.random((h, w)) < 0.7) * 255
        whole = cv2.goodFeaturesToTrack(crop, cfg.max_corners, cfg.corner_quality, cfg.corner_min_distance_px,
                                        mask=mask)
        found = box_corners(crop, mask[y1:y1 + h, x1:x1 + w], (x1, y1, x1 + w, y1 + h), cfg)
        assert (whole is None) == (found is None)
        if whole is not None:
            assert np.array_equal(found, whole), (x1, y1, w, h)

"""Camera motion between frames (payload.detect.ego_motion): the one estimate GMD, LMD and the
search region share, on synthetic frames with known motion."""

import cv2
import numpy as np
import pytest

from payload.config import Config, MotionConfig
from payload.detect.ego_motion import CameraMotion, EgoMotion, GreyLevels, estimate

W, H = 320, 240


def texture(h, w, seed, sigma=2.0):
    t = np.random.default_rng(seed).integers(0, 256, (h, w)).astype(np.float32)
    return cv2.normalize(cv2.GaussianBlur(t, (0, 0), sigma), None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def shifted_pair(size_wh, shift_xy, seed=1):
    """A textured frame and the same view after the camera moved: content moves by ``shift_xy``."""
    w, h = size_wh
    m = 40
    ground = texture(h + 2 * m, w + 2 * m, seed)
    prev = np.ascontiguousarray(ground[m:m + h, m:m + w])
    cur = np.ascontiguousarray(ground[m - shift_xy[1]:m - shift_xy[1] + h, m - shift_xy[0]:m - shift_xy[0] + w])
    return prev, cur


def test_estimate_recovers_a_known_warp():
    prev = texture(H, W, 3)
    angle = np.deg2rad(1.5)
    truth = np.array([[1.02 * np.cos(angle), -np.sin(angle), 4.0],
                      [np.sin(angle), 1.02 * np.cos(angle), -3.0],
                      [2e-5, -1e-5, 1.0]])
    cur = cv2.warpPerspective(prev, truth, (W, H), flags=cv2.INTER_LINEAR)
    est = estimate(prev, cur, MotionConfig())
    assert est.ok
    assert est.tracked >= 0.8 * 30 * 20 and est.inliers >= 0.8 * est.tracked
    corners = np.array([[[0, 0]], [[W, 0]], [[W, H]], [[0, H]]], np.float64)
    err = np.linalg.norm(cv2.perspectiveTransform(corners, est.matrix) - cv2.perspectiveTransform(corners, truth), axis=2)
    assert err.max() < 0.5, err.ravel()
    assert 3.0 < est.mean_shift_px < 10.0


def test_flat_image_gives_the_identity():
    flat = np.full((H, W), 128, np.uint8)
    est = estimate(flat, flat.copy(), MotionConfig())
    assert not est.ok
    assert est.tracked < MotionConfig().min_tracked_points
    np.testing.assert_array_equal(est.matrix, np.eye(3))


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="differ in size"):
        estimate(np.zeros((10, 10), np.uint8), np.zeros((10, 12), np.uint8), MotionConfig())
    with pytest.raises(ValueError, match="2-D uint8"):
        estimate(np.zeros((10, 10, 3), np.uint8), np.zeros((10, 10, 3), np.uint8), MotionConfig())


@pytest.mark.parametrize("size_wh, fine_wh, coarse_wh", [
    ((1920, 1080), (640, 360), (320, 180)),
    ((640, 512), (640, 512), (320, 256)),
    ((320, 256), (320, 256), (320, 256)),
])
def test_grey_levels_sizes_and_no_copy_when_narrow(size_wh, fine_wh, coarse_wh):
    grey = np.zeros((size_wh[1], size_wh[0]), np.uint8)
    levels = GreyLevels.of(grey)
    assert levels.full is grey
    assert levels.fine.shape[::-1] == fine_wh and levels.coarse.shape[::-1] == coarse_wh
    assert (levels.fine is grey) == (fine_wh == size_wh)  # a narrow frame is not copied
    sx, sy = levels.scale_xy(levels.coarse)
    assert sx == pytest.approx(coarse_wh[0] / size_wh[0]) and sy == pytest.approx(coarse_wh[1] / size_wh[1])


@pytest.mark.parametrize("fine", [True, False])
def test_both_levels_give_the_true_shift_in_full_frame_pixels(fine):
    prev, cur = shifted_pair((1920, 1080), (12, -6))  # content moves right 12, up 6
    camera = EgoMotion(Config().detector.global_.motion).estimate(GreyLevels.of(prev), GreyLevels.of(cur), fine=fine)
    assert camera.ok
    for xy in ((960.0, 540.0), (100.0, 900.0)):
        moved = camera.apply(xy)
        assert moved == pytest.approx((xy[0] + 12, xy[1] - 6), abs=0.5 if fine else 1.0)
    assert camera.mean_shift_px == pytest.approx(np.hypot(12, 6), abs=0.5 if fine else 1.0)


def test_no_previous_frame_or_another_size_gives_the_identity():
    ego = EgoMotion(MotionConfig())
    cur = GreyLevels.of(texture(240, 320, 1))
    assert not ego.estimate(None, cur, fine=True).ok
    other = GreyLevels.of(texture(200, 320, 1))
    camera = ego.estimate(other, cur, fine=False)
    assert not camera.ok and camera.apply((10.0, 20.0)) == (10.0, 20.0)


def test_for_crop_maps_crop_pixels_as_the_full_frame_does():
    prev, cur = shifted_pair((W, H), (5, 3))
    full = estimate(prev, cur, MotionConfig())
    x0, y0 = 90, 60
    local = full.for_crop((x0, y0))
    moved = np.array(local.apply((20.0, 30.0))) + (x0, y0)
    np.testing.assert_allclose(moved, full.apply((20.0 + x0, 30.0 + y0)), atol=1e-9)
    assert CameraMotion.identity().for_crop((x0, y0)).matrix.tolist() == np.eye(3).tolist()


def test_a_failed_estimate_at_a_level_stays_the_exact_identity():
    failed = CameraMotion.identity(tracked=3, mean_shift_px=2.0).to_full_frame((1 / 6.0, 1 / 6.0))
    assert not failed.ok and failed.matrix.tolist() == np.eye(3).tolist()
    assert failed.mean_shift_px == pytest.approx(12.0)


def test_at_scale_is_the_motion_on_a_scaled_copy():
    prev, cur = shifted_pair((640, 480), (8, -4))
    full = estimate(prev, cur, MotionConfig())
    half = full.at_scale(0.5)
    assert half.apply((100.0, 50.0)) == pytest.approx(tuple(np.array(full.apply((200.0, 100.0))) / 2), abs=1e-9)
    np.testing.assert_allclose(half.to_full_frame((0.5, 0.5)).matrix, full.matrix, atol=1e-12)
    assert half.mean_shift_px == pytest.approx(full.mean_shift_px / 2)

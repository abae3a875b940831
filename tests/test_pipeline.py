"""GLAD pipeline internals touched by the speed work: shared grey levels and homographies estimated
on a down-scaled copy, mapped back to full-frame pixels."""

import cv2
import numpy as np
import pytest

from payload.config import Config
from payload.detect.motion import estimate_homography
from payload.detect.pipeline import GreyLevels, _to_full_frame


@pytest.mark.parametrize("size_wh, motion_wh, ego_wh", [
    ((1920, 1080), (640, 360), (320, 180)),
    ((640, 512), (640, 512), (320, 256)),
    ((320, 256), (320, 256), (320, 256)),
])
def test_grey_levels_sizes_and_no_copy_when_narrow(size_wh, motion_wh, ego_wh):
    grey = np.zeros((size_wh[1], size_wh[0]), np.uint8)
    levels = GreyLevels.of(grey)
    assert levels.full is grey
    assert levels.motion.shape[::-1] == motion_wh and levels.ego.shape[::-1] == ego_wh
    assert (levels.motion is grey) == (motion_wh == size_wh)  # a narrow frame is not copied
    sx, sy = levels.scale_xy(levels.ego)
    assert sx == pytest.approx(ego_wh[0] / size_wh[0]) and sy == pytest.approx(ego_wh[1] / size_wh[1])


def test_homography_from_a_downscaled_copy_matches_the_true_shift(rng):
    # a textured 1080p frame and the same frame shifted by (+12, -6) px: a known camera motion
    texture = cv2.GaussianBlur(rng.integers(0, 256, (1140, 1980), dtype=np.uint8), (0, 0), 2.0)
    prev = np.ascontiguousarray(texture[30:1110, 30:1950])
    cur = np.ascontiguousarray(texture[36:1116, 18:1938])  # content moves right 12, up 6
    a, b = GreyLevels.of(prev), GreyLevels.of(cur)
    cfg = Config().detector.global_.motion
    estimate = _to_full_frame(estimate_homography(a.motion, b.motion, cfg), b.scale_xy(b.motion))
    assert estimate.ok
    moved = cv2.perspectiveTransform(np.array([[[960.0, 540.0]], [[100.0, 900.0]]]), estimate.matrix)
    np.testing.assert_allclose(moved.reshape(-1, 2) - [[960.0, 540.0], [100.0, 900.0]], [[12, -6], [12, -6]], atol=0.5)
    assert estimate.mean_shift_px == pytest.approx(np.hypot(12, 6), abs=0.5)  # in full-frame pixels

import numpy as np
import pytest

from payload.config import SearchRegionConfig, SwitcherConfig
from payload.detect.ego_motion import CameraMotion
from payload.detect.region import SearchRegion
from payload.detect.switcher import GLOBAL, LOCAL, Switcher

I3 = CameraMotion(np.eye(3))


def test_region_grows_by_k_per_miss_and_resets_on_hit():
    region = SearchRegion(SearchRegionConfig())
    region.start((500.0, 400.0), (20, 10), 0.9)
    sides = []
    for _ in range(5):
        region.predict(I3, 1 / 30)
        box = region.region_xyxy((1920, 1080))
        sides.append(int(box[2] - box[0]))
        region.miss()
    assert sides == [300, 304, 308, 312, 316]
    region.predict(I3, 1 / 30)
    region.hit((505.0, 400.0), (20, 10), 0.9)
    assert region.misses == 0
    box = region.region_xyxy((1920, 1080))
    assert box[2] - box[0] == 300


def test_region_is_clipped_to_the_image_and_keeps_its_size():
    region = SearchRegion(SearchRegionConfig())
    region.start((10.0, 1075.0), (8, 8), 0.9)
    x1, y1, x2, y2 = region.region_xyxy((1920, 1080))
    assert (x1, y2) == (0, 1080) and x2 - x1 == 300 and y2 - y1 == 300
    region.start((50.0, 50.0), (8, 8), 0.9)
    assert tuple(region.region_xyxy((200, 120))) == (0, 0, 200, 120)


def test_homography_carries_the_centre():
    region = SearchRegion(SearchRegionConfig())
    region.start((100.0, 100.0), (10, 10), 0.9)
    shift = CameraMotion(np.array([[1.0, 0, 30], [0, 1.0, -20], [0, 0, 1]]))
    assert region.predict(shift, 1 / 30) == pytest.approx((130.0, 80.0))


def test_kalman_learns_the_targets_own_velocity_under_camera_motion():
    region = SearchRegion(SearchRegionConfig())
    pan = CameraMotion(np.array([[1.0, 0, -12], [0, 1.0, 3], [0, 0, 1]]))  # camera pans: ground moves (-12, +3)/frame
    pos = np.array([400.0, 300.0])
    region.start(tuple(pos), (10, 10), 0.9)
    for _ in range(20):
        pos = pos + np.array([-12.0, 3.0]) + np.array([5.0, 2.0])  # ground motion + own motion
        region.predict(pan, 1 / 30)
        region.hit(tuple(pos), (10, 10), 0.9)
    vx, vy = region.velocity_px_s
    assert vx == pytest.approx(150.0, rel=0.1) and vy == pytest.approx(60.0, rel=0.1)
    predicted = region.predict(pan, 1 / 30)
    assert np.hypot(*(np.array(predicted) - (pos + [-7.0, 5.0]))) < 1.5
    # On a miss the filter is not updated: the prediction keeps going at the learnt velocity.
    region.miss()
    before = region.velocity_px_s
    region.predict(pan, 1 / 30)
    assert region.velocity_px_s == pytest.approx(before, rel=0.05)


def test_fixed_region_stays_at_last_box():
    region = SearchRegion(SearchRegionConfig(adaptive=False))
    region.start((400.0, 300.0), (10, 10), 0.9)
    shift = CameraMotion(np.array([[1.0, 0, 50], [0, 1.0, 0], [0, 0, 1]]))
    assert region.predict(shift, 1 / 30) == (400.0, 300.0)
    region.miss()
    box = region.region_xyxy((1920, 1080))
    assert box[2] - box[0] == 300  # no growth without the adaptive region


def test_switcher_returns_to_global_after_exactly_n_misses():
    n = 30
    sw = Switcher(SwitcherConfig(max_local_misses=n))
    assert sw.mode == GLOBAL
    assert sw.after(hit=False) == GLOBAL  # global miss: keep searching globally
    assert sw.after(hit=True) == LOCAL
    for i in range(n - 1):
        assert sw.after(hit=False) == LOCAL, i
    assert sw.after(hit=False) == GLOBAL
    assert sw.local_misses == 0


def test_switcher_hit_resets_miss_count_and_no_local_means_global():
    sw = Switcher(SwitcherConfig(max_local_misses=3))
    sw.after(True)
    sw.after(False)
    sw.after(False)
    assert sw.after(True) == LOCAL and sw.local_misses == 0
    assert Switcher(SwitcherConfig(), local_available=False).after(True) == GLOBAL


def test_reported_size_is_smoothed_over_hits_and_restarts_with_a_new_target():
    region = SearchRegion(SearchRegionConfig(size_smoothing=0.25))
    region.start((500.0, 400.0), (20, 10), 0.9)
    region.predict(I3, 1 / 30)
    region.hit((501.0, 400.0), (40, 30), 0.9)
    assert region.size_wh == pytest.approx((25.0, 15.0))  # 0.25 * new + 0.75 * tracked
    region.predict(I3, 1 / 30)
    region.hit((502.0, 400.0), (25, 15), 0.9)
    assert region.size_wh == pytest.approx((25.0, 15.0))
    assert region.predicted_box() == pytest.approx([489.5, 392.5, 514.5, 407.5])
    region.start((100.0, 100.0), (8, 6), 0.9)  # a new target: its own size, nothing carried over
    assert region.size_wh == (8.0, 6.0)


def test_size_smoothing_one_reports_raw_boxes():
    region = SearchRegion(SearchRegionConfig(size_smoothing=1.0))
    region.start((500.0, 400.0), (20, 10), 0.9)
    region.predict(I3, 1 / 30)
    region.hit((501.0, 400.0), (40, 30), 0.9)
    assert region.size_wh == (40.0, 30.0)


def test_reported_score_is_the_locks_blended_over_hits_and_restarts_with_a_new_target():
    region = SearchRegion(SearchRegionConfig(score_smoothing=0.25))
    region.start((500.0, 400.0), (20, 10), 0.8)
    region.predict(I3, 1 / 30)
    region.hit((501.0, 400.0), (20, 10), 0.4)
    assert region.score == pytest.approx(0.7)  # 0.25 * new + 0.75 * tracked
    region.miss()  # a miss carries the lock's confidence on
    region.predict(I3, 1 / 30)
    region.hit((502.0, 400.0), (20, 10), 0.3)
    assert region.score == pytest.approx(0.6)
    region.start((100.0, 100.0), (8, 6), 0.55)  # a new target: its own score, nothing carried over
    assert region.score == pytest.approx(0.55)
    raw = SearchRegion(SearchRegionConfig(score_smoothing=1.0))
    raw.start((500.0, 400.0), (20, 10), 0.8)
    raw.predict(I3, 1 / 30)
    raw.hit((501.0, 400.0), (20, 10), 0.4)
    assert raw.score == pytest.approx(0.4)

"""GLAD pipeline behaviour on tiny real ONNX models."""

import cv2
import numpy as np
import pytest

from payload.config import Config

# --- which modules' hits the classifier must confirm (detector.classifier.modules) ---------------

def _spot_glad(tmp_path, **overrides):
    """GLAD on tiny real ONNX models: a bright-spot detector as GAD and LAD, and a classifier whose
    drone probability is the patch's mean brightness. Global motion off: one frame, appearance only."""
    from onnx_factories import bright_spot_detector, brightness_classifier

    from payload.config import config_with
    from payload.detect.factory import build_detectors
    from payload.detect.pipeline import Glad

    cfg = config_with(Config(), **{
        "detector.global.appearance.model": bright_spot_detector(tmp_path / "spot.onnx"),
        "detector.local.appearance.model": str(tmp_path / "spot.onnx"),
        "detector.classifier.model": brightness_classifier(tmp_path / "bright.onnx"),
        "detector.global.motion.enabled": False,
        "detector.classifier.confirm_hits": 0,
        "detector.verifier.enabled": False,  # judged over frames: tests/test_verify.py
        **overrides,
    })
    return Glad(cfg.detector, build_detectors(cfg.detector))


def _spot_frame(index=0, side=4):
    from payload.types import Frame

    image = np.zeros((384, 640, 3), np.uint8)
    image[200:200 + side, 320:320 + side] = 255  # white on 4-aligned cells: detector score 1.0
    return Frame(image, index, index * 33_000_000, 0)


def test_a_target_predicted_out_of_the_picture_ends_there(tmp_path):
    # a spot runs out at the right edge, 16 px a frame: coasting on, the search region's prediction
    # ran along the border and up to y = -328 and was reported as the target for the switcher's ten
    # misses; a bearing from a box wholly outside the image is no bearing
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0})
    for i in range(14):
        x = 544 + 16 * i
        r = glad.process(_tiny_spot_frame(i, size_wh=(640, 384), xy=(x, 200), side=4 if x + 4 <= 640 else 0))
        if x + 4 <= 640:
            assert r.target is not None and r.target.measured
        else:  # gone: the prediction (x 640..644) is wholly outside: no target, back to the global stage
            assert r.target is None and not glad.tracks
        assert r.target is None or (r.target.xyxy[0] < 640 and r.target.xyxy[2] > 0
                                    and r.target.xyxy[1] < 384 and r.target.xyxy[3] > 0)


def test_appearance_hits_bypass_the_classifier_in_the_papers_setting(tmp_path):
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": ["GMD", "LMD"], "detector.classifier.lock_hits": 0})
    result = glad.process(_spot_frame())
    assert list(result.detections.module) == ["GAD"]
    assert result.detections.score[0] == pytest.approx(1.0)
    assert result.mode == "global"


def test_classifier_vetoes_a_global_appearance_hit_when_it_checks_gad(tmp_path):
    # the patch around the spot is mostly black: drone probability ~0.1 < 0.5
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": ["GAD", "GMD", "LMD"]})
    result = glad.process(_spot_frame())
    assert len(result.candidates) == 1 and len(result.detections) == 0
    assert result.target is None and not glad.tracks


def test_confirmed_appearance_hit_keeps_the_detector_confidence(tmp_path):
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": ["GAD"], "detector.classifier.threshold": 0.05})
    result = glad.process(_spot_frame())
    assert list(result.detections.module) == ["GAD"]
    assert result.detections.score[0] == pytest.approx(1.0)  # not replaced by the ~0.1 probability
    assert "classifier" in result.timings_ms


@pytest.mark.parametrize("side, lock_stands", [(4, False), (16, True)])
def test_lock_is_dropped_when_the_classifier_does_not_believe_in_it(tmp_path, side, lock_stands):
    # nothing gated, lock judged on 3 hits: a 4 px spot in black (drone probability 0.11) is followed
    # for two frames and then dropped; a 16 px white square is kept (the chosen hit is its corner cell,
    # whose 12 px patch is 44% white: probability 0.44)
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 3,
                                   "detector.classifier.lock_threshold": 0.3, "detector.local.motion.enabled": False})
    results = [glad.process(_spot_frame(i, side)) for i in range(5)]
    assert [r.mode for r in results[:3]] == ["global", "local", "local"]
    assert all(len(r.detections) == 1 for r in results[:2])
    if lock_stands:
        assert all(len(r.detections) == 1 for r in results) and results[-1].mode == "local"
    else:
        assert len(results[2].detections) == 0 and results[2].target is None
        assert results[3].mode == "global"  # searched globally again


@pytest.mark.parametrize("side, reported", [(4, False), (16, True)])
def test_a_lock_is_reported_once_the_classifier_confirms_it(tmp_path, side, reported):
    # confirmed when the first 2 hits average 0.3: the 4 px spot (drone probability 0.11) is followed
    # but never reported; the 16 px square (0.44) from its second hit on
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0,
                                   "detector.classifier.confirm_hits": 2, "detector.classifier.confirm_threshold": 0.3,
                                   "detector.local.motion.enabled": False})
    results = [glad.process(_spot_frame(i, side)) for i in range(4)]
    assert [r.mode for r in results] == ["global", "local", "local", "local"]  # followed all along
    assert len(results[0].detections) == 0 and results[0].target is None  # one hit: not judged yet
    assert len(results[0].candidates) >= 1  # the hit is kept among the candidates
    assert all((len(r.detections) == 1 and r.target is not None) == reported for r in results[1:])
    glad.process(_spot_frame(4, side=0))  # nothing to see: the lock is missed, not yet given up
    assert glad.tracks[0].region.active


def test_without_a_local_stage_global_hits_are_reported_at_once(tmp_path):
    # global only (the ablation's GAD row): every hit starts a new lock, so there is nothing to confirm over
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.confirm_hits": 2,
                                   "detector.classifier.confirm_threshold": 0.3,
                                   "detector.local.appearance.enabled": False, "detector.local.motion.enabled": False})
    results = [glad.process(_spot_frame(i, side=16)) for i in range(2)]
    assert [r.mode for r in results] == ["global", "global"]
    assert all(len(r.detections) == 1 and r.target is not None for r in results)


def test_lock_confirmation_waits_for_two_convincing_hits_in_a_row():
    from payload.detect.classifier import LockCheck

    lock = LockCheck(hits=0, threshold=0.5, confirm_hits=2, confirm_threshold=0.8)
    assert lock.active and not lock.confirmed
    assert lock.add(0.9) and not lock.confirmed  # one hit of two
    lock.add(0.6)
    assert not lock.confirmed  # mean 0.75
    lock.add(0.2)
    assert not lock.confirmed  # 0.6, 0.2
    lock.add(1.0)
    lock.add(0.7)
    assert lock.confirmed  # 1.0, 0.7: mean 0.85
    lock.add(0.0)
    assert lock.confirmed  # for the rest of the lock; the hold check judges it from here
    lock.reset()
    assert not lock.confirmed  # a new lock
    lock.update_config(0, 0.5, 0, 0.8)
    lock.reset()
    assert lock.confirmed and not lock.active  # off: every lock reported at once


def test_lock_check_judges_the_mean_of_the_last_hits():
    from payload.detect.classifier import LockCheck

    lock = LockCheck(hits=3, threshold=0.5)
    assert [lock.add(p) for p in (0.1, 0.1)] == [True, True]  # not judged before 3 hits
    assert lock.add(0.9) is False  # mean 0.37
    lock.reset()
    assert [lock.add(p) for p in (0.9, 0.2, 0.5, 0.1, 0.1)] == [True, True, True, False, False]
    lock.update_config(0, 0.5)
    assert lock.add(0.0) is True  # off


def test_an_unconfirmed_lock_the_classifier_rejects_is_dropped_early():
    from payload.detect.classifier import LockCheck

    # the shipped settings: hold judged on 10 hits at 0.15, confirmed by 2 hits averaging 0.8
    lock = LockCheck(hits=10, threshold=0.15, confirm_hits=2, confirm_threshold=0.8)
    # the global hit's crop convinced the classifier; the local hits on the same object do not
    assert [lock.add(p) for p in (0.99, 0.0, 0.1, 0.0, 0.0)] == [True, True, True, True, False]
    lock.reset()
    assert [lock.add(p) for p in (0.0, 0.0, 0.3, 0.3)] == [True, True, True, True]  # mean 0.15: kept
    lock.reset()
    # a confirmed lock keeps the whole window: a drone the classifier doubts while it turns
    assert [lock.add(p) for p in (0.9, 0.9)] == [True, True] and lock.confirmed
    assert all(lock.add(0.0) for _ in range(8))  # 10 hits, mean 0.18; unconfirmed it ended at the 4th 0.0
    assert lock.add(0.0) is False  # the last 10: 0.09


@pytest.mark.parametrize("smoothing, expected_wh", [(1.0, (4.0, 4.0)), (0.5, (7.0, 5.0))])
def test_local_box_reports_the_tracked_size(tmp_path, smoothing, expected_wh):
    # the spot detector's boxes are 4x4 px; the target's tracked size is set to 10x6 px after the
    # global hit (as earlier hits would have left it): the reported local box blends the two
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0,
                                   "detector.local.motion.enabled": False,
                                   "detector.search_region.size_smoothing": smoothing})
    assert glad.process(_spot_frame(0)).mode == "global"
    glad.tracks[0].region.size_wh = (10.0, 6.0)
    result = glad.process(_spot_frame(1))
    assert result.mode == "local" and result.candidates.xywh[0, 2:].tolist() == [4.0, 4.0]
    assert result.detections.xywh[0, 2:].tolist() == pytest.approx(expected_wh)
    np.testing.assert_allclose(result.detections.centers[0], result.candidates.centers[0])
    np.testing.assert_allclose(result.target.xyxy, result.detections.xyxy[0])
    assert glad.tracks[0].region.size_wh == pytest.approx(expected_wh)


@pytest.mark.parametrize("smoothing", [1.0, 0.5])
def test_local_box_reports_the_locks_score(tmp_path, smoothing):
    # reported local boxes carry the lock's confidence: the newest score blended into the tracked one
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0,
                                   "detector.local.motion.enabled": False,
                                   "detector.search_region.score_smoothing": smoothing})
    assert glad.process(_spot_frame(0)).mode == "global"
    glad.tracks[0].region.score = 0.2
    result = glad.process(_spot_frame(1))
    raw = float(result.candidates.score[0])
    assert result.mode == "local" and raw > 0.5
    expected = smoothing * raw + (1 - smoothing) * 0.2
    assert float(result.detections.score[0]) == pytest.approx(expected)
    assert result.target.score == pytest.approx(expected) and glad.tracks[0].region.score == pytest.approx(expected)


def _spots_frame(index, spots):
    """A black frame with 4x4 spots: (x, y, grey level) each, on 4-aligned cells."""
    from payload.types import Frame

    image = np.zeros((384, 640, 3), np.uint8)
    for x, y, level in spots:
        image[y:y + 4, x:x + 4] = level
    return Frame(image, index, index * 33_000_000, 0)


@pytest.mark.parametrize("second_frame, expected_x", [
    ([(320, 200, 128), (420, 200, 255)], 422),  # a weak hit near the lock, a strong one 100 px away: retarget
    ([(320, 200, 255), (420, 200, 255)], 322),  # as strong near the lock: it is kept
    ([(420, 200, 100)], None),  # only a weak hit far away (score 0.39 < T0): no target this frame
])
def test_lock_moves_to_a_confident_hit_beyond_the_jump_gate(tmp_path, second_frame, expected_x):
    # one target at a time (with room for more the far hit starts a target of its own: test_targets.py)
    glad = _spot_glad(tmp_path, **{"detector.targets.max": 1, "detector.classifier.modules": [], "detector.classifier.lock_hits": 0,
                                   "detector.classifier.threshold": 0.05, "detector.local.motion.enabled": False})
    assert glad.process(_spots_frame(0, [(320, 200, 255)])).mode == "global"
    result = glad.process(_spots_frame(1, second_frame))
    assert result.mode == "local"
    if expected_x is None:
        assert len(result.detections) == 0 and not result.target.measured
    else:
        assert result.detections.centers[0].tolist() == [expected_x, 202]
        assert glad.tracks[0].region.center == pytest.approx((expected_x, 202))


def test_no_retarget_without_the_jump_gate(tmp_path):
    # max_jump_px 0: every hit in the region is near enough; the most confident one is taken anyway
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0,
                                   "detector.switcher.max_jump_px": 0, "detector.local.motion.enabled": False})
    glad.process(_spots_frame(0, [(320, 200, 255)]))
    result = glad.process(_spots_frame(1, [(320, 200, 128), (420, 200, 255)]))
    assert result.detections.centers[0].tolist() == [422, 202]


# --- the global stage's native-resolution scan (detector.global.scan) --------------------------

def test_scan_tiles_cover_the_frame_in_turn():
    from payload.boxes import tiles_xyxy
    from payload.detect.scan import NativeScan

    every = tiles_xyxy((1920, 1080), (320, 320))
    scan = NativeScan()
    seen = [tuple(t) for _ in range(-(-len(every) // 3)) for t in scan.next_tiles((1920, 1080), (320, 320), 3)]
    assert set(seen) == {tuple(t) for t in every}
    assert [tuple(t) for t in scan.next_tiles((1920, 1080), (320, 320), 3)][0] in seen  # round again
    assert len(NativeScan().next_tiles((1920, 1080), (320, 320), 0)) == 0
    assert len(NativeScan().next_tiles((200, 100), (320, 320), 2)) == 1  # a frame smaller than a tile: one tile


def _tiny_spot_frame(index, size_wh=(1280, 768), xy=(1000, 600), side=4):
    from payload.types import Frame

    image = np.zeros((size_wh[1], size_wh[0], 3), np.uint8)
    image[xy[1]:xy[1] + side, xy[0]:xy[0] + side] = 255  # 4 px: a 2 px grey cell (score 0.25 < T0) once GAD halves the frame
    return Frame(image, index, index * 33_000_000, 0)


@pytest.mark.parametrize("tiles_per_frame, found", [(2, True), (0, False)])
def test_scan_finds_a_drone_the_down_scaled_global_detector_cannot_see(tmp_path, tiles_per_frame, found):
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0,
                                   "detector.global.scan.tiles_per_frame": tiles_per_frame,
                                   "detector.global.scan.points": False})  # the network's look (spots: test_points)
    results = []
    # 1280x768 in 320 px tiles: 15 tiles, all seen in 8 scans at 2 a frame; GAD and the scan take
    # turns (global motion off), so within 16 frames
    for i in range(16):
        results.append(glad.process(_tiny_spot_frame(i)))
        if len(results[-1].detections):
            break
    hit = results[-1].detections
    assert bool(len(hit)) == found
    assert all(len(r.candidates) == 0 for r in results[:-1])  # GAD alone never saw it
    if found:
        assert list(hit.module) == ["GAD"] and results[-1].mode == "global"
        assert hit.xyxy[0].tolist() == [1000, 600, 1004, 604]
        assert "scan" in results[-1].timings_ms
        assert glad.process(_tiny_spot_frame(len(results))).mode == "local"  # followed at native resolution


@pytest.mark.parametrize("size_wh, turns", [((1280, 768), True), ((640, 512), False)])
def test_on_a_strongly_down_scaled_frame_the_global_looks_take_turns(tmp_path, size_wh, turns):
    # issue 19: GAD, GMD, the scan and the spots in one 1080p frame cost ~55 ms; where GAD down-scales
    # the frame strongly they run one a global frame, in turn (with nothing followed, a band of spots
    # after GMD's and the scan's); elsewhere (no scan) GAD and then GMD as before
    glad = _spot_glad(tmp_path, **{"detector.global.motion.enabled": True})
    black = [_tiny_spot_frame(i, size_wh=size_wh, xy=(0, 0), side=0) for i in range(7)]
    timings = [glad.process(f).timings_ms for f in black]
    ran = [[m for m in ("GAD", "GMD", "scan", "points") if m in t] for t in timings]
    if turns:  # (the first frame has no previous one for GMD)
        assert ran == [["GAD"], ["GMD", "points"], ["scan", "points"], ["points"], ["GAD"], ["GMD", "points"],
                       ["scan", "points"]]
    else:
        assert ran == [["GAD"]] + [["GAD", "GMD"]] * 6


@pytest.mark.parametrize("max_input_scale, scanned", [(0.5, False), (1.0, True)])
def test_no_scan_where_the_global_input_keeps_most_of_the_resolution(tmp_path, max_input_scale, scanned):
    # 640x512 into 640x384 is a 0.75 scale (the Halmstad clips: scanning them cost val F); there this
    # 4 px spot falls across GAD's cells (< T0), while a native-resolution tile sees it whole
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0,
                                   "detector.global.scan.max_input_scale": max_input_scale})
    results = [glad.process(_tiny_spot_frame(i, size_wh=(640, 512), xy=(500, 400))) for i in range(4)]
    assert any(len(r.detections) for r in results) == scanned
    assert any("scan" in r.timings_ms for r in results) == scanned


@pytest.mark.parametrize("confirm_threshold, found", [(0.8, False), (0.1, True)])
def test_a_scan_hit_must_convince_the_classifier_as_a_lock_must(tmp_path, confirm_threshold, found):
    # the 4 px spot's 12 px patch is 11 % white: drone probability 0.11, enough for a GAD hit at the
    # classifier's threshold 0.05 but not for a scan hit below confirm_threshold
    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": ["GAD"], "detector.classifier.lock_hits": 0,
                                   "detector.classifier.threshold": 0.05,
                                   "detector.classifier.confirm_threshold": confirm_threshold})
    results = [glad.process(_tiny_spot_frame(i)) for i in range(16)]  # the scan every other global frame: all 15 tiles in 16
    assert any(len(r.detections) for r in results) == found
    assert any(len(r.candidates) for r in results)  # the scan saw it either way


# --- time budget: a frame with more motion candidates than GMD judges says so -------------------

def _movers_frames(count, shift_xy=(6, 3)):
    """Two frames of a still camera over dark textured ground with ``count`` grey textured movers
    (all below the spot detector's 0.5 brightness: GAD finds nothing, so GMD runs)."""
    from payload.types import Frame

    rng = np.random.default_rng(4)
    ground = cv2.GaussianBlur(rng.integers(0, 60, (384, 640), dtype=np.uint8), (0, 0), 2.0)
    prev = np.repeat(ground[:, :, None], 3, axis=2)
    cur = prev.copy()
    for i in range(count):
        x, y = 20 + 100 * (i % 6), 40 + 120 * (i // 6)
        patch = rng.integers(60, 120, (20, 20, 1), dtype=np.uint8).repeat(3, axis=2)
        prev[y:y + 20, x:x + 20] = patch
        cur[y + shift_xy[1]:y + 20 + shift_xy[1], x + shift_xy[0]:x + 20 + shift_xy[0]] = patch
    return Frame(prev, 0, 0, 0), Frame(cur, 1, 33_000_000, 0)


@pytest.mark.parametrize("cap, left_out", [(100, 0), (3, 7)])
def test_gmd_over_its_candidate_cap_judges_the_cap_and_reports_the_frame_degraded(tmp_path, cap, left_out):
    glad = _spot_glad(tmp_path, **{"detector.global.motion.enabled": True,
                                   "detector.global.motion.max_candidates": cap,
                                   "detector.global.motion.merge_distance_px": 0})
    first, second = _movers_frames(10)
    assert glad.process(first).degraded == {}
    result = glad.process(second)
    assert "GMD" in result.timings_ms
    assert result.degraded == ({"GMD": left_out} if left_out else {})


def test_gads_input_is_prepared_ahead_only_for_the_frames_whose_look_is_gads(tmp_path):
    # issue 19: on a frame GAD shrinks strongly the capture thread down-scales it ahead (Glad.prepare),
    # but only when the next global look is GAD's (one global frame in four), not on every frame
    glad = _spot_glad(tmp_path, **{"detector.global.motion.enabled": True})
    prepared, ran = [], []
    for i in range(9):
        frame = _tiny_spot_frame(i, xy=(0, 0), side=0)
        glad.prepare(frame)
        prepared.append("GAD" in frame.prepared)
        ran.append("GAD" in glad.process(frame).timings_ms)
    assert ran == [True, False, False, False, True, False, False, False, True]
    assert prepared == ran
    small = _tiny_spot_frame(9, size_wh=(640, 512), xy=(0, 0), side=0)
    glad.prepare(small)  # not scanned: GAD's input keeps most of the frame, nothing to move
    assert "GAD" not in small.prepared


@pytest.mark.parametrize("bogus", [None, "wrong size", "wrong type"])
def test_a_frame_prepared_ahead_gives_the_frame_step_it_would_have_given(tmp_path, bogus):
    from payload.detect.appearance import letterbox
    from payload.types import Frame

    unchecked = {"detector.classifier.modules": [], "detector.classifier.lock_hits": 0}
    plain, ahead = _spot_glad(tmp_path, **unchecked), _spot_glad(tmp_path, **unchecked)
    for i in range(12):
        # an 8 px spot moving right (4 px on 4-aligned cells in GAD's half-size input): GAD finds it
        # on its turn, then the local stage follows it
        image = _tiny_spot_frame(i, xy=(400 + 8 * i, 304), side=8).image
        a, b = Frame(image, i, i * 33_000_000, 0), Frame(image, i, i * 33_000_000, 0)
        ahead.prepare(b)
        if bogus == "wrong size" and "GAD" in b.prepared:  # the input of another frame size
            b.prepared["GAD"] = letterbox(np.full((100, 100, 3), 255, np.uint8), (640, 384))
        elif bogus == "wrong type" and "GAD" in b.prepared:
            b.prepared["GAD"] = (b.prepared["GAD"][0].astype(np.float64) + 1, b.prepared["GAD"][1])
        ra, rb = plain.process(a), ahead.process(b)
        assert (ra.mode, len(ra.detections)) == (rb.mode, len(rb.detections))
        np.testing.assert_array_equal(ra.detections.xyxy, rb.detections.xyxy)
        np.testing.assert_array_equal(ra.candidates.xyxy, rb.candidates.xyxy)
    assert ra.mode == "local" and len(ra.detections)  # it was found and followed


# --- the camera motion made ahead on the capture thread (Glad.prepare, issue 19) ----------------

@pytest.fixture(scope="module")
def moving_camera_frames():
    """A synthetic 1280x720 clip from a moving camera with a 6-20 px drone (GAD, GMD, the scan and
    the spots take turns there while it is searched for; then the local stage follows it)."""
    from payload.synth.scene import Scene
    from payload.types import Frame

    return [Frame(sf.image, sf.index, int(sf.index * 1e9 / 30), 0)
            for sf in Scene(seed=7, width=1280, height=720, fps=30.0, frames=48, target_px=(6.0, 20.0))]


def _fresh(frame):
    from payload.types import Frame

    return Frame(frame.image, frame.index, frame.t_capture_ns, frame.t_wall_ns)


def _same_result(a, b):
    assert (a.mode, a.state, len(a.detections), len(a.candidates)) == (b.mode, b.state, len(b.detections), len(b.candidates))
    np.testing.assert_array_equal(a.detections.xyxy, b.detections.xyxy)
    np.testing.assert_array_equal(a.candidates.xyxy, b.candidates.xyxy)
    np.testing.assert_array_equal(a.candidates.score, b.candidates.score)
    assert a.lock_p == b.lock_p or (np.isnan(a.lock_p) and np.isnan(b.lock_p))


@pytest.mark.parametrize("dropped", [(), (20, 21, 33)])
def test_the_camera_motion_made_ahead_gives_the_frame_step_it_would_have_given(moving_camera_frames, dropped):
    # The capture thread makes each frame's grey levels and the camera motion from the frame it
    # prepared before (the local stage's while a target is followed, GMD's when its look comes):
    # the frame step takes that motion instead of estimating it, and only when the frame it
    # processed last is the one the motion was made from. A frame the step never got (dropped by a
    # live source after it was prepared) leaves the next frame's motion made from it: not used.
    from payload.detect.pipeline import CAMERA, Glad

    plain, ahead = Glad(Config().detector), Glad(Config().detector)
    made_by_step = []
    estimate = ahead.ego_motion.estimate

    def counted(prev, cur, fine):
        made_by_step.append(fine)
        return estimate(prev, cur, fine)

    local, after_drop, modes, gmd_frames = [], [], set(), 0
    for frame in moving_camera_frames:
        b = _fresh(frame)
        ahead.prepare(b)
        if frame.index in dropped:
            continue
        ahead.ego_motion.estimate = counted
        rb = ahead.process(b)
        ahead.ego_motion.estimate = estimate
        _same_result(plain.process(_fresh(frame)), rb)
        modes.update(m for m in ("GAD", "GMD", "scan", "points") if m in rb.timings_ms)
        gmd_frames += "GMD" in rb.timings_ms
        made = b.prepared.get(CAMERA, (None, None, {}))[2].get(False)  # the local stage's, made ahead
        taken = made is not None and ahead._camera is made
        if frame.index - 1 in dropped:
            after_drop.append((CAMERA in b.prepared, taken))
        elif rb.mode == "local":
            local.append(taken)
    assert modes == {"GAD", "GMD", "scan", "points"} and len(local) > 20  # searched in turns, then followed
    assert all(local)  # every followed frame took the local stage's motion made ahead
    # the step estimated the local stage's motion only after a drop; GMD's there too and where the
    # capture thread did not foresee its look (the frame GMD first joins the turns)
    assert made_by_step.count(False) <= len(dropped)
    assert made_by_step.count(True) <= 1 + len(dropped) < gmd_frames
    assert not any(taken for _, taken in after_drop)  # made from the dropped frame, so not taken
    if dropped:
        assert any(made for made, _ in after_drop)


@pytest.mark.parametrize("bogus", ["not a tuple", "another previous frame", "another level", "settings reloaded",
                                   "grey of another size"])
def test_a_camera_motion_made_ahead_that_does_not_fit_is_not_taken(moving_camera_frames, bogus):
    # each a wrong camera motion that would change what is found, were it taken
    from payload.config import config_with
    from payload.detect.ego_motion import CameraMotion, GreyLevels
    from payload.detect.pipeline import CAMERA, GREY, Glad

    # "another level": the local stage's motion said to be GMD's; with GMD off none is made for GMD,
    # so every one made is the local stage's and none may be taken
    cfg = config_with(Config(), **{"detector.global.motion.enabled": False}) if bogus == "another level" else Config()
    plain, ahead = Glad(cfg.detector), Glad(cfg.detector)
    spoiled = 0
    for frame in moving_camera_frames:
        b = _fresh(frame)
        ahead.prepare(b)
        offered = []  # the motions this frame's step must not take
        if CAMERA in b.prepared:
            prev, cfg, made = b.prepared[CAMERA]
            wrong = {fine: CameraMotion(np.diag([2.0, 2.0, 1.0])) for fine in made}
            offered = list(made.values()) if bogus in ("not a tuple", "grey of another size") else list(wrong.values())
            if bogus == "not a tuple":
                b.prepared[CAMERA] = made
            elif bogus == "another previous frame":
                b.prepared[CAMERA] = (GreyLevels.of(prev.full.copy()), cfg, wrong)
            elif bogus == "another level":
                b.prepared[CAMERA] = (prev, cfg, {not fine: camera for fine, camera in wrong.items()})
            elif bogus == "settings reloaded":
                b.prepared[CAMERA] = (prev, cfg.model_copy(), wrong)
            spoiled += 1
        if bogus == "grey of another size":
            b.prepared[GREY] = GreyLevels.of(np.zeros((100, 100), np.uint8))
        rb = ahead.process(b)
        _same_result(plain.process(_fresh(frame)), rb)
        assert not any(ahead._camera is c for c in offered) or bogus == "grey of another size"
    assert spoiled >= 7


@pytest.mark.parametrize("gmd", [True, False])
def test_gmds_camera_motion_is_made_ahead_only_for_a_gmd_that_may_run(moving_camera_frames, gmd):
    # at 640x360 the global looks take no turns: GMD may run on every searching frame, so its (fine)
    # estimate is made ahead then, unless GMD is switched off
    from payload.config import config_with
    from payload.detect.pipeline import CAMERA, Glad
    from payload.types import Frame

    glad = Glad(config_with(Config(), **{"detector.global.motion.enabled": gmd}).detector)
    made = set()
    for frame in moving_camera_frames[:12]:
        b = Frame(cv2.resize(frame.image, (640, 360), interpolation=cv2.INTER_AREA), frame.index, frame.t_capture_ns, 0)
        glad.prepare(b)
        made.update(b.prepared.get(CAMERA, (None, None, {}))[2])
        glad.process(b)
    assert (True in made) == gmd

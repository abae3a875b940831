"""The isolated-spot detector (payload.detect.points) and its place in the scan and the local stage."""

from unittest import mock

import numpy as np
import pytest

from payload.detect.points import _HOLE_PX, _RING_PX, PointDetector, ring_max
from payload.types import Detections


def _sky(h=240, w=320, seed=0):
    """A smooth sky gradient with sensor noise (sd 2 grey levels)."""
    rng = np.random.default_rng(seed)
    grey = np.linspace(150, 190, h)[:, None] + np.zeros((1, w)) + rng.normal(0, 2, (h, w))
    return np.repeat(np.clip(grey, 0, 255).astype(np.uint8)[..., None], 3, axis=2)


def _centres(dets):
    return [tuple(np.round(c).astype(int)) for c in dets.centers]


def test_a_white_and_a_black_spot_on_the_sky_are_found_with_their_boxes():
    image = _sky()
    image[100:104, 60:64] = 245  # a 4 px white drone
    image[50:54, 200:204] = 40  # a dark one
    found = PointDetector().detect(image, offset_xy=(1000, 500))
    assert sorted(_centres(found)) == [(1062, 602), (1202, 552)]
    boxes = {tuple(np.round(c).astype(int)): b for c, b in zip(found.centers, found.xyxy)}
    assert boxes[(1062, 602)].tolist() == [1059, 599, 1065, 605]  # the spot and a pixel around it
    assert np.all((found.score > 0.5) & (found.score < 1)) and list(found.module) == ["GAD", "GAD"]


def test_a_spot_of_the_skys_grey_level_but_another_colour_is_found():
    """A white drone on a pale sunlit sky: its grey level is the sky's, its blue is not."""
    image = _sky()
    sky = image[100:104, 60:64].astype(np.int16)
    spot = sky.copy()
    spot[..., 0] -= 30  # less blue ...
    spot[..., 2] += 16  # ... more red: the grey level (0.114 B + 0.587 G + 0.299 R) moves by under 2
    image[100:104, 60:64] = np.clip(spot, 0, 255).astype(np.uint8)
    grey = (0.114 * image[..., 0] + 0.587 * image[..., 1] + 0.299 * image[..., 2]).round().astype(np.uint8)
    assert len(PointDetector().detect(grey)) == 0  # in grey it is sky
    assert _centres(PointDetector().detect(image)) == [(62, 102)]
    # a frame of other channels than BGR is read the same way, not refused
    alpha = np.concatenate([image, np.full(image.shape[:2] + (1,), 255, np.uint8)], axis=2)
    assert _centres(PointDetector().detect(alpha)) == [(62, 102)]
    assert _centres(PointDetector().detect(image[..., :1])) == [(62, 102)]  # blue alone: the spot 30 darker


def test_faint_spots_noise_and_large_objects_are_not_spots():
    image = _sky()
    image[100:104, 60:64] += 5  # 5 grey levels: below min_contrast 8
    image[30:90, 150:230] = 60  # a 60x80 px object: a helicopter, a roof, not a spot
    assert len(PointDetector().detect(image)) == 0


def test_a_spot_in_texture_is_not_isolated():
    rng = np.random.default_rng(3)
    image = _sky()
    image[:, :160] = rng.integers(60, 200, (240, 160, 1), dtype=np.uint8)  # textured ground on the left
    image[120:124, 80:84] = 250  # as bright as anywhere, but among neighbours as strong
    image[120:124, 240:244] = 250  # the same on the sky
    assert _centres(PointDetector().detect(image)) == [(242, 122)]


def test_strongest_first_and_at_most_max_points():
    image = _sky()
    for k in range(12):
        image[20 + 15 * k:23 + 15 * k, 40 + 20 * k:43 + 20 * k] = 200 + 4 * k
    found = PointDetector(max_points=5).detect(image)
    assert len(found) == 5 and np.all(np.diff(found.score) <= 0)
    assert min(c[1] for c in _centres(found)) >= 20 + 15 * 6  # the five brightest (last) spots


@pytest.mark.parametrize("dtype", [np.uint8, np.float32])  # the detector's response is uint8
@pytest.mark.parametrize("shape", [(320, 320), (25, 25), (25, 61), (90, 33)])
def test_ring_max_is_the_dilation_by_the_ring(shape, dtype):
    # the four-band shortcut must give exactly what the ring kernel gives, to the image's edges
    import cv2

    ring = np.ones((_RING_PX, _RING_PX), np.uint8)
    lo = (_RING_PX - _HOLE_PX) // 2
    ring[lo:lo + _HOLE_PX, lo:lo + _HOLE_PX] = 0
    rng = np.random.default_rng(sum(shape))
    response = (rng.random(shape) * 60).astype(dtype)
    response[rng.random(shape) < 0.8] = 0  # sparse, as top-hat responses are
    assert np.array_equal(ring_max(response), cv2.dilate(response, ring))
    one = np.zeros(shape, dtype)
    one[shape[0] // 2, shape[1] // 2] = 9.0  # a lone peak: not in its own ring, in its neighbours'
    out = ring_max(one)
    assert out[shape[0] // 2, shape[1] // 2] == 0 and out.max() == 9.0


def test_a_tiny_image_has_no_spots():
    assert len(PointDetector().detect(np.full((10, 10, 3), 128, np.uint8))) == 0


def _grey_spot_frame(index, xy=(1000, 600), size_wh=(1280, 768), colour=False):
    """A dim sky (60-90 grey) with a 4 px spot at 120: too dim for the bright-spot network (it
    answers above mid-grey), plain to the spot detector. ``colour``: the spot the sky's grey level
    but less blue and more red, plain in the blue and red channels only."""
    from payload.types import Frame

    image = _sky(size_wh[1], size_wh[0], seed=index) // 2
    spot = np.s_[xy[1]:xy[1] + 4, xy[0]:xy[0] + 4]
    if colour:
        image[spot + (0,)] -= 30
        image[spot + (2,)] += 16
    else:
        image[spot] = 120
    return Frame(image, index, index * 33_000_000, 0)


@pytest.mark.parametrize("points, colour", [(True, False), (True, True), (False, False)])
def test_the_scan_proposes_spots_and_the_local_stage_keeps_them(tmp_path, points, colour):
    from test_pipeline import _spot_glad

    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0,
                                   "detector.global.scan.tiles_per_frame": 2, "detector.global.scan.points": points,
                                   "detector.local.appearance.confidence": 0.5,  # LAD (T1) does not see it either
                                   "detector.classifier.threshold": 0.0, "detector.classifier.confirm_threshold": 0.0})
    results = [glad.process(_grey_spot_frame(i, colour=colour)) for i in range(20)]  # 15 tiles: 8 scans, GAD's turn between
    hits = [r for r in results if len(r.detections)]
    if not points:
        assert not hits and all(len(r.candidates) == 0 for r in results)  # the network never sees it
        return
    first = hits[0]
    assert first.mode == "global" and list(first.detections.module) == ["GAD"]
    assert first.detections.xyxy[0].tolist() == [999, 599, 1005, 605]
    after = results[results.index(first) + 1:]
    assert after and all(r.mode == "local" and len(r.detections) for r in after)  # followed by the spot cue
    assert all("points" in r.timings_ms for r in after)
    assert all(np.allclose(r.target.xyxy, [999, 599, 1005, 605], atol=3) for r in after)


@pytest.mark.parametrize("size_wh, xy, first", [
    ((1280, 768), (1000, 200), 1), ((1280, 768), (0, 0), 1), ((1280, 768), (1276, 764), 2),  # two bands
    ((1920, 1080), (1000, 200), 1), ((1920, 1080), (1916, 1076), 4),  # three bands, in turn from the top
    ((1920, 1080), (960, 356), 1), ((1920, 1080), (960, 360), 2),  # either side of a cut (centre y 358, 362)
    ((1920, 1080), (960, 716), 2), ((1920, 1080), (960, 720), 4),  # ... and of the next (718, 722)
])
def test_the_spot_look_covers_the_whole_frame_in_its_turns(tmp_path, size_wh, xy, first):
    # the spots are a global look of their own over the whole frame, a band of rows (at most
    # SPOT_BAND_PX pixels: a 1080p frame in three) a turn, and with nothing followed the scan's turn
    # takes the next band after it: a spot anywhere, the frame's corners and the bands' cuts included,
    # is found in its band's first turn
    from test_pipeline import _spot_glad

    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0,
                                   "detector.global.scan.tiles_per_frame": 1,
                                   "detector.local.appearance.confidence": 0.5,  # LAD (T1) does not see it
                                   "detector.classifier.threshold": 0.0, "detector.classifier.confirm_threshold": 0.0})
    results = [glad.process(_grey_spot_frame(i, xy=xy, size_wh=size_wh)) for i in range(first + 1)]
    # GAD | the scan, band 0 | the spots, band 1 | GAD | the scan, band 2 (global motion off)
    assert [len(r.detections) for r in results] == [0] * first + [1]
    assert [[m for m in ("GAD", "scan", "points") if m in r.timings_ms] for r in results] == [
        ["GAD"], ["scan", "points"], ["points"], ["GAD"], ["scan", "points"]][:first + 1]
    hit = results[-1].detections
    assert list(hit.module) == ["GAD"] and results[-1].mode == "global"
    # the spot and a pixel around it (reported on the spot's centroid: within a twentieth of a pixel)
    assert np.allclose(hit.xyxy[0], [xy[0] - 1, xy[1] - 1, xy[0] + 5, xy[1] + 5], atol=0.05)


def test_with_nothing_followed_the_scans_turn_searches_a_band_of_spots_too(tmp_path):
    # GAD's turn (its network on the whole frame, the dearest look) stays alone; the scan's takes a
    # band after its tiles, so that two bands are searched every three frames, not one
    from test_pipeline import _spot_glad

    glad = _spot_glad(tmp_path, **{"detector.global.scan.tiles_per_frame": 1})
    spots = glad._spots = mock.Mock(wraps=glad._spots)  # each band searched counted
    looks = []
    for i in range(6):
        before = spots.call_count
        r = glad.process(_grey_spot_frame(i, xy=(0, 0), size_wh=(1920, 1080)))  # the spot too dim for GAD's
        assert r.target is None                                                # bright-spot network
        looks.append(([m for m in ("GAD", "scan") if m in r.timings_ms], spots.call_count - before))
    assert looks == [(["GAD"], 0), (["scan"], 1), ([], 1)] * 2


def test_a_followed_target_gives_the_spots_their_own_turns_back(tmp_path):
    # beside a followed target the local stage has this frame's time: the spots keep to their turn
    glad, i = _locked_on_the_spot(tmp_path, **{"detector.targets.max": 2, "detector.targets.search_every": 1})
    spots = glad._spots = mock.Mock(wraps=glad._spots)  # each band searched counted
    turns = []
    for j in range(i, i + 9):
        before = spots.call_count
        r = glad.process(_grey_spot_frame(j))
        assert len(r.detections)  # followed and reported, the global stage looking for more every frame
        turns.append(("GAD" in r.timings_ms, "scan" in r.timings_ms, spots.call_count - before))
    assert sorted(set(turns)) == [(False, False, 1), (False, True, 0), (True, False, 0)]


def test_the_bands_find_what_the_whole_frame_gives(tmp_path):
    from test_pipeline import _spot_glad

    glad = _spot_glad(tmp_path)
    glad.points = PointDetector(max_points=10_000)
    rng = np.random.default_rng(5)
    grey = _sky(1080, 1920, seed=5)[..., 0]
    for x, y in zip(rng.integers(0, 1916, 400), rng.integers(0, 1076, 400)):
        grey[y:y + 3, x:x + 3] = rng.integers(0, 256)  # spots of either polarity, some near the cut
    grey[340:380, 100:1900:37] = 250  # a row of spots across a cut
    whole = PointDetector(max_points=10_000).detect(grey)
    bands = [glad._spots(grey) for _ in range(3)]
    assert all(len(band) for band in bands)
    by_box = lambda d: sorted(zip(map(tuple, d.xyxy.tolist()), d.score.tolist()))  # noqa: E731
    assert by_box(Detections.concat(bands)) == by_box(whole)


def test_no_spots_where_the_global_input_keeps_most_of_the_resolution(tmp_path):
    from test_pipeline import _spot_glad

    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0})
    results = [glad.process(_grey_spot_frame(i, xy=(500, 400), size_wh=(640, 512))) for i in range(8)]
    assert not any(len(r.candidates) for r in results)  # 640x512 is not scanned: Halmstad's clips unchanged


def _locked_on_the_spot(tmp_path, **settings):
    """GLAD (the spot cue, no classifier bar; ``settings`` on top) and the first frame index after it
    reported the spot."""
    from test_pipeline import _spot_glad

    glad = _spot_glad(tmp_path, **{"detector.classifier.modules": [], "detector.classifier.lock_hits": 0,
                                   "detector.global.scan.tiles_per_frame": 2, "detector.local.appearance.confidence": 0.5,
                                   "detector.classifier.threshold": 0.0, "detector.classifier.confirm_threshold": 0.0,
                                   **settings})
    i = 0
    while not len(glad.process(_grey_spot_frame(i)).detections):
        i += 1
        assert i < 20  # 15 tiles: 8 scans, GAD's turn between
    return glad, i + 1


def test_the_local_stages_spots_must_convince_the_classifier(tmp_path):
    glad, i = _locked_on_the_spot(tmp_path)
    # the brightness classifier gives this dim patch well under 0.5
    glad.models.classifier.update_config(glad.cfg.classifier.model_copy(update={"threshold": 0.5}))
    after = glad.process(_grey_spot_frame(i))
    assert after.mode == "local" and not len(after.detections) and len(after.candidates) == 1


def test_a_followed_spot_among_noise_nearly_as_strong_is_kept_where_the_search_would_not_propose_it(tmp_path):
    # a 4 px drone on a noisy sky stands only 1.1-1.5x above the largest noise response in its ring
    # (seed 304 of the tiny white drones): the whole-frame look needs 1.5x, the search region 1.2x
    from payload.detect.pipeline import LOCAL_SPOT_ISOLATION

    glad, i = _locked_on_the_spot(tmp_path)
    results = []
    for j in range(i, i + 5):
        frame = _grey_spot_frame(j)
        sky = int(frame.image[590, 1010, 0])
        frame.image[601:603, 1010:1012] = sky + 18  # a noise speck 10 px off, in the spot's ring: isolation 1.3-1.4
        found = PointDetector().detect(frame.image[450:750, 850:1150], offset_xy=(850, 450))
        assert (1002, 602) not in _centres(found)  # not isolated enough for the whole-frame look ...
        near = PointDetector().detect(frame.image[450:750, 850:1150], offset_xy=(850, 450),
                                      min_isolation=LOCAL_SPOT_ISOLATION)
        assert (1002, 602) in _centres(near)  # ... enough where the lock's prediction is
        results.append(glad.process(frame))
    for r in results:
        assert r.mode == "local" and len(r.detections), r.state  # measured, not coasting
        assert np.allclose(r.target.xyxy, [999, 599, 1005, 605], atol=3)


def test_a_hit_elsewhere_in_the_region_does_not_stop_the_spots_near_the_prediction(tmp_path):
    # a followed small drone that LAD does not see, and in its region, farther than the jump gate,
    # something LAD does see (a bird): the spots still look for the drone (seed 307 of the tiny white
    # drones lost every other frame of its lock to a bird 120 px away); LAD (T1) does not see the spot,
    # nor does the global stage take the bird's 0.55 as a new target
    glad, i = _locked_on_the_spot(tmp_path, **{"detector.global.appearance.confidence": 0.6})
    results = []
    for j in range(i, i + 5):
        frame = _grey_spot_frame(j)
        frame.image[560:564, 1080:1084] = 140  # 81 px from the spot (gate 50), inside the 300 px region
        results.append(glad.process(frame))
    for r in results:
        assert r.mode == "local" and "points" in r.timings_ms
        assert "LAD" in set(r.candidates.module[r.candidates.xyxy[:, 0] > 1070])  # LAD saw the bird
        assert np.allclose(r.target.xyxy, [999, 599, 1005, 605], atol=3) and len(r.detections)


def test_a_hit_beside_a_small_target_inside_the_gate_does_not_stop_the_spots_at_the_prediction(tmp_path):
    # a bird 25-50 px beside a followed 3-6 px drone, inside the jump gate but not where the drone
    # should be (seeds 304 and 309 of the tiny white drones): the spots still look for the drone
    glad, i = _locked_on_the_spot(tmp_path, **{"detector.global.appearance.confidence": 0.6})
    frame = _grey_spot_frame(i)
    frame.image[598:606, 1028:1036] = 250  # a bird the network sees, 30 px from the spot (gate 50)
    r = glad.process(frame)
    assert r.mode == "local" and "points" in r.timings_ms
    lad = r.candidates[r.candidates.module == "LAD"]
    assert any(b[0] >= 1025 for b in lad.xyxy)  # LAD saw the bird ...
    assert any(np.allclose(b, [999, 599, 1005, 605], atol=1) for b in lad.xyxy)  # ... and the spots the drone


def test_a_hit_is_where_a_target_should_be_within_the_gate_or_for_a_small_one_within_a_spot(tmp_path):
    from test_pipeline import _spot_glad

    glad = _spot_glad(tmp_path)
    track = glad._new_track()
    for size, distances, expected in [(4.0, [30.0], False), (4.0, [30.0, 9.0], True), (4.0, [], False),
                                      (24.0, [30.0], True), (24.0, [], False)]:
        track.region.size_wh = (size, size)
        assert glad._where_expected(track, np.float32(distances)) is expected


@pytest.mark.parametrize("value, expected", [
    ("sometimes", "detector.global.scan.points: 'sometimes' is not true or false"),
    ("2", "detector.global.scan.points: 2 is not true or false"),
    ("[true]", "detector.global.scan.points: [true] is not true or false"),
])
def test_a_bad_points_setting_is_one_line_naming_it(tmp_path, value, expected):
    from test_config import problems_loading

    path, problems = problems_loading(tmp_path, "detector:\n  global:\n    scan:\n      points: %s\n" % value)
    assert len(problems) == 1
    line = problems[0]
    assert "\n" not in line and line.startswith(str(path) + ":")
    assert line.endswith(expected), line


@pytest.mark.parametrize("background, ring_peak, spot, isolated", [
    (100, 10, 21, True), (100, 10, 20, False),  # 21 / (10 + 4) = 1.5 exactly: at the bar
    (100, 11, 23, True), (100, 11, 22, False),  # the bar 22.5: rounded up, not to the nearest
    (0, 166, 255, True), (0, 167, 255, False),  # a bar beyond 255 (256.5) is not met by 255
])
def test_the_8_bit_isolation_bar_is_the_rule_exactly(background, ring_peak, spot, isolated):
    # the detector compares in 8 bit (a whole 1080p frame in ~10 ms): a spot is isolated when its
    # response is at least 1.5 x (the ring's largest + 4), to the grey level, up to the top of the range
    image = np.full((60, 60), background, np.uint8)
    image[30, 30] = background + spot
    image[38, 38] = background + ring_peak  # 8 px off on the diagonal: in the spot's ring, and the spot in its
    found = PointDetector().detect(image)
    assert _centres(found) == ([(30, 30)] if isolated else [])
    if isolated:
        assert found.score[0] == pytest.approx(1.0 - (ring_peak + 4.0) / spot)


@pytest.mark.parametrize("spot, isolated", [(17, True), (16, False)])  # 1.2 x (10 + 4) = 16.8
def test_a_call_may_take_its_own_isolation_bar(spot, isolated):
    image = np.full((60, 60), 100, np.uint8)
    image[30, 30] = 100 + spot
    image[38, 38] = 110
    detector = PointDetector()
    assert _centres(detector.detect(image, min_isolation=1.2)) == ([(30, 30)] if isolated else [])
    assert len(detector.detect(image)) == 0 and detector.min_isolation == 1.5  # its own bar as before


def test_a_small_box_off_its_spot_is_moved_onto_the_spot():
    spot_centre = PointDetector().centre
    grey = _sky()[..., 0]
    grey[100:103, 60:64] = 250  # a 4x3 px white drone: its centre (62, 101.5)
    for box in ([58, 98, 63, 102], [61, 100, 66, 104], [60, 99, 64, 103]):  # 1-3 px off, either side
        assert spot_centre(grey, np.float32(box)) == pytest.approx((62.0, 101.5), abs=0.05)
    dark = _sky()[..., 0]
    dark[50:54, 200:204] = 40  # either polarity
    assert spot_centre(dark, np.float32([199, 49, 203, 53])) == pytest.approx((202.0, 52.0), abs=0.05)


def test_a_spot_reaching_beyond_the_box_is_centred_whole_not_taken_for_its_own_surroundings():
    """Seed 301 of configs/tiny-light-sky.yaml, frame 40: a 5 x 2 px drone, the network's box 3 px
    below it; the drone's upper row lay outside the box (and its 2 px margin). Counted as the
    surroundings, it outshone the spot's peak and the hit stayed off the drone."""
    spot_centre = PointDetector().centre
    grey = _sky()[..., 0]
    grey[100:102, 60:65] = 215  # the drone: rows 100-101, columns 60-64, centre (62.5, 101.0)
    grey[100, 60:65] = 205  # its upper row a little fainter, as a blurred edge
    assert spot_centre(grey, np.float32([60, 103, 64, 105])) == pytest.approx((62.5, 101.0), abs=0.3)
    # a spot larger than a spot's kernel reaching into the box stays the box's surroundings
    grey[100:102, 60:65] = grey[104, 60]
    grey[90:102, 50:75] = 215
    assert spot_centre(grey, np.float32([60, 103, 64, 105])) is None


@pytest.mark.parametrize("box", [
    [0, 0, 30, 30],  # larger than a spot: a network's box stays as it is
    [np.nan, 0, 4, 4], [0, 0, np.inf, 4],  # broken numbers
    [400, 400, 404, 404], [-20, -20, -16, -16],  # wholly outside the frame
    [4, 4, 4, 8],  # empty
    [150, 150, 155, 155],  # flat sky, no spot in it
])
def test_no_spot_centre_where_there_is_no_spot_to_move_to(box):
    spot_centre = PointDetector().centre
    grey = _sky()[..., 0]
    grey[100:103, 60:64] = 250
    assert spot_centre(grey, np.float32(box)) is None


def test_no_spot_centre_in_texture():
    spot_centre = PointDetector().centre
    rng = np.random.default_rng(3)
    grey = _sky()[..., 0]
    grey[:, :160] = rng.integers(60, 200, (240, 160), dtype=np.uint8)  # ground: neighbours as strong
    grey[120:124, 80:84] = 250
    assert spot_centre(grey, np.float32([79, 119, 85, 125])) is None
    grey[120:124, 240:244] = 250  # the same on the sky
    assert spot_centre(grey, np.float32([239, 119, 245, 125])) == pytest.approx((242.0, 122.0), abs=0.05)


def test_spot_centre_at_the_frames_edge():
    spot_centre = PointDetector().centre
    grey = _sky()[..., 0]
    grey[0:3, 316:320] = 250  # in the corner
    centre = spot_centre(grey, np.float32([315, -1, 321, 4]))
    assert centre == pytest.approx((318.0, 1.5), abs=0.05)


def test_glad_measures_a_small_local_hit_on_its_spot(tmp_path):
    """The local stage's hit, a network box 2 px off a 4 px drone, is measured on the drone's
    centre (what the region follows, the lock verifier measures and the report says); a hit with no
    isolated spot in it, or larger than a spot, stays as it is."""
    import cv2
    from test_pipeline import _spot_glad

    from payload.detect.ego_motion import GreyLevels
    from payload.types import LAD, Detections

    glad = _spot_glad(tmp_path)
    image = _grey_spot_frame(0).image
    grey = GreyLevels.of(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    off = Detections(np.float32([[1002, 598, 1006, 602]]), np.float32([0.7]), np.array([LAD], "<U3"))
    on = glad._on_spot(off, grey, image)
    assert on.centers[0].tolist() == pytest.approx([1002.0, 602.0], abs=0.05)  # the spot at 1000-1003, 600-603
    assert on.xywh[0, 2:].tolist() == [4.0, 4.0] and on.score.tolist() == off.score.tolist()
    assert on.module.tolist() == [LAD]
    sky = Detections(np.float32([[400, 300, 404, 304]]), np.float32([0.7]), np.array([LAD], "<U3"))
    assert glad._on_spot(sky, grey, image) is sky  # nothing stands out there
    large = Detections(np.float32([[990, 590, 1014, 614]]), np.float32([0.7]), np.array([LAD], "<U3"))
    assert glad._on_spot(large, grey, image) is large  # a 24 px box is no spot's


def test_a_small_local_hit_is_measured_on_a_spot_only_its_colours_show(tmp_path):
    """A white drone on a pale sky can be the sky's grey yet stand out in its blue (seed 304 of
    configs/tiny-light-sky.yaml: the box 3 px off the drone in 7 reported frames): where the grey
    level has no spot, the colour channels are looked at; where it has one, they are not."""
    import cv2
    from test_pipeline import _spot_glad

    from payload.detect.ego_motion import GreyLevels
    from payload.types import LAD, Detections

    glad = _spot_glad(tmp_path)
    image = _grey_spot_frame(0, colour=True).image  # the spot at 1000-1003, 600-603: blue and red only
    grey = GreyLevels.of(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    off = Detections(np.float32([[1002, 598, 1006, 602]]), np.float32([0.7]), np.array([LAD], "<U3"))
    assert glad.points.centre(grey.full, off.xyxy[0]) is None  # the grey level does not show it
    on = glad._on_spot(off, grey, image)
    assert on.centers[0].tolist() == pytest.approx([1002.0, 602.0], abs=0.05)


def test_a_spot_the_global_stage_finds_is_scored_by_the_classifier(tmp_path):
    """A spot has no confidence of its own (its score maps its isolation): as a motion hit, the one
    the global stage finds takes the classifier's drone probability, what decides whether it may
    start a target beside or in place of another (T0; seed 309 of the tiny white drones: the drone's
    spot at p 0.98-1.00, its isolation score 0.33-0.49 under T0 0.5)."""
    from test_pipeline import _spot_glad

    glad = _spot_glad(tmp_path, **{"detector.classifier.lock_hits": 0, "detector.global.scan.tiles_per_frame": 1,
                                   "detector.local.appearance.confidence": 0.5,  # LAD (T1) does not see it
                                   "detector.classifier.threshold": 0.0, "detector.classifier.confirm_threshold": 0.0})
    frames = [_grey_spot_frame(i, xy=(1000, 200)) for i in range(2)]
    results = [glad.process(f) for f in frames]  # GAD, then the scan and the spots' first band
    hit = results[-1].detections
    assert list(hit.module) == ["GAD"] and "points" in results[-1].timings_ms
    p = float(glad.models.classifier.probabilities(frames[-1].image, hit)[0])
    isolation_score = float(PointDetector().detect(frames[-1].image).score[0])
    assert hit.score[0] == pytest.approx(p, abs=1e-6) and abs(p - isolation_score) > 0.05

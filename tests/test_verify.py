"""The lock verifier (payload/detect/verify.py): per-frame rows, the reporting rule, the model contract,
and GLAD reporting a lock only once verified."""

import numpy as np
import pytest
from onnx_factories import bright_spot_detector, brightness_classifier, last_row_verifier

from payload.config import Config, config_with
from payload.detect.factory import build_detectors, builtin_model_path, check_verifier
from payload.detect.onnx_model import OnnxModel
from payload.detect.verify import FEATURES, N_FEATURES, LockFeatures, LockVerifier
from payload.errors import ConfigError, ModelError
from payload.types import Frame

P = FEATURES.index("drone_p")


def _row(drone_p):
    r = np.zeros(N_FEATURES, np.float32)
    r[0], r[P] = 1.0, drone_p
    return r


def _verifier(tmp_path, **kw):
    model = OnnxModel(last_row_verifier(tmp_path / "v.onnx", P), expected_inputs={"tracks": (None, None, N_FEATURES)})
    return LockVerifier(model, **kw)


# --- rows -------------------------------------------------------------------------------------------

def test_row_measures_motion_against_the_compensated_background():
    grey = np.full((200, 300), 100, np.uint8)
    grey[100:110, 150:160] = 200  # a bright 10x10 target on a flat background
    f = LockFeatures()
    first = f.row(grey, np.array([150, 100, 160, 110.0]), np.array([150, 100, 160, 110.0]), 0.9, "GAD", 0.8, None)
    assert first[FEATURES.index("present")] == 1 and first[FEATURES.index("gad")] == 1
    assert first[FEATURES.index("motion_valid")] == 0  # no previous frame: motion unknown, not zero motion
    assert first[FEATURES.index("contrast")] > 5 and first[FEATURES.index("log2_w")] == pytest.approx(np.log2(10))
    # the camera pans 20 px right (the background moves +20 in x) and the target moves 5 px down
    # against it: only those 5 px are its own motion
    pan = np.array([[1, 0, 20], [0, 1, 0], [0, 0, 1.0]])
    box = np.array([170, 105, 180, 115.0])
    second = f.row(grey, box, box, 0.8, "LAD", 0.7, pan)
    assert second[FEATURES.index("motion_valid")] == 1 and second[FEATURES.index("lad")] == 1
    assert second[FEATURES.index("rel_dx")] == pytest.approx(0.0, abs=1e-6)
    assert second[FEATURES.index("rel_dy")] == pytest.approx(0.5)  # 5 px of a 10 px box
    assert second[FEATURES.index("log_rel_px")] == pytest.approx(np.log1p(5.0))
    assert second[FEATURES.index("log_ego_px")] == pytest.approx(np.log1p(20.0))


def test_coasting_row_keeps_the_last_size_and_verdict_and_marks_itself():
    grey = np.zeros((100, 100), np.uint8)
    f = LockFeatures()
    f.row(grey, np.array([10, 10, 18, 14.0]), np.array([10, 10, 18, 14.0]), 0.9, "LAD", 0.6, None)
    coast = f.row(grey, np.array([12, 10, 20, 14.0]), None, 0.0, "", None, np.eye(3))
    assert coast[FEATURES.index("measured")] == 0 and coast[FEATURES.index("lad")] == 0
    assert coast[FEATURES.index("log2_w")] == pytest.approx(3.0) and coast[P] == pytest.approx(0.6)


@pytest.mark.parametrize("look", [False, True])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_inputs_never_reach_a_row(bad, look):
    grey = np.zeros((100, 100), np.uint8)
    f = LockFeatures(look=look)
    f.row(grey, np.array([10, 10, 18, 14.0]), np.array([10, 10, 18, 14.0]), bad, "LAD", bad, None)
    row = f.row(grey, np.array([10, 10, 18, 14.0]), np.array([10, 10, 18, 14.0]), 0.5, "LAD", 0.5,
                np.full((3, 3), bad))
    assert np.all(np.isfinite(row)) and row[FEATURES.index("motion_valid")] == 0


@pytest.mark.parametrize("look", [False, True])
def test_box_at_and_beyond_the_frame_edge_gives_finite_rows(look):
    grey = np.full((50, 60), 7, np.uint8)
    grey[::3] = 200  # texture, so that the look's statistics are not all zero
    f = LockFeatures(look=look)
    for box in ([-20, -20, 5, 5], [55, 45, 90, 90], [59, 49, 59, 49], [100, 100, 120, 120], [-500, -500, 900, 900]):
        assert np.all(np.isfinite(f.row(grey, np.array(box, float), np.array(box, float), 0.5, "LAD", 0.5, np.eye(3))))


# --- the rule -----------------------------------------------------------------------------------

def test_lock_is_judged_after_min_frames_and_released_below_the_release_threshold(tmp_path):
    v = _verifier(tmp_path, min_frames=3, threshold=0.7, release_threshold=0.4)
    assert v.window == 16  # the model's T
    assert not v.add(_row(0.9)) and not v.add(_row(0.9))  # two frames: followed, not judged
    assert np.isnan(v.probability)
    assert v.add(_row(0.9)) and v.probability == pytest.approx(0.9)
    assert v.add(_row(0.5))  # below threshold but above release: stays verified
    assert not v.add(_row(0.3))  # released
    assert not v.add(_row(0.6))  # must reach the threshold again, not the release level
    assert v.add(_row(0.75))
    v.reset()  # a new lock starts unverified
    assert not v.verified and len(v.rows) == 0


def test_a_lock_is_refused_only_after_refused_after_verdicts_in_a_row_under_the_bar(tmp_path):
    from payload.detect.verify import REFUSED_AFTER, REFUSED_BELOW

    v = _verifier(tmp_path, min_frames=2, threshold=0.9, release_threshold=0.7)
    low, held = REFUSED_BELOW - 0.2, REFUSED_BELOW + 0.1
    v.add(_row(low))  # not judged yet (min_frames 2): no verdict counts
    for _ in range(REFUSED_AFTER - 2):
        v.add(_row(low))
    v.add(_row(held))  # one verdict at the bar or more: the count starts again
    for _ in range(REFUSED_AFTER - 1):
        v.add(_row(low))
    assert not v.refused  # one verdict short
    v.add(_row(low))
    assert v.refused and not v.verified
    v.add(_row(held))  # one verdict at the bar or more: judged afresh
    assert not v.refused
    for _ in range(3 * v.window):
        v.add(_row(held))  # held back (under the 0.9 to verify), never refused
    assert not v.refused and not v.verified
    v.reset()
    assert not v.refused and v.below == 0
    off = _verifier(tmp_path, min_frames=1, enabled=False)
    for _ in range(2 * off.window):
        off.add(_row(low))
    assert not off.refused  # switched off: nothing is judged, nothing refused


def test_nan_from_the_network_is_not_verified(tmp_path):
    v = _verifier(tmp_path, min_frames=1, threshold=0.5, release_threshold=0.3)
    assert v.add(_row(0.9))
    assert not v.add(_row(np.nan))


def test_switched_off_or_without_model_every_lock_counts_as_verified(tmp_path):
    v = _verifier(tmp_path, min_frames=1, threshold=0.5, release_threshold=0.3, enabled=False)
    assert v.verified and v.add(_row(0.0))
    v.update_config(1, 0.5, 0.3, enabled=True)
    v.reset()
    assert not v.add(_row(0.1))
    assert LockVerifier(None).add(_row(0.0))


def test_window_array_pads_in_front_and_keeps_the_newest(tmp_path):
    v = _verifier(tmp_path, min_frames=1)
    for p in np.linspace(0, 1, 20):
        v.add(_row(p))
    w = v.window_array()
    assert w.shape == (16, N_FEATURES) and w[-1, P] == pytest.approx(1.0) and w[0, P] == pytest.approx(np.linspace(0, 1, 20)[4])


# --- contract and config ----------------------------------------------------------------------

def test_model_with_other_features_is_refused_in_one_line(tmp_path):
    path = last_row_verifier(tmp_path / "v5.onnx", 0, features=5)
    with pytest.raises(ModelError) as err:
        OnnxModel(path, expected_inputs={"tracks": (None, None, N_FEATURES)}, config_key="detector.verifier.model")
    assert "detector.verifier.model" in str(err.value) and "tracks" in str(err.value) and "\n" not in str(err.value)


def test_detector_model_given_as_verifier_is_refused(tmp_path):
    path = bright_spot_detector(tmp_path / "spot.onnx")
    cfg = config_with(Config(), **{"detector.verifier.model": path})
    with pytest.raises(ModelError) as err:
        build_detectors(cfg.detector)
    assert "tracks" in str(err.value)


def test_shipped_verifier_meets_the_contract():
    from payload.detect.verify import N_LOOK

    model = OnnxModel(builtin_model_path("verifier"), expected_inputs={"tracks": (None, None, None)})
    check_verifier(model)
    v = LockVerifier(model, min_frames=1)
    assert v.n_features == N_FEATURES + N_LOOK and v.features.look  # it judges the look of the target's pixels too
    v.add(np.r_[_row(0.5), np.zeros(N_LOOK, np.float32)])
    assert 0.0 <= v.probability <= 1.0


def test_verifier_with_a_feature_count_of_neither_kind_is_refused_in_one_line(tmp_path):
    from payload.detect.verify import N_LOOK

    path = last_row_verifier(tmp_path / "v.onnx", P, features=N_FEATURES + N_LOOK + 1)
    cfg = config_with(Config(), **{"detector.verifier.model": path})
    with pytest.raises(ModelError) as err:
        build_detectors(cfg.detector)
    msg = str(err.value)
    assert msg.startswith("detector.verifier.model: %s: " % path)  # the field and the file
    assert "[N, T, %d or %d]" % (N_FEATURES, N_FEATURES + N_LOOK) in msg and "\n" not in msg


def test_release_above_threshold_is_a_config_error():
    with pytest.raises(ConfigError) as err:
        config_with(Config(), **{"detector.verifier.threshold": 0.5, "detector.verifier.release_threshold": 0.6})
    assert "release_threshold" in str(err.value)


# --- in GLAD ------------------------------------------------------------------------------------------

def _glad(tmp_path, **overrides):
    from payload.detect.pipeline import Glad

    cfg = config_with(Config(), **{
        "detector.global.appearance.model": bright_spot_detector(tmp_path / "spot.onnx"),
        "detector.local.appearance.model": str(tmp_path / "spot.onnx"),
        "detector.classifier.model": brightness_classifier(tmp_path / "bright.onnx"),
        "detector.verifier.model": last_row_verifier(tmp_path / "v.onnx", P),
        "detector.global.motion.enabled": False,
        "detector.local.motion.enabled": False,
        "detector.classifier.modules": [],
        "detector.classifier.lock_hits": 0,
        "detector.classifier.confirm_hits": 0,
        **overrides,
    })
    return Glad(cfg.detector, build_detectors(cfg.detector))


def _frame(index, side):
    """A white square on black: the detector scores it 1.0 whatever its size; the classifier's drone
    probability is its patch's mean brightness (about 0.1 for 4 px, near 1 for 16 px)."""
    image = np.zeros((384, 640, 3), np.uint8)
    image[200:200 + side, 320:320 + side] = 255
    return Frame(image, index, index * 33_000_000, 0)


@pytest.mark.parametrize("side, reported_from", [(16, 4), (4, None)])
def test_glad_reports_a_lock_only_once_the_verifier_believes_it(tmp_path, side, reported_from):
    # drone probability 0.44 for the 16 px square, 0.11 for the 4 px one
    glad = _glad(tmp_path, **{"detector.verifier.min_frames": 4, "detector.verifier.threshold": 0.3,
                              "detector.verifier.release_threshold": 0.2})
    reported = [bool(len(glad.process(_frame(i, side)).detections)) for i in range(8)]
    assert glad.tracks  # followed all along
    if reported_from is None:
        assert not any(reported)  # a dim thing: followed, never sent
    else:
        assert reported == [False] * (reported_from - 1) + [True] * (8 - reported_from + 1)


def test_reload_switches_the_verifier_off_and_on(tmp_path):
    glad = _glad(tmp_path, **{"detector.verifier.min_frames": 2, "detector.verifier.threshold": 0.3,
                              "detector.verifier.release_threshold": 0.2})
    on = glad.cfg
    off = on.model_copy(update={"verifier": on.verifier.model_copy(update={"enabled": False})})
    assert glad.update_config(off) == ["detector.verifier.enabled"]
    assert len(glad.process(_frame(0, 4)).detections)  # off: a dim lock is reported at once
    assert glad.update_config(on) == ["detector.verifier.enabled"]
    glad.reset()
    assert not len(glad.process(_frame(0, 4)).detections)  # on again: judged first


# --- the look of the target's pixels -----------------------------------------------------------------

def test_look_rows_tell_a_round_steady_blob_from_a_changing_elongated_one():
    from payload.detect.verify import LOOK_FEATURES, PATCH_PX, look_row, target_patch

    grey = np.full((120, 160), 60, np.uint8)
    grey[50:56, 70:76] = 200  # a 6x6 warm blob
    round_ = target_patch(grey, np.array([70, 50, 76, 56.0]))
    wide = np.full((120, 160), 60, np.uint8)
    wide[52:54, 64:82] = 200  # the same place, spread into a horizontal bar (wings out)
    bar = target_patch(wide, np.array([70, 50, 76, 56.0]))
    assert round_.shape == (PATCH_PX, PATCH_PX) and round_.dtype == np.uint8
    nat = target_patch(grey, np.array([70, 50, 76, 56.0]), native=True)
    rows = np.stack([look_row(round_, nat, None), look_row(round_, nat, round_), look_row(bar, nat, round_)])
    f = {name: rows[:, i] for i, name in enumerate(LOOK_FEATURES)}
    assert f["look_ncc"][0] == 0.0  # no previous patch: no correlation claimed
    assert f["look_ncc"][1] == pytest.approx(1.0, abs=1e-4)  # the same look as last frame
    assert f["look_ncc"][2] < 0.5  # the look changed
    assert f["look_aniso"][0] < 0.2 and f["look_aniso"][2] > 0.8  # round, then a line
    assert f["look_cos2"][2] > 0.8  # ... along x
    assert np.isfinite(rows).all()


def test_look_rows_stay_finite_on_flat_and_edge_patches():
    from payload.detect.verify import look_row, target_patch

    flat = np.full((50, 50), 7, np.uint8)
    for b in ([0, 0, 1, 1], [49, 49, 50, 50], [-30, -30, 80, 80]):
        patch = target_patch(flat, np.array(b, float))
        assert np.isfinite(look_row(patch, patch, patch)).all() and np.isfinite(look_row(patch, patch, None)).all()


def test_run_time_rows_are_the_rows_the_verifier_was_trained_on():
    """GLAD's rows with the shipped verifier, frame by frame (the previous patch kept per lock), equal
    those training/train_verifier.py makes from the mined patches of the same frames and boxes."""
    import cv2

    from payload.detect.pipeline import Glad
    from payload.detect.verify import target_patch
    from payload.synth.scene import Scene
    from training.train_verifier import with_look

    cfg = Config()
    glad = Glad(cfg.detector.model_copy(update={"threads": 1}))
    assert glad.models.verifier is not None
    full, base, rel, nat, lock = [], [], [], [], []
    lock_id = -1
    for sf in Scene(seed=5, frames=40, target_px=(8.0, 20.0)):
        glad.process(Frame(image=sf.image, index=sf.index, t_capture_ns=int(sf.index * 1e9 / 30), t_wall_ns=0))
        track = glad.tracks[0] if glad.tracks else None
        if track is None or track.last_row is None:
            continue
        if len(track.verifier.rows) == 1:
            lock_id += 1
        grey = cv2.cvtColor(sf.image, cv2.COLOR_BGR2GRAY)
        full.append(track.last_row)
        base.append(track.last_row[:N_FEATURES])
        rel.append(target_patch(grey, track.verifier.features.box))
        nat.append(target_patch(grey, track.verifier.features.box, native=True))
        lock.append(lock_id)
    assert len(full) >= 20 and full[0].shape[0] > N_FEATURES  # the shipped verifier looks at the pixels
    trained = with_look(dict(rows=np.array(base), patch_rel=np.array(rel), patch_nat=np.array(nat), lock=np.array(lock)))
    np.testing.assert_allclose(np.array(full), trained, rtol=1e-5, atol=1e-5)


def test_a_frame_sized_box_makes_its_patch_from_a_bounded_square():
    from payload.detect.verify import MAX_PATCH_SIDE_PX, PATCH_PX, target_patch

    grey = np.zeros((1080, 1920), np.uint8)
    cy, cx = 540, 960
    half = MAX_PATCH_SIDE_PX // 2
    grey[cy - half:cy + half, cx - half:cx + half] = 255  # exactly the bounded square around the centre
    patch = target_patch(grey, np.array([0, 0, 1920, 1080.0]))
    assert patch.shape == (PATCH_PX, PATCH_PX) and patch.min() == 255  # the square, not the whole frame

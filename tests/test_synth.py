"""The synthetic air-to-air scene: determinism, truthful labels and homographies, export, source."""

import csv
import os

import cv2
import numpy as np
import pytest

from payload.capture.base import EndOfStream
from payload.capture.synthetic import SyntheticSource, scene_of
from payload.config import SyntheticSceneConfig
from payload.errors import ConfigError, SourceError
from payload.synth.export import export_clip, write_labels
from payload.synth.scene import MAX_BLUR_PX, Scene, SceneFrame
from payload.types import Frame

W, H = 640, 360


def _frames(n, **kw):
    kw.setdefault("width", W)
    kw.setdefault("height", H)
    return list(Scene(frames=n, **kw))


def test_same_seed_same_pixels_other_seed_differs():
    a = _frames(12, seed=7)
    b = _frames(12, seed=7)
    c = _frames(12, seed=8)
    assert len(a) == 12 and all(isinstance(f, SceneFrame) for f in a)
    for fa, fb in zip(a, b):
        assert fa.image.shape == (H, W, 3) and fa.image.dtype == np.uint8
        assert np.array_equal(fa.image, fb.image)
        assert np.array_equal(fa.homography, fb.homography)
        assert (fa.target_xyxy is None) == (fb.target_xyxy is None)
        if fa.target_xyxy is not None:
            assert np.array_equal(fa.target_xyxy, fb.target_xyxy)
    assert not np.array_equal(a[5].image, c[5].image)
    # frames=0 is endless.
    endless = iter(Scene(seed=7, width=160, height=120, frames=0))
    assert [next(endless).index for _ in range(5)] == [0, 1, 2, 3, 4]
    # Iterating the same Scene object twice replays the same clip.
    scene = Scene(seed=7, width=W, height=H, frames=3)
    assert all(np.array_equal(x.image, y.image) for x, y in zip(scene, scene))


@pytest.mark.parametrize("seed, clutter", [(2, 4), (3, 4), (5, 12)])  # seed 5 + 12: partly occluded frames
def test_label_box_is_tight_around_the_rendered_target(seed, clutter):
    with_target = _frames(40, seed=seed, clutter=clutter)
    without = _frames(40, seed=seed, clutter=clutter, render_target=False)
    boxed = 0
    for f, g in zip(with_target, without):
        changed = np.any(f.image != g.image, axis=2)
        if f.target_xyxy is None:
            assert not changed.any(), f"frame {f.index}: pixels changed but no label"
            continue
        boxed += 1
        assert 0.0 < f.target_visible <= 1.0
        x1, y1, x2, y2 = f.target_xyxy.astype(int)
        assert np.array_equal(f.target_xyxy, f.target_xyxy.round()), "boxes are whole-pixel bounds"
        inside = np.zeros_like(changed)
        inside[y1:y2, x1:x2] = True
        assert not (changed & ~inside).any(), f"frame {f.index}: target pixels outside its box"
        ys, xs = np.nonzero(changed)
        assert len(xs) > 0, f"frame {f.index}: a box but no target pixels"
        # Tight: the changed pixels reach (almost) every edge of the box.
        assert xs.min() - x1 <= 2 and x2 - 1 - xs.max() <= 2
        assert ys.min() - y1 <= 2 and y2 - 1 - ys.max() <= 2
    assert boxed >= 10, f"the target should be visible in most frames (got {boxed} of 40)"
    if clutter > 4:
        assert any(0 < f.target_visible < 0.97 for f in with_target), "expected some partly hidden frames"


def test_homography_is_the_ground_motion():
    frames = _frames(30, seed=4, clutter=0, birds=0, cars=0, noise=0.0)
    assert np.allclose(frames[0].homography, np.eye(3))
    errors, still = [], []
    for prev, cur in zip(frames, frames[1:]):
        warped = cv2.warpPerspective(prev.image, cur.homography, (W, H), flags=cv2.INTER_LINEAR)
        valid = cv2.warpPerspective(np.full((H, W), 255, np.uint8), cur.homography, (W, H)) == 255
        valid = cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        if cur.target_xyxy is not None:  # the target moves on its own
            x1, y1, x2, y2 = cur.target_xyxy.astype(int)
            valid[max(0, y1 - 30):y2 + 30, max(0, x1 - 30):x2 + 30] = False
        diff = np.abs(warped.astype(np.int16) - cur.image.astype(np.int16)).max(axis=2)
        errors.append(np.mean(diff[valid]))
        still.append(np.mean(np.abs(prev.image.astype(np.int16) - cur.image.astype(np.int16))))
    errors, still = np.array(errors), np.array(still)
    assert errors.max() < 4.0, errors  # only resampling blur is left
    assert np.mean(errors) < 0.5 * np.mean(still), (errors, still)  # and the camera does move


@pytest.mark.parametrize("target_px", [(4.0, 12.0), (40.0, 80.0)])
def test_target_size_respects_target_px(target_px):
    lo, hi = target_px
    frames = _frames(40, seed=5, target_px=target_px, clutter=0)
    spans = np.array([f.target_span_px for f in frames])
    assert (spans >= lo - 1e-6).all() and (spans <= hi + 1e-6).all()
    sides = []
    for f in frames:
        if f.target_xyxy is None:
            continue
        x1, y1, x2, y2 = f.target_xyxy
        if x1 <= 0 or y1 <= 0 or x2 >= W or y2 >= H:
            continue  # cut by the frame edge
        sides.append(max(x2 - x1, y2 - y1))
        assert sides[-1] <= hi + MAX_BLUR_PX + 2
    assert len(sides) >= 5
    assert lo * 0.5 <= np.median(sides) <= hi * 1.3, sides


def test_export_writes_mp4_csv_and_homographies(tmp_path):
    scene = Scene(seed=3, width=320, height=240, frames=20)
    video, labels = export_clip(scene, str(tmp_path), "SYN_T")
    assert video == os.path.join(str(tmp_path), "SYN_T.mp4") and os.path.isfile(labels)
    cap = cv2.VideoCapture(video)
    count = 0
    while True:
        ok, img = cap.read()
        if not ok:
            break
        assert img.shape == (240, 320, 3)
        count += 1
    assert count == 20
    truth = list(scene)
    with open(labels) as fh:
        rows = list(csv.DictReader(fh))
    assert rows and list(rows[0]) == ["frame", "class", "x", "y", "w", "h"]
    expected = {f.index: f.target_xyxy for f in truth if f.target_xyxy is not None}
    assert sorted(int(r["frame"]) for r in rows) == sorted(expected)
    for r in rows:
        box = expected[int(r["frame"])]
        assert r["class"] == "DRONE"
        assert float(r["x"]) == pytest.approx(box[0] + 1)  # 1-based, as MATLAB stores it
        assert float(r["y"]) == pytest.approx(box[1] + 1)
        assert float(r["w"]) == pytest.approx(box[2] - box[0])
        assert float(r["h"]) == pytest.approx(box[3] - box[1])
    homographies = np.load(os.path.join(str(tmp_path), "SYN_T_homography.npy"))
    assert homographies.shape == (20, 3, 3)
    assert np.allclose(homographies[7], truth[7].homography)


@pytest.mark.parametrize("kw", [dict(seed=8, target_px=(4.0, 20.0)), dict(seed=12, clutter=8),
                                dict(seed=5, render_target=False), dict(seed=3, width=1920, height=1080)])
def test_truth_without_drawing_is_the_drawn_truth(kw):
    kw.setdefault("width", W)
    kw.setdefault("height", H)
    drawn = list(Scene(frames=40, **kw))
    truth = list(Scene(frames=40, **kw).truth())
    assert [f.index for f in truth] == list(range(40))
    assert sum(f.target_xyxy is not None for f in drawn) >= 10
    for d, t in zip(drawn, truth):
        assert t.image is None and t.homography is None
        assert (d.target_xyxy is None) == (t.target_xyxy is None), d.index
        if d.target_xyxy is not None:
            assert np.array_equal(d.target_xyxy, t.target_xyxy), d.index
        assert (d.target_span_px, d.target_visible, d.camera_rpy_rad) == (t.target_span_px, t.target_visible,
                                                                          t.camera_rpy_rad)


def test_write_labels_writes_what_export_writes(tmp_path):
    scene = Scene(seed=9, width=W, height=H, frames=30, target_px=(6.0, 30.0))
    _, exported = export_clip(scene, str(tmp_path / "a"), "SYN_9")
    written = write_labels(scene, str(tmp_path / "b"), "SYN_9")
    with open(exported) as a, open(written) as b:
        rows = a.read()
        assert rows.count("\n") > 10 and rows == b.read()


def test_cli_synth_writes_a_clip(tmp_path):
    from payload.cli import main

    rc = main(["synth", str(tmp_path), "--seed", "9", "--frames", "3", "--width", "160", "--height", "120"])
    assert rc == 0
    assert os.path.isfile(str(tmp_path / "SYN_9.mp4")) and os.path.isfile(str(tmp_path / "SYN_9.csv"))


def test_synthetic_source_yields_frames_then_end_of_stream():
    cfg = SyntheticSceneConfig(seed=2, width=160, height=120, frames=4, fps=20.0)
    source = SyntheticSource(cfg)
    with source:
        frames = []
        for _ in range(4):
            frame = source.read(timeout_s=1.0)
            assert isinstance(frame, Frame) and frame.size_wh == (160, 120)
            assert source.last_truth.index == frame.index
            assert np.array_equal(source.last_truth.image, frame.image)
            frames.append(frame)
        with pytest.raises(EndOfStream):
            source.read(timeout_s=1.0)
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert all(b.t_capture_ns - a.t_capture_ns == 50_000_000 for a, b in zip(frames, frames[1:]))  # 1 / fps
    assert len(list(SyntheticSource(cfg))) == 4  # plain iteration stops at the end
    # paced at cfg.fps (capture.pace): tests/test_paced.py


def test_bad_inputs_are_one_line_errors(tmp_path):
    with pytest.raises(ConfigError):
        Scene(target_px=(20.0, 10.0))
    with pytest.raises(SourceError, match="file not found"):
        next(iter(Scene(width=160, height=120, frames=2, background=str(tmp_path / "none.mp4"))))


def test_video_background_is_played_frame_by_frame(tmp_path):
    path = str(tmp_path / "bg.mp4")
    colours = [(20 * k + 10, 100, 200 - 15 * k) for k in range(8)]
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (160, 128))
    for c in colours:
        writer.write(np.full((128, 160, 3), c, np.uint8))
    writer.release()
    frames = _frames(8, seed=1, width=320, height=240, background=path, clutter=0, birds=0, noise=0.0)
    for f, c in zip(frames, colours):
        assert np.abs(np.median(f.image.reshape(-1, 3), axis=0) - c).max() <= 8, (f.index, c)


def test_video_background_moves_by_the_homography(tmp_path):
    path = str(tmp_path / "still.mp4")
    texture = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 255, (128, 160, 3), dtype=np.uint8), (0, 0), 1.5)
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (160, 128))
    for _ in range(10):
        writer.write(texture)
    writer.release()
    frames = _frames(10, seed=1, background=path, clutter=0, birds=0, noise=0.0)
    core = (slice(40, H - 40), slice(40, W - 40))
    errors, still = [], []
    for prev, cur in zip(frames, frames[1:]):
        warped = cv2.warpPerspective(prev.image, cur.homography, (W, H))
        errors.append(np.mean(np.abs(warped[core].astype(int) - cur.image[core].astype(int))))
        still.append(np.mean(np.abs(prev.image[core].astype(int) - cur.image[core].astype(int))))
    assert max(errors) < 0.5 and np.mean(errors) < 0.3 * np.mean(still), (errors, still)


def test_real_video_background(halmstad_dir):
    path = os.path.join(halmstad_dir, "visible", "V_BIRD_001.mp4")
    if not os.path.isfile(path):
        pytest.skip(f"no {path}")
    frames = _frames(10, seed=1, background=path)
    assert all(f.image.shape == (H, W, 3) for f in frames)
    assert frames[0].image.std() > 10  # real content, not a blank frame
    assert sum(f.target_xyxy is not None for f in frames) >= 5


def _drone_pixels(**kw):
    """(mean grey of the pixels the target changed, elevation in degrees of every visible target)."""
    drawn = _frames(30, **kw)
    bare = _frames(30, render_target=False, **kw)
    values, elevations = [], []
    for f, g in zip(drawn, bare):
        changed = np.any(f.image != g.image, axis=2)
        if f.target_xyxy is None or not changed.any():
            continue
        values.append(f.image[changed].mean())
        x, y, z = f.target_direction
        elevations.append(np.degrees(np.arctan2(-y, np.hypot(x, z))))
    return float(np.mean(values)), elevations


def test_light_drone_in_a_clear_sky():
    """drone=light: a white/light-grey airframe (brighter than the default mostly dark ones);
    target_in_sky: every frame's target above the far hills."""
    for seed in (1, 2, 3):
        light, elevations = _drone_pixels(seed=seed, target_px=(14.0, 18.0), drone_look="light", sky="clear",
                                          target_in_sky=True)
        assert light > 140, seed
        assert len(elevations) >= 10 and min(elevations) >= 3.9, seed
    dark = [_drone_pixels(seed=seed, target_px=(14.0, 18.0))[0] for seed in (1, 2, 3)]
    assert min(dark) < 110


def test_clear_sky_has_the_sun_in_it():
    """sky=clear: a blue sky (blue above red) with a saturated sun disc somewhere in the backdrop."""
    from payload.synth.backdrop import Backdrop
    from payload.synth.camera import Lens, MotionLimits

    for seed in (1, 2):
        lens = Lens(640, 360, np.radians(60.0))
        clear = Backdrop(np.random.default_rng(seed), lens, MotionLimits(), sky="clear", glare_rng=np.random.default_rng(seed + 50)).image
        assert (clear.min(axis=2) >= 250).sum() > 50
        top = clear[: clear.shape[0] // 8].reshape(-1, 3).mean(axis=0)
        assert top[0] > top[2] + 30  # BGR: blue well above red at the zenith
    with pytest.raises(ValueError, match="sky"):
        Backdrop(np.random.default_rng(1), Lens(64, 36, 1.0), MotionLimits(), sky="pink")


def test_scene_look_options_are_checked_and_configurable():
    with pytest.raises(ConfigError, match="synthetic.drone='purple'"):
        Scene(drone_look="purple")
    with pytest.raises(ConfigError, match="synthetic.sky='night'"):
        Scene(sky="night")
    cfg = SyntheticSceneConfig(drone="light", sky="clear", target_in_sky=True, target_px=(3.0, 6.0))
    scene = scene_of(cfg)
    assert (scene.drone_look, scene.sky, scene.target_in_sky) == ("light", "clear", True)

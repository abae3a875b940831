"""Frame sources against real media: GStreamer pipelines, MP4 files written here, image folders.

GStreamer tests need PyGObject and the Gst typelibs (gir1.2-gstreamer-1.0); they skip without them.
"""

import logging
import os
import re
import shutil
import threading
import time

import cv2
import numpy as np
import pytest

from payload.capture import open_source
from payload.capture.base import EndOfStream, FrameSource
from payload.capture.file import ImageFolderSource, VideoFileSource
from payload.capture.gstreamer import GStreamerSource, bgr_pipeline
from payload.capture.paced import PacedSource
from payload.capture.readahead import ReadAhead
from payload.capture.v4l2 import V4L2Source
from payload.config import CaptureConfig, Retry
from payload.errors import SourceError

CLIP_FPS = 25.0


@pytest.fixture(scope="module")
def gst():
    try:
        import gi

        gi.require_version("Gst", "1.0")
        gi.require_version("GstApp", "1.0")
        from gi.repository import Gst, GstApp  # noqa: F401
    except (ImportError, ValueError) as exc:
        pytest.skip("PyGObject/GStreamer typelibs not available: %s" % exc)
    if shutil.which("gst-inspect-1.0") is None:
        pytest.skip("GStreamer tools not installed")
    return Gst


def _level(index):
    """The grey level image `index` of our test folders is painted with."""
    return 20 + 2 * index


def _paint_index(image, index):
    """Frame number as 8 black/white 20x20 blocks along the bottom: survives any codec and colour range."""
    for bit in range(8):
        image[-20:, 20 * bit : 20 * bit + 20] = 255 if (index >> bit) & 1 else 0
    return image


def _painted_index(image):
    """Which frame of a test clip this image is."""
    return sum(1 << bit for bit in range(8) if image[-16:-4, 20 * bit + 4 : 20 * bit + 16].mean() > 128)


def _write_clip(path, frames, size_wh=(160, 120)):
    w, h = size_wh
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), CLIP_FPS, (w, h))
    assert writer.isOpened(), "OpenCV cannot write mp4v here"
    for i in range(frames):
        image = np.full((h, w, 3), 90, np.uint8)
        cv2.rectangle(image, (4 + i % 100, 10), (24 + i % 100, 30), (255, 255, 255), -1)  # something that moves
        writer.write(_paint_index(image, i))
    writer.release()
    return str(path)


@pytest.fixture(scope="module")
def clip100(tmp_path_factory):
    return _write_clip(tmp_path_factory.mktemp("clip") / "clip100.mp4", 100)


@pytest.fixture(scope="module")
def clip20(tmp_path_factory):
    return _write_clip(tmp_path_factory.mktemp("clip") / "clip20.mp4", 20)


def _one_line(exc):
    text = str(exc)
    assert text and "\n" not in text and "Traceback" not in text
    return text


# --- GStreamer --------------------------------------------------------------------------------


def test_gstreamer_videotestsrc_gives_100_bgr_frames_in_order(gst):
    src = GStreamerSource("videotestsrc num-buffers=100 ! video/x-raw,width=320,height=240 ! appsink", backend="gi")
    with src:
        frames = list(src)
        assert src.live is False
        with pytest.raises(EndOfStream):
            src.read(0.5)
    assert len(frames) == 100
    assert [f.index for f in frames] == list(range(100))
    assert all(f.image.shape == (240, 320, 3) and f.image.dtype == np.uint8 for f in frames)
    t = np.array([f.t_capture_ns for f in frames], np.int64)
    assert np.all(np.abs(np.diff(t) - 1e9 / 30) <= 1)  # videotestsrc's 30 fps timeline (buffer PTS)
    assert abs(frames[0].t_wall_ns - time.time_ns()) < 60e9
    assert frames[0].image.flags.writeable
    assert src.stats.frames == 100 and src.stats.dropped == 0


def test_gstreamer_odd_width_rows_are_unpadded_and_colours_are_bgr(gst):
    # 321 px * 3 = 963 bytes, padded to 964 per row by GStreamer; a wrong stride would shear the image.
    pipeline = ("videotestsrc num-buffers=2 pattern=solid-color foreground-color=0xff3366cc "
                "! video/x-raw,width=321,height=17 ! appsink")
    with GStreamerSource(pipeline, backend="gi") as src:
        frames = list(src)
    assert len(frames) == 2
    image = frames[0].image
    assert image.shape == (17, 321, 3)
    # ARGB 0xff3366cc is R=0x33 G=0x66 B=0xcc; videoconvert's colour matrices may round by a step or two.
    diff = np.abs(image.astype(int) - np.array([0xCC, 0x66, 0x33])).max()
    assert diff <= 3, "pixels off by %d: stride or channel order wrong" % diff


def test_gstreamer_reads_an_mp4_like_opencv_does(gst, clip100):
    with VideoFileSource(clip100) as src:
        ref = list(src)
    pipeline = "filesrc location=%s ! decodebin ! videoconvert ! appsink" % clip100
    with GStreamerSource(pipeline, backend="gi") as src:
        got = list(src)
    assert len(ref) == len(got) == 100
    assert [f.index for f in got] == list(range(100))
    for a, b in zip(ref, got):
        assert b.image.shape == (120, 160, 3)
        # Two decoders and two YUV->BGR conversions (each with its own range handling): close, not identical.
        assert np.abs(a.image.astype(int) - b.image.astype(int)).mean() < 6
        assert _painted_index(b.image) == b.index
    dt_ns = np.diff([f.t_capture_ns for f in got])
    assert np.all(np.abs(dt_ns - 1e9 / CLIP_FPS) < 1e6)  # the file's 25 fps timeline (buffer PTS)


def test_broken_pipeline_is_one_line_source_error(gst):
    with pytest.raises(SourceError) as err:
        GStreamerSource("nosuchelement ! appsink", backend="gi").open()
    text = _one_line(err.value)
    assert text.startswith("capture.pipeline: ") and 'no element "nosuchelement"' in text


def test_pipeline_that_cannot_start_names_the_gstreamer_error(gst, tmp_path):
    missing = tmp_path / "nothing.mp4"
    with pytest.raises(SourceError) as err:
        GStreamerSource("filesrc location=%s ! decodebin ! appsink" % missing, backend="gi").open()
    text = _one_line(err.value)
    assert text.startswith("capture.pipeline: cannot start: filesrc")
    assert str(missing) in text


def test_pipeline_without_appsink_is_refused(gst):
    with pytest.raises(SourceError) as err:
        GStreamerSource("videotestsrc num-buffers=1 ! fakesink", backend="gi").open()
    assert "appsink" in _one_line(err.value)


def test_bgr_caps_are_added_only_when_missing():
    text, changed = bgr_pipeline("videotestsrc ! appsink sync=false")
    assert changed and text == "videotestsrc ! videoconvert ! video/x-raw,format=BGR ! appsink sync=false"
    already = "v4l2src ! videoconvert ! video/x-raw,format=BGR ! appsink drop=true"
    assert bgr_pipeline(already) == (already, False)
    bgrx = "nvvidconv ! video/x-raw,format=BGRx ! appsink"
    assert bgr_pipeline(bgrx)[1] is True  # BGRx is not BGR
    not_last = "appsink name=s videotestsrc ! s."
    assert bgr_pipeline(not_last) == (not_last, False)


def _live_pipeline(extra=""):
    return ("videotestsrc is-live=true %s ! video/x-raw,width=64,height=48,framerate=100/1 ! appsink" % extra).replace("  ", " ")


def test_live_pipeline_read_slowly_drops_and_returns_the_newest_frame(gst):
    src = GStreamerSource(_live_pipeline(), backend="gi")
    with src:
        assert src.live is True
        first = src.read(2.0)
        assert first is not None
        frames = [first]
        ages_ms = []
        for _ in range(6):
            time.sleep(0.1)  # a slow detector: ~10 camera frames arrive meanwhile
            frame = src.read(1.0)
            assert frame is not None
            ages_ms.append((time.monotonic_ns() - frame.t_capture_ns) / 1e6)
            frames.append(frame)
        stats = src.stats
    idx = [f.index for f in frames]
    assert all(b > a for a, b in zip(idx, idx[1:]))
    gaps = np.diff(idx)
    assert np.median(gaps) >= 5, "expected ~10 frames between slow reads, got %s" % gaps
    assert stats.dropped >= sum(gaps) - len(gaps) - 6
    assert stats.frames == len(frames)
    # Newest frame wins: what we get was grabbed a moment ago, not 100 ms of queue ago.
    assert np.median(ages_ms) < 40, ages_ms


def test_live_read_never_repeats_a_frame(gst):
    with GStreamerSource(_live_pipeline(), backend="gi") as src:
        idx = []
        for _ in range(20):
            frame = src.read(1.0)
            assert frame is not None
            idx.append(frame.index)
    assert len(set(idx)) == 20 and idx == sorted(idx)


def test_live_pipeline_that_ends_is_a_lost_camera_and_is_reopened(gst, caplog):
    caplog.set_level(logging.DEBUG, logger="payload.capture")
    src = GStreamerSource(_live_pipeline("num-buffers=20"), retry=Retry(initial_s=0.3, max_s=1.0), backend="gi")
    seen = []  # (monotonic s, frame index or None, connected)
    with src:
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            frame = src.read(0.05)
            seen.append((time.monotonic(), None if frame is None else frame.index, src.stats.connected))
    # counted once the capture thread has stopped: read inside the block, a reconnect finishing
    # between the count and the close was logged but not counted (CI, 2026-12-06: 4 logged, 3 counted)
    reconnects = src.stats.reconnects
    assert reconnects >= 2
    nones_down = [s for s in seen if s[1] is None and not s[2]]
    assert len(nones_down) >= 3, "read() must return None while the camera is down"
    idx = [s[1] for s in seen if s[1] is not None]
    assert idx == sorted(idx) and len(set(idx)) == len(idx), "indices keep counting across reconnects"
    assert max(idx) >= 40  # frames from at least the third connection
    losses = [r for r in caplog.records if r.getMessage().startswith("camera lost")]
    recoveries = [r for r in caplog.records if r.getMessage().startswith("camera recovered")]
    assert len(losses) >= reconnects and len(recoveries) == reconnects
    assert all(r.levelno == logging.WARNING for r in losses)


def test_error_in_a_live_pipeline_is_a_loss_and_is_reconnected(gst, caplog):
    caplog.set_level(logging.INFO, logger="payload.capture")
    pipeline = _live_pipeline().replace(" ! appsink", " ! identity error-after=10 ! appsink")
    src = GStreamerSource(pipeline, retry=Retry(initial_s=0.2, max_s=1.0), backend="gi")
    with src:
        deadline = time.monotonic() + 3.0
        while src.stats.reconnects < 1 and time.monotonic() < deadline:
            src.read(0.05)
        assert src.stats.reconnects >= 1
        assert src.read(1.0) is not None  # frames flow again after the reconnect
    lost = [r.getMessage() for r in caplog.records if r.getMessage().startswith("camera lost")]
    assert lost and "identity" in lost[0] and "Failed after iterations" in lost[0]
    assert ".c(" not in lost[0] and "\n" not in lost[0]


def test_reconnect_backs_off_exponentially_until_the_camera_returns(gst, clip20, tmp_path, caplog):
    caplog.set_level(logging.DEBUG, logger="payload.capture")
    camera = tmp_path / "camera.mp4"
    shutil.copy(clip20, camera)
    # A finite file pipeline forced live: its end is a camera loss; the file's absence makes reopening fail.
    pipeline = "filesrc location=%s ! decodebin ! videoconvert ! appsink sync=false" % camera
    src = GStreamerSource(pipeline, retry=Retry(initial_s=0.1, max_s=0.4), live=True, backend="gi")
    with src:
        os.rename(camera, tmp_path / "unplugged.mp4")
        time.sleep(1.6)  # attempts at ~0.1, 0.3, 0.7, 1.1, 1.5 s after the loss
        assert src.stats.connected is False and src.stats.reconnects == 0
        src.read(0.0)  # the last frame from before the loss, if nobody took it yet
        assert src.read(0.1) is None  # nothing while the camera is away
        os.rename(tmp_path / "unplugged.mp4", camera)
        deadline = time.monotonic() + 3.0
        while src.stats.reconnects == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert src.stats.reconnects >= 1
        frame = src.read(2.0)
    failed = [r for r in caplog.records if r.getMessage().startswith("reconnect failed")]
    waits = [float(re.search(r"retry_in_s=([\d.]+)", r.getMessage()).group(1)) for r in failed]
    assert waits[:4] == [0.2, 0.4, 0.4, 0.4], waits
    assert all("no such file" in r.getMessage().lower() or "not found" in r.getMessage().lower() for r in failed)
    gaps = np.diff([r.created for r in failed])
    assert gaps[0] >= 0.18 and all(g >= 0.36 for g in gaps[1:3]), gaps
    assert frame is not None and frame.image.shape == (120, 160, 3)
    assert 0 <= _painted_index(frame.image) < 20


def test_close_stops_the_reader_thread(gst):
    before = {t.name for t in threading.enumerate()}
    src = GStreamerSource(_live_pipeline(), backend="gi")
    src.open()
    assert src.read(2.0) is not None
    assert any(t.name.startswith("capture-") for t in threading.enumerate() if t.name not in before)
    src.close()
    src.close()  # twice is fine
    assert not any(t.name.startswith("capture-") and t.is_alive() for t in threading.enumerate() if t.name not in before)


# --- video files and image folders -------------------------------------------------------------


def test_video_file_source_reads_every_frame_on_the_file_timeline(clip100):
    with VideoFileSource(clip100) as src:
        frames = list(src)
    assert [f.index for f in frames] == list(range(100))
    assert all(f.image.shape == (120, 160, 3) for f in frames)
    assert [_painted_index(f.image) for f in frames] == list(range(100))
    dt_ns = np.diff([f.t_capture_ns for f in frames])
    assert np.all(np.abs(dt_ns - 1e9 / CLIP_FPS) <= 1)  # the clip's own 25 fps, however fast we read


def test_video_file_loop_keeps_counting(clip20):
    with VideoFileSource(clip20, loop=True) as src:
        frames = [src.read() for _ in range(45)]
    assert [f.index for f in frames] == list(range(45))
    assert [_painted_index(f.image) for f in frames] == [i % 20 for i in range(45)]
    assert np.all(np.diff([f.t_capture_ns for f in frames]) > 0)


def test_video_file_without_loop_ends(clip20):
    with VideoFileSource(clip20) as src:
        for _ in range(20):
            assert src.read() is not None
        with pytest.raises(EndOfStream):
            src.read()


# paced recordings (capture.pace): tests/test_paced.py


def test_image_folder_is_in_numeric_order(tmp_path):
    numbers = [10, 2, 1, 100, 11]
    for n in numbers:
        cv2.imwrite(str(tmp_path / ("%d.png" % n)), np.full((6, 9, 3), n, np.uint8))
    cv2.imwrite(str(tmp_path / "3.JPG"), np.full((6, 9, 3), 3, np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    with ImageFolderSource(str(tmp_path)) as src:
        frames = list(src)
    assert [f.index for f in frames] == list(range(6))
    assert [int(round(float(f.image.mean()))) for f in frames] == [1, 2, 3, 10, 11, 100]
    assert frames[0].image.shape == (6, 9, 3)


def test_image_folder_loop(tmp_path):
    for n in (1, 2, 3):
        cv2.imwrite(str(tmp_path / ("img_%d.bmp" % n)), np.full((4, 4, 3), n, np.uint8))
    with ImageFolderSource(str(tmp_path), loop=True) as src:
        frames = [src.read() for _ in range(7)]
    assert [int(f.image[0, 0, 0]) for f in frames] == [1, 2, 3, 1, 2, 3, 1]
    assert [f.index for f in frames] == list(range(7))


def test_empty_folder_is_one_line_error(tmp_path):
    (tmp_path / "readme.txt").write_text("no images here")
    with pytest.raises(SourceError) as err:
        ImageFolderSource(str(tmp_path)).open()
    text = _one_line(err.value)
    assert text.startswith("capture.path: %s: no images (.png .jpg" % tmp_path)


def test_missing_file_and_folder_messages_are_exact(tmp_path):
    missing = str(tmp_path / "y.mp4")
    with pytest.raises(SourceError) as err:
        VideoFileSource(missing).open()
    assert _one_line(err.value) == "capture.path: %s: no such file" % missing
    with pytest.raises(SourceError) as err:
        ImageFolderSource(str(tmp_path / "frames")).open()
    assert _one_line(err.value) == "capture.path: %s: no such folder" % (tmp_path / "frames")


def test_unreadable_video_is_one_line_error(tmp_path):
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"this is not a video" * 100)
    with pytest.raises(SourceError) as err:
        VideoFileSource(str(bad)).open()
    assert _one_line(err.value) == "capture.path: %s: cannot be read as a video (OpenCV decoded no frame)" % bad


def test_missing_v4l2_device_is_one_line_error():
    if os.path.exists("/dev/video9"):
        pytest.skip("/dev/video9 exists on this machine")
    with pytest.raises(SourceError) as err:
        V4L2Source("/dev/video9").open()
    assert _one_line(err.value) == "capture.device: /dev/video9: no such device"
    with pytest.raises(SourceError) as err:
        V4L2Source("9").open()  # a bare number means /dev/videoN
    assert "/dev/video9" in _one_line(err.value)


# --- dispatch ----------------------------------------------------------------------------------


def test_open_source_builds_each_kind(clip20, tmp_path):
    cv2.imwrite(str(tmp_path / "1.png"), np.zeros((4, 4, 3), np.uint8))
    src = open_source(CaptureConfig(source="file", path=clip20, loop=True))
    assert isinstance(src, ReadAhead) and isinstance(src.recording, VideoFileSource) and src.recording.loop
    with src:
        assert src.read().index == 0
    src = open_source(CaptureConfig(source="folder", path=str(tmp_path), pace=True, fps=10))
    assert isinstance(src, PacedSource) and isinstance(src.recording, ImageFolderSource) and src.fps == 10
    with src:
        assert src.read().image.shape == (4, 4, 3)
    src = open_source(CaptureConfig(source="v4l2", device="/dev/video9", width=640, height=480, fourcc="YUYV"))
    assert isinstance(src, V4L2Source) and (src.width, src.height, src.fourcc) == (640, 480, "YUYV")
    if not os.path.exists("/dev/video9"):
        with pytest.raises(SourceError):
            src.open()
    retry = Retry(initial_s=0.2, max_s=2.0)
    src = open_source(CaptureConfig(source="gstreamer", pipeline="videotestsrc ! appsink", retry=retry))
    assert isinstance(src, GStreamerSource) and src.pipeline.endswith("format=BGR ! appsink")
    assert src._reader._retry == retry


def test_open_source_synthetic():
    try:
        from payload.capture.synthetic import SyntheticSource
    except ImportError:
        pytest.skip("payload.capture.synthetic not in this tree yet")
    src = open_source(CaptureConfig(source="synthetic"))
    assert isinstance(src, SyntheticSource) and isinstance(src, FrameSource)


def test_unpaced_synthetic_frames_follow_the_scene_timeline():
    # eval/bench read the scene as fast as they can: capture times must still be 1/fps apart
    # (the search region's motion model uses them), as for a recording
    from payload.capture.synthetic import SyntheticSource
    from payload.config import SyntheticSceneConfig

    cfg = SyntheticSceneConfig(seed=3, width=320, height=240, fps=25.0, frames=4)
    with SyntheticSource(cfg) as src:
        frames = [src.read() for _ in range(4)]
        with pytest.raises(EndOfStream):
            src.read()
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert np.diff([f.t_capture_ns for f in frames]).tolist() == [40_000_000] * 3
    assert np.diff([f.t_wall_ns for f in frames]).tolist() == [40_000_000] * 3


@pytest.mark.parametrize("pace", [False, True])
def test_corrupt_and_empty_images_are_skipped_and_counted(tmp_path, pace):
    for i in range(8):
        cv2.imwrite(str(tmp_path / ("%02d.jpg" % i)), np.full((8, 8, 3), 30 * i, np.uint8))
    (tmp_path / "02.jpg").write_bytes(b"\xff\xd8\xff\xe0 not a jpeg")
    (tmp_path / "05.jpg").write_bytes(b"")
    src = open_source(CaptureConfig(source="folder", path=str(tmp_path), fps=200.0, pace=pace))
    with src:
        got = list(src)
    indices = [f.index for f in got]  # each keeps its place (and time) on the timeline
    if pace:  # a loaded machine may drop a frame or decode it late: counted below
        assert set(indices) <= {0, 1, 3, 4, 6, 7} and indices[-1] == 7
    else:
        assert indices == [0, 1, 3, 4, 6, 7]
    assert src.stats.unreadable == 2 and src.stats.frames + src.stats.dropped + src.stats.late == 6

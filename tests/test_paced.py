"""Recordings played as a camera (``capture.pace``): video file, image folder and synthetic scene
all through payload.capture.paced, and ``glad-payload bench --paced`` through the same path.

Timing bounds are one-sided where the machine's load could break them (a frame is never early;
late or dropped frames are counted, not forbidden) so that a loaded 2-core runner passes.
"""

import json
import logging
import os
import time

import cv2
import numpy as np
import pytest
import yaml
from test_capture import _level, _paint_index, _painted_index  # the test clips' frame marks

from payload.capture import open_source
from payload.capture.base import EndOfStream, SourceStats
from payload.capture.file import ImageFolderSource, VideoFileSource
from payload.capture.live import LiveReader
from payload.capture.paced import PacedGrabber, PacedSource
from payload.capture.readahead import ReadAhead
from payload.capture.synthetic import SyntheticSource
from payload.config import CaptureConfig, Retry, SyntheticSceneConfig
from payload.errors import SourceError

EARLY_S = 0.002  # clock granularity


def _folder(path, n, corrupt=()):
    """n 8x8 images painted with _level(index); those in ``corrupt`` are not images."""
    path.mkdir(exist_ok=True)
    for i in range(n):
        name = path / ("%03d.png" % i)
        if i in corrupt:
            name.write_bytes(b"not a png")
        else:
            cv2.imwrite(str(name), np.full((8, 8, 3), _level(i), np.uint8))
    return str(path)


@pytest.fixture(scope="module")
def clip60(tmp_path_factory):
    """A 60-frame 160x120 video whose frames carry their index painted along the bottom."""
    path = str(tmp_path_factory.mktemp("paced") / "clip60.mp4")
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (160, 120))
    assert writer.isOpened(), "OpenCV cannot write mp4v here"
    for i in range(60):
        writer.write(_paint_index(np.full((120, 160, 3), 90, np.uint8), i))
    writer.release()
    return path


def _read_all(source, consume_s=0.0, limit=None):
    """Every frame the source hands out until EndOfStream, sleeping ``consume_s`` after each."""
    frames = []
    deadline = time.monotonic() + 30.0
    while limit is None or len(frames) < limit:
        assert time.monotonic() < deadline, "the paced source never ended"
        try:
            frame = source.read(timeout_s=0.5)
        except EndOfStream:
            break
        if frame is not None:
            frames.append(frame)
            time.sleep(consume_s)
    return frames


def _never_early(frames, fps, t_open_ns):
    """Frame k is handed out no sooner than k / fps after frame 0, the clock's start (half a period
    allowed for the reader thread being preempted between the two), or, when the consumer missed
    frame 0, after the source was opened (``t_open_ns``, monotonic): the camera's rate."""
    t0_ns = frames[0].t_capture_ns if frames[0].index == 0 else t_open_ns
    for f in frames:
        assert (f.t_capture_ns - t0_ns) / 1e9 >= f.index / fps - max(EARLY_S, 0.5 / fps), f.index


def _accounted(source, frames, total):
    """Every frame of the recording was handed out, dropped (missed by the consumer), late
    (decoded after its successor was due) or unreadable: none lost without a count."""
    st = source.stats
    assert st.frames == len(frames)
    assert st.frames + st.dropped + st.late + st.unreadable == total, st


# --- each kind of recording, through open_source ----------------------------------------------


def test_paced_file_through_open_source_delivers_each_frame_at_the_rate(clip60):
    src = open_source(CaptureConfig(source="file", path=clip60, pace=True, fps=50.0))
    assert isinstance(src, PacedSource) and isinstance(src.recording, VideoFileSource)
    assert not src.recording.loop
    t_open = time.monotonic_ns()
    with src:
        frames = _read_all(src)
    elapsed = (time.monotonic_ns() - t_open) / 1e9
    _accounted(src, frames, 60)
    _never_early(frames, 50.0, t_open)
    assert elapsed >= 59 / 50.0 - EARLY_S  # the last frame is due 59 periods after the first
    assert [_painted_index(f.image) for f in frames] == [f.index for f in frames]  # each index is its image
    assert frames[-1].index == 59  # the last frame is never replaced, so never dropped
    assert all(b.index > a.index for a, b in zip(frames, frames[1:]))


def test_paced_looping_folder_keeps_counting_at_the_rate(tmp_path):
    path = _folder(tmp_path / "f", 4)
    src = open_source(CaptureConfig(source="folder", path=path, pace=True, fps=100.0, loop=True))
    assert isinstance(src.recording, ImageFolderSource) and src.recording.loop
    t_open = time.monotonic_ns()
    with src:
        frames = _read_all(src, limit=15)
        missed = src.stats.dropped + src.stats.late
    _never_early(frames, 100.0, t_open)
    assert frames[-1].index >= 14  # past the folder's 4 images: the loop goes on counting
    assert [int(f.image[0, 0, 0]) for f in frames] == [_level(f.index % 4) for f in frames]
    assert missed == frames[-1].index + 1 - len(frames)  # each index not handed out was counted


def test_paced_synthetic_scene_is_the_unpaced_scene_at_the_rate():
    cfg = SyntheticSceneConfig(seed=4, width=160, height=120, fps=40.0, frames=12)
    with SyntheticSource(cfg) as unpaced:
        scene = [f.image for f in unpaced]
    src = open_source(CaptureConfig(source="synthetic", pace=True, fps=5.0, synthetic=cfg))
    assert isinstance(src.recording, SyntheticSource) and src.fps == 40.0  # the scene's own rate
    t_open = time.monotonic_ns()
    with src:
        frames = _read_all(src)
    _accounted(src, frames, 12)
    _never_early(frames, 40.0, t_open)
    assert frames[-1].index == 11
    for f in frames:  # stamped at delivery, but the same scene frame as read unpaced
        assert np.array_equal(f.image, scene[f.index])


def test_unpaced_config_gives_the_unpaced_reader(clip60, tmp_path):
    # a file or folder decoded ahead on its own thread (tests/test_readahead.py); the scene as it is
    src = open_source(CaptureConfig(source="file", path=clip60))
    assert type(src) is ReadAhead and type(src.recording) is VideoFileSource
    assert type(open_source(CaptureConfig(source="synthetic"))) is SyntheticSource


def test_unreadable_images_keep_their_time_and_are_counted(tmp_path):
    path = _folder(tmp_path / "f", 8, corrupt=(2, 5))
    src = open_source(CaptureConfig(source="folder", path=path, pace=True, fps=50.0))
    t_open = time.monotonic_ns()
    with src:
        frames = _read_all(src)
    assert src.stats.unreadable == 2
    _accounted(src, frames, 8)
    assert not {2, 5} & {f.index for f in frames}
    _never_early(frames, 50.0, t_open)  # frame 3 still waits for its own time after 2's passed empty


# --- a consumer or a recording slower than the rate ---------------------------------------------


def test_a_slow_consumer_gets_the_newest_frame_and_the_missed_ones_are_dropped(tmp_path):
    path = _folder(tmp_path / "f", 30)
    src = open_source(CaptureConfig(source="folder", path=path, pace=True, fps=100.0))
    with src:
        frames = _read_all(src, consume_s=0.05)  # five periods per frame
    _accounted(src, frames, 30)
    assert src.stats.dropped >= 10, src.stats  # ~4 of every 5 frames came while the consumer was busy
    assert len(frames) <= 15
    assert frames[-1].index == 29  # the end is handed out, not dropped
    assert [int(f.image[0, 0, 0]) for f in frames] == [_level(f.index) for f in frames]


def test_a_paced_synthetic_scene_drops_what_a_slow_consumer_misses():
    """Unlike its earlier pacing, which waited for the consumer: a camera does not wait."""
    cfg = SyntheticSceneConfig(seed=5, width=160, height=120, fps=25.0, frames=20)
    src = open_source(CaptureConfig(source="synthetic", pace=True, synthetic=cfg))
    with src:
        frames = _read_all(src, consume_s=0.12)  # three periods per frame
    _accounted(src, frames, 20)
    # waiting for the consumer, it handed out all 20; a loaded machine may make some late instead
    assert len(frames) <= 12 and src.stats.dropped >= 3, src.stats
    assert frames[-1].index == 19


class _SlowFolder(ImageFolderSource):
    """An image folder whose images ``slow`` take ``delay_s`` to decode (a slow disk or codec)."""

    def __init__(self, path, slow, delay_s, fail_at=None):
        super().__init__(path)
        self.slow, self.delay_s, self.fail_at = slow, delay_s, fail_at

    def _next_image(self):
        if self._pos == self.fail_at:
            raise SourceError("%s: the disk went away" % self.path)
        if self._pos in self.slow:
            time.sleep(self.delay_s)
        return super()._next_image()


def test_a_frame_decoded_after_its_successor_was_due_is_late_skipped_and_counted(tmp_path):
    path = _folder(tmp_path / "f", 12)
    # frame 6's decoding starts when frame 5 is handed out (due at 5 periods) and ends 2.5 periods
    # later, after frame 7 was due: skipped. Frame 7 is decoded half a period after its time.
    src = PacedSource(_SlowFolder(path, slow={6}, delay_s=0.125), fps=20.0)
    with src:
        frames = _read_all(src)
    _accounted(src, frames, 12)
    assert src.stats.late >= 1 and 6 not in [f.index for f in frames], src.stats
    assert frames[-1].index == 11
    assert src.stats.late <= 3  # the frames after it are on time again (the clock does not drift)


def test_the_last_frame_is_handed_out_even_late(tmp_path):
    """Nothing newer is coming to replace it: frame 3 is decoded from 2 periods on for 3 periods,
    after its (missing) successor's time, and still goes out."""
    path = _folder(tmp_path / "f", 4)
    src = PacedSource(_SlowFolder(path, slow={3}, delay_s=0.15), fps=20.0)
    with src:
        frames = _read_all(src)
    assert frames[-1].index == 3 and int(frames[-1].image[0, 0, 0]) == _level(3)
    assert src.stats.late == 0
    _accounted(src, frames, 4)


# --- a recording is finite: its end ends the stream; it is never a lost camera -------------------


def test_the_end_of_the_recording_ends_the_stream_after_its_last_frame(tmp_path):
    path = _folder(tmp_path / "f", 5)
    src = open_source(CaptureConfig(source="folder", path=path, pace=True, fps=100.0))
    with src:
        time.sleep(0.3)  # the whole recording played while nobody read
        last = src.read(timeout_s=1.0)
        t = time.monotonic()
        with pytest.raises(EndOfStream):
            src.read(timeout_s=5.0)
        assert time.monotonic() - t < 1.0  # ends at once, no timeout waited
    assert last.index == 4 and int(last.image[0, 0, 0]) == _level(4)
    assert src.stats.dropped == 4 and src.stats.reconnects == 0
    assert not src.stats.connected


def test_a_slow_first_frame_is_waited_for_not_a_lost_camera(tmp_path, caplog):
    """The stall window of a camera (here 20 ms) does not apply: the scene's set-up or a slow disk
    is not a loss, and the rate's clock starts at the first frame, so the next ones are on time."""
    path = _folder(tmp_path / "f", 6)
    stats = SourceStats()
    recording = _SlowFolder(path, slow={0}, delay_s=0.4)
    recording.open()
    # a camera delivering every 50 ms would be lost after 20 ms without a frame
    reader = LiveReader(None, Retry(initial_s=0.01, max_s=0.01), stats, "slow-start", stall_s=0.02, poll_s=0.01,
                        finite=True)
    caplog.set_level(logging.DEBUG, logger="payload.capture")
    reader.start(PacedGrabber(recording, 20.0, stats))
    frames = []
    try:
        while True:
            frame = reader.read(timeout_s=2.0)
            assert frame is not None or frames, "no first frame within 2 s"
            if frame is not None:
                frames.append(frame)
    except EndOfStream:
        pass
    finally:
        reader.stop()
    assert [f.index for f in frames][0] == 0 and frames[-1].index == 5
    assert stats.frames + stats.dropped + stats.late == 6
    assert stats.late == 0 and stats.reconnects == 0
    assert "camera lost" not in caplog.text and "recording failed" not in caplog.text


def test_a_recording_that_fails_mid_way_ends_the_stream_with_one_line(tmp_path, caplog):
    path = _folder(tmp_path / "f", 8)
    src = PacedSource(_SlowFolder(path, slow=(), delay_s=0.0, fail_at=4), fps=100.0)
    caplog.set_level(logging.WARNING, logger="payload.capture")
    with src:
        frames = _read_all(src)
    assert frames[-1].index == 3 and src.stats.reconnects == 0
    failed = [r.getMessage() for r in caplog.records if "recording failed" in r.getMessage()]
    assert len(failed) == 1 and "the disk went away" in failed[0]


def test_a_missing_recording_is_reported_at_open(tmp_path):
    src = open_source(CaptureConfig(source="file", path=str(tmp_path / "none.mp4"), pace=True))
    with pytest.raises(SourceError, match="none.mp4"):
        src.open()


# --- glad-payload bench --paced ----------------------------------------------------------------


def test_bench_paced_plays_the_clip_through_the_paced_source(tmp_path, capsys, caplog):
    """``bench --paced 10`` on a 6-frame clip: the service's paced source, the loop never runs
    ahead of the camera's rate, and every frame is processed, dropped or late (its counts)."""
    from onnx_factories import brightness_classifier

    from payload.cli import main
    from payload.config import load_config
    from payload.detect.factory import builtin_model_path
    from payload.offline import synthetic_clip

    for name in ("global", "local"):
        if not os.path.isfile(builtin_model_path(name)):
            pytest.skip("shipped model %s not in the package" % name)
    data = {"capture": {"synthetic": {"width": 192, "height": 160, "seed": 3}},
            "detector": {"threads": 1, "classifier": {"model": brightness_classifier(tmp_path / "cls.onnx")}}}
    config = tmp_path / "bench.yaml"
    config.write_text(yaml.safe_dump(data))
    clip = synthetic_clip(load_config(str(config)), str(tmp_path / "clip"), 6)
    out = tmp_path / "paced.json"
    caplog.set_level(logging.INFO, logger="payload.capture")
    assert main(["bench", clip.video, "-c", str(config), "--paced", "10", "--no-stream", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["paced_fps"] == 10
    assert report["frames"] + report["frames_dropped"] + report["frames_late"] == 6
    n = report["frames"]
    assert n >= 2 and n / report["fps_end_to_end"] >= (n - 1) / 10.0 - EARLY_S  # never faster than the camera
    assert "late %d" % report["frames_late"] in capsys.readouterr().out
    assert "played as a camera source=PacedVideoFileSource fps=10" in caplog.text

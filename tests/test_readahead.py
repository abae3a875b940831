"""payload.capture.readahead: an unpaced file or folder decoded ahead on its own thread. Every
frame, in order, as the plain reader gives them; the end and a failure mid-way arrive in order;
close() stops a thread blocked on a full queue."""

import threading
import time

import numpy as np
import pytest
from test_capture import _level, _painted_index, _write_clip  # the test clips and their frame marks

from payload.capture import open_source
from payload.capture.base import EndOfStream, FrameSource
from payload.capture.file import VideoFileSource
from payload.capture.readahead import ReadAhead
from payload.config import CaptureConfig
from payload.errors import SourceError
from payload.types import Frame


@pytest.fixture(scope="module")
def clip30(tmp_path_factory):
    return _write_clip(tmp_path_factory.mktemp("ahead") / "clip30.mp4", 30)


def _all(source):
    frames = []
    while True:
        try:
            frame = source.read(timeout_s=5.0)
        except EndOfStream:
            return frames
        assert frame is not None, "no frame within 5 s"
        frames.append(frame)


def test_every_frame_in_order_with_the_plain_readers_stamps(clip30):
    with VideoFileSource(clip30) as plain:
        expected = _all(plain)
    src = open_source(CaptureConfig(source="file", path=clip30))
    with src:
        got = _all(src)
        with pytest.raises(EndOfStream):  # and again: the end stays the end
            src.read()
    assert [f.index for f in got] == list(range(30)) == [_painted_index(f.image) for f in got]
    offsets = [f.t_capture_ns - got[0].t_capture_ns for f in got]
    assert offsets == [f.t_capture_ns - expected[0].t_capture_ns for f in expected]  # the file's timeline
    assert src.stats.frames == 30 and not src.stats.connected


def test_looping_file_keeps_counting(clip30):
    with open_source(CaptureConfig(source="file", path=clip30, loop=True)) as src:
        indices = [src.read(timeout_s=5.0).index for _ in range(70)]
    assert indices == list(range(70))


class _Scripted(FrameSource):
    """Frames 0..n-1, an unreadable one (None) at ``gap``, then ``end`` raised; records the thread
    that decodes each frame and whether it was closed."""

    def __init__(self, n, end=EndOfStream, gap=None):
        super().__init__()
        self.n, self.end, self.gap = n, end, gap
        self.i = 0
        self.threads = set()
        self.closed = False

    def open(self):
        self.i = 0

    def read(self, timeout_s=1.0):
        self.threads.add(threading.current_thread().name)
        if self.i >= self.n:
            raise self.end() if isinstance(self.end, type) else self.end
        i, self.i = self.i, self.i + 1
        if i == self.gap:
            self.stats.unreadable += 1
            return None
        return Frame(np.full((4, 4, 3), _level(i), np.uint8), i, i, i)

    def close(self):
        self.closed = True


def test_decoding_runs_on_its_own_thread_ahead_of_the_consumer():
    rec = _Scripted(10)
    with ReadAhead(rec, depth=4) as src:
        deadline = time.monotonic() + 5.0
        while rec.i < 5 and time.monotonic() < deadline:  # nobody reads: the thread fills the queue
            time.sleep(0.01)
        assert rec.i == 5  # 4 queued, the 5th waiting for room: bounded, not the whole file
        assert threading.current_thread().name not in rec.threads
        assert [f.index for f in _all(src)] == list(range(10))


def test_a_failure_mid_way_comes_after_the_frames_before_it_and_an_unreadable_frame_is_counted():
    rec = _Scripted(6, end=SourceError("clip.mp4: decoding failed at frame 6"), gap=2)
    with ReadAhead(rec) as src:
        got = []
        with pytest.raises(SourceError, match="decoding failed at frame 6"):
            while True:
                frame = src.read(timeout_s=5.0)
                assert frame is not None
                got.append(frame.index)
        assert got == [0, 1, 3, 4, 5]
        assert src.stats.unreadable == 1
        with pytest.raises(SourceError):  # it stays failed
            src.read()


def test_close_stops_a_thread_blocked_on_a_full_queue_and_closes_the_recording():
    rec = _Scripted(1000)
    src = ReadAhead(rec, depth=2)
    src.open()
    assert src.read(timeout_s=5.0).index == 0
    time.sleep(0.05)
    t = time.monotonic()
    src.close()
    assert time.monotonic() - t < 1.0 and rec.closed
    assert not any(th.name.startswith("decode-") for th in threading.enumerate())
    with pytest.raises(SourceError, match="read before open"):
        src.read()


def test_a_missing_file_is_reported_at_open_in_one_line(tmp_path):
    src = open_source(CaptureConfig(source="file", path=str(tmp_path / "none.mp4")))
    with pytest.raises(SourceError) as info:
        src.open()
    assert "none.mp4" in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("pace", [False, True])
def test_frames_are_prepared_on_the_capture_thread(clip30, pace):
    # issue 19: work the detector will need (GLAD: GAD's down-scaled input) is done on the thread
    # that decodes, read ahead or played at camera rate, not on the consumer's
    done = {}

    def prepare(frame):
        done[frame.index] = threading.current_thread().name
        frame.prepared["mark"] = int(frame.image[0, 0, 0])

    src = open_source(CaptureConfig(source="file", path=clip30, pace=pace, fps=200.0))
    src.prepare = prepare
    with src:
        got = _all(src)
    assert got and all(f.prepared["mark"] == int(f.image[0, 0, 0]) for f in got)
    assert all(done[f.index] != threading.current_thread().name for f in got)


@pytest.mark.parametrize("pace", [False, True])
def test_a_failing_prepare_is_logged_once_and_frames_go_on_unprepared(clip30, pace, caplog):
    def prepare(frame):
        frame.prepared["half"] = 1
        raise ValueError("broken on purpose")

    src = open_source(CaptureConfig(source="file", path=clip30, pace=pace, fps=200.0))
    src.prepare = prepare
    with caplog.at_level("WARNING"), src:
        got = _all(src)
    assert len(got) >= 20 and all(f.prepared == {} for f in got)  # nothing half-made goes out
    lines = [r.getMessage() for r in caplog.records if "preparing a frame failed" in r.getMessage()]
    assert len(lines) == 1 and "ValueError: broken on purpose" in lines[0]

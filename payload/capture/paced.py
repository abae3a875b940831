"""A recording played as a live camera: frames at a fixed rate, whether anybody reads them or not.

Every ``capture.pace: true`` source comes through here (``open_source``), and so does
``glad-payload bench --paced FPS``: a video file, an image folder or the synthetic scene is read
by its own unpaced reader (payload.capture.file, payload.capture.synthetic) on the thread of a
``LiveReader``, the one behind every camera. ``PacedGrabber`` decodes one frame ahead and holds
it until its time: frame k (the recording's index) is due at ``t0 + k / fps``, the clock starting
when the first frame is decoded (a slow start, such as the scene's set-up, is no delay). Each
frame is stamped at delivery as a camera frame is, and keeps the recording's index.

As with a camera, the consumer gets the newest frame; one it did not take before the next
arrived is dropped and counted (``stats.dropped``). A frame decoded only after its successor was
due is skipped as well and counted apart (``stats.late``): the source, not the consumer, fell
behind; only the recording's last frame, with nothing newer to come, is handed out late. A
recording slower than the rate on every frame therefore delivers little but its last frame, and
``late`` says why. A recording is finite and is not a camera to reconnect: however long
a frame takes it is waited for, and the end of the recording ends the stream (``read()`` raises
EndOfStream once the last frame was read).

Compared with the earlier per-source pacing: frames that became stale are counted as ``late``
when the source fell behind (``dropped`` when the consumer did), and a paced synthetic scene
drops the frames a slow consumer misses, as a camera would, instead of waiting for it.
"""

import logging
import time
from typing import Optional

import numpy as np

from payload.capture.base import EndOfStream, FrameSource, SourceStats
from payload.capture.live import Grabber, LiveReader
from payload.config import Retry
from payload.errors import SourceError
from payload.types import Frame

log = logging.getLogger(__name__)


class PacedGrabber(Grabber):
    """The frames of an opened, unpaced recording (any finite FrameSource: file, folder, synthetic
    scene) at ``fps``, each held until its time; ``late`` and ``unreadable`` go to ``stats``."""

    def __init__(self, recording: FrameSource, fps: float, stats: SourceStats) -> None:
        if not fps > 0:
            raise SourceError("capture.fps: %r: expected a positive frame rate" % (fps,))
        self._recording = recording
        self._period_s = 1.0 / float(fps)
        self._stats = stats
        self._t0: Optional[float] = None  # when the first frame was decoded: its due time
        self._index0 = 0  # the recording's index of that frame
        self._next: Optional[Frame] = None  # decoded, waiting for its time
        self._late: Optional[Frame] = None  # decoded after its successor was due: skipped if one comes

    def grab(self, timeout_s: float) -> Optional[np.ndarray]:
        """One step per call (LiveReader checks for stop between calls): decode the next frame,
        or wait up to timeout_s for the held one's time. EndOfStream at the end of the recording."""
        if self._next is None:
            self._next = self._decode(timeout_s)
            if self._next is None:
                return None
        wait_s = self._due(self._next.index) - time.monotonic()
        if wait_s > timeout_s:
            time.sleep(max(0.0, timeout_s))
            return None
        if wait_s > 0:
            time.sleep(wait_s)
        frame, self._next = self._next, None
        self.index = frame.index
        return frame.image

    def _decode(self, timeout_s: float) -> Optional[Frame]:
        """The next frame to hand out, or None: unreadable, or late (held until a newer one comes)."""
        try:
            frame = self._recording.read(timeout_s)
        except EndOfStream:
            if self._late is None:
                raise
            frame, self._late = self._late, None  # the last frame: nothing newer is coming, it goes out late
            return frame
        self._stats.unreadable = self._recording.stats.unreadable
        if frame is None:  # an unreadable frame: its time passes without a frame
            return None
        if self._t0 is None:
            self._t0, self._index0 = time.monotonic(), frame.index
        if self._late is not None:  # a newer frame came: the late one is skipped
            self._stats.late += 1
            self._late = None
        if time.monotonic() > self._due(frame.index + 1):  # its successor is due already
            self._late = frame
            return None
        return frame

    def _due(self, index: int) -> float:
        return self._t0 + (index - self._index0) * self._period_s

    def close(self) -> None:
        self._recording.close()


class PacedSource(FrameSource):
    """An unpaced recording (not yet opened) delivered at ``fps`` like a camera (see the module doc)."""

    live = True

    def __init__(self, recording: FrameSource, fps: float) -> None:
        super().__init__()
        if not fps > 0:
            raise SourceError("capture.fps: %r: expected a positive frame rate" % (fps,))
        self.recording = recording
        self.fps = float(fps)
        self._reader: Optional[LiveReader] = None

    @property
    def name(self) -> str:
        return "Paced" + self.recording.name

    def open(self) -> None:
        if self._reader is not None:
            return
        self.recording.open()  # a missing or unreadable recording is reported here, at once
        grabber = PacedGrabber(self.recording, self.fps, self.stats)
        self._reader = LiveReader(None, Retry(), self.stats, self.name, finite=True, prepare=self._prepared)
        self._reader.start(grabber)
        log.info("recording played as a camera source=%s fps=%g", self.name, self.fps)

    def read(self, timeout_s: float = 1.0) -> Optional[Frame]:
        if self._reader is None:
            raise SourceError("%s: read before open()" % self.name)
        return self._reader.read(timeout_s)

    def close(self) -> None:
        if self._reader is not None:
            self._reader.stop()  # the thread closes the recording as it ends
            self._reader = None

"""A recording played as a live camera: frames at a fixed rate, whether anybody reads them or not.

``PacedRecording(path, fps)`` decodes a video file or image folder on its own thread (the
``LiveReader`` behind every camera) and delivers frame k at ``t0 + k / fps``: each frame is
decoded ahead and held until its time, then stamped at delivery as a camera frame is. The
consumer gets the newest frame; one it did not take before the next arrived is dropped and
counted (``stats.dropped``), as with a camera. A frame decoded only after its successor was due
is skipped as well and counted apart (``late``): the source, not the consumer, fell behind.
The end of the recording ends the stream (``read()`` raises EndOfStream).

``glad-payload bench --paced FPS`` measures the payload on it: what a camera at that rate would
see of the detector's speed (frames dropped, capture-to-MAVLink latency).
"""

import os
import time
from typing import Optional

import numpy as np

from payload.capture.base import FrameSource
from payload.capture.file import ImageFolderSource, VideoFileSource
from payload.capture.live import Grabber, LiveReader
from payload.config import Retry
from payload.errors import SourceError
from payload.types import Frame


class PacedGrabber(Grabber):
    """The frames of an opened, unpaced recording at ``fps``, each held until its time."""

    def __init__(self, recording, fps: float) -> None:
        if not fps > 0:
            raise SourceError("paced source: %r: expected a positive frame rate" % (fps,))
        self._recording = recording
        self._period_s = 1.0 / float(fps)
        self._t0: Optional[float] = None
        self._slot = 0  # the delivery slot of the next frame
        self._image: Optional[np.ndarray] = None  # decoded, waiting for its slot
        self.late = 0  # frames decoded after the next one was due: skipped

    def grab(self, timeout_s: float) -> Optional[np.ndarray]:
        if self._t0 is None:
            self._t0 = time.monotonic()
        while self._image is None:
            frame = self._recording.read(timeout_s)  # EndOfStream at the end
            if frame is not None and time.monotonic() <= self._due(self._slot + 1):
                self._image = frame.image
                break
            self.late += frame is not None  # an unreadable frame's slot passes without a frame
            self._slot += 1
        wait_s = self._due(self._slot) - time.monotonic()
        if wait_s > timeout_s:
            time.sleep(max(0.0, timeout_s))
            return None
        if wait_s > 0:
            time.sleep(wait_s)
        image, self._image = self._image, None
        self._slot += 1
        return image

    def _due(self, slot: int) -> float:
        return self._t0 + slot * self._period_s

    def close(self) -> None:
        self._recording.close()


class PacedRecording(FrameSource):
    """A video file or image folder delivered at ``fps`` like a camera (see the module doc)."""

    live = True

    def __init__(self, path: str, fps: float) -> None:
        super().__init__()
        self.path = path
        self.fps = float(fps)
        self._grabber: Optional[PacedGrabber] = None
        self._reader: Optional[LiveReader] = None

    @property
    def late(self) -> int:
        """Frames skipped because decoding fell behind the rate."""
        return self._grabber.late if self._grabber is not None else 0

    def open(self) -> None:
        if self._reader is not None:
            return
        kind = ImageFolderSource if os.path.isdir(self.path) else VideoFileSource
        recording = kind(self.path, fps=self.fps)
        recording.open()
        self._grabber = PacedGrabber(recording, self.fps)

        def reconnect():  # a recording that failed mid-way is not reopened
            raise SourceError("paced source: %s: cannot be played again" % self.path)

        self._reader = LiveReader(reconnect, Retry(), self.stats, "paced", finite=True)
        self._reader.start(self._grabber)

    def read(self, timeout_s: float = 1.0) -> Optional[Frame]:
        if self._reader is None:
            raise SourceError("paced source: %s: read before open()" % self.path)
        return self._reader.read(timeout_s)

    def close(self) -> None:
        if self._reader is not None:
            self._reader.stop()
            self._reader = None

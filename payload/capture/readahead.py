"""A recording decoded on its own thread, a few frames ahead of the detector (issue 19).

Unpaced, a video file or image folder is read as fast as the consumer asks; decoding in the
consumer's thread adds its whole cost to every frame (1-2 ms of H.264 at 640x512, several at
1080p). Here a thread decodes up to ``depth`` frames ahead into a queue, so decoding overlaps
detection on another core. Nothing is dropped and the order is kept (offline runs score every
frame); frames keep the recording's own timeline stamps. The recording's end, and an error while
decoding (a file that breaks mid-way), reach the consumer in order, after the frames before them.

The synthetic scene is not wrapped: the demo reads its ground truth (``last_truth``) beside the
frame just read. Played at camera rate (``capture.pace``), a recording already has its own thread
(payload.capture.paced).
"""

import logging
import queue
import threading
from typing import Optional

from payload.capture.base import EndOfStream, FrameSource
from payload.errors import SourceError
from payload.types import Frame

log = logging.getLogger(__name__)

_END = object()


class ReadAhead(FrameSource):
    """``recording`` (an unpaced, not yet opened FrameSource) decoded ``depth`` frames ahead."""

    live = False

    def __init__(self, recording: FrameSource, depth: int = 4) -> None:
        super().__init__()
        self.recording = recording
        self._queue: queue.Queue = queue.Queue(maxsize=max(1, depth))
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._ended: Optional[BaseException] = None

    @property
    def name(self) -> str:
        return self.recording.name

    def open(self) -> None:
        if self._thread is not None:
            return
        self.recording.open()  # a missing or unreadable file is reported here, at once
        self._stop.clear()
        self._ended = None
        self.stats.connected = True
        self._thread = threading.Thread(target=self._run, name="decode-" + self.name, daemon=True)
        self._thread.start()

    def _put(self, item) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self.recording.read(timeout_s=1.0)
            except EndOfStream:
                self._put(_END)
                return
            except Exception as exc:  # noqa: BLE001 - handed to the consumer, raised there in order
                self._put(exc)
                return
            if frame is not None and not self._put(self._prepared(frame)):
                return

    def read(self, timeout_s: float = 1.0) -> Optional[Frame]:
        if self._thread is None:
            raise SourceError("%s: read before open()" % self.name)
        if self._ended is not None:
            raise self._ended
        try:
            item = self._queue.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            return None
        self.stats.unreadable = self.recording.stats.unreadable
        if item is _END:
            self._ended = EndOfStream()
            raise self._ended
        if isinstance(item, BaseException):
            self._ended = item
            raise item
        self.stats.frames += 1
        return item

    def close(self) -> None:
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stop.set()
            thread.join(timeout=5.0)
            while not self._queue.empty():
                self._queue.get_nowait()
            if thread.is_alive():  # still inside the decoder: closing the file under it could crash
                log.warning("%s: the decoding thread did not stop within 5 s; the file is left open", self.name)
                return
        self.stats.connected = False
        self.recording.close()

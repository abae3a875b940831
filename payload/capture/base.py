"""The one interface every frame source implements.

Offline use iterates (``for frame in source``); the service loop calls ``read(timeout_s)`` so
that it keeps control while a live camera is lost and being reconnected.
"""

import abc
import logging
import time
from dataclasses import dataclass
from typing import Callable, Iterator, Optional

from payload.types import Frame

log = logging.getLogger(__name__)


class EndOfStream(Exception):
    """A finite source (file, folder, synthetic clip, paced or not) has no more frames."""


@dataclass
class SourceStats:
    frames: int = 0  # frames handed out by read()/iteration
    dropped: int = 0  # frames captured but replaced by a newer one before being read
    late: int = 0  # paced recordings: frames decoded after their successor was due, skipped
    reconnects: int = 0  # successful re-opens after a loss
    unreadable: int = 0  # recorded frames that could not be decoded (corrupt or empty image), skipped
    connected: bool = False


class FrameSource(abc.ABC):
    """A camera or recording delivering ``Frame`` objects with monotonic capture times."""

    #: True for cameras/pipelines (newest frame wins, loss is retried), False for recordings.
    live = False

    def __init__(self) -> None:
        self.stats = SourceStats()
        #: Called on each new frame by a source with a thread of its own (a camera, a recording read
        #: ahead or played at camera rate) before the consumer gets it, so that work the consumer
        #: will need (GLAD: grey levels, camera motion, GAD's input) runs on another core (issue 19); None: nothing.
        self.prepare: Optional[Callable[[Frame], None]] = None
        self._prepare_failed = False

    def _prepared(self, frame: Frame) -> Frame:
        """``frame`` after ``prepare``; a failing prepare is logged once and the frame goes on
        without it (the consumer does the work itself): capture never stops for it."""
        prepare = self.prepare
        if prepare is not None:
            try:
                prepare(frame)
            except Exception as exc:  # noqa: BLE001 - whatever it was, the frame still goes out
                frame.prepared.clear()
                if not self._prepare_failed:
                    self._prepare_failed = True
                    log.warning("source=%s preparing a frame failed (frames go on unprepared): %s: %s",
                                self.name, type(exc).__name__, exc)
        return frame

    @property
    def name(self) -> str:
        return type(self).__name__

    @abc.abstractmethod
    def open(self) -> None:
        """Open the source; raise SourceError with a one-line message if it cannot be opened."""

    @abc.abstractmethod
    def read(self, timeout_s: float = 1.0) -> Optional[Frame]:
        """The next frame (for live sources: the newest one).

        Returns None when no new frame arrived within timeout_s (a live source that is
        reconnecting, or a recording whose next image could not be decoded: skipped and
        counted in ``stats.unreadable``); raises EndOfStream when a finite source is exhausted.
        """

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device/file; safe to call twice."""

    def __enter__(self) -> "FrameSource":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self) -> Iterator[Frame]:
        while True:
            try:
                frame = self.read(timeout_s=1.0)
            except EndOfStream:
                return
            if frame is not None:
                yield frame


def now_ns():
    """(monotonic, wall) clock pair in ns, read together at capture time."""
    return time.monotonic_ns(), time.time_ns()

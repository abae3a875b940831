"""The reader thread behind every live source (V4L2 camera, GStreamer camera pipeline).

A camera does not wait for the detector: a thread grabs continuously, stamps each image with
``now_ns()`` at grab and keeps only the newest one, counting the ones replaced before anybody
read them. When the camera is lost it logs once, reconnects with exponential back-off and logs
the recovery; meanwhile ``read()`` returns None so that the service loop keeps control.
A finite source played as a camera (``finite``: a recording at camera rate, payload.capture.paced)
is never lost: a slow frame is waited for however long it takes, and the end of the recording
(or a recording that fails mid-way, logged) ends the stream: once its last frame was read,
``read()`` raises EndOfStream.
"""

import logging
import threading
import time
from typing import Callable, Optional

import numpy as np

from payload.capture.base import EndOfStream, SourceStats, now_ns
from payload.config import Retry
from payload.errors import CameraLost, PayloadError
from payload.types import Frame

log = logging.getLogger(__name__)

_END = "end of stream"


class Grabber:
    """One open connection to a camera. ``LiveReader`` calls it from its thread only."""

    #: The frame index of the image last grabbed, for a source that has its own numbering (a paced
    #: recording: the recording's index, so frames it skipped leave gaps); None: numbered by the reader.
    index = None  # type: Optional[int]

    def grab(self, timeout_s: float) -> Optional[np.ndarray]:
        """The next BGR image; None when none came within timeout_s; CameraLost when the camera is gone."""
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class LiveReader:
    """Keeps the newest frame of a camera, reconnecting with back-off when it is lost.

    ``connect()`` opens a new ``Grabber`` or raises a PayloadError (SourceError) saying why.
    ``stall_s``: a camera that delivers nothing for this long counts as lost, even without an error.
    ``finite``: a recording, not a camera: never stalled nor reconnected (``connect`` may be None);
    the grabber's EndOfStream, or its failure, ends the stream.
    """

    def __init__(
        self,
        connect: Optional[Callable[[], Grabber]],
        retry: Retry,
        stats: SourceStats,
        name: str,
        stall_s: float = 5.0,
        poll_s: float = 0.1,
        finite: bool = False,
        prepare: Optional[Callable[[Frame], Frame]] = None,
    ) -> None:
        self._connect = connect
        self._retry = retry
        self._stats = stats
        self._name = name
        self._stall_s = stall_s
        self._poll_s = poll_s
        self._finite = finite
        self._prepare = prepare  # the source's FrameSource._prepared: work done ahead, on this thread
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._latest = None  # type: Optional[Frame]
        self._latest_read = True
        self._next_index = 0
        self._thread = None  # type: Optional[threading.Thread]
        self._closed = False

    def start(self, grabber: Grabber) -> None:
        """Start the thread on an already open connection (so open() reports a bad device at once)."""
        self._stats.connected = True
        self._thread = threading.Thread(target=self._run, args=(grabber,), name="capture-" + self._name, daemon=True)
        self._thread.start()

    def read(self, timeout_s: float) -> Optional[Frame]:
        """The newest frame not yet read; None if none arrived within timeout_s."""
        deadline = time.monotonic() + max(0.0, timeout_s)
        with self._cond:
            while self._latest_read:
                if self._closed:
                    raise EndOfStream()
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)
            self._latest_read = True
            self._stats.frames += 1
            return self._latest

    def stop(self, join_s: float = 5.0) -> None:
        self._stop.set()
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(join_s)
            if self._thread.is_alive():
                log.warning("capture thread did not stop source=%s join_s=%.1f", self._name, join_s)
            self._thread = None

    # --- the thread -------------------------------------------------------------------------

    def _run(self, grabber: Optional[Grabber]) -> None:
        while not self._stop.is_set():
            if grabber is not None:
                reason = self._pump(grabber)
                self._close_quietly(grabber)
                grabber = None
                if self._stop.is_set():
                    break
                if self._finite:
                    if reason != _END:  # a recording is not reopened: what it delivered is what there is
                        log.warning("recording failed, stream ended source=%s reason=%s", self._name, reason)
                    with self._cond:  # read() hands out the last frame, then raises EndOfStream
                        self._closed = True
                        self._cond.notify_all()
                    break
                with self._cond:
                    self._stats.connected = False
                log.warning("camera lost source=%s reason=%s retry_in_s=%.2f", self._name, reason, self._retry.initial_s)
            grabber = self._reconnect()
        if grabber is not None:
            self._close_quietly(grabber)
        with self._cond:
            self._stats.connected = False

    def _pump(self, grabber: Grabber) -> str:
        """Grab until the camera is lost or we are stopped; returns why it ended."""
        last_s = time.monotonic()
        while not self._stop.is_set():
            try:
                image = grabber.grab(self._poll_s)
            except CameraLost as exc:
                return str(exc)
            except EndOfStream:  # a camera pipeline that ends has lost its camera (unless finite)
                return _END
            except Exception as exc:  # a driver error mid-stream is a loss, not a crash of the thread
                return "%s: %s" % (type(exc).__name__, exc)
            if image is None:
                # a recording waits for its next frame's time, or decodes slowly (a first frame
                # seconds away): that is no lost camera, and its end comes as EndOfStream
                if not self._finite and time.monotonic() - last_s > self._stall_s:
                    return "no frame for %.1f s" % self._stall_s
                continue
            t_capture_ns, t_wall_ns = now_ns()
            last_s = time.monotonic()
            index = grabber.index if grabber.index is not None else self._next_index
            frame = Frame(image=image, index=index, t_capture_ns=t_capture_ns, t_wall_ns=t_wall_ns)
            if self._prepare is not None:
                frame = self._prepare(frame)
            with self._cond:
                self._next_index = index + 1
                if not self._latest_read:
                    self._stats.dropped += 1
                self._latest = frame
                self._latest_read = False
                self._cond.notify_all()
        return "stopped"

    def _reconnect(self) -> Optional[Grabber]:
        """Try to reopen, waiting initial_s, then doubling up to max_s between attempts."""
        delay_s = self._retry.initial_s
        attempts = 0
        lost_s = time.monotonic()
        while not self._stop.wait(delay_s):
            attempts += 1
            try:
                grabber = self._connect()
            except PayloadError as exc:
                delay_s = min(delay_s * 2.0, self._retry.max_s)
                log.debug("reconnect failed source=%s attempt=%d error=%s retry_in_s=%.2f", self._name, attempts, exc, delay_s)
                continue
            with self._cond:
                self._stats.reconnects += 1
                self._stats.connected = True
            log.info(
                "camera recovered source=%s attempts=%d down_s=%.2f reconnects=%d",
                self._name, attempts, time.monotonic() - lost_s, self._stats.reconnects,
            )
            return grabber
        return None

    def _close_quietly(self, grabber: Grabber) -> None:
        try:
            grabber.close()
        except Exception as exc:  # closing a dead camera may fail; it is being dropped anyway
            log.debug("close after loss failed source=%s error=%s", self._name, exc)

"""Onboard recording for the flight review: H.264 in Matroska segments under a disk quota.

GStreamer's splitmuxsink cuts a new segment every ``recording.segment_s`` (at the next key frame,
one a second) or at a third of the quota, whichever comes first; after each cut, and once a
second, the oldest segments (of this run or earlier ones) are deleted while all of them together
exceed ``recording.quota_mb``. Matroska, not MP4: a segment cut short by a crash or a power loss
still plays (MP4 needs its index written at the end).

Names are ``glad-YYYYmmdd-HHMMSS-NNNNN.mkv`` (UTC start of the run, then the segment number), so
name order is time order across restarts. An unwritable folder at start, a full disk or any
other write error stops the recording with one log line; the detection loop never waits on it.
The decisions CSV is not written here (payload.records rotates it under outputs.directory).
"""

import glob
import logging
import os
import tempfile
import time
from typing import List, Optional, Tuple

import numpy as np

from payload.video import gst

log = logging.getLogger(__name__)

SEGMENT_GLOB = "glad-*.mkv"
_QUOTA_CHECK_S = 1.0


def _dir_problem(directory: str) -> Optional[str]:
    try:
        os.makedirs(directory, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=directory, prefix=".glad-rec-")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


class Recorder:
    """One recording pipeline (appsrc -> encoder -> splitmuxsink) and its quota."""

    def __init__(self, directory: str, segment_s: float, quota_mb: float, size_wh: Tuple[int, int], fps: float,
                 bitrate_kbps: int, encoder: str) -> None:
        problem = _dir_problem(directory)
        if problem is not None:
            raise gst.VideoUnavailable("recording.dir %s: %s" % (directory, problem))
        Gst, _ = gst.import_gst()
        self.directory = directory
        self.quota_bytes = int(quota_mb * 1e6)
        self.frames = 0  # frames queued for the encoder
        self.stopped: Optional[str] = None  # why recording stopped, once it has
        self._last_quota_check = 0.0
        self.deleted = 0  # segments deleted for the quota
        prefix = "glad-%s-" % time.strftime("%Y%m%d-%H%M%S", time.gmtime())
        self.pipeline = gst.OwnPipeline("%s ! %s ! splitmuxsink name=mux" % (
            gst.appsrc_text(size_wh, fps), gst.encoder_chain(encoder, bitrate_kbps, fps)))
        mux = self.pipeline.element("mux")
        mux.set_property("location", os.path.join(directory, prefix + "%05d.mkv"))
        mux.set_property("muxer", Gst.ElementFactory.make("matroskamux", None))
        mux.set_property("max-size-time", int(segment_s * 1e9))
        self._mux = mux
        self._set_segment_bytes()
        self._appsrc = self.pipeline.element("src")
        self._feed = gst.AppsrcFeed(self._appsrc, size_wh[0] * size_wh[1] * 3 // 2)
        self.pipeline.play()

    def _set_segment_bytes(self) -> None:
        # an open segment never holds more than a third of the quota, so deleting closed ones
        # always brings the total under it
        self._mux.set_property("max-size-bytes", max(1, self.quota_bytes // 3))

    @property
    def active(self) -> bool:
        return self.stopped is None

    @property
    def dropped(self) -> int:
        return self._feed.dropped

    def set_quota(self, quota_mb: float) -> None:
        self.quota_bytes = int(quota_mb * 1e6)
        self._set_segment_bytes()
        self.enforce_quota()

    def push(self, i420: np.ndarray) -> None:
        if self.stopped is None and self._feed.push(i420):
            self.frames += 1

    def segments(self) -> List[str]:
        """Every recording segment in the folder, oldest first."""
        return sorted(glob.glob(os.path.join(self.directory, SEGMENT_GLOB)))

    def enforce_quota(self) -> None:
        self._last_quota_check = time.monotonic()
        sizes = []
        for path in self.segments():
            try:
                sizes.append((path, os.path.getsize(path)))
            except OSError:
                pass  # deleted meanwhile
        total = sum(n for _, n in sizes)
        for path, n in sizes[:-1]:  # never the newest: it is being written
            if total <= self.quota_bytes:
                break
            try:
                os.unlink(path)
                self.deleted += 1
            except OSError:
                continue
            total -= n

    def poll(self) -> Optional[str]:
        """Handle the pipeline's news; returns the one line that stopped the recording, when it just did."""
        if self.stopped is not None:
            return None
        Gst = self.pipeline.Gst
        cut = False
        for msg in self.pipeline.messages(Gst.MessageType.ERROR | Gst.MessageType.ELEMENT):
            if msg.type == Gst.MessageType.ERROR:
                err, debug = msg.parse_error()
                why = " ".join(err.message.split())
                if debug and debug.strip():  # its last line ends with the errno's text: "No space left on device"
                    why += " " + debug.strip().splitlines()[-1].rsplit(": ", 1)[-1].strip()
                self.stopped = "recording stopped: %s: %s (%s); detection goes on" % (
                    msg.src.get_name() if msg.src is not None else "?", why, self.directory)
                self.pipeline.close()
                self.enforce_quota()
                return self.stopped
            structure = msg.get_structure()
            cut = cut or (structure is not None and structure.get_name() == "splitmuxsink-fragment-closed")
        if cut or time.monotonic() - self._last_quota_check >= _QUOTA_CHECK_S:
            self.enforce_quota()
        return None

    def stop(self) -> None:
        if self.stopped is None:
            self.pipeline.finish(self._appsrc)
            self.stopped = "stopped"
        self.enforce_quota()

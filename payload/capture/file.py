"""Recorded frames: a video file (OpenCV/FFmpeg) or a folder of numbered images.

Frame ``index`` is 0-based and keeps counting when ``loop`` starts the recording again, so it
never goes backwards. Capture times follow the recording's own timeline,
``t = t_start + index / fps`` (the file's frame rate, or ``fps`` for folders and for ``pace``),
so that time-based stages see the real interval between frames however fast we process.

``pace`` makes a recording behave like a camera running at ``fps``: frame k is due at
``t_start + k / fps`` (the clock starts at the first read); ``read()`` returns the newest due
frame, skipping and counting as dropped the ones that became stale while the caller was busy,
and waits (at most timeout_s, then None) when the next frame is not due yet.
"""

import abc
import logging
import math
import os
import re
import time
from typing import List, Optional

import cv2
import numpy as np

from payload.capture.base import EndOfStream, FrameSource, now_ns
from payload.config import path_problem
from payload.errors import SourceError
from payload.types import Frame

log = logging.getLogger(__name__)

#: Image types ImageFolderSource picks up (case-insensitive).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm")

#: What ``_next_image`` returns for a frame that exists but cannot be decoded.
UNREADABLE = np.empty((0,), np.uint8)


class _Recording(FrameSource):
    """The timeline, loop and pace logic shared by video files and image folders."""

    def __init__(self, path: str, fps: float = 30.0, loop: bool = False, pace: bool = False) -> None:
        super().__init__()
        if not fps > 0:
            raise SourceError("capture.fps: %r: expected a positive frame rate" % (fps,))
        self.path = path
        self.fps = float(fps)
        self.loop = loop
        self.pace = pace
        self._rate_fps = self.fps  # timeline rate: the file's own rate unless paced
        self._pos = 0  # position in the current pass through the recording
        self._pass_offset = 0  # timeline index of this pass's first frame
        self._t0 = None  # (mono, wall) of timeline index 0
        self._opened = False

    # --- what a recording kind provides -----------------------------------------------------

    @abc.abstractmethod
    def _open_media(self) -> Optional[float]:
        """Open (or reopen at the start); return the recording's frame rate if it has one."""

    @abc.abstractmethod
    def _next_image(self, decode: bool) -> Optional[np.ndarray]:
        """The image at self._pos (None at the end); with decode=False only step over it."""

    @abc.abstractmethod
    def _close_media(self) -> None:
        """Release the file."""

    # --- FrameSource ------------------------------------------------------------------------

    def open(self) -> None:
        if self._opened:
            return
        native_fps = self._open_media()
        if not self.pace and native_fps is not None and math.isfinite(native_fps) and native_fps > 0:
            self._rate_fps = float(native_fps)
        self._opened = True
        self.stats.connected = True
        if not self.pace:
            self._t0 = now_ns()
        log.info("recording opened source=%s path=%s timeline_fps=%.3f loop=%s pace=%s",
                 self.name, self.path, self._rate_fps, self.loop, self.pace)

    def close(self) -> None:
        if self._opened:
            self._close_media()
            self._opened = False
            self.stats.connected = False

    def read(self, timeout_s: float = 1.0) -> Optional[Frame]:
        if not self._opened:
            raise SourceError("%s: %s: read before open()" % (self.name, self.path))
        if not self.pace:
            return self._take(decode=True)
        if self._t0 is None:  # a paced recording starts its clock at the first read
            self._t0 = now_ns()
        nxt = self._pass_offset + self._pos
        elapsed_s = (time.monotonic_ns() - self._t0[0]) / 1e9
        due = int(math.floor(elapsed_s * self._rate_fps + 1e-9))
        if due < nxt:
            wait_s = nxt / self._rate_fps - elapsed_s
            if wait_s > timeout_s:
                time.sleep(max(0.0, timeout_s))
                return None
            time.sleep(max(0.0, wait_s))
            due = nxt
        for _ in range(due - nxt):  # newest frame wins: step over the stale ones
            self._take(decode=False)
            self.stats.dropped += 1
        return self._take(decode=True)

    # --- timeline ---------------------------------------------------------------------------

    def _take(self, decode: bool) -> Optional[Frame]:
        """The next frame on the timeline (rewinding when looping), or EndOfStream."""
        image = self._next_image(decode)
        if image is None:
            if not self.loop or self._pos == 0:
                raise EndOfStream()
            self._pass_offset += self._pos
            self._pos = 0
            self._close_media()
            self._open_media()
            image = self._next_image(decode)
            if image is None:
                raise EndOfStream()
        index = self._pass_offset + self._pos
        self._pos += 1
        if not decode:
            return None
        if image is UNREADABLE:  # its place on the timeline stays taken: later frames keep their times
            self.stats.unreadable += 1
            return None
        offset_ns = int(round(index * 1e9 / self._rate_fps))
        self.stats.frames += 1
        return Frame(image=image, index=index, t_capture_ns=self._t0[0] + offset_ns, t_wall_ns=self._t0[1] + offset_ns)


def _need_path(path: Optional[str], what: str, want_dir: bool) -> str:
    if not path:
        raise SourceError("capture.path: not set: expected the %s" % what)
    problem = path_problem(path, want_dir)
    if problem:
        raise SourceError("capture.path: %s" % problem)
    return path


class VideoFileSource(_Recording):
    """A video file read with OpenCV (FFmpeg backend on PyPI's OpenCV)."""

    def __init__(self, path: str, fps: float = 30.0, loop: bool = False, pace: bool = False) -> None:
        super().__init__(path, fps=fps, loop=loop, pace=pace)
        self._cap = None  # type: Optional[cv2.VideoCapture]
        self._first = None  # type: Optional[np.ndarray]

    def _open_media(self) -> Optional[float]:
        _need_path(self.path, "video file", want_dir=False)
        cap = cv2.VideoCapture(self.path)
        ok, first = cap.read() if cap.isOpened() else (False, None)
        if not ok or first is None:
            cap.release()
            raise SourceError("capture.path: %s: cannot be read as a video (OpenCV decoded no frame)" % self.path)
        self._cap = cap
        self._first = first  # decoded to prove the file is readable; handed out as frame 0
        return cap.get(cv2.CAP_PROP_FPS)

    def _next_image(self, decode: bool) -> Optional[np.ndarray]:
        if self._first is not None:
            image, self._first = self._first, None
            return image
        if self._cap is None:
            return None
        if not decode:
            return np.empty((0,), np.uint8) if self._cap.grab() else None
        ok, image = self._cap.read()
        return image if ok else None

    def _close_media(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
        self._first = None


def _natural_key(name: str) -> List:
    """Numbers in a name compare as numbers: frame2.png < frame10.png."""
    return [(0, int(part), "") if part.isdigit() else (1, 0, part.lower()) for part in re.split(r"(\d+)", name) if part]


class ImageFolderSource(_Recording):
    """The images of one folder, in numerical order of the numbers in their names."""

    def __init__(self, path: str, fps: float = 30.0, loop: bool = False, pace: bool = False) -> None:
        super().__init__(path, fps=fps, loop=loop, pace=pace)
        self.files = []  # type: List[str]

    def _open_media(self) -> Optional[float]:
        if not self.files:
            _need_path(self.path, "image folder", want_dir=True)
            names = [n for n in os.listdir(self.path) if n.lower().endswith(IMAGE_SUFFIXES)]
            if not names:
                raise SourceError("capture.path: %s: no images (%s) in the folder" % (self.path, " ".join(IMAGE_SUFFIXES)))
            self.files = [os.path.join(self.path, n) for n in sorted(names, key=_natural_key)]
        return None

    def _next_image(self, decode: bool) -> Optional[np.ndarray]:
        if self._pos >= len(self.files):
            return None
        if not decode:
            return np.empty((0,), np.uint8)
        path = self.files[self._pos]
        image = cv2.imread(path, cv2.IMREAD_COLOR)
        if image is None:  # corrupt, empty, or gone since listed: skip it, the recording goes on
            if not self.stats.unreadable:
                log.warning("capture.path: %s: cannot be read as an image; skipped (counted as unreadable)", path)
            return UNREADABLE
        return image

    def _close_media(self) -> None:
        pass

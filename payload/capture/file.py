"""Recorded frames: a video file (OpenCV/FFmpeg) or a folder of numbered images.

Frame ``index`` is 0-based and keeps counting when ``loop`` starts the recording again, so it
never goes backwards. Capture times follow the recording's own timeline,
``t = t_start + index / fps`` (the file's frame rate, or ``fps`` for folders), so that
time-based stages see the real interval between frames however fast we process.

These readers are unpaced: each ``read()`` decodes the next frame at once. Played at camera
rate (``capture.pace``), they are read by payload.capture.paced's thread instead.
"""

import abc
import logging
import math
import os
import re
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
    """The timeline and loop logic shared by video files and image folders."""

    def __init__(self, path: str, fps: float = 30.0, loop: bool = False) -> None:
        super().__init__()
        if not fps > 0:
            raise SourceError("capture.fps: %r: expected a positive frame rate" % (fps,))
        self.path = path
        self.fps = float(fps)
        self.loop = loop
        self._rate_fps = self.fps  # timeline rate: the file's own rate if it has one
        self._pos = 0  # position in the current pass through the recording
        self._pass_offset = 0  # timeline index of this pass's first frame
        self._t0 = None  # (mono, wall) of timeline index 0
        self._opened = False

    # --- what a recording kind provides -----------------------------------------------------

    @abc.abstractmethod
    def _open_media(self) -> Optional[float]:
        """Open (or reopen at the start); return the recording's frame rate if it has one."""

    @abc.abstractmethod
    def _next_image(self) -> Optional[np.ndarray]:
        """The image at self._pos (None at the end, UNREADABLE if it cannot be decoded)."""

    @abc.abstractmethod
    def _close_media(self) -> None:
        """Release the file."""

    # --- FrameSource ------------------------------------------------------------------------

    def open(self) -> None:
        if self._opened:
            return
        native_fps = self._open_media()
        if native_fps is not None and math.isfinite(native_fps) and native_fps > 0:
            self._rate_fps = float(native_fps)
        self._opened = True
        self.stats.connected = True
        self._t0 = now_ns()
        log.info("recording opened source=%s path=%s timeline_fps=%.3f loop=%s",
                 self.name, self.path, self._rate_fps, self.loop)

    def close(self) -> None:
        if self._opened:
            self._close_media()
            self._opened = False
            self.stats.connected = False

    def read(self, timeout_s: float = 1.0) -> Optional[Frame]:
        if not self._opened:
            raise SourceError("%s: %s: read before open()" % (self.name, self.path))
        return self._take()

    # --- timeline ---------------------------------------------------------------------------

    def _take(self) -> Optional[Frame]:
        """The next frame on the timeline (rewinding when looping), or EndOfStream."""
        image = self._next_image()
        if image is None:
            if not self.loop or self._pos == 0:
                raise EndOfStream()
            self._pass_offset += self._pos
            self._pos = 0
            self._close_media()
            self._open_media()
            image = self._next_image()
            if image is None:
                raise EndOfStream()
        index = self._pass_offset + self._pos
        self._pos += 1
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

    def __init__(self, path: str, fps: float = 30.0, loop: bool = False) -> None:
        super().__init__(path, fps=fps, loop=loop)
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

    def _next_image(self) -> Optional[np.ndarray]:
        if self._first is not None:
            image, self._first = self._first, None
            return image
        if self._cap is None:
            return None
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

    def __init__(self, path: str, fps: float = 30.0, loop: bool = False) -> None:
        super().__init__(path, fps=fps, loop=loop)
        self.files = []  # type: List[str]

    def _open_media(self) -> Optional[float]:
        if not self.files:
            _need_path(self.path, "image folder", want_dir=True)
            names = [n for n in os.listdir(self.path) if n.lower().endswith(IMAGE_SUFFIXES)]
            if not names:
                raise SourceError("capture.path: %s: no images (%s) in the folder" % (self.path, " ".join(IMAGE_SUFFIXES)))
            self.files = [os.path.join(self.path, n) for n in sorted(names, key=_natural_key)]
        return None

    def _next_image(self) -> Optional[np.ndarray]:
        if self._pos >= len(self.files):
            return None
        path = self.files[self._pos]
        image = cv2.imread(path, cv2.IMREAD_COLOR)
        if image is None:  # corrupt, empty, or gone since listed: skip it, the recording goes on
            if not self.stats.unreadable:
                log.warning("capture.path: %s: cannot be read as an image; skipped (counted as unreadable)", path)
            return UNREADABLE
        return image

    def _close_media(self) -> None:
        pass

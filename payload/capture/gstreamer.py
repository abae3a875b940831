"""A GStreamer pipeline ending in ``appsink``: Jetson CSI cameras, RTSP, files, test sources.

Two ways in, chosen at open():
- OpenCV's own GStreamer backend (``cv2.CAP_GSTREAMER``) when OpenCV was built with it
  (JetPack's system OpenCV; PyPI's wheels are not);
- otherwise PyGObject (``gi.repository.Gst``), imported only here and only when needed.

Frames must reach us as packed BGR in system memory. If the pipeline text has no
``format=BGR`` we insert ``videoconvert ! video/x-raw,format=BGR`` just before the final
appsink (videoconvert passes BGR through without copying) and say so in the log; a pipeline
whose appsink is not its last element must carry those caps itself.

Liveness: a pipeline is live when going to PAUSED answers NO_PREROLL (a camera, or
``videotestsrc is-live=true``); through OpenCV we guess it from the source element's name.
A live pipeline is read by a LiveReader thread (newest frame wins, stamped with now_ns() at
grab; EOS or an error is a lost camera and is reconnected with back-off). A finite one is read
frame by frame, stamped on its own timeline (open time + buffer PTS), and ends with
EndOfStream. ``live=True/False`` overrides the detection. Unless the pipeline sets ``sync=``
itself, appsink gets ``sync=false``: frames are handed over as soon as they exist.
"""

import logging
import re
from typing import Optional, Tuple

import cv2
import numpy as np

from payload.capture.base import EndOfStream, FrameSource, now_ns
from payload.capture.live import Grabber, LiveReader
from payload.config import Retry
from payload.errors import CameraLost, SourceError
from payload.gst import GstUnavailable, import_gst, one_line
from payload.types import Frame

log = logging.getLogger(__name__)

_BGR_CAPS = "video/x-raw,format=BGR"
_HAS_BGR = re.compile(r"format\s*=\s*(\(string\))?BGR(?![A-Za-z0-9])")
_FINAL_APPSINK = re.compile(r"!\s*(appsink\b[^!]*)$")
_CODE_LOCATION = re.compile(r"\.c\(\d+\)")
_SYNC_SET = re.compile(r"\bsync\s*=")
_LIVE_SOURCES = re.compile(r"\b(v4l2src|nvarguscamerasrc|nvv4l2camerasrc|libcamerasrc|rtspsrc|udpsrc|souphttpsrc|is-live\s*=\s*(true|1))\b")

def opencv_has_gstreamer() -> bool:
    """True when this OpenCV build can open GStreamer pipelines itself."""
    for line in cv2.getBuildInformation().splitlines():
        if line.strip().startswith("GStreamer:"):
            return "YES" in line.split(":", 1)[1]
    return False


def bgr_pipeline(pipeline: str) -> Tuple[str, bool]:
    """The pipeline with BGR caps ensured before a final appsink; True when we changed it."""
    text = pipeline.strip()
    if _HAS_BGR.search(text):
        return text, False
    match = _FINAL_APPSINK.search(text)
    if match is None:
        return text, False  # appsink not last: leave it to the caller's caps (checked at negotiation)
    return "%s! videoconvert ! %s ! %s" % (text[: match.start()], _BGR_CAPS, match.group(1).strip()), True


def _import_gst():
    """(Gst, GLib), initialised once (payload.gst); SourceError when GStreamer is missing."""
    try:
        return import_gst()
    except GstUnavailable as exc:
        raise SourceError("capture.pipeline: %s, or use an OpenCV built with GStreamer" % exc) from None


class _GiPipeline(Grabber):
    """One running instance of the pipeline, read through PyGObject."""

    def __init__(self, text: str, open_timeout_s: float) -> None:
        Gst, GLib = _import_gst()
        self._Gst = Gst
        self.text = text
        try:
            self._pipeline = Gst.parse_launch(text)
        except GLib.Error as exc:
            raise SourceError("capture.pipeline: %s (in %r)" % (one_line(exc.message), text)) from None
        self._sink = self._find_appsink()
        self._bus = self._pipeline.get_bus()
        self.live = False
        self.last_pts_ns = None  # type: Optional[int]
        try:
            self._start(open_timeout_s)
        except SourceError:
            self.close()
            raise

    def _find_appsink(self):
        if not isinstance(self._pipeline, self._Gst.Pipeline):  # one element: parse_launch returns it bare
            self._pipeline = self._wrap(self._pipeline)
        sinks = []
        it = self._pipeline.iterate_recurse()
        while True:
            ok, element = it.next()
            if ok != self._Gst.IteratorResult.OK:
                break
            factory = element.get_factory()
            if factory is not None and factory.get_name() == "appsink":
                sinks.append(element)
        if len(sinks) != 1:
            raise SourceError("capture.pipeline: %d appsink elements in %r: expected exactly one, at the end" % (len(sinks), self.text))
        return sinks[0]

    def _wrap(self, element):
        pipeline = self._Gst.Pipeline.new(None)
        pipeline.add(element)
        return pipeline

    def _bus_error(self) -> Optional[str]:
        msg = self._bus.pop_filtered(self._Gst.MessageType.ERROR)
        if msg is None:
            return None
        err, debug = msg.parse_error()
        detail = (debug or "").split("\n")[-1].strip()
        if _CODE_LOCATION.search(detail):  # "../gstfoo.c(123): func (): /GstPipeline:..." helps no operator
            detail = ""
        source = msg.src.get_name() if msg.src is not None else "pipeline"
        return one_line("%s: %s%s" % (source, err.message, " (%s)" % detail if detail else ""))

    def _fail(self, what: str) -> SourceError:
        error = self._bus_error()
        return SourceError("capture.pipeline: %s: %s (in %r)" % (what, error or "no error message from GStreamer", self.text))

    def _start(self, open_timeout_s: float) -> None:
        Gst = self._Gst
        timeout_ns = int(open_timeout_s * Gst.SECOND)
        ret = self._pipeline.set_state(Gst.State.PAUSED)
        if ret == Gst.StateChangeReturn.FAILURE:
            raise self._fail("cannot start")
        if ret == Gst.StateChangeReturn.NO_PREROLL:
            self.live = True
        else:
            ret, _, _ = self._pipeline.get_state(timeout_ns)
            if ret == Gst.StateChangeReturn.FAILURE:
                raise self._fail("cannot start")
            if ret == Gst.StateChangeReturn.ASYNC:
                raise self._fail("did not preroll within %.1f s" % open_timeout_s)
            self.live = ret == Gst.StateChangeReturn.NO_PREROLL
        # Newest frame wins for cameras; a recording must not lose frames (appsink then pushes back).
        self._sink.set_property("drop", self.live)
        self._sink.set_property("max-buffers", 1 if self.live else 4)
        if not _SYNC_SET.search(self.text):
            # Hand frames over as soon as they exist: a recording is read as fast as it is consumed
            # (like VideoFileSource), a camera without waiting for the pipeline clock.
            self._sink.set_property("sync", False)
        ret = self._pipeline.set_state(Gst.State.PLAYING)
        if ret == Gst.StateChangeReturn.FAILURE:
            raise self._fail("did not reach PLAYING")
        ret, state, _ = self._pipeline.get_state(timeout_ns)
        if ret == Gst.StateChangeReturn.FAILURE or (ret == Gst.StateChangeReturn.ASYNC and state != Gst.State.PLAYING):
            raise self._fail("did not reach PLAYING within %.1f s" % open_timeout_s)

    def grab(self, timeout_s: float) -> Optional[np.ndarray]:
        """The next image; None on timeout; EndOfStream at EOS; CameraLost on a pipeline error."""
        sample = self._sink.try_pull_sample(int(timeout_s * self._Gst.SECOND))
        if sample is None:
            error = self._bus_error()
            if error is not None:
                raise CameraLost("capture.pipeline: %s" % error)
            if self._sink.is_eos():
                raise EndOfStream()
            return None
        pts = sample.get_buffer().pts
        self.last_pts_ns = None if pts == self._Gst.CLOCK_TIME_NONE else int(pts)
        return self._to_bgr(sample)

    def _to_bgr(self, sample) -> np.ndarray:
        caps = sample.get_caps().get_structure(0)
        fmt = caps.get_value("format")
        width, height = caps.get_value("width"), caps.get_value("height")
        if fmt != "BGR":
            raise CameraLost("capture.pipeline: appsink receives format %s, expected BGR: end the pipeline with "
                             "'! videoconvert ! %s ! appsink'" % (fmt, _BGR_CAPS))
        buf = sample.get_buffer()
        ok, info = buf.map(self._Gst.MapFlags.READ)
        if not ok:
            raise CameraLost("capture.pipeline: cannot map a buffer")
        try:
            data = np.frombuffer(info.data, np.uint8)
            stride = data.size // height  # rows are padded to 4 bytes (e.g. width 321 -> 964, not 963)
            if stride < width * 3:
                raise CameraLost("capture.pipeline: buffer of %d bytes is too small for %dx%d BGR" % (data.size, width, height))
            # The copy gives the frame its own writable memory, independent of the GStreamer buffer.
            return data[: stride * height].reshape(height, stride)[:, : width * 3].reshape(height, width, 3).copy()
        finally:
            buf.unmap(info)

    def close(self) -> None:
        if self._pipeline is not None:
            self._pipeline.set_state(self._Gst.State.NULL)
            self._pipeline = None


class _CvPipeline(Grabber):
    """One running instance of the pipeline, read through OpenCV's GStreamer backend."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.live = bool(_LIVE_SOURCES.search(text))
        self._cap = cv2.VideoCapture(text, cv2.CAP_GSTREAMER)
        if not self._cap.isOpened():
            self._cap.release()
            raise SourceError("capture.pipeline: OpenCV could not start %r (run it with gst-launch-1.0 to see why)" % text)

    def grab(self, timeout_s: float) -> Optional[np.ndarray]:
        ok, image = self._cap.read()
        if not ok or image is None:
            if self.live:
                raise CameraLost("capture.pipeline: no frame from the camera pipeline")
            raise EndOfStream()
        return image

    def close(self) -> None:
        self._cap.release()


class GStreamerSource(FrameSource):
    """Frames from a GStreamer pipeline string ending in appsink.

    ``backend``: "auto" (OpenCV when it has GStreamer, else PyGObject), "opencv" or "gi".
    ``live``: None = detect; True treats end-of-stream as a lost camera and reconnects.
    """

    def __init__(
        self,
        pipeline: str,
        retry: Optional[Retry] = None,
        live: Optional[bool] = None,
        backend: str = "auto",
        open_timeout_s: float = 10.0,
        stall_s: float = 5.0,
    ) -> None:
        super().__init__()
        if not pipeline or not pipeline.strip():
            raise SourceError("capture.pipeline: empty: expected a GStreamer pipeline ending in appsink")
        if backend not in ("auto", "opencv", "gi"):
            raise SourceError("GStreamerSource backend %r: expected auto, opencv or gi" % (backend,))
        self.pipeline, changed = bgr_pipeline(pipeline)
        if changed:
            log.info("appended BGR conversion before appsink pipeline=%r", self.pipeline)
        self.backend = ("opencv" if opencv_has_gstreamer() else "gi") if backend == "auto" else backend
        self._live_override = live
        self._open_timeout_s = open_timeout_s
        self._reader = LiveReader(self._connect, retry or Retry(), self.stats, name=self.name, stall_s=stall_s,
                                  prepare=self._prepared)
        self._direct = None  # type: Optional[Grabber]
        self._t0 = (0, 0)
        self._opened = False
        self._index = 0

    def _connect(self) -> Grabber:
        if self.backend == "opencv":
            return _CvPipeline(self.pipeline)
        return _GiPipeline(self.pipeline, self._open_timeout_s)

    def open(self) -> None:
        if self._opened:
            return
        grabber = self._connect()
        detected = bool(getattr(grabber, "live", False))
        self.live = detected if self._live_override is None else self._live_override
        log.info("gstreamer opened backend=%s live=%s detected_live=%s", self.backend, self.live, detected)
        if self.live:
            self._reader.start(grabber)
        else:
            self._direct = grabber
            self._t0 = now_ns()
            self.stats.connected = True
        self._opened = True

    def read(self, timeout_s: float = 1.0) -> Optional[Frame]:
        if not self._opened:
            raise SourceError("capture.pipeline: read before open() or after close()")
        if self.live:
            return self._reader.read(timeout_s)
        try:
            image = self._direct.grab(timeout_s)
        except CameraLost as exc:  # an error inside a recording's pipeline: it cannot go on
            raise SourceError(str(exc)) from None
        if image is None:
            return None
        pts_ns = getattr(self._direct, "last_pts_ns", None)
        if pts_ns is not None:  # a recording: its own timeline, as VideoFileSource does
            t_capture_ns, t_wall_ns = self._t0[0] + pts_ns, self._t0[1] + pts_ns
        else:
            t_capture_ns, t_wall_ns = now_ns()
        frame = Frame(image=image, index=self._index, t_capture_ns=t_capture_ns, t_wall_ns=t_wall_ns)
        self._index += 1
        self.stats.frames += 1
        return frame

    def close(self) -> None:
        if not self._opened:
            return
        if self.live:
            self._reader.stop()
        elif self._direct is not None:
            self._direct.close()
            self._direct = None
        self.stats.connected = False
        self._opened = False

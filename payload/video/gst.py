"""GStreamer for the video: imported only here and only when video or recording is enabled
(PyGObject is the optional ``gstreamer`` extra), the per-platform encoder, and appsrc feeding.

Encoders, first found wins with ``encoder: auto``: ``nvv4l2h264enc`` (the Jetson's hardware
encoder, behind ``nvvidconv`` into NVMM memory) and ``openh264enc`` (Cisco's OpenH264, BSD
licensed, in gstreamer1.0-plugins-bad). x264enc is deliberately not among them: x264 is GPL
and the payload takes no GPL dependency.
"""

import os
import threading
from typing import Tuple

import numpy as np

from payload import gst as _gst
from payload.gst import one_line

#: Encoder element -> the chain after an I420 appsrc up to parsed H.264 ({bps}, {gop} filled in).
ENCODERS = {
    "nvv4l2h264enc": ("nvvidconv ! video/x-raw(memory:NVMM),format=I420 ! nvv4l2h264enc name=enc bitrate={bps} "
                      "iframeinterval={gop} idrinterval={gop} insert-sps-pps=true maxperf-enable=true ! h264parse"),
    # complexity low and one thread: the software encoder shares the CPU with detection; a key
    # frame every second lets a ground station join within a second and recording segments split there.
    "openh264enc": ("openh264enc name=enc bitrate={bps} rate-control=bitrate complexity=low multi-thread=1 "
                    "gop-size={gop} usage-type=camera ! h264parse"),
}
#: Elements an encoder's chain needs beside itself.
_NEEDS = {"nvv4l2h264enc": ("nvvidconv", "h264parse"), "openh264enc": ("h264parse",)}
#: ``encoder: auto`` tries these in order.
AUTO_ORDER = ("nvv4l2h264enc", "openh264enc")

#: The video's threads (ours and GStreamer's streaming threads, and the encoder's own threads they
#: start) run at the lowest priority (nice 19): where the CPU is short (a software encoder on a
#: few cores) the video gets what detection leaves and drops frames, instead of slowing it.
VIDEO_NICE = 19


class VideoUnavailable(Exception):
    """Video cannot run here; the message is one line for the operator."""


def import_gst():
    """(Gst, GLib), initialised once (payload.gst); VideoUnavailable when GStreamer is missing."""
    try:
        return _gst.import_gst()
    except _gst.GstUnavailable as exc:
        raise VideoUnavailable(str(exc)) from None


def import_rtsp_server():
    """GstRtspServer; VideoUnavailable when its typelib (gir1.2-gst-rtsp-server-1.0) is missing."""
    import_gst()
    try:
        import gi

        gi.require_version("GstRtspServer", "1.0")
        from gi.repository import GstRtspServer
    except (ImportError, ValueError) as exc:
        raise VideoUnavailable("the RTSP server is not usable from Python (%s): install "
                               "gir1.2-gst-rtsp-server-1.0" % one_line(exc)) from None
    return GstRtspServer


def has_elements(*names: str) -> bool:
    Gst, _ = import_gst()
    return all(Gst.ElementFactory.find(n) is not None for n in names)


def choose_encoder(name: str) -> str:
    """The encoder element to use for ``video.encoder`` (``auto`` or an ENCODERS name)."""
    candidates = AUTO_ORDER if name == "auto" else (name,)
    for candidate in candidates:
        if has_elements(candidate, *_NEEDS[candidate]):
            return candidate
    if name == "auto":
        raise VideoUnavailable("no H.264 encoder: install gstreamer1.0-plugins-bad (openh264enc) "
                               "or run on a Jetson (nvv4l2h264enc)")
    raise VideoUnavailable("video.encoder %s: element %s not found (gst-inspect-1.0 %s)"
                           % (name, " or ".join((name,) + _NEEDS[name]), name))


def encoder_chain(name: str, bitrate_kbps: int, fps: float) -> str:
    return ENCODERS[name].format(bps=int(bitrate_kbps) * 1000, gop=max(1, int(round(fps))))


def raw_caps(size_wh: Tuple[int, int], fps: float) -> str:
    w, h = size_wh
    return "video/x-raw,format=I420,width=%d,height=%d,framerate=%d/1000" % (w, h, int(round(fps * 1000)))


def appsrc_text(size_wh: Tuple[int, int], fps: float) -> str:
    """A live appsrc stamping each buffer with the pipeline clock when pushed (frames come
    when detection finishes them, not at a fixed rate)."""
    return ("appsrc name=src is-live=true format=time do-timestamp=true block=false caps=%s"
            % raw_caps(size_wh, fps))


def lower_this_thread() -> None:
    """Give the calling thread VIDEO_NICE (Linux nice is per thread, and threads started from this
    one inherit it). Not permitted (a seccomp filter) or not Linux: left as it is."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), VIDEO_NICE)
    except (AttributeError, OSError):
        pass


def lower_streaming_threads(bus) -> None:
    """Each streaming thread of the pipeline on ``bus`` lowers itself as it starts: GStreamer posts
    STREAM_STATUS ENTER synchronously from the new thread (its documented hook for priorities)."""
    Gst, _ = import_gst()

    def on_status(_bus, msg):
        kind, _owner = msg.parse_stream_status()
        if kind == Gst.StreamStatusType.ENTER:
            lower_this_thread()

    bus.enable_sync_message_emission()
    bus.connect("sync-message::stream-status", on_status)


class AppsrcFeed:
    """Pushes I420 frames into one appsrc without ever waiting: when the encoder behind it has not
    taken the last frames yet (``max_frames`` queued), the frame is dropped and counted."""

    def __init__(self, appsrc, frame_bytes: int, max_frames: int = 2) -> None:
        self.Gst, _ = import_gst()
        self.appsrc = appsrc
        self.limit = frame_bytes * max_frames
        appsrc.set_property("max-bytes", self.limit)
        self.pushed = 0
        self.dropped = 0  # frames the encoder was too far behind to take

    def push(self, i420: np.ndarray) -> bool:
        """True when the frame was queued for the encoder; False when dropped or the pipeline is gone."""
        if self.appsrc.get_property("current-level-bytes") + i420.nbytes > self.limit:
            self.dropped += 1
            return False
        ret = self.appsrc.emit("push-buffer", self.Gst.Buffer.new_wrapped(i420.tobytes()))
        if ret != self.Gst.FlowReturn.OK:
            return False
        self.pushed += 1
        return True

    def end(self) -> None:
        self.appsrc.emit("end-of-stream")


class OwnPipeline:
    """A pipeline we run ourselves (UDP stream, recording), its bus read by polling from the video
    thread: no GLib main loop needed."""

    def __init__(self, text: str) -> None:
        self.Gst, GLib = import_gst()
        self.text = text
        try:
            self.pipeline = self.Gst.parse_launch(text)
        except GLib.Error as exc:
            raise VideoUnavailable("%s (in %r)" % (one_line(exc.message), text)) from None
        self.bus = self.pipeline.get_bus()
        lower_streaming_threads(self.bus)

    def element(self, name: str):
        return self.pipeline.get_by_name(name)

    def play(self) -> None:
        if self.pipeline.set_state(self.Gst.State.PLAYING) == self.Gst.StateChangeReturn.FAILURE:
            problem = self.error() or "the pipeline would not start"
            self.close()
            raise VideoUnavailable(problem)

    def messages(self, types):
        """The pending bus messages of ``types`` (a Gst.MessageType mask), oldest first."""
        out = []
        while True:
            msg = self.bus.pop_filtered(types)
            if msg is None:
                return out
            out.append(msg)

    def error(self):
        """The first pending error as one line (element: message), or None."""
        for msg in self.messages(self.Gst.MessageType.ERROR):
            err, _debug = msg.parse_error()
            return "%s: %s" % (msg.src.get_name() if msg.src is not None else "?", one_line(err.message))
        return None

    def finish(self, appsrc, timeout_s: float = 3.0) -> None:
        """End of stream (so muxers write their trailers), then stop."""
        if appsrc is not None:
            appsrc.emit("end-of-stream")
            self.bus.timed_pop_filtered(int(timeout_s * 1e9), self.Gst.MessageType.EOS | self.Gst.MessageType.ERROR)
        self.close()

    def close(self) -> None:
        self.pipeline.set_state(self.Gst.State.NULL)

"""The video output the service runs: the live stream and the recording, fed from the detection
loop without ever making it wait.

``submit(frame, result, state)`` puts the newest frame in a slot of one (a frame not taken yet
is replaced and counted); a thread of its own takes the newest at most ``video.fps`` times a
second, draws it (payload.video.render) and hands it to the stream and the recorder, each of which
drops a frame its encoder is not ready for (counted too). Nothing is drawn or encoded for the
stream while no RTSP client watches. All video threads run at the lowest priority (gst.VIDEO_NICE).
"""

import logging
import threading
import time
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

from payload.config import Config, section_changes
from payload.detect.pipeline import GladResult
from payload.types import Frame
from payload.video.description import StreamDescription
from payload.video.gst import VideoUnavailable, choose_encoder, import_gst, lower_this_thread
from payload.video.handoff import NewestSlot
from payload.video.recorder import Recorder
from payload.video.render import render, to_i420
from payload.video.stream import RtspStream, UdpStream

log = logging.getLogger(__name__)

#: Keys a reload applies to a running video output; the rest of video/recording need a restart.
LIVE_KEYS = ("video.annotate", "video.bitrate_kbps", "recording.annotated", "recording.quota_mb")


def live_changes(old: Config, new: Config) -> List[str]:
    """The LIVE_KEYS that differ between two configs."""
    changed = section_changes(old.video, new.video, "video") + section_changes(old.recording, new.recording,
                                                                               "recording")
    return [k for k in changed if k in LIVE_KEYS]


@dataclass
class VideoStats:
    submitted: int  # frames the detection loop handed over
    dropped: int  # replaced in the slot before the video thread took them (behind, or above video.fps)
    streamed: int  # frames queued for the stream's encoder
    stream_dropped: int  # frames the stream's encoder was too far behind to take
    clients: int  # RTSP sessions now
    recorded: int  # frames queued for the recording's encoder
    record_dropped: int
    faults: int  # frames the video thread failed on (the first is logged)


def _open_stream(cfg: Config, encoder: str):
    v = cfg.video
    size = (v.width, v.height)
    if v.transport == "rtsp":
        try:
            return RtspStream(v.rtsp_port, v.path, v.advertise_host, size, v.fps, v.bitrate_kbps, encoder)
        except VideoUnavailable as exc:
            log.warning("video: no RTSP (%s); streaming RTP/UDP to %s:%d instead", exc, v.udp_host, v.udp_port)
    return UdpStream(v.udp_host, v.udp_port, size, v.fps, v.bitrate_kbps, encoder)


class VideoOutput:
    """The stream (when video.enabled) and the recording (when recording.enabled) of one service."""

    def __init__(self, cfg: Config, encoder: str) -> None:
        self.cfg = cfg
        self.encoder = encoder
        self.size_wh: Tuple[int, int] = (cfg.video.width, cfg.video.height)
        self.stream = None
        self.recorder: Optional[Recorder] = None
        if cfg.video.enabled:
            try:
                self.stream = _open_stream(cfg, encoder)
            except VideoUnavailable as exc:
                log.warning("video: stream off: %s; detection goes on", exc)
        if cfg.recording.enabled:
            r = cfg.recording
            try:
                self.recorder = Recorder(r.dir, r.segment_s, r.quota_mb, self.size_wh, cfg.video.fps,
                                         cfg.video.bitrate_kbps, encoder)
            except VideoUnavailable as exc:
                log.warning("recording off: %s; detection goes on", exc)
        self._slot = NewestSlot()
        self._streamed = 0
        self._faults = 0
        self._thread = threading.Thread(target=self._run, name="video", daemon=True)
        self._thread.start()
        if self.stream is not None:
            d = self.stream.description
            log.info("video: %s %dx%d %.0f fps %d kbit/s %s", d.uri, d.width, d.height, d.fps, d.bitrate_kbps,
                     d.encoder)
        if self.recorder is not None:
            log.info("recording: %s every %g s, quota %g MB", cfg.recording.dir, cfg.recording.segment_s,
                     cfg.recording.quota_mb)

    @classmethod
    def open(cls, cfg: Config) -> Optional["VideoOutput"]:
        """The output for ``cfg`` (None when neither video nor recording is enabled, or when GStreamer
        or an encoder is missing: then one line says why, and detection goes on)."""
        if not (cfg.video.enabled or cfg.recording.enabled):
            return None
        try:
            import_gst()
            encoder = choose_encoder(cfg.video.encoder)
        except VideoUnavailable as exc:
            log.warning("video and recording off: %s; detection goes on", exc)
            return None
        out = cls(cfg, encoder)
        if out.stream is None and out.recorder is None:
            out.stop()
            return None
        return out

    # --- the detection loop's side ---------------------------------------------------------

    def submit(self, frame: Frame, result: Optional[GladResult], state: str) -> None:
        """Hand over the newest frame and what GLAD made of it; returns at once."""
        self._slot.put((frame, result, state))

    @property
    def description(self) -> Optional[StreamDescription]:
        """The live stream as served, or None when there is none."""
        return self.stream.description if self.stream is not None else None

    def stats(self) -> VideoStats:
        s, r = self.stream, self.recorder
        return VideoStats(self._slot.put_count, self._slot.dropped, self._streamed,
                          s.encoder_dropped if s is not None else 0, s.clients if s is not None else 0,
                          r.frames if r is not None else 0, r.dropped if r is not None else 0, self._faults)

    def summary_fields(self) -> List[Tuple[str, int]]:
        """Counters for the service's summary line."""
        st = self.stats()
        return [("video_clients", st.clients), ("video_streamed", st.streamed), ("video_dropped", st.dropped),
                ("video_encoder_dropped", st.stream_dropped), ("recorded", st.recorded),
                ("record_dropped", st.record_dropped), ("video_faults", st.faults)]

    def apply(self, new: Config) -> List[str]:
        """The live keys of a reloaded config (LIVE_KEYS); the others wait for a restart."""
        applied = live_changes(self.cfg, new)
        if "video.bitrate_kbps" in applied and self.stream is not None:
            self.stream.set_bitrate(new.video.bitrate_kbps)
        if "recording.quota_mb" in applied and self.recorder is not None:
            self.recorder.set_quota(new.recording.quota_mb)
        self.cfg = self.cfg.model_copy(update={
            "video": self.cfg.video.model_copy(update={"annotate": new.video.annotate,
                                                       "bitrate_kbps": new.video.bitrate_kbps}),
            "recording": self.cfg.recording.model_copy(update={"annotated": new.recording.annotated,
                                                               "quota_mb": new.recording.quota_mb})})
        return applied

    def stop(self) -> None:
        self._slot.close()
        self._thread.join(timeout=5.0)
        for part in (self.stream, self.recorder):
            if part is not None:
                try:
                    part.stop()
                except Exception as exc:  # shutting down: report and go on closing the rest
                    log.warning("video shutdown: %s: %s", type(part).__name__, exc)

    # --- the video thread ------------------------------------------------------------------

    def _run(self) -> None:
        lower_this_thread()
        period = 1.0 / self.cfg.video.fps
        due = 0.0
        while not self._slot.closed:
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(min(wait, 0.5))  # above video.fps: frames meanwhile are replaced by newer ones
                continue
            item = self._slot.take(timeout_s=0.5)
            if item is not None:
                due = time.monotonic() + period
                try:
                    self._send(*item)
                except Exception:  # the video must never take the payload down; count and go on
                    self._faults += 1
                    if self._faults == 1:
                        log.exception("video: frame failed (later failures are counted: video_faults)")
            self._poll()

    def _send(self, frame: Frame, result: Optional[GladResult], state: str) -> None:
        feed = self.stream.feed if self.stream is not None else None
        recorder = self.recorder if self.recorder is not None and self.recorder.active else None
        if feed is None and recorder is None:
            return
        pictures: Dict[bool, object] = {}

        def picture(annotated: bool):
            if annotated not in pictures:
                pictures[annotated] = to_i420(render(frame.image, result, state, self.size_wh, annotated))
            return pictures[annotated]

        if feed is not None and feed.push(picture(self.cfg.video.annotate)):
            self._streamed += 1
        if recorder is not None:
            recorder.push(picture(self.cfg.recording.annotated))

    def _poll(self) -> None:
        if self.stream is not None:
            problem = self.stream.poll()
            if problem is not None:
                log.error("video: stream stopped: %s; detection goes on", problem)
        if self.recorder is not None:
            problem = self.recorder.poll()
            if problem is not None:
                log.error("%s", problem)

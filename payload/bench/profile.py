"""The speed profile of one runner on one clip: per-module time, FPS, capture-to-MAVLink latency.

Two passes over the same frames:

1. decode only: the source read as fast as it goes (the ceiling for end-to-end FPS);
2. the payload loop: read, then the service's frame step (payload.step: runner.process ->
   bearing -> TargetPublisher over a real MavlinkLink (``udpout``) to a UDP socket on 127.0.0.1
   that the bench itself opens and drains, counting the MAVLink messages that arrive).

3. with ``stream``: the payload loop three times more, with the live video on, off, on
   (payload.video: the RTSP server with a real rtspsrc client connected, so every frame is drawn
   and encoded as when a ground station watches; each frame handed over after the publish as the
   service does). The detection loop's FPS with the stream off and on are each the best of two
   alternating passes: on a shared machine one pass's FPS moves by tens of percent with the load.

Unpaced, each frame is read as soon as the previous one went through, and its latency runs from
the moment it is asked of the source (so decoding counts, as the camera's own delivery would).
With ``paced_fps`` the clip plays as a camera at that rate instead, through the service's own
paced path (``capture.pace``: payload.capture.paced, decoded on its own thread, newest frame
wins): frames the loop misses are dropped and counted, frames decoded too late are counted as
late, and latency runs from the frame's capture stamp. Either way it ends when the link thread has
written the frame's last message to the socket (``MavlinkLink.on_written``), or, for a frame
that sends nothing, when its step returns.
"""

import bisect
import logging
import os
import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from payload.capture import EndOfStream, open_source
from payload.config import Config
from payload.errors import SourceError
from payload.geometry import BearingModel, GeoModel
from payload.offline import recording_config
from payload.step import FrameStep
from payload.types import Frame

log = logging.getLogger(__name__)

#: Report order of the modules (others, e.g. a baseline's, follow in the order met).
MODULE_ORDER = ("decode", "wait", "grey", "GAD", "scan", "GMD", "classifier", "region", "LAD", "LMD", "switcher", "tiled",
                "bearing", "mavlink")
_LINK_WAIT_S = 5.0
_DRAIN_S = 0.3
_MAVLINK2_MAGIC = 0xFD
_HEARTBEAT_ID = 0


@dataclass(frozen=True)
class ModuleTime:
    """How often one module ran and how long it took when it did."""

    name: str
    runs: int  # frames on which it ran
    share: float  # runs / frames
    median_ms: float
    p95_ms: float
    mean_ms: float
    p99_ms: float = float("nan")

    def as_dict(self) -> Dict[str, object]:
        return {"name": self.name, "runs": self.runs, "share": self.share, "median_ms": self.median_ms,
                "p95_ms": self.p95_ms, "p99_ms": self.p99_ms, "mean_ms": self.mean_ms}


@dataclass(frozen=True)
class BenchReport:
    source: str
    runner: str
    size_wh: Tuple[int, int]
    frames: int
    modules: List[ModuleTime]
    fps_end_to_end: float  # decode + detect + bearing + send
    fps_without_decode: float  # detect + bearing + send
    fps_decode_only: float  # the source alone (pass 1)
    decode_ratio: float  # fps_end_to_end / fps_decode_only
    latency_p50_ms: float
    latency_p99_ms: float
    latency_max_ms: float
    modes: Dict[str, int]  # frames per detector mode (global / local)
    frames_with_target: int  # frames whose result carried a measured target
    messages_sent: int  # target messages the publisher handed to the link
    messages_received: int  # non-heartbeat MAVLink messages that reached the bench's socket
    providers: List[str]  # ONNX Runtime provider of each session, in model order
    threads: int  # detector.threads (0 = one fewer than the cores, at least 1)
    cpu_count: int
    load_avg: Tuple[float, float, float] = field(default=(0.0, 0.0, 0.0))
    fps_stream_off: float = float("nan")  # pass 2 and the second stream-off pass: the best end-to-end FPS
    fps_stream_on: float = float("nan")  # the two stream-on passes: the best end-to-end FPS; NaN when not run
    stream: str = ""  # what pass 3 streamed, or why it did not run
    stream_frames: int = 0  # frames pass 3 queued for the stream's encoder
    stream_dropped: int = 0  # frames pass 3 dropped (video thread or encoder behind)
    paced_fps: float = 0.0  # the camera rate the clip was played at (0: unpaced)
    frames_dropped: int = 0  # paced: frames the loop did not take before the next one came
    frames_late: int = 0  # paced: frames the source decoded too late for their slot (skipped)

    def module(self, name: str) -> Optional[ModuleTime]:
        return next((m for m in self.modules if m.name == name), None)

    def as_dict(self) -> Dict[str, object]:
        out = {k: getattr(self, k) for k in (
            "source", "runner", "frames", "fps_end_to_end", "fps_without_decode", "fps_decode_only",
            "decode_ratio", "latency_p50_ms", "latency_p99_ms", "latency_max_ms", "modes", "frames_with_target",
            "messages_sent", "messages_received", "providers", "threads", "cpu_count", "fps_stream_off", "fps_stream_on", "stream",
            "stream_frames", "stream_dropped", "paced_fps", "frames_dropped", "frames_late")}
        out["size_wh"] = list(self.size_wh)
        out["load_avg"] = list(self.load_avg)
        out["modules"] = [m.as_dict() for m in self.modules]
        return out


class UdpSink:
    """A UDP socket on 127.0.0.1 standing in for the autopilot: counts the MAVLink messages that arrive."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.by_msgid: Counter = Counter()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-udp-sink", daemon=True)

    @property
    def non_heartbeat(self) -> int:
        return sum(n for msgid, n in self.by_msgid.items() if msgid != _HEARTBEAT_ID)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(4096)
            except socket.timeout:
                continue
            except OSError:
                return
            # MAVLink 2 frame: magic, len, incompat, compat, seq, sysid, compid, msgid (3 bytes, LE)
            if len(data) >= 10 and data[0] == _MAVLINK2_MAGIC:
                self.by_msgid[data[7] | data[8] << 8 | data[9] << 16] += 1

    def __enter__(self) -> "UdpSink":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        time.sleep(_DRAIN_S)  # the last datagrams are still in flight
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.sock.close()


def decode_only_fps(cfg: Config, source: str, frames: int = 0) -> Tuple[float, int]:
    """Frames per second of reading ``source`` alone, and how many frames were read."""
    capture = recording_config(cfg, source).capture
    n = 0
    with open_source(capture) as frames_in:
        t0 = time.perf_counter()
        for _frame in frames_in:
            n += 1
            if frames and n >= frames:
                break
        elapsed = time.perf_counter() - t0
    return (n / elapsed if elapsed > 0 else float("nan")), n


def _module_times(per_frame: List[Dict[str, float]]) -> List[ModuleTime]:
    names = [m for m in MODULE_ORDER if any(m in t for t in per_frame)]
    names += list(dict.fromkeys(m for t in per_frame for m in t if m not in MODULE_ORDER))
    out = []
    for name in names:
        ms = np.array([t[name] for t in per_frame if name in t], np.float64)
        out.append(ModuleTime(name, int(len(ms)), len(ms) / float(len(per_frame)), float(np.median(ms)),
                              float(np.percentile(ms, 95)), float(ms.mean()), float(np.percentile(ms, 99))))
    return out


def _percentile(values: List[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


@dataclass
class _Pass:
    per_frame: List[Dict[str, float]] = field(default_factory=list)
    latency_ms: List[float] = field(default_factory=list)
    modes: Counter = field(default_factory=Counter)
    with_target: int = 0
    sent: int = 0
    size_wh: Tuple[int, int] = (0, 0)
    elapsed_s: float = 0.0
    dropped: int = 0
    late: int = 0


class _WriteClock:
    """When the link thread wrote (or dropped) each outbox message: (sequence number, monotonic ns)."""

    def __init__(self, link) -> None:
        self.written: List[Tuple[int, int]] = []
        link.on_written = self._on_written

    def _on_written(self, seq: int) -> None:
        self.written.append((seq, time.monotonic_ns()))

    def at(self, seq: int) -> Optional[int]:
        """When message ``seq`` had left (messages leave in order), or None if it has not yet."""
        i = bisect.bisect_left(self.written, (seq, -1))
        return self.written[i][1] if i < len(self.written) else None


def _loop_pass(cfg: Config, capture, runner, link, publisher, frames: int, video=None,
               paced_fps: float = 0.0) -> _Pass:
    """One pass of the payload loop over the clip: read, then the service's frame step (detect,
    bearing, publish, hand to video); paced, the clip plays as a camera at ``paced_fps``."""
    bearings = BearingModel(cfg.camera)
    step = FrameStep(runner, bearings, GeoModel(cfg.target, bearings), link, publisher, video=video)
    clock = _WriteClock(link)
    out = _Pass()
    ends: List[Tuple[int, int, int]] = []  # per frame: (start ns, end of step ns, last message queued or 0)
    if paced_fps:  # the service's paced path (capture.pace), at the bench's rate
        capture = capture.model_copy(update={"pace": True, "fps": paced_fps})
    source = open_source(capture)
    source.prepare = getattr(runner, "prepare", None)  # as the service: GLAD's work on the capture thread
    with source as frames_in:
        runner.reset()
        t_start = time.perf_counter()
        while not frames or len(out.per_frame) < frames:
            t_ask = time.perf_counter()
            t_ask_ns = time.monotonic_ns()
            try:
                frame = frames_in.read(timeout_s=1.0)
            except EndOfStream:
                break
            if frame is None:
                continue
            t_decoded = time.perf_counter()
            outcome = step(frame)
            ends.append((frame.t_capture_ns if paced_fps else t_ask_ns, time.monotonic_ns(),
                         link.last_queued if outcome.sent else 0))
            result = outcome.result
            timings = dict(outcome.timings_ms)
            # unpaced: the source decoding; paced: waiting for the camera's next frame (decoded on its thread)
            timings["wait" if paced_fps else "decode"] = (t_decoded - t_ask) * 1000.0
            out.per_frame.append(timings)
            out.modes[result.mode] += 1
            out.with_target += bool(result.target is not None and result.target.measured)
            out.sent += outcome.sent
            out.size_wh = frame.size_wh
        out.elapsed_s = time.perf_counter() - t_start
        if paced_fps:
            out.dropped, out.late = source.stats.dropped, source.stats.late
    deadline = time.monotonic() + _DRAIN_S  # the link thread writes the last frame's messages
    while ends and ends[-1][2] and clock.at(ends[-1][2]) is None and time.monotonic() < deadline:
        time.sleep(0.005)
    link.on_written = None
    for start_ns, step_ns, seq in ends:
        sent_ns = clock.at(seq) if seq else None
        out.latency_ms.append(((sent_ns if sent_ns is not None else step_ns) - start_ns) / 1e6)
    return out


def _fps(p: _Pass) -> float:
    return len(p.per_frame) / p.elapsed_s if p.per_frame and p.elapsed_s > 0 else float("nan")


def open_watched_stream(cfg: Config):
    """(VideoOutput serving cfg.video over RTSP on a free port, its rtspsrc client pipeline), both
    running and connected; or (None, why) when the video cannot run here."""
    from payload.config import config_with
    from payload.video.gst import VideoUnavailable, import_gst
    from payload.video.output import VideoOutput

    try:
        Gst, _ = import_gst()
    except VideoUnavailable as exc:
        return None, str(exc)
    vcfg = config_with(cfg, **{"video.enabled": True, "video.transport": "rtsp", "video.rtsp_port": 0,
                               "video.advertise_host": "127.0.0.1", "recording.enabled": False})
    video = VideoOutput.open(vcfg)
    if video is None:
        return None, "video unavailable (see the log)"
    uri = video.description.uri
    client = None
    if uri.startswith("rtsp:"):  # a ground station on another machine: receive only, decode nothing here
        client = Gst.parse_launch("rtspsrc location=%s latency=0 ! fakesink sync=false" % uri)
        client.set_state(Gst.State.PLAYING)
        # The server prepares the media (and answers the client's DESCRIBE, then SETUP and PLAY)
        # only once frames arrive: until the client holds a session, blank frames are fed, or on a
        # loaded host the measured passes ran, encoding nothing, before it connected.
        d = video.description
        blank = np.zeros((d.height, d.width, 3), np.uint8)
        deadline, i = time.monotonic() + 2 * _LINK_WAIT_S, 0
        while (video.stream.feed is None or video.stream.clients < 1) and time.monotonic() < deadline:
            video.submit(Frame(blank, i, time.monotonic_ns(), 0), None, "searching")
            i += 1
            time.sleep(0.05)
        # ... and settled, so that the measured passes' counts (taken against video.stats() then)
        # hold none of them: no counter has moved for two frame periods of the video thread. (A
        # frame taken while no client watched is counted nowhere, so the counters never add up.)
        quiet_s = max(0.2, 2.0 / vcfg.video.fps)
        deadline, last, since = time.monotonic() + _LINK_WAIT_S, None, time.monotonic()
        while time.monotonic() < deadline:
            st = video.stats()
            now = (st.submitted, st.dropped, st.streamed, st.stream_dropped, st.faults)
            if now != last:
                last, since = now, time.monotonic()
            elif time.monotonic() - since >= quiet_s:
                break
            time.sleep(0.05)
    return (video, client), ""


def run_bench(cfg: Config, source: str, runner, runner_name: str = "glad", frames: int = 0,
              stream: bool = False, paced_fps: float = 0.0) -> BenchReport:
    """Profile ``runner`` (see payload.bench.runners) on the video file or image folder ``source``;
    with ``stream``, once more with the live video on; with ``paced_fps``, played as a camera at
    that rate."""
    from payload.bench.runners import onnx_sessions
    from payload.mavlink.link import MavlinkLink
    from payload.mavlink.outputs import TargetPublisher

    fps_decode, _ = decode_only_fps(cfg, source, frames)
    capture = recording_config(cfg, source).capture
    on: List[_Pass] = []
    off_again: List[_Pass] = []
    stream_text, stream_frames, stream_dropped = "not measured (--no-stream)", 0, 0
    with UdpSink() as sink:
        link_cfg = cfg.mavlink.model_copy(update={"enabled": True, "connection": "udpout:127.0.0.1:%d" % sink.port})
        with MavlinkLink(link_cfg) as link:
            deadline = time.monotonic() + _LINK_WAIT_S
            while not link.status.connected and time.monotonic() < deadline:
                time.sleep(0.01)
            publisher = TargetPublisher(link, cfg.mavlink.outputs)
            off = _loop_pass(cfg, capture, runner, link, publisher, frames, paced_fps=paced_fps)
            time.sleep(_DRAIN_S)  # the last datagrams of pass 2 are still in flight
            received = sink.non_heartbeat
            if stream:
                watched, why = open_watched_stream(cfg)
                if watched is None:
                    stream_text = "not measured: " + why
                else:
                    video, client = watched
                    before = video.stats()  # the blank frames that brought the client in
                    try:
                        for video_on in (video, None, video):
                            (on if video_on else off_again).append(
                                _loop_pass(cfg, capture, runner, link, publisher, frames, video_on, paced_fps))
                        st = video.stats()
                        d = video.description
                        stream_text = "%s %dx%d %g fps %d kbit/s %s, %d client(s)" % (
                            d.uri, d.width, d.height, d.fps, d.bitrate_kbps, d.encoder, st.clients)
                        stream_frames = st.streamed - before.streamed
                        stream_dropped = st.dropped + st.stream_dropped - before.dropped - before.stream_dropped
                    finally:
                        if client is not None:
                            from payload.video.gst import import_gst

                            client.set_state(import_gst()[0].State.NULL)
                        video.stop()
    per_frame, latency_ms = off.per_frame, off.latency_ms
    if not per_frame:
        raise SourceError("bench %s: the source gave no frame" % source)
    n = len(per_frame)
    decode_s = sum(t.get("decode", t.get("wait", 0.0)) for t in per_frame) / 1000.0
    fps_e2e = n / off.elapsed_s
    providers = [m.providers[0] for m in onnx_sessions(runner)]
    return BenchReport(
        source=source, runner=runner_name, size_wh=off.size_wh, frames=n, modules=_module_times(per_frame),
        fps_end_to_end=fps_e2e, fps_without_decode=n / max(off.elapsed_s - decode_s, 1e-9),
        fps_decode_only=fps_decode, decode_ratio=fps_e2e / fps_decode, latency_p50_ms=_percentile(latency_ms, 50),
        latency_p99_ms=_percentile(latency_ms, 99), latency_max_ms=max(latency_ms), modes=dict(off.modes),
        frames_with_target=off.with_target, messages_sent=off.sent, messages_received=received,
        providers=providers, threads=cfg.detector.threads, cpu_count=os.cpu_count() or 0,
        load_avg=tuple(os.getloadavg()) if hasattr(os, "getloadavg") else (0.0, 0.0, 0.0),
        fps_stream_off=max(_fps(p) for p in [off] + off_again) if on else float("nan"),
        fps_stream_on=max(_fps(p) for p in on) if on else float("nan"),
        stream=stream_text, stream_frames=stream_frames, stream_dropped=stream_dropped,
        paced_fps=paced_fps, frames_dropped=off.dropped, frames_late=off.late,
    )

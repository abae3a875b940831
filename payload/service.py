"""``glad-payload run``: the long-lived service loop.

The newest frame goes through the frame step (payload.step: GLAD -> bearing -> MAVLink ->
records), one at a time. The loop never blocks on the camera or the link: a lost camera is
reconnected by its source (read() returns None meanwhile), a lost autopilot by the link thread,
and the step only queues its messages for the link thread to write. systemd hears READY=1 once the models are
loaded and the first frame arrived, WATCHDOG=1 only after frames that went all the way through
(a stalled camera, a detector failing on every frame or a hung reload stop the pings), and a
STATUS= line every summary interval. SIGHUP reloads the config: each component applies its own
section and returns the keys it applied, restart-only keys are refused in one line, an invalid
file keeps the running config. SIGTERM/SIGINT finish the current frame, flush the records and
close the link. The MAVLink camera protocol (payload.mavlink.camera) hands an operator's track
point to the loop, which designates it to GLAD at the start of the next frame and reports the
outcome after each frame. Records (detections.csv, decisions.csv) that cannot be written are reported
once and detection goes on. The live video and the recording (payload.video) get each processed
frame through a slot of one that never makes the loop wait.
"""

import logging
import os
import signal
import threading
import time
from dataclasses import dataclass
from typing import Callable, List, Optional

from payload.capture import open_source
from payload.capture.base import EndOfStream, FrameSource
from payload.config import (
    Config,
    LoggingConfig,
    changed_keys,
    config_with,
    flat_config,
    is_restart_key,
    load_run_config,
    section_changes,
)
from payload.detect.pipeline import Glad, GladResult
from payload.errors import ConfigError
from payload.geometry import BearingModel, GeoModel
from payload.records import DECISION_FIELDS, HEADER, CsvLog
from payload.sdnotify import Notifier
from payload.step import FrameStep, state_text
from payload.types import Frame
from payload.video import StreamDescription

log = logging.getLogger(__name__)


@dataclass
class LoopStats:
    frames: int = 0  # frames processed by GLAD
    skipped: int = 0  # frames read while detection was disabled by command
    hits: int = 0  # frames with a measured target
    faults: int = 0  # per-frame exceptions survived
    interval_frames: int = 0
    interval_start_s: float = 0.0


class Service:
    """The payload: one instance per process. ``run()`` returns the process exit code."""

    def __init__(self, cfg: Config, config_path: Optional[str] = None, max_frames: int = 0,
                 on_result: Optional[Callable[[Frame, GladResult], None]] = None, verbose: bool = False,
                 stream=None) -> None:
        self.cfg = cfg
        self.config_path = config_path
        self.max_frames = max_frames
        self.on_result = on_result  # the demo draws frames through this
        self.verbose = verbose  # -v: DEBUG logging whatever logging.level says
        self.notifier = Notifier()
        self.stats = LoopStats()
        self._stop = threading.Event()
        self._reload = threading.Event()
        self._ready_sent = False
        self.bearings = BearingModel(cfg.camera)
        self.geo = GeoModel(cfg.target, self.bearings)
        self.stream = stream  # a payload.video.StreamDescription to announce instead of the video output's
        self.link = None
        self.publisher = None
        self.camera = None  # payload.mavlink.camera.CameraProtocol
        self.source: Optional[FrameSource] = None
        self.glad: Optional[Glad] = None
        self.step: Optional[FrameStep] = None  # built by _start from the parts that run
        self._detections_csv: Optional[CsvLog] = None
        self._decisions_csv: Optional[CsvLog] = None
        self.video = None  # payload.video.output.VideoOutput while video or recording runs
        self._last_watchdog_s = 0.0
        self._last_result: Optional[GladResult] = None
        self._faults_reported = 0
        self._fault_report_s = 0.0

    # --- signals --------------------------------------------------------------------------

    def install_signal_handlers(self) -> None:
        signal.signal(signal.SIGTERM, lambda *_: self.stop())
        signal.signal(signal.SIGINT, lambda *_: self.stop())
        signal.signal(signal.SIGHUP, lambda *_: self._reload.set())

    def stop(self) -> None:
        self._stop.set()

    # --- start-up and shutdown ------------------------------------------------------------

    def _start(self) -> None:
        cfg = self.cfg
        self.notifier.status("loading models")
        self.glad = Glad(cfg.detector)  # loads and warms up the ONNX models
        if cfg.video.enabled or cfg.recording.enabled:  # before the link: the camera protocol announces the stream
            from payload.video.output import VideoOutput

            self.video = VideoOutput.open(cfg)
        if cfg.mavlink.enabled:
            from payload.mavlink.camera import CameraProtocol
            from payload.mavlink.link import MavlinkLink
            from payload.mavlink.outputs import TargetPublisher

            self.link = MavlinkLink(cfg.mavlink)
            self.link.position_rate_hz = self._position_rate_hz(cfg)
            self.camera = CameraProtocol(self.link, cfg, self.stream or self.stream_description())
            self.link.start()
            self.publisher = TargetPublisher(self.link, cfg.mavlink.outputs)
            self.publisher.camera = self.camera
        out = cfg.outputs
        if out.directory:
            try:
                os.makedirs(out.directory, exist_ok=True)
            except OSError:
                pass  # the first write reports it, once; detection goes on without records
            self._detections_csv = CsvLog(os.path.join(out.directory, "detections.csv"), HEADER,
                                          out.max_file_bytes, out.keep_files)
            self._decisions_csv = CsvLog(os.path.join(out.directory, "decisions.csv"), DECISION_FIELDS,
                                         out.max_file_bytes, out.keep_files)
        self.notifier.status("opening %s" % cfg.capture.source)
        self.step = FrameStep(self.glad, self.bearings, self.geo, self.link, self.publisher, self.camera,
                              self._detections_csv, self._decisions_csv, self.video)
        self.source = open_source(cfg.capture)
        self.source.prepare = self.glad.prepare  # grey levels, camera motion, GAD's input: made on the capture thread
        self.source.open()
        log.info("started source=%s mavlink=%s outputs=%s", cfg.capture.source,
                 cfg.mavlink.connection if cfg.mavlink.enabled else "off", cfg.outputs.directory or "off")

    @staticmethod
    def _position_rate_hz(cfg: Config) -> float:
        """GLOBAL_POSITION_INT is asked of the autopilot only when geo outputs can use it."""
        return cfg.mavlink.camera.position_rate_hz if cfg.target.span_m is not None else 0.0

    def _shutdown(self) -> None:
        self.notifier.stopping()
        if self.camera is not None:
            self.camera.cancel("shutting down")
        for closer in (self.source, self.video, self.link, self._detections_csv, self._decisions_csv):
            if closer is None:
                continue
            try:
                (closer.stop if hasattr(closer, "stop") else closer.close)()
            except Exception as exc:  # shutting down: report and go on closing the rest
                log.warning("shutdown: %s: %s", type(closer).__name__, exc)
        self._summary(final=True)

    # --- the loop -------------------------------------------------------------------------

    def run(self) -> int:
        try:
            self._start()
            self.stats.interval_start_s = time.monotonic()
            while not self._stop.is_set():
                if self._reload.is_set():
                    self._reload.clear()
                    self.reload()
                try:
                    frame = self.source.read(timeout_s=0.5)
                except EndOfStream:
                    log.info("source finished")
                    break
                if frame is not None:
                    self._step(frame)
                    if self.max_frames and self.stats.frames >= self.max_frames:
                        break
                self._maybe_summary()
        finally:
            self._shutdown()
        return 0

    def _step(self, frame: Frame) -> None:
        if not self._ready_sent:
            self.notifier.ready()
            self._ready_sent = True
            log.info("ready first_frame=%d size=%dx%d", frame.index, *frame.size_wh)
        try:
            outcome = self.step(frame)
            if outcome.result is not None and self.on_result is not None:
                self.on_result(frame, outcome.result)
        except Exception as exc:  # one bad frame must not take the payload down; count and go on
            self._fault(frame, exc)
            return
        result = outcome.result
        self.stats.interval_frames += 1
        if result is None:  # detection disabled by command: paused, and alive
            self.stats.skipped += 1
            self._watchdog()
            return
        self._last_result = result
        self.stats.frames += 1
        self.stats.hits += bool(result.target is not None and result.target.measured)
        self._watchdog()  # only a frame that went all the way through says we are alive

    def _fault(self, frame: Frame, exc: Exception) -> None:
        """Count a failed frame; the first is logged with its traceback, then one line per summary interval."""
        self.stats.faults += 1
        now = time.monotonic()
        if self.stats.faults == 1:
            log.exception("frame=%d fault (total faults=1); later faults are summed up, one line per %.0f s",
                          frame.index, self.cfg.logging.summary_interval_s)
        elif now - self._fault_report_s >= self.cfg.logging.summary_interval_s:
            log.error("frame faults=%d since the last report (total %d), last: frame=%d %s: %s",
                      self.stats.faults - self._faults_reported, self.stats.faults, frame.index,
                      type(exc).__name__, " ".join(str(exc).split())[:200])
        else:
            return
        self._faults_reported = self.stats.faults
        self._fault_report_s = now

    def _watchdog(self) -> None:
        interval = self.notifier.watchdog_interval_s
        now = time.monotonic()
        if interval is None or now - self._last_watchdog_s >= interval / 2.0:
            self.notifier.watchdog()
            self._last_watchdog_s = now

    # --- reporting ------------------------------------------------------------------------

    def stream_description(self) -> Optional[StreamDescription]:
        """The live video as served (for VIDEO_STREAM_INFORMATION), or None when there is none."""
        return self.video.description if self.video is not None else None

    def _state(self) -> str:
        return state_text(self._last_result, self.glad is not None and self.glad.designated)

    def _maybe_summary(self) -> None:
        if time.monotonic() - self.stats.interval_start_s >= self.cfg.logging.summary_interval_s:
            self._summary()

    def _summary(self, final: bool = False) -> None:
        now = time.monotonic()
        elapsed = max(now - self.stats.interval_start_s, 1e-6)
        fps = self.stats.interval_frames / elapsed
        src = self.source.stats if self.source is not None else None
        target = "-"
        if self._last_result is not None and self._last_result.target is not None:
            cx, cy = self._last_result.target.center
            target = "%.0f,%.0f" % (cx, cy)
            # the targets reported beside the one sent (detector.targets.max > 1): id@x,y each
            others = [t for t in self._last_result.targets if not t.primary]
            if others:
                target += " others=" + ";".join("%d@%.0f,%.0f" % ((t.id,) + t.target.center) for t in others)
        link = "off"
        if self.link is not None:
            st = self.link.status
            link = "up" if st.autopilot_seen else "lost"
            if not st.detection_enabled:
                link += ",disabled"
        line = ("fps=%.1f frames=%d drops=%d reconnects=%d state=%s target=%s link=%s faults=%d"
                % (fps, self.stats.frames, src.dropped if src else 0, src.reconnects if src else 0,
                   self._state(), target, link, self.stats.faults))
        # counters of things survived, shown once they happen
        extra = [("late", src.late if src else 0), ("unreadable", src.unreadable if src else 0),
                 ("attitude_not_finite", self.bearings.attitude_not_finite),
                 ("bearing_not_finite", self.bearings.bearing_not_finite),
                 ("rows_lost", sum(c.lost for c in (self._detections_csv, self._decisions_csv) if c is not None))]
        if self.video is not None:
            extra += self.video.summary_fields()
        line += "".join(" %s=%d" % (name, n) for name, n in extra if n)
        log.info("%s%s", "final " if final else "", line)
        self.notifier.status(line)
        self.stats.interval_frames = 0
        self.stats.interval_start_s = now

    # --- reload ---------------------------------------------------------------------------

    def reload(self) -> bool:
        """Re-read the config file; each component applies its own section and says which keys it
        applied. A changed key that none applied (restart-only) keeps its running value and is
        named in one line. An invalid file keeps the whole running config. Returns True if read."""
        if not self.config_path:
            log.warning("reload: no config file (running on built-in defaults); nothing to reload")
            return False
        self.notifier.reloading()
        try:
            return self._reload_from(load_run_config(self.config_path, running=self.cfg))
        except ConfigError as exc:
            for line in exc.problems:
                log.error("reload rejected, keeping the running config: %s", line)
            return False
        except Exception as exc:  # a reload must never take the payload down
            log.error("reload failed, keeping the running config: %s: %s", type(exc).__name__,
                      " ".join(str(exc).split())[:300])
            return False
        finally:
            self.notifier.ready()

    def _reload_from(self, new: Config) -> bool:
        running = flat_config(self.cfg)
        changed = changed_keys(self.cfg, new)
        pending = [k for k in changed if is_restart_key(k)]
        if pending:  # restart-only keys keep their running values, so a later reload reports them again
            new = config_with(new, **{k: running[k] for k in pending})
        applied = set(self._apply(new))
        refused = [k for k in changed if k not in pending and k not in applied]
        if refused:  # changed, and no component took it live
            new = config_with(new, **{k: running[k] for k in refused})
        self.cfg = new
        not_applied = sorted(pending + refused)
        if not_applied:
            log.warning("reload: these changes need a restart and are not applied yet: %s", ", ".join(not_applied))
        log.info("reload: applied %s changed=%s", self.config_path, ",".join(sorted(applied & set(changed))) or "nothing")
        return True

    def _apply(self, new: Config) -> List[str]:
        """Hand each running component its section; the union of the keys they applied."""
        applied = self.glad.update_config(new.detector) if self.glad is not None else []
        applied += self.bearings.apply(new.camera)
        applied += self.geo.apply(new.target)
        applied += self._apply_logging(new.logging)
        if self.publisher is not None:
            applied += self.publisher.apply(new.mavlink.outputs)
        if self.link is not None:
            applied += self.link.apply(new.mavlink)
            self.link.position_rate_hz = self._position_rate_hz(new)
        if self.camera is not None:
            applied += self.camera.apply(new)
        if self.video is not None:
            applied += self.video.apply(new)
        else:  # no video runs (off, or GStreamer missing): its live keys are only kept in the config
            from payload.video.output import live_changes

            applied += live_changes(self.cfg, new)
        return applied

    def _apply_logging(self, cfg: LoggingConfig) -> List[str]:
        """The logging section: the root level (unless -v) and the summary interval (read from self.cfg)."""
        if not self.verbose:
            logging.getLogger().setLevel(cfg.level)
        return section_changes(self.cfg.logging, cfg, "logging")


def main_run(args) -> int:
    cfg = load_run_config(args.config)
    verbose = bool(getattr(args, "verbose", False))
    logging.getLogger().setLevel(logging.DEBUG if verbose else cfg.logging.level)
    service = Service(cfg, config_path=args.config, max_frames=args.frames, verbose=verbose)
    service.install_signal_handlers()
    return service.run()

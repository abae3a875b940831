"""``glad-payload run``: the long-lived service loop.

source -> GLAD -> bearing -> MAVLink, always on the newest frame. The loop never blocks on
the camera or the link: a lost camera is reconnected by its source (read() returns None
meanwhile), a lost autopilot by the link thread. systemd hears READY=1 once the models are
loaded and the first frame arrived, WATCHDOG=1 only while frames are being processed, and a
STATUS= line every summary interval. SIGHUP reloads the config (an invalid file keeps the
running one); SIGTERM/SIGINT finish the current frame, flush the logs and close the link.
"""

import csv
import logging
import os
import signal
import threading
import time
from dataclasses import dataclass
from typing import Callable, List, Optional

from payload.capture import open_source
from payload.capture.base import EndOfStream, FrameSource
from payload.config import Config, changed_keys, config_with, flat_config, load_config, restart_required
from payload.detect.pipeline import Glad, GladResult
from payload.errors import ConfigError
from payload.geometry import CameraModel, bearing_for, mount_from_config
from payload.records import DetectionsCsvWriter
from payload.sdnotify import Notifier
from payload.types import Bearing, Frame

log = logging.getLogger(__name__)


@dataclass
class LoopStats:
    frames: int = 0  # frames processed by GLAD
    skipped: int = 0  # frames read while detection was disabled by command
    hits: int = 0  # frames with a measured target
    faults: int = 0  # per-frame exceptions survived
    interval_frames: int = 0
    interval_start_s: float = 0.0


class DecisionsCsvWriter:
    """One row per processed frame: what the switcher decided and what was sent."""

    FIELDS = ["frame", "t_capture_ns", "t_wall_ns", "mode", "state", "module", "score", "x", "y", "w", "h",
              "region_x", "region_y", "region_w", "region_h", "az_body_rad", "el_body_rad", "az_level_rad",
              "el_level_rad", "messages_sent"]

    def __init__(self, path: str) -> None:
        self._fh = open(path, "w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._fh)
        self._csv.writerow(self.FIELDS)

    def write(self, frame: Frame, result: GladResult, bearing: Optional[Bearing], sent: int) -> None:
        t = result.target
        box = [""] * 4 if t is None else ["%.1f" % t.xyxy[0], "%.1f" % t.xyxy[1],
                                          "%.1f" % (t.xyxy[2] - t.xyxy[0]), "%.1f" % (t.xyxy[3] - t.xyxy[1])]
        r = result.region_xyxy
        region = [""] * 4 if r is None else [int(r[0]), int(r[1]), int(r[2] - r[0]), int(r[3] - r[1])]
        angles = [""] * 4
        if bearing is not None:
            angles = ["%.5f" % v if v is not None else "" for v in
                      (bearing.az_body_rad, bearing.el_body_rad, bearing.az_level_rad, bearing.el_level_rad)]
        state = "searching" if t is None else ("detected" if t.measured else "coasting")
        self._csv.writerow([frame.index, frame.t_capture_ns, frame.t_wall_ns, result.mode, state,
                            "" if t is None else t.module, "" if t is None else "%.3f" % t.score,
                            *box, *region, *angles, int(sent)])
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()


class Service:
    """The payload: one instance per process. ``run()`` returns the process exit code."""

    def __init__(self, cfg: Config, config_path: Optional[str] = None, max_frames: int = 0,
                 on_result: Optional[Callable[[Frame, GladResult], None]] = None) -> None:
        self.cfg = cfg
        self.config_path = config_path
        self.max_frames = max_frames
        self.on_result = on_result  # the demo draws frames through this
        self.notifier = Notifier()
        self.stats = LoopStats()
        self._stop = threading.Event()
        self._reload = threading.Event()
        self._ready_sent = False
        self._camera: Optional[CameraModel] = None
        self._mount = None
        self.link = None
        self.publisher = None
        self.source: Optional[FrameSource] = None
        self.glad: Optional[Glad] = None
        self._detections_csv: Optional[DetectionsCsvWriter] = None
        self._decisions_csv: Optional[DecisionsCsvWriter] = None
        self._last_watchdog_s = 0.0
        self._last_result: Optional[GladResult] = None

    # --- signals --------------------------------------------------------------------------

    def install_signal_handlers(self) -> None:
        signal.signal(signal.SIGTERM, lambda *_: self.stop())
        signal.signal(signal.SIGINT, lambda *_: self.stop())
        signal.signal(signal.SIGHUP, lambda *_: self._reload.set())

    def stop(self) -> None:
        self._stop.set()

    def request_reload(self) -> None:
        self._reload.set()

    # --- start-up and shutdown ------------------------------------------------------------

    def _start(self) -> None:
        cfg = self.cfg
        self.notifier.status("loading models")
        self.glad = Glad(cfg.detector)  # loads and warms up the ONNX models
        if cfg.mavlink.enabled:
            from payload.mavlink.link import MavlinkLink
            from payload.mavlink.outputs import TargetPublisher

            self.link = MavlinkLink(cfg.mavlink)
            self.link.start()
            self.publisher = TargetPublisher(self.link, cfg.mavlink.outputs)
        if cfg.outputs.directory:
            os.makedirs(cfg.outputs.directory, exist_ok=True)
            self._detections_csv = DetectionsCsvWriter(os.path.join(cfg.outputs.directory, "detections.csv"))
            self._decisions_csv = DecisionsCsvWriter(os.path.join(cfg.outputs.directory, "decisions.csv"))
        self.notifier.status("opening %s" % cfg.capture.source)
        self.source = open_source(cfg.capture)
        self.source.open()
        log.info("started source=%s mavlink=%s outputs=%s", cfg.capture.source,
                 cfg.mavlink.connection if cfg.mavlink.enabled else "off", cfg.outputs.directory or "off")

    def _shutdown(self) -> None:
        self.notifier.stopping()
        for closer in (self.source, self.link, self._detections_csv, self._decisions_csv):
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
        self._watchdog()
        if self.link is not None and not self.link.detection_enabled:
            self.stats.skipped += 1
            self.stats.interval_frames += 1
            return
        try:
            result = self.glad.process(frame)
            bearing = self._bearing(frame, result)
            sent = 0
            if self.publisher is not None:
                sent = self.publisher.publish(result.target, bearing, frame.size_wh)
            if self._detections_csv is not None:
                self._detections_csv.write(frame.index, result.detections)
            if self._decisions_csv is not None:
                self._decisions_csv.write(frame, result, bearing, sent)
            if self.on_result is not None:
                self.on_result(frame, result)
        except Exception:  # one bad frame must not take the payload down; count and go on
            self.stats.faults += 1
            log.exception("frame=%d fault (total faults=%d)", frame.index, self.stats.faults)
            return
        self._last_result = result
        self.stats.frames += 1
        self.stats.interval_frames += 1
        self.stats.hits += bool(result.target is not None and result.target.measured)

    def _bearing(self, frame: Frame, result: GladResult) -> Optional[Bearing]:
        if result.target is None:
            return None
        if self._camera is None or self._camera.image_wh != frame.size_wh:
            self._camera = CameraModel.from_config(self.cfg.camera, frame.size_wh)
            self._mount = mount_from_config(self.cfg.camera.mount)
        attitude = self.link.attitude_at(frame.t_capture_ns) if self.link is not None else None
        return bearing_for(result.target, self._camera, self._mount, attitude)

    def _watchdog(self) -> None:
        interval = self.notifier.watchdog_interval_s
        now = time.monotonic()
        if interval is None or now - self._last_watchdog_s >= interval / 2.0:
            self.notifier.watchdog()
            self._last_watchdog_s = now

    # --- reporting ------------------------------------------------------------------------

    def _state(self) -> str:
        r = self._last_result
        if r is None or r.target is None:
            return "searching"
        return "tracking" if r.target.measured else "coasting"

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
        link = "off"
        if self.link is not None:
            st = self.link.status
            link = "up" if st.autopilot_seen else "lost"
            if not st.detection_enabled:
                link += ",disabled"
        line = ("fps=%.1f frames=%d drops=%d reconnects=%d state=%s target=%s link=%s faults=%d"
                % (fps, self.stats.frames, src.dropped if src else 0, src.reconnects if src else 0,
                   self._state(), target, link, self.stats.faults))
        log.info("%s%s", "final " if final else "", line)
        self.notifier.status(line)
        self.stats.interval_frames = 0
        self.stats.interval_start_s = now

    # --- reload ---------------------------------------------------------------------------

    def reload(self) -> bool:
        """Re-read the config file; apply what can change live. Returns True if applied."""
        if not self.config_path:
            log.warning("reload: no config file (running on built-in defaults); nothing to reload")
            return False
        self.notifier.reloading()
        try:
            new = load_config(self.config_path)
        except ConfigError as exc:
            for line in exc.problems:
                log.error("reload rejected, keeping the running config: %s", line)
            self.notifier.ready()
            return False
        pending: List[str] = restart_required(self.cfg, new)
        live = [k for k in changed_keys(self.cfg, new) if k not in pending]
        if pending:
            log.warning("reload: these changes need a restart and are not applied yet: %s", ", ".join(pending))
        self.glad.update_config(new.detector)
        if self.publisher is not None:
            self.publisher.cfg = new.mavlink.outputs
        logging.getLogger().setLevel(new.logging.level)
        self._camera = None  # camera intrinsics/mount may have changed
        # Restart-only keys keep their running values until a restart, so a later reload reports them again.
        running = flat_config(self.cfg)
        self.cfg = config_with(new, **{key: running[key] for key in pending})
        log.info("reload: applied %s changed=%s", self.config_path, ",".join(live) or "nothing")
        self.notifier.ready()
        return True


def main_run(args) -> int:
    cfg = load_config(args.config)
    logging.getLogger().setLevel(cfg.logging.level if not getattr(args, "verbose", False) else logging.DEBUG)
    service = Service(cfg, config_path=args.config, max_frames=args.frames)
    service.install_signal_handlers()
    return service.run()


"""``glad-payload demo``: the whole payload with no camera and no aircraft.

A synthetic air-to-air scene stands in for the camera and the fake autopilot rig
(sitl/fake_autopilot.py) for the vehicle, on loopback UDP. The service runs exactly as in
flight; a live status line shows progress and a summary closes the run. The output folder
gets the annotated MP4, detections.csv, decisions.csv and the autopilot's record. The annotated
live video is served over RTSP (video.rtsp_port, 8554 by default; RTP/UDP when the RTSP server
is missing or the port taken) and its URI printed at the first frame, to open in VLC or a
ground station while the demo runs; without GStreamer the demo runs without it.
"""

import json
import logging
import os
import socket
import subprocess
import sys
import time
from collections import Counter
from typing import Dict, List, Optional

import numpy as np

from payload.annotate import VideoOut, draw_result
from payload.config import Config, config_with, load_config
from payload.detect.pipeline import GladResult
from payload.errors import SourceError
from payload.service import Service
from payload.types import Frame

log = logging.getLogger(__name__)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FAKE_AUTOPILOT = os.path.join(REPO, "sitl", "fake_autopilot.py")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_fake_autopilot(port: int, record: str, extra=()) -> subprocess.Popen:
    if not os.path.exists(FAKE_AUTOPILOT):
        raise SourceError("demo: %s not found: the demo runs from a source checkout" % FAKE_AUTOPILOT)
    return subprocess.Popen(
        [sys.executable, FAKE_AUTOPILOT, "--listen", "udpin:127.0.0.1:%d" % port, "--record", record, *extra],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )


def wait_listening(autopilot: subprocess.Popen, record: str, timeout_s: float = 15.0) -> None:
    """Until the fake autopilot listens: it writes its record's first line once its port is bound.
    Else the first frames' messages would go nowhere (a busy machine takes a second or more to
    start it)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if autopilot.poll() is not None:
            err = autopilot.stderr.read().decode("utf-8", "replace").strip().splitlines() if autopilot.stderr else []
            raise SourceError("demo: the fake autopilot exited (status %s): %s"
                              % (autopilot.returncode, err[-1] if err else "no message"))
        if os.path.exists(record) and os.path.getsize(record) > 0:
            return
        time.sleep(0.05)
    log.warning("demo: fake autopilot not listening after %.0f s; starting anyway", timeout_s)


def record_rows(path: str) -> List[dict]:
    """The fake autopilot's record so far: one dict a complete line. Read at once and cut at line
    ends, because the autopilot may be half-way through its last line (iterating the file would
    yield that half, then its other half as a line of its own once the file has grown)."""
    if not os.path.exists(path):
        return []  # not started writing yet
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    rows = []
    for line in text.split("\n")[:-1]:
        try:
            rows.append(json.loads(line))
        except ValueError:
            pass  # a line cut by a kill, continued by a restarted autopilot
    return rows


def read_record(path: str) -> Counter:
    """Message type -> count of what the fake autopilot received from us."""
    return Counter(row.get("type", "?") for row in record_rows(path) if row.get("dir") == "in")


def demo_config(base: Config, out_dir: str, frames: int, port: int) -> Config:
    return config_with(base, **{
        "capture.source": "synthetic", "capture.pace": False, "capture.synthetic.frames": frames,
        "mavlink.enabled": True, "mavlink.connection": "udpout:127.0.0.1:%d" % port, "outputs.directory": out_dir,
        "video.enabled": True,
    })


class _DemoView:
    """Writes the annotated video, scores against the scene's truth, prints a status line."""

    def __init__(self, service_ref: Dict[str, Service], out_dir: str, fps: float) -> None:
        self.service_ref = service_ref
        self.video = VideoOut(os.path.join(out_dir, "demo.mp4"), fps)
        self.tp = self.fp = self.fn = 0
        self.t_start = time.monotonic()
        self.frames = 0
        self.tty = sys.stderr.isatty()

    def __call__(self, frame: Frame, result: GladResult) -> None:
        service = self.service_ref["service"]
        if self.frames == 0:
            print("live video         %s" % video_line(service), flush=True)
        truth = getattr(service.source, "last_truth", None)
        self._score(result, None if truth is None else truth.target_xyxy)
        self.frames += 1
        link = service.link.status if service.link is not None else None
        status = "link=%s" % ("up" if link and link.autopilot_seen else "waiting")
        self.video.write(draw_result(frame.image, result, status))
        fps = self.frames / max(time.monotonic() - self.t_start, 1e-6)
        line = "frame %4d  %5.1f fps  mode=%-6s  target=%-9s  %s  TP=%d FP=%d FN=%d" % (
            frame.index, fps, result.mode, _state(result), status, self.tp, self.fp, self.fn)
        if self.tty:
            sys.stderr.write("\r" + line)
            sys.stderr.flush()
        elif frame.index % 50 == 0:
            print(line, flush=True)

    def _score(self, result: GladResult, truth_xyxy: Optional[np.ndarray]) -> None:
        from payload.eval.metrics import match_frame

        gt = np.zeros((0, 4), np.float32) if truth_xyxy is None else np.asarray(truth_xyxy, np.float32).reshape(1, 4)
        tp = int(match_frame(result.detections, gt).sum()) if len(result.detections) else 0
        self.tp += tp
        self.fp += len(result.detections) - tp
        self.fn += len(gt) - tp

    def close(self) -> None:
        self.video.close()
        if self.tty:
            sys.stderr.write("\n")


def video_line(service: Service) -> str:
    d = service.stream_description()
    if d is None:
        return "off (GStreamer, the RTSP server or an H.264 encoder missing: see the log)"
    return "%s  (%dx%d H.264 %s)" % (d.uri, d.width, d.height, d.encoder)


def _state(result: GladResult) -> str:
    if result.target is None:
        return "searching"
    return "detected" if result.target.measured else "coasting"


def main_demo(args) -> int:
    out_dir = os.path.abspath(args.out)
    os.makedirs(out_dir, exist_ok=True)
    port = free_udp_port()
    record = os.path.join(out_dir, "autopilot.jsonl")
    if os.path.exists(record):
        os.remove(record)  # the fake autopilot appends; the summary counts this run only
    cfg = demo_config(load_config(args.config), out_dir, args.frames, port)
    autopilot = start_fake_autopilot(port, record)
    wait_listening(autopilot, record)
    ref: Dict[str, Service] = {}
    view = _DemoView(ref, out_dir, cfg.capture.synthetic.fps)
    service = Service(cfg, max_frames=args.frames, on_result=view)
    ref["service"] = service
    t0 = time.monotonic()
    try:
        service.install_signal_handlers()
        service.run()
    finally:
        view.close()
        time.sleep(0.3)  # let the last messages land in the record
        autopilot.terminate()
        try:
            autopilot.wait(timeout=5)
        except subprocess.TimeoutExpired:
            autopilot.kill()
    elapsed = time.monotonic() - t0
    received = read_record(record)
    precision = view.tp / max(view.tp + view.fp, 1)
    recall = view.tp / max(view.tp + view.fn, 1)
    f1 = 2 * precision * recall / max(precision + recall, 1e-9)
    print("")
    print("glad-payload demo summary")
    print("  frames processed   %d in %.1f s (%.1f fps incl. rendering the scene)"
          % (service.stats.frames, elapsed, service.stats.frames / max(elapsed, 1e-6)))
    print("  frames with target %d  (vs. scene truth: TP %d, FP %d, FN %d; P %.2f R %.2f F %.2f)"
          % (service.stats.hits, view.tp, view.fp, view.fn, precision, recall, f1))
    print("  live video         %s" % video_line(service))
    print("  autopilot received %s" % (", ".join("%s %d" % kv for kv in sorted(received.items())) or "nothing"))
    print("  outputs            %s/{demo.mp4, detections.csv, decisions.csv, autopilot.jsonl}" % out_dir)
    return 0

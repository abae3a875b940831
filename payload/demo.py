"""``glad-payload demo``: the whole payload with no camera and no aircraft.

A synthetic air-to-air scene stands in for the camera and the fake autopilot rig
(sitl/fake_autopilot.py) for the vehicle, on loopback UDP. The service runs exactly as in
flight; a live status line shows progress and a summary closes the run. The fake autopilot also
plays the ground station of the MAVLink camera protocol: it asks for CAMERA_INFORMATION and
VIDEO_STREAM_INFORMATION, designates the synthetic drone with MAV_CMD_CAMERA_TRACK_POINT a third
of the way in (where the scene has it) and stops tracking 10 frames before the end; the summary
shows that exchange and the designated lock. The output folder
gets the annotated MP4, detections.csv, decisions.csv and the autopilot's record. The annotated
live video is served over RTSP (video.rtsp_port, 8554 by default; RTP/UDP when the RTSP server
is missing or the port taken) and its URI printed at the first frame, to open in VLC or a
ground station while the demo runs; without GStreamer the demo runs without it.
"""

import logging
import os
import subprocess
import sys
import time
from typing import Dict, List, Optional

import numpy as np

from payload.annotate import VideoOut, draw_result
from payload.config import Config, config_with, load_config
from payload.detect.pipeline import GladResult
from payload.loopback import free_udp_port, read_record, record_rows, start_fake_autopilot, wait_listening
from payload.service import Service
from payload.types import Frame

log = logging.getLogger(__name__)

# the camera protocol's commands and answers, by number (common.xml)
_CMD_NAMES = {512: "REQUEST_MESSAGE", 2004: "CAMERA_TRACK_POINT", 2005: "CAMERA_TRACK_RECTANGLE",
              2010: "CAMERA_STOP_TRACKING"}
_MSG_NAMES = {259: "CAMERA_INFORMATION", 269: "VIDEO_STREAM_INFORMATION"}
_RESULTS = {0: "ACCEPTED", 1: "TEMPORARILY_REJECTED", 2: "DENIED", 3: "UNSUPPORTED", 4: "FAILED", 5: "IN_PROGRESS"}


class _GroundStation:
    """The camera-protocol commands of the demo, sent through the fake autopilot's stdin (it sends
    them as system 255, a ground station) when their frame comes."""

    def __init__(self, autopilot: subprocess.Popen, frames: int) -> None:
        self.autopilot = autopilot
        self.requests_sent = False
        self.designate_from = max(10, frames // 3) if frames >= 30 else None
        # near the end: the stop drops the lock, and what the global search takes next is another story
        self.stop_at = frames - 10 if frames >= 30 else None
        self.designated_at: Optional[int] = None
        self.point = None
        self.locked_at: Optional[int] = None

    def send(self, action: str) -> None:
        try:
            self.autopilot.stdin.write((action + "\n").encode())
            self.autopilot.stdin.flush()
        except (OSError, ValueError):
            pass  # the autopilot is gone; the summary shows what it got

    def on_frame(self, frame: Frame, truth, service: Service) -> None:
        if not self.requests_sent:
            self.requests_sent = True
            self.send("512,param1=259")  # MAV_CMD_REQUEST_MESSAGE(CAMERA_INFORMATION)
            self.send("512,param1=269")  # ... (VIDEO_STREAM_INFORMATION)
        w, h = frame.size_wh
        if (self.designate_from is not None and self.designated_at is None and frame.index >= self.designate_from
                and truth is not None and truth.target_xyxy is not None and truth.target_visible > 0.9):
            x1, y1, x2, y2 = (float(v) for v in truth.target_xyxy)
            self.point = ((x1 + x2) / 2 / w, (y1 + y2) / 2 / h)
            self.designated_at = frame.index
            self.send("2004,param1=%.4f,param2=%.4f" % self.point)  # where the operator clicks: the drone
        camera = service.camera
        if self.designated_at is not None and self.locked_at is None and camera is not None and camera.stats.confirmed:
            self.locked_at = frame.index
        if self.stop_at is not None and frame.index == max(self.stop_at, (self.designated_at or 0) + 15):
            self.send("2010")  # MAV_CMD_CAMERA_STOP_TRACKING


def camera_exchange(path: str) -> List[str]:
    """The camera protocol as the fake autopilot recorded it: each command sent, its ACKs, and the
    CAMERA_INFORMATION / VIDEO_STREAM_INFORMATION received; one line each."""
    rows = record_rows(path)
    sent = [r for r in rows if r.get("dir") == "out" and r.get("type") == "COMMAND_LONG"
            and r["fields"]["command"] in _CMD_NAMES]
    acks = [r for r in rows if r.get("dir") == "in" and r.get("type") == "COMMAND_ACK"
            and r["fields"]["command"] in _CMD_NAMES and r["fields"]["target_system"] == 255]
    answers: List[List[str]] = [[] for _ in sent]
    for a in acks:
        # each ACK answers the oldest command of its number still open (IN_PROGRESS keeps it open)
        for i, cmd in enumerate(sent):
            done = answers[i] and answers[i][-1] != "IN_PROGRESS"
            if cmd["fields"]["command"] == a["fields"]["command"] and cmd["t"] <= a["t"] and not done:
                answers[i].append(_RESULTS.get(a["fields"]["result"], str(a["fields"]["result"])))
                break
    lines = []
    for cmd, got in zip(sent, answers):
        f = cmd["fields"]
        what = _CMD_NAMES[f["command"]]
        if f["command"] == 512:
            what += " " + _MSG_NAMES.get(int(f["param1"]), str(int(f["param1"])))
        elif f["command"] == 2004:
            what += " (%.3f, %.3f)" % (f["param1"], f["param2"])
        lines.append("%s -> %s" % (what, ", ".join(got) or "no answer"))
    for r in rows:
        if r.get("dir") == "in" and r.get("type") == "CAMERA_INFORMATION":
            f = r["fields"]
            flags = [name for bit, name in ((512, "TRACKING_POINT"), (1024, "TRACKING_RECTANGLE"),
                                            (256, "VIDEO_STREAM")) if f["flags"] & bit]
            lines.append("CAMERA_INFORMATION: %s / %s, %dx%d, flags %s" % (
                bytes(f["vendor_name"]).rstrip(b"\0").decode("utf-8", "replace"),
                bytes(f["model_name"]).rstrip(b"\0").decode("utf-8", "replace"),
                f["resolution_h"], f["resolution_v"], "|".join(flags)))
            break
    for r in rows:
        if r.get("dir") == "in" and r.get("type") == "VIDEO_STREAM_INFORMATION":
            lines.append("VIDEO_STREAM_INFORMATION: %s" % r["fields"]["uri"])
            break
    return lines


def demo_config(base: Config, out_dir: str, frames: int, port: int) -> Config:
    return config_with(base, **{
        "capture.source": "synthetic", "capture.pace": False, "capture.synthetic.frames": frames,
        "mavlink.enabled": True, "mavlink.connection": "udpout:127.0.0.1:%d" % port, "outputs.directory": out_dir,
        "video.enabled": True,
    })


class _DemoView:
    """Writes the annotated video, scores against the scene's truth, prints a status line."""

    def __init__(self, service_ref: Dict[str, Service], out_dir: str, fps: float,
                 ground_station: Optional[_GroundStation] = None) -> None:
        self.service_ref = service_ref
        self.ground_station = ground_station
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
        if self.ground_station is not None:
            self.ground_station.on_frame(frame, truth, service)
        self.frames += 1
        link = service.link.status if service.link is not None else None
        status = "link=%s" % ("up" if link and link.autopilot_seen else "waiting")
        if service.glad is not None and service.glad.designated:
            status += " designated"
        self.video.write(draw_result(frame.image, result, status))
        fps = self.frames / max(time.monotonic() - self.t_start, 1e-6)
        line = "frame %4d  %5.1f fps  mode=%-6s  target=%-9s  %s  TP=%d FP=%d FN=%d" % (
            frame.index, fps, result.mode, result.state, status, self.tp, self.fp, self.fn)
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
    ground_station = _GroundStation(autopilot, args.frames)
    view = _DemoView(ref, out_dir, cfg.capture.synthetic.fps, ground_station)
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
    exchange = camera_exchange(record)
    for i, line in enumerate(exchange):
        print("  %-18s %s" % ("camera protocol" if i == 0 else "", line))
    gs = ground_station
    if gs.designated_at is not None:
        print("  designated lock    drone designated at frame %d: %s" % (
            gs.designated_at, "locked at frame %d" % gs.locked_at if gs.locked_at is not None else "not confirmed"))
    print("  outputs            %s/{demo.mp4, detections.csv, decisions.csv, autopilot.jsonl}" % out_dir)
    return 0

"""Issue 17's acceptance for the camera protocol: the payload as a process (`glad-payload run` on a
synthetic scene), MAVProxy in the middle routing it to the fake autopilot and to a pymavlink
ground station, which asks for CAMERA_INFORMATION, designates the synthetic drone with
MAV_CMD_CAMERA_TRACK_POINT (tracking statuses on it within 10 frames), stops tracking (back to
search) and designates an empty spot (FAILED, status ERROR). With the video on, it also asks for
VIDEO_STREAM_INFORMATION, opens the RTSP URI named there with a real rtspsrc client and decodes
frames; with GStreamer's RTSP server missing (the Python 3.8 venv) the payload answers DENIED and
leaves HAS_VIDEO_STREAM out, which is checked instead.
"""

import math
import os
import re
import subprocess
import sys
import time

import pytest
import yaml
from test_service import decisions_count, read_decisions, start_autopilot, start_payload, stop, wait_for
from test_video import Receiver

from payload.loopback import free_udp_port
from payload.synth.scene import Scene

pytestmark = pytest.mark.slow

W, H, SEED = 960, 540, 7
PAYLOAD = (1, 100)
ACCEPTED, DENIED, FAILED, IN_PROGRESS = 0, 2, 4, 5
HOME_LAT, HOME_LON = 47.397742, 8.545594


class GroundStation:
    """A pymavlink ground station (system 255, component 190) on its own UDP port."""

    def __init__(self, port):
        os.environ["MAVLINK20"] = "1"  # read by mavutil when it loads the dialect
        from pymavlink import mavutil

        self.mavutil = mavutil
        self.conn = mavutil.mavlink_connection("udpin:127.0.0.1:%d" % port, source_system=255, source_component=190,
                                               dialect="ardupilotmega")
        self.m = self.conn.mav
        self.received = []  # (t, message) from the payload's component

    def pump(self, seconds=0.05):
        deadline = time.monotonic() + seconds
        while True:
            msg = self.conn.recv_match(blocking=True, timeout=0.02)
            if msg is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == PAYLOAD:
                self.received.append((time.monotonic(), msg))
            if time.monotonic() >= deadline:
                return

    def wait(self, pred, timeout_s, what, since=0.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.pump()
            found = [(t, m) for t, m in self.received if t >= since and pred(m)]
            if found:
                return found
        raise AssertionError("ground station: timed out after %.0f s waiting for %s" % (timeout_s, what))

    def command(self, command, *params):
        p = list(params) + [0.0] * (7 - len(params))
        self.conn.mav.command_long_send(PAYLOAD[0], PAYLOAD[1], command, 0, *p)
        return time.monotonic()

    def acks(self, command, since=0.0):
        # (MAVProxy, system 255 too, takes the payload for its vehicle and sends it requests of its own:
        # only the ACKs addressed to this ground station's component count)
        return [m.result for t, m in self.received if t >= since and m.get_type() == "COMMAND_ACK"
                and m.command == command and m.target_component == 190]

    def close(self):
        self.conn.close()


def rtsp_gst():
    """GStreamer with the RTSP server and a client's elements, or None (then the payload serves no video)."""
    try:
        from payload.video.gst import VideoUnavailable, has_elements, import_gst, import_rtsp_server

        Gst, _ = import_gst()
        import_rtsp_server()
    except (ImportError, VideoUnavailable):
        return None
    ok = all(has_elements(e) for e in ("openh264enc", "rtspsrc", "rtph264depay", "avdec_h264"))
    return Gst if ok else None


def write_config(tmp_path, port, out_dir, video=False):
    cfg = {
        "capture": {"source": "synthetic", "pace": True,
                    "synthetic": {"seed": SEED, "width": W, "height": H, "fps": 15.0, "frames": 0,
                                  "target_px": [14.0, 30.0]}},
        "camera": {"hfov_deg": 60.0},
        "target": {"span_m": 0.5},
        "mavlink": {"connection": "udpout:127.0.0.1:%d" % port, "attitude_rate_hz": 20.0,
                    "camera": {"designate_frames": 10}},
        "outputs": {"directory": str(out_dir)},
        "logging": {"summary_interval_s": 1.0},
        "video": {"enabled": video, "rtsp_port": 0, "advertise_host": "127.0.0.1", "width": 320, "height": 192,
                  "fps": 15.0},
    }
    path = tmp_path / "payload.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return str(path)


def drone_at(frame_index):
    """The synthetic drone's box centre at a frame, normalised, or None when it is not well in view."""
    for sf in Scene(seed=SEED, width=W, height=H, fps=15.0, frames=frame_index + 1, target_px=(14.0, 30.0)).truth():
        if sf.index == frame_index:
            box = sf.target_xyxy
            if box is None or sf.target_visible < 0.9:
                return None
            return float(box[0] + box[2]) / 2 / W, float(box[1] + box[3]) / 2 / H
    return None


def test_camera_protocol_through_mavproxy(tmp_path, mavproxy_script):
    payload_port, ap_port, gcs_port = free_udp_port(), free_udp_port(), free_udp_port()
    out_dir = tmp_path / "out"
    log_path = tmp_path / "payload.log"
    router = subprocess.Popen(
        [sys.executable, mavproxy_script, "--master=udpin:127.0.0.1:%d" % payload_port,
         "--out=udpout:127.0.0.1:%d" % ap_port, "--out=udpout:127.0.0.1:%d" % gcs_port,
         "--daemon", "--non-interactive", "--default-modules=", "--state-basedir=%s" % tmp_path, "--nowait"],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=str(tmp_path),
    )
    autopilot = start_autopilot(ap_port, tmp_path / "record.jsonl")
    gcs = GroundStation(gcs_port)
    Gst = rtsp_gst()
    payload = start_payload(write_config(tmp_path, payload_port, out_dir, video=Gst is not None), log_path=log_path)
    try:
        gcs.wait(lambda m: m.get_type() == "HEARTBEAT", 60, "the payload's heartbeat through MAVProxy")
        # CAMERA_INFORMATION on request
        t = gcs.command(512, 259)  # MAV_CMD_REQUEST_MESSAGE(CAMERA_INFORMATION)
        info = gcs.wait(lambda m: m.get_type() == "CAMERA_INFORMATION", 10, "CAMERA_INFORMATION")[0][1]
        assert gcs.acks(512, t) == [ACCEPTED]
        assert (info.resolution_h, info.resolution_v) == (W, H)
        assert info.flags & 512 and info.flags & 1024  # tracking point, rectangle
        assert bytes(info.vendor_name).rstrip(b"\0") == b"glad-payload"
        t = gcs.command(512, 269)  # MAV_CMD_REQUEST_MESSAGE(VIDEO_STREAM_INFORMATION)
        if Gst is None:
            assert not info.flags & 256  # no HAS_VIDEO_STREAM without a stream
            gcs.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == 512 and m.result == DENIED, 10, "DENIED")
        else:
            assert info.flags & 256  # HAS_VIDEO_STREAM
            stream = gcs.wait(lambda m: m.get_type() == "VIDEO_STREAM_INFORMATION", 10, "VIDEO_STREAM_INFORMATION")[0][1]
            uri = bytes(stream.uri).rstrip(b"\0").decode() if isinstance(stream.uri, (bytes, bytearray)) else stream.uri
            assert uri.startswith("rtsp://127.0.0.1:") and (stream.resolution_h, stream.resolution_v) == (320, 192)
            receiver = Receiver(Gst, "rtspsrc location=%s latency=0" % uri)
            try:
                wait_for(lambda: len(receiver.frames) >= 2, 60, "2 decoded frames from %s" % uri)
            finally:
                receiver.close()
            assert receiver.frames[0].shape == (192, 320, 3)

        # designate the drone where the scene has it a few frames ahead of the last decision
        wait_for(lambda: decisions_count(out_dir) >= 30, 120, "30 processed frames")
        point = None
        while point is None:
            last = int(read_decisions(out_dir)[-1]["frame"])
            point = drone_at(last + 2)
            if point is None:
                time.sleep(0.2)
        t_track = gcs.command(2004, point[0], point[1], 0.0)  # MAV_CMD_CAMERA_TRACK_POINT
        gcs.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == 2004 and m.result != IN_PROGRESS
                 and m.target_component == 190, 30,
                 "the track point's final ACK")
        assert gcs.acks(2004, t_track) == [IN_PROGRESS, ACCEPTED]
        locked = re.findall(r"designated target locked after (\d+) frame", log_path.read_text())
        assert locked and int(locked[-1]) <= 10, locked
        t_acc = next(t for t, m in gcs.received if t >= t_track and m.get_type() == "COMMAND_ACK" and m.result == ACCEPTED)
        on_it = gcs.wait(lambda m: m.get_type() == "CAMERA_TRACKING_IMAGE_STATUS" and m.tracking_status & 1
                         and not math.isnan(m.point_x), 10, "tracking status after the lock", since=t_acc)
        first = on_it[0][1]
        assert math.hypot(first.point_x - point[0], first.point_y - point[1]) < 0.06
        geo = gcs.wait(lambda m: m.get_type() == "CAMERA_TRACKING_GEO_STATUS", 20, "CAMERA_TRACKING_GEO_STATUS",
                       since=t_acc)
        g = geo[-1][1]
        assert abs(g.lat / 1e7 - HOME_LAT) < 0.02 and abs(g.lon / 1e7 - HOME_LON) < 0.02 and 1.0 < g.dist < 500.0

        # stop: ACCEPTED, and the payload back to search (an IDLE status: the lock is judged afresh)
        t_stop = gcs.command(2010)
        gcs.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == 2010, 10, "STOP_TRACKING ACK")
        assert gcs.acks(2010, t_stop) == [ACCEPTED]
        gcs.wait(lambda m: m.get_type() == "CAMERA_TRACKING_IMAGE_STATUS" and m.tracking_status == 0, 10, "IDLE",
                 since=t_stop)
        assert "back to automatic search" in log_path.read_text()

        # an empty spot of sky: no target confirmed there within designate_frames -> FAILED, status ERROR
        last = int(read_decisions(out_dir)[-1]["frame"])
        drone = drone_at(last + 2) or (0.5, 0.5)
        empty = (0.1 if drone[0] > 0.5 else 0.9, 0.1)
        t_empty = gcs.command(2004, empty[0], empty[1], 0.0)
        gcs.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == 2004 and m.result == FAILED, 30, "FAILED")
        assert gcs.acks(2004, t_empty) == [IN_PROGRESS, FAILED]
        gcs.wait(lambda m: m.get_type() == "CAMERA_TRACKING_IMAGE_STATUS" and m.tracking_status & 2, 10,
                 "tracking status ERROR", since=t_empty)
        assert payload.poll() is None and router.poll() is None
        assert stop(payload) == 0
    finally:
        stop(payload)
        stop(autopilot)
        stop(router)
        gcs.close()
    log = log_path.read_text()
    assert "Traceback" not in log

"""`glad-payload run` under the faults and attacks of issue 20, each done for real: a service
process, a real SIGHUP, real files (corrupt images, a config that is not UTF-8, an alias bomb,
/dev/full), a real MAVLink peer over UDP sending NaN attitudes, and systemd's notify socket."""

import csv
import functools
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time

import cv2
import numpy as np
import pytest
import test_service
import yaml
from onnx_factories import bright_spot_detector, failing_detector
from test_service_lifecycle import NotifyListener, log_text, wait_log

from payload.config import config_with, flat_config, is_restart_key, parse_config
from payload.loopback import free_udp_port

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PROBE = os.path.join(REPO, "tests", "reload_probe.py")

pytestmark = pytest.mark.slow


def base_config(**sections):
    cfg = {
        "capture": {"source": "synthetic", "pace": True,
                    "synthetic": {"seed": 3, "width": 640, "height": 360, "fps": 30.0, "frames": 0}},
        "mavlink": {"enabled": False},
        "logging": {"summary_interval_s": 0.5},
    }
    for name, values in sections.items():
        cfg.setdefault(name, {}).update(values)
    return cfg


def write(path, cfg):
    path.write_text(yaml.safe_dump(cfg))
    return str(path)


def start(args, log_path, env=None, probe=None):
    cmd = [sys.executable, PROBE, probe] if probe else [sys.executable, "-m", "payload"]
    return subprocess.Popen(cmd + list(args), cwd=REPO, env=dict(os.environ, PYTHONUNBUFFERED="1", **(env or {})),
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=open(log_path, "w"))


stop = functools.partial(test_service.stop, timeout_s=30)


def wait_until(predicate, timeout_s, what, listener=None):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return
        if listener is not None:
            listener.drain(0.1)
        else:
            time.sleep(0.1)
    raise AssertionError("timed out waiting for " + what)


def summary_frames(text, with_drops=False):
    """Frames processed (plus, with_drops, frames a paced source dropped or decoded late) by the
    last summary line."""
    found = re.findall(r"fps=[\d.]+ frames=(\d+) drops=(\d+)(?:.* late=(\d+))?", text)
    if not found:
        return 0
    frames, drops, late = found[-1]
    return int(frames) + (int(drops) + int(late or 0) if with_drops else 0)


def watchdog_env(tmp_path, usec=1_000_000):
    sock = str(tmp_path / "notify.sock")
    return NotifyListener(sock), {"NOTIFY_SOCKET": sock, "WATCHDOG_USEC": str(usec)}


def run_watched(tmp_path, cfg):
    """``glad-payload run`` on ``cfg`` (written to payload.yaml) with a systemd notify socket and
    watchdog: (config path, log path, notify listener, process)."""
    cfg_path = tmp_path / "payload.yaml"
    write(cfg_path, cfg)
    listener, env = watchdog_env(tmp_path)
    log_path = tmp_path / "payload.log"
    return cfg_path, log_path, listener, start(["run", "--config", str(cfg_path)], log_path, env=env)


def ping_times(listener, since=0.0):
    return [t for t, m in listener.messages if m == "WATCHDOG=1" and t >= since]


# --- reload tells the truth ---------------------------------------------------------------------


def _changed(key, value):
    """A valid value different from ``value`` for a reloadable key."""
    special = {
        "camera.matrix": [500.0, 500.0, 320.0, 180.0],
        "camera.distortion": [0.01, 0.0, 0.0, 0.0, 0.0],
        "detector.classifier.modules": ["GAD", "GMD", "LAD", "LMD"],
        "detector.switcher.pick": "distance",
        "detector.targets.primary": "largest",
        "mavlink.outputs.debug_vect_frame": "level",
        "mavlink.command_sysids": [42],
        "mavlink.outputs.follow_target_sysid": 2,
        "mavlink.camera.vendor": "acme",
        "mavlink.camera.model": "eye",
        "camera.pixel_size_um": 3.0,
        "target.span_m": 0.4,
        "logging.level": "DEBUG",
    }
    if key in special:
        return special[key]
    if isinstance(value, bool):
        return not value
    if key.endswith("blur_px"):
        return value + 2  # stays odd
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return round(value * 0.9, 6) if value > 0 else 0.1
    if isinstance(value, (tuple, list)) and key.endswith("grid_wh"):
        return [value[0] - 10, value[1] - 5]
    raise AssertionError("no changed value for %s=%r: add one" % (key, value))


def _reloadable(cfg):
    return {k: v for k, v in flat_config(cfg).items() if not is_restart_key(k)}


def _norm(value):
    return json.loads(json.dumps(value, default=list))


@pytest.fixture(scope="module")
def reloaded(tmp_path_factory):
    """One service (MAVLink on, all stages loaded), then one SIGHUP that changes every reloadable key.
    Returns (new values by key, running values by key after the reload, the log)."""
    tmp = tmp_path_factory.mktemp("reload")
    port = free_udp_port()  # nobody listens: the link runs, its sends are dropped
    # the video and the recording run where GStreamer does (their live keys reach the running VideoOutput)
    start_cfg = base_config(mavlink={"enabled": True, "connection": "udpout:127.0.0.1:%d" % port},
                            video={"enabled": True, "transport": "udp", "udp_port": free_udp_port()},
                            recording={"enabled": True, "dir": str(tmp / "rec")})
    cfg_path = tmp / "payload.yaml"
    write(cfg_path, start_cfg)
    old = parse_config(start_cfg)
    new_values = {k: _changed(k, v) for k, v in _reloadable(old).items()}
    data = config_with(old, **new_values).model_dump(by_alias=True, mode="json")  # valid, or fix _changed
    log_path = tmp / "payload.log"
    out = str(tmp / "running.json")
    proc = start(["run", "--config", str(cfg_path)], log_path, probe=out)
    try:
        wait_until(lambda: "ready first_frame" in log_text(log_path), 120, "the first frame")
        assert "landing_target is on" not in log_text(log_path)
        cfg_path.write_text(yaml.safe_dump(data))
        proc.send_signal(signal.SIGHUP)
        wait_until(lambda: os.path.exists(out), 30, "the reload")
        time.sleep(1.0)  # frames go on with the new config
        assert proc.poll() is None
        assert stop(proc) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    with open(out) as fh:
        running = json.load(fh)
    return _norm(new_values), running, log_text(log_path)


def _check_running(new_values, running, keys):
    wrong = {}
    for key in keys:
        held = running.get(key)
        if not held or any(v != new_values[key] for v in held):
            wrong[key] = (new_values[key], held)
    assert not wrong, "running objects do not hold the reloaded values: %r" % wrong


def test_reload_applies_every_reloadable_key(reloaded):
    new_values, running, log = reloaded
    keys = [k for k in new_values if not (k.startswith("mavlink.") and not k.startswith("mavlink.outputs."))]
    assert len(keys) > 80
    _check_running(new_values, running, keys)
    applied = re.search(r"reload: applied \S+ changed=(\S+)", log).group(1).split(",")
    assert set(keys) <= set(applied)
    refused = re.findall(r"need a restart and are not applied yet: (.*)", log)
    assert not any(k in line.split(", ") for line in refused for k in keys)
    # turning landing_target (follow_target) on by reload says what start-up says
    assert log.count("mavlink.outputs.landing_target is on: a precision-landing autopilot may steer") == 1
    assert log.count("mavlink.outputs.follow_target is on: an autopilot in follow mode will chase") == 1
    assert "Traceback" not in log


def test_reload_applies_mavlink_keys_to_the_link(reloaded):
    new_values, running, log = reloaded
    keys = [k for k in new_values if k.startswith("mavlink.") and not k.startswith("mavlink.outputs.")]
    assert "mavlink.command_sysids" in keys and "mavlink.heartbeat_hz" in keys
    _check_running(new_values, running, keys)
    applied = re.search(r"reload: applied \S+ changed=(\S+)", log).group(1).split(",")
    assert set(keys) <= set(applied)


def test_restart_only_key_is_refused_in_one_line_and_keeps_running_value(tmp_path):
    cfg_path = tmp_path / "payload.yaml"
    write(cfg_path, base_config())
    log_path = tmp_path / "payload.log"
    out = str(tmp_path / "running.json")
    proc = start(["run", "--config", str(cfg_path)], log_path, probe=out)
    try:
        wait_until(lambda: "ready first_frame" in log_text(log_path), 120, "the first frame")
        write(cfg_path, base_config(detector={"backend": "cuda", "switcher": {"max_local_misses": 7}},
                                    outputs={"keep_files": 9}))
        proc.send_signal(signal.SIGHUP)
        wait_until(lambda: os.path.exists(out), 30, "the reload")
        assert stop(proc) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    log = log_text(log_path)
    lines = [line for line in log.splitlines() if "need a restart" in line]
    assert len(lines) == 1 and lines[0].endswith("not applied yet: detector.backend, outputs.keep_files")
    assert "changed=detector.switcher.max_local_misses" in log
    with open(out) as fh:
        held = json.load(fh)
    assert set(held["detector.switcher.max_local_misses"]) == {7} and set(held["detector.backend"]) == {"cpu"}


# --- config input: not UTF-8, alias bomb, 50 MB, empty ------------------------------------------

BOMB = "\n".join(["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
                 + ["a%d: &a%d [%s]" % (i, i, ", ".join(["*a%d" % (i - 1)] * 10)) for i in range(1, 10)]) + "\n"


def test_bad_config_files_on_sighup_keep_the_service_and_its_watchdog_running(tmp_path):
    cfg_path, log_path, listener, proc = run_watched(tmp_path, base_config())
    bad = [
        (b"logging:\n  level: \xff\xfeINFO\n", "not UTF-8 text (byte 0xff at offset 18)"),
        (BOMB.encode(), "holds more than 20000 values once its aliases"),
        (b"# " + b"x" * (50 << 20) + b"\n", "larger than 1048576 bytes (1 MiB)"),
        (b"", "the file is empty"),
    ]
    try:
        listener.wait_for("READY=1", 120)
        for content, message in bad:
            cfg_path.write_bytes(content)
            t0 = time.monotonic()
            proc.send_signal(signal.SIGHUP)
            wait_log(log_path, message, 20, listener)
            listener.drain(1.5)
            pings = ping_times(listener, since=t0 - 1.0)
            gaps = np.diff(pings)
            # pinged every 0.5 s while frames flow: the reload of a hostile file never stalls the loop for long
            assert len(pings) >= 4 and gaps.max() < 1.0, (message, gaps)
            assert proc.poll() is None
        write(cfg_path, base_config(detector={"switcher": {"max_local_misses": 7}}))
        proc.send_signal(signal.SIGHUP)
        wait_log(log_path, "changed=detector.switcher.max_local_misses", 20, listener)
        assert stop(proc) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    log = log_text(log_path)
    assert "Traceback" not in log
    for _, message in bad:
        lines = [line for line in log.splitlines() if message in line]
        assert len(lines) == 1 and "reload rejected, keeping the running config: %s" % cfg_path in lines[0]


def test_config_not_utf8_at_start_is_one_line(tmp_path):
    cfg_path = tmp_path / "payload.yaml"
    cfg_path.write_bytes(b"capture:\n  source: synthetic\n# caf\xe9\n")
    proc = subprocess.run([sys.executable, "-m", "payload", "run", "--config", str(cfg_path)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "%s:3: not UTF-8 text (byte 0xe9 at offset 34): save the file as UTF-8" % cfg_path]


# --- frames ---------------------------------------------------------------------------------


def test_image_folder_with_corrupt_and_empty_jpeg_goes_on(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(1)
    for i in range(40):
        image = rng.integers(0, 255, (120, 160, 3), np.uint8)
        cv2.imwrite(str(frames / ("%04d.jpg" % i)), image)
    (frames / "0005.jpg").write_bytes(b"\xff\xd8\xff\xe0 this is no jpeg" * 10)  # corrupt
    (frames / "0021.jpg").write_bytes(b"")  # zero bytes
    cfg_path = tmp_path / "payload.yaml"
    write(cfg_path, base_config(capture={"source": "folder", "path": str(frames), "pace": False}))
    log_path = tmp_path / "payload.log"
    proc = start(["run", "--config", str(cfg_path)], log_path)
    assert proc.wait(timeout=180) == 0, log_text(log_path)[-3000:]
    log = log_text(log_path)
    assert "source finished" in log and "Traceback" not in log
    final = [line for line in log.splitlines() if "final fps=" in line][-1]
    assert " frames=38 " in final and final.endswith("unreadable=2"), final
    assert log.count("cannot be read as an image") == 1  # the first one is named; the count says the rest


# --- outputs ------------------------------------------------------------------------------------


def test_disk_full_is_reported_once_and_detection_goes_on(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    for name in ("decisions.csv", "detections.csv"):
        os.symlink("/dev/full", str(out / name))  # every write: ENOSPC, as on a full disk
    cfg_path = tmp_path / "payload.yaml"
    # every lock reported at once (no lock verifier): both files get rows to fail on within 90 frames
    write(cfg_path, base_config(outputs={"directory": str(out)},
                                capture={"pace": False, "synthetic": {"seed": 7, "width": 640, "height": 360,
                                                                      "frames": 0}},
                                detector={"verifier": {"enabled": False}}))
    log_path = tmp_path / "payload.log"
    proc = start(["run", "--config", str(cfg_path), "--frames", "90"], log_path)
    assert proc.wait(timeout=180) == 0, log_text(log_path)[-3000:]
    log = log_text(log_path)
    assert "Traceback" not in log
    lines = [line for line in log.splitlines() if "outputs: cannot write" in line]
    # once for each file, not once a frame
    assert sorted(line.split(str(out) + "/")[1].split(":")[0] for line in lines) == ["decisions.csv", "detections.csv"]
    assert all("No space left on device" in line for line in lines)
    final = [line for line in log.splitlines() if "final fps=" in line][-1]
    assert " frames=90 " in final and " faults=0" in final and "rows_lost=" in final


def _decision_rows(out):
    rows = []
    for name in sorted(os.listdir(str(out))):
        if name.startswith("decisions.csv"):
            with open(str(out / name)) as fh:
                lines = fh.read().splitlines()
            assert lines[0].startswith("frame,t_capture_ns,"), name
            assert not any(line.startswith("frame,") for line in lines[1:]), name
            rows += list(csv.reader(lines[1:]))
    return rows


def test_decisions_csv_appends_across_restarts_and_rotates_by_size(tmp_path):
    out = tmp_path / "out"
    cfg_path = tmp_path / "payload.yaml"
    write(cfg_path, base_config(outputs={"directory": str(out), "max_file_bytes": 10000, "keep_files": 3},
                                capture={"pace": False}))
    for run, frames in enumerate((20, 150)):
        log_path = tmp_path / ("payload%d.log" % run)
        proc = start(["run", "--config", str(cfg_path), "--frames", str(frames)], log_path)
        assert proc.wait(timeout=180) == 0, log_text(log_path)[-3000:]
    rows = _decision_rows(out)
    assert len(rows) == 170  # both runs, nothing truncated
    assert os.path.exists(str(out / "decisions.csv.1"))
    assert all(os.path.getsize(str(out / n)) < 10000 + 400 for n in os.listdir(str(out)) if n.startswith("decisions"))
    frames = [int(r[0]) for r in rows]
    assert sorted(frames) == sorted(list(range(20)) + list(range(150)))


# --- non-finite attitude -----------------------------------------------------------------------


class NanAutopilot(threading.Thread):
    """A MAVLink autopilot on UDP (pymavlink): heartbeats, and ATTITUDE at 30 Hz that is finite in
    phase 0, has roll NaN in phase 1, pitch +inf in phase 2 and yaw -inf in phase 3 (the test sets
    ``phase``). Records the target messages it receives: (monotonic time, type, fields)."""

    def __init__(self, port):
        super().__init__(daemon=True)
        from payload.mavlink.transport import mavlink  # the link's MAVLink 2 dialect

        self.mav = mavlink
        self.parser = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.01)
        self.peer = None  # the payload's address, from its first datagram (udpin)
        self.phase = 0
        self.received = []
        self.stop_event = threading.Event()
        self.t0 = time.monotonic()

    def _send(self, msg):
        self.sock.sendto(msg.pack(self.parser), self.peer)

    def run(self):
        m = self.mav
        next_hb = next_att = 0.0
        while not self.stop_event.is_set():
            now = time.monotonic()
            if self.peer is not None:
                if now >= next_hb:
                    self._send(m.MAVLink_heartbeat_message(m.MAV_TYPE_QUADROTOR, m.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                           0, 0, m.MAV_STATE_ACTIVE, 3))
                    next_hb = now + 1.0
                if now >= next_att:
                    roll = float("nan") if self.phase == 1 else 0.1
                    pitch = float("inf") if self.phase == 2 else 0.05
                    yaw = -float("inf") if self.phase == 3 else 0.3
                    boot_ms = int((now - self.t0) * 1000)
                    self._send(m.MAVLink_attitude_message(boot_ms, roll, pitch, yaw, 0.0, 0.0, 0.0))
                    next_att = now + 1 / 30.0
            try:
                data, self.peer = self.sock.recvfrom(65535)
            except socket.timeout:
                continue
            for msg in self.parser.parse_buffer(data) or []:
                if msg.get_type() in ("DEBUG_VECT", "LANDING_TARGET", "CAMERA_TRACKING_IMAGE_STATUS"):
                    self.received.append((time.monotonic(), msg.get_type(), msg.to_dict()))

    def of_type(self, kind, start=0.0, end=float("inf")):
        return [f for t, k, f in list(self.received) if k == kind and start <= t < end]


def test_nan_and_inf_attitude_never_reach_a_sent_bearing(tmp_path):
    port = free_udp_port()
    autopilot = NanAutopilot(port)
    cfg_path = tmp_path / "payload.yaml"
    write(cfg_path, base_config(
        capture={"synthetic": {"seed": 7, "width": 960, "height": 540, "fps": 30.0, "frames": 0}},
        mavlink={"enabled": True, "connection": "udpout:127.0.0.1:%d" % port, "attitude_rate_hz": 0.0,
                 "timesync": False, "outputs": {"debug_vect_frame": "level", "landing_target": True}}))
    log_path = tmp_path / "payload.log"
    autopilot.start()
    proc = start(["run", "--config", str(cfg_path)], log_path)
    try:
        wait_until(lambda: autopilot.of_type("DEBUG_VECT"), 120, "a level bearing with a finite attitude")
        t_nan = time.monotonic()
        autopilot.phase = 1
        time.sleep(4.0)
        t_inf = time.monotonic()
        autopilot.phase = 2
        time.sleep(4.0)
        t_yaw = time.monotonic()
        autopilot.phase = 3
        time.sleep(4.0)
        t_end = time.monotonic()
        assert proc.poll() is None
        assert stop(proc) == 0
    finally:
        autopilot.stop_event.set()
        if proc.poll() is None:
            proc.kill()
    autopilot.join(5)
    autopilot.sock.close()
    log = log_text(log_path)
    assert "Traceback" not in log and " faults=0" in [line for line in log.splitlines() if "final fps=" in line][-1]
    for f in autopilot.of_type("DEBUG_VECT"):
        assert all(math.isfinite(f[k]) for k in ("x", "y", "z")), f
    for f in autopilot.of_type("LANDING_TARGET"):
        assert math.isfinite(f["angle_x"]) and math.isfinite(f["angle_y"]), f
    # no level bearing without a finite attitude (0.5 s for the frames in flight at the switch)
    assert autopilot.of_type("DEBUG_VECT", t_nan + 0.5, t_end) == []
    # frames and body-frame messages went on through the NaN and the inf phases
    for start_t, end_t in ((t_nan + 0.5, t_inf), (t_inf + 0.5, t_yaw), (t_yaw + 0.5, t_end)):
        assert autopilot.of_type("CAMERA_TRACKING_IMAGE_STATUS", start_t, end_t)


# --- a model with a fixed input size ------------------------------------------------------------


def test_model_with_fixed_100x100_input_is_one_line_at_start(tmp_path):
    model = bright_spot_detector(tmp_path / "fixed.onnx", hw=(100, 100))
    cfg_path = tmp_path / "payload.yaml"
    write(cfg_path, base_config(detector={"global": {"appearance": {"model": model}}}))
    proc = subprocess.run([sys.executable, "-m", "payload", "run", "--config", str(cfg_path)], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr and "ONNXRuntimeError" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        "glad-payload: detector.global.appearance.model: %s: input 'images' is fixed at [N,3,100,100], expected "
        "[N,3,384,640] (detector.global.appearance.input_wh [640, 384]) or dynamic H, W" % model)


# --- the watchdog means alive -------------------------------------------------------------------


def test_no_watchdog_ping_while_every_frame_faults(tmp_path):
    model = failing_detector(tmp_path / "failing.onnx")
    cfg = base_config(detector={"global": {"appearance": {"model": model}}})
    cfg_path, log_path, listener, proc = run_watched(tmp_path, cfg)
    try:
        listener.wait_for("READY=1", 120)
        # frames are read and every one faults: wait (drain) until over 30 are summed up (slow under load)
        deadline = time.monotonic() + 60.0
        total = 0
        while total <= 30 and time.monotonic() < deadline:
            listener.drain(1.0)
            totals = re.findall(r"\(total (\d+)\)", log_text(log_path))
            total = int(totals[-1]) if totals else 0
        assert proc.poll() is None
        assert total > 30
        assert ping_times(listener) == []
        # the faults are summed up, not one traceback a frame
        assert log_text(log_path).count("Traceback") == 1
        assert stop(proc) == 0
    finally:
        if proc.poll() is None:
            proc.kill()


def test_watchdog_pings_stop_while_capture_stalls(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(60):
        cv2.imwrite(str(frames / ("%04d.png" % i)), np.full((90, 160, 3), i * 4, np.uint8))
    os.remove(str(frames / "0030.png"))
    os.mkfifo(str(frames / "0030.png"))  # reading it blocks until someone writes: a stalled camera
    cfg = base_config(capture={"source": "folder", "path": str(frames), "pace": True, "fps": 10.0})
    cfg_path, log_path, listener, proc = run_watched(tmp_path, cfg)
    try:
        listener.wait_for("READY=1", 120)
        # frames read up to the FIFO, processed or (a loaded machine) dropped or late in the paced source
        wait_until(lambda: summary_frames(log_text(log_path), with_drops=True) >= 25, 60, "the frames before the stall",
                   listener)
        listener.drain(1.5)  # frame 30 is reached, its read blocks
        stalled_at = time.monotonic()
        listener.drain(3.0)
        assert len(ping_times(listener)) >= 3  # it was pinging while frames flowed
        assert ping_times(listener, since=stalled_at) == []
        assert proc.poll() is None  # stalled, not dead: systemd's watchdog is what ends it
    finally:
        proc.kill()
        proc.wait()


def test_watchdog_pings_stop_while_reload_hangs_and_resume_after(tmp_path):
    cfg_path, log_path, listener, proc = run_watched(tmp_path, base_config())
    try:
        listener.wait_for("READY=1", 120)
        listener.drain(1.0)
        good = yaml.safe_dump(base_config(detector={"switcher": {"max_local_misses": 7}}))
        os.remove(str(cfg_path))
        os.mkfifo(str(cfg_path))  # opening it blocks until a writer comes: a reload that hangs
        proc.send_signal(signal.SIGHUP)
        listener.drain(1.0)
        hung_at = time.monotonic()
        listener.drain(3.0)
        assert ping_times(listener, since=hung_at) == []
        with open(str(cfg_path), "w") as fh:  # the writer comes: the reload goes through
            fh.write(good)
        wait_log(log_path, "changed=detector.switcher.max_local_misses", 20, listener)
        resumed_at = time.monotonic()
        listener.drain(2.0)
        assert len(ping_times(listener, since=resumed_at)) >= 2
        assert stop(proc) == 0
    finally:
        if proc.poll() is None:
            proc.kill()


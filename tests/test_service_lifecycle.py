"""`glad-payload run` as systemd runs it: notify protocol on a real unix datagram socket,
SIGHUP reloads (valid, invalid, restart-only) and a clean SIGTERM."""

import os
import signal
import socket
import subprocess
import sys
import time

import pytest
import yaml

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

pytestmark = pytest.mark.slow


def config(path, **detector_local):
    cfg = {
        "capture": {"source": "synthetic", "pace": True,
                    "synthetic": {"seed": 3, "width": 640, "height": 360, "fps": 30.0, "frames": 0}},
        "detector": {"local": {"appearance": {"confidence": 0.1, **detector_local}}},
        "mavlink": {"enabled": False},
        "logging": {"summary_interval_s": 0.5},
    }
    path.write_text(yaml.safe_dump(cfg))


class NotifyListener:
    def __init__(self, path):
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(path)
        self.sock.settimeout(0.1)
        self.messages = []  # (monotonic time, message)

    def drain(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                data = self.sock.recv(4096)
            except socket.timeout:
                continue
            for line in data.decode().splitlines():
                self.messages.append((time.monotonic(), line))

    def wait_for(self, prefix, timeout_s):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if any(m.startswith(prefix) for _, m in self.messages):
                return
            self.drain(0.2)
        raise AssertionError("no %r notification; got %r" % (prefix, [m for _, m in self.messages][-10:]))

    def count(self, prefix):
        return sum(m.startswith(prefix) for _, m in self.messages)


def log_text(path):
    with open(path) as fh:
        return fh.read()


def wait_log(path, needle, timeout_s, listener, count=1):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if log_text(path).count(needle) >= count:
            return
        listener.drain(0.1)  # keep reading the socket, as systemd does, or its buffer fills
    raise AssertionError("log never said %r:\n%s" % (needle, log_text(path)[-2000:]))


def test_notify_reload_and_clean_stop(tmp_path):
    cfg_path = tmp_path / "payload.yaml"
    config(cfg_path)
    listener = NotifyListener(str(tmp_path / "notify.sock"))
    log_path = tmp_path / "payload.log"
    env = dict(os.environ, NOTIFY_SOCKET=str(tmp_path / "notify.sock"), WATCHDOG_USEC="2000000", PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "payload", "run", "--config", str(cfg_path)], cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=open(log_path, "w"))
    try:
        listener.wait_for("READY=1", 120)
        ready_at = next(t for t, m in listener.messages if m == "READY=1")
        # Nothing but status lines before READY (models loading, source opening): no watchdog yet.
        assert all(m.startswith("STATUS=") for t, m in listener.messages if t < ready_at)
        listener.drain(2.0)
        assert listener.count("WATCHDOG=1") >= 2  # pinged while frames flow (at least every 1 s here)
        assert any(m.startswith("STATUS=fps=") for _, m in listener.messages)

        # 1. A threshold change is applied live.
        config(cfg_path, confidence=0.25)
        proc.send_signal(signal.SIGHUP)
        wait_log(log_path, "changed=detector.local.appearance.confidence", 20, listener)
        listener.wait_for("RELOADING=1", 5)

        # 2. A broken file is reported one line per problem and the running config stays.
        cfg_path.write_text("detector:\n  local:\n    appearance:\n      confidence: 1.7\n")
        proc.send_signal(signal.SIGHUP)
        wait_log(log_path, "reload rejected, keeping the running config: %s:4: "
                 "detector.local.appearance.confidence: 1.7 is not in [0, 1]" % cfg_path, 20, listener)
        frames_before = log_text(log_path).count("fps=")
        listener.drain(1.5)
        assert proc.poll() is None and log_text(log_path).count("fps=") > frames_before  # still running

        # 3. A change that needs a restart says so.
        config(cfg_path, confidence=0.25)
        data = yaml.safe_load(cfg_path.read_text())
        data["capture"]["synthetic"]["seed"] = 4
        cfg_path.write_text(yaml.safe_dump(data))
        proc.send_signal(signal.SIGHUP)
        wait_log(log_path, "need a restart and are not applied yet: capture.synthetic.seed", 20, listener)
        # ...and still needs it at the next reload: the running value was kept, not overwritten.
        data["detector"]["backend"] = "cuda"
        cfg_path.write_text(yaml.safe_dump(data))
        proc.send_signal(signal.SIGHUP)
        wait_log(log_path, "need a restart and are not applied yet: capture.synthetic.seed, detector.backend", 20,
                 listener)
        proc.send_signal(signal.SIGHUP)
        wait_log(log_path, "capture.synthetic.seed, detector.backend", 20, listener, count=2)

        # 4. SIGTERM: finish the frame, say STOPPING=1, exit 0 with a final summary.
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
        listener.drain(0.5)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "STOPPING=1" in [m for _, m in listener.messages]
    text = log_text(log_path)
    assert "final fps=" in text and "Traceback" not in text

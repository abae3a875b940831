"""The payload as a process (`glad-payload run`) against the fake autopilot over real UDP."""

import csv
import math
import os
import signal
import subprocess
import sys
import time

import pytest
import yaml

from payload.loopback import FAKE_AUTOPILOT, free_udp_port, record_rows

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGET_TYPES = ("CAMERA_TRACKING_IMAGE_STATUS", "DEBUG_VECT")

pytestmark = pytest.mark.slow


def write_config(tmp_path, port, out_dir, frames=0, pace=False, timeout_s=3.0):
    cfg = {
        "capture": {"source": "synthetic", "pace": pace,
                    "synthetic": {"seed": 7, "width": 960, "height": 540, "fps": 30.0, "frames": frames}},
        "mavlink": {"connection": "udpout:127.0.0.1:%d" % port, "autopilot_timeout_s": timeout_s,
                    "attitude_rate_hz": 20.0},
        "outputs": {"directory": str(out_dir)},
        "logging": {"summary_interval_s": 1.0},
    }
    path = tmp_path / "payload.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return str(path)


def start_autopilot(port, record, *extra):
    # payload.loopback.start_fake_autopilot's, with a stdin to switch the link off and on (--stdin-control)
    return subprocess.Popen(
        [sys.executable, FAKE_AUTOPILOT, "--listen", "udpin:127.0.0.1:%d" % port, "--record", str(record), *extra],
        stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )


def start_payload(config, *extra, log_path):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen(
        [sys.executable, "-m", "payload", "run", "--config", config, *extra],
        cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=open(log_path, "w"),
    )


def read_decisions(out_dir):
    with open(os.path.join(out_dir, "decisions.csv")) as fh:
        return list(csv.DictReader(fh))


def wait_for(predicate, timeout_s, what):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError("timed out waiting for " + what)


def decisions_count(out_dir):
    path = os.path.join(out_dir, "decisions.csv")
    if not os.path.exists(path):
        return 0
    with open(path) as fh:
        return max(0, sum(1 for _ in fh) - 1)


def stop(proc, timeout_s=20):
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise


def check_target_messages_match(record, decisions, image_wh=(960, 540)):
    """Every tracking message is one of the payload's own decisions (box centre and bearing)."""
    w, h = image_wh
    centres = []
    azimuths = []
    for row in decisions:
        if row["state"] in ("detected", "coasting"):
            x, y, bw, bh = (float(row[k]) for k in ("x", "y", "w", "h"))
            # A coasting prediction may leave the image; the message carries it clipped to 0..1.
            centres.append((min(max((x + bw / 2) / w, 0.0), 1.0), min(max((y + bh / 2) / h, 0.0), 1.0)))
            azimuths.append(float(row["az_body_rad"]))
    assert centres, "the payload never had a target"
    tracking = [r for r in record if r.get("dir") == "in" and r["type"] == "CAMERA_TRACKING_IMAGE_STATUS"
                and not math.isnan(r["fields"]["point_x"])]
    vectors = [r for r in record if r.get("dir") == "in" and r["type"] == "DEBUG_VECT"]
    assert len(tracking) >= 0.5 * len(centres), (len(tracking), len(centres))
    assert len(vectors) >= 0.5 * len(centres)
    for r in tracking:
        px, py = r["fields"]["point_x"], r["fields"]["point_y"]
        # decisions.csv rounds to 0.1 px: allow that, nothing more
        assert min(abs(px - cx) + abs(py - cy) for cx, cy in centres) < 0.2 / min(w, h) * 2 + 1e-4
    for r in vectors:
        assert min(abs(r["fields"]["x"] - az) for az in azimuths) < 2e-4
        assert r["fields"]["name"].startswith("TGT_BRG")


def run_exchange(tmp_path, payload_port, autopilot_port, router=None):
    out_dir = tmp_path / "out"
    record = tmp_path / "record.jsonl"
    config = write_config(tmp_path, payload_port, out_dir, frames=0, pace=False)
    autopilot = start_autopilot(autopilot_port, record, "--stdin-control")
    payload = start_payload(config, "--frames", "300", log_path=tmp_path / "payload.log")
    try:
        t0 = time.monotonic()
        wait_for(lambda: decisions_count(out_dir) >= 100, 120, "100 processed frames")
        autopilot.stdin.write("disable\n")
        autopilot.stdin.flush()
        wait_for(lambda: any(r.get("type") == "COMMAND_ACK" for r in record_rows(record)), 10, "COMMAND_ACK")
        time.sleep(1.5)
        autopilot.stdin.write("enable\n")
        autopilot.stdin.flush()
        assert payload.wait(timeout=180) == 0, open(tmp_path / "payload.log").read()[-3000:]
        elapsed = time.monotonic() - t0
        time.sleep(0.5)
    finally:
        stop(payload)
        stop(autopilot)
        if router is not None:
            stop(router)
    rows = record_rows(record)
    decisions = read_decisions(out_dir)
    log = open(tmp_path / "payload.log").read()
    assert len(decisions) >= 300
    check_target_messages_match(rows, decisions)
    # Heartbeats from our camera component at ~1 Hz.
    # The link also sends one at once after each enable/disable (its state shows in system_status):
    # leave those out, they come within a moment of the COMMAND_ACK.
    acks = [r["t"] for r in rows if r.get("dir") == "in" and r["type"] == "COMMAND_ACK"]
    beats = [r["t"] for r in rows if r.get("dir") == "in" and r["type"] == "HEARTBEAT" and r["compid"] == 100
             and not any(0 <= r["t"] - t_ack < 0.1 for t_ack in acks)]
    rate = (len(beats) - 1) / (beats[-1] - beats[0])
    assert 0.7 < rate < 1.3, rate
    assert len(beats) >= int(elapsed * 0.6)
    # The disable command is acknowledged, then nothing about the target arrives until enable.
    ack = next(r for r in rows if r.get("dir") == "in" and r["type"] == "COMMAND_ACK")
    assert ack["fields"]["command"] == 31010 and ack["fields"]["result"] == 0
    enable = next(r for r in rows if r.get("dir") == "out" and r["type"] == "COMMAND_LONG" and r["fields"]["param1"] == 1.0)
    between = [r for r in rows if r.get("dir") == "in" and r["type"] in TARGET_TYPES and ack["t"] < r["t"] < enable["t"]]
    assert between == []
    after = [r for r in rows if r.get("dir") == "in" and r["type"] in TARGET_TYPES and r["t"] > enable["t"]]
    assert after, "target messages did not resume after enable"
    assert "detection disabled by command" in log and "detection enabled by command" in log
    return rows


def test_run_against_fake_autopilot_over_udp(tmp_path):
    port = free_udp_port()
    run_exchange(tmp_path, port, port)


def test_run_with_mavproxy_in_the_middle(tmp_path, mavproxy_script):
    mavproxy = mavproxy_script
    payload_port, autopilot_port = free_udp_port(), free_udp_port()
    # MAVProxy listens for the payload and forwards to the autopilot, as a GCS-side router would.
    router = subprocess.Popen(
        [sys.executable, mavproxy, "--master=udpin:127.0.0.1:%d" % payload_port,
         "--out=udpout:127.0.0.1:%d" % autopilot_port, "--daemon", "--non-interactive", "--default-modules=",
         "--state-basedir=%s" % tmp_path, "--nowait"],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=str(tmp_path),
    )
    time.sleep(1.0)
    rows = run_exchange(tmp_path, payload_port, autopilot_port, router=router)
    assert any(r["type"] == "CAMERA_TRACKING_IMAGE_STATUS" for r in rows)


def test_autopilot_killed_and_back(tmp_path):
    port = free_udp_port()
    out_dir = tmp_path / "out"
    config = write_config(tmp_path, port, out_dir, frames=0, pace=True, timeout_s=2.0)
    first, second = tmp_path / "first.jsonl", tmp_path / "second.jsonl"
    log_path = tmp_path / "payload.log"
    autopilot = start_autopilot(port, first)
    payload = start_payload(config, log_path=log_path)
    try:
        wait_for(lambda: any(r["type"] in TARGET_TYPES for r in record_rows(first)), 120, "first target message")
        # targets go out before the autopilot's heartbeat is in: only one that was found can be lost
        wait_for(lambda: "autopilot found" in open(log_path).read(), 15, "the autopilot to be found")
        autopilot.kill()
        autopilot.wait()
        wait_for(lambda: "autopilot lost" in open(log_path).read(), 15, "the loss to be logged")
        frames_at_loss = decisions_count(out_dir)
        time.sleep(2.0)
        assert decisions_count(out_dir) > frames_at_loss + 10, "frames stopped while the autopilot was away"
        autopilot = start_autopilot(port, second)
        wait_for(lambda: any(r["type"] in TARGET_TYPES for r in record_rows(second)), 30, "sending to resume")
        wait_for(lambda: any(r["type"] == "HEARTBEAT" and r.get("compid") == 100 for r in record_rows(second)),
                 5, "our heartbeat to reach the new autopilot")
        assert stop(payload) == 0
    finally:
        stop(payload)
        stop(autopilot)
    log = open(log_path).read()
    assert "Traceback" not in log
    assert "final " in log  # the clean-shutdown summary

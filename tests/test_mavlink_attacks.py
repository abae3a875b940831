"""Issue 20's attacks on the MAVLink input, each against the real link thread over real UDP on
127.0.0.1 with real pymavlink packets: from the fake autopilot (sitl/fake_autopilot.py), or from
``Peer``, a UDP socket with pymavlink's encoder playing an autopilot or an attacker."""

import json
import logging
import math
import os
import random
import socket
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as M
from test_mavlink import (
    ACCEPTED,
    CMD_SET_MESSAGE_INTERVAL,
    CMD_USER_1,
    Payload,
    free_port,
    link_cfg,
    start_fake,
    wait_for,
)

from payload.config import MavlinkConfig
from payload.mavlink.link import MavlinkLink

LOCAL = "127.0.0.1"


class Peer:
    """A MAVLink endpoint: a UDP socket on 127.0.0.1 and pymavlink's MAVLink 2 encoder/decoder."""

    def __init__(self, sysid=1, compid=1):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((LOCAL, 0))
        self.addr = self.sock.getsockname()
        self.mav = M.MAVLink(None, sysid, compid)
        self.rx = M.MAVLink(None)
        self.rx.robust_parsing = True

    def packet(self, msg, sysid=None):
        if sysid is not None:
            self.mav.srcSystem = sysid
        return msg.pack(self.mav)

    def send(self, dest, *msgs):
        self.sock.sendto(b"".join(self.packet(m) for m in msgs), dest)

    def heartbeat(self, dest):
        self.send(dest, M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3))

    def received(self, wait_s=0.0):
        """Messages that arrived (waiting up to wait_s for the first)."""
        out = []
        self.sock.settimeout(wait_s if wait_s > 0 else 0.001)
        try:
            while True:
                data = self.sock.recv(65535)
                out.extend(self.rx.parse_buffer(data) or [])
                self.sock.settimeout(0.001)
        except (socket.timeout, BlockingIOError):
            pass
        return out

    def close(self):
        self.sock.close()


def signed_fake(fakes, tmp_path, monkeypatch):
    """A signing fake autopilot and the config of a signing link to it (state file next to the key)."""
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    key = tmp_path / "mavlink.key"
    key.write_text(os.urandom(32).hex())
    port = free_port()
    fake = start_fake(fakes, tmp_path, f"udpin:{LOCAL}:{port}", "--signing-key", str(key))
    cfg = link_cfg(f"udpout:{LOCAL}:{port}", signing={"enabled": True, "key_file": str(key)})
    return fake, cfg, key


def command_acks(fake):
    return [r["fields"]["result"] for r in fake.acks(CMD_USER_1)]


# --- signing ------------------------------------------------------------------------------------


def test_forged_packet_does_not_lock_out_the_ground_station(fakes, tmp_path, monkeypatch):
    """One packet signed with a random key, timestamp 2^48-1, the GCS's link id (7), sysid 255:
    pymavlink recorded its timestamp for the GCS's stream before checking the hash, so every later
    genuine command was 'old'. Now the hash is checked first."""
    fake, cfg, _ = signed_fake(fakes, tmp_path, monkeypatch)
    with MavlinkLink(cfg) as link:
        wait_for(lambda: link.status.autopilot_seen, 10.0, "signed autopilot")
        fake.command("disable")
        wait_for(lambda: command_acks(fake) == [ACCEPTED], 5.0, "ACK of the genuine disable")
        rejected = link.status.rejected
        fake.command("enable,badkey,linkid=7,timestamp=%d" % (2 ** 48 - 1))
        wait_for(lambda: link.status.rejected > rejected, 5.0, "the forged packet rejected")
        assert not link.detection_enabled
        fake.command("enable")  # genuine, with the GCS's normal timestamp
        wait_for(lambda: command_acks(fake) == [ACCEPTED, ACCEPTED], 5.0, "ACK of the genuine enable")
        assert link.detection_enabled


def test_signed_disable_replayed_after_restart_is_refused(fakes, tmp_path, monkeypatch):
    """A genuine signed disable, captured as bytes, replayed to a restarted payload (a new link on
    the same key): refused, because the signing timestamps were kept across the restart."""
    fake, cfg, key = signed_fake(fakes, tmp_path, monkeypatch)
    with MavlinkLink(cfg) as link:
        wait_for(lambda: link.status.autopilot_seen, 10.0, "signed autopilot")
        fake.command("disable")
        wait_for(lambda: command_acks(fake) == [ACCEPTED], 5.0, "ACK of disable")
        fake.command("enable")
        wait_for(lambda: command_acks(fake) == [ACCEPTED, ACCEPTED], 5.0, "ACK of enable")
    captured = [r for r in fake.rows() if r.get("dir") == "out" and r["type"] == "COMMAND_LONG"]
    assert captured[0]["fields"]["param1"] == 0.0 and captured[0]["hex"]

    with MavlinkLink(cfg) as restarted:
        wait_for(lambda: restarted.status.autopilot_seen, 10.0, "autopilot after the restart")
        fake.command("replay,0")
        time.sleep(0.8)
        assert restarted.detection_enabled, "the replayed disable was accepted"
        assert command_acks(fake) == [ACCEPTED, ACCEPTED] and restarted.status.rejected >= 1
        fake.command("disable")  # the ground station itself is still heard after the restart
        wait_for(lambda: len(command_acks(fake)) == 3, 5.0, "ACK of a new disable")
        assert not restarted.detection_enabled
    # kept next to the key (no STATE_DIRECTORY here), with the ground station's stream
    state = json.loads((tmp_path / "mavlink.key.state").read_text())
    assert [7, 255, 190] in [row[:3] for row in state["streams"]]


def test_unwritable_signing_state_is_one_warning_and_the_link_goes_on(fakes, tmp_path, monkeypatch, caplog):
    fake, cfg, _ = signed_fake(fakes, tmp_path, monkeypatch)
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path / "missing" / "dir"))
    with caplog.at_level(logging.WARNING, logger="payload.mavlink.signing"), MavlinkLink(cfg) as link:
        wait_for(lambda: link.status.autopilot_seen, 10.0, "signed autopilot")
        for _ in range(2):
            fake.command("disable")
            fake.command("enable")
        wait_for(lambda: len(command_acks(fake)) == 4, 5.0, "ACKs")
    lines = [r.getMessage() for r in caplog.records if "cannot write" in r.getMessage()]
    assert len(lines) == 1 and str(tmp_path / "missing") in lines[0]


# --- udpin: who gets our messages -----------------------------------------------------------------


def test_udpin_talks_only_to_the_autopilot_not_to_every_sender(fakes, tmp_path):
    """3000 sources send one datagram each (GCS heartbeats, spoofed autopilot heartbeats): none
    becomes a destination (mavutil kept every sender forever and sent each message to all)."""
    port = free_port()
    link = MavlinkLink(link_cfg(f"udpin:{LOCAL}:{port}"))
    kept = []
    with link, Payload(link, link.cfg.outputs) as payload:
        fake1 = start_fake(fakes, tmp_path, f"udpout:{LOCAL}:{port}", name="fake1")
        wait_for(lambda: link.status.autopilot_seen, 10.0, "autopilot speaking first")
        gcs_hb = M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)
        ap_hb = M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)
        for i in range(3000):
            p = Peer(sysid=1 if i % 2 else 255)
            p.send((LOCAL, port), ap_hb if i % 2 else gcs_hb)
            if i % 150 == 0:
                kept.append(p)
            else:
                p.close()
        time.sleep(1.5)
        got = {p.addr: p.received() for p in kept}
        assert not any(got.values()), "a sender other than the autopilot received our messages"
        n = len(fake1.rows("DEBUG_VECT"))
        wait_for(lambda: len(fake1.rows("DEBUG_VECT")) > n + 5, 5.0, "target messages still reaching the autopilot")
        assert link.status.autopilot_seen and link.status.foreign >= 1

        # the autopilot goes away: its address expires once another autopilot speaks
        fake1.kill()
        wait_for(lambda: not link.status.autopilot_seen, 5.0, "autopilot lost")
        fake2 = start_fake(fakes, tmp_path, f"udpout:{LOCAL}:{port}", name="fake2")
        wait_for(lambda: len(fake2.rows("DEBUG_VECT")) > 5, 10.0, "target messages to the new autopilot's address")
        assert not any(p.received() for p in kept)
        assert not payload.errors
    for p in kept:
        p.close()


def test_udpout_ignores_a_spoofed_disable_from_another_socket(fakes, tmp_path):
    port = free_port()
    fake = start_fake(fakes, tmp_path, f"udpin:{LOCAL}:{port}")
    with MavlinkLink(link_cfg(f"udpout:{LOCAL}:{port}")) as link:
        wait_for(lambda: link.status.autopilot_seen, 10.0, "autopilot")
        conn = link._conn
        link_addr = (getattr(conn, "sock", None) or conn.port).getsockname()  # the link's own UDP port
        spoofer = Peer(sysid=255, compid=190)
        for _ in range(3):
            spoofer.send(link_addr, M.MAVLink_command_long_message(1, 100, CMD_USER_1, 0, 0, 0, 0, 0, 0, 0, 0))
        time.sleep(0.8)
        assert link.detection_enabled, "a disable from a socket that is not the autopilot was accepted"
        assert not [m for m in spoofer.received() if m.get_type() == "COMMAND_ACK"]
        spoofer.close()
        fake.command("disable")  # the same command through the autopilot is accepted
        wait_for(lambda: command_acks(fake) == [ACCEPTED], 5.0, "ACK of the genuine disable")
        assert not link.detection_enabled


# --- floods ---------------------------------------------------------------------------------------

FLOODER = r"""
import os, socket, sys, time
from pymavlink.dialects.v20 import ardupilotmega as M
port, flood_s = int(sys.argv[1]), float(sys.argv[2])
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
mav = M.MAVLink(None, 1, 1)
def heartbeat():
    s.sendto(M.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(mav), ("127.0.0.1", port))
garbage = [b"\xfd" + os.urandom(8191) for _ in range(16)]
t0 = time.monotonic()
next_hb = 0.0
phase = "before"
while True:
    now = time.monotonic() - t0
    if now >= next_hb:
        heartbeat()
        next_hb = now + 0.1
    if phase == "before" and now > 1.0:
        phase = "flood"
        print("FLOOD_START %.6f" % time.monotonic(), flush=True)
    if phase == "flood":
        for g in garbage:
            try:
                s.sendto(g, ("127.0.0.1", port))
            except OSError:
                pass
        if now > 1.0 + flood_s:
            phase = "after"
            print("FLOOD_END %.6f" % time.monotonic(), flush=True)
    else:
        time.sleep(0.01)
"""


def test_garbage_flood_does_not_outlive_itself(tmp_path):
    """3 s of 8 KiB garbage datagrams from the autopilot's own address (the worst case: they are
    parsed) mixed with its 10 Hz heartbeats: right after the flood the autopilot is heard again
    (mavutil's parser kept every unparsed byte: ~60 s of 'lost' after a 10 s flood)."""
    port = free_port()
    script = tmp_path / "flooder.py"
    script.write_text(FLOODER)
    with MavlinkLink(link_cfg(f"udpin:{LOCAL}:{port}", autopilot_timeout_s=1.0)) as link:
        wait_for(lambda: link.status.connected, 5.0, "socket open")
        flooder = subprocess.Popen([sys.executable, str(script), str(port), "3.0"], stdout=subprocess.PIPE, text=True)
        try:
            assert flooder.stdout.readline().startswith("FLOOD_START")
            assert link.status.autopilot_seen, "the autopilot should have been found before the flood"
            t_end = float(flooder.stdout.readline().split()[1])
            wait_for(lambda: link.status.autopilot_seen and link.status.autopilot_age_s < 0.3, 5.0,
                     "autopilot heard after the flood")
            assert time.monotonic() - t_end < 1.5, "autopilot heard %.1f s after the flood" % (time.monotonic() - t_end)
            # Nothing of the flood stays in the parser. Read from this thread while the link's own
            # thread may be inside one last queued datagram, so wait for the queue to drain.
            wait_for(lambda: link._conn.mav.buf_len() == 0, 2.0, "parser empty after the flood")
        finally:
            flooder.kill()
            flooder.wait(5)


def test_many_ignored_commands_are_counted_and_logged_rate_limited(caplog):
    """10,200 distinct (sysid, command) pairs from sysids not allowed to command: every one counted,
    a handful of WARNING lines (one per source per 10 s, at most 5 sources, then a summary)."""
    port = free_port()
    link = MavlinkLink(link_cfg(f"udpin:{LOCAL}:{port}"))
    ap = Peer(sysid=1, compid=1)
    pairs = [(sysid, 31000 + c) for sysid in range(2, 253) if sysid != 255 for c in range(40)][:10200]
    with caplog.at_level(logging.WARNING, logger="payload.mavlink"), link:
        wait_for(lambda: link.status.connected, 5.0, "socket open")
        ap.heartbeat((LOCAL, port))
        wait_for(lambda: link.status.autopilot_seen, 5.0, "autopilot")
        for i in range(0, len(pairs), 30):
            ap.sock.sendto(b"".join(
                ap.packet(M.MAVLink_command_long_message(1, 100, cmd, 0, 0, 0, 0, 0, 0, 0, 0), sysid=sysid)
                for sysid, cmd in pairs[i:i + 30]), (LOCAL, port))
            time.sleep(0.001)
        try:
            wait_for(lambda: link.status.commands_ignored == len(pairs), 10.0, "every command counted")
        finally:
            warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
            assert len([w for w in warnings if w.startswith("ignoring command")]) <= 5, len(warnings)
            assert len(warnings) <= 8, warnings
    assert link.detection_enabled
    ap.close()


# --- values ---------------------------------------------------------------------------------------


def test_non_finite_attitude_is_rejected_at_the_door():
    """ATTITUDE with roll NaN, pitch +inf, yaw -inf, roll 1e30 among good samples: dropped and
    counted; attitude_at gives only finite angles (before: NaN bearings, an exception on inf)."""
    port = free_port()
    ap = Peer(sysid=1, compid=1)
    link = MavlinkLink(link_cfg(f"udpin:{LOCAL}:{port}", attitude_rate_hz=0.0, timesync=False))
    bad = [(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (0.0, 0.0, -math.inf), (1e30, 0.0, 0.0)]
    with link:
        wait_for(lambda: link.status.connected, 5.0, "socket open")
        ap.heartbeat((LOCAL, port))
        wait_for(lambda: link.status.autopilot_seen, 5.0, "autopilot")
        msgs = []
        for i in range(60):  # 20 ms apart in autopilot time; every 10th is bad
            r, p, y = bad[(i // 10) % 4] if i % 10 == 5 else (0.1, -0.05, 0.3 + 0.01 * i)
            msgs.append(M.MAVLink_attitude_message(10_000 + 20 * i, r, p, y, 0.0, 0.0, 0.0))
        for i in range(0, 60, 6):
            ap.send((LOCAL, port), *msgs[i:i + 6])
        wait_for(lambda: link.status.attitude_age_s is not None, 5.0, "ATTITUDE")
        time.sleep(0.3)
        offset = link.status.time_offset_ns
        got = [link.attitude_at(t_boot_ms * 1_000_000 - offset) for t_boot_ms in range(10_000, 11_180, 5)]
        assert all(a is not None for a in got)
        assert all(math.isfinite(v) for a in got for v in (a.roll_rad, a.pitch_rad, a.yaw_rad))
        assert max(abs(a.roll_rad - 0.1) for a in got) < 1e-6
        assert link.status.nonfinite == 6
    ap.close()


# --- reload -------------------------------------------------------------------------------------


def test_apply_changes_command_sysids_and_rates_of_the_running_link(fakes, tmp_path):
    port = free_port()
    fake = start_fake(fakes, tmp_path, f"udpin:{LOCAL}:{port}")
    cfg = link_cfg(f"udpout:{LOCAL}:{port}", attitude_rate_hz=10.0)
    with MavlinkLink(cfg) as link:
        wait_for(lambda: link.status.autopilot_seen and link.status.attitude_age_s is not None, 10.0, "autopilot")
        new = MavlinkConfig(**dict(cfg.model_dump(), command_sysids=[42], heartbeat_hz=5.0, attitude_rate_hz=25.0,
                                   autopilot_timeout_s=2.0, retry={"initial_s": 0.3, "max_s": 0.6},
                                   connection="udpout:127.0.0.1:9", system_id=7,
                                   signing={"enabled": True, "key_file": "/nonexistent"}))
        applied = link.apply(new)
        assert sorted(applied) == ["mavlink.attitude_rate_hz", "mavlink.autopilot_timeout_s", "mavlink.command_sysids",
                                   "mavlink.heartbeat_hz", "mavlink.retry.initial_s", "mavlink.retry.max_s"]
        # restart-only keys are not claimed and keep their running values
        assert link.cfg.connection == cfg.connection and link.cfg.system_id == 1
        assert link.apply(new) == []

        fake.command("disable")  # from 255: no longer allowed
        time.sleep(0.8)
        assert link.detection_enabled and command_acks(fake) == [] and link.status.commands_ignored == 1
        fake.command("disable,sysid=42")
        wait_for(lambda: command_acks(fake) == [ACCEPTED], 5.0, "ACK of the disable from sysid 42")
        assert not link.detection_enabled

        t = time.monotonic()
        time.sleep(1.2)
        hbs = [r for r in fake.rows("HEARTBEAT") if r["compid"] == 100 and t < r["t"] < t + 1.0]
        assert len(hbs) >= 4, "heartbeat_hz=5 not applied"
        reqs = [r["fields"] for r in fake.rows("COMMAND_LONG") if r["fields"]["command"] == CMD_SET_MESSAGE_INTERVAL]
        assert reqs[-1]["param2"] == pytest.approx(40000)  # ATTITUDE asked again at 25 Hz


@pytest.mark.parametrize("seed", [1])
def test_random_senders_sysids_and_commands_do_not_flood_the_log(seed, caplog):
    """Autopilot heartbeats from 200 foreign system ids and 200 udpin senders: each kind logged a few
    times, not once per source."""
    rnd = random.Random(seed)
    port = free_port()
    ap = Peer(sysid=1, compid=1)
    # The autopilot sends one heartbeat: a timeout longer than the test keeps it (and its address) the
    # autopilot however slowly a loaded machine gets through the 400 datagrams below.
    cfg = link_cfg(f"udpin:{LOCAL}:{port}", autopilot_timeout_s=60.0)
    with caplog.at_level(logging.WARNING, logger="payload.mavlink"), MavlinkLink(cfg) as link:
        wait_for(lambda: link.status.connected, 5.0, "socket open")
        ap.heartbeat((LOCAL, port))
        wait_for(lambda: link.status.autopilot_seen, 5.0, "autopilot")
        hb = M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)
        # Paced (20 datagrams, then 10 ms): 400 datagrams at once overflow the socket's receive buffer
        # while a loaded machine has the link thread waiting for a core, and the kernel drops them.
        for n, sysid in enumerate(rnd.sample(range(2, 250), 200)):
            ap.sock.sendto(ap.packet(hb, sysid=sysid), (LOCAL, port))
            if n % 20 == 19:
                time.sleep(0.01)
        others = [Peer() for _ in range(200)]
        for n, p in enumerate(others):
            p.heartbeat((LOCAL, port))
            if n % 20 == 19:
                time.sleep(0.01)
        wait_for(lambda: link.status.foreign >= 150, 5.0, "datagrams from other senders counted")
        time.sleep(0.3)
        for p in others:
            p.close()
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert 1 <= len([w for w in warnings if w.startswith("ignoring autopilot heartbeat")]) <= 5
    assert 1 <= len([w for w in warnings if w.startswith("ignoring datagrams")]) <= 5
    ap.close()


# --- the same through the service process ----------------------------------------------------------


@pytest.mark.slow
def test_payload_process_restart_refuses_a_replayed_signed_disable(fakes, tmp_path):
    """`glad-payload run` with signing, as systemd runs it (STATE_DIRECTORY set): a genuine signed
    disable and enable, the payload stopped (SIGTERM) and started again, the captured disable
    replayed: no ACK and the new process stays ACTIVE (heartbeat system_status 4)."""
    key = tmp_path / "mavlink.key"
    key.write_text(os.urandom(32).hex())
    port = free_port()
    fake = start_fake(fakes, tmp_path, f"udpin:{LOCAL}:{port}", "--signing-key", str(key))
    cfg = {
        "capture": {"source": "synthetic", "pace": True,
                    "synthetic": {"seed": 7, "width": 320, "height": 240, "fps": 10.0, "frames": 0}},
        "mavlink": {"connection": f"udpout:{LOCAL}:{port}", "attitude_rate_hz": 0.0,
                    "signing": {"enabled": True, "key_file": str(key)}},
    }
    config = tmp_path / "payload.yaml"
    config.write_text(json.dumps(cfg))  # JSON is YAML
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    env = dict(os.environ, PYTHONUNBUFFERED="1", STATE_DIRECTORY=str(state_dir))
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

    def start(name):
        log = open(str(tmp_path / name), "w")
        proc = subprocess.Popen([sys.executable, "-m", "payload", "run", "--config", str(config)], cwd=repo, env=env,
                                stdout=subprocess.DEVNULL, stderr=log)
        return proc, log

    def heartbeats_since(t):
        return [r["fields"]["system_status"] for r in fake.rows("HEARTBEAT") if r["compid"] == 100 and r["t"] > t]

    def stop(proc):
        proc.send_signal(2)  # SIGINT, like SIGTERM: a clean stop that saves the signing state
        assert proc.wait(30) == 0

    first, log1 = start("first.log")
    try:
        wait_for(lambda: heartbeats_since(0), 60, "the first payload's heartbeat")
        fake.command("disable")
        wait_for(lambda: command_acks(fake) == [ACCEPTED], 10, "ACK of disable")
        fake.command("enable")
        wait_for(lambda: command_acks(fake) == [ACCEPTED, ACCEPTED], 10, "ACK of enable")
    finally:
        stop(first)
        log1.close()

    second, log2 = start("second.log")
    try:
        t_start = time.monotonic()
        wait_for(lambda: heartbeats_since(t_start), 60, "the restarted payload's heartbeat")
        fake.command("replay,0")
        t_replay = time.monotonic()
        time.sleep(2.5)
        assert command_acks(fake) == [ACCEPTED, ACCEPTED], "the replayed disable was acknowledged"
        after = heartbeats_since(t_replay)
        assert after and all(s == 4 for s in after), after  # ACTIVE: detection still enabled
    finally:
        stop(second)
        log2.close()
    log = (tmp_path / "second.log").read_text()
    assert "rejected packet from sysid=255" in log and "Traceback" not in log
    assert json.loads((state_dir / "mavlink-signing.json").read_text())["streams"]


def test_tcp_garbage_stream_leaves_the_parser_bounded():
    """2 MiB of garbage (many 0xFD markers with bogus lengths) down a TCP connection, then
    heartbeats: they are heard, and the parser never holds more than ~5 KiB."""
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind((LOCAL, 0))
    server.listen(1)
    link = MavlinkLink(link_cfg("tcp:%s:%d" % server.getsockname()))
    rnd = random.Random(3)
    garbage = bytes(0xFD if rnd.random() < 0.05 else rnd.randrange(256) for _ in range(1 << 16)) * 32
    with link:
        conn, _ = server.accept()
        wait_for(lambda: link.status.connected, 5.0, "TCP connected")
        biggest = 0
        for i in range(0, len(garbage), 1 << 14):
            conn.sendall(garbage[i:i + (1 << 14)])
            biggest = max(biggest, link._conn.mav.buf_len())
        # the backlog's parsing is measured in CPU seconds: a loaded machine stretches wall time, not work
        cpu_end = time.process_time()
        hb = M.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(M.MAVLink(None, 1, 1))

        def heard():  # the autopilot keeps sending at 20 Hz (the garbage's last bogus header may swallow one)
            conn.sendall(hb)
            biggest_now = link._conn.mav.buf_len()
            assert biggest_now <= 4 * 280 + 4096, biggest_now
            return link.status.autopilot_seen
        wait_for(heard, 10.0, "the heartbeat after the garbage")
        assert biggest <= 4 * 280 + 4096, biggest
        assert time.process_time() - cpu_end < 5.0
        conn.close()
    server.close()


@pytest.mark.parametrize("content", [b"\xff\xfe not json", b'{"timestamp": "x", "streams": []}', b"[]", b""])
def test_broken_signing_state_is_one_warning_and_the_link_runs(fakes, tmp_path, monkeypatch, caplog, content):
    fake, cfg, key = signed_fake(fakes, tmp_path, monkeypatch)
    (tmp_path / "mavlink.key.state").write_bytes(content)
    with caplog.at_level(logging.WARNING, logger="payload.mavlink.signing"), MavlinkLink(cfg) as link:
        wait_for(lambda: link.status.autopilot_seen, 10.0, "signed autopilot")
        fake.command("disable")
        wait_for(lambda: command_acks(fake) == [ACCEPTED], 5.0, "ACK of disable")
    lines = [r.getMessage() for r in caplog.records if "signing state" in r.getMessage()]
    assert len(lines) == 1 and "cannot read" in lines[0] and "mavlink.key.state" in lines[0], lines
    # rewritten whole by the accepted command
    assert json.loads((tmp_path / "mavlink.key.state").read_text())["streams"]


def test_a_radio_that_stops_taking_bytes_never_stalls_the_frame_step(caplog):
    """Issue 19: MAVLink sends are off the detection path. A serial link whose far end stops
    reading (a pseudo-terminal nobody reads: its buffer fills, then every write waits out
    pyserial's 0.5 s write timeout) stalls the link thread; the frame step only queues its
    messages, so it keeps its pace. Sending from the step, as before, a frame waited 0.5 s."""
    pytest.importorskip("serial")
    import numpy as np

    from payload.bench.runners import DetectorRun
    from payload.config import CameraConfig, MavlinkOutputsConfig
    from payload.geometry import BearingModel
    from payload.mavlink.outputs import TargetPublisher
    from payload.step import FrameStep
    from payload.types import Detections, Frame

    master, slave = os.openpty()
    box = Detections(np.array([[20.0, 10.0, 30.0, 18.0]]), np.array([0.9]), "LAD")
    detector = DetectorRun(lambda image: box, "LAD", [])
    link = MavlinkLink(link_cfg(os.ttyname(slave), baud=921600, timesync=False, attitude_rate_hz=0.0))
    step = FrameStep(detector, BearingModel(CameraConfig()), link=link,
                     publisher=TargetPublisher(link, MavlinkOutputsConfig()))
    image = np.zeros((48, 64, 3), np.uint8)
    longest_s, frames = 0.0, 0
    try:
        with caplog.at_level("WARNING", logger="payload.mavlink.link"), link:
            wait_for(lambda: link.status.connected, 5.0, "serial port open")
            t_end = time.monotonic() + 3.0
            while time.monotonic() < t_end:
                t0 = time.monotonic()
                outcome = step(Frame(image=image, index=frames, t_capture_ns=time.monotonic_ns(),
                                     t_wall_ns=time.time_ns()))
                longest_s = max(longest_s, time.monotonic() - t0)
                assert outcome.result.target is not None
                frames += 1
                time.sleep(0.004)
            st = link.status
    finally:
        os.close(master)
        os.close(slave)
    stalled = [r for r in caplog.records if "mavlink write failed" in r.getMessage()]
    # the attack worked: the link thread's writes timed out (0.5 s each) and the messages behind them were dropped
    assert stalled and st.dropped > 0, (len(stalled), st)
    # ... while no frame waited for it: the longest step is far below one write timeout
    assert longest_s < 0.25, "a frame step took %.3f s while the link was blocked" % longest_s

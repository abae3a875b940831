#!/usr/bin/env python3
"""A fake autopilot for testing the payload's MAVLink link without SITL.

    python sitl/fake_autopilot.py --listen udpin:127.0.0.1:14550 --record out.jsonl \
        --command-at 5:disable --command-at 10:enable --duration 20

It is system 1, component 1 (MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA) and:

- sends HEARTBEAT at 1 Hz;
- answers TIMESYNC requests with its boot clock (ns since this process started);
- answers MAV_CMD_SET_MESSAGE_INTERVAL for ATTITUDE with COMMAND_ACK and then streams
  ATTITUDE at the asked rate, following ``trajectory(t)`` (sinusoidal roll and pitch, yaw
  turning through +-pi); other message ids and commands get MAV_RESULT_UNSUPPORTED;
  with ``--scene-seed N`` (offered only when ``payload.synth.scene`` is importable) the
  attitude is instead the synthetic scene's camera (roll, pitch, yaw) at frame
  ``int(t * --scene-fps)``, so a payload rendering the same scene sees a consistent vehicle;
- answers MAV_CMD_SET_MESSAGE_INTERVAL for GLOBAL_POSITION_INT likewise and streams the
  vehicle's position: ``HOME`` moving east at 2 m/s, or with ``--scene-seed`` the scene's camera
  position (world x = east, y = down, z = north) around ``HOME``;
- sends COMMAND_LONG like a ground station (system 255, component 190 by default) at given
  times (``--command-at T:ACTION``) or when a line ``ACTION`` arrives on stdin
  (``--stdin-control``). ACTION = enable | disable | NUMBER (a MAV_CMD id), optionally
  followed by ``,sysid=N``, ``,compid=N``, ``,param1=X`` (to ``param7``), ``,unsigned``, and for attacks on
  signing ``,badkey`` (signed with a random key), ``,timestamp=N``, ``,linkid=N`` (default 7);
  ``replay,I`` sends the bytes of the I-th command sent (0-based) again, unchanged;
- with ``--signing-key FILE`` (32 raw bytes or 64 hex characters) signs what it sends and
  drops unsigned messages (recorded as BAD_DATA);
- records every message it receives as one JSON line (flushed per line):
  ``{"dir": "in", "t": monotonic_s, "sysid", "compid", "type", "signed", "fields"}``;
  the first line is ``{"type": "START", "t_start_ns": ...}`` (its boot time on the
  monotonic clock) and the commands it sends are recorded with ``"dir": "out"`` and their
  bytes in ``"hex"``.

Runs until killed (SIGTERM/SIGINT) or for ``--duration`` seconds.
"""

import argparse
import json
import math
import os
import select
import signal
import sys
import time

os.environ["MAVLINK20"] = "1"
os.environ.setdefault("MAVLINK_DIALECT", "ardupilotmega")

from pymavlink import mavutil  # noqa: E402

M = mavutil.mavlink
GCS_COMPID = 190  # MAV_COMP_ID_MISSIONPLANNER
HOME = (47.397742, 8.545594, 488.0)  # lat, lon (deg), alt (m AMSL) of the scripted flight
EARTH_RADIUS_M = 6378137.0
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _scene_class():
    """payload.synth.scene.Scene when importable (from this checkout or the environment), else None."""
    if REPO not in sys.path:
        sys.path.append(REPO)
    try:
        from payload.synth.scene import Scene
    except ImportError:
        return None
    return Scene


class SceneAttitude:
    """The synthetic scene's camera attitude per frame, rendered small (the camera path does not
    depend on the image size) and advanced lazily as time passes. A zero camera mount is assumed:
    camera roll/pitch/yaw = vehicle roll/pitch/yaw."""

    def __init__(self, scene_cls, seed, fps):
        self.fps = fps
        scene = scene_cls(seed=seed, width=160, height=96, fps=fps, frames=0, clutter=0, birds=0, cars=0, noise=0.0)
        self.frames = iter(scene)
        self.index = -1
        self.rpy = (0.0, 0.0, 0.0)
        self.ned = (0.0, 0.0, 0.0)

    def _advance(self, t_s):
        want = int(t_s * self.fps)
        while self.index < want:
            frame = next(self.frames)
            self.rpy = tuple(float(a) for a in frame.camera_rpy_rad)
            x, y, z = frame.camera_position_m
            self.ned = (z, x, y)
            self.index += 1

    def __call__(self, t_s):
        self._advance(t_s)
        return self.rpy

    def position(self, t_s):
        """(north, east, down) metres from HOME at t_s."""
        self._advance(t_s)
        return self.ned


def flight_ned(t_s):
    """The scripted vehicle's (north, east, down) metres from HOME: east at 2 m/s, 30 m up."""
    return 0.0, 2.0 * t_s, -30.0


def trajectory(t_s):
    """The scripted attitude (roll, pitch, yaw in rad) at t_s seconds after start."""
    roll = 0.2 * math.sin(2.0 * math.pi * 0.5 * t_s)
    pitch = 0.1 * math.sin(2.0 * math.pi * 0.3 * t_s + 0.5)
    yaw = math.remainder(2.8 + 2.0 * t_s, 2.0 * math.pi)  # crosses +-pi at t = 0.17 s, then every pi s
    return roll, pitch, yaw


def load_key(path):
    with open(path, "rb") as fh:
        data = fh.read()
    if len(data) == 32:
        return data
    return bytes.fromhex(data.strip().decode("ascii"))


def parse_action(text, default_sysid):
    """'disable,sysid=42,unsigned' -> dict(command, param1, sysid, compid, signed)."""
    parts = [p.strip() for p in text.strip().split(",") if p.strip()]
    if not parts:
        raise ValueError("empty command")
    head = parts[0].lower()
    out = {"sysid": default_sysid, "compid": GCS_COMPID, "signed": True, "badkey": False,
           "timestamp": None, "linkid": 7}
    if head in ("enable", "disable"):
        out["command"] = M.MAV_CMD_USER_1
        out["param1"] = 1.0 if head == "enable" else 0.0
    else:
        out["command"] = int(head)
    for p in parts[1:]:
        if p == "unsigned":
            out["signed"] = False
        elif p == "badkey":
            out["badkey"] = True
        else:
            key, value = p.split("=", 1)
            out[key] = float(value) if key.startswith("param") else int(value)
    out.setdefault("param1", 0.0)
    return out


class FakeAutopilot:
    def __init__(self, args):
        self.args = args
        self.start_ns = time.monotonic_ns()
        self.conn = mavutil.mavlink_connection(
            args.listen, source_system=args.sysid, source_component=args.compid
        )
        self.key = load_key(args.signing_key) if args.signing_key else None
        if self.key:
            self.conn.setup_signing(self.key, sign_outgoing=True)
        self.record = open(args.record, "a", encoding="utf-8") if args.record else None
        self.attitude_period_ns = int(1e9 / args.attitude_hz) if args.attitude_hz > 0 else 0
        scene_seed = getattr(args, "scene_seed", None)
        self.attitude_of = trajectory if scene_seed is None else SceneAttitude(_scene_class(), scene_seed, args.scene_fps)
        self.position_of = flight_ned if scene_seed is None else self.attitude_of.position
        self.position_period_ns = 0
        self.next_position_ns = 0
        self.next_attitude_ns = 0
        self.next_heartbeat_ns = 0
        self.sent = []  # bytes of each command sent, for replay
        self.pending = sorted(
            (float(spec.split(":", 1)[0]), spec.split(":", 1)[1]) for spec in args.command_at
        )
        self.write({"type": "START", "t": time.monotonic(), "t_start_ns": self.start_ns, "pid": os.getpid()})

    def boot_ns(self):
        return time.monotonic_ns() - self.start_ns

    def write(self, row):
        if self.record is not None:
            self.record.write(json.dumps(row, default=repr) + "\n")
            self.record.flush()

    def gcs_send(self, action):
        """Send COMMAND_LONG from another system id (a ground station) over the same link."""
        if action.strip().lower().startswith("replay,"):
            buf = self.sent[int(action.split(",")[1])]
            self.conn.write(buf)
            self.write({"dir": "out", "t": time.monotonic(), "type": "REPLAY", "hex": buf.hex()})
            return
        spec = parse_action(action, self.args.gcs_sysid)
        gcs = M.MAVLink(self.conn, srcSystem=spec["sysid"], srcComponent=spec["compid"])
        if self.key and spec["signed"]:
            gcs.signing.secret_key = os.urandom(32) if spec["badkey"] else self.key
            gcs.signing.sign_outgoing = True
            gcs.signing.link_id = spec["linkid"]
            ts = spec["timestamp"]
            gcs.signing.timestamp = self.conn.mav.signing.timestamp if ts is None else ts
            if ts is None:
                self.conn.mav.signing.timestamp += 1  # the next command is newer, however fast it follows
        msg = M.MAVLink_command_long_message(
            self.args.target_sysid, self.args.target_compid, spec["command"], 0,
            *(spec.get("param%d" % i, 0.0) for i in range(1, 8)),
        )
        gcs.send(msg)
        buf = bytes(msg.get_msgbuf())
        self.sent.append(buf)
        self.write({"dir": "out", "t": time.monotonic(), "sysid": spec["sysid"], "compid": spec["compid"],
                    "type": "COMMAND_LONG", "signed": bool(self.key and spec["signed"]), "fields": _fields(msg),
                    "hex": buf.hex()})

    def on_message(self, msg):
        kind = msg.get_type()
        row = {"dir": "in", "t": time.monotonic(), "sysid": msg.get_srcSystem(), "compid": msg.get_srcComponent(),
               "type": kind, "signed": bool(msg.get_signed()) if hasattr(msg, "get_signed") else False}
        if kind == "BAD_DATA":
            row["fields"] = {"reason": getattr(msg, "reason", "")}
        else:
            row["fields"] = _fields(msg)
        self.write(row)
        if kind == "TIMESYNC" and msg.tc1 == 0:
            self.conn.mav.send(M.MAVLink_timesync_message(self.boot_ns(), msg.ts1))
        elif kind == "COMMAND_LONG" and msg.target_system in (0, self.args.sysid) and msg.target_component in (
            0, self.args.compid
        ):
            self.on_command(msg)

    def on_command(self, msg):
        result = M.MAV_RESULT_UNSUPPORTED
        if msg.command == M.MAV_CMD_SET_MESSAGE_INTERVAL and int(msg.param1) == M.MAVLINK_MSG_ID_ATTITUDE:
            result = M.MAV_RESULT_ACCEPTED
            if msg.param2 < 0:
                self.attitude_period_ns = 0
            else:
                self.attitude_period_ns = int(msg.param2 * 1000) if msg.param2 > 0 else 100_000_000
            self.next_attitude_ns = 0
        elif msg.command == M.MAV_CMD_SET_MESSAGE_INTERVAL and int(msg.param1) == M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            result = M.MAV_RESULT_ACCEPTED
            self.position_period_ns = 0 if msg.param2 < 0 else int(msg.param2 * 1000) if msg.param2 > 0 else 200_000_000
            self.next_position_ns = 0
        ack = M.MAVLink_command_ack_message(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        self.conn.mav.send(ack)

    def tick(self, now_ns):
        if now_ns >= self.next_heartbeat_ns:
            self.conn.mav.send(M.MAVLink_heartbeat_message(
                M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                0, M.MAV_STATE_STANDBY, 3))
            self.next_heartbeat_ns = now_ns + 1_000_000_000
        if self.attitude_period_ns and now_ns >= self.next_attitude_ns:
            boot_ms = (now_ns - self.start_ns) // 1_000_000
            roll, pitch, yaw = self.attitude_of(boot_ms / 1000.0)
            self.conn.mav.send(M.MAVLink_attitude_message(boot_ms, roll, pitch, yaw, 0.0, 0.0, 0.0))
            self.next_attitude_ns = max(self.next_attitude_ns + self.attitude_period_ns, now_ns)
        if self.position_period_ns and now_ns >= self.next_position_ns:
            boot_ms = (now_ns - self.start_ns) // 1_000_000
            n, e, d = self.position_of(boot_ms / 1000.0)
            lat = HOME[0] + math.degrees(n / EARTH_RADIUS_M)
            lon = HOME[1] + math.degrees(e / (EARTH_RADIUS_M * math.cos(math.radians(HOME[0]))))
            alt = HOME[2] - d
            self.conn.mav.send(M.MAVLink_global_position_int_message(
                boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)), int(round(-d * 1000)),
                0, 0, 0, 65535))
            self.next_position_ns = max(self.next_position_ns + self.position_period_ns, now_ns)
        elapsed_s = (now_ns - self.start_ns) / 1e9
        while self.pending and self.pending[0][0] <= elapsed_s:
            self.gcs_send(self.pending.pop(0)[1])

    def run(self):
        deadline_ns = self.start_ns + int(self.args.duration * 1e9) if self.args.duration > 0 else None
        stdin_open = self.args.stdin_control
        stdin_buf = b""
        while deadline_ns is None or time.monotonic_ns() < deadline_ns:
            fd = self.conn.fd  # tcpin: changes from the listening socket to the accepted one
            readable, _, _ = select.select([fd, sys.stdin] if stdin_open else [fd], [], [], 0.002)
            if sys.stdin in readable:
                # os.read, not readline: lines left in a file object's buffer would wait for the next select
                data = os.read(sys.stdin.fileno(), 65536)
                if not data:
                    stdin_open = False
                stdin_buf += data
                *lines, stdin_buf = stdin_buf.split(b"\n")
                for line in lines:
                    if line.strip():
                        self.gcs_send(line.decode())
            if fd in readable:
                while True:
                    msg = self.conn.recv_msg()
                    if msg is None:
                        break
                    self.on_message(msg)
            self.tick(time.monotonic_ns())


def _fields(msg):
    d = msg.to_dict()
    d.pop("mavpackettype", None)
    return d


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--listen", default="udpin:127.0.0.1:14550", help="pymavlink connection string")
    p.add_argument("--record", default=None, help="JSON-lines file for every received message")
    p.add_argument("--duration", type=float, default=0.0, help="seconds to run; 0 = until killed")
    p.add_argument("--sysid", type=int, default=1)
    p.add_argument("--compid", type=int, default=1)
    p.add_argument("--attitude-hz", type=float, default=0.0, help="stream ATTITUDE from the start (0 = only when asked)")
    p.add_argument("--command-at", action="append", default=[], metavar="T:ACTION",
                   help="send a command T seconds after start, e.g. 5:disable, 6:enable,sysid=42, 7:31011")
    p.add_argument("--stdin-control", action="store_true", help="read ACTION lines from stdin")
    p.add_argument("--gcs-sysid", type=int, default=255, help="system id the commands come from")
    p.add_argument("--target-sysid", type=int, default=1, help="system id the commands go to")
    p.add_argument("--target-compid", type=int, default=100, help="component id the commands go to")
    p.add_argument("--signing-key", default=None, help="MAVLink 2 signing key file")
    if _scene_class() is not None:
        p.add_argument("--scene-seed", type=int, default=None,
                       help="ATTITUDE = the camera motion of the synthetic scene with this seed")
        p.add_argument("--scene-fps", type=float, default=30.0, help="frame rate of that scene")
    args = p.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    fake = FakeAutopilot(args)
    try:
        fake.run()
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())

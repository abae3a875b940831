"""The MAVLink connection to the autopilot (bytes in and out: ``payload.mavlink.transport``).

``MavlinkLink(cfg)`` owns one background thread that opens the connection (retrying with
back-off), receives, sends our HEARTBEAT, keeps time in sync with the autopilot, asks for
its ATTITUDE stream and answers commands. The caller (the frame step) only calls
``send_message`` / ``attitude_at`` / ``time_usec_for`` and reads ``status``; none of them
blocks or raises when the link or the autopilot is gone (sends are counted as dropped), and
none waits on the connection: ``send_message`` puts the message in the link's outbox
(``payload.mavlink.outbox``), which the link thread writes, so a slow or blocked socket, serial
port or TCP peer stalls the link thread only. The link thread takes its lock per received
message, never while writing.

Autopilot: the first HEARTBEAT with ``autopilot != MAV_AUTOPILOT_INVALID`` from our own
system id (``mavlink.system_id``). Lost after ``autopilot_timeout_s`` without one (logged
once); found again when heartbeats come back, and then ATTITUDE is requested again.

Time: the autopilot's clock against ours (``payload.mavlink.clock``), from TIMESYNC round trips
the link sends at 1 Hz (or, without answers, the ``time_boot_ms`` of what arrives);
``time_usec_for`` uses it. Attitude and position at a capture time: ``payload.mavlink.attitude``
keeps the samples, ``attitude_at`` / ``position_at`` interpolate them.

Commands (COMMAND_LONG addressed to our system id and component id, or broadcast 0), only
from a system id in ``mavlink.command_sysids``; others are ignored and logged:

- ``MAV_CMD_USER_1`` (31010), ``param1 = 1``: enable detection -> ACK ACCEPTED
- ``MAV_CMD_USER_1`` (31010), ``param1 = 0``: disable detection -> ACK ACCEPTED
  (other param1 values -> ACK DENIED)
- commands taken by a handler added with ``add_command_handler`` (the camera protocol,
  ``payload.mavlink.camera``) are answered there;
- any other command addressed to our component -> ACK UNSUPPORTED. Broadcast commands
  (target_component 0) we do not handle get no ACK, so that we never answer for the
  autopilot.

Signing (``mavlink.signing``): outgoing messages are signed; unsigned or wrongly signed
incoming messages are dropped (counted in ``status.rejected``), except RADIO_STATUS from
telemetry radios, which cannot sign. The signature is verified before any stream state is
touched, and the timestamps are kept across restarts (``payload.mavlink.signing``).

Input guards: a message with a NaN or infinite field (or an ATTITUDE angle beyond 4 pi) is
dropped at the door (``status.nonfinite``); ``udpin:`` talks only to the address the autopilot's
heartbeats come from and, while the autopilot lives, ignores other senders (``status.foreign``);
rejected and ignored input is logged at most once per source per 10 s, with counts.

Position: with ``position_rate_hz`` set (by the service, when geo outputs need it) the link asks
the autopilot for GLOBAL_POSITION_INT like ATTITUDE, and ``position_at`` interpolates it at a
frame's capture time. Samples without a fix (lat = lon = 0) or out of range are not kept.

Reload: ``apply(new_cfg)`` applies the live keys (``LIVE_KEYS``) and says which.
"""

import logging
import math
import select
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, List, Optional, Tuple

# The connection check and the key reading live in the config layer, so that check-config runs them too.
from payload.config import MavlinkConfig, flat_config, load_signing_key, section_changes  # noqa: F401  (load_signing_key re-exported)
from payload.config import check_connection as _check_connection
from payload.geometry import Attitude, Position
from payload.mavlink.attitude import PoseBuffer
from payload.mavlink.clock import AutopilotClock
from payload.mavlink.outbox import Outbox
from payload.mavlink.ratelog import RateLimitedLog
from payload.mavlink.signing import SigningState, default_state_path
from payload.mavlink.transport import SendDropped, UdpTransport, open_transport
from payload.mavlink.transport import mavlink as _M

log = logging.getLogger(__name__)

_CMD_DETECTION = _M.MAV_CMD_USER_1
_ATTITUDE_RETRY_S = 1.5
_ATTITUDE_MAX_TRIES = 5
_TIMESYNC_PERIOD_S = 1.0
_ANGLE_MAX = 4 * math.pi  # |roll|, |pitch|, |yaw| beyond this is not an attitude
_SIGNING_LINK_ID = 0
#: MAVLink extension fields newer than some pymavlink releases still in use; sent only where known.
_NEWER_EXTENSIONS = ("camera_device_id", "gimbal_device_id", "encoding")  # absent from pymavlink 2.4.38 (the floor)
#: mavlink.* keys that ``MavlinkLink.apply`` changes on a running link; the others need a restart.
LIVE_KEYS = (
    "command_sysids", "heartbeat_hz", "autopilot_timeout_s", "attitude_rate_hz", "timesync",
    "retry.initial_s", "retry.max_s",
)
_KEPT_KEYS = ("enabled", "connection", "baud", "system_id", "component_id", "component_type", "signing")


def constant(name: str, default: Optional[int] = None) -> int:
    """A MAVLink enum value by name (e.g. ``CAMERA_TRACKING_MODE_RECTANGLE``) from the loaded dialect."""
    value = getattr(_M, name, default)
    if value is None:
        raise KeyError(f"MAVLink constant {name} is not in this pymavlink dialect")
    return int(value)


@dataclass(frozen=True)
class LinkStatus:
    """A snapshot of the link, for logs and the service's health summary."""

    connected: bool  # the transport (serial port / socket) is open
    autopilot_seen: bool  # an autopilot heartbeat arrived within autopilot_timeout_s
    autopilot_age_s: Optional[float]  # seconds since its last heartbeat; None = never heard
    sent: int  # messages handed to the transport
    dropped: int  # send calls that could not be sent (no connection, no peer yet, write error)
    detection_enabled: bool
    attitude_age_s: Optional[float]  # seconds since the last ATTITUDE; None = none yet
    time_offset_ns: Optional[int]  # autopilot boot time - our monotonic time; None = unknown
    time_synced: bool  # offset from TIMESYNC round trips (False: coarse or none)
    rejected: int  # incoming messages dropped for a missing/bad signature
    commands_ignored: int  # COMMAND_LONGs from system ids not in command_sysids
    connect_failures: int  # failed attempts to open the connection (retried with back-off)
    nonfinite: int = 0  # incoming messages dropped for a NaN/inf field (or an attitude angle beyond 4 pi)
    foreign: int = 0  # udpin datagrams dropped for coming from another address than the autopilot's


class MavlinkLink:
    """One MAVLink connection run by a background thread; see the module doc for the protocol."""

    def __init__(self, cfg: MavlinkConfig):
        _check_connection(cfg.connection)
        self.cfg = cfg
        self._key = load_signing_key(cfg.signing.key_file) if cfg.signing.enabled and cfg.signing.key_file else None
        self._signing_state: Optional[SigningState] = None
        if self._key is not None:
            self._signing_state = SigningState(default_state_path(cfg.signing.key_file))
            self._signing_state.load()
        self._lock = threading.RLock()
        self._count_lock = threading.Lock()  # sent/dropped: counted by the link thread and by callers
        self._outbox = Outbox()
        #: called on the link thread with the outbox sequence number of each message written or dropped
        #: there (the benchmark times a frame's messages to the socket with it)
        self.on_written: Optional[Callable[[int], None]] = None
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._conn: Any = None
        self._broken = False
        self._sent = 0
        self._dropped = 0
        self._rejected_before = 0  # from connections already closed
        self._commands_ignored = 0
        self._connect_failures = 0
        self._nonfinite = 0
        self._foreign_before = 0  # from connections already closed
        self._foreign_seen = 0
        self._detection_enabled = True
        # rejected / ignored input: counted always, logged at most once per source per interval
        self._log_ignored = RateLimitedLog(log, "ignored commands")
        self._log_other_ap = RateLimitedLog(log, "ignored autopilot heartbeats")
        self._log_rejected = RateLimitedLog(log, "rejected packets")
        self._log_foreign = RateLimitedLog(log, "ignored datagrams")
        self._ratelogs = (self._log_ignored, self._log_other_ap, self._log_rejected, self._log_foreign)
        # autopilot
        self._ap_id: Optional[Tuple[int, int]] = None
        self._ap_alive = False
        self._ap_last_ns: Optional[int] = None
        self._att_requests = 0
        self._att_next_request_ns = 0
        self._att_acked = False
        # ATTITUDE and GLOBAL_POSITION_INT (asked for at position_rate_hz) in the autopilot's time base
        self.poses = PoseBuffer()
        self._att_last_rx_ns: Optional[int] = None
        self.position_rate_hz = 0.0
        self._pos_requests = 0
        self._pos_next_request_ns = 0
        self._pos_pending_until_ns = 0  # an ACK before this answers our position request
        self._command_handlers: List[Callable[[Any], bool]] = []
        self.clock = AutopilotClock()
        self._next_hb_ns = 0
        self._next_ts_ns = 0

    # --- public API --------------------------------------------------------------------------

    def start(self) -> None:
        """Start the background thread; returns at once (the connection is opened there)."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._outbox.open()
        self._thread = threading.Thread(target=self._run, name="mavlink-link", daemon=True)
        self._thread.start()
        log.info(
            "mavlink link starting: connection=%s sysid=%d compid=%d type=%s signing=%s",
            self.cfg.connection, self.cfg.system_id, self.cfg.component_id, self.cfg.component_type,
            "on" if self._key else "off",
        )

    def stop(self) -> None:
        """Stop the thread and close the connection; safe to call twice."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        with self._lock:
            self._close()
            if self._signing_state is not None:
                self._signing_state.save()
        self._outbox.close()

    def __enter__(self) -> "MavlinkLink":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def detection_enabled(self) -> bool:
        """False after a disable command (MAV_CMD_USER_1 param1=0) until an enable command."""
        return self._detection_enabled

    @property
    def status(self) -> LinkStatus:
        now = time.monotonic_ns()
        with self._lock:
            offset, synced = self.clock.offset()
            rejected = self._rejected_before
            foreign = self._foreign_before
            if self._conn is not None:
                rejected += self._conn.mav.signing.reject_count
                foreign += getattr(self._conn, "foreign", 0)
            return LinkStatus(
                connected=self._conn is not None,
                autopilot_seen=self._ap_alive,
                autopilot_age_s=None if self._ap_last_ns is None else (now - self._ap_last_ns) / 1e9,
                sent=self._sent,
                dropped=self._dropped + self._outbox.overflow,
                detection_enabled=self._detection_enabled,
                attitude_age_s=None if self._att_last_rx_ns is None else (now - self._att_last_rx_ns) / 1e9,
                time_offset_ns=offset,
                time_synced=synced,
                rejected=rejected,
                commands_ignored=self._commands_ignored,
                connect_failures=self._connect_failures,
                nonfinite=self._nonfinite,
                foreign=foreign,
            )

    def publishing(self) -> Any:
        """Hold while one frame's target messages are queued (``with link.publishing(): ...``): a
        command that disables detection is then handled, and its ACK queued, before or after them,
        never in between; the outbox keeps that order, so nothing about the target follows the ACK.
        (The link thread handles each received message under the same lock, and writes without it.)"""
        return self._lock

    def apply(self, cfg: MavlinkConfig) -> List[str]:
        """Apply the live-changeable keys of a reloaded ``mavlink`` section (LIVE_KEYS) to the
        running link; returns the dotted keys that changed and were applied (``mavlink.heartbeat_hz``...).
        Keys that need a restart (connection, baud, ids, component_type, signing) keep their
        running values here, whatever ``cfg`` says; ``outputs`` belongs to the publisher."""
        old = self.cfg
        live = {"mavlink." + k for k in LIVE_KEYS}
        changed = [k for k in section_changes(old, cfg, "mavlink") if k in live]
        restart_only = {k: getattr(old, k) for k in _KEPT_KEYS}
        with self._lock:
            self.cfg = cfg.model_copy(update=restart_only)
            if "mavlink.heartbeat_hz" in changed:
                self._next_hb_ns = 0  # the next one goes now, then at the new rate
            if "mavlink.attitude_rate_hz" in changed:
                # ask again at the new rate (0: stop asking; the autopilot's own stream setting stays),
                # now: an ATTITUDE of the old stream arriving first would count as the answer
                self._att_requests = 0
                self._att_acked = False
                self._att_next_request_ns = 0
                if self._ap_alive and self.cfg.attitude_rate_hz > 0:
                    self._request_attitude(time.monotonic_ns())
            if "mavlink.timesync" in changed:
                self.clock.forget_requests()
                self._next_ts_ns = 0
        if changed:
            values = flat_config(cfg, "mavlink")
            log.info("mavlink link applied: %s", ", ".join("%s=%s" % (k[len("mavlink."):], values[k]) for k in changed))
        return changed

    def send_message(self, msg_type: str, /, src_system: Optional[int] = None, **fields: Any) -> bool:
        """Send one MAVLink message by name, e.g. ``send_message("DEBUG_VECT", name=b"TGT_BRG", ...)``,
        from our system id or, with ``src_system``, from another (FOLLOW_TARGET: ArduPilot follows
        only another system than itself).

        Never blocks or raises on a dead link: returns False and counts a drop instead. True means
        queued: the link thread writes it (a write that then fails is counted as dropped there).
        """
        cls = getattr(_M, f"MAVLink_{msg_type.lower()}_message")
        for name in _NEWER_EXTENSIONS:
            if name in fields and name not in cls.fieldnames:
                del fields[name]  # an older pymavlink (the Jetson's) lacks it; 0 means "not used" anyway
        return self._send(cls(**fields), src_system)

    @property
    def last_queued(self) -> int:
        """The outbox sequence number of the last message queued (compare with ``on_written``)."""
        return self._outbox.last_seq

    def time_usec_for(self, t_monotonic_ns: int) -> int:
        """A time on our monotonic clock as autopilot time (us since its boot) when known, else our us."""
        return self.clock.usec_for(t_monotonic_ns)

    def attitude_at(self, t_monotonic_ns: int) -> Optional[Attitude]:
        """The vehicle attitude at a frame's capture time, interpolated from recent ATTITUDE messages.

        None without a time offset, without samples, or when the time is more than 100 ms outside
        the buffered samples (stale or future). Yaw is unwrapped before interpolating.
        """
        offset, _ = self.clock.offset()
        return None if offset is None else self.poses.attitude_at(int(t_monotonic_ns) + offset)

    def position_at(self, t_monotonic_ns: int) -> Optional[Position]:
        """The vehicle position at a frame's capture time, interpolated from recent GLOBAL_POSITION_INT.

        None without a time offset, without samples, or when the time is more than 300 ms outside
        the buffered samples."""
        offset, _ = self.clock.offset()
        return None if offset is None else self.poses.position_at(int(t_monotonic_ns) + offset)

    def add_command_handler(self, handler: Callable[[Any], bool]) -> None:
        """``handler(command_long)`` is offered each COMMAND_LONG addressed to our component from an
        allowed system id (signing and sysid checks done); it returns True when it handled (and
        acknowledged) the command. It runs on the link thread, under the link's lock."""
        self._command_handlers.append(handler)

    def ack(self, command: int, result: int, to: Tuple[int, int], progress: int = 0) -> bool:
        """Send COMMAND_ACK for ``command`` to (sysid, compid); safe from any thread."""
        return self._send(_M.MAVLink_command_ack_message(command, result, progress, 0, to[0], to[1]))

    # --- sending -----------------------------------------------------------------------------

    def _send(self, msg: Any, src_system: Optional[int] = None) -> bool:
        """Queue ``msg`` for the link thread (any thread); False, and a drop counted, when there is
        no connection or peer to send it to now."""
        conn = self._conn
        if conn is None or self._broken or not conn.can_send():
            with self._count_lock:
                self._dropped += 1
            return False
        self._outbox.put(msg, src_system)
        return True

    def _flush(self) -> None:
        """Write what the outbox holds, oldest first (the link thread only, without the lock)."""
        if not len(self._outbox):
            return
        for seq, msg, src_system in self._outbox.take():
            self._write(msg, src_system)
            if self.on_written is not None:
                self.on_written(seq)

    def _write(self, msg: Any, src_system: Optional[int]) -> None:
        conn = self._conn
        ok = False
        if conn is not None and not self._broken and conn.can_send():
            own = conn.mav.srcSystem
            try:
                if src_system is not None:
                    conn.mav.srcSystem = src_system
                conn.mav.send(msg)
                ok = True
            except SendDropped:
                pass
            except (OSError, ConnectionError) as exc:
                self._broken = True
                log.warning("mavlink write failed: connection=%s error=%s", self.cfg.connection, exc)
            finally:
                conn.mav.srcSystem = own
        with self._count_lock:
            if ok:
                self._sent += 1
            else:
                self._dropped += 1

    def _send_heartbeat(self) -> None:
        if self.cfg.component_type == "camera":
            mav_type = _M.MAV_TYPE_CAMERA
        else:
            mav_type = _M.MAV_TYPE_ONBOARD_CONTROLLER
        state = _M.MAV_STATE_ACTIVE if self._detection_enabled else _M.MAV_STATE_STANDBY
        self._send(_M.MAVLink_heartbeat_message(mav_type, _M.MAV_AUTOPILOT_INVALID, 0, 0, state, 3))

    def _ack(self, msg: Any, result: int) -> None:
        self._send(
            _M.MAVLink_command_ack_message(
                msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )
        )

    def _request_position(self, now_ns: int) -> None:
        sysid, compid = self._ap_id  # type: ignore[misc]
        self._send(
            _M.MAVLink_command_long_message(
                sysid, compid, _M.MAV_CMD_SET_MESSAGE_INTERVAL, self._pos_requests,
                _M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 1e6 / self.position_rate_hz, 0, 0, 0, 0, 0,
            )
        )
        self._pos_requests += 1
        self._pos_next_request_ns = now_ns + int(_ATTITUDE_RETRY_S * 1e9)
        self._pos_pending_until_ns = self._pos_next_request_ns
        log.info("requested GLOBAL_POSITION_INT: rate_hz=%.1f try=%d", self.position_rate_hz, self._pos_requests)

    def _request_attitude(self, now_ns: int) -> None:
        sysid, compid = self._ap_id  # type: ignore[misc]
        interval_us = 1e6 / self.cfg.attitude_rate_hz
        self._send(
            _M.MAVLink_command_long_message(
                sysid, compid, _M.MAV_CMD_SET_MESSAGE_INTERVAL, self._att_requests,
                _M.MAVLINK_MSG_ID_ATTITUDE, interval_us, 0, 0, 0, 0, 0,
            )
        )
        self._att_requests += 1
        self._att_next_request_ns = now_ns + int(_ATTITUDE_RETRY_S * 1e9)
        self._pos_pending_until_ns = 0  # the next SET_MESSAGE_INTERVAL ACK answers this request
        log.info("requested ATTITUDE: rate_hz=%.1f try=%d", self.cfg.attitude_rate_hz, self._att_requests)

    # --- the thread ----------------------------------------------------------------------------

    def _run(self) -> None:
        backoff_s = self.cfg.retry.initial_s
        failing = False
        while not self._stop.is_set():
            if self._conn is None:
                try:
                    conn = self._open()
                except (OSError, ConnectionError, ValueError) as exc:
                    self._connect_failures += 1
                    if not failing:
                        log.warning(
                            "mavlink connect failed, retrying: connection=%s error=%s", self.cfg.connection, exc
                        )
                    failing = True
                    self._stop.wait(backoff_s)
                    backoff_s = min(backoff_s * 2, self.cfg.retry.max_s)
                    continue
                with self._lock:
                    self._conn = conn
                    self._broken = False
                log.info("mavlink connected: connection=%s", self.cfg.connection)
                failing = False
                backoff_s = self.cfg.retry.initial_s
            try:
                self._step()
            except (OSError, ConnectionError) as exc:
                log.warning("mavlink connection lost, reconnecting: connection=%s error=%s", self.cfg.connection, exc)
                with self._lock:
                    self._close()
                self._stop.wait(backoff_s)
            except Exception as exc:  # the link must outlive one malformed message or a bug
                log.error("mavlink thread error, reopening: error=%r", exc, exc_info=True)
                with self._lock:
                    self._close()
                self._stop.wait(backoff_s)
            if self._broken:
                with self._lock:
                    self._close()
        if self._conn is not None:
            self._flush()  # what was queued before the stop (an ACK at shutdown) still goes out

    def _open(self) -> Any:
        conn = open_transport(self.cfg.connection, self.cfg.baud, self.cfg.system_id, self.cfg.component_id)
        if self._key is not None:
            conn.setup_signing(self._key, _SIGNING_LINK_ID, _allow_unsigned)
            self._signing_state.apply_to(conn.mav.signing)
        return conn

    def _close(self) -> None:
        if self._conn is not None:
            self._rejected_before += self._conn.mav.signing.reject_count
            self._foreign_before += getattr(self._conn, "foreign", 0)
            self._foreign_seen = 0
            if self._signing_state is not None:
                self._signing_state.update_from(self._conn.mav.signing)
            try:
                self._conn.close()
            except OSError:
                pass
            self._conn = None
            log.info("mavlink connection closed: connection=%s", self.cfg.connection)

    def _step(self) -> None:
        conn = self._conn
        wake = self._outbox.fd
        readable, _, _ = select.select([conn.fd] if wake is None else [conn.fd, wake], [], [], 0.02)
        if wake is not None and wake in readable:
            self._outbox.clear_wake()
        self._flush()
        if conn.fd in readable:
            # bounded per call (64 datagrams or 4 KiB), so periodic work keeps its schedule under a flood;
            # the lock is taken per message, so a frame queuing its messages waits for one at most
            for source, msg in conn.recv_msgs():
                if msg.get_type() == "BAD_DATA":  # garbage touches nothing other threads read: no lock
                    self._bad_data(msg)
                    continue
                with self._lock:
                    self._handle(msg, source)
            with self._lock:
                self._note_foreign(conn)
        with self._lock:
            self._periodic(time.monotonic_ns())
        self._flush()

    def _note_foreign(self, conn: Any) -> None:
        foreign = getattr(conn, "foreign", 0)
        if foreign > self._foreign_seen:
            addr = conn.last_source
            self._log_foreign(
                addr, "ignoring datagrams from %s:%d: not the autopilot's address %s (%d so far)",
                addr[0], addr[1], "%s:%d" % conn.peer if conn.peer else "-", foreign,
            )
            self._foreign_seen = foreign

    def _periodic(self, now_ns: int) -> None:
        if now_ns >= self._next_hb_ns:
            self._send_heartbeat()
            self._next_hb_ns = now_ns + int(1e9 / self.cfg.heartbeat_hz)
        for ratelog in self._ratelogs:
            ratelog.flush(now_ns)
        if self._signing_state is not None and self._conn is not None:
            self._signing_state.save(self._conn.mav.signing, force=False)
        if self._ap_alive and now_ns - self._ap_last_ns > self.cfg.autopilot_timeout_s * 1e9:
            self._ap_alive = False
            if isinstance(self._conn, UdpTransport):
                self._conn.exclusive = False  # hear whoever brings the autopilot back; send to the old peer till then
            log.warning(
                "autopilot lost: sysid=%d compid=%d silent_s=%.1f (detection continues)",
                self._ap_id[0], self._ap_id[1], (now_ns - self._ap_last_ns) / 1e9,
            )
        if not self._ap_alive:
            return
        if self.cfg.timesync and now_ns >= self._next_ts_ns:
            self._send(_M.MAVLink_timesync_message(0, self.clock.request(now_ns)))
            self._next_ts_ns = now_ns + int(_TIMESYNC_PERIOD_S * 1e9)
        if (
            self.cfg.attitude_rate_hz > 0
            and not self._att_acked
            and self._att_requests < _ATTITUDE_MAX_TRIES
            and now_ns >= self._att_next_request_ns
        ):
            self._request_attitude(now_ns)
        elif (
            self.position_rate_hz > 0
            and (self._att_acked or self.cfg.attitude_rate_hz <= 0 or self._att_requests >= _ATTITUDE_MAX_TRIES)
            and not self.poses.has_position
            and self._pos_requests < _ATTITUDE_MAX_TRIES
            and now_ns >= self._pos_next_request_ns
        ):
            # after ATTITUDE's request is answered: an ACK does not say which request it answers
            self._request_position(now_ns)

    # --- receiving -----------------------------------------------------------------------------

    def _handle(self, msg: Any, source: Any = None) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self._bad_data(msg)
            return
        if not _finite(msg):
            self._nonfinite += 1
            self._log_rejected(
                ("nonfinite", msg.get_srcSystem()), "rejected %s from sysid=%d compid=%d: NaN, inf or out-of-range field",
                kind, msg.get_srcSystem(), msg.get_srcComponent(),
            )
            return
        now_ns = time.monotonic_ns()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "HEARTBEAT":
            self._on_heartbeat(msg, src, now_ns, source)
        elif kind == "COMMAND_LONG":
            self._on_command(msg)
        elif src != self._ap_id:
            if kind == "TIMESYNC" and msg.tc1 == 0:
                self._send(_M.MAVLink_timesync_message(now_ns, msg.ts1))  # answer whoever asks
            return
        elif kind == "ATTITUDE":
            t_boot_ns = int(msg.time_boot_ms) * 1_000_000
            if not self.poses.add_attitude(t_boot_ns, msg.roll, msg.pitch, msg.yaw):
                return
            self._att_last_rx_ns = now_ns
            self.clock.on_boot_time(t_boot_ns, now_ns)
            self._att_acked = True  # it streams: no need to ask again
        elif kind == "GLOBAL_POSITION_INT":
            self._on_position(msg, now_ns)
        elif kind == "SYSTEM_TIME":
            self.clock.on_boot_time(int(msg.time_boot_ms) * 1_000_000, now_ns)
        elif kind == "TIMESYNC":
            self._on_timesync(msg, now_ns)
        elif kind == "COMMAND_ACK" and msg.command == _M.MAV_CMD_SET_MESSAGE_INTERVAL and now_ns < self._pos_pending_until_ns:
            self._pos_pending_until_ns = 0
            if msg.result != _M.MAV_RESULT_ACCEPTED:
                log.warning("GLOBAL_POSITION_INT request refused: result=%d (no geo outputs)", msg.result)
                self._pos_requests = _ATTITUDE_MAX_TRIES  # refused: do not insist
        elif kind == "COMMAND_ACK" and msg.command == _M.MAV_CMD_SET_MESSAGE_INTERVAL:
            self._att_acked = msg.result == _M.MAV_RESULT_ACCEPTED
            level = logging.INFO if self._att_acked else logging.WARNING
            log.log(level, "ATTITUDE request answered: result=%d", msg.result)
            if not self._att_acked:
                self._att_requests = _ATTITUDE_MAX_TRIES  # refused: do not insist

    def _bad_data(self, msg: Any) -> None:
        if msg.reason == "Invalid signature":
            data = bytes(msg.get_msgbuf())
            sysid = data[5] if len(data) > 5 and data[0] == _M.PROTOCOL_MARKER_V2 else -1
            self._log_rejected(sysid, "rejected packet from sysid=%d: missing or bad signature", sysid)

    def _on_heartbeat(self, msg: Any, src: Tuple[int, int], now_ns: int, source: Any) -> None:
        if msg.autopilot == _M.MAV_AUTOPILOT_INVALID:
            return  # a GCS, camera, companion computer...
        if src[0] != self.cfg.system_id:
            self._log_other_ap(
                src[0], "ignoring autopilot heartbeat: sysid=%d compid=%d, expected mavlink.system_id=%d",
                src[0], src[1], self.cfg.system_id,
            )
            return
        if self._ap_id is not None and src != self._ap_id and self._ap_alive:
            return  # a second autopilot component: stay with the first while it lives
        self._ap_last_ns = now_ns
        conn = self._conn
        if isinstance(conn, UdpTransport) and conn.listen and source is not None:
            # udpin: the autopilot's (or its router's) address becomes our only destination and,
            # while the autopilot lives, the only source we listen to
            if conn.peer != source:
                log.info("udpin: talking to %s:%d, the autopilot's address", source[0], source[1])
            conn.peer = source
            conn.exclusive = True
        if not self._ap_alive:
            first = self._ap_id is None
            self._ap_id = src
            self._ap_alive = True
            # a returning autopilot may have rebooted: forget its clock and attitude
            self.clock.reset()
            self.poses.clear()
            self._pos_requests = 0
            self._pos_next_request_ns = 0
            self._att_requests = 0
            self._att_acked = False
            self._att_next_request_ns = 0
            self._next_ts_ns = 0
            log.info(
                "autopilot %s: sysid=%d compid=%d autopilot=%d type=%d",
                "found" if first else "back", src[0], src[1], msg.autopilot, msg.type,
            )
            self._periodic(now_ns)

    def _on_position(self, msg: Any, now_ns: int) -> None:
        lat, lon = msg.lat / 1e7, msg.lon / 1e7
        if (msg.lat == 0 and msg.lon == 0) or abs(lat) > 90 or abs(lon) > 180:
            return  # no fix yet, or not a position
        t_boot_ns = int(msg.time_boot_ms) * 1_000_000
        if self.poses.add_position(t_boot_ns, lat, lon, msg.alt / 1000.0):
            self.clock.on_boot_time(t_boot_ns, now_ns)

    def _on_timesync(self, msg: Any, now_ns: int) -> None:
        if msg.tc1 == 0:
            self._send(_M.MAVLink_timesync_message(now_ns, msg.ts1))
            return
        self.clock.on_answer(msg.tc1, msg.ts1, now_ns)

    def _on_command(self, msg: Any) -> None:
        if msg.target_system not in (0, self.cfg.system_id):
            return
        if msg.target_component not in (0, self.cfg.component_id):
            return
        src_sys = msg.get_srcSystem()
        if src_sys not in self.cfg.command_sysids:
            self._commands_ignored += 1
            self._log_ignored(
                src_sys, "ignoring command from sysid=%d command=%d: not in mavlink.command_sysids=%s",
                src_sys, msg.command, list(self.cfg.command_sysids),
            )
            return
        if self._signing_state is not None and self._conn is not None:
            # before acting on it: after a crash or restart this command cannot be replayed
            self._signing_state.save(self._conn.mav.signing)
        if msg.command == _CMD_DETECTION:
            if msg.param1 in (0.0, 1.0):
                self._detection_enabled = msg.param1 == 1.0
                log.info(
                    "detection %s by command: sysid=%d compid=%d",
                    "enabled" if self._detection_enabled else "disabled", src_sys, msg.get_srcComponent(),
                )
                self._ack(msg, _M.MAV_RESULT_ACCEPTED)
                self._send_heartbeat()  # the state shows in system_status at once
            else:
                self._ack(msg, _M.MAV_RESULT_DENIED)
        elif msg.target_component != 0 and any(handler(msg) for handler in self._command_handlers):
            pass
        elif msg.target_component != 0:
            self._ack(msg, _M.MAV_RESULT_UNSUPPORTED)


def _allow_unsigned(_mav: Any, msg_id: int) -> bool:
    return msg_id == _M.MAVLINK_MSG_ID_RADIO_STATUS


def _finite(msg: Any) -> bool:
    """False when a float field of ``msg`` is NaN or infinite (or an ATTITUDE angle is beyond 4 pi)."""
    for name in msg.get_fieldnames():
        value = getattr(msg, name, None)
        if isinstance(value, float):
            if not math.isfinite(value):
                return False
        elif isinstance(value, list):
            if not all(math.isfinite(v) for v in value if isinstance(v, float)):
                return False
    if msg.get_type() == "ATTITUDE":
        return max(abs(msg.roll), abs(msg.pitch), abs(msg.yaw)) <= _ANGLE_MAX
    return True

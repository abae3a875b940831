"""MAVLink 2 signing rules for incoming packets, and the signing state kept across restarts.

``check_signature`` replaces pymavlink's: the hash is verified BEFORE the timestamp tables are
looked at or changed. (pymavlink records a new stream's timestamp first, so one forged packet
with the ground station's link id and timestamp 2^48-1 made every later genuine packet of that
stream "old" until a restart.) The rest follows the MAVLink signing spec: per stream
(link id, system id, component id) the timestamp must increase; a new stream may be at most
one minute behind our own timestamp, which follows the newest accepted packet.

``SigningState`` keeps our timestamp and the last timestamp of each stream in a small JSON file,
as the spec asks, so that a signed packet captured before a restart cannot be replayed after
it (the Jetson has no battery-backed clock: the wall clock alone may be behind after a boot).
The file is written atomically when a command has been accepted and every ``SAVE_PERIOD_S``.
"""

import hashlib
import hmac
import json
import logging
import os
import struct
import time
from typing import Any, Dict, Optional, Tuple

log = logging.getLogger(__name__)

_EPOCH_2015 = 1420070400  # MAVLink signing timestamps: 10 us units since 2015-01-01 00:00 UTC
_NEW_STREAM_LAG = 6000 * 1000  # a new stream may be this far (60 s) behind our timestamp
_MAX_STREAMS = 64  # only correctly signed packets add one; bounded all the same
_TS_MAX = (1 << 48) - 1
SAVE_PERIOD_S = 10.0
STATE_FILE_NAME = "mavlink-signing.json"

Stream = Tuple[int, int, int]  # (link id, system id, component id)


def wall_timestamp() -> int:
    """Now as a MAVLink signing timestamp (0 when the wall clock is before 2015)."""
    return max(0, int((time.time() - _EPOCH_2015) * 100_000))


def check_signature(signing: Any, msgbuf: bytes, src_system: int, src_component: int) -> bool:
    """True for a correctly signed, fresh packet; updates ``signing`` (pymavlink's MAVLinkSigning)
    only then. ``msgbuf`` is the whole packet including its 13-byte signature block."""
    key = signing.secret_key
    if key is None or len(msgbuf) < 13:
        return False
    digest = hashlib.sha256(bytes(key) + bytes(msgbuf[:-6])).digest()[:6]
    if not hmac.compare_digest(digest, bytes(msgbuf[-6:])):
        return False
    link_id = msgbuf[-13]
    tlow, thigh = struct.unpack("<IH", bytes(msgbuf[-12:-6]))
    timestamp = tlow + (thigh << 32)
    stream = (link_id, src_system, src_component)
    streams: Dict[Stream, int] = signing.stream_timestamps
    last = streams.get(stream)
    if last is not None:
        if timestamp <= last:
            return False  # replayed or reordered
    elif timestamp + _NEW_STREAM_LAG < signing.timestamp:
        return False  # a new stream from the past: a replay from before our newest timestamp
    streams.pop(stream, None)
    streams[stream] = timestamp  # insertion order = least recently updated first
    while len(streams) > _MAX_STREAMS:
        streams.pop(next(iter(streams)))
    signing.timestamp = max(signing.timestamp, timestamp)
    return True


def default_state_path(key_file: str) -> str:
    """Where the signing state lives: systemd's StateDirectory when set, else next to the key."""
    state_dir = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    if state_dir:
        return os.path.join(state_dir, STATE_FILE_NAME)
    return key_file + ".state"


class SigningState:
    """Our signing timestamp and the per-stream timestamps, persisted in ``path``."""

    def __init__(self, path: str):
        self.path = path
        self.timestamp = 0
        self.streams: Dict[Stream, int] = {}
        self._saved: Optional[Tuple[int, Tuple]] = None
        self._next_save = 0.0
        self._warned = False

    def load(self) -> None:
        """Read the file; a missing file is a first start, a broken one is logged and ignored."""
        try:
            with open(self.path, "rb") as fh:
                data = json.loads(fh.read(1 << 16).decode("utf-8"))
            timestamp = int(data["timestamp"])
            streams = {}
            for row in data["streams"][:_MAX_STREAMS]:
                link_id, sysid, compid, ts = (int(v) for v in row)
                streams[(link_id, sysid, compid)] = min(max(ts, 0), _TS_MAX)
        except FileNotFoundError:
            log.info("signing state: %s not found (first start): timestamps start from the wall clock", self.path)
            return
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.warning("signing state: cannot read %s (%s): timestamps start from the wall clock",
                        self.path, exc.__class__.__name__)
            return
        self.timestamp = min(max(timestamp, 0), _TS_MAX)
        self.streams = streams
        log.info("signing state: loaded %s timestamp=%d streams=%d", self.path, self.timestamp, len(streams))

    def apply_to(self, signing: Any) -> None:
        """Start a connection's signing from the saved state (never behind the wall clock)."""
        signing.timestamp = max(signing.timestamp, self.timestamp, wall_timestamp())
        for stream, ts in self.streams.items():
            signing.stream_timestamps[stream] = max(ts, signing.stream_timestamps.get(stream, 0))

    def update_from(self, signing: Any) -> None:
        self.timestamp = max(self.timestamp, int(signing.timestamp))
        self.streams.update(signing.stream_timestamps)
        while len(self.streams) > _MAX_STREAMS:
            self.streams.pop(next(iter(self.streams)))

    def save(self, signing: Optional[Any] = None, force: bool = True) -> bool:
        """Write the state atomically (temp file + rename); without ``force`` at most every
        SAVE_PERIOD_S and only when it changed. Returns True when written."""
        now = time.monotonic()
        if not force and now < self._next_save:
            return False
        self._next_save = now + SAVE_PERIOD_S
        if signing is not None:
            self.update_from(signing)
        snapshot = (self.timestamp, tuple(sorted(self.streams.items())))
        if snapshot == self._saved:
            return False
        rows = [[s[0], s[1], s[2], ts] for s, ts in snapshot[1]]
        text = json.dumps({"timestamp": self.timestamp, "streams": rows})
        tmp = self.path + ".tmp"
        try:
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
            _fsync_dir(os.path.dirname(os.path.abspath(self.path)))  # the rename itself survives a power cut
        except OSError as exc:
            if not self._warned:
                self._warned = True
                log.warning("signing state: cannot write %s: %s (replays from before a restart are then"
                            " refused only by the wall clock)", self.path, exc.strerror or exc)
            return False
        self._saved = snapshot
        return True


def _fsync_dir(path: str) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)

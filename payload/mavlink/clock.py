"""The autopilot's clock: its boot time against our monotonic clock, from TIMESYNC.

``offset_ns`` = autopilot boot time - our monotonic clock, from TIMESYNC round trips (the link
asks once a second; of the last few round trips the one with the smallest delay wins). Without
TIMESYNC answers a coarse offset comes from the ``time_boot_ms`` of received ATTITUDE,
GLOBAL_POSITION_INT and SYSTEM_TIME (biased by the link latency: arrival is always later than
sending, so the largest of them is the best bound). ``usec_for`` turns a capture time into
autopilot time (us since its boot), or our own microseconds while nothing is known.

The link thread feeds it; the frame step reads it. It has its own lock, held for microseconds,
so that reading it never waits on the link thread's work.
"""

import logging
import threading
from collections import deque
from typing import Deque, Dict, Optional, Tuple

log = logging.getLogger(__name__)

_SAMPLES = 8  # TIMESYNC round trips kept; the least-delayed wins
_COARSE = 64
_PENDING = 16  # requests awaiting an answer
_UINT64_MAX = (1 << 64) - 1


class AutopilotClock:
    """The offset between the autopilot's boot time and our monotonic clock."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pending: Dict[int, int] = {}  # ts1 we sent -> when
        self._samples: Deque[Tuple[int, int]] = deque(maxlen=_SAMPLES)  # (round trip, offset) ns
        self._coarse: Deque[int] = deque(maxlen=_COARSE)  # t_boot - arrival, ns

    def reset(self) -> None:
        """Forget everything: the autopilot came back and may have rebooted."""
        with self._lock:
            self._pending.clear()
            self._samples.clear()
            self._coarse.clear()

    def forget_requests(self) -> None:
        """Drop the requests still awaiting an answer (TIMESYNC switched off or on)."""
        with self._lock:
            self._pending.clear()

    def request(self, now_ns: int) -> int:
        """Note a TIMESYNC request sent now; returns its ts1."""
        with self._lock:
            self._pending[now_ns] = now_ns
            if len(self._pending) > _PENDING:
                self._pending.pop(min(self._pending))
        return now_ns

    def on_answer(self, tc1: int, ts1: int, now_ns: int) -> None:
        """An autopilot's answer (tc1 = its time) to our request ``ts1``, arrived at ``now_ns``."""
        with self._lock:
            sent_ns = self._pending.pop(int(ts1), None)
            if sent_ns is None:
                return
            rtt_ns = now_ns - sent_ns
            offset_ns = int(tc1) - (sent_ns + now_ns) // 2
            current, synced = self._offset()
            if synced and abs(offset_ns - current) > 50_000_000 + rtt_ns:
                log.info("autopilot clock jumped: offset_ms=%.1f -> %.1f", current / 1e6, offset_ns / 1e6)
                self._samples.clear()
            self._samples.append((rtt_ns, offset_ns))

    def on_boot_time(self, t_boot_ns: int, now_ns: int) -> None:
        """A message stamped ``t_boot_ns`` of autopilot time arrived at ``now_ns``: a coarse bound."""
        with self._lock:
            self._coarse.append(int(t_boot_ns) - now_ns)

    def offset(self) -> Tuple[Optional[int], bool]:
        """(autopilot boot time - our monotonic time in ns, or None; True when from TIMESYNC)."""
        with self._lock:
            return self._offset()

    def _offset(self) -> Tuple[Optional[int], bool]:
        if self._samples:
            return min(self._samples)[1], True
        if self._coarse:
            return max(self._coarse), False
        return None, False

    def usec_for(self, t_monotonic_ns: int) -> int:
        """A time on our monotonic clock as autopilot time (us since its boot) when known, else our us."""
        offset, _ = self.offset()
        if offset is None:
            return int(t_monotonic_ns) // 1000
        return min(max(0, (int(t_monotonic_ns) + offset) // 1000), _UINT64_MAX)

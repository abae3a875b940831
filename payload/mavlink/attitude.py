"""The vehicle's attitude and position at a frame's capture time.

ATTITUDE and GLOBAL_POSITION_INT samples are kept in the autopilot's time base (``time_boot_ms``)
as they arrive, and interpolated at a capture time already turned into that time base (the link
adds the clock's offset, payload.mavlink.clock). Attitude holds the nearest sample 100 ms
outside the buffered span, position (a few Hz) 300 ms; beyond that there is none. Yaw is
unwrapped before interpolating. A sample older than the newest is ignored, unless it is more
than a second older: the autopilot rebooted, and the buffer starts again.

The link thread adds; the frame step reads. Its own lock is held for microseconds.
"""

import bisect
import math
import threading
from collections import deque
from typing import Deque, List, Optional, Tuple

from payload.geometry import Attitude, Position

_ATTITUDE_BUFFER = 512
_ATTITUDE_HOLD_NS = 100_000_000  # nearest sample is used this far outside the buffered span
_POSITION_BUFFER = 128
_POSITION_HOLD_NS = 300_000_000  # GLOBAL_POSITION_INT comes at a few Hz: hold it a little longer
_REBOOT_NS = 1_000_000_000

Sample = Tuple[int, float, float, float]  # (t_boot_ns, three values)


class PoseBuffer:
    """Recent attitude and position samples of the vehicle, interpolated at a time."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._att: Deque[Sample] = deque(maxlen=_ATTITUDE_BUFFER)  # (t, roll, pitch, yaw)
        self._pos: Deque[Sample] = deque(maxlen=_POSITION_BUFFER)  # (t, lat_deg, lon_deg, alt_m)

    def clear(self) -> None:
        with self._lock:
            self._att.clear()
            self._pos.clear()

    def add_attitude(self, t_boot_ns: int, roll: float, pitch: float, yaw: float) -> bool:
        """Keep one ATTITUDE sample; False when it was ignored (not newer than the last)."""
        return self._add(self._att, (int(t_boot_ns), float(roll), float(pitch), float(yaw)))

    def add_position(self, t_boot_ns: int, lat_deg: float, lon_deg: float, alt_m: float) -> bool:
        """Keep one GLOBAL_POSITION_INT sample; False when it was ignored (not newer than the last)."""
        return self._add(self._pos, (int(t_boot_ns), float(lat_deg), float(lon_deg), float(alt_m)))

    def _add(self, samples: Deque[Sample], sample: Sample) -> bool:
        with self._lock:
            if samples and sample[0] <= samples[-1][0]:
                if sample[0] >= samples[-1][0] - _REBOOT_NS:
                    return False
                samples.clear()  # autopilot time went back: it rebooted
            samples.append(sample)
            return True

    @property
    def has_position(self) -> bool:
        return bool(self._pos)

    def attitudes(self) -> List[Sample]:
        with self._lock:
            return list(self._att)

    def attitude_at(self, t_boot_ns: int) -> Optional[Attitude]:
        """The attitude at autopilot time ``t_boot_ns``, or None (no sample within the hold)."""
        with self._lock:
            around = _around(self._att, int(t_boot_ns), _ATTITUDE_HOLD_NS)
        if around is None:
            return None
        (_, r0, p0, y0), (_, r1, p1, y1), a = around
        if around[0] is around[1]:
            return Attitude(r0, p0, y0)
        dyaw = math.remainder(y1 - y0, 2 * math.pi)
        yaw = math.remainder(y0 + a * dyaw, 2 * math.pi)
        return Attitude(r0 + a * (r1 - r0), p0 + a * (p1 - p0), yaw)

    def position_at(self, t_boot_ns: int) -> Optional[Position]:
        """The position at autopilot time ``t_boot_ns``, or None (no sample within the hold)."""
        with self._lock:
            around = _around(self._pos, int(t_boot_ns), _POSITION_HOLD_NS)
        if around is None:
            return None
        (_, *p0), (_, *p1), a = around
        if around[0] is around[1]:
            return Position(*p0)
        return Position(*(x0 + a * (x1 - x0) for x0, x1 in zip(p0, p1)))


def _around(samples, t: int, hold_ns: int):
    """(s0, s1, a): the time-ordered samples around time ``t`` (ns) and the weight of s1; the
    nearest one twice (a = 0) when ``t`` is outside them by at most ``hold_ns``; None beyond
    (or without samples)."""
    if not samples:
        return None
    i = bisect.bisect_left([s[0] for s in samples], t)
    if i == 0 or i == len(samples):
        nearest = samples[0] if i == 0 else samples[-1]
        return None if abs(t - nearest[0]) > hold_ns else (nearest, nearest, 0.0)
    s0, s1 = samples[i - 1], samples[i]
    return s0, s1, (t - s0[0]) / float(s1[0] - s0[0]) if s1[0] > s0[0] else 0.0

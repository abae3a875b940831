"""The soak's books: what the service did, from its decisions CSV, its log and the fake
autopilot's record, read as they grow."""

import math
from array import array
from typing import Dict, List, Optional, Tuple

from payload.soak.report import Restart

#: What the payload's publisher sends per frame.
PUBLISHED = ("CAMERA_TRACKING_IMAGE_STATUS", "DEBUG_VECT", "LANDING_TARGET")
IN_FLIGHT_S = 1.0  # frames captured this close before a kill may be sent after it: not counted


class Books:
    """What the service did, as read from its decisions CSV, its log and the autopilot's record."""

    def __init__(self) -> None:
        self.rows = 0  # decisions.csv rows
        self.last_capture_t = -math.inf  # capture time of the newest row
        self.windows: List[List[float]] = []  # [start, end] of each autopilot instance (end inf: up)
        self.restarts: List[Restart] = []
        # Capture times of the frames whose bearing (DEBUG_VECT) the payload should have sent,
        # and of the bearings the autopilot got: compared per frame once the windows are known.
        self.bearing_frames = array("d")
        self.bearings_got = array("d")
        self.bearings_unplaced = 0  # received bearings whose frame could not be told
        self.last_in_t = -math.inf  # newest message the autopilot received from us
        self.frames_logged: Optional[int] = None
        self.faults_logged: Optional[int] = None
        self.unreadable = 0  # frames the service skipped as undecodable (its summary's unreadable=)
        self.link_up_t = -math.inf  # when a summary line last said link=up
        self.tracebacks = 0
        self.log_lines: List[Tuple[float, str]] = []  # recent lines about reloads
        self.tail: List[str] = []  # the log's last lines, for a death report
        self._target_times: List[float] = []  # capture times of recent frames with a target
        self._boot_ns: List[int] = [0]  # time bases a bearing's time_usec may be in: ours, each autopilot's

    def on_record(self, row: dict) -> None:
        if row.get("type") == "START":
            t = float(row["t"])
            self.windows.append([t, math.inf])
            self._boot_ns.append(int(row.get("t_start_ns", 0)))
            for r in self.restarts:
                if r.pid == row.get("pid") and r.start_t is None:
                    r.start_t = t
                    r.t_ref = next((c for c in self._target_times if c >= t), None)
            return
        if row.get("dir") != "in":
            return
        t = float(row["t"])
        self.last_in_t = max(self.last_in_t, t)
        kind = row.get("type")
        fields = row.get("fields") or {}
        if kind == "DEBUG_VECT":
            captured = self._captured(fields.get("time_usec"), t)
            if captured is None:
                self.bearings_unplaced += 1
            else:
                self.bearings_got.append(captured)
        if kind not in PUBLISHED:
            return
        if kind == "CAMERA_TRACKING_IMAGE_STATUS" and not _finite(fields.get("point_x")):
            return  # "no target" status
        for r in self.restarts:
            if r.start_t is not None and r.first_msg_t is None and t >= r.start_t:
                r.first_msg_t = t

    def _captured(self, time_usec, received_t: float) -> Optional[float]:
        """The capture time of the frame a bearing is about: its time_usec is the capture time in
        the autopilot's clock once TIMESYNC has run (the boot of whichever autopilot it synced
        with, perhaps a killed one), else in ours. The base that puts it within 3 s before its
        arrival is the one (autopilots start seconds apart)."""
        if not isinstance(time_usec, int):
            return None
        for base in self._boot_ns:
            t = (time_usec * 1000 + base) / 1e9
            if received_t - 3.0 <= t <= received_t + 0.05:
                return t
        return None

    def on_decision(self, row: Dict[str, str]) -> None:
        self.rows += 1
        t = int(row["t_capture_ns"]) / 1e9
        self.last_capture_t = max(self.last_capture_t, t)
        if row["state"] in ("detected", "coasting"):
            if row.get("az_body_rad"):
                self.bearing_frames.append(t)
            self._target_times.append(t)
            del self._target_times[:-300]
            for r in self.restarts:
                if r.start_t is not None and r.t_ref is None and t >= r.start_t:
                    r.t_ref = t

    def bearings_lost(self) -> Tuple[int, int]:
        """(expected, received) bearings of frames captured while an autopilot listened, less
        the last IN_FLIGHT_S before each kill (those frames may be sent after it)."""
        spans = [(start, end - IN_FLIGHT_S) for start, end in self.windows]

        def inside(t: float) -> bool:
            return any(start <= t < end for start, end in spans)

        return sum(map(inside, self.bearing_frames)), sum(map(inside, self.bearings_got))

    def on_log(self, line: str, now: float) -> None:
        self.tail = (self.tail + [line])[-20:]
        if "Traceback (most recent call last)" in line:
            self.tracebacks += 1
        fields = dict(part.split("=", 1) for part in line.split() if "=" in part)
        if "frames" in fields and "fps" in fields:  # a summary line
            self.frames_logged = _int(fields["frames"], self.frames_logged)
            self.faults_logged = _int(fields.get("faults", ""), self.faults_logged)
            self.unreadable = _int(fields.get("unreadable", ""), self.unreadable)
            if fields.get("link", "").startswith("up"):
                self.link_up_t = now
        if "reload" in line.lower():
            self.log_lines = (self.log_lines + [(now, line)])[-50:]


def _finite(value) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


def _int(text: str, default: Optional[int]) -> Optional[int]:
    try:
        return int(text)
    except ValueError:
        return default

"""Log lines about rejected or ignored input, rate-limited so that input cannot flood the log.

Within each ``interval_s`` window a source (any hashable key: a system id, an address) gets at
most one line, and the window at most ``max_lines`` lines in all; everything else is counted
and summed up in one line when the window closes (``flush``, called periodically). Memory is
bounded: only the keys that got a line in the current window are remembered.
"""

import logging
import time
from typing import Any, Dict, Optional


class RateLimitedLog:
    def __init__(self, logger: logging.Logger, what: str, interval_s: float = 10.0, max_lines: int = 5,
                 level: int = logging.WARNING):
        self.logger = logger
        self.what = what  # e.g. "ignored commands"; used in the summary line
        self.interval_ns = int(interval_s * 1e9)
        self.max_lines = max_lines
        self.level = level
        self.total = 0  # events ever
        self._window_start: Optional[int] = None
        self._logged: Dict[Any, int] = {}  # key -> events in this window (only keys that got a line)
        self._suppressed = 0  # events in this window that got no line of their own

    def __call__(self, key: Any, msg: str, *args: Any) -> None:
        now = time.monotonic_ns()
        self.flush(now)
        self.total += 1
        if self._window_start is None:
            self._window_start = now
        if key in self._logged:
            self._logged[key] += 1
        elif len(self._logged) < self.max_lines:
            self._logged[key] = 1
            self.logger.log(self.level, msg, *args)
        else:
            self._suppressed += 1

    def flush(self, now_ns: Optional[int] = None) -> None:
        """Close the window if it is over: one summary line when events went unlogged."""
        now = time.monotonic_ns() if now_ns is None else now_ns
        if self._window_start is None or now - self._window_start < self.interval_ns:
            return
        repeats = sum(n - 1 for n in self._logged.values())
        if repeats or self._suppressed:
            self.logger.log(
                self.level, "%s: %d more in the last %.0f s (%d repeats from the sources above, %d from others)",
                self.what, repeats + self._suppressed, (now - self._window_start) / 1e9, repeats, self._suppressed,
            )
        self._window_start = None
        self._logged.clear()
        self._suppressed = 0

"""The soak's verdict: criteria over what was seen, and the printed report."""

import statistics
from dataclasses import dataclass
from typing import Any, List, Optional

#: Criteria (issue 20): RSS growth after the warm-up, autopilot restart to target messages.
MAX_RSS_GROWTH = 0.05
MAX_RESUME_S = 1.0
#: Open fds and threads are judged by their fewest over this many /proc samples (the plan's sample_s apart).
FLOOR_SAMPLES = 5


@dataclass
class Restart:
    pid: int  # the new autopilot's
    kill_t: float
    start_t: Optional[float] = None  # the new autopilot listens (its record's START)
    t_ref: Optional[float] = None  # capture time of the first frame with a target since then
    first_msg_t: Optional[float] = None  # the first target message it received

    @property
    def resume_s(self) -> Optional[float]:
        """From when the payload could send again (autopilot listening and a target in view) to
        the first target message received."""
        if self.start_t is None or self.first_msg_t is None:
            return None
        ref = self.start_t
        if self.t_ref is not None and self.t_ref < self.first_msg_t:
            ref = max(ref, self.t_ref)
        return max(0.0, self.first_msg_t - ref)


@dataclass
class Report:
    out: str
    plan: Any
    kinds: List[str]
    faults: List[Any]
    books: Any
    samples: List[Any]
    t0: Optional[float]
    service_rc: Optional[int]
    service_died: bool
    elapsed_s: float
    soak_cpu_s: float = 0.0

    def resources(self):
        """(start, end) after the warm-up and at the end: RSS as the median of three samples, open
        fds and threads as the fewest in five. A leak raises the floor; a file open while one
        frame is read, or a short-lived thread, lands in a sample now and then and does not (a
        median of three once counted a frame being read twice in three samples as a leaked fd)."""
        if self.t0 is None:
            return None
        after = [s for s in self.samples if s.t >= self.t0 + self.plan.warmup_s]
        if len(after) < 2 * FLOOR_SAMPLES:
            return None

        def judged(rows, rows_floor):
            out = {"rss_kb": statistics.median(s.rss_kb for s in rows)}
            out.update({k: min(getattr(s, k) for s in rows_floor) for k in ("fds", "threads")})
            return out

        return (judged(after[:3], after[:FLOOR_SAMPLES]), judged(after[-3:], after[-FLOOR_SAMPLES:]))

    def failures(self) -> List[str]:
        out = []
        if self.service_died:
            out.append("the service died (exit status %s)" % self.service_rc)
        elif self.service_rc not in (0, None):
            out.append("the service exited with status %s after SIGTERM" % self.service_rc)
        for kind in self.kinds:
            if not any(f.kind == kind for f in self.faults):
                out.append("%s: never injected (the soak is too short for the schedule)" % kind)
        for f in self.faults:
            if f.done and not f.survived:
                out.append("%s at %.1f s: %s" % (f.kind, f.t_start - (self.t0 or 0.0), f.why))
        for i, r in enumerate(self.books.restarts, 1):
            if r.resume_s is None:
                out.append("autopilot restart %d: target messages never resumed" % i)
            elif r.resume_s >= MAX_RESUME_S:
                out.append("autopilot restart %d: target messages resumed after %.2f s (limit %.1f s)"
                           % (i, r.resume_s, MAX_RESUME_S))
        res = self.resources()
        if res is None:
            out.append("too few /proc samples after the warm-up to judge RSS, fds and threads")
        else:
            start, end = res
            growth = end["rss_kb"] / start["rss_kb"] - 1.0
            if growth >= MAX_RSS_GROWTH:
                out.append("RSS grew %.1f %% after the warm-up (limit %.0f %%)" % (100 * growth, 100 * MAX_RSS_GROWTH))
            for k in ("fds", "threads"):
                if end[k] > start[k]:
                    out.append("%s not flat: %g -> %g" % (k, start[k], end[k]))
        if self.books.tracebacks:
            out.append("%d traceback(s) in the service log" % self.books.tracebacks)
        return out

    @property
    def passed(self) -> bool:
        return not self.failures()


def print_report(r: Report) -> None:
    b = r.books
    p = r.plan
    print("")
    print("glad-payload soak: %.1f min, a fault every %.0f s; outputs in %s" % (p.duration_s / 60.0, p.every_s, r.out))
    frames = b.frames_logged if b.frames_logged is not None else b.rows
    print("  frames processed     %d (%.1f fps; decisions rows %d; corrupt frames skipped %d; per-frame faults %s)"
          % (frames, b.rows / max(r.elapsed_s, 1e-6), b.rows, b.unreadable,
             "-" if b.faults_logged is None else b.faults_logged))
    parts = []
    for kind in r.kinds:
        mine = [f for f in r.faults if f.kind == kind and f.injected]
        parts.append("%s %d/%d" % (kind, sum(f.survived for f in mine), len(mine)))
    print("  faults survived      %s" % ", ".join(parts))
    expected, got = b.bearings_lost()
    print("  messages lost        %d of %d target bearings (DEBUG_VECT) of frames captured while an autopilot "
          "listened (%.2f %%)%s" % (expected - got, expected, 100.0 * (expected - got) / max(expected, 1),
                                    "; %d received could not be placed" % b.bearings_unplaced
                                    if b.bearings_unplaced else ""))
    delays = [x.resume_s for x in b.restarts]
    shown = " ".join("-" if d is None else "%.2f" % d for d in delays) or "none"
    known = [d for d in delays if d is not None]
    print("  autopilot restarts   %d; target messages resumed after (s): %s%s"
          % (len(delays), shown, "  (max %.2f, limit %.1f)" % (max(known), MAX_RESUME_S) if known else ""))
    res = r.resources()
    if res is None:
        print("  resources            too few samples after the %.0f s warm-up" % p.warmup_s)
    else:
        start, end = res
        print("  RSS                  %.1f MB after %.0f s -> %.1f MB at the end (%+.1f %%, limit +%.0f %%)"
              % (start["rss_kb"] / 1024.0, p.warmup_s, end["rss_kb"] / 1024.0,
                 100.0 * (end["rss_kb"] / start["rss_kb"] - 1.0), 100 * MAX_RSS_GROWTH))
        print("  open fds             %g -> %g (fewest in %d samples)" % (start["fds"], end["fds"], FLOOR_SAMPLES))
        print("  threads              %g -> %g (fewest in %d samples)" % (start["threads"], end["threads"], FLOOR_SAMPLES))
    print("  tracebacks in log    %d" % b.tracebacks)
    print("  the soak's own CPU   %.1f s (%.1f %% of one core)" % (r.soak_cpu_s, 100.0 * r.soak_cpu_s / max(r.elapsed_s, 1e-6)))
    failures = r.failures()
    print("  result               %s" % ("PASS" if not failures else "FAIL"))
    for line in failures:
        print("    - %s" % line)
    if r.service_died:
        print("  the service's last log lines:")
        for line in b.tail[-5:]:
            print("    | %s" % line)

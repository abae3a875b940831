"""The soak run: start the clip, the fake autopilot and the service, inject the faults on their
schedule, keep the books, print the report (see payload/soak/__init__.py)."""

import csv
import heapq
import json
import logging
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Tuple

import yaml

from payload.config import config_with, load_config
from payload.errors import PayloadError, SourceError
from payload.loopback import FAKE_AUTOPILOT, free_udp_port
from payload.soak import KINDS
from payload.soak.books import Books
from payload.soak.clip import corrupt, render_folder, restore
from payload.soak.report import Report, Restart, print_report
from payload.soak.watch import ProcSample, TailLines, sample, udp_ports

log = logging.getLogger(__name__)

TICK_S = 0.2
READY_TIMEOUT_S = 120.0


@dataclass
class Plan:
    """The schedule's timing, from the soak's length (short soaks get a compressed one)."""

    duration_s: float
    warmup_s: float  # resource use at the start is measured after this
    every_s: float  # one fault starts every every_s
    sample_s: float  # /proc sampling period
    down_s: float  # how long a killed autopilot stays down
    burst_s: float  # garbage burst length
    burst_rate: float  # garbage datagrams per second

    @classmethod
    def for_minutes(cls, minutes: float, every_s: Optional[float] = None) -> "Plan":
        if not (minutes > 0 and math.isfinite(minutes)):
            raise PayloadError("soak --minutes %r: expected a positive number of minutes" % minutes)
        duration = minutes * 60.0
        every = every_s if every_s else (20.0 if duration >= 300 else max(4.0, duration / 8.0))
        if not every >= 3.0:
            raise PayloadError("soak --every %r: expected at least 3 seconds between faults" % every_s)
        return cls(duration_s=duration, warmup_s=min(60.0, duration / 3.0), every_s=every,
                   sample_s=min(5.0, max(1.0, duration / 30.0)), down_s=min(5.0, 0.4 * every),
                   burst_s=min(5.0, 0.25 * every), burst_rate=2000.0)


@dataclass
class Fault:
    kind: str
    t_start: float  # soak clock (time.monotonic())
    deadline: float  # checks must hold by then (the next fault's start, or 2 s after t_end if later)
    t_end: Optional[float] = None  # the injection is over (autopilot back, frames restored, ...)
    injected: bool = False
    done: bool = False
    survived: bool = False
    why: str = ""
    detail: Dict[str, object] = field(default_factory=dict)


class Soak:
    def __init__(self, args) -> None:
        self.args = args
        self.plan = Plan.for_minutes(args.minutes, args.every)
        self.kinds = [k for k in KINDS if not (k == "corrupt_frames" and args.no_corrupt_frames)]
        self.out = os.path.abspath(args.out) if args.out else tempfile.mkdtemp(prefix="glad-soak-")
        self.books = Books()
        self.samples: List[ProcSample] = []
        self.faults: List[Fault] = []
        self.service: Optional[subprocess.Popen] = None
        self.autopilot: Optional[subprocess.Popen] = None
        self.port = free_udp_port()
        self._events: List[Tuple[float, int, Callable[[], None]]] = []
        self._seq = 0
        self._n_bad = 0
        self._good_variant = 0
        self._logs = []

    # --- set-up -------------------------------------------------------------------------------

    def prepare(self) -> None:
        a = self.args
        if a.clip_frames is None:  # longest clip (up to 90 frames) whose corrupt_frames hold fits between faults
            a.clip_frames = max(2, min(90, int(a.fps * (self.plan.every_s - 1.5) / 4.0) + 1))
        if a.clip_frames < 2 or not a.fps > 0 or min(a.size) < 64:
            raise PayloadError("soak: --clip-frames %d, --fps %g, --size %dx%d: expected at least 2 frames, a positive "
                               "rate and 64x64 or more" % (a.clip_frames, a.fps, a.size[0], a.size[1]))
        pass_s = (2 * a.clip_frames - 2) / a.fps  # the folder plays forwards then backwards
        # Corrupt frames stay for two passes: a paced source drops frames that went stale while
        # the service was busy (or were decoded late), and the fault only counts once one was read.
        self.hold_s = 2.0 * pass_s + 0.5
        if "corrupt_frames" in self.kinds and self.hold_s > self.plan.every_s - 1.0:
            raise PayloadError("soak: corrupt frames stay %.1f s (two passes through the clip), longer than the "
                               "%.0f s between faults allow: lower --clip-frames or raise --every"
                               % (self.hold_s, self.plan.every_s))
        base = load_config(a.config)  # a broken base config fails before anything is rendered
        for name in ("frames", "outputs", "autopilot.jsonl", "service.log", "autopilot.log", "config.yaml"):
            path = os.path.join(self.out, name)
            if os.path.isdir(path):
                shutil.rmtree(path)
            elif os.path.exists(path):
                os.remove(path)
        os.makedirs(self.out, exist_ok=True)
        print("soak: rendering %d frames (%dx%d, seed %d) into %s/frames"
              % (a.clip_frames, a.size[0], a.size[1], a.seed, self.out), flush=True)
        self.frames = render_folder(os.path.join(self.out, "frames"), a.seed, a.size[0], a.size[1], a.fps,
                                    a.clip_frames)
        self.config_path = os.path.join(self.out, "config.yaml")
        self.good = [self._config_text(base, 0.0), self._config_text(base, 0.01)]
        _write(self.config_path, self.good[0].encode("utf-8"))
        self.record = os.path.join(self.out, "autopilot.jsonl")
        self.decisions = TailLines(os.path.join(self.out, "outputs", "decisions.csv"))
        self.record_tail = TailLines(self.record)
        self.log_tail = TailLines(os.path.join(self.out, "service.log"))
        self._decision_fields: Optional[List[str]] = None

    def _config_text(self, base, nudge: float) -> str:
        """The service's config: the base with our capture, link and outputs; ``nudge`` moves a
        live threshold so that a good reload changes something."""
        a = self.args
        cfg = config_with(base, **{
            "capture.source": "folder", "capture.path": os.path.join(self.out, "frames"),
            "capture.fps": a.fps, "capture.loop": True, "capture.pace": True,
            "mavlink.enabled": True, "mavlink.connection": "udpout:127.0.0.1:%d" % self.port,
            "mavlink.outputs.debug_vect": True,  # the bearings counted for messages lost
            "outputs.directory": os.path.join(self.out, "outputs"),
            "detector.classifier.threshold": min(base.detector.classifier.threshold + nudge, 0.99),
        })
        return yaml.safe_dump(cfg.model_dump(mode="json", by_alias=True), sort_keys=False)

    def _start_autopilot(self) -> subprocess.Popen:
        err = open(os.path.join(self.out, "autopilot.log"), "a")
        self._logs.append(err)
        proc = subprocess.Popen([sys.executable, FAKE_AUTOPILOT, "--listen", "udpin:127.0.0.1:%d" % self.port,
                                 "--record", self.record], stdout=subprocess.DEVNULL, stderr=err)
        return proc

    def _start_service(self) -> subprocess.Popen:
        err = open(os.path.join(self.out, "service.log"), "a")
        self._logs.append(err)
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        return subprocess.Popen([sys.executable, "-m", "payload", "run", "--config", self.config_path],
                                env=env, stdout=subprocess.DEVNULL, stderr=err)

    # --- the run ------------------------------------------------------------------------------

    def run(self) -> int:
        self.prepare()
        p = self.plan
        try:
            self.autopilot = self._start_autopilot()
            self._wait(lambda: bool(self.books.windows), 15.0, "the fake autopilot to listen", self.autopilot)
            self.service = self._start_service()
            self._wait(lambda: self.books.rows > 0, READY_TIMEOUT_S, "the service's first frame", self.service)
            self.t0 = time.monotonic()
            self.cpu0 = sum(os.times()[:2])  # this process only: the soak's own load
            print("soak: service pid %d processing; %.1f min, a fault every %.0f s (%s)"
                  % (self.service.pid, p.duration_s / 60.0, p.every_s, ", ".join(self.kinds)), flush=True)
            self._schedule()
            self._loop()
        finally:
            rc = self._stop()
        report = self._report(rc)
        print_report(report)
        return 0 if report.passed else 1

    def _schedule(self) -> None:
        p = self.plan
        t, i = p.every_s, 0
        tail = max(p.every_s, 8.0)  # the last fault ends and is checked before the end (an autopilot takes seconds to start)
        while t + tail <= p.duration_s:
            kind = self.kinds[i % len(self.kinds)]
            fault = Fault(kind, self.t0 + t, deadline=self.t0 + min(t + p.every_s, p.duration_s))
            self.faults.append(fault)
            self._at(fault.t_start, lambda f=fault: self._inject(f))
            t += p.every_s
            i += 1
        self.next_sample = self.t0

    def _at(self, t: float, action: Callable[[], None]) -> None:
        self._seq += 1
        heapq.heappush(self._events, (t, self._seq, action))

    def _loop(self) -> None:
        end = self.t0 + self.plan.duration_s
        while time.monotonic() < end:
            now = time.monotonic()
            while self._events and self._events[0][0] <= now:
                heapq.heappop(self._events)[2]()
            self._tick(now)
            if self.service.poll() is not None:
                log.error("soak: the service exited (status %s)", self.service.returncode)
                return
            time.sleep(TICK_S)
        self._tick(time.monotonic())

    def _tick(self, now: float) -> None:
        self._read(now)
        if now >= self.next_sample:
            s = sample(self.service.pid, now)
            if s is not None:
                self.samples.append(s)
            self.next_sample = now + self.plan.sample_s
        for fault in self.faults:
            restart = fault.detail.get("restart")
            if fault.t_end is None and restart is not None and restart.start_t is not None:
                fault.t_end = restart.start_t  # over once the new autopilot listens (its start takes seconds)
            if not fault.done and fault.t_end is not None:
                self._check(fault, now)

    def _read(self, now: float) -> None:
        # Decisions before the record: a row's autopilot START is then always already in the record.
        decisions = self.decisions.read()
        for line in self.record_tail.read():
            try:
                self.books.on_record(json.loads(line))
            except ValueError:  # a line cut by a kill, perhaps continued by the next autopilot's START
                start = line.find('{"type": "START"')
                if start > 0:
                    self.books.on_record(json.loads(line[start:]))
        for values in csv.reader(decisions):
            if self._decision_fields is None or values[:1] == ["frame"]:
                self._decision_fields = values
                continue
            if len(values) == len(self._decision_fields):
                self.books.on_decision(dict(zip(self._decision_fields, values)))
        for line in self.log_tail.read():
            self.books.on_log(line, now)

    def _wait(self, done: Callable[[], bool], timeout_s: float, what: str, proc: subprocess.Popen) -> None:
        deadline = time.monotonic() + timeout_s
        while not done():
            if proc.poll() is not None:
                raise SourceError("soak: waiting for %s: the process exited (status %s); see %s"
                                  % (what, proc.returncode, self.out))
            if time.monotonic() > deadline:
                raise SourceError("soak: no sign of %s in %.0f s; see %s" % (what, timeout_s, self.out))
            time.sleep(TICK_S)
            self._read(time.monotonic())

    # --- faults -------------------------------------------------------------------------------

    def _inject(self, fault: Fault) -> None:
        if self.service.poll() is not None:
            return
        now = time.monotonic()
        fault.injected = True
        log.info("soak: %.1f s: %s", now - self.t0, fault.kind)
        if fault.kind == "autopilot_restart":
            self.autopilot.kill()
            self.autopilot.wait()
            for w in self.books.windows:
                w[1] = min(w[1], now)
            self._at(now + self.plan.down_s, lambda: self._autopilot_back(fault))
        elif fault.kind == "garbage":
            ports = udp_ports(self.service.pid)
            if not ports:
                fault.done, fault.why = True, "the payload has no UDP socket to send garbage to"
                return
            fault.detail["ports"] = sorted(ports)
            burst = threading.Thread(target=_garbage, args=(sorted(ports), self.plan.burst_s, self.plan.burst_rate,
                                                            fault.detail), daemon=True)
            burst.start()
            self._at(now + self.plan.burst_s + 0.1, lambda: self._ended(fault, burst))
        elif fault.kind == "corrupt_frames":
            fault.detail["unreadable"] = self.books.unreadable
            n = len(self.frames)  # three frames far apart: one stall does not step over all
            originals = corrupt([self.frames[n // 4], self.frames[n // 2], self.frames[3 * n // 4]])
            self._at(now + self.hold_s, lambda: (restore(originals), self._ended(fault)))
        elif fault.kind == "reload_good":
            self._good_variant = 1 - self._good_variant
            _write(self.config_path, self.good[self._good_variant].encode("utf-8"))
            self.service.send_signal(signal.SIGHUP)
            fault.t_end = now
        elif fault.kind == "reload_bad":
            how, data = self._bad_config()
            fault.detail["config"] = how
            _write(self.config_path, data)
            self.service.send_signal(signal.SIGHUP)
            good = self.good[self._good_variant].encode("utf-8")
            self._at(now + 1.0, lambda: (_write(self.config_path, good), self._ended(fault)))

    def _ended(self, fault: Fault, thread: Optional[threading.Thread] = None) -> None:
        if thread is not None:
            thread.join()
        fault.t_end = time.monotonic()

    def _autopilot_back(self, fault: Fault) -> None:
        self.autopilot = self._start_autopilot()
        self.books.restarts.append(Restart(pid=self.autopilot.pid, kill_t=fault.t_start))
        fault.detail["restart"] = self.books.restarts[-1]

    def _bad_config(self) -> Tuple[str, bytes]:
        """A broken config, a different way each time."""
        good = self.good[self._good_variant]
        self._n_bad += 1
        data = yaml.safe_load(good)
        how = ("YAML syntax error", "value out of range", "unknown key", "not UTF-8")[(self._n_bad - 1) % 4]
        if how == "YAML syntax error":
            return how, (good + "\ncapture: [unclosed\n").encode("utf-8")
        if how == "value out of range":
            data["detector"]["classifier"]["threshold"] = 7.0
        elif how == "unknown key":
            data["detector"]["clasifier"] = {"threshold": 0.5}
        else:
            return how, b"# \xff\xfe not UTF-8\n" + good.encode("utf-8")
        return how, yaml.safe_dump(data, sort_keys=False).encode("utf-8")

    def _check(self, fault: Fault, now: float) -> None:
        """A fault is survived once the service is alive, processing frames again after it, and
        what the kind needs holds; failed when that is not so by its deadline."""
        b = self.books
        missing = []
        if b.last_capture_t <= fault.t_end:
            missing.append("no frame processed after it")
        if fault.kind == "autopilot_restart":
            r = fault.detail["restart"]
            if r.first_msg_t is None:
                missing.append("no target message reached the restarted autopilot")
        elif fault.kind == "garbage":
            if "ports" in fault.detail and fault.detail.get("sent", 0) == 0:
                missing.append("no garbage sent")
            if b.link_up_t <= fault.t_end:
                missing.append("no summary line with link=up after the burst")
            if b.last_in_t <= fault.t_end:
                missing.append("the autopilot heard nothing from the payload after the burst")
        elif fault.kind == "corrupt_frames":
            if b.unreadable <= fault.detail["unreadable"]:
                missing.append("no summary line counting the corrupt frames as unreadable")
        elif fault.kind.startswith("reload"):
            lines = [line.lower() for t, line in b.log_lines if t >= fault.t_start]
            if fault.kind == "reload_good":
                said = any("reload: applied" in line for line in lines)
            else:
                said = any("reload" in line and ("reject" in line or "keep" in line) for line in lines)
            if not said:
                missing.append("no log line saying the reload was %s"
                               % ("applied" if fault.kind == "reload_good" else "rejected"))
        if not missing:
            fault.done, fault.survived = True, True
        elif now >= max(fault.deadline, fault.t_end + 2.0) or self.service.poll() is not None:
            fault.done, fault.why = True, "; ".join(missing)

    # --- the end ------------------------------------------------------------------------------

    def _stop(self) -> Optional[int]:
        rc = None
        self.service_died = True
        if self.service is not None:
            died = self.service.poll() is not None
            if not died:
                self.service.send_signal(signal.SIGTERM)
            try:
                rc = self.service.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.service.kill()
                rc = self.service.wait()
            self.service_died = died
        time.sleep(0.3)  # the last messages land in the record
        if self.autopilot is not None and self.autopilot.poll() is None:
            self.autopilot.terminate()
            try:
                self.autopilot.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.autopilot.kill()
                self.autopilot.wait()
        self._read(time.monotonic())
        for fault in self.faults:
            if not fault.done and fault.t_end is not None:
                self._check(fault, math.inf)
            if fault.injected and not fault.done:
                fault.done, fault.why = True, "the service died during it" if self.service_died else "unfinished"
        for tail in (self.decisions, self.record_tail, self.log_tail):
            tail.close()
        for fh in self._logs:
            fh.close()
        return rc

    def _report(self, rc: Optional[int]) -> Report:
        return Report(
            out=self.out, plan=self.plan, kinds=self.kinds, faults=self.faults, books=self.books,
            samples=self.samples, t0=getattr(self, "t0", None), service_rc=rc,
            service_died=getattr(self, "service_died", True),
            elapsed_s=(self.books.last_capture_t - self.t0) if hasattr(self, "t0") else 0.0,
            soak_cpu_s=sum(os.times()[:2]) - getattr(self, "cpu0", 0.0),
        )


def _garbage(ports: List[int], seconds: float, rate: float, detail: Dict[str, object]) -> None:
    """Random datagrams, some starting with a MAVLink magic byte, at the payload's ports."""
    pool = []
    for i in range(64):
        data = bytearray(os.urandom(1 + (i * 37) % 280))
        if i % 2 == 0:
            data[0] = 0xFD if i % 4 == 0 else 0xFE
        pool.append(bytes(data))
    sent = 0
    t_end = time.monotonic() + seconds
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        while time.monotonic() < t_end:
            for _ in range(20):
                for port in ports:
                    try:
                        sock.sendto(pool[sent % len(pool)], ("127.0.0.1", port))
                        sent += 1
                    except OSError:
                        pass
            time.sleep(20.0 / rate)
    detail["sent"] = sent


def _write(path: str, data: bytes) -> None:
    tmp = path + ".tmp"
    with open(tmp, "wb") as fh:
        fh.write(data)
    os.replace(tmp, path)


def main_soak(args) -> int:
    return Soak(args).run()

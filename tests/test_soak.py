"""``glad-payload soak``: a short real soak (the service process, the fake autopilot, real UDP,
real signals), and the pieces that judge it."""

import os
import re
import socket
import subprocess
import sys

import pytest

from payload.soak import KINDS
from payload.soak.books import Books
from payload.soak.report import Report, Restart
from payload.soak.runner import Fault, Plan
from payload.soak.watch import ProcSample, TailLines, sample, udp_ports

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.slow
def test_short_soak_injects_every_fault_and_passes(tmp_path):
    out = tmp_path / "soak"
    # The lock verifier off: on this 16-frame loop (the drone jumps back every 0.5 s) it reported no
    # target at all on the Python 3.8 / OpenCV 4.5 venv (on 3.11 it did), and this test needs a steady
    # stream of bearings to measure their loss under faults, not the verifier's verdict on a loop.
    # One target (the default): with cls14, on the loop's JPEG frames on the 3.8 venv, the first global
    # frame locks a speck at the frame's lower edge (classifier 0.6 > 0.5) that is never confirmed nor
    # dropped; the stale lock must give its place to the drone (payload.detect.pipeline).
    base = tmp_path / "base.yaml"
    base.write_text("detector:\n  verifier:\n    enabled: false\n")
    env = dict(os.environ, PYTHONPATH=REPO + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run(
        [sys.executable, "-m", "payload", "soak", "--minutes", "0.5", "--every", "4", "--clip-frames", "16",
         "--size", "640", "360", "--config", str(base), "--out", str(out)],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=240,
    )
    report = proc.stdout
    log_path = out / "service.log"
    assert proc.returncode == 0, report + proc.stderr[-3000:] + (log_path.read_text()[-3000:] if log_path.exists() else "")
    assert "result               PASS" in report
    frames = int(re.search(r"frames processed\s+(\d+)", report).group(1))
    assert frames > 300  # 30 s at 30 fps, minus start-up
    assert int(re.search(r"corrupt frames skipped (\d+)", report).group(1)) >= 1
    survived = dict(re.findall(r"(\w+) (\d+/\d+)", re.search(r"faults survived\s+(.*)", report).group(1)))
    assert set(survived) == set(KINDS)
    for kind, ratio in survived.items():
        ok, injected = map(int, ratio.split("/"))
        assert injected >= 1 and ok == injected, (kind, ratio)
    restarts = re.search(r"autopilot restarts\s+(\d+); target messages resumed after \(s\): ([0-9. ]+)", report)
    assert int(restarts.group(1)) >= 1
    assert all(float(d) < 1.0 for d in restarts.group(2).split())
    lost = re.search(r"messages lost\s+(-?\d+) of (\d+)", report)
    # Loopback UDP loses nothing unless the fake autopilot is starved of CPU for long (2 busy cores).
    assert int(lost.group(2)) > 100 and 0 <= int(lost.group(1)) <= 0.01 * int(lost.group(2))
    for what in ("open fds", "threads"):
        start, end = map(int, re.search(what + r"\s+(\d+) -> (\d+)", report).groups())
        assert 0 < end <= start
    # The service saw each fault: the broken config refused, the good one applied, the restored frames read.
    log = log_path.read_text()
    assert "reload rejected" in log and "reload: applied" in log
    assert min(p.stat().st_size for p in (out / "frames").iterdir()) > 1000  # corrupted frames restored


def _report(tmp_path, samples, restarts=(), faults=(), died=False, tracebacks=0):
    books = Books()
    books.restarts = list(restarts)
    books.tracebacks = tracebacks
    plan = Plan.for_minutes(1.0)
    return Report(out=str(tmp_path), plan=plan, kinds=["reload_good"], faults=list(faults) or
                  [Fault("reload_good", 30.0, 34.0, t_end=30.0, injected=True, done=True, survived=True)],
                  books=books, samples=samples, t0=0.0, service_rc=None if not died else 1, service_died=died,
                  elapsed_s=60.0)


def _samples(rss_end_kb, fds_end=9, threads_end=10):
    flat = [ProcSample(20.0 + i, 200_000, 9, 10) for i in range(5)]
    return flat + [ProcSample(50.0 + i, rss_end_kb, fds_end, threads_end) for i in range(5)]


def test_report_criteria(tmp_path):
    assert _report(tmp_path, _samples(205_000)).passed  # +2.5 %
    assert "RSS grew 6.0 %" in " ".join(_report(tmp_path, _samples(212_000)).failures())
    assert any("fds not flat" in f for f in _report(tmp_path, _samples(200_000, fds_end=10)).failures())
    assert any("threads not flat" in f for f in _report(tmp_path, _samples(200_000, threads_end=11)).failures())
    slow = Restart(pid=1, kill_t=10.0, start_t=12.0, t_ref=12.1, first_msg_t=13.2)
    assert slow.resume_s == pytest.approx(1.1)
    assert any("resumed after 1.10 s" in f for f in _report(tmp_path, _samples(200_000), [slow]).failures())
    never = Restart(pid=1, kill_t=10.0, start_t=12.0)
    assert any("never resumed" in f for f in _report(tmp_path, _samples(200_000), [never]).failures())
    assert any("died" in f for f in _report(tmp_path, _samples(200_000), died=True).failures())
    assert not _report(tmp_path, _samples(200_000), tracebacks=1).passed
    failed = Fault("reload_good", 30.0, 34.0, t_end=30.0, injected=True, done=True, why="no log line")
    assert any("no log line" in f for f in _report(tmp_path, _samples(200_000), faults=[failed]).failures())
    assert not _report(tmp_path, _samples(200_000)[:4]).passed  # too few samples to judge


def test_a_file_open_while_a_frame_is_read_is_no_leaked_fd(tmp_path):
    # The service opens each JPEG of the soak's frame folder to read it: a /proc sample taken then
    # counts one fd more. CI on a busy machine caught that in two of the last three samples (8 -> 9)
    # and failed the soak. A leak stays open in every sample after it; a read comes and goes.
    rows = [ProcSample(20.0 + i, 200_000, 8 + (i % 3 == 0), 6) for i in range(10)]
    rows += [ProcSample(50.0 + i, 200_000, 9 if i != 2 else 8, 6 + (i == 3)) for i in range(5)]
    assert _report(tmp_path, rows).passed
    leaked = rows[:10] + [ProcSample(50.0 + i, 200_000, 9 + (i == 1), 6) for i in range(5)]
    assert any("fds not flat: 8 -> 9" in f for f in _report(tmp_path, leaked).failures())
    thread_left = rows[:10] + [ProcSample(50.0 + i, 200_000, 8, 7) for i in range(5)]
    assert any("threads not flat: 6 -> 7" in f for f in _report(tmp_path, thread_left).failures())


def test_bearings_placed_by_capture_time():
    books = Books()
    books.on_record({"type": "START", "t": 100.0, "t_start_ns": 100_000_000_000, "pid": 1})
    # A frame at 101.0 s: its bearing in the autopilot's clock (synced), one in ours (not yet synced).
    books.on_decision({"t_capture_ns": "101000000000", "state": "detected", "az_body_rad": "0.1"})
    books.on_decision({"t_capture_ns": "101100000000", "state": "coasting", "az_body_rad": "0.1"})
    books.on_decision({"t_capture_ns": "101200000000", "state": "searching", "az_body_rad": ""})
    books.on_record({"dir": "in", "t": 101.02, "type": "DEBUG_VECT", "fields": {"time_usec": 1_000_000}})
    books.on_record({"dir": "in", "t": 101.12, "type": "DEBUG_VECT", "fields": {"time_usec": 101_100_000}})
    assert list(books.bearings_got) == pytest.approx([101.0, 101.1])
    assert books.bearings_lost() == (2, 2)
    # A frame just before a kill is in flight: counted on neither side.
    books.windows[0][1] = 101.5
    assert books.bearings_lost() == (0, 0)


def test_tail_lines_follows_rotation(tmp_path):
    path = tmp_path / "decisions.csv"
    path.write_bytes(b"a\nb")
    tail = TailLines(str(path))
    assert tail.read() == ["a"]  # "b" is not a complete line yet
    with open(path, "ab") as fh:
        fh.write(b"\nc\n")
    os.rename(path, str(path) + ".1")
    with open(str(path) + ".1", "ab") as fh:
        fh.write(b"d\n")  # written to the old file before the writer moved on
    path.write_bytes(b"e\n")
    assert tail.read() == ["b", "c", "d", "e"]
    tail.close()


def test_proc_probes_see_this_process():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        assert s.getsockname()[1] in udp_ports(os.getpid())
        here = sample(os.getpid(), 0.0)
    assert here.rss_kb > 1000 and here.fds >= 3 and here.threads >= 1
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    assert sample(dead.pid, 0.0) is None

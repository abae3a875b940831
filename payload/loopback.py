"""The fake autopilot (sitl/fake_autopilot.py) on loopback UDP: start it, wait until it listens,
read what it recorded. The demo, the soak run and the service tests stand it in for the vehicle.
"""

import json
import logging
import os
import socket
import subprocess
import sys
import time
from collections import Counter
from typing import List

from payload.errors import SourceError

log = logging.getLogger(__name__)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FAKE_AUTOPILOT = os.path.join(REPO, "sitl", "fake_autopilot.py")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_fake_autopilot(port: int, record: str, extra=()) -> subprocess.Popen:
    if not os.path.exists(FAKE_AUTOPILOT):
        raise SourceError("demo: %s not found: the demo runs from a source checkout" % FAKE_AUTOPILOT)
    return subprocess.Popen(
        [sys.executable, FAKE_AUTOPILOT, "--listen", "udpin:127.0.0.1:%d" % port, "--record", record,
         "--stdin-control", *extra],
        stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )


def wait_listening(autopilot: subprocess.Popen, record: str, timeout_s: float = 15.0) -> None:
    """Until the fake autopilot listens: it writes its record's first line once its port is bound.
    Else the first frames' messages would go nowhere (a busy machine takes a second or more to
    start it)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if autopilot.poll() is not None:
            err = autopilot.stderr.read().decode("utf-8", "replace").strip().splitlines() if autopilot.stderr else []
            raise SourceError("demo: the fake autopilot exited (status %s): %s"
                              % (autopilot.returncode, err[-1] if err else "no message"))
        if os.path.exists(record) and os.path.getsize(record) > 0:
            return
        time.sleep(0.05)
    log.warning("demo: fake autopilot not listening after %.0f s; starting anyway", timeout_s)


def record_rows(path: str) -> List[dict]:
    """The fake autopilot's record so far: one dict a complete line. Read at once and cut at line
    ends, because the autopilot may be half-way through its last line (iterating the file would
    yield that half, then its other half as a line of its own once the file has grown)."""
    if not os.path.exists(path):
        return []  # not started writing yet
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    rows = []
    for line in text.split("\n")[:-1]:
        try:
            rows.append(json.loads(line))
        except ValueError:
            pass  # a line cut by a kill, continued by a restarted autopilot
    return rows


def read_record(path: str) -> Counter:
    """Message type -> count of what the fake autopilot received from us."""
    return Counter(row.get("type", "?") for row in record_rows(path) if row.get("dir") == "in")

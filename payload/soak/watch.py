"""Watching a running process from outside: files as they grow, and /proc."""

import os
from dataclasses import dataclass
from typing import List, Optional, Set


class TailLines:
    """The complete lines appended to a file since the last call. Follows a rotation (the path
    now names a new file): the old file is read to its end through the open handle first."""

    def __init__(self, path: str) -> None:
        self.path = path
        self._fh = None
        self._ino = None
        self._partial = b""

    def read(self) -> List[str]:
        lines = []
        if self._fh is None and not self._open():
            return lines
        lines += self._drain()
        try:
            ino = os.stat(self.path).st_ino
        except OSError:
            ino = None
        if ino is not None and ino != self._ino:  # rotated: the old file is finished
            self._close()
            if self._open():
                lines += self._drain()
        return lines

    def close(self) -> None:
        self._close()

    def _open(self) -> bool:
        try:
            self._fh = open(self.path, "rb")
        except OSError:
            return False
        self._ino = os.fstat(self._fh.fileno()).st_ino
        self._partial = b""
        return True

    def _close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def _drain(self) -> List[str]:
        data = self._partial + self._fh.read()
        *complete, self._partial = data.split(b"\n")
        return [line.decode("utf-8", "replace") for line in complete]


@dataclass
class ProcSample:
    t: float  # time.monotonic()
    rss_kb: int
    fds: int
    threads: int


def sample(pid: int, t: float) -> Optional[ProcSample]:
    """RSS, open fds and threads of a process; None when it is gone."""
    try:
        with open("/proc/%d/status" % pid) as fh:
            status = dict(line.split(":", 1) for line in fh if ":" in line)
        fds = len(os.listdir("/proc/%d/fd" % pid))
    except OSError:
        return None
    return ProcSample(t, int(status["VmRSS"].split()[0]), fds, int(status["Threads"]))


def udp_ports(pid: int) -> Set[int]:
    """The local ports of the process's UDP sockets (its MAVLink socket), from /proc."""
    inodes = set()
    try:
        for fd in os.listdir("/proc/%d/fd" % pid):
            try:
                target = os.readlink("/proc/%d/fd/%s" % (pid, fd))
            except OSError:
                continue  # closed meanwhile
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    except OSError:
        return set()
    ports = set()
    for table in ("udp", "udp6"):
        try:
            with open("/proc/%d/net/%s" % (pid, table)) as fh:
                rows = fh.read().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            cols = row.split()
            if len(cols) > 9 and cols[9] in inodes:
                ports.add(int(cols[1].rsplit(":", 1)[1], 16))
    return ports

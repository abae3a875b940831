"""Messages on their way out: handed over by any thread, written by the link thread alone.

The frame step (and the camera protocol) only put a message here and go on: the socket, serial
port or TCP stream is written by the link thread, so a full buffer, a slow radio or a peer that
stops reading (a TCP write waits up to its timeout) delays the link, never a frame. First in,
first out: a frame's messages and a command's ACK leave in the order they were put. Bounded:
when the link thread falls behind by ``size`` messages the oldest is dropped (counted), as a
camera drops a frame nobody read. A pipe wakes the link thread as soon as something is put.
"""

import os
import threading
from collections import deque
from typing import Any, Deque, List, Optional, Tuple

Item = Tuple[int, Any, Optional[int]]  # (sequence number, pymavlink message, src_system or None for our own)


class Outbox:
    def __init__(self, size: int = 256) -> None:
        self.size = size
        self._lock = threading.Lock()
        self._items: Deque[Item] = deque()
        self._wake_r: Optional[int] = None
        self._wake_w: Optional[int] = None
        self.overflow = 0  # messages dropped because the link thread was size messages behind
        self.last_seq = 0  # sequence number of the last message put (1, 2, ...)

    def open(self) -> None:
        """Make the wake-up pipe (the link thread's start); again after ``close``."""
        if self._wake_r is None:
            self._wake_r, self._wake_w = os.pipe()
            os.set_blocking(self._wake_r, False)
            os.set_blocking(self._wake_w, False)

    @property
    def fd(self) -> Optional[int]:
        """Readable when something was put since the last ``take`` (for the link thread's select)."""
        return self._wake_r

    def put(self, msg: Any, src_system: Optional[int] = None) -> None:
        with self._lock:
            if len(self._items) >= self.size:
                self._items.popleft()
                self.overflow += 1
            self.last_seq += 1
            self._items.append((self.last_seq, msg, src_system))
        wake = self._wake_w
        if wake is not None:
            try:
                os.write(wake, b"\0")
            except OSError:
                pass  # the pipe is full of wake-ups already, or closed at shutdown

    def clear_wake(self) -> None:
        """Empty the wake-up pipe (before ``take``, so that a put after it wakes the thread again)."""
        if self._wake_r is not None:
            try:
                while os.read(self._wake_r, 4096):
                    pass
            except OSError:
                pass  # nothing left to read

    def take(self) -> List[Item]:
        """Everything waiting, oldest first; the queue is left empty."""
        with self._lock:
            items = list(self._items)
            self._items.clear()
        return items

    def __len__(self) -> int:
        return len(self._items)

    def close(self) -> None:
        fds = (self._wake_r, self._wake_w)
        self._wake_r = self._wake_w = None
        for fd in fds:
            if fd is not None:
                os.close(fd)

"""The detection loop's side of the video: a slot holding the newest item, never waited on."""

import threading
from typing import Any, Optional


class NewestSlot:
    """A queue of one where the newest item wins: ``put`` never blocks and replaces an item the
    consumer has not taken yet (counted in ``dropped``); ``take`` waits for an item."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: Optional[Any] = None
        self._closed = False
        self.put_count = 0
        self.dropped = 0  # items replaced before the consumer took them

    def put(self, item: Any) -> None:
        with self._cond:
            if self._item is not None:
                self.dropped += 1
            self._item = item
            self.put_count += 1
            self._cond.notify()

    def take(self, timeout_s: float) -> Optional[Any]:
        """The newest item, or None after ``timeout_s`` or once closed."""
        with self._cond:
            if self._item is None and not self._closed:
                self._cond.wait(timeout_s)
            item, self._item = self._item, None
            return item

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed

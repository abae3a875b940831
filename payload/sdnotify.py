"""The systemd notify protocol (sd_notify(3)) without a dependency.

A message is one datagram of ``KEY=VALUE`` lines to the unix socket named by
``$NOTIFY_SOCKET`` (a leading ``@`` names the abstract namespace). Without that variable
(not started by systemd with ``Type=notify``) every call is a no-op, so the service loop
calls these unconditionally.
"""

import logging
import os
import socket
import time
from typing import Mapping, Optional

log = logging.getLogger(__name__)


class Notifier:
    """Tells systemd about start-up, liveness, reloads and shutdown.

    Sending never raises: a notify failure must not stop detection. The first failure is
    logged as a warning, later ones at debug level.
    """

    def __init__(self, environ: Optional[Mapping[str, str]] = None) -> None:
        env = os.environ if environ is None else environ
        self.address = self._address(env.get("NOTIFY_SOCKET", ""))
        self.watchdog_interval_s = self._watchdog_interval_s(env)
        self._sock: Optional[socket.socket] = None
        self._warned = False

    @staticmethod
    def _address(name: str) -> Optional[str]:
        if not name:
            return None
        if name.startswith("@"):
            return "\0" + name[1:]
        if name.startswith("/"):
            return name
        log.warning("sd_notify NOTIFY_SOCKET=%r: expected an absolute path or @name; notifications off", name)
        return None

    @staticmethod
    def _watchdog_interval_s(env: Mapping[str, str]) -> Optional[float]:
        usec = env.get("WATCHDOG_USEC", "")
        if not usec:
            return None
        pid = env.get("WATCHDOG_PID", "")
        if pid and pid != str(os.getpid()):
            return None  # the watchdog is meant for another process (e.g. our parent)
        try:
            value = int(usec)
        except ValueError:
            log.warning("sd_notify WATCHDOG_USEC=%r is not an integer; watchdog pings off", usec)
            return None
        return value / 1e6 if value > 0 else None

    @property
    def enabled(self) -> bool:
        return self.address is not None

    def notify(self, message: str) -> bool:
        """Send one raw message (newline-separated ``KEY=VALUE`` lines). True when sent."""
        if self.address is None:
            return False
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
                self._sock.setblocking(False)  # never stall the frame loop on a busy manager
            self._sock.sendto(message.encode("utf-8"), self.address)
            return True
        except OSError as exc:
            level = logging.DEBUG if self._warned else logging.WARNING
            self._warned = True
            log.log(level, "sd_notify send failed socket=%r error=%s", self.address.replace("\0", "@"), exc)
            return False

    def ready(self, status: Optional[str] = None) -> bool:
        """Start-up done (models loaded, first frame read); also ends a reload."""
        return self.notify("READY=1" + ("\nSTATUS=%s" % _one_line(status) if status else ""))

    def watchdog(self) -> bool:
        """Liveness ping; send from the frame loop at least every ``watchdog_interval_s / 2``."""
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        """Free-form one-line status shown by ``systemctl status``."""
        return self.notify("STATUS=%s" % _one_line(text))

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")

    def reloading(self) -> bool:
        """A reload (SIGHUP) started; send ready() when the new config is in use."""
        return self.notify("RELOADING=1\nMONOTONIC_USEC=%d" % (time.monotonic_ns() // 1000))

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def _one_line(text: str) -> str:
    return " ".join(str(text).split())

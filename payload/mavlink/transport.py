"""Bytes in and out of the MAVLink connection: the only module that imports pymavlink.

It uses pymavlink's MAVLink 2 dialect (ardupilotmega) for packing and parsing, imported
directly so that nothing depends on the ``MAVLINK20`` environment variable, and its own
transports instead of ``mavutil``'s, because those let an attacker or a fault steer the link:

- UDP: every datagram is parsed on its own and whatever it leaves unparsed is dropped (a UDP
  MAVLink datagram holds whole packets), so a flood of garbage cannot pile up in the parser;
  a datagram that does not start with a MAVLink marker is dropped unparsed.
  ``udpout:`` connects its socket to the autopilot, so the kernel drops datagrams from anyone
  else. ``udpin:`` sends to one peer, chosen by the link (the source of the autopilot's
  heartbeats), and while ``exclusive`` is set drops datagrams from every other source; mavutil
  kept every sender as a destination forever.
- TCP and serial streams: read what is there (at most ``_READ_SIZE`` bytes a call) and keep at
  most ``_MAX_BUFFER`` unparsed bytes.
- Signing: signatures are checked with ``payload.mavlink.signing.check_signature``, which
  verifies the hash before it touches any stream state.
"""

import errno
import socket
from typing import Any, List, Optional, Tuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from payload.mavlink import signing as _signing

__all__ = ["mavlink", "Parser", "SendDropped", "open_transport"]

_MARKERS = (mavlink.PROTOCOL_MARKER_V1, mavlink.PROTOCOL_MARKER_V2)
_MAX_PACKET = 280  # MAVLink 2: 10 header + 255 payload + 2 crc + 13 signature
_MAX_BUFFER = 4 * _MAX_PACKET
_READ_SIZE = 4096
_DATAGRAMS_PER_CALL = 64
_MAX_BAD_CHUNKS = 4  # a datagram from an autopilot or router holds whole, valid packets
_TRANSIENT_SEND_ERRORS = (errno.ECONNREFUSED, errno.EAGAIN, errno.EWOULDBLOCK, errno.ENOBUFS,
                          errno.ENETUNREACH, errno.EHOSTUNREACH)

Address = Tuple[str, int]


class SendDropped(OSError):
    """A send that could not go out this time (no peer, peer not listening, buffer full); the
    connection itself is fine."""


class Parser(mavlink.MAVLink):
    """pymavlink's MAVLink 2 codec with our signature check and a bounded input buffer."""

    def __init__(self, transport: Any, src_system: int, src_component: int):
        super().__init__(transport, srcSystem=src_system, srcComponent=src_component)
        self.robust_parsing = True  # garbage becomes BAD_DATA messages, not exceptions

    def check_signature(self, msgbuf: Any, srcSystem: int, srcComponent: int) -> bool:  # noqa: N803 (pymavlink's)
        return _signing.check_signature(self.signing, msgbuf, srcSystem, srcComponent)

    def reset(self) -> None:
        self.buf = bytearray()
        self.buf_index = 0
        self.expected_length = mavlink.HEADER_LEN_V1 + 2
        self.have_prefix_error = False

    def parse_datagram(self, data: bytes) -> List[Any]:
        """The messages in one datagram; nothing carries over to the next one. Parsing stops at the
        _MAX_BAD_CHUNKS-th unparseable chunk, so a datagram of garbage costs little."""
        self.reset()
        out: List[Any] = []
        bad = 0
        try:
            m = self.parse_char(data)
            while m is not None:
                out.append(m)
                if m.get_type() == "BAD_DATA":
                    bad += 1
                    if bad >= _MAX_BAD_CHUNKS:
                        break
                m = self.parse_char(b"")
        finally:
            self.reset()
        return out

    def parse_stream(self, data: bytes) -> List[Any]:
        """Messages completed by ``data`` on a byte stream; unparsed bytes beyond _MAX_BUFFER are dropped."""
        out = self.parse_buffer(data) or []
        if self.buf_len() > _MAX_BUFFER:
            self.reset()
        return out


class _Transport:
    """What the link uses: ``fd`` (for select), ``recv_msgs()``, ``mav.send(msg)``, ``close()``."""

    fd: int

    def __init__(self, src_system: int, src_component: int):
        self.mav = Parser(self, src_system, src_component)

    def setup_signing(self, key: bytes, link_id: int, allow_unsigned: Any) -> None:
        s = self.mav.signing
        s.secret_key = key
        s.sign_outgoing = True
        s.link_id = link_id
        s.allow_unsigned_callback = allow_unsigned
        s.timestamp = max(s.timestamp, _signing.wall_timestamp())

    def can_send(self) -> bool:
        return True


class UdpTransport(_Transport):
    """``udpin:HOST:PORT`` (listen) or ``udpout:HOST:PORT`` (send to the autopilot there)."""

    def __init__(self, host: str, port: int, listen: bool, src_system: int, src_component: int):
        super().__init__(src_system, src_component)
        self.listen = listen
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setblocking(False)
            if listen:
                self.sock.bind((host, port))
                self.peer: Optional[Address] = None
            else:
                self.sock.connect((host, port))  # replies from anyone else are dropped by the kernel
                self.peer = self.sock.getpeername()
        except OSError:
            self.sock.close()
            raise
        self.fd = self.sock.fileno()
        self.exclusive = False  # udpin: drop datagrams from sources other than peer
        self.foreign = 0  # datagrams dropped for their source
        self.garbage = 0  # datagrams dropped for not starting with a MAVLink marker
        self.last_source: Optional[Address] = None

    def can_send(self) -> bool:
        return self.peer is not None

    def recv_msgs(self) -> List[Any]:
        """(source address, message) pairs from the datagrams waiting now (at most _DATAGRAMS_PER_CALL)."""
        out: List[Any] = []
        for _ in range(_DATAGRAMS_PER_CALL):
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:  # udpout: ICMP port unreachable from an earlier send
                continue
            out.extend(self.messages_from(data, addr))
        return out

    def messages_from(self, data: bytes, addr: Address) -> List[Any]:
        """(addr, message) pairs of one datagram from ``addr``, after the source and marker checks."""
        if self.listen and self.exclusive and addr != self.peer:
            self.foreign += 1
            self.last_source = addr
            return []
        if not data or data[0] not in _MARKERS:
            self.garbage += 1
            return []
        return [(addr, m) for m in self.mav.parse_datagram(data)]

    def write(self, buf: bytes) -> None:
        if self.peer is None:
            raise SendDropped("no peer yet")
        try:
            if self.listen:
                self.sock.sendto(buf, self.peer)
            else:
                self.sock.send(buf)
        except OSError as exc:
            if exc.errno in _TRANSIENT_SEND_ERRORS:
                raise SendDropped(str(exc)) from None
            raise

    def close(self) -> None:
        self.sock.close()


class _StreamTransport(_Transport):
    def recv_msgs(self) -> List[Any]:
        data = self._read()
        return [(None, m) for m in self.mav.parse_stream(data)] if data else []


class TcpTransport(_StreamTransport):
    """``tcp:HOST:PORT``: a TCP client; a closed connection raises ConnectionError (the link reconnects)."""

    def __init__(self, host: str, port: int, src_system: int, src_component: int):
        super().__init__(src_system, src_component)
        self.sock = socket.create_connection((host, port), timeout=2.0)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # small messages, sent at once
        self.sock.settimeout(0.5)  # a send that cannot go out in 0.5 s breaks the connection
        self.fd = self.sock.fileno()

    def _read(self) -> bytes:
        try:
            data = self.sock.recv(_READ_SIZE)
        except (BlockingIOError, InterruptedError, socket.timeout):
            return b""
        if not data:
            raise ConnectionError("connection closed by peer")
        return data

    def write(self, buf: bytes) -> None:
        self.sock.sendall(buf)

    def close(self) -> None:
        self.sock.close()


class SerialTransport(_StreamTransport):
    """A serial device (``/dev/ttyTHS0``) at ``baud``, through pyserial."""

    def __init__(self, device: str, baud: int, src_system: int, src_component: int):
        super().__init__(src_system, src_component)
        try:
            import serial  # only serial links need pyserial
        except ImportError:
            raise OSError("pyserial is not installed (pip install pyserial)") from None
        self.port = serial.Serial(device, baudrate=baud, timeout=0, write_timeout=0.5)
        self.fd = self.port.fileno()

    def _read(self) -> bytes:
        return self.port.read(_READ_SIZE)

    def write(self, buf: bytes) -> None:
        self.port.write(buf)

    def close(self) -> None:
        self.port.close()


def open_transport(connection: str, baud: int, src_system: int, src_component: int) -> _Transport:
    """The transport for a connection string checked by the link (udpin:, udp:, udpout:, tcp:, serial)."""
    scheme, _, rest = connection.partition(":")
    if scheme in ("udpin", "udp", "udpout", "tcp"):
        host, _, port = rest.rpartition(":")
        if scheme == "tcp":
            return TcpTransport(host, int(port), src_system, src_component)
        return UdpTransport(host, int(port), scheme != "udpout", src_system, src_component)
    return SerialTransport(connection, baud, src_system, src_component)

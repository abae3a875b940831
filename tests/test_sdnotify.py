import os
import socket
import time
import uuid

import pytest

from payload.sdnotify import Notifier


def _listener(address):
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(address)
    sock.settimeout(2.0)
    return sock


@pytest.fixture(params=["path", "abstract"])
def manager(request, tmp_path):
    """A real datagram socket standing where systemd's would: (NOTIFY_SOCKET value, socket)."""
    if request.param == "path":
        name = str(tmp_path / "notify")
        sock = _listener(name)
    else:
        name = "@glad-payload-test-%s" % uuid.uuid4().hex
        sock = _listener("\0" + name[1:])
    yield name, sock
    sock.close()


def _recv(sock):
    return sock.recv(4096).decode("utf-8")


def test_messages_reach_the_socket(manager):
    name, sock = manager
    notifier = Notifier({"NOTIFY_SOCKET": name})
    assert notifier.enabled
    assert notifier.ready()
    assert _recv(sock) == "READY=1"
    assert notifier.ready(status="tracking\nnow")
    assert _recv(sock) == "READY=1\nSTATUS=tracking now"
    assert notifier.watchdog()
    assert _recv(sock) == "WATCHDOG=1"
    assert notifier.status("fps=23.4 target=none")
    assert _recv(sock) == "STATUS=fps=23.4 target=none"
    assert notifier.stopping()
    assert _recv(sock) == "STOPPING=1"
    before_us = time.monotonic_ns() // 1000
    assert notifier.reloading()
    lines = _recv(sock).split("\n")
    after_us = time.monotonic_ns() // 1000
    assert lines[0] == "RELOADING=1"
    key, value = lines[1].split("=")
    assert key == "MONOTONIC_USEC" and before_us <= int(value) <= after_us
    notifier.close()


def test_without_notify_socket_every_call_is_a_no_op():
    notifier = Notifier({})
    assert not notifier.enabled
    assert notifier.watchdog_interval_s is None
    assert not notifier.ready() and not notifier.watchdog() and not notifier.status("x")
    assert not notifier.stopping() and not notifier.reloading()


def test_reads_the_real_environment(manager, monkeypatch):
    name, sock = manager
    monkeypatch.setenv("NOTIFY_SOCKET", name)
    monkeypatch.setenv("WATCHDOG_USEC", "10000000")
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    notifier = Notifier()
    assert notifier.watchdog_interval_s == pytest.approx(10.0)
    notifier.watchdog()
    assert _recv(sock) == "WATCHDOG=1"


@pytest.mark.parametrize(
    "env, interval",
    [
        ({"WATCHDOG_USEC": "5000000"}, 5.0),
        ({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(os.getpid())}, 5.0),
        ({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": "1"}, None),  # another process's watchdog
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "ten"}, None),
        ({}, None),
    ],
)
def test_watchdog_interval(env, interval):
    assert Notifier(env).watchdog_interval_s == (pytest.approx(interval) if interval else None)


def test_vanished_socket_is_reported_not_raised(tmp_path, caplog):
    path = str(tmp_path / "gone")
    notifier = Notifier({"NOTIFY_SOCKET": path})
    assert notifier.enabled
    assert not notifier.ready()  # nobody bound there: a warning, no exception
    assert any("sd_notify send failed" in r.getMessage() for r in caplog.records)


def test_relative_socket_name_is_refused(caplog):
    notifier = Notifier({"NOTIFY_SOCKET": "relative/notify"})
    assert not notifier.enabled
    assert any("NOTIFY_SOCKET" in r.getMessage() for r in caplog.records)

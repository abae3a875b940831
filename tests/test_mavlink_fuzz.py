"""Property-based tests (Hypothesis) of the MAVLink input path: random bytes, random valid messages
with random field values (NaN and inf included) and random signing fields go through the link's
receive path (the UDP transport's datagram checks and parser, then the link's handler, as the
link thread runs them) on a link with an open udpin socket. Properties: no exception escapes,
no non-finite value reaches the attitude or time state, a forged signature changes no signing
state, and what the link then sends can be packed."""

import contextlib
import math
import os
import socket
import struct
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as M
from test_mavlink import free_port, link_cfg

from payload.mavlink.link import MavlinkLink
from payload.mavlink.signing import wall_timestamp

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
HANDLED = ["HEARTBEAT", "ATTITUDE", "SYSTEM_TIME", "TIMESYNC", "COMMAND_LONG", "COMMAND_ACK"]
OTHERS = ["RADIO_STATUS", "DEBUG_VECT", "NAMED_VALUE_FLOAT", "GLOBAL_POSITION_INT", "CAMERA_TRACKING_IMAGE_STATUS",
          "LANDING_TARGET", "PARAM_VALUE"]
INT_RANGES = {"int8_t": (-128, 127), "uint8_t": (0, 255), "int16_t": (-2 ** 15, 2 ** 15 - 1),
              "uint16_t": (0, 2 ** 16 - 1), "int32_t": (-2 ** 31, 2 ** 31 - 1), "uint32_t": (0, 2 ** 32 - 1),
              "int64_t": (-2 ** 63, 2 ** 63 - 1), "uint64_t": (0, 2 ** 64 - 1)}


def _field(kind, length):
    if kind == "char":
        return st.binary(max_size=max(length, 1))
    if kind in ("float", "double"):
        one = st.floats(width=32 if kind == "float" else 64) | st.sampled_from([math.nan, math.inf, -math.inf])
    else:
        lo, hi = INT_RANGES[kind]
        one = st.integers(lo, hi) | st.sampled_from([lo, hi, 0])
    return st.lists(one, min_size=length, max_size=length) if length else one


def message(name):
    cls = getattr(M, "MAVLink_%s_message" % name.lower())
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))
    fields = {f: _field(t, lengths[f]) for f, t in zip(cls.fieldnames, cls.fieldtypes)}
    return st.fixed_dictionaries(fields).map(lambda kw: cls(**kw))


any_message = st.sampled_from(HANDLED + OTHERS).flatmap(message)
source = st.tuples(st.sampled_from([1, 1, 1, 2, 42, 255]), st.sampled_from([1, 1, 100, 190]))


@contextlib.contextmanager
def open_link(key=None, **kw):
    """A link with its udpin transport open and the autopilot (sysid 1, compid 1) known, its
    thread not started: the test drives the receive path itself."""
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    link = MavlinkLink(link_cfg("udpin:127.0.0.1:%d" % free_port(), **kw))
    link._conn = link._open()
    try:
        link.sink = sink.getsockname()
        feed(link, pack(M.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3), 1, 1, key, 1, wall_timestamp()))
        assert link.status.autopilot_seen
        yield link
    finally:
        link.stop()
        sink.close()


def feed(link, datagram, addr=None):
    """One datagram through the receive path, as MavlinkLink._step runs it."""
    with link._lock:
        for src, msg in link._conn.messages_from(datagram, addr or link.sink):
            link._handle(msg, src)
        link._periodic(time.monotonic_ns())
    link._flush()  # what the link thread writes after each pass


def pack(msg, sysid, compid, key=None, link_id=0, timestamp=0):
    mav = M.MAVLink(None, sysid, compid)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = link_id
        mav.signing.timestamp = timestamp
    return msg.pack(mav)


def check_state(link):
    """Nothing non-finite in the attitude or time state; what the service asks of it is finite."""
    for sample in link.poses.attitudes():
        assert all(math.isfinite(v) for v in sample[1:]), sample
    offset, _ = link.clock.offset()
    assert offset is None or isinstance(offset, int)
    now = time.monotonic_ns()
    for t in (now, now - 50_000_000, now + 50_000_000):
        att = link.attitude_at(t)
        assert att is None or all(math.isfinite(v) for v in (att.roll_rad, att.pitch_rad, att.yaw_rad)), att
        usec = link.time_usec_for(t)
        assert 0 <= usec < 2 ** 64
    # the bearing message of a frame taken now can always be packed and sent
    link.send_message("DEBUG_VECT", name=b"TGT_BRG", time_usec=link.time_usec_for(now), x=0.1, y=0.2, z=0.9)


KEY = os.urandom(32)


# One link per test for all its examples (module scope: Hypothesis runs a test body many times).
@pytest.fixture(scope="module")
def plain_link():
    with open_link() as link:
        yield link


@pytest.fixture(scope="module")
def signed_link(tmp_path_factory):
    key_file = tmp_path_factory.mktemp("signing") / "mavlink.key"
    key_file.write_text(KEY.hex())
    old = os.environ.pop("STATE_DIRECTORY", None)
    try:
        with open_link(KEY, signing={"enabled": True, "key_file": str(key_file)}) as link:
            yield link
    finally:
        if old is not None:
            os.environ["STATE_DIRECTORY"] = old


@SETTINGS
@given(datagrams=st.lists(st.binary(max_size=600), min_size=1, max_size=8))
def test_random_bytes(plain_link, datagrams):
    link = plain_link
    for data in datagrams:
        feed(link, data)
        feed(link, b"\xfd" + data)  # past the marker check, into the parser
    check_state(link)


@SETTINGS
@given(items=st.lists(st.tuples(any_message, source), min_size=1, max_size=10), cut=st.integers(0, 3))
def test_random_valid_messages(plain_link, items, cut):
    link = plain_link
    before = link.status.nonfinite
    n_nonfinite = 0
    for msg, (sysid, compid) in items:
        data = pack(msg, sysid, compid)
        feed(link, data[:len(data) - cut] if cut else data)  # also truncated
        if not cut and any(isinstance(v, float) and not math.isfinite(v)
                           for f in msg.fieldnames for v in (getattr(msg, f) if isinstance(getattr(msg, f), list)
                                                                else [getattr(msg, f)])):
            n_nonfinite += 1
    check_state(link)
    if not cut:
        assert link.status.nonfinite - before >= n_nonfinite


@SETTINGS
@given(packets=st.lists(st.tuples(any_message, source, st.binary(min_size=32, max_size=32), st.integers(0, 255),
                          st.integers(0, 2 ** 48 - 1), st.sampled_from(["wrong key", "bad signature", "unsigned"])),
                min_size=1, max_size=8))
def test_forged_signatures_change_nothing(signed_link, packets):
    link = signed_link
    signing = link._conn.mav.signing
    before = (dict(signing.stream_timestamps), link.detection_enabled)
    ts_before, st_before = signing.timestamp, link.status
    for msg, (sysid, compid), key, link_id, timestamp, how in packets:
        if how == "unsigned":
            data = pack(msg, sysid, compid)
        else:
            data = pack(msg, sysid, compid, key if how == "wrong key" else KEY, link_id, timestamp)
            if how == "bad signature":
                data = data[:-6] + bytes(b ^ 0x55 for b in data[-6:])
        feed(link, data)
    assert (dict(signing.stream_timestamps), link.detection_enabled) == before
    st = link.status
    # our timestamp moved only by our own sends (one tick per packed message), not to a forged one
    assert 0 <= signing.timestamp - ts_before <= (st.sent + st.dropped) - (st_before.sent + st_before.dropped)
    check_state(link)
    # the ground station (link id 7) is still heard with its current timestamp
    ts = max(wall_timestamp(), signing.stream_timestamps.get((7, 255, 190), 0) + 1)
    cmd = M.MAVLink_command_long_message(1, 100, 31010, 0, 1.0, 0, 0, 0, 0, 0, 0)
    feed(link, pack(cmd, 255, 190, KEY, 7, ts))
    assert signing.stream_timestamps[(7, 255, 190)] == ts


def test_signing_timestamp_block_is_parsed_little_endian():
    """The forged-signature test relies on pymavlink packing our timestamps as the spec says."""
    data = pack(M.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3), 1, 1, KEY, 9, 0x123456789A)
    tlow, thigh = struct.unpack("<IH", data[-12:-6])
    assert data[-13] == 9 and tlow + (thigh << 32) == 0x123456789A

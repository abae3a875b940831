"""No MAVLink target message leaves with a NaN or infinite value (issue 20): TargetPublisher on a
real MavlinkLink, the datagrams read back from a UDP socket and decoded with pymavlink."""

import math
import socket
import time

import numpy as np
import pytest

from payload.config import MavlinkConfig, MavlinkOutputsConfig
from payload.geometry import TargetGeo
from payload.mavlink.link import MavlinkLink
from payload.mavlink.outputs import TargetPublisher
from payload.mavlink.transport import mavlink
from payload.types import Bearing, Target

NAN, INF = float("nan"), float("inf")


def target(xyxy=(100.0, 100.0, 110.0, 108.0), score=0.9):
    return Target(frame_index=1, t_capture_ns=time.monotonic_ns(), xyxy=np.array(xyxy, np.float32), score=score,
                  module="LAD", measured=True)


def bearing(az=0.1, el=-0.05, az_level=0.12, el_level=0.02, confidence=0.9):
    return Bearing(t_capture_ns=time.monotonic_ns(), az_body_rad=az, el_body_rad=el, az_level_rad=az_level,
                   el_level_rad=el_level, confidence=confidence)


@pytest.fixture
def wire():
    """(publisher factory, read()): a link sending to a UDP socket of ours; read() decodes what arrived."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.2)
    link = MavlinkLink(MavlinkConfig(connection="udpout:127.0.0.1:%d" % sock.getsockname()[1], timesync=False,
                                     attitude_rate_hz=0.0))
    link.start()
    deadline = time.monotonic() + 10
    while not link.status.connected and time.monotonic() < deadline:
        time.sleep(0.05)
    parser = mavlink.MAVLink(None)

    def read():
        out = []
        while True:
            try:
                data = sock.recv(65536)
            except socket.timeout:
                return [m for m in out if m.get_type() != "HEARTBEAT"]
            out += parser.parse_buffer(data) or []

    yield (lambda **kw: TargetPublisher(link, MavlinkOutputsConfig(**kw))), read
    link.stop()
    sock.close()


def _finite(msg):
    fields = msg.to_dict()
    fields.pop("radius", None)  # NaN is MAVLink's "unknown" here: a rectangle has no radius
    return all(math.isfinite(v) for v in fields.values() if isinstance(v, float))


def test_finite_bearing_goes_out(wire):
    make, read = wire
    publisher = make(landing_target=True, debug_vect_frame="level")
    assert publisher.publish(target(), bearing(), (640, 480)) == 3
    assert sorted(m.get_type() for m in read()) == ["CAMERA_TRACKING_IMAGE_STATUS", "DEBUG_VECT", "LANDING_TARGET"]


@pytest.mark.parametrize("frame", ["body", "level"])
@pytest.mark.parametrize("bad", [dict(az=NAN), dict(el=INF), dict(az_level=NAN), dict(el_level=-INF),
                                 dict(confidence=NAN)])
def test_non_finite_bearing_is_withheld_and_counted(wire, frame, bad):
    make, read = wire
    publisher = make(landing_target=True, debug_vect_frame=frame)
    publisher.publish(target(), bearing(**bad), (640, 480))
    msgs = read()
    assert msgs and all(_finite(m) for m in msgs), [m.to_dict() for m in msgs]
    angles = ("az_level", "el_level") if frame == "level" else ("az", "el")
    debug_vect_bad = any(k in bad for k in angles + ("confidence",))
    landing_bad = any(k in bad for k in ("az", "el"))
    assert publisher.stats.not_finite == debug_vect_bad + landing_bad
    assert sorted(m.get_type() for m in msgs) == sorted(
        ["CAMERA_TRACKING_IMAGE_STATUS"] + ["DEBUG_VECT"] * (not debug_vect_bad) + ["LANDING_TARGET"] * (not landing_bad))


def test_non_finite_box_is_withheld(wire):
    make, read = wire
    publisher = make()
    assert publisher.publish(target(xyxy=(NAN, 1.0, 5.0, 5.0)), None, (640, 480)) == 0
    assert publisher.stats.not_finite == 1
    assert read() == []


_GEO_UNKNOWN = ("vel_n", "vel_e", "vel_d", "vel_acc", "hdg", "hdg_acc")  # NaN = MAVLink's "unknown"


def geo(**bad):
    values = dict(t_capture_ns=time.monotonic_ns(), range_m=80.0, range_sigma_m=8.0, lat_deg=47.4, lon_deg=8.55,
                  alt_m=500.0, h_acc_m=6.0, v_acc_m=3.0)
    values.update(bad)
    return TargetGeo(**values)


@pytest.mark.parametrize("bad", [dict(), dict(lat_deg=NAN), dict(lon_deg=INF), dict(alt_m=-INF), dict(h_acc_m=NAN),
                                 dict(v_acc_m=INF), dict(range_m=NAN)])
def test_non_finite_geo_is_withheld_and_counted(wire, bad):
    make, read = wire
    publisher = make(follow_target=True, debug_vect=False)
    publisher.publish(target(), None, (640, 480), geo(**bad))
    msgs = read()
    for m in msgs:
        fields = m.to_dict()
        for name in _GEO_UNKNOWN + ("radius",):
            fields.pop(name, None)
        assert all(math.isfinite(v) for v in fields.values() if isinstance(v, float)), fields
        assert all(math.isfinite(v) for v in fields.get("position_cov", []))
    types = sorted(m.get_type() for m in msgs)
    if not bad:
        assert types == ["CAMERA_TRACKING_GEO_STATUS", "CAMERA_TRACKING_IMAGE_STATUS", "FOLLOW_TARGET"]
    else:
        # range is not in FOLLOW_TARGET: a NaN range withholds only the geo status
        assert types == ["CAMERA_TRACKING_IMAGE_STATUS"] + ["FOLLOW_TARGET"] * ("range_m" in bad)
        assert publisher.stats.not_finite == 2 - ("range_m" in bad)

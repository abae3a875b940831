"""The MAVLink camera protocol (payload.mavlink.camera) and the geo outputs over the real link and
real UDP on 127.0.0.1, against the fake autopilot (sitl/fake_autopilot.py), which also plays the
ground station (system 255) sending the commands. The detection loop's side of a designation
(take / after_frame) is driven by the test, as the service does it each frame."""

import math
import time

import numpy as np
import pytest
from test_mavlink import Payload, free_port, link_cfg, signed_fake, start_fake, wait_for

from payload.config import Config, config_with
from payload.geometry import (
    Attitude,
    BearingModel,
    CameraModel,
    GeoModel,
    Position,
    TargetGeo,
    locate,
    mount_rotation,
    ned_between,
    range_from_size,
)
from payload.mavlink.camera import CameraProtocol
from payload.mavlink.link import MavlinkLink
from payload.mavlink.outputs import TargetPublisher
from payload.types import Target
from payload.video import StreamDescription

ACCEPTED, TEMPORARILY_REJECTED, DENIED, FAILED, IN_PROGRESS = 0, 1, 2, 4, 5
REQUEST_MESSAGE, SET_INTERVAL = 512, 511
TRACK_POINT, TRACK_RECTANGLE, STOP_TRACKING = 2004, 2005, 2010
CAMERA_INFORMATION, CAMERA_SETTINGS, VIDEO_STREAM_INFORMATION, VIDEO_STREAM_STATUS = 259, 260, 269, 270
TRACKING_IMAGE_STATUS = 275
HAS_VIDEO_STREAM, HAS_TRACKING_POINT, HAS_TRACKING_RECTANGLE = 256, 512, 1024
STREAM = StreamDescription("rtsp://192.168.1.10:8554/glad", 1280, 720, 25.0, 4000)
HOME = Position(47.397742, 8.545594, 488.0)


def camera_config(**kw):
    base = {"capture.synthetic.width": 960, "capture.synthetic.height": 540, "camera.hfov_deg": 70.0,
            "camera.pixel_size_um": 2.0, "mavlink.camera.designate_frames": 4}
    base.update(kw)
    return config_with(Config(), **base)


def results(fake, command):
    return [r["fields"]["result"] for r in fake.acks(command)]


def wait_results(fake, command, want, what):
    """Until the ACKs of ``command`` are ``want`` (in order); a wrong extra ACK fails."""
    got = wait_for(lambda: results(fake, command) if len(results(fake, command)) >= len(want) else None, 5.0, what)
    time.sleep(0.2)  # nothing more arrives
    assert results(fake, command) == want, what
    return got


@pytest.fixture
def rig(fakes, tmp_path):
    """A fake autopilot (udpin), our link (udpout) and a CameraProtocol with a stream."""
    port = free_port()
    fake = start_fake(fakes, tmp_path, f"udpin:127.0.0.1:{port}", "--attitude-hz", "20")
    cfg = camera_config()
    link = MavlinkLink(link_cfg(f"udpout:127.0.0.1:{port}"))
    camera = CameraProtocol(link, cfg, STREAM)
    with link:
        wait_for(lambda: link.status.autopilot_seen, 10.0, "autopilot")
        yield fake, link, camera


def test_requests_are_answered_with_the_camera_messages(rig):
    fake, link, camera = rig
    fake.command(f"{REQUEST_MESSAGE},param1={CAMERA_INFORMATION}")
    wait_results(fake, REQUEST_MESSAGE, [ACCEPTED], "ACK of REQUEST_MESSAGE(CAMERA_INFORMATION)")
    info = wait_for(lambda: fake.rows("CAMERA_INFORMATION"), 3.0, "CAMERA_INFORMATION")[0]["fields"]
    assert bytes(info["vendor_name"]).rstrip(b"\0") == b"glad-payload"
    assert bytes(info["model_name"]).rstrip(b"\0") == b"GLAD detector"
    assert (info["resolution_h"], info["resolution_v"]) == (960, 540)
    focal_px = 480.0 / math.tan(math.radians(35.0))
    assert info["focal_length"] == pytest.approx(focal_px * 0.002, rel=1e-5)
    assert info["sensor_size_h"] == pytest.approx(960 * 0.002) and info["sensor_size_v"] == pytest.approx(540 * 0.002)
    assert info["flags"] == HAS_TRACKING_POINT | HAS_TRACKING_RECTANGLE | HAS_VIDEO_STREAM

    fake.command("521")  # MAV_CMD_REQUEST_CAMERA_INFORMATION, the older request
    wait_results(fake, 521, [ACCEPTED], "ACK of REQUEST_CAMERA_INFORMATION")
    wait_for(lambda: len(fake.rows("CAMERA_INFORMATION")) == 2, 3.0, "second CAMERA_INFORMATION")

    fake.command("522")  # MAV_CMD_REQUEST_CAMERA_SETTINGS
    settings = wait_for(lambda: fake.rows("CAMERA_SETTINGS"), 3.0, "CAMERA_SETTINGS")[0]["fields"]
    assert settings["mode_id"] == 1  # CAMERA_MODE_VIDEO

    fake.command(f"{REQUEST_MESSAGE},param1={VIDEO_STREAM_INFORMATION}")
    vsi = wait_for(lambda: fake.rows("VIDEO_STREAM_INFORMATION"), 3.0, "VIDEO_STREAM_INFORMATION")[0]["fields"]
    assert vsi["uri"] == STREAM.uri and vsi["type"] == 0  # RTSP
    assert vsi.get("encoding", 1) == 1  # H.264 (pymavlink 2.4.38 has no encoding field)
    assert (vsi["resolution_h"], vsi["resolution_v"], vsi["bitrate"]) == (1280, 720, 4_000_000)
    assert vsi["framerate"] == 25.0 and vsi["stream_id"] == 1 and vsi["count"] == 1
    assert vsi["hfov"] == 70
    fake.command("2505")  # MAV_CMD_REQUEST_VIDEO_STREAM_STATUS
    wait_for(lambda: fake.rows("VIDEO_STREAM_STATUS"), 3.0, "VIDEO_STREAM_STATUS")

    # guards: a message we do not emit, a stream we do not have
    fake.command(f"{REQUEST_MESSAGE},param1=33")
    fake.command(f"{REQUEST_MESSAGE},param1={VIDEO_STREAM_INFORMATION},param2=3")
    wait_results(fake, REQUEST_MESSAGE, [ACCEPTED, ACCEPTED, DENIED, DENIED], "DENIED requests")
    assert len(fake.rows("VIDEO_STREAM_INFORMATION")) == 1

    # no stream: no HAS_VIDEO_STREAM, stream requests denied
    camera.stream = None
    fake.command("521")
    info = wait_for(lambda: fake.rows("CAMERA_INFORMATION")[2:], 3.0, "CAMERA_INFORMATION without stream")[0]["fields"]
    assert info["flags"] == HAS_TRACKING_POINT | HAS_TRACKING_RECTANGLE
    fake.command("2504")
    wait_results(fake, 2504, [DENIED], "VIDEO_STREAM_INFORMATION without a stream")
    assert camera.stats.requests == 6


def test_designation_is_in_progress_then_accepted_or_failed(rig):
    fake, link, camera = rig
    fake.command(f"{TRACK_POINT},param1=0.5,param2=0.4")
    wait_results(fake, TRACK_POINT, [IN_PROGRESS], "IN_PROGRESS")
    d = camera.take()
    assert d is not None and not d.stop and d.center_px((960, 540)) == pytest.approx((480.0, 216.0))
    assert camera.take() is None  # taken once
    assert camera.after_frame(False) is None and camera.after_frame(False) is None
    assert camera.after_frame(True) is True
    wait_results(fake, TRACK_POINT, [IN_PROGRESS, ACCEPTED], "ACCEPTED once confirmed")

    # a rectangle the local detectors do not confirm within designate_frames (4): FAILED, ERROR status
    fake.command(f"{TRACK_RECTANGLE},param1=0.1,param2=0.1,param3=0.3,param4=0.5")
    wait_results(fake, TRACK_RECTANGLE, [IN_PROGRESS], "IN_PROGRESS for the rectangle")
    d = camera.take()
    assert d.center_px((960, 540)) == pytest.approx((192.0, 162.0)) and d.size_px((960, 540)) == pytest.approx((192.0, 216.0))
    assert [camera.after_frame(False) for _ in range(4)] == [None, None, None, False]
    wait_results(fake, TRACK_RECTANGLE, [IN_PROGRESS, FAILED], "FAILED after 4 frames")
    errors = wait_for(lambda: [r for r in fake.rows("CAMERA_TRACKING_IMAGE_STATUS")
                               if r["fields"]["tracking_status"] == 2], 3.0, "tracking status ERROR")
    assert len(errors) == 1
    assert camera.stats.confirmed == 1 and camera.stats.failed == 1


def test_repeated_superseded_and_stopped_designations(rig):
    fake, link, camera = rig
    # a ground station's retry of the same command: IN_PROGRESS again, one designation
    fake.command(f"{TRACK_POINT},param1=0.3,param2=0.3")
    fake.command(f"{TRACK_POINT},param1=0.3,param2=0.3")
    wait_results(fake, TRACK_POINT, [IN_PROGRESS, IN_PROGRESS], "two IN_PROGRESS")
    assert camera.stats.designations == 1
    assert camera.take() is not None and camera.take() is None
    # a retry while it is being confirmed: still one
    fake.command(f"{TRACK_POINT},param1=0.3,param2=0.3")
    wait_results(fake, TRACK_POINT, [IN_PROGRESS] * 3, "third IN_PROGRESS")
    assert camera.take() is None and camera.confirming
    # another point supersedes it: the first FAILED, the new one IN_PROGRESS
    fake.command(f"{TRACK_POINT},param1=0.6,param2=0.6")
    wait_results(fake, TRACK_POINT, [IN_PROGRESS] * 3 + [FAILED, IN_PROGRESS], "superseded")
    assert camera.take().center == pytest.approx((0.6, 0.6))
    # STOP_TRACKING: the one being confirmed FAILED, stop ACCEPTED, the loop gets a stop
    fake.command(str(STOP_TRACKING))
    wait_results(fake, STOP_TRACKING, [ACCEPTED], "STOP_TRACKING accepted")
    assert results(fake, TRACK_POINT)[-1] == FAILED
    assert camera.take().stop and not camera.confirming
    assert camera.after_frame(True) is None  # nothing left to confirm
    # many in a burst: each answered, the newest wins
    for i in range(20):
        fake.command(f"{TRACK_POINT},param1={0.02 * i + 0.1:.2f},param2=0.5")
    wait_for(lambda: len(results(fake, TRACK_POINT)) >= 6 + 20 + 19, 5.0, "every burst command answered")
    assert camera.take().center == pytest.approx((0.48, 0.5)) and camera.take() is None


@pytest.mark.parametrize("action, why", [
    (f"{TRACK_POINT},param1=1.5,param2=0.5", "x outside the image"),
    (f"{TRACK_POINT},param1=0.5,param2=-0.1", "y outside the image"),
    (f"{TRACK_POINT},param1=0.5,param2=0.5,param3=2", "radius beyond the image"),
    (f"{TRACK_RECTANGLE},param1=0.5,param2=0.5,param3=0.4,param4=0.6", "inverted in x"),
    (f"{TRACK_RECTANGLE},param1=0.2,param2=0.6,param3=0.4,param4=0.5", "inverted in y"),
    (f"{TRACK_RECTANGLE},param1=0.2,param2=0.2,param3=0.2,param4=0.5", "empty"),
    (f"{TRACK_RECTANGLE},param1=0.2,param2=0.2,param3=1.2,param4=0.5", "beyond the image"),
])
def test_bad_track_parameters_are_denied(rig, action, why):
    fake, link, camera = rig
    fake.command(action)
    command = int(action.split(",")[0])
    wait_results(fake, command, [DENIED], why)
    assert camera.take() is None and camera.stats.denied == 1


def test_track_commands_from_others_nan_or_while_disabled_do_nothing(rig):
    fake, link, camera = rig
    # not an allowed system id: ignored (no ACK), as every command
    fake.command(f"{TRACK_POINT},param1=0.5,param2=0.5,sysid=42")
    # NaN parameter: dropped at the link's door (no ACK)
    fake.command(f"{TRACK_POINT},param1=nan,param2=0.5")
    fake.command(f"{TRACK_RECTANGLE},param1=0.1,param2=0.1,param3=inf,param4=0.5")
    wait_for(lambda: link.status.commands_ignored == 1 and link.status.nonfinite == 2, 5.0, "ignored and dropped")
    time.sleep(0.3)
    assert results(fake, TRACK_POINT) == [] and results(fake, TRACK_RECTANGLE) == []
    assert camera.take() is None and camera.stats.designations == 0
    # detection disabled by command: TEMPORARILY_REJECTED
    fake.command("disable")
    wait_for(lambda: not link.detection_enabled, 5.0, "disabled")
    fake.command(f"{TRACK_POINT},param1=0.5,param2=0.5")
    wait_results(fake, TRACK_POINT, [TEMPORARILY_REJECTED], "rejected while disabled")
    assert camera.take() is None
    # a designation in progress when detection is disabled is cancelled (the service does this)
    fake.command("enable")
    wait_for(lambda: link.detection_enabled, 5.0, "enabled")
    fake.command(f"{TRACK_POINT},param1=0.5,param2=0.5")
    wait_results(fake, TRACK_POINT, [TEMPORARILY_REJECTED, IN_PROGRESS], "accepted when enabled")
    camera.cancel("detection disabled by command")
    wait_results(fake, TRACK_POINT, [TEMPORARILY_REJECTED, IN_PROGRESS, FAILED], "cancelled")
    assert camera.take() is None


def test_message_interval_for_the_tracking_status(rig):
    fake, link, camera = rig
    with Payload(link, link.cfg.outputs) as payload:  # 20 Hz of scripted targets
        payload.publisher.camera = camera
        fake.command(f"{SET_INTERVAL},param1={TRACKING_IMAGE_STATUS},param2=-1")
        wait_results(fake, SET_INTERVAL, [ACCEPTED], "interval -1 accepted")
        time.sleep(0.3)
        n_off = len(fake.rows("CAMERA_TRACKING_IMAGE_STATUS"))
        time.sleep(1.0)
        assert len(fake.rows("CAMERA_TRACKING_IMAGE_STATUS")) == n_off
        assert len(fake.rows("DEBUG_VECT")) > 5  # the other outputs go on
        # REQUEST_MESSAGE for it: one, even while off
        fake.command(f"{REQUEST_MESSAGE},param1={TRACKING_IMAGE_STATUS}")
        wait_for(lambda: len(fake.rows("CAMERA_TRACKING_IMAGE_STATUS")) == n_off + 1, 3.0, "the requested status")
        fake.command(f"{SET_INTERVAL},param1={TRACKING_IMAGE_STATUS},param2=500000")  # 2 Hz
        wait_results(fake, SET_INTERVAL, [ACCEPTED, ACCEPTED], "interval 0.5 s accepted")
        t0 = time.monotonic()
        time.sleep(2.1)
        rows = [r for r in fake.rows("CAMERA_TRACKING_IMAGE_STATUS") if r["t"] > t0 + 0.05 and r["t"] < t0 + 2.05]
        assert 3 <= len(rows) <= 5, len(rows)  # idle statuses too: at most one a second, within the 2 Hz
        fake.command(f"{SET_INTERVAL},param1={TRACKING_IMAGE_STATUS},param2=0")  # back to every frame
        fake.command(f"{SET_INTERVAL},param1=30,param2=1000")  # ATTITUDE: not ours to stream
        fake.command(f"{SET_INTERVAL},param1={TRACKING_IMAGE_STATUS},param2=-7")
        wait_results(fake, SET_INTERVAL, [ACCEPTED, ACCEPTED, ACCEPTED, DENIED, DENIED], "interval guards")
        t1 = time.monotonic()
        time.sleep(1.0)
        assert len([r for r in fake.rows("CAMERA_TRACKING_IMAGE_STATUS") if r["t"] > t1 + 0.1]) >= 8
        assert camera.interval_us(TRACKING_IMAGE_STATUS) == 0
    assert not payload.errors


# --- geo -------------------------------------------------------------------------------------------


def test_range_and_position_of_a_target_of_known_geometry():
    cam = CameraModel.from_hfov(60.0, (1280, 720))
    f = cam.matrix[0, 0]
    # a 0.5 m drone 100 m away looks 0.5 f / 100 px across; east of a vehicle heading east, 10 m above it
    size = 0.5 * f / 100.0
    r, sigma = range_from_size(size, f, 0.5, 1.5, 0.0)
    assert r == pytest.approx(100.0) and sigma == pytest.approx(100.0 * 1.5 / size)
    el = math.asin(10.0 / 100.0)
    v = 720 / 2.0 - f * math.tan(el)  # image y of that elevation (level camera)
    target = Target(0, 0, np.array([640 - size / 2, v - size / 2, 640 + size / 2, v + size / 2]), 0.9, "LAD", True)
    geo = locate(target, cam, mount_rotation(), Attitude(0.0, 0.0, math.pi / 2), HOME, 0.5, 1.5, 0.2)
    ned = ned_between(HOME, Position(geo.lat_deg, geo.lon_deg, geo.alt_m))
    assert ned == pytest.approx([0.0, 100.0 * math.cos(el), -10.0], abs=0.05)
    assert geo.range_m == pytest.approx(100.0) and geo.h_acc_m > geo.v_acc_m > 0
    # too small a box: the model withholds it (and counts)
    model = GeoModel(camera_config(**{"target.span_m": 0.5, "target.max_relative_uncertainty": 0.3}).target,
                     BearingModel(camera_config(**{"camera.hfov_deg": 60.0}).camera))
    assert model.locate(target, (1280, 720), Attitude(0.0, 0.0, 1.0), HOME) is None  # 5.5 px: 34 %
    assert model.uncertain == 1
    target = Target(0, 0, np.array([600.0, 300.0, 620.0, 310.0]), 0.9, "LAD", True)  # 20 px: 21 %
    assert model.locate(target, (1280, 720), Attitude(0.0, 0.0, 1.0), HOME) is not None
    tiny = Target(0, 0, np.array([600.0, 300.0, 603.0, 302.0]), 0.9, "LAD", True)
    assert model.locate(tiny, (1280, 720), Attitude(0.0, 0.0, 1.0), HOME) is None and model.uncertain == 2
    assert model.locate(target, (1280, 720), None, HOME) is None and model.no_pose == 1
    assert model.locate(target, (1280, 720), Attitude(0.0, 0.0, 1.0), Position(float("nan"), 8.0, 400.0)) is None
    assert model.no_pose == 2


def test_position_stream_and_geo_messages(fakes, tmp_path):
    port = free_port()
    fake = start_fake(fakes, tmp_path, f"udpin:127.0.0.1:{port}")
    cfg = camera_config(**{"mavlink.outputs.follow_target": True, "mavlink.outputs.follow_target_sysid": 2,
                           "target.span_m": 0.5})
    link = MavlinkLink(link_cfg(f"udpout:127.0.0.1:{port}", attitude_rate_hz=20.0))
    link.position_rate_hz = 10.0
    publisher = TargetPublisher(link, cfg.mavlink.outputs)
    with link:
        wait_for(lambda: link.position_at(time.monotonic_ns()), 10.0, "GLOBAL_POSITION_INT at 10 Hz")
        reqs = [r["fields"] for r in fake.rows("COMMAND_LONG") if r["fields"]["command"] == SET_INTERVAL]
        assert [(r["param1"], r["param2"]) for r in reqs] == [(30, 50000), (33, 100000)]  # ATTITUDE, then position
        # the fake flies east at 2 m/s from its HOME, 30 m up: the interpolated position follows it
        t = time.monotonic_ns()
        pos = link.position_at(t)
        ned = ned_between(HOME, pos)
        assert ned[2] == pytest.approx(-30.0, abs=0.01)
        assert ned[1] == pytest.approx(2.0 * (t - fake.start_ns) / 1e9, abs=0.3)
        assert link.position_at(t - 10_000_000_000) is None  # long before the buffer
        geo = TargetGeo(t, 80.0, 8.0, 47.4, 8.55, 500.0, 6.0, 3.0)
        target = Target(0, t, np.array([100.0, 100.0, 120.0, 110.0]), 0.8, "LAD", True)
        publisher.publish(target, None, (960, 540), geo)
        bad = TargetGeo(t, 80.0, 8.0, float("nan"), 8.55, 500.0, 6.0, 3.0)
        publisher.publish(target, None, (960, 540), bad)
        gs = wait_for(lambda: fake.rows("CAMERA_TRACKING_GEO_STATUS"), 3.0, "CAMERA_TRACKING_GEO_STATUS")
        ft = wait_for(lambda: fake.rows("FOLLOW_TARGET"), 3.0, "FOLLOW_TARGET")
        time.sleep(0.3)
    assert len(fake.rows("CAMERA_TRACKING_GEO_STATUS")) == 1 and len(fake.rows("FOLLOW_TARGET")) == 1
    assert publisher.stats.not_finite == 2  # the NaN geo: neither message
    g = gs[0]["fields"]
    assert (g["lat"], g["lon"], g["alt"], g["dist"]) == (474000000, 85500000, 500.0, 80.0)
    assert g["h_acc"] == 6.0 and g["v_acc"] == 3.0 and g["tracking_status"] == 1
    f = ft[0]
    assert f["sysid"] == 2 and f["fields"]["est_capabilities"] == 1
    assert (f["fields"]["lat"], f["fields"]["lon"], f["fields"]["alt"]) == (474000000, 85500000, 500.0)
    assert f["fields"]["position_cov"] == [36.0, 36.0, 9.0]
    # our own messages still come from our system id
    assert {r["sysid"] for r in fake.rows("HEARTBEAT") if r["compid"] == 100} == {1}


def test_signing_rules_hold_for_camera_commands(fakes, tmp_path):
    fake, link = signed_fake(fakes, tmp_path)
    camera = CameraProtocol(link, camera_config(), None)
    with link:
        wait_for(lambda: link.status.autopilot_seen, 10.0, "signed autopilot")
        fake.command(f"{TRACK_POINT},param1=0.5,param2=0.5,unsigned")
        fake.command(f"{TRACK_POINT},param1=0.5,param2=0.5,badkey")
        fake.command(f"{REQUEST_MESSAGE},param1={CAMERA_INFORMATION},unsigned")
        wait_for(lambda: link.status.rejected >= 3, 5.0, "three rejected")
        time.sleep(0.3)
        assert results(fake, TRACK_POINT) == [] and not fake.rows("CAMERA_INFORMATION") and camera.take() is None
        fake.command(f"{TRACK_POINT},param1=0.5,param2=0.5")
        wait_results(fake, TRACK_POINT, [IN_PROGRESS], "the signed one")
        replayed = len([r for r in fake.rows() if r.get("dir") == "out" and r["type"] == "COMMAND_LONG"]) - 1
        assert camera.take() is not None
        fake.command(f"replay,{replayed}")  # the same bytes again: refused by the signature's timestamp
        time.sleep(0.8)
        assert results(fake, TRACK_POINT) == [IN_PROGRESS] and camera.take() is None

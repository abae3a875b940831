"""Pixel -> bearing geometry against hand-computed cases."""

import math

import cv2
import numpy as np
import pytest

from payload.config import CameraConfig, MountConfig
from payload.geometry import (
    Attitude,
    BearingModel,
    CameraModel,
    az_el,
    bearing_for,
    body_to_level,
    mount_from_config,
    mount_rotation,
)
from payload.types import Target

W, H = 1920, 1080


def target_at(u, v, half=5.0, score=0.8):
    return Target(
        frame_index=7,
        t_capture_ns=123456789,
        xyxy=np.array([u - half, v - half, u + half, v + half], np.float32),
        score=score,
        module="LAD",
        measured=True,
    )


@pytest.fixture
def camera():
    return CameraModel.from_config(CameraConfig(hfov_deg=80.0), (W, H))


def test_centre_pixel_is_straight_ahead(camera):
    b = bearing_for(target_at(W / 2, H / 2), camera, mount_rotation(), None)
    assert b.az_body_rad == pytest.approx(0.0, abs=1e-9)
    assert b.el_body_rad == pytest.approx(0.0, abs=1e-9)
    assert b.az_level_rad is None and b.el_level_rad is None
    assert b.confidence == pytest.approx(0.8)
    assert b.t_capture_ns == 123456789


@pytest.mark.parametrize("u, sign", [(0.0, -1.0), (float(W), 1.0)])
def test_edge_pixel_is_half_hfov(camera, u, sign):
    ray = camera.pixel_to_ray_cam(u, H / 2)
    az, el = az_el(mount_rotation() @ ray)
    assert az == pytest.approx(sign * math.radians(40.0), abs=1e-9)
    assert el == pytest.approx(0.0, abs=1e-9)
    assert camera.hfov_rad == pytest.approx(math.radians(80.0))


def test_square_pixels_top_edge_elevation(camera):
    # f = 960 / tan(40 deg); top edge is 540 px above the centre: el = atan(540 / f), positive up.
    f = 960.0 / math.tan(math.radians(40.0))
    az, el = az_el(mount_rotation() @ camera.pixel_to_ray_cam(W / 2, 0.0))
    assert az == pytest.approx(0.0, abs=1e-9)
    assert el == pytest.approx(math.atan(540.0 / f), abs=1e-9)


def test_explicit_matrix_is_used():
    cam = CameraModel.from_config(CameraConfig(matrix=(1000.0, 1000.0, 959.5, 539.5)), (W, H))
    # 1000 px right of the principal point at focal 1000 px: 45 degrees.
    az, el = az_el(mount_rotation() @ cam.pixel_to_ray_cam(959.5 + 0.5 + 1000.0, 540.0))
    assert az == pytest.approx(math.radians(45.0), abs=1e-9)
    assert el == pytest.approx(0.0, abs=1e-9)


def test_mount_yawed_90_looks_right(camera):
    r = mount_from_config(MountConfig(yaw_deg=90.0))
    assert az_el(r @ camera.pixel_to_ray_cam(W / 2, H / 2)) == pytest.approx((math.pi / 2, 0.0), abs=1e-9)
    # image right of a right-looking camera points backwards: azimuth beyond 90 deg
    az, _ = az_el(r @ camera.pixel_to_ray_cam(W, H / 2))
    assert az == pytest.approx(math.radians(130.0), abs=1e-9)


def test_mount_pitched_down_90_looks_down(camera):
    r = mount_rotation(pitch_deg=-90.0)
    ray = r @ camera.pixel_to_ray_cam(W / 2, H / 2)
    np.testing.assert_allclose(ray, [0.0, 0.0, 1.0], atol=1e-12)
    _, el = az_el(ray)
    assert el == pytest.approx(-math.pi / 2)
    # image top of a down-looking camera is body forward: pixel above centre -> +x
    ray_top = r @ camera.pixel_to_ray_cam(W / 2, 0.0)
    assert ray_top[0] > 0.3 and abs(ray_top[1]) < 1e-12


def test_mount_roll_90_turns_image_right_into_down(camera):
    # camera rolled 90 deg right: image right (+x cam) points body down
    r = mount_rotation(roll_deg=90.0)
    ray = r @ camera.pixel_to_ray_cam(W, H / 2)
    az, el = az_el(ray)
    assert az == pytest.approx(0.0, abs=1e-9)
    assert el == pytest.approx(-math.radians(40.0), abs=1e-9)


def test_pitched_vehicle_level_elevation(camera):
    # Nose up 10 deg: the image centre looks 10 deg above the horizon, same heading.
    b = bearing_for(target_at(W / 2, H / 2), camera, mount_rotation(), Attitude(0.0, math.radians(10.0), 1.2))
    assert b.el_body_rad == pytest.approx(0.0, abs=1e-9)
    assert b.el_level_rad == pytest.approx(math.radians(10.0), abs=1e-9)
    assert b.az_level_rad == pytest.approx(0.0, abs=1e-9)  # yaw is not removed: heading-referenced


def test_rolled_vehicle_level_angles(camera):
    # Rolled 30 deg right, target 20 deg right of the nose in the body frame (on the body y axis side):
    # body ray (cos20, sin20, 0) -> level (cos20, sin20*cos30, sin20*sin30): below the horizon.
    f = 960.0 / math.tan(math.radians(40.0))
    u = W / 2 + f * math.tan(math.radians(20.0))
    b = bearing_for(target_at(u, H / 2), camera, mount_rotation(), Attitude(math.radians(30.0), 0.0, 0.0))
    assert b.az_body_rad == pytest.approx(math.radians(20.0), abs=1e-6)  # float32 box
    s20, c20 = math.sin(math.radians(20.0)), math.cos(math.radians(20.0))
    x, y, z = c20, s20 * math.cos(math.radians(30.0)), s20 * math.sin(math.radians(30.0))
    assert b.az_level_rad == pytest.approx(math.atan2(y, x), abs=1e-6)
    assert b.el_level_rad == pytest.approx(math.atan2(-z, math.hypot(x, y)), abs=1e-6)
    assert b.el_level_rad < 0


def test_body_to_level_keeps_gravity_down():
    att = Attitude(math.radians(25.0), math.radians(-15.0), math.radians(170.0))
    # gravity in body coordinates, rotated back to level, points straight down
    r = body_to_level(att)
    g_body = r.T @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(r @ g_body, [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)


@pytest.mark.parametrize("u, v", [(W / 2, H / 2), (100.0, 80.0), (1800.0, 1000.0), (300.0, 900.0), (1500.0, 200.0)])
def test_distortion_round_trip(u, v):
    cfg = CameraConfig(matrix=(1100.0, 1095.0, 955.0, 545.0), distortion=[-0.28, 0.09, 0.001, -0.0005, -0.012])
    cam = CameraModel.from_config(cfg, (W, H))
    ray = cam.pixel_to_ray_cam(u, v)
    assert np.linalg.norm(ray) == pytest.approx(1.0)
    # OpenCV's own forward model (projection with distortion) brings the ray back to the pixel
    uv, _ = cv2.projectPoints(ray.reshape(1, 1, 3), np.zeros(3), np.zeros(3), cam.matrix, cam.distortion)
    assert (uv[0, 0, 0] + 0.5, uv[0, 0, 1] + 0.5) == pytest.approx((u, v), abs=1e-3)


def test_distortion_changes_the_ray():
    plain = CameraModel.from_config(CameraConfig(matrix=(1100.0, 1100.0, 959.5, 539.5)), (W, H))
    dist = CameraModel.from_config(
        CameraConfig(matrix=(1100.0, 1100.0, 959.5, 539.5), distortion=[-0.28, 0.09, 0.0, 0.0, 0.0]), (W, H)
    )
    # barrel distortion squeezes the edges: the true ray at an edge pixel is farther out
    az_plain, _ = az_el(mount_rotation() @ plain.pixel_to_ray_cam(1900.0, 540.0))
    az_dist, _ = az_el(mount_rotation() @ dist.pixel_to_ray_cam(1900.0, 540.0))
    assert az_dist > az_plain + math.radians(2.0)


@pytest.mark.parametrize("attitude", [Attitude(math.nan, 0.0, 0.0), Attitude(0.0, math.inf, 0.0),
                                      Attitude(0.0, 0.0, -math.inf)])
def test_non_finite_attitude_gives_body_angles_only(attitude):
    model = BearingModel(CameraConfig())
    bearing = model.bearing(target_at(700, 200), (1280, 720), attitude)
    assert math.isfinite(bearing.az_body_rad) and math.isfinite(bearing.el_body_rad)
    assert bearing.az_level_rad is None and bearing.el_level_rad is None
    assert model.attitude_not_finite == 1 and model.bearing_not_finite == 0


def test_non_finite_target_gives_no_bearing():
    model = BearingModel(CameraConfig())
    assert model.bearing(target_at(math.nan, 200), (1280, 720), Attitude(0.1, 0.0, 0.0)) is None
    assert model.bearing_not_finite == 1


def test_bearing_model_applies_a_reloaded_camera_section():
    model = BearingModel(CameraConfig())
    before = model.bearing(target_at(1000, 360), (1280, 720), None).az_body_rad
    new = CameraConfig(hfov_deg=40.0, mount=MountConfig(yaw_deg=10.0))
    assert model.apply(new) == ["camera.hfov_deg", "camera.mount.yaw_deg"]
    after = model.bearing(target_at(1000, 360), (1280, 720), None).az_body_rad
    assert after != before and model.camera((1280, 720)).hfov_rad == pytest.approx(math.radians(40.0))

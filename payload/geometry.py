"""Pixel -> bearing: pure functions from a box centre to azimuth/elevation angles.

Frames and signs (all right-handed):

- camera: x right, y down, z forward (OpenCV).
- body: FRD, x forward, y right, z down (MAVLink/aircraft).
- level: the body frame with roll and pitch removed; x is the vehicle heading projected on
  the horizon, z points down along gravity (yaw-referenced, so not north-referenced).

Azimuth is ``atan2(y, x)`` (positive to the right), elevation ``atan2(-z, hypot(x, y))``
(positive up), both in radians.

Pixel coordinates are continuous, as in ``Detections.xyxy``: pixel column i covers
[i, i + 1), so the image centre of a W-wide image is at x = W / 2. OpenCV camera matrices
put pixel *centres* on integers, so half a pixel is subtracted before undistorting.
"""

import math
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import cv2
import numpy as np

from payload.config import CameraConfig, MountConfig, section_changes
from payload.types import Bearing, Target

#: Fixed axis swap camera (x right, y down, z forward) -> body FRD for a camera looking
#: straight ahead: body x = camera z, body y = camera x, body z = camera y.
_CAM_TO_BODY_ZERO_MOUNT = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

# undistortPoints iterates a fixed 5 times by default, which leaves pixel-level errors at the
# edge of wide-angle lenses; these criteria converge to well under 1e-3 px.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)


@dataclass(frozen=True)
class Attitude:
    """Vehicle attitude (MAVLink ATTITUDE): Z-Y-X Euler angles of body FRD in NED, radians."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float

    @property
    def finite(self) -> bool:
        return all(math.isfinite(a) for a in (self.roll_rad, self.pitch_rad, self.yaw_rad))


def rotation_zyx(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """R = Rz(yaw) @ Ry(pitch) @ Rx(roll): rotates vectors from the rotated frame to the reference frame."""
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def mount_rotation(roll_deg: float = 0.0, pitch_deg: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    """Camera -> body FRD rotation (3x3) for a camera mounted at roll/pitch/yaw relative to the body.

    Zero mount = camera looking forward along body x, image right = body right. The angles
    are applied like a vehicle attitude (Z-Y-X): yaw_deg=90 looks right, pitch_deg=-90 looks
    straight down, roll_deg turns the image about the optical axis.
    """
    r_mount = rotation_zyx(math.radians(roll_deg), math.radians(pitch_deg), math.radians(yaw_deg))
    return r_mount @ _CAM_TO_BODY_ZERO_MOUNT


def mount_from_config(mount: MountConfig) -> np.ndarray:
    """``mount_rotation`` for the ``camera.mount`` config section."""
    return mount_rotation(mount.roll_deg, mount.pitch_deg, mount.yaw_deg)


def body_to_level(attitude: Attitude) -> np.ndarray:
    """Rotation body FRD -> level frame: roll and pitch removed, heading kept as x."""
    return rotation_zyx(attitude.roll_rad, attitude.pitch_rad, 0.0)


def az_el(vector: Sequence[float]) -> Tuple[float, float]:
    """(azimuth, elevation) in radians of a FRD-style vector: az positive right, el positive up."""
    x, y, z = (float(c) for c in vector)
    return math.atan2(y, x), math.atan2(-z, math.hypot(x, y))


@dataclass(frozen=True)
class CameraModel:
    """Pinhole intrinsics (OpenCV convention) plus optional OpenCV distortion coefficients."""

    matrix: np.ndarray  # 3x3, pixel centres on integers
    distortion: Optional[np.ndarray]  # k1, k2, p1, p2[, k3...] or None
    image_wh: Tuple[int, int]

    @classmethod
    def from_hfov(cls, hfov_deg: float, image_wh: Tuple[int, int]) -> "CameraModel":
        """Square pixels, principal point at the image centre, no distortion."""
        w, h = int(image_wh[0]), int(image_wh[1])
        f_px = (w / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        k = np.array([[f_px, 0.0, (w - 1) / 2.0], [0.0, f_px, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
        return cls(k, None, (w, h))

    @classmethod
    def from_config(cls, cfg: CameraConfig, image_wh: Tuple[int, int]) -> "CameraModel":
        """``camera.matrix`` [fx, fy, cx, cy] when set (OpenCV calibration values), else ``camera.hfov_deg``."""
        if cfg.matrix is None:
            model = cls.from_hfov(cfg.hfov_deg, image_wh)
            k = model.matrix
        else:
            fx, fy, cx, cy = cfg.matrix
            k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        dist = None if cfg.distortion is None else np.asarray(cfg.distortion, np.float64)
        return cls(k, dist, (int(image_wh[0]), int(image_wh[1])))

    @property
    def hfov_rad(self) -> float:
        """Horizontal field of view edge to edge (ignoring distortion)."""
        w = self.image_wh[0]
        fx, cx = self.matrix[0, 0], self.matrix[0, 2]
        return math.atan2(cx + 0.5, fx) + math.atan2(w - 0.5 - cx, fx)

    def pixel_to_ray_cam(self, u: float, v: float) -> np.ndarray:
        """Unit ray (camera frame) through the continuous pixel position (u, v)."""
        src = np.array([[[u - 0.5, v - 0.5]]], np.float64)
        if self.distortion is None:
            xy = cv2.undistortPoints(src, self.matrix, None)
        elif hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
            xy = cv2.undistortPointsIter(src, self.matrix, self.distortion, None, None, _UNDISTORT_CRITERIA)
        else:  # OpenCV 5 folded the criteria into undistortPoints
            xy = cv2.undistortPoints(src, self.matrix, self.distortion, None, None, None, _UNDISTORT_CRITERIA)
        ray = np.array([xy[0, 0, 0], xy[0, 0, 1], 1.0])
        return ray / np.linalg.norm(ray)



def bearing_for(
    target: Target,
    camera: CameraModel,
    mount: np.ndarray,
    attitude: Optional[Attitude],
) -> Bearing:
    """The bearing to the target's box centre.

    ``mount`` is the camera -> body rotation from ``mount_rotation``/``mount_from_config``;
    ``attitude`` is the vehicle attitude at the frame's capture time (None, or not finite: level
    angles None). Confidence is the target's score.
    """
    u, v = target.center
    ray_body = np.asarray(mount, np.float64) @ camera.pixel_to_ray_cam(u, v)
    az_body, el_body = az_el(ray_body)
    az_level = el_level = None
    if attitude is not None and attitude.finite:
        az_level, el_level = az_el(body_to_level(attitude) @ ray_body)
    return Bearing(
        t_capture_ns=int(target.t_capture_ns),
        az_body_rad=az_body,
        el_body_rad=el_body,
        az_level_rad=az_level,
        el_level_rad=el_level,
        confidence=float(target.score),
    )


def _finite(*values: Optional[float]) -> bool:
    return all(v is None or math.isfinite(v) for v in values)


class BearingModel:
    """The ``camera`` section at work: target -> bearing for frames of any size, at the attitude
    of capture time. A bearing is never handed on with a value that is not finite: a non-finite
    attitude (a broken or hostile ATTITUDE message) gives body-frame angles only, a non-finite
    body bearing gives none; both are counted."""

    def __init__(self, cfg: CameraConfig) -> None:
        self.cfg = cfg
        self.mount = mount_from_config(cfg.mount)
        self._camera: Optional[CameraModel] = None
        self.attitude_not_finite = 0  # attitudes dropped: level angles withheld
        self.bearing_not_finite = 0  # bearings withheld

    def apply(self, cfg: CameraConfig) -> List[str]:
        """Take a reloaded ``camera`` section from the next frame on; returns the keys applied."""
        keys = section_changes(self.cfg, cfg, "camera")
        self.cfg = cfg
        self.mount = mount_from_config(cfg.mount)
        self._camera = None  # rebuilt for the next frame's size
        return keys

    def camera(self, image_wh: Tuple[int, int]) -> CameraModel:
        if self._camera is None or self._camera.image_wh != tuple(image_wh):
            self._camera = CameraModel.from_config(self.cfg, image_wh)
        return self._camera

    def bearing(self, target: Target, image_wh: Tuple[int, int], attitude: Optional[Attitude]) -> Optional[Bearing]:
        if attitude is not None and not attitude.finite:
            self.attitude_not_finite += 1
            attitude = None
        bearing = bearing_for(target, self.camera(image_wh), self.mount, attitude)
        if not _finite(bearing.az_body_rad, bearing.el_body_rad, bearing.az_level_rad, bearing.el_level_rad,
                       bearing.confidence):
            self.bearing_not_finite += 1
            return None
        return bearing


# --- range and position ------------------------------------------------------------------------
#
# A drone of known span S (metres, rotor tip to rotor tip) that looks s pixels across through a
# lens of focal length f pixels is at range r = S f / s. Its size in the image is uncertain by
# the box's own noise (sigma_px, a pixel or two from the detector) and by its pose and motion
# blur (a relative error: a drone seen end-on is narrower than its span, a blurred one wider),
# so sigma_r / r = hypot(sigma_px / s, shape). With the vehicle's position and attitude at
# capture time the target lies r along the bearing's ray.

#: WGS-84 equatorial radius; a flat earth around the vehicle is exact to well under a metre at
#: the few hundred metres a drone can be seen at.
_EARTH_RADIUS_M = 6378137.0


@dataclass(frozen=True)
class Position:
    """The vehicle's position (MAVLink GLOBAL_POSITION_INT): degrees, metres above mean sea level."""

    lat_deg: float
    lon_deg: float
    alt_m: float

    @property
    def finite(self) -> bool:
        return all(math.isfinite(v) for v in (self.lat_deg, self.lon_deg, self.alt_m))


@dataclass(frozen=True)
class TargetGeo:
    """Where the target is: range along its bearing and, from the vehicle's position, lat/lon/alt."""

    t_capture_ns: int
    range_m: float
    range_sigma_m: float
    lat_deg: float
    lon_deg: float
    alt_m: float  # above mean sea level
    h_acc_m: float  # 1 sigma, horizontal
    v_acc_m: float  # 1 sigma, vertical

    @property
    def relative_uncertainty(self) -> float:
        return self.range_sigma_m / self.range_m


def apparent_size_px(xyxy: Sequence[float]) -> float:
    """The box's longer side: a drone's span shows as its width seen from the side and from below."""
    x1, y1, x2, y2 = (float(c) for c in xyxy)
    return max(x2 - x1, y2 - y1)


def range_from_size(size_px: float, focal_px: float, span_m: float, size_noise_px: float,
                    shape_uncertainty: float) -> Tuple[float, float]:
    """(range, 1-sigma range error) in metres of a drone ``span_m`` across that looks ``size_px``
    across; (nan, nan) for a box without size."""
    if not size_px > 0:
        return float("nan"), float("nan")
    r = span_m * focal_px / size_px
    return r, r * math.hypot(size_noise_px / size_px, shape_uncertainty)


def offset_position(origin: Position, ned_m: Sequence[float]) -> Position:
    """The position ``ned_m`` (north, east, down; metres) away from ``origin``."""
    n, e, d = (float(c) for c in ned_m)
    lat = origin.lat_deg + math.degrees(n / _EARTH_RADIUS_M)
    lon = origin.lon_deg + math.degrees(e / (_EARTH_RADIUS_M * math.cos(math.radians(origin.lat_deg))))
    return Position(lat, lon, origin.alt_m - d)


def ned_between(origin: Position, other: Position) -> np.ndarray:
    """Inverse of ``offset_position``: (north, east, down) metres from ``origin`` to ``other``."""
    n = math.radians(other.lat_deg - origin.lat_deg) * _EARTH_RADIUS_M
    e = math.radians(other.lon_deg - origin.lon_deg) * _EARTH_RADIUS_M * math.cos(math.radians(origin.lat_deg))
    return np.array([n, e, origin.alt_m - other.alt_m])


def locate(target: Target, camera: CameraModel, mount: np.ndarray, attitude: Attitude, position: Position,
           span_m: float, size_noise_px: float, shape_uncertainty: float) -> TargetGeo:
    """The target's position from its box (range from size, direction from centre), the vehicle's
    attitude and position at capture time. Values may be non-finite: the caller checks."""
    focal_px = float(camera.matrix[0, 0] + camera.matrix[1, 1]) / 2.0
    r, sigma_r = range_from_size(apparent_size_px(target.xyxy), focal_px, span_m, size_noise_px, shape_uncertainty)
    u, v = target.center
    ray_ned = rotation_zyx(attitude.roll_rad, attitude.pitch_rad, attitude.yaw_rad) @ (
        np.asarray(mount, np.float64) @ camera.pixel_to_ray_cam(u, v))
    where = offset_position(position, r * ray_ned)
    # across the ray: the box centre's noise as an angle; along it: the range error
    sigma_across = r * size_noise_px / focal_px
    horizontal, vertical = math.hypot(ray_ned[0], ray_ned[1]), abs(float(ray_ned[2]))
    h_acc = math.hypot(sigma_r * horizontal, sigma_across)
    v_acc = math.hypot(sigma_r * vertical, sigma_across)
    return TargetGeo(int(target.t_capture_ns), r, sigma_r, where.lat_deg, where.lon_deg, where.alt_m, h_acc, v_acc)


class GeoModel:
    """The ``target`` section at work: target -> TargetGeo, or None when there is no range
    (no ``target.span_m``), no attitude or position at capture time, a value that is not finite,
    or a range more uncertain than ``target.max_relative_uncertainty`` (each counted)."""

    def __init__(self, cfg, bearings: BearingModel) -> None:
        self.cfg = cfg  # TargetConfig
        self.bearings = bearings
        self.no_pose = 0  # withheld: no attitude or position at capture time
        self.uncertain = 0  # withheld: range too uncertain
        self.not_finite = 0  # withheld: a value not finite

    def apply(self, cfg) -> List[str]:
        keys = section_changes(self.cfg, cfg, "target")
        self.cfg = cfg
        return keys

    @property
    def enabled(self) -> bool:
        return self.cfg.span_m is not None

    def locate(self, target: Target, image_wh: Tuple[int, int], attitude: Optional[Attitude],
               position: Optional[Position]) -> Optional[TargetGeo]:
        cfg = self.cfg
        if cfg.span_m is None or not target.measured:
            return None
        if attitude is None or position is None or not attitude.finite or not position.finite:
            self.no_pose += 1
            return None
        geo = locate(target, self.bearings.camera(image_wh), self.bearings.mount, attitude, position,
                     cfg.span_m, cfg.size_noise_px, cfg.shape_uncertainty)
        if not all(math.isfinite(v) for v in (geo.range_m, geo.range_sigma_m, geo.lat_deg, geo.lon_deg, geo.alt_m,
                                                geo.h_acc_m, geo.v_acc_m)):
            self.not_finite += 1
            return None
        if geo.relative_uncertainty > cfg.max_relative_uncertainty:
            self.uncertain += 1
            return None
        return geo

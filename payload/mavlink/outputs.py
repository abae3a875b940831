"""Target and bearing -> MAVLink messages, one switch per message in ``mavlink.outputs``.

Per processed frame the service calls ``TargetPublisher.publish(target, bearing, image_wh)``:

- CAMERA_TRACKING_IMAGE_STATUS (``tracking_image_status``): tracking_mode RECTANGLE,
  rec_top_x/y and rec_bottom_x/y = the box normalised to 0..1 of the image, point_x/y = its
  centre, radius NaN, target_data IN_STATUS. tracking_status is ACTIVE for a measured target
  and ACTIVE|COASTING (the MAVLink flag "target is obscured and is being predicted") when the
  box is the search region's prediction. No target: IDLE, all fields NaN, sent when the
  target is lost and then at most once a second.
- DEBUG_VECT "TGT_BRG" (``debug_vect``): x = azimuth, y = elevation (rad), z = confidence,
  time_usec = the frame's capture time in the autopilot's time base (``link.time_usec_for``).
  Frame per ``debug_vect_frame``: body (FRD) or level; in level frame it is withheld while
  no attitude is known. Not sent without a target.
- CAMERA_TRACKING_GEO_STATUS (``tracking_geo_status``): the target's lat/lon/alt, h_acc/v_acc
  and dist from its range (``payload.geometry.GeoModel``); only when the service gives a geo
  (``target.span_m`` set, vehicle position and attitude at capture time, uncertainty within
  ``target.max_relative_uncertainty``), else withheld. Velocity and heading: NaN (unknown).
- FOLLOW_TARGET (``follow_target``, opt-in): the same position (est_capabilities POS), sent as
  system ``follow_target_sysid`` so that an autopilot follow mode can chase it (a WARNING is
  logged at start).
- LANDING_TARGET (``landing_target``, opt-in): frame MAV_FRAME_BODY_FRD, angle_x = azimuth
  (positive right), angle_y = -elevation (positive down, like image y), distance 0 = unknown,
  size 0. A precision-landing autopilot may steer toward it: a WARNING is logged at start.

The camera protocol (``payload.mavlink.camera``, ``camera``) may set an interval for the
tracking statuses (MAV_CMD_SET_MESSAGE_INTERVAL: -1 off, > 0 at most that often) and ask for
one CAMERA_TRACKING_IMAGE_STATUS (MAV_CMD_REQUEST_MESSAGE), which goes with the next frame.

``max_rate_hz`` caps target messages per second (0 = every processed frame). While detection
is disabled by command (``link.detection_enabled`` False) nothing is sent. No message goes out
with a value that is not finite, except the NaNs MAVLink defines as "unknown" (the radius, the
IDLE status's fields): such a message is withheld and counted (``stats.not_finite``).
"""

import logging
import math
import time
from dataclasses import dataclass
from typing import List, Optional, Tuple

from payload.config import MavlinkOutputsConfig, section_changes
from payload.geometry import TargetGeo
from payload.mavlink.link import MavlinkLink, constant
from payload.types import Bearing, Target

log = logging.getLogger(__name__)

_NAN = float("nan")
_IDLE_PERIOD_NS = 1_000_000_000
_ACTIVE = constant("CAMERA_TRACKING_STATUS_FLAGS_ACTIVE", 1)
_COASTING = constant("CAMERA_TRACKING_STATUS_FLAGS_COASTING", 8)  # missing in older pymavlink
_IDLE = constant("CAMERA_TRACKING_STATUS_FLAGS_IDLE", 0)
_MODE_RECTANGLE = constant("CAMERA_TRACKING_MODE_RECTANGLE", 2)
_MODE_NONE = constant("CAMERA_TRACKING_MODE_NONE", 0)
_DATA_IN_STATUS = constant("CAMERA_TRACKING_TARGET_DATA_IN_STATUS", 4)
_FRAME_BODY_FRD = constant("MAV_FRAME_BODY_FRD", 12)
_LANDING_VISION = constant("LANDING_TARGET_TYPE_VISION_OTHER", 3)
_MSG_IMAGE_STATUS = constant("MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS", 275)
_MSG_GEO_STATUS = constant("MAVLINK_MSG_ID_CAMERA_TRACKING_GEO_STATUS", 276)
_FOLLOW_POS = 1  # FOLLOW_TARGET est_capabilities: position
DEBUG_VECT_NAME = b"TGT_BRG"


@dataclass
class PublisherStats:
    frames: int = 0  # publish() calls
    messages: int = 0  # messages handed to the link
    rate_limited: int = 0  # frames skipped by max_rate_hz
    disabled: int = 0  # frames skipped while detection is disabled by command
    no_attitude: int = 0  # DEBUG_VECT withheld: level frame asked, no attitude
    not_finite: int = 0  # messages withheld because a value was NaN or infinite
    interval: int = 0  # tracking statuses skipped for a SET_MESSAGE_INTERVAL interval (or -1: off)


class TargetPublisher:
    """Sends the per-frame target messages selected in ``mavlink.outputs`` over a ``MavlinkLink``."""

    def __init__(self, link: MavlinkLink, cfg: MavlinkOutputsConfig):
        self.link = link
        self.cfg = cfg
        self.stats = PublisherStats()
        self._last_target_ns: Optional[int] = None
        self._last_idle_ns: Optional[int] = None
        self._had_target = False
        self._warned_level = False
        self.camera = None  # payload.mavlink.camera.CameraProtocol, set by the service
        self._last_sent_ns = {_MSG_IMAGE_STATUS: None, _MSG_GEO_STATUS: None}
        if cfg.landing_target:
            _warn_landing_target()
        if cfg.follow_target:
            _warn_follow_target()

    def apply(self, cfg: MavlinkOutputsConfig) -> List[str]:
        """Take a reloaded ``mavlink.outputs`` section from the next frame on; returns the keys applied."""
        keys = section_changes(self.cfg, cfg, "mavlink.outputs")
        if cfg.landing_target and not self.cfg.landing_target:
            _warn_landing_target()
        if cfg.follow_target and not self.cfg.follow_target:
            _warn_follow_target()
        self.cfg = cfg
        return keys

    def publish(self, target: Optional[Target], bearing: Optional[Bearing], image_wh: Tuple[int, int],
                geo: Optional[TargetGeo] = None) -> int:
        """Send this frame's messages; returns how many were sent (0 when skipped or the link is down)."""
        with self.link.publishing():
            return self._publish(target, bearing, image_wh, geo)

    def _due(self, msg_id: int, now_ns: int) -> bool:
        """Whether a tracking status may go now under the camera protocol's interval for it."""
        interval_us = self.camera.interval_us(msg_id) if self.camera is not None else 0
        if msg_id == _MSG_IMAGE_STATUS and self.camera is not None and self.camera.status_requested:
            self.camera.status_requested = False
            return True
        last = self._last_sent_ns[msg_id]
        if interval_us < 0 or (interval_us > 0 and last is not None and now_ns - last < interval_us * 1000):
            self.stats.interval += 1
            return False
        return True

    def _publish(self, target: Optional[Target], bearing: Optional[Bearing], image_wh: Tuple[int, int],
                 geo: Optional[TargetGeo] = None) -> int:
        self.stats.frames += 1
        if not self.link.detection_enabled:
            self.stats.disabled += 1
            return 0
        now_ns = time.monotonic_ns()
        if target is None:
            return self._publish_idle(now_ns)
        if self.cfg.max_rate_hz > 0 and self._last_target_ns is not None:
            if now_ns - self._last_target_ns < 1e9 / self.cfg.max_rate_hz:
                self.stats.rate_limited += 1
                return 0
        self._last_target_ns = now_ns
        self._had_target = True
        sent = 0
        if self.cfg.tracking_image_status and self._due(_MSG_IMAGE_STATUS, now_ns):
            self._last_sent_ns[_MSG_IMAGE_STATUS] = now_ns
            sent += self._tracking_status(target, image_wh)
        if geo is not None and self.cfg.tracking_geo_status and self._due(_MSG_GEO_STATUS, now_ns):
            self._last_sent_ns[_MSG_GEO_STATUS] = now_ns
            sent += self._geo_status(geo)
        if geo is not None and self.cfg.follow_target:
            sent += self._follow_target(geo)
        if bearing is not None and self.cfg.debug_vect:
            sent += self._debug_vect(bearing)
        if bearing is not None and self.cfg.landing_target:
            sent += self._landing_target(bearing)
        self.stats.messages += sent
        return sent

    def _publish_idle(self, now_ns: int) -> int:
        if not self.cfg.tracking_image_status:
            return 0
        requested = self.camera is not None and self.camera.status_requested
        due = self._last_idle_ns is None or now_ns - self._last_idle_ns >= _IDLE_PERIOD_NS
        if not (self._had_target or due or requested):
            return 0
        if not self._due(_MSG_IMAGE_STATUS, now_ns):
            return 0  # a lost target's IDLE then goes with the first frame the interval allows
        self._last_sent_ns[_MSG_IMAGE_STATUS] = now_ns
        self._had_target = False
        self._last_idle_ns = now_ns
        ok = self.link.send_message(
            "CAMERA_TRACKING_IMAGE_STATUS",
            tracking_status=_IDLE, tracking_mode=_MODE_NONE, target_data=0,
            point_x=_NAN, point_y=_NAN, radius=_NAN,
            rec_top_x=_NAN, rec_top_y=_NAN, rec_bottom_x=_NAN, rec_bottom_y=_NAN,
        )
        self.stats.messages += int(ok)
        return int(ok)

    def _tracking_status(self, target: Target, image_wh: Tuple[int, int]) -> int:
        w, h = float(image_wh[0]), float(image_wh[1])
        x1, y1, x2, y2 = (float(c) for c in target.xyxy)
        cx, cy = target.center

        def nx(x: float) -> float:
            return min(max(x / w, 0.0), 1.0)

        def ny(y: float) -> float:
            return min(max(y / h, 0.0), 1.0)

        status = _ACTIVE if target.measured else _ACTIVE | _COASTING
        if not _finite(cx, cy, x1, y1, x2, y2):
            self.stats.not_finite += 1
            return 0
        return int(
            self.link.send_message(
                "CAMERA_TRACKING_IMAGE_STATUS",
                tracking_status=status, tracking_mode=_MODE_RECTANGLE, target_data=_DATA_IN_STATUS,
                point_x=nx(cx), point_y=ny(cy), radius=_NAN,
                rec_top_x=nx(x1), rec_top_y=ny(y1), rec_bottom_x=nx(x2), rec_bottom_y=ny(y2),
            )
        )

    def _geo_status(self, geo: TargetGeo) -> int:
        if not _finite(geo.lat_deg, geo.lon_deg, geo.alt_m, geo.h_acc_m, geo.v_acc_m, geo.range_m):
            self.stats.not_finite += 1
            return 0
        # velocity and heading are not estimated: NaN, MAVLink's "unknown"
        return int(
            self.link.send_message(
                "CAMERA_TRACKING_GEO_STATUS",
                tracking_status=_ACTIVE, lat=_deg_e7(geo.lat_deg), lon=_deg_e7(geo.lon_deg), alt=float(geo.alt_m),
                h_acc=float(geo.h_acc_m), v_acc=float(geo.v_acc_m), vel_n=_NAN, vel_e=_NAN, vel_d=_NAN,
                vel_acc=_NAN, dist=float(geo.range_m), hdg=_NAN, hdg_acc=_NAN, camera_device_id=0,
            )
        )

    def _follow_target(self, geo: TargetGeo) -> int:
        if not _finite(geo.lat_deg, geo.lon_deg, geo.alt_m, geo.h_acc_m, geo.v_acc_m):
            self.stats.not_finite += 1
            return 0
        return int(
            self.link.send_message(
                "FOLLOW_TARGET", src_system=self.cfg.follow_target_sysid,
                timestamp=self.link.time_usec_for(geo.t_capture_ns) // 1000, est_capabilities=_FOLLOW_POS,
                lat=_deg_e7(geo.lat_deg), lon=_deg_e7(geo.lon_deg), alt=float(geo.alt_m),
                vel=[0.0, 0.0, 0.0], acc=[0.0, 0.0, 0.0], attitude_q=[1.0, 0.0, 0.0, 0.0], rates=[0.0, 0.0, 0.0],
                position_cov=[float(geo.h_acc_m) ** 2, float(geo.h_acc_m) ** 2, float(geo.v_acc_m) ** 2],
                custom_state=0,
            )
        )

    def _debug_vect(self, bearing: Bearing) -> int:
        if self.cfg.debug_vect_frame == "level":
            if bearing.az_level_rad is None or bearing.el_level_rad is None:
                self.stats.no_attitude += 1
                if not self._warned_level:
                    self._warned_level = True
                    log.warning("DEBUG_VECT withheld: debug_vect_frame=level but no ATTITUDE from the autopilot yet")
                return 0
            az, el = bearing.az_level_rad, bearing.el_level_rad
        else:
            az, el = bearing.az_body_rad, bearing.el_body_rad
        if not _finite(az, el, bearing.confidence):
            self.stats.not_finite += 1
            return 0
        return int(
            self.link.send_message(
                "DEBUG_VECT",
                name=DEBUG_VECT_NAME, time_usec=self.link.time_usec_for(bearing.t_capture_ns),
                x=float(az), y=float(el), z=float(bearing.confidence),
            )
        )

    def _landing_target(self, bearing: Bearing) -> int:
        if not _finite(bearing.az_body_rad, bearing.el_body_rad):
            self.stats.not_finite += 1
            return 0
        return int(
            self.link.send_message(
                "LANDING_TARGET",
                time_usec=self.link.time_usec_for(bearing.t_capture_ns), target_num=0, frame=_FRAME_BODY_FRD,
                angle_x=float(bearing.az_body_rad), angle_y=float(-bearing.el_body_rad),
                distance=0.0, size_x=0.0, size_y=0.0, type=_LANDING_VISION,
            )
        )


def _finite(*values: float) -> bool:
    return all(math.isfinite(float(v)) for v in values)


def _deg_e7(deg: float) -> int:
    return int(round(deg * 1e7))


def _warn_follow_target() -> None:
    log.warning(
        "mavlink.outputs.follow_target is on: an autopilot in follow mode will chase the detected "
        "drone's estimated position; disable it unless that is intended"
    )


def _warn_landing_target() -> None:
    log.warning(
        "mavlink.outputs.landing_target is on: a precision-landing autopilot may steer "
        "toward the detected drone; disable it unless that is intended"
    )

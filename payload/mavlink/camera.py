"""The MAVLink camera protocol: what a ground station or an autopilot asks of a camera with
visual tracking, and what the payload answers (docs/mavlink.md has the table).

``CameraProtocol`` registers with ``MavlinkLink.add_command_handler``; it sees only commands
addressed to our component from an allowed system id, signature and NaN checks done (the link's
door). It answers on the link thread:

- ``MAV_CMD_REQUEST_MESSAGE`` (param1 = message id) and the older requests
  ``MAV_CMD_REQUEST_CAMERA_INFORMATION`` / ``_CAMERA_SETTINGS`` / ``_VIDEO_STREAM_INFORMATION`` /
  ``_VIDEO_STREAM_STATUS``: ACK ACCEPTED, then the message. VIDEO_STREAM_* without a stream, and
  message ids we do not emit: ACK DENIED.
- ``MAV_CMD_SET_MESSAGE_INTERVAL`` for CAMERA_TRACKING_IMAGE_STATUS or _GEO_STATUS: interval in
  us (> 0: at most that often), 0 (default: every processed frame), -1 (off) -> ACCEPTED; other
  message ids -> DENIED; an interval below -1 -> DENIED.
- ``MAV_CMD_CAMERA_TRACK_POINT`` (param1/2 = x/y in 0..1, param3 = radius in 0..1 of the image
  width) and ``_TRACK_RECTANGLE`` (param1..4 = top-left x/y, bottom-right x/y in 0..1): a
  point outside the image or an empty or inverted rectangle -> DENIED; detection disabled by
  command -> TEMPORARILY_REJECTED; else ACK IN_PROGRESS and the designation goes to the detection
  loop, which puts GLAD's search region there. The first target the local detectors confirm there
  within ``mavlink.camera.designate_frames`` frames -> ACK ACCEPTED; none -> ACK FAILED, one
  CAMERA_TRACKING_IMAGE_STATUS with the ERROR flag, and GLAD back to search. The same command
  again while it is being confirmed -> IN_PROGRESS again (a ground station's retry); a different
  one supersedes it (the old one -> FAILED).
- ``MAV_CMD_CAMERA_STOP_TRACKING``: ACCEPTED; a designation being confirmed -> FAILED; GLAD
  returns to automatic search.

Thread hand-over: commands arrive on the link thread; the detection loop takes the newest
request at the start of each frame (``take``) and reports each frame's outcome
(``after_frame``). Nothing here touches GLAD.
"""

import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Optional, Tuple

from payload import __version__
from payload.config import Config, section_changes
from payload.geometry import CameraModel
from payload.mavlink.link import MavlinkLink, constant
from payload.mavlink.transport import mavlink as _M
from payload.video.description import RTSP, StreamDescription

log = logging.getLogger(__name__)

_NAN = float("nan")
_START_NS = time.monotonic_ns()

MSG_CAMERA_INFORMATION = _M.MAVLINK_MSG_ID_CAMERA_INFORMATION
MSG_CAMERA_SETTINGS = _M.MAVLINK_MSG_ID_CAMERA_SETTINGS
MSG_VIDEO_STREAM_INFORMATION = _M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION
MSG_VIDEO_STREAM_STATUS = _M.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS
MSG_TRACKING_IMAGE_STATUS = _M.MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS
MSG_TRACKING_GEO_STATUS = _M.MAVLINK_MSG_ID_CAMERA_TRACKING_GEO_STATUS

_LEGACY_REQUESTS = {
    _M.MAV_CMD_REQUEST_CAMERA_INFORMATION: MSG_CAMERA_INFORMATION,
    _M.MAV_CMD_REQUEST_CAMERA_SETTINGS: MSG_CAMERA_SETTINGS,
    _M.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION: MSG_VIDEO_STREAM_INFORMATION,
    _M.MAV_CMD_REQUEST_VIDEO_STREAM_STATUS: MSG_VIDEO_STREAM_STATUS,
}
CMD_TRACK_POINT = _M.MAV_CMD_CAMERA_TRACK_POINT
CMD_TRACK_RECTANGLE = _M.MAV_CMD_CAMERA_TRACK_RECTANGLE
CMD_STOP_TRACKING = _M.MAV_CMD_CAMERA_STOP_TRACKING

ACCEPTED = _M.MAV_RESULT_ACCEPTED
TEMPORARILY_REJECTED = _M.MAV_RESULT_TEMPORARILY_REJECTED
DENIED = _M.MAV_RESULT_DENIED
FAILED = _M.MAV_RESULT_FAILED
IN_PROGRESS = _M.MAV_RESULT_IN_PROGRESS

_FLAGS = constant("CAMERA_CAP_FLAGS_HAS_TRACKING_POINT", 512) | constant("CAMERA_CAP_FLAGS_HAS_TRACKING_RECTANGLE", 1024)
_HAS_VIDEO_STREAM = constant("CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM", 256)
_TRACKING_ERROR = constant("CAMERA_TRACKING_STATUS_FLAGS_ERROR", 2)
_MODE_NONE = constant("CAMERA_TRACKING_MODE_NONE", 0)
_MODE_VIDEO = constant("CAMERA_MODE_VIDEO", 1)
_STREAM_RUNNING = constant("VIDEO_STREAM_STATUS_FLAGS_RUNNING", 1)
_ENCODINGS = {"h264": constant("VIDEO_STREAM_ENCODING_H264", 1), "h265": constant("VIDEO_STREAM_ENCODING_H265", 2)}
_STREAM_ID = 1
#: A track point with radius 0 (or a very small one) starts the search region's box this wide.
_POINT_BOX_PX = 16.0


@dataclass(frozen=True)
class Designation:
    """An operator's track point or rectangle, in image fractions (0..1), or a stop."""

    command: int  # CMD_TRACK_POINT, CMD_TRACK_RECTANGLE or CMD_STOP_TRACKING
    params: Tuple[float, ...]  # the command's param1..4, for spotting a retry
    requester: Tuple[int, int]  # (sysid, compid) the ACKs go to
    center: Tuple[float, float] = (0.0, 0.0)
    size: Optional[Tuple[float, float]] = None  # a rectangle's, in fractions of the image width and height
    radius: float = 0.0  # a point's, in fractions of the image width (0 = unknown)

    def center_px(self, image_wh: Tuple[int, int]) -> Tuple[float, float]:
        return self.center[0] * image_wh[0], self.center[1] * image_wh[1]

    def size_px(self, image_wh: Tuple[int, int]) -> Tuple[float, float]:
        if self.size is None:
            side = max(2.0 * self.radius * image_wh[0], _POINT_BOX_PX)
            return side, side
        return max(self.size[0] * image_wh[0], 2.0), max(self.size[1] * image_wh[1], 2.0)

    @property
    def stop(self) -> bool:
        return self.command == CMD_STOP_TRACKING


@dataclass
class CameraStats:
    requests: int = 0  # messages sent on request
    designations: int = 0  # track commands accepted for confirmation
    confirmed: int = 0
    failed: int = 0  # not confirmed in time, superseded or cancelled
    denied: int = 0  # bad parameters


class CameraProtocol:
    """Answers the camera protocol's commands over ``link``; see the module doc."""

    def __init__(self, link: MavlinkLink, cfg: Config, stream: Optional[StreamDescription] = None) -> None:
        self.link = link
        self.cfg = cfg.mavlink.camera
        self.camera_cfg = cfg.camera
        self.stream = stream
        cap = cfg.capture
        if cap.source == "synthetic":
            self.image_wh: Tuple[int, int] = (cap.synthetic.width, cap.synthetic.height)
        else:
            self.image_wh = (cap.width, cap.height)  # corrected by the first frame (set_image_size)
        self.stats = CameraStats()
        self._lock = threading.Lock()
        self._posted: Optional[Designation] = None  # not yet taken by the detection loop
        self._active: Optional[Designation] = None  # taken, being confirmed
        self._frames = 0  # frames the active designation has had
        self._intervals = {MSG_TRACKING_IMAGE_STATUS: 0, MSG_TRACKING_GEO_STATUS: 0}  # us; 0 default, -1 off
        self.status_requested = False  # a CAMERA_TRACKING_IMAGE_STATUS was asked for: the next frame sends one
        link.add_command_handler(self.handle)

    # --- for the service and the publisher ---------------------------------------------------

    def apply(self, cfg: Config) -> list:
        """Take a reloaded ``mavlink.camera`` section (and the ``camera`` section for CAMERA_INFORMATION)."""
        keys = section_changes(self.cfg, cfg.mavlink.camera, "mavlink.camera")
        self.cfg = cfg.mavlink.camera
        self.camera_cfg = cfg.camera
        return keys

    def set_image_size(self, image_wh: Tuple[int, int]) -> None:
        self.image_wh = (int(image_wh[0]), int(image_wh[1]))

    def interval_us(self, msg_id: int) -> int:
        """The interval asked by SET_MESSAGE_INTERVAL for a tracking message: 0 default, -1 off."""
        return self._intervals.get(msg_id, 0)

    def take(self) -> Optional[Designation]:
        """The newest designation or stop posted since the last call (detection loop, frame start)."""
        with self._lock:
            request, self._posted = self._posted, None
            if request is not None and not request.stop:
                self._active = request
                self._frames = 0
            return request

    @property
    def confirming(self) -> bool:
        return self._active is not None

    def after_frame(self, measured: bool) -> Optional[bool]:
        """One frame's outcome for the designation being confirmed: True when ``measured`` (a target
        the local detectors confirmed) confirms it, False when its frames ran out (the caller puts
        GLAD back to search), None when nothing was decided."""
        with self._lock:
            active = self._active
            if active is None:
                return None
            self._frames += 1
            if measured:
                self._active = None
                self.stats.confirmed += 1
                result = True
            elif self._frames >= self.cfg.designate_frames:
                self._active = None
                self.stats.failed += 1
                result = False
            else:
                return None
        if result:
            log.info("designated target locked after %d frame(s)", self._frames)
            self.link.ack(active.command, ACCEPTED, active.requester)
        else:
            log.warning("designated target not confirmed within %d frames: back to search", self.cfg.designate_frames)
            self.link.ack(active.command, FAILED, active.requester)
            self._send_tracking_error()
        return result

    def cancel(self, why: str) -> None:
        """Fail the designation posted or being confirmed (detection disabled, shutting down)."""
        with self._lock:
            dropped = [d for d in (self._posted, self._active) if d is not None and not d.stop]
            self._posted = self._active = None
        for d in dropped:
            self.stats.failed += 1
            log.info("designation cancelled: %s", why)
            self.link.ack(d.command, FAILED, d.requester)

    # --- the link thread ---------------------------------------------------------------------

    def handle(self, msg: Any) -> bool:
        cmd = msg.command
        to = (msg.get_srcSystem(), msg.get_srcComponent())
        if cmd == _M.MAV_CMD_REQUEST_MESSAGE:
            self._request(cmd, int(msg.param1), msg.param2, to)
        elif cmd in _LEGACY_REQUESTS:
            self._request(cmd, _LEGACY_REQUESTS[cmd], 0.0, to)
        elif cmd == _M.MAV_CMD_SET_MESSAGE_INTERVAL:
            self._set_interval(msg, to)
        elif cmd in (CMD_TRACK_POINT, CMD_TRACK_RECTANGLE):
            self._track(msg, to)
        elif cmd == CMD_STOP_TRACKING:
            self._stop_tracking(msg, to)
        else:
            return False
        return True

    def _request(self, cmd: int, msg_id: int, param2: float, to: Tuple[int, int]) -> None:
        if msg_id in (MSG_VIDEO_STREAM_INFORMATION, MSG_VIDEO_STREAM_STATUS):
            # param2: stream id, 0 = all; we have at most one
            if self.stream is None or param2 not in (0.0, float(_STREAM_ID)):
                self.link.ack(cmd, DENIED, to)
                return
        send = {
            MSG_CAMERA_INFORMATION: self.send_camera_information,
            MSG_CAMERA_SETTINGS: self._send_camera_settings,
            MSG_VIDEO_STREAM_INFORMATION: self._send_stream_information,
            MSG_VIDEO_STREAM_STATUS: self._send_stream_status,
        }.get(msg_id)
        if send is None and msg_id != MSG_TRACKING_IMAGE_STATUS:
            self.link.ack(cmd, DENIED, to)
            return
        self.link.ack(cmd, ACCEPTED, to)
        self.stats.requests += 1
        if send is None:
            self.status_requested = True  # the publisher sends it with the next frame
        else:
            send()

    def _set_interval(self, msg: Any, to: Tuple[int, int]) -> None:
        msg_id, interval = int(msg.param1), msg.param2
        if msg_id not in self._intervals or interval < -1 or interval > 1e9:
            self.link.ack(msg.command, DENIED, to)
            return
        self._intervals[msg_id] = int(interval)
        log.info("message interval set by sysid=%d: msg_id=%d interval_us=%d", to[0], msg_id, int(interval))
        self.link.ack(msg.command, ACCEPTED, to)

    def _track(self, msg: Any, to: Tuple[int, int]) -> None:
        params = (msg.param1, msg.param2, msg.param3, msg.param4)
        designation = _designation(msg.command, params, to)
        if designation is None:
            self.stats.denied += 1
            log.info("track command %d denied: parameters %s out of range", msg.command, ["%g" % p for p in params])
            self.link.ack(msg.command, DENIED, to)
            return
        if not self.link.detection_enabled:
            self.link.ack(msg.command, TEMPORARILY_REJECTED, to)
            return
        superseded = []
        with self._lock:
            pending = [d for d in (self._posted, self._active) if d is not None and not d.stop]
            if any(d.command == designation.command and d.params == designation.params and d.requester == to
                   for d in pending):
                superseded = None  # a retry of the one in progress
            else:
                superseded = pending
                self._active = None
                self._posted = designation
                self.stats.designations += 1
        if superseded is None:
            self.link.ack(msg.command, IN_PROGRESS, to)
            return
        for d in superseded:
            self.stats.failed += 1
            self.link.ack(d.command, FAILED, d.requester)
        log.info("designation from sysid=%d: %s at (%.3f, %.3f)%s", to[0],
                 "rectangle" if designation.size else "point", designation.center[0], designation.center[1],
                 " (superseding another)" if superseded else "")
        self.link.ack(msg.command, IN_PROGRESS, to)

    def _stop_tracking(self, msg: Any, to: Tuple[int, int]) -> None:
        with self._lock:
            dropped = [d for d in (self._posted, self._active) if d is not None and not d.stop]
            self._active = None
            self._posted = Designation(CMD_STOP_TRACKING, (), to)
        for d in dropped:
            self.stats.failed += 1
            self.link.ack(d.command, FAILED, d.requester)
        log.info("stop tracking from sysid=%d: back to automatic search", to[0])
        self.link.ack(msg.command, ACCEPTED, to)

    # --- messages ----------------------------------------------------------------------------

    def camera_model(self) -> CameraModel:
        return CameraModel.from_config(self.camera_cfg, self.image_wh)

    def send_camera_information(self) -> bool:
        model = self.camera_model()
        w, h = self.image_wh
        focal_px = float(model.matrix[0, 0])
        pixel_mm = None if self.camera_cfg.pixel_size_um is None else self.camera_cfg.pixel_size_um / 1000.0
        # MAVLink: NaN = unknown, for the lens and the sensor (no pixel size configured)
        focal_mm = _NAN if pixel_mm is None else focal_px * pixel_mm
        sensor_h = _NAN if pixel_mm is None else w * pixel_mm
        sensor_v = _NAN if pixel_mm is None else h * pixel_mm
        flags = _FLAGS | (_HAS_VIDEO_STREAM if self.stream is not None else 0)
        return self.link.send_message(
            "CAMERA_INFORMATION",
            time_boot_ms=_boot_ms(), vendor_name=_uint8s(self.cfg.vendor, 32), model_name=_uint8s(self.cfg.model, 32),
            firmware_version=_firmware_version(__version__), focal_length=focal_mm,
            sensor_size_h=sensor_h, sensor_size_v=sensor_v, resolution_h=_u16(w), resolution_v=_u16(h),
            lens_id=0, flags=flags, cam_definition_version=0, cam_definition_uri=b"",
            gimbal_device_id=0, camera_device_id=0,
        )

    def _send_camera_settings(self) -> bool:
        # a fixed lens: zoom and focus unknown (NaN, as MAVLink defines it)
        return self.link.send_message("CAMERA_SETTINGS", time_boot_ms=_boot_ms(), mode_id=_MODE_VIDEO,
                                      zoomLevel=_NAN, focusLevel=_NAN, camera_device_id=0)

    def _send_stream_information(self) -> bool:
        s = self.stream
        if s is None:
            return False
        rtsp = s.kind == RTSP
        return self.link.send_message(
            "VIDEO_STREAM_INFORMATION",
            stream_id=_STREAM_ID, count=1,
            type=_M.VIDEO_STREAM_TYPE_RTSP if rtsp else _M.VIDEO_STREAM_TYPE_RTPUDP,
            flags=_STREAM_RUNNING, framerate=float(s.fps), resolution_h=_u16(s.width), resolution_v=_u16(s.height),
            bitrate=int(s.bitrate_kbps) * 1000, rotation=0, hfov=_u16(round(math.degrees(self.camera_model().hfov_rad))),
            name=b"glad", uri=s.uri.encode("utf-8")[:160], encoding=_ENCODINGS.get(s.encoding.lower(), 0), camera_device_id=0,
        )

    def _send_stream_status(self) -> bool:
        s = self.stream
        if s is None:
            return False
        return self.link.send_message(
            "VIDEO_STREAM_STATUS",
            stream_id=_STREAM_ID, flags=_STREAM_RUNNING, framerate=float(s.fps), resolution_h=_u16(s.width),
            resolution_v=_u16(s.height), bitrate=int(s.bitrate_kbps) * 1000, rotation=0,
            hfov=_u16(round(math.degrees(self.camera_model().hfov_rad))), camera_device_id=0,
        )

    def _send_tracking_error(self) -> bool:
        return self.link.send_message(
            "CAMERA_TRACKING_IMAGE_STATUS",
            tracking_status=_TRACKING_ERROR, tracking_mode=_MODE_NONE, target_data=0,
            point_x=_NAN, point_y=_NAN, radius=_NAN,
            rec_top_x=_NAN, rec_top_y=_NAN, rec_bottom_x=_NAN, rec_bottom_y=_NAN,
        )


def _designation(command: int, params: Tuple[float, ...], to: Tuple[int, int]) -> Optional[Designation]:
    """The designation a track command asks for, or None when its parameters are not one."""
    if not all(math.isfinite(p) for p in params):
        return None  # the link drops these at the door; checked again here so nothing depends on it
    if command == CMD_TRACK_POINT:
        x, y, radius = params[0], params[1], params[2]
        if not (0.0 <= x <= 1.0 and 0.0 <= y <= 1.0 and 0.0 <= radius <= 1.0):
            return None
        return Designation(command, tuple(params[:3]), to, (x, y), radius=radius)
    x1, y1, x2, y2 = params
    if not all(0.0 <= v <= 1.0 for v in params) or not (x1 < x2 and y1 < y2):
        return None  # outside the image, empty or inverted
    return Designation(command, tuple(params), to, ((x1 + x2) / 2, (y1 + y2) / 2), (x2 - x1, y2 - y1))


def _boot_ms() -> int:
    return ((time.monotonic_ns() - _START_NS) // 1_000_000) & 0xFFFFFFFF


def _u16(value: float) -> int:
    return int(min(max(value, 0), 65535))


def _uint8s(text: str, n: int) -> list:
    data = text.encode("utf-8")[:n]
    return list(data) + [0] * (n - len(data))


def _firmware_version(version: str) -> int:
    """MAVLink's firmware_version: (dev << 24) | (patch << 16) | (minor << 8) | major."""
    parts = []
    for p in version.split(".")[:3]:
        digits = "".join(c for c in p if c.isdigit())
        parts.append(int(digits) & 0xFF if digits else 0)
    major, minor, patch = (parts + [0, 0, 0])[:3]
    return (patch << 16) | (minor << 8) | major

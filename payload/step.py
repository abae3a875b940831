"""The frame step: frame -> GLAD -> bearing at the attitude of capture time -> messages -> records.

``FrameStep`` is the one place a frame goes through the payload. The service runs it on every
frame it reads (and so does the demo, which runs the service); the benchmark times it, with a
baseline detector in GLAD's place when asked (payload.bench). Each part is optional: without a
link there is no attitude, position or message; without a camera protocol no designation;
without records or video nothing is written or shown.

What the step owns, in order: an operator's designation taken at the start of the frame (the
camera protocol hands it over from the link thread), the detector, the attitude and position at
the frame's capture time (interpolated by the link), the bearing and geo position, the target
messages (handed to the link's queue: the socket is written by the link thread, never here),
the records and the live video. While detection is disabled by command the frame only goes to
the video. The target state has one vocabulary, ``GladResult.state`` (searching, following,
detected, coasting); ``state_text`` adds whether the lock is an operator's.
"""

import time
from dataclasses import dataclass, field
from typing import Dict, Optional

from payload.detect.pipeline import GladResult
from payload.geometry import BearingModel, GeoModel, TargetGeo
from payload.records import decision_row, result_rows
from payload.types import Bearing, Frame

#: What the live video shows while detection is disabled by command (no target state then).
DETECTION_OFF = "detection off"


def state_text(result: Optional[GladResult], designated: bool = False) -> str:
    """The target state as shown and logged: ``GladResult.state`` ('searching' before any
    result), with ',designated' while the lock is an operator's."""
    state = "searching" if result is None else result.state
    return state + ",designated" if designated else state


@dataclass(frozen=True)
class StepOutcome:
    """What one frame gave; ``result`` is None when detection was disabled by command."""

    result: Optional[GladResult]
    bearing: Optional[Bearing] = None
    geo: Optional[TargetGeo] = None
    sent: int = 0  # target messages handed to the link
    timings_ms: Dict[str, float] = field(default_factory=dict)  # the detector's, plus bearing and mavlink


class FrameStep:
    """One frame through the payload. ``detector`` has ``process(frame) -> GladResult`` (Glad, or
    a benchmark baseline); ``designate``/``release`` are used only with a camera protocol."""

    def __init__(self, detector, bearings: BearingModel, geo: Optional[GeoModel] = None, link=None,
                 publisher=None, camera=None, detections_csv=None, decisions_csv=None, video=None) -> None:
        self.detector = detector
        self.bearings = bearings
        self.geo = geo
        self.link = link  # payload.mavlink.link.MavlinkLink: attitude, position, detection switch
        self.publisher = publisher  # payload.mavlink.outputs.TargetPublisher
        self.camera = camera  # payload.mavlink.camera.CameraProtocol
        self.detections_csv = detections_csv  # payload.records.CsvLog
        self.decisions_csv = decisions_csv
        self.video = video  # payload.video.output.VideoOutput

    @property
    def designated(self) -> bool:
        return bool(getattr(self.detector, "designated", False))

    def __call__(self, frame: Frame) -> StepOutcome:
        if self.link is not None and not self.link.detection_enabled:
            if self.camera is not None:
                self.camera.cancel("detection disabled by command")
            if self.video is not None:
                self.video.submit(frame, None, DETECTION_OFF)  # the operator still sees the camera
            return StepOutcome(None)
        if self.camera is not None:
            self._designation(frame)
        result = self.detector.process(frame)
        if self.camera is not None and self.camera.confirming:
            # confirmed only by the operator's own target, not by another one reported beside it
            if self.camera.after_frame(result.designated_measured) is False:
                self.detector.release()
        timings = dict(result.timings_ms)
        t0 = time.perf_counter()
        bearing = geo = None
        if result.target is not None:
            # the link drops non-finite ATTITUDE at the door; the bearing model still refuses a non-finite result
            attitude = self.link.attitude_at(frame.t_capture_ns) if self.link is not None else None
            bearing = self.bearings.bearing(result.target, frame.size_wh, attitude)
            if self.link is not None and self.geo is not None and self.geo.enabled:
                geo = self.geo.locate(result.target, frame.size_wh, attitude,
                                      self.link.position_at(frame.t_capture_ns))
            timings["bearing"] = (time.perf_counter() - t0) * 1000.0
        sent = 0
        if self.publisher is not None:
            t1 = time.perf_counter()
            sent = self.publisher.publish(result.target, bearing, frame.size_wh, geo)
            timings["mavlink"] = (time.perf_counter() - t1) * 1000.0
        if self.detections_csv is not None:
            self.detections_csv.write_rows(result_rows(frame.index, result))
        if self.decisions_csv is not None:
            self.decisions_csv.write_rows([decision_row(frame, result, bearing, sent)])
        if self.video is not None:
            self.video.submit(frame, result, state_text(result, self.designated))
        return StepOutcome(result, bearing, geo, sent, timings)

    def _designation(self, frame: Frame) -> None:
        """An operator's track point or stop from the camera protocol, taken at the start of a frame
        (commands arrive on the link thread; the detector is only touched here)."""
        self.camera.set_image_size(frame.size_wh)
        request = self.camera.take()
        if request is None:
            return
        if request.stop:
            self.detector.release()
        else:
            self.detector.designate(request.center_px(frame.size_wh), request.size_px(frame.size_wh))

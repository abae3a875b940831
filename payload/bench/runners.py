"""What a benchmark row runs on each frame: GLAD itself, or one of the baselines.

Every runner has ``process(frame) -> GladResult`` and ``reset()``, so the eval and bench
loops treat them alike. Baselines (issue 6, item 3):

- ``global``: the global appearance detector alone on the down-scaled frame, every frame,
  reporting every box >= T0 (the paper's "YOLOv5s-1" situation);
- ``tiled``: the local (native-resolution) appearance detector on overlapping tiles of the
  full-resolution frame, merged with NMS (SAHI-style), every box >= T0 reported.
"""

import time
from typing import Callable, List

from payload.config import Config, config_with
from payload.detect.pipeline import Glad, GladResult
from payload.detect.tiled import DEFAULT_OVERLAP, TiledDetector
from payload.errors import ConfigError
from payload.types import Detections, Frame, Target

RUNNERS = ("glad", "global", "tiled")


class DetectorRun:
    """A stateless detector as a runner: all boxes reported, the best one is the target."""

    def __init__(self, detect: Callable[..., Detections], timing_key: str, sessions: List) -> None:
        self._detect = detect
        self.timing_key = timing_key
        self.sessions = sessions  # the OnnxModel objects it runs (for the provider report)

    def reset(self) -> None:
        """Nothing is carried between frames."""

    def process(self, frame: Frame) -> GladResult:
        t = time.perf_counter()
        found = self._detect(frame.image).sorted_by_score()
        timings = {self.timing_key: (time.perf_counter() - t) * 1000.0}
        target = None
        if len(found):
            target = Target(frame.index, frame.t_capture_ns, found.xyxy[0].copy(), float(found.score[0]),
                            str(found.module[0]), measured=True)
        return GladResult(frame.index, frame.t_capture_ns, "global", found, found, target, None, timings)


def onnx_sessions(runner) -> List:
    """The OnnxModel objects behind a runner (Glad or DetectorRun)."""
    if isinstance(runner, DetectorRun):
        return list(runner.sessions)
    models = runner.models
    found = [models.global_appearance, models.local_appearance, models.classifier]
    return [m.model for m in found if m is not None]


def build_runner(cfg: Config, kind: str = "glad", overlap: float = DEFAULT_OVERLAP):
    """A runner of ``kind`` (one of RUNNERS) with its models loaded and warmed up."""
    from payload.detect.factory import build_detectors

    if kind == "glad":
        return Glad(cfg.detector)
    if kind == "global":
        only = config_with(cfg, **{"detector.local.appearance.enabled": False, "detector.classifier.enabled": False})
        gad = build_detectors(only.detector).global_appearance
        if gad is None:
            raise ConfigError(["bench runner 'global' needs detector.global.appearance.enabled: true"])
        return DetectorRun(gad.detect, "GAD", [gad.model])
    if kind == "tiled":
        t0 = cfg.detector.global_.appearance.confidence
        only = config_with(cfg, **{"detector.global.appearance.enabled": False, "detector.classifier.enabled": False,
                                   "detector.local.appearance.enabled": True,
                                   "detector.local.appearance.confidence": t0})
        lad = build_detectors(only.detector).local_appearance
        tiled = TiledDetector(lad, overlap=overlap, nms_iou=cfg.detector.local.appearance.nms_iou)
        return DetectorRun(tiled.detect, "tiled", [lad.model])
    raise ConfigError(["bench runner %r: expected one of %s" % (kind, ", ".join(RUNNERS))])

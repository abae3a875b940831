"""The shipped ONNX models and the factory that turns the detector config into runnable detectors."""

import os
from dataclasses import dataclass
from typing import Optional

from payload.config import AppearanceConfig, DetectorConfig
from payload.detect.appearance import AppearanceDetector
from payload.detect.classifier import AppearanceClassifier
from payload.detect.onnx_model import OnnxModel
from payload.errors import ModelError
from payload.types import GAD, LAD

_HERE = os.path.dirname(os.path.abspath(__file__))
_FILES = {"global": "glad_global.onnx", "local": "glad_local.onnx", "classifier": "glad_classifier.onnx"}


def builtin_model_path(name: str) -> str:
    """Path of a model shipped in the package: 'global', 'local' or 'classifier'."""
    if name not in _FILES:
        raise ModelError("built-in model %r: expected one of %s" % (name, ", ".join(sorted(_FILES))))
    return os.path.join(_HERE, _FILES[name])


@dataclass(frozen=True)
class DetectorModels:
    global_appearance: Optional[AppearanceDetector]
    local_appearance: Optional[AppearanceDetector]
    classifier: Optional[AppearanceClassifier]


def build_detectors(cfg: DetectorConfig) -> DetectorModels:
    """Load the enabled models (warming each up); a disabled stage gives None."""

    def model(path: Optional[str], name: str, key: str, expected, warmup_hw) -> OnnxModel:
        return OnnxModel(
            path or builtin_model_path(name),
            backend=cfg.backend,
            threads=cfg.threads,
            fp16=cfg.fp16,
            engine_cache_dir=cfg.engine_cache_dir,
            expected_inputs=expected,
            config_key=key,
            warmup_hw=warmup_hw,
        )

    def appearance(app: AppearanceConfig, name: str, module: str) -> Optional[AppearanceDetector]:
        if not app.enabled:
            return None
        key = "detector.%s.appearance.model" % name
        m = model(app.model, name, key, {"images": 3}, (app.input_wh[1], app.input_wh[0]))
        return AppearanceDetector(m, app, module)

    classifier = None
    if cfg.classifier.enabled:
        m = model(cfg.classifier.model, "classifier", "detector.classifier.model", {"patches": 3}, None)
        classifier = AppearanceClassifier(m, cfg.classifier)
    return DetectorModels(
        global_appearance=appearance(cfg.global_.appearance, "global", GAD),
        local_appearance=appearance(cfg.local.appearance, "local", LAD),
        classifier=classifier,
    )

"""Building the detectors from the config and the shipped models: the ONNX sessions GLAD runs.

The shipped models are the files in ``payload/models/`` (its MODEL_CARD.md says what they are);
a config path replaces one. A disabled stage gives None.
"""

import os
from dataclasses import dataclass
from typing import Optional

import numpy as np

from payload.config import AppearanceConfig, DetectorConfig
from payload.detect.appearance import AppearanceDetector
from payload.detect.classifier import AppearanceClassifier
from payload.detect.onnx_model import OnnxModel
from payload.detect.verify import N_FEATURES, N_LOOK
from payload.errors import ModelError
from payload.types import GAD, LAD

MODELS_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "models")
_FILES = {"global": "glad_global.onnx", "local": "glad_local.onnx", "classifier": "glad_classifier.onnx",
          "verifier": "glad_verifier.onnx"}


def builtin_model_path(name: str) -> str:
    """Path of a model shipped in the package: 'global', 'local', 'classifier' or 'verifier'."""
    if name not in _FILES:
        raise ModelError("built-in model %r: expected one of %s" % (name, ", ".join(sorted(_FILES))))
    return os.path.join(MODELS_DIR, _FILES[name])


@dataclass(frozen=True)
class DetectorModels:
    global_appearance: Optional[AppearanceDetector]
    local_appearance: Optional[AppearanceDetector]
    classifier: Optional[AppearanceClassifier]
    verifier: Optional[OnnxModel] = None  # the lock verifier's network (payload.detect.verify)


def build_detectors(cfg: DetectorConfig) -> DetectorModels:
    """Load the enabled models (warming each up); a disabled stage gives None."""

    def model(path: Optional[str], name: str, key: str, expected, warmup_hw, varying_batch=False) -> OnnxModel:
        return OnnxModel(
            path or builtin_model_path(name),
            backend=cfg.backend,
            threads=cfg.threads,
            fp16=cfg.fp16,
            engine_cache_dir=cfg.engine_cache_dir,
            expected_inputs=expected,
            config_key=key,
            warmup_hw=warmup_hw,
            varying_batch=varying_batch,
        )

    def appearance(app: AppearanceConfig, name: str, module: str) -> Optional[AppearanceDetector]:
        if not app.enabled:
            return None
        key = "detector.%s.appearance.model" % name
        m = model(app.model, name, key, {"images": 3}, (app.input_wh[1], app.input_wh[0]))
        # GAD at its frame's own size (the networks take any size; ~25 % of GAD's time at 640x512);
        # LAD at its whole input, as measured: payload.detect.appearance
        return AppearanceDetector(m, app, module, fit=module == GAD)

    classifier = None
    if cfg.classifier.enabled:
        m = model(cfg.classifier.model, "classifier", "detector.classifier.model", {"patches": 3}, None,
                  varying_batch=True)
        classifier = AppearanceClassifier(m, cfg.classifier)
    verifier = None
    if cfg.verifier.enabled:
        verifier = model(cfg.verifier.model, "verifier", "detector.verifier.model",
                         {"tracks": (None, None, None)}, None)
        check_verifier(verifier)
    return DetectorModels(
        global_appearance=appearance(cfg.global_.appearance, "global", GAD),
        local_appearance=appearance(cfg.local.appearance, "local", LAD),
        classifier=classifier,
        verifier=verifier,
    )


def check_verifier(model: OnnxModel) -> None:
    """The verifier's contract (payload.detect.verify): [N, T, F] rows in, [N, 1] probability out."""
    shape = next(iter(model.input_shapes.values()))
    window, features = shape[1], shape[2]
    if not (isinstance(window, int) and window > 0 and features in (N_FEATURES, N_FEATURES + N_LOOK)):
        raise ModelError("%s: expected input [N, T, %d or %d] (T frames of the lock's rows, with or without the "
                         "look of its pixels), found %s" % (model.where, N_FEATURES, N_FEATURES + N_LOOK, list(shape)))
    out = model.run({next(iter(model.input_shapes)): np.zeros((1, window, features), np.float32)})[0]
    if out.size != 1:
        raise ModelError("%s: expected output [N, 1] (drone probability), found %s" % (model.where, list(out.shape)))

"""The shipped ONNX models: the files in this folder (MODEL_CARD.md); payload.detect.factory loads them."""

# where payload/bench/runners.py finds the factory; new code imports payload.detect.factory
from payload.detect.factory import build_detectors  # noqa: F401

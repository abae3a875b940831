"""The shipped ONNX models: the files in this folder (MODEL_CARD.md); payload.detect.factory loads them."""

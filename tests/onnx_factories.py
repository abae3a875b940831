"""Tiny real ONNX models built with onnx.helper, for testing the runtime without trained weights.

bright_spot_detector: the detector contract (input 'images' [N,3,H,W], output 'maps'
[N,5,H/4,W/4]); the score of a 4x4 cell is its mean brightness, kept at 3x3 local maxima,
offset 0.5 (cell centre) and box 4x4 px: a white 4x4 square on a black 4-aligned cell comes
back as exactly that box.
brightness_classifier: the classifier contract (input 'patches' [N,3,32,32], output [N,2]);
drone probability = mean brightness of the patch.
"""

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper


def _save(graph, path):
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return str(path)


def bright_spot_detector(path, input_name="images", channels=3, hw=("H", "W")):
    """``hw``: the input's spatial dims, dynamic by default; (100, 100) makes a fixed-size model."""
    x = helper.make_tensor_value_info(input_name, TensorProto.FLOAT, ["N", channels, *hw])
    y = helper.make_tensor_value_info("maps", TensorProto.FLOAT, ["N", 5, "h", "w"])
    consts = [
        numpy_helper.from_array(np.array(0.0, np.float32), "zero"),
        numpy_helper.from_array(np.array(0.5, np.float32), "half"),
        numpy_helper.from_array(np.array(4.0, np.float32), "four"),
    ]
    nodes = [
        helper.make_node("ReduceMean", [input_name], ["grey"], axes=[1], keepdims=1),
        helper.make_node("AveragePool", ["grey"], ["score"], kernel_shape=[4, 4], strides=[4, 4]),
        helper.make_node("MaxPool", ["score"], ["pooled"], kernel_shape=[3, 3], strides=[1, 1], pads=[1, 1, 1, 1]),
        helper.make_node("Equal", ["score", "pooled"], ["is_peak"]),
        helper.make_node("Cast", ["is_peak"], ["peak_f"], to=TensorProto.FLOAT),
        helper.make_node("Mul", ["score", "peak_f"], ["peak"]),
        helper.make_node("Mul", ["score", "zero"], ["zeros"]),
        helper.make_node("Add", ["zeros", "half"], ["offset"]),
        helper.make_node("Add", ["zeros", "four"], ["size"]),
        helper.make_node("Concat", ["peak", "offset", "offset", "size", "size"], ["maps"], axis=1),
    ]
    return _save(helper.make_graph(nodes, "bright_spot", [x], [y], consts), path)


def failing_detector(path):
    """The detector contract, but inference fails inside ONNX Runtime on any input that is not all
    black: a Gather index grows with the brightest pixel and runs out of its 10-element table.
    The all-zero warm-up and output probe pass, so the model loads; every real frame faults."""
    x = helper.make_tensor_value_info("images", TensorProto.FLOAT, ["N", 3, "H", "W"])
    y = helper.make_tensor_value_info("maps", TensorProto.FLOAT, ["N", 5, "h", "w"])
    consts = [
        numpy_helper.from_array(np.arange(10, dtype=np.float32), "table"),
        numpy_helper.from_array(np.array(1000.0, np.float32), "gain"),
        numpy_helper.from_array(np.array(0.0, np.float32), "zero"),
    ]
    nodes = [
        helper.make_node("AveragePool", ["images"], ["pooled"], kernel_shape=[4, 4], strides=[4, 4]),
        helper.make_node("ReduceMax", ["images"], ["brightest"], keepdims=0),
        helper.make_node("Mul", ["brightest", "gain"], ["scaled"]),
        helper.make_node("Cast", ["scaled"], ["index"], to=TensorProto.INT64),
        helper.make_node("Gather", ["table", "index"], ["picked"]),
        helper.make_node("Mul", ["picked", "zero"], ["nothing"]),
        helper.make_node("ReduceMean", ["pooled"], ["grey"], axes=[1], keepdims=1),
        helper.make_node("Add", ["grey", "nothing"], ["score"]),
        helper.make_node("Concat", ["score", "score", "score", "score", "score"], ["maps"], axis=1),
    ]
    return _save(helper.make_graph(nodes, "failing", [x], [y], consts), path)


def brightness_classifier(path):
    x = helper.make_tensor_value_info("patches", TensorProto.FLOAT, ["N", 3, 32, 32])
    y = helper.make_tensor_value_info("prob", TensorProto.FLOAT, ["N", 2])
    consts = [
        numpy_helper.from_array(np.array([-1, 1], np.int64), "shape"),
        numpy_helper.from_array(np.array(1.0, np.float32), "one"),
    ]
    nodes = [
        helper.make_node("ReduceMean", ["patches"], ["mean4"], axes=[1, 2, 3], keepdims=1),
        helper.make_node("Reshape", ["mean4", "shape"], ["drone"]),
        helper.make_node("Sub", ["one", "drone"], ["clutter"]),
        helper.make_node("Concat", ["clutter", "drone"], ["prob"], axis=1),
    ]
    return _save(helper.make_graph(nodes, "brightness", [x], [y], consts), path)


def last_row_verifier(path, feature_index, window=16, features=None):
    """The lock verifier's contract (input 'tracks' [N, T, F], output [N, 1]): the drone probability is
    feature ``feature_index`` of the newest row (e.g. FEATURES.index('drone_p'): the classifier's
    verdict on this frame). ``features``: F (default the runtime's N_FEATURES)."""
    from payload.detect.verify import N_FEATURES

    f = N_FEATURES if features is None else features
    x = helper.make_tensor_value_info("tracks", TensorProto.FLOAT, ["N", window, f])
    y = helper.make_tensor_value_info("drone_p", TensorProto.FLOAT, ["N", 1])
    consts = [numpy_helper.from_array(np.array(window - 1, np.int64), "last"),
              numpy_helper.from_array(np.array([feature_index], np.int64), "column")]
    nodes = [
        helper.make_node("Gather", ["tracks", "last"], ["newest"], axis=1),  # [N, F]
        helper.make_node("Gather", ["newest", "column"], ["drone_p"], axis=1),  # [N, 1]
    ]
    return _save(helper.make_graph(nodes, "last_row_verifier", [x], [y], consts), path)

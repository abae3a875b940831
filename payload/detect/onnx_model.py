"""ONNX Runtime session for one model: provider choice, input checks, warm-up. The only onnxruntime import.

``backend`` maps to an ordered provider list (TensorRT -> CUDA -> CPU); providers this
onnxruntime build does not offer are dropped with a log line, and after the session is made
the provider ORT actually picked is logged (it falls back to CPU silently otherwise).
TensorRT engines are cached per model hash and precision, so a restart does not rebuild
them; the warm-up run in the constructor keeps a slow first build out of the live loop.
"""

import hashlib
import logging
import os
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from payload.errors import BackendUnavailable, ModelError

log = logging.getLogger(__name__)

TRT = "TensorrtExecutionProvider"
CUDA = "CUDAExecutionProvider"
CPU = "CPUExecutionProvider"

_CHAINS = {"tensorrt": (TRT, CUDA, CPU), "cuda": (CUDA, CPU), "cpu": (CPU,)}

#: Warm-up and default spatial size for inputs whose H/W are dynamic.
_WARMUP_HW = 64
#: On a GPU provider a varying batch is always fed as this many rows (padded; more run in chunks of
#: it): on an H100, ONNX Runtime's CUDA provider took 19 ms per classifier run whenever the batch size
#: differed from the last run's (its cuDNN algorithm search, run again on every change of shape; 3 ms
#: with the heuristic search) against 0.17 ms at one size (docs/results.md, "On a GPU"); TensorRT
#: builds an engine for a shape outside its profile (seconds on a Jetson).
GPU_BATCH = 32


def _shape_fits(shape, spec) -> bool:
    """Whether an ONNX input shape (ints, or names/None for free dims) can take ``spec`` (None = any)."""
    if shape is None or len(shape) != len(spec):
        return False
    return all(want is None or not isinstance(have, int) or have == want for have, want in zip(shape, spec))


def _ort():
    try:
        import onnxruntime
    except ImportError as exc:
        raise BackendUnavailable("onnxruntime is not installed: pip install onnxruntime (or onnxruntime-gpu): %s" % exc) from None
    return onnxruntime


def providers_for(backend: str, fp16: bool, engine_cache_dir: Optional[str]) -> List:
    """Provider list for ``backend`` (cpu | cuda | tensorrt), best first, limited to what ORT offers."""
    if backend not in _CHAINS:
        raise BackendUnavailable("backend %r: expected one of cpu, cuda, tensorrt" % (backend,))
    available = set(_ort().get_available_providers())
    out: List[Any] = []
    for name in _CHAINS[backend]:
        if name not in available:
            log.warning("provider dropped provider=%s backend=%s reason=not offered by this onnxruntime build", name, backend)
            continue
        if name == TRT:
            opts = {"trt_fp16_enable": bool(fp16), "trt_engine_cache_enable": engine_cache_dir is not None}
            if engine_cache_dir is not None:
                opts["trt_engine_cache_path"] = engine_cache_dir
            out.append((TRT, opts))
        else:
            out.append(name)
    if not out:
        raise BackendUnavailable("backend %r: onnxruntime offers none of %s" % (backend, ", ".join(_CHAINS[backend])))
    return out


def intra_op_threads(threads: int) -> int:
    """ONNX Runtime intra-op threads of every session in the process: ``threads`` (detector.threads),
    or with 0 one fewer than the cores this process may run on, at least 1.

    The sessions run one after another on the detection thread, while capture and decoding run on
    their own: a pool as wide as the machine makes each inference wait for a core the decoder
    holds. On this 2-core build machine, V_DRONE_086: one thread gave the local stage 23-24 ms
    against 25-27 ms and the region's camera motion 2.8 ms against 6.5 ms (medians, load ~8);
    docs/results.md "Speed".
    """
    if threads:
        return int(threads)
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return max(1, cores - 1)


def _file_digest(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:16]


def _describe(shape) -> str:
    return "[%s]" % ",".join(str(d) if isinstance(d, int) else (d or "?") for d in shape)


def _check_fixed_dims(where: str, config_key: str, name: str, shape, channels: int, hw: Tuple[int, int]) -> None:
    """A model whose input is fixed to another size than the one it will be fed fails on the first
    frame inside ONNX Runtime: say so at load, naming the shape found and the one expected."""
    want = [1, channels, int(hw[0]), int(hw[1])]
    if all(not isinstance(d, int) or d <= 0 or d == w for d, w in zip(shape, want)):
        return
    size_key = config_key[: -len(".model")] + ".input_wh" if config_key.endswith(".model") else "the input size"
    raise ModelError("%s: input '%s' is fixed at %s, expected %s (%s [%d, %d]) or dynamic H, W"
                     % (where, name, _describe(shape), _describe(["N", channels, hw[0], hw[1]]), size_key,
                        hw[1], hw[0]))


class OnnxModel:
    """One inference session. ``expected_inputs`` maps each input name to its channel count (NCHW),
    or to a full shape tuple with None where any size goes (e.g. the verifier's [N, T, F] rows).

    ``config_key`` names the config field the path came from, for error messages;
    ``warmup_hw`` is the (H, W) the caller will feed (batch 1): the warm-up feeds it to dynamic
    inputs, so that TensorRT builds its engine for it here and not on the first live frame, and
    an input fixed to another size is refused here with one line.
    ``varying_batch``: the caller feeds batches of any size (the classifier's patches); on a GPU
    provider, where a change of batch size stalls the session, each is fed as ``GPU_BATCH`` rows.
    """

    def __init__(
        self,
        path: str,
        backend: str = "cpu",
        threads: int = 0,
        fp16: bool = True,
        engine_cache_dir: Optional[str] = None,
        expected_inputs: Optional[Dict[str, Any]] = None,
        config_key: str = "model",
        warmup_hw: Optional[Tuple[int, int]] = None,
        varying_batch: bool = False,
    ) -> None:
        expected_inputs = {"images": 3} if expected_inputs is None else dict(expected_inputs)
        self.path = path
        # the config field and the file, for every message about this model (contract checks included)
        self.where = where = "%s: %s" % (config_key, path)
        if not os.path.isfile(path):
            raise ModelError("%s: no such model file" % where)
        ort = _ort()
        cache_dir = None
        if engine_cache_dir is not None:
            # keyed by model content and precision; ORT checks the TensorRT version in its engine names
            cache_dir = os.path.join(engine_cache_dir, "%s-%s" % (_file_digest(path), "fp16" if fp16 else "fp32"))
            os.makedirs(cache_dir, exist_ok=True)
        providers = providers_for(backend, fp16, cache_dir)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = intra_op_threads(threads)
        # one graph node at a time: no inter-op pool beside the intra-op one
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.inter_op_num_threads = 1
        # FATAL only: ORT's errors reach us as exceptions, which the service reports once a summary
        # interval; at ERROR it would also print each one itself (a line a frame when every frame fails).
        opts.log_severity_level = 4
        # Idle intra-op threads must sleep, not spin: on 2-6 cores a spinning ORT worker takes a
        # core from the OpenCV work (decode, optical flow) that follows each inference.
        # Measured on 2 cores (docs/notebook/2026-11-22.md, "Speed work"): 146 -> 230 FPS,
        # p99 latency 23 -> 8 ms, 640x512.
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(path, sess_options=opts, providers=providers)
        except Exception as exc:  # ORT raises its own exception types for unreadable/invalid graphs
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ModelError("%s: not a usable ONNX model: %s" % (where, first[:200])) from None
        inputs = {i.name: i.shape for i in self.session.get_inputs()}
        for name, channels in expected_inputs.items():
            shape = inputs.get(name)
            if isinstance(channels, tuple):  # a full shape, None where any size goes ([N, T, F] rows)
                if not _shape_fits(shape, channels):
                    found = ", ".join("'%s' %s" % (n, _describe(s)) for n, s in inputs.items()) or "no inputs"
                    raise ModelError("%s: expected input '%s' %s, found %s" % (
                        where, name, _describe(["*" if d is None else d for d in channels]), found))
                continue
            ok = shape is not None and len(shape) == 4 and (not isinstance(shape[1], int) or shape[1] == channels)
            if not ok:
                found = ", ".join("'%s' %s" % (n, _describe(s)) for n, s in inputs.items()) or "no inputs"
                raise ModelError("%s: expected input '%s' [N,%d,H,W], found %s" % (where, name, channels, found))
            if warmup_hw is not None:
                _check_fixed_dims(where, config_key, name, shape, channels, warmup_hw)
        self.input_shapes = {n: list(inputs[n]) for n in expected_inputs}
        self._channels = expected_inputs
        self.output_names = [o.name for o in self.session.get_outputs()]
        self.providers = list(self.session.get_providers())
        wanted = providers[0][0] if isinstance(providers[0], tuple) else providers[0]
        log.info("model loaded path=%s provider=%s providers=%s", path, self.providers[0], ",".join(self.providers))
        if self.providers[0] != wanted:
            log.warning("provider fallback path=%s wanted=%s got=%s", path, wanted, self.providers[0])
        self.pad_batch = bool(varying_batch) and self.providers[0] != CPU
        self._warm_up(warmup_hw or (_WARMUP_HW, _WARMUP_HW), GPU_BATCH if self.pad_batch else 1)

    def _warm_up(self, hw: Tuple[int, int], batch: int = 1) -> None:
        feeds = {}
        for name, shape in self.input_shapes.items():
            spec = self._channels[name]
            default = tuple(1 if d is None else d for d in spec) if isinstance(spec, tuple) else (1, spec, hw[0], hw[1])
            dims = [d if isinstance(d, int) and d > 0 else default[i] for i, d in enumerate(shape)]
            dims[0] = batch if not isinstance(shape[0], int) or shape[0] <= 0 else dims[0]
            feeds[name] = np.zeros(dims, np.float32)
        try:
            self.session.run(None, feeds)
        except Exception as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ModelError("%s: warm-up inference failed: %s" % (self.where, first[:200])) from None

    def run(self, feeds: Dict[str, np.ndarray]) -> List[np.ndarray]:
        if not self.pad_batch:
            return self.session.run(None, feeds)
        n = len(next(iter(feeds.values())))
        if n > GPU_BATCH:
            parts = [self.run({k: v[i:i + GPU_BATCH] for k, v in feeds.items()}) for i in range(0, n, GPU_BATCH)]
            return [np.concatenate(outs) for outs in zip(*parts)]
        if n < GPU_BATCH:
            feeds = {k: np.concatenate([v, np.zeros((GPU_BATCH - n,) + v.shape[1:], v.dtype)]) for k, v in feeds.items()}
        return [out[:n] for out in self.session.run(None, feeds)]

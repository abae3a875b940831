"""``glad-payload bench``: the speed profile of one clip, or ``--ablation`` over a split.

  glad-payload bench [CLIP] [--frames N] [--runner glad|global|tiled] [--paced FPS] [--no-stream] [--json OUT.json]
  glad-payload bench --ablation [--split val | --clips A.mp4 ...] [--limit N] [--rows NAME ...]

Without CLIP (or --split/--clips for the ablation) the bench renders the built-in synthetic
scene (capture.synthetic in the config: 1920x1080 by default) to a temporary MP4 with its
labels, so decoding is real video decoding, as from a file. The payload loop then runs three
times more, with the live video on, off, on (video section of the config, RTSP with a client
connected), and the best FPS off and on are printed; --no-stream skips those runs. With --paced
FPS the clip plays as a camera at that rate through the service's paced source (capture.pace:
decoded on its own thread, newest frame wins) and the frames the loop missed (dropped) and the
source decoded too late (late) are printed with the latency from capture stamp to MAVLink send.
"""

import json
import logging
import math
import os
import sys
import tempfile
from typing import List

from payload.config import Config, load_config
from payload.errors import DataError
from payload.offline import (
    UsageError,
    clips_from_paths,
    find_splits,
    split_clips,
    synthetic_clip,
    synthetic_clips,
)

log = logging.getLogger(__name__)

SYNTHETIC_FRAMES = 150


def _f(value: float, digits: int = 1) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else "%.*f" % (digits, value)


def format_profile(report) -> str:
    """The profile as a text table (payload.bench.profile.BenchReport)."""
    w, h = report.size_wh
    lines = [
        "bench %s on %s (%dx%d, %d frames)" % (report.runner, report.source, w, h, report.frames),
        "onnxruntime providers=%s threads=%s cpus=%d load_avg=%s" % (
            ",".join(report.providers) or "-",
            report.threads or "auto (one fewer than the cores, at least 1)", report.cpu_count,
            "/".join("%.1f" % v for v in report.load_avg)),
        "",
        "%-11s %6s %7s %9s %9s %9s %9s" % ("module", "runs", "share%", "median_ms", "p95_ms", "p99_ms", "mean_ms"),
    ]
    for m in report.modules:
        lines.append("%-11s %6d %7.1f %9.2f %9.2f %9.2f %9.2f" % (m.name, m.runs, 100 * m.share, m.median_ms,
                                                                   m.p95_ms, m.p99_ms, m.mean_ms))
    lines.append("")
    if report.paced_fps:
        lines.append("paced at %g fps: frames processed %d, dropped %d (missed by the loop), late %d (decoding "
                     "behind the rate)" % (report.paced_fps, report.frames, report.frames_dropped, report.frames_late))
    lines += [
        "fps end-to-end (decode+detect+send)  %8s" % _f(report.fps_end_to_end),
        "fps without decoding                 %8s" % _f(report.fps_without_decode),
        "fps decode only (ceiling)            %8s" % _f(report.fps_decode_only),
        "end-to-end / decode-only             %8s" % _f(report.decode_ratio, 3),
        "fps end-to-end, live video off / on  %8s / %s  (on/off %s; best of 2 alternating passes each)" % (
            _f(report.fps_stream_off), _f(report.fps_stream_on), _f(report.fps_stream_on / report.fps_stream_off, 3)),
        "live video                           %s; %d frames encoded, %d dropped" % (
            report.stream, report.stream_frames, report.stream_dropped),
        "latency capture->MAVLink sent ms     p50 %s  p99 %s  max %s  (from the %s)" % (
            _f(report.latency_p50_ms, 2), _f(report.latency_p99_ms, 2), _f(report.latency_max_ms, 2),
            "capture stamp" if report.paced_fps else "read request"),
        "modes %s; frames with target %d; MAVLink messages sent %d, received on 127.0.0.1 %d" % (
            " ".join("%s=%d" % kv for kv in sorted(report.modes.items())), report.frames_with_target,
            report.messages_sent, report.messages_received),
    ]
    return "\n".join(lines)


def format_ablation(results) -> str:
    """One row per configuration: pooled P/R/F/AP, FPS, and how often each module ran."""
    width = max([len("configuration")] + [len(r.row.name) for r in results])
    header = "%-*s %6s %6s %6s %6s %6s %6s %6s %6s %8s %8s  %s" % (
        width, "configuration", "frames", "tp", "fp", "P", "R", "F", "AP", "det%", "fps_det", "fps_e2e",
        "modules ran (frames)")
    lines = [header, "-" * len(header)]
    for r in results:
        p = r.pooled
        runs = " ".join("%s=%d" % (k, v) for k, v in sorted(r.module_runs.items()))
        lines.append("%-*s %6d %6d %6d %6s %6s %6s %6s %6s %8s %8s  %s" % (
            width, r.row.name, r.frames, p.tp, p.fp, _f(p.precision, 3), _f(p.recall, 3), _f(p.f1, 3),
            _f(p.ap, 3), _f(100.0 * p.frames_with_detections), _f(r.fps_detect), _f(r.fps_end_to_end), runs or "-"))
    return "\n".join(lines)


def _write_json(path: str, data) -> None:
    try:
        with open(path, "w", encoding="utf-8") as handle:
            json.dump(data, handle, indent=2, default=lambda v: None)
            handle.write("\n")
    except OSError as exc:
        raise DataError("%s: cannot write JSON: %s" % (path, exc.strerror or exc)) from None


def _nan_to_none(data):
    if isinstance(data, float) and math.isnan(data):
        return None
    if isinstance(data, dict):
        return {k: _nan_to_none(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [_nan_to_none(v) for v in data]
    return data


def _ablation_clips(args, cfg: Config, tmp: str) -> List:
    if args.split and args.clips:
        raise UsageError("--ablation: give --split or --clips, not both")
    if args.split:
        return split_clips(find_splits(args.splits), args.split)
    if args.clips:
        return clips_from_paths(args.clips, args.labels)
    if args.synthetic:
        return synthetic_clips(cfg, tmp, args.frames or SYNTHETIC_FRAMES, args.synthetic, args.target_px)
    return [synthetic_clip(cfg, tmp, args.frames or SYNTHETIC_FRAMES)]


def main_bench(args) -> int:
    cfg = load_config(args.config)
    with tempfile.TemporaryDirectory(prefix="glad-bench-") as tmp:
        try:
            if args.ablation:
                return _ablation(args, cfg, tmp)
            return _profile(args, cfg, tmp)
        except UsageError as exc:
            print("glad-payload bench: %s" % exc, file=sys.stderr)
            return 2


def _profile(args, cfg: Config, tmp: str) -> int:
    from payload.bench.profile import run_bench
    from payload.bench.runners import build_runner

    paced = getattr(args, "paced", None)
    if paced is not None and not 0 < paced < 1000:
        raise UsageError("--paced %g: expected a camera rate in frames per second, above 0 and below 1000" % paced)
    source = args.source
    if source is None:
        source = synthetic_clip(cfg, tmp, args.frames or SYNTHETIC_FRAMES).video
    elif not os.path.exists(source):
        raise DataError("bench %s: no such file or folder" % source)
    runner = build_runner(cfg, args.runner)
    report = run_bench(cfg, source, runner, runner_name=args.runner, frames=args.frames,
                       stream=not args.no_stream, paced_fps=paced or 0.0)
    print(format_profile(report))
    if args.json:
        _write_json(args.json, _nan_to_none(report.as_dict()))
        print("wrote %s" % args.json)
    return 0


def _ablation(args, cfg: Config, tmp: str) -> int:
    from payload.bench.ablation import run_row, select_rows

    rows = select_rows(args.rows)
    clips = _ablation_clips(args, cfg, tmp)
    results = []
    for row in rows:
        results.append(run_row(cfg, row, clips, limit=args.limit))
        if not args.no_progress:
            print("done: %s" % row.name, file=sys.stderr)
    print(format_ablation(results))
    if args.json:
        _write_json(args.json, _nan_to_none({
            "clips": [c.name for c in clips], "limit": args.limit, "iou_match": 0.5,
            "cpu_count": os.cpu_count(), "load_avg": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
            "rows": [r.as_dict() for r in results]}))
        print("wrote %s" % args.json)
    return 0


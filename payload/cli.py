"""The ``glad-payload`` command line. Each subcommand lives in the module that owns the work;
this file only parses arguments and turns PayloadError into a one-line message and exit code."""

import argparse
import logging
import sys
from typing import List, Optional

from payload import __version__
from payload.errors import ConfigError, PayloadError
from payload.synth import seed_range


def _add_synthetic_args(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--synthetic", nargs="+", type=seed_range, default=[], metavar="SEED",
                   help="%s rendered synthetic clips (capture.synthetic scene) with these seeds, e.g. 100-109" % what)
    p.add_argument("--target-px", nargs=2, type=float, default=None, metavar=("MIN", "MAX"),
                   help="--synthetic: drone size range in px (default capture.synthetic.target_px)")


def _check_config(args) -> int:
    from payload.config import load_run_config

    load_run_config(args.file)  # what run loads: the values and the files they name
    print("%s: OK" % args.file)
    return 0


def _synth(args) -> int:
    from payload.synth.export import main_synth

    return main_synth(args)


def _detect(args) -> int:
    from payload.detect_cmd import main_detect

    return main_detect(args)


def _eval(args) -> int:
    from payload.eval.cli import main_eval

    return main_eval(args)


def _cv(args) -> int:
    from payload.eval.cv_cmd import main_cv

    return main_cv(args)


def _run(args) -> int:
    from payload.service import main_run

    return main_run(args)


def _demo(args) -> int:
    from payload.demo import main_demo

    return main_demo(args)


def _soak(args) -> int:
    from payload.soak.runner import main_soak

    return main_soak(args)


def _geo_error(args) -> int:
    from payload.eval.geo_error import main_geo_error

    return main_geo_error(args)


def _bench(args) -> int:
    from payload.bench.cli import main_bench

    return main_bench(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="glad-payload",
        description="Onboard drone-to-drone detection (GLAD) with MAVLink bearing output.",
    )
    parser.add_argument("--version", action="version", version="glad-payload " + __version__)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("check-config", help="validate a YAML config file; one line per problem")
    p.add_argument("file", help="YAML file")
    p.set_defaults(func=_check_config)

    p = sub.add_parser("run", help="run the payload service: camera -> GLAD -> MAVLink")
    p.add_argument("--config", "-c", default=None, help="YAML file (default: built-in defaults)")
    p.add_argument("--frames", type=int, default=0, help="stop after this many frames (0 = run until stopped)")
    p.set_defaults(func=_run)

    p = sub.add_parser("demo", help="the whole payload on a synthetic scene against a fake autopilot on loopback")
    p.add_argument("--out", default="demo-output", help="output folder for the annotated video and detections")
    p.add_argument("--frames", type=int, default=300, help="frames to process")
    p.add_argument("--config", "-c", default=None, help="YAML file (capture and mavlink sections are overridden)")
    p.set_defaults(func=_demo)

    p = sub.add_parser("detect", help="run GLAD over a video file or image folder and write detections CSV")
    p.add_argument("source", help="video file or image folder")
    p.add_argument("--out", required=True, help="detections CSV: frame,x,y,w,h,score,module,target_id,primary (every reported target; primary 1: the one sent)")
    p.add_argument("--config", "-c", default=None, help="YAML file (default: built-in defaults)")
    p.add_argument("--video", default=None, help="also write an annotated video here")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_detect)

    p = sub.add_parser("eval", help="score detections against labels (P, R, F, AP at IoU > 0.5)")
    p.add_argument("--dets", nargs="*", default=[], help="detections CSV(s) to score (with --labels)")
    p.add_argument("--labels", nargs="*", default=[], help="label file(s) or folder(s), one per --dets")
    p.add_argument("--split", default=None, help="run detect+score on a split of splits.json, e.g. val")
    p.add_argument("--splits", default=None, help="splits.json (default: ../shared/data/halmstad/splits.json)")
    p.add_argument("--clips", nargs="*", default=[], help="video files to run detect+score on (labels beside or in --labels)")
    p.add_argument("--config", "-c", default=None,
                   help="YAML file for detect and the camera model (default: built-in defaults)")
    p.add_argument("--json", default=None, help="also write the table as JSON here")
    p.add_argument("--limit", type=int, default=0, help="only the first N frames of each clip (0 = all)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_synthetic_args(p, "run detect+score on")
    p.add_argument("--frames", type=int, default=150, help="--synthetic: frames per clip")
    p.add_argument("--ego-motion", type=int, default=None, metavar="SEED",
                   help="--split/--clips: warp every frame (and its labels) as if the camera turned, rolled, "
                        "zoomed and shook, one camera path per clip from SEED")
    p.add_argument("--iou", type=float, default=0.5,
                   help="a detection matches a labelled box when their IoU exceeds this (default 0.5, the paper's)")
    p.add_argument("--frame-size", nargs=2, type=int, default=None, metavar=("W", "H"),
                   help="--dets: frame size of the scored clips, for the bearing error (camera section of --config)")
    p.set_defaults(func=_eval)

    p = sub.add_parser("geo-error", help="range-from-size and FOLLOW_TARGET position error on synthetic scenes of known geometry")
    from payload.eval.geo_error import add_arguments as add_geo_error_arguments

    add_geo_error_arguments(p)
    p.add_argument("--synthetic", nargs="+", type=seed_range, default=[], metavar="SEED",
                   help="scene seeds, e.g. 100-109 (default 100-109)")
    p.set_defaults(func=_geo_error)

    p = sub.add_parser("cv", help="grouped cross-validation of GLAD over the Halmstad clips: per fold, mean +- sd")
    p.add_argument("--config", "-c", default=None, help="YAML file (default: built-in defaults)")
    p.add_argument("--folds", default=None, help="fold definition (default: payload/eval/folds.json)")
    p.add_argument("--fold-models", default=None, metavar="DIR",
                   help="DIR/fold{k}/glad_global.onnx, glad_local.onnx, glad_classifier.onnx (training/cv_train.py) "
                        "and glad_verifier.onnx (training/train_verifier.py --export-folds), trained without fold k "
                        "(default: the shipped models, which saw these clips: optimistic)")
    p.add_argument("--splits", default=None, help="Halmstad splits.json, to find the data (default: ../shared/data/halmstad)")
    p.add_argument("--limit", type=int, default=0, help="only the first N frames of each clip (0 = all)")
    p.add_argument("--limit-clips", type=int, default=0, metavar="N",
                   help="only N clips of each kind per fold, spread over its clip numbers (0 = all)")
    p.add_argument("--folds-only", type=int, nargs="+", default=None, metavar="K",
                   help="run only these folds (e.g. the folds whose models are trained so far)")
    p.add_argument("--dets-dir", default=None, metavar="DIR",
                   help="keep each clip's detections here; a rerun with the same settings resumes / re-scores from them")
    p.add_argument("--iou", type=float, default=0.5, help="IoU a match must exceed (default 0.5, the paper's)")
    p.add_argument("--ego-motion", type=int, default=None, metavar="SEED",
                   help="warp every clip (frames and labels) as if the camera turned, rolled, zoomed and shook, one "
                        "camera path per clip from SEED: the payload flies, most Halmstad clips are filmed from the ground")
    p.add_argument("--json", default=None, help="write every figure (per fold, per clip, summary) as JSON here")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cv)

    p = sub.add_parser("bench", help="speed profile of a clip (per module, FPS, latency) or --ablation (Table V + baselines)")
    p.add_argument("source", nargs="?", default=None,
                   help="video file or image folder (default: render the synthetic scene of capture.synthetic)")
    p.add_argument("--config", "-c", default=None, help="YAML file (default: built-in defaults)")
    p.add_argument("--frames", type=int, default=0,
                   help="frames to profile (0 = the whole clip; the synthetic clip has 150 unless given)")
    p.add_argument("--runner", choices=("glad", "global", "tiled"), default="glad",
                   help="GLAD, or a baseline: the global detector alone, or tiled full-resolution inference")
    p.add_argument("--json", default=None, help="also write the report as JSON here")
    p.add_argument("--no-stream", action="store_true",
                   help="skip the payload-loop runs with the live video on and off (RTSP, a client connected)")
    p.add_argument("--paced", type=float, default=None, metavar="FPS",
                   help="play the clip as a camera at FPS, as capture.pace does (decoded on its own thread, "
                        "newest frame wins): frames dropped and late, latency from the capture stamp")
    p.add_argument("--ablation", action="store_true", help="score the Table V configurations and the baselines")
    p.add_argument("--rows", nargs="*", default=None, help="ablation: only these rows, by name")
    p.add_argument("--split", default=None, help="ablation: clips of a split of splits.json, e.g. val")
    p.add_argument("--splits", default=None, help="splits.json (default: ../shared/data/halmstad/splits.json)")
    p.add_argument("--clips", nargs="*", default=[], help="ablation: video files (labels beside or in --labels)")
    p.add_argument("--labels", nargs="*", default=[], help="ablation: label file(s) or folder for --clips")
    p.add_argument("--limit", type=int, default=0, help="ablation: only the first N frames of each clip")
    p.add_argument("--no-progress", action="store_true", help="no per-row progress lines")
    _add_synthetic_args(p, "ablation:")
    p.set_defaults(func=_bench)

    p = sub.add_parser("soak", help="run the service N minutes against the fake autopilot with faults; report")
    from payload.soak import add_arguments as add_soak_arguments

    add_soak_arguments(p)
    p.set_defaults(func=_soak)

    p = sub.add_parser("synth", help="render a synthetic air-to-air clip: MP4 + per-frame labels CSV")
    p.add_argument("out", help="output folder")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--background", default=None, help="video whose frames become the ground")
    p.add_argument("--name", default=None, help="clip name (default SYN_<seed>)")
    p.set_defaults(func=_synth)
    return parser


def main(argv: Optional[List[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "synthetic", None):
        args.synthetic = [seed for seeds in args.synthetic for seed in seeds]
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(args.func(args) or 0)
    except ConfigError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return 2
    except PayloadError as exc:
        print("glad-payload: %s" % exc, file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""``glad-payload geo-error``: the range-from-size error model and the FOLLOW_TARGET position error,
measured on synthetic scenes whose geometry is known.

A synthetic scene's drone is a direction from the camera and a span in pixels; a drone ``--span-m``
across is then at the true range R = span_m * f * zoom / span_px (f: the scene's focal length at
zoom 1). The payload's estimate comes from the box it is given, through the same code as in
flight (``payload.geometry.locate`` with the camera model of that frame's lens, the frame's camera
attitude as the vehicle's, zero mount, and the camera's position as the vehicle's
GLOBAL_POSITION_INT). Boxes (``--boxes``): ``truth``, the tight box of the drone's visible pixels
(the error of the size model alone: pose and blur), or ``glad``, GLAD's measured targets matched
to the truth (adds the detector's box noise). Frames where the drone is partly hidden or cut by
the image edge are left out (a cut box says nothing of the range).

Prints, per box-size bin, the median and 95th percentile of |range error| / range, and the
position error of what FOLLOW_TARGET would send (those frames the ``target`` section's
``max_relative_uncertainty`` lets through); ``--json`` keeps every sample for the plot
(bench/plot_geo_error.py).
"""

import json
import logging
from typing import Dict, List, Optional

import numpy as np

from payload.boxes import iou_matrix
from payload.config import CameraConfig, Config, config_with, load_config
from payload.geometry import (
    Attitude,
    BearingModel,
    CameraModel,
    GeoModel,
    Position,
    locate,
    mount_rotation,
    ned_between,
    offset_position,
)
from payload.types import Target

log = logging.getLogger(__name__)

HOME = Position(47.397742, 8.545594, 488.0)
BINS_PX = (4, 8, 16, 32, 64, 128)
_MIN_VISIBLE = 0.95  # share of the drone's pixels in view and not hidden


def _ned(world_xyz) -> np.ndarray:
    """The synthetic world frame (x right/east, y down, z forward/north) as NED."""
    x, y, z = (float(c) for c in world_xyz)
    return np.array([z, x, y])


def _boxes_from_glad(cfg: Config, scene) -> Dict[int, np.ndarray]:
    from payload.detect.pipeline import Glad
    from payload.types import Frame

    glad = Glad(cfg.detector)
    out = {}
    for sf in scene:
        r = glad.process(Frame(sf.image, sf.index, int(sf.index * 1e9 / scene.fps), 0))
        if r.target is not None and r.target.measured:
            out[sf.index] = np.asarray(r.target.xyxy, np.float64)
    return out


def measure(cfg: Config, seeds: List[int], frames: int, span_m: float, boxes: str, width: int, height: int,
            hfov_deg: float = 60.0) -> List[dict]:
    """One sample per frame with a usable box: size, true and estimated range, position error."""
    from payload.synth.scene import Scene

    target_cfg = cfg.target.model_copy(update={"span_m": span_m})
    samples = []
    for seed in seeds:
        scene = Scene(seed=seed, width=width, height=height, fps=30.0, frames=frames, hfov_deg=hfov_deg)
        detected = _boxes_from_glad(cfg, scene) if boxes == "glad" else None
        f1 = scene.lens.focal_px
        for sf in scene.truth():
            truth = sf.target_xyxy
            if truth is None or sf.target_visible < _MIN_VISIBLE:
                continue
            if truth[0] <= 0 or truth[1] <= 0 or truth[2] >= width or truth[3] >= height:
                continue
            box = truth.astype(np.float64)
            if detected is not None:
                box = detected.get(sf.index)
                if box is None or iou_matrix(box, truth)[0, 0] <= 0.1:
                    continue
            f = f1 * sf.camera_zoom
            # the lens of this frame as a calibration: principal point at the image centre
            cam_cfg = CameraConfig(matrix=(f, f, width / 2.0 - 0.5, height / 2.0 - 0.5))
            camera = CameraModel.from_config(cam_cfg, (width, height))
            true_range = span_m * f / sf.target_span_px
            cam_ned = _ned(sf.camera_position_m)
            vehicle = offset_position(HOME, cam_ned)
            true_ned = cam_ned + true_range * _ned(sf.target_direction)
            attitude = Attitude(*sf.camera_rpy_rad)
            target = Target(sf.index, 0, box.astype(np.float32), 1.0, "GT", True)
            geo = locate(target, camera, mount_rotation(), attitude, vehicle, span_m,
                         target_cfg.size_noise_px, target_cfg.shape_uncertainty)
            est_ned = ned_between(HOME, Position(geo.lat_deg, geo.lon_deg, geo.alt_m))
            sent = GeoModel(target_cfg, BearingModel(cam_cfg)).locate(target, (width, height), attitude, vehicle)
            samples.append({
                "seed": seed, "frame": sf.index, "size_px": float(max(box[2] - box[0], box[3] - box[1])),
                "span_px": float(sf.target_span_px), "range_m": float(true_range), "range_est_m": float(geo.range_m),
                "range_sigma_m": float(geo.range_sigma_m), "position_error_m": float(np.linalg.norm(est_ned - true_ned)),
                "sent": sent is not None,
            })
    return samples


def summarize(samples: List[dict]) -> dict:
    def stats(values) -> Optional[dict]:
        if not len(values):
            return None
        v = np.asarray(values)
        return {"n": int(len(v)), "median": float(np.median(v)), "p95": float(np.percentile(v, 95))}

    rel = [abs(s["range_est_m"] - s["range_m"]) / s["range_m"] for s in samples]
    out = {"all": stats(rel), "bins": []}
    for lo, hi in zip(BINS_PX[:-1], BINS_PX[1:]):
        sel = [r for r, s in zip(rel, samples) if lo <= s["size_px"] < hi]
        out["bins"].append({"size_px": [lo, hi], "range_rel_error": stats(sel)})
    sent = [s for s in samples if s["sent"]]
    out["follow_target"] = {
        "sent_share": len(sent) / max(len(samples), 1),
        "position_error_m": stats([s["position_error_m"] for s in sent]),
        "position_error_rel": stats([s["position_error_m"] / s["range_m"] for s in sent]),
        "range_m": stats([s["range_m"] for s in sent]),
    }
    return out


def _fmt(st: Optional[dict], scale: float = 100.0, unit: str = "%") -> str:
    if st is None:
        return "      -"
    return "%5.1f%s / %5.1f%s (n=%d)" % (st["median"] * scale, unit, st["p95"] * scale, unit, st["n"])


def main_geo_error(args) -> int:
    cfg = load_config(args.config) if args.config else Config()
    if args.max_relative_uncertainty is not None:
        cfg = config_with(cfg, **{"target.max_relative_uncertainty": args.max_relative_uncertainty})
    seeds = list(args.synthetic) or list(range(100, 110))  # (main flattens the ranges)
    samples = measure(cfg, seeds, args.frames, args.span_m, args.boxes, args.width, args.height)
    if not samples:
        print("no frame with a usable box")
        return 1
    summary = summarize(samples)
    print("range from apparent size: span %.2f m, %s boxes, %d frames of %d synthetic scenes (%dx%d)"
          % (args.span_m, args.boxes, len(samples), len(seeds), args.width, args.height))
    print("  |range error| / range, median / p95")
    print("    all boxes        %s" % _fmt(summary["all"]))
    for b in summary["bins"]:
        print("    %3d-%3d px       %s" % (b["size_px"][0], b["size_px"][1], _fmt(b["range_rel_error"])))
    ft = summary["follow_target"]
    print("  FOLLOW_TARGET (sent when sigma/range <= %.2f: %.0f %% of frames)"
          % (cfg.target.max_relative_uncertainty, 100 * ft["sent_share"]))
    print("    position error   %s" % _fmt(ft["position_error_m"], 1.0, " m"))
    print("    / true range     %s" % _fmt(ft["position_error_rel"]))
    print("    true range       %s" % _fmt(ft["range_m"], 1.0, " m"))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"settings": {"span_m": args.span_m, "boxes": args.boxes, "seeds": seeds, "frames": args.frames,
                                    "width": args.width, "height": args.height,
                                    "target": cfg.target.model_dump()},
                       "summary": summary, "samples": samples}, fh)
        print("  samples -> %s" % args.json)
    return 0


def add_arguments(p) -> None:
    p.add_argument("--span-m", type=float, default=0.5, help="the drones' span in metres (default 0.5)")
    p.add_argument("--boxes", choices=("truth", "glad"), default="truth",
                   help="truth: the drone's visible-pixel box; glad: GLAD's measured targets (slower)")
    p.add_argument("--frames", type=int, default=300, help="frames per scene")
    p.add_argument("--width", type=int, default=1920)
    p.add_argument("--height", type=int, default=1080)
    p.add_argument("--max-relative-uncertainty", type=float, default=None,
                   help="override target.max_relative_uncertainty for the FOLLOW_TARGET figures")
    p.add_argument("--config", "-c", default=None, help="YAML file: the target section's noise model (default built-in)")
    p.add_argument("--json", default=None, help="write every sample and the summary as JSON here")


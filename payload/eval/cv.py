"""Grouped cross-validation of GLAD over the Halmstad clips (``glad-payload cv``).

Each fold of payload/eval/folds.py holds out whole blocks of consecutive clip numbers of every
kind; GLAD runs on the held-out clips with that fold's networks (``DIR/fold{k}/glad_*.onnx``,
trained without them by training/cv_train.py) or, without a models folder, with the shipped
networks, which saw most of these clips in training: then only the thresholds and rules are
checked honestly and the network side is optimistic.

Four groups are scored per fold: visible drones and thermal drones (P/R/F/AP at IoU > 0.5
and by centre-in-box, bearing error), visible and thermal negatives (birds, airliners,
helicopters: the share of frames in which a target is reported, every one of them false).
Per metric: each fold, mean and sample standard deviation over the folds, and all folds pooled.
"""

import functools
import hashlib
import json
import logging
import math
import os
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from payload.errors import DataError
from payload.eval.folds import Folds, parse_clip
from payload.eval.metrics import IOU_MATCH, ClipScore, pool
from payload.offline import ClipSpec, DetectFn, UsageError, recorded_name, score_clips
from payload.records import DetectionsCsvWriter, read_detections_csv
from payload.types import Detections

log = logging.getLogger(__name__)

DRONE_GROUPS = ("visible drones", "thermal drones")
NEGATIVE_GROUPS = ("visible negatives", "thermal negatives")
GROUPS = DRONE_GROUPS + NEGATIVE_GROUPS
#: config key -> file name in DIR/fold{k}/
#: The networks that find and judge a box (training/cv_train.py); what mining locks runs.
DETECTOR_FILES = (
    ("detector.global.appearance.model", "glad_global.onnx"),
    ("detector.local.appearance.model", "glad_local.onnx"),
    ("detector.classifier.model", "glad_classifier.onnx"),
)
#: And the lock verifier: the shipped one learned every fold's locks; a fold's own comes from
#: training/train_verifier.py --export-folds.
MODEL_FILES = DETECTOR_FILES + (("detector.verifier.model", "glad_verifier.onnx"),)
SHIPPED_NOTE = "shipped models: trained on clips in these folds, figures optimistic"

#: (column, JSON key, value of a pooled group score); drone groups
DRONE_METRICS: Tuple[Tuple[str, str, Callable[[ClipScore], float]], ...] = (
    ("P", "precision", lambda s: s.precision),
    ("R", "recall", lambda s: s.recall),
    ("F", "f1", lambda s: s.f1),
    ("AP", "ap", lambda s: s.ap),
    ("cP", "centre_precision", lambda s: s.centre.precision if s.centre else math.nan),
    ("cR", "centre_recall", lambda s: s.centre.recall if s.centre else math.nan),
    ("cF", "centre_f1", lambda s: s.centre.f1 if s.centre else math.nan),
    ("cAP", "centre_ap", lambda s: s.centre.ap if s.centre else math.nan),
    ("deg50", "bearing_median_deg", lambda s: s.bearing_median_deg),
    ("deg95", "bearing_p95_deg", lambda s: s.bearing_p95_deg),
)
NEGATIVE_METRICS: Tuple[Tuple[str, str, Callable[[ClipScore], float]], ...] = (
    ("target%", "frames_with_target", lambda s: s.frames_with_detections),
)


def group_of(name: str) -> str:
    """``V_DRONE_013`` -> 'visible drones', ``IR_BIRD_004`` -> 'thermal negatives' (also as
    ``V_DRONE_013~ego7``, warped by ``--ego-motion``)."""
    kind, _ = parse_clip(recorded_name(name))
    sensor = "visible" if kind.startswith("V_") else "thermal"
    return "%s %s" % (sensor, "drones" if kind.endswith("_DRONE") else "negatives")


def halmstad_clips(data_dir: str) -> List[ClipSpec]:
    """Every clip of ``data_dir``/{visible,ir} with its labels (labels/<clip>.csv)."""
    clips = []
    for sub in ("visible", "ir"):
        folder = os.path.join(data_dir, sub)
        if not os.path.isdir(folder):
            raise UsageError("%s: no such folder (the Halmstad data: visible/, ir/, labels/)" % folder)
        for entry in sorted(os.listdir(folder)):
            stem, ext = os.path.splitext(entry)
            if ext.lower() != ".mp4":
                continue
            try:
                parse_clip(stem)
            except DataError:
                log.warning("cv: %s: not a Halmstad clip name, left out", os.path.join(folder, entry))
                continue
            labels = os.path.join(data_dir, "labels", stem + ".csv")
            if not os.path.isfile(labels):
                raise UsageError("clip %s: no labels at %s" % (stem, labels))
            clips.append(ClipSpec(stem, os.path.join(folder, entry), labels))
    if not clips:
        raise UsageError("%s: no clips in visible/ or ir/" % data_dir)
    return clips


def fold_clips(clips: Sequence[ClipSpec], folds: Folds, limit_clips: int = 0) -> List[List[ClipSpec]]:
    """The clips each fold holds out; ``limit_clips`` > 0 keeps that many of each kind per fold,
    spread evenly over the fold's clip numbers (a quick check, not the measure)."""
    held = folds.split([c.name for c in clips])
    by_name = {c.name: c for c in clips}
    out = []
    for names in held:
        if limit_clips > 0:
            kinds: Dict[str, List[str]] = {}
            for name in names:
                kinds.setdefault(parse_clip(name)[0], []).append(name)
            names = []
            for kind in sorted(kinds):
                members = kinds[kind]
                keep = np.unique(np.linspace(0, len(members) - 1, min(limit_clips, len(members))).round().astype(int))
                names += [members[i] for i in keep]
        out.append([by_name[n] for n in names])
    return out


def fold_model_files(models_dir: str, folds: Sequence[Union[int, str]],
                     wanted: Sequence[Tuple[str, str]] = MODEL_FILES) -> Dict[Union[int, str], Dict[str, str]]:
    """Per fold, config key -> ONNX file under ``models_dir``/fold{k}/ (``models_dir``/all/ for the
    fold "all": the networks trained on every fold); all ``wanted`` must exist."""
    out, missing = {}, []
    for fold in folds:
        files = {}
        for key, name in wanted:
            path = os.path.join(models_dir, "all" if fold == "all" else "fold%d" % fold, name)
            if not os.path.isfile(path):
                missing.append(path)
            files[key] = path
        out[fold] = files
    if missing:
        hint = ("; a fold's verifier comes from training/train_verifier.py --export-folds %s" % models_dir
                if any(p.endswith("glad_verifier.onnx") for p in missing) else "")
        raise UsageError("--fold-models %s: missing %s%s" % (models_dir, ", ".join(missing), hint))
    return out


def model_digests(cfg) -> Dict[str, str]:
    """SHA-256 (first 16 hex digits) of the ONNX files a config runs (shipped where unset), so
    that detections kept from other weights at the same path are not taken for these."""
    from payload.detect.factory import builtin_model_path

    files = {"global": cfg.detector.global_.appearance.model, "local": cfg.detector.local.appearance.model,
             "classifier": cfg.detector.classifier.model}
    if cfg.detector.verifier.enabled:
        files["verifier"] = cfg.detector.verifier.model
    out = {}
    for name, path in sorted(files.items()):
        path = path or builtin_model_path(name)
        digest = hashlib.sha256()
        try:
            with open(path, "rb") as handle:
                for block in iter(lambda: handle.read(1 << 20), b""):
                    digest.update(block)
        except OSError as exc:
            raise DataError("%s: cannot read model: %s" % (path, exc.strerror or exc)) from None
        out[name] = digest.hexdigest()[:16]
    return out


def _last_byte(path: str) -> bytes:
    with open(path, "rb") as handle:
        handle.seek(-1, os.SEEK_END)
        return handle.read(1)


class DetectionsStore:
    """Each finished clip's detections as CSV under ``root``/fold{k}/, so that an interrupted run
    resumes where it stopped and a finished one can be scored again without running GLAD.

    ``settings`` (frame limit, fold definition, ...) and each fold's ``fold_settings`` (its config
    and models) are kept in ``root``/settings.json; other settings, or another config for a fold
    already there, are refused rather than mixed. A fold run for the first time adds its own, so
    folds can be scored one by one as their models are trained and then all together from the
    kept detections. A clip counts as done once its line is in ``root``/done.jsonl (written
    after its CSV is complete).
    """

    def __init__(self, root: str, settings: Mapping[str, Any], fold_settings: Mapping[int, Any]) -> None:
        self.root = root
        common = json.loads(json.dumps(settings, sort_keys=True, default=str))
        per_fold = json.loads(json.dumps({str(k): v for k, v in fold_settings.items()}, sort_keys=True, default=str))
        path = os.path.join(root, "settings.json")
        try:
            os.makedirs(root, exist_ok=True)
            known: Dict[str, Any] = {"common": common, "folds": {}}
            if os.path.isfile(path):
                with open(path, encoding="utf-8") as handle:
                    known = json.load(handle)
                old = known.get("common") if isinstance(known, dict) else None
                if not isinstance(old, dict) or not isinstance(known.get("folds"), dict):
                    raise UsageError("--dets-dir %s: %s is not this version's settings file; give a new folder"
                                     % (root, path))
                if old != common:
                    changed = sorted(k for k in set(old) | set(common) if old.get(k) != common.get(k))
                    raise UsageError("--dets-dir %s was made with other settings (%s differ); give a new folder"
                                     % (root, ", ".join(changed)))
                clash = sorted(k for k, v in per_fold.items() if k in known["folds"] and known["folds"][k] != v)
                if clash:
                    raise UsageError("--dets-dir %s holds fold %s with another config or models; give a new folder"
                                     % (root, ", ".join(clash)))
            known["folds"].update(per_fold)
            with open(path + ".tmp", "w", encoding="utf-8") as handle:
                json.dump(known, handle, indent=1, sort_keys=True)
            os.replace(path + ".tmp", path)
            self.done: Dict[Tuple[int, str], int] = {}
            done_path = os.path.join(root, "done.jsonl")
            if os.path.isfile(done_path):
                with open(done_path, encoding="utf-8") as handle:
                    for line in handle:
                        try:
                            row = json.loads(line)
                            self.done[(int(row["fold"]), str(row["clip"]))] = int(row["frames"])
                        except (ValueError, KeyError, TypeError):
                            continue  # a line cut by a kill: that clip runs again
        except OSError as exc:
            raise DataError("--dets-dir %s: %s" % (root, exc.strerror or exc)) from None
        except ValueError as exc:
            raise DataError("%s: not valid JSON: %s" % (path, exc)) from None

    def _csv(self, fold: int, name: str) -> str:
        return os.path.join(self.root, "fold%d" % fold, name + ".csv")

    def wrap(self, fold: int, detect: DetectFn) -> DetectFn:
        """``detect`` with its result stored, or read back when the clip is already done."""

        def stored(clip: ClipSpec) -> Dict[int, Detections]:
            key = (fold, clip.name)
            if key not in self.done:
                found = detect(clip)
                tmp = self._csv(fold, clip.name) + ".tmp"
                with DetectionsCsvWriter(tmp) as writer:
                    for index in sorted(found):
                        writer.write(index, found[index])
                os.replace(tmp, self._csv(fold, clip.name))
                frames = max(found) + 1 if found else 0
                done_path = os.path.join(self.root, "done.jsonl")
                with open(done_path, "ab") as handle:
                    # a line cut by a kill must not swallow the next one
                    cut = handle.tell() > 0 and _last_byte(done_path) != b"\n"
                    handle.write((b"\n" if cut else b"") + json.dumps(
                        {"fold": fold, "clip": clip.name, "frames": frames}).encode("utf-8") + b"\n")
                self.done[key] = frames
            else:
                log.info("cv: fold=%d clip=%s read back from %s", fold, clip.name, self._csv(fold, clip.name))
            # scored from the file in both cases, so a resumed run scores exactly as an unbroken one
            found = read_detections_csv(self._csv(fold, clip.name))
            return {i: found.get(i, Detections.empty()) for i in range(self.done[key])}

        return stored


@dataclass
class FoldResult:
    fold: int
    clips: List[ClipScore]
    groups: Dict[str, ClipScore]  # each group's clips pooled; absent where the fold has none


def group_scores(clips: Sequence[ClipScore]) -> Dict[str, ClipScore]:
    members: Dict[str, List[ClipScore]] = {}
    for score in clips:
        members.setdefault(group_of(score.name), []).append(score)
    return {group: pool(members[group], name=group) for group in GROUPS if group in members}


def run_cv(per_fold: Sequence[Sequence[ClipSpec]], detector_for: Callable[[int], DetectFn],
           camera: Optional[Callable[[Tuple[int, int]], Any]] = None, iou_match: float = IOU_MATCH,
           only: Optional[Sequence[int]] = None) -> List[FoldResult]:
    """Score each fold's held-out clips with that fold's detector (``only``: these folds)."""
    results = []
    for fold, clips in enumerate(per_fold):
        if only is not None and fold not in only:
            continue
        log.info("cv: fold %d/%d, %d clips", fold + 1, len(per_fold), len(clips))
        scores = score_clips(clips, detector_for(fold), iou_match, camera) if clips else []
        results.append(FoldResult(fold, scores, group_scores(scores)))
    return results


def _metrics(group: str):
    return DRONE_METRICS if group in DRONE_GROUPS else NEGATIVE_METRICS


def summarise(results: Sequence[FoldResult]) -> Dict[str, Dict[str, Any]]:
    """Per group and metric: the folds' values, their mean and sample sd (NaN folds left out),
    and the value of all folds pooled."""
    out: Dict[str, Dict[str, Any]] = {}
    for group in GROUPS:
        per_fold = [r.groups.get(group) for r in results]
        present = [s for s in per_fold if s is not None]
        if not present:
            continue
        pooled = pool(present, name=group)
        entry: Dict[str, Any] = {"fold_ids": [r.fold for r in results],
                                 "clips": [len([c for c in r.clips if group_of(c.name) == group]) for r in results],
                                 "frames": [s.frames if s is not None else 0 for s in per_fold],
                                 "gt": [s.gt if s is not None else 0 for s in per_fold]}
        for _, key, value in _metrics(group):
            values = [value(s) if s is not None else math.nan for s in per_fold]
            finite = [v for v in values if not math.isnan(v)]
            mean = float(np.mean(finite)) if finite else math.nan
            sd = float(np.std(finite, ddof=1)) if len(finite) > 1 else math.nan
            entry[key] = {"folds": values, "mean": mean, "sd": sd, "pooled": value(pooled)}
        out[group] = entry
    return out


def _cell(value: float, fmt: str) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else fmt % value


def _format_metric(key: str, value: float, percent: bool) -> str:
    if percent:
        return _cell(100.0 * value if value is not None else value, "%.1f")
    return _cell(value, "%.2f" if key.startswith("bearing") else "%.3f")


def format_cv(summary: Mapping[str, Mapping[str, Any]]) -> str:
    """Text tables: per group, one row per fold, then mean, sd and all folds pooled."""
    lines = []
    for groups, metrics in ((DRONE_GROUPS, DRONE_METRICS), (NEGATIVE_GROUPS, NEGATIVE_METRICS)):
        names = [g for g in groups if g in summary]
        if not names:
            continue
        header = "%-18s %6s %5s %7s %6s" % ("group", "fold", "clips", "frames", "gt") + "".join(
            " %7s" % column for column, _, _ in metrics)
        lines += [header, "-" * len(header)]
        for group in names:
            entry = summary[group]
            percent = metrics is NEGATIVE_METRICS
            fmt = functools.partial(_format_metric, percent=percent)
            for i, fold in enumerate(entry["fold_ids"]):
                lines.append("%-18s %6d %5d %7d %6d" % (group, fold, entry["clips"][i], entry["frames"][i], entry["gt"][i])
                             + "".join(" %7s" % fmt(key, entry[key]["folds"][i]) for _, key, _ in metrics))
            totals = (sum(entry["clips"]), sum(entry["frames"]), sum(entry["gt"]))
            for row in ("mean", "sd", "pooled"):
                lead = "%-18s %6s %5s %7s %6s" % (group, row, *(("%d" % t) if row == "pooled" else "" for t in totals))
                lines.append(lead + "".join(" %7s" % fmt(key, entry[key][row]) for _, key, _ in metrics))
            lines.append("")
    return "\n".join(lines).rstrip("\n")


def headline(summary: Mapping[str, Mapping[str, Any]]) -> List[str]:
    """The acceptance figures of issue 16 as mean +- sd over the folds, one line per group."""
    out = []
    for group in GROUPS:
        if group not in summary:
            continue
        e = summary[group]
        if group in DRONE_GROUPS:
            out.append("%s: F %s (IoU 0.5), F %s (centre-in-box), AP %s, bearing error median %s deg"
                       % (group, _pm(e["f1"]), _pm(e["centre_f1"]), _pm(e["ap"]), _pm(e["bearing_median_deg"], "%.2f")))
        else:
            out.append("%s: frames with a false target %s %%" % (group, _pm(e["frames_with_target"], "%.1f", 100.0)))
    return out


def _pm(entry: Mapping[str, Any], fmt: str = "%.3f", scale: float = 1.0) -> str:
    mean, sd = entry["mean"], entry["sd"]
    return "%s +- %s" % (_cell(mean * scale, fmt), _cell(sd * scale, fmt))


def _json_ready(value: Any) -> Any:
    if isinstance(value, float):
        return None if math.isnan(value) else value
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    return value


def cv_report(results: Sequence[FoldResult], summary: Mapping[str, Any], meta: Mapping[str, Any]) -> Dict[str, Any]:
    """Everything as JSON-ready data: the settings, each fold's groups and clips, the summary."""
    return _json_ready({
        **meta,
        "summary": summary,
        "folds": [{"fold": r.fold,
                   "groups": {g: s.as_dict(curve=False) for g, s in r.groups.items()},
                   "clips": [c.as_dict(curve=False) for c in r.clips]} for r in results],
    })

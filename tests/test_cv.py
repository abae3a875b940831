"""Grouped cross-validation: the fold definition, the per-fold scoring and the ``cv`` command."""

import json
import math
import os
import random
import shutil

import cv2
import numpy as np
import pytest

from payload.cli import main
from payload.errors import DataError
from payload.eval import cv
from payload.eval.folds import (
    FOLDS_FILE,
    MAX_NUMBER,
    Folds,
    block_of,
    clip_frames,
    load_folds,
    make_folds,
    parse_clip,
)
from payload.offline import ClipSpec, UsageError
from payload.types import Detections

# ---------------------------------------------------------------- fold definition


def _frames(kinds):
    """{clip: frames} for kinds given as {kind: [(number, frames), ...]}."""
    return {"%s_%03d" % (kind, n): f for kind, clips in kinds.items() for n, f in clips}


def _check_folds(frames_by_clip, definition):
    folds = Folds(definition)
    held = folds.split(sorted(frames_by_clip))
    # every clip in exactly one fold
    assert sorted(n for names in held for n in names) == sorted(frames_by_clip)
    # no block of consecutive numbers on two sides
    fold_of_block = {}
    for fold, names in enumerate(held):
        for name in names:
            kind, number = parse_clip(name)
            key = (kind, block_of(number, definition["block_size"]))
            assert fold_of_block.setdefault(key, fold) == fold, "block %s split between folds" % (key,)
    # a model of fold k trains on everything else
    for fold in range(folds.k):
        assert set(folds.training(sorted(frames_by_clip), fold)) == set(frames_by_clip) - set(held[fold])
    return folds, held


def test_folds_take_whole_blocks_balanced_in_frames_and_cover_every_number():
    # 9 blocks of V_DRONE with 10 clips each (blocks 0-8), equal frames: 3 blocks per fold;
    # IR_BIRD with uneven blocks: the cut falls where the cumulative frames are nearest thirds
    frames = _frames({
        "V_DRONE": [(n, 300) for n in range(1, 91)],
        "IR_BIRD": [(1, 1000), (2, 1000), (11, 500), (21, 500), (31, 1000), (41, 1000)],
    })
    definition = make_folds(frames, k=3)
    folds, held = _check_folds(frames, definition)
    assert definition["kinds"]["V_DRONE"] == [[1, 30], [31, 60], [61, MAX_NUMBER]]
    assert definition["frames"]["V_DRONE"] == [9000, 9000, 9000]
    # IR_BIRD blocks 2000, 500, 500, 1000, 1000 (total 5000): cuts nearest 1667 and 3333 -> after
    # block 0 (2000) and after block 2 (3000)
    assert definition["kinds"]["IR_BIRD"] == [[1, 10], [11, 30], [31, MAX_NUMBER]]
    assert definition["frames"]["IR_BIRD"] == [2000, 1000, 2000]
    # numbers absent when the folds were made (clips kept aside) still belong to one fold
    assert folds.fold_of("V_DRONE_095") == 2 and folds.fold_of("IR_BIRD_005") == 0
    assert folds.fold_of("IR_BIRD_999") == 2


def test_folds_are_deterministic_whatever_the_order():
    rng = random.Random(3)
    frames = _frames({"V_BIRD": [(n, rng.randint(100, 400)) for n in range(1, 57)],
                      "IR_DRONE": [(n, rng.randint(200, 350)) for n in range(1, 130)]})
    first = make_folds(frames, k=4)
    items = list(frames.items())
    rng.shuffle(items)
    assert make_folds(dict(items), k=4) == first
    _check_folds(frames, first)
    assert all(len(r) == 4 for r in first["kinds"].values())


def test_too_few_blocks_for_the_folds_is_an_error():
    with pytest.raises(DataError, match="V_DRONE: 2 blocks cannot fill 3 folds"):
        make_folds(_frames({"V_DRONE": [(1, 300), (15, 300)]}), k=3)


@pytest.mark.parametrize("data, needle", [
    ({"k": 3}, "expected {"),
    ({"k": 2, "block_size": 10, "kinds": {"V_DRONE": [[1, 30], [31, 999], [1, 2]]}}, "has 3 ranges, expected k=2"),
    ({"k": 2, "block_size": 10, "kinds": {"V_DRONE": [[1, 30], [41, 999]]}}, "must tile 1..999"),
    ({"k": 2, "block_size": 10, "kinds": {"V_DRONE": [[1, 35], [36, 999]]}}, "in whole blocks of 10"),
    ({"k": 2, "block_size": 10, "kinds": {"V_DRONE": [[1, 30], [31, 500]]}}, "must end at 999"),
])
def test_bad_fold_files_are_refused_in_one_line(tmp_path, data, needle):
    path = tmp_path / "folds.json"
    path.write_text(json.dumps(data))
    with pytest.raises(DataError) as info:
        load_folds(str(path))
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_unknown_clip_names_and_kinds():
    folds = Folds({"k": 2, "block_size": 10, "kinds": {"V_DRONE": [[1, 10], [11, 999]]}})
    with pytest.raises(DataError, match="kind IR_DRONE has no folds"):
        folds.fold_of("IR_DRONE_001")
    with pytest.raises(DataError, match="expected a Halmstad clip name"):
        folds.fold_of("drone.mp4")


def test_shipped_folds_hold_every_real_clip_and_were_made_from_them(halmstad_dir):
    folds = load_folds()
    assert folds.k >= 3
    frames = clip_frames(halmstad_dir)
    _check_folds(frames, json.load(open(FOLDS_FILE)))
    made = make_folds(frames, folds.k, folds.block_size)
    assert made["kinds"] == {k: [list(r) for r in v] for k, v in folds.ranges.items()}, (
        "payload/eval/folds.json no longer matches the clips under %s: regenerate it on purpose "
        "(python -m payload.eval.folds --write) and retrain the fold models" % halmstad_dir)
    # each kind's folds within a factor 3.5 of each other in frames (whole blocks of 10 clips)
    for kind, per_fold in made["frames"].items():
        assert max(per_fold) <= 3.5 * min(per_fold), (kind, per_fold)


# ---------------------------------------------------------------- scoring per fold


def _det(boxes, scores):
    return Detections(np.array(boxes, np.float32).reshape(-1, 4), np.array(scores, np.float32), "GAD")


def _clip(tmp_path, name, frames, box=None):
    """A clip spec whose labels hold ``box`` (x, y, w, h, 1-based as Halmstad) on every frame."""
    path = tmp_path / (name + ".csv")
    cls = "DRONE" if "_DRONE_" in name else "BIRD"
    rows = ["%d,%s,%g,%g,%g,%g" % ((i, cls) + tuple(box)) for i in range(frames)] if box else []
    path.write_text("frame,class,x,y,w,h\n" + "\n".join(rows) + ("\n" if rows else ""))
    return ClipSpec(name, str(tmp_path / (name + ".mp4")), str(path))


def test_fold_clips_limit_spreads_over_each_kind():
    folds = Folds({"k": 2, "block_size": 10, "kinds": {"V_DRONE": [[1, 50], [51, 999]], "V_BIRD": [[1, 10], [11, 999]]}})
    clips = [ClipSpec("V_DRONE_%03d" % n, "", "") for n in range(1, 61)] + [ClipSpec("V_BIRD_%03d" % n, "", "") for n in (1, 2, 12)]
    per_fold = cv.fold_clips(clips, folds)
    assert [len(f) for f in per_fold] == [52, 11]
    limited = cv.fold_clips(clips, folds, limit_clips=3)
    assert [c.name for c in limited[0]] == ["V_BIRD_001", "V_BIRD_002", "V_DRONE_001", "V_DRONE_025", "V_DRONE_050"]
    assert [c.name for c in limited[1]] == ["V_BIRD_012", "V_DRONE_051", "V_DRONE_055", "V_DRONE_060"]


def test_run_cv_scores_each_fold_with_its_own_detector_and_summarises(tmp_path):
    # fold 0: one visible drone clip found on 3 of 4 frames; fold 1: found on 1 of 4 frames.
    # Fold 1's detector also reports a box on 1 of 2 frames of a bird clip; fold 0's is silent there.
    clips = [[_clip(tmp_path, "V_DRONE_001", 4, (11, 11, 20, 20)), _clip(tmp_path, "V_BIRD_001", 2)],
             [_clip(tmp_path, "V_DRONE_031", 4, (11, 11, 20, 20)), _clip(tmp_path, "V_BIRD_031", 2)]]
    hit = [10, 10, 30, 30]

    def detector_for(fold):
        def detect(clip):
            if clip.name.startswith("V_BIRD"):
                return {0: _det([[5, 5, 9, 9]], [0.6]) if fold == 1 else Detections.empty(), 1: Detections.empty()}
            found = 3 if fold == 0 else 1
            return {i: _det([hit], [0.9]) if i < found else Detections.empty() for i in range(4)}
        return detect

    results = cv.run_cv(clips, detector_for)
    summary = cv.summarise(results)
    recall = summary["visible drones"]["recall"]
    assert recall["folds"] == [0.75, 0.25]
    assert recall["mean"] == pytest.approx(0.5) and recall["sd"] == pytest.approx(math.sqrt(0.125))
    assert recall["pooled"] == pytest.approx(0.5)  # 4 of 8
    assert summary["visible drones"]["precision"]["folds"] == [1.0, 1.0]
    assert summary["visible drones"]["centre_recall"]["folds"] == [0.75, 0.25]
    target = summary["visible negatives"]["frames_with_target"]
    assert target["folds"] == [0.0, 0.5] and target["mean"] == pytest.approx(0.25)
    assert "thermal drones" not in summary
    text = cv.format_cv(summary)
    rows = [line.split() for line in text.splitlines() if line.startswith("visible drones")]
    assert [r[2] for r in rows] == ["0", "1", "mean", "sd", "pooled"]
    assert rows[0][7] == "0.750" and rows[2][4] == "0.500"  # R per fold and its mean
    assert "visible negatives: frames with a false target 25.0 +- 35.4 %" in cv.headline(summary)


def test_detections_store_resumes_adds_folds_and_refuses_other_settings(tmp_path):
    calls = []
    clip = _clip(tmp_path, "V_DRONE_001", 3, (11, 11, 20, 20))
    root = str(tmp_path / "dets")

    def detect(c):
        calls.append(c.name)
        return {0: _det([[10.004, 10, 30, 30]], [0.91234]), 1: Detections.empty(), 2: Detections.empty()}

    store = cv.DetectionsStore(root, {"limit": 0}, {0: "cfg-a"})
    first = store.wrap(0, detect)(clip)
    again = cv.DetectionsStore(root, {"limit": 0}, {0: "cfg-a"}).wrap(0, detect)(clip)
    assert calls == ["V_DRONE_001"]  # the second store read it back
    assert sorted(first) == sorted(again) == [0, 1, 2]
    np.testing.assert_allclose(again[0].xyxy, first[0].xyxy)
    assert len(again[1]) == 0
    # a cut done.jsonl line (a kill while writing) makes that clip run again, nothing else breaks
    with open(tmp_path / "dets" / "done.jsonl", "a") as handle:
        handle.write('{"fold": 0, "clip": "V_DRO')
    cv.DetectionsStore(root, {"limit": 0}, {0: "cfg-a"}).wrap(0, detect)(clip)
    assert calls == ["V_DRONE_001"]
    # another fold joins with its own models; then all folds together are read back
    cv.DetectionsStore(root, {"limit": 0}, {1: "cfg-b"}).wrap(1, detect)(clip)
    assert calls == ["V_DRONE_001"] * 2
    both = cv.DetectionsStore(root, {"limit": 0}, {0: "cfg-a", 1: "cfg-b"})
    both.wrap(0, detect)(clip), both.wrap(1, detect)(clip)
    assert calls == ["V_DRONE_001"] * 2
    with pytest.raises(UsageError, match="holds fold 0 with another config or models"):
        cv.DetectionsStore(root, {"limit": 0}, {0: "cfg-c"})
    with pytest.raises(UsageError, match="was made with other settings \\(limit differ\\)"):
        cv.DetectionsStore(root, {"limit": 5}, {0: "cfg-a"})


# ---------------------------------------------------------------- the command on a tiny data set


def _write_video(path, frames, box=None):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (160, 128))
    assert writer.isOpened(), "OpenCV cannot write mp4v here"
    for i in range(frames):
        img = np.full((128, 160, 3), (200, 180, 150), np.uint8)
        if box is not None:
            x, y, w, h = box
            cv2.rectangle(img, (x + 2 * i, y), (x + 2 * i + w - 1, y + h - 1), (40, 40, 40), -1)
        writer.write(img)
    writer.release()


@pytest.fixture
def tiny_halmstad(tmp_path):
    """A Halmstad-shaped folder: one clip of each group in each of 3 folds, 4 frames each."""
    root = tmp_path / "halmstad"
    for sub in ("visible", "ir", "labels"):
        (root / sub).mkdir(parents=True)
    (root / "splits.json").write_text("{}")
    names = []
    for number in (1, 11, 21):
        for kind, sub in (("V_DRONE", "visible"), ("IR_DRONE", "ir"), ("V_BIRD", "visible"), ("IR_AIRPLANE", "ir")):
            name = "%s_%03d" % (kind, number)
            drone = kind.endswith("DRONE")
            _write_video(root / sub / (name + ".mp4"), 4, (60, 50, 12, 9) if drone else None)
            rows = ["%d,DRONE,%d,51,12,9" % (i, 61 + 2 * i) for i in range(4)] if drone else []
            (root / "labels" / (name + ".csv")).write_text("frame,class,x,y,w,h\n" + "".join(r + "\n" for r in rows))
            names.append(name)
    folds = tmp_path / "folds.json"
    folds.write_text(json.dumps(make_folds({n: 4 for n in names}, k=3)))
    return root, folds


def test_cv_command_on_a_tiny_data_set(tiny_halmstad, tmp_path, capsys):
    root, folds = tiny_halmstad
    out = tmp_path / "cv.json"
    argv = ["cv", "--splits", str(root / "splits.json"), "--folds", str(folds), "--no-progress"]
    assert main(argv + ["--json", str(out), "--dets-dir", str(tmp_path / "dets")]) == 0
    printed = capsys.readouterr().out
    assert "shipped models: trained on clips in these folds, figures optimistic" in printed
    report = json.loads(out.read_text())
    assert report["optimistic"] is True and len(report["folds"]) == 3
    for fold, entry in enumerate(report["folds"]):
        assert sorted(c["name"] for c in entry["clips"]) == sorted(
            "%s_%03d" % (k, 10 * fold + 1) for k in ("V_DRONE", "IR_DRONE", "V_BIRD", "IR_AIRPLANE"))
        assert set(entry["groups"]) == set(cv.GROUPS)
        assert all(c["frames"] == 4 for c in entry["clips"])
    summary = report["summary"]
    for group, key in (("visible drones", "f1"), ("thermal drones", "centre_f1"),
                       ("thermal negatives", "frames_with_target")):
        folds_values = summary[group][key]["folds"]
        stored = [report["folds"][k]["groups"][group] for k in range(3)]
        direct = [s["centre"]["f1"] if key == "centre_f1" else
                  s["frames_with_detections"] if key == "frames_with_target" else s["f1"] for s in stored]
        assert folds_values == direct
        finite = [v for v in folds_values if v is not None]
        if finite:
            assert summary[group][key]["mean"] == pytest.approx(float(np.mean(finite)))
    # the per-fold table: three fold rows and mean/sd/pooled per group
    rows = [line.split() for line in printed.splitlines() if line.startswith("thermal negatives")]
    assert [r[2] for r in rows] == ["0", "1", "2", "mean", "sd", "pooled"]
    # a rerun with the same settings re-scores the kept detections: the same figures
    assert main(argv + ["--json", str(tmp_path / "again.json"), "--dets-dir", str(tmp_path / "dets")]) == 0
    assert json.loads((tmp_path / "again.json").read_text())["summary"] == summary


def test_cv_command_under_camera_motion(tiny_halmstad, tmp_path, capsys):
    # --ego-motion: every clip warped as if the camera moved (frames and labels), grouped as the clip
    # it came from; detections kept for the clips as filmed are not taken for these
    root, folds = tiny_halmstad
    argv = ["cv", "--splits", str(root / "splits.json"), "--folds", str(folds), "--no-progress",
            "--dets-dir", str(tmp_path / "dets")]
    out = tmp_path / "cv.json"
    assert main(argv + ["--ego-motion", "3", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "each warped by a camera path from seed 3" in printed
    report = json.loads(out.read_text())
    assert report["ego_motion"] == 3 and "--ego-motion 3" in report["command"]
    for fold, entry in enumerate(report["folds"]):
        assert sorted(c["name"] for c in entry["clips"]) == sorted(
            "%s_%03d~ego3" % (k, 10 * fold + 1) for k in ("V_DRONE", "IR_DRONE", "V_BIRD", "IR_AIRPLANE"))
        assert set(entry["groups"]) == set(cv.GROUPS)
        assert entry["groups"]["visible drones"]["gt"] > 0  # the warped labels are scored
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "other settings" in err and "ego_motion" in err and "\n" not in err
    # a seed numpy cannot take: one line, not its traceback (eval --ego-motion shares the check)
    assert main(argv[:-2] + ["--ego-motion", "-1"]) == 2
    assert capsys.readouterr().err.strip() == "glad-payload cv: --ego-motion -1: expected a seed >= 0"


def test_fold_model_files_of_a_fold_and_of_all_folds(tmp_path):
    from payload.offline import UsageError

    for sub in ("fold1", "all"):
        (tmp_path / sub).mkdir()
        for _, name in cv.MODEL_FILES:
            (tmp_path / sub / name).write_bytes(b"onnx")
    files = cv.fold_model_files(str(tmp_path), [1, "all"])
    assert files[1]["detector.classifier.model"] == str(tmp_path / "fold1" / "glad_classifier.onnx")
    assert files["all"]["detector.classifier.model"] == str(tmp_path / "all" / "glad_classifier.onnx")
    assert sorted(files["all"]) == sorted(key for key, _ in cv.MODEL_FILES)
    os.remove(str(tmp_path / "all" / "glad_local.onnx"))
    with pytest.raises(UsageError, match="all/glad_local.onnx") as raised:
        cv.fold_model_files(str(tmp_path), ["all", 0])
    assert "fold0/glad_global.onnx" in str(raised.value)  # every missing file, in one line
    # a fold's own verifier: required, since the shipped one learned every fold's locks
    os.remove(str(tmp_path / "fold1" / "glad_verifier.onnx"))
    with pytest.raises(UsageError, match="fold1/glad_verifier.onnx; a fold's verifier comes from "
                                         "training/train_verifier.py --export-folds"):
        cv.fold_model_files(str(tmp_path), [1])
    # mining locks runs with the verifier off: the detector's three networks suffice
    assert sorted(cv.fold_model_files(str(tmp_path), [1], cv.DETECTOR_FILES)[1]) == [
        "detector.classifier.model", "detector.global.appearance.model", "detector.local.appearance.model"]


def test_cv_command_with_fold_models(tiny_halmstad, tmp_path, capsys):
    root, folds = tiny_halmstad
    models = tmp_path / "models"
    shipped = os.path.join(os.path.dirname(cv.__file__), "..", "models")
    for k in range(3):
        (models / ("fold%d" % k)).mkdir(parents=True)
        for _, name in cv.MODEL_FILES:
            shutil.copy(os.path.join(shipped, name), str(models / ("fold%d" % k) / name))
    argv = ["cv", "--splits", str(root / "splits.json"), "--folds", str(folds), "--no-progress", "--limit", "2"]
    out = tmp_path / "cv.json"
    assert main(argv + ["--fold-models", str(models), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "figures optimistic" not in printed and "models: per fold: %s/fold{k}/" % models in printed
    report = json.loads(out.read_text())
    assert report["optimistic"] is False
    assert all(c["frames"] == 2 for f in report["folds"] for c in f["clips"])
    os.remove(str(models / "fold2" / "glad_local.onnx"))
    assert main(argv + ["--fold-models", str(models)]) == 2
    err = capsys.readouterr().err.strip()
    assert "missing" in err and "fold2/glad_local.onnx" in err and "\n" not in err
    # the folds trained so far can be run on their own
    assert main(argv + ["--fold-models", str(models), "--folds-only", "1", "0", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "folds 0 1 only" in printed and "mean +- sd over the 2 folds run (of 3)" in printed
    report = json.loads(out.read_text())
    assert [f["fold"] for f in report["folds"]] == [0, 1] and report["folds_run"] == [0, 1]
    assert report["summary"]["visible negatives"]["fold_ids"] == [0, 1]
    rows = [line.split() for line in printed.splitlines() if line.startswith("visible negatives")]
    assert [r[2] for r in rows] == ["0", "1", "mean", "sd", "pooled"]
    assert main(argv + ["--folds-only", "3"]) == 2
    assert "--folds-only 3: folds are 0..2" in capsys.readouterr().err


def test_cv_command_without_data_is_a_one_line_error(tmp_path, capsys):
    assert main(["cv", "--splits", str(tmp_path / "absent.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "no such file" in err and "\n" not in err


def test_kept_detections_know_which_verifier_made_them(tmp_path):
    # A run kept with one verifier must not be taken for another's (the store compares digests).
    from payload.config import config_with, load_config

    cfg = load_config(None)
    shipped = cv.model_digests(cfg)
    other = tmp_path / "verifier.onnx"
    other.write_bytes(b"not the shipped verifier")
    assert cv.model_digests(config_with(cfg, **{"detector.verifier.model": str(other)}))["verifier"] != shipped["verifier"]
    off = cv.model_digests(config_with(cfg, **{"detector.verifier.enabled": False}))
    assert "verifier" not in off and off["classifier"] == shipped["classifier"]

import json
import math
import os

import cv2
import numpy as np
import pytest

from payload.cli import main
from payload.errors import DataError
from payload.eval.cli import format_table
from payload.eval.labels import detect_format, load_labels
from payload.eval.metrics import (
    ap_11point,
    bearing_error_deg,
    centre_match_frame,
    match_frame,
    pool,
    score_clip,
)
from payload.geometry import CameraModel
from payload.offline import UsageError, clips_from_paths, score_clips, split_clips
from payload.records import DetectionsCsvWriter
from payload.types import Detections


def _det(boxes, scores, module="GAD"):
    return Detections(np.array(boxes, np.float32).reshape(-1, 4), np.array(scores, np.float32), module)


# ---------------------------------------------------------------- IoU and matching


def test_iou_of_exactly_half_is_not_a_match_but_just_above_is():
    gt = np.array([[0, 0, 10, 10]], np.float32)
    assert not match_frame(_det([[0, 0, 10, 5]], [0.9]), gt).any()
    assert match_frame(_det([[0, 0, 10, 5.01]], [0.9]), gt).all()


def test_greedy_matching_goes_by_score_not_by_overlap():
    gt = np.array([[0, 0, 10, 10]], np.float32)
    # The better-placed box has the lower score: the higher-scored one takes the only target.
    dets = _det([[0, 0, 10, 10], [0, 0, 10, 7]], [0.5, 0.9])
    assert list(match_frame(dets, gt)) == [False, True]


def test_each_ground_truth_matches_once_and_to_its_best_overlap():
    gt = np.array([[0, 0, 10, 10], [3, 0, 13, 10]], np.float32)
    dets = _det([[3, 0, 13, 10], [0, 0, 10, 10], [0, 0, 10, 10]], [0.9, 0.8, 0.7])
    # 0.9 overlaps gt0 by 0.54 and gt1 by 1.0 -> takes gt1; 0.8 takes gt0; 0.7 finds nothing free.
    assert list(match_frame(dets, gt)) == [True, True, False]


# ---------------------------------------------------------------- centre-in-box matching and bearing error


def test_centre_in_box_takes_a_small_box_on_the_target_that_iou_rejects():
    gt = np.array([[0, 0, 40, 40]], np.float32)
    small = _det([[15, 15, 25, 25]], [0.9])  # centre (20, 20) inside; IoU 100/1600
    assert not match_frame(small, gt).any()
    assert list(centre_match_frame(small, gt)) == [0]
    beside = _det([[41, 0, 81, 40]], [0.9])  # same size, centre outside
    assert list(centre_match_frame(beside, gt)) == [-1]
    edge = _det([[30, 10, 50, 30]], [0.9])  # centre (40, 20) on the right edge: inside
    assert list(centre_match_frame(edge, gt)) == [0]


def test_centre_matching_is_one_to_one_by_score():
    gt = np.array([[0, 0, 40, 40]], np.float32)
    dets = _det([[10, 10, 20, 20], [12, 12, 22, 22]], [0.5, 0.9])
    assert list(centre_match_frame(dets, gt)) == [-1, 0]  # the higher score takes the only box


def test_centre_matching_takes_the_box_whose_centre_is_nearest():
    # both boxes contain the first (higher-scored) centre; it takes gt1, whose centre is nearer,
    # which leaves gt0 to the second detection (inside gt0 only): two true positives
    gt = np.array([[0, 0, 20, 20], [10, 0, 30, 20]], np.float32)
    dets = _det([[17, 9, 19, 11], [4, 9, 6, 11]], [0.9, 0.8])
    assert list(centre_match_frame(dets, gt)) == [1, 0]


def test_bearing_error_is_the_angle_between_the_rays_not_the_pixel_distance():
    # 90 deg hfov over 200 px: focal length 100 px, optical axis through the continuous centre (100, 50)
    cam = CameraModel.from_hfov(90.0, (200, 100))
    on_axis = np.array([[95, 45, 105, 55]])  # centre (100, 50)
    off_50 = np.array([[140, 45, 160, 55]])  # centre (150, 50): 50 px right, atan(0.5)
    off_100 = np.array([[190, 45, 210, 55]])  # centre (200, 50): 100 px right, 45 deg
    assert bearing_error_deg(cam, on_axis, off_50)[0] == pytest.approx(math.degrees(math.atan(0.5)), abs=1e-6)
    # the same 50 px farther from the axis is a smaller angle: 45 - 26.57 = 18.43 deg
    assert bearing_error_deg(cam, off_50, off_100)[0] == pytest.approx(45.0 - math.degrees(math.atan(0.5)), abs=1e-6)
    below = np.array([[95, 95, 105, 105]])  # centre (100, 100): 50 px down
    assert bearing_error_deg(cam, on_axis, below)[0] == pytest.approx(math.degrees(math.atan(0.5)), abs=1e-6)
    assert bearing_error_deg(cam, on_axis, on_axis)[0] == pytest.approx(0.0, abs=1e-9)


def test_score_clip_reports_centre_scores_and_bearing_errors_of_centre_matches():
    cam = CameraModel.from_hfov(90.0, (200, 100))
    labels = {0: np.array([[80, 30, 120, 70]], np.float32),  # centre (100, 50)
              1: np.array([[80, 30, 120, 70]], np.float32),
              2: np.array([[80, 30, 120, 70]], np.float32)}
    dets = {
        0: _det([[81, 31, 119, 69]], [0.9]),  # same centre, IoU 0.9: both TP, bearing error 0
        1: _det([[105, 45, 115, 55]], [0.8]),  # centre (110, 50): centre TP only, atan(10/100)
        2: _det([[150, 45, 160, 55]], [0.7]),  # centre outside: FP both ways
    }
    score = score_clip("c", dets, labels, camera=cam)
    assert (score.tp, score.fp, score.fn) == (1, 2, 2)
    assert (score.centre.tp, score.centre.fp, score.centre.fn) == (2, 1, 1)
    assert score.centre.precision == pytest.approx(2 / 3) and score.centre.recall == pytest.approx(2 / 3)
    np.testing.assert_allclose(sorted(score.bearing_err_deg), [0.0, math.degrees(math.atan(0.1))], atol=1e-6)
    assert score.bearing_median_deg == pytest.approx(math.degrees(math.atan(0.1)) / 2, abs=1e-6)
    report = score.as_dict()
    assert report["centre"]["tp"] == 2 and report["bearing_error_deg"]["n"] == 2
    # pooled with a clip without any match: the centre counts add up, the errors are kept
    other = score_clip("d", {0: _det([[0, 0, 5, 5]], [0.95])}, {0: np.array([[80, 30, 120, 70]], np.float32)}, camera=cam)
    pooled = pool([score, other])
    assert (pooled.centre.tp, pooled.centre.fp, pooled.centre.fn) == (2, 2, 2)
    assert len(pooled.bearing_err_deg) == 2
    # ranked together: FP 0.95, TP 0.9, TP 0.8, FP 0.7 over 4 targets: precision 2/3 up to recall 1/2
    assert pooled.centre.ap == pytest.approx((6 * 2 / 3) / 11)
    no_camera = score_clip("c", dets, labels)
    assert no_camera.centre.tp == 2 and math.isnan(no_camera.bearing_median_deg)
    assert no_camera.as_dict()["bearing_error_deg"] == {"n": 0, "median": None, "p95": None}


# ---------------------------------------------------------------- P/R/F and 11-point AP


def test_hand_made_precision_recall_and_ap():
    labels = {i: np.array([[100 * i, 0, 100 * i + 20, 20]], np.float32) for i in range(4)}
    labels[4] = np.zeros((0, 4), np.float32)  # labelled frame with no target
    hit = lambda i: [100 * i + 1, 0, 100 * i + 21, 20]  # noqa: E731  IoU 19*20/(21*20) = 0.905
    dets = {
        0: _det([hit(0)], [0.9]),
        1: _det([[300, 300, 320, 320], hit(1)], [0.8, 0.7]),
        2: _det([hit(2)], [0.5]),
        4: _det([[0, 0, 20, 20]], [0.6]),
    }
    # Ranked: 0.9 TP, 0.8 FP, 0.7 TP, 0.6 FP, 0.5 TP with 4 targets (frame 3 missed):
    #   precision 1, 1/2, 2/3, 1/2, 3/5;  recall 1/4, 1/4, 1/2, 1/2, 3/4
    # interpolated precision (max precision at recall >= r):
    #   r = 0, .1, .2 -> 1;  r = .3, .4, .5 -> 2/3;  r = .6, .7 -> 3/5;  r = .8, .9, 1 -> 0
    # AP = (3 * 1 + 3 * 2/3 + 2 * 3/5) / 11 = 6.2 / 11
    score = score_clip("hand", dets, labels)
    assert (score.frames, score.gt, score.tp, score.fp, score.fn) == (5, 4, 3, 2, 1)
    assert score.precision == pytest.approx(3 / 5)
    assert score.recall == pytest.approx(3 / 4)
    assert score.f1 == pytest.approx(2 * 0.6 * 0.75 / 1.35)
    assert score.ap == pytest.approx(6.2 / 11)
    assert score.frames_with_detections == pytest.approx(4 / 5)
    # the PR curve: one point per threshold, the same precision/recall as the ranking above
    assert np.allclose(score.pr_curve(), [[0.9, 1, 1 / 4], [0.8, 1 / 2, 1 / 4], [0.7, 2 / 3, 1 / 2],
                                          [0.6, 1 / 2, 1 / 2], [0.5, 3 / 5, 3 / 4]])
    assert np.allclose(score.pr_curve(points=2, score_step=0.5), [[0.9, 1, 1 / 4], [0.5, 3 / 5, 3 / 4]])


def test_pr_curve_keeps_tied_scores_together():
    labels = {0: np.array([[0, 0, 20, 20]], np.float32), 1: np.array([[0, 0, 20, 20]], np.float32)}
    dets = {0: _det([[0, 0, 20, 20]], [0.5]), 1: _det([[50, 50, 70, 70]], [0.5])}
    # a threshold of 0.5 keeps both: one point, precision 1/2, recall 1/2 (never "1 of 1 kept")
    assert np.allclose(score_clip("tie", dets, labels).pr_curve(), [[0.5, 0.5, 0.5]])


def test_recall_exactly_on_a_grid_point_counts():
    # 3 of 10 found, all first: recall 0.3 must reach the r = 0.3 point (float k/10 trap).
    assert ap_11point(np.array([True, True, True]), gt=10) == pytest.approx(4 / 11)


def test_pooling_ranks_all_detections_together_not_an_average():
    gt = {0: np.array([[0, 0, 10, 10]], np.float32)}
    a = score_clip("a", {0: _det([[0, 0, 10, 10]], [0.9])}, gt)
    b = score_clip("b", {0: _det([[50, 50, 60, 60], [0, 0, 10, 10]], [0.95, 0.3])}, gt)
    assert a.ap == pytest.approx(1.0)
    assert b.ap == pytest.approx(0.5)
    pooled = pool([a, b])
    # Ranked together: FP .95, TP .9, TP .3 with 2 targets -> precision 0, 1/2, 2/3 at recall 0, 1/2, 1:
    # every recall point interpolates to 2/3 (the mean of the clip APs would be 0.75).
    assert pooled.ap == pytest.approx(2 / 3)
    assert (pooled.frames, pooled.gt, pooled.tp, pooled.fp, pooled.fn) == (2, 2, 2, 1, 0)
    assert pooled.precision == pytest.approx(2 / 3)
    assert pooled.frames_with_detections == pytest.approx(1.0)


def test_negative_clip_has_undefined_recall_and_counts_false_alarms():
    labels = {i: np.zeros((0, 4), np.float32) for i in range(10)}
    score = score_clip("birds", {3: _det([[0, 0, 5, 5]], [0.4])}, labels)
    assert (score.gt, score.tp, score.fp) == (0, 0, 1)
    assert score.precision == 0.0
    assert math.isnan(score.recall) and math.isnan(score.ap) and math.isnan(score.f1)
    assert score.frames_with_detections == pytest.approx(0.1)
    assert score.as_dict()["recall"] is None
    silent = score_clip("quiet", {}, labels)
    assert math.isnan(silent.precision) and silent.frames_with_detections == 0.0


def test_frames_limit_ignores_labels_past_it():
    labels = {i: np.array([[0, 0, 10, 10]], np.float32) for i in range(10)}
    score = score_clip("lim", {0: _det([[0, 0, 10, 10]], [0.9])}, labels, frames=2)
    assert (score.frames, score.gt, score.tp, score.fn) == (2, 2, 1, 1)


def test_table_has_fixed_columns():
    gt = {0: np.array([[0, 0, 10, 10]], np.float32)}
    a = score_clip("V_DRONE_013", {0: _det([[0, 0, 10, 10]], [0.9])}, gt)
    neg = score_clip("V_BIRD_031", {}, {0: np.zeros((0, 4), np.float32)})
    lines = format_table([a, neg], pool([a, neg])).splitlines()
    # the first eleven columns keep their places (docs and scripts read the POOLED line by them);
    # the centre-in-box and bearing columns follow
    assert lines[0].split() == ["clip", "frames", "gt", "tp", "fp", "fn", "P", "R", "F", "AP", "det%",
                                "cP", "cR", "cF", "cAP", "deg50", "deg95"]
    assert lines[2].split() == ["V_DRONE_013", "1", "1", "1", "0", "0", "1.000", "1.000", "1.000", "1.000", "100.0",
                                "1.000", "1.000", "1.000", "1.000", "-", "-"]  # no camera: no bearing error
    assert lines[3].split()[6:] == ["-", "-", "-", "-", "0.0", "-", "-", "-", "-", "-", "-"]
    assert lines[-1].split()[0] == "POOLED"
    assert len({len(line) for line in lines if not line.startswith("-")}) == 1


# ---------------------------------------------------------------- label formats


def test_halmstad_csv_is_one_based_and_counts_only_drones(tmp_path):
    path = tmp_path / "clip.csv"
    path.write_text("frame,class,x,y,w,h\n0,DRONE,11,21,30,15\n0,BIRD,100,100,5,5\n2,BIRD,1,1,4,4\n")
    labels = load_labels(str(path))
    assert detect_format(str(path)) == "halmstad"
    assert sorted(labels) == [0, 2]
    np.testing.assert_allclose(labels[0], [[10, 20, 40, 35]])
    assert labels[2].shape == (0, 4)
    birds = load_labels(str(path), classes=("bird",))
    assert len(birds[0]) == 1 and len(birds[2]) == 1
    everything = load_labels(str(path), classes=None)
    assert len(everything[0]) == 2


def labels_as(path, fmt, frames):
    """The labels of ``path``, checked: its format detected as ``fmt``, boxes on ``frames`` (0-based),
    the first one at (10, 20, 40, 35) in 0-based exclusive pixels."""
    assert detect_format(str(path)) == fmt
    labels = load_labels(str(path))
    assert sorted(labels) == frames
    np.testing.assert_allclose(labels[0], [[10, 20, 40, 35]])
    return labels


def test_voc_folder_frame_from_one_based_file_name(tmp_path):
    folder = tmp_path / "phantom16"
    folder.mkdir()
    xml = (
        "<annotation><filename>{name}.jpg</filename><size><width>1920</width><height>1080</height></size>"
        "{objects}</annotation>"
    )
    obj = "<object><name>{cls}</name><bndbox><xmin>{x1}</xmin><ymin>{y1}</ymin><xmax>{x2}</xmax><ymax>{y2}</ymax></bndbox></object>"
    (folder / "phantom16_0001.xml").write_text(
        xml.format(name="phantom16_0001", objects=obj.format(cls="drone", x1=11, y1=21, x2=40, y2=35)))
    (folder / "phantom16_0005.xml").write_text(xml.format(name="phantom16_0005", objects=""))
    (folder / "phantom16_0006.xml").write_text(
        xml.format(name="phantom16_0006", objects=obj.format(cls="bird", x1=1, y1=1, x2=5, y2=5)))
    labels = labels_as(folder, "voc", [0, 4, 5])  # 1-based inclusive -> 0-based exclusive
    assert labels[4].shape == (0, 4) and labels[5].shape == (0, 4)
    (folder / "phantom16_0007.xml").write_text("<annotation><object>")
    with pytest.raises(DataError, match="phantom16_0007.xml:1: not valid XML"):
        load_labels(str(folder))


def test_mot_gt_txt(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text("1,1,10,20,30,15,1,1,1.0\n1,2,50,50,5,5,0,1,1.0\n3,1,12,22,30,15,1,1,0.8\n")
    labels = labels_as(path, "mot", [0, 2])  # the conf-0 row is an ignore region
    np.testing.assert_allclose(labels[2], [[12, 22, 42, 37]])
    path.write_text("0,1,10,20,30,15,1\n")
    with pytest.raises(DataError, match=r"gt.txt:1: frame=0, expected >= 1"):
        load_labels(str(path))


def test_plain_text_one_line_per_frame(tmp_path):
    path = tmp_path / "groundtruth_rect.txt"
    path.write_text("10 20 30 15\n\n0 0 0 0\nNaN NaN NaN NaN\n12,22,30,15\n")
    labels = labels_as(path, "txt", [0, 1, 2, 3, 4])
    assert [len(labels[i]) for i in range(5)] == [1, 0, 0, 0, 1]
    np.testing.assert_allclose(labels[4], [[12, 22, 42, 37]])


@pytest.mark.parametrize(
    "name, body, fmt, needle",
    [
        ("a.csv", "frame,class,x,y,w,h\n0,DRONE,1,2,3\n", None, "a.csv:2: 5 fields, expected 6"),
        ("a.csv", "frame,class,x,y,w,h\n0,DRONE,1,2,abc,4\n", None, "a.csv:2: w='abc' is not a number"),
        ("a.csv", "frame,class,x,y,w,h\n0,DRONE,1,2,-3,4\n", "halmstad", "a.csv:2: w=-3, h=4 must be >= 0"),
        ("b.txt", "1 2 3 4\n1 2 3\n", "txt", "b.txt:2: 3 fields, expected 4"),
        ("b.txt", "1 2 3 four\n", "txt", "b.txt:1: '1 2 3 four' is not four numbers"),
        ("c.dat", "hello world\n", None, "c.dat: unknown label format"),
        ("d.csv", "x\n", "yolo", "label format 'yolo', expected one of halmstad|voc|mot|txt"),
    ],
)
def test_bad_label_files_give_one_line_errors(tmp_path, name, body, fmt, needle):
    path = tmp_path / name
    path.write_text(body)
    with pytest.raises(DataError) as info:
        load_labels(str(path), fmt=fmt)
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_missing_label_file(tmp_path):
    with pytest.raises(DataError, match="no such label file"):
        load_labels(str(tmp_path / "absent.csv"))
    with pytest.raises(DataError, match="cannot read labels"):
        load_labels(str(tmp_path / "absent.csv"), fmt="halmstad")


def test_real_halmstad_labels(halmstad_dir):
    path = os.path.join(halmstad_dir, "labels", "V_DRONE_013.csv")
    if not os.path.isfile(path):
        pytest.skip("%s not present" % path)
    with open(path) as handle:
        rows = [line.strip().split(",") for line in handle][1:]
    labels = load_labels(path)
    drones = [r for r in rows if r[1] == "DRONE"]
    assert sum(len(b) for b in labels.values()) == len(drones) > 0
    frame, _, x, y, w, h = drones[0]
    x, y, w, h = (float(v) for v in (x, y, w, h))
    np.testing.assert_allclose(labels[int(frame)][0], [x - 1, y - 1, x - 1 + w, y - 1 + h], atol=1e-3)
    assert all(b.dtype == np.float32 and b.shape[1:] == (4,) for b in labels.values())


def test_real_bird_clip_has_no_ground_truth(halmstad_dir):
    names = sorted(n for n in os.listdir(os.path.join(halmstad_dir, "labels")) if n.startswith("V_BIRD"))
    if not names:
        pytest.skip("no V_BIRD labels")
    labels = load_labels(os.path.join(halmstad_dir, "labels", names[0]))
    assert labels and all(len(b) == 0 for b in labels.values())


# ---------------------------------------------------------------- the eval command


def _write_dets(path, frames):
    with DetectionsCsvWriter(str(path)) as writer:
        for index, dets in frames.items():
            writer.write(index, dets)


def test_eval_command_scores_csv_pairs_and_writes_json(tmp_path, capsys):
    (tmp_path / "A_labels.csv").write_text("frame,class,x,y,w,h\n0,DRONE,1,1,10,10\n1,DRONE,1,1,10,10\n")
    (tmp_path / "B_labels.txt").write_text("50 50 10 10\n")
    _write_dets(tmp_path / "A.csv", {0: _det([[0, 0, 10, 10]], [0.9]), 1: _det([[30, 30, 40, 40]], [0.8])})
    _write_dets(tmp_path / "B.csv", {0: _det([[50, 50, 60, 60]], [0.7])})
    out = tmp_path / "scores.json"
    rc = main(["eval", "--dets", str(tmp_path / "A.csv"), str(tmp_path / "B.csv"),
               "--labels", str(tmp_path / "A_labels.csv"), str(tmp_path / "B_labels.txt"), "--json", str(out)])
    assert rc == 0
    table = capsys.readouterr().out
    names = [line.split()[0] for line in table.splitlines() if line.strip() and not line.startswith("-")]
    assert names[:4] == ["clip", "A", "B", "POOLED"]
    data = json.loads(out.read_text())
    assert [c["name"] for c in data["clips"]] == ["A", "B"]
    assert (data["clips"][0]["tp"], data["clips"][0]["fp"], data["clips"][0]["fn"]) == (1, 1, 1)
    assert data["pooled"]["tp"] == 2 and data["pooled"]["gt"] == 3
    assert data["pooled"]["precision"] == pytest.approx(2 / 3)


def test_eval_dets_bearing_error_needs_the_frame_size(tmp_path, capsys):
    # a 40x20 label centred at (320, 256), the optical axis of a 640x512 frame; the detection's
    # centre 16 px to the right: inside the box, IoU 280/920 (no IoU match). With the default
    # hfov 80 deg, f = 320 / tan(40 deg) px, the bearing error is atan(16 / f).
    (tmp_path / "A_labels.csv").write_text("frame,class,x,y,w,h\n0,DRONE,301,247,40,20\n")
    _write_dets(tmp_path / "A.csv", {0: _det([[326, 246, 346, 266]], [0.9])})
    args = ["eval", "--dets", str(tmp_path / "A.csv"), "--labels", str(tmp_path / "A_labels.csv")]
    out = tmp_path / "scores.json"
    assert main(args + ["--json", str(out)]) == 0
    assert "no bearing error: give --frame-size" in capsys.readouterr().out
    data = json.loads(out.read_text())
    assert data["pooled"]["tp"] == 0 and data["pooled"]["centre"]["tp"] == 1
    assert data["pooled"]["bearing_error_deg"]["n"] == 0
    assert main(args + ["--frame-size", "640", "512", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    pooled = next(line.split() for line in printed.splitlines() if line.startswith("POOLED"))
    expected = math.degrees(math.atan(16 / (320 / math.tan(math.radians(40)))))
    assert pooled[11:15] == ["1.000", "1.000", "1.000", "1.000"] and float(pooled[15]) == pytest.approx(expected, abs=0.01)
    data = json.loads(out.read_text())
    assert data["pooled"]["bearing_error_deg"]["median"] == pytest.approx(expected, abs=1e-6)
    assert main(args + ["--frame-size", "0", "512"]) == 2


def test_eval_iou_threshold_is_an_option(tmp_path, capsys):
    # a box half the labelled one's area overlaps it with IoU 0.5: not a match at the paper's
    # "IoU > 0.5", a match at --iou 0.3
    (tmp_path / "A_labels.csv").write_text("frame,class,x,y,w,h\n0,DRONE,1,1,20,10\n")
    _write_dets(tmp_path / "A.csv", {0: _det([[0, 0, 10, 10]], [0.9])})
    args = ["eval", "--dets", str(tmp_path / "A.csv"), "--labels", str(tmp_path / "A_labels.csv")]
    for extra, tp, note in (([], 0, False), (["--iou", "0.3"], 1, True)):
        out = tmp_path / "scores.json"
        assert main(args + extra + ["--json", str(out)]) == 0
        data = json.loads(out.read_text())
        assert data["pooled"]["tp"] == tp and data["iou_match"] == (0.3 if extra else 0.5)
        assert ("not the paper's 0.5" in capsys.readouterr().out) == note


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["eval"], "nothing to score"),
        (["eval", "--dets", "a.csv", "--labels", "a.csv", "--iou", "1.5"], "--iou 1.5: expected a number between 0 and 1"),
        (["eval", "--dets", "a.csv", "b.csv", "--labels", "a.csv"], "--dets has 2 files but --labels has 1"),
        (["eval", "--split", "val", "--splits", "/nonexistent/splits.json"], "--splits /nonexistent/splits.json: no such file"),
        (["eval", "--clips", "/nonexistent/clip.mp4"], "--clips /nonexistent/clip.mp4: no such file"),
    ],
)
def test_eval_usage_errors_exit_2_with_one_line(argv, needle, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err


def test_eval_bad_labels_exit_1_naming_the_line(tmp_path, capsys):
    (tmp_path / "l.csv").write_text("frame,class,x,y,w,h\n0,DRONE,1,1,ten,10\n")
    _write_dets(tmp_path / "d.csv", {})
    assert main(["eval", "--dets", str(tmp_path / "d.csv"), "--labels", str(tmp_path / "l.csv")]) == 1
    err = capsys.readouterr().err.strip()
    assert "l.csv:2: w='ten' is not a number" in err and "\n" not in err


def test_split_resolves_real_clips(halmstad_dir, tmp_path):
    splits = os.path.join(halmstad_dir, "splits.json")
    with open(splits) as handle:
        expected = json.load(handle)
    clips = split_clips(splits, "val,negatives_val")
    assert [c.name for c in clips] == expected["val"] + expected["negatives_val"]
    assert all(os.path.isfile(c.video) and os.path.isfile(c.labels) for c in clips)
    ir = split_clips(splits, "ir_val")
    assert all(os.sep + "ir" + os.sep in c.video for c in ir)
    with pytest.raises(UsageError, match="no such split"):
        split_clips(splits, "test")


def test_clips_with_labels_found_beside_and_scored_with_a_real_video(halmstad_dir, tmp_path):
    """The --clips path end to end, with a stand-in detector that reads the real video.

    The stand-in reports the labelled box on even frames only and a spurious box on odd ones:
    recall must be the share of targets on even frames, and every odd-frame box is an FP.
    """
    video = os.path.join(halmstad_dir, "visible", "V_DRONE_013.mp4")
    if not os.path.isfile(video):
        pytest.skip("%s not present" % video)
    clips = clips_from_paths([video], [])
    assert clips[0].labels == os.path.join(halmstad_dir, "labels", "V_DRONE_013.csv")
    truth = load_labels(clips[0].labels)

    def every_other_frame(clip):
        cap = cv2.VideoCapture(clip.video)
        out, index = {}, 0
        while index < 60:
            ok, _ = cap.read()
            if not ok:
                break
            boxes = truth.get(index, np.zeros((0, 4), np.float32))
            out[index] = _det(boxes, [0.9] * len(boxes)) if index % 2 == 0 else _det([[0, 0, 3, 3]], [0.2])
            index += 1
        cap.release()
        return out

    (score,) = score_clips(clips, every_other_frame)
    even_gt = sum(len(truth.get(i, ())) for i in range(0, 60, 2))
    all_gt = sum(len(truth.get(i, ())) for i in range(60))
    assert (score.frames, score.gt, score.tp, score.fp) == (60, all_gt, even_gt, 30)
    assert score.recall == pytest.approx(even_gt / all_gt)


@pytest.mark.slow
def test_split_runs_glad_end_to_end(halmstad_dir, capsys):
    rc = main(["eval", "--split", "val", "--limit", "2", "--no-progress"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    rows = [line.split() for line in out.out.splitlines() if line.startswith(("V_DRONE", "POOLED"))]
    with open(os.path.join(halmstad_dir, "splits.json")) as fh:
        n_val = len(json.load(fh)["val"])
    assert len(rows) == n_val + 1 and all(row[1] == "2" for row in rows[:n_val])


def test_synthetic_seeds_are_rendered_scored_and_named(tmp_path, capsys):
    # two seeded 1080p clips (a range) rendered, run through GLAD and scored against their own truth
    out = tmp_path / "syn.json"
    rc = main(["eval", "--synthetic", "3-4", "--frames", "6", "--target-px", "10", "20", "--no-progress",
               "--json", str(out)])
    assert rc == 0
    table = capsys.readouterr().out
    assert "SYN_3_1920x1080" in table and "SYN_4_1920x1080" in table
    report = json.loads(out.read_text())
    assert [c["name"] for c in report["clips"]] == ["SYN_3_1920x1080", "SYN_4_1920x1080"]
    assert all(c["frames"] == 6 for c in report["clips"])
    assert report["pooled"]["gt"] == sum(c["gt"] for c in report["clips"]) > 0


@pytest.mark.parametrize("argv, needle", [
    (["eval", "--synthetic", "3", "--split", "val"], "give one of --split, --clips, --synthetic"),
    (["eval", "--synthetic", "3", "--target-px", "20", "10"], "--target-px 20.0 10.0: expected 0 < MIN <= MAX"),
    (["eval", "--synthetic", "3", "--ego-motion", "1"], "--ego-motion warps recordings: give it with --split or --clips"),
])
def test_synthetic_usage_errors(argv, needle, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err

"""Synthetic ego-motion for recorded footage (eval --ego-motion): frames and labels warped alike."""

import cv2
import numpy as np
import pytest

from payload.offline import ClipSpec, score_clips, with_ego_motion
from payload.synth.ego_motion import EgoMotionWarp
from payload.types import Detections, Frame


def test_same_seed_same_path_in_any_order_and_seeds_differ():
    a, b = EgoMotionWarp((1, 0), (640, 512)), EgoMotionWarp((1, 0), (640, 512))
    late = a.homography(50).copy()
    assert np.array_equal(b.homography(50), late) and np.array_equal(a.homography(3), b.homography(3))
    assert not np.allclose(EgoMotionWarp((2, 0), (640, 512)).homography(50), late)


def test_camera_moves_smoothly_and_stays_inside_the_recorded_frame():
    warp = EgoMotionWarp((7, 0), (640, 512), fps=30)
    centre = np.array([[[320.0, 256.0]]])
    track = np.array([cv2.perspectiveTransform(centre, warp.homography(i)).ravel() for i in range(300)])
    steps = np.hypot(*np.diff(track, axis=0).T)
    assert 0.3 < np.median(steps) < 5.0  # it moves, as a turning camera does, without tearing
    corners = np.array([[[0.0, 0.0]], [[640.0, 0.0]], [[0.0, 512.0]], [[640.0, 512.0]]])
    for i in range(0, 300, 10):  # every warped pixel comes from the recording (no mirrored border)
        seen = cv2.perspectiveTransform(corners, np.linalg.inv(warp.homography(i))).reshape(-1, 2)
        assert (seen >= -0.5).all() and (seen[:, 0] <= 640.5).all() and (seen[:, 1] <= 512.5).all()


def test_labels_follow_the_warped_pixels():
    warp = EgoMotionWarp((3, 1), (640, 512))
    image = np.zeros((512, 640, 3), np.uint8)
    image[200:230, 300:340] = 255  # the labelled object: x 300-340, y 200-230
    for index in (0, 40, 120):
        warped = warp.frame(Frame(image, index, 0, 0)).image
        ys, xs = np.nonzero(warped[..., 0] > 127)
        seen = [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
        (box,) = warp.boxes(index, np.array([[300, 200, 340, 230]], np.float32))
        np.testing.assert_allclose(box, seen, atol=1.5)


def test_boxes_pushed_out_of_the_frame_are_dropped_and_edges_clipped():
    warp = EgoMotionWarp((3, 1), (640, 512))
    boxes = warp.boxes(10, np.array([[-30, 100, 8, 120], [40, 300, 100, 330], [300, 200, 340, 230]], np.float32))
    assert len(boxes) == 2  # the first one is mostly outside after the zoom-in
    assert boxes[0][0] == 0.0 and (boxes[:, 2] <= 640).all()


def test_score_clips_scores_against_the_warped_labels(tmp_path):
    # a stand-in detector that reports the warped labels: perfect; the unwarped ones: mostly wrong
    labels = tmp_path / "A.csv"
    labels.write_text("frame,class,x,y,w,h\n" + "".join("%d,DRONE,301,201,20,16\n" % i for i in range(20)))
    warp = EgoMotionWarp((5, 0), (640, 512))
    clip = ClipSpec("A~ego5", "A.mp4", str(labels), ego_motion=warp)
    truth = {i: np.array([[300, 200, 320, 216]], np.float32) for i in range(20)}

    def warped(_clip):
        return {i: Detections(warp.boxes(i, truth[i]), [0.9], "LAD") for i in range(20)}

    def unwarped(_clip):
        return {i: Detections(truth[i], [0.9], "LAD") for i in range(20)}

    (good,) = score_clips([clip], warped)
    (bad,) = score_clips([clip], unwarped)
    assert good.tp == 20 and good.fp == 0
    assert bad.tp < 10


def test_with_ego_motion_reads_the_videos_size(tmp_path):
    path = str(tmp_path / "clip.avi")
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 25, (320, 256))
    for _ in range(3):
        writer.write(np.zeros((256, 320, 3), np.uint8))
    writer.release()
    (clip,) = with_ego_motion([ClipSpec("clip", path, "labels.csv")], seed=4)
    assert clip.name == "clip~ego4" and clip.ego_motion.size_wh == (320, 256)
    assert clip.ego_motion.dt_s == pytest.approx(1 / 25)

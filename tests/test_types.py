import numpy as np
import pytest

from payload.types import Detections


def dets():
    return Detections([[0, 0, 10, 10], [5, 5, 7, 9], [1, 2, 3, 4]], [0.2, 0.9, 0.5], ["GAD", "LAD", "GMD"])


@pytest.mark.parametrize(
    "index,expected_scores",
    [
        (slice(None, 1), [0.2]),
        (slice(0, 0), []),
        (1, [0.9]),
        (np.array([2, 0]), [0.5, 0.2]),
        (np.array([True, False, True]), [0.2, 0.5]),
        (np.array([], int), []),
    ],
)
def test_selection(index, expected_scores):
    picked = dets()[index]
    assert picked.score.tolist() == pytest.approx(expected_scores)
    assert picked.xyxy.shape == (len(expected_scores), 4)


def test_empty_is_valid_and_concat_skips_empties():
    empty = Detections.empty()
    assert len(empty) == 0 and empty.xyxy.shape == (0, 4)
    both = Detections.concat([empty, dets(), empty])
    assert len(both) == 3
    assert len(Detections.concat([])) == 0


def test_sorted_shifted_and_geometry():
    d = dets().sorted_by_score()
    assert d.module.tolist() == ["LAD", "GMD", "GAD"]
    moved = d.shifted(100, 50)
    assert moved.xyxy[0].tolist() == [105, 55, 107, 59]
    assert d.xyxy[0].tolist() == [5, 5, 7, 9]  # the original is untouched
    assert moved.centers[0].tolist() == [106, 57]
    assert d.areas.tolist() == [8, 4, 100]
    assert Detections.from_xywh([[1, 2, 3, 4]], [1.0], "LMD").xyxy.tolist() == [[1, 2, 4, 6]]


def test_mismatched_lengths_rejected():
    with pytest.raises(ValueError, match="same length"):
        Detections([[0, 0, 1, 1]], [0.1, 0.2], ["GAD", "GAD"])


def test_resized_keeps_centres_scores_and_modules():
    d = Detections([[10, 20, 30, 40], [0, 0, 4, 2]], [0.9, 0.5], ["LAD", "LMD"])
    r = d.resized((10, 6))
    assert r.xyxy.tolist() == [[15, 27, 25, 33], [-3, -2, 7, 4]]
    assert r.score.tolist() == pytest.approx([0.9, 0.5]) and r.module.tolist() == ["LAD", "LMD"]
    assert d.xyxy.tolist()[0] == [10, 20, 30, 40]  # the input is not changed

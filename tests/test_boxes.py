"""payload.boxes: IoU, NMS, merging nearby boxes, tiles covering a frame."""

import numpy as np
import pytest

from payload.boxes import iou_matrix, merge_boxes, nms, tile_starts, tiles_xyxy

# ---------------------------------------------------------------- IoU


@pytest.mark.parametrize(
    "a, b, iou",
    [
        ([0, 0, 10, 10], [0, 0, 10, 10], 1.0),
        ([0, 0, 10, 10], [0, 0, 10, 5], 0.5),  # half covered
        ([0, 0, 10, 10], [10, 0, 20, 10], 0.0),  # touching edges share no area
        ([0, 0, 10, 10], [5, 5, 15, 15], 25.0 / 175.0),
        ([0, 0, 0, 0], [0, 0, 0, 0], 0.0),  # degenerate boxes never match
    ],
)
def test_iou(a, b, iou):
    assert iou_matrix(np.array([a]), np.array([b]))[0, 0] == pytest.approx(iou)


# ---------------------------------------------------------------- NMS


@pytest.mark.parametrize(
    "xyxy, score, iou, kept",
    [
        ([[0, 0, 10, 10], [1, 1, 11, 11], [50, 50, 60, 60]], [0.9, 0.8, 0.7], 0.4, [0, 2]),
        ([[0, 0, 10, 10], [1, 1, 11, 11]], [0.6, 0.8], 0.4, [1]),
        ([[0, 0, 10, 10], [5, 0, 15, 10]], [0.9, 0.8], 0.4, [0, 1]),  # IoU 1/3 < 0.4: both stay
        ([[0, 0, 10, 10], [5, 0, 15, 10]], [0.9, 0.8], 0.3, [0]),
        (np.zeros((0, 4)), [], 0.4, []),
    ],
)
def test_nms(xyxy, score, iou, kept):
    keep = nms(np.asarray(xyxy, np.float32).reshape(-1, 4), np.asarray(score, np.float32), iou)
    assert keep.tolist() == kept


# ---------------------------------------------------------------- merging


def test_merge_boxes_is_transitive_and_uses_gaps():
    boxes = np.array([[0, 0, 10, 10], [20, 0, 30, 10], [40, 0, 50, 10], [200, 200, 210, 210]], np.float32)
    merged = merge_boxes(boxes, 15)  # A-B and B-C 10 px apart, A-C 30 px apart
    assert sorted(merged.tolist()) == [[0, 0, 50, 10], [200, 200, 210, 210]]
    long_boxes = np.array([[0, 0, 100, 10], [105, 0, 200, 10]], np.float32)  # centres 102 px apart
    assert merge_boxes(long_boxes, 15).tolist() == [[0, 0, 200, 10]]


# ---------------------------------------------------------------- tiles


@pytest.mark.parametrize("size_wh", [(640, 512), (1920, 1080), (320, 320), (200, 150), (1000, 333)])
@pytest.mark.parametrize("tile_wh", [(320, 320), (256, 192)])
@pytest.mark.parametrize("overlap", [0.0, 0.2, 0.5])
def test_tiles_cover_the_frame_with_overlap(size_wh, tile_wh, overlap):
    w, h = size_wh
    tiles = tiles_xyxy(size_wh, tile_wh, overlap)
    covered = np.zeros((h, w), bool)
    for x1, y1, x2, y2 in tiles:
        assert 0 <= x1 < x2 <= w and 0 <= y1 < y2 <= h
        assert (x2 - x1, y2 - y1) == (min(tile_wh[0], w), min(tile_wh[1], h))  # every tile detector-sized
        covered[y1:y2, x1:x2] = True
    assert covered.all()
    for length, tile in ((w, tile_wh[0]), (h, tile_wh[1])):
        starts = tile_starts(length, tile, overlap)
        assert starts[0] == 0 and starts[-1] + min(tile, length) == length
        for a, b in zip(starts, starts[1:]):
            assert b > a
            assert a + tile - b >= overlap * tile - 1  # neighbours share at least the overlap (int stride)


def test_tile_overlap_out_of_range_is_refused():
    with pytest.raises(ValueError, match="overlap"):
        tile_starts(640, 320, 1.0)

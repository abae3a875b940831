import os

import numpy as np
import pytest

from payload.errors import DataError, PayloadError
from payload.records import DetectionsCsvWriter, read_detections_csv
from payload.types import Detections


def _dets(rows):
    return Detections(
        np.array([r[0] for r in rows], np.float32).reshape(-1, 4),
        np.array([r[1] for r in rows], np.float32),
        np.array([r[2] for r in rows]),
    )


def test_round_trip(tmp_path):
    path = tmp_path / "out" / "dets.csv"
    frames = {
        0: _dets([([10.5, 20.25, 40.5, 30.25], 0.9, "GAD"), ([100, 100, 110, 108], 0.31, "GMD")]),
        1: Detections.empty(),
        7: _dets([([0, 0, 3, 4], 0.5, "LAD")]),
        8: _dets([([5, 6, 7, 8], 0.123456, "LMD")]),
    }
    with DetectionsCsvWriter(str(path)) as writer:
        for index, dets in frames.items():
            writer.write(index, dets)
    assert writer.rows == 4
    lines = path.read_text().splitlines()
    assert lines[0] == "frame,x,y,w,h,score,module,target_id,primary"
    assert lines[1] == "0,10.50,20.25,30.00,10.00,0.9000,GAD,,1"  # no target id: a detector following none
    back = read_detections_csv(str(path))
    assert sorted(back) == [0, 7, 8]  # a frame without detections has no row
    for index in back:
        np.testing.assert_allclose(back[index].xyxy, frames[index].xyxy, atol=0.006)
        np.testing.assert_allclose(back[index].score, frames[index].score, atol=5e-5)
        assert list(back[index].module) == list(frames[index].module)


def test_each_frame_is_on_disk_before_close(tmp_path):
    path = tmp_path / "dets.csv"
    writer = DetectionsCsvWriter(str(path))
    writer.write(3, _dets([([1, 2, 3, 4], 0.7, "LAD")]))
    # Read while the writer is still open: what a crash right now would leave behind.
    assert sorted(read_detections_csv(str(path))) == [3]
    writer.close()
    with pytest.raises(ValueError):
        writer.write(4, _dets([([1, 2, 3, 4], 0.7, "LAD")]))


def test_header_only_file_is_empty(tmp_path):
    path = tmp_path / "dets.csv"
    DetectionsCsvWriter(str(path)).close()
    assert read_detections_csv(str(path)) == {}


@pytest.mark.parametrize(
    "body, needle",
    [
        ("frame,x,y,w,h,score\n", ":1: header"),
        ("", ":1: header <empty file>"),
        ("frame,x,y,w,h,score,module\n0,1,2,3,4,0.5,GAD\n1,1,2,3,0.5,GAD\n", ":3: 6 fields"),
        ("frame,x,y,w,h,score,module\nx,1,2,3,4,0.5,GAD\n", ":2: frame='x' is not an integer"),
        ("frame,x,y,w,h,score,module\n-1,1,2,3,4,0.5,GAD\n", ":2: frame=-1"),
        ("frame,x,y,w,h,score,module\n0,1,2,abc,4,0.5,GAD\n", ":2: w='abc' is not a number"),
        ("frame,x,y,w,h,score,module\n0,1,2,3,4,nan,GAD\n", ":2: score='nan' must be finite"),
        ("frame,x,y,w,h,score,module\n0,1,2,-3,4,0.5,GAD\n", ":2: w=-3, h=4 must be >= 0"),
        ("frame,x,y,w,h,score,module\n\n0,1,2,3,4,0.5,YOLO\n", ":3: module='YOLO', expected one of GAD|GMD|LAD|LMD"),
    ],
)
def test_bad_rows_give_one_line_errors_naming_file_and_line(tmp_path, body, needle):
    path = tmp_path / "bad.csv"
    path.write_text(body)
    with pytest.raises(DataError) as info:
        read_detections_csv(str(path))
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path))
    assert needle in message
    assert isinstance(info.value, PayloadError)


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match="cannot read detections CSV"):
        read_detections_csv(str(tmp_path / "absent.csv"))


def test_unwritable_path(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(DataError, match="cannot write detections CSV"):
        DetectionsCsvWriter(str(blocker / "dets.csv"))


# --- CsvLog: the service's records (issue 20) ---------------------------------------------------


def test_csv_log_appends_across_restarts_and_rotates_by_size(tmp_path):
    from payload.records import CsvLog

    path = str(tmp_path / "decisions.csv")
    for start in range(3):  # three "runs" of 40 rows each, ~35 bytes a row: 4 rotations
        log = CsvLog(path, ["frame", "note"], max_bytes=1000, keep=2)
        for i in range(40):
            assert log.write_rows([(start * 40 + i, "x" * 30)])
        log.close()
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["decisions.csv", "decisions.csv.1", "decisions.csv.2"]  # older files deleted
    rows = []
    for name in reversed(names):
        lines = (tmp_path / name).read_text().splitlines()
        assert lines[0] == "frame,note" and "frame,note" not in lines[1:]  # one header a file
        assert (tmp_path / name).stat().st_size < 1000 + 40
        rows += [int(line.split(",")[0]) for line in lines[1:]]
    assert rows == list(range(rows[0], 120))  # in order, nothing lost but what rotated out


def test_csv_log_ends_a_cut_row_and_moves_a_foreign_file_aside(tmp_path):
    from payload.records import CsvLog

    path = tmp_path / "decisions.csv"
    path.write_text("frame,note\n1,complete\n2,cut sh")  # the last run died mid-row
    log = CsvLog(str(path), ["frame", "note"])
    log.write_rows([(3, "next")])
    log.close()
    assert path.read_text().splitlines() == ["frame,note", "1,complete", "2,cut sh", "3,next"]
    path.write_text("old,header\n1,2\n")  # another layout (an older version): kept aside, not mixed
    log = CsvLog(str(path), ["frame", "note"], keep=1)
    log.write_rows([(4, "new")])
    log.close()
    assert path.read_text() == "frame,note\n4,new\n"
    assert (tmp_path / "decisions.csv.1").read_text() == "old,header\n1,2\n"


def test_csv_log_write_failure_is_reported_once_and_never_raises(tmp_path, caplog):
    from payload.records import CsvLog

    caplog.set_level("INFO")
    path = tmp_path / "decisions.csv"
    path.symlink_to("/dev/full")  # every write: ENOSPC
    log = CsvLog(str(path), ["frame"], retry_s=0.0)
    for i in range(20):
        assert not log.write_rows([(i,)])
    assert log.lost == 20 and log.rows == 0
    errors = [r.getMessage() for r in caplog.records if "cannot write" in r.getMessage()]
    assert len(errors) == 1 and "No space left on device" in errors[0] and "\n" not in errors[0]
    os.remove(str(path))  # space again
    assert log.write_rows([(20,)]) and path.read_text() == "frame\n20\n"
    assert any("writing %s again (20 rows lost" % path in r.getMessage() for r in caplog.records)
    log.close()

"""The CSV records: detections (written by ``detect`` and the service, read by ``eval``) and the
service's decisions.

Detections: one row per detection, ``frame,x,y,w,h,score,module,target_id,primary`` with
``frame`` 0-based, ``x,y`` the top-left corner in full-frame pixels (0-based), ``w,h`` in pixels,
``module`` one of GAD, GMD, LAD, LMD, ``target_id`` the target's id (empty for a detector that
follows no targets) and ``primary`` 1 for the target sent to the autopilot, 0 for the others GLAD
reports beside it. A frame without detections has no row. Files written before issue 16 lack the
last two columns: each of their rows counts as primary. ``glad-payload eval`` scores the primary
rows only, so its figures stay comparable with single-target runs.

Decisions (service only): one row per processed frame, what the switcher decided and what was sent,
and how many targets were reported.

The service writes both through ``CsvLog``: appended to across restarts, rotated by size, and
never stopping detection when the disk is full or the folder is gone (reported once).
"""

import csv
import logging
import math
import os
import time
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, TextIO, Tuple

import numpy as np

from payload.errors import DataError
from payload.types import MODULES, Detections

log = logging.getLogger(__name__)

HEADER = ("frame", "x", "y", "w", "h", "score", "module", "target_id", "primary")
#: The header before targets had ids (issue 16): still read, every row primary.
HEADER_SINGLE = HEADER[:7]


@dataclass(frozen=True)
class DetectionRow:
    """One row of a detections CSV."""

    frame: int
    xywh: Tuple[float, float, float, float]
    score: float
    module: str
    target_id: Optional[int]  # None: not a followed target's (a baseline's, or a file without the column)
    primary: bool


def detection_rows(frame_index: int, dets: Detections, target_id: Optional[int] = None,
                   primary: bool = True) -> List[tuple]:
    """The detections CSV rows of one frame's ``dets`` (of target ``target_id`` when given)."""
    tid = "" if target_id is None else str(int(target_id))
    flag = "1" if primary else "0"
    return [(int(frame_index), "%.2f" % x, "%.2f" % y, "%.2f" % w, "%.2f" % h, "%.4f" % score, str(module), tid, flag)
            for (x, y, w, h), score, module in zip(dets.xywh, dets.score, dets.module)]


def result_rows(frame_index: int, result: Any) -> List[tuple]:
    """The detections CSV rows of one frame's GladResult: each reported target measured this frame,
    with its id, the primary flagged; a detector that lists no targets (a baseline): its detections,
    all primary."""
    targets = getattr(result, "targets", ())
    if not targets:
        return detection_rows(frame_index, result.detections)
    rows: List[tuple] = []
    for t in targets:
        rows += detection_rows(frame_index, t.detections, t.id, t.primary)
    return rows


class DetectionsCsvWriter:
    """Appends detections frame by frame; each frame is flushed so a crash loses nothing written."""

    def __init__(self, path: str) -> None:
        self.path = path
        parent = os.path.dirname(os.path.abspath(path))
        try:
            os.makedirs(parent, exist_ok=True)
            self._file: Optional[TextIO] = open(path, "w", newline="", encoding="utf-8")
        except OSError as exc:
            raise DataError("%s: cannot write detections CSV: %s" % (path, exc.strerror or exc)) from None
        self._csv = csv.writer(self._file, lineterminator="\n")
        self._csv.writerow(HEADER)
        self._file.flush()
        self.rows = 0

    def write(self, frame_index: int, dets: Detections, target_id: Optional[int] = None, primary: bool = True) -> None:
        """One frame's detections (of target ``target_id`` when given)."""
        self._write(frame_index, detection_rows(frame_index, dets, target_id, primary))

    def write_result(self, frame_index: int, result: Any) -> None:
        """One frame's GladResult: every reported target measured this frame (``result_rows``)."""
        self._write(frame_index, result_rows(frame_index, result))

    def _write(self, frame_index: int, rows: List[tuple]) -> None:
        if self._file is None:
            raise ValueError("DetectionsCsvWriter(%s) is closed" % self.path)
        if frame_index < 0:
            raise ValueError("frame_index must be >= 0, got %d" % frame_index)
        if not rows:
            return
        self._csv.writerows(rows)
        self.rows += len(rows)
        self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> "DetectionsCsvWriter":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def parse_finite(path: str, line: int, name: str, text: str) -> float:
    """A finite float from a text field, or a DataError naming file:line, field and value."""
    try:
        value = float(text)
    except ValueError:
        raise DataError("%s:%d: %s=%r is not a number" % (path, line, name, text)) from None
    if not math.isfinite(value):
        raise DataError("%s:%d: %s=%r must be finite" % (path, line, name, text))
    return value


def read_detection_rows(path: str) -> List[DetectionRow]:
    """Every row of a detections CSV, with or without the target columns, in file order."""
    try:
        handle = open(path, newline="", encoding="utf-8")
    except OSError as exc:
        raise DataError("%s: cannot read detections CSV: %s" % (path, exc.strerror or exc)) from None
    out: List[DetectionRow] = []
    with handle:
        reader = csv.reader(handle)
        try:
            header = next(reader, None)
            columns = tuple(c.strip() for c in header) if header is not None else None
            if columns not in (HEADER, HEADER_SINGLE):
                raise DataError(
                    "%s:1: header %s, expected %s (or, written before targets had ids, %s)"
                    % (path, ",".join(header) if header else "<empty file>", ",".join(HEADER), ",".join(HEADER_SINGLE))
                )
            for row in reader:
                line = reader.line_num
                if not row or not "".join(row).strip():
                    continue
                if len(row) != len(columns):
                    raise DataError("%s:%d: %d fields, expected %d (%s)" % (path, line, len(row), len(columns), ",".join(columns)))
                out.append(_detection_row(path, line, row))
        except csv.Error as exc:
            raise DataError("%s:%d: %s" % (path, reader.line_num, exc)) from None
        except UnicodeDecodeError:
            raise DataError("%s: not a UTF-8 text file" % path) from None
    return out


def _detection_row(path: str, line: int, row: List[str]) -> DetectionRow:
    try:
        frame = int(row[0])
    except ValueError:
        raise DataError("%s:%d: frame=%r is not an integer" % (path, line, row[0])) from None
    if frame < 0:
        raise DataError("%s:%d: frame=%d must be >= 0" % (path, line, frame))
    x, y, w, h, score = (parse_finite(path, line, n, t) for n, t in zip(HEADER[1:6], row[1:6]))
    if w < 0 or h < 0:
        raise DataError("%s:%d: w=%s, h=%s must be >= 0" % (path, line, row[3], row[4]))
    module = row[6].strip()
    if module not in MODULES:
        raise DataError("%s:%d: module=%r, expected one of %s" % (path, line, module, "|".join(MODULES)))
    target_id, primary = None, True
    if len(row) > 7:
        text = row[7].strip()
        if text:
            if not text.isdigit():
                raise DataError("%s:%d: target_id=%r, expected a whole number >= 0 or empty" % (path, line, row[7]))
            target_id = int(text)
        flag = row[8].strip()
        if flag not in ("0", "1"):
            raise DataError("%s:%d: primary=%r, expected 1 (the target sent) or 0" % (path, line, row[8]))
        primary = flag == "1"
    return DetectionRow(frame, (x, y, w, h), score, module, target_id, primary)


def read_detections_csv(path: str, primary_only: bool = True) -> Dict[int, Detections]:
    """Frame index -> Detections of that frame (frames without rows are absent): the primary
    target's rows (what ``eval`` scores; every row of a file without the target columns), or
    every row with ``primary_only`` False."""
    rows: Dict[int, List[DetectionRow]] = {}
    for r in read_detection_rows(path):
        if r.primary or not primary_only:
            rows.setdefault(r.frame, []).append(r)
    out: Dict[int, Detections] = {}
    for frame in sorted(rows):
        xywh = np.array([r.xywh for r in rows[frame]], np.float32)
        out[frame] = Detections.from_xywh(xywh, [r.score for r in rows[frame]], [r.module for r in rows[frame]])
    log.debug("read detections path=%s frames=%d rows=%d", path, len(out), sum(len(d) for d in out.values()))
    return out


DECISION_FIELDS = ("frame", "t_capture_ns", "t_wall_ns", "mode", "state", "module", "score", "x", "y", "w", "h",
                   "region_x", "region_y", "region_w", "region_h", "az_body_rad", "el_body_rad", "az_level_rad",
                   "el_level_rad", "messages_sent", "lock_p", "targets")


def decision_row(frame: Any, result: Any, bearing: Any, sent: int) -> tuple:
    """The decisions CSV row of one processed frame (a Frame, its GladResult, its Bearing or None)."""
    t = result.target
    box = [""] * 4 if t is None else ["%.1f" % t.xyxy[0], "%.1f" % t.xyxy[1],
                                      "%.1f" % (t.xyxy[2] - t.xyxy[0]), "%.1f" % (t.xyxy[3] - t.xyxy[1])]
    r = result.region_xyxy
    region = [""] * 4 if r is None else [int(r[0]), int(r[1]), int(r[2] - r[0]), int(r[3] - r[1])]
    angles = [""] * 4
    if bearing is not None:
        angles = ["%.5f" % v if v is not None else "" for v in
                  (bearing.az_body_rad, bearing.el_body_rad, bearing.az_level_rad, bearing.el_level_rad)]
    lock_p = result.lock_p
    # the targets reported this frame (GLAD lists them; a detector that does not has its one or none)
    targets = len(getattr(result, "targets", ())) or int(t is not None)
    return (frame.index, frame.t_capture_ns, frame.t_wall_ns, result.mode, result.state,
            "" if t is None else t.module, "" if t is None else "%.3f" % t.score, *box, *region, *angles, int(sent),
            "%.3f" % lock_p if lock_p == lock_p else "", targets)


class CsvLog:
    """A CSV the service appends rows to for as long as it runs, and across restarts.

    - An existing file is appended to (its header is written once; a file with another header,
      from an older version, is rotated away first).
    - At ``max_bytes`` the file becomes ``PATH.1`` (``PATH.1`` -> ``PATH.2`` ..., ``keep`` old
      files kept, older ones deleted) and a new one starts (0 = never rotate).
    - A write never raises: when the disk is full or the folder is gone the failure is logged
      once, rows are dropped (counted in ``lost``) and the file is reopened every ``retry_s``.
    """

    def __init__(self, path: str, header: Sequence[str], max_bytes: int = 0, keep: int = 0,
                 retry_s: float = 10.0) -> None:
        self.path = path
        self.header = list(header)
        self.max_bytes = int(max_bytes)
        self.keep = int(keep)
        self.retry_s = retry_s
        self.rows = 0  # rows written
        self.lost = 0  # rows dropped because the file could not be written
        self.rotations = 0
        self._fh: Optional[TextIO] = None
        self._csv: Any = None
        self._retry_at = 0.0
        self._failing = False

    def write_rows(self, rows: Sequence[Sequence[Any]]) -> bool:
        """Append rows (flushed); False when they were dropped."""
        if not rows:
            return True
        try:
            if self._fh is None:
                if time.monotonic() < self._retry_at:
                    self.lost += len(rows)
                    return False
                self._open()
            self._csv.writerows(rows)
            self._fh.flush()
            if self.max_bytes and os.fstat(self._fh.fileno()).st_size >= self.max_bytes:
                self._rotate()
        except OSError as exc:
            self.lost += len(rows)
            self._fail(exc)
            return False
        self.rows += len(rows)
        if self._failing:
            self._failing = False
            log.info("outputs: writing %s again (%d rows lost meanwhile)", self.path, self.lost)
        return True

    def close(self) -> None:
        self._close_quietly()

    # --- inside ---------------------------------------------------------------------------------

    def _open(self) -> None:
        if os.path.exists(self.path) and not self._has_header():
            self._rotate_files()
        size = os.path.getsize(self.path) if os.path.isfile(self.path) else 0
        cut_short = False
        if size:
            with open(self.path, "rb") as fb:
                fb.seek(-1, os.SEEK_END)
                cut_short = fb.read(1) != b"\n"  # a row cut short by a crash or a full disk
        fh = open(self.path, "a", newline="", encoding="utf-8")
        try:
            if not size:
                csv.writer(fh, lineterminator="\n").writerow(self.header)
            elif cut_short:
                fh.write("\n")
            fh.flush()
        except BaseException:
            try:
                fh.close()
            except OSError:
                pass
            raise
        self._fh = fh
        self._csv = csv.writer(fh, lineterminator="\n")

    def _has_header(self) -> bool:
        if not os.path.isfile(self.path):
            return True  # not a regular file (a device, a pipe): written as it is, never rotated
        try:
            with open(self.path, newline="", encoding="utf-8", errors="replace") as fh:
                first = fh.readline(4096)
        except OSError:
            return True  # unreadable: let the append report it
        return not first or next(csv.reader([first]), []) == self.header

    def _rotate(self) -> None:
        self._close_quietly(raise_errors=True)
        self._rotate_files()
        self.rotations += 1
        self._open()

    def _rotate_files(self) -> None:
        if self.keep <= 0:
            os.remove(self.path)
            return
        for i in range(self.keep - 1, 0, -1):
            older = "%s.%d" % (self.path, i)
            if os.path.exists(older):
                os.replace(older, "%s.%d" % (self.path, i + 1))
        os.replace(self.path, self.path + ".1")

    def _fail(self, exc: OSError) -> None:
        self._close_quietly()
        self._retry_at = time.monotonic() + self.retry_s
        if not self._failing:
            self._failing = True
            log.error("outputs: cannot write %s: %s; detection goes on, rows are dropped until writing works "
                      "again (retried every %.0f s)", self.path, exc.strerror or exc, self.retry_s)

    def _close_quietly(self, raise_errors: bool = False) -> None:
        fh, self._fh, self._csv = self._fh, None, None
        if fh is None:
            return
        try:
            fh.close()  # flushes; the file is closed even when that fails
        except OSError:
            if raise_errors:
                raise

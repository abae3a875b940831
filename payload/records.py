"""The detections CSV written by ``detect`` and the service and read by ``eval``.

One row per detection: ``frame,x,y,w,h,score,module`` with ``frame`` 0-based, ``x,y`` the
top-left corner in full-frame pixels (0-based), ``w,h`` in pixels and ``module`` one of
GAD, GMD, LAD, LMD. A frame without detections has no row.
"""

import csv
import logging
import math
import os
from typing import Dict, List, Optional, TextIO

import numpy as np

from payload.errors import DataError
from payload.types import MODULES, Detections

log = logging.getLogger(__name__)

HEADER = ("frame", "x", "y", "w", "h", "score", "module")


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

    def write(self, frame_index: int, dets: Detections) -> None:
        if self._file is None:
            raise ValueError("DetectionsCsvWriter(%s) is closed" % self.path)
        if frame_index < 0:
            raise ValueError("frame_index must be >= 0, got %d" % frame_index)
        if not len(dets):
            return
        xywh = dets.xywh
        for (x, y, w, h), score, module in zip(xywh, dets.score, dets.module):
            self._csv.writerow(
                (int(frame_index), "%.2f" % x, "%.2f" % y, "%.2f" % w, "%.2f" % h, "%.4f" % score, str(module))
            )
        self.rows += len(dets)
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


def read_detections_csv(path: str) -> Dict[int, Detections]:
    """Frame index -> Detections of that frame (frames without rows are absent)."""
    try:
        handle = open(path, newline="", encoding="utf-8")
    except OSError as exc:
        raise DataError("%s: cannot read detections CSV: %s" % (path, exc.strerror or exc)) from None
    rows: Dict[int, List[list]] = {}
    with handle:
        reader = csv.reader(handle)
        try:
            header = next(reader, None)
            if header is None or tuple(c.strip() for c in header) != HEADER:
                raise DataError(
                    "%s:1: header %s, expected %s"
                    % (path, ",".join(header) if header else "<empty file>", ",".join(HEADER))
                )
            for row in reader:
                line = reader.line_num
                if not row or not "".join(row).strip():
                    continue
                if len(row) != len(HEADER):
                    raise DataError("%s:%d: %d fields, expected %d (%s)" % (path, line, len(row), len(HEADER), ",".join(HEADER)))
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
                rows.setdefault(frame, []).append([x, y, w, h, score, module])
        except csv.Error as exc:
            raise DataError("%s:%d: %s" % (path, reader.line_num, exc)) from None
        except UnicodeDecodeError:
            raise DataError("%s: not a UTF-8 text file" % path) from None
    out: Dict[int, Detections] = {}
    for frame in sorted(rows):
        xywh = np.array([r[:4] for r in rows[frame]], np.float32)
        out[frame] = Detections.from_xywh(xywh, [r[4] for r in rows[frame]], [r[5] for r in rows[frame]])
    log.debug("read detections path=%s frames=%d rows=%d", path, len(out), sum(len(d) for d in out.values()))
    return out

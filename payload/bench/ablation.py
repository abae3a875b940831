"""The paper's ablation (Table V) and the baselines: P/R/F/AP and FPS per configuration.

Each row is the user's config with a few dotted overrides (``payload.config.config_with``):
the four modules switched on or off, and the adaptive search region off except in the two
GLAD rows (``search_region.adaptive=false`` is a fixed square at the last box, as in the
authors' code). The baselines run the same clips through another runner (see runners).
Every clip starts from a fresh state (``reset()``); models are loaded once per row.
"""

import logging
import time
from collections import Counter
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence

from payload.bench.runners import build_runner
from payload.capture import open_source
from payload.config import Config, config_with
from payload.errors import ConfigError
from payload.eval.labels import load_labels
from payload.eval.metrics import ClipScore, pool, score_clip
from payload.offline import ClipSpec, recording_config
from payload.types import MODULES, Detections

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Row:
    """One configuration to score: a runner kind and the config overrides that define it."""

    name: str
    runner: str  # payload.bench.runners.RUNNERS
    overrides: Dict[str, object]


def _modules(gad: bool, gmd: bool, lad: bool, lmd: bool, adaptive: bool = False) -> Dict[str, object]:
    return {
        "detector.global.appearance.enabled": gad,
        "detector.global.motion.enabled": gmd,
        "detector.local.appearance.enabled": lad,
        "detector.local.motion.enabled": lmd,
        "detector.search_region.adaptive": adaptive,
    }


#: Table V of the paper, top to bottom.
ABLATION_ROWS = (
    Row("GAD", "glad", _modules(True, False, False, False)),
    Row("GMD", "glad", _modules(False, True, False, False)),
    Row("GAD+LAD", "glad", _modules(True, False, True, False)),
    Row("GMD+LMD", "glad", _modules(False, True, False, True)),
    Row("GAD+GMD+LAD", "glad", _modules(True, True, True, False)),
    Row("GAD+GMD+LAD+LMD", "glad", _modules(True, True, True, True)),
    # not in the paper: GAD without its native-resolution tiles (payload.detect.scan)
    Row("GLAD without the native scan", "glad",
        {**_modules(True, True, True, True, adaptive=True), "detector.global.scan.tiles_per_frame": 0}),
    Row("GLAD (adaptive region)", "glad", _modules(True, True, True, True, adaptive=True)),
)

#: Baselines on the same clips (issue 6, item 3).
BASELINE_ROWS = (
    Row("global detector alone (down-scaled)", "global", {}),
    Row("tiled full-res (SAHI-style)", "tiled", {}),
)

ALL_ROWS = ABLATION_ROWS + BASELINE_ROWS


@dataclass(frozen=True)
class RowResult:
    row: Row
    clips: List[ClipScore]
    pooled: ClipScore
    frames: int
    fps_detect: float  # frames / time in process() alone
    fps_end_to_end: float  # frames / (decode + process)
    module_runs: Dict[str, int]  # frames on which each of GAD/GMD/LAD/LMD ran

    def as_dict(self) -> Dict[str, object]:
        return {
            "name": self.row.name, "runner": self.row.runner, "overrides": self.row.overrides,
            "frames": self.frames, "fps_detect": self.fps_detect, "fps_end_to_end": self.fps_end_to_end,
            "module_runs": self.module_runs, "pooled": self.pooled.as_dict(),
            "clips": [c.as_dict() for c in self.clips],
        }


def select_rows(names: Optional[Sequence[str]]) -> List[Row]:
    """Rows by name (case-insensitive); None or empty = all of them."""
    if not names:
        return list(ALL_ROWS)
    by_name = {r.name.lower(): r for r in ALL_ROWS}
    missing = [n for n in names if n.lower() not in by_name]
    if missing:
        raise ConfigError(["--rows %s: no such row (have: %s)" % (", ".join(missing), "; ".join(r.name for r in ALL_ROWS))])
    return [by_name[n.lower()] for n in names]


def run_row(cfg: Config, row: Row, clips: Sequence[ClipSpec], limit: int = 0) -> RowResult:
    """Score one row over the clips, timing the detector separately from decoding."""
    row_cfg = config_with(cfg, **row.overrides) if row.overrides else cfg
    runner = build_runner(row_cfg, row.runner)
    scores = []
    frames = 0
    detect_s = total_s = 0.0
    runs: Counter = Counter()
    for clip in clips:
        labels = load_labels(clip.labels)
        found: Dict[int, Detections] = {}
        runner.reset()
        capture = clip.capture or recording_config(row_cfg, clip.video).capture
        source = open_source(capture)
        source.prepare = getattr(runner, "prepare", None)  # as the service: GLAD's work on the capture thread
        with source as frames_in:
            t_clip = time.perf_counter()
            for frame in frames_in:
                if limit and frame.index >= limit:
                    break
                t = time.perf_counter()
                result = runner.process(frame)
                detect_s += time.perf_counter() - t
                found[frame.index] = result.detections
                runs.update(m for m in result.timings_ms if m in MODULES)
                if "tiled" in result.timings_ms:
                    runs["tiled"] += 1
            total_s += time.perf_counter() - t_clip
        n = max(found) + 1 if found else 0
        frames += len(found)
        scores.append(score_clip(clip.name, found, labels, frames=n))
        log.info("ablation row=%s clip=%s frames=%d tp=%d fp=%d", row.name, clip.name, n, scores[-1].tp, scores[-1].fp)
    return RowResult(
        row=row, clips=scores, pooled=pool(scores, name=row.name), frames=frames,
        fps_detect=frames / detect_s if detect_s > 0 else float("nan"),
        fps_end_to_end=frames / total_s if total_s > 0 else float("nan"),
        module_runs=dict(runs),
    )


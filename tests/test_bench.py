"""glad-payload bench: the tiled baseline, the ablation rows, and the profile on a short synthetic clip."""

import json
import math
import os

import numpy as np
import pytest
import yaml
from onnx_factories import bright_spot_detector, brightness_classifier

from payload.bench.ablation import ABLATION_ROWS, BASELINE_ROWS, run_row, select_rows
from payload.boxes import tiles_xyxy
from payload.cli import main
from payload.config import AppearanceConfig, Config, config_with, load_config
from payload.detect.appearance import AppearanceDetector
from payload.detect.factory import builtin_model_path
from payload.detect.onnx_model import OnnxModel
from payload.detect.tiled import TiledDetector
from payload.errors import ConfigError
from payload.types import GAD, GMD, LAD, LMD

CLIP_FRAMES = 10


# --- tiling ------------------------------------------------------------------------------------


def test_tiled_detector_maps_boxes_back_and_merges_duplicates(tmp_path):
    model = OnnxModel(bright_spot_detector(tmp_path / "spot.onnx"))
    detector = AppearanceDetector(model, AppearanceConfig(confidence=0.5, input_wh=(64, 64)), LAD)
    tiled = TiledDetector(detector, overlap=0.25)  # stride 48: tiles start on 4-px cells
    image = np.zeros((160, 208, 3), np.uint8)
    squares = [(20, 20), (100, 120), (180, 140), (52, 56)]  # (52, 56) lies in four overlapping tiles
    for x, y in squares:
        image[y:y + 4, x:x + 4] = 255
    assert len(tiles_xyxy((208, 160), (64, 64), 0.25)) == 12
    found = tiled.detect(image)
    got = sorted(tuple(int(v) for v in box) for box in found.xyxy)
    assert got == sorted((x, y, x + 4, y + 4) for x, y in squares)
    assert set(found.module) == {LAD}


# --- ablation rows -------------------------------------------------------------------------------


@pytest.mark.parametrize("row", ABLATION_ROWS, ids=lambda r: r.name)
def test_ablation_rows_switch_the_named_modules(row):
    cfg = config_with(Config(), **row.overrides).detector
    named = {GAD, GMD, LAD, LMD} if row.name.startswith("GLAD") else set(row.name.split("+"))
    assert cfg.global_.appearance.enabled == (GAD in named)
    assert cfg.global_.motion.enabled == (GMD in named)
    assert cfg.local.appearance.enabled == (LAD in named)
    assert cfg.local.motion.enabled == (LMD in named)
    assert cfg.search_region.adaptive == row.name.startswith("GLAD")
    assert (cfg.global_.scan.tiles_per_frame == 0) == row.name.endswith("without the native scan")


def test_unknown_row_name_is_one_line_error():
    with pytest.raises(ConfigError, match="no such row"):
        select_rows(["GAD+XYZ"])


# --- on a rendered synthetic clip ----------------------------------------------------------------


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    """A short small synthetic clip with labels, and a config with a test classifier (the shipped
    detectors are used as they are)."""
    from payload.offline import synthetic_clip

    for name in ("global", "local"):
        if not os.path.isfile(builtin_model_path(name)):
            pytest.skip("shipped model %s not in the package" % name)
    root = tmp_path_factory.mktemp("bench")
    data = {"capture": {"synthetic": {"width": 320, "height": 256, "seed": 3}},
            "detector": {"threads": 1, "classifier": {"model": brightness_classifier(root / "cls.onnx")}}}
    path = root / "bench.yaml"
    path.write_text(yaml.safe_dump(data))
    cfg = load_config(str(path))
    clip = synthetic_clip(cfg, str(root / "clip"), CLIP_FRAMES)
    return cfg, str(path), clip


def _row(name):
    return select_rows([name])[0]


def test_gad_only_row_never_runs_motion_or_local_modules(synth):
    cfg, _, clip = synth
    result = run_row(cfg, _row("GAD"), [clip])
    assert result.frames == CLIP_FRAMES
    assert result.module_runs == {GAD: CLIP_FRAMES}
    assert result.pooled.gt > 0 and result.fps_detect > 0 and result.fps_end_to_end > 0


def test_motion_rows_never_run_appearance_modules(synth):
    cfg, _, clip = synth
    result = run_row(cfg, _row("GMD+LMD"), [clip])
    assert set(result.module_runs) <= {GMD, LMD}
    assert result.module_runs[GMD] >= 1  # from the second frame on, until a hit moves it local


def test_tiled_baseline_runs_tiles_on_every_frame(synth):
    cfg, _, clip = synth
    result = run_row(cfg, BASELINE_ROWS[1], [clip])
    assert result.module_runs == {"tiled": CLIP_FRAMES}


def test_bench_command_prints_and_writes_every_section(synth, tmp_path, capsys):
    _, config_path, clip = synth
    out = tmp_path / "bench.json"
    assert main(["bench", clip.video, "-c", config_path, "--json", str(out)]) == 0
    text = capsys.readouterr().out
    for section in ("module", "decode", "grey", "mavlink", "fps end-to-end", "fps without decoding",
                    "fps decode only", "end-to-end / decode-only", "latency capture->MAVLink", "providers=CPU",
                    "threads=1"):
        assert section in text
    report = json.loads(out.read_text())
    assert report["frames"] == CLIP_FRAMES and report["size_wh"] == [320, 256]
    modules = {m["name"]: m for m in report["modules"]}
    assert modules["decode"]["runs"] == modules["mavlink"]["runs"] == CLIP_FRAMES
    assert set(modules) & {GAD, LAD}  # some detector ran
    for m in modules.values():
        assert 0 <= m["median_ms"] <= m["p95_ms"] and 0 < m["share"] <= 1
    assert sum(report["modes"].values()) == CLIP_FRAMES
    fps = report["fps_end_to_end"]
    assert 0 < fps < report["fps_without_decode"] and fps < report["fps_decode_only"]
    assert math.isclose(report["decode_ratio"], fps / report["fps_decode_only"], rel_tol=1e-9)
    assert 0 < report["latency_p50_ms"] <= report["latency_p99_ms"] <= report["latency_max_ms"]
    assert report["latency_p50_ms"] >= modules["decode"]["median_ms"]
    assert report["providers"] and all(p == "CPUExecutionProvider" for p in report["providers"])
    # everything the publisher handed to the link arrived at the bench's own UDP socket
    assert report["messages_received"] == report["messages_sent"] > 0
    # the second payload-loop pass with the live video on: measured wherever the video can run
    assert "fps end-to-end, live video off / on" in text
    try:
        from payload.video.gst import VideoUnavailable, choose_encoder, import_rtsp_server

        import_rtsp_server()
        choose_encoder("auto")
    except VideoUnavailable as exc:
        assert report["fps_stream_on"] is None and report["fps_stream_off"] is None, exc
        assert report["stream"].startswith("not measured"), exc
    else:
        assert report["fps_stream_on"] > 0 and report["stream"].startswith("rtsp://127.0.0.1:")
        assert report["fps_stream_off"] >= report["fps_end_to_end"]  # the best of two off passes
        assert report["stream"].endswith("1 client(s)")  # the bench's rtspsrc client was connected
        assert report["stream_frames"] >= 1
        # two stream-on passes over the clip: each frame encoded or dropped, but for the last one or two
        # (one may wait in the slot and one be in the encoder when the stats are read)
        assert 2 * CLIP_FRAMES - 2 <= report["stream_frames"] + report["stream_dropped"] <= 2 * CLIP_FRAMES


def test_paced_bench_plays_the_clip_as_a_camera_and_accounts_for_every_frame(synth, tmp_path, capsys):
    """``--paced``: the clip at camera rate on its own thread; every frame of it is processed,
    dropped (the loop was busy when the next came) or late (decoding fell behind); each processed
    frame's latency runs from its capture stamp to the link thread's write (no timing asserted)."""
    _, config_path, clip = synth
    out = tmp_path / "paced.json"
    assert main(["bench", clip.video, "-c", config_path, "--paced", "30", "--no-stream", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    report = json.loads(out.read_text())
    assert report["paced_fps"] == 30
    assert report["frames"] + report["frames_dropped"] + report["frames_late"] == CLIP_FRAMES
    assert report["frames"] >= 1 and "paced at 30 fps: frames processed %d, dropped %d" % (
        report["frames"], report["frames_dropped"]) in text
    assert 0 < report["latency_p50_ms"] <= report["latency_p99_ms"] <= report["latency_max_ms"]
    assert "from the capture stamp" in text
    modules = {m["name"]: m for m in report["modules"]}
    assert "decode" not in modules and modules["wait"]["runs"] == modules["mavlink"]["runs"] == report["frames"]
    for m in modules.values():
        assert 0 <= m["median_ms"] <= m["p95_ms"] <= m["p99_ms"]
    assert report["messages_received"] == report["messages_sent"] > 0


def test_paced_bench_refuses_a_rate_that_is_not_positive(synth, capsys):
    _, config_path, clip = synth
    assert main(["bench", clip.video, "-c", config_path, "--paced", "-5", "--no-stream"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--paced -5" in err[0]


def test_bench_ablation_command_prints_each_row(synth, capsys, tmp_path):
    _, config_path, clip = synth
    out = tmp_path / "ablation.json"
    rows = ["GAD", "global detector alone (down-scaled)"]
    assert main(["bench", "--ablation", "--clips", clip.video, "-c", config_path, "--rows", *rows,
                 "--limit", "5", "--no-progress", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "fps_det" in text and all(r in text for r in rows)
    data = json.loads(out.read_text())
    assert [r["name"] for r in data["rows"]] == rows
    assert all(r["frames"] == 5 and r["pooled"]["frames"] == 5 for r in data["rows"])


def test_bench_on_missing_clip_is_one_line_error(capsys):
    assert main(["bench", "/nonexistent/clip.mp4"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "/nonexistent/clip.mp4" in err[0]



def test_bench_without_a_clip_renders_the_configured_synthetic_scene(synth, capsys):
    _, config_path, _ = synth
    assert main(["bench", "-c", config_path, "--frames", "4"]) == 0
    text = capsys.readouterr().out
    assert "SYN_3_320x256.mp4 (320x256, 4 frames)" in text and "fps decode only" in text

import os
import subprocess
import sys

import pytest
import yaml

from payload.config import Config, config_with, load_config, restart_required
from payload.errors import ConfigError

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

DEFAULT_YAML = os.path.join(REPO, "configs", "default.yaml")

# (YAML text, the one line expected after "FILE:LINE: ")
BROKEN = [
    ("detector:\n  local:\n    appearance:\n      confidence: 1.7\n",
     "detector.local.appearance.confidence: 1.7 is not in [0, 1]"),
    ("detector:\n  global:\n    apperance:\n      enabled: true\n",
     "detector.global.apperance: unknown key (did you mean 'appearance'?)"),
    ("capture:\n  source: webcam\n",
     "capture.source: 'webcam' is not one of 'synthetic', 'file', 'folder', 'v4l2' or 'gstreamer'"),
    ("mavlink:\n  system_id: 300\n", "mavlink.system_id: 300 is not in [1, 255]"),
    ("capture:\n  source: file\n",
     "capture: source 'file' needs capture.path: set it to the video file or image folder"),
    ("detector:\n  global:\n    motion:\n      blur_px: 4\n",
     "detector.global.motion: blur_px 4 must be odd (or 0 to switch blur off)"),
    ("detector:\n  search_region:\n    side_px: ten\n", "detector.search_region.side_px: 'ten' is not a whole number"),
    ("detector:\n  local:\n    motion:\n      t2: -1\n", "detector.local.motion.t2: -1 is not in [0, 255]"),
    ("detector:\n  global:\n    appearance:\n      input_wh: [640, 380]\n",
     "detector.global.appearance: input_wh [640, 380]: both sides must be positive multiples of 32"),
    ("mavlink:\n  outputs:\n    debug_vect_frame: earth\n",
     "mavlink.outputs.debug_vect_frame: 'earth' is not one of 'body' or 'level'"),
    ("logging:\n  levle: INFO\n", "logging.levle: unknown key (did you mean 'level'?)"),
    ("detector:\n  switcher:\n    max_local_misses: 3.5\n",
     "detector.switcher.max_local_misses: 3.5 is not a whole number"),
    ("detector:\n  classifier:\n    modules: [GAD, XYZ]\n",
     "detector.classifier.modules[1]: 'XYZ' is not one of 'GAD', 'GMD', 'LAD' or 'LMD'"),
]


def test_default_yaml_holds_every_default():
    # configs/default.yaml documents every key: it must equal the built-in defaults exactly.
    assert load_config(DEFAULT_YAML) == Config()
    with open(DEFAULT_YAML) as fh:
        data = yaml.safe_load(fh)
    assert data == Config().model_dump(by_alias=True, mode="json")


def test_a_file_setting_one_key_keeps_the_rest_of_its_section(tmp_path):
    # the local and global stages share one section type with different defaults: a file naming
    # only the local model must not put the global T0 and input size on the local detector
    path = tmp_path / "partial.yaml"
    path.write_text("detector:\n  local:\n    appearance:\n      model: /opt/local.onnx\n"
                    "  global:\n    motion:\n      t2: 6\n")
    c = load_config(str(path)).detector
    assert c.local.appearance.model == "/opt/local.onnx"
    assert (c.local.appearance.confidence, c.local.appearance.input_wh) == (0.1, (320, 320))
    assert c.global_.motion.t2 == 6.0
    assert (c.global_.motion.alpha, c.global_.motion.min_blob_area_px) == (0.0, 6)
    assert c.local.motion == Config().detector.local.motion


def test_paper_parameters_defaults():
    c = Config().detector
    assert c.global_.appearance.confidence == 0.5  # T0
    assert c.local.appearance.confidence == 0.1  # T1
    m = c.global_.motion
    # T3 is a circular spread (1 - R), not the paper's variance in rad^2: 0.8 rad^2 ~ 0.33 (see motion.py)
    assert (m.t2, m.angle_spread_max, m.speed_spread_max, m.min_speed_px) == (5.0, 0.33, 0.8, 1.0)  # T2-T5
    assert m.merge_distance_px == 15.0 and m.grid_wh == (30, 20)
    # measured deviations for 4-10 px targets in the global motion detector (payload/config.py)
    assert (m.alpha, m.open_iterations, m.min_blob_area_px) == (0.0, 0, 6)
    lm = c.local.motion
    assert (lm.alpha, lm.open_iterations, lm.min_blob_area_px) == (1.0, 1, 30)
    assert c.search_region.side_px == 300 and c.search_region.growth_px_per_miss == 4.0
    assert c.switcher.max_local_misses == 10  # measured deviation from the paper's 30 (payload/config.py)


@pytest.mark.parametrize("text,expected", BROKEN)
def test_broken_config_gives_one_line(tmp_path, text, expected):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(str(path))
    assert len(info.value.problems) == 1
    line = info.value.problems[0]
    assert "\n" not in line
    assert line.startswith(str(path) + ":")
    assert line.split(": ", 1)[1] == expected


def test_error_points_at_the_yaml_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("capture:\n  fps: 30\ndetector:\n  local:\n    appearance:\n      confidence: 1.7\n")
    with pytest.raises(ConfigError) as info:
        load_config(str(path))
    assert info.value.problems[0].startswith("%s:6: " % path)


def test_several_problems_one_line_each(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("capture:\n  sorce: file\nmavlink:\n  heartbeat_hz: 0\n")
    with pytest.raises(ConfigError) as info:
        load_config(str(path))
    assert len(info.value.problems) == 2


def test_not_yaml_and_missing_file(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("capture: [unclosed\n")
    with pytest.raises(ConfigError) as info:
        load_config(str(path))
    assert "not valid YAML" in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_config(str(tmp_path / "nope.yaml"))


def _cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "payload", *args], cwd=REPO, capture_output=True, text=True, timeout=60
    )


def test_check_config_cli():
    ok = _cli("check-config", DEFAULT_YAML)
    assert ok.returncode == 0, ok.stderr


def test_check_config_cli_bad(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(BROKEN[0][0])
    bad = _cli("check-config", str(path))
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines() == ["%s:4: %s" % (path, BROKEN[0][1])]
    assert "Traceback" not in bad.stderr


def test_restart_required_names_only_restart_keys():
    base = Config()
    thresholds = config_with(base, **{"detector.local.appearance.confidence": 0.2, "detector.global.motion.t2": 7.0})
    assert restart_required(base, thresholds) == []
    camera = config_with(base, **{"capture.device": "/dev/video2", "detector.backend": "cuda"})
    assert restart_required(base, camera) == ["capture.device", "detector.backend"]

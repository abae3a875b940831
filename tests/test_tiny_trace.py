"""bench/tiny_trace.py: where a synthetic drone's frames go, per frame and in shares."""

import os
import re
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(REPO, "bench", "tiny_trace.py")


def run(*args):
    return subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True, timeout=300, cwd=REPO)


def test_one_letter_a_labelled_frame_and_shares_that_count_them():
    proc = run("--config", os.path.join(REPO, "configs", "tiny-light-sky.yaml"), "301", "--frames", "12")
    assert proc.returncode == 0, proc.stderr
    letters, seed_line, all_line = proc.stdout.strip().splitlines()
    found = re.match(r"seed 301: (\d+) labelled frames: reported ([\d.]+) wrong ([\d.]+) coasting ([\d.]+) "
                     r"near ([\d.]+) far ([\d.]+) searching ([\d.]+)$", seed_line)
    assert found, seed_line
    n = int(found.group(1))
    assert 0 < n <= 12 and len(letters) == n and set(letters) <= set("TWonfstwONF_")
    shares = [float(x) for x in found.groups()[1:]]
    for share, kind in zip(shares, ("Tt", "Ww", "oO", "nN", "fF", "s_")):
        assert share == pytest.approx(sum(letters.count(c) for c in kind) / n, abs=0.0006)
    assert all_line == "all seeds: " + seed_line[len("seed 301: "):]


def _result(detections=(), target=None, following=False, region=None):
    from payload.types import Detections

    dets = Detections(np.float32(detections).reshape(-1, 4), np.ones(len(detections), np.float32),
                      np.array(["LAD"] * len(detections), "<U3"))
    return SimpleNamespace(detections=dets, target=target, following=following,
                           region_xyxy=None if region is None else np.float32(region))


def test_each_frame_is_put_where_it_went():
    sys.path.insert(0, os.path.join(REPO, "bench"))
    from tiny_trace import kind_of

    drone = np.float32([100, 100, 104, 104])
    assert kind_of(_result([[101, 101, 105, 105]]), drone) == "reported"  # centre (103, 103) on it
    assert kind_of(_result([[130, 100, 134, 104]]), drone) == "wrong"
    assert kind_of(_result(target=object()), drone) == "coasting"
    assert kind_of(_result(following=True, region=[50, 50, 150, 150]), drone) == "near"
    assert kind_of(_result(following=True, region=[200, 200, 300, 300]), drone) == "far"
    assert kind_of(_result(following=True), drone) == "far"  # no region: not near
    assert kind_of(_result(), drone) == "searching"


@pytest.mark.parametrize("args, expected", [
    (("301", "--frames", "0"), "--frames 0: expected at least 1 frame"),
    (("3x",), "'3x': expected a seed (7) or a range of seeds (100-109)"),
])
def test_a_bad_argument_is_one_line(args, expected):
    proc = run(*args)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert expected in proc.stderr.strip().splitlines()[-1]


def test_a_broken_config_is_one_line_naming_the_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("detector: {verifier: {threshold: 7}}\n")
    proc = run("--config", str(bad), "301", "--frames", "2")
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert str(bad) in proc.stderr and "threshold" in proc.stderr

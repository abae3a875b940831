"""bench/drone_free.py: the drone-free scenes' false-target count, and a broken config refused in one line."""

import os
import re
import subprocess
import sys

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(REPO, "bench", "drone_free.py")


def run(*args):
    return subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True, timeout=300, cwd=REPO)


def test_counts_every_frame_of_every_seed():
    proc = run("--first-seed", "6100", "--scenes", "2", "--frames", "6")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert [re.match(r"seed (\d+): a target in (\d+) of 6 frames", x).group(1) for x in lines[:2]] == ["6100", "6101"]
    hits = sum(int(re.match(r"seed \d+: a target in (\d+)", x).group(1)) for x in lines[:2])
    assert lines[2].startswith("drone-free scenes 6100-6101: a false target in %d of 12 frames" % hits)


def test_a_broken_config_is_one_line_naming_the_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("detector: {verifier: {threshold: 7}}\n")
    proc = run("--config", str(bad), "--scenes", "1", "--frames", "2")
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert str(bad) in proc.stderr and "threshold" in proc.stderr


@pytest.mark.parametrize("args", [("--scenes", "0"), ("--frames", "0"), ("--first-seed", "-1")])
def test_a_count_with_nothing_to_run_is_refused_in_one_line(args):
    # --scenes 0 or --frames 0 would divide by zero frames; a negative seed is no scene
    proc = run(*args)
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert args[0] in proc.stderr and "expected" in proc.stderr

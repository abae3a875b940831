"""`glad-payload demo`, the README's first command: the whole payload against the fake autopilot."""

import os
import re
import subprocess
import sys

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

pytestmark = pytest.mark.slow


def run_demo(out_dir, frames):
    proc = subprocess.run([sys.executable, "-m", "payload", "demo", "--out", str(out_dir), "--frames", str(frames)],
                          cwd=REPO, capture_output=True, text=True,
                          timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    hits = int(re.search(r"frames with target (\d+)", proc.stdout).group(1))
    received = re.search(r"autopilot received (.*)", proc.stdout).group(1)
    return hits, dict((name, int(count)) for name, count in re.findall(r"(\w+) (\d+)", received))


def test_demo_twice_in_one_folder_counts_each_run_alone(tmp_path):
    frames = 40
    for _ in range(2):
        hits, counts = run_demo(tmp_path, frames)
        assert hits >= 1
        # a tracking status for every frame with a target (and the frame that loses one), this run's
        # only: the demo waits for the fake autopilot to listen before the first frame
        assert hits <= counts.get("CAMERA_TRACKING_IMAGE_STATUS", 0) <= frames
        assert counts.get("HEARTBEAT", 0) >= 1
    for name in ("demo.mp4", "detections.csv", "decisions.csv", "autopilot.jsonl"):
        assert os.path.getsize(str(tmp_path / name)) > 0, name

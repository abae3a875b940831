"""Shared test fixtures. Data under ../shared is optional: tests that need it skip cleanly."""

import importlib.util
import os
import shutil
import sys

import numpy as np
import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HALMSTAD = os.path.join(os.path.dirname(REPO), "shared", "data", "halmstad")


@pytest.fixture
def halmstad_dir():
    if not os.path.isdir(HALMSTAD):
        pytest.skip("Halmstad data not found at %s" % HALMSTAD)
    return HALMSTAD


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def mavproxy_script():
    """This interpreter's MAVProxy script (run it with sys.executable); skips where it is missing.
    A mavproxy.py of another environment on PATH is no use: its MAVProxy cannot be imported here."""
    script = shutil.which("mavproxy.py", path=os.path.dirname(sys.executable))
    if importlib.util.find_spec("MAVProxy") is None or script is None:
        pytest.skip("MAVProxy is not installed (pip install --no-deps MAVProxy pyserial)")
    return script


@pytest.fixture
def fakes():
    """Fake autopilots started by a test (test_mavlink.start_fake), killed after it."""
    started = []
    yield started
    for f in started:
        f.kill()

"""Shared test fixtures. Data under ../shared is optional: tests that need it skip cleanly."""

import os

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

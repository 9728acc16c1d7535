"""Shared fixtures. Devices under test come from REINGS_TEST_DEVICES (comma list, default
"pocl"); "cuda" is added by setting it, e.g. REINGS_TEST_DEVICES=pocl,cuda on a GPU machine."""
from __future__ import annotations

import os

import pytest


def _devices():
    return [d.strip() for d in os.environ.get("REINGS_TEST_DEVICES", "pocl").split(",") if d.strip()]


def pytest_generate_tests(metafunc):
    if "device" in metafunc.fixturenames:
        metafunc.parametrize("device", _devices(), ids=lambda d: f"opencl-{d}")


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(0)


def data_root():
    """REINGS_DATA, or None (tests that need data skip)."""
    p = os.environ.get("REINGS_DATA")
    return p if p and os.path.isdir(p) else None

"""Shared fixtures. Devices under test come from REINGS_TEST_DEVICES (comma list, default
"pocl"); "cuda" is added by setting it, e.g. REINGS_TEST_DEVICES=pocl,cuda on a GPU machine.

The LPIPS model: the package looks only at explicit places (reings.metrics.find_lpips_model). For
the tests, REINGS_LPIPS_MODEL is set, when unset, from REINGS_MODELS, else from the models folder
beside REINGS_DATA, else from the development layout `<repo>/../shared/models`; without one the
LPIPS tests skip."""
from __future__ import annotations

import os

import pytest


def _lpips_for_tests() -> None:
    if os.environ.get("REINGS_LPIPS_MODEL"):
        return
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    dirs = [os.environ.get("REINGS_MODELS"),
            os.path.join(os.environ["REINGS_DATA"], "..", "models") if os.environ.get("REINGS_DATA") else None,
            os.path.join(repo, "..", "shared", "models")]
    for d in dirs:
        if d and os.path.isfile(os.path.join(d, "lpips_vgg.onnx")):
            os.environ["REINGS_LPIPS_MODEL"] = os.path.abspath(os.path.join(d, "lpips_vgg.onnx"))
            return


_lpips_for_tests()

# Queues record profiling timestamps in the tests (several read stage times: last_profile, profile=,
# kernel_census); the default, off, is tested in test_queue_profiling.py in subprocesses.
os.environ.setdefault("REINGS_QUEUE_PROFILING", "1")


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


def pytest_collection_modifyitems(config, items):
    """The long tests (marked `slow` or `oclgrind`: whole fits, kills, the simulator) first, the rest
    in collection order: with parallel workers (`make test` runs `pytest -n 2 --dist worksteal`)
    a long test started last would leave the other worker idle at the end."""
    def long(item):
        return item.get_closest_marker("slow") is not None or item.get_closest_marker("oclgrind") is not None

    items[:] = [i for i in items if long(i)] + [i for i in items if not long(i)]

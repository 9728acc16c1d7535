"""Every kernel file builds on the GPU schedule with its defaults.

PoCL and Oclgrind are CPU devices, so the backend builds every kernel with REINGS_CPU_SCHEDULE=1 on them, and a
file's GPU schedule (REINGS_CPU_SCHEDULE=0: work-groups, local memory, the schedule's own defines) is compiled only
where a test forces it. In session 25 bin.cl's GPU schedule did not build on NVIDIA (bin_emit and tile_ranges are
built without the scan's SCAN_WG / SCAN_ITEMS, which had no defaults there): this builds each file's whole program on
the GPU schedule, with no define but the schedule, on the test device. NVIDIA's own build (REINGS_NV_PTX=1: inline
PTX) needs an NVIDIA device: REINGS_TEST_DEVICES=cuda runs this there too."""
from __future__ import annotations

import pyopencl as cl
import pytest

from reings.backends import get_backend
from reings.backends.opencl.program import kernel_dir, library_for

FILES = sorted(p.name for p in kernel_dir().glob("*.cl"))


def test_every_kernel_file_is_listed():
    assert len(FILES) >= 15 and "bin.cl" in FILES and "project.cl" in FILES


@pytest.mark.parametrize("filename", FILES)
def test_builds_on_the_gpu_schedule_with_its_defaults(device, filename):
    be = get_backend(device)
    prg = library_for(be.handle).program(filename, REINGS_CPU_SCHEDULE=0)
    assert prg.get_info(cl.program_info.NUM_KERNELS) > 0


def test_the_library_counts_its_builds(device):
    """KernelLibrary.builds / build_seconds (metrics.json `kernel_builds`): a program not built before in this
    process adds one build and its seconds; asking for it again adds nothing (the per-process cache)."""
    import os

    from reings.pipeline import builds_since, kernel_builds

    be = get_backend(device)
    lib = library_for(be.handle)
    assert be.lib is lib
    before = kernel_builds(be)
    tag = int.from_bytes(os.urandom(3), "little")  # a define no earlier build used: a new program
    lib.program("l1.cl", REINGS_TEST_BUILD_TAG=tag)
    once = builds_since(be, before)
    assert once["programs"] == 1 and once["seconds"] > 0
    lib.program("l1.cl", REINGS_TEST_BUILD_TAG=tag)
    assert builds_since(be, before) == once
    assert kernel_builds(get_backend("reference")) is None


@pytest.mark.parametrize("variant", ["llff", "dtu", "llff-async", "llff-host", "metric-only", "warp-scale-2"])
def test_a_fit_builds_nothing_on_its_clock(device, monkeypatch, variant):
    """train.fit builds the programs its passes will use before its clock starts (`OpenCLBackend.prepare` with
    `train.programs_of`): on a fresh backend whose kernel library has forgotten every program, a fit with the
    hard depth pass, the soft depth term (on the photometric render, or its own pass with DTU's background
    pass), the view_warp term, DropGaussian, densification with the prune of unseen Gaussians and the SH
    degree rising builds its programs (so the library was really empty) and none on its clock
    (FitResult.kernel_builds). Also with the sync-free binning (the shared soft term's backward is then
    opacity-only), on the host engine, with the metric depth term as the only depth term, and with the
    view_warp term at 1/2 (LossConfig.view_warp_scale: the block mean's kernels too)."""
    from dataclasses import replace

    import reings.backends as backends
    from cases import dngaussian_fit_case
    from reings.backends.opencl.backend import OpenCLBackend

    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1,
                                           iterations=14, soft_depth_from=2, densify_until=14)
    L = replace(cfg.loss, soft_depth_shared=variant.startswith("llff"), dark_background=variant == "dtu",
                drop_gamma=0.2, view_warp_weight=1.0, view_warp_from=3, view_warp_baseline=0.05)
    if variant == "metric-only":
        L = replace(L, hard_depth=False, soft_depth=False, depth_metric=0.1)
    if variant == "warp-scale-2":
        L = replace(L, view_warp_scale=2)
    cfg = replace(cfg, loss=L, densify=replace(cfg.densify, prune_unseen=True, densify_from=5, densify_interval=5))
    fresh = OpenCLBackend(get_backend(device).spec, bin_mode="async" if variant == "llff-async" else "sync")
    lib = library_for(fresh.handle)
    monkeypatch.setattr(lib, "_programs", {})  # every program built anew (from the on-disk caches)
    monkeypatch.setitem(backends._CACHE, device, fresh)
    from reings.train import fit

    before = lib.builds
    r = fit(scene, cfg, device=device, init=init, depth_targets=list(scene.depths), progress=False,
            engine="host" if variant == "llff-host" else "auto")
    assert r.history.densify and r.history.view_warp, "the case must densify and take the view_warp term"
    assert lib.builds - before >= 5, "the fit built its programs (the library had forgotten them)"
    assert r.kernel_builds == {"programs": 0, "seconds": 0.0}, r.kernel_builds

"""kernels/common.h's scalar builtins (REINGS_SCALAR_BUILTINS, on where REINGS_CLANG_BUILTINS is: PoCL's CPU
devices): clang's __builtin_sqrtf / fabsf / floorf / isfinite / elementwise_abs and the plain-operator sign in
place of PoCL's library calls, which stop the work-item loop vectorizer (docs/perf_notes.md §35). They must not
change a value: the kernels that take them, built with the define on (this process, the default) and off (a
fresh process with REINGS_CL_BUILD_OPTIONS=-DREINGS_SCALAR_BUILTINS=0), give the same bytes on inputs with
edge values (non-finite and negative depths, ties, +-0, NaN; Gaussians behind the camera, huge and tiny
scales, non-finite cotangents). project.cl's lanes take clang's elementwise floor / ceil / max / min and sqrt
lane by lane (PROJ_LANE_BUILTINS). adam.cl's sqrt is covered by test_adam_kernel.py
(bit for bit against numpy, whose sqrt is correctly rounded, as __builtin_sqrtf's)."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("pyopencl")

_HERE = os.path.dirname(os.path.abspath(__file__))
_ROOT = os.path.dirname(_HERE)

# the outputs of every kernel that takes the builtins, written to the npz file argv[1]
_SNIPPET = textwrap.dedent("""
    import sys
    import numpy as np
    sys.path[:0] = [ROOT, HERE]
    from reings.backends import reference_loss as R
    from reings.backends.opencl.losses import DepthLossCL
    from reings.backends.opencl.view_warp import ViewWarpCL

    out = {}
    rng = np.random.default_rng(3)
    h, w = 37, 61
    # view_warp: depths with NaN, +-inf, negatives, zeros, a value at -1e-5 (an infinite disparity) and far
    # ones; the images with exact ties between neighbours (sign 0 in the smoothness and L1 terms)
    depth = rng.uniform(0.5, 30.0, (h, w)).astype(np.float32)
    depth[3, 4], depth[5, 9], depth[7, 11], depth[9, 2] = np.nan, np.inf, -np.inf, -3.0
    depth[11, 20], depth[12, 21], depth[13, 1] = 0.0, -0.0, -1e-5
    depth[15, :] = depth[15, 0]
    virt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    gt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    gt[:, 30:33] = gt[:, 30:31]
    virt[20] = gt[20]
    for b in (0.37, -0.21, 2.5):
        for cs in (True, False):
            vw = ViewWarpCL(DEVICE, cpu_schedule=cs)
            loss, v_virt, v_depth = vw(virt, depth, gt, 40.0, b)
            warped, valid = vw.forward(virt, depth, 40.0, b)
            key = f"vw_{b}_{cs}"
            out[key + "_loss"] = np.float64(loss)
            out[key + "_virt"], out[key + "_depth"], out[key + "_warped"] = v_virt, v_depth, warped
            out[key + "_valid"] = valid
            # no smoothness term (gs = 0: view_warp_smooth skipped), the depth gradient added into another's
            loss, v_virt, v_depth = vw(virt, depth, gt, 40.0, b, 0.5, 0.0, v_depth=depth * 0.01)
            out[key + "_nosmooth_loss"], out[key + "_nosmooth_virt"] = np.float64(loss), v_virt
            out[key + "_nosmooth_depth"] = v_depth
    # depth loss (+ smoothness, weights): ties (a copied column), a constant patch row (zero spread)
    d = rng.uniform(1.0, 5.0, (h, w)).astype(np.float32)
    t = rng.uniform(1.0, 5.0, (h, w)).astype(np.float32)
    d[:, 3] = d[:, 2]
    d[10:20, 10:20] = 2.0
    t[0:8, :] = 1.5
    wt = rng.uniform(0.0, 1.0, (h, w)).astype(np.float32)
    sw = R.DepthSmoothWeights(t)
    for fp64 in (True, False):
        for cs in (True, False):
            dl = DepthLossCL(DEVICE, fp64=fp64, cpu_schedule=cs)
            for i, (pl, pg) in enumerate(((5, 17), (3, 9), (8, 8))):
                loss, g = dl(d, t, pl, pg, 0.0001, smooth=(sw, 0.1), weight=wt if i == 1 else None)
                key = f"dl_{fp64}_{cs}_{i}"
                out[key + "_loss"], out[key + "_grad"] = np.float64(loss), g
    # project.cl: every forward output and backward gradient (test_project's block-I/O harness: culled rows, a
    # DropGaussian mask, the hard pass's opacity override, field masks, the accumulate mode into poisoned values,
    # non-finite and huge cotangents), both SH layouts, at 8 and 16 lanes
    from dataclasses import replace
    from cases import random_scene
    from reings.backends import get_backend
    from reings.backends.reference_drop import Drop
    from test_project import _block_io_outputs, _cast_grads, _random_grads

    be = get_backend(DEVICE)
    if be.cpu:
        for deg in (0, 3):
            g, cam = random_scene(203, 64, 48, seed=deg, sh_degree=deg, scale_median=0.1)
            means, scales = g.means.copy(), g.log_scales.copy()
            means[::7, 2] = -5.0
            scales[3::11] = 9.0  # boxes beyond the image and the grid's clamps
            scales[5::13] = -30.0
            g = replace(g, means=means, log_scales=scales)
            for vw in (8, 16):
                be.proj_vw = vw
                for layout in ("packed", "in_place"):
                    for name, a in _block_io_outputs(be, g, cam, layout, Drop.at_rate(0.25, key=3)):
                        out[f"proj_{deg}_{vw}_{layout}_{name}"] = a
            # the stage methods at every width (1: the scalar lanes), the opacity-only backward (project_bwd_opacity:
            # its block shortcut and its rescaled rows) among them; cotangents with +-inf, NaN and huge rows
            gr = _cast_grads(_random_grads(len(g), deg))
            with np.errstate(invalid="ignore", over="ignore"):
                edge = np.array([np.inf, -np.inf, np.nan, 3e38, -2e30, 1e-40])
                gr.v_opacities[4::9] = edge[np.arange(len(gr.v_opacities[4::9])) % 6]
                gr.v_conics[6::10, 1] = 1e25
            for vw in (1, 8, 16):
                be.proj_vw = vw
                drop = Drop.at_rate(0.25, key=5)
                p = be.project_fwd(g, cam, drop=drop)
                for f in ("means2d", "conics", "colors", "opacities", "depths", "radii", "tile_rect"):
                    out[f"stage_{deg}_{vw}_fwd_{f}"] = np.asarray(getattr(p, f))
                for fields in (None, ("opacity_logits",)):
                    for override in (None, 0.99):
                        gb = be.project_bwd(g, cam, None, gr, grad_fields=fields, opacity_override=override,
                                            drop=drop if override is None else None)  # never both (project_fwd)
                        for f in ("means", "quats", "log_scales", "opacity_logits", "sh"):
                            out[f"stage_{deg}_{vw}_bwd_{fields}_{override}_v_{f}"] = np.asarray(getattr(gb, f))
    np.savez(sys.argv[1], **out)
""")


def _outputs(tmp_path, device: str, scalar_builtins: int | None) -> dict:
    env = dict(os.environ)
    if scalar_builtins is not None:
        env["REINGS_CL_BUILD_OPTIONS"] = (env.get("REINGS_CL_BUILD_OPTIONS", "") +
                                          f" -DREINGS_SCALAR_BUILTINS={scalar_builtins}").strip()
    path = tmp_path / f"out_{scalar_builtins}.npz"
    code = f"ROOT, HERE, DEVICE = {_ROOT!r}, {_HERE!r}, {device!r}\n" + _SNIPPET
    p = subprocess.run([sys.executable, "-c", code, str(path)], env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-4000:]
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def test_scalar_builtins_keep_the_bits(device, tmp_path):
    from reings.backends.opencl.device import open_device
    from reings.backends.opencl.program import library_for
    from test_project import _nan_canonical

    if not library_for(open_device(device)).base_defines.get("REINGS_CLANG_BUILTINS"):
        pytest.skip("the scalar builtins are taken where clang's builtins are: PoCL's CPU devices")
    import pyopencl as cl

    # the builds differ only where the compiler has the builtins (else both take OpenCL's: a vacuous comparison)
    probe = ("__kernel void k(__global int *o) { o[0] = 0;\n#if !__has_builtin(__builtin_elementwise_max) || "
             "!__has_builtin(__builtin_elementwise_floor) || !__has_builtin(__builtin_sqrtf)\n#error no builtins\n#endif\n}")
    dev = open_device(device)
    try:
        cl.Program(dev.context, probe).build()
    except cl.RuntimeError:
        pytest.fail("this PoCL's clang lacks __builtin_elementwise_max / floor or __builtin_sqrtf: the two builds would "
                    "be one (project.cl's PROJ_LANE_BUILTINS off)")
    on, off = _outputs(tmp_path, device, None), _outputs(tmp_path, device, 0)
    assert on.keys() == off.keys() and len(on) > 40
    for k in on:
        assert on[k].dtype == off[k].dtype and on[k].shape == off[k].shape, k
        a, b = on[k], off[k]
        if k.startswith(("proj_", "stage_")) and "_v_" in k:  # gradients: a NaN's sign and payload may differ between two
            a, b = _nan_canonical(a), _nan_canonical(b)  # builds of PoCL's LLVM (test_project._nan_canonical)
        assert a.tobytes() == b.tobytes(), k

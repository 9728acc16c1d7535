"""Named hard-case scenes for every backend test (STYLE.md §3.7, brush `fuzz.rs`).

Each builder takes no argument and returns a `Case(gaussians, camera, description, expect_visible)`:
`expect_visible` is a bool [N] of which Gaussians the projection must keep (radii > 0), or None
where the case does not pin it (e.g. random scenes). All cameras are pinhole with OpenCV axes.

    CASES            name -> builder
    case(name)       build one
    POISON_VALUES    name -> float32 value, for paired cull / stay-visible tests
    random_scene     seeded random scene of any size
    perf_scene       docs/perf_notes.md §1.7 scenes A/B/C (re-exported from reings.bench_scenes)
    binning(be, mode)   an OpenCL backend's binning mode inside a `with` block (sync / async)
    depth_order(be, mode)   its depth order mode inside a `with` block (share / sort)
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import NamedTuple

import numpy as np

from reings.bench_scenes import perf_camera, perf_scene  # noqa: F401 (re-export)
from reings.types import SH_COUNTS, Camera, Gaussians

FLT_MAX = float(np.finfo(np.float32).max)
FLT_DENORM_MIN = float(np.finfo(np.float32).smallest_subnormal)  # 1.4e-45

# name -> value. Non-finite ones must cull the Gaussian they are put in; finite ones must never
# produce NaN/Inf downstream (and most keep the Gaussian visible, see test_reference_cases.py).
POISON_VALUES = {
    "nan": float("nan"),
    "+inf": float("inf"),
    "-inf": float("-inf"),
    "denorm": FLT_DENORM_MIN,
    "-denorm": -FLT_DENORM_MIN,
    "denorm_large": 1e-39,  # a subnormal float32 with more bits set
    "+flt_max": FLT_MAX,
    "-flt_max": -FLT_MAX,
    "zero": 0.0,
    "-zero": -0.0,
    "near": 0.01,  # the default near plane
    "alpha_min": 1.0 / 255.0,  # ALPHA_MIN
    "tile": 16.0,  # TILE_SIZE as a coordinate
}
NON_FINITE_POISON = ("nan", "+inf", "-inf")


class Case(NamedTuple):
    gaussians: Gaussians
    camera: Camera
    description: str
    expect_visible: np.ndarray | None = None


# ------------------------------------------------------------------------------------------------
# small builders
# ------------------------------------------------------------------------------------------------
def make_camera(width: int, height: int, f: float | None = None, cx: float | None = None,
                cy: float | None = None, viewmat=None) -> Camera:
    """Pinhole camera; default f = max(w, h) (about 53° across the long side), centred principal point."""
    f = float(max(width, height)) if f is None else float(f)
    cx = width / 2.0 if cx is None else float(cx)
    cy = height / 2.0 if cy is None else float(cy)
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]], dtype=np.float64)
    return Camera(K, np.eye(4) if viewmat is None else viewmat, width, height)


def rotation_viewmat(angles=(0.1, -0.2, 0.05), t=(0.1, -0.05, 0.2)) -> np.ndarray:
    """A world->camera matrix with a small rotation (x, y, z Euler angles) and translation."""
    ax, ay, az = angles
    Rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    Ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
    Rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
    V = np.eye(4)
    V[:3, :3] = Rz @ Ry @ Rx
    V[:3, 3] = t
    return V


def make_gaussians(means, quats=None, log_scales=None, opacity_logits=None, sh=None,
                   sh_degree: int = 0, seed: int = 0) -> Gaussians:
    """Gaussians with defaults: identity quats, log-scale ln(0.1), logit 1 (opacity 0.73), random
    positive-ish DC colour."""
    means = np.asarray(means, np.float64).reshape(-1, 3)
    n = len(means)
    rng = np.random.default_rng(seed)
    if quats is None:
        quats = np.tile([1.0, 0, 0, 0], (n, 1))
    if log_scales is None:
        log_scales = np.full((n, 3), np.log(0.1))
    if opacity_logits is None:
        opacity_logits = np.ones(n)
    if sh is None:
        sh = np.zeros((n, SH_COUNTS[sh_degree], 3))
        sh[:, 0, :] = rng.uniform(-0.5, 1.5, (n, 3))
        if sh_degree:
            sh[:, 1:, :] = rng.normal(0, 0.1, (n, SH_COUNTS[sh_degree] - 1, 3))
    return Gaussians(means, np.asarray(quats).reshape(n, 4), np.asarray(log_scales).reshape(n, 3),
                     np.asarray(opacity_logits).reshape(n), sh)


def random_scene(n: int, w: int, h: int, seed: int = 0, sh_degree: int = 0, scale_median: float = 0.05,
                 viewmat=None) -> tuple[Gaussians, Camera]:
    """docs/perf_notes.md §1.7-style random scene at any size: f = max(w, h), z ~ U(2, 8), x/y spread ±1.15 of the
    view (about 15% off-screen), log-scales N(ln scale_median, 0.5), raw (non-unit) quats N(0,1)^4,
    logits N(0.5, 1.5), DC U(-1, 1.5), higher bands N(0, 0.1). Returns (Gaussians, Camera)."""
    cam = make_camera(w, h, viewmat=viewmat)
    rng = np.random.default_rng(seed)
    z = rng.uniform(2.0, 8.0, n)
    x = rng.uniform(-1.15, 1.15, n) * (w / 2 / cam.fx) * z
    y = rng.uniform(-1.15, 1.15, n) * (h / 2 / cam.fy) * z
    cam_pts = np.stack([x, y, z], 1)
    V = cam.viewmat
    means = (cam_pts - V[:3, 3]) @ V[:3, :3]  # camera -> world
    log_scales = rng.normal(np.log(scale_median), 0.5, (n, 3))
    quats = rng.normal(0, 1, (n, 4))
    logits = rng.normal(0.5, 1.5, n)
    k = SH_COUNTS[sh_degree]
    sh = np.zeros((n, k, 3))
    sh[:, 0, :] = rng.uniform(-1.0, 1.5, (n, 3))
    if k > 1:
        sh[:, 1:, :] = rng.normal(0, 0.1, (n, k - 1, 3))
    return Gaussians(means, quats, log_scales, logits, sh), cam


def _random_quats(n, seed):
    return np.random.default_rng(seed).normal(0, 1, (n, 4))


# ------------------------------------------------------------------------------------------------
# the cases
# ------------------------------------------------------------------------------------------------
def _empty():
    return Case(Gaussians.empty(0), make_camera(32, 32), "no Gaussians", np.zeros(0, bool))


def _one():
    g = make_gaussians([[0.0, 0.0, 4.0]], log_scales=np.full((1, 3), np.log(0.3)))
    return Case(g, make_camera(32, 32), "one Gaussian in the middle", np.ones(1, bool))


def _needles():
    n = 6
    rng = np.random.default_rng(1)
    means = np.c_[rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(3, 5, n)]
    ls = np.tile([-9.0, -9.0, 0.0], (n, 1))
    g = make_gaussians(means, _random_quats(n, 2), ls, np.full(n, 2.0), sh_degree=1)
    return Case(g, make_camera(48, 40), "needles: log-scales (-9,-9,0), random rotations", np.ones(n, bool))


def _flat_discs():
    n = 6
    rng = np.random.default_rng(3)
    means = np.c_[rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(3, 5, n)]
    ls = np.tile([-12.0, -0.5, -0.5], (n, 1))
    g = make_gaussians(means, _random_quats(n, 4), ls, np.full(n, 2.0), sh_degree=2)
    return Case(g, make_camera(48, 40), "flat discs: one log-scale -12, random rotations", np.ones(n, bool))


def _larger_than_image():
    g = make_gaussians([[0.0, 0.0, 5.0], [0.3, -0.2, 3.0]], log_scales=np.log([[50.0] * 3, [20, 5, 30]]),
                       opacity_logits=[0.0, -1.0])
    return Case(g, make_camera(40, 30), "Gaussians far larger than the image", np.ones(2, bool))


def _near_plane():
    means = [[0.0, 0.0, 0.01],  # exactly at near (float32 0.01 < float64 0.01): culled
             [0.0, 0.0, -1.0],  # behind the camera
             [0.0, 0.0, 0.0],  # on the camera plane
             [0.1, 0.1, 0.005],  # between camera and near plane
             [0.0, 0.0, 0.0102],  # just in front of near: huge but valid
             [0.0, 0.0, 3.0]]
    g = make_gaussians(means, log_scales=np.full((6, 3), np.log(0.001)))
    return Case(g, make_camera(32, 24), "at / behind / just in front of the near plane (0.01)",
                np.array([False, False, False, False, True, True]))


def _offscreen_clamp():
    # f = 40, W = 40, cx = 20: lim_x_pos = 0.5 + 0.15 = 0.65 -> x/z = 1.0 is clamped
    means = [[4.0, 0.0, 4.0],  # x/z = 1.0, large: clamp active, still covers the image
             [0.0, -3.6, 4.0],  # y/z = -0.9 (lim_y_neg = 0.375+0.1125): clamp on y, large
             [40.0, 0.0, 4.0],  # x/z = 10, small: no tile covered -> culled
             [-3.0, 2.0, 2.0]]  # both axes clamped, large
    ls = np.log([[1.5] * 3, [1.2] * 3, [0.05] * 3, [1.0] * 3])
    g = make_gaussians(means, _random_quats(4, 5), ls, sh_degree=1)
    return Case(g, make_camera(40, 30), "off-screen with the Jacobian clamp active",
                np.array([True, True, False, True]))


def _quat_tiny():
    q = np.array([[0.6e-6, 0.0, 0.8e-6, 0.0],  # norm 1e-6: valid rotation
                  [0.0, 0.0, 0.0, 0.0],  # norm 0: culled
                  [1e-13, 0.0, 0.0, 0.0],  # below QUAT_NORM_MIN = 1e-12: culled
                  [3.0, -1.0, 2.0, 0.5]])  # non-unit, non-axis-aligned
    g = make_gaussians([[0, 0, 4.0], [0.2, 0, 4.0], [-0.2, 0, 4.0], [0, 0.2, 4.0]], q,
                       np.tile(np.log([0.3, 0.1, 0.05]), (4, 1)))
    return Case(g, make_camera(32, 32), "quaternions of norm 1e-6, 0, 1e-13 and non-unit",
                np.array([True, False, False, True]))


def _saturated():
    n = 12
    means = np.c_[np.zeros(n), np.zeros(n), 2.0 + 0.1 * np.arange(n)]
    g = make_gaussians(means, log_scales=np.full((n, 3), np.log(0.5)), opacity_logits=np.full(n, 4.0))
    return Case(g, make_camera(32, 32), "a stack of opaque Gaussians: T < 1e-4 mid-list (early stop)",
                np.ones(n, bool))


def _depth_ties():
    means = [[0.05, 0.0, 4.0], [-0.05, 0.0, 4.0], [0.0, 0.05, 4.0], [0.0, -0.05, 4.0], [0.0, 0.0, 4.0]]
    g = make_gaussians(means, log_scales=np.full((5, 3), np.log(0.4)))
    return Case(g, make_camera(32, 32), "five overlapping Gaussians at exactly the same depth",
                np.ones(5, bool))


def _sized(w, h, n=24, seed=0):
    def build():
        g, cam = random_scene(n, w, h, seed=seed, sh_degree=1, scale_median=0.1)
        return Case(g, cam, f"random scene on a {w}x{h} image", None)
    return build


def _tile_corner():
    cam = make_camera(32, 32, f=32.0, cx=16.0, cy=16.0)
    g = make_gaussians([[0.0, 0.0, 4.0]], log_scales=np.full((1, 3), np.log(0.2)))
    return Case(g, cam, "a Gaussian centred exactly on the corner of four tiles (pixel coord 16,16)",
                np.ones(1, bool))


def _camera_centre():
    V = rotation_viewmat()
    cam = make_camera(32, 32, viewmat=V)
    centre = cam.center
    means = np.stack([centre, centre + V[2, :3] * 4.0])  # at the centre; 4 units ahead
    g = make_gaussians(means, sh_degree=3)
    return Case(g, cam, "a Gaussian exactly at the camera centre (culled by near) and one ahead",
                np.array([False, True]))


def _alpha_clamp():
    g = make_gaussians([[0, 0, 4.0], [0.3, 0, 4.5], [-0.3, 0, 5.0]], log_scales=np.full((3, 3), np.log(0.3)),
                       opacity_logits=[12.0, -12.0, np.log(0.99 / 0.01)])
    return Case(g, make_camera(32, 32), "logits ±12 (α clamp 0.99; below 1/255 everywhere) and exactly 0.99",
                np.ones(3, bool))


def _many_in_one_tile():
    n = 300
    rng = np.random.default_rng(7)
    cam = make_camera(16, 16)
    means = np.c_[rng.uniform(-0.3, 0.3, (n, 2)), rng.uniform(2, 6, n)]
    g = make_gaussians(means, _random_quats(n, 8), rng.normal(np.log(0.05), 0.3, (n, 3)),
                       rng.normal(0, 1, n))
    return Case(g, cam, "300 Gaussians in one 16x16 tile", None)


def _rotated_camera():
    g, cam = random_scene(40, 48, 32, seed=11, sh_degree=3, scale_median=0.1, viewmat=rotation_viewmat())
    return Case(g, cam, "random SH-3 scene seen by a rotated, translated camera", None)


CASES = {
    "empty": _empty,
    "one": _one,
    "needles": _needles,
    "flat_discs": _flat_discs,
    "larger_than_image": _larger_than_image,
    "near_plane": _near_plane,
    "offscreen_clamp": _offscreen_clamp,
    "quat_tiny": _quat_tiny,
    "saturated": _saturated,
    "depth_ties": _depth_ties,
    "size_70x45": _sized(70, 45),
    "size_1x1": _sized(1, 1, n=6),
    "size_15x17": _sized(15, 17),
    "size_17x15": _sized(17, 15),
    "size_16x16": _sized(16, 16),
    "tile_corner": _tile_corner,
    "camera_centre": _camera_centre,
    "alpha_clamp": _alpha_clamp,
    "many_in_one_tile": _many_in_one_tile,
    "rotated_camera": _rotated_camera,
}


def case(name: str) -> Case:
    return CASES[name]()


def all_cases() -> list[tuple[str, Case]]:
    return [(k, f()) for k, f in CASES.items()]


def gaussians_before(cam: Camera, rng: np.random.Generator, n: int, opacity=(0.0, 2.0)) -> Gaussians:
    """n isotropic SH-0 Gaussians 3-4 units in front of `cam`, spread over its view (the depth terms'
    through-the-render finite-difference tests); opacity logits uniform in `opacity`. Draws from
    `rng` in a fixed order (depths, x, y, opacities, colours)."""
    pts = cam.center + cam.viewmat[2, :3] * rng.uniform(3, 4, (n, 1)) + cam.viewmat[0, :3] * rng.uniform(-1, 1, (n, 1)) \
        + cam.viewmat[1, :3] * rng.uniform(-0.8, 0.8, (n, 1))
    return Gaussians(pts.astype(np.float32), np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
                     np.full((n, 3), np.log(0.4), np.float32), rng.uniform(*opacity, n).astype(np.float32),
                     rng.normal(0, 0.5, (n, 1, 3)).astype(np.float32))


def dngaussian_fit_case(n_views: int, width: int, height: int, n_points: int, sh_degree: int, iterations: int,
                        soft_depth_from: int, densify_until: int):
    """(procedural scene, random init, DNGaussian config squeezed to `iterations`) for the engine tests:
    a small procedural scene with exact depths, `n_points` random Gaussians in a fixed box."""
    from dataclasses import replace

    import reings
    from reings.config import preset
    from reings.train import gaussians_from_points, random_points_in_box, with_iterations

    scene = reings.make_procedural_scene(n_views=n_views, width=width, height=height, supersample=1)
    rng = np.random.default_rng(0)
    init = gaussians_from_points(random_points_in_box([-2, 0, 0], [2, 2, 5], n_points, rng), None, sh_degree, rng)
    cfg = with_iterations(preset("dngaussian"), iterations)
    cfg = replace(cfg, sh_degree=sh_degree, loss=replace(cfg.loss, soft_depth_from=soft_depth_from),
                  densify=replace(cfg.densify, densify_until=densify_until))
    return scene, init, cfg


def assert_engines_agree(device: str, host_state, dev_state, what: str = "") -> None:
    """The device engine's parameters against the host engine's: bit-identical on PoCL (both run
    the same kernels in the same order, tests/test_device_fit.py), else within float32 rounding
    carried by the iterations (2e-5 + 1e-5 |x|)."""
    from reings.backends import get_backend
    from reings.backends.opencl import quirks

    exact = quirks.is_pocl(get_backend(device).handle.device)
    for k in host_state.params:
        if exact:
            np.testing.assert_array_equal(dev_state.params[k], host_state.params[k], err_msg=f"{what} {k}")
        else:
            np.testing.assert_allclose(dev_state.params[k], host_state.params[k], rtol=1e-5, atol=2e-5,
                                       err_msg=f"{what} {k}")


def fit_case(case, device: str, **kw):
    """`train.fit` of a (scene, init, config) case with the scene's exact depths as the targets,
    logging every 5 iterations (the engine tests' fit)."""
    from reings.train import fit

    scene, init, cfg = case
    return fit(scene, cfg, device=device, init=init, depth_targets=list(scene.depths), progress=False,
               log_every=5, **kw)


def assert_same_state(a, b, exact: bool, what: str, rtol: float = 1e-5, atol: float = 2e-5) -> None:
    """Two TrainStates: sizes, step counts, parameters and both Adam moments, and (exact) the
    densification statistics: bit for bit when `exact`, else within rtol / atol."""
    assert len(a) == len(b) and a.adam.step == b.adam.step and a.iteration == b.iteration, what
    for k in a.params:
        for x, y, n in ((a.params[k], b.params[k], "param"), (a.adam.exp_avg[k], b.adam.exp_avg[k], "exp_avg"),
                        (a.adam.exp_avg_sq[k], b.adam.exp_avg_sq[k], "exp_avg_sq")):
            if exact:
                np.testing.assert_array_equal(x, y, err_msg=f"{what} {n}/{k}")
            else:
                np.testing.assert_allclose(x, y, rtol=rtol, atol=atol, err_msg=f"{what} {n}/{k}")
    for k in a.stats:
        if exact:
            np.testing.assert_array_equal(a.stats[k], b.stats[k], err_msg=f"{what} stat/{k}")


def interrupt_and_resume(run, path: str, stop_at: int, every: int = 5):
    """run(**kw) -> FitResult is a `fit` call; run it with checkpoints every `every` iterations,
    interrupted by an exception at the eval of iteration `stop_at`, then again from the
    checkpoint: returns the resumed FitResult."""
    import os

    import pytest

    class Stop(Exception):
        pass

    def crash(g):
        raise Stop

    with pytest.raises(Stop):
        run(checkpoint=path, checkpoint_every=every, eval_fn=crash, eval_every=stop_at)
    assert os.path.exists(path)
    return run(checkpoint=path, checkpoint_every=every)


def assert_resumes_bit_identically(case, device: str, tmp_path, stop_at: int):
    """`fit_case` on the device engine, interrupted at the eval of iteration `stop_at` and resumed
    from its last checkpoint, against the uninterrupted fit: the state (moments and statistics
    included), the loss history and the densification records, bit for bit. Returns (reference,
    resumed) for the caller's own histories."""
    import os

    ref = fit_case(case, device, engine="device")
    res = interrupt_and_resume(lambda **kw: fit_case(case, device, engine="device", **kw),
                               os.path.join(tmp_path, "ck.npz"), stop_at=stop_at)
    assert_same_state(ref.state, res.state, True, "resumed vs uninterrupted")
    np.testing.assert_array_equal(res.history.loss, ref.history.loss)
    assert [tuple(x) for x in res.history.densify] == [tuple(x) for x in ref.history.densify]
    return ref, res


def assert_fd_along_random_directions(loss, g, grads, fields, rng, trials: int = 3, eps: float = 1e-4) -> None:
    """Central differences of `loss` (Gaussians -> float) at `g` along `trials` random unit
    directions (drawn from `rng`) of each field, against the analytic gradient `grads[field]`
    projected on them: |fd - an| <= tol |an| + 1e-6 for each (field, tol) of `fields`, in order."""
    from dataclasses import replace

    for field, tol in fields:
        x0 = np.asarray(getattr(g, field), np.float64)
        for _ in range(trials):
            v = rng.normal(size=x0.shape)
            v /= np.linalg.norm(v)
            ends = [loss(replace(g, **{field: x0 + s * eps * v})) for s in (1, -1)]
            fd = (ends[0] - ends[1]) / (2 * eps)
            an = float(np.sum(np.asarray(grads[field], np.float64) * v))
            assert abs(fd - an) <= tol * abs(an) + 1e-6, (field, fd, an)


@contextmanager
def _backend_mode(be, attr: str, mode: str, counter: str):
    """`be.<attr>` = `mode` inside the block; yields the change of the counts `be.<counter>` in it."""
    old, before = getattr(be, attr), dict(getattr(be, counter))
    setattr(be, attr, mode)
    done: dict = {}
    try:
        yield done
    finally:
        setattr(be, attr, old)
        done.update({k: getattr(be, counter)[k] - before[k] for k in before})


def binning(be, mode: str):
    """OpenCLBackend `be` binning in `mode` ("sync", "async" or "auto": OpenCLBackend.bin_mode,
    docs/perf_notes.md §8) inside the block; yields the counts of forwards binned per mode in it."""
    return _backend_mode(be, "bin_mode", mode, "binned")


def depth_order(be, mode: str):
    """OpenCLBackend `be` with its depth order mode `mode` ("share" or "sort": OpenCLBackend.depth_order,
    docs/perf_notes.md §9) inside the block; yields the forwards that sorted / shared an order in it."""
    return _backend_mode(be, "depth_order", mode, "depth_sorts")


def device_depth_frame(trainer, cam: Camera, depth, alpha):
    """A stand-in for a device trainer's rendered frame of `cam`: its depth and alpha maps ([H, W])
    uploaded as the frame's "out_depth" / "out_alpha" buffers (what cross_warp and hold_depth read)."""
    import types

    import pyopencl as cl

    mf = cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR
    ctx = trainer.handle.context
    return types.SimpleNamespace(width=cam.width, height=cam.height, camera=cam,
                                 bufs={k: cl.Buffer(ctx, mf, hostbuf=np.ascontiguousarray(x, np.float32))
                                       for k, x in (("out_depth", depth), ("out_alpha", alpha))})


def load_bench(name: str, as_name: str | None = None):
    """The module bench/<name>.py (a script, not a package) loaded for a test."""
    import importlib.util
    import os

    path = os.path.join(os.path.dirname(__file__), "..", "bench", f"{name}.py")
    spec = importlib.util.spec_from_file_location(as_name or f"{name}_under_test", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def run_tool(main, argv) -> int:
    """A bench tool's `main(argv)` that runs a `reings` command in this process, with the logging the CLI
    configures for its process undone after (and its warnings kept out of the test's)."""
    import logging
    import warnings

    log = logging.getLogger("reings")
    handlers, level = list(log.handlers), log.level
    try:
        with warnings.catch_warnings():
            return main(argv)
    finally:
        log.handlers[:] = handlers
        log.setLevel(level)


def densify_state(means):
    """A TrainState of small opaque Gaussians at `means` (SH degree 0) with zeroed densification statistics:
    the geometric prunes' cases (tests/test_fit_lead.py, tests/test_near_prune.py)."""
    from reings.densify import init_stats
    from reings.state import TrainState

    n = len(means)
    g = Gaussians(np.asarray(means, np.float32), np.tile([1, 0, 0, 0], (n, 1)).astype(np.float32),
                  np.full((n, 3), -3, np.float32), np.full(n, 2, np.float32), np.zeros((n, 1, 3), np.float32))
    st = TrainState.from_gaussians(g, 0)
    init_stats(st)
    return st


def prune_on_both_engines(scene, init, cfg, device, key: str):
    """A fit of `cfg` on the host and the device engines: both must drop the same counts under densification
    history `key` at every step, some in all, and end with the same count. Returns the device engine's result."""
    from reings.train import fit

    runs = {e: fit(scene, cfg, device=device, init=init, depth_targets=list(scene.depths), progress=False,
                   log_every=5, engine=e) for e in ("host", "device")}
    h, d = runs["host"].history, runs["device"].history
    assert [n[key] for _, n in h.densify] == [n[key] for _, n in d.densify]
    assert sum(n[key] for _, n in d.densify) > 0
    assert h.n_gaussians == d.n_gaussians
    return runs["device"]

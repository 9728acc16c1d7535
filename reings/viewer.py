"""`reings view RUN_DIR|file.ply`: an interactive viewer in the browser (optional extra `view`).

The Gaussians are drawn by viser's Gaussian-splat scene (viser, a numpy-only Python package with
a prebuilt web client: `pip install 'reings[view]'`), with the run's training cameras as frustums
and the browser's first view at the first training camera. The splats carry each Gaussian's
centre, covariance R·diag(s²)·Rᵀ, opacity and its degree-0 colour (0.5 + C0·SH_dc: viser draws
view-independent colour; higher SH bands are not shown).
"""
from __future__ import annotations

import os

import numpy as np

from .types import Camera, Gaussians

SH_C0 = 0.28209479177387814  # the degree-0 SH basis constant (3DGS)


def splat_arrays(g: Gaussians):
    """(centres [N,3], covariances [N,3,3], rgb [N,3] in [0,1], opacity [N,1]) as float32."""
    q = g.quats.astype(np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    w, x, y, z = q.T
    R = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                  2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                  2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1).reshape(-1, 3, 3)
    s2 = np.exp(2.0 * g.log_scales.astype(np.float64))
    cov = np.einsum("nij,nj,nkj->nik", R, s2, R)
    rgb = np.clip(0.5 + SH_C0 * g.sh[:, 0, :].astype(np.float64), 0.0, 1.0)
    op = 1.0 / (1.0 + np.exp(-g.opacity_logits.astype(np.float64)))
    keep = np.all(np.isfinite(g.means), axis=1) & np.all(np.isfinite(cov.reshape(-1, 9)), axis=1)
    f32 = lambda a: np.ascontiguousarray(a[keep], dtype=np.float32)  # noqa: E731
    return f32(g.means), f32(cov), f32(rgb), f32(op[:, None])


def _wxyz(R) -> np.ndarray:
    from .paths import _quat

    return _quat(R)


def load_model(path):
    """(Gaussians, training cameras or []) of a run folder or a .ply file."""
    from .io.ply import read_ply

    path = os.fspath(path)
    if os.path.isdir(path):
        from .video import load_run

        g, recs = load_run(path)
        return g, [r.camera for r in recs]
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no run folder or .ply file there")
    return read_ply(path), []


def serve(model, host: str = "127.0.0.1", port: int = 8080, cameras=None, verbose: bool = False):
    """Start the viewer of `model` (a run folder, a .ply, or `Gaussians` with `cameras`); returns
    the running `viser.ViserServer` (its `.stop()` ends it)."""
    try:
        import viser
    except ImportError as e:
        raise ImportError("the viewer needs viser: pip install 'reings[view]'") from e
    if isinstance(model, Gaussians):
        g, cams = model, list(cameras or [])
    else:
        g, cams = load_model(model)
    if len(g) == 0:
        raise ValueError("the model has no Gaussians to show")
    server = viser.ViserServer(host=host, port=int(port), verbose=verbose)
    centres, cov, rgb, op = splat_arrays(g)
    server.scene.add_gaussian_splats("/model", centers=centres, covariances=cov, rgbs=rgb, opacities=op)
    for i, cam in enumerate(cams):
        _add_frustum(server, f"/cameras/{i:03d}", cam, scale=0.05 * _scene_size(centres))
    if cams:
        _first_view(server, cams[0], centres)
    return server


def _scene_size(centres) -> float:
    lo, hi = np.percentile(centres, [5, 95], axis=0)
    return float(np.linalg.norm(hi - lo)) or 1.0


def _add_frustum(server, name: str, cam: Camera, scale: float) -> None:
    R = cam.viewmat[:3, :3].T  # camera-to-world; viser's frustums use OpenCV axes, as reings does
    fov = 2.0 * np.arctan(cam.height / (2.0 * cam.fy))
    server.scene.add_camera_frustum(name, fov=float(fov), aspect=cam.width / cam.height, scale=scale,
                                    wxyz=_wxyz(R), position=tuple(cam.center), color=(255, 140, 0))


def _first_view(server, cam: Camera, centres) -> None:
    up = -cam.viewmat[1, :3]
    fwd = cam.viewmat[2, :3]
    depth = float(np.median((centres - cam.center) @ fwd)) if len(centres) else 1.0
    server.scene.set_up_direction(tuple(float(v) for v in up))
    ic = server.initial_camera
    ic.position = tuple(float(v) for v in cam.center)
    ic.look_at = tuple(float(v) for v in cam.center + max(depth, 1e-3) * fwd)
    ic.up = tuple(float(v) for v in up)
    ic.fov = float(2.0 * np.arctan(cam.height / (2.0 * cam.fy)))


def main_view(args) -> int:
    import time

    server = serve(args.model, host=args.host, port=args.port)
    print(f"viewing {args.model} at http://{args.host}:{server.get_port()} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        server.stop()
    return 0

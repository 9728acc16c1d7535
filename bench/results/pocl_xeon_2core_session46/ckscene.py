"""The scene of a reings checkpoint for this folder's A/B scripts: the repository and bench/ on sys.path, then
`load(CK/STAGE.npz)` -> (Gaussians, Camera, reference Projected, reference Bins) seen from the run's first camera
(bench/bench_rasterize.py's --checkpoint scene)."""
import os
import sys
from types import SimpleNamespace

_R = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
sys.path.insert(0, _R)
sys.path.insert(0, os.path.join(_R, "bench"))


def load(checkpoint: str):
    import bench_rasterize as B
    from reings.backends import reference as ref

    g, cam = B._scene(SimpleNamespace(checkpoint=checkpoint, cameras=None, view=0, opacity=None, n=None, scene="A"))
    proj = ref.project_fwd(g, cam)
    return g, cam, proj, ref.bin(proj, cam.width, cam.height)

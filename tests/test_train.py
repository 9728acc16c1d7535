"""The training engine's inputs from the backends: the screen-space gradient side channel that
densification reads (`backend.last_screen`), checked against the float64 reference."""
import numpy as np

from reings.backends import get_backend
from reings.rendering import render_vjp

from asserts import assert_grad_close
from cases import random_scene


def test_last_screen_matches_reference(device):
    g, cam = random_scene(400, 70, 45, seed=3)
    v_rgb = np.random.default_rng(1).normal(size=(45, 70, 3)).astype(np.float32)
    render_vjp(g, cam, v_rgb, device="reference")
    ref_v2d, ref_radii = get_backend("reference").last_screen
    render_vjp(g, cam, v_rgb, device=device)
    v2d, radii = get_backend(device).last_screen
    np.testing.assert_array_equal(radii > 0, ref_radii > 0)
    assert not np.any(v2d[radii == 0]), "culled Gaussians must carry no screen gradient"
    assert_grad_close(v2d, ref_v2d, "v_means2d")


def test_last_screen_only_after_full_vjp(device):
    """A depth-only pass (grad_fields restricted) must not leave stale statistics behind."""
    g, cam = random_scene(50, 32, 32, seed=4)
    render_vjp(g, cam, np.ones((32, 32, 3), np.float32), device=device)
    assert get_backend(device).last_screen is not None
    render_vjp(g, cam, np.zeros((32, 32, 3), np.float32), v_depth=np.ones((32, 32), np.float32),
               device=device, grad_fields=("means",))
    assert get_backend(device).last_screen is None


def test_trainers_implement_the_contract():
    """Every operation of the Trainer contract (reings/backends/base.py) exists in both trainers
    with the contract's parameters, and each backend makes the trainers its `engines` name."""
    import inspect

    import pytest

    from reings.backends.base import Trainer
    from reings.backends.host_trainer import HostTrainer
    from reings.backends.opencl.trainer import DeviceTrainer

    ops = [n for n, f in vars(Trainer).items() if callable(f) and not n.startswith("_")]
    assert {"forward", "photometric", "depth_loss", "backward", "regularize", "accumulate", "adam_step"} <= set(ops)

    def params(f):
        return [{"fr": "frame"}.get(p, p) for p in inspect.signature(f).parameters]

    for cls in (HostTrainer, DeviceTrainer):
        for n in ops:
            assert params(getattr(cls, n)) == params(getattr(Trainer, n)), f"{cls.__name__}.{n}"
    ref = get_backend("reference")
    assert ref.engines == ("host",) and isinstance(ref.trainer([]), HostTrainer)
    with pytest.raises(ValueError, match="OpenCL"):
        ref.trainer([], engine="device")

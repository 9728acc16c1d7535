"""`--extent frusta`: the training-frusta box asked for directly, identical to the fallback box."""
import numpy as np
import pytest

import reings
from reings.data.sfm import frusta_extent, frusta_only_extent


def test_frusta_only_extent_is_the_fallback_box():
    scene = reings.make_procedural_scene()
    tr, _ = reings.few_shot_split(scene, 3)
    train = scene.subset(tr)
    ext = frusta_only_extent(train)
    lo, hi, _ = frusta_extent(train.cameras, train.bounds)
    assert ext.method == "frusta" and ext.note == "requested"
    np.testing.assert_array_equal(ext.lo, lo)
    np.testing.assert_array_equal(ext.hi, hi)
    assert np.all(ext.hi > ext.lo)


def test_run_records_the_extent_choice(device):
    r = reings.run(method="dngaussian", iterations=3, device=device, depth_prior="none", extent="frusta",
                   with_lpips=False, eval_every=0, quiet=True)
    assert r.metrics["sfm"]["method"] == "frusta"
    assert r.metrics["config"]["extent"] == "frusta"
    with pytest.raises(ValueError, match="extent"):
        reings.run(method="dngaussian", iterations=3, device=device, extent="box", quiet=True)

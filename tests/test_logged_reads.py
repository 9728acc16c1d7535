"""The training loop's reads (train._Iteration.logged): with DropGaussian, the view_warp, metric
depth and cross_warp terms and the three penalties on (host engine, a few iterations, logging every
2), each term is read from the trainer exactly once per logging iteration and never on the others,
the image and the parameters are never read by the loop, and each logged loss is the sum of the
values the trainer returned for that iteration (photometric + view_warp + metric depth + cross_warp
+ penalties, in the loop's order) and each logged train PSNR that of the read error."""
from __future__ import annotations

from collections import defaultdict
from dataclasses import replace

import numpy as np

from cases import dngaussian_fit_case

READS = ("read_loss", "read_mse", "read_view_warp", "read_depth_metric", "read_cross_warp", "read_regularize",
         "read_rgb", "read_params")
TERMS = ("read_loss", "read_view_warp", "read_depth_metric", "read_cross_warp", "read_regularize")  # the sum's order


def test_logged_reads_and_loss_sum(device, monkeypatch):
    from reings import train
    from reings.backends.host_trainer import HostTrainer

    scene, init, cfg = dngaussian_fit_case(n_views=3, width=40, height=30, n_points=150, sh_degree=1, iterations=9,
                                           soft_depth_from=3, densify_until=25)
    cfg = replace(cfg, loss=replace(cfg.loss, drop_gamma=0.2, view_warp_weight=1.0, view_warp_from=1,
                                    view_warp_baseline=0.3, cross_warp=0.5, cross_warp_from=1, depth_metric=0.3,
                                    shape_pena=0.01, scale_pena=0.01, opa_pena=0.01))
    now = {"it": None}
    calls = defaultdict(list)  # iteration -> [(read, value)]
    step = train._Iteration.__call__

    def iteration(self, it):
        now["it"] = it
        return step(self, it)

    monkeypatch.setattr(train._Iteration, "__call__", iteration)
    for name in READS:
        orig = getattr(HostTrainer, name)

        def wrapped(self, *a, _orig=orig, _name=name, **k):
            v = _orig(self, *a, **k)
            calls[now["it"]].append((_name, v))
            return v

        monkeypatch.setattr(HostTrainer, name, wrapped)
    res = train.fit(scene, cfg, device=device, init=init, depth_targets=list(scene.depths), progress=False,
                    log_every=2, engine="host")
    logging = [2, 4, 6, 8, 9]
    assert res.history.iteration == logging
    assert sorted(calls) == logging  # no read on any other iteration (nor outside the loop)
    for i, it in enumerate(logging):
        got = calls[it]
        names = [n for n, _ in got]
        assert sorted(names) == sorted(READS[:6]), (it, names)  # each term once; never read_rgb / read_params
        vals = dict(got)
        total = 0.0
        for n in TERMS:
            v = vals[n]
            total += v["loss"] if isinstance(v, dict) else v
        assert res.history.loss[i] == total
        assert res.history.train_psnr[i] == train._psnr(vals["read_mse"])
        assert all(np.isfinite(v["loss"] if isinstance(v, dict) else v) for _, v in got)
        assert vals["read_regularize"] > 0 and vals["read_cross_warp"]["loss"] > 0
    assert [it for it, *_ in res.history.cross_warp] == logging
    assert [it for it, *_ in res.history.view_warp] == logging
    assert [it for it, *_ in res.history.depth_metric] == logging

"""`reings run --preset quick` on the procedural scene: ReInGS should beat DNGaussian.

Measured (PoCL, 2 shared cores, this commit): reings PSNR 14.90 in 55 s of training (65 s wall),
dngaussian PSNR 18.04 in 33 s (40 s wall). The PSNR-vs-seconds series shows the coarse stage at
19.3 dB after 200 iterations, then the IVPS re-initialisation dropping it to 13.7 dB and the fine
and final stages ending at 14.5 / 14.9 dB. Until the schedules are fixed this is an expected
failure (strict=False: it reports XPASS once ReInGS wins); it is not tuned to pass.
"""
from __future__ import annotations

import json

import pytest

from reings.cli import main


@pytest.mark.slow
@pytest.mark.xfail(raises=AssertionError, strict=False,
                   reason="quick preset: reings 14.90 dB < dngaussian 18.04 dB on the procedural scene (IVPS drop)")
def test_quick_reings_beats_quick_dngaussian(tmp_path, capsys):
    psnr = {}
    for method in ("dngaussian", "reings"):
        out = tmp_path / method
        rc = main(["run", "--device", "pocl", "--preset", "quick", "--method", method, "--out", str(out), "--quiet"])
        if rc != 0:  # not an AssertionError: a broken run must fail, not xfail
            pytest.fail(f"reings run --method {method} exited {rc}")
        m = json.loads((out / "metrics.json").read_text())
        psnr[method] = m["mean"]["psnr"]
    print(psnr)
    assert psnr["reings"] > psnr["dngaussian"], psnr

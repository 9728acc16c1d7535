"""Side-by-side peer: gsplat 1.5.3 (CUDA + PyTorch) on the same scene arrays as `reings bench`.

Runs only where torch with CUDA and gsplat are importable (the GPU machine); otherwise prints a
line saying so and exits 0. Never imported by the `reings` package.

    python bench/peer_gsplat.py --scenes A,B,C --sh 0,3 [--json OUT.jsonl]

Per scene: forward, forward+backward (L1 against a fixed random target) and a full training step
with torch fused Adam; median of 40 CUDA-event timings after 8 warm-ups, plus wall clock with a
synchronize. Also saves gsplat's image for scene A (sh0) as .npy for image comparison when --save.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time


def _time_cuda(torch, fn, warmup=8, repeats=40):
    for _ in range(warmup):
        fn()
    torch.cuda.synchronize()
    ev, wall = [], []
    for _ in range(repeats):
        s, e = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        t0 = time.perf_counter()
        s.record()
        fn()
        e.record()
        torch.cuda.synchronize()
        wall.append((time.perf_counter() - t0) * 1e3)
        ev.append(s.elapsed_time(e))
    return statistics.median(ev), statistics.median(wall)


def run(scenes=("A", "B", "C"), shs=(0, 3), save=None):
    try:
        import torch
        from gsplat import rasterization
    except Exception as e:  # pragma: no cover - depends on the machine
        print(f"peer_gsplat: gsplat/torch not available ({type(e).__name__}: {e}); skipped")
        return []
    if not torch.cuda.is_available():
        print("peer_gsplat: no CUDA device; skipped")
        return []
    import numpy as np

    from reings.bench_scenes import perf_scene

    dev = torch.device("cuda")
    rows = []
    for name in scenes:
        for sh in shs:
            g, cam = perf_scene(name, sh_degree=sh)
            W, H = cam.width, cam.height
            t = lambda a: torch.tensor(np.asarray(a), device=dev, dtype=torch.float32)
            params = {
                "means": t(g.means).requires_grad_(), "quats": t(g.quats).requires_grad_(),
                "log_scales": t(g.log_scales).requires_grad_(), "logits": t(g.opacity_logits).requires_grad_(),
                "sh": t(g.sh).requires_grad_(),
            }
            view = t(cam.viewmat)[None]
            Ks = t(cam.K)[None]
            target = torch.rand(H, W, 3, device=dev, generator=torch.Generator(device=dev).manual_seed(0))

            def forward():
                colors = params["sh"]
                img, alpha, meta = rasterization(
                    params["means"], params["quats"], torch.exp(params["log_scales"]), torch.sigmoid(params["logits"]),
                    colors, view, Ks, W, H, near_plane=0.01, sh_degree=sh, packed=False)
                return img[0], meta

            def fwd():
                with torch.no_grad():
                    forward()

            def fwdbwd():
                img, _ = forward()
                loss = (img - target).abs().mean()
                loss.backward()
                for p in params.values():
                    p.grad = None

            opt = torch.optim.Adam(list(params.values()), lr=1e-3, eps=1e-15, fused=True)

            def step():
                img, _ = forward()
                loss = (img - target).abs().mean()
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()

            r = {"peer": "gsplat", "scene": name, "sh": sh, "N": len(g), "device": torch.cuda.get_device_name()}
            r["fwd_ms"], r["fwd_wall_ms"] = _time_cuda(torch, fwd)
            r["fwdbwd_ms"], r["fwdbwd_wall_ms"] = _time_cuda(torch, fwdbwd)
            snapshot = {k: v.detach().clone() for k, v in params.items()}
            r["step_ms"], r["step_wall_ms"] = _time_cuda(torch, step)
            with torch.no_grad():
                for k, v in params.items():
                    v.copy_(snapshot[k])
                img, meta = forward()
                r["visible"] = int((meta["radii"] > 0).any(-1).sum().item()) if meta["radii"].dim() == 3 else int((meta["radii"] > 0).sum().item())
                r["intersections"] = int(meta["isect_ids"].numel()) if "isect_ids" in meta else None
            r["peak_mem_mb"] = torch.cuda.max_memory_allocated() / 2**20
            if save and name == "A" and sh == 0:
                np.save(save, img.detach().cpu().numpy())
            rows.append(r)
            print(json.dumps(r), flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="A,B,C")
    ap.add_argument("--sh", default="0,3")
    ap.add_argument("--json", default=None)
    ap.add_argument("--save", default=None, help="save scene A sh0 image (.npy)")
    a = ap.parse_args(argv)
    rows = run(a.scenes.split(","), [int(s) for s in a.sh.split(",")], a.save)
    if a.json:
        with open(a.json, "a") as f:
            for r in rows:
                f.write(json.dumps(r) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Sort benchmark: reings' radix sort vs numpy.argsort(kind="stable") vs pyopencl.algorithm.RadixSort,
same keys, same run (issue 2 §6; docs/perf_notes.md §4.2 / §7).

    python bench/bench_sort.py --device pocl [--n 1048576] [--repeats 7] [--json-only]

Cases (n = 1M by default):
    isect42   1M (tile << 32 | depth) uint64 keys, tile in [0, 768), depth = float32 bits of U(2, 8),
              sorted on 42 bits (32 depth + ceil(log2 768) = 10 tile bits)
    isect43   the same keys on 43 bits (gsplat's key width)
    2stage    Brush's scheme: a 32-bit depth sort of 100k visible Gaussians, then a stable 10-bit
              tile-id sort of the 1M intersections (the time is the sum of both)
Each implementation sorts (key, uint32 index) pairs; the time is the median wall time of `repeats`
runs after one warm-up, device work included (queue.finish), host<->device transfers excluded
(every implementation gets its input already on the device, numpy in host memory). numpy's time
is argsort alone (it returns the permutation, the payload gather is not counted).
Output: a table, then one JSON line per measurement (device, driver, case, n, bits, impl, ms).
`run(device, n, repeats)` returns the same rows for `reings bench`.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import numpy as np


def _median_ms(fn, repeats: int, setup=None) -> float:
    ts = []
    for i in range(repeats + 1):
        if setup is not None:
            setup()
        t0 = time.perf_counter()
        fn()
        t = (time.perf_counter() - t0) * 1e3
        if i:  # the first run is a warm-up (builds, caches)
            ts.append(t)
    return statistics.median(ts)


def make_keys(n: int, seed: int = 0, tiles: int = 768):
    rng = np.random.default_rng(seed)
    tile = rng.integers(0, tiles, n, dtype=np.uint64)
    depth = rng.uniform(2, 8, n).astype(np.float32).view(np.uint32)
    return tile, depth


def run(device: str = "pocl", n: int = 1 << 20, repeats: int = 7, with_pyopencl: bool = True) -> list[dict]:
    import pyopencl as cl

    from reings.backends.opencl.device import open_device
    from reings.backends.opencl.sort import RadixSort

    h = open_device(device, profiling=True)  # kernel times from events
    q, ctx = h.queue, h.context
    mf = cl.mem_flags
    ours = RadixSort.for_handle(h)
    base = {"device": h.device.name.strip(), "platform": h.platform.name.strip(),
            "driver": h.device.driver_version.strip(), "compute_units": int(h.device.max_compute_units),
            "schedule": "cpu" if ours.cpu else "gpu", "max_digit_bits": ours.max_bits}
    rows: list[dict] = []

    pyo = None
    if with_pyopencl:
        try:
            from pyopencl.algorithm import RadixSort as PyoRadixSort

            pyo = {}
            for kt, ctype in ((np.uint64, "ulong"), (np.uint32, "uint")):
                pyo[kt] = PyoRadixSort(ctx, f"{ctype} *keys, uint *vals", key_expr="keys[i]",
                                       sort_arg_names=["keys", "vals"], key_dtype=kt)
        except Exception as e:  # mako missing, or a build failure
            print(f"# pyopencl.algorithm.RadixSort unavailable: {type(e).__name__}: {e}", file=sys.stderr)
            pyo = None

    def time_ours(keys: np.ndarray, bits: int) -> float:
        key64 = keys.dtype == np.uint64
        nn = keys.size
        src_k = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=keys)
        src_v = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.arange(nn, dtype=np.uint32))
        kb = cl.Buffer(ctx, mf.READ_WRITE, keys.nbytes)
        vb = cl.Buffer(ctx, mf.READ_WRITE, 4 * nn)

        def setup():  # the sort clobbers its input: restore it, outside the timed region
            cl.enqueue_copy(q, kb, src_k)
            cl.enqueue_copy(q, vb, src_v)
            q.finish()

        def go():
            ours.sort_pairs(kb, vb, nn, 0, bits, key64=key64)
            q.finish()

        return _median_ms(go, repeats, setup)

    def time_pyo(keys: np.ndarray, bits: int) -> float | None:
        if pyo is None:
            return None
        import pyopencl.array as cla

        kd = cla.to_device(q, keys)
        vd = cla.to_device(q, np.arange(keys.size, dtype=np.uint32))
        sorter = pyo[keys.dtype.type]

        def go():
            (_k, _v), ev = sorter(kd, vd, key_bits=bits, queue=q)
            ev.wait()
            q.finish()

        return _median_ms(go, max(1, min(repeats, 5)), None)

    def time_numpy(keys: np.ndarray) -> float:
        return _median_ms(lambda: np.argsort(keys, kind="stable"), repeats)

    tile, depth = make_keys(n)
    isect = (tile << np.uint64(32)) | depth.astype(np.uint64)
    for case, bits in (("isect42", 42), ("isect43", 43)):
        r = {"case": case, "n": n, "bits": bits}
        t_np = time_numpy(isect)
        rows.append({**base, **r, "impl": "numpy.argsort(stable)", "ms": t_np})
        t = time_ours(isect, bits)
        rows.append({**base, **r, "impl": "reings", "ms": t, "speedup_vs_numpy": t_np / t})
        tp = time_pyo(isect, bits)
        if tp is not None:
            rows.append({**base, **r, "impl": "pyopencl.RadixSort", "ms": tp, "speedup_vs_numpy": t_np / tp})

    # 2-stage: depth sort of the visible Gaussians, then a stable 10-bit tile sort of the intersections
    nv = max(1, n // 10)
    vis_depth = make_keys(nv, seed=1)[1]
    tile32 = tile.astype(np.uint32)
    r = {"case": "2stage", "n": n, "bits": "32@n/10+10"}
    t_np = time_numpy(vis_depth) + time_numpy(tile32)
    rows.append({**base, **r, "impl": "numpy.argsort(stable)", "ms": t_np})
    t = time_ours(vis_depth, 32) + time_ours(tile32, 10)
    rows.append({**base, **r, "impl": "reings", "ms": t, "speedup_vs_numpy": t_np / t})
    if pyo is not None:
        tp = time_pyo(vis_depth, 32) + time_pyo(tile32, 10)
        rows.append({**base, **r, "impl": "pyopencl.RadixSort", "ms": tp, "speedup_vs_numpy": t_np / tp})
    return rows


def print_table(rows: list[dict]) -> None:
    if not rows:
        return
    r0 = rows[0]
    print(f"# {r0['device']} [{r0['platform']}], driver {r0['driver']}, {r0['compute_units']} CUs, "
          f"schedule={r0['schedule']}, digits <= {r0['max_digit_bits']} bits")
    print(f"{'case':9s} {'n':>9s} {'bits':>11s} {'impl':24s} {'ms':>9s} {'x numpy':>8s}")
    for r in rows:
        sp = f"{r['speedup_vs_numpy']:.2f}" if "speedup_vs_numpy" in r else ""
        print(f"{r['case']:9s} {r['n']:9d} {str(r['bits']):>11s} {r['impl']:24s} {r['ms']:9.2f} {sp:>8s}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="pocl")
    ap.add_argument("--n", type=int, default=1 << 20)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--no-pyopencl", action="store_true", help="skip pyopencl.algorithm.RadixSort")
    ap.add_argument("--json-only", action="store_true")
    a = ap.parse_args(argv)
    rows = run(a.device, n=a.n, repeats=a.repeats, with_pyopencl=not a.no_pyopencl)
    if not a.json_only:
        print_table(rows)
    for r in rows:
        print(json.dumps(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())

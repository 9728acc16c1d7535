"""Sort geometry sweep (issue 15, docs/perf_notes.md §10): RadixSort.sort_pairs over elements per
work-item, work-group size and digit width, on the depth sort's and the tile sort's sizes.

    python bench/bench_sort_geometry.py --device cuda:0 [--repeats 50] [--out sweep.jsonl]
    python bench/bench_sort_geometry.py --device pocl --schedule gpu --quick --repeats 3

Cases:
    depth  n in 10k, 20k, 40k, 80k, 160k uint32 keys = float32 bits of U(1, 20), bits [0, 32)
    tile   n in 100k, 400k, 1M uint32 tile ids in [0, 768), bits [0, 10)
Configs: items in 1, 2, 4, 8 x wg in 128, 256 x max_bits in 8, 10, 11 (skipped: wg * items >
65536, wg above the device's limit, local memory over the device's). --quick: depth 20k and tile
100k only. --schedule device (default) uses the device's schedule; on the CPU schedule (PoCL)
items and wg do not exist, so only max_bits varies; --schedule gpu forces the GPU kernels (any
device). Every sort is (key, arange) pairs -> a separate output pair (`out=`, as the depth sort of
the backend: the inputs are only read, nothing to restore between runs).
Per config: one warm-up sort (program build), its result checked once against
numpy.argsort(kind="stable"); then --repeats sorts, each with
    device ms  sum over the sort's launches of (end - start) from OpenCL profiling events
    span ms    first launch's start to last launch's end (launch gaps included)
    wall ms    sort_pairs + queue.finish on the host
and the medians reported. A table, a per-case summary (the geometry before docs/perf_notes.md §10,
wg 256 / items 8 / 8 bits; the fastest config by span; the default since §10: items auto for this
device's compute units, 11 bits), and with --out one JSON line per config. Exit status 1 if any result differs from numpy's.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

DEPTH_N = (10_000, 20_000, 40_000, 80_000, 160_000)
TILE_N = (100_000, 400_000, 1_000_000)
ITEMS, WGS, BITS = (1, 2, 4, 8), (128, 256), (8, 10, 11)


def cases(quick: bool) -> list[tuple[str, int, int]]:
    """(case, n, end_bit); every sort starts at bit 0."""
    depth = (20_000,) if quick else DEPTH_N
    tile = (100_000,) if quick else TILE_N
    return [("depth", n, 32) for n in depth] + [("tile", n, 10) for n in tile]


def make_keys(case: str, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if case == "depth":
        return rng.uniform(1, 20, n).astype(np.float32).view(np.uint32)
    return rng.integers(0, 768, n).astype(np.uint32)


def _timed_sorter(handle, cpu: bool, wg: int, items: int, bits: int, onesweep: bool = False):
    """A RadixSort whose kernel launches are recorded in `.events` (for the profiling sums)."""
    from reings.backends.opencl.sort import RadixSort

    class _Rec:
        def __init__(self, k, log):
            self.k, self.log = k, log

        def __call__(self, *a, **kw):
            ev = self.k(*a, **kw)
            self.log.append(ev)
            return ev

    class TimedRadixSort(RadixSort):
        def kernels(self, key64, items=None, bits=None):
            return tuple(_Rec(k, self.events) for k in super().kernels(key64, items, bits))

        def onesweep_kernels(self, key64, items, bits):
            return tuple(_Rec(k, self.events) for k in super().onesweep_kernels(key64, items, bits))

    s = TimedRadixSort(handle, cpu_schedule=cpu, wg=wg, items=items, max_bits=bits, onesweep=onesweep)
    s.events = []
    return s


def configs(cpu: bool, max_wg: int, onesweep=(0,)) -> list[tuple[int, int, int, int]]:
    """(wg, items, bits, onesweep); the CPU schedule has no wg nor items (reported as 0) nor onesweep."""
    if cpu:
        return [(0, 0, b, 0) for b in BITS]
    return [(wg, it, b, o) for o in onesweep for wg in WGS for it in ITEMS for b in BITS
            if wg * it <= 65536 and wg <= max_wg]


def measure(h, sorter, kb, vb, out, n: int, end_bit: int, repeats: int) -> dict:
    q = h.queue
    dev, span, wall = [], [], []
    for _ in range(repeats):
        sorter.events.clear()
        t0 = time.perf_counter()
        sorter.sort_pairs(kb, vb, n, 0, end_bit, out=out)
        q.finish()
        wall.append((time.perf_counter() - t0) * 1e3)
        evs = sorter.events
        dev.append(sum(e.profile.end - e.profile.start for e in evs) * 1e-6)
        span.append((evs[-1].profile.end - evs[0].profile.start) * 1e-6)
    return {"device_ms": statistics.median(dev), "span_ms": statistics.median(span),
            "wall_ms": statistics.median(wall), "launches": len(sorter.events)}


def run(device: str, repeats: int, quick: bool, schedule: str, log=sys.stderr, onesweep=(0,)) -> list[dict]:
    import pyopencl as cl

    from reings.backends.opencl.device import open_device
    from reings.backends.opencl.sort import _cpu_schedule, split_bits

    h = open_device(device, profiling=True)  # kernel times from events
    cpu = _cpu_schedule(h, None if schedule == "device" else schedule == "cpu")
    d = h.device
    base = {"device": d.name.strip(), "platform": h.platform.name.strip(), "driver": d.driver_version.strip(),
            "compute_units": int(d.max_compute_units), "schedule": "cpu" if cpu else "gpu", "repeats": repeats}
    mf = cl.mem_flags
    rows = []
    for case, n, end_bit in cases(quick):
        keys = make_keys(case, n)
        ref = np.argsort(keys & np.uint32((1 << end_bit) - 1) if end_bit < 32 else keys, kind="stable")
        kb = cl.Buffer(h.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=keys)
        vb = cl.Buffer(h.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.arange(n, dtype=np.uint32))
        out = tuple(cl.Buffer(h.context, mf.READ_WRITE, 4 * n) for _ in range(2))
        t_case = time.perf_counter()
        for wg, items, bits, os_ in configs(cpu, int(d.max_work_group_size), onesweep):
            r = {**base, "case": case, "n": n, "end_bit": end_bit, "wg": wg, "items": items, "max_bits": bits,
                 "passes": len(split_bits(0, end_bit, bits)), "onesweep": os_}
            try:
                s = _timed_sorter(h, cpu, wg or 256, items or 8, bits, bool(os_))  # explicit: no env
                if os_ and not s.uses_onesweep(n, items, bits, False, r["passes"]):
                    raise ValueError("onesweep: the block's local memory or status words are over the limits")
                s.sort_pairs(kb, vb, n, 0, end_bit, out=out)  # warm-up: builds the program
            except (ValueError, cl.Error) as e:  # local memory over the device's, a build failure
                rows.append({**r, "skipped": f"{type(e).__name__}: {str(e).splitlines()[0][:160]}"})
                continue
            got = np.empty(n, np.uint32)
            cl.enqueue_copy(h.queue, got, out[1])
            h.queue.finish()
            r["ok"] = bool(np.array_equal(got, ref))
            r.update(measure(h, s, kb, vb, out, n, end_bit, repeats))
            rows.append(r)
            del s  # its scratch
        print(f"# {case} n={n}: {time.perf_counter() - t_case:.1f} s", file=log, flush=True)
    return rows


def auto_pick(r0: dict, n: int, wg: int) -> int:
    from reings.backends.opencl.sort import auto_items

    return auto_items(n, wg, r0["compute_units"])


def print_table(rows: list[dict]) -> None:
    from reings.backends.opencl.sort import ONESWEEP_AUTO_ITEMS, ONESWEEP_BITS_DEFAULT

    if not rows:
        return
    r0 = rows[0]
    print(f"# {r0['device']} [{r0['platform']}], driver {r0['driver']}, {r0['compute_units']} CUs, "
          f"schedule={r0['schedule']}, median of {r0['repeats']}")
    print(f"{'case':6s} {'n':>8s} {'os':>2s} {'wg':>4s} {'items':>5s} {'bits':>4s} {'pass':>4s} {'device ms':>10s} "
          f"{'span ms':>9s} {'wall ms':>9s} {'launches':>8s}  ok")
    for r in rows:
        head = (f"{r['case']:6s} {r['n']:8d} {r.get('onesweep', 0):2d} {r['wg']:4d} {r['items']:5d} {r['max_bits']:4d} "
                f"{r['passes']:4d}")
        if "skipped" in r:
            print(f"{head}  skipped: {r['skipped']}")
        else:
            print(f"{head} {r['device_ms']:10.4f} {r['span_ms']:9.4f} {r['wall_ms']:9.4f} {r['launches']:8d}  "
                  f"{'ok' if r['ok'] else 'MISMATCH'}")
    print("# summary per case, device ms / span ms: before §10 (wg 256, items 8, bits 8) | fastest by span | "
          "§10's default (wg 256, items auto at this device's CUs, bits 11) | the default since §20 (onesweep, "
          "wg 256, items 4, bits 8; rows with --onesweep 1)")
    done = [r for r in rows if "skipped" not in r]
    for case, n in dict.fromkeys((r["case"], r["n"]) for r in done):
        rs = [r for r in done if (r["case"], r["n"]) == (case, n)]
        best = min(rs, key=lambda r: r["span_ms"])
        gpu = r0["schedule"] == "gpu"
        want_items = auto_pick(r0, n, 256) if gpu else 0
        pick = {"before": (256 if gpu else 0, 8 if gpu else 0, 8, 0),
                "s10": (256 if gpu else 0, want_items, 11 if gpu else 8, 0),
                "now": (256, ONESWEEP_AUTO_ITEMS, ONESWEEP_BITS_DEFAULT, 1)}
        cell = {}
        for name, key in pick.items():
            m = [r for r in rs if (r["wg"], r["items"], r["max_bits"], r.get("onesweep", 0)) == key]
            cell[name] = f"{m[0]['device_ms']:.4f} / {m[0]['span_ms']:.4f}" if m else "-"
        print(f"{case:6s} {n:8d}  before {cell['before']:>17s} | best os {best.get('onesweep', 0)} wg {best['wg']} "
              f"items {best['items']} bits {best['max_bits']}: {best['device_ms']:.4f} / {best['span_ms']:.4f} | "
              + (f"§10 (items {want_items}, bits 11): {cell['s10']} | now: {cell['now']}" if gpu
                 else "now: 8 bits on the CPU schedule"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="pocl")
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--quick", action="store_true", help="depth 20k and tile 100k only")
    ap.add_argument("--schedule", choices=("device", "gpu", "cpu"), default="device")
    ap.add_argument("--out", help="JSON lines, one per config")
    ap.add_argument("--onesweep", default="0",
                    help="GPU schedule: comma list of 0 (radix_hist + radix_scan + radix_scatter per pass) and 1 "
                         "(radix_global_hist + radix_onesweep per pass); default 0, the rows before it existed")
    ap.add_argument("--items", help="comma list of elements per work-item (default 1,2,4,8)")
    ap.add_argument("--bits", help="comma list of digit widths (default 8,10,11)")
    ap.add_argument("--wgs", help="comma list of work-group sizes (default 128,256)")
    a = ap.parse_args(argv)
    global ITEMS, BITS, WGS
    ITEMS = tuple(int(x) for x in a.items.split(",")) if a.items else ITEMS
    BITS = tuple(int(x) for x in a.bits.split(",")) if a.bits else BITS
    WGS = tuple(int(x) for x in a.wgs.split(",")) if a.wgs else WGS
    onesweep = tuple(int(x) for x in a.onesweep.split(","))
    for e in ("REINGS_SORT_ITEMS", "REINGS_SORT_WG", "REINGS_SORT_BITS"):
        if os.environ.get(e):
            print(f"# note: {e}={os.environ[e]} is ignored here (every config is explicit)", file=sys.stderr)
    t0 = time.perf_counter()
    rows = run(a.device, max(1, a.repeats), a.quick, a.schedule, onesweep=onesweep)
    print_table(rows)
    print(f"# {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    if a.out:
        with open(a.out, "w") as f:
            for r in rows:
                f.write(json.dumps(r) + "\n")
    bad = [r for r in rows if r.get("ok") is False]
    if bad:
        print(f"MISMATCH against numpy in {len(bad)} configs", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

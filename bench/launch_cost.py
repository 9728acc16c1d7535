"""What one kernel launch costs the host and the device (issue 15: where a step's queue gaps come from).

    python bench/launch_cost.py --device cuda:0
    python bench/launch_cost.py --device pocl --launches 500

A do-nothing kernel with 16 arguments (12 buffers, 4 scalars, as a typical reings stage) is enqueued
--launches times into one in-order queue, in four ways:

    invoker   k(queue, global, local, *args) through pyopencl's typed invoker (every argument set on
              every launch; an event made and dropped per launch)
    preset    the arguments set once (k.set_args), then pyopencl.enqueue_nd_range_kernel per launch
    noevent   the arguments set by the typed invoker (k.set_args) per launch, then
              clEnqueueNDRangeKernel called through ctypes (from the OpenCL library pyopencl loaded)
              with a NULL event pointer, as OpenCL allows: no event made, wrapped or released
    noevent_preset  the arguments set once, then the ctypes call per launch

Session 24 (docs/perf_notes.md §18) measured on an H100: invoker 17–19 us, preset 14–15 us, noevent 17.5–18 us,
noevent_preset 13.6–14.2 us per launch, wall = enqueue in every way: the host is the limit, and NVIDIA's
enqueue itself (~13 us on that host) is most of it; leaving the event out saves < 1 us (reings keeps pyopencl's path).

and for two global sizes (one work-group; --groups work-groups). --buffer-sweep B1,B2,... (session 25): the
`preset` way for do-nothing kernels of B distinct buffer arguments each (one work-group): whether NVIDIA's enqueue
costs per buffer argument (a cost per buffer would favour fewer, larger buffers: an arena of the training state). Per way: the host's seconds in the
enqueue loop per launch ("enqueue us") and the wall from the first enqueue to the end of
queue.finish() per launch ("wall us"). wall ~ enqueue: the host is the limit (the device finished
each launch before the next arrived); wall > enqueue: the device's own cost per launch (its launch
latency) is the limit, and the difference is what the host could spend without slowing the queue.
Median of --repeats after one warm-up round; one JSON line per way to --json.
"""
from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import json
import os
import statistics
import struct
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

SOURCE = """
__kernel void nothing(int n,
                      __global const float* a0, __global const float* a1, __global const float* a2,
                      __global const float* a3, __global const float* a4, __global const float* a5,
                      float s0, int s1, float s2,
                      __global float* o0, __global float* o1, __global float* o2, __global float* o3,
                      __global float* o4, __global float* o5)
{
    int i = get_global_id(0);
    if (i >= n && s1 < 0) o0[0] = a0[0] + a1[0] + a2[0] + a3[0] + a4[0] + a5[0] + s0 + s2;  /* never */
}
"""


def enqueue_no_event():
    """clEnqueueNDRangeKernel of the OpenCL library this process's pyopencl loaded, through ctypes
    (PyDLL: the call keeps the GIL), for (queue ptr, kernel ptr, dims, NULL, packed global, packed local,
    0, NULL, NULL)."""
    import pyopencl._cl  # noqa: F401  (loads the library)

    path = None
    try:
        with open("/proc/self/maps") as f:  # Linux: the loader pyopencl is linked to
            for line in f:
                p = line.split()[-1]
                if "libOpenCL" in os.path.basename(p) and os.path.isfile(p):
                    path = p
                    break
    except OSError:  # no /proc: the system's loader
        pass
    fn = ctypes.PyDLL(path or ctypes.util.find_library("OpenCL")).clEnqueueNDRangeKernel
    fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint, ctypes.c_void_p, ctypes.c_char_p,
                   ctypes.c_char_p, ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
    fn.restype = ctypes.c_int32
    return fn


def buffer_sweep(be, counts, a) -> list:
    """The preset way's enqueue and wall per launch for kernels of each count of buffer arguments."""
    import pyopencl as cl

    q, ctx, rows = be.queue, be.handle.context, []
    for nb in counts:
        params = ", ".join(["int n"] + [f"__global float* b{i}" for i in range(nb)])
        body = "if (get_global_id(0) >= n && n < 0) b0[0] = 1.0f;" if nb else ""
        k = cl.Kernel(cl.Program(ctx, f"__kernel void nothing_{nb}({params}) {{ {body} }}").build(), f"nothing_{nb}")
        bufs = [cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 4096) for _ in range(nb)]
        k.set_args(np.int32(1), *bufs)
        g, l = (a.wg,), (a.wg,)
        enq, wall = [], []
        for r in range(a.repeats + 1):
            q.finish()
            t0 = time.perf_counter()
            for _ in range(a.launches):
                cl.enqueue_nd_range_kernel(q, k, g, l)
            t1 = time.perf_counter()
            q.finish()
            t2 = time.perf_counter()
            if r:
                enq.append((t1 - t0) / a.launches * 1e6)
                wall.append((t2 - t0) / a.launches * 1e6)
        rec = dict(device=be.device_name, way="preset", buffers=nb, groups=1, wg=a.wg, launches=a.launches,
                   enqueue_us=statistics.median(enq), wall_us=statistics.median(wall))
        rows.append(rec)
        print(f"preset   buffers {nb:4d}: enqueue {rec['enqueue_us']:7.2f} us/launch, wall {rec['wall_us']:7.2f} us/launch",
              flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="pocl")
    ap.add_argument("--launches", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--groups", type=int, default=512, help="work-groups of the larger launch")
    ap.add_argument("--wg", type=int, default=256)
    ap.add_argument("--json", default=None)
    ap.add_argument("--buffer-sweep", default=None, help="comma-separated buffer counts: the preset way per count")
    a = ap.parse_args(argv)

    import pyopencl as cl

    from reings.backends import get_backend
    from reings.backends.opencl.program import typed_invoker

    be = get_backend(a.device)
    raw = enqueue_no_event()
    q, ctx = be.queue, be.handle.context
    prg = cl.Program(ctx, SOURCE).build()
    k = prg.nothing
    mf = cl.mem_flags
    bufs = [cl.Buffer(ctx, mf.READ_WRITE, 4096) for _ in range(12)]
    n = np.int32(1)
    args = [n, *bufs[:6], np.float32(1.0), np.int32(1), np.float32(2.0), *bufs[6:]]
    typed_invoker(k, args)
    rows = []
    if a.buffer_sweep:
        rows += buffer_sweep(be, [int(x) for x in a.buffer_sweep.split(",")], a)
    for groups in (1, a.groups):
        g, l = (groups * a.wg,), (a.wg,)
        gb, lb, qp = struct.pack("@N", g[0]), struct.pack("@N", l[0]), q.int_ptr
        for way in ("invoker", "preset", "noevent", "noevent_preset"):
            enq, wall = [], []
            for r in range(a.repeats + 1):
                q.finish()
                if way in ("preset", "noevent_preset"):
                    k.set_args(*args)
                t0 = time.perf_counter()
                if way == "invoker":
                    for _ in range(a.launches):
                        k(q, g, l, *args)
                elif way == "preset":
                    for _ in range(a.launches):
                        cl.enqueue_nd_range_kernel(q, k, g, l)
                elif way == "noevent":
                    bad = 0
                    for _ in range(a.launches):
                        k.set_args(*args)
                        bad |= raw(qp, k.int_ptr, 1, None, gb, lb, 0, None, None)
                else:
                    bad = 0
                    for _ in range(a.launches):
                        bad |= raw(qp, k.int_ptr, 1, None, gb, lb, 0, None, None)
                t1 = time.perf_counter()
                if way.startswith("noevent") and bad:
                    raise SystemExit(f"launch_cost: clEnqueueNDRangeKernel failed in way {way} (status bits {bad})")
                q.finish()
                t2 = time.perf_counter()
                if r:
                    enq.append((t1 - t0) / a.launches * 1e6)
                    wall.append((t2 - t0) / a.launches * 1e6)
            rec = dict(device=be.device_name, way=way, groups=groups, wg=a.wg, launches=a.launches,
                       enqueue_us=statistics.median(enq), wall_us=statistics.median(wall))
            rows.append(rec)
            print(f"{way:8s} groups {groups:5d}: enqueue {rec['enqueue_us']:7.2f} us/launch, wall {rec['wall_us']:7.2f} "
                  f"us/launch", flush=True)
    if a.json:
        with open(a.json, "a") as f:
            for rec in rows:
                f.write(json.dumps(rec) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

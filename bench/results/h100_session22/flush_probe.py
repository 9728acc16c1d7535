"""Experiment (session 22): does submitting the queue more often help a GPU run? Every K-th kernel
launch is followed by queue.flush() (pyopencl._cl.enqueue_nd_range_kernel wrapped, as
reings.backends.opencl.harness.ClCalls counts launches); K = 0: unchanged.

    python flush_probe.py K host [bench/bench_host.py args]
    python flush_probe.py K cli  [reings cli args]
"""
import os
import sys

here = os.path.dirname(os.path.abspath(__file__))
root = os.environ.get("REINGS_SRC", os.getcwd())
sys.path.insert(0, os.path.join(root, "bench"))
sys.path.insert(0, root)
k, what, rest = int(sys.argv[1]), sys.argv[2], sys.argv[3:]

import pyopencl._cl as _cl  # noqa: E402

if k > 0:
    orig = _cl.enqueue_nd_range_kernel
    count = [0]

    def launch(queue, *a, **kw):
        ev = orig(queue, *a, **kw)
        count[0] += 1
        if count[0] % k == 0:
            queue.flush()
        return ev

    _cl.enqueue_nd_range_kernel = launch

if what == "host":
    import bench_host

    bench_host.main(rest)
else:
    from reings.cli import main

    sys.exit(main(rest))

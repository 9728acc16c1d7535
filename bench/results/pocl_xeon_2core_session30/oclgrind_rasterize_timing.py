import sys, time
sys.path.insert(0, "tests")
from oclgrind_util import run_oclgrind
code = '''
import time, numpy as np
from test_rasterize import _scene, _cotangents, BG
from reings.backends.opencl.rasterize import rasterize_fwd_host, rasterize_bwd_host
cpu = False
t0 = time.time()
for name in ("size_17x15", "saturated", "many_in_one_tile"):
    proj, bins, w, h = _scene(name)
    vr, vd, va = _cotangents(w, h)
    t = time.time(); o = rasterize_fwd_host(proj, bins, w, h, BG, True, device="oclgrind", cpu_schedule=cpu); print(name, w, h, len(proj.means2d) if hasattr(proj,"means2d") else "", "fwd", round(time.time()-t,1), flush=True)
    t = time.time(); g = rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, device="oclgrind", cpu_schedule=cpu); print(name, "bwd", round(time.time()-t,1), flush=True)
    t = time.time(); g = rasterize_bwd_host(proj, bins, w, h, None, None, va, BG, device="oclgrind", cpu_schedule=cpu); print(name, "bwd2", round(time.time()-t,1), flush=True)
    if name != "size_17x15": continue
    t = time.time(); g = rasterize_bwd_host(proj, bins, w, h, None, vd, None, BG, device="oclgrind", cpu_schedule=cpu, opacity_only=True); print(name, "bwd_opa", round(time.time()-t,1), flush=True)
    t = time.time(); g = rasterize_bwd_host(proj, bins, w, h, vr, vd, None, BG, device="oclgrind", cpu_schedule=cpu, v_depth_o=vd[::-1].copy()); print(name, "bwd_do", round(time.time()-t,1), flush=True)
print("total", time.time()-t0)
'''
p = run_oclgrind(code)
print(p.stdout)

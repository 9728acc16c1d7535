"""Not kept (docs/perf_notes.md §33): PoCL's CPU exp (Sleef's expf_u10) written out without its range handling,
compared bit for bit with OpenCL's exp on every float of [-X, 0] (16 lanes, one PoCL device).

    python exp_check.py 87    # range [-87, 0]: 0 bad vectors; 100: mismatches below -87 (subnormal results)"""
import numpy as np, pyopencl as cl, sys, time
src = r'''
inline float16 exp_rep(float16 x) {
    const float16 qf = rint(x * 1.442695040888963407359924681001892137426645954152985934135449406931f);
    float16 s = fma(qf, (float16)(-0.693145751953125f), x);
    s = fma(qf, (float16)(-1.428606765330187045e-06f), s);
    float16 u = (float16)(0.000198527617612853646278381f);
    u = fma(u, s, (float16)(0.00139304355252534151077271f));
    u = fma(u, s, (float16)(0.00833336077630519866943359f));
    u = fma(u, s, (float16)(0.0416664853692054748535156f));
    u = fma(u, s, (float16)(0.166666671633720397949219f));
    u = fma(u, s, (float16)(0.5f));
    u = (float16)(1.0f) + fma(s * s, u, s);
    return u * as_float16((convert_int16(qf) + 127) << 23);
}
__kernel void k(const uint lo, __global uint *bad, __global uint *first) {
    const uint base = lo + get_global_id(0) * 16u;
    const uint16 bits = (uint16)(base) + (uint16)(0,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15);
    const float16 x = -as_float16(bits);   /* negative floats: bits of |x| */
    const float16 a = exp(x), b = exp_rep(x);
    const int16 d = as_int16(a) != as_int16(b);
    if (any(d)) { atomic_inc(bad); *first = base; }
}
'''
ctx = cl.Context([d for p in cl.get_platforms() for d in p.get_devices() if 'pthread' in d.name or 'Portable' in p.name][:1])
q = cl.CommandQueue(ctx)
prg = cl.Program(ctx, src).build()
bad = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 4); first = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 4)
cl.enqueue_fill_buffer(q, bad, np.uint32(0), 0, 4)
lo = 0  # +0
hi = np.float32(float(sys.argv[1]) if len(sys.argv) > 1 else 88.0).view(np.uint32)
t = time.time(); step = 1 << 26
for s in range(lo, int(hi), step):
    n = min(step, int(hi) - s)
    prg.k(q, (n // 16,), None, np.uint32(s), bad, first)
q.finish()
b = np.empty(1, np.uint32); cl.enqueue_copy(q, b, bad); f = np.empty(1, np.uint32); cl.enqueue_copy(q, f, first)
print("range [-%s, 0]" % (sys.argv[1] if len(sys.argv) > 1 else 88), "bad vectors", b[0], "first", f[0], -np.array(f).view(np.float32)[0] if b[0] else None, "%.1fs" % (time.time() - t))

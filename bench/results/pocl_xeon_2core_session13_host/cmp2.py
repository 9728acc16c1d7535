import sys, numpy as np
a=np.load(sys.argv[1]); b=np.load(sys.argv[2])
assert set(a.files)==set(b.files)
bad = 0
for k in sorted(a.files):
    x, y = a[k], b[k]
    if k.endswith(("_loss", "_psnr", "_vw", "_dm")):
        same = x.tobytes() == y.tobytes()
        r = np.max(np.abs(x - y) / np.maximum(np.abs(x), 1e-30)) if x.size else 0.0
        print(f"{k:40s} history bit-equal {same}  max rel diff {r:.2e}")
    else:
        if not (x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()):
            print("STATE DIFFERS", k); bad += 1
print("state arrays compared:", sum(1 for k in a.files if not k.endswith(('_loss','_psnr','_vw','_dm'))), "differing:", bad)

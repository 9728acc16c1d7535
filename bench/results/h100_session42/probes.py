# Session 42: call 4's flower runs (A: --fit-scale 2,2,1 --fit-scale-share 1,0.5,1): each fit's test-PSNR probes and
# the final model's PSNR per test view, from their metrics.json (call 4's logs.tgz, not kept: ~1 MB of histories).
# Usage: python probes.py METRICS.json...
import json, sys

for f in sys.argv[1:]:
    m = json.load(open(f))
    print(f"seed {m['seed']}: PSNR {m['mean']['psnr']:.4f}; per test view",
          dict(zip(m["test_names"], [round(x, 2) for x in m["per_image"]["psnr"]])))
    for st in m["stages"]:
        if "history" in st:
            h = st["history"]
            print(f"  {st['stage']}: probes", [(int(e[0]), round(e[2]["psnr"], 2)) for e in h["eval"]])

#!/usr/bin/env python
"""The bad-input and fault catalogue of issue 14: try every case of `tests/fault_catalogue.py`
(bad command lines for every subcommand, corrupt data folders of every format, bad API input,
corrupted run folders, symlinks planted at outputs, a full disk, kills followed by a resume) as a
demanding user or an attacker would, classify each outcome, and print the counts per category.

    .venv/bin/python scripts/catalogue.py --json catalogue.json          # everything (~10 min, 2 cores)
    .venv/bin/python scripts/catalogue.py --quick                         # a smoke test (~1 min)
    .venv/bin/python scripts/catalogue.py --only cli,api --list           # which cases there are

Outcomes (tests/fault_catalogue.py documents them): clean, unclear, traceback, wrong (silent-wrong),
lost (data lost). Every command runs as a subprocess (`python -m reings.cli ...`, or a child Python
for an API call) with a fresh sandbox folder as its working directory. The exit status is 0 when
every case is clean, 1 otherwise. docs/catalogue.md has the measured counts.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPO, "tests"))

import fault_catalogue as fc  # noqa: E402


def _table(records) -> tuple[str, dict]:
    cats = [c for c in fc.CATEGORIES if any(r["category"] == c for r in records)]
    counts = {}
    for c in cats + ["total"]:
        rs = [r for r in records if (r["category"] == c if c != "total" else r["category"] != "control")]
        counts[c] = {"tried": len(rs), **{o: sum(r["outcome"] == o for r in rs) for o in fc.OUTCOMES}}
    head = f"{'category':<10} {'tried':>6} " + " ".join(f"{o:>9}" for o in fc.OUTCOMES)
    lines = [head, "-" * len(head)]
    for c in cats + ["total"]:
        n = counts[c]
        lines.append(f"{c:<10} {n['tried']:>6} " + " ".join(f"{n[o]:>9}" for o in fc.OUTCOMES))
    lines.insert(-1, "-" * len(head))
    return "\n".join(lines), counts


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", metavar="FILE", help="write the counts and every case's record here")
    ap.add_argument("--quick", action="store_true", help="only the smoke-test subset (a few cases per category)")
    ap.add_argument("--only", metavar="CATS", help=f"comma list of categories ({', '.join(fc.CATEGORIES)})")
    ap.add_argument("--match", metavar="TEXT", help="only cases whose id contains TEXT")
    ap.add_argument("--jobs", type=int, default=2, help="cases run at once (default 2; disk and kill cases alone)")
    ap.add_argument("--work", metavar="DIR", help="sandbox folder (default: a temporary one, removed at the end)")
    ap.add_argument("--keep", action="store_true", help="keep the sandboxes")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    ap.add_argument("--verbose", "-v", action="store_true", help="print every case, not only those that are not clean")
    args = ap.parse_args(argv)
    cats = set(args.only.split(",")) if args.only else None
    if cats and cats - set(fc.CATEGORIES):
        ap.error(f"--only: unknown categories {sorted(cats - set(fc.CATEGORIES))}")
    todo = [c for c in fc.cases(cats, quick=args.quick) if not args.match or args.match in c.id]
    if args.list:
        for c in todo:
            print(f"{c.category:<10} {c.id}")
        return 0
    work = os.path.abspath(args.work) if args.work else tempfile.mkdtemp(prefix="reings-catalogue-")
    os.makedirs(work, exist_ok=True)
    env = fc.case_env(extra={"REINGS_CACHE_DIR": os.path.join(work, "cache")})
    fixtures = fc.Fixtures(os.path.join(work, "fixtures"), env)
    t0 = time.perf_counter()
    print(f"{len(todo)} cases; building the fixtures in {fixtures.root} ...", file=sys.stderr, flush=True)
    _prebuild(fixtures, todo)
    records = []

    def one(case):
        try:
            rec = fc.run_case(case, fixtures, os.path.join(work, "cases"), mode="subprocess", env=env)
        except Exception as e:  # a fault of the catalogue itself (a setup that failed): reported, never clean
            rec = {"id": case.id, "category": case.category, "outcome": "harness", "seconds": 0.0,
                   "why": f"the case's setup or check failed: {type(e).__name__}: {e}"}
        if rec["outcome"] != "clean" or args.verbose:
            print(f"{rec['outcome']:<9} {rec['id']}  ({rec['seconds']:.1f} s)  {rec['why']}", file=sys.stderr,
                  flush=True)
        if not args.keep:
            shutil.rmtree(os.path.join(work, "cases", case.id.replace("/", "__")), ignore_errors=True)
        return rec

    parallel = [c for c in todo if not c.slow]
    serial = [c for c in todo if c.slow]
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        records += list(pool.map(one, parallel))
    records += [one(c) for c in serial]
    seconds = time.perf_counter() - t0
    text, counts = _table(records)
    print(text)
    harness = [r["id"] for r in records if r["outcome"] == "harness"]
    if harness:
        print(f"{len(harness)} cases could not be set up (not counted): {', '.join(harness)}")
    print(f"{len(records)} cases in {seconds:.0f} s on {platform.node()} ({os.cpu_count()} cores)")
    if args.json:
        import reings

        with open(args.json, "w") as f:
            json.dump({"command": " ".join([os.path.relpath(sys.argv[0], REPO)] + (argv or sys.argv[1:])),
                       "reings": reings.__version__, "seconds": seconds, "machine": platform.platform(),
                       "cpus": os.cpu_count(), "counts": counts, "cases": records}, f, indent=1)
    if not args.work and not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    bad = sum(r["outcome"] != "clean" for r in records)
    return 1 if bad else 0


def _prebuild(fixtures, todo):
    """Build the fixtures the cases need before the cases run side by side."""
    ids = " ".join(c.id for c in todo)
    for kind in fc.SCENE_KINDS:  # the cases build them lazily too, but two threads must not race
        if kind in ids or kind == "llff":
            fixtures.scene(kind)
    if any(c.category in ("runfolder", "symlink", "disk") or c.id.startswith(("cli/render", "cli/view", "cli/export",
                                                                                  "api/other"))
           for c in todo):
        fixtures.finished_run()
    if "cli/process" in ids:
        fixtures.photos()
    if any(c.category == "kill" for c in todo):
        fixtures.kill_reference()


if __name__ == "__main__":
    sys.exit(main())

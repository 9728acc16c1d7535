"""`python -m reings.ensemble_worker IN OUT`: one ensemble member in a worker process of its own
(`reings.ensemble`, `--ensemble-jobs`): the member's inputs from the pickle IN, its model, records
and log lines to the pickle OUT (written whole: a temp file, then a rename)."""
from __future__ import annotations

import os
import pickle
import sys

from .ensemble import RECORDS


def run_member(payload: dict) -> dict:
    """A worker's member: its stages on a backend of its own; its records, model and log lines."""
    from .backends import get_backend
    from .pipeline import RunContext, stages_of

    p, lines = payload, []
    ctx = RunContext(p["cfg"], get_backend(p["cfg"].device), p["train"], p["test"], p["priors"], p["box"],
                     lines.append, progress=False, family=p["family"])
    ctx.confidences, ctx.prior_options, ctx.in_memory = p["confidences"], p["prior_options"], p["in_memory"]
    ctx.member_index = p["k"]  # its checkpoints: member<k>_<stage>.npz
    ctx.g = p["g"]
    for name, stage in stages_of(p["cfg"].method)[p["split"]:]:
        ctx.g = stage(ctx, name)
    return {**{key: getattr(ctx, key) for key in RECORDS}, "log": lines}


def main(argv=None) -> int:
    src, dst = (argv if argv is not None else sys.argv[1:])[:2]
    with open(src, "rb") as f:
        payload = pickle.load(f)
    r = run_member(payload)
    tmp = dst + ".tmp"
    with open(tmp, "wb") as f:
        pickle.dump(r, f, protocol=pickle.HIGHEST_PROTOCOL)
    os.replace(tmp, dst)
    return 0


if __name__ == "__main__":  # pragma: no cover (run as a worker process by tests/test_ensemble.py)
    sys.exit(main())

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

    lines = []
    ctx = RunContext.__new__(RunContext)
    ctx.__dict__.update(payload["state"])  # the member's context as RunContext.member made it
    ctx.backend, ctx.log, ctx.progress = get_backend(ctx.cfg.device), lines.append, False
    for name, stage in stages_of(ctx.cfg.method)[payload["split"]:]:
        ctx.g = stage(ctx, name)
    return {**{key: getattr(ctx, key) for key in RECORDS}, "log": lines}


def _exit_with_parent() -> None:
    """Exit when the parent's end of stdin closes (the parent died: SIGKILL, the OOM killer), so
    no orphan goes on writing this member's checkpoints under a later resume."""
    import threading

    def watch():  # the raw descriptor: a thread blocked in sys.stdin's buffer would hold its lock at shutdown
        try:
            while os.read(0, 1 << 16):
                pass
        except OSError:
            pass
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def main(argv=None) -> int:
    src, dst = (argv if argv is not None else sys.argv[1:])[:2]
    if argv is None:
        _exit_with_parent()
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

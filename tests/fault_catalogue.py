"""The bad-input and fault catalogue of issue 14, kept as one table that the tests
(`tests/test_catalogue.py`, `tests/test_disk_full.py`, `tests/test_kills.py`) and the runner
(`scripts/catalogue.py`, docs/catalogue.md) share.

A `Case` is one thing a demanding user or an attacker can do: a command line (`argv`, run as
`reings ARGV`) or a Python call (`call(ctx)`), after a `setup(ctx)` that builds or corrupts its
inputs in a fresh sandbox folder. Every case runs with the sandbox as its working directory; the
sandbox is listed (content hashes, symlink targets) before and after, and the outcome is one of

    clean      the expected result: a non-zero exit with one `error:` line naming the problem
               (the case's `needles`) and no traceback, or for the few valid inputs among the
               cases (`expect="ok"`) a success whose result passes the case's `check`
    unclear    an error without a traceback, but not one line naming the problem
    traceback  a Python traceback, a crash by a signal, or an exception class of no user-facing
               kind (IndexError, MemoryError, ...) from an API call
    wrong      silent-wrong: exit 0 (or a return) where an error was due, a result that fails its
               check, a valid input refused, or no answer within the case's time limit
    lost       data lost: a file that was in the sandbox before (a finished run, the input scene,
               a victim file beside --out) changed or removed, or a file written outside the
               paths the case may write (`writes`)

Categories: `CATEGORIES`. Placeholders in `argv`: {root} the sandbox, {out} = {root}/out (not
there unless the setup makes it), {scene} = {root}/scene, {run} = {root}/run, {victim} =
{root}/victim.txt, {py} = this Python.
"""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)

CATEGORIES = {
    "cli": "bad CLI arguments and option values (every subcommand)",
    "data": "bad or corrupt data folders (LLFF, DTU, COLMAP, Blender, nerfstudio)",
    "api": "bad API input (reings.run, reconstruct, render, read_ply, ...)",
    "runfolder": "corrupted run folders (checkpoints, run.json, metrics.json, cameras.json, the PLY)",
    "symlink": "symlinks planted at outputs",
    "disk": "full disk (RLIMIT_FSIZE at a chosen write)",
    "kill": "SIGKILL / SIGINT at chosen and random moments, then a resume",
    "control": "valid inputs of each format (must succeed; not counted as catalogue cases)",
}
OUTCOMES = ("clean", "unclear", "traceback", "wrong", "lost")
SLOW = ("disk", "kill")  # run only in a subprocess (a process-wide file-size limit, signals)

VICTIM_TEXT = "precious: a file that is not reings' to write\n"


@dataclass
class Case:
    id: str
    category: str
    argv: tuple | None = None
    call: Callable | None = None
    setup: Callable | None = None
    expect: str = "error"  # "error", "ok", or "either" (success or a clean error are both right)
    needles: tuple = ()
    check: Callable | None = None  # expect ok: f(ctx, result) -> None, or what is wrong
    writes: tuple = ("out",)  # sandbox-relative paths the case may create or change
    after: Callable | None = None  # f(ctx, argv) -> None or (outcome, why): a resume, a rerun
    env: dict = field(default_factory=dict)
    timeout: float = 120.0
    quick: bool = False  # in the runner's --quick subset
    runner: Callable | None = None  # f(ctx, argv, env, timeout) -> (rc, stdout, stderr, timed_out)
    inproc: bool = True  # may run inside the test process (not: it starts servers or waits on the network)

    @property
    def slow(self) -> bool:
        return self.category in SLOW

    @property
    def needs(self) -> tuple:
        """Optional packages the case needs (the tests skip it without them)."""
        mods = ["cv2"]
        if "colmap" in self.id or self.id.startswith("cli/process"):
            mods.append("pycolmap")
        if "/view" in self.id:
            mods.append("viser")
        if self.id.startswith("cli/worker") or "cluster" in self.id or "runs-per-gpu" in self.id:
            mods.append("distributed")
        if "lpips" in self.id:
            mods.append("onnxruntime")
        return tuple(mods)


# {{{ fixtures: small valid scenes of every format, a finished run, photos

RUN_FAST = ("--views", "2", "--method", "3dgs", "--iterations", "3", "--depth-prior", "none", "--no-lpips",
            "--eval-every", "0", "--init-points", "200", "--quiet")
FACTOR = {"llff": ("--factor", "8"), "colmap": ("--factor", "1"), "dtu": ("--factor", "25"),
          "blender": (), "nerfstudio": ("--factor", "1")}
SCENE_KINDS = tuple(FACTOR)

# the kill table's run: test_kills.py's settings (procedural scene, quick preset, 24 iterations a stage)
KILL_ARGS = ("run", "--method", "reings", "--preset", "quick", "--iterations", "24", "--depth-prior", "exact",
             "--no-lpips", "--eval-every", "6", "--checkpoint-every", "4", "--checkpoint-seconds", "0", "--seed", "2",
             "--quiet")
# (what must exist before the signal, extra delay in s or "random", signal name)
KILL_MOMENTS = [("config.toml", 0.0, "SIGKILL"),                 # right after the folder is claimed
                ("checkpoints/fine.npz", 0.0, "SIGINT"),         # Ctrl-C in the fine fit
                ("checkpoints/final.npz", "random", "SIGKILL"),  # somewhere in the final fit
                ("renders/*.png", 0.0, "SIGKILL")]               # while the test renders are written


# the finished run of the fixtures, with relative paths (run.json records the data folder as given)
RERUN_ARGV = ("run", "--data", "scene", *RUN_FAST, *FACTOR["llff"], "--out", "run")


# `reings render` of the sandbox's finished run; interpolate: the model of a 3-iteration run has too few
# opaque Gaussians for the spiral's depth range
RENDER = ("render", "{run}", "--path", "interpolate")


def run_argv(kind: str = "llff", *extra) -> tuple:
    """`reings run` on the sandbox's scene of `kind` with the smallest settings, into {out}."""
    return ("run", "--data", "{scene}", *RUN_FAST, *FACTOR[kind], "--out", "{out}", *extra)


def _procedural(n, w, h):
    from reings.data.procedural import make_procedural_scene

    return make_procedural_scene(n_views=n, width=w, height=h, supersample=1)


def _write_pngs(folder, images, names):
    from reings.data.images import write_png

    os.makedirs(folder, exist_ok=True)
    for im, n in zip(images, names):
        write_png(os.path.join(folder, n), im)


GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def _c2w(cam) -> np.ndarray:
    c2w = np.eye(4)
    c2w[:3, :3] = cam.viewmat[:3, :3].T
    c2w[:3, 3] = cam.center
    return c2w


def _truth(d, sc):
    """The true cameras of a fixture scene, beside it (the control cases compare the loader's with them)."""
    np.savez(d + ".truth.npz", K=np.stack([c.K for c in sc.cameras]), viewmat=np.stack([c.viewmat for c in sc.cameras]))


def build_llff(d):
    sc = _procedural(10, 48, 36)
    _truth(d, sc)
    names = [f"image{i:03d}.png" for i in range(len(sc))]
    _write_pngs(os.path.join(d, "images_8"), sc.images, names)
    rows = []
    for cam, (near, far) in zip(sc.cameras, sc.bounds):
        R, C = cam.viewmat[:3, :3].T, cam.center
        cols = np.stack([R[:, 1], R[:, 0], -R[:, 2], C, [cam.height * 8, cam.width * 8, cam.fx * 8]], axis=1)
        rows.append(np.concatenate([cols.ravel(), [0.9 * near, 1.1 * far]]))
    np.save(os.path.join(d, "poses_bounds.npy"), np.stack(rows))


def build_colmap(d, text=False):
    from reings.data.colmap import write_model

    sc = _procedural(10, 48, 36)
    _truth(d, sc)
    names = [f"img{i:02d}.png" for i in range(len(sc))]
    _write_pngs(os.path.join(d, "images"), sc.images, names)
    write_model(os.path.join(d, "sparse", "0"), sc.cameras, names, text=text)


def build_dtu(d):
    sc = _procedural(49, 64, 48)
    _truth(d, sc)
    names = [f"{i:06d}.png" for i in range(49)]
    _write_pngs(os.path.join(d, "image"), sc.images, names)
    _write_pngs(os.path.join(d, "mask"), [np.ones((48, 64, 3), np.float32)] * 49, names)
    mats = {}
    for i, cam in enumerate(sc.cameras):
        K = cam.K.copy()
        K[:2] *= 25.0  # the images are 1600x1200 / 25
        P = np.eye(4)
        P[:3, :4] = K @ cam.viewmat[:3, :4]
        mats[f"world_mat_{i}"] = P
        mats[f"scale_mat_{i}"] = np.eye(4)  # the unit sphere: bounds |C| -/+ 1 for the scene box's fallback
    np.savez(os.path.join(d, "cameras_sphere.npz"), **mats)


def build_blender(d):
    sc = _procedural(90, 32, 24)  # the protocol's train ids go up to 86
    _truth(d, sc)
    for split, idx in (("train", range(88)), ("test", range(88, 90))):
        frames = []
        names = [f"r_{i}.png" for i in idx]
        _write_pngs(os.path.join(d, split), [sc.images[i] for i in idx], names)
        for i, n in zip(idx, names):
            frames.append({"file_path": f"./{split}/{n[:-4]}",
                           "transform_matrix": (_c2w(sc.cameras[i]) @ GL_TO_CV).tolist()})
        with open(os.path.join(d, f"transforms_{split}.json"), "w") as f:
            json.dump({"camera_angle_x": float(np.radians(60.0)), "frames": frames}, f)


def build_nerfstudio(d):
    sc = _procedural(10, 48, 36)
    _truth(d, sc)
    names = [f"frame_{i:05d}.png" for i in range(len(sc))]
    _write_pngs(os.path.join(d, "images"), sc.images, names)
    c = sc.cameras[0]
    meta = {"camera_model": "OPENCV", "fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy, "w": c.width,
            "h": c.height, "frames": [{"file_path": f"images/{n}", "transform_matrix": (_c2w(cam) @ GL_TO_CV).tolist()}
                                      for n, cam in zip(names, sc.cameras)]}
    with open(os.path.join(d, "transforms.json"), "w") as f:
        json.dump(meta, f, indent=1)


def build_photos(d):
    """Four photos of the procedural scene that COLMAP registers (tests/test_process.py's)."""
    import cv2

    from reings.data.procedural import make_procedural_scene

    views = (3, 7, 11, 15)
    sc = make_procedural_scene(n_views=20, width=320, height=240, views=views)
    os.makedirs(d, exist_ok=True)
    for i, im in zip(views, sc.images):
        u8 = np.clip(np.rint(im * 255), 0, 255).astype(np.uint8)
        cv2.imwrite(os.path.join(d, f"photo_{i:02d}.png"), u8[..., ::-1])


class Fixtures:
    """Valid inputs built once under `root` (scenes/<kind>, runs/finished, photos, runs/kill_ref)
    and copied into each case's sandbox."""

    def __init__(self, root: str, env: dict | None = None):
        self.root = os.path.abspath(root)
        self.env = env
        os.makedirs(self.root, exist_ok=True)

    def _once(self, name, build):
        d = os.path.join(self.root, name)
        if not os.path.exists(os.path.join(d, ".built")):
            shutil.rmtree(d, ignore_errors=True)
            os.makedirs(d)
            build(d)
            open(os.path.join(d, ".built"), "w").close()
        return d

    def scene(self, kind: str) -> str:
        return self._once(f"scenes/{kind}", globals()[f"build_{kind}"])

    def photos(self) -> str:
        return self._once("photos", build_photos)

    def finished_run(self) -> str:
        """A finished `reings run` (RERUN_ARGV: the llff scene at ./scene, RUN_FAST, into ./run) made
        by the command line itself; a case's sandbox gets both, so RERUN_ARGV there finds its settings."""
        scene = self.scene("llff")

        def build(d):
            _copytree(scene, os.path.join(d, "scene"))
            rc, _, err, _ = cli_subprocess(RERUN_ARGV, d, self.env, 600)
            if rc != 0:
                raise RuntimeError(f"the fixture run failed: {err[-2000:]}")
        return os.path.join(self._once("runs/finished", build), "run")

    def kill_reference(self) -> str:
        def build(d):
            rc, _, err, _ = cli_subprocess([*KILL_ARGS, "--out", os.path.join(d, "run")], d, self.env, 900)
            if rc != 0:
                raise RuntimeError(f"the kill reference run failed: {err[-2000:]}")
        return os.path.join(self._once("runs/kill_ref", build), "run")
# }}}


# {{{ the sandbox of one case

def _copytree(src, dst):
    shutil.copytree(src, dst, symlinks=True, ignore=shutil.ignore_patterns(".built"))


class Ctx:
    """What a case's setup, call and checks see: the sandbox and the fixtures."""

    def __init__(self, root: str, fixtures: Fixtures):
        self.root = root
        self.fx = fixtures
        self.out = os.path.join(root, "out")
        self.scene_dir = os.path.join(root, "scene")
        self.run_dir = os.path.join(root, "run")
        self.victim = os.path.join(root, "victim.txt")

    def p(self, *parts) -> str:
        return os.path.join(self.root, *parts)

    @property
    def vars(self) -> dict:
        return {"root": self.root, "out": self.out, "scene": self.scene_dir, "run": self.run_dir,
                "victim": self.victim, "py": sys.executable}

    def scene(self, kind: str = "llff") -> str:
        if not os.path.exists(self.scene_dir):
            _copytree(self.fx.scene(kind), self.scene_dir)
        return self.scene_dir

    def finished_run(self) -> str:
        if not os.path.exists(self.run_dir):
            _copytree(self.fx.finished_run(), self.run_dir)
        return self.run_dir

    def make_victim(self) -> str:
        with open(self.victim, "w") as f:
            f.write(VICTIM_TEXT)
        return self.victim

    def write(self, rel: str, data) -> str:
        p = self.p(rel)
        os.makedirs(os.path.dirname(p), exist_ok=True)
        with open(p, "wb" if isinstance(data, bytes) else "w") as f:
            f.write(data)
        return p


def snapshot(root: str) -> dict:
    """{relative path: ("file", sha256) | ("link", target) | ("dir", None)} of everything under root."""
    snap = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for n in dirnames + filenames:
            p = os.path.join(dirpath, n)
            rel = os.path.relpath(p, root)
            if os.path.islink(p):
                snap[rel] = ("link", os.readlink(p))
                continue
            if os.path.isdir(p):
                snap[rel] = ("dir", None)
                continue
            h = hashlib.sha256()
            try:
                with open(p, "rb") as f:
                    for chunk in iter(lambda: f.read(1 << 20), b""):
                        h.update(chunk)
            except OSError as e:
                snap[rel] = ("unreadable", str(e))
                continue
            snap[rel] = ("file", h.hexdigest())
    return snap


def _under(rel: str, prefixes) -> bool:
    return any(rel == p or rel.startswith(p.rstrip("/") + os.sep) for p in prefixes)


def data_lost(before: dict, after: dict, writes) -> str | None:
    """Why the sandbox lost data between the two snapshots, or None: a file that was there changed
    or went (unless under `writes`), or a new file outside `writes`."""
    for rel, what in before.items():
        if what[0] == "dir" or _under(rel, writes):
            continue
        if rel not in after:
            return f"{rel} was removed"
        if after[rel] != what:
            return f"{rel} was changed"
    for rel, what in after.items():
        if rel not in before and what[0] != "dir" and not _under(rel, writes):
            return f"{rel} was written (outside the paths the command may write)"
    return None
# }}}


# {{{ running a case: a subprocess (the runner), or in this process (the tests)

def case_env(base: dict | None = None, extra: dict | None = None) -> dict:
    env = dict(os.environ if base is None else base)
    env.pop("REINGS_LPIPS_MODEL", None)
    env.setdefault("PYTHONPATH", "")
    env.update(extra or {})
    return env


def cli_subprocess(argv, cwd, env=None, timeout=120.0, prefix=None):
    """(rc, stdout, stderr, timed_out) of `python -m reings.cli ARGV` (or `prefix + ARGV`)."""
    cmd = list(prefix or [sys.executable, "-m", "reings.cli"]) + list(argv)
    try:
        r = subprocess.run(cmd, cwd=cwd, env=case_env() if env is None else env, capture_output=True, text=True,
                           errors="replace",
                           timeout=timeout,
                           stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired as e:
        return None, _text(e.stdout), _text(e.stderr), True
    return r.returncode, r.stdout, r.stderr, False


def _text(b) -> str:
    return b.decode(errors="replace") if isinstance(b, bytes) else (b or "")


class _Hang(BaseException):
    """The in-process time limit (a BaseException, so no `except Exception` takes it)."""


@contextlib.contextmanager
def _alarm(seconds):
    def on_alarm(*_):
        raise _Hang()

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, float(seconds))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@contextlib.contextmanager
def _in(cwd, env_extra):
    old_cwd, old_env = os.getcwd(), dict(os.environ)
    os.chdir(cwd)
    os.environ.pop("REINGS_LPIPS_MODEL", None)
    os.environ.update(env_extra or {})
    try:
        yield
    finally:
        os.chdir(old_cwd)
        os.environ.clear()
        os.environ.update(old_env)


def cli_inprocess(argv, cwd, env_extra=None, timeout=120.0):
    """(rc, stdout, stderr, timed_out) of reings.cli.main(ARGV) in this process; an exception that
    escapes main() is printed as Python would print it."""
    from reings.cli import main

    out, err = io.StringIO(), io.StringIO()
    rc, timed_out = None, False
    with _in(cwd, env_extra), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            with _alarm(timeout):
                rc = main(list(argv))
        except SystemExit as e:
            rc = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
            if not isinstance(e.code, int) and e.code is not None:
                print(e.code, file=sys.stderr)
        except _Hang:
            timed_out = True
        except BaseException:  # noqa: BLE001 - what the interpreter would print
            traceback.print_exc()
            rc = 1
    return rc, out.getvalue(), err.getvalue(), timed_out


# exception classes a user may see from the API: the message is the report
API_ERRORS = (ValueError, TypeError, OSError)
API_ERROR_NAMES = ("DeviceNotFound", "KernelBuildError")


def api_call(case, ctx, timeout=120.0) -> dict:
    """Run `case.call(ctx)` here: {"raised": class name or None, "clean_class", "message",
    "traceback", "check": why the result is wrong or None}."""
    res = {"raised": None, "clean_class": False, "message": "", "traceback": "", "check": None, "timed_out": False}
    with _in(ctx.root, {k: v.format(**ctx.vars) for k, v in case.env.items()}):
        try:
            with _alarm(timeout):
                value = case.call(ctx)
            if case.check is not None:
                res["check"] = case.check(ctx, value)
        except _Hang:
            res["timed_out"] = True
        except BaseException as e:  # noqa: BLE001
            names = [k.__name__ for k in type(e).__mro__]
            res.update(raised=type(e).__name__, message=str(e), traceback=traceback.format_exc(),
                       clean_class=isinstance(e, API_ERRORS) or any(n in API_ERROR_NAMES for n in names))
    return res


def api_subprocess(case, ctx, env=None, timeout=120.0) -> dict:
    code = ("import json, sys; sys.path.insert(0, %r); import fault_catalogue as fc; "
            "r = fc.api_child(%r, %r, %r); print('@@RESULT@@' + json.dumps(r))" % (HERE, case.id, ctx.root, ctx.fx.root))
    try:
        r = subprocess.run([sys.executable, "-c", code], cwd=ctx.root, env=case_env() if env is None else env,
                           capture_output=True, text=True, errors="replace", timeout=timeout, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        return {"raised": None, "timed_out": True, "message": "", "traceback": "", "check": None,
                "clean_class": False}
    for line in r.stdout.splitlines():
        if line.startswith("@@RESULT@@"):
            return json.loads(line[len("@@RESULT@@"):])
    return {"raised": f"exit {r.returncode}", "clean_class": False, "message": "",
            "traceback": (r.stderr or "")[-3000:], "check": None, "timed_out": False}


def api_child(case_id, root, fixtures_root) -> dict:
    case = case_by_id(case_id)
    res = api_call(case, Ctx(root, Fixtures(fixtures_root)), timeout=case.timeout)
    res["check"] = None if res["check"] is None else str(res["check"])
    return res
# }}}


# {{{ classifying an outcome

def _error_lines(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if "error:" in ln]


def classify_cli(case, ctx, rc, out, err, timed_out) -> tuple[str, str]:
    if timed_out:
        return "wrong", f"no answer within {case.timeout:g} s"
    if "Traceback (most recent call last)" in err or rc is None or rc < 0 or rc not in (0, 1, 2, 130):
        tail = [ln for ln in err.strip().splitlines() if ln.strip()][-1:] or [f"exit {rc}"]
        return "traceback", f"exit {rc}: {tail[0][:300]}"
    if rc == 0:
        if case.expect == "error":
            return "wrong", "exit 0 where an error was due"
        why = case.check(ctx, out) if case.check else None
        return ("wrong", f"exit 0 but {why}") if why else ("clean", "succeeded as it should")
    lines = _error_lines(err)
    msg = lines[-1] if lines else (err.strip().splitlines() or [""])[-1]
    if case.expect == "ok":
        return "wrong", f"refused a valid input (exit {rc}): {msg[:300]}"
    if len(lines) != 1:
        return "unclear", f"{len(lines)} error lines: {err.strip()[-300:]}"
    needles = [n.format(**ctx.vars) for n in case.needles]
    missing = [n for n in needles if n not in err]
    if missing:
        return "unclear", f"message lacks {missing[0]!r}: {msg[:300]}"
    return "clean", msg[:300]


def classify_api(case, ctx, res) -> tuple[str, str]:
    if res.get("timed_out"):
        return "wrong", f"no answer within {case.timeout:g} s"
    if res["raised"] is None:
        if case.expect == "error":
            return "wrong", "returned where an error was due"
        return ("wrong", f"returned, but {res['check']}") if res["check"] else ("clean", "returned as it should")
    msg = f"{res['raised']}: {res['message']}"[:300]
    if not res["clean_class"]:
        return "traceback", msg
    if case.expect == "ok":
        return "wrong", f"refused a valid input: {msg}"
    needles = [n.format(**ctx.vars) for n in case.needles]
    missing = [n for n in needles if n not in res["message"]]
    if missing:
        return "unclear", f"message lacks {missing[0]!r}: {msg}"
    return "clean", msg


WORST = {o: i for i, o in enumerate(OUTCOMES)}


def run_case(case, fixtures: Fixtures, work: str, mode: str = "subprocess", env=None) -> dict:
    """Set up, run and classify one case in a fresh sandbox `work/<id>`; returns its record."""
    root = os.path.join(work, case.id.replace("/", "__"))
    shutil.rmtree(root, ignore_errors=True)
    os.makedirs(root)
    ctx = Ctx(root, fixtures)
    t = time.perf_counter()
    if case.setup is not None:
        case.setup(ctx)
    before = snapshot(root)
    case_vars = {k: v.format(**ctx.vars) for k, v in case.env.items()}
    if case.argv is not None:
        argv = [a.format(**ctx.vars) for a in case.argv]
        if case.runner is not None:
            rc, out, err, to = case.runner(ctx, argv, case_env(env, case_vars), case.timeout)
        elif mode == "subprocess" or case.slow or not case.inproc:
            rc, out, err, to = cli_subprocess(argv, root, case_env(env, case_vars), case.timeout)
        else:
            rc, out, err, to = cli_inprocess(argv, root, case_vars, case.timeout)
        outcome, why = classify_cli(case, ctx, rc, out, err, to)
        rec = {"rc": rc, "stderr_tail": err[-1500:]}
    else:
        argv = None
        res = (api_subprocess(case, ctx, case_env(env, case_vars), case.timeout) if mode == "subprocess"
               else api_call(case, ctx, case.timeout))
        outcome, why = classify_api(case, ctx, res)
        rec = {"raised": res["raised"], "stderr_tail": res.get("traceback", "")[-1500:]}
    lost = data_lost(before, snapshot(root), case.writes)
    if lost:
        outcome, why = "lost", lost
    if case.after is not None and outcome in ("clean", "unclear"):
        bad = case.after(ctx, argv)
        if bad and WORST[bad[0]] > WORST[outcome]:
            outcome, why = bad
    rec.update(id=case.id, category=case.category, outcome=outcome, why=why, seconds=time.perf_counter() - t)
    return rec
# }}}


# {{{ setup helpers

def seq(*steps):
    """A setup running `steps` in order."""
    def setup(ctx):
        for s in steps:
            s(ctx)
    return setup


def scene(kind="llff", corrupt=None):
    """Setup: the valid `kind` scene at {scene}, then `corrupt(ctx, scene_dir)`."""
    def setup(ctx):
        d = ctx.scene(kind)
        if corrupt is not None:
            corrupt(ctx, d)
    return setup


def finished(corrupt=None):
    """Setup: a finished run at {run} (and the llff scene it was made from at {scene})."""
    def setup(ctx):
        ctx.scene("llff")
        d = ctx.finished_run()
        if corrupt is not None:
            corrupt(ctx, d)
    return setup


def victim(ctx):
    ctx.make_victim()


def write(rel, data):
    return lambda ctx: ctx.write(rel, data)


def mkdir(rel):
    return lambda ctx: os.makedirs(ctx.p(rel), exist_ok=True)


def symlink(target_rel, link_rel):
    def setup(ctx):
        link = ctx.p(link_rel)
        os.makedirs(os.path.dirname(link), exist_ok=True)
        os.symlink(ctx.p(target_rel), link)
    return setup


def truncate(path, keep=0.5):
    with open(path, "rb") as f:
        data = f.read()
    with open(path, "wb") as f:
        f.write(data[: int(len(data) * keep)])


def _png_bytes(h, w, c=3, dtype=np.uint8):
    import cv2

    ok, buf = cv2.imencode(".png", np.full((h, w, c) if c > 1 else (h, w), 128, dtype))
    assert ok
    return buf.tobytes()


def _patch_png_size(data: bytes, w: int, h: int) -> bytes:
    """The PNG with its IHDR width and height replaced (the CRC made right again)."""
    import struct
    import zlib

    ihdr = bytearray(data[12:29])  # b"IHDR" + 13 bytes
    ihdr[4:12] = struct.pack(">II", w, h)
    return data[:12] + bytes(ihdr) + struct.pack(">I", zlib.crc32(bytes(ihdr)) & 0xFFFFFFFF) + data[33:]


def _edit_npy(name, edit):
    def corrupt(ctx, d):
        p = os.path.join(d, name)
        a = np.load(p)
        np.save(p, edit(a.copy()))
    return corrupt


def _edit_json(rel, edit):
    def corrupt(ctx, d):
        p = os.path.join(d, rel)
        with open(p) as f:
            meta = json.load(f)
        r = edit(meta)  # edits in place, or returns the new text
        meta = r if isinstance(r, str) else meta
        with open(p, "w") as f:
            f.write(meta if isinstance(meta, str) else json.dumps(meta))
    return corrupt


def _edit_npz(name, edit):
    def corrupt(ctx, d):
        p = os.path.join(d, name)
        with np.load(p) as z:
            arrays = {k: z[k] for k in z.files}
        r = edit(arrays)
        np.savez(p, **(r if isinstance(r, dict) else arrays))
    return corrupt


def _files(d, sub):
    return sorted(os.path.join(d, sub, n) for n in os.listdir(os.path.join(d, sub)))


def _replace_file(sub, index, data_or_fn):
    """Replace the `index`-th file of `sub` by bytes, or by fn(old bytes)."""
    def corrupt(ctx, d):
        p = _files(d, sub)[index]
        with open(p, "rb") as f:
            old = f.read()
        new = data_or_fn(old) if callable(data_or_fn) else data_or_fn
        with open(p, "wb") as f:
            f.write(new)
    return corrupt


def _remove(rel):
    def corrupt(ctx, d):
        p = os.path.join(d, rel)
        shutil.rmtree(p) if os.path.isdir(p) else os.unlink(p)
    return corrupt


def _remove_nth(sub, index):
    return lambda ctx, d: os.unlink(_files(d, sub)[index])


def _both(*fns):
    def corrupt(ctx, d):
        for fn in fns:
            fn(ctx, d)
    return corrupt
# }}}


# {{{ checks of results that must succeed

def finished_run_check(ctx, _out=None):
    p = os.path.join(ctx.out, "metrics.json")
    if not os.path.isfile(p):
        return "no metrics.json"
    with open(p) as f:
        m = json.load(f)
    psnr = (m.get("mean") or {}).get("psnr")
    if not isinstance(psnr, (int, float)) or not np.isfinite(psnr):
        return f"test PSNR is {psnr!r}"
    return None


def victim_intact(ctx, _out=None):
    with open(ctx.victim) as f:
        return None if f.read() == VICTIM_TEXT else "the victim file outside --out was changed"


def all_of(*checks):
    def check(ctx, out):
        for c in checks:
            why = c(ctx, out)
            if why:
                return why
        return None
    return check
# }}}


# {{{ the cases: bad command lines

# `reings run` on a valid scene with one bad option: (name, options, words the message must hold)
RUN_OPTIONS = [
    ("views-0", ["--views", "0"], ["views", ">= 2"]),
    ("views-1", ["--views", "1"], ["views", "got 1"]),
    ("views-negative", ["--views", "-3"], ["views", "-3"]),
    ("views-word", ["--views", "two"], ["--views", "two"]),
    ("views-float", ["--views", "2.5"], ["--views", "2.5"]),
    ("views-too-many", ["--views", "99"], ["99"]),
    ("method-unknown", ["--method", "nerf"], ["unknown method 'nerf'"]),
    ("method-empty", ["--method", ""], ["method"]),
    ("method-bad-ablation", ["--method", "reings-no-foo"], ["foo"]),
    ("device-unknown", ["--device", "tpu9"], ["tpu9"]),
    ("device-cuda-absent", ["--device", "cuda:7"], ["cuda"]),
    ("device-opencl-index", ["--device", "opencl:9:9"], ["opencl:9:9"]),
    ("device-empty", ["--device", ""], ["device"]),
    ("preset-unknown", ["--preset", "turbo"], ["--preset", "turbo"]),
    ("iterations-zero", ["--iterations", "0"], ["--iterations", ">= 1"]),
    ("iterations-two", ["--iterations", "1,2"], ["--iterations", "A,B,C"]),
    ("iterations-words", ["--iterations", "a,b,c"], ["--iterations", "'a'"]),
    ("iterations-negative", ["--iterations", "5,-1,3"], ["--iterations", "-1"]),
    ("iterations-float", ["--iterations", "2.5"], ["--iterations", "2.5"]),
    ("seed-negative", ["--seed", "-1"], ["--seed", "-1"]),
    ("seed-float", ["--seed", "1.5"], ["--seed", "1.5"]),
    ("depth-prior-missing-onnx", ["--depth-prior", "onnx:{root}/missing.onnx"], ["missing.onnx"]),
    ("depth-prior-empty-onnx", ["--depth-prior", "onnx:"], ["onnx"]),
    ("depth-prior-unknown", ["--depth-prior", "midas"], ["midas"]),
    ("depth-prior-exact-on-data", ["--depth-prior", "exact"], ["exact"]),
    ("factor-zero", ["--factor", "0"], ["--factor", ">= 1"]),
    ("factor-negative", ["--factor", "-2"], ["--factor", "-2"]),
    ("factor-absent-folder", ["--factor", "100000"], ["images_100000"]),
    ("dataset-unknown", ["--dataset", "kitti"], ["--dataset", "kitti"]),
    ("dataset-procedural-with-data", ["--dataset", "procedural"], ["procedural", "{scene}"]),
    ("dataset-dtu-on-llff", ["--dataset", "dtu"], ["{scene}"]),
    ("dataset-blender-on-llff", ["--dataset", "blender"], ["{scene}"]),
    ("holdout-unknown", ["--holdout", "all"], ["--holdout", "all"]),
    ("extent-unknown", ["--extent", "box"], ["--extent", "box"]),
    ("init-points-zero", ["--init-points", "0"], ["--init-points", ">= 1"]),
    ("sh-degree-4", ["--sh-degree", "4"], ["--sh-degree", "4"]),
    ("sh-degree-negative", ["--sh-degree", "-1"], ["--sh-degree", "-1"]),
    ("max-gaussians-zero", ["--max-gaussians", "0"], ["--max-gaussians", ">= 1"]),
    ("depth-smooth-negative", ["--depth-smooth", "-1"], ["--depth-smooth", ">= 0"]),
    ("depth-smooth-nan", ["--depth-smooth", "nan"], ["--depth-smooth", "nan"]),
    ("depth-smooth-inf", ["--depth-smooth", "inf"], ["--depth-smooth", "inf"]),
    ("depth-smooth-word", ["--depth-smooth", "x"], ["--depth-smooth", "'x'"]),
    ("recipe-unknown", ["--recipe", "blender"], ["--recipe", "blender"]),
    ("view-warp-negative", ["--view-warp", "-1"], ["--view-warp", "-1"]),
    ("view-warp-nan", ["--view-warp", "nan"], ["--view-warp", "nan"]),
    ("view-warp-start-1", ["--view-warp-start", "1"], ["--view-warp-start", "[0, 1)"]),
    ("view-warp-start-nan", ["--view-warp-start", "nan"], ["--view-warp-start", "nan"]),
    ("view-warp-disparity-zero", ["--view-warp-disparity", "0"], ["--view-warp-disparity", "positive"]),
    ("view-warp-disparity-inf", ["--view-warp-disparity", "inf"], ["--view-warp-disparity", "inf"]),
    ("opacity-decay-zero", ["--opacity-decay", "0"], ["--opacity-decay", "(0, 1]"]),
    ("opacity-decay-above-1", ["--opacity-decay", "1.5"], ["--opacity-decay", "1.5"]),
    ("opacity-decay-nan", ["--opacity-decay", "nan"], ["--opacity-decay", "nan"]),
    ("ehps-gamma-zero", ["--ehps-gamma", "0"], ["--ehps-gamma", "> 0"]),
    ("ehps-gamma-inf", ["--ehps-gamma", "inf"], ["--ehps-gamma", "inf"]),
    ("ehps-beta1-inf", ["--ehps-beta1", "inf"], ["--ehps-beta1", "inf"]),
    ("ehps-beta2-negative", ["--ehps-beta2", "-1"], ["--ehps-beta2", "-1"]),
    ("ehps-beta2-nan", ["--ehps-beta2", "nan"], ["--ehps-beta2", "nan"]),
    ("ehps-min-points-zero", ["--ehps-min-points", "0"], ["--ehps-min-points", ">= 1"]),
    ("ivps-delta-2", ["--ivps-delta", "2"], ["--ivps-delta", "[0, 1]"]),
    ("ivps-fraction-zero", ["--ivps-fraction", "0"], ["--ivps-fraction", "(0, 1]"]),
    ("ivps-hard-opacity-zero", ["--ivps-hard-opacity", "0"], ["--ivps-hard-opacity", "(0, 1]"]),
    ("ivps-min-alpha-2", ["--ivps-min-alpha", "2"], ["--ivps-min-alpha", "[0, 1]"]),
    ("ivps-depth-unknown", ["--ivps-depth", "soft"], ["--ivps-depth", "soft"]),
    ("cvps-fraction-zero", ["--cvps-fraction", "0"], ["--cvps-fraction", "(0, 1]"]),
    ("cvps-fraction-1.5", ["--cvps-fraction", "1.5"], ["--cvps-fraction", "1.5"]),
    ("final-prune-1", ["--final-prune", "1"], ["--final-prune", "[0, 1)"]),
    ("final-prune-negative", ["--final-prune", "-0.1"], ["--final-prune", "-0.1"]),
    ("eval-every-negative", ["--eval-every", "-1"], ["--eval-every", ">= 0"]),
    ("checkpoint-every-zero", ["--checkpoint-every", "0"], ["--checkpoint-every", ">= 1"]),
    ("checkpoint-seconds-negative", ["--checkpoint-seconds", "-1"], ["--checkpoint-seconds", "-1"]),
    ("checkpoint-seconds-nan", ["--checkpoint-seconds", "nan"], ["--checkpoint-seconds", "nan"]),
    ("out-empty", ["--out", ""], ["--out", "empty"]),
    ("out-blank", ["--out", "   "], ["--out", "empty"]),
    ("unknown-option", ["--bogus"], ["--bogus"]),
    ("config-missing", ["--config", "{root}/none.toml"], ["none.toml"]),
    ("config-a-folder", ["--config", "{root}"], ["--config", "{root}"]),
    ("data-missing", ["--data", "{root}/nowhere"], ["nowhere", "not found"]),
    ("data-empty-string", ["--data", ""], ["--data"]),
]

# `--config FILE` holding this text
BAD_TOML = [
    ("garbage", "views = = 3\n", ["bad.toml"]),
    ("binary", b"\xff\xfe\x00\x01garbage\n", ["bad.toml"]),
    ("unknown-key", "colour = 3\n", ["bad.toml", "colour"]),
    ("wrong-type", 'views = "three"\n', ["bad.toml", "views"]),
    ("bad-value", "views = 1\n", ["bad.toml", "views"]),
    ("nan", "view_warp = nan\n", ["bad.toml", "view_warp"]),
    ("nested-bad", "[reings]\ngamma = -1.0\n", ["bad.toml", "gamma"]),
    ("unknown-section", "[foo]\nx = 1\n", ["bad.toml", "foo"]),
    ("array-for-int", "seed = [1, 2]\n", ["bad.toml", "seed"]),
    ("huge-int", "seed = 99999999999999999999999\n", []),  # a valid seed: numpy takes any size
]
TOML_OK = ("huge-int",)


def _cli_run_cases():
    cases = [Case(f"cli/run/{name}", "cli", run_argv("llff", *opts), setup=scene("llff"), needles=tuple(needles),
                  quick=name in ("views-0", "method-unknown", "device-unknown", "out-empty"))
             for name, opts, needles in RUN_OPTIONS]
    cases += [Case(f"cli/run/config-{name}", "cli", run_argv("llff", "--config", "{root}/bad.toml"),
                   setup=seq(scene("llff"), write("bad.toml", text)), needles=tuple(needles), quick=name == "garbage",
                   expect="either" if name in TOML_OK else "error", check=finished_run_check)
              for name, text, needles in BAD_TOML]
    cases += [
        Case("cli/run/depth-prior-garbage-onnx", "cli", run_argv("llff", "--depth-prior", "onnx:{root}/garbage.onnx"),
             setup=seq(scene("llff"), write("garbage.onnx", b"\x08\x01garbage" * 50)), needles=("garbage.onnx",)),
        Case("cli/run/out-is-a-file", "cli", run_argv("llff", "--out", "{victim}"), setup=seq(scene("llff"), victim),
             needles=("{victim}", "not a folder"), writes=()),
        Case("cli/run/out-under-a-file", "cli", run_argv("llff", "--out", "{victim}/sub"),
             setup=seq(scene("llff"), victim), needles=("{victim}",), writes=()),
        Case("cli/run/data-is-a-file", "cli", run_argv("llff", "--data", "{victim}"), setup=victim,
             needles=("{victim}", "not a folder")),
        Case("cli/run/data-empty-folder", "cli", run_argv("llff", "--data", "{root}/empty"), setup=mkdir("empty"),
             needles=("{root}/empty", "cannot detect")),
        Case("cli/run/lpips-model-missing", "cli", run_argv("llff", "--lpips"), setup=scene("llff"),
             env={"REINGS_LPIPS_MODEL": "/nonexistent/lpips_vgg.onnx"}, needles=("/nonexistent/lpips_vgg.onnx",)),
        Case("cli/run/lpips-model-garbage", "cli", run_argv("llff", "--lpips"),
             setup=seq(scene("llff"), write("models/lpips_vgg.onnx", b"not an onnx model")),
             env={"REINGS_LPIPS_MODEL": "models/lpips_vgg.onnx"}, needles=("lpips_vgg.onnx",)),
    ]
    return cases


EVAL_BASE = ("eval", "--root", "{root}/root", "--views", "2", "--methods", "3dgs", "--iterations", "3",
             "--depth-prior", "none", "--no-lpips", "--eval-every", "0", "--init-points", "200", "--quiet",
             "--out", "{out}")


def _eval_root(ctx):
    _copytree(ctx.fx.scene("llff"), ctx.p("root", "fern"))


EVAL_OPTIONS = [
    ("root-missing", ["--root", "{root}/nowhere"], ["nowhere", "not found"]),
    ("root-empty", ["--root", "{root}/empty"], ["scene folders"]),
    ("views-zero", ["--views", "0,3"], ["--views", ">= 2"]),
    ("views-word", ["--views", "a"], ["--views", "'a'"]),
    ("views-empty", ["--views", ""], ["--views"]),
    ("methods-unknown", ["--methods", "3dgs,nerf"], ["unknown method 'nerf'"]),
    ("methods-empty", ["--methods", ""], ["--methods"]),
    ("seeds-negative", ["--seeds", "-1"], ["--seeds", "-1"]),
    ("seeds-word", ["--seeds", "a"], ["--seeds", "'a'"]),
    ("seeds-gap", ["--seeds", "1,,2"], ["--seeds"]),  # read as 1,2: either is right
    ("device-unknown", ["--device", "tpu9"], ["tpu9"]),
    ("scenes-unknown", ["--scenes", "trex"], ["trex", "found: fern"]),
    ("dataset-unknown", ["--dataset", "kitti"], ["kitti"]),
    ("cluster-bad", ["--cluster", "local:x"], ["local:N"]),
    ("cluster-address", ["--cluster", "nowhere"], ["scheduler address"]),
    ("runs-per-gpu-without-cluster", ["--runs-per-gpu", "4"], ["--runs-per-gpu", "--cluster local"]),
    ("runs-per-gpu-zero", ["--cluster", "local:1", "--runs-per-gpu", "0"], ["K >= 1"]),
    ("holdout-none", ["--holdout", "none"], ["holdout"]),
    ("iterations-bad", ["--iterations", "0"], ["--iterations"]),
]


def _cli_other_cases():
    E = "cli/eval/"
    cases = [Case(E + name, "cli", EVAL_BASE + tuple(opts), setup=_eval_root if "root" not in name else mkdir("empty"),
                  needles=tuple(needles), quick=name == "views-zero", expect="either" if name == "seeds-gap" else "error")
             for name, opts, needles in EVAL_OPTIONS]
    cases += [
        Case(E + "root-a-file", "cli", EVAL_BASE + ("--root", "{victim}"), setup=victim, needles=("{victim}",)),
        Case(E + "table-only-missing", "cli", ("eval", "--table-only", "--out", "{out}"), needles=("{out}", "not found")),
        Case(E + "no-out", "cli", EVAL_BASE[:-2], setup=_eval_root, needles=("--out",)),
        Case(E + "out-is-a-file", "cli", EVAL_BASE[:-1] + ("{victim}",), setup=seq(_eval_root, victim),
             needles=("{victim}",), writes=()),
    ]
    B = ("bench", "--n", "200", "--sort", "none", "--reference", "none", "--pairs", "none", "--repeats", "2",
         "--warmup", "0", "--scenes", "A", "--sh", "0")
    cases += [
        Case("cli/bench/unknown-option", "cli", ("bench", "--bogus"), needles=("--bogus",)),
        Case("cli/bench/device-unknown", "cli", B + ("--device", "tpu9"), needles=("tpu9",)),
        Case("cli/bench/scene-unknown", "cli", B + ("--scenes", "Z"), needles=("Z",)),
        Case("cli/bench/sh-word", "cli", B + ("--sh", "x"), needles=("--sh", "'x'")),
        Case("cli/bench/sh-4", "cli", B + ("--sh", "4"), needles=("--sh", "4")),
        Case("cli/bench/repeats-zero", "cli", B + ("--repeats", "0"), needles=("--repeats", "0")),
        Case("cli/bench/n-negative", "cli", B + ("--n", "-5"), needles=("--n", "-5")),
        Case("cli/bench/out-a-folder", "cli", B + ("--out", "{root}/d"), setup=mkdir("d"), needles=("{root}/d",)),
        Case("cli/devices/unknown-option", "cli", ("devices", "--bogus"), needles=("--bogus",)),
        Case("cli/devices/extra-argument", "cli", ("devices", "pocl"), needles=("pocl",)),
        Case("cli/no-command", "cli", (), needles=("command",)),
        Case("cli/unknown-command", "cli", ("train",), needles=("train",)),
    ]
    return cases + _cli_product_cases()


def _photos(n=None, corrupt=None, where="photos"):
    def setup(ctx):
        src = ctx.fx.photos()
        os.makedirs(ctx.p(where), exist_ok=True)
        for name in sorted(n for n in os.listdir(src) if n.endswith(".png"))[:n]:
            shutil.copy(os.path.join(src, name), ctx.p(where, name))
        if corrupt is not None:
            corrupt(ctx, ctx.p(where))
    return setup


def _cli_product_cases():
    P, R, V, W, X = "cli/process/", "cli/render/", "cli/view/", "cli/worker/", "cli/export/"
    run = seq(finished(), mkdir("out"))  # --out {out}/v.mp4 needs its folder
    ro = ("--path", "interpolate", "--out", "{out}/v.mp4")  # interpolate: a short run's model has no spiral
    cases = [
        Case(P + "photos-missing", "cli", ("process", "{root}/nowhere", "--out", "{out}"), needles=("nowhere",)),
        Case(P + "photos-a-file", "cli", ("process", "{victim}", "--out", "{out}"), setup=victim,
             needles=("{victim}",)),
        Case(P + "photos-empty", "cli", ("process", "{root}/empty", "--out", "{out}"), setup=mkdir("empty"),
             needles=("{root}/empty", "no image files")),
        Case(P + "one-photo", "cli", ("process", "{root}/photos", "--out", "{out}", "--quiet"), setup=_photos(1),
             needles=("{root}/photos", "at least 2")),
        Case(P + "no-out", "cli", ("process", "{root}/photos"), setup=_photos(2), needles=("--out",)),
        Case(P + "out-empty", "cli", ("process", "{root}/photos", "--out", ""), setup=_photos(2), needles=("--out",)),
        Case(P + "out-not-empty", "cli", ("process", "{root}/photos", "--out", "{out}", "--quiet"),
             setup=seq(_photos(2), write("out/keep.txt", "mine")), needles=("{out}", "--overwrite"), writes=()),
        Case(P + "out-is-the-photos", "cli", ("process", "{root}/photos", "--out", "{root}/photos", "--overwrite",
                                               "--quiet"), setup=_photos(), needles=("{root}/photos",), writes=(),
             timeout=300),
        Case(P + "out-holds-the-photos", "cli", ("process", "{root}/p/photos", "--out", "{root}/p", "--overwrite",
                                                  "--quiet"), setup=_photos(where="p/photos"),
             needles=("{root}/p",), writes=(), timeout=300),
        Case(P + "text-as-photo", "cli", ("process", "{root}/photos", "--out", "{out}", "--quiet"),
             setup=_photos(corrupt=lambda ctx, d: open(os.path.join(d, "photo_99.png"), "w").write("not a photo")),
             needles=("photo_99.png",), timeout=300),
        Case(R + "frames-zero", "cli", (*RENDER, "--frames", "0", *ro), setup=run, needles=("--frames",)),
        Case(R + "frames-negative", "cli", (*RENDER, "--frames", "-5", *ro), setup=run, needles=("--frames",)),
        Case(R + "frames-word", "cli", (*RENDER, "--frames", "abc", *ro), setup=run, needles=("--frames",)),
        Case(R + "frames-huge", "cli", (*RENDER, "--frames", "100000000", "--size", "8x6", *ro), setup=run,
             needles=("--frames", "100000000"), timeout=60),
        Case(R + "fps-zero", "cli", ("render", "{run}", "--fps", "0", *ro), setup=run, needles=("--fps",)),
        Case(R + "fps-nan", "cli", ("render", "{run}", "--fps", "nan", *ro), setup=run, needles=("--fps",)),
        Case(R + "fps-inf", "cli", ("render", "{run}", "--fps", "inf", *ro), setup=run, needles=("--fps", "inf")),
        Case(R + "size-zero", "cli", ("render", "{run}", "--size", "0x0", *ro), setup=run, needles=("--size",)),
        Case(R + "size-word", "cli", ("render", "{run}", "--size", "64by48", *ro), setup=run, needles=("--size",)),
        Case(R + "size-huge", "cli", ("render", "{run}", "--size", "99999x99999", *ro), setup=run, needles=("--size",)),
        Case(R + "size-negative", "cli", ("render", "{run}", "--size", "-4x3", *ro), setup=run, needles=("--size",)),
        Case(R + "background-range", "cli", ("render", "{run}", "--background", "2,0,0", *ro), setup=run,
             needles=("--background",)),
        Case(R + "background-short", "cli", ("render", "{run}", "--background", "1,1", *ro), setup=run,
             needles=("--background",)),
        Case(R + "background-nan", "cli", ("render", "{run}", "--background", "nan,0,0", *ro), setup=run,
             needles=("--background",)),
        Case(R + "out-gif", "cli", ("render", "{run}", "--out", "{out}/v.gif"), setup=run,
             needles=("v.gif", "unknown video extension"), quick=True),
        Case(R + "out-no-extension", "cli", ("render", "{run}", "--out", "{out}/video"), setup=run,
             needles=("video", "extension")),
        Case(R + "out-missing-folder", "cli", (*RENDER, "--frames", "2", "--out", "{root}/no/such/v.mp4"),
             setup=run, needles=("{root}/no/such",)),
        Case(R + "out-exists", "cli", ("render", "{run}", "--out", "{root}/old.mp4"),
             setup=seq(run, write("old.mp4", b"an older video")), needles=("old.mp4", "--overwrite")),
        Case(R + "depth-out-gif", "cli", ("render", "{run}", *ro, "--depth-out", "{out}/d.gif"), setup=run,
             needles=("d.gif",)),
        Case(R + "out-equals-depth-out", "cli", (*RENDER, "--frames", "2", *ro, "--depth-out",
                                                 "{out}/v.mp4"), setup=run, needles=("v.mp4", "--depth-out")),
        Case(R + "cameras-missing", "cli", ("render", "{run}", "--cameras", "{root}/none.json", *ro), setup=run,
             needles=("none.json",)),
        Case(R + "cameras-garbage", "cli", ("render", "{run}", "--cameras", "{root}/c.json", *ro),
             setup=seq(run, write("c.json", "{not json")), needles=("c.json",)),
        Case(R + "path-unknown", "cli", ("render", "{run}", "--path", "circle", *ro), setup=run, needles=("--path",)),
        Case(R + "device-unknown", "cli", ("render", "{run}", "--device", "tpu9", *ro), setup=run, needles=("tpu9",)),
        Case(R + "nothing-to-write", "cli", ("render", "{run}"), setup=run, needles=("nothing to write",)),
        Case(R + "run-missing", "cli", ("render", "{root}/nowhere", *ro), setup=mkdir("out"),
             needles=("nowhere", "not found")),
        Case(R + "run-a-file", "cli", ("render", "{victim}", *ro), setup=seq(victim, mkdir("out")),
             needles=("{victim}",)),
        Case(R + "run-empty", "cli", ("render", "{root}/empty", *ro), setup=seq(mkdir("empty"), mkdir("out")),
             needles=("no gaussians.ply",)),
        Case(R + "frames-dir-a-file", "cli", (*RENDER, "--frames", "2", "--frames-dir", "{victim}"),
             setup=seq(run, victim), needles=("{victim}",), writes=()),
        Case(R + "frames-dir-holds-frames", "cli", (*RENDER, "--frames", "2", "--frames-dir", "{root}/f"),
             setup=seq(run, write("f/frame_0000.png", b"an earlier frame")), needles=("{root}/f", "--overwrite"),
             writes=()),
        Case(V + "missing", "cli", ("view", "{root}/nowhere"), needles=("nowhere",), timeout=30),
        Case(V + "empty-folder", "cli", ("view", "{root}/empty"), setup=mkdir("empty"), needles=("no gaussians.ply",),
             timeout=30),
        Case(V + "garbage-ply", "cli", ("view", "{root}/x.ply"), setup=write("x.ply", b"\x00garbage" * 10),
             needles=("x.ply",), timeout=30),
        Case(V + "text-file", "cli", ("view", "{victim}"), setup=victim, needles=("{victim}", "not a PLY"), timeout=30),
        Case(V + "empty-model", "cli", ("view", "{root}/e.ply"),
             setup=write("e.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nend_header\n"),
             needles=("e.ply",), timeout=30),
        Case(V + "port-negative", "cli", ("view", "{run}", "--port", "-1"), setup=run, needles=("--port", "-1"),
             timeout=30),
        Case(V + "port-huge", "cli", ("view", "{run}", "--port", "70000"), setup=run, needles=("--port", "70000"),
             timeout=30),
        Case(V + "port-word", "cli", ("view", "{run}", "--port", "http"), setup=run, needles=("--port",), timeout=30),
        Case(V + "host-bad", "cli", ("view", "{run}", "--host", "no such host!"), setup=run,
             needles=("no such host!",), timeout=30),
        Case(W + "no-scheduler", "cli", ("worker",), needles=("--scheduler",)),
        Case(W + "runs-zero", "cli", ("worker", "--scheduler", "tcp://127.0.0.1:9", "--runs", "0"),
             needles=("--runs 0",), quick=True),
        Case(W + "runs-negative", "cli", ("worker", "--scheduler", "tcp://127.0.0.1:9", "--runs", "-2"),
             needles=("--runs", "-2")),
        Case(W + "runs-word", "cli", ("worker", "--scheduler", "tcp://127.0.0.1:9", "--runs", "x"), needles=("--runs",)),
        Case(W + "device-unknown", "cli", ("worker", "--scheduler", "tcp://127.0.0.1:9", "--device", "tpu9"),
             needles=("tpu9",), timeout=60),
        Case(W + "pocl-threads-negative", "cli", ("worker", "--scheduler", "tcp://127.0.0.1:9", "--pocl-threads", "-1"),
             needles=("--pocl-threads", "-1"), timeout=60),
        Case(W + "scheduler-garbage", "cli", ("worker", "--scheduler", "not a url"), needles=("not a url",), timeout=60),
        Case(W + "scheduler-unreachable", "cli", ("worker", "--scheduler", "tcp://127.0.0.1:9"),
             needles=("tcp://127.0.0.1:9",), timeout=180, inproc=False,
             env={"DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "3s"}),
        Case(X + "run-missing", "cli", ("export", "{root}/nowhere", "--out", "{out}"), needles=("nowhere", "not found")),
        Case(X + "format-unknown", "cli", ("export", "{run}", "--format", "obj", "--out", "{out}"), setup=run,
             needles=("--format",)),
        Case(X + "sh-degree-4", "cli", ("export", "{run}", "--sh-degree", "4", "--out", "{out}"), setup=run,
             needles=("--sh-degree",)),
        Case(X + "sh-degree-word", "cli", ("export", "{run}", "--sh-degree", "x", "--out", "{out}"), setup=run,
             needles=("--sh-degree",)),
        Case(X + "out-empty", "cli", ("export", "{run}", "--out", ""), setup=run, needles=("--out",)),
        Case(X + "no-out", "cli", ("export", "{run}"), setup=run, needles=("--out",)),
        Case(X + "out-is-a-file", "cli", ("export", "{run}", "--out", "{victim}"), setup=seq(run, victim),
             needles=("{victim}",), writes=()),
        Case(X + "out-taken", "cli", ("export", "{run}", "--out", "{out}"),
             setup=seq(run, write("out/point_cloud.ply", b"an earlier export")), needles=("point_cloud.ply", "--overwrite"),
             writes=()),
        Case(X + "out-is-the-run", "cli", ("export", "{run}", "--format", "inria", "--out", "{run}"), setup=run,
             needles=("cameras.json", "--overwrite"), writes=()),
    ]
    return cases
# }}}


# {{{ the cases: bad API input

FAST_KW = dict(views=2, method="3dgs", iterations=3, depth_prior="none", with_lpips=False, eval_every=0,
               init_points=200, quiet=True)


def _run(**kw):
    """reings.run on the sandbox's llff scene with the fast settings and `kw`, into {out}."""
    def call(ctx):
        import reings

        args = {"data": ctx.scene_dir, "out": ctx.out, "factor": 8, **FAST_KW, **kw}
        return reings.run(**{k: v for k, v in args.items() if v is not _DROP})
    return call


_DROP = object()


def _tiny_scene(n=3, w=24, h=18):
    return _procedural(n, w, h)


def _reconstruct(edit):
    """reings.reconstruct on (images, cameras, kw) of a tiny procedural scene after `edit`."""
    def call(ctx):
        import reings

        sc = _tiny_scene()
        ims, cams, kw = edit(list(sc.images), list(sc.cameras), {"iterations": 3, "depth_prior": "none",
                                                                 "method": "3dgs", "init_points": 100})
        return reings.reconstruct(ims, cams, **kw)
    return call


def _g(n=20, seed=0, **over):
    from reings.types import Gaussians

    rng = np.random.default_rng(seed)
    a = dict(means=rng.uniform([-1, -1, 3], [1, 1, 6], (n, 3)), quats=rng.normal(size=(n, 4)),
             log_scales=rng.uniform(-3, -2, (n, 3)), opacity_logits=rng.uniform(-1, 2, n), sh=rng.normal(0, .5, (n, 1, 3)))
    a.update(over)
    return Gaussians(**a)


def _cam(w=32, h=24, **over):
    from reings.types import Camera

    a = dict(K=np.array([[30.0, 0, w / 2], [0, 30.0, h / 2], [0, 0, 1]]), viewmat=np.eye(4), width=w, height=h)
    a.update(over)
    return Camera(**a)


def _cam_over_alloc():
    """A camera so large that even a 4-byte-per-pixel buffer exceeds PoCL's largest allocation
    (CL_DEVICE_MAX_MEM_ALLOC_SIZE scales with the machine's memory: 20000 x 20000 fit on a 23 GB
    machine), so the render refuses before allocating any image buffer. The case keeps its id."""
    import math

    from reings.backends import get_backend

    side = int(math.isqrt(int(get_backend("pocl").handle.device.max_mem_alloc_size) // 4)) + 1024
    return _cam(max(side, 20000), max(side, 20000))


def _render(g=None, cam=None, **kw):
    def call(ctx):
        import reings

        return reings.render(_g() if g is None else g(), _cam() if cam is None else cam(), **kw)
    return call


def _finite_render(ctx, out):
    return None if np.all(np.isfinite(out.rgb)) and np.all(np.isfinite(out.depth)) else "the render holds NaN/Inf"


PLY_HEAD = b"ply\nformat binary_little_endian 1.0\n"


def _ply_bytes(n=3, deg=0):
    import tempfile

    from reings.io.ply import write_ply

    with tempfile.TemporaryDirectory() as d:
        write_ply(os.path.join(d, "a.ply"), _g(n, sh=np.zeros((n, (1, 4, 9, 16)[deg], 3))))
        with open(os.path.join(d, "a.ply"), "rb") as f:
            return f.read()


def _read_ply(make):
    """read_ply of {root}/m.ply holding make() (bytes)."""
    def call(ctx):
        from reings.io.ply import read_ply

        p = ctx.p("m.ply")
        with open(p, "wb") as f:
            f.write(make())
        return read_ply(p)
    return call


def _ply_edit(old, new, n=3, deg=1):
    return lambda: _ply_bytes(n, deg).replace(old, new, 1)


def _render_path(**kw):
    def call(ctx):
        import reings

        return reings.render_path(ctx.run_dir, **{"frames": 2, "size": (8, 6), "path": "interpolate", **kw})
    return call


def _api_run_cases():
    A = "api/run/"
    s = scene("llff")
    cases = [
        Case(A + "views-1", "api", call=_run(views=1), setup=s, needles=("views",), quick=True),
        Case(A + "views-string", "api", call=_run(views="3"), setup=s, needles=("views", "'3'")),
        Case(A + "views-bool", "api", call=_run(views=True), setup=s, needles=("views", "True")),
        Case(A + "views-numpy-float", "api", call=_run(views=np.float64(2.5)), setup=s, needles=("views", "2.5")),
        Case(A + "method-int", "api", call=_run(method=3), setup=s, needles=("method", "3")),
        Case(A + "method-unknown", "api", call=_run(method="nerf"), setup=s, needles=("nerf",)),
        Case(A + "unknown-keyword", "api", call=_run(bogus=1), setup=s, needles=("bogus",)),
        Case(A + "device-unknown", "api", call=_run(device="tpu9"), setup=s, needles=("tpu9",)),
        Case(A + "device-none", "api", call=_run(device=None), setup=s, needles=("device", "None")),
        Case(A + "seed-negative", "api", call=_run(seed=-1), setup=s, needles=("seed", "-1")),
        Case(A + "seed-float", "api", call=_run(seed=1.5), setup=s, needles=("seed", "1.5")),
        Case(A + "iterations-zero", "api", call=_run(iterations=[0]), setup=s, needles=("iterations",)),
        Case(A + "iterations-two", "api", call=_run(iterations=(1, 2)), setup=s, needles=("iterations",)),
        Case(A + "iterations-string", "api", call=_run(iterations="3"), setup=s, needles=("iterations",)),
        Case(A + "out-empty", "api", call=_run(out=""), setup=s, needles=("out",)),
        Case(A + "out-int", "api", call=_run(out=5), setup=s, needles=("out", "5")),
        Case(A + "data-int", "api", call=_run(data=123), setup=s, needles=("data", "123")),
        Case(A + "data-missing", "api", call=_run(data="nowhere"), setup=s, needles=("nowhere",)),
        Case(A + "scene-not-a-scene", "api", call=_run(data=_DROP, scene="x"), setup=s, needles=("Scene",)),
        Case(A + "config-positional-string", "api", call=lambda ctx: __import__("reings").run("fern"),
             needles=("RunConfig",)),
        Case(A + "eval-every-negative", "api", call=_run(eval_every=-1), setup=s, needles=("eval_every",)),
        Case(A + "eval-every-bool", "api", call=_run(eval_every=True), setup=s, needles=("eval_every",)),
        Case(A + "cvps-fraction-nan", "api", call=_run(cvps_fraction=float("nan")), setup=s, needles=("cvps_fraction",)),
        Case(A + "reings-dict-bad", "api", call=_run(reings={"gamma": 0}), setup=s, needles=("gamma",)),
        Case(A + "reings-dict-unknown", "api", call=_run(reings={"colour": 1}), setup=s, needles=("colour",)),
        Case(A + "output-int", "api", call=_run(output=5), setup=s, needles=("output",)),
        Case(A + "depth-prior-int", "api", call=_run(depth_prior=0), setup=s, needles=("depth_prior",)),
        Case(A + "depth-smooth-bool", "api", call=_run(depth_smooth=True), setup=s, needles=("depth_smooth",)),
        Case(A + "factor-float", "api", call=_run(factor=2.5), setup=s, needles=("factor", "2.5")),
        Case(A + "dataset-unknown", "api", call=_run(dataset="kitti"), setup=s, needles=("kitti",)),
    ]
    return cases


def _api_other_cases():
    R, P, G, L = "api/reconstruct/", "api/render/", "api/read_ply/", "api/other/"
    nan_im = lambda i, c, k: ([np.full_like(i[0], np.nan)] + i[1:], c, k)  # noqa: E731
    cases = [
        Case(R + "count-mismatch", "api", call=_reconstruct(lambda i, c, k: (i, c[:2], k)),
             needles=("3 images but 2 cameras",)),
        Case(R + "one-view", "api", call=_reconstruct(lambda i, c, k: (i[:1], c[:1], k)), needles=("at least 2",)),
        Case(R + "no-views", "api", call=_reconstruct(lambda i, c, k: ([], [], k)), needles=("at least 2",)),
        Case(R + "nan-image", "api", call=_reconstruct(nan_im), needles=("image 0", "NaN")),
        Case(R + "int32-image", "api", call=_reconstruct(lambda i, c, k: ([x.astype(np.int32) for x in i], c, k)),
             needles=("image 0", "int32")),
        Case(R + "grey-image", "api", call=_reconstruct(lambda i, c, k: ([x[..., 0] for x in i], c, k)),
             needles=("image 0", "shape")),
        Case(R + "cameras-are-dicts", "api", call=_reconstruct(lambda i, c, k: (i, [{} for _ in c], k)),
             needles=("cameras[0]", "Camera")),
        Case(R + "size-mismatch", "api", call=_reconstruct(lambda i, c, k: ([x[:10] for x in i], c, k)),
             needles=("24x10", "24x18")),
        Case(R + "bounds-shape", "api", call=_reconstruct(lambda i, c, k: (i, c, {**k, "bounds": np.ones((2, 2))})),
             needles=("bounds",)),
        Case(R + "bounds-nan", "api", call=_reconstruct(lambda i, c, k: (i, c, {**k, "bounds": np.full((3, 2), np.nan)})),
             needles=("bounds",)),
        Case(R + "names-duplicate", "api", call=_reconstruct(lambda i, c, k: (i, c, {**k, "names": ["a", "a", "b"]})),
             needles=("unique",)),
        Case(R + "images-a-string", "api", call=_reconstruct(lambda i, c, k: ("abc", c, k)), needles=("image 0",)),
        Case(R + "method-unknown", "api", call=_reconstruct(lambda i, c, k: (i, c, {**k, "method": "nerf"})),
             needles=("nerf",)),
        Case(P + "gaussians-a-string", "api", call=_render(g=lambda: "g"), needles=("gaussians",), quick=True),
        Case(P + "camera-a-string", "api", call=_render(cam=lambda: "cam"), needles=("camera",)),
        Case(P + "background-two", "api", call=_render(background=(1, 1)), needles=("background",)),
        Case(P + "near-zero", "api", call=_render(near=0), needles=("near",)),
        Case(P + "near-nan", "api", call=_render(near=float("nan")), needles=("near",)),
        Case(P + "device-unknown", "api", call=_render(device="tpu9"), needles=("tpu9",)),
        Case(P + "opacity-override-2", "api", call=_render(opacity_override=2), needles=("opacity_override",)),
        Case(P + "camera-20000", "api", call=_render(cam=_cam_over_alloc), needles=("largest allocation",),
             timeout=300),
        Case(P + "gaussians-bad-shape", "api", call=_render(g=lambda: _g(means=np.zeros((20, 2)))),
             needles=("Gaussians.means",)),
        Case(P + "gaussians-sh-5", "api", call=_render(g=lambda: _g(sh=np.zeros((20, 5, 3)))), needles=("Gaussians.sh",)),
        Case(P + "gaussians-strings", "api", call=_render(g=lambda: _g(means=np.full((20, 3), "a"))),
             needles=("Gaussians.means",)),
        Case(P + "camera-K-2x2", "api", call=_render(cam=lambda: _cam(K=np.eye(2))), needles=("Camera.K",)),
        Case(P + "camera-width-0", "api", call=_render(cam=lambda: _cam(0, 24)), needles=("width",)),
        Case(P + "camera-nan", "api", call=_render(cam=lambda: _cam(viewmat=np.full((4, 4), np.nan))),
             needles=("finite",)),
        Case(P + "camera-width-float", "api", call=_render(cam=lambda: _cam(width=32.5)), needles=("32.5",)),
        Case(P + "nan-gaussians", "api", call=_render(g=lambda: _g(means=np.full((20, 3), np.nan))), expect="ok",
             check=_finite_render),
        Case(P + "no-gaussians", "api", call=_render(g=lambda: _g(0)), expect="ok", check=_finite_render),
        Case(P + "vjp-v-rgb-shape", "api",
             call=lambda ctx: __import__("reings").render_vjp(_g(), _cam(), np.zeros((3, 3, 3))), needles=("v_rgb",)),
        Case(P + "vjp-grad-fields", "api",
             call=lambda ctx: __import__("reings").render_vjp(_g(), _cam(), np.zeros((24, 32, 3)), grad_fields=["foo"]),
             needles=("grad_fields", "foo")),
        Case(G + "missing", "api", call=lambda ctx: __import__("reings.io.ply").io.ply.read_ply(ctx.p("none.ply")),
             needles=("none.ply",)),
        Case(G + "a-folder", "api", call=lambda ctx: __import__("reings.io.ply").io.ply.read_ply(ctx.root),
             needles=("{root}",)),
        Case(G + "empty", "api", call=_read_ply(lambda: b""), needles=("m.ply",)),
        Case(G + "garbage", "api", call=_read_ply(lambda: os.urandom(64)), needles=("m.ply",)),
        Case(G + "truncated", "api", call=_read_ply(lambda: _ply_bytes(3, 1)[:-5]), needles=("m.ply", "truncated")),
        Case(G + "absurd-count", "api", call=_ply_case(b"element vertex 3\n", b"element vertex 1000000000000000\n"),
             needles=("m.ply", "1000000000000000")),
        Case(G + "negative-count", "api", call=_ply_case(b"element vertex 3\n", b"element vertex -3\n"),
             needles=("m.ply", "-3")),
        Case(G + "count-word", "api", call=_ply_case(b"element vertex 3\n", b"element vertex many\n"),
             needles=("m.ply", "many")),
        Case(G + "no-end-header", "api", call=_read_ply(lambda: PLY_HEAD + b"comment x\n" * 200000),
             needles=("m.ply", "end_header")),
        Case(G + "non-ascii-header", "api", call=_ply_case(b"format", b"\xff\xfeformat"), needles=("m.ply",)),
        Case(G + "ascii-format", "api", call=_ply_case(b"binary_little_endian", b"ascii"), needles=("m.ply", "ascii")),
        Case(G + "missing-property", "api", call=_ply_case(b"property float opacity\n", b""),
             needles=("m.ply", "opacity")),
        Case(G + "duplicate-property", "api", call=_ply_case(b"property float y\n", b"property float x\n"),
             needles=("m.ply", "x")),
        Case(G + "list-property", "api", call=_ply_case(b"property float nx\n", b"property list uchar int nx\n"),
             needles=("m.ply",)),
        Case(G + "f-rest-count", "api", call=_ply_case(b"property float f_rest_8\n", b""), needles=("m.ply", "f_rest")),
        Case(G + "unknown-type", "api", call=_ply_case(b"property float x\n", b"property quux x\n"),
             needles=("m.ply", "quux")),
        Case(G + "nan-values", "api", call=_read_ply(lambda: PLY_HEAD + b"element vertex 1\n" + b"".join(
            b"property float %s\n" % a.encode() for a in _ply_names()) + b"end_header\n" + np.full(
            len(_ply_names()), np.nan, "<f4").tobytes()), expect="either", needles=("m.ply",)),
        Case(L + "render-path-unknown", "api", call=_render_path(path="circle"), setup=finished(), needles=("circle",)),
        Case(L + "render-path-frames-0", "api", call=_render_path(frames=0), setup=finished(), needles=("frames",)),
        Case(L + "render-path-frames-negative", "api", call=_render_path(frames=-1), setup=finished(),
             needles=("frames",)),
        Case(L + "render-path-size-0", "api", call=_render_path(size=(0, 10)), setup=finished(), needles=("size",)),
        Case(L + "render-path-cameras-strings", "api", call=_render_path(cameras=["x"]), setup=finished(),
             needles=("cameras[0]",)),
        Case(L + "render-path-no-cameras", "api", call=lambda ctx: __import__("reings").render_path(_g()),
             needles=("cameras",)),
        Case(L + "render-path-device", "api", call=_render_path(device="tpu9"), setup=finished(), needles=("tpu9",)),
        Case(L + "export-format", "api", call=lambda ctx: __import__("reings").export_run(ctx.run_dir, ctx.out, "obj"),
             setup=finished(), needles=("obj",)),
        Case(L + "export-sh-degree", "api",
             call=lambda ctx: __import__("reings").export_run(ctx.run_dir, ctx.out, sh_degree=4), setup=finished(),
             needles=("sh-degree", "4")),
        Case(L + "load-scene-int", "api", call=lambda ctx: __import__("reings").load_scene(123), needles=("123",)),
        Case(L + "load-scene-dataset", "api", call=lambda ctx: __import__("reings").load_scene(ctx.root, "kitti"),
             needles=("kitti",)),
        Case(L + "few-shot-split-0", "api",
             call=lambda ctx: __import__("reings").few_shot_split(_tiny_scene(10), 0), needles=("n_views=0",)),
        Case(L + "few-shot-split-many", "api",
             call=lambda ctx: __import__("reings").few_shot_split(_tiny_scene(10), 50), needles=("n_views=50",)),
        Case(L + "read-cameras-folder", "api", call=lambda ctx: __import__("reings").read_cameras_json(ctx.root),
             needles=("{root}",)),
        Case(L + "load-run-config-garbage", "api",
             call=lambda ctx: __import__("reings").load_run_config(ctx.write("c.toml", "= =")), needles=("c.toml",)),
        Case(L + "depth-prior-unknown", "api", call=lambda ctx: __import__("reings").get_depth_prior("midas"),
             needles=("midas",)),
        Case(L + "evaluate-images-shapes", "api",
             call=lambda ctx: __import__("reings").evaluate_images([np.zeros((8, 8, 3))], [np.zeros((9, 8, 3))],
                                                                  with_lpips=False), needles=("shape",)),
    ]
    for c in cases:  # the files the calls themselves write (the bad input)
        if c.id.startswith(G):
            c.writes = ("m.ply",)
        elif c.id == L + "load-run-config-garbage":
            c.writes = ("c.toml",)
    return cases


def _ply_names():
    from reings.io.ply import attribute_names

    return attribute_names(0)


def _ply_case(old, new):
    return _read_ply(_ply_edit(old, new))
# }}}


# {{{ the cases: bad data folders (`reings run --data` on a corrupted copy of a valid scene)

def _rot_scale(a):
    a[0, 0:3] *= 2.0  # the first pose's rotation rows scaled: not a rotation
    return a


def _reflect(a):
    a[0, 2] *= -1
    a[0, 7] *= -1
    a[0, 12] *= -1  # one axis of the first pose flipped: a reflection
    return a


def _hwf(a, v):
    a[:, 4] = v
    return a


def _far_before_near(a):
    a[:, 15], a[:, 16] = 10.0, 1.0
    return a


def _with(a, idx, value):
    a[idx] = value
    return a


LLFF_CORRUPT = [
    ("poses-missing", _remove("poses_bounds.npy"), ["cannot detect"]),
    ("poses-empty-file", _replace_file(".", -1, b""), ["poses_bounds.npy"]),
    ("poses-garbage", _replace_file(".", -1, b"\x93NUMPY garbage" * 9), ["poses_bounds.npy"]),
    ("poses-truncated", lambda ctx, d: truncate(os.path.join(d, "poses_bounds.npy")), ["poses_bounds.npy"]),
    ("poses-15-columns", _edit_npy("poses_bounds.npy", lambda a: a[:, :15]), ["poses_bounds.npy", "(N, 17)"]),
    ("poses-1d", _edit_npy("poses_bounds.npy", lambda a: a.ravel()), ["poses_bounds.npy", "(N, 17)"]),
    ("poses-nan", _edit_npy("poses_bounds.npy", lambda a: _with(a, (1, 3), np.nan)),
     ["poses_bounds.npy row 1", "non-finite"]),
    ("bounds-inf", _edit_npy("poses_bounds.npy", lambda a: _with(a, (2, 16), np.inf)),
     ["poses_bounds.npy row 2", "non-finite"]),
    ("poses-complex", _edit_npy("poses_bounds.npy", lambda a: a + 1e-3j), ["poses_bounds.npy", "complex"]),
    ("poses-strings", _edit_npy("poses_bounds.npy", lambda a: a.astype(str)), ["poses_bounds.npy", "real numbers"]),
    ("poses-object", lambda ctx, d: np.save(os.path.join(d, "poses_bounds.npy"), np.array([None, 1], dtype=object),
                                            allow_pickle=True), ["poses_bounds.npy"]),
    ("poses-fewer-than-images", _edit_npy("poses_bounds.npy", lambda a: a[:9]), ["9 poses but 10 images"]),
    ("poses-none", _edit_npy("poses_bounds.npy", lambda a: a[:0]), ["0 poses but 10 images"]),
    ("hwf-negative", _edit_npy("poses_bounds.npy", lambda a: _hwf(a, -1.0)), ["poses_bounds.npy row 0", "hwf"]),
    ("hwf-aspect", _edit_npy("poses_bounds.npy", lambda a: _with(a, (slice(None), 9), 999.0)), ["row 0", "aspect"]),
    ("rotation-scaled", _edit_npy("poses_bounds.npy", _rot_scale), ["row 0", "rotation"]),
    ("rotation-reflection", _edit_npy("poses_bounds.npy", _reflect), ["row 0", "rotation"]),
    ("bounds-far-before-near", _edit_npy("poses_bounds.npy", _far_before_near), ["poses_bounds.npy", "bounds"]),
    ("bounds-negative", _edit_npy("poses_bounds.npy", lambda a: _with(a, (slice(None), 15), -1.0)),
     ["poses_bounds.npy", "bounds"]),
    ("images-missing", _remove("images_8"), ["images_8"]),
    ("images-empty", lambda ctx, d: [os.unlink(p) for p in _files(d, "images_8")], ["images_8", "no image files"]),
    ("png-truncated", _replace_file("images_8", 1, lambda b: b[: len(b) // 2]), ["image001.png", "truncated PNG"]),
    ("png-empty", _replace_file("images_8", 1, b""), ["image001.png", "empty"]),
    ("png-is-text", _replace_file("images_8", 1, b"just some text\n"), ["image001.png", "not a PNG"]),
    ("png-wrong-aspect", _replace_file("images_8", 1, lambda b: _png_bytes(48, 48)), ["image001.png", "aspect"]),
    ("png-grey", _replace_file("images_8", 1, lambda b: _png_bytes(36, 48, 1)), []),
    ("png-16-bit", _replace_file("images_8", 1, lambda b: _png_bytes(36, 48, 3, np.uint16)), []),
    ("png-bomb-header", _replace_file("images_8", 1, lambda b: _patch_png_size(b, 100000, 75000)), ["image001.png"]),
    ("png-a-folder", lambda ctx, d: os.makedirs(os.path.join(d, "images_8", "image010.png")), []),
    ("png-tiny", lambda ctx, d: [open(p, "wb").write(_png_bytes(3, 4)) for p in _files(d, "images_8")], []),
]
LLFF_OK = ("png-grey", "png-16-bit", "png-tiny", "png-a-folder")


DTU_CORRUPT = [
    ("cameras-missing", _remove("cameras_sphere.npz"), ["cannot detect"]),
    ("cameras-garbage", _replace_file(".", 0, b"PK\x03\x04 garbage"), ["cameras_sphere.npz"]),
    ("cameras-truncated", lambda ctx, d: truncate(os.path.join(d, "cameras_sphere.npz")), ["cameras_sphere.npz"]),
    ("world-mat-nan", _edit_npz("cameras_sphere.npz", lambda z: z.update(world_mat_3=np.full((4, 4), np.nan))),
     ["world_mat_3", "non-finite"]),
    ("world-mat-object", lambda ctx, d: _save_npz_object(d), ["world_mat_0", "cannot read"]),
    ("world-mat-3x3", _edit_npz("cameras_sphere.npz", lambda z: z.update(world_mat_3=np.eye(3))),
     ["world_mat_3", "shape (3, 3)"]),
    ("world-mat-singular", _edit_npz("cameras_sphere.npz", lambda z: z.update(world_mat_3=np.zeros((4, 4)))),
     ["world_mat_3", "singular"]),
    ("world-mat-strings", _edit_npz("cameras_sphere.npz", lambda z: z.update(world_mat_3=np.full((4, 4), "1"))),
     ["world_mat_3", "real numbers"]),
    ("world-mat-complex", _edit_npz("cameras_sphere.npz", lambda z: z.update(world_mat_3=np.eye(4) * 1j)),
     ["world_mat_3", "real numbers"]),
    ("world-mat-count", _edit_npz("cameras_sphere.npz", lambda z: z.pop("world_mat_48")), ["48 cameras but 49 images"]),
    ("world-mat-gap", _edit_npz("cameras_sphere.npz", lambda z: z.update(world_mat_49=z.pop("world_mat_5"))),
     ["world_mat_5"]),
    ("scale-mat-strings", _edit_npz("cameras_sphere.npz", lambda z: z.update(scale_mat_0=np.full((4, 4), "a"))),
     ["scale_mat_0", "real numbers"]),
    ("mask-wrong-aspect", _replace_file("mask", 4, lambda b: _png_bytes(64, 64)), ["000004.png", "aspect"]),
    ("mask-count", _remove_nth("mask", 4), ["mask", "48 masks but 49 images"]),
    ("mask-truncated", _replace_file("mask", 4, lambda b: b[: len(b) // 2]), ["000004.png", "truncated"]),
    ("image-wrong-aspect", _replace_file("image", 4, lambda b: _png_bytes(48, 48)), ["000004.png", "aspect"]),
    ("image-count", _both(_remove_nth("image", 4), _remove_nth("mask", 4)), ["49 cameras but 48 images"]),
    ("mask-smaller", _replace_file("mask", 4, lambda b: _png_bytes(24, 32)), []),
]
DTU_OK = ("mask-smaller",)


def _save_npz_object(d):
    p = os.path.join(d, "cameras_sphere.npz")
    with np.load(p) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["world_mat_0"] = np.array([None, 1], dtype=object)
    np.savez(p, **arrays)


def _colmap_text(edit):
    """The model rewritten as text, `edit(text of a file name)` applied."""
    def corrupt(ctx, d):
        from reings.data.colmap import read_model

        m = os.path.join(d, "sparse", "0")
        read_model(m).write_text(m)
        for f in ("cameras.bin", "images.bin", "points3D.bin"):
            os.unlink(os.path.join(m, f))
        edit(m)
    return corrupt


def _sub_line(fname, index, fn):
    """Replace the `index`-th data line of a COLMAP text file by fn(line)."""
    def edit(m):
        p = os.path.join(m, fname)
        lines = open(p).read().splitlines()
        data = [i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#")]
        lines[data[index]] = fn(lines[data[index]])
        open(p, "w").write("\n".join(lines) + "\n")
    return edit


def _words(line, **at):
    w = line.split()
    for k, v in at.items():
        w[int(k[1:])] = v
    return " ".join(w)


COLMAP_CORRUPT = [
    ("cameras-garbage", _replace_file("sparse/0", 0, b"\x01\x00garbage"), ["sparse/0"]),
    ("images-missing", _remove("sparse/0/images.bin"), ["images.bin"]),
    ("images-truncated", lambda ctx, d: truncate(os.path.join(d, "sparse/0/images.bin")), ["sparse/0"]),
    ("points-empty", _replace_file("sparse/0", 2, b""), ["sparse/0"]),
    ("image-file-missing", _remove("images/img03.png"), ["img03.png"]),
    ("image-truncated", _replace_file("images", 3, lambda b: b[: len(b) // 2]), ["img03.png", "truncated"]),
    ("fisheye-camera", _colmap_text(_sub_line("cameras.txt", 0, lambda ln: _words(
        ln, w1="OPENCV_FISHEYE") + " 0 0 0 0")), ["OPENCV_FISHEYE"]),
    ("focal-nan", _colmap_text(_sub_line("cameras.txt", 0, lambda ln: _words(ln, w4="nan"))), ["sparse/0"]),
    ("quaternion-nan", _colmap_text(_sub_line("images.txt", 0, lambda ln: _words(ln, w1="nan"))), ["sparse/0"]),
    ("translation-inf", _colmap_text(_sub_line("images.txt", 0, lambda ln: _words(ln, w5="inf"))), ["sparse/0"]),
    ("text-garbage", _colmap_text(_sub_line("images.txt", 0, lambda ln: "this is not a COLMAP line")), ["sparse/0"]),
    ("camera-id-unknown", _colmap_text(_sub_line("images.txt", 0, lambda ln: _words(ln, w8="77"))), ["sparse/0"]),
]


def _bl_frame(k, fn):
    def edit(meta):
        fn(meta["frames"][k])
    return _edit_json("transforms_train.json", edit)


def _set(key, value):
    def fn(d):
        d[key] = value
    return fn


def _pop(key):
    return lambda d: d.pop(key)


BLENDER_CORRUPT = [
    ("json-invalid", _replace_file(".", -1, b"{not json"), ["transforms_train.json", "invalid JSON"]),
    ("json-a-list", _edit_json("transforms_train.json", lambda m: json.dumps([m])), ["transforms_train.json"]),
    ("frames-empty", _edit_json("transforms_train.json", lambda m: m.update(frames=[])), ["transforms_train.json",
                                                                                           "frames"]),
    ("frames-a-dict", _edit_json("transforms_train.json", lambda m: m.update(frames={})), ["transforms_train.json",
                                                                                            "frames"]),
    ("frame-a-string", _edit_json("transforms_train.json", lambda m: m["frames"].__setitem__(3, "r_3")),
     ["transforms_train.json frame 3"]),
    ("file-path-missing", _bl_frame(3, _pop("file_path")), ["transforms_train.json frame 3"]),
    ("matrix-3x3", _bl_frame(3, _set("transform_matrix", np.eye(3).tolist())), ["frame 3", "(4, 4)"]),
    ("matrix-strings", _bl_frame(3, _set("transform_matrix", [["a"] * 4] * 4)), ["frame 3"]),
    ("matrix-nan", _bl_frame(3, _set("transform_matrix", [[float("nan")] * 4] * 4)), ["frame 3", "non-finite"]),
    ("matrix-singular", _bl_frame(3, _set("transform_matrix", np.zeros((4, 4)).tolist())), ["frame 3"]),
    ("angle-missing", _edit_json("transforms_train.json", lambda m: m.pop("camera_angle_x")),
     ["transforms_train.json frame 0", "camera_angle_x"]),
    ("angle-string", _edit_json("transforms_train.json", lambda m: m.update(camera_angle_x="wide")),
     ["transforms_train.json", "camera_angle_x"]),
    ("angle-zero", _edit_json("transforms_train.json", lambda m: m.update(camera_angle_x=0)),
     ["transforms_train.json frame 0"]),
    ("angle-negative", _edit_json("transforms_train.json", lambda m: m.update(camera_angle_x=-1.0)),
     ["transforms_train.json frame 0"]),
    ("image-missing", _remove("train/r_5.png"), ["r_5.png"]),
    ("image-truncated", _replace_file("train", 5, lambda b: b[: len(b) // 2]), ["truncated"]),
]


NERFSTUDIO_CORRUPT = [
    ("json-invalid", _replace_file(".", -1, b"{not json"), ["transforms.json"]),
    ("focal-string", _edit_json("transforms.json", lambda m: m.update(fl_x="big")), ["transforms.json frame 0",
                                                                                     "intrinsics"]),
    ("focal-negative", _edit_json("transforms.json", lambda m: m.update(fl_x=-30.0)), ["transforms.json frame 0"]),
    ("size-zero", _edit_json("transforms.json", lambda m: m.update(w=0)), ["transforms.json frame 0", "w"]),
    ("size-negative", _edit_json("transforms.json", lambda m: m.update(h=-36)), ["transforms.json frame 0", "h"]),
    ("cx-nan", _edit_json("transforms.json", lambda m: m.update(cx=float("nan"))), ["transforms.json frame 0"]),
    ("k4", _edit_json("transforms.json", lambda m: m.update(k4=0.1)), ["k4"]),
    ("fisheye", _edit_json("transforms.json", lambda m: m.update(camera_model="OPENCV_FISHEYE")), ["OPENCV_FISHEYE"]),
    ("same-image-twice", _edit_json("transforms.json", lambda m: m["frames"][1].update(
        file_path=m["frames"][0]["file_path"])), ["transforms.json", "same image"]),
    ("frames-empty", _edit_json("transforms.json", lambda m: m.update(frames=[])), ["transforms.json", "frames"]),
    ("distortion-string", _edit_json("transforms.json", lambda m: m.update(k1="x")), ["transforms.json frame 0"]),
    ("image-missing", _remove("images/frame_00004.png"), ["frame_00004.png"]),
]


def _data_cases():
    cases = []
    for kind, table, ok in (("llff", LLFF_CORRUPT, LLFF_OK), ("dtu", DTU_CORRUPT, DTU_OK), ("colmap", COLMAP_CORRUPT, ()),
                            ("blender", BLENDER_CORRUPT, ()), ("nerfstudio", NERFSTUDIO_CORRUPT, ())):
        for name, corrupt, needles in table:
            cases.append(Case(f"data/{kind}/{name}", "data", run_argv(kind), setup=scene(kind, corrupt),
                              needles=tuple(needles), expect="either" if name in ok else "error",
                              check=finished_run_check, quick=name in ("poses-nan", "world-mat-nan")))
    for name, extra in (("extent-frusta", ("--extent", "frusta")),):
        cases.append(Case(f"data/llff/bounds-far-before-near-{name}", "data", run_argv("llff", *extra),
                          setup=scene("llff", _edit_npy("poses_bounds.npy", _far_before_near)),
                          needles=("poses_bounds.npy", "bounds")))
    cases += [Case(f"control/run-{kind}", "control", run_argv(kind), setup=scene(kind), expect="ok",
                   check=finished_run_check, quick=kind == "llff") for kind in ("llff", "dtu")]
    cases += [Case(f"control/load-{kind}", "control", call=_load(kind), setup=scene(kind), expect="ok",
                   check=_true_cameras(kind)) for kind in SCENE_KINDS]
    return cases


def _load(kind):
    def call(ctx):
        import reings

        return reings.load_scene(ctx.scene_dir, factor=int(dict(zip(FACTOR[kind][::2], FACTOR[kind][1::2])).get(
            "--factor", 8)))
    return call


def _true_cameras(kind):
    """The loaded scene's cameras are the ones the fixture was made with (a silently wrong loader fails)."""
    def check(ctx, sc):
        with np.load(ctx.fx.scene(kind) + ".truth.npz") as z:
            K, V = z["K"], z["viewmat"]
        if len(sc) != len(K):
            return f"{len(sc)} views, not {len(K)}"
        for i, cam in enumerate(sc.cameras):
            if not (np.allclose(cam.K, K[i], rtol=1e-6, atol=1e-6) and np.allclose(cam.viewmat, V[i], atol=1e-6)):
                return f"view {i} ({sc.names[i]}): its camera differs from the true one"
        return None
    return check
# }}}


# {{{ the cases: corrupted run folders, symlinks at outputs

def _unfinish(ctx, d):
    """The finished run made an interrupted one of this sandbox: metrics.json gone (its checkpoints
    stay), checkpoints/run.json naming the sandbox's scene (a run's settings hold the absolute path)."""
    os.unlink(os.path.join(d, "metrics.json"))
    p = os.path.join(d, "checkpoints", "run.json")
    with open(p) as f:
        settings = json.load(f)
    settings["data"] = os.path.abspath(ctx.scene_dir)
    with open(p, "w") as f:
        json.dump(settings, f, indent=1)


def _ckpt(edit):
    def corrupt(ctx, d):
        _unfinish(ctx, d)
        p = os.path.join(d, "checkpoints", "3dgs.npz")
        with np.load(p) as z:
            arrays = {k: z[k] for k in z.files}
        r = edit(arrays)
        np.savez(p, **(r if isinstance(r, dict) else arrays))
    return corrupt


def _put(rel, data):
    def corrupt(ctx, d):
        v = data() if callable(data) else data
        with open(os.path.join(d, rel), "wb" if isinstance(v, bytes) else "w") as f:
            f.write(v)
    return corrupt


def _cams(edit):
    return _edit_json("cameras.json", edit)


def _runfolder_cases():
    F = "runfolder/"
    rerun = RERUN_ARGV
    render = (*RENDER, "--frames", "2", "--size", "8x6", "--frames-dir", "{out}/f")
    export = ("export", "{run}", "--out", "{out}")
    inria = ("export", "{run}", "--format", "inria", "--out", "{out}")
    cases = [
        Case(F + "rerun-finished", "runfolder", rerun, setup=finished(), needles=("run already holds a finished run",),
             writes=(), quick=True),
        Case(F + "overwrite-with-bad-option", "runfolder", rerun + ("--overwrite", "--seed", "-1"), setup=finished(),
             needles=("--seed",), writes=()),
        Case(F + "overwrite-with-corrupt-scene", "runfolder", rerun + ("--overwrite",),
             setup=finished(lambda ctx, d: truncate(_files(ctx.scene_dir, "images_8")[2])),
             needles=("image002.png",), writes=()),
        Case(F + "overwrite-with-missing-prior", "runfolder", rerun + ("--overwrite", "--depth-prior", "onnx:none.onnx"),
             setup=finished(), needles=("none.onnx",), writes=()),
        Case(F + "run-json-garbage", "runfolder", rerun,
             setup=finished(_both(_unfinish, _put("checkpoints/run.json", "{ not json"))),
             needles=("run.json", "unreadable"), writes=()),
        Case(F + "run-json-a-list", "runfolder", rerun, setup=finished(_both(_unfinish, _put("checkpoints/run.json", "[]"))),
             needles=("run.json", "unreadable"), writes=()),
        Case(F + "run-json-other-settings", "runfolder", rerun + ("--seed", "5"), setup=finished(_unfinish),
             needles=("other settings", "seed"), writes=()),
        Case(F + "checkpoint-truncated", "runfolder", rerun,
             setup=finished(_both(_unfinish, lambda ctx, d: truncate(os.path.join(d, "checkpoints", "3dgs.npz")))),
             needles=("3dgs.npz", "checkpoint"), writes=("run",)),
        Case(F + "checkpoint-garbage", "runfolder", rerun,
             setup=finished(_both(_unfinish, _put("checkpoints/3dgs.npz", b"PK\x03\x04" + b"\x00" * 64))),
             needles=("3dgs.npz", "checkpoint"), writes=("run",)),
        Case(F + "checkpoint-missing-arrays", "runfolder", rerun,
             setup=finished(_ckpt(lambda a: {k: v for k, v in a.items() if not k.startswith("param/means")})),
             needles=("3dgs.npz",), writes=("run",)),
        Case(F + "checkpoint-wrong-shapes", "runfolder", rerun,
             setup=finished(_ckpt(lambda a: a.update({"param/means": a["param/means"][:, :2]}))),
             needles=("3dgs.npz",), writes=("run",)),
        Case(F + "checkpoint-rows-differ", "runfolder", rerun,
             setup=finished(_ckpt(lambda a: a.update({"param/quats": a["param/quats"][:-5]}))),
             needles=("3dgs.npz",), writes=("run",)),
        Case(F + "checkpoint-object-array", "runfolder", rerun,
             setup=finished(_ckpt(lambda a: a.update(iteration=np.array([None], dtype=object)))),
             needles=("3dgs.npz",), writes=("run",)),
        Case(F + "config-toml-garbage", "runfolder", ("run", "--config", "{run}/config.toml", "--out", "{out}"),
             setup=finished(_put("config.toml", "method = \n")), needles=("config.toml",)),
        Case(F + "config-toml-bad-value", "runfolder", ("run", "--config", "{run}/config.toml", "--out", "{out}"),
             setup=finished(_put("config.toml", "views = 0\n")), needles=("config.toml", "views")),
        Case(F + "render-ply-truncated", "runfolder", render,
             setup=finished(lambda ctx, d: truncate(os.path.join(d, "gaussians.ply"))),
             needles=("gaussians.ply", "truncated"), quick=True),
        Case(F + "render-ply-missing", "runfolder", render, setup=finished(_remove("gaussians.ply")),
             needles=("no gaussians.ply",)),
        Case(F + "render-ply-garbage", "runfolder", render, setup=finished(_put("gaussians.ply", b"\x00" * 100)),
             needles=("gaussians.ply",)),
        Case(F + "render-ply-empty-model", "runfolder", render, setup=finished(_put(
            "gaussians.ply", lambda: PLY_HEAD + b"element vertex 0\n" + b"".join(
                b"property float %s\n" % a.encode() for a in _ply_names()) + b"end_header\n")), expect="either",
             needles=("gaussians.ply",)),
        Case(F + "render-cameras-garbage", "runfolder", render, setup=finished(_put("cameras.json", "{not json")),
             needles=("cameras.json",)),
        Case(F + "render-cameras-empty", "runfolder", render, setup=finished(_put("cameras.json", "[]")),
             needles=("cameras.json",)),
        Case(F + "render-cameras-a-dict", "runfolder", render, setup=finished(_put("cameras.json", '{"a": 1}')),
             needles=("cameras.json",)),
        Case(F + "render-cameras-missing", "runfolder", render, setup=finished(_remove("cameras.json")),
             needles=("cameras.json",)),
        Case(F + "render-camera-huge", "runfolder", (*RENDER, "--frames", "1",
                                                     "--frames-dir", "{out}/f"),
             setup=finished(_cams(lambda c: [e.update(width=1000000, height=750000) for e in c])),
             needles=("cameras.json",), timeout=120),
        Case(F + "render-camera-nan", "runfolder", render,
             setup=finished(_cams(lambda c: c[0].update(fx=float("nan")))), needles=("cameras.json", "fx")),
        Case(F + "render-camera-not-rotation", "runfolder", render,
             setup=finished(_cams(lambda c: c[0].update(rotation=[[2, 0, 0], [0, 1, 0], [0, 0, 1]]))),
             needles=("cameras.json", "rotation")),
        Case(F + "render-camera-float-width", "runfolder", render,
             setup=finished(_cams(lambda c: c[0].update(width=48.5))), needles=("cameras.json", "width")),
        Case(F + "render-camera-bool-width", "runfolder", render,
             setup=finished(_cams(lambda c: c[0].update(width=True))), needles=("cameras.json", "width")),
        Case(F + "export-metrics-garbage", "runfolder", export, setup=finished(_put("metrics.json", "{oops")),
             needles=("metrics.json",)),
        Case(F + "export-metrics-a-list", "runfolder", export, setup=finished(_put("metrics.json", "[]")),
             needles=("metrics.json",)),
        Case(F + "export-metrics-missing", "runfolder", export, setup=finished(_remove("metrics.json")),
             needles=("metrics.json",)),
        Case(F + "export-iterations-garbage", "runfolder", inria, setup=finished(_edit_json(
            "metrics.json", lambda m: m["run_config"].update(iterations="lots"))), expect="either",
             needles=("metrics.json",)),
        Case(F + "export-inria-cameras-garbage", "runfolder", inria, setup=finished(_put("cameras.json", "[{}]")),
             needles=("cameras.json",)),
        Case(F + "export-ply-truncated", "runfolder", export,
             setup=finished(lambda ctx, d: truncate(os.path.join(d, "gaussians.ply"))), needles=("gaussians.ply",)),
        Case(F + "view-ply-garbage", "runfolder", ("view", "{run}"), setup=finished(_put("gaussians.ply", b"ply\n\x00")),
             needles=("gaussians.ply",), timeout=30),
        Case(F + "view-cameras-missing", "runfolder", ("view", "{run}"), setup=finished(_remove("cameras.json")),
             needles=("cameras.json",), timeout=30),
        Case(F + "view-cameras-garbage", "runfolder", ("view", "{run}"), setup=finished(_put("cameras.json", "[1]")),
             needles=("cameras.json",), timeout=30),
        Case(F + "eval-table-only-corrupt", "runfolder", ("eval", "--table-only", "--out", "{root}/grid"),
             setup=finished(lambda ctx, d: (os.makedirs(ctx.p("grid", "llff", "3dgs", "2views")),
                                            os.replace(d, ctx.p("grid", "llff", "3dgs", "2views", "fern")),
                                            ctx.write("grid/llff/3dgs/2views/fern/metrics.json", "{oops"))),
             expect="either", needles=("metrics.json",), writes=("grid/results.json", "grid/results.md")),
    ]
    return cases


def _symlink_cases():
    S = "symlink/"
    run = run_argv("llff")
    ok = all_of(finished_run_check, victim_intact)

    def planted(rel):
        return seq(scene("llff"), victim, symlink("victim.txt", f"out/{rel}"))

    def planted_dir(rel):
        return seq(scene("llff"), victim, write("elsewhere/view000.png", VICTIM_TEXT), symlink("elsewhere", f"out/{rel}"))

    cases = [Case(S + f"out-{name}", "symlink", run, setup=planted(name), expect="ok", check=ok,
                  quick=name == "gaussians.ply")
             for name in ("gaussians.ply", "config.toml", "cameras.json", "psnr_vs_time.svg")]
    cases += [
        Case(S + "out-metrics.json", "symlink", run, setup=planted("metrics.json"), needles=("metrics.json",), writes=()),
        Case(S + "out-checkpoints-run.json", "symlink", run, setup=planted("checkpoints/run.json"), expect="either",
             check=ok, needles=("run.json",)),
        Case(S + "out-checkpoint-tmp", "symlink", run, setup=planted("checkpoints/3dgs.npz.tmp.npz"), expect="ok",
             check=ok),
        Case(S + "out-render-png", "symlink", run, setup=planted("renders/view000.png"), expect="ok", check=ok),
        Case(S + "out-renders-folder", "symlink", run, setup=planted_dir("renders"), expect="either", check=ok,
             needles=("renders",)),
        Case(S + "out-depths-folder", "symlink", run, setup=planted_dir("depths"), expect="either", check=ok,
             needles=("depths",)),
        Case(S + "out-checkpoints-folder", "symlink", run, setup=planted_dir("checkpoints"), expect="either",
             check=ok, needles=("checkpoints",)),
        Case(S + "previous-run-folder", "symlink", RERUN_ARGV + ("--overwrite",),
             setup=seq(finished(), write("elsewhere/metrics.json", VICTIM_TEXT), symlink("elsewhere", "run/.previous-run")),
             needles=(".previous-run",), writes=()),
        Case(S + "export-point-cloud", "symlink", ("export", "{run}", "--out", "{out}", "--overwrite"),
             setup=seq(finished(), victim, symlink("victim.txt", "out/point_cloud.ply")), expect="ok",
             check=lambda ctx, out: victim_intact(ctx)),
        Case(S + "render-video", "symlink", (*RENDER, "--frames", "2", "--size", "8x6", "--out", "{out}/v.mp4"),
             setup=seq(finished(), mkdir("elsewhere"), symlink("elsewhere/v.mp4", "out/v.mp4")), expect="ok",
             check=lambda ctx, out: None if not os.listdir(ctx.p("elsewhere")) else "wrote through the symlink"),
        Case(S + "render-frame", "symlink", (*RENDER, "--frames", "2", "--size", "8x6", "--frames-dir",
                                             "{out}/f", "--overwrite"),
             setup=seq(finished(), victim, symlink("victim.txt", "out/f/frame_0000.png")), expect="ok",
             check=lambda ctx, out: victim_intact(ctx)),
    ]
    return cases
# }}}


# {{{ the cases: a full disk, kills

# `python -c FSIZE_WRAPPER ARGV` runs `reings ARGV` with the process's file-size limit (RLIMIT_FSIZE,
# which fails a write as a full disk does) set to $REINGS_TEST_FSIZE_LIMIT bytes at the first write of a
# file whose name or absolute path matches $REINGS_TEST_FSIZE_AT (the OpenCL compiler writes its own
# files before; the caches of the depth prior and the SfM box are .npz files too)
FSIZE_WRAPPER = r"""
import fnmatch, os, resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)   # the write fails with EFBIG instead of killing the process
AT, LIMIT = os.environ["REINGS_TEST_FSIZE_AT"], int(os.environ["REINGS_TEST_FSIZE_LIMIT"])
import reings.io.files as files, reings.outputs as outputs, reings.video as video

def arm(path):
    p = os.path.abspath(os.fspath(path))
    if fnmatch.fnmatch(os.path.basename(p), AT) or fnmatch.fnmatch(p, AT):
        resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))

def wrap(module, name, at):
    real = getattr(module, name)
    def limited(*a, **k):
        arm(a[at])
        return real(*a, **k)
    setattr(module, name, limited)

wrap(files, "atomic_write", 0)
wrap(outputs, "write_png_atomic", 0)
wrap(video, "write_video", 0)
from reings.cli import main
sys.exit(main(sys.argv[1:]))
"""


def fsize_runner(ctx, argv, env, timeout):
    return cli_subprocess(argv, ctx.root, env, timeout, prefix=[sys.executable, "-c", FSIZE_WRAPPER])


def _no_temps(root) -> str | None:
    left = [os.path.relpath(os.path.join(d, n), root) for d, _, ns in os.walk(root) for n in ns
            if n.startswith(".tmp-")]
    return f"temporary files left: {left[:3]}" if left else None


def resume_finishes(ctx, argv):
    """After a refused write: no temporary file left, and the same command without the limit
    finishes the run."""
    why = _no_temps(ctx.root)
    if why:
        return "unclear", why
    rc, _, err, _ = cli_subprocess(argv, ctx.root, None, 600)
    if rc != 0:
        return "wrong", f"the rerun without the limit failed: {err.strip()[-300:]}"
    why = finished_run_check(ctx)
    return ("wrong", f"the rerun: {why}") if why else None


def no_temps_after(ctx, argv):
    why = _no_temps(ctx.root)
    return ("unclear", why) if why else None


def _disk_cases():
    D = "disk/"
    run = run_argv("llff", "--checkpoint-every", "1", "--checkpoint-seconds", "0")

    def case(name, argv, at, limit, needles, setup=scene("llff"), after=resume_finishes, **kw):
        return Case(D + name, "disk", argv, setup=setup, needles=needles, after=after, runner=fsize_runner,
                    env={"REINGS_TEST_FSIZE_AT": at, "REINGS_TEST_FSIZE_LIMIT": str(limit)}, timeout=300, **kw)

    render = (*RENDER, "--frames", "3", "--size", "16x12")
    return [
        case("run-checkpoint", run, "*/checkpoints/*.npz", 4096, ("writing", "checkpoints")),
        case("run-config", run, "config.toml", 100, ("writing", "config.toml")),
        case("run-cameras", run, "cameras.json", 100, ("writing", "cameras.json")),
        case("run-render-png", run, "image*.png", 100, ("renders", "image")),
        case("run-gaussians-ply", run, "gaussians.ply", 4096, ("writing", "gaussians.ply"), quick=True),
        case("run-metrics", run, "metrics.json", 1000, ("writing", "metrics.json")),
        case("overwrite-finished-run", run_argv("llff", "--out", "{run}", "--overwrite", "--seed", "1"),
             "*/checkpoints/*.npz", 4096,
             ("writing", "checkpoints"), setup=finished(), after=no_temps_after, writes=()),
        case("export-ply", ("export", "{run}", "--out", "{out}"), "point_cloud.ply", 4096,
             ("writing", "point_cloud.ply"), setup=finished(), after=no_temps_after),
        case("render-frames", render + ("--frames-dir", "{out}/f"), "frame_*.png", 100, ("frame_0000.png",),
             setup=finished(), after=no_temps_after),
        case("render-video", render + ("--out", "{out}/v.avi"), "v.avi", 1000, ("v.avi",),
             setup=seq(finished(), mkdir("out")), after=no_temps_after),
    ]


def _kill_runner(moment):
    pattern, delay, signame = KILL_MOMENTS[moment]

    def runner(ctx, argv, env, timeout):
        import glob

        sig = getattr(signal, signame)
        wait = float(np.random.default_rng(moment).uniform(0.0, 1.5)) if delay == "random" else delay
        p = subprocess.Popen([sys.executable, "-m", "reings.cli", *argv], cwd=ctx.root, env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, errors="replace",
                             stdin=subprocess.DEVNULL)
        try:
            t = time.time()
            while not glob.glob(os.path.join(ctx.out, pattern)) and p.poll() is None and time.time() - t < timeout:
                time.sleep(0.01)
            time.sleep(wait)
            if p.poll() is None:
                p.send_signal(sig)
            _, err = p.communicate(timeout=120)
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()
        if sig == signal.SIGINT and p.returncode not in (0, 130):
            return p.returncode, "", err, False
        if p.returncode == 130 and not err.strip().endswith("reings: interrupted"):
            return 1, "", err + "\n(no 'reings: interrupted' line)", False
        rc, out, err, to = cli_subprocess(argv, ctx.root, env, timeout)
        if rc == 2 and "already holds a finished run" in err:  # the kill came after metrics.json
            rc = 0
        return rc, out, err, to
    return runner


def same_as_reference(ctx, _out=None):
    ref = ctx.fx.kill_reference()
    want = json.load(open(os.path.join(ref, "metrics.json")))
    got = json.load(open(os.path.join(ctx.out, "metrics.json")))
    if got["mean"] != want["mean"] or got["gaussians"] != want["gaussians"]:
        return f"resumed run differs: {got['mean']} vs {want['mean']}"
    if open(os.path.join(ctx.out, "gaussians.ply"), "rb").read() != open(os.path.join(ref, "gaussians.ply"), "rb").read():
        return "gaussians.ply differs from the uninterrupted run's"
    if sorted(os.listdir(os.path.join(ctx.out, "renders"))) != sorted(os.listdir(os.path.join(ref, "renders"))):
        return "renders/ differs"
    return _no_temps(ctx.out)


def _kill_cases():
    return [Case(f"kill/{m[2].lower()}-at-{m[0].split('/')[-1].replace('*', 'any')}", "kill", KILL_ARGS + ("--out", "{out}"),
                 expect="ok", check=same_as_reference, runner=_kill_runner(i), timeout=600, quick=i == 0)
            for i, m in enumerate(KILL_MOMENTS)]
# }}}


def all_cases() -> list[Case]:
    cases = (_cli_run_cases() + _cli_other_cases() + _data_cases() + _api_run_cases() + _api_other_cases()
             + _runfolder_cases() + _symlink_cases() + _disk_cases() + _kill_cases())
    ids = [c.id for c in cases]
    assert len(ids) == len(set(ids)), sorted(i for i in ids if ids.count(i) > 1)
    return cases


_BY_ID: dict = {}


def case_by_id(case_id: str) -> Case:
    if not _BY_ID:
        _BY_ID.update((c.id, c) for c in all_cases())
    return _BY_ID[case_id]


def cases(categories=None, quick: bool = False) -> list[Case]:
    return [c for c in all_cases() if (categories is None or c.category in categories) and (c.quick or not quick)]

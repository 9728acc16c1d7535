"""The package's structure, read from its source with `ast`: nothing here imports `reings`.

Checked (issue 11, "Done when"):
  (a) no import cycle among the modules of `reings/`;
  (b) no module under `reings/backends/` imports an engine module (`reings.train`, `densify`,
      `state`, `optim`, `losses`, `pipeline`, `evaluate`);
  (c) no module of `reings/` outside `reings/backends/` imports `pyopencl`, in any form;
  (d) no function or method in `reings/` is longer than `MAX_FUNCTION_LINES` lines;
  (e) `reings/` has exactly one training loop, in `fit` of `reings/train.py`.

The import graph (a, b): one node per module (`reings/x/__init__.py` is `reings.x`). Every
`import` and `from ... import` statement counts wherever it is written (module level, inside a
function, inside `try`), because a function-local import still runs and still closes a cycle at
run time; only the body of `if TYPE_CHECKING:` is skipped (it never runs). Relative imports are
resolved against the importing module's package. `import a.b.c` is an edge to the longest prefix
of `a.b.c` that is a module of the package; `from p import n` is an edge to `p.n` where that is a
module, else to `p` (a name defined in `p`). Importing a submodule also runs its parent packages'
`__init__`, but those edges are left out: with them every package would be in a cycle with each
submodule it imports. Imports through `importlib.import_module("...")` strings (the lazy names of
`reings/__init__.py`) are not part of the graph.

Each check has a self-test on a small synthetic package written to `tmp_path`, so a checker that
stopped finding its violation would fail here, not pass silently.
"""
from __future__ import annotations

import ast
from collections import deque
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "reings"

MAX_FUNCTION_LINES = 120
BACKENDS = "reings.backends"
ENGINE_MODULES = ("reings.train", "reings.densify", "reings.state", "reings.optim", "reings.losses",
                  "reings.pipeline", "reings.evaluate")
OPENCL_MODULE = "pyopencl"
# the one training loop: (path relative to the repository root, function name)
TRAINING_LOOP_HOME = ("reings/train.py", "fit")


# {{{ reading the package


@dataclass(frozen=True)
class Module:
    name: str  # dotted, e.g. "reings.data.types"
    path: Path
    is_package: bool  # an __init__.py

    @property
    def package(self) -> str:
        """The package its relative imports resolve against."""
        return self.name if self.is_package else self.name.rpartition(".")[0]

    @property
    def rel(self) -> str:
        return self.path.as_posix()


def package_modules(root: Path = ROOT, package: str = PACKAGE) -> dict[str, Module]:
    """Every module of `root/package` by dotted name (files in folders without `__init__.py` too)."""
    out = {}
    for path in sorted((root / package).rglob("*.py")):
        rel = path.relative_to(root)
        parts = list(rel.with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        if is_pkg:
            parts.pop()
        out[".".join(parts)] = Module(".".join(parts), rel, is_pkg)
    return out


def parse(root: Path, mod: Module) -> ast.Module:
    return ast.parse((root / mod.path).read_text(encoding="utf-8"), filename=str(mod.path))


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def import_nodes(tree: ast.AST):
    """Every `import` / `from ... import` node, at any depth, outside `if TYPE_CHECKING:` bodies."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            children = node.orelse
        else:
            children = list(ast.iter_child_nodes(node))
        stack.extend(children)


@dataclass(frozen=True)
class Edge:
    src: str
    dst: str
    line: int


def _longest_module_prefix(dotted: str, modules: dict[str, Module]) -> str | None:
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        cand = ".".join(parts[:k])
        if cand in modules:
            return cand
    return None


def _absolute_from(mod: Module, node: ast.ImportFrom) -> str:
    """The absolute dotted name of a `from X import ...` source."""
    if node.level == 0:
        return node.module or ""
    base = mod.package.split(".")
    if node.level > 1:
        base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imported_names(mod: Module, node) -> list[str]:
    """Absolute dotted names a node imports (`from p import a, b` gives `p.a`, `p.b`)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    src = _absolute_from(mod, node)
    return [f"{src}.{a.name}" if a.name != "*" else src for a in node.names] or [src]


def import_edges(root: Path = ROOT, package: str = PACKAGE) -> tuple[dict[str, Module], list[Edge]]:
    """(modules, edges between modules of the package) as described in the module docstring."""
    modules = package_modules(root, package)
    edges = []
    for mod in modules.values():
        for node in import_nodes(parse(root, mod)):
            if isinstance(node, ast.Import):
                targets = [_longest_module_prefix(a.name, modules) for a in node.names]
            else:
                src = _absolute_from(mod, node)
                targets = []
                for a in node.names:
                    sub = f"{src}.{a.name}"
                    targets.append(sub if sub in modules else _longest_module_prefix(src, modules))
            for t in targets:
                if t is not None and t != mod.name:
                    edges.append(Edge(mod.name, t, node.lineno))
    return modules, edges


# }}}

# {{{ (a) cycles


def strongly_connected(nodes, succ) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative), each sorted."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = 0
    for start in sorted(nodes):
        if start in index:
            continue
        work = [(start, iter(sorted(succ.get(start, ()))))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(succ.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    out.append(sorted(comp))
    return out


def shortest_cycle(start: str, succ, within: set) -> list[str]:
    """A shortest path start -> ... -> start inside `within` (breadth first)."""
    prev: dict[str, str] = {}
    queue = deque([start])
    while queue:
        v = queue.popleft()
        for w in sorted(succ.get(v, ())):
            if w == start:
                path = [v]
                while path[-1] != start:
                    path.append(prev[path[-1]])
                return path[::-1] + [start]
            if w in within and w not in prev:
                prev[w] = v
                queue.append(w)
    return []


def import_cycles(root: Path = ROOT, package: str = PACKAGE) -> list[str]:
    """One message per import cycle (strongly connected component): its modules and one
    shortest cycle through the first of them, each edge with the importing line."""
    modules, edges = import_edges(root, package)
    succ: dict[str, set] = {}
    where: dict[tuple, int] = {}
    for e in edges:
        succ.setdefault(e.src, set()).add(e.dst)
        where.setdefault((e.src, e.dst), e.line)
    msgs = []
    for comp in strongly_connected(modules, succ):
        if len(comp) == 1:
            continue
        cyc = shortest_cycle(comp[0], succ, set(comp))
        steps = " -> ".join(
            f"{a} ({modules[a].rel}:{where[(a, b)]})" for a, b in zip(cyc, cyc[1:])) + f" -> {cyc[-1]}"
        msgs.append(f"cycle of {len(comp)} modules {comp}: {steps}")
    return msgs


def test_no_import_cycle():
    cycles = import_cycles()
    assert not cycles, "import cycles in reings/:\n  " + "\n  ".join(cycles)


# }}}

# {{{ (b) backends do not import the engine


def backend_engine_imports(root: Path = ROOT, package: str = PACKAGE) -> list[str]:
    modules, edges = import_edges(root, package)
    bad = []
    for e in edges:
        if e.src == BACKENDS or e.src.startswith(BACKENDS + "."):
            hit = [m for m in ENGINE_MODULES if e.dst == m or e.dst.startswith(m + ".")]
            if hit:
                bad.append((modules[e.src].rel, e.line, e.dst))
    return [f"{rel}:{line} imports {dst}" for rel, line, dst in sorted(set(bad))]


def test_backends_do_not_import_the_engine():
    bad = backend_engine_imports()
    assert not bad, ("reings/backends/ must not import the engine modules "
                     f"{', '.join(ENGINE_MODULES)}:\n  " + "\n  ".join(bad))


# }}}

# {{{ (c) pyopencl only under reings/backends/

# calls that import a module named by a string: __import__("x"), importlib.import_module("x"),
# importlib.util.find_spec("x"), pytest.importorskip("x")
_IMPORT_CALLS = ("__import__", "import_module", "find_spec", "importorskip")


def _names_opencl(s) -> bool:
    return isinstance(s, str) and (s == OPENCL_MODULE or s.startswith(OPENCL_MODULE + "."))


def _is_sys_modules(node) -> bool:
    return isinstance(node, ast.Attribute) and node.attr == "modules" and isinstance(node.value, ast.Name) \
        and node.value.id == "sys"


def opencl_uses(tree: ast.AST, mod: Module) -> list[str]:
    """Lines of `mod` that import pyopencl: import statements (TYPE_CHECKING ones included, for
    this check), import calls with a literal name, and `sys.modules["pyopencl..."]` lookups."""
    hits = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            if any(_names_opencl(n) for n in imported_names(mod, node)):
                hits.append(node.lineno)
        elif isinstance(node, ast.Call):
            f = node.func
            fname = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
            args = [a.value for a in node.args if isinstance(a, ast.Constant)]
            if fname in _IMPORT_CALLS and any(_names_opencl(a) for a in args[:1]):
                hits.append(node.lineno)
            if fname == "get" and isinstance(f, ast.Attribute) and _is_sys_modules(f.value) and \
                    any(_names_opencl(a) for a in args[:1]):
                hits.append(node.lineno)
        elif isinstance(node, ast.Subscript) and _is_sys_modules(node.value):
            sl = node.slice
            if isinstance(sl, ast.Constant) and _names_opencl(sl.value):
                hits.append(node.lineno)
    return sorted(set(hits))


def opencl_outside_backends(root: Path = ROOT, package: str = PACKAGE) -> list[str]:
    bad = []
    for mod in package_modules(root, package).values():
        if mod.name == BACKENDS or mod.name.startswith(BACKENDS + "."):
            continue
        lines = (root / mod.path).read_text(encoding="utf-8").splitlines()
        bad += [f"{mod.rel}:{ln}: {lines[ln - 1].strip()}" for ln in opencl_uses(parse(root, mod), mod)]
    return bad


def test_pyopencl_only_in_backends():
    bad = opencl_outside_backends()
    assert not bad, "pyopencl imported outside reings/backends/:\n  " + "\n  ".join(bad)


# }}}

# {{{ (d) function length


def long_functions(root: Path = ROOT, package: str = PACKAGE, limit: int = MAX_FUNCTION_LINES) -> list[str]:
    """`def` to last line (decorators not counted; nested functions count in their parent too)."""
    out = []
    for mod in package_modules(root, package).values():
        tree = parse(root, mod)
        for node, qual in _functions(tree):
            n = node.end_lineno - node.lineno + 1
            if n > limit:
                out.append(f"{qual} ({mod.rel}:{node.lineno}): {n} lines")
    return out


def _functions(tree, prefix=""):
    """(node, qualified name) of every function and method, nested ones included."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            qual = prefix + node.name
            yield node, qual
            yield from _functions(node, qual + ".")
        elif isinstance(node, ast.ClassDef):
            yield from _functions(node, prefix + node.name + ".")
        else:
            yield from _functions(node, prefix)


def test_no_long_functions():
    bad = long_functions()
    assert not bad, f"functions longer than {MAX_FUNCTION_LINES} lines:\n  " + "\n  ".join(bad)


# }}}

# {{{ (e) one training loop


def _mentions_iteration(node: ast.AST, aliases: frozenset = frozenset()) -> bool:
    """Whether an expression names an iteration count: an identifier containing "iter"
    (`cfg.iterations`, `state.iteration`, `n_iters`) or a local name assigned from one."""
    for sub in ast.walk(node):
        name = sub.id if isinstance(sub, ast.Name) else sub.attr if isinstance(sub, ast.Attribute) else ""
        if "iter" in name.lower() or (isinstance(sub, ast.Name) and sub.id in aliases):
            return True
    return False


def _iteration_aliases(func: ast.AST) -> frozenset:
    """Local names of `func` assigned (directly or through each other) from an iteration count,
    e.g. `last = cfg.iterations + 1` or `stop = last`."""
    assigns = [(t.id, n.value) for n in ast.walk(func) if isinstance(n, ast.Assign)
               for t in n.targets if isinstance(t, ast.Name)]
    assigns += [(n.target.id, n.value) for n in ast.walk(func)
                if isinstance(n, (ast.AnnAssign, ast.AugAssign)) and isinstance(n.target, ast.Name) and n.value]
    aliases: set = set()
    changed = True
    while changed:
        changed = False
        for name, value in assigns:
            if name not in aliases and _mentions_iteration(value, frozenset(aliases)):
                aliases.add(name)
                changed = True
    return frozenset(aliases)


def is_iteration_loop(node: ast.AST, aliases: frozenset = frozenset()) -> bool:
    """A loop over the optimisation iterations: `for ... in range(...)` whose loop variable or
    range arguments name an iteration count (`for it in range(state.iteration + 1,
    cfg.iterations + 1)`, `for iteration in range(a, b)`), or a `while` loop whose condition
    does (`while it < cfg.iterations`)."""
    if isinstance(node, (ast.For, ast.AsyncFor)):
        it = node.iter
        is_range = isinstance(it, ast.Call) and isinstance(it.func, ast.Name) and it.func.id == "range"
        return is_range and (_mentions_iteration(node.target) or any(_mentions_iteration(a, aliases) for a in it.args))
    if isinstance(node, ast.While):
        return _mentions_iteration(node.test, aliases)
    return False


def training_loops(root: Path = ROOT, package: str = PACKAGE) -> list[tuple[str, str, int]]:
    """(file, innermost enclosing function, line) of every iteration loop in the package.

    The criterion: the training loop is the loop that counts optimisation iterations, so it is
    a `range(...)` over an iteration count, or with an iteration loop variable, or a `while` on
    an iteration count (see `is_iteration_loop`; an identifier containing "iter", e.g.
    `cfg.iterations`, `state.iteration`, `n_iters`, or a local variable assigned from one). Any
    second copy of the loop, whatever it calls inside (losses, kernels, Adam), has to count the
    same iterations, so it is found without knowing the names of the step functions, which
    change. Loops over views, parameter groups or pixels do not count iterations and are not
    matched; a non-training loop that does (say an iterative solver) must name its count
    otherwise (`n_steps`). A loop nested in another iteration loop is reported once (the outer).
    """
    found = []
    for mod in package_modules(root, package).values():
        tree = parse(root, mod)

        def visit(node, func, aliases, inside_loop):
            for child in ast.iter_child_nodes(node):
                f, a = func, aliases
                if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    f, a = child.name, _iteration_aliases(child)
                hit = is_iteration_loop(child, a) and not inside_loop
                if hit:
                    found.append((mod.rel, func or "<module>", child.lineno))
                visit(child, f, a, inside_loop or hit)

        visit(tree, None, frozenset(), False)
    return found


def test_one_training_loop():
    """Exactly one loop in reings/ counts optimisation iterations, and it is in `fit` of
    reings/train.py. A loop "counts iterations" when it is `for x in range(...)` with an
    iteration count among the range arguments or as the loop variable, or `while <condition on an
    iteration count>`; an iteration count is an identifier containing "iter" (`cfg.iterations`,
    `state.iteration`, `n_iters`) or a local variable assigned from one. A second fit loop has to
    count the same iterations whatever it calls, so this finds it without knowing the step
    functions' names (details: `training_loops`)."""
    loops = training_loops()
    home_file, home_func = TRAINING_LOOP_HOME
    listing = "\n  ".join(f"{f}:{ln} in {fn}" for f, fn, ln in loops)
    assert len(loops) == 1, f"expected exactly one training loop (in {home_file} {home_func}), found {len(loops)}:\n  {listing}"
    f, fn, _ = loops[0]
    assert (f, fn) == (home_file, home_func), f"the training loop is in {f} {fn}, expected {home_file} {home_func}"


# }}}

# {{{ self-tests of the checkers on a synthetic package


def _write(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return root


def test_cycle_finder_catches_a_function_local_relative_cycle(tmp_path):
    _write(tmp_path, {
        "reings/__init__.py": "",
        "reings/data/__init__.py": "from .a import f\n",
        "reings/data/a.py": "from .b import g\nfrom . import e\n",
        "reings/data/b.py": "def g():\n    from ..data.c import h\n",
        "reings/data/c.py": "def h():\n    from . import a\n",
        "reings/data/e.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .a import f\n",
    })
    cycles = import_cycles(tmp_path)
    assert len(cycles) == 1, cycles
    assert "['reings.data.a', 'reings.data.b', 'reings.data.c']" in cycles[0], cycles
    assert "reings.data.a (reings/data/a.py:1) -> reings.data.b (reings/data/b.py:2) -> " \
           "reings.data.c (reings/data/c.py:2) -> reings.data.a" in cycles[0], cycles
    # e's import of a runs only under a type checker: no edge. A plain one closes a -> e -> a.
    _write(tmp_path, {"reings/data/e.py": "def f():\n    from .a import f\n"})
    cycles = import_cycles(tmp_path)
    assert len(cycles) == 1 and "['reings.data.a', 'reings.data.b', 'reings.data.c', 'reings.data.e']" in cycles[0]
    assert "reings.data.a (reings/data/a.py:2) -> reings.data.e (reings/data/e.py:2) -> reings.data.a" in cycles[0]


def test_cycle_finder_resolves_from_package_import_module(tmp_path):
    # `from reings.x import y` where y is a module is an edge to reings.x.y, not to reings.x
    _write(tmp_path, {
        "reings/__init__.py": "",
        "reings/x/__init__.py": "from reings.x import y\n",
        "reings/x/y.py": "import reings.z.w\n",
        "reings/z/__init__.py": "",
        "reings/z/w.py": "from ..x import y as _y\n",
    })
    cycles = import_cycles(tmp_path)
    assert len(cycles) == 1 and "['reings.x.y', 'reings.z.w']" in cycles[0], cycles


def test_backend_check_catches_engine_imports(tmp_path):
    _write(tmp_path, {
        "reings/__init__.py": "", "reings/train.py": "", "reings/losses.py": "",
        "reings/optim/__init__.py": "", "reings/optim/adam.py": "",
        "reings/backends/__init__.py": "", "reings/backends/base.py": "from ..types import X\n",
        "reings/types.py": "",
        "reings/backends/opencl/__init__.py": "",
        "reings/backends/opencl/trainer.py": ("from ...optim.adam import step\n"
                                               "def f():\n    from reings import losses\n"),
        "reings/backends/opencl/ok.py": "from ..base import X\nimport reings.types\n",
    })
    bad = backend_engine_imports(tmp_path)
    assert bad == ["reings/backends/opencl/trainer.py:1 imports reings.optim.adam",
                   "reings/backends/opencl/trainer.py:3 imports reings.losses"], bad


def test_opencl_check_catches_every_form(tmp_path):
    _write(tmp_path, {
        "reings/__init__.py": '"""pyopencl is imported by the backends only"""\n',
        "reings/backends/__init__.py": "", "reings/backends/opencl/__init__.py": "import pyopencl\n",
        "reings/bench.py": ("import pyopencl as cl\n"
                            "def f():\n    import pyopencl._cl as _cl\n"
                            "    from pyopencl.algorithm import RadixSort\n"
                            "    import importlib, sys\n"
                            "    importlib.import_module('pyopencl.array')\n"
                            "    __import__('pyopencl')\n"
                            "    cl = sys.modules['pyopencl']\n"
                            "    cl = sys.modules.get('pyopencl')\n"
                            "    raise RuntimeError('pyopencl is missing')\n"),
    })
    bad = opencl_outside_backends(tmp_path)
    assert [b.split(": ")[0] for b in bad] == [f"reings/bench.py:{n}" for n in (1, 3, 4, 6, 7, 8, 9)], bad


def test_length_check_counts_methods_and_nested_functions(tmp_path):
    def func(name, n_lines, indent=""):  # a def of exactly n_lines lines
        return f"{indent}def {name}():\n" + f"{indent}    x = 1\n" * (n_lines - 1)

    _write(tmp_path, {
        "reings/__init__.py": "",
        "reings/m.py": (func("short", 120) + "class C:\n" + func("long", 121, "    ")
                        + "def outer():\n" + func("inner", 121, "    ")),
    })
    bad = long_functions(tmp_path)
    assert bad == ["C.long (reings/m.py:122): 121 lines", "outer (reings/m.py:243): 122 lines",
                   "outer.inner (reings/m.py:244): 121 lines"], bad


def test_loop_finder_finds_a_second_fit_loop(tmp_path):
    _write(tmp_path, {
        "reings/__init__.py": "",
        "reings/train.py": ("def fit(cfg, state):\n"
                            "    for it in range(state.iteration + 1, cfg.iterations + 1):\n"
                            "        for v in range(len(cfg.views)):\n            pass\n"
                            "        for j in range(cfg.iterations):\n            pass\n"
                            "def _fit_device(cfg):\n    it = 0\n"
                            "    while it < cfg.iterations:\n        it += 1\n"
                            "def helper(views):\n    for i in range(len(views)):\n        pass\n"
                            "def _fit_again(cfg, start):\n    last = cfg.iterations + 1\n    stop = last\n"
                            "    for step in range(start, stop):\n        pass\n"
                            "def _fit_named(a, b):\n    for iteration in range(a, b):\n        pass\n"),
        "reings/pipeline.py": "def stage(n_iters):\n    for i in range(n_iters):\n        pass\n",
    })
    loops = training_loops(tmp_path)
    assert sorted(loops) == [("reings/pipeline.py", "stage", 2), ("reings/train.py", "_fit_again", 17),
                             ("reings/train.py", "_fit_device", 9), ("reings/train.py", "_fit_named", 20),
                             ("reings/train.py", "fit", 2)], loops


# }}}

"""The library's shape: no module over 450 lines, no import cycle among its modules or packages.

The imports are read, never run: every module under ``pmsr_nn/`` is parsed with ``ast`` and
each ``import`` / ``from ... import`` anywhere in it (module level, inside functions, under
``if TYPE_CHECKING``) is an edge of the module graph, relative imports resolved against the
module's package. ``from P import name`` points at the module ``P.name`` when there is one, else at
``P`` (its ``__init__``). A package ``__init__`` that imports its own submodules is an ordinary edge
(so a submodule that imports its package's ``__init__`` back closes a cycle); the implicit import
of a module's parent packages is not an edge (every submodule would otherwise depend on its
package's ``__init__``, and every ``__init__`` that gathers its submodules would be a cycle).
Imports by string (``importlib.import_module``) are not seen.

Packages: the same graph with every module of a subpackage (``pmsr_nn.X.*``) merged into one node
``pmsr_nn.X``; a top-level module is a node of its own. Dependencies must point one way between
packages too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "pmsr_nn"
MAX_LINES = 450

LONG_MODULES: dict[str, str] = {}
"""Modules allowed over ``MAX_LINES`` lines: path (relative to the repository) -> why."""


def modules(root: Path, package: str) -> dict[str, tuple[Path, bool]]:
    """Every module of ``root / package`` by dotted name: its file and whether it is a package."""
    out = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        out[".".join(parts[:-1] if is_package else parts)] = (path, is_package)
    return out


def _known(name: str, known) -> str | None:
    """``name`` or its longest prefix that is a module of ``known``; ``None`` outside them."""
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


def import_graph(root: Path, package: str) -> dict[str, dict[str, int]]:
    """Module -> {imported module of the package: line of its first import}, self-imports left out."""
    mods = modules(root, package)
    graph = {}
    for name, (path, is_package) in mods.items():
        here = name.split(".") if is_package else name.split(".")[:-1]
        edges: dict[str, int] = {}
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    if node.level - 1 >= len(here):
                        continue  # beyond the top package: not ours
                    base = ".".join(here[:len(here) - (node.level - 1)] + ([node.module] if node.module else []))
                else:
                    base = node.module or ""
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            for target in targets:
                target = _known(target, mods)
                if target is not None and target != name:
                    edges.setdefault(target, node.lineno)
        graph[name] = edges
    return graph


def package_graph(graph: dict[str, dict[str, int]]) -> dict[str, set[str]]:
    """``graph`` with each subpackage's modules merged into one node (``a.b.c`` -> ``a.b``)."""
    node = lambda name: ".".join(name.split(".")[:2])  # noqa: E731
    out: dict[str, set[str]] = {}
    for name, edges in graph.items():
        out.setdefault(node(name), set()).update(node(t) for t in edges if node(t) != node(name))
    return out


def cycles(graph) -> list[list[str]]:
    """The strongly connected components of ``graph`` (node -> iterable of nodes) with more than
    one node, or one node that points at itself: each sorted, the list sorted (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(graph.get(start, ())))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(graph.get(w, ()))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1 or v in graph.get(v, ()):
                    found.append(sorted(component))
    return sorted(found)


def _describe(component: list[str], graph: dict[str, dict[str, int]]) -> str:
    return "; ".join(f"{a} -> {b} (line {line})" for a in component for b, line in sorted(graph[a].items())
                     if b in component)


def test_the_cycle_finder_finds_a_made_up_cycle_and_nothing_else():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"a", "e"}, "f": {"g"}, "g": {"f"}}
    assert cycles(graph) == [["a", "b", "c"], ["e"], ["f", "g"]]
    assert cycles({"a": {"b", "c"}, "b": {"c"}, "c": set()}) == []


def test_imports_are_resolved_relative_function_level_and_to_packages(tmp_path):
    files = {
        "pkg/__init__.py": "from .sub import helper\n",  # an __init__ gathering its submodules
        "pkg/top.py": "import os\n\ndef late():\n    from pkg.sub import deep\n",  # absolute, inside a function
        "pkg/sub/__init__.py": "from .deep import helper\n",
        "pkg/sub/deep.py": "from .. import top\nfrom ..top import late as later\n",  # relative, two levels
        "pkg/sub/free.py": "from . import helper\n",  # a name of the package: its __init__
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    graph = import_graph(tmp_path, "pkg")
    assert {k: set(v) for k, v in graph.items()} == {
        "pkg": {"pkg.sub"}, "pkg.top": {"pkg.sub.deep"}, "pkg.sub": {"pkg.sub.deep"},
        "pkg.sub.deep": {"pkg.top"}, "pkg.sub.free": {"pkg.sub"}}
    assert graph["pkg.top"]["pkg.sub.deep"] == 4
    assert cycles(graph) == [["pkg.sub.deep", "pkg.top"]]
    assert cycles(package_graph(graph)) == [["pkg.sub", "pkg.top"]]


def test_no_module_is_longer_than_450_lines():
    lengths = {str(path.relative_to(ROOT)): len(path.read_text().splitlines())
               for path, _ in modules(ROOT, PACKAGE).values()}
    too_long = {p: n for p, n in lengths.items() if n > MAX_LINES and p not in LONG_MODULES}
    assert not too_long, f"modules over {MAX_LINES} lines (split them along a real seam): {too_long}"
    stale = {p for p in LONG_MODULES if lengths.get(p, 0) <= MAX_LINES}
    assert not stale, f"LONG_MODULES lists modules that are gone or short now: {sorted(stale)}"


@pytest.fixture(scope="module")
def graph() -> dict[str, dict[str, int]]:
    return import_graph(ROOT, PACKAGE)


def test_the_import_graph_sees_the_library(graph):
    # a known import inside a function and a known relative import, so an empty graph cannot pass
    assert "pmsr_nn.filters.gaussian" in graph["pmsr_nn.filters.kalman"]
    assert "pmsr_nn.nets.representation" in graph["pmsr_nn.nets.training"]


def test_no_import_cycle_among_modules(graph):
    found = cycles(graph)
    assert not found, "import cycles: " + " | ".join(_describe(c, graph) for c in found)


def test_no_import_cycle_among_packages(graph):
    packages = package_graph(graph)
    found = cycles(packages)
    detail = [f"{a} -> {b} (line {line})" for c in found for a in graph for b, line in graph[a].items()
              if ".".join(a.split(".")[:2]) in c and ".".join(b.split(".")[:2]) in c
              and a.split(".")[:2] != b.split(".")[:2]]
    assert not found, f"package cycles {found}: " + "; ".join(detail)


PRIVATE_IMPORTS_ALLOWED: dict[str, str] = {}
"""Modules allowed to use another module's private names: path (relative to the repository) -> why."""


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_imports(root: Path, package: str) -> dict[str, list[str]]:
    """Per module file (relative path): each use of another module's private name (one leading
    underscore), as ``line: what``: ``from M import _x`` with ``M`` a module of the package, and
    ``m._x`` with ``m`` a name bound to a module of the package (``import P.m as m``,
    ``from P import m``). A module's own names are its business."""
    mods = modules(root, package)
    out: dict[str, list[str]] = {}
    for name, (path, is_package) in mods.items():
        here = name.split(".") if is_package else name.split(".")[:-1]
        tree = ast.parse(path.read_text(), filename=str(path))
        bound: dict[str, str] = {}  # local name -> module of the package it is bound to
        found = []
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name in mods:
                        bound[a.asname or a.name.split(".")[0]] = a.name if a.asname else a.name.split(".")[0]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    if node.level - 1 >= len(here):
                        continue
                    base = ".".join(here[:len(here) - (node.level - 1)] + ([node.module] if node.module else []))
                else:
                    base = node.module or ""
                if base not in mods:
                    continue
                for a in node.names:
                    full = f"{base}.{a.name}"
                    if full in mods:
                        bound[a.asname or a.name] = full
                    elif _private(a.name) and base != name:
                        found.append(f"{node.lineno}: from {base} import {a.name}")
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in bound
                    and _private(node.attr) and bound[node.value.id] != name):
                found.append(f"{node.lineno}: {bound[node.value.id]}.{node.attr}")
        if found:
            out[str(path.relative_to(root))] = found
    return out


def test_the_private_import_finder_finds_made_up_uses(tmp_path):
    files = {
        "pkg/__init__.py": "",
        "pkg/a.py": "_hidden = 1\nvisible = _hidden\n",  # its own private name: fine
        "pkg/b.py": "from .a import _hidden, visible\n",
        "pkg/c.py": "from . import a\nfrom pkg import a as other\n\ndef f():\n    return a._hidden + other.__name__\n",
        "pkg/d.py": "import pkg.a as m\nimport os\nx = m._hidden + os._exit.__class__.__name__.__len__()\n",
        "pkg/e.py": "from os import _exit\nfrom .a import visible\n",  # not the package's: fine
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    assert private_imports(tmp_path, "pkg") == {
        "pkg/b.py": ["1: from pkg.a import _hidden"], "pkg/c.py": ["5: pkg.a._hidden"], "pkg/d.py": ["3: pkg.a._hidden"]}


def test_no_module_uses_another_modules_private_names():
    found = {p: uses for p, uses in private_imports(ROOT, PACKAGE).items() if p not in PRIVATE_IMPORTS_ALLOWED}
    assert not found, f"private names used across modules (make them public or move them): {found}"
    stale = {p for p in PRIVATE_IMPORTS_ALLOWED if p not in private_imports(ROOT, PACKAGE)}
    assert not stale, f"PRIVATE_IMPORTS_ALLOWED lists modules that no longer need it: {sorted(stale)}"


HARNESS = "pmsr_nn.harness"
STAGES = ("scenario", "run", "results", "report")
"""The harness's stage packages, in order: a stage imports only the stages before it."""

HARNESS_ENTRIES = {"evaluate", "dispatch", "workers", "demo", "ablation"}
"""The harness's modules outside the stages: entry paths that compose all four (nothing in a stage
imports them)."""


def stage_violations(graph: dict[str, dict[str, int]], harness: str = HARNESS, stages=STAGES) -> list[str]:
    """Each import of a stage module (``harness.<stage>.*``) that points at a later stage or at
    the harness outside the stages (its ``__init__`` or an entry module), as ``a -> b (line n)``."""
    def stage(name: str) -> int | None:  # index of the stage; len(stages) outside them; None outside the harness
        parts = name.split(".")
        depth = len(harness.split("."))
        if parts[:depth] != harness.split("."):
            return None
        return stages.index(parts[depth]) if len(parts) > depth and parts[depth] in stages else len(stages)

    out = []
    for a, edges in graph.items():
        sa = stage(a)
        if sa is None or sa == len(stages):
            continue
        out += [f"{a} -> {b} (line {line})" for b, line in sorted(edges.items())
                if stage(b) is not None and stage(b) > sa]
    return out


def test_the_stage_check_finds_made_up_backward_imports(tmp_path):
    files = {
        "pkg/__init__.py": "", "pkg/h/__init__.py": "from .entry import go\n", "pkg/h/entry.py": "from .b.y import f\n",
        "pkg/h/a/__init__.py": "", "pkg/h/a/x.py": "import os\nfrom ..b import y\n",  # first stage -> second: wrong
        "pkg/h/b/__init__.py": "", "pkg/h/b/y.py": "from ..a.x import os\nfrom .z import g\n",  # backward, own stage: fine
        "pkg/h/b/z.py": "def g():\n    from .. import entry\n",  # a stage -> the entry above the stages: wrong
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    assert stage_violations(import_graph(tmp_path, "pkg"), "pkg.h", ("a", "b")) == [
        "pkg.h.a.x -> pkg.h.b.y (line 2)", "pkg.h.b.z -> pkg.h.entry (line 2)"]


def test_the_harness_stages_import_only_earlier_stages(graph):
    assert {m for m in graph if m.startswith(f"{HARNESS}.results.")}, "no results stage seen: the check reads nothing"
    found = stage_violations(graph)
    assert not found, "a harness stage imports a later stage or an entry module: " + "; ".join(found)


def test_every_harness_module_lives_in_a_stage_or_is_an_entry(graph):
    loose = {m.split(".")[2] for m in graph if m.startswith(f"{HARNESS}.") and m.split(".")[2] not in STAGES}
    assert loose == HARNESS_ENTRIES, f"harness modules outside the stages: {sorted(loose - HARNESS_ENTRIES)}"

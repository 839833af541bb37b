"""The import rules of docs/architecture.md, read off the package's source with ``ast``.

- no import cycle between modules (imports inside functions included: a cycle hidden in a
  function is still one);
- the layers that know no family (fem, fem.adapt, stepping, io, plotting, parallel, and the
  top-level errors and timing) import neither rothe.ris nor rothe.eld;
- rothe.ris and rothe.eld never import each other;
- no module outside rothe.cli imports rothe.cli;
- an import inside a function says why in a comment (a heavy or optional dependency, start-up
  time, a platform-only module; never a cycle).
"""

from __future__ import annotations

import ast
from pathlib import Path

import rothe

PACKAGE = Path(rothe.__file__).parent
FAMILIES = ("rothe.ris", "rothe.eld")
NEUTRAL = (
    "rothe.fem",
    "rothe.stepping",
    "rothe.io",
    "rothe.plotting",
    "rothe.parallel",
    "rothe.errors",
    "rothe.timing",
    "rothe._version",
)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _resolve(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def import_graph() -> dict[str, set[str]]:
    """module -> the rothe modules it imports (a name imported from a package counts as the
    submodule when one of that name exists)."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                base = _resolve(node, name, path.name == "__init__.py")
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    targets.add(sub if sub in modules else base)
            elif isinstance(node, ast.Import):
                targets.update(a.name for a in node.names)
        graph[name] = {t for t in targets if t in modules and t != name}
    return graph


def _inside(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per strongly connected component with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycle():
    graph = import_graph()
    # a package's __init__ re-exports its modules: an edge from a submodule to its own package's
    # __init__ would make every such pair a cycle, so the package itself is not a target
    trimmed = {m: {t for t in ts if not _inside(m, t) or t == m} for m, ts in graph.items()}
    assert _cycles(trimmed) == []


def test_the_shared_layers_know_no_family():
    bad = [
        (m, t)
        for m, ts in import_graph().items()
        for t in ts
        if any(_inside(m, n) for n in NEUTRAL) and any(_inside(t, f) for f in FAMILIES)
    ]
    assert bad == []


def test_the_families_never_import_each_other():
    bad = [
        (m, t)
        for m, ts in import_graph().items()
        for t in ts
        if (_inside(m, "rothe.ris") and _inside(t, "rothe.eld"))
        or (_inside(m, "rothe.eld") and _inside(t, "rothe.ris"))
    ]
    assert bad == []


def test_only_the_command_line_imports_the_command_line():
    bad = [
        (m, t)
        for m, ts in import_graph().items()
        for t in ts
        if _inside(t, "rothe.cli") and not _inside(m, "rothe.cli")
    ]
    assert bad == []


def test_the_rules_can_fail():
    """The checks see a cycle and a forbidden direction when there is one."""
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]
    graph = import_graph()
    assert any(_inside(t, "rothe.fem") for t in graph["rothe.ris.adapt"])  # families use fem


#: the reasons an import may sit inside a function (a word of its comment): a heavy or optional
#: dependency, the command line's start-up time, a platform-only module (never a cycle: a cycle
#: hidden in a function is still one)
REASONS = ("heavy", "optional", "start-up", "matplotlib", "dask", "numba", "petsc", "mpi", "posix")


def function_imports_without_a_reason() -> list[str]:
    """Imports inside functions whose comment (on their line or the two lines above) names none
    of :data:`REASONS`."""
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        lines = path.read_text().split("\n")
        for fn in ast.walk(ast.parse("\n".join(lines))):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if isinstance(node, (ast.Import, ast.ImportFrom)):
                    context = lines[max(0, node.lineno - 3) : node.end_lineno]
                    comments = " ".join(line.split("#", 1)[1] for line in context if "#" in line)
                    if not any(word in comments.lower() for word in REASONS):
                        bad.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}")
    return sorted(set(bad))


def test_imports_inside_functions_say_why():
    # only heavy or optional dependencies, start-up time or a platform-only module, with a comment
    assert function_imports_without_a_reason() == []

"""No import circle in ``groundstation.solve``: its modules' imports form a DAG.

Every import counts, wherever it stands: at the top, inside a function (a lazy import that
closes a circle is still a circle, only deferred) or under ``TYPE_CHECKING``. An import of
``a.b`` (``import a.b``, ``from a import b`` with ``b`` a module) is an edge to ``a.b``, not to
the package ``a``, whose ``__init__`` Python runs first either way.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from peers import cli_env

import groundstation.solve

SOLVE = Path(groundstation.solve.__file__).parent


def import_graph(package_dir: Path, package: str) -> dict[str, set[str]]:
    """Module -> the modules of ``package`` it imports (the package's own files only)."""
    files: dict[str, Path] = {}
    for path in sorted(package_dir.rglob("*.py")):
        parts = [package, *path.relative_to(package_dir).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        files[".".join(parts)] = path
    graph: dict[str, set[str]] = {name: set() for name in files}
    for name, path in files.items():
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: from the module's package, one level up per dot
                    anchor = name.split(".")[: len(name.split(".")) - node.level + is_pkg]
                    base = ".".join([*anchor, *([base] if base else [])])
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in files else base
                           for a in node.names]
            graph[name].update(t for t in targets if t in files and t != name)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle (``[a, b, ..., a]``), or None when the graph is a DAG."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt):], nxt]
            if nxt not in state and (found := visit(nxt)) is not None:
                return found
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (found := visit(start)) is not None:
            return found
    return None


def test_solve_has_no_import_circle() -> None:
    graph = import_graph(SOLVE, "groundstation.solve")
    assert "groundstation.solve.pipeline" in graph and graph["groundstation.solve.pipeline"]
    cycle = find_cycle(graph)
    assert cycle is None, "import circle in groundstation.solve: " + " -> ".join(cycle or [])


def test_a_lazy_import_that_closes_a_circle_is_found(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg.sub import b\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "b.py").write_text("def f():\n    from ..c import g\n    return g\n")
    (pkg / "c.py").write_text("import typing\nif typing.TYPE_CHECKING:\n    import pkg.a\n")
    graph = import_graph(pkg, "pkg")
    assert graph["pkg.a"] == {"pkg.sub.b"} and graph["pkg.sub.b"] == {"pkg.c"}
    assert find_cycle(graph) == ["pkg.a", "pkg.sub.b", "pkg.c", "pkg.a"]
    (pkg / "c.py").write_text("def g():\n    return 1\n")
    assert find_cycle(import_graph(pkg, "pkg")) is None


def test_a_solve_refused_at_once_loads_neither_scipy_stats_nor_matplotlib(tmp_path: Path) -> None:
    """A mistake on the ``solve`` line is answered before the heavy libraries load (scipy.stats
    and matplotlib were 1 s of the 1.3 s of CPU such a refusal took)."""
    code = ("import sys\nfrom groundstation.cli import main\n"
            "rc = main(['solve', 'missing.ubx', '--base', 'b.ubx', '--base-xyz', '1,2,3',"
            " '--out-dir', 'out'])\n"
            "print(rc, sorted(m for m in ('scipy.stats', 'matplotlib', 'scipy.special')"
            " if m in sys.modules))\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=cli_env(),
                          capture_output=True, text=True, timeout=60, check=False)
    assert "no such file" in proc.stderr, proc.stderr
    assert proc.stdout.split() == ["2", "[]"], proc.stdout
    assert not (tmp_path / "out").exists()

"""The house's stages import one way: the writer at the bottom takes nothing from the stages above it,
and no module circles back to itself."""

from __future__ import annotations

import ast
from pathlib import Path

import runner

RUNNER = Path(runner.__file__).parent


def _module(path: Path) -> str:
    parts = path.relative_to(RUNNER.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module(p): p for p in RUNNER.rglob("*.py")}


def _run_nodes(node: ast.AST) -> list[ast.AST]:
    """Every node under `node` but what only the type checker reads (`if TYPE_CHECKING:` bodies)."""
    found: list[ast.AST] = []
    for child in ast.iter_child_nodes(node):
        if isinstance(child, ast.If) and ast.unparse(child.test).endswith("TYPE_CHECKING"):
            found += [n for other in child.orelse for n in [other, *_run_nodes(other)]]
        else:
            found += [child, *_run_nodes(child)]
    return found


def _imports(name: str) -> set[str]:
    """The runner modules `name` imports, at module level or inside a function (what runs, not what is only type-checked)."""
    path = MODULES[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in _run_nodes(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + [base] if base else up)
            targets = [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        for target in targets:
            while target and target not in MODULES:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


def test_the_terminal_writer_imports_nothing_of_the_stages_above_it() -> None:
    stages = ("runner.scenario", "runner.run", "runner.results", "runner.report", "runner.history")
    above = sorted(m for m in _imports("runner.terminal") if m.startswith(stages))
    assert above == [], f"runner/terminal.py is the writer every command imports; it draws no cells: {above}"


def test_no_module_imports_itself_back() -> None:
    graph = {name: _imports(name) for name in MODULES}
    done: set[str] = set()

    def visit(name: str, path: list[str]) -> None:
        if name in path:
            raise AssertionError("import circle: " + " -> ".join(path[path.index(name) :] + [name]))
        if name in done:
            return
        for other in sorted(graph[name]):
            visit(other, path + [name])
        done.add(name)

    for name in sorted(graph):
        visit(name, [])


def test_no_room_outgrows_a_newcomer():
    """Issue 39: no Python module over 900 lines, no C file over 1,500 (model.py was 1,738, _probe.c 2,612)."""
    package = Path(__file__).resolve().parent.parent / "runner"  # the source tree: an install holds no C files
    assert (package / "run" / "_probe.c").is_file()
    big = [f"{p.relative_to(package)}: {n}" for p in package.rglob("*.py") if (n := len(p.read_text().splitlines())) > 900]
    big += [f"{p.relative_to(package)}: {n}" for p in package.rglob("*.c") if (n := len(p.read_text().splitlines())) > 1500]
    assert not big, big

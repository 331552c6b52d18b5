"""Static checks of the seqnet.describe package: no import cycles, no private imports, small modules and
functions, no branches on method names, no process-wide side effects."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from seqnet.describe import DESCRIBERS

PACKAGE = Path(__file__).resolve().parents[2] / "src" / "seqnet" / "describe"
MODULES = {p.stem: ast.parse(p.read_text(encoding="utf-8")) for p in sorted(PACKAGE.glob("*.py"))}
PACKAGE_PATH = ["seqnet", "describe"]
CLI = Path(__file__).resolve().parents[2] / "src" / "seqnet" / "cli" / "describe_cmd.py"


def sibling_imports(tree: ast.Module) -> list[tuple[str, list[str]]]:
    """``(sibling module, imported names)`` of every ``from .x import ...`` anywhere in the module
    (function-level and ``TYPE_CHECKING`` imports included); the package itself is ``__init__``."""
    out = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.ImportFrom):
            continue
        names = [a.name for a in node.names]
        absolute = (node.module or "").split(".")
        if node.level == 1:
            out.append((node.module or "__init__", names))
        elif node.level == 2 and absolute[0] == "describe" or node.level == 0 and absolute[:2] == PACKAGE_PATH:
            parts = absolute[1:] if node.level == 2 else absolute[2:]
            out.append((parts[0] if parts else "__init__", names))
        elif node.level == 2 and node.module is None and "describe" in names:
            out.append(("__init__", names))
    return out


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of ``graph`` (node -> nodes it imports) as a path, or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*path, nxt]
            found = None if nxt in state else visit(nxt, [*path, nxt])
            if found:
                return found
        state[node] = 2
        return None

    for name in sorted(graph):
        found = None if name in state else visit(name, [name])
        if found:
            return found
    return None


def test_no_import_cycles_between_describe_modules():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    graph = {name: {m for m, _ in sibling_imports(tree)} for name, tree in MODULES.items()}
    assert "cnn" in graph["netvlad"] and "netvlad" not in graph["cnn"]  # the cnn <-> netvlad cycle is gone
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph) or [])


def test_modules_import_siblings_directly_and_nothing_private():
    for name, tree in MODULES.items():
        for module, names in sibling_imports(tree):
            assert module != "__init__" or name == "__init__", f"{name} imports the package facade"
            assert not any(n.startswith("_") for n in names), f"{name} imports private {names} from {module}"


@pytest.mark.parametrize("name", sorted(MODULES))
def test_small_modules_and_functions(name):
    source = (PACKAGE / f"{name}.py").read_text(encoding="utf-8")
    assert len(source.splitlines()) <= 300
    for node in ast.walk(MODULES[name]):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            assert node.end_lineno - node.lineno + 1 <= 50, f"{name}.{node.name} is over 50 lines"


def test_no_branches_on_method_names_and_no_side_effects():
    trees = [*MODULES.values(), ast.parse(CLI.read_text(encoding="utf-8"))]
    for tree in trees:
        for node in ast.walk(tree):
            if isinstance(node, ast.Compare):
                consts = [c for c in ast.walk(node) if isinstance(c, ast.Constant) and c.value in DESCRIBERS]
                assert not consts, f"comparison with a method name at line {node.lineno}"
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
                assert node.func.id != "print", f"print at line {node.lineno}"
            if isinstance(node, ast.Attribute):
                assert node.attr not in ("set_num_threads", "use"), f"process-wide setting at line {node.lineno}"
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                mods = [a.name for a in node.names] + [getattr(node, "module", None) or ""]
                assert not any(m.split(".")[0] == "tqdm" for m in mods), "tqdm imported directly"

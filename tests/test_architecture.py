"""The layout rules of docs/architecture.md, checked on the source tree.

* the layer order declared at the top of docs/architecture.md: a package imports only packages of lower
  layers (module-level, function-level and TYPE_CHECKING imports alike);
* no import cycle between seqnet modules (module-level and function-level imports alike);
* no module imports the package root (``seqnet/__init__``) and no private name crosses modules;
* no module over 300 lines, no function over 50 lines;
* no process-wide side effects in library code (thread counts, matplotlib backends, tqdm bars
  other than through seqnet.core.progress, ``print``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "seqnet"
MODULES = sorted(SRC.rglob("*.py"))


def module_name(path: Path, root: Path = SRC.parent) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def resolve(path: Path, node: ast.ImportFrom, root: Path = SRC.parent) -> str:
    """The absolute module an ``ImportFrom`` refers to."""
    if node.level == 0:
        return node.module or ""
    base = module_name(path, root).split(".")
    if not is_package(path):
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


KNOWN = {module_name(p) for p in MODULES}


def imports_of(path: Path, root: Path = SRC.parent) -> list[tuple[str, list[str], int]]:
    """``(module, names, line)`` of every seqnet import in ``path`` (all nesting levels)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            mod = resolve(path, node, root)
            if not mod.startswith("seqnet"):
                continue
            names = [a.name for a in node.names]
            subs = [f"{mod}.{n}" for n in names if f"{mod}.{n}" in KNOWN]
            out.append((mod, [n for n in names if f"{mod}.{n}" not in KNOWN], node.lineno))
            out += [(s, [], node.lineno) for s in subs]
        elif isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names if a.name.startswith("seqnet")]
    return out


def graph() -> dict[str, set[str]]:
    g: dict[str, set[str]] = {}
    for p in MODULES:
        me = module_name(p)
        deps = set()
        for mod, names, _ in imports_of(p):
            if names and mod != me and me.startswith(mod + "."):
                deps.add(mod)  # `from . import NAME`: a name of the own package's __init__ (which may import me)
            # importing seqnet.a.b also runs seqnet.a's __init__, except from inside seqnet.a itself
            parts = mod.split(".")
            for i in range(2, len(parts) + 1):
                prefix = ".".join(parts[:i])
                if prefix in KNOWN and prefix != me and not me.startswith(prefix + "."):
                    deps.add(prefix)
        g[me] = deps
    return g


def find_cycle(g: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(g.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state and (c := visit(m)):
                return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(g):
        if n not in state and (c := visit(n)):
            return c
    return None


def test_no_import_cycle():
    assert find_cycle(graph()) is None, " -> ".join(find_cycle(graph()) or [])


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(SRC)))
def test_imports_follow_the_rules(path):
    for mod, names, line in imports_of(path):
        where = f"{path.relative_to(SRC)}:{line}"
        if mod == "seqnet":
            pytest.fail(f"{where}: imports the package root (seqnet/__init__); import the module instead")
        private = [n for n in names if n.startswith("_") and n != "__version__"]
        assert not private, f"{where}: imports private name(s) {private} from {mod}"


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(SRC)))
def test_sizes(path):
    text = path.read_text()
    assert len(text.splitlines()) <= 300, f"{path.relative_to(SRC)} has {len(text.splitlines())} lines"
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1
            assert n <= 50, f"{path.relative_to(SRC)}:{node.lineno} {node.name} has {n} lines"


FORBIDDEN_CALLS = {"set_num_threads": "thread counts are set by the CLI only", "use": "matplotlib backend",
                   "print": "library code logs, the CLI prints"}


@pytest.mark.parametrize("path", [p for p in MODULES if "cli" not in p.relative_to(SRC).parts],
                         ids=lambda p: str(p.relative_to(SRC)))
def test_no_process_wide_side_effects(path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            owner = f.value.id if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) else ""
            bad = name == "print" or name == "set_num_threads" or (name == "use" and owner == "matplotlib")
            assert not bad, f"{path.relative_to(SRC)}:{node.lineno}: {name}() ({FORBIDDEN_CALLS[name]})"
        if isinstance(node, (ast.Import, ast.ImportFrom)) and path.name != "progress.py":
            mods = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            assert not any(m.startswith("tqdm") for m in mods), \
                f"{path.relative_to(SRC)}:{node.lineno}: progress bars come from seqnet.core.progress"
        if isinstance(node, ast.ImportFrom) and node.module == "matplotlib" and any(
                a.name == "pyplot" for a in node.names):
            pytest.fail(f"{path.relative_to(SRC)}:{node.lineno}: pyplot keeps global state; use report.new_figure")


DOCS = SRC.parents[1] / "docs" / "architecture.md"


def declared_layers() -> dict[str, int]:
    """``{package: layer}`` from the ```layers block of docs/architecture.md (words before the description,
    which is separated by three spaces or more)."""
    text = DOCS.read_text()
    block = text.split("```layers\n", 1)[1].split("```", 1)[0]
    layers: dict[str, int] = {}
    for line in block.splitlines():
        level, rest = line.split(maxsplit=1)
        for name in rest.split("   ", 1)[0].split():
            assert name not in layers, f"{name} is declared in two layers"
            layers[name] = int(level)
    return layers


def package_of(module: str) -> str:
    """The top-level package (or module) of ``seqnet.a.b`` (``a``); the root is ``seqnet``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "seqnet"


def test_every_package_has_one_declared_layer():
    layers = declared_layers()
    present = {package_of(m) for m in KNOWN}
    missing = sorted(present - set(layers))
    assert not missing, f"packages missing from docs/architecture.md's layers: {missing}"
    assert set(layers) <= present, f"layers name packages that do not exist: {sorted(set(layers) - present)}"


def test_no_import_goes_up_or_sideways():
    layers = declared_layers()
    wrong = sorted(f"{a} (layer {layers[package_of(a)]}) imports {b} (layer {layers[package_of(b)]})"
                   for a, deps in graph().items() for b in deps
                   if package_of(a) != package_of(b) and layers[package_of(b)] >= layers[package_of(a)])
    assert not wrong, "imports against the layer order of docs/architecture.md:\n" + "\n".join(wrong)


def test_the_layer_check_sees_a_lazy_import_going_up(tmp_path):
    """The import scan reads function-level and TYPE_CHECKING imports, not only the module's top."""
    src = tmp_path / "seqnet" / "data"
    src.mkdir(parents=True)
    (src / "x.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..eval import a\n"
                              "def f():\n    from ..cli.common import b\n")
    found = {m for m, _, _ in imports_of(src / "x.py", root=tmp_path)}
    assert {"seqnet.eval", "seqnet.cli.common"} <= found


def test_no_suffixed_siblings():
    """A module that outgrows itself becomes a package, never ``a.py`` beside ``a_more.py``."""
    packages = [p.parent for p in MODULES if p.name == "__init__.py"]
    for pkg in packages:
        stems = {p.stem for p in pkg.glob("*.py")} | {p.name for p in pkg.iterdir() if (p / "__init__.py").is_file()}
        pairs = sorted(f"{a} / {b}" for a in stems for b in stems if b.startswith(a + "_"))
        assert not pairs, f"{pkg.relative_to(SRC)}: suffixed siblings {pairs}"


def test_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


TESTS = Path(__file__).resolve().parent


def test_the_top_level_holds_packages_and_at_most_four_modules():
    modules = sorted(p.name for p in SRC.glob("*.py"))
    assert len(modules) <= 4, modules


def test_tests_mirror_the_packages():
    packages = {p.name for p in SRC.iterdir() if (p / "__init__.py").is_file()}
    dirs = {p.name for p in TESTS.iterdir() if p.is_dir() and not p.name.startswith((".", "_"))}
    assert dirs <= packages, f"test folders without a package: {sorted(dirs - packages)}"
    assert packages <= dirs, f"packages without a test folder: {sorted(packages - dirs)}"
    assert not list(TESTS.glob("test_*.py"))[1:], "tests live in the folder of their package"


@pytest.mark.parametrize("path", [p for p in MODULES if "cli" not in p.relative_to(SRC).parts],
                         ids=lambda p: str(p.relative_to(SRC)))
def test_library_code_chains_causes(path):
    """``raise … from None`` only where the CLI turns an error into its one line (cli/); elsewhere ``from e``."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Raise) and isinstance(node.cause, ast.Constant) and node.cause.value is None:
            pytest.fail(f"{path.relative_to(SRC)}:{node.lineno}: raise ... from None drops the cause for API callers")


def test_the_gpu_check_skips_cleanly_without_a_gpu():
    """benchmarks/gpu_check.sh exists and, where torch sees no CUDA device, says so and exits 0."""
    import subprocess

    import torch

    script = SRC.parents[1] / "benchmarks" / "gpu_check.sh"
    assert script.is_file()
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is present: run the check itself")
    p = subprocess.run(["bash", str(script)], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and "no CUDA device" in p.stdout, (p.stdout, p.stderr)


def test_test_modules_have_distinct_names():
    """pytest imports test modules by their file name (no packages): two of one name break collection."""
    names = [p.name for p in TESTS.rglob("test_*.py")]
    assert len(names) == len(set(names)), sorted({n for n in names if names.count(n) > 1})

"""Docs that cannot drift: what README.md, docs/*.md, docstrings and comments name must exist and run.

* every ``seqnet.x.y`` (and relative ``:mod:`.x```) named in the docs, in docstrings and comments of src/seqnet and
  benchmarks/ is a module of the source tree or a name defined in one (read from the modules' syntax trees, nothing
  imported), and every ``dir/file.py`` (.md, .sh) path and markdown link they name is a file of the repository;
* every ``seqnet ...`` call of a ```bash / ```sh / ```console block of the docs parses with seqnet's own parser
  (nothing run; shell variables set in the block filled in), and no unlabelled block holds one;
* every ```python block compiles and imports only what seqnet defines;
* the README's Quick start runs as written on the synthetic dataset it makes, its Python snippet too (``seqnet train``
  only parsed: an untrained model of the same shape stands in for what it would write).

Everything is derived from the tree, so a module moved or renamed without its docs fails here, naming file:line.
"""

from __future__ import annotations

import ast
import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
import tokenize
from collections.abc import Iterator
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SRC = REPO / "src"
PKG = SRC / "seqnet"
README = REPO / "README.md"
DOCS = [README, *sorted((REPO / "docs").glob("*.md"))]
SOURCES = [*sorted(PKG.rglob("*.py")), *sorted((REPO / "benchmarks").glob("*.py"))]
SHELLS = {"bash", "sh", "shell", "console"}
# Command lines of the docs that cannot parse as written, each with the reason (keep this tiny: fix the docs first).
UNPARSABLE: dict[str, str] = {}
# Paths the docs name that are not files of this repository (each with what it is).
EXTERNAL_PATHS = {
    "my_vpr/describer.py": "docs/describe.md: the reader's own describer module in the plugin example",
    "datasets/msls.py": "src/seqnet/data/msls.py: a file of mapillary/mapillary_sls, whose layout it reads",
}

FILE_SUFFIXES = {  # ``seqnet.pt`` is a file name, not a module
    "pt", "pth", "py", "json", "npy", "npz", "h5", "csv", "txt", "log", "html", "png", "db", "mat"}
DOTTED = re.compile(r"(?<![\w./-])seqnet(?:\.[A-Za-z_]\w*)+")
RELATIVE = re.compile(r":(?:mod|func|class|meth|attr|data|obj|exc):`~?(\.+[A-Za-z_][\w.]*)`")
# ``dir/file.py`` (.md, .sh) paths; those under out/, OUT/, RUN/, ... are what a command writes, and ../ is outside the
# repository (../shared/: data beside it, absent in CI), so neither is a repository file
OUTPUTS = r"out|OUT|RUN|MAP|DIR|runs|data|\.\."
FILE_PATH = re.compile(rf"(?<![\w/.:-])((?!(?:{OUTPUTS})/)(?:[\w.-]+/)+[\w-]+\.(?:py|md|sh))(?![\w/])")
MD_LINK = re.compile(r"\]\(([^)\s]+)\)")


def module_name(path: Path) -> str:
    parts = path.relative_to(SRC).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in PKG.rglob("*.py")}


# ---- what the docs say: (file, line, text) pieces ------------------------------------------------------------------
def rel(path: Path) -> str:
    return str(path.relative_to(REPO))


def prose(path: Path) -> Iterator[tuple[int, str]]:
    """``(first line, text)`` of the prose of ``path``: a markdown file whole, a Python file's comments and
    docstrings."""
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".md":
        yield 1, text
        return
    tree = ast.parse(text)
    docs = {(n.body[0].lineno, n.body[0].col_offset) for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and n.body
            and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)
            and isinstance(n.body[0].value.value, str)}
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type == tokenize.COMMENT or (tok.type == tokenize.STRING and tok.start in docs):
            yield tok.start[0], tok.string


def mentions(pattern: re.Pattern[str]) -> Iterator[tuple[Path, int, str]]:
    """``(file, line, first group or match)`` of every match of ``pattern`` in the prose of the docs and sources."""
    for path in [*DOCS, *SOURCES]:
        for start, text in prose(path):
            for m in pattern.finditer(text):
                yield path, start + text.count("\n", 0, m.start()), m.group(m.lastindex or 0)


# ---- what the tree holds --------------------------------------------------------------------------------------------
def absolute(module: str, is_package: bool, level: int, name: str | None) -> str:
    base = module.split(".")
    base = base[: len(base) - (level - 1 if is_package else level)]
    return ".".join(base + ([name] if name else []))


def statements(body: list[ast.stmt]) -> Iterator[ast.stmt]:
    """Top-level statements, looking inside ``if`` / ``try`` / ``with`` blocks (``TYPE_CHECKING`` imports)."""
    for node in body:
        yield node
        for block in ("body", "orelse", "finalbody", "handlers"):
            if isinstance(node, (ast.If, ast.Try, ast.With, ast.ExceptHandler)):
                yield from statements(getattr(node, block, []))


def targets(node: ast.stmt) -> list[str]:
    found = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
    return [n.id for t in found if t is not None for n in ast.walk(t) if isinstance(n, ast.Name)]


@cache
def namespace(module: str) -> dict[str, object]:
    """The names ``module`` defines: a def / class node, ``("from", module, name)`` for an import, or ``None``."""
    path = MODULES[module]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names: dict[str, object] = {}
    for node in statements(tree.body):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names[node.name] = node
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            names.update(dict.fromkeys(targets(node)))
        elif isinstance(node, ast.ImportFrom):
            src = absolute(module, path.name == "__init__.py", node.level, node.module) if node.level else node.module
            names.update({a.asname or a.name: ("from", src, a.name) for a in node.names if a.name != "*"})
            if any(a.name == "*" for a in node.names) and src in MODULES:
                names.update({k: v for k, v in namespace(src).items() if not k.startswith("_")})
        elif isinstance(node, ast.Import):
            names.update({(a.asname or a.name).split(".")[0]: ("from", a.name, None) for a in node.names})
    if "__getattr__" in names:  # PEP 562: the names it answers are string constants in it or keys of a table
        lazy = [*ast.walk(names["__getattr__"])] + [d for n in tree.body if isinstance(n, (ast.Assign, ast.AnnAssign))
                                                     for d in ast.walk(n) if isinstance(d, ast.Dict)]
        for node in lazy:
            keys = node.keys if isinstance(node, ast.Dict) else [node]
            names.update({k.value: None for k in keys if isinstance(k, ast.Constant) and isinstance(k.value, str)
                          and k.value.isidentifier()})
    return names


def class_has(module: str, cls: ast.ClassDef, attr: str) -> bool:
    """``attr`` is defined in ``cls`` (body, ``self.attr = ...``) or may come from a base outside seqnet."""
    for node in ast.walk(cls):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.name == attr:
            return True
        if isinstance(node, (ast.Assign, ast.AnnAssign)) and (attr in targets(node) or any(
                isinstance(t, ast.Attribute) and t.attr == attr
                for t in (node.targets if isinstance(node, ast.Assign) else [node.target]))):
            return True
    return any(resolves(module, [ast.unparse(b), attr]) for b in cls.bases if ast.unparse(b) != "object")


def resolves(module: str, rest: list[str]) -> bool:
    """``module.rest[0].rest[1]...`` names something: a submodule, a defined name, a class attribute."""
    if not rest:
        return True
    if f"{module}.{rest[0]}" in MODULES:
        return resolves(f"{module}.{rest[0]}", rest[1:])
    names = namespace(module)
    if rest[0] not in names:
        return False
    entry = names[rest[0]]
    if isinstance(entry, tuple):
        _, src, name = entry
        if src not in MODULES:
            return not str(src).startswith("seqnet")  # a name from outside seqnet: not ours to check
        return resolves(src, ([name] if name else []) + rest[1:])
    if isinstance(entry, ast.ClassDef) and len(rest) > 1:
        return class_has(module, entry, rest[1])
    return True


def exists(dotted: str) -> bool:
    parts = dotted.split(".")
    top = max(i for i in range(1, len(parts) + 1) if ".".join(parts[:i]) in MODULES)
    return resolves(".".join(parts[:top]), parts[top:])


def relative_target(path: Path, ref: str) -> str:
    """The absolute name of ``:mod:`.ref``` written in ``path``."""
    level = len(ref) - len(ref.lstrip("."))
    return absolute(module_name(path), path.name == "__init__.py", level, ref.lstrip(".") or None)


# ---- 1. names and paths ---------------------------------------------------------------------------------------------
def test_named_modules_and_names_exist():
    named = list(mentions(DOTTED))
    assert len(named) > 100, f"only {len(named)} seqnet.x names found: is the scanner broken?"
    stale = [f"{rel(p)}:{line}: {name}" for p, line, name in named
             if not exists(name) and name.split(".")[-1] not in FILE_SUFFIXES]
    stale += [f"{rel(p)}:{line}: {ref} (= {relative_target(p, ref)})" for p, line, ref in mentions(RELATIVE)
              if p.suffix == ".py" and PKG in p.parents and not exists(relative_target(p, ref))]
    assert not stale, "names that no module of src/seqnet defines:\n" + "\n".join(stale)


def path_exists(doc: Path, ref: str) -> bool:
    bases = [doc.parent, REPO, SRC, PKG, REPO / "tests", *[d for d in doc.parents if PKG in d.parents]]
    return any((base / ref).exists() for base in bases)


def test_named_files_exist():
    named = list(mentions(FILE_PATH))
    assert len(named) > 10, f"only {len(named)} file paths found: is the scanner broken?"
    assert set(EXTERNAL_PATHS) <= {ref for _, _, ref in named}, "EXTERNAL_PATHS names a path the docs no longer hold"
    stale = [f"{rel(p)}:{line}: {ref}" for p, line, ref in named
             if not path_exists(p, ref) and ref not in EXTERNAL_PATHS]
    for doc in DOCS:
        for i, text in enumerate(doc.read_text(encoding="utf-8").splitlines(), 1):
            for m in MD_LINK.finditer(text):
                target = m.group(1).split("#")[0]
                if target and not re.match(r"[a-z]+:", target) and not (doc.parent / target).exists():
                    stale.append(f"{rel(doc)}:{i}: link {m.group(1)}")
    assert not stale, "files named in the docs that the repository does not hold:\n" + "\n".join(stale)


# ---- 2. command blocks ----------------------------------------------------------------------------------------------
def blocks(doc: Path, languages: set[str]) -> Iterator[tuple[int, str, str]]:
    """``(line, language, body)`` of every fenced block of ``doc`` in one of ``languages``."""
    for m in re.finditer(r"^```(\w*)[^\n]*\n(.*?)^```", doc.read_text(encoding="utf-8"), re.M | re.S):
        if m.group(1) in languages:
            yield doc.read_text(encoding="utf-8").count("\n", 0, m.start()) + 2, m.group(1), m.group(2)


def seqnet_argvs(line: str) -> list[list[str]]:
    """The argument lists of every ``seqnet`` (``python -m seqnet``, ``torchrun ... -m seqnet``) call on ``line``."""
    line = re.sub(r"(?<!\S)\d*(?:>>?|<)&?\s*\S+", "", line.removeprefix("$ "))  # redirections
    lex = shlex.shlex(line, posix=True, punctuation_chars=True)
    lex.whitespace_split = True
    calls, words = [], []
    for token in [*lex, ";"]:
        if token in {"&&", "||", ";", "|", "&"}:
            while words and re.fullmatch(r"\w+=\S*", words[0]):  # environment assignments
                words.pop(0)
            if words[:1] == ["seqnet"]:
                calls.append(words[1:])
            elif "-m" in words and words[words.index("-m") + 1:][:1] == ["seqnet"]:
                calls.append(words[words.index("-m") + 2:])
            words = []
        else:
            words.append(token)
    return calls


def expand(line: str, variables: dict[str, str]) -> str:
    """``line`` with the block's shell variables set so far (``X=...``; ``for X in A B``: A) put in, as a shell
    would."""
    assigned = re.fullmatch(r"\s*(?:for\s+(\w+)\s+in\s+(\S+).*|(\w+)=(\S.*))", line)
    if assigned and assigned.group(1):
        variables[assigned.group(1)] = assigned.group(2)
    elif assigned:
        variables[assigned.group(3)] = " ".join(shlex.split(assigned.group(4), comments=True))
    return re.sub(r"\$\{?(\w+)\}?", lambda m: variables.get(m.group(1), m.group(0)), line)


def command_lines(doc: Path) -> Iterator[tuple[int, str, list[str]]]:
    """``(line, text, argv)`` of every seqnet call in the shell blocks of ``doc`` (continuations joined)."""
    for start, language, body in blocks(doc, SHELLS):
        joined, first, variables = "", start, {}
        for i, text in enumerate(body.splitlines()):
            if language == "console" and not (joined or text.startswith("$ ")):
                continue  # a transcript: commands follow "$ ", the rest is what they printed
            first = first if joined else start + i
            joined += text.rstrip()
            if joined.endswith("\\"):
                joined = joined[:-1] + " "
                continue
            for argv in seqnet_argvs(expand(joined, variables)):
                yield first, joined.strip(), argv
            joined = ""


def parse(argv: list[str]):  # noqa: ANN201 - argparse.Namespace, or the usage error
    from seqnet import SeqnetError
    from seqnet.cli import build_parser

    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            return build_parser(argv).parse_args(argv)
    except SystemExit as e:  # --help, --version
        return None if e.code == 0 else f"exit {e.code}"
    except SeqnetError as e:
        return e


def test_command_blocks_parse():
    failed, seen = [], 0
    for doc in DOCS:
        for line, text, argv in command_lines(doc):
            seen += 1
            result = parse(argv)
            if isinstance(result, (Exception, str)) and text not in UNPARSABLE:
                failed.append(f"{rel(doc)}:{line}: {text}\n    {result}")
    assert seen > 10, f"only {seen} seqnet command lines found in {len(DOCS)} docs: is the block parser broken?"
    assert not failed, "command lines of the docs that seqnet does not accept:\n" + "\n".join(failed)
    assert all(any(text == t for doc in DOCS for _, t, _ in command_lines(doc)) for text in UNPARSABLE), \
        "UNPARSABLE names a line the docs no longer hold"


def test_command_blocks_are_labelled():
    """A command in an unlabelled block would escape the check above."""
    from seqnet.cli import COMMANDS

    found = [f"{rel(doc)}:{start + i}: {text}" for doc in DOCS for start, _, body in blocks(doc, {""})
             for i, text in enumerate(body.splitlines())
             if re.match(rf"(\$ )?(python -m )?seqnet ({'|'.join(COMMANDS)})\b", text)]
    assert not found, "seqnet commands in blocks without a language (label them ```bash or ```console):\n" + \
        "\n".join(found)


def test_python_blocks_compile_and_import():
    """Every ```python block of the docs is Python, and what it imports from seqnet exists."""
    stale = []
    for doc in DOCS:
        for start, _, body in blocks(doc, {"python"}):
            try:
                tree = ast.parse(body)
            except SyntaxError as e:
                stale.append(f"{rel(doc)}:{start + (e.lineno or 1) - 1}: {e.msg}")
                continue
            stale += [f"{rel(doc)}:{start + node.lineno - 1}: from {node.module} import {a.name}"
                      for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.level == 0
                      and (node.module or "").split(".")[0] == "seqnet" for a in node.names
                      if not exists(f"{node.module}.{a.name}")]
    assert not stale, "python blocks of the docs that do not compile or import what seqnet lacks:\n" + \
        "\n".join(stale)


# ---- 3. the README's Quick start, run --------------------------------------------------------------------------------
def quick_start() -> tuple[list[tuple[int, str, list[str]]], list[str]]:
    """The seqnet calls and the Python snippets of the README's "Quick start" section."""
    section = re.search(r"^## Quick start\n(.*?)(?=^## )", README.read_text(encoding="utf-8"), re.M | re.S)
    assert section, "README.md has no '## Quick start' section"
    calls = [c for c in command_lines(README) if c[1] in section.group(1)]
    snippets = [body for _, _, body in blocks(README, {"python"}) if body in section.group(1)]
    assert calls and snippets, "the Quick start holds no seqnet command or no Python snippet"
    return calls, snippets


def stand_in_model(cwd: Path, args) -> None:  # noqa: ANN001 - the parsed `seqnet train` arguments
    """``RUN/best.pt`` of an untrained S_L of the shape ``seqnet train`` would write: training takes minutes (S_1 on
    the synthetic dataset: 160 s on 2 cores), so the test checks its command line and the later commands run on this."""
    import torch

    from seqnet import SeqNet, load_dataset
    from seqnet.sequence.checkpoints import save_checkpoint

    ds = load_dataset(cwd / args.dataset)
    torch.manual_seed(0)
    model = SeqNet(ds.reference.dim, args.out_dims or ds.reference.dim, args.seq_len, args.w)
    model.provenance = ds.reference.provenance
    (cwd / args.out).mkdir(parents=True)
    save_checkpoint(cwd / args.out / "best.pt", model)


def test_quick_start_runs(tmp_path):
    calls, snippets = quick_start()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(SRC), os.environ.get("PYTHONPATH")]))}
    for line, text, argv in calls:
        args = parse(argv)
        assert not isinstance(args, (Exception, str)), f"README.md:{line}: {text}\n    {args}"
        if argv[0] == "train":
            stand_in_model(tmp_path, args)
            continue
        done = subprocess.run([sys.executable, "-m", "seqnet", *argv], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=120)
        assert done.returncode == 0, f"README.md:{line}: {text}\n{done.stderr[-2000:]}"
        assert not getattr(args, "out", None) or (tmp_path / args.out).exists(), f"README.md:{line}: no {args.out}"
    for code in snippets:
        done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=120)
        assert done.returncode == 0, f"README.md Quick start snippet:\n{code}\n{done.stderr[-2000:]}"


@pytest.mark.parametrize("line", ["seqnet eval --dataset d --out o  # x", "$ PYTHONPATH=src python -m seqnet synth d",
                                  "pip install x && seqnet demo 2>&1 | tail"])
def test_command_lines_are_found(line):
    assert seqnet_argvs(line) in ([["eval", "--dataset", "d", "--out", "o"]], [["synth", "d"]], [["demo"]])

"""The package's layers import only downwards, and nothing imports in a circle.

Every ``import`` of the package, at module level or inside a function, is an edge; the layers
are read from the tree (see docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import tactilesnn

ROOT = Path(tactilesnn.__file__).resolve().parent

#: bottom to top; a module is in the first layer with a matching prefix
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("core", ("core",)),
    ("schema", ("schema",)),
    ("components", ("datasets_synth", "encoders", "models", "recordings", "readers")),
    ("pipeline", ("config", "data_policy", "resolve", "pipeline", "trainer", "baselines")),
    (
        "training | export | service",
        ("training", "selection", "estimator", "stream_training", "export", "service"),
    ),
    ("application", ("app",)),
    ("benchmarks", ("bench",)),
    ("cli", ("cli", "__main__")),
]
#: layer 4's parts sit side by side: none imports another (the estimator and the encoder
#: selection are part of training)
SIDE_BY_SIDE = {
    "training": "training",
    "selection": "training",
    "estimator": "training",
    "stream_training": "training",
    "export": "export",
    "service": "service",
}


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path) -> set[str]:
    """Package modules imported by ``path`` (relative dotted names, '' = the package root)."""
    mod = _module(path)
    pkg = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
    if mod == "":
        pkg = []
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - (node.level - 1)]
                target = ".".join([*base, *([node.module] if node.module else [])])
            elif (node.module or "").startswith("tactilesnn"):
                target = node.module[len("tactilesnn") :].lstrip(".")
            else:
                continue
            for alias in node.names:  # `from . import x` may name a submodule
                sub = f"{target}.{alias.name}".lstrip(".")
                out.add(sub if _exists(sub) else target)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("tactilesnn"):
                    out.add(alias.name[len("tactilesnn") :].lstrip("."))
    return {m for m in out if m != mod}


def _exists(mod: str) -> bool:
    p = ROOT.joinpath(*mod.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def _layer(mod: str) -> int:
    if mod in ("", "core.version"):  # the package root imports nothing eagerly
        return 0
    head = mod.split(".")[0]
    for i, (_, prefixes) in enumerate(LAYERS):
        if head in prefixes:
            return i
    raise AssertionError(f"module tactilesnn.{mod} is in no layer: add it to LAYERS")


def _graph() -> dict[str, set[str]]:
    return {_module(p): _imports(p) for p in ROOT.rglob("*.py")}


@pytest.mark.slow
def test_every_module_is_in_a_layer():
    for mod in _graph():
        _layer(mod)


@pytest.mark.slow
def test_no_upward_import():
    bad = []
    for mod, deps in _graph().items():
        if mod == "":
            continue
        for dep in deps:
            if dep != "" and _layer(dep) > _layer(mod):
                bad.append(f"{mod} ({LAYERS[_layer(mod)][0]}) -> {dep} ({LAYERS[_layer(dep)][0]})")
    assert not bad, "upward imports:\n" + "\n".join(sorted(bad))


@pytest.mark.slow
def test_training_export_and_service_do_not_import_each_other():
    bad = []
    for mod, deps in _graph().items():
        part = SIDE_BY_SIDE.get(mod.split(".")[0])
        if part is not None:
            bad += [f"{mod} -> {d}" for d in deps
                    if SIDE_BY_SIDE.get(d.split(".")[0], part) != part]  # fmt: skip
    assert not bad, bad


@pytest.mark.slow
def test_no_import_circle():
    graph = _graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if d not in graph:
                continue
            if state.get(d) == 1:
                cycle = [*stack[stack.index(d) :], d]
                raise AssertionError("import circle: " + " -> ".join(cycle))
            if d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


@pytest.mark.slow
def test_the_service_never_imports_torch():
    """``tactilesnn.service`` runs with numpy + onnxruntime only (a deployment without torch)."""
    graph = _graph()
    seen, todo = set(), [m for m in graph if m.startswith("service")]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        todo += [d for d in graph.get(m, ()) if d in graph]
    for m in seen:
        text = ROOT.joinpath(*m.split(".")).with_suffix(".py")
        text = text if text.is_file() else ROOT.joinpath(*m.split("."), "__init__.py")
        tree = ast.parse(text.read_text())
        names = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import)
                 for a in n.names} | {(n.module or "").split(".")[0] for n in ast.walk(tree)
                                      if isinstance(n, ast.ImportFrom) and not n.level}  # fmt: skip
        assert "torch" not in names, f"tactilesnn.{m} imports torch"


@pytest.mark.slow
def test_the_command_line_imports_only_the_application_layer():
    """cli.py parses, calls ``app`` (or, for ``tactilesnn bench``, the benchmark package) and
    prints: every package import it makes is of those two."""
    graph = _graph()
    outside = sorted(m for m in graph["cli"]
                     if m in graph and m.split(".")[0] not in ("app", "bench"))  # fmt: skip
    assert not outside, f"cli.py imports {outside}: go through tactilesnn.app"


def test_architecture_page_names_only_modules_that_exist():
    """docs/architecture.md's tree names modules (``name.py``) that are in the package."""
    import re

    page = (ROOT.parent / "docs" / "architecture.md").read_text()
    tree = page[page.index("```") : page.index("```", page.index("```") + 3)]
    named = set(re.findall(r"\b([a-z_]+)\.py\b", tree))
    files = {p.stem for p in ROOT.rglob("*.py")}
    missing = sorted(named - files)
    assert not missing, f"docs/architecture.md names {missing}, not in the package"


@pytest.mark.slow
def test_product_code_never_imports_a_benchmark():
    """The benchmarks sit beside the product: only the command line's ``bench`` command (and
    the benchmarks themselves) import them."""
    bad = []
    for mod, deps in _graph().items():
        if mod.split(".")[0] in ("bench", "cli"):
            continue
        bad += [f"{mod} -> {d}" for d in deps if d.split(".")[0] == "bench"]
    assert not bad, bad


#: the longest a function of the package may be (lines, decorators and docstring included)
MAX_FUNCTION_LINES = 80


def test_no_function_is_longer_than_a_screen():
    """Functions under ~80 lines: a longer one does several things; split it by concern."""
    long = []
    for path in ROOT.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({n})")
    assert not long, long

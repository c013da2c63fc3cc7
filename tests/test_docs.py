"""The README and docs/ teach what the code does: every command in them parses with the CLI's own
parser, the README's Python quickstart runs, every docs page is linked, the README stays short."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from tactilesnn.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _shell_blocks(text: str) -> list[str]:
    return re.findall(r"```(?:sh|bash|console)\n(.*?)```", text, re.S)


def _commands(text: str) -> list[tuple[str, list[str]]]:
    """``tactilesnn ...`` / ``python train.py ...`` invocations of the shell blocks (a synopsis
    line with ``[optional]`` parts or ``...`` is skipped)."""
    out = []
    for block in _shell_blocks(text):
        for raw in block.splitlines():
            line = raw.split(" #")[0].strip()
            for part in re.split(r"&&|;|\|(?!\|)|(?<!&)&(?!&)", line):
                part = part.strip()
                if part.startswith("python train.py"):
                    part = "tactilesnn" + part[len("python train.py") :]
                if not part.startswith("tactilesnn ") or "..." in part or "[" in part:
                    continue
                out.append((raw.strip(), shlex.split(part)[1:]))
    return out


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_command_parses(page):
    parser = build_parser()
    for raw, argv in _commands(page.read_text()):
        try:
            parser.parse_args(argv)
        except SystemExit as e:
            raise AssertionError(f"{page.name}: `{raw}` does not parse") from e


def test_the_docs_show_commands():
    assert sum(len(_commands(p.read_text())) for p in PAGES) >= 15


def test_every_docs_page_is_linked_from_the_readme_and_it_stays_short():
    readme = (ROOT / "README.md").read_text()
    for page in (ROOT / "docs").glob("*.md"):
        assert f"](docs/{page.name})" in readme, f"docs/{page.name} is not linked from README"
    for target in re.findall(r"\]\(((?:docs/)?[\w./-]+\.(?:md|png))\)", readme):
        assert (ROOT / target).is_file(), f"README links to a missing {target}"
    assert len(readme.splitlines()) < 250


def test_readme_python_quickstart_runs(tmp_path, monkeypatch):
    code = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert code, "the README has a Python quickstart"
    monkeypatch.chdir(tmp_path)
    exec(compile(code[0], "README.md", "exec"), {"__name__": "readme"})
    assert (tmp_path / "model.onnx").is_file()

"""The fused kernel's build is keyed by what it depends on: environments that differ build side
by side, identical ones share a build; without a terminal the compile says so in one line."""

from __future__ import annotations

import tactilesnn.models._lif_kernel as lk


def test_build_name_follows_source_torch_compiler_and_flags(monkeypatch):
    base = lk.build_name()
    assert base == lk.build_name() and base.startswith("tactilesnn_lif_")
    monkeypatch.setattr(lk, "CFLAGS", ("-O2", "-fopenmp"))
    flags = lk.build_name()
    monkeypatch.undo()
    monkeypatch.setattr(lk, "_SOURCE", lk._SOURCE + "\n// changed\n")
    source = lk.build_name()
    monkeypatch.undo()
    monkeypatch.setenv("CXX", "/opt/other/g++")
    compiler = lk.build_name()
    monkeypatch.undo()
    import torch

    monkeypatch.setattr(torch, "__file__", "/elsewhere/venv/torch/__init__.py")
    other_env = lk.build_name()
    assert len({base, flags, source, compiler, other_env}) == 5


def test_compiling_without_a_terminal_prints_one_line_before_and_after(capsys):
    with lk._elapsed_bar("kernel"):
        pass
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "compiling" in err[0] and err[1].startswith("kernel: done in")
    with lk._elapsed_bar("kernel", quiet=True):  # a cached build: nothing
        pass
    assert capsys.readouterr().err == ""

"""Benchmarks (``tactilesnn bench <name>``), one module each: the one home of the project's
benchmarks (no product code imports one).

A benchmark module defines ``HELP`` (one line), ``add_arguments(parser)`` (its own flags; ``--out``
and ``--quiet`` are every benchmark's) and ``main(out, options) -> exit status``; its measuring
functions (``run(...)``) are the Python API. Adding one: a new module and a line below.
"""

from __future__ import annotations

from types import ModuleType

from ..core.registry import Registry

#: name on the command line -> its module (imported when first asked for)
BENCHMARKS: Registry = Registry("benchmark")
for _name, _module in (
    ("gwt-vs-stft", "gwt_vs_stft"), ("encoders", "encoders"), ("snn", "snn"),
    ("serve", "serve"), ("tasks", "tasks"), ("real", "real"), ("pareto", "pareto"),
    ("stability", "stability"), ("skip", "skip"), ("busy", "busy"), ("sim2real", "sim2real"),
    ("localise", "localise"), ("fit", "fit"), ("gpu", "gpu"), ("graphs", "graphs"),
    ("shift", "shift"),
):  # fmt: skip
    BENCHMARKS.register_module(_name, f"{__name__}.{_module}")


def benchmark(name: str) -> ModuleType:
    """The module of benchmark ``name`` (ValueError naming the known ones)."""
    return BENCHMARKS.get(name)


def write_result(out, name: str, obj: dict) -> None:
    """``obj`` as ``out/name`` (JSON, atomic) when ``out`` is given; says where."""
    from pathlib import Path

    from ..core.files import write_json_atomic

    if out is None:
        return
    path = Path(out) / name
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, obj)
    print(f"results: {path}")


#: the environment variable naming the folder of real recordings the benchmarks read
#: (``--data-root`` wins); the benchmarks never guess a path relative to the repository
DATA_ROOT_ENV = "TACTILESNN_DATA_ROOT"


def add_data_root(p, what: str) -> None:
    """The ``--data-root DIR`` flag (default: ``$TACTILESNN_DATA_ROOT``)."""
    import os

    p.add_argument("--data-root", default=os.environ.get(DATA_ROOT_ENV),
                   help=f"folder holding {what} (read in place, never copied; default: "
                        f"${DATA_ROOT_ENV})")  # fmt: skip


def data_root(options, name: str):
    """``options.data_root`` as a folder that exists (ValueError saying how to give one)."""
    from pathlib import Path

    if not options.data_root:
        raise ValueError(f"bench {name} reads real recordings: give their folder with "
                         f"--data-root DIR or the environment variable {DATA_ROOT_ENV}")  # fmt: skip
    root = Path(options.data_root)
    if not root.is_dir():
        raise ValueError(f"--data-root {root}: no such folder")
    return root


def require_out(out, name: str):
    if out is None:
        raise ValueError(f"bench {name} needs --out DIR")
    return out


def add_quick_and_overwrite(p, result: str) -> None:
    """The ``--quick`` / ``--overwrite`` flags of the benchmarks that write ``result``."""
    p.add_argument("--quick", action="store_true", help="a few small cases (as the tests run)")
    p.add_argument("--overwrite", action="store_true", help=f"replace an existing {result}")

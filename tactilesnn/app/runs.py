"""Run folders: atomic writes, no silent overwrite, weights without pickle."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from ..core.files import jsonable


class RunExistsError(FileExistsError):
    """The requested run folder exists and overwriting was not asked for."""


def default_run_dir(root: Path, *parts: str) -> Path:
    """``root/<parts joined by ->-<UTC timestamp>``, unique within the second."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    base = root / "-".join([*parts, stamp])
    path, k = base, 1
    while path.exists():
        path, k = Path(f"{base}_{k}"), k + 1
    return path


def is_run_folder(path: Path) -> bool:
    """True if ``path`` is a run folder this package wrote (its ``config.json`` says so)."""
    cfg = Path(path) / "config.json"
    try:
        d = json.loads(cfg.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(d, dict) and "tactilesnn_version" in d and "pipeline" in d


def check_writable(path: Path, overwrite: bool) -> None:
    """Fail early, before any work, when ``path`` exists and may not be replaced.

    ``--overwrite`` replaces only a run folder this package wrote: never a file, and never a
    folder holding anything else (``--out . --overwrite`` must not wipe a working directory).
    """
    if not path.exists() and not path.is_symlink():
        return
    if not path.is_dir() or path.is_symlink():
        raise RunExistsError(f"{path} exists and is not a run folder; choose another --out")
    if not overwrite:
        raise RunExistsError(
            f"run folder {path} already exists; pass --overwrite to replace it or choose another --out"
        )
    if any(path.iterdir()) and not is_run_folder(path):
        raise RunExistsError(
            f"{path} is not a tactilesnn run folder (no config.json written by tactilesnn): "
            "refusing to replace it; choose another --out"
        )


class RunWriter:
    """Collects a run's files in a temporary sibling folder and moves it into place at the end.

    An interrupted run never leaves a half-written folder under the final name, and an existing
    folder is replaced only if ``overwrite`` was given.
    """

    def __init__(self, path: Path, overwrite: bool = False) -> None:
        self.path = Path(path)
        self.overwrite = overwrite
        check_writable(self.path, overwrite)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.parent))

    def write_json(self, name: str, obj: object) -> None:
        (self.tmp / name).write_text(json.dumps(obj, indent=2, sort_keys=True, default=jsonable))

    def write_arrays(self, name: str, arrays: dict[str, np.ndarray]) -> None:
        np.savez(self.tmp / name, **arrays)

    def file(self, name: str) -> Path:
        return self.tmp / name

    def commit(self) -> Path:
        check_writable(self.path, self.overwrite)
        if self.path.exists():
            old = self.path.with_name(f".{self.path.name}.old-{os.getpid()}")
            os.replace(self.path, old)
            os.replace(self.tmp, self.path)
            shutil.rmtree(old)
        else:
            os.replace(self.tmp, self.path)
        return self.path

    def abort(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)

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


#: the marker tactilesnn writes into every folder it creates (run, checkpoint, temporary): what
#: kind of folder it is, a random token, the writing process and the files it wrote. Only folders
#: whose every entry tactilesnn can prove it wrote are ever removed.
MARKER = ".tactilesnn-owner.json"
#: what a run folder holds (folders written before the marker are recognised by these names)
RUN_FILES = frozenset({
    "config.json", "config.toml", "weights.npz", "metrics.json", "confusion_matrix.json",
    "confusion_matrix.png", "training_error.png", "test_windows.png", "model.onnx",
    "model.int8.onnx", "model.nir", MARKER,
    # temporaries of an interrupted export / metrics update
    ".model.onnx.tmp", ".metrics.json.tmp", ".model.int8.onnx.tmp",
})  # fmt: skip
#: what a checkpoint folder (``<out>.partial``) holds
PARTIAL_FILES = frozenset({"run.json", "checkpoint.json", "checkpoint.npz", "checkpoint.tmp.json",
                           "checkpoint.tmp.npz", ".run.json.tmp", MARKER})  # fmt: skip


class ForeignFilesError(FileExistsError):
    """A folder tactilesnn would replace holds files it did not write."""


def write_marker(folder: Path, kind: str) -> None:
    """Mark ``folder`` as written by this process (see :data:`MARKER`)."""
    import secrets

    (Path(folder) / MARKER).write_text(json.dumps(
        {"kind": kind, "token": secrets.token_hex(16), "pid": os.getpid(),
         "files": sorted(p.name for p in Path(folder).iterdir() if p.name != MARKER)}
    ))  # fmt: skip


def read_marker(folder: Path) -> dict | None:
    """The folder's marker, or None if it has none (or it is not one tactilesnn wrote)."""
    try:
        d = json.loads((Path(folder) / MARKER).read_text())
    except (OSError, ValueError):
        return None
    ok = isinstance(d, dict) and isinstance(d.get("token"), str) and len(d["token"]) == 32
    return d if ok else None


def foreign_entries(folder: Path, known: frozenset[str]) -> list[str]:
    """Entries of ``folder`` tactilesnn did not write: not named in ``known`` nor in the
    folder's marker (sub-folders and links are always foreign)."""
    marker = read_marker(folder) or {}
    listed = set(marker.get("files", ())) | known
    out = []
    for p in sorted(Path(folder).iterdir()):
        if p.name not in listed or p.is_symlink() or p.is_dir():
            out.append(p.name)
    return out


def remove_owned(folder: Path, known: frozenset[str], what: str) -> None:
    """Remove ``folder`` if every entry in it is one tactilesnn wrote (ForeignFilesError
    naming the others otherwise; nothing is removed then). A folder that is a link or a file
    is never removed."""
    folder = Path(folder)
    if folder.is_symlink() or not folder.is_dir():
        raise ForeignFilesError(f"{folder} is not a folder tactilesnn wrote (a link or a file); "
                                f"move it away or choose another --out")  # fmt: skip
    if read_marker(folder) is None and not any(folder.iterdir()):
        raise ForeignFilesError(f"{folder} is an empty folder tactilesnn did not make; remove it "
                                "or choose another --out")  # fmt: skip
    foreign = foreign_entries(folder, known)
    if foreign:
        shown = ", ".join(foreign[:5]) + (
            f" and {len(foreign) - 5} more" if len(foreign) > 5 else ""
        )
        raise ForeignFilesError(f"{what} {folder} holds files tactilesnn did not write ({shown}); "
                                "nothing was removed: move them away or choose another --out")  # fmt: skip
    shutil.rmtree(folder)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


class OutLock:
    """``<out>.lock``: one training writes into an ``--out`` at a time (refused up front). The
    lock is created with its content in one step (a hard link of a written temporary file), so a
    lock of ours always holds its process id and token; a lock whose process no longer runs is
    taken over, and anything else at that name (a user's file, an empty or unreadable one) is
    refused, named, and left as it is."""

    def __init__(self, out: Path) -> None:
        import secrets

        self.path = Path(out).with_name(Path(out).name + ".lock")
        self.token = secrets.token_hex(16)

    def __enter__(self) -> OutLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f"{self.path.name}.{self.token}.tmp")
        try:  # (a full disk fails here, before any lock exists; the temporary file goes)
            tmp.write_text(json.dumps({"pid": os.getpid(), "token": self.token}))
            for _ in range(2):
                try:
                    self._create(tmp)
                    return self
                except FileExistsError:
                    held = self._holder()
                    if held is None:
                        raise RunExistsError(
                            f"{self.path} exists and is not a tactilesnn lock (it does not hold "
                            "a process id and token that tactilesnn wrote); it is left as it "
                            "is: move it away or choose another --out"
                        ) from None
                    if _pid_alive(held):
                        raise RunExistsError(
                            f"another tactilesnn process (pid {held}) is writing "
                            f"{self.path.with_suffix('')}; wait for it or choose another --out"
                        ) from None
                    self.path.unlink(missing_ok=True)  # its process is gone
        finally:
            tmp.unlink(missing_ok=True)
        raise RunExistsError(f"could not take the lock {self.path}")

    def _create(self, written: Path) -> None:
        """The lock at :attr:`path` with ``written``'s content, failing if it exists."""
        try:
            os.link(written, self.path)
        except FileExistsError:
            raise
        except OSError:  # a file system without hard links: create exclusively, then write
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            try:
                with os.fdopen(fd, "w") as f:
                    f.write(written.read_text())
            except OSError:
                self.path.unlink(missing_ok=True)
                raise

    def _holder(self) -> int | None:
        """The process id a lock of ours holds; None for anything else at that name."""
        try:
            if self.path.is_symlink() or not self.path.is_file():
                return None
            d = json.loads(self.path.read_text())
            ok = isinstance(d, dict) and set(d) == {"pid", "token"}
            return (
                int(d["pid"])
                if ok and isinstance(d["token"], str) and len(d["token"]) == 32
                else None
            )
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def __exit__(self, *exc: object) -> None:
        try:
            if json.loads(self.path.read_text()).get("token") == self.token:
                self.path.unlink()
        except (OSError, ValueError):
            pass


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
    foreign = foreign_entries(path, RUN_FILES)
    if foreign:
        raise ForeignFilesError(
            f"run folder {path} also holds files tactilesnn did not write ({', '.join(foreign[:5])}"
            "); --overwrite would delete them: move them away or choose another --out"
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
        _remove_stale_temporaries(self.path)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.parent))
        write_marker(self.tmp, "tmp")

    def write_json(self, name: str, obj: object) -> None:
        (self.tmp / name).write_text(json.dumps(obj, indent=2, sort_keys=True, default=jsonable))

    def write_arrays(self, name: str, arrays: dict[str, np.ndarray]) -> None:
        np.savez(self.tmp / name, **arrays)

    def file(self, name: str) -> Path:
        return self.tmp / name

    def commit(self) -> Path:
        check_writable(self.path, self.overwrite)
        write_marker(self.tmp, "run")
        if self.path.exists():
            old = self.path.with_name(f".{self.path.name}.old-{os.getpid()}")
            os.replace(self.path, old)
            os.replace(self.tmp, self.path)
            remove_owned(old, RUN_FILES, "the replaced run folder")  # (checked above)
        else:
            os.replace(self.tmp, self.path)
        return self.path

    def abort(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)


def _remove_stale_temporaries(path: Path) -> None:
    """Temporary folders of ``path`` left by a killed process (their marker's process is gone)."""
    for tmp in path.parent.glob(f".{path.name}.*"):
        marker = read_marker(tmp) if tmp.is_dir() and not tmp.is_symlink() else None
        if (
            marker is not None
            and marker.get("kind") == "tmp"
            and not _pid_alive(int(marker["pid"]))
        ):
            try:
                remove_owned(tmp, RUN_FILES, "a temporary folder")
            except ForeignFilesError:
                pass  # something else was put there: leave it

"""Files without pickle, written atomically (temporary file + rename)."""

from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def replace_atomically(path: Path, write: Callable[[Path], object], suffix: str = "") -> None:
    """``write(tmp)`` to a temporary file beside ``path`` (``.<name>.tmp<suffix>``; ``suffix``
    for writers that insist on an extension), then rename it onto ``path``: readers see the old
    file or the new one, never half of one; on any failure (a full disk) the temporary file is
    removed and ``path`` left as it was."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text_atomic(path: Path, text: str) -> None:
    """Replace ``path`` with ``text`` (:func:`replace_atomically`)."""
    replace_atomically(path, lambda tmp: tmp.write_text(text))


def write_json_atomic(path: Path, obj: object) -> None:
    """Replace ``path`` with ``obj`` as JSON (temporary file + rename; the temporary file is
    removed if the write fails, e.g. on a full disk)."""
    write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=True, default=jsonable))


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes; of a folder: of its ``manifest.json`` when it has one (a
    generated dataset's manifest holds every shard's hash), else of every file's relative name
    and bytes (a folder of recordings)."""
    import hashlib

    path = Path(path)
    h = hashlib.sha256()
    if path.is_dir() and not (path / "manifest.json").is_file():
        files = sorted(p for p in path.rglob("*") if p.is_file())
    else:
        files = [path / "manifest.json" if path.is_dir() else path]
    for p in files:
        if path.is_dir():
            h.update(os.fsencode(p.relative_to(path)) + b"\0")  # (undecodable names too)
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def load_arrays(path: Path) -> dict[str, np.ndarray]:
    """Load a weights file written by :meth:`RunWriter.write_arrays` (pickle disabled)."""
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise ValueError(f"{path} is corrupt or not a weights file ({e})") from e


#: the largest JSON file a run folder holds (config, metrics, checkpoint notes)
MAX_JSON_BYTES = 64 << 20


def read_json(path: Path) -> dict:
    """The JSON object at ``path``; ValueError naming the file when it is not one (not UTF-8,
    malformed, too large, not a regular file, or not an object)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: not a regular file")
    if path.stat().st_size > MAX_JSON_BYTES:
        raise ValueError(f"{path}: {path.stat().st_size} bytes; at most {MAX_JSON_BYTES} expected")
    try:
        doc = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, RecursionError, ValueError) as e:
        raise ValueError(f"{path}: not a readable JSON file ({str(e)[:120]})") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: a JSON object expected, got {type(doc).__name__}")
    return doc


def jsonable(o: object) -> object:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_npz_atomic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """``arrays`` as a compressed ``.npz`` at ``path`` (temporary file + rename)."""
    replace_atomically(path, lambda tmp: np.savez_compressed(tmp, **arrays), ".npz")


def npy_header(f: Any) -> tuple[tuple[int, ...], np.dtype]:
    """``(shape, dtype)`` from the header of the ``.npy`` stream ``f`` (a file or a zip member),
    no data read: what an array would take is known before it is loaded. ValueError if it is
    not a ``.npy`` header."""
    major, _ = np.lib.format.read_magic(f)
    read = (np.lib.format.read_array_header_1_0 if major == 1
            else np.lib.format.read_array_header_2_0)  # fmt: skip
    shape, _, dtype = read(f)
    return tuple(shape), dtype

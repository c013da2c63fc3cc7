"""Property-based fuzzing of the hostile surfaces of hardening II (any JSON document as a
request body is in ``test_fuzz.py``): array headers that lie about their size, settings files
of any type, and the states a run folder and its checkpoint folder may be found in. Each ends
in a specific error or a correct result, never a traceback or a file of the user's removed."""

from __future__ import annotations

import io
import json
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tactilesnn.app.config_file import read_train_file
from tactilesnn.cli import main
from tactilesnn.recordings import load_data_file

FUZZ = settings(max_examples=40, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip


@st.composite
def lying_npz(draw):
    """An .npz whose X.npy header declares a shape (up to terabytes) over a tiny body."""
    shape = tuple(draw(st.lists(st.integers(0, 10**7), min_size=1, max_size=4)))
    dtype = draw(st.sampled_from(["<f4", "<f8", "<i2", "|u1"]))
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": dtype, "fortran_order": False,
                                                  "shape": shape})  # fmt: skip
    body = header.getvalue() + bytes(draw(st.integers(0, 64)))
    return body


@FUZZ
@given(lying_npz())
def test_array_headers_that_lie_are_refused_before_reading(body):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "x.npz"
        with zipfile.ZipFile(path, "w") as z:
            z.writestr("X.npy", b"\x93NUMPY" + body[6:] if body[:6] == b"\x93NUMPY" else body)
            for name, arr in {"y": np.zeros(2, np.int64), "fs": np.array(100.0),
                              "class_names": np.array(["a", "b"])}.items():  # fmt: skip
                buf = io.BytesIO()
                np.save(buf, arr)
                z.writestr(f"{name}.npy", buf.getvalue())
        with pytest.raises((ValueError, FileNotFoundError)):
            load_data_file(path, seed=0)


toml_values = st.one_of(
    st.booleans(), st.integers(-(2**63), 2**63 - 1), st.floats(allow_nan=False),
    st.text(max_size=5).map(json.dumps), st.lists(st.integers(0, 3), max_size=3).map(str),
)  # fmt: skip
KEYS = ["out", "overwrite", "resume", "quiet", "task", "data", "epochs", "seed", "val_fraction",
        "export", "clock_afferents", "encoder", "model", "n_bands", "difficulty"]  # fmt: skip


@FUZZ
@given(st.dictionaries(st.sampled_from(KEYS), toml_values, max_size=5))
def test_settings_files_of_any_type_are_typed_or_refused(table):
    lines = [f"{k} = {str(v).lower() if isinstance(v, bool) else v}" for k, v in table.items()]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "c.toml"
        path.write_text("\n".join(lines) + "\n")
        try:
            f = read_train_file(path)
        except ValueError as e:
            assert str(e)
            return
    for key in ("overwrite", "resume", "quiet", "export"):
        value = f.command.get(key, f.run.get(key))
        assert value is None or isinstance(value, bool)
    assert isinstance(f.command.get("out", ""), str)


TINY = ["--task-kw", "n_planar=4", "--task-kw", "n_concave=2", "--task-kw", "n_convex=2",
        "--task-kw", "n_test=2", "--epochs", "1", "--quiet", "--no-export"]  # fmt: skip
STATES = ["absent", "user-dir", "user-empty-dir", "file", "link"]


@pytest.mark.slow
@settings(max_examples=12, deadline=None)
@given(st.sampled_from(STATES), st.sampled_from(["absent", "run+notes", "user-dir"]),
       st.booleans(), st.booleans())  # fmt: skip
def test_folder_states_never_lose_a_users_file(partial_state, out_state, overwrite, resume):
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        out, partial = tmp / "r", tmp / "r.partial"
        precious = {}

        def keep(path: Path, text: str) -> None:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            precious[path] = text

        if out_state == "run+notes":
            assert main(["train", *TINY, "--out", str(out)]) == 0
            keep(out / "notes.md", "mine")
        elif out_state == "user-dir":
            keep(out / "thesis.tex", "mine")
        if partial_state == "user-dir":
            keep(partial / "data.csv", "1,2")
        elif partial_state == "user-empty-dir":
            partial.mkdir()
        elif partial_state == "file":
            keep(partial, "a file")
        elif partial_state == "link":
            keep(tmp / "elsewhere" / "keep", "x")
            os.symlink(tmp / "elsewhere", partial)
        argv = ["train", *TINY, "--out", str(out)]
        rc = main([*argv, *(["--overwrite"] if overwrite else []),
                   *(["--resume"] if resume else [])])  # fmt: skip
        assert rc in (0, 2)
        for path, text in precious.items():
            assert path.read_text() == text, path
        if partial_state == "user-empty-dir":
            assert partial.is_dir()

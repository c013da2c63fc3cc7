"""The README's training commands run under a 2 GiB address-space limit (issue: 19 GB peaks).

Each command is taken from README.md as written, with ``--epochs 1`` (memory does not grow with
epochs) and a temporary ``--out``; it runs in a subprocess whose ``RLIMIT_AS`` is 2 GiB, so any
allocation beyond the bound fails the command. Training, evaluation and the verified ONNX export
must all succeed.
"""

from __future__ import annotations

import json
import os
import re
import resource
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
LIMIT_BYTES = 2 << 30
#: every task of the README's table (``material``'s LIF encoding of 900 x 8 x 1,500 samples
#: took ~9 min before the closed-form converter; about a minute now)
TASKS = ["texture", "stiffness_curvature", "material", "touch"]


def readme_train_commands() -> dict[str, list[str]]:
    """``tactilesnn train --task ...`` commands of the documented task table (README and
    docs/), by task name."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    text = "\n".join(p.read_text() for p in pages).replace("\\\n", " ")
    out = {}
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("tactilesnn train --task"):
            argv = shlex.split(line)[1:]  # from "train" on
            out[argv[argv.index("--task") + 1]] = argv
    return out


def _limited() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT_BYTES, LIMIT_BYTES))


def _run(argv: list[str]) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("tactilesnn")
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "2")}
    return subprocess.run(
        [str(exe), *argv], preexec_fn=_limited, capture_output=True, text=True, env=env,
        timeout=900,
    )  # fmt: skip


def test_readme_lists_the_task_commands() -> None:
    assert {"texture", "stiffness_curvature", "material", "touch"} <= set(readme_train_commands())


@pytest.mark.slow
@pytest.mark.parametrize("task", TASKS)
def test_readme_command_runs_under_2gib(task: str, tmp_path: Path) -> None:
    argv = readme_train_commands()[task]
    argv = re.sub(r"--epochs \d+", "", " ".join(argv)).split()
    i = argv.index("--out")
    del argv[i : i + 2]
    out = tmp_path / "run"
    argv += ["--epochs", "1", "--quiet", "--out", str(out)]
    proc = _run(argv)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "test accuracy" in proc.stdout
    assert (out / "weights.npz").is_file()
    assert (out / "model.onnx").is_file(), proc.stdout
    if task == "touch":  # the largest task's data: evaluate under the limit too (once suffices)
        ev = _run(["evaluate", str(out), "--json", "--quiet"])
        assert ev.returncode == 0, ev.stderr[-3000:]


def test_limit_is_real(tmp_path: Path) -> None:
    """The limit bites: asking for 3 GiB in the limited child fails (the test above is not
    vacuous)."""
    code = "import numpy as np; np.ones(3 << 30, np.uint8)"
    proc = subprocess.run(
        [sys.executable, "-c", code], preexec_fn=_limited, capture_output=True, text=True
    )
    assert proc.returncode != 0 and "MemoryError" in proc.stderr


@pytest.mark.slow
def test_a_1000_x_13000_sample_20_class_file_trains_under_2gib(tmp_path: Path) -> None:
    """The issue's size: 1,000 recordings of 13,000 samples at 2 kHz, 20 classes (a tone per
    class, random phase and gain, noise). `train --data` with no setting but the epochs: cut into
    7 windows per recording, bands up to 0.45 fs chosen from the rate, encoder chosen on held-out
    recordings, exported and verified; all under the 2 GiB address-space limit (peak RSS measured
    with /usr/bin/time -v: 0.91 GB with the default epochs)."""
    rng = np.random.default_rng(0)
    n, s, fs = 1000, 13000, 2000.0
    y = np.arange(n) % 20
    t = np.arange(s) / fs
    X = np.sin(2 * np.pi * (20 + 15 * y)[:, None] * t + rng.uniform(0, 6, (n, 1)))
    X = X * rng.uniform(0.5, 2, (n, 1)) + 0.5 * rng.standard_normal((n, s))
    path = tmp_path / "big20.npz"
    np.savez(path, X=X[:, None].astype(np.float32), y=y, fs=fs,
             class_names=np.array([f"tone{i}" for i in range(20)]))  # fmt: skip
    del X
    out = tmp_path / "run"
    proc = _run(["train", "--data", str(path), "--epochs", "10", "--quiet", "--out", str(out)])
    assert proc.returncode == 0, proc.stderr[-3000:]
    m = json.loads((out / "metrics.json").read_text())
    assert m["n_train_windows"] + m["n_test_windows"] == 7 * n
    assert m["test_accuracy_per_recording"] >= 0.9, m["test_accuracy_per_recording"]
    assert (out / "model.onnx").is_file()

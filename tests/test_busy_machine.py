"""OpenMP threads do not spin away a busy machine's time slices (see tactilesnn/__init__.py)."""

import os
import subprocess
import sys


def _spin(env: dict) -> str:
    code = "import tactilesnn, os; print(os.environ.get('GOMP_SPINCOUNT'))"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()  # fmt: skip


def test_spin_count_is_bounded_unless_the_user_set_one():
    env = {k: v for k, v in os.environ.items() if k != "GOMP_SPINCOUNT"}
    assert _spin(env) == "10000"
    assert _spin({**env, "GOMP_SPINCOUNT": "300000"}) == "300000"

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


def test_threads_follow_the_cpus_left_by_running_processes(monkeypatch):
    import torch

    from tactilesnn.core.perf import fit_threads

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.delenv("TACTILESNN_THREADS", raising=False)
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas() -> set[int]:
        return {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}

    before = torch.get_num_threads()
    saved = threadpool_limits(limits=None)  # restores numpy's BLAS pools on exit
    try:
        torch.set_num_threads(2)
        threadpool_limits(limits=2, user_api="blas")
        assert fit_threads(cpus=2, others=2) == 1 and torch.get_num_threads() == 1
        assert blas() <= {1}  # numpy's BLAS follows torch's threads (no spinning pool)
        assert fit_threads(cpus=4, others=1) == 3
        assert fit_threads(cpus=2, others=0) == 2
        assert fit_threads(cpus=2, others=0) is None  # already so
        torch.set_num_threads(1)
        threadpool_limits(limits=2, user_api="blas")
        assert fit_threads(cpus=2, others=1) is None  # torch already at 1 ...
        assert blas() <= {1}  # ... and BLAS's pool, sized at numpy's import, follows it too
        torch.set_num_threads(2)
        monkeypatch.setenv("TACTILESNN_THREADS", "1")
        assert fit_threads(cpus=8, others=0) == 1
        monkeypatch.setenv("OMP_NUM_THREADS", "3")  # the user's choice wins
        assert fit_threads(cpus=2, others=5) is None and torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
        saved.restore_original_limits()


def test_runnable_processes_are_read_from_the_kernel_count(tmp_path):
    from tactilesnn.core.perf import other_runnable

    f = tmp_path / "loadavg"
    f.write_text("2.01 1.77 1.32 3/80 19343\n")
    assert other_runnable(samples=3, gap_s=0, path=str(f)) == 2  # itself not counted
    f.write_text("garbage\n")
    assert other_runnable(samples=1, path=str(f)) is None
    assert other_runnable(samples=1, path=str(tmp_path / "none")) is None


def test_threads_are_refitted_while_governed_and_rate_limited(monkeypatch):
    import torch

    from tactilesnn.core import perf

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.delenv("TACTILESNN_THREADS", raising=False)
    before = torch.get_num_threads()
    clock = [100.0]
    monkeypatch.setattr("time.monotonic", lambda: clock[0])
    monkeypatch.setattr(perf, "_last_refit", 0.0)
    try:
        torch.set_num_threads(2)
        monkeypatch.setattr(perf, "_governed", False)
        assert perf.refit_threads(cpus=2, others=1) is None  # fit_threads never chose: untouched
        assert torch.get_num_threads() == 2
        assert perf.fit_threads(cpus=2, others=0) is None and perf._governed  # alone at start
        assert perf.refit_threads(cpus=2, others=1) == 1  # a second training started later
        clock[0] += 0.5
        assert perf.refit_threads(cpus=2, others=0) is None  # not before REFIT_EVERY_S
        assert torch.get_num_threads() == 1
        clock[0] += perf.REFIT_EVERY_S
        assert perf.refit_threads(cpus=2, others=0) == 2  # it ended: both CPUs again
        monkeypatch.setenv("TACTILESNN_THREADS", "2")
        perf.fit_threads(cpus=2, others=0)  # a user setting ends the governing
        clock[0] += perf.REFIT_EVERY_S
        assert not perf._governed and perf.refit_threads(cpus=2, others=1) is None
    finally:
        perf._governed = False
        torch.set_num_threads(before)


def test_a_run_records_the_thread_counts_it_used(monkeypatch):
    """Every count fit_threads set and the current one, and whether they followed the load:
    a seeded result reruns bit-identically only at those counts."""
    import torch

    from tactilesnn.core import perf

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.delenv("TACTILESNN_THREADS", raising=False)
    monkeypatch.setattr(perf, "_counts_set", set())
    monkeypatch.setattr(perf, "_governed", perf._governed)  # (restored afterwards)
    monkeypatch.setattr(perf, "limit_blas", lambda n: None)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        perf.fit_threads(cpus=2, others=1)
        perf.fit_threads(cpus=2, others=0)
        assert perf.compute_threads() == {"counts": [1, 2], "fitted_to_load": True}
        monkeypatch.setenv("TACTILESNN_THREADS", "1")
        monkeypatch.setattr(perf, "_counts_set", set())
        perf.fit_threads()
        assert perf.compute_threads() == {"counts": [1], "fitted_to_load": False}
    finally:
        torch.set_num_threads(before)

"""Speed on a busy machine: ``tactilesnn bench busy``.

The default training (``tactilesnn train --no-export``, a fresh process each time) timed alone and
beside ``--neighbours`` CPU-bound processes (pure-Python loops, as other users' jobs or a sweep's
other trials are), in alternating rounds; medians of the wall times and their ratio. ``--pair``:
beside a second copy of the same training instead (a sweep's normal case), each copy's wall time
against one alone. With ``n``
neighbours on ``c`` usable CPUs a fair scheduler leaves the job ``c / (n + c)`` of the machine at
worst, so a ratio near ``(n + c) / c`` is the share lost, and much more than that is time wasted
(threads spinning at barriers, oversubscription: the 12.5x of issue 30 for a 2x share). The
neighbours are started and stopped by the benchmark (their process group killed), so nothing is
left running.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ..core.perf import usable_cpus

HELP = "the default training alone and beside CPU-bound neighbours: wall times and their ratio"

#: a CPU-bound neighbour: a pure-Python loop (holds its core, no threads)
NEIGHBOUR = [sys.executable, "-c", "while True:\n    pass"]


def train_command(out: Path, epochs: int | None = None) -> list[str]:
    """``tactilesnn train`` with the defaults into ``out`` (no export: the training is timed)."""
    cmd = [sys.executable, "-c", "import sys; from tactilesnn.cli import main; sys.exit(main())",
           "train", "--out", str(out), "--quiet", "--no-export"]  # fmt: skip
    return cmd + (["--epochs", str(epochs)] if epochs else [])


def timed(cmd: list[str]) -> float:
    """Wall seconds of ``cmd`` (RuntimeError with its error output if it fails)."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(
            f"{' '.join(cmd[:3])}... failed ({done.returncode}): {done.stderr[-500:]}"
        )
    return time.perf_counter() - t0


def beside(cmd: list[str], neighbours: int) -> float:
    """Wall seconds of ``cmd`` while ``neighbours`` CPU-bound processes run; they are stopped
    (process group killed) however ``cmd`` ends."""
    procs = [subprocess.Popen(NEIGHBOUR, start_new_session=True) for _ in range(neighbours)]
    try:
        time.sleep(0.5)  # the neighbours hold their cores before the job starts
        return timed(cmd)
    finally:
        for p in procs:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def side_by_side(cmds: list[list[str]]) -> list[float]:
    """Wall seconds of each of ``cmds`` started together (RuntimeError if one fails; the others
    are stopped)."""
    t0 = time.perf_counter()
    procs = [subprocess.Popen(c, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              start_new_session=True) for c in cmds]  # fmt: skip
    ends: list[float | None] = [None] * len(procs)
    try:
        while any(e is None for e in ends):
            for i, p in enumerate(procs):
                if ends[i] is None and p.poll() is not None:
                    ends[i] = time.perf_counter() - t0
                    if p.returncode != 0:
                        raise RuntimeError(f"side-by-side job {i} failed ({p.returncode}): "
                                           f"{p.stderr.read()[-500:] if p.stderr else ''}")  # fmt: skip
            time.sleep(0.05)
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    return [float(e) for e in ends]  # type: ignore[arg-type]


def run_pair(out: Path | None = None, rounds: int = 2, epochs: int | None = None) -> dict:
    """Alternating rounds of (one alone, two side by side) -> medians and the ratio of each copy
    to one alone (a fair share of 2 CPUs between two equal jobs: 1.0x with 2 usable CPUs, 2.0x
    with 1)."""
    if rounds < 1:
        raise ValueError("rounds must be at least 1")
    alone, pair = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            alone.append(timed(train_command(Path(tmp) / f"alone-{r}", epochs)))
            print(f"round {r + 1}: alone {alone[-1]:.1f} s", flush=True)
            both = side_by_side(
                [train_command(Path(tmp) / f"pair-{r}-{i}", epochs) for i in (0, 1)]
            )
            pair += both
            print(f"round {r + 1}: side by side {both[0]:.1f} s and {both[1]:.1f} s", flush=True)
    cpus = usable_cpus()
    res = {"cpus": cpus, "rounds": rounds, "alone_s": alone, "pair_s": pair,
           "alone_median_s": statistics.median(alone), "pair_median_s": statistics.median(pair),
           "fair_share_ratio": max(1.0, 2 / cpus)}  # fmt: skip
    res["ratio"] = res["pair_median_s"] / res["alone_median_s"]
    return _report(res, out, "busy_pair.json",
                   f"one alone {res['alone_median_s']:.1f} s, each of two side by side "
                   f"{res['pair_median_s']:.1f} s: {res['ratio']:.2f}x (the slower copy "
                   f"{max(pair) / res['alone_median_s']:.2f}x of the median alone)")  # fmt: skip


def _report(res: dict, out: Path | None, name: str, line: str) -> dict:
    """Print ``line`` and write ``res`` as ``out/name`` (when ``out`` is given)."""
    print(line)
    if out is not None:
        from . import write_result

        write_result(out, name, res)
    return res


def run(
    out: Path | None = None,
    neighbours: int = 2,
    rounds: int = 2,
    epochs: int | None = None,
    command: list[str] | None = None,
) -> dict:
    """Alternating rounds of (alone, beside) -> medians, ratio and the fair-share ratio.
    ``command``: the job to time (default: the default training into a temporary folder)."""
    if neighbours < 1 or rounds < 1:
        raise ValueError("neighbours and rounds must be at least 1")
    alone, busy = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            for kind, times in (("alone", alone), ("beside", busy)):
                cmd = command or train_command(Path(tmp) / f"run-{r}-{kind}", epochs)
                times.append(timed(cmd) if kind == "alone" else beside(cmd, neighbours))
                print(f"round {r + 1}: {kind} {times[-1]:.1f} s", flush=True)
    cpus = usable_cpus()
    res = {
        "cpus": cpus,
        "neighbours": neighbours,
        "rounds": rounds,
        "alone_s": alone,
        "beside_s": busy,
        "alone_median_s": statistics.median(alone),
        "beside_median_s": statistics.median(busy),
        "fair_share_ratio": (neighbours + cpus) / cpus,
    }
    res["ratio"] = res["beside_median_s"] / res["alone_median_s"]
    return _report(res, out, "busy.json",
                   f"alone {res['alone_median_s']:.1f} s, beside {neighbours} CPU-bound neighbours "
                   f"{res['beside_median_s']:.1f} s: {res['ratio']:.2f}x (a fair share of {cpus} "
                   f"CPUs: {res['fair_share_ratio']:.2f}x)")  # fmt: skip


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--neighbours", type=int, default=2, help="CPU-bound processes beside the job")
    p.add_argument("--rounds", type=int, default=2, help="alternating (alone, beside) rounds")
    p.add_argument(
        "--epochs", type=int, default=None, help="training epochs (default: the default's)"
    )
    p.add_argument("--pair", action="store_true",
                   help="two copies of the training side by side, not CPU-bound neighbours")  # fmt: skip


def main(out: Path | None, options: argparse.Namespace) -> int:
    if options.pair:
        run_pair(out, rounds=options.rounds, epochs=options.epochs)
        return 0
    run(out, neighbours=options.neighbours, rounds=options.rounds, epochs=options.epochs)
    return 0

"""Grid or random search over any ``tactilesnn train`` settings; each trial a normal run folder.

A sweep file (TOML) names the settings by their ``train`` flag (``n_bands`` = ``--n-bands``)::

    [base]              # given to every trial
    task = "hook_loop"
    epochs = 5
    [grid]              # every combination of these lists
    encoder = ["gwt", "stft"]
    n_bands = [10, 20]
    [random]            # or: `trials` draws (seeded) from these
    trials = 6
    seed = 0
    [random.space]
    n_bands = [8, 12, 16, 20]               # a list: one of its values
    readout_lr = {log_uniform = [1e-3, 3e-2]}
    readout_tau_ms = {uniform = [50, 200]}

Trials are enumerated deterministically; a trial's folder is named from its settings
(``trials/t003-<sha1>``), so a sweep started again skips the trials whose run folder is complete
(resume) and a changed sweep file only runs what is new. Trials run in local worker processes
(``workers``) or on a Dask cluster (``scheduler="tcp://host:port"``, needs the ``distributed``
extra; a worker that dies has its trial run again elsewhere). Every trial writes its run atomically,
so a killed worker leaves no half-written results. ``results.json`` / ``results.md`` gather them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import logging
import os
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
import tomllib

from ..core.files import write_json_atomic, write_text_atomic
from ..core.stages import bar_disabled
from .defaults import run_spec
from .options import check_settings, train_options
from .run import RunSpec, train_run

log = logging.getLogger("tactilesnn")

#: trials one sweep may hold (a grid's combinations or random draws)
MAX_TRIALS = 10_000


def load_sweep(path: Path) -> dict:
    """Read and check a sweep file (unknown settings and malformed sections are refused)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"sweep file {path} does not exist")
    try:
        spec = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{path}: not valid TOML ({e})") from e
    extra = set(spec) - {"base", "grid", "random"}
    if extra:
        raise ValueError(f"{path}: unknown section(s) {sorted(extra)}; use base, grid, random")
    if ("grid" in spec) == ("random" in spec):
        raise ValueError(f"{path}: give exactly one of [grid] or [random]")
    known = train_options()
    space = spec.get("grid") or spec["random"].get("space", {})
    for key in [*spec.get("base", {}), *space]:
        if key not in known:
            raise ValueError(f"{path}: '{key}' is not a setting a sweep can vary (train --help)")
    check_settings(spec.get("base", {}), f"{path} [base]")
    if "grid" in spec:
        n = 1
        for key, values in spec["grid"].items():
            if not isinstance(values, list) or not values:
                raise ValueError(f"{path}: grid.{key} must be a non-empty list")
            n *= len(values)
        if n > MAX_TRIALS:
            raise ValueError(f"{path}: the grid has {n} combinations (at most {MAX_TRIALS})")
    else:
        r = spec["random"]
        trials = r.get("trials")
        if isinstance(trials, bool) or not isinstance(trials, int) or not 1 <= trials <= MAX_TRIALS:
            raise ValueError(f"{path}: random.trials must be an integer in 1-{MAX_TRIALS}")
        for key, dist in space.items():
            _check_distribution(key, dist, path)
    return spec


def _check_distribution(key: str, dist: object, path: Path) -> None:
    if isinstance(dist, list) and dist:
        return
    if isinstance(dist, dict) and len(dist) == 1:
        (kind, bounds), = dist.items()  # fmt: skip
        ok = isinstance(bounds, list) and len(bounds) == 2 and bounds[0] < bounds[1]
        if kind in ("uniform", "log_uniform") and ok and (kind == "uniform" or bounds[0] > 0):
            return
    raise ValueError(
        f"{path}: random.space.{key} must be a list of values or {{uniform = [lo, hi]}} / "
        "{log_uniform = [lo, hi]} with 0 < lo < hi"
    )


def trials(spec: dict) -> list[dict]:
    """The sweep's trials in a fixed order, each the full settings dict (base + its values)."""
    base = dict(spec.get("base", {}))
    if "grid" in spec:
        keys = list(spec["grid"])
        combos = itertools.product(*(spec["grid"][k] for k in keys))
        return [{**base, **dict(zip(keys, c, strict=True))} for c in combos]
    r = spec["random"]
    rng = np.random.default_rng(int(r.get("seed", 0)))
    out = []
    for _ in range(r["trials"]):
        t = dict(base)
        for key, dist in r.get("space", {}).items():
            if isinstance(dist, list):
                t[key] = dist[int(rng.integers(len(dist)))]
            else:
                (kind, (lo, hi)), = dist.items()  # fmt: skip
                u = (
                    rng.uniform(np.log(lo), np.log(hi))
                    if kind == "log_uniform"
                    else rng.uniform(lo, hi)
                )
                t[key] = float(np.exp(u) if kind == "log_uniform" else u)
        out.append(t)
    return out


def trial_id(index: int, settings: dict) -> str:
    digest = hashlib.sha1(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:8]
    return f"t{index:03d}-{digest}"


def check_trial(settings: dict) -> RunSpec:
    """A trial's run, built as ``train`` builds it (bad values fail before any work)."""
    try:
        return run_spec(check_settings(settings, "trial"), Path("x"), progress=False)
    except (TypeError, ValueError) as e:
        raise ValueError(f"trial settings {settings} are not valid train settings: {e}") from e


def run_trial(settings: dict, out: str, threads: int = 1) -> dict:
    """Train one trial into ``out`` (skipped when its run folder is complete); its metrics."""
    import torch

    out_path = Path(out)
    if not (out_path / "metrics.json").is_file():
        torch.set_num_threads(max(1, threads))
        t0 = time.perf_counter()
        try:
            train_run(dataclasses.replace(check_trial(settings), out=out_path, overwrite=True))
        except Exception as e:  # one failed trial is reported in the table, the others go on
            log.error("trial %s failed: %s", out_path.name, e)
            return {"error": f"{type(e).__name__}: {e}", "seconds": time.perf_counter() - t0}
    m = json.loads((out_path / "metrics.json").read_text())
    keys = ("test_accuracy", "test_accuracy_ci95", "fit_seconds", "encode_seconds",
            "test_accuracy_per_recording")  # fmt: skip
    return {k: m[k] for k in keys if k in m}


def _local(jobs: list[tuple[str, dict, str]], workers: int) -> Iterator[tuple[str, dict]]:
    threads = max(1, (os.cpu_count() or 1) // max(1, workers))
    if workers <= 1:
        for tid, s, out in jobs:
            yield tid, run_trial(s, out, threads)
        return
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futs = {pool.submit(run_trial, s, out, threads): tid for tid, s, out in jobs}
        for f in as_completed(futs):
            yield futs[f], f.result()


def _dask(jobs: list[tuple[str, dict, str]], scheduler: str) -> Iterator[tuple[str, dict]]:
    from ..core.dask_run import on_dask

    for i, res in on_dask(run_trial, [(s, out, 1) for _, s, out in jobs], scheduler):
        yield jobs[i][0], res


def run_sweep(
    sweep_file: Path,
    out: Path,
    workers: int = 2,
    scheduler: str | None = None,
    progress: bool = True,
) -> list[dict]:
    """Run every trial of ``sweep_file`` not yet finished in ``out``; returns the result rows
    (best first) and writes ``results.json`` and ``results.md``."""
    from tqdm.auto import tqdm

    spec = load_sweep(sweep_file)
    todo = trials(spec)
    for s in todo:
        check_trial(s)
    out = Path(out)
    (out / "trials").mkdir(parents=True, exist_ok=True)
    spec_path = out / "sweep.json"
    if spec_path.exists() and json.loads(spec_path.read_text()) != spec:
        log.info("%s: the sweep file changed; finished trials with unchanged settings are kept",
                 out)  # fmt: skip
    write_json_atomic(spec_path, spec)
    ids = [trial_id(i, s) for i, s in enumerate(todo)]
    rows = {tid: {"trial": tid, "settings": s} for tid, s in zip(ids, todo, strict=True)}
    jobs = [(tid, s, str(out / "trials" / tid)) for tid, s in zip(ids, todo, strict=True)]
    done = sum((Path(o) / "metrics.json").is_file() for _, _, o in jobs)
    log.info("sweep: %d trials (%d already finished) on %s", len(jobs), done,
             scheduler or f"{workers} local worker(s)")  # fmt: skip
    bar = tqdm(total=len(jobs), desc="sweep", unit="trial", disable=bar_disabled(progress))
    results = _dask(jobs, scheduler) if scheduler else _local(jobs, workers)
    for tid, res in results:
        rows[tid].update(res)
        bar.update()
        write_json_atomic(out / "results.json", list(rows.values()))  # survives an interruption
    bar.close()
    ordered = sorted(rows.values(), key=lambda r: -r.get("test_accuracy", -1.0))
    plot_front(ordered, out / "results.png")
    write_json_atomic(out / "results.json", ordered)
    write_text_atomic(out / "results.md", results_table(ordered))
    return ordered


def plot_front(rows: list[dict], path: Path) -> None:
    """Test error vs training time (fit + encode seconds) of the finished trials, the Pareto
    front marked (``row["pareto_front"]``), drawn as ``bench pareto`` draws its points."""
    from .plots import pareto_front
    from .plots import plot_cost_error as plot

    done = [r for r in rows if "test_accuracy" in r]
    if not done:
        return
    varied = _varied(rows)
    pts = [{"test_error": 1 - r["test_accuracy"], "test_error_ci95": r["test_accuracy_ci95"],
            "train_s": (r.get("fit_seconds") or 0) + (r.get("encode_seconds") or 0),
            "label": ", ".join(f"{k}={_cell(r['settings'].get(k, ''))}" for k in varied)[:40]
            or r["trial"]} for r in done]  # fmt: skip
    pareto_front(pts, cost_key="train_s")
    for r, p in zip(done, pts, strict=True):
        r["pareto_front"] = p["front"]
    tmp = path.with_name("." + path.name)
    plot(pts, tmp, "sweep: test error vs training time (red: Pareto front)", cost_key="train_s",
         xlabel="training time: encode + fit (s)")  # fmt: skip
    os.replace(tmp, path)


def _varied(rows: list[dict]) -> list[str]:
    """The settings that differ between trials (what the table's columns and the picture's
    labels name)."""
    return sorted({k for r in rows for k, v in r["settings"].items()
                   if any(o["settings"].get(k) != v for o in rows)})  # fmt: skip


def _cell(value: object) -> str:
    return ", ".join(map(str, value)) if isinstance(value, list | tuple) else str(value)


def results_table(rows: list[dict]) -> str:
    """Markdown table: varied settings, test accuracy +- 95 % CI, fit and encode seconds."""
    varied = _varied(rows)
    head = ["trial", *varied, "test accuracy", "fit s", "encode s", "front"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        acc = (f"{100 * r['test_accuracy']:.2f} +- {100 * r['test_accuracy_ci95']:.2f} %"
               if "test_accuracy" in r else r.get("error", "not run"))  # fmt: skip
        cells = [r["trial"], *(_cell(r["settings"].get(k, "")) for k in varied), acc,
                 f"{r.get('fit_seconds') or 0:.1f}", f"{r.get('encode_seconds') or 0:.1f}",
                 "**yes**" if r.get("pareto_front") else ""]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"

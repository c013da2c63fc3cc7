"""Command-line interface: ``tactilesnn train | evaluate | bench``.

``python train.py ...`` is the same as ``tactilesnn train ...``.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from .datasets_synth import TASKS
from .pipeline import ENCODERS, MODELS, PipelineConfig
from .runs import RunExistsError

log = logging.getLogger("tactilesnn")


def _add_pipeline_args(p: argparse.ArgumentParser) -> None:
    d = PipelineConfig()
    p.add_argument("--task", default="hook_loop", choices=sorted(TASKS), help="synthetic task")
    p.add_argument("--encoder", default=d.encoder, choices=ENCODERS)
    p.add_argument("--model", default=d.model, choices=MODELS)
    p.add_argument("--seed", type=int, default=0, help="dataset split, generation and init seed")
    p.add_argument("--epochs", type=int, default=d.epochs)
    p.add_argument("--lr", type=float, default=d.lr, help="tempotron learning rate lambda")
    p.add_argument("--momentum", type=float, default=d.momentum)
    p.add_argument("--batch-size", type=int, default=d.batch_size)
    p.add_argument("--tau-ms", type=float, default=d.tau_ms, help="membrane time constant")
    p.add_argument("--tau-s-ms", type=float, default=d.tau_s_ms, help="synaptic time constant")
    p.add_argument("--n-bands", type=int, default=d.n_bands)
    p.add_argument("--f-lo-hz", type=float, default=d.f_lo_hz)
    p.add_argument("--f-hi-hz", type=float, default=d.f_hi_hz)
    p.add_argument(
        "--difficulty",
        type=float,
        default=1.0,
        help="multiplier of noise, speed variation, Z ripple and texture irregularity",
    )
    p.add_argument(
        "--amplitude-spread",
        type=float,
        default=1.0,
        help="multiplier of the force set-point range and coupling-gain spread",
    )


def _config(args: argparse.Namespace, seed: int | None = None, encoder: str | None = None):
    return PipelineConfig(
        encoder=encoder or args.encoder,
        model=args.model,
        seed=args.seed if seed is None else seed,
        epochs=args.epochs,
        lr=args.lr,
        momentum=args.momentum,
        batch_size=args.batch_size,
        tau_ms=args.tau_ms,
        tau_s_ms=args.tau_s_ms,
        n_bands=args.n_bands,
        f_lo_hz=args.f_lo_hz,
        f_hi_hz=args.f_hi_hz,
    )


def cmd_train(args: argparse.Namespace) -> int:
    from .runs import default_run_dir
    from .training import train_run

    config = _config(args)
    out = (
        Path(args.out)
        if args.out
        else default_run_dir(Path("runs"), args.task, config.encoder, config.model)
    )
    task_kwargs = {
        "seed": args.seed,
        "difficulty": args.difficulty,
        "amplitude_spread": args.amplitude_spread,
    }
    path, m = train_run(
        args.task, task_kwargs, config, out, overwrite=args.overwrite, progress=not args.quiet
    )
    print(
        f"{args.task} {config.encoder}+{config.model}: test accuracy "
        f"{100 * m['test_accuracy']:.2f} % (+-{100 * m['test_accuracy_ci95']:.2f} % 95% CI, "
        f"{m['n_test_windows']} windows from {m['n_test_scans']} scans); "
        f"amplitude-only linear baseline {100 * m['trivial_amplitude_baseline_accuracy']:.2f} %"
    )
    print(f"run folder: {path}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from .datasets_synth import get_task
    from .training import load_run

    pipe, cfg = load_run(Path(args.run_dir))
    task = get_task(cfg["task"], **cfg["task_kwargs"])
    _, test = task.build(progress=not args.quiet)
    acc = pipe.score(test.X, test.y)
    print(json.dumps({"run": str(args.run_dir), "test_accuracy": acc, "n": int(test.y.size)}))
    return 0


BENCHMARKS = ("gwt-vs-stft", "encoders", "snn")


def cmd_bench(args: argparse.Namespace) -> int:
    if args.name == "snn":
        from .bench import snn

        res = snn.run(repeats=args.repeats)
        if args.out:
            _write_json(Path(args.out) / "snn.json", res)
        return 0
    if args.name == "encoders":
        from .bench import encoders

        out = Path(args.out) / "encoders.json" if args.out else None
        encoders.run(out, repeats=args.repeats, sparse=args.sparse)
        return 0
    from .bench import gwt_vs_stft

    if args.out is None:
        raise ValueError("gwt-vs-stft needs --out DIR")
    gwt_vs_stft.run(
        seeds=args.seeds,
        out=Path(args.out),
        overwrite=args.overwrite,
        epochs=args.epochs,
        difficulty=args.difficulty,
        progress=not args.quiet,
    )
    return 0


def _write_json(path: Path, obj: dict) -> None:
    import os

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(obj, indent=2))
    os.replace(tmp, path)
    print(f"results: {path}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tactilesnn", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("train", help="train a pipeline and write a run folder")
    _add_pipeline_args(p)
    p.add_argument("--out", help="run folder (default runs/<task>-<encoder>-<model>-<time>)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run folder")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("evaluate", help="evaluate a run folder on its task's test split")
    p.add_argument("run_dir")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("bench", help="benchmarks")
    p.add_argument("name", choices=BENCHMARKS)
    p.add_argument("--seeds", type=int, default=5, help="gwt-vs-stft: dataset/training seeds")
    p.add_argument("--out", help="output folder")
    p.add_argument("--repeats", type=int, default=7, help="encoders: timed runs per case")
    p.add_argument("--sparse", action="store_true", help="encoders: activity-gate benchmark")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--epochs", type=int, default=PipelineConfig().epochs)
    p.add_argument("--difficulty", type=float, default=1.0)
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from .perf import tune_allocator

    tune_allocator()
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(message)s",
    )
    try:
        return args.func(args)
    except (ValueError, RunExistsError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

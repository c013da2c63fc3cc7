"""Command-line interface: parse, call the application layer, print.

``tactilesnn train | evaluate | finetune | export | generate | calibrate | sweep | serve |
demo-stream | bench``;
``python train.py ...`` is the same as ``tactilesnn ...``.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

if TYPE_CHECKING:
    from .app.options import Option

log = logging.getLogger("tactilesnn")

DESCRIPTION = """\
tactilesnn: spiking-network tactile perception (sensor models, spike encoders, SNN classifiers,
ONNX export and an inference service). Start with:
  tactilesnn train                       the default synthetic task and pipeline
  tactilesnn train --data recordings.npz your recordings (.npz: X [N, channels, samples], y, fs,
                                         class_names); defaults follow the file
Each command has its own --help. `python train.py ...` is the same command line."""


SCHEDULER_HELP = (
    "Dask scheduler address (tcp://HOST:PORT) to run on a cluster instead of local processes; "
    "needs the 'distributed' extra, and --out on a file system the workers share"
)


class _HelpFormatter(argparse.HelpFormatter):
    """Appends ``(default: X)`` to a flag's help unless the help already states its default."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        d = action.default
        unset = d is None or d is False or d is argparse.SUPPRESS  # (0 is a default to show)
        if "default" in text or unset or not action.option_strings:
            return text
        return f"{text} (default: {' '.join(map(str, d)) if isinstance(d, list | tuple) else d})"


def _command(sub: argparse._SubParsersAction, name: str, text: str) -> argparse.ArgumentParser:
    return sub.add_parser(name, formatter_class=_HelpFormatter, help=text, description=text)


def _add_option(p: argparse.ArgumentParser | argparse._ArgumentGroup, o: Option) -> None:
    """One setting of :mod:`tactilesnn.app.options` as a flag (pipeline settings default to
    unset, so only those given override a ``--config`` file and the data's defaults)."""
    kw: dict = {"help": o.help, "default": argparse.SUPPRESS if o.pipeline else o.default}
    if o.choices:
        kw["choices"] = o.choices
    if o.kind is bool:
        kw["action"] = argparse.BooleanOptionalAction
    elif o.repeated:
        kw.update(action="append", metavar="KEY=VALUE")
    elif o.kind is tuple:
        kw["nargs"] = "+"
    else:
        kw["type"] = o.kind
    p.add_argument(o.flag, **kw)


def _add_train_args(p: argparse.ArgumentParser) -> None:
    """``--config``, the run options, then one flag per pipeline setting."""
    from .app.options import pipeline_options, run_options

    p.add_argument(
        "--config", help="TOML file of settings (nested sections or flat keys); flags win"
    )
    for o in run_options():
        _add_option(p, o)
    g = p.add_argument_group("pipeline settings (unset flags keep the component's default)")
    for o in pipeline_options():
        _add_option(g, o)


def _settings(args: argparse.Namespace) -> dict:
    """The train settings of parsed ``args``: every run option, the pipeline settings given."""
    from .app.options import train_options

    return {k: getattr(args, k) for k in train_options() if hasattr(args, k)}


def _task_option_values(args: argparse.Namespace) -> dict:
    """The task parameters of ``generate``'s flags (the same options as ``train``'s)."""
    from .app.defaults import task_params

    return task_params(args.task, {"difficulty": args.difficulty, "faults": args.faults,
                                   "amplitude_spread": args.amplitude_spread,
                                   "task_kw": args.task_kw})  # fmt: skip


def cmd_train(args: argparse.Namespace) -> int:
    from .app.commands import condition_lines, frame_stream_line, parity_line, stream_hint
    from .app.defaults import run_spec
    from .app.run import train_run

    if args.resume and not args.out:
        raise ValueError("--resume needs the --out folder of the interrupted run")
    file = args.train_file
    spec = run_spec(_settings(args), Path(args.out) if args.out else None,
                    toml=file.pipeline if file else None, overwrite=args.overwrite,
                    resume=args.resume, progress=not args.quiet,
                    config_text=file.text if file else None)  # fmt: skip
    result = train_run(spec)
    m, encoder = result.metrics, result.config.encoder_type
    if "encoder_selection" in m:
        sel = m["encoder_selection"]
        held = ", ".join(f"{k} {100 * v['per_window']:.1f} %"
                         + (f" (round {v['stopped_after']})" if v.get("stopped_after") else "")
                         for k, v in sel["scores"].items())  # fmt: skip
        how = ("held-out training recordings" if sel.get("validation", "recordings") == "recordings"
               else sel["validation"].split(" (")[0])  # fmt: skip
        print(f"encoder chosen on {how}: {sel['chosen']} (per window: {held}; "
              f"last round {sel['fit_windows']} + {sel['val_windows']} windows, "
              f"{sel['seconds']:.0f} s)")  # fmt: skip
    print(
        f"{spec.source.label} {encoder}+{result.config.model_type}: test accuracy "
        f"{100 * m['test_accuracy']:.2f} % (+-{100 * m['test_accuracy_ci95']:.2f} % 95% CI, "
        f"{m['n_test_windows']} windows); "
        f"amplitude-only linear baseline {100 * m['trivial_amplitude_baseline_accuracy']:.2f} %"
    )
    if "test_accuracy_per_recording" in m:
        print(f"per recording (scores summed over its windows): "
              f"{100 * m['test_accuracy_per_recording']:.2f} % on {m['n_test_recordings']}")  # fmt: skip
    for line in condition_lines(m, spec.source):
        print(line)
    if "in_stream" in m:
        st = m["in_stream"]
        print(f"as a stream serves them (each window coded with its recording's past, "
              f"{st['test_windows_with_past']} of {m['n_test_windows']} test windows have one; "
              f"trained on both codes: {st['train_windows_added']} windows added): "
              f"{100 * st['test_accuracy']:.2f} % (+-{100 * st['test_accuracy_ci95']:.2f} %)")  # fmt: skip
    if "frame_stream" in m:
        print(frame_stream_line(m["frame_stream"]))
    path = result.path
    if "error" in m.get("onnx", {}):
        print(f"run folder {path} is complete, but the ONNX export failed: {m['onnx']['error']}")
        print(f"retry with: tactilesnn export {path} --out {path / 'model.onnx'}")
        return 1
    if "onnx" in m:
        print(
            f"model.onnx: {m['onnx']['nodes']} nodes; on the test split onnxruntime vs torch: "
            f"{parity_line(m['onnx'])}"
        )
    print(f"run folder: {path}")
    hint = stream_hint(encoder, path) if "onnx" in m else None
    if hint:
        print(hint)
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from .app.commands import evaluate, evaluation_lines

    rep = evaluate(Path(args.run_dir), Path(args.data) if args.data else None, every=args.all,
                   fs_hz=args.fs, progress=not args.quiet)  # fmt: skip
    if args.json:
        print(json.dumps({k: v for k, v in rep.items() if k != "test_accuracy_ci95"}))
    else:
        print("\n".join(evaluation_lines(rep)))
    return 0


def cmd_finetune(args: argparse.Namespace) -> int:
    from .app.finetune import finetune_lines, finetune_run

    m = finetune_run(Path(args.run_dir), Path(args.data), Path(args.out) if args.out else None,
                     overwrite=args.overwrite, export=not args.no_export, fs_hz=args.fs,
                     choose_prior=args.choose_prior, class_share=args.class_share,
                     progress=not args.quiet, adapt_only=args.adapt_only)  # fmt: skip
    if args.json:
        print(json.dumps({k: m[k] for k in ("path", "test_accuracy", "n_test_windows",
                                            "test_accuracy_per_recording", "pretrained")
                          if k in m}))  # fmt: skip
    else:
        print("\n".join(finetune_lines(m)))
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from .app.commands import export_run

    lines = export_run(Path(args.run_dir), Path(args.out), fmt=args.format, stream=args.stream,
                       stream_step=args.stream_step, quantize=args.quantize,
                       overwrite=args.overwrite, progress=not args.quiet,
                       frames=args.frames)  # fmt: skip
    print("\n".join(lines))
    return 0


def cmd_convert(args: argparse.Namespace) -> int:
    from .app.convert import convert

    out = Path(args.out) if args.out else None
    report = convert(Path(args.source), out, args.fs, args.overwrite, args.dry_run)
    print("\n".join(report.lines()))
    return 0


def _parse_convert(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = _command(sub, "convert", "recordings as they come (timestamped arrays, a folder of CSV / "
                 "TSV / .npy files) -> one .npz in the documented format")  # fmt: skip
    p.add_argument("source", help="an .npz, a folder of recordings or a generated dataset")
    p.add_argument("--out", help=".npz file to write (required unless --dry-run)")
    p.add_argument("--fs", type=float, help="sampling rate (Hz) of recordings without a time "
                   "column")  # fmt: skip
    p.add_argument("--dry-run", action="store_true", help="print what would be read (files, "
                   "classes, channels, rate and where it came from, lengths, what is dropped) "
                   "and write nothing")  # fmt: skip
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=cmd_convert)
    return p


def cmd_generate(args: argparse.Namespace) -> int:
    from .app.commands import generate_dataset

    lines = generate_dataset(args.task, args.n, args.seed, Path(args.out),
                             shard_size=args.shard_size, workers=args.workers,
                             overwrite=args.overwrite, resume=args.resume,
                             progress=not args.quiet, task_kwargs=_task_option_values(args),
                             scheduler=args.scheduler)  # fmt: skip
    print("\n".join(lines))
    return 0


def cmd_tasks(args: argparse.Namespace) -> int:
    from .app.commands import describe_tasks

    print("\n".join(describe_tasks()))
    return 0


def _parse_tasks(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = _command(sub, "tasks", "list the synthetic tasks (classes, channels, rate, window, units)")
    p.set_defaults(func=cmd_tasks)
    return p


def cmd_sweep(args: argparse.Namespace) -> int:
    from .app.sweep import run_sweep

    rows = run_sweep(Path(args.config), Path(args.out), workers=args.workers,
                     scheduler=args.scheduler, progress=not args.quiet)  # fmt: skip
    failed = [r["trial"] for r in rows if "test_accuracy" not in r]
    best = rows[0] if rows and "test_accuracy" in rows[0] else None
    print(f"{args.out}: {len(rows) - len(failed)} of {len(rows)} trials finished; table "
          f"{Path(args.out) / 'results.md'}")  # fmt: skip
    if best:
        print(f"best: {best['trial']} {best['settings']} test accuracy "
              f"{100 * best['test_accuracy']:.2f} %")  # fmt: skip
    if failed:
        print(f"failed trials (see their logs above): {failed}", file=sys.stderr)
        return 1
    return 0


def cmd_demo_stream(args: argparse.Namespace) -> int:
    from .app.commands import stream_demo

    print("\n".join(stream_demo(args.url, args.task, args.stream, args.seconds, args.speed,
                                args.chunk_ms, args.seed)))  # fmt: skip
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    from .app.commands import serve

    return serve(args)


def cmd_bench(args: argparse.Namespace) -> int:
    from .bench import benchmark

    return benchmark(args.name).main(Path(args.out) if args.out else None, args)


def _resume_hint(args: argparse.Namespace, argv: list[str]) -> str:
    """How to continue an interrupted command, if it can be continued."""
    out = getattr(args, "out", None)
    if args.command == "train" and out:
        partial = Path(out).with_name(Path(out).name + ".partial")
        if (partial / "checkpoint.json").is_file():
            again = " ".join(a for a in argv if a not in ("--resume", "--overwrite"))
            return f"; the last finished epoch is saved: tactilesnn {again} --resume"
    if args.command == "generate":
        return "; finish it with the same command and --resume"
    return ""


def _parse_train(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = _command(sub, "train", "train a pipeline and write a run folder")
    _add_train_args(p)
    p.add_argument("--out", help="run folder (default runs/<source>-<encoder>-<model>-<time>, "
                   "named after the encoder trained)")  # fmt: skip
    p.add_argument("--overwrite", action="store_true", help="replace an existing run folder")
    p.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_train, train_file=None)
    return p


def _parse_evaluate(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = _command(sub, "evaluate", "evaluate a run folder on its test split or --data")
    p.add_argument("run_dir", help="run folder written by train")
    p.add_argument("--data", help="recordings .npz or generated folder to evaluate on (its test "
                   "split, cut as the run's data was)")  # fmt: skip
    p.add_argument("--all", action="store_true", help="with --data: evaluate on every recording")
    p.add_argument("--fs", type=float, help="with --data: the sampling rate (Hz) of recordings "
                   "without a time column (default: the rate the run's data was given)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print one JSON line instead of a summary")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_evaluate)
    return p


def _parse_finetune(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = _command(sub, "finetune", "pretrain, then fine-tune: adapt a run (e.g. trained on a "
                 "calibrated model's generated recordings) to a few labelled recordings")  # fmt: skip
    p.add_argument("run_dir", help="the pretrained run folder (kept as it is)")
    p.add_argument("--data", required=True, help="recordings .npz or folder of the real sensor: "
                   "cut as the run's windows were, split by recording; the training split "
                   "fine-tunes, the test split scores")  # fmt: skip
    p.add_argument("--out", help="the new run folder (default: runs/<data>-finetuned-...)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out run")
    p.add_argument("--fs", type=float, help="the sampling rate (Hz) of recordings without a "
                   "time column")  # fmt: skip
    p.add_argument("--choose-prior", action="store_true", help="the prior's strength by "
                   "leave-one-recording-out cross-validation on the training split (default: "
                   "the model's own)")  # fmt: skip
    p.add_argument("--class-share", action="store_true", help="also fine-tune each window on "
                   "its share of its class's signal as the run's generated recordings hold it "
                   "(the same length and protocol), and keep the mean of the two read-outs")  # fmt: skip
    p.add_argument("--adapt-only", action="store_true", help="only re-estimate the read-out's "
                   "input scaling on the training split (labels unused), the weights as "
                   "pretrained: a run trained on synthetic recordings alone, read on your "
                   "sensor")  # fmt: skip
    p.add_argument("--no-export", action="store_true", help="skip the verified ONNX export")
    p.add_argument("--json", action="store_true", help="print one JSON line instead of a summary")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_finetune)
    return p


def _parse_export(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = _command(sub, "export", "export a run folder to ONNX (window -> scores) or NIR")
    p.add_argument("run_dir", help="run folder written by train")
    p.add_argument("--out", required=True, help="model.onnx (or model.nir) to write")
    p.add_argument(
        "--format",
        choices=("onnx", "nir"),
        default="onnx",
        help="onnx: the whole pipeline; nir: the SNN only (input: spike raster), needs 'nir'",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.add_argument(
        "--quantize", action="store_true", help="also write <out>.int8.onnx (dynamic int8)"
    )
    p.add_argument(
        "--stream",
        action="store_true",
        help="write the stream graph instead (half a window per call, every sample transformed "
        "once; encoders with a stream form: cgwt); serve and classify it like model.onnx",
    )
    p.add_argument(
        "--stream-step",
        type=int,
        default=None,
        metavar="SAMPLES",
        help="with --stream: samples per call, a window's scores each call (default half a "
        "window; any whole number of the encoder's hops dividing the window, at most half of "
        "it: one hop gives every frame's spikes and scores one call after its last sample, "
        "at a whole window's coding and classifying per frame)",
    )
    p.add_argument(
        "--frames",
        action="store_true",
        help="write the one-frame step graph instead (one hop of samples and the state per "
        "call: the frame's scores and decision; a continuous code and a stream model: "
        "--encoder frames --model stream)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_export)
    return p


def _parse_generate(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from .app.options import run_options, task_names

    p = _command(sub, "generate", "render a synthetic task into sharded files")
    p.add_argument("--task", default="hook_loop", choices=task_names(), help="synthetic task")
    p.add_argument("--n", type=int, required=True, help="number of samples (scans or trials)")
    p.add_argument("--seed", type=int, default=0, help="sample i depends only on (task, seed, i)")
    p.add_argument("--out", required=True, help="dataset folder (train --data reads it)")
    p.add_argument("--shard-size", type=int, default=50, help="samples per shard file")
    p.add_argument("--workers", type=int, default=2, help="local rendering processes")
    p.add_argument("--difficulty", type=float, default=1.0,
                   help="multiplier of the task's noise and nuisance spread")  # fmt: skip
    p.add_argument("--amplitude-spread", type=float, default=1.0,
                   help="multiplier of the task's amplitude nuisances")  # fmt: skip
    for o in run_options():
        if o.name in ("faults", "task_kw"):
            _add_option(p, o)
    p.add_argument("--overwrite", action="store_true", help="replace a dataset in --out")
    p.add_argument("--resume", action="store_true", help="finish an interrupted generation")
    p.add_argument("--scheduler", help=SCHEDULER_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_generate)
    return p


def _name_value(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` (a number) of ``calibrate --known``."""
    name, sep, value = text.partition("=")
    try:
        if not sep or not name.strip():
            raise ValueError
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=NUMBER, got {text!r}") from None


def _parse_calibrate(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from .app.options import task_names

    p = _command(sub, "calibrate", "fit a task's sensor model to your recordings (a fit file "
                 "that generate / train read with --task-kw calibration=FILE)")  # fmt: skip
    p.add_argument("--data", required=True,
                   help="recordings as train --data reads them (.npz or folder)")  # fmt: skip
    p.add_argument("--task", default="braille", choices=task_names(),
                   help="the task whose scene the recordings are (its classes named as theirs)")  # fmt: skip
    p.add_argument("--out", required=True, help="the fit file to write (JSON)")
    p.add_argument("--recordings", type=int, nargs="+",
                   help="fit on these recordings only (indices in file order; default all)")  # fmt: skip
    p.add_argument("--evaluations", type=int, default=1200,
                   help="the optimiser's evaluations (default 1200: ~6 min on one free core, "
                   "~3 on two; each round's points run on the cores other work leaves free)")  # fmt: skip
    p.add_argument("--budget-s", type=float, default=600.0,
                   help="at most this many seconds of search, whatever --evaluations says")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="the optimiser's seed")
    p.add_argument("--optimiser", default="cma", choices=("cma", "optuna-tpe", "random"),
                   help="the black-box search (cma: CMA-ES, the default; optuna-tpe needs optuna, "
                   "installed with .[bench])")  # fmt: skip
    p.add_argument("--known", type=_name_value, nargs="+", metavar="NAME=VALUE",
                   help="values you measured, held fixed instead of fitted, in the fit's units "
                   "(e.g. speed_mm_s=10.07 from the arm's encoder, force_N=1.5)")  # fmt: skip
    p.add_argument("--fs", type=float, help="sampling rate (Hz) for recordings without one")
    p.add_argument("--plot", help="also write the statistics picture (PNG): real, the model's "
                   "defaults and the fit")  # fmt: skip
    p.add_argument("--statistics-only", action="store_true",
                   help="no fit: the recordings' statistics next to the task's model at its "
                   "defaults (--out: JSON), for a sensor the task cannot be fitted to")  # fmt: skip
    p.add_argument("--overwrite", action="store_true", help="replace --out / --plot")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_calibrate)
    return p


def cmd_calibrate(args: argparse.Namespace) -> int:
    from .app.calibrate import calibrate, compare

    if args.statistics_only:
        print("\n".join(compare(Path(args.data), args.task, Path(args.out),
                                Path(args.plot) if args.plot else None,
                                overwrite=args.overwrite, fs_hz=args.fs, seed=args.seed)))  # fmt: skip
        return 0
    lines = calibrate(Path(args.data), args.task, Path(args.out), args.recordings,
                      budget_s=args.budget_s, evaluations=args.evaluations, seed=args.seed,
                      optimiser=args.optimiser,
                      plot=Path(args.plot) if args.plot else None, overwrite=args.overwrite,
                      fs_hz=args.fs, progress=not args.quiet,
                      known=dict(args.known) if args.known else None)  # fmt: skip
    print("\n".join(lines))
    return 0


def _parse_sweep(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = _command(sub, "sweep", "grid / random search over train settings, each a run folder")
    p.add_argument("--config", required=True, help="sweep TOML ([base] + [grid] or [random])")
    p.add_argument("--out", required=True,
                   help="sweep folder: trials/<id>/ run folders, results.json, results.md; "
                   "finished trials are skipped when run again")  # fmt: skip
    p.add_argument("--workers", type=int, default=2, help="local trial processes")
    p.add_argument("--scheduler", help=SCHEDULER_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_sweep)
    return p


def _parse_serve(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from .app.options import add_serve_arguments

    p = _command(sub, "serve", "HTTP inference service (onnxruntime + numpy only; without "
                 "torch: python -m tactilesnn.service)")  # fmt: skip
    add_serve_arguments(p)
    p.set_defaults(func=cmd_serve)
    return p


def _parse_demo_stream(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from .app.options import task_names

    p = _command(sub, "demo-stream", "stream a synthetic task to a running service (live page)")
    p.add_argument("--url", default="http://127.0.0.1:8000", help="the service's base URL")
    p.add_argument("--task", default="hook_loop", choices=task_names(), help="synthetic task")
    p.add_argument("--stream", default="demo", help="stream id on the service")
    p.add_argument("--seconds", type=float, default=0.0,
                   help="seconds of signal to send (default: 0 = until interrupted)")  # fmt: skip
    p.add_argument("--speed", type=float, default=1.0,
                   help="pace as a multiple of real time (0 = as fast as the service answers)")  # fmt: skip
    p.add_argument("--chunk-ms", type=float, default=100.0, help="signal per request (ms)")
    p.add_argument("--seed", type=int, default=0, help="task seed (which scans are rendered)")
    p.set_defaults(func=cmd_demo_stream)
    return p


def _parse_bench(sub: argparse._SubParsersAction, full: bool = True) -> argparse.ArgumentParser:
    """``bench NAME``: each benchmark's flags (``full=False``: its names only, nothing imported,
    for a command line that is not ``bench``)."""
    p = _command(sub, "bench", "benchmarks (each has its own flags: tactilesnn bench NAME --help)")
    names = p.add_subparsers(dest="name", required=True, metavar="NAME", help="which benchmark")
    from .bench import BENCHMARKS, benchmark

    for name in BENCHMARKS.names():
        if not full:
            names.add_parser(name)
            continue
        module = benchmark(name)
        b = _command(names, name, module.HELP)
        p.commands[name] = b  # type: ignore[attr-defined]
        b.add_argument("--out", help="output folder")
        b.add_argument("--quiet", action="store_true", help="no progress bars")
        module.add_arguments(b)
        b.set_defaults(func=cmd_bench)
    return p


#: the sub-commands and their parsers (``python train.py`` passes anything else to ``train``)
COMMANDS = {"train": _parse_train, "evaluate": _parse_evaluate, "finetune": _parse_finetune,
            "export": _parse_export,
            "convert": _parse_convert, "generate": _parse_generate, "tasks": _parse_tasks,
            "calibrate": _parse_calibrate,
            "sweep": _parse_sweep,
            "serve": _parse_serve, "demo-stream": _parse_demo_stream, "bench": _parse_bench}  # fmt: skip


#: flags whose value is a path that must exist, per command
EXISTING_PATHS = {"train": ("--data", "--config"), "evaluate": ("--data",)}


class SuggestingParser(argparse.ArgumentParser):
    """An argument parser whose errors suggest the closest flag or choice ("did you mean");
    ``commands``: the sub-commands' parsers by name."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.commands: dict[str, argparse.ArgumentParser] = {}

    def error(self, message: str) -> NoReturn:
        import difflib
        import re

        hint = ""
        unknown = re.match(r"unrecognized arguments: (.*)", message)
        invalid = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if unknown:
            flags = sorted(_all_flags(self))
            guesses = {tok: difflib.get_close_matches(tok.split("=")[0], flags, n=1)
                       for tok in unknown.group(1).split() if tok.startswith("--")}  # fmt: skip
            hint = "; ".join(f"{tok}: did you mean {g[0]}?" for tok, g in guesses.items() if g)
        elif invalid:
            choices = re.findall(r"'?([^',\s]+)'?", invalid.group(2))
            g = difflib.get_close_matches(invalid.group(1), choices, n=1)
            hint = f"did you mean {g[0]}?" if g else ""
        super().error(f"{message} ({hint})" if hint else message)


def _all_flags(parser: argparse.ArgumentParser) -> set[str]:
    """Every ``--flag`` of ``parser`` and of its sub-commands."""
    out: set[str] = set()
    for action in parser._actions:
        out.update(o for o in action.option_strings if o.startswith("--"))
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                out |= _all_flags(sub)
    return out


def build_parser(bench: bool = True) -> SuggestingParser:
    """The command line, built from the settings schema (:mod:`tactilesnn.schema`; torch is not
    imported). ``bench=False``: the benchmarks' own flags are left out (their modules unimported),
    for a command line that does not start with ``bench``."""
    from .app.environment import __version__

    parser = SuggestingParser(prog="tactilesnn", description=DESCRIPTION,
                              formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--version", action="version", version=f"tactilesnn {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, add in COMMANDS.items():
        p = _parse_bench(sub, full=bench) if name == "bench" else add(sub)
        parser.commands[name] = p
    return parser


def _check_args(parser: SuggestingParser, argv: list[str]) -> argparse.Namespace:
    """``argv`` parsed; an unknown flag is answered by its command's parser (the closest of that
    command's flags), a path that must exist (``--data``, ``--config``) before any work."""
    args, extra = parser.parse_known_args(argv)
    command = parser.commands.get(args.command, parser)
    command = getattr(command, "commands", {}).get(getattr(args, "name", None), command)
    if extra:
        command.error(f"unrecognized arguments: {' '.join(extra)}")
    for flag in EXISTING_PATHS.get(args.command, ()):
        value = getattr(args, flag.lstrip("-"), None)
        if isinstance(value, str) and not Path(value).exists():
            command.error(f"{flag} {value}: no such file or folder")
    return args


def _read_config(parser: argparse.ArgumentParser, argv: list[str]):
    """``train --config FILE``: the file's run options become the train flags' defaults (flags
    given still win); returns the :class:`~tactilesnn.app.config_file.TrainFile` or None."""
    if not argv or argv[0] != "train":
        return None
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--config")
    known, _ = pre.parse_known_args(argv[1:])
    if not known.config:
        return None
    from .app.config_file import read_train_file

    file = read_train_file(Path(known.config))
    parser.commands["train"].set_defaults(train_file=file, **file.run, **file.command)
    return file


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    first = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(bench=first == "bench")
    try:
        _read_config(parser, argv)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    args = _check_args(parser, argv)
    from .app.environment import fit_threads, tune_allocator

    tune_allocator()
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(message)s",
    )
    threads = fit_threads()
    if threads is not None:
        logging.getLogger("tactilesnn").info(
            "other processes are running: %d compute thread(s) (OMP_NUM_THREADS or "
            "TACTILESNN_THREADS choose)", threads)  # fmt: skip
    from .app.commands import ExportError

    try:
        return args.func(args)
    except (ValueError, FileExistsError, FileNotFoundError, ExportError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except ImportError as e:  # an optional extra that is not installed (nir, distributed...)
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a full disk, a read-only folder, a permission: the machine's, not ours
        print(f"error: {e.strerror or e} ({e.filename or 'while writing'}); nothing partial "
              "was left under the output's name", file=sys.stderr)  # fmt: skip
        return 2
    except KeyboardInterrupt:
        print(f"interrupted{_resume_hint(args, argv)}", file=sys.stderr)
        return 130

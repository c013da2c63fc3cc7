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

import numpy as np

from .config import (
    DATA_ENCODER_CANDIDATES,
    DEFAULT_ENCODER,
    DEFAULT_MODEL,
    TOP_FLAGS,
    PipelineConfig,
    TrainConfig,
    apply_flat,
    data_file_defaults,
    encoder_settings_given,
    flat_settings,
    registries,
)
from .datasets_synth import TASKS

log = logging.getLogger("tactilesnn")


SCHEDULER_HELP = (
    "Dask scheduler address (tcp://HOST:PORT) to run on a cluster instead of local processes; "
    "needs the 'distributed' extra, and --out on a file system the workers share"
)
TASK_KW_HELP = "extra task parameter, repeatable (e.g. layout_name=mia14, n_samples=2000)"
FAULTS_FLAG = "--faults"
FAULTS_HELP = (
    'sensor faults for trial tasks, e.g. "dead=3;short=0-1@1e5;gain_sd=0.1;drift_per_s=0.01"'
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
    return sub.add_parser(name, formatter_class=_HelpFormatter, help=text)


def _add_pipeline_args(p: argparse.ArgumentParser) -> None:
    """Run options, then one flag per pipeline setting (the flat names of every registered
    component's config, :func:`tactilesnn.config.flat_settings`); each is also a TOML key."""
    p.add_argument(
        "--config", help="TOML file of settings (nested sections or flat keys); flags win"
    )
    p.add_argument("--task", default="hook_loop", choices=sorted(TASKS),
                   help="synthetic task to generate and train on (ignored with --data)")  # fmt: skip
    p.add_argument(
        "--data",
        help="recordings .npz (X [N,C,S], y, fs, class_names; see README) or a folder written "
        "by tactilesnn generate",
    )
    p.add_argument(
        "--data-window-s",
        type=float,
        help="with --data: cut each recording into windows of this many seconds (scores are "
        "then also summed per recording); 0: one window per recording; default: rows of >= 2 s "
        "and 256 samples without recording ids are cut into 7 windows (a quarter of the row, "
        "every eighth), shorter rows are kept whole",
    )
    p.add_argument(
        "--data-hop-s",
        type=float,
        help="with --data-window-s: seconds between window starts (default: half a window)",
    )
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
    p.add_argument(FAULTS_FLAG, help=FAULTS_HELP)
    p.add_argument("--task-kw", action="append", metavar="KEY=VALUE", help=TASK_KW_HELP)
    p.add_argument(
        "--val-fraction",
        type=float,
        default=0.0,
        help="fraction of training scans held out for early stopping / best weights",
    )
    g = p.add_argument_group("pipeline settings (unset flags keep the component's default)")
    for kind, reg in registries().items():
        g.add_argument(
            f"--{kind}",
            choices=reg.names(),
            default=argparse.SUPPRESS,
            help=f"{kind} component (default {DEFAULT_ENCODER if kind == 'encoder' else DEFAULT_MODEL}"
            "; with --data chosen from the file, see README)",
        )
    for name, (owner, default, text, choices) in flat_settings().items():
        kw: dict = {"default": argparse.SUPPRESS, "help": f"{text} [{owner}; default {default!r}]"}
        if choices:
            kw["choices"] = choices
        if isinstance(default, bool):
            kw["action"] = argparse.BooleanOptionalAction
        elif isinstance(default, tuple):
            kw["nargs"] = "+"
        else:
            kw["type"] = type(default)
        g.add_argument("--" + name.replace("_", "-"), **kw)


def _given_settings(args: argparse.Namespace) -> set[str]:
    """Pipeline settings the user gave: flags on the command line and the TOML's keys."""
    flags = {k for k in [*registries(), *flat_settings()] if hasattr(args, k)}
    return flags | set(getattr(args, "_pipeline_toml", None) or {})


def _config(args: argparse.Namespace) -> PipelineConfig:
    """TOML settings (if any) overridden by the flags given on the command line.

    With ``--data`` the defaults follow the file: every channel, the ``readout`` model, and the
    ``events`` encoder for event files (``X [N, taxels, polarity, bins]``), unless the settings
    say otherwise.
    """
    flat = {k: getattr(args, k) for k in [*registries(), *flat_settings()] if hasattr(args, k)}
    base = getattr(args, "_pipeline_toml", None) or {}
    if not getattr(args, "data", None) and "channels" not in {*flat, *base}:
        from .datasets_synth import get_task

        # the default channel ('dynamic', hook_loop's) where the task has it, else all of them
        names = get_task(args.task, **_task_kwargs(args)).channel_names
        if not set(PipelineConfig().channels) <= set(names):
            flat["channels"] = ("all",)
    if getattr(args, "data", None):
        from .recordings import event_grid, is_event_file

        given = _given_settings(args)
        events = is_event_file(Path(args.data))
        grid = event_grid(Path(args.data)) if events else None
        owners = flat_settings()
        for key, value in data_file_defaults(events, grid).items():
            # a default setting of the default model (or encoder) only goes with that component
            part = owners[key][0].split()[0] if key in owners else None
            if key not in given and part not in given:
                flat[key] = value
    return apply_flat(base, flat)


def _apply_toml(sub: argparse.ArgumentParser, argv: list[str]) -> tuple[str | None, dict]:
    """Load ``--config``: run options become the parser's defaults; returns the file's text and
    its pipeline settings (nested sections, or the flat form of earlier versions)."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--config")
    known, _ = pre.parse_known_args(argv)
    if not known.config:
        return None, {}
    import tomllib

    path = Path(known.config)
    if not path.is_file():
        raise ValueError(f"config file {path} does not exist")
    text = path.read_text()
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{path}: not valid TOML: {e}") from e
    nested = isinstance(table.get("encoder"), dict) or isinstance(table.get("model"), dict)
    if not nested and isinstance(table.get("train"), dict):  # the flat form under [train]
        table = {**{k: v for k, v in table.items() if k != "train"}, **table["train"]}
    dests = {a.dest for a in sub._actions} - {"help", "config"}
    pipeline_keys = {*registries(), *flat_settings()}
    settings: dict = {}
    defaults = {}
    for key, value in table.items():
        dest = key.replace("-", "_")
        if nested and key in ("encoder", "model", "train", *TOP_FLAGS):
            settings[key] = value
        elif not nested and dest in pipeline_keys:
            settings[dest] = value
        elif dest in dests and dest not in pipeline_keys:
            defaults[dest] = tuple(value) if isinstance(value, list) else value
        else:
            raise ValueError(f"{path}: unknown setting {key!r}")
    try:
        if nested:
            PipelineConfig.from_dict(settings)
        else:
            PipelineConfig.from_flat(settings, strict=True)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: {e}") from e
    sub.set_defaults(**defaults)
    return text, settings


def _parse_task_kw(items: Sequence[str] | None) -> dict:
    """``["layout_name=mia14", "n_samples=2000"]`` -> kwargs (values parsed as JSON if possible)."""
    out: dict = {}
    for item in items or []:
        key, sep, val = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--task-kw expects key=value, got {item!r}")
        try:
            value = json.loads(val)
        except json.JSONDecodeError:
            value = val
        out[key.strip()] = tuple(value) if isinstance(value, list) else value
    return out


def _task_kwargs(args: argparse.Namespace) -> dict:
    kw = {"difficulty": args.difficulty, "amplitude_spread": args.amplitude_spread}
    kw.update(_parse_task_kw(getattr(args, "task_kw", None)))
    if getattr(args, "faults", None):
        from .datasets_synth import parse_faults
        from .datasets_synth.base import task_parameters

        if "faults" not in task_parameters(args.task):
            raise ValueError(
                f"--faults applies to tasks with a sensor-fault model, not {args.task}"
            )

        parse_faults(args.faults)  # fail early on a typo
        kw["faults"] = args.faults
    return kw


def cmd_train(args: argparse.Namespace) -> int:
    from .runs import default_run_dir
    from .training import train_run

    config = _config(args)
    source = Path(args.data).stem if args.data else args.task
    out = (
        Path(args.out)
        if args.out
        else default_run_dir(Path("runs"), source, config.encoder_type, config.model_type)
    )
    if args.resume and not args.out:
        raise ValueError("--resume needs the --out folder of the interrupted run")
    if (args.data_window_s or args.data_hop_s) and not args.data:
        raise ValueError("--data-window-s / --data-hop-s cut a --data file's recordings")
    task_kwargs = dict(_task_kwargs(args), seed=config.seed)
    select = None
    window_s, hop_s = args.data_window_s, args.data_hop_s
    if args.data:
        from .recordings import auto_window, is_event_file

        if window_s is None and hop_s is None:
            window_s, hop_s = auto_window(Path(args.data)) or (None, None)
            if window_s is not None:
                log.info("recordings of %s cut into %.3g s windows every %.3g s (--data-window-s 0 "
                         "keeps them whole)", args.data, window_s, hop_s)  # fmt: skip
        elif window_s == 0:
            if hop_s is not None:
                raise ValueError("--data-hop-s needs a window length (--data-window-s > 0)")
            window_s = None

        if not is_event_file(Path(args.data)) and not encoder_settings_given(_given_settings(args)):
            select = DATA_ENCODER_CANDIDATES
    path, m = train_run(
        args.task,
        task_kwargs,
        config,
        out,
        overwrite=args.overwrite,
        progress=not args.quiet,
        data=Path(args.data) if args.data else None,
        data_window_s=window_s,
        data_hop_s=hop_s,
        select_encoders=select,
        resume=args.resume,
        val_fraction=args.val_fraction,
        config_text=getattr(args, "_config_text", None),
        export=args.export,
    )
    encoder = config.encoder_type
    if "encoder_selection_val_accuracy" in m:
        encoder = json.loads((path / "config.json").read_text())["pipeline"]["encoder"]["type"]
        held = ", ".join(
            f"{k} {100 * v:.1f} %" for k, v in m["encoder_selection_val_accuracy"].items()
        )
        print(f"encoder chosen on held-out training recordings: {encoder} ({held})")
    print(
        f"{source} {encoder}+{config.model_type}: test accuracy "
        f"{100 * m['test_accuracy']:.2f} % (+-{100 * m['test_accuracy_ci95']:.2f} % 95% CI, "
        f"{m['n_test_windows']} windows); "
        f"amplitude-only linear baseline {100 * m['trivial_amplitude_baseline_accuracy']:.2f} %"
    )
    if "test_accuracy_per_recording" in m:
        print(f"per recording (scores summed over its windows): "
              f"{100 * m['test_accuracy_per_recording']:.2f} % on {m['n_test_recordings']}")  # fmt: skip
    if "error" in m.get("onnx", {}):
        print(f"run folder {path} is complete, but the ONNX export failed: {m['onnx']['error']}")
        print(f"retry with: tactilesnn export {path} --out {path / 'model.onnx'}")
        return 1
    if "onnx" in m:
        print(
            f"model.onnx: {m['onnx']['nodes']} nodes; on the test split onnxruntime vs torch: "
            f"{_parity(m['onnx'])}"
        )
    print(f"run folder: {path}")
    return 0


def _parity(rep: dict) -> str:
    """One line of an export's verification report."""
    text = (
        f"encoder spike times within {rep.get('encoder_max_time_diff_ms', 0.0):.1e} ms, model "
        f"scores within {rep.get('model_max_score_diff', 0.0):.1e}; end to end max score "
        f"difference {rep['max_score_diff']:.1e}"
    )
    if rep.get("windows_beyond_atol"):
        text += f" ({rep['windows_beyond_atol']} window(s) with a spike on a step boundary)"
    return text + f", predictions agree {100 * rep['prediction_agreement']:.2f} %"


def cmd_evaluate(args: argparse.Namespace) -> int:
    from .datasets_synth import get_task
    from .recordings import load_data_file
    from .training import load_run, recording_accuracy, run_data

    pipe, cfg = load_run(Path(args.run_dir))
    if args.data:  # cut as the run's own data was
        tr, test = load_data_file(Path(args.data), pipe.config.seed,
                                  window_s=cfg.get("data_window_s"), hop_s=cfg.get("data_hop_s"))  # fmt: skip
        if args.all:
            test = type(test)(
                np.concatenate([tr.X, test.X]),
                np.concatenate([tr.y, test.y]),
                np.concatenate([tr.scan, test.scan]),
                test.fs_hz,
                test.class_names,
                test.channel_names,
            )
        if abs(test.fs_hz - pipe.fs_hz) > 1e-6 * pipe.fs_hz:
            raise ValueError(f"data sampled at {test.fs_hz} Hz, the run expects {pipe.fs_hz} Hz")
        test = _match_channels(test, pipe.channel_names)
    elif cfg.get("data"):
        _, test = run_data(cfg, pipe.config.seed)
    else:
        _, test = get_task(cfg["task"], **cfg["task_kwargs"]).build(progress=not args.quiet)
    scores = pipe.scores(pipe.encode(test.X, progress=not args.quiet)).numpy()
    pred = scores.argmax(1)
    per_rec = recording_accuracy(scores, test.y, test.scan)
    acc = float((pred == test.y).mean()) if test.y.size else 0.0
    recall = {
        name: float((pred[test.y == i] == i).mean()) if (test.y == i).any() else None
        for i, name in enumerate(pipe.class_names)
    }
    if args.json:
        out = {"run": str(args.run_dir), "test_accuracy": acc, "n": int(test.y.size),
               "per_class_recall": recall, **(per_rec or {})}  # fmt: skip
        print(json.dumps(out))
        return 0
    from .pipeline import accuracy_ci95

    print(f"{args.run_dir}: accuracy {100 * acc:.2f} % (+-{100 * accuracy_ci95(acc, test.y.size):.2f} %"
          f" 95% CI) on {test.y.size} windows")  # fmt: skip
    if per_rec is not None:
        a, n = per_rec["test_accuracy_per_recording"], per_rec["n_test_recordings"]
        print(f"  per recording (scores summed over its windows): {100 * a:.2f} % "
              f"(+-{100 * per_rec['test_accuracy_per_recording_ci95']:.2f} %) on {n} recordings")  # fmt: skip
    width = max(len(n) for n in pipe.class_names)
    for name, r in recall.items():
        print(f"  {name:<{width}}  recall {'-' if r is None else f'{100 * r:6.2f} %'}")
    return 0


def _match_channels(data, want: Sequence[str]):
    """``data`` with its channels in the run's order (by name); ValueError if they differ."""
    have = tuple(data.channel_names)
    if have == tuple(want):
        return data
    if sorted(have) != sorted(want):
        raise ValueError(f"the data's channels {list(have)} are not the run's {list(want)}")
    log.warning("data channels are in another order than the run's: reordered by name")
    idx = [have.index(c) for c in want]
    return type(data)(data.X[:, idx], data.y, data.scan, data.fs_hz, data.class_names, tuple(want))


def cmd_export(args: argparse.Namespace) -> int:
    from .datasets_synth import get_task
    from .export import data_hash, export_pipeline
    from .training import load_run, run_data

    pipe, cfg = load_run(Path(args.run_dir))
    if args.format == "nir":
        pipe.model.to_nir()  # refuses models NIR cannot express, before any work
    if cfg.get("data"):
        _, test = run_data(cfg, pipe.config.seed)
    else:
        _, test = get_task(cfg["task"], **cfg["task_kwargs"]).build(progress=not args.quiet)
    if args.format == "nir":
        from .export.nir import compare, write_nir

        path = write_nir(pipe.model, Path(args.out), overwrite=args.overwrite)
        rep = compare(pipe.model, pipe.encode(test.X), path)
        if not rep["simulated"]:
            print(f"exported {path} (recurrent graph; not simulated by the reference consumer)")
            return 0
        print(
            f"exported {path} (model only; input: the spike raster at "
            f"{pipe.model.config.dt_ms:g} ms). Read back with nir.read and simulated with nirtorch "
            f"on {test.y.size} test windows: max score difference "
            f"{rep['subtract_reset_max_score_diff']:.2e}, predictions agree "
            f"{100 * rep['subtract_reset_prediction_agreement']:.2f} % (plain NIR reset-to-zero: "
            f"{100 * rep['nir_reset_to_zero_prediction_agreement']:.2f} %)"
        )
        return 0
    report = export_pipeline(
        pipe,
        Path(args.out),
        test.X,
        metadata={"training_data_sha256": data_hash(cfg), "run": str(args.run_dir)},
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    print(
        f"exported {args.out}: {report['nodes']} nodes; on {report['n_checked']} test windows "
        f"onnxruntime vs torch: {_parity(report)}"
    )
    if args.quantize:
        from .export import quantize_int8

        q = quantize_int8(Path(args.out), test.X, test.y, overwrite=args.overwrite)
        print(
            f"int8 model {q['path']}: test accuracy {100 * q['int8_accuracy']:.2f} % vs float32 "
            f"{100 * q['float_accuracy']:.2f} % (change {100 * q['accuracy_change']:+.2f} points); "
            f"{q['int8_bytes']} vs {q['float_bytes']} bytes"
        )
    return 0


def cmd_generate(args: argparse.Namespace) -> int:
    from .datasets_synth.generate import generate

    m = generate(
        args.task,
        args.n,
        args.seed,
        Path(args.out),
        shard_size=args.shard_size,
        workers=args.workers,
        overwrite=args.overwrite,
        resume=args.resume,
        progress=not args.quiet,
        task_kwargs=_task_kwargs(args),
        scheduler=args.scheduler,
    )
    print(
        f"{args.out}: {m['n_samples']} samples, {m['n_windows']} windows in "
        f"{len(m['shards'])} shards ({m['fs_hz']:g} Hz, classes {', '.join(m['class_names'])})"
    )
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from .sweep import run_sweep

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
    import urllib.error

    from .service.client import ServiceError
    from .service.demo import demo_stream

    try:
        n = demo_stream(args.url, args.task, stream=args.stream, seconds=args.seconds,
                        speed=args.speed, chunk_ms=args.chunk_ms, seed=args.seed)  # fmt: skip
    except (ServiceError, urllib.error.URLError) as e:
        raise ValueError(f"the service at {args.url} answered: {e} (is tactilesnn serve "
                         "running with a model?)") from e  # fmt: skip
    print(f"streamed {args.task} to {args.url} (stream {args.stream!r}): {n} windows classified")
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    from .service.app import serve

    if not (args.stream_ttl_s > 0 and np.isfinite(args.stream_ttl_s)):
        raise ValueError(f"--stream-ttl-s must be a positive number, got {args.stream_ttl_s}")
    serve(args.model, host=args.host, port=args.port, threads=args.threads,
          stream_ttl_s=args.stream_ttl_s, allowed_hosts=args.allowed_hosts)  # fmt: skip
    return 0


BENCHMARKS = (
    "gwt-vs-stft",
    "encoders",
    "snn",
    "serve",
    "tasks",
    "real",
    "pareto",
    "stability",
    "skip",
)


def cmd_bench(args: argparse.Namespace) -> int:
    if args.name in ("pareto", "stability") and args.out is None:
        raise ValueError(f"bench {args.name} needs --out DIR")
    if args.name == "skip":
        from .bench import skip

        skip.run(Path(args.out) if args.out else None, quick=args.quick, overwrite=args.overwrite)
        return 0
    if args.name == "stability":
        from .bench import stability

        _, ok = stability.run(Path(args.out), quick=args.quick, progress=not args.quiet,
                              overwrite=args.overwrite)  # fmt: skip
        return 0 if ok else 1
    if args.name == "pareto":
        from .bench import pareto

        pareto.run(Path(args.out), task=args.task, quick=args.quick, epochs=args.bench_epochs or 10,
                   overwrite=args.overwrite, progress=not args.quiet)  # fmt: skip
        return 0
    if args.name == "serve":
        from .bench import serve as bench_serve

        if not args.model:
            raise ValueError("bench serve needs --model model.onnx")
        res = bench_serve.run(args.model, clients=args.clients, seconds=args.seconds)
        if args.out:
            _write_json(Path(args.out) / "serve.json", res)
        return 0
    if args.name == "real":
        from .bench import real

        if args.out is None:
            raise ValueError("bench real needs --out DIR")
        real.run(Path(args.out), data_root=Path(args.data_root), seeds=args.seeds or 3,
                 datasets=args.datasets, pipelines=args.pipelines,
                 epochs=args.bench_epochs, progress=not args.quiet)  # fmt: skip
        return 0
    if args.name == "tasks":
        from .bench import tasks

        res = tasks.run(workers=args.workers, progress=not args.quiet)
        if args.out:
            _write_json(Path(args.out) / "tasks.json", res)
        if args.references:  # each task as a user's file: spike pipeline vs strong references
            from .bench import real

            if args.out is None:
                raise ValueError("bench tasks --references needs --out DIR")
            names = list(real.synthetic_datasets())
            real.run(Path(args.out) / "references", datasets=names, seeds=args.seeds or 1,
                     pipelines=args.pipelines or ["default+readout"], epochs=args.bench_epochs,
                     progress=not args.quiet)  # fmt: skip
        return 0
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
        seeds=args.seeds or 5,
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


def _port(text: str) -> int:
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port must be an integer in 1-65535, got {text!r}")
    return port


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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tactilesnn", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    p = _command(sub, "train", "train a pipeline and write a run folder")
    _add_pipeline_args(p)
    p.add_argument("--out", help="run folder (default runs/<task>-<encoder>-<model>-<time>)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run folder")
    p.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    p.add_argument(
        "--export",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="write model.onnx (window -> scores) into the run folder",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_train)

    p = _command(sub, "evaluate", "evaluate a run folder on its test split or --data")
    p.add_argument("run_dir", help="run folder written by train")
    p.add_argument("--data", help="recordings .npz or generated folder to evaluate on (its test "
                   "split, cut as the run's data was)")  # fmt: skip
    p.add_argument("--all", action="store_true", help="with --data: evaluate on every recording")
    p.add_argument("--json", action="store_true", help="print one JSON line instead of a summary")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_evaluate)

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
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_export)

    p = _command(sub, "generate", "render a synthetic task into sharded files")
    p.add_argument("--task", default="hook_loop", choices=sorted(TASKS), help="synthetic task")
    p.add_argument("--n", type=int, required=True, help="number of samples (scans or trials)")
    p.add_argument("--seed", type=int, default=0, help="sample i depends only on (task, seed, i)")
    p.add_argument("--out", required=True, help="dataset folder (train --data reads it)")
    p.add_argument("--shard-size", type=int, default=50, help="samples per shard file")
    p.add_argument("--workers", type=int, default=2, help="local rendering processes")
    p.add_argument("--difficulty", type=float, default=1.0,
                   help="multiplier of the task's noise and nuisance spread")  # fmt: skip
    p.add_argument("--amplitude-spread", type=float, default=1.0,
                   help="multiplier of the task's amplitude nuisances")  # fmt: skip
    p.add_argument(FAULTS_FLAG, help=FAULTS_HELP)
    p.add_argument("--task-kw", action="append", metavar="KEY=VALUE", help=TASK_KW_HELP)
    p.add_argument("--overwrite", action="store_true", help="replace a dataset in --out")
    p.add_argument("--resume", action="store_true", help="finish an interrupted generation")
    p.add_argument("--scheduler", help=SCHEDULER_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_generate)

    p = _command(sub, "sweep", "grid / random search over train settings, each a run folder")
    p.add_argument("--config", required=True, help="sweep TOML ([base] + [grid] or [random])")
    p.add_argument("--out", required=True,
                   help="sweep folder: trials/<id>/ run folders, results.json, results.md; "
                   "finished trials are skipped when run again")  # fmt: skip
    p.add_argument("--workers", type=int, default=2, help="local trial processes")
    p.add_argument("--scheduler", help=SCHEDULER_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_sweep)

    p = _command(sub, "serve", "HTTP inference service (onnxruntime + numpy only)")
    p.add_argument("model", help="model.onnx written by train or export")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on")
    p.add_argument("--port", type=_port, default=8000, help="TCP port (1-65535)")
    p.add_argument("--threads", type=int, default=0, help="onnxruntime intra-op threads")
    p.add_argument("--stream-ttl-s", type=float, default=300.0,
                   help="drop a stream after this many seconds without a chunk")  # fmt: skip
    p.add_argument("--allowed-hosts", nargs="+", default=[], metavar="NAME",
                   help="extra host names browsers may use to reach the service (DNS-rebinding "
                        "guard; loopback names are always allowed; '*' turns the check off)")  # fmt: skip
    p.set_defaults(func=cmd_serve)

    p = _command(sub, "demo-stream", "stream a synthetic task to a running service (live page)")
    p.add_argument("--url", default="http://127.0.0.1:8000", help="the service's base URL")
    p.add_argument("--task", default="hook_loop", choices=sorted(TASKS), help="synthetic task")
    p.add_argument("--stream", default="demo", help="stream id on the service")
    p.add_argument("--seconds", type=float, default=0.0,
                   help="seconds of signal to send (default: 0 = until interrupted)")  # fmt: skip
    p.add_argument("--speed", type=float, default=1.0,
                   help="pace as a multiple of real time (0 = as fast as the service answers)")  # fmt: skip
    p.add_argument("--chunk-ms", type=float, default=100.0, help="signal per request (ms)")
    p.add_argument("--seed", type=int, default=0, help="task seed (which scans are rendered)")
    p.set_defaults(func=cmd_demo_stream)

    p = _command(sub, "bench", "benchmarks")
    p.add_argument("name", choices=BENCHMARKS, help="which benchmark (see README)")
    p.add_argument(
        "--seeds",
        type=int,
        default=None,
        help="gwt-vs-stft (default 5) / real (default 3): dataset and training seeds",
    )
    p.add_argument("--out", help="output folder")
    p.add_argument("--repeats", type=int, default=7, help="encoders: timed runs per case")
    p.add_argument("--sparse", action="store_true", help="encoders: activity-gate benchmark")
    p.add_argument("--model", help="serve: model.onnx to load-test")
    p.add_argument("--clients", type=int, default=8, help="serve: concurrent clients")
    p.add_argument("--seconds", type=float, default=10.0, help="serve: duration per case")
    p.add_argument("--workers", type=int, default=2, help="tasks: generation processes")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out folder")
    p.add_argument("--epochs", type=int, default=TrainConfig().epochs,
                   help="gwt-vs-stft / tasks: training epochs")  # fmt: skip
    p.add_argument("--difficulty", type=float, default=1.0,
                   help="gwt-vs-stft / tasks: task difficulty multiplier")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument(
        "--data-root",
        default="../shared/data",
        help="real: folder holding the real datasets (never copied into the repo)",
    )
    p.add_argument("--datasets", nargs="+", help="real: subset of datasets (default: the real ones "
                   "found); synth:<task> runs the same check on a synthetic task")  # fmt: skip
    p.add_argument("--pipelines", nargs="+", help="real: subset of spike pipelines")
    p.add_argument(
        "--bench-epochs",
        type=int,
        default=None,
        help="real: epochs (default: each model's own default, as train --data); pareto: "
        "epochs per configuration (default 10)",
    )
    p.add_argument("--task", default="hook_loop", choices=sorted(TASKS),
                   help="pareto: the task whose pipelines are compared")  # fmt: skip
    p.add_argument("--references", action="store_true",
                   help="tasks: also each task's spike pipeline (--data defaults) against the "
                   "non-spiking references of bench real")  # fmt: skip
    p.add_argument("--quick", action="store_true",
                   help="pareto / stability / skip: a few small cases (as the test suite runs)")  # fmt: skip
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    config_text, pipeline_toml = None, {}
    if argv and argv[0] == "train":
        sub = next(
            a
            for a in parser._subparsers._group_actions
            if isinstance(a, argparse._SubParsersAction)
        ).choices["train"]
        try:
            config_text, pipeline_toml = _apply_toml(sub, argv[1:])
        except ValueError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
    args = parser.parse_args(argv)
    args._config_text = config_text
    args._pipeline_toml = pipeline_toml
    from .perf import tune_allocator

    tune_allocator()
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(message)s",
    )
    from .export.onnx import ExportError

    try:
        return args.func(args)
    except (ValueError, FileExistsError, FileNotFoundError, ExportError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"interrupted{_resume_hint(args, argv)}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""The commands other than ``train``, ``convert``, ``sweep`` and ``bench`` as application
functions: each takes typed arguments, does the work through the layers below, and returns the
lines to print (the command line parses and prints; nothing else)."""

from __future__ import annotations

import argparse
import urllib.error
from pathlib import Path
from typing import Any

from ..core.checks import ExportError
from ..datasets_synth import get_task
from ..datasets_synth.generate import generate
from ..encoders import ENCODERS
from ..pipeline import accuracy_ci95
from ..service import command as service_command
from ..service.client import ServiceError
from ..training import recording_accuracy, stream_metrics
from .demo import demo_stream
from .options import task_names
from .run import evaluation_data, load_run, source_of
from .runs import RUN_FILES

__all__ = [
    "ExportError",
    "describe_tasks",
    "evaluate",
    "export_run",
    "generate_dataset",
    "serve",
    "stream_demo",
    "task_names",
]  # fmt: skip


def parity_line(rep: dict) -> str:
    """One line of an export's verification report."""
    text = (
        f"encoder spike times within {rep.get('encoder_max_time_diff_ms', 0.0):.1e} ms, model "
        f"scores within {rep.get('model_max_score_diff', 0.0):.1e}; end to end max score "
        f"difference {rep['max_score_diff']:.1e}"
    )
    if rep.get("windows_beyond_atol"):
        text += f" ({rep['windows_beyond_atol']} window(s) with a spike on a step boundary)"
    return text + f", predictions agree {100 * rep['prediction_agreement']:.2f} %"


def frame_stream_line(st: dict) -> str:
    """The train command's line for a stream model scored frame by frame
    (:func:`~tactilesnn.stream_training.stream_evaluation`)."""
    text = (f"as a stream (frame by frame, state carried, a decision every {st['frame_ms']:.3g} "
            f"ms frame): per window {100 * st['per_window']:.2f} %")  # fmt: skip
    if "per_recording" in st:
        text += f", per recording {100 * st['per_recording']:.2f} %"
    lat = st.get("decision_latency_ms")
    if lat:
        text += (f"; decision latency median {lat['median']:.0f} ms (quartiles {lat['q25']:.0f}-"
                 f"{lat['q75']:.0f}), {100 * st['settled_fraction']:.0f} % of "
                 f"{st['segments']} label segments settle")  # fmt: skip
    return text


def stream_hint(encoder: str, path: Path) -> str | None:
    """How to export a run's stream graph, where its encoder has a stream form (or its
    one-frame step graph, where it has a frame step)."""
    if ENCODERS.get(encoder).has_frame_step:
        return (f"for streams, a decision every frame: tactilesnn export {path} --frames --out "
                f"{path / 'frames.onnx'} (with a stream model: --model stream)")  # fmt: skip
    if not ENCODERS.get(encoder).has_stream_form:
        return None
    return (f"for streams (each sample transformed once): tactilesnn export {path} --stream "
            f"--out {path / 'stream.onnx'} (a window every half window; --stream-step SAMPLES "
            "for another step, one hop for a window every frame)")  # fmt: skip


# ---------------------------------------------------------------- evaluate
def evaluate(run_dir: Path, data: Path | None = None, every: bool = False,
             fs_hz: float | None = None, progress: bool = True) -> dict[str, Any]:  # fmt: skip
    """A run folder on its test split or on ``data`` (every recording with ``every``): accuracy
    per window (with its 95 % interval) and per recording, in a stream where the encoder has
    one, and per-class recall."""
    pipe, cfg = load_run(Path(run_dir))
    test = evaluation_data(pipe, cfg, data, every=every, progress=progress, fs_hz=fs_hz)
    scores = pipe.scores(pipe.encode(test.X, progress=progress)).numpy()
    pred = scores.argmax(1)
    per_rec = recording_accuracy(scores, test.y, test.scan)
    acc = float((pred == test.y).mean()) if test.y.size else 0.0
    in_rec = pipe.encode_in_recordings(test.X, test.scan) if test.y.size else None
    st = stream_metrics(pipe, scores, in_rec, test.y, None) if in_rec is not None else None
    recall = {
        name: float((pred[test.y == i] == i).mean()) if (test.y == i).any() else None
        for i, name in enumerate(pipe.class_names)
    }
    return {"run": str(run_dir), "test_accuracy": acc, "n": int(test.y.size),
            "test_accuracy_ci95": accuracy_ci95(acc, test.y.size), "per_class_recall": recall,
            **(per_rec or {}), **({"in_stream": st} if st else {})}  # fmt: skip


def evaluation_lines(rep: dict[str, Any]) -> list[str]:
    """:func:`evaluate`'s report as the command prints it."""
    lines = [f"{rep['run']}: accuracy {100 * rep['test_accuracy']:.2f} % "
             f"(+-{100 * rep['test_accuracy_ci95']:.2f} % 95% CI) on {rep['n']} windows"]  # fmt: skip
    if "test_accuracy_per_recording" in rep:
        lines.append(f"  per recording (scores summed over its windows): "
                     f"{100 * rep['test_accuracy_per_recording']:.2f} % "
                     f"(+-{100 * rep['test_accuracy_per_recording_ci95']:.2f} %) on "
                     f"{rep['n_test_recordings']} recordings")  # fmt: skip
    if "in_stream" in rep:
        st = rep["in_stream"]
        lines.append(f"  as a stream serves them (each window coded with its recording's past, "
                     f"{st['test_windows_with_past']} have one): "
                     f"{100 * st['test_accuracy']:.2f} %")  # fmt: skip
    recall = rep["per_class_recall"]
    width = max(len(n) for n in recall)
    lines += [f"  {name:<{width}}  recall {'-' if r is None else f'{100 * r:6.2f} %'}"
              for name, r in recall.items()]  # fmt: skip
    return lines


def condition_lines(m: dict, source: Any) -> list[str]:
    """The test accuracy per value of each condition the data states (``metrics.json``'s
    ``by_condition``), the held-out condition first and named so."""
    left_out = source.condition_left_out
    lines = []
    for name, rows in sorted(
        (m.get("by_condition") or {}).items(), key=lambda kv: kv[0] != left_out
    ):
        parts = []
        for value, r in rows.items():
            rec = r.get("accuracy_per_recording")
            per = f" ({100 * rec:.1f} % per recording)" if rec is not None else ""
            parts.append(f"{name}={value}: {100 * r['accuracy']:.1f} %{per}")
        head = (
            f"on the held-out conditions ({source.hold_out}, none trained on)"
            if name == left_out
            else f"by condition {name}"
        )
        lines.append(f"{head}: " + "; ".join(parts))
    for name, r in (m.get("unseen_conditions") or {}).items():
        rec = r.get("accuracy_per_recording")
        per = f", {100 * rec:.1f} % per recording" if rec is not None else ""
        lines.append(f"unseen values of {name} (training windows, each scored by a read-out "
                     f"re-fitted without its value): {100 * r['accuracy']:.1f} %{per} ("
                     + "; ".join(f"{name}={v}: {100 * a:.1f} %" for v, a in r["per_value"].items())
                     + f"); to test on one: --hold-out '{name}=VALUE'")  # fmt: skip
    return lines


# ---------------------------------------------------------------- export
#: the run folder's files an export may replace (its own exports)
EXPORT_FILES = frozenset({"model.onnx", "model.int8.onnx", "model.nir"})


def _refuse_run_file(run_dir: Path, out: Path) -> None:
    """An export must not replace what the run itself needs (its weights, settings, metrics):
    ``--overwrite`` replaces an earlier export, never the run."""
    target = out.resolve()
    if target.parent == run_dir.resolve() and target.name in RUN_FILES - EXPORT_FILES:
        raise ValueError(f"--out {out} is the run's own {target.name}; export to another name "
                         "(model.onnx, or a path outside the run folder)")  # fmt: skip


def export_run(run_dir: Path, out: Path, fmt: str = "onnx", stream: bool = False,
               stream_step: int | None = None, quantize: bool = False, overwrite: bool = False,
               progress: bool = True, frames: bool = False) -> list[str]:  # fmt: skip
    """Export a run folder (ONNX window graph, ONNX stream graph, the one-frame step graph or
    NIR), every conflict among the options refused before any work; returns the lines to
    print."""
    if frames and (stream or quantize or fmt != "onnx"):
        raise ValueError("--frames writes the float32 ONNX one-frame step graph: drop --stream / "
                         "--quantize / --format")  # fmt: skip
    if stream_step is not None and not stream:
        raise ValueError("--stream-step sets the stream graph's step: add --stream")
    if stream and (quantize or fmt != "onnx"):
        raise ValueError(
            "--stream writes the float32 ONNX stream graph: drop --quantize / --format"
        )
    int8 = Path(out).with_name(Path(out).stem + ".int8.onnx")  # (as export.quantize_int8)
    for path in (Path(out), *([int8] if quantize else [])):
        _refuse_run_file(Path(run_dir), path)
    pipe, cfg = load_run(Path(run_dir))
    if frames and pipe.frame_problem():
        raise ValueError(f"--frames: {pipe.frame_problem()}")
    if fmt == "nir":
        pipe.model.to_nir()  # refuses models NIR cannot express, before any work
    if stream:
        from ..export.stream_graph import StreamEncoderGraph

        StreamEncoderGraph(pipe, stream_step)  # refuses a step that does not fit, first
    test = source_of(cfg).load_test(pipe.config.seed, progress=progress)
    if fmt == "nir":
        return _export_nir(pipe, test, Path(out), overwrite)
    from ..export import data_hash, export_pipeline, quantize_int8  # (onnx: ~1.4 s to import)

    meta = {"training_data_sha256": data_hash(cfg), "run": str(run_dir)}
    if frames:
        from ..export.frames import export_frames

        rep = export_frames(pipe, Path(out), test.X, metadata=meta, overwrite=overwrite)
        return [
            f"exported the one-frame step graph {out} ({rep['hop_samples']} samples = "
            f"{rep['frame_ms']:.4g} ms per call: the frame's scores and decision, state carried): "
            f"{rep['nodes']} nodes; over {rep['frames']} frames of test windows joined into one "
            f"recording, onnxruntime vs torch frame by frame: {rep['spike_flips']} spike flips, "
            f"scores within {rep['max_score_diff']:.2g}, decisions agree "
            f"{100 * rep['decisions_agree']:.2f} %"
        ]
    if stream:
        from ..export.stream_graph import export_stream

        rep = export_stream(pipe, Path(out), test.X, metadata=meta, overwrite=overwrite,
                            step=stream_step)  # fmt: skip
        step_ms = 1000.0 * rep["step_samples"] / pipe.fs_hz
        return [
            f"exported the stream graph {out} ({rep['step_samples']} samples = {step_ms:.4g} "
            f"ms per call: a window's scores every call, every sample transformed once): "
            f"{rep['nodes']} nodes; on {rep['windows_checked']} windows "
            f"of the test windows joined into one stream, onnxruntime vs torch: spike times within "
            f"{rep['encoder_max_time_diff_ms']:.2g} ms, scores within {rep['max_score_diff']:.2g}, "
            f"predictions agree {100 * rep['prediction_agreement']:.2f} %"
        ]
    report = export_pipeline(pipe, Path(out), test.X, metadata=meta, overwrite=overwrite,
                             progress=progress)  # fmt: skip
    lines = [f"exported {out}: {report['nodes']} nodes; on {report['n_checked']} test windows "
             f"onnxruntime vs torch: {parity_line(report)}"]  # fmt: skip
    if quantize:
        q = quantize_int8(Path(out), test.X, test.y, overwrite=overwrite)
        lines.append(
            f"int8 model {q['path']}: test accuracy {100 * q['int8_accuracy']:.2f} % vs float32 "
            f"{100 * q['float_accuracy']:.2f} % (change {100 * q['accuracy_change']:+.2f} points); "
            f"{q['int8_bytes']} vs {q['float_bytes']} bytes"
        )
    return lines


def _export_nir(pipe, test, out: Path, overwrite: bool) -> list[str]:
    """The run's model as a NIR graph at ``out``, read back and simulated on the test windows."""
    from ..export.nir import compare, write_nir

    path = write_nir(pipe.model, out, overwrite=overwrite)
    rep = compare(pipe.model, pipe.encode(test.X), path)
    if not rep["simulated"]:
        return [f"exported {path} (recurrent graph; not simulated by the reference consumer)"]
    return [
        f"exported {path} (model only; input: the spike raster at "
        f"{pipe.model.config.dt_ms:g} ms). Read back with nir.read and simulated with nirtorch "
        f"on {test.y.size} test windows: max score difference "
        f"{rep['subtract_reset_max_score_diff']:.2e}, predictions agree "
        f"{100 * rep['subtract_reset_prediction_agreement']:.2f} % (plain NIR reset-to-zero: "
        f"{100 * rep['nir_reset_to_zero_prediction_agreement']:.2f} %)"
    ]


# ---------------------------------------------------------------- synthetic tasks
def describe_tasks() -> list[str]:
    """One paragraph per registered task: its classes, channels, rate, window and units."""
    lines = []
    for name in task_names():
        task = get_task(name)
        classes = task.class_names
        shown = ", ".join(classes[:6]) + (", ..." if len(classes) > 6 else "")
        doc = (type(task).__doc__ or "").strip().splitlines()[0]
        lines.append(f"{name}: {doc}\n  {len(classes)} classes ({shown}); "
                     f"{len(task.channel_names)} channels at {task.fs_hz:g} Hz, {task.window}-sample "
                     f"windows; {task.n_samples} samples by default; units: "
                     f"{task.units or '-'}")  # fmt: skip
    return lines


def generate_dataset(task: str, n: int, seed: int, out: Path, **kw: Any) -> list[str]:
    """Render a synthetic task into sharded files (see
    :func:`~tactilesnn.datasets_synth.generate.generate`)."""
    m = generate(task, n, seed, Path(out), **kw)
    return [f"{out}: {m['n_samples']} samples, {m['n_windows']} windows in "
            f"{len(m['shards'])} shards ({m['fs_hz']:g} Hz, classes "
            f"{', '.join(m['class_names'])})"]  # fmt: skip


# ---------------------------------------------------------------- the service
def add_serve_arguments(p: argparse.ArgumentParser) -> None:
    service_command.add_arguments(p)


def serve(args: argparse.Namespace) -> int:
    return service_command.run(args)


def stream_demo(url: str, task: str, stream: str, seconds: float, speed: float, chunk_ms: float,
                seed: int) -> list[str]:  # fmt: skip
    """Stream a synthetic task to a running service (its live page shows it)."""
    try:
        n = demo_stream(url, task, stream=stream, seconds=seconds, speed=speed,
                        chunk_ms=chunk_ms, seed=seed)  # fmt: skip
    except (ServiceError, urllib.error.URLError) as e:
        raise ValueError(f"the service at {url} answered: {e} (is tactilesnn serve running "
                         "with a model?)") from e  # fmt: skip
    return [f"streamed {task} to {url} (stream {stream!r}): {n} windows classified"]

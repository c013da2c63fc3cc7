"""CLI: train writes a complete run folder, refuses overwrites, evaluate reloads it."""

import json
import subprocess
import sys

import numpy as np
import pytest

from tactilesnn.app.run import load_run
from tactilesnn.cli import main


@pytest.fixture(scope="session")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "r1"
    rc = main(["train", "--epochs", "2", "--out", str(out), "--quiet", "--seed", "3"])
    assert rc == 0
    return out


@pytest.mark.slow
def test_train_writes_run_folder(run_dir, capsys):
    names = {p.name for p in run_dir.iterdir()}
    assert {"config.json", "weights.npz", "metrics.json", "confusion_matrix.json"} <= names
    assert {"confusion_matrix.png", "training_error.png", "test_windows.png"} <= names
    m = json.loads((run_dir / "metrics.json").read_text())
    assert 0.5 <= m["test_accuracy"] <= 1.0 and len(m["train_error_history"]) == 2
    cm = json.loads((run_dir / "confusion_matrix.json").read_text())
    assert np.array(cm["matrix"]).sum() == m["n_test_windows"]
    # weights load without pickle
    with np.load(run_dir / "weights.npz", allow_pickle=False) as f:
        assert f["model.net.weight"].shape[0] == 2


def test_refuses_to_overwrite(run_dir, capsys):
    before = (run_dir / "metrics.json").read_text()
    rc = main(["train", "--epochs", "1", "--out", str(run_dir), "--quiet"])
    assert rc == 2
    assert "already exists" in capsys.readouterr().err
    assert (run_dir / "metrics.json").read_text() == before


@pytest.mark.slow
def test_evaluate_reproduces_metrics(run_dir, capsys):
    assert main(["evaluate", str(run_dir), "--quiet", "--json"]) == 0
    got = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    saved = json.loads((run_dir / "metrics.json").read_text())
    assert got["test_accuracy"] == pytest.approx(saved["test_accuracy"])
    assert got["per_class_recall"] == pytest.approx(saved["per_class_recall"])
    assert main(["evaluate", str(run_dir), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert f"accuracy {100 * saved['test_accuracy']:.2f} %" in text and "hook  recall" in text


def test_pipeline_refuses_bad_windows(run_dir):
    pipe, _ = load_run(run_dir)
    x = np.zeros((2, 2, 100), np.float32)
    x[1, 1, 42] = np.inf
    with pytest.raises(ValueError, match="channel 1, sample 42"):
        pipe.predict(x)
    with pytest.raises(ValueError, match=r"\[N, 2 channels, 100 samples\]"):
        pipe.predict(np.zeros((2, 2, 50)))


def test_unknown_names_are_refused(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["train", "--encoder", "wavelet"])
    assert "invalid choice" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path)]) == 2
    assert "not a run folder" in capsys.readouterr().err


@pytest.mark.slow
def test_train_py_is_the_same_cli(capsys):
    """train.py runs the CLI, options alone meaning ``train`` (two processes: each start imports
    torch, seconds on a busy machine); the rest of the help in process."""

    def script(*argv: str) -> str:
        return subprocess.run([sys.executable, "train.py", *argv], capture_output=True,
                              text=True, check=True).stdout  # fmt: skip

    top = script("--help")
    assert "evaluate" in top and "bench" in top  # every command
    assert "--task" in script("--epochs", "1", "--help")

    def run(*argv: str) -> str:
        with pytest.raises(SystemExit) as stop:
            main(list(argv))
        assert stop.value.code in (0, None)
        return capsys.readouterr().out

    assert run("--help") == top
    assert "--encoder" in run("train", "--help")
    assert "run_dir" in run("evaluate", "--help")
    assert run("--version").startswith("tactilesnn ")


def test_generate_trial_task_with_task_kw_and_faults(tmp_path, capsys):
    out = tmp_path / "sc"
    args = ["generate", "--task", "stiffness_curvature", "--n", "4", "--out", str(out),
            "--task-kw", "layout_name=mia14", "--faults", "dead=2", "--quiet"]  # fmt: skip
    assert main(args) == 0
    m = json.loads((out / "manifest.json").read_text())
    assert len(m["channel_names"]) == 14 and m["parameters"]["faults"]["dead"] == [2]
    bad = ["generate", "--task", "texture", "--n", "2", "--out", str(tmp_path / "x"),
           "--task-kw", "layout=1", "--quiet"]  # fmt: skip
    assert main(bad) != 0
    assert "has no parameter(s) ['layout']" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["texture", "stiffness_curvature", "material", "touch"])
def test_task_configs_parse(name):
    from pathlib import Path

    from tactilesnn.app.config_file import read_train_file
    from tactilesnn.app.defaults import run_spec

    path = Path(__file__).resolve().parents[1] / "configs" / f"{name}.toml"
    file = read_train_file(path)
    assert file.run["task"] == name
    spec = run_spec(file.run, Path("x"), toml=file.pipeline)  # every key is a valid setting
    assert spec.config.channels in (("all",), ("dynamic",)) and spec.source.name == name


def test_serve_refuses_a_port_out_of_range(capsys):
    with pytest.raises(SystemExit) as e:
        main(["serve", "model.onnx", "--port", "99999"])
    assert e.value.code == 2 and "port must be an integer in 1-65535" in capsys.readouterr().err


def test_every_flag_of_every_command_has_help_with_its_default_and_choices():
    import argparse

    from tactilesnn.cli import build_parser

    def commands(parser, prefix=""):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, p in a.choices.items():
                    yield prefix + name, p
                    yield from commands(p, prefix + name + " ")

    seen = dict(commands(build_parser()))
    assert "bench stability" in seen and "bench real" in seen  # each benchmark's own flags
    for name, p in seen.items():
        text = p.format_help()
        for a in p._actions:
            if isinstance(a, argparse._HelpAction):
                continue
            flag = a.option_strings[0] if a.option_strings else a.dest
            assert a.help, f"{name} {flag}: no help text"
            if a.choices and a.option_strings:
                assert "{" + ",".join(map(str, a.choices)) + "}" in text, f"{name} {flag}"
            if a.option_strings and a.default is not None and a.default is not False:
                # SUPPRESS: a pipeline setting, whose help names the component's default
                assert "default" in p.formatter_class(name)._get_help_string(a), f"{name} {flag}"


@pytest.mark.slow
def test_without_out_the_run_folder_is_named_after_what_was_trained(tmp_path, monkeypatch,
                                                                    capsys):  # fmt: skip
    import re

    rng = np.random.default_rng(0)
    y = np.arange(24) % 2
    t = np.arange(128) / 100.0
    X = np.sin(2 * np.pi * np.where(y == 0, 3.0, 9.0)[:, None, None] * t) + 0.1 * rng.normal(
        size=(24, 2, 128))  # fmt: skip
    np.savez(tmp_path / "d.npz", X=X.astype(np.float32), y=y, fs=np.array(100.0),
             class_names=np.array(["slow", "fast"]))  # fmt: skip
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--data", "d.npz", "--epochs", "2", "--quiet", "--no-export"]) == 0
    chosen = re.search(r"encoder chosen on held-out training recordings: (\w+)",
                       capsys.readouterr().out).group(1)  # fmt: skip
    (run,) = (tmp_path / "runs").iterdir()
    assert run.name.startswith(f"d-{chosen}-readout-")
    assert main(["train", "--epochs", "1", "--quiet", "--no-export", "--task-kw", "n_planar=4",
                 "--task-kw", "n_concave=2", "--task-kw", "n_convex=2", "--task-kw",
                 "n_test=2"]) == 0  # fmt: skip
    assert any(p.name.startswith("hook_loop-gwt-tempotron-") for p in (tmp_path / "runs").iterdir())


def test_tasks_lists_every_registered_task(capsys):
    from tactilesnn.datasets_synth import TASKS

    assert main(["tasks"]) == 0
    out = capsys.readouterr().out
    for name in TASKS:
        assert f"\n{name}: " in f"\n{out}"
    assert "3 classes (a, b, c); 12 channels at 93.3 Hz" in out


def test_a_mistyped_flag_or_choice_gets_a_suggestion(capsys):
    import pytest

    from tactilesnn.cli import main

    with pytest.raises(SystemExit):
        main(["train", "--epcohs", "5"])
    assert "--epcohs: did you mean --epochs?" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "--encoder", "cgtw"])
    assert "did you mean cgwt?" in capsys.readouterr().err


def test_the_parser_is_built_without_torch():
    """The settings schema (:mod:`tactilesnn.schema`) declares every flag without torch: the
    whole parser but the benchmarks' own flags is built with torch, scipy and the components'
    modules unimported."""
    code = ("import sys; from tactilesnn.cli import build_parser; p = build_parser(bench=False); "
            "print(sorted(m for m in ('torch', 'scipy', 'tactilesnn.encoders.base', "
            "'tactilesnn.datasets_synth') if m in sys.modules), len(p.commands))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["[]", "12"], out.stdout


@pytest.mark.parametrize(
    "argv,match",
    [
        (["train", "--epcohs", "5"], "did you mean --epochs?"),
        (["train", "--encoder", "stfy"], "did you mean stft?"),
        (["trian"], "did you mean train?"),
        (["train", "--data", "/no/such/file.npz"], "--data /no/such/file.npz: no such file"),
        (["evaluate", "run", "--fs"], "argument --fs: expected one argument"),
    ],
)
def test_mistakes_are_answered_before_torch_is_imported(argv, match):
    """The parser itself answers, from the torch-free schema (no mirror of its flags)."""
    import subprocess
    import sys

    code = ("import sys\nfrom tactilesnn.cli import main\ntry:\n    rc = main(sys.argv[1:])\n"
            "except SystemExit as e:\n    rc = e.code\nprint('torch' in sys.modules, rc)")  # fmt: skip
    r = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True,
                       timeout=120)  # fmt: skip
    assert r.stdout.split() == ["False", "2"], r.stdout + r.stderr
    assert match in r.stderr


def test_good_command_lines_parse():
    from tactilesnn.cli import _check_args, build_parser

    for argv in (["train", "--epochs", "3", "--encoder", "stft", "--no-export"],
                 ["train", "--ep", "3"], ["-v", "train", "--difficulty", "-0.5"],
                 ["train", "--encoder", "lif", "--lif-neurons", "4"]):  # fmt: skip
        args = _check_args(build_parser(bench=False), argv)
        assert args.command == "train"
    args = _check_args(build_parser(), ["bench", "fit", "--quiet"])
    assert (args.command, args.name, args.quiet) == ("bench", "fit", True)


def test_the_command_line_loads_onnx_only_to_export() -> None:
    """Building the parser (``--help``, every command's start) leaves onnx unimported: ~1.4 s
    that ``evaluate``, ``generate`` or ``calibrate`` do not need (the export imports it)."""
    code = (
        "import sys; from tactilesnn.cli import build_parser; build_parser(); "
        "from tactilesnn.app import commands; print('onnx' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"

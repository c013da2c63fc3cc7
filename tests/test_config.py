"""Nested typed configuration, registries, and capability checks before any work."""

import json
from dataclasses import dataclass

import pytest

from tactilesnn.cli import main
from tactilesnn.config import PipelineConfig, TrainConfig
from tactilesnn.core.registry import Registry
from tactilesnn.datasets_synth import TASKS, register_task
from tactilesnn.encoders import ENCODERS, GWTConfig, LIFPopulationConfig
from tactilesnn.models import MODELS, SNNConfig, TempotronConfig


def test_round_trip_and_type_tags():
    cfg = PipelineConfig(
        channels=("all",), encoder=LIFPopulationConfig(neurons=3), model=SNNConfig(hidden=7),
        train=TrainConfig(epochs=2),
    )  # fmt: skip
    d = json.loads(json.dumps(cfg.to_dict()))
    assert d["encoder"]["type"] == "lif" and d["model"]["type"] == "snn"
    assert PipelineConfig.from_dict(d) == cfg
    assert cfg.encoder_type == "lif" and cfg.model_type == "snn"


def test_flat_form_and_its_errors():
    cfg = PipelineConfig.from_flat(encoder="stft", n_bands=12, stft_frame_samples=50, epochs=3)
    assert cfg.encoder.n_bands == 12 and cfg.encoder.frame_samples == 50 and cfg.train.epochs == 3
    with pytest.raises(ValueError, match="setting of encoder lif"):
        PipelineConfig.from_flat(encoder="gwt", lif_neurons=4)
    with pytest.raises(ValueError, match="unknown pipeline setting 'bands'"):
        PipelineConfig.from_flat(bands=4)
    with pytest.raises(ValueError, match="unknown encoder 'wavelet'"):
        PipelineConfig.from_flat(encoder="wavelet")
    # the old SNN learning rate no longer drives the gradient tempotron
    t = PipelineConfig.from_flat(tempotron_train="gradient", tempotron_adam_lr=0.01)
    assert t.model.adam_lr == 0.01


@pytest.mark.parametrize(
    "bad",
    [
        {"epochs": 1.7},
        {"epochs": 0},
        {"lr": float("nan")},
        {"lr": -1.0},
        {"f_lo_hz": 80.0, "f_hi_hz": 5.0},
        {"encoder": "lif", "lif_neurons": 0},
        {"n_bands": 100000},
    ],
)
def test_bad_values_are_refused(bad):
    with pytest.raises(ValueError):
        PipelineConfig.from_flat(**bad)


@pytest.mark.slow
def test_toml_sections_and_flag_precedence(tmp_path):
    toml = tmp_path / "exp.toml"
    toml.write_text(
        'channels = ["dynamic"]\n[encoder]\ntype = "lif"\nneurons = 3\n'
        '[model]\ntype = "snn"\nhidden = 8\n[train]\nepochs = 2\n'
    )
    out = tmp_path / "r"
    assert main(["train", "--config", str(toml), "--lif-tau-ms", "5", "--epochs", "1",
                 "--out", str(out), "--quiet", "--no-export"]) == 0  # fmt: skip
    cfg = json.loads((out / "config.json").read_text())["pipeline"]
    assert cfg["encoder"] == {"type": "lif", "neurons": 3, "lo": 0.25, "hi": 4.0, "tau_ms": 5.0,
                              "max_spikes": 8, "norm": "train", "keep": "spread"}  # fmt: skip
    assert cfg["model"]["hidden"] == 8 and cfg["train"]["epochs"] == 1


def test_cli_refuses_settings_of_an_unselected_component(tmp_path, capsys):
    rc = main(["train", "--encoder", "gwt", "--lif-neurons", "4", "--out", str(tmp_path / "x")])
    assert rc == 2
    assert "'lif_neurons' is a setting of encoder lif, but the encoder is 'gwt'" in (
        capsys.readouterr().err
    )
    assert not (tmp_path / "x").exists()
    bad = tmp_path / "bad.toml"
    bad.write_text('[encoder]\ntype = "gwt"\nneurons = 3\n')
    assert main(["train", "--config", str(bad), "--out", str(tmp_path / "y")]) == 2
    assert "has no setting(s) ['neurons']" in capsys.readouterr().err


def test_registries_refuse_duplicates_and_name_choices():
    reg = Registry("widget")

    @dataclass(frozen=True)
    class Cfg:
        a: int = 1

    reg.register("w", Cfg)(type("W", (), {}))
    with pytest.raises(ValueError, match="already registered"):
        reg.register("w")(type("W2", (), {}))
    with pytest.raises(ValueError, match="choose one of: w"):
        reg.get("v")
    assert set(ENCODERS.names()) >= {"gwt", "stft", "lif"}
    assert set(MODELS.names()) >= {"tempotron", "snn"}
    assert isinstance(PipelineConfig().encoder, GWTConfig)
    assert isinstance(PipelineConfig().model, TempotronConfig)


def test_task_registry_checks_unique_names_and_ids():
    ids = [c.task_id for _, c in TASKS.items()]
    assert len(set(ids)) == len(ids)

    @dataclass(frozen=True)
    class Dup:
        name = "hook_loop"
        task_id = 99

    with pytest.raises(ValueError, match="already registered"):
        register_task(Dup)

    @dataclass(frozen=True)
    class SameId:
        name = "new_task"
        task_id = TASKS["texture"].task_id

    with pytest.raises(ValueError, match="already used by 'texture'"):
        register_task(SameId)
    assert "new_task" not in TASKS


def test_flat_toml_keys_outside_train_are_checked_too(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("epochz = 3\n[train]\nepochs = 1\n")
    assert main(["train", "--config", str(bad), "--out", str(tmp_path / "x")]) == 2
    assert "unknown setting 'epochz'" in capsys.readouterr().err


def test_tempotron_settings_have_prefixed_names_and_the_old_ones_as_aliases():
    from tactilesnn.config import flat_settings

    new = PipelineConfig.from_flat(model="tempotron", tempotron_lr=0.01, tempotron_tau_ms=120.0)
    old = PipelineConfig.from_flat(model="tempotron", lr=0.01, tau_ms=120.0)
    assert new == old and new.model.lr == 0.01 and new.model.tau_ms == 120.0
    assert flat_settings()["lr"].help == "alias of --tempotron-lr"
    assert "alias" not in flat_settings()["tempotron_lr"].help


def test_a_wide_task_defaults_to_the_linear_cost_model_unless_a_model_is_named():
    from tactilesnn.app.defaults import run_spec
    from tactilesnn.config import DEFAULT_MODEL, WIDE_INPUT_MODEL

    # 100 chip channels x the GWT's bands: thousands of events, the tempotron's cost squared
    wide = run_spec({"task": "localise"}, None)
    assert wide.config.model_type == WIDE_INPUT_MODEL and wide.config.level_neurons > 0
    assert wide.select_encoders  # and the encoder is chosen, as for a data file
    assert not run_spec({"task": "localise", "encoder": "lif"}, None).select_encoders
    assert (
        run_spec({"task": "localise", "model": "tempotron"}, None).config.model_type == "tempotron"
    )
    named = run_spec({"task": "localise", "tempotron_lr": 0.01}, None).config
    assert named.model_type == "tempotron" and named.model.lr == 0.01
    # 12 taxels stay under the bound: the default model as documented
    narrow = run_spec({"task": "braille"}, None)
    assert narrow.config.model_type == DEFAULT_MODEL and not narrow.select_encoders
    assert run_spec({"task": "hook_loop"}, None).config.model_type == DEFAULT_MODEL

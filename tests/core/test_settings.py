"""The settings schema: every component setting is one field carrying its flag, help and
choices; the CLI's flat names are derived from it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import pytest

from tactilesnn.config import PipelineConfig, TrainConfig, flat_settings, place_flat
from tactilesnn.core.settings import (
    KEY,
    ComponentSettings,
    choices_of,
    flag_fields,
    help_texts,
    legacy_values,
    saved_before,
    setting,
    while_selecting,
)
from tactilesnn.encoders import ENCODERS
from tactilesnn.models import MODELS


def _configs():
    for reg in (ENCODERS, MODELS):
        for name in reg.names():
            yield name, reg.config_class(name)


@pytest.mark.parametrize("name,cls", list(_configs()))
def test_every_component_field_is_declared_in_the_schema(name, cls):
    assert issubclass(cls, ComponentSettings), name
    for f in dataclasses.fields(cls):
        assert KEY in f.metadata, f"{name}.{f.name} is a field without setting(...)"
        assert f.metadata[KEY].help, f"{name}.{f.name} has no help text"


def test_pipeline_and_train_fields_are_declared_too():
    for cls in (PipelineConfig, TrainConfig):
        for f in dataclasses.fields(cls):
            if f.name not in ("encoder", "model", "train"):
                assert KEY in f.metadata, f"{cls.__name__}.{f.name}"


def test_a_setting_is_one_field():
    @dataclass(frozen=True)
    class Toy(ComponentSettings):
        width_mm: float = setting(2.0, flag="toy_width_mm", aliases=("width",),
                                  help="contact width (mm)")  # fmt: skip
        shape: str = setting("disc", choices=("disc", "bar"), help="contact shape")
        hidden: int = setting(3, flat=False, saved_before=1, help="set in TOML only")
        fast: bool = setting(True, while_selecting=False, legacy=False, help="fast path")

    assert flag_fields(Toy) == {"toy_width_mm": "width_mm", "width": "width_mm",
                                "shape": "shape", "fast": "fast"}  # fmt: skip
    assert help_texts(Toy)["width_mm"] == "contact width (mm)" and "hidden" not in help_texts(Toy)
    assert choices_of(Toy) == {"shape": ("disc", "bar")}
    assert saved_before(Toy) == {"hidden": 1}
    assert legacy_values(Toy) == {"fast": False}
    assert while_selecting(Toy) == {"fast": False}
    assert Toy().width_mm == 2.0 and Toy.data_defaults(100.0, 50) == {}


def test_a_flat_name_declared_twice_is_refused():
    @dataclass(frozen=True)
    class Twice(ComponentSettings):
        a: int = setting(1, flag="x", help="a")
        b: int = setting(2, flag="x", help="b")

    with pytest.raises(ValueError, match="declared twice"):
        flag_fields(Twice)


def test_a_setting_without_a_default_is_required():
    @dataclass(frozen=True)
    class Needs(ComponentSettings):
        rate_hz: float = setting(help="sampling rate (Hz)")

    with pytest.raises(TypeError):
        Needs()
    assert Needs(rate_hz=100.0).rate_hz == 100.0


def test_a_mutable_default_is_refused():
    with pytest.raises(TypeError, match="default_factory"):
        setting([1], help="a list")


def test_the_flat_names_come_from_the_fields():
    flat = flat_settings()
    assert flat["csnn_tau_ms"].default == 50.0 and flat["csnn_tau_ms"].part == "model"
    assert flat["lr_schedule"].choices == ("constant", "cosine")
    assert flat["tau_ms"].help == "alias of --tempotron-tau-ms"  # an earlier version's name
    assert set(flat["n_bands"].components) >= {"gwt", "stft", "cgwt", "bands"}
    parts = place_flat({"csnn_tau_ms": 20.0, "epochs": 3, "channels": ["a"]}, "events", "csnn")
    assert parts["model"] == {"tau_ms": 20.0} and parts["train"] == {"epochs": 3}
    assert parts["top"] == {"channels": ("a",)}

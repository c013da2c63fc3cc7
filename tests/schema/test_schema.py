"""The torch-free settings schema declares exactly the components the package registers."""

import subprocess
import sys

import pytest

from tactilesnn.core.registry import Registry
from tactilesnn.encoders import ENCODERS
from tactilesnn.encoders.band_code import TRANSFORMS, envelope_codes
from tactilesnn.models import MODELS
from tactilesnn.schema.encoders import ENVELOPE_CODES, TRANSFORM_NAMES
from tactilesnn.schema.tasks import TASKS


def test_the_schema_imports_without_torch():
    code = ("import sys; import tactilesnn.schema.encoders, tactilesnn.schema.models, "
            "tactilesnn.schema.tasks, tactilesnn.config, tactilesnn.app.options; "
            "print([m for m in ('torch', 'scipy') if m in sys.modules])")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("registry", [ENCODERS, MODELS, TASKS], ids=lambda r: r.kind)
def test_every_declared_name_registers_its_class(registry):
    for name in registry.names():
        cls = registry.get(name)
        assert cls.registry_name == name
        if registry is not TASKS:
            assert registry.name_of_config(registry.config_class(name)()) == name


def test_the_band_code_choices_are_the_registries():
    assert TRANSFORM_NAMES == TRANSFORMS.names()
    assert ENVELOPE_CODES == envelope_codes()


def test_a_declared_module_that_registers_nothing_is_named():
    reg = Registry("thing")
    reg.declare("x", None, "tactilesnn.core.checks")
    assert "x" in reg and reg.names() == ("x",)
    with pytest.raises(ValueError, match="registered no class"):
        reg.get("x")


def test_a_declaration_and_a_registration_must_agree():
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class A:
        pass

    @dataclass(frozen=True)
    class B:
        pass

    reg = Registry("thing")
    reg.declare("x", A, "tactilesnn.core.checks")
    assert reg.config_class("x") is A
    with pytest.raises(ValueError, match="another config"):
        reg.register("x", B)(type("X", (), {}))
    reg.register("x", A)(type("X", (), {}))
    assert reg.get("x").registry_name == "x"

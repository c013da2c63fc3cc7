"""One settings schema: a setting is one dataclass field whose metadata says how users set it.

A component's configuration is a frozen dataclass; each user-facing field is declared with
:func:`setting`, which stores its flat name (the command-line flag without ``--``, the key of the
flat ``--config`` form and of sweeps), help text, choices, aliases and the values old saves imply::

    @dataclass(frozen=True)
    class ConvSNNConfig(ComponentSettings):
        tau_ms: float = setting(50.0, flag="csnn_tau_ms", help="membrane time constant (ms)")

The CLI, settings files, sweeps and docs/cli.md read the schema through :func:`flag_fields`,
:func:`help_texts`, :func:`choices_of` (nothing else lists a component's flags). Optional
behaviour of a configuration is a typed member of :class:`ComponentSettings` (defaults that do
nothing), never found by probing attributes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any, ClassVar

#: the metadata key of a field declared with :func:`setting`
KEY = "tactilesnn.setting"
_UNSET: Any = object()


@dataclass(frozen=True)
class SettingInfo:
    """How users set one field. ``flag``: its flat name (default: the field's name);
    ``aliases``: further flat names; ``choices``: the values it accepts (per element for a
    tuple-valued field); ``saved_before``: the value a run saved before the field existed had;
    ``flat=False``: no flat name (set in the nested settings form only);
    ``legacy``: its value in the flat run folders of the first versions (when it differs from
    today's default); ``while_selecting``: its value while ``train --data`` compares encoders."""

    help: str
    flag: str | None = None
    flat: bool = True
    aliases: tuple[str, ...] = ()
    choices: tuple[Any, ...] | None = None
    saved_before: Any = _UNSET
    legacy: Any = _UNSET
    while_selecting: Any = _UNSET


def setting(
    default: Any = _UNSET,
    *,
    help: str,
    flag: str | None = None,
    flat: bool = True,
    aliases: Sequence[str] = (),
    choices: Sequence[Any] | None = None,
    saved_before: Any = _UNSET,
    legacy: Any = _UNSET,
    while_selecting: Any = _UNSET,
    default_factory: Any = _UNSET,
) -> Any:
    """A dataclass field users can set (see :class:`SettingInfo` for the keywords)."""
    info = SettingInfo(help=help, flag=flag, flat=flat, aliases=tuple(aliases),
                       choices=None if choices is None else tuple(choices),
                       saved_before=saved_before, legacy=legacy,
                       while_selecting=while_selecting)  # fmt: skip
    meta = {KEY: info}
    if default_factory is not _UNSET:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    if default is _UNSET:  # a setting without a default: required
        return dataclasses.field(metadata=meta)
    if isinstance(default, (list, dict, set)):
        raise TypeError("a mutable default needs default_factory")
    return dataclasses.field(default=default, metadata=meta)


def infos(cls: type) -> dict[str, SettingInfo]:
    """Field name -> :class:`SettingInfo` of every field declared with :func:`setting`."""
    return {f.name: f.metadata[KEY] for f in dataclasses.fields(cls) if KEY in f.metadata}


@cache
def flag_fields(cls: type) -> dict[str, str]:
    """Flat name -> field name: each field's flag first, then its aliases (in field order)."""
    out: dict[str, str] = {}
    for name, info in infos(cls).items():
        if not info.flat:
            continue
        for flag in (info.flag or name, *info.aliases):
            if flag in out:
                raise ValueError(f"{cls.__name__}: flat name {flag!r} is declared twice")
            out[flag] = name
    return out


def help_texts(cls: type) -> dict[str, str]:
    """Field name -> help text (of the fields with a flat name)."""
    return {name: info.help for name, info in infos(cls).items() if info.flat}


def choices_of(cls: type) -> dict[str, tuple[Any, ...]]:
    """Field name -> its choices, for the fields that have them."""
    return {n: i.choices for n, i in infos(cls).items() if i.choices is not None}


def _marked(cls: type, attr: str) -> dict[str, Any]:
    return {n: getattr(i, attr) for n, i in infos(cls).items() if getattr(i, attr) is not _UNSET}


def saved_before(cls: type) -> dict[str, Any]:
    """Field -> the value a run saved before the field existed had (for fields added later)."""
    return _marked(cls, "saved_before")


def legacy_values(cls: type) -> dict[str, Any]:
    """Field -> its value in run folders of the flat (first) settings form."""
    return _marked(cls, "legacy")


def while_selecting(cls: type) -> dict[str, Any]:
    """Field -> its value while ``train --data`` compares encoders (a cheaper fit)."""
    return _marked(cls, "while_selecting")


class ComponentSettings:
    """Base of every registered component's configuration (encoders, models): the optional
    behaviour a configuration may declare, with defaults that do nothing."""

    #: :meth:`data_defaults` sets fields from a data file's facts
    follows_data: ClassVar[bool] = False

    @classmethod
    def data_defaults(
        cls, fs_hz: float, window: int, median_hz: float | None = None
    ) -> dict[str, Any]:
        """Field values that follow a data file's facts (rate in Hz, window in samples, the
        training windows' median power frequency in Hz), for ``train --data``; none by default."""
        return {}

"""Registries of components (encoders, models, sensors, tasks, benchmarks): a name, a class
and its config class.

A registry maps a name to ``(component class, config class)``. Configurations are frozen
dataclasses; the registry gives each its ``type`` tag, so a configuration alone says which
component it builds, and code outside the registries never branches on component names. A name
may be *declared* before its class is imported (:meth:`Registry.declare`: its config class and
the module that registers the class, imported when the class is first asked for), so the settings
schema and the command line need neither torch nor the components' modules; an entry may also be
a module itself (:meth:`Registry.register_module`: the benchmarks).
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Iterator
from typing import Any


class Registry:
    """Named components of one kind (``"encoder"``, ``"model"``, ...)."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._entries: dict[str, tuple[Any, type | None]] = {}
        self._modules: dict[str, str] = {}  # name -> module path, imported on first get()
        self._declared: dict[str, type | None] = {}  # name -> config class, class not imported

    def register(self, name: str, config: type | None = None) -> Callable[[type], type]:
        """Class decorator registering the class under ``name``; names must be unique."""

        def deco(cls: type) -> type:
            if name in self._entries:
                raise ValueError(f"{self.kind} {name!r} is already registered")
            if name in self._declared and self._declared[name] is not config:
                raise ValueError(f"{self.kind} {name!r} was declared with another config class")
            if config is not None:
                if not dataclasses.is_dataclass(config):
                    raise TypeError(f"{self.kind} {name!r}: config must be a dataclass")
                if any(c is config for _, c in self._entries.values()):
                    raise ValueError(f"{config.__name__} already configures another {self.kind}")
            self._entries[name] = (cls, config)
            cls.registry_name = name
            return cls

        return deco

    def declare(self, name: str, config: type | None, module: str) -> None:
        """Declare ``name`` with its config class; ``module`` registers the component class
        (with :meth:`register`) and is imported when the class is first asked for."""
        if name in self:
            raise ValueError(f"{self.kind} {name!r} is already registered")
        if config is not None and any(c is config for c in self._declared.values()):
            raise ValueError(f"{config.__name__} already configures another {self.kind}")
        self._declared[name] = config
        self._modules[name] = module

    def register_module(self, name: str, path: str) -> None:
        """Register the module at ``path`` as ``name``, imported when :meth:`get` first asks."""
        if name in self:
            raise ValueError(f"{self.kind} {name!r} is already registered")
        self._modules[name] = path

    def __contains__(self, name: object) -> bool:
        return name in self._entries or name in self._modules

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self.names())

    def names(self) -> tuple[str, ...]:
        return tuple(sorted({*self._entries, *self._modules}))

    def registered(self, name: str) -> bool:
        """True if ``name``'s class (or module) is registered, not only declared."""
        return name in self._entries

    def registered_items(self) -> list[tuple[str, Any]]:
        """``(name, class)`` of the classes registered so far (nothing imported)."""
        return [(n, c) for n, (c, _) in self._entries.items()]

    def items(self) -> Iterator[tuple[str, Any]]:
        """``(name, class or module)`` in name order (modules imported)."""
        return ((n, self.get(n)) for n in self.names())

    def get(self, name: str) -> Any:
        """The component class (or module) registered as ``name`` (ValueError listing the
        choices)."""
        if name not in self:
            raise ValueError(
                f"unknown {self.kind} {name!r}; choose one of: {', '.join(self.names())}"
            )
        if name not in self._entries:
            module = importlib.import_module(self._modules[name])
            if name in self._declared:  # the module registers the class
                if name not in self._entries:
                    raise ValueError(f"{self.kind} {name!r}: {module.__name__} registered no "
                                     "class under that name")  # fmt: skip
            else:
                self._entries[name] = (module, None)
        return self._entries[name][0]

    __getitem__ = get

    def config_class(self, name: str) -> type:
        """The config class of ``name`` (a declared name's without importing its module)."""
        if name in self._declared and name not in self._entries:
            cfg = self._declared[name]
        else:
            self.get(name)
            cfg = self._entries[name][1]
        if cfg is None:
            raise ValueError(f"{self.kind} {name!r} has no configuration class")
        return cfg

    def name_of_config(self, config: object) -> str:
        """The registered name whose config class ``config`` is an instance of."""
        for name, cfg in self._configs():
            if cfg is not None and type(config) is cfg:
                return name
        raise TypeError(
            f"{type(config).__name__} is not the configuration of a registered {self.kind}"
        )

    def component_for(self, config: object) -> type:
        return self.get(self.name_of_config(config))

    def _configs(self) -> Iterator[tuple[str, type | None]]:
        yield from self._declared.items()
        yield from ((n, c) for n, (_, c) in self._entries.items() if n not in self._declared)

    def config_from_dict(self, d: dict[str, Any]) -> Any:
        """``{"type": name, **fields}`` -> the config instance (unknown fields refused)."""
        if "type" not in d:
            raise ValueError(f"{self.kind} settings need a 'type' ({', '.join(self.names())})")
        name = d["type"]
        cls = self.config_class(name)
        known = {f.name for f in dataclasses.fields(cls)}
        values = {k: v for k, v in d.items() if k != "type"}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(
                f"{self.kind} {name!r} has no setting(s) {unknown}; its settings: {sorted(known)}"
            )
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})

    def config_to_dict(self, config: object) -> dict[str, Any]:
        return {"type": self.name_of_config(config), **dataclasses.asdict(config)}

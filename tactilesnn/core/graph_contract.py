"""The exported graph's contract: its input / output names and metadata, as one typed object.

The export writes a :class:`GraphContract` into the ONNX file's metadata
(:meth:`GraphContract.to_metadata`); the service reads it back with
:meth:`GraphContract.from_metadata`, which validates every field (types, ranges, lengths) and
refuses a tampered or foreign model with a specific error instead of serving wrong labels.

Graph I/O (every exported pipeline):

- input ``window`` float32 ``[batch, channels, window_samples]`` in the sensor's units;
- for a stateful model, one input per state name ``[batch, units]`` and an output
  ``<name>_out`` with its next value (zeros start a stream);
- output ``scores`` float32 ``[batch, classes]``;
- optional ``early_class`` int64 ``[batch]`` and ``decision_ms`` float32 ``[batch]`` (a model
  deciding before the window ends), and the intermediate value ``spikes`` (the encoder's spike
  times, ms, ``+inf`` = silent) that a live view may expose as an output.

Only numpy and the standard library: the service imports this without torch.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .gate import active_channels

WINDOW_INPUT = "window"
SCORES_OUTPUT = "scores"
SPIKES_VALUE = "spikes"
#: the class of a model's first output neuron to fire (int64) and when (ms of the window's code)
EARLY_OUTPUTS = ("early_class", "decision_ms")
STATE_OUTPUT_SUFFIX = "_out"

#: metadata keys the contract owns; anything else is carried in ``extra`` unchanged
_OWN = (
    "tactilesnn_version", "fs_hz", "window_samples", "channels", "class_names", "units",
    "encoder", "model", "state_inputs", "pipeline_config", "bytes_per_window",
    "encoder_channels", "gate_rms", "bands_hz", "bands_transformed",
)  # fmt: skip
MAX_NAME_CHARS = 200
MAX_ENTRIES = 1 << 16


class ContractError(ValueError):
    """The graph's metadata does not describe a usable tactilesnn export."""


def state_output(name: str) -> str:
    """Graph output carrying the next value of state input ``name``."""
    return name + STATE_OUTPUT_SUFFIX


@dataclass(frozen=True)
class GraphContract:
    """What a runtime needs to know about an exported pipeline (see the module docstring).

    ``gate_rms`` (input units, one per entry of ``encoder_channels``): the encoder's activity
    gate; a window's channel whose RMS about its mean is at or below it is not encoded (its
    afferents are silent). ``bands_hz`` / ``bands_transformed``: the encoder's band centres and
    the indices of those it transforms (the others are outside the sensor's passband).
    """

    fs_hz: float
    window_samples: int
    channels: tuple[str, ...]
    class_names: tuple[str, ...]
    encoder: str = ""
    model: str = ""
    state_inputs: tuple[str, ...] = ()
    bytes_per_window: int = 0
    encoder_channels: tuple[int, ...] = ()
    units: str = ""
    pipeline_config: dict = field(default_factory=dict)
    version: str = ""
    gate_rms: tuple[float, ...] | None = None
    bands_hz: tuple[float, ...] | None = None
    bands_transformed: tuple[int, ...] | None = None
    extra: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check(self)

    # ------------------------------------------------------------------ I/O names
    @property
    def plain_outputs(self) -> list[str]:
        """What plain classification asks the graph for: scores and each state's next value."""
        return [SCORES_OUTPUT, *(state_output(n) for n in self.state_inputs)]

    # ------------------------------------------------------------------ activity gate
    def silent_channels(self, window: np.ndarray) -> np.ndarray:
        """``window [channels, samples]`` -> bool ``[len(encoder_channels)]``: which encoder
        channels the activity gate silences (all False without a gate): the encoder's rule,
        :func:`~tactilesnn.core.gate.active_channels` (in float64)."""
        if self.gate_rms is None or not self.encoder_channels:
            return np.zeros(len(self.encoder_channels), bool)
        window = np.asarray(window, np.float64)[list(self.encoder_channels)]
        return ~active_channels(window, np.asarray(self.gate_rms, np.float64))

    # ------------------------------------------------------------------ metadata
    def to_metadata(self) -> dict[str, str]:
        """ONNX ``metadata_props`` (every value a string)."""
        meta = {
            "tactilesnn_version": self.version,
            "fs_hz": repr(float(self.fs_hz)),
            "window_samples": str(int(self.window_samples)),
            "channels": json.dumps(list(self.channels)),
            "class_names": json.dumps(list(self.class_names)),
            "units": self.units,
            "encoder": self.encoder,
            "model": self.model,
            "state_inputs": json.dumps(list(self.state_inputs)),
            "pipeline_config": json.dumps(self.pipeline_config),
            "bytes_per_window": str(int(self.bytes_per_window)),
            "encoder_channels": json.dumps([int(i) for i in self.encoder_channels]),
        }
        if self.gate_rms is not None:
            meta["gate_rms"] = json.dumps([float(v) for v in self.gate_rms])
        if self.bands_hz is not None:
            meta["bands_hz"] = json.dumps([round(float(f), 4) for f in self.bands_hz])
        if self.bands_transformed is not None:
            meta["bands_transformed"] = json.dumps([int(i) for i in self.bands_transformed])
        return {**{k: str(v) for k, v in self.extra.items()}, **meta}

    @classmethod
    def from_metadata(cls, meta: Mapping[str, str]) -> GraphContract:
        """Parse and validate; :class:`ContractError` names the first field that is wrong."""
        meta = dict(meta)
        missing = [
            k for k in ("fs_hz", "window_samples", "channels", "class_names") if k not in meta
        ]
        if missing:
            raise ContractError(f"not a tactilesnn export: metadata lacks {missing}")

        def js(key: str, default: Any = None) -> Any:
            if key not in meta or meta[key] in ("", "null"):
                return default
            try:
                return json.loads(meta[key])
            except (ValueError, RecursionError) as e:
                raise ContractError(f"metadata {key!r} is not valid JSON ({e})") from e

        def number(key: str, kind: type) -> Any:
            try:
                value = kind(meta[key]) if kind is float else int(meta[key], 10)
            except (TypeError, ValueError) as e:
                raise ContractError(
                    f"metadata {key!r} = {meta[key][:50]!r} is not a {kind.__name__}"
                ) from e
            return value

        def tup(value: Any, key: str) -> tuple | None:
            if value is None:
                return None
            if not isinstance(value, list):
                raise ContractError(
                    f"metadata {key!r} must be a JSON list, got {type(value).__name__}"
                )
            return tuple(value)

        config = js("pipeline_config", {})
        if not isinstance(config, dict):
            raise ContractError("metadata 'pipeline_config' must be a JSON object")
        return cls(
            fs_hz=number("fs_hz", float),
            window_samples=number("window_samples", int),
            channels=tup(js("channels"), "channels") or (),
            class_names=tup(js("class_names"), "class_names") or (),
            encoder=str(meta.get("encoder", "")),
            model=str(meta.get("model", "")),
            state_inputs=tup(js("state_inputs", []), "state_inputs") or (),
            bytes_per_window=number("bytes_per_window", int) if meta.get("bytes_per_window") else 0,
            encoder_channels=tup(js("encoder_channels", []), "encoder_channels") or (),
            units=str(meta.get("units", "")),
            pipeline_config=config,
            version=str(meta.get("tactilesnn_version", "")),
            gate_rms=tup(js("gate_rms"), "gate_rms"),
            bands_hz=tup(js("bands_hz"), "bands_hz"),
            bands_transformed=tup(js("bands_transformed"), "bands_transformed"),
            extra={k: v for k, v in meta.items() if k not in _OWN},
        )


def _names(values: Sequence, what: str, unique: bool) -> None:
    if not values:
        raise ContractError(f"{what} is empty")
    if len(values) > MAX_ENTRIES:
        raise ContractError(f"{what}: {len(values)} entries (at most {MAX_ENTRIES})")
    for v in values:
        if not isinstance(v, str) or not v or len(v) > MAX_NAME_CHARS:
            raise ContractError(
                f"{what} must be non-empty strings of at most {MAX_NAME_CHARS} characters, "
                f"got {str(v)[:60]!r}"
            )
    if unique and len(set(values)) != len(values):
        raise ContractError(f"{what} holds duplicates")


def _ints(values: Sequence, what: str, lo: int, hi: int) -> None:
    for v in values:
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v < hi:
            raise ContractError(f"{what} must be integers in [{lo}, {hi}), got {str(v)[:40]!r}")


def _check(c: GraphContract) -> None:
    if not (isinstance(c.fs_hz, int | float) and math.isfinite(c.fs_hz) and c.fs_hz > 0):
        raise ContractError(f"fs_hz must be a positive finite number, got {c.fs_hz!r}")
    if not (isinstance(c.window_samples, int) and 0 < c.window_samples <= 1 << 26):
        raise ContractError(f"window_samples must be a positive integer, got {c.window_samples!r}")
    _names(c.channels, "channels", unique=True)
    _names(c.class_names, "class_names", unique=True)
    if len(c.class_names) < 2:
        raise ContractError("class_names must name at least two classes")
    if c.state_inputs:
        _names(c.state_inputs, "state_inputs", unique=True)
        if WINDOW_INPUT in c.state_inputs:
            raise ContractError(f"state_inputs must not name the {WINDOW_INPUT!r} input")
    if not (isinstance(c.bytes_per_window, int) and c.bytes_per_window >= 0):
        raise ContractError("bytes_per_window must be an integer >= 0")
    _ints(c.encoder_channels, "encoder_channels", 0, len(c.channels))
    if c.gate_rms is not None:
        ok = all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                 and v >= 0 for v in c.gate_rms)  # fmt: skip
        if not ok or len(c.gate_rms) != len(c.encoder_channels):
            raise ContractError(
                "gate_rms must hold one finite threshold >= 0 per encoder channel "
                f"({len(c.encoder_channels)}), got {str(c.gate_rms)[:80]}"
            )
    if c.bands_hz is not None:
        if not all(isinstance(v, int | float) and math.isfinite(v) and v > 0 for v in c.bands_hz):
            raise ContractError("bands_hz must hold positive finite frequencies")
        if c.bands_transformed is not None:
            _ints(c.bands_transformed, "bands_transformed", 0, len(c.bands_hz))

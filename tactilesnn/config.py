"""Typed, nested pipeline settings: ``PipelineConfig(channels, encoder, model, train)``.

``encoder`` and ``model`` are the configuration dataclasses of registered components; their
``type`` tag (the registry name) is written next to their fields, so a saved configuration says
which components it builds. TOML form::

    channels = ["dynamic"]
    clock_afferents = 5

    [encoder]
    type = "lif"
    neurons = 8

    [model]
    type = "snn"
    hidden = 64

    [train]
    epochs = 40

The flat form of earlier versions (``encoder = "lif"``, ``lif_neurons = 8``, ``snn_hidden = 64``,
``epochs = 40`` in one table; also the command-line flag names) is still read: each component's
config field declares its flat name (:func:`~tactilesnn.core.settings.setting`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from .core.checks import check_choice, check_device_name, check_int
from .core.registry import Registry
from .core.settings import choices_of, flag_fields, help_texts, legacy_values, setting
from .schema.encoders import ENCODERS, LEVEL_SCALES
from .schema.models import MODELS

DEFAULT_ENCODER = "gwt"
#: a time reference needs a few afferents; thousands are a typo (and gigabytes of spike times)
MAX_CLOCK_AFFERENTS = 1024
DEFAULT_MODEL = "tempotron"
#: the default model's exact maximum holds [events, events] lags per window: above this many
#: input events a task's default run takes the linear-cost model instead (a 100-channel task gave
#: the tempotron 4,005; at 2,005 one window costs 87 ms per pass: hours for 40 epochs)
DEFAULT_MODEL_MAX_AFFERENTS = 512
WIDE_INPUT_MODEL = "readout"


#: how Adam's learning rate runs over the epochs (:class:`TrainConfig`)
LR_SCHEDULES = ("constant", "cosine")


@dataclass(frozen=True)
class TrainConfig:
    """The training loop: epochs, mini-batches, early stopping, seed."""

    epochs: int = setting(40, help="training epochs (upper bound with early stopping)")
    batch_size: int = setting(32, help="mini-batch size")
    patience: int = setting(
        0, help="early stopping: epochs without validation improvement (needs --val-fraction)"
    )
    keep_best: bool = setting(
        True, help="keep the weights with the best validation (else training) accuracy"
    )
    seed: int = setting(0, help="dataset split, generation and initialisation seed")
    device: str = setting(
        "auto",
        help="where encoding and the model's gradient training run: auto (a CUDA GPU when torch "
        "sees one, else the CPU), cpu, cuda or cuda:N; rule learning, the readout's exact solve "
        "and inference stay on the CPU",
    )
    lr_schedule: str = setting(
        "constant",
        choices=LR_SCHEDULES,
        help="the gradient models' learning rate over the epochs: constant, or cosine (from the "
        "model's rate down to 0 at the last epoch's last step)",
    )

    def __post_init__(self) -> None:
        check_int(self.epochs, "epochs", 1)
        check_int(self.batch_size, "batch_size", 1)
        check_int(self.patience, "patience", 0)
        check_int(self.seed, "seed", 0)
        if not isinstance(self.keep_best, bool):
            raise ValueError(f"keep_best must be true or false, got {self.keep_best!r}")
        check_device_name(self.device)
        check_choice(self.lr_schedule, "lr_schedule", LR_SCHEDULES)


#: level-code neurons per statistic: more only splits the same rank finer
MAX_LEVEL_NEURONS = 64


@dataclass(frozen=True)
class PipelineConfig:
    """Everything that defines a trained pipeline except its weights (saved in the run folder)."""

    # seed 001 encodes the dynamic (piezo) output; ("all",) = every channel of the data
    channels: tuple[str, ...] = setting(
        ("dynamic",),
        help="input channels by name ('all' = every channel of the data, in its order)",
    )
    clock_afferents: int = setting(
        5, help="afferents firing at fixed times in every window (a time reference)"
    )
    level_neurons: int = setting(
        0,
        help="neurons per channel statistic of the calibrated level code appended to the "
        "encoder's spikes (window mean and log sd ranked on the training windows: an ON/OFF "
        "latency pair, then Gaussian fields; 0 = off)",
    )
    #: runs saved before the setting existed read as "rank" (the default)
    level_scale: str = setting(
        "rank",
        choices=LEVEL_SCALES,
        help="what the level code's ON/OFF pair codes: 'rank' (the value's rank among the "
        "training windows), 'linear' (its position in the training range), 'rank+linear' (a "
        "pair of each; the model weighs them) or 'wide' (its position in the training range "
        "widened by its span each side: levels beyond the training ones still code)",
    )
    level_share: bool = setting(
        False,
        help="add a third level statistic: the channel's share of the window's total level "
        "across channels (a scale-free spatial pattern: where a press is, whatever its force)",
    )
    gain_norm: bool = setting(
        False,
        help="divide each window by its mean absolute level over the pipeline's channels before "
        "coding (a harder press scales every channel alike: the code sees the pattern, not the "
        "force); window graphs only",
    )
    rest_ms: float = setting(
        0.0,
        help="rest reference: each channel less its mean over the window's first rest_ms ms (a "
        "re-mounted sensor's or a new session's offset drops out; before gain_norm); 0 = off; "
        "window graphs only",
    )
    encoder: Any = field(default_factory=lambda: ENCODERS.config_class(DEFAULT_ENCODER)())
    model: Any = field(default_factory=lambda: MODELS.config_class(DEFAULT_MODEL)())
    train: TrainConfig = field(default_factory=TrainConfig)

    def __post_init__(self) -> None:
        object.__setattr__(self, "channels", tuple(str(c) for c in self.channels))
        if not self.channels:
            raise ValueError("channels must name at least one channel (or 'all')")
        check_int(self.clock_afferents, "clock_afferents", 0)
        if self.clock_afferents > MAX_CLOCK_AFFERENTS:
            raise ValueError(f"clock_afferents must be at most {MAX_CLOCK_AFFERENTS}, got "
                             f"{self.clock_afferents}")  # fmt: skip
        check_int(self.level_neurons, "level_neurons", 0)
        if self.level_neurons == 1 or self.level_neurons > MAX_LEVEL_NEURONS:
            raise ValueError(f"level_neurons must be 0 (off) or 2..{MAX_LEVEL_NEURONS}, got "
                             f"{self.level_neurons}")  # fmt: skip
        if self.level_scale not in LEVEL_SCALES:
            raise ValueError(f"level_scale must be one of {', '.join(LEVEL_SCALES)}, got "
                             f"{self.level_scale!r}")  # fmt: skip
        if not isinstance(self.level_share, bool):
            raise TypeError(f"level_share must be true or false, got {self.level_share!r}")
        if not isinstance(self.gain_norm, bool):
            raise TypeError(f"gain_norm must be true or false, got {self.gain_norm!r}")
        if not (isinstance(self.rest_ms, int | float) and 0 <= self.rest_ms < math.inf):
            raise ValueError(f"rest_ms must be a finite number of ms >= 0, got {self.rest_ms!r}")
        ENCODERS.name_of_config(self.encoder)  # TypeError if not a registered encoder's config
        MODELS.name_of_config(self.model)
        if not isinstance(self.train, TrainConfig):
            raise TypeError(f"train must be a TrainConfig, got {type(self.train).__name__}")

    @property
    def encoder_type(self) -> str:
        return ENCODERS.name_of_config(self.encoder)

    @property
    def model_type(self) -> str:
        return MODELS.name_of_config(self.model)

    @property
    def seed(self) -> int:
        return self.train.seed

    def replace(self, **changes: Any) -> PipelineConfig:
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ dict / TOML forms
    def to_dict(self) -> dict[str, Any]:
        """Nested, JSON-ready: components carry their ``type`` tag."""
        return {
            **_plain({k: getattr(self, k) for k in TOP_FLAGS}),
            "encoder": _plain(ENCODERS.config_to_dict(self.encoder)),
            "model": _plain(MODELS.config_to_dict(self.model)),
            "train": dataclasses.asdict(self.train),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PipelineConfig:
        """Nested form (as written by :meth:`to_dict`) or the flat form of earlier versions."""
        if not is_nested(d):  # a run folder written before the component layer
            cfg = cls.from_flat(d, strict=False)
            legacy = legacy_values(type(cfg.model))
            return cfg.replace(model=dataclasses.replace(cfg.model, **legacy)) if legacy else cfg
        unknown = sorted(set(d) - {*TOP_FLAGS, "encoder", "model", "train"})
        if unknown:
            raise ValueError(f"unknown pipeline settings: {', '.join(unknown)}")
        train = d.get("train", {})
        tknown = {f.name for f in dataclasses.fields(TrainConfig)}
        if set(train) - tknown:
            raise ValueError(f"[train] has no setting(s) {sorted(set(train) - tknown)}")
        kw: dict[str, Any] = {"train": TrainConfig(**train)}
        for key in TOP_FLAGS:
            if key in d:
                kw[key] = d[key]
        kw["encoder"] = ENCODERS.config_from_dict(d.get("encoder", {"type": DEFAULT_ENCODER}))
        kw["model"] = MODELS.config_from_dict(d.get("model", {"type": DEFAULT_MODEL}))
        return cls(**kw)

    @classmethod
    def from_flat(cls, d: dict[str, Any] | None = None, strict: bool = True, **kw: Any):
        """Build from flat settings (``encoder="lif", lif_neurons=4, snn_hidden=16, epochs=2``).

        ``strict``: a setting of a component that is not selected (``lif_neurons`` with the GWT
        encoder) is an error; otherwise it is ignored (old run folders saved every field).
        """
        flat = {**(d or {}), **kw}
        enc_name = flat.pop("encoder", DEFAULT_ENCODER)
        model_name = flat.pop("model", DEFAULT_MODEL)
        parts = place_flat(flat, enc_name, model_name, strict)
        return cls(
            encoder=ENCODERS.config_class(enc_name)(**parts["encoder"]),
            model=MODELS.config_class(model_name)(**parts["model"]),
            train=TrainConfig(**parts["train"]),
            **parts["top"],
        )


#: flat names of the pipeline's own fields (-> field)
TOP_FLAGS: dict[str, str] = flag_fields(PipelineConfig)


def encoder_settings_given(keys: set[str]) -> bool:
    """True if ``keys`` (flat setting names or TOML sections given by the user) choose an
    encoder or set one of an encoder's settings."""
    owners = flat_settings()
    return "encoder" in keys or any(owners[k].part == "encoder" for k in keys if k in owners)


def place_flat(
    flat: dict[str, Any], encoder: str, model: str, strict: bool = True
) -> dict[str, dict[str, Any]]:
    """Sort flat settings into field values per part (``top``, ``train``, ``encoder``,
    ``model``) for the named components.

    ``strict``: a setting of a component that is not selected is an error; otherwise ignored.
    """
    enc_flags = flag_fields(ENCODERS.config_class(encoder))
    model_flags = flag_fields(MODELS.config_class(model))
    parts: dict[str, dict[str, Any]] = {"top": {}, "train": {}, "encoder": {}, "model": {}}
    for key, value in flat.items():
        value = tuple(value) if isinstance(value, list) else value
        for part, flags in (("top", TOP_FLAGS), ("train", flag_fields(TrainConfig)),
                            ("encoder", enc_flags), ("model", model_flags)):  # fmt: skip
            if key in flags:
                parts[part][flags[key]] = value
                break
        else:
            owner = owner_of_flag(key)
            if owner is None:
                raise ValueError(f"unknown pipeline setting {key!r}")
            if strict:
                kind, names = owner
                chosen = encoder if kind == "encoder" else model
                raise ValueError(
                    f"{key!r} is a setting of {kind} {' / '.join(names)}, but the {kind} is "
                    f"{chosen!r}"
                )
    return parts


def apply_flat(base: dict[str, Any], flat: dict[str, Any]) -> PipelineConfig:
    """``base`` (nested or flat settings) with flat overrides: the command line over a TOML file.

    A flat setting of a component that is not selected is refused (``--lif-neurons`` with
    ``--encoder gwt``); changing a component's type drops the old component's settings.
    """
    if not is_nested(base):
        return PipelineConfig.from_flat({**base, **flat}, strict=True)
    d = PipelineConfig.from_dict(base).to_dict()
    for kind in ("encoder", "model"):
        if kind in flat and flat[kind] != d[kind]["type"]:
            d[kind] = {"type": flat[kind]}
    rest = {k: v for k, v in flat.items() if k not in ("encoder", "model")}
    parts = place_flat(rest, d["encoder"]["type"], d["model"]["type"])
    d.update(parts.pop("top"))
    for part, values in parts.items():
        d[part].update(values)
    return PipelineConfig.from_dict(d)


def is_nested(d: dict[str, Any]) -> bool:
    """True for the nested form (component tables), False for the flat form."""
    return (
        isinstance(d.get("encoder"), dict)
        or isinstance(d.get("model"), dict)
        or (isinstance(d.get("train"), dict))
    )


def owner_of_flag(flag: str) -> tuple[str, tuple[str, ...]] | None:
    """``("encoder" | "model", registered names)`` whose config has the flat name ``flag``."""
    for kind, reg in (("encoder", ENCODERS), ("model", MODELS)):
        names = tuple(n for n in reg.names() if flag in flag_fields(reg.config_class(n)))
        if names:
            return kind, names
    return None


class FlatSetting(NamedTuple):
    """One flat setting name: which part of the pipeline it sets (``pipeline``, ``train``,
    ``encoder`` or ``model``), the registered components that have it (encoder / model
    settings), its default, help text and choices."""

    part: str
    components: tuple[str, ...]
    default: Any
    help: str
    choices: tuple[str, ...] | None

    @property
    def owner(self) -> str:
        """For help texts: ``"encoder gwt, stft"``, ``"train"``."""
        return " ".join([self.part, ", ".join(self.components)]).strip()


def flat_settings() -> dict[str, FlatSetting]:
    """Every flat setting name -> its :class:`FlatSetting` (for the CLI and settings files)."""
    out: dict[str, FlatSetting] = {}
    for part, cls in (("pipeline", PipelineConfig), ("train", TrainConfig)):
        texts, choices = help_texts(cls), choices_of(cls)
        for name, fld in flag_fields(cls).items():
            out[name] = FlatSetting(part, (), _field_default(cls, fld), texts[fld],
                                    choices.get(fld))  # fmt: skip
    for kind, reg in (("encoder", ENCODERS), ("model", MODELS)):
        for comp in reg.names():
            cfg_cls = reg.config_class(comp)
            texts, choices = help_texts(cfg_cls), choices_of(cfg_cls)
            first: dict[str, str] = {}  # field -> its first (primary) flat name
            for flag, fld in flag_fields(cfg_cls).items():
                text = texts[fld]
                if fld in first:  # a later name of the same field: an alias
                    text = f"alias of --{first[fld].replace('_', '-')}"
                first.setdefault(fld, flag)
                if flag in out:  # several components share the name (e.g. n_bands)
                    out[flag] = out[flag]._replace(components=(*out[flag].components, comp))
                else:
                    c = choices.get(fld)
                    out[flag] = FlatSetting(kind, (comp,), _field_default(cfg_cls, fld), text,
                                            tuple(c) if c else None)  # fmt: skip
    return out


def registries() -> dict[str, Registry]:
    return {"encoder": ENCODERS, "model": MODELS}


def _field_default(cls: type, name: str) -> Any:
    for f in dataclasses.fields(cls):
        if f.name == name:
            if f.default is not dataclasses.MISSING:
                return f.default
            return f.default_factory()  # type: ignore[misc]
    raise KeyError(name)


def _plain(d: dict[str, Any]) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

"""A scikit-learn classifier over the spike pipeline: ``SpikeClassifier().fit(X, y, fs_hz=...)``.

Hyperparameters live in ``__init__`` (stored as given, checked in ``fit``), what is learned from
the data ends in ``_``: the class labels (``classes_``), the channel names, the pipeline
(``pipeline_``, a :class:`~tactilesnn.pipeline.SpikePipeline` to export with
:func:`tactilesnn.export_pipeline`) and the temperature that calibrates ``predict_proba``.
So ``clone``, ``GridSearchCV``, ``cross_val_score`` and ``Pipeline`` work.

``X``: ``[N, channels, samples]`` windows at ``fs_hz`` in the sensor's units (``[N, samples]``
is one channel; ``[N, taxels, polarity, bins]`` event counts), or a
:class:`~tactilesnn.core.data.WindowDataset` (its rate, channel and class names are used).
The defaults are those of ``tactilesnn train --data`` (a user's file): every channel, the
``readout`` model, the encoder chosen among the causal GWT, STFT and LIF on held-out training windows
(``encoder="auto"``; the ``events`` encoder for event counts).
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np
import torch
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils.validation import check_array, check_is_fitted, column_or_1d

from .core.checks import check_float32_range, check_rate
from .core.data import DataFacts, WindowDataset
from .models.base import seeded
from .recordings import events_as_channels, layout_of
from .resolve import Resolution, resolve
from .selection import resolved_config
from .training import fit_pipeline

#: ``encoder=AUTO``: chosen among the data-file candidates on held-out training windows (not a
#: registered name: a mode of the estimator, as of ``train --data``)
AUTO = "auto"


class SpikeClassifier(ClassifierMixin, BaseEstimator):
    """Spike-encoder + spiking-model classifier with the scikit-learn API.

    Parameters
    ----------
    encoder : registered encoder name, or ``"auto"``: as ``train --data`` (chosen on held-out
        training windows; the ``events`` encoder for event counts).
    model : registered model name (``readout``, ``snn``, ``tempotron``, ``csnn``...), or
        ``"auto"``: as ``train --data`` (``readout``; ``csnn`` for event taxels on a grid).
    encoder_params, model_params : settings of the encoder's / model's config (field names, e.g.
        ``{"n_bands": 16}``, ``{"hidden": 64}``); unset fields keep the component's defaults
        for the data's rate and window.
    channels : ``"all"`` or channel names to use (names given to ``fit`` or ``ch0, ch1...``).
    epochs : training epochs (None: the model's default).
    batch_size, clock_afferents, seed : as ``tactilesnn train``.
    level_neurons : receptive fields of the calibrated level code appended to the encoder's
        spikes (:mod:`tactilesnn.encoders.level`; 0 = off, needed by models that map every
        afferent onto a taxel grid, such as ``csnn``; None: as ``train --data``).
    level_scale, level_share : what the level code's pairs code (``"rank"``, ``"linear"``,
        ``"rank+linear"`` or ``"wide"``) and whether each channel's share of the window's total level is a
        third statistic (None: as ``train --data`` for the data: ``rank+linear`` and the share
        for analog windows, the rank pair alone for event counts).
    val_fraction : windows (whole groups) held out of training for best-weight selection and
        the probability calibration (0: both on the training windows).
    fs_hz : sampling rate (Hz) when ``fit`` is not given one (``fit``'s wins).
    progress : progress bars while encoding and training.
    """

    def __init__(
        self,
        encoder: str = AUTO,
        model: str = AUTO,
        encoder_params: dict | None = None,
        model_params: dict | None = None,
        channels: str | tuple[str, ...] = "all",
        epochs: int | None = None,
        batch_size: int = 32,
        clock_afferents: int = 5,
        level_neurons: int | None = None,
        level_scale: str | None = None,
        level_share: bool | None = None,
        val_fraction: float = 0.0,
        seed: int = 0,
        fs_hz: float | None = None,
        progress: bool = False,
    ) -> None:
        self.encoder = encoder
        self.model = model
        self.encoder_params = encoder_params
        self.model_params = model_params
        self.channels = channels
        self.epochs = epochs
        self.batch_size = batch_size
        self.clock_afferents = clock_afferents
        self.level_neurons = level_neurons
        self.level_scale = level_scale
        self.level_share = level_share
        self.val_fraction = val_fraction
        self.seed = seed
        self.fs_hz = fs_hz
        self.progress = progress

    # ------------------------------------------------------------------ fit
    def fit(
        self,
        X: Any,
        y: Any = None,
        fs_hz: float | None = None,
        groups: Any = None,
        channel_names: Any = None,
    ) -> SpikeClassifier:
        """Learn the classes, calibrate the encoder, train the model.

        ``groups`` ``[N]``: recording ids (windows of one recording are held out together);
        ``channel_names``: names of ``X``'s channels (default ``ch0, ch1...``)."""
        with seeded(int(self.seed)):  # the caller's torch generator is left as it was
            return self._fit(X, y, fs_hz, groups, channel_names)

    def _fit(self, X, y, fs_hz, groups, channel_names) -> SpikeClassifier:
        data, labels = self._dataset(X, y, fs_hz, groups, channel_names)
        self.classes_ = labels
        self.n_features_in_ = int(np.prod(data.X.shape[1:]))
        self.channel_names_ = data.channel_names
        self.fs_hz_ = data.fs_hz
        config, self.encoder_selection_ = resolved_config(self._config(data), data)
        with seeded(config.seed):  # the one fit path (as tactilesnn train fits)
            fitted = fit_pipeline(config, data, progress=self.progress,
                                  val_fraction=float(self.val_fraction))  # fmt: skip
        self.history_ = fitted.history
        self.pipeline_ = fitted.pipeline
        calib = ((fitted.val_spikes, fitted.val_set.y) if fitted.val_set is not None
                 else (fitted.train_spikes, fitted.train_y))  # fmt: skip
        self.temperature_ = _temperature(self.pipeline_.scores(calib[0]).numpy(),
                                         np.asarray(calib[1]))  # fmt: skip
        return self

    def _dataset(self, X, y, fs_hz, groups, channel_names) -> tuple[WindowDataset, np.ndarray]:
        """The training windows and the class labels, as the user gives them (``classes_``)."""
        if isinstance(X, WindowDataset):
            if y is not None:
                raise ValueError("fit(WindowDataset) takes its labels from the dataset; pass no y")
            return X, np.asarray(X.class_names)
        if y is None:
            raise ValueError(f"{type(self).__name__} requires y to be passed, but the target y is "
                             "None (or pass a WindowDataset, which holds its labels)")  # fmt: skip
        check_classification_targets(y)
        fs = fs_hz if fs_hz is not None else self.fs_hz
        if fs is None:
            raise ValueError("the sampling rate is unknown: pass fit(X, y, fs_hz=...) or "
                             "SpikeClassifier(fs_hz=...)")  # fmt: skip
        fs = _rate(fs)
        arr = _windows(X)
        facts = None
        if arr.ndim == 4:  # event counts: a channel per taxel and polarity, as train --data
            facts, arr, channel_names = _event_channels(arr, fs, channel_names)
        labels, y_idx = np.unique(column_or_1d(y, warn=True), return_inverse=True)
        if len(y_idx) != len(arr):
            raise ValueError(f"X has {len(arr)} windows but y has {len(y_idx)} labels")
        if labels.size < 2:
            raise ValueError(f"y holds {labels.size} class; a classifier needs at least two")
        names = _channel_names(channel_names, arr.shape[1])
        scan = np.arange(len(arr)) if groups is None else np.unique(groups, return_inverse=True)[1]
        if len(scan) != len(arr):
            raise ValueError(f"groups has {len(scan)} entries for {len(arr)} windows")
        data = WindowDataset(arr, y_idx.astype(np.int64), scan.astype(np.int64), float(fs),
                             tuple(str(c) for c in labels), names, facts=facts)  # fmt: skip
        return data, labels

    def _config(self, data: WindowDataset) -> Resolution:
        """The run's settings as ``tactilesnn train --data`` resolves them for the file the
        windows were read from (their :attr:`~WindowDataset.facts`; windows from elsewhere are
        analog recordings), this estimator's parameters the user's choices
        (:func:`~tactilesnn.resolve.resolve`)."""
        given: dict[str, Any] = {
            "channels": ("all",) if self.channels == "all" else tuple(self.channels),
            "clock_afferents": self.clock_afferents, "batch_size": self.batch_size,
            "seed": self.seed,
        }  # fmt: skip
        for key in ("encoder", "model"):
            if getattr(self, key) != AUTO:
                given[key] = getattr(self, key)
        for key in ("level_neurons", "level_scale", "level_share", "epochs"):
            if getattr(self, key) is not None:
                given[key] = getattr(self, key)
        return resolve(given, facts=data.facts or DataFacts(events=False),
                       fields={"encoder": self.encoder_params or {},
                               "model": self.model_params or {}})  # fmt: skip

    # ------------------------------------------------------------------ predict
    def decision_function(self, X: Any) -> np.ndarray:
        """Class scores ``[N, classes]`` (the model's own units, higher = more likely); with two
        classes, as scikit-learn has it, ``[N]``: the second class's score minus the first's."""
        scores = self._scores(X)
        return scores[:, 1] - scores[:, 0] if scores.shape[1] == 2 else scores

    def _scores(self, X: Any, fs_hz: Any = None, channel_names: Any = None) -> np.ndarray:
        check_is_fitted(self, "pipeline_")
        if not isinstance(X, WindowDataset) and (fs_hz is not None or channel_names is not None):
            arr = _windows(X, min_samples=1)
            fs = self.fs_hz_ if fs_hz is None else _rate(fs_hz)
            names = (self.channel_names_ if channel_names is None
                     else _channel_names(channel_names, arr.shape[1]))  # fmt: skip
            X = WindowDataset(arr, np.zeros(len(arr), np.int64), np.arange(len(arr)), fs,
                              tuple(str(c) for c in self.classes_), names)  # fmt: skip
        if isinstance(X, WindowDataset):  # it says its rate and channels: checked, as the CLI does
            X = self._matched(_stated(X, fs_hz, channel_names))
        arr = _windows(X, min_samples=1)  # (a wrong window length is reported below)
        if arr.ndim == 4:  # event counts, a channel per taxel and polarity (as in fit)
            arr = arr.reshape(len(arr), -1, arr.shape[-1])
        want = (len(self.channel_names_), self.pipeline_.window)
        if arr.shape[1:3] != want:
            raise ValueError(
                f"X has {int(np.prod(arr.shape[1:]))} features, but {type(self).__name__} is "
                f"expecting {self.n_features_in_} features as input: {want[0]} channels of "
                f"{want[1]} samples (as in fit), got {list(arr.shape[1:])}"
            )
        with torch.no_grad():
            return self.pipeline_.scores(self.pipeline_.encode(arr)).numpy().astype(np.float64)

    def _matched(self, data: WindowDataset) -> WindowDataset:
        """``data`` with its channels in the fitted order (by name); ValueError for another rate
        or other channels (a window at 100 Hz read as 200 Hz is a wrong answer, not an error
        the model could see)."""
        from dataclasses import replace

        if abs(float(data.fs_hz) - self.fs_hz_) > 1e-6 * self.fs_hz_:
            raise ValueError(f"the windows are sampled at {float(data.fs_hz):g} Hz, the model at "
                             f"{self.fs_hz_:g} Hz: resample them first")  # fmt: skip
        have, want = tuple(data.channel_names), tuple(self.channel_names_)
        if np.ndim(data.X) == 3 and np.shape(data.X)[1] != len(have):
            raise ValueError(f"the dataset's windows have {np.shape(data.X)[1]} channels but "
                             f"{len(have)} channel names {list(have)[:6]}; name every channel")  # fmt: skip
        if have == want:
            return data
        if sorted(have) != sorted(want):
            raise ValueError(f"the windows' channels {list(have)} are not the model's {list(want)}")
        return replace(data, X=np.asarray(data.X)[:, [have.index(c) for c in want]],
                       channel_names=want)  # fmt: skip

    def predict(self, X: Any, *, fs_hz: Any = None, channel_names: Any = None) -> np.ndarray:
        """Class labels ``[N]`` of the windows ``X``. ``fs_hz`` and ``channel_names``, where
        given, say what ``X`` holds: another rate than the model's is refused, channels in
        another order are put in the model's (by name), other channels refused (a
        :class:`WindowDataset` says both itself)."""
        scores = self._scores(X, fs_hz, channel_names)  # (first: it checks the estimator is fitted)
        return self.classes_[scores.argmax(1)]

    def predict_proba(self, X: Any, *, fs_hz: Any = None, channel_names: Any = None
                      ) -> np.ndarray:  # fmt: skip
        """Class probabilities ``[N, classes]``: a softmax of the scores divided by a temperature
        fitted (maximum likelihood) on the validation windows, else the training windows
        (``fs_hz``, ``channel_names``: as :meth:`predict`)."""
        return _softmax(self._scores(X, fs_hz, channel_names) / self.temperature_)

    def score(self, X: Any, y: Any = None, sample_weight: Any = None) -> float:
        """Accuracy on ``(X, y)``, or on a :class:`WindowDataset` (its labels: class names when
        the estimator was fitted on names, else the indices)."""
        if isinstance(X, WindowDataset) and y is None:
            check_is_fitted(self, "pipeline_")
            names = self.classes_.dtype.kind in "US"
            X = self._matched(X)
            X, y = X.X, (np.asarray(X.class_names)[X.y] if names else X.y)
        return super().score(X, y, sample_weight=sample_weight)

    def predict_log_proba(self, X: Any) -> np.ndarray:
        return np.log(np.clip(self.predict_proba(X), 1e-300, None))

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.allow_nan = False
        tags.input_tags.three_d_array = True
        return tags


def _rate(fs: Any) -> float:
    """``fs`` (Hz) as a float: a positive finite real number, numpy's scalars too
    (``np.float32(200)``), not a bool."""
    if (
        isinstance(fs, bool | np.bool_)
        or not isinstance(fs, numbers.Real)
        or not math.isfinite(fs)
        or fs <= 0
    ):
        raise ValueError(f"fs_hz must be a positive finite number of Hz, got {fs!r}")
    return check_rate(fs, "fs_hz")


def _stated(data: WindowDataset, fs_hz: Any, channel_names: Any) -> WindowDataset:
    """``data``, whose own rate and channel names a keyword may only repeat (ValueError where
    it says otherwise: which one is right is the user's call, not ours)."""
    if fs_hz is not None and abs(_rate(fs_hz) - float(data.fs_hz)) > 1e-6 * float(data.fs_hz):
        raise ValueError(f"fs_hz={fs_hz} but the dataset says {float(data.fs_hz):g} Hz; drop "
                         "the keyword or fix the dataset's fs_hz")  # fmt: skip
    if channel_names is not None and tuple(map(str, channel_names)) != tuple(data.channel_names):
        raise ValueError(f"channel_names={list(channel_names)[:6]} but the dataset names "
                         f"{list(data.channel_names)[:6]}; drop the keyword or fix the dataset")  # fmt: skip
    return data


def _windows(X: Any, min_samples: int = 2) -> np.ndarray:
    """``[N, samples]`` -> ``[N, 1, samples]``; 3-D windows and 4-D event counts as given.
    scikit-learn's own checks first (sparse, complex, object, empty, NaN/Inf: its messages)."""
    if isinstance(X, WindowDataset):
        X = X.X
    arr = check_array(X, dtype=(np.float32, np.float64), allow_nd=True, ensure_min_samples=1,
                      ensure_min_features=min_samples, input_name="X")  # fmt: skip
    if arr.ndim == 2:
        arr = arr[:, None, :]
    if arr.ndim not in (3, 4):
        raise ValueError(
            f"X must be [N, channels, samples] (or [N, samples], or [N, taxels, polarity, bins] "
            f"event counts), got shape {list(arr.shape)}"
        )
    if arr.shape[-1] < min_samples:
        raise ValueError(f"windows need at least 2 samples, got shape {list(arr.shape)}")
    check_float32_range(arr, "X")
    return np.ascontiguousarray(arr, dtype=np.float32)


def _event_channels(arr: np.ndarray, fs: float,
                    names: Any) -> tuple[DataFacts, np.ndarray, np.ndarray]:  # fmt: skip
    """Event counts ``[N, taxels, polarity, bins]`` -> ``(their facts, [N, taxels x polarity,
    bins], the channels' names <taxel>:<polarity>)`` as ``train --data`` reads an event file
    (``names``: the taxels' names); taxels that fill a square form its grid."""
    taxels = arr.shape[1]
    arrays = {"X": arr, "fs": np.asarray(fs)}
    if names is not None:
        arrays["channel_names"] = np.asarray([str(c) for c in names])
    out = events_as_channels(arrays, "X")
    layout = layout_of(taxels, None, None, "X")
    return DataFacts(True, *(layout or (None, ()))), out["X"], out["channel_names"]


def _channel_names(names: Any, n: int) -> tuple[str, ...]:
    if names is None:
        return tuple(f"ch{i}" for i in range(n))
    names = tuple(str(c) for c in names)
    if len(names) != n or len(set(names)) != n:
        raise ValueError(f"channel_names must be {n} distinct names, got {len(names)}")
    return names


def _softmax(z: np.ndarray) -> np.ndarray:
    z = z - z.max(1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(1, keepdims=True)


def _temperature(scores: np.ndarray, y: np.ndarray) -> float:
    """Temperature ``T`` minimising the negative log-likelihood of ``softmax(scores / T)`` over
    a log grid (robust for any score scale; 1 if the scores carry no spread)."""
    spread = float(np.std(scores))
    if not np.isfinite(spread) or spread <= 0:
        return 1.0
    grid = spread * np.logspace(-3, 3, 121)
    idx = np.arange(len(y))

    def nll(t: float) -> float:
        p = _softmax(scores / t)
        return float(-np.log(np.clip(p[idx, y], 1e-300, None)).mean())

    return float(min(grid, key=nll))

"""Property-based fuzzing (hypothesis) of every input surface: the ``.npz`` loader, the TOML /
settings layer, the encoders and the service bodies.

Each property: a specific error (ValueError / TypeError / FileNotFoundError, or a 4xx with a
message) or a correct result (shapes, finite spike times in the window, ordering) — never another
exception type, a NaN, a 5xx, or a change to files the user owns.
"""

from __future__ import annotations

import io
import json
import math
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tactilesnn.app.runs import RunWriter
from tactilesnn.config import PipelineConfig
from tactilesnn.encoders.base import ENCODERS, build_encoder
from tactilesnn.recordings import load_data_file

FUZZ = settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
SPECIFIC = (ValueError, TypeError, FileNotFoundError, FileExistsError)

# ---------------------------------------------------------------- values that break things
floats_any = st.floats(allow_nan=True, allow_infinity=True, width=64)
wild_float = st.one_of(
    floats_any, st.sampled_from([0.0, -0.0, 1e-45, 1e-12, 1e20, 1e39, -1e308, 3.4e38])
)
scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**40), 2**40), wild_float, st.text(max_size=8)
)


def array_like(max_dims: int = 4):
    dtypes = st.sampled_from([np.float32, np.float64, np.int16, np.int64, np.bool_, np.complex64])
    shapes = hnp.array_shapes(min_dims=0, max_dims=max_dims, min_side=0, max_side=6)
    return st.one_of(
        hnp.arrays(dtypes, shapes),
        st.lists(st.text(max_size=4), max_size=4).map(np.array),
        st.just(np.array(["a", "b"], dtype=object)),
    )


# ---------------------------------------------------------------- the .npz loader
@st.composite
def npz_contents(draw):
    """Mostly plausible files with one or more fields damaged."""
    n = draw(st.integers(0, 6))
    c = draw(st.integers(0, 3))
    w = draw(st.integers(0, 40))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    arrays = {
        "X": rng.standard_normal((n, c, w)),
        "y": rng.integers(0, 2, n),
        "fs": np.array(100.0),
        "class_names": np.array(["a", "b"]),
    }
    for key in draw(st.lists(st.sampled_from([*sorted(arrays), "channel_names", "recording",
                                                            "split"]), max_size=3)):  # fmt: skip
        arrays[key] = draw(array_like())
    if draw(st.booleans()) and arrays["X"].dtype.kind == "f" and arrays["X"].size:
        flat = arrays["X"].reshape(-1)
        flat[draw(st.integers(0, flat.size - 1))] = draw(wild_float)
    for key in draw(st.lists(st.sampled_from(sorted(arrays)), max_size=2)):
        arrays.pop(key, None)
    return arrays


def _check_datasets(train, test) -> None:
    for ds in (train, test):
        assert ds.X.dtype == np.float32 and ds.X.ndim == 3 and ds.X.shape[2] >= 2
        assert np.isfinite(ds.X).all()
        assert ds.y.dtype == np.int64 and ds.y.shape == (ds.X.shape[0],)
        assert ((ds.y >= 0) & (ds.y < len(ds.class_names))).all()
        assert math.isfinite(ds.fs_hz) and ds.fs_hz > 0
    # windows of one recording never straddle the split
    assert not set(train.scan.tolist()) & set(test.scan.tolist())


@pytest.mark.slow
@FUZZ
@given(npz_contents())
def test_loader_gives_a_specific_error_or_valid_data(arrays) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "d.npz"
        np.savez(path, **arrays)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                train, test = load_data_file(path, seed=0)
            except SPECIFIC as e:
                assert str(e)
                return
        _check_datasets(train, test)


@FUZZ
@given(st.binary(max_size=400), st.integers(0, 399))
def test_loader_damaged_bytes(blob: bytes, cut: int) -> None:
    """Random bytes, or a valid file truncated anywhere: a specific error, never a traceback."""
    with tempfile.TemporaryDirectory() as tmp:
        good = Path(tmp) / "good.npz"
        np.savez(good, X=np.zeros((4, 1, 8)), y=np.array([0, 1, 0, 1]), fs=100.0,
                 class_names=np.array(["a", "b"]))  # fmt: skip
        for data in (blob, good.read_bytes()[: cut * len(good.read_bytes()) // 400]):
            path = Path(tmp) / "d.npz"
            path.write_bytes(data)
            with pytest.raises(SPECIFIC):
                load_data_file(path, seed=0)


# ---------------------------------------------------------------- settings / TOML layer
SETTING_KEYS = ["channels", "clock_afferents", "encoder", "model", "epochs", "lr", "seed",
                "n_bands", "f_lo_hz", "f_hi_hz", "stats", "mapping", "dynamic_range_db",
                "lif_neurons", "lif_lo", "lif_hi", "lif_tau_ms", "snn_hidden", "snn_dt_ms",
                "snn_readout", "no_such_key"]  # fmt: skip
setting_values = st.one_of(
    scalars,
    st.sampled_from(["gwt", "stft", "lif", "delta", "events", "tempotron", "snn", "readout"]),
    st.lists(st.one_of(st.text(max_size=5), st.sampled_from(["all", "mean", "std"])), max_size=3),
)


@FUZZ
@given(st.dictionaries(st.sampled_from(SETTING_KEYS), setting_values, max_size=5))
def test_flat_settings_error_or_valid_config(flat: dict) -> None:
    try:
        cfg = PipelineConfig.from_flat(flat, strict=True)
    except SPECIFIC as e:
        assert str(e)
        return
    again = PipelineConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert again == cfg  # what is accepted round-trips through the run folder's JSON


def _toml_value(v) -> str | None:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return (
            "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
        )
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        parts = [_toml_value(x) for x in v]
        return None if None in parts else "[" + ", ".join(parts) + "]"
    return None


@FUZZ
@given(
    st.dictionaries(st.sampled_from(SETTING_KEYS), setting_values, max_size=5),
    st.sampled_from(["flat", "train", "nested"]),
)
@pytest.mark.slow
def test_toml_files_error_or_valid(table: dict, form: str) -> None:
    """A TOML file through the CLI's reader: a one-line error (exit 2) or accepted settings."""
    from tactilesnn.app.config_file import read_train_file

    lines = [f"{k} = {_toml_value(v)}" for k, v in table.items() if _toml_value(v) is not None]
    if form == "train":
        lines = ["[train]", *lines]
    elif form == "nested":
        lines = ['[encoder]\ntype = "gwt"', *lines]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "c.toml"
        path.write_text("\n".join(lines) + "\n")
        try:
            read_train_file(path)
        except SPECIFIC as e:
            assert str(e)


# ---------------------------------------------------------------- encoders
ENC_NAMES = ["gwt", "stft", "lif", "delta", "bands"]


@FUZZ
@given(
    st.sampled_from(ENC_NAMES),
    hnp.arrays(
        np.float64,
        st.tuples(st.integers(1, 3), st.integers(1, 2), st.just(96)),
        elements=st.one_of(
            st.floats(width=32, allow_nan=False, allow_infinity=False),
            st.sampled_from([0.0, 1e-30, -1e-12, 1e20]),
        ),
    ),
    st.floats(1e-30, 1e30),
)
@pytest.mark.slow
def test_encoders_give_valid_spikes_for_any_float32(name: str, X: np.ndarray, scale: float):
    """Any finite float32 input, trained at any unit scale: spike times are finite inside the
    window or +inf (silent), ascending per afferent, never NaN."""
    enc = build_encoder(ENCODERS.config_class(name)(), 1000.0, X.shape[2], X.shape[1])
    rng = np.random.default_rng(0)
    train = scale * rng.standard_normal((4, X.shape[1], X.shape[2]))
    enc.fit(train)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = enc.encode(X.astype(np.float32)).numpy()
    assert t.shape == (X.shape[0], enc.n_afferents, enc.max_spikes)
    assert not np.isnan(t).any()
    fin = np.isfinite(t)
    assert ((t[fin] >= 0) & (t[fin] <= enc.duration_ms + 1e-3)).all()
    assert np.array_equal(np.sort(t, axis=-1), t)  # ascending slots, silent ones last


@FUZZ
@given(st.sampled_from(["gwt", "stft"]), st.floats(-38, 38))
def test_scalogram_codes_are_scale_invariant(name: str, log_scale: float) -> None:
    """The GWT/STFT latency codes are normalised per window: x and 10^k x give the same spikes
    (within float32 rounding), over the whole float32 range (was all-silent below 1e-12 and
    wrong above 1e19)."""
    t = np.arange(200) / 1000.0
    x = (np.sin(2 * np.pi * 20 * t) + 0.3 * np.sin(2 * np.pi * 70 * t))[None, None]
    enc = build_encoder(ENCODERS.config_class(name)(), 1000.0, 200, 1)
    ref = enc.encode(x).numpy()
    got = enc.encode(x * 10.0**log_scale).numpy()
    both = np.isfinite(ref) & np.isfinite(got)
    # a flip is only allowed for spikes at the code's cutoff (the window end)
    flips = np.isfinite(ref) != np.isfinite(got)
    assert (np.where(np.isfinite(ref), ref, got)[flips] > enc.duration_ms - 0.5).all()
    assert np.abs(got[both] - ref[both]).max(initial=0) < 0.05


@FUZZ
@given(st.sampled_from([1e39, -1e39, 1e300, np.nan, np.inf, -np.inf]), st.integers(0, 99))
def test_pipeline_refuses_values_float32_cannot_hold(bad: float, pos: int) -> None:
    from tactilesnn.pipeline import SpikePipeline

    pipe = SpikePipeline(PipelineConfig.from_flat(channels=["all"], epochs=1), 1000.0, 100,
                         ("c0",), ("a", "b"))  # fmt: skip
    X = np.zeros((1, 1, 100))
    X[0, 0, pos] = bad
    with pytest.raises(ValueError, match=r"float32|non-finite"):
        pipe.validate(X)


# ---------------------------------------------------------------- files the user owns
@FUZZ
@given(
    st.lists(
        st.sampled_from(
            ["notes.txt", "data.npz", "config.json", "weights.npz", "sub/x.txt", "manifest.json"]
        ),
        max_size=4,
        unique=True,
    ),
    st.booleans(),
)
def test_run_writer_never_touches_foreign_folders(names: list[str], overwrite: bool) -> None:
    """A folder tactilesnn did not write is refused (with or without --overwrite) and left
    byte-for-byte as it was."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        out.mkdir()
        for n in names:
            (out / n).parent.mkdir(parents=True, exist_ok=True)
            (out / n).write_text(f"user data {n}")
        before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
        try:
            w = RunWriter(out, overwrite=overwrite)
        except SPECIFIC:
            pass
        else:  # only an empty folder may be taken
            assert not names
            w.abort()
        after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
        assert after == before


# ---------------------------------------------------------------- service bodies
json_values = st.recursive(
    st.one_of(
        st.none(),
        st.booleans(),
        st.integers(),
        st.floats(allow_nan=False),
        st.text(max_size=6),
        # integers float() cannot hold (the 5,000-digit ones: tests/service/test_security.py)
        st.sampled_from([10**400, -(10**400), 1e308, -1e308]),
    ),
    lambda kids: st.one_of(
        st.lists(kids, max_size=4), st.dictionaries(st.text(max_size=6), kids, max_size=4)
    ),
    max_leaves=30,
)


@pytest.fixture(scope="session")
def client(tmp_path_factory):
    from starlette.testclient import TestClient

    from tactilesnn.service.app import create_app
    from tests.helpers import exported_model

    small = {"seed": 0, "n_planar": 6, "n_concave": 3, "n_convex": 3, "n_test": 2}
    path, _, test = exported_model(tmp_path_factory.mktemp("fuzz_svc"), small)
    with TestClient(
        create_app(str(path), max_body_bytes=100_000), base_url="http://127.0.0.1"
    ) as c:
        yield c, test


def _window_like(draw, test) -> object:
    base = test.X[0].astype(np.float64)
    kind = draw(st.sampled_from(["ok", "scaled", "poke", "shape", "value"]))
    if kind == "scaled":
        return (base * 10.0 ** draw(st.integers(-40, 40))).tolist()
    if kind == "poke":
        b = base.copy()
        b[0, draw(st.integers(0, b.shape[1] - 1))] = draw(wild_float)
        return [[None if not math.isfinite(v) else v for v in row] for row in b.tolist()]
    if kind == "shape":
        return np.zeros(draw(hnp.array_shapes(max_dims=3, max_side=5))).tolist()
    if kind == "value":
        return draw(json_values)
    return base.tolist()


@pytest.mark.slow
@FUZZ
@given(st.data())
def test_service_bodies_get_4xx_or_a_correct_answer(client, data) -> None:
    c, test = client
    route = data.draw(st.sampled_from(["/v1/classify", "/v1/stream/fz"]))
    key = "window" if route == "/v1/classify" else "chunk"
    kind = data.draw(st.sampled_from(["json", "raw", "npy"]))
    if kind == "json":
        body = {key: _window_like(data.draw, test)}
        if data.draw(st.booleans()):
            body["fs_hz"] = data.draw(
                st.one_of(wild_float.filter(math.isfinite), st.text(max_size=3))
            )
        r = c.post(route, content=json.dumps(body), headers={"content-type": "application/json"})
    elif kind == "raw":
        ctype = data.draw(st.sampled_from(["application/json", "application/x-npy", "text/plain"]))
        r = c.post(
            route, content=data.draw(st.binary(max_size=300)), headers={"content-type": ctype}
        )
    else:
        buf = io.BytesIO()
        np.save(buf, data.draw(array_like(3)), allow_pickle=True)  # a pickled .npy is refused
        r = c.post(route, content=buf.getvalue(), headers={"content-type": "application/x-npy"})
    assert r.status_code in (200, 400, 413, 415, 422, 429), r.text
    out = r.json()
    if r.status_code == 200 and route == "/v1/classify":
        scores = np.asarray(out["scores"], dtype=float)
        assert np.isfinite(scores).all() and len(out["classes"]) == scores.shape[0]
    elif r.status_code != 200:
        assert out["error"]


@FUZZ
@given(st.data())
def test_any_json_document_gets_a_4xx_or_an_answer(client, data):
    c, test = client
    route, key = data.draw(st.sampled_from([("/v1/classify", "window"), ("/v1/stream/z", "chunk")]))
    doc = data.draw(st.one_of(
        json_values,
        st.fixed_dictionaries({key: json_values}, optional={"fs_hz": json_values}),
        st.fixed_dictionaries({key: st.just(test.X[0].tolist())}, optional={"fs_hz": json_values}),
    ))  # fmt: skip
    body = json.dumps(doc).encode()  # (Infinity and NaN included: Python writes them)
    if data.draw(st.booleans()):
        body = body[: data.draw(st.integers(0, 50))]  # cut short
    r = c.post(route, content=body, headers={"content-type": "application/json"})
    assert r.status_code in (200, 400, 413, 415, 422, 429), (r.status_code, r.text[:200])
    if r.status_code != 200:
        assert r.json()["error"]

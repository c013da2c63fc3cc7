"""Text tables as people save them: delimiters, decimal commas, byte-order marks, title lines,
headers or none, empty columns; every refusal names the line and the column."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactilesnn.core.tables import read_table

VALUES = np.array([[0.0, 1.5, -2.25], [0.01, 1.75, -2.0], [0.02, 2.0, 3.5e-3], [0.03, 2.5, 4.0]])


def _write(path, text: str, encoding: str = "utf-8") -> None:
    path.write_bytes(text.encode(encoding))


def _rows(delim: str, decimal: str = ".") -> list[str]:
    return [delim.join(f"{v:g}".replace(".", decimal) for v in row) for row in VALUES]


@pytest.mark.parametrize(
    "delim,decimal", [(",", "."), (";", ","), ("\t", "."), ("\t", ","), (" ", "."), ("|", ".")]
)
@pytest.mark.parametrize("header", [True, False])
def test_delimiter_decimal_mark_and_header_are_found(tmp_path, delim, decimal, header):
    lines = _rows(delim, decimal)
    if header:
        lines = [delim.join(["time", "a", "b"]), *lines]
    _write(tmp_path / "r.csv", "\n".join(lines) + "\n")
    table = read_table(tmp_path / "r.csv")
    np.testing.assert_allclose(table.values, VALUES)
    assert table.header is header
    assert table.names == (["time", "a", "b"] if header else ["col1", "col2", "col3"])


def test_a_spreadsheet_export_bom_title_and_empty_columns(tmp_path):
    text = "Export of 28.11.2026" + "," * 20 + "\r\n"
    text += "time,left,right" + "," * 18 + "\r\n"
    text += "".join(",".join(f"{v:g}" for v in row) + "," * 18 + "\r\n" for row in VALUES)
    _write(tmp_path / "r.csv", text, "utf-8-sig")
    table = read_table(tmp_path / "r.csv")
    np.testing.assert_allclose(table.values, VALUES)
    assert table.names == ["time", "left", "right"] and table.header
    assert any("byte-order mark" in n for n in table.notes)
    assert any("title line" in n for n in table.notes)
    assert list(table.line_numbers) == [3, 4, 5, 6]


def test_utf16_and_windows_1252_text(tmp_path):
    text = "time;Kraft µN\n" + "\n".join(f"{i};{i * 0.5:g}".replace(".", ",") for i in range(5))
    _write(tmp_path / "a.csv", text, "utf-16")
    _write(tmp_path / "b.csv", text, "cp1252")
    for name in ("a.csv", "b.csv"):
        table = read_table(tmp_path / name)
        assert table.names == ["time", "Kraft µN"]
        np.testing.assert_allclose(table.values[:, 1], np.arange(5) * 0.5)


@pytest.mark.parametrize(
    "body,match",
    [
        ("t,a\n0,1\n1,\n2,3\n", r"line 3, column 2 \('a'\) holds an empty cell"),
        ("t,a\n0,1\n1,x\n2,3\n", r"line 3, column 2 \('a'\) holds 'x'"),
        ("t,a\n0,1\n1,nan\n2,3\n", r"line 3, column 2 \('a'\) holds nan"),
        ("t,a\n0,1\n1,2\n2,3,7\n", r"line 4, column 3 holds '7', a column the other rows"),
        ("just words\nmore words\n", r"no rows of numbers"),
        ("", r"empty file"),
    ],
)
def test_refusals_name_the_line_and_the_column(tmp_path, body, match):
    _write(tmp_path / "r.csv", body)
    with pytest.raises(ValueError, match=match):
        read_table(tmp_path / "r.csv")


@settings(max_examples=40, deadline=None)
@given(
    values=st.integers(2, 5).flatmap(
        lambda c: st.lists(
            st.lists(st.floats(-1e6, 1e6, allow_nan=False, width=32), min_size=c, max_size=c),
            min_size=3,
            max_size=12,
        )
    ),
    delim=st.sampled_from([",", ";", "\t"]),
    header=st.booleans(),
)
def test_any_numeric_table_round_trips(tmp_path_factory, values, delim, header):
    path = tmp_path_factory.mktemp("t") / "r.csv"
    a = np.array(values, np.float64)
    lines = [delim.join(repr(float(v)) for v in row) for row in a]
    if header:
        lines = [delim.join(f"c{j}" for j in range(a.shape[1])), *lines]
    path.write_text("\n".join(lines))
    table = read_table(path)
    np.testing.assert_array_equal(table.values, a)
    assert table.header is header

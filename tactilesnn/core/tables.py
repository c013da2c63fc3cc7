"""Text tables as people save them (CSV, TSV, spreadsheet exports) -> numbers and column names.

:func:`read_table` decides, from the file alone: the text encoding (UTF-8 with or without a
byte-order mark, UTF-16 with one, else Windows-1252, said in the notes), the delimiter (tab,
``;``, ``,``, ``|`` or runs of spaces: the first that splits the data rows into one steady number
of fields), the decimal mark (``1,5`` where ``,`` is not the delimiter), title lines above the
data, whether there is a header line (the line just above the first run of numeric rows, when it
names the columns), and trailing or wholly empty columns (dropped, said in the notes). Every
refusal names the file, the line and the column, and what to do. Pure Python and NumPy.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .checks import check_allocation

#: delimiters tried, in order of preference (``None``: runs of white space)
DELIMITERS: tuple[str | None, ...] = ("\t", ";", ",", "|", None)
#: data lines looked at to decide the delimiter, decimal mark and header
SAMPLE_LINES = 64
#: the largest text table read (bytes; a recording per file)
MAX_TABLE_BYTES = 1 << 31

_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(nan|inf|infinity)$", re.I)
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+([eE][+-]?\d+)?$")


@dataclass
class Table:
    """A text table: ``values [rows, columns]`` float64, one name per column (``col1`` ... where
    the file has no header), the file's line number of each row (1-based), and what was decided
    (``notes``, one phrase each)."""

    values: np.ndarray
    names: list[str]
    line_numbers: np.ndarray
    header: bool
    notes: list[str] = field(default_factory=list)


def decode(raw: bytes, path: Path) -> tuple[str, str | None]:
    """The text of a file's bytes and a note when it was not plain UTF-8."""
    if raw.startswith(b"\xef\xbb\xbf"):
        return raw[3:].decode("utf-8", errors="strict"), "UTF-8 byte-order mark skipped"
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16"), "UTF-16 text"
    try:
        return raw.decode("utf-8"), None
    except UnicodeDecodeError:
        return raw.decode("cp1252", errors="replace"), "not UTF-8: read as Windows-1252"


def _split(line: str, delimiter: str | None) -> list[str]:
    if delimiter is not None and '"' in line:  # quoted cells may hold the delimiter ("1,25")
        cells = [c.strip() for c in next(csv.reader([line], delimiter=delimiter))]
    else:
        cells = [c.strip().strip('"').strip() for c in line.split(delimiter)]
    while cells and cells[-1] == "":
        cells.pop()
    return cells


def _is_number(cell: str, decimal_comma: bool) -> bool:
    if decimal_comma and _DECIMAL_COMMA.match(cell):
        return True
    return bool(_NUMBER.match(cell))


def _numeric(cells: list[str], decimal_comma: bool) -> bool:
    filled = [c for c in cells if c]
    return bool(filled) and all(_is_number(c, decimal_comma) for c in filled)


def _choose_delimiter(sample: list[str]) -> str | None:
    """The first delimiter that splits most sampled lines into one number (> 1) of fields."""
    for d in DELIMITERS:
        if d is not None and not any(d in line for line in sample):
            continue  # one field per line: not this delimiter (no need to split to know)
        counts = [len(_split(line, d)) for line in sample]
        mode = max(sorted(set(counts)), key=counts.count)
        if mode > 1 and counts.count(mode) >= 0.5 * len(counts):
            return d
    return None  # one column


def _data_start(lines: list[str], delimiter: str | None, decimal_comma: bool, width: int) -> int:
    """Index of the first line of numbers about as wide as the data rows (``width`` fields; a
    title line that is one number is not data), or -1."""
    for i, line in enumerate(lines[:10_000]):
        cells = _split(line, delimiter)
        if len(cells) >= max(1, width // 2) and _numeric(cells, decimal_comma):
            return i
    return -1


def read_table(path: Path) -> Table:
    """The numbers and column names of the text table at ``path`` (see the module docstring)."""
    path = Path(path)
    size = path.stat().st_size
    if size > MAX_TABLE_BYTES:
        raise ValueError(f"{path}: {size / 2**30:.1f} GiB of text; at most "
                         f"{MAX_TABLE_BYTES >> 30} GiB per recording file (store large "
                         "recordings as .npy or .npz)")  # fmt: skip
    check_allocation(4 * size, f"the numbers of {path}")  # <= size / 2 cells of 8 bytes
    text, encoding_note = decode(path.read_bytes(), path)
    all_lines = text.splitlines()
    numbered = [(i + 1, s) for i, s in enumerate(all_lines) if s.strip()]
    if not numbered:
        raise ValueError(f"{path}: empty file")
    lines = [s for _, s in numbered]
    mid = len(lines) // 2 if len(lines) > 2 * SAMPLE_LINES else 0
    sample = lines[mid : mid + SAMPLE_LINES]
    delimiter = _choose_delimiter(sample)
    split_sample = [_split(line, delimiter) for line in sample]
    cells_sample = [c for cells in split_sample for c in cells if c]
    # a comma-separated file may still hold decimal commas inside quoted cells ("0,005")
    quoted = delimiter == "," and any('"' in line for line in sample)
    decimal_comma = ((delimiter != "," or quoted)
                     and any(_DECIMAL_COMMA.match(c) for c in cells_sample)
                     and not any("." in c for c in cells_sample))  # fmt: skip
    counts = [len(cells) for cells in split_sample]
    start = _data_start(lines, delimiter, decimal_comma, max(sorted(set(counts)), key=counts.count))
    if start < 0:
        bad = _split(lines[min(mid, len(lines) - 1)], delimiter)
        cell = next((c for c in bad if c and not _is_number(c, decimal_comma)), bad[:1])
        raise ValueError(f"{path}: no rows of numbers found (line {numbered[mid][0]} holds "
                         f"{str(cell)[:40]!r}); a recording file holds one row per sample, one "
                         "column per channel")  # fmt: skip
    notes = [n for n in (encoding_note,) if n]
    if delimiter not in (",", None):
        notes.append(f"delimiter {delimiter!r}")
    if decimal_comma:
        notes.append("decimal comma")
    data_lines = lines[start:]
    line_numbers = np.array([n for n, _ in numbered[start:]], np.int64)
    first = [_split(line, delimiter) for line in data_lines[:SAMPLE_LINES]]
    widths = [len(r) for r in first]
    n_cols, width = max(widths), max(sorted(set(widths)), key=widths.count)
    # columns past the rows' usual width are checked to be empty in every row (else refused)
    filled = [j for j in range(width) if any(j < len(r) and r[j] for r in first)]
    header = start > 0
    if header:
        names = _split(lines[start - 1], delimiter)
        # pandas' to_csv leaves its row index's column unnamed (",time,a,b"): still a header
        if len(names) < len(filled) or any(not names[j] for j in filled if j > 0):
            header = False  # a title line, or a header that does not name every data column
    titles = start - (1 if header else 0)
    if titles:
        title = " ".join(_split(lines[0], delimiter))[:40]
        notes.append(f"{titles} title line(s) above the data skipped ({title!r})")
    if not header:
        names = [f"col{j + 1}" for j in range(n_cols)]
    dropped = [j for j in range(n_cols) if j not in filled]
    if dropped:
        notes.append(f"{len(dropped)} empty column(s) dropped")
    values = _parse(data_lines, delimiter, decimal_comma, filled, line_numbers, path,
                    [names[j] for j in filled])  # fmt: skip
    if dropped:
        _check_empty(data_lines, delimiter, dropped, line_numbers, path)
    return Table(values, [names[j] for j in filled], line_numbers, header, notes)


def _parse(lines: list[str], delimiter: str | None, decimal_comma: bool, cols: list[int],
           line_numbers: np.ndarray, path: Path, names: list[str]) -> np.ndarray:  # fmt: skip
    """``lines`` -> float64 ``[rows, len(cols)]`` (NumPy's C parser; on failure, the first bad
    cell is found line by line and named)."""
    if delimiter is not None and '"' in lines[0]:  # quoted cells: split by the csv module
        return _parse_cells(lines, delimiter, decimal_comma, cols, line_numbers, path, names)
    if decimal_comma:
        lines = [line.replace(",", ".") for line in lines]
    clean = [line.replace('"', "") for line in lines] if '"' in lines[0] else lines
    try:
        values = np.loadtxt(clean, delimiter=delimiter, usecols=cols, dtype=np.float64, ndmin=2,
                            comments=None)  # fmt: skip
    except ValueError:
        values = None
    if values is None or values.shape[0] != len(lines):
        for k, line in enumerate(clean):
            cells = _split(line, delimiter)
            for c, j in zip(names, cols, strict=True):
                cell = cells[j] if j < len(cells) else ""
                if not _is_number(cell, False):
                    what = "an empty cell" if not cell else f"{cell[:40]!r}"
                    raise ValueError(f"{path}: line {line_numbers[k]}, column {j + 1} ({c!r}) "
                                     f"holds {what}, not a number; fill or delete that row")  # fmt: skip
        raise ValueError(f"{path}: could not read the numbers")  # not reached: a cell is named
    bad = np.argwhere(~np.isfinite(values))
    if len(bad):
        r, c = bad[0]
        raise ValueError(f"{path}: line {line_numbers[r]}, column {cols[c] + 1} ({names[c]!r}) "
                         f"holds {values[r, c]} ({len(bad)} non-finite cell(s) in all); fill "
                         "or delete those rows")  # fmt: skip
    return values


def _parse_cells(lines: list[str], delimiter: str, decimal_comma: bool, cols: list[int],
                 line_numbers: np.ndarray, path: Path, names: list[str]) -> np.ndarray:  # fmt: skip
    """Quoted ``lines`` -> float64 ``[rows, len(cols)]``, cell by cell (a quoted cell may hold
    the delimiter or a decimal comma); the first bad cell is named."""
    out = np.empty((len(lines), len(cols)), np.float64)
    for k, row in enumerate(csv.reader(lines, delimiter=delimiter)):
        for i, j in enumerate(cols):
            cell = row[j].strip() if j < len(row) else ""
            if decimal_comma:
                cell = cell.replace(",", ".")
            if not _is_number(cell, False):
                what = "an empty cell" if not cell else f"{cell[:40]!r}"
                raise ValueError(f"{path}: line {line_numbers[k]}, column {j + 1} "
                                 f"({names[i]!r}) holds {what}, not a number; fill or delete "
                                 "that row")  # fmt: skip
            out[k, i] = float(cell)
    bad = np.argwhere(~np.isfinite(out))
    if len(bad):
        r, c = bad[0]
        raise ValueError(f"{path}: line {line_numbers[r]}, column {cols[c] + 1} ({names[c]!r}) "
                         f"holds {out[r, c]}; fill or delete those rows")  # fmt: skip
    return out


def _check_empty(lines: list[str], delimiter: str | None, dropped: list[int],
                 line_numbers: np.ndarray, path: Path) -> None:  # fmt: skip
    """A column taken for empty from the first rows must be empty in every row."""
    for k, line in enumerate(lines):
        cells = _split(line, delimiter)
        for j in dropped:
            if j < len(cells) and cells[j]:
                raise ValueError(f"{path}: line {line_numbers[k]}, column {j + 1} holds "
                                 f"{cells[j][:40]!r}, a column the other rows leave empty; "
                                 "clear that cell or fill the column")  # fmt: skip

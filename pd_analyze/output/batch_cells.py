"""CSV lines of a table batch, column by column in Arrow: the bytes `csv.writer` writes for the same rows.

`CsvWriter.line` formats a row's cells one by one in Python; here each column is formatted at once with
pyarrow compute (casts, regular expressions, joins) and the lines are one string buffer, written as
is. The cells are today's: times `2026-01-01 00:00:00.026500+00:00`, floats as Python's repr, True and
False, missing as an empty cell, text a spreadsheet would run prefixed with an apostrophe; and a cell is
quoted exactly where `csv.writer` (QUOTE_MINIMAL, lineterminator "\\n") quotes it, so the files are the
same byte for byte.
"""

from __future__ import annotations

import csv
from collections.abc import Callable
from functools import cache

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pd_analyze.analysis.schema import COLUMNS, TIME, Column

_L = pa.large_string()
# writers._NUMBER for RE2: Python's \d is any Unicode decimal digit, and its $ also
# matches before a newline that ends the text (RE2's $ matches only at the very end).
_NUMBER_TOKEN = r"([+-]?(\p{Nd}+(\.\p{Nd}*)?|\.\p{Nd}+)([eE][+-]?\p{Nd}+)?|[+-]?inf|nan)"
_NUMBER = rf"^{_NUMBER_TOKEN}( {_NUMBER_TOKEN})*\n?$"


def _text(text: str) -> pa.Scalar:
    return pa.scalar(text, _L)


@cache
def _quoted_chars() -> str:
    """The characters that make csv.writer quote a cell (with lineterminator "\\n"): asked of csv itself,
    since Python versions differ (3.11 leaves a lone carriage return unquoted)."""
    line = csv.writer(_Returned, lineterminator="\n").writerow
    return "".join(ch for ch in ',"\r\n' if line([f"a{ch}b"]).startswith('"'))


class _Returned:
    @staticmethod
    def write(text: str) -> str:
        return text


def _string_buffers(values: pa.Array) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (n + 1, into the second) and UTF-8 bytes of a large_string array, without copies."""
    n = len(values)
    buffers = values.buffers()
    if not n or buffers[1] is None:
        return np.zeros(n + 1, np.int64), np.zeros(0, np.uint8)
    offsets = np.frombuffer(buffers[1], dtype=np.int64)[values.offset:values.offset + n + 1]
    return offsets, (np.frombuffer(buffers[2], dtype=np.uint8) if buffers[2] is not None else np.zeros(0, np.uint8))


def _byte_table(chars: str) -> np.ndarray:
    table = np.zeros(256, dtype=bool)
    table[[ord(c) for c in chars]] = True
    return table


_FORMULA_START = "=+-@\t\r"  # writers._FORMULA


def _column_bytes(values: pa.Array) -> bytes:
    offsets, data = _string_buffers(values)
    return data[offsets[0]:offsets[-1]].tobytes() if len(values) else b""


def _rows_holding(values: pa.Array, chars: str, text: bytes | None = None) -> np.ndarray:
    """Which cells hold any of these ASCII characters (a UTF-8 sequence never holds an ASCII byte);
    `text`: the column's bytes, when the caller has them."""
    mask = np.zeros(len(values), dtype=bool)
    text = _column_bytes(values) if text is None else text
    if not any(ch.encode() in text for ch in chars):  # memchr over the column: almost always the answer
        return mask
    offsets, data = _string_buffers(values)
    hits = np.flatnonzero(_byte_table(chars)[data[offsets[0]:offsets[-1]]]) + offsets[0]
    mask[np.searchsorted(offsets, hits, side="right") - 1] = True
    return mask


def _rows_starting(values: pa.Array, chars: str, text: bytes) -> np.ndarray:
    """Which cells start with one of these ASCII characters (an empty or missing cell does not)."""
    mask = np.zeros(len(values), dtype=bool)
    if not any(ch.encode() in text for ch in chars):  # none anywhere in the column
        return mask
    offsets, data = _string_buffers(values)
    starts = offsets[:-1]
    nonempty = offsets[1:] > starts
    mask[nonempty] = _byte_table(chars)[data[starts[nonempty]]]
    return mask


def float_text(values: pa.Array) -> pa.Array:
    """float64 values (no NaN) as Python's repr writes them: shortest round trip, `1.0`, `1e-05`, `inf`."""
    text = pc.cast(values, _L)
    x = np.abs(values.to_numpy(zero_copy_only=False))  # nulls come as NaN: compare False below
    with np.errstate(invalid="ignore"):
        positional = ((x >= 1e-4) & (x < 1e16)) | (x == 0) | np.isinf(x)  # where repr writes no exponent
        whole = positional & (x == np.floor(x)) & np.isfinite(x)  # repr writes 5.0, Arrow 5
    scientific = _rows_holding(text, "e")  # where Arrow writes an exponent
    odd = positional == scientific  # the notations differ: repr() those cells
    odd &= values.is_valid().to_numpy(zero_copy_only=False)
    if scientific.any():  # repr's exponent has two digits at least: 1e-07, not 1e-7
        text = pc.replace_substring_regex(text, r"e([+-])(\d)$", "e\\10\\2")
    fix = whole & ~odd
    if fix.any():
        text = pc.if_else(pa.array(fix), pc.binary_join_element_wise(text, _text(".0"), _text("")), text)
    if odd.any():
        fixed = [repr(v) for v in values.filter(pa.array(odd)).to_pylist()]
        text = pc.replace_with_mask(text, pa.array(odd), pa.array(fixed, _L))
    return text


_TIME_TEMPLATE = np.frombuffer(b"0000-00-00 00:00:00.000000+00:00", dtype=np.uint8)
_PAIRS = np.array([ord(str(i // 10)) | ord(str(i % 10)) << 8 for i in range(100)], dtype="<u2")  # "00" ... "99"


def time_text(values: pa.Array) -> pa.Array:
    """timestamp[us, UTC] as writers.csv_time: `2026-01-01 00:00:00.026500+00:00`, microseconds always.

    Every such cell is 32 characters (the years a table holds have four digits), so the text is built
    as a block of bytes, two digits at a time; the civil date of a day by H. Hinnant's civil_from_days."""
    us = pc.fill_null(pc.cast(values, pa.int64()), 0).to_numpy(zero_copy_only=False)
    days, rest = np.divmod(us, 86_400_000_000)
    seconds, micros = np.divmod(rest, 1_000_000)
    z = days + 719_468
    era = np.floor_divide(z, 146_097)
    doe = z - era * 146_097
    yoe = (doe - doe // 1460 + doe // 36_524 - doe // 146_096) // 365
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    month = np.where(mp < 10, mp + 3, mp - 9)
    year = yoe + era * 400 + (month <= 2)
    out = np.tile(_TIME_TEMPLATE, (len(us), 1))
    even = out.view("<u2")  # two characters at even positions ...
    odd = out[:, 1:31].view("<u2")  # ... and at odd ones (position p: column (p - 1) // 2)
    even[:, 0] = _PAIRS[year // 100]
    even[:, 1] = _PAIRS[year % 100]
    odd[:, 2] = _PAIRS[month]  # position 5
    even[:, 4] = _PAIRS[doy - (153 * mp + 2) // 5 + 1]
    odd[:, 5] = _PAIRS[seconds // 3600]  # 11
    even[:, 7] = _PAIRS[seconds // 60 % 60]
    odd[:, 8] = _PAIRS[seconds % 60]  # 17
    even[:, 10] = _PAIRS[micros // 10_000]
    even[:, 11] = _PAIRS[micros // 100 % 100]
    even[:, 12] = _PAIRS[micros % 100]
    offsets = pa.py_buffer(np.arange(0, 32 * len(us) + 1, 32, dtype=np.int64))
    text = pa.Array.from_buffers(_L, len(us), [None, offsets, pa.py_buffer(out)])
    return pc.if_else(values.is_valid(), text, pa.scalar(None, _L)) if values.null_count else text


def int_text(values: pa.Array) -> pa.Array:
    """int64 values as str() writes them; a column of few distinct values (ids, counts) through a table of
    the texts of its range, which costs a gather instead of a conversion per cell."""
    if len(values) > 64 and values.null_count < len(values):
        low, high = pc.min_max(values).values()
        low, high = low.as_py(), high.as_py()
        if high - low < len(values) // 4:
            texts = pc.cast(pa.array(np.arange(low, high + 1, dtype=np.int64)), _L)
            return texts.take(pc.subtract(values, pa.scalar(low, pa.int64())))
    return pc.cast(values, _L)


def _few(values: pa.Array, text: Callable[[pa.Array], pa.Array]) -> pa.Array:
    """`text` of each distinct value once when the values repeat (latencies measured in whole
    microseconds of capture time do), else of every cell."""
    if len(values) > 64:
        encoded = pc.dictionary_encode(values)
        if 2 * len(encoded.dictionary) <= len(values):
            return text(encoded.dictionary).take(encoded.indices)
    return text(values)


def neutralised(values: pa.Array, text: bytes | None = None) -> pa.Array:
    """Text cells a spreadsheet would run as a formula, with a leading apostrophe (writers.neutralise);
    `text`: the column's bytes, when the caller has them."""
    formula = _rows_starting(values, _FORMULA_START, _column_bytes(values) if text is None else text)
    if not formula.any():
        return values
    run = pc.and_(pa.array(formula), pc.invert(pc.match_substring_regex(values, _NUMBER)))
    return pc.if_else(run, pc.binary_join_element_wise(_text("'"), values, _text("")), values)


def quoted(values: pa.Array, text: bytes | None = None) -> pa.Array:
    """Text cells quoted where csv.writer quotes them, quotes inside doubled; `text` as for neutralised."""
    need = _rows_holding(values, _quoted_chars(), text)
    if not need.any():
        return values
    body = pc.replace_substring(values, '"', '""')
    return pc.if_else(pa.array(need), pc.binary_join_element_wise(_text('"'), body, _text('"'), _text("")), values)


def text_cells(values: pa.Array) -> pa.Array:
    """A text column's CSV cells: neutralised, then quoted (the column's bytes read once when neither
    changes a cell, as for nearly every column)."""
    text = _column_bytes(values)
    # an apostrophe added is no character that needs quotes: the bytes before say where quotes may be needed
    return quoted(neutralised(values, text), text)


def _cells(col: Column, values: pa.Array) -> pa.Array:
    """One column's CSV cells (null for an empty cell)."""
    if col.dtype == TIME:
        return time_text(values)
    if col.dtype == "Float64":
        return _few(values, float_text)
    if col.dtype == "boolean":
        return pc.if_else(values, _text("True"), _text("False"))
    if col.dtype == "Int64":
        return int_text(values)
    return text_cells(values)


def csv_lines(name: str, batch: pa.RecordBatch) -> pa.Array:
    """The CSV lines of a batch (columns of batch_schema(name)), each ending in a newline."""
    cells = [_cells(c, batch.column(i)) for i, c in enumerate(COLUMNS[name])]
    last = pc.fill_null(cells[-1], _text(""))
    cells[-1] = pc.binary_join_element_wise(last, _text(""), _text("\n"))  # the line's end: a pass over one column
    return pc.binary_join_element_wise(*cells, _text(","), null_handling="replace", null_replacement="")


def string_data(values: pa.Array) -> memoryview:
    """The characters of a large_string array without nulls, end to end, as UTF-8 bytes."""
    if len(values) == 0:
        return memoryview(b"")
    offsets = np.frombuffer(values.buffers()[1], dtype=np.int64)
    return memoryview(values.buffers()[2])[offsets[values.offset]:offsets[values.offset + len(values)]]

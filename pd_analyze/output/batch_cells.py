"""CSV lines of a table batch, column by column in Arrow: the bytes `csv.writer` writes for the same rows.

`CsvWriter.line` formats a row's cells one by one in Python; here each column is formatted at once with
pyarrow compute (casts, regular expressions, joins) and the lines are one string buffer, written as
is. The cells are the row path's: times `2026-01-01 00:00:00.026500+00:00` and durations `0.001499` at
each row's capture's resolution (model.times), True and False, missing as an empty cell, text a
spreadsheet would run prefixed with an apostrophe; and a cell is quoted exactly where `csv.writer`
(QUOTE_MINIMAL, lineterminator "\\n") quotes it, so the files are the same byte for byte.
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Mapping
from functools import cache

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pd_analyze.analysis.schema import COLUMNS, TIME, Column
from pd_analyze.model.times import DEFAULT_DIGITS, MAX_DIGITS, NS

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


def duration_text(values: pa.Array, digits: int | np.ndarray) -> pa.Array:
    """Seconds (float64) as model.times.duration_text writes them at `digits` decimals (one number, or one per
    row): the integer of the last decimal, split at the point, trailing zeros dropped but one."""
    x = values.to_numpy(zero_copy_only=False)  # nulls come as NaN: not finite, so left to the end
    with np.errstate(invalid="ignore", over="ignore"):
        scaled = np.rint(x * 10.0 ** np.asarray(digits, np.float64))
        exact = np.isfinite(scaled) & (np.abs(scaled) < _EXACT)
    k = np.abs(np.where(exact, scaled, 0)).astype(np.int64)
    unit = np.broadcast_to(10 ** np.asarray(digits, np.int64), k.shape)
    whole, frac = np.divmod(k, unit)
    # the fraction with its leading zeros: unit + frac written, its leading 1 cut off, then trailing zeros
    decimals = pc.utf8_rtrim(pc.utf8_slice_codeunits(pc.cast(pa.array(unit + frac), _L), 1), characters="0")
    decimals = pc.if_else(pc.equal(decimals, _text("")), _text("0"), decimals)
    sign = pc.if_else(pa.array(scaled < 0), _text("-"), _text(""))
    text = pc.binary_join_element_wise(sign, int_text(pa.array(whole)), _text("."), decimals, _text(""))
    odd = ~exact & values.is_valid().to_numpy(zero_copy_only=False)
    if odd.any():  # infinite, or too large for the integer of its last decimal: as repr writes it
        text = pc.replace_with_mask(text, pa.array(odd), pa.array([repr(v) for v in x[odd].tolist()], _L))
    return pc.if_else(values.is_valid(), text, pa.scalar(None, _L)) if values.null_count else text


_EXACT = float(2**53)  # as model.times: the integer of a duration's last decimal is exact in a double below this
_TIME_TEMPLATE = "0000-00-00{}00:00:00.000000000{}"
_PAIRS = np.array([ord(str(i // 10)) | ord(str(i % 10)) << 8 for i in range(100)], dtype="<u2")  # "00" ... "99"
_POINT = 19  # where a time's decimal point is in the template
_ZONE = _POINT + 10  # and where its zone begins


def time_text(values: pa.Array, digits: int | np.ndarray = MAX_DIGITS, sep: str = " ",
              zone: str = "+00:00") -> pa.Array:
    """timestamp[ns, UTC] as model.times.time_text writes it, with `digits` decimals of a second (one number,
    or one per row): `2026-01-01 00:00:00.026500+00:00` at 6; JSON's with sep "T" and zone "Z".

    The cells are built as a block of bytes (the years a table holds have four digits), two digits at a time,
    with all nine decimals, then cut to the resolution. The civil date of a day by H. Hinnant's
    civil_from_days."""
    ns = pc.fill_null(pc.cast(values, pa.int64()), 0).to_numpy(zero_copy_only=False)
    days, rest = np.divmod(ns, 86_400 * NS)
    seconds, frac = np.divmod(rest, NS)
    z = days + 719_468
    era = np.floor_divide(z, 146_097)
    doe = z - era * 146_097
    yoe = (doe - doe // 1460 + doe // 36_524 - doe // 146_096) // 365
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    month = np.where(mp < 10, mp + 3, mp - 9)
    year = yoe + era * 400 + (month <= 2)
    template = np.frombuffer(_TIME_TEMPLATE.format(sep, zone).encode(), dtype=np.uint8)
    width = len(template) + len(template) % 2  # an odd width padded: the rows are read as pairs of characters
    out = np.zeros((len(ns), width), np.uint8)
    out[:, :len(template)] = template
    even = out.view("<u2")  # two characters at even positions ...
    odd = out[:, 1:width - 1].view("<u2")  # ... and at odd ones (position p: column (p - 1) // 2)
    even[:, 0] = _PAIRS[year // 100]
    even[:, 1] = _PAIRS[year % 100]
    odd[:, 2] = _PAIRS[month]  # position 5
    even[:, 4] = _PAIRS[doy - (153 * mp + 2) // 5 + 1]
    odd[:, 5] = _PAIRS[seconds // 3600]  # 11
    even[:, 7] = _PAIRS[seconds // 60 % 60]
    odd[:, 8] = _PAIRS[seconds % 60]  # 17
    even[:, 10] = _PAIRS[frac // 10_000_000]  # 20: the decimals
    even[:, 11] = _PAIRS[frac // 100_000 % 100]
    even[:, 12] = _PAIRS[frac // 1000 % 100]
    even[:, 13] = _PAIRS[frac // 10 % 100]
    out[:, 28] = ord("0") + frac % 10
    at = np.arange(width)
    d = np.asarray(digits)
    # the characters kept: all before the point, the point and `digits` decimals (none without decimals), the zone
    end = _POINT + np.where(d > 0, d + 1, 0)
    if d.ndim == 0:  # one resolution: every cell one width
        keep = (at < end) | ((at >= _ZONE) & (at < len(template)))
        cells = np.ascontiguousarray(out[:, keep])
        offsets = np.arange(len(ns) + 1, dtype=np.int64) * int(keep.sum())
    else:  # one per row: each row's characters picked, the offsets their running count
        keep = (at < end[:, None]) | ((at >= _ZONE) & (at < len(template)))
        cells = out[keep]
        offsets = np.zeros(len(ns) + 1, np.int64)
        np.cumsum(keep.sum(axis=1), out=offsets[1:])
    text = pa.Array.from_buffers(_L, len(ns), [None, pa.py_buffer(offsets), pa.py_buffer(cells)])
    return pc.if_else(values.is_valid(), text, pa.scalar(None, _L)) if values.null_count else text


def row_digits(captures: pa.Array, digits: Mapping[str, int]) -> int | np.ndarray:
    """Each row's resolution (model.times digits) by its capture, DEFAULT_DIGITS where the capture is not
    known: one number when every row has the same (one capture's rows, nearly always)."""
    encoded = pc.dictionary_encode(captures)
    known = [digits.get(c, DEFAULT_DIGITS) for c in encoded.dictionary.to_pylist()]
    if encoded.null_count:
        known.append(DEFAULT_DIGITS)
    if len(set(known)) <= 1:
        return known[0] if known else DEFAULT_DIGITS
    index = pc.fill_null(encoded.indices, len(known) - 1).to_numpy(zero_copy_only=False)
    return np.array(known, np.int64)[index]


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
    """`text` of each distinct value once when the values repeat (latencies of a microsecond capture
    often do), else of every cell."""
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


def _cells(col: Column, values: pa.Array, digits: int | np.ndarray) -> pa.Array:
    """One column's CSV cells (null for an empty cell); `digits`: the rows' resolution (row_digits)."""
    if col.dtype == TIME:
        return time_text(values, digits)
    if col.dtype == "Float64":  # (the tables' floats are durations, in seconds)
        if np.ndim(digits):
            return duration_text(values, digits)
        return _few(values, lambda v: duration_text(v, digits))
    if col.dtype == "boolean":
        return pc.if_else(values, _text("True"), _text("False"))
    if col.dtype == "Int64":
        return int_text(values)
    return text_cells(values)


def csv_lines(name: str, batch: pa.RecordBatch, digits: Mapping[str, int]) -> pa.Array:
    """The CSV lines of a batch (columns of batch_schema(name)), each ending in a newline; `digits`: each
    capture's resolution (Rows.digits)."""
    places = row_digits(batch.column("capture"), digits)
    cells = [_cells(c, batch.column(i), places) for i, c in enumerate(COLUMNS[name])]
    last = pc.fill_null(cells[-1], _text(""))
    cells[-1] = pc.binary_join_element_wise(last, _text(""), _text("\n"))  # the line's end: a pass over one column
    return pc.binary_join_element_wise(*cells, _text(","), null_handling="replace", null_replacement="")


def string_data(values: pa.Array) -> memoryview:
    """The characters of a large_string array without nulls, end to end, as UTF-8 bytes."""
    if len(values) == 0:
        return memoryview(b"")
    offsets = np.frombuffer(values.buffers()[1], dtype=np.int64)
    return memoryview(values.buffers()[2])[offsets[values.offset]:offsets[values.offset + len(values)]]

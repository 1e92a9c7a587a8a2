"""The table cells of a batch's value blocks, as columns: `analysis.rows.block_values` of each block.

Numbers are gathered from the buffer by format size and converted with numpy and pyarrow (decimal
casts, hexadecimal digits from a lookup table); floats are formatted once per distinct bit pattern;
strings, octets and unicode (rare) are made per block in Python, as `rows._cell` makes them. The
cells are then joined per block with single spaces. The format categories here are also the decode's
table of value sizes (`SIZE`).
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pd_analyze.model import pd_values as pt

# How a format's values become text (protocol.profidrive_view.value_of, analysis.rows.block_values)
NONE, SIGNED, UNSIGNED, HEX, FLOAT, STRING, OCTETS, UNICODE, UNSIZED = range(9)
_KIND_CATEGORY = {"bool": UNSIGNED, "int": SIGNED, "uint": UNSIGNED, "float": FLOAT, "hex": HEX, "bits": HEX,
                  "nibbles": HEX, "n2": SIGNED, "n4": SIGNED, "e2": SIGNED, "c4": SIGNED, "t2": UNSIGNED,
                  "time_date": UNSIGNED, "string": STRING, "octets": OCTETS, "unicode": UNICODE,
                  "zero": NONE, "error": NONE}


def _tables() -> tuple[np.ndarray, np.ndarray]:
    """Per format code: bytes per value (-1: no size the columns can use, i.e. unknown formats and the
    Date, whose size the per-frame parse may have to guess) and text category."""
    size = np.full(256, -1, np.int64)
    category = np.full(256, UNSIZED, np.int8)
    for code, spec in pt.FORMATS.items():
        if code == pt.FMT_DATE:
            continue
        size[code] = spec.size
        # value_of shows a kind it does not name as the unsigned integer
        category[code] = _KIND_CATEGORY.get(spec.kind, UNSIGNED)
    return size, category


SIZE, CATEGORY = _tables()
_HEX_DIGITS = np.frombuffer(b"0123456789abcdef", np.uint8)


def block_text(b: np.ndarray, fmt: np.ndarray, n_values: np.ndarray, data_start: np.ndarray,
               data_len: np.ndarray) -> pa.Array:
    """One string per block (a pyarrow string array): its values as the tables show them, "" for error
    and Zero blocks. Every block must be of a format with a SIZE."""
    n_blocks = len(fmt)
    if n_blocks == 0:
        return pa.array([], pa.string())
    category = CATEGORY[fmt]
    numeric = (category == SIGNED) | (category == UNSIGNED) | (category == HEX) | (category == FLOAT)
    textual = (category == STRING) | (category == OCTETS) | (category == UNICODE)
    entries = np.where(numeric, n_values.astype(np.int64), textual.astype(np.int64))
    offsets = np.zeros(n_blocks + 1, np.int64)
    np.cumsum(entries, out=offsets[1:])
    pieces: list[pa.Array] = []
    places: list[np.ndarray] = []
    # numbers: one group per format present; the value j of block k is entry offsets[k] + j
    for code in np.flatnonzero(np.bincount(fmt, minlength=256)):
        cat, size = int(CATEGORY[code]), int(SIZE[code])
        if cat not in (SIGNED, UNSIGNED, HEX, FLOAT):
            continue
        blocks = np.flatnonzero(fmt == code)
        counts = entries[blocks]
        total = int(counts.sum())
        if not total:
            continue
        within = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
        at = np.repeat(data_start[blocks], counts) + within * size
        places.append(np.repeat(offsets[blocks], counts) + within)
        pieces.append(_numbers(b, at, size, cat))
    strings = np.flatnonzero(textual)
    if len(strings):
        places.append(offsets[strings])
        pieces.append(pa.array([_string_cell(int(category[k]), bytes(b[data_start[k]:data_start[k] + data_len[k]]))
                                for k in strings.tolist()], pa.string()))
    if not pieces:
        return pa.array([""] * n_blocks, pa.string())
    values = pa.concat_arrays(pieces)
    where = np.concatenate(places)
    if len(where) > 1 and not (where[1:] > where[:-1]).all():  # put the entries in block and value order
        order = np.empty(len(where), np.int64)
        order[where] = np.arange(len(where))
        values = values.take(pa.array(order))
    lists = pa.ListArray.from_arrays(pa.array(offsets.astype(np.int32)), values)
    return pc.binary_join(lists, " ")


def _numbers(b: np.ndarray, at: np.ndarray, size: int, cat: int) -> pa.Array:
    """The text of the values of `size` bytes at offsets `at`, one category."""
    raw = b[at[:, None] + np.arange(size)]
    if cat == HEX:
        return _hex(raw)
    if cat == FLOAT:
        return _floats(raw, size)
    unsigned = _big_endian(raw)
    if cat == SIGNED and size < 8:
        top = np.uint64(1) << np.uint64(8 * size - 1)
        values = unsigned.astype(np.int64) - ((unsigned & top) << np.uint64(1)).astype(np.int64)
    elif cat == SIGNED:
        values = unsigned.view(np.int64)
    else:
        values = unsigned
    return pa.array(values).cast(pa.string())


def _big_endian(raw: np.ndarray) -> np.ndarray:
    """Rows of big-endian bytes (at most 8) as uint64."""
    full = np.zeros((len(raw), 8), np.uint8)
    full[:, 8 - raw.shape[1]:] = raw
    return full.view(">u8").ravel().astype(np.uint64)


def _hex(raw: np.ndarray) -> pa.Array:
    """0x followed by two lower-case digits per byte (f"0x{v:0{2 * size}x}")."""
    count, size = raw.shape
    width = 2 + 2 * size
    chars = np.empty((count, width), np.uint8)
    chars[:, 0], chars[:, 1] = ord("0"), ord("x")
    chars[:, 2::2] = _HEX_DIGITS[raw >> 4]
    chars[:, 3::2] = _HEX_DIGITS[raw & 0x0F]
    offsets = np.arange(0, (count + 1) * width, width, dtype=np.int32)
    return pa.StringArray.from_buffers(count, pa.py_buffer(offsets), pa.py_buffer(chars.tobytes()))


def _floats(raw: np.ndarray, size: int) -> pa.Array:
    """pd_values.float_text of each value (the shortest text of its width that reads back to the same
    bits; nan, inf and -inf as str() gives them), formatted once per distinct bit pattern (-0.0 is not 0.0)."""
    distinct, inverse = np.unique(_big_endian(raw), return_inverse=True)
    width = np.uint32 if size == 4 else np.uint64
    with np.errstate(invalid="ignore"):  # a signalling NaN is converted like any other
        floats = distinct.astype(width).view(np.float32 if size == 4 else np.float64).astype(np.float64)
    texts = [pt.float_text(v, size) for v in floats.tolist()]
    return pa.array(texts, pa.string()).take(pa.array(inverse.ravel()))


def _string_cell(cat: int, data: bytes) -> str:
    """rows._cell of the one value values_of gives a string, octet or unicode block."""
    if cat == OCTETS:
        return data.hex()
    text = data.decode("utf-16-be", errors="replace") if cat == UNICODE else data.decode("latin-1")
    if not text.isprintable():
        return repr(text)
    return f'"{text}"' if " " in text else text

"""What output.column_fields reads a field with: the places of its occurrences in a batch's buffer (`Piece`), and
each distinct occurrence made once as the tree's Field (`assemble` -> `Occurrences`)."""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.model.layout import Layout
from pd_analyze.model.shown import Field, View
from pd_analyze.output.frame_view import _tshark_text, _width_of

Decode = Callable[[bytes], object]


class PartRows(Protocol):
    """A part's column rows as the readers see them (output.column_fields.PartFields)."""

    view: BatchView  # the part's column decode
    rows: np.ndarray  # int64 indices into view.p
    data: np.ndarray  # uint8: the batch's buffer
    ptype: np.ndarray  # per row
    stub: np.ndarray  # bool per row: its stub is decoded in its tree as the columns decode it
    fault: np.ndarray  # bool per row: a fault or reject
    rpc_at: np.ndarray  # int64 per row: its DCE/RPC header's offset in the buffer


@dataclass(slots=True)
class Occurrences:
    """One field over a part's rows: `known` per row (the tree's occurrences are exactly these: none where the
    row has no such field); per occurrence its row (`owner`, ascending, in the tree's order within a row) and
    `code`, an index into `fields`, the distinct occurrences as the tree's Field objects."""

    known: np.ndarray
    owner: np.ndarray
    code: np.ndarray
    fields: list[Field]

    def values(self) -> list[object]:
        """Each distinct occurrence's value (FrameView.values)."""
        return [f.value for f in self.fields]

    def text_lists(self) -> list[list[str]]:
        """Each distinct occurrence as `-T fields` prints it (FrameView.shown: one text, or one per item of a
        list value)."""
        return [_tshark_text(f, 0.0) for f in self.fields]


@dataclass(slots=True)
class Piece:
    """Occurrences of one concrete field name read alike: at buf[at : at + size] of each row in `rows`."""

    name: str
    rows: np.ndarray  # int64 indices into the part's rows
    at: np.ndarray  # int64 offsets in buf
    size: int
    decode: Decode
    order: int | np.ndarray = 0  # its place (per occurrence, or for all) in a row: tags, addresses, values


def unsigned(raw: bytes) -> object:
    return int.from_bytes(raw, "big")


def entry_piece(layout: Layout, view: View, name: str, rows: np.ndarray, at: np.ndarray) -> Piece:
    """The View entry `name` of `layout` (its offset, size, source field and converter) at structures `at`."""
    entry = next(e for e in view.entries if e[0] == name)
    _name, offset, size, _memo, conv, _show, source, _k = entry
    unpack = struct.Struct(layout.order + layout.codes[source]).unpack

    def decode(raw: bytes) -> object:
        value = unpack(raw)[0]
        return value if conv is None else conv(value)
    return Piece(name, rows, at + offset, size, decode)


def sized(name: str, rows: np.ndarray, at: np.ndarray, length: np.ndarray, decode: Decode = bytes) -> list[Piece]:
    """Byte fields of varying length: one piece per length."""
    return [Piece(name, rows[length == size], at[length == size], int(size), decode)
            for size in np.unique(length).tolist()]


def _gather(data: np.ndarray, at: np.ndarray, size: int) -> np.ndarray:
    """The `size` bytes at each offset of `at`, one row each."""
    if size == 0:
        return np.zeros((len(at), 0), np.uint8)
    return data[at[:, None] + np.arange(size)]


def _distinct(raw: np.ndarray) -> tuple[np.ndarray, list[bytes]]:
    """Rows of bytes: each row's index among the distinct rows, and those rows."""
    n, size = raw.shape
    if n == 0:
        return np.zeros(0, np.int64), []
    if size <= 8:
        key = np.zeros(n, np.uint64)
        for j in range(size):
            key = (key << np.uint64(8)) | raw[:, j].astype(np.uint64)
        uniq, inverse = np.unique(key, return_inverse=True)
        return inverse.ravel(), [int(k).to_bytes(size, "big") for k in uniq.tolist()]
    uniq, inverse = np.unique(np.ascontiguousarray(raw).view(f"V{size}").ravel(), return_inverse=True)
    return inverse.ravel(), [bytes(u) for u in uniq.tolist()]


def assemble(data: np.ndarray, known: np.ndarray, pieces: list[Piece], by_offset: bool) -> Occurrences:
    owners, codes, orders, offsets = [], [], [], []
    fields: list[Field] = []
    for piece in pieces:
        rows = piece.rows[known[piece.rows]]
        if not len(rows):
            continue
        at = piece.at[known[piece.rows]]
        inverse, distinct = _distinct(_gather(data, at, piece.size))
        codes.append(inverse + len(fields))
        fields += [Field(piece.name, 0, piece.size, raw, piece.decode(raw), "") for raw in distinct]
        owners.append(rows)
        order = piece.order
        orders.append(order[known[piece.rows]] if isinstance(order, np.ndarray) else np.full(len(rows), order))
        offsets.append(at)
    if not owners:
        empty = np.zeros(0, np.int64)
        return Occurrences(known, empty, empty, fields)
    owner, code, order = np.concatenate(owners), np.concatenate(codes), np.concatenate(orders)
    # within a row: by frame offset where several fields answer one name (FrameView.fields sorts them so),
    # else in the pieces' order (tags outer first, addresses first first)
    second = np.concatenate(offsets) if by_offset else order
    sort = np.lexsort((second, owner))
    return Occurrences(known, owner[sort], code[sort], fields)


def of_width(found: Occurrences, width: int) -> Occurrences:
    """The occurrences of one width (tshark's value_b, value_w, value_dw, value_float: FrameView.fields)."""
    fit = np.array([_width_of(f) == width for f in found.fields], bool)
    keep = fit[found.code] if len(found.code) else np.zeros(0, bool)
    return Occurrences(found.known, found.owner[keep], found.code[keep], found.fields)

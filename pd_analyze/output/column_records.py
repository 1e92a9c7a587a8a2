"""The record fields of a part's column rows (output.column_fields): the IOD header's kind, a record not decoded
as PROFIdrive (record.data), the stub's trailing bytes, and a PROFIdrive record's header, addresses and blocks
(profidrive_view.annotate) as the column decode (protocol.profidrive_batch) holds them."""

from __future__ import annotations

import re

import numpy as np

from pd_analyze.model import pd_values as pt
from pd_analyze.model.values import OP_WRITE, PTYPE_RESPONSE
from pd_analyze.output.column_read import Decode, PartRows, Piece, entry_piece, sized, unsigned
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol import profidrive, rpc
from pd_analyze.protocol.profidrive_view import value_of, values_of

IOD_KINDS = (rec.WRITE_REQ, rec.WRITE_RES, rec.READ_RES, rec.READ_REQ_IMPLICIT, rec.READ_REQ)
_ADDRESS = (("attr", 0, 1), ("n_elems", 1, 1), ("pnu", 2, 2), ("subindex", 4, 2))  # profidrive_view.annotate
_TEXT_FORMATS = np.array(sorted(code for code, f in pt.FORMATS.items() if f.kind in ("string", "octets", "unicode")))


def iod_kind(pf: PartRows) -> np.ndarray:
    """Each row's IOD header layout (an index into IOD_KINDS, -1 without a block), as pnio.iod_layout
    chooses it for the row's own operation."""
    p, rows = pf.view.p, pf.rows
    write = p.opnum[rows] == OP_WRITE
    response = pf.ptype == PTYPE_RESPONSE
    nil = (p.ar_hi[rows] == 0) & (p.ar_lo[rows] == 0)
    kind = np.select([write & ~response, write & response, response, nil, np.ones(len(rows), bool)],
                     [0, 1, 2, 3, 4])
    return np.where(pf.stub & p.has_block[rows], kind, -1)


def _record_bounds(pf: PartRows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row: does its IOD block carry a record (a write request's, a read response's), where the record
    starts in buf, and the bytes the stub holds after the IOD header."""
    p, rows = pf.view.p, pf.rows
    kind = iod_kind(pf)
    carries = (kind == 0) | (kind == 2)
    start = pf.rpc_at + rpc.HEADER_SIZE + rec.NDR_SIZE + rec.IOD_SIZE
    after = p.body_len[rows].astype(np.int64) - rec.NDR_SIZE - rec.IOD_SIZE
    return carries, start, after


def record(pf: PartRows, name: str, exact: str) -> tuple[np.ndarray, list[Piece]] | None:
    """record.data (a record not decoded as PROFIdrive, whole in a column row) and record.trailing (the stub's
    bytes after the record, or after a header that carries none)."""
    p, rows = pf.view.p, pf.rows
    carries, start, after = _record_bounds(pf)
    has_block = iod_kind(pf) >= 0
    record_len = p.record_len[rows].astype(np.int64)
    if name == "record.data":
        mine = np.flatnonzero(carries & (pf.view.rec_of[rows] < 0))
        return pf.stub | pf.fault, sized(name, mine, start[mine], record_len[mine])
    if name == "record.trailing":
        used = np.where(carries, record_len, 0)
        trailing = np.where(has_block, after - used, 0)
        mine = np.flatnonzero(trailing > 0)
        return pf.stub | pf.fault, sized(name, mine, start[mine] + used[mine], trailing[mine])
    return None


def pd(pf: PartRows, name: str, exact: str) -> tuple[np.ndarray, list[Piece]] | None:
    """A PROFIdrive record's header and addresses (profidrive_view.annotate), of the regular records the
    columns decoded; the blocks' fields are not read here (unknown where a record has blocks)."""
    view, rows = pf.view, pf.rows
    p, r = view.p, view.records.records
    rec_of = view.rec_of[rows]
    parsed = pf.stub & (rec_of >= 0)
    known = pf.stub | pf.fault
    at = p.rec_start[rows].astype(np.int64)
    response = pf.ptype == PTYPE_RESPONSE
    if name in ("pd.ref", "pd.req_id", "pd.resp_id", "pd.do", "pd.n_params"):
        pieces = []
        for layout, side in ((profidrive.HEADER, ~response), (profidrive.RESPONSE_HEADER, response)):
            if name in layout.positions:
                mine = np.flatnonzero(parsed & side)
                pieces.append(entry_piece(layout, layout.view, name, mine, at[mine]))
        return known, pieces
    if name.startswith("pd.addr[i]."):
        part = name.rpartition(".")[2]
        offset, size = next((off, size) for key, off, size in _ADDRESS if key == part)
        n_addr = _of_record(r.n_addr, rec_of, parsed)
        pieces = []
        for k in range(int(n_addr.max()) if len(n_addr) else 0):
            concrete = f"pd.addr[{k}].{part}"
            if exact and exact != concrete:
                continue
            mine = np.flatnonzero(n_addr > k)
            pieces.append(Piece(concrete, mine, at[mine] + 4 + 6 * k + offset, size, unsigned, k))
        return known, pieces
    if name == "pd.trailing":  # the bytes after the parsed record (profidrive_view.annotate)
        end = _of_record(r.end, rec_of, parsed)
        length = p.rec_len[rows].astype(np.int64)
        mine = np.flatnonzero(parsed & (end < length))
        return known, sized(name, mine, at[mine] + end[mine], length[mine] - end[mine], bytes.hex)  # shown as hex
    if name.startswith("pd.val["):
        return _blocks(pf, name, exact, parsed, known)
    return None


def _blocks(pf: PartRows, name: str, exact: str, parsed: np.ndarray,
            known: np.ndarray) -> tuple[np.ndarray, list[Piece]] | None:
    """The fields of the value, Zero and error blocks (profidrive_view._block_fields) of the parsed records.
    A block of a description's size is shown as the description elements when its address asks for one (a
    response's: its request's, as the pairing finds it): its record's rows are unknown here."""
    view, rows = pf.view, pf.rows
    r, k = view.records.records, view.records.blocks
    rec_of = view.rec_of[rows]
    row_of = np.full(len(r.regular), -1, np.int64)
    row_of[rec_of[parsed]] = np.flatnonzero(parsed)
    owner = row_of[k.record] if len(k.record) else np.zeros(0, np.int64)
    mine = np.flatnonzero(owner >= 0)
    owner, fmt = owner[mine], k.format[mine].astype(np.int64)
    start, length, m = k.data_start[mine].astype(np.int64), k.data_len[mine].astype(np.int64), k.n_values[mine]
    position, pad = mine - r.first_block[k.record[mine]], k.pad[mine]
    error = fmt == pt.FMT_ERROR
    described = ~error & (length == pt.DESCRIPTION_SIZE)
    known = known.copy()
    known[owner[described]] = False
    part = name[len("pd.val[i]."):]
    if part.startswith("desc."):
        return known, []
    wanted = _indexes(exact)
    if wanted:
        keep = position == wanted[0]
        owner, fmt, start, length, m, position, pad, error = (
            a[keep] for a in (owner, fmt, start, length, m, position, pad, error))
    order = position * 1024
    if part in ("format", "n_values"):
        at = start - (2 if part == "format" else 1)
        return known, [Piece(name, owner, at, 1, unsigned, order)]
    if part == "pad":
        with_pad = pad >= 0
        return known, [Piece(name, owner[with_pad], (start + length)[with_pad], 1, unsigned, order[with_pad])]
    if part in ("error", "error_subindex"):
        word = 0 if part == "error" else 1
        mine = error & (m > word)
        return known, [Piece(name, owner[mine], start[mine] + 2 * word, 2, unsigned, order[mine])]
    if part == "string":
        text = np.isin(fmt, _TEXT_FORMATS) & ~error
        return known, [Piece(name, owner[text & (fmt == code) & (length == size)],
                              start[text & (fmt == code) & (length == size)], size, _text_value(code),
                              order[text & (fmt == code) & (length == size)])
                       for code, size in sorted(set(zip(fmt[text].tolist(), length[text].tolist(), strict=True)))]
    if part == "value[j]":
        return known, _values(owner, fmt, start, m, order, error, wanted[1] if len(wanted) > 1 else -1)
    return None


def _values(owner: np.ndarray, fmt: np.ndarray, start: np.ndarray, m: np.ndarray, order: np.ndarray,
            error: np.ndarray, only: int) -> list[Piece]:
    """pd.val[i].value[j]: each value of a numeric block, and an error block's words after the first two."""
    pieces = []
    numeric = ~error & ~np.isin(fmt, _TEXT_FORMATS)
    for code in np.unique(fmt[numeric]).tolist():
        size = pt.FORMATS[code].size
        blocks = np.flatnonzero(numeric & (fmt == code))
        count = m[blocks].astype(np.int64)
        each = np.repeat(blocks, count)
        j = np.arange(len(each)) - np.repeat(np.cumsum(count) - count, count)
        if only >= 0:
            each, j = each[j == only], j[j == only]
        pieces.append(Piece("pd.val[i].value[j]", owner[each], start[each] + size * j, size, _number(code),
                             order[each] + j))
    blocks = np.flatnonzero(error & (m > 2))
    count = m[blocks].astype(np.int64) - 2
    each = np.repeat(blocks, count)
    j = np.arange(len(each)) - np.repeat(np.cumsum(count) - count, count) + 2
    if only >= 0:
        each, j = each[j == only], j[j == only]
    pieces.append(Piece("pd.val[i].value[j]", owner[each], start[each] + 2 * j, 2, unsigned, order[each] + j))
    return pieces


def _number(code: int) -> Decode:
    return lambda raw: value_of(code, raw)[0]


def _text_value(code: int) -> Decode:
    """A string block's one value (profidrive_view.values_of)."""
    spec = pt.FORMATS[code]
    return lambda raw: values_of(profidrive.Block(0, code, len(raw) // max(spec.size, 1), spec.size, raw))[0][2]


def _indexes(exact: str) -> list[int]:
    """The indexes of a concrete name: pd.val[2].value[1] -> [2, 1]; none for a name without them."""
    return [int(i) for i in re.findall(r"\[(\d+)\]", exact)] if exact else []


def _of_record(column: np.ndarray, rec_of: np.ndarray, parsed: np.ndarray) -> np.ndarray:
    """A record column per row (int64), 0 for the rows without a parsed record."""
    out = np.zeros(len(rec_of), np.int64)
    out[parsed] = column[rec_of[parsed]]
    return out

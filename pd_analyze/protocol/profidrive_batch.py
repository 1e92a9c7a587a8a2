"""PROFIdrive parameter requests and responses of a batch decoded as columns (protocol.md 3, 4).

The same decode as `profidrive.parse_request` / `parse_response` and the table cells of
`analysis.rows.block_values`, applied to many records at once: the header of each record, its
parameter addresses (requests) exploded one row each, its value and error blocks walked position by
position over all records together. A record whose parse is not ordinary is `regular = False` and its
frame goes to the per-frame dissector: a record shorter than its header or than its addresses, an
unknown Response ID, a block overrunning the record, a format of unknown size, a Date (0x32), a pad byte
missing before a following block (the per-frame parse looks ahead there), the AKD address echo, a
header-level error (fewer blocks than parameters), a change request with fewer value blocks than
addresses, a record of No. of parameters 0 (its table row and a negative answer's one error block are
the per-frame path's), a Request or Response ID of the selected profile's own (protocol.md 5.5).

More precisely, whatever may make the per-frame parse report a structural finding other than
pad_nonzero / pad_missing_final (pd_too_short, pd_response_too_short, block_overrun,
response_block_overrun, change_blocks for fewer blocks, format_unsupported(_stop), pad_missing,
date_padded, akd_address_echo, header_level_error, pd_response_truncated) is irregular: so is a
non-zero byte where a pad byte goes before another block (the parse looks ahead to choose), and a pad
note on a one-block response longer than 10 bytes (the parse then tries the echo). A regular record
decodes to exactly the header, addresses and blocks of the reference (`parsed` rebuilds them), with
`complete` True and no echo.

`flag` marks the records on which a P or Q rule of the record alone may report something (limits of
the generic and vendor profiles, P5-P10, Q1, Q6-Q13 as far as they need no request; the pad findings
pad_nonzero and pad_missing_final; F3): the caller has their findings made by the per-frame checks. Q7's
No. of values against the request is the caller's, as are Q2-Q5. Every irregular record is flagged too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pd_analyze.model import pd_values as pt
from pd_analyze.protocol import profidrive
from pd_analyze.protocol import profidrive_batch_checks as batch_checks
from pd_analyze.protocol import profidrive_batch_text as batch_text
from pd_analyze.protocol.profidrive_checks import Checker

# Response IDs whose records carry blocks (3.3), and every known one (4.1), indexed by the ID
_RESPONSE_BODY = np.zeros(256, bool)
_RESPONSE_BODY[[pt.RES_READ, pt.RES_READ_NAK, pt.RES_CHANGE_NAK, pt.RES_NOT_SUPPORTED]] = True
_KNOWN_RESPONSE = _RESPONSE_BODY.copy()
_KNOWN_RESPONSE[pt.RES_CHANGE] = True


@dataclass(slots=True)
class RecordColumns:
    """One entry per record given, in the order given."""

    regular: np.ndarray  # bool
    flag: np.ndarray  # bool: a P or Q rule of the record alone may report (batch_checks.flags)
    limits_only: np.ndarray  # bool: flagged only for a limit of its header or addresses (stated from the columns)
    plausible: np.ndarray  # bool: profidrive.plausible(record, response) (index 0x002F carries PROFIdrive)
    ref: np.ndarray  # uint8 Request Reference
    ident: np.ndarray  # uint8 Request ID (requests) or Response ID (responses)
    do: np.ndarray  # uint8 DO-ID
    n: np.ndarray  # uint8 No. of parameters
    first_addr: np.ndarray  # int64: index of the record's first row in AddressColumns (requests)
    n_addr: np.ndarray  # int32: its address rows
    first_block: np.ndarray  # int64: index of the record's first row in BlockColumns
    n_blocks: np.ndarray  # int32: its block rows
    end: np.ndarray  # int64: bytes of the record the parse consumed (profidrive.Parsed.end); 0 if not regular


@dataclass(slots=True)
class AddressColumns:
    """One entry per parameter address of the (regular) requests, in record and address order."""

    record: np.ndarray  # int64 index into RecordColumns
    attr: np.ndarray  # uint8
    n_elems: np.ndarray  # uint8
    pnu: np.ndarray  # uint16
    subindex: np.ndarray  # uint16


@dataclass(slots=True)
class BlockColumns:
    """One entry per value, Zero or error block of the (regular) records, in record and block order:
    the value blocks of a change request, the blocks of a response."""

    record: np.ndarray  # int64 index into RecordColumns
    format: np.ndarray  # uint8
    n_values: np.ndarray  # uint8
    data_start: np.ndarray  # int64: offset of the first value byte in buf
    data_len: np.ndarray  # int32: n_values x the format's size
    error: np.ndarray  # int32: error number of an error block (Format 0x44), -1 otherwise
    error_subindex: np.ndarray  # int32: its second value when it has one, -1 otherwise
    pad: np.ndarray  # int16: the pad byte consumed after the block's values (Block.pad), -1 when none
    made_text: object = None  # `text` once made
    buf: np.ndarray | None = None  # the bytes `text` is made from, until it is

    @property
    def text(self) -> object:
        """The block's values as the tables show them: analysis.rows.block_values(block), "" for error and
        Zero blocks (a pyarrow string array, or a numpy object array of str); made on first use (the dump's
        paths never ask, and pyarrow's conversion of Python strings loads pandas)."""
        if self.made_text is None:
            self.made_text = batch_text.block_text(self.buf, self.format, self.n_values, self.data_start,
                                                   self.data_len)
            self.buf = None
        return self.made_text

    def __getstate__(self) -> tuple:
        """Pickled (a worker's decode sent to the engine, analysis.split): the texts made here, where the
        columns were decoded, and the buffer left behind."""
        self.text  # noqa: B018 (made now)
        return tuple(getattr(self, name) for name in self.__dataclass_fields__)

    def __setstate__(self, state: tuple) -> None:
        for name, value in zip(self.__dataclass_fields__, state, strict=True):
            object.__setattr__(self, name, value)


@dataclass(slots=True)
class DecodedRecords:
    records: RecordColumns
    addresses: AddressColumns
    blocks: BlockColumns


def decode(buf: bytes, start: np.ndarray, length: np.ndarray, response: np.ndarray,
           checker: Checker) -> DecodedRecords:
    """The records buf[start[i] : start[i] + length[i]], parameter responses where `response[i]`,
    parameter requests (write) elsewhere."""
    b = np.frombuffer(buf, np.uint8)
    start = np.asarray(start, np.int64).ravel()
    length = np.asarray(length, np.int64).ravel()
    response = np.asarray(response, bool).ravel()
    count = len(start)
    ref, ident, do, n_u8 = _header(b, start, length >= 4)
    n = n_u8.astype(np.int64)
    regular = length >= 4  # pd_too_short, pd_response_too_short
    regular &= n_u8 > 0  # No. of parameters 0: one parameter row of its own, and a negative answer's one block
    addr_end = 4 + 6 * n
    regular &= response | (length >= addr_end)  # pd_too_short: a request ends inside its addresses
    regular &= ~response | _KNOWN_RESPONSE[ident]  # Q1's unknown Response ID: the body is not decoded
    ids = checker.ids
    if ids is not None:  # a profile's own Request/Response IDs (protocol.md 5.5) are the per-frame parse's
        regular &= ~np.isin(ident, np.array([*ids.requests, *ids.responses], np.uint8))
    # the blocks each record has: a change request's one per address, a response's (3.3)
    blocks = np.zeros(count, np.int64)
    change = regular & ~response & (ident == pt.REQ_CHANGE)
    blocks[change] = n[change]
    body = regular & response & _RESPONSE_BODY[ident]
    blocks[body] = np.where((ident[body] == pt.RES_NOT_SUPPORTED) & (n[body] == 0), 1, n[body])
    first = np.where(response, 4, addr_end)
    # a pad note makes the per-frame parse try the AKD address echo on a one-block response
    echo = response & (blocks == 1) & (length > 10)
    walk = _walk(b, start, length, blocks, first, echo)
    regular &= ~walk.irregular
    end = np.where(regular, walk.end, 0)
    n_blocks = np.where(regular, blocks, 0).astype(np.int32)
    first_block = _exclusive_sum(n_blocks)
    n_addr = np.where(regular & ~response, n, 0).astype(np.int32)
    first_addr = _exclusive_sum(n_addr)
    addresses = _addresses(b, start, n_addr, first_addr)
    block_cols, position = _assemble(b, walk, regular, first_block, int(n_blocks.sum()))
    pad_note = regular & walk.pad_note
    flag, limits_only = batch_checks.flags(batch_checks.Columns(
        regular, response, length, end, pad_note, ref, ident, do, n_u8, first_addr, addresses.record,
        addresses.attr, addresses.n_elems, addresses.pnu, addresses.subindex, block_cols.record, position,
        block_cols.format, block_cols.n_values, block_cols.data_start, block_cols.data_len, block_cols.error),
        b, checker)
    plausible = _plausible(buf, start, length, response, regular, end, ref, ident, n, checker.record.max_params)
    records = RecordColumns(regular, flag, limits_only, plausible,
                            ref, ident, do, n_u8, first_addr, n_addr, first_block, n_blocks, end)
    return DecodedRecords(records, addresses, block_cols)


def _exclusive_sum(counts: np.ndarray) -> np.ndarray:
    out = np.zeros(len(counts), np.int64)
    np.cumsum(counts[:-1], out=out[1:])
    return out


def _be16(b: np.ndarray, at: np.ndarray) -> np.ndarray:
    return (b[at].astype(np.int32) << 8) | b[at + 1]


def _header(b: np.ndarray, start: np.ndarray, present: np.ndarray) -> list[np.ndarray]:
    """The header fields (profidrive.HEADER: one byte each, the same offsets for requests and
    responses) of the records that have one; 0 elsewhere."""
    at = start[present]
    out = []
    for offset, code in zip(profidrive.HEADER.offsets, profidrive.HEADER.codes, strict=True):
        assert code == "B"  # one byte per field: a plain gather
        column = np.zeros(len(start), np.uint8)
        column[present] = b[at + offset]
        out.append(column)
    return out


@dataclass(slots=True)
class _Walk:
    """The blocks found, position by position: per position a tuple of the records' indices and
    their blocks' format, No. of values, data start, data length and pad byte (-1 none)."""

    rounds: list[tuple[np.ndarray, ...]]
    end: np.ndarray  # int64: record-relative end of the parse
    irregular: np.ndarray  # bool
    pad_note: np.ndarray  # bool: pad_nonzero or pad_missing_final reported


def _walk(b: np.ndarray, start: np.ndarray, length: np.ndarray, blocks: np.ndarray, first: np.ndarray,
          echo: np.ndarray) -> _Walk:
    """profidrive._blocks over every record at once: one round per block position."""
    walk = _Walk([], first.copy(), np.zeros(len(start), bool), np.zeros(len(start), bool))
    rec = np.flatnonzero(blocks > 0)
    pos = first[rec]
    i = 0
    while len(rec):
        st, size_left = start[rec], length[rec] - pos
        # block_overrun / truncation before all blocks: the record ends before Format and No. of values
        ok = size_left >= 2
        walk.irregular[rec[~ok]] = True
        rec, pos, st, size_left = rec[ok], pos[ok], st[ok], size_left[ok]
        fmt = b[st + pos]
        m = b[st + pos + 1]
        need = batch_text.SIZE[fmt] * m
        # format_unsupported(_stop), Date (its size may be guessed), values overrunning the record
        ok = (batch_text.SIZE[fmt] >= 0) & (need <= size_left - 2)
        walk.irregular[rec[~ok]] = True
        rec, pos, st, fmt, m, need = rec[ok], pos[ok], st[ok], fmt[ok], m[ok], need[ok]
        end = pos + 2 + need
        left = length[rec] - end
        more = i < blocks[rec] - 1
        odd = (need & 1).astype(bool)  # error blocks are even
        follows = left >= 1
        byte = np.full(len(rec), -1, np.int64)
        byte[follows] = b[st[follows] + end[follows]]
        take = odd & ((left == 1) | (more & (byte == 0)))
        # a non-zero byte where a pad byte should be, before another block: the per-frame parse
        # looks ahead (pad_missing or pad_nonzero)
        walk.irregular[rec[odd & more & (left >= 2) & (byte != 0)]] = True
        note = (take & (byte != 0)) | (odd & (left == 0) & ~more)  # pad_nonzero, pad_missing_final
        walk.pad_note[rec[note]] = True
        walk.irregular[rec[note & echo[rec]]] = True
        end = end + take
        walk.rounds.append((rec, fmt, m, st + pos + 2, need, np.where(take, byte, -1)))
        walk.end[rec] = end
        again = more & ~walk.irregular[rec]
        rec, pos = rec[again], end[again]
        i += 1
    return walk


def _assemble(b: np.ndarray, walk: _Walk, regular: np.ndarray, first_block: np.ndarray,
              total: int) -> tuple[BlockColumns, np.ndarray]:
    """The blocks of the regular records in record and block order, and each one's position."""
    record = np.zeros(total, np.int64)
    position = np.zeros(total, np.int64)
    fmt = np.zeros(total, np.uint8)
    m = np.zeros(total, np.uint8)
    data_start = np.zeros(total, np.int64)
    data_len = np.zeros(total, np.int32)
    pad = np.full(total, -1, np.int16)
    for i, (rec, f, count, at, need, pad_byte) in enumerate(walk.rounds):
        keep = regular[rec]
        rec = rec[keep]
        row = first_block[rec] + i
        record[row], position[row], fmt[row], m[row] = rec, i, f[keep], count[keep]
        data_start[row], data_len[row], pad[row] = at[keep], need[keep], pad_byte[keep]
    error = np.full(total, -1, np.int32)
    error_subindex = np.full(total, -1, np.int32)
    is_error = fmt == pt.FMT_ERROR
    one = np.flatnonzero(is_error & (m >= 1))
    error[one] = _be16(b, data_start[one])
    two = np.flatnonzero(is_error & (m >= 2))
    error_subindex[two] = _be16(b, data_start[two] + 2)
    return BlockColumns(record, fmt, m, data_start, data_len, error, error_subindex, pad, buf=b), position


def _addresses(b: np.ndarray, start: np.ndarray, n_addr: np.ndarray, first_addr: np.ndarray) -> AddressColumns:
    """The parameter addresses (>BBHH from byte 4) exploded one row each."""
    total = int(n_addr.sum())
    record = np.repeat(np.arange(len(start)), n_addr)
    at = start[record] + 4 + 6 * (np.arange(total) - first_addr[record])
    return AddressColumns(record, b[at], b[at + 1], _be16(b, at + 2).astype(np.uint16),
                          _be16(b, at + 4).astype(np.uint16))


def _plausible(buf: bytes, start: np.ndarray, length: np.ndarray, response: np.ndarray, regular: np.ndarray,
               end: np.ndarray, ref: np.ndarray, ident: np.ndarray, n: np.ndarray, max_params: int) -> np.ndarray:
    """profidrive.plausible(record, response, max_params) of each record."""
    out = (length >= 4) & (ref != 0) & (n >= 1) & (n <= max_params)
    addr_end = 4 + 6 * n
    request = ~response
    out &= ~request | ((ident == pt.REQ_READ) & (length == addr_end)) | \
        ((ident == pt.REQ_CHANGE) & (length > addr_end))
    positive_change = response & (ident == pt.RES_CHANGE)
    out &= ~positive_change | (length == 4)
    body = response & _RESPONSE_BODY[ident]
    out &= ~response | positive_change | body
    # a regular parse is complete and without the echo; the others are parsed as the reference does
    out &= ~(body & regular) | (end == length)
    for i in np.flatnonzero(out & body & ~regular):
        at = int(start[i])
        out[i] = profidrive.plausible(buf[at:at + int(length[i])], True, max_params)
    return out


def parsed(d: DecodedRecords, buf: bytes, start: int, length: int, response: bool, i: int) -> profidrive.Parsed:
    """Record i of a decoded batch (a regular one) as profidrive.parse_request / parse_response give it."""
    r, a, k = d.records, d.addresses, d.blocks
    assert r.regular[i], "only a regular record is decoded by the columns"
    p = profidrive.Parsed(response, length, int(r.ref[i]), int(r.ident[i]), int(r.do[i]), int(r.n[i]))
    p.end, p.complete = int(r.end[i]), True
    for row in range(int(r.first_addr[i]), int(r.first_addr[i]) + int(r.n_addr[i])):
        p.addresses.append(profidrive.Address(4 + 6 * (row - int(r.first_addr[i])), int(a.attr[row]),
                                              int(a.n_elems[row]), int(a.pnu[row]), int(a.subindex[row])))
    for row in range(int(r.first_block[i]), int(r.first_block[i]) + int(r.n_blocks[i])):
        at, size = int(k.data_start[row]), int(k.data_len[row])
        offset = at - start - 2
        block = profidrive.Block(offset, int(k.format[row]), int(k.n_values[row]),
                                 pt.FORMATS[int(k.format[row])].size, bytes(buf[at:at + size]),
                                 error=int(k.error[row]), error_subindex=int(k.error_subindex[row]))
        if k.pad[row] >= 0:
            block.pad_offset, block.pad = offset + 2 + size, int(k.pad[row])
        p.blocks.append(block)
    return p


def merge_records(a: DecodedRecords, b: DecodedRecords) -> DecodedRecords:
    """The records of `a`, then those of `b` (decoded from another buffer: b's `data_start` keep pointing
    into it, so only what needs no value bytes may be read of them), every index shifted to match."""
    ra, rb = a.records, b.records
    offsets = {"first_addr": len(a.addresses.record), "first_block": len(a.blocks.record)}
    records = RecordColumns(*(np.concatenate([getattr(ra, f), getattr(rb, f) + offsets[f] if f in offsets
                                              else getattr(rb, f)]) for f in RecordColumns.__dataclass_fields__))
    shift = len(ra.ref)
    addresses = AddressColumns(*(np.concatenate([getattr(a.addresses, f), getattr(b.addresses, f) + (
        shift if f == "record" else 0)]) for f in AddressColumns.__dataclass_fields__))
    columns: dict[str, object] = {}
    for f in BlockColumns.__dataclass_fields__:
        if f == "made_text":  # each made from its own buffer first
            columns[f] = _concat_text(a.blocks.text, b.blocks.text)
        elif f != "buf":
            x, y = getattr(a.blocks, f), getattr(b.blocks, f)
            columns[f] = np.concatenate([x, y + (shift if f == "record" else 0)])
    return DecodedRecords(records, addresses, BlockColumns(**columns))  # type: ignore[arg-type]


def _concat_text(x: object, y: object) -> object:
    """Two BlockColumns.text columns (pyarrow string arrays or numpy object arrays of str) as one."""
    if hasattr(x, "to_pylist") or hasattr(y, "to_pylist"):
        import pyarrow as pa

        def arrow(t: object) -> object:
            return (t if hasattr(t, "to_pylist") else pa.array(list(t), pa.large_string())).cast(pa.large_string())

        return pa.concat_arrays([arrow(x), arrow(y)])
    return np.concatenate([np.asarray(x, object), np.asarray(y, object)])

"""Registry fields read from the column decode of a batch (analysis.engine.view), as the per-frame tree holds
them: every occurrence of a field in a frame, its value (`FrameView.values`) and its `-T fields` text
(`FrameView.shown`), for the PNIO RPC frames the columns decoded regularly (issue 24 point 1).

A field is read where the tree puts it: Ethernet and its VLAN tags, IPv4, UDP, the DCE/RPC header, the NDR
args, the IOD header of the row's kind, the record (raw, or a PROFIdrive header and its addresses) at the
offsets of the protocol's Layout declarations, through the same Views (derived fields, converters) the dump's
annotation uses. Each distinct value is made once, as a Field of the dissector's shape, and judged or shown
by the display filter's and `-T fields`' own code; the frames are the numpy columns.

What a row's tree holds depends on its kind, and for a response on the operation its request has (the tree
decodes a response as the answer to it): `PartFields` is told per row whether its stub is the columns' own
(`stub_known`); where it is not, the stub's fields are unknown (None). A field the columns do not read (a
value block's values, the links a pairing adds) is unknown for the rows that may hold it and absent for
those that cannot; the caller dissects the rows it must know.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.model import pd_values as pt
from pd_analyze.model.layout import Layout
from pd_analyze.model.shown import Field, View
from pd_analyze.model.values import (
    OP_WRITE,
    PTYPE_FAULT,
    PTYPE_REJECT,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
    VLAN_TPIDS,
)
from pd_analyze.output.frame_view import FieldRef, _tshark_text, _width_of
from pd_analyze.protocol import link, profidrive, rpc
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.link_batch import MAX_TAGS
from pd_analyze.protocol.profidrive_view import value_of, values_of

Decode = Callable[[bytes], object]
_TPIDS = np.array(sorted(VLAN_TPIDS), np.int64)
_PNIO_PTYPES = (PTYPE_REQUEST, PTYPE_RESPONSE)
_IOD_KINDS = (rec.WRITE_REQ, rec.WRITE_RES, rec.READ_RES, rec.READ_REQ_IMPLICIT, rec.READ_REQ)
_ADDRESS = (("attr", 0, 1), ("n_elems", 1, 1), ("pnu", 2, 2), ("subindex", 4, 2))  # profidrive_view.annotate
# fields no regular column row's tree holds (the dissector adds them to fragments, reassembled or cut PDUs,
# other operations, faults, Write-Multiple; or never to a frame: the tables' and the decode command's own)
_NEVER_IN_ROWS = frozenset({
    "rpc.body", "ndr.blocks", "iod.multi_pad", "pd.echo", "pd.cut", "rpc.fragments", "rpc.reassembled_in",
    "ip.reassembled_from", "eth.vlan_ids", "rpc.retransmissions", "dpv1.function", "dpv1.slot", "dpv1.index",
    "dpv1.length", "sll.pkttype", "sll.hatype", "sll.halen", "sll.addr", "sll.protocol", "sll.ifindex",
    "sll.reserved"})
_STUB_FAMILIES = ("ndr.", "iod.", "record.", "pd.")
_TEXT_FORMATS = np.array(sorted(code for code, f in pt.FORMATS.items() if f.kind in ("string", "octets", "unicode")))


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
class _Piece:
    """Occurrences of one concrete field name read alike: at buf[at : at + size] of each row in `rows`."""

    name: str
    rows: np.ndarray  # int64 indices into the part's rows
    at: np.ndarray  # int64 offsets in buf
    size: int
    decode: Decode
    order: int | np.ndarray = 0  # its place (per occurrence, or for all) in a row: tags, addresses, values


class PartFields:
    """The fields of `rows` (indices into view.p, in frame order) of a part's column decode. `stub_known`
    (per row): the row's stub, record included, is decoded in its tree as the columns decode it (a request;
    a response whose request has its operation)."""

    def __init__(self, view: BatchView, rows: np.ndarray, stub_known: np.ndarray) -> None:
        self.view, self.rows = view, rows
        p = view.p
        self.data = np.frombuffer(view.batch.buf, np.uint8)
        self.ptype = p.ptype[rows]
        self.fault = (self.ptype == PTYPE_FAULT) | (self.ptype == PTYPE_REJECT)
        self.stub = stub_known & np.isin(self.ptype, _PNIO_PTYPES)
        self.frame_start = view.batch.start[p.pos[rows]].astype(np.int64)
        self.rpc_at = p.body_start[rows].astype(np.int64) - rpc.HEADER_SIZE
        self._l3: tuple[np.ndarray, np.ndarray] | None = None
        self._cache: dict[tuple[tuple[str, ...], str, int], Occurrences | None] = {}

    # --- a reference ---------------------------------------------------------------------------------
    def occurrences(self, ref: FieldRef) -> Occurrences | None:
        """The field's occurrences in every row; None when the columns cannot say for any row."""
        key = (ref.names, ref.exact, ref.width)
        if key not in self._cache:
            self._cache[key] = self._occurrences(ref)
        return self._cache[key]

    def _occurrences(self, ref: FieldRef) -> Occurrences | None:
        n = len(self.rows)
        known = np.ones(n, bool)
        pieces: list[_Piece] = []
        for name in ref.names:
            got = self._pieces(name, ref.exact)
            if got is None:
                return None
            row_known, some = got
            known &= row_known
            pieces += some
        found = _assemble(self.data, known, pieces, len(ref.names) > 1)
        return found if ref.width < 0 else _of_width(found, ref.width)

    def _pieces(self, name: str, exact: str = "") -> tuple[np.ndarray, list[_Piece]] | None:
        n = len(self.rows)
        if name in _NEVER_IN_ROWS:
            return self.stub | self.fault if name.startswith(_STUB_FAMILIES) or name == "rpc.body" else \
                np.ones(n, bool), []
        if name == "rpc.fault_status":
            return np.ones(n, bool), self._fault_status()
        family = name.partition(".")[0]
        reader = _READERS.get(family)
        if reader is None:
            return None
        return reader(self, name, exact)

    # --- where the structures are ------------------------------------------------------------------
    def l3(self) -> tuple[np.ndarray, np.ndarray]:
        """Each row's VLAN tag count and the offset of its IPv4 header in buf (the rows are Ethernet frames
        with at most link_batch.MAX_TAGS tags: the column decode takes no other)."""
        if self._l3 is None:
            d, start = self.data, self.frame_start
            off = np.full(len(start), 14, np.int64)
            tags = np.zeros(len(start), np.int64)
            walking = np.ones(len(start), bool)
            for _ in range(MAX_TAGS + 1):
                at = start + off - 2
                etype = (d[at].astype(np.int64) << 8) | d[at + 1]
                walking &= np.isin(etype, _TPIDS)
                if not walking.any():
                    break
                off[walking] += 4
                tags[walking] += 1
            self._l3 = tags, start + off
        return self._l3

    def _fault_status(self) -> list[_Piece]:
        rows = np.flatnonzero(self.fault)
        at = self.rpc_at[rows] + rpc.HEADER_SIZE
        little = self.view.p.little[self.rows[rows]]
        out = []
        for layout, mine in ((rpc.FAULT_LE, little), (rpc.FAULT_BE, ~little)):
            out.append(_entry_piece(layout, layout.view, "rpc.fault_status", rows[mine], at[mine]))
        return out


# --- the families ---------------------------------------------------------------------------------------
def _eth(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[_Piece]] | None:
    rows = np.arange(len(pf.rows))
    if name in link.ETH.positions:
        return np.ones(len(rows), bool), [_entry_piece(link.ETH, link.ETH.view, name, rows, pf.frame_start)]
    return None


def _vlan_value(name: str) -> Decode:
    part = name.partition(".")[2]
    if part == "etype":
        return lambda raw: int.from_bytes(raw, "big")
    shift, mask = {"pcp": (13, 0x7), "dei": (12, 0x1), "id": (0, 0x0FFF)}[part]
    return lambda raw: (int.from_bytes(raw, "big") >> shift) & mask


def _vlan(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[_Piece]] | None:
    """link.annotate's tag fields: pcp, dei and id from the TCI, the EtherType after it (vlan.tpid is not
    shown: its bytes are the EtherType before)."""
    n = len(pf.rows)
    if name == "vlan.tpid":
        return np.ones(n, bool), []
    if name not in ("vlan.pcp", "vlan.dei", "vlan.id", "vlan.etype"):
        return None
    tags, _l3 = pf.l3()
    decode = _vlan_value(name)
    pieces = []
    for k in range(int(tags.max()) if n else 0):
        rows = np.flatnonzero(tags > k)
        at = pf.frame_start[rows] + 14 + 4 * k + (2 if name == "vlan.etype" else 0)
        pieces.append(_Piece(name, rows, at, 2, decode, k))
    return np.ones(n, bool), pieces


def _ip(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[_Piece]] | None:
    n = len(pf.rows)
    rows = np.arange(n)
    _tags, l3 = pf.l3()
    if name == "ip.options":
        ihl = (pf.data[l3] & 0x0F).astype(np.int64) * 4
        with_options = np.flatnonzero(ihl > 20)
        pieces = [_Piece(name, with_options[ihl[with_options] == size], l3[with_options[ihl[with_options] == size]]
                         + 20, size - 20, bytes) for size in np.unique(ihl[with_options]).tolist()]
        return np.ones(n, bool), pieces
    view = link.IPV4_SHOWN
    if name not in view.names:
        return None
    return np.ones(n, bool), [_entry_piece(link.IPV4, view, name, rows, l3)]


def _udp(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[_Piece]] | None:
    if name not in link.UDP.positions:
        return None
    rows = np.arange(len(pf.rows))
    return np.ones(len(rows), bool), [_entry_piece(link.UDP, link.UDP.view, name, rows, pf.rpc_at - link.UDP.size)]


def _rpc(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[_Piece]] | None:
    if name not in rpc.HEADER_LE.positions:
        return None  # the links, the fault status: not here
    little = pf.view.p.little[pf.rows]
    pieces = [_entry_piece(layout, layout.view, name, np.flatnonzero(mine), pf.rpc_at[mine])
              for layout, mine in ((rpc.HEADER_LE, little), (rpc.HEADER_BE, ~little))]
    return np.ones(len(pf.rows), bool), pieces


def _ndr(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[_Piece]] | None:
    little = pf.view.p.little[pf.rows]
    response = pf.ptype == PTYPE_RESPONSE
    pieces = []
    for layouts, side in ((rec.NDR_REQ, ~response), (rec.NDR_RES, response)):
        for is_little, mine in ((True, little), (False, ~little)):
            layout = layouts[is_little]
            rows = np.flatnonzero(pf.stub & side & mine)
            if name in layout.positions:
                pieces.append(_entry_piece(layout, layout.view, name, rows, pf.rpc_at[rows] + rpc.HEADER_SIZE))
    if not pieces and name not in rec.NDR_RES[True].positions and name not in rec.NDR_REQ[True].positions:
        return None
    return pf.stub | pf.fault, pieces


def _iod_kind(pf: PartFields) -> np.ndarray:
    """Each row's IOD header layout (an index into _IOD_KINDS, -1 without a block), as pnio.iod_layout
    chooses it for the row's own operation."""
    p, rows = pf.view.p, pf.rows
    write = p.opnum[rows] == OP_WRITE
    response = pf.ptype == PTYPE_RESPONSE
    nil = (p.ar_hi[rows] == 0) & (p.ar_lo[rows] == 0)
    kind = np.select([write & ~response, write & response, response, nil, np.ones(len(rows), bool)],
                     [0, 1, 2, 3, 4])
    return np.where(pf.stub & p.has_block[rows], kind, -1)


def _iod(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[_Piece]] | None:
    if not any(name in layout.positions for layout in _IOD_KINDS):
        return None
    kind = _iod_kind(pf)
    at = pf.rpc_at + rpc.HEADER_SIZE + rec.NDR_SIZE
    pieces = []
    for k, layout in enumerate(_IOD_KINDS):
        if name in layout.positions:
            rows = np.flatnonzero(kind == k)
            pieces.append(_entry_piece(layout, layout.view, name, rows, at[rows]))
    return pf.stub | pf.fault, pieces


def _record_bounds(pf: PartFields) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row: does its IOD block carry a record (a write request's, a read response's), where the record
    starts in buf, and the bytes the stub holds after the IOD header."""
    p, rows = pf.view.p, pf.rows
    kind = _iod_kind(pf)
    carries = (kind == 0) | (kind == 2)
    start = pf.rpc_at + rpc.HEADER_SIZE + rec.NDR_SIZE + rec.IOD_SIZE
    after = p.body_len[rows].astype(np.int64) - rec.NDR_SIZE - rec.IOD_SIZE
    return carries, start, after


def _record(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[_Piece]] | None:
    """record.data (a record not decoded as PROFIdrive, whole in a column row) and record.trailing (the stub's
    bytes after the record, or after a header that carries none)."""
    p, rows = pf.view.p, pf.rows
    carries, start, after = _record_bounds(pf)
    has_block = _iod_kind(pf) >= 0
    record_len = p.record_len[rows].astype(np.int64)
    if name == "record.data":
        mine = np.flatnonzero(carries & (pf.view.rec_of[rows] < 0))
        return pf.stub | pf.fault, _sized(name, mine, start[mine], record_len[mine])
    if name == "record.trailing":
        used = np.where(carries, record_len, 0)
        trailing = np.where(has_block, after - used, 0)
        mine = np.flatnonzero(trailing > 0)
        return pf.stub | pf.fault, _sized(name, mine, start[mine] + used[mine], trailing[mine])
    return None


def _pd(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[_Piece]] | None:
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
                pieces.append(_entry_piece(layout, layout.view, name, mine, at[mine]))
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
            pieces.append(_Piece(concrete, mine, at[mine] + 4 + 6 * k + offset, size, _unsigned, k))
        return known, pieces
    if name == "pd.trailing":  # the bytes after the parsed record (profidrive_view.annotate)
        end = _of_record(r.end, rec_of, parsed)
        length = p.rec_len[rows].astype(np.int64)
        mine = np.flatnonzero(parsed & (end < length))
        return known, _sized(name, mine, at[mine] + end[mine], length[mine] - end[mine], bytes.hex)  # shown as hex
    if name.startswith("pd.val["):
        return _blocks(pf, name, exact, parsed, known)
    return None


def _blocks(pf: PartFields, name: str, exact: str, parsed: np.ndarray,
            known: np.ndarray) -> tuple[np.ndarray, list[_Piece]] | None:
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
        return known, [_Piece(name, owner, at, 1, _unsigned, order)]
    if part == "pad":
        with_pad = pad >= 0
        return known, [_Piece(name, owner[with_pad], (start + length)[with_pad], 1, _unsigned, order[with_pad])]
    if part in ("error", "error_subindex"):
        word = 0 if part == "error" else 1
        mine = error & (m > word)
        return known, [_Piece(name, owner[mine], start[mine] + 2 * word, 2, _unsigned, order[mine])]
    if part == "string":
        text = np.isin(fmt, _TEXT_FORMATS) & ~error
        return known, [_Piece(name, owner[text & (fmt == code) & (length == size)],
                              start[text & (fmt == code) & (length == size)], size, _text_value(code),
                              order[text & (fmt == code) & (length == size)])
                       for code, size in sorted(set(zip(fmt[text].tolist(), length[text].tolist(), strict=True)))]
    if part == "value[j]":
        return known, _values(owner, fmt, start, m, order, error, wanted[1] if len(wanted) > 1 else -1)
    return None


def _values(owner: np.ndarray, fmt: np.ndarray, start: np.ndarray, m: np.ndarray, order: np.ndarray,
            error: np.ndarray, only: int) -> list[_Piece]:
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
        pieces.append(_Piece("pd.val[i].value[j]", owner[each], start[each] + size * j, size, _number(code),
                             order[each] + j))
    blocks = np.flatnonzero(error & (m > 2))
    count = m[blocks].astype(np.int64) - 2
    each = np.repeat(blocks, count)
    j = np.arange(len(each)) - np.repeat(np.cumsum(count) - count, count) + 2
    if only >= 0:
        each, j = each[j == only], j[j == only]
    pieces.append(_Piece("pd.val[i].value[j]", owner[each], start[each] + 2 * j, 2, _unsigned, order[each] + j))
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


def _of_width(found: Occurrences, width: int) -> Occurrences:
    """The occurrences of one width (tshark's value_b, value_w, value_dw, value_float: FrameView.fields)."""
    fit = np.array([_width_of(f) == width for f in found.fields], bool)
    keep = fit[found.code] if len(found.code) else np.zeros(0, bool)
    return Occurrences(found.known, found.owner[keep], found.code[keep], found.fields)


def _of_record(column: np.ndarray, rec_of: np.ndarray, parsed: np.ndarray) -> np.ndarray:
    """A record column per row (int64), 0 for the rows without a parsed record."""
    out = np.zeros(len(rec_of), np.int64)
    out[parsed] = column[rec_of[parsed]]
    return out


_READERS: dict[str, Callable[[PartFields, str, str], tuple[np.ndarray, list[_Piece]] | None]] = {
    "eth": _eth, "vlan": _vlan, "ip": _ip, "udp": _udp, "rpc": _rpc, "ndr": _ndr, "iod": _iod, "record": _record,
    "pd": _pd}


# --- reading and assembling -----------------------------------------------------------------------
def _unsigned(raw: bytes) -> object:
    return int.from_bytes(raw, "big")


def _entry_piece(layout: Layout, view: View, name: str, rows: np.ndarray, at: np.ndarray) -> _Piece:
    """The View entry `name` of `layout` (its offset, size, source field and converter) at structures `at`."""
    entry = next(e for e in view.entries if e[0] == name)
    _name, offset, size, _memo, conv, _show, source, _k = entry
    unpack = struct.Struct(layout.order + layout.codes[source]).unpack

    def decode(raw: bytes) -> object:
        value = unpack(raw)[0]
        return value if conv is None else conv(value)
    return _Piece(name, rows, at + offset, size, decode)


def _sized(name: str, rows: np.ndarray, at: np.ndarray, length: np.ndarray, decode: Decode = bytes) -> list[_Piece]:
    """Byte fields of varying length: one piece per length."""
    return [_Piece(name, rows[length == size], at[length == size], int(size), decode)
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


def _assemble(data: np.ndarray, known: np.ndarray, pieces: list[_Piece], by_offset: bool) -> Occurrences:
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


class OtherFrames:
    """The fields of frames the column decode skips (not PNIO RPC, output.frame_layers shows their headers):
    the link, IPv4, UDP and DCE/RPC headers are read per frame (unknown here); no other layer is there."""

    def __init__(self, count: int) -> None:
        self.count = count

    def occurrences(self, ref: FieldRef) -> Occurrences | None:
        if any(name.partition(".")[0] in _HEADER_FAMILIES or name in rpc.HEADER_LE.positions for name in ref.names):
            return None
        empty = np.zeros(0, np.int64)
        return Occurrences(np.ones(self.count, bool), empty, empty, [])


_HEADER_FAMILIES = frozenset({"eth", "vlan", "sll", "ip", "udp"})

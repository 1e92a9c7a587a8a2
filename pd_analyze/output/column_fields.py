"""Registry fields read from the column decode of a batch (analysis.engine.view), as the per-frame tree holds
them: every occurrence of a field in a frame, its value (`FrameView.values`) and its `-T fields` text
(`FrameView.shown`), for the PNIO RPC frames the columns decoded regularly (issue 24 point 1).

A field is read where the tree puts it: Ethernet and its VLAN tags, IPv4, UDP, the DCE/RPC header, the NDR
args, the IOD header of the row's kind (here), the record: raw, or a PROFIdrive header, its addresses and
blocks (output.column_records), at the offsets of the protocol's Layout declarations, through the same Views
(derived fields, converters) the dump's annotation uses. Each distinct value is made once, as a Field of the
dissector's shape, and judged or shown by the display filter's and `-T fields`' own code
(output.column_read); the frames are the numpy columns.

What a row's tree holds depends on its kind, and for a response on the operation its request has (the tree
decodes a response as the answer to it): `PartFields` is told per row whether its stub is the columns' own
(`stub_known`); where it is not, the stub's fields are unknown. A field the columns do not read (a block of a
description's size, which the tree may show as one by its request's address; the links a pairing adds) is
unknown for the rows that may hold it and absent for those that cannot; the caller dissects the rows it must
know.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.model.values import (
    PTYPE_FAULT,
    PTYPE_REJECT,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
    VLAN_TPIDS,
)
from pd_analyze.output.column_read import Decode, Occurrences, Piece, assemble, entry_piece, of_width
from pd_analyze.output.column_records import IOD_KINDS, iod_kind, pd, record
from pd_analyze.output.frame_view import FieldRef
from pd_analyze.protocol import link, rpc
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.link_batch import MAX_TAGS

_TPIDS = np.array(sorted(VLAN_TPIDS), np.int64)
_PNIO_PTYPES = (PTYPE_REQUEST, PTYPE_RESPONSE)
# fields no regular column row's tree holds (the dissector adds them to fragments, reassembled or cut PDUs,
# other operations, faults, Write-Multiple; or never to a frame: the tables' and the decode command's own)
_NEVER_IN_ROWS = frozenset({
    "rpc.body", "ndr.blocks", "iod.multi_pad", "pd.echo", "pd.cut", "rpc.fragments", "rpc.reassembled_in",
    "ip.reassembled_from", "eth.vlan_ids", "rpc.retransmissions", "dpv1.function", "dpv1.slot", "dpv1.index",
    "dpv1.length", "sll.pkttype", "sll.hatype", "sll.halen", "sll.addr", "sll.protocol", "sll.ifindex",
    "sll.reserved"})
_STUB_FAMILIES = ("ndr.", "iod.", "record.", "pd.")


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
        pieces: list[Piece] = []
        for name in ref.names:
            got = self._pieces(name, ref.exact)
            if got is None:
                return None
            row_known, some = got
            known &= row_known
            pieces += some
        found = assemble(self.data, known, pieces, len(ref.names) > 1)
        return found if ref.width < 0 else of_width(found, ref.width)

    def _pieces(self, name: str, exact: str = "") -> tuple[np.ndarray, list[Piece]] | None:
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

    def _fault_status(self) -> list[Piece]:
        rows = np.flatnonzero(self.fault)
        at = self.rpc_at[rows] + rpc.HEADER_SIZE
        little = self.view.p.little[self.rows[rows]]
        out = []
        for layout, mine in ((rpc.FAULT_LE, little), (rpc.FAULT_BE, ~little)):
            out.append(entry_piece(layout, layout.view, "rpc.fault_status", rows[mine], at[mine]))
        return out


# --- the families ---------------------------------------------------------------------------------------
def _eth(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[Piece]] | None:
    rows = np.arange(len(pf.rows))
    if name in link.ETH.positions:
        return np.ones(len(rows), bool), [entry_piece(link.ETH, link.ETH.view, name, rows, pf.frame_start)]
    return None


def _vlan_value(name: str) -> Decode:
    part = name.partition(".")[2]
    if part == "etype":
        return lambda raw: int.from_bytes(raw, "big")
    shift, mask = {"pcp": (13, 0x7), "dei": (12, 0x1), "id": (0, 0x0FFF)}[part]
    return lambda raw: (int.from_bytes(raw, "big") >> shift) & mask


def _vlan(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[Piece]] | None:
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
        pieces.append(Piece(name, rows, at, 2, decode, k))
    return np.ones(n, bool), pieces


def _ip(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[Piece]] | None:
    n = len(pf.rows)
    rows = np.arange(n)
    _tags, l3 = pf.l3()
    if name == "ip.options":
        ihl = (pf.data[l3] & 0x0F).astype(np.int64) * 4
        with_options = np.flatnonzero(ihl > 20)
        pieces = [Piece(name, with_options[ihl[with_options] == size], l3[with_options[ihl[with_options] == size]]
                         + 20, size - 20, bytes) for size in np.unique(ihl[with_options]).tolist()]
        return np.ones(n, bool), pieces
    view = link.IPV4_SHOWN
    if name not in view.names:
        return None
    return np.ones(n, bool), [entry_piece(link.IPV4, view, name, rows, l3)]


def _udp(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[Piece]] | None:
    if name not in link.UDP.positions:
        return None
    rows = np.arange(len(pf.rows))
    return np.ones(len(rows), bool), [entry_piece(link.UDP, link.UDP.view, name, rows, pf.rpc_at - link.UDP.size)]


def _rpc(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[Piece]] | None:
    if name not in rpc.HEADER_LE.positions:
        return None  # the links, the fault status: not here
    little = pf.view.p.little[pf.rows]
    pieces = [entry_piece(layout, layout.view, name, np.flatnonzero(mine), pf.rpc_at[mine])
              for layout, mine in ((rpc.HEADER_LE, little), (rpc.HEADER_BE, ~little))]
    return np.ones(len(pf.rows), bool), pieces


def _ndr(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[Piece]] | None:
    little = pf.view.p.little[pf.rows]
    response = pf.ptype == PTYPE_RESPONSE
    pieces = []
    for layouts, side in ((rec.NDR_REQ, ~response), (rec.NDR_RES, response)):
        for is_little, mine in ((True, little), (False, ~little)):
            layout = layouts[is_little]
            rows = np.flatnonzero(pf.stub & side & mine)
            if name in layout.positions:
                pieces.append(entry_piece(layout, layout.view, name, rows, pf.rpc_at[rows] + rpc.HEADER_SIZE))
    if not pieces and name not in rec.NDR_RES[True].positions and name not in rec.NDR_REQ[True].positions:
        return None
    return pf.stub | pf.fault, pieces


def _iod(pf: PartFields, name: str, exact: str) -> tuple[np.ndarray, list[Piece]] | None:
    if not any(name in layout.positions for layout in IOD_KINDS):
        return None
    kind = iod_kind(pf)
    at = pf.rpc_at + rpc.HEADER_SIZE + rec.NDR_SIZE
    pieces = []
    for k, layout in enumerate(IOD_KINDS):
        if name in layout.positions:
            rows = np.flatnonzero(kind == k)
            pieces.append(entry_piece(layout, layout.view, name, rows, at[rows]))
    return pf.stub | pf.fault, pieces


_READERS: dict[str, Callable[[PartFields, str, str], tuple[np.ndarray, list[Piece]] | None]] = {
    "eth": _eth, "vlan": _vlan, "ip": _ip, "udp": _udp, "rpc": _rpc, "ndr": _ndr, "iod": _iod, "record": record,
    "pd": pd}


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

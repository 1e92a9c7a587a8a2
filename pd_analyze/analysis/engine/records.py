"""The parameter records a transaction refers to, whichever decoder made them: a column record of the
batch (its index into the batch's decoded records) or a per-frame parse. What the engine asks of them:
the addresses of a request, whether it writes values, the values a read brought back per element, and
what a record costs the caps while its transaction is pending."""

from __future__ import annotations

import struct

import numpy as np

from pd_analyze.analysis.engine.facts import Carried, Record
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.model import pd_values as pt
from pd_analyze.protocol import profidrive
from pd_analyze.protocol.profidrive import Parsed
from pd_analyze.protocol.profidrive_view import cell_text, values_of

Element = tuple  # device, DO, PNU, subindex: one array element of one drive's parameter
Address = tuple[int, int, int, int]  # attribute, No. of elements, PNU, subindex

_ADDRESSES = struct.Struct(">BBHH")  # a parameter address (protocol.md 3.1), as the columns read it
PACKED = np.uint16  # an address's fields as `Records.packed` keeps them (attribute and count are 8 bits)
PACKED_ADDRESS = 4 * np.dtype(PACKED).itemsize  # bytes of one address in `Records.packed`
_WHOLE = frozenset({"string", "octets", "unicode"})  # one value per block, whatever No. of values says
_NUMBERS = frozenset({"hex", "bits", "nibbles"})  # the cell shows 0x..., an element's value is the number


class Records:
    """The records of one batch (`view`) and the parses of earlier batches and of the per-frame decode."""

    def __init__(self, view: BatchView | None) -> None:
        self.view = view
        self._matrix: np.ndarray | None = None  # the view's addresses as one (n, 4) array, made on first use

    def parsed(self, record: Record) -> Parsed | None:
        """A record as profidrive.parse_request / parse_response give it."""
        if record is None or isinstance(record, Parsed):
            return record
        if isinstance(record, Carried):  # (a request: only requests outlive their batch)
            return profidrive.parse_request(record.data, 0, [])
        assert self.view is not None
        return self.view.parsed_record(record)

    def addresses(self, record: Record) -> list[Address]:
        if record is None:
            return []
        if isinstance(record, Parsed):
            return [(a.attr, a.n_elems, a.pnu, a.subindex) for a in record.addresses]
        if isinstance(record, Carried):
            n = record.data[3]
            return list(_ADDRESSES.iter_unpack(record.data[4:4 + 6 * n]))
        return list(map(tuple, self.address_array(record).tolist()))

    def address_array(self, record: Record) -> np.ndarray:
        """`addresses` as an (n, 4) int64 array."""
        if isinstance(record, int) and not isinstance(record, bool):
            rc = self.view.records.records  # type: ignore[union-attr]
            if self._matrix is None:  # one stacking per batch, not one per record asked
                a = self.view.records.addresses  # type: ignore[union-attr]
                self._matrix = np.stack([a.attr, a.n_elems, a.pnu, a.subindex], axis=1).astype(np.int64)
            first = int(rc.first_addr[record])
            return self._matrix[first:first + int(rc.n_addr[record])]
        return np.array(self.addresses(record), np.int64).reshape(-1, 4)

    def packed(self, record: Record) -> bytes:
        """`addresses` packed (PACKED quadruples: each field fits, as the wire has it in 8 or 16 bits): what a
        channel keeps of its last request beyond its batch, a fraction of the memory of tuples."""
        return self.address_array(record).astype(PACKED).tobytes()


    def writes_values(self, record: Record, req_id: int) -> bool:
        """A change parameter, or a vendor service laid out as one (protocol.md 5.5)."""
        if isinstance(record, Parsed) or record is None:
            return profidrive.writes_values(record)
        return req_id == pt.REQ_CHANGE  # (a profile's own Request ID is never a column record)

    def cost(self, record: Record) -> int:
        """Bytes a pending transaction keeps alive for its parameter request (profidrive.footprint)."""
        if record is None:
            return 0
        if isinstance(record, Parsed):
            return profidrive.footprint(record)
        if isinstance(record, Carried):
            return 128 + len(record.data)
        rc = self.view.records.records  # type: ignore[union-attr]
        n = int(rc.n_addr[record])
        return 256 + 2 * (4 + 6 * n) + 128 * n + 192 * int(rc.n_blocks[record])

    def carried(self, record: Record) -> Record:
        """The record as it outlives its batch: a column record's bytes (the batch's buffer and columns go)."""
        if not isinstance(record, int):
            return record
        view = self.view
        i = int(view.rec_pdu[record])  # type: ignore[union-attr]
        start, length = int(view.p.rec_start[i]), int(view.p.rec_len[i])  # type: ignore[union-attr]
        return Carried(bytes(view.batch.buf[start:start + length]))  # type: ignore[union-attr]

    def read_back(self, request: Record, response: Record, device: int, do: int) -> list[tuple[Element, str]]:
        """What an answered read brought back: (element, value as a table cell shows it) per element of
        each Value address answered with values (all elements, or the first when the drive gave one)."""
        if request is None or response is None:
            return []
        if isinstance(request, Carried) and isinstance(response, int):
            return self._read_back_columns(-1, response, device, do, self.addresses(request))
        if isinstance(request, int) and isinstance(response, int):
            return self._read_back_columns(request, response, device, do)
        req, res = self.parsed(request), self.parsed(response)
        out: list[tuple[Element, str]] = []
        for addr, block in zip(req.addresses, res.blocks, strict=False):  # type: ignore[union-attr]
            if addr.attr != pt.ATTR_VALUE or block.is_error:
                continue
            keys = [(device, do, addr.pnu, addr.subindex + j) for j in range(max(addr.n_elems, 1))]
            values = [cell_text(v, size) for _, size, v, _ in values_of(block)]
            if len(values) == len(keys):
                out += zip(keys, values, strict=True)
            elif len(values) == 1:
                out.append((keys[0], values[0]))
        return out

    def _read_back_columns(self, req: int, res: int, device: int, do: int,
                           addresses: list[Address] | None = None) -> list[tuple[Element, str]]:
        view = self.view
        rc, a, b = view.records.records, view.records.addresses, view.records.blocks  # type: ignore[union-attr]
        first_block = int(rc.first_block[res])
        if addresses is None:
            first = int(rc.first_addr[req])
            rows = slice(first, first + int(rc.n_addr[req]))
            addresses = list(zip(a.attr[rows].tolist(), a.n_elems[rows].tolist(), a.pnu[rows].tolist(),
                                 a.subindex[rows].tolist(), strict=True))
        text = None
        out: list[tuple[Element, str]] = []
        for j in range(min(len(addresses), int(rc.n_blocks[res]))):
            attr, n_elems, pnu, sub = addresses[j]
            bi = first_block + j
            fmt = int(b.format[bi])
            if attr != pt.ATTR_VALUE or fmt == pt.FMT_ERROR:
                continue
            spec = pt.FORMATS[fmt]
            n = int(b.n_values[bi])
            if spec.kind in _NUMBERS:
                at, size = int(b.data_start[bi]), spec.size
                buf = view.batch.buf  # type: ignore[union-attr]
                values = [str(int.from_bytes(buf[at + i * size:at + (i + 1) * size], "big")) for i in range(n)]
            else:
                text = view.block_texts if text is None else text  # type: ignore[union-attr]
                cell = text[bi]
                values = [cell] if spec.kind in _WHOLE else cell.split(" ") if n > 1 else [cell] if n else []
            count = max(n_elems, 1)
            if len(values) == count:
                out += [((device, do, pnu, sub + i), value) for i, value in enumerate(values)]
            elif len(values) == 1:
                out.append(((device, do, pnu, sub), values[0]))
        return out


def unpacked(packed: bytes) -> tuple[Address, ...]:
    """The addresses of `Records.packed`."""
    return tuple(map(tuple, np.frombuffer(packed, PACKED).reshape(-1, 4).tolist()))

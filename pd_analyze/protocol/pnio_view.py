"""How a decoded PNIO PDU is shown in the dump: its one-line summary and its layers (NDR args, IOD
blocks, Write-Multiple padding, records), each field with offset, bytes and value."""

from __future__ import annotations

from pd_analyze.model.layout import Field, plain
from pd_analyze.model.pd_values import NEGATIVE_RESPONSE
from pd_analyze.model.values import (
    ERROR_CODE_READ,
    ERROR_DECODE_PNIORW,
    INDEX_PD_GLOBAL,
    INDEX_PD_LOCAL,
    INDEX_WRITE_MULTIPLE,
    PNIO_ERROR_CODE,
    PNIO_OPNUM,
    PNIORW_STATE_CONFLICT,
    PROFIDRIVE_INDICES,
    PTYPE_RESPONSE,
    RECORD_SERVICES,
    code1_name,
    code2_name,
    status_text,
)
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol import profidrive, profidrive_view
from pd_analyze.protocol.frames import Layer
from pd_analyze.protocol.profidrive_view import Checks
from pd_analyze.protocol.profiles import VendorResponse


def pdu_summary(ptype: int, seq: int, stub: rec.Stub, fragments: int, opnum: int) -> str:
    """The one-line summary of a decoded PNIO PDU (the dump's frame heading)."""
    op = PNIO_OPNUM.get(opnum, f"opnum {opnum}")
    kind = "response" if ptype == PTYPE_RESPONSE else "request"
    parts = [f"{op} {kind}", f"seq {seq}"]
    if stub.status is not None and not stub.status.ok:
        parts.append(f"PNIOStatus {status_text(stub.status.text())}")
    for block in stub.blocks[:4]:
        v = block.values
        key = (block.layout, v[rec.B_API], v[rec.B_SLOT], v[rec.B_SUBSLOT], block.index, block.record_len)
        text = _BLOCK_TEXTS.get(key)
        if text is None:
            text = f"{block.layout.title.split(' ')[0]} api {v[rec.B_API]:#x} slot " \
                   f"{v[rec.B_SLOT]}/{v[rec.B_SUBSLOT]:#x} index {block.index:#06x}"
            if block.layout in (rec.WRITE_REQ, rec.READ_RES):
                text += f" {block.record_len} bytes"
            if len(_BLOCK_TEXTS) >= 4096:
                _BLOCK_TEXTS.clear()
            _BLOCK_TEXTS[key] = text
        parts.append(text)
        negative = negative_response(block)
        if negative:
            parts.append(negative)
    if len(stub.blocks) > 4:
        parts.append(f"... {len(stub.blocks) - 4} more blocks")
    if fragments:
        parts.append(f"reassembled from {fragments} fragments")
    return ", ".join(parts)


# a block's part of the summary by what it names (blocks at the same address repeat through a capture), and
# its layer's title by its layout and index
_BLOCK_TEXTS: dict[tuple, str] = {}
_BLOCK_TITLES: dict[tuple, str] = {}


def negative_response(block: rec.Block) -> str:
    """A negative parameter response in the record, as the heading names it: "PROFIdrive negative read
    response (0x81), ref 1" (tshark's Info: "Negative read response"); "" for anything else."""
    parsed = block.pd[0] if isinstance(block.pd, tuple) else None
    if parsed is None or not parsed.response or not parsed.header_ok:
        return ""
    if isinstance(parsed.vendor, VendorResponse):  # a vendor's own negative Response ID (protocol.md 5.5)
        words = parsed.vendor.name if parsed.vendor.negative else ""  # its name says negative
    else:
        words = NEGATIVE_RESPONSE.get(parsed.ident, "")
    return f"PROFIdrive {words} ({parsed.ident:#04x}), ref {parsed.ref}" if words else ""


def stub_layers(stub: rec.Stub, body: bytes, base: int, opnum: int, response: bool, checks: Checks) -> list[Layer]:
    """The dump's layers of a decoded stub: NDR args, IOD blocks, records (PROFIdrive field by field)."""
    layers: list[Layer] = []
    if not stub.ndr:
        title = "NDR stub (truncated)" if opnum in PNIO_OPNUM else \
            f"Stub of opnum {opnum} (not a PNIO operation: not decoded)"
        layers.append(Layer(title, 0, [plain("rpc.body", 0, body, len(body), body, base)]))
        return layers
    layout = stub.ndr_layout
    layers.append(Layer(layout.title, 0, explain_status(layout.annotate(body, 0, stub.ndr, base), stub.status)))
    if opnum not in RECORD_SERVICES:
        rest = body[rec.NDR_SIZE:]
        if rest:
            layers.append(Layer(f"{PNIO_OPNUM.get(opnum, 'PNIO')} blocks (not decoded)", 0,
                                    [plain("ndr.blocks", rec.NDR_SIZE, body, len(rest), rest, base)]))
        return layers
    pads = dict(rec.multi_pads(stub)) if len(stub.blocks) > 1 else {}  # (a Write-Multiple's inner blocks)
    for block in stub.blocks:
        depth = 1 + block.depth
        title = _BLOCK_TITLES.get((block.layout, block.index))
        if title is None:
            title = f"{block.layout.title}, index {block.index:#06x}"
            if len(_BLOCK_TITLES) < 4096:
                _BLOCK_TITLES[(block.layout, block.index)] = title
        layers.append(Layer(title, depth,
                            explain_status(block.layout.annotate(body, block.offset, block.values, base),
                                           block.status)))
        if block.layout in (rec.WRITE_REQ, rec.READ_RES) and block.index != INDEX_WRITE_MULTIPLE:
            refused = response and stub.status is not None and not stub.status.ok
            layers += record_layers(block, base, depth + 1, checks, refused)
        end = block.record_offset + len(block.record)
        if end in pads:
            pad = body[end:end + pads[end]]
            layers.append(Layer("Write-Multiple padding", depth,
                                    [plain("iod.multi_pad", end, body, pads[end], pad, base)]))
    if stub.trailing:
        start = len(body) - stub.trailing
        layers.append(Layer("Trailing bytes", 1, [plain("record.trailing", start, body, stub.trailing,
                                                            body[start:], base)]))
    return layers


def explain_status(fields: list[Field], status: rec.Status | None) -> list[Field]:
    """The PNIOStatus fields of a header in words: ErrorCode1 and ErrorCode2 named by what ErrorDecode
    says they are (protocol.md 4.6), and a failed status marked as the failure it is, not as a
    well-formed field ("ok"), on its ErrorCode."""
    if status is None or status.ok:
        return fields
    for i, f in enumerate(fields):
        part = f.name.rpartition(".")[2]
        check = None
        if part == "code1":
            meaning = code1_name(status.decode, status.code1)
        elif part == "code2":
            meaning = code2_name(status.decode, status.code1, status.code2)
        elif part == "code" and ".status." in f.name:
            meaning = PNIO_ERROR_CODE.get(status.code, "")
            check = status_check(status)
        else:
            continue
        shown = f"0x{f.value:02x} ({meaning})" if meaning and isinstance(f.value, int) else None
        fields[i] = f.replaced(shown, check)  # shown for this status only: a copy, not the Layout's shared field
    return fields


def status_check(status: rec.Status) -> str:
    """The check text of a status that is not OK: B5 on a read is the device saying "not ready yet"
    (the controller reads again, protocol.md 7.3), anything else a refused record service."""
    if status.code == ERROR_CODE_READ and status.decode == ERROR_DECODE_PNIORW \
            and status.code1 == PNIORW_STATE_CONFLICT:
        return f"not ready: {status_text(status.text())}; the controller reads again"
    return f"failed: {status_text(status.text())}"


def record_layers(block: rec.Block, base: int, depth: int, checks: Checks, refused: bool = False) -> list[Layer]:
    """A record's layers: a PROFIdrive request or response field by field, any other record raw.

    A PROFIdrive record cut short (fewer bytes than its RecordDataLength: the snaplen, a short PDU) is shown
    decoded as far as its bytes go, as tshark shows it: the header, the whole addresses and value blocks,
    the part the bytes end inside as `pd.cut` (protocol.md 1.3). It is decoded here for the dump only: the
    record_truncated finding (H5) stands for it, and no transaction takes its contents. At index 0x002F
    (plausible as PROFIdrive only when whole, protocol.md 1.4) and in a refused read response it stays raw."""
    data = block.record
    parsed, request = block.pd if isinstance(block.pd, tuple) else (cut_record(block, checks, refused), None)
    if parsed is not None:
        at = base + block.record_offset
        return [Layer(title, depth, fields) for title, fields in
                profidrive_view.annotate(parsed, data, at, checks, request)]
    what = "PROFIdrive, not decoded" if block.index in PROFIDRIVE_INDICES else "not PROFIdrive"
    return [Layer(f"Record data, index {block.index:#06x} ({len(data)} bytes, {what})", depth,
                  [raw_record(block, base)])]


def cut_record(block: rec.Block, checks: Checks, refused: bool) -> profidrive.Parsed | None:
    """A PROFIdrive record at 0xB02E/0xB02F with fewer bytes than its RecordDataLength, parsed as far as
    they go (its findings are not the frame's: H5 reports the cut); None for any other record."""
    if refused or block.index not in _CUT_DECODED or len(block.record) >= block.record_len \
            or block.layout not in (rec.WRITE_REQ, rec.READ_RES):
        return None
    parse = profidrive.parse_response if block.layout is rec.READ_RES else profidrive.parse_request
    return parse(block.record, 0, [], checks.ids)


_CUT_DECODED = frozenset({INDEX_PD_LOCAL, INDEX_PD_GLOBAL})


def raw_record(block: rec.Block, base: int) -> Field:
    return Field("record.data", base + block.record_offset, len(block.record), bytes(block.record),
                 bytes(block.record), f"{len(block.record)} bytes")

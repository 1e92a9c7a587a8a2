"""Rules N1-N9 and H1-H14 of protocol.md section 6 on decoded NDR args and IOD blocks.

Each function takes what the lower layers decoded (tuples, Stub) and returns findings; nothing here
parses bytes. Structural findings that stop a decode (R1, R3, H5 truncation) come from the parsers.
"""

from __future__ import annotations

from operator import itemgetter

from pd_analyze.model.rules import Finding, finding
from pd_analyze.model.values import (
    API_PROFIDRIVE,
    ERROR_CODE_READ,
    ERROR_CODE_WRITE,
    ERROR_DECODE_PNIO,
    ERROR_DECODE_PNIORW,
    INDEX_PD_DPV1,
    INDEX_WRITE_MULTIPLE,
    OP_READ,
    OP_READ_IMPLICIT,
    OP_WRITE,
    PROFIDRIVE_INDICES,
)
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.pnio import Block, Stub

BLOCK_LENGTH = rec.IOD_SIZE - 4  # H2: BlockLength counts the bytes after BlockType and itself


def ndr(stub: Stub, stub_len: int, opnum: int, frame: int, request: Stub | None) -> list[Finding]:
    """N1-N9 on an NDR args header (and the request it answers)."""
    if not stub.ndr:
        return []
    out = []
    args_len = stub.args_len
    if args_len != stub_len - rec.NDR_SIZE:
        out.append(finding("ndr_args_len", frame, "ndr.args_len", args_len, stub_len - rec.NDR_SIZE,
                           "ArgsLength differs from the stub length - 20"))
    if stub.actual_count != args_len or stub.offset != 0:
        bad, value, want = (("ndr.offset", stub.offset, 0) if stub.offset
                            else ("ndr.actual_count", stub.actual_count, args_len))
        out.append(finding("ndr_array", frame, bad, value, want,
                           "NDR array ActualCount must equal ArgsLength and Offset must be 0"))
    if not stub.response:
        if stub.max_count != stub.args_max:
            out.append(finding("ndr_max_count", frame, "ndr.max_count", stub.max_count, stub.args_max,
                               "MaximumCount differs from ArgsMaximum"))
        read = stub.blocks[0] if stub.blocks and opnum in (OP_READ, OP_READ_IMPLICIT) else None
        if read is not None and stub.args_max < rec.IOD_SIZE + read.record_len:
            out.append(finding("ndr_args_max_small", frame, "ndr.args_max", stub.args_max,
                               f">= {rec.IOD_SIZE + read.record_len}",
                               "ArgsMaximum cannot hold the read header plus the requested record"))
        return out
    if request is not None:
        out += ndr_paired(stub, request, frame)
    status = stub.status
    if status is not None:
        out += pnio_status(status, opnum, frame, "ndr.status")
        if not status.ok and status.code1 != 0xB5 and stub.blocks and opnum != OP_WRITE:
            out.append(finding("error_with_blocks", frame, "ndr.args_len", args_len, 0,
                               "read response with error status still carries blocks"))
        if opnum == OP_WRITE and stub.blocks and stub.blocks[0].status not in (None, status):
            out.append(finding("pnio_status_differs", frame, "iod.status.code", stub.blocks[0].status.text(),
                               status.text(), "NDR PNIOStatus and write-response block status differ"))
    return out


def ndr_paired(stub: Stub, request: Stub, frame: int) -> list[Finding]:
    """N4: a response's NDR header against its request's ArgsMaximum."""
    if not stub.ndr or not stub.response or not request.ndr:
        return []
    args_max, args_len = request.args_max, stub.args_len
    if stub.max_count == args_max and args_len <= args_max:
        return []
    bad, value = (("ndr.max_count", stub.max_count) if stub.max_count != args_max else ("ndr.args_len", args_len))
    return [finding("ndr_response_max", frame, bad, value, args_max if bad == "ndr.max_count" else f"<= {args_max}",
                    "response NDR header inconsistent with the request's ArgsMaximum")]


def pnio_status(status: rec.Status, opnum: int, frame: int, prefix: str) -> list[Finding]:
    """N6, N7 on one PNIOStatus."""
    if status.ok:
        return []
    out = []
    if status.code == 0 or status.decode not in (ERROR_DECODE_PNIORW, ERROR_DECODE_PNIO):
        bad = f"{prefix}.code" if status.code == 0 else f"{prefix}.decode"
        out.append(finding("pnio_status_form", frame, bad, status.text(),
                           "all zero, or ErrorCode != 0 with ErrorDecode 0x80/0x81",
                           f"PNIOStatus {status.text()} is not a valid error form"))
    want = ERROR_CODE_WRITE if opnum == OP_WRITE else ERROR_CODE_READ if opnum in (OP_READ, OP_READ_IMPLICIT) \
        else None
    if want is not None and status.code not in (0, want):
        if status.code == 0x81:
            out.append(finding("pnio_status_generic", frame, f"{prefix}.code", "0x81", f"{want:#04x}",
                               "generic PNIO ErrorCode on a record service (accepted)"))
        else:
            out.append(finding("pnio_status_service", frame, f"{prefix}.code", f"{status.code:#04x}",
                               f"{want:#04x}", "ErrorCode does not match the service"))
    return out


def blocks(stub: Stub, opnum: int, frame: int, request: Stub | None, max_record: int,
           tolerate: frozenset[str] = frozenset()) -> list[Finding]:
    """H1-H14 on the IOD blocks of one stub (`max_record`: the profile's record limit, `tolerate`: the
    vendor profile's tolerations)."""
    out: list[Finding] = []
    expected = rec.EXPECTED_BLOCK.get((opnum, stub.response))
    if expected is None:
        return out
    for block in stub.blocks:
        out += _header_form(block, expected, frame, stub.response)
        if not stub.response:
            out += _request_header(block, opnum, frame, max_record, tolerate)
        else:
            out += _response_header(block, frame)
    if stub.trailing:
        out.append(finding("trailing_stub_bytes", frame, "record.trailing", stub.trailing, 0,
                           f"{stub.trailing} bytes after the last block/record"))
    if not stub.response and opnum == OP_WRITE and stub.blocks and stub.blocks[0].index == INDEX_WRITE_MULTIPLE:
        out += _multi_sum(stub, frame)
    if stub.response and request is not None:
        out += mirroring(stub, request, opnum, frame)
    return out


def header_undecodable(stub: Stub, opnum: int) -> bool:
    """A wrong BlockType (H1) or a BlockLength other than 60 (H2) in the stub's IOD headers: the PDU is read
    with the fixed 64-byte layout, but what it holds cannot be trusted, so its transaction is `malformed`
    (protocol.md 7.4 rule 1)."""
    expected = rec.EXPECTED_BLOCK.get((opnum, stub.response))
    if expected is None:
        return False
    return any((b.depth == 0 and b.values[rec.B_TYPE] != expected) or b.values[rec.B_LENGTH] != BLOCK_LENGTH
               for b in stub.blocks)


def _header_form(block: Block, expected: int, frame: int, response: bool) -> list[Finding]:
    out = []
    v = block.values
    if block.depth == 0 and v[rec.B_TYPE] != expected:
        out.append(finding("block_type", frame, "iod.block_type", f"{v[rec.B_TYPE]:#06x}", f"{expected:#06x}",
                           "BlockType does not match the service and direction"))
    if block.depth == 1 and response and v[rec.B_TYPE] != expected:
        out.append(finding("multi_write_structure", frame, "iod.block_type", f"{v[rec.B_TYPE]:#06x}",
                           f"{expected:#06x}", "inner Write-Multiple response is not an IODWriteResHeader"))
    if v[rec.B_LENGTH] != BLOCK_LENGTH:
        out.append(finding("block_length", frame, "iod.block_length", v[rec.B_LENGTH], BLOCK_LENGTH,
                           "BlockLength is not 60 (decoded with the fixed 64-byte layout)"))
    if (v[rec.B_VHIGH], v[rec.B_VLOW]) != (1, 0):
        out.append(finding("block_version", frame, "iod.version_high", f"{v[rec.B_VHIGH]}.{v[rec.B_VLOW]}",
                           "1.0", "block version is not 1.0"))
    rw_pad = v[-1]  # every IOD layout ends with its RWPadding
    if v[rec.B_PAD] or rw_pad.count(0) != len(rw_pad):
        bad = "iod.pad" if v[rec.B_PAD] else "iod.rw_pad"
        out.append(finding("padding_nonzero", frame, bad, f"{v[rec.B_PAD]:#06x}" if v[rec.B_PAD]
                           else rw_pad.hex(), "0", "padding bytes are not zero"))
    if response and block.layout in (rec.WRITE_RES, rec.READ_RES):
        add1, add2 = v[rec.B_ADD_VAL1], v[rec.B_ADD_VAL2]
        if add1 or add2:
            out.append(finding("additional_values", frame, "iod.add_val1", f"{add1}/{add2}", "0/0",
                               "AdditionalValue1/2 not zero"))
    if block.status is not None and block.depth == 1:
        out += pnio_status(block.status, OP_WRITE, frame, "iod.status")
    return out


def _request_header(block: Block, opnum: int, frame: int, max_record: int,
                    tolerate: frozenset[str]) -> list[Finding]:
    out = []
    v = block.values
    nil = v[rec.B_AR] == rec.NIL_UUID
    if opnum == OP_WRITE and nil:
        out.append(finding("aruuid_nil_write", frame, "iod.ar_uuid", "NIL", "an AR's UUID",
                           "write with a NIL ARUUID"))
    elif (opnum == OP_READ and nil) or (opnum == OP_READ_IMPLICIT and not nil):
        out.append(finding("aruuid_implicit", frame, "iod.ar_uuid", "NIL" if nil else "non-NIL",
                           "non-NIL for Read, NIL for ReadImplicit",
                           "ARUUID does not fit the read service (explicit vs implicit)"))
    index, reclen = v[rec.B_INDEX], v[rec.B_RECLEN]
    if index in PROFIDRIVE_INDICES:
        if index == INDEX_PD_DPV1:
            out.append(finding("profibus_index", frame, "iod.index", "0x002f", "0xb02e/0xb02f",
                               "PROFIdrive parameter access over the DPV1 index 47"))
        elif v[rec.B_API] == 0 and "api_dap" in tolerate:
            out.append(finding("api_dap_yaskawa", frame, "iod.api", "0x00000000", "0x00003a00",
                               "API 0x0000 (device access point) on a PROFIdrive index, as Yaskawa documents"))
        elif v[rec.B_API] != API_PROFIDRIVE:
            out.append(finding("api_not_profidrive", frame, "iod.api", f"{v[rec.B_API]:#010x}",
                               "0x00003a00", "API is not the PROFIdrive API 0x3A00"))
        if opnum == OP_WRITE and not 4 <= reclen <= max_record:
            out.append(finding("pd_record_length", frame, "iod.record_len", reclen, f"4 ... {max_record}",
                               "PROFIdrive parameter request length out of range (device answers B1)"))
        if opnum != OP_WRITE and reclen < max_record:
            out.append(finding("pd_read_buffer_small", frame, "iod.record_len", reclen, f">= {max_record}",
                               f"read buffer below {max_record} bytes: a long parameter response may not fit (B1)"))
    return out


def _response_header(block: Block, frame: int) -> list[Finding]:
    if block.layout is rec.READ_RES and block.index in PROFIDRIVE_INDICES and block.record_len < 4:
        return [finding("pd_record_length", frame, "iod.record_len", block.record_len, ">= 4",
                        "PROFIdrive parameter response shorter than its 4-byte header")]
    return []


def _multi_sum(stub: Stub, frame: int) -> list[Finding]:
    outer = stub.blocks[0]
    inner = stub.blocks[1:]
    if not inner:
        return [finding("multi_write_structure", frame, "iod.record_len", outer.record_len, "> 0",
                        "Write-Multiple without inner writes")]
    end = inner[-1].record_offset + len(inner[-1].record)
    want = outer.record_offset + outer.record_len
    if stub.truncated:
        return []
    # protocol.md 2.8 / H11: the outer length either ends with the last record or also counts its 1-3 pad
    # bytes up to the next multiple of 4 (writers differ; both are valid); the pad bytes must be zero
    if stub.last_pad and want == end + len(stub.last_pad) and want % 4 == 0:
        if any(stub.last_pad):
            return [finding("multi_write_padding", frame, "iod.multi_pad", stub.last_pad.hex(), "00",
                            "Write-Multiple pad bytes after the last record not zero")]
        return []
    if end != want:
        return [finding("multi_write_structure", frame, "iod.record_len", outer.record_len,
                        end - outer.record_offset, "outer RecordDataLength differs from the inner blocks")]
    return []


_MIRRORED = (("iod.seq", rec.B_SEQ), ("iod.api", rec.B_API), ("iod.slot", rec.B_SLOT),
             ("iod.subslot", rec.B_SUBSLOT), ("iod.index", rec.B_INDEX))


_mirrored_values = itemgetter(*(i for _, i in _MIRRORED), rec.B_AR)


def mirroring(stub: Stub, request: Stub, opnum: int, frame: int) -> list[Finding]:
    """H6-H8: each response block mirrors the request block in the same position."""
    out = []
    for pos, (res, req) in enumerate(zip(stub.blocks, request.blocks, strict=False)):
        if _mirrored_values(res.values) == _mirrored_values(req.values):
            continue  # the common case: every mirrored field equal, ARUUID included
        for name, i in _MIRRORED:
            if res.values[i] != req.values[i]:
                out.append(finding("response_not_mirrored", frame, name, res.values[i], req.values[i],
                                   f"response block {pos} does not mirror the request's {name}"))
        want_ar = req.target_ar if req.target_ar and res.values[rec.B_AR] != rec.NIL_UUID else req.values[rec.B_AR]
        if res.values[rec.B_AR] != want_ar and res.values[rec.B_AR] != req.values[rec.B_AR]:
            out.append(finding("response_not_mirrored", frame, "iod.ar_uuid", "differs", "request's ARUUID",
                               f"response block {pos} does not mirror the request's ARUUID"))
    if not stub.blocks or not request.blocks:
        return out
    res, req = stub.blocks[0], request.blocks[0]
    if opnum == OP_WRITE and req.index != INDEX_WRITE_MULTIPLE and res.record_len != req.record_len:
        out.append(finding("write_length_mirror", frame, "iod.record_len", res.record_len, req.record_len,
                           "write response RecordDataLength differs from the request's"))
    if opnum != OP_WRITE and res.record_len > req.record_len:
        out.append(finding("read_length_exceeded", frame, "iod.record_len", res.record_len,
                           f"<= {req.record_len}", "read response longer than the read request allows"))
    return out


# Fields some rule above examines: the dump marks them "ok" when no finding names them.
CHECKED_FIELDS = frozenset({
    "rpc.frag_len", "rpc.if_version", "rpc.auth_proto", "rpc.flags1", "rpc.drep", "rpc.serial_lo",
    "rpc.opnum", "ndr.args_max", "ndr.args_len", "ndr.max_count", "ndr.offset", "ndr.actual_count",
    "ndr.status.code", "ndr.status.decode", "iod.block_type", "iod.block_length", "iod.version_high",
    "iod.pad", "iod.rw_pad", "iod.seq", "iod.ar_uuid", "iod.api", "iod.slot", "iod.subslot", "iod.index",
    "iod.record_len", "iod.add_val1", "iod.status.code", "iod.status.decode", "iod.multi_pad",
})

"""PROFIdrive parameter-access samples (issue "PROFIdrive parameter access",
item 7): clean commissioning, negative responses, B5 and PNIO errors,
injected range violations, global/DPV1 indices, AKD-like and Yaskawa-like
drives.

Each file is built by a `*_capture()` function that returns the capture and
its Intent: every injected violation is declared with `x.on(frame, rule)`
on the line that injects it, every transaction with `x.txn(...)` and the
verdict of protocol.md 7.4. `pd_sample` registers each in catalog.EXPECTED;
`python -m devtools.synth` writes them to sample_pcaps/expected/.

Conventions as sample_pcaps/README.md: session 1 (.11 -> .21), API 0x3A00,
slot 1/1, Index 0xB02E, DO 1, read RecordDataLength 240, references counting
up per transaction (never reused, so no transaction-level T findings).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from . import pnio_encode, rpc_encode
from .catalog import Built, pd_sample
from .expect import GENERIC, Intent
from .fixtures import session
from .pd_encode import (
    ATTR_DESCRIPTION,
    ATTR_TEXT,
    REQ_CHANGE,
    REQ_READ,
    akd_echo_response,
    change_ok,
    change_request,
    date_value,
    description,
    error_block,
    pd_request,
    pd_response,
    read_request,
    text_entries,
    time_value,
    value_block,
    zero_block,
)
from .pd_encode import ParamAddress as P
from .scenario import Capture, PnioSession

# PNIOStatus values used below (protocol.md 4.6)
DF_B0 = pnio_encode.pnio_status(0xDF, 0x80, 0xB0, 0x00)  # write: invalid index
DF_B1 = pnio_encode.pnio_status(0xDF, 0x80, 0xB1, 0x00)  # write: write length error
DF_B7 = pnio_encode.pnio_status(0xDF, 0x80, 0xB7, 0x00)  # write: invalid range (request header)
DE_B1 = pnio_encode.pnio_status(0xDE, 0x80, 0xB1, 0x00)  # read: buffer too small for the response
DE_B2 = pnio_encode.pnio_status(0xDE, 0x80, 0xB2, 0x00)  # read: invalid slot/subslot

NCA_SERVER_TOO_BUSY = 0x1C010014
NCA_PROTO_ERROR = 0x1C01000B


def _ok_read(ref: int, do: int, blocks: list[bytes]) -> bytes:
    return pd_response(ref, 0x01, do, blocks)


# ---- pd_commissioning.pcap -------------------------------------------------------------------------

# 39 identification/status parameters read in one request (4 + 39 x 6 = 238 bytes).
MANY_PNUS = (2, 20, 21, 22, 24, 25, 26, 27, 31, 32, 33, 34, 35, 36, 37, 39, 46, 47, 50, 51,
             52, 53, 54, 56, 60, 61, 62, 63, 68, 69, 70, 71, 72, 73, 74, 75, 76, 77, 78)  # fmt: skip


@pd_sample("pd_commissioning.pcap")
def pd_commissioning_capture() -> Built:
    """A clean commissioning session: every common format, multi-parameter
    requests, pad bytes between and after odd lists, strings, description
    and text reads, changes. No findings under the generic profile."""
    cap = Capture()
    s = session(cap, 1, rtt_us=1200, gap_us=800)
    x = Intent(cap)

    # ref 1: 39 parameters in one read request, alternating Unsigned16 / Word
    assert len(MANY_PNUS) == 39
    req = read_request(1, 1, [P(p) for p in MANY_PNUS])
    blocks = [value_block(0x06 if i % 2 == 0 else 0x42, [(p * 37) & 0xFFFF]) for i, p in enumerate(MANY_PNUS)]
    x.txn(s.parameter_access(req, _ok_read(1, 1, blocks), b5_retries=1), 1, "ok", "39 parameters in one request")

    # ref 2: every numeric format; Boolean, Integer8 and Unsigned8 lists are odd -> pad before the next block
    numeric = [
        (P(722), value_block(0x01, [1])),
        (P(100), value_block(0x02, [-5])),
        (P(101), value_block(0x03, [-1234])),
        (P(102), value_block(0x04, [-123_456_789])),
        (P(103), value_block(0x05, [200])),
        (P(104), value_block(0x06, [50_000])),
        (P(105), value_block(0x07, [4_000_000_000])),
        (P(106), value_block(0x08, [3.5])),
        (P(107), value_block(0x0F, [0.1])),
        (P(108), value_block(0x37, [-(2**40)])),
        (P(109), value_block(0x38, [2**63 + 5])),
    ]
    req = read_request(2, 1, [a for a, _ in numeric])
    x.txn(s.parameter_access(req, _ok_read(2, 1, [b for _, b in numeric])), 2, "ok", "numeric formats")

    # ref 3: strings, times and dates; the Date x 3 list at the end gets the final pad byte
    strings = [
        (P(975, n_elems=13), value_block(0x09, "SINAMICS G120")),  # 13 characters + pad
        (P(976, n_elems=5), value_block(0x0A, bytes([0xDE, 0xAD, 0xBE, 0xEF, 0x01]))),  # 5 octets + pad
        (P(977, n_elems=6), value_block(0x27, "Pump 1")),  # UCS-2, 12 bytes
        (P(3100), value_block(0x0C, [time_value(45_296_789, 15_341)])),  # 12:34:56.789 on 2026-01-01
        (P(3101), value_block(0x34, [time_value(45_296_789)])),
        (P(3102), value_block(0x35, [time_value(3_600_000, 2)])),
        (P(3103), value_block(0x36, [time_value(1500)])),
        (P(3104), value_block(0x32, [date_value(2026, 1, 1, 12, 34, 56_789, weekday=4)])),  # 7 bytes + pad
        (P(3105, n_elems=3), value_block(0x32, [date_value(2025, 12, d, 8, 0, 0) for d in (29, 30, 31)])),
    ]
    req = read_request(3, 1, [a for a, _ in strings])
    x.txn(s.parameter_access(req, _ok_read(3, 1, [b for _, b in strings]), b5_retries=1), 3, "ok",
          "strings, times, dates")  # fmt: skip

    # ref 4: profile formats N2 ... X4 and Byte/Word/Double word (Byte x 3 -> pad)
    special = [
        (P(1070), value_block(0x71, [0x2000])),  # N2 50 %
        (P(1071), value_block(0x72, [-0x2000_0000])),  # N4 -50 %
        (P(1072), value_block(0x79, [3 * 128])),  # E2 3.0
        (P(1073), value_block(0x7A, [12_345])),  # C4 1.2345
        (P(1074), value_block(0x76, [100])),  # T2
        (P(1075), value_block(0x77, [70_000])),  # T4
        (P(1076), value_block(0x73, [0x8421])),  # V2
        (P(1077), value_block(0x74, [0x1234])),  # L2
        (P(1078), value_block(0x75, [16_384])),  # R2
        (P(1079), value_block(0x78, [250])),  # D2
        (P(1080), value_block(0x7B, [-100])),  # X2
        (P(1081), value_block(0x7C, [1_000_000])),  # X4
        (P(2050, n_elems=3), value_block(0x41, [0x01, 0x80, 0xFF])),
        (P(2051, n_elems=2), value_block(0x42, [0xBEEF, 0x0001])),
        (P(2052), value_block(0x43, [0xDEADBEEF])),
    ]
    req = read_request(4, 1, [a for a, _ in special])
    x.txn(s.parameter_access(req, _ok_read(4, 1, [b for _, b in special])), 4, "ok", "N2/N4/E2/C4/T2/T4/V2/L2/...")

    # ref 5: description (attribute 0x20) and text (0x30) reads
    desc = description(0x0008, 0, "Max. speed", std_factor=1.0, low=bytes(4), high=bytes.fromhex("45fa0000"))
    descr = [
        (P(1082, 0, 1, ATTR_DESCRIPTION), value_block(0x0A, desc)),  # complete description, 46 octets
        (P(1082, 6, 1, ATTR_DESCRIPTION), value_block(0x09, "Max. speed".ljust(16))),  # element 6: name
        (P(1082, 1, 1, ATTR_DESCRIPTION), value_block(0x06, [0x0008])),  # element 1: identifier
        (P(1082, 8, 1, ATTR_DESCRIPTION), value_block(0x0A, bytes.fromhex("45fa0000"))),  # element 8: high limit
        (P(700, 0, 2, ATTR_TEXT), value_block(0x09, text_entries(["Terminals", "PROFINET"]))),  # 2 x 16 characters
    ]
    req = read_request(5, 1, [a for a, _ in descr])
    x.txn(s.parameter_access(req, _ok_read(5, 1, [b for _, b in descr]), b5_retries=2), 5, "ok",
          "description and text")  # fmt: skip

    # ref 6: change P1120 (Float32)
    req = change_request(6, 1, [(P(1120), value_block(0x08, [10.0]))])
    x.txn(s.parameter_access(req, change_ok(6, 1, 1), b5_retries=1), 6, "ok", "change Float32")

    # ref 7: multi-parameter change with odd lists in the middle and at the end (final pad)
    items = [
        (P(1000, n_elems=0), value_block(0x03, [-300])),  # non-array: elements 0, one value
        (P(730, n_elems=3), value_block(0x05, [1, 0, 1])),  # 3 bytes + pad
        (P(2900, n_elems=5), value_block(0x09, "Pump1")),  # 5 characters + pad
        (P(1080, 1, 2), value_block(0x07, [1500, 3000])),  # subindex 1..2
        (P(731), value_block(0x01, [1])),  # last: 1 byte + final pad
    ]
    x.txn(s.parameter_access(change_request(7, 1, items), change_ok(7, 1, 5), b5_retries=2), 7, "ok",
          "multi-parameter change")  # fmt: skip

    # ref 8: change with Byte/Word/Double word, N2, E2 and Float64
    items = [
        (P(2050, n_elems=3), value_block(0x41, [0x02, 0x40, 0x7F])),
        (P(2051), value_block(0x42, [0xCAFE])),
        (P(2052), value_block(0x43, [0x00010002])),
        (P(1070), value_block(0x71, [0x4000])),
        (P(1072), value_block(0x79, [-64])),
        (P(107), value_block(0x0F, [2.5])),
    ]
    x.txn(s.parameter_access(change_request(8, 1, items), change_ok(8, 1, 6)), 8, "ok", "change word formats")

    # ref 9: read back what was changed (Unsigned8 x 3 last -> final pad)
    req = read_request(9, 1, [P(1120), P(730, n_elems=3)])
    res = _ok_read(9, 1, [value_block(0x08, [10.0]), value_block(0x05, [1, 0, 1])])
    x.txn(s.parameter_access(req, res), 9, "ok", "read back")
    return cap, x


# ---- pd_negative.pcap ------------------------------------------------------------------------------------


@pd_sample("pd_negative.pcap")
def pd_negative_capture() -> Built:
    """Negative responses: partial 0x81/0x82, one error of each class, the
    header-level single error block, reserved and manufacturer numbers."""
    cap = Capture()
    s = session(cap, 1)
    x = Intent(cap, (GENERIC, "sinamics"))

    def nak_read(ref: int, addrs: list[P], blocks: list[bytes], note: str, **kw: Any) -> list:
        res = pd_response(ref, 0x81, 1, blocks, n_params=len(addrs))  # n mirrored even for one header-level error
        calls = s.parameter_access(read_request(ref, 1, addrs), res, **kw)
        return x.txn(calls, ref, "nak", note)

    def nak_change(ref: int, items: list[tuple[P, bytes]], blocks: list[bytes], note: str, **kw: Any) -> list:
        res = pd_response(ref, 0x82, 1, blocks, n_params=len(items))
        calls = s.parameter_access(change_request(ref, 1, items), res, **kw)
        return x.txn(calls, ref, "nak", note)

    # ref 1: 0x81 partial: value, error 0x00 (PNU does not exist, no subindex), value
    nak_read(1, [P(964), P(9999), P(2000)],
             [value_block(0x42, [0x1234]), error_block(0x00), value_block(0x08, [1500.0])],
             "0x81 partial: P9999 error 0x00", b5_retries=1)  # fmt: skip
    # ref 2: 0x82 partial: Zero, 0x02 limit exceeded (subindex 0), Zero, 0x01 read-only (subindex 0)
    nak_change(2, [(P(1120), value_block(0x08, [10.0])), (P(1082), value_block(0x08, [99_999.0])),
                   (P(1121), value_block(0x08, [5.0])), (P(2), value_block(0x06, [1]))],
               [zero_block(), error_block(0x02, 0), zero_block(), error_block(0x01, 0)],
               "0x82 partial: errors 0x02 and 0x01 with subindex")  # fmt: skip
    # ref 3: 0x03 faulty subindex (subindex 5 reported)
    nak_read(3, [P(2000, 5)], [error_block(0x03, 5)], "error 0x03 with subindex 5")
    # ref 4: 0x11 operating state (no subindex) and 0x14 value impermissible (subindex 0)
    nak_change(4, [(P(304), value_block(0x06, [400])), (P(1300), value_block(0x06, [7]))],
               [error_block(0x11), error_block(0x14, 0)], "errors 0x11 and 0x14")  # fmt: skip
    # ref 5: 0x15 response too long: 20 text entries would need 320 bytes
    nak_read(5, [P(700, 0, 20, ATTR_TEXT)], [error_block(0x15)], "error 0x15 response too long")
    # ref 6: 0x16 parameter address impermissible (description element 13 does not exist)
    nak_read(6, [P(1082, 13, 1, ATTR_DESCRIPTION)], [error_block(0x16)], "error 0x16")
    # ref 7: 0x17 illegal format (Word written to a Float32 parameter)
    nak_change(7, [(P(1120), value_block(0x42, [0x0010]))], [error_block(0x17)], "error 0x17")
    # ref 8: 0x18 number of values inconsistent (6 values for a 4-element array)
    nak_change(8, [(P(2000, 0, 6), value_block(0x06, [1, 2, 3, 4, 5, 6]))], [error_block(0x18)], "error 0x18")
    # ref 9: 0x19 DO does not exist (global access to DO 9)
    calls = s.parameter_access(read_request(9, 9, [P(964)]), pd_response(9, 0x81, 9, [error_block(0x19)]),
                               index=0xB02F)  # fmt: skip
    x.txn(calls, 9, "nak", "error 0x19 on B02F DO 9")
    # ref 10: illegal Request ID 0x70 -> Response ID 0x80 with error 0x21
    calls = s.parameter_access(pd_request(10, 0x70, 1, [P(964)]), pd_response(10, 0x80, 1, [error_block(0x21)]))
    x.on(x.write_req(calls), "pd_request_range")  # P2: Request ID 0x70
    x.on(x.final_res(calls), "vendor_limit", profiles=["sinamics"])  # SINAMICS lists 0x01/0x02/0x81/0x82 only
    x.txn(calls, 10, "nak", "Request ID 0x70 -> 0x80 / 0x21")
    # ref 11: 0x22 too many parameters: 20 addresses, one error block for the whole request
    calls = nak_read(11, [P(2000 + i) for i in range(20)], [error_block(0x22)], "header-level 0x22")
    x.on(x.final_res(calls), "header_level_error")
    # ref 12: 0x23 multi-parameter access not supported: two changes, one error block
    calls = nak_change(12, [(P(1120), value_block(0x08, [1.0])), (P(1121), value_block(0x08, [1.0]))],
                       [error_block(0x23)], "header-level 0x23")  # fmt: skip
    x.on(x.final_res(calls), "header_level_error")
    # ref 13: reserved error number 0x12 (W)
    calls = nak_read(13, [P(964)], [error_block(0x12)], "reserved error 0x12")
    x.on(x.final_res(calls), "error_reserved")
    # ref 14: manufacturer-specific 0x65 and 0x87 (I, SINAMICS texts under --profile sinamics)
    calls = nak_read(14, [P(1520), P(964), P(1521)],
                     [error_block(0x65), value_block(0x42, [0x1234]), error_block(0x87)],
                     "manufacturer-specific 0x65, 0x87", b5_retries=1)  # fmt: skip
    x.on([x.final_res(calls)] * 2, "error_manufacturer")
    # ref 15: manufacturer-specific 0xC9 on a change
    calls = nak_change(15, [(P(1082), value_block(0x08, [60_000.0]))], [error_block(0xC9)],
                       "manufacturer-specific 0xC9")  # fmt: skip
    x.on(x.final_res(calls), "error_manufacturer")
    return cap, x


# ---- pd_b5_and_pnio_errors.pcap -----------------------------------------------------------------------------


@pd_sample("pd_b5_and_pnio_errors.pcap")
def pd_b5_and_pnio_errors_capture() -> Built:
    """B5 retries and every way a transaction ends with a PNIO error or an
    RPC fault/reject instead of a parameter response."""
    cap = Capture()
    s = session(cap, 1)
    x = Intent(cap)
    one = read_request

    # ref 1: read with 3 B5 answers, 10 ms apart
    calls = s.parameter_access(one(1, 1, [P(964)]), _ok_read(1, 1, [value_block(0x42, [0x1234])]),
                               b5_retries=3, read_gap_us=10_000)  # fmt: skip
    x.txn(calls, 1, "ok", "3 B5")
    # ref 2: change with 5 B5 answers (the drive saves to non-volatile memory)
    calls = s.parameter_access(change_request(2, 1, [(P(971), value_block(0x06, [1]))]), change_ok(2, 1, 1),
                               b5_retries=5, read_gap_us=20_000)  # fmt: skip
    x.txn(calls, 2, "ok", "5 B5")
    # ref 3: a valid 238-byte request refused with DF 80 B1 00 (this device's parameter buffer is smaller)
    calls = s.parameter_access(one(3, 1, [P(2000 + i) for i in range(39)]), None, write_status=DF_B1)
    x.txn(calls, 3, "pnio_error", "write DF 80 B1 00")
    # ref 4: global access on a device with B02E only -> DF 80 B0 00 invalid index
    calls = s.parameter_access(one(4, 2, [P(10)]), None, index=0xB02F, write_status=DF_B0)
    x.txn(calls, 4, "pnio_error", "write DF 80 B0 00")
    # ref 5: request header refused at the write (DO 32 unknown to this device) -> DF 80 B7 00
    calls = s.parameter_access(one(5, 32, [P(964)]), None, write_status=DF_B7)
    x.txn(calls, 5, "pnio_error", "write DF 80 B7 00")
    # ref 6: 8 text entries (132-byte response) read with a 64-byte buffer -> DE 80 B1 00
    calls = s.parameter_access(one(6, 1, [P(700, 0, 8, ATTR_TEXT)]), None, read_status=DE_B1,
                               read_kw={"max_len": 64})  # fmt: skip
    x.on(x.read_reqs(calls), "pd_read_buffer_small")  # H14: read RecordDataLength 64
    x.txn(calls, 6, "pnio_error", "read DE 80 B1 00")
    # ref 7: submodule pulled between write and read -> DE 80 B2 00
    calls = s.parameter_access(one(7, 1, [P(964)]), None, b5_retries=1, read_status=DE_B2)
    x.txn(calls, 7, "pnio_error", "read DE 80 B2 00")
    # ref 8: the write is answered with an RPC fault (server too busy)
    calls = s.parameter_access(one(8, 1, [P(964)]), None, write_fault=(rpc_encode.FAULT, NCA_SERVER_TOO_BUSY))
    x.on(calls[0].response, "rpc_fault")
    x.txn(calls, 8, "pnio_error", "write answered with fault 0x1C010014")
    # ref 9: the final read is answered with an RPC reject (protocol error)
    calls = s.parameter_access(one(9, 1, [P(964)]), None, b5_retries=1, read_fault=(rpc_encode.REJECT, NCA_PROTO_ERROR))
    x.on(calls[-1].response, "rpc_fault")
    x.txn(calls, 9, "pnio_error", "read answered with reject 0x1C01000B")
    # ref 10: a normal read afterwards: the channel works again
    calls = s.parameter_access(one(10, 1, [P(964)]), _ok_read(10, 1, [value_block(0x42, [0x1234])]))
    x.txn(calls, 10, "ok")
    return cap, x


# ---- pd_out_of_range.pcap -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One out-of-range transaction: the records, the verdict, and where the
    injected violation shows: rules on the write request ("write"), on the
    final read response ("response") or on every request header ("requests")."""

    request: bytes
    response: bytes | None
    verdict: str
    note: str
    at: str
    rules: tuple[str, ...]
    kw: dict[str, Any] = field(default_factory=dict)
    txn_rules: tuple[str, ...] = ()  # transaction-level rules on the final read response


def _out_of_range_cases() -> list[Case]:
    word, f10 = value_block(0x42, [0x1234]), value_block(0x08, [10.0])
    b7, b1 = {"write_status": DF_B7}, {"write_status": DF_B1}
    pre = "request"  # rules on the write request
    post = "response"  # rules on the final read response
    full = [(P(2100, n_elems=114), value_block(0x06, list(range(114))))]  # a 240-byte change request
    dates = date_value(2026, 1, 1) + b"\x00" + date_value(2026, 1, 2) + b"\x00"  # 2 Dates of 8 bytes
    return [
        # --- parameter requests: P1-P10 and H13 ---
        Case(read_request(0, 1, [P(964)]), None, "pnio_error", "P2 Request Reference 0 (refused: B7)", pre,
             ("pd_request_range",), b7),
        Case(pd_request(2, 0x03, 1, [P(964)]), pd_response(2, 0x80, 1, [error_block(0x21)]), "nak",
             "P2 Request ID 0x03 -> Response ID 0x80, error 0x21", pre, ("pd_request_range",)),
        Case(pd_request(3, REQ_READ, 1, []), None, "pnio_error", "P2 n = 0 (B7)", pre, ("pd_request_range",), b7),
        Case(read_request(4, 1, [P(2000 + i) for i in range(40)]), None, "pnio_error",
             "P2 n = 40: the record is 244 bytes, so H13 too (B1)", pre, ("pd_request_range", "pd_record_length"), b1),
        Case(read_request(5, 1, [P(964, attr=0x40)]), pd_response(5, 0x81, 1, [error_block(0x16)]), "nak",
             "P2 attribute 0x40", pre, ("pd_request_range",)),
        Case(read_request(6, 1, [P(2000, n_elems=235)]), pd_response(6, 0x81, 1, [error_block(0x16)]), "nak",
             "P2 235 elements", pre, ("pd_request_range",)),
        Case(read_request(7, 1, [P(0)]), pd_response(7, 0x81, 1, [error_block(0x00)]), "nak", "P2 PNU 0", pre,
             ("pd_request_range",)),
        Case(read_request(8, 1, [P(964, 0xFFFF)]), pd_response(8, 0x81, 1, [error_block(0x03, 0xFFFF)]), "nak",
             "P3 subindex 0xFFFF", pre, ("subindex_ffff",)),
        Case(pd_request(9, REQ_READ, 1, [P(964)], n_params=2), None, "malformed", "P1 n = 2, one address (B7)", pre,
             ("pd_too_short",), b7),
        Case(pd_request(10, REQ_READ, 1, [P(964)], trailer=bytes.fromhex("deadbeef")), _ok_read(10, 1, [word]), "ok",
             "P5 read request with 4 junk bytes", pre, ("read_request_length",)),
        Case(pd_request(11, REQ_CHANGE, 1, [P(1120), P(1121)], [f10]), None, "malformed",
             "P6 change request: 2 addresses, 1 value block (B7)", pre, ("change_blocks",), b7),
        Case(change_request(12, 1, [(P(1120), zero_block())]), pd_response(12, 0x82, 1, [error_block(0x17)]), "nak",
             "P6 Zero format in a change request", pre, ("change_blocks",)),
        Case(change_request(13, 1, [(P(2000, n_elems=4), value_block(0x07, [1], n_values=4))]), None, "malformed",
             "P6 value block claims 4 Unsigned32, carries 1 (B7)", pre, ("block_overrun",), b7),
        Case(change_request(14, 1, [(P(2000, n_elems=2), value_block(0x06, [1, 2, 3]))]),
             pd_response(14, 0x82, 1, [error_block(0x18)]), "nak", "P7 3 values for 2 elements", pre,
             ("n_values_mismatch",)),
        Case(change_request(15, 1, [(P(2100, n_elems=115), value_block(0x06, list(range(115))))]), None, "pnio_error",
             "P8 230 value bytes: the record is 242 bytes, so H13 too (B1)", pre,
             ("value_too_long", "pd_record_length"), b1),
        Case(change_request(16, 1, [(P(730, n_elems=3), value_block(0x05, [1, 2, 3], pad=b"\x55")), (P(1120), f10)]),
             change_ok(16, 1, 2), "ok", "P8 pad byte 0x55", pre, ("pad_nonzero",)),
        Case(change_request(17, 1, [(P(730, n_elems=3), value_block(0x05, [1, 2, 3], pad=b"")), (P(1120), f10)]),
             change_ok(17, 1, 2), "ok", "P8 pad byte missing", pre, ("pad_missing",)),
        Case(change_request(18, 1, [(P(1082, 6, 1, ATTR_DESCRIPTION), value_block(0x09, "Speed limit".ljust(16)))]),
             pd_response(18, 0x82, 1, [error_block(0x07, 6)]), "nak", "P9 change of a description element", pre,
             ("change_description",)),
        Case(pd_request(19, REQ_CHANGE, 1, [P(1120)], [f10], trailer=b"\x00\x00"), change_ok(19, 1, 1), "ok",
             "P10 two bytes after the change request", pre, ("request_trailing",)),
        Case(pd_request(20, REQ_CHANGE, 1, [a for a, _ in full], [b for _, b in full], trailer=b"\xaa"), None,
             "pnio_error", "H13 write RecordDataLength 241 = 240-byte request + 1 byte (B1)", pre,
             ("request_trailing", "pd_record_length"), b1),
        # --- parameter responses: Q1, Q6-Q13, F1, F2 ---
        Case(read_request(21, 1, [P(964)]), bytes([21, 0x01]), "malformed", "Q1 2-byte response (H13 too)", post,
             ("pd_response_too_short", "pd_record_length")),
        Case(read_request(22, 1, [P(964)]), pd_response(22, 0x05, 1, n_params=1), "reference_mismatch",
             "Q1 Response ID 0x05 (header only); Q3 it does not answer Request ID 0x01", post, ("response_id",),
             txn_rules=("response_id_mismatch",)),
        Case(change_request(23, 1, [(P(1120), f10)]), change_ok(23, 1, 1) + f10, "ok",
             "Q6 positive change response echoing the value", post, ("change_response_body",)),
        Case(read_request(24, 1, [P(964), P(965)]), _ok_read(24, 1, [word, error_block(0x00)]), "ok",
             "Q7 positive read response with an error block", post, ("read_response_blocks",)),
        Case(read_request(25, 1, [P(2000, n_elems=3)]), _ok_read(25, 1, [value_block(0x43, [1, 2])]), "ok",
             "Q7 2 values for 3 elements", post, ("n_values_read",)),
        Case(read_request(26, 1, [P(964)]), pd_response(26, 0x81, 1, [word]), "nak", "Q8 0x81 without an error block",
             post, ("nak_blocks",)),
        Case(change_request(27, 1, [(P(1120), f10), (P(1082), value_block(0x08, [1e6]))]),
             pd_response(27, 0x82, 1, [f10, error_block(0x02, 0)]), "nak",
             "Q8 0x82 with a value block where Zero belongs", post, ("nak_blocks",)),
        Case(read_request(28, 1, [P(964)]), pd_response(28, 0x81, 1, [b"\x44\x00"]), "nak",
             "Q9 error block with 0 values", post, ("error_block_count",)),
        Case(read_request(29, 1, [P(2000, 1)]), pd_response(29, 0x81, 1, [error_block(0x03, 1, extra=[0])]), "nak",
             "Q9 error block with 3 values", post, ("error_block_count",)),
        Case(read_request(30, 1, [P(2000, 9)]), pd_response(30, 0x81, 1, [error_block(0x03)]), "nak",
             "Q9 error 0x03 without its subindex", post, ("error_subindex_presence",)),
        Case(read_request(31, 1, [P(964)]), pd_response(31, 0x81, 1, [error_block(0x30)]), "nak",
             "Q10 reserved error 0x30", post, ("error_reserved",)),
        Case(read_request(32, 1, [P(2100, n_elems=120)]), _ok_read(32, 1, [value_block(0x06, list(range(120)))]),
             "ok", "Q11 246-byte response (read buffer 480, so no H8)", post, ("response_too_long",),
             {"read_kw": {"max_len": 480}}),
        Case(read_request(33, 1, [P(964)]), _ok_read(33, 1, [word]) + b"\xff\xff", "ok",
             "Q12 two bytes after the response", post, ("response_trailing",)),
        Case(read_request(34, 1, [P(964), P(965)]), pd_response(34, 0x01, 1, [word], n_params=2), "malformed",
             "Q12 n = 2, one block", post, ("pd_response_truncated",)),
        Case(read_request(35, 1, [P(2000, n_elems=2)]), _ok_read(35, 1, [value_block(0x43, [1], n_values=2)]),
             "malformed", "Q12 block claims 2 Double words, carries 1", post, ("response_block_overrun",)),
        Case(read_request(36, 1, [P(975, n_elems=6)]), _ok_read(36, 1, [value_block(0x09, "Pump\x071")]), "ok",
             "Q13 VisibleString with a BEL character", post, ("string_nonprintable",)),
        Case(read_request(37, 1, [P(722)]), _ok_read(37, 1, [value_block(0x01, [2])]), "ok", "Q13 Boolean 2", post,
             ("boolean_value",)),
        Case(read_request(38, 1, [P(964)]), _ok_read(38, 1, [value_block(0x0B, b"\x12\x34", n_values=1)]), "ok",
             "F1 unknown format 0x0B in the last block", post, ("format_unsupported",)),
        Case(read_request(39, 1, [P(964), P(965)]), _ok_read(39, 1, [value_block(0x0B, b"\x12\x34", n_values=1), word]),
             "malformed", "F1 unknown format 0x0B before the last block", post, ("format_unsupported_stop",)),
        Case(read_request(40, 1, [P(3105, n_elems=2)]), _ok_read(40, 1, [value_block(0x32, dates, n_values=2)]), "ok",
             "F2 two Dates padded to 8 bytes", post, ("date_padded",)),
        Case(read_request(41, 1, [P(730, n_elems=3)]), _ok_read(41, 1, [value_block(0x05, [1, 2, 3], pad=b"")]), "ok",
             "P8 final pad byte missing in a response", post, ("pad_missing_final",)),
        # --- IOD header of PROFIdrive requests: H10, H14 ---
        Case(read_request(42, 1, [P(964)]), _ok_read(42, 1, [word]), "ok", "H10 API 0 on 0xB02E (write and read)",
             "requests", ("api_not_profidrive",), {"common_kw": {"api": 0}}),
        Case(read_request(43, 1, [P(964)]), _ok_read(43, 1, [word]), "ok", "H14 read RecordDataLength 100", "reads",
             ("pd_read_buffer_small",), {"read_kw": {"max_len": 100}}),
    ]  # fmt: skip


@pd_sample("pd_out_of_range.pcap")
def pd_out_of_range_capture() -> Built:
    """One injected violation per transaction (protocol.md 6.2-6.4), ref =
    position (1-based; ref 1 is the Request Reference 0 case). Where a
    violation necessarily breaks a second rule (a 244-byte request is also
    longer than 240 bytes) both are expected on the same frame."""
    cap = Capture()
    s = session(cap, 1)
    x = Intent(cap)
    for ref, case in enumerate(_out_of_range_cases(), 1):
        calls = s.parameter_access(case.request, case.response, **case.kw)
        txn_findings = [(x.final_res(calls), rule) for rule in case.txn_rules]
        x.txn(calls, case.request[0], case.verdict, case.note, findings=txn_findings)
        frames = {
            "request": [x.write_req(calls)],
            "response": [x.final_res(calls)],
            "reads": x.read_reqs(calls),
            "requests": [x.write_req(calls), *x.read_reqs(calls)],
        }[case.at]
        assert case.request[0] in (ref, 0), ref
        for rule in case.rules:
            x.on(frames, rule)
    return cap, x


# ---- pd_global_and_dpv1_index.pcap ---------------------------------------------------------------------------


@pd_sample("pd_global_and_dpv1_index.pcap")
def pd_global_and_dpv1_index_capture() -> Built:
    """Global access (0xB02F) to several DOs, PROFIdrive over the DPV1 index
    0x002F, and a record at 0x002F that is not PROFIdrive."""
    cap = Capture()
    s = session(cap, 1)
    x = Intent(cap, (GENERIC, "sinamics"))

    calls = s.parameter_access(read_request(1, 2, [P(10)]), _ok_read(1, 2, [value_block(0x06, [1])]), index=0xB02F)
    x.txn(calls, 1, "ok", "B02F DO 2")
    calls = s.parameter_access(change_request(2, 3, [(P(1120), value_block(0x08, [10.0]))]), change_ok(2, 3, 1),
                               index=0xB02F, b5_retries=1)  # fmt: skip
    x.txn(calls, 2, "ok", "B02F DO 3")
    calls = s.parameter_access(read_request(3, 4, [P(2000), P(964)]),
                               _ok_read(3, 4, [value_block(0x08, [3000.0]), value_block(0x42, [0x5678])]),
                               index=0xB02F)  # fmt: skip
    x.txn(calls, 3, "ok", "B02F DO 4")
    calls = s.parameter_access(read_request(4, 1, [P(964)]), _ok_read(4, 1, [value_block(0x42, [0x1234])]),
                               index=0xB02F)  # fmt: skip
    x.txn(calls, 4, "ok", "B02F DO 1")
    # PROFIdrive over index 0x002F: profibus_index on every request header (write and reads)
    calls = s.parameter_access(read_request(5, 1, [P(964)]), _ok_read(5, 1, [value_block(0x42, [0x1234])]),
                               index=0x002F)  # fmt: skip
    x.on([x.write_req(calls), *x.read_reqs(calls)], "profibus_index")
    x.txn(calls, 5, "ok", "0x002F read")
    calls = s.parameter_access(change_request(6, 1, [(P(1121), value_block(0x08, [5.0]))]), change_ok(6, 1, 1),
                               index=0x002F, b5_retries=1)  # fmt: skip
    x.on([x.write_req(calls), *x.read_reqs(calls)], "profibus_index")
    x.txn(calls, 6, "ok", "0x002F change")
    # a vendor data record 47 that is not a PROFIdrive request (reference 0): no transaction
    c = s.write(0x002F, bytes.fromhex("0000000102030405"), api=0)
    x.on(c.request, "profibus_index")
    x.on(c.request, "not_profidrive")
    return cap, x


# ---- pd_akd_like.pcap ------------------------------------------------------------------------------------------


@pd_sample("pd_akd_like.pcap")
def pd_akd_like_capture() -> Built:
    """A Kollmorgen-AKD-like drive: DO 0, formats 0x41-0x43, 0x82 with format
    0x00 'no data', positive change response + 00 00, one address echo."""
    cap = Capture()
    s = session(cap, 1)
    x = Intent(cap, (GENERIC, "akd"))

    calls = s.parameter_access(read_request(1, 0, [P(200)]), _ok_read(1, 0, [value_block(0x43, [0x000186A0])]))
    x.txn(calls, 1, "ok", "read DWord")
    calls = s.parameter_access(change_request(2, 0, [(P(201), value_block(0x43, [5000]))]),
                               change_ok(2, 0, 1) + b"\x00\x00", b5_retries=1)  # fmt: skip
    x.on(x.final_res(calls), "change_response_body", profiles=[GENERIC])
    x.on(x.final_res(calls), "akd_trailing_zero", profiles=["akd"])
    x.txn(calls, 2, "ok", "positive change response + 00 00 (AKD manual)")
    req = read_request(3, 0, [P(202), P(203), P(204)])
    res = _ok_read(3, 0, [value_block(0x41, [0x7F]), value_block(0x42, [0x0102]), value_block(0x43, [7])])
    x.txn(s.parameter_access(req, res), 3, "ok", "Byte (+pad), Word, DWord")
    calls = s.parameter_access(
        change_request(4, 0, [(P(205), value_block(0x42, [10])), (P(206), value_block(0x43, [10**9]))]),
        pd_response(4, 0x82, 0, [zero_block(fmt=0x00), error_block(0x02, 0)]),
    )
    x.on(x.final_res(calls), "format_zero_akd", profiles=[GENERIC])  # F3: 0x00 instead of 0x40
    x.on(x.final_res(calls), "nak_blocks", profiles=[GENERIC])  # Q8: a 0x82 block neither 0x40 nor 0x44
    x.txn(calls, 4, "nak", "0x82: format 0x00 'no data' + error 0x02")
    echo = akd_echo_response(5, 0x01, 0, P(207), value_block(0x43, [0x12345678]))
    calls = s.parameter_access(read_request(5, 0, [P(207)]), echo, b5_retries=1)
    x.on(x.final_res(calls), "akd_address_echo")  # V1, under every profile
    x.txn(calls, 5, "ok", "response with the AKD address echo")
    calls = s.parameter_access(read_request(6, 0, [P(9999)]), pd_response(6, 0x81, 0, [error_block(0x00)]))
    x.txn(calls, 6, "nak", "error 0x00")
    calls = s.parameter_access(change_request(7, 0, [(P(208), value_block(0x41, [1]))]), change_ok(7, 0, 1))
    x.txn(calls, 7, "ok", "Byte change (+pad), header-only response")
    return cap, x


# ---- pd_yaskawa_like.pcap --------------------------------------------------------------------------------------


def v1000(register: int, *, n_elems: int = 0) -> P:
    """A V1000 drive parameter by its register: PNU = group (high byte),
    subindex = parameter number (low byte), e.g. b1-01 = 0x0180."""
    return P(register >> 8, register & 0xFF, n_elems)


B1_01, C1_01, E2_01 = 0x0180, 0x0200, 0x030E


@pd_sample("pd_yaskawa_like.pcap")
def pd_yaskawa_like_capture() -> Built:
    """A Yaskawa-SI-EP3-like drive: one parameter per request, DO 1, API 0 or
    0x3A00, slot/subslot 1, group/number addressing; then requests that
    break the Yaskawa limits (vendor_limit under --profile yaskawa only)."""
    cap = Capture()
    s: PnioSession = session(cap, 1)
    x = Intent(cap, (GENERIC, "yaskawa"))
    api0 = {"api": 0}

    def api_dap(calls: list) -> None:
        frames = [x.write_req(calls), *x.read_reqs(calls)]
        x.on(frames, "api_not_profidrive", profiles=[GENERIC])
        x.on(frames, "api_dap_yaskawa", profiles=["yaskawa"])

    # --- part 1: within the Yaskawa limits ---
    calls = s.parameter_access(read_request(1, 1, [P(964, 1)]), _ok_read(1, 1, [value_block(0x06, [0x0136])]))
    x.txn(calls, 1, "ok", "P964[1] over API 0x3A00")
    calls = s.parameter_access(read_request(2, 1, [v1000(B1_01)]), _ok_read(2, 1, [value_block(0x06, [1])]),
                               common_kw=api0)  # fmt: skip
    api_dap(calls)
    x.txn(calls, 2, "ok", "b1-01 over API 0")
    calls = s.parameter_access(change_request(3, 1, [(v1000(C1_01), value_block(0x06, [100]))]), change_ok(3, 1, 1),
                               b5_retries=1, common_kw=api0)  # fmt: skip
    api_dap(calls)
    x.txn(calls, 3, "ok", "C1-01 = 10.0 s over API 0")
    calls = s.parameter_access(read_request(4, 1, [v1000(E2_01)]), _ok_read(4, 1, [value_block(0x06, [290])]),
                               b5_retries=2)  # fmt: skip
    x.txn(calls, 4, "ok", "E2-01 with 2 B5")
    calls = s.parameter_access(read_request(5, 1, [v1000(0x0F00)]), pd_response(5, 0x81, 1, [error_block(0x00)]))
    x.txn(calls, 5, "nak", "group 0x0F does not exist")

    # --- part 2: outside the Yaskawa limits (generic profile: inside) ---
    calls = s.parameter_access(read_request(6, 1, [v1000(B1_01), v1000(C1_01)]),
                               pd_response(6, 0x81, 1, [error_block(0x23)], n_params=2))  # fmt: skip
    x.on(x.write_req(calls), "vendor_limit", profiles=["yaskawa"])  # n = 2
    x.on(x.final_res(calls), "header_level_error")
    x.txn(calls, 6, "nak", "n = 2 -> header-level 0x23")
    calls = s.parameter_access(read_request(7, 1, [P(964, 0, 1, ATTR_DESCRIPTION)]),
                               pd_response(7, 0x81, 1, [error_block(0x16)]))  # fmt: skip
    x.on(x.write_req(calls), "vendor_limit", profiles=["yaskawa"])  # attribute 0x20
    x.txn(calls, 7, "nak", "attribute 0x20")
    calls = s.parameter_access(read_request(8, 0, [v1000(B1_01)]), _ok_read(8, 0, [value_block(0x06, [1])]))
    x.on(x.write_req(calls), "vendor_limit", profiles=["yaskawa"])  # request DO 0
    x.on(x.final_res(calls), "vendor_limit", profiles=["yaskawa"])  # mirrored DO 0 ("to be set to 1")
    x.txn(calls, 8, "ok", "DO 0 (mirrored)")
    calls = s.parameter_access(read_request(9, 1, [v1000(B1_01)]), _ok_read(9, 1, [value_block(0x06, [1])]),
                               common_kw={"slot": 2})  # fmt: skip
    x.on([x.write_req(calls), *x.read_reqs(calls)], "vendor_limit", profiles=["yaskawa"])  # slot 2
    x.txn(calls, 9, "ok", "slot 2")
    return cap, x

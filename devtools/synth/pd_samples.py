"""PROFIdrive parameter-access samples (issue "PROFIdrive parameter access",
item 7), first part: clean commissioning, negative responses, B5 and PNIO
errors. The injected range violations are in pd_range_samples.py, the
global/DPV1 indices and the AKD-like and Yaskawa-like drives in
pd_vendor_samples.py.

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

from typing import Any

from . import rpc_encode
from .catalog import Built, pd_sample
from .expect import GENERIC, Intent
from .fixtures import DE_B1, DE_B2, DF_B0, DF_B1, DF_B7, ok_read, session
from .pd_encode import (
    ATTR_DESCRIPTION,
    ATTR_TEXT,
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
from .sim_capture import Capture

# NCA status of the RPC fault / reject that answer a call instead of a response
NCA_SERVER_TOO_BUSY = 0x1C010014
NCA_PROTO_ERROR = 0x1C01000B

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
    x.txn(s.parameter_access(req, ok_read(1, 1, blocks), b5_retries=1), 1, "ok", "39 parameters in one request")

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
    x.txn(s.parameter_access(req, ok_read(2, 1, [b for _, b in numeric])), 2, "ok", "numeric formats")

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
    x.txn(s.parameter_access(req, ok_read(3, 1, [b for _, b in strings]), b5_retries=1), 3, "ok",
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
    x.txn(s.parameter_access(req, ok_read(4, 1, [b for _, b in special])), 4, "ok", "N2/N4/E2/C4/T2/T4/V2/L2/...")

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
    x.txn(s.parameter_access(req, ok_read(5, 1, [b for _, b in descr]), b5_retries=2), 5, "ok",
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
    res = ok_read(9, 1, [value_block(0x08, [10.0]), value_block(0x05, [1, 0, 1])])
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
    calls = s.parameter_access(one(1, 1, [P(964)]), ok_read(1, 1, [value_block(0x42, [0x1234])]),
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
    calls = s.parameter_access(one(10, 1, [P(964)]), ok_read(10, 1, [value_block(0x42, [0x1234])]))
    x.txn(calls, 10, "ok")
    return cap, x

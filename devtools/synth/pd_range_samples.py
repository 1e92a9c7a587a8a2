"""pd_out_of_range.pcap: one injected violation per transaction (protocol.md 6.2-6.4), from
the parameter request and response checks P1-P10, Q1, Q6-Q13, F1, F2 to the IOD header checks H10,
H13, H14, each with the verdict the transaction gets.

Built like pd_samples.py: the case table says where each violation shows and which rules must fire.

Conventions as sample_pcaps/README.md: session 1 (.11 -> .21), API 0x3A00,
slot 1/1, Index 0xB02E, DO 1, read RecordDataLength 240, references counting
up per transaction (never reused, so no transaction-level T findings).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .catalog import Built, pd_sample
from .expect import Intent
from .fixtures import DF_B1, DF_B7, ok_read, session
from .pd_encode import (
    ATTR_DESCRIPTION,
    REQ_CHANGE,
    REQ_READ,
    change_ok,
    change_request,
    date_value,
    error_block,
    pd_request,
    pd_response,
    read_request,
    value_block,
    zero_block,
)
from .pd_encode import ParamAddress as P
from .sim_capture import Capture

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
        Case(pd_request(10, REQ_READ, 1, [P(964)], trailer=bytes.fromhex("deadbeef")), ok_read(10, 1, [word]), "ok",
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
        Case(read_request(24, 1, [P(964), P(965)]), ok_read(24, 1, [word, error_block(0x00)]), "ok",
             "Q7 positive read response with an error block", post, ("read_response_blocks",)),
        Case(read_request(25, 1, [P(2000, n_elems=3)]), ok_read(25, 1, [value_block(0x43, [1, 2])]), "ok",
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
        Case(read_request(32, 1, [P(2100, n_elems=120)]), ok_read(32, 1, [value_block(0x06, list(range(120)))]),
             "ok", "Q11 246-byte response (read buffer 480, so no H8)", post, ("response_too_long",),
             {"read_kw": {"max_len": 480}}),
        Case(read_request(33, 1, [P(964)]), ok_read(33, 1, [word]) + b"\xff\xff", "ok",
             "Q12 two bytes after the response", post, ("response_trailing",)),
        Case(read_request(34, 1, [P(964), P(965)]), pd_response(34, 0x01, 1, [word], n_params=2), "malformed",
             "Q12 n = 2, one block", post, ("pd_response_truncated",)),
        Case(read_request(35, 1, [P(2000, n_elems=2)]), ok_read(35, 1, [value_block(0x43, [1], n_values=2)]),
             "malformed", "Q12 block claims 2 Double words, carries 1", post, ("response_block_overrun",)),
        Case(read_request(36, 1, [P(975, n_elems=6)]), ok_read(36, 1, [value_block(0x09, "Pump\x071")]), "ok",
             "Q13 VisibleString with a BEL character", post, ("string_nonprintable",)),
        Case(read_request(37, 1, [P(722)]), ok_read(37, 1, [value_block(0x01, [2])]), "ok", "Q13 Boolean 2", post,
             ("boolean_value",)),
        Case(read_request(38, 1, [P(964)]), ok_read(38, 1, [value_block(0x0B, b"\x12\x34", n_values=1)]), "ok",
             "F1 unknown format 0x0B in the last block", post, ("format_unsupported",)),
        Case(read_request(39, 1, [P(964), P(965)]), ok_read(39, 1, [value_block(0x0B, b"\x12\x34", n_values=1), word]),
             "malformed", "F1 unknown format 0x0B before the last block", post, ("format_unsupported_stop",)),
        Case(read_request(40, 1, [P(3105, n_elems=2)]), ok_read(40, 1, [value_block(0x32, dates, n_values=2)]), "ok",
             "F2 two Dates padded to 8 bytes", post, ("date_padded",)),
        Case(read_request(41, 1, [P(730, n_elems=3)]), ok_read(41, 1, [value_block(0x05, [1, 2, 3], pad=b"")]), "ok",
             "P8 final pad byte missing in a response", post, ("pad_missing_final",)),
        # --- IOD header of PROFIdrive requests: H10, H14 ---
        Case(read_request(42, 1, [P(964)]), ok_read(42, 1, [word]), "ok", "H10 API 0 on 0xB02E (write and read)",
             "requests", ("api_not_profidrive",), {"common_kw": {"api": 0}}),
        Case(read_request(43, 1, [P(964)]), ok_read(43, 1, [word]), "ok", "H14 read RecordDataLength 100", "reads",
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
        frames = {
            "request": [x.write_req(calls)],
            "response": [x.final_res(calls)],
            "reads": x.read_reqs(calls),
            "requests": [x.write_req(calls), *x.read_reqs(calls)],
        }[case.at]
        # a malformed one: the PDU its violation makes undecodable decided the verdict (T8 there)
        x.txn(calls, case.request[0], case.verdict, case.note, findings=txn_findings,
              decided=frames[0] if case.verdict == "malformed" else None)
        assert case.request[0] in (ref, 0), ref
        for rule in case.rules:
            x.on(frames, rule)
    return cap, x

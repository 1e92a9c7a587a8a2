"""PROFIdrive samples of addressing and vendor dialects: global access (0xB02F) and the DPV1
index 0x002F, a Kollmorgen-AKD-like drive and a Yaskawa-SI-EP3-like drive, each with the findings
its vendor profile changes.

Built like pd_samples.py: every finding declared on the line that causes it, per profile.

Conventions as sample_pcaps/README.md: session 1 (.11 -> .21), API 0x3A00,
slot 1/1, Index 0xB02E, DO 1, read RecordDataLength 240, references counting
up per transaction (never reused, so no transaction-level T findings).
"""

from __future__ import annotations

from .catalog import Built, pd_sample
from .expect import GENERIC, Intent
from .fixtures import ok_read, session
from .pd_encode import (
    ATTR_DESCRIPTION,
    akd_echo_response,
    change_ok,
    change_request,
    error_block,
    pd_response,
    read_request,
    value_block,
    zero_block,
)
from .pd_encode import ParamAddress as P
from .pnio_session import PnioSession
from .sim_capture import Capture

# ---- pd_global_and_dpv1_index.pcap ---------------------------------------------------------------------------


@pd_sample("pd_global_and_dpv1_index.pcap")
def pd_global_and_dpv1_index_capture() -> Built:
    """Global access (0xB02F) to several DOs, PROFIdrive over the DPV1 index
    0x002F, and a record at 0x002F that is not PROFIdrive."""
    cap = Capture()
    s = session(cap, 1)
    x = Intent(cap, (GENERIC, "sinamics"))

    calls = s.parameter_access(read_request(1, 2, [P(10)]), ok_read(1, 2, [value_block(0x06, [1])]), index=0xB02F)
    x.txn(calls, 1, "ok", "B02F DO 2")
    calls = s.parameter_access(change_request(2, 3, [(P(1120), value_block(0x08, [10.0]))]), change_ok(2, 3, 1),
                               index=0xB02F, b5_retries=1)  # fmt: skip
    x.txn(calls, 2, "ok", "B02F DO 3")
    calls = s.parameter_access(read_request(3, 4, [P(2000), P(964)]),
                               ok_read(3, 4, [value_block(0x08, [3000.0]), value_block(0x42, [0x5678])]),
                               index=0xB02F)  # fmt: skip
    x.txn(calls, 3, "ok", "B02F DO 4")
    calls = s.parameter_access(read_request(4, 1, [P(964)]), ok_read(4, 1, [value_block(0x42, [0x1234])]),
                               index=0xB02F)  # fmt: skip
    x.txn(calls, 4, "ok", "B02F DO 1")
    # PROFIdrive over index 0x002F: profibus_index on every request header (write and reads)
    calls = s.parameter_access(read_request(5, 1, [P(964)]), ok_read(5, 1, [value_block(0x42, [0x1234])]),
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

    calls = s.parameter_access(read_request(1, 0, [P(200)]), ok_read(1, 0, [value_block(0x43, [0x000186A0])]))
    x.txn(calls, 1, "ok", "read DWord")
    calls = s.parameter_access(change_request(2, 0, [(P(201), value_block(0x43, [5000]))]),
                               change_ok(2, 0, 1) + b"\x00\x00", b5_retries=1)  # fmt: skip
    x.on(x.final_res(calls), "change_response_body", profiles=[GENERIC])
    x.on(x.final_res(calls), "akd_trailing_zero", profiles=["akd"])
    x.txn(calls, 2, "ok", "positive change response + 00 00 (AKD manual)")
    req = read_request(3, 0, [P(202), P(203), P(204)])
    res = ok_read(3, 0, [value_block(0x41, [0x7F]), value_block(0x42, [0x0102]), value_block(0x43, [7])])
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
    calls = s.parameter_access(read_request(1, 1, [P(964, 1)]), ok_read(1, 1, [value_block(0x06, [0x0136])]))
    x.txn(calls, 1, "ok", "P964[1] over API 0x3A00")
    calls = s.parameter_access(read_request(2, 1, [v1000(B1_01)]), ok_read(2, 1, [value_block(0x06, [1])]),
                               common_kw=api0)  # fmt: skip
    api_dap(calls)
    x.txn(calls, 2, "ok", "b1-01 over API 0")
    calls = s.parameter_access(change_request(3, 1, [(v1000(C1_01), value_block(0x06, [100]))]), change_ok(3, 1, 1),
                               b5_retries=1, common_kw=api0)  # fmt: skip
    api_dap(calls)
    x.txn(calls, 3, "ok", "C1-01 = 10.0 s over API 0")
    calls = s.parameter_access(read_request(4, 1, [v1000(E2_01)]), ok_read(4, 1, [value_block(0x06, [290])]),
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
    calls = s.parameter_access(read_request(8, 0, [v1000(B1_01)]), ok_read(8, 0, [value_block(0x06, [1])]))
    x.on(x.write_req(calls), "vendor_limit", profiles=["yaskawa"])  # request DO 0
    x.on(x.final_res(calls), "vendor_limit", profiles=["yaskawa"])  # mirrored DO 0 ("to be set to 1")
    x.txn(calls, 8, "ok", "DO 0 (mirrored)")
    calls = s.parameter_access(read_request(9, 1, [v1000(B1_01)]), ok_read(9, 1, [value_block(0x06, [1])]),
                               common_kw={"slot": 2})  # fmt: skip
    x.on([x.write_req(calls), *x.read_reqs(calls)], "vendor_limit", profiles=["yaskawa"])  # slot 2
    x.txn(calls, 9, "ok", "slot 2")
    return cap, x

"""Edge samples (issue "Right on every edge"): what a fault trace holds at its edges, each case with the
verdict protocol.md 7.3/7.4 gives it.

pd_edge_cases.pcap: write requests cut by damage (one inside its IOD header, one inside its record),
each answered and then read as usual; a global (0xB02F) and a local (0xB02E) channel on one AR, the global
write left to time out while a read on 0xB02E finds no write of its own (the fallback pairing never crosses
indexes, 7.2); a busy drive given up by the next write and by the deadline after B5 answers only (7.3 step
5); a Write-Multiple whose outer RecordDataLength counts the last record's pad bytes (2.8, H11), once with
zero pad bytes and once with non-zero ones; whole-request errors (a header-level error on three
parameters, a request of no parameter); and a busy transaction still open when the capture ends.

pd_sew_movilink.pcap: SEW MOVILINK services carried in the PROFIdrive record (protocol.md 5.5): READ,
WRITE volatile, a negative answer with a MOVILINK error word, READ minimum, and a PROFIdrive read.

Built like txn_samples.py: sessions one after the other on the capture's clock, every transaction and
every finding declared on the line that causes it.
"""

from __future__ import annotations

from typing import Any

from . import pnio_encode
from .capture_files import Frame
from .catalog import Built, pd_sample
from .expect import GENERIC, Intent
from .fixtures import session
from .pd_encode import ParamAddress as P
from .pd_encode import change_ok, change_request, error_block, pd_request, pd_response, read_request, value_block
from .rpc_session import Call
from .sim_capture import Capture

# Bytes before the IOD header of a request frame: Ethernet 14, IPv4 20, UDP 8, CL-RPC header 80, NDR args 20
IOD_AT = 14 + 20 + 8 + 80 + 20
RECORD_AT = IOD_AT + 64


def _word(ref: int, value: int = 0x1234) -> bytes:
    return pd_response(ref, 0x01, 1, [value_block(0x42, [value])])


def _cut(cap: Capture, call: Call, keep: int) -> Frame:
    """The call's request frame captured with only its first `keep` bytes (damage or a short snaplen on one
    interface): the record header keeps the length on the wire, as libpcap does."""
    old = call.request[0]
    new = Frame(old.ts_ns, old.data[:keep], old.linktype, len(old.data), old.iface)
    at = next(i for i, f in enumerate(cap.frames) if f is old)
    cap.frames[at] = call.request[0] = new
    return new


@pd_sample("pd_edge_cases.pcap")
def pd_edge_cases_capture() -> Built:
    cap = Capture()
    x = Intent(cap)

    # --- session 1 (.11 -> .21): writes cut short (protocol.md 7.3 step 1) -------------------------------
    s = session(cap, 1)
    calls = s.parameter_access(change_request(1, 1, [(P(1120), value_block(0x08, [10.0]))]), change_ok(1, 1, 1),
                               b5_retries=2)  # fmt: skip
    cut = _cut(cap, calls[0], IOD_AT + 28)  # cut inside the IOD header, before its Index
    x.on(cut, "rpc_truncated")
    x.on(cut, "truncated_capture_pnio")
    x.on(cut, "iod_truncated")
    x.txn(calls, None, "malformed", "write cut inside its IOD header (its reference unknown): opened by its "
          "response (index 0xB02E); its two B5 reads and the response pair with it", decided=cut)
    calls = s.parameter_access(read_request(2, 1, [P(964)]), _word(2), b5_retries=1)
    cut = _cut(cap, calls[0], RECORD_AT + 6)  # cut inside the record (6 of 10 bytes)
    x.on(cut, "rpc_truncated")
    x.on(cut, "truncated_capture_pnio")
    x.on(cut, "record_truncated")
    x.txn(calls, 2, "malformed", "write cut inside its record", decided=cut)
    x.txn(s.parameter_access(read_request(3, 1, [P(965)]), _word(3)), 3, "ok", "the next one pairs as usual")

    # --- session 2 (.12 -> .22): 0xB02F and 0xB02E on one AR (protocol.md 7.2) -------------------------------
    s = session(cap, 2)
    calls = s.parameter_access(read_request(1, 2, [P(10)]), None, index=0xB02F)
    x.txn(calls, 1, "timeout", "global channel: write accepted, never read: the deadline closes it mid-capture")
    x.txn(s.parameter_access(read_request(1, 1, [P(964)]), _word(1), b5_retries=1), 1, "ok", "local channel")
    c = s.read(0xB02E, status=pnio_encode.STATUS_B5)  # the idle local channel answers B5
    x.loose(c.request[0], "read_without_request")  # never paired with the pending 0xB02F write

    # --- session 3 (.13 -> .23): a busy drive given up (protocol.md 7.3 step 5) ------------------------------
    s = session(cap, 3)
    calls = s.parameter_access(change_request(1, 1, [(P(971), value_block(0x06, [1]))]), None, b5_retries=3,
                               read_gap_us=100_000)  # fmt: skip
    x.txn(calls, 1, "pnio_error", "three B5, then the controller writes again: refused, not silent (DE80B500)")
    given_up = calls
    calls = s.parameter_access(change_request(2, 1, [(P(971), value_block(0x06, [1]))]), change_ok(2, 1, 1),
                               b5_retries=1)  # fmt: skip
    x.txn(calls, 2, "ok", "the next write", findings=[(x.write_req(calls), "write_while_pending")])
    x.superseded(given_up, x.write_req(calls))
    calls = s.parameter_access(read_request(3, 1, [P(964)]), None, b5_retries=4, read_gap_us=2_000_000)
    x.txn(calls, 3, "pnio_error", "four B5 over 8 s, then no more reads: the deadline passes inside the capture")
    cap.clock.advance_us(3_000_000)  # beyond both deadlines before the next frame

    # --- session 4 (.14 -> .24): Write-Multiple padded after its last record (protocol.md 2.8, H11) ---------
    s = session(cap, 4)
    multi = s.write_multiple([(0x1000, bytes(5)), (0xB02E, read_request(1, 1, [P(964)]))],
                             outer={"pad_after_last": True})  # fmt: skip
    calls = [multi, s.read(0xB02E, status=pnio_encode.STATUS_B5), s.read(0xB02E, _word(1))]
    x.txn(calls, 1, "ok", "Write-Multiple: outer RecordDataLength counts the last record's 2 zero pad bytes")
    multi = s.write_multiple([(0x1001, bytes(6))], outer={"pad_after_last": True, "pad_fill": 0xFF})
    x.on(multi.request[0], "multi_write_padding")  # the pad bytes after the last record are not zero

    # --- session 5 (.15 -> .25): errors on the whole request ---------------------------------------------
    s = session(cap, 5)
    calls = s.parameter_access(read_request(1, 1, [P(964), P(965), P(10)]),
                               pd_response(1, 0x81, 1, [error_block(0x23)], n_params=3))  # fmt: skip
    x.on(x.final_res(calls), "header_level_error")
    x.txn(calls, 1, "nak", "one error block 0x23 for three parameters: every parameter row carries it")
    calls = s.parameter_access(pd_request(2, 0x01, 1, []), pd_response(2, 0x81, 1, [error_block(0x16)], n_params=0))
    x.on(x.write_req(calls), "pd_request_range")  # No. of parameters 0
    x.txn(calls, 2, "nak", "a request of no parameter refused with 0x16: one parameter row, empty PNU")

    # --- session 6 (.16 -> .26): still busy when the capture ends -------------------------------------------
    s = session(cap, 6)
    calls = s.parameter_access(change_request(1, 1, [(P(971), value_block(0x06, [1]))]), None, b5_retries=2,
                               read_gap_us=1_000_000)  # fmt: skip
    x.txn(calls, 1, "timeout", "two B5, then the capture ends 2 s after the write", capture_ended=True)
    return cap, x


# ---- pd_sew_movilink.pcap --------------------------------------------------------------------------------------
SEW = "sew"
SEW_KW = {"api": 0, "slot": 0, "subslot": 1}  # data set 47 as the SEW manuals address it (protocol.md 5.5)
FIRMWARE, P170 = 8300, 0x2129  # MOVILINK index 8300 "firmware version"; P170 is index 0x2129


def _movilink(ref: int, service: int, index: int, value: int | None = None) -> bytes:
    """A MOVILINK service in the PROFIdrive record: Request ID 0x40, axis 0, the service in the Attribute's
    high nibble, a double word after the address for the WRITE services."""
    values = [value_block(0x43, [value])] if value is not None else []
    return pd_request(ref, 0x40, 0, [P(index, 0, 0, service)], values)


@pd_sample("pd_sew_movilink.pcap")
def pd_sew_movilink_capture() -> Built:
    """SEW MOVILINK services over data set 47 (index 0x002F, API 0, slot 0, subslot 1), session 1. Under
    `--profile sew` each is decoded and paired (tests/test_sew_profile.py asserts those verdicts); under the
    generic profile Request ID 0x40 stays reserved: the records are not PROFIdrive (N1 not_profidrive),
    no transaction opens, and only the one PROFIdrive read is a transaction."""
    cap = Capture()
    x = Intent(cap, (GENERIC, SEW))
    s = session(cap, 1)

    def sew_access(request: bytes, response: bytes, **kw: Any) -> list[Call]:
        calls = s.parameter_access(request, response, index=0x002F, common_kw=SEW_KW, **kw)
        x.on([x.write_req(calls), *x.read_reqs(calls)], "profibus_index")
        return calls

    def movilink(request: bytes, response: bytes, **kw: Any) -> None:
        """Under the generic profile: the write and the answer are not PROFIdrive (N1), no transaction
        opens and its reads find none (T2)."""
        calls = sew_access(request, response, **kw)
        x.on([x.write_req(calls), x.final_res(calls)], "not_profidrive", profiles=[GENERIC])
        x.loose(x.read_reqs(calls), "read_without_request")

    # ref 1: READ parameter 8300, the manuals' example: 0x311C7289
    movilink(_movilink(1, 0x10, FIRMWARE), pd_response(1, 0x40, 0, [value_block(0x43, [0x311C7289])]), b5_retries=1)
    # ref 2: WRITE parameter volatile P170 = 3000, answered header only
    movilink(_movilink(2, 0x30, P170, 3000), pd_response(2, 0x40, 0, n_params=1))
    # ref 3: READ parameter of an index the drive does not have: negative, MOVILINK error class 0x08, code 0x11
    movilink(_movilink(3, 0x10, 0x1234), pd_response(3, 0xC0, 0, [error_block(0x0811)]))
    # ref 4: READ minimum of P170
    movilink(_movilink(4, 0x40, P170), pd_response(4, 0x40, 0, [value_block(0x43, [0])]))
    # ref 5: a PROFIdrive read of the same double word (SEW supports it, DO 0 = the single axis)
    calls = sew_access(read_request(5, 0, [P(FIRMWARE)]), pd_response(5, 0x01, 0, [value_block(0x43, [0x311C7289])]))
    x.txn(calls, 5, "ok", "PROFIdrive Request ID 0x01 on an SEW drive")
    return cap, x

"""Transaction samples (issue "Transactions: pair requests with responses, flag NAKs, record errors,
retries and timeouts", item 6): interleaved channels of several controllers and drives, retries and
duplicates, timeouts.

Built like pd_samples.py: each `*_capture()` returns the capture and its Intent, every transaction
declared with `x.txn(...)` (verdict of protocol.md 7.4; reads, B5 answers, duplicate requests, closing
PNIOStatus and the 7.6 figures follow from the calls), every transaction-level finding (6.5 T1-T6) and
frame-level finding on the line that causes it. Several sessions run on their own clocks and are merged
by time (`Capture.time_sorted`), so frame numbers are known only at the end; the Intent resolves them.

Hosts: controllers 192.168.1.1c (c = 1, 2, ...), drives 192.168.1.2d, as sample_pcaps/README.md; the
session of controller c with drive d uses activity 000000ac-...-cd and ARUUID 000000a2-...-cd (hex
digits c and d); a second channel on the same AR uses its own activity 000000ac-...-1cd.
"""

from __future__ import annotations

from typing import Any

from . import pnio_encode
from .capture_files import Frame
from .catalog import Built, pd_sample
from .expect import Intent
from .fixtures import DE_B2, DF_B1, DF_B5, fixed_uuid, plant
from .pd_encode import ParamAddress as P
from .pd_encode import change_ok, change_request, error_block, pd_response, read_request, value_block
from .pnio_session import PnioSession
from .rpc_session import Call
from .sim_capture import EPOCH_NS, Capture, Clock, Host

MS = 1_000_000  # ns


def _hosts(n: int) -> tuple[list[Host], list[Host]]:
    """Controllers .11 ... and drives .21 ..., one Host object per address (shared by its sessions)."""
    pairs = [plant(i) for i in range(1, n + 1)]
    return [c for c, _ in pairs], [d for _, d in pairs]


def _session(
    cap: Capture, ctrl: Host, dev: Host, c: int, d: int, start_ms: float, *, channel: int = 0, **kw: Any
) -> PnioSession:
    """Controller c with drive d on its own clock; channel 1 = a second activity on the same AR."""
    return PnioSession(cap, ctrl, dev, activity=fixed_uuid(0xAC, 0x100 * channel + 0x10 * c + d),
                       ar_uuid=fixed_uuid(0xA2, 0x10 * c + d), own_clock=Clock(EPOCH_NS + round(start_ms * MS)),
                       **kw)  # fmt: skip


def _word(ref: int, do: int = 1, value: int = 0x1234) -> bytes:
    return pd_response(ref, 0x01, do, [value_block(0x42, [value])])


def _mirror(cap: Capture, calls: list[Call], delay_ns: int = 4000) -> tuple[list[Frame], list[Frame]]:
    """Every frame of the calls captured a second time, frame-identical, `delay_ns` later (a mirror port
    that sees both directions twice). A duplicate request is a retransmission to the analyser (counted
    on its call); a duplicate response is not decoded again (protocol.md 2.4); both belong to the call's
    transaction (its frames). Returns the copies of the requests and of the responses."""
    req_copies, res_copies = [], []
    for c in calls:
        req_copies += [cap.repeat(f, (f.ts_ns or 0) + delay_ns) for f in c.request]
        res_copies += [cap.repeat(f, (f.ts_ns or 0) + delay_ns) for f in c.response]
        c.retransmits += 1
    return req_copies, res_copies


# ---- pd_interleaved.pcap -----------------------------------------------------------------------------------


@pd_sample("pd_interleaved.pcap")
def pd_interleaved_capture() -> Built:
    """Three controllers x four drives at once: twelve ARs on their own clocks, merged by time, so
    transactions of different channels overlap; drive .21 (from controller .11) has a second channel on
    the same AR (slot 2, own activity) and drive .22 (from .12) a global channel 0xB02F, both busy at the
    same time as the first channel. Mixed verdicts; one read answered from another UDP port."""
    cap = Capture()
    x = Intent(cap)
    ctrls, devs = _hosts(4)
    ctrls = ctrls[:3]
    s: dict[tuple[int, int], PnioSession] = {}
    for c in range(1, 4):
        for d in range(1, 5):
            # start 0.37 ms apart, RTT 1.9 ... 4.1 ms: every channel overlaps several others
            s[c, d] = _session(cap, ctrls[c - 1], devs[d - 1], c, d, 0.37 * (4 * (c - 1) + d - 1),
                               rtt_us=1100 + 200 * (3 * d + c), gap_us=700 + 90 * (c + d))  # fmt: skip

    f32 = 0x08

    def read1(key: tuple[int, int], ref: int, pnu: int, **kw: Any) -> list[Call]:
        return s[key].parameter_access(read_request(ref, 1, [P(pnu)]), _word(ref, 1, pnu), **kw)

    # controller .11
    x.txn(read1((1, 1), 1, 964, b5_retries=1), 1, "ok", ".11 -> .21 slot 1")
    x.txn(read1((1, 2), 1, 965), 1, "ok", ".11 -> .22")
    calls = s[1, 3].parameter_access(read_request(1, 1, [P(9999)]), pd_response(1, 0x81, 1, [error_block(0x00)]))
    x.txn(calls, 1, "nak", ".11 -> .23: P9999 does not exist")
    x.txn(read1((1, 4), 1, 966, b5_retries=2), 1, "ok", ".11 -> .24")
    # .11 -> .21, second channel on the same AR: slot 2, its own activity, overlapping the slot 1 transaction
    s2 = _session(cap, ctrls[0], devs[0], 1, 1, 0.9, channel=1, slot=2, rtt_us=2500, gap_us=600)
    calls = s2.parameter_access(change_request(1, 1, [(P(1120), value_block(f32, [10.0]))]), change_ok(1, 1, 1),
                                b5_retries=2)  # fmt: skip
    x.txn(calls, 1, "ok", ".11 -> .21 slot 2 (second channel of the AR)")
    calls = s2.parameter_access(read_request(2, 1, [P(1120)]), _word(3, 1))
    x.txn(
        calls,
        2,
        "reference_mismatch",
        ".11 -> .21 slot 2: response carries reference 3",
        findings=[(x.final_res(calls), "reference_mismatch")],
    )
    x.txn(read1((1, 1), 2, 967), 2, "ok", ".11 -> .21 slot 1 again")

    # controller .12
    x.txn(read1((2, 1), 1, 964), 1, "ok", ".12 -> .21")
    x.txn(read1((2, 2), 1, 964, b5_retries=1), 1, "ok", ".12 -> .22 B02E")
    # .12 -> .22: global access 0xB02F to DO 2 on a second activity of the same AR, while B02E is busy
    g = _session(cap, ctrls[1], devs[1], 2, 2, 1.3, channel=1, rtt_us=1700, gap_us=500)
    calls = g.parameter_access(read_request(1, 2, [P(10)]), pd_response(1, 0x01, 2, [value_block(0x06, [2])]),
                               index=0xB02F, b5_retries=1)  # fmt: skip
    x.txn(calls, 1, "ok", ".12 -> .22 B02F DO 2 (second channel of the AR)")
    calls = g.parameter_access(change_request(2, 2, [(P(1082), value_block(f32, [99_999.0]))]),
                               pd_response(2, 0x82, 2, [error_block(0x02, 0)]), index=0xB02F)  # fmt: skip
    x.txn(calls, 2, "nak", ".12 -> .22 B02F: limit exceeded")
    calls = s[2, 3].parameter_access(read_request(1, 1, [P(2000 + i) for i in range(20)]), None, write_status=DF_B1)
    x.txn(calls, 1, "pnio_error", ".12 -> .23: write refused DF 80 B1 00")
    # .12 -> .24: the final read is answered from UDP port 49153 (paired by activity + sequence number)
    calls = s[2, 4].parameter_access(read_request(1, 1, [P(964)]), None, b5_retries=1)
    s[2, 4].reply_port = 49153
    calls.append(s[2, 4].read(0xB02E, _word(1, 1, 0x4711)))
    s[2, 4].reply_port = None
    x.txn(calls, 1, "ok", ".12 -> .24: final read answered from port 49153")
    x.txn(read1((2, 3), 2, 964), 2, "ok", ".12 -> .23 after the refused write")

    # controller .13
    x.txn(read1((3, 1), 1, 964), 1, "ok", ".13 -> .21")
    calls = s[3, 2].parameter_access(change_request(1, 1, [(P(2), value_block(0x06, [1]))]),
                                     pd_response(1, 0x82, 1, [error_block(0x01, 0)]), b5_retries=1)  # fmt: skip
    x.txn(calls, 1, "nak", ".13 -> .22: P2 is read-only")
    calls = s[3, 3].parameter_access(read_request(1, 1, [P(964)]), None, b5_retries=1, read_status=DE_B2)
    x.txn(calls, 1, "pnio_error", ".13 -> .23: read DE 80 B2 00")
    x.txn(read1((3, 4), 1, 964, b5_retries=3, read_gap_us=2000), 1, "ok", ".13 -> .24, three B5")
    x.txn(read1((3, 3), 2, 964), 2, "ok", ".13 -> .23 again")
    x.txn(read1((3, 1), 2, 968), 2, "ok", ".13 -> .21 again")

    cap.frames = cap.time_sorted()
    return cap, x


# ---- pd_retries_and_duplicates.pcap --------------------------------------------------------------------------


@pd_sample("pd_retries_and_duplicates.pcap")
def pd_retries_and_duplicates_capture() -> Built:
    """Retransmitted RPC requests, a transaction captured twice by a mirror port, retries with the same
    reference after a PNIO error and after a timeout (T4), reference reuse after ok (T1), a write while a
    transaction is pending (T3), a read without request (T2), fallback pairing (T6), B5 polling above the
    threshold (T5) ending with the response or a timeout, and a run of 260 transactions on one channel
    whose reference wraps 255 -> 1. One session per part, one after the other on the capture's clock."""
    cap = Capture()
    x = Intent(cap)
    ctrls, devs = _hosts(4)

    def sess(n: int, **kw: Any) -> PnioSession:
        return PnioSession(cap, ctrls[n - 1], devs[n - 1], activity=fixed_uuid(0xAC, n), ar_uuid=fixed_uuid(0xA2, n),
                           **kw)  # fmt: skip

    # --- session 1 (.11 -> .21): retransmissions, duplicates, retries, reuse, write while pending ---
    s = sess(1)
    # ref 1: the write request is sent again 50 ms later (identical PDU); the answer follows the copy
    calls = s.parameter_access(read_request(1, 1, [P(964)]), _word(1), write_kw={"retransmit_after_us": [50_000]})
    x.on(calls[0].request[1], "rpc_retransmission")
    x.txn(calls, 1, "ok", "write request retransmitted once")
    # ref 2: the final read request is sent three times (30 ms apart)
    calls = s.parameter_access(read_request(2, 1, [P(965)]), None, b5_retries=1)
    calls.append(s.read(0xB02E, _word(2), retransmit_after_us=[30_000, 60_000]))
    x.on(calls[-1].request[1:], "rpc_retransmission")
    x.txn(calls, 2, "ok", "final read request retransmitted twice")
    # ref 3: every frame captured twice by a mirror port (4 µs apart, frame-identical)
    calls = s.parameter_access(change_request(3, 1, [(P(1120), value_block(0x08, [10.0]))]), change_ok(3, 1, 1),
                               b5_retries=1)  # fmt: skip
    req_copies, res_copies = _mirror(cap, calls)
    x.on(req_copies + res_copies, "rpc_retransmission")  # duplicate requests and duplicate responses
    x.txn(calls, 3, "ok", "mirror-port duplicates: 3 duplicate requests counted, every copy its frame",
          copies=req_copies + res_copies)
    # ref 4: the write is refused with DF 80 B5 00 (busy), the controller writes again with the same reference
    calls = s.parameter_access(read_request(4, 1, [P(966)]), None, write_status=DF_B5)
    x.txn(calls, 4, "pnio_error", "write refused DF 80 B5 00")
    calls = s.parameter_access(read_request(4, 1, [P(966)]), _word(4), b5_retries=1)
    x.txn(calls, 4, "ok", "retry after pnio_error", findings=[(x.write_req(calls), "retry")])
    # ref 5: two B5, then the drive stays silent; the controller writes again 10.5 s after the first write
    t0 = s.clock.now_ns
    calls = s.parameter_access(read_request(5, 1, [P(967)]), None, b5_retries=2)
    x.txn(calls, 5, "pnio_error", "two B5, then the controller stops polling: closed by the 10 s deadline at "
          "the retry, every read refused B5 (protocol.md 7.3 step 5)")
    s.clock.now_ns = t0 + 10_500 * MS
    calls = s.parameter_access(read_request(5, 1, [P(967)]), _word(5))
    x.txn(calls, 5, "ok", "retry after the busy refusal", findings=[(x.write_req(calls), "retry")])
    # ref 5 once more, after it succeeded: reference reused (T1)
    calls = s.parameter_access(read_request(5, 1, [P(968)]), _word(5))
    x.txn(calls, 5, "ok", "reference 5 reused after ok", findings=[(x.write_req(calls), "reference_reused")])
    # ref 6 gets one B5; the controller writes ref 7 while it is pending (T3): ref 6 is given up, its one
    # read refused B5: pnio_error DE80B500 (protocol.md 7.3 step 5)
    calls = s.parameter_access(read_request(6, 1, [P(969)]), None, b5_retries=1)
    x.txn(calls, 6, "pnio_error", "superseded by the write of ref 7 after a B5 answer")
    given_up = calls
    calls = s.parameter_access(read_request(7, 1, [P(970)]), _word(7))
    x.txn(calls, 7, "ok", "written while ref 6 was pending", findings=[(x.write_req(calls), "write_while_pending")])
    x.superseded(given_up, x.write_req(calls))

    # --- session 2 (.12 -> .22): read without request (T2), fallback pairing (T6) ---
    s = sess(2)
    c = s.read(0xB02E, status=pnio_encode.STATUS_B5)  # nothing written on this AR: the idle drive answers B5
    x.loose(c.request[0], "read_without_request")
    calls = s.parameter_access(read_request(1, 1, [P(964)]), _word(1), b5_retries=1, read_kw={"slot": 2})
    x.txn(
        calls,
        1,
        "ok",
        "written to slot 1, read through slot 2 (V1000 style)",
        findings=[(calls[1].request[0], "fallback_pairing")],
    )  # the first read only

    # --- session 3 (.13 -> .23): B5 polling above the threshold of 50 (T5) ---
    s = sess(3, rtt_us=1200, gap_us=800)
    calls = s.parameter_access(change_request(1, 1, [(P(971), value_block(0x06, [1]))]), change_ok(1, 1, 1),
                               b5_retries=55, read_gap_us=20_000)  # fmt: skip
    x.txn(
        calls,
        1,
        "ok",
        "55 B5 answers (save to non-volatile memory), then the response",
        findings=[(calls[51].response[0], "b5_polling")],
    )  # the 51st B5 answer
    calls = s.parameter_access(change_request(2, 1, [(P(971), value_block(0x06, [1]))]), None,
                               b5_retries=60, read_gap_us=150_000)  # fmt: skip
    x.txn(
        calls,
        2,
        "pnio_error",
        "60 B5 answers within 8.9 s, then the controller gives up: every read refused (7.3 step 5)",
        findings=[(calls[51].response[0], "b5_polling")],
    )
    s.clock.advance_us(1_500_000)  # the deadline of ref 2 passes before the next frame

    # --- session 4 (.14 -> .24): 260 transactions on one channel, the reference wraps 255 -> 1 (no T1) ---
    s = sess(4, rtt_us=900, gap_us=300)
    for k in range(260):
        ref = k % 255 + 1
        value = value_block(0x06, [k])
        calls = s.parameter_access(change_request(ref, 1, [(P(2900), value)]), change_ok(ref, 1, 1))
        x.txn(calls, ref, "ok", "reference 255, the last before the wrap" if ref == 255 else "")

    cap.frames = cap.time_sorted()  # the mirror copies into place
    return cap, x


# ---- pd_timeouts.pcap ----------------------------------------------------------------------------------------


@pd_sample("pd_timeouts.pcap")
def pd_timeouts_capture() -> Built:
    """Transactions that end without a parameter response (protocol.md 7.3 steps 4 and 5, 7.5): closed by
    the 10 s deadline while other traffic goes on, after no read at all, after B5 answers only (a busy
    drive given up: pnio_error), after an unanswered write or read (R7 rpc_unanswered after 5 s), and one
    still open when the capture ends.
    Four sessions on their own clocks, merged by time; session 1 keeps polling every second."""
    cap = Capture()
    x = Intent(cap)
    ctrls, devs = _hosts(4)

    def sess(n: int, start_s: float) -> PnioSession:
        return _session(cap, ctrls[n - 1], devs[n - 1], n, n, start_s * 1000)

    def at(s: PnioSession, seconds: float) -> None:
        s.clock.now_ns = EPOCH_NS + round(seconds * 1000) * MS

    # session 1 (.11 -> .21): the background, a read of P63 every second from 0 to 30 s
    bg = sess(1, 0.0)
    for k in range(31):
        at(bg, k)
        x.txn(bg.parameter_access(read_request(k % 255 + 1, 1, [P(63)]), _word(k % 255 + 1, 1, k)), k % 255 + 1,
              "ok")  # fmt: skip

    # session 2 (.12 -> .22)
    s = sess(2, 1.2)
    calls = s.parameter_access(read_request(1, 1, [P(964)]), None)  # write accepted, the controller never reads
    x.txn(calls, 1, "timeout", "write accepted, no read: closed by the deadline at 11.2 s, mid-capture")
    at(s, 13.0)
    calls = s.parameter_access(read_request(2, 1, [P(964)]), None, b5_retries=3, read_gap_us=500_000)
    x.txn(calls, 2, "pnio_error", "three B5 within 1.5 s, then the controller stops polling: closed at 23 s, "
          "every read refused B5 (protocol.md 7.3 step 5)")

    # session 3 (.13 -> .23)
    s = sess(3, 2.4)
    c = s.write(0xB02E, read_request(1, 1, [P(964)]), respond=False)  # the write is never answered
    x.on(c.request, "rpc_unanswered")  # R7 after 5 s
    x.txn([c], 1, "timeout", "write never answered: rpc_unanswered at 7.4 s, timeout at 12.4 s")
    at(s, 15.0)
    calls = s.parameter_access(read_request(2, 1, [P(964)]), None, b5_retries=1)
    # the second read is never answered; the RPC client sends it again after 1 s and 2 s (identical PDU)
    calls.append(s.read(0xB02E, respond=False, retransmit_after_us=[1_000_000, 2_000_000]))
    x.on(calls[-1].request[0], "rpc_unanswered")  # 5 s after the first copy
    x.on(calls[-1].request[1:], "rpc_retransmission")
    x.txn(calls, 2, "timeout", "one B5, then a read never answered, sent three times: last answer B5")

    # session 4 (.14 -> .24): a change still waiting when the capture ends (30.0 s + the last answer)
    s = sess(4, 26.5)
    calls = s.parameter_access(change_request(1, 1, [(P(971), value_block(0x06, [1]))]), None, b5_retries=2,
                               read_gap_us=1_000_000)  # fmt: skip
    x.txn(calls, 1, "timeout", "two B5, then the capture ends 3.5 s after the write", capture_ended=True)

    cap.frames = cap.time_sorted()
    return cap, x

"""The two samples the notebook, the HTML report and the untrusted-string tests read.

fault_trace.pcap: three drives commissioned at once by three controllers on their own clocks, with
NAKs, B5 polling, a refused write, a busy drive given up and its retry. crafted_strings.pcap: hostile text in every
place a capture carries it (markup, terminal control, spreadsheet formulas).

Built from constants and seeded Random only, byte for byte the same on every run; keep
sample_pcaps/README.md in step.
"""

from __future__ import annotations

import random
from typing import Any

from . import pnio_encode
from .catalog import intent_of, sample
from .expect import Intent
from .fixtures import pcap_of, session
from .pd_encode import ParamAddress as P
from .pd_encode import (
    change_ok,
    change_request,
    description,
    error_block,
    pd_response,
    read_request,
    text_entries,
    value_block,
)
from .pnio_session import PnioSession
from .sim_capture import EPOCH_NS, Capture, Clock

# ---- fault_trace.pcap: three drives interleaved, for the notebook and the HTML report -------------------


@intent_of("fault_trace.pcap")
def fault_trace_capture() -> tuple[Capture, Intent]:
    """Commissioning of three drives by three controllers at once (own clocks,
    merged by time): change trails preceded by reads, NAKs with several error
    numbers, B5 polling, a write refused with DF 80 B1 00, a timeout and its
    retry. sample_pcaps/README.md lists what the analyser must find."""
    cap = Capture()
    x = Intent(cap)
    f32, w16, u16 = 0x08, 0x42, 0x06
    df_b1 = pnio_encode.pnio_status(0xDF, 0x80, 0xB1, 0x00)
    refs: dict[str, int] = {}  # last Request Reference per device
    pauses: dict[str, random.Random] = {}  # the controllers' idle times between transactions

    def drive(n: int, start_ms: int, rtt_us: float, jitter_us: float) -> PnioSession:
        s = session(cap, n, own_clock=Clock(EPOCH_NS + start_ms * 1_000_000), rtt_us=rtt_us, gap_us=1500,
                    jitter_us=jitter_us, rng=random.Random(n))
        refs[s.device.ip], pauses[s.device.ip] = 0, random.Random(10 + n)
        return s

    def nxt(s: PnioSession) -> int:
        refs[s.device.ip] += 1
        return refs[s.device.ip]

    def access(s: PnioSession, request: bytes, response: bytes | None, pause_ms: float, retry: bool = False,
               **kw: Any) -> None:
        """One transaction, then the controller's idle time before the next one."""
        calls = s.parameter_access(request, response, **kw)
        if "write_status" in kw:
            verdict = "pnio_error"
        elif response is None:  # the controller stops polling; the 10 s deadline passes inside the capture
            # every read answered B5: the drive refused each time (protocol.md 7.3 step 5), else silence
            verdict = "pnio_error" if kw.get("b5_retries") else "timeout"
        else:
            verdict = "nak" if response[1] & 0x80 else "ok"
        x.txn(calls, request[0], verdict, findings=[(x.write_req(calls), "retry")] if retry else ())
        s.clock.advance_us(pauses[s.device.ip].uniform(0.6, 1.4) * pause_ms * 1000)

    def read1(s: PnioSession, pnu: int, fmt: int, value: float, pause_ms: float, **kw: Any) -> None:
        r = nxt(s)
        access(s, read_request(r, 1, [P(pnu)]), pd_response(r, 0x01, 1, [value_block(fmt, [value])]), pause_ms, **kw)

    def change1(s: PnioSession, pnu: int, fmt: int, value: float, pause_ms: float, error: int = -1,
                ref: int = 0, **kw: Any) -> None:
        r = ref or nxt(s)
        block = error_block(error, 0) if error in (0x01, 0x02, 0x14) else error_block(error)  # with subindex
        res = change_ok(r, 1, 1) if error < 0 else pd_response(r, 0x82, 1, [block])
        access(s, change_request(r, 1, [(P(pnu), value_block(fmt, [value]))]), res, pause_ms, retry=bool(ref),
               **kw)

    # drive 1 (.21): quick (1.2 ms RTT), one change below the limit, one PNU that does not exist
    d1 = drive(1, 0, 1200, 400)
    read1(d1, 1082, f32, 1500.0, 300)  # max. speed, read before the change
    change1(d1, 1082, f32, 3000.0, 300, b5_retries=1)
    read1(d1, 1120, f32, 10.0, 300)  # ramp-up time
    change1(d1, 1120, f32, 5.0, 300)
    read1(d1, 1121, f32, 10.0, 300)  # ramp-down time
    change1(d1, 1121, f32, 0.001, 300, error=0x02)  # below the lower limit
    change1(d1, 1121, f32, 2.0, 300)
    r = nxt(d1)  # three parameters at once, one of them does not exist
    access(d1, read_request(r, 1, [P(964), P(9999), P(2000)]),
           pd_response(r, 0x81, 1, [value_block(w16, [0x1234]), error_block(0x00), value_block(f32, [3000.0])]),
           300, b5_retries=1)
    for k in range(16):  # monitoring: actual speed
        read1(d1, 63, f32, 2950.0 + 5 * k, 1200, b5_retries=int(k % 3 == 0))

    # drive 2 (.22): slow (4 ms RTT, B5 polling 20 ms apart), refuses changes while running
    d2 = drive(2, 120, 4000, 2500)
    slow = {"read_gap_us": 20_000}
    read1(d2, 2, u16, 7, 400)
    change1(d2, 2, u16, 1, 400, error=0x01)  # P2 is read-only
    read1(d2, 1300, u16, 20, 400)  # control mode
    change1(d2, 1300, u16, 21, 400, error=0x11, b5_retries=2, **slow)  # not while the drive runs
    change1(d2, 971, u16, 1, 400, b5_retries=12, **slow)  # save to non-volatile memory: long B5 polling
    for k in range(16):
        read1(d2, 63, f32, 1400.0 + k, 1200, b5_retries=2 + k % 4, **slow)
    change1(d2, 1300, u16, 21, 400, error=0x11)

    # drive 3 (.23): a refused write, a busy drive given up and its retry, NAKs on subindex and data type
    d3 = drive(3, 260, 1800, 600)
    read1(d3, 964, w16, 0x1234, 500)
    r = nxt(d3)  # a 20-parameter read the device's parameter buffer cannot take
    access(d3, read_request(r, 1, [P(2000 + i) for i in range(20)]), None, 500, write_status=df_b1)
    read1(d3, 1082, f32, 1500.0, 500)
    r = nxt(d3)  # three B5, then the controller stops polling: given up on a busy drive (pnio_error DE80B500)
    access(d3, change_request(r, 1, [(P(1082), value_block(f32, [2800.0]))]), None, 12_000, b5_retries=3)
    change1(d3, 1082, f32, 2800.0, 500, ref=r, b5_retries=1)  # the controller retries with the same reference
    r = nxt(d3)
    access(d3, read_request(r, 1, [P(945, 40)]), pd_response(r, 0x81, 1, [error_block(0x03, 40)]), 500)
    change1(d3, 1120, w16, 5, 500, error=0x05)  # Word written to a Float32 parameter
    change1(d3, 1120, f32, 5.0, 500)
    for k in range(8):
        read1(d3, 63, f32, 2790.0 + k, 1000)
    cap.frames = cap.time_sorted()
    return cap, x


@sample("fault_trace.pcap")
def fault_trace() -> bytes:
    return pcap_of(fault_trace_capture()[0])


# ---- crafted_strings.pcap: untrusted text in every place a capture carries it ----------------------------


@sample("crafted_strings.pcap")
def crafted_strings() -> bytes:
    """Strings a hostile device (or a forged capture) could send, in every place a capture carries text:
    a text array (attribute 0x30), a description's name (attribute 0x20, subindex 0), VisibleString,
    OctetString and UnicodeString values, read and written. Markup and script (<script>, attribute and
    URL injection), terminal control (ANSI CSI and OSC, C1 CSI, CR, BS, BEL) and spreadsheet formulas
    (leading =, +, -, @, tab, CR). Every output must show them inertly (tests/test_untrusted_strings.py)."""
    cap = Capture()
    s = session(cap, 1)

    def text(pnu: int, value: str, fmt: int = 0x09) -> tuple[P, bytes]:
        return P(pnu, n_elems=len(value)), value_block(fmt, value)

    # ref 1 (frames 1-4): a text array and a description whose name is markup
    names = text_entries(["<script>alert(1)", "</script><b>x</b"])
    desc = description(0x0009, 16, "<svg/onload=a()>")
    s.parameter_access(read_request(1, 1, [P(1, n_elems=2, attr=0x30), P(2, attr=0x20)]),
                       pd_response(1, 0x01, 1, [value_block(0x09, names), value_block(0x0A, desc)]))
    # ref 2 (frames 5-8): attribute and URL injection, answered with a NAK (so the HTML drill-down shows it)
    html = [text(20, '"><img src=x onerror=alert(2)>'), text(21, "javascript:alert(3)"),
            text(22, "' onmouseover='alert(4)")]
    s.parameter_access(read_request(2, 1, [a for a, _ in html] + [P(23)]),
                       pd_response(2, 0x81, 1, [b for _, b in html] + [error_block(0x00)]))
    # ref 3 (frames 9-12): terminal control sequences, NAK
    term = [text(30, "\x1b[31mRED\x1b[0m\x1b]0;pwned\x07"), text(31, "\x9b2J\rOVER\x08WRITTEN"),
            (P(32, n_elems=12), value_block(0x0A, b"\x1b[2J<script>")), text(33, "\u202eevil\u2028x", 0x27)]
    s.parameter_access(read_request(3, 1, [a for a, _ in term] + [P(34)]),
                       pd_response(3, 0x81, 1, [b for _, b in term] + [error_block(0x00)]))
    # ref 4 (frames 13-16) reads formulas, ref 5 (17-20) writes others over them: the change trail has both
    formulas = ["=cmd|' /C calc'!A0", "+SUM(1,2)", "-2+3", "@SUM(1,2)", "\t=1+2", "\r=1+2"]
    read = [text(40 + i, f) for i, f in enumerate(formulas)]
    s.parameter_access(read_request(4, 1, [a for a, _ in read]), pd_response(4, 0x01, 1, [b for _, b in read]))
    written = [text(40 + i, f) for i, f in enumerate(["=1+1", "+1-1", "-1+1", "@A1", "\t@A1", "\r-1"])]
    s.parameter_access(change_request(5, 1, written), change_ok(5, 1, len(written)))
    return pcap_of(cap)

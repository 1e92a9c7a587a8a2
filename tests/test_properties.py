"""Property-based tests (hypothesis) of each layer's parser on arbitrary and on half-valid input.

The property, for every layer: a parser either returns fields whose offsets and lengths lie inside its
input (and whose bytes are the input's bytes there), or reports a decode finding; it never raises.
Structured strategies build valid headers with arbitrary fields and tails, so the deep layers are reached.
PD_HYPOTHESIS_EXAMPLES=20000 pytest tests/test_properties.py hunts longer than the default 300 examples.
"""

from __future__ import annotations

import os
import struct
import tempfile

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from devtools.fuzz.harness import check_result
from pd_analyze import capture
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.engine.run import analyze_frames
from pd_analyze.analysis.rows import Rows
from pd_analyze.model.values import LINKTYPE_ETHERNET, LINKTYPE_RAW, LINKTYPE_SLL, LINKTYPE_SLL2
from pd_analyze.protocol import link, profidrive, profidrive_view, profiles, rpc, rpc_calls, rpc_fragments
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.dissector import Dissector
from pd_analyze.protocol.profidrive_checks import Checker

EXAMPLES = int(os.environ.get("PD_HYPOTHESIS_EXAMPLES", "300"))  # more for a longer hunt
SETTINGS = settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
CHECKERS = [Checker(profiles.generic(), profiles.load(name)) for name in ("generic", "sinamics", "akd", "yaskawa")]
PNIO_IF = bytes.fromhex("dea000016c9711d1827100a02442df7d")
LINKTYPES = st.sampled_from([LINKTYPE_ETHERNET, LINKTYPE_SLL, LINKTYPE_SLL2, LINKTYPE_RAW, 228, 0, 999])


def small(n: int) -> st.SearchStrategy[int]:
    """Mostly the interesting values of an n-byte field: 0, 1, max, max-1, small ones."""
    top = (1 << (8 * n)) - 1
    return st.one_of(st.sampled_from([0, 1, 2, 3, 4, 6, top, top - 1, top >> 1]), st.integers(0, top))


# --- layer 1: capture files -----------------------------------------------------------------------
PCAP_HEADER = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)


@st.composite
def capture_files(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from(["raw", "pcap", "pcapng"]))
    if kind == "raw":
        return draw(st.binary(max_size=300))
    if kind == "pcap":
        records = b""
        for _ in range(draw(st.integers(0, 4))):
            data = draw(st.binary(max_size=80))
            caplen = draw(st.just(len(data)) | small(4))
            records += struct.pack("<IIII", draw(small(4)), draw(small(4)), caplen, draw(small(4))) + data
        return PCAP_HEADER + records + draw(st.binary(max_size=20))
    blocks = struct.pack("<IIIHHq", 0x0A0D0D0A, 28, 0x1A2B3C4D, 1, 0, -1) + struct.pack("<I", 28)
    for _ in range(draw(st.integers(0, 5))):
        btype = draw(st.sampled_from([1, 3, 6, 2, 5, 0x0A0D0D0A, 0xBAD]))
        body = draw(st.binary(max_size=60))
        body += b"\x00" * (-len(body) % 4)
        size = draw(st.just(len(body) + 12) | small(4))
        trailer = draw(st.just(size) | small(4))
        blocks += struct.pack("<II", btype, size) + body + struct.pack("<I", trailer)
    return blocks + draw(st.binary(max_size=12))


@SETTINGS
@given(capture_files())
def test_capture_reader_yields_bounded_frames_or_capture_error(data: bytes) -> None:
    fd, path = tempfile.mkstemp(suffix=".pcap")
    try:
        os.write(fd, data)
        os.close(fd)
        numbers = []
        try:
            for f in capture.frames(path):
                numbers.append(f.number)
                assert len(f.data) <= capture.MAX_CAPLEN and isinstance(f.ts, float)
        except capture.CaptureError as exc:
            assert exc.offset is None or 0 <= exc.offset <= len(data)
            assert str(exc).startswith(path)
        assert numbers == list(range(1, len(numbers) + 1))
    finally:
        os.unlink(path)


# --- layer 2: link, IPv4, UDP -----------------------------------------------------------------------
@st.composite
def ipv4_frames(draw: st.DrawFn) -> tuple[int, bytes]:
    """An Ethernet (maybe VLAN-tagged) or raw IPv4 frame with arbitrary IP/UDP fields and payload."""
    payload = draw(st.binary(max_size=120))
    udp = struct.pack(">HHHH", draw(small(2)), draw(small(2)), draw(st.just(8 + len(payload)) | small(2)), 0)
    ihl = draw(st.sampled_from([5, 5, 5, 6, 4, 15, 0]))
    body = udp + payload
    total = draw(st.just(ihl * 4 + len(body)) | small(2))
    flags = draw(st.sampled_from([0, 0, 0x2000, 0x4000]) | small(2))
    ip = struct.pack(">BBHHHBBH4s4s", draw(st.sampled_from([4, 4, 6, 0])) << 4 | ihl, 0, total,
                     draw(st.integers(0, 3)), flags, 64, draw(st.sampled_from([17, 17, 6, 1])), 0,
                     bytes([10, 0, 0, draw(st.integers(1, 2))]), bytes([10, 0, 0, 3]))
    ip += bytes(max(0, ihl * 4 - 20)) + body
    ip = ip[:draw(st.integers(0, len(ip)))] if draw(st.booleans()) and draw(st.booleans()) else ip
    if draw(st.booleans()):
        return LINKTYPE_RAW, ip
    tags = b"".join(struct.pack(">HH", 0x8100, draw(small(2))) for _ in range(draw(st.integers(0, 2))))
    return LINKTYPE_ETHERNET, bytes(12) + tags + b"\x08\x00" + ip


@SETTINGS
@given(st.lists(st.one_of(ipv4_frames(), st.tuples(LINKTYPES, st.binary(max_size=80))), max_size=8))
def test_link_layer_offsets_inside_the_frame(frames: list[tuple[int, bytes]]) -> None:
    decoder = link.LinkDecoder()
    for number, (linktype, data) in enumerate(frames, 1):
        out = decoder.datagram(number, linktype, data)
        if isinstance(out, str):
            continue
        assert 0 <= out.ip_offset <= len(data)
        if out.payload_offset >= 0:
            assert data[out.payload_offset:out.payload_offset + len(out.payload)] == out.payload
        else:
            assert out.fragments and number in out.fragments
        for _title, fields in link.annotate(linktype, data, out):
            for f in fields:
                if f.offset >= 0:
                    assert f.offset + f.length <= len(data) and f.raw == data[f.offset:f.offset + f.length]
    decoder.finish()
    assert decoder._open.bytes == 0


# --- layer 3: DCE/RPC --------------------------------------------------------------------------------
@st.composite
def rpc_headers(draw: st.DrawFn, body: bytes = b"") -> bytes:
    little = draw(st.booleans())
    order = "<" if little else ">"

    def uuid_wire(raw: bytes) -> bytes:
        return raw[3::-1] + raw[5:3:-1] + raw[7:5:-1] + raw[8:] if little else raw

    activity = bytes([draw(st.integers(0, 2))]) * 16
    head = struct.pack("BBBB3sB", 4, draw(st.sampled_from([0, 2, 0, 2, 3, 6, 1, 4, 5, 7, 8, 9, 10])),
                       draw(st.sampled_from([0x20, 0x0A, 0x24, 0x26, 0x06, 0x04, 0x00]) | small(1)),
                       draw(st.sampled_from([0, 0, 1, 2])), b"\x10\x00\x00" if little else b"\x00\x00\x00", 0)
    head += bytes(16) + uuid_wire(draw(st.sampled_from([PNIO_IF, PNIO_IF, bytes(16)]))) + uuid_wire(activity)
    head += struct.pack(order + "IIIHHHHH", 0, 1, draw(st.integers(0, 3)), draw(st.sampled_from([2, 3, 5, 0, 4, 9])),
                        0xFFFF, 0xFFFF, draw(st.just(len(body)) | small(2)), draw(st.integers(0, 3) | small(2)))
    head += bytes([draw(st.sampled_from([0, 0, 0, 1])), 0])
    assert len(head) == 80
    return head + body


@SETTINGS
@given(st.lists(st.binary(max_size=40).flatmap(lambda body: rpc_headers(body)), min_size=1, max_size=12))
def test_rpc_fragments_and_calls_stay_consistent(pdus: list[bytes]) -> None:
    table, calls = rpc_fragments.FragmentTable(), rpc_calls.CallTable()
    for number, payload in enumerate(pdus, 1):
        assert rpc.plausible(payload)
        hdr = rpc.header(payload)
        findings: list = []
        body = payload[80:80 + hdr.frag_len]
        key = (hdr.activity, hdr.seq)
        if hdr.flags1 & 0x04:
            whole = table.add((*key, hdr.ptype, b"a", b"b"), number, float(number), hdr, body, findings)
            if whole is not None:
                assert len(whole.frames) >= 1 and number in whole.frames
        elif hdr.ptype == 0:
            calls.request(key, rpc_calls.Call(number, 0.0, b"a", b"b", hdr.interface, hdr.opnum, body), findings)
        elif hdr.ptype == 2:
            calls.close(key)
            table.drop_call(key, number, findings)
        assert table._sets.bytes >= 0 and calls.open.bytes >= 0 and calls.closed.bytes >= 0
    table.finish(len(pdus))
    assert table._sets.bytes == 0 and not table._by_call


# --- layer 4: NDR and IOD blocks ---------------------------------------------------------------------
@st.composite
def stubs(draw: st.DrawFn) -> tuple[bytes, bool, bool, int]:
    little, response = draw(st.booleans()), draw(st.booleans())
    opnum = draw(st.sampled_from([2, 3, 5, 3, 0, 4, 9]))
    order = "<" if little else ">"
    blocks = b""
    for _ in range(draw(st.integers(0, 3))):
        record = draw(st.binary(max_size=40))
        index = draw(st.sampled_from([0xB02E, 0xB02F, 0x002F, 0xE040, 0x1000]))
        btype = draw(st.sampled_from([0x0008, 0x8008, 0x0009, 0x8009, 0x1234]))
        rlen = draw(st.just(len(record)) | small(4))
        blocks += struct.pack(">HHBBH16sIHHHHI", btype, draw(st.just(60) | small(2)), 1, 0, 1,
                              draw(st.sampled_from([bytes(16), b"\xaa" * 16])), 0x3A00, 1, 1, 0, index, rlen)
        blocks += draw(st.binary(min_size=24, max_size=24)) + record
    ndr = struct.pack(order + "IIIII", *(draw(small(4)) for _ in range(5)))
    stub = (ndr + blocks)[:draw(st.integers(0, len(ndr + blocks)))] if draw(st.booleans()) else ndr + blocks
    return stub, little, response, opnum


@SETTINGS
@given(stubs())
def test_stub_blocks_and_records_inside_the_stub(case: tuple[bytes, bool, bool, int]) -> None:
    data, little, response, opnum = case
    findings: list = []
    stub = rec.parse_stub(data, little, response, opnum, 1, findings)
    for block in stub.blocks:
        assert block.offset >= 0 and block.offset + rec.IOD_SIZE <= len(data)
        assert data[block.record_offset:block.record_offset + len(block.record)] == block.record
        assert len(block.record) <= block.record_len
        if block.layout in (rec.WRITE_REQ, rec.READ_RES):  # the headers that carry a record
            assert len(block.record) == block.record_len or findings
        else:
            assert block.record == b""
    if stub.truncated:
        assert findings
    assert 0 <= stub.trailing <= len(data)


# --- layer 5: PROFIdrive records ---------------------------------------------------------------------
@st.composite
def value_blocks(draw: st.DrawFn) -> bytes:
    fmt = draw(st.sampled_from([0x01, 0x02, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A, 0x0C, 0x0F, 0x27, 0x32,
                                0x40, 0x41, 0x42, 0x44, 0x00, 0x0B, 0x7C]) | small(1))
    size = {0x01: 1, 0x02: 1, 0x05: 1, 0x06: 2, 0x07: 4, 0x08: 4, 0x09: 1, 0x0A: 1, 0x0C: 6, 0x0F: 8, 0x27: 2,
            0x32: 7, 0x40: 0, 0x41: 1, 0x42: 2, 0x44: 2, 0x00: 0, 0x7C: 4}.get(fmt, 1)
    if draw(st.booleans()):  # well formed: the values fill exactly No. of values x size, pad or not
        m = draw(st.integers(0, 5))
        block = bytes([fmt, m]) + draw(st.binary(min_size=m * size, max_size=m * size))
        return block + (draw(st.sampled_from([b"", b"\x00", b"\x55"])) if m * size % 2 else b"")
    return bytes([fmt, draw(small(1))]) + draw(st.binary(max_size=24))


@st.composite
def records(draw: st.DrawFn) -> bytes:
    """A PROFIdrive header, addresses and value/error blocks: counts that agree, or are one off, or anything."""
    ident = draw(st.sampled_from([0x01, 0x02, 0x80, 0x81, 0x82, 0x00, 0x03]))
    blocks = draw(st.lists(value_blocks(), max_size=4))
    k = len(blocks)
    n = draw(st.sampled_from([k, k, k + 1, k + 1, max(0, k - 1), 39, 255]) | st.integers(0, 6))
    out = bytes([draw(st.integers(0, 255)), ident, draw(st.integers(0, 3)), n])
    if draw(st.booleans()):  # a request's addresses (or, in a response, bytes that look like them)
        for _ in range(min(n, 6)):
            out += struct.pack(">BBHH", draw(st.sampled_from([0x10, 0x20, 0x30, 0x00])), draw(small(1)),
                               draw(small(2)), draw(small(2)))
    return out + b"".join(blocks) + draw(st.sampled_from([b"", b"", b""]) | st.binary(max_size=4))


def _inside(sections: list, data: bytes, base: int) -> None:
    for _title, fields in sections:
        for f in fields:
            off = f.offset - base
            assert off >= 0 and off + f.length <= len(data), (f.name, f.offset, f.length, len(data))
            assert f.raw == data[off:off + f.length], f.name


@SETTINGS
@given(records(), st.booleans(), st.sampled_from(CHECKERS))
def test_profidrive_blocks_inside_the_record_or_a_finding(data: bytes, response: bool, checker: Checker) -> None:
    findings: list = []
    parse = profidrive.parse_response if response else profidrive.parse_request
    p = parse(data, 1, findings)
    assert p.end <= len(data)
    for a in p.addresses:
        assert a.offset >= 4 and a.offset + 6 <= len(data)
    for b in p.blocks:
        assert b.offset >= 4 and b.offset + 2 + len(b.data) <= len(data)
        assert data[b.offset + 2:b.offset + 2 + len(b.data)] == b.data
        assert b.end <= len(data)
        profidrive_view.values_of(b)
    checked = checker.response(p, 1, None) if response else checker.request(p, 1)
    if not p.complete:
        assert findings or checked, "an incomplete decode must say why"
    _inside(profidrive_view.annotate(p, data, 1000, checker), data, 1000)
    assert profidrive.footprint(p) > 0
    profidrive.plausible(data, response)


# --- the whole frame loop ----------------------------------------------------------------------------
@st.composite
def pnio_frames(draw: st.DrawFn) -> bytes:
    stub, _little, _response, _opnum = draw(stubs())
    rpc_pdu = draw(rpc_headers(stub))
    udp = struct.pack(">HHHH", 49152, 34964, 8 + len(rpc_pdu), 0) + rpc_pdu
    sender = draw(st.integers(1, 2))
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0, 64, 17, 0, bytes([10, 0, 0, sender]),
                     bytes([10, 0, 0, 3 - sender])) + udp
    frame = bytes(12) + b"\x08\x00" + ip
    return frame[:draw(st.integers(14, len(frame)))] if draw(st.integers(0, 9)) == 0 else frame


@SETTINGS
@given(st.lists(st.tuples(pnio_frames(), st.floats(0, 30)), min_size=1, max_size=10), st.booleans())
def test_dissector_and_engine_on_arbitrary_pnio_frames(frames: list[tuple[bytes, float]], annotate: bool) -> None:
    d = Dissector(annotate=annotate, rpc_timeout=2.0, checker=CHECKERS[1])
    data = {}
    results = []
    raw = []
    for number, (frame, ts) in enumerate(sorted(frames, key=lambda f: f[1]), 1):
        data[number] = frame
        raw.append(capture.RawFrame(number, ts, LINKTYPE_ETHERNET, frame))
        results += d.feed(raw[-1])
    results += d.finish()
    for res in results:
        if annotate:
            check_result(res, data[res.frame])
    assert d.accounting.read == len(frames) and d.accounting.balanced()
    acc = analyze_frames(raw, Settings("sinamics", txn_timeout=5.0, rpc_timeout=2.0), Rows(), batch_frames=3).accounting
    assert acc.read == len(frames) and acc.balanced()

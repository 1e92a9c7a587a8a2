"""Exact-value tests of the sample generator (devtools.synth).

The generator is the ground truth for the decoder's tests, so each layer is
checked against an independent parse (dpkt for Ethernet/IP/UDP, struct for
RPC/NDR/IOD/PROFIdrive) and the worked example against protocol.md 9.
"""

from __future__ import annotations

import ast
import gzip
import io
import itertools
import json
import struct
import uuid
from pathlib import Path

import dpkt
import pytest

from devtools.synth import (
    basic_samples,
    build,
    capture_files,
    catalog,
    fixtures,
    format_samples,
    net_encode,
    pd_encode,
    pnio_encode,
    pnio_session,
    rpc_encode,
    sim_capture,
)
from devtools.synth.__main__ import main as synth_main

SAMPLE_DIR = Path(__file__).resolve().parent.parent / "sample_pcaps"
EPOCH = 1_767_225_600

# protocol.md 9.1 / 9.2, UDP payloads of frames 1 and 6
WORKED_F1 = bytes.fromhex(
    "04002000100000000000a0de976cd11182710001000200020100a0de976cd111827100a02442df7d1111111122223333"
    "44445555666677770000000001000000010000000300ffffffff64000000000038410000500000003841000000000000"
    "500000000008003c01000001aaaaaaaabbbbccccddddeeeeffff000100003a00000100010000b02e0000001000000000"
    "000000000000000000000000000000000000000001010102100103c40000100307d00000"
)
WORKED_F6 = bytes.fromhex(
    "04020a00100000000000a0de976cd11182710001000200020100a0de976cd111827100a02442df7d1111111122223333"
    "44445555666677770000005f01000000030000000200ffffffff6a000000000000000000560000003001000000000000"
    "560000008009003c01000003aaaaaaaabbbbccccddddeeeeffff000100003a00000100010000b02e0000001600000000"
    "000000000000000000000000000000000000000001010102420112344303000000010000000200000003"
)


def udp_payloads(pcap: bytes) -> list[tuple[float, dpkt.ethernet.Ethernet]]:
    return [(ts, dpkt.ethernet.Ethernet(buf)) for ts, buf in dpkt.pcap.Reader(io.BytesIO(pcap))]


# ---- worked example ------------------------------------------------------------


def test_worked_example_hex_lengths() -> None:
    assert len(WORKED_F1) == 180
    assert len(WORKED_F6) == 186


def test_worked_example_frames_match_protocol_md() -> None:
    frames = udp_payloads(basic_samples.worked_example())
    assert len(frames) == 6
    times = [round((ts - EPOCH) * 1e4) for ts, _ in frames]
    assert times == [0, 21, 25, 44, 146, 163]  # 0.1 ms units, table of section 9
    payloads = [bytes(e.data.data.data) for _, e in frames]
    assert payloads[0] == WORKED_F1
    assert payloads[5] == WORKED_F6
    for _, e in frames:
        ip, u = e.data, e.data.data
        req = ip.src == bytes([192, 168, 0, 1])
        assert (u.sport, u.dport) == ((49152, 34964) if req else (34964, 49152))


def test_worked_example_frames_2_to_5() -> None:
    p = [bytes(e.data.data.data) for _, e in udp_payloads(basic_samples.worked_example())]
    # frame 2 Write.res: NDR status 0, IODWriteResHeader RecordDataLength 16, status OK
    assert p[1][1] == 2 and struct.unpack_from("<IH", p[1], 64)[0] == 1
    assert p[1][80:100] == struct.pack("<5I", 0, 64, 16696, 0, 64)
    assert struct.unpack_from(">HH", p[1], 100) == (0x8008, 60)
    assert struct.unpack_from(">I", p[1], 136)[0] == 16 and p[1][144:148] == bytes(4)
    # frames 3 and 5 Read.req: ArgsMaximum 304, RecordDataLength 240, IOD SeqNumber 2 / 3
    for frame, seq in ((p[2], 2), (p[4], 3)):
        assert struct.unpack_from("<I", frame, 64)[0] == seq
        assert struct.unpack_from("<I", frame, 80)[0] == 304
        assert struct.unpack_from(">HHBBH", frame, 100) == (0x0009, 60, 1, 0, seq)
        assert struct.unpack_from(">I", frame, 136)[0] == 240
    # frame 4: the B5 answer, NDR only
    assert p[3][80:] == bytes.fromhex("00b580de00000000300100000000000000000000")


# ---- determinism ---------------------------------------------------------------


def test_regeneration_is_byte_identical(tmp_path: Path) -> None:
    assert synth_main(["synth", str(tmp_path)]) == 0
    names = sorted(p.name for p in tmp_path.iterdir() if p.is_file())
    assert names == sorted(s.name for s in catalog.SAMPLES)
    for name in names:
        committed = SAMPLE_DIR / name
        assert committed.exists(), f"{name} missing from sample_pcaps/"
        assert (tmp_path / name).read_bytes() == committed.read_bytes(), name
    # the expected findings are generated too (from the generator's intent) and committed
    expected = sorted(p.name for p in (tmp_path / "expected").iterdir())
    assert expected == sorted(f"{n}.json" for n in build.build_expected())
    for name in expected:
        committed = SAMPLE_DIR / "expected" / name
        assert committed.exists(), f"expected/{name} missing from sample_pcaps/"
        assert (tmp_path / "expected" / name).read_text() == committed.read_text(), name


def test_build_twice_identical() -> None:
    assert build.build_all() == build.build_all()


def test_readme_mentions_every_sample() -> None:
    readme = (SAMPLE_DIR / "README.md").read_text()
    for s in catalog.SAMPLES:
        assert f"`{s.name}`" in readme, s.name


# ---- link layer ------------------------------------------------------------------


def test_ethernet_vlan_stack_roundtrip() -> None:
    payload = net_encode.ipv4("10.0.0.1", "10.0.0.2", net_encode.udp(1, 2, b"x" * 30), ident=7)
    tags = (net_encode.VlanTag(200, tpid=net_encode.ETH_QINQ), net_encode.VlanTag(100, pcp=6, dei=1))
    raw = net_encode.ethernet(
        net_encode.mac("02:00:00:00:00:02"), net_encode.mac("02:00:00:00:00:01"), net_encode.ETH_IPV4, payload,
        vlans=tags,
    )
    assert raw[12:14] == b"\x88\xa8" and raw[16:18] == b"\x81\x00" and raw[20:22] == b"\x08\x00"
    assert struct.unpack_from(">H", raw, 18)[0] == (6 << 13) | (1 << 12) | 100
    e = dpkt.ethernet.Ethernet(raw)
    assert [t.id for t in e.vlan_tags] == [200, 100]
    assert isinstance(e.data, dpkt.ip.IP) and e.data.id == 7


def test_ethernet_min_padding() -> None:
    raw = net_encode.ethernet(b"\xff" * 6, b"\x02" * 6, net_encode.ETH_ARP, b"\x00" * 28)
    assert len(raw) == 60


def test_ipv4_udp_checksums() -> None:
    pkt = net_encode.ipv4(
        "192.168.1.1",
        "192.168.1.2",
        net_encode.udp(49152, 34964, b"abc", src_ip="192.168.1.1", dst_ip="192.168.1.2"),
        ident=0x1234,
        df=True,
    )
    ip = dpkt.ip.IP(pkt)
    assert net_encode.inet_checksum(pkt[:20]) == 0  # header checksum valid
    assert ip.df == 1 and ip.mf == 0 and ip.offset == 0 and ip.id == 0x1234
    u = ip.data
    pseudo = pkt[12:20] + struct.pack("!BBH", 0, 17, len(bytes(u)))
    assert net_encode.inet_checksum(pseudo + bytes(u)) == 0
    assert net_encode.udp(1, 2, b"z")[6:8] == b"\x00\x00"  # no IPs: checksum 0


def test_ip_fragments_offsets_and_mf() -> None:
    dgram = net_encode.udp(1, 2, bytes(range(256)) * 12)  # 3080 bytes
    frags = net_encode.ip_fragments("1.1.1.1", "2.2.2.2", dgram, ident=99, mtu=1500)
    parsed = [dpkt.ip.IP(f) for f in frags]
    assert [p.offset * 8 for p in parsed] == [0, 1480, 2960]  # dpkt gives 8-byte units
    assert [p.mf for p in parsed] == [1, 1, 0]
    assert all(p.id == 99 and net_encode.inet_checksum(f[:20]) == 0 for p, f in zip(parsed, frags, strict=True))
    assert b"".join(f[20:] for f in frags) == dgram


def test_sll_and_sll2_headers() -> None:
    a = net_encode.sll(0x0800, b"P", pkttype=net_encode.SLL_OUTGOING, addr=b"\x02" * 6)
    assert struct.unpack(">HHH8sH", a[:16]) == (4, 1, 6, b"\x02" * 6 + b"\x00\x00", 0x0800) and a[16:] == b"P"
    b = net_encode.sll2(0x0800, b"P", ifindex=3, addr=b"\x02" * 6)
    assert struct.unpack(">HHIHBB8s", b[:20]) == (0x0800, 0, 3, 1, 0, 6, b"\x02" * 6 + b"\x00\x00")


# ---- DCE/RPC -----------------------------------------------------------------------

ACT = uuid.UUID("11111111-2222-3333-4444-555566667777")


@pytest.mark.parametrize("drep", [rpc_encode.DREP_LE, rpc_encode.DREP_BE])
def test_rpc_header_drep_order(drep: bytes) -> None:
    le = drep == rpc_encode.DREP_LE
    e = "<" if le else ">"
    h = rpc_encode.rpc_header(
        ptype=0, activity=ACT, seq=0x01020304, opnum=3, drep=drep, serial=0x0A0B, frag_len=100, frag_num=2
    )
    assert len(h) == 80 and h[4:7] == drep
    assert h[7] == 0x0A and h[79] == 0x0B  # serial hi / lo
    assert h[40:56] == (ACT.bytes_le if le else ACT.bytes)
    assert h[8:24] == (rpc_encode.NIL_UUID.bytes)
    assert h[24:40] == (rpc_encode.PNIO_DEVICE_IF.bytes_le if le else rpc_encode.PNIO_DEVICE_IF.bytes)
    assert struct.unpack_from(e + "IIIHHHHH", h, 56) == (0, 1, 0x01020304, 3, 0xFFFF, 0xFFFF, 100, 2)
    assert h[40:44] == (b"\x11" * 4) and h[44:46] == b"\x22\x22"


def test_rpc_uuid_be_vs_le_first_fields() -> None:
    u = uuid.UUID("00010203-0405-0607-0809-0a0b0c0d0e0f")
    assert rpc_encode.uuid_wire(u, True).hex() == "03020100050407060809" + "0a0b0c0d0e0f"
    assert rpc_encode.uuid_wire(u, False).hex() == "000102030405060708090a0b0c0d0e0f"


def test_pnio_object_uuid() -> None:
    assert str(rpc_encode.pnio_object_uuid(1, 2, 0x2A)) == "dea00000-6c97-11d1-8271-00010002002a"


def test_cl_fragments_flags_numbers_serials() -> None:
    body = bytes(range(256)) * 12  # 3072 bytes -> 1384 + 1384 + 304
    pdus = rpc_encode.cl_fragments(body, flags1=rpc_encode.F1_IDEMPOTENT, ptype=0, activity=ACT, seq=5, opnum=3)
    assert [len(p) - 80 for p in pdus] == [1384, 1384, 304]
    assert [p[2] for p in pdus] == [0x24, 0x24, 0x2E]  # frag; frag; frag+last+nofack
    assert [struct.unpack_from("<H", p, 76)[0] for p in pdus] == [0, 1, 2]
    assert [p[7] * 256 + p[79] for p in pdus] == [0, 1, 2]
    assert [struct.unpack_from("<H", p, 74)[0] for p in pdus] == [1384, 1384, 304]
    assert b"".join(p[80:] for p in pdus) == body
    sized = rpc_encode.cl_fragments(body, sizes=[100, 200], last_extra=0, ptype=2, activity=ACT)
    assert [len(p) - 80 for p in sized] == [100, 200, len(body) - 300] and sized[-1][2] == 0x06


def test_control_pdu_bodies() -> None:
    assert rpc_encode.status_body(0x1C010003, True) == bytes.fromhex("0300011c")
    assert rpc_encode.status_body(0x1C010003, False) == bytes.fromhex("1c010003")
    fb = rpc_encode.fack_body(little=True, serial_num=2, selack=[0x5])
    assert struct.unpack("<BBHIIHHI", fb) == (1, 0, 1, 1464, 1464, 2, 1, 5)
    assert rpc_encode.cancel_ack_body(7, False) == bytes.fromhex("000000000000000701")


# ---- NDR, IOD blocks, Write-Multiple -------------------------------------------------


def test_ndr_status_order() -> None:
    st = pnio_encode.pnio_status(0xDE, 0x80, 0xB5, 0x00)
    assert pnio_encode.ndr_status(st, True) == bytes.fromhex("00b580de")
    assert pnio_encode.ndr_status(st, False) == bytes.fromhex("de80b500")
    res = pnio_encode.ndr_response(b"x" * 6, status=st, max_count=304, little=False)
    assert struct.unpack_from(">4sIIII", res) == (st, 6, 304, 0, 6)
    req = pnio_encode.ndr_request(b"y" * 10, args_max=16696, little=True, actual_count=9)
    assert struct.unpack_from("<IIIII", req) == (16696, 10, 16696, 0, 9)


def test_iod_headers_fields() -> None:
    ar = uuid.UUID("aaaaaaaa-bbbb-cccc-dddd-eeeeffff0001")
    common = dict(seq=3, ar_uuid=ar, api=0x3A00, slot=1, subslot=2, index=0xB02E, record_len=22)
    w = pnio_encode.iod_write_res(status=pnio_encode.STATUS_B5, add_val1=5, add_val2=6, **common)
    assert len(w) == 64
    f = struct.unpack(">HHBBH16sIHHHHIHH4s16s", w)
    assert f == (0x8008, 60, 1, 0, 3, ar.bytes, 0x3A00, 1, 2, 0, 0xB02E, 22, 5, 6, pnio_encode.STATUS_B5, bytes(16))
    r = pnio_encode.iod_read_res(add_val1=1, **common)
    assert struct.unpack_from(">HHH", r, 0)[0] == 0x8009 and struct.unpack_from(">HH", r, 40) == (1, 0)
    bad = pnio_encode.iod_write_req(block_length=61, pad=0x55, rw_padding=b"\x01" * 24, **common)
    assert struct.unpack_from(">H", bad, 2)[0] == 61 and bad[32:34] == b"\x00\x55" and bad[40:] == b"\x01" * 24


def test_implicit_read_target_ar() -> None:
    target = uuid.UUID("aaaaaaaa-bbbb-cccc-dddd-eeeeffff0001")
    h = pnio_encode.iod_read_req(
        seq=1, ar_uuid=rpc_encode.NIL_UUID, api=0, slot=0, subslot=1, index=0xAFF0, record_len=4096,
        target_ar_uuid=target,
    )
    assert h[8:24] == bytes(16) and h[40:56] == target.bytes and h[56:64] == bytes(8)


def test_write_multiple_alignment() -> None:
    ar = uuid.UUID(int=1)
    inner = [
        pnio_encode.InnerWrite(0xB02E, b"A" * 10, 2, ar),
        pnio_encode.InnerWrite(0x1000, b"B" * 5, 3, ar),
        pnio_encode.InnerWrite(0x1001, b"C" * 7, 4, ar),
    ]
    body = pnio_encode.write_multiple_req(inner, seq=1, ar_uuid=ar)
    assert struct.unpack_from(">H", body, 34)[0] == 0xE040
    rec_len = struct.unpack_from(">I", body, 36)[0]
    assert rec_len == len(body) - 64 == (74 + 2) + (69 + 3) + 71
    pos = 64
    for w, pad in zip(inner, (2, 3, 0), strict=True):
        assert pos % 4 == 0 and struct.unpack_from(">HH", body, pos + 32)[1] == w.index
        pos += 64 + len(w.data)
        assert body[pos : pos + pad] == bytes(pad)
        pos += pad
    res = pnio_encode.write_multiple_res(
        [pnio_encode.iod_write_res(seq=2, ar_uuid=ar, api=0, slot=0, subslot=1, index=0xB02E, record_len=0)],
        seq=1, ar_uuid=ar,
    )
    assert len(res) == 128 and struct.unpack_from(">I", res, 36)[0] == 64


# ---- PROFIdrive ------------------------------------------------------------------------


def test_value_block_pad_rule() -> None:
    assert pd_encode.value_block(0x05, [1, 2, 3]) == bytes.fromhex("0503010203") + b"\x00"
    assert pd_encode.value_block(0x42, [0x1234]) == bytes.fromhex("42011234")
    assert pd_encode.value_block(0x09, "ABC") == b"\x09\x03ABC\x00"
    assert pd_encode.value_block(0x09, "ABC", pad=b"") == b"\x09\x03ABC"
    assert pd_encode.value_block(0x03, [-2]) == bytes.fromhex("0301fffe")
    assert pd_encode.value_block(0x08, [1.0]) == bytes.fromhex("08013f800000")
    assert pd_encode.value_block(0x27, "Hi") == bytes.fromhex("270200480069")
    assert pd_encode.value_block(0x43, [1], n_values=3) == bytes.fromhex("430300000001")


def test_error_and_zero_blocks() -> None:
    assert pd_encode.error_block(0x14, 0) == bytes.fromhex("440200140000")
    assert pd_encode.error_block(0x00) == bytes.fromhex("44010000")
    assert pd_encode.error_block(0x02, 1, extra=[9], n_values=0) == bytes.fromhex("4400000200010009")
    assert pd_encode.zero_block() == b"\x40\x00"


def test_requests_and_responses() -> None:
    addr = pd_encode.ParamAddress(1120)
    req = pd_encode.change_request(3, 1, [(addr, pd_encode.value_block(0x08, [10.0]))])
    assert req == bytes.fromhex("03020101100104600000080141200000")
    assert pd_encode.change_ok(3, 1, 1) == bytes.fromhex("03020101")
    assert pd_encode.pd_response(1, 0x81, 1, [pd_encode.error_block(0)], n_params=2) == bytes.fromhex(
        "0181010244010000"
    )


# ---- writers --------------------------------------------------------------------------------


def test_pcap_variants_headers_and_truncation() -> None:
    f = capture_files.Frame(EPOCH * 10**9 + 123_456_789, bytes(100))
    us = capture_files.pcap_bytes([f], snaplen=64)
    magic, _, _, _, _, snap, lt = struct.unpack_from("<IHHiIII", us)
    assert (magic, snap, lt) == (0xA1B2C3D4, 64, 1)
    assert struct.unpack_from("<IIII", us, 24) == (EPOCH, 123456, 64, 100)
    ns = capture_files.pcap_bytes([f], nanosecond=True, big_endian=True, linktype=101)
    assert ns[:4] == bytes.fromhex("a1b23c4d") and struct.unpack_from(">I", ns, 20)[0] == 101
    assert struct.unpack_from(">II", ns, 24) == (EPOCH, 123_456_789)
    ts, buf = next(iter(dpkt.pcap.Reader(io.BytesIO(ns))))
    assert len(buf) == 100 and abs(float(ts) - (EPOCH + 0.123456789)) < 1e-6


def _pcapng_blocks(data: bytes) -> list[tuple[int, bytes]]:
    out, pos = [], 0
    while pos < len(data):
        btype, blen = struct.unpack_from("<II", data, pos)
        assert struct.unpack_from("<I", data, pos + blen - 4)[0] == blen and blen % 4 == 0
        out.append((btype, data[pos + 8 : pos + blen - 4]))
        pos += blen
    return out


def test_pcapng_two_interfaces_sample() -> None:
    blocks = _pcapng_blocks(format_samples.two_interfaces())
    types = [t for t, _ in blocks]
    assert types[:3] == [0x0A0D0D0A, 1, 1] and 3 in types and 0x0B0B in types
    idbs = [b for t, b in blocks if t == 1]
    assert [struct.unpack_from("<H", b)[0] for b in idbs] == [1, 113]
    assert b"\x09\x00\x01\x00\x06" in idbs[0] and b"\x09\x00\x01\x00\x09" in idbs[1]  # if_tsresol 6 / 9
    epbs = [b for t, b in blocks if t == 6]
    ifaces = [struct.unpack_from("<I", b)[0] for b in epbs]
    assert ifaces == [0] * 4 + [1] * 6
    hi, lo = struct.unpack_from("<II", epbs[4], 4)
    assert ((hi << 32) | lo) == EPOCH * 10**9 + 5_000_123  # nanosecond ticks on interface 1
    hi, lo = struct.unpack_from("<II", epbs[1], 4)
    assert ((hi << 32) | lo) == EPOCH * 10**6 + 1500  # microsecond ticks on interface 0


def test_gzip_deterministic_and_valid() -> None:
    data = bytes(range(256)) * 300
    gz = capture_files.gzip_bytes(data)
    assert gz[:4] == b"\x1f\x8b\x08\x00" and gz[4:8] == bytes(4)  # no FNAME, mtime 0
    assert gzip.decompress(gz) == data
    assert gzip.decompress(format_samples.gzip_pcapng_named())[:4] == b"\x0a\x0d\x0d\x0a"
    assert gzip.decompress(basic_samples.record_rw_le_gz()) == basic_samples.record_rw_le()


# ---- simulated capture and sessions -----------------------------------------------------


def test_session_sequence_boot_time_and_reply_port() -> None:
    cap = sim_capture.Capture()
    ctrl, dev = fixtures.plant(1)
    s = pnio_session.PnioSession(cap, ctrl, dev, activity=ACT, ar_uuid=uuid.UUID(int=5), reply_port=50000, seq=7)
    calls = s.parameter_access(
        pd_encode.read_request(1, 1, [pd_encode.ParamAddress(964)]), b"\x01\x01\x01\x01", b5_retries=2
    )
    assert [c.seq for c in calls] == [7, 8, 9, 10]
    assert [c.opnum for c in calls] == [3, 2, 2, 2]
    pl = [bytes(dpkt.ethernet.Ethernet(f.data).data.data.data) for f in cap.frames]
    sports = [dpkt.ethernet.Ethernet(f.data).data.data.sport for f in cap.frames]
    assert sports == [49152, 50000] * 4
    assert struct.unpack_from("<I", pl[0], 56)[0] == 0  # client boot unknown in first call
    assert all(struct.unpack_from("<I", p, 56)[0] == 0x5F000000 for p in pl[1:])
    assert [len(p) for p in pl[3:6:2]] == [100, 100]  # B5 answers: NDR only
    iod_seqs = [struct.unpack_from(">H", p, 106)[0] for p in pl if len(p) > 100]
    assert iod_seqs == [1, 1, 2, 3, 4, 4]
    ts = [f.ts_ns for f in cap.frames]
    assert ts == sorted(ts) and ts[0] == sim_capture.EPOCH_NS


def test_retransmitted_request_is_identical_rpc_pdu() -> None:
    frames = udp_payloads(basic_samples.other_port_response())
    assert len(frames) == 7
    p5, p6 = (bytes(frames[i][1].data.data.data) for i in (4, 5))
    assert p5 == p6 and round(frames[5][0] - frames[4][0], 3) == 0.1


# Files allowed more than 40 frames: fault_trace is a 25 s session, the pd_* files one transaction
# per case.
MAX_FRAMES = {"fault_trace.pcap": 450, "pd_out_of_range.pcap": 160, "pd_negative.pcap": 70,
              "pd_b5_and_pnio_errors.pcap": 60, "pd_commissioning.pcap": 60, "pd_yaskawa_like.pcap": 50,
              "pd_interleaved.pcap": 110, "pd_retries_and_duplicates.pcap": 1340, "pd_timeouts.pcap": 150,
              "pd_edge_cases.pcap": 80}  # fmt: skip


def test_all_pcap_samples_parse_with_dpkt() -> None:
    for s in catalog.SAMPLES:
        data = s.build()
        if s.name.endswith(".gz") or data[:2] == b"\x1f\x8b":
            data = gzip.decompress(data)
        if data[:4] == b"\x0a\x0d\x0d\x0a":
            assert _pcapng_blocks(data)
            continue
        n = sum(1 for _ in dpkt.pcap.Reader(io.BytesIO(data)))
        assert 6 <= n <= MAX_FRAMES.get(s.name, 40), s.name


def test_truncated_sample_caplen() -> None:
    recs = list(dpkt.pcap.Reader(io.BytesIO(format_samples.truncated_snaplen())))
    data = format_samples.truncated_snaplen()
    pos, cut = 24, []
    for _ in recs:
        _, _, incl, orig = struct.unpack_from("<IIII", data, pos)
        cut.append(incl < orig)
        pos += 16 + incl
    assert [i + 1 for i, c in enumerate(cut) if c] == [7, 11]


def test_session_overrides_reach_the_wire() -> None:
    cap = sim_capture.Capture()
    ctrl, dev = fixtures.plant(1)
    s = pnio_session.PnioSession(cap, ctrl, dev, activity=ACT, ar_uuid=uuid.UUID(int=5))
    s.write(
        0xB02E,
        b"\x01\x01\x01\x01",
        req_iod={"block_length": 61},
        req_ndr={"args_len": 999},
        req_rpc={"flags1": 0x30, "serial": 0x0102},
        res_iod={"rw_padding": b"\x07" * 16},
        status=bytes.fromhex("df80b500"),
    )
    req, res = (bytes(dpkt.ethernet.Ethernet(f.data).data.data.data) for f in cap.frames)
    assert req[2] == 0x30 and (req[7], req[79]) == (1, 2)
    assert struct.unpack_from("<I", req, 84)[0] == 999 and struct.unpack_from(">H", req, 102)[0] == 61
    assert res[80:84] == bytes.fromhex("00b580df") and res[144:148] == bytes.fromhex("df80b500")
    assert res[148:164] == b"\x07" * 16


def test_interleaved_sessions_with_own_clocks() -> None:
    cap = sim_capture.Capture()
    a = fixtures.session(cap, 1, own_clock=sim_capture.Clock(sim_capture.EPOCH_NS))
    b = fixtures.session(cap, 2, own_clock=sim_capture.Clock(sim_capture.EPOCH_NS + 500_000))
    for s in (a, b):
        fixtures.txn_read_one(s, 1, b5=0)
    order = [dpkt.ethernet.Ethernet(f.data).data.src[-1] for f in cap.time_sorted()]
    assert order[:4] == [11, 12, 21, 22]  # the two channels interleave in time


def test_sll_packet_type_by_capturing_host() -> None:
    m = sim_capture.Medium(net_encode.LINKTYPE_LINUX_SLL, local_ip="192.168.1.11")
    cap = sim_capture.Capture(medium=m)
    fixtures.txn_read_one(fixtures.session(cap, 1, medium=m), 1, b5=0)
    assert [struct.unpack_from(">H", f.data)[0] for f in cap.frames] == [4, 0, 4, 0]


# ---- PROFIdrive samples (pd_*.pcap) and their encoders -------------------------------------------------------


def test_composite_value_encoders() -> None:
    assert pd_encode.date_value(2026, 3, 21, 14, 5, 30_000, weekday=6) == bytes([0x75, 0x30, 5, 14, 0xD5, 3, 26])
    assert pd_encode.time_value(45_296_789, 15_341) == struct.pack(">IH", 45_296_789, 15_341)
    assert pd_encode.time_value(1500) == struct.pack(">I", 1500)
    d = pd_encode.description(0x0008, 4, "Max. speed", std_factor=2.0, var_attr=0x0102, high=b"\x45\xfa\x00\x00",
                               id_ext=7, ref_param=8, normalisation=9)  # fmt: skip
    assert len(d) == 46
    assert struct.unpack_from(">HHfHI", d) == (0x0008, 4, 2.0, 0x0102, 0)
    assert d[14:30] == b"Max. speed      " and d[30:34] == bytes(4) and d[34:38] == b"\x45\xfa\x00\x00"
    assert struct.unpack_from(">HHHH", d, 38) == (0, 7, 8, 9)
    assert pd_encode.text_entries(["On", "A very long text entry"]) == "On" + " " * 14 + "A very long text"
    echo = pd_encode.akd_echo_response(5, 1, 0, pd_encode.ParamAddress(207), pd_encode.value_block(0x43, [1]))
    assert echo == bytes.fromhex("05010001" + "100100cf0000" + "430100000001")


def _pnio_records(pcap: bytes) -> list[tuple[int, int, int, bytes]]:
    """(frame, ptype, opnum, record) of every LE-DREP Write.req / Read.res carrying a record, parsed with struct."""
    out = []
    for i, (_, buf) in enumerate(dpkt.pcap.Reader(io.BytesIO(pcap)), 1):
        p = bytes(dpkt.ethernet.Ethernet(buf).data.data.data)
        ptype, opnum = p[1], struct.unpack_from("<H", p, 68)[0]
        if len(p) >= 80 + 84 and (ptype, opnum) in ((0, 3), (2, 2)):
            rec_len = struct.unpack_from(">I", p, 80 + 20 + 36)[0]
            out.append((i, ptype, opnum, p[164 : 164 + rec_len]))
    return out


def _blocks(record: bytes, pos: int, n: int) -> list[tuple[int, int, bytes]]:
    """(format, m, values) of n value blocks with the word-alignment pad rule (protocol.md 3.2)."""
    out = []
    for _ in range(n):
        fmt, m = record[pos], record[pos + 1]
        size = pd_encode.FORMAT_SIZE[fmt]
        out.append((fmt, m, record[pos + 2 : pos + 2 + m * size]))
        pos += 2 + m * size
        if (m * size) % 2:
            assert record[pos] == 0
            pos += 1
    assert pos == len(record)
    return out


def test_commissioning_covers_every_common_format_with_pads() -> None:
    formats, pads = set(), 0
    for _, ptype, _, rec in _pnio_records(build.build_all()["pd_commissioning.pcap"]):
        n = rec[3]
        if ptype == 2 and rec[1] == 0x01:
            blocks = _blocks(rec, 4, n)
        elif ptype == 0 and rec[1] == 0x02:
            blocks = _blocks(rec, 4 + 6 * n, n)
        else:
            continue
        formats |= {f for f, _, _ in blocks}
        pads += sum(1 for f, m, _ in blocks if (m * pd_encode.FORMAT_SIZE[f]) % 2)
    every = {0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A, 0x0C, 0x0F, 0x27, 0x32, 0x34, 0x35,
             0x36, 0x37, 0x38, 0x41, 0x42, 0x43, 0x71, 0x72, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A,
             0x7B, 0x7C}  # fmt: skip
    assert every <= formats
    assert pads >= 10


def test_commissioning_39_parameters_and_description() -> None:
    recs = _pnio_records(build.build_all()["pd_commissioning.pcap"])
    first_write = recs[0][3]
    assert (first_write[1], first_write[3], len(first_write)) == (0x01, 39, 238)
    descr = next(r for _, t, _, r in recs if t == 0 and r[4] == 0x20)
    assert struct.unpack_from(">BBHH", descr, 4) == (0x20, 1, 1082, 0)  # complete description
    res = next(r for _, t, _, r in recs if t == 2 and r[0] == descr[0])
    fmt, m, values = _blocks(res, 4, res[3])[0]
    assert (fmt, m, values[14:30]) == (0x0A, 46, b"Max. speed      ")


def test_session_fault_and_error_endings() -> None:
    cap = sim_capture.Capture()
    s = fixtures.session(cap, 1)
    req = pd_encode.read_request(1, 1, [pd_encode.ParamAddress(964)])
    calls = s.parameter_access(req, None, write_fault=(rpc_encode.FAULT, 0x1C010014))
    assert len(calls) == 1 and len(cap.frames) == 2
    calls = s.parameter_access(req, None, b5_retries=1, read_fault=(rpc_encode.REJECT, 0x1C01000B))
    calls += s.parameter_access(req, None, read_status=bytes.fromhex("de80b100"), common_kw={"api": 0, "slot": 2},
                                read_kw={"max_len": 64})  # fmt: skip
    p = [bytes(dpkt.ethernet.Ethernet(f.data).data.data.data) for f in cap.frames]
    assert [x[1] for x in p] == [0, 3, 0, 2, 0, 2, 0, 6, 0, 2, 0, 2]
    assert p[1][80:] == bytes.fromhex("1400011c") and p[7][80:] == bytes.fromhex("0b00011c")  # NCA status, LE
    assert p[11][80:84] == bytes.fromhex("00b180de") and len(p[11]) == 100  # DE 80 B1 00, NDR only
    for frame in (p[8], p[10]):  # common_kw reaches the write and the read header
        assert struct.unpack_from(">IH", frame, 124) == (0, 2)
    assert struct.unpack_from(">I", p[10], 136)[0] == 64


INTERLEAVED = {"pd_interleaved.pcap", "pd_timeouts.pcap"}  # sessions on their own clocks, merged by time


def test_pd_samples_registered_deterministic_with_expectations() -> None:
    names = [s.name for s in catalog.SAMPLES if s.name.startswith("pd_")]
    assert names == list(catalog.EXPECTED) and len(names) == 12
    first, second = build.build_expected(), build.build_expected()
    assert first == second
    built = build.build_all()
    for name in names:
        doc = json.loads(first[name])
        frames = sum(1 for _ in dpkt.pcap.Reader(io.BytesIO(built[name])))
        assert doc["profiles"][0]["profile"] == "generic"
        for entry in doc["profiles"]:
            assert all(1 <= f <= frames for f, _ in entry["findings"]), name
        spans = [t["frames"] for t in doc["transactions"]]
        assert spans == sorted(spans), name  # in the order of the write requests
        if name not in INTERLEAVED:
            assert all(a[1] < b[0] for a, b in itertools.pairwise(spans)), name  # one at a time
    commissioning = json.loads(first["pd_commissioning.pcap"])
    assert commissioning["profiles"] == [{"profile": "generic", "findings": []}]
    assert {t["verdict"] for t in commissioning["transactions"]} == {"ok"}


def test_intent_frames_and_profiles() -> None:
    from devtools.synth.expect import Intent, dumps

    cap = sim_capture.Capture()
    s = fixtures.session(cap, 1)
    x = Intent(cap, ("generic", "akd"))
    calls = s.parameter_access(pd_encode.read_request(3, 0, [pd_encode.ParamAddress(1)]), b"\x03\x01\x00\x01",
                               b5_retries=2)  # fmt: skip
    x.on(x.read_reqs(calls), "vendor_limit", profiles=["akd"])
    x.on(x.final_res(calls), "pd_response_truncated")
    x.txn(calls, 3, "malformed", "test", findings=[(x.final_res(calls), "n_params_not_mirrored")],
          decided=x.final_res(calls))  # the cut response decides the verdict: T8 there (protocol.md 6.5)
    with pytest.raises(ValueError, match="not declared"):
        x.on(x.write_req(calls), "x", profiles=["yaskawa"])
    doc = x.render("t.pcap")
    assert doc["profiles"] == [
        {"profile": "generic", "findings": [[8, "pd_response_truncated"]]},
        {"profile": "akd", "findings": [[3, "vendor_limit"], [5, "vendor_limit"], [7, "vendor_limit"],
                                        [8, "pd_response_truncated"]]},
    ]  # fmt: skip
    assert doc["transactions"] == [{"ref": 3, "frames": [1, 8], "verdict": "malformed", "reads": 3, "b5_retries": 2,
                                    "rpc_retransmissions": 0, "pnio_status": "", "capture_ended": False,
                                    "t_write_rtt": 0.0015, "t_total": 0.009,
                                    "findings": [[8, "n_params_not_mirrored"], [8, "txn_failed"]],
                                    "note": "test"}]  # fmt: skip
    assert json.loads(dumps(doc)) == doc


def test_intent_figures_from_the_calls() -> None:
    """Figures of protocol.md 7.6 from the generator's frames: truncated to the file's resolution, B5
    answers and the closing PNIOStatus from the calls, loose transaction-level findings."""
    from devtools.synth.expect import Intent, dumps

    cap = sim_capture.Capture(sim_capture.Clock(sim_capture.EPOCH_NS + 999))
    s = fixtures.session(cap, 1, rtt_us=1000.5, gap_us=500)
    x = Intent(cap)
    req = pd_encode.read_request(1, 1, [pd_encode.ParamAddress(964)])
    calls = s.parameter_access(req, None, b5_retries=2)  # stops after the B5 answers
    x.txn(calls, 1, "timeout", capture_ended=True)
    calls = s.parameter_access(req, None, b5_retries=1, read_status=bytes.fromhex("de80b200"))
    x.txn(calls, 1, "pnio_error")
    c = s.read(0xB02E, status=pnio_encode.STATUS_B5, retransmit_after_us=[10_000])
    x.loose(c.request[0], "read_without_request")
    calls = s.parameter_access(req, None, write_fault=(rpc_encode.FAULT, 0x1C010014))
    x.txn(calls, 1, "pnio_error")
    doc = x.render("t.pcap")
    fig = ["reads", "b5_retries", "pnio_status", "capture_ended", "t_write_rtt", "t_total"]
    assert [[t[k] for k in fig] for t in doc["transactions"]] == [
        [2, 2, "DE80B500", True, 0.001001, None],  # ...000.999 -> ...1001.499 µs: written 0 and 1001 µs
        [2, 1, "DE80B200", False, 0.001, None],  # ...4502.499 -> ...5502.999 µs: written 4502 and 5502
        [0, 0, "1C010014", False, 0.001, None],
    ]
    assert doc["loose"] == [[cap.number(c.request[0]), "read_without_request"]]
    assert c.retransmits == 1 and json.loads(dumps(doc)) == doc
    ns = Intent(cap, resolution_ns=1)
    ns.txn(calls, 1, "pnio_error")
    assert ns.render("t.pcapng")["transactions"][0]["t_write_rtt"] == 0.0010005


# ---- structure of devtools ---------------------------------------------------------------------------------

DEVTOOLS = Path(__file__).resolve().parent.parent / "devtools"


def _devtools_modules() -> dict[str, tuple[Path, bool]]:
    """Dotted name -> (file, is a package) for every module under devtools/."""
    out = {}
    for path in sorted(DEVTOOLS.rglob("*.py")):
        parts = list(path.relative_to(DEVTOOLS.parent).with_suffix("").parts)
        package = parts[-1] == "__init__"
        out[".".join(parts[:-1] if package else parts)] = (path, package)
    return out


def _imported(name: str, modules: dict[str, tuple[Path, bool]]) -> set[str]:
    """Dotted names of what module `name` imports, at the top or deferred inside a function:
    `from pkg import module` imports that module, `from module import name` the module."""
    path, package = modules[name]
    here = name if package else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = here.split(".")[: len(here.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            found |= {f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names}
    return found


def test_devtools_imports_form_no_cycle() -> None:
    """The imports inside devtools flow one way: no module reaches itself again, deferred imports included."""
    modules = _devtools_modules()
    graph = {name: {m for m in _imported(name, modules) if m in modules and m != name} for name in modules}
    assert {"devtools.synth.catalog", "devtools.synth.basic_samples"} <= graph["devtools.synth.build"]
    done: set[str] = set()

    def visit(name: str, path: tuple[str, ...]) -> None:
        assert name not in path, "import cycle: " + " -> ".join((*path[path.index(name):], name))
        if name not in done:
            for target in sorted(graph[name]):
                visit(target, (*path, name))
            done.add(name)

    for name in sorted(graph):
        visit(name, ())


def test_generator_imports_nothing_from_the_analyser() -> None:
    """The samples are the analyser's ground truth, so the generator must not be built from the analyser."""
    modules = _devtools_modules()
    synth = {name: spec for name, spec in modules.items() if name.startswith("devtools.synth")}
    assert "devtools.synth.build" in synth
    for name in synth:
        used = {m for m in _imported(name, modules) if m.split(".")[0] == "pd_analyze"}
        assert not used, f"{name} imports {sorted(used)}"


def test_no_devtools_module_shares_a_name_with_a_product_module() -> None:
    """A test imports both the generator's encoders and the analyser's parsers; equal names would make one of
    them need an alias (the generator once had link, rpc, pnio, profidrive and writers too)."""
    product = {p.stem for p in (DEVTOOLS.parent / "pd_analyze").rglob("*.py")} - {"__init__", "__main__"}
    product |= {p.name for p in (DEVTOOLS.parent / "pd_analyze").rglob("*") if p.is_dir() and p.name != "__pycache__"}
    ours = {name.rpartition(".")[2] for name in _devtools_modules()} - {"__init__", "__main__", "devtools"}
    assert {"link", "rpc", "writers", "capture"} <= product and "net_encode" in ours
    assert not ours & product, sorted(ours & product)

"""Capture reading: pcap/pcapng variants, gzip by magic, and damaged files (exact offsets)."""

import gzip
import struct

import pytest

from pd_analyze.capture import MAX_CAPLEN, CaptureError, frames

FRAME_A = bytes(range(60))
FRAME_B = bytes(range(100, 164))


def pcap(records: list[tuple[int, int, bytes]], magic: int = 0xA1B2C3D4, order: str = "<",
         linktype: int = 1) -> bytes:
    out = struct.pack(order + "IHHiIII", magic, 2, 4, 0, 0, 65535, linktype)
    for sec, frac, data in records:
        out += struct.pack(order + "IIII", sec, frac, len(data), len(data)) + data
    return out


def block(btype: int, body: bytes, order: str = "<") -> bytes:
    body += b"\x00" * (-len(body) % 4)
    size = len(body) + 12
    return struct.pack(order + "II", btype, size) + body + struct.pack(order + "I", size)


def shb(order: str = "<") -> bytes:
    return block(0x0A0D0D0A, struct.pack(order + "IHHq", 0x1A2B3C4D, 1, 0, -1), order)


def idb(linktype: int, tsresol: int | None = None, order: str = "<") -> bytes:
    opts = b""
    if tsresol is not None:
        opts = struct.pack(order + "HH", 9, 1) + bytes([tsresol, 0, 0, 0]) + struct.pack(order + "HH", 0, 0)
    return block(1, struct.pack(order + "HHI", linktype, 0, 0) + opts, order)


def epb(iface: int, ticks: int, data: bytes, order: str = "<") -> bytes:
    return block(6, struct.pack(order + "IIIII", iface, ticks >> 32, ticks & 0xFFFFFFFF, len(data), len(data))
                 + data, order)


def spb(data: bytes, order: str = "<") -> bytes:
    return block(3, struct.pack(order + "I", len(data)) + data, order)


def write(tmp_path, name: str, data: bytes) -> str:
    path = tmp_path / name
    path.write_bytes(data)
    return str(path)


@pytest.mark.parametrize(("magic", "order", "frac", "ts"), [
    (0xA1B2C3D4, "<", 250_000, 10.25), (0xA1B2C3D4, ">", 250_000, 10.25),
    (0xA1B23C4D, "<", 250_000_000, 10.25), (0xA1B23C4D, ">", 123, 10.000000123),
])
def test_pcap_resolutions_and_byte_orders(tmp_path, magic, order, frac, ts):
    path = write(tmp_path, "x.pcap", pcap([(10, frac, FRAME_A), (11, 0, FRAME_B)], magic, order, 113))
    got = list(frames(path))
    assert [(f.number, f.linktype, f.data) for f in got] == [(1, 113, FRAME_A), (2, 113, FRAME_B)]
    assert got[0].ts == pytest.approx(ts, abs=1e-9) and got[1].ts == 11.0


def test_pcapng_interfaces_with_own_linktype_and_resolution(tmp_path):
    data = (shb() + idb(1) + block(0x0BAD, b"custom block to skip") + idb(113, tsresol=9)
            + epb(0, 5_500_000, FRAME_A) + epb(1, 7_000_000_123, FRAME_B) + spb(FRAME_A))
    got = list(frames(write(tmp_path, "two.pcapng", data)))
    assert [(f.number, f.iface, f.linktype, f.data) for f in got] == [
        (1, 0, 1, FRAME_A), (2, 1, 113, FRAME_B), (3, 0, 1, FRAME_A)]
    assert got[0].ts == 5.5 and got[1].ts == pytest.approx(7.000000123, abs=1e-9)
    assert got[2].ts == got[1].ts  # an SPB has no timestamp: the previous one is kept


def test_pcapng_big_endian_section(tmp_path):
    data = shb(">") + idb(1, order=">") + epb(0, 1_000_000, FRAME_A, ">")
    (got,) = frames(write(tmp_path, "be.pcapng", data))
    assert (got.ts, got.data) == (1.0, FRAME_A)


def test_gzip_detected_by_magic_not_name(tmp_path):
    inner = shb() + idb(1) + epb(0, 0, FRAME_A)
    path = write(tmp_path, "named.pcap", gzip.compress(inner, mtime=0))
    assert [f.data for f in frames(path)] == [FRAME_A]


def test_truncated_pcap_record_names_offset_after_good_frames(tmp_path):
    data = pcap([(1, 0, FRAME_A), (2, 0, FRAME_B)])
    path = write(tmp_path, "cut.pcap", data[:-10])
    got = []
    with pytest.raises(CaptureError) as err:
        got.extend(frames(path))
    assert [f.number for f in got] == [1]
    assert err.value.offset == 24 + 16 + len(FRAME_A)
    assert "truncated" in str(err.value) and "cut.pcap" in str(err.value)


def test_truncated_pcap_record_header(tmp_path):
    data = pcap([(1, 0, FRAME_A)]) + b"\x01\x02\x03"
    got = []
    with pytest.raises(CaptureError) as err:
        got.extend(frames(write(tmp_path, "h.pcap", data)))
    assert len(got) == 1 and err.value.offset == 24 + 16 + 60


def test_hostile_caplen_is_refused_before_any_allocation(tmp_path):
    data = pcap([(1, 0, FRAME_A)]) + struct.pack("<IIII", 2, 0, 0xFFFFFFF0, 0xFFFFFFF0)
    with pytest.raises(CaptureError) as err:
        list(frames(write(tmp_path, "huge.pcap", data)))
    assert err.value.offset == 24 + 16 + 60 and str(MAX_CAPLEN) in str(err.value)


def test_pcapng_block_length_errors(tmp_path):
    good = shb() + idb(1) + epb(0, 0, FRAME_A)
    bad_trailer = bytearray(epb(0, 0, FRAME_B))
    bad_trailer[-4:] = struct.pack("<I", 12)
    got = []
    with pytest.raises(CaptureError) as err:
        got.extend(frames(write(tmp_path, "t.pcapng", good + bytes(bad_trailer))))
    assert len(got) == 1 and err.value.offset == len(good) and "trailing length" in str(err.value)
    odd = good + struct.pack("<II", 6, 13)
    with pytest.raises(CaptureError) as err:
        list(frames(write(tmp_path, "o.pcapng", odd)))
    assert err.value.offset == len(good) and "invalid length 13" in str(err.value)


@pytest.mark.parametrize(("content", "message"), [
    (b"", "empty file"), (b"hello world, not a capture", "not a pcap or pcapng file"),
])
def test_not_a_capture(tmp_path, content, message):
    with pytest.raises(CaptureError) as err:
        list(frames(write(tmp_path, "x.bin", content)))
    assert message in str(err.value) and err.value.offset == 0


def test_missing_and_directory(tmp_path):
    with pytest.raises(CaptureError, match="no such file"):
        list(frames(str(tmp_path / "absent.pcap")))
    with pytest.raises(CaptureError, match="is a directory"):
        list(frames(str(tmp_path)))


def test_gzip_crc_error_reported_after_good_frames(tmp_path):
    raw = bytearray(gzip.compress(pcap([(1, 0, FRAME_A), (2, 0, FRAME_B)]), mtime=0))
    raw[-8] ^= 0xFF  # CRC32 of the trailer
    got = []
    with pytest.raises(CaptureError) as err:
        got.extend(frames(write(tmp_path, "crc.pcap.gz", bytes(raw))))
    assert len(got) == 2 and "CRC" in str(err.value)


IP_FRAME = bytes(12) + b"\x08\x00" + bytes(46)
VLAN_FRAME = bytes(12) + b"\x81\x00" + bytes(50)
RT_FRAME = bytes(12) + b"\x88\x92" + bytes(46)
SHORT_FRAME = bytes(10)  # too short for an EtherType: passed on, the link layer judges it


def test_ip_only_runs_stand_for_the_skipped_frames(tmp_path):
    data = [RT_FRAME, RT_FRAME, IP_FRAME, RT_FRAME, VLAN_FRAME, SHORT_FRAME, RT_FRAME, RT_FRAME, RT_FRAME]
    path = tmp_path / "mix.pcap"
    path.write_bytes(pcap([(n, 500, d) for n, d in enumerate(data, 1)]))
    got = [(f.number, f.ts, f.data, f.run) for f in frames(str(path), ip_only=True)]
    assert got == [(2, 2.0005, b"", 2), (3, 3.0005, IP_FRAME, 0), (4, 4.0005, b"", 1), (5, 5.0005, VLAN_FRAME, 0),
                   (6, 6.0005, SHORT_FRAME, 0), (9, 9.0005, b"", 3)]
    assert [f.run for f in frames(str(path))] == [0] * 9  # without ip_only: a record per frame


def test_ip_only_run_is_accounted_before_damage(tmp_path):
    path = tmp_path / "cut.pcap"
    path.write_bytes(pcap([(1, 0, RT_FRAME), (2, 0, RT_FRAME)]) + struct.pack("<IIII", 3, 0, 60, 60) + bytes(10))
    got = []
    with pytest.raises(CaptureError, match="record data truncated"):
        for f in frames(str(path), ip_only=True):
            got.append((f.number, f.run))
    assert got == [(2, 2)]


def test_ip_only_ignored_for_other_link_types(tmp_path):
    path = tmp_path / "raw.pcap"
    path.write_bytes(pcap([(1, 0, RT_FRAME), (2, 0, RT_FRAME)], linktype=101))
    assert [(f.number, f.run) for f in frames(str(path), ip_only=True)] == [(1, 0), (2, 0)]


def test_cut_runs_at_split_frames(tmp_path):
    from pd_analyze.capture import cut_runs

    data = [RT_FRAME] * 5 + [IP_FRAME] + [RT_FRAME] * 4
    path = tmp_path / "runs.pcap"
    path.write_bytes(pcap([(n, 0, d) for n, d in enumerate(data, 1)]))
    got = [(f.number, f.run) for f in cut_runs(frames(str(path), ip_only=True), (3, 5, 6, 8, 20))]
    assert got == [(2, 2), (4, 2), (5, 1), (6, 0), (7, 1), (10, 3)]


@pytest.mark.parametrize("order", ["<", ">"])
def test_ip_only_runs_across_read_chunks(tmp_path, order):
    """Runs longer than a read chunk (1 MiB), in both byte orders: same frames, numbers and times."""
    rt = RT_FRAME + bytes(440)  # 6,000 of them fill more than a chunk
    data = [IP_FRAME if n % 2500 == 3 else rt for n in range(1, 6_001)]
    path = tmp_path / "long.pcap"
    path.write_bytes(b"".join([pcap([], order=order)] + [
        struct.pack(order + "IIII", n, n % 1000, len(d), len(d)) + d for n, d in enumerate(data, 1)]))
    every = list(frames(str(path)))
    got = list(frames(str(path), ip_only=True))
    assert sum(f.run or 1 for f in got) == len(every) == 6_000
    assert [f for f in got if not f.run] == [f for f in every if f.data == IP_FRAME]
    for f in got:
        if f.run:  # the run ends at its number and carries that frame's time
            assert f.ts == every[f.number - 1].ts and all(e.data == rt for e in every[f.number - f.run:f.number])

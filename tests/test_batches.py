"""The batch reader: exactly the frames and the errors of capture.frames, in numpy columns over one buffer."""

from __future__ import annotations

import gzip
import json
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from devtools.fuzz import corpus
from pd_analyze import capture
from pd_analyze.capture import MAX_CAPLEN, CaptureError, chunks, pcap
from pd_analyze.capture.batches import BATCH_FRAMES, FrameBatch, batches
from tests.test_capture import FRAME_A, FRAME_B, block, epb, idb, shb, spb
from tests.test_capture import pcap as pcap_file
from tests.test_cli import DAMAGE, _damaged

REPO = Path(__file__).resolve().parents[1]
SEEDS = corpus.seed_paths()
SAMPLE = str(REPO / "sample_pcaps" / "pd_retries_and_duplicates.pcap")
DTYPES = {"number": np.int64, "ts": np.float64, "linktype": np.int32, "start": np.int64, "caplen": np.int64,
          "iface": np.int32}


def frames_of(batch: FrameBatch) -> list[capture.RawFrame]:
    return [batch.raw_frame(i) for i in range(len(batch))]


def same(got: list[capture.RawFrame], want: list[capture.RawFrame]) -> None:
    """Field by field, times bit for bit."""
    assert [(f.number, f.linktype, f.data, f.iface) for f in got] == [
        (f.number, f.linktype, f.data, f.iface) for f in want]
    assert [f.ts.hex() for f in got] == [f.ts.hex() for f in want]


def outcome(frames) -> tuple[list[capture.RawFrame], tuple | None]:
    """The frames an iterator yields and the error (path, offset, reason, text) it ends with, if any."""
    got = []
    try:
        for item in frames:
            got.extend(frames_of(item) if isinstance(item, FrameBatch) else [item])
    except CaptureError as exc:
        return got, (exc.path, exc.offset, exc.reason, str(exc))
    return got, None


def small_reads(monkeypatch: pytest.MonkeyPatch, chunk: int = 64) -> None:
    """Reads of `chunk` bytes in both readers, so that records of a small file straddle reads and chunks;
    the record limit shrinks with them, as the batch reader (like pcap_frames) relies on a read holding
    any record whole."""
    from pd_analyze.capture import batches as module

    monkeypatch.setattr(pcap, "_CHUNK", chunk)
    monkeypatch.setattr(pcap, "MAX_CAPLEN", chunk - 16)
    monkeypatch.setattr(module, "MAX_CAPLEN", chunk - 16)


def test_a_read_holds_any_record() -> None:
    assert pcap._CHUNK >= MAX_CAPLEN + 16


def same_outcome(path: str, size: int = BATCH_FRAMES) -> tuple | None:
    want, error = outcome(capture.frames(path))
    got, got_error = outcome(batches(path, size))
    same(got, want)
    assert got_error == error
    return error


# --- every real capture, every batch size --------------------------------------------------------------------
@pytest.mark.parametrize("path", SEEDS, ids=[Path(p).name for p in SEEDS])
def test_same_frames_as_capture_frames(path: str) -> None:
    want = list(capture.frames(path))
    for size in (1, 7, 1000, BATCH_FRAMES):
        got = list(batches(path, size))
        assert all(0 < len(b) <= size for b in got)
        same([f for b in got for f in frames_of(b)], want)


@pytest.mark.parametrize("path", [SAMPLE, str(REPO / "sample_pcaps" / "two_interfaces.pcapng"),
                                  str(REPO / "sample_pcaps" / "record_rw_le.pcap.gz")])
def test_columns_have_the_contract_types_and_frames_lie_in_buf(path: str) -> None:
    info = capture.CaptureInfo(path)
    for batch in batches(path, 100, info):
        assert {name: getattr(batch, name).dtype for name in DTYPES} == {k: np.dtype(v) for k, v in DTYPES.items()}
        assert isinstance(batch.buf, bytes) and len({len(getattr(batch, name)) for name in DTYPES}) == 1
        assert (batch.start >= 0).all() and (batch.start + batch.caplen <= len(batch.buf)).all()
    reference = capture.CaptureInfo(path)
    list(capture.frames(path, reference))
    assert vars(info) == vars(reference)  # format, compression, link types learnt alike


def test_a_batch_holds_a_chunk_at_most(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Memory: a pcap's buf is one chunk (its records' headers included), whatever the file's size."""
    small_reads(monkeypatch, 256)
    path = tmp_path / "many.pcap"
    path.write_bytes(pcap_file([(n, n, bytes([n % 251]) * (14 + n % 40)) for n in range(1, 400)]))
    got = list(batches(str(path), 50))
    assert max(len(b.buf) for b in got) <= chunks.PIECES * 256 + 16 + 60
    same([f for b in got for f in frames_of(b)], list(capture.frames(str(path))))


def test_size_must_be_positive() -> None:
    with pytest.raises(ValueError, match="at least 1"):
        next(batches(SAMPLE, 0))


def test_link_type_beyond_int32_keeps_its_bit_pattern(tmp_path: Path) -> None:
    path = tmp_path / "fcs.pcap"
    path.write_bytes(pcap_file([(1, 0, FRAME_A)], linktype=0xF0000001))
    (batch,) = batches(str(path))
    assert batch.linktype.view(np.uint32).tolist() == [f.linktype for f in capture.frames(str(path))]


# --- damaged files: the same frames before the damage, the same error -------------------------------------------
@pytest.mark.parametrize("kind", [k for k in DAMAGE if k != "stdin_cut"])
def test_damaged_files_of_the_cli_tests(tmp_path: Path, kind: str) -> None:
    path, _stdin, frames, offset = _damaged(tmp_path, kind)
    error = same_outcome(path)
    assert error is not None and error[1] == offset


def _records(count: int) -> list[tuple[int, int, bytes]]:
    return [(n, n * 7919 % 1_000_000, bytes([n]) * (14 + n * 5 % 31)) for n in range(1, count + 1)]


@pytest.mark.parametrize(("magic", "order"), [(0xA1B2C3D4, "<"), (0xA1B23C4D, ">")])
def test_pcap_cut_at_every_byte(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, magic: int, order: str) -> None:
    """Every length of a pcap, with reads of 64 bytes so that records straddle reads and chunks."""
    small_reads(monkeypatch)
    data = pcap_file(_records(25), magic, order)
    path = tmp_path / "cut.pcap"
    errors = set()
    for end in range(len(data) + 1):
        path.write_bytes(data[:end])
        error = same_outcome(str(path), 3)
        errors.add(error[2].split(" (")[0] if error else None)
    assert errors >= {None, "empty file: no capture header", "pcap file header truncated", "record header truncated",
                      "record data truncated"}


def test_gzip_cut_and_corrupted_anywhere(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A gzip stream ends early or breaks at every point: the frames inflated before it and the error (a record
    cut short, or the read that fails) are those of capture.frames, whose reads the batch reader follows."""
    small_reads(monkeypatch)
    data = pcap_file(_records(60))
    packed = gzip.compress(data, compresslevel=1, mtime=0)
    path = tmp_path / "cut.pcap.gz"
    reasons = set()
    for end in range(10, len(packed) + 1):
        path.write_bytes(packed[:end])
        error = same_outcome(str(path), 5)
        reasons.add(error[2].split(" (")[0] if error else None)
    for at in range(10, len(packed) - 8, 3):
        broken = bytearray(packed)
        broken[at] ^= 0x55
        path.write_bytes(bytes(broken))
        error = same_outcome(str(path), 5)
        reasons.add(error[2].split(" (")[0] if error else None)
    assert {"record header truncated", "record data truncated", "read failed"} <= reasons


@pytest.mark.parametrize("kind", ["truncated_data", "truncated_header", "too_long", "too_long_in_chunk", "crc",
                                  "trailing_garbage", "multi_member"])
def test_pcap_damage(tmp_path: Path, kind: str) -> None:
    good = pcap_file([(1, 0, FRAME_A), (2, 500_000, FRAME_B)])
    data = {
        "truncated_data": good[:-10],
        "truncated_header": good + b"\x01\x02\x03",
        "too_long": good + struct.pack("<IIII", 2, 0, 0xFFFFFFF0, 0xFFFFFFF0),
        "too_long_in_chunk": good + struct.pack("<IIII", 3, 0, MAX_CAPLEN + 1, 60) + bytes(MAX_CAPLEN + 100),
        "crc": gzip.compress(good, mtime=0)[:-8] + b"\x00" * 4 + gzip.compress(good, mtime=0)[-4:],
        "trailing_garbage": gzip.compress(good) + b"junk",
        "multi_member": gzip.compress(good[:30]) + gzip.compress(good[30:]),
    }[kind]
    path = tmp_path / "damaged.pcap"
    path.write_bytes(data)
    same_outcome(str(path))


def _pcapng_damage(kind: str) -> bytes:
    good = shb() + idb(1) + epb(0, 5, FRAME_A)
    short = {"epb12": (6, 12), "epb28": (6, 28), "pb16": (2, 16), "spb12": (3, 12)}
    if kind in short:
        btype, size = short[kind]
        return good + struct.pack("<II", btype, size) + bytes(size - 12) + struct.pack("<I", size)
    if kind == "trailer":
        bad = bytearray(epb(0, 0, FRAME_B))
        bad[-4:] = struct.pack("<I", 12)
        return good + bytes(bad)
    if kind == "odd_length":
        return good + struct.pack("<II", 6, 13)
    if kind == "big_epb":
        interface = block(1, struct.pack("<HHI", 1, 0, 0xFFFFFFFF))
        return shb() + interface + epb(0, 0, FRAME_A) + epb(0, 0, bytes(MAX_CAPLEN + 4))
    if kind == "big_spb":
        interface = block(1, struct.pack("<HHI", 1, 0, 0xFFFFFFFF))
        big = bytes(MAX_CAPLEN + 4)
        return shb() + interface + spb(FRAME_A) + block(3, struct.pack("<I", len(big)) + big)
    if kind == "unknown_iface":
        return good + epb(3, 0, FRAME_B)
    if kind == "cut":
        return (good + epb(0, 7, FRAME_B))[:-9]
    raise AssertionError(kind)


@pytest.mark.parametrize("compressed", [False, True])
@pytest.mark.parametrize("kind", ["epb12", "epb28", "pb16", "spb12", "trailer", "odd_length", "big_epb", "big_spb",
                                  "unknown_iface", "cut"])
def test_pcapng_damage(tmp_path: Path, kind: str, compressed: bool) -> None:
    data = _pcapng_damage(kind)
    path = tmp_path / "damaged.pcapng"
    path.write_bytes(gzip.compress(data, mtime=0) if compressed else data)
    error = same_outcome(str(path), 1)
    assert error is not None and ("decompressed data" in error[2]) == compressed


def _pcapng_mix() -> bytes:
    """Two sections (little- then big-endian), interfaces with their own resolutions and offsets, every
    packet block kind, blocks to skip, times past 2^53 ticks."""
    def pb(iface: int, ticks: int, data: bytes, order: str = "<") -> bytes:
        return block(2, struct.pack(order + "HHIIII", iface, 0, ticks >> 32, ticks & 0xFFFFFFFF, len(data),
                                    len(data)) + data, order)

    def idb_offset(linktype: int, offset: int, order: str) -> bytes:
        opts = struct.pack(order + "HH", 9, 1) + bytes([0x80 | 20, 0, 0, 0])  # 2^-20 s
        opts += struct.pack(order + "HHq", 14, 8, offset) + struct.pack(order + "HH", 0, 0)
        return block(1, struct.pack(order + "HHI", linktype, 0, 0) + opts, order)

    frames = [bytes([n]) * (14 + n % 23) for n in range(1, 40)]
    out = shb() + idb(1) + block(0x0BAD, b"custom") + idb(113, tsresol=9)
    for n, frame in enumerate(frames[:20]):
        out += epb(n % 2, 1_700_000_000_123_456_789 + n * 977, frame) if n % 5 else spb(frame)
    out += pb(1, 1 << 60, frames[20]) + block(5, bytes(16))  # a packet block, an interface statistics block
    out += shb(">") + idb_offset(1, -3600, ">") + idb(101, tsresol=6, order=">")
    for n, frame in enumerate(frames[21:]):
        out += epb(n % 2, (1 << 40) + n * 12_345, frame, ">")
    return out


@pytest.mark.parametrize("compressed", [False, True])
def test_pcapng_cut_at_every_byte(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compressed: bool) -> None:
    """Every length of a pcapng of every kind of block, read in small pieces so that blocks straddle chunks."""
    small_reads(monkeypatch)
    data = _pcapng_mix()
    assert len(list(capture.frames(_write(tmp_path, data, False)))) == 39
    reasons = set()
    for end in range(0, len(data) + 1, 3 if compressed else 1):
        error = same_outcome(_write(tmp_path, data[:end], compressed), 3)
        reasons.add(error[2].split(" (")[0] if error else None)
    assert {None, "block truncated", "section header block truncated"} <= reasons


@pytest.mark.parametrize("compressed", [False, True])
def test_pcapng_corrupted_anywhere(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compressed: bool) -> None:
    """A byte flipped anywhere (every third byte: every position in a 32-bit word is hit)."""
    small_reads(monkeypatch)
    data = _pcapng_mix()
    reasons = []
    for at in range(0, len(data), 3):
        broken = bytearray(data)
        broken[at] ^= 0xFF
        error = same_outcome(_write(tmp_path, bytes(broken), compressed), 4)
        reasons.append(error[2] if error else "")
    for told in ("has invalid length", "trailing length differs", "caplen", "names interface", "byte-order magic"):
        assert any(told in reason for reason in reasons), told


def test_gzip_pcapng_cut_in_its_compressed_data(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    small_reads(monkeypatch)
    packed = gzip.compress(_pcapng_mix(), compresslevel=1, mtime=0)
    reasons = set()
    for end in range(10, len(packed) + 1):
        path = tmp_path / "cut.pcapng.gz"
        path.write_bytes(packed[:end])
        error = same_outcome(str(path), 5)
        reasons.add(error[2].split(" (")[0] if error else None)
    assert {"block truncated", "read failed"} <= reasons


def _write(tmp_path: Path, data: bytes, compressed: bool) -> str:
    path = tmp_path / ("x.pcapng.gz" if compressed else "x.pcapng")
    path.write_bytes(gzip.compress(data, compresslevel=1, mtime=0) if compressed else data)
    return str(path)


def test_pcapng_sections_changing_byte_order_over_and_over(tmp_path: Path) -> None:
    """300 sections, little- and big-endian in turn: past a few changes a chunk is read block by block."""
    data = b"".join(shb(o) + idb(1, order=o) + epb(0, n, bytes([n % 256]) * 60, o) + spb(bytes(61), o)
                    for n, o in zip(range(300), "<>" * 150, strict=True))
    for end in (len(data), len(data) - 5, len(data) // 2 + 3):
        path = _write(tmp_path, data[:end], False)
        same_outcome(path, 7)
    assert len(list(capture.frames(_write(tmp_path, data, False)))) == 600


def test_unreadable_missing_and_permission(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert "read failed" in same_outcome("/proc/self/mem")[2]
    assert "no such file" in same_outcome(str(tmp_path / "absent.pcap"))[2]

    def denied(path: str, mode: str) -> None:
        raise PermissionError(13, "Permission denied", path)

    from pd_analyze.capture import reader

    monkeypatch.setattr(reader, "open", denied, raising=False)
    assert "permission denied" in same_outcome("/some/capture.pcap")[2]


def test_a_read_failing_after_good_reads_is_met_where_capture_frames_meets_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A file whose reads fail from some byte on (a failing disk): the same frames, the same offset."""
    small_reads(monkeypatch)
    data = pcap_file(_records(80))
    path = tmp_path / "disk.pcap"
    path.write_bytes(data)

    from pd_analyze.capture import reader

    for bad in range(100, len(data), 37):
        monkeypatch.setattr(reader, "open", _failing_from(bad), raising=False)
        error = same_outcome(str(path), 4)
        assert error is not None and "Input/output error" in error[2]


def test_a_failing_disk_under_a_pcapng_stops_the_frames_with_a_read_failure(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """pcapng reads block by block, the batch reader in chunks: where a failing disk stops them may differ
    (it does on a real disk too, with the buffer's reads); the frames before it and the message do not."""
    small_reads(monkeypatch)
    path = tmp_path / "disk.pcapng"
    path.write_bytes(_pcapng_mix())

    from pd_analyze.capture import reader

    for bad in range(100, len(_pcapng_mix()), 53):
        monkeypatch.setattr(reader, "open", _failing_from(bad), raising=False)
        want, error = outcome(capture.frames(str(path)))
        got, got_error = outcome(batches(str(path), 4))
        same(got, want[:len(got)])
        assert got_error is not None and error is not None and got_error[1] <= error[1]
        assert got_error[2] == error[2] and error[2].startswith("read failed") and "Input/output" in error[2]


def _failing_from(bad: int):
    """An `open` whose files fail every read that reaches byte `bad`."""

    class Failing:
        def __init__(self, name: str, mode: str) -> None:
            self.file = open(name, mode)  # noqa: SIM115

        def __getattr__(self, name: str):
            return getattr(self.file, name)

        def read(self, size: int = -1) -> bytes:
            if size < 0 or self.file.tell() + size > bad:
                raise OSError(5, "Input/output error")
            return self.file.read(size)

    return Failing


STDIN_CODE = """
import json, sys
from pd_analyze import capture
from pd_analyze.capture.batches import batches
out = []
try:
    frames = (b.raw_frame(i) for b in batches("-", 3) for i in range(len(b))) if sys.argv[1] == "batches" \
        else capture.frames("-")
    for f in frames:
        out.append([f.number, f.ts.hex(), f.linktype, f.data.hex(), f.iface])
except capture.CaptureError as exc:
    out.append([exc.path, exc.offset, exc.reason])
print(json.dumps(out))
"""


@pytest.mark.parametrize("kind", ["whole", "cut", "gzip", "pcapng"])
def test_standard_input(kind: str) -> None:
    good = Path(SAMPLE).read_bytes()
    data = {"whole": good, "cut": good[:5000], "gzip": gzip.compress(good[:7000]),
            "pcapng": (REPO / "sample_pcaps" / "two_interfaces.pcapng").read_bytes()}[kind]
    runs = [subprocess.run([sys.executable, "-c", STDIN_CODE, reader], input=data, capture_output=True, timeout=60,
                           cwd=REPO) for reader in ("batches", "frames")]
    assert [r.returncode for r in runs] == [0, 0], runs[0].stderr
    got, want = (json.loads(r.stdout) for r in runs)
    assert got == want and len(want) > 5



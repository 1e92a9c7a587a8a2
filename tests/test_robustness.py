"""Hostile input: the accounting invariant, the memory caps, and a regression test for every decoder fix the
fuzz harness and the property tests led to (each test names what crashed, hung or grew before the fix)."""

from __future__ import annotations

import gzip
import io
import json
import struct
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

import pd_analyze
from devtools import hostile
from devtools.fuzz import corpus
from devtools.synth import fixtures
from devtools.synth.pd_encode import ParamAddress, change_ok, change_request, value_block
from devtools.synth.sim_capture import Capture
from pd_analyze import capture
from pd_analyze.analysis.capture_run import CaptureResult, Settings
from pd_analyze.analysis.engine.rules import LastDone
from pd_analyze.analysis.engine.run import EngineRun, analyze_frames
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.schema import frame_of
from pd_analyze.capture import gzip_stream, reader
from pd_analyze.capture.batches import frame_batches
from pd_analyze.model import capped
from pd_analyze.model.rules import finding
from pd_analyze.protocol import link, profidrive, rpc, rpc_calls, rpc_fragments
from pd_analyze.protocol.dissector import MAX_LOOSE_FINDINGS, Dissector
from pd_analyze.protocol.frames import Accounting
from pd_analyze.protocol.hold import MAX_HELD_FIELDS
from tests.test_capture import FRAME_A, block, epb, idb, shb

REPO = Path(__file__).resolve().parents[1]
SEEDS = corpus.seed_paths()


# --- the accounting invariant on every capture ----------------------------------------------------------------
@pytest.mark.parametrize("path", SEEDS, ids=[Path(p).name for p in SEEDS])
def test_every_frame_is_accounted_for(path: str) -> None:
    """frames read = decoded + skipped (by reason) + malformed (by reason), from analyze() and the summary."""
    a = pd_analyze.analyze(path)
    row = a.accounting.iloc[0]
    frames = sum(1 for _ in capture.frames(path))
    assert row.read == frames and bool(row.balanced)
    assert row.read == row.decoded + sum(row.skipped_by_reason.values()) + sum(row.malformed_by_reason.values())
    assert (row.skipped, row.malformed) == (sum(row.skipped_by_reason.values()), sum(row.malformed_by_reason.values()))
    from pd_analyze.output import report

    text = report.summary(a)
    assert f"{row.read} frames read = {row.decoded} decoded + {row.skipped} skipped + {row.malformed} malformed" in text
    for why, n in row.skipped_by_reason.items():
        assert f"{n} {why}" in text


def test_invalid_ip_header_counts_as_malformed() -> None:
    ip = bytearray(struct.pack(">BBHHHBBH4s4s", 0x43, 0, 40, 0, 0, 64, 17, 0, bytes(4), bytes(4)) + bytes(20))
    d = Dissector()
    d.feed(capture.RawFrame(1, 0.0, 1, bytes(12) + b"\x08\x00" + bytes(ip)))
    assert d.accounting.malformed == {link.SKIP_MALFORMED: 1} and d.accounting.balanced()


# --- capture.py ---------------------------------------------------------------------------------------------
def test_gzip_of_a_highly_compressible_pcapng_reads_in_linear_time(tmp_path: Path) -> None:
    """Before: every small read copied the whole inflated rest: 300,000 frames took 197 s (quadratic)."""
    data = shb() + idb(1) + epb(0, 0, bytes(60)) * 200_000
    path = tmp_path / "zeros.pcapng.gz"
    path.write_bytes(gzip.compress(data, compresslevel=9))
    started = time.perf_counter()
    assert sum(1 for _ in capture.frames(str(path))) == 200_000
    assert time.perf_counter() - started < 10


def test_gzip_inflates_in_bounded_steps() -> None:
    """A 100 MB run of zeros in 100 kB: one read inflates at most _GZIP_STEP bytes, not the whole member."""
    bomb = gzip.compress(bytes(100 * 1024 * 1024), compresslevel=9)
    stream = gzip_stream._Gunzip(io.BytesIO(bomb))
    for _ in range(1000):
        assert stream.read(16) == bytes(16)
        assert len(stream.pending) <= 2 * gzip_stream._GZIP_STEP
    assert len(stream.backlog) <= len(bomb)


def test_gzip_multi_member_and_trailing_garbage(tmp_path: Path) -> None:
    raw = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1) + struct.pack("<IIII", 1, 0, 60, 60) + FRAME_A
    for blob, frames in ((gzip.compress(raw[:30]) + gzip.compress(raw[30:]), 1), (gzip.compress(raw) + b"junk", 1)):
        path = tmp_path / "m.pcap.gz"
        path.write_bytes(blob)
        assert len(list(capture.frames(str(path)))) == frames


@pytest.mark.parametrize(("btype", "size"), [(6, 12), (6, 28), (2, 16), (3, 12)])
def test_pcapng_packet_block_shorter_than_its_header(tmp_path: Path, btype: int, size: int) -> None:
    """Before: an EPB/PB of 12-28 bytes with consistent length fields raised struct.error (property test)."""
    block = struct.pack("<II", btype, size) + bytes(size - 12) + struct.pack("<I", size)
    good = shb() + idb(1) + epb(0, 0, FRAME_A)
    path = tmp_path / "short.pcapng"
    path.write_bytes(good + block)
    got = []
    with pytest.raises(capture.CaptureError) as err:
        got.extend(capture.frames(str(path)))
    assert len(got) == 1 and err.value.offset == len(good) and "shorter than its" in err.value.reason


@pytest.mark.parametrize("kind", ["epb", "spb"])
def test_pcapng_caplen_above_the_limit(tmp_path: Path, kind: str) -> None:
    """Before: a pcapng packet block could carry up to 327,680 bytes (its length limit), above MAX_CAPLEN."""
    big = bytes(capture.MAX_CAPLEN + 4)
    interface = block(1, struct.pack("<HHI", 1, 0, 0xFFFFFFFF))  # snaplen 2^32 - 1
    good = shb() + interface + epb(0, 0, FRAME_A)
    path = tmp_path / "big.pcapng"
    path.write_bytes(good + (epb(0, 0, big) if kind == "epb" else block(3, struct.pack("<I", len(big)) + big)))
    got = []
    with pytest.raises(capture.CaptureError) as err:
        got.extend(capture.frames(str(path)))
    assert len(got) == 1 and err.value.offset == len(good) and f"exceeds {capture.MAX_CAPLEN}" in err.value.reason


def test_read_error_is_a_capture_error() -> None:
    """Before: EIO on the first read (a failing disk, /proc/self/mem) escaped as OSError: 'internal error'."""
    with pytest.raises(capture.CaptureError, match="read failed"):
        list(capture.frames("/proc/self/mem"))


def test_permission_denied(monkeypatch: pytest.MonkeyPatch) -> None:
    def denied(path: str, mode: str) -> None:
        raise PermissionError(13, "Permission denied", path)

    monkeypatch.setattr(reader, "open", denied, raising=False)
    with pytest.raises(capture.CaptureError, match="permission denied"):
        list(capture.frames("/some/capture.pcap"))


def test_gzip_error_offsets_say_they_are_in_the_decompressed_data(tmp_path: Path) -> None:
    raw = bytearray(gzip.compress(shb() + idb(1) + epb(0, 0, FRAME_A) + b"\x06\x00\x00\x00", mtime=0))
    path = tmp_path / "cut.pcapng.gz"
    path.write_bytes(bytes(raw))
    with pytest.raises(capture.CaptureError) as err:
        list(capture.frames(str(path)))
    assert "decompressed data" in str(err.value) and err.value.offset is not None


# --- tables --------------------------------------------------------------------------------------------------
def test_pcapng_times_beyond_datetime64_become_nat(tmp_path: Path) -> None:
    """Before: a pcapng timestamp after 2262 (tsresol 0, ticks 2^40) crashed building the tables."""
    frames = list(capture.frames(str(REPO / "sample_pcaps" / "worked_example.pcap")))
    data = shb() + idb(1, tsresol=0) + b"".join(epb(0, (1 << 40) + i, f.data) for i, f in enumerate(frames))
    path = tmp_path / "future.pcapng"
    path.write_bytes(data)
    a = pd_analyze.analyze(str(path))
    assert len(a.transactions) == 1 and a.transactions.t_start.isna().all()
    assert frame_of("transactions", Rows().transactions).empty


# --- link.py: IP reassembly caps ----------------------------------------------------------------------------
def _fragment(ident: int, offset8: int, size: int = 64, more: bool = True, fill: int = 0, src: int = 1) -> bytes:
    payload = bytes([fill]) * size
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + size, ident, (0x2000 if more else 0) | offset8, 64, 17, 0,
                     bytes([10, 0, src >> 8 & 0xFF, src & 0xFF]), bytes([10, 0, 0, 1]))
    return bytes(12) + b"\x08\x00" + ip + payload


def test_one_datagram_flooded_with_pieces_is_capped() -> None:
    """Before: pieces of one datagram were unbounded, and each new one was compared with all (quadratic)."""
    decoder = link.LinkDecoder()
    started = time.perf_counter()
    for n in range(20_000):
        decoder.datagram(n + 1, 1, _fragment(7, n % 8000, 8))
    assert time.perf_counter() - started < 10
    entry = next(iter(decoder._open.values()))
    assert len(entry.pieces) <= capped.IP_PIECES and decoder.evicted >= 20_000 // capped.IP_PIECES - 1


def test_identical_fragment_copies_are_not_held_twice() -> None:
    decoder = link.LinkDecoder()
    for n in range(100):
        decoder.datagram(n + 1, 1, _fragment(7, 0, 64))
    entry = next(iter(decoder._open.values()))
    assert len(entry.pieces) == 1 and decoder._open.bytes == 64 + link.PIECE_OVERHEAD


def test_many_datagrams_evicted_with_bounded_findings() -> None:
    decoder = link.LinkDecoder()
    for n in range(5000):
        decoder.datagram(n + 1, 1, _fragment(n & 0xFFFF, 0, 1400, src=n >> 16))
        assert len(decoder._open) <= capped.IP_DATAGRAMS.count and decoder._open.bytes <= capped.IP_DATAGRAMS.bytes
    assert decoder.evicted == 5000 - capped.IP_DATAGRAMS.count
    listed = [f for f in decoder.findings if f.name == "ip_frag_evicted"]
    assert len(listed) == capped.MAX_LISTED
    decoder.findings = []  # the dissector drains them after every frame
    ends = decoder.finish()
    summary = [f for f in ends if f.name == "ip_frag_evicted"]
    assert len(summary) == 1 and f"{5000 - capped.IP_DATAGRAMS.count - 100} more datagrams" in summary[0].message
    assert sum(f.name == "ip_frag_incomplete" for f in ends) == capped.IP_DATAGRAMS.count


# --- rpc.py: CL fragments and calls -------------------------------------------------------------------------
def _hdr(num: int, last: bool = False, seq: int = 1) -> rpc.Header:
    return rpc.Header((), True, 0, 0x04 | (0x02 if last else 0), b"a" * 16, b"i" * 16, seq, 3, 0, num)


def test_fragment_set_flooded_with_numbers_is_capped() -> None:
    """Before: one set held any number of fragments (65,536 x 64 kB), and its 'missing' finding listed every
    absent number (a 300 kB message per set, 3 s to build at the end of the capture)."""
    table = rpc_fragments.FragmentTable()
    findings: list = []
    for n in range(0, 3000, 2):
        table.add((b"a", 1, 0, b"s", b"d"), n, 0.0, _hdr(n), bytes(1384), findings)
        assert table._sets.bytes <= capped.CL_SET_BYTES
    assert any(f.name == "rpc_frag_evicted" and "above" in f.message for f in findings)
    (missing,) = table.finish(9999)
    assert missing.name == "rpc_frag_missing" and len(missing.message) < 300 and "more)" in missing.message


def test_fragment_table_total_bytes_and_done_digests_are_capped() -> None:
    table = rpc_fragments.FragmentTable()
    findings: list = []
    for s in range(20_000):
        table.add((b"a", s, 0, b"s", b"d"), s, 0.0, _hdr(0, seq=s), bytes(1384), findings)
        assert table._sets.bytes <= capped.CL_FRAGMENT_SETS.bytes and len(table._sets) <= capped.CL_FRAGMENT_SETS.count
    assert table.evicted > 0 and sum(f.name == "rpc_frag_evicted" for f in findings) == capped.MAX_LISTED
    for s in range(3000):  # complete sets of 40 fragments each: the digests kept for late copies are capped
        for n in range(40):
            table.add((b"b", s, 0, b"s", b"d"), n, 0.0, _hdr(n, last=n == 39, seq=s), bytes([n]), findings)
    assert table._done.bytes <= capped.CL_DONE_SETS.bytes and len(table._done) <= capped.CL_DONE_SETS.count


def test_answers_find_their_fragment_sets_without_a_scan() -> None:
    """Before: every response scanned all open fragment sets (4,096 per frame)."""
    table = rpc_fragments.FragmentTable()
    findings: list = []
    for s in range(4000):
        table.add((b"a" * 16, s, 0, b"s", b"d"), s, 0.0, _hdr(0, seq=s), b"x", findings)
    started = time.perf_counter()
    for s in range(4000):
        table.drop_call((b"a" * 16, s), s, findings)
    assert time.perf_counter() - started < 1 and not table._sets and not table._by_call
    assert sum(f.name == "rpc_frag_missing" for f in findings) == 4000


def test_open_and_closed_calls_are_capped_by_bytes() -> None:
    calls = rpc_calls.CallTable()
    findings: list = []
    for s in range(2000):
        key = (b"a", s)
        call = calls.request(key, rpc_calls.Call(s, 0.0, b"s", b"d", b"i", 3, bytes(60_000)), findings)
        calls.charge(key, call, 100_000, findings)
        assert calls.open.bytes <= capped.OPEN_CALLS.bytes + 200_000
        if s % 2:
            calls.close(key)
            assert calls.closed.bytes <= capped.ANSWERED_CALLS.bytes
    assert calls.evicted > 0 and calls.finish() != []
    assert sum(f.name == "rpc_call_evicted" for f in findings) == capped.MAX_LISTED


# --- profidrive.py -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("record", [bytes([1, 0x01, 1, 2, 0x09, 1, 65]), bytes([1, 0x81, 1, 3, 0x09, 3, 65, 66, 67]),
                                    bytes([1, 0x02, 1, 2]) + bytes([0x10, 1, 0, 1, 0, 0]) * 2 + bytes([0x09, 1, 65])])
def test_odd_value_list_at_the_record_end_with_more_blocks_expected(record: bytes) -> None:
    """Before: IndexError looking for the pad byte past the end (the long fuzz run, cases 12728 and 33700)."""
    findings: list = []
    parse = profidrive.parse_request if record[1] == 0x02 else profidrive.parse_response
    p = parse(record, 1, findings)
    assert not p.complete and len(p.blocks) == 1 and p.end == len(record)
    assert [f.name for f in findings] in (["pd_response_truncated"], ["change_blocks"])


# --- dissect.py and transactions.py -------------------------------------------------------------------------
def test_channel_table_is_capped_by_bytes() -> None:
    """Before: 16,384 channels each kept a parsed request of up to 255 parameters (400 MB)."""
    d = Dissector()
    for raw in hostile.frames("calls", 20_000):
        d.feed(raw)
        assert d._pd_requests.bytes <= 16 * 1024 * 1024 + 100_000
    assert len(d._pd_requests) < 20_000
    assert d._pd_requests.bytes == sum(profidrive.footprint(p) for p, _ in d._pd_requests.values())


class _Counting(Rows):
    """The engine's rows counted, not kept (a streaming consumer)."""

    def __init__(self) -> None:
        super().__init__()
        self.evicted = 0

    def add_table(self, name: str, table: object) -> None:
        if name == "transactions":
            self.evicted += sum(c == "evicted" for c in table.column("closed_by").to_pylist())  # type: ignore[attr-defined]

    def add_finding(self, capture: str, f: object, txn: int | None = None) -> None:
        pass


def test_engine_state_is_bounded() -> None:
    """Before: pending transactions were unbounded, closed ones stayed alive through the call table, and a
    read on a new channel scanned every pending transaction."""
    rows = _Counting()
    engine = EngineRun(Settings(), rows, lambda _f: "flood", [CaptureResult("flood", Accounting())])
    machine = engine.machine
    started = time.perf_counter()
    for batch in frame_batches(hostile.frames("calls", 40_000), 1000):
        engine.feed(batch)
        assert machine.pending.bytes <= capped.PENDING_TRANSACTIONS.bytes + 100_000
        assert engine.last_request.bytes <= capped.CHANNEL_REQUESTS.bytes + 100_000
        assert len(engine.pairing.open) <= capped.OPEN_CALLS.count
    assert time.perf_counter() - started < 120
    assert rows.evicted > 0 and len(machine.pending) <= capped.PENDING_TRANSACTIONS.count
    pending = {id(t) for t in machine.pending.values()}
    referenced = {id(t) for c in machine._calls.values() for t in c.txns if t is not None}
    assert referenced <= pending  # no closed transaction is kept alive by its calls
    # a channel's last transaction is kept whole only while it is open
    assert all(isinstance(v, LastDone) or not v.closed_by for v in engine.finals.last.values())


def test_long_b5_polling_is_linear_and_bounded() -> None:
    """Before: every frame of a transaction was checked against all its frames (quadratic), without limit."""
    cap = Capture()
    s = fixtures.session(cap, 1, rtt_us=1, gap_us=1)
    req = change_request(1, 1, [(ParamAddress(1120), value_block(0x08, [1.0]))])
    s.parameter_access(req, change_ok(1, 1, 1), b5_retries=6000)
    rows = Rows()
    started = time.perf_counter()
    frames = [capture.RawFrame(number, f.ts_ns / 1e9, 1, f.data) for number, f in enumerate(cap.frames, 1)]
    analysis = pd_analyze.Analysis(rows, [analyze_frames(frames, Settings(), rows, "b5")], "generic", 10.0, 5.0)
    assert time.perf_counter() - started < 30
    first = analysis.transactions.iloc[0]
    assert first.closed_by == "evicted" and len(first.frames.split()) == capped.TXN_FRAMES + 1
    found = analysis.findings
    assert (found[found.txn == first.txn].name == "txn_evicted").any() and first.verdict == "timeout"


def test_dump_hold_is_bounded_by_fields() -> None:
    """Before: the dump held up to 10,000 annotated frames waiting for answers (500 MB of fields)."""
    d = Dissector(annotate=True)
    for raw in hostile.frames("calls", 3000):
        d.feed(raw)
        assert d.hold._fields <= MAX_HELD_FIELDS + 1000
        assert len(d.hold._fragments) <= capped.CL_FRAGMENT_SETS.count
    assert set(d.hold._index) == {r.frame for r in d.hold._held}


def test_dump_keeps_a_bounded_number_of_loose_findings() -> None:
    d = Dissector(annotate=True)
    bad = bytes(12) + b"\x08\x00" + struct.pack(">BBHHHBBH4s4s", 0x43, 0, 40, 0, 0, 64, 17, 0, bytes(4), bytes(4))
    d.loose_findings = [finding("link_malformed", 1, "ip.len", 0, 0, "x")] * MAX_LOOSE_FINDINGS
    d.feed(capture.RawFrame(1, 0.0, 1, bad + bytes(20)))
    assert len(d.loose_findings) == MAX_LOOSE_FINDINGS and d.loose_dropped == 1


# --- memory: hostile captures ------------------------------------------------------------------------------
HOSTILE_FRAMES = 200_000
EXPECTED_CAPS = {"ip": {"ip_frag_evicted"}, "cl": {"rpc_frag_evicted"}, "calls": {"rpc_call_evicted", "txn_evicted"},
                 "mixed": {"ip_frag_evicted", "rpc_frag_evicted", "rpc_call_evicted", "txn_evicted"}}


@pytest.fixture(scope="module")
def hostile_runs() -> list[dict]:
    """200,000 frames of only unfinished fragments or unanswered requests, each kind in its own process; the
    fragment kinds also keep the table rows and build the DataFrames, as analyze() does."""
    runs = [(kind, False) for kind in EXPECTED_CAPS] + [("ip", True), ("cl", True)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        return list(pool.map(lambda run: hostile.run_isolated(run[0], HOSTILE_FRAMES, tables=run[1]), runs))


def test_hostile_captures_keep_memory_bounded(hostile_runs: list[dict]) -> None:
    """Every frame read once, every cap hit, and the peak RSS under hostile.LIMIT_MB (issue #23's 300 MiB;
    README, Robustness, has the 1,000,000-frame run). Before: the floods of never-answered calls peaked at
    about 400-420 MiB (a batch's 39-parameter rows made in one go, summary rows as Python in one go)."""
    assert [r["path"] for r in hostile_runs] == ["report"] * 4 + ["tables"] * 2
    for r in hostile_runs:
        assert r["frames"] == HOSTILE_FRAMES and r["balanced"], r
        assert set(r["evictions"]) == EXPECTED_CAPS[r["kind"]], r
        assert r["peak_rss_mb"] < hostile.LIMIT_MB, r


def test_hostile_command_line() -> None:
    r = subprocess.run([sys.executable, "-m", "devtools.hostile", "--kind", "ip", "--frames", "5000", "--json"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout)
    assert result["kind"] == "ip" and result["balanced"] and result["peak_rss_mb"] < hostile.LIMIT_MB



def test_skipped_runs_give_the_same_results_and_accounting(tmp_path):
    """The reader's runs of non-IP frames (ip_only) change nothing but the speed."""
    from devtools.synth.mixed_capture import make_capture
    from pd_analyze.protocol.dissector import dissect_frames

    path = tmp_path / "mixed.pcap"
    count = make_capture(path, 3000, pnio_share=0.2)

    def run(ip_only: bool) -> tuple[list, Dissector]:
        d = Dissector()
        out = [(r.frame, r.summary, r.findings) for r in dissect_frames(capture.frames(str(path), ip_only=ip_only), d)]
        return out, d

    (plain, d1), (runs, d2) = run(False), run(True)
    assert runs == plain and len(plain) > 500
    assert d2.accounting == d1.accounting and d2.accounting.read == count and d2.accounting.balanced()
    assert d2.accounting.skipped[link.SKIP_NOT_IPV4] > count // 2


# --- a capture whose file name is not UTF-8 ------------------------------------------------------------------
@pytest.mark.parametrize("fmt", ["csv", "json", "parquet", "html"])
def test_a_file_name_that_is_not_utf8_is_named_with_escapes_in_every_output(fmt: str, tmp_path: Path) -> None:
    """A Latin-1 file name (undecodable bytes come to Python as lone surrogates, which no UTF-8 file holds): the
    report is written in every format, each table names the capture with the byte escaped (caf\\xe9.pcap), as
    analyze() and the summary do; it was an internal error for CSV, Parquet and HTML."""
    import os

    import pandas as pd

    src = Path("sample_pcaps/fault_trace.pcap")
    path = os.path.join(os.fsdecode(tmp_path), os.fsdecode(b"caf\xe9.pcap"))
    with open(path, "wb") as f:
        f.write(src.read_bytes())
    shown = os.fsdecode(tmp_path) + "/caf\\xe9.pcap"
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "report", "--format", fmt, "--out", str(out), path],
                       capture_output=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.decode().splitlines()[0].startswith(f"{shown}: 408 frames read = 408 decoded")
    if fmt == "json":
        first = json.loads((out / "transactions.jsonl").read_text(encoding="utf-8").splitlines()[0])
        assert first["capture"] == shown
    elif fmt == "parquet":
        assert set(pd.read_parquet(out / "transactions").capture.astype(str)) == {"caf\\xe9.pcap"}
    else:
        assert set(pd.read_csv(out / "transactions.csv").capture) == {shown}
    if fmt == "html":
        assert "<title>pd-analyze report: caf\\xe9.pcap</title>" in (out / "report.html").read_text(encoding="utf-8")
    a = pd_analyze.analyze(path)
    assert set(a.transactions.capture.astype(str)) == {shown} and len(a.transactions) == 62
    assert a.accounting.capture.tolist() == [shown]

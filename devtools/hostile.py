"""Hostile captures for the memory bounds: only unfinished fragments, or only requests never answered.

    python -m devtools.hostile --frames 1000000                 # every kind, report path (README table)
    python -m devtools.hostile --frames 1000000 --kind cl --dump   # one kind through the dump path
    python -m devtools.hostile --frames 1000000 --kind ip --tables # keeping the table rows, as analyze()

The frames are made by the sample generator's encoders (one template per kind, then the fields that
make each frame new are patched in) and streamed into the analyser without a file, one microsecond
apart, so no timeout ever frees anything: only the caps of the reassembly tables, the call table, the
channel tables and the transaction engine bound the memory. Each kind runs in its own process and
reports its peak resident set size; the report and dump paths with the command line's allocator
(pyarrow on the C library's malloc: engine.allocator), `--tables` with pyarrow's own, as a notebook has.

Kinds:
  ip       IPv4 fragments with More Fragments set, never completed: new datagram ids, and floods of
           pieces for one id (consistent where they overlap)
  cl       CL-RPC request fragments (1,384-byte bodies) that never get their last fragment: new
           activity/sequence number sets, and sets flooded with fragment numbers
  calls    PNIO Write requests of PROFIdrive change requests (39 parameters each) on ever new channels,
           and Read requests, never answered
  txns     half-finished PROFIdrive transactions on ever new channels: the write request answered OK, then
           0-3 reads answered B5 (not ready), then nothing more on that channel
  changes40  PROFIdrive change requests of 40 parameters (one over the profile's 39: P2, and 404 bytes:
           H13) on ever new channels, never answered
  mixed    ip, cl and calls interleaved

`write_pcap(kind, count, path)` writes a flood as a pcap file, for the command line (benchmarks/bench.py).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import struct
import subprocess
import sys
import time
import uuid
from collections import Counter
from collections.abc import Iterator

from pd_analyze.capture import RawFrame

KINDS = ("ip", "cl", "calls", "mixed")  # the memory bounds' floods (tests/test_columnar.py runs each)
TRANSACTION_KINDS = ("txns", "changes40")  # issue #23's transaction floods (tests/test_floods.py)
ALL_KINDS = KINDS + TRANSACTION_KINDS
LIMIT_MB = 300  # the peak RSS a flood may take in one process (issue #23: 300 MiB)
_EPOCH = 1_767_225_600.0


def _templates() -> dict[str, bytes]:
    """One frame per kind, from the sample generator (Ethernet, no VLAN: IPv4 at 14, RPC at 42)."""
    from devtools.synth import net_encode, pnio_encode, rpc_encode
    from devtools.synth.pd_encode import ParamAddress, change_request, value_block
    from devtools.synth.pnio_session import PnioSession
    from devtools.synth.sim_capture import Capture, host

    cap = Capture()
    ctrl, dev = host("02:00:00:00:01:01", "192.168.1.11"), host("02:00:00:00:02:01", "192.168.1.21")
    s = PnioSession(cap, ctrl, dev, activity=uuid.UUID(int=1), ar_uuid=uuid.UUID(int=2))
    items = [(ParamAddress(1000 + i), value_block(0x06, [i])) for i in range(39)]
    write_req, _ = s.write_stubs(0xB02E, change_request(1, 1, items))
    read_req, _, _ = s.read_stubs(0xB02E)
    big_req, _ = s.write_stubs(0x1000, bytes(4000))
    out = {}
    s.send(s.pdu(rpc_encode.REQUEST, write_req, seq=1, opnum=3, from_client=True), from_client=True)
    out["write"] = cap.frames[-1].data
    s.send(s.pdu(rpc_encode.REQUEST, read_req, seq=2, opnum=2, from_client=True), from_client=True)
    out["read"] = cap.frames[-1].data
    first = s.pdus(rpc_encode.REQUEST, big_req, seq=3, opnum=3, from_client=True)[0]  # Flags1 0x24: not the last
    s.send(first, from_client=True)
    out["cl"] = cap.frames[-1].data
    payload = net_encode.udp(49152, 34964, bytes(2900), src_ip=ctrl.ip, dst_ip=dev.ip)
    out["ip"] = cap.send_ip(ctrl, dev, payload)[0].data  # the first IP fragment: MF set, offset 0
    items = [(ParamAddress(1000 + i), value_block(0x06, [i])) for i in range(40)]
    write40, _ = s.write_stubs(0xB02E, change_request(1, 1, items))
    half_req, half_res = s.write_stubs(0xB02E, change_request(1, 1, [(ParamAddress(1120), value_block(0x08, [1.0]))]))
    b5_req, b5_res, _ = s.read_stubs(0xB02E, status=pnio_encode.STATUS_B5)
    for name, stub, opnum, client in (("write40", write40, 3, True), ("half_write", half_req, 3, True),
                                      ("half_write_res", half_res, 3, False), ("half_read", b5_req, 2, True),
                                      ("half_b5", b5_res, 2, False)):
        ptype = rpc_encode.REQUEST if client else rpc_encode.RESPONSE
        s.send(s.pdu(ptype, stub, seq=1, opnum=opnum, from_client=client), from_client=client)
        out[name] = cap.frames[-1].data
    return out


_IP_ID, _IP_FRAG = 14 + 4, 14 + 6
_ACTIVITY, _SEQ, _FRAG_NUM = 42 + 40, 42 + 64, 42 + 76
_SLOT, _SUBSLOT = 42 + 80 + 20 + 28, 42 + 80 + 20 + 30


def _half_finished(t: dict[str, bytes], rng: random.Random) -> Iterator[bytearray]:
    """Transactions left half-finished, each on a new channel: the write request and its OK answer, then 0-3
    reads answered B5 (the drive not ready), then nothing more; a new activity every 50 channels."""
    channel = seq = 0
    while True:
        channel += 1
        script = ["half_write", "half_write_res"] + ["half_read", "half_b5"] * rng.choice((0, 1, 2, 3))
        for k, name in enumerate(script):
            seq += k % 2 == 0  # a request and its answer share the call's sequence number
            data = bytearray(t[name])
            struct.pack_into("<IH", data, _ACTIVITY, 0x10000 + channel // 50, 0xBEEF)
            struct.pack_into("<I", data, _SEQ, seq)
            if name != "half_b5":  # (a B5 answer carries no IOD header)
                struct.pack_into(">HH", data, _SLOT, channel & 0xFFFF, (channel >> 16) & 0xFFFF)
            yield data


def frames(kind: str, count: int, seed: int = 1) -> Iterator[RawFrame]:
    """`count` hostile frames of one kind, numbered from 1, one microsecond apart."""
    t = _templates()
    rng = random.Random(f"pd-analyze hostile {kind} {seed}")
    kinds = ("ip", "cl", "calls") if kind == "mixed" else (kind,)
    half = _half_finished(t, rng)
    ip_id = 0
    activity = 0
    seq = 0
    for n in range(1, count + 1):
        what = kinds[n % len(kinds)]
        if what == "txns":
            data = next(half)
        elif what == "changes40":
            seq += 1
            data = bytearray(t["write40"])
            struct.pack_into("<IH", data, _ACTIVITY, 0x20000 + seq // 50, 0xCAFE)
            struct.pack_into("<I", data, _SEQ, seq)
            struct.pack_into(">HH", data, _SLOT, seq & 0xFFFF, (seq >> 16) & 0xFFFF)  # a new channel each time
        elif what == "ip":
            data = bytearray(t["ip"])
            if n % 1000 < 200:  # a flood of pieces for one datagram (same bytes where they overlap)
                struct.pack_into(">HH", data, _IP_ID, 0xF00D, 0x2000 | rng.randrange(0x2000))
                data[34:] = bytes(len(data) - 34)
            else:
                ip_id += 1
                struct.pack_into(">H", data, _IP_ID, ip_id & 0xFFFF)
                struct.pack_into(">I", data, 14 + 12, 0x0A000000 | (ip_id >> 16))  # a new source per 65,536 ids
        elif what == "cl":
            data = bytearray(t["cl"])
            if n % 1000 < 200:  # one set flooded with fragment numbers
                data[_ACTIVITY:_ACTIVITY + 16] = b"\xf1" * 16
                struct.pack_into("<I", data, _SEQ, 7)
                struct.pack_into("<H", data, _FRAG_NUM, rng.randrange(65536))
            else:
                seq += 1
                struct.pack_into("<IH", data, _ACTIVITY, seq >> 16, seq & 0xFFFF)
                struct.pack_into("<I", data, _SEQ, seq)
                struct.pack_into("<H", data, _FRAG_NUM, rng.randrange(8))
            data[42 + 7], data[42 + 79] = data[_FRAG_NUM + 1], data[_FRAG_NUM]  # serial = fragment number
        else:
            seq += 1
            data = bytearray(t["write"] if n % 4 else t["read"])
            if seq % 50 == 0:
                activity += 1
            struct.pack_into("<IH", data, _ACTIVITY, activity, 0xABCD)
            struct.pack_into("<I", data, _SEQ, seq)
            struct.pack_into(">HH", data, _SLOT, seq & 0xFFFF, (seq >> 16) & 0xFFFF)  # a new channel each time
        yield RawFrame(n, _EPOCH + n * 1e-6, 1, bytes(data))


def write_pcap(kind: str, count: int, path: str | os.PathLike[str], seed: int = 1) -> int:
    """The flood as a microsecond pcap file; returns the frames written."""
    with open(path, "wb") as f:
        f.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, 1))
        for raw in frames(kind, count, seed):
            sec = int(raw.ts)
            f.write(struct.pack("<IIII", sec, round((raw.ts - sec) * 1e6), len(raw.data), len(raw.data)))
            f.write(raw.data)
    return count


def peak_rss_mb() -> float:
    """Peak resident set size of this process in MB: VmHWM on Linux (getrusage's ru_maxrss survives exec,
    so a child started by a big process would report its parent's peak), else ru_maxrss."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run(kind: str, count: int, dump: bool = False, seed: int = 1, tables: bool = False) -> dict[str, object]:
    """Stream one kind through the report path (or the dump path); what happened and the peak RSS.

    The report path hands its tables and findings on (counted here, as a streaming consumer would); with
    `tables` they are kept and made DataFrames at the end, as `analyze()` does: that memory grows with the
    transactions and findings, which are the analysis's data.
    """
    from pd_analyze.analysis.capture_run import Settings
    from pd_analyze.analysis.engine.run import analyze_frames
    from pd_analyze.output import dump as dump_mod
    from pd_analyze.protocol.dissector import Dissector

    started = time.perf_counter()
    findings: Counter[str] = Counter()
    evicted: Counter[str] = Counter()  # items the caps dropped (a summary finding counts those not listed)

    def tally(name: str, value: object, message: str) -> None:
        findings[name] += 1
        if name.endswith("_evicted"):
            evicted[name] += int(str(value)) - 100 if " in all; " in message else 1

    if dump:
        d = Dissector(annotate=True)
        for raw in frames(kind, count, seed):
            for res in d.feed(raw):
                dump_mod.frame_text(res)
                for f in res.findings:
                    tally(f.name, f.value, f.message)
        for res in d.finish():
            for f in res.findings:
                tally(f.name, f.value, f.message)
        for f in d.loose_findings:
            tally(f.name, f.value, f.message)
        acc, transactions = d.accounting, 0
    else:
        sink = _Tally(tally, keep=tables)
        acc = analyze_frames(frames(kind, count, seed), Settings(), sink, kind).accounting
        transactions = sink.count
        if tables:
            from pd_analyze.analysis.schema import COLUMNS, frame_of
            from pd_analyze.analysis.table_batches import frame_from_batches

            for name in COLUMNS:
                frame_of(name, getattr(sink, name))
                frame_from_batches(name, sink.tables.get(name, []))
    return {
        "kind": kind, "path": "dump" if dump else "tables" if tables else "report", "frames": acc.read,
        "decoded": acc.decoded,
        "skipped": sum(acc.skipped.values()), "malformed": sum(acc.malformed.values()),
        "balanced": acc.balanced(), "transactions": transactions,
        "evictions": dict(sorted(evicted.items())),
        "findings": sum(findings.values()), "peak_rss_mb": round(peak_rss_mb(), 1),
        "seconds": round(time.perf_counter() - started, 1),
    }


def _tally_sink():  # noqa: ANN202 (a Rows subclass, made when pd_analyze is imported)
    from pd_analyze.analysis.rows import Rows

    class Tally(Rows):
        """The engine's rows counted (findings tallied by name) and, with `keep`, kept as analyze() keeps them."""

        def __init__(self, tally, keep: bool) -> None:  # noqa: ANN001
            super().__init__()
            self.tally, self.keep, self.count = tally, keep, 0

        def add_table(self, name: str, table: object) -> None:
            if name == "transactions":
                self.count += table.num_rows  # type: ignore[attr-defined]
            elif name == "findings":
                for n, v, m in zip(*(table.column(c).to_pylist() for c in ("name", "value", "message")),  # type: ignore[attr-defined]
                                   strict=True):
                    self.tally(n, v, m)
            if self.keep:
                super().add_table(name, table)

        def add_finding(self, capture: str, f, txn: int | None = None) -> None:  # noqa: ANN001
            self.tally(f.name, f.value, f.message)
            if self.keep:
                super().add_finding(capture, f, txn)

    return Tally


def _Tally(tally, keep: bool):  # noqa: ANN001, ANN202, N802
    return _tally_sink()(tally, keep)


def run_isolated(kind: str, count: int, dump: bool = False, seed: int = 1, tables: bool = False) -> dict[str, object]:
    """`run` in a fresh interpreter, so the peak RSS is this capture's alone."""
    cmd = [sys.executable, "-m", "devtools.hostile", "--kind", kind, "--frames", str(count), "--seed", str(seed),
           "--json", "--inline"] + (["--dump"] if dump else []) + (["--tables"] if tables else [])
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    if out.returncode not in (0, 1) or not out.stdout.strip():  # (1: over LIMIT_MB, which the result says)
        raise RuntimeError(f"{' '.join(cmd)} failed ({out.returncode}): {out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m devtools.hostile", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog="\n\n".join(
                                         __doc__.split("\n\n")[2:]))
    parser.add_argument("--kind", choices=(*ALL_KINDS, "all"), default="all")
    parser.add_argument("--frames", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--dump", action="store_true", help="the dump path (annotated) instead of the report path")
    parser.add_argument("--tables", action="store_true", help="keep the table rows and build the DataFrames, "
                                                              "as analyze() does")
    parser.add_argument("--json", action="store_true", help="one JSON object per kind")
    parser.add_argument("--inline", action="store_true", help=argparse.SUPPRESS)  # run here, not in a child
    args = parser.parse_args(argv)
    kinds = ALL_KINDS if args.kind == "all" else (args.kind,)
    if not args.tables:  # the command line's allocator (cli.base); analyze() leaves a notebook's as it is
        from pd_analyze.analysis.engine.allocator import prefer_system_pool

        prefer_system_pool()
    worst = 0.0
    if not args.json:
        print(f"{'kind':<7} {'path':<7} {'frames':>10} {'balanced':>9} {'peak RSS':>9} {'time':>7}  caps hit")
    for kind in kinds:
        result = (run(kind, args.frames, args.dump, args.seed, args.tables) if args.inline
                  else run_isolated(kind, args.frames, args.dump, args.seed, args.tables))
        worst = max(worst, float(result["peak_rss_mb"]))  # type: ignore[arg-type]
        if args.json:
            print(json.dumps(result))
        else:
            caps = ", ".join(f"{k} {v:,}" for k, v in result["evictions"].items()) or "-"  # type: ignore[union-attr]
            print(f"{kind:<7} {result['path']:<7} {result['frames']:>10,} {result['balanced']!s:>9} "
                  f"{result['peak_rss_mb']:>6.0f} MB {result['seconds']:>6}s  {caps}")
    return 0 if worst < LIMIT_MB else 1


if __name__ == "__main__":
    raise SystemExit(main())

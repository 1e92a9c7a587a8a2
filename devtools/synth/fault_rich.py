"""A commissioning capture rich in faults, and its truth: what protocol.md 6 and 7 say the analyser must report.

    python -m devtools.synth.fault_rich OUT.pcap --frames 1000000 [--seed 1] [--truth OUT.json]

Every frame is PNIO RPC: two controllers (each with an AR to every drive) change and read the parameters of
four drives, about 4.3 frames a transaction, with the faults a real commissioning capture has on every drive
(the shares are `Shape`'s, after issue #23): half the frames priority-tagged (802.1Q, VID 0) at random, 8 %
of transactions NAKed, 2 % PNIO record errors (DF80B0/B1/B2/B6/B8/C3), 1 % each timeouts, response reference
mismatches, reused request references and duplicated frames (a mirror-port copy or an RPC retransmission),
2 % with a header field out of range (reference 0, 0 or 40 parameters, an attribute not 0x10/0x20/0x30,
more than 234 elements), 0.5 % each a frame cut by the snaplen and a structurally broken request, 10 %
polled with B5 (5 % of those exhausted: every read answered B5 until the controller gives up, DE80B500),
10 % on index 0xB02F; and multi-parameter reads and changes, changes read back, Write-Multiple, and now and
then a CL- or IP-fragmented PDU. Each (controller, drive) pair is an actor on its own clock
(fault_actor); their frames are merged by time and written as they are made (memory stays bounded: only
the actors' current transactions and the channels' pending ones are held), in a nanosecond pcap.

With `truth` the transactions' truth (fault_truth) is returned and, with `truth_path`, written beside the
capture as JSON: per transaction, numbered 1, 2, ... in the order of its write request frame, the verdict
(protocol.md 7.4), b5_retries, reads, pnio_status, the error numbers per parameter of a NAK, its frames and
the findings it must raise at which frames.
"""

from __future__ import annotations

import argparse
import heapq
import json
import random
import struct
import sys
from collections import Counter
from collections.abc import Iterator
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import IO, Any, Final

from . import fault_kinds as fk
from .capture_files import PCAP_MAGIC_NS
from .fault_actor import MS, Actor
from .fault_truth import Channels, Slot, Txn, ambiguous_end
from .fixtures import fixed_uuid
from .net_encode import LINKTYPE_ETHERNET, VlanTag
from .pnio_session import PnioSession
from .rpc_encode import DREP_BE, DREP_LE, pnio_object_uuid
from .sim_capture import EPOCH_NS, Capture, Clock, host


@dataclass(frozen=True)
class Shape:
    """The plant and the shares of its faults (per transaction unless said otherwise)."""

    controllers: int = 2
    drives: int = 4
    nak: float = 0.08
    record_error: float = 0.02
    timeout: float = 0.01
    reference_mismatch: float = 0.01
    out_of_range: float = 0.02
    snaplen_cut: float = 0.005
    broken_request: float = 0.005
    b5_polling: float = 0.10
    b5_exhausted: float = 0.05  # of the transactions polled with B5
    reused_reference: float = 0.01
    retry_same_reference: float = 0.5  # of the writes after a failure on the channel (T4)
    duplicate: float = 0.01
    global_index: float = 0.10  # on 0xB02F
    vlan_tagged: float = 0.5  # of the frames
    fragmented: float = 0.005  # a CL- or IP-fragmented PDU
    write_multiple: float = 0.01
    read_back: float = 0.5  # of the successful changes

    def faults(self) -> list[tuple[str, float]]:
        """The faults that decide a transaction's verdict, with their shares (exclusive)."""
        return [("nak", self.nak), ("record_error", self.record_error), ("timeout", self.timeout),
                ("reference_mismatch", self.reference_mismatch), ("out_of_range", self.out_of_range),
                ("snaplen_cut", self.snaplen_cut), ("broken_request", self.broken_request),
                ("b5_exhausted", self.b5_polling * self.b5_exhausted)]


# Every kind and variant once at the start of the capture, spread over the actors (entry k to actor k modulo
# their number), each actor making its share before it stops: a capture of a few thousand frames holds each
# of them (the tests rely on it), a large one does not notice. The transactions left to their deadline come
# last: their actors idle until the deadline has passed while the others go on, then write again.
_GIVEN_UP: Final = (*(f"timeout/{v}" for v in ("write", "no_read", "read", "read_after_b5")),
                    *(f"b5_exhausted/{v}" for v in ("short", "long")))
PROLOGUE: Final = (
    *(f"{k}/supersede" for k in _GIVEN_UP),
    *(f"nak/{v}" for v in ("read", "change", "whole")), *(f"record_error/{v}" for v in ("write", "read")),
    "reference_mismatch", *(f"out_of_range/{v}" for v in fk.OUT_OF_RANGE),
    *(f"snaplen_cut/{v}" for v in ("write_header", "write_record", "answer")),
    *(f"broken_request/{v}" for v in fk.BROKEN),
    *(f"fragmented/{v}" for v in ("cl_write", "cl_answer", "ip_write", "ip_answer")),
    "write_multiple", "normal/mirror", "normal/retransmit", "normal/reuse", "normal/mirror", "normal/retransmit",
    *(f"{k}/deadline" for k in _GIVEN_UP),
)  # fmt: skip
VLAN_TAG: Final = VlanTag(0).encode()  # priority tag: 802.1Q, VID 0, PCP 0


def plant(shape: Shape, seed: int, channels: Channels) -> list[Actor]:
    """One actor per (controller, drive): controllers 192.168.10.1.., drives 192.168.10.101..; the third
    drive of every four speaks big-endian DCE/RPC."""
    ctrls = [host(f"02:00:00:0a:01:{c:02x}", f"192.168.10.{1 + c}", 0x2000 * c) for c in range(shape.controllers)]
    devs = [host(f"02:00:00:0a:02:{d:02x}", f"192.168.10.{101 + d}", 0x2000 * d + 0x1000)
            for d in range(shape.drives)]
    drives = [fk.Drive(seed * 1000 + d) for d in range(shape.drives)]
    actors = []
    for c, ctrl in enumerate(ctrls):
        for d, dev in enumerate(devs):
            n = c * shape.drives + d
            s = PnioSession(Capture(clock=Clock(EPOCH_NS + n * 911_000)), ctrl, dev,
                            activity=fixed_uuid(0xAC, 0x100 + n), ar_uuid=fixed_uuid(0xA2, 0x100 + n),
                            object_uuid=pnio_object_uuid(1, 0x0100 + d, 0x002A if d % 2 == 0 else 0x011E),
                            controller_port=49152 + n, drep=DREP_BE if d % 4 == 2 else DREP_LE,
                            rtt_us=600 + 250 * (d % 4), jitter_us=900, gap_us=300,
                            rng=random.Random(f"fault-rich rtt {seed} {n}"))
            actors.append(Actor(s, drives[d], shape, channels, random.Random(f"fault-rich {seed} {n}")))
    for k, kind in enumerate(PROLOGUE):
        actors[k % len(actors)].prologue.append(kind)
    return actors


class _Pcap:
    """Slots into a nanosecond pcap, numbered as written; each frame priority-tagged at random."""

    def __init__(self, out: IO[bytes], tagged: float, rng: random.Random) -> None:
        self.out, self.tagged, self.rng = out, tagged, rng
        out.write(struct.pack("<IHHiIII", PCAP_MAGIC_NS, 2, 4, 0, 0, 262144, LINKTYPE_ETHERNET))
        self.frames = 0
        self.txns = 0
        self.last_ts = 0

    def write(self, slot: Slot) -> None:
        data, wire, cut = slot.data or b"", slot.wire_len, slot.cut
        if self.rng.random() < self.tagged:
            data, wire = data[:12] + VLAN_TAG + data[12:], wire + 4
            cut = None if cut is None else cut + 4
        if cut is not None:
            data = data[:cut]
        sec, ns = divmod(slot.ts_ns, 1_000_000_000)
        self.out.write(struct.pack("<IIII", sec, ns, len(data), wire) + data)
        self.frames += 1
        slot.number, slot.data, self.last_ts = self.frames, None, slot.ts_ns
        for txn in slot.opens:  # numbered in the order of their write request frame (and in it)
            self.txns += 1
            txn.number = self.txns


def _kind(actor: Actor, shape: Shape) -> str:
    r = actor.rng.random()
    for name, share in shape.faults():
        if r < share:
            return name
        r -= share
    return "normal"


def _merged(actors: list[Actor], shape: Shape, frames: int, made: list[int]) -> Iterator[Slot]:
    """The actors' frames in time order (ties by actor), each actor making its next transaction when its
    queue runs dry, until `frames` frames have been made and every actor has made its prologue and the write
    it owes a channel (after giving up on a transaction, or to read a change back)."""
    heap = []
    for i, a in enumerate(actors):
        a.step(_kind(a, shape))
        made[0] += len(a.out)
        heap.append((a.out[0].ts_ns, i))
    heapq.heapify(heap)
    while heap:
        _, i = heapq.heappop(heap)
        a = actors[i]
        yield a.out.popleft()
        if not a.out and (made[0] < frames or a.prologue or a.owes_write):
            a.step(_kind(a, shape))
            made[0] += len(a.out)
        if a.out:
            heapq.heappush(heap, (a.out[0].ts_ns, i))


def make_fault_rich(path: Path | str, frames: int = 1_000_000, *, seed: int = 1, shape: Shape = Shape(),
                    truth: bool = True, truth_path: Path | str | None = None) -> dict[str, Any]:
    """Write a fault-rich capture of about `frames` frames to `path`; return its summary and, with `truth`,
    its truth (see the module's docstring), also written to `truth_path` when given."""
    channels = Channels()
    actors = plant(shape, seed, channels)
    kept: list[Txn] = []
    verdicts: Counter[str] = Counter()
    kinds: Counter[str] = Counter()

    def drain() -> None:
        for txn in channels.closed:
            verdicts[txn.verdict] += 1
            kinds[txn.kind] += 1
            if truth:
                kept.append(txn)
        channels.closed.clear()

    with Path(path).open("wb") as out:
        pcap = _Pcap(out, shape.vlan_tagged, random.Random(f"fault-rich vlan {seed}"))
        made = [0]
        for slot in _merged(actors, shape, frames, made):
            pcap.write(slot)
            if len(channels.closed) > 4096:
                drain()
        a = actors[0]
        while ambiguous_end(channels.open(), pcap.last_ts):  # a deadline on the last frame: one more
            a.s.clock.now_ns = max(a.s.clock.now_ns, pcap.last_ts + 3 * MS)
            a.step("normal")
            while a.out:
                pcap.write(a.out.popleft())
        channels.finish(pcap.last_ts)
        drain()
    summary: dict[str, Any] = {
        "generator": "devtools.synth.fault_rich", "seed": seed, "frames": pcap.frames,
        "transactions_count": pcap.txns, "txn_timeout_s": 10.0, "shape": asdict(shape),
        "verdicts": dict(sorted(verdicts.items())), "kinds": dict(sorted(kinds.items())),
    }  # fmt: skip
    if truth:
        summary["transactions"] = [t.render() for t in sorted(kept, key=lambda t: t.number)]
        if truth_path is not None:
            Path(truth_path).write_text(dumps(summary))
    return summary


def dumps(truth: dict[str, Any]) -> str:
    """The truth as JSON, one transaction a line (diff-friendly)."""
    head = {k: v for k, v in truth.items() if k != "transactions"}
    lines = [json.dumps(head)[:-1] + ', "transactions": [']
    txns = [json.dumps(t) for t in truth.get("transactions", [])]
    lines += [t + ("," if k < len(txns) - 1 else "") for k, t in enumerate(txns)]
    return "\n".join(lines) + "\n]}\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m devtools.synth.fault_rich", description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m devtools.synth.fault_rich fr.pcap --frames 20000 "
                                        "--truth fr.json")
    ap.add_argument("out", type=Path, help="the capture to write (a nanosecond pcap)")
    ap.add_argument("--frames", type=int, default=1_000_000, help="about this many frames (default 1,000,000)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--truth", type=Path, metavar="JSON", help="also write the truth here")
    for f in fields(Shape):
        ap.add_argument(f"--{f.name.replace('_', '-')}", type=type(f.default), default=f.default,
                        help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    shape = Shape(**{f.name: getattr(args, f.name) for f in fields(Shape)})
    got = make_fault_rich(args.out, args.frames, seed=args.seed, shape=shape, truth=args.truth is not None,
                          truth_path=args.truth)
    print(f"{args.out}: {got['frames']:,} frames, {got['transactions_count']:,} transactions; "
          + ", ".join(f"{k} {v:,}" for k, v in got["verdicts"].items()), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

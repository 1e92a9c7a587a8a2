"""One controller's parameter access to one drive in a fault-rich capture: an RPC session on its own AR and
its own clock, making one transaction at a time of the kind it is given, and recording each one's truth
(fault_truth) as it makes it.

The frames of a transaction are queued in `out` as `Slot`s, in time order; fault_rich merges the queues of
every actor by time into one file. A transaction that gets no final answer stays pending on its channel;
the actor then waits, as a controller does, until it gives up and writes again on the channel (before the
10 s deadline: the old one is superseded) or until the deadline has passed.
"""

from __future__ import annotations

import random
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

from . import fault_kinds as fk
from .fault_truth import TXN_TIMEOUT_NS, Channels, Slot, Txn
from .pnio_encode import STATUS_B5, InnerWrite
from .pnio_session import PnioSession
from .rpc_encode import F1_NOFACK
from .rpc_session import Call
from .sim_capture import Capture, Medium

# Bytes before the IOD header of an untagged PNIO frame: Ethernet 14, IPv4 20, UDP 8, CL-RPC 80, NDR args 20
IOD_AT: Final = 14 + 20 + 8 + 80 + 20
RECORD_AT: Final = IOD_AT + 64
RECORD_ERRORS: Final = (0xB0, 0xB1, 0xB2, 0xB6, 0xB8, 0xC3)  # PNIORW ErrorCode1 of a refused record service
T5_THRESHOLD: Final = 50  # B5 answers above which T5 is raised (protocol.md 6.5, the analyser's default)
MS: Final = 1_000_000  # ns


def status_text(code: int, code1: int) -> str:
    return f"{code:02X}80{code1:02X}00"


@dataclass(frozen=True)
class Where:
    """A transaction's channel as the actor addresses it."""

    index: int
    slot: int
    do: int

    @property
    def axis(self) -> tuple[int, int]:
        return self.slot, self.do


class Actor:
    """Controller `s.controller` talking to drive `s.device` on one AR."""

    def __init__(self, s: PnioSession, drive: fk.Drive, shape: Any, channels: Channels, rng: random.Random,
                 prologue: Sequence[str] = ()) -> None:
        self.s, self.drive, self.shape, self.channels, self.rng = s, drive, shape, channels, rng
        self.out: deque[Slot] = deque()
        self.prologue = list(prologue)
        self._refs: dict[tuple, int] = {}  # the last reference written per channel
        self._failed: set[tuple] = set()  # channels whose last transaction the controller saw fail
        self._busy: set[tuple] = set()  # channels whose drive may still process a request given up
        self._readback: dict[tuple, tuple[Where, list[fk.Address]]] = {}
        self._next: Where | None = None  # the channel the next transaction must use
        self._slots: list[Slot] = []  # the frames of the transaction being made
        self._by_frame: dict[int, Slot] = {}

    @property
    def owes_write(self) -> bool:
        """A channel waits for this actor's next write: a transaction given up, a change to read back."""
        return self._next is not None

    @property
    def cap(self) -> Capture:
        return self.s.cap

    def channel(self, w: Where) -> tuple:
        s = self.s
        return s.device.ip, s.controller.ip, str(s.ar_uuid), s.api, w.slot, 1, w.index

    # --- choosing what comes next ---------------------------------------------------------------------------
    def step(self, kind: str) -> None:
        """Make one transaction (two for a Write-Multiple) of `kind` ("normal" or a fault of the shape),
        after the controller's think time; its frames are queued in `out`."""
        planned = self.prologue.pop(0) if self.prologue else ""
        kind, *variant = (planned or kind).split("/")  # e.g. "timeout/write/deadline": the variant, else drawn
        self.s.clock.advance_us(self.rng.uniform(500, 25_000))
        w = self._next or self._where()
        self._next = None
        ch = self.channel(w)
        if ch in self._busy:
            self._busy.discard(ch)
            if self.rng.random() < 0.5:  # the drive still processes the request given up (protocol.md 7.1)
                if planned:
                    self.prologue.insert(0, planned)  # made next time
                kind, variant = "busy_write", []
        if kind == "normal" and ch in self._readback:
            kind = "read_back"
        elif kind == "normal" and w.index == 0xB02E and self.rng.random() < self.shape.write_multiple:
            kind = "write_multiple"
        elif kind == "normal" and self.rng.random() < self.shape.fragmented:
            kind = "fragmented"
        getattr(self, "_" + kind)(w, variant)
        self.out.extend(self._slots)
        self._slots, self._by_frame = [], {}

    def _pick(self, variant: Sequence[str], k: int, choices: Sequence[str]) -> str:
        return variant[k] if len(variant) > k else self.rng.choice(choices)

    def _where(self) -> Where:
        if self.rng.random() < self.shape.global_index:
            return Where(0xB02F, 1, self.rng.randint(1, 3))  # global access: the DO-ID selects the drive object
        return Where(0xB02E, 1, 1)

    def _ref(self, ch: tuple, reuse: bool = False) -> int:
        """The controller's next Request Reference on the channel: a new one, the same again after a failure
        (a retry, T4) or, rarely, by mistake (T1)."""
        last = self._refs.get(ch)
        retry = ch in self._failed and self.rng.random() < self.shape.retry_same_reference
        self._failed.discard(ch)
        if last is not None and (reuse or retry or self.rng.random() < self.shape.reused_reference):
            return last
        ref = (last or 0) % 255 + 1
        self._refs[ch] = ref
        return ref

    # --- frames -------------------------------------------------------------------------------------------------
    def _frames(self, call: Call) -> tuple[list[Slot], list[Slot]]:
        """The call's request and response frames as slots (new frames of the capture become slots)."""
        for f in self.cap.frames:
            slot = Slot(f.ts_ns or 0, f.data)
            self._by_frame[id(f)] = slot
            self._slots.append(slot)
        self.cap.frames.clear()
        return [self._by_frame[id(f)] for f in call.request], [self._by_frame[id(f)] for f in call.response]

    def _mirror(self, slot: Slot) -> Slot:
        """A copy of the frame from a mirror port, a few microseconds later."""
        copy = Slot(slot.ts_ns + self.rng.randint(1_000, 40_000), slot.data or b"")
        self._slots.insert(self._slots.index(slot) + 1, copy)
        return copy

    def _own(self, txns: Sequence[Txn], req: list[Slot], res: list[Slot]) -> None:
        for txn in txns:
            txn.frames += req + res

    def _duplicate(self, txns: Sequence[Txn], calls: Sequence[tuple[list[Slot], list[Slot]]],
                   force: bool = False) -> None:
        """With the shape's rate, one frame of the transaction again: a mirror-port copy (a request copy is a
        retransmission of its call; every copy raises R7)."""
        single = [(s, k == 0) for req, res in calls for k, part in enumerate((req, res)) if len(part) == 1
                  for s in part if s.cut is None]
        if not single or (not force and self.rng.random() >= self.shape.duplicate * 0.7):  # 0.3: retransmissions
            return
        slot, request = self.rng.choice(single)
        copy = self._mirror(slot)
        for txn in txns:
            txn.frames.append(copy)
            txn.on(copy, "rpc_retransmission")
            txn.rpc_retransmissions += request

    # --- the write ------------------------------------------------------------------------------------------
    def _before_write(self, chs: Sequence[tuple]) -> None:
        """Keep a write clear of a pending transaction's deadline by a millisecond or more: on the deadline
        itself the analyser's clock resolution decides whether it supersedes."""
        for ch in chs:
            old = self.channels.pending(ch)
            if old is not None and abs(self.s.clock.now_ns - old.deadline_ns) < 2 * MS:
                self.s.clock.now_ns = old.deadline_ns + 3 * MS

    def _write(self, kind: str, w: Where, ref: int | None, request: bytes, *, status: bytes | None = None,
               respond: bool = True, **kw: Any) -> tuple[Txn, list[Slot], list[Slot]]:
        ch = self.channel(w)
        self._before_write([ch])
        call = self.s.write(w.index, request, respond=respond, slot=w.slot, **({"status": status} if status else {}),
                            **kw)
        req, res = self._frames(call)
        txn = Txn(kind, ch, ref, req[0], req[len(req) // (call.retransmits + 1) - 1])
        req[0].opens.append(txn)
        self._own([txn], req, res)
        self.channels.write(txn)
        if res:
            txn.write_res = res[-1]
        if call.retransmits:
            txn.rpc_retransmissions += call.retransmits
            for copy in req[len(req) // (call.retransmits + 1):]:
                txn.on(copy, "rpc_retransmission")
        return txn, req, res

    def _reads(self, txn: Txn, w: Where, b5: int, gap_ms: float | None = None) -> list[tuple[list[Slot], list[Slot]]]:
        """`b5` reads answered DE 80 B5 00 (not ready), `gap_ms` apart (default: a few ms)."""
        out = []
        for _ in range(b5):
            gap = (gap_ms if gap_ms is not None else self.rng.uniform(2, 10)) * 1000
            req, res = self._frames(self.s.read(w.index, status=STATUS_B5, slot=w.slot, gap_us=gap))
            self._own([txn], req, res)
            txn.reads += 1
            txn.b5_retries += 1
            if txn.b5_retries == T5_THRESHOLD + 1:
                txn.on(res[-1], "b5_polling")
            out.append((req, res))
        return out

    def _b5_count(self) -> int:
        if self.rng.random() >= self.shape.b5_polling:
            return 0
        return self.rng.choice((1, 1, 1, 1, 2, 2, 3, 4))

    def _final(self, txn: Txn, w: Where, answer: bytes | None, *, status: bytes | None = None,
               respond: bool = True, **kw: Any) -> tuple[list[Slot], list[Slot]]:
        call = self.s.read(w.index, answer, slot=w.slot, respond=respond, **({"status": status} if status else {}),
                           **kw)
        req, res = self._frames(call)
        self._own([txn], req, res)
        txn.reads += 1
        if call.retransmits:
            txn.rpc_retransmissions += call.retransmits
            txn.on(req[-1], "rpc_retransmission")
        return req, res

    def _close(self, txn: Txn) -> None:
        self.channels.ended(txn)

    # --- answered transactions ------------------------------------------------------------------------------
    def _answered(self, kind: str, w: Where, ref: int, request: bytes, answer: bytes, response: str,
                  rows: list | None = None, *, cut: str = "", fragment: str = "", dup: str = "") -> Txn:
        """Write, B5 polls, final read answered with a parameter response ("ok", "nak" or "mismatch")."""
        wkw: dict[str, Any] = {}
        rkw: dict[str, Any] = {}
        chance = self.shape.duplicate * 0.3  # (0.7: mirror copies, _duplicate)
        retransmit = dup == "retransmit" or (not (cut or fragment or dup) and self.rng.random() < chance)
        if retransmit:
            (wkw if self.rng.random() < 0.5 else rkw)["retransmit_after_us"] = [self.rng.uniform(50_000, 400_000)]
        if fragment == "cl_write":
            wkw["req_rpc"] = {"max_body": self.rng.choice((48, 64, 100, 120))}
        elif fragment == "cl_answer":
            rkw["res_rpc"] = {"max_body": self.rng.choice((48, 64, 100)), "flags1": F1_NOFACK}
        small = Medium(mtu=self.rng.choice((120, 150, 180)))  # IP fragments: the call's both PDUs
        if fragment == "ip_write":
            self.s.medium = small
        if cut == "write_header":  # a slow answer: other controllers' writes come before it
            wkw["rtt_us"] = self.rng.uniform(5_000, 30_000)
        txn, wreq, wres = self._write(kind, w, ref if cut != "write_header" else None, request, **wkw)
        if fragment == "ip_write":
            self.s.medium = None
        if cut == "write_header":  # cut inside the IOD header, before its Index: opened by its response
            self._cut(txn, wreq[0], IOD_AT + self.rng.randrange(8, 34), "iod_truncated")
        elif cut == "write_record":  # cut inside the record, after its header (the reference is known)
            self._cut(txn, wreq[0], RECORD_AT + self.rng.randrange(4, len(request)), "record_truncated")
        polls = self._reads(txn, w, self._b5_count())
        if fragment == "ip_answer":
            self.s.medium = small
        req, res = self._final(txn, w, answer, **rkw)
        self.s.medium = None
        if cut == "answer":
            self._cut(txn, res[-1], RECORD_AT + self.rng.randrange(1, len(answer)), "record_truncated")
        if response == "mismatch":
            txn.on(res[-1], "reference_mismatch")
        txn.errors = (rows or []) if response == "nak" else []
        txn.answered(res[-1], response)
        self._close(txn)
        if not (retransmit or fragment or cut):
            self._duplicate([txn], [(wreq, wres), *polls, (req, res)], force=dup == "mirror")
        return txn

    def _cut(self, txn: Txn, slot: Slot, keep: int, rule: str) -> None:
        """The frame captured with its first `keep` bytes only (the snaplen): R1, L1 and `rule` at it."""
        slot.cut = keep
        txn.malformed_at = slot
        for r in ("rpc_truncated", "truncated_capture_pnio", rule):
            txn.on(slot, r)

    def _normal(self, w: Where, variant: Sequence[str] = (), *, kind: str = "normal", **kw: Any) -> Txn:
        ch = self.channel(w)
        ref = self._ref(ch, reuse="reuse" in variant)
        if "mirror" in variant or "retransmit" in variant:
            kw["dup"] = variant[0]
        r = self.rng.random()
        if r < 0.65:  # a read of one parameter, or of several (arrays included)
            addrs = fk.addresses(self.rng, 1 if r < 0.45 else self.rng.randint(2, 6))
            request, answer = fk.read_request(ref, w.do, addrs), fk.read_answer(self.drive, w.axis, ref, w.do, addrs)
            return self._answered(f"{kind}_read", w, ref, request, answer, "ok", **kw)
        addrs = fk.addresses(self.rng, 1 if r < 0.85 else self.rng.randint(2, 4), writable=True)
        request, new = fk.change(self.drive, w.axis, ref, w.do, addrs, self.rng)
        txn = self._answered(f"{kind}_change", w, ref, request, fk.change_answer(ref, w.do, len(addrs)), "ok", **kw)
        fk.apply(self.drive, w.axis, addrs, new)
        if self.rng.random() < self.shape.read_back:  # the commissioning engineer reads the change back
            self._readback[ch] = (w, addrs)
            self._next = w
        return txn

    def _read_back(self, w: Where, variant: Sequence[str] = ()) -> None:
        ch = self.channel(w)
        _, addrs = self._readback.pop(ch)
        ref = self._ref(ch)
        answer = fk.read_answer(self.drive, w.axis, ref, w.do, addrs)
        self._answered("read_back", w, ref, fk.read_request(ref, w.do, addrs), answer, "ok")

    def _fragmented(self, w: Where, variant: Sequence[str] = ()) -> None:
        how = self._pick(variant, 0, ("cl_write", "cl_answer", "ip_write", "ip_answer"))
        self._normal(w, kind=f"fragmented_{how}", fragment=how)

    def _nak(self, w: Where, variant: Sequence[str] = ()) -> None:
        ref = self._ref(self.channel(w))
        r = self.rng.random()
        how = variant[0] if variant else "read" if r < 0.45 else "change" if r < 0.85 else "whole"
        kind = f"nak_{how}"
        if how == "read":
            request, answer, rows = fk.nak_read(self.drive, w.axis, ref, w.do, self.rng)
        elif how == "change":
            request, answer, rows = fk.nak_change(self.drive, w.axis, ref, w.do, self.rng)
        else:
            request, answer, rows = fk.nak_whole(ref, w.do, self.rng)
        txn = self._answered(kind, w, ref, request, answer, "nak", rows)
        if kind == "nak_whole":
            txn.on(txn.final_res, "header_level_error")  # type: ignore[arg-type]

    def _reference_mismatch(self, w: Where, variant: Sequence[str] = ()) -> None:
        ref = self._ref(self.channel(w))
        addrs = fk.addresses(self.rng, self.rng.randint(1, 3))
        wrong = ref % 255 + 1
        answer = fk.read_answer(self.drive, w.axis, wrong, w.do, addrs)
        self._answered("reference_mismatch", w, ref, fk.read_request(ref, w.do, addrs), answer, "mismatch")

    def _out_of_range(self, w: Where, variant: Sequence[str] = ()) -> None:
        sub = self._pick(variant, 0, fk.OUT_OF_RANGE)
        ch = self.channel(w)
        ref = 0 if sub == "ref0" else self._ref(ch)
        request, answer, rows = fk.out_of_range(sub, self.drive, w.axis, ref, w.do, self.rng)
        if answer is None:  # 244 bytes: refused as a write longer than 240 bytes (protocol.md 3.6)
            txn = self._refused(f"out_of_range_{sub}", w, ref, request, status_text(0xDF, 0xB1))
            txn.on(txn.write_at, "pd_record_length")
        else:
            txn = self._answered(f"out_of_range_{sub}", w, ref, request, answer, "nak" if rows else "ok", rows)
        txn.on(txn.write_at, "pd_request_range")

    def _snaplen_cut(self, w: Where, variant: Sequence[str] = ()) -> None:
        cut = self._pick(variant, 0, ("write_header", "write_record", "answer"))
        last = self.channels.state(self.channel(w)).last
        if cut == "write_header" and last is not None and last.ref is None:
            cut = "write_record"  # two references unknown in a row would compare equal (T1/T4)
        self._normal(w, kind=f"snaplen_{cut}", cut=cut)

    # --- refused and broken requests ------------------------------------------------------------------------
    def _refused(self, kind: str, w: Where, ref: int, request: bytes, status: str, *, broken: str = "",
                 **kw: Any) -> Txn:
        """A write answered with an error PNIOStatus (a PNIO record error): no reads follow. `broken`: the
        request cannot be parsed, the finding of that name at its frame (malformed)."""
        txn, req, res = self._write(kind, w, ref, request, status=bytes.fromhex(status), **kw)
        if broken:
            txn.malformed_at = txn.write_at
            txn.on(txn.write_at, broken)
        txn.failed(res[-1], status)
        self._close(txn)
        self._failed.add(txn.channel)
        self._duplicate([txn], [(req, res)])
        return txn

    def _record_error(self, w: Where, variant: Sequence[str] = ()) -> None:
        ch = self.channel(w)
        ref = self._ref(ch)
        addrs = fk.addresses(self.rng, self.rng.randint(1, 3))
        request = fk.read_request(ref, w.do, addrs)
        code1 = self.rng.choice(RECORD_ERRORS)
        if self._pick(variant, 0, ("write", "write", "write", "read")) == "write":
            self._refused("record_error_write", w, ref, request, status_text(0xDF, code1))
            return
        txn, _, _ = self._write("record_error_read", w, ref, request)
        self._reads(txn, w, self._b5_count())
        status = status_text(0xDE, code1)
        _, res = self._final(txn, w, None, status=bytes.fromhex(status))
        txn.failed(res[-1], status)
        self._close(txn)
        self._failed.add(ch)

    def _busy_write(self, w: Where, variant: Sequence[str] = ()) -> None:
        """The write after a busy drive was given up, answered DF80B500: still processing (protocol.md 7.1)."""
        ref = self._ref(self.channel(w))
        request = fk.read_request(ref, w.do, fk.addresses(self.rng, 1))
        self._refused("busy_write", w, ref, request, status_text(0xDF, 0xB5))

    def _broken_request(self, w: Where, variant: Sequence[str] = ()) -> None:
        sub = self._pick(variant, 0, fk.BROKEN)
        ref = self._ref(self.channel(w))
        request, iod = fk.broken(sub, ref, w.do, self.rng)
        self._refused(f"broken_{sub}", w, ref, request, status_text(0xDF, 0xB7), broken=sub, req_iod=iod)

    # --- transactions left pending --------------------------------------------------------------------------
    def _timeout(self, w: Where, variant: Sequence[str] = ()) -> None:
        """No final answer: the write unanswered, never read, or a read unanswered (after B5 or not)."""
        ch = self.channel(w)
        ref = self._ref(ch)
        request = fk.read_request(ref, w.do, fk.addresses(self.rng, self.rng.randint(1, 3)))
        how = self._pick(variant, 0, ("write", "no_read", "read", "read_after_b5"))
        txn, _, _ = self._write(f"timeout_{how}", w, ref, request, respond=how != "write")
        if how in ("read", "read_after_b5"):
            self._reads(txn, w, self.rng.randint(1, 4) if how == "read_after_b5" else 0)
            self._final(txn, w, None, respond=False)
        self._give_up(txn, w, variant[1:])

    def _b5_exhausted(self, w: Where, variant: Sequence[str] = ()) -> None:
        """Every read answered B5 until the controller gives up (protocol.md 7.3 step 5): DE80B500."""
        ch = self.channel(w)
        ref = self._ref(ch)
        addrs = fk.addresses(self.rng, 1, writable=True)
        request, _ = fk.change(self.drive, w.axis, ref, w.do, addrs, self.rng)
        txn, _, _ = self._write("b5_exhausted", w, ref, request)
        long = self._pick(variant, 0, ("short",) * 9 + ("long",)) == "long"
        self._reads(txn, w, self.rng.randint(T5_THRESHOLD + 1, T5_THRESHOLD + 6) if long else self.rng.randint(1, 8))
        self._busy.add(ch)
        self._give_up(txn, w, variant[1:])

    def _give_up(self, txn: Txn, w: Where, variant: Sequence[str] = ()) -> None:
        """The controller waits, then writes on the channel again: before the deadline (the pending one is
        superseded) or after it."""
        self._failed.add(txn.channel)
        self._next = w
        if self._pick(variant, 0, ("supersede", "deadline")) == "supersede":
            wait = self.rng.uniform(0.3, 8.0) * 1e9
        else:
            wait = TXN_TIMEOUT_NS + self.rng.uniform(0.2, 1.5) * 1e9
        self.s.clock.now_ns = max(self.s.clock.now_ns, txn.write.ts_ns + round(wait))

    # --- Write-Multiple -----------------------------------------------------------------------------------------
    def _write_multiple(self, w: Where, variant: Sequence[str] = ()) -> None:
        """One Write-Multiple (0xE040) carrying a parameter request for each of two drive objects (slots 1 and
        2): two transactions opened by one frame, each then read on its own channel."""
        s = self.s
        where = [Where(0xB02E, 1, 1), Where(0xB02E, 2, 1)]
        chs = [self.channel(x) for x in where]
        self._before_write(chs)
        refs = [self._ref(ch) for ch in chs]
        plans = [fk.addresses(self.rng, self.rng.randint(1, 3)) for _ in where]
        inner = [InnerWrite(0xB02E, fk.read_request(ref, 1, addrs), s.next_iod_seq(), s.ar_uuid, s.api, x.slot, 1)
                 for x, ref, addrs in zip(where, refs, plans, strict=True)]
        req, res = self._frames(s.write_multiple(inner))
        txns = [Txn("write_multiple", ch, ref, req[0], req[-1]) for ch, ref in zip(chs, refs, strict=True)]
        for txn in txns:
            req[0].opens.append(txn)
            self._own([txn], req, res)
            self.channels.write(txn)
            txn.write_res = res[-1]
        for txn, x, ref, addrs in zip(txns, where, refs, plans, strict=True):
            self._reads(txn, x, self._b5_count())
            _, fres = self._final(txn, x, fk.read_answer(self.drive, x.axis, ref, 1, addrs))
            txn.answered(fres[-1], "ok")
            self._close(txn)


"""The truth of a fault-rich capture: what protocol.md 7 says the analyser must report for every transaction
the generator (fault_rich) makes, decided from what the generator put on the wire, never by the analyser.

A transaction is recorded while it is made (`Txn`): its frames, the answers its calls got, and the frames
where a finding must be raised. How a transaction without a final answer ends (protocol.md 7.3 steps 4-5) is
decided later, by the next write on its channel (`Channels.write`) or at the end of the capture
(`Channels.finish`); the verdict follows protocol.md 7.4, first matching rule wins. Frames are `Slot`s:
numbered only when written to the file, so the truth follows the frames wherever the merge of the sessions
puts them. A transaction is numbered and timed by the first frame of its write request (7.6); a finding on
a PDU is raised at the frame that completes it, where it is decoded (its last IP or CL fragment), as tshark
decodes a reassembled call on its completing frame (protocol.md 8.1).

The rule ids and names stated here are the protocol's (protocol.md 6); they are written out rather than
taken from pd_analyze's registry because the truth is the generator's own statement, which the tests hold
the analyser to (tests/test_fault_rich.py checks that the two registries agree).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Final

TXN_TIMEOUT_NS: Final = 10_000_000_000  # protocol.md 7.5 txn_timeout, 10 s of capture time

# protocol.md 6: the rules the truth states, by name (the analyser's names) with their ids
RULE_IDS: Final = {
    "rpc_truncated": "R1", "rpc_retransmission": "R7", "truncated_capture_pnio": "L1",
    "iod_truncated": "H0", "block_length": "H2", "record_truncated": "H5", "pd_record_length": "H13",
    "pd_request_range": "P2", "block_overrun": "P6", "change_blocks": "P6", "format_unsupported_stop": "F1",
    "reference_mismatch": "Q2", "header_level_error": "Q5",
    "reference_reused": "T1", "write_while_pending": "T3", "retry": "T4", "b5_polling": "T5",
    "txn_failed": "T8", "txn_refused": "T9",
}  # fmt: skip
B5_STATUS: Final = "DE80B500"  # a read answered "state conflict": the drive is not ready (protocol.md 4.6)
ANSWERED: Final = ("ok", "nak")  # T1: a reference reused after one of these
FAILED: Final = ("pnio_error", "timeout")  # T4: a retry of one of these


class Slot:
    """One frame on its way to the file: its bytes, time and the number it gets when written."""

    __slots__ = ("cut", "data", "number", "opens", "ts_ns", "wire_len")

    def __init__(self, ts_ns: int, data: bytes, wire_len: int | None = None) -> None:
        self.ts_ns = ts_ns
        self.data: bytes | None = data
        self.wire_len = len(data) if wire_len is None else wire_len
        self.number = 0  # 1-based, set when written
        self.opens: list[Txn] = []  # the transactions whose write request starts here, by position
        self.cut: int | None = None  # keep only this many bytes (of the untagged frame): the snaplen


@dataclass(eq=False, slots=True)
class Txn:
    """One PROFIdrive transaction as the generator made it, and what the analyser must report of it."""

    kind: str  # what the generator made (e.g. "nak_change", "timeout_unanswered_write")
    channel: tuple  # device, controller, AR, API, slot, subslot, index (protocol.md 7.2)
    ref: int | None  # None: the request was cut before its reference
    write: Slot  # the first frame of the write request: numbers the transaction, times its start
    write_at: Slot  # the frame that completes the write request: where it is decoded, its findings are
    frames: list[Slot] = field(default_factory=list)
    reads: int = 0
    b5_retries: int = 0
    rpc_retransmissions: int = 0
    malformed_at: Slot | None = None  # the undecodable PDU (protocol.md 7.4 rule 1)
    write_res: Slot | None = None
    final_res: Slot | None = None
    pnio_status: str = ""
    response: str = ""  # how the final read was answered: "ok", "nak", "mismatch"; "" before
    errors: list[list[Any]] = field(default_factory=list)  # NAK: [pnu, subindex, error, whole_request] per row
    findings: list[tuple[Slot, str]] = field(default_factory=list)
    closed_by: str = ""  # "", "response", "pnio_error", "superseded", "deadline", "capture_end"
    decided_at: Slot | None = None  # the frame that decided a failed verdict (T8)
    capture_ended: bool = False
    verdict: str = ""
    number: int = 0

    @property
    def deadline_ns(self) -> int:
        return self.write.ts_ns + TXN_TIMEOUT_NS

    def on(self, slot: Slot, rule: str) -> None:
        """A finding of `rule` the analyser must raise at `slot`."""
        if rule not in RULE_IDS:
            raise ValueError(f"rule {rule} is not one the truth states")
        self.findings.append((slot, rule))

    # --- how it ends ------------------------------------------------------------------------------------
    def answered(self, slot: Slot, response: str) -> None:
        """The final read response (protocol.md 7.3 step 3): "ok", "nak" or "mismatch" (Q2 failed)."""
        self.final_res, self.response = slot, response
        self._close("response", slot)

    def failed(self, slot: Slot, status: str) -> None:
        """A write or read answered with an error PNIOStatus (not B5 on a read), or an RPC fault."""
        self.final_res = slot if self.write_res is not slot else None
        self.pnio_status = status
        self._close("pnio_error", slot)

    def superseded(self, slot: Slot) -> None:
        """The next write on the channel came before the deadline (T3 is the new transaction's)."""
        self._close("superseded", slot)

    def expired(self, last_ts_ns: int | None = None) -> None:
        """The deadline passed inside the capture, or (`last_ts_ns` given) the capture ended first."""
        if last_ts_ns is not None and self.deadline_ns > last_ts_ns:
            self.capture_ended = True
            self._close("capture_end", self.write_at)
        else:
            self._close("deadline", self.write_at)

    def _close(self, why: str, slot: Slot) -> None:
        if self.closed_by:
            raise AssertionError(f"transaction of {self.kind} closed twice ({self.closed_by}, {why})")
        self.closed_by = why
        unanswered = why in ("superseded", "deadline", "capture_end")
        if unanswered and self.b5_retries and not self.pnio_status:
            self.pnio_status = B5_STATUS  # the last answer was B5 (a timeout), or every one (7.3 step 5)
        self.verdict = self._verdict(unanswered)
        if self.verdict == "malformed":
            self.decided_at = self.malformed_at
        elif self.verdict in FAILED:
            self.decided_at = slot
        if self.decided_at is not None:
            self.on(self.decided_at, "txn_failed")
        if self.verdict == "nak" and self.final_res is not None:
            self.on(self.final_res, "txn_refused")

    def _verdict(self, unanswered: bool) -> str:
        """protocol.md 7.4, first matching rule wins."""
        gave_up = self.closed_by in ("superseded", "deadline")  # 7.3 step 5: inside the capture
        busy = self.reads > 0 and self.b5_retries == self.reads and gave_up
        if self.malformed_at is not None:
            return "malformed"
        if self.closed_by == "pnio_error" or busy:
            return "pnio_error"
        if unanswered:
            return "timeout"
        return {"mismatch": "reference_mismatch", "nak": "nak", "ok": "ok"}[self.response]

    # --- output -----------------------------------------------------------------------------------------
    def render(self) -> dict[str, Any]:
        if not self.closed_by:
            raise AssertionError(f"transaction of {self.kind} never closed")
        res = self.write_res
        done = self.final_res if self.closed_by == "response" else None
        return {
            "txn": self.number, "write_req_frame": self.write.number, "kind": self.kind,
            "device": self.channel[0], "controller": self.channel[1], "slot": self.channel[4],
            "index": f"{self.channel[6]:#06x}", "ref": self.ref, "verdict": self.verdict,
            "b5_retries": self.b5_retries, "reads": self.reads, "rpc_retransmissions": self.rpc_retransmissions,
            "pnio_status": self.pnio_status, "errors": self.errors, "closed_by": self.closed_by,
            "capture_ended": self.capture_ended, "frames": sorted(s.number for s in self.frames),
            "write_res_frame": None if res is None else res.number,
            "t_start_ns": self.write.ts_ns,
            "t_write_rtt_ns": None if res is None else res.ts_ns - self.write.ts_ns,
            "t_total_ns": None if done is None else done.ts_ns - self.write.ts_ns,
            "findings": sorted([s.number, RULE_IDS[rule], rule] for s, rule in self.findings),
        }  # fmt: skip


@dataclass
class _Channel:
    last: Txn | None = None  # the last transaction closed (T1, T4)
    pending: Txn | None = None  # the transaction waiting for its final answer


class Channels:
    """The channels' state as protocol.md 7.3 runs it: the pending transaction of each, the last closed."""

    def __init__(self) -> None:
        self._by_key: dict[tuple, _Channel] = {}
        self.closed: list[Txn] = []  # in the order they closed (drained by the caller)

    def state(self, channel: tuple) -> _Channel:
        return self._by_key.setdefault(channel, _Channel())

    def pending(self, channel: tuple) -> Txn | None:
        return self.state(channel).pending

    def write(self, txn: Txn) -> None:
        """A write request opens `txn` on its channel: the pending one is superseded (T3) or has passed its
        deadline; then T1/T4 against the channel's last transaction (protocol.md 6.5)."""
        ch = self.state(txn.channel)
        old = ch.pending
        if old is not None:
            if txn.write_at.ts_ns <= old.deadline_ns:
                txn.on(txn.write_at, "write_while_pending")
                old.superseded(txn.write_at)
            else:
                old.expired()
            self._closed(ch, old)
        last = ch.last
        if last is not None and last.ref == txn.ref and txn.ref is not None:
            if last.verdict in ANSWERED:
                txn.on(txn.write_at, "reference_reused")
            elif last.verdict in FAILED:
                txn.on(txn.write_at, "retry")
        ch.pending = txn

    def ended(self, txn: Txn) -> None:
        """`txn` closed by an answer (its channel is idle again)."""
        ch = self.state(txn.channel)
        if ch.pending is txn:
            ch.pending = None
        self._closed(ch, txn)

    def open(self) -> Iterator[Txn]:
        return (ch.pending for ch in self._by_key.values() if ch.pending is not None)

    def finish(self, last_ts_ns: int) -> None:
        """The capture ended at `last_ts_ns`: every pending transaction ends (protocol.md 7.3 step 4)."""
        for ch in self._by_key.values():
            if ch.pending is not None:
                txn, ch.pending = ch.pending, None
                txn.expired(last_ts_ns)
                self._closed(ch, txn)

    def _closed(self, ch: _Channel, txn: Txn) -> None:
        ch.last = txn
        self.closed.append(txn)


def ambiguous_end(open_txns: Iterable[Txn], last_ts_ns: int, margin_ns: int = 2_000_000) -> bool:
    """Whether a pending transaction's deadline lies so near the capture's last frame that timestamps
    rounded to a file's resolution (or to a float) could put it on either side."""
    return any(abs(t.deadline_ns - last_ts_ns) < margin_ns for t in open_txns)

"""CL-RPC calls (protocol.md 2.4): requests paired with their responses by activity UUID + sequence number,
never by ports; retransmissions and reused keys told apart by a digest of the body; open calls expire
after rpc_timeout of capture time, and answered calls are remembered as long to spot duplicates (a copy
that comes later is a new call, or an orphan); both tables capped (model.capped)."""

from __future__ import annotations

import zlib
from collections.abc import Iterator
from dataclasses import InitVar, dataclass

from pd_analyze.model import rules
from pd_analyze.model.capped import ANSWERED_CALLS, MAX_LISTED, OPEN_CALLS, CappedTable
from pd_analyze.model.rules import Finding

CALL_OVERHEAD = 512  # bytes a call costs beyond its body (objects), counted against the byte caps
NO_RESPONSE = "no response within {timeout:g} s"  # why a call was not answered: it expired


def unanswered_finding(frame: int, seq: int, timeout: float, why: str = NO_RESPONSE) -> Finding:
    """rpc_unanswered: the request of `frame` got no response (it expired, or the capture ended)."""
    return rules.finding("rpc_unanswered", frame, "rpc.seq", seq, f"a response within {timeout:g} s",
                         f"request not answered ({why.format(timeout=timeout)})")


@dataclass(slots=True)
class Call:
    """An RPC call: the request as first seen, and what the analysis learnt from it."""

    frame: int
    ts: float
    src: bytes
    dst: bytes
    interface: bytes
    opnum: int
    body: InitVar[bytes]  # the request's body: its size and digest are kept, not the bytes
    size: int = 0
    digest: int = 0  # CRC-32 of the body: an identical copy is a retransmission, another body a reused key
    info: object = None  # what the record layer keeps for checking the response
    copies: int = 0
    working: int = 0
    pings: int = 0
    response_frame: int = 0
    answered: float = float("-inf")  # capture time of the answer
    cost: int = 0  # bytes it keeps alive (what was decoded from it), counted against the caps

    def __post_init__(self, body: bytes) -> None:
        self.size = len(body)
        self.digest = zlib.crc32(body)

    def same_body(self, other: Call) -> bool:
        return self.digest == other.digest and self.size == other.size


class CallTable:
    """Open calls by (activity, seq); closed ones remembered a while to spot duplicates."""

    def __init__(self) -> None:
        self.open: CappedTable[tuple[bytes, int], Call] = CappedTable(OPEN_CALLS)
        self.closed: CappedTable[tuple[bytes, int], Call] = CappedTable(ANSWERED_CALLS)

    @property
    def evicted(self) -> int:
        """Open calls dropped by the caps."""
        return self.open.evicted

    def request(self, key: tuple[bytes, int], call: Call, findings: list[Finding]) -> Call:
        """Register a request; returns the call it belongs to (the first copy on retransmission)."""
        known = self.open.get(key) or self.closed.get(key)
        if known is not None:
            if known.same_body(call):
                known.copies += 1
                findings.append(rules.finding(
                    "rpc_retransmission", call.frame, "rpc.seq", key[1], "a new sequence number",
                    f"request retransmitted (copy {known.copies} of frame {known.frame})"))
            else:
                findings.append(rules.finding(
                    "rpc_key_reused", call.frame, "rpc.seq", key[1], "a new sequence number",
                    f"activity/sequence number of frame {known.frame} reused with a different body"))
            return known
        call.cost = CALL_OVERHEAD + call.size
        self._evicted(self.open.add(key, call, call.frame, call.cost), call.frame, findings)
        return call

    def charge(self, key: tuple[bytes, int], call: Call, extra: int, findings: list[Finding]) -> None:
        """What was decoded from an open call's request (kept in `info`) adds `extra` bytes to its cost."""
        if self.open.get(key) is call:
            call.cost += extra
            self.open.charge(key, extra)
            self._evicted(self.open.make_room(call.frame, keep=key), call.frame, findings)

    @staticmethod
    def _evicted(evicted: list[tuple[tuple[bytes, int], Call, bool]], number: int, findings: list[Finding]) -> None:
        """Open calls the caps dropped (the oldest; never the one just added or grown)."""
        for old_key, old, listed in evicted:
            if listed:
                findings.append(rules.finding(
                    OPEN_CALLS.rule, number, "rpc.seq", old_key[1], OPEN_CALLS.text(),
                    f"open-call table full: call of frame {old.frame} dropped unanswered"))

    def open_frames(self) -> Iterator[int]:
        """Request frame of every unanswered call."""
        return (call.frame for call in self.open.values())

    def close(self, key: tuple[bytes, int], ts: float = float("-inf")) -> Call | None:
        """The open call of `key`, answered at capture time `ts`: remembered until rpc_timeout after."""
        call = self.open.pop(key, None)
        if call is not None:
            call.answered = ts
            self.closed.remember(key, call)  # the oldest are forgotten when the table is full
        return call

    def finish(self) -> list[Finding]:
        """At the end of the capture: how many open calls the caps dropped beyond those listed."""
        more = self.open.unlisted()
        if not more:
            return []
        return [rules.finding(
            OPEN_CALLS.rule, self.open.last_eviction, "rpc.seq", self.evicted, OPEN_CALLS.text(),
            f"{more} more open calls dropped unanswered by the table caps "
            f"({self.evicted} in all; only the first {MAX_LISTED} are listed one by one)")]

    def expire(self, now: float, timeout: float) -> list[tuple[tuple[bytes, int], Call]]:
        """Calls opened more than `timeout` seconds of capture time before `now`; answered calls are
        forgotten as long after their answer."""
        closed = self.closed
        while closed:  # in the order answered: stop at the first still remembered
            key = next(iter(closed))
            if closed[key].answered + timeout >= now:
                break
            closed.pop(key)
        first = self.open.oldest()
        if first is None or first.ts + timeout >= now:
            return []  # the common case, checked for every frame: nothing is due
        out = []
        for key, call in self.open.items():
            if call.ts + timeout >= now:
                break
            out.append((key, call))
        for key, _call in out:
            self.open.pop(key)
        return out

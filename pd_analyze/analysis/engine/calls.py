"""CL-RPC calls (protocol.md 2.4): every PNIO PDU of the capture, in frame order, paired with its call by
activity UUID and sequence number, never by ports. The one implementation of the pairing for every
command: retransmissions and reused keys told apart by the digest of the body, duplicate and orphan
responses, R4, calls expiring after rpc_timeout of capture time, answered calls remembered as long (to
recognise a late copy), a PDU whose interface is not PNIO's taken as PNIO when its call or activity is;
both tables capped (model.capped), every eviction stated.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

from pd_analyze.analysis.engine.facts import Key, Pdu
from pd_analyze.capture.raw import RawFrame
from pd_analyze.model import rules
from pd_analyze.model.capped import ANSWERED_CALLS, KNOWN_ACTIVITIES, MAX_LISTED, OPEN_CALLS, CappedTable
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import (
    PTYPE_FAULT,
    PTYPE_NOCALL,
    PTYPE_REJECT,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
    PTYPE_WORKING,
)
from pd_analyze.protocol.rpc import response_findings
from pd_analyze.protocol.rpc_calls import CALL_OVERHEAD, NO_RESPONSE, unanswered_finding

_ANSWERS = (PTYPE_RESPONSE, PTYPE_FAULT, PTYPE_REJECT, PTYPE_WORKING, PTYPE_NOCALL)  # PNIO if their call is
END_OF_CAPTURE = "end of capture"
_SAME = 4096  # distinct values (activities, addresses, interfaces) open calls share one object of


class Sent(NamedTuple):
    """What the checks of a later answer (engine.findings) read of a call's request once the part it came in
    is done, in place of its row (`part_done`): a column row (its frame is the call's `raw`), its part and
    its operation."""

    part: int
    opnum: int
    odd: bool = False  # (read as a row's: a column row, never the current part's)
    col: int = -1


class Call:
    """An RPC call: its request as first seen, and what the transactions learn of it (`fsm`)."""

    __slots__ = ("answered", "copies", "digest", "dst", "frame", "fsm", "ifc", "opnum", "raw", "request",
                 "response_frame", "src", "ts")

    def __init__(self, row: Pdu | None) -> None:
        if row is not None:
            self.frame, self.ts = row.frame, row.ts
            self.src, self.dst, self.ifc, self.opnum = row.src, row.dst, row.ifc, row.opnum
            self.digest = row.digest
        self.request: Pdu | Sent | None = row  # the request's row (its records, its frames for the checks of
        # the answer); a Sent once its part is done (engine.run)
        self.copies = 0
        self.response_frame = 0
        self.answered = -1  # capture time of the answer (ns); -1: none yet
        self.fsm: object = None  # what the transactions keep of the call (machine)
        self.raw = None  # its request frame, kept when the call outlives its batch unanswered (the checks of
        # its answer read it)


@dataclass(slots=True)
class AnsweredLog:
    """Calls the vector path took whole in one batch, answered: remembered rpc_timeout after their answer
    as columns, found by key through `index` (key -> row); a call found becomes a Call of the table."""

    columns: dict[str, list]  # frame, ts, answered, src, dst, if_hi, if_lo, opnum, digest, size, response_frame
    index: dict[Key, int]
    last: int  # the latest answer among them (ns)

    def call(self, i: int) -> Call:
        c = self.columns
        call = Call(None)
        call.frame, call.ts, call.answered = c["frame"][i], c["ts"][i], c["answered"][i]
        call.src, call.dst, call.opnum = c["src"][i], c["dst"][i], c["opnum"][i]
        call.ifc = (c["if_hi"][i], c["if_lo"][i])
        call.digest, call.response_frame = (c["digest"][i], c["size"][i]), c["response_frame"][i]
        return call


def part_done(rows: list[Pdu], raw_of: Callable[[Pdu], RawFrame]) -> None:
    """The part's rows go: a call still open keeps what the checks of its answer read of its request, its
    frame (`raw_of` a column row) and a Sent, not the row; and no row points at its call any more, so a call
    evicted or expired is freed at once (a row and its call made a cycle only the cyclic collector frees: a
    flood of never-answered calls piled them up). A write cut before its IOD header keeps its row: its answer
    opens the transaction (machine)."""
    sent: dict[tuple[int, int], Sent] = {}  # (one per operation: the part's calls share it)
    for row in rows:
        call = row.call
        if row.whole and row.ptype == PTYPE_REQUEST and not row.copy and call is not None and call.answered < 0 \
                and not row.odd and call.raw is None:
            call.raw = raw_of(row)
        if row.cut:
            continue
        if call is not None and call.request is row and not row.odd:
            call.request = sent.setdefault((row.part, row.opnum), Sent(row.part, row.opnum))
        row.call = None


def ip_text(value: int) -> str:
    return f"{value >> 24}.{value >> 16 & 255}.{value >> 8 & 255}.{value & 255}"


class Pairing:
    """Open calls by key, answered calls remembered rpc_timeout after their answer, the activities of PNIO
    calls (a ping or acknowledgement of one is PNIO too); capture times in nanoseconds."""

    def __init__(self, rpc_timeout: float) -> None:
        self.timeout = round(rpc_timeout * 1e9)
        self.rpc_timeout = rpc_timeout
        self.open: CappedTable[Key, Call] = CappedTable(OPEN_CALLS)
        self.closed: CappedTable[Key, Call] = CappedTable(ANSWERED_CALLS)
        self.activities: CappedTable[tuple[int, int], None] = CappedTable(KNOWN_ACTIVITIES)
        # the activities the loop met first in the current part, with the frame (see `order_activities`)
        self.new_activities: list[tuple[int, tuple[int, int]]] = []
        self.logs: list[AnsweredLog] = []  # the vector path's answered calls, batch by batch
        self.loose: list[Finding] = []  # findings of no frame's own: calls that expired or were never answered
        self.now = -(1 << 62)
        self._same: dict[object, object] = {}  # values open calls share (cleared past _SAME)

    def pnio(self, row: Pdu, first_seen: dict[tuple[int, int], int]) -> bool:
        """Whether a PDU whose interface is not PNIO's belongs to a PNIO call or activity (protocol.md 1.4);
        `first_seen`: activities the vector path's rows of the part make known, at their first frames."""
        key = row.key
        if row.ptype in _ANSWERS:
            return key in self.open or self._answered(key) is not None
        act = (key[0], key[1])
        return act in self.activities or first_seen.get(act, row.frame) < row.frame

    def _answered(self, key: Key) -> Call | None:
        """The call of `key` answered less than rpc_timeout ago: in the table, or in the vector path's logs
        (moved to the table when found: a copy counts on it)."""
        call = self.closed.get(key)
        if call is None:
            for log in self.logs:
                i = log.index.get(key)
                if i is not None:
                    call = log.call(i)
                    del log.index[key]
                    self.closed.remember(key, call)
                    break
        if call is not None and call.answered + self.timeout < self.now:
            self.closed.pop(key, None)
            return None
        return call

    def remember_log(self, keys: list[Key], columns: dict[str, list]) -> None:
        """The calls the vector path took whole in a batch, answered."""
        if not keys:
            return
        self.logs.append(AnsweredLog(columns, dict(zip(keys, range(len(keys)), strict=True)),
                                     max(columns["answered"])))
        while len(self.logs) > 1 and sum(len(log.index) for log in self.logs) > ANSWERED_CALLS.count:
            self.logs.pop(0)  # the oldest batch's calls are forgotten (ANSWERED_CALLS)

    def order_activities(self, first_seen: dict[tuple[int, int], int]) -> None:
        """The end of a part the vector path took calls of: the activities first met in it, by the loop and
        (`first_seen`: activity -> first frame, those unknown when the part began) by the vector path, known
        in the order of their first frames, as a loop over every row would have met them (the oldest is
        forgotten first; no activity was forgotten within the part: the vector path keeps off near the cap)."""
        if not first_seen:
            self.new_activities.clear()
            return
        found = dict(first_seen)
        for frame, act in self.new_activities:
            found[act] = min(frame, found.get(act, frame))
        self.new_activities.clear()
        for act in found:
            self.activities.pop(act, None)
        for _frame, act in sorted((frame, act) for act, frame in found.items()):
            self.activities.remember(act, None)

    def tick(self, now: int) -> None:
        """Capture time reached `now` (over every frame, PNIO or not): the calls due expire."""
        if now > self.now:
            self.now = now
            self.expire()

    def pair(self, row: Pdu) -> None:
        """One PNIO PDU, in frame order (after `tick` to its frame's time)."""
        act = (row.key[0], row.key[1])
        if act not in self.activities:
            self.activities.remember(act, None)
            self.new_activities.append((row.frame, act))
        if not row.whole:
            copy = row.raw.fragment_copy if row.raw is not None else None
            if copy is not None:  # an identical request fragment again: the call counts it
                call = self.open.get(row.key)
                if call is not None:
                    call.copies += 1
                    row.call, row.copy, row.resent = call, True, True  # (its frame is the call's transactions')
            return
        ptype = row.ptype
        if ptype == PTYPE_REQUEST:
            self._request(row)
        elif ptype == PTYPE_RESPONSE:
            self._response(row)
        elif ptype in (PTYPE_FAULT, PTYPE_REJECT):
            row.call = self._close(row.key, row.ts)

    def _request(self, row: Pdu) -> None:
        key = row.key
        known = self.open.get(key) or self._answered(key)
        if known is not None:
            if known.digest == row.digest:
                known.copies += 1
                row.resent = True
                row.findings.append(rules.finding(
                    "rpc_retransmission", row.frame, "rpc.seq", key[2], "a new sequence number",
                    f"request retransmitted (copy {known.copies} of frame {known.frame})"))
            else:
                row.findings.append(rules.finding(
                    "rpc_key_reused", row.frame, "rpc.seq", key[2], "a new sequence number",
                    f"activity/sequence number of frame {known.frame} reused with a different body"))
            row.call = known
            row.copy = True
            return
        same = self._same
        if len(same) > _SAME:
            same.clear()
        call = Call(row)
        # the activity, addresses and interface a flood's calls share, held once (not per open call)
        key = row.key = (same.setdefault(key[0], key[0]), same.setdefault(key[1], key[1]), key[2])
        call.src, call.dst = same.setdefault(row.src, row.src), same.setdefault(row.dst, row.dst)
        call.ifc = same.setdefault(row.ifc, row.ifc)
        row.call = call
        for old_key, old, listed in self.open.add(key, call, row.frame, CALL_OVERHEAD + row.digest[1]):
            if listed:
                row.findings.append(rules.finding(
                    OPEN_CALLS.rule, row.frame, "rpc.seq", old_key[2], OPEN_CALLS.text(),
                    f"open-call table full: call of frame {old.frame} dropped unanswered"))

    def _response(self, row: Pdu) -> None:
        key = row.key
        call = self._close(key, row.ts)
        if call is None:
            dup = self._answered(key)
            if dup is not None:
                row.findings.append(rules.finding(
                    "rpc_retransmission", row.frame, "rpc.seq", key[2], "one response per call",
                    f"duplicate response (call of frame {dup.frame} already answered)"))
                row.copy = True
                row.call = dup
            else:
                row.findings.append(rules.finding("orphan_response", row.frame, "rpc.seq", key[2], "an open request",
                                                  "response without an open request (decoded with its own opnum)"))
            return
        row.call = call
        call.response_frame = row.frame
        row.findings += response_findings(call.frame, row.ifc == call.ifc and row.opnum == call.opnum, row.opnum,
                                          call.opnum, ip_text(row.src), ip_text(call.dst),
                                          (row.src, row.dst) == (call.dst, call.src), row.frame)

    def _close(self, key: Key, ts: int) -> Call | None:
        """The open call of `key`, answered at `ts`: remembered until rpc_timeout after."""
        call = self.open.pop(key, None)
        if call is not None:
            call.answered = ts
            self.closed.remember(key, call)  # the oldest are forgotten when the table is full
        return call

    def expire(self) -> None:
        """Calls opened more than rpc_timeout before now are unanswered; answered calls are forgotten as
        long after their answer."""
        now, timeout, closed = self.now, self.timeout, self.closed
        if self.logs and self.logs[0].last + timeout < now:
            self.logs = [log for log in self.logs if log.last + timeout >= now]
        while closed:  # in the order answered: stop at the first still remembered
            key = next(iter(closed))
            if closed[key].answered + timeout >= now:
                break
            closed.pop(key)
        first = self.open.oldest()
        if first is None or first.ts + timeout >= now:
            return  # the common case: nothing is due
        due = []
        for key, call in self.open.items():
            if call.ts + timeout >= now:
                break
            due.append((key, call))
        for key, call in due:
            self.open.pop(key)
            self.loose.append(unanswered_finding(call.frame, key[2], self.rpc_timeout, NO_RESPONSE))

    def finish(self) -> None:
        """End of capture: every open call unanswered, and how many the caps dropped beyond those listed."""
        for key, call in list(self.open.items()):
            self.open.pop(key)
            self.loose.append(unanswered_finding(call.frame, key[2], self.rpc_timeout, END_OF_CAPTURE))
        more = self.open.unlisted()
        if more:
            evicted = self.open.evicted
            self.loose.append(rules.finding(
                OPEN_CALLS.rule, self.open.last_eviction, "rpc.seq", evicted, OPEN_CALLS.text(),
                f"{more} more open calls dropped unanswered by the table caps "
                f"({evicted} in all; only the first {MAX_LISTED} are listed one by one)"))

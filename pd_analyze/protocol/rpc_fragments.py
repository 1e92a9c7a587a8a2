"""CL-RPC fragment reassembly (protocol.md 2.3): fragment sets keyed by activity + sequence number +
direction + address pair, completed when the last fragment and every number before it are in; duplicates,
conflicts, holes and late copies reported; the table capped (model.capped)."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

from pd_analyze.model import rules
from pd_analyze.model.capped import CL_DONE_SETS, CL_FRAGMENT_SETS, CL_SET_BYTES, MAX_LISTED, CappedTable
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import FLAG1_LASTFRAG, PTYPE_REQUEST
from pd_analyze.protocol.rpc import Header

FRAGMENT_OVERHEAD = 128  # bytes a held fragment costs beyond its body, so tiny fragments count too
DIGEST_SIZE = 16  # bytes of a remembered fragment's digest (CL_DONE_SETS counts them)


@dataclass(slots=True)
class _FragSet:
    first_frame: int
    first_ts: float
    bodies: dict[int, bytes] = field(default_factory=dict)
    frames: dict[int, int] = field(default_factory=dict)
    last: int = -1
    size: int = 0


class Reassembled(NamedTuple):
    body: bytes
    frames: tuple[int, ...]  # frames of fragments 0..last, in fragment order
    first_ts: float


class _Done(NamedTuple):
    """A reassembled set: the frame that completed it and a digest of each fragment body."""

    frame: int
    digests: dict[int, bytes]


def _digest(body: bytes) -> bytes:
    return hashlib.blake2b(body, digest_size=DIGEST_SIZE).digest()


class FragmentTable:
    """CL fragment reassembly keyed by activity + seq + direction + address pair (protocol.md 2.3)."""

    def __init__(self) -> None:
        self._sets: CappedTable[tuple, _FragSet] = CappedTable(CL_FRAGMENT_SETS)
        self._done: CappedTable[tuple, _Done] = CappedTable(CL_DONE_SETS)  # by the bytes of their digests
        self._by_call: dict[tuple, list[tuple]] = {}  # (activity, seq) -> keys of its request sets

    @property
    def evicted(self) -> int:
        """Fragment sets dropped by the caps."""
        return self._sets.evicted

    def add(self, key: tuple, number: int, ts: float, hdr: Header, body: bytes,
            findings: list[Finding]) -> Reassembled | None:
        """Add one fragment; the whole body once the set is complete, else None."""
        entry = self._sets.get(key)
        if entry is None and self._late_copy(key, hdr.frag_num, body):
            done = self._done[key]
            findings.append(rules.finding(
                "rpc_retransmission", number, "rpc.frag_num", hdr.frag_num, "a new fragment",
                f"fragment {hdr.frag_num} retransmitted after its PDU was reassembled in frame "
                f"{done.frame} (identical copy)"))
            return None
        cost = len(body) + FRAGMENT_OVERHEAD
        if entry is not None and entry.size + cost > CL_SET_BYTES:
            self._drop(key, number, findings, f"fragment set above {CL_SET_BYTES} bytes")
            entry = None
        for victim, old, listed in self._sets.make_room(number, cost, key not in self._sets, keep=key):
            self._dropped(victim, old, listed, number, findings, "fragment table full")
        if entry is None:
            entry = _FragSet(number, ts)
            self._sets.put(key, entry)
            if key[2] == PTYPE_REQUEST:
                self._by_call.setdefault(key[:2], []).append(key)
        num = hdr.frag_num
        is_last = bool(hdr.flags1 & FLAG1_LASTFRAG)
        if num in entry.bodies:
            if entry.bodies[num] != body:
                findings.append(rules.finding(
                    "rpc_frag_conflict", number, "rpc.frag_num", num, "identical copy",
                    f"fragment {num} repeated with different bytes (first copy from frame "
                    f"{entry.frames[num]} kept)"))
            return None
        if (is_last and entry.last >= 0 and num != entry.last) or (entry.last >= 0 and num > entry.last):
            findings.append(rules.finding(
                "rpc_frag_inconsistent", number, "rpc.frag_num", num, f"<= {entry.last}",
                f"fragment {num} conflicts with last fragment {entry.last}"))
            return None
        if is_last and any(n > num for n in entry.bodies):
            findings.append(rules.finding(
                "rpc_frag_inconsistent", number, "rpc.frag_num", num, f"> {max(entry.bodies)}",
                f"last fragment {num} below fragment {max(entry.bodies)} already seen"))
            return None
        entry.bodies[num] = body
        entry.frames[num] = number
        entry.size += cost
        self._sets.charge(key, cost)
        if is_last:
            entry.last = num
        if entry.last < 0 or len(entry.bodies) != entry.last + 1:
            return None
        self._pop(key)
        self._remember(key, number, entry)
        order = range(entry.last + 1)
        return Reassembled(b"".join(entry.bodies[n] for n in order),
                           tuple(entry.frames[n] for n in order), entry.first_ts)

    def open_pairs(self) -> set[tuple[bytes, bytes]]:
        """(source, destination) of every unfinished set."""
        return {(key[3], key[4]) for key in self._sets}

    def open_frames(self) -> Iterator[int]:
        """First frame of every unfinished set."""
        return (entry.first_frame for entry in self._sets.values())

    def seen(self, key: tuple, num: int, body: bytes) -> bool:
        """True when this exact fragment is already held, or was part of the set reassembled last
        under this key (a retransmitted copy, protocol.md 2.3)."""
        entry = self._sets.get(key)
        if entry is not None:
            return entry.bodies.get(num) == body
        return self._late_copy(key, num, body)

    def reassembled_in(self, key: tuple) -> int | None:
        """The frame that completed the last set reassembled under this key, if remembered."""
        done = self._done.get(key)
        return done.frame if done is not None else None

    def _late_copy(self, key: tuple, num: int, body: bytes) -> bool:
        done = self._done.get(key)
        return done is not None and done.digests.get(num) == _digest(body)

    def _remember(self, key: tuple, number: int, entry: _FragSet) -> None:
        self._done.remember(key, _Done(number, {n: _digest(b) for n, b in entry.bodies.items()}),
                            DIGEST_SIZE * len(entry.bodies))  # the oldest are forgotten

    def _pop(self, key: tuple) -> _FragSet:
        """Take a set out of the table (complete, missing pieces or dropped)."""
        entry = self._sets.pop(key)
        self._unindex(key)
        return entry

    def _unindex(self, key: tuple) -> None:
        if key[2] == PTYPE_REQUEST:
            keys = self._by_call.get(key[:2], [])
            if key in keys:
                keys.remove(key)
            if not keys:
                self._by_call.pop(key[:2], None)

    def pending_calls(self) -> bool:
        """Whether any unfinished set belongs to a request (drop_call may find one)."""
        return bool(self._by_call)

    def drop_call(self, call_key: tuple, number: int, findings: list[Finding]) -> None:
        """The call was answered: any unfinished fragment set of its request is missing pieces."""
        for key in list(self._by_call.get(call_key[:2], ())):
            findings.append(self._missing(key, self._pop(key), number))

    def _missing(self, key: tuple, entry: _FragSet, number: int) -> Finding:
        have = sorted(entry.bodies)
        top = entry.last if entry.last >= 0 else (have[-1] if have else 0)
        absent = _gaps(have, top)  # ranges, not numbers: a set may name up to 65,536 fragments
        missing = f"[{_spans(absent)}]" if absent else "the last fragment"
        expect = f"fragments 0..{entry.last}" if entry.last >= 0 else "a last fragment"
        return rules.finding(
            "rpc_frag_missing", entry.first_frame, "rpc.frag_num", _spans(_runs(have), ","), expect,
            f"fragment set of seq {key[1]} incomplete (missing {missing}; noticed at frame {number})")

    def _drop(self, key: tuple, number: int, findings: list[Finding], why: str) -> None:
        self._dropped(key, *self._sets.evict(key, number), number, findings, why)

    def _dropped(self, key: tuple, entry: _FragSet, listed: bool, number: int, findings: list[Finding],
                 why: str) -> None:
        self._unindex(key)
        if listed:
            findings.append(rules.finding(
                CL_FRAGMENT_SETS.rule, number, "rpc.frag_num", len(entry.bodies),
                f"{CL_FRAGMENT_SETS.text()}, {CL_SET_BYTES} bytes per set",
                f"{why}: set of seq {key[1]} from frame {entry.first_frame} dropped"))

    def finish(self, number: int) -> list[Finding]:
        out = [self._missing(key, entry, number) for key, entry in self._sets.items()]
        more = self._sets.unlisted()
        if more:
            out.append(rules.finding(
                CL_FRAGMENT_SETS.rule, self._sets.last_eviction, "rpc.frag_num", self.evicted, CL_FRAGMENT_SETS.text(),
                f"{more} more fragment sets dropped by the table caps "
                f"({self.evicted} in all; only the first {MAX_LISTED} are listed one by one)"))
        self._sets.clear()
        self._by_call.clear()
        return out


def _runs(numbers: list[int]) -> list[tuple[int, int]]:
    """Sorted numbers as (first, last) runs of consecutive numbers."""
    runs: list[tuple[int, int]] = []
    for n in numbers:
        if runs and n == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], n)
        else:
            runs.append((n, n))
    return runs


def _gaps(have: list[int], top: int) -> list[tuple[int, int]]:
    """The runs of 0..top missing from the sorted numbers `have`."""
    gaps, expect = [], 0
    for n in have:
        if n > top:
            break
        if n > expect:
            gaps.append((expect, n - 1))
        expect = n + 1
    if expect <= top:
        gaps.append((expect, top))
    return gaps


def _spans(runs: list[tuple[int, int]], sep: str = ", ", limit: int = 8) -> str:
    """'0, 2-5, 9' for runs; past `limit` runs the rest is counted, so the text stays short."""
    parts = [str(lo) if lo == hi else f"{lo}-{hi}" for lo, hi in runs[:limit]]
    if len(runs) > limit:
        parts.append(f"... ({sum(hi - lo + 1 for lo, hi in runs[limit:])} more)")
    return sep.join(parts)



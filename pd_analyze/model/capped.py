"""Tables of open state with caps on count and bytes: when one is full, its oldest entry goes.

Every table that holds state for something still open (IP datagrams in reassembly, CL-RPC fragment
sets, open RPC calls, pending transactions) and every memory of things past (answered calls, the
last request per channel) is a CappedTable with its Cap declared here: one name per cap, its limits,
and the finding an eviction earns. A table counts its evictions; its owner turns the first
MAX_LISTED of them into findings one by one and the rest into one finding with the total, so a flood
cannot flood the findings as well. Bytes count what a Python object costs, not only its payload, so
floods of tiny pieces are bounded too.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import TypeVar

MAX_LISTED = 100  # evictions of one table reported one by one; the rest in one finding at the end
MIB = 1024 * 1024


@dataclass(frozen=True, slots=True)
class Cap:
    """The limits of one table."""

    name: str  # what the table holds, as messages and the README name it
    count: int  # entries
    bytes: int = 0  # summed entry costs; 0 = no byte cap
    rule: str = ""  # finding name of an eviction; "" = entries are forgotten without a finding

    def text(self) -> str:
        """The cap as an expected value: '<= 1024 IP datagrams in reassembly, 16777216 bytes'."""
        return f"<= {self.count} {self.name}" + (f", {self.bytes} bytes" if self.bytes else "")


# The caps, one name each (README "Memory" lists them)
IP_DATAGRAMS = Cap("IP datagrams in reassembly", 1024, 16 * MIB, "ip_frag_evicted")
IP_PIECES = 256  # fragments of one datagram (45 carry the largest datagram at MTU 1500)
CL_FRAGMENT_SETS = Cap("CL-RPC fragment sets", 4096, 16 * MIB, "rpc_frag_evicted")
CL_SET_BYTES = MIB  # one fragment set (a PNIO record service needs a small fraction of it)
CL_DONE_SETS = Cap("reassembled fragment sets remembered", 4096, MIB)  # MIB: 65,536 fragment digests
CL_LINKED_SETS = Cap("fragment sets whose frames the dump will link", CL_FRAGMENT_SETS.count)
IP_FRAGMENT_TIMES = Cap("IP fragment times awaiting their datagram", 65_536)
OPEN_CALLS = Cap("open RPC calls", 65_536, 32 * MIB, "rpc_call_evicted")
ANSWERED_CALLS = Cap("answered RPC calls remembered (rpc_timeout after the answer)", 65_536)
KNOWN_ACTIVITIES = Cap("activities known", 65_536)
CHANNEL_REQUESTS = Cap("channels' last parameter requests", 16_384, 16 * MIB)
PENDING_TRANSACTIONS = Cap("pending transactions", 16_384, 32 * MIB, "txn_evicted")
TXN_FRAMES = 10_000  # frames of one transaction (10 s of B5 polling every millisecond)
TXN_CALLS = Cap("transaction calls awaiting their answer", 65_536)
READ_VALUES = Cap("values last read back, per parameter element", 262_144)
CHANNEL_HISTORY = Cap("channels' last closed transactions", 65_536)
# transactions whose rows wait rpc_timeout for late copies of their calls (engine.late; beyond: not listed)
LATE_COPIES = Cap("transactions held for late copies of their calls", 4096, 8 * MIB)  # bytes: their rows' tables

_pop = OrderedDict.pop  # the dict's own, under CappedTable.pop (faster than super() on every call)
_ROOM: list = []  # make_room's answer when nothing had to go (never appended to)

K = TypeVar("K")
V = TypeVar("V")


class CappedTable(OrderedDict[K, V]):
    """An insertion-ordered table under a Cap; reads are the OrderedDict's own (`in`, get, [], items).

    Eviction takes the oldest entry in O(1): an OrderedDict pops its front in O(1), where a dict's
    iterator walks every slot freed before it. Write with `put` and `pop` (they keep the byte count)."""

    def __init__(self, cap: Cap) -> None:
        super().__init__()
        self.cap = cap
        self._count, self._max_bytes = cap.count, cap.bytes  # read on every put: kept at hand
        self._costs: dict[K, int] = {}  # only for a table with a byte cap
        self.bytes = 0
        self.evicted = 0
        self.last_eviction = 0  # frame of the last eviction

    def oldest(self) -> V | None:
        return next(iter(self.values()), None) if self else None

    def put(self, key: K, value: V, cost: int = 0) -> None:
        """Add an entry as the newest (a key already there is replaced and becomes the newest)."""
        if key in self:
            self.pop(key)
        self[key] = value
        if self._max_bytes:
            self._costs[key] = cost
            self.bytes += cost

    def add(self, key: K, value: V, frame: int, cost: int = 0) -> list[tuple[K, V, bool]]:
        """`put`, then make room around it: the evicted entries, as make_room gives them."""
        if key in self:
            self.pop(key)
        self[key] = value
        if self._max_bytes:
            self._costs[key] = cost
            self.bytes += cost
            if self.bytes > self._max_bytes:
                return self.make_room(frame, keep=key)
        if len(self) <= self._count:
            return _ROOM
        return self.make_room(frame, keep=key)

    def remember(self, key: K, value: V, cost: int = 0) -> None:
        """`put` for a memory of things past (a Cap without a rule): the oldest others are forgotten,
        counted but not reported; the fast way of a table that is full most of the time."""
        self[key] = value
        self.move_to_end(key)  # a key already there becomes the newest
        count, max_bytes = self._count, self._max_bytes
        if max_bytes:
            costs = self._costs
            self.bytes += cost - costs.get(key, 0)
            costs[key] = cost
        while len(self) > count or (max_bytes and self.bytes > max_bytes and len(self) > 1):
            victim, _ = self.popitem(last=False)  # the oldest, in O(1)
            if max_bytes:
                self.bytes -= self._costs.pop(victim)
            self.evicted += 1

    def charge(self, key: K, extra: int) -> None:
        """An entry grew (or shrank) by `extra` bytes."""
        if self._max_bytes:
            self._costs[key] += extra
            self.bytes += extra

    def pop(self, key: K, *default: V | None) -> V | None:  # type: ignore[override]
        """Take an entry out (KeyError, or `default` when given, if it is not there)."""
        if default and key not in self:
            return default[0]
        if self._max_bytes:
            self.bytes -= self._costs.pop(key)
        return _pop(self, key)

    def full(self, incoming: int = 0, adding: bool = False) -> bool:
        """Over a cap once `incoming` bytes (and, `adding`, one more entry) come in."""
        return len(self) + adding > self._count or (self._max_bytes > 0 and self.bytes + incoming > self._max_bytes)

    def make_room(self, frame: int, incoming: int = 0, adding: bool = False,
                  keep: K | None = None) -> list[tuple[K, V, bool]]:
        """Evict the oldest entries (never `keep`, the one growing) until `incoming` bytes and, `adding`,
        one more entry fit; each evicted (key, value, listed): listed for the first MAX_LISTED."""
        if len(self) + adding <= self._count and (not self._max_bytes or self.bytes + incoming <= self._max_bytes):
            return _ROOM  # the common case, on every put: room enough
        out = []
        count, max_bytes = self._count, self._max_bytes
        while self and (len(self) + adding > count or (max_bytes and self.bytes + incoming > max_bytes)):
            if next(iter(self)) != keep:
                victim, value = self.popitem(last=False)  # the oldest, in O(1)
            else:  # never the one growing: the next oldest
                victim = next(key for key in self if key != keep) if len(self) > 1 else None
                if victim is None:
                    break
                value = super().pop(victim)
            if max_bytes:
                self.bytes -= self._costs.pop(victim)
            self.evicted += 1
            self.last_eviction = frame
            out.append((victim, value, self.evicted <= MAX_LISTED))
        return out

    def evict(self, key: K, frame: int) -> tuple[V, bool]:
        """Drop an entry the caps cannot hold; (its value, whether to list the eviction one by one)."""
        value: V = self.pop(key)  # type: ignore[assignment]
        self.evicted += 1
        self.last_eviction = frame
        return value, self.evicted <= MAX_LISTED

    def unlisted(self) -> int:
        """Evictions beyond the first MAX_LISTED: counted in one finding at the end."""
        return max(0, self.evicted - MAX_LISTED)

    def clear(self) -> None:
        super().clear()
        self._costs.clear()
        self.bytes = 0

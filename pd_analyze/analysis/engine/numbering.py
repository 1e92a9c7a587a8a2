"""Transaction numbers: 1, 2, ... in the order of the write requests that open them (README: txn), whichever
way (loop or vector) a transaction went.

A transaction is numbered when the batch it opens in is settled, and its rows are handed on when it has a
number. One case makes a number wait: a write request cut before its IOD header was complete (snaplen,
damage) opens its transaction only when its answer names a PROFIdrive index (protocol.md 7.3 step 1), yet
the transaction is numbered at the request's frame. While such a request is unanswered, the transactions
opened after its frame wait for their numbers (and, closed, for their rows); the vector path stays off
meanwhile (its transactions are numbered in their batch). The wait ends with the answer, or when the call
expires (rpc_timeout of capture time) or leaves the pairing's table: a bounded delay, rare in practice.
"""

from __future__ import annotations

from pd_analyze.analysis.engine.calls import Call, Pairing
from pd_analyze.analysis.engine.facts import Key, Pdu
from pd_analyze.analysis.engine.records import Records
from pd_analyze.analysis.engine.txn import Txn
from pd_analyze.analysis.engine.txncols import TxnCols
from pd_analyze.model.values import PTYPE_REQUEST


class Numbering:
    """The next number, the cut write requests still unanswered, the transactions waiting for a number."""

    def __init__(self) -> None:
        self.next = 1
        self._cuts: list[tuple[int, Key, Call]] = []  # (request frame, key, call), in frame order
        self._waiting: list[Txn] = []  # opened, not numbered yet
        self._held: list[Txn] = []  # closed, not numbered yet: their rows wait

    def note_cuts(self, rows: list[Pdu]) -> None:
        """The loop's rows of a batch: the write requests among them cut before their IOD header."""
        for row in rows:
            if row.cut and row.whole and row.ptype == PTYPE_REQUEST and not row.copy and row.call is not None:
                self._cuts.append((row.frame, row.key, row.call))

    def barrier(self, pairing: Pairing) -> int | None:
        """The frame of the oldest cut write request still awaiting its answer (None: none): transactions
        opened at or after it wait for their numbers."""
        self._cuts = [c for c in self._cuts if c[2].answered < 0 and pairing.open.get(c[1]) is c[2]]
        return self._cuts[0][0] if self._cuts else None

    def waits(self, pairing: Pairing, rows: list[Pdu]) -> bool:
        """Whether numbers may wait in this batch (a cut write request pending, or among the batch's
        `rows`): the vector path then leaves the batch to the loop."""
        return self.barrier(pairing) is not None or any(row.cut for row in rows)

    def number(self, opened: list[Txn], cols: TxnCols | None, barrier: int | None) -> None:
        """Number the transactions `opened` (by the machine) and `cols` (by the vector path) with those waiting,
        in the order of their write requests, all but those opened at or after `barrier`."""
        self._waiting.extend(opened)
        order = sorted([(t.opened_at, t.position, 0, i) for i, t in enumerate(self._waiting)]
                       + ([(int(f), 0, 1, k) for k, f in enumerate(cols.write_frame.tolist())] if cols else []))
        still: list[Txn] = []
        for at, _pos, kind, i in order:
            if kind == 0:
                txn = self._waiting[i]
                if barrier is not None and at >= barrier:
                    still.append(txn)
                    continue
                txn.number = self.next
            else:
                cols.number[i] = self.next  # type: ignore[union-attr]
            self.next += 1
        self._waiting = still

    def ready(self, closed: list[Txn], records: Records) -> list[Txn]:
        """Of the closed transactions and those held, the ones numbered (their rows may go); the others are
        held, their records kept as parses (the batch's columns go)."""
        held = self._held + closed
        self._held = [t for t in held if not t.number]
        for txn in self._held:
            txn.request, txn.response = records.parsed(txn.request), records.parsed(txn.response)
        return [t for t in held if t.number]

"""What the analysis says of each frame, in frame order: the transactions the frame belongs to (and whether
it opens or closes them) and the findings at it, taken from the report's own rows, so `annotate`, `extract`
and the display filters' analysis fields (txn.id, txn.verdict, txn.b5_retries, finding.rule, finding.severity) say what
`report` says, whichever path (frame by frame or columnar) read the capture.

The notes go through the report's bounded on-disk sort (`spool.Spool`), keyed by frame: memory stays flat
in the capture size. A transaction's rows come when it closes, so they are sorted, not merged.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

from pd_analyze.analysis.capture_run import CaptureResult, Settings
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.schema import RULE_RANK, FindingRow, ParameterRow, TransactionRow
from pd_analyze.model import pd_values as pt
from pd_analyze.model.rules import Finding
from pd_analyze.output.spool import Spool

OPEN, CLOSE = "open", "close"
_TXN, _FINDING = "t", "f"
_SEV_LETTER = {"error": "E", "warning": "W", "info": "I"}
_MEMORY_ROWS = 4096  # notes held before the sort spills to disk
FINAL_ANSWER = frozenset({"response", "pnio_error"})  # closed_by values whose closing frame is an answer


class TxnNote(NamedTuple):
    txn: int
    verdict: str
    role: str  # OPEN (its write request), CLOSE (its final answer), "" (another of its frames)
    params: str  # P964[0] P2000[0..2]
    errors: str  # the transactions table's errors cell: P2000[0]:0x02 ...
    closed_by: str
    b5_retries: int  # reads answered B5 (not ready)


class FindingNote(NamedTuple):
    severity: str
    rule: str
    name: str
    message: str
    field: str = ""
    value: str = ""
    expected: str = ""
    source: str = ""

    def finding(self, frame: int) -> Finding:
        """The finding as the analysis made it."""
        return Finding(self.rule, self.name, self.severity, frame, self.field, self.value, self.expected, self.source,
                       self.message)


@dataclass(slots=True)
class FrameNote:
    frame: int
    txns: list[TxnNote] = field(default_factory=list)
    findings: list[FindingNote] = field(default_factory=list)
    names: pt.Names = pt.PROFIDRIVE_NAMES  # the run's profile's error texts (Checker.names)

    def comment(self) -> str:
        """The packet comment of `annotate`, '' when the frame neither has a finding nor opens or closes a
        transaction: 'pd-analyze: txn 12 nak; P2000[0] error 0x02 value out of range; W H5 ...'."""
        parts = []
        for t in self.txns:
            if t.role == OPEN:
                parts.append(f"txn {t.txn} request {t.params or '(unparsed)'}: {_outcome(t)}")
            elif t.role == CLOSE:
                parts.append(f"txn {t.txn} {t.verdict}")
                parts += _error_texts(t.errors, self.names)
        parts += [f"{_SEV_LETTER.get(f.severity, '?')} {f.rule} {f.message}" for f in self.findings]
        return "pd-analyze: " + "; ".join(parts) if parts else ""


def _outcome(t: TxnNote) -> str:
    if t.verdict == "timeout" and t.closed_by:
        return f"timeout ({t.closed_by.replace('_', ' ')})"
    return t.verdict


def _error_texts(errors: str, names: pt.Names) -> list[str]:
    """'P2000[0]:0x02 *:0x11' as 'P2000[0] error 0x02 value out of range', ..."""
    out = []
    for item in errors.split():
        param, _, code = item.rpartition(":")
        try:
            text = names.error(int(code, 16))
        except ValueError:
            text = ""
        who = "request" if param == "*" else param
        out.append(f"{who} error {code} {text}".rstrip())
    return out


def _key(note: tuple) -> tuple:
    """Frame, then the transactions (by number) before the findings (in the findings table's order)."""
    if note[0] == _TXN:
        return (note[1], 0, note[2])
    return (note[1], 1, RULE_RANK.get(note[4], -1))


class _NoteRows(Rows):
    """Rows that become notes: each transaction row a note on each of its frames, each finding row a note
    on its frame; parameters are handed to `on_parameter` (extract selects by PNU), changes dropped."""

    def __init__(self, spool: Spool, on_transaction: Callable[[Any], None] | None,
                 on_parameter: Callable[[Any], None] | None, on_calls: Callable[..., None] | None = None,
                 txns: bool = True, on_table: Callable[[str, Any], None] | None = None) -> None:
        super().__init__(transactions=_Sink(self._transaction), parameters=_Sink(on_parameter),  # type: ignore[arg-type]
                         findings=_Sink(self._finding), changes=_Sink(None))  # type: ignore[arg-type]
        self.spool = spool
        self.on_transaction = on_transaction
        self.on_calls = on_calls
        self.txns = txns  # False: the transactions are not noted at their frames (the findings only)
        self.on_table = on_table  # the engine's tables as they come (its rows then reach the notes only)

    def add_calls(self, requests: Any, answers: Any, decided: Any) -> None:
        if self.on_calls is not None:
            self.on_calls(requests, answers, decided)

    def _transaction(self, row: Any) -> None:
        if self.on_transaction is not None:
            self.on_transaction(row)
        if not self.txns:
            return
        frames = {int(x) for x in (row.frames or "").split()}
        opens = row.write_req_frame
        closes = (row.read_res_frame or row.write_res_frame) if row.closed_by in FINAL_ANSWER else None
        frames.update(f for f in (opens, closes) if f is not None)
        params, errors, closed_by = row.params or "", row.errors or "", row.closed_by or ""
        for frame in sorted(frames):
            role = OPEN if frame == opens else CLOSE if frame == closes else ""
            self.spool.append((_TXN, frame, row.txn, row.verdict or "", role, params, errors, closed_by,
                               row.b5_retries or 0))

    def _finding(self, row: Any) -> None:
        if row.frame is not None:
            self.spool.append((_FINDING, row.frame, row.severity or "", row.rule or "", row.name or "",
                               row.message or "", row.field or "", _text(row.value), _text(row.expected),
                               row.source or ""))

    def add_table(self, name: str, table: object) -> None:
        """The columnar path's rows as pyarrow tables: read row by row as the per-frame path gives them."""
        if self.on_table is not None:
            self.on_table(name, table)
            if name == "parameters" or (name == "transactions" and not self.txns):
                return  # nothing of theirs is noted at a frame
        row_type = {"transactions": TransactionRow, "parameters": ParameterRow, "findings": FindingRow}.get(name)
        if row_type is None:
            return
        columns = [table.column(f).to_pylist() for f in row_type._fields]  # type: ignore[attr-defined]
        sink = getattr(self, name)
        take = self.on_transaction
        if self.on_table is not None and name == "transactions":
            self.on_transaction = None  # on_table had them
        try:
            for values in zip(*columns, strict=True):
                sink.append(row_type._make(values))
        finally:
            self.on_transaction = take

    def extend(self, other: Rows, offset: int) -> None:  # pragma: no cover - one capture, one process
        raise NotImplementedError("frame notes are collected in one process")


def _text(value: object) -> str:
    return "" if value is None else str(value)


class _Sink:
    """A table attribute of Rows that hands each row to a function (or drops it)."""

    def __init__(self, take: Callable[[Any], None] | None) -> None:
        self.take = take

    def append(self, row: Any) -> None:
        if self.take is not None:
            self.take(row)

    def extend(self, rows: Any) -> None:
        for row in rows:
            self.append(row)


class NotesUpto(Protocol):
    """What reads a capture's notes a batch at a time, in frame order (Notes; copy_filter.NotesAhead)."""

    def upto(self, last: int) -> list[FrameNote]: ...


class Notes:
    """The notes of one capture, read once in frame order (`at`, for frames asked in increasing order, or
    iteration); `captures` says how the analysis went (its error, if the file is damaged)."""

    def __init__(self, spool: Spool, captures: list[CaptureResult], names: pt.Names = pt.PROFIDRIVE_NAMES) -> None:
        self.captures = captures
        self.names = names
        self._spool = spool
        self._entries = (entry for chunk in spool.chunks(_MEMORY_ROWS) for entry in chunk)
        self._next: tuple | None = next(self._entries, None)

    def at(self, frame: int) -> FrameNote | None:
        """The note of `frame` (None when the analysis says nothing of it); frames asked in increasing order."""
        entry = self._next
        while entry is not None and entry[1] < frame:
            entry = next(self._entries, None)
        note = None
        while entry is not None and entry[1] == frame:
            note = note or FrameNote(frame, names=self.names)
            if entry[0] == _TXN:
                note.txns.append(TxnNote(*entry[2:]))
            else:
                note.findings.append(FindingNote(*entry[2:]))
            entry = next(self._entries, None)
        self._next = entry
        return note

    def upto(self, last: int) -> list[FrameNote]:
        """The notes of the frames up to `last` not read yet, in frame order."""
        out = []
        while self._next is not None and self._next[1] <= last:
            note = self.at(self._next[1])
            if note is not None:
                out.append(note)
        return out

    def __iter__(self) -> Iterator[FrameNote]:
        while self._next is not None:
            note = self.at(self._next[1])
            if note is not None:
                yield note

    def close(self) -> None:
        self._entries.close()
        self._spool.close()

    def errors_besides(self, known: list[str]) -> list[str]:
        """The analysis's capture errors ('path: error') not among `known` (the copy met some itself)."""
        return [e for e in (f"{c.path}: {c.error}" for c in self.captures if c.error) if e not in known]


def collect(path: str, settings: Settings, on_transaction: Callable[[Any], None] | None = None,
            on_parameter: Callable[[Any], None] | None = None, on_calls: Callable[..., None] | None = None,
            txns: bool = True, on_table: Callable[[str, Any], None] | None = None) -> Notes:
    """Analyse one capture (as `report` does) and sort what it says by frame; `on_transaction` and
    `on_parameter` see the transactions' and parameters' rows as they close (with `on_table`, only those
    made one by one: `on_table` has the engine's tables whole), `on_calls` the calls paired
    (Rows.add_calls); `txns` False: only the findings are noted at their frames."""
    from pd_analyze.analysis.jobs import run

    spool = Spool(_key, _MEMORY_ROWS)
    rows = _NoteRows(spool, on_transaction, on_parameter, on_calls, txns, on_table)
    try:
        captures = run([path], rows, settings)
    except BaseException:
        spool.close()
        raise
    return Notes(spool, captures, rows.names)

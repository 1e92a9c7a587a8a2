"""Parameter state: per device, DO, PNU and subindex, the value the capture last confirmed written, the value
it last read back, and how the writes ended.

The state is folded from the rows of the `transactions` and `parameters` tables, whichever path made them
(rows one by one, or the columnar path's pyarrow tables), so a capture analysed either way gives the same
state. A fold is independent of the order the rows come in: "last" is the largest (txn, place of the
address in its request), and transactions are numbered in the order of their write requests in both
paths. What is kept is one entry per array element seen, never a row per frame or per transaction:
`StateRows` folds the rows as the analysis closes them and drops them, so memory stays flat in the
capture's size.

Rules (issue "Audit a commissioning"): each element of an array access is its own subindex row; a
VisibleString, OctetString or UnicodeString access is one value in the row of its first subindex. A write
is confirmed by a positive change response, or by a 0x82 negative response that answers it without error
(a Zero block); refused when its block, or the whole request (a header-level error, `*:0x..` in
`transactions.errors`), carries a PROFIdrive error; unconfirmed when the transaction ended without a
parameter response (timeout, pnio_error, malformed, reference_mismatch). Only the Value attribute is state:
Description and Text reads are not.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from operator import attrgetter
from typing import TYPE_CHECKING, Any, NamedTuple

from pd_analyze.analysis.jobs import run
from pd_analyze.analysis.param_values import cells_agree, one_value, split_cell
from pd_analyze.analysis.rows import Rows, _shifted, _shifted_table
from pd_analyze.analysis.schema import TIME, Column, time_series
from pd_analyze.analysis.stations import merged
from pd_analyze.model import pd_values as pt
from pd_analyze.model.times import NS, nanos
from pd_analyze.model.verdicts import ANSWERED

if TYPE_CHECKING:
    import pandas as pd

    from pd_analyze.analysis.capture_run import CaptureResult, Progress, Settings
    from pd_analyze.model.rules import Finding

Key = tuple[str, int, int, int]  # device, DO, PNU, subindex
VALUE = "Value"
CHANGE, READ = f"0x{pt.REQ_CHANGE:02x}", f"0x{pt.REQ_READ:02x}"  # the req_id cells of transactions

# The table's columns, declared once (name, dtype as schema.Column, description)
STATE_COLUMNS: tuple[Column, ...] = tuple(Column(*c) for c in (
    ("device", "category", "drive IP address"),
    ("station", "string", "the drive's station name as it announced it (PN-DCP), empty when the capture has none"),
    ("do", "Int64", "DO-ID"), ("pnu", "Int64", "parameter number"), ("subindex", "Int64", "array element"),
    ("param", "string", "P<pnu>[<subindex>]"),
    ("name", "string", "profile parameter name (PNU 900-999), empty when unknown"),
    ("format", "category", "data type of the value last seen on the wire"),
    ("value", "string", "the value the capture last saw: the later of the last confirmed write and the last read"),
    ("written", "string", "last value confirmed written (positive change response, or no error inside a 0x82)"),
    ("written_capture", "category", "capture of that write"),
    ("written_frame", "Int64", "its write request frame"), ("written_t", TIME, "its time"),
    ("read", "string", "last value read back"), ("read_capture", "category", "capture of that read"),
    ("read_frame", "Int64", "frame of the read response carrying it"), ("read_t", TIME, "its time"),
    ("agrees", "boolean", "the last read after the last confirmed write shows its value (empty: no read after it)"),
    ("writes", "Int64", "change requests addressing the element"),
    ("refused", "Int64", "writes refused with a PROFIdrive error"),
    ("unconfirmed", "Int64", "writes that ended without a parameter response (timeout, PNIO error, ...)"),
    ("last_error", "string", "PROFIdrive error of the last refused write (0x..)"),
    ("last_error_text", "string", "its meaning"),
    ("refused_frame", "Int64", "write request frame of the last refused write"),
))
STATE_ROW = NamedTuple("StateRow", [(c.name, object) for c in STATE_COLUMNS])


class Seen(NamedTuple):
    """One value of one element on the wire."""

    order: tuple[int, int]  # (txn, place of the address in its request): the larger is the later
    value: str | None
    fmt: str
    capture: str
    frame: int | None
    t: int | None  # nanoseconds since the epoch (model.times)
    note: str = ""  # refused: "0x02 low or high limit exceeded"; unconfirmed: the verdict


def _later(old: Seen | None, new: Seen) -> Seen:
    return new if old is None or new.order > old.order else old


@dataclass(slots=True)
class ElementState:
    """What the capture shows of one element of one drive's parameter."""

    written: Seen | None = None  # last confirmed write
    read: Seen | None = None  # last value read back
    refused: Seen | None = None  # last refused write (note: its error)
    unconfirmed: Seen | None = None  # last write without a parameter response (note: its verdict)
    writes: int = 0
    n_refused: int = 0
    n_unconfirmed: int = 0

    @property
    def last(self) -> Seen | None:
        """The value the capture last saw: the later of the last confirmed write and the last read."""
        if self.written is None or self.read is None:
            return self.written or self.read
        return self.read if self.read.order > self.written.order else self.written

    @property
    def agrees(self) -> bool | None:
        w, r = self.written, self.read
        if w is None or r is None or r.order < w.order:
            return None
        return cells_agree(w.fmt, w.value, r.fmt, r.value)


class TxnInfo(NamedTuple):
    """What a parameter row needs of its transaction's row."""

    capture: str
    req_id: str
    verdict: str
    errors: str
    write_req_frame: int | None
    read_res_frame: int | None
    t_start: int | None  # nanoseconds
    t_total: float | None  # seconds (the exact nanoseconds / 1e9)


TXN_FIELDS = ("txn", *TxnInfo._fields)
PARAM_FIELDS = ("txn", "device", "do", "pnu", "subindex", "elements", "attribute", "format", "values_written",
                "values_read", "error", "error_text")


class ParamCells(NamedTuple):
    txn: int
    device: str
    do: int | None
    pnu: int | None
    subindex: int | None
    elements: int | None
    attribute: str | None
    format: str | None
    values_written: str | None
    values_read: str | None
    error: str | None
    error_text: str | None


@dataclass
class StateTable:
    """The state of every element seen, folded from table rows in any order of transactions."""

    elements: dict[Key, ElementState] = field(default_factory=dict)
    stations: dict[str, str] = field(default_factory=dict)  # device IP -> station name (analysis.stations)
    pending: dict[int, list[ParamCells]] = field(default_factory=dict)  # rows whose transaction row is to come
    names: pt.Names = pt.PROFIDRIVE_NAMES  # what the run's profile calls parameters (Checker.names)
    digits: dict[str, int] = field(default_factory=dict)  # each capture's resolution (Rows.digits)

    def add(self, txns: dict[int, TxnInfo], params: Iterable[ParamCells]) -> None:
        """Parameter rows and the rows of their transactions (a transaction's rows all in one call)."""
        place: dict[int, int] = {}
        for p in params:
            info = txns.get(p.txn)
            if info is None:
                self.pending.setdefault(p.txn, []).append(p)
                continue
            k = place[p.txn] = place.get(p.txn, -1) + 1
            self._row(info, p, k)
        for txn in list(self.pending):
            if txn in txns:
                for k, p in enumerate(self.pending.pop(txn)):
                    self._row(txns[txn], p, k)

    def add_rows(self, transactions: Iterable[tuple], parameters: Iterable[tuple]) -> None:
        """Rows as `Rows` makes them (named tuples; times in integer nanoseconds)."""
        get = attrgetter(*TXN_FIELDS)
        txns = {}
        for r in transactions:
            txn, capture, req_id, verdict, errors, wframe, rframe, t_start, t_total = get(r)
            txns[txn] = TxnInfo(capture, req_id, verdict, errors or "", wframe, rframe, nanos(t_start), t_total)
        self.add(txns, map(ParamCells._make, map(attrgetter(*PARAM_FIELDS), parameters)))

    def add_tables(self, transactions: Iterable[Any], parameters: Iterable[Any]) -> None:
        """The columnar path's pyarrow tables (table_batches.batch_schema; times in nanoseconds)."""
        import pyarrow as pa

        txns = {}
        for table in transactions:
            cols = [table.column(n) for n in TXN_FIELDS]
            i = TXN_FIELDS.index("t_start")
            cols[i] = cols[i].cast(pa.int64())
            for txn, *rest in zip(*(c.to_pylist() for c in cols), strict=True):
                txns[txn] = TxnInfo(*rest)
        cells = (ParamCells._make(row) for table in parameters
                 for row in zip(*(table.column(n).to_pylist() for n in PARAM_FIELDS), strict=True))
        self.add({k: v._replace(errors=v.errors or "") for k, v in txns.items()}, cells)

    def _state(self, key: Key) -> ElementState:
        st = self.elements.get(key)
        if st is None:
            st = self.elements[key] = ElementState()
        return st

    def _row(self, info: TxnInfo, p: ParamCells, k: int) -> None:
        if p.attribute != VALUE or p.pnu is None or p.subindex is None or p.do is None:
            return  # Description and Text are no state; a request without addresses names no parameter
        fmt = p.format or ""
        n = 1 if one_value(fmt) else max(p.elements or 0, 1)
        order = (p.txn, k)
        if info.req_id == CHANGE:
            self._write(info, p, fmt, n, order)
        elif info.req_id == READ and info.verdict in ANSWERED and not p.error and p.values_read:
            values = split_cell(fmt, p.values_read)
            if len(values) != n and len(values) != 1:
                return  # as the engine's values read (transaction.elements_read): nothing to assign
            # (t_total is a whole number of nanoseconds / 1e9: times 1e9 and rounded, those nanoseconds again)
            t = None if info.t_start is None or info.t_total is None else info.t_start + round(info.t_total * NS)
            for j, value in enumerate(values):
                seen = Seen(order, value, fmt, info.capture, info.read_res_frame, t)
                st = self._state((p.device, p.do, p.pnu, p.subindex + j))
                st.read = _later(st.read, seen)

    def _write(self, info: TxnInfo, p: ParamCells, fmt: str, n: int, order: tuple[int, int]) -> None:
        values = split_cell(fmt, p.values_written)
        error, text = p.error or "", p.error_text or ""
        if info.errors.startswith("*:"):  # a header-level error refused the whole request (protocol.md 3.3)
            error = info.errors[2:].split()[0]
            text = pt.error_text(int(error, 16)) if error.startswith("0x") else ""
        for j in range(n):
            seen = Seen(order, values[j] if j < len(values) else None, fmt, info.capture, info.write_req_frame,
                        info.t_start)
            st = self._state((p.device, p.do, p.pnu, p.subindex + j))
            st.writes += 1
            if error:
                st.n_refused += 1
                st.refused = _later(st.refused, seen._replace(note=f"{error} {text}".strip()))
            elif info.verdict in ANSWERED:
                st.written = _later(st.written, seen)
            else:
                st.n_unconfirmed += 1
                st.unconfirmed = _later(st.unconfirmed, seen._replace(note=info.verdict))

    # --- the table ----------------------------------------------------------------------------------------
    def ordered(self) -> list[Key]:
        """The elements in table order: device (as an address), DO, PNU, subindex."""
        return sorted(self.elements, key=lambda k: (device_order(k[0]), k[1], k[2], k[3]))

    def rows(self) -> Iterator[tuple]:
        for key in self.ordered():
            yield state_row(key, self.elements[key], self.stations.get(key[0], ""), self.names)

    def frame(self) -> pd.DataFrame:
        return state_frame(list(self.rows()))


def state_row(key: Key, st: ElementState, station: str = "", names: pt.Names = pt.PROFIDRIVE_NAMES) -> tuple:
    device, do, pnu, sub = key
    w, r, last, ref = st.written, st.read, st.last, st.refused
    err, _, err_text = (ref.note.partition(" ") if ref is not None else ("", "", ""))
    fmt = last.fmt if last is not None else (ref or st.unconfirmed or Seen((0, 0), None, "", "", None, None)).fmt
    return STATE_ROW(
        device, station, do, pnu, sub, f"P{pnu}[{sub}]", names.pnu(pnu), fmt, last.value if last else None,
        w.value if w else None, w.capture if w else None, w.frame if w else None, w.t if w else None,
        r.value if r else None, r.capture if r else None, r.frame if r else None, r.t if r else None,
        st.agrees, st.writes, st.n_refused, st.n_unconfirmed, err, err_text, ref.frame if ref else None)


def state_frame(rows: list[tuple]) -> pd.DataFrame:
    """The typed DataFrame of state rows (times from nanoseconds, exactly)."""
    import pandas as pd

    df = pd.DataFrame.from_records(rows, columns=[c.name for c in STATE_COLUMNS])
    for c in STATE_COLUMNS:
        if c.dtype == TIME:
            df[c.name] = time_series([nanos(v) for v in df[c.name]], df.index)
        else:
            df[c.name] = df[c.name].astype(c.dtype)
    return df


def device_order(device: str) -> tuple:
    parts = device.split(".")
    if len(parts) == 4 and all(p.isdigit() for p in parts):
        return (0, *map(int, parts))
    return (1, device)


class StateRows(Rows):
    """Rows folded into a StateTable as the analysis hands them on, then dropped (flat memory).

    `inner`, when given, receives every row as well (audit collects its findings beside the state)."""

    FOLD_ROWS = 4096  # parameter rows held before they are folded

    def __init__(self, inner: Rows | None = None) -> None:
        super().__init__()
        self.state = StateTable()
        self.inner = inner

    def add_finding(self, capture: str, f: Finding, txn: int | None = None) -> None:
        if self.inner is not None:
            self.inner.add_finding(capture, f, txn)

    def note_digits(self, capture: str, digits: int) -> None:
        super().note_digits(capture, digits)
        if self.inner is not None:
            self.inner.note_digits(capture, digits)

    def use_names(self, names: pt.Names) -> None:
        super().use_names(names)
        self.state.names = names
        if self.inner is not None:
            self.inner.use_names(names)

    def add_table(self, name: str, table: object) -> None:
        if name in ("transactions", "parameters"):
            super().add_table(name, table)
        if self.inner is not None:
            self.inner.add_table(name, table)

    def batch_done(self) -> None:
        self.fold()
        if self.inner is not None:
            self.inner.batch_done()

    def extend(self, other: Rows, offset: int) -> None:
        """A worker's rows (a file or part of one), its transaction numbers shifted by `offset`."""
        if self.inner is not None:
            self.inner.extend(other, offset)
        for capture, digits in other.digits.items():
            Rows.note_digits(self, capture, digits)
        self.transactions.extend(_shifted(other.transactions, offset))
        self.parameters.extend(_shifted(other.parameters, offset))
        for name in ("transactions", "parameters"):
            for table in other.tables.get(name, ()):
                Rows.add_table(self, name, _shifted_table(table, offset))
        self.fold()

    def fold(self) -> None:
        """Fold what is held into the state and drop it."""
        if self.transactions or self.parameters:
            self.state.add_rows(self.transactions, self.parameters)
            self.transactions.clear()
            self.parameters.clear()
        if self.tables:
            self.state.add_tables(self.tables.get("transactions", ()), self.tables.get("parameters", ()))
            self.tables.clear()


def state_of(rows: Rows, stations: Mapping[str, str] | None = None) -> StateTable:
    """The state of an analysis' rows (Analysis.rows: rows made one by one and the columns' tables), with the
    captures' station names (IP address -> name; analysis.stations.merged)."""
    table = StateTable(stations=dict(stations or {}), names=rows.names, digits=rows.digits)
    table.add_rows(rows.transactions, rows.parameters)
    table.add_tables(rows.tables.get("transactions", ()), rows.tables.get("parameters", ()))
    return table


def collect(files: list[str], settings: Settings, progress: Progress | None = None, jobs: int = 1,
            chain: bool = False, inner: Rows | None = None) -> tuple[StateTable, list[CaptureResult]]:
    """The parameter state of captures, folded while they are read (`inner`: see StateRows)."""
    rows = StateRows(inner)
    results = run(files, rows, settings, progress, jobs, chain)
    rows.fold()
    rows.state.stations = merged(results)
    rows.state.digits = rows.digits
    return rows.state, results

"""`pd-analyze extract`: only the frames of the selected transactions, in the capture's own format, for a
drive vendor's support.

A transaction is selected when it passes every criterion given (a list within one criterion is "any of"):
its verdict, a parameter number it addresses, its device, its number (the report's txn), and with a display
filter any frame of it matching. Exactly the frames the report names are written: its `frames` column, every
frame that belongs to the transaction (requests, responses, B5 answers, RPC and IP fragments, retransmitted
requests, duplicate answers and mirror copies, a Write-Multiple's frames in each transaction it opens). One
rule for both, so `report` on the written file finds the same transactions with the same verdicts; the
liveness PDUs of a call (ping, working, FACK, ack) are no transaction's frames and are not written.

A pcap is written as a pcap (its file header, then the chosen records as they are), a pcapng as a pcapng
(every section header, interface description and other non-packet block kept, then the chosen packet
blocks as they are): times, lengths and bytes are the input's.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pd_analyze.analysis.capture_run import CaptureResult, Settings
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.table_batches import rows_to_batch
from pd_analyze.capture import CaptureError
from pd_analyze.capture.records import CaptureCopy
from pd_analyze.model.verdicts import VERDICTS
from pd_analyze.output import frame_notes
from pd_analyze.output.capture_copy import Copied, UsageError, check_paths, dissector_for, frames, output
from pd_analyze.output.copy_filter import matching
from pd_analyze.output.display_filter import DisplayFilter


@dataclass(frozen=True)
class Selection:
    """What `extract` keeps; an empty criterion does not restrict."""

    verdicts: frozenset[str] = frozenset()
    pnus: frozenset[int] = frozenset()
    devices: frozenset[str] = frozenset()
    txns: frozenset[int] = frozenset()
    flt: DisplayFilter | None = None

    def __post_init__(self) -> None:
        unknown = sorted(self.verdicts - set(VERDICTS))
        if unknown:
            raise UsageError(f"--verdict: {', '.join(unknown)} is not a verdict ({', '.join(VERDICTS)})")

    def row_passes(self, row: Any) -> bool:
        """A transaction row against the criteria of the transactions table (the PNUs are its parameters')."""
        return ((not self.verdicts or row.verdict in self.verdicts)
                and (not self.devices or row.device in self.devices)
                and (not self.txns or row.txn in self.txns))


def numbers(text: str, what: str) -> frozenset[int]:
    """'964,0x3c4, 2000' as integers; UsageError naming the option otherwise."""
    out = set()
    for item in _items(text):
        try:
            out.add(int(item, 0))
        except ValueError:
            raise UsageError(f"{what}: {item!r} is not a number (decimal or 0x hex)") from None
    return frozenset(out)


def words(text: str) -> frozenset[str]:
    return frozenset(_items(text))


def _items(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def extract(capture: str, out: str, settings: Settings, selection: Selection) -> Copied:
    """Write the frames of the selected transactions of `capture` to `out`: one analysis names them (the
    transactions table's `frames`), then the records are copied, none dissected; a display filter reads
    the capture once more, judging only the frames of transactions the other criteria keep."""
    check_paths(capture, out)
    chosen, captures = _chosen(capture, settings, selection)
    wanted = chosen.frames()
    result = Copied(out, transactions=chosen.count())
    with CaptureCopy(capture) as copy, output(out) as stream:
        stream.write(copy.header)
        at, end = 0, len(wanted)
        try:
            for block in copy.blocks():
                number = block.number
                if not number:  # a pcapng's section, interface and other blocks
                    stream.write(block.raw)
                    continue
                while at < end and wanted[at] < number:
                    at += 1
                if at < end and wanted[at] == number:
                    stream.write(block.raw)
                    result.frames += 1
        except CaptureError as exc:
            result.errors.append(str(exc))
    known = result.errors
    result.errors += [e for e in (f"{c.path}: {c.error}" for c in captures if c.error) if e not in known]
    return result


class _Chosen:
    """The transactions the tables' criteria keep, as they close: each kept transaction's frames (its
    `frames` cell with the frames that open and close it), as two flat integer columns (frame, txn), and
    the transactions with a parameter of a chosen PNU. Memory: 16 bytes a frame of a kept transaction."""

    def __init__(self, selection: Selection) -> None:
        self.selection = selection
        self._frames: list[np.ndarray] = []
        self._txns: list[np.ndarray] = []
        self._with_pnu: list[np.ndarray] = []
        self._only: np.ndarray | None = None  # the transactions a display filter kept (None: no filter)

    def table(self, name: str, table: pa.Table) -> None:
        if name == "transactions":
            self._transactions(table)
        elif name == "parameters" and self.selection.pnus:
            kept = table.filter(pc.is_in(table.column("pnu"), pa.array(sorted(self.selection.pnus), pa.int64())))
            self._with_pnu.append(kept.column("txn").to_numpy(zero_copy_only=False))

    def _transactions(self, table: pa.Table) -> None:
        s = self.selection
        mask = None
        for column, chosen in (("verdict", s.verdicts), ("device", s.devices), ("txn", s.txns)):
            if chosen:
                values = pa.array(sorted(chosen), table.schema.field(column).type)
                test = pc.fill_null(pc.is_in(table.column(column), values), False)
                mask = test if mask is None else pc.and_(mask, test)
        if mask is not None:
            table = table.filter(mask)
        if not table.num_rows:
            return
        cells = pc.split_pattern(pc.fill_null(table.column("frames"), ""), " ")
        flat = pc.list_flatten(cells)
        owner = pc.list_parent_indices(cells).to_numpy()
        nonempty = pc.greater(pc.utf8_length(flat), 0)
        frames = pc.cast(flat.filter(nonempty), pa.int64()).to_numpy()
        txn = table.column("txn").to_numpy(zero_copy_only=False)
        owner = owner[nonempty.to_numpy(zero_copy_only=False)]
        # the frames that open and close it, as its notes have them (frame_notes), should a cell lack them
        closes = pc.if_else(pc.is_in(table.column("closed_by"), pa.array(sorted(frame_notes.FINAL_ANSWER))),
                            pc.coalesce(table.column("read_res_frame"), table.column("write_res_frame")), None)
        ends = [table.column("write_req_frame").to_numpy(zero_copy_only=False).astype(float),
                closes.to_numpy(zero_copy_only=False).astype(float)]
        end_frames = np.concatenate(ends)
        end_owner = np.tile(np.arange(table.num_rows), 2)
        known = ~np.isnan(end_frames)
        self._frames += [frames, end_frames[known].astype(np.int64)]
        self._txns += [txn[owner], txn[end_owner[known]]]

    def rows(self, rows: Rows) -> None:
        """Rows made one by one (a capture name Arrow cannot hold): as a table each."""
        for name in ("transactions", "parameters"):
            made = getattr(rows, name)
            if made:
                self.table(name, _as_table(name, made))
                made.clear()

    def row(self, name: str) -> Callable[[Any], None]:
        """A row made one by one, as a table of one row."""
        return lambda row: self.table(name, _as_table(name, [row]))

    def keep_only(self, txns: set[int]) -> None:
        self._only = np.fromiter(txns, np.int64, len(txns))

    def _kept(self) -> tuple[np.ndarray, np.ndarray]:
        frames = np.concatenate(self._frames) if self._frames else np.zeros(0, np.int64)
        txns = np.concatenate(self._txns) if self._txns else np.zeros(0, np.int64)
        keep = np.ones(len(txns), bool)
        if self.selection.pnus:
            keep &= np.isin(txns, np.concatenate(self._with_pnu) if self._with_pnu else np.zeros(0, np.int64))
        if self._only is not None:
            keep &= np.isin(txns, self._only)
        return frames[keep], txns[keep]

    def frames(self) -> np.ndarray:
        """The frames to write, sorted, each once."""
        return np.unique(self._kept()[0])

    def candidates(self) -> dict[int, list[int]]:
        """The transactions each frame of a kept transaction belongs to (what a display filter judges)."""
        out: dict[int, list[int]] = {}
        for frame, txn in zip(*(a.tolist() for a in self._kept()), strict=True):
            out.setdefault(frame, []).append(txn)
        return out

    def count(self) -> int:
        return len(np.unique(self._kept()[1]))


def _as_table(name: str, rows: list) -> pa.Table:
    """Rows made one by one as a table (the capture's name left out: Arrow may not hold it, and no
    criterion reads it)."""
    return rows_to_batch(name, [row._replace(capture="") for row in rows])


class _ChosenRows(Rows):
    """The analysis's rows handed to `_Chosen` as they come, nothing held (findings and changes dropped)."""

    def __init__(self, chosen: _Chosen) -> None:
        super().__init__()
        self.chosen = chosen

    def add_table(self, name: str, table: object) -> None:
        self.chosen.table(name, table)  # type: ignore[arg-type]

    def batch_done(self) -> None:
        super().batch_done()
        self.chosen.rows(self)
        self.findings.clear()
        self.changes.clear()


def _chosen(capture: str, settings: Settings, selection: Selection) -> tuple[_Chosen, list[CaptureResult]]:
    """The selected transactions: the tables' criteria in one analysis; with a display filter, those of
    them with a frame it matches, read in a second pass that judges only their frames."""
    from pd_analyze.analysis.jobs import run

    chosen = _Chosen(selection)
    flt = selection.flt
    if flt is not None and flt.needs_analysis:  # txn.* and finding.* need the notes of every frame
        notes = frame_notes.collect(capture, settings, chosen.row("transactions"), chosen.row("parameters"),
                                    on_table=chosen.table)
        captures = notes.captures
    else:
        captures = run([capture], _ChosenRows(chosen), settings)
        notes = None
    try:
        if flt is not None:
            chosen.keep_only(_matching(capture, settings, flt, notes, chosen.candidates()))
        return chosen, captures
    finally:
        if notes is not None:
            notes.close()


def _matching(capture: str, settings: Settings, flt: DisplayFilter, notes: frame_notes.Notes | None,
              candidates: dict[int, list[int]]) -> set[int]:
    """Transactions with a frame the filter matches, among `candidates` (frame: its kept transactions): the
    filter judged on the columns where it can be, else frame by frame on the records and trees."""
    found: set[int] = set()
    matched = matching(capture, settings, flt, notes)
    if matched is not None:  # judged on the columns (output.copy_filter)
        for frame in matched:
            txns = candidates.get(frame)
            if txns is not None:
                found.update(txns)
        return found
    with CaptureCopy(capture) as copy:
        try:
            for _block, view in frames(copy, dissector_for(settings, flt), notes):
                if view is not None and view.number in candidates and flt.matches(view):
                    found.update(candidates[view.number])
        except CaptureError:
            pass  # the copy pass reports it
    return found


def selection_of(verdicts: Iterable[str], pnus: Iterable[int], devices: Iterable[str], txns: Iterable[int],
                 flt: DisplayFilter | None) -> Selection:
    return Selection(frozenset(verdicts), frozenset(pnus), frozenset(devices), frozenset(txns), flt)

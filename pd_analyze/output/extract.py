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

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from pd_analyze.analysis.capture_run import Settings
from pd_analyze.capture import CaptureError
from pd_analyze.capture.records import CaptureCopy
from pd_analyze.model.verdicts import VERDICTS
from pd_analyze.output import frame_notes
from pd_analyze.output.capture_copy import Copied, UsageError, check_paths, dissector_for, frames, output
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
    """Write the frames of the selected transactions of `capture` to `out`."""
    check_paths(capture, out)
    chosen = _chosen(capture, settings, selection)
    result = Copied(out, transactions=len(chosen))
    notes = frame_notes.collect(capture, settings)
    try:
        with CaptureCopy(capture) as copy, output(out) as stream:
            stream.write(copy.header)
            try:
                for block, view in frames(copy, dissector_for(settings, None, always=True), notes):
                    if view is None:
                        stream.write(block.raw)
                        continue
                    if view.note is None or not any(t.txn in chosen for t in view.note.txns):
                        continue
                    stream.write(block.raw)
                    result.frames += 1
            except CaptureError as exc:
                result.errors.append(str(exc))
    finally:
        notes.close()
    result.errors += notes.errors_besides(result.errors)
    return result


def _chosen(capture: str, settings: Settings, selection: Selection) -> set[int]:
    """The numbers of the selected transactions: the tables' criteria in one analysis; with a display
    filter, those of them with a matching frame, read in a second pass. Only numbers are held."""
    passing: set[int] = set()
    with_pnu: set[int] = set()

    def on_parameter(row: Any) -> None:
        if row.pnu is not None and int(row.pnu) in selection.pnus:
            with_pnu.add(row.txn)

    def on_transaction(row: Any) -> None:
        if selection.row_passes(row):
            passing.add(row.txn)

    notes = frame_notes.collect(capture, settings, on_transaction, on_parameter if selection.pnus else None)
    try:
        chosen = passing & with_pnu if selection.pnus else passing
        return chosen if selection.flt is None else chosen & _matching(capture, settings, selection.flt, notes)
    finally:
        notes.close()


def _matching(capture: str, settings: Settings, flt: DisplayFilter, notes: frame_notes.Notes) -> set[int]:
    """Transactions with a frame the filter matches."""
    found: set[int] = set()
    with CaptureCopy(capture) as copy:
        try:
            for _block, view in frames(copy, dissector_for(settings, flt), notes):
                if view is not None and view.note is not None and flt.matches(view):
                    found.update(t.txn for t in view.note.txns)
        except CaptureError:
            pass  # the copy pass reports it
    return found


def selection_of(verdicts: Iterable[str], pnus: Iterable[int], devices: Iterable[str], txns: Iterable[int],
                 flt: DisplayFilter | None) -> Selection:
    return Selection(frozenset(verdicts), frozenset(pnus), frozenset(devices), frozenset(txns), flt)

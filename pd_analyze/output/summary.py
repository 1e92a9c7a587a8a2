"""The report's text summary, accumulated row by row: counts, groupings and latency quantiles.

Fed the rows of the tables in the order they are added (not sorted: the report feeds them as they
close), it needs no DataFrame: counters per group, and per device the latency values as compact float
arrays (16 bytes a completed transaction), since exact quantiles need every value. Quantiles
interpolate linearly between the two nearest ranks, as pandas' (numpy's) default does. Ranked lists put
the largest count first; equal counts keep the order of their keys (device, DO, parameter, error; rule
and name), or, for the value counts, the order of first appearance in the table (by transaction, then
as added), which is remembered per value.
"""

from __future__ import annotations

import math
from array import array
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from pd_analyze.analysis.schema import capture_text, sort_key
from pd_analyze.analysis.stations import per_capture
from pd_analyze.model.rules import SEVERITIES
from pd_analyze.model.times import DEFAULT_DIGITS
from pd_analyze.model.verdicts import VERDICTS
from pd_analyze.output.summary_words import (
    FAILED,
    WHOLE_REQUEST,
    device_key,
    error_words,
    few,
    in_words,
    known,
    missing,
    ms,
    na_text,
    named,
    params_label,
    reason,
    refused_entries,
)
from pd_analyze.protocol.frames import ranked

if TYPE_CHECKING:
    from pd_analyze.analysis.capture_run import CaptureResult

TOP = 10
# Distinct entries itemised per list (failures per drive; NAKs by device, DO, parameter and error): a flood
# of distinct failures (every request another parameter set) is counted past it, not itemised, so the
# summary's memory stays bounded whatever the capture
ITEMISED = 10_000
_LAST = float("inf")


_TXN_ORDER = sort_key("transactions")
_PARAM_ORDER = sort_key("parameters")


def _order(key: tuple) -> tuple:
    """Sort key of a group key with missing parts last (as pandas sorts group keys)."""
    return tuple((missing(v), 0 if missing(v) else v) for v in key)


def _ranked(counts: dict, top: int) -> list[tuple[object, int]]:
    """Largest count first; ties in key order."""
    items = sorted(counts.items(), key=lambda kv: _order(kv[0] if isinstance(kv[0], tuple) else (kv[0],)))
    return sorted(items, key=lambda kv: -kv[1])[:top]


def _ranked_by_first(counts: dict, first: dict) -> list[tuple[object, int]]:
    """Largest count first; ties in the order of first appearance in the table."""
    return sorted(counts.items(), key=lambda kv: (-kv[1], first[kv[0]]))


def quantile(values: Sequence[float], q: float) -> float:
    """The q-quantile of sorted values, interpolated linearly (numpy's "linear" method, bit for bit)."""
    n = len(values)
    if n == 0:
        return math.nan
    at = (n - 1) * q
    if at >= n - 1:
        return values[-1]
    below = math.floor(at)
    a, b, t = values[below], values[below + 1], at - below
    diff = b - a
    return b - diff * (1 - t) if t >= 0.5 else a + diff * t


class Summary:
    """Accumulates the summary from table rows; `text()` renders it. Times are written at their capture's
    resolution (`digits`: Rows.digits, the same dict the run fills)."""

    # the verdicts listed per drive (a NAK by its refused parameters), and how many slowest transactions are
    # kept (for add_batch)
    FAILED = FAILED | {"nak"}
    SLOWEST = TOP
    WHOLE_REQUEST = WHOLE_REQUEST

    def __init__(self, digits: Mapping[str, int] | None = None) -> None:
        self.digits = {} if digits is None else digits
        self.transactions = 0
        self.verdicts: Counter[str] = Counter()
        self.any_failed = False
        self.failed: dict[str, Counter[str]] = {}
        self.naks: Counter[tuple] = Counter()
        self.by_error: Counter[str] = Counter()
        self.by_do: Counter[int] = Counter()
        # ("error" / "do" / "refused", value): first place in the table (ranked lists: equal counts in this order)
        self.first: dict[tuple[str, object], tuple] = {}
        self.b5_total = self.b5_transactions = 0
        self.b5_max: tuple[int, tuple, object] | None = None  # retries, place in the table, txn
        self.added = Counter()  # rows added per table: a row's place among equal keys
        # the names the parameters table gave parameters and error numbers (the run's profile's words)
        self.pnu_names: dict[int, str] = {}
        self.error_texts: dict[str, str] = {}
        # a device is (capture, address) until the text is written: station names are per capture (analysis.stations)
        self.latency: dict[tuple, tuple[array, array]] = {}  # device: t_total, t_write_rtt (seconds)
        # per drive (device, slot, DO): parameters that failed, timed out or were refused, by reason; past
        # ITEMISED distinct entries, their count per drive
        self.refused: Counter[tuple] = Counter()
        self.unitemised: Counter[tuple] = Counter()
        self.naks_unitemised = 0
        self.last_whole: object = None  # the transaction of the last whole-request error counted (once per request)
        self.slowest: list[tuple] = []  # (-t_total, place, device, slot, do, params, txn), the TOP slowest
        self.findings = 0
        self.severities: Counter[str] = Counter()
        self.rules: Counter[tuple[str, str]] = Counter()

    def add(self, table: str, rows: Iterable[tuple]) -> None:
        """Rows of one table, in the order they were added to it (the order of `Rows`' lists)."""
        if table == "transactions":
            self._transactions(rows)
        elif table == "parameters":
            self._parameters(rows)
        elif table == "findings":
            self._findings(rows)

    def _transactions(self, rows: Iterable[tuple]) -> None:
        for r in rows:
            self.transactions += 1
            self.added["transactions"] += 1
            verdict, device = r.verdict, (r.capture, r.device)
            if verdict in VERDICTS:
                self.verdicts[verdict] += 1
            if verdict != "ok":
                self.any_failed = True
                if verdict in VERDICTS and not missing(r.device):
                    self.failed.setdefault(device, Counter())[verdict] += 1
            b5 = r.b5_retries
            if not missing(b5):
                self.b5_total += b5
                if b5 > 0:
                    self.b5_transactions += 1
                place = (_TXN_ORDER(r), self.added["transactions"])
                if self.b5_max is None or b5 > self.b5_max[0] or (b5 == self.b5_max[0] and place < self.b5_max[1]):
                    self.b5_max = (b5, place, r.txn)
            self.drive_row(r.txn, self.added["transactions"], verdict, device, r.slot, r.do, r.params,
                           r.pnio_error_text, r.closed_by, r.b5_retries, r.t_total, r.t_last_read, r.errors, r.n_params)
            total = r.t_total
            if not missing(total) and not missing(r.device):
                totals, rtts = self.latency.setdefault(device, (array("d"), array("d")))
                totals.append(total)
                if not missing(r.t_write_rtt):
                    rtts.append(r.t_write_rtt)

    def drive_row(self, txn: object, number: int, verdict: object, device: object, slot: object, do: object,
                  params: object, status: object, closed_by: object, b5: object, total: object,
                  last_read: object = None, errors: object = None, n_params: object = None) -> None:
        """One transaction's part in the per-drive lists: a failure with its reason in words (a NAK: each
        parameter it refused, with the error), and its time among the slowest. `number`: its place among the
        rows added (ties in the order added)."""
        slot, do = (None if missing(v) else v for v in (slot, do))
        place = (_LAST if missing(txn) else txn, number)
        label = params_label(params, n_params)
        if verdict in FAILED:
            entries = [(label, reason(verdict, status, closed_by, b5, last_read, self._digits(device)))]
        elif verdict == "nak":  # each parameter refused; a negative answer that names no error, as such (Q8)
            entries = refused_entries(errors, label) or [(label, "refused: negative response without an error block")]
        else:
            entries = []
        for label, why in entries:
            key = (device_key(device), slot, do, label, why)
            if key not in self.refused and len(self.refused) >= ITEMISED:
                self.unitemised[key[:3]] += 1
                continue
            self.refused[key] += 1
            if place < self.first.get(("refused", key), (_LAST,)):
                self.first[("refused", key)] = place
        if not missing(total):
            entry = (-total, (_LAST if missing(txn) else txn, number), device_key(device), slot, do, label, txn)
            if len(self.slowest) < TOP:
                self.slowest.append(entry)
                self.slowest.sort(key=lambda e: (e[0], e[1]))
            elif (entry[0], entry[1]) < (self.slowest[-1][0], self.slowest[-1][1]):
                self.slowest[-1] = entry
                self.slowest.sort(key=lambda e: (e[0], e[1]))

    def _digits(self, device: object) -> int:
        """The resolution of a device's capture (a device is (capture, address))."""
        return self.digits.get(device_key(device)[0], DEFAULT_DIGITS)

    def _parameters(self, rows: Iterable[tuple]) -> None:
        first = self.first
        for r in rows:
            self.added["parameters"] += 1
            if r.pnu_name and not missing(r.pnu):
                self.pnu_names[r.pnu] = r.pnu_name
            err = r.error
            if missing(err) or err == "":
                continue
            self.error_text(err, r.error_text)
            param = r.param
            if r.whole_request is True:  # one error for the whole request: counted once, on its first row
                if r.txn == self.last_whole:
                    continue
                self.last_whole, param = r.txn, WHOLE_REQUEST
            self.count_nak(((r.capture, r.device), r.do, param, err), 1)
            place = (_PARAM_ORDER(r), self.added["parameters"])
            self.by_error[err] += 1
            if place < first.get(("error", err), (_LAST,)):
                first[("error", err)] = place
            do = r.do
            if not missing(do):
                self.by_do[do] += 1
                if place < first.get(("do", do), (_LAST,)):
                    first[("do", do)] = place

    def count_nak(self, key: tuple, n: int) -> None:
        """NAKs of one (device, DO, parameter, error): the error's text is added when written, one per number
        (`error_text`); past ITEMISED distinct ones, counted only."""
        if key in self.naks or len(self.naks) < ITEMISED:
            self.naks[key] += n
        else:
            self.naks_unitemised += n

    def error_text(self, error: str, text: object) -> None:
        """Remember an error number's words. Should a capture give one number two texts (a vendor's error
        word and the profile's number under one profile), the first in sort order: the same whatever order
        the rows come in."""
        if isinstance(text, str) and text:
            had = self.error_texts.get(error)
            self.error_texts[error] = text if had is None else min(had, text)

    def add_batch(self, table: str, batch: Any) -> None:
        """A pyarrow Table of batch_schema(table): the same as `add` of the same rows in the same order,
        counted a column at a time (pyarrow and numpy, imported here: the row path needs neither)."""
        from pd_analyze.output import summary_batches

        if not batch.num_rows:
            return
        if table == "transactions":
            summary_batches.transactions(self, batch)
        elif table == "parameters":
            summary_batches.parameters(self, batch)
        elif table == "findings":
            summary_batches.findings(self, batch)

    def _findings(self, rows: Iterable[tuple]) -> None:
        for r in rows:
            self.findings += 1
            if r.severity in SEVERITIES:
                self.severities[r.severity] += 1
            if not missing(r.rule) and not missing(r.name):
                self.rules[(r.rule, r.name)] += 1

    def text(self, captures: Sequence[CaptureResult], top: int = TOP) -> str:
        """Accounting per capture; verdicts; failures by device; NAKs; B5 retries; latency; findings. A device
        is named by its address and, where its capture has it, its PN-DCP station name (analysis.stations: two
        captures' drives at one address with different names are two devices)."""
        label_of = per_capture(captures)

        def label(device: tuple) -> str:
            return label_of(*device)

        failed, naks, refused, unitemised, latency = self._by_label(label)
        places: dict[str, int] = {}  # a device's resolution: the finest of its captures'
        for dev in self.latency:
            places[label(dev)] = max(places.get(label(dev), 0), self._digits(dev))

        lines = []
        for c in captures:
            acc = c.accounting
            line = (f"{capture_text(c.path)}: {acc.read} frames read = {acc.decoded} decoded + "
                    f"{sum(acc.skipped.values())} skipped + {sum(acc.malformed.values())} malformed; "
                    f"{c.transactions} transactions")
            lines.append(line + (f"; ERROR {c.error}" if c.error else ""))
            for kind, reasons in (("skipped", acc.skipped), ("malformed", acc.malformed)):
                if reasons:  # the invariant by reason: every frame is accounted for
                    lines.append(f"  {kind}: " + "; ".join(f"{n} {why}" for why, n in ranked(reasons)))
        lines.append("")
        if not self.transactions:  # the findings still count (a read without its write, a damaged record, ...)
            lines.append("No PROFIdrive transactions found.")
            return "\n".join(lines + self._findings_lines(top))
        lines.append(f"Transactions: {self.transactions}  "
                     + "  ".join(f"{v}={self.verdicts[v]}" for v in VERDICTS))
        if self.any_failed:
            lines.append("")
            lines.append("Failures by device (worst first):")
            totals = {dev: sum(c.values()) for dev, c in failed.items()}
            for dev, total in _ranked(totals, top):
                counts = failed[dev]  # type: ignore[index]
                detail = ", ".join(f"{v}={counts[v]}" for v in VERDICTS if counts[v])
                lines.append(f"  {dev:<16} {total:>6}  ({detail})")
        if self.naks or self.naks_unitemised:
            lines.append("")
            lines.append("NAKs by PNU and error number (worst first):")
            for (dev, do, param, err), n in _ranked(naks, top):  # type: ignore[misc]
                lines.append(f"  {n:>6}  {dev} DO {known(do)} {named(na_text(param), self.pnu_names)} "
                             f"error {error_words(na_text(err), self.error_texts)}")
            if self.naks_unitemised:
                lines.append(f"  ... and {self.naks_unitemised} more NAKs not itemised (the summary itemises "
                             f"{ITEMISED:,} distinct ones; the parameters table lists them all)")
            first = {k[1]: v for k, v in self.first.items() if k[0] == "error"}
            lines.append("  by error number: " + ", ".join(
                f"{e}={n}" for e, n in _ranked_by_first(self.by_error, first)))
            first = {k[1]: v for k, v in self.first.items() if k[0] == "do"}
            lines.append("  by DO: " + ", ".join(f"{d}={n}" for d, n in _ranked_by_first(self.by_do, first)))
        if self.refused or self.unitemised:
            lines.append("")
            lines.append("Failed, timed-out and refused parameters per drive (device, slot, DO; worst first):")
            drives: dict[tuple, dict[tuple, int]] = {drive: {} for drive in unitemised}
            firsts: dict[tuple, tuple] = {}
            for (dev, slot, do, params, why), (n, place) in refused.items():
                drives.setdefault((dev, slot, do), {})[(params, why)] = n
                firsts[(dev, slot, do, params, why)] = place
            totals = {drive: sum(entries.values()) + unitemised[drive] for drive, entries in drives.items()}
            for (dev, slot, do), total in _ranked(totals, top):  # type: ignore[misc]
                lines.append(f"  {dev} slot {known(slot)} DO {known(do)}: {total}")
                entries = drives[(dev, slot, do)]
                first = {entry: firsts[(dev, slot, do, *entry)] for entry in entries}
                for (params, why), n in _ranked_by_first(entries, first)[:top]:  # type: ignore[misc]
                    lines.append(f"    {n:>6}  {few(params, self.pnu_names)}: {in_words(why, self.error_texts)}")
                if len(entries) > top:
                    lines.append(f"    ... {len(entries) - top} more (the transactions and parameters tables list "
                                 "them all)")
                if unitemised[(dev, slot, do)]:
                    lines.append(f"    ... and {unitemised[(dev, slot, do)]} more failures not itemised (the "
                                 f"summary itemises {ITEMISED:,} distinct ones)")
            if len(totals) > top:
                lines.append(f"  ... {len(totals) - top} more drives")
        if self.slowest:
            lines.append("")
            lines.append("Slowest parameters, ms (write to final response):")
            times = [ms(-entry[0], self._digits(entry[2])) for entry in self.slowest]
            cell = max(8, *(len(text) for text in times))
            for text, (_neg, _place, dev, slot, do, params, txn) in zip(times, self.slowest, strict=True):
                lines.append(f"  {text:>{cell}}  {label(dev)} slot {known(slot)} DO {known(do)} "
                             f"{few(params, self.pnu_names)} (transaction {na_text(txn)})")
        lines.append("")
        lines.append(f"B5 retries: {self.b5_total} in {self.b5_transactions} transactions"
                     + (f" (max {self.b5_max[0]} in transaction {self.b5_max[2]})"
                        if self.b5_transactions and self.b5_max is not None else ""))
        if latency:
            lines.append("")
            lines.append("Latency per device, ms (write to final response; slowest first):")
            width = max(16, *(len(dev) for dev in latency))
            stats = []
            for dev in sorted(latency):
                totals, rtts = (sorted(a) for a in latency[dev])
                stats.append((dev, len(totals), quantile(totals, 0.5), quantile(totals, 0.9),
                              quantile(totals, 0.99), totals[-1], quantile(rtts, 0.5)))
            shown = [(dev, n, [ms(v, places[dev]) for v in values])
                     for dev, n, *values in sorted(stats, key=lambda s: -s[3])[:top]]
            # aligned at any resolution, two spaces apart at least
            cell = max(8, *(len(text) + 1 for _, _, texts in shown for text in texts[:4]))
            lines.append(f"  {'device':<{width}} {'n':>6} {'p50':>{cell}} {'p90':>{cell}} {'p99':>{cell}} "
                         f"{'max':>{cell}}  write rtt p50")
            for dev, n, (p50, p90, p99, most, w50) in shown:
                lines.append(f"  {dev:<{width}} {n:>6} {p50:>{cell}} {p90:>{cell}} {p99:>{cell}} {most:>{cell}}  {w50}")
        return "\n".join(lines + self._findings_lines(top))

    def _by_label(self, label: Callable[[tuple], str]) -> tuple[dict, Counter, dict, Counter, dict]:
        """The counters keyed by device, keyed by its label instead (devices of one name and address in several
        captures are one): failures by verdict, NAKs, the per-drive entries with their first place, the drives'
        counts not itemised, the latencies."""
        failed: dict[str, Counter[str]] = {}
        for dev, counts in self.failed.items():
            failed.setdefault(label(dev), Counter()).update(counts)
        naks: Counter[tuple] = Counter()
        for (dev, *rest), n in self.naks.items():
            naks[(label(dev), *rest)] += n
        refused: dict[tuple, tuple[int, tuple]] = {}
        for key, n in self.refused.items():
            merged_key = (label(key[0]), *key[1:])
            had, first = refused.get(merged_key, (0, (_LAST,)))
            refused[merged_key] = (had + n, min(first, self.first[("refused", key)]))
        unitemised: Counter[tuple] = Counter()
        for (dev, *rest), n in self.unitemised.items():
            unitemised[(label(dev), *rest)] += n
        latency: dict[str, tuple[array, array]] = {}
        for dev, (totals, rtts) in self.latency.items():
            got_totals, got_rtts = latency.setdefault(label(dev), (array("d"), array("d")))
            got_totals.extend(totals)
            got_rtts.extend(rtts)
        return failed, naks, refused, unitemised, latency

    def _findings_lines(self, top: int) -> list[str]:
        if not self.findings:
            return []
        return ["", f"Findings: {self.findings}  " + "  ".join(f"{s}={self.severities[s]}"
                                                               for s in ("error", "warning", "info")),
                *(f"  {n:>6}  {rule} {name}" for (rule, name), n in _ranked(self.rules, top))]

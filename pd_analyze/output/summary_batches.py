"""Summary.add_batch's counting, a column at a time: what Summary.add counts row by row, for a batch.

Each function takes the Summary and a pyarrow Table of one table's batch schema and leaves the Summary
as `add` of the same rows would: the same counters (incremented in order of first appearance), the same
first places (a row's place is its sort key, then its number among the rows added so far), the same
latency arrays in the same order.
"""

from __future__ import annotations

from array import array
from collections import Counter
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pd_analyze.model.rules import SEVERITIES
from pd_analyze.model.verdicts import VERDICTS

Summary = Any  # output.summary.Summary, which imports this module (when its add_batch is first called)

_LAST = float("inf")


def _values(strings: tuple[str, ...]) -> pa.Array:
    return pa.array(strings, pa.large_string())


def _mask(values: pa.ChunkedArray | pa.Array) -> np.ndarray:
    """A boolean column as numpy, missing as False."""
    return pc.fill_null(values, False).to_numpy(zero_copy_only=False) if len(values) else np.zeros(0, bool)


def _group_counts(table: pa.Table, keys: list[str]) -> list[tuple[tuple, int]]:
    """(key values, count) of each group, missing values as None, groups in order of first appearance.

    Each key's dictionary codes, folded into one group number per row by numpy, not Table.group_by: that
    loads pyarrow's query engine and datasets (some 20 ms of a report's start-up, issue #23)."""
    if not table.num_rows:
        return []
    group = np.zeros(table.num_rows, np.int64)
    columns = []
    for key in keys:
        encoded = pc.dictionary_encode(table.column(key), null_encoding="encode").combine_chunks()
        codes = encoded.indices.to_numpy()
        # renumbered after each key, so the group numbers stay below the rows (no overflow however many keys)
        group = np.unique(group * len(encoded.dictionary) + codes, return_inverse=True)[1].reshape(-1)
        columns.append((encoded.dictionary.to_pylist(), codes))
    _, first, counts = np.unique(group, return_index=True, return_counts=True)
    order = np.argsort(first, kind="stable")
    return [(tuple(values[codes[row]] for values, codes in columns), int(count))
            for row, count in zip(first[order].tolist(), counts[order].tolist(), strict=True)]


def _firsts(codes: np.ndarray, txn: pa.ChunkedArray, places: np.ndarray) -> np.ndarray:
    """For each code 0..k-1 (each present), the row of its smallest place (txn, missing last; then number)."""
    missing = _mask(txn.is_null())
    order = np.lexsort((places, pc.fill_null(txn, 0).to_numpy(), missing))
    first = np.full(codes.max() + 1 if len(codes) else 0, -1, dtype=np.int64)
    ranked = codes[order]
    _, at = np.unique(ranked, return_index=True)
    first[ranked[at]] = order[at]
    return first


def _place(txn: object, number: int) -> tuple:
    return (_LAST if txn is None else txn, number)


def transactions(acc: Summary, t: pa.Table) -> None:
    n, base = t.num_rows, acc.added["transactions"]
    acc.transactions += n
    acc.added["transactions"] += n
    verdict, device = t.column("verdict"), t.column("device")
    known = pc.is_in(verdict, value_set=_values(VERDICTS))
    for item in pc.value_counts(pc.filter(verdict, known)).to_pylist():
        acc.verdicts[item["values"]] += item["counts"]
    ok = _mask(pc.equal(verdict, "ok"))
    if not ok.all():  # a missing verdict is not ok either
        acc.any_failed = True
        failed = _mask(known) & ~ok & _mask(device.is_valid())
        keys = ["capture", "device", "verdict"]
        for (capture, dev, v), count in _group_counts(t.filter(pa.array(failed)), keys):
            acc.failed.setdefault((capture, dev), Counter())[v] += count
    b5 = t.column("b5_retries")
    valid = _mask(b5.is_valid())
    if valid.any():
        values = pc.fill_null(b5, 0).to_numpy()
        acc.b5_total += int(values[valid].sum())
        acc.b5_transactions += int(np.count_nonzero(values[valid] > 0))
        most = int(values[valid].max())
        rows = np.flatnonzero(valid & (values == most))
        txn = t.column("txn").take(pa.array(rows))
        best = int(rows[_firsts(np.zeros(len(rows), np.int64), txn, rows)[0]])
        number = t.column("txn")[best].as_py()
        place = _place(number, base + best + 1)
        if acc.b5_max is None or most > acc.b5_max[0] or (most == acc.b5_max[0] and place < acc.b5_max[1]):
            acc.b5_max = (most, place, number)
    _drives(acc, t, base)
    total = t.column("t_total")
    timed = _mask(total.is_valid()) & ~np.isnan(total.to_numpy()) & _mask(device.is_valid())
    if timed.any():
        rows = pa.array(np.flatnonzero(timed))
        # a device is (capture, address) (Summary.latency): the two joined by a NUL, which neither holds
        joined = pc.binary_join_element_wise(t.column("capture").take(rows), device.take(rows),
                                             pa.scalar("\x00", pa.large_string()))
        devices = pc.dictionary_encode(joined).combine_chunks()
        codes = devices.indices.to_numpy()
        totals = total.take(rows).to_numpy()
        rtts = t.column("t_write_rtt").take(rows).to_numpy()  # missing as NaN, which is missing too
        order = np.argsort(codes, kind="stable")
        bounds = np.searchsorted(codes[order], np.arange(len(devices.dictionary) + 1))
        for code, dev in enumerate(devices.dictionary.to_pylist()):
            at = order[bounds[code]:bounds[code + 1]]
            got_totals, got_rtts = acc.latency.setdefault(tuple(dev.split("\x00", 1)), (array("d"), array("d")))
            got_totals.frombytes(totals[at].tobytes())
            rtt = rtts[at]
            got_rtts.frombytes(rtt[~np.isnan(rtt)].tobytes())


def parameters(acc: Summary, t: pa.Table) -> None:
    n, base = t.num_rows, acc.added["parameters"]
    acc.added["parameters"] += n
    named = t.filter(pa.array(_mask(pc.and_(pc.not_equal(t.column("pnu_name"), ""), t.column("pnu").is_valid()))))
    if named.num_rows:
        acc.pnu_names.update(pair for pair, _ in _group_counts(named, ["pnu", "pnu_name"]))
    error = t.column("error")
    naks = _mask(error.is_valid()) & _mask(pc.not_equal(error, ""))
    if not naks.any():
        return
    for (err, text), _ in _group_counts(t.filter(pa.array(naks)), ["error", "error_text"]):
        acc.error_text(err, text)
    # an error of the whole request counts once, on the request's first row (Summary._parameters)
    whole = naks & _mask(t.column("whole_request"))
    at = np.flatnonzero(whole)
    if len(at):
        txn = pc.fill_null(t.column("txn"), -1).to_numpy(zero_copy_only=False)[at]
        before = np.concatenate(([-2 if acc.last_whole is None else acc.last_whole], txn[:-1]))
        naks[at[txn == before]] = False
        acc.last_whole = int(txn[-1])
    rows = np.flatnonzero(naks)
    sub = t.take(pa.array(rows))
    places = base + rows + 1
    whole_rows = pa.array(whole[rows])
    sub = sub.set_column(sub.schema.get_field_index("param"), "param",
                         pc.if_else(whole_rows, pa.scalar(acc.WHOLE_REQUEST, sub.schema.field("param").type),
                                    sub.column("param")))
    for (capture, dev, *rest), count in _group_counts(sub, ["capture", "device", "do", "param", "error"]):
        acc.count_nak(((capture, dev), *rest), count)
    _count_first(acc, "error", acc.by_error, sub.column("error"), sub.column("txn"), places)
    do = sub.column("do")
    known = _mask(do.is_valid())
    if known.any():
        at = pa.array(np.flatnonzero(known))
        _count_first(acc, "do", acc.by_do, do.take(at), sub.column("txn").take(at), places[known])


def _count_first(acc: Summary, kind: str, counter: Counter, values: pa.ChunkedArray, txn: pa.ChunkedArray,
                 places: np.ndarray) -> None:
    """Count each value, and keep its first place in the table (acc.first[(kind, value)])."""
    encoded = pc.dictionary_encode(values).combine_chunks()
    codes = encoded.indices.to_numpy()
    counts = np.bincount(codes)
    first = _firsts(codes, txn, places)
    for code, value in enumerate(encoded.dictionary.to_pylist()):
        counter[value] += int(counts[code])
        row = int(first[code])
        place = _place(txn[row].as_py(), int(places[row]))
        if place < acc.first.get((kind, value), (_LAST,)):
            acc.first[(kind, value)] = place


def findings(acc: Summary, t: pa.Table) -> None:
    acc.findings += t.num_rows
    severity = t.column("severity")
    for item in pc.value_counts(pc.filter(severity, pc.is_in(severity, value_set=_values(SEVERITIES)))).to_pylist():
        acc.severities[item["values"]] += item["counts"]
    named = _mask(t.column("rule").is_valid()) & _mask(t.column("name").is_valid())
    for key, count in _group_counts(t.filter(pa.array(named)), ["rule", "name"]):
        acc.rules[key] += count


_DRIVE_COLS = ["txn", "verdict", "capture", "device", "slot", "do", "params", "pnio_error_text", "closed_by",
               "b5_retries", "t_total", "t_last_read", "errors", "n_params"]
_DRIVE_ROWS = 1024


def _drives(acc: Summary, t: pa.Table, base: int) -> None:
    """Summary.drive_row for the rows that can matter: every failed one, and those at least as slow as
    the TOP-th slowest of the batch (a faster one cannot be among the slowest overall)."""
    failed = _mask(pc.is_in(t.column("verdict"), value_set=_values(tuple(acc.FAILED))))
    totals = t.column("t_total").to_numpy(zero_copy_only=False).astype(float)
    timed = ~np.isnan(totals)
    slow = np.zeros(len(totals), bool)
    if timed.any():
        cut = np.sort(totals[timed])[::-1][min(acc.SLOWEST, int(timed.sum())) - 1]
        slow = timed & (totals >= cut)
    rows = np.flatnonzero(failed | slow)
    if not len(rows):
        return
    picked = t.select(_DRIVE_COLS)
    for at in range(0, len(rows), _DRIVE_ROWS):  # (as Python rows a few at a time: a flood's are long texts)
        some = rows[at:at + _DRIVE_ROWS]
        for i, row in zip(some.tolist(), picked.take(pa.array(some)).to_pylist(), strict=True):
            total = row["t_total"]
            acc.drive_row(row["txn"], base + i + 1, row["verdict"], (row["capture"], row["device"]), row["slot"],
                          row["do"], row["params"], row["pnio_error_text"], row["closed_by"], row["b5_retries"],
                          None if total is None or total != total else total, _number(row["t_last_read"]),
                          row["errors"], row["n_params"])


def _number(value: object) -> object:
    return None if value is None or value != value else value

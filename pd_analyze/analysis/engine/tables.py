"""The rows of the transactions closed in a batch, as Arrow tables (table_batches.batch_schema).

A transaction whose records are column records of the batch has its parameter rows made from its
request's addresses, the value blocks it wrote and the blocks of its response, gathered by index; the
value texts are the columns' (BlockColumns.text). Only what is per transaction (and the few rows with an
error or a change) is made in Python. A transaction with a record parsed frame by frame (an odd frame,
or a request of an earlier batch) has its rows made by `analysis.rows.Rows.add`, the same cells.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pyarrow as pa

from pd_analyze.analysis.engine.facts import Carried
from pd_analyze.analysis.engine.records import Records
from pd_analyze.analysis.engine.rules import WHOLE, refusal, refused_finding
from pd_analyze.analysis.engine.txn import Txn
from pd_analyze.analysis.engine.txncols import MISSING, TxnCols, in_slices, of_txns
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.analysis.rows import Rows, finding_row
from pd_analyze.analysis.table_batches import TIME_TYPE, batch_schema, rows_to_batch
from pd_analyze.model import pd_values as pt
from pd_analyze.model.times import MAX_TIME_NS, NS
from pd_analyze.model.values import status_text
from pd_analyze.model.verdicts import ANSWERED
from pd_analyze.protocol import profidrive_batch
from pd_analyze.protocol.profidrive_batch import DecodedRecords, merge_records
from pd_analyze.protocol.profidrive_checks import Checker

_NAMES = ("transactions", "parameters", "findings", "changes")
Made = dict[str, list[pa.Table]]  # rows of the four tables, by name


def _hex_table() -> list[str]:
    return [f"0x{v:02x}" for v in range(256)]


_HEX = _hex_table()


@functools.cache
def _cells() -> tuple[pa.Array, pa.Array]:
    """The format and attribute cells by code (the format's shifted by one: "" for a row without a value
    block); made on first use, as making an Arrow array loads pandas (a dump never needs them)."""
    return (pa.array(["", *(pt.FORMAT_NAME.get(v) or _HEX[v] for v in range(256))], pa.large_string()),
            pa.array([pt.ATTRIBUTE.get(v) or _HEX[v] for v in range(256)], pa.large_string()))


def _hex(value: int) -> str:
    return f"0x{value:02x}" if value >= 0 else ""


def _columnar(t: Txn, view: BatchView | None) -> bool:
    """Its records are column records of the batch, or its request's bytes carried from an earlier batch
    (decoded again by the columns here); the response's too, if any."""
    if not (t.response is None or (view is not None and isinstance(t.response, int))):
        return False
    return isinstance(t.request, Carried) or (view is not None and isinstance(t.request, int))


def _merged(view: BatchView | None, carried: list[bytes], checker: Checker) -> tuple[DecodedRecords, int]:
    """The batch's decoded records and, after them, the carried requests' records decoded again by the
    columns (their first index). Only what the tables read is merged: headers, addresses, block formats,
    errors and texts (not the bytes a block's values are at)."""
    buf = b"".join(carried)
    lengths = np.fromiter((len(c) for c in carried), np.int64, len(carried))
    starts = np.zeros(len(carried), np.int64)
    np.cumsum(lengths[:-1], out=starts[1:])
    extra = profidrive_batch.decode(buf, starts, lengths, np.zeros(len(carried), bool), checker)
    if view is None:
        return extra, 0
    return merge_records(view.records, extra), len(view.records.records.ref)


class TableBuilder:
    """Rows of closed transactions, a batch at a time."""

    def __init__(self, checker: Checker) -> None:
        self.checker = checker
        names = checker.names
        self.names = names  # the run's profile's parameter names and error texts (Checker.names)
        self._error_texts: dict[int, str] = {}
        self._fallback = Rows(names=names)

    def tables(self, view: BatchView | None, txns: list[Txn], capture_of: Callable[[int], str], offset: int,
               episodes: TxnCols | None = None) -> Iterator[tuple[list[Txn], TxnCols | None, Made]]:
        """The four tables' rows of `txns` (closed, numbered, in number order) and of the `episodes` the vector
        path took, slice after slice (txncols.in_slices): each slice's transactions of both ways, its rows."""
        columnar = {id(t) for t in txns if _columnar(t, view)}
        for part, cols in in_slices(txns, episodes):
            out: Made = {name: [] for name in _NAMES}
            here = [t for t in part if id(t) in columnar]
            if len(here) < len(part):
                rows = self._fallback
                records = Records(view)
                for t in part:
                    if id(t) not in columnar:
                        rows.add(capture_of(t.write_frame), t, records, offset)
                for name in _NAMES:
                    found = getattr(rows, name)
                    if found:
                        out[name].append(rows_to_batch(name, found))
                        found.clear()
            if here:
                self._columns(*self._requests(view, here), capture_of, offset, out)
            if cols is not None and len(cols):
                self._columns(view.records, cols, capture_of, offset, out)  # type: ignore[union-attr]
            if len(out["findings"]) > 1:  # by transaction, whichever way each went: two transactions' findings
                # of one rule at one frame (T8 of a superseded one and of its successor) keep one order in any batches
                out["findings"] = [pa.concat_tables(out["findings"]).sort_by("txn")]
            yield part, cols, out

    def _requests(self, view: BatchView | None, here: list[Txn]) -> tuple[DecodedRecords, TxnCols]:
        """The records of `here` (transactions whose records the columns read) and their columns: requests
        carried from an earlier batch are decoded again, after the batch's own records when a transaction
        reads those (merging copies the batch's records: a slice of only carried requests, as a flood's
        timeouts, decodes its own alone)."""
        carried = [t.request.data for t in here if isinstance(t.request, Carried)]
        if not carried:
            return view.records, of_txns(here, [t.request for t in here])  # type: ignore[union-attr,misc]
        in_view = any(not isinstance(t.request, Carried) or isinstance(t.response, int) for t in here)
        decoded, first = _merged(view if in_view else None, carried, self.checker)
        base = iter(range(first, first + len(carried)))
        return decoded, of_txns(here, [next(base) if isinstance(t.request, Carried) else t.request for t in here])

    def _error_text(self, err: int) -> str:
        text = self._error_texts.get(err)
        if text is None:
            text = self._error_texts[err] = self.names.error(err)
        return text

    def _columns(self, records: DecodedRecords, t: TxnCols, capture_of: Callable[[int], str], offset: int,
                 out: dict[str, list[pa.Table]]) -> None:
        rc, ac, bc = records.records, records.addresses, records.blocks
        n = len(t)
        req, res = t.req, t.res
        has_res = res >= 0
        s = np.where(has_res, res, 0)
        numbers = t.number + offset
        captures = _captures(capture_of, t.write_frame)
        chan_texts = [self._fallback.channel_texts(c) for c in t.channel]  # (Rows' cache: the one)
        ch_idx = pa.array(t.ch)
        texts = [pa.array([x[i] for x in chan_texts], pa.large_string()).take(ch_idx) for i in range(4)]
        # --- parameters: one row per address of each request -----------------------------------------
        na = rc.n_addr[req].astype(np.int64)
        owner = np.repeat(np.arange(n), na)
        starts = np.zeros(n, np.int64)
        np.cumsum(na[:-1], out=starts[1:])
        j = np.arange(int(na.sum())) - np.repeat(starts, na)
        ai = rc.first_addr[req][owner] + j
        pnu, sub, elems, attr = ac.pnu[ai], ac.subindex[ai], ac.n_elems[ai], ac.attr[ai]
        change = t.req_id == pt.REQ_CHANGE
        wb = np.where(change[owner] & (j < rc.n_blocks[req][owner]), rc.first_block[req][owner] + j, -1)
        rb = np.where(has_res[owner] & (j < np.where(has_res, rc.n_blocks[s], 0)[owner]),
                      rc.first_block[s][owner] + j, -1)
        # a header-level error (one error block answering several parameters, protocol.md 3.3): every
        # parameter row carries it, marked whole_request (rows.whole_request_error); a request of no
        # parameter is never regular here (profidrive_batch), so every request has its address rows
        first_res = np.where(has_res, rc.first_block[s], 0)
        whole = has_res & (np.where(has_res, rc.n_blocks[s], 0) == 1) & (na > 1)
        whole[whole] &= bc.format[first_res[whole]] == pt.FMT_ERROR
        whole_row = whole[owner]
        rb = np.where(whole_row, first_res[owner], rb)
        err = _at(bc.error, rb, -1)
        err_sub = np.where(err >= 0, _at(bc.error_subindex, rb, -1), -1)
        src = np.where(wb >= 0, wb, rb)
        fmt = _at(bc.format, src, -1)
        fmt_cell = np.where(fmt != pt.FMT_ERROR, fmt, -1)
        count = np.maximum(elems, 1)
        ranged = (attr == pt.ATTR_VALUE) & (count > 1)
        label_cells = _labels(pnu, sub, count, ranged)
        text = _texts(bc.text)
        written = _take(text, wb)
        read = _take(text, rb)
        failed = np.flatnonzero(err >= 0)  # the rows with an error (few, but for refusals)
        fails = err[failed].tolist()
        err_hex, err_text = np.full(len(err), "", object), np.full(len(err), "", object)
        err_hex[failed] = [_hex(e) for e in fails]
        err_text[failed] = [self._error_text(e) for e in fails]
        device_of = texts[0]
        owner_idx = pa.array(owner)
        out["parameters"].append(pa.Table.from_arrays([
            pa.array(numbers[owner], pa.int64()), captures.take(owner_idx), device_of.take(owner_idx),
            pa.array(t.do[owner], pa.int64()), label_cells,
            pa.array(pnu, pa.int64()), _pnu_names(pnu, self.names), pa.array(sub, pa.int64()),
            pa.array(elems, pa.int64()), _cells()[1].take(pa.array(attr)),
            _cells()[0].take(pa.array(fmt_cell + 1)),
            written, read, pa.array(err_hex.tolist(), pa.large_string()),
            pa.array(err_text.tolist(), pa.large_string()),
            pa.array(err_sub, pa.int64(), mask=err_sub < 0),
            pa.array(whole_row, pa.bool_()),
        ], schema=batch_schema("parameters")))
        # --- per transaction: its label, its errors -------------------------------------------------------
        params = _joined_texts(label_cells, np.r_[starts, len(owner)])
        labels = label_cells.take(pa.array(failed)).to_pylist()
        errors: dict[int, list[str]] = {}  # (only the transactions with some: few, but for refusals)
        for o, label, e in zip(owner[failed].tolist(), labels, fails, strict=True):
            errors.setdefault(o, []).append(f"{label}:{_hex(e)}")
        for o in np.flatnonzero(whole).tolist():
            errors[o] = [f"*:{_hex(int(bc.error[first_res[o]]))}"]
        error_cells = [""] * n
        for o, words in errors.items():
            error_cells[o] = " ".join(words)
        self._refused(t, fails, owner[failed].tolist(), labels, whole,
                      _at(bc.error, np.where(whole, first_res, -1), -1))
        # --- changes: one row per value block written ---------------------------------------------------
        start_times = _times(t.t_start)
        changes = np.flatnonzero(wb >= 0)
        if len(changes):
            out["changes"].append(self._changes(t, changes, owner, label_cells, pnu, sub, written, err, numbers,
                                                captures, device_of, starts, start_times))
        # --- transactions ---------------------------------------------------------------------------------
        resp_id = [_HEX[int(i)] if h else "" for i, h in zip(rc.ident[s].tolist(), has_res.tolist(), strict=True)]
        out["transactions"].append(self._transactions(t, numbers, captures, texts, params,
                                                      error_cells, resp_id, start_times))
        cap = captures.to_pylist() if t.findings else []
        found = [finding_row(cap[k], f, int(numbers[k])) for k, fs in t.findings.items() for f in fs]
        if found:
            out["findings"].append(rows_to_batch("findings", found))

    def _refused(self, t: TxnCols, errs: list[int], owners: list[int], labels: list[str], whole: np.ndarray,
                 whole_error: np.ndarray) -> None:
        """T9 of each transaction refused by the drive (verdict nak), at its response, naming its errors
        (`errs`, `owners`, `labels`: the parameter rows with an error)."""
        naks = [k for k, v in enumerate(t.verdict) if v == "nak"]
        if not naks:
            return
        words: dict[int, list[str]] = {k: [] for k in naks}
        for o, label, e in zip(owners, labels, errs, strict=True):
            if o in words and not whole[o]:
                words[o].append(refusal(label, e, self._error_text(e)))
        for k in naks:
            if whole[k]:
                e = int(whole_error[k])
                words[k] = [refusal(WHOLE, e, self._error_text(e))]
            t.findings.setdefault(k, []).append(refused_finding(int(t.read_res_frame[k]), int(t.write_frame[k]),
                                                                words[k]))

    def _changes(self, t: TxnCols, rows: np.ndarray, owner: np.ndarray, labels: pa.Array, pnu: np.ndarray,
                 sub: np.ndarray, written: pa.Array, err: np.ndarray, numbers: np.ndarray, captures: pa.Array,
                 devices: pa.Array, starts: np.ndarray, start_times: pa.Array) -> pa.Table:
        """One row per value block written (`rows`: among the parameter rows, transaction after transaction),
        a column at a time."""
        k = owner[rows]
        taken = pa.array(rows)
        kept = pa.array(k)
        starts_at = start_times.take(kept)
        errs = err[rows]
        verdicts = np.array(t.verdict, object)
        result = np.where(np.isin(verdicts, list(ANSWERED)), "ok", verdicts)[k]
        for at in np.flatnonzero(errs >= 0).tolist():
            e = int(errs[at])
            result[at] = f"error {_hex(e)}: {self._error_text(e)}"
        before = np.full(len(owner), "", object)  # per parameter row; only changes with some value known
        for entry, cells in t.values_before.items():
            before[int(starts[entry]):int(starts[entry]) + len(cells)] = cells
        text, integer = pa.large_string(), pa.int64()
        return pa.Table.from_arrays([
            captures.take(kept), devices.take(kept), pa.array(t.do[k], integer), pa.array(numbers[k], integer),
            pa.array(t.write_frame[k], integer), starts_at, labels.take(taken),
            pa.array(pnu[rows], integer), _pnu_names(pnu[rows], self.names), pa.array(sub[rows], integer),
            written.take(taken), pa.array(result.tolist(), text), pa.array(before[rows].tolist(), text),
        ], schema=batch_schema("changes"))

    @staticmethod
    def _transactions(t: TxnCols, numbers: np.ndarray, captures: pa.Array, texts: list[pa.Array],
                      params: pa.Array, errors: list[str], resp_id: list[str], start_times: pa.Array) -> pa.Table:
        """The transactions' rows, a column at a time (the cells Rows.add makes)."""
        text, integer = pa.large_string(), pa.int64()
        channel = t.channel
        ch = t.ch
        start = t.t_start
        columns = [
            pa.array(numbers, integer), captures,
            *texts,
            *(pa.array(np.array([c[i] for c in channel], np.int64)[ch] if channel else np.zeros(0, np.int64), integer)
              for i in (4, 5, 6)),
            _opt_int(t.ref), _each(t.req_id.tolist(), _hex), _opt_int(t.do),
            _opt_int(t.n_params),
            params, pa.array(resp_id, text), pa.array(t.verdict, text), pa.array(errors, text),
            pa.array(t.pnio_status, text), _each(t.pnio_status, status_text),
            pa.array(t.b5, integer), pa.array(t.reads, integer), pa.array(t.retrans, integer),
            pa.array(t.write_frame, integer), pa.array(t.write_res_frame, integer, mask=t.write_res_frame == 0),
            _joined(t.read_frames, t.read_offsets), pa.array(t.read_res_frame, integer, mask=t.read_res_frame == 0),
            _joined(t.frames, t.frame_offsets),
            start_times,
            _seconds(t.t_write_res, start), _seconds(t.t_done, start), _seconds(t.t_done, t.t_last_read),
            _seconds(t.t_first_read, t.t_write_res), _seconds(t.t_last_read, start),
            pa.array(t.capture_ended, pa.bool_()), pa.array(t.closed_by, text),
        ]
        return pa.Table.from_arrays(columns, schema=batch_schema("transactions"))


def _each(values: list, text: Callable[[Any], str]) -> pa.Array:
    """The texts of `values` (few distinct ones), each made once."""
    made = {v: text(v) for v in set(values)}
    return pa.array([made[v] for v in values], pa.large_string())


def _captures(capture_of: Callable[[int], str], frames: np.ndarray) -> pa.Array:
    """Each transaction's capture (by its write request frame): one text for the usual single capture."""
    if not len(frames):
        return pa.array([], pa.large_string())
    first, last = capture_of(int(frames.min())), capture_of(int(frames.max()))
    if first == last:
        return pa.array([first] * len(frames), pa.large_string())
    return pa.array([capture_of(int(f)) for f in frames.tolist()], pa.large_string())


def _opt_int(values: np.ndarray) -> pa.Array:
    return pa.array(values, pa.int64(), mask=values < 0)


def _seconds(end: np.ndarray, begin: np.ndarray) -> pa.Array:
    """end - begin in seconds, exactly from the nanoseconds; missing where either is."""
    missing = (end == MISSING) | (begin == MISSING)
    return pa.array(np.where(missing, 0, end - begin) / NS, pa.float64(), mask=missing)


def _joined(values: np.ndarray, offsets: np.ndarray) -> pa.Array:
    """Each entry's integers as one text, separated by spaces ('' for none)."""
    import pyarrow.compute as pc

    strings = pa.array(values.astype(np.int64)).cast(pa.string())
    lists = pa.ListArray.from_arrays(pa.array(offsets, pa.int32()), strings)
    return pc.binary_join(lists, " ").cast(pa.large_string())


def _at(column: np.ndarray, rows: np.ndarray, missing: int) -> np.ndarray:
    """column[rows] as int64, `missing` where rows is -1."""
    out = np.full(len(rows), missing, np.int64)
    have = rows >= 0
    out[have] = column[rows[have]]
    return out


def _texts(text: object) -> pa.Array:
    return text if isinstance(text, pa.Array) else pa.array(text, pa.large_string())


def _take(text: pa.Array, rows: np.ndarray) -> pa.Array:
    """text[rows], "" where rows is -1."""
    if not len(rows) or not len(text):
        return pa.array([""] * len(rows), pa.large_string())
    taken = text.take(pa.array(np.maximum(rows, 0)))
    if text.type != pa.large_string():
        taken = taken.cast(pa.large_string())
    missing = rows < 0
    if missing.any():
        import pyarrow.compute as pc

        taken = pc.if_else(pa.array(missing), pa.scalar("", pa.large_string()), taken)
    return taken


def _times(ns: np.ndarray) -> pa.Array:
    """Capture times (integer nanoseconds) as the tables hold them: those same nanoseconds, missing beyond
    datetime64[ns] (model.times.nanos, a column at a time)."""
    return pa.array(ns, pa.int64(), mask=(ns >= MAX_TIME_NS) | (ns <= -MAX_TIME_NS)).cast(TIME_TYPE)


def _pnu_names(pnu: np.ndarray, names: pt.Names) -> pa.Array:
    """The name of each parameter number ("" for most: profile parameters and the profile's own table)."""
    unique, inverse = np.unique(pnu, return_inverse=True)
    return pa.array([names.pnu(p) for p in unique.tolist()], pa.large_string()).take(pa.array(inverse.ravel()))


def _labels(pnu: np.ndarray, sub: np.ndarray, count: np.ndarray, ranged: np.ndarray) -> pa.Array:
    """Each address's label, P<pnu>[<subindex>] or P<pnu>[<first>..<last>] for several Value elements
    (profidrive.Address.label, a column at a time); each distinct address's text made once when they repeat
    (a drive's parameters come again and again: the joins cost per row)."""
    if len(pnu) > 64:
        # one int64 per address (PNU and subindex are 16 bits, the last element at most 16 bits and 255 more)
        last = np.where(ranged, sub.astype(np.int64) + count - 1, -1)
        unique, inverse = np.unique(pnu.astype(np.int64) << 40 | sub.astype(np.int64) << 20 | (last + 1),
                                    return_inverse=True)
        if 2 * len(unique) <= len(pnu):
            u_pnu, u_sub, u_last = unique >> 40, unique >> 20 & 0xFFFFF, (unique & 0xFFFFF) - 1
            return _label_texts(u_pnu, u_sub, u_last - u_sub + 1, u_last >= 0).take(pa.array(inverse.ravel()))
    return _label_texts(pnu, sub, count, ranged)


def _label_texts(pnu: np.ndarray, sub: np.ndarray, count: np.ndarray, ranged: np.ndarray) -> pa.Array:
    import pyarrow.compute as pc

    def text(values: np.ndarray) -> pa.Array:
        return pa.array(values.astype(np.int64)).cast(pa.string())

    last_element = sub.astype(np.int64) + count - 1  # (in int64: subindex 65535 and 3 elements end at 65537)
    last = pc.if_else(pa.array(ranged), pc.binary_join_element_wise("..", text(last_element), ""), "")
    return pc.binary_join_element_wise("P", text(pnu), "[", text(sub), last, "]", "").cast(pa.large_string())


def _joined_texts(values: pa.Array, offsets: np.ndarray) -> pa.Array:
    """The texts of each group (values[offsets[i]:offsets[i + 1]]) joined by spaces."""
    import pyarrow.compute as pc

    lists = pa.LargeListArray.from_arrays(pa.array(offsets, pa.int64()), values)
    return pc.binary_join(lists, pa.scalar(" ", values.type))

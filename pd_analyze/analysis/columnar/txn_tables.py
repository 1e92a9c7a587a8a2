"""The rows of the columnar transactions closed in a batch, as Arrow tables (table_batches.batch_schema):
the cells `analysis.rows.Rows.add` makes, built from the batch's record columns.

A transaction's parameter rows come from its request's addresses, the value blocks it wrote and the
blocks of its response, gathered by index; the value texts are the columns' (BlockColumns.text). Only
what is per transaction (and the few rows with an error or a change) is made in Python. A transaction
whose parameter request was parsed in an earlier batch goes through `Rows.add` itself (they are few:
those that straddle a batch boundary).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pyarrow as pa

from pd_analyze.analysis.columnar.batch_view import BatchView
from pd_analyze.analysis.columnar.state import Txn
from pd_analyze.analysis.columnar.txn_rows import Converter
from pd_analyze.analysis.rows import Rows, finding_row
from pd_analyze.analysis.schema import COLUMNS, micros
from pd_analyze.analysis.table_batches import TIME_TYPE, batch_schema, rows_to_batch
from pd_analyze.model import pd_values as pt
from pd_analyze.model.values import status_text
from pd_analyze.model.verdicts import ANSWERED

_NAMES = ("transactions", "parameters", "findings", "changes")


def _hex_table() -> list[str]:
    return [f"0x{v:02x}" for v in range(256)]


_HEX = _hex_table()
_FORMAT = [pt.FORMAT_NAME.get(v) or _HEX[v] for v in range(256)]
_ATTRIBUTE = [pt.ATTRIBUTE.get(v) or _HEX[v] for v in range(256)]


def _hex(value: int) -> str:
    return f"0x{value:02x}" if value >= 0 else ""


class TableBuilder:
    """Rows of closed columnar transactions, a batch at a time."""

    def __init__(self, convert: Converter, names: pt.Names = pt.PROFIDRIVE_NAMES) -> None:
        self.convert = convert
        self.names = names  # the run's profile's parameter names and error texts (Checker.names)
        self._texts: dict[tuple, tuple[str, str, str, str]] = {}
        self._error_texts: dict[int, str] = {}
        self._fallback = Rows(names=names)

    def tables(self, view: BatchView, txns: list[Txn], capture_of: Callable[[int], str],
               offset: int) -> dict[str, list[pa.Table]]:
        """The four tables' rows of `txns` (closed, numbered)."""
        out: dict[str, list[pa.Table]] = {name: [] for name in _NAMES}
        here = [t for t in txns if isinstance(t.request, (int, np.integer))]
        if len(here) < len(txns):
            rows = self._fallback
            for t in txns:
                if not isinstance(t.request, (int, np.integer)):
                    txn = self.convert.transaction(t, view)
                    txn.txn = t.number
                    rows.add(capture_of(t.write_frame), txn, offset)
            for name in _NAMES:
                found = getattr(rows, name)
                if found:
                    out[name].append(rows_to_batch(name, found))
                    found.clear()
        if here:
            self._columns(view, here, capture_of, offset, out)
        return out

    def _channel_texts(self, t: Txn) -> tuple[str, str, str, str]:
        texts = self._texts.get(t.channel)
        if texts is None:
            if len(self._texts) > 65536:
                self._texts.clear()
            texts = self._texts[t.channel] = self._fallback._channel(self.convert.channel(t.channel))
        return texts

    def _error_text(self, err: int) -> str:
        text = self._error_texts.get(err)
        if text is None:
            text = self._error_texts[err] = self.names.error(err)
        return text

    def _columns(self, view: BatchView, txns: list[Txn], capture_of: Callable[[int], str], offset: int,
                 out: dict[str, list[pa.Table]]) -> None:
        rc, ac, bc = view.records.records, view.records.addresses, view.records.blocks
        n = len(txns)
        req = np.fromiter((t.request for t in txns), np.int64, n)
        res = np.fromiter((t.response if isinstance(t.response, (int, np.integer)) else -1 for t in txns), np.int64, n)
        has_res = res >= 0
        s = np.where(has_res, res, 0)
        numbers = [t.number + offset for t in txns]
        captures = [capture_of(t.write_frame) for t in txns]
        texts = [self._channel_texts(t) for t in txns]
        # --- parameters: one row per address of each request -----------------------------------------
        na = rc.n_addr[req].astype(np.int64)
        owner = np.repeat(np.arange(n), na)
        starts = np.zeros(n, np.int64)
        np.cumsum(na[:-1], out=starts[1:])
        j = np.arange(int(na.sum())) - np.repeat(starts, na)
        ai = rc.first_addr[req][owner] + j
        pnu, sub, elems, attr = ac.pnu[ai], ac.subindex[ai], ac.n_elems[ai], ac.attr[ai]
        change = np.array([t.req_id == pt.REQ_CHANGE for t in txns], bool)
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
        labels = [f"P{p}[{a}..{a + c - 1}]" if r else f"P{p}[{a}]"
                  for p, a, c, r in zip(pnu.tolist(), sub.tolist(), count.tolist(), ranged.tolist(), strict=True)]
        text = _texts(bc.text)
        written = _take(text, wb)
        read = _take(text, rb)
        errs = err.tolist()
        owners = owner.tolist()
        devices = [texts[o][0] for o in owners]
        dos = [txns[o].do for o in owners]
        out["parameters"].append(pa.Table.from_arrays([
            pa.array([numbers[o] for o in owners], pa.int64()),
            pa.array([captures[o] for o in owners], pa.large_string()),
            pa.array(devices, pa.large_string()), pa.array(dos, pa.int64()), pa.array(labels, pa.large_string()),
            pa.array(pnu, pa.int64()), _pnu_names(pnu, self.names), pa.array(sub, pa.int64()),
            pa.array(elems, pa.int64()),
            pa.array([_ATTRIBUTE[a] for a in attr.tolist()], pa.large_string()),
            pa.array(["" if f < 0 else _FORMAT[f] for f in fmt_cell.tolist()], pa.large_string()),
            written, read, pa.array([_hex(e) for e in errs], pa.large_string()),
            pa.array([self._error_text(e) if e >= 0 else "" for e in errs], pa.large_string()),
            pa.array(err_sub, pa.int64(), mask=err_sub < 0),
            pa.array(whole_row, pa.bool_()),
        ], schema=batch_schema("parameters")))
        # --- per transaction: its label, its errors -------------------------------------------------------
        params: list[list[str]] = [[] for _ in range(n)]
        errors: list[list[str]] = [[] for _ in range(n)]
        for o, label, e in zip(owners, labels, errs, strict=True):
            params[o].append(label)
            if e >= 0:
                errors[o].append(f"{label}:{_hex(e)}")
        for o in np.flatnonzero(whole).tolist():
            errors[o] = [f"*:{_hex(int(bc.error[first_res[o]]))}"]
        # --- changes: one row per value block written ---------------------------------------------------
        changes = np.flatnonzero(wb >= 0).tolist()
        if changes:
            out["changes"].append(self._changes(txns, changes, owners, labels, pnu, sub, written, errs, numbers,
                                                captures, devices, j))
        # --- transactions ---------------------------------------------------------------------------------
        resp_id = [_HEX[int(i)] if h else "" for i, h in zip(rc.ident[s].tolist(), has_res.tolist(), strict=True)]
        out["transactions"].append(self._transactions(txns, numbers, captures, texts, params, errors, resp_id))
        found = [finding_row(captures[k], f, numbers[k]) for k, t in enumerate(txns) for f in t.findings]
        if found:
            out["findings"].append(rows_to_batch("findings", found))

    def _changes(self, txns: list[Txn], rows: list[int], owners: list[int], labels: list[str], pnu: np.ndarray,
                 sub: np.ndarray, written: pa.Array, errs: list[int], numbers: list[int], captures: list[str],
                 devices: list[str], j: np.ndarray) -> pa.Table:
        cols: list[list] = [[] for _ in range(13)]
        idx = np.array(rows, np.int64)
        values = written.take(pa.array(idx)).to_pylist()
        positions = j[idx].tolist()
        for row, value, i in zip(rows, values, positions, strict=True):
            t = txns[owners[row]]
            e = errs[row]
            if e >= 0:
                result = f"error {_hex(e)}: {self._error_text(e)}"
            else:
                result = "ok" if t.verdict in ANSWERED else t.verdict
            before = t.values_before[i] if i < len(t.values_before) else [None]
            for col, cell in zip(cols, (captures[owners[row]], devices[row], t.do, numbers[owners[row]], t.write_frame,
                                        t.t_start, labels[row], None, None, None, value, result,
                                        " ".join(b for b in before if b is not None) if all(before) else ""),
                                 strict=True):
                col.append(cell)
        cols[7], cols[8], cols[9] = pnu[idx], _pnu_names(pnu[idx], self.names), sub[idx]
        return _table("changes", cols)

    @staticmethod
    def _transactions(txns: list[Txn], numbers: list[int], captures: list[str], texts: list[tuple],
                      params: list[list[str]], errors: list[list[str]], resp_id: list[str]) -> pa.Table:
        """The transactions' rows, a column at a time (the cells Rows.add makes)."""
        res = [t.t_write_res for t in txns]
        start = [t.t_start for t in txns]
        done = [t.t_read_res if t.closed_by == "response" else None for t in txns]
        first_read = [t.t_reads[0] if t.t_reads else None for t in txns]
        last_read = [t.t_reads[-1] if t.t_reads else None for t in txns]
        text, integer, real = pa.large_string(), pa.int64(), pa.float64()
        columns = [
            pa.array(numbers, integer), pa.array(captures, text),
            *(pa.array([x[i] for x in texts], text) for i in range(4)),
            *(pa.array([t.channel[i] for t in txns], integer) for i in (4, 5, 6)),
            pa.array([t.ref if t.ref >= 0 else None for t in txns], integer),
            pa.array([_hex(t.req_id) for t in txns], text),
            pa.array([t.do if t.do >= 0 else None for t in txns], integer),
            pa.array([t.n_params if t.n_params >= 0 else None for t in txns], integer),
            pa.array([" ".join(p) for p in params], text), pa.array(resp_id, text),
            pa.array([t.verdict for t in txns], text), pa.array([" ".join(e) for e in errors], text),
            pa.array([t.pnio_status for t in txns], text),
            pa.array([status_text(t.pnio_status) for t in txns], text), pa.array([t.b5 for t in txns], integer),
            pa.array([len(t.read_frames) for t in txns], integer), pa.array([0] * len(txns), integer),
            pa.array([t.write_frame for t in txns], integer),
            pa.array([t.write_res_frame or None for t in txns], integer),
            pa.array([" ".join(map(str, t.read_frames)) for t in txns], text),
            pa.array([t.read_res_frame or None for t in txns], integer),
            pa.array([" ".join(map(str, sorted(t.frames))) for t in txns], text),
            pa.array([micros(v) for v in start], integer).cast(TIME_TYPE),
            pa.array([None if r is None else r - s for r, s in zip(res, start, strict=True)], real),
            pa.array([None if d is None else d - s for d, s in zip(done, start, strict=True)], real),
            pa.array([None if d is None or r is None else d - r for d, r in zip(done, last_read, strict=True)], real),
            pa.array([None if r is None or f is None else f - r for r, f in zip(res, first_read, strict=True)], real),
            pa.array([None if r is None else r - s for r, s in zip(last_read, start, strict=True)], real),
            pa.array([t.capture_ended for t in txns], pa.bool_()), pa.array([t.closed_by for t in txns], text),
        ]
        return pa.Table.from_arrays(columns, schema=batch_schema("transactions"))


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


def _table(name: str, cols: list) -> pa.Table:
    schema = batch_schema(name)
    arrays = []
    for c, field, values in zip(COLUMNS[name], schema, cols, strict=True):
        if field.type == TIME_TYPE:
            arrays.append(pa.array([round(v * 1e6) for v in values], pa.int64()).cast(TIME_TYPE))
        else:
            arrays.append(pa.array(values, field.type))
        del c
    return pa.Table.from_arrays(arrays, schema=schema)


def _pnu_names(pnu: np.ndarray, names: pt.Names) -> pa.Array:
    """The name of each parameter number ("" for most: profile parameters and the profile's own table)."""
    return pa.array([names.pnu(p) for p in pnu.tolist()], pa.large_string())

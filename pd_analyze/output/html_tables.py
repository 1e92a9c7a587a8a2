"""The HTML report's tables as the page's script takes them: columns (name, label, kind) and rows of cells.

The columns lead with what a reader looks at first (the transaction, its drive and parameters, the verdict
and the error in words); the script keeps the first column in place when the table scrolls sideways and
makes every `txn` cell a link to the transaction's frames. Big tables embed at most `limit` rows, the
failed transactions and the errors first, and say what they left out.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from pd_analyze.model import pd_values as pt
from pd_analyze.model.times import DEFAULT_DIGITS, ms_decimals
from pd_analyze.output.frame_notes import _error_texts


@dataclass(frozen=True, slots=True)
class Col:
    name: str  # column of the DataFrame
    label: str
    # num, str, time (UTC datetime), ms (seconds shown as milliseconds), verdict, severity, frames (a list of
    # frame numbers), req_id / resp_id (the ID with its name), errors (the errors cell in words); times and
    # milliseconds at the row's capture's resolution (model.times)
    kind: str


TRANSACTION_COLS = (
    Col("txn", "txn", "num"), Col("device", "device", "str"), Col("params", "parameters", "str"),
    Col("verdict", "verdict", "verdict"), Col("errors", "errors", "errors"),
    Col("pnio_error_text", "PNIOStatus", "str"), Col("t_total", "total ms", "ms"), Col("b5_retries", "B5", "num"),
    Col("t_start", "time (UTC)", "time"), Col("do", "DO", "num"), Col("ref", "ref", "num"),
    Col("req_id", "request", "req_id"), Col("resp_id", "response", "resp_id"),
    Col("t_write_rtt", "write rtt ms", "ms"), Col("reads", "reads", "num"), Col("closed_by", "closed by", "str"),
    Col("index", "index", "str"), Col("controller", "controller", "str"), Col("frames", "frames", "frames"),
    Col("capture", "capture", "str"),
)
FINDING_COLS = (
    Col("frame", "frame", "num"), Col("txn", "txn", "num"), Col("severity", "severity", "severity"),
    Col("rule", "rule", "str"), Col("name", "name", "str"), Col("message", "message", "str"),
    Col("field", "field", "str"), Col("value", "value", "str"), Col("expected", "expected", "str"),
    Col("source", "source", "str"), Col("capture", "capture", "str"),
)
CHANGE_COLS = (
    Col("txn", "txn", "num"), Col("device", "device", "str"), Col("param", "parameter", "str"),
    Col("pnu_name", "name", "str"), Col("value_written", "value written", "str"), Col("result", "result", "str"),
    Col("value_before", "value before", "str"), Col("do", "DO", "num"), Col("frame", "frame", "num"),
    Col("t", "time (UTC)", "time"), Col("capture", "capture", "str"),
)
_SCRIPT_KIND = {"req_id": "str", "resp_id": "str", "errors": "str"}  # formatted here, filtered as text


def cols(columns: tuple[Col, ...], several_captures: bool) -> tuple[Col, ...]:
    """The columns to show: the capture column only when the page holds more than one capture."""
    return columns if several_captures else tuple(c for c in columns if c.name != "capture")


def cap_transactions(t: pd.DataFrame, limit: int) -> tuple[pd.DataFrame, int, str]:
    if len(t) <= limit:
        return t, len(t), "in txn order"
    failed = t[t.verdict != "ok"].head(limit)
    ok = t[t.verdict == "ok"].head(limit - len(failed))
    shown = pd.concat([failed, ok]).sort_values("txn", kind="stable")
    if ok.empty:
        return shown, len(t), f"the first {len(failed):,} failed ones"
    return shown, len(t), f"every failed transaction ({len(failed):,}), then the first {len(ok):,} ok ones"


def cap_findings(f: pd.DataFrame, limit: int) -> tuple[pd.DataFrame, int, str]:
    if len(f) <= limit:
        return f, len(f), "in frame order"
    order = f.assign(_rank=f.severity.cat.codes).sort_values(["_rank", "frame"], ascending=[False, True],
                                                              kind="stable")
    return order.head(limit).drop(columns="_rank").sort_values("frame", kind="stable"), len(f), "errors first"


def table(df: pd.DataFrame, total: int, chosen: str, columns: tuple[Col, ...], where: str, name: str,
          names: pt.Names = pt.PROFIDRIVE_NAMES, digits: Mapping[str, int] | None = None) -> dict[str, Any]:
    """A table's data for the page: `total` rows in all, `df` the ones embedded (`chosen` says which);
    `digits`: each capture's resolution (Rows.digits)."""
    spec = [{"name": c.name, "label": c.label, "kind": _SCRIPT_KIND.get(c.kind, c.kind)} for c in columns]
    places = row_digits(df["capture"], digits or {}) if "capture" in df else DEFAULT_DIGITS
    values = [column(df[c.name], c.kind, names, places) for c in columns]
    rows = [list(r) for r in zip(*values, strict=True)] if values and len(df) else []
    note = ""
    if len(df) < total:
        note = (f"{len(df):,} of {total:,} {name} embedded ({chosen}); the other {total - len(df):,} are in "
                f"{where}.")
    return {"columns": spec, "rows": rows, "total": total, "note": note}


def row_digits(captures: pd.Series, digits: Mapping[str, int]) -> np.ndarray:
    """Each row's resolution (decimals of a second) by its capture; DEFAULT_DIGITS for one not known."""
    return np.array([digits.get(c, DEFAULT_DIGITS) for c in captures.astype("object")], np.int64)


def column(s: pd.Series, kind: str, names: pt.Names = pt.PROFIDRIVE_NAMES,
           digits: int | np.ndarray = DEFAULT_DIGITS) -> list[object]:
    """A column's cells as the page shows them (None for an empty cell); `digits`: the rows' resolution."""
    if kind == "time":  # as the CSV writes it, without the zone (the heading says UTC)
        import pyarrow as pa

        from pd_analyze.output.batch_cells import time_text

        return time_text(pa.array(s.to_numpy(dtype="datetime64[ns]"), pa.timestamp("ns")), digits, " ", "").to_pylist()
    if kind == "ms":  # a number (the script sorts and compares it), to the resolution's last decimal
        scale = 10.0 ** ms_decimals_of(digits)
        ms = np.rint(s.astype("Float64").to_numpy(dtype="float64", na_value=np.nan) * 1000 * scale) / scale
        return [None if v != v else v for v in ms.tolist()]
    if kind == "num":
        return [None if pd.isna(v) else (int(v) if float(v).is_integer() else float(v)) for v in s.astype("object")]
    if kind in ("req_id", "resp_id"):  # the ID with its name: "0x81 request parameter, negative"
        ids = pt.REQUEST_ID if kind == "req_id" else pt.RESPONSE_ID
        return [None if pd.isna(v) else named_id(str(v), ids) for v in s.astype("object")]
    if kind == "errors":  # "P2[0]:0x01" as "P2[0] error 0x01 parameter value cannot be changed"
        return [None if pd.isna(v) or not v else "; ".join(_error_texts(str(v), names)) for v in s.astype("object")]
    return [None if pd.isna(v) else str(v) for v in s.astype("object")]


def ms_decimals_of(digits: int | np.ndarray) -> int | np.ndarray:
    """model.times.ms_decimals of one resolution or of each row's."""
    return np.maximum(np.asarray(digits) - 3, 0) if np.ndim(digits) else ms_decimals(int(digits))


def named_id(text: str, ids: Mapping[int, str]) -> str:
    try:
        name = ids.get(int(text, 16), "") if text else ""
    except ValueError:
        return text
    return f"{text} {name}" if name else text

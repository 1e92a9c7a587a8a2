"""The four tidy tables: their columns declared once (name, dtype, description), the row type of each,
their order, and their typed DataFrames.

The DataFrames, the streamed report files and `pd-analyze fields --tables` read the declaration. Rows
are named tuples; pandas is imported only when a DataFrame is built (`frame_of`), never on the
CSV/JSON report path.
"""

from __future__ import annotations

from collections import namedtuple
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from functools import lru_cache
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from pd_analyze.model.rules import RULES, SEVERITIES
from pd_analyze.model.times import nanos
from pd_analyze.model.verdicts import VERDICTS

if TYPE_CHECKING:
    import pandas as pd

VERDICT = "category:verdict"  # categoricals with fixed categories (the same in every chunk and file)
SEVERITY = "category:severity"
FIXED_CATEGORIES = {VERDICT: (VERDICTS, False), SEVERITY: (SEVERITIES, True)}
TIME = "datetime64[ns, UTC]"  # a capture time: integer nanoseconds in every row, batch and file (model.times)


@dataclass(frozen=True, slots=True)
class Column:
    name: str
    dtype: str  # a pandas dtype name, or VERDICT / SEVERITY
    description: str


def _cols(*cols: tuple[str, str, str]) -> tuple[Column, ...]:
    return tuple(Column(*c) for c in cols)


COLUMNS: Mapping[str, tuple[Column, ...]] = MappingProxyType({
    "transactions": _cols(
        ("txn", "Int64", "transaction number, 1, 2, ... in the order of the write request frames"),
        ("capture", "category", "capture file"),
        ("device", "category", "device (drive) IP address"),
        ("controller", "category", "controller (PLC) IP address"),
        ("ar", "string", "ARUUID of the channel"),
        ("index", "category", "record index (0xb02e, 0xb02f, 0x002f)"),
        ("api", "Int64", "API"), ("slot", "Int64", "slot"), ("subslot", "Int64", "subslot"),
        ("ref", "Int64", "Request Reference"), ("req_id", "category", "Request ID"),
        ("do", "Int64", "DO-ID"), ("n_params", "Int64", "No. of parameters"),
        ("params", "string", "parameters addressed, e.g. P964[0] P2000[0..2]"),
        ("resp_id", "category", "Response ID"),
        ("verdict", VERDICT, "malformed, pnio_error, timeout, reference_mismatch, nak or ok"),
        ("errors", "string", "PROFIdrive errors per parameter, e.g. P964[0]:0x02"),
        ("pnio_status", "string", "PNIOStatus that closed the transaction (8 hex digits), empty when none"),
        ("pnio_error_text", "string", "that status in words, e.g. DF80C300 write: resource unavailable "
                                      "(an RPC fault's NCA status likewise)"),
        ("b5_retries", "Int64", "reads answered B5 (state conflict: not ready)"),
        ("reads", "Int64", "read calls"),
        ("rpc_retransmissions", "Int64", "duplicate request PDUs"),
        ("write_req_frame", "Int64", "frame of the write request"),
        ("write_res_frame", "Int64", "frame of the write response"),
        ("read_req_frames", "string", "frames of the read requests"),
        ("read_res_frame", "Int64", "frame of the final read response"),
        ("frames", "string", "every frame that belongs to the transaction: requests, answers, B5 answers, "
                               "fragments, retransmissions and copies (protocol.md 7.6); what extract writes"),
        ("t_start", TIME, "time of the write request: the capture's timestamp, exact"),
        ("t_write_rtt", "Float64", "seconds from write request to write response (every t_ figure the exact "
                                   "difference of two capture timestamps)"),
        ("t_total", "Float64", "seconds from write request to the final read response"),
        ("t_final_read_rtt", "Float64", "seconds from the final read request to its response"),
        ("t_first_read_gap", "Float64", "seconds from write response to the first read request"),
        ("t_last_read", "Float64", "seconds from write request to the last read request: for a timeout, how long "
                                   "the controller kept asking"),
        ("capture_ended", "boolean", "still open when the capture ended"),
        ("closed_by", "category", "response, pnio_error, deadline, superseded, capture_end or evicted"),
    ),
    "parameters": _cols(
        ("txn", "Int64", "transaction"), ("capture", "category", "capture file"),
        ("device", "category", "device IP address"), ("do", "Int64", "DO-ID"),
        ("param", "string", "P<pnu>[<subindex>..]"), ("pnu", "Int64", "parameter number"),
        ("pnu_name", "string", "standard name of the parameter (PROFIdrive profile parameters), empty when none"),
        ("subindex", "Int64", "first subindex"), ("elements", "Int64", "No. of elements"),
        ("attribute", "category", "Value, Description or Text"), ("format", "category", "data type"),
        ("values_written", "string", "values of a change request"),
        ("values_read", "string", "values of the response"),
        ("error", "string", "PROFIdrive error number (0x..), empty when none"),
        ("error_text", "string", "meaning of the error number"),
        ("error_subindex", "Int64", "the error's second value: subindex of the first faulty element, empty when "
                                    "the drive gives none"),
        ("whole_request", "boolean", "the error refused the whole request (one error block for all its "
                                     "parameters, protocol.md 3.3), not this parameter alone"),
    ),
    "findings": _cols(
        ("capture", "category", "capture file"), ("frame", "Int64", "frame number"),
        ("txn", "Int64", "transaction, empty when the frame belongs to none"),
        ("severity", SEVERITY, "info, warning or error"), ("rule", "category", "rule id (protocol.md 6)"),
        ("name", "category", "rule name"), ("field", "string", "field name (pd-analyze fields)"),
        ("value", "string", "observed value"), ("expected", "string", "expected value or range"),
        ("source", "string", "document the limit comes from"), ("message", "string", "one-line message"),
    ),
    "changes": _cols(
        ("capture", "category", "capture file"), ("device", "category", "device IP address"),
        ("do", "Int64", "DO-ID"), ("txn", "Int64", "transaction"), ("frame", "Int64", "write request frame"),
        ("t", TIME, "time of the change request: the capture's timestamp, exact"),
        ("param", "string", "P<pnu>[<subindex>..]"),
        ("pnu", "Int64", "parameter number"),
        ("pnu_name", "string", "standard name of the parameter, empty when none"),
        ("subindex", "Int64", "first subindex"),
        ("value_written", "string", "values written"),
        ("result", "string", "ok, the PROFIdrive error, or the transaction verdict"),
        ("value_before", "string", "last value read earlier in the capture, empty when unknown"),
    ),
})


def _row_type(table: str) -> type:
    return namedtuple(table.capitalize()[:-1] + "Row", [c.name for c in COLUMNS[table]])


# The row of each table: a tuple read by column name (row.txn, row.frame, ...)
TransactionRow = _row_type("transactions")
ParameterRow = _row_type("parameters")
FindingRow = _row_type("findings")
ChangeRow = _row_type("changes")
ROW_TYPES: Mapping[str, type] = MappingProxyType({
    "transactions": TransactionRow, "parameters": ParameterRow, "findings": FindingRow, "changes": ChangeRow})


# The order of each table: by this column, ties in the order the rows were added (a stable sort); the
# findings of one frame by their rule's place in the registry (link, RPC, NDR, IOD, request, response,
# transaction), whichever part of the analysis found them first.
SORT_COLUMN: Mapping[str, str] = MappingProxyType({
    "transactions": "txn", "parameters": "txn", "findings": "frame", "changes": "txn"})
RULE_RANK: Mapping[str, int] = MappingProxyType({name: i for i, name in enumerate(RULES)})
_LAST = float("inf")  # a missing key sorts last, as pandas puts NA last


def sort_key(name: str, by_capture: bool = False) -> Callable[[tuple], object]:
    """The sort key of a table's rows; `by_capture` groups findings by capture first (audit, Parquet)."""
    fields = ROW_TYPES[name]._fields  # rows may come back from disk as plain lists: by position
    col = fields.index(SORT_COLUMN[name])
    cap = fields.index("capture")
    if name == "findings":
        rule = fields.index("name")
        if by_capture:
            return lambda r: (r[cap], _LAST if r[col] is None else r[col], RULE_RANK.get(r[rule], -1))
        return lambda r: (_LAST if r[col] is None else r[col], RULE_RANK.get(r[rule], -1))
    if by_capture:
        return lambda r: (r[cap], _LAST if r[col] is None else r[col])
    return lambda r: _LAST if r[col] is None else r[col]


@lru_cache(maxsize=4096)
def capture_text(path: str) -> str:
    """A capture's name as the tables hold it: the path itself, or, for a file name that is not UTF-8 (its
    undecodable bytes come as lone surrogates, which no UTF-8 file or Arrow column can hold), the name with
    those bytes written as backslash escapes: caf\\xe9.pcap."""
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        return path.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    return path


def text_cell(value: object) -> str | None:
    """A string cell as pandas' "string" dtype holds it: None stays missing, anything else str()."""
    if value is None or (isinstance(value, float) and value != value):
        return None
    return value if isinstance(value, str) else str(value)


def float_cell(value: object) -> float | None:
    if value is None:
        return None
    value = float(value)  # type: ignore[arg-type]
    return None if value != value else value  # NaN is missing, as in the Float64 column


def _category(col: Column) -> Callable[[object], str | None]:
    """Cells of a categorical: a fixed categorical has no cell for a value outside its categories."""
    fixed = FIXED_CATEGORIES.get(col.dtype)
    if fixed is None:
        return text_cell
    allowed = frozenset(fixed[0])
    return lambda v: v if v in allowed else None  # type: ignore[return-value]


def cell_value(col: Column) -> Callable[[object], Any]:
    """The typed value of one cell of a row (None when missing), as every table file and batch holds it:
    times as integer nanoseconds (model.times.nanos), NaN missing, text cells str(), values outside fixed
    categories missing."""
    if col.dtype == TIME:
        return nanos
    if col.dtype == "Float64":
        return float_cell
    if col.dtype in ("Int64", "boolean"):
        return lambda v: v
    if col.dtype == "string":
        return text_cell
    return _category(col)


def pandas_dtype(col: Column) -> object:
    """The pandas dtype of a column (pandas imported here, on first use)."""
    import pandas as pd

    if col.dtype in FIXED_CATEGORIES:
        categories, ordered = FIXED_CATEGORIES[col.dtype]
        return pd.CategoricalDtype(list(categories), ordered=ordered)
    return col.dtype


def __getattr__(name: str) -> object:
    # the pandas dtypes of the fixed categoricals, for callers that used the module constants
    if name in ("VERDICT_DTYPE", "SEVERITY_DTYPE"):
        return pandas_dtype(Column("", VERDICT if name == "VERDICT_DTYPE" else SEVERITY, ""))
    raise AttributeError(name)


def time_series(ns: Iterable[int | None], index: object = None) -> pd.Series:
    """Capture times (integer nanoseconds, None missing) as a datetime64[ns, UTC] Series, exactly: never
    through a float (pandas converts a nullable integer column to float on its way to a datetime)."""
    import numpy as np
    import pandas as pd

    raw = np.array([np.iinfo(np.int64).min if v is None else v for v in ns], np.int64)  # int64 min: NaT
    return pd.Series(raw.view("datetime64[ns]"), index=index).dt.tz_localize("UTC")


def frame_of(name: str, rows: Iterable[tuple]) -> pd.DataFrame:
    """A typed DataFrame of one table from its rows."""
    import pandas as pd

    cols = COLUMNS[name]
    df = pd.DataFrame.from_records(list(rows), columns=[c.name for c in cols])
    for c in cols:
        if c.dtype == TIME:
            df[c.name] = time_series([nanos(v) for v in df[c.name]], df.index)
        else:
            df[c.name] = df[c.name].astype(pandas_dtype(c))
    if len(df):
        if name == "findings":
            rank = df["name"].astype(object).map(RULE_RANK).fillna(-1)
            order = pd.DataFrame({"frame": df["frame"], "rank": rank}).sort_values(["frame", "rank"], kind="stable")
            df = df.loc[order.index].reset_index(drop=True)
        else:
            df = df.sort_values([SORT_COLUMN[name]], kind="stable").reset_index(drop=True)
    return df

"""The four tables as Arrow batches: their schema, today's rows converted, their order, their DataFrames.

The columnar report path hands each table on as pyarrow Tables of `batch_schema(name)`, a batch at a
time. A batch holds exactly the cells a row holds once `schema.cell_value` has read it: times as integer
nanoseconds (timestamp[ns, UTC]; missing beyond datetime64[ns]), NaN missing, text cells str(), a fixed
categorical's value outside its categories missing. Categoricals are plain strings here; their encoding
is made where a DataFrame or a Parquet file is built.

Kept apart from `schema` because this module needs pyarrow at import, and `schema` is on the CSV/JSON
row path, which imports neither pyarrow nor pandas.
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import cache
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pd_analyze.analysis.schema import (
    COLUMNS,
    FIXED_CATEGORIES,
    RULE_RANK,
    SEVERITY,
    SORT_COLUMN,
    TIME,
    VERDICT,
    cell_value,
    pandas_dtype,
)
from pd_analyze.model.times import MAX_TIME_NS

if TYPE_CHECKING:
    import pandas as pd

TIME_TYPE = pa.timestamp("ns", tz="UTC")
_TYPES = {"Int64": pa.int64(), "string": pa.large_string(), "category": pa.large_string(),
          VERDICT: pa.large_string(), SEVERITY: pa.large_string(), TIME: TIME_TYPE, "Float64": pa.float64(),
          "boolean": pa.bool_()}
SEQ = "__seq"  # the arrival number of a row, where a key needs it: ties keep the order rows came in


@cache
def batch_schema(name: str) -> pa.Schema:
    """The Arrow schema of one table's batches: its columns in order, all nullable."""
    return pa.schema([pa.field(c.name, _TYPES[c.dtype]) for c in COLUMNS[name]])


def rows_to_batch(name: str, rows: Iterable[tuple]) -> pa.Table:
    """Row tuples (as `Rows` builds them: times as integer nanoseconds, None for missing) as one batch."""
    cols, schema = COLUMNS[name], batch_schema(name)
    rows = rows if isinstance(rows, list | tuple) else list(rows)
    columns = list(zip(*rows, strict=True)) if rows else [()] * len(cols)
    arrays = []
    for c, field, cells in zip(cols, schema, columns, strict=True):
        if c.dtype == TIME:
            arrays.append(pa.array([cell_value(c)(v) for v in cells], pa.int64()).cast(TIME_TYPE))
            continue
        if c.dtype not in FIXED_CATEGORIES:
            try:  # whole columns at once (NaN missing: from_pandas), as the cells almost always are
                arrays.append(pa.array(cells, field.type, from_pandas=True))
                continue
            except (pa.ArrowInvalid, pa.ArrowTypeError):
                pass  # a cell of another type (an int in a text column ...): each cell as the files hold it
        value = cell_value(c)
        arrays.append(pa.array([value(v) for v in cells], field.type))
    return pa.Table.from_arrays(arrays, schema=schema)


def conform(name: str, table: pa.Table) -> pa.Table:
    """A batch made to hold what `rows_to_batch` would: the schema's columns in order and types, NaN
    missing, times beyond datetime64[ns] missing, values outside a fixed categorical's categories missing.

    Cheap when the batch conforms already (one pass over the float, time and fixed columns)."""
    schema = batch_schema(name)
    if not table.schema.equals(schema):
        table = table.select(schema.names).cast(schema)
    columns = list(table.columns)
    changed = False
    for i, c in enumerate(COLUMNS[name]):
        col = columns[i]
        if c.dtype == "Float64":
            bad = pc.is_nan(col)
        elif c.dtype == TIME:
            ns = pc.cast(col, pa.int64())
            bad = pc.or_(pc.greater_equal(ns, MAX_TIME_NS), pc.less_equal(ns, -MAX_TIME_NS))
        elif c.dtype in FIXED_CATEGORIES:
            known = pc.is_in(col, value_set=pa.array(FIXED_CATEGORIES[c.dtype][0], pa.large_string()))
            bad = pc.and_(pc.invert(known), pc.is_valid(col))
        else:
            continue
        if pc.any(bad).as_py():  # null where bad (a null stays null)
            columns[i] = pc.if_else(bad, pa.scalar(None, col.type), col)
            changed = True
    return pa.Table.from_arrays(columns, schema=schema) if changed else table


@cache
def _rules() -> pa.Array:
    return pa.array(sorted(RULE_RANK, key=RULE_RANK.__getitem__), pa.large_string())


def order_keys(name: str, table: pa.Table, by_capture: bool = False) -> list[tuple[str, pa.ChunkedArray]]:
    """The sort key of a table's rows as columns without nulls, most significant first.

    The table's order (schema.sort_key): by SORT_COLUMN, missing last; findings then by their rule's
    rank (-1 when the rule is not registered); `by_capture` puts the capture first. Ties are left to
    the caller (arrival order). Each nullable part is a pair: 1 when missing (so it sorts last), then
    the value with missing filled."""
    parts = []
    if by_capture:
        cap = table.column("capture")
        parts += [("__cap_na", pc.cast(pc.is_null(cap), pa.int8())), ("__cap", pc.fill_null(cap, ""))]
    key = table.column(SORT_COLUMN[name])
    parts += [("__key_na", pc.cast(pc.is_null(key), pa.int8())), ("__key", pc.fill_null(key, 0))]
    if name == "findings":
        rank = pc.fill_null(pc.index_in(table.column("name"), value_set=_rules()), -1)
        parts.append(("__rank", pc.cast(rank, pa.int32())))
    return parts


def sort_indices(keys: pa.Table) -> pa.Array:
    """Indices that sort a table of key columns (order_keys' parts, then SEQ when given) ascending;
    a stable sort, so rows equal in every key keep their order."""
    return pc.sort_indices(keys, sort_keys=[(n, "ascending") for n in keys.column_names])


def table_order(name: str, table: pa.Table, by_capture: bool = False) -> pa.Array:
    """Indices that put a batch (its rows in arrival order) in table order, ties as they came."""
    parts = order_keys(name, table, by_capture)
    return sort_indices(pa.table(dict(parts)))


def frame_from_batches(name: str, tables: Iterable[pa.Table]) -> pd.DataFrame:
    """A typed DataFrame of one table from its batches (rows in arrival order, batch after batch), equal
    to `schema.frame_of` of the same rows: same dtypes, same order (ties as the rows came)."""
    import pandas as pd

    tables = [conform(name, t) for t in tables]
    table = pa.concat_tables(tables) if tables else batch_schema(name).empty_table()
    table = table.take(table_order(name, table))
    data = {}
    for c in COLUMNS[name]:
        col = table.column(c.name)
        if c.dtype == TIME:
            data[c.name] = col.to_pandas().astype(TIME)
        elif c.dtype in ("Int64", "Float64", "boolean"):
            data[c.name] = col.to_pandas(types_mapper={pa.int64(): pd.Int64Dtype(), pa.float64(): pd.Float64Dtype(),
                                                       pa.bool_(): pd.BooleanDtype()}.get)
        elif col.null_count == len(col):  # DataFrame.from_records infers object for a column of None only
            data[c.name] = pd.Series([None] * len(col), dtype=object).astype(pandas_dtype(c))
        else:
            data[c.name] = col.to_pandas().astype(pandas_dtype(c))
    return pd.DataFrame(data, index=pd.RangeIndex(len(table)))


def arrival_numbers(start: int, count: int) -> pa.Array:
    """SEQ values for `count` rows arriving after `start` others."""
    return pa.array(np.arange(start, start + count, dtype=np.int64))

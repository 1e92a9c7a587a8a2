"""Table files written a chunk of rows at a time: CSV, JSON Lines, and a Hive-partitioned Parquet dataset.

Cells are formatted from the column declarations of tables_out, the same way in every chunk, so the
files do not depend on where chunks start: times with microseconds always (`2026-01-01 00:00:00.000000+00:00`
in CSV, `2026-01-01T00:00:00.000000Z` in JSON), floats at full precision, empty cells (CSV) or null
(JSON) for missing values. CSV and JSON need neither pandas nor pyarrow; Parquet imports pyarrow when
the first Parquet file is opened, and pandas for the schema metadata that gives the same dtypes back
(pyarrow imports pandas anyway as soon as it converts a Python list).
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
from collections.abc import Callable, Sequence
from datetime import UTC, datetime, timedelta
from typing import Any
from urllib.parse import quote

from pd_analyze.analysis.schema import COLUMNS, FIXED_CATEGORIES, TIME, Column, micros

_FORMULA = re.compile(r"^[=+\-@\t\r]")
_NUMBER = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$")
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
_EPOCH_NAIVE = datetime(1970, 1, 1)


def neutralise(text: object) -> object:
    """A cell a spreadsheet would run as a formula gets a leading apostrophe; numbers stay numbers."""
    if isinstance(text, str) and _FORMULA.match(text) and not _NUMBER.match(text):
        return "'" + text
    return text


def _text(value: object) -> str | None:
    """A string cell as pandas' "string" dtype holds it: None stays missing, anything else str()."""
    if value is None or (isinstance(value, float) and value != value):
        return None
    return value if isinstance(value, str) else str(value)


def _float(value: object) -> float | None:
    if value is None:
        return None
    value = float(value)  # type: ignore[arg-type]
    return None if value != value else value  # NaN is missing, as in the Float64 column


def _category(col: Column) -> Callable[[object], str | None]:
    """Cells of a categorical: a fixed categorical has no cell for a value outside its categories."""
    fixed = FIXED_CATEGORIES.get(col.dtype)
    if fixed is None:
        return _text
    allowed = frozenset(fixed[0])
    return lambda v: v if v in allowed else None  # type: ignore[return-value]


def value_of(col: Column) -> Callable[[object], Any]:
    """The typed value of one cell (None when missing); times as whole microseconds."""
    if col.dtype == TIME:
        return micros
    if col.dtype == "Float64":
        return _float
    if col.dtype in ("Int64", "boolean"):
        return lambda v: v
    if col.dtype == "string":
        return _text
    return _category(col)


def csv_time(us: int) -> str:
    return (_EPOCH + timedelta(microseconds=us)).isoformat(" ", "microseconds")


def json_time(us: int) -> str:
    return (_EPOCH_NAIVE + timedelta(microseconds=us)).isoformat("T", "microseconds") + "Z"


_FORMULA_START = frozenset("=+-@\t\r")


class _Cells:
    """What a row needs before csv or json can write it: times formatted, NaN made missing, text cells
    made str, values outside fixed categories missing. Integers, booleans and None go out as they are."""

    def __init__(self, name: str, time_text: Callable[[int], str]) -> None:
        cols = COLUMNS[name]
        self.time_text = time_text
        self.times = [i for i, c in enumerate(cols) if c.dtype == TIME]
        self.floats = [i for i, c in enumerate(cols) if c.dtype == "Float64"]
        self.texts = [i for i, c in enumerate(cols) if c.dtype in ("string", "category")]
        self.fixed = [(i, frozenset(FIXED_CATEGORIES[c.dtype][0])) for i, c in enumerate(cols)
                      if c.dtype in FIXED_CATEGORIES]

    def row(self, row: tuple) -> list:
        out = list(row)
        for i in self.times:
            us = micros(out[i])
            out[i] = None if us is None else self.time_text(us)
        for i in self.floats:
            v = out[i]
            if v is not None:
                out[i] = _float(v)
        for i in self.texts:
            v = out[i]
            if v is not None and type(v) is not str:
                out[i] = _text(v)
        for i, allowed in self.fixed:
            if out[i] not in allowed:
                out[i] = None
        return out


class _Returned:
    """A file whose write() returns the text: csv.writer.writerow then returns the row's line."""

    @staticmethod
    def write(text: str) -> str:
        return text


class _LineWriter:
    """A text file of one line per row: `line(row)` is a row's text, written by `write_lines`;
    `write(rows)` does both."""

    path: str
    _file: Any

    def line(self, row: tuple) -> str:
        raise NotImplementedError

    def write_lines(self, lines: Sequence[str]) -> None:
        self._file.write("".join(lines))

    def write(self, rows: Sequence[tuple]) -> None:
        self.write_lines([self.line(row) for row in rows])

    def close(self) -> str:
        self._file.close()
        return self.path


class CsvWriter(_LineWriter):
    """One CSV file, header first; text cells a spreadsheet would run as a formula get an apostrophe."""

    def __init__(self, path: str, name: str) -> None:
        self.path = path
        self._cells = _Cells(name, csv_time)
        self._texts = self._cells.texts
        self._line = csv.writer(_Returned, lineterminator="\n").writerow  # None is written as an empty cell
        self._file = open(path, "w", newline="", encoding="utf-8")  # noqa: SIM115 - closed by close()
        self._file.write(self._line([c.name for c in COLUMNS[name]]))

    def line(self, row: tuple) -> str:
        cells = self._cells.row(row)
        for i in self._texts:  # the same test as neutralise(), inline: this runs for every text cell
            v = cells[i]
            if v and v[0] in _FORMULA_START and not _NUMBER.match(v):
                cells[i] = "'" + v
        return self._line(cells)


class JsonWriter(_LineWriter):
    """JSON Lines, ASCII only: one object per row, null for a missing value."""

    def __init__(self, path: str, name: str) -> None:
        self.path = path
        self._names = [c.name for c in COLUMNS[name]]
        self._cells = _Cells(name, json_time)
        self._floats = self._cells.floats
        self._encode = json.JSONEncoder(ensure_ascii=True, separators=(",", ":"), allow_nan=False).encode
        self._file = open(path, "w", encoding="ascii")  # noqa: SIM115 - closed by close()

    def line(self, row: tuple) -> str:
        cells = self._cells.row(row)
        for i in self._floats:  # JSON has no infinity: null, as for NaN
            if cells[i] is not None and not math.isfinite(cells[i]):
                cells[i] = None
        return self._encode(dict(zip(self._names, cells, strict=True))) + "\n"


class ParquetWriter:
    """A Hive-partitioned dataset DIR/capture=<file>/part-0.parquet, a row group per chunk and capture.

    Rows must come grouped by capture (the report sorts findings by capture for Parquet; the other
    tables are in transaction order, which runs file by file): one partition file is open at a time.
    Without rows, DIR/part-0.parquet holds the schema, capture column included."""

    def __init__(self, path: str, name: str) -> None:
        import pyarrow as pa

        self.path = path
        self._pa = pa
        self._cols = COLUMNS[name]
        self._capture = [c.name for c in self._cols].index("capture")
        self._schema = _arrow_schema(name)
        self._keep = [i for i in range(len(self._cols)) if i != self._capture]
        self._file_schema = pa.schema([self._schema.field(i) for i in self._keep], metadata=self._schema.metadata)
        self._values = [value_of(c) for c in self._cols]
        self._file: tuple[str, Any] | None = None  # capture, its open pyarrow.parquet.ParquetWriter
        self._closed: set[str] = set()
        os.makedirs(path, exist_ok=True)

    def write(self, rows: Sequence[tuple]) -> None:
        start = 0
        for i in range(1, len(rows) + 1):  # runs of one capture
            if i == len(rows) or rows[i][self._capture] != rows[start][self._capture]:
                self._write_run(rows[start:i])
                start = i

    def _write_run(self, rows: Sequence[tuple]) -> None:
        capture = str(rows[0][self._capture])
        if self._file is None or self._file[0] != capture:
            self._close_file()
            self._file = (capture, self._open(capture))
        columns = list(zip(*rows, strict=True))
        arrays = [self._array(i, columns[i]) for i in self._keep]
        self._file[1].write_table(self._pa.Table.from_arrays(arrays, schema=self._file_schema))

    def _open(self, capture: str) -> Any:
        import pyarrow.parquet as pq

        if capture in self._closed:  # a bug in the caller's order, never the capture's fault
            raise ValueError(f"rows of capture {capture!r} do not come together")
        folder = os.path.join(self.path, "capture=" + quote(capture, safe=""))
        if os.path.isdir(folder):  # as pandas' delete_matching: this partition is replaced
            for old in os.listdir(folder):
                if os.path.isfile(os.path.join(folder, old)):
                    os.unlink(os.path.join(folder, old))
        os.makedirs(folder, exist_ok=True)
        return pq.ParquetWriter(os.path.join(folder, "part-0.parquet"), self._file_schema)

    def _array(self, i: int, cells: Sequence[object]) -> Any:
        pa = self._pa
        col, kind = self._cols[i], self._schema.field(i).type
        if col.dtype == TIME:
            return pa.array([micros(v) for v in cells], pa.int64()).cast(pa.timestamp("us", tz="UTC")).cast(kind)
        fixed = FIXED_CATEGORIES.get(col.dtype)
        if fixed is not None:
            codes = {c: j for j, c in enumerate(fixed[0])}
            return pa.DictionaryArray.from_arrays(pa.array([codes.get(v) for v in cells], kind.index_type),
                                                  pa.array(fixed[0], kind.value_type), ordered=fixed[1])
        target = kind.value_type if pa.types.is_dictionary(kind) else kind
        try:  # whole columns at once; NaN is missing (from_pandas), as in the Float64 column
            array = pa.array(cells, target, from_pandas=True)
        except (pa.ArrowInvalid, pa.ArrowTypeError):  # a cell of another type: each cell as the DataFrame holds it
            array = pa.array([self._values[i](v) for v in cells], target)
        return array.dictionary_encode().cast(kind) if pa.types.is_dictionary(kind) else array

    def _close_file(self) -> None:
        if self._file is not None:
            self._file[1].close()
            self._closed.add(self._file[0])
            self._file = None

    def close(self) -> str:
        import pyarrow.parquet as pq

        self._close_file()
        if not self._closed:  # no partition to write: one file keeps the schema
            pq.write_table(self._schema.empty_table(), os.path.join(self.path, "part-0.parquet"))
        return self.path


def _arrow_schema(name: str) -> Any:
    """The Arrow schema of a table, with the pandas metadata that reads back as the DataFrame's dtypes.

    Categoricals with fixed categories keep int8 codes; the others get int32 codes, since a chunk cannot
    know how many values the whole column will have."""
    import pyarrow as pa

    from pd_analyze.analysis.schema import frame_of

    meta = pa.Schema.from_pandas(frame_of(name, []), preserve_index=False).metadata
    simple = {"Int64": pa.int64(), "string": pa.large_string(), "Float64": pa.float64(), "boolean": pa.bool_(),
              TIME: pa.timestamp("ns", tz="UTC"), "category": pa.dictionary(pa.int32(), pa.string())}
    fields = []
    for c in COLUMNS[name]:
        fixed = FIXED_CATEGORIES.get(c.dtype)
        kind = pa.dictionary(pa.int8(), pa.string(), ordered=fixed[1]) if fixed else simple[c.dtype]
        fields.append(pa.field(c.name, kind))
    return pa.schema(fields, metadata=meta)


WRITERS: dict[str, type[CsvWriter] | type[JsonWriter] | type[ParquetWriter]] = {
    "csv": CsvWriter, "json": JsonWriter, "parquet": ParquetWriter}


def open_table(out_dir: str, name: str, fmt: str) -> CsvWriter | JsonWriter | ParquetWriter:
    """The writer of one table in `out_dir`: name.csv, name.jsonl, or the dataset directory name/."""
    path = os.path.join(out_dir, name if fmt == "parquet" else f"{name}.{'jsonl' if fmt == 'json' else fmt}")
    return WRITERS[fmt](path, name)

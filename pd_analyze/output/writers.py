"""Table files written a chunk of rows at a time: CSV, JSON Lines, and a Hive-partitioned Parquet dataset.

Cells are formatted from the column declarations of tables_out, the same way in every chunk, so the
files do not depend on where chunks start: a row's times and durations at its capture's resolution
(model.times; `digits`, the dict Rows.digits, read when a row is formatted): a microsecond capture's
times `2026-01-01 00:00:00.002936+00:00` in CSV, `2026-01-01T00:00:00.002936Z` in JSON, its durations
`0.001499` (never in exponent form, in JSON a number too); a nanosecond capture's with nine decimals;
empty cells (CSV) or null (JSON) for missing values. CSV and JSON need neither pandas nor pyarrow;
Parquet imports pyarrow when the first Parquet file is opened, and pandas for the schema metadata that
gives the same dtypes back (pyarrow imports pandas anyway as soon as it converts a Python list). Parquet
keeps times as timestamp[ns] and durations as doubles, exactly.

`write_batch(table)` writes rows that come as a pyarrow batch (table_batches.batch_schema) into the same
bytes: CSV formatted a column at a time (batch_cells), JSON Lines through the same encoder, Parquet with
the same dictionaries and partitions. CSV and JSON can also format ahead (`format_batch`) and write the
lines later (`write_formatted`), so that table_sink sorts one column of lines.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
from collections.abc import Callable, Mapping, Sequence
from typing import Any
from urllib.parse import quote

from pd_analyze.analysis.schema import COLUMNS, FIXED_CATEGORIES, TIME, float_cell, text_cell
from pd_analyze.analysis.schema import cell_value as value_of
from pd_analyze.model.times import DEFAULT_DIGITS, duration_text, nanos, time_text

_FORMULA = re.compile(r"^[=+\-@\t\r]")
# A number, or a list of numbers separated by single spaces (values_written "-775.375 2225.25"): data a
# spreadsheet cannot run, so never prefixed; the formula guard is for free text only.
_NUMBER_TOKEN = r"([+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?|[+-]?inf|nan)"
_NUMBER = re.compile(rf"^{_NUMBER_TOKEN}( {_NUMBER_TOKEN})*$")
CSV_BATCH_ROWS = 65_536  # rows formatted a column at a time at once (each call costs some microseconds)


def neutralise(text: object) -> object:
    """A cell a spreadsheet would run as a formula gets a leading apostrophe; numbers stay numbers."""
    if isinstance(text, str) and _FORMULA.match(text) and not _NUMBER.match(text):
        return "'" + text
    return text


def csv_time(ns: int, digits: int = DEFAULT_DIGITS) -> str:
    return time_text(ns, digits)


def json_time(ns: int, digits: int = DEFAULT_DIGITS) -> str:
    return time_text(ns, digits, "T", "Z")


_FORMULA_START = frozenset("=+-@\t\r")


class _Cells:
    """What a row needs before csv or json can write it: times and durations as text at the row's capture's
    resolution (`digits` by capture), NaN made missing (for JSON, `finite`, infinity too), text cells made
    str, values outside fixed categories missing. Integers, booleans and None go out as they are."""

    def __init__(self, name: str, time_text: Callable[[int, int], str], digits: Mapping[str, int] | None,
                 finite: bool = False) -> None:
        self.cols = cols = COLUMNS[name]
        self.time_text = time_text
        self.digits = {} if digits is None else digits  # (the caller's dict: a capture may be learnt later)
        self.finite = finite
        self.capture = [c.name for c in cols].index("capture")
        self.times = [i for i, c in enumerate(cols) if c.dtype == TIME]
        self.floats = [i for i, c in enumerate(cols) if c.dtype == "Float64"]
        self.texts = [i for i, c in enumerate(cols) if c.dtype in ("string", "category")]
        self.fixed = [(i, frozenset(FIXED_CATEGORIES[c.dtype][0])) for i, c in enumerate(cols)
                      if c.dtype in FIXED_CATEGORIES]

    def row(self, row: tuple) -> list:
        out = list(row)
        digits = self.digits.get(text_cell(out[self.capture]), DEFAULT_DIGITS)  # type: ignore[arg-type]
        for i in self.times:
            ns = nanos(out[i])
            out[i] = None if ns is None else self.time_text(ns, digits)
        for i in self.floats:
            v = out[i]
            if v is not None:
                v = float_cell(v)
                out[i] = None if v is None or (self.finite and not math.isfinite(v)) else duration_text(v, digits)
        for i in self.texts:
            v = out[i]
            if v is not None and type(v) is not str:
                out[i] = text_cell(v)
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

    def __init__(self, path: str, name: str, digits: Mapping[str, int] | None = None) -> None:
        self.path = path
        self._cells = _Cells(name, csv_time, digits)
        self._texts = self._cells.texts
        self._name = name
        self._line = csv.writer(_Returned, lineterminator="\n").writerow  # None is written as an empty cell
        self._file = open(path, "w", newline="", encoding="utf-8")  # noqa: SIM115 - closed by close()
        self._file.write(self._line([c.name for c in COLUMNS[name]]))

    def write_batch(self, table: Any) -> None:
        """Rows of a pyarrow Table of batch_schema(name), in table order (as TableSink hands them on):
        the same bytes `write` writes for the same rows, formatted a column at a time."""
        self.write_formatted(self.format_batch(table))

    def format_batch(self, table: Any) -> Any:
        """The CSV lines of a batch's rows (a pyarrow ChunkedArray, one line a row), to be written later."""
        import pyarrow as pa

        from pd_analyze.output.batch_cells import csv_lines

        batches = table.combine_chunks().to_batches(max_chunksize=CSV_BATCH_ROWS)  # few calls: each costs
        return pa.chunked_array([csv_lines(self._name, b, self._cells.digits) for b in batches], pa.large_string())

    def write_formatted(self, lines: Any) -> None:
        """Lines made by format_batch (or pieces of them, in any order the caller chose)."""
        from pd_analyze.output.batch_cells import string_data

        self._file.flush()  # the header and any rows written as text go first
        for chunk in lines.chunks:
            self._file.buffer.write(string_data(chunk))

    def line(self, row: tuple) -> str:
        cells = self._cells.row(row)
        for i in self._texts:  # the same test as neutralise(), inline: this runs for every text cell
            v = cells[i]
            if v and v[0] in _FORMULA_START and not _NUMBER.match(v):
                cells[i] = "'" + v
        return self._line(cells)


class JsonWriter(_LineWriter):
    """JSON Lines, ASCII only: one object per row, null for a missing value (and for infinity)."""

    def __init__(self, path: str, name: str, digits: Mapping[str, int] | None = None) -> None:
        self.path = path
        self._names = [c.name for c in COLUMNS[name]]
        self._cells = _Cells(name, json_time, digits, finite=True)
        self._encode = json.JSONEncoder(ensure_ascii=True, separators=(",", ":"), allow_nan=False).encode
        # the columns in runs: durations (numbers written as their text, which json would write in exponent
        # form below 1e-4) and the others (encoded together, as one object's members)
        floats = set(self._cells.floats)
        self._runs: list[tuple[bool, list[int]]] = []
        for i in range(len(self._names)):
            if self._runs and self._runs[-1][0] == (i in floats):
                self._runs[-1][1].append(i)
            else:
                self._runs.append((i in floats, [i]))
        self._file = open(path, "w", encoding="ascii")  # noqa: SIM115 - closed by close()

    def _object(self, cells: Sequence[object]) -> str:
        """A row's line from its cells (durations as text): what json writes for the same object."""
        names, encode = self._names, self._encode
        if len(self._runs) == 1:
            return encode(dict(zip(names, cells, strict=True))) + "\n"
        parts = []
        for numbers, run in self._runs:
            if numbers:
                parts += [f'"{names[i]}":{"null" if cells[i] is None else cells[i]}' for i in run]
            else:
                parts.append(encode({names[i]: cells[i] for i in run})[1:-1])
        return "{" + ",".join(parts) + "}\n"

    def line(self, row: tuple) -> str:
        return self._object(self._cells.row(row))

    def write_batch(self, table: Any) -> None:
        """Rows of a pyarrow Table of batch_schema(name), in table order: the same bytes `write` writes
        for the same rows (the cells become Python values again and go through the same encoder)."""
        self.write_formatted(self.format_batch(table))

    def format_batch(self, table: Any) -> Any:
        """The JSON lines of a batch's rows (a pyarrow ChunkedArray, one line a row), to be written later."""
        import pyarrow as pa
        import pyarrow.compute as pc

        from pd_analyze.output.batch_cells import duration_text, row_digits
        from pd_analyze.output.batch_cells import time_text as times

        table = table.combine_chunks()
        digits = row_digits(table.column("capture").combine_chunks(), self._cells.digits) if table.num_rows else 0
        columns = []
        for c, values in zip(self._cells.cols, table.columns, strict=True):
            values = values.combine_chunks()
            if c.dtype == TIME:
                columns.append(times(values, digits, "T", "Z").to_pylist())
            elif c.dtype == "Float64":  # JSON has no infinity (nor NaN): null
                text = duration_text(values, digits)
                columns.append(pc.if_else(pc.is_finite(values), text, pa.scalar(None, text.type)).to_pylist())
            else:
                columns.append(values.to_pylist())
        line = self._object
        return pa.chunked_array([pa.array([line(row) for row in zip(*columns, strict=True)], pa.large_string())])

    def write_formatted(self, lines: Any) -> None:
        """Lines made by format_batch (or pieces of them, in any order the caller chose)."""
        from pd_analyze.output.batch_cells import string_data

        self._file.flush()
        for chunk in lines.chunks:
            self._file.buffer.write(string_data(chunk))


class ParquetWriter:
    """A Hive-partitioned dataset DIR/capture=<file name>/part-0.parquet, a row group per chunk and capture.

    Rows must come grouped by capture (the report sorts findings by capture for Parquet; the other
    tables are in transaction order, which runs file by file): one partition file is open at a time.
    Without rows, DIR/part-0.parquet holds the schema, capture column included."""

    def __init__(self, path: str, name: str, digits: Mapping[str, int] | None = None) -> None:
        import pyarrow as pa

        self.path = path  # (`digits` unused: Parquet keeps every time and duration exactly)
        self._pa = pa
        self._cols = COLUMNS[name]
        self._capture = [c.name for c in self._cols].index("capture")
        self._schema = _arrow_schema(name)
        self._keep = [i for i in range(len(self._cols)) if i != self._capture]
        self._file_schema = pa.schema([self._schema.field(i) for i in self._keep], metadata=self._schema.metadata)
        self._values = [value_of(c) for c in self._cols]
        self._file: tuple[str, Any] | None = None  # capture, its open pyarrow.parquet.ParquetWriter
        self._closed: set[str] = set()
        self._partitions: dict[str, str] = {}  # capture path -> its partition name
        os.makedirs(path, exist_ok=True)

    def write(self, rows: Sequence[tuple]) -> None:
        start = 0
        for i in range(1, len(rows) + 1):  # runs of one capture
            if i == len(rows) or rows[i][self._capture] != rows[start][self._capture]:
                self._write_run(rows[start:i])
                start = i

    def _write_run(self, rows: Sequence[tuple]) -> None:
        self._switch(str(rows[0][self._capture]))
        columns = list(zip(*rows, strict=True))
        arrays = [self._array(i, columns[i]) for i in self._keep]
        self._file[1].write_table(self._pa.Table.from_arrays(arrays, schema=self._file_schema))

    def write_batch(self, table: Any) -> None:
        """Rows of a pyarrow Table of batch_schema(name), in table order and grouped by capture (as
        TableSink hands them on; findings with by_capture): the same files `write` writes."""
        import numpy as np
        import pyarrow.compute as pc

        if not table.num_rows:
            return
        capture = pc.fill_null(table.column("capture"), "None").combine_chunks()  # str(None), as write() names it
        starts = [0, *(np.flatnonzero(pc.not_equal(capture[1:], capture[:-1]).to_numpy(zero_copy_only=False)) + 1)]
        for start, end in zip(starts, [*starts[1:], len(capture)], strict=True):  # runs of one capture
            self._switch(capture[start].as_py())
            run = table.slice(start, end - start)
            arrays = [self._batch_array(i, run.column(i)) for i in self._keep]
            self._file[1].write_table(self._pa.Table.from_arrays(arrays, schema=self._file_schema))  # type: ignore[index]

    def _batch_array(self, i: int, values: Any) -> Any:
        """A batch column as _array makes it: times in ns, fixed categoricals int8 codes of their
        categories, the other categoricals int32 dictionaries."""
        import pyarrow.compute as pc

        pa = self._pa
        kind = self._schema.field(i).type
        fixed = FIXED_CATEGORIES.get(self._cols[i].dtype)
        values = values.combine_chunks()
        if fixed is not None:
            codes = pc.index_in(values, value_set=pa.array(fixed[0], values.type)).cast(kind.index_type)
            return pa.DictionaryArray.from_arrays(codes, pa.array(fixed[0], kind.value_type), ordered=fixed[1])
        if pa.types.is_dictionary(kind):
            return pc.dictionary_encode(values).cast(kind)
        return values.cast(kind)

    def _switch(self, capture: str) -> None:
        """The partition file of this capture open (a new partition closes the one before)."""
        if self._file is None or self._file[0] != capture:
            self._close_file()
            self._file = (capture, self._open(capture))

    def _open(self, capture: str) -> Any:
        import pyarrow.parquet as pq

        if capture in self._closed:  # a bug in the caller's order, never the capture's fault
            raise ValueError(f"rows of capture {capture!r} do not come together")
        folder = os.path.join(self.path, "capture=" + quote(self._partition(capture), safe=""))
        if os.path.isdir(folder):  # as pandas' delete_matching: this partition is replaced
            for old in os.listdir(folder):
                if os.path.isfile(os.path.join(folder, old)):
                    os.unlink(os.path.join(folder, old))
        os.makedirs(folder, exist_ok=True)
        return pq.ParquetWriter(os.path.join(folder, "part-0.parquet"), self._file_schema)

    def _partition(self, capture: str) -> str:
        """The partition of a capture: its file name (a reader's `capture` column), made unique with ~2,
        ~3, ... when captures of the same name in other directories share the dataset."""
        name = self._partitions.get(capture)
        if name is None:
            base = os.path.basename(capture) or capture
            taken = set(self._partitions.values())
            name, k = base, 1
            while name in taken:
                k += 1
                name = f"{base}~{k}"
            self._partitions[capture] = name
        return name

    def _array(self, i: int, cells: Sequence[object]) -> Any:
        pa = self._pa
        col, kind = self._cols[i], self._schema.field(i).type
        if col.dtype == TIME:
            return pa.array([nanos(v) for v in cells], pa.int64()).cast(kind)
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


def open_table(out_dir: str, name: str, fmt: str,
               digits: Mapping[str, int] | None = None) -> CsvWriter | JsonWriter | ParquetWriter:
    """The writer of one table in `out_dir`: name.csv, name.jsonl, or the dataset directory name/; `digits`:
    each capture's resolution (Rows.digits, the same dict: captures read later are written at theirs)."""
    path = os.path.join(out_dir, name if fmt == "parquet" else f"{name}.{'jsonl' if fmt == 'json' else fmt}")
    return WRITERS[fmt](path, name, digits)

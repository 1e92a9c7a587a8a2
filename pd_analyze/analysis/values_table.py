"""`Analysis.values`: every value written or read, one row each and typed, for pandas users.

The `parameters` table holds a parameter's values as one text cell ("-775.375 2225.25"), as a reader and a
CSV want them. This long table splits them back into one typed value per array element: the cell texts are
exact (integers, hex, the shortest float text that reads back to the same bits), so nothing is lost.
"""

from __future__ import annotations

import ast

import pandas as pd

from pd_analyze.model import pd_values as pt

_TEXT_FORMATS = frozenset(pt.FORMAT_NAME[code] for code, f in pt.FORMATS.items()
                          if f.kind in ("string", "unicode", "octets"))
_FLOAT_FORMATS = frozenset(pt.FORMAT_NAME[code] for code, f in pt.FORMATS.items() if f.kind == "float")
COLUMNS = ("txn", "capture", "device", "do", "param", "pnu", "pnu_name", "side", "element", "format", "value",
           "number")


def values_frame(parameters: pd.DataFrame) -> pd.DataFrame:
    """One row per value of `parameters.values_written` (side "written") and `values_read` ("read"):
    element = subindex + position for Value access; value as int, float or str; number as Float64 (the
    value when it is a number, else missing)."""
    out: dict[str, list] = {c: [] for c in COLUMNS}
    for r in parameters.itertuples(index=False):
        for side, cell in (("written", r.values_written), ("read", r.values_read)):
            if not isinstance(cell, str) or not cell:
                continue
            if r.format in _TEXT_FORMATS:
                values: list[object] = [_text(cell)]
            elif r.format in _FLOAT_FORMATS:  # 1500 is a float here: the shortest text drops ".0"
                values = [float(t) for t in cell.split(" ")]
            else:
                values = [_number(t) for t in cell.split(" ")]
            first = 0 if pd.isna(r.subindex) or r.attribute != "Value" else int(r.subindex)
            for k, value in enumerate(values):
                for name, item in zip(COLUMNS, (r.txn, r.capture, r.device, r.do, r.param, r.pnu, r.pnu_name, side,
                                                first + k, r.format, value, _float(value)), strict=True):
                    out[name].append(item)
    frame = pd.DataFrame(out, columns=list(COLUMNS))
    frame["value"] = pd.Series(out["value"], dtype=object)
    types = {"txn": "Int64", "capture": "category", "device": "category", "do": "Int64", "param": "string",
             "pnu": "Int64", "pnu_name": "string", "side": "category", "element": "Int64", "format": "category",
             "number": "Float64"}
    return frame.astype(types)


def _number(token: str) -> object:
    """A value token as its number: 0x.. (Byte, Word, bit fields) and integers as int, floats as float."""
    try:
        return int(token, 16) if token.startswith("0x") else int(token)
    except ValueError:
        pass
    try:
        return float(token)
    except ValueError:
        return token


def _text(cell: str) -> str:
    """A string value as text: a cell holds it as is, in double quotes when it has spaces, or as Python's
    repr when it has characters that are not printable (escapes resolved here)."""
    if cell[:1] in ("'", '"') and len(cell) >= 2 and cell[-1] == cell[0]:
        try:
            value = ast.literal_eval(cell)
        except (ValueError, SyntaxError):
            value = None
        if isinstance(value, str) and not value.isprintable():
            return value
        if cell[0] == '"':
            return cell[1:-1]
    return cell


def _float(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) else None

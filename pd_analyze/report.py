"""The report: the four tables written as files, and a summary worst offenders first."""

from __future__ import annotations

import os
import re

import pandas as pd

from pd_analyze.analysis import Analysis
from pd_analyze.tables_out import COLUMNS

TABLES = tuple(COLUMNS)
_FORMULA = re.compile(r"^[=+\-@\t\r]")
_NUMBER = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$")


def neutralise(text: object) -> object:
    """A cell a spreadsheet would run as a formula gets a leading apostrophe; numbers stay numbers."""
    if isinstance(text, str) and _FORMULA.match(text) and not _NUMBER.match(text):
        return "'" + text
    return text


def write_tables(analysis: Analysis, out_dir: str, fmt: str) -> list[str]:
    """transactions, parameters, findings, changes as csv / parquet / json (JSON Lines) files."""
    os.makedirs(out_dir, exist_ok=True)
    written = []
    for name in TABLES:
        df: pd.DataFrame = getattr(analysis, name)
        path = os.path.join(out_dir, f"{name}.{'jsonl' if fmt == 'json' else fmt}")
        if fmt == "csv":
            safe = df.copy()
            for col in safe.columns:
                if safe[col].dtype == "string" or isinstance(safe[col].dtype, pd.CategoricalDtype):
                    safe[col] = safe[col].astype("object").map(neutralise)
            safe.to_csv(path, index=False)
        elif fmt == "parquet":
            path = _parquet_dataset(df, os.path.join(out_dir, name))
        else:
            df.to_json(path, orient="records", lines=True, date_format="iso", date_unit="us")
        written.append(path)
    return written


def _parquet_dataset(df: pd.DataFrame, path: str) -> str:
    """A Hive-partitioned dataset DIR/<table>/capture=<file>/part-0.parquet (DuckDB, Spark, Dask read it)."""
    os.makedirs(path, exist_ok=True)
    if df.empty:  # no partition to write: one file keeps the schema
        df.to_parquet(os.path.join(path, "part-0.parquet"), index=False)
        return path
    df.to_parquet(path, index=False, partition_cols=["capture"], existing_data_behavior="delete_matching",
                  basename_template="part-{i}.parquet")
    return path


def _ms(seconds: float) -> str:
    return "-" if pd.isna(seconds) else f"{seconds * 1000:.1f}"


def summary(analysis: Analysis, top: int = 10) -> str:
    """Verdict counts; NAKs by device, DO, PNU and error; B5 retries; latency per device."""
    t, p = analysis.transactions, analysis.parameters
    lines = []
    for row in analysis.accounting.itertuples():
        line = (f"{row.capture}: {row.read} frames read = {row.decoded} decoded + {row.skipped} skipped + "
                f"{row.malformed} malformed; {row.transactions} transactions")
        lines.append(line + (f"; ERROR {row.error}" if row.error else ""))
        for kind, reasons in (("skipped", row.skipped_by_reason), ("malformed", row.malformed_by_reason)):
            if reasons:  # the invariant by reason: every frame is accounted for
                lines.append(f"  {kind}: " + "; ".join(f"{n} {why}" for why, n in
                                                       sorted(reasons.items(), key=lambda item: -item[1])))
    lines.append("")
    if t.empty:
        lines.append("No PROFIdrive transactions found.")
        return "\n".join(lines)
    counts = t.verdict.value_counts()
    lines.append(f"Transactions: {len(t)}  " + "  ".join(f"{v}={counts.get(v, 0)}" for v in
                                                         ("ok", "nak", "reference_mismatch", "timeout",
                                                          "pnio_error", "malformed")))
    failed = t[t.verdict != "ok"]
    if not failed.empty:
        lines.append("")
        lines.append("Failures by device (worst first):")
        by_dev = failed.groupby("device", observed=True).verdict.value_counts().unstack(fill_value=0)
        by_dev = by_dev.assign(total=by_dev.sum(axis=1)).sort_values("total", ascending=False)
        for dev, row in by_dev.head(top).iterrows():
            detail = ", ".join(f"{k}={int(v)}" for k, v in row.items() if k != "total" and v)
            lines.append(f"  {dev:<16} {int(row.total):>6}  ({detail})")
    errs = p[p.error.fillna("") != ""]
    if not errs.empty:
        lines.append("")
        lines.append("NAKs by PNU and error number (worst first):")
        grouped = errs.groupby(["device", "do", "param", "error", "error_text"], observed=True, dropna=False)
        for (dev, do, param, err, text), n in grouped.size().sort_values(ascending=False).head(top).items():
            lines.append(f"  {n:>6}  {dev} DO {do} {param} error {err} ({text})")
        lines.append("  by error number: " + ", ".join(f"{e}={n}" for e, n in errs.error.value_counts().items()))
        lines.append("  by DO: " + ", ".join(f"{d}={n}" for d, n in errs["do"].value_counts().items()))
    b5 = t[t.b5_retries > 0]
    lines.append("")
    lines.append(f"B5 retries: {int(t.b5_retries.sum())} in {len(b5)} transactions"
                 + (f" (max {int(t.b5_retries.max())} in transaction {int(t.loc[t.b5_retries.idxmax(), 'txn'])})"
                    if len(b5) else ""))
    done = t[t.t_total.notna()]
    if not done.empty:
        lines.append("")
        lines.append("Latency per device, ms (write to final response; slowest first):")
        lines.append(f"  {'device':<16} {'n':>6} {'p50':>8} {'p90':>8} {'p99':>8} {'max':>8}  write rtt p50")
        stats = done.groupby("device", observed=True).agg(
            n=("t_total", "size"), p50=("t_total", lambda s: s.quantile(0.5)),
            p90=("t_total", lambda s: s.quantile(0.9)), p99=("t_total", lambda s: s.quantile(0.99)),
            max=("t_total", "max"), w50=("t_write_rtt", lambda s: s.quantile(0.5)))
        for dev, row in stats.sort_values("p90", ascending=False).head(top).iterrows():
            lines.append(f"  {dev:<16} {int(row.n):>6} {_ms(row.p50):>8} {_ms(row.p90):>8} {_ms(row.p99):>8} "
                         f"{_ms(row['max']):>8}  {_ms(row.w50)}")
    f = analysis.findings
    if not f.empty:
        lines.append("")
        sev = f.severity.value_counts()
        lines.append(f"Findings: {len(f)}  " + "  ".join(f"{s}={sev.get(s, 0)}" for s in ("error", "warning", "info")))
        for (rule, name), n in f.groupby(["rule", "name"], observed=True).size().sort_values(
                ascending=False).head(top).items():
            lines.append(f"  {n:>6}  {rule} {name}")
    return "\n".join(lines)

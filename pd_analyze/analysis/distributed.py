"""Lazy Dask DataFrames over many captures, one partition per capture (extra `pd-analyze[dask]`).

    from dask.distributed import Client
    import pd_analyze.analysis.distributed
    client = Client()                                   # or a cluster's scheduler address
    t = pd_analyze.analysis.distributed.analyze("captures/*.pcapng").transactions
    t[t.verdict != "ok"].groupby("device").size().compute()

Each capture is analysed by one task on whichever worker gets it; the four tables share that task.
Transaction numbers (`txn`) count per capture here: (capture, txn) identifies a transaction.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import NamedTuple

import dask
import dask.dataframe as dd
import pandas as pd

from pd_analyze.analysis.api import accounting_frame, expand, table_frame
from pd_analyze.analysis.capture_run import DEFAULT_TXN_TIMEOUT, CaptureResult, Settings
from pd_analyze.analysis.jobs import analyze_file
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.schema import COLUMNS, frame_of
from pd_analyze.protocol import profiles
from pd_analyze.protocol.dissector import DEFAULT_RPC_TIMEOUT


class Tables(NamedTuple):
    transactions: dd.DataFrame
    parameters: dd.DataFrame
    findings: dd.DataFrame
    changes: dd.DataFrame
    accounting: dd.DataFrame


def _table(part: tuple[Rows, object], name: str) -> pd.DataFrame:
    return table_frame(part[0], name)  # (the engine's rows come as pyarrow tables, Rows.add_table)


def _accounting(part: tuple[Rows, CaptureResult]) -> pd.DataFrame:
    return accounting_frame([part[1]])


def analyze(paths: str | Iterable[str], profile: str = profiles.DEFAULT, timeout: float = DEFAULT_TXN_TIMEOUT,
            rpc_timeout: float = DEFAULT_RPC_TIMEOUT) -> Tables:
    """The tables of `paths` (files, directories, globs) as lazy Dask DataFrames, one partition per capture."""
    profiles.load(profile)
    files = expand(paths)
    settings = Settings(profile, timeout, rpc_timeout)
    parts = [dask.delayed(analyze_file, pure=True)(path, settings, dask_key_name=f"pd-analyze-{i}-{path}")
             for i, path in enumerate(files)]
    tables = {name: dd.from_delayed([dask.delayed(_table)(part, name) for part in parts],
                                    meta=frame_of(name, []), verify_meta=False)
              for name in COLUMNS}
    accounting = dd.from_delayed([dask.delayed(_accounting)(part) for part in parts], meta=accounting_frame([]))
    return Tables(accounting=accounting, **tables)


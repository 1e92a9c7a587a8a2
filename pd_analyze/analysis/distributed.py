"""Lazy Dask DataFrames over many captures, one partition per capture (extra `pd-analyze[dask]`).

    from dask.distributed import Client
    import pd_analyze.analysis.distributed
    client = Client()                                   # or a cluster's scheduler address
    t = pd_analyze.analysis.distributed.analyze("captures/*.pcapng").transactions
    t[t.verdict != "ok"].groupby("device").size().compute()

Each capture is analysed by one task on whichever worker gets it; the four tables share that task.
Transaction numbers (`txn`) count per capture here: (capture, txn) identifies a transaction.

One large capture is better taken by `analyze_capture`: a plain pcap is cut into byte ranges at record
boundaries (capture.split), each range read and decoded by a task on the cluster (the workers must see
the file at the same path), and the one engine runs in this process over the ranges' batches in frame
order (analysis.split), so the tables are those of one process, exactly:

    t = pd_analyze.analysis.distributed.analyze_capture("day.pcap", client=client).transactions
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from typing import NamedTuple

import dask
import dask.dataframe as dd
import pandas as pd

from pd_analyze.analysis import split
from pd_analyze.analysis.api import Analysis, accounting_frame, expand, table_frame
from pd_analyze.analysis.capture_run import DEFAULT_TXN_TIMEOUT, CaptureResult, Settings
from pd_analyze.analysis.engine.run import run_batches
from pd_analyze.analysis.jobs import analyze_file
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.schema import COLUMNS, frame_of
from pd_analyze.capture.split import PIECE_BYTES
from pd_analyze.protocol import profiles
from pd_analyze.protocol.dissector import DEFAULT_RPC_TIMEOUT
from pd_analyze.protocol.frames import Accounting


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



def analyze_capture(path: str, profile: str = profiles.DEFAULT, timeout: float = DEFAULT_TXN_TIMEOUT,
                    rpc_timeout: float = DEFAULT_RPC_TIMEOUT, client: object = None, piece_bytes: int = PIECE_BYTES,
                    window: int = 0) -> Tables:
    """The tables of one capture, its byte ranges (pieces of about `piece_bytes`) read and decoded as tasks
    on the cluster of `client` (default: the current client), at most `window` of them on their way at once
    (0: twice the cluster's threads); the engine runs here over them in frame order. A pcapng or gzip
    capture is read here and its batches sent to the cluster to be decoded. The tables equal
    pd_analyze.analyze(path)'s, each one Dask partition; `txn` counts as in one process."""
    from dask.distributed import get_client

    profiles.load(profile)
    client = client or get_client()
    settings = Settings(profile, timeout, rpc_timeout)
    window = window or max(2, 2 * sum(client.nthreads().values()))  # type: ignore[attr-defined]
    submit = functools.partial(client.submit, pure=False)  # type: ignore[attr-defined]
    rows = Rows()
    result = CaptureResult(path, Accounting())
    result.accounting = run_batches(split.decoded(path, settings, submit, window, piece_bytes), settings, rows,
                                    lambda _frame: path, [result], None)
    analysis = Analysis(rows, [result], profile, timeout, rpc_timeout)
    with dask.config.set({"dataframe.convert-string": False}):  # the tables' own dtypes, as analyze() gives them
        tables = {name: dd.from_pandas(getattr(analysis, name), npartitions=1) for name in COLUMNS}
        return Tables(accounting=dd.from_pandas(analysis.accounting, npartitions=1), **tables)

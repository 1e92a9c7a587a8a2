"""One capture on several cores: its pieces decoded in worker processes, the one engine run over them in
frame order in this process (`--jobs N` on one file; analysis.distributed does the same on a cluster).

Exact by construction: what the workers do is the column decode of a batch (`BatchView.parts`), which
needs no state from any other batch or frame; everything that does (the per-frame dissector's IP and CL
reassembly, pairing, the transactions' machine, the caps, the clock, numbering, accounting) stays in the
one `EngineRun` of this process, fed the batches in frame order exactly as one process feeds them. The
engine's tables do not depend on where batches begin (tests/test_columnar.py, tests/test_split.py), so a
piece's batches need not be those of one reader of the whole file.

A plain pcap is cut into pieces at record boundaries (capture.split) that the workers read themselves;
any other capture (pcapng, gzip) is read here, as one process reads it, and its batches are sent to the
workers for their decode. Either way at most `jobs` pieces or batches are on their way at once
(memory), and a damaged file's error comes after every good frame, as one process reports it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future

from pd_analyze.analysis.capture_run import CaptureResult, Progress, Settings
from pd_analyze.analysis.engine.run import run_batches
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.analysis.rows import Rows
from pd_analyze.capture import CaptureError
from pd_analyze.capture.batches import BATCH_FRAMES, FrameBatch, batches
from pd_analyze.capture.split import PIECE_BYTES, Piece, piece_batches, pieces
from pd_analyze.protocol.frames import Accounting
from pd_analyze.protocol.profidrive_checks import Checker

Views = list[tuple[FrameBatch, BatchView]]
Decoded = tuple[FrameBatch, Views]


def analyze_file(path: str, settings: Settings, jobs: int, progress: Progress | None = None,
                 rows: Rows | None = None, offset: int = 0, piece_bytes: int | None = None,
                 piece_frames: int = 0) -> tuple[Rows, CaptureResult]:
    """One capture, its decode in `jobs` - 1 worker processes and the engine here (the tables, accounting
    and error those of engine.files.analyze_file)."""
    from concurrent.futures import ProcessPoolExecutor

    rows = Rows() if rows is None else rows
    result = CaptureResult(path, Accounting())
    with ProcessPoolExecutor(max_workers=max(1, jobs - 1)) as pool:
        source = decoded(path, settings, pool.submit, jobs, piece_bytes, piece_frames)
        result.accounting = run_batches(source, settings, rows, lambda _frame: path, [result], progress, offset)
    return rows, result


def decoded(path: str, settings: Settings, submit: Callable[..., Future], window: int,
            piece_bytes: int | None = None, piece_frames: int = 0) -> Iterator[Decoded]:
    """The capture's batches with their column decode, in frame order, the decode made by `submit`'s
    workers (at most `window` tasks on their way); then the capture's CaptureError, if any."""
    size = settings.batch_frames or BATCH_FRAMES
    cut = pieces(path, piece_bytes or PIECE_BYTES, piece_frames, size)
    if cut is not None and len(cut) > 1:
        yield from in_order((submit(decode_piece, path, piece, settings) for piece in cut), window)
    else:
        yield from _read_here(path, settings, submit, window)


def in_order(tasks: Iterator[Future], window: int) -> Iterator[Decoded]:
    """The pieces' batches in the order of `tasks` (each a piece's (batches, error)), at most `window`
    tasks started ahead; a piece's error ends the capture after its good batches."""
    waiting: deque[Future] = deque()
    for task in tasks:
        waiting.append(task)
        if len(waiting) >= window:
            yield from _done(waiting.popleft())
    while waiting:
        yield from _done(waiting.popleft())


def _done(task: Future) -> Iterator[Decoded]:
    got, error = task.result()
    yield from got
    if error is not None:
        raise error


def _read_here(path: str, settings: Settings, submit: Callable[..., Future], window: int) -> Iterator[Decoded]:
    """A capture read in this process (pcapng, gzip, a pcap of one piece), each batch decoded by a worker;
    the reader's error after every batch read before it."""
    waiting: deque[tuple[FrameBatch, Future]] = deque()
    size = settings.batch_frames or BATCH_FRAMES
    try:
        for batch in batches(path, size):
            waiting.append((batch, submit(decode_batch, batch, settings)))
            if len(waiting) >= window:
                yield _attached(*waiting.popleft())
    except CaptureError:
        while waiting:
            yield _attached(*waiting.popleft())
        raise
    while waiting:
        yield _attached(*waiting.popleft())


def _attached(batch: FrameBatch, task: Future) -> Decoded:
    """A batch with the views a worker made of it, given back their frames (the worker does not send the
    batch's bytes back: this process holds them)."""
    views = []
    for start, stop, view in task.result():
        part = batch.part(start, stop)
        view.batch = part
        views.append((part, view))
    return batch, views


# --- in the workers ------------------------------------------------------------------------------------
_CHECKERS: dict[str, Checker] = {}


def _checker(settings: Settings) -> Checker:
    if settings.profile not in _CHECKERS:
        _CHECKERS[settings.profile] = settings.checker()
    return _CHECKERS[settings.profile]


def decode_piece(path: str, piece: Piece, settings: Settings) -> tuple[list[Decoded], CaptureError | None]:
    """A piece of a pcap read and decoded (a worker's task): its batches with their views, and the error
    that ended it (the last piece of a damaged file), if any."""
    out: list[Decoded] = []
    checker = _checker(settings)
    try:
        for batch in piece_batches(path, piece, settings.batch_frames or BATCH_FRAMES):
            out.append((batch, list(BatchView.parts(batch, checker))))
    except CaptureError as exc:
        return out, exc
    return out, None


def decode_batch(batch: FrameBatch, settings: Settings) -> list[tuple[int, int, BatchView]]:
    """A batch's views (a worker's task), each with the frames of the batch it covers, without the frames'
    bytes."""
    out = []
    first = int(batch.number[0])
    for part, view in BatchView.parts(batch, _checker(settings)):
        start = int(part.number[0]) - first
        view.batch = None  # type: ignore[assignment]
        out.append((start, start + len(part), view))
    return out

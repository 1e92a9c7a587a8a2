"""`annotate -Y` and `extract -Y` judge their filter on the column decode (issue 24 point 1, output.copy_filter).

The differential test: over every sample capture, mutated captures of the fuzz corpus, a fault-rich capture and
the real captures, the frames `copy_filter.matching` names are exactly those the per-frame judgement matches
(every frame dissected with the copies' own pairing and judged on its tree, the analysis's notes beside it), for
filters of every operator and field family; and `annotate -Y` / `extract -Y` write byte for byte the files the
per-frame path writes (PD_ANALYZE_PER_FRAME=1), with the same standard error and exit code.
"""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from click.testing import CliRunner

from devtools.fuzz import corpus, mutators
from devtools.synth.fault_rich import make_fault_rich
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.capture import CaptureError
from pd_analyze.capture.records import CaptureCopy
from pd_analyze.cli.base import main
from pd_analyze.output import dump_prefilter, frame_notes
from pd_analyze.output.capture_copy import dissector_for, frames
from pd_analyze.output.copy_filter import NotesAhead, matching
from pd_analyze.output.display_filter import DisplayFilter, parse
from tests.support import every_shared_capture
from tests.test_dump_columns import FILTERS, SAMPLE_FILES, SAMPLES

SETTINGS = Settings()


def _per_frame(path: Path, flt: DisplayFilter) -> list[int]:
    """The frames the copies' per-frame judgement matches (capture_copy.frames)."""
    notes = frame_notes.collect(str(path), SETTINGS) if flt.needs_analysis else None
    out = []
    try:
        with CaptureCopy(str(path)) as copy:
            for _block, view in frames(copy, dissector_for(SETTINGS, flt), notes):
                if view is not None and flt.matches(view):
                    out.append(view.number)
    except CaptureError:
        pass
    finally:
        if notes is not None:
            notes.close()
    return out


def _columns(path: Path, flt: DisplayFilter) -> list[int]:
    notes = frame_notes.collect(str(path), SETTINGS) if flt.needs_analysis else None
    try:
        matched = matching(str(path), SETTINGS, flt, notes)
        assert matched is not None, path.name  # a file: judged on the columns, never the per-frame fallback
        return list(matched)
    finally:
        if notes is not None:
            notes.close()


def same_frames(path: Path, filters: list[str]) -> None:
    for expression in filters:
        flt = parse(expression)
        assert _columns(path, flt) == _per_frame(path, flt), (path.name, expression)


def _copy(command: list[str], out: Path, per_frame: bool) -> tuple[bytes, str, int]:
    result = CliRunner().invoke(main, [*command, "-w", str(out)],
                                env={dump_prefilter.PER_FRAME_ENV: "1" if per_frame else ""})
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    written = out.read_bytes() if out.exists() else b""
    out.unlink(missing_ok=True)
    return written, result.stderr.replace(str(out), "OUT"), result.exit_code


def same_copies(path: Path, filters: list[str], tmp: Path) -> None:
    for expression in filters:
        for command in (["annotate", str(path), "-Y", expression], ["extract", str(path), "-Y", expression]):
            columns = _copy(command, tmp / "columns.pcapng", False)
            per_frame = _copy(command, tmp / "per_frame.pcapng", True)
            assert columns == per_frame, (path.name, command)


def _readable(paths: list[Path]) -> list[Path]:
    return [p for p in paths if p.suffix in (".pcap", ".pcapng", ".gz")]


@pytest.mark.parametrize("path", _readable(SAMPLE_FILES), ids=[p.name for p in _readable(SAMPLE_FILES)])
def test_the_columns_match_the_frames_the_per_frame_judgement_matches_on_samples(path: Path, tmp_path: Path) -> None:
    same_frames(path, FILTERS)
    same_copies(path, FILTERS[::5], tmp_path)


def test_on_a_fault_rich_capture(tmp_path: Path) -> None:
    path = tmp_path / "fr.pcap"
    make_fault_rich(path, 3_000, seed=5)
    same_frames(path, FILTERS)
    same_copies(path, FILTERS[::4], tmp_path)


def test_on_mutated_captures_of_the_fuzz_corpus(tmp_path: Path) -> None:
    seeds = corpus.load_seeds(corpus.seed_paths([SAMPLES]))
    rng = random.Random(42)
    for n, seed in enumerate(rng.sample(seeds, 8)):
        path = tmp_path / f"fuzz-{n}{Path(seed.name).suffix}"
        path.write_bytes(mutators.mutate_file(random.Random(100 + n), seed.data))
        same_frames(path, FILTERS[::2])
        same_copies(path, FILTERS[1::8], tmp_path)


def test_on_real_captures(tmp_path: Path) -> None:
    for path in every_shared_capture():
        same_frames(path, FILTERS[::2])
        same_copies(path, FILTERS[::8], tmp_path)


def test_record_fields_of_a_pcapng_file_are_judged_on_the_columns() -> None:
    """frame.iface, frame.caplen and frame.time_epoch of a pcapng's records, judged on the columns as on the
    records (tests/test_dump_columns.py has pcapng files of every time unit)."""
    pcapng = SAMPLES / "two_interfaces.pcapng"
    for expression in ("frame.iface == 1", "frame.caplen > 100", "frame.time_epoch > 1767225600.01"):
        flt = parse(expression)
        columns = _columns(pcapng, flt)
        assert columns and columns == _per_frame(pcapng, flt), expression


def test_the_notes_read_ahead_are_held_until_the_copy_passes_them(tmp_path: Path) -> None:
    """The filter's pass reads the notes a batch ahead of the copy: each written frame still gets its own note,
    and the notes the copy passed are let go."""
    path = tmp_path / "fr.pcap"
    make_fault_rich(path, 2_000, seed=3)
    flt = parse('txn.verdict == "nak" or finding.severity == "error"')
    reference = {n.frame: n.comment() for n in frame_notes.collect(str(path), SETTINGS)}
    notes = frame_notes.collect(str(path), SETTINGS)
    try:
        ahead = NotesAhead(notes)
        matched = matching(str(path), SETTINGS, flt, ahead)
        assert matched is not None
        seen = {}
        for frame in matched:
            note = ahead.at(frame)
            assert note is not None  # every matching frame has a transaction or a finding noted
            seen[frame] = note.comment()
            assert all(held.frame > frame for held in ahead._held)
    finally:
        notes.close()
    assert seen and seen == {f: c for f, c in reference.items() if f in seen}
    assert sorted(seen) == _per_frame(path, flt)

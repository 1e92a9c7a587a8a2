"""The dump's memory is a few hundred frames whatever a part's size (output.dump_file.DumpFrames): a part is
walked CHUNK_FRAMES frames at a time and its results leave as soon as nothing before them is still to come;
those that must wait behind a fragment still to be reassembled wait on disk beyond HELD_RESULTS
(output.dump.FrameSpool). The bound is counted, not timed: `DumpFrames.held_most`, the most results held at once.
"""

from __future__ import annotations

import io
import struct
from pathlib import Path

import pytest
from click.testing import CliRunner

from devtools import hostile
from devtools.synth.fault_rich import make_fault_rich
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.cli.base import main
from pd_analyze.output import dump, dump_facts, dump_file
from pd_analyze.output.display_filter import parse

SAMPLES = Path(__file__).resolve().parents[1] / "sample_pcaps"


def _dump(path: str, fmt: str = "text", spool: bool = True, time_format: str = "e",
          selection: dump_file.Selection | None = None) -> tuple[str, int, int]:
    """The second pass of `dump` as cli.dump runs it: (its output, frames printed, results held at once)."""
    settings = Settings()
    facts = dump_facts.collect(str(path), settings, txns=False)
    frames = dump_file.DumpFrames(str(path), settings, settings.checker(), facts)
    clock = dump.Clock(time_format)
    out = io.StringIO()
    kept = dump.FrameSpool(fmt) if spool else None
    try:
        count = dump.render(frames.timed(frames.results(selection or dump_file.Selection(), kept), clock), fmt,
                            lambda text: out.write(text + "\n"), dump.plain_style, False, clock)
    finally:
        facts.close()
        if kept is not None:
            kept.close()
    return out.getvalue(), count, frames.held_most


def test_a_part_far_bigger_than_a_chunk_is_held_a_chunk_at_a_time(tmp_path):
    path = tmp_path / "fr.pcap"
    make_fault_rich(path, 3_000, seed=5)  # one batch, one part: every frame is printed
    text, printed, held = _dump(path, spool=False)
    assert printed > 8 * dump_file.CHUNK_FRAMES
    assert held <= dump_file.CHUNK_FRAMES + 8  # a chunk's frames (and a reassembled PDU's)
    assert text.count("\nFrame ") + text.startswith("Frame ") == printed


@pytest.fixture(scope="module")
def flood(tmp_path_factory):
    """CL and IP fragments never completed among PNIO calls: each fragment is held back until the per-frame
    dissector's hold gives up on it (10,000 held frames or 50,000 fields), and every later frame waits."""
    path = tmp_path_factory.mktemp("held") / "mixed.pcap"
    hostile.write_pcap("mixed", 3_000, path, seed=3)
    return path


@pytest.mark.parametrize(("fmt", "time_format"), [("text", "e"), ("text", "dd"), ("json", "e")])
def test_frames_waiting_behind_a_fragment_wait_on_disk_beyond_the_bound(flood, fmt, time_format):
    unbounded, printed, held = _dump(flood, fmt, spool=False, time_format=time_format)
    assert held > 2 * dump_file.HELD_RESULTS  # without the spool, this capture holds many more
    bounded, printed_spooled, held_spooled = _dump(flood, fmt, time_format=time_format)
    assert held_spooled == dump_file.HELD_RESULTS
    assert (bounded, printed_spooled) == (unbounded, printed)  # byte for byte
    assert printed == 2000  # its PNIO RPC frames: the calls and the CL fragments (two thirds of it)


def test_a_filtered_dump_is_bounded_alike(flood):
    selection = dump_file.Filtered(parse("pd.ref or dcerpc.opnum == 3"))
    unbounded, printed, held = _dump(flood, selection=selection, spool=False)
    bounded, printed_spooled, held_spooled = _dump(flood, selection=dump_file.Filtered(
        parse("pd.ref or dcerpc.opnum == 3")))
    assert held > dump_file.HELD_RESULTS >= held_spooled
    assert (bounded, printed_spooled) == (unbounded, printed)


def _retimed(src: Path, dst: Path, frame: int, sec: int, usec: int) -> None:
    """A copy of a little-endian microsecond pcap with one frame's time changed."""
    data = bytearray(src.read_bytes())
    assert struct.unpack_from("<I", data)[0] == 0xA1B2C3D4
    at, number = 24, 0
    while at < len(data):
        number += 1
        if number == frame:
            struct.pack_into("<II", data, at, sec, usec)
        at += 16 + struct.unpack_from("<I", data, at + 8)[0]
    dst.write_bytes(bytes(data))


@pytest.mark.parametrize("chunk", [2, dump_file.CHUNK_FRAMES])
def test_relative_times_count_from_an_earlier_odd_frame_of_the_first_part(tmp_path, monkeypatch, chunk):
    """-t r counts from the least time of the first part's first column row and its odd PNIO RPC frames, as
    when the part was printed whole: frames already dissected wait until no odd frame left can be earlier."""
    monkeypatch.setattr(dump_file, "CHUNK_FRAMES", chunk)
    path = tmp_path / "retimed.pcap"
    # frame 7 (cut by the snaplen: the per-frame dissector's) one second before frame 3 (the first PNIO RPC frame)
    _retimed(SAMPLES / "truncated_snaplen.pcap", path, 7, 1767225599, 680)
    result = CliRunner().invoke(main, ["dump", str(path), "-t", "r"])
    heads = [line.split("  ")[:2] for line in result.output.splitlines() if line.startswith("Frame ")]
    assert heads == [["Frame 3", "1.000000"], ["Frame 4", "1.001500"], ["Frame 5", "1.002500"],
                     ["Frame 6", "1.004000"], ["Frame 7", "0.000000"], ["Frame 8", "1.006500"],
                     ["Frame 9", "1.007500"], ["Frame 10", "1.009000"]]

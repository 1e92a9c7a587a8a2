"""`dump -Y FILTER` of a capture file (issue 24 point 1): the frames a filter selects, judged on the column
decode with the report's notes (a filter of analysis fields) or frame by frame (a dissected field), and only
those dissected to be printed. The differential test: over the samples, mutated captures of the fuzz corpus,
a generated fault-rich capture and the real captures, for filters of every operator and field family, the
frames printed are those the per-frame path selects, and each printed frame's lines are byte for byte its
lines in the full dump.
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
from pd_analyze.cli.base import main
from pd_analyze.output.display_filter import parse
from pd_analyze.output.frame_select import views
from pd_analyze.protocol.dissector import Dissector
from tests.support import every_shared_capture

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_pcaps"

# every operator (==, !=, ~=, ===, <, <=, >, >=, in with sets and ranges, contains, matches, a bare field,
# and, or, not, brackets) and every field family (frame, link, IPv4, UDP, DCE/RPC, NDR/PNIO status, IOD,
# PROFIdrive header, addresses, values, txn.*, finding.*); no link field (rpc.request_frame and the like are
# the report's pairing in the new path, by design: issue 28 point 2)
FILTERS = [
    "frame.number > 4 and frame.number <= 40",
    "eth.src contains 02:00:00 or eth.type != 0x0800",
    "ip.src == 192.168.1.21 or ip.dst == 192.168.0.0/24",
    "udp.dport == 34964 and udp.len >= 200",
    "rpc.ptype == 2 and rpc.seq in {1..5 9 12}",
    "!(rpc.ptype == 0) && ndr.status.code == 0xde",
    "pn_io.error_code1 == 0xb5",
    "iod.index == 0xb02e and iod.record_len < 12",
    "pd.ref ~= 1",
    "pd.ref === 2",
    'pd.req_id == "request parameter (read)"',
    "pd.resp_id >= 0x80",
    "pd.addr.pnu in {964 2000..3000}",
    "pn_io.profidrive.parameter.number == 964",  # (these three: judged on the columns first, dump_prefilter)
    "pd.addr.pnu == 2000",
    "pd.addr.pnu eq 0x3c4",
    "pd.val.value",
    "pd.val.error == 0x11 or pd.val.error_subindex",
    'pd.val.string matches "^sin"',
    'txn.verdict == "nak"',
    "txn.b5_retries > 0 or txn.id < 3",
    'txn.verdict contains "out" and pd.ref',
    'finding.rule matches "^[TQ]"',
    'finding.severity == "warning"',
    "not finding.rule",
    'pd.addr.pnu == 964 or finding.rule == "T9"',
]


def dump(*args: str) -> list[str]:
    result = CliRunner().invoke(main, ["dump", "--color", "never", *args])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return result.stdout.splitlines()


def frame_blocks(lines: list[str]) -> dict[int, list[str]]:
    """Each frame's lines (from its 'Frame N' heading to the blank line after it), by frame number."""
    out: dict[int, list[str]] = {}
    current: list[str] | None = None
    for line in lines:
        if line.startswith("Frame "):
            current = out[int(line.split()[1])] = [line]
        elif line and not line.startswith(" "):  # the findings on frames that are not PNIO RPC, after the frames
            current = None
        elif current is not None:
            current.append(line)
    return out


def per_frame(path: Path, expression: str) -> list[int]:
    """The frames today's per-frame path (a dissector beside the records) selects; on a damaged capture, those
    before the damage (CaptureError ends the records, as it ends the dump)."""
    settings = Settings()
    dissector = Dissector(annotate=True, rpc_timeout=settings.rpc_timeout, checker=settings.checker())
    out = []
    try:
        for view in views(str(path), settings, dissector, parse(expression), [], every_frame=False):
            out.append(view.number)
    except CaptureError:
        pass
    return out


def differential(path: Path, filters: list[str] = FILTERS) -> None:
    full = frame_blocks(dump(str(path)))
    for expression in filters:
        got = frame_blocks(dump(str(path), "-Y", expression))
        assert list(got) == per_frame(path, expression), (path.name, expression)
        assert {n: lines for n, lines in got.items() if lines != full[n]} == {}, (path.name, expression)


SAMPLE_FILES = sorted(p for p in SAMPLES.iterdir() if p.is_file() and p.name != "README.md")


@pytest.mark.parametrize("path", SAMPLE_FILES, ids=[p.name for p in SAMPLE_FILES])
def test_filter_on_samples_prints_what_the_per_frame_path_selects(path: Path) -> None:
    differential(path)


def test_filter_on_a_fault_rich_capture(tmp_path: Path) -> None:
    path = tmp_path / "fr.pcap"
    make_fault_rich(path, 3_000, seed=7)
    differential(path)


def test_filter_on_mutated_captures_of_the_fuzz_corpus(tmp_path: Path) -> None:
    seeds = {s.name: s for s in corpus.load_seeds(corpus.seed_paths([SAMPLES]))}
    for n, name in enumerate(["fault_trace.pcap", "pd_edge_cases.pcap", "ip_fragments.pcap",
                              "cl_fragments_fack.pcapng", "pd_retries_and_duplicates.pcap"] * 2):
        path = tmp_path / f"fuzz-{n}{Path(name).suffix}"
        path.write_bytes(mutators.mutate_file(random.Random(n), seeds[name].data))
        differential(path, FILTERS[::3])


def test_filter_on_real_captures() -> None:
    for path in every_shared_capture():
        differential(path, FILTERS[::2])

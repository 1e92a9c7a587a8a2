"""Filters and `-T fields` read from the column decode (issue 24 point 1): output.column_fields reads the
registry's fields from the columns, output.dump_prefilter judges a filter on them three-valued, and
output.fields_file writes `-T fields` lines from them, dissecting only the frames the columns cannot tell.

The differential test: over every sample capture, mutated captures of the fuzz corpus, a fault-rich capture
and the real captures, `dump -T fields` (every field family, tshark's names, -E options, -Y filters of every
operator) and `dump -Y` print byte for byte what the per-frame path prints (PD_ANALYZE_PER_FRAME=1, the
path before the columns: every frame dissected, judged and shown from its tree), standard error and exit
code included.
"""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from devtools.fuzz import corpus, mutators
from devtools.synth.fault_rich import make_fault_rich
from pd_analyze.analysis.engine.decode import Decoder
from pd_analyze.capture.batches import batches
from pd_analyze.cli.base import main
from pd_analyze.output import dump_prefilter
from pd_analyze.output.column_fields import PartFields
from pd_analyze.output.display_filter import parse
from pd_analyze.output.frame_view import LAYERS, OWN, TSHARK, FrameView, _tshark_text, resolve
from pd_analyze.protocol.dissector import Dissector, dissect
from tests.support import every_shared_capture

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_pcaps"
SAMPLE_FILES = sorted(p for p in SAMPLES.iterdir() if p.is_file() and p.name != "README.md")

# every field family (frame, record, link, VLAN, IPv4, UDP, DCE/RPC, fault, NDR and PNIO status, IOD headers,
# records, PROFIdrive header, addresses, values, strings, errors, descriptions, fragments), registry and tshark
# names, an indexed name, tshark's value widths, and fields no column row holds
FIELDS = (
    "frame.number", "frame.time_epoch", "frame.caplen", "frame.linktype", "frame.iface", "eth.src", "eth.dst",
    "eth.type", "vlan.id", "vlan.pcp", "vlan.dei", "vlan.etype", "ip.src", "ip.dst", "ip.id", "ip.flags.mf",
    "ip.frag_offset", "ip.options", "ip.checksum", "ip.version", "ip.ihl", "ip.ttl", "udp.srcport", "udp.dstport",
    "udp.len", "udp.checksum", "dcerpc.pkt_type", "dcerpc.opnum", "dcerpc.dg_seqnum", "dcerpc.dg_act_id",
    "dcerpc.dg_if_id", "dcerpc.obj_id", "dcerpc.drep", "dcerpc.dg_flags1", "dcerpc.dg_flags2",
    "dcerpc.dg_server_boot", "dcerpc.dg_serial_lo", "dcerpc.dg_serial_hi", "dcerpc.dg_ihint", "dcerpc.dg_frag_len",
    "dcerpc.dg_frag_num", "rpc.fault_status", "rpc.body", "pn_io.args_max", "pn_io.error_code", "pn_io.error_code1",
    "pn_io.error_code2", "ndr.status.decode", "pn_io.args_len", "pn_io.array_act_count", "pn_io.array_offset",
    "ndr.blocks", "pn_io.block_type", "pn_io.block_length", "pn_io.api", "pn_io.slot_nr", "pn_io.subslot_nr",
    "pn_io.index", "pn_io.record_data_length", "pn_io.ar_uuid", "pn_io.target_ar_uuid", "pn.padding", "iod.add_val1",
    "iod.status.code", "iod.status.code1", "iod.multi_pad", "record.data", "record.trailing", "pd.ref", "pd.req_id",
    "pd.resp_id", "pd.do", "pd.n_params", "pd.addr.attr", "pd.addr.pnu", "pd.addr[1].pnu", "pd.addr.subindex",
    "pd.addr.n_elems", "pd.trailing", "pd.echo", "pd.cut", "pd.val.format", "pd.val.n_values", "pd.val.value",
    "pn_io.profidrive.parameter.value_w", "pn_io.profidrive.parameter.value_float",
    "pn_io.profidrive.parameter.value_b", "pd.val.string", "pd.val[1].value[0]", "pd.val.error",
    "pd.val.error_subindex", "pd.val.pad", "pd.val.desc.name", "pd.val.desc.low_limit", "eth.vlan_ids",
    "rpc.fragments", "rpc.reassembled_in", "ip.reassembled_from")
ANALYSIS = ("txn.id", "txn.verdict", "txn.b5_retries", "finding.rule", "finding.severity")
# every operator (== != ~= === < <= > >=, in with ranges, &, contains, matches, a bare field, not and or, brackets)
# over every family, the analysis fields too
FILTERS = [
    "pn_io.profidrive.parameter.number == 964",
    "pd.ref in {1..5 9}",
    "!pd.ref",
    "udp.dstport == 34964 or pd.val.error",
    "frame.number > 3 && !(rpc.ptype == 2)",
    'finding.rule matches "^[TQ]" or pd.n_params >= 2',
    "pd.addr.pnu ~= 964",
    "pd.addr.pnu != 964",
    "pd.val.value === 0 or pd.val.value < 0",
    "eth.src contains 02:00 and vlan.id <= 100",
    "ip.dst == 192.168.0.0/16 and iod.index != 0xb02e",
    'ndr.status.code1 == 0xb5 or txn.verdict == "nak"',
    'pd.val.string contains "a" or pd.req_id == "change parameter (write)"',
    "frame.caplen > 200 and dcerpc.opnum in {2 3}",
    "record.data or pd.trailing or iod.record_len < 8",
    "dcerpc.dg_flags1 & 0x20 and not pd.addr.pnu bitwise_and 0x3",
]


def dump(args: list[str], per_frame: bool) -> tuple[str, str, int]:
    result = CliRunner().invoke(main, ["dump", "--color", "never", *args],
                                env={dump_prefilter.PER_FRAME_ENV: "1" if per_frame else ""})
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return result.stdout, result.stderr, result.exit_code


def same_as_per_frame(path: Path, args: list[str]) -> None:
    columns, per_frame = dump([str(path), *args], False), dump([str(path), *args], True)
    assert columns == per_frame, (path.name, args)


def e(*names: str) -> list[str]:
    return [x for name in names for x in ("-e", name)]


def differential(path: Path, filters: list[str] = FILTERS, text_filters: list[str] = FILTERS[::3]) -> None:
    same_as_per_frame(path, ["-T", "fields", *e(*FIELDS)])
    same_as_per_frame(path, ["-T", "fields", *e(*FIELDS[:40]), "-E", "occurrence=l", "-E", "aggregator=/s", "-E",
                             "quote=d", "-E", "header=y", "-E", "separator=,", "--frames", "2-5,9-"])
    same_as_per_frame(path, ["-T", "fields", *e("frame.number", *ANALYSIS, "pd.addr.pnu"), "-E", "occurrence=f"])
    for expression in filters:
        same_as_per_frame(path, ["-T", "fields", "-Y", expression, *e("frame.number", "pd.ref", "pd.addr.pnu",
                                                                      "ip.src", "pd.val.value")])
    for expression in text_filters:
        same_as_per_frame(path, ["-Y", expression])


@pytest.mark.parametrize("path", SAMPLE_FILES, ids=[p.name for p in SAMPLE_FILES])
def test_columns_print_what_the_per_frame_path_prints_on_samples(path: Path) -> None:
    differential(path)


def test_columns_on_a_fault_rich_capture(tmp_path: Path) -> None:
    path = tmp_path / "fr.pcap"
    make_fault_rich(path, 3_000, seed=11)
    differential(path, FILTERS[::2])


def test_columns_on_mutated_captures_of_the_fuzz_corpus(tmp_path: Path) -> None:
    seeds = corpus.load_seeds(corpus.seed_paths([SAMPLES]))
    rng = random.Random(24)
    for n, seed in enumerate(rng.sample(seeds, 8)):
        path = tmp_path / f"fuzz-{n}{Path(seed.name).suffix}"
        path.write_bytes(mutators.mutate_file(random.Random(n), seed.data))
        differential(path, FILTERS[::4], FILTERS[1::7])


def test_columns_on_real_captures() -> None:
    for path in every_shared_capture():
        differential(path, FILTERS[::2], FILTERS[1::5])


# --- the pieces --------------------------------------------------------------------------------------
def _parts(path: Path) -> tuple[dict, list]:
    """The per-frame results of a capture by frame, and its column decode's parts."""
    truth = {r.frame: r for r in dissect(str(path), dissector=Dissector(annotate=True))}
    decoder = Decoder(Dissector(annotate=False, pairing=False))
    return truth, [part for batch in batches(str(path)) for part in decoder.parts(batch)]


@pytest.mark.parametrize("name", ["fault_trace.pcap", "pd_edge_cases.pcap", "pd_akd_like.pcap", "vlan_stacked.pcap",
                                  "record_rw_be.pcap", "crafted_strings.pcap", "pd_negative.pcap"])
def test_every_field_read_from_the_columns_is_the_trees(name: str) -> None:
    """Each field of the registry (and each tshark name), wherever the columns say they know it, has the
    occurrences, values (their types too) and -T fields texts of the frame's tree."""
    truth, parts = _parts(SAMPLES / name)
    refs = [r for r in (resolve(n) for n in sorted(set(OWN) | set(TSHARK) | {"pd.addr[1].pnu", "pd.val[0].value[1]"}))
            if r is not None and r.kind == LAYERS]
    known_cells = 0
    for part in parts:
        view, rows = part.view, part.rows
        frames = view.frame_no[rows].tolist()
        stub = np.array([view.p.ptype[i] != 2 or truth[f].pdu.opnum == view.p.opnum[i]
                         for i, f in zip(rows.tolist(), frames, strict=True)], bool)
        fields = PartFields(view, rows, stub)
        for ref in refs:
            occ = fields.occurrences(ref)
            if occ is None:
                continue
            values, texts = occ.values(), [_tshark_text(f, 0.0) for f in occ.fields]
            for k in np.flatnonzero(occ.known).tolist():
                tree = FrameView(frames[k], 0.0, truth[frames[k]])
                codes = occ.code[occ.owner == k].tolist()
                got = [values[c] for c in codes]
                assert (got, [type(v) for v in got]) == (tree.values(ref), [type(v) for v in tree.values(ref)]), \
                    (name, frames[k], ref.text)
                assert [t for c in codes for t in texts[c]] == tree.shown(ref), (name, frames[k], ref.text)
                known_cells += 1
    assert known_cells > 1000


def test_a_filter_is_decided_where_its_decided_parts_decide_it() -> None:
    """Kleene's logic on the columns of the worked example (1 write request of P964 and P2000, 2 its write
    response, 3 and 5 read requests, 4 the B5 answer, 6 the read response with two value blocks): a value
    block's values are read from the columns, a link a pairing adds is unknown everywhere."""
    truth, parts = _parts(SAMPLES / "worked_example.pcap")
    (part,) = parts
    view, rows = part.view, part.rows
    fields = PartFields(view, rows, np.ones(len(rows), bool))
    frames = view.frame_no[rows]
    judged = dump_prefilter.Rows(fields, frames, view.ts[rows], {})

    def sure_maybe(expression: str) -> tuple[list[int], list[int]]:
        sure, maybe = dump_prefilter.candidates_of(parse(expression))(judged)
        return frames[sure].tolist(), frames[maybe].tolist()

    assert frames.tolist() == [1, 2, 3, 4, 5, 6]
    assert sure_maybe("pd.addr.pnu == 964") == ([1], [])
    assert sure_maybe("pd.addr.pnu != 964") == ([], [])
    assert sure_maybe("pd.addr.pnu ~= 964") == ([1], [])
    assert sure_maybe("pd.val.value") == ([6], [])
    assert sure_maybe("rpc.request_frame") == ([], [1, 2, 3, 4, 5, 6])
    assert sure_maybe("rpc.request_frame or pd.ref") == ([1, 6], [2, 3, 4, 5])
    assert sure_maybe("rpc.request_frame and pd.ref") == ([], [1, 6])
    assert sure_maybe("not (rpc.request_frame and pd.ref)") == ([2, 3, 4, 5], [1, 6])
    assert sure_maybe('ndr.status.code1 == 0xb5 or txn.verdict == "nak"') == ([4], [])


def test_the_frames_the_columns_read_are_not_dissected(monkeypatch: pytest.MonkeyPatch) -> None:
    """-T fields of fields the columns hold dissects only the frames the columns do not decode: the IP
    fragments of two datagrams (1-3, 5-6) and the Write-Multiple response 7; the response 4 to the
    reassembled write, and the read 8-9, are read from the columns."""
    fed: list[int] = []
    feed = Dissector.feed

    def counted(self: Dissector, frame: object) -> list:
        fed.append(frame.number)
        return feed(self, frame)

    monkeypatch.setattr(Dissector, "feed", counted)
    out, _err, code = dump([str(SAMPLES / "ip_fragments.pcap"), "-T", "fields", *e("frame.number", "pd.ref",
                                                                                   "pd.addr.pnu")], False)
    assert code == 0 and len(out.splitlines()) == 9
    assert fed == [1, 2, 3, 5, 6, 7]

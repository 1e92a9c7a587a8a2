"""Results back to Wireshark (issue 17): annotated pcapng copies read by tshark, extracted fault traces whose
report equals the selected rows, display filters (-Y) and `dump -T fields` as tshark has them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from pd_analyze.analysis.api import analyze
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.output.display_filter import FilterError, parse
from pd_analyze.output.frame_select import views
from pd_analyze.protocol.dissector import Dissector
from tests import tshark_fields as tf
from tests.support import unavailable

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_pcaps"
FAULT = SAMPLES / "fault_trace.pcap"
WORKED = SAMPLES / "worked_example.pcap"
TIMEOUTS = SAMPLES / "pd_timeouts.pcap"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pd_analyze.cli", *map(str, args)], capture_output=True,
                          timeout=300, cwd=ROOT)


def tshark(path: Path, *args: str) -> list[list[str]]:
    """tshark -T fields of a file (an empty profile, as the conformance test runs it), rows of cells."""
    if tf.TSHARK is None:
        unavailable(tf.INSTALL_HINT)
    env = dict(os.environ, WIRESHARK_CONFIG_DIR=tf._config_dir(), LC_ALL="C", TZ="UTC")
    out = subprocess.run([tf.TSHARK, "-n", "-2", "-r", str(path), "-o", "dcerpc.desegment_dcerpc:TRUE",
                          "-o", "dcerpc.reassemble_dcerpc:TRUE", *args], capture_output=True, env=env, timeout=300,
                         check=True).stdout.decode()
    return [line.split("\t") for line in out.splitlines()]


# --- annotate ---------------------------------------------------------------------------------------

FRAME_COLUMNS = ("-o", "frame.generate_md5_hash:TRUE", "-T", "fields", "-e", "frame.number", "-e",
                 "frame.time_epoch", "-e", "frame.len", "-e", "frame.cap_len", "-e", "frame.md5_hash", "-e",
                 "frame.interface_id")
ANNOTATED = ["fault_trace.pcap", "pd_negative.pcap", "pd_b5_and_pnio_errors.pcap", "two_interfaces.pcapng",
             "truncated_snaplen.pcap", "pcap_nsec_be.pcap", "cl_fragments_fack.pcapng", "record_rw_le.pcap.gz",
             "ip_fragments.pcap", "pd_out_of_range.pcap", "linux_sll2.pcap"]


def commented_frames(path: Path) -> set[int]:
    """The frames the analysis names: findings, and the frames that open or close a transaction."""
    a = analyze(str(path))
    t = a.transactions
    frames = {int(f) for f in a.findings["frame"].dropna()}
    frames |= {int(f) for f in t["write_req_frame"].dropna()}
    answered = t[t["closed_by"].isin(["response", "pnio_error"])]
    closes = answered["read_res_frame"].fillna(answered["write_res_frame"])
    return frames | {int(f) for f in closes.dropna()}


@pytest.mark.parametrize("name", ANNOTATED)
def test_tshark_reads_the_annotated_copy(name: str, tmp_path: Path) -> None:
    src, out = SAMPLES / name, tmp_path / "annotated.pcapng"
    r = run("annotate", src, "-w", out)
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:4] == b"\x0a\x0d\x0d\x0a"  # pcapng whatever the input
    before = [[*row[:-1], row[-1] or "0"] for row in tshark(src, *FRAME_COLUMNS)]  # a pcap's frames: interface 0
    after = tshark(out, *FRAME_COLUMNS, "-e", "frame.comment")
    assert [row[:-1] for row in after] == before  # same frames, bytes, lengths, times, interfaces
    comments = {int(row[0]): row[-1] for row in after if row[-1]}
    assert set(comments) == commented_frames(src)
    assert all(text.startswith("pd-analyze: ") for text in comments.values())
    assert r.stderr.decode().strip() == f"{out}: {len(after)} frames written, {len(comments)} with a pd-analyze comment"


def test_annotate_comments_say_verdicts_errors_and_rules(tmp_path: Path) -> None:
    out = tmp_path / "a.pcapng"
    assert run("annotate", FAULT, "-w", out).returncode == 0
    rows = tshark(out, "-Y", "frame.comment", "-T", "fields", "-e", "frame.number", "-e", "frame.comment")
    comments = {int(n): text for n, text in rows}
    assert comments[19] == "pd-analyze: txn 5 request P2[0]: nak"
    # the refusal and the failure are findings at the frame that decided the verdict: T9, T8 (protocol.md 6.5)
    assert comments[22] == "pd-analyze: txn 5 nak; P2[0] error 0x01 parameter value cannot be changed; I T9 the " \
        "drive refused the transaction of frame 19: P2[0]: error 0x01 (parameter value cannot be changed)"
    assert comments[27].endswith("P2019[0]: pnio_error") and comments[28] == "pd-analyze: txn 7 pnio_error; W T8 " \
        "the transaction of frame 27 failed: pnio_error: DF80B100 write: access write length error (parameter " \
        "request above the record limit or shorter than its header, or read buffer too small) (in the answer to the " \
        "write)"
    assert comments[291].startswith("pd-analyze: txn 42 request P1082[0]: ok; I T4 ")
    assert comments[60] == "pd-analyze: txn 15 request P1082[0]: pnio_error; W T8 the transaction of frame 60 " \
        "failed: pnio_error: DE80B500 read: access state conflict (PROFIdrive: response not ready yet / request " \
        "still processed): every read answered B5 (3), no final response within 10 s"  # a busy drive given up (7.3)
    assert not [text for text in comments.values() if ": timeout" in text]


def test_annotate_keeps_existing_comments_and_filters_frames(tmp_path: Path) -> None:
    once, twice, naks = tmp_path / "1.pcapng", tmp_path / "2.pcapng", tmp_path / "n.pcapng"
    assert run("annotate", WORKED, "-w", once).returncode == 0
    assert run("annotate", once, "-w", twice).returncode == 0
    rows = tshark(twice, "-Y", "frame.comment", "-T", "fields", "-e", "frame.number", "-e", "frame.comment")
    first = "pd-analyze: txn 1 request P964[0] P2000[0..2]: ok"
    assert rows == [["1", f"{first},{first}"], ["6", "pd-analyze: txn 1 ok,pd-analyze: txn 1 ok"]]
    r = run("annotate", FAULT, "-w", naks, "-Y", 'txn.verdict == "nak" and pd.resp_id')
    assert r.returncode == 0
    rows = tshark(naks, "-T", "fields", "-e", "frame.number", "-e", "frame.time_epoch")
    assert len(rows) == 7  # the 7 NAK responses of the trace, nothing else
    assert r.stderr.decode().strip() == f"{naks}: 7 frames written, 7 with a pd-analyze comment"


def test_annotate_refuses_stdin_and_overwriting_the_input(tmp_path: Path) -> None:
    r = run("annotate", "-", "-w", tmp_path / "x.pcapng")
    assert r.returncode == 2 and b"give a file, not -" in r.stderr
    copy = tmp_path / "c.pcap"
    copy.write_bytes(WORKED.read_bytes())
    r = run("annotate", copy, "-w", copy)
    assert r.returncode == 2 and b"is the capture itself" in r.stderr
    assert copy.read_bytes() == WORKED.read_bytes()


# --- extract ----------------------------------------------------------------------------------------

# columns that number or name frames and files: renumbered in the extracted file
RENUMBERED = ["txn", "capture", "write_req_frame", "write_res_frame", "read_req_frames", "read_res_frame", "frames"]


def _same_rows(original: pd.DataFrame, extracted: pd.DataFrame) -> None:
    """The extracted file's transactions are the selected rows, frame numbers aside. A timeout is closed
    by what follows it, which the extracted file may not hold: the deadline passed by later traffic, or the
    next transaction of its channel (superseded), becomes the end of the file or the deadline; closed_by
    and capture_ended say so, the verdict and every figure are the same. A busy drive given up (every read
    B5 until the controller wrote again or the deadline passed: pnio_error DE80B500, protocol.md 7.3 step 5)
    is, for the same reason, a timeout at the end of the extracted file when what gave it up is not in it."""
    a = original.drop(columns=RENUMBERED).reset_index(drop=True).astype(str)
    b = extracted.drop(columns=RENUMBERED).reset_index(drop=True).astype(str)
    closers = ["deadline", "superseded", "capture_end"]
    busy = (a["verdict"] == "pnio_error") & (a["pnio_status"] == "DE80B500")
    moved = ((a["verdict"] == "timeout") | busy) & a["closed_by"].isin(closers) & b["closed_by"].isin(closers)
    a.loc[moved, ["closed_by", "capture_ended"]] = b.loc[moved, ["closed_by", "capture_ended"]]
    given_up = busy & (b["verdict"] == "timeout") & (b["closed_by"] == "capture_end")
    status = ["verdict", "pnio_status", "pnio_error_text", "closed_by", "capture_ended"]
    a.loc[given_up, status] = b.loc[given_up, status]
    pd.testing.assert_frame_equal(a, b)


@pytest.mark.parametrize(("name", "args", "count"), [
    ("fault_trace.pcap", ["--verdict", "nak,timeout,pnio_error"], 9),
    ("fault_trace.pcap", ["--pnu", "1300,63", "--device", "192.168.1.22"], 19),
    ("fault_trace.pcap", ["--txn", "14,7"], 2),
    ("fault_trace.pcap", ["-Y", "finding.rule == \"T4\""], 1),
    ("pd_retries_and_duplicates.pcap", ["--verdict", "timeout,pnio_error"], 4),
    ("pd_b5_and_pnio_errors.pcap", ["--verdict", "pnio_error"], 7),
    ("ip_fragments.pcap", [], 1),
    ("other_port_response.pcap", [], 1),
    ("two_interfaces.pcapng", ["--device", "192.168.1.22"], 1),
])
def test_extract_round_trip(name: str, args: list[str], count: int, tmp_path: Path) -> None:
    src = SAMPLES / name
    out = tmp_path / ("out" + "".join(src.suffixes))
    r = run("extract", src, "-w", out, *args)
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:4] == src.read_bytes()[:4]  # the input's format and byte order
    original = analyze(str(src)).transactions
    selected = original[original["txn"].isin(_chosen(original, args))]
    assert len(selected) == count
    _same_rows(selected, analyze(str(out)).transactions)


def _chosen(t: pd.DataFrame, args: list[str]) -> set[int]:
    """The transactions the options select, from the report's own tables."""
    keep = pd.Series(True, index=t.index)
    options = dict(zip(args[::2], args[1::2], strict=True))
    if "--verdict" in options:
        keep &= t["verdict"].isin(options["--verdict"].split(","))
    if "--device" in options:
        keep &= t["device"].isin(options["--device"].split(","))
    if "--txn" in options:
        keep &= t["txn"].isin([int(x) for x in options["--txn"].split(",")])
    if "--pnu" in options:
        wanted = {f"P{p}[" for p in options["--pnu"].split(",")}
        keep &= t["params"].map(lambda text: any(w in text for w in wanted))
    if "-Y" in options:  # finding.rule == "T4": the one T4 finding's transaction (frame 291)
        keep &= t["frames"].map(lambda text: "291" in text.split())
    return set(t.loc[keep, "txn"])


def test_extract_keeps_the_frames_of_the_calls_and_nothing_else(tmp_path: Path) -> None:
    """Every frame of the selected transactions' calls (retransmission 6 included), in order, bytes as they were."""
    out = tmp_path / "o.pcap"
    assert run("extract", SAMPLES / "other_port_response.pcap", "-w", out).returncode == 0
    assert out.read_bytes() == (SAMPLES / "other_port_response.pcap").read_bytes()
    out = tmp_path / "f.pcap"
    r = run("extract", FAULT, "-w", out, "--txn", "5")
    assert r.stderr.decode().strip() == f"{out}: 4 frames of 1 transactions written"
    src = {row[0]: row[1:] for row in tshark(FAULT, *FRAME_COLUMNS)}
    got = tshark(out, *FRAME_COLUMNS)
    assert [src[str(n)] for n in (19, 20, 21, 22)] == [row[1:] for row in got]


def test_extract_usage_errors(tmp_path: Path) -> None:
    r = run("extract", FAULT, "-w", tmp_path / "x.pcap", "--verdict", "nak,late")
    assert r.returncode == 2 and b"late is not a verdict" in r.stderr
    r = run("extract", FAULT, "-w", tmp_path / "x.pcap", "--pnu", "12a")
    assert r.returncode == 2 and b"'12a' is not a number" in r.stderr


# --- display filters --------------------------------------------------------------------------------

FILTERS = [  # (capture, expression, frames it selects among the PNIO RPC frames)
    (WORKED, "pd.ref == 1", [1, 6]),
    (WORKED, "pn_io.profidrive.parameter.request_reference == 0x01", [1, 6]),
    (WORKED, "pd.addr.pnu == 2000", [1]),
    (WORKED, "pd.addr.pnu != 964", []),  # a repeated field: != when no occurrence equals
    (WORKED, "pd.addr.pnu ~= 964", [1]),  # ~= when any occurrence differs
    (WORKED, "pd.addr.pnu === 964", []),
    (WORKED, "pd.addr.pnu in {964 965}", [1]),
    (WORKED, "pn_io.profidrive.parameter.number in {2000, 3000}", [1]),
    (WORKED, "pd.addr.pnu in {100..1000}", [1]),
    (WORKED, "not pd.ref", [2, 3, 4, 5]),
    (WORKED, "pn_io.error_code1 == 0xb5", [4]),
    (WORKED, "iod.index == 0xb02e && rpc.ptype == 0", [1, 3, 5]),
    (WORKED, "rpc.ptype == 2 and not (ndr.status.code == 0xde)", [2, 6]),
    (WORKED, "ip.src == 192.168.0.2 or pd.addr.pnu >= 2000", [1, 2, 4, 6]),
    (WORKED, "ip.dst == 192.168.0.0/24 and frame.number > 4", [5, 6]),
    (WORKED, "txn.id == 1 and txn.verdict == \"ok\"", [1, 2, 3, 4, 5, 6]),
    (WORKED, "pd.val.value", [6]),
    (WORKED, "pd.req_id == \"request parameter (read)\"", [1]),  # a value name
    (FAULT, "pd.addr.pnu == 964 and txn.verdict == \"nak\"", [97]),  # txn 17's request
    (FAULT, "finding.rule == \"T4\"", [291]),
    # T4 at 291, T9 txn_refused at the negative response of each of the 7 NAKs (protocol.md 6.5)
    (FAULT, "finding.severity == \"info\"", [22, 52, 56, 102, 291, 300, 318, 396]),
    (FAULT, "pd.val.error == 0x11", [52, 396]),  # txns 12 and 59
    (FAULT, "pn_io.profidrive.parameter.error_num in {0x02 0x03} and ip.src == 192.168.1.21", [56]),
    (SAMPLES / "pd_negative.pcap", "txn.verdict == \"nak\" and pd.val.error_subindex", [10, 14, 18]),
    # contains and matches on every text field, the analysis fields included (== keeps to the value names)
    (TIMEOUTS, "txn.verdict contains \"out\"", [9, 10, 15, 73, 75, 77, 79, 80, 85, 90, 127, 128, 129, 130, 135, 136]),
    (TIMEOUTS, "finding.severity contains \"arn\"", [9, 15, 57, 73, 80, 127]),  # R7; T8 at each failed write
    (FAULT, "txn.verdict matches \"^(NAK|pnio)\" and frame.number < 60", [19, 20, 21, 22, 27, 28, 45, 46, 47, 48,
                                                                          49, 50, 51, 52, 53, 54, 55, 56]),
    (FAULT, "txn.verdict matches \"(?-i)^NAK\"", []),  # (?-i): case-sensitive, as PCRE2's
    (FAULT, "finding.rule ~ \"t4\"", [291]),
    (FAULT, "finding.rule matches \"^T[0-9]$\" or finding.rule contains \"Q\"",  # T4; T8 (28, 60) and T9
     [22, 28, 52, 56, 60, 102, 291, 300, 318, 396]),
    (SAMPLES / "pd_commissioning.pcap", "pd.val.string contains \"Pump\"", [16, 35]),  # the read, the write
    (SAMPLES / "pd_commissioning.pcap", "pd.val.string matches \"^sinamics\"", [16]),
    (WORKED, "eth.src contains 02:00:00 and eth.src matches \"\\\\x02\\\\x01$\" and frame.number < 3", [2]),
]


@pytest.mark.parametrize(("capture", "expression", "frames"), FILTERS)
def test_filter_selects(capture: Path, expression: str, frames: list[int]) -> None:
    settings = Settings()
    dissector = Dissector(annotate=True, rpc_timeout=settings.rpc_timeout, checker=settings.checker())
    got = [v.number for v in views(str(capture), settings, dissector, parse(expression), [], every_frame=False)]
    assert got == frames


@pytest.mark.parametrize(("expression", "column", "message"), [
    ("pd.ref ==", 10, "expected a value after ==, found the end"),
    ("pd.nope == 1", 1, "'pd.nope' is neither a field of the registry nor a tshark name it maps"),
    ("(pd.ref == 1", 13, "expected ) to close the ( at column 1, found the end"),
    ("pd.ref == 1)", 12, "unexpected ')' (a missing ( ?)"),
    ("pd.ref == abc", 11, "'abc' is not an integer (pd.ref holds integers)"),
    ("pd.addr.pnu in {964", 20, "expected a set element or }, found the end"),
    ('txn.verdict == "late"', 16, "'late' is not a verdict"),
    ('txn.verdict == "out"', 16, "'out' is not a verdict (ok, nak, reference_mismatch, timeout, pnio_error, "
                                 "malformed)"),
    ('pd.ref contains "1"', 8, "contains needs a text or bytes field, pd.ref holds integers"),
    ("ip.src & 1", 8, "& needs an integer field, ip.src holds addresses"),
    ("pd.ref & x", 10, "'x' is not an integer (pd.ref holds integers)"),
    ('ip.src matches "168"', 8, "matches needs a text or bytes field, ip.src holds addresses"),
    ("txn.verdict matches nak", 21, "matches needs a regular expression in double quotes, found 'nak'"),
    ('finding.rule ~ "("', 16, "'(' is not a regular expression (missing ), unterminated subpattern"),
    ("pd.ref $ 1", 8, "unexpected character '$'"),
    ("pd.ref == 1 and", 16, "expected a field name, found the end"),
    ('finding.rule contains "x', 23, 'string not closed'),
    ("", 1, "empty filter"),
])
def test_filter_errors_point_at_the_column(expression: str, column: int, message: str) -> None:
    with pytest.raises(FilterError) as err:
        parse(expression)
    assert err.value.column == column and err.value.message.startswith(message)


def test_contains_on_an_analysis_field_selects_as_tshark_would() -> None:
    """`txn.verdict contains "out"` exited 2 ("'out' is not a verdict"): a part of a value is searched, not named."""
    r = run("dump", TIMEOUTS, "-Y", 'txn.verdict contains "out"', "-T", "fields", "-e", "frame.number", "-e",
            "txn.verdict")
    assert r.returncode == 0
    assert r.stdout.decode().splitlines()[:3] == ["9\ttimeout", "10\ttimeout", "15\ttimeout"]


def test_filter_error_is_one_line_and_exit_2() -> None:
    r = run("dump", WORKED, "-Y", "pd.ref == abc")
    assert r.returncode == 2 and r.stdout == b""
    assert r.stderr.decode() == ("pd-analyze: -Y 'pd.ref == abc': column 11: 'abc' is not an integer "
                                 "(pd.ref holds integers)\n")


@pytest.mark.parametrize("expression", [
    "pn_io.profidrive.parameter.request_reference == 0x01", "pn_io.profidrive.parameter.number ~= 964",
    "pn_io.profidrive.parameter.number != 964", "not pn_io.profidrive.parameter.request_reference",
    "pn_io.error_code1 == 0xb5", "pn_io.profidrive.parameter.error_num == 0x02 || dcerpc.dg_seqnum > 300",
    "dcerpc.dg_flags1 & 0x20", "pn_io.profidrive.parameter.request_reference & 0x02",
    "dcerpc.dg_flags1 bitwise_and 0x08 && !(pn_io.index & 0x0001)",
])
def test_tshark_names_select_what_tshark_selects(expression: str) -> None:
    for capture in (WORKED, FAULT):
        theirs = [row[0] for row in tshark(capture, "-Y", expression, "-T", "fields", "-e", "frame.number")]
        r = run("dump", capture, "-Y", expression, "-T", "fields", "-e", "frame.number")
        assert r.returncode == 0 and r.stdout.decode().split() == theirs


# --- dump -T fields ---------------------------------------------------------------------------------

TSHARK_FIELDS = ["frame.number", "frame.time_epoch", "pn_io.profidrive.parameter.request_reference", "pn_io.index",
                 "pn_io.profidrive.parameter.number", "pn_io.profidrive.parameter.index",
                 "pn_io.profidrive.parameter.no_of_elems", "pn_io.profidrive.parameter.value_w",
                 "pn_io.profidrive.parameter.error_num", "pn_io.seq_number", "pn_io.slot_nr", "pn_io.error_code"]


@pytest.mark.parametrize("name", ["record_rw_le.pcap", "fault_trace.pcap", "pd_negative.pcap",
                                  "two_interfaces.pcapng", "pcap_nsec_be.pcap"])
def test_fields_print_as_tshark_prints_them(name: str) -> None:
    args = [a for f in TSHARK_FIELDS for a in ("-e", f)]
    r = run("dump", SAMPLES / name, "-T", "fields", *args, "-E", "header=y")
    assert r.returncode == 0
    theirs = tshark(SAMPLES / name, "-T", "fields", *args, "-E", "header=y")
    ours = [line.split("\t") for line in r.stdout.decode().splitlines()]
    if name == "pd_negative.pcap":  # protocol.md 8.3 #14: tshark leaves the error block after Response ID 0x80
        assert ours[42][8] == "0x0021" and theirs[42][8] == ""
        ours[42][8] = ""
    assert ours == theirs


def test_fields_options_and_analysis_fields() -> None:
    r = run("dump", WORKED, "-T", "fields", "-e", "frame.number", "-e", "pd.ref", "-e", "pd.addr.pnu", "-e",
            "txn.verdict", "-E", "header=y", "-E", "separator=,", "-E", "quote=d", "-E", "aggregator=/s",
            "--frames", "1,4-")
    assert r.returncode == 0
    assert r.stdout.decode().splitlines() == [
        '"frame.number","pd.ref","pd.addr.pnu","txn.verdict"', '"1","0x01","964 2000","ok"',
        '"4",,,"ok"', '"5",,,"ok"', '"6","0x01",,"ok"']
    r = run("dump", WORKED, "-T", "fields", "-e", "pd.nope")
    assert r.returncode == 2 and b"-e pd.nope: neither a field" in r.stderr
    r = run("dump", WORKED, "-T", "fields")
    assert r.returncode == 2 and b"needs at least one -e FIELD" in r.stderr
    r = run("dump", WORKED, "-T", "fields", "-e", "pd.ref", "-E", "colour=y")
    assert r.returncode == 2 and b"-E colour=y" in r.stderr


@pytest.mark.parametrize("name", ["fault_trace.pcap", "pd_retries_and_duplicates.pcap", "pd_out_of_range.pcap",
                                  "ip_fragments.pcap", "truncated_snaplen.pcap"])
def test_comments_are_the_same_whichever_path_reads_the_capture(name: str) -> None:
    """The notes come from the report's rows: the columnar path's tables say what the per-frame path says."""
    from pd_analyze.output import frame_notes

    said = []
    for columns in (False, True):
        notes = frame_notes.collect(str(SAMPLES / name), Settings(vector=columns))
        said.append([(note.frame, note.comment()) for note in notes])
        notes.close()
    assert said[0] == said[1] and said[0]


def _records(path: Path) -> list[tuple[int, bytes]]:
    """(time in ns, bytes) of every record of a pcap, in order."""
    import dpkt

    with path.open("rb") as f:
        return [(round(ts * 1e6), bytes(buf))
                for ts, buf in dpkt.pcap.Reader(f)]


def test_extract_writes_exactly_the_frames_its_transactions_list(tmp_path: Path) -> None:
    """One rule for `transactions.frames` and `extract` (issue #26 point 4): the frames written are exactly the
    `frames` of the chosen transactions. Txn 3 of pd_retries_and_duplicates is captured twice by a mirror port:
    its frames are every one from 14 to 25, the copies of its requests (15, 19, 23) and of its answers (17, 21,
    25) included, and extract writes those twelve."""
    src = SAMPLES / "pd_retries_and_duplicates.pcap"
    t = analyze(str(src)).transactions.set_index("txn")
    assert t.loc[3, "frames"] == " ".join(str(n) for n in range(14, 26))
    assert t.loc[3, "rpc_retransmissions"] == 3
    source = _records(src)
    failed = list(t.index[t.verdict == "pnio_error"])
    for args, chosen in ((["--txn", "3"], [3]), (["--verdict", "pnio_error"], failed)):
        out = tmp_path / "x.pcap"
        r = run("extract", src, "-w", out, *args)
        assert r.returncode == 0, r.stderr
        listed = sorted({int(n) for txn in chosen for n in t.loc[txn, "frames"].split()})
        assert _records(out) == [source[n - 1] for n in listed]
        assert r.stderr.decode().strip() == f"{out}: {len(listed)} frames of {len(chosen)} transactions written"


def test_value_str_names_only_the_string_values() -> None:
    """The string values are pd.val[i].string, the numbers pd.val[i].value[j]: without their indexes the two names
    are distinct (pd.val.value once collected the numbers and the strings, while `pd-analyze fields` called it
    tshark's value_str); value_str is the first (tshark itself misreads frame 16: protocol.md 8.3 #1)."""
    r = run("dump", SAMPLES / "pd_commissioning.pcap", "-T", "fields", "-e", "pn_io.profidrive.parameter.value_str",
            "-e", "pd.val.string", "-e", "pd.val.value", "--frames", "16")
    strings, same, numbers = r.stdout.decode().rstrip("\n").split("\t")
    assert strings == same == "SINAMICS G120,deadbeef01,Pump 1"
    assert numbers and not {"SINAMICS G120", "deadbeef01", "Pump 1"} & set(numbers.split(","))
    listed = {line.split()[0]: line for line in run("fields").stdout.decode().splitlines()}
    assert "pd.val[i].value" not in listed
    assert "pn_io.profidrive.parameter.value_str" in listed["pd.val[i].string"]
    assert "value_str" not in listed["pd.val[i].value[j]"]
    found = parse('pd.val.string contains "Pump"')
    assert [ref.names for ref in found.refs] == [("pd.val[i].string",)]
    assert [ref.names for ref in parse("pd.val.value").refs] == [("pd.val[i].value[j]",)]


def test_the_readme_b5_example_selects_the_b5_answers() -> None:
    """The README's `-Y` example for "the B5 answers" once was `not pd.ref and iod.index == 0xb02e`, which selects
    read requests and write responses and never a B5 answer (a B5 answer has no IOD header)."""
    import re

    import pd_analyze

    line = next(line for line in (ROOT / "README.md").read_text().splitlines() if line.endswith("# the B5 answers"))
    expression = re.search(r"-Y '([^']+)'", line).group(1)
    assert expression == "ndr.status.code1 == 0xb5"
    r = run("dump", FAULT, "-Y", expression, "-T", "fields", "-e", "frame.number", "-e", "rpc.ptype", "-e",
            "ndr.status.code", "-e", "iod.index")
    rows = [line.split("\t") for line in r.stdout.decode().splitlines()]
    assert {tuple(row[1:]) for row in rows} == {("2", "0xde", "")}  # read responses, no IOD header
    assert len(rows) == pd_analyze.analyze(str(FAULT)).transactions.b5_retries.sum() == 82
    old = run("dump", FAULT, "-Y", "not pd.ref and iod.index == 0xb02e", "-T", "fields", "-e", "frame.number")
    assert not set(old.stdout.decode().split()) & {row[0] for row in rows}


NOT_PNIO_FIELDS = ["frame.number", "dcerpc.pkt_type", "dcerpc.opnum", "dcerpc.dg_act_id", "ip.src", "udp.srcport",
                   "udp.dstport", "ip.flags.mf", "dcerpc.dg_seqnum", "dcerpc.drep", "dcerpc.dg_flags1", "ip.id"]


def test_fields_of_frames_that_are_not_pnio_as_tshark_fills_them() -> None:
    """`-T fields` left every cell of a DCE/RPC frame that is not PNIO (an endpoint-mapper call) empty, and those
    of a plain UDP frame, where tshark fills the layers it decodes; an IP fragment shows its IPv4 header alone."""
    args = [a for f in NOT_PNIO_FIELDS for a in ("-e", f)]
    rows = {name: [line.split("\t") for line in run("dump", SAMPLES / name, "-T", "fields", *args).stdout.decode()
                   .splitlines()] for name in ("record_rw_le.pcap", "ip_fragments.pcap")}
    epm = rows["record_rw_le.pcap"]
    assert epm[2][:8] == ["3", "0", "2", "000000e9-0000-1000-8000-000000000001", "192.168.1.11", "49160", "34964",
                          "0"]  # an endpoint-mapper request (opnum 2: map)
    assert epm[16][:8] == ["17", "", "", "", "192.168.1.11", "50010", "50020", "0"]  # UDP, not DCE/RPC
    assert epm[0] == ["1"] + [""] * (len(NOT_PNIO_FIELDS) - 1)  # not IPv4, no field of these
    assert rows["ip_fragments.pcap"][0][:8] == ["1", "", "", "", "192.168.1.11", "", "", "1"]  # a first fragment
    for name, ours in rows.items():
        assert ours == tshark(SAMPLES / name, "-T", "fields", *args), name


def test_the_fields_of_a_frame_cut_anywhere_never_raise() -> None:
    """Bad input never crashes: every frame of the samples cut at every length, and with bytes flipped."""
    import random

    from pd_analyze import capture
    from pd_analyze.output.frame_layers import fields_of

    rng = random.Random(26)
    for name in ("record_rw_le.pcap", "ip_fragments.pcap", "vlan_stacked.pcap", "linux_sll.pcap"):
        for frame in capture.frames(str(SAMPLES / name)):
            data = bytes(frame.data)
            for n in range(len(data) + 1):
                fields_of(frame.linktype, data[:n])
            for _ in range(50):
                flipped = bytearray(data)
                flipped[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
                fields_of(frame.linktype, bytes(flipped))

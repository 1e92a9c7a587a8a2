"""Issue #16: every output in the engineer's words -- status names, sources a reader can look up,
one notation, exact floats, standard parameter names, and citations that resolve in docs/protocol.md."""

from __future__ import annotations

import re
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from pd_analyze.analysis.api import analyze
from pd_analyze.model import pd_values as pt
from pd_analyze.model.rules import RULES
from pd_analyze.model.values import status_text
from pd_analyze.output.writers import neutralise
from pd_analyze.protocol import profiles
from tests.support import table_rows

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "sample_pcaps"
ERRORS = str(SAMPLES / "pd_b5_and_pnio_errors.pcap")
NEGATIVE = str(SAMPLES / "pd_negative.pcap")
SEED_FILE = re.compile(r"\b\d{3}_[0-9a-f]{16}\.txt\b")


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pd_analyze.cli", *args], capture_output=True, timeout=120)


# --- 1. PNIOStatus explained everywhere ------------------------------------------------------------------

@pytest.mark.parametrize(("status", "text"), [
    ("DF80C300", "DF80C300 write: resource unavailable"),
    ("DE80B500", "DE80B500 read: access state conflict (PROFIdrive: response not ready yet / request still "
                 "processed)"),
    ("DE80B200", "DE80B200 read: access invalid slot/subslot"),
    ("DF81CC01", "DF81CC01 write: PNIO CMWRR (write record): AR state not primary"),
    ("1C010014", "1C010014 RPC fault/reject: nca_server_too_busy"),
    ("00000000", "00000000 OK"),
    ("", ""),
])
def test_status_text(status, text):
    assert status_text(status) == text


def test_transactions_carry_the_status_in_words():
    t = analyze(ERRORS).transactions.set_index("txn")
    assert t.loc[4, "pnio_status"] == "DF80B000"
    assert t.loc[4, "pnio_error_text"] == ("DF80B000 write: access invalid index (no parameter access point at this "
                                           "slot/subslot/index)")
    assert t.loc[8, "pnio_error_text"] == "1C010014 RPC fault/reject: nca_server_too_busy"
    assert t.loc[1, "pnio_error_text"] == ""


def test_dump_names_every_status_byte_and_never_calls_a_failure_ok():
    out = run("dump", ERRORS, "--frames", "14,28").stdout.decode()
    assert "ndr.status.code1 = 0xb5 (access: state conflict" in out
    assert "[not ready: DE80B500 read: access state conflict" in out
    failed = [line for line in out.splitlines() if "status.code = 0xdf" in line]
    assert len(failed) == 2  # the NDR status and the IODWriteResHeader's
    assert all(line.endswith("[failed: DF80B000 write: access invalid index (no parameter access point at this "
                             "slot/subslot/index)]") for line in failed)
    assert "iod.status.code1 = 0xb0 (access: invalid index" in out
    heading = next(line for line in out.splitlines() if line.startswith("Frame 14 "))
    assert heading.endswith("PNIOStatus DE80B500 read: access state conflict (PROFIdrive: response not ready "
                            "yet / request still processed)")


# --- 2. Sources a reader can look up ------------------------------------------------------------------------

def test_no_source_names_an_internal_file():
    texts = [r.source for r in RULES.values()] + list(profiles.TOLERATIONS.values())
    for name in profiles.packaged():
        texts += [lim.source for lim in profiles.load(name).limits]
    assert texts and not [t for t in texts if SEED_FILE.search(t)]
    for path in [*ROOT.joinpath("pd_analyze").rglob("*.*"), ROOT / "README.md", ROOT / "docs" / "protocol.md"]:
        if path.suffix in (".py", ".toml", ".md", ".js", ".css", ".html"):
            assert not SEED_FILE.search(path.read_text(encoding="utf-8")), path


def test_vendor_limit_cites_title_page_and_table():
    yaskawa = profiles.load("yaskawa")
    source = next(lim.source for lim in yaskawa.limits if lim.key == "request.n_params")
    assert source == "Yaskawa SI-EP3 PROFINET Technical Manual SIEP C730600 89E, p. 38, table 8.10: No. of Parameters 1"
    sinamics = profiles.load("sinamics")
    assert next(lim.source for lim in sinamics.limits if lim.key == "request.n_params").startswith(
        "SINAMICS Function Manual 06/2012, p. 613: ")


_CITATION = re.compile(r"protocol\.md(?: sections?| section| §)? ?((?:\d+(?:\.\d+)?(?:\s*(?:-|,|and|/)\s*)?)+)")


def _sections() -> set[str]:
    doc = (ROOT / "docs" / "protocol.md").read_text(encoding="utf-8")
    return {m.group(1) for m in re.finditer(r"^#{2,3} (\d+(?:\.\d+)?)\.? ", doc, re.M)}


def test_every_protocol_md_citation_resolves_in_the_projects_docs():
    sections = _sections()
    assert {"1.4", "2.5", "3.6", "4.6", "4.7", "6.3", "7.4", "9"} <= sections
    cited: dict[str, set[str]] = {}
    files = [p for p in ROOT.joinpath("pd_analyze").rglob("*") if p.suffix in (".py", ".toml", ".js", ".html")]
    files += [p for p in ROOT.joinpath("devtools").rglob("*.py")] + [ROOT / "README.md"]
    for path in files:
        for m in _CITATION.finditer(path.read_text(encoding="utf-8")):
            for number in re.findall(r"\d+(?:\.\d+)?", m.group(1)):
                cited.setdefault(number.rstrip("."), set()).add(path.name)
    assert len(cited) > 20
    missing = {n: sorted(where) for n, where in cited.items() if n not in sections}
    assert not missing


def test_readme_links_the_protocol_reference():
    assert "(docs/protocol.md)" in (ROOT / "README.md").read_text(encoding="utf-8")


# --- 3. One notation; numbering of addresses and blocks ---------------------------------------------------

def test_headings_number_addresses_and_blocks_as_the_field_names_do():
    r = run("decode", "01 01 01 02 10 01 03 c4 00 00 10 03 07 d0 00 00", "--request")
    out = r.stdout.decode()
    assert "Parameter address [0]: P964[0] (drive unit identification)" in out
    assert "Parameter address [1]: P2000[0..2]" in out
    after = out.split("Parameter address [1]: P2000[0..2]")[1]
    assert "pd.addr[1].pnu = 2000" in after and "pd.addr[0]" not in after


_ALL_SAMPLES = sorted(str(p) for p in SAMPLES.glob("*") if p.suffix in (".pcap", ".pcapng", ".gz"))


@pytest.mark.parametrize("profile", ["generic", "sinamics", "sew"])
def test_every_finding_shows_its_value_as_its_field_does(profile):
    """The registry decides the notation of a number (hex for IDs, codes and formats, decimal for counts and
    lengths): a finding's value about a field is written as the field is, in every sample under every
    profile. b5_polling counts B5 answers on txn.b5_retries; the too-short records give their length on
    iod.record_len (before, a count stood on a hex status field and a length on a hex Attribute)."""
    from pd_analyze.model import fields as registry

    findings = analyze(_ALL_SAMPLES, profile=profile).findings
    checked = 0
    for f in findings.itertuples():
        base = re.sub(r"\[\d+\]", "", f.field or "")
        known = registry.FIELDS.get(base) or registry.FIELDS.get(re.sub(r"\[\d+\]", "[i]", f.field or ""))
        if known is None or known.type not in (registry.HEX, registry.UINT) or not f.value:
            continue
        number = f.value.split()[0]
        if not re.fullmatch(r"-?\d+|0x[0-9a-f]+", number):
            continue  # a text value (a status text, a range) is not a number in a notation
        checked += 1
        hexa = registry.value_text(f.field, int(number, 0)).startswith("0x")  # (the dump pads to the width)
        assert number.startswith("0x") == hexa, (f.name, f.field, f.value)
    assert checked > 50
    names = set(findings.name)
    assert {"b5_polling", "pd_too_short"} <= names or profile != "generic", sorted(names)
    b5 = findings[findings.name == "b5_polling"]
    assert set(b5.field) <= {"txn.b5_retries"} and all(v.isdigit() for v in b5.value)


# --- 4. Exact values -----------------------------------------------------------------------------------------

@pytest.mark.parametrize(("raw", "text"), [
    ("46caa340", "25937.625"), ("3dcccccd", "0.1"), ("44bb8000", "1500"), ("7f7fffff", "3.4028235e+38"),
    ("00000001", "1e-45"), ("80000000", "-0"), ("c4420000", "-776"),
])
def test_float32_is_the_shortest_text_that_reads_back(raw, text):
    value = struct.unpack(">f", bytes.fromhex(raw))[0]
    assert pt.float_text(value, 4) == text
    assert struct.pack(">f", float(text)).hex() == raw


def test_float64_shortest_text():
    assert pt.float_text(0.1, 8) == "0.1"
    assert pt.float_text(25937.625, 8) == "25937.625"
    assert pt.float_text(float("nan"), 8) == "nan"


def test_dump_and_json_show_the_exact_float():
    args = ("decode", "01 01 01 01 08 01 46 ca a3 40", "--response")
    assert "pd.val[0].value[0] = 25937.625" in run(*args).stdout.decode()
    assert '"value":25937.625,"show":"25937.625"' in run(*args, "--format", "json").stdout.decode()


def test_numbers_in_a_csv_cell_are_never_prefixed():
    assert neutralise("-775.375 2225.25") == "-775.375 2225.25"
    assert neutralise("-1") == "-1"
    assert neutralise("-inf nan") == "-inf nan"
    assert neutralise("=SUM(A1)") == "'=SUM(A1)"
    assert neutralise("-1 =A1") == "'-1 =A1"
    assert neutralise("@cmd") == "'@cmd"


def test_parameters_error_subindex_column():
    p = analyze(NEGATIVE).parameters
    row = p[p.param == "P2000[5]"].iloc[0]
    assert (row.error, row.error_text, row.error_subindex) == ("0x03", "faulty subindex", 5)
    assert str(p.dtypes["error_subindex"]) == "Int64"
    assert p[p.param == "P9999[0]"].error_subindex.isna().all()  # error 0x00 has no second value


# --- 5. Standard parameter names -----------------------------------------------------------------------------

def test_pnu_names():
    assert pt.pnu_name(964) == "drive unit identification"
    assert pt.pnu_name(947) == "fault number"
    assert pt.pnu_name(985) == "number list of defined parameters"
    assert pt.pnu_name(2000) == ""
    assert pt.pnu_name(2000, {2000: "speed setpoint"}) == "speed setpoint"


def test_pnu_name_columns():
    a = analyze(NEGATIVE)
    p = a.parameters
    assert p[p.pnu == 964].pnu_name.unique().tolist() == ["drive unit identification"]
    assert p[p.pnu == 2000].pnu_name.unique().tolist() == [""]
    assert list(a.changes.columns[:9]) == ["capture", "device", "do", "txn", "frame", "t", "param", "pnu", "pnu_name"]


PLANT_PROFILE = """\
name = "plant"
title = "Plant drives"
description = "the plant's own parameter list"

[error_texts]
"0xC9" = "above the currently valid upper limit"

[pnu_names]
"p1082" = "maximum speed"
"2000" = "reference speed"
"0x4B0" = "ramp-down time"  # 1200
"r947" = "fault number (plant)"
"""


@pytest.fixture
def plant(tmp_path):
    path = tmp_path / "plant.toml"
    path.write_text(PLANT_PROFILE, encoding="utf-8")
    return str(path)


def test_a_profile_file_names_its_parameters(plant):
    named = profiles.load(plant)
    assert dict(named.pnu_names) == {1082: "maximum speed", 2000: "reference speed", 1200: "ramp-down time",
                                     947: "fault number (plant)"}
    assert named.names.pnu(1082) == "maximum speed" and named.names.pnu(947) == "fault number (plant)"
    assert named.names.pnu(964) == "drive unit identification" and named.names.pnu(1083) == ""
    assert named.names.error(0xC9) == "manufacturer-specific 0xc9: above the currently valid upper limit"
    for bad, says in (('"p0" = "x"', "'p0' is not a parameter number 1 ... 65535"),
                      ('"speed" = "x"', "'speed' is not a parameter number"),
                      ('"70000" = "x"', "'70000' is not a parameter number"),
                      ('"12" = ""', "the name of '12' must be a non-empty string"),
                      ('"12" = 3', "the name of '12' must be a non-empty string")):
        broken = Path(plant).with_name("broken.toml")
        broken.write_text(f'name = "broken"\n[pnu_names]\n{bad}\n', encoding="utf-8")
        with pytest.raises(profiles.ProfileError, match=re.escape(says)):
            profiles.load(str(broken))
    assert "parameter names: 4 (P947, P1082, P1200, P2000)" in run("profiles", plant).stdout.decode()


def test_the_profile_names_reach_the_tables_the_summary_and_the_state_on_both_paths(tmp_path, plant):
    from pd_analyze.analysis.capture_run import Settings
    from pd_analyze.analysis.param_state import collect
    from pd_analyze.output import report

    a = analyze(NEGATIVE, profile=plant)
    p = a.parameters
    assert p[p.pnu == 1082].pnu_name.unique().tolist() == ["maximum speed"]
    assert p[p.pnu == 2000].pnu_name.unique().tolist() == ["reference speed"]
    assert p[p.pnu == 964].pnu_name.unique().tolist() == ["drive unit identification"]
    assert p[p.error == "0xc9"].error_text.tolist() == ["manufacturer-specific 0xc9: above the currently valid "
                                                       "upper limit"]
    assert a.changes[a.changes.pnu == 1082].pnu_name.unique().tolist() == ["maximum speed"]
    text = report.summary(a)
    assert "       1  192.168.1.21 DO 1 P1082[0] (maximum speed) error 0xc9 (manufacturer-specific 0xc9: above the " \
           "currently valid upper limit)" in text.splitlines()  # the NAKs, named likewise
    assert "         1  P1082[0] (maximum speed): refused: error 0xc9 (manufacturer-specific 0xc9: above the " \
           "currently valid upper limit)" in _drive_lines(report.summary(a, top=30))
    files = {}
    for columns in (False, True):
        out = tmp_path / str(columns)
        streamed = report.stream([NEGATIVE], str(out), "csv", Settings(plant, vector=columns))
        assert streamed.summary == text
        files[columns] = (out / "parameters.csv").read_bytes(), (out / "changes.csv").read_bytes()
        state, _ = collect([NEGATIVE], Settings(plant, vector=columns))
        assert {row[6] for row in state.rows() if row[3] == 2000} == {"reference speed"}  # pnu_name
    assert files[False] == files[True] and b",maximum speed," in files[True][0]
    plain = analyze(NEGATIVE).parameters
    assert plain[plain.pnu == 1082].pnu_name.unique().tolist() == [""]  # only the profile in use names them


def test_the_dump_names_parameters_as_the_profile_does(plant):
    out = run("dump", NEGATIVE, "--profile", plant).stdout.decode()
    assert "Parameter address [1]: P1082[0] (maximum speed)" in out
    assert "pd.addr[1].pnu = 1082 (maximum speed)" in out
    assert "(manufacturer-specific 0xc9: above the currently valid upper limit)" in out
    assert "maximum speed" not in run("dump", NEGATIVE).stdout.decode()


def test_annotate_comments_give_the_profile_error_texts(plant):
    from pd_analyze.analysis.capture_run import Settings
    from pd_analyze.output.frame_notes import collect

    def texts(settings: Settings) -> list[str]:
        notes = collect(NEGATIVE, settings)
        try:
            return [n.comment() for n in notes if "0xc9" in n.comment()]
        finally:
            notes.close()

    plant_text = "manufacturer-specific 0xc9: above the currently valid upper limit"
    refused = "I T9 the drive refused the transaction of frame 61: P1082[0]: error 0xc9"  # at the NAK (6.5)
    assert texts(Settings(plant)) == [f"pd-analyze: txn 15 nak; P1082[0] error 0xc9 {plant_text}; I Q10 {plant_text}; "
                                      f"{refused} ({plant_text})"]
    assert texts(Settings()) == ["pd-analyze: txn 15 nak; P1082[0] error 0xc9 manufacturer-specific 0xc9; I Q10 "
                                 f"manufacturer-specific 0xc9; {refused} (manufacturer-specific 0xc9)"]


def test_b5_retries_is_a_display_filter_field_and_where_b5_polling_counts():
    out = run("dump", ERRORS, "-Y", "txn.b5_retries >= 2", "-T", "fields", "-e", "frame.number", "-e", "txn.id",
              "-e", "txn.b5_retries").stdout.decode()
    rows = [line.split("\t") for line in out.splitlines()]
    assert rows and all(int(r[2]) >= 2 for r in rows)
    t = analyze(ERRORS).transactions
    want = {int(x) for f in t[t.b5_retries >= 2].frames for x in f.split()}
    assert {int(r[0]) for r in rows} == want


# --- 7. dump habits -----------------------------------------------------------------------------------------

RETRIES = str(SAMPLES / "pd_retries_and_duplicates.pcap")


def test_findings_only_shows_every_finding_audit_shows_at_its_frame():
    audit = run("audit", RETRIES, "--fail-on", "never").stdout.decode().splitlines()[:-1]
    want = sorted((int(line.split(":")[1]), line.split(": ", 1)[1].split()[1]) for line in audit)
    out = run("dump", RETRIES, "--findings-only").stdout.decode()
    got, frame = [], 0
    for line in out.splitlines():
        if line.startswith("Frame "):
            frame = int(line.split()[1])
        elif line.startswith("  ! "):
            got.append((frame, line.split()[2]))
    assert sorted(got) == want
    assert ("28", "T4") in {(str(f), r) for f, r in got}  # a transaction-level finding, at its frame
    assert "Frame 28 " in out and "! I T4 retry [pd.ref]: retry of the transaction of frame 26" in out


def test_a_closed_pipe_ends_quietly_with_the_sigpipe_status():
    for args in (("dump", NEGATIVE), ("dump", NEGATIVE, "--format", "json"), ("dump", NEGATIVE, "--color")):
        p = subprocess.Popen([sys.executable, "-m", "pd_analyze.cli", *args], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE)
        p.stdout.read(10)
        p.stdout.close()
        err = p.stderr.read()
        assert p.wait(timeout=120) == 141, args
        assert b"Traceback" not in err and b"Exception" not in err


def test_frames_beyond_the_capture_are_reported_on_stderr():
    r = run("dump", str(SAMPLES / "worked_example.pcap"), "--frames", "4,90-100,200-")
    assert r.returncode == 0 and r.stdout.decode().count("Frame ") == 1
    assert "pd-analyze: " in r.stderr.decode()
    assert "--frames 90-100, 200- lie beyond the capture's 6 frames" in r.stderr.decode()
    assert "--frames 7-9 (of 4-9) lies beyond the capture's 6 frames" in run(  # the part of a range past the end
        "dump", str(SAMPLES / "worked_example.pcap"), "--frames", "4-9").stderr.decode()


def test_color_always_never_auto():
    path = str(SAMPLES / "worked_example.pcap")
    assert run("dump", path, "--frames", "1", "--color", "always").stdout.startswith(b"\x1b[32mFrame 1\x1b[0m")
    assert run("dump", path, "--frames", "1", "--color").stdout.startswith(b"\x1b[32mFrame 1")
    for args in (("--color", "never"), ("--color", "auto"), ("--no-color",), ()):
        assert b"\x1b" not in run("dump", path, "--frames", "1", *args).stdout, args  # auto: not a terminal


def test_time_formats():
    path = str(SAMPLES / "worked_example.pcap")

    def heads(*args: str) -> list[str]:
        out = run("dump", path, "--frames", "1,4", *args).stdout.decode()
        return [line.split("  ")[1] for line in out.splitlines() if line.startswith("Frame ")]
    assert heads() == ["1767225600.000000", "1767225600.004400"]
    assert heads("-t", "ud") == ["2026-01-01 00:00:00.000000 UTC", "2026-01-01 00:00:00.004400 UTC"]
    assert heads("-t", "u") == ["00:00:00.000000", "00:00:00.004400"]
    assert heads("-t", "r") == ["0.000000", "0.004400"]
    assert heads("-t", "dd") == ["0.000000", "0.004400"]
    assert heads("--time-format", "r", "--frames", "4-") == ["0.004400", "0.014600", "0.016300"]


def test_dump_accepts_a_directory(tmp_path):
    for name in ("worked_example.pcap", "write_multiple.pcap"):
        (tmp_path / name).write_bytes((SAMPLES / name).read_bytes())
    r = run("dump", str(tmp_path), "--findings-only")
    assert r.returncode == 0
    assert [line for line in r.stdout.decode().splitlines() if line.startswith("==> ")] == [
        f"==> {tmp_path / 'worked_example.pcap'} <==", f"==> {tmp_path / 'write_multiple.pcap'} <=="]


# --- 8. No output on unreadable input ------------------------------------------------------------------------

@pytest.mark.parametrize("fmt", ["csv", "parquet", "html"])
def test_report_on_unreadable_input_writes_nothing(tmp_path, fmt):
    bad = tmp_path / "notes.pcap"
    bad.write_text("hello, not a capture")
    for path in (tmp_path / "absent.pcap", bad):
        out = tmp_path / f"out-{path.stem}"
        r = run("report", str(path), "--out", str(out), "--format", fmt)
        assert r.returncode == 2
        assert not out.exists()
        assert b"Wrote" not in r.stderr and r.stderr.decode().startswith(f"pd-analyze: {path}: ")


def test_report_names_an_unreadable_file_before_what_it_wrote(tmp_path):
    r = run("report", str(tmp_path / "absent.pcap"), str(SAMPLES / "worked_example.pcap"), "--out", str(tmp_path / "o"))
    err = r.stderr.decode()
    assert r.returncode == 2 and err.index("no such file") < err.index("Wrote ")


def _decoded(hex_bytes: str) -> dict:
    import json

    return json.loads(run("decode", hex_bytes, "--request", "--format", "json").stdout)


@pytest.mark.parametrize(("record", "name", "shown"), [
    ("01 01 01 01 10 eb 03 c4 00 00", "pd.addr[0].n_elems", "235"),  # a count: decimal in field and finding
    ("01 03 01 01 10 01 03 c4 00 00", "pd.req_id", "0x03"),  # an ID: hex in both
    ("01 01 01 01 10 01 03 c4 ff ff", "pd.addr[0].subindex", "65535"),
])
def test_a_field_and_its_findings_share_one_notation(record, name, shown):
    doc = _decoded(record)
    assert next(f["show"] for f in doc["fields"] if f["name"] == name).split(" ")[0] == shown
    about = [f for f in doc["findings"] if f["field"] == name]
    assert about and all(f["value"] == shown and f"{name} = {shown}" in f["message"] for f in about
                         if f["name"] in ("pd_request_range", "vendor_limit"))
    assert all(f["value"] == shown for f in about)


# --- 6. The summary answers the commissioning questions ----------------------------------------------------

def test_summary_lists_failed_parameters_per_drive_with_the_reason_and_the_slowest():
    from pd_analyze.output import report

    text = report.summary(analyze([ERRORS, str(SAMPLES / "pd_timeouts.pcap")]))
    drives = text.split("Failed, timed-out and refused parameters per drive (device, slot, DO; worst first):\n")[1]
    drives = drives.split("\n\n")[0].splitlines()
    assert drives[0] == "  192.168.1.21 slot 1 DO 1: 5"
    assert "         1  P964[0] (drive unit identification): DE80B200 read: access invalid slot/subslot" in drives
    assert "         1  P964[0] (drive unit identification): 1C010014 RPC fault/reject: nca_server_too_busy" in drives
    assert "         1  P2000[0] P2001[0] P2002[0] ... (39 parameters): DF80B100 write: access write length error " \
           "(parameter request above the record limit or shorter than its header, or read buffer too small)" in drives
    assert "         1  P971[0] (transfer into non-volatile memory): timeout: the capture ended before an answer " \
           "came (its last read 1004 ms after the write, 2 B5 answers)" in drives
    # a busy drive given up (every read B5 until the deadline) is pnio_error DE80B500 (protocol.md 7.3 step 5)
    assert "         1  P964[0] (drive unit identification): DE80B500 read: access state conflict (PROFIdrive: " \
           "response not ready yet / request still processed)" in drives
    assert "         1  P964[0] (drive unit identification): timeout: no answer within the transaction timeout (the " \
           "controller gave up: last read 5 ms after the write, 1 B5 answer)" in drives
    slowest = text.split("Slowest parameters, ms (write to final response):\n")[1].splitlines()
    assert slowest[0] == ("   111.500  192.168.1.21 slot 1 DO 1 P971[0] (transfer into non-volatile memory) "
                          "(transaction 2)")


def _drive_lines(text: str) -> list[str]:
    part = text.split("Failed, timed-out and refused parameters per drive (device, slot, DO; worst first):\n")[1]
    return part.split("\n\n")[0].splitlines()


def test_summary_names_each_refused_parameter_of_a_nak_in_the_order_of_the_capture():
    from pd_analyze.output import report

    drives = _drive_lines(report.summary(analyze(NEGATIVE)))
    assert drives[:4] == [
        "  192.168.1.21 slot 1 DO 1: 17",
        "         1  P9999[0]: refused: error 0x00 (impermissible parameter number (PNU does not exist))",
        "         1  P1082[0]: refused: error 0x02 (low or high limit exceeded)",
        "         1  P2[0]: refused: error 0x01 (parameter value cannot be changed)"]  # transaction 1, then 2
    assert "         1  P2000[0] P2001[0] P2002[0] ... (20 parameters): refused as a whole request: error 0x22 " \
           "(too many parameter requests (multi-parameter))" not in drives[:11]  # beyond the first ten ...
    assert drives[11] == "    ... 7 more (the transactions and parameters tables list them all)"  # ... and counted
    assert drives[12:] == ["  192.168.1.21 slot 1 DO 9: 1",
                           "         1  P964[0] (drive unit identification): refused: error 0x19 (axis / DO does not "
                           "exist)"]
    assert len(_drive_lines(report.summary(analyze(NEGATIVE), top=30))) == 1 + 17 + 2


def test_summary_lists_a_nak_that_names_no_error_too():
    from pd_analyze.output import report

    drives = _drive_lines(report.summary(analyze(str(SAMPLES / "pd_out_of_range.pcap")), top=40))
    assert "         2  P964[0] (drive unit identification): refused: negative response without an error block" \
        in drives  # Q8: a 0x81 answer with no error block, transactions 190 and 192


def test_summary_itemises_a_bounded_number_of_failures_and_counts_the_rest(monkeypatch):
    """A flood of distinct failures (each request another parameter set) must not grow the summary without
    bound: past ITEMISED distinct entries a failure or NAK is counted, not listed; the totals stay exact, and
    the rows and the batches feed the same summary."""
    from pd_analyze.analysis.schema import sort_key
    from pd_analyze.analysis.table_batches import rows_to_batch
    from pd_analyze.output import report, summary

    a = analyze(NEGATIVE)
    whole = _drive_lines(report.summary(a, top=40))
    monkeypatch.setattr(summary, "ITEMISED", 3)
    rows_acc, batch_acc = summary.Summary(), summary.Summary()
    for name in ("transactions", "parameters"):
        rows = sorted(table_rows(a.rows, name), key=sort_key(name))
        rows_acc.add(name, rows)
        for k in range(0, len(rows), 4):
            batch_acc.add_batch(name, rows_to_batch(name, rows[k:k + 4]))
    text = rows_acc.text(a.captures, top=40)
    assert batch_acc.text(a.captures, top=40) == text
    assert len(rows_acc.refused) == 3 and len(rows_acc.naks) == 3
    drives = _drive_lines(text)
    assert drives[0] == whole[0] == "  192.168.1.21 slot 1 DO 1: 17"  # the total stays exact
    assert drives[1:4] == whole[1:4]  # the first three in capture order are itemised
    assert drives[4] == "    ... and 14 more failures not itemised (the summary itemises 3 distinct ones)"
    assert drives[5:] == ["  192.168.1.21 slot 1 DO 9: 1",
                          "    ... and 1 more failures not itemised (the summary itemises 3 distinct ones)"]
    p = a.parameters  # an error of the whole request is one NAK, whatever the number of its parameters
    naks = int(((p.error != "") & ~p.whole_request).sum()) + p[p.whole_request].txn.nunique()
    assert f"  ... and {naks - 3} more NAKs not itemised (the summary itemises 3 distinct " \
           "ones; the parameters table lists them all)" in text.splitlines()


def test_summary_names_a_drive_by_its_station_name_when_the_capture_has_it(tmp_path):
    """A drive that answered a PN-DCP Identify (frame 25) is named '192.168.1.21 (pump-1)' wherever the summary
    lists drives; the other keeps its address. The same text from analyze() and the streamed report, the
    columnar path (which finds the name in its batches) and the per-frame one (in a pass of its own)."""
    from pd_analyze.analysis.capture_run import Settings
    from pd_analyze.output import report

    path = str(SAMPLES / "audit_commissioning.pcap")
    text = report.summary(analyze(path))
    for columns in (False, True):
        assert report.stream([path], str(tmp_path / str(columns)), "csv", Settings(vector=columns)).summary == text
    lines = text.splitlines()
    assert "  192.168.1.21 (pump-1)      2  (nak=2)" in lines
    assert "       2  192.168.1.21 (pump-1) DO 1 P1300[0] error 0x02 (low or high limit exceeded)" in lines
    assert _drive_lines(text) == ["  192.168.1.21 (pump-1) slot 1 DO 1: 2",
                                  "         2  P1300[0]: refused: error 0x02 (low or high limit exceeded)"]
    slowest = text.split("Slowest parameters, ms (write to final response):\n")[1].splitlines()
    assert slowest[2] == "     2.400  192.168.1.21 (pump-1) slot 1 DO 1 P1300[0] (transaction 3)"  # a microsecond pcap
    assert slowest[4] == "     2.400  192.168.1.22 slot 1 DO 1 P1120[0] (transaction 5)"
    latency = text.split("Latency per device, ms (write to final response; slowest first):\n")[1].splitlines()
    assert latency[:3] == [
        "  device                     n      p50      p90      p99      max  write rtt p50",
        "  192.168.1.21 (pump-1)      4    2.400    2.400    2.400    2.400  0.900",
        "  192.168.1.22               2    2.400    2.400    2.400    2.400  0.900"]


# --- 10. The HTML report -------------------------------------------------------------------------------------

def test_the_plots_name_a_drive_by_its_station_name():
    from pd_analyze.output import plots

    a = analyze([str(SAMPLES / "audit_commissioning.pcap"), ERRORS])
    for chart in (plots.timeline, plots.latency):
        ticks = [t.get_text() for t in chart(a).axes[0].get_yticklabels()]
        assert ticks == ["192.168.1.21 (pump-1)", "192.168.1.22"], chart.__name__
    legend = [t.get_text() for t in plots.b5_retries(analyze(ERRORS)).axes[0].get_legend().get_texts()]
    assert legend and all(t.startswith("192.168.1.") and "(pump-1)" not in t for t in legend)  # no DCP there


@pytest.mark.parametrize("width", [None, 6.0])  # plots.timeline's own figure (the HTML report's), an axes of 6 in
def test_timeline_labels_neither_overprint_nor_leave_the_chart(width):
    """Every failure label lies inside the axes and overlaps no other label nor a failure marker; every text
    of the chart (title, tick labels, axis label, legend, labels) lies inside the saved (tight) area; the
    title counts the failures left without a label."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.text import Annotation

    from pd_analyze.output import plots

    a = analyze([str(SAMPLES / n) for n in ("fault_trace.pcap", "pd_b5_and_pnio_errors.pcap", "pd_timeouts.pcap")])
    if width is None:
        fig = plots.timeline(a)
    else:
        fig = Figure(figsize=(width, 4.0), layout="constrained")
        plots.timeline(a, fig.add_subplot())
    FigureCanvasAgg(fig)
    renderer = fig.canvas.get_renderer()
    fig.draw(renderer)
    ax = fig.axes[0]
    labels = [c for c in ax.get_children() if isinstance(c, Annotation)]
    boxes = [label.get_window_extent(renderer) for label in labels]
    inside = ax.get_window_extent(renderer)
    assert len(labels) >= 10
    for i, box in enumerate(boxes):
        assert inside.x0 <= box.x0 and box.x1 <= inside.x1 and inside.y0 <= box.y0 and box.y1 <= inside.y1
        assert not any(box.overlaps(other) for other in boxes[i + 1:]), labels[i].get_text()
    failures = int((a.transactions.verdict != "ok").sum())
    title = ax.get_title(loc="left")
    if len(labels) < failures:
        assert title.endswith(f"; {failures - len(labels)} failures without a label: too close to others)")
    else:
        assert title.endswith(f"({len(a.transactions)} transactions)")
    saved = fig.get_tightbbox(renderer).transformed(fig.dpi_scale_trans)  # what bbox_inches="tight" keeps
    low, high = sorted(ax.get_xlim())
    ticks = [t for x, t in zip(ax.get_xticks(), ax.get_xticklabels(), strict=True) if low <= x <= high]  # drawn
    texts = [ax.title, ax.xaxis.label, *ax.get_yticklabels(), *ticks, *ax.get_legend().get_texts(), *labels]
    for text in texts:
        if text.get_text():
            box = text.get_window_extent(renderer)
            assert saved.x0 <= box.x0 and box.x1 <= saved.x1 and saved.y0 <= box.y0 and box.y1 <= saved.y1, \
                text.get_text()


def test_html_shows_ids_as_words_status_texts_and_parameter_names():
    from pd_analyze.output import html_report

    page = html_report.render(analyze(ERRORS))
    assert '"DF80B000 write: access invalid index (no parameter access point at this slot/subslot/index)"' in page
    assert '"0x02 change parameter (write)"' in page and '"0x01 request parameter, positive"' in page
    page = html_report.render(analyze(NEGATIVE))
    assert '"0x81 request parameter, negative"' in page


def test_values_typed_for_pandas():
    v = analyze(NEGATIVE).values
    six = v[(v.param == "P2000[0..5]") & (v.side == "written")]
    assert six.element.tolist() == [0, 1, 2, 3, 4, 5] and six.value.tolist() == [1, 2, 3, 4, 5, 6]
    read = v[(v.param == "P2000[0]") & (v.side == "read")].iloc[0]
    assert type(read.value) is float and read.value == 1500.0 and read.format == "FloatingPoint32"
    word = v[(v.param == "P964[0]") & (v.side == "read")].iloc[0]
    assert word.value == 0x1234 and word.pnu_name == "drive unit identification"
    assert str(v.dtypes["number"]) == "Float64" and str(v.dtypes["element"]) == "Int64"
    text = analyze(str(SAMPLES / "crafted_strings.pcap")).values
    assert text[text.param == "P1[0]"].value.iloc[0] == "<script>alert(1)</script><b>x</b"
    assert text[text.param == "P1[0]"].number.isna().all()


def test_parquet_partitions_are_named_by_the_capture_file_name(tmp_path):
    import pandas as pd

    from pd_analyze.output import report

    for sub in ("line1", "line2"):
        (tmp_path / sub).mkdir()
        (tmp_path / sub / "drive.pcap").write_bytes((SAMPLES / "worked_example.pcap").read_bytes())
    files = [str(tmp_path / "line1" / "drive.pcap"), str(tmp_path / "line2" / "drive.pcap")]
    report.write_tables(analyze(files), str(tmp_path / "out"), "parquet")
    parts = sorted(p.parent.name for p in (tmp_path / "out" / "transactions").rglob("*.parquet"))
    assert parts == ["capture=drive.pcap", "capture=drive.pcap~2"]
    back = pd.read_parquet(tmp_path / "out" / "transactions")
    assert sorted(back.capture.astype(str)) == ["drive.pcap", "drive.pcap~2"]


def test_timeline_labels_failures_with_their_transaction_numbers():
    import base64

    from pd_analyze.output import html_report

    page = html_report.render(analyze(ERRORS))
    figure = page.split('<figure id="plot-timeline">')[1].split("</figure>")[0]
    svg = base64.b64decode(figure.split("base64,")[1].split('"')[0]).decode()
    texts = re.findall(r"<text[^>]*>([^<]*)</text>", svg)
    for txn, status in ((3, "DF80B100"), (4, "DF80B000"), (7, "DE80B200"), (8, "1C010014")):
        assert any(t.startswith(f"{txn}: pnio_error {status} ") for t in texts), (txn, [t for t in texts if ":" in t])
    assert "labelled with their txn number and what failed" in figure


# --- 9. Progress that tells the time ----------------------------------------------------------------------

def _repeated_capture(path: Path, times: int) -> int:
    """A pcap of the retries sample `times` over (100 s apart): enough frames for several progress updates."""
    src = (SAMPLES / "pd_retries_and_duplicates.pcap").read_bytes()
    out, at = bytearray(src[:24]), 24
    records = []
    while at < len(src):
        size = 16 + struct.unpack_from("<I", src, at + 8)[0]
        records.append(src[at:at + size])
        at += size
    for k in range(times):
        for r in records:
            sec, usec = struct.unpack_from("<II", r, 0)
            out += struct.pack("<II", sec + 100 * k, usec) + r[8:]
    path.write_bytes(bytes(out))
    return len(out)


@pytest.mark.skipif(not Path("/proc/self/fdinfo").is_dir(), reason="the read position is seen through /proc")
def test_progress_on_a_terminal_shows_percent_of_bytes_and_time_left(tmp_path):
    import fcntl
    import os
    import pty
    import termios
    import threading

    capture = tmp_path / "big.pcap"
    _repeated_capture(capture, 40)  # 11.8 MB: more than one 8 MiB read of the capture, so a bar part way
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 160, 0, 0))
    seen = bytearray()

    def read() -> None:
        while True:
            try:
                chunk = os.read(master, 65536)
            except OSError:
                return
            if not chunk:
                return
            seen.extend(chunk)
    reader = threading.Thread(target=read)
    reader.start()
    r = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "report", str(capture), "--out", str(tmp_path / "o")],
                       stdout=subprocess.DEVNULL, stderr=slave, timeout=300)
    os.close(slave)
    reader.join(10)
    os.close(master)
    lines = seen.decode(errors="replace").replace("\r", "\n").splitlines()
    bars = [line for line in lines if line.startswith(f"{capture}: ") and "%|" in line]
    assert r.returncode == 0 and bars
    # at the end: every byte and every frame read (1,339 frames of the sample, 40 times)
    assert any(re.search(r" 100%\|.*\| 11\.8M/11\.8M \[\d\d:\d\d<\d\d:\d\d, .*53,560 frames\]", b) for b in bars)
    assert any(re.search(r" (3[0-9]|[4-9][0-9])%\|.*<\d\d:\d\d", b) for b in bars)  # part way, with the time left


def test_t_last_read_says_how_long_the_controller_kept_asking():
    t = analyze(str(SAMPLES / "pd_timeouts.pcap")).transactions
    timed_out = t[(t.verdict == "timeout") & t.t_last_read.notna()]
    assert sorted(round(float(x) * 1000, 1) for x in timed_out.t_last_read) == [5.0, 1004.0]
    given_up = t[(t.verdict == "pnio_error") & (t.pnio_status == "DE80B500")]  # protocol.md 7.3 step 5
    assert round(float(given_up.t_last_read.max()) * 1000, 1) == 1005.5
    assert str(t.dtypes["t_last_read"]) == "Float64"

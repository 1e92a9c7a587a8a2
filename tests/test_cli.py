"""The command line: outputs, exit codes, and helpful errors under bad usage."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

SAMPLE = "sample_pcaps/worked_example.pcap"


def run(*args: str, stdin: bytes | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pd_analyze.cli", *args], capture_output=True, input=stdin,
                          timeout=120)


def test_dump_text_and_accounting_line():
    r = run("dump", SAMPLE, "--frames", "6")
    out = r.stdout.decode()
    assert r.returncode == 0
    assert out.startswith("Frame 6  1767225600.016300  192.168.0.2 -> 192.168.0.1  Read response, seq 3")
    assert "00d4  12 34" in out and "pd.val[0].value[0] = 0x1234" in out
    assert r.stderr.decode().strip() == f"{SAMPLE}: 6 frames read, 6 PNIO RPC decoded, 0 skipped"
    assert "\x1b[" not in out  # no colour when stdout is not a terminal


def test_dump_json_lines_and_stdin():
    data = Path(SAMPLE).read_bytes()
    r = run("dump", "-", "--format", "json", stdin=data)
    lines = [json.loads(line) for line in r.stdout.decode().splitlines()]
    assert r.returncode == 0 and [o["frame"] for o in lines] == [1, 2, 3, 4, 5, 6]
    first = lines[0]
    assert set(first) >= {"frame", "time", "src", "dst", "fields", "findings"}
    seq = next(f for f in first["fields"] if f["name"] == "rpc.seq")
    assert seq == {"name": "rpc.seq", "offset": 106, "length": 4, "raw": "01000000", "value": 1, "show": "1",
                   "check": ""}


def test_findings_only():
    r = run("dump", "sample_pcaps/truncated_snaplen.pcap", "--findings-only")
    out = r.stdout.decode()
    assert r.returncode == 0 and out.count("Frame ") == 1 and "! E R1 rpc_truncated" in out


def test_bad_usage_exit_2():
    for args, text in ((("dump", SAMPLE, "--frames", "9-3"), "bad frame range"),
                       (("dump", SAMPLE, "--profile", "nosuch"), "unknown profile 'nosuch'"),
                       (("dump", SAMPLE, "--bogus"), "No such option"),
                       (("dump",), "no capture given"),
                       (("decode", "zz", "--request"), "not hex")):
        r = run(*args)
        assert r.returncode == 2, args
        assert text in r.stderr.decode(), (args, r.stderr)
        assert b"Traceback" not in r.stderr


def test_unreadable_input_exit_2(tmp_path):
    bad = tmp_path / "cut.pcap"
    bad.write_bytes(Path(SAMPLE).read_bytes()[:300])
    r = run("dump", str(bad))
    assert r.returncode == 2
    assert r.stdout.decode().count("Frame ") == 1
    assert f"{bad}: byte " in r.stderr.decode() and b"Traceback" not in r.stderr
    r = run("report", str(tmp_path / "absent.pcap"), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "no such file" in r.stderr.decode()


def test_decode_sinamics_style_multi_parameter_change():
    r = run("decode", "40 02 02 04 10 01 04 1F 00 00 10 01 04 20 00 00 10 02 04 21 00 01 10 01 04 22 00 00"
            " 43 01 00 00 00 05 06 01 00 07 08 02 3F 80 00 00 40 00 00 00 42 01 12 34", "--request",
            "--profile", "sinamics")
    out = r.stdout.decode()
    assert r.returncode == 0
    for text in ("pd.ref = 64", "pd.n_params = 4", "Parameter address [2]: P1057[1..2]",
                 "Parameter [2]: P1057[1..2] FloatingPoint32 x 2", "pd.val[2].value[1] = 2", "no findings"):
        assert text in out, text


def test_decode_dpv1_and_json():
    r = run("decode", "5F 00 2F 0A 01 01 01 01 10 00 00 2F 00 00", "--dpv1", "--format", "json")
    obj = json.loads(r.stdout)
    names = [f["name"] for f in obj["fields"]]
    assert names[:4] == ["dpv1.function", "dpv1.slot", "dpv1.index", "dpv1.length"]
    assert obj["findings"] == []
    r = run("decode", "5F 00 2E 0B 01 01 01 01 10 00 00 2F 00 00", "--dpv1", "--format", "json")
    assert [f["field"] for f in json.loads(r.stdout)["findings"]] == ["dpv1.index", "dpv1.length"]


def test_report_and_audit(tmp_path):
    out = tmp_path / "rep"
    r = run("report", "sample_pcaps/truncated_snaplen.pcap", SAMPLE, "--out", str(out))
    assert r.returncode == 0
    assert "Transactions: 3  ok=2" in r.stdout.decode()
    assert sorted(p.name for p in out.iterdir()) == ["changes.csv", "findings.csv", "parameters.csv",
                                                      "transactions.csv"]
    r = run("audit", "sample_pcaps/truncated_snaplen.pcap")
    lines = r.stdout.decode().splitlines()
    assert r.returncode == 1
    # a frame's findings in the order of their rules in the registry (model/rules.py): rpc_truncated is
    # found reading the RPC header, truncated_capture_pnio (why it is cut) is declared after it
    assert lines[:4] == ["sample_pcaps/truncated_snaplen.pcap:7: error R1 rpc_truncated: fragment body cut: "
                         "134 of 176 bytes present [txn 2]",
                         "sample_pcaps/truncated_snaplen.pcap:7: error L1 truncated_capture_pnio: capture cut inside "
                         "a PNIO RPC PDU (snaplen) [txn 2]",
                         "sample_pcaps/truncated_snaplen.pcap:7: error H5 record_truncated: record at index 0xb02e "
                         "truncated: RecordDataLength 92, 50 bytes present [txn 2]",
                         # the transaction the cut write request opened is malformed: T8 at that request (6.5)
                         "sample_pcaps/truncated_snaplen.pcap:7: warning T8 txn_failed: the transaction of frame 7 "
                         "failed: malformed: the write request of frame 7 cannot be decoded [txn 2]"]
    assert lines[-1] == "5 findings in 1 capture: 3 error, 1 warning, 1 info"
    assert run("audit", "sample_pcaps/truncated_snaplen.pcap", "--fail-on", "never").returncode == 0
    assert run("audit", SAMPLE, "--fail-on", "info").returncode == 0


def test_profiles_and_fields_listing():
    r = run("profiles")
    out = r.stdout.decode()
    assert r.returncode == 0
    assert out.splitlines()[0].split() == ["limit", "generic", "akd", "sew", "sinamics", "yaskawa"]
    assert "Yaskawa SI-EP3 PROFINET Technical Manual SIEP C730600 89E, p. 38" in out
    assert "    Request ID 0x40 SEW MOVILINK service (layout read, answered 0x40/0xc0)  <- DFE32B Fieldbus " \
           "Interface PROFINET IO, ch. 7.2" in out and "      Attribute 0x30: MOVILINK WRITE parameter volatile " \
           "(change)" in out
    r = run("fields")
    assert "pd.addr[i].pnu" in r.stdout.decode() and "pn_io.profidrive.parameter.number" in r.stdout.decode()


# --- hostile and broken input: every command, every kind of damage --------------------------------------------
def _damaged(tmp_path: Path, kind: str) -> tuple[str, bytes | None, int, int | None]:
    """(path or '-', stdin, frames before the damage, byte offset of the damage or None)."""
    import gzip
    import itertools
    import struct

    from tests.test_capture import epb, idb, shb

    good = Path(SAMPLE).read_bytes()
    starts = [24]
    while starts[-1] < len(good):
        starts.append(starts[-1] + 16 + struct.unpack_from("<I", good, starts[-1] + 8)[0])
    path = tmp_path / f"{kind}.pcap"
    if kind == "bad_magic":
        data, frames, offset = b"\x00\x01\x02\x03" + good[4:], 0, 0
    elif kind == "record_header_cut":
        data, frames, offset = good[:starts[3] + 9], 3, starts[3]
    elif kind == "caplen_too_big":
        data = bytearray(good)
        struct.pack_into("<I", data, starts[3] + 8, 262_145)
        data, frames, offset = bytes(data), 3, starts[3]
    elif kind == "pcapng_block_length":
        records = [good[s + 16:e] for s, e in itertools.pairwise(starts)]
        blocks = [epb(0, 1_000_000 * i, f) for i, f in enumerate(records)]
        bad = bytearray(blocks[3])
        bad[-4:] = struct.pack("<I", 16)
        head = shb() + idb(1) + b"".join(blocks[:3])
        data, frames, offset = head + bytes(bad) + b"".join(blocks[4:]), 3, len(head)
        path = tmp_path / "block.pcapng"
    elif kind == "gzip_crc":
        raw = bytearray(gzip.compress(good, mtime=0))
        raw[-8] ^= 0xFF
        data, frames, offset = bytes(raw), 6, len(good)
        path = tmp_path / "crc.pcap.gz"
    elif kind == "empty":
        data, frames, offset = b"", 0, 0
    elif kind == "stdin_cut":
        return "-", good[:starts[4] + 20], 4, starts[4]
    elif kind == "unreadable":
        return "/proc/self/mem", None, 0, 0
    elif kind == "directory":
        (tmp_path / "empty_dir").mkdir()
        return str(tmp_path / "empty_dir"), None, 0, None
    else:
        raise AssertionError(kind)
    path.write_bytes(data)
    return str(path), None, frames, offset


DAMAGE = ("bad_magic", "record_header_cut", "caplen_too_big", "pcapng_block_length", "gzip_crc", "empty",
          "stdin_cut", "unreadable", "directory")


@pytest.mark.parametrize("kind", DAMAGE)
@pytest.mark.parametrize("command", ["dump", "report", "audit"])
def test_damaged_input_one_line_error_results_before_it_exit_2(tmp_path, kind, command):
    path, stdin, frames, offset = _damaged(tmp_path, kind)
    args = [command, path] + (["--out", str(tmp_path / "out")] if command == "report" else [])
    r = run(*args, stdin=stdin if stdin is not None else b"")
    out, err = r.stdout.decode(), r.stderr.decode()
    assert r.returncode == 2, (kind, command, err)
    assert "Traceback" not in err and "internal error" not in err, err
    errors = [line for line in err.splitlines() if line.startswith(("pd-analyze:", "Error:"))]
    assert len(errors) == 1, err  # one line
    if kind == "directory":
        assert "no capture files matched" in errors[0]  # dump takes a directory as report and audit do
        return
    where = f"{path}: byte {offset}: "
    assert errors[0].startswith(f"pd-analyze: {where}"), errors[0]
    if command == "dump":  # the results for every frame before the damage
        assert [line.split()[1] for line in out.splitlines() if line.startswith("Frame ")] == [
            str(n) for n in range(1, frames + 1)]
    elif command == "report" and frames == 0 and path != "-":  # nothing readable: no summary, no files
        assert out == "" and not (tmp_path / "out").exists() and "Wrote" not in err
    elif command == "report":
        assert out.startswith(f"{path}: {frames} frames read = {frames} decoded + 0 skipped + 0 malformed")
        assert "ERROR byte" in out.splitlines()[0]
    else:  # findings of the frames before the damage only, and the total line
        lines = out.splitlines()
        assert lines[-1].endswith(" info") and " findings in 1 capture: " in lines[-1]
        assert all(int(line.split(":")[1]) <= frames for line in lines[:-1])


def test_unreadable_file_without_read_rights(tmp_path):
    import os

    if os.geteuid() == 0:
        pytest.skip("root reads any file: permission denied is covered in tests/test_robustness.py")
    bad = tmp_path / "locked.pcap"
    bad.write_bytes(Path(SAMPLE).read_bytes())
    bad.chmod(0)
    r = run("audit", str(bad))
    assert r.returncode == 2 and "permission denied" in r.stderr.decode()


@pytest.mark.parametrize(("profile", "message"), [
    ('name = "x"\nerror_texts = "nope"\n', "'error_texts' must be a table"),
    ('name = "x"\ntolerate = 5\n', "'tolerate' must be a list"),
    ('name = "x"\nvendor_ids = 7\n', "'vendor_ids' must be a list of integers"),
    ('name = "x"\nlimit = 3\n', "'limit' must be an array of tables"),
    ('name = "x"\n[[limit]]\nkey = "iod.slot"\nallowed = "1-3"\nsource = "s"\n', "'allowed' must be a list"),
    ('name = "x"\n[[limit]]\nkey = ["iod.slot"]\nallowed = [1]\nsource = "s"\n', "'key' must be a string"),
    ('name = "x"\n[[limit]]\nkey = "iod.slot"\nallowed = [1]\nsource = "s"\nrule = 5\n', "'rule' must be"),
    ('name = "x"\ntolerate = [["a"]]\n', "tolerate entries must be names"),
    ('import os\nos.system("true")\n', "not valid TOML"),
    ("\xff\xfe", "not valid TOML"),
])
def test_malformed_profile_file_is_a_usage_error(tmp_path, profile, message):
    path = tmp_path / "mine.toml"
    path.write_bytes(profile.encode("latin-1"))
    commands = [["audit", SAMPLE, "--profile", str(path)]]
    if "TOML" in message:  # every command that takes a profile
        commands += [["dump", SAMPLE, "--profile", str(path)], ["profiles", str(path)],
                     ["report", SAMPLE, "--profile", str(path), "--out", str(tmp_path / "o")],
                     ["decode", "01010101100103c40000", "--request", "--profile", str(path)]]
    for args in commands:
        r = run(*args)
        err = r.stderr.decode()
        assert r.returncode == 2 and message in err and str(path) in err and "Traceback" not in err, (args, err)
        assert "internal error" not in err


@pytest.mark.parametrize(("args", "text"), [
    (("dump", SAMPLE, "--frames", "abc"), "bad frame range 'abc'"),
    (("dump", SAMPLE, "--frames", "0"), "frames are numbered from 1"),
    (("dump", SAMPLE, "--frames", ","), "empty frame selection"),
    (("report", SAMPLE, "--timeout", "nan"), "'nan' is not a number of seconds"),
    (("audit", SAMPLE, "--rpc-timeout", "0"), "is not in the range"),
    (("report", SAMPLE, "--format", "xlsx"), "'xlsx' is not one of"),
    (("audit", SAMPLE, "--fail-on", "sometimes"), "'sometimes' is not one of"),
    (("audit", SAMPLE, "--profile", "nosuch"), "unknown profile 'nosuch' (known: akd, generic"),
    (("profiles", "nosuch"), "unknown profile 'nosuch'"),
    (("frobnicate",), "No such command 'frobnicate'"),
    (("report", "--bogus", SAMPLE), "No such option"),
    (("audit",), "no capture given"),
])
def test_bad_usage_helpful_message_exit_2(args, text):
    r = run(*args)
    err = r.stderr.decode()
    assert r.returncode == 2 and text in err and "Traceback" not in err, (args, err)


def test_report_to_an_unwritable_place_is_a_usage_error(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    proc = run("report", "sample_pcaps/worked_example.pcap", "--out", str(blocker / "out"))
    assert proc.returncode == 2
    err = proc.stderr.decode().strip().splitlines()
    assert err == [f"pd-analyze: --out {blocker / 'out'}: cannot write there (Not a directory) (see 'pd-analyze report "
                   "--help')"]
    assert "Traceback" not in proc.stderr.decode() and not (blocker.parent / "out").exists()


def test_report_from_standard_input_with_jobs(tmp_path):
    """Standard input is one stream: --jobs analyses it in one process."""
    proc = run("report", "-r", "-", "--jobs", "2", "--out", str(tmp_path), stdin=Path(SAMPLE).read_bytes())
    assert proc.returncode == 0, proc.stderr.decode()
    assert (tmp_path / "transactions.csv").read_text().count("\n") == 2  # header and the one transaction


# --- one form for every error; the small edges of issue 26 (point 9) -----------------------------------------

def test_an_unreadable_dump_ends_with_its_error_alone(tmp_path):
    """`dump` of an input that cannot be read at all printed "0 frames read, ..." after its error."""
    junk = tmp_path / "junk.pcap"
    junk.write_bytes(b"junk\n")
    reason = f"pd-analyze: {junk}: byte 0: not a pcap or pcapng file (magic 6a756e6b; convert other formats with " \
             "editcap first)\n"
    for extra in ((), ("-T", "fields", "-e", "frame.number"), ("-Y", "pd.ref")):
        r = run("dump", str(junk), *extra)
        assert (r.returncode, r.stdout, r.stderr.decode()) == (2, b"", reason), extra
    r = run("dump", "-", stdin=b"")
    assert r.returncode == 2 and r.stderr.decode() == "pd-analyze: -: byte 0: empty file: no capture header\n"
    cut = tmp_path / "cut.pcap"  # damaged after its first frame: that frame, the error, then the count
    cut.write_bytes(Path(SAMPLE).read_bytes()[:300])
    r = run("dump", str(cut))
    assert r.stderr.decode().splitlines() == [f"pd-analyze: {cut}: byte 262: record data truncated (22 of 206 bytes "
                                              "present)", f"{cut}: 1 frames read, 1 PNIO RPC decoded, 0 skipped"]


def test_every_error_is_one_line_that_starts_the_same_and_a_missing_file_reads_the_same(tmp_path):
    """Error lines began `pd-analyze:` for captures and `Error:` elsewhere, and a missing file read `no such file` or
    `cannot read it (No such file or directory)` depending on the option."""
    absent = str(tmp_path / "absent")
    for args in (("dump", absent), ("dump", "-r", absent), ("report", absent), ("audit", absent),
                 ("params", absent), ("diff", absent, SAMPLE), ("diff", SAMPLE, absent),
                 ("annotate", absent, "-w", str(tmp_path / "o.pcapng")), ("extract", absent, "-w", str(tmp_path / "o")),
                 ("audit", SAMPLE, "--expect", absent)):
        r = run(*args)
        assert (r.returncode, r.stderr.decode()) == (2, f"pd-analyze: {absent}: no such file\n"), args
    for command in ("dump", "audit"):
        r = run(command, SAMPLE, "--profile", absent + ".toml")
        assert (r.returncode, r.stderr.decode()) == (2, f"pd-analyze: Invalid value for --profile: {absent}.toml: no "
                                                        f"such file (see 'pd-analyze {command} --help')\n")
    for args, line in ((("frobnicate",), "No such command 'frobnicate' (see 'pd-analyze --help')"),
                       (("dump", SAMPLE, "--bogus"), "No such option '--bogus' (see 'pd-analyze dump --help')"),
                       (("dump", SAMPLE, "-Y", "pd.ref =="), "-Y 'pd.ref ==': column 10: expected a value after ==, "
                                                             "found the end")):
        r = run(*args)
        assert (r.returncode, r.stderr.decode()) == (2, f"pd-analyze: {line}\n"), args


def test_a_frame_range_partly_beyond_the_capture_is_said(tmp_path):
    """`--frames 5-9` of a capture of 6 frames said nothing of 7-9; a range wholly beyond it was said."""
    for extra in ((), ("-T", "fields", "-e", "frame.number")):
        r = run("dump", SAMPLE, "--frames", "2,5-9", *extra)
        assert r.returncode == 0
        assert r.stderr.decode().splitlines() == [
            f"pd-analyze: {SAMPLE}: --frames 7-9 (of 5-9) lies beyond the capture's 6 frames",
            f"{SAMPLE}: 6 frames read, 6 PNIO RPC decoded, 0 skipped"]
    r = run("dump", SAMPLE, "--frames", "5-7,9-12,20-")
    assert r.stderr.decode().splitlines()[0] == (f"pd-analyze: {SAMPLE}: --frames 7 (of 5-7), 9-12, 20- lie beyond "
                                                 "the capture's 6 frames")
    r = run("dump", SAMPLE, "--frames", "3-,4-6")  # an open end runs to the capture's end: nothing to say
    assert r.stderr.decode().splitlines() == [f"{SAMPLE}: 6 frames read, 6 PNIO RPC decoded, 0 skipped"]


def test_decode_dash_reads_standard_input():
    hex_text = "01 01 01 02 10 01 03 C4 00 00 10 03 07 D0 00 00"
    given = run("decode", hex_text, "--request")
    r = run("decode", "-", "--request", stdin=(hex_text[:23] + "\n" + hex_text[24:] + "\n").encode())
    assert r.returncode == given.returncode == 0 and r.stdout == given.stdout
    assert r.stdout.decode().startswith("PROFIdrive parameter request, 16 bytes, profile generic\n")
    r = run("decode", "-", "--request", stdin=b"")
    assert (r.returncode, r.stderr.decode()) == (2, "pd-analyze: Invalid value for HEX: no bytes given (see "
                                                    "'pd-analyze decode --help')\n")

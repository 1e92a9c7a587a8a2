"""The command line: outputs, exit codes, and helpful errors under bad usage."""

import json
import subprocess
import sys
from pathlib import Path

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
    for text in ("pd.ref = 64", "pd.n_params = 4", "Parameter address 3: P1057[1..2]",
                 "Parameter 3: P1057[1..2] FloatingPoint32 x 2", "pd.val[2].value[1] = 2", "no findings"):
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
    assert lines[0] == ("sample_pcaps/truncated_snaplen.pcap:7: error R1 rpc_truncated: fragment body cut: "
                        "134 of 176 bytes present [txn 2]")
    assert lines[-1] == "4 findings in 1 capture: 3 error, 0 warning, 1 info"
    assert run("audit", "sample_pcaps/truncated_snaplen.pcap", "--fail-on", "never").returncode == 0
    assert run("audit", SAMPLE, "--fail-on", "info").returncode == 0


def test_profiles_and_fields_listing():
    r = run("profiles")
    out = r.stdout.decode()
    assert r.returncode == 0 and out.splitlines()[0].split() == ["limit", "generic", "akd", "sinamics", "yaskawa"]
    assert "000_8871e7857f299724.txt" in out
    r = run("fields")
    assert "pd.addr[i].pnu" in r.stdout.decode() and "pn_io.profidrive.parameter.number" in r.stdout.decode()

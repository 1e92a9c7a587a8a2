"""The summary prints no internal value, counts what its lines name, and keeps its findings when no transaction
formed (issue 28, points 6-8), from both of its feeds: rows (output/summary.py) and batches
(output/summary_batches.py), which must give the same text. The captures are built here with the generator's
encoders."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import pd_analyze
from devtools.synth import fixtures
from devtools.synth.pd_encode import ParamAddress as P
from devtools.synth.pd_encode import error_block, pd_request, pd_response, read_request
from devtools.synth.sim_capture import Capture
from pd_analyze.analysis.schema import sort_key
from pd_analyze.analysis.table_batches import rows_to_batch
from pd_analyze.output import report
from pd_analyze.output.summary import Summary
from tests.support import table_rows

ROOT = Path(__file__).resolve().parents[1]
E22 = "error 0x22 (too many parameter requests (multi-parameter))"
E16 = "error 0x16 (parameter address impermissible (attribute, elements, PNU, subindex or combination))"


@pytest.fixture(scope="module")
def captures(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    where = tmp_path_factory.mktemp("summary")
    cap = Capture()
    s = fixtures.session(cap, 1)
    # txn 1: a 40-parameter read refused as a whole (one error block, No. of parameters mirrored)
    s.parameter_access(read_request(1, 1, [P(2000 + k) for k in range(40)]),
                       pd_response(1, 0x81, 1, [error_block(0x22)], n_params=40))
    # txn 2: a request of no parameter, refused
    s.parameter_access(pd_request(2, 0x01, 1, []), pd_response(2, 0x81, 1, [error_block(0x16)], n_params=0))
    # txn 3: a request too short for its header (its DO is not decoded), refused
    s.parameter_access(b"\x03\x01", pd_response(3, 0x81, 1, [error_block(0x16)]))
    # txn 4: one parameter refused
    s.parameter_access(read_request(4, 1, [P(964)]), pd_response(4, 0x81, 1, [error_block(0x00)]))
    # txns 5-25: 21 more 40-parameter requests refused as a whole
    for ref in range(5, 26):
        s.parameter_access(read_request(ref, 1, [P(2000 + k) for k in range(40)]),
                           pd_response(ref, 0x81, 1, [error_block(0x22)], n_params=40))
    mix = where / "mix.pcap"
    mix.write_bytes(fixtures.pcap_of(cap))
    cap = Capture()
    s = fixtures.session(cap, 1)
    s.read(0xB02E, pd_response(9, 0x81, 1, [error_block(0x02)]))  # a negative response, its request not captured
    orphan = where / "orphan.pcap"
    orphan.write_bytes(fixtures.pcap_of(cap))
    return {"mix": mix, "orphan": orphan}


def both_feeds(analysis: pd_analyze.Analysis, batch: int) -> tuple[str, str]:
    """The summary from the rows one by one, and from batches of `batch` rows (a request's rows split over
    batches), in table order; times at each capture's resolution, as the report writes them."""
    rows_acc, batch_acc = Summary(analysis.rows.digits), Summary(analysis.rows.digits)
    for name in ("transactions", "parameters", "findings"):
        rows = sorted(table_rows(analysis.rows, name), key=sort_key(name))
        rows_acc.add(name, rows)
        for k in range(0, len(rows), batch):
            batch_acc.add_batch(name, rows_to_batch(name, rows[k:k + batch]))
    return rows_acc.text(analysis.captures), batch_acc.text(analysis.captures)


def summary_of(path: Path) -> str:
    """The summary, the same from the rows and from batches of 1, 3 and 4,096 rows."""
    analysis = pd_analyze.analyze(str(path))
    text = report.summary(analysis)
    for batch in (1, 3, 4096):
        assert both_feeds(analysis, batch) == (text, text), batch
    return text


def section(text: str, heading: str) -> list[str]:
    return text.split(heading + "\n")[1].split("\n\n")[0].splitlines()


def test_a_whole_request_refusal_counts_once(captures):
    """Point 7: one refused 40-parameter request counted 0x22=40 (21 of them 0x22=840), against the per-drive
    list's "refused as a whole request"."""
    naks = section(summary_of(captures["mix"]), "NAKs by PNU and error number (worst first):")
    assert naks == [
        f"      22  192.168.1.21 DO 1 (whole request) {E22}",
        f"       1  192.168.1.21 DO 1 (whole request) {E16}",
        "       1  192.168.1.21 DO 1 P964[0] (drive unit identification) error 0x00 (impermissible parameter number "
        "(PNU does not exist))",
        f"       1  192.168.1.21 DO unknown (whole request) {E16}",
        "  by error number: 0x22=22, 0x16=2, 0x00=1",
        "  by DO: 1=24"]


def test_no_internal_value_is_printed(captures):
    """Point 6: `DO <NA>` for a request whose DO is unknown, and "(parameters not decoded)" with an empty PNU for a
    request of no parameter."""
    text = summary_of(captures["mix"])
    assert "<NA>" not in text and "DO -1" not in text
    drives = section(text, "Failed, timed-out and refused parameters per drive (device, slot, DO; worst first):")
    assert drives == [
        "  192.168.1.21 slot 1 DO 1: 24",
        f"        22  P2000[0] P2001[0] P2002[0] ... (40 parameters): refused as a whole request: {E22}",
        f"         1  (request of no parameter): refused as a whole request: {E16}",
        "         1  P964[0] (drive unit identification): refused: error 0x00 (impermissible parameter number (PNU "
        "does not exist))",
        "  192.168.1.21 slot 1 DO unknown: 1",
        "         1  (parameters not decoded): malformed: a PDU could not be decoded (see the findings)"]
    import pandas as pd

    params = pd_analyze.analyze(str(captures["mix"])).parameters  # the table holds no DO -1 either
    assert params.query("txn == 3")[["do", "param", "error"]].astype(object).values.tolist() == [[pd.NA, "", "0x16"]]


def test_the_html_page_shows_the_same_summary(captures, tmp_path):
    """Point 6, the HTML part: the page's summary text is the report's."""
    r = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "report", str(captures["mix"]), "--format", "html",
                        "--out", str(tmp_path)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    page = (tmp_path / "report.html").read_text()
    summary = page.split('<section id="summary-text">')[1].split("</section>")[0]
    assert "&lt;NA&gt;" not in summary and "DO unknown" in summary
    assert f"      22  192.168.1.21 DO 1 (whole request) {E22}" in summary
    assert "         1  (request of no parameter): refused as a whole request: error 0x16" in summary


def test_findings_stay_when_no_transaction_formed(captures):
    """Point 8: `report` printed only "No PROFIdrive transactions found." where `audit` listed the findings; a
    negative response without its request appears as the read that had no write (T2) and its own findings."""
    text = summary_of(captures["orphan"])
    assert text.splitlines()[1:] == [
        "",
        "No PROFIdrive transactions found.",
        "",
        "Findings: 2  error=0  warning=1  info=1",
        "       1  Q9 error_subindex_presence",
        "       1  T2 read_without_request"]
    audit = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "audit", str(captures["orphan"])],
                           capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert audit.stdout.splitlines()[-1] == "2 findings in 1 capture: 0 error, 1 warning, 1 info"


def test_one_text_per_error_number_whatever_the_order_of_rows(captures):
    """Point 6 of issue 26 (already done by commit 5839303 for the per-drive list, verified here): one error number
    given two texts (a vendor's word and the profile's) reads one text, the same in both feeds and in either order
    of the rows; the NAK list too has one line per number."""
    analysis = pd_analyze.analyze(str(captures["mix"]))
    rows = sorted(table_rows(analysis.rows, "parameters"), key=sort_key("parameters"))
    at = next(i for i, r in enumerate(rows) if r.error == "0x00")
    worded = rows[at]._replace(error_text="vendor: no such parameter", txn=rows[-1].txn + 1)
    texts = set()
    for order in ([*rows, worded], [worded, *rows]):
        for feed in ("rows", "batches"):
            acc = Summary(analysis.rows.digits)
            for name in ("transactions", "findings"):
                acc.add(name, table_rows(analysis.rows, name))
            if feed == "rows":
                acc.add("parameters", order)
            else:
                acc.add_batch("parameters", rows_to_batch("parameters", order))
            texts.add(acc.text(analysis.captures))
    (text,) = texts
    naks = section(text, "NAKs by PNU and error number (worst first):")
    assert [line for line in naks if "error 0x00" in line] == [
        "       2  192.168.1.21 DO 1 P964[0] (drive unit identification) error 0x00 (impermissible parameter number "
        "(PNU does not exist))"]  # the first text in sort order, whatever came first


def _one_drive(path: Path, name: str) -> Path:
    """Drive .21 changes P1120 twice; it announces `name` in a PN-DCP Identify response ("" announces none)."""
    from devtools.synth.audit_samples import dcp_identify_response
    from devtools.synth.net_encode import ETH_PNRT
    from devtools.synth.pd_encode import change_ok, change_request, value_block

    cap = Capture()
    s = fixtures.session(cap, 1)
    for ref in (1, 2):
        s.parameter_access(change_request(ref, 1, [(P(1120), value_block(0x08, [10.0]))]), change_ok(ref, 1, 1))
    if name:
        ctrl, dev = fixtures.plant(1)
        cap.send_ether(dev, ctrl.mac, ETH_PNRT, dcp_identify_response(dev.ip, name, 1))
    path.write_bytes(fixtures.pcap_of(cap))
    return path


def _latency_devices(paths: list[Path]) -> list[str]:
    analysis = pd_analyze.analyze([str(p) for p in paths])
    text = report.summary(analysis)
    for batch in (1, 4096):
        assert both_feeds(analysis, batch) == (text, text)
    return [line[2:].split("  ")[0].rstrip() for line in
            section(text, "Latency per device, ms (write to final response; slowest first):")[1:]]


def test_station_names_are_kept_per_capture(tmp_path):
    """Point 6 of issue 26: names were merged by address across captures (the later capture's name for every
    capture's drive at that address). Two plants' drives at one address are two devices; a capture without a name
    takes the one name the others agree on; the parameter state, folded by address, shows each name."""
    pump, fan, plain = (_one_drive(tmp_path / f"{n or 'none'}.pcap", n) for n in ("pump-1", "fan-3", ""))
    assert _latency_devices([pump, fan, plain]) == ["192.168.1.21", "192.168.1.21 (fan-3)", "192.168.1.21 (pump-1)"]
    assert _latency_devices([plain, pump]) == ["192.168.1.21 (pump-1)"]  # one name: the same drive
    r = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "params", str(pump), str(fan)], capture_output=True,
                       text=True, timeout=120, cwd=ROOT)
    assert r.stdout.splitlines()[1].startswith("192.168.1.21 (pump-1 / fan-3)  1   P1120[0]")
    assert pd_analyze.analyze([str(fan), str(pump)]).parameter_state.station.tolist() == ["fan-3 / pump-1"]


def test_group_counts_come_in_order_of_first_appearance_nulls_and_chunks_included() -> None:
    """summary_batches._group_counts (numpy over dictionary codes, not pyarrow's group_by, whose order
    differed): each group once, with its count, in the order its first row comes."""
    import pyarrow as pa

    from pd_analyze.output.summary_batches import _group_counts

    device = pa.chunked_array([pa.array(["b", None, "a"], pa.large_string()),
                               pa.array(["a", None, "b", "b"], pa.large_string())])
    do = pa.chunked_array([pa.array([1, 2, None], pa.int64()), pa.array([None, 2, 1, 1], pa.int64())])
    table = pa.table({"device": device, "do": do})
    assert _group_counts(table, ["device", "do"]) == [(("b", 1), 3), ((None, 2), 2), (("a", None), 2)]
    assert _group_counts(table, ["do"]) == [((1,), 3), ((2,), 2), ((None,), 2)]
    assert _group_counts(table.slice(0, 0), ["device", "do"]) == []

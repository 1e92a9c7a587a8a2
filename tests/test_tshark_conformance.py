"""Conformance against tshark 4.0 (protocol.md section 8), frame by frame, field by field.

For every capture in sample_pcaps/ and ../shared/captures/:

- the analyser reports exactly the frames tshark decodes as PNIO CL-RPC (`test_frame_set`);
- every registry field with a tshark counterpart (all layers of protocol.md 8.2, LAYERS) has, per
  frame, the same list of values as its tshark field in the same scope (`test_fields`; the mapping
  and the normalisation live in tshark_fields.py). PROFIdrive fields (pd.*) are compared per record,
  values as raw bits (8.1).

A difference passes only when one of the named rules below explains that exact difference, and each
rule checks the values on both sides where tshark has any (which frame tshark links instead, which
time it measures, which prefix it decodes), so a rule cannot hide an unrelated error
(`test_rules_check_exact_values`, `test_pd_views_compare_exact_values`). Rules come from protocol.md
8.3/8.4 (tshark differs) or from the analyser's documented behaviour; every rule cites its section.
The tshark PROFIdrive bugs of 8.3 are record views (PD_RULES): what of a record is compared, in the
words of 8.3's last column; the bugs no sample shows are exercised on a synthetic capture
(`test_pd_rules_on_synthetic_bugs`). PD_UNLISTED is tshark behaviour 8.3 does not list yet,
PD_DOCUMENTED where the analyser decodes a record differently on purpose (1.4, 5.3), ANALYSER_GAPS /
PD_GAPS analyser shortcomings whose fix lies outside this test: accepted only in their exact form,
to be deleted with the fix. The terminal summary
(tests/conftest.py) counts what each rule accepted.

tshark missing: skip with an install hint on a developer's machine, fail when CI is set (.ci/run
installs tshark, so a skipped conformance test there is an error).
"""

from __future__ import annotations

import copy
import re
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol import profidrive
from pd_analyze.protocol.pnio_view import cut_record
from pd_analyze.protocol.profidrive_checks import Checker
from tests import tshark_fields as tf
from tests.support import SHARED_CAPTURES, unavailable

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "sample_pcaps"
SHARED = SHARED_CAPTURES
PATTERNS = ("*.pcap", "*.pcapng", "*.gz")

# Layers compared (protocol.md 8.2, every row). pd.* fields are found in scope "pd", concrete names
# such as pd.addr[2].pnu grouped under their registry template, and compared record by record; the
# values as raw bits (tshark_fields.PdValue); the tshark PROFIdrive bugs of protocol.md 8.3 are the
# record views below (PD_RULES).
LAYERS = ("frame", "eth", "ip", "udp", "rpc", "ndr", "iod", "pd")

PTYPE_REQUEST, PTYPE_PING, PTYPE_RESPONSE, PTYPE_FAULT, PTYPE_WORKING, PTYPE_NOCALL, PTYPE_REJECT, PTYPE_ACK = (
    0, 1, 2, 3, 4, 5, 6, 7)
LINK_FIELDS = ("rpc.request_frame", "rpc.rtt")
NIL_UUID = "00000000-0000-0000-0000-000000000000"
BT_WRITE_REQ = 0x0008
INDEX_WRITE_MULTIPLE = 0xE040


# --- which captures ----------------------------------------------------------------------------

def capture_files() -> list[Path]:
    """Globbed at collection time: sample_pcaps/ may still be growing. ../shared/captures is
    skipped cleanly when absent (MANIFEST.md)."""
    found: list[Path] = []
    for folder in (SAMPLES, SHARED):
        if folder.is_dir():
            found += sorted({p for pattern in PATTERNS for p in folder.glob(pattern) if p.is_file()})
    return found


def require_tshark() -> None:
    """Skip (developer machine) or fail (CI) when tshark 4.0 is not there."""
    if tf.TSHARK is None:
        unavailable(tf.INSTALL_HINT)
    version = tf.tshark_version()
    if not re.search(r"\b4\.0\.\d+", version):
        unavailable(f"the conformance exceptions are written for tshark 4.0, found {version!r}")


@pytest.fixture(scope="session")
def tshark() -> None:
    require_tshark()


def _id(path: Path) -> str:
    return f"{path.parent.name}/{path.name}"


CAPTURES = capture_files()


@pytest.fixture(scope="session")
def conformance_cache(tshark: None) -> dict[str, tf.Conformance]:
    tf.prefetch(str(p) for p in CAPTURES)  # once per session, in parallel; cached per capture
    return {}


def conformance(path: Path, cache: dict[str, tf.Conformance]) -> tf.Conformance:
    """Both decodes of one capture; tshark runs once per capture per session (cached)."""
    key = str(path)
    if key not in cache:
        cache[key] = tf.Conformance(key, tf.analyser_frames(key), tf.tshark_frames(key),
                                    tf.compared_fields(LAYERS))
    return cache[key]


# --- exception rules ---------------------------------------------------------------------------

Rule = Callable[[tf.Conformance, int, str, list[object], list[object]], bool]


@dataclass(frozen=True)
class NamedRule:
    name: str
    ref: str
    fields: tuple[str, ...] | None  # None: the rule decides by itself which fields it concerns
    check: Rule | None = None
    view: ViewRule | None = None  # pd.* record rules (protocol.md 8.3): how the record is compared


RULES: list[NamedRule] = []
ANALYSER_GAPS: list[NamedRule] = []
LINKS = ("rpc.request_frame", "rpc.rtt", "rpc.response_frame")
HEADER_FOUR = ("iod.block_type", "iod.block_length", "iod.version_high", "iod.version_low")


def rule(name: str, ref: str, fields: tuple[str, ...] | None = None,
         registry: list[NamedRule] = RULES) -> Callable[[Rule], Rule]:
    def register(fn: Rule) -> Rule:
        registry.append(NamedRule(name, ref, fields, fn))
        return fn
    return register


def _rtt_ok(c: tf.Conformance, n: int, rtt: list[object], request: object) -> bool:
    """`rtt` is the one value n.ts - request.ts (within the rpc.rtt tolerance)."""
    frame = c.an.get(n)
    req = c.an.get(request) if isinstance(request, int) else None
    return (frame is not None and req is not None and len(rtt) == 1 and isinstance(rtt[0], float)
            and tf.values_equal("rpc.rtt", rtt[0], round(frame.ts - req.ts, 9)))


def _link(c: tf.Conformance, n: object, side: str) -> object:
    """The frame that `side` ("ours"/"theirs") links n to through rpc.request_frame."""
    if not isinstance(n, int):
        return None
    values = c.ours(n, "rpc.request_frame") if side == "ours" else c.theirs(n, "rpc.request_frame")
    return values[0] if len(values) == 1 else None


def _link_ok(c: tf.Conformance, n: int, name: str, values: list[object], request: object) -> bool:
    """rpc.request_frame is exactly [request], or rpc.rtt exactly n.ts - request.ts."""
    return values == [request] if name == "rpc.request_frame" else _rtt_ok(c, n, values, request)


def _same_call(c: tf.Conformance, a: object, b: object) -> bool:
    return a in c.an and b in c.an and c.an[a].call_key == c.an[b].call_key


def _is_request(c: tf.Conformance, n: object) -> bool:
    return n in c.an and c.an[n].ptype == PTYPE_REQUEST


def _copies(c: tf.Conformance, first: object) -> set[int]:
    """Frames the analyser flags as retransmitted copies of the request in frame `first`."""
    if first not in c.an:
        return set()
    f = c.an[first]
    return {n for n, a in c.an.items() if n != first and a.ptype == PTYPE_REQUEST
            and a.call_key == f.call_key and "rpc_retransmission" in a.findings}


def _first_copy(c: tf.Conformance, n: object) -> int | None:
    """The call's frame when request n is a retransmitted copy of it, else None."""
    if not _is_request(c, n) or "rpc_retransmission" not in c.an[n].findings:
        return None
    key = c.an[n].call_key  # the call's frame: not a copy, not a fragment reassembled elsewhere
    first = min((m for m, a in c.an.items() if a.ptype == PTYPE_REQUEST and a.call_key == key
                 and "rpc_retransmission" not in a.findings and not a.values.get("rpc.reassembled_in")),
                default=None)
    return first if n in _copies(c, first) else None


def _call_frames(c: tf.Conformance, n: object) -> set[int]:
    """Request frames of n's call as tshark may name them: the call's frame and its copies."""
    return {m for m, a in c.an.items() if a.ptype == PTYPE_REQUEST and _same_call(c, n, m)
            and not a.values.get("rpc.reassembled_in")}


def _duplicate_response(c: tf.Conformance, n: object) -> bool:
    """A response PDU the analyser counts as a retransmission: a second response to an answered
    call, or a copy of a response fragment after its PDU was reassembled (protocol.md 2.3, 2.4)."""
    return n in c.an and c.an[n].ptype == PTYPE_RESPONSE and "rpc_retransmission" in c.an[n].findings


@rule("retransmitted request: tshark links the last copy",
      "protocol.md 8.4 (a retransmitted request replaces tshark's call record, response linked to the last "
      "copy; the analyser links the first copy and counts the others, 2.4)", LINKS)
def retransmitted_request(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    if name != "rpc.response_frame":
        last = _link(c, n, "theirs")
        first = _first_copy(c, last)
        return (first is not None and _link(c, n, "ours") == first
                and _link_ok(c, n, name, ours, first) and _link_ok(c, n, name, theirs, last))
    if len(ours) == 1 and theirs == []:  # the first copy: tshark moved its response to a later copy
        return _link(c, ours[0], "ours") == n and _first_copy(c, _link(c, ours[0], "theirs")) == n
    if ours == [] and len(theirs) == 1 and _first_copy(c, n) is not None:  # the later copy
        response = theirs[0]
        return _link(c, response, "theirs") == n and (
            _link(c, response, "ours") == _first_copy(c, n) or _duplicate_response(c, response))
    return False


@rule("duplicate response: counted, not linked",
      "protocol.md 2.4 (same key again: a retransmission, counted) and 2.3 (identical fragment copies dropped); "
      "tshark 4.0 pairs every response PDU with the call's (last) request, 8.4", LINKS)
def duplicate_response(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    if ours:
        return False
    if name != "rpc.response_frame":
        request = _link(c, n, "theirs")
        return _duplicate_response(c, n) and request in _call_frames(c, n) and _link_ok(c, n, name, theirs, request)
    return len(theirs) == 1 and _duplicate_response(c, theirs[0]) and n in _call_frames(c, theirs[0]) \
        and _link(c, theirs[0], "theirs") == n


@rule("retransmitted fragment dropped",
      "protocol.md 2.3 (identical duplicate fragments are retransmissions: dropped, counted); tshark still "
      "gives the copy dcerpc.reassembled_in", ("rpc.reassembled_in",))
def retransmitted_fragment(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    if ours or len(theirs) != 1 or "rpc_retransmission" not in c.an[n].findings:
        return False
    done = theirs[0]
    return (_same_call(c, n, done) and c.an[done].ptype == c.an[n].ptype
            and bool(c.ours(done, "rpc.fragments")))


@rule("fault/reject not paired by tshark",
      "protocol.md 8.4 (RPC pairing) and 2.2 (fault/reject close the call); tshark 4.0 looks no call up for "
      "fault/reject PDUs (no dcerpc.request_in/response_in/time)", LINKS)
def fault_unpaired(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    if theirs:
        return False
    if name != "rpc.response_frame":
        request = _link(c, n, "ours")
        return (c.an[n].ptype in (PTYPE_FAULT, PTYPE_REJECT) and _same_call(c, n, request)
                and _is_request(c, request) and _link_ok(c, n, name, ours, request))
    return (len(ours) == 1 and ours[0] in c.an and c.an[ours[0]].ptype in (PTYPE_FAULT, PTYPE_REJECT)
            and _same_call(c, n, ours[0]))


@rule("ping/ack linked by tshark only",
      "protocol.md 2.2 (ping is counted on the open call, ack ignored: the analyser gives control PDUs no "
      "link); tshark 4.0 shows the call's request in dcerpc.request_in/dcerpc.time", LINK_FIELDS)
def control_pdu_link(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    request = _link(c, n, "theirs")
    return (not ours and c.an[n].ptype in (PTYPE_PING, PTYPE_ACK) and request in _call_frames(c, n)
            and _link_ok(c, n, name, theirs, request))


@rule("pairing across UDP conversations",
      "protocol.md 8.4 (tshark pairs within one UDP address/port conversation; the analyser on activity + "
      "sequence number only, 2.4)", LINKS)
def other_conversation(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    if theirs:
        return False
    other = _link(c, n, "ours") if name != "rpc.response_frame" else (ours[0] if len(ours) == 1 else None)
    if not _same_call(c, n, other) or c.an[n].conversation == c.an[other].conversation:
        return False
    return ours == [other] if name == "rpc.response_frame" else _link_ok(c, n, name, ours, other)


@rule("fragmented response: tshark links its first fragment",
      "protocol.md 7.6 (a response is timed at the frame that completes it) and 2.3; tshark 4.0 links the "
      "request to the first response fragment and gives every response fragment request_in/time (8.1 says "
      "'only dcerpc.reassembled_in', which holds for request fragments)", LINKS)
def fragmented_response(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    if name == "rpc.response_frame":
        if len(ours) != 1 or len(theirs) != 1 or ours[0] not in c.an:
            return False
        fragments = c.ours(ours[0], "rpc.fragments")  # one tuple: the frames of the reassembled response
        return len(fragments) == 1 and theirs[0] in fragments[0] and theirs[0] != ours[0]
    # an earlier fragment of a response: the analyser links only the completing frame to the request
    done = c.ours(n, "rpc.reassembled_in")
    if ours or c.an[n].ptype != PTYPE_RESPONSE or len(done) != 1 or done[0] not in c.an:
        return False
    request, tshark_request = _link(c, done[0], "ours"), _link(c, n, "theirs")
    return (request in c.an and tshark_request in {request} | _copies(c, request)
            and _link_ok(c, n, name, theirs, tshark_request))


def _blocks(c: tf.Conformance, n: int) -> list[tuple[object, ...]]:
    """The analyser's IOD header blocks of frame n: (BlockType, ARUUID, BlockLength, version)."""
    return list(zip(c.ours(n, "iod.block_type"), c.ours(n, "iod.ar_uuid"), c.ours(n, "iod.block_length"),
                    zip(c.ours(n, "iod.version_high"), c.ours(n, "iod.version_low"), strict=True), strict=True))


def _nil_write_targets(c: tf.Conformance, n: int) -> list[tf.TsField]:
    """tshark's pn_io.target_ar_uuid occurrences read from a write header with a NIL ARUUID."""
    frame = c.ts[n]
    blocks: dict[int, dict[str, str]] = {}
    for f in frame.fields:
        if f.scope == "iod" and f.name in ("pn_io.block_type", "pn_io.ar_uuid"):
            blocks.setdefault(f.block_pos, {})[f.name] = f.show
    nil_writes = {pos for pos, b in blocks.items() if b.get("pn_io.ar_uuid") == NIL_UUID
                  and tf.parse_int(b.get("pn_io.block_type", "0")) == BT_WRITE_REQ}
    return [f for f in tf.tshark_occurrences(frame, "iod.target_ar_uuid") if f.block_pos in nil_writes]


@rule("TargetARUUID read from a NIL-ARUUID write header",
      "protocol.md 8.4 (tshark reads a TargetARUUID from a write header whose ARUUID is NIL; display only, the "
      "analyser reports H9): tshark shows TargetARUUID instead of the RWPadding",
      ("iod.target_ar_uuid", "iod.rw_pad"))
def nil_aruuid_write(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    extra = _nil_write_targets(c, n)
    if not extra:
        return False
    if name == "iod.target_ar_uuid":
        kept = [tf.normalise_ts(name, f) for f in tf.tshark_occurrences(c.ts[n], name) if f not in extra]
        return tf.compare_lists(name, ours, kept)
    blocks = _blocks(c, n)
    if len(blocks) != len(ours):
        return False
    kept = [pad for pad, (kind, ar, _, _) in zip(ours, blocks, strict=True)
            if not (kind == BT_WRITE_REQ and ar == NIL_UUID)]
    return len(kept) < len(ours) and tf.compare_lists(name, kept, theirs)


@rule("IOD header with BlockLength != 60 or version != 1.0",
      "protocol.md 8.3 #12 (tshark: version != 1.0 -> block body not decoded, BlockLength != 60 -> next data "
      "searched at BlockLength + 4; the analyser keeps the fixed layout, H2/H3)")
def irregular_iod_header(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    """Both decode the block headers alike; before the first irregular block all fields agree; after
    it tshark's values are missing (version) or read at the wrong place (length); pd.* of such PDUs
    are skipped."""
    blocks = _blocks(c, n)
    bad = [i for i, (_, _, length, version) in enumerate(blocks) if length != 60 or version != (1, 0)]
    if not bad or name in HEADER_FOUR:
        return False
    if name.startswith("pd."):
        return True
    if not name.startswith("iod."):
        return False
    first = bad[0]
    if blocks[first][3] != (1, 0):  # body of that block not decoded: tshark has a prefix of ours
        return len(theirs) < len(ours) and ours[:len(theirs)] == theirs and len(theirs) >= min(first, len(ours))
    keep = first + 1 if len(ours) == len(blocks) else min(len(ours), len(theirs))
    return tf.compare_lists(name, ours[:keep], theirs[:keep])


@rule("PDU cut by the snaplen: stub decoded by the analyser only",
      "protocol.md 1.3 (frames captured short are decoded as far as the captured bytes go, R1); tshark 4.0 "
      "hands no truncated CL-RPC stub to PNIO ('Packet size limited during capture')")
def truncated_stub(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    return (name.startswith(("ndr.", "iod.", "pd.")) and theirs == [] and bool(ours)
            and "rpc_truncated" in c.an[n].findings and c.ts[n].truncated)


def _if_version(c: tf.Conformance, n: object) -> object:
    return c.an[n].one("rpc.if_version") if n in c.an else None


@rule("interface version != 1: stub decoded by the analyser only",
      "protocol.md 6.1 R5 (rpc.if_version = 1, W; the analyser decodes on); tshark 4.0 registers PNIO for "
      "interface version 1 and leaves the stub of another version (and of its response) undecoded")
def interface_version(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    if not name.startswith(("ndr.", "iod.", "pd.")) or theirs or not ours:
        return False
    return _if_version(c, n) != 1 or (c.an[n].ptype == PTYPE_RESPONSE and _if_version(c, _link(c, n, "ours")) != 1)


@rule("nested Write-Multiple: tshark stops after the nested header",
      "protocol.md 2.8 / 6.2 H11 (nested 0xE040 -> E, the analyser decodes the following inner writes); "
      "tshark 4.0 takes the nested record for another Write-Multiple and decodes nothing after it")
def nested_write_multiple(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    index = c.ours(n, "iod.index")
    nested = [i for i, x in enumerate(index) if i > 0 and x == INDEX_WRITE_MULTIPLE]
    if not name.startswith("iod.") or not nested or len(ours) != len(index):
        return False
    keep = nested[0] + 1
    return len(theirs) == keep and tf.compare_lists(name, ours[:keep], theirs)


def _no_tshark_time(c: tf.Conformance, n: object) -> bool:
    return n in c.ts and not c.ts[n].values("frame", "frame.time_epoch")


@rule("pcapng Simple Packet Block: no timestamp",
      "protocol.md 1.2 (pcapng read per block; an SPB carries no timestamp): tshark 4.0 shows none and times "
      "its calls from 0; the analyser keeps the previous frame's time (capture.py) so capture-time timeouts "
      "stay monotonic", ("frame.ts", "rpc.rtt"))
def simple_packet_block(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    if name == "frame.ts":
        return theirs == [] and len(ours) == 1 and _no_tshark_time(c, n)
    request = _link(c, n, "theirs")
    if request not in c.an or request != _link(c, n, "ours") \
            or not (_no_tshark_time(c, n) or _no_tshark_time(c, request)):
        return False
    tshark_time = {m: 0.0 if _no_tshark_time(c, m) else c.an[m].ts for m in (n, request)}
    return (_rtt_ok(c, n, ours, request) and len(theirs) == 1 and isinstance(theirs[0], float)
            and tf.values_equal(name, theirs[0], tshark_time[n] - tshark_time[request]))


@rule("authenticated PDU: body not decoded",
      "protocol.md 2.1 (rpc.auth_proto != 0: W, body not decoded); tshark 4.0 decodes the stub")
def authenticated_body(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    return (name.startswith(("ndr.", "iod.", "pd.")) and not ours and bool(theirs)
            and c.an[n].one("rpc.auth_proto") not in (0, None))


# Analyser gaps: tshark is right; the fix lies outside this test owner's files. Each rule names the
# fix; delete the rule with it.

@rule("ANALYSER GAP: an authenticated PDU neither opens nor closes its call",
      "protocol.md 2.4 (pairing needs the header only); fix: dissect.Dissector._udp returns for "
      "auth_proto != 0 before _request/_response", LINKS, registry=ANALYSER_GAPS)
def authenticated_call(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    other = _link(c, n, "theirs") if name != "rpc.response_frame" else (theirs[0] if len(theirs) == 1 else None)
    if ours or not _same_call(c, n, other):
        return False
    auth = [m for m in (n, other) if c.an[m].one("rpc.auth_proto") not in (0, None)]
    if not auth or "orphan_response" not in c.an[max(n, other)].findings:
        return False
    return theirs == [other] if name == "rpc.response_frame" else _link_ok(c, n, name, theirs, other)


@rule("ANALYSER GAP: a response decoded with its own opnum instead of its request's",
      "protocol.md 2.4 (orphans are 'decoded with their own opnum', so paired responses with the request's; "
      "R4 W); tshark uses the request's opnum. Fix: dissect.Dissector._data_pdu passes hdr.opnum to "
      "rec.parse_stub/checks for a paired response",
      ("iod.add_val1", "iod.add_val2", "iod.status.code", "iod.status.decode", "iod.status.code1",
       "iod.status.code2", "iod.rw_pad", "iod.target_ar_uuid"), registry=ANALYSER_GAPS)
def response_opnum(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    request = _link(c, n, "ours")
    return (c.an[n].ptype == PTYPE_RESPONSE and _same_call(c, n, request)
            and c.an[request].one("rpc.opnum") != c.an[n].one("rpc.opnum")
            and "rpc_response_mismatch" in c.an[n].findings)


@rule("ANALYSER GAP: a header cut short is not decoded as far as present",
      "protocol.md 1.3 (decode as far as the bytes go) vs the analyser's all-or-nothing NDR (20 bytes) and "
      "IOD (64 bytes) headers (findings ndr_truncated / iod_truncated); tshark shows the fields present. Fix "
      "would need partial Blocks in record.py and their annotation in dissect.py")
def cut_header(c: tf.Conformance, n: int, name: str, ours: list[object], theirs: list[object]) -> bool:
    finding = {"ndr.": "ndr_truncated", "iod.": "iod_truncated"}.get(name[:4])
    return (finding is not None and finding in c.an[n].findings and len(theirs) == len(ours) + 1
            and tf.compare_lists(name, ours, theirs[:len(ours)]))


# --- PROFIdrive (protocol.md 8.3): how a record is compared where tshark 4.0.17 decodes it wrongly ---
#
# pd.* fields are compared per record (Mismatch.record = the IOD header block whose record it is).
# Where a bug of protocol.md 8.3 applies to a record, its rule gives a *view*: which of the record's
# values both sides are compared on, exactly as 8.3's last column says ("compare only up to the
# first such block", "skip such records", ...). The view decides by the analyser's decode of the
# record (which bug applies, from which block on) and by the value block of each value (both sides
# tag every pd value with its block; -1 = header and addresses), never by the values themselves, so
# what it keeps is compared exactly. A difference is accepted when one view, or failing that all
# views that apply to the record together, make both sides equal.

Items = list[tuple[int, object]]  # (value block, value) of one field in one record, in wire order
View = Callable[[str, str, Items], Items | None]  # (field, "ours"/"theirs", items) -> compared items; None: reject
ViewRule = Callable[[tf.Conformance, int, int], View | None]  # (conformance, frame, record) -> view, None: n/a

BLOCK_HEAD = ("pd.val[i].format", "pd.val[i].n_values")  # tshark reads each block's own first two bytes right
FMT_VISIBLE_STRING, FMT_ZERO, FMT_ERROR = 0x09, 0x40, 0x44
RES_NOT_SUPPORTED, RES_READ_NAK, RES_CHANGE_NAK = 0x80, 0x81, 0x82
TSHARK_FORMATS = frozenset(tf.VALUE_FIELD_OF_FORMAT)  # formats tshark 4.0.17 has a value field for (8.2)
SUBINDEX_ERRORS = frozenset({0x01, 0x02, 0x03, 0x06, 0x07, 0x14, 0x20})  # 8.3 #11: second word = error_subindex
ERROR_BRANCH = frozenset({RES_READ_NAK, RES_CHANGE_NAK})  # Response IDs whose 0x44 blocks tshark reads as errors
INDEX_PD_DPV1 = 0x002F


@dataclass(frozen=True)
class PdRecord:
    """The analyser's side of one record: its IOD header block, the stub, and the PROFIdrive decode
    (None when the analyser did not take the record for PROFIdrive)."""

    block: rec.Block
    stub: rec.Stub
    last: bool  # the stub's last block: the bytes after its record are the PDU's
    parsed: profidrive.Parsed | None

    @property
    def data(self) -> bytes:
        return self.block.record

    @property
    def blocks(self) -> list[profidrive.Block]:
        return self.parsed.blocks if self.parsed is not None else []

    @property
    def ident(self) -> int | None:
        """Response ID of a parameter response, None for a request."""
        return self.parsed.ident if self.parsed is not None and self.parsed.response else None

    @property
    def errors(self) -> list[tuple[int, profidrive.Block]]:
        """The error blocks tshark decodes as such (0x81/0x82; elsewhere 0x44 is a format, 8.3 #2)."""
        return [(i, b) for i, b in enumerate(self.blocks) if b.is_error] if self.ident in ERROR_BRANCH else []


def _pd_record(c: tf.Conformance, n: int, record: int) -> PdRecord | None:
    pdu = c.an[n].result.pdu if n in c.an else None
    if pdu is None or pdu.stub is None or not 0 <= record < len(pdu.stub.blocks):
        return None
    block = pdu.stub.blocks[record]
    refused = pdu.stub.status is not None and not pdu.stub.status.ok
    # a record cut short is decoded for the dump as far as its bytes go (pnio_view.cut_record)
    parsed = block.pd[0] if isinstance(block.pd, tuple) else cut_record(block, _CHECKER, refused)
    return PdRecord(block, pdu.stub, record == len(pdu.stub.blocks) - 1, parsed)


_CHECKER = Checker.for_profile()


def _cut(k: int, whole: bool = True) -> View:
    """Blocks before k; block k whole, or only its Format and No. of values; nothing after."""
    def view(name: str, side: str, items: Items) -> Items:
        return [(b, v) for b, v in items if b < k or (b == k and (whole or name in BLOCK_HEAD))]
    return view


def _header_only(name: str, side: str, items: Items) -> Items:
    return [(b, v) for b, v in items if b < 0]


def _nothing(name: str, side: str, items: Items) -> Items:
    return []


PD_RULES: list[NamedRule] = []  # the tshark bugs of protocol.md 8.3
PD_UNLISTED: list[NamedRule] = []  # tshark 4.0.17 behaviour that 8.3 does not list (yet)
PD_DOCUMENTED: list[NamedRule] = []  # the analyser decodes differently on purpose (1.4, 5.3; 8.4)
PD_GAPS: list[NamedRule] = []  # analyser shortcomings


def pd_rule(name: str, ref: str, registry: list[NamedRule] = PD_RULES) -> Callable[[ViewRule], ViewRule]:
    def register(fn: ViewRule) -> ViewRule:
        registry.append(NamedRule(name, ref, None, None, fn))
        return fn
    return register


@pd_rule("8.3 #1 VisibleString read as C strings",
         "protocol.md 8.3 #1 (tshark reads each of the m values of a 0x09 block as a NUL-terminated string up "
         "to the end of the PDU; the following values and parameters are misaligned): compare the first "
         "value_str only if a NUL byte directly follows the m characters; compare nothing after a 0x09 block")
def visible_string(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    k = next((i for i, b in enumerate(p.blocks) if b.format == FMT_VISIBLE_STRING), None) if p else None
    if p is None or k is None:
        return None
    text, after = p.blocks[k].data, p.blocks[k].offset + 2 + len(p.blocks[k].data)
    # tshark's first value is the m characters when the first NUL is the byte right after them
    nul = after < len(p.data) and p.data[after] == 0 and 0 not in text
    head = _cut(k, whole=False)

    def view(name: str, side: str, items: Items) -> Items:
        kept = head(name, side, items)
        if name == tf.PD_STRING and nul:
            kept += [(b, v) for b, v in items if b == k][:1]  # the first value_str of the block
        return kept
    return view


@pd_rule("8.3 #2 format without a tshark value field",
         "protocol.md 8.3 #2 (tshark advances one byte per value of an unsupported format: 0x00/0x40 in value "
         "lists, Float64, (U)Int64, dates/times, UnicodeString, N2/N4, T2/T4, D2, R2, L2, E2, C4, X2/X4, 0x44 "
         "outside the error branch; 8.2 maps no field to them): compare only up to the first such block")
def unsupported_format(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    if p is None or p.ident in (RES_CHANGE_NAK, RES_NOT_SUPPORTED):  # blocks not read as values (#9, 0x80)
        return None
    error_branch = p.ident == RES_READ_NAK
    k = next((i for i, b in enumerate(p.blocks) if b.format not in TSHARK_FORMATS
              and not (b.is_error and error_branch)), None)
    return None if k is None else _cut(k, whole=False)


@pd_rule("8.3 #3 no pad byte handling",
         "protocol.md 8.3 #3 (tshark ignores the 3.2 pad byte: after an odd byte-count list the next Format "
         "is the pad): compare only up to the first odd byte-count list that is followed by another block")
def odd_list(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    blocks = p.blocks if p else []
    k = next((i for i, b in enumerate(blocks[:-1]) if not b.is_error and len(b.data) % 2), None)
    return None if k is None else _cut(k)


@pd_rule("8.3 #4 error block with 0 values",
         "protocol.md 8.3 #4 (No. of values 0 in an error block: loop underflow, [Malformed Packet]): skip such "
         "records")
def error_block_empty(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    return _nothing if p and any(b.n_values == 0 for _, b in p.errors) else None


@pd_rule("8.3 #5 error block with more than 2 values",
         "protocol.md 8.3 #5 (with 3+ error values the 3rd and later words are labelled subindex or Value "
         "by the previous word): skip error blocks with > 2 values (their Format and No. of values are "
         "still compared)")
def error_block_long(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    long = {i for i, b in p.errors if b.n_values > 2} if p else set()
    if not long:
        return None

    def view(name: str, side: str, items: Items) -> Items:
        return [(b, v) for b, v in items if b not in long or name in BLOCK_HEAD]
    return view


@pd_rule("8.3 #6 parameter loop stops after error 0x23",
         "protocol.md 8.3 #6 (after an error block with error 0x23 tshark stops, even if more blocks follow): "
         "skip records with 0x23 followed by further blocks")
def error_0x23(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    last = len(p.blocks) - 1 if p else 0
    return _nothing if p and any(b.error == 0x23 and i < last for i, b in p.errors) else None


@pd_rule("8.3 #7 record not bounded by RecordDataLength",
         "protocol.md 8.3 #7 (tshark runs the PROFIdrive parser to the end of the PDU, not of the record): "
         "compare only when the PDU holds no byte after RecordDataLength (a record cut short ends with the PDU: "
         "both decode the bytes present)")
def record_length(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    if p is None or p.block.layout not in (rec.WRITE_REQ, rec.READ_RES):
        return None
    present = len(p.data) + (p.stub.trailing if p.last else 0)
    return _nothing if present > p.block.record_len else None


@pd_rule("8.3 #9 negative change response with a value block",
         "protocol.md 8.3 #9 (in a 0x82 response blocks other than 0x44 consume nothing: right only for 0x40 "
         "with 0 values): compare only 0x82 records whose blocks are 0x40/0 or 0x44")
def negative_change(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    if p is None or p.ident != RES_CHANGE_NAK:
        return None
    regular = all(b.is_error or (b.format == FMT_ZERO and b.n_values == 0) for b in p.blocks)
    return None if regular else _nothing


@pd_rule("8.3 #11 second error word labelled by the error number",
         "protocol.md 8.3 #11 (tshark labels the second error word error_subindex only after errors 0x01, 0x02, "
         "0x03, 0x06, 0x07, 0x14, 0x20, else value_w): compare the second word with error_subindex or value_w "
         "by that rule")
def error_subindex_label(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    moved = {i for i, b in p.errors if b.n_values == 2 and b.error not in SUBINDEX_ERRORS} if p else set()
    if not moved:
        return None
    # the analyser's own error_subindex values of those blocks (not the parse's): a wrong one is caught
    ob, _ = c.pd_blocks(n, "pd.val[i].error_subindex", record)
    subindex = dict(zip(ob, c.pd_records(n, "pd.val[i].error_subindex").get(record, ([], []))[0], strict=True))

    def view(name: str, side: str, items: Items) -> Items:
        if side != "ours":
            return items
        if name == "pd.val[i].error_subindex":
            return [(b, v) for b, v in items if b not in moved]
        if name == tf.PD_VALUES:
            extra = [(b, tf.PdValue("value_w", subindex[b])) for b in sorted(moved) if b in subindex]
            return sorted(items + extra, key=lambda item: item[0])
        return items
    return view


@pd_rule("8.3 #14 Response ID 0x80 body not decoded",
         "protocol.md 8.3 #14 (Response ID 0x80, request not supported: tshark decodes only the 4-byte header, "
         "not the error block that follows; 3.3/4.1: one error block, normally 0x21): compare the header "
         "fields only")
def not_supported_body(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    if p is None or p.ident != RES_NOT_SUPPORTED:
        return None

    def view(name: str, side: str, items: Items) -> Items | None:
        if side == "theirs" and any(b >= 0 for b, _ in items):
            return None  # tshark decoded a block after all: not this behaviour
        return _header_only(name, side, items)
    return view


# Differences that protocol.md 8.3 does not list yet (tshark behaviour seen with 4.0.17) go to PD_UNLISTED:
# accepted only in their exact form, tshark's side pinned to the record bytes, to be added to 8.3 (or
# removed). None is left: the last one, the 0x80 body, is 8.3 #14 above.


# Documented analyser behaviour (not a tshark bug): the record is decoded differently on purpose.

def _header_bytes(p: PdRecord) -> dict[str, list[object]]:
    """The record's first four bytes as the header fields tshark reads there (protocol.md 3.1/3.3)."""
    names = ("pd.ref", "pd.resp_id" if p.stub.response else "pd.req_id", "pd.do", "pd.n_params")
    return {name: [byte] for name, byte in zip(names, p.data, strict=False)}


@pd_rule("0x002F record not plausible: decoded by tshark only",
         "protocol.md 1.4 (0x002F is PROFIdrive only if the header is plausible, else 'not PROFIdrive' I) and "
         "8.4 (tshark decodes 0x002F under any API; 8.3 #13 nothing range-checked): the analyser has no "
         "PROFIdrive fields; tshark's header fields must be the record's first four bytes", registry=PD_DOCUMENTED)
def implausible_dpv1(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    if p is None or p.parsed is not None or p.block.index != INDEX_PD_DPV1 \
            or "not_profidrive" not in c.an[n].findings:
        return None
    header = _header_bytes(p)

    def view(name: str, side: str, items: Items) -> Items | None:
        if side == "ours":
            return [] if not items else None
        return [] if name not in header or [v for _, v in items] == header[name] else None
    return view


@pd_rule("AKD address echo: the analyser decodes after the echo",
         "protocol.md 5.3 (a response that parses only with the 6-byte address echo is decoded after it, "
         "W akd_address_echo); tshark reads Format at byte 4 as the profile says: its first block is the "
         "echo's bytes 4/5, nothing after is compared", registry=PD_DOCUMENTED)
def akd_echo(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    if p is None or p.parsed is None or not p.parsed.echo:
        return None
    echo = {"pd.val[i].format": p.data[4], "pd.val[i].n_values": p.data[5]}

    def view(name: str, side: str, items: Items) -> Items | None:
        if side == "theirs" and name in echo and [v for b, v in items if b == 0][:1] != [echo[name]]:
            return None
        return _header_only(name, side, items)
    return view


@pd_rule("whole request refused with No. of parameters 0: the analyser decodes the one error block",
         "protocol.md 3.3 (a header-level error: one error block for the whole request while No. of parameters "
         "mirrors the request, here 0); tshark reads No. of parameters blocks, none: compare the header only",
         registry=PD_DOCUMENTED)
def no_parameter_refused(c: tf.Conformance, n: int, record: int) -> View | None:
    p = _pd_record(c, n, record)
    if p is None or p.parsed is None or not p.stub.response or p.parsed.n != 0 or len(p.blocks) != 1 \
            or not p.blocks[0].is_error:
        return None

    def view(name: str, side: str, items: Items) -> Items | None:
        if side == "theirs" and any(b >= 0 for b, _ in items):
            return None  # tshark decoded the block after all: not this behaviour
        return _header_only(name, side, items)
    return view


# Analyser gaps (tshark is right, the analyser shows the bytes raw) go to PD_GAPS, deleted with their fix.
# None is left: a record shorter than its header and a block overrunning the record are decoded as far as
# the bytes go (protocol.md 1.3; profidrive_view._fields_present, _cut_block).


def _view_of(rules: list[tuple[NamedRule, View]]) -> View:
    def view(name: str, side: str, items: Items) -> Items | None:
        out: Items | None = items
        for _rule, v in rules:
            if out is None:
                return None
            out = v(name, side, out)
        return out
    return view


def _accepts(c: tf.Conformance, m: tf.Mismatch, view: View) -> bool:
    assert m.record is not None
    ob, tb = c.pd_blocks(m.frame, m.field, m.record)
    if len(ob) != len(m.analyser) or len(tb) != len(m.tshark):
        return False
    ours = view(m.field, "ours", list(zip(ob, m.analyser, strict=True)))
    theirs = view(m.field, "theirs", list(zip(tb, m.tshark, strict=True)))
    return ours is not None and theirs is not None and tf.compare_lists(
        m.field, [v for _, v in ours], [v for _, v in theirs])


def pd_views(c: tf.Conformance, m: tf.Mismatch) -> list[tuple[NamedRule, View]]:
    """The pd rules that apply to the mismatch's record, with their views, in rule order."""
    if m.record is None:
        return []
    out = []
    for r in PD_RULES + PD_UNLISTED + PD_DOCUMENTED + PD_GAPS:
        assert r.view is not None
        v = r.view(c, m.frame, m.record)
        if v is not None:
            out.append((r, v))
    return out


def explain_pd(c: tf.Conformance, m: tf.Mismatch) -> tuple[NamedRule, View] | None:
    """The pd rule (or the 8.3 rules together) whose view makes the record's values equal."""
    views = pd_views(c, m)
    for r, v in views:
        if _accepts(c, m, v):
            return r, v
    listed = [(r, v) for r, v in views if r in PD_RULES]
    if len(listed) > 1 and _accepts(c, m, _view_of(listed)):
        combined = NamedRule(" + ".join(r.name for r, _ in listed), "; ".join(r.ref for r, _ in listed), None)
        return combined, _view_of(listed)
    return None


ALL_RULES = RULES + PD_RULES + PD_UNLISTED + PD_DOCUMENTED + PD_GAPS + ANALYSER_GAPS


def _checks(rules: list[NamedRule], c: tf.Conformance, m: tf.Mismatch) -> NamedRule | None:
    for r in rules:
        if r.check is None or (r.fields is not None and m.field not in r.fields):
            continue
        if r.check(c, m.frame, m.field, m.analyser, m.tshark):
            return r
    return None


def explain(c: tf.Conformance, m: tf.Mismatch) -> NamedRule | None:
    """The rule that accepts this exact difference, if any: the field rules, then for pd.* the
    record views (8.3), then the analyser gaps."""
    found = _checks(RULES, c, m)
    if found is None and m.record is not None:
        pd = explain_pd(c, m)
        found = pd[0] if pd is not None else None
    return found or _checks(ANALYSER_GAPS, c, m)


def unexplained(c: tf.Conformance, used: Counter | None = None) -> list[tf.Mismatch]:
    out = []
    for number in sorted(set(c.an) & set(c.ts)):
        for m in c.mismatches(number):
            r = explain(c, m)
            if r is None:
                out.append(m)
            elif used is not None:
                used[r.name] += 1
    return out


# Frames tshark and the analyser may legitimately disagree on as PNIO RPC. A frame-set rule is
# called with the frame number and which side alone has it ("ours"/"theirs").
FrameRule = Callable[[tf.Conformance, int, str], bool]
FRAME_SET_RULES: list[tuple[str, str, FrameRule]] = []


def frame_rule(name: str, ref: str) -> Callable[[FrameRule], FrameRule]:
    def register(fn: FrameRule) -> FrameRule:
        FRAME_SET_RULES.append((name, ref, fn))
        return fn
    return register


@frame_rule("server PDU of a PNIO call with another interface UUID",
            "protocol.md 1.4 item 4 (a response/fault/reject/working/nocall is PNIO when it pairs with a PNIO "
            "request, whatever its interface UUID); tshark 4.0 links no fault/reject/working/nocall to its call "
            "(8.4 RPC pairing), so nothing ties such a PDU to PNIO there")
def server_pdu_other_interface(c: tf.Conformance, n: int, side: str) -> bool:
    if side != "ours" or n not in c.ts or c.ts[n].first("rpc", "dcerpc.ver") != "4":
        return False
    frame = c.an[n]
    return (frame.ptype in (PTYPE_FAULT, PTYPE_WORKING, PTYPE_NOCALL, PTYPE_REJECT)
            and c.ts[n].first("rpc", "dcerpc.dg_if_id") not in tf.PNIO_INTERFACES
            and any(_is_request(c, m) and _same_call(c, n, m) and m < n for m in c.an))


def frame_set_differences(c: tf.Conformance, used: Counter | None = None) -> list[tuple[int, str]]:
    """Frames only one side reports as PNIO RPC and no frame-set rule explains."""
    ours, theirs = set(c.an), c.tshark_pnio_frames()
    out = []
    for n, side in sorted([(n, "ours") for n in ours - theirs] + [(n, "theirs") for n in theirs - ours]):
        name = next((name for name, _, fn in FRAME_SET_RULES if fn(c, n, side)), None)
        if name is None:
            out.append((n, side))
        elif used is not None:
            used[name] += 1
    return out


# --- the tests ---------------------------------------------------------------------------------

RULE_USE: Counter = Counter()


@pytest.mark.parametrize("path", CAPTURES, ids=_id)
def test_frame_set(tshark: None, conformance_cache: dict[str, tf.Conformance], path: Path) -> None:
    """The analyser reports exactly the frames tshark decodes as PNIO CL-RPC (protocol.md 1.4)."""
    c = conformance(path, conformance_cache)
    bad = frame_set_differences(c, RULE_USE)
    only_ours = [n for n, side in bad if side == "ours"]
    only_theirs = [n for n, side in bad if side == "theirs"]
    assert not bad, (f"{path.name}: PNIO RPC frames reported only by the analyser {only_ours[:20]}, "
                     f"only by tshark {only_theirs[:20]}")


@pytest.mark.parametrize("path", CAPTURES, ids=_id)
def test_fields(tshark: None, conformance_cache: dict[str, tf.Conformance], path: Path) -> None:
    """Every mapped field equals tshark's, frame by frame, except where a named rule explains it."""
    c = conformance(path, conformance_cache)
    bad = unexplained(c, RULE_USE)
    assert not bad, f"{path.name}: {len(bad)} field differences from tshark 4.0:\n" + "\n".join(
        str(m) for m in bad[:40])


def test_captures_present() -> None:
    """Something to compare: sample_pcaps/ is in the repository; ../shared/captures may be absent."""
    if not CAPTURES:
        unavailable(f"no captures in {SAMPLES} or {SHARED}")
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} absent: the shared real-world captures are not compared")


# --- self-tests: the comparison can fail ---------------------------------------------------------

def test_compare_catches_wrong_value() -> None:
    """compare_frame reports a single deliberately wrong value, a missing and an extra occurrence."""
    names = ["iod.index", "ndr.args_len", "frame.ts", "rpc.rtt"]
    theirs = {"iod.index": [0xE040, 0xB02E], "ndr.args_len": [80], "frame.ts": [1767225600.0000021],
              "rpc.rtt": [0.0015]}
    good = copy.deepcopy(theirs)
    assert list(tf.compare_frame(1, good, theirs, names)) == []
    for name, wrong in (("iod.index", [0xE040, 0xB02F]), ("iod.index", [0xE040]),
                        ("ndr.args_len", [80, 80]), ("frame.ts", [1767225600.000003]),
                        ("rpc.rtt", [0.0025])):
        ours = dict(good, **{name: wrong})
        found = list(tf.compare_frame(1, ours, theirs, names))
        assert [m.field for m in found] == [name], (name, wrong)


def test_parse_tshark_numbers() -> None:
    assert tf.parse_int("0x00003a00") == 0x3A00
    assert tf.parse_int("181") == 181
    assert tf.parse_int("0xb02e") == 0xB02E
    assert tf.parse_abs_time("Jan  1, 1970 00:00:02.000000000 UTC") == 2
    assert tf.parse_abs_time("Aug  2, 2013 15:54:25.402778000 UTC") == 1375458865


def test_skip_or_fail_without_tshark(monkeypatch: pytest.MonkeyPatch) -> None:
    """No tshark: skip on a developer's machine, fail when CI is set."""
    monkeypatch.setattr(tf, "TSHARK", None)
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="tshark not installed: apt-get install tshark"):
        require_tshark()
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="tshark not installed"):
        require_tshark()


def _first_capture_with(pred: Callable[[tf.Conformance, int], bool],
                        cache: dict[str, tf.Conformance]) -> tuple[tf.Conformance, int]:
    for path in CAPTURES:
        c = conformance(path, cache)
        for n in sorted(set(c.an) & set(c.ts)):
            if pred(c, n):
                return c, n
    pytest.skip("no capture with a suitable frame")


def test_wrong_analyser_value_is_caught(tshark: None, conformance_cache: dict[str, tf.Conformance]) -> None:
    """A deliberately wrong analyser value in a real capture is reported, also for fields that have
    exception rules (a wrong request frame is not excused by the pairing rules)."""
    c, n = _first_capture_with(lambda c, n: bool(c.ours(n, "iod.index")) and bool(c.ours(n, "rpc.request_frame"))
                               and not c.mismatches(n), conformance_cache)
    for name, bump in (("iod.index", 1), ("ndr.args_len", 1), ("rpc.request_frame", -1), ("rpc.seq", 1)):
        broken = copy.copy(c)
        broken.an = dict(c.an)
        frame = c.an[n]
        values = dict(frame.values)
        values[name] = [values[name][0] + bump, *values[name][1:]]
        broken.an[n] = tf.AnFrame(n, frame.result, values, frame.where)
        bad = [m for m in unexplained(broken) if m.frame == n]
        assert [m.field for m in bad] == [name], (c.path, n, name, bad)


def _wrong(value: object) -> object:
    """A value that differs from `value` beyond every tolerance."""
    if isinstance(value, tf.PdValue):
        return tf.PdValue(value.kind, value.value + 1 + abs(value.value))
    if isinstance(value, str):
        return value + "?"
    assert isinstance(value, int | float), value
    return value + 1


PD_SELF_TEST = ("pd.ref", "pd.req_id", "pd.resp_id", "pd.do", "pd.n_params", "pd.addr[i].attr", "pd.addr[i].n_elems",
                "pd.addr[i].pnu", "pd.addr[i].subindex", "pd.val[i].format", "pd.val[i].n_values", tf.PD_VALUES,
                tf.PD_STRING, "pd.val[i].error", "pd.val[i].error_subindex")


@pytest.mark.parametrize("name", PD_SELF_TEST)
def test_wrong_pd_value_is_caught(tshark: None, conformance_cache: dict[str, tf.Conformance],
                                  synthetic: tuple[tf.Conformance, dict[int, str]], name: str) -> None:
    """A deliberately wrong PROFIdrive value (each mapped field in turn, the last value of the frame)
    is reported, on a frame that otherwise agrees with tshark (for a VisibleString only the synthetic
    capture has one: tshark 4.0 reads m strings, 8.3 #1)."""
    sources = [conformance(path, conformance_cache) for path in CAPTURES] + [synthetic[0]]
    c, n = next(((c, n) for c in sources for n in sorted(set(c.an) & set(c.ts))
                 if c.ours(n, name) and not c.mismatches(n)), (None, 0))
    assert c is not None, f"no frame with {name} that agrees with tshark"
    broken = copy.copy(c)
    broken.an = dict(c.an)
    frame = c.an[n]
    values = dict(frame.values)
    values[name] = [*values[name][:-1], _wrong(values[name][-1])]
    broken.an[n] = tf.AnFrame(n, frame.result, values, frame.where)
    bad = [m for m in unexplained(broken) if m.frame == n]
    assert [m.field for m in bad] == [name], (c.path, n, name, bad)


def test_rules_are_named_and_cited() -> None:
    for name, ref in [(r.name, r.ref) for r in ALL_RULES] + [(name, ref) for name, ref, _ in FRAME_SET_RULES]:
        assert name and "protocol.md" in ref, name


def test_rules_check_exact_values(tshark: None, conformance_cache: dict[str, tf.Conformance]) -> None:
    """A difference a rule accepts is no longer accepted once the analyser's value is wrong in
    another way: the rules pin both sides' values, they do not skip fields. (Checked where there is
    a value to pin: links and times, and fields tshark does give; a rule for a stub tshark leaves
    undecoded has nothing to compare with.)"""
    tried = 0
    for path in CAPTURES:
        c = conformance(path, conformance_cache)
        for n in sorted(set(c.an) & set(c.ts)):
            for m in c.mismatches(n):
                pinned = m.field in LINK_FIELDS or (m.field.startswith("iod.") and m.tshark)
                if not pinned or not m.analyser or explain(c, m) is None:
                    continue
                bump = 0.001 if m.field == "rpc.rtt" else 1
                wrong = [m.analyser[0] + bump, *m.analyser[1:]]
                assert explain(c, tf.Mismatch(n, m.field, wrong, m.tshark)) is None, (path.name, m, wrong)
                tried += 1
    if not tried:
        pytest.skip("no accepted difference on request_frame/rtt/rw_pad in these captures")


def _pinned_pd(c: tf.Conformance, m: tf.Mismatch) -> list[int]:
    """Positions of the analyser values that the pd view accepting `m` compares."""
    if m.record is None or _checks(RULES, c, m) is not None:
        return []
    found = explain_pd(c, m)
    if found is None:
        return []
    ob, _ = c.pd_blocks(m.frame, m.field, m.record)
    kept = found[1](m.field, "ours", [(b, i) for i, b in enumerate(ob)]) or []
    return [i for _, i in kept if type(i) is int]


def test_pd_views_compare_exact_values(tshark: None, conformance_cache: dict[str, tf.Conformance],
                                      synthetic: tuple[tf.Conformance, dict[int, str]]) -> None:
    """Where a protocol.md 8.3 view accepts a PROFIdrive difference, every analyser value the view
    keeps is still compared exactly: made wrong, the difference is no longer accepted."""
    tried = Counter()
    for c in [conformance(path, conformance_cache) for path in CAPTURES] + [synthetic[0]]:
        path = Path(c.path)
        for n in sorted(set(c.an) & set(c.ts)):
            for m in c.mismatches(n):
                for i in _pinned_pd(c, m):
                    wrong = list(m.analyser)
                    wrong[i] = _wrong(wrong[i])
                    assert explain(c, tf.Mismatch(n, m.field, wrong, m.tshark, m.record)) is None, \
                        (path.name, m, i, wrong)
                    tried[m.field] += 1
    if not tried:
        pytest.skip("no accepted PROFIdrive difference with compared values in these captures")


def _synthetic_bugs() -> tuple[bytes, dict[int, str]]:
    """A capture with the 8.3 bugs the sample captures do not show (#4, #6, #7, #11), built with
    devtools.synth, and the frame each rule must explain."""
    from devtools.synth.fixtures import pcap_of, session
    from devtools.synth.pd_encode import ParamAddress as P
    from devtools.synth.pd_encode import change_request, error_block, pd_response, read_request, value_block
    from devtools.synth.sim_capture import Capture

    cap = Capture()
    s = session(cap, 1)
    word = value_block(0x06, [7])
    two = [P(1), P(2)]
    expect = {}

    def access(request: bytes, response: bytes, rule: str, **kw: object) -> None:
        calls = s.parameter_access(request, response, **kw)
        expect[cap.number(calls[-1].response[-1])] = rule

    access(read_request(1, 1, two), pd_response(1, 0x81, 1, [error_block(0x05, 3), word]), "8.3 #11")
    access(change_request(2, 1, [(P(1), word), (P(2), word)]),
           pd_response(2, 0x82, 1, [error_block(0x14, 1), error_block(0x11, 2)]), "8.3 #11")
    access(read_request(3, 1, two), pd_response(3, 0x81, 1, [error_block(0x23), word]), "8.3 #6")
    access(read_request(4, 1, two), pd_response(4, 0x81, 1, [b"\x44\x00", word]), "8.3 #4")
    beyond = pd_response(5, 0x01, 1, [word, word])  # the second block lies after RecordDataLength
    access(read_request(5, 1, two), beyond, "8.3 #7", read_kw={"res_iod": {"record_len": len(beyond) - 4}})
    # no bug (rule ""): records cut short (RecordDataLength more than present) end with their PDU, and both
    # decode the bytes present (protocol.md 1.3): a whole response, a request cut inside its second address,
    # a response cut inside a value
    def cut(request: bytes, response: bytes, **kw: object) -> None:
        calls = s.parameter_access(request, response, **kw)
        expect[cap.number(calls[0].request[-1])] = expect[cap.number(calls[-1].response[-1])] = ""

    short = pd_response(6, 0x01, 1, [word])
    cut(read_request(6, 1, [P(1)]), short, read_kw={"res_iod": {"record_len": len(short) + 4}})
    cut(read_request(8, 1, two)[:13], pd_response(8, 0x01, 1, [word, word]), write_kw={"req_iod": {"record_len": 16}})
    long = pd_response(9, 0x01, 1, [value_block(0x07, [1, 2, 3])])[:-2]
    cut(read_request(9, 1, [P(2000, n_elems=3)]), long, read_kw={"res_iod": {"record_len": 18}})
    # no bug: a one-character VisibleString + pad reads right (the self-test's value_str)
    s.parameter_access(read_request(7, 1, [P(975)]), pd_response(7, 0x01, 1, [value_block(0x09, "A")]))
    return pcap_of(cap), expect


@pytest.fixture(scope="session")
def synthetic(tshark: None, tmp_path_factory: pytest.TempPathFactory) -> tuple[tf.Conformance, dict[int, str]]:
    """Both decodes of the synthetic capture and the rule expected per frame."""
    data, expect = _synthetic_bugs()
    path = tmp_path_factory.mktemp("pd") / "pd_tshark_bugs.pcap"
    path.write_bytes(data)
    key = str(path)
    return tf.Conformance(key, tf.analyser_frames(key), tf.tshark_frames(key), tf.compared_fields(LAYERS)), expect


def test_pd_rules_on_synthetic_bugs(synthetic: tuple[tf.Conformance, dict[int, str]]) -> None:
    """The 8.3 rules no sample capture exercises, on records that show those tshark bugs: each
    difference is accepted by the expected rule, and nothing else differs."""
    c, expect = synthetic
    assert not frame_set_differences(c)
    seen: dict[int, set[str]] = {}
    for n in sorted(set(c.an) & set(c.ts)):
        for m in c.mismatches(n):
            r = explain(c, m)
            assert r is not None, str(m)
            seen.setdefault(n, set()).add(r.name)
    assert set(seen) == {n for n, rule in expect.items() if rule}, (seen, expect)
    for n, names in seen.items():
        assert all(name.startswith(expect[n] + " ") for name in names), (n, names, expect[n])
    # the records cut short: decoded by both, every field compared, none differs
    cut = sorted(n for n, rule in expect.items() if not rule)
    assert [c.an[n].values.get("pd.addr[i].pnu") for n in cut[::2]] == [[1], [1], [2000]]
    assert [len(c.an[n].values.get("pd.val[i].value[j]", [])) for n in cut[1::2]] == [1, 2, 2]
    assert [c.an[n].values.get("pd.cut") for n in cut] == [None, None, ["00"], None, None, ["0000"]]

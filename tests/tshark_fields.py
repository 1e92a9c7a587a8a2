"""tshark side of the conformance test (protocol.md section 8): run tshark, read its PDML, normalise.

tshark is run once per capture with two passes (`-2`, so forward links such as `dcerpc.response_in`
and `dcerpc.reassembled_in` are filled in) and PDML output, which keeps the protocol tree: the
tree is what tells the IOD header blocks (the analyser's `iod.*`) from blocks that tshark decodes
inside records and Connect bodies, which the analyser shows as raw bytes (protocol.md 1.1).

Every tshark field occurrence is given a *scope*, and an analyser field is compared with the
occurrences of its registry `tshark` name in the scope of its layer (its name's first part):

| analyser prefix | scope | where in the tshark tree |
|---|---|---|
| frame, eth, vlan, ip, udp | same name | the protocol of that name |
| rpc | rpc | the `dcerpc` protocol |
| ndr | ndr | a PNIO protocol, outside every `pn_io.block` (args, array, NDR PNIOStatus) |
| iod | iod | directly inside an IOD header block (BlockType 0x0008/0x8008/0x0009/0x8009) |
| pd | pd | `pn_io.profidrive.*` fields, anywhere in a PNIO protocol (tshark nests them in untyped `pn_io.block`s) |

Values are normalised to the analyser's value types (`normalise_ts`, `normalise_analyser`), so the
comparison itself is a plain equality except for the time fields, which get a tolerance
(`values_equal`).
"""

from __future__ import annotations

import atexit
import calendar
import functools
import math
import os
import re
import shutil
import struct
import subprocess
import tempfile
import time
import xml.etree.ElementTree as ET
from collections import defaultdict
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import NamedTuple

from pd_analyze.capture import CaptureError
from pd_analyze.model import fields as registry
from pd_analyze.protocol.dissector import Dissector, dissect
from pd_analyze.protocol.frames import FrameResult

TSHARK = shutil.which("tshark")
INSTALL_HINT = "tshark not installed: apt-get install tshark"

# PNIO interface UUIDs (protocol.md 1.4): Device, Controller, Supervisor, ParameterServer.
PNIO_INTERFACES = frozenset(f"dea0000{i}-6c97-11d1-8271-00a02442df7d" for i in range(1, 5))
IOD_HEADER_TYPES = frozenset({0x0008, 0x8008, 0x0009, 0x8009})  # protocol.md 2.6
# Offset of the 2-byte Padding (iod.pad) inside an IOD header block; every other pn.padding in the
# block is the RWPadding (iod.rw_pad) (protocol.md 2.6).
IOD_PAD_OFFSET = 32

# Layer prefix of an analyser field name -> tshark scope (see the module docstring).
SCOPE_OF_PREFIX = {"frame": "frame", "eth": "eth", "vlan": "vlan", "ip": "ip", "udp": "udp",
                   "rpc": "rpc", "ndr": "ndr", "iod": "iod", "pd": "pd"}
_PROTO_SCOPES = {"frame": "frame", "eth": "eth", "vlan": "vlan", "ieee8021ad": "vlan", "ip": "ip", "udp": "udp",
                 "dcerpc": "rpc"}
# eth.vlan_ids <-> vlan.id (protocol.md 8.2). tshark 4.0 decodes an 802.1ad S-tag (TPID 0x88A8) as
# protocol `ieee8021ad` with the ID in `ieee8021ad.id`, not `vlan.id`; both are tags of the list.
VLAN_ID_FIELDS = ("vlan.id", "ieee8021ad.id")

# tshark fields whose value is not comparable; their byte length is compared instead (protocol.md
# 8.2: "pn.padding — length text only; pad values not comparable").
LENGTH_ONLY = frozenset({"pn.padding"})

# Tolerances (protocol.md 8.1 / brief): a float64 holds an epoch time to ~2.4e-7 s, so two
# correctly rounded readings of the same timestamp differ by at most ~2 ULP; 5e-16 relative is
# ~0.7 us at today's epoch and still catches a 1 us error. An RTT is the difference of two such
# readings (analyser rounds it to 9 digits).
TS_REL_TOL = 5e-16
TS_ABS_TOL = 1e-9
RTT_ABS_TOL = 5e-7
FLOAT_REL_TOL = 1e-6  # value_float is rounded text (protocol.md 8.1)


# --- tshark -------------------------------------------------------------------------------------

def tshark_version() -> str:
    if TSHARK is None:
        return ""
    out = subprocess.run([TSHARK, "-v"], capture_output=True, text=True, check=False).stdout
    return out.splitlines()[0] if out else ""


@functools.cache
def _config_dir() -> str:
    """An empty Wireshark profile, so a developer's preferences cannot change the decode."""
    path = tempfile.mkdtemp(prefix="pd-analyze-tshark-")
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


@functools.lru_cache(maxsize=64)
def tshark_frames(path: str) -> dict[int, TsFrame]:
    """Every DCE/RPC frame of a capture as tshark 4.0 decodes it, by frame number (cached)."""
    if TSHARK is None:
        raise RuntimeError(INSTALL_HINT)
    env = dict(os.environ, WIRESHARK_CONFIG_DIR=_config_dir(), LC_ALL="C", TZ="UTC")
    cmd = [TSHARK, "-n", "-2", "-r", path, "-Y", "dcerpc", "-T", "pdml",
           "-o", "dcerpc.desegment_dcerpc:TRUE", "-o", "dcerpc.reassemble_dcerpc:TRUE"]
    proc = subprocess.run(cmd, capture_output=True, env=env, check=False)
    # A damaged or foreign file: tshark says so and exits 2, after the frames it could read (none
    # for a foreign file); the analyser stops at the same place with a CaptureError.
    return parse_pdml(proc.stdout)


def prefetch(paths: Iterable[str]) -> None:
    """Run tshark on several captures at once (tshark's start-up dominates its run time)."""
    todo = list(paths)
    if TSHARK is None or len(todo) < 2:
        return
    with ThreadPoolExecutor(max_workers=max(2, min(8, os.cpu_count() or 2))) as pool:
        list(pool.map(tshark_frames, todo))


# --- PDML ---------------------------------------------------------------------------------------

@dataclass(slots=True)
class TsField:
    name: str
    show: str
    value: str  # raw bytes as hex, as tshark gives them
    pos: int
    size: int
    scope: str
    block_pos: int = -1  # start of the enclosing IOD header block (scope iod)
    pd_record: int = -1  # scope pd: ordinal of the IOD header block (in the frame) whose record holds it
    pd_block: int = -1  # scope pd: value/error block of the record (-1: header and addresses)


@dataclass(slots=True)
class TsFrame:
    number: int
    protos: list[str] = field(default_factory=list)
    fields: list[TsField] = field(default_factory=list)
    truncated: bool = False  # "Packet size limited during capture"
    _index: dict[tuple[str, str], list[TsField]] = field(default_factory=dict)

    def values(self, scope: str, name: str) -> list[TsField]:
        if not self._index and self.fields:
            for f in self.fields:
                self._index.setdefault((f.scope, f.name), []).append(f)
        return self._index.get((scope, name), [])

    def first(self, scope: str, name: str) -> str | None:
        found = self.values(scope, name)
        return found[0].show if found else None


def parse_pdml(data: bytes) -> dict[int, TsFrame]:
    frames: dict[int, TsFrame] = {}
    if not data.strip():
        return frames
    try:
        for _event, elem in ET.iterparse(_BytesReader(data), events=("end",)):
            if elem.tag != "packet":
                continue
            frame = _packet(elem)
            frames[frame.number] = frame
            elem.clear()
    except ET.ParseError:
        pass  # output cut off (tshark killed, or crashed): the complete packets before it stand
    return frames


class _BytesReader:
    def __init__(self, data: bytes) -> None:
        self._data = memoryview(data)
        self._pos = 0

    def read(self, size: int = -1) -> bytes:
        end = len(self._data) if size < 0 else self._pos + size
        out = bytes(self._data[self._pos:end])
        self._pos += len(out)
        return out


def _int_attr(elem: ET.Element, name: str) -> int:
    text = elem.get(name)
    return int(text) if text else 0


def _packet(elem: ET.Element) -> TsFrame:
    frame = TsFrame(0)
    position = _PdPosition()
    for proto in elem.findall("proto"):
        name = proto.get("name", "")
        frame.protos.append(name)
        if name == "_ws.short":
            frame.truncated = True
        if name in _PROTO_SCOPES:
            scope = _PROTO_SCOPES[name]
            for f in proto.iter("field"):
                if f.get("name"):
                    frame.fields.append(_field(f, scope))
            if name == "frame":
                frame.number = next(int(f.show) for f in frame.fields if f.name == "frame.number")
        elif name.startswith("pn_io"):
            _pnio(proto, frame.fields, "ndr", -1, position)
    return frame


def _field(elem: ET.Element, scope: str, block_pos: int = -1) -> TsField:
    return TsField(elem.get("name", ""), elem.get("show", ""), elem.get("value", ""),
                   _int_attr(elem, "pos"), _int_attr(elem, "size"), scope, block_pos)


def _block_type(block: ET.Element) -> int | None:
    """The BlockType in the block's own BlockHeader (PROFIdrive items are untyped pn_io.blocks)."""
    for header in block.findall("field[@name='pn_io.block_header']"):
        for f in header.findall("field[@name='pn_io.block_type']"):
            return parse_int(f.get("show", ""))
    return None


@dataclass(slots=True)
class _PdPosition:
    """Where the PROFIdrive fields of a frame are: the IOD header whose record is being decoded
    (its ordinal in the frame, as the analyser's stub blocks) and the value block in that record
    (one more at each `format`)."""

    record: int = -1
    block: int = -1


PD_FORMAT = "pn_io.profidrive.parameter.format"


def _pnio(elem: ET.Element, out: list[TsField], scope: str, block_pos: int, at: _PdPosition) -> None:
    """Fields of a PNIO protocol subtree, each with the scope of its nearest enclosing block."""
    for child in elem:
        if child.tag != "field":
            continue
        name = child.get("name", "")
        if not name and child.get("size") == "0":
            continue  # generated summary (AR info after a Write): not on the wire
        if name == "pn_io.block":
            kind = _block_type(child)
            if kind in IOD_HEADER_TYPES:
                at.record, at.block = at.record + 1, -1
                _pnio(child, out, "iod", _int_attr(child, "pos"), at)
            else:
                _pnio(child, out, "record", -1, at)  # record content / Connect blocks (protocol.md 1.1)
            continue
        if name.startswith("pn_io.profidrive.parameter."):
            if name == PD_FORMAT:
                at.block += 1
            f = _field(child, "pd", block_pos)
            f.pd_record, f.pd_block = at.record, at.block
            out.append(f)
        elif name.startswith("pn_io.profidrive."):
            out.append(_field(child, "pd", block_pos))
        elif name:
            out.append(_field(child, scope, block_pos))
        _pnio(child, out, scope, block_pos, at)


# --- normalisation ------------------------------------------------------------------------------

def parse_int(text: str) -> int:
    """tshark integers: `0x…` hex, otherwise decimal (protocol.md 8.1); booleans as 0/1."""
    text = text.strip()
    if text.lower() in ("true", "false"):
        return int(text.lower() == "true")
    return int(text, 16) if text.lower().startswith("0x") else int(text)


def parse_abs_time(text: str) -> int:
    """`Jan  1, 1970 00:00:02.000000000 UTC` (tshark's FT_ABSOLUTE_TIME) to whole seconds."""
    stamp = " ".join(text.replace(" UTC", "").split())
    head = stamp.split(".")[0]
    return calendar.timegm(time.strptime(head, "%b %d, %Y %H:%M:%S"))


def normalise_ts(name: str, f: TsField) -> object:
    """One tshark occurrence as the analyser value of the field `name` (a registry name)."""
    if f.name in LENGTH_ONLY:
        return f.size
    if f.name in PD_VALUE_KIND:
        return _pd_ts_value(f)
    kind = registry.field(name).type
    if kind in (registry.UINT, registry.HEX, registry.INT, registry.FLAGS, registry.FRAMEREF, registry.LIST):
        if f.name == "dcerpc.dg_server_boot":
            return parse_abs_time(f.show)
        return parse_int(f.show)
    if kind in (registry.FLOAT, registry.TIME):
        return float(f.show)
    if kind == registry.UUID:
        return f.show.lower()
    if kind == registry.BYTES:
        return f.show.replace(":", "").lower()
    return f.show


def normalise_analyser(name: str, value: object, length: int) -> object:
    tshark = registry.field(name).tshark
    if tshark in LENGTH_ONLY:
        return length
    if isinstance(value, bytes | bytearray):
        return bytes(value).hex()
    if isinstance(value, str) and registry.field(name).type == registry.UUID:
        return value.lower()
    return value


def values_equal(name: str, a: object, b: object) -> bool:
    if isinstance(a, PdValue) and isinstance(b, PdValue) and a.kind == b.kind == "value_float":
        x, y = float(a.value), float(b.value)
        return (math.isnan(x) and math.isnan(y)) or math.isclose(x, y, rel_tol=FLOAT_REL_TOL)
    if name == "frame.ts":
        return isinstance(a, float) and isinstance(b, float) and math.isclose(
            a, b, rel_tol=TS_REL_TOL, abs_tol=TS_ABS_TOL)
    if name == "rpc.rtt":
        return isinstance(a, float) and isinstance(b, float) and abs(a - b) <= RTT_ABS_TOL
    return a == b


# --- PROFIdrive values (protocol.md 8.1, 8.2) ---------------------------------------------------
#
# tshark has one value field per size class; the analyser has one value field per value
# (`pd.val[i].value[j]`), one per string (`pd.val[i].string`) and the elements of a complete
# description (`pd.val[i].desc.*`, attribute 0x20 subindex 0: OctetString x 46). Both sides become
# PdValue(kind, raw unsigned value) items in wire order: `pd.val[i].value[j]` is compared with the
# value_b/value_w/value_dw/value_float occurrences, `pd.val[i].string` with value_str. The analyser
# item is made from the field's raw bytes and its block's Format (8.1: "compare the analyser's raw
# value, not its signed/scaled presentation"); formats tshark has no field for give no item (8.2,
# 8.3 #2). A one-byte OctetString (0x0A) is a 1-byte format: one value_b per octet.

_PD = "pn_io.profidrive.parameter"
VALUE_FIELD_OF_FORMAT = {
    **dict.fromkeys((0x01, 0x02, 0x05, 0x0A, 0x41), "value_b"),
    **dict.fromkeys((0x03, 0x06, 0x42, 0x73), "value_w"),
    **dict.fromkeys((0x04, 0x07, 0x43), "value_dw"),
    0x08: "value_float", 0x09: "value_str"}
FMT_ERROR = 0x44  # its third and later words (analyser pd.val[i].value[k]) are words: value_w
PD_VALUE_KIND = {f"{_PD}.{kind}": kind for kind in ("value_b", "value_w", "value_dw", "value_float", "value_str")}
VALUE_SIZE = {"value_b": 1, "value_w": 2, "value_dw": 4, "value_float": 4}
PD_VALUES, PD_STRING = "pd.val[i].value[j]", "pd.val[i].string"
_PD_VALUE_SOURCES = (PD_VALUES, PD_STRING)
_PD_DESC = "pd.val[i].desc."


class PdValue(NamedTuple):
    """One PROFIdrive value as tshark's field `kind` holds it: the unsigned raw value (a float for
    value_float)."""

    kind: str
    value: int | float

    def __repr__(self) -> str:
        if isinstance(self.value, int):
            return f"{self.kind}={self.value:#x}"
        return f"{self.kind}={self.value!r}"


def pd_values(fmt: object, raw: bytes) -> list[tuple[str, object]]:
    """(registry name, item) of the analyser value bytes `raw` of a block of Format `fmt`."""
    kind = "value_w" if fmt == FMT_ERROR else VALUE_FIELD_OF_FORMAT.get(fmt) if isinstance(fmt, int) else None
    if kind is None:
        return []
    if kind == "value_str":
        return [(PD_STRING, raw.decode("latin-1"))]
    size = VALUE_SIZE[kind]
    out: list[tuple[str, object]] = []
    for k in range(0, len(raw) - size + 1, size):
        chunk = raw[k:k + size]
        value = struct.unpack(">f", chunk)[0] if kind == "value_float" else int.from_bytes(chunk, "big")
        out.append((PD_VALUES, PdValue(kind, value)))
    return out


def _pd_ts_value(f: TsField) -> object:
    """A tshark value_* occurrence: numbers from the shown value (hex or float text), the string
    from its bytes (tshark escapes non-printable characters in `show`)."""
    kind = PD_VALUE_KIND[f.name]
    if kind == "value_str":
        return bytes.fromhex(f.value).decode("latin-1")
    return PdValue(kind, float(f.show) if kind == "value_float" else parse_int(f.show))


_BLOCK_INDEX = re.compile(r"^pd\.val\[(\d+)\]")


def pd_block(name: str) -> int:
    """The value block of a concrete analyser field name (pd.val[3].format -> 3); -1 otherwise."""
    m = _BLOCK_INDEX.match(name)
    return int(m.group(1)) if m else -1


# --- the analyser side --------------------------------------------------------------------------

def template(name: str) -> str:
    """The registry key of a concrete field name (pd.val[3].value[1] -> pd.val[i].value[j])."""
    fn = getattr(registry, "template", None)
    return fn(name) if fn is not None else name


@dataclass(slots=True)
class AnFrame:
    """One analyser frame: every field's values by registry name, in emission order. For pd.*
    fields, `where` gives each value's (record, block): the ordinal of the IOD header block whose
    record holds it (as tshark's TsField.pd_record) and its value block (-1: header, addresses)."""

    number: int
    result: FrameResult
    values: dict[str, list[object]]
    where: dict[str, list[tuple[int, int]]] = field(default_factory=dict)

    def one(self, name: str) -> object:
        found = self.values.get(name)
        return found[0] if found else None

    @property
    def findings(self) -> set[str]:
        return {f.name for f in self.result.findings}

    @property
    def ptype(self) -> int:
        return self.result.ptype

    @property
    def ts(self) -> float:
        return self.result.ts

    @property
    def call_key(self) -> tuple[object, object]:
        return self.one("rpc.activity"), self.one("rpc.seq")

    @property
    def conversation(self) -> frozenset[tuple[object, object]]:
        """The UDP conversation (tshark's pairing scope): both address/port ends, unordered."""
        return frozenset({(self.one("ip.src"), self.one("udp.sport")), (self.one("ip.dst"), self.one("udp.dport"))})


def compared_fields(prefixes: Iterable[str]) -> list[str]:
    """Registry fields with a tshark counterpart in the given layers, in registry order."""
    want = tuple(p + "." for p in prefixes)
    return [n for n, d in registry.FIELDS.items() if d.tshark and n.startswith(want)]


@functools.lru_cache(maxsize=64)
def analyser_frames(path: str) -> dict[int, AnFrame]:
    """Every PNIO RPC frame the analyser reports, by frame number (cached per capture)."""
    out: dict[int, AnFrame] = {}
    try:
        for result in dissect(path, dissector=Dissector(annotate=True)):
            out[result.frame] = _an_frame(result)
    except CaptureError:
        pass  # a damaged file: the frames before the damage are complete results (as tshark's)
    return out


def _an_frame(result: FrameResult) -> AnFrame:
    """All field values of one frame by registry name. frame.no and frame.ts are FrameResult
    attributes, eth.vlan_ids is the list of the per-tag vlan.id fields (outer first)."""
    values: dict[str, list[object]] = defaultdict(list)
    where: dict[str, list[tuple[int, int]]] = defaultdict(list)
    values["frame.no"].append(result.frame)
    values["frame.ts"].append(result.ts)
    record, formats = -1, {}  # IOD header ordinal; Format of each value block of its record
    for f in result.fields():
        if f.name == "vlan.id":  # eth.vlan_ids: one entry per tag, outer first
            values["eth.vlan_ids"].append(f.value)
        if f.name == "iod.block_type":
            record, formats = record + 1, {}
        name = template(f.name)
        if name.startswith("pd."):
            block = pd_block(f.name)
            if name == "pd.val[i].format":
                formats[block] = f.value
            if name in _PD_VALUE_SOURCES or name.startswith(_PD_DESC):
                for target, item in pd_values(formats.get(block), f.raw):
                    values[target].append(item)
                    where[target].append((record, block))
                continue
            where[name].append((record, block))
        values[name].append(normalise_analyser(name, f.value, f.length))
    return AnFrame(result.frame, result, dict(values), dict(where))


def tshark_occurrences(frame: TsFrame, name: str) -> list[TsField]:
    """tshark's occurrences for the analyser field `name`, in its scope (protocol.md 8.2 mapping)."""
    fdef = registry.field(name)
    assert fdef.tshark, name
    if name == "eth.vlan_ids":
        return [f for f in frame.fields if f.scope == "vlan" and f.name in VLAN_ID_FIELDS]
    scope = SCOPE_OF_PREFIX[name.split(".")[0]]
    if "|" in fdef.tshark:  # one analyser field, several tshark fields: all of them in wire order
        names = set(fdef.tshark.split("|"))
        return [f for f in frame.fields if f.scope == scope and f.name in names]
    found = frame.values(scope, fdef.tshark)
    if fdef.tshark == "pn.padding" and name.startswith("iod."):
        # iod.pad and iod.rw_pad are both pn.padding: told apart by their offset in the block.
        pad = name == "iod.pad"
        found = [f for f in found if (f.pos - f.block_pos == IOD_PAD_OFFSET) == pad]
    return found


def tshark_values(frame: TsFrame, name: str) -> list[object]:
    return [normalise_ts(name, f) for f in tshark_occurrences(frame, name)]


# --- comparison ---------------------------------------------------------------------------------

@dataclass(slots=True)
class Mismatch:
    frame: int
    field: str
    analyser: list[object]
    tshark: list[object]
    record: int | None = None  # pd.* fields: compared per record (IOD header ordinal in the frame)

    def __str__(self) -> str:
        where = f" (record {self.record})" if self.record is not None else ""
        return f"frame {self.frame} {self.field}{where}: analyser {self.analyser!r} != tshark {self.tshark!r}"


def compare_lists(name: str, ours: list[object], theirs: list[object]) -> bool:
    return len(ours) == len(theirs) and all(values_equal(name, a, b) for a, b in zip(ours, theirs, strict=True))


def compare_frame(number: int, ours: dict[str, list[object]], theirs: dict[str, list[object]],
                  names: Iterable[str]) -> Iterator[Mismatch]:
    """Every field of `names` whose list of values differs between the two sides."""
    for name in names:
        a, b = ours.get(name, []), theirs.get(name, [])
        if not compare_lists(name, a, b):
            yield Mismatch(number, name, a, b)


@dataclass
class Conformance:
    """Both decodes of one capture, with the lookups the exception rules need."""

    path: str
    an: dict[int, AnFrame]
    ts: dict[int, TsFrame]
    names: list[str]
    _theirs: dict[int, dict[str, list[object]]] = field(default_factory=dict)

    def ours(self, number: int, name: str) -> list[object]:
        frame = self.an.get(number)
        return frame.values.get(name, []) if frame is not None else []

    def theirs(self, number: int, name: str) -> list[object]:
        frame = self.ts.get(number)
        if frame is None:
            return []
        cached = self._theirs.setdefault(number, {})
        if name not in cached:
            cached[name] = tshark_values(frame, name)
        return cached[name]

    def tshark_pnio_frames(self) -> set[int]:
        """Frames tshark decodes as PNIO CL-RPC: DCE/RPC v4 with a PNIO interface UUID, or linked
        (request/response/reassembly) to such a frame (protocol.md 1.4 item 4)."""
        direct = {n for n, f in self.ts.items()
                  if f.first("rpc", "dcerpc.ver") == "4" and f.first("rpc", "dcerpc.dg_if_id") in PNIO_INTERFACES}
        linked = set()
        for n, f in self.ts.items():
            if n in direct or f.first("rpc", "dcerpc.ver") != "4":
                continue
            refs = [parse_int(x.show) for x in f.fields if x.scope == "rpc" and x.name in LINK_FIELDS]
            if any(r in direct for r in refs):
                linked.add(n)
        return direct | linked

    def mismatches(self, number: int) -> list[Mismatch]:
        """Differences per field; pd.* fields per record (so a rule for one record's tshark bug
        leaves the others compared in full)."""
        out = []
        for name in self.names:
            if not name.startswith("pd."):
                out += compare_frame(number, self.an[number].values, {name: self.theirs(number, name)}, [name])
                continue
            for record, (ours, theirs) in sorted(self.pd_records(number, name).items()):
                if not compare_lists(name, ours, theirs):
                    out.append(Mismatch(number, name, ours, theirs, record))
        return out

    def pd_records(self, number: int, name: str) -> dict[int, tuple[list[object], list[object]]]:
        """Both sides' values of a pd.* field, split by record."""
        ours, theirs = self.ours(number, name), self.theirs(number, name)
        groups: dict[int, tuple[list[object], list[object]]] = {}
        for (record, _), value in zip(self.an[number].where.get(name, []), ours, strict=True):
            groups.setdefault(record, ([], []))[0].append(value)
        for f, value in zip(tshark_occurrences(self.ts[number], name), theirs, strict=True):
            groups.setdefault(f.pd_record, ([], []))[1].append(value)
        return groups

    def pd_blocks(self, number: int, name: str, record: int) -> tuple[list[int], list[int]]:
        """The value block of each of the record's values of `name`, analyser and tshark side
        (parallel to the lists of pd_records)."""
        ours = [b for r, b in self.an[number].where.get(name, []) if r == record]
        theirs = [f.pd_block for f in tshark_occurrences(self.ts[number], name) if f.pd_record == record]
        return ours, theirs


LINK_FIELDS = frozenset({"dcerpc.request_in", "dcerpc.response_in", "dcerpc.reassembled_in"})

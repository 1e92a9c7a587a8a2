"""The columnar decode (protocol/pnio_batch.py) against the per-frame reference, frame by frame.

Every capture of sample_pcaps/ and ../shared/captures/, and a few thousand frames mutated from them (the
fuzzer's frame mutations and targeted field values), under the generic and the vendor profiles:

- a ROUTE_SKIP frame fed alone to a fresh Dissector is skipped with that reason and earns no finding;
- a ROUTE_PNIO frame's columns are what rpc.header and pnio.parse_stub decode from its bytes, and when
  its flag is clear the frame-local rules of the reference report nothing on it;
- a ROUTE_DECIDE frame is plausible CL-RPC other than a request, on an interface that is not PNIO;
- a batch decodes as its frames one at a time (DREP byte orders and VLAN tags mixed).
"""

from __future__ import annotations

import contextlib
import random
from collections.abc import Sequence
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from devtools.fuzz import corpus, mutators
from devtools.synth.mixed_capture import make_capture
from pd_analyze import capture
from pd_analyze.capture import RawFrame
from pd_analyze.capture.batches import FrameBatch
from pd_analyze.model.layout import fields_by_order
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import (
    PROFIDRIVE_INDICES,
    PTYPE_FAULT,
    PTYPE_REJECT,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
    RECORD_SERVICES,
)
from pd_analyze.protocol import link, link_batch, pnio, pnio_batch, rpc
from pd_analyze.protocol import pnio_checks as checks
from pd_analyze.protocol.dissector import Dissector
from pd_analyze.protocol.pnio_batch import ROUTE_DECIDE, ROUTE_FRAMES, ROUTE_PNIO, ROUTE_SKIP, SKIP_REASONS
from pd_analyze.protocol.profidrive_checks import Checker
from tests.support import SHARED_CAPTURES

ROOT = Path(__file__).resolve().parents[1]
CAPTURE_DIRS = (ROOT / "sample_pcaps", SHARED_CAPTURES)
PROFILES = ("generic", "sinamics", "yaskawa", "akd")
MUTATED = 3000  # frames from the fuzzer's mutations
TARGETED = 5000  # PNIO frames with one header field set to a chosen value


def make_batch(frames: Sequence[RawFrame]) -> FrameBatch:
    """The frames as one FrameBatch over one buffer (what capture.batches will yield)."""
    lengths = np.array([len(f.data) for f in frames], np.int64)
    start = np.zeros(len(frames), np.int64)
    start[1:] = np.cumsum(lengths)[:-1]
    return FrameBatch(b"".join(f.data for f in frames), np.array([f.number for f in frames], np.int64),
                      np.array([f.ts for f in frames], np.float64), np.array([f.linktype for f in frames], np.int32),
                      start, lengths, np.array([f.iface for f in frames], np.int32),
                      np.array([round(f.ts * 1e6) * 1000 for f in frames], np.int64))


def capture_frames() -> list[RawFrame]:
    """Every frame of every capture (of a damaged one, those before the damage)."""
    out: list[RawFrame] = []
    for path in corpus.seed_paths(CAPTURE_DIRS):
        with contextlib.suppress(capture.CaptureError):  # the frames before the damage stay in `out`
            out.extend(capture.frames(path))
    return out


@cache
def all_frames() -> tuple[RawFrame, ...]:
    """The captures' frames, the fuzzer's mutations of them and targeted field values, numbered 1 ... n."""
    frames = capture_frames()
    rng = random.Random(20_260_301)
    seeds = [sf for seed in corpus.load_seeds(corpus.seed_paths(CAPTURE_DIRS)) for sf in seed.frames]
    rpc_seeds = [sf for sf in seeds if sf.rpc >= 0]
    for _ in range(MUTATED):
        sf = rng.choice(rpc_seeds if rng.random() < 0.8 else seeds)
        data = mutators.mutate_frame(rng, sf, rng.choice(seeds).raw.data)
        frames.append(sf.raw._replace(data=data))
    frames += targeted(frames, rng) + link_targeted(frames, rng)
    return tuple(f._replace(number=n) for n, f in enumerate(frames, 1))


# Offsets (in the RPC body) and sizes of the NDR and IOD fields a targeted mutation sets
_STUB_FIELDS = tuple((off, size) for off, size in zip(pnio.NDR_REQ[False].offsets, pnio.NDR_REQ[False].sizes,
                                                      strict=True)) + tuple(
    (pnio.NDR_SIZE + off, size) for layout in (pnio.WRITE_RES, pnio.READ_REQ_IMPLICIT)
    for off, size in zip(layout.offsets, layout.sizes, strict=True))
_HEADER_FIELDS = tuple(zip(rpc.HEADER_BE.offsets, rpc.HEADER_BE.sizes, strict=True))
_VALUES = (0, 1, 2, 4, 0x3A00, 0xB02E, 0xB02F, 0x002F, 0xE040, 0x8009, 0x0008, 60, 240, 0xDE80B500, 0x81)


# PNIOStatus values (ErrorCode, ErrorDecode, ErrorCode1, ErrorCode2), valid and invalid forms
_STATUSES = ("00000000", "de80b500", "de80a000", "df80b100", "df80b500", "81813c00", "de000000", "00800000",
             "de81cc00", "dfa0b000", "0000b500", "de80b600")
_AR = pnio.READ_REQ.offsets[pnio.READ_REQ.index("iod.ar_uuid")]
_WRITE_RES_STATUS = pnio.WRITE_RES.offsets[pnio.WRITE_RES.index("iod.status.code")]
_DREP = rpc.HEADER_BE.offsets[rpc.HEADER_BE.index("rpc.drep")]


def targeted(frames: Sequence[RawFrame], rng: random.Random) -> list[RawFrame]:
    """PNIO frames with one RPC header, NDR or IOD field (or a byte of a UUID or padding) set to an edge value,
    or a value with a meaning: a NIL ARUUID, a PNIOStatus, a DREP float representation."""
    batch = make_batch(frames)
    out = pnio_batch.decode(batch, Checker.for_profile())
    pdus = out.pdus
    rows = np.flatnonzero(out.frames.route[pdus.pos] == ROUTE_PNIO)
    made = []
    for _ in range(TARGETED):
        i = rng.choice(rows)
        frame = frames[int(pdus.pos[i])]
        data = bytearray(frame.data)
        body = int(pdus.body_start[i] - batch.start[pdus.pos[i]])
        little = bool(pdus.little[i])
        roll = rng.random()
        if roll < 0.05:
            made.append(frame._replace(data=_longer(frame, rng.choice((1, 2, 4, 7)))))
            continue
        if roll < 0.1:  # ArgsLength and ActualCount alike: N1 alone
            value = (int(pdus.args_len[i]) + rng.choice((-2, -1, 1, 4))) & 0xFFFFFFFF
            raw = value.to_bytes(4, "little" if little else "big")
            for off in (pnio.NDR_REQ[False].offsets[1], pnio.NDR_REQ[False].offsets[4]):
                data[body + off:body + off + 4] = raw
            made.append(frame._replace(data=bytes(data)))
            continue
        if roll < 0.2:
            off, raw = rng.choice(((pnio.NDR_SIZE + _AR, bytes(16)), (pnio.NDR_SIZE + _AR, rng.randbytes(16)),
                                   (_DREP + 1 - rpc.HEADER_SIZE, bytes([rng.randrange(4)]))))
        elif roll < 0.3:
            status = bytes.fromhex(rng.choice(_STATUSES))
            off, raw = rng.choice(((0, status[::-1] if little else status),
                                   (pnio.NDR_SIZE + _WRITE_RES_STATUS, status)))
        else:
            if roll < 0.45:
                off, size = rng.choice(_HEADER_FIELDS)
                off -= rpc.HEADER_SIZE
            else:
                off, size = rng.choice(_STUB_FIELDS)
            if size > 8:  # a byte of a UUID or of the padding
                off, size = off + rng.randrange(size), 1
            value = rng.choice(_VALUES) if rng.random() < 0.7 else rng.randrange(1 << (8 * size))
            value &= (1 << (8 * size)) - 1
            raw = value.to_bytes(size, "little" if little and rng.random() < 0.8 else "big")
        at = body + off
        if at + len(raw) <= len(data):
            data[at:at + len(raw)] = raw
        made.append(frame._replace(data=bytes(data)))
    return made


def link_targeted(frames: Sequence[RawFrame], rng: random.Random) -> list[RawFrame]:
    """Frames cut inside their link headers, IPv4 and UDP fields set to edge values, IPv4 options inserted."""
    batch = make_batch(frames)
    out = pnio_batch.decode(batch, Checker.for_profile())
    pnio_frames = [frames[i] for i in np.flatnonzero(out.frames.route == ROUTE_PNIO)]
    tagged = [f for f in pnio_frames if link.headers(f.linktype, f.data).tags]
    made = [f._replace(data=f.data[:cut]) for f in rng.sample(tagged, min(len(tagged), 6))
            for cut in range(11, link.headers(f.linktype, f.data).l3 + 22)]
    edits = (("ver_ihl", 0, 1, (0x40, 0x41, 0x44, 0x45, 0x46, 0x4F, 0x00, 0x55, 0x65)),
             ("ip.len", 2, 2, (0, 1, 19, 20, 27, 28, 29, 0xFFFF)),
             ("ip.flags", 6, 2, (0x2000, 0x0001, 0x4000, 0x8000, 0x1FFF, 0x6000)),
             ("ip.proto", 9, 1, (6, 1, 0, 16, 18)))
    for _ in range(600):
        f = rng.choice(pnio_frames)
        data = bytearray(f.data)
        l3 = link.headers(f.linktype, f.data).l3
        roll = rng.random()
        if roll < 0.15:  # options, lengths made to fit: still ordinary
            words = rng.choice((1, 2, 10))
            data[l3 + 20:l3 + 20] = bytes([1]) * (4 * words)  # NOP options
            data[l3] = 0x45 + words
            data[l3 + 2:l3 + 4] = (int.from_bytes(data[l3 + 2:l3 + 4], "big") + 4 * words).to_bytes(2, "big")
        elif roll < 0.3:
            udp = l3 + (data[l3] & 0x0F) * 4
            ulen = int.from_bytes(data[udp + 4:udp + 6], "big")
            value = rng.choice((0, 1, 7, 8, 9, 87, 88, ulen - 1, ulen + 1, 0xFFFF))
            data[udp + 4:udp + 6] = (value & 0xFFFF).to_bytes(2, "big")
        elif roll < 0.4:
            data[l3 - 2:l3] = rng.choice((0x86DD, 0x0806, 0x8100, 0x88A8, 0x0800, 0x05DC)).to_bytes(2, "big")
        elif roll < 0.45 and f.linktype == 1:  # more VLAN tags (802.1ad, 802.1Q, legacy): up to beyond MAX_TAGS
            for _ in range(rng.randint(1, link_batch.MAX_TAGS + 2)):
                data[12:12] = rng.choice((0x8100, 0x88A8, 0x9100)).to_bytes(2, "big") + rng.randbytes(2)
        elif roll < 0.5:  # other link types: the per-frame path's, but with their address pair
            linktype = rng.choice((101, 113, 228, 276, 0))
            made.append(f._replace(linktype=linktype, data=bytes(data[l3:] if linktype in (101, 228) else data)))
            continue
        else:
            _name, off, size, values = rng.choice(edits)
            data[l3 + off:l3 + off + size] = rng.choice(values).to_bytes(size, "big")
        made.append(f._replace(data=bytes(data)))
    return made


def _longer(frame: RawFrame, extra: int) -> bytes:
    """The frame with `extra` bytes after its RPC PDU, inside the UDP datagram (R2), lengths made to fit."""
    data = bytearray(frame.data)
    l3 = link.headers(frame.linktype, frame.data).l3
    udp = l3 + (data[l3] & 0x0F) * 4
    end = l3 + int.from_bytes(data[l3 + 2:l3 + 4], "big")
    data[end:end] = bytes(range(1, extra + 1))
    for at in (l3 + 2, udp + 4):
        data[at:at + 2] = (int.from_bytes(data[at:at + 2], "big") + extra).to_bytes(2, "big")
    return bytes(data)


@pytest.fixture(scope="module")
def frames() -> tuple[RawFrame, ...]:
    return all_frames()


@pytest.fixture(scope="module")
def batch(frames: tuple[RawFrame, ...]) -> FrameBatch:
    return make_batch(frames)


@cache
def checker(profile: str) -> Checker:
    return Checker.for_profile(profile)


@cache
def decoded(profile: str) -> pnio_batch.DecodedBatch:
    return pnio_batch.decode(make_batch(all_frames()), checker(profile))


# --- Layout.columns ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("layout", [rpc.HEADER_LE, rpc.HEADER_BE, pnio.NDR_REQ[True], pnio.NDR_RES[True],
                                    pnio.NDR_RES[False], pnio.WRITE_REQ, pnio.READ_REQ_IMPLICIT, pnio.WRITE_RES,
                                    pnio.READ_RES, link.IPV4, link.UDP, link.ETH, link.SLL2],
                         ids=lambda layout: f"{layout.title} {layout.order}")
def test_layout_columns_are_the_struct_unpack(layout) -> None:
    rng = random.Random(7)
    buf = rng.randbytes(4096)
    at = np.array(sorted(rng.sample(range(4096 - layout.size + 1), 200)), np.int64)
    cols = layout.columns(np.frombuffer(buf, np.uint8), at)
    for row, off in enumerate(at):
        values = layout.unpack(buf, int(off))
        for i, name in enumerate(layout.names):
            got = cols[name][row]
            assert (bytes(got) if cols[name].ndim == 2 else int(got)) == values[i], name
    part = layout.columns(np.frombuffer(buf, np.uint8), at, layout.names[-1:] + layout.names[:1])
    assert [list(map(bytes, c)) if c.ndim == 2 else c.tolist() for c in part.values()] == \
        [list(map(bytes, cols[n])) if cols[n].ndim == 2 else cols[n].tolist() for n in part]
    assert {name: c.shape for name, c in layout.columns(np.frombuffer(buf, np.uint8), at[:0]).items()} == \
        {name: (0, *c.shape[1:]) for name, c in cols.items()}


@pytest.mark.parametrize("share", [0.1, 0.9, 1.0])
def test_layout_reads_only_valid_rows(share: float) -> None:
    """Rows not valid may lie anywhere (even outside the data): they are not read, and their fields are 0."""
    rng = random.Random(11)
    buf = rng.randbytes(1000)
    layout = pnio.WRITE_RES
    at = np.array([rng.randrange(-500, 1500) for _ in range(300)], np.int64)
    valid = np.array([rng.random() < share for _ in at]) & (at >= 0) & (at <= len(buf) - layout.size)
    cols = layout.columns(np.frombuffer(buf, np.uint8), at, valid=valid)
    raw = layout.records(np.frombuffer(buf, np.uint8), at, valid)
    for row, off in enumerate(at):
        want = layout.unpack(buf, int(off)) if valid[row] else layout.unpack(bytes(layout.size))
        got = [bytes(c[row]) if c.ndim == 2 else int(c[row]) for c in cols.values()]
        assert got == list(want) == [bytes(c[row]) if c.ndim == 2 else int(c[row])
                                     for c in layout.fields(raw).values()], row


def test_fields_by_order_reads_each_row_in_its_byte_order() -> None:
    rng = random.Random(12)
    buf = rng.randbytes(3000)
    at = np.array(sorted(rng.sample(range(3000 - 20), 100)), np.int64)
    little = np.array([rng.random() < 0.5 for _ in at])
    for layouts in (pnio.NDR_REQ, pnio.NDR_RES):
        raw = layouts[True].records(np.frombuffer(buf, np.uint8), at)
        cols = fields_by_order(layouts[True], layouts[False], raw, little, layouts[True].names)
        for row, off in enumerate(at):
            layout = layouts[bool(little[row])]
            assert {name: int(cols[name][row]) for name in layout.names} == dict(
                zip(layout.names, layout.unpack(buf, int(off)), strict=True)), row
        for same in (True, False):
            whole = fields_by_order(layouts[True], layouts[False], raw, np.full(len(at), same), layouts[True].names)
            assert all((whole[name] == layouts[same].fields(raw)[name]).all() for name in layouts[True].names)


# --- the differential test --------------------------------------------------------------------------------
def test_corpus_reaches_every_route(frames: tuple[RawFrame, ...]) -> None:
    routes = decoded("generic").frames.route
    counts = np.bincount(routes, minlength=4)
    assert len(frames) > 10_000
    assert counts[ROUTE_PNIO] > 3000 and counts[ROUTE_DECIDE] > 10 and counts[ROUTE_SKIP] > 1000, counts
    assert decoded("generic").pdus.flag.sum() > 1000  # the mutations reach the rules
    reasons = set(decoded("generic").frames.skip_reason[routes == ROUTE_SKIP].tolist())
    assert {SKIP_REASONS[r] for r in reasons} >= {link.SKIP_NOT_IPV4, link.SKIP_NOT_UDP, link.SKIP_SHORT,
                                                  rpc.SKIP_NOT_RPC, rpc.SKIP_NOT_PNIO}


@pytest.mark.parametrize("profile", PROFILES)
def test_skipped_frames_are_skipped_alike(profile: str, frames: tuple[RawFrame, ...]) -> None:
    out = decoded(profile).frames
    assert ((out.skip_reason >= 0) == (out.route == ROUTE_SKIP)).all()
    for i in np.flatnonzero(out.route == ROUTE_SKIP):
        d = Dissector(checker=checker(profile))
        results = d.feed(frames[i]) + d.finish()
        assert (results, d.loose_findings, dict(d.accounting.malformed)) == ([], [], {}), i
        assert dict(d.accounting.skipped) == {SKIP_REASONS[out.skip_reason[i]]: 1}, i


def test_vlan_tags_beyond_the_walk_go_to_the_frames_path(frames: tuple[RawFrame, ...]) -> None:
    route = decoded("generic").frames.route
    tags = [len(link.headers(f.linktype, f.data).tags) if f.linktype == 1 else 0 for f in frames]
    deep = [i for i, n in enumerate(tags) if n > link_batch.MAX_TAGS]
    assert deep and all(route[i] == ROUTE_FRAMES for i in deep)
    assert any(route[i] == ROUTE_PNIO for i, n in enumerate(tags) if n == link_batch.MAX_TAGS)


def test_group_is_the_address_pair(frames: tuple[RawFrame, ...]) -> None:
    out = decoded("generic").frames
    for i, frame in enumerate(frames):
        l3 = link.headers(frame.linktype, frame.data).l3 if frame.linktype in (1, 101, 113, 228, 276) else -1
        if l3 < 0 or len(frame.data) < l3 + 20:
            assert out.group[i] == 0, i
            continue
        src, dst = (int.from_bytes(frame.data[l3 + k:l3 + k + 4], "big") for k in (12, 16))
        assert out.group[i] == min(src, dst) << 32 | max(src, dst), i


def test_decide_frames_are_other_rpc_than_requests(frames: tuple[RawFrame, ...]) -> None:
    out = decoded("generic")
    for row in np.flatnonzero(out.frames.route[out.pdus.pos] == ROUTE_DECIDE):
        i = int(out.pdus.pos[row])
        dgram = link.LinkDecoder().datagram(i + 1, frames[i].linktype, frames[i].data)
        assert isinstance(dgram, link.Datagram) and rpc.plausible(dgram.payload), i
        hdr = rpc.header(dgram.payload)
        assert hdr.ptype != PTYPE_REQUEST and not rpc.is_pnio_uuid(hdr.interface), i
        _same_rpc_columns(out.pdus, row, dgram, hdr)
        stub = ("args_max", "status", "args_len", "max_count", "has_block", "block_type", "iod_seq", "ar_hi", "ar_lo",
                "target_hi", "target_lo", "api", "slot", "subslot", "index", "record_len", "block_status",
                "rec_start", "rec_len", "flag")
        assert [getattr(out.pdus, name)[row] for name in stub] == [0] * len(stub), i  # the RPC header only
        d = Dissector()  # no call or activity known: the reference skips it
        assert d.feed(frames[i]) == [] and dict(d.accounting.skipped) == {rpc.SKIP_NOT_PNIO: 1}
    assert set(np.flatnonzero(out.frames.route == ROUTE_DECIDE)) == set(out.pdus.pos[
        out.frames.route[out.pdus.pos] == ROUTE_DECIDE])


@pytest.mark.parametrize("profile", PROFILES)
def test_pnio_frames_decode_as_the_reference(profile: str, frames: tuple[RawFrame, ...],
                                             batch: FrameBatch) -> None:
    out = decoded(profile)
    pdus = out.pdus
    assert (np.diff(pdus.pos) > 0).all()
    assert set(pdus.pos.tolist()) == set(np.flatnonzero(out.frames.route >= ROUTE_DECIDE).tolist())
    unflagged_clean = flagged_clean = 0
    for row in np.flatnonzero(out.frames.route[pdus.pos] == ROUTE_PNIO):
        i = int(pdus.pos[row])
        local = _reference(frames[i], pdus, row, batch, checker(profile))
        if not pdus.flag[row]:
            assert local == [], (i, local)
            unflagged_clean += 1
        elif not local:
            flagged_clean += 1
    assert unflagged_clean > 1000
    print(f"{profile}: {unflagged_clean} PNIO frames unflagged, {flagged_clean} flagged without a local finding")


def _reference(frame: RawFrame, pdus: pnio_batch.PduColumns, row: int, batch: FrameBatch,
               checker: Checker) -> list[Finding]:
    """The reference's decode of one ROUTE_PNIO frame compared with its columns; its frame-local findings."""
    number = frame.number
    dgram = link.LinkDecoder().datagram(number, frame.linktype, frame.data)
    assert isinstance(dgram, link.Datagram) and not dgram.truncated and rpc.plausible(dgram.payload), number
    hdr = rpc.header(dgram.payload)
    _same_rpc_columns(pdus, row, dgram, hdr)
    response = hdr.ptype == PTYPE_RESPONSE
    body = dgram.payload[rpc.HEADER_SIZE:rpc.HEADER_SIZE + hdr.frag_len]
    if hdr.ptype in (PTYPE_FAULT, PTYPE_REJECT):  # a fault with its status: always flagged (rpc_fault)
        assert rpc.is_pnio_uuid(hdr.interface) and len(body) == hdr.frag_len >= 4 and pdus.flag[row], number
        layout = rpc.FAULT_LE if hdr.little else rpc.FAULT_BE
        assert pdus.status[row] == layout.unpack(body)[0] and not pdus.has_block[row], number
        (res,) = Dissector(checker=checker).feed(frame)
        assert "rpc_fault" in [f.name for f in res.findings], number
        return res.findings
    assert rpc.is_pnio_uuid(hdr.interface) and hdr.ptype in (PTYPE_REQUEST, PTYPE_RESPONSE), number
    assert len(body) == hdr.frag_len == pdus.body_len[row]
    assert batch.buf[pdus.body_start[row]:pdus.body_start[row] + pdus.body_len[row]] == body
    structural: list[Finding] = []
    stub = pnio.parse_stub(body, hdr.little, response, hdr.opnum, number, structural)
    assert structural == [] and not stub.truncated and len(stub.blocks) <= 1, number
    d = Dissector(checker=checker)  # the whole PDU of one frame: no fragment, no authentication, not cut
    (res,) = d.feed(frame)
    assert res.pdu is not None and res.pdu.stub is not None and not res.pdu.malformed and not res.pdu.fragments
    assert d.accounting.decoded == 1 and not d.accounting.malformed, number
    status = stub.status or pnio.OK_STATUS
    assert (pdus.args_max[row], pdus.args_len[row], pdus.max_count[row], pdus.status[row]) == (
        max(stub.args_max, 0), stub.args_len, stub.max_count, int(status.text(), 16)), number
    assert pdus.has_block[row] == bool(stub.blocks)
    if stub.blocks:
        block = stub.blocks[0]
        v = block.values
        assert (pdus.block_type[row], pdus.iod_seq[row], pdus.api[row], pdus.slot[row], pdus.subslot[row],
                pdus.index[row], pdus.record_len[row]) == (v[pnio.B_TYPE], v[pnio.B_SEQ], v[pnio.B_API],
                                                            v[pnio.B_SLOT], v[pnio.B_SUBSLOT], block.index,
                                                            block.record_len), number
        assert _uuid(pdus.ar_hi[row], pdus.ar_lo[row]) == v[pnio.B_AR]
        assert _uuid(pdus.target_hi[row], pdus.target_lo[row]) == (block.target_ar or bytes(16))
        assert pdus.block_status[row] == (int(block.status.text(), 16) if block.status else 0)
        if block.layout in (pnio.WRITE_REQ, pnio.READ_RES) and status.ok:
            assert batch.buf[pdus.rec_start[row]:pdus.rec_start[row] + pdus.rec_len[row]] == block.record
            assert len(block.record) == block.record_len
        else:
            assert pdus.rec_start[row] == pdus.rec_len[row] == 0
    else:
        assert response and not status.ok and hdr.opnum != 3 and len(body) == pnio.NDR_SIZE, number
        assert (pdus.block_type[row], pdus.index[row], pdus.rec_len[row], pdus.ar_hi[row]) == (0, 0, 0, 0)
    # the frame-local rules (module docstring of pnio_batch)
    local = rpc.check_header(hdr, number, len(dgram.payload) - rpc.HEADER_SIZE, hdr.opnum in RECORD_SERVICES)
    if not response and hdr.opnum in RECORD_SERVICES and hdr.interface[3] != 1:
        local.append("pnio_interface")  # Dissector._request's finding
    local += checks.ndr(stub, hdr.frag_len, hdr.opnum, number, None)
    local += checks.blocks(stub, hdr.opnum, number, None, checker.record.max_length, checker.tolerate)
    for block in stub.blocks if not response else ():
        if block.index in PROFIDRIVE_INDICES:
            v = block.values
            local += checker.iod(v[pnio.B_API], v[pnio.B_SLOT], v[pnio.B_SUBSLOT], block.index, number)
    return local


def _same_rpc_columns(pdus: pnio_batch.PduColumns, row: int, dgram: link.Datagram, hdr: rpc.Header) -> None:
    assert (pdus.src[row], pdus.dst[row], pdus.sport[row], pdus.dport[row]) == (
        int.from_bytes(dgram.src, "big"), int.from_bytes(dgram.dst, "big"), dgram.sport, dgram.dport)
    assert (pdus.ptype[row], pdus.flags1[row], pdus.little[row], pdus.seq[row], pdus.opnum[row],
            pdus.body_len[row]) == (hdr.ptype, hdr.flags1, hdr.little, hdr.seq, hdr.opnum, hdr.frag_len)
    assert _uuid(pdus.act_hi[row], pdus.act_lo[row]) == hdr.activity
    assert _uuid(pdus.if_hi[row], pdus.if_lo[row]) == hdr.interface


def _uuid(hi: np.uint64, lo: np.uint64) -> bytes:
    return int(hi).to_bytes(8, "big") + int(lo).to_bytes(8, "big")


def test_pdu_columns_keep_the_contract_dtypes() -> None:
    pdus = decoded("generic").pdus
    want = {"pos": np.int64, "src": np.uint32, "dst": np.uint32, "sport": np.uint16, "dport": np.uint16,
            "ptype": np.uint8, "flags1": np.uint8, "little": np.bool_, "act_hi": np.uint64, "act_lo": np.uint64,
            "if_hi": np.uint64, "if_lo": np.uint64, "seq": np.uint32, "opnum": np.uint16, "body_start": np.int64,
            "body_len": np.int32, "args_max": np.uint32, "status": np.uint32, "args_len": np.uint32,
            "max_count": np.uint32, "has_block": np.bool_, "block_type": np.uint16, "iod_seq": np.uint16,
            "ar_hi": np.uint64, "ar_lo": np.uint64, "target_hi": np.uint64, "target_lo": np.uint64,
            "api": np.uint32, "slot": np.uint16, "subslot": np.uint16, "index": np.uint16,
            "record_len": np.uint32, "block_status": np.uint32, "rec_start": np.int64, "rec_len": np.int32,
            "flag": np.bool_}
    assert {name: getattr(pdus, name).dtype for name in want} == {name: np.dtype(t) for name, t in want.items()}
    assert len({len(getattr(pdus, name)) for name in want}) == 1
    frames = decoded("generic").frames
    assert (frames.route.dtype, frames.skip_reason.dtype, frames.group.dtype) == (np.int8, np.int8, np.uint64)


# --- batches decode as their frames one at a time -----------------------------------------------------------
def _rows(out: pnio_batch.DecodedBatch, offset: int) -> list[tuple]:
    """Frame and PDU columns of a decoded batch as rows (PDU positions moved by `offset`)."""
    f = out.frames
    p = out.pdus
    pdu = {int(p.pos[k]): tuple(getattr(p, name)[k].item() for name in pnio_batch.PduColumns.__slots__
                                if name != "pos") for k in range(len(p.pos))}
    return [(f.route[i].item(), f.skip_reason[i].item(), f.group[i].item(), pdu.get(i)) for i in range(len(f.route))]


def _in_pieces(batch: FrameBatch, cuts: Sequence[int]) -> list[tuple]:
    """The batch decoded as consecutive batches over the same buffer, ending at `cuts`."""
    rows, lo = [], 0
    for hi in [*cuts, len(batch)]:
        part = FrameBatch(batch.buf, batch.number[lo:hi], batch.ts[lo:hi], batch.linktype[lo:hi],
                          batch.start[lo:hi], batch.caplen[lo:hi], batch.iface[lo:hi], batch.ns[lo:hi])
        rows += _rows(pnio_batch.decode(part, checker("generic")), lo)
        lo = hi
    return rows


def test_a_batch_decodes_as_its_frames_one_at_a_time(batch: FrameBatch) -> None:
    whole = _rows(decoded("generic"), 0)
    rng = random.Random(5)
    cuts = sorted(rng.sample(range(1, len(batch)), len(batch) // 40))
    assert _in_pieces(batch, cuts) == whole
    singles = sorted(rng.sample(range(len(batch)), 400))
    one = [_rows(pnio_batch.decode(make_batch([all_frames()[i]]), checker("generic")), 0)[0] for i in singles]
    assert [_moved(row, int(batch.start[i])) for row, i in zip(one, singles, strict=True)] == \
        [whole[i] for i in singles]


def _moved(row: tuple, by: int) -> tuple:
    """A single-frame batch's row with its buffer offsets (body_start, rec_start) as in the whole batch."""
    route, reason, group, pdu = row
    if pdu is None:
        return row
    names = [name for name in pnio_batch.PduColumns.__slots__ if name != "pos"]
    values = list(pdu)
    values[names.index("body_start")] += by
    if values[names.index("rec_start")]:  # 0: no record
        values[names.index("rec_start")] += by
    return route, reason, group, tuple(values)


def test_mixed_byte_orders_and_vlan_tags_in_one_batch() -> None:
    paths = [ROOT / "sample_pcaps" / name for name in ("record_rw_le.pcap", "record_rw_be.pcap", "vlan_stacked.pcap",
                                                        "implicit_read.pcap", "pd_yaskawa_like.pcap")]
    lists = [list(capture.frames(str(p))) for p in paths]
    mixed = [f for group in zip(*(fs * 4 for fs in lists), strict=False) for f in group]
    mixed = [f._replace(number=n) for n, f in enumerate(mixed, 1)]
    out = pnio_batch.decode(make_batch(mixed), checker("generic"))
    assert sum(out.pdus.little) and sum(~out.pdus.little)  # both byte orders
    assert any(len(link.headers(f.linktype, f.data).tags) > 1 for f in mixed)
    whole = _rows(out, 0)
    start = make_batch(mixed).start
    for i, frame in enumerate(mixed):
        alone = _rows(pnio_batch.decode(make_batch([frame]), checker("generic")), 0)[0]
        assert _moved(alone, int(start[i])) == whole[i], i
    assert np.bincount(out.frames.route, minlength=4)[ROUTE_PNIO] > 0.8 * len(mixed)


# --- the ordinary path is taken -------------------------------------------------------------------------------
def test_a_synthetic_parameter_access_capture_is_all_columnar(tmp_path: Path) -> None:
    path = tmp_path / "mixed.pcap"
    make_capture(path, 3000, pnio_share=1.0)
    frames = list(capture.frames(str(path)))
    out = pnio_batch.decode(make_batch(frames), checker("generic"))
    routes = out.frames.route
    assert (routes != ROUTE_FRAMES).all() and (routes != ROUTE_DECIDE).all()
    assert set(out.frames.skip_reason[routes == ROUTE_SKIP].tolist()) <= {SKIP_REASONS.index(rpc.SKIP_NOT_RPC)}
    assert (routes == ROUTE_PNIO).sum() > 0.9 * len(frames)
    assert out.pdus.flag.sum() == 0  # clean synthetic traffic: nothing for the per-frame checks
    assert (out.pdus.rec_len > 0).sum() > 0.2 * len(out.pdus.pos)  # records (B5 polls carry none)


def test_an_empty_batch() -> None:
    out = pnio_batch.decode(make_batch([]), checker("generic"))
    assert len(out.frames.route) == len(out.pdus.pos) == 0

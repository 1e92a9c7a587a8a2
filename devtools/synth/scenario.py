"""Simulation layer: a deterministic clock, hosts, the capture being built,
and a controller/device PNIO session that turns record services into frames.

Design: builders (`pdu`, `*_stub`) return bytes without side effects;
emitters (`send`, `call` and the record services) append frames to the
Capture and advance the clock. Every service accepts per-layer override
dicts (req_rpc/res_rpc for the RPC header, req_ndr/res_ndr, req_iod/res_iod)
so a later scenario can inject one wrong field in one line.
"""

from __future__ import annotations

import random
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from . import net_encode, pnio_encode, rpc_encode
from .capture_files import Frame
from .net_encode import LINKTYPE_ETHERNET, LINKTYPE_LINUX_SLL, LINKTYPE_LINUX_SLL2, LINKTYPE_RAW, VlanTag

EPOCH_NS: Final = 1_767_225_600 * 1_000_000_000  # 2026-01-01T00:00:00Z

WRITE_ARGS_MAX: Final = 16696  # ArgsMaximum of protocol.md section 9 frame 1

Overrides = Mapping[str, Any] | None


class Clock:
    """Capture time in integer nanoseconds; never reads the wall clock."""

    def __init__(self, start_ns: int = EPOCH_NS) -> None:
        self.now_ns = start_ns

    def advance_us(self, us: float) -> int:
        self.now_ns += round(us * 1000)
        return self.now_ns

    def set_rel(self, seconds: float, base_ns: int = EPOCH_NS) -> int:
        """Jump to base + seconds (for tables such as protocol.md 9)."""
        self.now_ns = base_ns + round(seconds * 1e9)
        return self.now_ns


@dataclass
class Host:
    mac: bytes
    ip: str
    ip_ident: int = 0x0100  # next IPv4 identification

    def next_ident(self) -> int:
        ident = self.ip_ident
        self.ip_ident = (self.ip_ident + 1) & 0xFFFF
        return ident


def host(mac_text: str, ip: str, ip_ident: int = 0x0100) -> Host:
    return Host(net_encode.mac(mac_text), ip, ip_ident)


@dataclass(frozen=True)
class Medium:
    """How an IP packet or Ethernet payload becomes captured bytes.

    For SLL/SLL2, `local_ip` is the capturing host: packets it sends are
    marked "outgoing", others "to us".
    """

    linktype: int = LINKTYPE_ETHERNET
    vlans: tuple[VlanTag, ...] = ()
    mtu: int = 1500
    iface: int = 0
    local_ip: str | None = None

    def frame(self, src_mac: bytes, dst_mac: bytes, ethertype: int, payload: bytes, src_ip: str | None) -> bytes:
        if self.linktype == LINKTYPE_ETHERNET:
            return net_encode.ethernet(dst_mac, src_mac, ethertype, payload, vlans=self.vlans)
        pkttype = net_encode.SLL_OUTGOING if src_ip is not None and src_ip == self.local_ip else net_encode.SLL_HOST
        if self.linktype == LINKTYPE_LINUX_SLL:
            return net_encode.sll(ethertype, payload, pkttype=pkttype, addr=src_mac)
        if self.linktype == LINKTYPE_LINUX_SLL2:
            return net_encode.sll2(ethertype, payload, pkttype=pkttype, addr=src_mac, ifindex=self.iface + 1)
        if self.linktype == LINKTYPE_RAW:
            if ethertype != net_encode.ETH_IPV4:
                raise ValueError("raw IP link type carries IPv4 only")
            return payload
        raise ValueError(f"unsupported link type {self.linktype}")


@dataclass
class Capture:
    """The frame list being built, in file order, plus the shared clock."""

    clock: Clock = field(default_factory=Clock)
    medium: Medium = field(default_factory=Medium)
    frames: list[Frame] = field(default_factory=list)

    def add(self, data: bytes, *, ts_ns: int | None = None, medium: Medium | None = None) -> Frame:
        m = medium or self.medium
        frame = Frame(self.clock.now_ns if ts_ns is None else ts_ns, data, m.linktype, iface=m.iface)
        self.frames.append(frame)
        return frame

    def send_ether(
        self,
        src: Host,
        dst_mac: bytes,
        ethertype: int,
        payload: bytes,
        *,
        ts_ns: int | None = None,
        medium: Medium | None = None,
    ) -> Frame:
        m = medium or self.medium
        return self.add(m.frame(src.mac, dst_mac, ethertype, payload, None), ts_ns=ts_ns, medium=m)

    def send_ip(
        self,
        src: Host,
        dst: Host,
        ip_payload: bytes,
        *,
        ts_ns: int | None = None,
        medium: Medium | None = None,
        ident: int | None = None,
        df: bool = False,
        fragment_order: Sequence[int] | None = None,
        fragment_gap_ns: int = 20_000,
    ) -> list[Frame]:
        """One IP datagram, split into fragments when it exceeds the MTU.
        fragment_order lists fragment indexes in emission order (e.g. [2, 0, 1])."""
        m = medium or self.medium
        t = self.clock.now_ns if ts_ns is None else ts_ns
        ip_id = src.next_ident() if ident is None else ident
        if 20 + len(ip_payload) <= m.mtu:
            packets = [net_encode.ipv4(src.ip, dst.ip, ip_payload, ident=ip_id, df=df)]
        else:
            packets = net_encode.ip_fragments(src.ip, dst.ip, ip_payload, ident=ip_id, mtu=m.mtu)
        order = range(len(packets)) if fragment_order is None else fragment_order
        out = []
        for k, i in enumerate(order):
            data = m.frame(src.mac, dst.mac, net_encode.ETH_IPV4, packets[i], src.ip)
            out.append(self.add(data, ts_ns=t + k * fragment_gap_ns, medium=m))
        return out

    def send_udp(self, src: Host, sport: int, dst: Host, dport: int, payload: bytes, **ip_kw: Any) -> list[Frame]:
        segment = net_encode.udp(sport, dport, payload, src_ip=src.ip, dst_ip=dst.ip)
        return self.send_ip(src, dst, segment, **ip_kw)

    def repeat(self, frame: Frame, ts_ns: int) -> Frame:
        """Identical bytes again later: a retransmission or capture duplicate."""
        copy = Frame(ts_ns, frame.data, frame.linktype, frame.orig_len, frame.iface)
        self.frames.append(copy)
        return copy

    def number(self, frame: Frame) -> int:
        """1-based frame number in file order (by identity, duplicates differ)."""
        for i, f in enumerate(self.frames):
            if f is frame:
                return i + 1
        raise ValueError("frame not in capture")

    def time_sorted(self) -> list[Frame]:
        """Frames ordered by timestamp (stable), for merged interleavings."""
        return sorted(self.frames, key=lambda f: f.ts_ns or 0)


@dataclass
class Call:
    """What one RPC call put on the wire."""

    seq: int
    opnum: int
    request: list[Frame]
    response: list[Frame]
    args_max: int = 0
    retransmits: int = 0  # identical copies of the request PDU sent after the first
    status: bytes | None = None  # PNIOStatus of the record response (None: no response, or a fault/reject)
    fault: int | None = None  # NCA status of a fault/reject answer


def _answered(call: Call, respond: bool, status: bytes, fault: tuple[int, int] | None) -> Call:
    """Record on the call how the server answered a record service (for the samples' expectations)."""
    if respond:
        call.status, call.fault = (None, fault[1]) if fault is not None else (status, None)
    return call


def _merge(base: dict[str, Any], extra: Overrides) -> dict[str, Any]:
    if extra:
        base.update(extra)
    return base


_STUB_KEYS: Final = frozenset(
    {
        "status", "api", "slot", "subslot", "ar_uuid", "add_val1", "add_val2", "max_len", "target_ar_uuid",
        "header_on_error", "req_ndr", "req_iod", "res_ndr", "res_iod", "args_max",
    }
)  # fmt: skip


def _split_stub_kw(call_kw: dict[str, Any], stub_kw: Overrides) -> dict[str, Any]:
    """Move the stub-builder keywords out of call_kw (in place)."""
    kw = {k: call_kw.pop(k) for k in list(call_kw) if k in _STUB_KEYS}
    return _merge(kw, stub_kw)


@dataclass
class PnioSession:
    """One controller talking to one device over one activity UUID (one AR).

    Owns the RPC sequence number, the IOD SeqNumber, the ARUUID and the
    default addressing (API/slot/subslot). `reply_port` lets the device
    answer from another UDP port. Latencies come from rtt_us/gap_us plus an
    optional jitter drawn from a seeded Random (deterministic).
    """

    cap: Capture
    controller: Host
    device: Host
    activity: uuid.UUID
    ar_uuid: uuid.UUID
    object_uuid: uuid.UUID = field(default_factory=lambda: rpc_encode.pnio_object_uuid(1, 0x0002, 0x0002))
    interface: uuid.UUID = rpc_encode.PNIO_DEVICE_IF
    controller_port: int = 49152
    device_port: int = 34964
    reply_port: int | None = None
    drep: bytes = rpc_encode.DREP_LE
    server_boot: int = 0x5F000000
    client_boot: int = 0  # what the client puts in requests; learnt from the first reply
    seq: int = 1  # next RPC sequence number
    iod_seq: int = 1  # next IOD SeqNumber
    api: int = pnio_encode.API_PROFIDRIVE
    slot: int = 1
    subslot: int = 1
    rtt_us: float = 1500.0
    gap_us: float = 1000.0
    jitter_us: float = 0.0
    rng: random.Random = field(default_factory=lambda: random.Random(0))
    max_frag_body: int | None = rpc_encode.MAX_FRAG_BODY  # None: never CL-fragment
    frag_gap_us: float = 100.0
    medium: Medium | None = None
    own_clock: Clock | None = None  # give each session its own clock to interleave, then cap.time_sorted()

    # ---- small helpers -------------------------------------------------
    @property
    def little(self) -> bool:
        return rpc_encode.drep_little(self.drep)

    @property
    def clock(self) -> Clock:
        return self.cap.clock if self.own_clock is None else self.own_clock

    def next_seq(self) -> int:
        s = self.seq
        self.seq = (self.seq + 1) & 0xFFFFFFFF
        return s

    def next_iod_seq(self) -> int:
        s = self.iod_seq
        self.iod_seq = (self.iod_seq + 1) & 0xFFFF
        return s

    def _lat(self, base: float | None, default: float) -> int:
        us = default if base is None else base
        if self.jitter_us and base is None:
            us += self.rng.uniform(0, self.jitter_us)
        return round(us * 1000)

    # ---- PDU builders (no side effects) --------------------------------
    def _hdr(self, ptype: int, seq: int, opnum: int, from_client: bool) -> dict[str, Any]:
        return dict(
            ptype=ptype,
            activity=self.activity,
            seq=seq,
            opnum=opnum,
            object_uuid=self.object_uuid,
            interface=self.interface,
            drep=self.drep,
            boot_time=self.client_boot if from_client else self.server_boot,
        )

    def pdu(self, ptype: int, body: bytes = b"", *, seq: int, opnum: int, from_client: bool, **hdr: Any) -> bytes:
        """One RPC PDU with this session's UUIDs, DREP and boot time; hdr
        overrides any rpc_header field (flags1 defaults: request 0x20,
        response 0x0A, others 0)."""
        fields = self._hdr(ptype, seq, opnum, from_client)
        flags1 = {rpc_encode.REQUEST: rpc_encode.REQ_FLAGS1, rpc_encode.RESPONSE: rpc_encode.RES_FLAGS1}
        fields["flags1"] = flags1.get(ptype, 0)
        return rpc_encode.rpc_pdu(body, **_merge(fields, hdr))

    def pdus(
        self,
        ptype: int,
        body: bytes,
        *,
        seq: int,
        opnum: int,
        from_client: bool,
        max_body: int | None = None,
        sizes: Sequence[int] | None = None,
        **hdr: Any,
    ) -> list[bytes]:
        """The body as one PDU, or as CL fragments when it exceeds max_body
        (default: the session's max_frag_body) or sizes is given. Fragment
        Flags1 base: request 0x20, response 0 (asks for FACKs); override
        with flags1=, the last-fragment extra bits with last_extra=."""
        limit = self.max_frag_body if max_body is None else max_body
        if sizes is None and (limit is None or len(body) <= limit):
            return [self.pdu(ptype, body, seq=seq, opnum=opnum, from_client=from_client, **hdr)]
        fields = self._hdr(ptype, seq, opnum, from_client)
        fields["flags1"] = rpc_encode.F1_IDEMPOTENT if ptype == rpc_encode.REQUEST else 0
        fields = _merge(fields, hdr)
        return rpc_encode.cl_fragments(body, max_body=limit or rpc_encode.MAX_FRAG_BODY, sizes=sizes, **fields)

    # ---- emitters -------------------------------------------------------
    def send(self, pdu: bytes, *, from_client: bool, at_ns: int | None = None, **ip_kw: Any) -> list[Frame]:
        """Put one RPC PDU on the wire (IP-fragmented if it exceeds the MTU;
        ip_kw: fragment_order, ident, df, ...)."""
        t = self.clock.now_ns if at_ns is None else at_ns
        if from_client:
            return self.cap.send_udp(
                self.controller,
                self.controller_port,
                self.device,
                self.device_port,
                pdu,
                ts_ns=t,
                medium=self.medium,
                **ip_kw,
            )
        sport = self.device_port if self.reply_port is None else self.reply_port
        return self.cap.send_udp(
            self.device, sport, self.controller, self.controller_port, pdu, ts_ns=t, medium=self.medium, **ip_kw
        )

    def send_all(
        self, pdus: Sequence[bytes], *, from_client: bool, at_ns: int | None = None, **ip_kw: Any
    ) -> list[Frame]:
        """Send PDUs (e.g. CL fragments) back to back, frag_gap_us apart."""
        t = self.clock.now_ns if at_ns is None else at_ns
        out: list[Frame] = []
        for k, p in enumerate(pdus):
            out += self.send(p, from_client=from_client, at_ns=t + k * round(self.frag_gap_us * 1000), **ip_kw)
        return out

    def send_pdu(
        self,
        ptype: int,
        *,
        seq: int,
        opnum: int,
        from_client: bool,
        body: bytes = b"",
        at_ns: int | None = None,
        **hdr: Any,
    ) -> list[Frame]:
        """Emit a single non-data PDU (ping, working, nocall, fault, ...)."""
        p = self.pdu(ptype, body, seq=seq, opnum=opnum, from_client=from_client, **hdr)
        return self.send(p, from_client=from_client, at_ns=at_ns)

    def fack(
        self, *, seq: int, opnum: int, frag_num: int, from_client: bool, at_ns: int | None = None, **body: Any
    ) -> list[Frame]:
        """FACK for fragment frag_num (header frag_num and body serial_num)."""
        fb = rpc_encode.fack_body(**_merge(dict(little=self.little, serial_num=frag_num), body))
        return self.send_pdu(
            rpc_encode.FACK, seq=seq, opnum=opnum, from_client=from_client, body=fb, frag_num=frag_num, at_ns=at_ns
        )

    def status_pdu(
        self, ptype: int, status: int, *, seq: int, opnum: int, at_ns: int | None = None, **hdr: Any
    ) -> list[Frame]:
        """Fault or reject from the server with a 4-byte NCA status."""
        body = rpc_encode.status_body(status, self.little)
        return self.send_pdu(ptype, seq=seq, opnum=opnum, from_client=False, body=body, at_ns=at_ns, **hdr)

    def reply(self, opnum: int, stub: bytes, *, seq: int, at_ns: int | None = None, **hdr: Any) -> list[Frame]:
        """Response PDU(s) for a call the caller drives by hand."""
        frames = self.send_all(
            self.pdus(rpc_encode.RESPONSE, stub, seq=seq, opnum=opnum, from_client=False, **hdr),
            from_client=False,
            at_ns=at_ns,
        )
        self.client_boot = self.server_boot
        return frames

    def call(
        self,
        opnum: int,
        req_stub: bytes,
        res_stub: bytes | None,
        *,
        seq: int | None = None,
        rtt_us: float | None = None,
        gap_us: float | None = None,
        res_ptype: int = rpc_encode.RESPONSE,
        req_rpc: Overrides = None,
        res_rpc: Overrides = None,
        req_ip: Overrides = None,
        res_ip: Overrides = None,
        retransmit_after_us: Sequence[float] = (),
        args_max: int = 0,
    ) -> Call:
        """Request now, reply (response/fault/reject) after rtt, then idle
        for gap. res_stub None: the request stays unanswered.
        retransmit_after_us: identical copies of the request PDU sent that
        long after the first one (the reply follows the last copy)."""
        s = self.next_seq() if seq is None else seq
        t0 = self.clock.now_ns
        req = self.pdus(rpc_encode.REQUEST, req_stub, seq=s, opnum=opnum, from_client=True, **dict(req_rpc or {}))
        req_frames = self.send_all(req, from_client=True, at_ns=t0, **dict(req_ip or {}))
        for delay in retransmit_after_us:
            req_frames += self.send_all(req, from_client=True, at_ns=t0 + round(delay * 1000), **dict(req_ip or {}))
        res_frames: list[Frame] = []
        t_end = req_frames[-1].ts_ns or t0
        if res_stub is not None:
            t1 = t_end + self._lat(rtt_us, self.rtt_us)
            res = self.pdus(res_ptype, res_stub, seq=s, opnum=opnum, from_client=False, **dict(res_rpc or {}))
            res_frames = self.send_all(res, from_client=False, at_ns=t1, **dict(res_ip or {}))
            t_end = res_frames[-1].ts_ns or t1
            self.client_boot = self.server_boot
        self.clock.now_ns = t_end + self._lat(gap_us, self.gap_us)
        return Call(s, opnum, req_frames, res_frames, args_max, len(retransmit_after_us))

    # ---- stub builders for the record services -------------------------
    def _addr(self, index: int, api: int | None, slot: int | None, subslot: int | None, ar: Any) -> dict[str, Any]:
        """IOD addressing with session defaults; takes a fresh IOD SeqNumber."""
        return dict(
            seq=self.next_iod_seq(),
            ar_uuid=self.ar_uuid if ar is None else ar,
            api=self.api if api is None else api,
            slot=self.slot if slot is None else slot,
            subslot=self.subslot if subslot is None else subslot,
            index=index,
        )

    def req_stub(self, block: bytes, *, args_max: int, ndr: Overrides = None) -> bytes:
        return pnio_encode.ndr_request(block, **_merge(dict(args_max=args_max, little=self.little), ndr))

    def res_stub(self, blocks: bytes, *, status: bytes, max_count: int, ndr: Overrides = None) -> bytes:
        fields = dict(status=status, max_count=max_count, little=self.little)
        return pnio_encode.ndr_response(blocks, **_merge(fields, ndr))

    def write_stubs(
        self,
        index: int,
        data: bytes,
        *,
        status: bytes = pnio_encode.STATUS_OK,
        api: int | None = None,
        slot: int | None = None,
        subslot: int | None = None,
        ar_uuid: Any = None,
        add_val1: int = 0,
        add_val2: int = 0,
        args_max: int = WRITE_ARGS_MAX,
        req_ndr: Overrides = None,
        req_iod: Overrides = None,
        res_ndr: Overrides = None,
        res_iod: Overrides = None,
    ) -> tuple[bytes, bytes]:
        """Write request and response stubs (NDR + IOD header [+ record]).
        The NDR status repeats the block status, as devices do."""
        addr = self._addr(index, api, slot, subslot, ar_uuid)
        block = pnio_encode.iod_write_req(**_merge(dict(addr, record_len=len(data)), req_iod)) + data
        fields = dict(addr, record_len=len(data), status=status, add_val1=add_val1, add_val2=add_val2)
        res_block = pnio_encode.iod_write_res(**_merge(fields, res_iod))
        return (
            self.req_stub(block, args_max=args_max, ndr=req_ndr),
            self.res_stub(res_block, status=status, max_count=args_max, ndr=res_ndr),
        )

    def read_stubs(
        self,
        index: int,
        data: bytes | None = None,
        *,
        status: bytes = pnio_encode.STATUS_OK,
        max_len: int = 240,
        target_ar_uuid: Any = None,
        api: int | None = None,
        slot: int | None = None,
        subslot: int | None = None,
        ar_uuid: Any = None,
        add_val1: int = 0,
        add_val2: int = 0,
        args_max: int | None = None,
        header_on_error: bool = False,
        req_ndr: Overrides = None,
        req_iod: Overrides = None,
        res_ndr: Overrides = None,
        res_iod: Overrides = None,
    ) -> tuple[bytes, bytes, int]:
        """Read request/response stubs and the ArgsMaximum (64 + max_len by
        default). An error status gives an NDR-only response (ArgsLength 0)
        unless header_on_error."""
        amax = 64 + max_len if args_max is None else args_max
        addr = self._addr(index, api, slot, subslot, ar_uuid)
        req_fields = dict(addr, record_len=max_len, target_ar_uuid=target_ar_uuid)
        block = pnio_encode.iod_read_req(**_merge(req_fields, req_iod))
        payload = b""
        if status == pnio_encode.STATUS_OK or header_on_error:
            rec = data or b""
            fields = dict(addr, record_len=len(rec), add_val1=add_val1, add_val2=add_val2)
            payload = pnio_encode.iod_read_res(**_merge(fields, res_iod)) + rec
        return (
            self.req_stub(block, args_max=amax, ndr=req_ndr),
            self.res_stub(payload, status=status, max_count=amax, ndr=res_ndr),
            amax,
        )

    # ---- record services -------------------------------------------------
    def write(
        self,
        index: int,
        data: bytes,
        *,
        respond: bool = True,
        args_max: int = WRITE_ARGS_MAX,
        fault: tuple[int, int] | None = None,
        stub_kw: Overrides = None,
        **call_kw: Any,
    ) -> Call:
        """Record write (opnum 3) + IODWriteResHeader answer. stub_kw goes to
        write_stubs (status, api, slot, req_iod, ...); the rest to call().
        For brevity status/api/slot/subslot/ar_uuid/add_val*/req_*/res_* may
        also be given directly. fault=(ptype, NCA status): the server answers
        with that fault (3) or reject (6) PDU instead of a response."""
        kw = _split_stub_kw(call_kw, stub_kw)
        req, res = self.write_stubs(index, data, args_max=args_max, **kw)
        if fault is not None:
            res, call_kw["res_ptype"] = rpc_encode.status_body(fault[1], self.little), fault[0]
        c = self.call(3, req, res if respond else None, args_max=args_max, **call_kw)
        return _answered(c, respond, kw.get("status", pnio_encode.STATUS_OK), fault)

    def read(
        self,
        index: int,
        data: bytes | None = None,
        *,
        opnum: int = 2,
        respond: bool = True,
        fault: tuple[int, int] | None = None,
        stub_kw: Overrides = None,
        **call_kw: Any,
    ) -> Call:
        """Record read (opnum 2; 5 for implicit). Stub keywords and fault as write()."""
        kw = _split_stub_kw(call_kw, stub_kw)
        req, res, amax = self.read_stubs(index, data, **kw)
        if fault is not None:
            res, call_kw["res_ptype"] = rpc_encode.status_body(fault[1], self.little), fault[0]
        c = self.call(opnum, req, res if respond else None, args_max=amax, **call_kw)
        return _answered(c, respond, kw.get("status", pnio_encode.STATUS_OK), fault)

    def read_implicit(self, index: int, data: bytes | None = None, *, target_ar_uuid: Any = None, **kw: Any) -> Call:
        """ReadImplicit (opnum 5): NIL ARUUID, TargetARUUID names the AR
        (default: this session's)."""
        target = self.ar_uuid if target_ar_uuid is None else target_ar_uuid
        return self.read(index, data, opnum=5, ar_uuid=rpc_encode.NIL_UUID, target_ar_uuid=target, **kw)

    def write_multiple(
        self,
        writes: Sequence[tuple[int, bytes] | pnio_encode.InnerWrite],
        *,
        statuses: Sequence[bytes] | None = None,
        status: bytes = pnio_encode.STATUS_OK,
        args_max: int = WRITE_ARGS_MAX,
        inner_res_record_len: int | None = None,
        outer: Overrides = None,
        res_outer: Overrides = None,
        **call_kw: Any,
    ) -> Call:
        """Write-Multiple 0xE040. Items (index, data) use the session's
        addressing and fresh IOD SeqNumbers; InnerWrite items are used as
        given. The response holds one IODWriteResHeader per inner write
        (record length mirrored unless inner_res_record_len is given)."""
        outer_seq = self.next_iod_seq()
        inner: list[pnio_encode.InnerWrite] = []
        for w in writes:
            if isinstance(w, pnio_encode.InnerWrite):
                inner.append(w)
            else:
                idx, data = w
                seq = self.next_iod_seq()
                inner.append(pnio_encode.InnerWrite(idx, data, seq, self.ar_uuid, self.api, self.slot, self.subslot))
        body = pnio_encode.write_multiple_req(inner, **_merge(dict(seq=outer_seq, ar_uuid=self.ar_uuid), outer))
        req = self.req_stub(body, args_max=args_max)
        sts = list(statuses) if statuses is not None else [pnio_encode.STATUS_OK] * len(inner)
        res_inner = [
            pnio_encode.iod_write_res(
                seq=w.seq,
                ar_uuid=w.ar_uuid,
                api=w.api,
                slot=w.slot,
                subslot=w.subslot,
                index=w.index,
                record_len=len(w.data) if inner_res_record_len is None else inner_res_record_len,
                status=st,
            )
            for w, st in zip(inner, sts, strict=True)
        ]
        res_body = pnio_encode.write_multiple_res(
            res_inner, **_merge(dict(seq=outer_seq, ar_uuid=self.ar_uuid, status=status), res_outer)
        )
        res = self.res_stub(res_body, status=status, max_count=args_max)
        return _answered(self.call(3, req, res, args_max=args_max, **call_kw), True, status, None)

    def parameter_access(
        self,
        request: bytes,
        response: bytes | None,
        *,
        index: int = 0xB02E,
        b5_retries: int = 0,
        write_status: bytes = pnio_encode.STATUS_OK,
        read_status: bytes = pnio_encode.STATUS_OK,
        write_fault: tuple[int, int] | None = None,
        read_fault: tuple[int, int] | None = None,
        read_gap_us: float | None = None,
        common_kw: Overrides = None,
        write_kw: Overrides = None,
        read_kw: Overrides = None,
    ) -> list[Call]:
        """PROFIdrive transaction: write the parameter request, then read
        until the response comes: b5_retries "DE 80 B5 00" answers first,
        each a new RPC call. response None: stop after the B5 reads (the
        transaction stays open).

        The transaction ends early when the write is answered with an error
        status (write_status) or a fault/reject (write_fault = (ptype, NCA
        status)); the final read may be answered with an error status
        (read_status, no record) or a fault/reject (read_fault) instead of
        the response. common_kw goes to the write and every read (api, slot,
        ...), write_kw / read_kw to one side only."""
        wkw = _merge(dict(common_kw or {}), write_kw)
        rkw = _merge(dict(common_kw or {}), read_kw)
        calls = [self.write(index, request, status=write_status, fault=write_fault, **wkw)]
        if write_status != pnio_encode.STATUS_OK or write_fault is not None:
            return calls
        for _ in range(b5_retries):
            kw = _merge(dict(gap_us=read_gap_us), rkw)
            calls.append(self.read(index, status=pnio_encode.STATUS_B5, **kw))
        if read_fault is not None:
            calls.append(self.read(index, fault=read_fault, **rkw))
        elif read_status != pnio_encode.STATUS_OK:
            calls.append(self.read(index, status=read_status, **rkw))
        elif response is not None:
            calls.append(self.read(index, response, **rkw))
        return calls

    def cm_call(
        self,
        opnum: int,
        req_blocks: bytes,
        res_blocks: bytes,
        *,
        status: bytes = pnio_encode.STATUS_OK,
        args_max: int = 4096,
        **call_kw: Any,
    ) -> Call:
        """Connect (0) / Release (1) / Control (4): NDR header + opaque blocks."""
        req = self.req_stub(req_blocks, args_max=args_max)
        res = self.res_stub(res_blocks, status=status, max_count=args_max)
        return self.call(opnum, req, res, args_max=args_max, **call_kw)

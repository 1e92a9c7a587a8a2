"""The CL-RPC layer of a simulated controller/device pair: sequence numbers, boot times, PDUs and CL
fragments, and calls (request, then response, fault or reject, with retransmissions) put on the wire
of a Capture.

Every emitter accepts per-layer override dicts (req_rpc/res_rpc for the RPC header, req_ip/res_ip
for IP) so a scenario can inject one wrong field in one line.
"""

from __future__ import annotations

import random
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from . import rpc_encode
from .capture_files import Frame
from .sim_capture import Capture, Clock, Host, Medium

Overrides = Mapping[str, Any] | None


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


def merge(base: dict[str, Any], extra: Overrides) -> dict[str, Any]:
    if extra:
        base.update(extra)
    return base


@dataclass
class RpcSession:
    """One CL-RPC client (the controller) talking to one server (the device) over one activity UUID.

    Owns the RPC sequence number and both boot times. `reply_port` lets the
    device answer from another UDP port. Latencies come from rtt_us/gap_us plus
    an optional jitter drawn from a seeded Random (deterministic). Builders
    (`pdu`, `pdus`) return bytes without side effects; emitters (`send`,
    `call`, ...) append frames to the Capture and advance the clock.
    """

    cap: Capture
    controller: Host
    device: Host
    activity: uuid.UUID
    object_uuid: uuid.UUID = field(default_factory=lambda: rpc_encode.pnio_object_uuid(1, 0x0002, 0x0002))
    interface: uuid.UUID = rpc_encode.PNIO_DEVICE_IF
    controller_port: int = 49152
    device_port: int = 34964
    reply_port: int | None = None
    drep: bytes = rpc_encode.DREP_LE
    server_boot: int = 0x5F000000
    client_boot: int = 0  # what the client puts in requests; learnt from the first reply
    seq: int = 1  # next RPC sequence number
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
        return rpc_encode.rpc_pdu(body, **merge(fields, hdr))

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
        fields = merge(fields, hdr)
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
        fb = rpc_encode.fack_body(**merge(dict(little=self.little, serial_num=frag_num), body))
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

"""The PNIO record services of a simulated controller/device pair (one AR): IOD headers and NDR
stubs, record write and read (explicit and implicit), Write-Multiple, the PROFIdrive parameter access
(write, B5 polling, final read) and the CM calls, each ending as an RPC call.

Every service accepts per-layer override dicts (req_ndr/res_ndr, req_iod/res_iod, and those of
rpc_session) so a scenario can inject one wrong field in one line.
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

from . import pnio_encode, rpc_encode
from .rpc_session import Call, Overrides, RpcSession, merge

WRITE_ARGS_MAX: Final = 16696  # ArgsMaximum of protocol.md section 9 frame 1


def _answered(call: Call, respond: bool, status: bytes, fault: tuple[int, int] | None) -> Call:
    """Record on the call how the server answered a record service (for the samples' expectations)."""
    if respond:
        call.status, call.fault = (None, fault[1]) if fault is not None else (status, None)
    return call


_STUB_KEYS: Final = frozenset(
    {
        "status", "api", "slot", "subslot", "ar_uuid", "add_val1", "add_val2", "max_len", "target_ar_uuid",
        "header_on_error", "req_ndr", "req_iod", "res_ndr", "res_iod", "args_max",
    }
)  # fmt: skip


def _split_stub_kw(call_kw: dict[str, Any], stub_kw: Overrides) -> dict[str, Any]:
    """Move the stub-builder keywords out of call_kw (in place)."""
    kw = {k: call_kw.pop(k) for k in list(call_kw) if k in _STUB_KEYS}
    return merge(kw, stub_kw)


@dataclass(kw_only=True)
class PnioSession(RpcSession):
    """An RPC session on one AR: it owns the IOD SeqNumber, the ARUUID and the
    default addressing (API/slot/subslot), and turns record services (write,
    read, Write-Multiple, PROFIdrive parameter access, CM calls) into calls.
    """

    ar_uuid: uuid.UUID
    iod_seq: int = 1  # next IOD SeqNumber
    api: int = pnio_encode.API_PROFIDRIVE
    slot: int = 1
    subslot: int = 1

    # ---- small helpers -------------------------------------------------
    def next_iod_seq(self) -> int:
        s = self.iod_seq
        self.iod_seq = (self.iod_seq + 1) & 0xFFFF
        return s

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
        return pnio_encode.ndr_request(block, **merge(dict(args_max=args_max, little=self.little), ndr))

    def res_stub(self, blocks: bytes, *, status: bytes, max_count: int, ndr: Overrides = None) -> bytes:
        fields = dict(status=status, max_count=max_count, little=self.little)
        return pnio_encode.ndr_response(blocks, **merge(fields, ndr))

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
        block = pnio_encode.iod_write_req(**merge(dict(addr, record_len=len(data)), req_iod)) + data
        fields = dict(addr, record_len=len(data), status=status, add_val1=add_val1, add_val2=add_val2)
        res_block = pnio_encode.iod_write_res(**merge(fields, res_iod))
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
        block = pnio_encode.iod_read_req(**merge(req_fields, req_iod))
        payload = b""
        if status == pnio_encode.STATUS_OK or header_on_error:
            rec = data or b""
            fields = dict(addr, record_len=len(rec), add_val1=add_val1, add_val2=add_val2)
            payload = pnio_encode.iod_read_res(**merge(fields, res_iod)) + rec
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
        body = pnio_encode.write_multiple_req(inner, **merge(dict(seq=outer_seq, ar_uuid=self.ar_uuid), outer))
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
            res_inner, **merge(dict(seq=outer_seq, ar_uuid=self.ar_uuid, status=status), res_outer)
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
        wkw = merge(dict(common_kw or {}), write_kw)
        rkw = merge(dict(common_kw or {}), read_kw)
        calls = [self.write(index, request, status=write_status, fault=write_fault, **wkw)]
        if write_status != pnio_encode.STATUS_OK or write_fault is not None:
            return calls
        for _ in range(b5_retries):
            kw = merge(dict(gap_us=read_gap_us), rkw)
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

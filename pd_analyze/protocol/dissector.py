"""One pass over a capture: frames -> UDP -> PNIO CL-RPC PDUs -> NDR/IOD blocks -> records.

`Dissector.feed` takes one frame and returns the PNIO RPC frames that are ready (possibly none,
possibly earlier ones). With `annotate=True` (the dump) every field is annotated and a frame that
waits for a forward link (its response, or the frame that reassembles its fragment) is held back
until the link is known or can no longer come, so the output stays in frame order; the hold is
bounded in time (rpc_timeout of capture time) and count. Without annotation (report, audit) no
field objects are built and nothing is held.
"""

# Longer than 450 lines: the frame loop reads one frame through every layer in order (link, RPC, NDR,
# IOD, record); the layers' parsing, checks and views live in their own modules, what stays is that one
# reading and the state it keeps per capture.

from __future__ import annotations

import zlib
from collections.abc import Iterable, Iterator
from typing import NamedTuple

from pd_analyze import capture
from pd_analyze.model.capped import (
    CHANNEL_REQUESTS,
    IP_FRAGMENT_TIMES,
    KNOWN_ACTIVITIES,
    CappedTable,
)
from pd_analyze.model.layout import derived
from pd_analyze.model.rules import Finding, finding
from pd_analyze.model.values import (
    FLAG1_FRAG,
    INDEX_PD_DPV1,
    INDEX_WRITE_MULTIPLE,
    IP_ETHERTYPES,
    LINKTYPE_ETHERNET,
    NCA_STATUS,
    PNIO_OPNUM,
    PROFIDRIVE_INDICES,
    PTYPE_CANCEL,
    PTYPE_FAULT,
    PTYPE_NOCALL,
    PTYPE_PING,
    PTYPE_REJECT,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
    PTYPE_WORKING,
    RECORD_SERVICES,
    RPC_PTYPE,
)
from pd_analyze.protocol import link, pnio_view, profidrive, rpc, rpc_calls, rpc_fragments
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol import pnio_checks as checks
from pd_analyze.protocol.frames import Accounting, FrameResult, Layer, Pdu, mark_checks
from pd_analyze.protocol.hold import HeldFrames
from pd_analyze.protocol.links import Links, Request
from pd_analyze.protocol.pnio_checks import CHECKED_FIELDS
from pd_analyze.protocol.profidrive_checks import Checker

DEFAULT_RPC_TIMEOUT = 5.0
MAX_LOOSE_FINDINGS = 100_000  # kept when nobody drains them (the dump lists them at the end)

# Frame outcomes beyond the link-layer skip reasons.
MALFORMED_RPC = "PNIO RPC PDU truncated or undecodable"


class Dissector:
    """State for one capture: IP and CL reassembly, open calls, the ordered output."""

    def __init__(self, annotate: bool = False, rpc_timeout: float = DEFAULT_RPC_TIMEOUT,
                 checker: Checker | None = None, pairing: bool = True, links: Links | None = None) -> None:
        self.annotate = annotate
        # links: the pairing told, not found (the dump of a file shows the report's, protocol.links): no
        # pairing of its own, and the results leave unmarked (the dump marks them with the report's findings)
        self.links = links
        pairing = pairing and links is None
        # pairing=False: a decoder of PDUs for the analysis engine, which pairs calls itself (one
        # implementation of protocol.md 2.4 and 7): no call table, responses decoded with their own opnum,
        # no check that compares a response with its request or its channel's last parameter request
        self.pairing = pairing
        self.force_opnum: int | None = None  # without pairing: decode responses as answers to this operation
        self.records = True  # False: the PROFIdrive records are not parsed (their checks are not wanted)
        self.rpc_timeout = rpc_timeout
        self.checker = checker or Checker.for_profile()
        self.records_not_profidrive = 0
        # the last parameter request per channel and its frame, to label the blocks of responses
        self._pd_requests: CappedTable[tuple, tuple[profidrive.Parsed | Unparsed, int]] = CappedTable(CHANNEL_REQUESTS)
        self.link = link.LinkDecoder()
        self.frags = rpc_fragments.FragmentTable()
        self.calls = rpc_calls.CallTable()
        self.accounting = Accounting()
        self.loose_findings: list[Finding] = []  # findings on frames that are not PNIO RPC
        self.loose_dropped = 0  # beyond MAX_LOOSE_FINDINGS
        self._activities: CappedTable[bytes, None] = CappedTable(KNOWN_ACTIVITIES)
        self.hold = HeldFrames(rpc_timeout) if annotate else None  # the dump's ordered output
        self._now = float("-inf")
        self._fragment_times: CappedTable[int, float] = CappedTable(IP_FRAGMENT_TIMES)  # by frame

    # --- the frame loop -------------------------------------------------------------------
    def feed(self, frame: capture.RawFrame) -> list[FrameResult]:
        self.accounting.read += 1
        number, ts, linktype, data = frame.number, frame.ts, frame.linktype, frame.data
        out: list[FrameResult] = []
        if ts > self._now:
            self._now = ts
            self._expire(out)  # deadlines passed before this frame arrived, whatever frame it is
        dgram = self.link.datagram(number, linktype, data)
        if self.link.findings:
            self.loose_findings += self.link.findings
            self.link.findings = []
        if dgram is link.SKIP_FRAGMENT:
            self._fragment_times.remember(number, ts)  # for timing the reassembled PDU from its first piece
        if isinstance(dgram, str):
            (self.accounting.malformed if dgram in link.MALFORMED else self.accounting.skipped)[dgram] += 1
        else:
            result = self._udp(number, ts, linktype, data, dgram)
            if result is not None:
                out.append(result)
        if len(self.loose_findings) > MAX_LOOSE_FINDINGS:
            self.loose_dropped += len(self.loose_findings) - MAX_LOOSE_FINDINGS
            del self.loose_findings[MAX_LOOSE_FINDINGS:]
        return self._leaving(self.hold.release(out, self._now)) if self.hold is not None else out

    def advance(self, now: float) -> None:
        """Capture time reached `now` on frames this dissector did not see (the report path): the calls
        due expire (their findings go with the loose ones)."""
        if now > self._now:
            self._now = now
            out: list[FrameResult] = []
            self._expire(out)

    # --- frames read by the column decode (dump -T fields): their state, not their tree -----------------
    def answered_as(self, key: tuple[bytes, int]) -> int | None:
        """The operation a response of call `key` would be decoded as now (its request's, protocol.md 2.4);
        None when it pairs no request (it is decoded with its own). The clock must stand at its time."""
        call = self.calls.open.get(key) or self.calls.closed.get(key)
        return call.opnum if call is not None else None

    def pass_pdu(self, number: int, ts: float, ptype: int, key: tuple[bytes, int], src: bytes, dst: bytes,
                 interface: bytes, opnum: int, body: bytes | memoryview, record_len: int = -1, channel: tuple = (),
                 request: Unparsed | None = None) -> list[FrameResult]:
        """A PNIO RPC request or response the column decode read whole and regular (no fragment, a record
        service, an ordinary stub), passed by without its tree: what `feed` leaves of it in the state (its
        activity, its call opened or answered, a parameter request remembered for its channel's responses:
        `channel` and `request`; `record_len`: the record its IOD header carries, -1 without a header), and
        the results the hold releases at its time. Its findings are not made."""
        self.accounting.read += 1
        out: list[FrameResult] = []
        if ts > self._now:
            self._now = ts
            self._expire(out)
        if self.pairing and key[0] not in self._activities:
            self.remember_activity(key[0])
        self.accounting.decoded += 1
        if ptype == PTYPE_REQUEST:
            call = rpc_calls.Call(number, ts, src, dst, interface, opnum, body)
            known = self.calls.request(key, call, [])
            if known is call:  # not a retransmission: the call keeps what was decoded of it (_data_pdu)
                blocks = [(record_len, request.footprint if request is not None else 0)] if record_len >= 0 else []
                self.calls.charge(key, call, _stub_cost(blocks), [])
            if request is not None and self.pairing:
                self._pd_requests.remember(channel, (request, number), request.footprint)
        else:
            self.frags.drop_call(key, number, [])
            answered = self.calls.close(key, ts)
            if answered is not None:
                answered.response_frame = number
                if self.hold is not None:
                    self.hold.link_response(answered.frame, number)
        if self.hold is None or not (out or self.hold.first_held()):  # nothing to release (most rows)
            return out
        return self._leaving(self.hold.release(out, self._now))

    def adopt_request(self, frame: capture.RawFrame) -> rpc_calls.Call | None:
        """Open the call of a request frame counted elsewhere (the columnar path hands its group over):
        the frame is dissected as usual, its accounting left as it was; `reorder` restores time order."""
        acc = self.accounting
        read, decoded = acc.read, acc.decoded
        self.feed(frame)
        acc.read, acc.decoded = read, decoded
        return next((c for c in self.calls.open.values() if c.frame == frame.number), None)

    def adopt_answered(self, key: tuple[bytes, int], call: rpc_calls.Call) -> None:
        """An answered call learnt elsewhere, remembered as the dissector's own (to spot late copies)."""
        self.calls.closed.remember(key, call)

    def adopt_channel_request(self, channel: tuple, parsed: profidrive.Parsed, frame: int) -> None:
        """A channel's last parameter request learnt elsewhere (to label and check a later response)."""
        self._pd_requests.remember(channel, (parsed, frame), profidrive.footprint(parsed))

    def busy_pairs(self) -> set[tuple[bytes, bytes]]:
        """Address pairs (source, destination) with something open here: calls, CL fragment sets, IP
        datagrams in reassembly."""
        out = {(call.src, call.dst) for call in self.calls.open.values()}
        out.update(self.frags.open_pairs())
        out.update(self.link.open_pairs())
        return out

    def channel_requests(self) -> Iterator[tuple[tuple, tuple[profidrive.Parsed, int]]]:
        """Each channel's last parameter request and its frame."""
        return iter(self._pd_requests.items())

    def reorder(self) -> None:
        """Open and answered calls back in time order (adopted ones came in late): expiry walks them oldest
        first."""
        for table, when in ((self.calls.open, lambda c: c.ts), (self.calls.closed, lambda c: c.answered)):
            for key, _call in sorted(table.items(), key=lambda item: when(item[1])):
                table.move_to_end(key)

    def open_frames(self) -> Iterator[int]:
        """Frames whose outcome is still open: unanswered calls, unfinished IP or CL reassemblies."""
        yield from self.calls.open_frames()
        yield from self.frags.open_frames()
        yield from self.link.open_frames()

    def finish(self, frames_read: int | None = None) -> list[FrameResult]:
        """End of capture: unfinished fragments, unanswered calls, everything still held. `frames_read`:
        the frames of the capture when this dissector did not read them all (the columnar path)."""
        last = self.accounting.read if frames_read is None else frames_read
        ends = self.link.finish()
        self.loose_findings += ends
        out: list[FrameResult] = []
        for f in self.frags.finish(last):
            self._attach(f, out)
        for key, call in list(self.calls.open.items()):
            self.calls.open.pop(key)
            self._unanswered(call, key, out, "end of capture")
        self.loose_findings += self.calls.finish()
        return self._leaving(self.hold.finish(out, self._now)) if self.hold is not None else out

    # --- UDP payload to PNIO RPC ------------------------------------------------------------
    def _udp(self, number: int, ts: float, linktype: int, data: bytes,
             dgram: link.Datagram) -> FrameResult | None:
        payload = dgram.payload
        if not rpc.plausible(payload):
            self._skip_udp(number, dgram, rpc.SKIP_NOT_RPC)
            return None
        hdr = rpc.header(payload)
        if not self._is_pnio(hdr):
            self._skip_udp(number, dgram, rpc.SKIP_NOT_PNIO)
            return None
        if self.pairing and hdr.activity not in self._activities:
            self.remember_activity(hdr.activity)
        res = FrameResult(number, ts, dgram.src, dgram.dst, "", hdr.ptype)
        if not self.pairing:
            res.decide = not rpc.is_pnio_uuid(hdr.interface) and hdr.ptype != PTYPE_REQUEST
            res.key = (hdr.activity, hdr.seq)
            res.truncated = dgram.truncated
        base = dgram.payload_offset if dgram.payload_offset >= 0 else 0
        if self.annotate:
            res.layers += [Layer(title, 0, fields) for title, fields in link.annotate(linktype, data, dgram)]
            layout = rpc.HEADER_LE if hdr.little else rpc.HEADER_BE
            res.layers.append(Layer(layout.title, 0, layout.annotate(payload, 0, hdr.values, base)))
        present = len(payload) - rpc.HEADER_SIZE
        body = payload[rpc.HEADER_SIZE:rpc.HEADER_SIZE + hdr.frag_len]
        record_service = hdr.opnum in RECORD_SERVICES
        res.findings += rpc.check_header(hdr, number, present, record_service)
        if present < hdr.frag_len:
            res.findings.append(finding("rpc_truncated", number, "rpc.frag_len", hdr.frag_len,
                                        f"<= {present}", f"fragment body cut: {present} of "
                                                         f"{hdr.frag_len} bytes present"))
            if dgram.truncated:
                res.findings.append(finding("truncated_capture_pnio", number, "frame.caplen", len(data),
                                            "the whole IP datagram", "capture cut inside a PNIO RPC PDU "
                                                                     "(snaplen)"))
            self.accounting.malformed[MALFORMED_RPC] += 1
            res.counted = MALFORMED_RPC
            if hdr.ptype in (PTYPE_REQUEST, PTYPE_RESPONSE) and not hdr.flags1 & FLAG1_FRAG:
                # decode what is present, so the transaction it belongs to is known (and malformed)
                self._data_pdu(res, hdr, dgram, body, base + rpc.HEADER_SIZE)
                res.summary += " [truncated]"
                self._answered_in(res, hdr)
            else:
                res.summary = f"{_pdu_name(hdr)} [truncated]"
            if res.pdu is None:
                res.pdu = self._bare_pdu(number, ts, dgram, hdr)
                res.pdu.unpaired = True
            res.pdu.malformed = True
            return res
        self.accounting.decoded += 1
        if hdr.ptype in (PTYPE_REQUEST, PTYPE_RESPONSE):
            self._data_pdu(res, hdr, dgram, body, base + rpc.HEADER_SIZE)
            self._answered_in(res, hdr)
        elif hdr.ptype in (PTYPE_FAULT, PTYPE_REJECT):
            self._fault(res, hdr, dgram, body, base + rpc.HEADER_SIZE)
        else:
            self._control(res, hdr, dgram)
        return res

    def _answered_in(self, res: FrameResult, hdr: rpc.Header) -> None:
        """With links: a request's forward link to its answer, after its layers (where the hold puts it)."""
        if self.links is not None and hdr.ptype == PTYPE_REQUEST and res.pdu is not None:
            self.links.request_seen(res)
            answer = self.links.answer(res.frame)
            if answer:
                res.layers.append(Layer("Call", 0, [derived("rpc.response_frame", answer)]))

    def _skip_udp(self, number: int, dgram: link.Datagram, reason: str) -> None:
        self.accounting.skipped[reason] += 1
        if dgram.truncated:
            self.loose_findings.append(truncated_elsewhere(number))

    def _is_pnio(self, hdr: rpc.Header) -> bool:
        if rpc.is_pnio_uuid(hdr.interface):
            return True
        if not self.pairing:  # PNIO if its call or activity is: the engine decides (FrameResult.decide)
            return hdr.ptype != PTYPE_REQUEST
        if hdr.ptype in (PTYPE_RESPONSE, PTYPE_FAULT, PTYPE_REJECT, PTYPE_WORKING, PTYPE_NOCALL):
            key = (hdr.activity, hdr.seq)
            return key in self.calls.open or key in self.calls.closed
        return hdr.ptype != PTYPE_REQUEST and hdr.activity in self._activities

    def remember_activity(self, activity: bytes) -> None:
        """An activity of a PNIO call (also one seen elsewhere, by the columnar path): a later ping or
        acknowledgement of it is PNIO too."""
        if activity not in self._activities:
            self._activities.remember(activity, None)

    def _bare_pdu(self, number: int, ts: float, dgram: link.Datagram, hdr: rpc.Header,
                  malformed: bool = False) -> Pdu:
        return Pdu(number, ts, dgram.src, dgram.dst, dgram.sport, dgram.dport, hdr.ptype, hdr.opnum,
                   hdr.activity, hdr.seq, malformed=malformed, interface=hdr.interface)

    # --- requests and responses -------------------------------------------------------------
    def _data_pdu(self, res: FrameResult, hdr: rpc.Header, dgram: link.Datagram, body: bytes,
                  body_base: int) -> None:
        number = res.frame
        key = (hdr.activity, hdr.seq)
        response = hdr.ptype == PTYPE_RESPONSE
        stub_base = body_base
        frames: tuple[int, ...] = ()
        whole_ts = None
        if hdr.flags1 & FLAG1_FRAG:
            fkey = (hdr.activity, hdr.seq, hdr.ptype, dgram.src, dgram.dst)
            if self.frags.seen(fkey, hdr.frag_num, body):
                call = self.calls.open.get(key)
                if call is not None and not response:
                    call.copies += 1
                if not response:
                    res.fragment_copy = key
                res.findings.append(finding("rpc_retransmission", number, "rpc.frag_num", hdr.frag_num,
                                            "a new fragment", "fragment retransmitted (identical copy)"))
                res.summary = f"{_pdu_name(hdr)}, fragment {hdr.frag_num} [retransmission]"
                done = self.frags.reassembled_in(fkey)
                if self.hold is not None and done:
                    res.layers.append(Layer("Fragment", 0, [derived("rpc.reassembled_in", done)]))
                return
            whole = self.frags.add(fkey, number, res.ts, hdr, body, res.findings)
            if self.hold is not None:
                self.hold.link_fragment(fkey, number)
            if whole is None:
                res.summary = f"{_pdu_name(hdr)}, fragment {hdr.frag_num} ({len(body)} bytes)"
                if self.hold is not None:
                    self.hold.wait(res)
                return
            body, frames, stub_base, whole_ts = whole.body, whole.frames, 0, whole.first_ts
            if self.hold is not None:
                self.hold.link_reassembled(fkey, number)
                res.layers.append(Layer(f"Reassembled body: {len(body)} bytes from {len(frames)} fragments",
                                        0, [derived("rpc.fragments", frames)]))
        pdu = self._bare_pdu(number, res.ts, dgram, hdr)
        res.pdu = pdu
        if frames or dgram.fragments:
            self._first_frame(pdu, dgram, frames, whole_ts if frames else None)
        linked = None
        if not self.pairing:
            pdu.digest = (zlib.crc32(body), len(body))
            if response:
                self.frags.drop_call(key, res.frame, res.findings)
                linked = self._request_link(res) if self.links is not None else None
            elif hdr.opnum in RECORD_SERVICES and hdr.interface[3] != 1:
                res.findings.append(_other_interface(hdr, res.frame))
        elif response:
            self._response(res, hdr, dgram, key, body, pdu)
        else:
            self._request(res, hdr, dgram, key, body, pdu)
        if hdr.values[rpc.I_AUTH]:
            res.summary = f"{_pdu_name(hdr)} [authenticated, body not decoded]"
            return
        # a response is decoded as an answer to its request's operation (R4 reports a differing opnum)
        opnum = pdu.request.opnum if response and pdu.request is not None else hdr.opnum
        if response and self.force_opnum is not None:
            opnum = self.force_opnum
        if linked is not None:
            opnum = linked.opnum
        pdu.opnum = opnum
        stub = rec.parse_stub(body, hdr.little, response, opnum, number, res.findings)
        pdu.stub = stub
        pdu.malformed = stub.truncated or checks.header_undecodable(stub, opnum)  # protocol.md 7.4 rule 1
        request_stub = pdu.request.info if pdu.request is not None and isinstance(pdu.request.info, rec.Stub) else None
        if not response and not pdu.retransmission and pdu.request is not None:
            pdu.request.info = stub
        declared = len(body) if frames else hdr.frag_len  # a cut PDU keeps its declared length
        res.findings += checks.ndr(stub, declared, opnum, number, request_stub)
        res.findings += checks.blocks(stub, opnum, number, request_stub, self.checker.record.max_length,
                                      self.checker.tolerate)
        self._records(res, stub, hdr, dgram)
        if not response and not pdu.retransmission and pdu.request is not None:
            self.calls.charge(key, pdu.request, _decoded_cost(stub), res.findings)  # info keeps the stub
        if self.annotate:
            res.summary = pnio_view.pdu_summary(hdr.ptype, hdr.seq, stub, len(frames), opnum)
            res.layers += pnio_view.stub_layers(stub, body, stub_base, opnum, response, self.checker)

    def _request_link(self, res: FrameResult) -> Request | None:
        """With links: the request an answer answers, as the report pairs it (its Call layer added)."""
        request = self.links.request(res.frame)  # type: ignore[union-attr]
        if request is not None:
            res.layers.append(Layer("Call", 0, [derived("rpc.request_frame", request.frame),
                                                derived("rpc.rtt", round(res.ts - request.ts, 9))]))
        return request

    def _first_frame(self, pdu: Pdu, dgram: link.Datagram, cl_frames: tuple[int, ...],
                     cl_first_ts: float | None) -> None:
        """The frames a reassembled PDU came in, and the time of its first (IP or CL fragments)."""
        pieces = set(cl_frames) | set(dgram.fragments)
        pdu.fragments = tuple(sorted(pieces))
        times = [self._fragment_times.pop(n) for n in dgram.fragments if n in self._fragment_times]
        if cl_first_ts is not None:
            times.append(cl_first_ts)
        pdu.first_ts = min(times, default=pdu.ts)

    def _request(self, res: FrameResult, hdr: rpc.Header, dgram: link.Datagram, key: tuple,
                 body: bytes, pdu: Pdu) -> None:
        call = rpc_calls.Call(res.frame, res.ts, dgram.src, dgram.dst, hdr.interface, hdr.opnum, body)
        known = self.calls.request(key, call, res.findings)
        if known is not call:
            pdu.retransmission = True
        pdu.request = known
        if hdr.opnum in RECORD_SERVICES and hdr.interface[3] != 1:
            res.findings.append(_other_interface(hdr, res.frame))
        if self.hold is not None and known is call:
            self.hold.wait(res)

    def _response(self, res: FrameResult, hdr: rpc.Header, dgram: link.Datagram, key: tuple,
                  body: bytes, pdu: Pdu) -> None:
        self.frags.drop_call(key, res.frame, res.findings)
        call = self.calls.close(key, res.ts)
        if call is None:
            dup = self.calls.closed.get(key)
            if dup is not None:
                res.findings.append(finding("rpc_retransmission", res.frame, "rpc.seq", hdr.seq,
                                            "one response per call", f"duplicate response (call of "
                                                                     f"frame {dup.frame} already answered)"))
                pdu.retransmission = True
                pdu.request = dup
            else:
                res.findings.append(finding("orphan_response", res.frame, "rpc.seq", hdr.seq,
                                            "an open request", "response without an open request "
                                                               "(decoded with its own opnum)"))
            return
        pdu.request = call
        call.response_frame = res.frame
        res.findings += rpc.check_response(call, hdr, dgram.src, dgram.dst, res.frame)
        if self.hold is not None:
            res.layers.append(Layer("Call", 0, [derived("rpc.request_frame", call.frame),
                                                derived("rpc.rtt", round(res.ts - call.ts, 9))]))
            self.hold.link_response(call.frame, res.frame)

    def _fault(self, res: FrameResult, hdr: rpc.Header, dgram: link.Datagram, body: bytes,
               body_base: int) -> None:
        layout = rpc.FAULT_LE if hdr.little else rpc.FAULT_BE
        key = (hdr.activity, hdr.seq)
        pdu = self._bare_pdu(res.frame, res.ts, dgram, hdr)
        res.pdu = pdu
        status = layout.unpack(body)[0] if len(body) >= 4 else None
        pdu.fault_status = status
        call = self.calls.close(key, res.ts) if self.pairing else None
        pdu.request = call
        name = RPC_PTYPE[hdr.ptype]
        text = f"{status:#010x} {NCA_STATUS.get(status, '')}".strip() if status is not None else "no status"
        res.summary = f"{name.capitalize()}: seq {hdr.seq}, {text}"
        res.findings.append(finding("rpc_fault", res.frame, "rpc.fault_status", text, "a response",
                                    f"call answered with {name} {text}"))
        if call is not None:
            self.frags.drop_call(key, res.frame, res.findings)
            if self.hold is not None:
                self.hold.link_response(call.frame, res.frame)
        if self.annotate:
            fields = layout.annotate(body, 0, (status,), body_base) if status is not None else []
            told = self.links.request(res.frame) if self.links is not None else None
            if call is not None or told is not None:
                frame, ts = (call.frame, call.ts) if call is not None else (told.frame, told.ts)  # type: ignore[union-attr]
                fields += [derived("rpc.request_frame", frame), derived("rpc.rtt", round(res.ts - ts, 9))]
            res.layers.append(Layer(f"{name.capitalize()} body", 0, fields))

    def _control(self, res: FrameResult, hdr: rpc.Header, dgram: link.Datagram) -> None:
        key = (hdr.activity, hdr.seq)
        call = self.calls.open.get(key) if self.pairing else None
        name = RPC_PTYPE[hdr.ptype]
        res.summary = f"{name.capitalize()}: seq {hdr.seq}"
        if hdr.ptype == PTYPE_WORKING and call is not None:
            call.working += 1
        elif hdr.ptype == PTYPE_PING and call is not None:
            call.pings += 1
        elif hdr.ptype == PTYPE_NOCALL:
            res.findings.append(finding("rpc_nocall", res.frame, "rpc.seq", hdr.seq, "a known call",
                                        "server answered nocall: it has no record of the call"))
        elif hdr.ptype == PTYPE_CANCEL:
            res.findings.append(finding("rpc_cancel", res.frame, "rpc.seq", hdr.seq, "", "client cancelled the call"))
        if call is not None:
            res.summary += f" (call of frame {call.frame})"
        elif self.links is not None:
            request = self.links.open_call(hdr.activity, hdr.seq, res.frame, res.ts)
            if request:
                res.summary += f" (call of frame {request})"
        del dgram

    # --- records ----------------------------------------------------------------------------
    def _records(self, res: FrameResult, stub: rec.Stub, hdr: rpc.Header, dgram: link.Datagram) -> None:
        """PROFIdrive records at 0xB02E/0xB02F/0x002F are decoded and checked; others only counted."""
        response = hdr.ptype == PTYPE_RESPONSE
        number = res.frame
        for block in stub.blocks:
            if block.index not in PROFIDRIVE_INDICES:
                if block.layout in (rec.WRITE_REQ, rec.READ_RES) and block.index != INDEX_WRITE_MULTIPLE:
                    self.records_not_profidrive += 1
                continue
            v = block.values
            if not response:
                res.findings += self.checker.iod(v[rec.B_API], v[rec.B_SLOT], v[rec.B_SUBSLOT], block.index, number)
            if not self.records:  # the IOD fields' limits (P4) only: the record's checks are not wanted
                continue
            if block.layout not in (rec.WRITE_REQ, rec.READ_RES) or len(block.record) < block.record_len:
                continue
            if response and stub.status is not None and not stub.status.ok:
                continue
            max_params = self.checker.record.max_params
            if block.index == INDEX_PD_DPV1 and not profidrive.plausible(block.record, response, max_params,
                                                                                       self.checker.ids):
                res.findings.append(finding("not_profidrive", number, "iod.index", "0x002f",
                                            "a plausible PROFIdrive header", "record at index 0x002F is not a "
                                                                             "PROFIdrive parameter block"))
                self.records_not_profidrive += 1
                continue
            key = _channel(dgram, v, block.target_ar, response)
            if response:
                request, request_frame = self._pd_requests.get(key, (None, 0)) if self.pairing else (None, 0)
                if isinstance(request, Unparsed):  # passed by: parsed as feed parses a request
                    request = profidrive.parse_request(request.record, request_frame, [], self.checker.ids)
                if self.links is not None:
                    told = self.links.parameter_request(number, block)
                    request_frame, request = told if told is not None else (0, None)
                parsed = profidrive.parse_response(block.record, number, res.findings, self.checker.ids)
                res.findings += self.checker.response(parsed, number, request)
                block.pd = (parsed, request)
                if self.annotate and request_frame:
                    res.layers.append(Layer("Parameter access", 0, [derived("pd.request_frame", request_frame)]))
            else:
                parsed = profidrive.parse_request(block.record, number, res.findings, self.checker.ids)
                res.findings += self.checker.request(parsed, number)
                block.pd = (parsed, None)
                if self.pairing:
                    self._remember_request(key, parsed, number)

    def _remember_request(self, key: tuple, parsed: profidrive.Parsed, number: int) -> None:
        """The channel's last parameter request, within the CHANNEL_REQUESTS caps (the oldest go)."""
        self._pd_requests.remember(key, (parsed, number), profidrive.footprint(parsed))

    # --- findings discovered later, unanswered calls -----------------------------------------
    def _attach(self, f: Finding, out: list[FrameResult]) -> None:
        """A finding discovered later for an earlier frame: on its held result, else loose."""
        held = self.hold.find(f.frame) if self.hold is not None else None
        (held.findings if held is not None else self.loose_findings).append(f)

    def _unanswered(self, call: rpc_calls.Call, key: tuple, out: list[FrameResult], why: str) -> None:
        self._attach(rpc_calls.unanswered_finding(call.frame, key[1], self.rpc_timeout, why), out)

    def _expire(self, out: list[FrameResult]) -> None:
        for key, call in self.calls.expire(self._now, self.rpc_timeout):
            self._unanswered(call, key, out, rpc_calls.NO_RESPONSE)

    def _leaving(self, results: list[FrameResult]) -> list[FrameResult]:
        """Annotated results as they leave: every field's check says ok or names its finding (with links, the
        dump marks them with the report's findings instead)."""
        if self.links is None:
            for res in results:
                mark_checks(res, CHECKED_FIELDS)
        return results


def truncated_elsewhere(frame: int) -> Finding:
    """L1 info: a frame cut by the snaplen outside a PNIO RPC PDU."""
    return finding("truncated_capture", frame, "frame.caplen", "", "",
                   "frame captured shorter than its IP total length")


def _other_interface(hdr: rpc.Header, frame: int) -> Finding:
    return finding("pnio_interface", frame, "rpc.interface", hdr.interface.hex(), "PNIO Device interface",
                   "Read/Write on a PNIO interface other than Device")


def _decoded_cost(stub: rec.Stub) -> int:
    """Bytes a request's decoded stub keeps alive in its open call: blocks, records, parsed PROFIdrive."""
    return _stub_cost([(len(block.record), profidrive.footprint(block.pd[0]) if isinstance(block.pd, tuple) else 0)
                       for block in stub.blocks])


def _stub_cost(blocks: list[tuple[int, int]]) -> int:
    """_decoded_cost of a stub of these blocks: each one's record length and its PROFIdrive parse's footprint
    (0 when none)."""
    return 256 + sum(512 + record_len + footprint for record_len, footprint in blocks)


class Unparsed(NamedTuple):
    """A parameter request passed by (Dissector.pass_pdu): its record, parsed when a response on its channel
    asks, and the footprint its parse has (profidrive.footprint, known beforehand from the columns)."""

    record: bytes
    footprint: int


def _channel(dgram: link.Datagram, v: tuple, target_ar: bytes, response: bool) -> tuple:
    """Device, controller, AR (TargetAR for implicit reads), API, slot, subslot, index (protocol.md 7.2)."""
    device, controller = (dgram.src, dgram.dst) if response else (dgram.dst, dgram.src)
    ar = target_ar if v[rec.B_AR] == rec.NIL_UUID and target_ar else v[rec.B_AR]
    return device, controller, ar, v[rec.B_API], v[rec.B_SLOT], v[rec.B_SUBSLOT], v[rec.B_INDEX]


def _pdu_name(hdr: rpc.Header) -> str:
    op = PNIO_OPNUM.get(hdr.opnum, f"opnum {hdr.opnum}")
    return f"{op} {RPC_PTYPE.get(hdr.ptype, str(hdr.ptype))}, seq {hdr.seq}"


def dissect(path: str, annotate: bool = False, rpc_timeout: float = DEFAULT_RPC_TIMEOUT,
            dissector: Dissector | None = None) -> Iterator[FrameResult]:
    """Every PNIO RPC frame of a capture, in frame order. CaptureError after the good frames."""
    return dissect_frames(capture.frames(path, ip_only=True), dissector or Dissector(annotate, rpc_timeout))


def dissect_frames(frames: Iterable[capture.RawFrame], d: Dissector) -> Iterator[FrameResult]:
    """The frame loop over any frame source (one file, or a chain of files numbered as one)."""
    accounting, not_ip = d.accounting, d.accounting.skipped
    try:
        for frame in frames:
            # Most of a PROFINET capture is cyclic PN-RT, LLDP, ARP...: an Ethernet frame that carries
            # no IPv4 (tagged or not) is counted here without a call (or by the reader, as a run of
            # them, timed at its last frame); the result is the same as feed's, its time included.
            if frame.run:
                accounting.read += frame.run
                not_ip[link.SKIP_NOT_IPV4] += frame.run
                d.advance(frame.ts)
                continue
            if frame.linktype == LINKTYPE_ETHERNET and frame.data[12:14] not in IP_ETHERTYPES:
                accounting.read += 1
                not_ip[link.SKIP_NOT_IPV4] += 1
                d.advance(frame.ts)
                continue
            yield from d.feed(frame)
    except capture.CaptureError:
        yield from d.finish()  # the frames before the damage are complete results
        raise
    yield from d.finish()

"""A large mixed PROFIdrive capture for benchmarks and scale tests, generated deterministically.

Eight drives answer reads, changes, multi-parameter requests and NAKs with some B5 polling, among
cyclic PN-RT frames and other UDP traffic; frames are written as they are made (bounded memory).
"""

from __future__ import annotations

import random
import struct
from pathlib import Path

from . import net_encode
from .fixtures import pn_rt, session
from .pd_encode import ParamAddress as P
from .pd_encode import change_ok, change_request, error_block, pd_response, read_request, value_block
from .pnio_session import PnioSession
from .sim_capture import Capture


def make_capture(path: Path, frames: int, seed: int = 1, pnio_share: float = 0.1, faults: float = 0.0) -> int:
    """A mixed capture of about `frames` frames; returns the exact count.

    `pnio_share` is the fraction of frames that are PNIO RPC: cyclic PN-RT IO data dominates a real
    PROFINET capture (each drive exchanges a frame per cycle in each direction), so 0.1 stands for
    a commissioning tool polling parameters busily; 0.5 is a parameter-access-only trace.
    `faults` is the share of transactions that go wrong: never answered (a timeout, superseded by the
    next write), a write or read refused with an error PNIOStatus, a read answered by an RPC fault, a
    write request left without its RPC response, a retry with the same Request Reference."""
    rng = random.Random(seed)
    cap = Capture()
    sessions = [session(cap, n) for n in range(1, 9)]
    refs = [0] * len(sessions)
    written = 0
    with path.open("wb") as out:
        out.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, 1))
        while written < frames:
            n = rng.randrange(len(sessions))
            s = sessions[n]
            if not (faults and rng.random() < faults and _fault(s, refs[n], rng)):
                refs[n] = refs[n] % 255 + 1
                _transaction(s, refs[n], rng)
            pnio = len(cap.frames)
            cyclic = round(pnio * (1 - pnio_share) / pnio_share * rng.uniform(0.5, 1.5))
            for k in range(cyclic):  # cyclic IO data between parameter accesses, both directions
                other = sessions[k % len(sessions)]
                src, dst = (other.device, other.controller) if k & 1 else (other.controller, other.device)
                pn_rt(cap, src, dst, (written + k) & 0xFFFF)
            if rng.random() < 0.1:
                cap.send_ip(s.controller, s.device, net_encode.udp(50010, 50020, bytes(64)))
            for f in cap.frames:
                sec, ns = divmod(f.ts_ns, 1_000_000_000)
                out.write(struct.pack("<IIII", sec, ns // 1000, len(f.data), len(f.data)) + f.data)
            written += len(cap.frames)
            cap.frames.clear()
    return written


_WRITE_ERROR = bytes.fromhex("df80b000")  # IODWriteRes, PNIORW, invalid index
_READ_ERROR = bytes.fromhex("de80a000")  # IODReadRes, PNIORW, application read error
_FAULT = (3, 0x1C010003)  # an RPC fault PDU: nca_s_fault_... (protocol.md 2.1)


def _fault(s: PnioSession, ref: int, rng: random.Random) -> bool:
    """One transaction that goes wrong (the Request Reference of the last one: a retry, or a reuse); False
    when the kind drawn needs a reference of its own (the caller then makes an ordinary one)."""
    kind = rng.randrange(6)
    req = read_request(ref, 1, [P(rng.randrange(1, 3000))])
    res = pd_response(ref, 1, 1, [value_block(0x42, [rng.randrange(65536)])])
    if kind == 0:  # the drive stays busy: B5 until the controller gives up (the next write supersedes it)
        s.parameter_access(req, None, b5_retries=rng.randrange(1, 4))
    elif kind == 1:
        s.parameter_access(req, res, write_status=_WRITE_ERROR)
    elif kind == 2:
        s.parameter_access(req, res, b5_retries=rng.randrange(2), read_status=_READ_ERROR)
    elif kind == 3:
        s.parameter_access(req, res, read_fault=_FAULT)
    elif kind == 4:
        s.write(0xB02E, req, respond=False)
    else:
        return False
    return True


def _transaction(s: PnioSession, ref: int, rng: random.Random) -> None:
    kind = rng.random()
    b5 = rng.choice((0, 0, 0, 1, 1, 2, 3))
    if kind < 0.55:
        req = read_request(ref, 1, [P(rng.randrange(1, 3000))])
        res = pd_response(ref, 1, 1, [value_block(0x42, [rng.randrange(65536)])])
    elif kind < 0.7:
        addrs = [P(964), P(2000, n_elems=3), P(107, n_elems=3)]
        req = read_request(ref, 1, addrs)
        res = pd_response(ref, 1, 1, [value_block(0x08, [1.5]), value_block(0x43, [1, 2, 3]),
                                      value_block(0x05, [1, 2, 3])])
    elif kind < 0.9:
        req = change_request(ref, 1, [(P(1120), value_block(0x08, [rng.random() * 100]))])
        res = change_ok(ref, 1, 1)
    else:
        req = read_request(ref, 1, [P(rng.randrange(1, 3000)), P(5)])
        res = pd_response(ref, 0x81, 1, [value_block(0x06, [1]), error_block(0x00)])
    s.parameter_access(req, res, b5_retries=b5)



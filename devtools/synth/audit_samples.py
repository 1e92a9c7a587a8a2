"""Commissioning-audit samples (issue "Audit a commissioning"): a commissioning of two drives with the set of
parameters it was meant to leave, and a later recommissioning of the first drive with known differences.

- `audit_commissioning.pcap`: drive .21 (session 1) gets Float32, Integer16, an Unsigned8 array, a
  VisibleString; a 0x82 negative response confirms P1121 (Zero block) while refusing P1300 (error 0x02),
  whose second write is refused again; everything written is read back. Drive .22 (session 2) gets P1120.
  Last, drive .21 answers a PN-DCP Identify with its station name "pump-1".
- `audit_commissioning.csv` (in sets/): the intended set the capture meets exactly (a `*` line for P1120,
  the rest for .21; P1300 is not in it).
- `audit_recommissioning.pcap`: drive .21 again: P1120 12.0 (not 10.0), P730[1] 1 (not 0), P2900 "Pump2",
  P1300 accepted this time, P1121 not touched, P1000 as before; drive .22 absent.

Conventions as pd_samples.py: API 0x3A00, slot 1/1, Index 0xB02E, DO 1, references counting up.
"""

from __future__ import annotations

from .catalog import STATIC_EXPECTED, Built, intent_of, parameter_set, sample
from .expect import Intent
from .fixtures import ok_read, pcap_of, plant, session
from .net_encode import ETH_PNRT
from .pd_encode import ParamAddress as P
from .pd_encode import change_ok, change_request, error_block, pd_response, read_request, value_block, zero_block
from .sim_capture import Capture

RES_CHANGE_NAK = 0x82
DCP_IDENTIFY_RESPONSE = 0xFEFF  # FrameID


def dcp_identify_response(ip: str, name: str, xid: int) -> bytes:
    """A PN-DCP Identify response (ServiceID 5, ServiceType 1 success) with the IP parameter and NameOfStation
    blocks (each: Option, Suboption, DCPBlockLength, BlockInfo, value; padded to an even length)."""

    def block(option: int, sub: int, value: bytes) -> bytes:
        body = (0).to_bytes(2, "big") + value  # BlockInfo 0
        return bytes([option, sub]) + len(body).to_bytes(2, "big") + body + bytes(len(body) & 1)

    addr = bytes(int(x) for x in ip.split("."))
    blocks = block(1, 2, addr + bytes([255, 255, 255, 0]) + bytes(4)) + block(2, 2, name.encode())
    return (DCP_IDENTIFY_RESPONSE.to_bytes(2, "big") + bytes([5, 1]) + xid.to_bytes(4, "big") + bytes(2)
            + len(blocks).to_bytes(2, "big") + blocks)
F32, I16, U8, U16, VSTR = 0x08, 0x03, 0x05, 0x06, 0x09


@intent_of("audit_commissioning.pcap")
def audit_commissioning_capture() -> Built:
    """Two drives commissioned; one parameter refused twice, one confirmed inside a 0x82."""
    cap = Capture()
    s1 = session(cap, 1, rtt_us=900, gap_us=600)
    s2 = session(cap, 2, rtt_us=900, gap_us=600)
    x = Intent(cap)

    # ref 1 (.21): the main change: Float32, Integer16, Unsigned8 x 3 (+ pad), VisibleString x 5 (+ final pad)
    items = [(P(1120), value_block(F32, [10.0])), (P(1000), value_block(I16, [-300])),
             (P(730, n_elems=3), value_block(U8, [1, 0, 1])), (P(2900, n_elems=5), value_block(VSTR, "Pump1"))]
    x.txn(s1.parameter_access(change_request(1, 1, items), change_ok(1, 1, 4)), 1, "ok", "change 4 parameters")

    # ref 2 (.21): 0x82: P1121 written (Zero block), P1300 refused (0x02 low or high limit exceeded)
    items = [(P(1121), value_block(F32, [0.1])), (P(1300), value_block(U16, [7]))]
    res = pd_response(2, RES_CHANGE_NAK, 1, [zero_block(), error_block(0x02, 0)], n_params=2)
    x.txn(s1.parameter_access(change_request(2, 1, items), res), 2, "nak", "0x82: P1121 ok, P1300 0x02")

    # ref 3 (.21): P1300 again, refused again
    res = pd_response(3, RES_CHANGE_NAK, 1, [error_block(0x02, 0)], n_params=1)
    x.txn(s1.parameter_access(change_request(3, 1, [(P(1300), value_block(U16, [7]))]), res), 3, "nak",
          "P1300 refused again")  # fmt: skip

    # ref 4 (.21): read everything back
    back = [(P(1120), value_block(F32, [10.0])), (P(1000), value_block(I16, [-300])),
            (P(730, n_elems=3), value_block(U8, [1, 0, 1])), (P(2900, n_elems=5), value_block(VSTR, "Pump1")),
            (P(1121), value_block(F32, [0.1]))]
    x.txn(s1.parameter_access(read_request(4, 1, [a for a, _ in back]), ok_read(4, 1, [b for _, b in back])), 4,
          "ok", "read back")  # fmt: skip

    # ref 5, 6 (.22): P1120 written and read back
    req = change_request(5, 1, [(P(1120), value_block(F32, [10.0]))])
    x.txn(s2.parameter_access(req, change_ok(5, 1, 1)), 5, "ok", "second drive: change P1120")
    x.txn(s2.parameter_access(read_request(6, 1, [P(1120)]), ok_read(6, 1, [value_block(F32, [10.0])])), 6, "ok",
          "second drive: read back")  # fmt: skip

    # frame 25: drive .21 answers a DCP Identify with its station name (drive .22 announces none)
    ctrl, dev = plant(1)
    cap.send_ether(dev, ctrl.mac, ETH_PNRT, dcp_identify_response(dev.ip, "pump-1", 0x1001))
    return cap, x


sample("audit_commissioning.pcap")(lambda: pcap_of(audit_commissioning_capture()[0]))
STATIC_EXPECTED["audit_commissioning.pcap"] = []  # clean: the audit is of the values, not of the protocol


# The intended set audit_commissioning.pcap meets: no expect_* finding, audit exits 0.
AUDIT_SET = """\
# Intended parameter set of audit_commissioning.pcap (pd-analyze audit --expect)
device,do,pnu,subindex,value,tolerance
*,1,1120,0,10.0,
192.168.1.21,1,1000,0,-300,
192.168.1.21,1,730,0,1,
192.168.1.21,1,730,1,0,
192.168.1.21,1,730,2,1,
192.168.1.21,1,2900,0,Pump1,
192.168.1.21,1,1121,0,0.1,
"""


@parameter_set("audit_commissioning.csv")
def audit_commissioning_set() -> bytes:
    return AUDIT_SET.encode()


@intent_of("audit_recommissioning.pcap")
def audit_recommissioning_capture() -> Built:
    """Drive .21 recommissioned with known differences from audit_commissioning.pcap."""
    cap = Capture()
    s1 = session(cap, 1, rtt_us=900, gap_us=600)
    x = Intent(cap)

    items = [(P(1120), value_block(F32, [12.0])), (P(1000), value_block(I16, [-300])),
             (P(730, n_elems=3), value_block(U8, [1, 1, 1])), (P(2900, n_elems=5), value_block(VSTR, "Pump2")),
             (P(1300), value_block(U16, [7]))]
    x.txn(s1.parameter_access(change_request(1, 1, items), change_ok(1, 1, 5)), 1, "ok", "change 5 parameters")
    back = [(P(1120), value_block(F32, [12.0])), (P(730, n_elems=3), value_block(U8, [1, 1, 1]))]
    x.txn(s1.parameter_access(read_request(2, 1, [a for a, _ in back]), ok_read(2, 1, [b for _, b in back])), 2,
          "ok", "read back")  # fmt: skip
    return cap, x


sample("audit_recommissioning.pcap")(lambda: pcap_of(audit_recommissioning_capture()[0]))
STATIC_EXPECTED["audit_recommissioning.pcap"] = []

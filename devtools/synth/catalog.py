"""The registries of the sample generator: which files exist and what each is built to contain.

- `SAMPLES` (`@sample(name)`): every file of sample_pcaps/ and the function that builds its bytes,
  in registration order;
- `INTENTS` (`@intent_of(*names)`): for the older files, the builder of the transactions a file is
  built to contain; `STATIC_EXPECTED`: their frame-level findings, as sample_pcaps/README.md states them;
- `EXPECTED` (`@pd_sample(name)`): for the PROFIdrive and transaction samples, whose builders return
  (capture, Intent), the whole expectation; `pd_sample` registers the file in `SAMPLES` as well.

The sample modules fill these when imported; build.py imports them all.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .expect import Intent
from .fixtures import pcap_of
from .sim_capture import Capture

Built = tuple[Capture, Intent]


@dataclass(frozen=True)
class Sample:
    name: str
    build: Callable[[], bytes]


SAMPLES: list[Sample] = []


def sample(name: str) -> Callable[[Callable[[], bytes]], Callable[[], bytes]]:
    def register(fn: Callable[[], bytes]) -> Callable[[], bytes]:
        SAMPLES.append(Sample(name, fn))
        return fn

    return register


# sample_pcaps/sets/<name>: intended parameter sets (pd-analyze audit --expect) of the samples, as bytes
PARAMETER_SETS: dict[str, Callable[[], bytes]] = {}


def parameter_set(name: str) -> Callable[[Callable[[], bytes]], Callable[[], bytes]]:
    """Register the builder of an intended parameter set (sample_pcaps/sets/<name>)."""

    def register(fn: Callable[[], bytes]) -> Callable[[], bytes]:
        PARAMETER_SETS[name] = fn
        return fn

    return register


# file name -> the transactions the file is built to contain (the README's description of the file, recorded
# by its builder); the frame-level findings of these files are STATIC_EXPECTED below.
INTENTS: dict[str, Callable[[], Intent]] = {}


def intent_of(*names: str) -> Callable[[Callable[..., Built]], Callable[..., Built]]:
    """Register a builder returning (capture, intent) as the transaction intent of the files named."""

    def register(build: Callable[..., Built]) -> Callable[..., Built]:
        for name in names:
            INTENTS[name] = lambda: build()[1]
        return build

    return register


# The frame-level findings of the older files, as sample_pcaps/README.md states them (frame numbers are the
# README's). Clean files expect no finding; the pd_*.pcap files record theirs while they are built (EXPECTED).
STATIC_EXPECTED: dict[str, list[tuple[int, str]]] = {
    "worked_example.pcap": [],
    "record_rw_le.pcap": [],
    "record_rw_be.pcap": [],
    "record_rw_le.pcap.gz": [],
    "vlan_stacked.pcap": [],
    "ip_fragments.pcap": [],
    "cl_fragments_fack.pcapng": [(6, "rpc_retransmission")],  # frag 1 again, identical: dropped and counted
    "implicit_read.pcap": [],
    "write_multiple.pcap": [],
    "other_port_response.pcap": [(6, "rpc_retransmission")],  # identical request 100 ms later
    "two_interfaces.pcapng": [],
    "gzip_pcapng_named.pcap": [],
    "linux_sll.pcap": [],
    "linux_sll2.pcap": [],
    "raw_ipv4.pcap": [],
    "pcap_nsec_be.pcap": [],
    "rpc_control_pdus.pcap": [
        (14, "rpc_nocall"),  # nocall: W on the call
        (15, "rpc_retransmission"),  # identical request again
        (17, "pnio_interface"),  # Read to the Supervisor interface: I
        (18, "rpc_fault"),  # fault 0x1C010003
        (20, "rpc_fault"),  # reject 0x1C010002
        (22, "rpc_cancel"),  # cl_cancel: I on the call
        (24, "rpc_fault"),  # fault nca_s_fault_cancel
    ],
    "truncated_snaplen.pcap": [
        (7, "rpc_truncated"),  # R1: RPC body 134 of 176 bytes
        (7, "record_truncated"),  # H5: 50 of 92 record bytes present
        (7, "truncated_capture_pnio"),  # E: cut inside a PNIO RPC PDU
        (11, "truncated_capture"),  # I: cut outside PNIO
    ],
    "fault_trace.pcap": [],  # its one finding, T4 retry on frame 291, is a transaction's (fault_trace_capture)
}

# file name -> its expectation, rendered from the Intent its builder recorded (sample_pcaps/expected/<name>.json)
EXPECTED: dict[str, Callable[[], dict[str, Any]]] = {}


def pd_sample(name: str) -> Callable[[Callable[[], Built]], Callable[[], Built]]:
    """Register a capture builder both as a sample file and as its expectations."""

    def register(build: Callable[[], Built]) -> Callable[[], Built]:
        sample(name)(lambda: pcap_of(build()[0]))
        EXPECTED[name] = lambda: build()[1].render(name)
        return build

    return register

"""One import point for every pure encoder, layer by layer.

    from devtools.synth.encode import ethernet, ipv4, udp, rpc_pdu, ...

The functions live in net_encode.py, rpc_encode.py, pnio_encode.py and
pd_encode.py; this module only re-exports them so callers need not know
the split.
"""

from __future__ import annotations

from .net_encode import (
    ETH_ARP,
    ETH_IPV4,
    ETH_PNRT,
    ETH_QINQ,
    ETH_VLAN,
    LINKTYPE_ETHERNET,
    LINKTYPE_LINUX_SLL,
    LINKTYPE_LINUX_SLL2,
    LINKTYPE_RAW,
    VlanTag,
    arp,
    ethernet,
    inet_checksum,
    ip4,
    ip_fragments,
    ipv4,
    mac,
    pn_rt_cyclic,
    sll,
    sll2,
    udp,
)
from .pd_encode import (
    ParamAddress,
    change_ok,
    change_request,
    encode_values,
    error_block,
    pd_request,
    pd_response,
    read_request,
    value_block,
    zero_block,
)
from .pnio_encode import (
    API_PROFIDRIVE,
    INDEX_WRITE_MULTIPLE,
    READ_REQ,
    READ_RES,
    STATUS_B5,
    STATUS_OK,
    WRITE_REQ,
    WRITE_RES,
    InnerWrite,
    align4_pad,
    ar_block_req,
    ar_block_res,
    block,
    control_block,
    iod_header,
    iod_read_req,
    iod_read_res,
    iod_write_req,
    iod_write_res,
    ndr_request,
    ndr_response,
    ndr_status,
    pnio_status,
    write_multiple_records,
    write_multiple_req,
    write_multiple_res,
)
from .rpc_encode import (
    DREP_BE,
    DREP_LE,
    EPM_IF,
    MAX_FRAG_BODY,
    NIL_UUID,
    PNIO_DEVICE_IF,
    cancel_ack_body,
    cancel_body,
    cl_fragments,
    fack_body,
    pnio_object_uuid,
    rpc_header,
    rpc_pdu,
    split_body,
    status_body,
    uuid_wire,
)

__all__ = [
    "API_PROFIDRIVE", "DREP_BE", "DREP_LE", "EPM_IF", "ETH_ARP", "ETH_IPV4", "ETH_PNRT", "ETH_QINQ",
    "ETH_VLAN", "INDEX_WRITE_MULTIPLE", "LINKTYPE_ETHERNET", "LINKTYPE_LINUX_SLL", "LINKTYPE_LINUX_SLL2",
    "LINKTYPE_RAW", "MAX_FRAG_BODY", "NIL_UUID", "PNIO_DEVICE_IF", "READ_REQ", "READ_RES", "STATUS_B5",
    "STATUS_OK", "WRITE_REQ", "WRITE_RES", "InnerWrite", "ParamAddress", "VlanTag", "align4_pad",
    "ar_block_req", "ar_block_res", "arp", "block", "cancel_ack_body", "cancel_body", "change_ok",
    "change_request", "cl_fragments", "control_block", "encode_values", "error_block", "ethernet",
    "fack_body", "inet_checksum", "iod_header", "iod_read_req", "iod_read_res", "iod_write_req",
    "iod_write_res", "ip4", "ip_fragments", "ipv4", "mac", "ndr_request", "ndr_response", "ndr_status",
    "pd_request", "pd_response", "pn_rt_cyclic", "pnio_object_uuid", "pnio_status", "read_request",
    "rpc_header", "rpc_pdu", "sll", "sll2", "split_body", "status_body", "udp", "uuid_wire", "value_block",
    "write_multiple_records", "write_multiple_req", "write_multiple_res", "zero_block",
]  # fmt: skip

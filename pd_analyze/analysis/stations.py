"""Station names of the drives: the name each device announces with its IP address in PN-DCP Identify or Get
responses (protocol.dcp), read in a pass of its own over the captures.

The report paths skip non-IP frames without looking at them (most of a PROFINET capture is cyclic PN-RT), so
the names are gathered here instead, only for the parameter state. Standard input (`-`) cannot be read twice:
its drives keep their address alone. A capture that cannot be read gives no name; its error is reported by
the analysis itself. When a device announces several names, the last one counts (a name set during
commissioning).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from pd_analyze.capture import CaptureError
from pd_analyze.capture.batches import FrameBatch, batches
from pd_analyze.model.values import LINKTYPE_ETHERNET
from pd_analyze.protocol.dcp import FRAME_IDS, PN_RT, station

STDIN = "-"
_FRAME_IDS = np.array(sorted(FRAME_IDS), dtype=np.uint16)
_ETYPE_AT = (12, 16)  # EtherType untagged, and behind one VLAN tag (DCP is not expected behind two)


def stations(paths: Iterable[str]) -> dict[str, str]:
    """IP address -> station name, from every capture but standard input."""
    names: dict[str, str] = {}
    for path in paths:
        if path == STDIN:
            continue
        try:
            for batch in batches(path):
                for i in _pn_rt(batch):
                    start = int(batch.start[i])
                    found = station(bytes(batch.buf[start:start + int(batch.caplen[i])]))
                    if found is not None:
                        names[found[0]] = found[1]
        except (CaptureError, OSError):
            continue
    return names


def _pn_rt(batch: FrameBatch) -> np.ndarray:
    """Indexes of a batch's Ethernet frames with EtherType 0x8892 (PN-RT) and a DCP response FrameID, found
    without a Python loop: most frames of a PROFINET capture are cyclic PN-RT or IP, a handful DCP."""
    data = np.frombuffer(batch.buf, dtype=np.uint8)
    hit = np.zeros(len(batch), dtype=bool)
    for at in _ETYPE_AT:
        ok = (batch.linktype == LINKTYPE_ETHERNET) & (batch.caplen >= at + 4)
        first = np.where(ok, batch.start + at, 0)
        frame_id = data[first + 2].astype(np.uint16) << 8 | data[first + 3]
        hit |= ok & (data[first] == PN_RT[0]) & (data[first + 1] == PN_RT[1]) & np.isin(frame_id, _FRAME_IDS)
    return np.flatnonzero(hit)

"""Station names of the drives: the name each device announces with its IP address in PN-DCP Identify or Get
responses (protocol.dcp), gathered while a capture is analysed, kept per capture (CaptureResult.stations) and
shown beside the address wherever a drive is named (summary, parameter state).

The report paths skip non-IP frames without dissecting them (most of a PROFINET capture is cyclic PN-RT), so
the names are found beside them: the columnar path picks the DCP responses out of each batch by its columns
(`names_in_batch`); the per-frame path, read for small captures, looks at every frame in a pass of its own
(`names_in_file`), so that its frame loop keeps skipping cheaply. When a device announces several names in one
capture, the last one counts (a name set during commissioning). Across captures the names are kept per capture,
never one capture's name for another's drive: a drive is named by its own capture's announcement, or, where its
capture has none, by the one name the other captures agree on (`per_capture`); tables folded over captures by
address (the parameter state) show every name an address was given, in capture order (`merged`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Mapping
from typing import TYPE_CHECKING

from pd_analyze import capture
from pd_analyze.capture import CaptureError, RawFrame
from pd_analyze.model.values import LINKTYPE_ETHERNET, VLAN_TPIDS
from pd_analyze.protocol.dcp import FRAME_IDS, PN_RT, station

if TYPE_CHECKING:
    import numpy as np

    from pd_analyze.analysis.capture_run import CaptureResult
    from pd_analyze.capture.batches import FrameBatch

STDIN = "-"
_ETYPE_AT = (12, 16)  # EtherType untagged, and behind one VLAN tag (DCP is not expected behind two)


def names_in_batch(batch: FrameBatch, names: dict[str, str]) -> None:
    """Add the announcements among a batch's frames to `names` (IP address -> station name)."""
    for i in _pn_rt(batch):
        start = int(batch.start[i])
        found = station(bytes(batch.buf[start:start + int(batch.caplen[i])]))
        if found is not None:
            names[found[0]] = found[1]


def names_in_file(path: str) -> dict[str, str]:
    """IP address -> station name, from every frame of a capture file. A capture that cannot be read to its
    end gives the names before the damage; its error is reported by the analysis itself. Standard input
    (`-`) cannot be read twice: its drives keep their address alone on this path."""
    names: dict[str, str] = {}
    if path == STDIN:
        return names
    with contextlib.suppress(CaptureError, OSError):
        names_in_frames(capture.frames(path), names)
    return names


def names_in_frames(frames: Iterable[RawFrame], names: dict[str, str]) -> None:
    """Add the announcements among `frames` to `names` (IP address -> station name)."""
    for frame in frames:
        found = station(frame.data) if frame.linktype == LINKTYPE_ETHERNET else None
        if found is not None:
            names[found[0]] = found[1]


def merged(captures: Iterable[CaptureResult]) -> dict[str, str]:
    """IP address -> name over several captures: the one name they agree on; where two captures name one address
    differently (two plants' drives at one address, or a drive renamed), every name in capture order, joined by
    ' / ' (the later capture's name once replaced the earlier's)."""
    return {device: " / ".join(given) for device, given in _given(r.stations for r in captures).items()}


def per_capture(captures: Iterable[CaptureResult]) -> Callable[[str, str], str]:
    """label(capture, device): the device as people name it in that capture: its address, and the name that capture
    announced for it, or, where that capture holds none, the one name every capture that names it agrees on."""
    own = {result.path: result.stations for result in captures}
    agreed = {device: given[0] for device, given in _given(own.values()).items() if len(given) == 1}

    def label(capture: str, device: str) -> str:
        name = own.get(capture, {}).get(device) or agreed.get(device, "")
        return f"{device} ({name})" if name else device
    return label


def _given(stations: Iterable[Mapping[str, str]]) -> dict[str, list[str]]:
    """IP address -> the distinct names the captures give it, in capture order."""
    names: dict[str, list[str]] = {}
    for found in stations:
        for device, name in found.items():
            given = names.setdefault(device, [])
            if name not in given:
                given.append(name)
    return names


def device_label(device: str, names: Mapping[str, str]) -> str:
    """A device as people name it: its address, and its station name where the capture has one."""
    name = names.get(device, "")
    return f"{device} ({name})" if name else device


def _pn_rt(batch: FrameBatch) -> np.ndarray:
    """Indexes of the batch's frames that may be a DCP response, found without a Python loop (most frames of a
    PROFINET capture are cyclic PN-RT or IP, a handful DCP): Ethernet frames with EtherType 0x8892 (PN-RT) and
    a DCP response FrameID, untagged or behind one VLAN tag, and every frame behind two or more tags (rare:
    protocol.dcp.station walks any number, as the per-frame path does, and decides)."""
    import numpy as np

    data = np.frombuffer(batch.buf, dtype=np.uint8)
    hit = np.zeros(len(batch), dtype=bool)
    ethernet = batch.linktype == LINKTYPE_ETHERNET
    for at in _ETYPE_AT:
        long_enough = np.flatnonzero(ethernet & (batch.caplen >= at + 4))
        first = batch.start[long_enough] + at  # (each frame holds these 4 bytes: no index leaves the buffer)
        frame_id = data[first + 2].astype(np.uint16) << 8 | data[first + 3]
        match = (data[first] == PN_RT[0]) & (data[first + 1] == PN_RT[1]) & np.isin(frame_id, _FRAME_IDS)
        hit[long_enough[match]] = True
    tagged = np.flatnonzero(ethernet & (batch.caplen >= 18))
    first = batch.start[tagged]
    outer, inner = (data[first + at].astype(np.uint16) << 8 | data[first + at + 1] for at in _ETYPE_AT)
    hit[tagged[np.isin(outer, _TPIDS) & np.isin(inner, _TPIDS)]] = True
    return np.flatnonzero(hit)


_FRAME_IDS = sorted(FRAME_IDS)
_TPIDS = sorted(VLAN_TPIDS)

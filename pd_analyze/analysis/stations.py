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

from pd_analyze.capture import CaptureError
from pd_analyze.capture.reader import frames
from pd_analyze.model.values import LINKTYPE_ETHERNET
from pd_analyze.protocol.dcp import PN_RT, station

STDIN = "-"


def stations(paths: Iterable[str]) -> dict[str, str]:
    """IP address -> station name, from every capture but standard input."""
    names: dict[str, str] = {}
    for path in paths:
        if path == STDIN:
            continue
        try:
            for f in frames(path):
                if f.linktype == LINKTYPE_ETHERNET and PN_RT in f.data[12:24]:  # (cheap: behind up to 2 tags)
                    found = station(f.data)
                    if found is not None:
                        names[found[0]] = found[1]
        except (CaptureError, OSError):
            continue
    return names

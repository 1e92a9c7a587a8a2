"""Names of the PROFIdrive profile parameters (PNU 900 ... 999), which mean the same on every drive.

Source: PROFIdrive profile V4.2, profile parameters, as printed in public drive manuals (ABB RETA-02 and
Danfoss VACON 100 PROFINET manuals, HEIDENHAIN PROFIBUS-DP encoder manual); protocol.md 4.7. Vendor
parameter numbers have no name here: the manuals of the seeds carry no name table.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

PNU_NAMES: Mapping[int, str] = MappingProxyType({
    915: "DO IO data assignment, setpoint telegram",
    916: "DO IO data assignment, actual value telegram",
    918: "node address",
    919: "device system number",
    922: "telegram selection",
    923: "list of all parameters for signals",
    925: "controller sign-of-life failures tolerated",
    927: "operator control rights",
    930: "operating mode",
    944: "fault message counter",
    945: "fault code",
    947: "fault number",
    948: "fault time",
    949: "fault value",
    952: "number of fault situations",
    964: "drive unit identification",
    965: "profile identification number",
    971: "transfer into non-volatile memory",
    974: "base mode parameter access service identification",
    975: "drive object identification",
    **{pnu: "number list of defined parameters" for pnu in range(980, 990)},
})


def pnu_name(pnu: int | None) -> str:
    """The profile name of a parameter number, empty when the profile gives it none."""
    return PNU_NAMES.get(pnu, "") if pnu is not None else ""

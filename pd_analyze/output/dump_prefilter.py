"""The frames of a batch's column decode that a display filter may match, judged without a tree (`dump -Y`,
issue 24 point 1): a superset, never smaller than the frames the filter matches, so that dissecting only
these and judging each on its tree gives the per-frame result exactly.

One form is known today, the commonest question of a day's trace: `pd.addr.pnu == N` (or its tshark name
pn_io.profidrive.parameter.number). A parameter address is in a tree only inside a parameter request's
record, or in a response's echo of addresses, which the column decode never calls regular (protocol
.profidrive_batch); so a frame is left out when the columns decoded its record as regular and none of its
addresses has PNU N, when it is a read request (an IODReadReqHeader carries no record), and when it is a
write response decoded as one (its request's operation, as the report pairs it, is a write too).
"""

from __future__ import annotations

import re
from collections.abc import Callable

import numpy as np

from pd_analyze.analysis.engine.decode import Decoded
from pd_analyze.model.values import OP_READ, OP_READ_IMPLICIT, OP_WRITE, PTYPE_REQUEST, PTYPE_RESPONSE
from pd_analyze.output.display_filter import DisplayFilter
from pd_analyze.output.dump_facts import FileLinks

Candidates = Callable[[Decoded, np.ndarray, FileLinks], np.ndarray]
_PNU = "pd.addr[i].pnu"
_EQUALS = re.compile(r"^\s*[\w.]+\s*(?:==|eq|any_eq)\s*(0x[0-9a-fA-F]+|\d+)\s*$")


def candidates_of(flt: DisplayFilter) -> Candidates | None:
    """The column test of a filter of a known form; None for any other filter (every frame is a candidate)."""
    match = _EQUALS.match(flt.text)
    if match is None or len(flt.refs) != 1:
        return None
    ref = flt.refs[0]
    if ref.names != (_PNU,) or ref.exact or ref.width != -1:
        return None
    pnu = int(match.group(1), 0)
    return lambda part, rows, links: _with_pnu(part, rows, links, pnu)


def _with_pnu(part: Decoded, rows: np.ndarray, links: FileLinks, pnu: int) -> np.ndarray:
    view = part.view
    p, rec = view.p, view.records
    rec_of = view.rec_of[rows]
    decoded = rec_of >= 0
    out = np.ones(len(rows), bool)
    if len(rec.addresses.pnu):  # records decoded as regular: a candidate when one of its addresses is N
        hit = np.zeros(len(rec.records.regular), bool)
        hit[rec.addresses.record[rec.addresses.pnu == pnu]] = True
        r = rec_of[decoded]
        out[decoded] = ~rec.records.regular[r] | hit[r]
    else:
        out[decoded] = ~rec.records.regular[rec_of[decoded]]
    ptype, opnum = p.ptype[rows], p.opnum[rows]
    bare = ~decoded & view.pnio[rows]
    out[bare & (ptype == PTYPE_REQUEST) & ((opnum == OP_READ) | (opnum == OP_READ_IMPLICIT))] = False
    for k in np.flatnonzero(bare & (ptype == PTYPE_RESPONSE) & (opnum == OP_WRITE)).tolist():
        request = links.request(int(view.frame_no[rows[k]]))
        out[k] = request is not None and request.opnum != OP_WRITE
    return out

"""The targets table of benchmarks/bench.py: each target of issues #23 (one engine at column speed), #24
(dumps at tshark speed) and #25 (one capture on every core) with what the run measured and whether it is met.

A target whose figures a run did not measure (a step skipped, tshark missing) says n/a and why.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

MIB: Final = 1024  # kB
RSS_LIMIT_MIB: Final = 300  # issue #23: peak RSS of report, and of each flood, in one process
FLAT: Final = 1.2  # 4x the frames: at most this much more peak RSS
STARTUP: Final = "report, start-up"
ONLY_PNIO, ONLY_OTHER = "report, PNIO RPC frames only", "report, other frames only"
MANY: Final = "report DIR of {} files --jobs {}"
PARTS: Final = 8
NO_TSHARK: Final = "tshark not on PATH"
FLOOD_NAMES: Final = {"calls": "never-answered calls", "cl": "CL fragments", "ip": "IP fragments",
                      "mixed": "calls, CL and IP fragments mixed", "txns": "half-finished transactions",
                      "changes40": "never-answered 40-parameter changes"}


@dataclass
class Costs:
    skip: float | None  # us per frame, None when not measurable
    analyse: float | None
    noisy: bool  # a class took less than `noise` seconds beyond start-up: its cost is rough
    noise: float


def _met(*checks: bool | None) -> str:
    """no if any measured check fails; n/a if one could not be measured; else yes."""
    if any(c is False for c in checks):
        return "no"
    return "n/a" if any(c is None for c in checks) else "yes"


def _ratio(slow: Any, fast: Any) -> float | None:
    """How many times faster `fast` ran than `slow` (None if either was not timed)."""
    return slow.wall / fast.wall if slow and fast else None


def _x(value: float | None, why_not: str) -> str:
    return f"n/a ({why_not})" if value is None else f"{value:.2f}x"


def _at_least(value: float | None, target: float) -> bool | None:
    return None if value is None else value >= target


def targets(b: Any, caps: list[str], args: argparse.Namespace, costs: Costs | None, tshark: bool,
            floods: Sequence[str]) -> list[list[str]]:
    """The rows: `caps` the captures of the run, `floods` the flood kinds (devtools.hostile)."""
    rows = _engine(b, caps, args, tshark)
    rows += _dumps(b, caps, args, tshark)
    rows += _jobs(b, caps, args)
    rows += _floods(b, floods)
    start = b.get(STARTUP)
    rows.append(["`report` of a 10-frame capture within 0.3 s",
                 f"{start.wall:.2f} s" if start else "n/a (--skip-startup)", _met(start and start.wall <= 0.3)])
    if costs is not None:
        rows.append(_cost_row(costs))
    one, two = b.get(MANY.format(PARTS, 1)), b.get(MANY.format(PARTS, 2))
    r = _ratio(one, two)
    measured = f"{two.wall:.2f} s against {one.wall:.2f} s ({r:.2f}x)" if one and two else "n/a (--skip-files)"
    rows.append([f"{PARTS} files: `report DIR --jobs 2` faster than `--jobs 1`", measured,
                 _met(None if r is None else r > 1)])
    return rows


def _engine(b: Any, caps: list[str], args: argparse.Namespace, tshark: bool) -> list[list[str]]:
    """Issue #23: report against tshark's field extraction; peak RSS bounded and flat."""
    rows = []
    for cap in caps:
        speed = 10 if cap == "mix" else 5
        report = b.get(f"{cap}: pd-analyze report")
        r = _ratio(b.get(f"{cap}: tshark PROFIdrive fields"), report)
        rows.append([f"{cap}: `report` >= {speed}x faster than tshark's field extraction",
                     _x(r, NO_TSHARK if not tshark else "not timed"), _met(_at_least(r, speed))])
        big = b.get(f"{cap}: pd-analyze report, 4x frames")
        within = report.rss <= RSS_LIMIT_MIB * MIB if report else None
        flat = big.rss <= FLAT * report.rss if big and report else None
        growth = (f"; {big.rss / MIB:.0f} MiB with 4x the frames ({big.rss / report.rss:.2f}x)" if big and report
                  else "; 4x n/a (--skip-scale)" if cap != "mix" else "")
        measured = f"{report.rss / MIB:.0f} MiB{growth}" if report else "n/a"
        flat_target = f", flat: 4x the frames <= {FLAT}x" if cap != "mix" else ""
        rows.append([f"{cap}: peak RSS of `report` <= {RSS_LIMIT_MIB} MiB{flat_target}", measured,
                     _met(within, flat) if cap != "mix" else _met(within)])
    for what in ("params", "audit"):
        one, big = b.get(f"dense: pd-analyze {what}"), b.get(f"dense: pd-analyze {what}, 4x frames")
        flat = big.rss <= FLAT * one.rss if big and one else None
        measured = (f"{one.rss / MIB:.0f} MiB; " if one else "n/a; ") + (
            f"{big.rss / MIB:.0f} MiB with 4x the frames ({big.rss / one.rss:.2f}x)" if big and one else
            "4x n/a (--skip-scale or --skip-dumps)")
        rows.append([f"dense: peak RSS of `{what}` flat: 4x the frames <= {FLAT}x the RSS", measured, _met(flat)])
    return rows


def _dumps(b: Any, caps: list[str], args: argparse.Namespace, tshark: bool) -> list[list[str]]:
    """Issue #24: dumps against tshark, the commands that print frames against report."""
    rows = []
    why = "--skip-dumps" if args.skip_dumps else NO_TSHARK if not tshark else "not timed"
    for cap in (c for c in ("dense", "fault-rich") if c in caps):
        pairs = (("`dump -Y` (about 1 % of the frames) at least as fast as `tshark -Y ... -V`",
                  "pd-analyze dump -Y (about 1 %)", "tshark -Y -V (about 1 %)", 1.0),
                 ("`dump -T fields` (3 fields) at least as fast as tshark's", "pd-analyze dump -T fields",
                  "tshark -T fields", 1.0),
                 ("`dump` text >= 0.5x `tshark -V`", "pd-analyze dump (text)", "tshark -V", 0.5),
                 ("`dump --format json` >= 1x `tshark -T json`", "pd-analyze dump --format json", "tshark -T json",
                  1.0))
        for target, mine, theirs, speed in pairs:
            r = _ratio(b.get(f"{cap}: {theirs}"), b.get(f"{cap}: {mine}"))
            note = b.notes.get(f"{cap}: dump -Y", "") if "-Y" in mine else ""
            skipped = "--skip-tshark-v" if "-V" in theirs and "-Y" not in theirs and args.skip_tshark_v else why
            rows.append([f"{cap}: {target}", _x(r, skipped) + (f"; {note}" if note else ""),
                         _met(_at_least(r, speed))])
        report = b.get(f"{cap}: pd-analyze report")
        for what in ("annotate", "extract --verdict nak", "annotate -Y pnu", "extract -Y pnu", "params", "audit"):
            t = b.get(f"{cap}: pd-analyze {what}")
            r = t.wall / report.wall if t and report else None
            measured = f"{r:.2f}x report's time ({t.wall:.2f} s)" if r is not None and t else "n/a (--skip-dumps)"
            rows.append([f"{cap}: `{what}` within 1.5x of `report`'s time", measured,
                         _met(None if r is None else r <= 1.5)])
    return rows


def _jobs(b: Any, caps: list[str], args: argparse.Namespace) -> list[list[str]]:
    """Issue #25: one capture in N processes, output identical to one process's."""
    rows = []
    n = args.jobs
    for cap in (c for c in ("dense", "fault-rich") if c in caps):
        for what in ("report", "audit", "params"):
            one, many = b.get(f"{cap}: pd-analyze {what}"), b.get(f"{cap}: pd-analyze {what} --jobs {n}")
            r = _ratio(one, many)
            same = b.notes.get(f"{cap}: {what} --jobs identical")
            measured = f"{_x(r, '--jobs 1')}; identical: {same}" if same else "n/a (--jobs 1)"
            rows.append([f"{cap}: `{what} --jobs {max(n, 2)}` >= 1.7x faster than one process, output identical",
                         measured, _met(_at_least(r, 1.7), None if same is None else same == "yes")])
    # the mutated capture and the floods: output identical (bench.jobs' _jobs_pair)
    for key, same in b.notes.items():
        cap = key.split(":")[0]
        if key.endswith(": report --jobs identical") and cap not in ("dense", "fault-rich"):  # (those: above)
            rows.append([f"{cap}: `report --jobs {max(n, 2)}` output identical to one process", same,
                         _met(same == "yes")])
    return rows


def _floods(b: Any, floods: Sequence[str]) -> list[list[str]]:
    """Issue #23: each flood at least as fast as tshark, bounded, every frame counted once."""
    rows = []
    for kind in floods:
        t = b.get(f"flood of {kind}: report")
        target = (f"flood of {FLOOD_NAMES.get(kind, kind)}: `report` at least as fast as tshark's field "
                  f"extraction, peak RSS <= {RSS_LIMIT_MIB} MiB, `N frames read` = the frames in the file")
        if t is None:
            rows.append([target, "n/a (--skip-floods)", "n/a"])
            continue
        r = _ratio(b.get(f"flood of {kind}: tshark PROFIdrive fields"), t)
        read = b.notes.get(f"flood of {kind}: frames read", "n/a")
        counted = None if read == "n/a" else int(read) == t.frames
        said = f"{int(read):,}" if read != "n/a" else read
        rows.append([target, f"{_x(r, NO_TSHARK)}; {t.rss / MIB:.0f} MiB; {said} of {t.frames:,} frames read",
                     _met(_at_least(r, 1.0), t.rss <= RSS_LIMIT_MIB * MIB, counted)])
    return rows


def _cost_row(c: Costs) -> list[str]:
    target = "non-PNIO frames skipped >= 5x faster than PNIO frames are analysed"
    if c.skip is None or c.analyse is None:
        return [target, "n/a: a class is empty or no slower than start-up (use more frames)", "n/a"]
    note = f"; rough: under {c.noise} s beyond start-up, use more frames" if c.noisy else ""
    return [target, f"{c.skip:.2f} us against {c.analyse:.2f} us per frame: {c.analyse / c.skip:.1f}x{note}",
            _met(None if c.noisy else c.analyse >= 5 * c.skip)]  # noise alone can pass or fail it

"""A parsed display filter as a tree (output.display_filter makes it): the tests of fields, `not`, `and`, `or`.
The per-frame path compiles it to one predicate over a frame's view (`compiled`); the column path judges it
node by node (output.dump_prefilter)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from pd_analyze.output.frame_view import FieldRef, FrameView

Predicate = Callable[[FrameView], bool]
Each = Callable[[object], bool]


@dataclass(frozen=True, slots=True)
class Test:
    """One test of a field: `each` holds of one occurrence; the frame passes when any occurrence does, or
    (`every`) when the field is present and every occurrence does (tshark 4's !=: present and none equal, and
    ===). A bare field is `each` always true."""

    ref: FieldRef
    each: Each
    every: bool = False

    def judge(self, found: list[object]) -> bool:
        """The test over a frame's occurrences of the field."""
        each = self.each
        if self.every:
            return bool(found) and all(each(x) for x in found)
        return any(each(x) for x in found)


@dataclass(frozen=True, slots=True)
class Not:
    item: Node


@dataclass(frozen=True, slots=True)
class All:
    """and: every item holds."""

    items: tuple[Node, ...]


@dataclass(frozen=True, slots=True)
class Any:
    """or: some item holds."""

    items: tuple[Node, ...]


Node = Test | Not | All | Any


def compiled(node: Node) -> Predicate:
    """The predicate of a tree over one frame's view."""
    if isinstance(node, Test):
        values, ref, judge = FrameView.values, node.ref, node.judge
        return lambda v: judge(values(v, ref))
    if isinstance(node, Not):
        inner = compiled(node.item)
        return lambda v: not inner(v)
    terms = [compiled(item) for item in node.items]
    if isinstance(node, All):
        return lambda v: all(t(v) for t in terms)
    return lambda v: any(t(v) for t in terms)

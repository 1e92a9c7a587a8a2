"""The dump's ordered output: annotated frames held back until their forward links are known.

A request waits for the frame of its response, a fragment for the frame that reassembles its PDU, so
the dump shows `rpc.response_frame` and `rpc.reassembled_in` and still writes frames in order. The hold
is bounded in time (rpc_timeout of capture time) and in frames and fields: past a bound a frame leaves
without its link. Findings discovered later for a held frame join it. The report path holds nothing.
"""

from __future__ import annotations

from collections import deque

from pd_analyze.model.capped import CL_LINKED_SETS, CappedTable
from pd_analyze.model.layout import derived
from pd_analyze.protocol.frames import FrameResult, Layer

MAX_HELD_FRAMES = 10_000
MAX_HELD_FIELDS = 50_000  # annotated fields of the held frames (a field costs some 300 bytes)


class HeldFrames:
    """Annotated results in frame order, each released once nothing it waits for can still come."""

    def __init__(self, rpc_timeout: float) -> None:
        self.rpc_timeout = rpc_timeout
        self._held: deque[FrameResult] = deque()
        self._index: dict[int, FrameResult] = {}  # the held results by frame
        self._fields = 0
        self._waiting: dict[int, FrameResult] = {}  # results waiting for a forward link, by frame
        self._fragments: CappedTable[tuple, list[int]] = CappedTable(CL_LINKED_SETS)  # frames per fragment set

    def wait(self, res: FrameResult) -> None:
        """`res` waits for a forward link (its response, or its PDU's reassembly)."""
        self._waiting[res.frame] = res

    def link_response(self, request_frame: int, response_frame: int) -> None:
        held = self._waiting.pop(request_frame, None)
        if held is not None:
            held.layers.append(Layer("Call", 0, [derived("rpc.response_frame", response_frame)]))

    def link_fragment(self, fkey: tuple, number: int) -> None:
        """Remember a held fragment's frame, to link it to the frame that reassembles its PDU."""
        frames = self._fragments.get(fkey)
        if frames is None:
            frames = []
            self._fragments.remember(fkey, frames)  # the oldest: sets evicted or never completed
        if len(frames) < MAX_HELD_FRAMES:  # beyond that, the frames have left the hold anyway
            frames.append(number)

    def link_reassembled(self, fkey: tuple, completing: int) -> None:
        """The fragment set `fkey` was reassembled in frame `completing`: its held fragments learn it."""
        for fragment_frame in self._fragments.pop(fkey, []) or []:
            held = self._waiting.pop(fragment_frame, None)
            if held is not None and fragment_frame != completing:
                held.layers.append(Layer("Fragment", 0, [derived("rpc.reassembled_in", completing)]))

    def first_held(self) -> int:
        """The frame of the first result still held (0: none): every result released comes before it."""
        return self._held[0].frame if self._held else 0

    def find(self, frame: int) -> FrameResult | None:
        """The held result of `frame`, for a finding discovered later (it then waits no longer)."""
        return self._waiting.pop(frame, None) or self._index.get(frame)

    def release(self, new: list[FrameResult], now: float) -> list[FrameResult]:
        """Hold `new`; hand on, in order, every result that waits for nothing (any more) at time `now`."""
        if not self._held and not self._waiting:  # nothing held and nothing waits: `new` leaves as it came
            return new
        for res in new:
            self._held.append(res)
            self._index[res.frame] = res
            self._fields += sum(len(layer.fields) for layer in res.layers)
        ready = []
        while self._held:
            head = self._held[0]
            blocked = head.frame in self._waiting
            if blocked and (len(self._held) > MAX_HELD_FRAMES or self._fields > MAX_HELD_FIELDS
                            or head.ts + self.rpc_timeout < now):
                self._waiting.pop(head.frame, None)
                blocked = False
            if blocked:
                break
            ready.append(self._held.popleft())
            self._index.pop(head.frame, None)
            self._fields -= sum(len(layer.fields) for layer in head.layers)
        return ready

    def finish(self, new: list[FrameResult], now: float) -> list[FrameResult]:
        """End of capture: nothing more can come; every held result goes, in order."""
        self._waiting.clear()
        return self.release(new, now)

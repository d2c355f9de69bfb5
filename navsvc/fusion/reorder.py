"""The reorder window (pure): packets up to ``window_s`` late are applied in time order.

Works for any filter that can ``apply`` a packet in time order, take a ``snapshot`` of its
state and ``restore`` one (:class:`Replayable`): a late packet rolls the filter back to the
last snapshot before it, and the packets since are replayed around it. Older packets are
refused with ``time_backwards``. A snapshot is taken every ``SNAPSHOT_EVERY`` packets, not at
each: a late packet replays a few more, and the copies cost little per packet.

A packet the filter refuses (it raises :class:`PacketError` and changes nothing) is not kept;
a late one that is refused leaves the filter and the window as they were.

The road filter's batched path (:mod:`navsvc.fusion.road.batch`) comes in as runs of samples
(:meth:`ReorderWindow.add_run`): a run is one item of the history, so a group starts (a
snapshot is taken) at most at every ``SNAPSHOT_EVERY`` items and at run boundaries; a late
packet that falls inside a run splits it, and both parts are replayed through the batched
path (or packet by packet, when the replayed late packet leaves the filter uninitialised).
"""

from __future__ import annotations

from collections import deque
from typing import Generic, Protocol, TypeVar

from navsvc.errors import PacketError, RejectReason
from navsvc.fusion.road.batch import SampleRun, T
from navsvc.types import FusedEstimate, Packet

SNAPSHOT_EVERY = 8  # packets between saved states

S = TypeVar("S")  # a filter's snapshot
Item = Packet | SampleRun  # what the history holds: a packet, or a run of samples


def _start(item: Item) -> float:
    """The time of an item's first packet."""
    return item.first_t if isinstance(item, SampleRun) else item.t


class Replayable(Protocol[S]):
    """What the window needs of a filter."""

    @property
    def t(self) -> float | None:
        """Time of the latest packet applied (None before any)."""
        ...

    def apply(self, packet: Packet) -> list[FusedEstimate]:
        """Apply a packet not older than ``t``; the estimates it emits."""
        ...

    def snapshot(self) -> S:
        """The state, as a copy that later packets cannot change."""
        ...

    def restore(self, snapshot: S) -> None:
        """Return to a snapshot, leaving the snapshot as it was."""
        ...


class RunReplayable(Replayable[S], Protocol[S]):
    """A filter with a batched path (the road filter)."""

    def apply_run(self, run: SampleRun, start: int = 0, events: bool = False,
                  last_match_t: float | None = None, match_interval_s: float | None = None
                  ) -> tuple[int, list[FusedEstimate]]:
        """Samples ``start..`` of a run, in time order; the next index and the estimates
        (:meth:`navsvc.fusion.road.filter.RoadFilter.apply_run`)."""
        ...


class ReorderWindow(Generic[S]):
    """The packets of the last ``window_s``, in groups each with the state before its first."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self.late_rejected = 0  # packets refused as too late (never rolled back)
        self._history: deque[tuple[S, list[Item]]] = deque()

    def add(self, f: Replayable[S], packet: Packet) -> list[FusedEstimate]:
        """Apply ``packet`` to ``f`` in time order; the estimates it emitted.

        Raises :class:`PacketError` (``time_backwards``) for a packet older than the window.
        """
        t_now = f.t
        if t_now is None or packet.t >= t_now:
            return self._apply_logged(f, packet)
        if packet.t < t_now - self.window_s or not self._history \
                or packet.t < _start(self._history[0][1][0]):
            self.late_rejected += 1
            raise PacketError(RejectReason.TIME_BACKWARDS,
                              f"t={packet.t} is {t_now - packet.t:.3f} s before the latest "
                              f"packet (window {self.window_s} s)")
        return self._replay_with(f, packet)

    def clear(self) -> None:
        """Forget the history (after a change that cannot be replayed)."""
        self._history.clear()

    def add_run(self, f: RunReplayable[S], run: SampleRun, start: int = 0,
                events: bool = False, last_match_t: float | None = None,
                match_interval_s: float | None = None) -> tuple[int, list[FusedEstimate]]:
        """Apply samples ``start..`` of ``run`` (in time order, none older than ``f.t``) with
        ``f.apply_run``, and keep the part it took as one item; returns what it returned."""
        if self.window_s <= 0.0:
            return f.apply_run(run, start, events, last_match_t, match_interval_s)
        before = self._snapshot_if_due(f)
        end, out = f.apply_run(run, start, events, last_match_t, match_interval_s)
        self._log(before, run.part(start, end), float(run.rows[end - 1, T]))
        return end, out

    def _apply_logged(self, f: Replayable[S], packet: Item) -> list[FusedEstimate]:
        if isinstance(packet, SampleRun):  # a run of the history, replayed whole
            return self.add_run(f, packet)[1]  # type: ignore[arg-type]
        if self.window_s <= 0.0:
            return f.apply(packet)
        before = self._snapshot_if_due(f)
        out = f.apply(packet)  # a refused packet raises here: not kept
        self._log(before, packet, packet.t)
        return out

    def _snapshot_if_due(self, f: Replayable[S]) -> S | None:
        history = self._history
        new_group = not history or len(history[-1][1]) >= SNAPSHOT_EVERY
        return f.snapshot() if new_group else None

    def _log(self, before: S | None, item: Item, t_last: float) -> None:
        history = self._history
        if before is not None:
            history.append((before, [item]))
        else:
            history[-1][1].append(item)
        # a group can go once the next one starts before the window: it covers the rest
        horizon = t_last - self.window_s
        while len(history) > 1 and _start(history[1][1][0]) < horizon:
            history.popleft()

    def _replay_with(self, f: Replayable[S], late: Packet) -> list[FusedEstimate]:
        groups = list(self._history)
        g = next(k for k in range(len(groups) - 1, -1, -1)
                 if _start(groups[k][1][0]) <= late.t)
        replay = [p for _, packets in groups[g:] for p in packets]
        before = next((i for i, p in enumerate(replay) if _start(p) > late.t), len(replay))
        head, tail = replay[:before], replay[before:]
        last = head[-1] if head else None
        if isinstance(last, SampleRun):  # a run the late packet falls inside
            first, rest = last.split_at(late.t)
            head.pop()
            head += [first] if len(first) else []
            tail[:0] = [rest] if len(rest) else []
        now = f.snapshot()
        for _ in range(len(groups) - g):
            self._history.pop()
        f.restore(groups[g][0])
        try:
            for p in head:
                self._apply_logged(f, p)  # outputs of replayed packets were already emitted
            out = self._apply_logged(f, late)
        except PacketError:
            f.restore(now)
            self._history = deque(groups)
            raise
        for p in tail:
            self._apply_logged(f, p)
        return out

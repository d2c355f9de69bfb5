"""The reorder window (pure): packets up to ``window_s`` late are applied in time order.

Works for any filter that can ``apply`` a packet in time order, take a ``snapshot`` of its
state and ``restore`` one (:class:`Replayable`): a late packet rolls the filter back to the
last snapshot before it, and the packets since are replayed around it. Older packets are
refused with ``time_backwards``. A snapshot is taken every ``SNAPSHOT_EVERY`` packets, not at
each: a late packet replays a few more, and the copies cost little per packet.

A packet the filter refuses (it raises :class:`PacketError` and changes nothing) is not kept;
a late one that is refused leaves the filter and the window as they were.
"""

from __future__ import annotations

from collections import deque
from typing import Generic, Protocol, TypeVar

from navsvc.errors import PacketError, RejectReason
from navsvc.types import FusedEstimate, Packet

SNAPSHOT_EVERY = 8  # packets between saved states

S = TypeVar("S")  # a filter's snapshot


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


class ReorderWindow(Generic[S]):
    """The packets of the last ``window_s``, in groups each with the state before its first."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self.late_rejected = 0  # packets refused as too late (never rolled back)
        self._history: deque[tuple[S, list[Packet]]] = deque()

    def add(self, f: Replayable[S], packet: Packet) -> list[FusedEstimate]:
        """Apply ``packet`` to ``f`` in time order; the estimates it emitted.

        Raises :class:`PacketError` (``time_backwards``) for a packet older than the window.
        """
        t_now = f.t
        if t_now is None or packet.t >= t_now:
            return self._apply_logged(f, packet)
        if packet.t < t_now - self.window_s or not self._history \
                or packet.t < self._history[0][1][0].t:
            self.late_rejected += 1
            raise PacketError(RejectReason.TIME_BACKWARDS,
                              f"t={packet.t} is {t_now - packet.t:.3f} s before the latest "
                              f"packet (window {self.window_s} s)")
        return self._replay_with(f, packet)

    def clear(self) -> None:
        """Forget the history (after a change that cannot be replayed)."""
        self._history.clear()

    def _apply_logged(self, f: Replayable[S], packet: Packet) -> list[FusedEstimate]:
        if self.window_s <= 0.0:
            return f.apply(packet)
        history = self._history
        new_group = not history or len(history[-1][1]) >= SNAPSHOT_EVERY
        before = f.snapshot() if new_group else None
        out = f.apply(packet)  # a refused packet raises here: not kept
        if before is not None:
            history.append((before, [packet]))
        else:
            history[-1][1].append(packet)
        # a group can go once the next one starts before the window: it covers the rest
        horizon = packet.t - self.window_s
        while len(history) > 1 and history[1][1][0].t < horizon:
            history.popleft()
        return out

    def _replay_with(self, f: Replayable[S], late: Packet) -> list[FusedEstimate]:
        groups = list(self._history)
        g = next(k for k in range(len(groups) - 1, -1, -1) if groups[k][1][0].t <= late.t)
        replay = [p for _, packets in groups[g:] for p in packets]
        before = next((i for i, p in enumerate(replay) if p.t > late.t), len(replay))
        now = f.snapshot()
        for _ in range(len(groups) - g):
            self._history.pop()
        f.restore(groups[g][0])
        try:
            for p in replay[:before]:
                self._apply_logged(f, p)  # outputs of replayed packets were already emitted
            out = self._apply_logged(f, late)
        except PacketError:
            f.restore(now)
            self._history = deque(groups)
            raise
        for p in replay[before:]:
            self._apply_logged(f, p)
        return out

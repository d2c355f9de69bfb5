"""Right road and road changes: the two matching metrics that compare any matcher with the
truth of a simulated drive, at the same epochs (bench helper: ``navsvc.sim.evaluate``'s
right-road share has a 5 m tolerance at intersections only and scores each run at its own
epochs; this one scores every matcher at the drive's GPS fixes, the inputs all of them get).

Roads are the drive's edges taken undirected (``{u, v}``), as ``navsvc.sim.evaluate`` does.
The truth (10 Hz records with ``u``, ``v``) gives the distance driven ``s`` at each epoch and
its sequence of roads, each driven over a span of ``s`` (a *road change* is where one span
ends and the next begins).

* **Epochs**: the drive's GPS fix times, from START_S on (our online matcher's first output
  comes 2 s after its first fix; the first seconds are left out for every matcher alike).
  A matcher's road at an epoch is that of its output at the same time, or none.
* **Right road within TOLERANCE_M along the path**: an epoch is right when the matcher's road
  is one the truth drives on within TOLERANCE_M before or after the epoch's ``s`` (the true
  road, or either road of a change that near: tolerance at junctions). No road is wrong.
  Share of all epochs.
* **Road changes**: the truth's change from road A to road B, at distance ``s_k`` along its
  path, is judged on its *window*: the epochs at which the truth is on A or B within
  CHANGE_WINDOW_M of ``s_k`` (the approach and the exit). It is *observable* when the window
  holds at least one epoch on A and one on B (a road shorter than a second's driving may hold
  none; changes in a GPS outage hold none). It is *made correctly* when every epoch of the
  window is on the right road as in the first metric, and the matcher is on A at one epoch of
  it at least and on B at one at least. A wrong road or no road near the junction, a switch
  to B more than TOLERANCE_M early, staying on A more than TOLERANCE_M past it, or never
  showing A or B fails it; a flicker between A and B within TOLERANCE_M of the junction does
  not; a wrong road further than CHANGE_WINDOW_M from any junction fails no change. Share of
  the observable changes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from roadgraph import LocalFrame

TOLERANCE_M = 10.0  # along the truth's path, either side of an epoch
START_S = 5.0  # epochs before this are left out
CHANGE_WINDOW_M = 50.0  # a road change is judged on the epochs this near it, either side

Road = frozenset[int]


@dataclass(frozen=True)
class RoadScore:
    epochs: int
    right: int
    changes: int  # observable truth road changes
    changes_right: int
    changes_unobservable: int

    @property
    def right_share(self) -> float:
        return self.right / self.epochs if self.epochs else float("nan")

    @property
    def changes_share(self) -> float:
        return self.changes_right / self.changes if self.changes else float("nan")


@dataclass(frozen=True)
class _Span:
    road: Road
    s0_m: float
    s1_m: float


@dataclass(frozen=True)
class TruthPath:
    """The truth of one drive: time, distance driven, span index per record, the spans."""

    t: np.ndarray
    s_m: np.ndarray
    span_of: np.ndarray
    spans: tuple[_Span, ...]

    def span_at(self, t: float) -> int:
        i = int(np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1))
        return int(self.span_of[i])

    def s_at(self, t: float) -> float:
        return float(np.interp(t, self.t, self.s_m))

    def roads_near(self, s_m: float) -> set[Road]:
        """The roads the truth drives on within TOLERANCE_M of ``s_m`` along its path."""
        return {sp.road for sp in self.spans
                if sp.s0_m <= s_m + TOLERANCE_M and sp.s1_m >= s_m - TOLERANCE_M}


def truth_path(drive: list[dict[str, Any]]) -> TruthPath:
    truth = sorted((r for r in drive if r.get("kind") == "truth"), key=lambda r: r["t"])
    frame = LocalFrame.for_point(truth[0]["lon"], truth[0]["lat"])
    xy = frame.coords_to_local(np.array([(r["lon"], r["lat"]) for r in truth]))
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    roads = [frozenset((r["u"], r["v"])) for r in truth]
    starts = [0] + [i for i in range(1, len(roads)) if roads[i] != roads[i - 1]]
    ends = starts[1:] + [len(roads) - 1]
    spans = tuple(_Span(roads[a], float(s[a]), float(s[b])) for a, b in zip(starts, ends))
    span_of = np.searchsorted(np.array(starts), np.arange(len(roads)), side="right") - 1
    return TruthPath(np.array([r["t"] for r in truth]), s, span_of, spans)


def epochs_of(drive: list[dict[str, Any]], truth: TruthPath) -> list[float]:
    return [r["t"] for r in drive if r.get("kind") == "gps"
            and max(START_S, truth.t[0]) <= r["t"] <= truth.t[-1]]


def roads_at(estimates: list[dict[str, Any]], epochs: list[float]) -> list[Road | None]:
    """A run's road at each epoch: that of its output at the same time (within 1 ms)."""
    by_t = {round(r["t"], 3): r.get("edge") for r in estimates}
    edges = [by_t.get(round(t, 3)) for t in epochs]
    return [frozenset((e["u"], e["v"])) if e else None for e in edges]


def score(truth: TruthPath, epochs: list[float], roads: list[Road | None]) -> RoadScore:
    s = [truth.s_at(t) for t in epochs]
    allowed = [truth.roads_near(x) for x in s]
    right = sum(r is not None and r in ok for r, ok in zip(roads, allowed))
    span = [truth.span_at(t) for t in epochs]
    observable = made = 0
    for k in range(1, len(truth.spans)):
        a, b = truth.spans[k - 1], truth.spans[k]
        window = [i for i, sp in enumerate(span) if sp in (k - 1, k)
                  and abs(s[i] - b.s0_m) <= CHANGE_WINDOW_M]
        if {span[i] for i in window} != {k - 1, k}:
            continue
        observable += 1
        got = [roads[i] for i in window]
        made += (all(r is not None and r in allowed[i] for r, i in zip(got, window))
                 and a.road in got and b.road in got)
    return RoadScore(len(epochs), right, observable, made, len(truth.spans) - 1 - observable)

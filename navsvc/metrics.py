"""The service's Prometheus metrics, defined in one place (served as text at ``/v1/metrics``).

Each app has its own registry, so that tests can run several apps in one process. What a
fleet operator watches, per worker: packets accepted and rejected by reason, open sessions,
ingest latency (``navsvc_batch_seconds``), trip-log append and commit latency (and batches
per commit) and size, checkpoint lag (packets a restart would replay, and for how long), and
event-loop lag. Behind the balancer
:func:`merge_expositions` joins every worker's scrape into one, each series labelled with
its ``worker``.
"""

from __future__ import annotations

import asyncio
import functools
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, TypeVar

from prometheus_client import CONTENT_TYPE_LATEST as CONTENT_TYPE
from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.metrics_core import Metric
from prometheus_client.parser import text_string_to_metric_families

__all__ = ["CONTENT_TYPE", "Metrics", "merge_expositions", "watch_event_loop"]

LOOP_LAG_PERIOD_S = 0.25  # the event-loop lag probe sleeps this long, and measures the excess
_FAST_BUCKETS = (0.0001, 0.0002, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 1.0)
F = TypeVar("F", bound=Callable[..., Any])


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.packets_accepted = Counter(
            "navsvc_packets_accepted", "Sensor packets accepted", registry=self.registry)
        self.packets_rejected = Counter(
            "navsvc_packets_rejected", "Sensor packets rejected, by reason", ["reason"],
            registry=self.registry)
        self.positions = Counter(
            "navsvc_positions", "Matched positions sent to clients", registry=self.registry)
        self.sessions = Gauge("navsvc_sessions", "Open sessions", registry=self.registry)
        self.sessions_expired = Counter(
            "navsvc_sessions_expired", "Sessions ended for being idle", registry=self.registry)
        self.ws_dropped = Counter(
            "navsvc_websocket_messages_dropped",
            "Outgoing WebSocket messages dropped because the client read too slowly",
            registry=self.registry)
        self.viewer_dropped = Counter(
            "navsvc_viewer_messages_dropped",
            "Map viewer updates dropped because the viewer read too slowly",
            registry=self.registry)
        self.batch_seconds = Histogram(
            "navsvc_batch_seconds",
            "Time from receiving a batch of packets to its matched positions being logged "
            "and ready to send (fusion, matching, trip log)",
            buckets=(0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 1.0),
            registry=self.registry)
        self.match_seconds = Histogram(
            "navsvc_match_request_seconds", "Time to match one trace (POST /match)",
            buckets=(0.01, 0.05, 0.1, 0.5, 1.0, 5.0, 30.0), registry=self.registry)

        self.triplog_append_seconds = Histogram(
            "navsvc_triplog_append_seconds",
            "Time to write one batch's accepted packets to the trip log (the API's batches "
            "are then committed in groups: navsvc_triplog_commit_seconds)",
            buckets=_FAST_BUCKETS, registry=self.registry)
        self.triplog_commit_seconds = Histogram(
            "navsvc_triplog_commit_seconds",
            "Time to commit one group of batches to the trip log (their replies wait for it)",
            buckets=_FAST_BUCKETS, registry=self.registry)
        self.triplog_commit_batches = Histogram(
            "navsvc_triplog_commit_batches",
            "Batches committed together in one trip-log commit (the messages of one turn of "
            "the event loop)", buckets=(1, 2, 5, 10, 20, 50, 100, 200, 500),
            registry=self.registry)
        self.triplog_bytes = Gauge(
            "navsvc_triplog_bytes", "Size of the trip log's files (database, write-ahead log)",
            ["file"], registry=self.registry)
        self.checkpoint_lag_packets = Gauge(
            "navsvc_checkpoint_lag_packets",
            "Packets logged since their session's last checkpoint, over all sessions: what a "
            "restart would replay", registry=self.registry)
        self.checkpoint_lag_seconds = Gauge(
            "navsvc_checkpoint_lag_seconds",
            "Longest time since the last checkpoint of a session with packets after it",
            registry=self.registry)
        self.event_loop_lag = Histogram(
            "navsvc_event_loop_lag_seconds",
            f"How late the event loop woke a {LOOP_LAG_PERIOD_S} s sleep (time it was busy "
            "and every request waited)", buckets=_FAST_BUCKETS, registry=self.registry)

    def watch_triplog(self, path: Path) -> None:
        """Report the trip log's file sizes at every scrape."""
        for name, file in (("database", path), ("wal", path.with_name(path.name + "-wal"))):
            self.triplog_bytes.labels(name).set_function(functools.partial(_size, file))

    def watch_checkpoints(self, lag: Callable[[], tuple[int, float]]) -> None:
        """Report ``lag()`` (packets, seconds; SessionStore.checkpoint_lag) at every scrape."""
        self.checkpoint_lag_packets.set_function(lambda: lag()[0])
        self.checkpoint_lag_seconds.set_function(lambda: lag()[1])

    def timed_append(self, append: F) -> F:
        """``append`` (TripLog.append) timed into ``navsvc_triplog_append_seconds``."""
        histogram = self.triplog_append_seconds

        @functools.wraps(append)
        def timed(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            try:
                return append(*args, **kwargs)
            finally:
                histogram.observe(time.perf_counter() - start)
        return timed  # type: ignore[return-value]

    def timed_commit(self, triplog: Any) -> Callable[[], None]:
        """``triplog.commit`` (TripLog) timed into ``navsvc_triplog_commit_seconds``, its
        group's size into ``navsvc_triplog_commit_batches``."""
        commit, seconds, batches = triplog.commit, self.triplog_commit_seconds, \
            self.triplog_commit_batches

        @functools.wraps(commit)
        def timed() -> None:
            group = triplog.group
            if group is None:
                return
            start = time.perf_counter()
            try:
                commit()
            finally:
                seconds.observe(time.perf_counter() - start)
                batches.observe(group.batches)
        return timed

    def text(self) -> bytes:
        return generate_latest(self.registry)


def _size(path: Path) -> float:
    try:
        return float(path.stat().st_size)
    except FileNotFoundError:
        return 0.0


async def watch_event_loop(histogram: Histogram, period_s: float = LOOP_LAG_PERIOD_S) -> None:
    """Sleep ``period_s`` again and again; observe how much later than asked each wake-up was."""
    while True:
        start = time.perf_counter()
        await asyncio.sleep(period_s)
        histogram.observe(max(0.0, time.perf_counter() - start - period_s))


class _Families:
    """A collector yielding fixed metric families (for :func:`merge_expositions`)."""

    def __init__(self, families: list[Metric]) -> None:
        self._families = families

    def collect(self) -> Iterator[Metric]:
        return iter(self._families)


def merge_expositions(scrapes: Mapping[str, str], up: Mapping[str, bool]) -> bytes:
    """One exposition of several workers' (text by worker id), every sample labelled
    ``worker``, plus ``navsvc_worker_up`` (1 or 0) for each worker of ``up``."""
    merged: dict[str, Metric] = {}
    for worker, text in scrapes.items():
        for family in text_string_to_metric_families(text):
            into = merged.setdefault(family.name, Metric(family.name, family.documentation,
                                                         family.type, family.unit))
            for sample in family.samples:
                into.samples.append(sample._replace(labels={**sample.labels,
                                                            "worker": worker}))
    workers_up = Metric("navsvc_worker_up", "1 when the worker answered this scrape", "gauge")
    for worker, answered in up.items():
        workers_up.add_sample("navsvc_worker_up", {"worker": worker}, 1.0 if answered else 0.0)
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_Families([*merged.values(), workers_up]))
    return generate_latest(registry)

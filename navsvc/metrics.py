"""The service's Prometheus metrics, defined in one place (served as text at ``/v1/metrics``).

Each app has its own registry, so that tests can run several apps in one process.
"""

from __future__ import annotations

from prometheus_client import CONTENT_TYPE_LATEST as CONTENT_TYPE
from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest

__all__ = ["CONTENT_TYPE", "Metrics"]


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

    def text(self) -> bytes:
        return generate_latest(self.registry)

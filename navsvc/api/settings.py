"""Service settings: command-line options over environment variables over defaults.

| variable | default | what |
|---|---|---|
| ``NAVSVC_MAP`` | (required) | road-graph database to serve |
| ``NAVSVC_TRIPLOG`` | ``<map>.trips.db`` beside the map | trip log (SQLite, WAL) |
| ``NAVSVC_TRIPLOG_SYNC`` | ``normal`` | ``full``: fsync each batch (survives power loss) |
| ``NAVSVC_API_KEYS`` | (empty: open) | comma-separated keys accepted in ``X-API-Key`` |
| ``NAVSVC_MAX_BODY_BYTES`` | 4194304 | largest request body (413 beyond) |
| ``NAVSVC_MAX_BATCH_PACKETS`` | 1000 | packets per POST or WebSocket message (413 beyond) |
| ``NAVSVC_MAX_TRACE_POINTS`` | 20000 | points per ``POST /match`` |
| ``NAVSVC_MAX_SESSIONS_PER_KEY`` | 10000 | open sessions per API key (429 beyond) |
| ``NAVSVC_SESSION_IDLE_S`` | 3600 | a session with no packet for this long ends |
| ``NAVSVC_WS_QUEUE`` | 64 | replies queued per WebSocket before the oldest is dropped |
| ``NAVSVC_STREAM_PORT`` | (none) | the session stream on picows too, on this port (fast_stream) |
| ``NAVSVC_STREAM_HOST`` | 127.0.0.1 | its address (``navsvc serve`` sets it to ``--host``) |
| ``NAVSVC_VIEW_HISTORY`` | 7200 | batches with fixes or positions kept per watched session |
| ``NAVSVC_PROFILES`` | (none) | folder of tuned profiles a session may name (``navsvc tune``) |
| ``NAVSVC_WORKERS`` | 1 | ``navsvc serve``: worker processes behind HAProxy (navsvc.cluster) |
| ``NAVSVC_WORKER_ID`` | (none) | worker k: session ids ``w<k>-...``, trip log ``<triplog>.w<k>`` |
| ``NAVSVC_PEERS`` | (none) | all workers' URLs in order: fleet-wide ``/v1/sessions``, metrics |
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from navsvc.errors import ConfigError
from navsvc.triplog import triplog_path_for


@dataclass(frozen=True)
class Settings:
    map_path: Path
    triplog_path: Path | None = None  # None: beside the map
    triplog_sync: str = "normal"
    api_keys: frozenset[str] = frozenset()
    max_body_bytes: int = 4 * 1024 * 1024
    max_batch_packets: int = 1000
    max_trace_points: int = 20_000
    max_sessions_per_key: int = 10_000
    session_idle_s: float = 3600.0
    ws_queue_messages: int = 64
    view_history_batches: int = 7200  # per session a map viewer watches (navsvc.web.feed)
    profiles_path: Path | None = None  # a folder of tuned profiles (`serve --profiles`)
    worker_id: int | None = None  # one worker of several (navsvc.cluster); None: alone
    peers: tuple[str, ...] = ()  # every worker's base URL, in worker order (self included)
    stream_port: int | None = None  # the picows session stream's port; None: not served
    stream_host: str = "127.0.0.1"

    def __post_init__(self) -> None:
        for name in ("max_body_bytes", "max_batch_packets", "max_trace_points",
                     "max_sessions_per_key", "session_idle_s", "ws_queue_messages",
                     "view_history_batches"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.triplog_sync not in ("normal", "full"):
            raise ConfigError(f"triplog_sync must be normal or full, got {self.triplog_sync!r}")
        if self.stream_port is not None and not 0 <= self.stream_port <= 65535:
            raise ConfigError(f"stream_port must be from 0 to 65535, got {self.stream_port}")
        if self.worker_id is not None and self.worker_id < 0:
            raise ConfigError(f"worker_id must be >= 0, got {self.worker_id}")
        if self.peers and (self.worker_id is None or self.worker_id >= len(self.peers)):
            raise ConfigError(f"NAVSVC_PEERS lists {len(self.peers)} workers, so this one "
                              f"needs a worker id below {len(self.peers)} (NAVSVC_WORKER_ID, "
                              f"--worker-id), got {self.worker_id}")

    def profiles(self) -> dict[str, dict[str, Any]]:
        """The profiles of ``profiles_path`` by name (read once; none without a folder)."""
        return _profiles(self.profiles_path) if self.profiles_path is not None else {}

    @property
    def triplog(self) -> Path:
        """The trip log; a worker's is its own, ``<triplog>.w<k>``."""
        path = self.triplog_path or triplog_path_for(self.map_path)
        return path if self.worker_id is None else path.with_name(
            f"{path.name}.w{self.worker_id}")

    @property
    def session_prefix(self) -> str:
        """What this server's session ids begin with (the balancer routes on it)."""
        return "" if self.worker_id is None else f"w{self.worker_id}-"

    @classmethod
    def from_env(cls, env: Mapping[str, str] = os.environ, **overrides: Any) -> Settings:
        """Settings from ``NAVSVC_*`` variables; ``overrides`` that are not None win."""
        values: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            name = "NAVSVC_" + _ENV_NAMES.get(f.name, f.name).upper()
            if name in env and env[name] != "":
                values[f.name] = _convert(f.name, env[name], name)
        values.update({k: v for k, v in overrides.items() if v is not None})
        if "map_path" not in values:
            raise ConfigError("no map: pass --map DB or set NAVSVC_MAP")
        return cls(**values)


_ENV_NAMES = {"map_path": "map", "triplog_path": "triplog",
              "view_history_batches": "view_history",
              "profiles_path": "profiles"}


@functools.cache
def _profiles(folder: Path) -> dict[str, dict[str, Any]]:
    from navsvc.tuning.profile import read_profiles

    return read_profiles(folder)


_INTS = {"max_body_bytes", "max_batch_packets", "max_trace_points", "max_sessions_per_key",
         "ws_queue_messages", "view_history_batches", "worker_id", "stream_port"}


def _convert(field: str, text: str, env_name: str) -> Any:
    try:
        if field in ("map_path", "triplog_path", "profiles_path"):
            return Path(text)
        if field == "api_keys":
            return frozenset(k.strip() for k in text.split(",") if k.strip())
        if field == "peers":
            return tuple(u.strip().rstrip("/") for u in text.split(",") if u.strip())
        if field in _INTS:
            return int(text)
        if field == "session_idle_s":
            return float(text)
        return text
    except ValueError:
        raise ConfigError(f"{env_name}={text!r} is not a valid number") from None

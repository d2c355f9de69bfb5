"""The whole fleet from any worker: ``/v1/sessions`` and ``/v1/metrics`` across workers.

Behind the balancer (navsvc.cluster) a request that names no session lands on any worker. So
that it still sees every worker, the worker that gets it asks the others
(``NAVSVC_PEERS``) for their part with ``?scope=worker`` and joins the answers: the caller's
sessions on every worker, and every worker's metrics labelled with its ``worker``. A worker
that does not answer within :data:`PEER_TIMEOUT_S` is left out and named
(``workers_unreachable``; ``navsvc_worker_up 0``). The peers are asked in threads (stdlib
``urllib``), so the event loop goes on serving meanwhile.

Chosen over Prometheus scraping each worker alone because one URL through the balancer then
shows everything, on one machine or many, with nothing to configure per worker; Prometheus may
still scrape each worker directly with ``?scope=worker`` (README).
"""

from __future__ import annotations

import asyncio
import urllib.error
import urllib.request
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from navsvc.api.settings import Settings

PEER_TIMEOUT_S = 2.0
Scope = Literal["fleet", "worker"]


@dataclass(frozen=True)
class PeerAnswer:
    """One worker's answer: its id, and its body (None: it did not answer with 200)."""

    worker_id: int
    body: bytes | None


def other_workers(settings: Settings, scope: Scope) -> list[tuple[int, str]]:
    """The workers to ask besides this one: none for ``scope=worker`` or a lone server."""
    if scope == "worker" or settings.worker_id is None:
        return []
    return [(k, url) for k, url in enumerate(settings.peers) if k != settings.worker_id]


def _get(url: str, headers: Mapping[str, str]) -> bytes | None:
    request = urllib.request.Request(url, headers=dict(headers))
    try:
        with urllib.request.urlopen(request, timeout=PEER_TIMEOUT_S) as response:
            body: bytes = response.read()
            return body if response.status == 200 else None
    except (urllib.error.URLError, OSError, ValueError):
        return None


async def ask_workers(workers: list[tuple[int, str]], path: str,
                      headers: Mapping[str, str]) -> list[PeerAnswer]:
    """GET ``path?scope=worker`` of each worker at once, in threads."""
    separator = "&" if "?" in path else "?"
    bodies = await asyncio.gather(*(asyncio.to_thread(
        _get, f"{url}{path}{separator}scope=worker", headers) for _, url in workers))
    return [PeerAnswer(k, body) for (k, _), body in zip(workers, bodies)]

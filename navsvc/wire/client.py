"""A client of the service: create a session, stream packets over its WebSocket, collect the
matched positions, end the session (``navsvc send``, and a model for integrators).

It needs nothing beyond the service's own runtime dependencies: the two REST calls go through
the standard library (``urllib.request``), the stream through ``websockets`` (which the server
uses too), so ``navsvc send`` works in any install, the Docker image's included."""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from websockets.exceptions import ConnectionClosed, InvalidHandshake
from websockets.sync.client import connect

from navsvc.errors import NavsvcError

REFUSED = (4401, 4404)  # WebSocket close codes: bad key, unknown session


class ServiceError(NavsvcError):
    """The service refused a request or could not be reached."""


@dataclass
class StreamResult:
    session_id: str
    positions: list[dict[str, Any]] = field(default_factory=list)
    rejected: list[dict[str, Any]] = field(default_factory=list)  # index: position in the file
    accepted: int = 0
    reconnects: int = 0  # connections that dropped and were made again


def _request(method: str, url: str, path: str, body: Any = None, api_key: str | None = None,
             timeout_s: float = 30.0) -> tuple[int, bytes]:
    """One HTTP request to the service at ``url``; returns the status and body (an error
    status too, not raised)."""
    headers = {"X-API-Key": api_key} if api_key else {}
    data = None
    if body is not None:
        data = json.dumps(body).encode()
        headers["Content-Type"] = "application/json"
    request = urllib.request.Request(url + path, data=data, headers=headers, method=method)
    try:
        with urllib.request.urlopen(request, timeout=timeout_s) as response:
            return int(response.status), bytes(response.read())
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise ServiceError(f"{url}: cannot connect: {reason}") from exc


def create_session(url: str, options: dict[str, Any], api_key: str | None = None) -> str:
    status, body = _request("POST", url, "/v1/sessions", options, api_key)
    if status != 201:
        raise ServiceError(f"{url}: session refused ({status}): {body.decode(errors='replace')}")
    session_id: str = json.loads(body)["id"]
    return session_id


def close_session(url: str, session_id: str, api_key: str | None = None) -> None:
    """End the session (its trip log is dropped); one already gone is not an error."""
    status, body = _request("DELETE", url, f"/v1/sessions/{session_id}", api_key=api_key)
    if status not in (204, 404):
        raise ServiceError(f"{url}: session {session_id} not closed ({status}): "
                           f"{body.decode(errors='replace')}")


def stream_packets(url: str, session_id: str, packets: Sequence[Any], *, batch: int = 10,
                   realtime: bool = False, api_key: str | None = None,
                   progress: Callable[[int], None] | None = None,
                   retries: int = 5) -> StreamResult:
    """Send packets in numbered batches over the session's WebSocket, one reply per batch;
    with ``realtime`` each batch leaves when its last packet's time has come.

    When the connection drops, it reconnects (up to ``retries`` times in a row, waiting a
    little longer each time) and sends the unanswered batch again under the same number: the
    server applies it once, and answers a resend with its first reply."""
    result = StreamResult(session_id)
    ws_url = url.replace("http", "ws", 1) + f"/v1/sessions/{session_id}/stream"
    headers = {"X-API-Key": api_key} if api_key else {}
    start_wall, start_t = time.monotonic(), _first_time(packets)
    seq, failures = 0, 0
    while seq * batch < len(packets):
        try:
            with connect(ws_url, additional_headers=headers, max_size=None) as ws:
                while seq * batch < len(packets):
                    i = seq * batch
                    chunk = packets[i:i + batch]
                    if realtime and start_t is not None:
                        last = chunk[-1]
                        t = float(last["t"]) if isinstance(last, dict) and \
                            _is_number(last.get("t")) else start_t
                        time.sleep(max(0.0, start_wall + t - start_t - time.monotonic()))
                    ws.send(json.dumps({"type": "batch", "seq": seq, "packets": chunk}))
                    reply = json.loads(ws.recv(timeout=60))
                    if reply["type"] == "error":
                        raise ServiceError(f"batch at packet {i}: {reply['code']}: "
                                           f"{reply['message']}")
                    result.accepted += reply["accepted"]
                    result.positions += reply["positions"]
                    result.rejected += [{**r, "index": i + r["index"]}
                                        for r in reply["rejected"]]
                    seq, failures = seq + 1, 0
                    if progress:
                        progress(len(chunk))
        except InvalidHandshake as exc:
            raise ServiceError(f"{ws_url}: {exc}") from exc
        except (OSError, ConnectionClosed, TimeoutError) as exc:
            closed = exc.rcvd if isinstance(exc, ConnectionClosed) else None
            if closed is not None and closed.code in REFUSED:  # no use trying again
                raise ServiceError(f"{ws_url}: refused ({closed.code}): {closed.reason}"
                                   ) from exc
            failures += 1
            result.reconnects += 1
            if failures > retries:
                raise ServiceError(f"{ws_url}: {exc} (gave up after {retries} retries)"
                                   ) from exc
            time.sleep(min(5.0, 0.2 * 2 ** failures))
    return result


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _first_time(packets: Sequence[Any]) -> float | None:
    for p in packets:
        if isinstance(p, dict) and _is_number(p.get("t")):
            return float(p["t"])
    return None

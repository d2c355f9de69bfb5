"""A real navsvc server in a child process (uvicorn on 127.0.0.1), for the API tests."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import httpx


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@dataclass
class Server:
    url: str
    ws_url: str
    process: subprocess.Popen[bytes]
    log: Path

    def client(self, **kwargs: object) -> httpx.Client:
        return httpx.Client(base_url=self.url + "/v1", timeout=30.0, **kwargs)  # type: ignore[arg-type]

    def kill(self) -> None:
        """``kill -9``: no shutdown code runs."""
        self.process.send_signal(signal.SIGKILL)
        self.process.wait(timeout=10)

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill()


def start_server(db: Path, log: Path, env: dict[str, str] | None = None,
                 port: int | None = None) -> Server:
    """``python -m navsvc serve --map DB`` on a loopback port (a free one unless given);
    returns once healthy."""
    return start_process(lambda port: [
        sys.executable, "-m", "navsvc", "serve", "--map", str(db), "--host", "127.0.0.1",
        "--port", str(port)], log, env, port)


def start_process(command: Callable[[int], list[str]], log: Path,
                  env: dict[str, str] | None = None, port: int | None = None) -> Server:
    """A server ``command(port)`` on a loopback port (a free one unless given); returns once
    ``/v1/healthz`` answers."""
    port = port or free_port()
    out = log.open("ab")
    process = subprocess.Popen(command(port), stdout=out, stderr=subprocess.STDOUT,
                               env={**os.environ, **(env or {})})
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 90.0
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"server exited with {process.returncode}: {log.read_text()}")
        try:
            if httpx.get(url + "/v1/healthz", timeout=1.0).status_code == 200:
                return Server(url, f"ws://127.0.0.1:{port}", process, log)
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    process.kill()
    raise RuntimeError(f"server did not become healthy: {log.read_text()}")

"""Where the server's CPU goes: py-spy's collapsed stacks (``service_load.py --profile DIR``)
summed into the parts of a packet's way through the service.

Each sample goes to the innermost frame of its stack that names a part (so the GPS fix's
matcher step counts as matcher, its JSON as the reply, a metric inside the ingest as
metrics); a sample with no such frame is the event loop itself (uvloop, the socket calls).

    python bench/profile_summary.py DIR/0-gyro_accel-200.txt [--us-per-packet 35]
"""

from __future__ import annotations

import argparse
import collections
from pathlib import Path

# (part, substrings of a frame "function (file:line)"), tried in this order on each frame
PARTS: list[tuple[str, tuple[str, ...]]] = [
    ("matcher (OnlineMatcher steps)", ("OnlineMatcher.", "navsvc/matching/")),
    ("filter (engine: runs, GPS fixes)", ("FusionEngine.", "RoadFilter.", "ReorderWindow.",
                                          "navsvc/fusion/")),
    ("trip log (append, commit)", ("TripLog.append", "TripLog.commit", "TripLog._in_group",
                                   "timed_commit")),
    ("trip log: session checkpoints", ("SessionStore.checkpoint", "dump_vehicle")),
    ("trip log: WAL checkpointer thread", ("TripLog._checkpoint",)),
    ("trip log: dropping ended sessions", ("drop_closed",)),
    ("metrics (prometheus_client)", ("prometheus_client/", "Metrics.")),
    ("decode and validate (msgspec, runs)", ("decode_message", "navsvc/wire/bulk.py",
                                             "_Run.", "validate_all")),
    ("reply (positions to JSON)", ("batch_reply", "position_json", "to_json")),
    ("session glue (navsvc/session.py)", ("VehicleSession.", "SessionStore.")),
    ("WebSocket send (reply JSON, uvicorn)", ("WebSocket.send", "send_all",
                                              "WebSocketsSansIOProtocol.send")),
    ("route glue (stream.py, sessions.py)", ("navsvc/api/routes/",)),
    ("picows endpoint (fast_stream.py: frames in, replies out)", ("navsvc/api/fast_stream.py",)),
    ("HTTP requests (sessions opened, closed)", ("httptools_impl",)),
    ("WebSocket receive (uvicorn, websockets)", ("websockets/", "WebSocketsSansIOProtocol",
                                                 "wsproto", "starlette/websockets")),
    ("ASGI stack (starlette, fastapi)", ("starlette/", "fastapi/")),
    ("other threads", ("threading.py",)),
]
EVENT_LOOP = "event loop itself (uvloop, socket calls)"


def part_of(frames: list[str]) -> str:
    for frame in reversed(frames):
        for part, needles in PARTS:
            if any(n in frame for n in needles):
                return part
    return EVENT_LOOP


def summarise(path: Path) -> dict[str, int]:
    """Samples per part, from a collapsed-stack file (``frame;frame;... count``)."""
    samples: collections.Counter[str] = collections.Counter()
    for line in path.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        if stack:
            samples[part_of(stack.split(";"))] += int(count)
    return dict(samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("stacks", type=Path, nargs="+")
    parser.add_argument("--us-per-packet", type=float, default=None,
                        help="the run's server CPU per packet, to split it in microseconds")
    args = parser.parse_args()
    for path in args.stacks:
        samples = summarise(path)
        total = sum(samples.values())
        print(f"{path}: {total} samples")
        for part, n in sorted(samples.items(), key=lambda kv: -kv[1]):
            us = "" if args.us_per_packet is None else \
                f"  {args.us_per_packet * n / total:5.1f} us/packet"
            print(f"  {100.0 * n / total:5.1f} %{us}  {part}")


if __name__ == "__main__":
    main()

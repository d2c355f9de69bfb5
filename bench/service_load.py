"""Load on the real service: throughput, latency and memory with many WebSocket sessions.

Starts ``navsvc serve`` as its own process on a copy of the map (loopback) and drives it from
this process (asyncio, one WebSocket per session). Sessions replay a simulated drive.

- throughput: gyro + odometer sessions (100 Hz IMU, 50 Hz odometer, 1 Hz GPS) send their
  packets as fast as the server answers (batches of 100); packets per second accepted, end
  to end.
- real rate: every 0.1 s each session sends the packets of that 0.1 s (and the GPS fix when
  there is one), each session from its own point of the drive (up to 60 s in) and at its
  own phase of the 0.1 s; latency is from sending a message that holds a GPS fix to
  receiving the reply with its matched position. ``gyro_accel`` sessions send what the issue
  names, 100 Hz inertial (10 IMU packets a message) and 1 Hz GPS: 101 packets/s a session;
  ``gyro_odometer`` sessions also send a 50 Hz wheel odometer (151 packets/s).
- GPS only: sessions created with ``sensors: gps_only`` send one fix a second.
- memory: the server's resident memory before and after opening the sessions, per session.
- floor: the real-rate runs against ``bench/ws_floor.py``, the same FastAPI + uvicorn
  WebSocket stack answering without doing any work: what the transport alone costs.

The server runs in one process, so it uses one core; the load generator takes the other (its
garbage collector is off while it measures latency, as its pauses would be counted as the
server's). "packets/s per core" is packets per second over the server's CPU use (user + system
time per second of the run); "CPU us/packet" is that CPU time per packet, and "cores needed"
what the offered load would take at that cost (above 1 the server cannot keep up).

    python bench/service_load.py [--map maps/monaco.db] [--seconds 20]
        [--real-rate 1,100,200] [--sensors gyro_accel,gyro_odometer] [--gps-only 1000]
        [--throughput 1,4] [--floor 200]
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import websockets
from report import RESULTS, print_table, write_json

from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from roadgraph import RoadGraph
from tests.api.server import Server, start_process, start_server

START_SPREAD_TICKS = 600  # sessions start up to 60 s apart in the drive
GOLDEN_RATIO = (1.0 + 5.0 ** 0.5) / 2.0  # k x this, mod 1: evenly spread, never repeating


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def cpu_s(pid: int) -> float:
    """User + system CPU seconds the process has used."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def drive_packets(map_path: Path, seconds: float) -> list[dict[str, Any]]:
    """The simulated drive's sensor packets (every kind; truth left out)."""
    drive = simulate_drive(RoadGraph.open(map_path), DriveSpec(duration_s=seconds, seed=7,
                                                               tunnels_block_gps=False))
    return [r for r in drive if r["kind"] != "truth"]


def sent_by(packets: list[dict[str, Any]], sensors: str) -> list[dict[str, Any]]:
    """The packets a vehicle with this sensor configuration sends."""
    kinds = set(SENSOR_KINDS[sensors])
    return [p for p in packets if p["kind"] in kinds]


def tick_batches(packets: list[dict[str, Any]], tick_s: float = 0.1) -> list[list[dict]]:
    """The packets of each ``tick_s`` of the drive, in order (empty ticks kept)."""
    end = packets[-1]["t"]
    out: list[list[dict]] = [[] for _ in range(int(end / tick_s) + 1)]
    for p in packets:
        out[int(p["t"] / tick_s)].append(p)
    return out


async def open_sessions(server: Server, count: int, sensors: str) -> list[str]:
    async with httpx.AsyncClient(base_url=server.url + "/v1", timeout=60.0) as client:
        ids = []
        for _ in range(count):
            r = await client.post("/sessions", json={"vehicle_id": "load", "sensors": sensors})
            r.raise_for_status()
            ids.append(r.json()["id"])
        return ids


async def close_sessions(server: Server, ids: list[str]) -> None:
    async with httpx.AsyncClient(base_url=server.url + "/v1", timeout=60.0) as client:
        for sid in ids:
            await client.delete(f"/sessions/{sid}")


async def _exchange(ws: Any, batch: list[dict]) -> dict[str, Any]:
    await ws.send(json.dumps(batch))
    reply: dict[str, Any] = json.loads(await ws.recv())
    if reply.get("type") != "result":
        raise RuntimeError(f"server answered {reply}")
    return reply


async def throughput(server: Server, packets: list[dict], sessions: int) -> dict[str, Any]:
    ids = await open_sessions(server, sessions, "gyro_odometer")
    batches = [packets[i:i + 100] for i in range(0, len(packets), 100)]
    accepted = 0

    async def one(sid: str) -> None:
        nonlocal accepted
        async with websockets.connect(f"{server.ws_url}/v1/sessions/{sid}/stream",
                                      max_size=None) as ws:
            for batch in batches:
                reply = await _exchange(ws, batch)  # not inside `+=`: other sessions add too
                accepted += reply["accepted"]

    start, cpu = time.perf_counter(), cpu_s(server.process.pid)
    await asyncio.gather(*(one(s) for s in ids))
    elapsed = time.perf_counter() - start
    busy = (cpu_s(server.process.pid) - cpu) / elapsed
    await close_sessions(server, ids)
    return {"scenario": "throughput", "sessions": sessions, "packets": accepted,
            "seconds": elapsed, "packets_per_s": accepted / elapsed, "server_cpu": busy,
            "packets_per_cpu_s": accepted / elapsed / max(busy, 1e-9)}


async def real_rate(server: Server, ticks: list[list[dict]], sessions: int, seconds: float,
                    sensors: str) -> dict[str, Any]:
    before = rss_mb(server.process.pid)
    ids = await open_sessions(server, sessions, sensors)
    latencies: list[float] = []
    late = 0
    sent = 0
    offered = sum(len(ticks[(k * 37) % START_SPREAD_TICKS + i])
                  for k in range(sessions) for i in range(int(seconds * 10))) / seconds
    sockets = [await websockets.connect(f"{server.ws_url}/v1/sessions/{sid}/stream",
                                        max_size=None) for sid in ids]
    start = time.perf_counter() + 0.5
    cpu = cpu_s(server.process.pid)
    client_cpu = time.process_time()
    gc.collect()
    gc.disable()  # this process's full collections (100+ ms with 1,000 sockets) are not the
    # server's latency: keep them out of the measurement

    async def one(k: int, ws: Any) -> None:
        nonlocal late, sent
        # each session sends at its own phase of the 0.1 s tick, as independent vehicles do
        # (k / sessions put sessions / 10 of them on the same instant, in bursts)
        offset = 0.1 * ((k * GOLDEN_RATIO) % 1.0)
        # and start each session at its own point of the drive: in step, every session would
        # reach the same junction (and the matcher's costliest moments) in the same second
        first = (k * 37) % START_SPREAD_TICKS
        for i, batch in enumerate(ticks[first:first + int(seconds * 10)]):
            if not batch:
                continue
            due = start + i * 0.1 + offset
            wait = due - time.perf_counter()
            if wait > 0:
                await asyncio.sleep(wait)
            elif wait < -0.1:
                late += 1
            t0 = time.perf_counter()
            reply = await _exchange(ws, batch)
            sent += len(batch)
            if reply["positions"] and any(p["kind"] == "gps" for p in batch):
                latencies.append(time.perf_counter() - t0)

    await asyncio.gather(*(one(k, ws) for k, ws in enumerate(sockets)))
    elapsed = time.perf_counter() - start  # longer than planned when the server fell behind
    gc.enable()
    client_busy = (time.process_time() - client_cpu) / elapsed
    after = rss_mb(server.process.pid)
    busy = (cpu_s(server.process.pid) - cpu) / elapsed
    for ws in sockets:
        await ws.close()
    await close_sessions(server, ids)
    lat_ms = sorted(1e3 * x for x in latencies)
    cpu_per_packet = busy * elapsed / sent
    return {"scenario": f"real rate ({sensors})", "sessions": sessions, "packets": sent,
            "seconds": elapsed, "packets_per_s": sent / elapsed, "offered_per_s": offered,
            "server_cpu_us_per_packet": 1e6 * cpu_per_packet,
            "cores_needed": offered * cpu_per_packet,
            "latency_p50_ms": statistics.median(lat_ms),
            "latency_p99_ms": lat_ms[min(len(lat_ms) - 1, int(0.99 * len(lat_ms)))],
            "late_ticks": late, "server_cpu": busy, "client_cpu": client_busy,
            "rss_before_mb": before, "rss_after_mb": after,
            "mb_per_session": (after - before) / sessions}


def start_floor(log: Path) -> Server:
    """``bench/ws_floor.py`` on a free loopback port; returns once it answers."""
    floor = str(Path(__file__).with_name("ws_floor.py"))
    return start_process(lambda port: [sys.executable, floor, str(port)], log)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--map", type=Path, default=RESULTS.parent.parent / "maps" / "monaco.db")
    parser.add_argument("--seconds", type=float, default=20.0, help="real-rate run length")
    parser.add_argument("--real-rate", default="1,100,200", help="session counts")
    parser.add_argument("--sensors", default="gyro_accel,gyro_odometer",
                        help="sensor configurations of the real-rate sessions")
    parser.add_argument("--gps-only", default="1000", help="session counts")
    parser.add_argument("--throughput", default="1,4", help="session counts")
    parser.add_argument("--floor", default="200",
                        help="session counts of real-rate runs against the bare WebSocket "
                             "stack (bench/ws_floor.py)")
    args = parser.parse_args()
    drive = drive_packets(args.map, args.seconds + START_SPREAD_TICKS / 10 + 5.0)
    packets = sent_by(drive, "gyro_odometer")
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / args.map.name
        shutil.copy(args.map, db)
        server = start_server(db, Path(tmp) / "server.log",
                              env={"NAVSVC_WS_QUEUE": "1024"})
        rows: list[dict[str, Any]] = []
        try:
            for n in map(int, filter(None, args.throughput.split(","))):
                rows.append(asyncio.run(throughput(server, packets, n)))
                print(rows[-1])
            runs = [(sensors, int(n)) for sensors in filter(None, args.sensors.split(","))
                    for n in filter(None, args.real_rate.split(","))]
            runs += [("gps_only", int(n)) for n in filter(None, args.gps_only.split(","))]
            for sensors, n in runs:
                ticks = tick_batches(sent_by(drive, sensors))
                rows.append(asyncio.run(real_rate(server, ticks, n, args.seconds, sensors)))
                print(rows[-1])
        finally:
            server.stop()
        floor = start_floor(Path(tmp) / "floor.log")
        try:
            for sensors in filter(None, args.sensors.split(",")):
                for n in map(int, filter(None, args.floor.split(","))):
                    row = asyncio.run(real_rate(floor, tick_batches(sent_by(drive, sensors)), n,
                                                args.seconds, sensors))
                    rows.append({**row, "scenario": f"floor: bare stack ({sensors})"})
                    print(rows[-1])
        finally:
            floor.stop()
    print_table("navsvc service under load (server: 1 process; loopback WebSocket)",
                ["scenario", "sessions", "offered/s", "packets/s", "server CPU",
                 "packets/s per core", "CPU us/packet", "cores needed", "p50 ms", "p99 ms",
                 "late ticks", "MB/session"],
                [[r["scenario"], r["sessions"], r.get("offered_per_s", ""), r["packets_per_s"],
                  r["server_cpu"], r["packets_per_s"] / max(r["server_cpu"], 1e-9),
                  r.get("server_cpu_us_per_packet", ""), r.get("cores_needed", ""),
                  r.get("latency_p50_ms", ""), r.get("latency_p99_ms", ""),
                  r.get("late_ticks", ""), r.get("mb_per_session", "")] for r in rows])
    write_json("service_load", {"rows": rows})


if __name__ == "__main__":
    main()

"""Load on the real service: throughput, latency and memory with many WebSocket sessions.

Starts ``navsvc serve`` as its own process on a copy of the map (loopback) and drives it from
this process (asyncio, one WebSocket per session). Sessions replay a simulated drive.

- throughput: gyro + odometer sessions (100 Hz IMU, 50 Hz odometer, 1 Hz GPS) send their
  packets as fast as the server answers (batches of 100); packets per second accepted, end
  to end.
- real rate: every 0.1 s each session sends the packets of that 0.1 s (and the GPS fix when
  there is one), each session from its own point of the drive (up to 60 s in) and at its
  own phase of the 0.1 s; latency is from sending a message that holds a GPS fix to
  receiving the reply with its matched position. A server far behind stops the run at 1.5x
  its length ("unsent ticks": what was left). ``gyro_accel`` sessions send what the issue
  names, 100 Hz inertial (10 IMU packets a message) and 1 Hz GPS: 101 packets/s a session;
  ``gyro_odometer`` sessions also send a 50 Hz wheel odometer (151 packets/s).
- GPS only: sessions created with ``sensors: gps_only`` send one fix a second.
- memory: the server's resident memory before and after opening the sessions, per session.
- floor: the real-rate runs against ``bench/ws_floor.py``, the same FastAPI + uvicorn
  WebSocket stack answering without doing any work: what the transport alone costs. With
  ``--floor-stacks`` the floor is measured for each alternative in the same run: uvicorn
  with each of its WebSocket implementations (``uvicorn`` = websockets-sansio, the
  service's; ``uvicorn-websockets``; ``uvicorn-wsproto``), ``granian`` (the same ASGI app),
  ``picows`` (no ASGI), and any of them ``+msgpack``: MessagePack binary frames instead of
  JSON text, both ways.

Servers (``--workers``, run one after the other): ``0`` is one ``navsvc serve`` process with no
balancer (as ``make run``); ``N`` >= 1 is ``navsvc serve --workers N --balancer``, HAProxy in
front of N worker processes, the load going through HAProxy. The server's CPU is that of every
process of it (workers, HAProxy, supervisor); the generator's CPU is this process's, reported
beside it, since on this 2-core machine both come out of the same two cores ("cores used" is
their sum). "others" is the CPU the rest of the machine used meanwhile (from /proc/stat): how
noisy the run was. The load generator's garbage collector is off while it measures latency,
as its pauses would be counted as the server's. "packets/s per core" is packets per second
over the server's CPU use; "CPU us/packet" is that CPU time per packet, and "cores needed"
what the offered load would take at that cost (above the server's cores it cannot keep up).

    python bench/service_load.py [--map maps/monaco.db] [--seconds 20] [--workers 0,1,2]
        [--real-rate 50,100,200,500] [--sensors gyro_accel] [--gps-only ""]
        [--throughput 8] [--floor 50,100,200,500]
        [--floor-stacks uvicorn,uvicorn+msgpack,uvicorn-websockets,uvicorn-wsproto,granian,picows]
        [--profile DIR]
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import msgspec
import websockets
from report import RESULTS, print_table, write_json

from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from roadgraph import RoadGraph

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # for tests.api.server
from tests.api.server import Server, free_port, start_process, start_server  # noqa: E402

START_SPREAD_TICKS = 600  # sessions start up to 60 s apart in the drive
GOLDEN_RATIO = (1.0 + 5.0 ** 0.5) / 2.0  # k x this, mod 1: evenly spread, never repeating
DEADLINE_FACTOR = 1.5  # a real-rate run stops sending at 1.5x its length (the server is behind)


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def cpu_s(pid: int) -> float:
    """User + system CPU seconds the process has used."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def machine_busy_s() -> float:
    """CPU seconds the whole machine has been busy (every core; /proc/stat)."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(values[:8]) - values[3] - values[4]) / os.sysconf("SC_CLK_TCK")


def server_pids(server: Server) -> list[int]:
    """The server's processes: it and all its descendants (a supervisor's workers, HAProxy's
    master and the worker it forks)."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except OSError:
                continue
            parents.setdefault(ppid, []).append(int(entry.name))
    pids, todo = [], [server.process.pid]
    while todo:
        pid = todo.pop()
        pids.append(pid)
        todo += parents.get(pid, [])
    return pids


def is_balancer(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip() == "haproxy"
    except OSError:
        return False


class CpuMeter:
    """CPU seconds of the server's processes, of this process, and of the rest of the
    machine, from when it is made until :meth:`read`."""

    def __init__(self, server: Server) -> None:
        self.pids = server_pids(server)
        self.balancer_pids = [p for p in self.pids if is_balancer(p)]
        self.start = time.perf_counter()
        self.server = sum(map(cpu_s, self.pids))
        self.balancer = sum(map(cpu_s, self.balancer_pids))
        self.client = time.process_time()
        self.machine = machine_busy_s()

    def read(self) -> dict[str, float]:
        """Cores used (CPU seconds per second) by the server, the generator and the rest."""
        elapsed = time.perf_counter() - self.start
        server = (sum(map(cpu_s, self.pids)) - self.server) / elapsed
        balancer = (sum(map(cpu_s, self.balancer_pids)) - self.balancer) / elapsed
        client = (time.process_time() - self.client) / elapsed
        others = (machine_busy_s() - self.machine) / elapsed - server - client
        return {"server_cpu": server, "balancer_cpu": balancer, "client_cpu": client,
                "others_cpu": max(0.0, others),
                "server_cpu_s": server * elapsed, "client_cpu_s": client * elapsed}


def rss_total_mb(server: Server) -> float:
    return sum(rss_mb(pid) for pid in server_pids(server))


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


_UNPACK = msgspec.msgpack.Decoder().decode
WIRES: dict[str, Callable[[Any], str | bytes]] = {"json": json.dumps,
                                                  "msgpack": msgspec.msgpack.Encoder().encode}


async def _exchange(ws: Any, batch: str | bytes) -> dict[str, Any]:
    """Send one batch (JSON text, or MessagePack bytes, encoded beforehand: the generator's
    CPU is the server's too on this machine) and read its reply (in the same format)."""
    await ws.send(batch)
    answer = await ws.recv()
    reply: dict[str, Any] = json.loads(answer) if isinstance(answer, str) else _UNPACK(answer)
    if reply.get("type") != "result":
        raise RuntimeError(f"server answered {reply}")
    return reply


async def throughput(server: Server, packets: list[dict], sessions: int) -> dict[str, Any]:
    ids = await open_sessions(server, sessions, "gyro_odometer")
    batches = [json.dumps(packets[i:i + 100]) for i in range(0, len(packets), 100)]
    accepted = 0

    async def one(sid: str) -> None:
        nonlocal accepted
        async with websockets.connect(f"{server.ws_url}/v1/sessions/{sid}/stream",
                                      max_size=None) as ws:
            for batch in batches:
                reply = await _exchange(ws, batch)  # not inside `+=`: other sessions add too
                accepted += reply["accepted"]

    start, meter = time.perf_counter(), CpuMeter(server)
    await asyncio.gather(*(one(s) for s in ids))
    elapsed = time.perf_counter() - start
    cpu = meter.read()
    await close_sessions(server, ids)
    return {"scenario": "throughput", "sessions": sessions, "packets": accepted,
            "seconds": elapsed, "packets_per_s": accepted / elapsed, **cpu,
            "packets_per_cpu_s": accepted / elapsed / max(cpu["server_cpu"], 1e-9),
            "load_average": os.getloadavg()[0]}


async def real_rate(server: Server, ticks: list[list[dict]], sessions: int, seconds: float,
                    sensors: str, wire: str = "json") -> dict[str, Any]:
    before = rss_total_mb(server)
    ids = await open_sessions(server, sessions, sensors)
    latencies: list[float] = []
    late = 0
    unsent = 0  # ticks not sent by the deadline (a server far behind stops the run)
    sent = 0
    offered = sum(len(ticks[(k * 37) % START_SPREAD_TICKS + i])
                  for k in range(sessions) for i in range(int(seconds * 10))) / seconds
    sockets = [await websockets.connect(f"{server.ws_url}/v1/sessions/{sid}/stream",
                                        max_size=None) for sid in ids]
    encode = WIRES[wire]
    encoded = [[encode(batch) if batch else "" for batch in session_ticks]
               for session_ticks in [ticks[(k * 37) % START_SPREAD_TICKS:
                                           (k * 37) % START_SPREAD_TICKS + int(seconds * 10)]
                                     for k in range(sessions)]]
    has_fix = [[any(p["kind"] == "gps" for p in batch) for batch in
                ticks[(k * 37) % START_SPREAD_TICKS:(k * 37) % START_SPREAD_TICKS
                      + int(seconds * 10)]] for k in range(sessions)]
    start = time.perf_counter() + 0.5
    deadline = start + DEADLINE_FACTOR * seconds
    meter = CpuMeter(server)
    gc.collect()
    gc.disable()  # this process's full collections (100+ ms with 1,000 sockets) are not the
    # server's latency: keep them out of the measurement

    async def one(k: int, ws: Any) -> None:
        nonlocal late, sent, unsent
        # each session sends at its own phase of the 0.1 s tick, as independent vehicles do
        # (k / sessions put sessions / 10 of them on the same instant, in bursts)
        offset = 0.1 * ((k * GOLDEN_RATIO) % 1.0)
        # and start each session at its own point of the drive: in step, every session would
        # reach the same junction (and the matcher's costliest moments) in the same second
        # (``encoded`` and ``has_fix`` hold each session's ticks from there)
        for i, batch in enumerate(encoded[k]):
            if not batch:
                continue
            due = start + i * 0.1 + offset
            wait = due - time.perf_counter()
            if wait > 0:
                await asyncio.sleep(wait)
            elif wait < -0.1:
                late += 1
                if time.perf_counter() > deadline:
                    unsent += sum(1 for b in encoded[k][i:] if b)
                    break
            t0 = time.perf_counter()
            reply = await _exchange(ws, batch)
            sent += reply["accepted"] + len(reply["rejected"])
            if reply["positions"] and has_fix[k][i]:
                latencies.append(time.perf_counter() - t0)

    await asyncio.gather(*(one(k, ws) for k, ws in enumerate(sockets)))
    elapsed = time.perf_counter() - start  # longer than planned when the server fell behind
    cpu = meter.read()
    gc.enable()
    after = rss_total_mb(server)
    for ws in sockets:
        await ws.close()
    await close_sessions(server, ids)
    lat_ms = sorted(1e3 * x for x in latencies)
    cpu_per_packet = cpu["server_cpu_s"] / sent
    return {"scenario": f"real rate ({sensors})", "sessions": sessions, "packets": sent,
            "seconds": elapsed, "packets_per_s": sent / elapsed, "offered_per_s": offered,
            "server_cpu_us_per_packet": 1e6 * cpu_per_packet,
            "cores_needed": offered * cpu_per_packet,
            "latency_p50_ms": statistics.median(lat_ms),
            "latency_p99_ms": lat_ms[min(len(lat_ms) - 1, int(0.99 * len(lat_ms)))],
            "late_ticks": late, "unsent_ticks": unsent, **cpu,
            "load_average": os.getloadavg()[0],
            "rss_before_mb": before, "rss_after_mb": after,
            "mb_per_session": (after - before) / sessions}


def start_floor(log: Path, stack: str = "uvicorn") -> Server:
    """``bench/ws_floor.py`` on a free loopback port with a stack of ``--floor-stacks``
    (its ``+wire`` left out: the floor takes both); returns once it answers."""
    floor = str(Path(__file__).with_name("ws_floor.py"))
    name = stack.split("+")[0]
    server, _, ws = name.partition("-")
    if server not in ("uvicorn", "granian", "picows") or (ws and server != "uvicorn"):
        raise SystemExit(f"unknown floor stack {stack!r}")
    extra = ["--server", server] + (["--ws", ws] if ws else [])
    started = start_process(lambda port: [sys.executable, floor, str(port), *extra], log)
    if server == "picows":  # its WebSocket listens on the next port
        port = int(started.url.rsplit(":", 1)[1])
        started.ws_url = f"ws://127.0.0.1:{port + 1}"
    return started


def floor_wire(stack: str) -> str:
    wire = stack.partition("+")[2] or "json"
    if wire not in WIRES:
        raise SystemExit(f"unknown wire format {wire!r} in floor stack {stack!r}")
    return wire


def start_workers(db: Path, log: Path, workers: int, env: dict[str, str]) -> Server:
    """``navsvc serve --workers N --balancer`` on free loopback ports; returns once every
    worker is up behind HAProxy."""
    base = free_port()
    server = start_process(lambda port: [
        sys.executable, "-m", "navsvc", "serve", "--map", str(db), "--host", "127.0.0.1",
        "--port", str(port), "--workers", str(workers), "--balancer",
        "--worker-port-base", str(base)], log, env)
    deadline = time.monotonic() + 120.0
    while time.monotonic() < deadline:
        text = httpx.get(server.url + "/v1/metrics", timeout=10).text
        if text.count("navsvc_worker_up{") == workers and "} 0.0" not in "".join(
                line for line in text.splitlines() if line.startswith("navsvc_worker_up")):
            return server
        time.sleep(0.5)
    server.stop()
    raise RuntimeError(f"workers did not come up: {log.read_text()[-2000:]}")


def profiler(server: Server, folder: Path | None, name: str, seconds: float
             ) -> subprocess.Popen[bytes] | None:
    """py-spy sampling the server's processes for a real-rate run (``--profile DIR``): the
    collapsed stacks in ``DIR/NAME.txt`` (for flamegraph.pl or speedscope); None without."""
    if folder is None:
        return None
    folder.mkdir(parents=True, exist_ok=True)
    spy = shutil.which("py-spy", path=str(Path(sys.executable).parent)) or "py-spy"
    return subprocess.Popen(
        [spy, "record", "--pid", str(server.process.pid), "--subprocesses", "--nonblocking",
         "--format", "raw", "--rate", "200", "--duration", str(int(seconds) + 1),
         "--output", str(folder / f"{name}.txt")],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def server_name(workers: int) -> str:
    return "1 process" if workers == 0 else f"{workers} worker{'s' * (workers > 1)} + HAProxy"


def counts(text: str) -> list[int]:
    return [int(n) for n in text.split(",") if n.strip()]


def run_server(db: Path, tmp: Path, workers: int, drive: list[dict], args: argparse.Namespace
               ) -> list[dict[str, Any]]:
    """Every scenario against one server (``workers`` 0: a single process, no balancer)."""
    env = {"NAVSVC_WS_QUEUE": "1024"}
    stream_port = free_port() if args.stream == "picows" else None
    if stream_port is not None:  # the WebSockets go to the picows endpoint on this port
        env["NAVSVC_STREAM_PORT"] = str(stream_port)
    log = tmp / f"server-{workers}.log"
    server = start_server(db, log, env=env) if workers == 0 else \
        start_workers(db, log, workers, env)
    if stream_port is not None:
        server.ws_url = f"ws://127.0.0.1:{stream_port}"
    rows: list[dict[str, Any]] = []
    try:
        for n in counts(args.throughput):
            rows.append(asyncio.run(throughput(server, sent_by(drive, "gyro_odometer"), n)))
            print({**rows[-1], "server": server_name(workers)}, flush=True)
        runs = [(sensors, n) for sensors in filter(None, args.sensors.split(","))
                for n in counts(args.real_rate)]
        runs += [("gps_only", n) for n in counts(args.gps_only)]
        for sensors, n in runs:
            ticks = tick_batches(sent_by(drive, sensors))
            spy = profiler(server, args.profile, f"{workers}-{sensors}-{n}", args.seconds)
            rows.append(asyncio.run(real_rate(server, ticks, n, args.seconds, sensors)))
            if spy is not None:
                spy.wait(timeout=60)
            print({**rows[-1], "server": server_name(workers)}, flush=True)
    finally:
        server.stop()
        for suffix in ("", "-wal", "-shm"):  # the next server starts on an empty log
            for old in tmp.glob(f"*.trips.db*{suffix}"):
                old.unlink(missing_ok=True)
    name = server_name(workers) + (" (picows)" if stream_port is not None else "")
    return [{**r, "server": name, "workers": workers} for r in rows]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--map", type=Path, default=RESULTS.parent.parent / "maps" / "monaco.db")
    parser.add_argument("--seconds", type=float, default=15.0, help="real-rate run length")
    parser.add_argument("--workers", default="0,1,2",
                        help="servers, one after the other: 0 = one process, no balancer; "
                             "N = N workers behind HAProxy (default 0,1,2)")
    parser.add_argument("--real-rate", default="50,100,200,500", help="session counts")
    parser.add_argument("--sensors", default="gyro_accel",
                        help="sensor configurations of the real-rate sessions (gyro_accel, "
                             "gyro_odometer, ...)")
    parser.add_argument("--gps-only", default="", help="session counts (e.g. 1000)")
    parser.add_argument("--throughput", default="8",
                        help="session counts of the saturation runs")
    parser.add_argument("--floor", default="50,100,200,500",
                        help="session counts of real-rate runs against the bare WebSocket "
                             "stack (bench/ws_floor.py)")
    parser.add_argument("--floor-stacks", default="uvicorn",
                        help="floor stacks, one after the other: uvicorn (websockets-sansio, "
                             "as navsvc serve), uvicorn-websockets, uvicorn-wsproto, granian, "
                             "picows; '+msgpack' for MessagePack frames (default uvicorn)")
    parser.add_argument("--stream", choices=("uvicorn", "picows"), default="uvicorn",
                        help="the service's WebSocket endpoint the sessions stream to: "
                             "uvicorn's (the API's port) or picows's (navsvc serve "
                             "--stream-port; default uvicorn)")
    parser.add_argument("--profile", type=Path, default=None, metavar="DIR",
                        help="sample the server with py-spy during each real-rate run, the "
                             "stacks into DIR (collapsed format)")
    args = parser.parse_args()
    drive = drive_packets(args.map, max(120.0, args.seconds + START_SPREAD_TICKS / 10 + 5.0))
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / args.map.name
        shutil.copy(args.map, db)
        for workers in counts(args.workers):
            rows += run_server(db, Path(tmp), workers, drive, args)
        for stack in filter(None, args.floor_stacks.split(",")):
            floor = start_floor(Path(tmp) / "floor.log", stack)
            try:
                for sensors in filter(None, args.sensors.split(",")):
                    for n in counts(args.floor):
                        row = asyncio.run(real_rate(
                            floor, tick_batches(sent_by(drive, sensors)), n, args.seconds,
                            sensors, floor_wire(stack)))
                        rows.append({**row, "scenario": f"floor: bare stack ({sensors})",
                                     "server": f"floor: {stack}", "workers": 0})
                        print(rows[-1], flush=True)
            finally:
                floor.stop()
    print_tables(rows)
    write_json("service_load", {"rows": rows, "scaling": scaling(rows),
                                "argv": sys.argv[1:]})


def scaling(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Saturation packets/s of N workers over 1 worker (both behind HAProxy), as measured
    and per core the servers used."""
    sat = {r["workers"]: r for r in rows if r["scenario"] == "throughput"}
    if 1 not in sat:
        return {}
    one = sat[1]
    return {str(w): {"packets_per_s_ratio": r["packets_per_s"] / one["packets_per_s"],
                     "packets_per_server_cpu_s_ratio":
                         r["packets_per_cpu_s"] / one["packets_per_cpu_s"]}
            for w, r in sat.items() if w >= 1}


def print_tables(rows: list[dict[str, Any]]) -> None:
    sat = [r for r in rows if r["scenario"] == "throughput"]
    if sat:
        print_table("saturation: sessions send as fast as the server answers (gyro_odometer, "
                    "batches of 100); cores = CPU seconds per second",
                    ["server", "sessions", "packets/s", "server cores", "of which HAProxy",
                     "generator cores", "others' cores", "packets/s per server core", "load avg"],
                    [[r["server"], r["sessions"], r["packets_per_s"], r["server_cpu"],
                      r["balancer_cpu"], r["client_cpu"], r["others_cpu"], r["packets_per_cpu_s"],
                      r["load_average"]] for r in sat])
    for w, ratio in scaling(rows).items():
        print(f"  {w} worker(s) / 1 worker: packets/s x{ratio['packets_per_s_ratio']:.2f}, "
              f"per server core x{ratio['packets_per_server_cpu_s_ratio']:.2f}")
    real = [r for r in rows if r["scenario"] != "throughput"]
    print_table("real rate: every 0.1 s each session sends that 0.1 s of packets; latency "
                "from sending a message with a GPS fix to its position",
                ["server", "scenario", "sessions", "offered/s", "packets/s", "server cores",
                 "of which HAProxy", "generator cores", "others' cores", "CPU us/packet",
                 "cores needed",
                 "p50 ms", "p99 ms", "late ticks", "unsent ticks", "MB/session"],
                [[r["server"], r["scenario"], r["sessions"], r["offered_per_s"],
                  r["packets_per_s"], r["server_cpu"], r["balancer_cpu"], r["client_cpu"],
                  r["others_cpu"],
                  r["server_cpu_us_per_packet"], r["cores_needed"], r["latency_p50_ms"],
                  r["latency_p99_ms"], r["late_ticks"], r["unsent_ticks"], r["mb_per_session"]]
                 for r in real])


if __name__ == "__main__":
    main()

"""Independent tasks in one process or on Dask distributed; and batch matching of traces.

Tuning evaluations (``navsvc tune``) and traces of a fleet (``navsvc match``) are independent
tasks over one map. :func:`executor` gives the same interface for three places to run them:

* in this process (``workers=0``, or Dask not installed): tasks run one after another;
* a local Dask cluster of ``workers`` processes on 127.0.0.1 (``--workers N``);
* an existing Dask cluster (``--scheduler ADDRESS``), unchanged.

The map is opened once per process (:func:`worker_graph`, cached by path), not once per task:
a Dask worker keeps it between tasks. Large inputs shared by every task (the drives of a tuning
run) are sent to each worker once (:meth:`Executor.share`). On a remote cluster the map path
must exist on the workers.

Batch matching (:func:`match_file`) reads one trace, matches it with the HMM of
``navsvc.matching.hmm`` and writes its route JSON; a bad trace comes back as an error naming
its file (and line), and the others go on.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from navsvc.errors import ConfigError, NavsvcError
from navsvc.matching.hmm import HmmConfig
from roadgraph import RoadGraph, RoadGraphError

SCHEDULER_TIMEOUT_S = 10.0  # to connect to a cluster named by --scheduler

# The Dask settings of a local cluster (bench/batch_scaling.py measured each):
# * the workers' statistical profiler samples every 10 ms holding the GIL: a replay took 1.35x
#   as long on one worker as in this process; without it, the same;
# * the event loops' housekeeping (a health tick every 20 ms, the memory monitor every 100 ms,
#   the system monitor every 500 ms) kept an idle cluster of 2 workers at 7 % of a core (its
#   scheduler and nannies 3.9 %, each worker 1.7 %); at 1 s / 1 s / 5 s, 1.2 %. Replays and
#   traces are seconds of CPU-bound work with a few MB in memory: nothing needs faster checks;
# * one thread per worker for every numeric library (Dask sets OMP, MKL and OpenBLAS; numba
#   too, should a kernel ever run parallel): with 2 workers on 2 cores more would oversubscribe.
LOCAL_CLUSTER_CONFIG: dict[str, Any] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.nanny.pre-spawn-environ.NUMBA_NUM_THREADS": 1,
}


@lru_cache(maxsize=4)
def worker_graph(path: str) -> RoadGraph:
    """The map at ``path``, opened once per process."""
    return RoadGraph.open(path)


class Executor:
    """Runs ``fn(*args)`` for each task; results as they complete, with their index."""

    workers = 1
    where = "in process"
    distributed = False  # True on Dask

    def share(self, value: Any) -> Any:
        """A handle to ``value`` for the tasks' arguments (sent to each worker once)."""
        return value

    def run(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]
            ) -> Iterator[tuple[int, Any]]:
        for i, args in enumerate(tasks):
            yield i, fn(*args)

    def warm_up(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` once in every worker process (here: once in this one)."""
        fn(*args)

    def cpu_seconds(self) -> float:
        """CPU seconds used so far by the processes that run the tasks (here: this one; on
        Dask: the workers, each process's every thread), for CPU per task against wall."""
        return time.process_time()

    def close(self) -> None:
        """Stop what this executor started (a local cluster)."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class DaskExecutor(Executor):
    """Tasks on a Dask distributed cluster: a local one it starts, or one it joins."""

    distributed = True

    def __init__(self, workers: int | None = None, scheduler: str | None = None) -> None:
        try:
            import dask
            from distributed import Client, LocalCluster
        except ImportError:
            raise ConfigError("Dask distributed is not installed: pip install "
                              "'navsvc[distributed]' (or run without --workers/--scheduler)"
                              ) from None
        logging.getLogger("distributed").setLevel(logging.WARNING)  # its INFO lines on close
        self._cluster = None
        if scheduler is not None:
            try:
                self._client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)  # type: ignore[no-untyped-call]
            except (OSError, TimeoutError) as exc:
                raise ConfigError(f"cannot reach the Dask scheduler at {scheduler}: {exc}"
                                  ) from None
            self.where = f"on the Dask cluster at {scheduler}"
        else:
            n = workers or os.cpu_count() or 1
            dask.config.set(LOCAL_CLUSTER_CONFIG)
            # every port on loopback; the scheduler's HTTP server (health, metrics) on a free
            # port (with None it still took 8787, and a second cluster warned of the clash)
            self._cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                         host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                         silence_logs=40)  # type: ignore[no-untyped-call]
            self._client = Client(self._cluster)  # type: ignore[no-untyped-call]
            self.where = f"on a local Dask cluster of {n} processes"
        self.workers = max(len(self._client.scheduler_info().get("workers", {})), 1)

    def share(self, value: Any) -> Any:
        return self._client.scatter(value, broadcast=True, hash=False)  # type: ignore[no-untyped-call]

    def run(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]
            ) -> Iterator[tuple[int, Any]]:
        from distributed import as_completed

        futures = [self._client.submit(fn, *args, pure=False) for args in tasks]
        index = {f.key: i for i, f in enumerate(futures)}
        for future in as_completed(futures):  # type: ignore[no-untyped-call]
            yield index[future.key], future.result()

    def warm_up(self, fn: Callable[..., Any], *args: Any) -> None:
        self._client.run(fn, *args)

    def cpu_seconds(self) -> float:
        return float(sum(self._client.run(time.process_time).values()))

    def close(self) -> None:
        self._client.close()  # type: ignore[no-untyped-call]
        if self._cluster is not None:
            self._cluster.close()


def executor(workers: int | None = None, scheduler: str | None = None) -> Executor:
    """In process when ``workers`` is 0 and no scheduler is named; else on Dask (``workers``
    None: one process per core)."""
    if scheduler is None and workers == 0:
        return Executor()
    if workers is not None and workers < 0:
        raise ConfigError(f"--workers must be >= 0, got {workers}")
    return DaskExecutor(workers, scheduler)


def open_map(path: str) -> None:
    """Open the map in this process, and import the matcher and the tuning replay (a
    worker's warm-up: its first task then costs what the others do)."""
    import navsvc.tuning.replay  # noqa: F401
    import navsvc.wire.route  # noqa: F401

    worker_graph(path)


# --- batch matching -----------------------------------------------------------------------

@dataclass(frozen=True)
class TraceSummary:
    """One trace of a batch: what it gave, or why it failed."""

    trace: str
    output: str | None = None
    points: int = 0
    matched_share: float = 0.0
    segments: int = 0
    length_m: float = 0.0
    time_s: float = 0.0
    error: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if v is not None or k == "error"}


def match_file(map_path: str, trace: str, output: str, config: HmmConfig) -> TraceSummary:
    """Match one trace file and write its route JSON to ``output`` (a worker's task)."""
    from navsvc.wire.route import match_trace
    from navsvc.wire.traces import read_trace

    started = time.perf_counter()
    try:
        route = match_trace(worker_graph(map_path), read_trace(Path(trace)), config)
        _write(Path(output), json.dumps(route, ensure_ascii=False))
    except (NavsvcError, RoadGraphError) as exc:
        message = str(exc)
        return TraceSummary(trace, error=message if message.startswith(trace)
                            else f"{trace}: {message}", time_s=time.perf_counter() - started)
    except Exception as exc:  # noqa: BLE001 (a fault of ours on one trace: the batch goes on)
        return TraceSummary(trace, error=f"{trace}: {type(exc).__name__}: {exc}",
                            time_s=time.perf_counter() - started)
    points = route["points"]
    matched = sum(1 for p in points if p["matched"] is not None)
    return TraceSummary(trace, output, len(points), matched / len(points) if points else 0.0,
                        len(route["segments"]), route["length_m"],
                        time.perf_counter() - started)


def match_files(map_path: str, jobs: Sequence[tuple[str, str]], config: HmmConfig
                ) -> list[TraceSummary]:
    """Several traces in one task (``(trace, output)`` each): a trace takes a few ms, a Dask
    task's round trip about as long, so a batch sends them in chunks."""
    return [match_file(map_path, trace, output, config) for trace, output in jobs]


def chunks(items: Sequence[Any], workers: int, per_worker: int = 4) -> list[list[Any]]:
    """``items`` in order, in about ``per_worker`` chunks per worker; ``workers`` 0 (in
    process, where a task costs nothing): one item per chunk, for the progress bar.

    On Dask even one worker gets chunks: one trace per task made 1 worker match 32 traces/s
    against 117 in process (300-point traces of about 9 ms CPU each, and a task's round trip
    about as long), measured by bench/batch_scaling.py."""
    size = 1 if workers <= 0 else max(1, -(-len(items) // (workers * per_worker)))
    return [list(items[i:i + size]) for i in range(0, len(items), size)]


def _write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)
    except OSError as exc:
        raise NavsvcError(f"{path}: cannot write ({exc.strerror})") from None


TRACE_SUFFIXES = (".gpx", ".geojson", ".json", ".csv", ".jsonl", ".ndjson")


def expand_traces(inputs: Sequence[str]) -> list[Path]:
    """Files, folders (their trace files, sorted) and globs, in order, without repeats."""
    import glob

    found: list[Path] = []
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            found += sorted(p for p in path.iterdir()
                            if p.is_file() and p.suffix.lower() in TRACE_SUFFIXES)
        elif path.exists():
            found.append(path)
        elif glob.has_magic(item):
            matches = sorted(Path(p) for p in glob.glob(item, recursive=True))
            if not matches:
                raise ConfigError(f"{item}: no file matches")
            found += [p for p in matches if p.is_file()]
        else:
            raise ConfigError(f"{item}: no such file or folder")
    unique = list(dict.fromkeys(found))
    if not unique:
        raise ConfigError("no trace files found in " + ", ".join(inputs))
    return unique


def output_paths(traces: Sequence[Path], folder: Path) -> list[Path]:
    """``folder``/STEM.route.json per trace (``STEM-2`` and so on when stems repeat)."""
    seen: dict[str, int] = {}
    out = []
    for t in traces:
        n = seen[t.stem] = seen.get(t.stem, 0) + 1
        out.append(folder / (f"{t.stem}.route.json" if n == 1 else f"{t.stem}-{n}.route.json"))
    return out

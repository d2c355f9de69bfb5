"""A finished drive or run, as the map page replays it (``navsvc view FILE``).

Two kinds of file, told apart by their records:

- a drive (``navsvc simulate``, or a vehicle's recorded packets): its sensor packets go
  through the same :class:`~navsvc.session.VehicleSession` as a live session (as ``navsvc
  run``), giving the raw fixes and the matched positions; its ``kind: "truth"`` records are
  the truth track, drawn with ``--truth``;
- a run (``navsvc run`` or ``navsvc send -o``): matched positions only; the raw fixes are not
  in it.

The result is the JSON of ``GET /v1/view/replay``: ``{"source", "kind", "fixes",
"positions", "truth", "rejected", "problems"}``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from navsvc.errors import TraceError
from navsvc.session import VehicleSession, config_from_options
from navsvc.web.feed import fixes_of
from navsvc.wire.jsonl import Line, iter_lines
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph

POSITION_FIELDS = frozenset({"t", "lat", "lon", "fused_lat", "fused_lon", "state"})
MAX_PROBLEMS = 20  # bad lines named in the replay (and printed), at most


def _is_position(value: Any) -> bool:
    return isinstance(value, dict) and POSITION_FIELDS <= value.keys()


def _truth_fix(r: dict[str, Any]) -> bool:
    return r.get("kind") == "truth" and isinstance(r.get("lat"), (int, float)) \
        and isinstance(r.get("lon"), (int, float)) and isinstance(r.get("t"), (int, float))


def load_replay(path: Path, graph: RoadGraph, options: dict[str, Any] | None = None,
                with_truth: bool = False) -> dict[str, Any]:
    """The replay of a drive or run file (see the module's docstring). Raises TraceError for
    a file that cannot be read or holds neither packets nor positions."""
    lines = list(iter_lines(path))
    problems = [f"{path}:{line.number}: {line.error}" for line in lines if line.error]
    values = [line for line in lines if line.error is None]
    if not values:
        raise TraceError(f"{path}: no records")
    if all(_is_position(line.value) for line in values):
        replay = {"kind": "run", "fixes": [], "positions": [line.value for line in values],
                  "truth": [], "rejected": 0}
    else:
        replay = _run_drive(path, values, graph, options or {}, problems)
        if not replay["positions"] and not replay["fixes"]:
            raise TraceError(f"{path}: neither sensor packets with a GPS fix nor matched "
                             f"positions ({replay['rejected']} records refused)")
        if with_truth:
            replay["truth"] = [{"t": r["t"], "lat": r["lat"], "lon": r["lon"]}
                               for r in (line.value for line in values)
                               if isinstance(r, dict) and _truth_fix(r)]
    return {"source": path.name, **replay, "problems": problems[:MAX_PROBLEMS]}


def _run_drive(path: Path, lines: list[Line], graph: RoadGraph, options: dict[str, Any],
               problems: list[str]) -> dict[str, Any]:
    """The drive's packets through a session, line by line (as ``navsvc run``)."""
    session = VehicleSession(config_from_options(options), graph)
    fixes: list[dict[str, Any]] = []
    positions: list[dict[str, Any]] = []
    rejected = 0
    for line in lines:
        result = session.add_records([line.value], first_index=line.number)
        for r in result.rejections:
            problems.append(f"{path}:{line.number}: {r.reason.code}: {r.detail}")
        rejected += len(result.rejections)
        fixes += fixes_of(result.records)
        positions += [position_json(p, graph.frame) for p in result.positions]
    return {"kind": "drive", "fixes": fixes, "positions": positions, "truth": [],
            "rejected": rejected}

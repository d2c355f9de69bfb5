"""One evaluation of a parameter set on one drive: replay it through a session, score it.

The replay is the code of ``navsvc run`` (:class:`navsvc.session.VehicleSession` on the
drive's records, those of the sensor configuration only, as ``navsvc send`` sends them); the
score is :mod:`navsvc.tuning.fitness`. A drive carries its truth records, or the geometry of
its known route (a real log). Pure apart from the graph, which the caller opens once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely

from navsvc.errors import ConfigError
from navsvc.session import VehicleSession, config_from_options
from navsvc.sim.evaluate import evaluate
from navsvc.sim.simulate import SENSOR_KINDS
from navsvc.tuning.fitness import DriveScore, failed, route_score, truth_score
from navsvc.wire.positions import position_json
from roadgraph import RoadGraph


@dataclass(frozen=True)
class TuneDrive:
    """A drive to tune on: its records, and its route when it has no truth."""

    name: str
    records: tuple[dict[str, Any], ...]
    route: shapely.Geometry | None = None  # in the map's metres
    map_path: str | None = None  # its own map (bench/tune_eval.py); None: the run's map

    @property
    def has_truth(self) -> bool:
        return any(r.get("kind") == "truth" for r in self.records)


def replay(graph: RoadGraph, drive: TuneDrive, options: dict[str, Any],
           parameters: dict[str, Any]) -> DriveScore:
    """The score of ``drive`` under the session ``options`` with ``parameters`` set."""
    try:
        config = config_from_options({**options, "profile": {
            **_parameters(options.get("profile")), **parameters}})
        session = VehicleSession(config, graph)
    except ConfigError as exc:
        return failed(f"configuration refused: {exc}")
    kinds = set(SENSOR_KINDS[config.fusion.sensors.value])
    result = session.add_records([r for r in drive.records if r.get("kind") in kinds])
    positions = [position_json(p, graph.frame) for p in result.positions]
    if not positions:
        return failed("the replay produced no position")
    if drive.route is not None:
        return route_score(drive.route, _xy(graph, positions, "lat", "lon"),
                           _xy(graph, positions, "fused_lat", "fused_lon"))
    try:
        return truth_score(evaluate(list(drive.records), positions))
    except ValueError as exc:
        return failed(str(exc))


def _xy(graph: RoadGraph, positions: list[dict[str, Any]], lat: str, lon: str
        ) -> np.ndarray:
    lonlat = np.array([(p[lon], p[lat]) for p in positions if p[lat] is not None],
                      dtype=np.float64).reshape(-1, 2)
    return graph.frame.coords_to_local(lonlat)


def _parameters(profile: Any) -> dict[str, Any]:
    """The parameters of the options' own profile (the start of a run), if any."""
    if not isinstance(profile, dict):
        return {}
    found = profile.get("parameters", profile)
    return dict(found) if isinstance(found, dict) else {}

"""Compile (or load from numba's on-disk cache) the filter kernels before serving.

numba compiles each kernel at its first call: ~30 s for the road filter and the strapdown INS
together on a cold cache, then ~1 s to load them from the cache (``__pycache__`` beside the
source, or ``NUMBA_CACHE_DIR``). A server warms up in its start-up, before it answers, so that
no client's first packets stall; the Docker image runs ``navsvc serve --warm-up-only`` at
build time so that the container starts on a filled cache.

The warm-up drives are simulated on the served map (a few seconds each), so they go through
the same start-up rules as a real vehicle's packets and keep doing so when those change.
"""

from __future__ import annotations

import logging
import time

from navsvc.session import VehicleSession, config_from_options
from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
from roadgraph import RoadGraph

log = logging.getLogger(__name__)

# (sensor configuration, GPS modes): every kernel family the sessions use
WARM_UP_RUNS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("gyro_odometer", ("ekf", "rules", "fuzzy")),
    ("steering_odometer", ("ekf",)),
    ("gyro_two_accels", ("ekf",)),
    ("gps_only", ("ekf",)),
    ("strapdown", ("ekf",)),
)
WARM_UP_DRIVE_S = 8.0


def warm_up(graph: RoadGraph) -> float:
    """Run a short simulated drive through a throwaway session of each sensor configuration;
    return the seconds it took. Logs what it does (a cold cache takes ~30 s)."""
    start = time.perf_counter()
    log.info("warming up: loading the filter kernels (compiling them when the numba cache is "
             "empty, ~30 s; then cached)")
    for sensors, modes in WARM_UP_RUNS:
        drive = simulate_drive(graph, DriveSpec(duration_s=WARM_UP_DRIVE_S, seed=1,
                                                sensors=SENSOR_KINDS[sensors],
                                                full_imu=sensors == "strapdown"))
        for mode in modes:
            t0 = time.perf_counter()
            session = VehicleSession(config_from_options({"sensors": sensors, "fusion": mode}),
                                     graph)
            result = session.add_records(drive)
            if not result.positions or result.rejections:
                log.warning("warm-up %s/%s: %d positions, %d packets refused", sensors, mode,
                            len(result.positions), len(result.rejections))
            log.debug("warm-up %s/%s: %.2f s", sensors, mode, time.perf_counter() - t0)
    elapsed = time.perf_counter() - start
    log.info("warm-up done in %.1f s", elapsed)
    return elapsed

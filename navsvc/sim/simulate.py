"""Simulated drives on a road graph, with truth and realistic sensor errors (pure, seeded).

A route is a random walk over the graph (no U-turns except at dead ends). Its polyline is
smoothed through corners (Chaikin corner cutting), a speed profile respects the road class,
lateral acceleration in curves, acceleration and braking limits and stops at some
intersections; the vehicle follows it in time. Sensors see the truth through the errors of
:class:`SensorErrors`: gyro bias, bias drift and noise; odometer scale error and tick
quantisation; accelerometer bias and noise; steering bias and noise; GPS Gauss-Markov
correlated error plus white noise, multipath jumps, and outages (explicit windows, and
tunnels).

Harsher errors, all off by default (so that an existing :class:`DriveSpec` simulates the same
drive, bit for bit): gyro scale factor and a given turn-on bias; a given odometer scale and
speed-only odometers; GPS course noise that grows as speed falls and no course or speed below
a threshold; receivers that send no course, speed or HDOP; non-line-of-sight (NLOS) runs,
long biased stretches that the HDOP does not show; GPS latency (the fix at ``t`` is where the
car was ``gps_latency_s`` earlier); a standstill at the start; and a recorded real error in
place of the synthetic one (:mod:`navsvc.sim.gnss_replay`). :mod:`navsvc.sim.harsh` draws
them per drive. Draws for these come from a second random stream of the seed, so the first
stream (route, stops and the default errors) is drawn as before.

Output: records in the wire format of interfaces.md (packets plus ``kind: "truth"``), time
ordered, ``t`` in seconds since the start of the drive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import networkx as nx
import numpy as np
import numpy.typing as npt

from navsvc.sim.gnss_replay import GnssErrorRecording, replay_error
from roadgraph import EdgeKey, RoadGraph
from roadgraph.geometry import FloatArray

_SPEED_BY_HIGHWAY_MPS = {
    "motorway": 25.0, "motorway_link": 15.0, "trunk": 20.0, "trunk_link": 13.0,
    "primary": 14.0, "primary_link": 11.0, "secondary": 12.5, "secondary_link": 10.0,
    "tertiary": 11.0, "tertiary_link": 9.0, "unclassified": 9.0, "residential": 8.5,
    "living_street": 4.0, "service": 5.0,
}


SENSOR_KINDS: dict[str, tuple[str, ...]] = {
    "all": ("imu", "odometer", "steering", "gps"),
    "gyro_odometer": ("imu", "odometer", "gps"),
    "steering_odometer": ("steering", "odometer", "gps"),
    "gyro_accel": ("imu", "gps"),
    "gyro_two_accels": ("imu", "gps"),
    "gps_only": ("gps",),
    "strapdown": ("imu", "odometer", "gps"),  # 6-axis fields (DriveSpec.full_imu); odometer
    # optional
}  # the packet kinds a vehicle of each sensor configuration sends


@dataclass(frozen=True)
class SensorErrors:
    """Error model of the simulated sensors (1-sigma values unless said otherwise)."""

    gyro_bias_dps: float = 0.3  # initial bias, drawn once per drive
    gyro_bias_drift_dps_per_sqrt_s: float = 0.005
    gyro_noise_dps: float = 0.1  # per sample
    odometer_scale_error: float = 0.02  # drawn once per drive
    ticks_per_m: float = 27.3  # quantisation of cumulative distance
    accel_bias_mps2: float = 0.05
    accel_noise_mps2: float = 0.05
    steering_bias_rad: float = 0.003
    steering_noise_rad: float = 0.003
    gps_markov_sigma_m: float = 2.5  # correlated error per axis
    gps_markov_tau_s: float = 30.0
    gps_white_sigma_m: float = 1.5
    gps_multipath_rate_per_s: float = 0.01  # chance per fix that a jump starts
    gps_multipath_m: tuple[float, float] = (10.0, 30.0)
    gps_multipath_duration_s: tuple[float, float] = (2.0, 6.0)
    gps_speed_sigma_mps: float = 0.2
    gps_heading_sigma_deg: float = 2.0
    # harsher errors, off by default (see the module docstring)
    gyro_turn_on_bias_dps: float | None = None  # this turn-on bias instead of a draw
    gyro_scale_error: float = 0.0  # the gyro reads (1 + this) x the true rate
    odometer_scale: float | None = None  # this scale factor error instead of a draw
    odometer_speed_sigma_mps: float = 0.05  # noise of a speed-only odometer
    gps_course_sigma_1mps_deg: float = 0.0  # course noise grows as this / speed (1 m/s units)
    gps_min_speed_for_course_mps: float = 0.0  # slower: the fix has no course and no speed
    gps_nlos_rate_per_s: float = 0.0  # chance per second that an NLOS run starts
    gps_nlos_m: tuple[float, float] = (20.0, 80.0)  # its bias, uniform, random direction
    gps_nlos_duration_s: tuple[float, float] = (10.0, 60.0)
    gps_latency_s: float = 0.0  # the fix at t is where the car was this long before t
    imu_mount_deg: tuple[float, float] = (0.0, 0.0)  # the 6-axis IMU's pitch (nose up) and
    # yaw (left) in the car: a phone or box not squared to the car's axes


STANDARD_GRAVITY_MPS2 = 9.80665
HARSH_STREAM = 15  # the second random stream of a seed: np.random.default_rng((seed, 15))
HEIGHT_STREAM = 16  # the third: the fixes' height error
VERTICAL_ERROR_RATIO = 1.5  # a fix's height errs this many times as much as north or east


@dataclass(frozen=True)
class DriveSpec:
    """What to simulate."""

    duration_s: float = 600.0
    seed: int = 0
    imu_rate_hz: float = 100.0
    odometer_rate_hz: float = 50.0
    steering_rate_hz: float = 50.0
    gps_rate_hz: float = 1.0
    truth_rate_hz: float = 10.0
    outages: tuple[tuple[float, float], ...] = ()  # (start_s, length_s)
    tunnels_block_gps: bool = True
    sensors: tuple[str, ...] = ("imu", "odometer", "steering", "gps")
    full_imu: bool = False  # imu packets also carry 6-axis gyro_dps and accel_mps2 (flat road)
    stop_probability: float = 0.2  # at each intersection
    stop_duration_s: tuple[float, float] = (3.0, 15.0)
    max_lateral_accel_mps2: float = 2.0
    corner_half_width_m: float = 6.0  # corners are rounded over this much road each side
    # (a 90-degree corner then has about 5 m of radius at its tightest)
    max_accel_mps2: float = 1.5
    max_decel_mps2: float = 2.5
    wheelbase_m: float = 2.7
    errors: SensorErrors = field(default_factory=SensorErrors)
    start_standstill_s: float = 0.0  # stand still this long before driving off
    lane_offset_m: float = 0.0  # the car drives this far right of a two-way road's centre
    # line (its lane; the map has only the centre line) ...
    one_way_offset_m: float = 0.0  # ... and this far right of a one-way road's (left: < 0)
    odometer_reports: str = "distance"  # "distance" (cumulative, ticks) or "speed" (only)
    gps_reports_velocity: bool = True  # speed and course on each fix
    gps_reports_hdop: bool = True
    gps_reports_height: bool = False  # a height on each fix (``VERTICAL_ERROR_RATIO``)
    gps_error_replay: GnssErrorRecording | None = None  # real error instead of the synthetic
    gps_error_replay_offset_s: int | None = None  # into the recording; None: from the seed

    def __post_init__(self) -> None:
        if self.odometer_reports not in ("distance", "speed"):
            raise ValueError(f"odometer_reports must be 'distance' or 'speed', "
                             f"not {self.odometer_reports!r}")
        if self.start_standstill_s < 0 or self.errors.gps_latency_s < 0:
            raise ValueError("start_standstill_s and gps_latency_s must be >= 0")


@dataclass(frozen=True)
class _Path:
    """The smoothed route: vertices, cumulative length, heading, owning edge, speed limit."""

    xy: FloatArray
    s: FloatArray
    heading: FloatArray  # unwrapped, compass convention
    edge: list[EdgeKey]  # per segment
    v_max: FloatArray  # per vertex
    stops: list[tuple[float, float]]  # (s, dwell seconds)


def random_route(graph: RoadGraph, length_m: float, rng: np.random.Generator) -> list[EdgeKey]:
    """At least ``length_m`` of driving: shortest paths to random intersections, chained.

    Each leg starts with a road leaving the previous leg's end without turning back, so the
    route never makes a U-turn on the spot.
    """
    core = max(nx.strongly_connected_components(graph.graph), key=len)  # every node reachable
    junctions = [n.id for n in graph.nodes if n.degree >= 3 and n.id in core]
    edges = [EdgeKey(e.u, e.v, e.key) for e in graph.edges
             if e.u != e.v and e.length_m > 20.0 and e.u in core and e.v in core]
    route = [edges[rng.integers(len(edges))]]
    total = graph.edge(route[0]).length_m
    failures = 0
    for _ in range(10_000):
        if total >= length_m:
            return route
        last = route[-1]
        onward = [EdgeKey(e.u, e.v, e.key) for e in graph.out_edges(last.v)
                  if e.u != e.v and e.v != last.u and e.v in core
                  and abs(graph.turn_angle_rad(last, EdgeKey(e.u, e.v, e.key))) < 2.6]
        if not onward:  # dead end: drop the last edge and try another way from before it
            if len(route) > 1:
                total -= graph.edge(route.pop()).length_m
            else:
                route = [edges[rng.integers(len(edges))]]
                total = graph.edge(route[0]).length_m
            continue
        first = onward[rng.integers(len(onward))]
        target = junctions[rng.integers(len(junctions))]
        try:
            leg = [first, *graph.shortest_path(first.v, target)]
        except nx.NetworkXNoPath:
            failures += 1
            continue
        joints = zip([last, *leg[:-1]], leg)
        if any(abs(graph.turn_angle_rad(a, b)) > 2.6 for a, b in joints):  # turns back on itself
            failures += 1
            if failures > 20:  # boxed in: back off one edge, or start afresh
                if len(route) > 1:
                    total -= graph.edge(route.pop()).length_m
                else:
                    route = [edges[rng.integers(len(edges))]]
                    total = graph.edge(route[0]).length_m
                failures = 0
            continue
        failures = 0
        route += leg
        total += sum(graph.edge(k).length_m for k in leg)
    raise RuntimeError("could not build a route on this map")


def _chaikin(xy: FloatArray, owner: list[int], rounds: int = 3) -> tuple[FloatArray, list[int]]:
    """Corner cutting: keeps the end points; each new point inherits its segment's owner."""
    for _ in range(rounds):
        p0, p1 = xy[:-1], xy[1:]
        q, r = 0.75 * p0 + 0.25 * p1, 0.25 * p0 + 0.75 * p1
        inner = np.empty((2 * len(p0), 2))
        inner[0::2], inner[1::2] = q, r
        xy = np.vstack([xy[:1], inner, xy[-1:]])
        seg_owner = [o for o in owner for _ in range(2)]
        owner = [seg_owner[0], *seg_owner[1:], seg_owner[-1]][: len(xy) - 1]
    return xy, owner


def _resample(xy: FloatArray, owner: npt.NDArray[np.int64],
              spacing_m: float) -> tuple[FloatArray, list[int]]:
    """Even vertex spacing, so that corner cutting gives curves of realistic radius."""
    seg_len = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg_len)])
    s_new = np.append(np.arange(0.0, s[-1], spacing_m), s[-1])
    s_new = s_new[np.concatenate([[True], np.diff(s_new) > 0.1])]
    x, y = np.interp(s_new, s, xy[:, 0]), np.interp(s_new, s, xy[:, 1])
    mid = 0.5 * (s_new[:-1] + s_new[1:])
    seg = np.clip(np.searchsorted(s, mid, side="right") - 1, 0, len(owner) - 1)
    return np.column_stack([x, y]), owner[seg].tolist()


def _round_corners(xy: FloatArray, half_width_m: float, spacing_m: float) -> FloatArray:
    """A moving average of the evenly spaced vertices over ``half_width_m`` each side (end
    points kept): a corner becomes a curve a car can drive. Corner cutting alone, on 2 m
    vertices, turned 90 degrees in 1 m of radius, which asked for 70 degrees of steering
    at the wheels (cars have 35-40) and gyro rates of 85 degrees a second at walking pace."""
    k = int(round(half_width_m / spacing_m))
    if k < 1 or len(xy) < 2 * k + 1:
        return xy
    padded = np.vstack([np.repeat(xy[:1], k, axis=0), xy, np.repeat(xy[-1:], k, axis=0)])
    kernel = np.ones(2 * k + 1) / (2 * k + 1)
    out = np.column_stack([np.convolve(padded[:, i], kernel, mode="valid") for i in (0, 1)])
    out[0], out[-1] = xy[0], xy[-1]
    return out


def _remove_spikes(xy: FloatArray, owner: list[int],
                   max_turn_rad: float = math.radians(100.0)) -> tuple[FloatArray, list[int]]:
    """Drop vertices where the line doubles back within one vertex spacing.

    Junction consolidation moves a node to its cluster's centre, so an edge may start with a
    short stub pointing back; no car drives that.
    """
    for _ in range(1000):
        seg = np.diff(xy, axis=0)
        heading = np.arctan2(seg[:, 0], seg[:, 1])
        turn = np.abs(np.remainder(np.diff(heading) + math.pi, 2.0 * math.pi) - math.pi)
        bad = np.flatnonzero(turn > max_turn_rad)
        if bad.size == 0:
            break
        i = int(bad[0]) + 1  # the vertex between segment i-1 and i
        xy = np.delete(xy, i, axis=0)
        owner = owner[:i] + owner[i + 1:]
    return xy, owner


def _keep_lane(xy: FloatArray, oneway: list[bool], spec: DriveSpec,
               blend_m: float = 20.0, spacing_m: float = 2.0) -> FloatArray:
    """The rounded centre line moved sideways into the car's lane: ``lane_offset_m`` right
    of a two-way road's centre line, ``one_way_offset_m`` of a one-way road's (``oneway``:
    per segment). The offset changes smoothly over ``blend_m`` where the road's kind changes
    (a lane change), and is held within a third of the curve's radius, so that a tight
    corner is not turned inside out."""
    per_segment = np.where(oneway, spec.one_way_offset_m, spec.lane_offset_m)
    offset = np.concatenate([per_segment[:1], 0.5 * (per_segment[:-1] + per_segment[1:]),
                             per_segment[-1:]])
    k = int(round(blend_m / spacing_m / 2.0))
    if len(offset) > 2 * k + 1:
        padded = np.concatenate([np.repeat(offset[:1], k), offset, np.repeat(offset[-1:], k)])
        offset = np.convolve(padded, np.ones(2 * k + 1) / (2 * k + 1), mode="valid")
    step = np.gradient(xy, axis=0)
    heading = np.unwrap(np.arctan2(step[:, 0], step[:, 1]))
    length = np.maximum(np.hypot(step[:, 0], step[:, 1]), 1e-9)
    radius = length / np.maximum(np.abs(np.gradient(heading)), 1e-9)
    offset = np.clip(offset, -radius / 3.0, radius / 3.0)
    right = np.column_stack([np.cos(heading), -np.sin(heading)])  # clockwise of the heading
    moved: FloatArray = xy + offset[:, None] * right
    return moved


def _build_path(graph: RoadGraph, route: list[EdgeKey], spec: DriveSpec,
                rng: np.random.Generator) -> _Path:
    pts, owner, node_s = [], [], []
    for i, key in enumerate(route):
        coords = graph.edge(key).coords
        start = 0 if i == 0 else 1
        pts.append(coords[start:])
        owner.extend([i] * (len(coords) - 1))
    xy = np.vstack(pts)
    xy, owner = _resample(xy, np.array(owner), spacing_m=2.0)
    xy, owner = _remove_spikes(xy, owner)
    xy = _round_corners(xy, spec.corner_half_width_m, spacing_m=2.0)
    if spec.lane_offset_m or spec.one_way_offset_m:
        xy = _keep_lane(xy, [graph.edge(route[o]).oneway for o in owner], spec)
        xy, owner = _remove_spikes(xy, owner)
    xy, owner = _chaikin(xy, owner)
    seg = np.diff(xy, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    s = np.concatenate([[0.0], np.cumsum(seg_len)])
    seg_heading = np.unwrap(np.arctan2(seg[:, 0], seg[:, 1]))
    heading = np.concatenate([seg_heading[:1], 0.5 * (seg_heading[:-1] + seg_heading[1:]),
                              seg_heading[-1:]])
    edges = [route[o] for o in owner]
    v_road = np.array([_SPEED_BY_HIGHWAY_MPS.get(graph.edge(e).highway, 10.0) for e in edges])
    v_max = np.concatenate([v_road[:1], np.minimum(v_road[:-1], v_road[1:]), v_road[-1:]])
    curvature = np.abs(np.gradient(heading, s, edge_order=1))
    v_max = np.minimum(v_max, np.sqrt(spec.max_lateral_accel_mps2 / np.maximum(curvature, 1e-4)))
    for i in range(1, len(owner)):
        if owner[i] != owner[i - 1]:
            node_s.append(s[i])
    stops = [(ns, float(rng.uniform(*spec.stop_duration_s))) for ns in node_s
             if rng.random() < spec.stop_probability]
    for stop_s, _ in stops:
        v_max[np.argmin(np.abs(s - stop_s))] = 0.0
    v_max[0] = 0.0
    return _Path(xy, s, heading, edges, _limit_accel(s, v_max, spec), stops)


def _limit_accel(s: FloatArray, v: FloatArray, spec: DriveSpec) -> FloatArray:
    v = v.copy()
    ds = np.diff(s)
    for i in range(1, len(v)):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2.0 * spec.max_accel_mps2 * ds[i - 1]))
    for i in range(len(v) - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2.0 * spec.max_decel_mps2 * ds[i]))
    return v


def _time_of_s(path: _Path, v_min_mps: float = 0.3) -> tuple[FloatArray, FloatArray]:
    """Time at each path vertex, and (time, s) knots with the dwell of each stop inserted."""
    v_mid = np.maximum(0.5 * (path.v_max[:-1] + path.v_max[1:]), v_min_mps)
    t = np.concatenate([[0.0], np.cumsum(np.diff(path.s) / v_mid)])
    knots_t, knots_s = list(t), list(path.s)
    for stop_s, dwell in sorted(path.stops, reverse=True):
        i = int(np.searchsorted(path.s, stop_s))
        knots_t = knots_t[:i + 1] + [knots_t[i] + dwell] + [k + dwell for k in knots_t[i + 1:]]
        knots_s = knots_s[:i + 1] + [knots_s[i]] + knots_s[i + 1:]
    return np.array(knots_t), np.array(knots_s)


@dataclass
class _Truth:
    t: FloatArray
    x: FloatArray
    y: FloatArray
    heading: FloatArray  # unwrapped
    rate: FloatArray  # heading rate, clockwise positive
    speed: FloatArray
    accel: FloatArray
    s: FloatArray
    edge_index: npt.NDArray[np.intp]


def _sample_truth(path: _Path, duration_s: float, rate_hz: float) -> _Truth:
    knots_t, knots_s = _time_of_s(path)
    dt = 1.0 / rate_hz
    t = np.arange(0.0, min(duration_s, knots_t[-1]), dt)
    s = np.interp(t, knots_t, knots_s)
    x = np.interp(s, path.s, path.xy[:, 0])
    y = np.interp(s, path.s, path.xy[:, 1])
    heading = np.interp(s, path.s, path.heading)
    speed = np.gradient(s, dt)
    seg = np.clip(np.searchsorted(path.s, s, side="right") - 1, 0, len(path.edge) - 1)
    return _Truth(t, x, y, heading, np.gradient(heading, dt), speed, np.gradient(speed, dt),
                  s, seg)


def simulate_drive(graph: RoadGraph, spec: DriveSpec) -> list[dict[str, Any]]:
    """Simulate one drive: wire-format records in time order (packets and truth)."""
    rng = np.random.default_rng(spec.seed)
    route = random_route(graph, spec.duration_s * 15.0 + 500.0, rng)
    path = _build_path(graph, route, spec, rng)
    if spec.start_standstill_s > 0:
        path = replace(path, stops=[(0.0, spec.start_standstill_s), *path.stops])
    truth = _sample_truth(path, spec.duration_s, spec.imu_rate_hz)
    records = _truth_records(graph, path, truth, spec)
    sensors = set(spec.sensors)
    if "imu" in sensors:
        records += _imu_records(truth, spec, rng)
    if "odometer" in sensors:
        records += _odometer_records(truth, spec, rng)
    if "steering" in sensors:
        records += _steering_records(truth, spec, rng)
    if "gps" in sensors:
        records += _gps_records(graph, path, truth, spec, rng,
                                np.random.default_rng((spec.seed, HARSH_STREAM)))
    order = {"truth": 0, "gps": 1, "imu": 2, "odometer": 3, "steering": 4}
    records.sort(key=lambda r: (r["t"], order[r["kind"]]))
    return records


def _every(truth: _Truth, rate_hz: float, imu_rate_hz: float) -> npt.NDArray[np.int64]:
    step = max(int(round(imu_rate_hz / rate_hz)), 1)
    return np.arange(0, len(truth.t), step)


def _truth_records(graph: RoadGraph, path: _Path, truth: _Truth,
                   spec: DriveSpec) -> list[dict[str, Any]]:
    out = []
    frame = graph.frame
    for i in _every(truth, spec.truth_rate_hz, spec.imu_rate_hz):
        lon, lat = frame.to_wgs84(truth.x[i], truth.y[i])
        key = path.edge[truth.edge_index[i]]
        out.append({"t": round(float(truth.t[i]), 4), "kind": "truth", "lat": lat, "lon": lon,
                    "heading_deg": math.degrees(truth.heading[i]) % 360.0,
                    "speed_mps": max(float(truth.speed[i]), 0.0),
                    "osm_way_id": graph.edge(key).osm_way_ids[0], "u": key.u, "v": key.v})
    return out


def _imu_records(truth: _Truth, spec: DriveSpec, rng: np.random.Generator) -> list[dict[str, Any]]:
    e = spec.errors
    n = len(truth.t)
    dt = 1.0 / spec.imu_rate_hz
    turn_on = rng.normal(0.0, e.gyro_bias_dps) if e.gyro_turn_on_bias_dps is None \
        else e.gyro_turn_on_bias_dps
    bias = turn_on + np.cumsum(
        rng.normal(0.0, e.gyro_bias_drift_dps_per_sqrt_s * math.sqrt(dt), n))
    true_left_dps = -np.degrees(truth.rate)
    if e.gyro_scale_error:
        true_left_dps = true_left_dps * (1.0 + e.gyro_scale_error)
    yaw_left_dps = true_left_dps + bias + rng.normal(0.0, e.gyro_noise_dps, n)
    accel_bias = rng.normal(0.0, e.accel_bias_mps2)
    fwd = truth.accel + accel_bias + rng.normal(0.0, e.accel_noise_mps2, n)
    left = -truth.speed * truth.rate + rng.normal(0.0, e.accel_noise_mps2, n)
    out: list[dict[str, Any]] = [
        {"t": round(float(truth.t[i]), 4), "kind": "imu", "yaw_rate_dps": float(yaw_left_dps[i]),
         "accel_fwd_mps2": float(fwd[i]), "accel_left_mps2": float(left[i])} for i in range(n)]
    if spec.full_imu:  # the same readings as a 6-axis IMU on a level road (x fwd, y left, z up)
        car_to_imu = _mount(*e.imu_mount_deg).T
        for r in out:
            gyro = car_to_imu @ [0.0, 0.0, r["yaw_rate_dps"]]
            accel = car_to_imu @ [r["accel_fwd_mps2"], r["accel_left_mps2"],
                                  STANDARD_GRAVITY_MPS2]
            r["gyro_dps"], r["accel_mps2"] = gyro.tolist(), accel.tolist()
    return out


def _mount(pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """The IMU's axes in the car's (forward, left, up): yawed left, then pitched nose up."""
    p, y = math.radians(pitch_deg), math.radians(yaw_deg)
    yaw = np.array([[math.cos(y), -math.sin(y), 0.0], [math.sin(y), math.cos(y), 0.0],
                    [0.0, 0.0, 1.0]])
    nose_up = np.array([[math.cos(p), 0.0, -math.sin(p)], [0.0, 1.0, 0.0],
                        [math.sin(p), 0.0, math.cos(p)]])
    mount: np.ndarray = yaw @ nose_up
    return mount


def _odometer_records(truth: _Truth, spec: DriveSpec,
                      rng: np.random.Generator) -> list[dict[str, Any]]:
    e = spec.errors
    scale = 1.0 + (rng.normal(0.0, e.odometer_scale_error) if e.odometer_scale is None
                   else e.odometer_scale)
    if spec.odometer_reports == "speed":
        return _speed_odometer_records(truth, spec, scale, rng)
    out = []
    for i in _every(truth, spec.odometer_rate_hz, spec.imu_rate_hz):
        ticks = math.floor(truth.s[i] * scale * e.ticks_per_m)
        out.append({"t": round(float(truth.t[i]), 4), "kind": "odometer",
                    "distance_m": ticks / e.ticks_per_m})
    return out


def _speed_odometer_records(truth: _Truth, spec: DriveSpec, scale: float,
                            rng: np.random.Generator) -> list[dict[str, Any]]:
    """A wheel-speed sensor: speed only, scaled, noisy, never negative, 0 when standing."""
    out = []
    for i in _every(truth, spec.odometer_rate_hz, spec.imu_rate_hz):
        v = float(truth.speed[i])
        reading = 0.0 if v < 0.05 else \
            max(v * scale + rng.normal(0.0, spec.errors.odometer_speed_sigma_mps), 0.0)
        out.append({"t": round(float(truth.t[i]), 4), "kind": "odometer", "speed_mps": reading})
    return out


def _steering_records(truth: _Truth, spec: DriveSpec,
                      rng: np.random.Generator) -> list[dict[str, Any]]:
    e = spec.errors
    bias = rng.normal(0.0, e.steering_bias_rad)
    curvature_left = _curvature_left(truth)
    out = []
    for i in _every(truth, spec.steering_rate_hz, spec.imu_rate_hz):
        angle = math.atan(spec.wheelbase_m * curvature_left[i]) + bias + \
            rng.normal(0.0, e.steering_noise_rad)
        out.append({"t": round(float(truth.t[i]), 4), "kind": "steering",
                    "angle_deg": math.degrees(angle)})
    return out


def _curvature_left(truth: _Truth) -> FloatArray:
    """The path's curvature (1/m, left positive) where the car is: the angle its wheels are
    steered to, also at walking pace through a corner after a stop, and kept while it
    stands (it was taken as straight ahead below 1 m/s, so steering said nothing of the
    slow corners where a car turns most)."""
    ds, dheading = np.gradient(truth.s), np.gradient(truth.heading)
    moving = ds > 1e-6
    curvature = np.where(moving, -dheading / np.where(moving, ds, 1.0), 0.0)
    last_moving = np.maximum.accumulate(np.where(moving, np.arange(len(ds)), 0))
    return np.where(moving | (last_moving > 0), curvature[last_moving], 0.0)


def _gps_blocked(graph: RoadGraph, path: _Path, truth: _Truth, i: int, spec: DriveSpec) -> bool:
    t = truth.t[i]
    if any(start <= t < start + length for start, length in spec.outages):
        return True
    return spec.tunnels_block_gps and graph.edge(path.edge[truth.edge_index[i]]).tunnel


def _gps_records(graph: RoadGraph, path: _Path, truth: _Truth, spec: DriveSpec,
                 rng: np.random.Generator, extra: np.random.Generator) -> list[dict[str, Any]]:
    """GPS fixes; ``rng`` draws the default errors (in their original order), ``extra`` the
    harsher ones (NLOS runs, the replay offset)."""
    e = spec.errors
    dt = 1.0 / spec.gps_rate_hz
    phi = math.exp(-dt / e.gps_markov_tau_s)
    markov = rng.normal(0.0, e.gps_markov_sigma_m, 2)
    jump, jump_until = np.zeros(2), -1.0
    nlos, nlos_until = np.zeros(2), -1.0
    fixes = _every(truth, spec.gps_rate_hz, spec.imu_rate_hz)
    replayed = _replayed_error(spec, truth.t[fixes], extra)
    heights = np.random.default_rng((spec.seed, HEIGHT_STREAM))
    up_sigma_m = VERTICAL_ERROR_RATIO * e.gps_markov_sigma_m
    up_m = heights.normal(0.0, up_sigma_m)
    out = []
    for n, i in enumerate(fixes):
        t = float(truth.t[i])
        markov = phi * markov + rng.normal(0.0, e.gps_markov_sigma_m * math.sqrt(1 - phi ** 2), 2)
        up_m = phi * up_m + heights.normal(0.0, up_sigma_m * math.sqrt(1 - phi ** 2))
        if t >= jump_until and rng.random() < e.gps_multipath_rate_per_s * dt:
            jump, jump_until = _random_offset(rng, e.gps_multipath_m,
                                              e.gps_multipath_duration_s, t)
        if e.gps_nlos_rate_per_s and t >= nlos_until and \
                extra.random() < e.gps_nlos_rate_per_s * dt:
            nlos, nlos_until = _random_offset(extra, e.gps_nlos_m, e.gps_nlos_duration_s, t)
        if _gps_blocked(graph, path, truth, i, spec):
            continue
        err = markov + rng.normal(0.0, e.gps_white_sigma_m, 2) + (jump if t < jump_until else 0)
        if t < nlos_until:
            err = err + nlos
        if replayed is not None:
            if not replayed[0][n]:
                continue
            err = replayed[1][n]
        out.append(_gps_record(graph, truth, i, err, spec, rng, t < jump_until))
        if spec.gps_reports_height:  # a level world at height zero
            out[-1]["alt_m"] = up_m + heights.normal(
                0.0, VERTICAL_ERROR_RATIO * e.gps_white_sigma_m)
    return out


def _random_offset(rng: np.random.Generator, size_m: tuple[float, float],
                   duration_s: tuple[float, float], t: float) -> tuple[FloatArray, float]:
    """A bias of uniform size in a uniform direction, and when it ends."""
    angle = rng.uniform(0.0, 2.0 * math.pi)
    offset = rng.uniform(*size_m) * np.array([math.sin(angle), math.cos(angle)])
    return offset, t + rng.uniform(*duration_s)


def _replayed_error(spec: DriveSpec, t_s: FloatArray, extra: np.random.Generator) -> (
        tuple[npt.NDArray[np.bool_], FloatArray] | None):
    recording = spec.gps_error_replay
    if recording is None:
        return None
    offset = spec.gps_error_replay_offset_s
    if offset is None:
        offset = int(extra.integers(recording.duration_s))
    return replay_error(recording, t_s, offset)


def _gps_record(graph: RoadGraph, truth: _Truth, i: int, err: FloatArray, spec: DriveSpec,
                rng: np.random.Generator, multipath: bool) -> dict[str, Any]:
    """One fix: the truth (``gps_latency_s`` before ``t``) plus ``err``, and what the
    receiver reports besides."""
    e = spec.errors
    t = float(truth.t[i])
    if e.gps_latency_s:
        then = t - e.gps_latency_s
        x, y, v, h = (float(np.interp(then, truth.t, a))
                      for a in (truth.x, truth.y, truth.speed, truth.heading))
    else:
        x, y, v, h = truth.x[i], truth.y[i], float(truth.speed[i]), truth.heading[i]
    lon, lat = graph.frame.to_wgs84(x + err[0], y + err[1])
    speed = max(v + rng.normal(0.0, e.gps_speed_sigma_mps), 0.0)
    sigma_deg = e.gps_heading_sigma_deg
    if e.gps_course_sigma_1mps_deg:
        sigma_deg += e.gps_course_sigma_1mps_deg / max(speed, 0.1)
    heading = math.degrees(h) + rng.normal(0.0, sigma_deg)
    if speed < 0.5:
        heading = rng.uniform(0.0, 360.0)  # a stopped receiver's course wanders
    record: dict[str, Any] = {"t": round(t, 4), "kind": "gps", "lat": lat, "lon": lon,
                              "speed_mps": speed, "heading_deg": heading % 360.0,
                              "hdop": 2.5 if multipath else 1.0, "sats": 8, "fix": "3d"}
    if not spec.gps_reports_velocity or speed < e.gps_min_speed_for_course_mps:
        del record["speed_mps"], record["heading_deg"]
    if not spec.gps_reports_hdop:
        del record["hdop"]
    return record

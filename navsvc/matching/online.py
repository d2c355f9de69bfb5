"""Online map matching of one vehicle's fused estimates (seed: Mayhew 1999, section 5.7).

The vehicle is on one directed edge of the intersection graph at a time:

* **before start-up** (the filter has no heading yet): the estimate is placed on the roads
  near it (:meth:`OnlineMatcher.on_road`) and reported on the nearest, by distance alone.
* **start-up / re-initialisation**: candidate edges from the spatial index within a radius set
  by the position uncertainty; the best by distance and heading.
* **between intersections**: project onto the current edge and follow it.
* **ambiguity region**: once the projection is within ``r_a`` of the edge's end node, every
  edge reachable from that node within ``2 r_a + 20 m`` (oneway respected, no U-turn except at
  a dead end; a U-turn is turning back along the road just driven, so a loop that returns to
  its start by another way counts), and the current edge itself, is a hypothesis. Each epoch
  its probability is updated from the distance to the road and from **turn detection**: the
  heading change accumulated since entering the region against the road's own change of
  direction (which cancels a constant heading error). The most probable road is reported;
  leaving the region (further than ``r_a`` from the node) commits to it. While the vehicle
  stands the probabilities hold: a standing car repeats its position and tells nothing new,
  and fixes scattered about it would otherwise wear away what its turn showed.
* **off road / lost**: far from the current road for a while (a car park) → ``off_road`` and
  a new start-up search each epoch; heading against the road for a while → ``lost``, then
  start-up; further than ``poor_fit_sigmas`` of road and position sigma for a while, or
  holding less than ``rival_share`` of the likelihood of the roads beside the estimate (the
  wrong branch of a narrow fork, running beside the right one) → start-up, which takes the
  better road. The same holds in an ambiguity region once no hypothesis fits (a road the
  region did not think of), rather than waiting to be far enough to count as off road.
* **jump**: an estimate that moved farther than its speed and uncertainty explain since the
  last update (the filter re-acquired GPS) → start-up at once.

Ambiguity radius (the seed: expected drift times the map's longest adjacent-node distance;
also at least ``k`` sigma of the filter's position)::

    r_a = clamp(max(drift_fraction x longest_adjacent_m, sigma_factor x tracking_sigma_m),
                min_radius_m, max_radius_m)

Pure: no I/O; :meth:`OnlineMatcher.update` takes an estimate and returns a matched position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from navsvc.errors import ConfigError
from navsvc.matching.on_road import on_road_posterior
from navsvc.types import EdgeRef, FusedEstimate, MatchedPosition, MatchState
from roadgraph import EdgeKey, EdgeProjection, EdgeRecord, RoadGraph
from roadgraph.geometry import wrap_angle_rad

U_TURN_RAD = math.radians(150.0)  # back to the node just left, this sharply: a U-turn


@dataclass(frozen=True)
class MatcherConfig:
    """Matcher parameters (metres, seconds, radians)."""

    drift_fraction: float = 0.04  # seed: dead-reckoning drift, 4 % of distance travelled
    sigma_factor: float = 3.0
    min_radius_m: float = 12.0
    max_radius_m: float = 35.0
    road_sigma_m: float = 4.0  # spread of positions around the road centre line
    turn_sigma_rad: float = math.radians(20.0)
    prior_keep: float = 0.85  # weight of the previous probabilities at each epoch
    confident_probability: float = 0.8  # below this a region reports ``ambiguous``
    startup_radius_m: tuple[float, float] = (25.0, 150.0)  # clamp of 3 sigma + 15 m
    jump_m: float = 15.0  # the estimate moved this much (or 3 sigma) more than its speed
    # explains since the last update: it jumped (a re-acquired fix) → start-up at once
    off_road_distance_m: float = 30.0  # (or 4 sigma, the larger) from the current road ...
    off_road_after_s: float = 3.0  # ... for this long → off road
    lost_heading_rad: float = math.radians(60.0)  # against the road ...
    lost_after_s: float = 4.0  # ... for this long while moving → lost
    poor_fit_sigmas: float = 3.0  # further from the road than this many sigmas ...
    poor_fit_after_s: float = 2.0  # ... for this long → start-up (a better road may be near)
    rival_share: float = 0.3  # ... or less than this share of the roads beside it, as long
    min_speed_for_heading_mps: float = 2.0

    def __post_init__(self) -> None:
        if not 0.0 < self.min_radius_m <= self.max_radius_m:
            raise ConfigError("need 0 < min_radius_m <= max_radius_m")
        if not 0.0 <= self.prior_keep < 1.0:
            raise ConfigError("prior_keep must be in [0, 1)")


@dataclass
class _Region:
    """The ambiguity region around one intersection being passed."""

    node: int
    radius_m: float
    entry_heading_rad: float  # the estimate's heading on entry
    entry_road_bearing_rad: float  # the road's direction there
    probabilities: dict[EdgeKey, float] = field(default_factory=dict)


@dataclass
class MatcherState:
    """Everything one vehicle's matcher remembers (plain data)."""

    edge: EdgeKey | None = None
    region: _Region | None = None
    far_since_t: float | None = None
    against_since_t: float | None = None
    poor_fit_since_t: float | None = None
    off_road: bool = False
    last_estimate: tuple[float, float, float, float] | None = None  # (t, x_m, y_m,
    # tracking_sigma_m) of the last update


class OnlineMatcher:
    """One vehicle's matcher: ``update`` with each estimate, get the matched position."""

    def __init__(self, graph: RoadGraph, config: MatcherConfig = MatcherConfig()) -> None:
        self.graph = graph
        self.config = config
        self.state = MatcherState()
        self._seed_radius_m = config.drift_fraction * graph.info.max_adjacent_node_distance_m

    def ambiguity_radius_m(self, position_sigma_m: float) -> float:
        c = self.config
        r = max(self._seed_radius_m, c.sigma_factor * position_sigma_m)
        return min(max(r, c.min_radius_m), c.max_radius_m)

    def on_road(self, e: FusedEstimate) -> FusedEstimate:
        """Before start-up: the estimate given that the car is on a road within 3 sigma of
        it (:func:`navsvc.matching.on_road.on_road_posterior`, with the estimate's mean
        variance in each axis: a leap's spread along one is taken as round), its covariance
        all GPS error as before; unchanged when none is that near, or when 3 sigma reach
        beyond the start-up radius (a fix that unsure would weigh every road of a town, one
        by one, for a position the roads hardly sharpen; the tune split's reach at most
        91 m)."""
        var_m2 = e.position_sigma_m ** 2
        road_sigma_m = self.config.road_sigma_m
        radius_m = 3.0 * math.sqrt(var_m2 + road_sigma_m ** 2)
        if var_m2 <= 0.0 or radius_m > self.config.startup_radius_m[1]:
            return e
        found = on_road_posterior(e.x_m, e.y_m, var_m2,
                                  self.graph.edges_near(e.x_m, e.y_m, radius_m), road_sigma_m)
        if found is None:
            return e
        x_m, y_m, cov_m2 = found
        return replace(e, x_m=x_m, y_m=y_m, position_cov_m2=cov_m2,
                       gps_bias_var_m2=float(np.trace(cov_m2)) / 2.0)

    # --- one epoch -----------------------------------------------------------------------
    def update(self, e: FusedEstimate) -> MatchedPosition:
        if not e.initialized:
            return self._before_start_up(e)
        s = self.state
        jumped = self._jumped(e)
        s.last_estimate = (e.t, e.x_m, e.y_m, e.tracking_sigma_m)
        if jumped:
            return self._start_again(e)
        if s.edge is None:
            return self._start(e)
        proj = self.graph.project(s.edge, e.x_m, e.y_m)
        lost = self._check_lost(e, proj)
        if lost is not None:
            return lost
        if s.region is None and proj.remaining_m <= self.ambiguity_radius_m(e.tracking_sigma_m):
            self._enter_region(e, proj)
        if s.region is not None:
            return self._in_region(e, proj)
        return self._on_road(e, proj)

    def _before_start_up(self, e: FusedEstimate) -> MatchedPosition:
        """Before the filter starts (its heading unknown, or re-acquiring): the nearest road
        within the start-up radius, by distance alone, is reported but not taken as the road
        (start-up weighs the heading too, once there is one)."""
        near = self.graph.edges_near(e.x_m, e.y_m, self._startup_radius_m(e.position_sigma_m),
                                     limit=1)
        if not near:
            return MatchedPosition(e, MatchState.INITIALIZING, e.x_m, e.y_m)
        proj = near[0]
        return MatchedPosition(
            estimate=e, state=MatchState.INITIALIZING, x_m=proj.x_m, y_m=proj.y_m,
            edge=self._edge_ref(proj), distance_to_road_m=proj.distance_m,
            next_node=proj.edge.v, distance_to_next_node_m=proj.remaining_m,
            road_bearing_rad=proj.bearing_rad)

    def _jumped(self, e: FusedEstimate) -> bool:
        """The estimate moved farther than its speed explains since the last update, by
        ``jump_m`` or 3 tracking sigmas (before or after the move, the larger): the filter
        jumped to a re-acquired fix, and the road it was matched to says nothing of where it
        is now. Kept, a position re-acquired 2 m from the truth was matched to a road 15 m
        away, and the map feedback pulled it there (Monaco 546 of the tune split: 1.9 ->
        1.5x raw GPS). A correction within 3 sigma of the estimate before it is no jump: the
        first fix after a 30 s gap moved one 16 m, and a start-up there took the wrong road
        of a junction the region had right (Monaco 291). Tune split, 600 drives: one drive
        better, none worse by more than 2 %."""
        last = self.state.last_estimate
        if last is None:
            return False
        t, x, y, sigma_m = last
        moved_m = math.hypot(e.x_m - x, e.y_m - y)
        return moved_m - abs(e.speed_mps) * max(e.t - t, 0.0) > \
            max(self.config.jump_m, 3.0 * max(sigma_m, e.tracking_sigma_m))

    def _start_again(self, e: FusedEstimate) -> MatchedPosition:
        """Forget the road and its timers, and start up where the estimate is now."""
        s = self.state
        s.edge, s.region, s.far_since_t, s.poor_fit_since_t = None, None, None, None
        return self._start(e)

    def _start(self, e: FusedEstimate) -> MatchedPosition:
        """Start-up and re-initialisation: the best nearby edge by distance and heading."""
        s = self.state
        best: tuple[float, EdgeProjection] | None = None
        for proj in self.graph.edges_near(e.x_m, e.y_m, self._startup_radius_m(e.tracking_sigma_m)):
            score = self._likelihood(e, proj, self._heading_error(e, proj))
            if best is None or score > best[0]:
                best = (score, proj)
        if best is None or best[0] <= 0.0:
            s.off_road = True
            return MatchedPosition(e, MatchState.OFF_ROAD, e.x_m, e.y_m)
        s.edge, s.region, s.far_since_t, s.against_since_t = best[1].edge, None, None, None
        s.off_road = False
        return self._on_road(e, best[1])

    def _startup_radius_m(self, sigma_m: float) -> float:
        """How far start-up looks for a road: 3 sigma + 15 m, within ``startup_radius_m``."""
        lo, hi = self.config.startup_radius_m
        return min(max(3.0 * sigma_m + 15.0, lo), hi)

    def _check_lost(self, e: FusedEstimate, proj: EdgeProjection) -> MatchedPosition | None:
        """Off road (far from the road) or lost (moving against it) for long enough."""
        c, s = self.config, self.state
        if proj.distance_m > c.startup_radius_m[1]:  # the estimate jumped (re-acquired GPS)
            # farther than start-up would look: no road this far off is still the one driven
            # (a GPS-only drive reported "on road" 1.6 km from it for a second)
            return self._start_again(e)
        far = proj.distance_m > max(c.off_road_distance_m, 4.0 * e.tracking_sigma_m)
        s.far_since_t = (s.far_since_t if s.far_since_t is not None else e.t) if far else None
        against = e.speed_mps >= c.min_speed_for_heading_mps and s.region is None and \
            abs(self._heading_error(e, proj)) > c.lost_heading_rad
        s.against_since_t = (s.against_since_t if s.against_since_t is not None else e.t) \
            if against else None
        if s.far_since_t is not None and e.t - s.far_since_t >= c.off_road_after_s:
            s.edge = None
            return self._start(e)
        # the wrong one of two roads that fork at a small angle: no heading error, and for a
        # long way no further than off_road_distance_m, but clearly off it for its sigma
        if s.region is None and self._fits_poorly(e, proj.distance_m, proj):
            return self._start(e)
        if s.against_since_t is not None and e.t - s.against_since_t >= c.lost_after_s:
            s.edge, s.region, s.against_since_t = None, None, None
            return MatchedPosition(e, MatchState.LOST, e.x_m, e.y_m,
                                   distance_to_road_m=proj.distance_m)
        return None

    def _fits_poorly(self, e: FusedEstimate, distance_m: float,
                     matched: EdgeProjection | None = None) -> bool:
        """Further than ``poor_fit_sigmas`` from the best road for ``poor_fit_after_s``, or (given
        the ``matched`` road's projection) farther than ``road_sigma_m`` from it and holding less
        than ``rival_share`` of the likelihood of the roads beside it (:meth:`road_share`) for as
        long: then the matcher forgets its road (the caller starts up again, which takes the best).
        The share catches the wrong branch of a fork taken in an outage: the estimate ran beside the
        road it drove, 11 m off, and 15 m from the matched one, inside the distance rule, until the
        feedback of the matched road pulled it there (Monaco 546 of the tune split: 1.37 -> 0.45x
        raw GPS, drift 11.3 -> 1.4 %). Tune split, 600 drives: mean log fused/raw -0.2 % (3 better,
        2 worse), drives above 0.9x raw 10 -> 9, drift over 4 % 5 -> 4; a share of 0.4 gave the
        same. In the weaker configurations (120 drives each) it is a coin flip where the estimate is
        surer than it should be (steering Andorra 42: 18 m off with a sigma of 3.6, it took a road
        that led away, 0.70 -> 2.80x): gyro_accel +1.6 % (3 better, 4 worse), steering +1.5 % (1/3),
        GPS alone +0.9 % (4/5), strapdown +0.3 % (0/2), rules and fuzzy -0.1 % and -0.4 % (1/0,
        2/0)."""
        c, s = self.config, self.state
        poor = distance_m > c.poor_fit_sigmas * math.hypot(c.road_sigma_m, e.tracking_sigma_m)
        if not poor and matched is not None and distance_m > c.road_sigma_m:
            poor = self._share(e, matched) < c.rival_share
        s.poor_fit_since_t = (s.poor_fit_since_t if s.poor_fit_since_t is not None else e.t) \
            if poor else None
        if s.poor_fit_since_t is None or e.t - s.poor_fit_since_t < c.poor_fit_after_s:
            return False
        s.edge, s.region, s.poor_fit_since_t = None, None, None
        return True

    # --- ambiguity regions ---------------------------------------------------------------
    def _enter_region(self, e: FusedEstimate, proj: EdgeProjection) -> None:
        s = self.state
        assert s.edge is not None
        radius = self.ambiguity_radius_m(e.tracking_sigma_m)
        hypotheses = [s.edge, *self._reachable(s.edge, 2.0 * radius + 20.0)]
        s.region = _Region(node=s.edge.v, radius_m=radius, entry_heading_rad=e.heading_rad,
                           entry_road_bearing_rad=proj.bearing_rad,
                           probabilities={h: 1.0 / len(hypotheses) for h in hypotheses})

    def _reachable(self, edge: EdgeKey, reach_m: float) -> list[EdgeKey]:
        """Edges reachable from ``edge.v`` within ``reach_m`` (no U-turns but at dead ends)."""
        found: list[EdgeKey] = []
        frontier = [(edge, 0.0)]
        while frontier:
            came, travelled = frontier.pop()
            outs = self.graph.out_edges(came.v)
            turning = [o for o in outs if not self._is_u_turn(came, o)] or outs  # dead end
            for out in turning:
                key = EdgeKey(out.u, out.v, out.key)
                if key in found or key == edge:
                    continue
                found.append(key)
                if travelled + out.length_m < reach_m:
                    frontier.append((key, travelled + out.length_m))
        return found

    def _is_u_turn(self, came: EdgeKey, out: EdgeRecord) -> bool:
        return out.v == came.u and abs(self.graph.turn_angle_rad(
            came, EdgeKey(out.u, out.v, out.key))) > U_TURN_RAD

    def _in_region(self, e: FusedEstimate, proj: EdgeProjection) -> MatchedPosition:
        c, s = self.config, self.state
        region = s.region
        assert region is not None and s.edge is not None
        projections = {h: self.graph.project(h, e.x_m, e.y_m) for h in region.probabilities}
        if self._fits_poorly(e, min(p.distance_m for p in projections.values())):
            return self._start(e)  # on a road none of the hypotheses leads to
        if e.speed_mps < c.min_speed_for_heading_mps:  # standing: nothing new to learn
            return self._report(e, projections)
        turned = wrap_angle_rad(e.heading_rad - region.entry_heading_rad)
        posterior = {}
        for h, p in projections.items():
            expected = wrap_angle_rad(p.bearing_rad - region.entry_road_bearing_rad)
            prior = c.prior_keep * region.probabilities[h] + \
                (1.0 - c.prior_keep) / len(projections)
            posterior[h] = prior * self._likelihood(e, p, wrap_angle_rad(turned - expected))
        total = sum(posterior.values())
        if total <= 0.0:  # nothing explains the motion
            s.edge, s.region = None, None
            return MatchedPosition(e, MatchState.LOST, e.x_m, e.y_m,
                                   distance_to_road_m=proj.distance_m)
        region.probabilities = {h: v / total for h, v in posterior.items()}
        best = max(region.probabilities, key=region.probabilities.__getitem__)
        node = self.graph.node(region.node)
        if math.hypot(e.x_m - node.x_m, e.y_m - node.y_m) > region.radius_m and \
                (best != s.edge or projections[best].remaining_m > region.radius_m):
            s.edge, s.region = best, None  # leaving the region: commit
            if projections[best].remaining_m <= self.ambiguity_radius_m(e.tracking_sigma_m):
                self._enter_region(e, projections[best])
                return self._in_region(e, projections[best])
            return self._on_road(e, projections[best])
        return self._report(e, projections)

    def _report(self, e: FusedEstimate,
                projections: dict[EdgeKey, EdgeProjection]) -> MatchedPosition:
        """The region's most probable road (with the others when not confident)."""
        c, region = self.config, self.state.region
        assert region is not None
        best = max(region.probabilities, key=region.probabilities.__getitem__)
        confident = region.probabilities[best] >= c.confident_probability
        if not confident:
            ranked = sorted(region.probabilities.items(), key=lambda kv: -kv[1])
            candidates = tuple((self._edge_ref(projections[h]), prob)
                               for h, prob in ranked if prob >= 0.01)
            norm = sum(prob for _, prob in candidates)
            candidates = tuple((ref, prob / norm) for ref, prob in candidates)
        else:
            candidates = ()
        return self._position(e, projections[best],
                              MatchState.ON_ROAD if confident else MatchState.AMBIGUOUS,
                              candidates)

    # --- scoring and output --------------------------------------------------------------
    def _heading_error(self, e: FusedEstimate, proj: EdgeProjection) -> float:
        if e.speed_mps < self.config.min_speed_for_heading_mps:
            return 0.0  # a stopped vehicle's heading says little about the road
        return wrap_angle_rad(e.heading_rad - proj.bearing_rad)

    def _likelihood(self, e: FusedEstimate, proj: EdgeProjection, angle_error_rad: float) -> float:
        c = self.config
        sigma_d2 = c.road_sigma_m ** 2 + e.tracking_sigma_m ** 2
        sigma_h = math.hypot(c.turn_sigma_rad, e.heading_sigma_rad)
        if e.speed_mps < c.min_speed_for_heading_mps:
            angle_error_rad = 0.0
        return math.exp(-0.5 * proj.distance_m ** 2 / sigma_d2
                        - 0.5 * (angle_error_rad / sigma_h) ** 2)

    def road_share(self, e: FusedEstimate, edge: EdgeKey) -> float:
        """The share of ``edge`` in the likelihood (distance and heading, as at start-up) of
        the roads beside the estimate: 1 when no other could be the one driven, a half when
        another fits as well. A road whose end only lies near (the next edge of the same
        street) is not beside it."""
        return self._share(e, self.graph.project(edge, e.x_m, e.y_m))

    def _share(self, e: FusedEstimate, proj: EdgeProjection) -> float:
        """:meth:`road_share` of the road of ``proj``, the estimate's projection onto it."""
        c = self.config
        matched = self._likelihood(e, proj, self._heading_error(e, proj))
        total = matched
        radius = 3.0 * math.hypot(c.road_sigma_m, e.tracking_sigma_m)
        for other in self.graph.edges_near(e.x_m, e.y_m, radius):
            if other.edge != proj.edge and 0.0 < other.offset_m < other.length_m:
                total += self._likelihood(e, other, self._heading_error(e, other))
        return matched / total if total > 0.0 else 0.0

    def _on_road(self, e: FusedEstimate, proj: EdgeProjection) -> MatchedPosition:
        return self._position(e, proj, MatchState.ON_ROAD)

    def _edge_ref(self, proj: EdgeProjection) -> EdgeRef:
        record = self.graph.edge(proj.edge)
        return EdgeRef(u=record.u, v=record.v, key=record.key, osm_way_ids=record.osm_way_ids,
                       name=record.name, offset_m=proj.offset_m, length_m=record.length_m)

    def _position(self, e: FusedEstimate, proj: EdgeProjection, state: MatchState,
                  candidates: tuple[tuple[EdgeRef, float], ...] = ()) -> MatchedPosition:
        return MatchedPosition(
            estimate=e, state=state, x_m=proj.x_m, y_m=proj.y_m, edge=self._edge_ref(proj),
            distance_to_road_m=proj.distance_m, candidates=candidates,
            next_node=proj.edge.v, distance_to_next_node_m=proj.remaining_m,
            road_bearing_rad=proj.bearing_rad, in_ambiguity_region=self.state.region is not None)

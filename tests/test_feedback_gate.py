"""Which matches the session feeds back to the filter (navsvc.session.feedback_wanted)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from navsvc.session import SessionConfig, feedback_probability, feedback_wanted
from navsvc.types import FusedEstimate, MatchedPosition, MatchState

CONFIG = SessionConfig()


def _match(distance_m: float, sigma_m: float, *, heading_deg: float = 0.0,
           state: MatchState = MatchState.ON_ROAD, speed_mps: float = 10.0,
           ambiguous: bool = False, heading_sigma_deg: float = 2.0) -> MatchedPosition:
    estimate = FusedEstimate(t=1.0, x_m=distance_m, y_m=0.0,
                             heading_rad=math.radians(heading_deg), speed_mps=speed_mps,
                             yaw_rate_rps=0.0, position_cov_m2=np.eye(2) * sigma_m ** 2,
                             heading_sigma_rad=math.radians(heading_sigma_deg))
    return MatchedPosition(estimate=estimate, state=state, x_m=0.0, y_m=0.0,
                           distance_to_road_m=distance_m, road_bearing_rad=0.0,
                           in_ambiguity_region=ambiguous)


def test_close_confident_match_is_fed_back() -> None:
    assert feedback_wanted(_match(3.0, 2.0), CONFIG)


def test_drift_far_from_the_road_is_pulled_back_when_the_estimate_is_that_unsure() -> None:
    # 15 m off with sigma 5 m: an outage's drift (3 x hypot(5, 2) = 16.2 m)
    assert feedback_wanted(_match(15.0, 5.0), CONFIG)


def test_a_road_far_outside_a_sure_estimate_is_not_followed() -> None:
    # 13 m off with sigma 3 m: more likely the wrong road than the estimate's error
    assert not feedback_wanted(_match(13.0, 3.0), CONFIG)


def test_no_feedback_when_unsure_of_the_road_itself() -> None:
    assert not feedback_wanted(_match(1.0, 2.0, ambiguous=True), CONFIG)
    assert not feedback_wanted(_match(1.0, 2.0, state=MatchState.OFF_ROAD), CONFIG)
    assert not feedback_wanted(_match(1.0, 2.0, heading_deg=30.0), CONFIG)
    assert not feedback_wanted(_match(1.0, 2.0, speed_mps=0.5), CONFIG)


def test_no_feedback_while_the_heading_is_unknown() -> None:
    """A heading sure to 45 degrees still takes a road along it; one sure to no better than
    a random guess (a restart) does not: any road lies within 20 degrees of some heading."""
    assert feedback_wanted(_match(3.0, 20.0, heading_sigma_deg=45.0), CONFIG)
    assert not feedback_wanted(_match(3.0, 20.0, heading_sigma_deg=104.0), CONFIG)


@given(st.floats(0.0, 200.0), st.floats(0.1, 50.0))
def test_the_gate_is_the_larger_of_the_fixed_distance_and_the_sigma_gate(
        distance_m: float, sigma_m: float) -> None:
    gate_m = CONFIG.feedback_gate_sigmas * math.hypot(sigma_m, CONFIG.feedback_sigma_across_m)
    limit_m = max(CONFIG.feedback_max_distance_m, gate_m)
    if abs(distance_m - limit_m) > 1e-6:
        assert feedback_wanted(_match(distance_m, sigma_m), CONFIG) == (distance_m < limit_m)


def test_a_matched_road_holding_half_the_likelihood_or_more_is_fed_back_as_sure() -> None:
    assert feedback_probability(1.0) == feedback_probability(0.5) == 1.0


@given(st.floats(min_value=0.0, max_value=0.5, exclude_max=True))
def test_a_rivalled_road_is_fed_back_as_a_measurement_only_that_likely(share: float) -> None:
    """Below half, the probability falls with the share: a half at a quarter, none at none,
    and continuous at a half."""
    assert feedback_probability(share) == pytest.approx(2.0 * share)

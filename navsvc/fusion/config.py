"""The settings of one vehicle's fusion (pure data): :class:`FusionConfig`.

Seed: Mayhew 1999, chapters 4-5 (noise, thresholds and the GPS validity rules keep the
thesis's values where it gives them). The sensor configuration picks a :class:`Profile`; the
settings of the strapdown INS alone are ``navsvc.fusion.ins.strapdown.StrapdownOptions``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from navsvc.errors import ConfigError
from navsvc.fusion.profiles import PROFILES, GpsMode, Profile, SensorConfig
from navsvc.fusion.road.fuzzy import THESIS_SETS, FuzzySets
from navsvc.fusion.road.motion import ProcessNoise
from navsvc.fusion.road.rules import RuleParams


@dataclass(frozen=True)
class FusionConfig:
    """Fusion parameters; every field may be overridden per session."""

    sensors: SensorConfig = SensorConfig.GYRO_ODOMETER
    gps_mode: GpsMode = GpsMode.EKF
    process: ProcessNoise = ProcessNoise()
    gyro_sigma_rps: float = 0.005  # white noise of one gyro sample
    odometer_sigma_mps: float = 0.15  # speed from one odometer interval
    accel_sigma_mps2: float = 0.3
    steering_sigma_rad: float = 0.005
    wheelbase_m: float = 2.7
    ticks_per_m: float = 27.3  # thesis: ABS pulses per metre
    gps_uere_m: float = 3.5  # sigma = HDOP x UERE when no accuracy_m is given (tuned: bench)
    gps_default_sigma_m: float = 5.0  # a fix that says nothing of its accuracy (the learnt
    # scale widens it when the fixes are further off; 8 m: tune split -0.5 %, 61 drives
    # better, 62 worse, 2 more past a target)
    gps_velocity_sigma_mps: float = 0.5
    initial_gps_latency_s: float = 0.1  # a fix is where the car was this long before its
    # time stamp (a state: learnt from the fixes; clients stamping at reception are
    # 0.1-0.2 s late, those using the receiver's own time 0)
    initial_gps_latency_sigma_s: float = 0.1
    max_gps_latency_s: float = 0.5
    min_speed_for_gps_heading_mps: float = 2.8  # thesis m_GPSVelocityThreshold
    gps_gate_scale: float = 1.0  # chi-square gate multiplier (ekf mode)
    gps_nis_memory_fixes: float = 10.0  # ekf: the fixes (seconds' worth, at any rate) the
    # GPS error level is learnt over
    gps_huber_nis: float = 5.99  # ekf: a fix past this NIS (95 %, 2 dof) pulls as one at it
    gps_bias_share: float = 0.85  # ekf: of a fix's sigma, the part that is a slowly changing
    # error (two bias states carry it; averaging fixes does not remove it)
    gps_bias_max_sigmas: float = 6.0  # ekf: the bias states never hold more than this many
    # of their steady sigmas (a fix that far off is a jump, not a slowly changing error)
    gps_bias_tau_s: float = 30.0  # ekf: its time constant (receivers: 10-60 s; 60 s:
    # tune split +1.4 %, 88 drives better, 125 worse)
    leap_onset_share: float = 0.85  # ekf: a start between two tracks lies this share of
    # the way back to the fixes before their leap (most leaps start a run; tune split)
    held_bias_wander: float = 0.3  # ekf: while the bias states hold the leap of a start
    # between two tracks, they wander with this share of the half leap as steady sigma,
    # within half the half leap (tuned: tune split)
    track_gap_s: float = 3.0  # ekf: fixes further apart than this break the GPS track
    track_settled_s: float = 3.0  # ekf: a track this long is trusted over a sudden jump
    track_confirm_nis: float = 2.0  # ekf with dead reckoning: a fix this close (NIS) to the
    # track while a jump is being refused confirms the track carried through a gap
    max_jump_s: float = 60.0  # ekf: a jump away from a settled track is refused this long
    # at most (non-line-of-sight runs last 10-60 s) ...
    jump_min_m: float = 10.0  # ... when it is this large: smaller is no non-line-of-sight
    # leap (20-80 m), but the track drifting from precise fixes
    heading_unknown_sigma_rad: float = math.radians(20.0)  # ekf: a heading less sure than
    # this takes the receiver's course whole, and its track refuses no jump of the fixes
    jump_spread_m: float = 30.0  # ... while its fixes stay this close to the first (or 4
    # sigma) ...
    jump_drift_mps: float = 3.0  # ... plus this much a second: fixes running away from the
    # estimate faster mean the estimate is diverging (a heading gone wrong), not the GPS
    jump_map_after_s: float = 3.0  # ekf with a map: a refused jump is tested against the
    # roads after this long (two tracks: the estimate's and the jumped fixes')
    jump_map_track_off_m: float = 12.0  # ... the jump is followed when the estimate's track
    # lies this far (rms) from any road along its heading ...
    jump_map_ratio: float = 2.0  # ... and this many times farther than the fixes' track
    turned_path_window_s: float = 20.0  # ekf with dead reckoning: refused fixes whose path
    # over this long is the estimate's turned (a heading gone wrong) ...
    turned_path_min_fixes: int = 7  # ... one a second, at least this many, ...
    turned_path_min_rad: float = math.radians(30.0)  # ... by at least this much ...
    turned_path_misfit_sigmas: float = 2.0  # ... and lies within this many fix sigmas of it
    turned_path_shift_misfit_m: float = 20.0  # ... while this far (rms) from it only shifted
    # (a non-line-of-sight error that changes as the car turns looks turned over short paths)
    gps_map_memory_s: float = 60.0  # ekf with a map: the fixes' distance from the roads is
    # learnt over this long (it measures their slowly changing error, which the NIS cannot)
    gps_map_max_sigma_m: float = 10.0  # ... a floor of at most this
    gps_map_min_ratio: float = 0.25  # ... and, with dead reckoning, the reported position
    # covariance scaled by that error's variance over the fixes', down to this
    road_fit_radius_m: float = 30.0  # roads farther than this count as this far
    road_fit_max_bearing_rad: float = math.radians(30.0)  # a road along the heading
    reacquire_after_gated_s: float = 30.0  # fixes refused this long → start over from GPS
    gps_lost_beyond_m: float = 150.0  # ekf: refused fixes farther than any non-line-of-sight
    # error (20-80 m) from the estimate are no jump; such fixes ...
    gps_lost_after_s: float = 2.0  # ... for this long (3 fixes at least; after a gap, the
    # first) → start over from GPS
    inflate_after_gated_fixes: int = 3  # ekf: refused this often in a row → widen position P
    reset_heading_after_gated_courses: int = 3  # ekf: GPS course refused this often → adopt it
    max_hdop: float = 20.0  # thesis validity: DOP > 20 is bad
    min_sats: int = 3  # thesis validity: fewer than 3 satellites is bad
    stationary_after_samples: int = 20  # thesis: odometer zero for 20+ samples
    still_max_turn_rate_rps: float = 0.05  # ... unless the vehicle turns faster than this
    odometer_window_s: float = 0.25  # speed from distance over at least this long (ticks)
    initial_heading_min_move_m: float = 15.0  # heading from fixes over a baseline this long
    # (the odometer's distance; without one, the ends' distance)
    initial_heading_min_move_sigmas: float = 4.0  # ... and this many fix sigmas long
    initial_heading_max_baseline_s: float = 10.0  # ... and at most this long apart
    initial_heading_max_distance_misfit: float = 0.5  # ... with the fixes moving along it
    # within this share of the odometer's distance (tuned: tune split)
    initial_heading_max_turn_rad: float = math.radians(10.0)  # ... with less turn between
    weighted_reacquire_after_s: float = 30.0  # rules, fuzzy: fixes far from the estimate
    # this long restart it from GPS (a restart onto a non-line-of-sight run is undone when
    # the fixes jump back)
    gps_gap_s: float = 10.0  # no fix this long is a GPS gap: the first fix after it that
    # lies beyond any non-line-of-sight error (gps_lost_beyond_m) restarts from GPS at once
    weighted_reacquire_after_gap_s: float = 3.0  # rules, fuzzy: fixes far from the
    # estimate this long since a gap restart it from GPS (it drifted in the gap)
    weighted_diverging_mps: float = 1.0  # rules, fuzzy: refused fixes whose offset from the
    # estimate changes faster than this (beyond jump_spread_m or 4 sigma) say the estimate
    # diverges (a non-line-of-sight run's offset stays put): restart from GPS at once
    velocity_baseline_s: float = 5.0  # rules, fuzzy: course and speed from fixes at most
    # this far back when the receiver sends none (with the start-up heading's conditions)
    initial_speed_sigma_mps: float = 5.0  # speed at start-up when nothing measured it
    odo_scale_limits: tuple[float, float] = (0.9, 1.1)  # a wheel odometer is never further off
    # (tyre wear and pressure: a few per cent); GPS and the map taught 0.85 for 0.96 in a
    # street canyon (gh-issue-13 474). Tune split, against +-30 %: default (600 drives) 5
    # drives better, none worse; rules, fuzzy, steering (120 each) 5, 5 and 2 better, none
    # worse; no target count changed but steering's over 50 m, 12 -> 11
    reorder_window_s: float = 0.25
    output_interval_s: float = 1.0  # emit an estimate at least this often (GPS outages)
    max_step_s: float = 0.1  # longer gaps are propagated in steps of this size
    initial_gyro_bias_sigma_rps: float = 0.02
    min_still_gyro_samples: int = 100  # gyro samples at a standstill before start-up that
    # give the starting gyro bias (their mean)
    still_gyro_bias_sigma_rps: float = 2e-4  # ... with this sigma on top of the mean's
    initial_odo_scale_sigma: float = 0.05
    initial_gyro_scale_sigma: float = 0.02  # MEMS gyros are 1-3 % off
    gyro_scale_error_limit: float = 0.1  # ... and never more than this
    rules: RuleParams = RuleParams()
    fuzzy: FuzzySets = THESIS_SETS

    def __post_init__(self) -> None:
        positive = ("gyro_sigma_rps", "odometer_sigma_mps", "accel_sigma_mps2", "wheelbase_m",
                    "ticks_per_m", "gps_uere_m", "gps_default_sigma_m", "max_step_s",
                    "output_interval_s", "gps_gate_scale")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"{name} must be a finite number > 0, got {value}")
        if self.gps_mode not in self.profile.gps_modes:
            raise ConfigError(self.profile.ekf_only_reason)
        if self.reorder_window_s < 0.0:
            raise ConfigError(f"reorder_window_s must be >= 0, got {self.reorder_window_s}")

    @property
    def profile(self) -> Profile:
        """What the sensor configuration runs and fuses (:data:`PROFILES`)."""
        return PROFILES[self.sensors]

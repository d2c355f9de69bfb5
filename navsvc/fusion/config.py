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
    gps_default_sigma_m: float = 5.0
    gps_velocity_sigma_mps: float = 0.5
    min_speed_for_gps_heading_mps: float = 2.8  # thesis m_GPSVelocityThreshold
    gps_gate_scale: float = 1.0  # chi-square gate multiplier (ekf mode)
    reinit_after_gated_fixes: int = 10  # ekf: this many gated fixes in a row → restart from GPS
    reset_heading_after_gated_courses: int = 3  # ekf: GPS course refused this often → adopt it
    max_hdop: float = 20.0  # thesis validity: DOP > 20 is bad
    min_sats: int = 3  # thesis validity: fewer than 3 satellites is bad
    stationary_after_samples: int = 20  # thesis: odometer zero for 20+ samples
    odometer_window_s: float = 0.25  # speed from distance over at least this long (ticks)
    initial_heading_min_move_m: float = 5.0  # heading from two fixes this far apart
    reorder_window_s: float = 0.25
    output_interval_s: float = 1.0  # emit an estimate at least this often (GPS outages)
    max_step_s: float = 0.1  # longer gaps are propagated in steps of this size
    initial_gyro_bias_sigma_rps: float = 0.02
    initial_odo_scale_sigma: float = 0.05
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

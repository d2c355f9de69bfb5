"""Sensor fusion of one vehicle (pure: no I/O, no clock).

Public surface: the engine, its configuration and the choices a session makes.
"""

from navsvc.fusion.engine import FusionConfig, FusionEngine, GpsMode
from navsvc.fusion.ins.error_state import Integration
from navsvc.fusion.ins.mechanisation import Mechanisation
from navsvc.fusion.ins.strapdown import StrapdownEngine, StrapdownOptions
from navsvc.fusion.road.motion import SensorConfig

__all__ = ["FusionConfig", "FusionEngine", "GpsMode", "Integration", "Mechanisation",
           "SensorConfig", "StrapdownEngine", "StrapdownOptions"]

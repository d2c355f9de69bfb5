"""Sensor fusion of one vehicle (pure: no I/O, no clock).

:class:`FusionEngine` is one shell over two filters, chosen by the sensor configuration's
:class:`Profile` (:data:`PROFILES`): the road-vehicle EKF (:mod:`navsvc.fusion.road`) and the
strapdown INS (:mod:`navsvc.fusion.ins`). Shared by both: :mod:`.kalman` (the one update),
:mod:`.gnss`, :mod:`.odometer`, :mod:`.reorder` and the compiled-kernel helper :mod:`._jit`.
"""

from navsvc.fusion.config import FusionConfig
from navsvc.fusion.engine import Filter, FusionEngine
from navsvc.fusion.ins.error_state import Integration
from navsvc.fusion.ins.mechanisation import Mechanisation
from navsvc.fusion.ins.strapdown import StrapdownOptions
from navsvc.fusion.profiles import PROFILES, FilterKind, GpsMode, Profile, SensorConfig

__all__ = ["PROFILES", "Filter", "FilterKind", "FusionConfig", "FusionEngine", "GpsMode",
           "Integration", "Mechanisation", "Profile", "SensorConfig", "StrapdownOptions"]

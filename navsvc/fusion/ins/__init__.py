"""The strapdown INS with its loosely coupled GNSS EKF (Giroux, Gourdeau, Landry 2005).

Modules: :mod:`.earth` (WGS84, gravity, earth and transport rates), :mod:`.attitude`
(rotations), :mod:`.mechanisation` (the navigation state and its advance), :mod:`.error_state`
(the 21-state error-state EKF: ``feedback`` and ``feedforward``), :mod:`.total_state` (the
``direct`` integration: the EKF over the navigation state), :mod:`.measurements` (GNSS,
body velocity, rest, the matched road), :mod:`.strapdown` (the INS as a session's filter:
packets in, estimates out; public from :mod:`navsvc.fusion`).
"""

from navsvc.fusion._jit import Array
from navsvc.fusion.ins.attitude import dcm_to_euler, euler_to_dcm, level_from_accel
from navsvc.fusion.ins.earth import EARTH_RATE_RPS, EarthModel, normal_gravity_mps2, radii_m
from navsvc.fusion.ins.error_state import GnssFix, ImuNoise, InsFilter, Integration, replay
from navsvc.fusion.ins.measurements import (
    AcrossRoad,
    BodyVelocity,
    GnssPosition,
    GnssVelocity,
    Rest,
)
from navsvc.fusion.ins.mechanisation import Mechanisation, NavState, mechanise
from navsvc.fusion.ins.total_state import DirectInsFilter, ins_filter

__all__ = ["EARTH_RATE_RPS", "AcrossRoad", "Array", "BodyVelocity", "DirectInsFilter", "EarthModel",
           "GnssFix", "GnssPosition", "GnssVelocity", "ImuNoise", "InsFilter", "Integration",
           "Mechanisation", "NavState", "Rest",
           "dcm_to_euler", "euler_to_dcm", "ins_filter", "level_from_accel", "mechanise",
           "normal_gravity_mps2", "radii_m", "replay"]

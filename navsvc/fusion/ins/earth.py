"""The earth model of the strapdown INS (pure): WGS84 radii of curvature, normal gravity, and
the earth and transport rates in the navigation frame (north-east-down).

Seed: Giroux, Gourdeau, Landry 2005 (docs/seed-digest.md); conventions as KF-GINS. ``FLAT``
is a flat, non-rotating earth (the paper found no significant difference).
"""

from __future__ import annotations

import enum
import math

import numpy as np

from navsvc.fusion._jit import Array, jit

WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3
EARTH_RATE_RPS = 7.2921151467e-5


class EarthModel(enum.Enum):
    WGS84 = "wgs84"  # earth rate and transport rate
    FLAT = "flat"  # neither (the paper found no significant difference)


@jit
def radii_m(lat_rad: float) -> tuple[float, float]:
    """Meridian and prime-vertical radii of curvature (RM, RN)."""
    s2 = math.sin(lat_rad) ** 2
    w = math.sqrt(1.0 - WGS84_E2 * s2)
    return WGS84_A * (1.0 - WGS84_E2) / w**3, WGS84_A / w


@jit
def normal_gravity_mps2(lat_rad: float, h_m: float) -> float:
    """Somigliana normal gravity with the free-air height correction."""
    s2 = math.sin(lat_rad) ** 2
    g0 = 9.7803253359 * (1.0 + 0.00193185265241 * s2) / math.sqrt(1.0 - WGS84_E2 * s2)
    return g0 - 3.086e-6 * h_m




@jit
def nav_rates(lat: float, h: float, v: Array, rotating: float) -> tuple[Array, Array]:
    """Earth rate and transport rate in the navigation frame (both zero on a flat earth:
    ``rotating`` 0)."""
    rm, rn = radii_m(lat)
    w_ie = rotating * EARTH_RATE_RPS * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    w_en = rotating * np.array([v[1] / (rn + h), -v[0] / (rm + h),
                                -v[1] * math.tan(lat) / (rn + h)])
    return w_ie, w_en



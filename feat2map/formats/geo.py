"""Where a map lies on Earth, for the formats that write latitude and longitude (Lanelet2,
CommonRoad): the map's local frame is metres east/north of `HDMap.origin`, an easting/northing
in a northern UTM zone (default `UTM_ZONE`); pyproj converts to WGS84."""
from __future__ import annotations

from functools import lru_cache

import numpy as np

import math

from ..config import UTM_ORIGIN, UTM_ZONE, limits, plain_number
from ..errors import Feat2MapError
from ..model import HDMap
from .base import ExportOption

GEO_OPTIONS = (
    ExportOption("--zone", "zone", {"type": int, "metavar": "N", "help": f"UTM zone of the map (default {UTM_ZONE})"}),
    ExportOption("--origin", "origin", {"type": float, "nargs": 2, "metavar": ("X", "Y"),
                                        "help": "UTM easting/northing of the map's (0, 0) (default: the map's "
                                                f"origin, else {UTM_ORIGIN[0]:.0f} {UTM_ORIGIN[1]:.0f})"}),
)


def check_origin(origin, where: str) -> tuple[float, float]:
    """`origin` as two floats when they are finite and within the coordinate limit (an easting
    or northing of 1e300 would make every written coordinate unusable); else an error naming
    `where` (the option, on the command line)."""
    cap = limits().max_coordinate_m
    try:
        x, y = (float(v) for v in origin)
    except (TypeError, ValueError):
        raise Feat2MapError(f"needs two numbers (easting, northing), got {origin!r:.60}", where) from None
    if not all(math.isfinite(v) and abs(v) <= cap for v in (x, y)):
        raise Feat2MapError(f"easting and northing must be finite and within +-{plain_number(cap)} m "
                            f"(max_coordinate_m), got {x:g} {y:g}", where)
    return x, y


def utm_origin(m: HDMap, zone: int, origin: tuple[float, float] | None, where: str) -> tuple[float, float]:
    """The UTM easting/northing of the map's (0, 0): `origin` if given, else the map's, else
    `UTM_ORIGIN`; a zone outside 1..60 is an error naming `where`."""
    if not isinstance(zone, int) or isinstance(zone, bool) or not 1 <= zone <= 60:
        raise Feat2MapError(f"UTM zone must be an integer 1..60, got {zone!r}", where)
    if origin is not None:
        return check_origin(origin, f"{where}: origin")
    return (float(m.origin[0]), float(m.origin[1])) if any(m.origin) else UTM_ORIGIN


@lru_cache(maxsize=8)
def _to_wgs84(zone: int):
    from pyproj import Transformer

    return Transformer.from_crs(f"EPSG:{32600 + zone}", "EPSG:4326", always_xy=True)


def utm_to_latlon(zone: int, easting, northing) -> tuple[np.ndarray, np.ndarray]:
    """Latitudes and longitudes [deg] of UTM (northern `zone`) eastings and northings."""
    lon, lat = _to_wgs84(zone).transform(np.asarray(easting, dtype=float), np.asarray(northing, dtype=float))
    return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)


def utm_projection(zone: int) -> str:
    """The PROJ string of northern UTM `zone` on WGS84 (as Apollo's header writes it)."""
    return f"+proj=utm +zone={zone} +ellps=WGS84 +datum=WGS84 +units=m +no_defs"


def local_tmerc(zone: int, origin: tuple[float, float]) -> str:
    """UTM `zone` as a transverse Mercator whose false origin puts `origin` (easting, northing)
    at (0, 0): the PROJ string under which a file's coordinates are the map's local metres
    (OpenDRIVE's geoReference, CommonRoad's geoTransformation)."""
    lon0 = -183 + 6 * zone
    return (f"+proj=tmerc +lat_0=0 +lon_0={lon0} +k=0.9996 +x_0={500000.0 - origin[0]!r} "
            f"+y_0={-origin[1]!r} +datum=WGS84 +units=m +no_defs")

"""How wrong is the declination at a remembered position (daemon.position_memory) when the vehicle has moved?
The change of the WMM2025 declination over a displacement, on a global grid of sites, every direction; beside it
the WMM's own declination uncertainty (its error model) and a year of secular variation (what a clock that
does not know the date costs).

    python bench/remembered_position_error.py [--km 50] [--max-lat 60]

The WMM is pygeomag's (an implementation independent of ahrsd's core.wmm). The WMM2025 error model
(technical report, global averages): δD = sqrt(0.26² + (5417 nT / H)²) degrees, H the horizontal field.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from pygeomag import GeoMag

EARTH_RADIUS_KM = 6371.0088
ERR_D_CONST_DEG, ERR_D_H_NT = 0.26, 5417.0        # WMM2025 error model (declination)


def moved(lat_deg: float, lon_deg: float, km: float, bearing_deg: float) -> tuple[float, float]:
    """The point `km` along the great circle from (lat, lon) at `bearing_deg` (the direct problem, sphere)."""
    d = km / EARTH_RADIUS_KM
    p1, l1, b = math.radians(lat_deg), math.radians(lon_deg), math.radians(bearing_deg)
    p2 = math.asin(math.sin(p1) * math.cos(d) + math.cos(p1) * math.sin(d) * math.cos(b))
    l2 = l1 + math.atan2(math.sin(b) * math.sin(d) * math.cos(p1), math.cos(d) - math.sin(p1) * math.sin(p2))
    return math.degrees(p2), (math.degrees(l2) + 540.0) % 360.0 - 180.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--km", type=float, default=50.0, help="displacement (default 50 km)")
    ap.add_argument("--max-lat", type=float, default=60.0, help="sites up to this latitude, both hemispheres")
    ap.add_argument("--step-deg", type=float, default=5.0, help="grid spacing (default 5°)")
    ap.add_argument("--year", type=float, default=2026.9)
    args = ap.parse_args(argv)
    gm = GeoMag(coefficients_file="wmm/WMM_2025.COF")
    lats = np.arange(-args.max_lat, args.max_lat + 1e-9, args.step_deg)
    lons = np.arange(-180.0, 180.0, args.step_deg)
    moved_deg, moved_f_ut, moved_dip_deg, model_deg, secular_deg = [], [], [], [], []
    for lat in lats:
        for lon in lons:
            here = gm.calculate(glat=lat, glon=lon, alt=0.0, time=args.year)
            worst = np.zeros(3)
            for bearing in range(0, 360, 45):
                la, lo = moved(lat, lon, args.km, bearing)
                there = gm.calculate(glat=la, glon=lo, alt=0.0, time=args.year)
                worst = np.maximum(worst, [abs((there.d - here.d + 180.0) % 360.0 - 180.0),
                                           abs(there.f - here.f) / 1000.0, abs(there.i - here.i)])
            moved_deg.append(worst[0])
            moved_f_ut.append(worst[1])
            moved_dip_deg.append(worst[2])
            model_deg.append(math.hypot(ERR_D_CONST_DEG, ERR_D_H_NT / here.h))
            later = gm.calculate(glat=lat, glon=lon, alt=0.0, time=args.year + 1.0)
            secular_deg.append(abs((later.d - here.d + 180.0) % 360.0 - 180.0))
    q = (50, 95, 100)
    print(f"{len(moved_deg)} sites, |lat| <= {args.max_lat:g}°, every {args.step_deg:g}°, WMM2025 at {args.year}")
    for name, v in ((f"declination change over {args.km:g} km (worst of 8 directions)", moved_deg),
                    (f"|F| change over {args.km:g} km (µT)", moved_f_ut),
                    (f"dip change over {args.km:g} km", moved_dip_deg),
                    ("WMM2025's own declination uncertainty (1σ, error model)", model_deg),
                    ("secular variation over one year", secular_deg)):
        p = np.percentile(v, q)
        unit = "" if "µT" in name else "°"
        print(f"  {name}: median {p[0]:.2f}{unit}, 95 % {p[1]:.2f}{unit}, worst {p[2]:.2f}{unit}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

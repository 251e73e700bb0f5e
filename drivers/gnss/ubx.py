"""u-blox UBX-NAV-PVT <-> GnssFix. Parsing and generation are pyubx2's; this maps the fields.

NAV-PVT (u-blox 8 / M8 receiver description, UBX-13003221, §32.17.15; same layout on M9/F9) carries the
whole navigation solution of one epoch: fixType, flags (gnssFixOK, diffSoln, carrSoln), numSV, lon/lat
(1e-7 deg, pyubx2 scales them to degrees), height (above the ellipsoid) and hMSL in mm, hAcc/vAcc in mm,
velN/velE/velD in mm/s, sAcc in mm/s, pDOP, and flags3.invalidLlh. We use `height` (ellipsoid), as GnssFix
does.
"""

from __future__ import annotations

import math

from pyubx2 import GET, UBXMessage

from ahrsd.core.gnss import GnssFix, GnssFixType, make_fix

NAV_PVT_IDENTITY = "NAV-PVT"
# UBX fixType (NAV-PVT): 0 no fix, 1 dead reckoning only, 2 2D, 3 3D, 4 GNSS + dead reckoning, 5 time only.
_UBX_FIX_TO_FIX_TYPE = {2: GnssFixType.FIX_2D, 3: GnssFixType.FIX_3D, 4: GnssFixType.FIX_3D}


def fix_type_from_nav_pvt(ubx_fix_type: int, gnss_fix_ok: int, diff_soln: int, carr_soln: int) -> GnssFixType:
    """The MAVLink-numbered fix type of a NAV-PVT solution.

    u-blox: "fixes not marked valid [gnssFixOK = 0] should not normally be used", so they are NO_FIX, as are
    dead reckoning only and time only. carrSoln 1/2 is an RTK float/fixed solution, diffSoln a differential one.
    """
    base = _UBX_FIX_TO_FIX_TYPE.get(int(ubx_fix_type))
    if base is None or not gnss_fix_ok:
        return GnssFixType.NO_FIX
    if base is GnssFixType.FIX_2D:
        return base
    if carr_soln == 2:
        return GnssFixType.RTK_FIXED
    if carr_soln == 1:
        return GnssFixType.RTK_FLOAT
    return GnssFixType.DGPS if diff_soln else GnssFixType.FIX_3D


def fix_from_nav_pvt(msg, t_s: float, source: str = "ubx") -> GnssFix:
    """Convert a parsed pyubx2 NAV-PVT message to a GnssFix valid at `t_s` (the caller's clock).

    invalidLlh set: latitude, longitude and altitude are NaN (the velocity may still be good).
    `extra`: itow_ms, receiver_time_s (iTOW in s), ubx_fix_type, pdop, head_mot_deg.
    """
    invalid_llh = bool(getattr(msg, "invalidLlh", 0))
    if invalid_llh:
        lat = lon = alt = math.nan
    else:
        lat, lon, alt = float(msg.lat), float(msg.lon), msg.height / 1000.0
    fix_type = fix_type_from_nav_pvt(msg.fixType, msg.gnssFixOk, msg.diffSoln, msg.carrSoln)
    vel = (msg.velN / 1000.0, msg.velE / 1000.0, msg.velD / 1000.0)
    extra = {"itow_ms": int(msg.iTOW), "receiver_time_s": msg.iTOW / 1000.0, "ubx_fix_type": int(msg.fixType),
             "pdop": float(msg.pDOP), "head_mot_deg": float(msg.headMot), "invalid_llh": invalid_llh}
    return make_fix(t_s, lat, lon, alt, vel, h_acc_m=msg.hAcc / 1000.0, v_acc_m=msg.vAcc / 1000.0,
                    s_acc_m_s=msg.sAcc / 1000.0, fix_type=fix_type, num_sats=int(msg.numSV), source=source,
                    extra=extra)


def nav_pvt_message(fix: GnssFix, itow_ms: int) -> UBXMessage:
    """A NAV-PVT message (pyubx2) describing `fix`, as a receiver would send it (for the simulated receiver).

    Values are rounded to NAV-PVT's integer units; NaN accuracies are sent as 0 (not meaningful on the wire),
    NaN position as invalidLlh, a NaN down velocity as 0 (NAV-PVT always reports one).
    """
    ft = fix.fix_type
    ubx_fix = {GnssFixType.NO_GPS: 0, GnssFixType.NO_FIX: 0, GnssFixType.FIX_2D: 2}.get(ft, 3)
    position_ok = all(math.isfinite(v) for v in (fix.lat_deg, fix.lon_deg, fix.alt_m))

    def mm(value: float) -> int:
        return int(round(value * 1000.0)) if math.isfinite(value) else 0

    vn, ve, vd = (float(v) for v in fix.vel_ned_m_s)
    speed = math.hypot(vn, ve) if math.isfinite(vn) and math.isfinite(ve) else 0.0
    head = math.degrees(math.atan2(ve, vn)) % 360.0 if speed > 0 else 0.0
    return UBXMessage(
        "NAV", "NAV-PVT", GET, iTOW=int(itow_ms) % (7 * 86400 * 1000), fixType=ubx_fix,
        gnssFixOk=int(ft >= GnssFixType.FIX_2D), diffSoln=int(ft == GnssFixType.DGPS),
        carrSoln={GnssFixType.RTK_FLOAT: 1, GnssFixType.RTK_FIXED: 2}.get(ft, 0),
        numSV=max(int(fix.num_sats), 0), lat=fix.lat_deg if position_ok else 0.0,
        lon=fix.lon_deg if position_ok else 0.0, height=mm(fix.alt_m) if position_ok else 0,
        hMSL=mm(fix.alt_m) if position_ok else 0, hAcc=max(mm(fix.h_acc_m), 0), vAcc=max(mm(fix.v_acc_m), 0),
        velN=mm(vn), velE=mm(ve), velD=mm(vd), gSpeed=mm(speed), headMot=head,
        sAcc=max(mm(fix.s_acc_m_s), 0), pDOP=1.0, invalidLlh=int(not position_ok))

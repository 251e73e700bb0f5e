"""GPS_RAW_INT / GLOBAL_POSITION_INT -> GnssFix against hand-computed values, through pymavlink's wire format."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from ahrsd.core.gnss import GnssFixType
from ahrsd.drivers.gnss.mavlink import (MavlinkGnssSelector, fix_from_global_position_int,
                                        fix_from_gps_raw_int)


def _wire(msg):
    """Pack and parse the message as MAVLink 2, so the converter sees what a real link delivers."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    return mav.parse_char(msg.pack(mav))


def _raw(**kw):
    v = dict(time_usec=1_700_000_000_000_000, fix_type=3, lat=473977420, lon=85455940, alt=488120, eph=120,
             epv=250, vel=1000, cog=9000, satellites_visible=13, alt_ellipsoid=536400, h_acc=1500, v_acc=2600,
             vel_acc=180)
    v.update(kw)
    return _wire(mavlink2.MAVLink_gps_raw_int_message(**v))


def test_gps_raw_int_scaling():
    f = fix_from_gps_raw_int(_raw(), t_s=7.0)
    assert f.t_s == 7.0
    assert (f.lat_deg, f.lon_deg) == pytest.approx((47.3977420, 8.5455940), abs=1e-9)
    assert f.alt_m == pytest.approx(536.4) and f.extra["alt_msl"] is False     # ellipsoid height preferred
    # cog 9000 cdeg = 90° (east) at 1000 cm/s -> 10 m/s east
    np.testing.assert_allclose(f.vel_ned_m_s[:2], [0.0, 10.0], atol=1e-12)
    assert math.isnan(f.vel_ned_m_s[2])
    assert (f.h_acc_m, f.v_acc_m, f.s_acc_m_s) == pytest.approx((1.5, 2.6, 0.18))
    assert f.hdop == pytest.approx(1.2) and f.num_sats == 13 and f.fix_type == GnssFixType.FIX_3D


@pytest.mark.parametrize("vel, cog, want", [
    (250, 18000, (-2.5, 0.0)),                                  # south
    (500, 31500, (5 * math.sqrt(0.5), -5 * math.sqrt(0.5))),   # north-west
    (0, 65535, (0.0, 0.0)),                                     # stationary, course unknown
])
def test_gps_raw_int_velocity(vel, cog, want):
    f = fix_from_gps_raw_int(_raw(vel=vel, cog=cog), 0.0)
    np.testing.assert_allclose(f.vel_ned_m_s[:2], want, atol=1e-12)


def test_gps_raw_int_unknown_sentinels_are_nan():
    f = fix_from_gps_raw_int(_raw(vel=65535, eph=65535, satellites_visible=255, h_acc=0, v_acc=0xFFFFFFFF,
                                  vel_acc=0, alt_ellipsoid=0), 0.0)
    assert np.all(np.isnan(f.vel_ned_m_s))
    assert math.isnan(f.hdop) and f.num_sats == -1
    assert math.isnan(f.h_acc_m) and math.isnan(f.v_acc_m) and math.isnan(f.s_acc_m_s)
    assert f.alt_m == pytest.approx(488.12) and f.extra["alt_msl"] is True    # no extension: MSL altitude
    g = fix_from_gps_raw_int(_raw(vel=1000, cog=65535), 0.0)
    assert np.all(np.isnan(g.vel_ned_m_s[:2]))


@pytest.mark.parametrize("code, want", [(0, GnssFixType.NO_GPS), (1, GnssFixType.NO_FIX), (2, GnssFixType.FIX_2D),
                                        (6, GnssFixType.RTK_FIXED), (8, GnssFixType.FIX_3D)])
def test_gps_raw_int_fix_types(code, want):
    assert fix_from_gps_raw_int(_raw(fix_type=code), 0.0).fix_type == want


def _gpi(**kw):
    v = dict(time_boot_ms=123456, lat=-338688000, lon=1512093000, alt=58000, relative_alt=3000, vx=150, vy=-250,
             vz=30, hdg=27000)
    v.update(kw)
    return _wire(mavlink2.MAVLink_global_position_int_message(**v))


def test_global_position_int():
    f = fix_from_global_position_int(_gpi(), 2.0)
    assert (f.lat_deg, f.lon_deg, f.alt_m) == pytest.approx((-33.8688, 151.2093, 58.0))
    np.testing.assert_allclose(f.vel_ned_m_s, [1.5, -2.5, 0.3])
    assert f.fix_type == GnssFixType.FIX_3D and math.isnan(f.h_acc_m) and f.extra["fused"] is True
    assert fix_from_global_position_int(_gpi(lat=0, lon=0), 2.0).fix_type == GnssFixType.NO_FIX


def test_selector_prefers_the_raw_receiver():
    sel = MavlinkGnssSelector()                                  # fused off by default
    assert sel.handle(_gpi(), 0.0) is None
    fused = MavlinkGnssSelector(use_fused=True, raw_timeout_s=2.0)
    assert fused.handle(_gpi(), 0.0) is not None                 # no raw receiver yet
    assert fused.handle(_raw(time_usec=1_000_000), 1.0).source == "mavlink:GPS_RAW_INT"
    assert fused.handle(_raw(time_usec=1_000_000), 1.1) is None  # the same fix sent again
    assert fused.handle(_gpi(), 2.5) is None                     # raw fix 1.5 s ago
    assert fused.handle(_raw(fix_type=1, time_usec=3_000_000), 3.5) is not None   # no fix: does not count
    assert fused.handle(_gpi(), 3.6) is not None                 # last raw fix 2.6 s ago
    assert fused.counters == {"gps_raw_int": 2, "gps_raw_int_repeated": 1, "global_position_int": 2,
                              "global_position_int_skipped": 1}

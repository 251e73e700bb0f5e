"""NMEA 0183 RMC/GGA/VTG (+ GSA) -> GnssFix, one fix per epoch. Parsing and generation are pynmeagps's.

A receiver sends several sentences per navigation epoch (u-blox: RMC, VTG, GGA, GSA, GSV, GLL): GGA has the
position, altitude, fix quality, satellites and HDOP; RMC the position, status, speed and course; VTG the
speed and course; GSA the 2D/3D mode. `NmeaEpochAssembler` combines the sentences of one epoch (same UTC
time; VTG and GSA carry none and join the epoch they arrive in) into one GnssFix. NMEA has no vertical
velocity (vel_d is NaN) and no accuracy estimates (NaN; HDOP is kept in `GnssFix.hdop`). Altitude: GGA's
altitude is above mean sea level; adding the geoid separation (GGA `sep`) gives the height above the
ellipsoid that GnssFix uses (without `sep`, the MSL altitude is used and `extra["alt_msl"]` is True).
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass

from pynmeagps import GET, NMEAMessage

from ahrsd.core.gnss import GnssFix, GnssFixType, make_fix

KNOT_M_S = 1852.0 / 3600.0            # international knot
EPOCH_SENTENCES = ("RMC", "GGA", "VTG", "GSA")
_TIMED = ("RMC", "GGA")
# GGA quality indicator (NMEA 0183 v4.10): 0 invalid, 1 GPS (SPS), 2 DGPS, 3 PPS, 4 RTK fixed, 5 RTK float,
# 6 estimated (dead reckoning), 7 manual input, 8 simulation. 6-8 are not GNSS measurements.
_GGA_QUALITY = {1: GnssFixType.FIX_3D, 2: GnssFixType.DGPS, 3: GnssFixType.FIX_3D, 4: GnssFixType.RTK_FIXED,
                5: GnssFixType.RTK_FLOAT}
# RMC/VTG/GNS mode indicator (NMEA >= 2.3): A autonomous, D differential, F float RTK, R RTK, P precise;
# N not valid, E estimated, M manual, S simulator.
_RMC_MODE = {"A": GnssFixType.FIX_2D, "D": GnssFixType.DGPS, "F": GnssFixType.RTK_FLOAT,
             "R": GnssFixType.RTK_FIXED, "P": GnssFixType.FIX_2D, "": GnssFixType.FIX_2D}


def _num(value) -> float:
    """A pynmeagps field as a float: empty fields ('') are NaN, and so is a field that reads as infinite ('1E310',
    'inf'): no NMEA quantity is, and math.cos/sin of it would raise instead of leaving the value unknown."""
    if value is None or value == "":
        return math.nan
    try:
        number = float(value)
    except (TypeError, ValueError):
        return math.nan
    return number if math.isfinite(number) else math.nan


@dataclass(frozen=True, slots=True)
class _Sentence:
    """The fields of a parsed RMC/GGA/VTG/GSA sentence that a fix is made of (pynmeagps's names); a field the
    sentence lacks (a receiver sending a short sentence, or another type's field) reads as empty ('')."""

    lat: object = ""
    lon: object = ""
    alt: object = ""            # GGA: above mean sea level
    sep: object = ""            # GGA: geoid separation
    quality: object = ""        # GGA
    numSV: object = ""          # GGA
    HDOP: object = ""           # GGA, GSA
    status: object = ""         # RMC
    posMode: object = ""        # RMC, VTG
    spd: object = ""            # RMC: knots
    cog: object = ""            # RMC: degrees
    sogn: object = ""           # VTG: knots
    sogk: object = ""           # VTG: km/h
    cogt: object = ""           # VTG: degrees true
    navMode: object = ""        # GSA
    time: object = ""           # RMC, GGA: UTC time of day
    date: object = ""           # RMC

    @classmethod
    def of(cls, msg) -> "_Sentence":
        return cls(**{name: getattr(msg, name, "") for name in cls.__slots__})


def _seconds_of_day(t) -> float:
    if not isinstance(t, dt.time):
        return math.nan
    return t.hour * 3600.0 + t.minute * 60.0 + t.second + t.microsecond * 1e-6


class NmeaEpochAssembler:
    """Collect the RMC/GGA/VTG/GSA sentences of each epoch and emit one GnssFix per epoch.

    `add(msg, t_s)`: a parsed pynmeagps message and the time it arrived minus the receiver latency; returns
    the fixes completed by it (0 or 1). An epoch is complete when a sentence of a new epoch arrives (a new
    UTC time, or a second VTG/GSA), or, once the receiver's set of sentence types per epoch has been learned
    from the first complete epoch, as soon as every type of that set has arrived (no one-epoch delay).
    The fix's `t_s` is that of the epoch's first sentence (the earliest after the measurement).
    `flush()` emits the pending epoch (end of input).
    """

    def __init__(self, source: str = "nmea"):
        self.source = source
        self._pending: dict[str, NMEAMessage] = {}
        self._pending_time = None
        self._pending_t_s = math.nan
        self._epoch_types: frozenset[str] | None = None
        self.sentences_used = 0
        self.sentences_ignored = 0

    def add(self, msg, t_s: float) -> list[GnssFix]:
        msg_id = getattr(msg, "msgID", "")
        if msg_id not in EPOCH_SENTENCES:
            self.sentences_ignored += 1
            return []
        self.sentences_used += 1
        out: list[GnssFix] = []
        msg_time = getattr(msg, "time", None) if msg_id in _TIMED else None
        new_epoch = msg_id in self._pending or (
            msg_time is not None and self._pending_time is not None and msg_time != self._pending_time)
        if new_epoch:
            if self._epoch_types is None:
                self._epoch_types = frozenset(self._pending)
            out += self.flush()
        if not self._pending:
            self._pending_t_s = float(t_s)
        self._pending[msg_id] = msg
        if msg_time is not None and self._pending_time is None:
            self._pending_time = msg_time
        if self._epoch_types is not None and self._epoch_types <= self._pending.keys():
            out += self.flush()
        return out

    def flush(self) -> list[GnssFix]:
        if not self._pending:
            return []
        sentences, t_s = self._pending, self._pending_t_s
        self._pending, self._pending_time, self._pending_t_s = {}, None, math.nan
        return [fix_from_nmea_epoch(sentences, t_s, self.source)]


def fix_from_nmea_epoch(sentences: dict, t_s: float, source: str = "nmea") -> GnssFix:
    """One GnssFix from the sentences of one epoch, keyed by type ("RMC", "GGA", "VTG", "GSA")."""
    rmc, gga, vtg, gsa = (_Sentence.of(sentences[k]) if k in sentences else None for k in EPOCH_SENTENCES)
    extra: dict = {}
    lat = lon = alt = math.nan
    if gga is not None and math.isfinite(_num(gga.lat)) and math.isfinite(_num(gga.lon)):
        lat, lon = _num(gga.lat), _num(gga.lon)
    elif rmc is not None:
        lat, lon = _num(rmc.lat), _num(rmc.lon)
    if gga is not None:
        alt_msl, sep = _num(gga.alt), _num(gga.sep)
        alt = alt_msl + sep if math.isfinite(sep) else alt_msl
        extra["alt_msl"] = not math.isfinite(sep)

    fix_type = _fix_type(rmc, gga, vtg, gsa)
    speed_m_s, course_deg = math.nan, math.nan
    for msg, speed_field, course_field in ((rmc, "spd", "cog"), (vtg, "sogn", "cogt")):
        if msg is not None and not math.isfinite(speed_m_s):
            speed_m_s = _num(getattr(msg, speed_field)) * KNOT_M_S
            course_deg = _num(getattr(msg, course_field))
    if vtg is not None and not math.isfinite(speed_m_s):
        speed_m_s = _num(vtg.sogk) / 3.6
    if speed_m_s == 0.0 and not math.isfinite(course_deg):
        course_deg = 0.0          # receivers leave the course empty when stationary
    course = math.radians(course_deg)
    vel = (speed_m_s * math.cos(course), speed_m_s * math.sin(course), math.nan)

    timed = rmc if rmc is not None else gga
    if timed is not None:
        extra["receiver_time_s"] = _seconds_of_day(timed.time)
    if rmc is not None and isinstance(getattr(rmc, "date", None), dt.date) and isinstance(rmc.time, dt.time):
        extra["utc"] = dt.datetime.combine(rmc.date, rmc.time, tzinfo=dt.timezone.utc)
    sats = _num(gga.numSV) if gga is not None else math.nan
    num_sats = int(sats) if math.isfinite(sats) else -1
    hdop = _num(gga.HDOP) if gga is not None else math.nan
    if not math.isfinite(hdop) and gsa is not None:
        hdop = _num(gsa.HDOP)
    return make_fix(t_s, lat, lon, alt, vel, fix_type=fix_type, num_sats=num_sats, hdop=hdop, source=source,
                    extra=extra)


def _fix_type(rmc, gga, vtg, gsa) -> GnssFixType:
    candidates = []
    if rmc is not None:
        mode = getattr(rmc, "posMode", "") or ""
        ok = rmc.status == "A" and mode in _RMC_MODE
        candidates.append(_RMC_MODE[mode] if ok else GnssFixType.NO_FIX)
    if gga is not None:
        quality = int(_num(gga.quality)) if math.isfinite(_num(gga.quality)) else 0
        candidates.append(_GGA_QUALITY.get(quality, GnssFixType.NO_FIX))
    if not candidates or GnssFixType.NO_FIX in candidates:
        return GnssFixType.NO_FIX
    fix_type = candidates[-1] if gga is not None else candidates[0]   # GGA knows the altitude (3D)
    if gsa is not None:
        nav_mode = _num(gsa.navMode)
        if nav_mode == 1:
            return GnssFixType.NO_FIX
        if nav_mode == 2:
            return GnssFixType.FIX_2D
    return fix_type


def nmea_epoch_sentences(fix: GnssFix, utc: dt.datetime, talker: str = "GP",
                         geoid_sep_m: float = 0.0) -> list[NMEAMessage]:
    """RMC, VTG and GGA (pynmeagps messages) describing `fix` at UTC `utc`, as a receiver sends them.

    GGA's MSL altitude is `fix.alt_m - geoid_sep_m` with `sep = geoid_sep_m`, so ellipsoid height round-trips.
    A fix below FIX_2D is sent with empty position fields, RMC status V and GGA quality 0.
    """
    valid = fix.fix_type >= GnssFixType.FIX_2D and math.isfinite(fix.lat_deg) and math.isfinite(fix.lon_deg)
    mode = {GnssFixType.DGPS: "D", GnssFixType.RTK_FIXED: "R", GnssFixType.RTK_FLOAT: "F"}.get(fix.fix_type, "A")

    def field(value: float, digits: int):
        """A numeric field, empty when the receiver has no valid value."""
        return round(value, digits) if valid and math.isfinite(value) else ""

    speed_kn = fix.ground_speed_m_s / KNOT_M_S
    course_deg = math.degrees(fix.course_rad)
    t = utc.time()
    lat, lon = (fix.lat_deg, fix.lon_deg) if valid else ("", "")
    rmc = NMEAMessage(talker, "RMC", GET, time=t, status="A" if valid else "V", lat=lat, lon=lon,
                      spd=field(speed_kn, 3), cog=field(course_deg, 2), date=utc.date(), mv="", mvEW="",
                      posMode=mode if valid else "N")
    vtg = NMEAMessage(talker, "VTG", GET, cogt=field(course_deg, 2), cogtUnit="T", cogm="", cogmUnit="M",
                      sogn=field(speed_kn, 3), sognUnit="N", sogk=field(speed_kn * KNOT_M_S * 3.6, 3), sogkUnit="K",
                      posMode=mode if valid else "N")
    quality = {GnssFixType.DGPS: 2, GnssFixType.RTK_FIXED: 4, GnssFixType.RTK_FLOAT: 5}.get(fix.fix_type, 1)
    gga = NMEAMessage(talker, "GGA", GET, time=t, lat=lat, lon=lon, quality=quality if valid else 0,
                      numSV=max(fix.num_sats, 0), HDOP=round(fix.hdop, 2) if math.isfinite(fix.hdop) else "",
                      alt=field(fix.alt_m - geoid_sep_m, 3), altUnit="M", sep=field(geoid_sep_m, 3), sepUnit="M",
                      diffAge="", diffStation="")
    return [rmc, vtg, gga]

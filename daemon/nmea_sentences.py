"""NMEA 0183 heading and attitude sentences built from one estimate (docs/marine.md).

Sentences (IEC 61162-1 / NMEA 0183 field layouts, as `pynmeagps` defines them; pynmeagps generates the
framing and the checksum):

* `HDT` true heading: `$--HDT,x.x,T`.
* `HDG` magnetic sensor heading, deviation, variation: `$--HDG,x.x,x.x,a,x.x,a`. ahrsd's magnetic heading is
  already compensated (the calibration removes the vehicle's deviation), so deviation is 0.0; variation is the
  declination ahrsd uses (WMM or configured), E positive.
* `HDM` magnetic heading: `$--HDM,x.x,M` (off by default: HDG carries the same and more).
* `ROT` rate of turn, degrees per minute, negative when the bow turns to port, and a status `A` (valid) or `V`.
* `XDR` attitude as Airmar heading sensors and Signal K's own NMEA 0183 output send it:
  `$--XDR,A,<pitch>,D,PTCH,A,<roll>,D,ROLL` — transducer type A (angular displacement), unit D (degrees),
  pitch positive bow up, roll positive starboard side down (port side up). These are the FRD/NED Euler angles
  of the estimate (CONTRIBUTING.md conventions) and Signal K's `navigation.attitude` signs.

What is withheld: a sentence that carries a heading is not sent while the heading state is UNKNOWN or the
estimator is initialising (HDT and HDG have no status field to say "invalid"; a consumer times the heading
out instead, exactly as VISION_POSITION_ESTIMATE is withheld). ROT is sent with status `V` while
initialising (it has a status field); XDR is withheld while initialising.
"""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.angles import wrap_pi_float
from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags, HeadingState

SENTENCE_IDS = ("HDT", "HDG", "HDM", "ROT", "XDR")
DEFAULT_RATES_HZ = {"HDT": 10.0, "HDG": 10.0, "HDM": 0.0, "ROT": 5.0, "XDR": 5.0}
# A classic 4800-baud port carries 480 bytes/s: the defaults above need up to 820. Below 38400 baud the
# defaults keep the true heading and the rate of turn at full rate and send HDG and XDR once a second.
LOW_SPEED_RATES_HZ = {"HDT": 10.0, "HDG": 1.0, "HDM": 0.0, "ROT": 5.0, "XDR": 1.0}
LOW_SPEED_BELOW_BAUD = 38400
MAX_SENTENCE_CHARS = 82          # NMEA 0183: '$' to <CR><LF> inclusive
HEADING_SENTENCES = frozenset({"HDT", "HDG", "HDM"})
DECIMALS = 1                     # 0.1° and 0.1 °/min: the resolution marine heading sensors send
ROT_LIMIT_DEG_MIN = 99999.9      # beyond any gyro's range; bounds the field's width (and the byte budget)


def heading_known(est: AttitudeEstimate) -> bool:
    return (est.heading_state != HeadingState.UNKNOWN
            and not est.flags & EstimateFlags.INITIALISING
            and math.isfinite(est.heading_true_rad))


def rate_of_turn_deg_min(est: AttitudeEstimate) -> float:
    """Rate of change of the heading, °/min: ψ̇ = (q sin φ + r cos φ) / cos θ (ZYX Euler kinematics,
    Groves 2nd ed. eq. 2.58); positive turning to starboard (clockwise seen from above)."""
    _, q, r = (float(v) for v in est.rate_body_rad_s)
    cos_pitch = math.cos(est.pitch_rad)
    if abs(cos_pitch) < 1e-6:
        return math.nan
    yaw_rate = (q * math.sin(est.roll_rad) + r * math.cos(est.roll_rad)) / cos_pitch
    return math.degrees(yaw_rate) * 60.0


def _deg360(angle_rad: float) -> float:
    deg = round(math.degrees(angle_rad) % 360.0, DECIMALS)
    return 0.0 if deg >= 360.0 else deg + 0.0          # + 0.0: never "-0.0"


def _signed(value: float) -> float:
    return round(value, DECIMALS) + 0.0


def build_sentence(sentence_id: str, est: AttitudeEstimate, talker: str) -> bytes | None:
    """One sentence for this estimate, or None when it must be withheld (see the module docstring)."""
    # imported here, not at the top: daemon.config takes this module's sentence tables for every daemon, and one
    # without an NMEA output need not load pynmeagps
    from pynmeagps import GET, NMEAMessage

    initialising = bool(est.flags & EstimateFlags.INITIALISING)
    if sentence_id in HEADING_SENTENCES and not heading_known(est):
        return None
    if sentence_id == "HDT":
        msg = NMEAMessage(talker, "HDT", GET, headingT=_deg360(est.heading_true_rad), headingTu="T")
    elif sentence_id == "HDG":
        variation_deg = _signed(math.degrees(wrap_pi_float(est.heading_true_rad - est.heading_mag_rad)))
        msg = NMEAMessage(talker, "HDG", GET, headingM=_deg360(est.heading_mag_rad), deviation=0.0,
                          deviationEW="E", variation=abs(variation_deg),
                          variationEW="E" if variation_deg >= 0.0 else "W")
    elif sentence_id == "HDM":
        msg = NMEAMessage(talker, "HDM", GET, headingM=_deg360(est.heading_mag_rad), headingMag="M")
    elif sentence_id == "ROT":
        rot = min(max(rate_of_turn_deg_min(est), -ROT_LIMIT_DEG_MIN), ROT_LIMIT_DEG_MIN)
        valid = not initialising and math.isfinite(rot)
        msg = NMEAMessage(talker, "ROT", GET, rot=_signed(rot) if math.isfinite(rot) else "",
                          valid="A" if valid else "V")
    elif sentence_id == "XDR":
        if initialising or not (math.isfinite(est.pitch_rad) and math.isfinite(est.roll_rad)):
            return None
        msg = NMEAMessage(talker, "XDR", GET,
                          tdrtype_01="A", data_01=_signed(math.degrees(est.pitch_rad)), dataunit_01="D",
                          tdrid_01="PTCH",
                          tdrtype_02="A", data_02=_signed(math.degrees(est.roll_rad)), dataunit_02="D",
                          tdrid_02="ROLL")
    else:
        raise ValueError(f"unknown NMEA sentence {sentence_id!r} (known: {', '.join(SENTENCE_IDS)})")
    return msg.serialize()


def worst_case_estimate() -> AttitudeEstimate:
    """An estimate whose sentences have every field at its widest (for the serial byte budget)."""
    return AttitudeEstimate(
        t_s=0.0, q_wxyz=np.array([1.0, 0.0, 0.0, 0.0]), roll_rad=math.radians(-179.9),
        pitch_rad=math.radians(-89.9), yaw_rad=math.radians(-179.9),
        heading_mag_rad=math.radians(359.9), heading_true_rad=math.radians(180.0),   # variation 179.9 W
        rate_body_rad_s=np.array([0.0, 0.0, math.radians(9999.9 / 60.0)]),   # with roll −179.9°: ROT −99999.9
        gyro_bias_rad_s=np.zeros(3), sigma_rpy_rad=np.zeros(3))


def worst_case_bytes(sentence_id: str, talker: str) -> int:
    """The longest this sentence gets, in bytes (<CR><LF> included)."""
    est = worst_case_estimate()
    sentence = build_sentence(sentence_id, est, talker)
    assert sentence is not None
    return len(sentence)

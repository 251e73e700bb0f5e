"""ADIS16405 register map, bit fields, scales and word codecs.

Everything here is a pure constant or a pure function: no I/O. The driver (`adis16405.py`) and the
simulated chip (`simulated.py`) both use it, so the encode/decode pair is tested once and shared.

Sources: Linux `drivers/iio/imu/adis16400.c` / `adis.c` (register addresses, bits, timeouts, SPI clocks,
sample-rate formula, -3 dB table), ADIS16405 datasheet (scales, SENS_AVG, burst), EngineerZone thread 81805
("X gyro output error on ADIS16405": worked raw words and the X-gyro burst bug), and PSAS's ChibiOS
`adis16405.c` driver (burst word order).
"""

from __future__ import annotations

import enum
import math

import numpy as np

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2  # the g in "mg" (the datasheet's scale)

# --------------------------------------------------------------------------------------------------------
# Register addresses (16-bit registers at even byte addresses)          # kernel adis16400.c ADIS16400_* defines
# --------------------------------------------------------------------------------------------------------
FLASH_CNT = 0x00
SUPPLY_OUT = 0x02
XGYRO_OUT = 0x04
YGYRO_OUT = 0x06
ZGYRO_OUT = 0x08
XACCL_OUT = 0x0A
YACCL_OUT = 0x0C
ZACCL_OUT = 0x0E
XMAGN_OUT = 0x10
YMAGN_OUT = 0x12
ZMAGN_OUT = 0x14
TEMP_OUT = 0x16
AUX_ADC = 0x18
XGYRO_OFF = 0x1A
YGYRO_OFF = 0x1C
ZGYRO_OFF = 0x1E
XACCL_OFF = 0x20
YACCL_OFF = 0x22
ZACCL_OFF = 0x24
XMAGN_HIF = 0x26
YMAGN_HIF = 0x28
ZMAGN_HIF = 0x2A
XMAGN_SIF = 0x2C
YMAGN_SIF = 0x2E
ZMAGN_SIF = 0x30
GPIO_CTRL = 0x32
MSC_CTRL = 0x34
SMPL_PRD = 0x36
SENS_AVG = 0x38
SLP_CNT = 0x3A
DIAG_STAT = 0x3C
GLOB_CMD = 0x3E
ALM_MAG1 = 0x40
ALM_MAG2 = 0x42
ALM_SMPL1 = 0x44
ALM_SMPL2 = 0x46
ALM_CTRL = 0x48
AUX_DAC = 0x4A
PRODUCT_ID = 0x56

REGISTERS: dict[str, int] = {
    name: value
    for name, value in dict(globals()).items()
    if name.isupper() and isinstance(value, int) and not name.startswith("_") and value <= PRODUCT_ID
}
"""Register name -> address."""
REGISTER_NAMES: dict[int, str] = {addr: name for name, addr in REGISTERS.items()}
"""Address -> register name."""

OUTPUT_REGISTERS = (SUPPLY_OUT, XGYRO_OUT, YGYRO_OUT, ZGYRO_OUT, XACCL_OUT, YACCL_OUT, ZACCL_OUT,
                    XMAGN_OUT, YMAGN_OUT, ZMAGN_OUT, TEMP_OUT, AUX_ADC)
"""The 12 output registers, in burst-read order."""  # PSAS ADIS16405BurstData, kernel scan order

PRODUCT_ID_ADIS16405 = 0x4015  # 16405 decimal; kernel compares prod_id with the part number
PRODUCT_ID_ADIS16400 = 0x4010  # sibling without magnetometer (reported so a mismatch error can name it)

# --------------------------------------------------------------------------------------------------------
# SPI frames                                                          # datasheet SPI timing; kernel adis.c
# --------------------------------------------------------------------------------------------------------
WRITE_BIT = 0x80                 # upper byte 0x80|addr: write the data byte to that byte address
BURST_COMMAND = bytes((GLOB_CMD, 0x00))  # 0x3E00 starts a burst read
BURST_DATA_BYTES = 24            # 12 big-endian words follow the command frame
BURST_FRAME_BYTES = len(BURST_COMMAND) + BURST_DATA_BYTES

SPI_FAST_HZ = 2_000_000          # kernel ADIS16400_SPI_FAST: only when divisor < 0x0A and time base 0
SPI_SLOW_HZ = 300_000            # kernel ADIS16400_SPI_SLOW
SPI_BURST_HZ = 1_000_000         # kernel ADIS16400_SPI_BURST: burst reads never faster than 1 MHz
SPI_FAST_MAX_DIVISOR = 0x0A      # kernel: fast clock if (SMPL_PRD & 0x7F) < 0x0A
STALL_US = 50                    # kernel read_delay = write_delay = 50 µs between frames (conservative)


def read_frame(addr: int) -> bytes:
    """The 2-byte frame that requests register `addr` (its data arrives in the next frame)."""
    return bytes((addr & 0x7F, 0x00))


def write_frames(addr: int, value: int) -> tuple[bytes, bytes]:
    """Two byte-write frames for a 16-bit register: upper byte to addr+1, then lower byte to addr."""
    return (bytes((WRITE_BIT | ((addr + 1) & 0x7F), (value >> 8) & 0xFF)),
            bytes((WRITE_BIT | (addr & 0x7F), value & 0xFF)))


def spi_speed_hz(smpl_prd: int) -> int:
    """Register-access SPI clock allowed by the current SMPL_PRD (kernel adis16400_set_freq rule)."""
    if (smpl_prd & SMPL_PRD_TIME_BASE) == 0 and (smpl_prd & SMPL_PRD_DIVISOR_MASK) < SPI_FAST_MAX_DIVISOR:
        return SPI_FAST_HZ
    return SPI_SLOW_HZ


# --------------------------------------------------------------------------------------------------------
# Output word format                                                 # datasheet output-register format
# --------------------------------------------------------------------------------------------------------
ND = 1 << 15                     # new data since the last read of this register
EA = 1 << 14                     # error/alarm: read DIAG_STAT
DATA14_MASK = 0x3FFF
DATA12_MASK = 0x0FFF


def decode_signed14(word: int) -> int:
    """Bits 13:0 as two's complement (gyro, accel, mag). 0x8002 -> +2, 0xBFF9 -> -7 (EZ thread 81805)."""
    return ((word & DATA14_MASK) ^ 0x2000) - 0x2000


def decode_signed12(word: int) -> int:
    """Bits 11:0 as two's complement (TEMP_OUT)."""
    return ((word & DATA12_MASK) ^ 0x0800) - 0x0800


def decode_unsigned14(word: int) -> int:
    """Bits 13:0 unsigned (SUPPLY_OUT)."""
    return word & DATA14_MASK


def decode_unsigned12(word: int) -> int:
    """Bits 11:0 unsigned (AUX_ADC)."""
    return word & DATA12_MASK


def encode_signed14(lsb: int, nd: bool = True, ea: bool = False) -> int:
    """Inverse of decode_signed14 (values outside -8192..8191 wrap: callers clip first)."""
    return (lsb & DATA14_MASK) | (ND if nd else 0) | (EA if ea else 0)


def encode_signed12(lsb: int, nd: bool = True, ea: bool = False) -> int:
    return (lsb & DATA12_MASK) | (ND if nd else 0) | (EA if ea else 0)


def encode_unsigned(lsb: int, bits: int, nd: bool = True, ea: bool = False) -> int:
    return (lsb & ((1 << bits) - 1)) | (ND if nd else 0) | (EA if ea else 0)


def encode_signed14_array(lsb: np.ndarray) -> np.ndarray:
    """Vectorised encode (no ND/EA) of int LSB values already clipped to the 14-bit range."""
    return (np.asarray(lsb, dtype=np.int64) & DATA14_MASK).astype(np.uint16)


def decode_signed14_array(words: np.ndarray) -> np.ndarray:
    w = np.asarray(words, dtype=np.int64)
    return ((w & DATA14_MASK) ^ 0x2000) - 0x2000


LSB14_MIN, LSB14_MAX = -(1 << 13), (1 << 13) - 1
LSB12_MIN, LSB12_MAX = -(1 << 11), (1 << 11) - 1

# --------------------------------------------------------------------------------------------------------
# Scales (ADIS16405 datasheet; kernel adis16400 channel scales)
# --------------------------------------------------------------------------------------------------------
GYRO_DPS_PER_LSB_300 = 0.05      # °/s per LSB at ±300 °/s (default range)
GYRO_DPS_PER_LSB = {300: 0.05, 150: 0.025, 75: 0.0125}   # per SENS_AVG range setting
ACCEL_G_PER_LSB = 3.333e-3       # 3.333 mg/LSB
MAG_GAUSS_PER_LSB = 0.5e-3       # 0.5 mgauss/LSB
TEMP_C_PER_LSB = 0.14            # 0.14 °C/LSB, 12-bit signed
TEMP_C_AT_ZERO = 25.0            # 0 LSB = 25 °C
SUPPLY_V_PER_LSB = 2.418e-3      # 2.418 mV/LSB, 14-bit unsigned
AUX_V_PER_LSB = 805.8e-6         # 805.8 µV/LSB, 12-bit unsigned

UT_PER_GAUSS = 100.0             # 1 gauss = 100 µT

GYRO_RAD_S_PER_LSB = math.radians(GYRO_DPS_PER_LSB_300)
ACCEL_M_S2_PER_LSB = ACCEL_G_PER_LSB * STANDARD_GRAVITY_M_S2
MAG_UT_PER_LSB = MAG_GAUSS_PER_LSB * UT_PER_GAUSS          # 0.05 µT

# Measurement ranges (the simulated chip saturates here; the driver flags values at or beyond them)
GYRO_RANGE_DPS = 300.0           # ±300 °/s at SENS_AVG range 100b
ACCEL_RANGE_G = 18.0             # ±18 g
MAG_RANGE_GAUSS = 2.5            # ±2.5 gauss

# Offset registers (kernel reads calibbias as 12-bit signed: sign_extend32(val, 11))
GYRO_OFF_DPS_PER_LSB = 0.0125    # XGYRO_OFF scale [datasheet memory, unverified]
ACCEL_OFF_G_PER_LSB = ACCEL_G_PER_LSB
MAG_HIF_GAUSS_PER_LSB = MAG_GAUSS_PER_LSB


def gyro_range_lsb(range_dps: float = GYRO_RANGE_DPS) -> int:
    return int(round(range_dps / GYRO_DPS_PER_LSB[int(range_dps)]))


ACCEL_RANGE_LSB = int(round(ACCEL_RANGE_G / ACCEL_G_PER_LSB))      # 5401
MAG_RANGE_LSB = int(round(MAG_RANGE_GAUSS / MAG_GAUSS_PER_LSB))    # 5000


def temp_c_from_lsb(lsb: int) -> float:
    return TEMP_C_AT_ZERO + TEMP_C_PER_LSB * lsb


# --------------------------------------------------------------------------------------------------------
# DIAG_STAT, MSC_CTRL, GLOB_CMD bits (kernel adis16400.c)
# --------------------------------------------------------------------------------------------------------
class DiagStat(enum.IntFlag):
    """DIAG_STAT (0x3C) bits. Any of them set raises EA on the output words."""

    SUPPLY_LOW = 1 << 0          # supply < 4.75 V
    SUPPLY_HIGH = 1 << 1         # supply > 5.25 V
    FLASH_UPDATE_FAILED = 1 << 2
    SPI_FAILURE = 1 << 3         # SPI communication failure (e.g. frame not a multiple of 16 bits)
    SENSOR_OVERRANGE = 1 << 4
    SELF_TEST_FAILED = 1 << 5
    FLASH_CHECKSUM = 1 << 6
    ALARM1 = 1 << 8
    ALARM2 = 1 << 9
    ZGYRO_SELF_TEST = 1 << 10
    YGYRO_SELF_TEST = 1 << 11
    XGYRO_SELF_TEST = 1 << 12
    XACCL_SELF_TEST = 1 << 13
    YACCL_SELF_TEST = 1 << 14
    ZACCL_SELF_TEST = 1 << 15


DIAG_GYRO_SELF_TEST = DiagStat.XGYRO_SELF_TEST | DiagStat.YGYRO_SELF_TEST | DiagStat.ZGYRO_SELF_TEST
DIAG_ACCEL_SELF_TEST = DiagStat.XACCL_SELF_TEST | DiagStat.YACCL_SELF_TEST | DiagStat.ZACCL_SELF_TEST
DIAG_ALL = DiagStat(0xFF7F)      # bit 7 is unused


def diag_faults(diag_stat: int) -> list[str]:
    """Names of the DIAG_STAT bits that are set, lowest bit first (unknown bits as 'BIT7' etc)."""
    names = []
    for bit in range(16):
        if diag_stat & (1 << bit):
            member = DiagStat._value2member_map_.get(1 << bit)
            names.append(member.name if member is not None else f"BIT{bit}")
    return names


class MscCtrl(enum.IntFlag):
    """MSC_CTRL (0x34) bits."""

    DATA_RDY_DIO2 = 1 << 0       # data-ready on DIO2 (0 = DIO1)
    DATA_RDY_POL_HIGH = 1 << 1
    DATA_RDY_EN = 1 << 2
    ACCL_ALIGN = 1 << 6          # point-of-percussion alignment
    GYRO_BIAS = 1 << 7           # linear-g compensation for the gyros
    POS_SELF_TEST = 1 << 8
    NEG_SELF_TEST = 1 << 9
    INT_SELF_TEST = 1 << 10      # internal self-test, clears itself when done
    MEM_TEST = 1 << 11


MSC_CTRL_DEFAULT = 0x0006        # DATA_RDY_EN | POL_HIGH (datasheet default; PSAS writes 0x86)


class GlobCmd(enum.IntFlag):
    """GLOB_CMD (0x3E) command bits (write 1 to execute)."""

    AUTO_NULL = 1 << 0
    FACTORY_CAL_RESTORE = 1 << 1
    DAC_LATCH = 1 << 2
    FLASH_UPDATE = 1 << 3
    PRECISION_AUTO_NULL = 1 << 4
    SOFTWARE_RESET = 1 << 7


# Timings (kernel adis16400_timeouts, ADIS16400_STARTUP_DELAY)
RESET_TIME_S = 0.170             # software reset: 170 ms
SELF_TEST_TIME_S = 0.012         # internal self-test: 12 ms
STARTUP_TIME_S = 0.290           # power-on startup delay
AUTO_NULL_TIME_S = 0.050         # [assumption] short auto-null averaging window
PRECISION_AUTO_NULL_TIME_S = 30.0  # precision auto-null averages ~30 s [datasheet memory, unverified]
FACTORY_RESTORE_TIME_S = 0.050   # [assumption]

# --------------------------------------------------------------------------------------------------------
# SMPL_PRD: output data rate                      # datasheet SMPL_PRD register; kernel adis16400_get_freq()
# --------------------------------------------------------------------------------------------------------
SMPL_PRD_TIME_BASE = 1 << 7      # 1: 52.851 Hz base, 0: 1638.404 Hz base
SMPL_PRD_DIVISOR_MASK = 0x7F
TIME_BASE_FAST_HZ = 1638.404
TIME_BASE_SLOW_HZ = 52.851
SMPL_PRD_DEFAULT = 0x01          # 819.2 SPS


def sample_rate_hz(smpl_prd: int) -> float:
    """Output rate for a SMPL_PRD value: (52.851 if bit7 else 1638.404) / (divisor + 1). 0x01 -> 819.202."""
    base = TIME_BASE_SLOW_HZ if smpl_prd & SMPL_PRD_TIME_BASE else TIME_BASE_FAST_HZ
    return base / ((smpl_prd & SMPL_PRD_DIVISOR_MASK) + 1)


def smpl_prd_for_rate(rate_hz: float) -> int:
    """The SMPL_PRD value whose rate is closest to rate_hz (fast time base preferred)."""
    best, best_err = SMPL_PRD_DEFAULT, math.inf
    for value in range(256):
        err = abs(math.log(sample_rate_hz(value) / rate_hz))
        if err < best_err - 1e-12:
            best, best_err = value, err
    return best


def nearest_rate_hz(rate_hz: float) -> float:
    """The rate the chip runs at when asked for rate_hz: that of the nearest SMPL_PRD setting (204.8 ->
    1638.404 / 8 = 204.8005)."""
    return sample_rate_hz(smpl_prd_for_rate(rate_hz))


# --------------------------------------------------------------------------------------------------------
# SENS_AVG: gyro range and Bartlett filter                               # datasheet SENS_AVG register
# --------------------------------------------------------------------------------------------------------
SENS_AVG_RANGE_SHIFT = 8
SENS_AVG_RANGE_MASK = 0x0700
SENS_AVG_FILTER_MASK = 0x0007
SENS_AVG_RANGE_BITS = {300: 0b100, 150: 0b010, 75: 0b001}   # datasheet SENS_AVG[10:8]
SENS_AVG_DEFAULT = 0x0402        # ±300 °/s, N = 2 (PSAS writes 0x0402)
FILTER_3DB_DIVISORS = (2, 6, 12, 25, 50, 100, 200, 200)     # kernel adis16400_3db_divisors[N]


def encode_sens_avg(range_dps: int = 300, filter_n: int = 2) -> int:
    if range_dps not in SENS_AVG_RANGE_BITS:
        raise ValueError(f"gyro range must be one of {sorted(SENS_AVG_RANGE_BITS)} °/s, not {range_dps}")
    if not 0 <= filter_n <= 7:
        raise ValueError(f"SENS_AVG filter N must be 0..7, not {filter_n}")
    return (SENS_AVG_RANGE_BITS[range_dps] << SENS_AVG_RANGE_SHIFT) | filter_n


def decode_sens_avg(value: int) -> tuple[int, int]:
    """(gyro range °/s, filter N). Unknown range patterns read as ±300 (the widest)."""
    bits = (value & SENS_AVG_RANGE_MASK) >> SENS_AVG_RANGE_SHIFT
    range_dps = 300
    for dps, pattern in SENS_AVG_RANGE_BITS.items():
        if bits == pattern:
            range_dps = dps
    return range_dps, value & SENS_AVG_FILTER_MASK


def bartlett_taps(filter_n: int) -> np.ndarray:
    """Normalised taps of the SENS_AVG Bartlett window filter for setting N.

    Two cascaded 2^N-tap moving averages = a triangular (Bartlett) window of 2^(N+1) - 1 taps; its -3 dB
    point reproduces the kernel's table (N=1: fs/5.5 ≈ fs/6, N=2: fs/12.5 ≈ fs/12). N = 0 is no filtering.
    """
    box = np.ones(1 << filter_n)
    taps = np.convolve(box, box)
    return taps / taps.sum()


def filter_3db_hz(sample_rate: float, filter_n: int) -> float:
    """-3 dB bandwidth as the kernel reports it: sps / {2, 6, 12, 25, 50, 100, 200}[N]."""
    return sample_rate / FILTER_3DB_DIVISORS[filter_n]

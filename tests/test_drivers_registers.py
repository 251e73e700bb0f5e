"""Register map, bits, scales and codecs against the ADIS16405 datasheet (Analog Devices, Rev. B) register map and the
Linux IIO driver drivers/iio/imu/adis16400.c."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ahrsd.drivers import registers as R

# the register table of the datasheet / Linux adis16400 driver
ANCHOR_MAP = {
    "FLASH_CNT": 0x00, "SUPPLY_OUT": 0x02, "XGYRO_OUT": 0x04, "YGYRO_OUT": 0x06, "ZGYRO_OUT": 0x08,
    "XACCL_OUT": 0x0A, "YACCL_OUT": 0x0C, "ZACCL_OUT": 0x0E, "XMAGN_OUT": 0x10, "YMAGN_OUT": 0x12,
    "ZMAGN_OUT": 0x14, "TEMP_OUT": 0x16, "AUX_ADC": 0x18, "XGYRO_OFF": 0x1A, "YGYRO_OFF": 0x1C,
    "ZGYRO_OFF": 0x1E, "XACCL_OFF": 0x20, "YACCL_OFF": 0x22, "ZACCL_OFF": 0x24, "XMAGN_HIF": 0x26,
    "YMAGN_HIF": 0x28, "ZMAGN_HIF": 0x2A, "XMAGN_SIF": 0x2C, "YMAGN_SIF": 0x2E, "ZMAGN_SIF": 0x30,
    "GPIO_CTRL": 0x32, "MSC_CTRL": 0x34, "SMPL_PRD": 0x36, "SENS_AVG": 0x38, "SLP_CNT": 0x3A,
    "DIAG_STAT": 0x3C, "GLOB_CMD": 0x3E, "ALM_MAG1": 0x40, "ALM_MAG2": 0x42, "ALM_SMPL1": 0x44,
    "ALM_SMPL2": 0x46, "ALM_CTRL": 0x48, "AUX_DAC": 0x4A, "PRODUCT_ID": 0x56,
}


def test_register_map_matches_anchor():
    assert R.REGISTERS == ANCHOR_MAP
    for name, addr in ANCHOR_MAP.items():
        assert getattr(R, name) == addr
        assert R.REGISTER_NAMES[addr] == name
    assert R.PRODUCT_ID_ADIS16405 == 0x4015
    assert R.OUTPUT_REGISTERS == tuple(ANCHOR_MAP[n] for n in (
        "SUPPLY_OUT", "XGYRO_OUT", "YGYRO_OUT", "ZGYRO_OUT", "XACCL_OUT", "YACCL_OUT", "ZACCL_OUT",
        "XMAGN_OUT", "YMAGN_OUT", "ZMAGN_OUT", "TEMP_OUT", "AUX_ADC"))


def test_ez_worked_words():
    # EngineerZone thread 81805: 0x8002 -> +2 LSB with ND set; 0xBFF9 -> -7 LSB with ND set
    assert R.decode_signed14(0x8002) == 2 and 0x8002 & R.ND and not 0x8002 & R.EA
    assert R.decode_signed14(0xBFF9) == -7 and 0xBFF9 & R.ND and not 0xBFF9 & R.EA
    assert R.ND == 0x8000 and R.EA == 0x4000
    # the burst-bug pair from the same thread: 0xBFF8 = -8 LSB (-0.4 °/s); 0x9FF8 reads +8184 LSB (+409 °/s)
    assert R.decode_signed14(0xBFF8) * R.GYRO_DPS_PER_LSB_300 == pytest.approx(-0.4)
    assert R.decode_signed14(0x9FF8) * R.GYRO_DPS_PER_LSB_300 == pytest.approx(409.2)


def test_scales():
    assert R.GYRO_DPS_PER_LSB_300 == 0.05
    assert R.GYRO_RAD_S_PER_LSB == pytest.approx(math.radians(0.05))
    assert R.ACCEL_M_S2_PER_LSB == pytest.approx(3.333e-3 * 9.80665)
    assert R.MAG_UT_PER_LSB == pytest.approx(0.05)          # 0.5 mgauss = 0.05 µT
    assert R.temp_c_from_lsb(0) == 25.0
    assert R.temp_c_from_lsb(10) == pytest.approx(26.4)
    assert R.temp_c_from_lsb(-178) == pytest.approx(25 - 24.92)   # IIO offset 25/0.14 = 178 LSB
    assert R.SUPPLY_V_PER_LSB == 2.418e-3 and R.AUX_V_PER_LSB == 805.8e-6
    assert R.GYRO_DPS_PER_LSB == {300: 0.05, 150: 0.025, 75: 0.0125}
    # ranges: ±300 °/s, ±18 g, ±2.5 gauss in LSB
    assert R.gyro_range_lsb(300) == R.gyro_range_lsb(150) == R.gyro_range_lsb(75) == 6000
    assert R.ACCEL_RANGE_LSB == 5401 and R.MAG_RANGE_LSB == 5000


def test_other_word_formats():
    assert R.decode_signed12(0x8FFF) == -1 and R.decode_signed12(0x87FF) == 2047 and R.decode_signed12(0x0800) == -2048
    assert R.decode_unsigned14(0xFFFF) == 0x3FFF and R.decode_unsigned14(0x8000 | 2068) == 2068
    assert R.decode_unsigned12(0xCFFF) == 0xFFF
    assert R.encode_signed14(-7) == 0xBFF9 and R.encode_signed14(2) == 0x8002
    assert R.encode_signed14(-7, nd=False, ea=True) == 0x7FF9
    assert R.encode_signed12(-1) == 0x8FFF
    assert R.encode_unsigned(2068, 14, nd=False) == 2068


@settings(derandomize=True, max_examples=200)
@given(st.integers(R.LSB14_MIN, R.LSB14_MAX), st.booleans(), st.booleans())
def test_signed14_round_trip(lsb, nd, ea):
    w = R.encode_signed14(lsb, nd, ea)
    assert 0 <= w <= 0xFFFF
    assert R.decode_signed14(w) == lsb
    assert bool(w & R.ND) == nd and bool(w & R.EA) == ea
    assert R.decode_signed14_array(np.array([w]))[0] == lsb
    assert R.encode_signed14_array(np.array([lsb]))[0] == w & 0x3FFF


@settings(derandomize=True, max_examples=100)
@given(st.integers(R.LSB12_MIN, R.LSB12_MAX))
def test_signed12_round_trip(lsb):
    assert R.decode_signed12(R.encode_signed12(lsb)) == lsb


def test_diag_stat_bits_named():
    assert R.diag_faults(0) == []
    expected = {0: "SUPPLY_LOW", 1: "SUPPLY_HIGH", 2: "FLASH_UPDATE_FAILED", 3: "SPI_FAILURE", 4: "SENSOR_OVERRANGE",
                5: "SELF_TEST_FAILED", 6: "FLASH_CHECKSUM", 8: "ALARM1", 9: "ALARM2", 10: "ZGYRO_SELF_TEST",
                11: "YGYRO_SELF_TEST", 12: "XGYRO_SELF_TEST", 13: "XACCL_SELF_TEST", 14: "YACCL_SELF_TEST",
                15: "ZACCL_SELF_TEST"}
    for bit, name in expected.items():
        assert R.diag_faults(1 << bit) == [name]
    assert R.diag_faults(1 << 7) == ["BIT7"]
    assert R.diag_faults(0x1021) == ["SUPPLY_LOW", "SELF_TEST_FAILED", "XGYRO_SELF_TEST"]
    assert int(R.DIAG_ALL) == 0xFF7F


def test_msc_ctrl_and_glob_cmd_bits():
    assert R.MscCtrl.INT_SELF_TEST == 0x0400 and R.MscCtrl.MEM_TEST == 0x0800
    assert R.MscCtrl.POS_SELF_TEST == 0x100 and R.MscCtrl.NEG_SELF_TEST == 0x200
    assert R.MscCtrl.GYRO_BIAS | R.MscCtrl.DATA_RDY_EN | R.MscCtrl.DATA_RDY_POL_HIGH == 0x86   # PSAS value
    assert R.GlobCmd.SOFTWARE_RESET == 0x80 and R.GlobCmd.PRECISION_AUTO_NULL == 0x10
    assert R.GlobCmd.FLASH_UPDATE == 0x08 and R.GlobCmd.DAC_LATCH == 0x04
    assert R.GlobCmd.FACTORY_CAL_RESTORE == 0x02 and R.GlobCmd.AUTO_NULL == 0x01


def test_frames():
    assert R.read_frame(R.PRODUCT_ID) == b"\x56\x00"
    assert R.BURST_COMMAND == b"\x3e\x00" and R.BURST_FRAME_BYTES == 26
    # anchors: write = (0x80|(addr+1))<<8 | hi, then (0x80|addr)<<8 | lo;  0xBE80 = reset, 0xBE02 = restore
    assert R.write_frames(R.SMPL_PRD, 0x0102) == (b"\xb7\x01", b"\xb6\x02")
    assert R.write_frames(R.GLOB_CMD, 0x0080)[1] == b"\xbe\x80"


def test_sample_rate_formula():
    assert R.sample_rate_hz(0x01) == pytest.approx(819.202)
    assert R.sample_rate_hz(0x00) == pytest.approx(1638.404)
    assert R.sample_rate_hz(0x80) == pytest.approx(52.851)
    assert R.sample_rate_hz(0x81) == pytest.approx(52.851 / 2)
    assert R.sample_rate_hz(0x7F) == pytest.approx(1638.404 / 128)
    assert R.smpl_prd_for_rate(819.2) == 0x01
    assert R.smpl_prd_for_rate(409.6) == 0x03
    assert R.sample_rate_hz(R.smpl_prd_for_rate(1.0)) == pytest.approx(1.0, rel=0.03)


def test_spi_clock_rule():
    assert R.spi_speed_hz(0x00) == R.spi_speed_hz(0x09) == 2_000_000
    assert R.spi_speed_hz(0x0A) == R.spi_speed_hz(0x7F) == 300_000
    assert R.spi_speed_hz(0x81) == 300_000          # slow time base: never fast
    assert R.SPI_BURST_HZ == 1_000_000


def test_sens_avg():
    assert R.encode_sens_avg(300, 2) == 0x0402 == R.SENS_AVG_DEFAULT
    assert R.encode_sens_avg(150, 0) == 0x0200 and R.encode_sens_avg(75, 7) == 0x0107
    assert R.decode_sens_avg(0x0402) == (300, 2) and R.decode_sens_avg(0x0105) == (75, 5)
    with pytest.raises(ValueError):
        R.encode_sens_avg(200, 1)
    with pytest.raises(ValueError):
        R.encode_sens_avg(300, 8)


@pytest.mark.parametrize("n", range(8))
def test_bartlett_taps(n):
    taps = R.bartlett_taps(n)
    assert len(taps) == 2 ** (n + 1) - 1
    assert taps.sum() == pytest.approx(1.0)
    assert np.allclose(taps, taps[::-1]) and np.argmax(taps) == len(taps) // 2
    if 1 <= n <= 6:
        # -3 dB point of the taps within 12 % of the kernel's sps / {6, 12, 25, 50, 100, 200}[N]
        f = np.linspace(1e-6, 0.5, 200001)
        h = np.abs(np.exp(-2j * np.pi * np.outer(f, np.arange(len(taps)))) @ taps) if n < 4 else None
        if h is None:   # long filters: closed form of two cascaded boxes
            m = 2 ** n
            h = (np.sin(np.pi * f * m) / (m * np.sin(np.pi * f))) ** 2
        f3 = f[np.argmax(h < 1 / math.sqrt(2))]
        assert f3 == pytest.approx(1 / R.FILTER_3DB_DIVISORS[n], rel=0.12)
    assert R.filter_3db_hz(819.2, 2) == pytest.approx(819.2 / 12)

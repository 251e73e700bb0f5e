"""The output register read after a burst whose index the host clock leaves open (Adis16405.take_newer_sample,
drivers/chip_source._checked_index). SUPPLY_OUT is read: with ND set a sample newer than the burst's is ready
(its supply may differ from the burst's, but by no more than a supply moves in one sample period); with ND clear
the register still holds the burst's own sample, so its supply word must be the burst's, to the LSB. Any other
answer is not the chip's and must not decide an index: a FrameError, counted as a rejected frame.

The bus answers are built here word by word (tests/support/frame_bus.py: a burst gives one frame, register reads
come pipelined from a table), so the expectations are the rule above, not the driver's arithmetic."""

from __future__ import annotations

import pytest
from support.frame_bus import FrameBus

from ahrsd.drivers import registers as R
from ahrsd.drivers.adis16405 import Adis16405
from ahrsd.drivers.errors import FrameError

BURST_SUPPLY_LSB = 2068                 # 5.0 V at 2.418 mV/LSB
AXES_LSB = [100, -200, 300, 50, -60, -300, 400, -100, 900]
# a supply step no supply makes between two samples 1.2 ms apart: 100 LSB is 0.24 V
STEP_BEYOND_ANY_SUPPLY_LSB = 101


def burst_words(supply_lsb, lsb9, flag_bits):
    """SUPPLY_OUT and the nine sensor words (14 bits, two's complement) with the flag bits, TEMP_OUT, AUX_ADC."""
    return [(w & 0x3FFF) | flag_bits for w in [supply_lsb] + list(lsb9)] + [0, 0]


def driver_after_a_burst(supply_out_word: int) -> Adis16405:
    """A driver that has just read a burst (ND set, supply BURST_SUPPLY_LSB) on a bus whose SUPPLY_OUT register
    now answers `supply_out_word`."""
    words = burst_words(BURST_SUPPLY_LSB, AXES_LSB, R.ND)
    imu = Adis16405(FrameBus(words, {R.XGYRO_OUT: words[1], R.SUPPLY_OUT: supply_out_word}))
    imu.read_sample()
    assert imu.counters["garbage_frames"] == 0 and imu.counters["samples"] == 1
    return imu


@pytest.mark.parametrize("supply_lsb", [BURST_SUPPLY_LSB, BURST_SUPPLY_LSB - 100, BURST_SUPPLY_LSB + 100])
def test_nd_set_says_a_newer_sample_is_ready_and_is_taken(supply_lsb):
    imu = driver_after_a_burst(R.ND | supply_lsb)
    assert imu.take_newer_sample() is True
    assert imu.newer_sample_taken
    assert imu.counters["garbage_frames"] == 0


def test_nd_clear_with_the_bursts_own_supply_says_the_burst_was_the_newest():
    imu = driver_after_a_burst(BURST_SUPPLY_LSB)
    assert imu.take_newer_sample() is False
    assert not imu.newer_sample_taken
    assert imu.counters["garbage_frames"] == 0


@pytest.mark.parametrize("supply_lsb", [BURST_SUPPLY_LSB + 1, BURST_SUPPLY_LSB - 1, 0])
def test_nd_clear_with_another_supply_word_is_no_answer(supply_lsb):
    """Without ND the register holds the burst's sample: a supply word one LSB off is another sample's (or a
    corrupt word), and the index it would decide cannot be trusted."""
    imu = driver_after_a_burst(supply_lsb)
    with pytest.raises(FrameError, match="another sample's supply without ND"):
        imu.take_newer_sample()
    assert imu.counters["garbage_frames"] == 1


@pytest.mark.parametrize("step_lsb", [STEP_BEYOND_ANY_SUPPLY_LSB, -STEP_BEYOND_ANY_SUPPLY_LSB])
def test_nd_set_with_a_supply_step_no_supply_makes_is_no_answer(step_lsb):
    imu = driver_after_a_burst(R.ND | (BURST_SUPPLY_LSB + step_lsb))
    with pytest.raises(FrameError, match="supply step"):
        imu.take_newer_sample()
    assert imu.counters["garbage_frames"] == 1
    assert not imu.newer_sample_taken

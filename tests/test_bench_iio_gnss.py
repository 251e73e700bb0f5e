"""bench/iio_gnss.py: the GNSS receiver bench/latency.py runs beside a simulated IIO device (`--sensor iio --gnss on`)
describes the vehicle of the kernel's records at the same instants. The chip's time origin is found here from the
records themselves, not from what the device publishes: the first record's stamp (CLOCK_MONOTONIC, the kernel's
edge time) minus its chip sample index over the rate. Each fix, stamped on arrival − the receiver's latency as the
daemon's serial source stamps it, must then lie on the scenario's truth at that chip time (the truth computed here
from the scenario, simulation.open_stream). A receiver on another time origin is off by the boat's speed × the
offset: the boat makes 4.05 m/s (3.51 north, 2.02 east) in its first seconds, straight and steady, so an offset
shows only in position, whose own error is ~2 m. The test catches a receiver on the host's clock (the boat kilometres
away) or an offset beyond ~2 s (8 m); the ~0.3 s between the chip's time 0 and the receiver's start is within
the fixes' noise here."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from ahrsd.drivers.gnss.serial_port import SerialGnssSource
from ahrsd.drivers.iio_source import IioSource
from ahrsd.drivers.simulated_iio import SimulatedIioDevice
from ahrsd.simulation import open_stream
from bench.iio_gnss import IioGnssReceiver

SCENARIO, SEED = "boat", 0
RATE_HZ = 819.2                 # the chip's default (SMPL_PRD 1): the device's rate, not written here
FIXES = 15                      # 3 s of fixes at 5 Hz
TOLERANCE_M = 8.0               # median horizontal distance to the truth: the fixes' own error is ~2 m (their
                                # median, measured: 2.0-2.1 m in three runs, 20:08-20:10 UTC)


def horizontal_m(lat1, lon1, lat2, lon2) -> np.ndarray:
    """Local flat-earth distance (metres), enough over metres."""
    r = 6_371_000.0
    dn = np.radians(np.asarray(lat1) - lat2) * r
    de = np.radians(np.asarray(lon1) - lon2) * r * math.cos(math.radians(float(np.mean(lat2))))
    return np.hypot(dn, de)


@pytest.fixture
def rig(tmp_path):
    device = SimulatedIioDevice(tmp_path / "iio", scenario=SCENARIO, seed=SEED)
    device.wait_ready()
    receiver = IioGnssReceiver(device, SCENARIO, seed=SEED)
    yield device, receiver
    receiver.close()
    device.close()


def test_the_receivers_fixes_lie_on_the_records_vehicle_at_the_records_time(rig):
    device, receiver = rig
    source = IioSource(str(device.sysfs))
    source.start()
    port = SerialGnssSource(receiver.device, receiver.baud, "ubx", latency_s=receiver.latency_s)
    samples, fixes = [], []
    end = time.monotonic() + 60.0
    try:
        while len(fixes) < FIXES and time.monotonic() < end:
            samples += source.poll()
            fixes += [f for f in port.read() if f.has_position]
            time.sleep(0.02)
    finally:
        port.close()
        source.close()
    assert len(fixes) >= FIXES and samples
    # the chip's time 0 from the kernel's records: the first record read is the first the kernel wrote
    origin_s = samples[0].t_s - device.first_index_written / RATE_HZ
    chip_t = np.array([f.t_s for f in fixes]) - origin_s
    truth = open_stream(SCENARIO, seed=SEED, errors="ideal").truth_at(chip_t)
    dist = horizontal_m([f.lat_deg for f in fixes], [f.lon_deg for f in fixes], truth.lat_deg, truth.lon_deg)
    speed = np.hypot(truth.vel_ned_m_s[:, 0], truth.vel_ned_m_s[:, 1])
    assert np.median(speed) > 2.0             # moving: a time offset shows as a distance
    assert np.median(dist) < TOLERANCE_M, (np.median(dist), np.median(speed))

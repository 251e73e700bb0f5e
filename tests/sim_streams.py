"""Sensor streams for tests of the simulated chip: constant values plus optional white noise."""

from __future__ import annotations

import numpy as np

from ahrsd.drivers import registers as R


class FixedStream:
    """A minimal stream for tests and bench work: constant values plus optional white noise.

    Same shape as `ahrsd.simulation`'s SensorStream (`next_block(n)` -> object with t_s, gyro_rad_s,
    accel_m_s2, mag_ut, temp_c, truth_q_wxyz, truth_gyro_rad_s), without any physics. The values are
    attributes; a change takes effect from the next block the chip pulls (every 256 samples).
    noise_std: (gyro rad/s, accel m/s², mag µT) standard deviations of white noise per sample.
    """

    def __init__(self, gyro_rad_s=(0.0, 0.0, 0.0), accel_m_s2=(0.0, 0.0, -R.STANDARD_GRAVITY_M_S2),
                 mag_ut=(20.0, 0.0, 45.0), temp_c: float = 25.0, rate_hz: float = 819.202,
                 noise_std=(0.0, 0.0, 0.0), seed: int = 0):
        self.gyro_rad_s = np.asarray(gyro_rad_s, dtype=float)
        self.accel_m_s2 = np.asarray(accel_m_s2, dtype=float)
        self.mag_ut = np.asarray(mag_ut, dtype=float)
        self.temp_c = float(temp_c)
        self.rate_hz = rate_hz
        self.noise_std = tuple(float(x) for x in noise_std)
        self._rng = np.random.default_rng(seed)
        self._k = 0

    def next_block(self, n: int):
        from types import SimpleNamespace

        t = (self._k + np.arange(n)) / self.rate_hz
        self._k += n
        out = []
        for value, std in zip((self.gyro_rad_s, self.accel_m_s2, self.mag_ut), self.noise_std):
            block = np.tile(value, (n, 1))
            if std > 0:
                block = block + self._rng.normal(0.0, std, (n, 3))
            out.append(block)
        q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        return SimpleNamespace(t_s=t, gyro_rad_s=out[0], accel_m_s2=out[1], mag_ut=out[2],
                               temp_c=np.full(n, self.temp_c), truth_q_wxyz=q,
                               truth_gyro_rad_s=np.tile(self.gyro_rad_s, (n, 1)))

"""Sensor error model of a MEMS IMU with a magnetometer, with ADIS16405 defaults.

Per axis (the usual inertial-sensor error model: Groves, "Principles of GNSS, Inertial, and Multisensor
Integrated Navigation Systems", 2nd ed., §4.4, eqs. 4.16–4.17, with a magnetometer added):

    gyro  = (I + diag(scale) + misalignment) · ω_true + b_turn_on + b_gm(t) + k_T (T − 25 °C) + n
    accel = (I + diag(scale) + misalignment) · f_true + b_turn_on + b_gm(t) + k_T (T − 25 °C) + n
    mag   = soft_iron · B_true + hard_iron (+ hard_iron_step from hard_iron_step_t_s on) + n

b_gm is a first-order Gauss–Markov process (bias instability) with standard deviation σ and correlation time τ:
b[k+1] = φ b[k] + w, φ = exp(−Δt/τ), var(w) = σ²(1 − φ²), started from its stationary distribution.
n is white noise whose per-sample standard deviation is density · √rate_hz (the random-walk convention: an
angle random walk N gives σ = N/√Δt per sample), so a lower sample rate behaves like averaged samples.

Frame: the sensor frame, which the simulator takes equal to the body frame (FRD).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2
from ahrsd.simulation.magnetic import VehicleIron

DEG = np.pi / 180.0

# --- ADIS16405 figures (NaveGo's ADIS16405 error profile, github.com/rodralez/NaveGo = datasheet values) ------
ADIS_ARW_DEG_RT_H = 2.0              # gyro angle random walk, °/√h (NaveGo ADIS16405.arw)
ADIS_GYRO_BIAS_STAB_DEG_S = 0.007    # gyro in-run bias stability, °/s (NaveGo gb_drift)
ADIS_VRW_M_S_RT_H = 0.2              # accel velocity random walk, m/s/√h (NaveGo)
ADIS_ACCEL_BIAS_STAB_MG = 0.2        # accel in-run bias stability, mg (NaveGo)
ADIS_MAG_NOISE_MGAUSS_RMS = 1.25     # magnetometer output noise at 819.2 SPS, mgauss rms (datasheet)
ADIS_RATE_HZ = 819.2                 # ADIS16405 default output rate (datasheet SMPL_PRD default; 1638.4/2)
# Choices (not datasheet figures), see docs/simulation.md:
BIAS_CORR_TIME_S = 100.0             # Gauss–Markov correlation time of both bias-instability processes
GYRO_TURN_ON_SIGMA_DEG_S = 0.1       # residual turn-on bias after factory calibration (NaveGo's 3 °/s is worst case)
ACCEL_TURN_ON_SIGMA_MG = 5.0         # residual turn-on bias (NaveGo's 50 mg is the uncalibrated worst case)
SCALE_SIGMA = 0.003                  # 0.3 % scale-factor error per axis (gyro and accel)
MISALIGN_SIGMA_RAD = 0.1 * DEG       # per off-diagonal element (axis-to-axis non-orthogonality + mounting)
MAG_HARD_SIGMA_UT = 0.4              # sensor's own residual magnetometer offset (4 mgauss)
MAG_SCALE_SIGMA = 0.005              # magnetometer scale error per axis
MAG_MISALIGN_SIGMA_RAD = 0.2 * DEG   # magnetometer axis non-orthogonality


def _vec3(x, name):
    a = np.array(x, dtype=float)
    if a.shape == ():
        a = np.full(3, float(a))
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers, got {x!r}")
    a.flags.writeable = False
    return a


def _mat3(x, name):
    a = np.array(x, dtype=float)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be a finite 3x3 matrix")
    a.flags.writeable = False
    return a


def _nonneg(x, name):
    v = float(x)
    if not np.isfinite(v) or v < 0:
        raise ValueError(f"{name} must be finite and ≥ 0, got {x!r}")
    return v


@dataclass(frozen=True, eq=False)
class SensorErrors:
    """Every error of the simulated sensor, as realised values (the turn-on draws are already made).

    Gyro (rad/s), accelerometer (m/s²), magnetometer (µT); vectors are per axis (x, y, z) of the sensor frame.
    """

    gyro_bias_rad_s: np.ndarray                 # turn-on bias, rad/s
    gyro_scale: np.ndarray                      # fractional scale-factor error (0.003 = +0.3 %)
    gyro_misalignment_rad: np.ndarray           # (3,3) off-diagonal cross-axis coupling, rad; diagonal must be 0
    gyro_noise_density_rad_s_rthz: float        # white noise (ARW), rad/s/√Hz: per-sample σ = this · √rate_hz
    gyro_bias_instability_rad_s: float          # σ of the Gauss–Markov in-run bias, rad/s
    gyro_bias_corr_time_s: float                # τ of that process, s
    gyro_bias_temp_rad_s_per_c: np.ndarray      # bias change per °C away from 25 °C, rad/s/°C
    accel_bias_m_s2: np.ndarray                 # turn-on bias, m/s²
    accel_scale: np.ndarray                     # fractional scale-factor error
    accel_misalignment_rad: np.ndarray          # (3,3) off-diagonal, rad
    accel_noise_density_m_s2_rthz: float        # white noise (VRW), m/s²/√Hz = m/s/√s
    accel_bias_instability_m_s2: float          # σ of the Gauss–Markov in-run bias, m/s²
    accel_bias_corr_time_s: float               # τ, s
    accel_bias_temp_m_s2_per_c: np.ndarray      # bias change per °C away from 25 °C
    hard_iron_ut: np.ndarray                    # (3,) magnetometer offset, µT (sensor offset + vehicle hard iron)
    soft_iron: np.ndarray                       # (3,3) distortion: measured = soft_iron · true + hard_iron
    mag_noise_density_ut_rthz: float            # white noise, µT/√Hz: per-sample σ = this · √rate_hz
    temp_ambient_c: float = 25.0                # sensor temperature at power-on, °C
    temp_warmup_c: float = 0.0                  # self-heating rise after power-on, °C
    temp_warmup_tau_s: float = 600.0            # time constant of that rise, s
    hard_iron_step_ut: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """(3,) change of the hard iron at `hard_iron_step_t_s` (a battery, winch or load moved), sensor frame, µT."""
    hard_iron_step_t_s: float = math.inf        # stream time of that change, s (inf: never)

    def __post_init__(self):
        for name in ("gyro_bias_rad_s", "gyro_scale", "gyro_bias_temp_rad_s_per_c",
                     "accel_bias_m_s2", "accel_scale", "accel_bias_temp_m_s2_per_c", "hard_iron_ut",
                     "hard_iron_step_ut"):
            object.__setattr__(self, name, _vec3(getattr(self, name), name))
        for name in ("gyro_misalignment_rad", "accel_misalignment_rad", "soft_iron"):
            object.__setattr__(self, name, _mat3(getattr(self, name), name))
        for name in ("gyro_misalignment_rad", "accel_misalignment_rad"):
            if np.any(np.diag(getattr(self, name)) != 0.0):
                raise ValueError(f"{name}: the diagonal must be zero (scale errors go in *_scale)")
        if abs(np.linalg.det(self.soft_iron)) < 1e-6:
            raise ValueError("soft_iron is singular")
        for name in ("gyro_noise_density_rad_s_rthz", "gyro_bias_instability_rad_s",
                     "accel_noise_density_m_s2_rthz", "accel_bias_instability_m_s2",
                     "mag_noise_density_ut_rthz", "temp_warmup_c"):
            object.__setattr__(self, name, _nonneg(getattr(self, name), name))
        for name in ("gyro_bias_corr_time_s", "accel_bias_corr_time_s", "temp_warmup_tau_s"):
            v = float(getattr(self, name))
            if not v > 0 or not np.isfinite(v):
                raise ValueError(f"{name} must be a positive finite time, got {v!r}")
            object.__setattr__(self, name, v)
        object.__setattr__(self, "temp_ambient_c", float(self.temp_ambient_c))
        step_t = float(self.hard_iron_step_t_s)
        if math.isnan(step_t):
            raise ValueError("hard_iron_step_t_s must be a time or inf, got nan")
        object.__setattr__(self, "hard_iron_step_t_s", step_t)

    # --- derived ------------------------------------------------------------------------------------------
    @property
    def gyro_matrix(self) -> np.ndarray:
        """gyro = gyro_matrix · ω + bias: a perfect calibration is inv(gyro_matrix) · (raw − bias)."""
        return np.eye(3) + np.diag(self.gyro_scale) + self.gyro_misalignment_rad

    @property
    def accel_matrix(self) -> np.ndarray:
        return np.eye(3) + np.diag(self.accel_scale) + self.accel_misalignment_rad

    def noise_std(self, rate_hz: float) -> dict:
        """Per-sample white-noise standard deviations at `rate_hz`: {'gyro_rad_s', 'accel_m_s2', 'mag_ut'}."""
        s = np.sqrt(rate_hz)
        return {"gyro_rad_s": self.gyro_noise_density_rad_s_rthz * s,
                "accel_m_s2": self.accel_noise_density_m_s2_rthz * s,
                "mag_ut": self.mag_noise_density_ut_rthz * s}

    def replace(self, **changes) -> "SensorErrors":
        return dataclasses.replace(self, **changes)

    def with_vehicle_iron(self, iron: VehicleIron) -> "SensorErrors":
        """The errors in force when this sensor sits in a vehicle with `iron`.

        The vehicle distorts the field at the sensor (S_v B + h_v), then the sensor's own matrix and offset act:
        measured = S_s (S_v B + h_v) + h_s, i.e. soft = S_s S_v, hard = S_s h_v + h_s.
        """
        return self.replace(soft_iron=self.soft_iron @ iron.soft_iron,
                            hard_iron_ut=self.soft_iron @ iron.hard_iron_ut + self.hard_iron_ut)

    # --- constructors --------------------------------------------------------------------------------------
    @classmethod
    def ideal(cls) -> "SensorErrors":
        """No errors at all: the sensor outputs the truth."""
        z3, z33 = np.zeros(3), np.zeros((3, 3))
        return cls(z3, z3, z33, 0.0, 0.0, BIAS_CORR_TIME_S, z3,
                   z3, z3, z33, 0.0, 0.0, BIAS_CORR_TIME_S, z3,
                   z3, np.eye(3), 0.0)

    @classmethod
    def adis16405(cls, seed: int = 0) -> "SensorErrors":
        """An ADIS16405 as shipped (factory-calibrated), its turn-on errors drawn from `seed`.

        Noise and bias-instability figures from NaveGo's ADIS16405 profile (the datasheet values);
        turn-on biases, scale and misalignment spreads are this simulator's choices (docs/simulation.md).
        """
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xAD15]))

        def off_diag(sigma):
            m = rng.normal(0.0, sigma, (3, 3))
            np.fill_diagonal(m, 0.0)
            return m

        gyro_bias = rng.normal(0.0, GYRO_TURN_ON_SIGMA_DEG_S * DEG, 3)
        gyro_scale = rng.normal(0.0, SCALE_SIGMA, 3)
        gyro_mis = off_diag(MISALIGN_SIGMA_RAD)
        accel_bias = rng.normal(0.0, ACCEL_TURN_ON_SIGMA_MG * 1e-3 * STANDARD_GRAVITY_M_S2, 3)
        accel_scale = rng.normal(0.0, SCALE_SIGMA, 3)
        accel_mis = off_diag(MISALIGN_SIGMA_RAD)
        hard = rng.normal(0.0, MAG_HARD_SIGMA_UT, 3)
        soft = np.eye(3) + np.diag(rng.normal(0.0, MAG_SCALE_SIGMA, 3)) + off_diag(MAG_MISALIGN_SIGMA_RAD)
        return cls(
            gyro_bias_rad_s=gyro_bias,
            gyro_scale=gyro_scale,
            gyro_misalignment_rad=gyro_mis,
            # ARW 2 °/√h = 2/60 °/√s → 5.8e-4 rad/s/√Hz; at 819.2 SPS σ = 0.95 °/s per sample, which matches
            # the datasheet's (unverified) 0.9 °/s rms output noise, so ARW alone explains the output noise.
            gyro_noise_density_rad_s_rthz=ADIS_ARW_DEG_RT_H / 60.0 * DEG,
            gyro_bias_instability_rad_s=ADIS_GYRO_BIAS_STAB_DEG_S * DEG,
            gyro_bias_corr_time_s=BIAS_CORR_TIME_S,
            gyro_bias_temp_rad_s_per_c=np.zeros(3),   # the ADIS16405 is temperature-compensated at the factory
            accel_bias_m_s2=accel_bias,
            accel_scale=accel_scale,
            accel_misalignment_rad=accel_mis,
            # VRW 0.2 m/s/√h = 3.3e-3 m/s²/√Hz; at 819.2 SPS σ = 0.095 m/s² = 9.7 mg (datasheet: 9 mg rms).
            accel_noise_density_m_s2_rthz=ADIS_VRW_M_S_RT_H / 60.0,
            accel_bias_instability_m_s2=ADIS_ACCEL_BIAS_STAB_MG * 1e-3 * STANDARD_GRAVITY_M_S2,
            accel_bias_corr_time_s=BIAS_CORR_TIME_S,
            accel_bias_temp_m_s2_per_c=np.zeros(3),
            hard_iron_ut=hard,
            soft_iron=soft,
            # 1.25 mgauss = 0.125 µT rms per sample at 819.2 SPS, expressed as a density.
            mag_noise_density_ut_rthz=ADIS_MAG_NOISE_MGAUSS_RMS * 0.1 / np.sqrt(ADIS_RATE_HZ),
            temp_ambient_c=25.0,
            temp_warmup_c=6.0,        # a few °C of self-heating after power-on (choice; TEMP_OUT shows it)
            temp_warmup_tau_s=600.0,
        )


def first_order_recursion(phi: float, w: np.ndarray, state: np.ndarray):
    """y[k] = φ·y[k−1] + w[k] for the rows of w (n, 3), with y[−1] = state; returns y and its last row.

    Closed form, y[j] = φʲ·(φ·y[−1] + Σ_{i≤j} φ⁻ⁱ·w[i]), over chunks short enough that φ⁻ⁱ stays below 1e3
    (numpy only: scipy.signal.lfilter computes the same, but importing scipy.signal would weigh on the
    simulated daemon's start)."""
    w = np.asarray(w, dtype=float)
    n = len(w)
    out = np.empty_like(w)
    if n == 0:
        return out, state
    if phi == 0.0:
        out[:] = w
        return out, out[-1]
    chunk = n if phi >= 1.0 else max(1, min(n, int(math.log(1e3) / -math.log(phi))))
    y = np.asarray(state, dtype=float)
    for a in range(0, n, chunk):
        blk = w[a : a + chunk]
        p = phi ** np.arange(len(blk), dtype=float)[:, None]
        out[a : a + len(blk)] = p * (phi * y + np.cumsum(blk / p, axis=0))
        y = out[a + len(blk) - 1]
    return out, y


class ErrorProcess:
    """Applies a `SensorErrors` to blocks of truth, keeping the random processes' state between blocks.

    Each random source has its own generator, so the output does not depend on how the stream is cut into
    blocks: two blocks of 50 equal one block of 100, bit for bit.
    """

    def __init__(self, errors: SensorErrors, rate_hz: float, seed: int = 0):
        self.errors = errors
        self.rate_hz = float(rate_hz)
        dt = 1.0 / self.rate_hz
        ss = np.random.SeedSequence([int(seed), 0x5EED])
        gens = [np.random.default_rng(s) for s in ss.spawn(5)]
        self._rng_gyro, self._rng_accel, self._rng_mag, self._rng_gyro_gm, self._rng_accel_gm = gens
        std = errors.noise_std(self.rate_hz)
        self._gyro_std, self._accel_std, self._mag_std = std["gyro_rad_s"], std["accel_m_s2"], std["mag_ut"]
        self._phi_g = np.exp(-dt / errors.gyro_bias_corr_time_s)
        self._phi_a = np.exp(-dt / errors.accel_bias_corr_time_s)
        self._w_g = errors.gyro_bias_instability_rad_s * np.sqrt(1.0 - self._phi_g**2)
        self._w_a = errors.accel_bias_instability_m_s2 * np.sqrt(1.0 - self._phi_a**2)
        # Gauss–Markov states start from their stationary distribution (the sensor has been on before).
        self._gm_g = self._rng_gyro_gm.normal(0.0, 1.0, 3) * errors.gyro_bias_instability_rad_s
        self._gm_a = self._rng_accel_gm.normal(0.0, 1.0, 3) * errors.accel_bias_instability_m_s2
        self._gyro_mat_t = errors.gyro_matrix.T
        self._accel_mat_t = errors.accel_matrix.T
        self._soft_t = errors.soft_iron.T

    @staticmethod
    def _gauss_markov(rng, phi, w_std, state, n):
        """n steps of b[k] = φ b[k−1] + w[k], starting after `state`; returns (n,3) and the last state."""
        if w_std == 0.0:
            out = state[None, :] * phi ** np.arange(1, n + 1)[:, None]
            return out, (out[-1] if n else state)
        return first_order_recursion(phi, rng.standard_normal((n, 3)) * w_std, state)

    def temperature_c(self, t_s: np.ndarray) -> np.ndarray:
        e = self.errors
        return e.temp_ambient_c + e.temp_warmup_c * (1.0 - np.exp(-np.maximum(t_s, 0.0) / e.temp_warmup_tau_s))

    def apply(self, t_s, gyro_true, accel_true, mag_true):
        """Sensor outputs for truth arrays (n,3); returns gyro, accel, mag, temp_c, gyro_bias, accel_bias."""
        n = len(t_s)
        e = self.errors
        temp = self.temperature_c(t_s)
        dtemp = (temp - 25.0)[:, None]
        gm_g, self._gm_g = self._gauss_markov(self._rng_gyro_gm, self._phi_g, self._w_g, self._gm_g, n)
        gm_a, self._gm_a = self._gauss_markov(self._rng_accel_gm, self._phi_a, self._w_a, self._gm_a, n)
        gyro_bias = e.gyro_bias_rad_s + gm_g + dtemp * e.gyro_bias_temp_rad_s_per_c
        accel_bias = e.accel_bias_m_s2 + gm_a + dtemp * e.accel_bias_temp_m_s2_per_c
        gyro = gyro_true @ self._gyro_mat_t + gyro_bias
        accel = accel_true @ self._accel_mat_t + accel_bias
        mag = mag_true @ self._soft_t + e.hard_iron_ut
        if math.isfinite(e.hard_iron_step_t_s):
            mag += (np.asarray(t_s)[:, None] >= e.hard_iron_step_t_s) * e.hard_iron_step_ut
        if self._gyro_std:
            gyro += self._rng_gyro.standard_normal((n, 3)) * self._gyro_std
        if self._accel_std:
            accel += self._rng_accel.standard_normal((n, 3)) * self._accel_std
        if self._mag_std:
            mag += self._rng_mag.standard_normal((n, 3)) * self._mag_std
        return gyro, accel, mag, temp, gyro_bias, accel_bias

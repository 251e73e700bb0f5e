"""Simulated sensor streams: a scenario's truth, the site's gravity and field, and a sensor error model.

    open_stream("level-turns").next_block(82)   # the next 82 samples at 819.2 Hz, with ADIS16405 errors
    simulate("tumble", seconds=90, rate_hz=100)  # one block of 90 s, for tests and benchmarks
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ahrsd.simulation.errors import ErrorProcess, SensorErrors
from ahrsd.simulation.euler_quat import ned_to_body
from ahrsd.core.gravity import EARTH_RADIUS_M, normal_gravity_m_s2
from ahrsd.simulation.gravity import earth_rate_ned_rad_s, transport_rate_ned_rad_s
from ahrsd.simulation.magnetic import VehicleIron
from ahrsd.simulation.scenarios import Scenario, make_scenario
from ahrsd.simulation.site import DEFAULT_SITE, Site
from ahrsd.simulation.track import GeodeticTrack


@dataclass(frozen=True, eq=False)
class Truth:
    """The vehicle's true state at times t_s (n,): attitude q_wxyz (n,4) body→NED (w ≥ 0), body rate w.r.t. NED
    rate_rad_s (n,3) in body axes, velocity vel_ned_m_s (n,3), geodetic lat_deg, lon_deg, alt_m (n,) on the
    spherical Earth (R0 = 6 378 137 m, height above it; simulation.track)."""

    t_s: np.ndarray
    q_wxyz: np.ndarray
    rate_rad_s: np.ndarray
    vel_ned_m_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray


def _wxyz(q_xyzw: np.ndarray) -> np.ndarray:
    q = np.column_stack([q_xyzw[:, 3], q_xyzw[:, :3]])
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


@dataclass(frozen=True, eq=False)
class SensorBlock:
    """n consecutive samples. Sensor outputs are in the sensor (= body, FRD) frame, with errors, not quantised.

    t_s (n,) s; gyro_rad_s, accel_m_s2 (specific force: +g on the up axis at rest), mag_ut (n,3);
    temp_c (n,) °C; truth_q_wxyz (n,4) body→NED, scalar first, w ≥ 0; truth_gyro_rad_s (n,3) body rate w.r.t.
    NED in body axes; truth_mag_ut (n,3) Earth field in body axes, without vehicle iron or disturbances.
    Extra truth: truth_accel_m_s2 (n,3) specific force without errors; truth_disturbance_ut (n,3) local
    disturbance field in body axes (zero when none); truth_gyro_bias_rad_s, truth_accel_bias_m_s2 (n,3) total
    bias in force at each sample (turn-on + Gauss–Markov + temperature). Where the vehicle is: truth_vel_ned_m_s
    (n,3) m/s; truth_lat_deg, truth_lon_deg, truth_alt_m (n,) geodetic on the simulator's spherical Earth, from the
    site at t = 0 (a vehicle that stays put is at the site).
    """

    t_s: np.ndarray
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    mag_ut: np.ndarray
    temp_c: np.ndarray
    truth_q_wxyz: np.ndarray
    truth_gyro_rad_s: np.ndarray
    truth_mag_ut: np.ndarray
    truth_accel_m_s2: np.ndarray
    truth_disturbance_ut: np.ndarray
    truth_gyro_bias_rad_s: np.ndarray
    truth_accel_bias_m_s2: np.ndarray
    truth_vel_ned_m_s: np.ndarray
    truth_lat_deg: np.ndarray
    truth_lon_deg: np.ndarray
    truth_alt_m: np.ndarray

    def truth(self) -> Truth:
        """The truth fields as a `Truth` (for the GNSS model)."""
        return Truth(self.t_s, self.truth_q_wxyz, self.truth_gyro_rad_s, self.truth_vel_ned_m_s,
                     self.truth_lat_deg, self.truth_lon_deg, self.truth_alt_m)

    def __len__(self) -> int:
        return len(self.t_s)

    def samples(self, first_counter: int = 0):
        """The sensor outputs as `ImuSample`s (SI, body frame, flags NEW_DATA), one per row: for feeding
        calibration or an estimator directly, without the byte-level chip."""
        from ahrsd.core.sample import ImuSample, SampleFlags

        # make_sample's coercions once for the block: each row of a float64 (n, 3) array is what make_sample
        # would have passed on as it is, and tolist() gives the floats float() would
        gyro, accel, mag = (np.asarray(v, dtype=np.float64).reshape(-1, 3)
                            for v in (self.gyro_rad_s, self.accel_m_s2, self.mag_ut))
        new_data = SampleFlags.NEW_DATA
        for t_s, g, a, m, temp_c, counter in zip(np.asarray(self.t_s, dtype=np.float64).tolist(), gyro, accel, mag,
                                                   np.asarray(self.temp_c, dtype=np.float64).tolist(),
                                                   range(first_counter, first_counter + len(self.t_s))):
            yield ImuSample(t_s, g, a, m, temp_c=temp_c, flags=new_data, counter=counter)

    @staticmethod
    def concatenate(blocks) -> "SensorBlock":
        blocks = list(blocks)
        return SensorBlock(**{f.name: np.concatenate([getattr(b, f.name) for b in blocks])
                              for f in dataclasses.fields(SensorBlock)})


def _resolve_errors(errors, seed) -> SensorErrors:
    if isinstance(errors, SensorErrors):
        return errors
    if errors == "adis16405":
        return SensorErrors.adis16405(seed)
    if errors == "ideal":
        return SensorErrors.ideal()
    raise ValueError(f"errors must be 'adis16405', 'ideal' or a SensorErrors, got {errors!r}")


class SensorStream:
    """An endless stream of samples at `rate_hz` from one scenario. Stateful: call `next_block(n)` repeatedly.

    `errors` is the SensorErrors in force, vehicle iron included (its hard_iron_ut/soft_iron are what a perfect
    magnetometer calibration must find). `scenario` is the Scenario object (its parameters, helpers like
    `leg_of`), `site` the Site, `earth_field` the WMM2025 field there, `earth_rate` whether the Earth rotates.
    `field_anomaly_ned_ut` (None: none) is added to WMM's field to make the true field the magnetometer senses;
    `earth_field` stays WMM's, what an estimator is told (it does not know the anomaly).
    """

    CHUNK = 256  # samples generated at a time for small requests (0.31 s at 819.2 Hz)

    def __init__(self, scenario: Scenario, rate_hz: float, seed: int, errors: SensorErrors, site: Site,
                 start_s: float, vehicle_iron: VehicleIron | None, earth_rate: bool,
                 field_anomaly_ned_ut=None):
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be positive, got {rate_hz!r}")
        self.scenario = scenario
        self.rate_hz = float(rate_hz)
        self.seed = int(seed)
        self.site = site
        self.start_s = float(start_s)
        self.vehicle_iron = vehicle_iron
        self.sensor_errors = errors
        self.errors = errors.with_vehicle_iron(vehicle_iron) if vehicle_iron is not None else errors
        self.earth_field = site.earth_field()
        self.field_anomaly_ned_ut = _anomaly_ned_ut(field_anomaly_ned_ut)
        # The true field: WMM's plus the local departure from it (map error, a local anomaly; fixed to north). No
        # anomaly: WMM's vector itself, so that today's streams stay bit for bit.
        self._field_ned = (self.earth_field.ned_ut if self.field_anomaly_ned_ut is None
                           else self.earth_field.ned_ut + self.field_anomaly_ned_ut)
        self._gravity_ned = site.gravity_ned_m_s2
        self.earth_rate = bool(earth_rate)
        self._track = GeodeticTrack(scenario.velocity_ned_m_s, site.lat_deg, site.lon_deg, site.alt_m)
        self._process = ErrorProcess(self.errors, self.rate_hz, self.seed)
        self._k = 0  # index of the next sample handed out
        self._k_gen = 0  # index of the next sample to generate
        self._buffer: SensorBlock | None = None
        self._buf_pos = 0

    @property
    def samples_emitted(self) -> int:
        return self._k

    def next_block(self, n: int) -> SensorBlock:
        """The next `n` samples (n ≥ 1).

        Samples are generated in chunks of at least CHUNK and served from a buffer, so small requests (one
        sample per simulated SPI burst) cost a slice, not a full evaluation; the values do not depend on how
        the stream is cut into blocks.
        """
        n = int(n)
        if n < 1:
            raise ValueError(f"n must be ≥ 1, got {n}")
        buf = self._buffer
        if buf is None and n >= self.CHUNK:
            out = self._generate(self._k, n)
        else:
            parts = []
            need = n
            while need:
                if buf is None:
                    buf, self._buf_pos = self._generate(self._k_gen, max(self.CHUNK, need)), 0
                take = min(need, len(buf) - self._buf_pos)
                parts.append(_slice(buf, self._buf_pos, self._buf_pos + take))
                self._buf_pos += take
                need -= take
                if self._buf_pos == len(buf):
                    buf = None
            self._buffer = buf
            out = parts[0] if len(parts) == 1 else SensorBlock.concatenate(parts)
        self._k += n
        return out

    def _generate(self, k0: int, n: int) -> SensorBlock:
        """Samples k0 … k0+n−1; advances the random processes (call in sample order only)."""
        self._k_gen = k0 + n
        t = self.start_s + (k0 + np.arange(n)) / self.rate_hz
        sc = self.scenario
        q_xyzw, omega = sc.attitude_and_rate(t)
        v = sc.velocity_ned_m_s(t)
        lat_deg, lon_deg, alt_m = self._position_deg(t)
        if self.earth_rate:
            # Rotating Earth, the local-navigation-frame equations (Groves 2nd ed. §5.4) at the vehicle's position: the
            # gyros sense the body rate w.r.t. NED plus C_n^b (ω_ie + ω_en), and the specific force is
            # f^n = V̇ + (2 ω_ie + ω_en) × V − g(L, h) (the velocity equation solved for f).
            w_ie = earth_rate_ned_rad_s(lat_deg)
            w_en = transport_rate_ned_rad_s(v, lat_deg, alt_m)
            f_ned = sc.accel_ned_m_s2(t) + np.cross(2.0 * w_ie + w_en, v)
            f_ned[:, 2] -= normal_gravity_m_s2(lat_deg, alt_m)
            gyro_sensed = omega + ned_to_body(q_xyzw, w_ie + w_en)
        else:
            # Flat, non-rotating Earth with the site's gravity throughout.
            f_ned = sc.accel_ned_m_s2(t) - self._gravity_ned
            gyro_sensed = omega
        accel_true = ned_to_body(q_xyzw, f_ned)
        mag_earth = ned_to_body(q_xyzw, self._field_ned)
        dist_ned = sc.disturbance_ned_ut(t)
        dist = ned_to_body(q_xyzw, dist_ned) if dist_ned is not None else np.zeros((n, 3))
        gyro, accel, mag, temp, gbias, abias = self._process.apply(t, gyro_sensed, accel_true, mag_earth + dist)
        return SensorBlock(t, gyro, accel, mag, temp, _wxyz(q_xyzw), omega, mag_earth, accel_true, dist, gbias, abias,
                           v, lat_deg, lon_deg, alt_m)

    def _position_deg(self, t):
        return self._track.position(t)

    def truth_at(self, t_s) -> Truth:
        """The exact truth at any times t_s ≥ 0 (not only at sample instants); no effect on the stream."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        sc = self.scenario
        lat_deg, lon_deg, alt_m = self._position_deg(t)
        q_xyzw, omega = sc.attitude_and_rate(t)
        return Truth(t, _wxyz(q_xyzw), omega, sc.velocity_ned_m_s(t), lat_deg, lon_deg, alt_m)


def _slice(block: SensorBlock, a: int, b: int) -> SensorBlock:
    if a == 0 and b == len(block):
        return block
    return SensorBlock(*(getattr(block, f.name)[a:b] for f in dataclasses.fields(SensorBlock)))


def _anomaly_ned_ut(field_anomaly_ned_ut):
    if field_anomaly_ned_ut is None:
        return None
    v = np.array(field_anomaly_ned_ut, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"field_anomaly_ned_ut must be 3 finite NED components (µT), got {field_anomaly_ned_ut!r}")
    return v


def _resolve_scenario(scenario, site: Site) -> Scenario:
    sc = make_scenario(scenario) if isinstance(scenario, str) else scenario
    if not isinstance(sc, Scenario):
        raise TypeError(f"scenario must be a name or a Scenario, got {type(scenario).__name__}")
    return sc.with_gravity(site.gravity_m_s2)   # a coordinated turn banks for the local gravity: no lateral force


def open_stream(scenario: str | Scenario, rate_hz: float = 819.2, seed: int = 0,
                errors: str | SensorErrors = "adis16405", site: Site = DEFAULT_SITE, start_s: float = 0.0,
                *, vehicle_iron: VehicleIron | str | None = "scenario", earth_rate: bool | None = None,
                field_anomaly_ned_ut=None) -> SensorStream:
    """An endless simulated sensor stream.

    scenario: a name from SCENARIOS or a Scenario instance (e.g. make_scenario("auv-out-and-back", leg_s=120)).
    errors: "adis16405" (datasheet noise, turn-on errors drawn from `seed`), "ideal", or a SensorErrors.
    vehicle_iron: "scenario" (the scenario's default: level-turns, tumble, auv-out-and-back carry
      VehicleIron.default(), the others none), None for no vehicle iron, or a VehicleIron.
    earth_rate: True for a rotating Earth (Groves 2nd ed. §5.4, evaluated at the vehicle's position): the gyros
      also sense the Earth rate (15 °/h) and the transport rate, the specific force includes the Coriolis and
      transport terms and gravity is g(L, h) along the track, so the NED mechanisation
      (`simulation.strapdown`) reproduces the trajectory. False for a flat, non-rotating Earth with the site's
      gravity throughout (the Earth rate is below the ADIS16405's bias stability).
      None (default):
      the scenario's choice, `Scenario.rotating_earth` (True for boat, car and plane, False for the others).
      The truth rate is always relative to NED; the magnetic field is the site's throughout (tracks of a few km).
    field_anomaly_ned_ut: None (default: the true field is WMM2025's exactly) or a constant NED vector (µT) added
      to WMM's field: the local field's departure from the model (WMM's declination error is ~0.3-0.5° 1σ, NOAA's
      WMM error model; local anomalies add more). The stream's `earth_field` stays WMM's (what an estimator uses).
    """
    site = site if site is not None else DEFAULT_SITE
    sc = _resolve_scenario(scenario, site)
    if isinstance(vehicle_iron, str):
        if vehicle_iron != "scenario":
            raise ValueError(f"vehicle_iron must be 'scenario', None or a VehicleIron, got {vehicle_iron!r}")
        vehicle_iron = sc.default_iron
    if earth_rate is None:
        earth_rate = sc.rotating_earth
    return SensorStream(sc, rate_hz, seed, _resolve_errors(errors, seed), site, start_s, vehicle_iron, earth_rate,
                        field_anomaly_ned_ut)


def simulate(scenario: str | Scenario, seconds: float, rate_hz: float = 819.2, seed: int = 0,
             errors: str | SensorErrors = "adis16405", site: Site = DEFAULT_SITE, start_s: float = 0.0,
             **kwargs) -> SensorBlock:
    """`seconds` of a scenario as one SensorBlock (round(seconds · rate_hz) samples); kwargs as open_stream."""
    n = int(round(seconds * rate_hz))
    return open_stream(scenario, rate_hz, seed, errors, site, start_s, **kwargs).next_block(n)

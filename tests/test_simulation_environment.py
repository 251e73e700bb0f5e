"""Site, gravity (1980 International Gravity Formula) and the WMM field the simulator uses."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from ahrsd.simulation import DEFAULT_SITE, SCENARIOS, Site, simulate
from ahrsd.core.gravity import normal_gravity_m_s2
from support.gravity_worked_values import GRAVITY_WORKED_VALUES


@pytest.mark.parametrize("lat, g0, g1000", GRAVITY_WORKED_VALUES)
def test_normal_gravity_matches_the_worked_values(lat, g0, g1000):
    assert normal_gravity_m_s2(lat, 0.0) == pytest.approx(g0, abs=1.5e-6)
    assert normal_gravity_m_s2(lat, 1000.0) == pytest.approx(g1000, abs=1.5e-6)


def test_gravity_is_vectorised_and_symmetric_in_latitude():
    g = normal_gravity_m_s2(np.array([-45.0, 45.0]), np.array([0.0, 0.0]))
    assert g.shape == (2,) and g[0] == pytest.approx(g[1])


def test_default_site_is_documented_and_inside_wmm2025():
    assert DEFAULT_SITE == Site(36.42, 54.98, 1345.0, dt.date(2026, 1, 1))
    f = DEFAULT_SITE.earth_field()
    assert 45 < f.total_ut < 55 and 50 < np.degrees(f.inclination_rad) < 60


def wmm2025_ned_ut(site: Site) -> np.ndarray:
    """The WMM2025 main field straight from pygeomag (its own coefficient file, km, decimal year), in µT."""
    from pygeomag import GeoMag

    start = dt.date(site.date.year, 1, 1)
    year = site.date.year + (site.date - start).days / (dt.date(site.date.year + 1, 1, 1) - start).days
    r = GeoMag(coefficients_file="wmm/WMM_2025.COF").calculate(glat=site.lat_deg, glon=site.lon_deg,
                                                               alt=site.alt_m / 1000.0, time=year)
    return np.array([r.x, r.y, r.z]) / 1000.0


@pytest.mark.parametrize("name", SCENARIOS)
def test_truth_field_magnitude_equals_wmm_total(name):
    b = simulate(name, 2.0, rate_hz=50.0, errors="ideal")
    total = np.linalg.norm(wmm2025_ned_ut(DEFAULT_SITE))
    np.testing.assert_allclose(np.linalg.norm(b.truth_mag_ut, axis=1), total, rtol=1e-6)


def test_truth_field_rotated_to_ned_is_the_wmm_vector_and_other_sites_differ():
    from scipy.spatial.transform import Rotation

    site = Site(-33.9, 18.4, 0.0, dt.date(2027, 6, 1))   # Cape Town: southern hemisphere, field points up
    b = simulate("tumble", 2.0, rate_hz=20.0, errors="ideal", site=site, vehicle_iron=None)
    q = b.truth_q_wxyz
    ned = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, 0]])).apply(b.truth_mag_ut)
    np.testing.assert_allclose(ned, np.tile(wmm2025_ned_ut(site), (len(b), 1)), atol=1e-3)
    assert wmm2025_ned_ut(site)[2] < 0
    np.testing.assert_allclose(np.linalg.norm(b.accel_m_s2, axis=1), normal_gravity_m_s2(-33.9, 0.0))
    # ideal sensor without iron on the tumble: mag output equals the truth field
    np.testing.assert_allclose(b.mag_ut, b.truth_mag_ut, atol=1e-12)

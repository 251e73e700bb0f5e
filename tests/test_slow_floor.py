"""The learned magnetometer's floor over the trust window (estimator/slow_floor.py, docs/gnss.md "(pa96)"): the share
of a first-order Gauss–Markov error's variance left in its mean over a window, against the double integral of its
autocorrelation done by scipy (independent of the closed form under test), and the floor at Punta Arenas with worked
numbers."""

from __future__ import annotations

import math

import pytest
from scipy.integrate import quad

from ahrsd.estimator.ins import InsParams
from ahrsd.estimator.slow_floor import slow_floor_var_rad2, time_average_share

DEG = math.pi / 180.0
H_PUNTA_ARENAS_UT = 19.61       # WMM horizontal field at −53.16, −70.91 (docs/gnss.md "boat39")


def _share_by_integral(corr_s: float, window_s: float) -> float:
    """(1/T²)∫₀ᵀ∫₀ᵀ e^(−|t−s|/τ) ds dt = (2/T²)∫₀ᵀ (T − u) e^(−u/τ) du: the variance of the mean of a unit-variance
    error, its autocorrelation integrated numerically."""
    value, _ = quad(lambda u: (window_s - u) * math.exp(-u / corr_s), 0.0, window_s, epsabs=1e-12, epsrel=1e-12)
    return 2.0 * value / window_s ** 2


@pytest.mark.parametrize("corr_s, window_s", [(5.0, 20.0), (5.0, 1.0), (3.0, 100.0), (5.0, 5.0)])
def test_the_share_is_the_variance_of_the_errors_mean_over_the_window(corr_s, window_s):
    assert time_average_share(corr_s, window_s) == pytest.approx(_share_by_integral(corr_s, window_s), rel=1e-6)


def test_nothing_averages_without_a_window_or_a_correlation_time():
    assert time_average_share(5.0, 0.0) == 1.0
    assert time_average_share(0.0, 20.0) == 1.0
    assert time_average_share(math.inf, 20.0) == 1.0
    assert time_average_share(5.0, 1e-4) == pytest.approx(1.0, abs=1e-4)


def test_punta_arenas_floor_over_the_reentry_window():
    # the defaults: 1 µT unmodelled, correlated over iron_tau_s 5 s, judged over the monitor's reentry_s 20 s
    p = InsParams()
    assert (p.iron_unmodelled_ut, p.iron_tau_s) == (1.0, 5.0)
    floor_deg = 1.0 / H_PUNTA_ARENAS_UT / DEG                        # 2.922°
    share = 2.0 * (4.0 - 1.0 + math.exp(-4.0)) / 16.0                  # T/τ = 4: 0.3773
    slow = slow_floor_var_rad2(p, H_PUNTA_ARENAS_UT ** 2, 20.0)
    assert floor_deg == pytest.approx(2.922, abs=1e-3)
    assert math.sqrt(slow) / DEG == pytest.approx(floor_deg * math.sqrt(share), rel=1e-9)
    assert math.sqrt(slow) / DEG == pytest.approx(1.795, abs=1e-3)
    # the room it leaves the learned iron under the 3° trust limit: 2.40°, not boat39's 0.69°
    assert math.sqrt(9.0 - (math.sqrt(slow) / DEG) ** 2) == pytest.approx(2.404, abs=1e-3)


def test_a_calibrations_own_figure_is_not_averaged():
    # a calibration that states 1°: its figure is the floor (smaller than 2.92°), and nothing says it changes as the
    # vehicle moves; one that states 2°: the averaged 1.795° is the smaller
    h2 = H_PUNTA_ARENAS_UT ** 2
    assert slow_floor_var_rad2(InsParams(mag_calibration_sigma_rad=1.0 * DEG), h2, 20.0) == pytest.approx((1.0 * DEG) ** 2)
    assert math.sqrt(slow_floor_var_rad2(InsParams(mag_calibration_sigma_rad=2.0 * DEG), h2, 20.0)) / DEG \
        == pytest.approx(1.795, abs=1e-3)

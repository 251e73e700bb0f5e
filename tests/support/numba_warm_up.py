"""Compile the numba kernels the test suite calls into numba's on-disk cache once, before pytest-xdist starts its
workers (tests/conftest.py, `pytest_configure` in the controller).

Why: a fresh checkout (CI's) has no cache, and numba compiles a kernel on its first call in each process that
does not find it cached. Every xdist worker, and every daemon subprocess a test starts meanwhile, would then
compile the same mekf and ins kernels at the same time on the machine's two cores. Compiled once here, the
workers load them from the cache.

`python numba_warm_up.py GROUP` compiles one group (mekf, ins); the conftest runs the groups in parallel. Each
step goes through the public entry points with the types the code passes, so the cache entries are the ones
the suite loads. A step that fails is reported and skipped: the warm-up only saves time, the tests compile
whatever is missing themselves.
"""

from __future__ import annotations

import sys
import time

import numpy as np

GROUPS = ("mekf", "ins")


def _mekf_steps():
    from ahrsd.estimator.mekf import Mekf
    from ahrsd.estimator.warm_up import warm_up

    yield "mekf step", lambda: warm_up("mekf")

    def batch():
        n = 200
        t = np.arange(n) / 100.0
        Mekf().run_batch(t, np.zeros((n, 3)), np.tile([0.0, 0.0, -9.81], (n, 1)), np.tile([20.0, 0.0, 45.0], (n, 1)))
    yield "mekf batch", batch

    def allan():
        from ahrsd.calibration.allan.analysis import analyse_static

        rng = np.random.default_rng(0)
        n = 20000
        analyse_static(np.arange(n) / 100.0, gyro_rad_s=rng.normal(0.0, 1e-3, (n, 3)))
    yield "allan fit", allan


def _ins_steps():
    from ahrsd.estimator.warm_up import warm_up

    yield "ins step", lambda: warm_up("ins")

    def smoother():
        from ahrsd.core.gnss import GnssFix
        from ahrsd.core.sample import make_sample
        from ahrsd.estimator.ins_smoother import SmoothingIns

        est = SmoothingIns()
        for i in range(300):
            t_s = i / 100.0
            est.update(make_sample(t_s, np.zeros(3), np.array([0.0, 0.0, -9.81]), np.array([20.0, 0.0, 45.0])))
            if i % 20 == 10:
                est.update_gnss(GnssFix(t_s=t_s - 0.1, lat_deg=52.0, lon_deg=4.0, alt_m=0.0,
                                        vel_ned_m_s=np.zeros(3), h_acc_m=2.5, v_acc_m=5.0, s_acc_m_s=0.1))
        est.smoothed_roll_pitch()
    yield "ins smoother", smoother


def run(group: str) -> int:
    steps = {"mekf": _mekf_steps, "ins": _ins_steps}[group]
    for name, step in steps():
        started = time.monotonic()
        try:
            step()
        except Exception as exc:  # noqa: BLE001 - a warm-up that fails only costs the time it would have saved
            print(f"numba warm-up: {name} skipped: {type(exc).__name__}: {exc}", file=sys.stderr)
            continue
        print(f"numba warm-up: {name} {time.monotonic() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(run(sys.argv[1]))

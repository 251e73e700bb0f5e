"""Allan white noise of the simulated ADIS16405 at each SENS_AVG filter setting, against the simulator's configured
density: `ahrsd record --sim static --filter-taps N` (819.2 SPS through the SPI byte level, the chip's Bartlett window
of two 2^N-tap averages and its 14-bit output), then the analysis `ahrsd calibrate allan` runs on the recording.

    .venv/bin/python bench/allan_filters.py                    # N = 0…7, 300 s each (about 35 s per setting)
    .venv/bin/python bench/allan_filters.py --taps 5 7 --seconds 120

Per sensor and axis: the white noise read against the configured density (± its reported 1σ), the other terms
reported, and the filtered noise per sample in LSB (the configured noise σ·√(Σh²) over the output's step): below
about half an LSB the 14-bit output holds a handful of values, and the analysis says "below LSB" instead
(calibration/allan/resolution.py). The chip's "stuck axis" warnings of those settings are not shown.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ahrsd.calibration.allan.analysis import analyse_static
from ahrsd.cli.main import main as cli_main
from ahrsd.drivers import registers as R
from ahrsd.drivers.recording import read_recording
from ahrsd.simulation.errors import SensorErrors


def run(filter_n: int, seconds: float, workdir: Path) -> None:
    path = workdir / f"static_n{filter_n}.csv"
    t0 = time.perf_counter()
    status = cli_main(["record", "--sim", "static", "--seconds", str(seconds), "--filter-taps", str(filter_n),
                       "--output", str(path), "--quiet"])
    if status != 0:
        raise SystemExit(f"record failed with status {status}")
    rec = read_recording(path)
    t1 = time.perf_counter()
    res = analyse_static(rec.t_s, rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut)
    t2 = time.perf_counter()
    errors = SensorErrors.adis16405(0)
    configured = {"gyro": errors.gyro_noise_density_rad_s_rthz, "accel": errors.accel_noise_density_m_s2_rthz,
                  "mag": errors.mag_noise_density_ut_rthz}
    data = {"gyro": rec.gyro_rad_s, "accel": rec.accel_m_s2, "mag": rec.mag_ut}
    gain = float(np.sqrt(np.sum(R.bartlett_taps(filter_n) ** 2)))
    print(f"N = {filter_n} ({len(R.bartlett_taps(filter_n))}-tap window), {seconds:g} s: record {t1 - t0:.0f} s, "
          f"analysis {t2 - t1:.1f} s")
    for sensor, axes in res.parameters.items():
        steps = np.abs(np.diff(data[sensor][:, 0]))
        lsb = float(np.min(steps[steps > 0]))
        noise_lsb = configured[sensor] * np.sqrt(rec.sample_rate_hz) * gain / lsb
        cells = []
        for axis, p in axes.items():
            white = p.terms.get("white")
            text = ("white not read" if white is None else
                    f"{white.value / configured[sensor] - 1:+.1%} ± {white.uncertainty / configured[sensor]:.1%}")
            others = sorted(set(p.terms) - {"white"})
            if p.too_short_need_s is not None:
                text = "too short"
            if p.noise_lsb is not None:
                text = f"below LSB ({p.noise_lsb:.2f} LSB: no term read)"
            cells.append(f"{axis} {text}" + (f" (+{', '.join(others)})" if others else ""))
        print(f"  {sensor:<5} noise {noise_lsb:.2f} LSB: " + "; ".join(cells))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--taps", type=int, nargs="+", default=list(range(8)), help="SENS_AVG settings N (0…7)")
    ap.add_argument("--seconds", type=float, default=300.0)
    args = ap.parse_args()
    logging.disable(logging.WARNING)     # the driver's "axis stuck" warnings: a long window's few output values
    with tempfile.TemporaryDirectory(prefix="allan_filters_") as tmp:
        for n in args.taps:
            run(n, args.seconds, Path(tmp))
            sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The simulated IIO device's test rig (tests/test_iio_source.py, test_iio_rate.py): `ahrsd run --iio` started on
it as a subprocess, waiting for the simulated kernel's records, and reading an `IioSource` until it gave enough."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path


def start_iio_daemon(tmp_path, device, *flags: str) -> tuple[subprocess.Popen, Path]:
    """`ahrsd run --iio` on the simulated device (output piped, MAVLink to a discard port); (process, stats file)."""
    stats = tmp_path / "stats.json"
    proc = subprocess.Popen([sys.executable, "-m", "ahrsd.cli", "run", "--iio", str(device.sysfs), *flags,
                             "--state-dir", str(tmp_path / "state"), "--no-log",
                             "--mavlink", "udpout:127.0.0.1:9", "--stats-file", str(stats)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return proc, stats


def wait_for_records(device, proc, count: int, t_end: float) -> None:
    """Until the simulated kernel has written `count` records (or the daemon ended, or t_end)."""
    while device.stats["records"] < count and time.monotonic() < t_end and proc.poll() is None:
        time.sleep(0.1)


def take_samples(src, want: int, t_end: float, got: list, errors: list) -> None:
    """Poll `src` into `got` until it holds `want` samples or t_end; what a poll raised goes to `errors` (the test
    looks at what the daemon would be told)."""
    while len(got) < want and time.monotonic() < t_end:
        try:
            got += src.poll()
        except Exception as exc:  # noqa: BLE001 - the test looks at what the daemon would be told
            errors.append(exc)
        time.sleep(0.02)

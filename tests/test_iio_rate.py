"""`[sensor] rate_hz` with the kernel's IIO driver: the daemon writes the driver's `sampling_frequency`, reads it
back and runs at what it reads; the simulated IIO device applies the write as adis16400_set_freq does.

The numbers are worked by hand from the driver (drivers/iio/imu/adis16400.c, integer arithmetic in milli-SPS):
* write "204.800000": the IIO core parses 204 + 800000 µ, write_raw takes 204 × 1000 + 800000 / 1000 = 204800;
  set_freq: t = 1638404 / 204800 = 8 (8.0000195), below 128, so SMPL_PRD = t − 1 = 7; get_freq: 1638404 / 8 =
  204800 (204800.5) → "204.800000".
* 102.4: 1638404 / 102400 = 16 → SMPL_PRD 15 = 0x0F; 1638404 / 16 = 102400 (102400.25) → "102.400000".
* 12.8 (the spidev rule's SMPL_PRD 0x7F, 1638404 / 128 = 12800 mSPS written): t = 1638404 / 12800 = 128 (128.0003),
  not below 128: the slow time base, bit 7, with t = 52851 / 12800 = 4 (4.13), not decremented: SMPL_PRD 0x84;
  get_freq: 52851 / 5 = 10570 (10570.2) → "10.570000", 10.57 SPS.
* 819.2 (SMPL_PRD 1): 1638404 / 2 = 819202 → "819.202000"; written back: 1638404 / 819202 = 2 → SMPL_PRD 1.
"""

from __future__ import annotations

import errno
import json
import logging
import re
import statistics
import time

import numpy as np
import pytest

from ahrsd.drivers import iio_source
from ahrsd.drivers.errors import BusError
from ahrsd.drivers.iio_source import (IioSource, driver_milli_sps, driver_smpl_prd, sysfs_rate_text,
                                      written_milli_sps)
from ahrsd.drivers.simulated_iio import SimulatedIioDevice
from support.iio_rig import start_iio_daemon, take_samples, wait_for_records


def test_the_drivers_integer_rules_give_the_worked_numbers():
    assert [written_milli_sps(t) for t in ("204.8", "204.800000\n", "12.8", "819.2020009", "10")] == \
        [204800, 204800, 12800, 819202, 10000]
    assert [driver_smpl_prd(m) for m in (204800, 102400, 12800, 819202, 10000)] == [0x07, 0x0F, 0x84, 0x01, 0x85]
    assert [driver_milli_sps(p) for p in (0x07, 0x0F, 0x84, 0x01)] == [204800, 102400, 10570, 819202]
    assert [sysfs_rate_text(m) for m in (204800, 10570, 819202)] == ["204.800000", "10.570000", "819.202000"]


@pytest.fixture(scope="module")
def device(tmp_path_factory):
    dev = SimulatedIioDevice(tmp_path_factory.mktemp("iio"), scenario="static", seed=3)
    yield dev
    dev.close()


def test_the_rate_is_written_read_back_and_set_on_the_chip(device, caplog):
    """204.8 first, with records: their kernel time stamps are 8 / 1638.404 s apart, none lost; then the slow
    rates (a write from a slow SMPL_PRD to a fast one runs at the fast clock: kept for last in no test)."""
    caplog.set_level(logging.INFO, logger="ahrsd.drivers.iio_source")
    src = IioSource(str(device.sysfs), rate_hz=204.8)
    src.start()
    assert (device.smpl_prd, src.sample_rate_hz) == (0x07, 204.8)
    got, t_end = [], time.monotonic() + 30.0
    while len(got) < 250 and time.monotonic() < t_end:
        got += src.poll()
        time.sleep(0.05)
    src.close()
    assert len(got) >= 250
    assert np.median(np.diff([s.t_s for s in got])) == pytest.approx(8 / 1638.404, rel=1e-4)
    assert src.counters()["lost_samples_host"] == 0
    for rate_hz, smpl_prd, text, sps in ((12.8, 0x84, "10.570000", 10.57), (102.4, 0x0F, "102.400000", 102.4)):
        src = IioSource(str(device.sysfs), rate_hz=rate_hz)
        src.start()
        assert (device.smpl_prd, src.sample_rate_hz) == (smpl_prd, sps), rate_hz
        assert (device.sysfs / "sampling_frequency").read_text() == text + "\n"
    assert "sampling_frequency asked 12.8 SPS (wrote 12.800000), the driver reads back 10.570000" in caplog.text


def test_the_rate_is_written_again_after_a_re_probe(tmp_path):
    """The device unbound and probed again (the probe resets the chip: SMPL_PRD back at 0x01): the source's
    re-open writes 102.4 again, and the records after it come 16 / 1638.404 s apart."""

    device = SimulatedIioDevice(tmp_path, scenario="static", seed=4)
    try:
        src = IioSource(str(device.sysfs), rate_hz=102.4)
        src.start()
        got, errors, t_end = [], [], time.monotonic() + 60.0
        take_samples(src, 50, t_end, got, errors)
        device.remove()
        while not errors and time.monotonic() < t_end:
            take_samples(src, len(got) + 1, min(t_end, time.monotonic() + 0.2), got, errors)
        device.recreate()
        assert device.smpl_prd == 0x01                     # the probe's reset, read over SPI
        after = len(got)
        take_samples(src, after + 100, t_end, got, errors)
        src.close()
    finally:
        device.close()
    assert src.counters()["reopens"] == 1 and device.smpl_prd == 0x0F
    assert np.median(np.diff([s.t_s for s in got[after:]])) == pytest.approx(16 / 1638.404, rel=1e-4)


def test_a_refused_write_is_a_clear_start_up_error(device, monkeypatch, capsys, tmp_path):
    """EACCES (the unit's group lacks the file) through `ahrsd run`: one line naming the file and the fix, exit
    1; EINVAL (the driver refuses the value) the same BusError from the source."""
    from ahrsd.cli.main import main

    write = iio_source._write

    def refuse(err):
        def _write(path, value):
            if path.name == "sampling_frequency":
                raise OSError(err, "refused")
            write(path, value)
        return _write

    monkeypatch.setattr(iio_source, "_write", refuse(errno.EACCES))
    code = main(["run", "--iio", str(device.sysfs), "--rate-hz", "204.8", "--state-dir", str(tmp_path / "state"),
                 "--no-log", "--status-line", "off"])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err, err
    assert f"{device.sysfs}/sampling_frequency" in err and "Permission denied" in err
    assert "99-ahrsd-iio.rules" in err and "ahrsd-iio.conf" in err
    monkeypatch.setattr(iio_source, "_write", refuse(errno.EINVAL))
    with pytest.raises(BusError, match=r"writing 102\.400000 to .*sampling_frequency failed \(Invalid argument\)"):
        IioSource(str(device.sysfs), rate_hz=102.4).start()


def test_an_empty_read_back_runs_at_the_drivers_rule_for_the_value_written(tmp_path, caplog):
    """Kernels since 5.5 read sampling_frequency as an empty line (drivers.iio_source's module doc): the rate is
    set_freq's for the value written — and without rate_hz the chip's default is written, so that it is known."""
    device = SimulatedIioDevice(tmp_path, scenario="static", seed=3, rate_reads_empty=True)
    try:
        assert (device.sysfs / "sampling_frequency").read_text() == "\n"
        src = IioSource(str(device.sysfs), rate_hz=12.8)
        src.start()
        assert (device.smpl_prd, src.sample_rate_hz) == (0x84, 10.57)
        src = IioSource(str(device.sysfs))
        src.start()
        assert (device.smpl_prd, src.sample_rate_hz) == (0x01, 819.202)
    finally:
        device.close()
    assert "reads empty" in caplog.text and "wrote 819.202000" in caplog.text


def test_the_daemon_runs_the_simulated_iio_device_at_the_rate_it_wrote(tmp_path):
    """`ahrsd run --iio … --rate-hz 204.8`: the status line's measured rate is 204.8 SPS (the driver's default
    would show 819.2), and no sample is lost; then a 0.25 s interrupt outage and the "kernel" gone: every record
    it wrote reached the daemon, and the daemon's count of lost samples is exactly the chip samples no record
    carried (the simulated kernel's own count). One daemon for both checks (tests/test_iio_source.py's module
    doc): the outage's accounting does not depend on the rate."""

    device = SimulatedIioDevice(tmp_path / "iio", scenario="static", seed=5)
    proc, stats = start_iio_daemon(tmp_path, device, "--rate-hz", "204.8", "--status-line", "on")
    try:
        t_end = time.monotonic() + 120.0
        wait_for_records(device, proc, 100, t_end)
        time.sleep(6.5)                                      # 1330 samples at 204.8 SPS, status lines each second
        lost_before_outage = device.lost_truth()
        device.stall(0.25)
        wait_for_records(device, proc, device.stats["records"] + 200, t_end)
        device.close()                                       # the "kernel" stops; the daemon drains the rest
        time.sleep(1.0)
    finally:
        proc.send_signal(2)
        out, _ = proc.communicate(timeout=30)
        device.close()
    assert proc.returncode in (0, 130), out[-2000:]
    rates = [float(x) for x in re.findall(r"(\d+\.\d) SPS", out)]
    assert len(rates) >= 4, out[-2000:]
    # the status lines of the outage's second and of the drain read low: the steady seconds before them are most
    assert statistics.median(rates) == pytest.approx(204.8, rel=0.05), rates
    assert device.smpl_prd == 0x07 and "reads back 204.800000" in out
    assert "through the kernel's IIO driver" in out
    st = json.loads(stats.read_text())
    assert lost_before_outage == 0
    assert st["source"]["records"] == device.stats["records"] >= 1200 and device.stats["overflow_dropped"] == 0
    assert st["pipeline"]["samples"] == device.stats["records"] - st["source"]["stale"]
    truth = device.lost_truth()
    assert truth >= 0.25 * 204.8 * 0.9
    assert st["pipeline"]["lost_samples"] == st["source"]["lost_samples_host"] == truth, (st, truth)

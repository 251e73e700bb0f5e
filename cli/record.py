"""`ahrsd record`: record raw ADIS16405 samples (real over SPI, or the simulated chip) to a CSV recording."""

from __future__ import annotations

import argparse


SIM_SEED = 0
SIM_ERRORS = "adis16405"
SIM_ONLY_OPTIONS = ("seed", "errors", "realtime", "site", "iron")   # options of the simulated chip, refused with --spi


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows "(default: X)" only for options that have a value by default (not "None"/"False" noise)."""

    def _get_help_string(self, action):
        if action.default is None or action.default is False or "default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


def register(subparsers) -> None:
    from ahrsd.simulation.place_options import SITE_FORMAT, VEHICLE_IRONS, site_arg

    p = subparsers.add_parser(
        "record",
        help="record raw IMU samples to a CSV file (simulated chip or a real ADIS16405 on SPI)",
        description="Read the ADIS16405 through the driver and write every fresh sample to a CSV recording "
        "(header t_s,gyro_x_rad_s,...,mag_z_ut then temp_c,supply_v,flags,counter and, for --sim, the truth "
        "quaternion truth_qw..truth_qz). With a terminal, a one-line live status shows what is arriving. "
        "Whenever a GNSS source exists (the simulated receiver of a moving vehicle scenario: boat, car, plane; "
        "or --gnss-serial) its fixes go to REC.gnss.csv beside the recording, on the same time base "
        "(docs/gnss.md).",
        formatter_class=_HelpFormatter,
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--sim", metavar="SCENARIO", nargs="?", const="static",
                     help="simulated ADIS16405 driven by a simulation scenario (static, rate-table, level-turns, "
                     "coordinated-turn, tumble, auv-out-and-back, mag-disturbance, and the vehicles with a GNSS "
                     "receiver: boat, car, plane; --sim alone: static)")
    src.add_argument("--spi", metavar="DEV", help="real ADIS16405 on this spidev node, e.g. /dev/spidev0.0")
    p.add_argument("--output", "-o", required=True, metavar="FILE", help="CSV file to write")
    p.add_argument("--seconds", type=float, default=None,
                   help="how long to record (sample time); without it: until Ctrl-C, and --sim then runs in real time "
                   "(with it, --sim runs as fast as possible unless --realtime)")
    # --seed/--errors/--realtime default to None so that one given with --spi can be refused (see run)
    p.add_argument("--seed", type=int, default=None, help=f"simulation seed (--sim) (default: {SIM_SEED})")
    p.add_argument("--errors", default=None, choices=("adis16405", "ideal"),
                   help=f"simulated sensor errors (--sim) (default: {SIM_ERRORS})")
    p.add_argument("--site", type=site_arg, default=None, metavar=SITE_FORMAT,
                   help="with --sim: the place (degrees, metres above the ellipsoid, date for the field) of the "
                   "simulated chip's field and gravity and of the simulated GNSS receiver's track (default: the "
                   "simulator's site, python -m ahrsd.simulation; a negative latitude as --site=-45.87,170.50)")
    p.add_argument("--iron", choices=VEHICLE_IRONS, default=None,
                   help="with --sim: the simulated vehicle's iron instead of the scenario's own (default: the "
                   "scenario's; held-out and unseen: irons no default was chosen on, docs/simulation.md)")
    p.add_argument("--rate-hz", type=float, default=None,
                   help="output data rate; the nearest SMPL_PRD setting is used (chip default 819.2)")
    p.add_argument("--filter-taps", type=int, default=None, metavar="N", choices=range(8),
                   help="SENS_AVG Bartlett filter setting N (0..7: two 2^N-tap averages; chip default 2)")
    p.add_argument("--realtime", action="store_true", default=None,
                   help="with --sim: run the simulated chip on the wall clock (paced) instead of as fast as possible")
    p.add_argument("--no-self-test", action="store_true", help="skip the start-up self-test")
    p.add_argument("--gnss-serial", metavar="DEVICE[,BAUD]", default=None,
                   help="also record the GNSS receiver (UBX/NMEA) on this serial port (baud default 115200)")
    p.add_argument("--no-gnss", action="store_true", help="do not record the simulated vehicle's GNSS receiver")
    p.add_argument("--gnss-lever-arm-m", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="--sim: the simulated receiver's antenna relative to the IMU, body FRD, m (default 0 0 0; "
                   "give the same to replay/calibrate, or [gnss] lever_arm_m)")
    p.add_argument("--quiet", "-q", action="store_true", help="no live status line")
    p.set_defaults(func=run)


class RecordError(Exception):
    """A recording that cannot start: one line on stderr, and the exit status (1 failed, 2 bad usage)."""

    def __init__(self, message: str, status: int = 1):
        super().__init__(message)
        self.status = status


def run(args, open_bus=None) -> int:
    """open_bus(kind, **options): the chip's bus (default drivers.source.open_chip_bus; a test passes a faulty one)."""
    import sys

    from ahrsd.drivers.source import open_chip_bus

    try:
        return _record(args, open_bus or open_chip_bus)
    except RecordError as exc:
        print(f"ahrsd record: error: {exc}", file=sys.stderr)
        return exc.status


def _record(args, open_bus) -> int:
    """Check the options, open the chip and the files, record, and say what was written."""
    import signal
    import sys
    import time

    from ahrsd.drivers.source_recorder import SourceRecorder

    _check_options(args)
    simulated = args.sim is not None
    # a simulated run without an end is a live demo: pace it, or it would fill the disk as fast as the CPU goes
    paced = (not simulated) or args.realtime or args.seconds is None
    bus, source = _open_chip(args, paced, open_bus)
    imu = source.driver
    gnss, writer = _open_files(args, bus, source, paced)
    status = _LiveStatus.wanted(args, imu)
    recorder = SourceRecorder(source, writer, paced=paced,
                              truth_q_wxyz=(lambda: source.bus.burst_truth_q_wxyz) if simulated else None,
                              on_sample=lambda sample: _after_sample(recorder, sample, gnss, status))
    n_target = None if args.seconds is None else max(1, int(round(args.seconds * imu.sample_rate_hz)))

    def _stop(signum, frame):
        raise KeyboardInterrupt        # SIGTERM ends the recording like Ctrl-C: the file is flushed and closed

    previous_sigterm = signal.signal(signal.SIGTERM, _stop)
    try:
        if not recorder.run(n_target):
            print(f"\nahrsd record: error: {recorder.failure}", file=sys.stderr)
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous_sigterm)
        writer.close()
        imu.close()
        gnss_summary = gnss.close() if gnss is not None else ""
    status.end()
    _print_summary(args, recorder, source, time.monotonic() - status.wall0, gnss_summary)
    if simulated:
        import logging

        logging.getLogger("ahrsd.record").debug("simulated chip: %s", bus.stats)
    return 0 if recorder.failure is None else 1


def _check_options(args) -> None:
    """Refuse what cannot be recorded as asked (exit 2)."""
    import math

    if args.seconds is not None and not (math.isfinite(args.seconds) and args.seconds > 0):   # nan/inf: traceback
        raise RecordError("--seconds must be a positive, finite number of seconds", 2)
    sim_only = [f"--{name}" for name in SIM_ONLY_OPTIONS if getattr(args, name) is not None]
    if args.sim is None and sim_only:
        raise RecordError(f"{', '.join(sim_only)} only apply to the simulated chip (--sim), not to --spi", 2)
    if args.sim is not None:
        from ahrsd.simulation import SCENARIOS

        if args.sim not in SCENARIOS:
            raise RecordError(f"unknown scenario {args.sim!r}; choose one of: {', '.join(SCENARIOS)}", 2)


def _open_chip(args, paced: bool, open_chip_bus):
    """The chip's bus and its started source, read through drivers.source."""
    import time

    from ahrsd.drivers.errors import DriverError
    from ahrsd.drivers.ground_truth import BurstTruthTap
    from ahrsd.drivers.source import start_chip_source

    clock = time.monotonic if paced else None
    try:
        if args.sim is not None:
            from ahrsd.simulation.place_options import vehicle_iron

            iron = "scenario" if args.iron is None else vehicle_iron(args.iron)
            bus = open_chip_bus("sim", scenario=args.sim, seed=SIM_SEED if args.seed is None else args.seed,
                                errors=SIM_ERRORS if args.errors is None else args.errors, clock=clock,
                                site=args.site, vehicle_iron=iron)
        else:
            bus = open_chip_bus("spi", spi_device=args.spi)
        # a simulated chip is read through a tap that keeps the truth of the sample each burst returned
        read_bus = BurstTruthTap(bus) if args.sim is not None else bus
        # one timing path (drivers.sample_timer): the host clock, or the free-running chip's own
        source = start_chip_source(read_bus, "ADIS16405", clock=clock or bus.now, self_test=not args.no_self_test,
                                   sample_rate_hz=args.rate_hz, filter_n=args.filter_taps)
    except DriverError as exc:
        raise RecordError(str(exc)) from None
    return bus, source


def _open_files(args, bus, source, paced: bool):
    """The GNSS recorder (or None) and the IMU recording's writer. The GNSS source first: when it cannot start,
    the run ends before any file is created (a header-only recording would look like one that caught nothing)."""
    from ahrsd.drivers.errors import DriverError
    from ahrsd.drivers.recording import TRUTH_COLUMNS, RecordingWriter

    try:
        gnss = _open_gnss(args, bus, source, paced)
    except (OSError, ValueError, DriverError) as exc:
        source.driver.close()
        raise RecordError(f"GNSS: {exc}") from None
    extra = ("temp_c", "supply_v", "flags", "counter") + (TRUTH_COLUMNS if args.sim is not None else ())
    try:
        return gnss, RecordingWriter(args.output, extra_columns=extra)
    except OSError as exc:
        source.driver.close()
        if gnss is not None:
            gnss.close()
            gnss.path.unlink(missing_ok=True)     # its header only: nothing was recorded
        raise RecordError(f"cannot write {args.output}: {exc}") from None


def _after_sample(recorder, sample, gnss, status) -> None:
    import time

    now = time.monotonic()
    if gnss is not None:
        gnss.poll(sample.t_s, now)
    status.show(recorder.written, sample, now)


def _print_summary(args, recorder, source, elapsed_s: float, gnss_summary: str) -> None:
    """What was written, and what went wrong on the way, in words."""
    import logging
    import sys

    counters = source.counters()        # the driver's counters and the source's lost samples
    problems = problems_in_words(counters)
    print(f"ahrsd record: wrote {recorder.written} samples ({recorder.span_s:.2f} s of data at "
          f"{source.driver.sample_rate_hz:.1f} SPS) to {args.output} in {elapsed_s:.2f} s"
          + (f"; {', '.join(problems)}" if problems else ""), file=sys.stderr)
    if gnss_summary:
        print(f"ahrsd record: {gnss_summary}", file=sys.stderr)
    logging.getLogger("ahrsd.record").debug("counters: %s", counters)


# What the end-of-run line reports, in the driver's and the source's counter names (drivers/adis16405.py
# COUNTER_NAMES, drivers/chip_source.py), as the words a user reads. Reads that found no new sample yet
# ("stale") are how a paced reader meets the chip's data-ready, not a problem, and are not reported.
PROBLEMS = (
    (("lost_samples_host",), "{} samples lost (gaps in the recording)"),
    (("garbage_frames",), "{} corrupt frames rejected"),
    (("short_reads", "bus_errors"), "{} failed bus transfers"),
    (("ea_flags",), "{} samples with the chip's alarm flag set"),
    (("saturations",), "{} samples with an axis at full scale"),
    (("stuck_axis",), "{} axes seen stuck"),
    (("burst_bug_recovered",), "{} X-gyro burst errors corrected"),
    (("burst_bug_unverified",), "{} gyro samples marked invalid (burst error not confirmed)"),
    (("self_test_failures",), "{} failed self-test attempts"),
)


def problems_in_words(counters: dict) -> list[str]:
    """The counters a user acts on, as phrases ("3 corrupt frames rejected"); nothing for a clean run."""
    out = []
    for names, text in PROBLEMS:
        n = sum(int(counters.get(name, 0) or 0) for name in names)
        if n:
            out.append(text.format(n))
    return out


def _open_gnss(args, bus, source, paced: bool):
    """The GNSS recorder beside the IMU recording, or None (no GNSS source)."""
    from ahrsd.cli.gnss_record import GnssRecorder
    from ahrsd.drivers.gnss.recording import gnss_path_for

    path = gnss_path_for(args.output)
    if args.gnss_serial:
        device, _, baud = args.gnss_serial.partition(",")
        if baud and not baud.isdigit():
            raise ValueError(f"--gnss-serial {args.gnss_serial!r}: expected DEVICE or DEVICE,BAUD")
        if not paced:
            raise ValueError("--gnss-serial needs the IMU on the host clock: a real sensor, or --sim with --realtime")
        return GnssRecorder.for_serial(path, device, int(baud or 115200), source.clock)
    arm = (0.0, 0.0, 0.0)
    if args.gnss_lever_arm_m is not None:
        from ahrsd.daemon.config import checked_lever_arm_m

        if args.sim is None or args.no_gnss:
            raise ValueError("--gnss-lever-arm-m is the simulated receiver's: it goes with --sim (and GNSS)")
        try:
            arm = checked_lever_arm_m(args.gnss_lever_arm_m)
        except ValueError as exc:
            raise ValueError(f"--gnss-lever-arm-m {exc}") from None
    if args.sim is None or args.no_gnss:
        return None
    from ahrsd.simulation.vehicles import VEHICLES

    if args.sim not in VEHICLES:
        return None        # a scenario that does not move: no receiver to record
    seed = SIM_SEED if args.seed is None else args.seed
    return GnssRecorder.for_scenario(path, args.sim, seed, bus.now, source.clock, lever_arm_m=arm, site=args.site)


class _LiveStatus:
    """The one-line live status on a terminal (none with --quiet or in a pipe), four times a second."""

    PERIOD_S = 0.25

    def __init__(self, imu, out=None):
        import time

        self.imu = imu
        self.out = out
        self.wall0 = time.monotonic()
        self._next = self.wall0

    @classmethod
    def wanted(cls, args, imu) -> "_LiveStatus":
        import sys

        return cls(imu, None if args.quiet or not sys.stderr.isatty() else sys.stderr)

    def show(self, written: int, s, now: float) -> None:
        import math

        if self.out is None or now < self._next:
            return
        self._next = now + self.PERIOD_S
        counters = self.imu.counters
        g = [math.degrees(v) for v in s.gyro_rad_s]
        a, m = s.accel_m_s2, s.mag_ut
        rejected = counters["garbage_frames"] + counters["short_reads"] + counters["bus_errors"]
        elapsed = now - self.wall0
        line = (f"\r{written:8d} samples {written / max(elapsed, 1e-9):7.1f}/s  "
                f"gyro {g[0]:+7.2f} {g[1]:+7.2f} {g[2]:+7.2f} °/s  "
                f"accel {a[0]:+6.2f} {a[1]:+6.2f} {a[2]:+6.2f} m/s²  "
                f"mag {m[0]:+6.1f} {m[1]:+6.1f} {m[2]:+6.1f} µT  "
                f"T {s.temp_c:4.1f}°C  flags {s.flags.value:#05x}  rejected {rejected}")
        self.out.write(line)
        self.out.flush()

    def end(self) -> None:
        if self.out is not None:
            self.out.write("\n")

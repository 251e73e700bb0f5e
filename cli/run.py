"""`ahrsd run`: the daemon (sensor → calibration → estimator → MAVLink), in a terminal or under systemd."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run", help="run the AHRS daemon",
        description="Run the AHRS daemon. Without arguments and without /etc/ahrsd/ahrsd.toml it runs a simulated "
        "ADIS16405 and sends MAVLink to udpout:127.0.0.1:14550. Flags override the config file.")
    p.add_argument("--config", metavar="FILE", help="TOML config (default: $CONFIGURATION_DIRECTORY/ahrsd.toml or "
                   "/etc/ahrsd/ahrsd.toml when present)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--sim", metavar="SCENARIO", help="simulated ADIS16405 running SCENARIO: static (default), "
                     "rate-table, level-turns, coordinated-turn, tumble, auv-out-and-back, mag-disturbance, boat, "
                     "car, plane (the last three with a GNSS receiver: --gnss-sim)")
    src.add_argument("--spi", metavar="DEVICE", help="real ADIS16405 on this spidev node, e.g. /dev/spidev0.0")
    src.add_argument("--iio", metavar="DEVICE", help="the ADIS16405 through the kernel's adis16400 IIO driver: "
                     "iio:deviceN, its name (adis16405) or its sysfs directory")
    src.add_argument("--replay", metavar="FILE", help="replay a recording made by `ahrsd record`")
    p.add_argument("--rate-hz", metavar="SPS", type=float,
                   help="--sim/--spi: the chip's output data rate, the nearest SMPL_PRD setting (default 819.2; "
                   "lower costs less CPU: [sensor] rate_hz, docs/daemon.md)")
    p.add_argument("--replay-speed", metavar="X", type=float,
                   help="with --replay: replay X times faster than real time (default 1)")
    gnss = p.add_mutually_exclusive_group()
    gnss.add_argument("--gnss-replay", metavar="GNSS_CSV", help="with --replay: replay this GNSS recording in step "
                      "with the IMU recording (REC.gnss.csv, written by `ahrsd record`)")
    gnss.add_argument("--gnss-serial", metavar="DEVICE[,BAUD]", help="a GNSS receiver (UBX/NMEA) on this serial "
                      "port, e.g. /dev/serial0,115200")
    gnss.add_argument("--gnss-sim", action="store_true", help="with --sim: the simulated receiver of the scenario, "
                      "UBX over a pseudo-terminal read as a serial port")
    p.add_argument("--estimator", metavar="NAME", help="mekf, thesis or ins (default: ins with a GNSS source, "
                   "else mekf)")
    p.add_argument("--mavlink", metavar="URL", action="append",
                   help="MAVLink endpoint (repeatable; replaces the config's): udpout:HOST:PORT, udpin:HOST:PORT, "
                   "tcp:HOST:PORT, tcpin:HOST:PORT, /dev/ttyAMA0,921600")
    p.add_argument("--nmea", metavar="URL", action="append",
                   help="NMEA 0183 heading output (repeatable; replaces the config's [[nmea]]): udp:HOST:PORT, "
                   "udpbcast:HOST:PORT, tcpserver:HOST:PORT, serial:/dev/ttyUSB0[,BAUD] (docs/marine.md)")
    p.add_argument("--state-dir", metavar="DIR", help="calibration/parameter directory (default, as `ahrsd calibrate`: "
                   "$STATE_DIRECTORY under systemd, else /var/lib/ahrsd, the service's, when it exists and is writable, "
                   "else ~/.local/state/ahrsd)")
    p.add_argument("--status-line", choices=("auto", "on", "off"), help="live status line (default auto: on a TTY)")
    p.add_argument("--check-config", action="store_true", help="validate the configuration, print it and exit")
    p.add_argument("--sim-faults", metavar="SCHEDULE", help="inject faults into the simulated chip, e.g. "
                   "'bus_error@3-4;garbage@1-2:p=0.05' (see docs/reliability.md; simulated sensor only)")
    logs = p.add_mutually_exclusive_group()
    logs.add_argument("--log-dir", metavar="DIR", help="keep on-vehicle logs (raw samples, MAVLink .tlog) here "
                      "(turns logging on; default [log] dir: <state dir>/logs)")
    logs.add_argument("--no-log", action="store_true", help="no on-vehicle logs, whatever [log] enabled says")
    p.add_argument("--stats-file", metavar="FILE", help="write every counter of the run as JSON here on exit")
    p.set_defaults(func=run)


# True once a daemon this process ran has stopped: its service returned, --stats-file was written and the state
# directory's lock released. cli.main's console entry may then end the process without the interpreter's teardown.
daemon_stopped = False


def run(args: argparse.Namespace) -> int:
    global daemon_stopped
    import dataclasses
    import logging
    import os
    import sys

    from ahrsd.daemon.config import ConfigError

    try:
        cfg = _config(args)
    except ConfigError as exc:
        print(f"ahrsd run: error: {exc}", file=sys.stderr)
        return 2
    plan = None
    if args.sim_faults:
        plan = _fault_plan(args.sim_faults, cfg)
        if plan is None:
            return 2
    if args.check_config:
        import json

        from ahrsd.daemon.magcal_settings import MagCalSettings

        shown = dataclasses.asdict(cfg)
        # no [magcal] table is the field calibration's defaults (as the daemon builds it): print those, not null,
        # so that accept_broadcast = false shows beside [mavlink] accept_broadcast_commands
        shown["magcal"] = dataclasses.asdict(cfg.magcal or MagCalSettings())
        print(json.dumps(shown, indent=2, default=str))
        return 0
    if logging.getLogger().level > logging.INFO:
        logging.getLogger("ahrsd").setLevel(logging.INFO)   # the daemon reports its life cycle by default
    from ahrsd.daemon.state_lock import StateDirBusy, StateDirLock

    state_dir = cfg.state.resolve(os.environ)    # as the daemon resolves it (daemon.service)
    try:   # before anything in the directory is written, and before a compile: a refusal comes at once
        lock = StateDirLock.acquire(state_dir)
    except StateDirBusy as exc:
        print(f"ahrsd run: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:   # an unusable directory: the daemon warns that nothing persists, and runs
        lock = None
        logging.getLogger("ahrsd").warning("cannot lock the state directory %s (%s): a second daemon on it would "
                                           "not be refused", state_dir, exc.strerror or exc)
    try:
        source = _open_checked_source(cfg, plan)
        if source is None:
            return 1
        from ahrsd.daemon.service import Service

        code = _serve(Service(cfg, source=source), source, cfg, args.stats_file)
    finally:
        if lock is not None:
            lock.release()
    daemon_stopped = True
    return code


def _config(args):
    """The config file (or the defaults) with the command line's overrides; ConfigError when invalid."""
    import dataclasses

    from ahrsd.daemon.config import Config, DaemonConfig, default_config_path, load_config

    path = args.config or default_config_path()
    cfg = load_config(path) if path else Config()
    cfg = cfg.with_overrides(sim=args.sim, spi=args.spi, iio=args.iio, replay=args.replay,
                             mavlink=args.mavlink, state_dir=args.state_dir, replay_speed=args.replay_speed,
                             gnss_replay=args.gnss_replay, gnss_serial=args.gnss_serial,
                             gnss_sim=args.gnss_sim, estimator=args.estimator,
                             log_dir=args.log_dir, log_enabled=False if args.no_log else None,
                             nmea=args.nmea, rate_hz=args.rate_hz)
    if args.status_line:
        cfg = dataclasses.replace(cfg, daemon=DaemonConfig(status_line=args.status_line))
    return cfg


def _fault_plan(schedule: str, cfg):
    """--sim-faults: the simulated chip's fault plan; None (the reason on stderr) when it cannot be had."""
    import sys

    from ahrsd.cli.fault_schedule import FaultScheduleError, build_plan, parse_schedule

    if cfg.sensor.source != "sim":
        print("ahrsd run: error: --sim-faults needs the simulated sensor (--sim), not a real one", file=sys.stderr)
        return None
    try:
        # the schedule is in seconds; the plan counts the chip's samples, at the rate the chip will run at
        return build_plan(parse_schedule(schedule), cfg.sensor.chip_rate_hz, seed=cfg.sensor.seed)
    except FaultScheduleError as exc:
        print(f"ahrsd run: error: --sim-faults: {exc}", file=sys.stderr)
        return None


def _open_checked_source(cfg, plan):
    """The sensor source, after what can fail at once has been checked (`_START_CHECKS`, in order: the estimator's
    compile last, so a wrong path or address is said before it); None (one error line on stderr) when something
    failed."""
    import sys

    from ahrsd.drivers.errors import DriverError
    from ahrsd.drivers.source import open_source

    problem = next((p for check in _START_CHECKS if (p := check(cfg)) is not None), None)
    if problem is not None:
        print(f"ahrsd run: error: {problem}", file=sys.stderr)
        return None
    # the chip sources retry a failed start and a lost bus with backoff (daemon.sensor_recovery)
    try:
        return open_source(cfg.sensor, faults=plan)
    except DriverError as exc:   # a missing IIO device or data-ready GPIO: one line, not a traceback
        print(f"ahrsd run: error: {exc}", file=sys.stderr)
        return None


def _replay_file_problem(cfg) -> str | None:
    """A replay's recording that cannot be read: said before the estimator compiles, in one line."""
    if cfg.sensor.source != "replay":
        return None
    from ahrsd.drivers.recording import check_recording

    try:
        check_recording(cfg.sensor.replay_file)
    except (OSError, ValueError) as exc:
        return f"cannot replay {_os_error_text(exc, cfg.sensor.replay_file)}"
    return None


def _gnss_replay_problem(cfg) -> str | None:
    """The GNSS recording too: its header and first fix, as the daemon's backend reads them at its start."""
    if cfg.gnss.source != "replay":
        return None
    from ahrsd.drivers.gnss.recording import iter_gnss_fixes

    fixes = iter_gnss_fixes(cfg.gnss.file)
    try:
        next(fixes, None)
    except (OSError, ValueError) as exc:
        return f"cannot replay the GNSS recording {exc}"
    finally:
        fixes.close()
    return None


def _signing_key_problem(cfg) -> str | None:
    """The daemon loads the signing key at its start: a key it cannot use fails here, before a compile."""
    if not cfg.signing.key_file:
        return None
    from ahrsd.daemon.signing import SigningKeyError, load_key

    try:
        load_key(cfg.signing.key_file)
    except SigningKeyError as exc:
        return str(exc)
    return None


def _endpoint_problem(cfg) -> str | None:
    """A server address the daemon cannot have (not a local address, a port taken)."""
    from ahrsd.daemon.mavlink_io import EndpointOpenError, check_endpoint_opens

    for endpoint in cfg.endpoints:
        try:
            check_endpoint_opens(endpoint.url)
        except EndpointOpenError as exc:
            return str(exc)
    return None


def _nmea_output_problem(cfg) -> str | None:
    """An NMEA output's TCP server address too (its message names the output and the address)."""
    from ahrsd.daemon.nmea_transport import check_nmea_output_opens

    for output in cfg.nmea:
        try:
            check_nmea_output_opens(output.url)
        except OSError as exc:
            return str(exc)
    return None


def _estimator_problem(cfg) -> str | None:
    """The estimator's compile (first start only): an unknown estimator is said before it, not after."""
    from ahrsd.cli.warm_up import compile_estimator

    try:
        compile_estimator(cfg.estimator_name)
    except (ValueError, ModuleNotFoundError) as exc:
        return f"estimator {cfg.estimator_name!r}: {exc}"
    return None


_START_CHECKS = (_replay_file_problem, _gnss_replay_problem, _signing_key_problem, _endpoint_problem,
                 _nmea_output_problem, _estimator_problem)


def _serve(service, source, cfg, stats_file) -> int:
    """Run the daemon until it stops; its exit code (1 for a replay that could not be read to its end, 130 on
    Ctrl-C), and --stats-file written whatever happened."""
    import asyncio
    import logging
    import sys

    from ahrsd.daemon.sensor_recovery import report_sensor_alarms
    from ahrsd.drivers.replay_source import ReplaySource

    async def main() -> int:
        alarms = asyncio.get_running_loop().create_task(report_sensor_alarms(service))
        try:
            return await service.run()
        finally:
            alarms.cancel()

    try:
        code = asyncio.run(main())
        replay_error = source.error if isinstance(source, ReplaySource) else None
        if replay_error is not None and code == 0:
            # the reader reported the sensor failure; a replay that could not be read to its end is a failed run
            print(f"ahrsd run: error: the replay stopped early: {_os_error_text(replay_error, cfg.sensor.replay_file)}",
                  file=sys.stderr)
            return 1
        return code
    except KeyboardInterrupt:
        logging.getLogger("ahrsd").info("interrupted")
        return 130
    finally:
        if stats_file:
            from ahrsd.daemon.run_stats import write_stats

            write_stats(service, stats_file)


def _os_error_text(exc: Exception, path: str) -> str:
    """`path: reason` for an OSError (whose str() repeats errno and path), else the exception's own text."""
    if isinstance(exc, OSError):
        return f"{exc.filename or path}: {exc.strerror or exc}"
    return str(exc)

"""`ahrsd replay`: run a recording through calibration and an estimator, one output row per input sample.

    ahrsd replay RECORDING [--estimator {mekf,thesis,ins}] --output OUT.csv [--calibration FILE]
                 [--gnss GNSS.csv] [--lat DEG --lon DEG [--alt-m M] [--date YYYY-MM-DD]] [--set NAME=VALUE ...]
                 [--plot FILE.png]

The output CSV is a public interface (docs/replay.md): it is how the estimator is evaluated on data the
project has never seen. Its header is exactly OUTPUT_HEADER (with --gnss AIDED_OUTPUT_HEADER; with a calibration
check that runs, FIELD_CIRCLE_OUTPUT_COLUMNS follow); the first eight columns are fixed for good.
On a terminal a progress bar shows the rate and the time left (none in a pipe or with --quiet).
Exit status: 0 done, 1 bad input (recording, calibration, parameters, output path), 2 bad usage (including
--plot without matplotlib, checked before the replay runs).
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable

from ahrsd.core.estimator_names import ESTIMATORS

# The CSV columns, picked by name from the replay table (ahrsd.estimator.replay.ATTITUDE_COLUMNS, which
# documents each); named here so that `ahrsd --help` needs no numpy and the file format cannot drift.
OUTPUT_COLUMNS = (
    "t_s", "qw", "qx", "qy", "qz", "roll_deg", "pitch_deg", "yaw_deg", "heading_mag_deg", "heading_true_deg",
    "sigma_roll_deg", "sigma_pitch_deg", "sigma_yaw_deg", "gyro_bias_x_rad_s", "gyro_bias_y_rad_s",
    "gyro_bias_z_rad_s", "flags",
)
OUTPUT_HEADER = ",".join(OUTPUT_COLUMNS)
# With --gnss (an aided estimator) these follow (ahrsd.estimator.replay.NAV_COLUMNS): NED velocity and position
NAV_OUTPUT_COLUMNS = ("vel_n_m_s", "vel_e_m_s", "vel_d_m_s", "lat_deg", "lon_deg", "alt_m")
# ... and the heading checks (ahrsd.estimator.replay.HEADING_COLUMNS): the magnetometer-free GNSS yaw (true
# north) and its 1σ (NaN until the bank has one), the heading state (0 unknown, 1 magnetometer, 2 GNSS only,
# 3 learning)
HEADING_OUTPUT_COLUMNS = ("gsf_yaw_deg", "gsf_sigma_deg", "heading_state")
AIDED_OUTPUT_HEADER = ",".join(OUTPUT_COLUMNS + NAV_OUTPUT_COLUMNS + HEADING_OUTPUT_COLUMNS)
# When a calibration states its heading error and the estimator checks it by the field's circle in turns (mekf:
# ahrsd.estimator.replay.FIELD_CIRCLE_COLUMNS) these follow: the verdict per sample (0 not judged: too little
# turning, 1 consistent, 2 the calibration found wrong, 3 consistent with the hard iron mekf learned from the turns)
# and the circle centre's offset, µT (NaN while not judged).
# Without the check the header stays OUTPUT_HEADER (or AIDED_OUTPUT_HEADER).
FIELD_CIRCLE_OUTPUT_COLUMNS = ("mag_cal_check", "mag_field_centre_ut")
_FORMAT = ",".join(["%.6f"] + ["%.9f"] * 4 + ["%.6f"] * 5 + ["%.6f"] * 3 + ["%.6e"] * 3 + ["%d"])
_NAV_FORMAT = ",".join(["%.4f"] * 3 + ["%.9f"] * 2 + ["%.4f"] + ["%.4f"] * 2 + ["%d"])
_FIELD_CIRCLE_FORMAT = "%d,%.3f"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "replay",
        help="run a recording through calibration and an estimator; write the attitude per sample (CSV)",
        description="Replay a CSV recording (see `ahrsd record`; any sample rate, taken from its t_s column) "
        "through a calibration (none without --calibration: mekf's heading is then unknown) and an attitude estimator, and write one row "
        f"per input sample with the header: {OUTPUT_HEADER}. Without --lat/--lon the quaternion, yaw and "
        "heading are referenced to magnetic north; with them, to true north (WMM2025 declination there). The "
        "speed (× real time) is printed to stderr at the end. With --gnss (a GNSS recording, docs/gnss.md) the "
        f"aided estimator (ins) runs and the rows add {','.join(NAV_OUTPUT_COLUMNS)}; the declination then "
        "comes from the first fix's position unless --lat/--lon are given. Documented in docs/replay.md.",
    )
    p.add_argument("recording", metavar="RECORDING", help="CSV recording (header t_s,gyro_x_rad_s,...,mag_z_ut)")
    p.add_argument("--estimator", "-e", default=None, choices=ESTIMATORS,
                   help="mekf (default without --gnss): the error-state quaternion filter; thesis: the thesis's "
                   "vector KF + Wahba; ins (default with --gnss): the GNSS-aided INS")
    p.add_argument("--gnss", metavar="GNSS.csv", default=None,
                   help="GNSS recording on the recording's time base (REC.gnss.csv, written by `ahrsd record`): "
                   "its fixes are merged in time order with the samples")
    p.add_argument("--output", "-o", required=True, metavar="OUT.csv", help="output CSV file ('-' for stdout)")
    p.add_argument("--calibration", "-c", metavar="FILE", default=None,
                   help="calibration file (ahrsd calibrate / the state directory's calibration); without it the samples go in "
                        "as they are and the magnetometer's calibration is unknown (mekf: heading σ 180°, as the daemon)")
    p.add_argument("--lat", type=float, default=None, metavar="DEG", help="latitude for the WMM declination")
    p.add_argument("--lon", type=float, default=None, metavar="DEG", help="longitude for the WMM declination")
    p.add_argument("--alt-m", type=float, default=0.0, metavar="M", help="height above the ellipsoid, m (default 0)")
    p.add_argument("--date", default=None, metavar="YYYY-MM-DD",
                   help="date of the recording for the WMM (default: today)")
    p.add_argument("--set", dest="params", action="append", default=[], metavar="NAME=VALUE",
                   help="estimator parameter override (a field of MekfParams / ThesisKfParams), repeatable")
    p.add_argument("--plot", metavar="FILE.png", default=None,
                   help="also draw roll, pitch and heading with their 1σ bands, the flags, and the error against "
                   "the recording's truth columns when it has them (needs matplotlib: pip install matplotlib, or install ahrsd with -e '.[plot]')")
    p.add_argument("--quiet", "-q", action="store_true", help="no summary and no progress bar on stderr")
    p.set_defaults(func=run)


def _true_north(args) -> bool:
    """REFERENCE: the quaternion, yaw and figure are relative to true north (NED) when a position is given
    (--lat/--lon) or comes from the first GNSS fix (--gnss): the WMM declination there rotates the estimator's
    magnetic-north attitude about down. Else to magnetic north."""
    return args.lat is not None or bool(args.gnss)


class ReplayError(Exception):
    """Bad input: reported as one line on stderr, exit status 1."""


def _parse_params(items: list[str]) -> dict:
    import ast

    params = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ReplayError(f"--set {item!r}: expected NAME=VALUE")
        word = text.strip()
        if word.lower() in ("true", "false"):   # as the config file writes a switch (TOML), not only Python's True
            value = word.lower() == "true"
        else:
            try:
                value = ast.literal_eval(word)
            except (ValueError, SyntaxError):
                value = word   # a bare word (e.g. a string option)
        params[name.strip()] = value
    return params


GATE_HINT_FRACTION = 0.1   # of the fixes offered: more velocities rejected than this, and the replay says why it may be


CALIBRATION_WRONG = "calibration wrong or iron changed"


def _disagreement_cause(calibration, calibration_sigma_rad) -> str:
    """Why a magnetometer disagreed with GNSS, as the daemon's heading state says it (daemon/heading_status.py): a
    calibration that states its heading error was wrong (or the iron moved since); none, or one of unknown quality,
    is the reason itself."""
    from ahrsd.calibration.heading_trust import has_mag_calibration
    from ahrsd.estimator.calibration_heading import calibration_states_error

    if calibration_sigma_rad is not None and calibration_states_error(calibration_sigma_rad):
        return CALIBRATION_WRONG
    if has_mag_calibration(calibration):
        return "the magnetometer calibration states no heading error"
    return "magnetometer not calibrated (no --calibration)"


def _gate_summary(estimator, by_cause: dict[str, int] | None = None, mag_cause: str = CALIBRATION_WRONG) -> str:
    """What the aided filter's innovation gate did with the fixes, and why, when it rejected many velocities: the
    cause the evidence supports (`by_cause`: the rejections counted by cause as the replay went,
    estimator/velocity_rejection_watch.py — the daemon's rule and `calibrate mag --gnss`'s): the heading when it
    explains all but GATE_HINT_FRACTION of the fixes offered (a filter whose heading is wrong or not yet found
    rejects correct fixes), else the antenna's place and the fixes' time stamps (a filter whose attitude is right
    rejects a correct fix only if the antenna is not where it was told). First, whatever the count, the antenna's
    place when the lever-arm check found the told arm wrong (its latch: the filter may have adopted the fitted arm
    since and rejected few). `mag_cause`: why the magnetometer disagreed, when the heading checks rejected it
    (_disagreement_cause)."""
    from ahrsd.estimator.base import GnssAidedEstimator, HeadingCheckedEstimator
    from ahrsd.estimator.velocity_rejection_watch import heading_causes_text, heading_explained

    if not isinstance(estimator, GnssAidedEstimator):
        return "not offered"
    c = estimator.gnss_counters
    text = (f"the filter fused {c.fused_velocity} velocities and {c.fused_position} positions, its gate rejected "
            f"{c.rejected_velocity} and {c.rejected_position}")
    report = estimator.heading_report() if isinstance(estimator, HeadingCheckedEstimator) else None
    if report is not None and report.mag_rejections:
        # the magnetometer, not the antenna: a filter pulled by a wrong magnetometer rejects correct fixes
        text += f"; WARNING: {_rejection_summary(report, mag_cause)}"
    limit = GATE_HINT_FRACTION * max(c.offered, 1)
    arm = " ".join(f"{v:g}" for v in estimator.lever_arm_m)
    fit = estimator.lever_arm_fit()
    if fit is not None and fit.arm_wrong:
        # the lever-arm check's latch (estimator/lever_arm_fit.py), as the heading reads it: where the velocities
        # put the antenna, whether or not the fitted arm, once adopted, left many rejections
        at = ", ".join(f"{v:.1f}" for v in fit.antenna_m(estimator.lever_arm_m).tolist())
        used = "; the filter fused at the fitted arm once it was sure of it" if fit.arm_adopted else ""
        text += (f"; WARNING: the GNSS velocities fit an antenna at ({at}) m ±{float(max(fit.sigma_m)):.1f} m, not "
                 f"where the filter was told ({arm} m, body FRD){used}: measure it and give it "
                 f"(--set \"lever_arm_m=(x, y, z)\")")
    elif c.rejected_velocity > limit:
        heading = heading_explained(by_cause or {})
        unexplained = c.rejected_velocity - sum(heading.values())
        if heading and unexplained <= limit:
            text += (f"; WARNING: the velocities were rejected while the filter's heading was not one to trust "
                     f"({heading_causes_text(heading)}), not for the antenna's place or the fixes' time stamps")
        else:
            known = f" ({unexplained} of them with its heading known)" if heading else ""
            text += (f"; WARNING: that many rejected velocities{known} usually mean the antenna is not where "
                     f"the filter was told ({arm} m, body FRD: --set \"lever_arm_m=(x, y, z)\") or the fixes' "
                     "time stamps are off")
    return text


def _rejection_summary(report, mag_cause: str) -> str:
    """Why the heading checks rejected the magnetometer (estimator.ins.HeadingReport): an iron that stepped while
    the gyro saw no turn (estimator/mag_step.py), said as such with the first step's time and size, and the
    rejections for a disagreement with GNSS."""
    resets = f"heading reset to the GNSS yaw {report.yaw_resets}×"
    others = report.mag_rejections - report.mag_steps
    parts = []
    if report.mag_steps:
        times = "once" if report.mag_steps == 1 else f"{report.mag_steps}×, the first"
        parts.append(f"iron changed {times} at {report.first_step_t_s:.1f} s: magnetometer heading stepped by "
                     f"{report.first_step_deg:+.1f}° while the gyro saw no turn, magnetometer rejected")
    if others:
        by = (f"by {report.max_disagreement_deg:.1f}° when rejected" if others == 1 else
              f"by up to {report.max_disagreement_deg:.1f}° (the largest at its {others} rejections)")
        parts.append(f"magnetometer disagreed with GNSS {by}: {mag_cause}")
    return "; ".join(parts) + f" ({resets})"


_STATE_NAMES = {0: "unknown", 1: "magnetometer", 2: "GNSS only", 3: "learning"}
MAX_STATE_CHANGES_SHOWN = 12


def _state_changes(t_s, states, history: list) -> None:
    """Append (t, state) at each change of the heading state column."""
    import numpy as np

    s = states.astype(int)
    prev = history[-1][1] if history else None
    change = np.flatnonzero(np.diff(s)) + 1
    if prev is None or (len(s) and s[0] != prev):
        change = np.concatenate([[0], change])
    history.extend((float(t_s[k]), int(s[k])) for k in change)


def _history_text(history: list, last_t: float) -> str:
    """The time spent in each heading state and its first changes."""
    if not history:
        return "(none)"
    spent: dict[int, float] = {}
    for (t0, st), (t1, _) in zip(history, history[1:] + [(last_t, -1)]):
        spent[st] = spent.get(st, 0.0) + max(t1 - t0, 0.0)
    total = ", ".join(f"{_STATE_NAMES.get(k, k)} {v:.0f} s" for k, v in sorted(spent.items()))
    changes = " → ".join(f"{_STATE_NAMES.get(st, st)} at {t:.1f} s" for t, st in history[:MAX_STATE_CHANGES_SHOWN])
    more = f" (+{len(history) - MAX_STATE_CHANGES_SHOWN} more)" if len(history) > MAX_STATE_CHANGES_SHOWN else ""
    return f"{total}; {changes}{more}"


def _declination_rad(args, gnss_position=None) -> float:
    """WMM declination at --lat/--lon, else at the first GNSS fix's position `(lat, lon, alt)`, else 0."""
    import datetime as dt
    import math

    if args.lat is None and args.lon is None:
        if gnss_position is None:
            return 0.0
        lat, lon, alt = gnss_position
    elif args.lat is None or args.lon is None:
        raise ReplayError("--lat and --lon go together")
    else:
        lat, lon, alt = args.lat, args.lon, args.alt_m
    from ahrsd.core.wmm import earth_field

    date = None
    if args.date:
        try:
            date = dt.date.fromisoformat(args.date)
        except ValueError:
            raise ReplayError(f"--date {args.date!r}: expected YYYY-MM-DD") from None
    if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)):
        raise ReplayError("--lat, --lon and --alt-m must be finite numbers")
    try:
        return earth_field(lat, lon, alt, date).declination_rad
    except ValueError as exc:
        raise ReplayError(str(exc)) from None


def _gnss_fixes(path: str, validator):
    """The recording's fixes that pass the validator (the daemon's edge check), and the first one's position."""
    import math

    from ahrsd.drivers.gnss.recording import GnssRecordingFormatError, read_gnss_recording

    try:
        fixes = read_gnss_recording(path)
    except GnssRecordingFormatError as exc:       # names the file, and the line and column or the OS error
        raise ReplayError(str(exc)) from None
    good = [f for f in fixes if validator.check(f) is None]
    if not good:
        raise ReplayError(f"{path}: no usable fix ({len(fixes)} rows, {validator.rejected} rejected)")
    first = good[0]
    alt = first.alt_m if math.isfinite(first.alt_m) else 0.0
    return good, (first.lat_deg, first.lon_deg, alt)


def format_rows(table, row_format: str = _FORMAT) -> str:
    """CSV text of output rows (one `%` over the whole chunk: faster than a format per row)."""
    row = row_format + "\n"
    return (row * len(table)) % tuple(table.ravel().tolist())


class _Output:
    """The output file, written to a temporary file beside it and renamed at the end, so a replay that fails
    half-way leaves no partial output; '-' streams to stdout."""

    def __init__(self, path: str, header: str = OUTPUT_HEADER, row_format: str = _FORMAT):
        import os
        import sys
        import tempfile

        from .output_target import renamed_into_place

        self.path = path
        self.header, self.row_format = header, row_format
        self._tmp = None
        self._opened_through = False
        if path == "-":
            self._file = sys.stdout
        elif not renamed_into_place(path):
            self._file = open(path, "w", encoding="utf-8", newline="\n")
            self._opened_through = True
        else:
            directory = os.path.dirname(os.path.abspath(path))
            fd, self._tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".part", dir=directory)
            # mkstemp makes it 0600; the output gets the mode open() would give it (0666 less the umask),
            # like the recording it came from and the figure beside it
            umask = os.umask(0)
            os.umask(umask)
            os.fchmod(fd, 0o666 & ~umask)
            self._file = os.fdopen(fd, "w", encoding="utf-8", newline="\n")
        self._header_written = False

    def write(self, table) -> None:
        if not self._header_written:   # not before the first rows: a bad recording prints nothing to stdout
            self._file.write(self.header + "\n")
            self._header_written = True
        self._file.write(format_rows(table, self.row_format))

    def commit(self) -> None:
        import os

        if self._tmp is None:
            if self._opened_through:
                self._file.close()
            else:
                self._file.flush()
            return
        self._file.close()
        os.replace(self._tmp, self.path)
        self._tmp = None

    def discard(self) -> None:
        import os

        if self._tmp is not None:
            self._file.close()
            try:
                os.unlink(self._tmp)
            except OSError:
                pass
            self._tmp = None


class ReplayUsageError(ReplayError):
    """An option that cannot work as given (e.g. --plot without matplotlib): exit status 2."""


def run(args) -> int:
    """`ahrsd replay`: the estimator compiled (and announced) through cli.warm_up, as `ahrsd run` does."""
    from ahrsd.cli import warm_up

    return replay_command(args, compile_estimator=warm_up.compile_estimator, count_compiles=warm_up.numba_compiles)


def replay_command(args, *, compile_estimator: Callable[[str], object], count_compiles: Callable[[], int]) -> int:
    """The replay `args` (the parsed command line) asks for; the exit status. Its estimator is compiled first by
    `compile_estimator(name)`, and `count_compiles()` (numba's compiles so far) tells a compile from a cache load.
    Bad input is one line on stderr: status 1, or 2 for an option that cannot work as given."""
    import sys

    try:
        return _run(args, compile_estimator, count_compiles)
    except ReplayError as exc:
        print(f"ahrsd replay: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, ReplayUsageError) else 1


def _plot(args, trace, title: str, fixes) -> None:
    """The replay figure, with the recording's truth attitude when it has the truth columns."""
    import numpy as np

    from ahrsd.drivers.recording import TRUTH_COLUMNS, open_text, read_header, read_recording
    from ahrsd.estimator.replay_plot import plot_replay

    with open_text(args.recording) as f:
        columns = read_header(f.readline(), args.recording)
    truth_q = truth_t = None
    if all(c in columns for c in TRUTH_COLUMNS):
        rec = read_recording(args.recording, strict=False)
        truth_q, truth_t = rec.truth_q_wxyz, rec.t_s
        if not np.isfinite(truth_q).any():
            truth_q = truth_t = None
    try:
        plot_replay(trace, args.plot, truth_q, truth_t, title=title, fixes=fixes or ())
    except OSError as exc:
        raise ReplayError(f"{args.plot}: cannot write the plot: {exc.strerror or exc}") from None


def _run(args, compile_estimator: Callable[[str], object], count_compiles: Callable[[], int]) -> int:
    """Read the inputs, build the estimator, replay the recording into the output, draw, and summarise."""
    import os
    import sys
    import time

    t_start, cpu_start = time.perf_counter(), time.process_time()
    trace = _plot_trace(args)
    params = _parse_params(args.params)
    estimator_name = args.estimator or ("ins" if args.gnss else "mekf")
    fixes, validator, first_position = _gnss_input(args)
    declination = _declination_rad(args, first_position)
    calibration = _load_calibration(args)
    if os.path.isdir(args.recording):
        raise ReplayError(f"{args.recording}: is a directory, not a recording")
    compile_wall_s = compile_cpu_s = 0.0
    if os.path.isfile(args.recording):   # a missing one fails at once, without a compile
        compile_wall_s, compile_cpu_s = _compile_announced(estimator_name, compile_estimator, count_compiles)
    params = _told_calibration_sigma(estimator_name, calibration, params)
    estimator = _make_estimator(estimator_name, declination, params, aided=fixes is not None)
    done = _replay(args, estimator, calibration, fixes, trace, params.get("mag_calibration_sigma_rad"))
    if trace is not None:
        from ahrsd.estimator.replay_plot import replay_title

        position = (args.lat, args.lon) if args.lat is not None else first_position
        _plot(args, trace, replay_title(os.path.basename(args.recording), estimator_name, aided=done.aided,
                                        declination_rad=declination, position_deg=position,
                                        position_from_gnss=args.lat is None), fixes)
    if not args.quiet:
        _print_summary(args, done, estimator_name, estimator, declination, validator,
                       time.perf_counter() - t_start - compile_wall_s, time.process_time() - cpu_start - compile_cpu_s,
                       compile_wall_s, _disagreement_cause(calibration, params.get("mag_calibration_sigma_rad")))
        unknown = _unknown_heading_text(estimator_name, calibration, params.get("mag_calibration_sigma_rad"), done.aided)
        if unknown:
            print(f"ahrsd replay: {unknown}", file=sys.stderr)
    return 0


def _unknown_heading_text(estimator_name: str, calibration, calibration_sigma_rad, aided: bool) -> str:
    """What the summary says when mekf's heading is unknown for want of a calibration figure, as the daemon's heading
    state says it ("hdg unknown uncal"): without GNSS the magnetometer calibration is the only heading reference, and
    the σ column carries the unknown calibration (estimator/calibration_heading.py) — "" otherwise."""
    import math

    from ahrsd.estimator.calibration_heading import UNKNOWN_CALIBRATION_SIGMA_RAD, calibration_states_error

    if aided or estimator_name != "mekf" or calibration_sigma_rad is None or calibration_states_error(calibration_sigma_rad):
        return ""
    why = ("no magnetometer calibration given (--calibration FILE: ahrsd calibrate mag, or the state directory's)"
           if calibration is None else "the calibration does not state the heading error it leaves")
    return (f"heading unknown (sigma_yaw_deg {math.degrees(UNKNOWN_CALIBRATION_SIGMA_RAD):.0f}°): {why}; without "
            "GNSS the magnetometer calibration is the only heading reference (roll and pitch are unaffected)")


def _compile_announced(estimator_name: str, compile_estimator: Callable[[str], object],
                       count_compiles: Callable[[], int]) -> tuple[float, float]:
    """Compile the estimator first, as `ahrsd run` does, so the first replay after an install says "compiling the
    … estimator" instead of sitting silent while it compiles (cli.warm_up; a cached start says nothing). The "ahrsd"
    logger is raised to INFO for that only: the replay's own log stays at the command line's level.

    Returns the compile's (wall s, CPU s) when it compiled, (0, 0) when it loaded the cache: the summary's speed
    is the replay's, a one-off compile reported beside it (counted in, it would make the first run look slow)."""
    import logging
    import time

    logger = logging.getLogger("ahrsd")
    level = logger.level
    if not logger.isEnabledFor(logging.INFO):
        logger.setLevel(logging.INFO)
    compiles_before = count_compiles()
    wall_start, cpu_start = time.perf_counter(), time.process_time()
    try:
        compile_estimator(estimator_name)
    finally:
        logger.setLevel(level)
    if count_compiles() == compiles_before:
        return 0.0, 0.0
    return time.perf_counter() - wall_start, time.process_time() - cpu_start


def _plot_trace(args):
    """With --plot: the trace the figure is drawn from (matplotlib checked before the replay runs), else None."""
    if not args.plot:
        return None
    from ahrsd.core.plotting import PlotUnavailableError, pyplot
    from ahrsd.estimator.replay_plot import ReplayTrace

    try:
        pyplot()
    except PlotUnavailableError as exc:
        raise ReplayUsageError(str(exc)) from None
    trace = ReplayTrace()
    trace.true_north = _true_north(args)
    return trace


def _gnss_input(args):
    """With --gnss: (the usable fixes, their validator, the first fix's position), else (None, None, None)."""
    if not args.gnss:
        return None, None, None
    from ahrsd.drivers.gnss.validation import GnssFixValidator

    validator = GnssFixValidator(name=f"replay {args.gnss}")
    fixes, first_position = _gnss_fixes(args.gnss, validator)
    return fixes, validator, first_position


def _load_calibration(args):
    """The --calibration file's calibration, or None."""
    if not args.calibration:
        return None
    from ahrsd.calibration.store import CalibrationFileError, load_calibration_file

    try:
        return load_calibration_file(args.calibration)
    except CalibrationFileError as exc:
        raise ReplayError(str(exc)) from None


def _told_calibration_sigma(name: str, calibration, params: dict) -> dict:
    """The parameters with the heading error the calibration predicts (ins, mekf), for ins its frame's tilt and,
    for mekf, the accelerometer bias it leaves, as the daemon tells them."""
    if name in ("ins", "mekf") and "mag_calibration_sigma_rad" not in params:
        from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad

        # how far ins may trust this calibration's magnetometer, and the heading error a magnetometer-held heading's
        # published σ carries without GNSS (estimator/calibration_heading.py): as the daemon does (NaN: unknown)
        params = {**params, "mag_calibration_sigma_rad": calibration_heading_sigma_rad(calibration)}
    if name == "ins" and "mag_calibration_frame_tilt_sigma_rad" not in params:
        from ahrsd.calibration.heading_trust import calibration_frame_tilt_sigma_rad

        # the calibration frame's tilt against the body (its levelling's): ins's frame-tilt states' prior, as the
        # daemon tells it (0: none stated, the frame is the body's)
        params = {**params, "mag_calibration_frame_tilt_sigma_rad": calibration_frame_tilt_sigma_rad(calibration)}
    if name == "ins" and "mag_calibration_frame_tilt_heading_sigma_rad" not in params:
        from ahrsd.calibration.heading_trust import calibration_frame_tilt_heading_sigma_rad

        # the share of its heading error that tilt makes: ins's harmonics leave it to the frame-tilt states
        params = {**params, "mag_calibration_frame_tilt_heading_sigma_rad":
                  calibration_frame_tilt_heading_sigma_rad(calibration)}
    if name == "mekf" and "accel_bias_sigma_m_s2" not in params:
        from ahrsd.calibration.accel_trust import calibration_accel_bias_sigma_m_s2

        # mekf's published tilt σ carries the accelerometer bias the calibration leaves, as the daemon tells it
        sigma_m_s2 = calibration_accel_bias_sigma_m_s2(calibration)
        if sigma_m_s2 is not None:
            params = {**params, "accel_bias_sigma_m_s2": sigma_m_s2}
    return params


def _make_estimator(name: str, declination_rad: float, params: dict, aided: bool):
    """The estimator with these parameters; `aided`: it must take GNSS fixes."""
    from ahrsd.estimator import make_estimator
    from ahrsd.estimator.base import GnssAidedEstimator

    try:
        estimator = make_estimator(name, declination_rad=declination_rad, **params)
    except ModuleNotFoundError as exc:
        raise ReplayError(f"estimator {name!r} is not available ({exc})") from None
    except (TypeError, ValueError) as exc:
        raise ReplayError(f"estimator {name!r}: {exc}") from None
    if aided and not isinstance(estimator, GnssAidedEstimator):
        raise ReplayError(f"--gnss needs the aided estimator (ins); {name} takes no GNSS fixes")
    return estimator


class _CheckedSamples:
    """The recording's samples, streamed (constant memory), with their count and first and last times; t_s must
    be finite for the estimator's Δt."""

    def __init__(self, path: str, samples):
        import math

        self.path, self._samples = path, samples
        self.first_t = self.last_t = math.nan
        self.count = 0

    def __iter__(self):
        import math

        for sample in self._samples:
            t = sample.t_s
            if not math.isfinite(t):
                raise ReplayError(f"{self.path}: sample {self.count + 1}: t_s is not a finite number")
            if self.count == 0:
                self.first_t = t
            self.last_t = t
            self.count += 1
            yield sample


@dataclass
class _ReplayDone:
    """What the replay loop did: the samples it read, whether GNSS aided it, the heading-state changes (t, state)
    and the CPU time of the loop (read, estimate, write)."""

    samples: _CheckedSamples
    aided: bool
    history: list
    loop_cpu_s: float
    calibration_check: object = None   # CalibrationCheckSummary while the circle check ran, else None
    calibration_sigma_rad: float = float("nan")
    rejected_velocity_by_cause: dict | None = None   # aided: the gate's rejected velocities by cause (RejectionWatch)


def _output_order(aided: bool, checked: bool = False) -> tuple[list[int], int, int]:
    """The replay table's columns in the output CSV's order, the heading-state column of the table and where its
    calibration check's columns start (`checked`: the table has them)."""
    from ahrsd.estimator.replay import ATTITUDE_COLUMNS, FIELD_CIRCLE_COLUMNS, HEADING_COLUMNS, NAV_COLUMNS

    order = [ATTITUDE_COLUMNS.index(name) for name in OUTPUT_COLUMNS]
    circle_col = len(ATTITUDE_COLUMNS)
    if aided:
        order += [len(ATTITUDE_COLUMNS) + NAV_COLUMNS.index(name) for name in NAV_OUTPUT_COLUMNS]
        order += [len(ATTITUDE_COLUMNS) + len(NAV_COLUMNS) + HEADING_COLUMNS.index(name)
                  for name in HEADING_OUTPUT_COLUMNS]
        circle_col += len(NAV_COLUMNS) + len(HEADING_COLUMNS)
    if checked:
        order += [circle_col + FIELD_CIRCLE_COLUMNS.index(name) for name in FIELD_CIRCLE_OUTPUT_COLUMNS]
    return order, len(ATTITUDE_COLUMNS) + len(NAV_COLUMNS) + HEADING_COLUMNS.index("heading_state"), circle_col


def _replay(args, estimator, calibration, fixes, trace, calibration_sigma_rad=None) -> _ReplayDone:
    """Stream the recording (calibrated) through the estimator into the output file, a table at a time;
    `calibration_sigma_rad`: the heading error the estimator was told the calibration leaves (None: not told)."""
    import time

    from ahrsd.drivers.recording import iter_samples
    from ahrsd.estimator.replay import field_circle_columns, replay_attitude
    from ahrsd.estimator.velocity_rejection_watch import RejectionWatch

    from .calibration_check_summary import CalibrationCheckSummary

    aided = fixes is not None
    watch = RejectionWatch(estimator, estimator.params.mag_enabled) if aided else None
    field_circle = field_circle_columns(estimator, calibration_sigma_rad)
    checked = field_circle is not None
    out = _open_output(args.output, aided, checked)
    verdicts = CalibrationCheckSummary() if checked else None
    # a file cut mid-row: its complete rows
    samples = _CheckedSamples(args.recording, iter_samples(args.recording, strict=False))
    t_run = time.process_time()
    try:
        with _replay_errors(args):
            tables = replay_attitude(estimator, _calibrated(samples, calibration), true_north=_true_north(args),
                                     fixes=fixes, field_circle=field_circle, on_estimate=watch)
            history = _write_tables(args, tables, out, aided, verdicts, trace)
            if samples.count == 0:
                raise ReplayError(f"{args.recording}: the recording has a header but no samples")
            out.commit()
    finally:
        out.discard()
    return _ReplayDone(samples, aided, history, time.process_time() - t_run, verdicts,
                       float(calibration_sigma_rad) if checked else float("nan"),
                       None if watch is None else dict(watch.by_cause))


def _open_output(path: str, aided: bool, checked: bool) -> _Output:
    """The output file with its header and row format: the attitude columns, then the aided estimator's (`aided`)
    and the calibration check's (`checked`)."""
    header, row_format = (AIDED_OUTPUT_HEADER, _FORMAT + "," + _NAV_FORMAT) if aided else (OUTPUT_HEADER, _FORMAT)
    if checked:
        header += "," + ",".join(FIELD_CIRCLE_OUTPUT_COLUMNS)
        row_format += "," + _FIELD_CIRCLE_FORMAT
    try:
        return _Output(path, header, row_format)
    except OSError as exc:
        raise ReplayError(f"{path}: cannot write: {exc.strerror or exc}") from None


def _calibrated(samples, calibration):
    """The samples through the calibration (as they are without one, or with the identity)."""
    return map(calibration.apply, samples) if calibration is not None and not calibration.is_identity else samples


@contextmanager
def _replay_errors(args):
    """Reading the recording or writing the output failed: one line naming the file (ReplayError)."""
    from ahrsd.drivers.recording import RecordingFormatError

    try:
        yield
    except FileNotFoundError:
        raise ReplayError(f"{args.recording}: no such file") from None
    except UnicodeDecodeError:
        raise ReplayError(f"{args.recording}: not a text (UTF-8) CSV file") from None
    except RecordingFormatError as exc:
        raise ReplayError(str(exc)) from None
    except OSError as exc:
        raise ReplayError(f"{exc.filename or args.output}: {exc.strerror or exc}") from None


def _write_tables(args, tables, out: _Output, aided: bool, verdicts, trace) -> list[tuple[float, int]]:
    """Each replay table into the output file (in the CSV's column order), the heading state's changes (`aided`),
    the calibration check's verdicts (`verdicts`, a CalibrationCheckSummary) and the figure's trace (`trace`), with
    a progress bar; the heading state's changes (t, state)."""
    from .progress import expected_rows, progress_bar

    order, state_col, circle_col = _output_order(aided, verdicts is not None)
    history: list[tuple[float, int]] = []
    with progress_bar(args.quiet, expected_rows(args.recording), "replay") as bar:
        for table in tables:
            out.write(table[:, order])
            if aided:
                _state_changes(table[:, 0], table[:, state_col], history)
            if verdicts is not None:
                verdicts.add(table[:, 0], table[:, circle_col], table[:, circle_col + 1])
            bar.update(len(table))
            if trace is not None:
                trace.add(table)
    return history


def _print_summary(args, done: _ReplayDone, estimator_name: str, estimator, declination: float, validator,
                   wall_s: float, cpu_s: float, compile_wall_s: float = 0.0,
                   mag_cause: str = CALIBRATION_WRONG) -> None:
    """The end-of-run lines on stderr: what was replayed, through what, referenced to which north, how fast (the
    replay's wall and CPU time: an estimator compile before it, `compile_wall_s` > 0, is named apart)."""
    import math
    import sys

    count, aided = done.samples.count, done.aided
    duration = done.samples.last_t - done.samples.first_t
    rate = (count - 1) / duration if count > 1 and duration > 0 else math.nan
    if math.isfinite(rate):
        duration += 1.0 / rate
    speed = duration / wall_s if wall_s > 0 else math.inf
    cpu_speed = duration / cpu_s if cpu_s > 0 else math.inf
    where = ("magnetic north (no position)" if not _true_north(args)
             else f"true north, declination {math.degrees(declination):+.2f}°"
             + (" at the first fix" if args.lat is None else ""))
    gnss = ""
    if aided:
        reasons = ", ".join(f"{k} {v}" for k, v in validator.counters.items() if k != "accepted" and v)
        gnss = (f"and {validator.counters['accepted']} GNSS fixes ({validator.rejected} rejected"
                f"{': ' + reasons if reasons else ''}; "
                f"{_gate_summary(estimator, done.rejected_velocity_by_cause, mag_cause)}) ")
    print(f"ahrsd replay: {count} samples ({duration:.1f} s at {rate:.1f} Hz) {gnss}through {estimator_name}, "
          f"heading to {where}; {wall_s:.2f} s wall ({done.loop_cpu_s * 1e6 / count:.1f} CPU µs/sample to read, "
          f"estimate and write): {speed:.1f}× real time ({cpu_speed:.1f}× per CPU second)"
          + (f", after compiling {estimator_name} for {compile_wall_s:.1f} s wall (first run after an install, "
             "cached afterwards; not counted)" if compile_wall_s > 0 else ""), file=sys.stderr)
    if aided:
        print(f"ahrsd replay: heading state {_history_text(done.history, done.samples.last_t)}", file=sys.stderr)
    if done.calibration_check is not None:
        print(f"ahrsd replay: {done.calibration_check.text(done.calibration_sigma_rad)}", file=sys.stderr)
    if args.plot:
        print(f"ahrsd replay: figure written to {args.plot}", file=sys.stderr)

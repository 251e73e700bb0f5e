"""`ahrsd replay`: run a recording through calibration and an estimator, one output row per input sample.

    ahrsd replay RECORDING [--estimator {mekf,thesis}] --output OUT.csv [--calibration FILE]
                 [--lat DEG --lon DEG [--alt-m M] [--date YYYY-MM-DD]] [--set NAME=VALUE ...]

The output CSV is a public interface (docs/replay.md): it is how the estimator is evaluated on data the
project has never seen. Its header is exactly OUTPUT_HEADER; the first eight columns are fixed for good.
Exit status: 0 done, 1 bad input (recording, calibration, parameters, output path), 2 bad usage.
"""

from __future__ import annotations

OUTPUT_COLUMNS = (
    "t_s",                                     # the input sample's time, s
    "qw", "qx", "qy", "qz",                    # body (FRD) → NED, Hamilton, scalar first (see REFERENCE)
    "roll_deg", "pitch_deg", "yaw_deg",        # ZYX Euler of that quaternion; yaw in [−180, 180)
    "heading_mag_deg", "heading_true_deg",     # [0, 360); true = magnetic + declination (0 without a position)
    "sigma_roll_deg", "sigma_pitch_deg", "sigma_yaw_deg",   # 1σ uncertainty
    "gyro_bias_x_rad_s", "gyro_bias_y_rad_s", "gyro_bias_z_rad_s",
    "flags",                                   # EstimateFlags as an integer
)
OUTPUT_HEADER = ",".join(OUTPUT_COLUMNS)
# REFERENCE: the quaternion and yaw are relative to true north (NED) when a position is given (--lat/--lon: the
# WMM declination rotates the estimator's magnetic-north attitude about down), else to magnetic north.
_FORMAT = ",".join(["%.6f"] + ["%.9f"] * 4 + ["%.6f"] * 5 + ["%.6f"] * 3 + ["%.6e"] * 3 + ["%d"])


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "replay",
        help="run a recording through calibration and an estimator; write the attitude per sample (CSV)",
        description="Replay a CSV recording (see `ahrsd record`; any sample rate, taken from its t_s column) "
        "through a calibration (identity without --calibration) and an attitude estimator, and write one row "
        f"per input sample with the header: {OUTPUT_HEADER}. Without --lat/--lon the quaternion, yaw and "
        "heading are referenced to magnetic north; with them, to true north (WMM2025 declination there). The "
        "speed (× real time) is printed to stderr at the end. Documented in docs/replay.md.",
    )
    p.add_argument("recording", metavar="RECORDING", help="CSV recording (header t_s,gyro_x_rad_s,...,mag_z_ut)")
    p.add_argument("--estimator", "-e", default="mekf", choices=("mekf", "thesis"),
                   help="mekf (default): the error-state quaternion filter; thesis: the thesis's vector KF + Wahba")
    p.add_argument("--output", "-o", required=True, metavar="OUT.csv", help="output CSV file ('-' for stdout)")
    p.add_argument("--calibration", "-c", metavar="FILE", default=None,
                   help="calibration file (ahrsd calibrate / the state directory's calibration); default identity")
    p.add_argument("--lat", type=float, default=None, metavar="DEG", help="latitude for the WMM declination")
    p.add_argument("--lon", type=float, default=None, metavar="DEG", help="longitude for the WMM declination")
    p.add_argument("--alt-m", type=float, default=0.0, metavar="M", help="height above the ellipsoid, m (default 0)")
    p.add_argument("--date", default=None, metavar="YYYY-MM-DD",
                   help="date of the recording for the WMM (default: today)")
    p.add_argument("--set", dest="params", action="append", default=[], metavar="NAME=VALUE",
                   help="estimator parameter override (a field of MekfParams / ThesisKfParams), repeatable")
    p.add_argument("--quiet", "-q", action="store_true", help="no summary on stderr")
    p.set_defaults(func=run)


class ReplayError(Exception):
    """Bad input: reported as one line on stderr, exit status 1."""


def _parse_params(items: list[str]) -> dict:
    import ast

    params = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ReplayError(f"--set {item!r}: expected NAME=VALUE")
        try:
            value = ast.literal_eval(text.strip())
        except (ValueError, SyntaxError):
            value = text.strip()   # a bare word (e.g. a string option)
        params[name.strip()] = value
    return params


def _declination_rad(args) -> float:
    import datetime as dt
    import math

    if args.lat is None and args.lon is None:
        return 0.0
    if args.lat is None or args.lon is None:
        raise ReplayError("--lat and --lon go together")
    from ahrsd.estimator.wmm import earth_field

    date = None
    if args.date:
        try:
            date = dt.date.fromisoformat(args.date)
        except ValueError:
            raise ReplayError(f"--date {args.date!r}: expected YYYY-MM-DD") from None
    if not (math.isfinite(args.lat) and math.isfinite(args.lon) and math.isfinite(args.alt_m)):
        raise ReplayError("--lat, --lon and --alt-m must be finite numbers")
    try:
        return earth_field(args.lat, args.lon, args.alt_m, date).declination_rad
    except ValueError as exc:
        raise ReplayError(str(exc)) from None


def replay_arrays(estimator, t_s, gyro_rad_s, accel_m_s2, mag_ut, sample_flags=None, true_north: bool = False):
    """Feed samples one at a time (as the daemon does) and return the output table (n, len(OUTPUT_COLUMNS)).

    true_north: rotate the quaternion and yaw by the estimator's declination (heading_true − heading_mag) so
    they are relative to true north; otherwise they stay relative to magnetic north, as estimated.
    """
    import math

    import numpy as np

    from ahrsd.drivers.sample import ImuSample, SampleFlags

    n = len(t_s)
    rows = []
    append = rows.append
    deg = 180.0 / math.pi
    nan = math.nan
    none = SampleFlags.NONE
    flag_values = sample_flags.tolist() if sample_flags is not None else None
    t_list = t_s.tolist()
    update = estimator.update
    flag_enums: dict[int, SampleFlags] = {}   # the enum constructor is slow; there are few distinct values
    for i in range(n):
        if flag_values is None:
            flags = none
        else:
            value = int(flag_values[i])
            flags = flag_enums.get(value)
            if flags is None:
                flags = flag_enums[value] = SampleFlags(value)
        est = update(ImuSample(t_list[i], gyro_rad_s[i], accel_m_s2[i], mag_ut[i], nan, nan, flags, 0, i))
        if est.roll_rad == est.roll_rad:   # initialised (not NaN)
            q0, q1, q2, q3 = est.q_wxyz.tolist()
        else:
            q0 = q1 = q2 = q3 = nan
        s0, s1, s2 = est.sigma_rpy_rad.tolist()
        b0, b1, b2 = est.gyro_bias_rad_s.tolist()
        append((t_list[i], q0, q1, q2, q3, est.roll_rad * deg, est.pitch_rad * deg, est.yaw_rad * deg,
                  est.heading_mag_rad * deg, est.heading_true_rad * deg, s0 * deg, s1 * deg, s2 * deg,
                  b0, b1, b2, int(est.flags)))
    table = np.array(rows, dtype=np.float64).reshape(n, len(OUTPUT_COLUMNS))
    from ahrsd.estimator.rotations import quat_multiply, wrap_pi

    yaw = np.radians(table[:, 7])
    if true_north:
        decl = np.radians(table[:, 9] - table[:, 8])          # per row: the declination in force
        decl = np.where(np.isfinite(decl), decl, 0.0)
        rot_z = np.column_stack([np.cos(decl / 2), np.zeros(n), np.zeros(n), np.sin(decl / 2)])
        q = quat_multiply(rot_z, table[:, 1:5])
        table[:, 1:5] = q * np.where(q[:, :1] < 0, -1.0, 1.0)
        yaw = yaw + decl
    table[:, 7] = np.degrees(wrap_pi(yaw))                      # [−180, 180)
    return table


def write_output(path: str, table) -> None:
    """Write the output CSV (header OUTPUT_HEADER); '-' writes to stdout."""
    import sys

    import numpy as np

    if path == "-":
        np.savetxt(sys.stdout, table, fmt=_FORMAT, header=OUTPUT_HEADER, comments="")
        return
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        np.savetxt(f, table, fmt=_FORMAT, header=OUTPUT_HEADER, comments="")


def run(args) -> int:
    import sys

    try:
        return _run(args)
    except ReplayError as exc:
        print(f"ahrsd replay: error: {exc}", file=sys.stderr)
        return 1


def _run(args) -> int:
    import math
    import sys
    import time

    import numpy as np

    from ahrsd.drivers.recording import RecordingFormatError, read_recording
    from ahrsd.estimator import make_estimator

    t_start = time.perf_counter()
    cpu_start = time.process_time()
    params = _parse_params(args.params)
    declination = _declination_rad(args)

    # Recording (header checked, non-numeric or short rows named by line number).
    try:
        rec = read_recording(args.recording)
    except FileNotFoundError:
        raise ReplayError(f"{args.recording}: no such file") from None
    except IsADirectoryError:
        raise ReplayError(f"{args.recording}: is a directory, not a recording") from None
    except UnicodeDecodeError:
        raise ReplayError(f"{args.recording}: not a text (UTF-8) CSV file") from None
    except RecordingFormatError as exc:
        raise ReplayError(str(exc)) from None
    except OSError as exc:
        raise ReplayError(f"{args.recording}: cannot read: {exc.strerror or exc}") from None
    n = len(rec)
    if n == 0:
        raise ReplayError(f"{args.recording}: the recording has a header but no samples")
    if not np.all(np.isfinite(rec.t_s)):
        bad = int(np.flatnonzero(~np.isfinite(rec.t_s))[0])
        raise ReplayError(f"{args.recording}: line {bad + 2}: t_s is not a finite number")

    # Calibration (identity without a file), applied with the same equations as Calibration.apply.
    gyro, accel, mag = rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut
    if args.calibration:
        from ahrsd.calibration.store import CalibrationFileError, load_calibration_file

        try:
            cal = load_calibration_file(args.calibration)
        except CalibrationFileError as exc:
            raise ReplayError(str(exc)) from None
        if not cal.is_identity:
            gyro, accel, mag = (np.ascontiguousarray(v) for v in cal.apply_arrays(gyro, accel, mag))

    try:
        estimator = make_estimator(args.estimator, declination_rad=declination, **params)
    except ModuleNotFoundError as exc:
        raise ReplayError(f"estimator {args.estimator!r} is not available ({exc})") from None
    except (TypeError, ValueError) as exc:
        raise ReplayError(f"estimator {args.estimator!r}: {exc}") from None

    flags = rec.extra.get("flags")
    if flags is not None:
        flags = np.where(np.isfinite(flags), flags, 0).astype(np.int64)
    t_run = time.process_time()
    table = replay_arrays(estimator, rec.t_s, gyro, accel, mag, flags, true_north=args.lat is not None)
    t_est = time.process_time() - t_run
    try:
        write_output(args.output, table)
    except OSError as exc:
        raise ReplayError(f"{args.output}: cannot write: {exc.strerror or exc}") from None
    wall = time.perf_counter() - t_start
    cpu = time.process_time() - cpu_start

    if not args.quiet:
        duration = float(rec.t_s[-1] - rec.t_s[0]) if n > 1 else 0.0
        rate = rec.sample_rate_hz
        if n > 1 and math.isfinite(rate) and rate > 0:
            duration += 1.0 / rate
        speed = duration / wall if wall > 0 else math.inf
        cpu_speed = duration / cpu if cpu > 0 else math.inf
        where = ("magnetic north (no position)" if args.lat is None
                 else f"true north, declination {math.degrees(declination):+.2f}°")
        print(f"ahrsd replay: {n} samples ({duration:.1f} s at {rate:.1f} Hz) through {args.estimator}, "
              f"heading to {where}; {wall:.2f} s wall ({t_est * 1e6 / n:.1f} CPU µs/sample in the estimator loop): "
              f"{speed:.1f}× real time ({cpu_speed:.1f}× per CPU second)", file=sys.stderr)
    return 0

"""`ahrsd log {list,cut}`: what the on-vehicle logs hold, and a time window of them cut into one recording.

    ahrsd log list [--dir DIR] [--json]
    ahrsd log cut --from TIME --to TIME --output REC.csv [--dir DIR] [--quiet]

The logs are drivers/sample_log.py's `imu-*.csv.gz` files, drivers/gnss/log.py's `gnss-*.gnss.csv.gz` (every
GNSS fix delivered, accepted or rejected), drivers/tlog.py's `mavlink-*.tlog` (the MAVLink traffic; listed, not
cut: MAVProxy, MAVExplorer and pymavlink read it as it is) and their `.json` sidecars. TIME is ISO-8601
(`2026-12-01T10:42:00`, UTC unless it carries an offset; mapped to sample times through each file's sidecar)
or a number of seconds on the samples' own clock (the t_s column, as `log list` shows it). The cut is a
plain recording (`.csv`, or `.csv.gz` by its name) that `replay` and `calibrate` take as it is; when the
samples were logged calibrated, a comment line in it and `<output>.json` say which calibration was in force.
With GNSS logs in the directory, the fixes over the cut's span go to `REC.gnss.csv` beside it (the GNSS
recording format: `ahrsd run --replay REC.csv --gnss-replay REC.gnss.csv` replays both).
Exit status: 0 done, 1 nothing to cut or bad input, 2 bad usage.
"""

from __future__ import annotations

LOG_DIR_HELP = ("log directory (default: logs/ in the state directory `ahrsd run` uses when given none: "
                "$STATE_DIRECTORY, else /var/lib/ahrsd, the service's, when it exists and is writable, else "
                "~/.local/state/ahrsd)")
_SMALLEST_LOG_BYTES = 30   # a gzip header and a flushed CSV header take more than this


def register(subparsers) -> None:
    p = subparsers.add_parser("log", help="list the on-vehicle logs; cut a time window into a recording",
                              description="List the sample logs the service keeps (rotating .csv.gz files with "
                              "JSON sidecars) and cut a time window of them into one plain recording.")
    sub = p.add_subparsers(dest="log_command", metavar="ACTION", required=True)
    ls = sub.add_parser("list", help="the logged files: time span, samples, size, calibration in force")
    ls.add_argument("--dir", default=None, metavar="DIR", help=LOG_DIR_HELP)
    ls.add_argument("--json", action="store_true", help="one JSON object per file, one per line")
    ls.set_defaults(func=run)
    cut = sub.add_parser("cut", help="cut [--from, --to] of the logs into one recording (CSV)")
    cut.add_argument("--dir", default=None, metavar="DIR", help=LOG_DIR_HELP)
    cut.add_argument("--from", dest="t_from", required=True, metavar="TIME",
                     help="start: ISO-8601 (UTC unless an offset is given) or seconds of sample time (t_s)")
    cut.add_argument("--to", dest="t_to", required=True, metavar="TIME", help="end (same forms as --from)")
    cut.add_argument("--output", "-o", required=True, metavar="REC.csv", help="the recording to write (.csv or .csv.gz)")
    cut.add_argument("--quiet", "-q", action="store_true", help="no summary and no progress bar on stderr")
    cut.set_defaults(func=run)


class LogError(Exception):
    """Bad input or nothing to cut: one line on stderr, exit status 1."""


def run(args) -> int:
    import sys

    if args.dir is None:                # as [log] dir = "": <state dir>/logs (daemon.config)
        from ahrsd.core.state_dir import default_state_dir

        args.dir = str(default_state_dir() / "logs")
    try:
        return _list(args) if args.log_command == "list" else _cut(args)
    except LogError as exc:
        print(f"ahrsd log {args.log_command}: error: {exc}", file=sys.stderr)
        return 1


# ---------------------------------------------------------------------------------------------- the files


def _log_files(directory: str, kind: str = "samples") -> list[tuple]:
    """[(path, sidecar dict)] of the sample logs (kind "samples"), GNSS logs ("gnss") or MAVLink logs ("tlog")
    in `directory`, oldest first."""
    import json
    from pathlib import Path

    from ahrsd.core.state_dir import SERVICE_STATE_DIR
    from ahrsd.drivers.gnss.log import GNSS_LOG_PREFIX, GNSS_LOG_SUFFIX
    from ahrsd.drivers.rotating_log import SIDECAR_SUFFIX
    from ahrsd.drivers.sample_log import SAMPLE_LOG_PREFIX, SAMPLE_LOG_SUFFIX
    from ahrsd.drivers.tlog import TLOG_PREFIX, TLOG_SUFFIX

    d = Path(directory)
    if not d.is_dir():
        by_hand = ("`ahrsd run` started by hand keeps logs only with [log] enabled = true (then in <state dir>/logs, "
                   "where this looks by default) or --log-dir DIR (give that as --dir)")
        service_logs = SERVICE_STATE_DIR / "logs"
        where = (f"the service keeps its logs there once it has run; {by_hand}" if d == service_logs
                 else f"the service's is {service_logs}; {by_hand}")
        raise LogError(f"{directory}: no such log directory ({where})")
    prefix, suffix = {"samples": (SAMPLE_LOG_PREFIX, SAMPLE_LOG_SUFFIX), "gnss": (GNSS_LOG_PREFIX, GNSS_LOG_SUFFIX),
                      "tlog": (TLOG_PREFIX, TLOG_SUFFIX)}[kind]
    out = []
    for path in sorted(d.glob(f"{prefix}-*{suffix}")):
        try:
            side = json.loads(path.with_name(path.name + SIDECAR_SUFFIX).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            side = {}   # a file without a readable sidecar still lists and cuts (on sample time only)
        out.append((path, side))
    return out


def _span_unix(side: dict) -> tuple[float | None, float | None]:
    off = side.get("unix_minus_t_s")
    if off is None or "t_first_s" not in side:
        return None, None
    return side["t_first_s"] + off, side.get("t_last_s", side["t_first_s"]) + off


def _iso(unix_s: float | None) -> str:
    import datetime as dt

    if unix_s is None:
        return "?"
    return dt.datetime.fromtimestamp(unix_s, dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _iso_text(text: str | None) -> str | None:
    """A sidecar's ISO time (`2026-12-05T20:31:34.124451Z`) to the second, as `_iso` writes it."""
    return None if not text else text.split(".")[0].rstrip("Z") + "Z"


def _calibration_label(side: dict) -> str:
    if not side.get("calibrated"):
        return "raw (uncalibrated)"
    cal = side.get("calibration") or {}
    parts = [str(cal[k]) for k in ("checksum", "method", "date") if cal.get(k)]
    return "calibrated: " + (", ".join(parts) if parts else "calibration not recorded")


def _list(args) -> int:
    import json

    files = _log_files(args.dir)
    if not files:
        raise LogError(f"{args.dir}: no sample logs (imu-*.csv.gz) there")
    gnss_files = _log_files(args.dir, "gnss")
    total = 0
    for path, side in files:
        size = path.stat().st_size
        total += size
        first, last = _span_unix(side)
        if args.json:
            print(json.dumps({"kind": "samples", "file": str(path), "size_bytes": size, "start_utc": None if first is None else _iso(first),
                              "end_utc": None if last is None else _iso(last), "t_first_s": side.get("t_first_s"),
                              "t_last_s": side.get("t_last_s"), "samples": side.get("entries"),
                              "closed": side.get("closed", False), "calibrated": bool(side.get("calibrated")),
                              "calibration": side.get("calibration")}, sort_keys=True))
            continue
        state = "" if side.get("closed") else " (open, or cut by a crash)"
        t = (f"t_s {side['t_first_s']:.1f}…{side.get('t_last_s', float('nan')):.1f}" if "t_first_s" in side else "t_s ?")
        print(f"{path.name}  {_iso(first)} → {_iso(last)}  {t}  {side.get('entries', '?')} samples  "
              f"{size / 1e6:.2f} MB  {_calibration_label(side)}{state}")
    for path, side in gnss_files:
        size = path.stat().st_size
        total += size
        first, last = _span_unix(side)
        if args.json:
            print(json.dumps({"kind": "gnss", "file": str(path), "size_bytes": size,
                              "start_utc": None if first is None else _iso(first),
                              "end_utc": None if last is None else _iso(last), "t_first_s": side.get("t_first_s"),
                              "t_last_s": side.get("t_last_s"), "fixes": side.get("entries"),
                              "closed": side.get("closed", False)}, sort_keys=True))
            continue
        state = "" if side.get("closed") else " (open, or cut by a crash)"
        t = (f"t_s {side['t_first_s']:.1f}…{side.get('t_last_s', float('nan')):.1f}" if "t_first_s" in side else "t_s ?")
        print(f"{path.name}  {_iso(first)} → {_iso(last)}  {t}  {side.get('entries', '?')} GNSS fixes (accepted "
              f"and rejected)  {size / 1e6:.2f} MB{state}")
    tlog_files = _log_files(args.dir, "tlog")
    for path, side in tlog_files:
        size = path.stat().st_size
        total += size
        # frames are stamped with the wall clock (drivers/tlog.py): the span is the file's opening and closing
        start, end = side.get("opened_utc"), side.get("closed_utc")
        if args.json:
            print(json.dumps({"kind": "tlog", "file": str(path), "size_bytes": size,
                              "start_utc": _iso_text(start), "end_utc": _iso_text(end),
                              "messages": side.get("entries"), "closed": side.get("closed", False)}, sort_keys=True))
            continue
        state = "" if side.get("closed") else " (open, or cut by a crash)"
        print(f"{path.name}  {_iso_text(start) or '?'} → {_iso_text(end) or '?'}  {side.get('entries', '?')} MAVLink "
              f"messages in and out  {size / 1e6:.2f} MB{state}")
    if not args.json:
        extra = ", ".join(f"{n} of {what}" for n, what in ((len(gnss_files), "GNSS fixes"),
                                                           (len(tlog_files), "MAVLink traffic")) if n)
        print(f"{len(files) + len(gnss_files) + len(tlog_files)} files{f' ({extra})' if extra else ''}, "
              f"{total / 1e6:.1f} MB in {args.dir}")
    return 0


# ---------------------------------------------------------------------------------------------- the cut


def parse_time(text: str) -> tuple[str, float]:
    """('unix', s) for ISO-8601 (UTC unless an offset is given), ('t', s) for a plain number of seconds."""
    import datetime as dt
    import math

    try:
        value = float(text)
    except ValueError:
        pass
    else:
        if not math.isfinite(value):
            raise LogError(f"{text!r}: not a finite number of seconds")
        return "t", value
    try:
        when = dt.datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise LogError(f"{text!r}: expected ISO-8601 (2026-12-01T10:42:00, UTC unless an offset is given) or "
                       "seconds of sample time") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.timezone.utc)
    return "unix", when.timestamp()


def _window_in_t(kind_value, side: dict) -> float | None:
    kind, value = kind_value
    if kind == "t":
        return value
    off = side.get("unix_minus_t_s")
    return None if off is None else value - off


def _cut(args) -> int:
    import json
    import sys

    t_from, t_to = parse_time(args.t_from), parse_time(args.t_to)
    if t_from[0] == t_to[0] and t_to[1] <= t_from[1]:
        raise LogError(f"--to {args.t_to} is not after --from {args.t_from}")
    chosen = _logs_in_window(args, t_from, t_to)
    _check_one_calibration(chosen)
    side0 = chosen[0][1]
    count, first_t, last_t = _write_cut(args, chosen, side0)
    meta = {"source": "ahrsd log cut", "from": args.t_from, "to": args.t_to, "files": [p.name for p, _, _, _ in chosen],
            "samples": count, "t_first_s": first_t, "t_last_s": last_t, "calibrated": bool(side0.get("calibrated")),
            "calibration": side0.get("calibration")}
    if "unix_minus_t_s" in side0:
        meta["unix_minus_t_s"] = side0["unix_minus_t_s"]
    gnss = _cut_gnss(args.dir, args.output, first_t, last_t)
    if gnss is not None:
        meta["gnss"] = gnss
    with open(f"{args.output}.json", "w", encoding="utf-8") as f:
        json.dump(meta, f, indent=1, sort_keys=True)
        f.write("\n")
    if not args.quiet:
        print(f"ahrsd log cut: {count} samples, t_s {first_t:.3f}…{last_t:.3f} ({last_t - first_t:.1f} s) from "
              f"{len(chosen)} file(s) into {args.output}; samples {_calibration_label(side0)}", file=sys.stderr)
        if gnss is not None:
            print(f"ahrsd log cut: {gnss['fixes']} GNSS fixes ({gnss['rejected']} rejected live) into "
                  f"{gnss['file']}", file=sys.stderr)
    return 0


def _logs_in_window(args, t_from, t_to) -> list[tuple]:
    """The sample logs of args.dir that overlap the window: (path, sidecar, window start and end in their
    t_s); a log whose sidecar cannot map an ISO-8601 window is skipped with a note. LogError when none."""
    import math
    import sys

    chosen = []
    for path, side in _log_files(args.dir):
        lo, hi = _window_in_t(t_from, side), _window_in_t(t_to, side)
        if lo is None or hi is None:
            print(f"ahrsd log cut: {path.name}: its sidecar has no time mapping; skipped for an ISO-8601 window "
                  "(give --from/--to in seconds of sample time to include it)", file=sys.stderr)
            continue
        first, last = side.get("t_first_s", -math.inf), side.get("t_last_s", math.inf)
        if last >= lo and first <= hi:
            chosen.append((path, side, lo, hi))
    if not chosen:
        raise LogError(f"no logged samples between {args.t_from} and {args.t_to} in {args.dir} "
                       "(`ahrsd log list` shows what is there)")
    return chosen


def _check_one_calibration(chosen: list[tuple]) -> None:
    """One recording holds samples of one calibration: LogError when the chosen logs' calibrated samples
    disagree (raw samples do not depend on the calibration the daemon had in force)."""
    import json

    calibrations = {json.dumps([bool(s.get("calibrated")), s.get("calibration") if s.get("calibrated") else None],
                               sort_keys=True) for _, s, _, _ in chosen}
    if len(calibrations) > 1:
        changes = "; ".join(f"{p.name}: {_calibration_label(s)}" for p, s, _, _ in chosen)
        raise LogError(f"the window spans more than one calibration ({changes}): cut it where the calibration "
                       "changed, one recording per calibration")


def _write_cut(args, chosen: list[tuple], side0: dict) -> tuple[int, float, float]:
    """The window's samples into args.output (written under a temporary name, renamed when complete):
    (samples, first and last t_s). LogError when there are none or the files fail."""
    import math
    import os

    from ahrsd.drivers.recording import SAMPLE_COLUMNS, RecordingFormatError, RecordingWriter, iter_samples

    from .output_target import renamed_into_place
    from .progress import progress_bar

    expected = sum(s.get("entries", 0) for _, s, _, _ in chosen) or None
    count, first_t, last_t = 0, math.nan, math.nan
    head, base = os.path.split(args.output)
    tmp = os.path.join(head, f".{base}.part" + (".gz" if base.endswith(".gz") else ""))   # renamed when complete
    if not renamed_into_place(args.output):
        tmp = args.output                   # a device or FIFO: written through, never replaced
    try:
        with RecordingWriter(tmp, extra_columns=SAMPLE_COLUMNS) as out, \
                progress_bar(args.quiet, expected, "log cut") as bar:
            note = (f"ahrsd log cut {args.t_from} .. {args.t_to} from {', '.join(p.name for p, _, _, _ in chosen)}; "
                    f"samples {_calibration_label(side0)}")
            out.comment(note)
            for path, side, lo, hi in chosen:
                if side.get("entries") == 0 or path.stat().st_size < _SMALLEST_LOG_BYTES:
                    continue   # killed within its opening: not even a header to read
                for sample in iter_samples(path, strict=False):
                    bar.update()
                    if lo <= sample.t_s <= hi:
                        out.write(sample)
                        if count == 0:
                            first_t = sample.t_s
                        last_t = sample.t_s
                        count += 1
        if count == 0:
            raise LogError(f"no logged samples between {args.t_from} and {args.t_to} (the files around it: "
                           f"{', '.join(p.name for p, _, _, _ in chosen)})")
        if tmp != args.output:
            os.replace(tmp, args.output)
    except (OSError, RecordingFormatError) as exc:
        raise LogError(f"{getattr(exc, 'filename', None) or args.output}: {getattr(exc, 'strerror', None) or exc}") from None
    finally:
        if tmp != args.output and os.path.exists(tmp):
            os.unlink(tmp)
    return count, first_t, last_t


def _cut_gnss(directory: str, output: str, first_t: float, last_t: float) -> dict | None:
    """The logged GNSS fixes with t_s in [first_t, last_t] (the samples' span of the cut), accepted and rejected
    as they came, into the GNSS recording beside `output`; what it holds, or None without GNSS logs."""
    import math
    import os
    import sys

    from ahrsd.drivers.gnss.log import GNSS_LOG_EXTRA_COLUMNS, REJECTION_CODES
    from ahrsd.drivers.gnss.recording import (GnssRecordingFormatError, GnssRecordingWriter, gnss_path_for,
                                              iter_gnss_fixes)

    logged = _log_files(directory, "gnss")
    if not logged:
        return None
    files = [(p, s) for p, s in logged if s.get("t_last_s", math.inf) >= first_t and s.get("t_first_s", -math.inf) <= last_t]
    target = gnss_path_for(output)
    tmp = target.with_name(f".{target.name}.part" + (".gz" if target.name.endswith(".gz") else ""))
    fixes = rejected = 0
    try:
        with GnssRecordingWriter(tmp, extra_columns=GNSS_LOG_EXTRA_COLUMNS) as out:
            for path, side in files:
                if side.get("entries") == 0 or path.stat().st_size < _SMALLEST_LOG_BYTES:
                    continue
                try:
                    for fix in iter_gnss_fixes(path, source="log"):
                        if first_t <= fix.t_s <= last_t:
                            out.write(fix)
                            fixes += 1
                            rejected += fix.extra.get("rejection", 0.0) != 0.0
                except GnssRecordingFormatError as exc:   # a file cut by a crash: what it held up to there
                    print(f"ahrsd log cut: {exc}; the fixes before it are kept", file=sys.stderr)
        os.replace(tmp, target)
    except OSError as exc:
        raise LogError(f"{exc.filename or target}: {exc.strerror or exc}") from None
    finally:
        if tmp.exists():
            tmp.unlink()
    return {"file": str(target), "files": [p.name for p, _ in files], "fixes": fixes, "rejected": rejected,
            "rejection_codes": REJECTION_CODES}

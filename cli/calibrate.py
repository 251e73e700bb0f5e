"""`ahrsd calibrate {allan,accel,gyro,mag}`: bench calibrations from a recording (or, for accel, live).

Each fit is written through the calibration store (merged with the stored calibration's other sensors) unless
it was refused or `--dry-run` is given. Output is for a person, or with `--json` one JSON object whose keys
are a public interface (docs/calibration.md):
  mag:   hard_iron_ut [3], soft_iron [3][3], residual_rms_ut      calibrated = soft_iron · (raw − hard_iron)
         (+ quality.heading_reference: the deviation card A..E when a heading reference was given; A is folded
         into soft_iron, B..E are reported only; reference_site: where the reference field was taken, and why)
  accel: bias_m_s2 [3], matrix [3][3]                             calibrated = matrix · (raw − bias) (+ quadratic)
  gyro:  bias_rad_s [3], matrix [3][3]                            calibrated = matrix · (raw − bias)
  allan: <sensor>.<axis>.white_noise, .bias_instability (+ kalman Q/R)
Exit status: 0 fitted (and saved), 1 refused or failed, 2 bad usage (including --plot without matplotlib,
matplotlib, the optional `plot` extra: checked before anything is fitted or saved).
"""

from __future__ import annotations

import dataclasses


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "calibrate",
        help="bench calibration: Allan noise analysis, accelerometer, gyro and magnetometer fits",
        description="Fit a sensor's error model to a recording (see `ahrsd record`) and store it in the state "
        "directory (atomic, checksummed, previous version kept).",
    )
    sub = p.add_subparsers(dest="sensor", metavar="SENSOR", required=True)
    a = sub.add_parser("allan", help="Allan-variance noise analysis of a static recording (ARW/VRW, bias "
                       "instability, Kalman Q/R); writes noise.json to the state directory")
    _common_options(a, saves_calibration=False)
    _register_accel(sub)
    _register_gyro(sub)
    _register_mag(sub)


def _common_options(sp, recording_required=True, saves_calibration=True) -> None:
    """The options every sensor's calibration takes (and the recording, unless it may be live); --force for those
    that save calibration.json (the daemon's: Allan's noise.json it never reads)."""
    if recording_required:
        sp.add_argument("recording", metavar="RECORDING", help="CSV recording (ahrsd record)")
    sp.add_argument("--state-dir", metavar="DIR", default=None,
                    help="where the calibration is stored (default, as `ahrsd run`: $STATE_DIRECTORY, else "
                    "/var/lib/ahrsd, the service's, when it exists and is writable, else ~/.local/state/ahrsd)")
    sp.add_argument("--json", action="store_true", help="print one JSON object instead of a report")
    sp.add_argument("--plot", metavar="FILE.png", help="write a plot (needs matplotlib: pip install matplotlib, or install "
                    "ahrsd with -e '.[plot]')")
    sp.add_argument("--dry-run", action="store_true", help="fit and report, but do not save")
    if saves_calibration:
        sp.add_argument("--force", action="store_true",
                        help="save even while a running ahrsd holds the state directory (it uses the new calibration "
                        "only after a restart, and saves its own over it if it accepts a magnetometer calibration first)")
    sp.add_argument("--sensor-id", default=None, help="sensor serial or id to record in the metadata")
    sp.set_defaults(func=run)


def _register_accel(sub) -> None:
    c = sub.add_parser("accel", help="multi-position accelerometer calibration (12 parameters) from the still "
                       "periods of a recording, or live (--live) with operator guidance")
    c.add_argument("recording", metavar="RECORDING", nargs="?", help="CSV recording (omit with --live)")
    _common_options(c, recording_required=False)
    c.add_argument("--lat", type=float, default=None, help="latitude (deg) for local gravity (default: none, standard gravity 9.80665 m/s²)")
    c.add_argument("--alt-m", type=float, default=0.0, help="height above the ellipsoid (m) for local gravity")
    c.add_argument("--terms", default="auto", choices=("auto", "6", "9", "12"),
                   help="model size: 12 = bias, scale, misalignment, quadratic (thesis)")
    c.add_argument("--min-still-s", type=float, default=2.0,
                   help="shortest still period used as a position, s (default 2: holds of 2 s or more)")
    c.add_argument("--align-to-faces", action="store_true",
                   help="also align the calibration to the unit's housing: it must have rested flat on each of its "
                   "six faces on a surface levelled to about 0.02° (docs/calibration.md)")
    c.add_argument("--live", action="store_true", help="guided live calibration from the sensor")
    c.add_argument("--sim", metavar="SCENARIO", help="with --live: the simulated chip running this scenario "
                   "(accel-positions: the guided positions of a six-face calibration)")
    c.add_argument("--spi", metavar="DEV", help="with --live: the real ADIS16405 on this spidev node")
    c.add_argument("--timeout-s", type=float, default=900.0, help="with --live: give up after this long")


def _register_gyro(sub) -> None:
    g = sub.add_parser("gyro", help="rate-table gyro calibration (12 parameters) or bias only")
    _common_options(g)
    g.add_argument("--bias-only", action="store_true", help="bias from the still periods (no rate table)")
    g.add_argument("--estimator-bias", action="store_true",
                   help="with --bias-only: run the estimator over the recording and add its converged gyro bias "
                   "(the filter's bias is folded back into the calibration)")
    g.add_argument("--table-rate-deg-s", type=float, default=None,
                   help="the rate table's rate (table axis vertical); default: the recording's truth columns")


def _register_mag(sub) -> None:
    m = sub.add_parser("mag", help="magnetometer calibration (ellipsoid, two-step, three-step, backstepping)")
    _common_options(m)
    m.add_argument("--lat", type=float, default=None,
                   help="latitude (deg) of the calibration site, for the reference field (WMM2025); with --gnss "
                   "the default is the median position of the recording's fixes")
    m.add_argument("--lon", type=float, default=None, help="longitude (deg), given with --lat")
    m.add_argument("--alt-m", type=float, default=None,
                   help="height above the ellipsoid (m); default 0, with --gnss and no --lat/--lon the fixes' median")
    m.add_argument("--date", default=None, help="YYYY-MM-DD (default today)")
    m.add_argument("--method", default="ellipsoid", choices=("ellipsoid", "two-step", "three-step", "backstepping"),
                   help="fit (default: ellipsoid, needs a tumble; backstepping for a vehicle that cannot be "
                   "tumbled)")
    m.add_argument("--align-recording", metavar="FILE", default=None,
                   help="three-step: a recording of levelled turns about each axis for the alignment step")
    m.add_argument("--heading-ref-delay-s", type=float, default=0.0, metavar="S",
                   help="backstepping: latency of the recording's heading_ref_deg column (GNSS course: ~2 s)")
    m.add_argument("--swing-table", metavar="FILE", default=None,
                   help="compass-swing table (CSV reference_deg,compass_deg; compass = the heading this "
                   "calibration gives): fit the deviation card A..E, fold the constant offset A into the soft "
                   "iron, report B..E")
    m.add_argument("--gnss", metavar="GNSS.csv", default=None,
                   help="backstepping: a GNSS recording of the run (REC.gnss.csv): level with the GNSS-aided "
                   "attitude (ins) instead of the accelerometer")
    m.add_argument("--gnss-course", action="store_true",
                   help="with --gnss: also take the heading offset from the GNSS course on straight tracks above "
                   "2 m/s (course = heading + crab: only without current, leeway or crosswind; docs/gnss.md)")
    m.add_argument("--accel-bias-sigma-mg", type=float, default=None, metavar="MG",
                   help="with --gnss: how well the accelerometer bias is known, 1σ in mg (default: 2 with an "
                   "accelerometer calibration in the state directory, else the aided filter's 10)")
    m.add_argument("--lever-arm-m", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="with --gnss: the GNSS antenna's position relative to the IMU, body FRD (x forward, y right, "
                   "z down), m, as the daemon's [gnss] lever_arm_m (default 0 0 0)")


# ---------------------------------------------------------------------------------------------- helpers


class _Fail(Exception):
    """A reported failure: message for the person, exit status 1."""


class _Usage(_Fail):
    """Bad usage (an option that cannot work as given): message for the person, exit status 2."""


def _plot_needs_matplotlib() -> str:
    from ahrsd.core.plotting import PLOT_INSTALL_HINT

    return f"--plot needs matplotlib: {PLOT_INSTALL_HINT}"


_RECORDING_META: dict = {}


def _read(path, quiet: bool = True):
    """The recording at `path`; unless `quiet` (the command's --json; by default), a progress bar while it is
    read."""
    import os

    from ahrsd.drivers.recording import RecordingFormatError, read_recording

    from .progress import expected_rows, progress_bar

    try:
        with progress_bar(quiet, expected_rows(path), f"reading {os.path.basename(path)}") as bar:
            rec = read_recording(path, strict=False, on_rows=bar.update)   # a file cut mid-row: its complete rows
    except FileNotFoundError:
        raise _Fail(f"{path}: no such file") from None
    except (RecordingFormatError, ValueError, OSError) as exc:
        raise _Fail(f"cannot read the recording: {exc}") from None
    if len(rec) < 16:
        raise _Fail(f"{path}: only {len(rec)} samples, too few for any fit: record longer (at least a few seconds)")
    if not _RECORDING_META:  # the first recording read is the one the fit is about: note it in the metadata
        import numpy as np

        _RECORDING_META["recording"] = str(path)
        temp = rec.extra.get("temp_c")
        if temp is not None and np.any(np.isfinite(temp)):
            _RECORDING_META["temp_c"] = float(np.nanmean(temp))
    return rec


def _save(args, sensor, model, meta):
    """Merge into the stored calibration and save; returns (path or None, note)."""
    from ahrsd.calibration.store import CalibrationStore

    if args.dry_run:
        return None, "not saved (--dry-run)"
    store = CalibrationStore(args.state_dir)
    current = store.load()
    cal = current.with_sensor(sensor, model, **{**_RECORDING_META, **meta})
    if args.sensor_id:
        cal = type(cal)(cal.gyro, cal.accel, cal.mag, {**cal.metadata, "sensor_id": args.sensor_id})
    try:
        path = store.save(cal)
    except OSError as exc:
        raise _Fail(f"cannot save to {args.state_dir}: {exc.strerror or exc}") from None
    last_load = store.last_load
    if last_load is None or last_load.source == "identity":
        base = "no earlier calibration"
    else:
        base = f"the other sensors of {last_load.path}"
    kept = (f"the previous file is kept as {store.previous_path.name}" if store.previous_path.exists()
            else "there was no previous file")
    return path, f"saved to {path} (merged with {base}; {kept})"


def _emit(args, payload: dict, text: str) -> None:
    import json

    from ahrsd.calibration.models import _jsonable

    if args.json:
        print(json.dumps(_jsonable(payload), sort_keys=True))
    else:
        print(text)


def _stored(args):
    from ahrsd.calibration.store import CalibrationStore

    return CalibrationStore(args.state_dir).load()


def _gaps(rec):
    """The recording's gaps (calibration.recording_gaps): from its counter column when it has one, else t_s."""
    from ahrsd.calibration.recording_gaps import find_gaps

    return find_gaps(rec.t_s, rec.extra.get("counter"))


def _judged_on_gaps(res, gaps, integrating: str | None):
    """The one gap check of every fit from a recording. A fit that relates samples across time (`integrating`
    says what it does, for the message) is refused when the longest gap is above
    recording_gaps.MAX_GAP_INTEGRATING_S (identity model, the fitted one under quality['rejected_model']); a fit
    that averages (integrating None) keeps its result. Either way the caller reports the gaps (_gap_report)."""
    from ahrsd.calibration.recording_gaps import integrating_refusal

    refusal = integrating_refusal(gaps, integrating) if integrating and res.ok else None
    if refusal is None:
        return res
    return dataclasses.replace(res, model=type(res.model).identity(), refused=refusal,
                               quality={**res.quality, "rejected_model": res.model.to_dict()})


def _gap_report(payload: dict, lines: list, gaps, under_title: bool = True) -> None:
    """The gaps in the --json object (key `gaps`) and as a report line under the title, or last (`under_title`
    False: the Allan report leads with the data sheet's figures, docs/calibration.md)."""
    payload["gaps"] = gaps.to_json_dict()
    line = "  " + gaps.describe()
    if under_title:
        lines.insert(1, line)
    else:
        lines.append(line)


# ---------------------------------------------------------------------------------------------- commands


def _allan(args) -> int:
    import os

    from ahrsd.calibration.allan.analysis import NOISE_FILE_NAME, StaticAllanAnalysis, describe, save_noise_parameters
    from ahrsd.calibration.recording_gaps import GapCounter
    from ahrsd.drivers.recording import RecordingFormatError, iter_recording_chunks

    from .progress import activity, expected_rows, progress_bar

    try:   # streamed: one chunk of the recording in memory at a time (.csv or .csv.gz)
        analysis = StaticAllanAnalysis()
        gap_counter = GapCounter()    # Allan averages: gaps are reported, not refused (recording_gaps)
        with progress_bar(args.json, expected_rows(args.recording), f"reading {os.path.basename(args.recording)}") as bar:
            for chunk in iter_recording_chunks(args.recording, strict=False):
                analysis.add(chunk.t_s, chunk.gyro_rad_s, chunk.accel_m_s2, chunk.mag_ut)
                gap_counter.add(chunk.t_s, chunk.extra.get("counter"))
                bar.update(len(chunk))
        with activity(args.json, "Allan analysis"):
            res = analysis.result()
    except FileNotFoundError:
        raise _Fail(f"{args.recording}: no such file") from None
    except (RecordingFormatError, OSError) as exc:
        raise _Fail(f"cannot read the recording: {exc}") from None
    except ValueError as exc:
        raise _Fail(str(exc)) from None
    payload = res.to_json_dict()
    note = "not saved (--dry-run)"
    if not args.dry_run:
        from pathlib import Path

        try:
            path = save_noise_parameters(res, Path(args.state_dir) / NOISE_FILE_NAME)
        except OSError as exc:
            raise _Fail(f"cannot save to {args.state_dir}: {exc.strerror or exc}") from None
        note = f"saved to {path}"
        payload["saved_to"] = str(path)
    if args.plot:
        from ahrsd.cli.plots.allan import plot_allan

        _write_plot(args, plot_allan, res)
    from ahrsd.calibration.allan.analysis import summary

    length = f"{res.duration_s / 3600:.2f} h" if res.duration_s >= 360 else f"{res.duration_s:.1f} s"
    lines = [f"Allan analysis of {args.recording}: {length} at {res.rate_hz:.1f} Hz; noise "
             f"parameters {note}"]
    lines += summary(res)
    _gap_report(payload, lines, gap_counter.result(), under_title=False)
    lines += ["  details:"] + ["  " + line for line in describe(res)]
    _emit(args, payload, "\n".join(lines))
    return 0


def _accel(args) -> int:
    import numpy as np

    from ahrsd.calibration import report
    from ahrsd.calibration.inertial.accel import local_gravity_m_s2

    g = local_gravity_m_s2(args.lat, args.alt_m)
    res, source, gaps = _accel_fit(args, g)
    payload = {"sensor": "accel", **res.to_json_dict(), "positions_source": source}
    lines = [f"Accelerometer calibration ({res.terms} parameters) from {source}; g = {g:.5f} m/s²"
             + ("" if args.lat is not None else " (standard gravity: give --lat for local gravity)")]
    if gaps is not None:     # the still periods' means average: gaps are reported, not refused
        _gap_report(payload, lines, gaps)
    q = res.quality
    lines.append(f"  distinct orientations: {q.get('distinct_orientations')}; faces up: "
                 + ", ".join(k for k, v in q.get("faces", {}).items() if v))
    if "holds" in q:
        lines.append(report.accel_holds_line(q["holds"], args.min_still_s))
    if "face_alignment" in q:
        lines.append(report.accel_alignment_line(q["face_alignment"]))
    rc = _report_fit(args, res, payload, lines, "accel", report.accel_model_lines,
                     {"method": f"multi-position {res.terms}-parameter", "residual_rms_m_s2": res.residual_rms_m_s2,
                      "positions": q.get("positions"), "g_m_s2": g,
                      **({"face_alignment": q["face_alignment"]} if "face_alignment" in q else {})})
    if args.plot and res.ok:
        from ahrsd.cli.plots.mag import plot_residuals

        _write_plot(args, plot_residuals, np.array(q["position_residuals_m_s2"]) * 1e3, "position", "|f| − g (mm/s²)",
                    "accelerometer residual per position")
    return rc


def _accel_fit(args, g: float):
    """(fit, where the positions came from, the recording's gaps or None live) for gravity g: the positions held
    live or the still periods of the recording, the multi-position fit (refused naming short holds when none was
    long enough), what the holds cost, and the alignment to the faces if asked."""
    import math

    from ahrsd.calibration.inertial.accel import fit_accel

    if not (math.isfinite(args.min_still_s) and args.min_still_s > 0):
        raise _Usage(f"--min-still-s {args.min_still_s}: expected a positive number of seconds")
    terms = args.terms if args.terms == "auto" else int(args.terms)
    if args.live and args.recording:
        raise _Usage("give a RECORDING or --live, not both")
    if (args.sim or args.spi) and not args.live:
        raise _Usage("--sim/--spi go with --live (a recording is given as RECORDING)")
    gaps = None
    if args.live:
        means, source = _accel_live(args)
    else:
        if not args.recording:
            raise _Usage("give a RECORDING, or --live with --sim SCENARIO or --spi DEV")
        means, source, periods, used, skipped, rate_hz, gaps = _still_positions(args)
    if args.live or len(means):
        res = fit_accel(means, g, terms)
    else:
        from ahrsd.calibration.inertial.accel import AccelFitResult, short_holds_refusal
        from ahrsd.calibration.models import AccelModel

        res = AccelFitResult(AccelModel.identity(), math.nan, 6 if terms == "auto" else terms, {"positions": 0},
                             short_holds_refusal(periods, args.min_still_s))
    if not args.live:
        res = _with_holds(res, used, skipped, rate_hz, args.min_still_s)
    if args.align_to_faces:
        from ahrsd.calibration.inertial.accel_alignment import align_to_faces

        res = align_to_faces(res, means)
    return res, source, gaps


def _still_positions(args):
    """(position means (n, 3), a description, every still period, those used, those too short, the sample
    rate, the gaps) of the recording."""
    import math

    import numpy as np

    from ahrsd.calibration.inertial.accel import split_by_duration, still_periods

    rec = _read(args.recording, quiet=args.json)
    step_s = float(np.median(np.diff(rec.t_s)))
    if not (math.isfinite(step_s) and step_s > 0):
        raise _Fail(f"{args.recording}: t_s does not increase (median step {step_s:g} s): the sample times "
                    "must grow by the sample period")
    rate_hz = 1.0 / step_s
    periods = still_periods(rec.accel_m_s2, rec.gyro_rad_s, rate_hz)
    used, skipped = split_by_duration(periods, args.min_still_s)
    means = np.array([p.mean_accel_m_s2 for p in used]).reshape(-1, 3)
    return means, f"{len(used)} still periods in {args.recording}", periods, used, skipped, rate_hz, _gaps(rec)


def _with_holds(res, used, skipped, rate_hz, min_still_s):
    """The fit result with what the holds cost in its quality, and a refusal that names the short holds."""

    from ahrsd.calibration.inertial.accel import hold_cost

    quality = {**res.quality, "holds": hold_cost(used, skipped, rate_hz)}
    refused = res.refused
    if refused is not None and used and skipped:
        refused = (f"{refused}; {len(skipped)} more still periods were shorter than --min-still-s "
                   f"{min_still_s:g} (the longest {max(p.duration_s for p in skipped):.1f} s): lower "
                   "--min-still-s to use them")
    return dataclasses.replace(res, quality=quality, refused=refused)


def _accel_live(args):
    """The guided live session's position means from the chip (--sim SCENARIO or --spi DEV), and what they are."""
    import sys

    from ahrsd.calibration.inertial.accel import GUIDED_TARGETS, GUIDED_TARGETS_FACE_PAIRS, GuidedSession

    source, clock = _live_chip_source(args)
    imu = source.driver
    # --align-to-faces: each face twice, turned half round between, so a surface tilt cancels (accel_alignment)
    session = GuidedSession(rate_hz=imu.sample_rate_hz,
                            targets=GUIDED_TARGETS_FACE_PAIRS if args.align_to_faces else GUIDED_TARGETS)
    out = sys.stderr
    out.write(session.prompt + "\n")
    try:
        _guide(session, source, clock, args.timeout_s, out)
    except KeyboardInterrupt:
        out.write(f"\ninterrupted; {session.coverage()}\n")
    finally:
        imu.close()
    return session.position_means(), f"{len(session.recorded)} guided live positions"


def _live_chip_source(args):
    """The chip's sample source for --live (one timing path: drivers.sample_timer) and the clock it reads on:
    the simulated chip's own time (free-running) or the host's monotonic clock for --spi."""
    import time

    from ahrsd.drivers.errors import DriverError
    from ahrsd.drivers.source import start_chip_source

    if bool(args.sim) == bool(args.spi):
        raise _Usage("--live needs exactly one of --sim SCENARIO or --spi DEV")
    if args.sim:
        from ahrsd.simulation.scenarios import EXTRA_SCENARIOS, SCENARIOS

        # checked here, as `record` and `run` check theirs: the simulator's own ValueError came up as a traceback
        if args.sim not in SCENARIOS + tuple(EXTRA_SCENARIOS):
            raise _Usage(f"unknown scenario {args.sim!r}; choose one of: "
                         f"{', '.join(SCENARIOS + tuple(EXTRA_SCENARIOS))} (accel-positions: the guided positions)")
    try:
        if args.sim:
            from ahrsd.drivers.simulated import SimulatedAdis16405

            bus = SimulatedAdis16405(args.sim, clock=None)
            clock = bus.now
        else:
            from ahrsd.drivers.spi import SpidevBus

            bus = SpidevBus(args.spi)
            clock = time.monotonic
        return start_chip_source(bus, "ADIS16405", clock=clock), clock
    except DriverError as exc:
        raise _Fail(f"sensor: {exc}") from None


def _guide(session, source, clock, timeout_s: float, out) -> None:
    """Feed the session every sample until it has every position or `timeout_s` of sensor time passed, writing
    its prompts to `out`; a corrupt frame is skipped, any other sensor error ends the calibration."""
    from ahrsd.drivers.errors import DriverError, FrameError

    t_first = None
    while not session.done:
        try:
            sample = source.read_one(clock())
        except FrameError:
            continue
        except DriverError as exc:
            raise _Fail(f"sensor: {exc}") from None
        if sample is None:
            continue
        t_first = sample.t_s if t_first is None else t_first
        if sample.t_s - t_first > timeout_s:
            out.write(f"timed out after {timeout_s:.0f} s of sensor time; {session.coverage()}\n")
            return
        msg = session.feed(sample)
        if msg:
            out.write(msg + "\n")


def _gyro(args) -> int:
    from ahrsd.calibration import report

    rec = _read(args.recording)
    stored = _stored(args)
    if args.bias_only:
        res, source, segs = _gyro_bias_only(args, rec, stored)
    else:
        res, source, ref, raw = _gyro_rate_table(args, rec, stored)
    gaps = _gaps(rec)
    res = _judged_on_gaps(res, gaps, _gyro_integrates(args))
    payload = {"sensor": "gyro", **res.to_json_dict(), "source": source}
    lines = [f"Gyro calibration ({res.method}) from {source}"]
    _gap_report(payload, lines, gaps)
    rc = _report_fit(args, res, payload, lines, "gyro", report.gyro_model_lines,
                     {"method": res.method, "residual_rms_rad_s": res.residual_rms_rad_s})
    if args.plot:
        from .plots import gyro as gyro_plot

        title = f"gyro calibration ({res.method}) of {args.recording}" + ("" if res.ok else ": REFUSED")
        if args.bias_only:
            used = [(s.start, s.stop) for s in segs] or [(0, len(rec))]
            q = res.quality
            fig = gyro_plot.bias_figure(rec.t_s, rec.gyro_rad_s, used, res.model.bias_rad_s if res.ok else None,
                                        q.get("std_rad_s"), title)
        else:
            fig = gyro_plot.rate_table_figure(ref, res.model.apply(raw) if res.ok else raw, title,
                                              "calibrated" if res.ok else "raw")
        _write_plot(args, gyro_plot.save, fig)
    return rc


def _gyro_integrates(args) -> str | None:
    """What of the gyro fit relates samples across time (for the gap check), None when it only averages: the
    reference rate differentiated from the truth attitude (across a gap, one step of the gap's length) and the
    estimator run for --estimator-bias. The still means of --bias-only and the segment means against
    --table-rate-deg-s average."""
    if args.bias_only:
        return "the estimator run of --estimator-bias" if args.estimator_bias else None
    if args.table_rate_deg_s is None:
        return "the rate-table reference differentiated from the truth attitude"
    return None


def _gyro_bias_only(args, rec, stored):
    """(fit, where it came from, the still segments) of `--bias-only`: the bias from the still periods of 3 s or
    more (all samples when there is none), then with the estimator's learned bias folded in if asked."""
    import numpy as np

    from ahrsd.calibration.inertial import gyro as gyro_cal
    from ahrsd.calibration.inertial.accel import find_still_segments

    segs = find_still_segments(rec.accel_m_s2, None, rec.sample_rate_hz, min_still_s=3.0)
    idx = np.concatenate([np.arange(s.start, s.stop) for s in segs]) if segs else np.arange(len(rec))
    res = gyro_cal.fit_bias_only(rec.gyro_rad_s[idx], stored.gyro.matrix)
    source = (f"{len(idx)} still samples of {args.recording}" if segs else
              f"all {len(idx)} samples of {args.recording} (no still period of 3 s or more found)")
    if not res.ok and not segs:
        res = dataclasses.replace(res, refused=f"{res.refused} (the accelerometer showed no still period of 3 s "
                                  "or more either)")
    if args.estimator_bias and res.ok:
        res, source = _fold_estimator_bias(rec, stored, res, source)
    return res, source, segs


def _gyro_rate_table(args, rec, stored):
    """(fit, where it came from, the reference rates, the segments' raw mean rates) of the rate-table fit: the
    steady segments against the table's rate (`--table-rate-deg-s`) or the recording's truth attitude."""
    import math

    import numpy as np

    from ahrsd.calibration.inertial import gyro as gyro_cal

    accel = stored.accel.apply(rec.accel_m_s2)  # the accelerometer defines the vertical: use it calibrated
    segs = gyro_cal.steady_segments(rec.gyro_rad_s, accel, rec.sample_rate_hz)
    if args.table_rate_deg_s is not None:
        ref = gyro_cal.reference_rates_from_accel(segs, math.radians(args.table_rate_deg_s))
        source = f"{len(segs)} steady segments, table rate {args.table_rate_deg_s} °/s"
    elif rec.truth_q_wxyz is not None:
        truth = gyro_cal.body_rates_from_quaternions(rec.t_s, rec.truth_q_wxyz)
        ref = gyro_cal.reference_rates_from_truth(segs, truth)
        source = f"{len(segs)} steady segments, reference from the recording's truth attitude"
    else:
        raise _Fail(f"{len(segs)} steady segments found but nothing to compare them with: give "
                    "--table-rate-deg-s (the table's rate; the recording has no truth columns), or use "
                    "--bias-only for a still recording")
    raw = np.array([s.mean_gyro_rad_s for s in segs]).reshape(-1, 3)
    return gyro_cal.fit_rate_table(raw, ref, weights=[s.stop - s.start for s in segs]), source, ref, raw


def _write_plot(args, save, *what) -> None:
    """save(*what, args.plot), then say where the figure is (stderr: --json keeps stdout one object)."""
    import sys

    try:
        save(*what, args.plot)
    except OSError as exc:
        raise _Fail(f"{args.plot}: cannot write the plot: {exc.strerror or exc}") from None
    print(f"ahrsd calibrate {args.sensor}: figure written to {args.plot}", file=sys.stderr)


def _fold_estimator_bias(rec, stored, res, source):
    """Run the default estimator over the recording calibrated with the new bias and add the gyro bias it
    converged to (in the calibrated frame: b_new = b + M⁻¹·b_est)."""

    import numpy as np

    from ahrsd.calibration.models import GyroModel
    from ahrsd.core.sample import make_sample
    from ahrsd.estimator import make_estimator

    cal = stored.with_sensor("gyro", res.model)
    est = make_estimator()
    last = None
    for i in range(len(rec)):
        last = est.update(cal.apply(make_sample(rec.t_s[i], rec.gyro_rad_s[i], rec.accel_m_s2[i], rec.mag_ut[i])))
    b_est = np.asarray(last.gyro_bias_rad_s, dtype=float)
    model = GyroModel(res.model.bias_rad_s + np.linalg.solve(res.model.matrix, b_est), res.model.matrix)
    quality = {**res.quality, "estimator_bias_rad_s": b_est.tolist()}
    return dataclasses.replace(res, model=model, quality=quality, method="bias-only+estimator"), \
        source + " + the estimator's converged bias"


def _mag(args) -> int:
    """`calibrate mag`: the options, the inputs, one call of the calibration procedure
    (calibration/mag/procedure.py: fit, alignment, swing, GNSS levelling), the report and the figure."""
    import datetime as dt
    import os

    from ahrsd.calibration.mag import procedure
    from ahrsd.core.wmm import earth_field

    from .progress import activity

    def reference_field(site: MagSite):
        try:
            return earth_field(site.lat_deg, site.lon_deg, site.alt_m, date)
        except ValueError as exc:     # a position out of range: stderr (and the --json error object)
            raise _Usage(str(exc)) from None

    try:
        date = dt.date.fromisoformat(args.date) if args.date else None
    except ValueError as exc:
        raise _Usage(str(exc)) from None
    if not os.path.exists(args.recording):          # said first: the site's questions wait for a recording
        raise _Fail(f"{args.recording}: no such file")
    site = _given_mag_site(args)
    ref = reference_field(site) if site else None     # a bad --lat/--lon fails before the files are read
    _check_mag_options(args)
    swing_table = _read_swing_table(args.swing_table) if args.swing_table else None  # bad file: fail before fitting
    rec, data, ref_note, gnss, alignment = _mag_inputs(args)
    if site is None:
        from ahrsd.cli.calibrate_gnss import median_position

        lat_deg, lon_deg, alt_m = median_position(gnss.fixes)
        site = MagSite(lat_deg, lon_deg, alt_m if args.alt_m is None else args.alt_m,
                       f"the median of the {len(gnss.fixes)} GNSS fixes of {args.gnss}")
        ref = reference_field(site)
    options = {}
    if args.method == "backstepping" and args.heading_ref_delay_s:
        options["heading_ref_delay_s"] = args.heading_ref_delay_s
    try:
        calibrated = procedure.calibrate_mag(
            args.method, data, ref, alignment=alignment, gnss=gnss, fit_options=options,
            swing_table=None if swing_table is None else procedure.SwingTable(*swing_table, args.swing_table),
            step=lambda description: activity(args.json, description))
    except NotImplementedError as exc:
        raise _Fail(str(exc)) from None
    except procedure.MagCalibrationError as exc:
        raise _Fail(("--gnss: " if exc.step == "gnss" else "") + str(exc)) from None
    gaps = _gaps(rec)
    integrates = ("the back-stepping fit (low-pass filters and levelling run over time)"
                  if args.method == "backstepping" else None)   # the other methods fit the field's samples
    calibrated = dataclasses.replace(calibrated, result=_judged_on_gaps(calibrated.result, gaps, integrates))
    rc = _report_mag(args, calibrated, data, ref, ref_note, site, gaps)
    if args.plot:
        _plot_mag(args, calibrated.result, data, rec, ref, swing_table)
    return rc


@dataclasses.dataclass(frozen=True)
class MagSite:
    """Where the reference field is taken (WMM2025) and where that position came from."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    source: str


def _given_mag_site(args) -> MagSite | None:
    """The site --lat/--lon give; None when neither is given and --gnss will give it; else the position the
    daemon last knew (daemon.position_memory). A usage error when nothing gives it, or only one of the two is
    given."""
    if args.lat is None and args.lon is None:
        return None if args.gnss else _remembered_mag_site(args)
    if args.lat is None or args.lon is None:
        raise _Usage("give --lat and --lon together")
    return MagSite(args.lat, args.lon, 0.0 if args.alt_m is None else args.alt_m, "given with --lat/--lon")


def _remembered_mag_site(args) -> MagSite:
    """The position the daemon last knew, kept in the state directory, when young enough for the daemon's own
    declination (MAX_AGE_DAYS); a usage error naming the three ways to give a site otherwise."""
    import time
    from pathlib import Path

    from ahrsd.daemon.position_memory import FILE_NAME, MAX_AGE_DAYS, read_position_file

    path = Path(args.state_dir) / FILE_NAME
    ways = ("give --lat and --lon, or --gnss GNSS.csv (with --method backstepping) whose fixes give it, or let "
            "the daemon remember one: `ahrsd run` with a GNSS receiver or an autopilot's position keeps its last "
            f"position in the state directory ({path}; --state-dir DIR for another)")
    pos, problem = read_position_file(Path(args.state_dir))
    if pos is None:
        why = f"the remembered position is unusable ({problem})" if problem else "no position remembered"
        raise _Usage(f"the reference field needs the calibration site, and {why}: {ways}")
    now_s = time.time()
    age = pos.describe_age(now_s)
    if pos.too_old(now_s):
        raise _Usage(f"the reference field needs the calibration site, and the position the daemon last knew is "
                     f"{age} ({pos.saved_date.isoformat()}; older than {MAX_AGE_DAYS:.0f} days the vehicle may "
                     f"have moved): {ways}")
    return MagSite(pos.lat_deg, pos.lon_deg, pos.alt_m if args.alt_m is None else args.alt_m,
                   f"the position the daemon last knew, from its {pos.source} on {pos.saved_date.isoformat()}, "
                   f"{age} ({path}): give --lat/--lon if the vehicle has moved since")


def _check_mag_options(args) -> None:
    """The options of `calibrate mag` that go only with others, and their ranges (a usage error otherwise)."""
    import math

    if args.heading_ref_delay_s and args.method != "backstepping":
        raise _Usage("--heading-ref-delay-s goes with --method backstepping")
    if not (math.isfinite(args.heading_ref_delay_s) and 0.0 <= args.heading_ref_delay_s <= 60.0):
        raise _Usage(f"--heading-ref-delay-s {args.heading_ref_delay_s}: expected 0…60 s")
    if args.align_recording and args.method != "three-step":
        raise _Usage("--align-recording goes with --method three-step")
    if args.gnss and args.method != "backstepping":
        raise _Usage("--gnss goes with --method backstepping")
    if args.gnss_course and not args.gnss:
        raise _Usage("--gnss-course needs --gnss GNSS.csv")
    if args.accel_bias_sigma_mg is not None and not args.gnss:
        raise _Usage("--accel-bias-sigma-mg needs --gnss GNSS.csv")
    if args.lever_arm_m is not None:
        from ahrsd.daemon.config import checked_lever_arm_m

        if not args.gnss:
            raise _Usage("--lever-arm-m needs --gnss GNSS.csv")
        try:
            checked_lever_arm_m(args.lever_arm_m)
        except ValueError as exc:
            raise _Usage(f"--lever-arm-m {exc}") from None
    if args.accel_bias_sigma_mg is not None and not (math.isfinite(args.accel_bias_sigma_mg)
                                                     and 0.0 < args.accel_bias_sigma_mg <= 1000.0):
        raise _Usage(f"--accel-bias-sigma-mg {args.accel_bias_sigma_mg}: expected 0 < MG ≤ 1000")


def _mag_inputs(args):
    """What the fit takes: (the recording, its MagFitInput with the stored gyro and accelerometer calibration
    applied and the heading reference, the reference's note, the GNSS levelling or None, the alignment
    recording or None)."""
    from ahrsd.calibration.mag import procedure
    from ahrsd.calibration.mag.fit_types import MagFitInput

    rec = _read(args.recording, quiet=args.json)
    stored = _stored(args)
    gyro, accel, _ = stored.apply_arrays(rec.gyro_rad_s, rec.accel_m_s2, None)
    heading_ref, ref_note = _heading_reference_column(rec, args.recording, args.method)
    gnss = None
    if args.gnss:
        fixes, heading_ref, ref_note = _gnss_for_backstepping(args, rec, heading_ref, ref_note)
        accel_bias_sigma_m_s2, prior_note = _levelling_accel_bias_prior(args, stored)
        ref_note = ref_note + "; " + prior_note
        gnss_options = {"accel_bias_sigma_m_s2": accel_bias_sigma_m_s2}
        if args.lever_arm_m is not None:
            gnss_options["filter_overrides"] = {"lever_arm_m": tuple(args.lever_arm_m)}
        gnss = procedure.GnssLevelling(fixes, gnss_options)
    alignment = None
    if args.align_recording:
        arec = _read(args.align_recording, quiet=args.json)
        alignment = procedure.AlignmentRecording(arec.gyro_rad_s, stored.accel.apply(arec.accel_m_s2), arec.mag_ut,
                                                 arec.sample_rate_hz)
    return rec, MagFitInput(rec.t_s, rec.mag_ut, accel, gyro, heading_ref), ref_note, gnss, alignment


def _report_mag(args, calibrated, data, ref, ref_note, site: MagSite, gaps) -> int:
    """The fit's report (text or --json) and, unless --dry-run, the stored calibration (_report_fit)."""
    import numpy as np

    from ahrsd.calibration import report
    from ahrsd.calibration.mag.levelling_error import frame_tilt_heading_std_deg, frame_tilt_sigma_deg

    res = calibrated.result
    site_json = {"lat_deg": site.lat_deg, "lon_deg": site.lon_deg, "alt_m": site.alt_m, "source": site.source}
    payload = {"sensor": "mag", **res.to_json_dict(), "field_ut": ref.total_ut,
               "inclination_deg": float(np.degrees(ref.inclination_rad)), "reference_site": site_json}
    lines = [f"Magnetometer calibration ({res.method}) from {len(data)} samples of {args.recording}",
             f"  reference field (WMM2025 at {site.lat_deg:.4f}, {site.lon_deg:.4f}, {site.alt_m:.0f} m: "
             f"{site.source}): |F| = {ref.total_ut:.2f} µT, dip {np.degrees(ref.inclination_rad):.2f}°"]
    _gap_report(payload, lines, gaps)
    lines += ["  " + note for note in calibrated.notes]
    if ref_note:
        lines.append("  " + ref_note)
    lines += _gnss_beside_hint(args)
    q = res.quality
    meta = {"method": res.method, "residual_rms_ut": res.residual_rms_ut, "field_ut": ref.total_ut,
            "site": {**site_json, "date": args.date}}
    if "heading_reference" in q:
        meta["heading_reference"] = q["heading_reference"]
    pred = q.get("predicted_heading") or {}
    if "heading_dependent_std_deg" in pred and "offset_std_deg" in pred:   # what ins then trusts (heading_trust.py)
        meta["heading_std_deg"] = pred["heading_dependent_std_deg"]
        meta["offset_std_deg"] = pred["offset_std_deg"]
    frame_tilt_deg = frame_tilt_sigma_deg(pred.get("levelling"))
    if frame_tilt_deg is not None:   # the levelling's body-fixed tilt: ins's frame-tilt states' prior (heading_trust.py)
        meta["frame_tilt_std_deg"] = frame_tilt_deg
        tilt_heading_deg = frame_tilt_heading_std_deg(pred.get("levelling"))
        if tilt_heading_deg is not None:   # its share of heading_std_deg: ins's harmonics leave it to those states
            meta["frame_tilt_heading_std_deg"] = tilt_heading_deg
    return _report_fit(args, res, payload, lines, "mag", report.mag_model_lines, meta)


def _gnss_beside_hint(args) -> list[str]:
    """A back-stepping fit levelled by the accelerometer while the run's GNSS recording lies beside it: say that
    `--gnss` levels with the aided attitude. On a heaving, turning vehicle the accelerometer's levelling error is
    not in the predicted heading error (docs/magcal-vehicle.md)."""
    from pathlib import Path

    from ahrsd.drivers.gnss.recording import gnss_path_for

    if args.method != "backstepping" or args.gnss or not args.recording:
        return []
    beside = gnss_path_for(args.recording)
    if not Path(beside).is_file():
        return []
    return [f"  note: levelled by the accelerometer, though {beside} lies beside the recording: on a vehicle that "
            f"heaves or turns, `--gnss {beside}` levels with the GNSS-aided attitude, whose error the predicted "
            "heading error then covers (docs/magcal-vehicle.md)"]


def _plot_mag(args, res, data, rec, ref, swing_table) -> None:
    """--plot: the back-stepping figure of a fit that succeeded, else the field before and after the model."""
    if args.method == "backstepping" and res.ok:
        from ahrsd.calibration.mag.backstepping_paper import BacksteppingError
        from ahrsd.cli.plots.backstepping import plot_backstepping

        try:
            _write_plot(args, lambda path: plot_backstepping(res, data, path, swing_table=swing_table))
        except BacksteppingError as exc:
            raise _Fail(f"cannot plot: {exc}") from None
    else:
        model = res.model if res.ok else None
        from ahrsd.cli.plots.mag import plot_mag

        _write_plot(args, plot_mag, rec.mag_ut, model, ref.total_ut)


def _gnss_for_backstepping(args, rec, heading_ref, ref_note):
    """--gnss: the validated fixes (the fit levels with the aided estimator over them: cli.calibrate_gnss), and
    with --gnss-course the course as the heading reference."""
    import numpy as np

    from ahrsd.cli import calibrate_gnss as cg

    if heading_ref is not None and args.gnss_course:
        raise _Usage("the recording has a heading_ref_deg column and --gnss-course gives the course: use one")
    if args.heading_ref_delay_s and args.gnss_course:
        raise _Usage("--heading-ref-delay-s is for a heading_ref_deg column; a GNSS recording is stamped at its "
                     "time of validity")
    try:
        fixes, validator = cg.read_validated_fixes(args.gnss)
    except cg.GnssInputError as exc:
        raise _Fail(str(exc)) from None
    from ahrsd.calibration.mag.backstepping_aided import SMOOTH_LEVELLING
    from ahrsd.estimator import AIDED_ESTIMATOR

    note = (f"levelling: {AIDED_ESTIMATOR} aided by {len(fixes)} GNSS fixes of {args.gnss} "
            f"({validator.rejected} rejected)" + (", smoothed over the run (RTS)" if SMOOTH_LEVELLING else "")
            + ("" if args.lever_arm_m is None else
               ", antenna at " + " ".join(f"{v:g}" for v in args.lever_arm_m) + " m (body FRD)"))
    if not args.gnss_course:
        return fixes, heading_ref, note + ("; " + ref_note if ref_note else "")
    course = cg.course_reference_deg(fixes, rec.t_s)
    n = int(np.isfinite(course).sum())
    note += (f"; heading reference: GNSS course on straight tracks above {cg.COURSE_MIN_SPEED_M_S:g} m/s, "
             f"{n} of {len(course)} samples ({n / len(course):.0%})")
    return fixes, (course if n else None), note


def _levelling_accel_bias_prior(args, stored):
    """--gnss: the aided levelling's accelerometer-bias prior (m/s², None: the filter's default) and a note. The
    levelling cannot tell a bias from a tilt on a vehicle that stays level (calibration.backstepping_aided), so
    what splits them is the bench calibration: known to ~2 mg when there is one."""
    from ahrsd.calibration.accel_trust import calibration_accel_bias_sigma_m_s2
    from ahrsd.core.angles import STANDARD_GRAVITY_M_S2

    mg = 1e-3 * STANDARD_GRAVITY_M_S2
    if args.accel_bias_sigma_mg is not None:
        return args.accel_bias_sigma_mg * mg, f"accelerometer bias prior {args.accel_bias_sigma_mg:g} mg (given)"
    calibrated_sigma_m_s2 = calibration_accel_bias_sigma_m_s2(stored)
    if calibrated_sigma_m_s2 is not None:
        aligned = "face_alignment" in (stored.metadata.get("accel") or {})
        return (calibrated_sigma_m_s2,
                f"accelerometer calibrated: bias prior {calibrated_sigma_m_s2 / mg:g} mg"
                + ("" if aligned else "; its frame is not aligned to the housing (`ahrsd calibrate accel "
                   "--align-to-faces`: at a dip I, each 0.1° of the triad's rotation moves the heading by up to "
                   "0.1°·tan I; docs/calibration.md)"))
    return None, ("WARNING: no accelerometer calibration in the state directory: the horizon is only as good as "
                  "the filter can separate the accelerometer bias from tilt (prior 10 mg, up to 0.6°); run "
                  "`ahrsd calibrate accel` first (docs/magcal-vehicle.md)")


def _heading_reference_column(rec, path, method):
    """The recording's `heading_ref_deg` column (true heading in degrees, NaN where there is none) and a note for
    the report; (None, note-or-None) when there is no usable column."""
    import numpy as np

    col = rec.extra.get("heading_ref_deg")
    if col is None:
        return None, None
    h = np.array(col, dtype=np.float64)
    finite = np.isfinite(h)
    bad = finite & ~((h >= -360.0) & (h <= 720.0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise _Fail(f"{path}: heading_ref_deg {float(h[i])!r} at t = {rec.t_s[i]:.3f} s is not a heading in degrees "
                    "(expected −360…720; use NaN for no reference)")
    n = int(finite.sum())
    if n == 0:
        return None, "heading_ref_deg column present but empty (all NaN): no heading reference"
    if method != "backstepping":
        return None, (f"heading_ref_deg column ({n} samples) not used: only --method backstepping fits a heading "
                      "reference (or give --swing-table)")
    return h % 360.0, f"heading reference: heading_ref_deg column, {n} of {len(h)} samples ({n / len(h):.0%})"


def _read_swing_table(path):
    from ahrsd.calibration.mag.swing import SwingTableError, load_swing_table

    try:
        return load_swing_table(path)
    except SwingTableError as exc:
        raise _Fail(f"swing table: {exc}") from None


def _report_fit(args, res, payload, lines, sensor, describe, meta) -> int:
    """Common tail: refused → report and 1; else save, report parameters and 0. The magnetometer report leads
    with what the operator decides on (cli.fit_summary), the details after it."""
    from ahrsd.calibration.report import _QUALITY_NOT_LISTED

    from .fit_summary import detail_lines, mag_decision_lines

    if not res.ok:
        payload["saved_to"] = None
        if sensor == "mag":
            lines[1:1] = mag_decision_lines(res, f"REFUSED: {res.refused}")
        else:
            lines.append(f"  REFUSED: {res.refused}")
        _emit(args, payload, "\n".join(lines))
        return 1
    model = res.model
    path, note = _save(args, sensor, model, meta)
    payload["saved_to"] = None if path is None else str(path)
    if sensor == "mag":
        lines[1:1] = mag_decision_lines(res, f"accepted, {note}")
        lines += describe(model, res)
        lines.append("  details:")
        lines += detail_lines(res.quality, frozenset(_QUALITY_NOT_LISTED) | {
            "predicted_heading", "heading_coverage", "coverage", "sphere_coverage", "tilt", "warnings",
            "attitude_source", "residual_max_ut", "sigma_hard_iron_ut"})
    else:   # the fit's own figures after the model, under "details:" as the magnetometer's (issue 30 item 8)
        lines += describe(model, res)
        details = detail_lines(res.quality, frozenset(_QUALITY_NOT_LISTED))
        lines += ["  details:", *details] if details else []
        lines.append(f"  {note}")
    _emit(args, payload, "\n".join(lines))
    return 0


def run(args) -> int:
    import sys

    handlers = {"allan": _allan, "accel": _accel, "gyro": _gyro, "mag": _mag}
    _RECORDING_META.clear()
    if args.state_dir is None:          # the directory `ahrsd run` reads when it is given none
        from ahrsd.core.state_dir import default_state_dir

        args.state_dir = str(default_state_dir())
    try:
        if args.plot:
            _check_matplotlib()   # before fitting and saving: a missing optional extra is a usage error
        if args.sensor != "allan" and not (args.dry_run or args.force):     # allan has no --force
            _refuse_a_held_state_dir(args.state_dir)
        return handlers[args.sensor](args)
    except _Fail as exc:
        failure = exc
    except ImportError as exc:   # a plot's PlotUnavailableError, should the check above be bypassed
        from ahrsd.core.plotting import PlotUnavailableError

        if not isinstance(exc, PlotUnavailableError):
            raise
        failure = _Usage(_plot_needs_matplotlib())
    if args.json:
        import json

        print(json.dumps({"sensor": args.sensor, "error": str(failure)}))
    print(f"ahrsd calibrate {args.sensor}: error: {failure}", file=sys.stderr)
    return 2 if isinstance(failure, _Usage) else 1


def _refuse_a_held_state_dir(state_dir: str) -> None:
    """_Fail when a running ahrsd holds `state_dir` (daemon.state_lock): it reads calibration.json only when it
    starts (daemon.service), and every calibration it applies itself (a magnetometer calibration accepted, a
    fixed yaw: daemon.calibration_swap) saves its whole calibration over the file, so one written under it is
    unused until a restart and may be lost. Nothing is created or written by the check."""
    from ahrsd.daemon.state_lock import holder

    busy = holder(state_dir)
    if busy is not None:
        raise _Fail(f"a running ahrsd ({busy.who}) holds {state_dir}: it would use this calibration only after a "
                    f"restart and saves its own over it when it accepts a magnetometer calibration; stop it first "
                    f"(systemctl stop ahrsd), calibrate, start it again — or --force (then restart it), or "
                    f"--dry-run")


def _check_matplotlib() -> None:
    import importlib

    try:
        importlib.import_module("matplotlib")
    except ImportError:
        raise _Usage(_plot_needs_matplotlib()) from None

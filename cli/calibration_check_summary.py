"""The replay summary's line for the magnetometer calibration checked without GNSS (estimator/field_circle.py):
the verdict over the run as the daemon names it (daemon/heading_status.py), from the replay table's
mag_cal_check and mag_field_centre_ut columns (estimator/replay.FIELD_CIRCLE_COLUMNS)."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.estimator.field_circle import N_SECTORS, CalibrationVerdict, FieldCircleParams, wrong_calibration_text


class CalibrationCheckSummary:
    """`add(t_s, verdict, centre_ut)` per table (columns); `text(calibration_sigma_rad)` at the end."""

    def __init__(self):
        self.first_judged_t_s = math.nan     # the first sample the check judged (covered enough turning)
        self.first_wrong_t_s = math.nan      # the first sample it found the calibration wrong
        self.first_wrong_ut = math.nan       # the centre's offset then
        self.max_wrong_ut = math.nan         # the largest offset while wrong
        self.wrong_s = 0.0                   # time found wrong
        self.last_centre_ut = math.nan       # the centre's offset at the last judged sample
        self.first_corrected_t_s = math.nan  # the first sample consistent with the correction learned from the turns
        self.last_corrected_ut = math.nan    # the field's offset the correction removes, at the last such sample
        self._last_t_s = math.nan
        self._last_wrong = False

    def add(self, t_s, verdict, centre_ut) -> None:
        t_s = np.asarray(t_s, dtype=float)
        v = np.asarray(verdict).astype(int)
        if not len(t_s):
            return
        judged = v != int(CalibrationVerdict.NOT_JUDGED)
        wrong = v == int(CalibrationVerdict.WRONG)
        corrected = v == int(CalibrationVerdict.CORRECTED)
        if judged.any():
            if not math.isfinite(self.first_judged_t_s):
                self.first_judged_t_s = float(t_s[np.argmax(judged)])
            self.last_centre_ut = float(np.asarray(centre_ut)[np.flatnonzero(judged)[-1]])
        if wrong.any():
            if not math.isfinite(self.first_wrong_t_s):
                k = int(np.argmax(wrong))
                self.first_wrong_t_s, self.first_wrong_ut = float(t_s[k]), float(centre_ut[k])
            self.max_wrong_ut = float(np.nanmax([self.max_wrong_ut, np.nanmax(np.asarray(centre_ut)[wrong])]))
        if corrected.any():
            if not math.isfinite(self.first_corrected_t_s):
                self.first_corrected_t_s = float(t_s[np.argmax(corrected)])
            self.last_corrected_ut = float(np.asarray(centre_ut)[np.flatnonzero(corrected)[-1]])
        # time in WRONG: each sample's interval to the next (the first one's from the previous table's last)
        dt = np.diff(np.concatenate([[self._last_t_s if math.isfinite(self._last_t_s) else t_s[0]], t_s]))
        was = np.concatenate([[self._last_wrong], wrong[:-1]])
        self.wrong_s += float(np.sum(dt[was]))
        self._last_t_s, self._last_wrong = float(t_s[-1]), bool(wrong[-1])

    def text(self, calibration_sigma_rad: float) -> str:
        """The verdict over the run: wrong (when first, by how much, for how long), consistent, or not judged."""
        stated_deg = math.degrees(calibration_sigma_rad)
        what = (f"magnetometer calibration (stated heading error ±{stated_deg:.1f}°) checked without GNSS by the "
                "field's circle in turns: ")
        if math.isfinite(self.first_wrong_t_s):
            more = f", up to {self.max_wrong_ut:.1f} µT" if self.max_wrong_ut >= self.first_wrong_ut + 0.05 else ""
            then = "" if not math.isfinite(self.first_corrected_t_s) else (
                f"; then {wrong_calibration_text(self.last_corrected_ut, corrected=True)} (consistent with it from "
                f"{self.first_corrected_t_s:.1f} s on; samples marked mag_cal_check = 3)")
            return (what + f"WARNING: {wrong_calibration_text(self.first_wrong_ut)} (found at "
                    f"{self.first_wrong_t_s:.1f} s{more}; wrong for {self.wrong_s:.0f} s; samples marked "
                    "mag_cal_check = 2)" + then)
        if math.isfinite(self.first_judged_t_s):
            return what + (f"checked, consistent (judged from {self.first_judged_t_s:.1f} s on; the circle's centre "
                           f"{self.last_centre_ut:.1f} µT off at the last judgement: within the fit's uncertainty or "
                           "the stated error)")
        p = FieldCircleParams()
        return what + (f"not judged: the vehicle did not turn enough (the field must sweep "
                       f"{360 * p.min_sectors // N_SECTORS}° within about {p.window_s:.0f} s)")

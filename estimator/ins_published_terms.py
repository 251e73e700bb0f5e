"""What ins's built estimate adds to its filter's outputs, compiled: one call per estimate built (`Ins._build_estimate`,
at every `update`), where the same arithmetic written out in Python costs several times the filter step's call.

On a fresh copy of the flat output record (`out`, written in place) and the scalars the Python parts hold, in this
order:
- the yaw 1σ: at least the unconfirmed heading's floor once navigating (heading_confirmation.py), π while the GNSS
  velocities fit another antenna place (lever_arm_fit.py `heading_bent`), and with the accelerometer axes' heading
  term once aided (accel_axes_heading.py);
- the roll and pitch 1σ with the accelerometer axes' tilt term at the low-passed specific force (accel_axes_tilt.py);
- the published heading's offset (published_heading.py): the yaw and the quaternion turned back by it about down;
- the magnetic yaw wrapped to ±π, and the position in degrees, the longitude wrapped to ±180°.
The rules are the modules' named above; this only evaluates them where the estimate is built. What is not written
here: the yaw σ before the first fix (calibration_heading.py, field_circle.py: Python objects) and the published σ
with an offset (slewed_yaw.py), which the caller writes; whether to build a NavState.
"""

from __future__ import annotations

import math

from numba import njit

from .accel_axes_tilt import accel_axes_tilt_variance_in_force_rad2
from .ins_core import INS_OUT_DTYPE
from .kernel_rotations import dcm

_TWO_PI = 2.0 * math.pi
_RAD_TO_DEG = 180.0 / math.pi    # math.degrees's factor (CPython: x · 180/π), so the same bits
# where the fields start in the flat float64 view of an INS_OUT_DTYPE record (frozen into the kernel)
_Q, _SIGMA, _EULER, _LAT, _LON, _H = (INS_OUT_DTYPE.fields[name][1] // 8 for name in (
    "q", "sigma_rpy_rad", "euler_rad", "lat_rad", "lon_rad", "h_m"))


@njit(cache=True)
def published_terms(out, q, f_ned, unconfirmed_sigma_rad, navigating, heading_bent, yaw_sigma_written,
                    axes_tilt_sigma_rad, axes_heading_var_rad2, offset_rad, declination_rad):
    """(roll, pitch, magnetic yaw, true yaw, yaw 1σ, lat °, lon °, height m) of the estimate, `out` updated.

    out: the flat float64 copy of an INS_OUT_DTYPE record; q, f_ned: the filter's attitude (body → true NED) and
    its low-passed specific force (NED); navigating: a fix has set the velocity and position. axes_heading_var_rad2: the accelerometer axes' heading variance, 0 before the
    first fix. yaw_sigma_written: write the yaw σ into `out` (the caller writes it when it adds more)."""
    sig_roll = out[_SIGMA]
    sig_pitch = out[_SIGMA + 1]
    sigma_yaw = out[_SIGMA + 2]
    roll = out[_EULER]
    pitch = out[_EULER + 1]
    yaw_true = out[_EULER + 2]
    if unconfirmed_sigma_rad > sigma_yaw and navigating:
        sigma_yaw = unconfirmed_sigma_rad        # HeadingConfirmation.unconfirmed_yaw_sigma says why
    if heading_bent:
        # the GNSS velocities fit another antenna place than the one told (lever_arm_fit.py): the heading they held,
        # and the GNSS yaw bank's, are bent by an error no state models: unknown until an arm (the told one or the
        # fitted one adopted) leaves the gate rejecting as a right arm does
        sigma_yaw = math.pi
    if axes_tilt_sigma_rad > 0.0:
        # the x and y axes' misalignment; the z axis's lean, which a fix levels through the vertical channel, is the
        # E_AZ_LEAN states', already in the filter's σ
        var_roll, var_pitch = accel_axes_tilt_variance_in_force_rad2(dcm(q[0], q[1], q[2], q[3]), f_ned[0],
                                                                     f_ned[1], f_ned[2], axes_tilt_sigma_rad)
        if var_roll > 0.0 or var_pitch > 0.0:
            out[_SIGMA] = math.sqrt(sig_roll * sig_roll + var_roll)
            out[_SIGMA + 1] = math.sqrt(sig_pitch * sig_pitch + var_pitch)
    if axes_heading_var_rad2 > 0.0:
        sigma_yaw = math.sqrt(sigma_yaw * sigma_yaw + axes_heading_var_rad2)
    if offset_rad != 0.0:
        # the filter's yaw moved faster than the published one may: publish it turned back by the offset
        yaw_true += offset_rad
        c = math.cos(0.5 * offset_rad)
        s = math.sin(0.5 * offset_rad)
        w, x, y, z = out[_Q], out[_Q + 1], out[_Q + 2], out[_Q + 3]
        out[_Q] = c * w - s * z
        out[_Q + 1] = c * x - s * y
        out[_Q + 2] = c * y + s * x
        out[_Q + 3] = c * z + s * w
    if yaw_sigma_written:
        out[_SIGMA + 2] = sigma_yaw
    yaw = (yaw_true - declination_rad + math.pi) % _TWO_PI - math.pi
    lat_deg = out[_LAT] * _RAD_TO_DEG
    lon_deg = (out[_LON] * _RAD_TO_DEG + 180.0) % 360.0 - 180.0
    return roll, pitch, yaw, yaw_true, sigma_yaw, lat_deg, lon_deg, out[_H]

"""The gyro calibration figure (`ahrsd calibrate gyro --plot FILE.png`).

Bias-only: each axis's rate over the recording, the still periods the bias was taken from shaded, the fitted
bias and its ±1σ spread of the samples. Rate table: for each steady segment the reference rate and what the
calibrated gyro measured, and the residual (calibrated − reference) the fit leaves.
"""

from __future__ import annotations

import numpy as np

from ahrsd.core.plotting import pyplot

MAX_POINTS = 20_000     # per trace: a long recording is drawn decimated (the figure's pixels cannot show more)


def bias_figure(t_s: np.ndarray, gyro_rad_s: np.ndarray, used: list[tuple[int, int]], bias_rad_s, std_rad_s,
                title: str):
    """The bias-only figure: one panel per axis, in °/s. `used`: (start, stop) sample ranges the bias came
    from; bias_rad_s / std_rad_s None when the fit was refused (the rates are drawn alone)."""
    plt = pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(12, 7), sharex=True)
    step = max(1, len(t_s) // MAX_POINTS)
    rate_deg_s = np.degrees(np.asarray(gyro_rad_s, dtype=float))
    for k, ax in enumerate(axes):
        ax.plot(t_s[::step], rate_deg_s[::step, k], lw=0.5, color="0.4", label="raw rate")
        for n, (start, stop) in enumerate(used):
            ax.axvspan(t_s[start], t_s[stop - 1], color="tab:green", alpha=0.12, gid="still",
                       label="still: used for the bias" if n == 0 else None)
        if bias_rad_s is not None:
            b, s = np.degrees(bias_rad_s[k]), np.degrees(std_rad_s[k])
            ax.axhline(b, color="tab:red", lw=1.2, label=f"bias {b:+.3f} °/s ({b * 3600:+.0f} °/h)")
            ax.axhspan(b - s, b + s, color="tab:red", alpha=0.10, label=f"±1σ of the samples ({s:.3f} °/s)")
        ax.set_ylabel(f"{'xyz'[k]} (°/s)")
        ax.grid(alpha=0.3)
        _legend_beside(ax)
    axes[-1].set_xlabel("t (s)")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def rate_table_figure(reference_rad_s: np.ndarray, measured_rad_s: np.ndarray, title: str,
                      measured: str = "calibrated"):
    """The rate-table figure: per steady segment and axis, reference and measured mean rate (top) and the
    residual measured − reference (bottom), in °/s. measured_rad_s: the raw segment means through the fitted
    model (`measured` = "calibrated"), or the raw means when the fit was refused (`measured` = "raw")."""
    plt = pyplot()
    ref = np.degrees(np.asarray(reference_rad_s, dtype=float)).reshape(-1, 3)
    cal = np.degrees(np.asarray(measured_rad_s, dtype=float)).reshape(-1, 3)
    seg = np.arange(1, len(ref) + 1)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(11.5, 6.5), sharex=True)
    for k, colour in enumerate(("tab:blue", "tab:orange", "tab:green")):
        top.plot(seg, ref[:, k], "o", mfc="none", color=colour, label=f"{'xyz'[k]} reference")
        top.plot(seg, cal[:, k], "x", color=colour, label=f"{'xyz'[k]} {measured}")
        bottom.plot(seg, cal[:, k] - ref[:, k], "o-", color=colour, ms=4, lw=0.8, label="xyz"[k])
    top.set_ylabel("mean rate (°/s)")
    bottom.set_ylabel(f"{measured} − reference (°/s)")
    bottom.set_xlabel("steady segment")
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
        _legend_beside(ax)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def _legend_beside(ax) -> None:
    """The legend right of the panel, outside it: inside, "best" still covered the ±90 °/s segments at the top
    of a full six-axis table (a user could not see that the y axis was turned both ways)."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)


def save(fig, path) -> None:
    plt = pyplot()
    try:
        fig.savefig(path, dpi=100)
    finally:
        plt.close(fig)

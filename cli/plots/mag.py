"""Figures of bench calibrations (`ahrsd calibrate ... --plot FILE.png`): magnetometer before and
after, per-position residuals. matplotlib is the optional `ahrsd[plot]` extra, imported only here.
"""

from __future__ import annotations

import numpy as np

from ahrsd.core.plotting import pyplot





def plot_mag(mag_ut: np.ndarray, model, field_ut: float, path) -> None:
    """The raw (and, with a MagModel, calibrated) field in the xy, xz and yz planes against the |F| circle."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6))
    cal = None if model is None else model.apply(mag_ut)
    circle = np.linspace(0, 2 * np.pi, 200)
    for ax, (i, j) in zip(axes, ((0, 1), (0, 2), (1, 2))):
        ax.plot(mag_ut[:, i], mag_ut[:, j], ".", ms=1, alpha=0.5, label="raw")
        if cal is not None:
            ax.plot(cal[:, i], cal[:, j], ".", ms=1, alpha=0.5, label="calibrated")
        ax.plot(field_ut * np.cos(circle), field_ut * np.sin(circle), "k--", lw=0.8, label="|F| (WMM)")
        ax.set_aspect("equal")
        ax.set_xlabel(f"{'xyz'[i]} (µT)")
        ax.set_ylabel(f"{'xyz'[j]} (µT)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", markerscale=8)
    fig.suptitle("magnetometer before/after calibration" if cal is not None else "magnetometer (fit refused)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_residuals(values, xlabel: str, ylabel: str, title: str, path) -> None:
    """One bar per value (e.g. the accelerometer residual per position)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.bar(range(1, len(values) + 1), values)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)

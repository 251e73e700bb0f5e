"""The Allan analysis figure (`ahrsd calibrate allan --plot FILE.png`): per sensor and axis the Allan deviation
with its confidence band, each term the curve shows drawn over its τ range, and the IEEE Std 952 readings marked
(N at τ = 1 s, B at the flicker floor's minimum, K at τ = 3 s). Needs matplotlib (the optional `ahrsd[plot]`
extra)."""

from __future__ import annotations

import numpy as np

from ahrsd.calibration.allan.terms import FLICKER_FACTOR
from ahrsd.calibration.report import sig_figs
from ahrsd.core.plotting import pyplot

TERM_STYLE = {"quantization": ("Q", "tab:purple"), "white": ("N", "tab:blue"), "flicker": ("B", "tab:green"),
              "rate_random_walk": ("K", "tab:red"), "rate_ramp": ("R", "tab:brown"),
              "gauss_markov": ("GM", "tab:orange")}
UNITS = {"gyro": "rad/s", "accel": "m/s²", "mag": "µT"}


def plot_allan(result, path) -> None:
    """Write the figure to `path` (PNG)."""
    plt = pyplot()
    sensors = list(result.adev)
    fig, grid = plt.subplots(len(sensors), 3, figsize=(15, 4.2 * len(sensors)), squeeze=False)
    taus = result.taus_s
    for row, sensor in zip(grid, sensors):
        for i, (ax, axis) in enumerate(zip(row, "xyz")):
            p = result.parameters[sensor][axis]
            ax.fill_between(taus, result.adev_lower[sensor][:, i], result.adev_upper[sensor][:, i],
                            color="0.8", label="68 % band")
            ax.loglog(taus, result.adev[sensor][:, i], "k.-", lw=1, ms=3, label="Allan deviation")
            for name, est in p.terms.items():
                short, colour = TERM_STYLE[name]
                t = np.geomspace(*est.tau_range_s, 100)
                ax.loglog(t, np.sqrt(p.fit.contribution(name, t)), "-", color=colour, lw=2,
                          label=f"{short} {sig_figs(est.value)} ± {sig_figs(est.uncertainty, 1)}")
                reading = est.reading_tau_s
                if reading is not None and name in ("white", "rate_random_walk"):
                    lo, hi = min(reading, est.tau_range_s[0]), max(reading, est.tau_range_s[1])
                    t = np.geomspace(lo, hi, 100)
                    ax.loglog(t, np.sqrt(p.fit.contribution(name, t)), ":", color=colour, lw=1)
                    ax.plot([reading], [est.value], "o", color=colour, mec="k", ms=8)
                    ax.annotate(f"{short} (τ={reading:g} s)", (reading, est.value), textcoords="offset points",
                                xytext=(6, 6), color=colour)
            if p.bias_instability is not None:
                level = FLICKER_FACTOR * p.bias_instability
                ax.plot([p.tau_bias_instability_s], [level], "s", color=TERM_STYLE["flicker"][1], mec="k", ms=8)
                ax.annotate(f"B = min σ / 0.664 = {sig_figs(p.bias_instability)}", (p.tau_bias_instability_s, level), textcoords="offset points",
                            xytext=(6, -14), color=TERM_STYLE["flicker"][1])
            if p.fit is not None and p.terms:
                # the model over the τ it was fitted on: below that (the sensor filter's correlated samples) the
                # white term N²(1/τ − D/τ²) is not the curve and turns negative
                fitted = taus >= min(est.tau_range_s[0] for est in p.terms.values())
                ax.loglog(taus[fitted], np.sqrt(p.fit.avar(taus[fitted])), "--", color="0.4", lw=1,
                          label="model (fitted τ)")
            ax.set_title(f"{sensor} {axis}")
            ax.set_xlabel("τ (s)")
            ax.set_ylabel(f"σ(τ) ({UNITS[sensor]})")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)

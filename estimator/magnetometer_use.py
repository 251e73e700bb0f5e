"""What the kernel does with the magnetometer after each heading check: whether it fuses it, whether its update may
move the horizon, and its heading bias's variance and time constant.

The heading checks (ins.Ins._check_heading) decide on the magnetometer (heading_monitor.py) and hand this part what
it needs: the monitor's decision, the variances of the magnetometer heading at this check, whether the iron is being
learned or has been, the learned magnetometer's floor at this place and the heading rate. It returns the four kernel
settings (`MagnetometerKernelUse`), which the filter writes into its kernel parameters. It keeps no state and reads
nothing of the filter; the figures it judges with come through `MagnetometerUseParams` (InsParams satisfies it).

Why each rule: the docstrings below; docs/tour.md ("The aided boat's heading after the learning") and
docs/estimator.md (the rejected magnetometer fused at its floor).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Protocol


class MagnetometerUseParams(Protocol):
    """The figures the part judges with (InsParams' fields and property of the same names)."""

    mag_moves_tilt: bool
    mag_trusted_moves_tilt: bool
    iron_learned_tau_s: float
    iron_heading_corr_rad: float

    @property
    def mag_bias_tau(self) -> float: ...


@dataclass(frozen=True)
class MagnetometerKernelUse:
    """The kernel's magnetometer settings after a check (the kernel parameters of the same names). The bias's
    variance and time constant are None where the check had no magnetometer heading: the kernel keeps its own."""

    mag_use: float                       # 1.0: fused
    mag_moves_tilt: float                # 1.0: its update may move the horizon
    mag_bias_var_rad2: float | None      # the heading bias's variance at this attitude
    mag_bias_tau_s: float | None         # the heading bias's time constant


@dataclass(frozen=True)
class IronState:
    """What the iron learning has done, as the part needs it."""

    learning: bool                # the monitor learns the iron now (HeadingMonitor.learning)
    updates: int                  # the learner's updates in this run
    restored: bool                # a learned iron was restored at start-up
    before_rejection: bool        # an iron had been learned before the magnetometer's current rejection
    offset_held: bool = False     # the learned iron's heading offset is no longer learned against the yaw


def magnetometer_use(params: MagnetometerUseParams, *, monitor_use: bool, trusted_sigma_rad: float,
                     slow_var_rad2: float, mag_var_rad2: float, noise_rad2: float, trust_var_rad2: float,
                     calibration_untrusted: bool, iron: IronState,
                     learned_floor_var_rad2: Callable[[], float | None],
                     heading_rate_rad_s: Callable[[], float], yaw_var_rad2: float) -> MagnetometerKernelUse:
    """The kernel's settings after the check.

    monitor_use: the monitor's decision (MonitorDecision.mag_use); trusted_sigma_rad: its trust limit;
    slow_var_rad2: the magnetometer heading's slowly varying variance judged at the previous check (what trust
    uses); mag_var_rad2, noise_rad2: this check's variance and its white part (NaN: no magnetometer heading);
    trust_var_rad2: the variance the heading state uses; learned_floor_var_rad2: the learned magnetometer's floor at
    this place (None: no WMM field); heading_rate_rad_s: |rate about down|, bias removed; yaw_var_rad2: the filter's
    yaw variance at the check (`never_trusted_here`). The floor and the rate are functions of
    no arguments, called only by the rule that reads them (`rejected_magnetometer_fused`, once its other conditions
    hold): the filter works them out at a check only when one is read.

    Not fused while the iron is being learned (`IronState.learning`), even where the monitor has let the
    magnetometer back (it judges the variance at this heading, the learning the worst heading's): the iron is
    learned against the filter's own attitude, so the field it corrects tells the filter its own yaw over the
    learning window back, not a second heading. Fused, the two errors are one error counted twice (the Kalman
    update takes the measurement's error as independent of the state's, Maybeck, Stochastic Models, Estimation and
    Control vol. 1 ch. 5): the filter's yaw follows the half-learned magnetometer and the iron learns that yaw
    (docs/tour.md "The aided boat's heading after the learning"). The GNSS holds the heading until the learning
    ends; then the learned iron's error is carried as the harmonic states (Ins._set_mag_harmonics). Except once the
    learned iron's offset is held (`IronState.offset_held`, IronLearner.hold_offset): the learner no longer learns
    the heading offset against the filter's yaw, so the error is no longer counted twice, and a magnetometer the
    monitor uses is fused while the rest of its iron is learned; without it the monitor's re-entry at one heading
    (its floor over the trust window, slow_floor.py) left the magnetometer unused, neither fused as rejected nor
    trusted, for the rest of the learning (Reykjavík, H 13.2 µT: docs/gnss.md "(pa96)")."""
    p = params
    use = monitor_use and (not iron.learning or iron.offset_held)
    mag_use = 1.0 if use else 0.0
    trusted = use and slow_var_rad2 < trusted_sigma_rad ** 2
    moves_tilt = 1.0 if p.mag_moves_tilt or (p.mag_trusted_moves_tilt and trusted) else 0.0
    if not math.isfinite(mag_var_rad2):
        return MagnetometerKernelUse(mag_use, moves_tilt, None, None)
    bias_var = mag_var_rad2 - noise_rad2     # at this attitude; the white part is the kernel's own noise
    learned = iron.updates > 0 or iron.restored
    tau = p.iron_learned_tau_s if learned else p.mag_bias_tau
    if rejected_magnetometer_fused(p, monitor_use=monitor_use, calibration_untrusted=calibration_untrusted,
                                   iron=iron, trust_var_rad2=trust_var_rad2,
                                   never_trusted=lambda: never_trusted_here(learned_floor_var_rad2(),
                                                                            trusted_sigma_rad, yaw_var_rad2)):
        return MagnetometerKernelUse(1.0, 0.0, max(trust_var_rad2, bias_var),
                                     max(p.iron_learned_tau_s,
                                         p.iron_heading_corr_rad / max(heading_rate_rad_s(), 1e-6)))
    return MagnetometerKernelUse(mag_use, moves_tilt, bias_var, tau)


def rejected_magnetometer_fused(params: MagnetometerUseParams, *, monitor_use: bool, calibration_untrusted: bool,
                                iron: IronState, trust_var_rad2: float, never_trusted: Callable[[], bool]) -> bool:
    """`iron_heading_corr_rad`: the monitor rejects a magnetometer without a trusted calibration, but an iron has
    been learned since the rejection and none before it, so the learner's covariance and the floor
    (`trust_var_rad2`) are all the error there is; and the floor plus the filter's yaw variance keeps it above the
    trust limit here (`never_trusted_here`; `never_trusted` is asked last, once the others hold). Not with a trusted calibration: its own σ stands in for the floor there
    (Ins._magnetometer_trust_var), and the rejection has just shown the calibration wrong."""
    return (params.iron_heading_corr_rad > 0.0 and not monitor_use and calibration_untrusted
            and iron.updates > 0 and not iron.before_rejection and not iron.restored
            and math.isfinite(trust_var_rad2) and never_trusted())


def never_trusted_here(learned_floor_var_rad2: float | None, trusted_sigma_rad: float,
                       yaw_var_rad2: float) -> bool:
    """The learned magnetometer cannot be trusted on what this learning can give here: the floor of its heading
    variance (what no learned iron explains, `iron_unmodelled_ut`, over the WMM horizontal field at the filter's
    position) plus the filter's yaw variance now (rad²) is above the monitor's trust limit. The floor alone puts it
    there for good where H is below ~19 µT with the defaults (high latitudes). The yaw term: the iron is learned
    against the filter's yaw, and the yaw error common to the learning window is learned as iron, as a heading
    offset the same at every heading (learned_iron.py), so the learned magnetometer's heading error is at least that
    yaw error; where the floor leaves less room than the yaw's variance (Punta Arenas, H 19.6 µT: floor 2.92°,
    room 0.69°), re-entry waits for the learner's own covariance to claim what the yaw cannot give (seed 96: 650 s
    of GNSS-only heading) while the learned magnetometer's honest heading goes unused (docs/gnss.md "boat39").
    Where the sum is below the limit the magnetometer is left out until it re-enters: fused weakly meanwhile, the
    kernel's field check follows the learned iron and takes it back at once on re-entry, with an iron not yet
    learned as well as the check's delay left it (docs/figures.md "At places and irons not tuned on"). Without the
    WMM field (None): False."""
    if learned_floor_var_rad2 is None:
        return False
    return learned_floor_var_rad2 + yaw_var_rad2 > trusted_sigma_rad ** 2

"""The magnetometer's use in the kernel after a heading check, the part alone (estimator/magnetometer_use.py), built
without a filter: not fused while the iron is being learned; the horizon moved only by a trusted magnetometer and only
where allowed; the heading bias's variance and time constant; a rejected magnetometer fused at its floor only where
every condition of `iron_heading_corr_rad` holds (docs/estimator.md). The expected settings are the rules written
out by hand, not the part's output."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import pytest

from ahrsd.estimator.magnetometer_use import IronState, magnetometer_use, never_trusted_here

DEG = math.pi / 180.0
TRUSTED = 3.0 * DEG
LEARNED_TAU_S = 3.0
BIAS_TAU_S = 40.0
CORR_RAD = 0.5
NOT_LEARNING = IronState(learning=False, updates=0, restored=False, before_rejection=False)


def _params(**kw):
    base = dict(mag_moves_tilt=False, mag_trusted_moves_tilt=True, iron_learned_tau_s=LEARNED_TAU_S,
                iron_heading_corr_rad=CORR_RAD, mag_bias_tau=BIAS_TAU_S)
    base.update(kw)
    return SimpleNamespace(**base)


def _use(params=None, **kw):
    args = dict(monitor_use=True, trusted_sigma_rad=TRUSTED, slow_var_rad2=(1.0 * DEG) ** 2,
                mag_var_rad2=(2.0 * DEG) ** 2, noise_rad2=(0.5 * DEG) ** 2, trust_var_rad2=(2.5 * DEG) ** 2,
                calibration_untrusted=True, iron=NOT_LEARNING, learned_floor_var_rad2=None, heading_rate_rad_s=0.1,
                yaw_var_rad2=(0.5 * DEG) ** 2)
    args.update(kw)
    for name in ("learned_floor_var_rad2", "heading_rate_rad_s"):     # the part asks for these when it reads them
        args[name] = (lambda value: lambda: value)(args[name])
    return magnetometer_use(params or _params(), **args)


def test_not_fused_while_the_iron_is_learned_even_where_the_monitor_lets_it_back():
    learning = replace(NOT_LEARNING, learning=True)
    assert _use(iron=learning).mag_use == 0.0
    assert _use(iron=learning).mag_moves_tilt == 0.0      # not used: not trusted either
    assert _use().mag_use == 1.0
    assert _use(monitor_use=False).mag_use == 0.0



def test_fused_while_the_iron_is_learned_once_its_offset_is_held():
    # pa96: an offset held (IronLearner.hold_offset) is no longer learned against the filter's yaw, so the learned
    # magnetometer fused meanwhile is not counted twice; the monitor's word still decides
    held = replace(NOT_LEARNING, learning=True, updates=10, offset_held=True)
    assert _use(iron=held).mag_use == 1.0
    assert _use(iron=held, monitor_use=False, learned_floor_var_rad2=(2.0 * DEG) ** 2).mag_use == 0.0
    assert _use(iron=replace(held, offset_held=False)).mag_use == 0.0

def test_the_horizon_is_moved_only_by_a_trusted_magnetometer_and_only_where_allowed():
    assert _use(slow_var_rad2=(1.0 * DEG) ** 2).mag_moves_tilt == 1.0
    # the previous check's slowly varying variance judges the trust, not this check's
    assert _use(slow_var_rad2=(4.0 * DEG) ** 2, mag_var_rad2=(1.0 * DEG) ** 2).mag_moves_tilt == 0.0
    assert _use(params=_params(mag_trusted_moves_tilt=False)).mag_moves_tilt == 0.0
    assert _use(monitor_use=False).mag_moves_tilt == 0.0
    # mag_moves_tilt: any magnetometer moves it, used or not
    assert _use(params=_params(mag_moves_tilt=True), monitor_use=False, slow_var_rad2=1.0).mag_moves_tilt == 1.0



def test_with_the_filters_own_defaults_only_a_trusted_magnetometer_moves_the_horizon():
    """ins's default InsParams, not this file's: a magnetometer the monitor keeps out, or one whose slowly varying
    variance is above the trusted σ, gets no gain on the tilt; a trusted one does (`mag_moves_tilt` True by
    default would let any magnetometer lean the horizon while aided: issue 29, item 5)."""
    from ahrsd.estimator.ins import InsParams

    p = InsParams()
    assert _use(params=p, monitor_use=False).mag_moves_tilt == 0.0
    assert _use(params=p, slow_var_rad2=(4.0 * DEG) ** 2, mag_var_rad2=(1.0 * DEG) ** 2).mag_moves_tilt == 0.0
    assert _use(params=p, slow_var_rad2=(1.0 * DEG) ** 2).mag_moves_tilt == 1.0


def test_the_bias_is_the_slow_part_with_the_learned_irons_time_constant_once_there_is_one():
    u = _use()
    assert u.mag_bias_var_rad2 == pytest.approx((2.0 * DEG) ** 2 - (0.5 * DEG) ** 2, rel=1e-12)
    assert u.mag_bias_tau_s == BIAS_TAU_S
    assert _use(iron=replace(NOT_LEARNING, updates=3)).mag_bias_tau_s == LEARNED_TAU_S
    assert _use(iron=replace(NOT_LEARNING, restored=True)).mag_bias_tau_s == LEARNED_TAU_S
    # no magnetometer heading at this check: the kernel keeps its own
    none = _use(mag_var_rad2=math.nan)
    assert none.mag_bias_var_rad2 is None and none.mag_bias_tau_s is None
    assert none.mag_use == 1.0


# the case where every condition holds: rejected, no trusted calibration, an iron learned since the rejection and
# none before, not restored, a finite trust variance, and a floor above the trust limit (high latitudes)
LEARNED_SINCE = IronState(learning=False, updates=5, restored=False, before_rejection=False)
HIGH_FLOOR = (4.0 * DEG) ** 2
REJECTED = dict(monitor_use=False, iron=LEARNED_SINCE, learned_floor_var_rad2=HIGH_FLOOR, calibration_untrusted=True,
                trust_var_rad2=(5.0 * DEG) ** 2, mag_var_rad2=(2.0 * DEG) ** 2, noise_rad2=(0.5 * DEG) ** 2,
                heading_rate_rad_s=0.05, yaw_var_rad2=(0.5 * DEG) ** 2)


def test_a_rejected_magnetometer_is_fused_at_its_floor_where_it_can_never_be_trusted():
    u = _use(**REJECTED)
    assert u.mag_use == 1.0
    assert u.mag_moves_tilt == 0.0
    assert u.mag_bias_var_rad2 == (5.0 * DEG) ** 2       # the trust variance, above the slow part
    assert u.mag_bias_tau_s == pytest.approx(CORR_RAD / 0.05)
    # the slow part when it is the larger; the learned iron's time constant when turning fast
    assert _use(**{**REJECTED, "trust_var_rad2": (1.0 * DEG) ** 2}).mag_bias_var_rad2 == pytest.approx(
        (2.0 * DEG) ** 2 - (0.5 * DEG) ** 2, rel=1e-12)
    assert _use(**{**REJECTED, "heading_rate_rad_s": 1.0}).mag_bias_tau_s == LEARNED_TAU_S
    # standing still: the time constant stays finite
    assert math.isfinite(_use(**{**REJECTED, "heading_rate_rad_s": 0.0}).mag_bias_tau_s)


@pytest.mark.parametrize("change", [
    {"params": _params(iron_heading_corr_rad=0.0)},
    {"calibration_untrusted": False},
    {"iron": replace(LEARNED_SINCE, updates=0)},
    {"iron": replace(LEARNED_SINCE, before_rejection=True)},
    {"iron": replace(LEARNED_SINCE, restored=True)},
    {"trust_var_rad2": math.inf},
    {"learned_floor_var_rad2": (2.0 * DEG) ** 2},     # it can re-enter here: left out until it does
    {"learned_floor_var_rad2": None},                  # no WMM field
], ids=["off", "trusted-calibration", "no-iron", "iron-before", "restored", "no-trust-var", "floor-low", "no-field"])
def test_a_rejected_magnetometer_stays_out_unless_every_condition_holds(change):
    u = _use(**{**REJECTED, **change})
    assert u.mag_use == 0.0


def test_never_trusted_here_compares_the_floor_with_the_trust_limit():
    assert never_trusted_here((3.1 * DEG) ** 2, TRUSTED, 0.0)
    assert not never_trusted_here((2.9 * DEG) ** 2, TRUSTED, 0.0)
    assert not never_trusted_here(None, TRUSTED, (5.0 * DEG) ** 2)
    assert never_trusted_here(math.inf, TRUSTED, 0.0)


def test_never_trusted_here_counts_the_yaw_the_iron_is_learned_against():
    """The learned iron takes in the learning window's yaw error as a heading offset (learned_iron.py), so the
    learned magnetometer is no better than floor² + yaw variance. Worked numbers (boat39): Punta Arenas, WMM
    horizontal field 19.61 µT, floor 1 µT / H = 2.92°, leaves room for a yaw 1σ of √(3² − 2.92²) = 0.69°; the
    held-out site, H 24.6 µT, floor 2.33°, room 1.89°."""
    floor_pa = (1.0 / 19.61) ** 2                         # rad², iron_unmodelled_ut 1 µT over H
    assert math.degrees(math.sqrt(floor_pa)) == pytest.approx(2.92, abs=0.005)
    room_deg = math.sqrt(3.0 ** 2 - math.degrees(math.sqrt(floor_pa)) ** 2)
    assert room_deg == pytest.approx(0.69, abs=0.01)
    assert never_trusted_here(floor_pa, TRUSTED, (1.0 * DEG) ** 2)              # the yaw σ after the learning
    assert never_trusted_here(floor_pa, TRUSTED, ((room_deg + 0.01) * DEG) ** 2)
    assert not never_trusted_here(floor_pa, TRUSTED, ((room_deg - 0.01) * DEG) ** 2)
    assert not never_trusted_here(floor_pa, TRUSTED, 0.0)                       # the floor alone: it could re-enter
    floor_site = (1.0 / 24.6) ** 2
    assert not never_trusted_here(floor_site, TRUSTED, (1.5 * DEG) ** 2)
    assert never_trusted_here(floor_site, TRUSTED, (2.0 * DEG) ** 2)


def test_a_rejected_magnetometer_is_fused_where_the_yaw_leaves_its_floor_no_room():
    """The whole rule with the yaw term: the same floor, below the trust limit, fused or not by the yaw variance."""
    floor = (2.9 * DEG) ** 2
    assert _use(**{**REJECTED, "learned_floor_var_rad2": floor, "yaw_var_rad2": (1.0 * DEG) ** 2}).mag_use == 1.0
    assert _use(**{**REJECTED, "learned_floor_var_rad2": floor, "yaw_var_rad2": (0.5 * DEG) ** 2}).mag_use == 0.0


def _not_to_be_read():
    raise AssertionError("read where no rule needs it")


@pytest.mark.parametrize("change", [{"monitor_use": True}, {"calibration_untrusted": False},
                                    {"iron": replace(LEARNED_SINCE, updates=0)}, {"trust_var_rad2": math.inf},
                                    {"mag_var_rad2": math.nan}],
                         ids=["monitor-uses", "trusted-calibration", "no-iron", "no-trust-var", "no-mag-heading"])
def test_the_floor_and_the_heading_rate_are_read_only_by_the_rule_that_needs_them(change):
    """The filter works out the floor and the heading rate at a check only when the rejected-but-fused rule reads
    them (they are asked for, not passed): where another condition decides first, neither is asked; where the
    rule's other conditions hold, both are."""
    args = {k: v for k, v in REJECTED.items() if k not in ("learned_floor_var_rad2", "heading_rate_rad_s")}
    args.update(trusted_sigma_rad=TRUSTED, slow_var_rad2=(1.0 * DEG) ** 2)
    u = magnetometer_use(_params(), **{**args, **change}, learned_floor_var_rad2=_not_to_be_read,
                         heading_rate_rad_s=_not_to_be_read)
    assert u.mag_use == (1.0 if change.get("monitor_use") else 0.0)
    asked = []
    u = magnetometer_use(_params(), **args, learned_floor_var_rad2=lambda: asked.append("floor") or HIGH_FLOOR,
                         heading_rate_rad_s=lambda: asked.append("rate") or 0.05)
    assert u.mag_use == 1.0 and asked == ["floor", "rate"]

"""Cross-validated tuning of `mekf` on the BROAD trials: how well a parameter choice carries over to unseen data.

    .venv/bin/python bench/accuracy.py --cv            # the candidate grid below, beside VQF
    .venv/bin/python bench/cv.py                       # the same, on its own
    .venv/bin/python bench/cv.py --candidate gyro_bias_walk_rad_s_sqrt_s=1e-4   # the defaults against other sets

Every candidate parameter set runs once on every trial (one batch run each). Then, for each fold:

* leave-one-trial-out (LOTO): hold one trial out, pick the candidate with the lowest mean total RMSE on the
  other trials, score that candidate on the held-out trial;
* leave-one-pair-out (LOPO): hold out every trial of one kind of motion (the A/C repetitions, the two
  stationary- and the two attached-magnet trials are one kind each), select on the rest, score on those held out.

The mean of the held-out scores is the cross-validated figure of the tuning procedure (select from this grid);
the in-sample figure is the candidate that is best on all trials, scored on those same trials. "Best": the
lowest mean; candidates within 0.1 % of it are a tie, broken by the worst trial against VQF. The gap between
the two is what the selection learned about these particular recordings. The grid varies one parameter at a
time around the defaults, a few values each (the machine is shared: keep it small).
"""

from __future__ import annotations

import math
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.broad import broad_errors, load_trial, ned_to_enu, trial_paths  # noqa: E402

_DEG = math.pi / 180.0

# (label, MekfParams overrides): the defaults first, then one parameter at a time
CANDIDATES: list[tuple[str, dict]] = [
    ("defaults", {}),
    ("acc_tau=1.0", {"acc_lowpass_tau_s": 1.0}),
    ("acc_tau=3.0", {"acc_lowpass_tau_s": 3.0}),
    ("acc_noise=0.08", {"acc_noise_m_s2": 0.08}),
    ("acc_noise=0.3", {"acc_noise_m_s2": 0.3}),
    ("acc_reject=1.0", {"acc_reject_m_s2": 1.0}),
    ("acc_reject=3.0", {"acc_reject_m_s2": 3.0}),
    ("bias_walk=3e-6", {"gyro_bias_walk_rad_s_sqrt_s": 3e-6}),
    ("bias_walk=3e-5", {"gyro_bias_walk_rad_s_sqrt_s": 3e-5}),
    ("hdg_noise=0.06", {"mag_heading_noise_rad": 0.06}),
    ("hdg_noise=0.2", {"mag_heading_noise_rad": 0.2}),
    ("dip_tol=10", {"mag_dip_tol_rad": 10.0 * _DEG}),
    ("dip_tol=20", {"mag_dip_tol_rad": 20.0 * _DEG}),
    ("norm_tol=0.05", {"mag_norm_tol": 0.05}),
    ("norm_tol=0.15", {"mag_norm_tol": 0.15}),
] + [
    ("acc_adapt=0,rate_noise=0", {"acc_adaptive_gain": 0.0, "gyro_rate_noise_sqrt_s": 0.0}),
] + [
    # the acceleration-adaptive tilt noise with the rate-dependent tilt process noise that balances it in fast
    # rotation: off, and a 4 × 4 grid
    (f"acc_adapt={gain:g},rate_noise={rate:g}", {"acc_adaptive_gain": gain, "gyro_rate_noise_sqrt_s": rate})
    for gain in (1.0, 3.0, 10.0, 30.0) for rate in (1e-4, 3e-4, 1e-3, 3e-3)
] + [
    # the body-fixed field offset (attached magnet): off, or learned with a forgetting time constant, and the
    # rotation between the snapshots it compares
    (f"mag_offset_tau={tau:g}", {"mag_offset_tau_s": tau}) for tau in (0.0, 30.0, 120.0)
] + [
    (f"mag_offset_angle={deg:g}", {"mag_offset_min_angle_rad": deg * _DEG}) for deg in (10.0, 30.0)
] + [
    (f"mag_offset_explain={ratio:g}", {"mag_offset_explain_ratio": ratio}) for ratio in (0.25, 0.75)
]


# the tuning procedures compared by their cross-validated figure: select from these candidates (labels' prefixes)
GRIDS: dict[str, tuple[str, ...]] = {
    "defaults only": ("defaults",),
    "one at a time": ("defaults", "acc_tau", "acc_noise", "acc_reject", "bias_", "hdg_", "dip_", "norm_"),
    "adaptive tilt": ("defaults", "acc_adapt="),
    "attached-magnet offset": ("defaults", "mag_offset_"),
    "adaptive tilt + offset": ("defaults", "acc_adapt=", "mag_offset_"),
    "all": ("",),
}


def kind_of(trial_name: str) -> str:
    """The kind of motion of a BROAD trial: its name without the number and the repetition / distance suffix
    ("10_undisturbed_slow_translation_A" → "undisturbed_slow_translation")."""
    kind = re.sub(r"^\d+_", "", trial_name)
    return re.sub(r"_([A-Z]|\d+cm)$", "", kind)


@dataclass
class CvResult:
    trials: list[str]
    labels: list[str]
    err_deg: np.ndarray        # (candidates, trials) total RMSE
    vqf_deg: np.ndarray        # (trials,)
    loto_deg: np.ndarray       # (trials,) held-out score, leave-one-trial-out
    loto_pick: list[int]       # candidate picked for each held-out trial
    lopo_deg: np.ndarray       # (trials,) held-out score, leave-one-pair(kind)-out
    lopo_pick: list[int]
    in_sample_pick: int        # best candidate on all trials


# candidates whose training mean is within this fraction of the best are a tie, broken by the worst trial
TIE_REL = 0.001  # 0.1 %: 0.002° on a 2° mean, no difference


def select(err_deg: np.ndarray, vqf_deg: np.ndarray, train: list[int]) -> int:
    """The candidate picked on the training trials: lowest mean total RMSE; among those within TIE_REL of it,
    the one whose worst trial against VQF is best (the targets bound the worst trial too)."""
    means = err_deg[:, train].mean(axis=1)
    tied = np.flatnonzero(means <= means.min() * (1.0 + TIE_REL))
    worst = (err_deg[np.ix_(tied, train)] / vqf_deg[train]).max(axis=1)
    return int(tied[np.argmin(worst)])


def held_out_scores(err_deg: np.ndarray, vqf_deg: np.ndarray, folds: list[list[int]]) -> tuple[np.ndarray, list[int]]:
    """For each fold (trial indices held out): the candidate `select`ed on the other trials, scored on the
    held-out trials. Returns the held-out error per trial and the pick per trial."""
    n_cand, n_trials = err_deg.shape
    score = np.full(n_trials, np.nan)
    pick = [-1] * n_trials
    for held in folds:
        best = select(err_deg, vqf_deg, [i for i in range(n_trials) if i not in held])
        for i in held:
            score[i] = err_deg[best, i]
            pick[i] = best
    return score, pick


def evaluate(err_deg: np.ndarray, vqf_deg: np.ndarray, trials: list[str], labels: list[str]) -> CvResult:
    loto, loto_pick = held_out_scores(err_deg, vqf_deg, [[i] for i in range(len(trials))])
    kinds = [kind_of(t) for t in trials]
    groups = [[i for i, k in enumerate(kinds) if k == kind] for kind in dict.fromkeys(kinds)]
    lopo, lopo_pick = held_out_scores(err_deg, vqf_deg, groups)
    return CvResult(trials, labels, err_deg, vqf_deg, loto, loto_pick, lopo, lopo_pick,
                    select(err_deg, vqf_deg, list(range(len(trials)))))


def run_grid(candidates=CANDIDATES, trial_names=None, max_samples=None) -> CvResult:
    """Every candidate and VQF on every trial (batch runs)."""
    from vqf import VQF

    from ahrsd.estimator.mekf import Mekf

    paths = trial_paths(names=trial_names)
    err = np.zeros((len(candidates), len(paths)))
    vqf_err = np.zeros(len(paths))
    names = []
    for j, p in enumerate(paths):
        tr = load_trial(p, max_samples=max_samples)
        names.append(tr.name)
        out = VQF(1.0 / tr.rate_hz).updateBatch(tr.gyro_rad_s, tr.accel_m_s2, tr.mag_ut)
        vqf_err[j] = broad_errors(out["quat9D"], tr).total_deg  # VQF's output is already IMU → ENU
        for c, (_, overrides) in enumerate(candidates):
            q, _ = Mekf(**overrides).run_batch(tr.t_s, tr.gyro_rad_s, tr.accel_m_s2, tr.mag_ut)
            err[c, j] = broad_errors(ned_to_enu(q), tr).total_deg
    return evaluate(err, vqf_err, names, [label for label, _ in candidates])


def parse_candidate(text: str) -> tuple[str, dict]:
    """`NAME=VALUE[,NAME=VALUE…]` (MekfParams fields, numbers) as a (label, overrides) candidate."""
    overrides = {}
    for item in text.split(","):
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"candidate {text!r}: expected NAME=VALUE[,NAME=VALUE…]")
        overrides[name.strip()] = float(value)
    return text, overrides


def print_report(r: CvResult, grids: bool = True) -> None:
    n_cand = len(r.labels)
    print(f"\n## (c) Cross-validated tuning on BROAD: {n_cand} candidate sets × {len(r.trials)} trials, "
          "total RMSE (deg) in movement phases")
    print("\ncandidate sets, in-sample (each scored on the trials it is judged on):")
    width = max(22, *(len(label) for label in r.labels))
    print(f"{'candidate':{width}s} {'mean':>6s} {'/VQF':>6s} {'worst /VQF':>11s} trial")
    for c, label in enumerate(r.labels):
        ratio = r.err_deg[c] / r.vqf_deg
        mark = "  <- best on all trials" if c == r.in_sample_pick else ""
        print(f"{label:{width}s} {r.err_deg[c].mean():6.3f} {r.err_deg[c].mean() / r.vqf_deg.mean():6.3f} "
              f"{ratio.max():11.2f} {r.trials[int(np.argmax(ratio))][:2]}{mark}")
    ins = r.err_deg[r.in_sample_pick]
    dflt = r.err_deg[0]
    print(f"\n{'trial':44s} {'vqf':>6s} {'dflt':>6s} {'in-smp':>6s} {'LOTO':>6s} {'LOPO':>6s} "
          f"{'LOTO/vqf':>8s}  picked (LOTO)")
    for i, name in enumerate(r.trials):
        print(f"{name:44s} {r.vqf_deg[i]:6.2f} {dflt[i]:6.2f} {ins[i]:6.2f} {r.loto_deg[i]:6.2f} "
              f"{r.lopo_deg[i]:6.2f} {r.loto_deg[i] / r.vqf_deg[i]:8.2f}  {r.labels[r.loto_pick[i]]}")
    print("-" * 100)
    kinds = [kind_of(t) for t in r.trials]
    for kind in dict.fromkeys(kinds):
        idx = [i for i, k in enumerate(kinds) if k == kind]
        v = r.vqf_deg[idx].mean()
        print(f"{'kind ' + kind:44s} {v:6.2f} {dflt[idx].mean():6.2f} {ins[idx].mean():6.2f} "
              f"{r.loto_deg[idx].mean():6.2f} {r.lopo_deg[idx].mean():6.2f} {r.loto_deg[idx].mean() / v:8.2f}")
    print("-" * 100)
    v = r.vqf_deg.mean()
    print(f"{'mean (all)':44s} {v:6.2f} {dflt.mean():6.2f} {ins.mean():6.2f} {r.loto_deg.mean():6.2f} "
          f"{r.lopo_deg.mean():6.2f} {r.loto_deg.mean() / v:8.3f}")
    for label, s in (("in-sample", ins), ("defaults", dflt), ("LOTO", r.loto_deg), ("LOPO", r.lopo_deg)):
        ratio = s / r.vqf_deg
        w = int(np.argmax(ratio))
        print(f"mekf / VQF {label:10s}: mean ratio {s.mean() / v:.3f} (target ≤ 0.90); worst trial "
              f"{r.trials[w]} {ratio[w]:.2f} (target ≤ 1.30)")
    if not grids:
        return
    print(f"\n{'tuning procedure (select from)':32s} {'n':>3s} {'in-smp':>7s} {'LOTO':>7s} {'LOPO':>7s} "
          f"{'worst LOTO/vqf':>15s}  picked on all trials")
    for grid, prefixes in GRIDS.items():
        rows = [c for c, label in enumerate(r.labels)
                if label == "defaults" or any(label.startswith(p) for p in prefixes if p != "defaults")]
        if grid == "defaults only":
            rows = [0]
        sub = evaluate(r.err_deg[rows], r.vqf_deg, r.trials, [r.labels[c] for c in rows])
        print(f"{grid:32s} {len(rows):3d} {sub.err_deg[sub.in_sample_pick].mean() / v:7.3f} "
              f"{sub.loto_deg.mean() / v:7.3f} {sub.lopo_deg.mean() / v:7.3f} "
              f"{(sub.loto_deg / r.vqf_deg).max():15.2f}  {sub.labels[sub.in_sample_pick]}")
    print("(ratios of the mean to VQF's mean)")
    counts = {r.labels[c]: r.loto_pick.count(c) for c in sorted(set(r.loto_pick))}
    print("\nLOTO picks (all): " + ", ".join(f"{k} ×{n}" for k, n in counts.items()))
    counts = {r.labels[c]: r.lopo_pick.count(c) for c in sorted(set(r.lopo_pick))}
    print("LOPO picks (all, per trial): " + ", ".join(f"{k} ×{n}" for k, n in counts.items()))


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", nargs="*", help="BROAD trial name prefixes or substrings (default: all)")
    ap.add_argument("--max-samples", type=int, default=None)
    ap.add_argument("--candidate", action="append", default=None, metavar="NAME=VALUE[,NAME=VALUE…]",
                    help="instead of the grid: the defaults and this MekfParams set (repeatable); the report "
                         "then has no tuning-procedure table")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    candidates = CANDIDATES if not args.candidate else [("defaults", {})] + [parse_candidate(c) for c in args.candidate]
    r = run_grid(candidates, trial_names=args.trials, max_samples=args.max_samples)
    print_report(r, grids=not args.candidate)
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

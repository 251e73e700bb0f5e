"""bench/cv.py's cross-validation: the held-out selection is computed by hand on a small error table."""

from __future__ import annotations

import numpy as np

from bench.cv import TIE_REL, evaluate, held_out_scores, kind_of, select


def test_leave_one_out_picks_on_the_other_trials_and_scores_the_held_out_one():
    # candidate 0 is perfect on trials 0, 1 and bad on 2; candidate 1 is mediocre everywhere
    err = np.array([[1.0, 1.0, 10.0], [2.0, 2.0, 2.0]])
    score, pick = held_out_scores(err, np.ones(3), [[0], [1], [2]])
    # hold out 0: means on {1, 2} are 5.5 and 2 → candidate 1 → 2.0; likewise for 1;
    # hold out 2: means on {0, 1} are 1 and 2 → candidate 0 → 10.0 (the overfit pick pays on the held-out)
    assert pick == [1, 1, 0]
    np.testing.assert_array_equal(score, [2.0, 2.0, 10.0])


def test_leave_one_pair_out_holds_out_every_trial_of_a_kind():
    trials = ["01_undisturbed_slow_rotation_A", "03_undisturbed_slow_rotation_C",
              "32_disturbed_attached_magnet_1cm", "34_disturbed_attached_magnet_3cm"]
    assert [kind_of(t) for t in trials] == ["undisturbed_slow_rotation"] * 2 + ["disturbed_attached_magnet"] * 2
    err = np.array([[1.0, 1.0, 2.2, 2.2], [3.0, 3.0, 2.0, 2.0]])
    r = evaluate(err, np.ones(4), trials, ["a", "b"])
    # rotation pair held out → selected on the magnet pair (2.2 vs 2.0) → "b"; magnet pair held out → "a"
    assert r.lopo_pick == [1, 1, 0, 0]
    np.testing.assert_array_equal(r.lopo_deg, [3.0, 3.0, 2.2, 2.2])
    # leave-one-trial-out keeps the other repetition in training: "a" wins every fold (means 1.8 vs 2.33,
    # 1.4 vs 2.67), so it looks better than leaving the whole kind out
    assert r.loto_pick == [0, 0, 0, 0]
    np.testing.assert_array_equal(r.loto_deg, err[0])
    assert r.in_sample_pick == 0        # means 1.6 and 2.5


def test_a_tie_in_the_mean_is_broken_by_the_worst_trial_against_vqf():
    vqf = np.array([1.0, 2.0, 2.0])
    err = np.array([[1.0, 2.0, 3.0],        # mean 2.0, worst ratio 1.5
                    [1.2, 2.4, 2.4]])       # mean 2.0, worst ratio 1.2
    err[0, 2] -= 0.5 * TIE_REL * 6.0        # row 0 now lower by half the tie margin: still a tie
    assert err[0].mean() < err[1].mean()
    assert select(err, vqf, [0, 1, 2]) == 1  # the better worst trial wins the tie
    err[0, 2] -= 3.0 * TIE_REL * 6.0        # row 0 lower by more than the margin: the lowest mean wins
    assert select(err, vqf, [0, 1, 2]) == 0

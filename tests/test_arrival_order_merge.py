"""simulation.gnss.in_arrival_order merges samples and fixes exactly as heapq.merge of their keys (time, 0 for a
fix / 1 for a sample, index) does: compared with that reference on random inputs, with ties, NaN times (one NaN
object and distinct ones), samples out of order and either input empty."""

import heapq
import random
from types import SimpleNamespace

from ahrsd.simulation.gnss import in_arrival_order


def _reference(samples, fixes):
    arrival = sorted((f.extra.get("t_rx_s", f.t_s), i) for i, f in enumerate(fixes))
    keyed_imu = ((s.t_s, 1, i, s) for i, s in enumerate(samples))
    keyed_fix = ((t, 0, i, fixes[i]) for t, i in arrival)
    return [item for *_, item in heapq.merge(keyed_imu, keyed_fix)]


def test_the_merge_is_heapq_merge_of_the_keys():
    rnd = random.Random(34)
    shared_nan = float("nan")

    def t():
        x = rnd.choice([0.0, 0.5, 1.0, 1.5, 2.0, None, None, 3.0])
        return x if x is not None else (shared_nan if rnd.random() < 0.5 else float("nan"))

    for _ in range(3000):
        samples = [SimpleNamespace(t_s=t()) for _ in range(rnd.randint(0, 6))]
        if rnd.random() < 0.7:
            samples.sort(key=lambda s: (s.t_s != s.t_s, s.t_s))
        fixes = [SimpleNamespace(t_s=t(), extra={"t_rx_s": t()} if rnd.random() < 0.7 else {})
                 for _ in range(rnd.randint(0, 5))]
        got, want = list(in_arrival_order(samples, fixes)), _reference(samples, fixes)
        assert len(got) == len(want) and all(a is b for a, b in zip(got, want))

"""bench/reader_calls.py `--split`: the reader thread's CPU from each wake's return to the next wait is counted, and
the wait itself is not.

The truth is made here: a stand-in pacing class whose wait and whose work between waits move a stepped CPU clock by
known amounts (the wait 1000 ns, the work after the first, second and third wake 30, 50 and 70 ns), so the work
counted must be 30 + 50 + 70 = 150 ns over three loops, whatever the machine's load."""

from __future__ import annotations

from bench.reader_calls import time_loop_work


class _SteppedCpu:
    def __init__(self):
        self.ns = 0

    def __call__(self) -> int:
        return self.ns


def _pacing_class(cpu: _SteppedCpu):
    class Pacing:
        def __init__(self):
            self.stats: dict = {}

        def wait_for_sample(self) -> bool:
            cpu.ns += 1000          # the sleep, the timer's next read time: not work
            return True

    return Pacing


def test_the_work_between_waits_is_counted_and_the_wait_is_not():
    cpu = _SteppedCpu()
    pacing_class = _pacing_class(cpu)
    time_loop_work(pacing_class, cpu_ns=cpu)
    pacing = pacing_class()
    pacing.wait_for_sample()            # the first wait: no work before it to count
    for work_ns in (30, 50, 70):
        cpu.ns += work_ns               # the read, the chip, the hand-over tick
        assert pacing.wait_for_sample() is True
    assert pacing.stats == {"split_work_ns": 150, "split_loops": 3}


def test_a_wait_that_raises_still_ends_the_wait():
    cpu = _SteppedCpu()
    pacing_class = _pacing_class(cpu)

    def failing_wait(self):
        cpu.ns += 1000
        raise InterruptedError

    pacing_class.wait_for_sample = failing_wait
    time_loop_work(pacing_class, cpu_ns=cpu)
    pacing = pacing_class()
    for _ in range(2):
        try:
            pacing.wait_for_sample()
        except InterruptedError:
            pass
        cpu.ns += 40
    assert pacing.stats == {"split_work_ns": 40, "split_loops": 1}


def test_the_hot_loop_reads_each_sample_once_and_hands_every_one_over():
    """`--hot`: the stepped clock paces the reader at the chip's sample times (a read per sample, few stale), the
    counted window is the N loops asked after the warm-up, and every fresh sample is handed over (none dropped at a
    full buffer, which would make the loop cheaper than the reader's)."""
    from bench.reader_calls import hot_reads

    r = hot_reads(500)
    assert r["loops"] == 500
    assert r["handed_over"] == r["reads"] - r["stale"]
    assert r["reads"] == 1000 + 500 - 1          # warm-up and window; the stopping loop reads no more
    assert r["stale"] < 0.05 * r["reads"]
    assert 0.0 < r["chip_s"] < r["cpu_s"]

"""bench/soak.py's answered-requests criterion, on hand-counted figures: a kind of request answered on fewer than
95 % fails unless the kernel counted at least as many datagrams dropped (on the daemon's socket or the client's)
as there are unanswered requests: a daemon stalled on a loaded machine loses what did not fit its socket's
buffer, counted by the kernel, never unseen."""

from __future__ import annotations

from bench import soak

SENT = {"ack": 1000, "param_value": 200}


def test_every_request_answered_passes():
    _lines, failed = soak.answers_accounted(SENT, {"ack": 1000, "param_value": 3200}, 0, 0, 0, 10.0)
    assert failed == []


def test_unanswered_requests_fail_unless_the_kernel_counted_them_dropped():
    answers = {"ack": 900, "param_value": 200}        # 100 acks unanswered: 90 %
    _l, failed = soak.answers_accounted(SENT, answers, 0, 0, 0, 10.0)
    assert [f for f in failed if "ack" in f] != []
    _l, failed = soak.answers_accounted(SENT, answers, 0, 60, 39, 10.0)   # 99 counted dropped: one unseen
    assert [f for f in failed if "ack" in f] != []
    _l, failed = soak.answers_accounted(SENT, answers, 0, 60, 40, 10.0)   # 100 counted: all accounted for
    assert failed == []


def test_timesync_counts_refused_and_the_kernels_drops():
    sent = {"timesync": 500}
    # 10 s at the per-sender limit: BURST + 20/s answerable; the rest must be counted refused
    answerable = int(soak.BURST + soak.ANSWERS_PER_S * 10.0)
    _l, failed = soak.answers_accounted(sent, {"timesync": answerable}, 500 - answerable, 0, 0, 10.0)
    assert failed == []
    _l, failed = soak.answers_accounted(sent, {"timesync": answerable - 40}, 500 - answerable, 0, 0, 10.0)
    assert failed != []
    _l, failed = soak.answers_accounted(sent, {"timesync": answerable - 40}, 500 - answerable, 40, 0, 10.0)
    assert failed == []

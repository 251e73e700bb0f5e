"""Keeping a throwaway estimator's news out of the daemon's log.

The warm-up (estimator.warm_up) runs an estimator on made-up samples and a made-up fix to compile its kernels; what
that estimator says about itself ("ins: velocity and position set from the GNSS fix at t=0.000 s") is not news of
the daemon's vehicle, so below WARNING it is not logged while the warm-up runs.
"""

from __future__ import annotations

import logging
from contextlib import contextmanager


@contextmanager
def estimator_news_muted():
    """Within the block the `ahrsd.estimator` loggers log WARNING and above only."""
    estimator_log = logging.getLogger("ahrsd.estimator")
    level = estimator_log.level
    estimator_log.setLevel(max(level, logging.WARNING))
    try:
        yield
    finally:
        estimator_log.setLevel(level)

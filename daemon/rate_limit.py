"""A token bucket: at most `burst` events at once, refilled at `rate_per_s`.

Used to bound the STATUSTEXTs that remote input can trigger (a hostile or broken link sending refused
parameter writes must not be able to fill the radio link with our answers).
"""

from __future__ import annotations


class TokenBucket:
    def __init__(self, rate_per_s: float, burst: int) -> None:
        self.rate_per_s = float(rate_per_s)
        self.burst = float(burst)
        self._tokens = float(burst)
        self._last_s: float | None = None

    def take(self, now_s: float) -> bool:
        """Spend one token if there is one (True) or refuse (False)."""
        if self._last_s is not None:
            self._tokens = min(self.burst, self._tokens + (now_s - self._last_s) * self.rate_per_s)
        self._last_s = now_s
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False

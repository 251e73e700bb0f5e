"""What `HealthReport` is given besides the health and the outbound link, as the tests build it
(test_state_change_statustext, test_heading_status): the service's sample count and the systemd notifier."""

from __future__ import annotations


class Counts:
    samples = 0


class Notifier:
    """Records the status lines it is told (sd_notify's STATUS=); the watchdog ping does nothing."""

    def __init__(self):
        self.statuses = []

    def status(self, text):
        self.statuses.append(text)

    def watchdog(self):
        pass

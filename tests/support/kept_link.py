"""An endpoint that keeps what it is sent: what daemon.outbound.Outbound needs of an endpoint (`send`,
`send_together`), for the parts built alone."""

from __future__ import annotations


class KeptLink:
    def __init__(self):
        self.sent = []

    def send(self, msg) -> bool:
        self.sent.append(msg)
        return True

    def send_together(self, msgs) -> bool:
        self.sent += msgs
        return True

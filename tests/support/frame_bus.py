"""A test's SPI bus that answers a burst read with one given frame and register reads from a table, pipelined like
the ADIS16405 (the data of a request arrives in the next 2-byte frame): the driver's frame checks and its register
reads after a burst (tests/test_drivers_adis16405.py, tests/test_adis_index_read.py) against answers built word
by word."""

from __future__ import annotations

import time

from ahrsd.drivers import registers as R


class FrameBus:
    """`words`: the burst's twelve words after the command's slot; `registers`: address → the word a register
    read answers (0 for any other address)."""

    def __init__(self, words, registers):
        self.frame = bytes(2) + b"".join(w.to_bytes(2, "big") for w in words)
        self.registers = registers
        self.requested = None

    def transfer(self, tx, speed_hz, delay_us=0):
        if tx[:2] == R.BURST_COMMAND:
            return self.frame
        answer = self.registers.get(self.requested, 0) if self.requested is not None else 0
        self.requested = tx[0] & 0x7F if not tx[0] & R.WRITE_BIT else None
        return answer.to_bytes(2, "big")

    def sleep(self, seconds):
        time.sleep(seconds)

    def close(self):
        pass

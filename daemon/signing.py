"""MAVLink 2 signing set-up (mavlink.io en/guide/message_signing.md): key loading and the persisted signing timestamp.

The key file holds the 32-byte secret either raw or as 64 hex characters. The key is never logged (only a
short SHA-256 fingerprint, which identifies the key without revealing it). The signing timestamp (10 µs units
since 2015-01-01) must never go backwards, even across reboots of a computer without an RTC, so the last one
is stored in the state directory and the next run starts at max(clock, stored + 1 minute).

`verify_signature_before_timestamp` closes a hole in pymavlink's receive check (see there).
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import os
import time
from pathlib import Path

from ahrsd.calibration.atomic_file import write_atomic

log = logging.getLogger(__name__)

SIGNING_EPOCH_UNIX_S = 1420070400   # 2015-01-01T00:00:00Z (MAVLink signing spec)
TIMESTAMP_FILE = "signing_timestamp"
ONE_MINUTE = 60 * 100_000           # in 10 µs units


class SigningKeyError(ValueError):
    pass


SIGNATURE_LEN = 6


def verify_signature_before_timestamp(mav) -> None:
    """Make `mav` (a pymavlink MAVLink object with signing set up) check a frame's signature before it looks
    at its timestamp.

    pymavlink's MAVLink.check_signature stores the frame's timestamp as the newest of its stream (link id,
    system, component) first and verifies the signature after, so anyone on the link could send one frame with
    a forged signature, a genuine sender's ids and a timestamp far ahead, and every later genuinely signed frame
    of that sender would be refused as a replay. The signature (the first 6 bytes of
    SHA-256(key + frame up to the signature), MAVLink 2 signing spec) is checked here first; only a frame that
    passes reaches pymavlink's timestamp bookkeeping.
    """
    timestamp_check = mav.check_signature

    def check(msgbuf, src_system, src_component) -> bool:
        digest = hashlib.sha256(mav.signing.secret_key + bytes(msgbuf[:-SIGNATURE_LEN])).digest()
        if not hmac.compare_digest(digest[:SIGNATURE_LEN], bytes(msgbuf[-SIGNATURE_LEN:])):
            return False
        return timestamp_check(msgbuf, src_system, src_component)

    mav.check_signature = check


def load_key(path: str | os.PathLike) -> bytes:
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise SigningKeyError(f"signing.key_file {path}: cannot read ({exc.strerror})") from None
    text = data.strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    if len(data) == 32:
        return data
    raise SigningKeyError(f"signing.key_file {path}: expected 32 raw bytes or 64 hex characters "
                          f"(found {len(data)} bytes)")


def key_fingerprint(key: bytes) -> str:
    return hashlib.sha256(key).hexdigest()[:8]


def clock_timestamp(now_unix_s: float | None = None) -> int:
    now = time.time() if now_unix_s is None else now_unix_s    # host clock: the MAVLink signing epoch is UTC
    return max(0, int((now - SIGNING_EPOCH_UNIX_S) * 100_000))


def initial_timestamp(state_dir: Path | None) -> int:
    stored = read_timestamp(state_dir)
    return max(clock_timestamp(), stored + ONE_MINUTE if stored else 0)


def read_timestamp(state_dir: Path | None) -> int:
    if state_dir is None:
        return 0
    try:
        return int((Path(state_dir) / TIMESTAMP_FILE).read_text().strip())
    except (OSError, ValueError):
        return 0


def save_timestamp(state_dir: Path | None, timestamp: int) -> None:
    if state_dir is None or timestamp <= 0:
        return
    path = Path(state_dir) / TIMESTAMP_FILE
    try:
        write_atomic(path, f"{int(timestamp)}\n".encode())
    except OSError as exc:
        log.warning("cannot store the signing timestamp in %s: %s", path, exc)

"""The state directory when none is given (calibration, parameters, heading memory, logs): one rule for
`ahrsd run`, `ahrsd calibrate` and `ahrsd log`, so a calibration written by hand is the one a run loads
(two defaults would let calibrate-then-run run uncalibrated).
"""

from __future__ import annotations

import os
from pathlib import Path

# systemd/ahrsd.service: StateDirectory=ahrsd (with DynamicUser=yes a link to /var/lib/private/ahrsd)
SERVICE_STATE_DIR = Path("/var/lib/ahrsd")


def default_state_dir(environ=os.environ) -> Path:
    """1. $STATE_DIRECTORY (its first entry): the service, which systemd gives its StateDirectory;
    2. /var/lib/ahrsd when it exists and this user may write there: the service is installed on this computer
       (it creates the directory at its first start), so a calibration made by hand (as root) is the one it
       loads, and a run by hand uses the vehicle's calibration;
    3. $XDG_STATE_HOME/ahrsd, by default ~/.local/state/ahrsd: a development computer, or a user who may not
       write the service's directory."""
    if environ.get("STATE_DIRECTORY"):
        return Path(environ["STATE_DIRECTORY"].split(":")[0])
    if SERVICE_STATE_DIR.is_dir() and os.access(SERVICE_STATE_DIR, os.W_OK | os.X_OK):
        return SERVICE_STATE_DIR
    return Path(environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state") / "ahrsd"

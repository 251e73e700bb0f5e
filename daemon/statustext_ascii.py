"""The bytes of a STATUSTEXT: the daemon's messages in plain ASCII.

The daemon's log lines use "±", "°", "µT", "σ"; a STATUSTEXT carries `char[50]`, which ground stations decode as
ASCII (MAVProxy prints each byte of a UTF-8 "±" as a replacement character, "(��0.3��)"). So the text is spelled
out in ASCII here, at the one edge every STATUSTEXT goes through, and the log keeps its symbols.
"""

from __future__ import annotations

import unicodedata

# what a ground station operator reads for each symbol the daemon's texts use
_SPELLED = {
    "±": "+-", "°": " deg", "µ": "u", "μ": "u", "σ": "sigma", "→": "->", "←": "<-", "×": "x", "÷": "/",
    "≤": "<=", "≥": ">=", "≈": "~", "−": "-", "–": "-", "—": "-", "…": "...", "·": ".", "’": "'", "‘": "'",
    "“": '"', "”": '"', "²": "^2", "³": "^3", "Δ": "d", "δ": "d", "ψ": "psi", "φ": "phi", "θ": "theta",
}


def statustext_ascii(text: str) -> bytes:
    """`text` as ASCII bytes for a STATUSTEXT: the symbols above spelled out, accents dropped (NFKD), anything else
    '?'. "heading from magnetometer (±0.3°)" → b"heading from magnetometer (+-0.3 deg)"."""
    spelled = "".join(_SPELLED.get(c, c) for c in text).replace("  deg", " deg")
    plain = unicodedata.normalize("NFKD", spelled)
    return "".join(c for c in plain if not unicodedata.combining(c)).encode("ascii", "replace")

"""Accuracy of the GNSS-aided `ins` beside mekf and VQF on moving scenarios: an alias of the vehicle section of
bench/accuracy.py (one implementation, bench/vehicle_accuracy.py).

    .venv/bin/python bench/ins_accuracy.py              # = accuracy.py --vehicles (boat, car, plane)
    .venv/bin/python bench/ins_accuracy.py --quick      # 1 seed, one site
    .venv/bin/python bench/ins_accuracy.py --vehicle-scenarios coordinated-turn level-turns
"""

from __future__ import annotations

import sys
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.accuracy import main as accuracy_main  # noqa: E402


def main(argv=None) -> int:
    return accuracy_main(["--vehicles", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    raise SystemExit(main())

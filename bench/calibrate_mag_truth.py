"""`ahrsd calibrate mag --json` outputs against the simulator's truth: the calibration's true-heading error on
bench/backstepping_gnss.py's grid (the noise-free raw field of the same simulated sensor and vehicle iron at every
5° of heading, roll and pitch each in −8…8°, tilt-compensated with that true tilt; the mean offset NOT removed),
beside what the fit predicts and the share of grid errors beyond 3σ of it (σ = √(offset² + heading-dependent²)).

    ahrsd record --sim car --seconds 150 --seed 3 -o car3.csv
    ahrsd calibrate mag --method backstepping car3.csv --gnss car3.gnss.csv --dry-run --json > car3.json
    .venv/bin/python bench/calibrate_mag_truth.py car 3 car3.json

The recording must be at the default site (`record` without --site/--iron): the truth is
`simulation.open_stream(SCENARIO, seed=SEED).errors` and DEFAULT_SITE's field (bench/sim_calibration.py's way).
It also prints the fit's levelling passes (kept one starred) and their GNSS velocity rejections.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.backstepping_gnss import _rms, grid_error_deg  # noqa: E402


def judge(scenario: str, seed: int, fit_json: dict) -> str:
    from ahrsd.calibration.models import MagModel
    from ahrsd.simulation import DEFAULT_SITE, open_stream

    errors = open_stream(scenario, seed=seed).errors
    truth = SimpleNamespace(field=DEFAULT_SITE.earth_field(), soft_iron=errors.soft_iron,
                            hard_iron_ut=errors.hard_iron_ut)
    model = MagModel(np.asarray(fit_json["hard_iron_ut"]), np.asarray(fit_json["soft_iron"]))
    err = grid_error_deg(truth, model)
    q = fit_json.get("quality", {})
    pred = q.get("predicted_heading", {})
    sigma = float(np.hypot(pred.get("offset_std_deg", np.nan), pred.get("heading_dependent_std_deg", np.nan)))
    passes = []
    for p in q.get("aided_levelling", {}).get("passes", []):
        if "levelling" in p:
            passes.append(f"{p['levelling']}{' *' if p.get('kept') else ''}: {'ok' if p['ok'] else 'refused'}")
        else:
            g = p.get("gnss", {})
            passes.append(f"magnetometer {p['magnetometer']}: {'ok' if p['ok'] else 'refused'}, rejected "
                          f"{g.get('rejected_velocity')}/{g.get('offered')}, resets {g.get('reset_velocity')}")
    return (f"{scenario} seed {seed}: grid RMS {_rms(err):.3f}° (mean {err.mean():+.3f}°, max {np.abs(err).max():.3f}°); "
            f"predicted offset {pred.get('offset_std_deg', np.nan):.2f}° / heading-dependent "
            f"{pred.get('heading_dependent_std_deg', np.nan):.2f}°; beyond 3σ {100 * np.mean(np.abs(err) > 3 * sigma):.1f} %"
            f"\n  passes: {'; '.join(passes)}\n  warnings: {q.get('warnings', [])}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario")
    ap.add_argument("seed", type=int)
    ap.add_argument("fit_json", help="the output of `ahrsd calibrate mag ... --json`")
    args = ap.parse_args()
    text = Path(args.fit_json).read_text()
    print(judge(args.scenario, args.seed, json.loads(text[text.index("{"):])))


if __name__ == "__main__":
    main()

"""What a daemon's own process imports: `ahrsd run` imports the simulation package for the scenario names and the
simulator's site, never for a rotation (its simulated chip runs in the reader's producer process), so that import
must not load scipy.spatial (simulation/scenarios.py says why; the figure is in docs/simulation.md)."""

from __future__ import annotations

import subprocess
import sys

# the modules `ahrsd run --sim` imports in its own process before the estimator's kernels load (cli/run.py)
DAEMON_IMPORTS = ("ahrsd.cli.main", "ahrsd.cli.run", "ahrsd.daemon.config", "ahrsd.daemon.position",
                  "ahrsd.daemon.service", "ahrsd.drivers.source")


def test_the_daemon_process_imports_no_scipy_spatial_for_the_scenario_names():
    probe = (f"import sys\nimport {', '.join(DAEMON_IMPORTS)}\n"
             "from ahrsd.daemon.config import Config\n"
             "Config().with_overrides(sim='rate-table')\n"         # the --sim check reads the scenario names
             "print(sorted(m for m in sys.modules if m.startswith('scipy.spatial')))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout

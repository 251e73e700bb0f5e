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
    """And, in the same process, no pynmeagps without an NMEA output (daemon/nmea_sentences.py imports it where it
    builds a sentence)."""
    probe = (f"import sys\nimport {', '.join(DAEMON_IMPORTS)}\n"
             "from ahrsd.daemon.config import Config\n"
             "Config().with_overrides(sim='rate-table')\n"         # the --sim check reads the scenario names
             "print(sorted(m for m in sys.modules if m.startswith('scipy.spatial')))\n"
             "print(sorted(m for m in sys.modules if m.startswith('pynmeagps')))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    spatial, unused = out.stdout.splitlines()
    assert spatial == "[]", out.stdout
    assert unused == "[]", out.stdout


def test_the_ahrsd_script_module_imports_neither_numpy_nor_the_estimator():
    """multiprocessing's spawn imports the parent's main module again in each child it starts (the daemon's
    sensor reader, the field fit's worker): for the `ahrsd` script that is ahrsd.cli.main, which must then not
    load numpy or digest the kernels' sources (ahrsd.estimator) for the --estimator choices.

    In the same process, then, what the fit's worker imports next (daemon/magcal.py's `_warm_up`, the job's
    modules): no numba, so no estimator's kernels (the levelling error's one estimator default comes from
    estimator/accel_bias_prior.py, not estimator/mekf.py)."""
    probe = ("import sys\nimport ahrsd.cli.main\n"
             "print(sorted(m for m in sys.modules if m == 'numpy' or m.startswith('ahrsd.estimator')))\n"
             "import ahrsd.daemon.magcal\nahrsd.daemon.magcal._warm_up()\n"
             "print(sorted(m for m in sys.modules if m == 'numba' or m.startswith('numba.')))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    script, worker = out.stdout.splitlines()
    assert script == "[]", out.stdout
    assert worker == "[]", out.stdout


def test_a_command_runs_with_numbas_cache_at_the_source_keyed_directory():
    """A command's own numba kernels (calibration/allan/irls.py is outside ahrsd.estimator) are defined once the
    estimator package has pointed numba's cache at the directory keyed by the kernels' sources, as when
    ahrsd.cli.main imported it at its top."""
    probe = ("import os, sys\nimport ahrsd.cli.log as log\nfrom ahrsd.cli.main import main\n"
             "def spy(args):\n"
             "    print(os.path.basename(os.environ.get('NUMBA_CACHE_DIR', '')).startswith('ahrsd-kernels-'),\n"
             "          'numba' in sys.modules)\n"
             "    return 0\n"
             "log.run = spy\n"
             "sys.exit(main(['log', 'list', '--dir', '.']))")
    env = {k: v for k, v in __import__("os").environ.items() if k != "NUMBA_CACHE_DIR"}
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "False"], out.stdout

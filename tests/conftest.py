"""Shared test fixtures. Tests that need ../shared (real data) skip with a reason when it is absent.

Shared helpers live in tests/support (import `support.<module>`); the benchmark scripts import as `bench.<name>`
(the repository root is put on the path here, once, for the tests that pin a benchmark's criteria)."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("AHRSD_SHARED", REPO.parent / "shared"))
BROAD_DIR = SHARED / "data" / "broad"

if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

# One BLAS thread per process (the workers, and the daemons and CLI runs they start, inherit it; numpy is not
# imported yet). The suite already runs more processes than the machine has cores: OpenBLAS's own threads,
# one per core in each process, then wait for a core by spinning, which costs CPU and changes no result.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# Bytecode on, whatever the environment says: the suite starts many Python processes (the numba warm-up, daemons,
# CLI runs), and with PYTHONDONTWRITEBYTECODE set each one compiles ahrsd's sources again. The first process to
# import a module writes its .pyc (into the checkout's __pycache__, which git ignores); the others load it.
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False


_warm_up_running: list[subprocess.Popen] = []     # the numba warm-up's ins group, while the workers collect


def pytest_configure(config):
    """With pytest-xdist workers (the README's `-n 4`), compile the numba kernels once in the controller before
    the workers run a test (tests/support/numba_warm_up.py says why); the groups run side by side. Skipped in a
    worker, without -n, and with AHRSD_TEST_NO_WARM_UP=1.

    The mekf group ends long before the ins group, and on the core it leaves idle one collection of the tests
    runs meanwhile: it writes the test modules' assertion-rewritten bytecode, which each worker would otherwise
    make again on a fresh checkout (the workers collect at the same time, so none finds another's). The workers
    start when that collection is done, and collect while the ins group still compiles (collecting calls no
    kernel); the controller hands out the first test when the ins group is done
    (pytest_xdist_node_collection_finished)."""
    workers = getattr(config.option, "numprocesses", None)
    if workers and not hasattr(config, "workerinput"):
        # hand out the files in the workers' collection order (pytest_collection_modifyitems below), not
        # re-sorted by their number of tests
        config.option.loadscopereorder = False
    if hasattr(config, "workerinput") or not workers or os.environ.get("AHRSD_TEST_NO_WARM_UP") == "1":
        return
    script = Path(__file__).parent / "support" / "numba_warm_up.py"
    # the workers (started after this, with this environment) learn that the kernels are compiled before their
    # first test: a module that compiles them itself for a run without -n skips that (test_gnss_daemon_run)
    os.environ["AHRSD_TEST_KERNELS_WARMED_UP"] = "1"
    ins, mekf = (subprocess.Popen([sys.executable, str(script), group], stdout=subprocess.DEVNULL)
                 for group in ("ins", "mekf"))
    _warm_up_running.append(ins)
    mekf.wait()
    collect = subprocess.Popen([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                                *config.args], cwd=config.invocation_params.dir, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, env=dict(os.environ, AHRSD_TEST_NO_WARM_UP="1"))
    collect.wait()


def _warm_up_done() -> None:
    while _warm_up_running:
        _warm_up_running.pop().wait()


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_node_collection_finished(node, ids):
    """In the controller, before it schedules the workers' tests: the warm-up's ins group has written its cache
    (a worker that ran an ins test before would compile the kernels itself)."""
    _warm_up_done()


def pytest_unconfigure(config):
    _warm_up_done()       # a run that ended before any worker collected leaves no compiler behind


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config, items):
    """In a pytest-xdist worker (whose collection order the controller hands the files out in, one file to a
    worker under `--dist loadfile`): the files with a `slow` test first, then the others by their number of
    tests, as pytest-xdist itself would order them; each file's tests keep their order. A long file that
    starts last, as a file of one or two tests would, ends the run on one worker while the others stand idle;
    started first, it runs beside the rest."""
    if not hasattr(config, "workerinput"):
        return
    files: dict[str, list[int]] = {}      # file -> [index of its first test, its number of tests, has a slow test]
    for index, item in enumerate(items):
        entry = files.setdefault(item.nodeid.split("::")[0], [index, 0, 0])
        entry[1] += 1
        entry[2] |= item.get_closest_marker("slow") is not None
    order = {name: (not slow, -count, first) for name, (first, count, slow) in files.items()}
    items[:] = [item for _, item in sorted(enumerate(items), key=lambda pair: (order[pair[1].nodeid.split("::")[0]],
                                                                                 pair[0]))]


@pytest.fixture
def broad_dir() -> Path:
    if not BROAD_DIR.is_dir() or not any(BROAD_DIR.glob("*.npz")):
        pytest.skip(f"BROAD data not found at {BROAD_DIR} (needs ../shared/data/broad beside the checkout)")
    return BROAD_DIR


@pytest.fixture(autouse=True)
def _logging_left_enabled():
    """A test must not leave logging disabled: `logging.disable` is process-wide, so every later test of the same
    worker would lose the warnings it checks with caplog (which tests those are depends on how the files fall on
    the workers). The test that leaves it disabled fails here, by name, and the next one starts clean."""
    yield
    left = logging.root.manager.disable
    if left != logging.NOTSET:
        logging.disable(logging.NOTSET)
        pytest.fail(f"the test left logging disabled at level {left} (logging.disable is process-wide)")


@pytest.fixture(autouse=True)
def _no_system_state_dir(tmp_path_factory, monkeypatch):
    """`ahrsd calibrate`, `run` and `log` without a state directory use core.state_dir's default ($STATE_DIRECTORY,
    /var/lib/ahrsd, ~/.local/state/ahrsd): point it at an empty directory, through $STATE_DIRECTORY so that the
    daemons and commands a test starts as subprocesses get it too (a machine with the service installed has a
    /var/lib/ahrsd they would otherwise use), so no test depends on, or changes, the machine's own calibration.
    A test of the rule itself removes $STATE_DIRECTORY."""
    import ahrsd.core.state_dir as state_dir

    # one mkdtemp per test, not three tmp_path_factory.mktemp: mktemp lists the whole base temp directory to
    # number the new one, so with every test adding to it the listings grow with the square of the test count
    root = Path(tempfile.mkdtemp(prefix="state-dirs-", dir=tmp_path_factory.getbasetemp()))
    for name in ("no-service", "default-state", "default-xdg"):
        (root / name).mkdir()
    monkeypatch.setattr(state_dir, "SERVICE_STATE_DIR", root / "no-service" / "ahrsd")
    monkeypatch.setenv("STATE_DIRECTORY", str(root / "default-state"))
    monkeypatch.setenv("XDG_STATE_HOME", str(root / "default-xdg"))


@pytest.fixture
def ahrsd_inproc(capsys):
    """`ahrsd calibrate ARGS` run in this process (what the subprocess form checks, without an interpreter
    start-up and numba's cache load per call). Returns a CompletedProcess; check_rc asserts the exit code."""
    from ahrsd.cli.main import main

    def run(*args, check_rc=None):
        capsys.readouterr()
        try:
            rc = main(["calibrate", *map(str, args)])
        except SystemExit as exc:  # argparse usage errors
            rc = exc.code
        out, err = capsys.readouterr()
        if check_rc is not None:
            assert rc == check_rc, out + err
        return subprocess.CompletedProcess(["ahrsd", "calibrate", *map(str, args)], rc, out, err)

    return run

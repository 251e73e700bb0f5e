"""tools/check_structure.py: clean on this tree, and each rule fails on the code it forbids (the shapes the
daemon had before it was composed of parts: a nine-mixin Service, a monkeypatched AutopilotState, a probed
optional part)."""

from __future__ import annotations

import contextlib
import importlib.util
import io
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TOOL = ROOT / "tools" / "check_structure.py"


def _tool():
    spec = importlib.util.spec_from_file_location("check_structure_tool", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


CHECK_STRUCTURE = _tool()


def run(root: Path) -> subprocess.CompletedProcess:
    """The tool's `main` in this process (its exit code and what it prints): the tool is plain Python on a tree,
    no process of its own is needed to read its verdict."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = CHECK_STRUCTURE.main([str(TOOL), str(root)])
    return subprocess.CompletedProcess([str(TOOL), str(root)], code, out.getvalue(), "")


def test_this_tree_is_clean():
    # the tool as the hook runs it, in a process of its own: on the whole tree a fresh interpreter's small heap
    # makes its garbage collections cheaper than this process's
    r = subprocess.run([sys.executable, str(TOOL), str(ROOT)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout


def _files(tmp_path: Path, sources: dict[str, str]) -> Path:
    """A tree with each source at its path below tmp_path (directories made as needed)."""
    for name, source in sources.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(source)
    return tmp_path


def _tree(tmp_path: Path, source: str) -> Path:
    return _files(tmp_path, {"daemon/bad.py": source})


def test_a_class_of_mixins_fails(tmp_path):
    r = run(_tree(tmp_path, "class A: pass\nclass B: pass\nclass C: pass\nclass Service(A, B, C):\n    pass\n"))
    assert r.returncode == 1 and "bad.py:4: class Service has 3 bases" in r.stdout


def test_two_bases_pass(tmp_path):
    assert run(_tree(tmp_path, "class A: pass\nclass B: pass\nclass C(A, B):\n    pass\n")).returncode == 0


def test_setattr_on_another_object_fails(tmp_path):
    src = ("def hook(autopilot, fn):\n"
           "    setattr(autopilot, 'on_gps_raw_int', fn)\n"
           "class Own:\n"
           "    def set(self, name, v):\n"
           "        setattr(self, name, v)\n")
    r = run(_tree(tmp_path, src))
    assert r.returncode == 1 and "bad.py:2: setattr on autopilot" in r.stdout and "bad.py:5" not in r.stdout


def test_probing_a_part_fails(tmp_path):
    src = ("def a(service):\n"
           "    return getattr(service, 'magcal', None)\n"
           "def b(self):\n"
           "    return hasattr(self, 'anything')\n"
           "def c(x):\n"
           "    return getattr(x.owner, 'gnss', None)\n"
           "def d(source):\n"
           "    return getattr(source, 'per_sample', False)\n"    # the source interface declares it
           "def e(msg):\n"
           "    return getattr(msg, 'target_system', 0)\n"        # a field of some message types: allowed
           "def f(self):\n"
           "    return getattr(self.pipeline.estimator, 'learned_iron', None)\n")   # estimator/base.py declares it
    r = run(_tree(tmp_path, src))
    assert r.returncode == 1
    for line in (2, 4, 6, 8, 12):
        assert f"bad.py:{line}:" in r.stdout
    assert "bad.py:10:" not in r.stdout


def test_probing_an_estimator_outside_the_daemon_fails(tmp_path):
    """Outside daemon/ rule 4 holds: an estimator's capabilities are Protocols of estimator/base.py, in the CLI and
    the calibration as in the daemon; setattr and bases are the package's own business. Rule 14 holds in every
    package, the shapes main had: the field session read `getattr(estimate, "body_yaw_rad", None)` (an attitude of
    one of two undeclared shapes), the stream `hasattr(sc, "with_gravity")`; a MAVLink 2 extension field,
    Python's own dunders and a getattr without a default (no probe) stay allowed (probe.py)."""
    (tmp_path / "cli").mkdir()
    (tmp_path / "cli" / "bad.py").write_text(
        "def a(estimator):\n"
        "    return getattr(estimator, 'gnss_counters', None)\n"
        "def b(args):\n"
        "    return getattr(args, 'gnss')\n"                # a part's name, but an argparse namespace: allowed here
        "def c(x):\n"
        "    setattr(x, 'y', 1)\n")
    (tmp_path / "calibration").mkdir()
    (tmp_path / "calibration" / "bad.py").write_text(
        "def d(est):\n"
        "    return hasattr(est, 'update_gnss')\n")
    _files(tmp_path, {"calibration/probe.py": textwrap.dedent("""\
        def a(estimate):
            return getattr(estimate, 'body_yaw_rad', None)
        def b(sc):
            return hasattr(sc, 'with_gravity')
        def c(msg):
            return getattr(msg, 'alt_ellipsoid', 0)
        def d(cls):
            return hasattr(cls, '__post_init__')
        def e(cfg, key):
            return getattr(cfg, 'rate_hz'), getattr(cfg, key, None)
        """), "daemon/probe.py": "def f(estimate):\n    return getattr(estimate, 'gyro_bias_rad_s', 0.0)\n"})
    r = run(tmp_path)
    assert r.returncode == 1
    assert "cli/bad.py:2: getattr(estimator, 'gnss_counters') probes an estimator" in r.stdout
    assert "calibration/bad.py:2: hasattr(est, 'update_gnss') probes an estimator" in r.stdout
    assert "bad.py:4:" not in r.stdout and "bad.py:6:" not in r.stdout
    assert "calibration/probe.py:2: getattr(estimate, 'body_yaw_rad', …) probes an object for a member" in r.stdout
    assert "calibration/probe.py:4: hasattr(sc, 'with_gravity') probes an object for a member" in r.stdout
    assert "daemon/probe.py:2: getattr(estimate, 'gyro_bias_rad_s', …) probes" in r.stdout
    assert all(f"calibration/probe.py:{line}:" not in r.stdout for line in (6, 8, 10)), r.stdout


def test_a_spy_on_an_estimator_in_a_test_fails(tmp_path):
    """Rule 5, the shape test_heading_monitor had: the estimator's methods replaced by spies; assigning data to
    an attribute, or a spy to something that is not an estimator, is not this rule's business."""
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_bad.py").write_text(textwrap.dedent("""\
        def test_a(est):
            check = est._monitor.check
            def spy(*a):
                return check(*a)
            est._monitor.check = spy
            est._check_heading = lambda t: None
            est.params = None
            router.clock = lambda: 0.0
        """))
    r = run(tmp_path)
    assert r.returncode == 1
    assert "tests/test_bad.py:5: est._monitor.check replaced by a spy" in r.stdout
    assert "tests/test_bad.py:6: est._check_heading replaced by a spy" in r.stdout
    assert "test_bad.py:7:" not in r.stdout and "test_bad.py:8:" not in r.stdout


def test_a_part_reading_the_host_clock_fails_unless_the_line_says_why(tmp_path):
    src = ("import time\n"
           "class Limiter:\n"
           "    def __init__(self, clock=time.monotonic):\n"          # a clock it is given: allowed
           "        self.clock = clock\n"
           "    def due(self):\n"
           "        return time.monotonic() > 5.0\n"                   # reads the host's clock itself
           "def stamp():\n"
           "    return time.time_ns()    # host clock: a protocol's time stamp\n")
    r = run(_tree(tmp_path, src))
    assert r.returncode == 1 and "bad.py:6: time.monotonic() read by a part" in r.stdout
    assert "bad.py:3" not in r.stdout and "bad.py:8" not in r.stdout


def test_monkeypatching_another_modules_object_fails_in_every_package(tmp_path):
    """Rule 7, the shape magcal had (`AutopilotState.on_gps_raw_int` replaced) and the reader process's class
    switch had (`Adis16405.samples_as_records = True`, now the driver's constructor setting): an attribute of an
    imported module or name assigned or set with setattr, in daemon/ and outside it; a part's own state, a local
    object's and a line that says why (`# process-wide:`) are not this rule's."""
    (tmp_path / "daemon").mkdir()
    (tmp_path / "daemon" / "bad.py").write_text(textwrap.dedent("""\
        import ahrsd.daemon.autopilot
        from ahrsd.daemon.autopilot import AutopilotState
        def hook(fn, state):
            AutopilotState.on_gps_raw_int = fn
            ahrsd.daemon.autopilot.AutopilotState.on_global_position_int = fn
            setattr(AutopilotState, 'on_gps_raw_int', fn)
            state.on_gps_raw_int = fn
        """))
    (tmp_path / "drivers").mkdir()
    (tmp_path / "drivers" / "bad.py").write_text(textwrap.dedent("""\
        from ahrsd.drivers import adis16405 as chip
        from ahrsd.drivers.adis16405 import Adis16405
        class Own:
            count = 0
            def bump(self):
                self.count += 1
        def child():
            Adis16405.spi_speed_hz = 2_000_000
            chip.Adis16405.spi_speed_hz = 2_000_000
            chip.READS += 1
            Adis16405.spi_speed_hz = 2_000_000   # process-wide: this process's bus is slower
        """))
    r = run(tmp_path)
    assert r.returncode == 1
    for at in ("daemon/bad.py:4:", "daemon/bad.py:5:", "daemon/bad.py:6:", "drivers/bad.py:8:", "drivers/bad.py:9:",
               "drivers/bad.py:10:"):
        assert f"{at} " in r.stdout and "sets another module's object" in r.stdout.split(at)[1].splitlines()[0], at
    for clean in ("daemon/bad.py:7:", "drivers/bad.py:6:", "drivers/bad.py:11:"):
        assert clean not in r.stdout, clean


def test_probing_a_settings_object_in_the_drivers_fails(tmp_path):
    """Rule 8: drivers.source once read `getattr(sensor_cfg, "rate_hz", None)`, so a settings object without the
    field meant "the chip's own rate" while the config's default meant 819.2 SPS; the fields are declared now
    (drivers/source_settings.py). A message's optional field stays data."""
    (tmp_path / "drivers").mkdir()
    (tmp_path / "drivers" / "bad.py").write_text(textwrap.dedent("""\
        def a(sensor_cfg):
            return getattr(sensor_cfg, 'rate_hz', None)
        def b(settings):
            return hasattr(settings, 'reader')
        def c(msg):
            return getattr(msg, 'invalidLlh', 0)
        def d(sensor_cfg):
            return sensor_cfg.rate_hz
        """))
    r = run(tmp_path)
    assert r.returncode == 1
    assert "drivers/bad.py:2: getattr(sensor_cfg, 'rate_hz') probes a settings object" in r.stdout
    assert "drivers/bad.py:4: hasattr(settings, 'reader') probes a settings object" in r.stdout
    assert "bad.py:6:" not in r.stdout and "bad.py:8:" not in r.stdout


def test_a_forwarding_wrapper_fails_in_every_package_and_in_tests_and_a_lazy_module_import_passes(tmp_path):
    """Rule 9: drivers.ground_truth and drivers.threaded_source forwarded whatever they lacked to what they wrapped
    (`def __getattr__(self, name): return getattr(self.inner, name)`), estimator.estimate_view.EstimateView every
    field to its snapshot, and test fakes everything to the chip or source behind them; a wrapper now declares
    what it passes on. A module's `__getattr__` (PEP 562, drivers/__init__.py's imports on first use) is not
    this rule's."""
    (tmp_path / "drivers").mkdir()
    (tmp_path / "drivers" / "bad.py").write_text(textwrap.dedent("""\
        class Wrapper:
            def __init__(self, inner):
                self.inner = inner
            def __getattr__(self, name):
                return getattr(self.inner, name)
        class Declared:
            bus = property(lambda self: self.inner.bus)
        def __getattr__(name):
            raise AttributeError(name)
        """))
    forwards = "class {}:\n    def __getattr__(self, name):\n        return 0\n"
    r = run(_files(tmp_path, {"daemon/bad.py": forwards.format("View"), "estimator/view.py": forwards.format("View"),
                              "tests/test_fake.py": forwards.format("Bus")}))
    assert r.returncode == 1
    assert "drivers/bad.py:4: class Wrapper forwards every attribute" in r.stdout
    assert "daemon/bad.py:2: class View forwards every attribute" in r.stdout
    assert "estimator/view.py:2: class View forwards every attribute" in r.stdout
    assert "tests/test_fake.py:2: class Bus forwards every attribute" in r.stdout
    assert "bad.py:7:" not in r.stdout and "bad.py:8:" not in r.stdout


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    (tmp_path / "simulation").mkdir()
    (tmp_path / "simulation" / "__init__.py").write_text("")
    for name, source in files.items():
        (tmp_path / "simulation" / name).write_text(textwrap.dedent(source))
    return tmp_path


def test_a_module_level_import_cycle_fails_whichever_form_it_takes(tmp_path):
    # the shape simulation/scenarios.py and vehicles.py had: importing vehicles first failed with
    # "cannot import name 'VEHICLES' from partially initialized module"
    r = run(_package(tmp_path, {
        "scenarios.py": "from ahrsd.simulation.base import DEG\nfrom ahrsd.simulation.vehicles import VEHICLES\n",
        "vehicles.py": "from . import scenarios\nVEHICLES = {}\n",
        "base.py": "DEG = 1.0\n"}))
    assert r.returncode == 1, r.stdout
    assert "scenarios.py:2: module-level import of ahrsd.simulation.vehicles closes an import cycle" in r.stdout
    assert "vehicles.py:1: module-level import of ahrsd.simulation.scenarios" in r.stdout
    assert "base.py" not in r.stdout


def test_an_import_inside_a_function_or_for_type_checking_is_no_cycle(tmp_path):
    r = run(_package(tmp_path, {
        "a.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ahrsd.simulation.b import B\n"
                "def make():\n    from ahrsd.simulation.b import B\n    return B()\n",
        "b.py": "from ahrsd.simulation.a import make\nclass B:\n    pass\n"}))
    assert r.returncode == 0, r.stdout


def test_a_package_importing_its_submodules_is_no_cycle(tmp_path):
    # drivers/__init__.py imports .adis16405, which imports `from . import registers`: the package is only
    # being initialised, none of its own names is read
    root = _package(tmp_path, {"registers.py": "X = 1\n", "chip.py": "from . import registers\n"})
    (root / "simulation" / "__init__.py").write_text("from .chip import registers\n")
    assert run(root).returncode == 0


def test_a_comment_or_docstring_naming_a_session_fails_in_every_package_but_a_string_the_code_uses_passes(tmp_path):
    """Rule 11, issue 29 item 7 (the shapes three modules had: "(session 23's walk)" in a module docstring, "session
    23" in a function's): history is in git, figures in docs/. A string the code uses (a message with the word) and
    tests/ are not this rule's."""
    (tmp_path / "daemon").mkdir()
    (tmp_path / "daemon" / "bad.py").write_text(textwrap.dedent('''\
        """One daemon per state directory: the state is silently mixed (session 23's walk)."""
        def f():
            """Limits that hold the wave peaks (sessions 24–25)."""
            return 1   # walk26's walk found it
        def g():
            return "mag-cal session 2 accepted"
        '''))
    r = run(_files(tmp_path, {"cli/bad.py": "x = 1\n# why: the operator's prompt waits for an answer (Session 7)\n",
                              "tests/test_ok.py": '"""Found on session 23\'s walk."""\n'}))
    assert r.returncode == 1
    for at in ("daemon/bad.py:1:", "daemon/bad.py:3:", "daemon/bad.py:4:", "cli/bad.py:2:"):
        assert f"{at} a comment names a session" in r.stdout, (at, r.stdout)
    assert "daemon/bad.py:6:" not in r.stdout and "test_ok.py" not in r.stdout, r.stdout
    assert r.stdout.count("a comment names a session") == 4, r.stdout


def test_a_fake_class_fails_in_every_package_but_not_in_tests(tmp_path):
    """Rule 12, the shape daemon.magcal had: a `_FakeCommand` forged for its own handler lacked the `command`
    field CommandArgs.of reads, and PREFLIGHT_CALIBRATION's magnetometer path failed for it. A name that only
    contains the word and tests/ are not this rule's."""
    r = run(_files(tmp_path, {
        "daemon/bad.py": "class _FakeCommand:\n    pass\nclass DummyLink:\n    pass\nclass MockClock:\n    pass\n"
                         "class StubSource:\n    pass\nclass FakeryReport:\n    pass\nclass NoFakeHere:\n    pass\n",
        "tests/test_ok.py": "class FakeHost:\n    pass\n"}))
    assert r.returncode == 1
    for at in ("bad.py:1:", "bad.py:3:", "bad.py:5:", "bad.py:7:"):
        assert f"{at} class " in r.stdout and "is a fake" in r.stdout.split(at)[1].splitlines()[0], (at, r.stdout)
    assert r.stdout.count("is a fake") == 4, r.stdout


def test_a_test_module_imported_by_another_fails_and_tests_support_passes(tmp_path):
    """Rule 13, the shape eight test modules had (`from test_field_circle import _run`, one inside a function):
    what tests share lives in tests/support/."""
    r = run(_files(tmp_path, {
        "tests/test_a.py": "import test_b\nfrom test_c import helper\nfrom support.rig import rig\n"
                           "import testing_tools\ndef test_x():\n    from test_d.sub import y\n",
        "tests/support/rig.py": "from support.other import thing\n"}))
    assert r.returncode == 1
    for at, name in (("test_a.py:1:", "test_b"), ("test_a.py:2:", "test_c"), ("test_a.py:6:", "test_d.sub")):
        assert f"{at} imports the test module {name} " in r.stdout, (at, r.stdout)
    assert r.stdout.count("imports the test module") == 3, r.stdout

"""The calibration package's layout rules, read from the import statements (every import, also those inside
functions): no import loop between its modules; the fits (mag/, inertial/) never import the runtime modules
above them but `models`, the Allan analysis (allan/) none but the number format and the atomic write, and nothing
of calibration/ imports it; only the orchestrators (field, mag.procedure) import the dispatcher; the plotting modules
are imported by the CLI only, so the daemon never loads them."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    bits = list(rel.parts)
    if bits[-1] == "__init__":
        bits = bits[:-1]
    return ".".join(["ahrsd", *bits])


def _imports(path: Path) -> set[str]:
    """Every ahrsd module `path` imports, resolved to full dotted names (relative imports included)."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            out.add(target)
            # `from pkg import module` imports the module pkg.module
            out.update(f"{target}.{a.name}" for a in node.names)
    return {m for m in out if m.startswith("ahrsd.")}


def import_graph(part: str) -> dict[str, set[str]]:
    files = sorted((ROOT / part).rglob("*.py"))
    modules = {_module_name(f): f for f in files}
    return {m: {t for t in _imports(f) if t in modules and t != m} for m, f in modules.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def test_the_cycle_finder_finds_a_loop_and_passes_a_tree():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_no_import_loop_inside_calibration():
    graph = import_graph("calibration")
    assert "ahrsd.calibration.mag.fit" in graph and "ahrsd.calibration.mag.fit_types" in graph
    assert find_cycle(graph) is None, f"import loop: {' -> '.join(find_cycle(graph))}"


def test_the_fits_do_not_import_the_runtime_modules():
    graph = import_graph("calibration")
    allowed = {"ahrsd.calibration", "ahrsd.calibration.models"}
    for module, targets in graph.items():
        if module.startswith(("ahrsd.calibration.mag", "ahrsd.calibration.inertial")):
            upward = {t for t in targets if t.startswith("ahrsd.calibration")
                      and not t.startswith(("ahrsd.calibration.mag", "ahrsd.calibration.inertial"))} - allowed
            assert not upward, f"{module} imports {sorted(upward)}"


def test_the_allan_analysis_imports_of_the_runtime_only_the_number_format_and_the_atomic_write():
    """calibration/allan/ is an offline fit like mag/ and inertial/: apart from the runtime modules, which it may use
    only for the report's significant figures and noise.json's atomic write."""
    graph = import_graph("calibration")
    assert "ahrsd.calibration.allan.analysis" in graph and "ahrsd.calibration.allan.terms" in graph
    allowed = {"ahrsd.calibration", "ahrsd.calibration.report", "ahrsd.calibration.atomic_file"}
    for module, targets in graph.items():
        if module.startswith("ahrsd.calibration.allan"):
            upward = {t for t in targets if t.startswith("ahrsd.calibration")
                      and not t.startswith("ahrsd.calibration.allan")} - allowed
            assert not upward, f"{module} imports {sorted(upward)}"
        else:
            assert not any(t.startswith("ahrsd.calibration.allan") for t in targets), \
                f"{module} imports the offline Allan analysis"


def test_the_method_modules_do_not_import_the_dispatcher():
    graph = import_graph("calibration")
    dispatcher = "ahrsd.calibration.mag.fit"
    users = sorted(m for m, targets in graph.items() if dispatcher in targets)
    assert users == ["ahrsd.calibration.field", "ahrsd.calibration.mag.procedure"], users


def test_calibration_and_the_daemon_import_no_plotting_module():
    for part in ("calibration", "daemon"):
        for path in sorted((ROOT / part).rglob("*.py")):
            bad = {m for m in _imports(path) if m.startswith("ahrsd.cli.plots") or m == "ahrsd.core.plotting"
                   or m.endswith("_plot")}
            assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


def test_the_daemon_does_not_load_a_plotting_module():
    code = ("import sys, ahrsd.daemon.service, ahrsd.daemon.magcal, ahrsd.calibration.field\n"
            "print(sorted(m for m in sys.modules if m.startswith(('matplotlib', 'ahrsd')) and 'plot' in m))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300)
    assert out.stdout.strip() == "[]", out.stdout

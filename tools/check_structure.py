"""Structure rules for the daemon's parts (docs/architecture.md), beside ../shared/hooks/check_layers.py.

Usage: python tools/check_structure.py [CHECKOUT]   (exit 0 when clean; each violation printed as path:line)

Rules in daemon/:
1. no class with more than two bases (the daemon is composed of parts, not assembled from mixins);
2. no `setattr` on an object other than `self`/`cls` (no part replaces another object's methods or state);
3. no `getattr`/`hasattr` probing of the daemon's parts: not on the service or a part itself (`self`,
   `service`, `svc`, `s`, `host`, `self.service`, `self.host`), not on a sensor source (`source`, `src`,
   `self.source`: drivers/source_interface.py declares what a source has), not on an estimator (`estimator`,
   `est`, `self.pipeline.estimator`, …: estimator/base.py declares its capabilities as Protocols, tested with
   isinstance) and not for an attribute named like
   a part (an optional part is `None` or a null object by type, and is tested with `is None`).
6. no part reads the host's clock itself (`time.monotonic()`, `time.time()`, their `_ns` forms): a rate limit or
   a timeout runs on the clock the part is given (`Service.clock`, which a test steps). A line that must read the
   host's clock (a protocol's time stamp, a wall time persisted across reboots) says why in a `# host clock:`
   comment on that line.
Rule in every other package (cli/, calibration/, estimator/, drivers/, core/, simulation/):
4. no `getattr`/`hasattr` probing of an estimator (the names of rule 3): what an estimator can do is declared
   in estimator/base.py, whoever asks.
Rule in every package (daemon/ and the others above):
7. no monkeypatching of another module's objects: no attribute of an imported module or of a name imported from
   one is assigned (`autopilot.AutopilotState.on_gps_raw_int = hook`, `Adis16405.flag = True`) or set with
   `setattr`; a module changes another's behaviour through what that one declares (an argument, a
   subscription). A line that must set a process-wide switch says why in a `# process-wide:` comment.
Rule in drivers/ and daemon/:
8. no `getattr`/`hasattr` probing of a settings object (`sensor_cfg`, `settings`, `cfg`, `config`, …): what a
   source is built from is a declared type (drivers/source_settings.py: SensorSettings; the daemon's config
   tables), every field with its one default, so a missing field is an error, not a second meaning.
Rule in every package and in tests/:
9. no `__getattr__` method in a class (a wrapper that forwards whatever it is asked to what it wraps): a wrapper
   declares each member it passes on (a property or a method), so what a source, a bus, a sentence or an
   estimate view has is read in one place (drivers/source_interface.py, drivers/spi.py SpiBus,
   estimator/estimate_view.py EstimateView); a test's fake declares what the code under test uses of it. A
   module's own `__getattr__` (PEP 562: a name imported on first use, drivers/__init__.py) is not a wrapper and
   stays allowed.
10. no import cycle between modules through their module-level imports (those run when a module is first
   imported; an import inside a function or under `if TYPE_CHECKING:` does not count): a module of the cycle
   imported first finds the other half-built ("cannot import name … from partially initialized module"), so
   whether it works depended on which one a program happened to import first. Shared parts go into a module
   both import (simulation/scenario_base.py).
Rule in every package (not tests/, tools/ or bench/):
11. no comment or docstring tells the code's history by session ("session 23", "sessions 24–25", "walk26's
   walk"): a comment says why the code is as it is; when and by whom it changed is in git, and what was measured
   is in docs/ (issue 29 item 7). Rule 11 reads comments (`#`) and docstrings only, never strings the code uses.
12. no fake, dummy or mock class (`class _FakeCommand`): a module that needs another's behaviour calls it with
   what it has (daemon.magcal's PREFLIGHT_CALIBRATION path calls `_start(CommandArgs(...))`), it does not forge
   the other's input; a forged message missed a field the reader needs and failed where no test looked. Fakes
   live in tests/.
14. no probing of an object for a member by name (`hasattr(x, "name")`, `getattr(x, "name", default)`): our own
   types declare their members (a dataclass field with its default, a Protocol: calibration.field.FieldAttitude,
   daemon.magcal.MagCalEstimate, a GnssFix's `s_acc_m_s`, Scenario.with_gravity), so a probe of one hides a
   missing member behind a second meaning. Allowed: Python's own dunder names, and the members of other
   libraries' objects that not all of them have, listed in FOREIGN_ATTRIBUTES with where they come from (a
   MAVLink 2 extension field, an optional UBX or NMEA field, an exception's errno, argparse's `func`).
Rule in tests/:
5. no spy on an estimator: no function or lambda assigned to an attribute of an estimator object (the names of
   rule 3, and what hangs below them: `est._monitor.check = spy`). A test reads what the estimator decided
   from its records (`Ins.heading_checks`), so it keeps testing the code that runs.
13. no test module imports another (`from test_field_circle import _run`): what tests share has one home,
   tests/support/, where a reader looks for it; a test module is free to change for its own tests.
"""

from __future__ import annotations

import ast
import io
import re
import sys
import tokenize
from pathlib import Path

MAX_BASES = 2
ESTIMATOR_OBJECTS = {"estimator", "est", "self.estimator", "pipeline.estimator", "p.estimator",
                     "self.pipeline.estimator"}                           # an estimator: estimator/base.py
PROBED_OBJECTS = {"self", "service", "svc", "s", "host", "self.service", "self.host", "self.svc",
                  "source", "src", "self.source", "service.source",    # a sensor source: drivers.source_interface
                  *ESTIMATOR_OBJECTS}
DAEMON = "daemon"
SETTINGS_RULE_PACKAGES = ("drivers", DAEMON)
SETTINGS_OBJECTS = {"sensor_cfg", "sensor_settings", "settings", "cfg", "config", "self.settings", "self.config",
                    "self.cfg", "self.sensor_cfg"}                    # drivers/source_settings.py, daemon/config.py
ESTIMATOR_RULE_PACKAGES = ("cli", "calibration", "estimator", "drivers", "core", "simulation")
TESTS = "tests"
PART_NAMES = {
    "magcal", "field_calibration", "gnss", "pipeline", "reader", "publishers", "inbound", "param_protocol",
    "declination", "positions", "housekeeping", "health_report", "swap", "heading", "heading_slew",
    "restart_heading", "source_set_check", "endpoint_outputs", "outbound", "logs", "status_line", "commands",
    "params", "autopilot", "notifier", "listeners",
}


# rule 14: members of other libraries' objects that some of those objects lack, read with a default
FOREIGN_ATTRIBUTES = {
    # pymavlink messages: the target fields exist on targeted message types only; MAVLink 2 extension fields
    # (GPS_RAW_INT's alt_ellipsoid, h_acc, v_acc, vel_acc; STATUSTEXT's id, chunk_seq); get_type on messages only
    "target_system", "target_component", "alt_ellipsoid", "h_acc", "v_acc", "vel_acc", "id", "chunk_seq",
    "get_type",
    # pyubx2 / pynmeagps parsed messages: fields of some message types or protocol versions only
    "invalidLlh", "msgID", "time", "date", "posMode",
    # an OSError's fields, os.O_DIRECTORY (not on every platform), argparse's sub-command, numba's dispatcher class
    "errno", "filename", "strerror", "O_DIRECTORY", "func", "CPUDispatcher",
}
HOST_CLOCKS = {"time.monotonic", "time.time", "time.monotonic_ns", "time.time_ns"}
HOST_CLOCK_MARK = "# host clock:"
# rule 11: a session named ("session 23", "sessions 24–25") or a session's walk by its helper ("walk26's walk")
SESSION_HISTORY = re.compile(r"\bsessions? \d+|\b[a-z]+\d{2}'s walk\b", re.IGNORECASE)
PROCESS_WIDE_MARK = "# process-wide:"


def _dotted(node: ast.AST) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        inner = _dotted(node.value)
        return f"{inner}.{node.attr}" if inner else ""
    return ""


def _parsed(path: Path) -> tuple[ast.Module, str]:
    """A file's syntax tree and its text (read once)."""
    text = path.read_text(encoding="utf-8")
    return ast.parse(text), text


def _imported_names(nodes: list[ast.AST]) -> set[str]:
    """The names a module binds by importing: modules (`import a.b` binds a) and names from them."""
    names = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            names |= {alias.asname or alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            names |= {alias.asname or alias.name for alias in node.names}
    return names


def _root_name(node: ast.AST) -> str:
    while isinstance(node, ast.Attribute):
        node = node.value
    return node.id if isinstance(node, ast.Name) else ""


def _monkeypatches(nodes: list[ast.AST], lines: list[str], shown: str) -> list[str]:
    """Rule 7: an attribute of an imported module or name assigned, or set with setattr."""
    imported = _imported_names(nodes)
    out = []
    for node in nodes:
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
            targets = [node.target]
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "setattr"
              and node.args):
            targets = [node.args[0]]        # setattr(target, ...): the object itself is set on
        else:
            continue
        for target in targets:
            attribute_set = isinstance(target, ast.Attribute) or isinstance(node, ast.Call)
            if (attribute_set and _root_name(target) in imported
                    and PROCESS_WIDE_MARK not in lines[node.lineno - 1]):
                what = ast.unparse(target) if isinstance(node, ast.Assign | ast.AugAssign | ast.AnnAssign) \
                    else f"setattr({ast.unparse(target)}, …)"
                out.append(f"{shown}:{node.lineno}: {what} sets another module's object (monkeypatching: pass "
                           f"an argument or subscribe instead; or say why on the line: '{PROCESS_WIDE_MARK} ...')")
    return out


def _forwarding_wrappers(nodes: list[ast.AST], shown: str) -> list[str]:
    """Rule 9: a class with a `__getattr__` method."""
    return [f"{shown}:{item.lineno}: class {node.name} forwards every attribute it lacks (__getattr__): declare "
            "the members it passes on (a property or a method each)"
            for node in nodes if isinstance(node, ast.ClassDef)
            for item in node.body if isinstance(item, ast.FunctionDef) and item.name == "__getattr__"]


def _comment_lines(text: str, nodes: list[ast.AST]) -> list[tuple[int, str]]:
    """(line, text) of every `#` comment and every docstring line (a string standing alone as a statement)."""
    out = [(tok.start[0], tok.string) for tok in tokenize.generate_tokens(io.StringIO(text).readline)
           if tok.type == tokenize.COMMENT]
    for node in nodes:
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            out += [(node.lineno + i, line) for i, line in enumerate(node.value.value.splitlines())]
    return out


def _session_history(text: str, nodes: list[ast.AST], shown: str) -> list[str]:
    """Rule 11: a comment or docstring that names a session."""
    if not SESSION_HISTORY.search(text):
        return []      # every comment and docstring line is text of the file: one that cannot match needs no tokenizing
    return [f"{shown}:{line}: a comment names a session ({m.group(0)!r}): say why, not when (history is in "
            "git, figures in docs/)"
            for line, comment in _comment_lines(text, nodes) if (m := SESSION_HISTORY.search(comment))]


FAKE_CLASS = re.compile(r"^_*(Fake|Dummy|Mock|Stub)[A-Z_]")


def _fake_classes(nodes: list[ast.AST], shown: str) -> list[str]:
    """Rule 12: a class named as a fake."""
    return [f"{shown}:{node.lineno}: class {node.name} is a fake in a package (call the code with what you have; "
            "fakes live in tests/)"
            for node in nodes if isinstance(node, ast.ClassDef) and FAKE_CLASS.match(node.name)]


def check_file(path: Path, shown: str, daemon_rules: bool = True, settings_rule: bool = False,
               parsed: tuple[ast.Module, str] | None = None) -> list[str]:
    """The problems in one file: every rule (daemon_rules), or only rules 4 (an estimator probed), 7, 9 (a
    forwarding wrapper), 11 (a session named in a comment), 12 (a fake class) and 14 (a member probed); and rule 8
    (a settings object probed) with settings_rule. parsed: its `_parsed`, when the caller has it."""
    try:
        tree, text = parsed or _parsed(path)
    except SyntaxError as exc:
        return [f"{shown}:{exc.lineno}: does not parse"]
    lines = text.splitlines()
    nodes = list(ast.walk(tree))      # each rule reads every node: walked once (the walk is most of the run)
    out = (_monkeypatches(nodes, lines, shown) + _forwarding_wrappers(nodes, shown)
           + _session_history(text, nodes, shown) + _fake_classes(nodes, shown))
    for node in nodes:
        if (daemon_rules and isinstance(node, ast.Call) and _dotted(node.func) in HOST_CLOCKS
                and HOST_CLOCK_MARK not in lines[node.lineno - 1]):
            out.append(f"{shown}:{node.lineno}: {_dotted(node.func)}() read by a part (take a clock argument, "
                       f"Service.clock; or say why on the line: '{HOST_CLOCK_MARK} ...')")
        if daemon_rules and isinstance(node, ast.ClassDef) and len(node.bases) > MAX_BASES:
            out.append(f"{shown}:{node.lineno}: class {node.name} has {len(node.bases)} bases (at most "
                       f"{MAX_BASES}: compose parts instead of mixing them in)")
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.args):
            continue
        name, target = node.func.id, _dotted(node.args[0])
        if daemon_rules and name == "setattr" and target not in ("self", "cls"):
            out.append(f"{shown}:{node.lineno}: setattr on {target or 'an expression'} (a part changes only "
                       "its own state; subscribe or pass a callback instead)")
        if name in ("getattr", "hasattr"):
            attr = node.args[1].value if len(node.args) > 1 and isinstance(node.args[1], ast.Constant) else None
            if daemon_rules and (target in PROBED_OBJECTS or attr in PART_NAMES):
                out.append(f"{shown}:{node.lineno}: {name}({target or 'expression'}, {attr!r}) probes a part "
                           "(declare it: a constructor argument, None or a null object by type)")
            elif not daemon_rules and target in ESTIMATOR_OBJECTS:
                out.append(f"{shown}:{node.lineno}: {name}({target}, {attr!r}) probes an estimator (declare the "
                           "capability as a Protocol in estimator/base.py and test it with isinstance)")
            if settings_rule and target in SETTINGS_OBJECTS:
                out.append(f"{shown}:{node.lineno}: {name}({target}, {attr!r}) probes a settings object (declare "
                           "the field with its default: drivers/source_settings.py SensorSettings)")
            reported = any(o.startswith(f"{shown}:{node.lineno}: {name}(") for o in out)     # rules 3, 4, 8
            if (not reported and isinstance(attr, str) and (name == "hasattr" or len(node.args) > 2)
                    and not attr.startswith("__") and attr not in FOREIGN_ATTRIBUTES):
                default = ", …" if name == "getattr" else ""
                out.append(f"{shown}:{node.lineno}: {name}({target or 'expression'}, {attr!r}{default}) probes an object "
                           "for a member (declare it on the type: a field with its default, a Protocol; a member of "
                           "another library's object goes into FOREIGN_ATTRIBUTES, with where it comes from)")
    return sorted(out, key=lambda line: int(line.split(":")[1]))


def _is_estimator(dotted: str) -> bool:
    return any(dotted == name or dotted.startswith(name + ".") for name in ESTIMATOR_OBJECTS)


def check_test_file(path: Path, shown: str) -> list[str]:
    """Rule 5: a function or lambda assigned to an attribute of an estimator (a spy replacing its method); rule 9:
    a fake that forwards whatever it lacks; rule 13: a test module imported."""
    try:
        tree, _ = _parsed(path)
    except SyntaxError as exc:
        return [f"{shown}:{exc.lineno}: does not parse"]
    nodes = list(ast.walk(tree))
    functions = {n.name for n in nodes if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
    out = _forwarding_wrappers(nodes, shown)
    for node in nodes:
        imported = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                    else [node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level
                    else [])
        for name in imported:
            if name.split(".")[0].startswith("test_"):
                out.append(f"{shown}:{node.lineno}: imports the test module {name} (what tests share lives in "
                           "tests/support/)")
        if not isinstance(node, ast.Assign):
            continue
        value = node.value
        if not (isinstance(value, ast.Lambda) or (isinstance(value, ast.Name) and value.id in functions)):
            continue
        for target in node.targets:
            if isinstance(target, ast.Attribute) and _is_estimator(_dotted(target.value)):
                out.append(f"{shown}:{node.lineno}: {_dotted(target)} replaced by a spy (read the estimator's "
                           "records of what it decided instead)")
    return out


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(["ahrsd", *parts])


def _is_type_checking(node: ast.If) -> bool:
    return _dotted(node.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING")


def _module_level_imports(tree: ast.Module, module: str, is_package: bool, modules) -> list[tuple[str, int]]:
    """(imported module, line) for the imports that run when `module` is imported: its top level and the
    bodies of top-level try / if blocks other than `if TYPE_CHECKING:`. `from P import x` imports the module P.x
    when there is one (P itself is then only the package being initialised, whose names are not read), else
    reads x from P."""
    out, todo = [], list(tree.body)
    package = module if is_package else module.rpartition(".")[0]
    while todo:
        node = todo.pop(0)
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{anchor}.{base}" if base else anchor
            out += [(f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base, node.lineno) for a in node.names]
        elif isinstance(node, ast.If) and not _is_type_checking(node):
            todo += node.body + node.orelse
        elif isinstance(node, ast.Try):
            todo += node.body + node.orelse + node.finalbody + [n for h in node.handlers for n in h.body]
    return out


def _import_edges(tree: ast.Module, name: str, path: Path, paths: dict[str, Path]) -> list[tuple[str, int]]:
    """Module `name`'s module-level imports of this checkout's other modules (`paths`: name → file), one edge a
    line and module."""
    edges = [(target, line) for target, line in _module_level_imports(tree, name, path.name == "__init__.py", paths)
             if target in paths and target != name]
    return list(dict.fromkeys(edges))                  # one line importing two names of a module: one edge


def _import_cycles(root: Path, paths: dict[str, Path], edges: dict[str, list[tuple[str, int]]]) -> list[str]:
    """Rule 10: the cycles of the module-level import graph among this checkout's modules (`paths`, `edges`:
    _import_edges of each module that parses; Tarjan's strongly connected components; a module importing
    itself is no cycle)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v: str) -> None:                         # recursion depth ≤ the number of modules (a few hundred)
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w, _ in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                members = set(component)
                for m in sorted(members):
                    for w, line in edges[m]:
                        if w in members:
                            out.append(f"{paths[m].relative_to(root)}:{line}: module-level import of {w} "
                                       f"closes an import cycle ({', '.join(sorted(members))})")

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def check(root: Path) -> list[str]:
    """Every problem: the import cycles first, then each file's, in path order. Each file is parsed once, for
    its import edges and its rules, and its tree dropped before the next (the trees of every file kept at once
    make each garbage collection walk them all)."""
    packages = (DAEMON, *ESTIMATOR_RULE_PACKAGES)
    files = [(package, path) for package in packages for path in sorted((root / package).rglob("*.py"))]
    paths = {_module_name(root, path): path for _, path in files}
    edges: dict[str, list[tuple[str, int]]] = {}
    found = []
    for package, path in files:
        try:
            parsed = _parsed(path)
        except SyntaxError:
            parsed = None                              # check_file reports it
        else:
            name = _module_name(root, path)
            if paths[name] == path:                    # a module and a package of one name: the later file's edges
                edges[name] = _import_edges(parsed[0], name, path, paths)
        found += check_file(path, str(path.relative_to(root)), daemon_rules=package == DAEMON,
                            settings_rule=package in SETTINGS_RULE_PACKAGES, parsed=parsed)
    out = _import_cycles(root, paths, edges)
    out += found
    for path in sorted((root / TESTS).rglob("*.py")):
        out += check_test_file(path, str(path.relative_to(root)))
    return out


def main(argv: list[str]) -> int:
    root = Path(argv[1]) if len(argv) > 1 else Path(__file__).resolve().parent.parent
    problems = check(root)
    for p in problems:
        print(p)
    print(f"check_structure: {len(problems)} problem(s) in {root}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))

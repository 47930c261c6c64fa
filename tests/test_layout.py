"""Regression gates on the layout: who may own ROS entities, who may import rclpy."""

from __future__ import annotations

import ast
import re
import subprocess
import sys

import pytest

from common.harness.procs import REPO

# Outside the gateway proper: the demo robot, the ROS nodes of the tests (tests/support/) and of
# the benchmark (bench/: publishers, the DDS floor, the subscribe-per-request baseline), and the ROS
# programs both run (common/harness/: no gateway module imports it, see below).
EXEMPT = ("rosworker", "tests", "demo", "bench")
HARNESS = ("common", "harness")
CREATES = re.compile(r"\bcreate_(subscription|publisher|callback_group|generic_subscription)\s*\(")
IMPORTS_RCLPY = re.compile(r"^\s*(import|from)\s+rclpy\b", re.MULTILINE)


def python_files(*tops: str):
    """The modules under each of ``tops``; common/harness/ only when asked for by name ("common/harness")."""
    for top in tops:
        inside = tuple(top.split("/")) == HARNESS
        yield from (p for p in (REPO / top).rglob("*.py") if "__pycache__" not in p.parts
                    and (inside or p.relative_to(REPO).parts[:2] != HARNESS))


def test_only_the_ros_worker_creates_subscriptions_publishers_or_callback_groups():
    offenders = []
    for path in REPO.rglob("*.py"):
        rel = path.relative_to(REPO)
        if rel.parts[0] in EXEMPT or rel.parts[:2] == HARNESS or rel.parts[0].startswith(".") \
                or "__pycache__" in rel.parts:
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if CREATES.search(line):
                offenders.append(f"{rel}:{number}: {line.strip()}")
    assert not offenders, "ROS entities created outside rosworker/:\n" + "\n".join(offenders)


def test_the_http_side_and_ipc_never_import_rclpy():
    offenders = [str(p.relative_to(REPO)) for p in python_files("app", "supervisor", "ipc", "common")
                 if IMPORTS_RCLPY.search(p.read_text())]
    assert not offenders, f"rclpy imported on the HTTP side: {offenders}"


def test_the_gate_itself_catches_an_offender():
    assert CREATES.search("    self.sub = node.create_subscription(String, '/x', cb, 1)")
    assert CREATES.search("node.create_publisher(String, '/x', 10)")
    assert IMPORTS_RCLPY.search("from rclpy.node import Node")
    assert not IMPORTS_RCLPY.search("# rclpy is not imported here")


IMPORTS_ZENOH = re.compile(r"^\s*(import|from)\s+zenoh\b", re.MULTILINE)


def test_only_the_fleet_link_holds_a_zenoh_session():
    """Zenoh (its Rust threads and callbacks) lives in the fleet-link process only (issue 34): never in a
    gevent HTTP worker, never in the ROS worker, never in the supervisor itself."""
    offenders = [str(p.relative_to(REPO)) for p in python_files("app", "rosworker", "supervisor", "ipc", "common")
                 if IMPORTS_ZENOH.search(p.read_text()) and p.parent != REPO / "supervisor" / "fleet"]
    assert not offenders, f"zenoh imported outside supervisor/fleet/: {offenders}"
    assert IMPORTS_ZENOH.search("    import zenoh\n") and not IMPORTS_ZENOH.search("# zenoh is not imported")


def test_gevent_stays_out_of_the_ros_worker_and_the_supervisor():
    """Only the HTTP workers use gevent (app/http_worker.py patches them after the fork).

    The supervisor's children are plain processes started by exec; ``common/`` is loaded by
    all three, so it stays free of gevent too."""
    files = [*python_files("rosworker", "supervisor", "common")]
    offenders = [str(p.relative_to(REPO)) for p in files if "gevent" in p.read_text()]
    assert not offenders, f"gevent named outside the HTTP workers: {offenders}"


# One package per process (supervisor/, app/, rosworker/), the wire (ipc/) and what all three share
# (common/): which of the gateway's packages each may import.  Read from the source (every import
# statement, function-level ones too), so that a wrong-way import fails here before it is used.
OURS = ("app", "supervisor", "rosworker", "ipc", "common", "demo", "bench", "tests")
MAY_IMPORT = {
    "common": set(),
    "ipc": {"common"},  # the client's per-process channels (common/process.py's PerProcess)
    "app": {"ipc", "common"},
    "supervisor": {"ipc", "common"},
    "rosworker": {"ipc", "common"},
    "demo": {"supervisor", "common"},  # demo/run.py: the supervisor's Child; the robot: common/harness/
    # the harness (beside common/, imported by no gateway module): the fleet's wire, the ROS worker's client
    "common/harness": {"common", "ipc"},
}


def imported_packages(path) -> set[str]:
    """The top-level names ``path`` imports absolutely (relative imports stay in its package)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_each_package_imports_only_the_packages_below_it():
    offenders = []
    for top, allowed in MAY_IMPORT.items():
        for path in python_files(top):
            wrong = {n for n in imported_packages(path) if n in OURS and n != top.split("/")[0]} - allowed
            if wrong:
                offenders.append(f"{path.relative_to(REPO)} imports {sorted(wrong)}")
    assert not offenders, "imports against the layout:\n" + "\n".join(offenders)


# A family (the same name in each process: app/faults/ beside rosworker/faults/) plugs in through its
# FAMILY (app/core/family.py, rosworker/core/family.py).  It imports no other family (it reaches their
# resources through the registries of core/), and what is shared (core/ and the like, and the process's
# top modules: wsgi.py, main.py) imports no family: it finds them (discover()) and knows none by name.
# app/auth/ and app/audit/ are shared: every request passes them (create_app installs them by name).  So is
# a mode of a process, app/fleet/ (issue 34: create_app picks it by name): it serves the faults family's
# stream and rules through what that family offers (app/core/resources.py's Relayed), importing none.
SHARED = {"app": {"core", "sse", "openapi", "ui", "auth", "audit", "fleet"}, "rosworker": {"core", "ros"}}


def import_base(node: ast.ImportFrom, package: str) -> str:
    """The module a ``from ... import`` in ``package`` imports from, a relative one resolved."""
    if node.level == 0:
        return node.module or ""
    parts = package.split(".")
    return ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))


def imported_modules(path, package: str) -> set[str]:
    """The dotted names ``path`` (a module of ``package``) imports, relative imports resolved."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = import_base(node, package)
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)  # "from .. import faults"
    return names


def family_imports(root, top: str) -> list[str]:
    """Imports against the family rules in ``root/top`` (``app`` or ``rosworker``)."""
    shared = SHARED[top]
    offenders = []
    for path in (p for p in (root / top).rglob("*.py") if "__pycache__" not in p.parts):
        rel = path.relative_to(root)
        package = ".".join(rel.parts[:-1])   # a module's package; an __init__.py's own
        own = rel.parts[1] if len(rel.parts) > 2 else None    # the folder it is in (None: a top module)
        for name in imported_modules(path, package):
            parts = name.split(".")
            if len(parts) < 2 or parts[0] != top or not (root / top / parts[1] / "__init__.py").exists():
                continue
            target = parts[1]
            if target in shared or target == own:
                continue
            who = "shared code" if own is None or own in shared else f"family {own}"
            offenders.append(f"{rel}: {who} imports family {target} ({name})")
    return offenders


@pytest.mark.parametrize("top", sorted(SHARED))
def test_no_family_imports_another_and_the_shared_code_imports_none(top):
    offenders = family_imports(REPO, top)
    assert not offenders, "imports against the family rules:\n" + "\n".join(offenders)


def test_the_family_gate_catches_an_offender(tmp_path):
    for folder, text in (("core", ""), ("faults", ""), ("logs", "from ..faults import store\n"),
                         ("data", "def f():\n    from app.logs import book\n"),
                         ("core/inner", "from ... import faults\n"),
                         ("fleet", "from ..faults import hub as faultstream\n")):
        (tmp_path / "app" / folder).mkdir(parents=True, exist_ok=True)
        (tmp_path / "app" / folder / "__init__.py").write_text(text)
    (tmp_path / "app" / "wsgi.py").write_text("from .data import routes\nfrom .core import family\n")
    found = family_imports(tmp_path, "app")
    assert sorted({line.split(": ")[0] for line in found}) == [
        "app/core/inner/__init__.py", "app/data/__init__.py", "app/fleet/__init__.py", "app/logs/__init__.py",
        "app/wsgi.py"], found


# No import cycles among the gateway's modules: what a module imports when it is loaded (function-level
# imports and ``if TYPE_CHECKING:`` blocks run later or never, so they cannot close a cycle at load).
def load_time_imports(path, module: str, known: set[str]) -> set[str]:
    """The modules of ``known`` that loading ``path`` (``module``) imports."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out: set[str] = set()

    def visit(nodes) -> None:
        for node in nodes:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                visit(node.orelse)
                continue
            if isinstance(node, ast.Import):
                out.update(alias.name for alias in node.names if alias.name in known)
            elif isinstance(node, ast.ImportFrom):
                base = import_base(node, package)
                for alias in node.names:
                    full = f"{base}.{alias.name}"
                    out.add(full if full in known else base)
            visit(ast.iter_child_nodes(node))

    visit(ast.parse(path.read_text(), str(path)).body)
    return (out & known) - {module}


def import_cycles(root, tops) -> list[list[str]]:
    """Every cycle (strongly connected set of two or more modules) of the load-time imports under ``tops``."""
    files = {}
    for top in tops:
        for path in (p for p in (root / top).rglob("*.py") if "__pycache__" not in p.parts):
            parts = list(path.relative_to(root).with_suffix("").parts)
            files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {module: load_time_imports(path, module, set(files)) for module, path in files.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles = []
    for start in sorted(graph):   # Tarjan's strongly connected components, without recursion
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    cycles.append(sorted(component))
    return cycles


def test_no_import_cycles():
    cycles = import_cycles(REPO, ("app", "rosworker", "ipc", "common", "supervisor"))
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_cycle_gate_catches_a_cycle(tmp_path):
    (tmp_path / "app" / "faults").mkdir(parents=True)
    (tmp_path / "app" / "__init__.py").write_text("")
    (tmp_path / "app" / "faults" / "__init__.py").write_text("from . import hub\n")
    (tmp_path / "app" / "faults" / "hub.py").write_text("from .routes import x\ndef f():\n    from .. import wsgi\n")
    (tmp_path / "app" / "faults" / "routes.py").write_text("import app.faults.hub\n")
    (tmp_path / "app" / "wsgi.py").write_text("from .faults import hub\n")
    assert import_cycles(tmp_path, ("app",)) == [["app.faults.hub", "app.faults.routes"]]


# The bench runs from tests/ (tests/reliability/test_bench_smoke.py), not the other way round: a test
# may move without breaking ``make bench``.  What the bench shares with the tests (a private ROS domain,
# processes with deadlines, the gateway as an operator starts it, ROS programs both run) is
# common/harness/, which neither owns: it uses neither, and the bench uses nothing of tests/.
NOT_USED = {"bench": {"tests"}, "common/harness": {"tests", "bench"}, "demo": {"tests", "bench"}}


def used_packages(path) -> set[str]:
    """The dotted names ``path`` imports (absolutely) or runs (``"-m", "tests.support.x"``)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            names.update(re.findall(r"^(?:tests|bench)(?:\.\w+)+$", node.value))
    return names


def uses_against_the_layout(root) -> list[str]:
    offenders = []
    for top, banned in NOT_USED.items():
        for path in sorted(p for p in (root / top).rglob("*.py") if "__pycache__" not in p.parts):
            offenders += [f"{path.relative_to(root)}: {name}" for name in sorted(used_packages(path))
                          if name.split(".")[0] in banned]
    return offenders


def test_the_bench_uses_nothing_of_tests_and_the_harness_neither():
    offenders = uses_against_the_layout(REPO)
    assert not offenders, "uses against the layout:\n" + "\n".join(offenders)


def probe_tree(root, files: dict[str, str]) -> None:
    """Write ``files`` (a path under ``root`` -> its text), folders made as needed."""
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)


def test_the_uses_gate_catches_an_offender(tmp_path):
    probe_tree(tmp_path, {
        "bench/run.py": "from tests.support.gateway import Gateway\n",
        "bench/ok.py": "from common.harness.gateway import Gateway\nNAME = 'tests of the bench'\n",
        "bench/spawn.py": "ARGV = ['-m', 'tests.support.rospub']\n",
        "common/harness/proc.py": "def f():\n    import bench.procs\n",
        "demo/robot.py": "from tests.support import rosops\n"})
    found = uses_against_the_layout(tmp_path)
    assert found == [
        "bench/run.py: tests.support.gateway", "bench/spawn.py: tests.support.rospub",
        "common/harness/proc.py: bench.procs", "demo/robot.py: tests.support"], found


# The harness starts the gateway's processes from outside; no module of the gateway imports it (so that
# rclpy, zenoh and the tests' clients in it never load in a gateway process, and common/'s rules above
# may leave it out).
PRODUCT = ("app", "rosworker", "ipc", "supervisor", "common")


def harness_imports(root) -> list[str]:
    offenders = []
    for top in PRODUCT:
        for path in (p for p in (root / top).rglob("*.py") if "__pycache__" not in p.parts):
            rel = path.relative_to(root)
            if rel.parts[:2] == HARNESS:
                continue
            package = ".".join(rel.parts[:-1])
            names = [n for n in sorted(imported_modules(path, package))
                     if n == "common.harness" or n.startswith("common.harness.")]
            if names:
                offenders.append(f"{rel}: {', '.join(names)}")
    return offenders


def test_no_gateway_module_imports_the_harness():
    offenders = harness_imports(REPO)
    assert not offenders, "the gateway imports common/harness/:\n" + "\n".join(offenders)


def test_the_harness_gate_catches_an_offender(tmp_path):
    probe_tree(tmp_path, {
        "app/core/x.py": "from common.harness.procs import Proc\n",
        "common/settings.py": "from .harness import gateway\n",
        "common/families.py": "def f():\n    from . import harness\n",
        "supervisor/ok.py": "from common import settings\n",
        "common/harness/gateway.py": "from common.harness import procs\n"})
    found = harness_imports(tmp_path)
    assert sorted(line.split(": ")[0] for line in found) == [
        "app/core/x.py", "common/families.py", "common/settings.py"], found


def test_the_import_gate_reads_function_level_imports(tmp_path):
    probe = tmp_path / "mod.py"
    probe.write_text("from . import sibling\ndef f():\n    from app.wsgi import create_app\n    import ipc.protocol\n")
    assert imported_packages(probe) == {"app", "ipc"}


# Imported for real (not grepped): rosworker/, supervisor/, ipc/ and common/ load nothing from app/, so the HTTP side
# may change (Flask, gunicorn, gevent) without touching the process that owns rclpy.
CHECK = r"""
import importlib, pkgutil, sys
import common, ipc, rosworker, supervisor
for pkg in (common, ipc, rosworker, supervisor):
    for mod in pkgutil.iter_modules(pkg.__path__):
        importlib.import_module(f"{pkg.__name__}.{mod.name}")
loaded = sorted(m for m in sys.modules if m == "app" or m.startswith("app."))
print(",".join(loaded))
"""


def test_rosworker_supervisor_ipc_and_common_import_nothing_from_app():
    out = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"modules of app/ imported outside the HTTP workers: {out.stdout.strip()}"


# Tests mirror the code: tests/<package>/ for each package, tests/system/ for the gateway as it is
# deployed, tests/reliability/ for load and faults; only this file stays at the top.  The two processes'
# tests mirror their folders (a family, core/, ...): tests/app/<folder>/, tests/rosworker/<folder>/, and the
# modules that boot a whole gateway tests/system/<folder>/ for a folder of either (tests/system/'s top holds
# what spans the families: end to end, nginx, the README, the demo ...).
TEST_FOLDERS = {"app", "supervisor", "rosworker", "ipc", "common", "system", "reliability"}
MIRRORED = {"app": ("app",), "rosworker": ("rosworker",), "system": ("app", "rosworker")}


def code_folders(*packages: str) -> set[str]:
    return {p.name for top in packages for p in (REPO / top).iterdir() if p.is_dir() and p.name != "__pycache__"}


def misplaced_tests(root) -> list[str]:
    """The test modules under ``root`` (a tests/ tree) outside the folder of what they test."""
    misplaced = []
    for path in root.rglob("test_*.py"):
        parts = path.relative_to(root).parts
        if "__pycache__" in parts or parts == ("test_layout.py",):
            continue
        top, folders = parts[0], parts[1:-1]
        if top not in TEST_FOLDERS:
            misplaced.append(str(path.relative_to(root)))
        elif top in MIRRORED and not (folders == () and top == "system"):
            if len(folders) != 1 or folders[0] not in code_folders(*MIRRORED[top]):
                misplaced.append(str(path.relative_to(root)))
    return sorted(misplaced)


def test_every_test_module_lives_in_the_folder_of_what_it_tests():
    misplaced = misplaced_tests(REPO / "tests")
    assert not misplaced, (f"test modules outside tests/{{{','.join(sorted(TEST_FOLDERS))}}}/, or in tests/app/, "
                           f"tests/rosworker/, tests/system/ but not in a folder of the code they test: {misplaced}")
    assert TEST_FOLDERS - {"system", "reliability"} <= {p.name for p in REPO.iterdir() if (p / "__init__.py").exists()}


def test_the_test_folder_rule_catches_a_module_outside_its_folder(tmp_path):
    for rel in ("app/faults/test_a.py", "rosworker/core/test_b.py", "system/test_c.py", "system/logs/test_d.py",
                "ipc/test_e.py", "app/test_top.py", "rosworker/nofamily/test_f.py", "system/faults/deep/test_g.py",
                "elsewhere/test_h.py"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("")
    assert misplaced_tests(tmp_path) == ["app/test_top.py", "elsewhere/test_h.py", "rosworker/nofamily/test_f.py",
                                         "system/faults/deep/test_g.py"]


def test_every_dashboard_file_is_declared_package_data():
    """pyproject.toml: each folder of app/ui is a package (found, as every folder of ours is) with its files
    as package data (setuptools warns "Package would be ignored" otherwise), and the licence is an SPDX
    string."""
    import fnmatch
    import tomllib

    from setuptools import find_namespace_packages

    project = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert isinstance(project["project"]["license"], str)
    tool = project["tool"]["setuptools"]
    packages = find_namespace_packages(str(REPO), include=tool["packages"]["find"]["include"])
    undeclared = []
    for path in (REPO / "app" / "ui").rglob("*"):
        if path.is_dir() or "__pycache__" in path.parts:
            continue
        package = ".".join(path.parent.relative_to(REPO).parts)
        patterns = tool["package-data"].get(package, [])
        if package not in packages or not any(fnmatch.fnmatch(path.name, p) for p in patterns):
            undeclared.append(str(path.relative_to(REPO)))
    assert not undeclared, f"dashboard files not declared as package data in pyproject.toml: {undeclared}"

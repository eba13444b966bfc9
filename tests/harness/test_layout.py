"""The package layout's rules, read from the source with ``ast`` so they stay true.

* One room per job.  The top of the package holds only ``TOP_LEVEL``: the pytest11
  entry point (``plugin.py``, hooks only), ``python -m pytest_driveeval``, and the
  modules whose import paths are the public Python API (``pytest_driveeval`` itself,
  ``assertions``, ``verdict``, ``strategies``, ``closed_loop``, ``obstacle``).  What
  serves pytest (collection, fixtures, options, results, run folders, failures, status
  lines) lives in ``harness/``; what every part leans on (errors, ``Outcome``, atomic
  writes, time limits, the use-case interface and registry) in ``core/``, which imports
  no other part.  The public names of ``core`` are re-exported by ``pytest_driveeval``.
* ``io/`` holds one subpackage per format (``IO_FORMATS``) and no loose module: a
  reader shared by formats goes where its format is (``safe_pickle`` serves only
  ScenarioNet's pickles).
* No module imports an underscore name from another module: a private name is
  a promise to its own module only.
* No import cycles between packages (each root module counts as a package of
  its own), lazy imports inside functions included: data flows down.
* No import cycles between modules either, inside a package or across: a
  package's ``__init__`` counts as a module, and a submodule that needs what
  its package's ``__init__`` defines is a cycle (move it into a module both
  import).  Importing ``a.b.c`` counts as importing ``a.b.c`` only, not the
  ``__init__`` files Python runs on the way.  This rule counts imports under
  ``if TYPE_CHECKING:`` too: a circle of modules that name each other's types is
  still a circle to read (baseline/rules -> usecase -> scenario/loaded ->
  scenario/envelope -> baseline/rules was one, until ``Section`` got a module of its own).
* Each part of the package imports only the parts below it (``ALLOWED``).  A part is a
  subpackage, or a root module; ``harness/`` is a room, not one layer: its modules keep
  the layers they had at the root (``runs`` and ``settings`` lie below ``baseline``,
  which the collection, fixtures and results call), so each of its modules is a part of
  its own, for this rule and the package cycle rule.

Otherwise imports under ``if TYPE_CHECKING:`` are annotations, not dependencies.
"""
from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

from conftest import REPO_ROOT

PACKAGE = "pytest_driveeval"
ROOT = REPO_ROOT / PACKAGE

# The modules at the top of the package: the entry point, ``python -m``, the public import paths.
TOP_LEVEL = {"__init__", "__main__", "plugin", "assertions", "verdict", "strategies", "closed_loop", "obstacle"}
# io/'s subpackages, one per format.
IO_FORMATS = {"l5", "ros", "scenarionet", "commonroad", "t4"}
# Subpackages whose modules are parts of their own (see the docstring).
ROOMS = {"harness"}

# What each part of the package may import (besides itself).  A part is a
# subpackage (its top level), a module of a room, or a root module; the pytest side
# (plugin, harness's collect, fixtures, results, failure, progress, assertions,
# __init__) may import anything.
FOUNDATION = {"core", "geometry"}
ALLOWED = {
    "core": set(),
    "geometry": set(),
    "verdict": {"core"},
    "harness": set(),
    "harness.settings": {"harness.runs"},
    "harness.runs": {"core", "report"},
    "strategies": set(),
    "search": {"core", "strategies"},
    # Runs chunks of an item locally or on Ray; the use cases call it, never the other way round.
    "execute": {"core"},
    "io": FOUNDATION,
    "metrics": FOUNDATION,
    # The IDM expert baseline drives by the simulator's own IDM and lanes (sim never imports policies);
    # PDM-Closed scores its proposals with the nuPlan score's own terms and boxes (issue 36).
    "policies": {"core", "sim", "metrics", "geometry"},
    "sim": FOUNDATION | {"io", "metrics"},
    "synth": FOUNDATION | {"io"},
    # Reads LogArrays only for annotations, so sim may import raster later without a cycle.
    "raster": FOUNDATION | {"io"},
    "report": FOUNDATION,
    "scenario": {"core", "baseline"},
    # Reads and compares the records runs keep; the use cases declare their rules with its types.
    "baseline": {"core", "harness.runs", "harness.settings"},
    "usecases": FOUNDATION | {"baseline", "verdict", "io", "metrics", "sim", "policies", "report", "scenario",
                             "search", "strategies", "execute", "raster"},
    # Stable import paths of the Python API, onto their use case's package.
    "closed_loop": {"usecases"},
    "obstacle": {"usecases"},
    # ``python -m pytest_driveeval``: parses the command line and hands it to the command's module.
    "__main__": {"baseline", "datacheck"},
    # ``check-data``: reads each format as the evaluation would, up to its scene (sim builds them).
    "datacheck": FOUNDATION | {"io", "sim"},
}
PYTEST_SIDE = {"plugin", "harness.collect", "harness.fixtures", "harness.results", "harness.failure",
               "harness.progress", "assertions", "__init__"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO_ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def is_package(name: str) -> bool:
    return (REPO_ROOT / name.replace(".", "/") / "__init__.py").is_file()


def exists(name: str) -> bool:
    base = REPO_ROOT / name.replace(".", "/")
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def _type_checking_lines(tree: ast.AST) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                lines.update(range(child.lineno, (child.end_lineno or child.lineno) + 1))
    return lines


# Each rule reads every file: parse each once.
@functools.lru_cache(maxsize=None)
def imports(path: Path, annotations: bool = False) -> list[tuple[str, str | None, int]]:
    """(imported module, imported name or None, line) of every import in ``path``
    that reaches into our package, with relative imports resolved; those under
    ``if TYPE_CHECKING:`` only with ``annotations``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = set() if annotations else _type_checking_lines(tree)
    here = module_name(path)
    base = here if path.name == "__init__.py" else here.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if getattr(node, "lineno", None) in skip:
            continue
        if isinstance(node, ast.Import):
            out += [(a.name, None, node.lineno) for a in node.names if a.name.split(".")[0] == PACKAGE]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = base.split(".")
                target = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != PACKAGE:
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                # ``from pkg import submodule`` imports the submodule, not a name.
                out.append((sub, None, node.lineno) if exists(sub) else (target, alias.name, node.lineno))
    return out


def part(name: str) -> str:
    """The part of the package a module belongs to (its top-level subpackage, its module
    of a room, or root module)."""
    parts = name.split(".")
    if len(parts) > 2 and parts[1] in ROOMS:
        return ".".join(parts[1:3])
    return parts[1] if len(parts) > 1 else "__init__"


def node(name: str) -> str:
    """A module's package for the cycle rule: its own package, or itself at the root or in a room."""
    if is_package(name) or name.count(".") == 1 or (name.count(".") == 2 and name.split(".")[1] in ROOMS):
        return name
    return name.rpartition(".")[0]


SOURCES = sorted(ROOT.rglob("*.py"))


def test_the_rules_see_the_whole_package():
    # A rule that reads nothing passes vacuously: make sure it reads what is there.
    names = {module_name(p) for p in SOURCES}
    assert {"pytest_driveeval.plugin", "pytest_driveeval.geometry", "pytest_driveeval.sim.logreplay.engine",
            "pytest_driveeval.usecases.closed_loop", "pytest_driveeval.usecases.obstacle_segmentation"} <= names
    edges = [(module_name(p), t) for p in SOURCES for t, _, _ in imports(p)]
    assert ("pytest_driveeval.sim.logreplay.engine", "pytest_driveeval.geometry") in {
        (a, node(b)) for a, b in edges}
    # A lazy import inside a function is an edge of the module graph.
    assert "pytest_driveeval.execute.ray_path" in module_graph()["pytest_driveeval.execute.chunks"]
    # An import under TYPE_CHECKING is an edge only of the graph that counts annotations.
    assert "pytest_driveeval.scenario.loaded" in module_graph(annotations=True)["pytest_driveeval.core.usecase"]
    assert "pytest_driveeval.scenario.loaded" not in module_graph()["pytest_driveeval.core.usecase"]


def test_the_top_of_the_package_holds_only_the_entry_point_and_the_public_paths():
    loose = {p.stem for p in ROOT.glob("*.py")} - TOP_LEVEL
    assert not loose, (f"{sorted(loose)} at the top of {PACKAGE}/: the pytest side goes in harness/, "
                       "what every part leans on in core/")
    # The pytest11 entry point installed copies load.
    assert "pytest_driveeval.plugin" in (REPO_ROOT / "pyproject.toml").read_text(encoding="utf-8")


def test_the_plugin_holds_hooks_only():
    tree = ast.parse((ROOT / "plugin.py").read_text(encoding="utf-8"))
    functions = [n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))]
    assert functions and all(name.startswith("pytest_") for name in functions), functions


def test_io_holds_one_subpackage_per_format():
    io = ROOT / "io"
    entries = {p.name for p in io.iterdir() if p.name != "__pycache__"}
    assert entries == {"__init__.py"} | IO_FORMATS, sorted(entries)
    assert all((io / name / "__init__.py").is_file() for name in IO_FORMATS)


def test_no_module_imports_another_modules_private_names():
    offences = [f"{p.relative_to(REPO_ROOT)}:{line}: {target}.{name}"
                for p in SOURCES for target, name, line in imports(p)
                if name is not None and name.startswith("_") and not name.startswith("__")]
    assert not offences, "private names imported from another module:\n" + "\n".join(offences)


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    stack: list[str] = []

    def visit(v: str) -> list[str] | None:
        state[v] = 1
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if state.get(w) == 1:
                return stack[stack.index(w):] + [w]
            if w not in state:
                found = visit(w)
                if found:
                    return found
        stack.pop()
        state[v] = 2
        return None

    for v in sorted(graph):
        if v not in state:
            found = visit(v)
            if found:
                return found
    return None


def package_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for p in SOURCES:
        source = node(module_name(p))
        for target, _, _ in imports(p):
            if node(target) != source:
                graph.setdefault(source, set()).add(node(target))
    return graph


def test_no_import_cycles_between_packages():
    cycle = find_cycle(package_graph())
    assert cycle is None, "import cycle between packages: " + " -> ".join(cycle)


def module_graph(annotations: bool = False) -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for p in SOURCES:
        source = module_name(p)
        for target, _, _ in imports(p, annotations):
            if target != source:
                graph.setdefault(source, set()).add(target)
    return graph


def test_no_import_cycles_between_modules():
    cycle = find_cycle(module_graph(annotations=True))
    assert cycle is None, "import cycle between modules (annotations count): " + " -> ".join(cycle)


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


@pytest.mark.parametrize("source_part", sorted(ALLOWED))
def test_each_part_imports_only_what_lies_below_it(source_part):
    offences = []
    for p in SOURCES:
        name = module_name(p)
        if part(name) != source_part:
            continue
        for target, _, line in imports(p):
            to = part(target)
            if to != source_part and to not in ALLOWED[source_part]:
                offences.append(f"{p.relative_to(REPO_ROOT)}:{line}: imports {target}")
    assert not offences, f"{source_part} may import only {sorted(ALLOWED[source_part])}:\n" + "\n".join(offences)


def test_every_part_has_a_rule():
    parts = {part(module_name(p)) for p in SOURCES}
    assert parts - set(ALLOWED) - PYTEST_SIDE == set()


def test_tests_mirror_the_package():
    """Every subpackage has its tests in a folder of the same name, and no test file
    sits loose at the top of tests/."""
    tests = REPO_ROOT / "tests"
    assert not [p.name for p in tests.glob("test_*.py")]
    for sub in sorted(p.parent for p in ROOT.glob("*/__init__.py")):
        if sub.name == "usecases":
            continue
        assert (tests / sub.name).is_dir() and any((tests / sub.name).rglob("test_*.py")), sub.name
    for case in sorted(p.parent for p in (ROOT / "usecases").glob("*/__init__.py")):
        assert any((tests / "usecases" / case.name).glob("test_*.py")), case.name

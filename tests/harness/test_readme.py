"""What README.md and the manual's pages (docs/**/*.md) name exists: repository paths, the
scripts' options, the pytest options, ini keys, marks and extras, the Python names their
snippets import.

A new user copies these first; a renamed file or option must fail here, not in
their terminal.  Only code (spans, fenced blocks) and link targets are read: prose
such as "examples/min" is not a path.
"""
from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

from conftest import REPO_ROOT

try:
    # The names below import torch.  A pytester run earlier in the session (the browser
    # test's) drops the modules first imported inside it, and torch cannot be imported
    # twice in one process; imported at collection it is kept.
    import torch  # noqa: F401
except ImportError:
    pass

README = REPO_ROOT / "README.md"
DOCS = REPO_ROOT / "docs"
# Every page a user reads: the README and the manual (docs/, built by mkdocs.yml).
PAGES = [README, *sorted(DOCS.rglob("*.md"))]
PACKAGE = REPO_ROOT / "pytest_driveeval"
# The repository's top-level folders: a path starting with one of them is meant to be a
# repository file (driveeval-results/, checkpoints/, runs/ are the user's).
REPO_FOLDERS = ("pytest_driveeval", "scenario_tests", "fixtures", "examples", "benchmarks", "tests", "docs")
# Files the README shows only for what pytest would print about them: variants of
# scenario_tests/speed/urban.scenario.yaml that a reader is asked to imagine.
IMAGINED = {
    "scenario_tests/speed/bad.scenario.yaml": "urban.scenario.yaml with MaxSpeed misspelt",
    "scenario_tests/speed/tight.scenario.yaml": "urban.scenario.yaml with MaxAcceleration: 2.0",
}

FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
SPAN = re.compile(r"`([^`\n]+)`")
LINK = re.compile(r"\]\(([^)\s]+)\)")
PATH = re.compile(r"(?<![\w./:-])(?:\.\./)*(?:" + "|".join(REPO_FOLDERS) + r")/[\w.*/<-]*")
DOTTED = re.compile(r"(?<![\w.])pytest_driveeval(?:\.\w+)+")
COMMAND = re.compile(r"(?:^|\s)python (\S+\.py)([^\n|`]*)")


def _blocks(pages: list[Path] = PAGES) -> list[tuple[str, str]]:
    """(language, text) of every fenced block."""
    return [(m.group(1), m.group(2)) for page in pages for m in FENCE.finditer(page.read_text())]


def _code(pages: list[Path] = PAGES) -> list[str]:
    """The fenced blocks (continued lines joined), the code spans and the link targets that
    name repository paths from the root (a manual page's links to its neighbours are checked
    by mkdocs build --strict, tests/harness/test_docs_site.py)."""
    out = [block.replace("\\\n", " ") for _, block in _blocks(pages)]
    for page in pages:
        outside = FENCE.sub("", page.read_text())
        out += SPAN.findall(outside) + LINK.findall(outside)
    return out


def _repo_paths() -> set[str]:
    return {m.group(0).rstrip(".") for chunk in _code() for m in PATH.finditer(chunk)}


def _exists(path: str) -> bool:
    # YAML snippets name files relative to a scenario two folders down (../../fixtures/...).
    while path.startswith("../"):
        path = path[3:]
    path = path.split("<", 1)[0]  # runs/<run id>/...: the folder before the placeholder
    if "*" in path:
        return any(REPO_ROOT.glob(path))
    return (REPO_ROOT / path).exists()


def test_the_readme_names_paths_this_test_reads():
    # A regex that stopped matching would pass every check below vacuously.
    paths = _repo_paths()
    assert {"scenario_tests/speed/urban.scenario.yaml", "docs/report.png",
            "../../fixtures/models/planning_model.pt2"} <= paths
    assert len(paths) > 40


def test_every_repository_path_in_the_readme_exists():
    missing = sorted(p for p in _repo_paths() - set(IMAGINED) if not _exists(p))
    assert missing == []


def test_the_imagined_files_are_still_named_and_still_imagined():
    """The exceptions above go when the README stops showing them."""
    paths = _repo_paths()
    assert [p for p in IMAGINED if p not in paths or _exists(p)] == []


def test_scenarios_that_python_snippets_mark_exist():
    named = {name for lang, block in _blocks() if lang == "python"
             for name in re.findall(r"driveeval_scenario\(\"([^\"]+)\"\)", block)}
    assert named, "no @pytest.mark.driveeval_scenario in the README's snippets"
    scenarios = [p.as_posix() for p in (REPO_ROOT / "scenario_tests").rglob("*.scenario.yaml")]
    assert sorted(n for n in named if not any(s.endswith("/" + n) for s in scenarios)) == []


def _commands() -> list[tuple[str, list[str]]]:
    out = []
    for chunk in _code():
        for m in COMMAND.finditer(chunk):
            script = m.group(1)
            if script.split("/", 1)[0] in REPO_FOLDERS:
                out.append((script, re.findall(r"(?<!\S)(--[\w-]+)", m.group(2))))
    return out


def test_every_script_option_in_the_readme_is_the_scripts():
    commands = _commands()
    assert {"examples/train_gnn_policy.py", "benchmarks/bench_unroll.py"} <= {s for s, _ in commands}
    unknown = [(script, option) for script, options in commands for option in options
               if f'"{option}"' not in (REPO_ROOT / script).read_text()]
    assert unknown == []


def test_every_extra_and_mark_the_readme_installs_or_selects_exists():
    import tomllib

    project = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())
    extras = set(project["project"]["optional-dependencies"])
    markers = {line.split(":", 1)[0] for line in project["tool"]["pytest"]["ini_options"]["markers"]}
    text = "\n".join(_code())
    installed = {extra for spec in re.findall(r"pip install [^\n]*?['\"]?[.\w-]*\[([\w,-]+)\]", text)
                 for extra in spec.split(",")}
    selected = {word for expression in re.findall(r"(?<!python )-m (\w+|\"[^\"]+\"|'[^']+')", text)
                for word in re.findall(r"\w+", expression)} - {"not", "and", "or"}
    assert {"all", "test", "ray"} <= installed and {"demo", "slow"} <= selected
    assert sorted(installed - extras) == [] and sorted(selected - markers) == []


def _package_source() -> str:
    return "\n".join(p.read_text() for p in sorted(PACKAGE.rglob("*.py")))


def test_every_pytest_option_and_ini_key_in_the_readme_is_registered():
    registered = _package_source()
    text = "\n".join(_code())
    options = set(re.findall(r"--driveeval-[\w-]+", text))
    names = set(re.findall(r"(?<![\w.-])driveeval_\w+", text))  # ini keys, fixtures, the marker
    assert "--driveeval-output" in options and "driveeval_keep_runs" in names
    assert sorted(o for o in options if f'"{o}"' not in registered) == []
    assert sorted(n for n in names if not re.search(rf"\b{n}\b", registered)) == []


def _resolve(dotted: str) -> object:
    """The module, or the attribute of the longest importable module prefix."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            found = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for name in parts[cut:]:
            found = getattr(found, name)
        return found
    raise ModuleNotFoundError(dotted)


def test_every_python_name_in_the_readme_imports():
    pytest.importorskip("torch")
    dotted = {m.group(0) for chunk in _code() for m in DOTTED.finditer(chunk)}
    imported = []
    for lang, block in _blocks():
        if lang != "python":
            continue
        for node in ast.walk(ast.parse(block)):
            if isinstance(node, ast.ImportFrom) and node.module.startswith("pytest_driveeval"):
                imported += [f"{node.module}.{alias.name}" for alias in node.names]
    assert "pytest_driveeval.closed_loop.unroll_scenes" in imported
    broken = []
    for name in sorted(dotted | set(imported)):
        try:
            _resolve(name)
        except (ImportError, AttributeError) as error:
            broken.append(f"{name}: {error}")
    assert broken == []


def test_the_layout_lists_what_is_there():
    """The README's tree: top-level folders at the root; the package's entries under
    pytest_driveeval/, or inside the folder that starts their line (``sim/ ...;
    logreplay/``), also on the lines that carry its description on."""
    tree = next(block for _, block in _blocks() if block.startswith("pytest_driveeval/\n"))
    entry = re.compile(r"(?<![\w/.])[\w<>]+(?:\.py|/)(?:[\w<>]+/)?(?=[\s,]|$)")
    checked, missing = 0, []
    for line in tree.splitlines():
        first, _, rest = line.strip().partition(" ")
        if entry.fullmatch(first):
            folder = (REPO_ROOT if not line.startswith(" ") else PACKAGE) / first.split("<", 1)[0]
            names = [first] + entry.findall(rest)
        else:  # the description of the entry above, carried on
            names = entry.findall(line)
        for name in names:
            name = name.split("<", 1)[0]
            checked += 1
            if not any((base / name).exists() for base in (folder.parent, folder)):
                missing.append(f"{name} (near {folder.relative_to(REPO_ROOT)})")
    assert checked > 30 and missing == []


def _demo_items(pytester) -> list[pytest.Item]:
    recorder = pytester.inline_run("--collect-only", "-p", "no:cacheprovider", str(REPO_ROOT / "scenario_tests"))
    return recorder.getcalls("pytest_collection_finish")[0].session.items


def test_the_demo_items_the_readme_names_exist(pytester):
    named = {m.group(0) for chunk in _code() for m in re.finditer(r"scenario_tests/[\w./-]+::[\w\[\].-]+", chunk)}
    assert "scenario_tests/speed/urban.scenario.yaml::speed_limit[urban_stop]" in named
    collected = {Path(item.path).relative_to(REPO_ROOT).as_posix() + "::" + item.name
                 for item in _demo_items(pytester)}
    assert sorted(named - collected) == []


def test_the_demo_counts_in_the_readme_are_the_demos(pytester):
    """Every demo item passes or fails as it declares (the lead's demo run checks that);
    so its counts are the items collected and those marked xfail."""
    claimed = re.search(r"It ends `(\d+) passed, (\d+) xfailed`", README.read_text())
    assert claimed, "the README no longer states the demo's counts"
    items = _demo_items(pytester)
    xfail = sum(item.get_closest_marker("xfail") is not None for item in items)
    assert (len(items) - xfail, xfail) == tuple(map(int, claimed.groups()))


def test_these_checks_read_the_readme_and_every_manual_page():
    names = {page.relative_to(REPO_ROOT).as_posix() for page in PAGES}
    assert {"README.md", "docs/closed-loop.md", "docs/policy-benchmark.md", "docs/options.md",
            "docs/reference/scenario-keys.md"} <= names
    assert len(names) > 12


def test_the_readme_is_the_pitch_the_set_up_the_tour_and_links():
    """The rest lives in the manual, where a user finds it; a README that grows again is
    a manual page that was not made."""
    text = README.read_text()
    headings = re.findall(r"^## (.+)$", text, re.M)
    assert headings == ["Set-up in two commands", "A five-minute tour", "Bring your planner",
                        "Real files as their datasets write them", "The manual"]
    assert len(text.splitlines()) < 260

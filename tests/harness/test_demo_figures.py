"""The demo's figures that the manual quotes live in one file, docs/demo_figures.yaml: each quote
there must be in the README or a docs page with the file's value, each item must be a demo item,
and the cheap search (spray.scenario.yaml) must give the file's values when run afresh."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from conftest import REPO_ROOT

FIGURES = REPO_ROOT / "docs" / "demo_figures.yaml"
PAGES = [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").rglob("*.md"))]


def _entries() -> dict:
    return yaml.safe_load(FIGURES.read_text())


def _quoted(value, digits) -> str:
    return f"{value:.{digits}f}" if digits is not None else str(value)


def _quotes() -> list[tuple[str, str]]:
    """(figure, the text the manual must hold) for every quote of every figure."""
    out = []
    for name, entry in _entries().items():
        for figure in entry["figures"]:
            for quote in figure["quotes"]:
                text = quote["text"].replace("{}", _quoted(figure["value"], quote.get("digits")))
                out.append((f"{name}: {figure['key']}", text))
    return out


def test_the_file_names_the_figures_the_issue_found_stale():
    keys = {(name, figure["key"]) for name, entry in _entries().items() for figure in entry["figures"]}
    assert {("lateral_search", "figures.minimal_lateral"), ("lateral_search", "figures.search_examples"),
            ("gnn_search", "figures.search_failures"), ("gnn_search", "figures.search_examples"),
            ("dropout_search", "figures.minimal_dropout"), ("dropout_search", "details.search.minimal.case")} <= keys


def test_every_quote_of_a_demo_figure_is_in_the_manual_with_the_files_value():
    text = "\n".join(page.read_text() for page in PAGES)
    quotes = _quotes()
    assert len(quotes) > 20
    missing = [f"{figure}: {quote!r}" for figure, quote in quotes if quote not in text]
    assert missing == [], "the manual quotes these figures otherwise than docs/demo_figures.yaml (or not at all)"


@pytest.mark.parametrize("stale", ["lateral=-1.59375", "96 examples, 55 failing", "19 of 227", "dropout 0.42 (frame 1"])
def test_the_stale_figures_are_gone(stale):
    assert all(stale not in page.read_text() for page in PAGES)


def _record_value(record: dict, key: str):
    value = record
    for part in key.split("."):
        value = value[part]
    return value


def test_every_item_is_a_demo_item(pytester):
    recorder = pytester.inline_run("--collect-only", "-p", "no:cacheprovider", str(REPO_ROOT / "scenario_tests"))
    items = recorder.getcalls("pytest_collection_finish")[0].session.items
    collected = {Path(item.path).relative_to(REPO_ROOT).as_posix() + "::" + item.name for item in items}
    assert sorted(entry["item"] for entry in _entries().values() if entry["item"] not in collected) == []


def test_the_cheap_search_gives_the_files_figures_when_run_afresh(tmp_path):
    """The spray search runs in seconds; the default profile (the demo's), a fresh output folder
    (no example database), the demo's seed."""
    pytest.importorskip("rosbags")
    cheap = [entry for entry in _entries().values() if entry.get("cheap")]
    assert len(cheap) == 1
    entry = cheap[0]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO_ROOT), os.environ.get("PYTHONPATH")]))}
    env.pop("CI", None)  # CI's own search profile searches other examples
    done = subprocess.run([sys.executable, "-m", "pytest", entry["item"], "-p", "no:cacheprovider", "-q",
                           "--driveeval-search-profile", "default", "--driveeval-output", str(tmp_path / "out")],
                          cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert "1 xfailed" in done.stdout, done.stdout + done.stderr
    record = json.loads((tmp_path / "out" / "summary.json").read_text())["results"][0]
    assert {figure["key"]: _record_value(record, figure["key"]) for figure in entry["figures"]} == \
        {figure["key"]: figure["value"] for figure in entry["figures"]}

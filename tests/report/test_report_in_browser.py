"""The self-contained pytest-html report, opened in headless Chromium as a person
would: the bird's-eye GIF and the chart are really displayed (decoded, with a
non-zero natural size), not only present in the markup.

Needs Debian's chromium and the playwright package (no browser download: it
drives /usr/bin/chromium).  Skips where they are missing, except in CI, where
.ci/run installs them and a missing browser is a failure.
"""
from __future__ import annotations

import os
import shutil

import pytest

from conftest import REPO_ROOT

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _need(what: str) -> None:
    if os.environ.get("CI"):
        pytest.fail(f"{what} is missing in CI (.ci/run installs it)")
    pytest.skip(f"{what} not installed: the HTML report check needs the system's Chromium (apt install chromium) and playwright (pip install -e '.[test]')")


@pytest.fixture(scope="module")
def browser():
    if CHROMIUM is None:
        _need("chromium")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _need("playwright")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        yield browser
        browser.close()


def test_report_shows_the_animation_and_chart(pytester, browser):
    pytest.importorskip("torch")
    shutil.copytree(REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr", pytester.path / "gen.zarr")
    pytester.makefile(".scenario.yaml", cv="""\
ScenarioFormatVersion: 3.0.0
ScenarioName: constant-velocity-red-light
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - logs: {Path: gen.zarr}
  Model: constant_velocity
  Unroll: {Scenes: [3], StartFrame: 10}
  Conditions:
    Collisions: {Front: 0, Side: 0, Rear: 0, AtFaultOnly: true}
""")
    pytester.runpytest("-q", "--html=report.html", "--self-contained-html")
    page = browser.new_page(viewport={"width": 1280, "height": 1100})
    page.goto((pytester.path / "report.html").as_uri())
    page.wait_for_load_state("load")

    def shown_image() -> dict:
        page.wait_for_function("(() => { const i = document.querySelector('.media-container__viewport img');"
                               " return i && i.complete; })()")
        return page.evaluate("""(() => {
            const i = document.querySelector('.media-container__viewport img');
            const box = i.getBoundingClientRect();
            return {src: i.src.slice(0, 22), w: i.naturalWidth, h: i.naturalHeight, shown: box.width * box.height,
                    name: document.querySelector('.media__name').textContent};
        })()""")

    first = shown_image()
    target = os.environ.get("DRIVEEVAL_REPORT_SCREENSHOT")  # docs/make_report_picture.py: the README picture
    page.screenshot(path=target or str(pytester.path / "report.png"))
    page.click(".media-container__nav--right")
    second = shown_image()
    page.close()
    assert first["name"] == "scene_3_gif" and first["src"].startswith("data:image/gif;base64")
    assert second["name"] == "chart" and second["src"].startswith("data:image/png;base64")
    for image in (first, second):
        assert image["w"] > 0 and image["h"] > 0 and image["shown"] > 0, image


def test_an_expected_failure_shows_its_finding_not_a_hidden_traceback(project, browser):
    from conftest import speed_scenario

    project.makefile(".scenario.yaml", known=speed_scenario("known", datasets=("fast.csv",),
                                                            extra="XFail: {Reason: ticket 7, Strict: true}\n"))
    project.runpytest("-q", "--html=report.html", "--self-contained-html").assert_outcomes(xfailed=1)
    page = browser.new_page(viewport={"width": 1280, "height": 1100})
    page.goto((project.path / "report.html").as_uri())
    page.wait_for_load_state("load")
    page.wait_for_selector("tbody.results-table-row .col-result")
    shown = page.evaluate("""(() => {
        const row = [...document.querySelectorAll('tbody.results-table-row')]
            .find(r => (r.querySelector('.col-result') || {}).textContent === 'XFailed');
        const log = row.querySelector('.log');
        const box = log.getBoundingClientRect();
        return {text: log.innerText, red: log.querySelectorAll('span.error').length, area: box.width * box.height};
    })()""")
    page.close()
    assert shown["area"] > 0  # the row is open, its text on screen
    assert "speed should be <= 14 m/s" in shown["text"] and "known.scenario.yaml:11" in shown["text"]
    assert "ScenarioFailed" not in shown["text"] and "traceback" not in shown["text"]
    assert shown["red"] == 0  # pytest-html paints lines starting with "E " red: an error, which this is not
